//! The optimal assignment of this frame's observations to the lanes (docs/design.md §4.3): an
//! exhaustive branch-and-bound over the gated pairs with explicit stacks (no recursion), bounded
//! by the leaf count of the module docs.

use super::*;

/// Best assignment found by [`search`].
pub(super) struct Search {
    /// Lane of observation `i`, or [`NONE`].
    pub(super) assign: [u8; MAX_LANES],
    pub(super) total: f32,
    pub(super) leaves: u32,
}

/// Exhaustive branch-and-bound search over injective partial maps of `n_obs` observations into
/// the lanes (bit `j` of `allowed[i]`: pair `(i, j)` allowed, `cost[i][j]` its cost), with
/// `n_lanes` live lanes. Explicit stack, no recursion; see the module docs for the bound.
pub(super) fn search(
    cost: &[[f32; MAX_LANES]; MAX_LANES],
    allowed: &[u32; MAX_LANES],
    n_obs: usize,
    n_lanes: u32,
    gate: f32,
) -> Search {
    let n_obs = n_obs.min(MAX_LANES);
    let mut best = Search {
        assign: [NONE; MAX_LANES],
        total: f32::INFINITY,
        leaves: 0,
    };
    let mut cur = [NONE; MAX_LANES];
    // Next candidate per depth: 0..MAX_LANES a lane, MAX_LANES "unmatched", above: exhausted.
    let mut next = [0u8; MAX_LANES + 1];
    let mut acc = [0.0f32; MAX_LANES + 1];
    let mut used = 0u32;
    let mut depth = 0usize;
    // Every node is entered once per candidate step; this bounds the loop for any input.
    loop {
        let here = acc.get(depth).copied().unwrap_or(f32::INFINITY);
        let exhausted = if depth >= n_obs {
            let unmatched = n_lanes.saturating_sub(used.count_ones());
            #[allow(clippy::cast_precision_loss)]
            let total = here + gate * unmatched as f32;
            best.leaves = best.leaves.saturating_add(1);
            if total < best.total {
                best.total = total;
                best.assign = cur;
            }
            true
        } else {
            let c = next.get(depth).copied().unwrap_or(u8::MAX);
            if usize::from(c) > MAX_LANES {
                true
            } else {
                if let Some(n) = next.get_mut(depth) {
                    *n = c.saturating_add(1);
                }
                let lane = usize::from(c);
                let step = if lane < MAX_LANES {
                    let bit = 1u32 << lane;
                    let ok = used & bit == 0 && allowed.get(depth).is_some_and(|a| a & bit != 0);
                    if ok {
                        cost.get(depth)
                            .and_then(|row| row.get(lane))
                            .copied()
                            .map(|s| (s, c))
                    } else {
                        None
                    }
                } else {
                    Some((gate, NONE))
                };
                if let Some((s, l)) = step {
                    let a = here + s;
                    // Prune: every remaining term is >= 0, a tie never replaces the best.
                    if a < best.total {
                        if let Some(slot) = cur.get_mut(depth) {
                            *slot = l;
                        }
                        if l != NONE {
                            used |= 1u32 << l;
                        }
                        depth += 1;
                        if let Some(x) = acc.get_mut(depth) {
                            *x = a;
                        }
                        if let Some(n) = next.get_mut(depth) {
                            *n = 0;
                        }
                    }
                }
                false
            }
        };
        if exhausted {
            if depth == 0 {
                break;
            }
            depth -= 1;
            if let Some(slot) = cur.get_mut(depth) {
                if *slot != NONE {
                    used &= !(1u32 << *slot);
                }
                *slot = NONE;
            }
        }
    }
    best
}
