//! One row step of the coupled JPDACF (DESIGN 4.1 steps 2–5): gating, bounded joint-event
//! enumeration, joint-Gaussian event weights in the log domain, and the exact moment-matched update
//! of the event mixture.
//!
//! # The update, as computed
//! With `G = P̄ H̄ᵀ` (the covariance of every track's state with every track's predicted
//! measurement), a pattern `δ` (set of detected tracks) has gain `K_δ = G_δ S_δ⁻¹`. Summing the event
//! mixture `x̄_A = x̄ + K_δ ν_A`, `P_δ = P̄ − K_δ S_δ K_δᵀ` in closed form gives
//!
//! `x̄⁺ = x̄ + G y`, `P̄⁺ = P̄ − G (C + y yᵀ) Gᵀ`, with
//! `y = Σ_A β_A E_δ S_δ⁻¹ ν_A`, `C = Σ_A β_A E_δ (S_δ⁻¹ − S_δ⁻¹ ν_A ν_Aᵀ S_δ⁻¹) E_δᵀ`,
//!
//! where `E_δ` embeds the pattern's `k` tracks among all `D`. This is algebraically identical to
//! DESIGN's `Σ_A β_A (P_δ + x̄_A x̄_Aᵀ) − x̄⁺ x̄⁺ᵀ`; the state-sized work happens once per row and
//! only for the tracks that appear in some pattern (`C` and `y` are zero elsewhere).
//!
//! # How the events are scored
//! * The detection patterns are the subsets of the *eligible* tracks (not masked, at least one
//!   candidate), visited depth first: a pattern is its parent (the pattern without its highest
//!   track) plus one track, so its `S_δ = L D Lᵀ` factor is the parent's plus one row (`O(k²)`,
//!   no square root) and `ln det S_δ` the parent's plus `ln d_k`. A pattern without events has no
//!   descendant with events; its subtree is skipped.
//! * A pattern's events are enumerated depth first over its tracks; each pick extends the forward
//!   substitution `u = L⁻¹ ν` by one entry and `r = S_δ⁻¹ ν = Σ_a (u_a / d_a) (L⁻¹)_aᵀ` by one
//!   term, so an event costs `O(k)` plus its `O(k²)` share `β_A r rᵀ` of `C`.
//!   `Σ_δ W_δ S_δ⁻¹ = Σ_a (W / d_a) (L⁻¹)_aᵀ (L⁻¹)_a` is summed once per pattern-tree node with
//!   `W` the weight of its subtree, and `β[t][j]` once per event-tree node.
//! * Weights are `e^{lw − ref}` with `ref` the all-missed event's log-weight: nothing is rescaled
//!   during the pass; should the largest `lw` end up more than 60 (natural-log units) from `ref`
//!   (extreme parameters), the pass is redone with `ref` at that maximum.
//!
//! # Bounds and cost
//! * at most [`MAX_ROW_POINTS`] points per row (the rest are counted in `ignored_points`);
//! * at most `max_events` joint events are scored. When `Π_t (1 + n_t)` (a bound on the event
//!   count) exceeds the budget, the events are counted (at most `max_events + 1` leaves visited);
//!   when there are more, (track, point) candidates are dropped in order of increasing
//!   single-track PDA probability (each track's candidates and its miss normalised among
//!   themselves, so no track loses its plausible points first), until `Π_t (1 + n_t) ≤
//!   max_events`, and the row is flagged `approximated` (DESIGN 4.1 step 5: "drop the least
//!   likely candidates until it fits"). The coupled likelihood does not factor over clusters, so
//!   all tracks stay in one enumeration; the sort (a stable insertion sort, no panic branch) costs O(C²) compares for C ≤ D·m candidates;
//! * at most `2^D` detection patterns, `O(D²)` each; at most `max_events` events, `O(D²)` each;
//!   the covariance update `n(n+1)/2 · k_e · NS²` multiply-adds for `n` tracks of which `k_e`
//!   are eligible; no recursion (explicit stacks of depth ≤ D), no allocation. A second pass
//!   (same cost) only with extreme parameters (see above).
//!
//! Stages reported to a probe: [`Stage::Gating`] computes `ẑ_t`, `S̄_tt` and the gates;
//! [`Stage::Events`] the event count and pruning, `G` and `S̄` on the eligible tracks, the
//! patterns and events; [`Stage::Update`] the state update.
//!
//! A numerical failure (a non-positive-definite `S_δ`, all event weights zero, a correction that
//! could overflow: any entry of `G`, `G C'` or `G y` beyond `3e14` in magnitude) leaves the state
//! untouched and sets `failed`.

use nalgebra::{SMatrix, SVector};

use super::{get, set, Stacked};
use crate::math;
use crate::probe::{NoProbe, Probe, Stage};

/// Largest number of points one row can hold (the gate masks are `u32`).
pub const MAX_ROW_POINTS: usize = 32;

/// Largest number of (track, point) candidates (16 tracks × 32 points), the size of the pruning
/// list (3 KiB of stack when the budget forces pruning).
const CANDIDATES: usize = 16 * MAX_ROW_POINTS;

/// How a missed track is weighted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MissModel {
    /// `1 − P_D` (textbook JPDA).
    Textbook,
    /// `1 − P_D P_G`: a detection outside the gate is also a miss (DESIGN 4.1; the default).
    Gated,
}

/// Parameters of a row step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RowParams {
    /// Detection probability `P_D` of a lane in a row.
    pub pd: f32,
    /// Gate probability `P_G` (the χ² mass inside `gamma`).
    pub pg: f32,
    /// Gate threshold `γ` on the squared Mahalanobis distance (inclusive).
    pub gamma: f32,
    /// Poisson clutter density `λ_c`, points per metre of lateral extent in one row.
    pub clutter_density: f32,
    /// Variance of a point's lateral position, m².
    pub r: f32,
    /// Miss weighting.
    pub miss: MissModel,
}

impl Default for RowParams {
    /// `P_D = 0.9`, 99 % gate (`γ = 6.635`, one degree of freedom), `λ_c = 0.05 /m`,
    /// `r = 0.01 m²`, [`MissModel::Gated`].
    fn default() -> Self {
        Self {
            pd: 0.9,
            pg: 0.99,
            gamma: 6.634_897,
            clutter_density: 0.05,
            r: 0.01,
            miss: MissModel::Gated,
        }
    }
}

/// What a row step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowOutcome<const LANES: usize> {
    /// `P(track t missed)` per track.
    pub beta_miss: [f32; LANES],
    /// `P(point j from track t)`: `beta[t][j]`.
    pub beta: [[f32; MAX_ROW_POINTS]; LANES],
    /// Gate masks: bit `j` of `valid[t]` is set when point `j` is valid for track `t` (after any
    /// pruning).
    pub valid: [u32; LANES],
    /// Joint events scored.
    pub events: u32,
    /// Detection patterns scored (the all-missed one included; patterns under one without
    /// events are skipped).
    pub patterns: u32,
    /// Candidates dropped to fit the event budget.
    pub dropped_candidates: u32,
    /// The event budget forced the approximation.
    pub approximated: bool,
    /// Points valid for no track.
    pub clutter_points: u32,
    /// Points beyond [`MAX_ROW_POINTS`] or with a non-finite coordinate (not used).
    pub ignored_points: u32,
    /// A numerical failure: the state was left untouched.
    pub failed: bool,
}

impl<const LANES: usize> Default for RowOutcome<LANES> {
    fn default() -> Self {
        Self {
            beta_miss: [1.0; LANES],
            beta: [[0.0; MAX_ROW_POINTS]; LANES],
            valid: [0; LANES],
            events: 0,
            patterns: 0,
            dropped_candidates: 0,
            approximated: false,
            clutter_points: 0,
            ignored_points: 0,
            failed: false,
        }
    }
}

/// Counts the joint events (each of the first `n` tracks missed or assigned one point of its
/// mask, no point twice) up to `limit + 1`: an explicit-stack walk over the tracks (depth ≤ n)
/// whose last level is counted in one step (`1 + |mask ∖ used|`), stopping once past `limit`.
///
/// # Complexity
/// `O(min(events, limit) / (1 + m_last))` steps, no recursion.
fn count_events<const L: usize>(valid: &[u32; L], n: usize, limit: u64) -> u64 {
    const MISS: u64 = 1 << 32;
    let n = n.min(L);
    let Some(last) = n.checked_sub(1) else {
        return 1;
    };
    let last_mask = get(valid, last);
    let mut opt = [0u64; L]; // options left per level: bit 32 = missed, bits 0..32 = points
    let mut pick = [0u32; L];
    let mut used = 0u32;
    let mut depth = 0usize;
    let mut total = 0u64;
    set(&mut opt, 0, MISS | u64::from(get(valid, 0)));
    loop {
        if depth == last {
            total += 1 + u64::from((last_mask & !used).count_ones());
            if total > limit {
                return limit + 1;
            }
        } else {
            let o = get(&opt, depth);
            if o != 0 {
                set(&mut opt, depth, o & o.wrapping_sub(1));
                let bit = match o.trailing_zeros() {
                    32 => 0,
                    b => 1u32.wrapping_shl(b),
                };
                set(&mut pick, depth, bit);
                used |= bit;
                depth += 1;
                set(&mut opt, depth, MISS | u64::from(get(valid, depth) & !used));
                continue;
            }
        }
        // This level is done: back to the previous one.
        let Some(up) = depth.checked_sub(1) else {
            return total;
        };
        depth = up;
        used &= !get(&pick, depth);
    }
}

/// One row step on `state` with measurement row `h` (`z = hᵀ x_t + noise`, e.g. `[1, 1, 0, …]` for
/// the offset + curve state) and the row's lateral positions `points`.
///
/// # Complexity
/// See the module docs: bounded by `2^LANES` patterns and `max_events` events, no allocation, no
/// recursion.
pub fn update<const NS: usize, const LANES: usize>(
    state: &mut Stacked<NS, LANES>,
    h: &SVector<f32, NS>,
    points: &[f32],
    params: &RowParams,
    max_events: usize,
) -> RowOutcome<LANES> {
    update_masked(state, h, points, params, max_events, 0)
}

/// [`update`] with the tracks of `skip` (bit `t` = track `t`) excluded from gating and from the
/// events: they take no points and carry no miss factor, but the joint update still moves them
/// through their cross-covariances (the exact update for a lane that cannot be detected).
///
/// # Complexity
/// As [`update`].
pub fn update_masked<const NS: usize, const LANES: usize>(
    state: &mut Stacked<NS, LANES>,
    h: &SVector<f32, NS>,
    points: &[f32],
    params: &RowParams,
    max_events: usize,
    skip: u32,
) -> RowOutcome<LANES> {
    update_probed(state, h, points, params, max_events, skip, &mut NoProbe)
}

/// A pass weighs events by `e^{lw − ref}`; when its largest log-weight `lw` ends up more than
/// this (natural-log units) away from `ref`, the pass is redone with `ref` at that maximum. The
/// first pass takes `ref` = the all-missed event's log-weight, which no event undercuts by more
/// than the sum of the per-track detection gains (≈ 6.5 per track with the defaults), so the
/// redo only happens with extreme parameters.
const WINDOW: f32 = 60.0;

/// One member of the current detection pattern (its tracks in increasing order): its row of the
/// `LDLᵀ` factor of `S_δ` and of `L⁻¹`. A pattern's factor is its parent's (the pattern without
/// its highest track) plus one row, so a pattern costs `O(k²)`, not `O(k³)`.
#[derive(Clone, Copy)]
struct Member<const L: usize> {
    /// Track index.
    tr: u8,
    /// Position in the list of eligible tracks.
    pos: u8,
    /// Gate mask.
    mask: u32,
    /// The tracks of the pattern ending with this member (bit `t` = track `t`).
    set: u32,
    /// Predicted measurement `ẑ_t`.
    zh: f32,
    /// `1 / d_a`.
    invd: f32,
    /// `ln det` of the leading `a + 1` members' `S`.
    logdet: f32,
    /// Row `a` of the unit lower factor `L`, in member coordinates (entries `b < a`).
    l: [f32; L],
    /// Row `a` of `L⁻¹` in track coordinates (`li[tr_b] = (L⁻¹)_ab`, `li[tr] = 1`, the rest 0).
    li: [f32; L],
    /// Total event weight of the patterns in this member's subtree of the pattern tree (the
    /// pattern ending with this member and its descendants), for `Σ_δ wd_δ S_δ⁻¹`.
    wsub: f32,
}

impl<const L: usize> Member<L> {
    const EMPTY: Self = Self {
        tr: 0,
        pos: 0,
        mask: 0,
        set: 0,
        zh: 0.0,
        invd: 0.0,
        logdet: 0.0,
        l: [0.0; L],
        li: [0.0; L],
        wsub: 0.0,
    };
}

/// One node of a pattern's event tree (members `0..=a` assigned): the candidates left at this
/// level, the pick, the running forward substitution (`u_a`, `e_a = u_a / d_a`,
/// `q = Σ u_b e_b`, `r = Σ_b e_b (L⁻¹)_bᵀ`, i.e. `S⁻¹ ν` of the members so far, in track
/// coordinates) and the weight of the node's finished subtree.
#[derive(Clone, Copy)]
struct Level<const L: usize> {
    rem: u32,
    pick: u32,
    u: f32,
    q: f32,
    w: f32,
    r: [f32; L],
}

impl<const L: usize> Level<L> {
    const EMPTY: Self = Self {
        rem: 0,
        pick: 0,
        u: 0.0,
        q: 0.0,
        w: 0.0,
        r: [0.0; L],
    };
}

/// The mixture sums of a row, in track coordinates and units of `e^{−ref}`:
/// `wtot = Σ w`, `y = Σ w S_δ⁻¹ ν`, `c = Σ w (S_δ⁻¹ − S_δ⁻¹ ν νᵀ S_δ⁻¹)` (lower triangle, padded
/// with zeros outside the pattern), `bmiss[t] = Σ_{t missed} w`, `beta[t][j] = Σ_{t→j} w`.
struct Acc<const L: usize> {
    wtot: f32,
    y: [f32; L],
    c: [[f32; L]; L],
    bmiss: [f32; L],
    beta: [[f32; MAX_ROW_POINTS]; L],
    lwmax: f32,
    events: u32,
    patterns: u32,
}

impl<const L: usize> Acc<L> {
    const fn new() -> Self {
        Self {
            wtot: 0.0,
            y: [0.0; L],
            c: [[0.0; L]; L],
            bmiss: [0.0; L],
            beta: [[0.0; MAX_ROW_POINTS]; L],
            lwmax: f32::NEG_INFINITY,
            events: 0,
            patterns: 0,
        }
    }

    /// `β[t][j] += w` for member `mb` picking point `j` in events of total weight `w`.
    #[inline(always)]
    fn pick(&mut self, mb: &Member<L>, j: u32, w: f32) {
        if let Some(b) = self
            .beta
            .get_mut(usize::from(mb.tr))
            .and_then(|r| r.get_mut(j as usize))
        {
            *b += w;
        }
    }

    /// Adds an event of weight `w` with `r = S_δ⁻¹ ν`: `y += w r`, `c −= w r rᵀ` over the
    /// tracks `0..hi` (`r` is zero past the pattern's highest track).
    #[inline(always)]
    fn event(&mut self, r: &[f32; L], hi: usize, w: f32) {
        let r = r.get(..hi).unwrap_or(&[]);
        for (p, ((yp, crow), rp)) in self
            .y
            .iter_mut()
            .zip(self.c.iter_mut())
            .zip(r.iter())
            .enumerate()
        {
            let wr = w * rp;
            *yp += wr;
            for (cv, rq) in crow.iter_mut().zip(r.iter()).take(p + 1) {
                *cv -= wr * rq;
            }
        }
    }

    /// Adds `w (L⁻¹)_aᵀ (1/d_a) (L⁻¹)_a` for member `mb` (`w` the weight of the patterns
    /// containing the member's prefix): summed over the pattern tree, `Σ_δ wd_δ S_δ⁻¹`, at one
    /// `O(t²)` outer product per pattern instead of `O(k³)`.
    #[inline(always)]
    fn inverse_term(&mut self, mb: &Member<L>, w: f32) {
        if w == 0.0 {
            return;
        }
        let hi = (usize::from(mb.tr) + 1).min(L);
        let li = mb.li.get(..hi).unwrap_or(&[]);
        let s = w * mb.invd;
        for (p, (crow, lip)) in self.c.iter_mut().zip(li.iter()).enumerate() {
            let a = s * lip;
            for (cv, liq) in crow.iter_mut().zip(li.iter()).take(p + 1) {
                *cv += a * liq;
            }
        }
    }
}

/// What a row's event pass needs: the tracks, their predicted measurements and joint
/// innovation covariance, gate masks, points and the log-weight constants.
struct Ctx<'a, const L: usize> {
    elig: [u8; L],
    na: usize,
    sbar: &'a [[f32; L]; L],
    zhat: &'a [f32; L],
    valid: &'a [u32; L],
    points: &'a [f32],
    ln_2pi: f32,
    ln_pd_lambda: f32,
    ln_miss: f32,
    active: f32,
    /// The tracks that can be missed (bit `t`): the first `n`, not masked.
    active_set: u32,
}

impl<const L: usize> Ctx<'_, L> {
    /// Log-weight of a pattern with `k` detected tracks and `ln det S_δ = logdet`, before the
    /// events' Mahalanobis terms (DESIGN 4.1 step 3).
    fn base(&self, k: usize, logdet: f32) -> f32 {
        let kf = k as f32;
        -0.5 * logdet - 0.5 * kf * self.ln_2pi
            + kf * self.ln_pd_lambda
            + (self.active - kf) * self.ln_miss
    }

    /// Appends eligible track `pos` to the pattern `mems[..k]` as member `k` and computes its
    /// factor row (`f_b = S_tb − Σ_{c<b} l_bc f_c`, `l_kb = f_b / d_b`,
    /// `d_k = S_tt − Σ_b l_kb f_b`) and its row of `L⁻¹` (`e_t − Σ_b l_kb (L⁻¹)_b`). `false` when
    /// `d_k` is not positive and finite (`S_δ` not positive definite).
    fn push(&self, mems: &mut [Member<L>; L], k: usize, pos: usize) -> bool {
        let t = usize::from(get(&self.elig, pos));
        let Some((done, rest)) = mems.split_at_mut_checked(k) else {
            return false;
        };
        let (Some(new), Some(srow)) = (rest.first_mut(), self.sbar.get(t)) else {
            return false;
        };
        let mut f = [0.0f32; L];
        let mut l = [0.0f32; L];
        let mut dk = get(srow, t);
        for (b, mb) in done.iter().enumerate() {
            let mut fb = get(srow, usize::from(mb.tr));
            for (lbc, fc) in mb.l.iter().zip(f.iter()).take(b) {
                fb -= lbc * fc;
            }
            set(&mut f, b, fb);
            let lkb = fb * mb.invd;
            set(&mut l, b, lkb);
            dk -= lkb * fb;
        }
        if !(dk.is_finite() && dk > 0.0) {
            return false;
        }
        let mut li = [0.0f32; L];
        for (lkb, mb) in l.iter().zip(done.iter()) {
            let hi = usize::from(mb.tr) + 1;
            for (v, w) in li.iter_mut().zip(mb.li.iter()).take(hi) {
                *v -= lkb * w;
            }
        }
        set(&mut li, t, 1.0);
        *new = Member {
            tr: t as u8,
            pos: pos as u8,
            mask: get(self.valid, t),
            set: done.last().map_or(0, |m| m.set) | (1 << t),
            zh: get(self.zhat, t),
            invd: 1.0 / dk,
            logdet: done.last().map_or(0.0, |m| m.logdet) + math::ln(dk),
            l,
            li,
            wsub: 0.0,
        };
        true
    }

    /// Scores the events of the pattern `mems` (injective assignments of its members to points
    /// of their masks; explicit stack, depth ≤ k) into `acc`; returns the number of events and
    /// their total weight. A member's pick extends `u`, `e`, `q` and `r` by one term; a node's
    /// sums are added once its subtree is finished ([`Acc::finish`]).
    fn score(
        &self,
        mems: &[Member<L>],
        base: f32,
        reference: f32,
        lev: &mut [Level<L>; L],
        acc: &mut Acc<L>,
    ) -> (u32, f32) {
        let weighted = base.is_finite();
        let k = mems.len().min(L);
        let Some(m0) = mems.first() else {
            // The all-missed event.
            if !weighted {
                return (1, 0.0);
            }
            acc.lwmax = acc.lwmax.max(base);
            return (1, math::exp(base - reference));
        };
        let levs = lev.get_mut(..k).unwrap_or(&mut []);
        if let Some(l0) = levs.first_mut() {
            l0.rem = m0.mask;
        }
        let mut events = 0u32;
        let mut wd = 0.0f32;
        let mut used = 0u32;
        let mut depth = 0usize;
        // Each pass descends (≤ k), takes a candidate or ascends: bounded by the event tree.
        while let Some((prev, cur)) = levs.split_at_mut_checked(depth) {
            let (Some((lv, below)), Some(mb)) = (cur.split_first_mut(), mems.get(depth)) else {
                break;
            };
            if lv.rem == 0 {
                // Every child of the node one level up is done: finish it.
                let Some((pl, upper)) = prev.split_last_mut() else {
                    break;
                };
                if let Some(pm) = mems.get(depth - 1) {
                    acc.pick(pm, pl.pick, pl.w);
                }
                match upper.last_mut() {
                    Some(gp) => gp.w += pl.w,
                    None => wd += pl.w,
                }
                used &= !(1u32.wrapping_shl(pl.pick));
                depth -= 1;
                continue;
            }
            let hi = (usize::from(mb.tr) + 1).min(L);
            if below.is_empty() {
                // The last member: every remaining candidate is a leaf (one joint event) and the
                // forward substitution's prefix `ẑ + Σ_b l_b u_b` is shared by all of them.
                let mut c = mb.zh;
                for (lb, pl) in mb.l.iter().zip(prev.iter()) {
                    c += lb * pl.u;
                }
                let (q0, r0) = prev.last().map_or((0.0, [0.0; L]), |p| (p.q, p.r));
                let mut rem = lv.rem;
                lv.rem = 0;
                let mut wsum = 0.0f32;
                while rem != 0 {
                    let j = rem.trailing_zeros();
                    rem &= rem.wrapping_sub(1);
                    events += 1;
                    let ua = self.points.get(j as usize).copied().unwrap_or(0.0) - c;
                    let ea = ua * mb.invd;
                    let q = q0 + ua * ea;
                    if !(weighted && q.is_finite()) {
                        continue; // weight 0 (e.g. ln 0 of a zero miss factor): no contribution
                    }
                    let lw = base - 0.5 * q;
                    acc.lwmax = acc.lwmax.max(lw);
                    let w = math::exp(lw - reference);
                    for ((v, pv), li) in lv.r.iter_mut().zip(r0.iter()).zip(mb.li.iter()) {
                        *v = pv + ea * li;
                    }
                    acc.pick(mb, j, w);
                    acc.event(&lv.r, hi, w);
                    wsum += w;
                }
                match prev.last_mut() {
                    Some(p) => p.w += wsum,
                    None => wd += wsum,
                }
                continue;
            }
            let j = lv.rem.trailing_zeros();
            lv.rem &= lv.rem.wrapping_sub(1);
            lv.pick = j;
            let mut ua = self.points.get(j as usize).copied().unwrap_or(0.0) - mb.zh;
            for (lb, pl) in mb.l.iter().zip(prev.iter()) {
                ua -= lb * pl.u;
            }
            let ea = ua * mb.invd;
            lv.u = ua;
            // All L entries, so that r stays zero past the highest member's track.
            match prev.last() {
                Some(p) => {
                    lv.q = p.q + ua * ea;
                    for ((v, pv), w) in lv.r.iter_mut().zip(p.r.iter()).zip(mb.li.iter()) {
                        *v = pv + ea * w;
                    }
                }
                None => {
                    lv.q = ua * ea;
                    for (v, w) in lv.r.iter_mut().zip(mb.li.iter()) {
                        *v = ea * w;
                    }
                }
            }
            if let Some(next) = below.first_mut() {
                lv.w = 0.0;
                used |= 1u32.wrapping_shl(j);
                depth += 1;
                next.rem = mems.get(depth).map_or(0, |m| m.mask) & !used;
            }
        }
        (events, wd)
    }

    /// One pass over the detection patterns (the subsets of the eligible tracks, depth first, so
    /// that each extends its parent's factor by one row; a pattern without events has no
    /// descendant with events, so its subtree is skipped), weights `e^{lw − reference}`.
    /// `false` when some `S_δ` is not positive definite.
    fn pass(&self, reference: f32, acc: &mut Acc<L>) -> bool {
        let mut mems = [Member::<L>::EMPTY; L];
        let mut lev = [Level::<L>::EMPTY; L];
        let mut k = 0usize;
        let mut next = 0usize;
        let mut descend = true;
        let mut first = true;
        loop {
            if first {
                first = false; // the empty pattern (every track missed)
            } else if descend && next < self.na {
                if !self.push(&mut mems, k, next) {
                    return false;
                }
                k += 1;
            } else {
                // Pattern tree: the member's subtree is done; add its S⁻¹ term, pass its weight up.
                let Some(a) = k.checked_sub(1) else {
                    break;
                };
                let Some((head, tail)) = mems.split_at_mut_checked(a) else {
                    break;
                };
                let Some(last) = tail.first() else {
                    break;
                };
                acc.inverse_term(last, last.wsub);
                if let Some(parent) = head.last_mut() {
                    parent.wsub += last.wsub;
                }
                next = usize::from(last.pos) + 1;
                k = a;
                descend = true;
                continue;
            }
            acc.patterns += 1;
            let pattern = mems.get(..k).unwrap_or(&[]);
            let base = self.base(k, pattern.last().map_or(0.0, |m| m.logdet));
            let (events, wd) = self.score(pattern, base, reference, &mut lev, acc);
            acc.events += events;
            descend = events > 0;
            next = pattern.last().map_or(0, |m| usize::from(m.pos) + 1);
            if wd > 0.0 {
                let mut missed = self.active_set;
                if let Some(last) = k.checked_sub(1).and_then(|a| mems.get_mut(a)) {
                    last.wsub += wd;
                    missed &= !last.set;
                }
                acc.wtot += wd;
                while missed != 0 {
                    if let Some(b) = acc.bmiss.get_mut(missed.trailing_zeros() as usize) {
                        *b += wd;
                    }
                    missed &= missed - 1;
                }
            }
        }
        true
    }
}

/// [`update_masked`] reporting its stages ([`Stage::Gating`], [`Stage::Events`],
/// [`Stage::Update`]) to `probe`.
///
/// # Complexity
/// As [`update`].
#[allow(non_snake_case, clippy::too_many_lines)]
pub fn update_probed<const NS: usize, const LANES: usize, P: Probe>(
    state: &mut Stacked<NS, LANES>,
    h: &SVector<f32, NS>,
    points: &[f32],
    params: &RowParams,
    max_events: usize,
    skip: u32,
    probe: &mut P,
) -> RowOutcome<LANES> {
    probe.enter(Stage::Gating);
    let mut out = RowOutcome::<LANES>::default();
    let (xs, ps, n) = state.parts_mut();
    let n = n.min(LANES);
    let m = points.len().min(MAX_ROW_POINTS);
    out.ignored_points = (points.len() - m) as u32;
    let points = points.get(..m).unwrap_or(&[]);
    if n == 0 {
        out.ignored_points += points.iter().filter(|z| !z.is_finite()).count() as u32;
        out.clutter_points = points.iter().filter(|z| z.is_finite()).count() as u32;
        return out;
    }
    let n_skipped = (0..n).filter(|t| skip & (1 << t) != 0).count();

    // Gating on each track's marginal (step 2): ẑ_t = h·x_t and S̄_tt = hᵀ P_tt h + r, on plain
    // arrays (`[f32; NS]` vectors, column-major blocks) so the small products unroll. The rest
    // of G = P̄ H̄ᵀ and S̄ = H̄ P̄ H̄ᵀ + r I is only needed for the eligible tracks (below).
    let [hv] = h.data.0;
    let mut zhat = [0.0f32; LANES];
    let mut sbar = [[0.0f32; LANES]; LANES];
    for (t, ((prow, x), (zh, srow))) in ps
        .iter()
        .zip(xs.iter())
        .zip(zhat.iter_mut().zip(sbar.iter_mut()))
        .enumerate()
        .take(n)
    {
        let [xv] = x.data.0;
        *zh = dot(&hv, &xv);
        if let Some(ptt) = prow.get(t) {
            set(srow, t, dot(&hv, &mat_vec(ptt, &hv)) + params.r);
        }
    }
    let mut any_valid = 0u32;
    for (t, (srow, (zt, valid))) in sbar
        .iter()
        .zip(zhat.iter().zip(out.valid.iter_mut()))
        .enumerate()
        .take(n)
    {
        let st = get(srow, t);
        if !(st.is_finite() && st > 0.0) {
            out.failed = true;
            return out;
        }
        if skip & (1 << t) != 0 {
            continue;
        }
        let mut mask = 0u32;
        for (j, z) in points.iter().enumerate() {
            let e = z - zt;
            // Inclusive gate; a non-finite point gives NaN or inf and never passes.
            if e * e / st <= params.gamma {
                mask |= 1 << j;
            }
        }
        *valid = mask;
        any_valid |= mask;
    }
    for (j, z) in points.iter().enumerate() {
        if !z.is_finite() {
            out.ignored_points += 1;
        } else if any_valid & (1 << j) == 0 {
            out.clutter_points += 1;
        }
    }

    probe.enter(Stage::Events);
    let ln_pd = math::ln(params.pd);
    let missf = match params.miss {
        MissModel::Textbook => 1.0 - params.pd,
        MissModel::Gated => 1.0 - params.pd * params.pg,
    };
    let ln_miss = math::ln(missf);
    let ln_lambda = math::ln(params.clutter_density);
    let ln_2pi = math::ln(2.0 * core::f32::consts::PI);

    // Bounded enumeration (step 5): when the events do not fit, drop candidates in order of their
    // single-track PDA probability `p_tj = L_tj / (1 − P_D P_G + Σ_j' L_tj')`,
    // `L_tj = P_D N(z_j; ẑ_t, S_t) / λ_c` — the least likely first, whatever track they belong to,
    // so a track keeps its plausible points — until the bound Π (1 + n_t) fits the budget.
    // The bound is an upper bound of the event count, so the exact count is only needed when it
    // exceeds the budget.
    let budget = max_events.max(1) as u64;
    let bound = |valid: &[u32; LANES]| -> u64 {
        valid
            .iter()
            .take(n)
            .map(|v| 1 + u64::from(v.count_ones()))
            .product()
    };
    if bound(&out.valid) > budget && count_events(&out.valid, n, budget) > budget {
        out.approximated = true;
        prune(
            &mut out,
            &sbar,
            &zhat,
            points,
            n,
            budget,
            ln_pd - ln_lambda,
            ln_miss,
            ln_2pi,
        );
    }

    // Event weights (step 3) and the mixture moments (step 4), in one pass over the detection
    // patterns and their events (`Ctx::pass`), redone once if the weights' scale was off.
    let mut elig = [0u8; LANES];
    let mut na = 0usize;
    for (t, v) in out.valid.iter().enumerate().take(n) {
        if skip & (1 << t) == 0 && *v != 0 {
            set(&mut elig, na, t as u8);
            na += 1;
        }
    }
    // G restricted to the eligible columns, g[i][s] = P_{i,e_s} h, and S̄ among the eligible
    // tracks (symmetric: the upper triangle, mirrored).
    let el = elig.get(..na).unwrap_or(&[]);
    let mut g = [[[0.0f32; NS]; LANES]; LANES];
    if na > 0 {
        for (gi, prow) in g.iter_mut().zip(ps.iter()).take(n) {
            for (gs, &ts) in gi.iter_mut().zip(el.iter()) {
                if let Some(p) = prow.get(usize::from(ts)) {
                    *gs = mat_vec(p, &hv);
                }
            }
        }
    }
    for (s1, &t1) in el.iter().enumerate() {
        let g1 = g
            .get(usize::from(t1))
            .copied()
            .unwrap_or([[0.0; NS]; LANES]);
        for (&t2, g12) in el.iter().zip(g1.iter()).skip(s1 + 1) {
            let v = dot(&hv, g12);
            put(&mut sbar, usize::from(t1), usize::from(t2), v);
            put(&mut sbar, usize::from(t2), usize::from(t1), v);
        }
    }
    let ctx = Ctx {
        elig,
        na,
        sbar: &sbar,
        zhat: &zhat,
        valid: &out.valid,
        points,
        ln_2pi,
        ln_pd_lambda: ln_pd - ln_lambda,
        ln_miss,
        active: (n - n_skipped) as f32,
        active_set: !skip & (u32::MAX >> (32 - n.clamp(1, 32))),
    };
    let empty = ctx.base(0, 0.0);
    let mut reference = if empty.is_finite() { empty } else { 0.0 };
    let mut acc = Acc::<LANES>::new();
    if !ctx.pass(reference, &mut acc) {
        return failed(out);
    }
    if acc.lwmax.is_finite()
        && ((acc.lwmax - reference).abs() > WINDOW || !(acc.wtot.is_finite() && acc.wtot > 0.0))
    {
        reference = acc.lwmax;
        acc = Acc::new();
        if !ctx.pass(reference, &mut acc) {
            return failed(out);
        }
    }
    out.events = acc.events;
    out.patterns = acc.patterns;
    let Acc {
        wtot,
        y,
        c,
        bmiss,
        beta,
        ..
    } = acc;
    probe.enter(Stage::Update);
    if !(wtot.is_finite() && wtot > 0.0) {
        return failed(out);
    }
    let inv = 1.0 / wtot;
    // Only the eligible tracks (those in some detection pattern) have rows in y and C, so
    // C' = C + y yᵀ is compacted to them: P⁺ = P̄ − G_e C'_e G_eᵀ, x⁺ = x̄ + G_e y_e. With none
    // (every track missed for sure), the state does not move.
    let mut ye = [0.0f32; LANES];
    for (ys, &ts) in ye.iter_mut().zip(el.iter()) {
        *ys = get(&y, usize::from(ts)) * inv;
    }
    let mut ce = [[0.0f32; LANES]; LANES];
    for (s1, &t1) in el.iter().enumerate() {
        let y1 = get(&ye, s1);
        for (s2, &t2) in el.iter().enumerate().take(s1 + 1) {
            let v = at(&c, usize::from(t1), usize::from(t2)) * inv + y1 * get(&ye, s2);
            put(&mut ce, s1, s2, v);
            put(&mut ce, s2, s1, v);
        }
    }
    let gn = g.get(..if na > 0 { n } else { 0 }).unwrap_or(&[]);
    let yn = ye.get(..na).unwrap_or(&[]);
    let cn = ce.get(..na).unwrap_or(&[]);
    // u[i][s'] = Σ_s g[i][s] C'[s][s'], dx[i] = Σ_s g[i][s] y[s].
    let mut dx = [[0.0f32; NS]; LANES];
    let mut u = [[[0.0f32; NS]; LANES]; LANES];
    // (Sums go to locals, not through references into the arrays, so they stay in registers.)
    for ((gi, d), ui) in gn.iter().zip(dx.iter_mut()).zip(u.iter_mut()) {
        let gi = gi.get(..na).unwrap_or(&[]);
        let mut acc = [0.0f32; NS];
        for (git, yt) in gi.iter().zip(yn.iter()) {
            axpy(&mut acc, *yt, git);
        }
        *d = acc;
        for (s2, uis) in ui.iter_mut().enumerate().take(na) {
            let mut acc = [0.0f32; NS];
            for (git, crow) in gi.iter().zip(cn.iter()) {
                axpy(&mut acc, get(crow, s2), git);
            }
            *uis = acc;
        }
    }
    if na > 0 {
        // P⁺_ij = P̄_ij − Σ_s u[i][s] g[j][s]ᵀ for the upper blocks (diagonal blocks symmetrised),
        // written in place with the mirrored lower blocks. A row must leave the state untouched
        // when it fails, so the update is only done when it cannot produce a non-finite value:
        // with every u, g and dx entry finite and at most `LIMIT` in magnitude, each correction is
        // below `16·LIMIT² < 2^103` (half an ulp of f32::MAX), so subtracting it from a finite
        // entry cannot overflow, whatever the state's magnitude; beyond (absurd values) the row
        // fails.
        const LIMIT: f32 = 3e14;
        let small = |v: &f32| v.abs() <= LIMIT; // false for NaN and ±inf
        let mut ok = dx.iter().take(n).all(|d| d.iter().all(small));
        for (ui, gi) in u.iter().zip(gn.iter()) {
            ok &= ui.iter().take(na).all(|v| v.iter().all(small));
            ok &= gi.iter().take(na).all(|v| v.iter().all(small));
        }
        if !ok {
            return failed(out);
        }
        for (i, ui) in u.iter().enumerate().take(n) {
            let ui = ui.get(..na).unwrap_or(&[]);
            for (j, gj) in gn.iter().enumerate().skip(i) {
                // Column b of the block: P_·b − Σ_s u_s g_s[b].
                let mut red = [[0.0f32; NS]; NS];
                for (uv, gv) in ui.iter().zip(gj.iter()) {
                    for (col, gb) in red.iter_mut().zip(gv.iter()) {
                        axpy(col, *gb, uv);
                    }
                }
                let Some(pij) = ps.get_mut(i).and_then(|r| r.get_mut(j)) else {
                    continue;
                };
                let mut blk = pij.data.0;
                for (col, rcol) in blk.iter_mut().zip(red.iter()) {
                    for (e, r) in col.iter_mut().zip(rcol.iter()) {
                        *e -= r;
                    }
                }
                if i == j {
                    for a in 0..NS {
                        for b in 0..a {
                            // (Halves first: cannot overflow.)
                            let v = 0.5 * at(&blk, a, b) + 0.5 * at(&blk, b, a);
                            put(&mut blk, a, b, v);
                            put(&mut blk, b, a, v);
                        }
                    }
                }
                let m = SMatrix::<f32, NS, NS>::from_data(nalgebra::ArrayStorage(blk));
                *pij = m;
                if i != j {
                    if let Some(b) = ps.get_mut(j).and_then(|r| r.get_mut(i)) {
                        *b = m.transpose();
                    }
                }
            }
        }
        for (x, d) in xs.iter_mut().zip(dx.iter()).take(n) {
            for (xv, dv) in x.iter_mut().zip(d.iter()) {
                *xv += dv;
            }
        }
    }
    for (t, ((bm, brow), src)) in out
        .beta_miss
        .iter_mut()
        .zip(out.beta.iter_mut())
        .zip(beta.iter())
        .enumerate()
        .take(n)
    {
        *bm = if skip & (1 << t) != 0 {
            1.0
        } else {
            get(&bmiss, t) * inv
        };
        for (v, s) in brow.iter_mut().zip(src.iter()).take(m) {
            *v = s * inv;
        }
    }
    out
}

/// Drops (track, point) candidates in order of increasing single-track PDA probability until
/// the bound `Π (1 + n_t)` on the event count fits `budget` (step 5); `ln_pd_lambda` is
/// `ln P_D − ln λ_c`.
///
/// # Complexity
/// `O(C²)` compares (insertion sort) for the `C ≤ n·m` candidates; 4 KiB of stack for the candidate list.
#[allow(clippy::too_many_arguments)]
fn prune<const LANES: usize>(
    out: &mut RowOutcome<LANES>,
    sbar: &[[f32; LANES]; LANES],
    zhat: &[f32; LANES],
    points: &[f32],
    n: usize,
    budget: u64,
    ln_pd_lambda: f32,
    ln_miss: f32,
    ln_2pi: f32,
) {
    let mut cand = [(0.0f32, 0u8, 0u8); CANDIDATES];
    let mut nc = 0usize;
    for t in 0..n {
        let st = at(sbar, t, t);
        let zt = get(zhat, t);
        let ln_norm = ln_pd_lambda - 0.5 * (ln_2pi + math::ln(st));
        let mask = get(&out.valid, t);
        let first = nc;
        let mut lmax = ln_miss;
        for (j, z) in points.iter().enumerate() {
            if mask & (1 << j) != 0 {
                let e = z - zt;
                let l = ln_norm - 0.5 * (e * e / st);
                lmax = lmax.max(l);
                set(&mut cand, nc, (l, t as u8, j as u8));
                nc += 1;
            }
        }
        // log-sum-exp over the miss and the candidates, then normalise in place.
        let mut sum = math::exp(ln_miss - lmax);
        for c in cand.iter().take(nc).skip(first) {
            sum += math::exp(c.0 - lmax);
        }
        let ln_total = lmax + math::ln(sum);
        for c in cand.iter_mut().take(nc).skip(first) {
            c.0 -= ln_total;
        }
    }
    if let Some(c) = cand.get_mut(..nc) {
        super::sort_by(c, |a, b| a.0.total_cmp(&b.0).is_lt());
    }
    for &(_, t, j) in cand.iter().take(nc) {
        let bound: u64 = out
            .valid
            .iter()
            .take(n)
            .map(|v| 1 + u64::from(v.count_ones()))
            .product();
        if bound <= budget {
            break;
        }
        let t = usize::from(t);
        let mask = get(&out.valid, t) & !(1u32 << j);
        set(&mut out.valid, t, mask);
        out.dropped_candidates += 1;
    }
}

/// Marks `out` failed, with the weights of an untouched row (β cleared, every track missed).
fn failed<const LANES: usize>(mut out: RowOutcome<LANES>) -> RowOutcome<LANES> {
    out.failed = true;
    out.beta = [[0.0; MAX_ROW_POINTS]; LANES];
    out.beta_miss = [1.0; LANES];
    out
}

/// Element `(i, j)` of a fixed 2-D array, or 0 past its end.
#[inline]
fn at<const R: usize, const C: usize>(a: &[[f32; C]; R], i: usize, j: usize) -> f32 {
    a.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0)
}

/// `a · b`.
#[inline(always)]
fn dot<const N: usize>(a: &[f32; N], b: &[f32; N]) -> f32 {
    a.iter().zip(b.iter()).map(|(x, y)| x * y).sum()
}

/// `P h` for a column-major block `P` (columns where `h` is zero are skipped: `h = [1, 1, 0, …]`
/// has zeros).
#[inline(always)]
fn mat_vec<const N: usize>(p: &SMatrix<f32, N, N>, h: &[f32; N]) -> [f32; N] {
    let mut out = [0.0f32; N];
    for (col, hb) in p.data.0.iter().zip(h.iter()) {
        if *hb != 0.0 {
            axpy(&mut out, *hb, col);
        }
    }
    out
}

/// `y += a x`.
#[inline(always)]
fn axpy<const N: usize>(y: &mut [f32; N], a: f32, x: &[f32; N]) {
    for (yv, xv) in y.iter_mut().zip(x.iter()) {
        *yv += a * xv;
    }
}

/// Sets element `(i, j)` of a fixed 2-D array (no-op past its end).
#[inline]
fn put<const R: usize, const C: usize>(a: &mut [[f32; C]; R], i: usize, j: usize, v: f32) {
    if let Some(e) = a.get_mut(i).and_then(|r| r.get_mut(j)) {
        *e = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn event_count_matches_formula_for_full_gating() {
        // Σ_k C(D,k) C(m,k) k!: D = 3, m = 4 → 1 + 12 + 36 + 24 = 73.
        assert_eq!(count_events(&[0b1111u32; 3], 3, 1000), 73);
        assert_eq!(count_events(&[0b1111u32; 3], 3, 10), 11);
        assert_eq!(count_events(&[0b1111u32; 3], 3, 73), 73);
        // Shared single candidates: {}, {0→0}, {1→0}, {2→1}, {0→0, 2→1}, {1→0, 2→1}.
        assert_eq!(count_events(&[0b01u32, 0b01, 0b10], 3, 100), 6);
        assert_eq!(count_events(&[0u32; 3], 3, 100), 1);
        assert_eq!(count_events(&[0b111u32; 3], 0, 100), 1);
        assert_eq!(count_events(&[0b111u32; 3], 1, 100), 4);
    }
    /// Brute-force f64 oracle of a row step: every joint event, its weight from the joint
    /// Gaussian, and the moment-matched mixture (DESIGN 4.1), for `NS = 2` tracks.
    #[allow(clippy::type_complexity, clippy::needless_range_loop)]
    fn oracle(
        s: &Stacked<2, 3>,
        h: [f64; 2],
        z: &[f64],
        p: &RowParams,
    ) -> (Vec<f64>, Vec<Vec<f64>>, Vec<f64>, Vec<Vec<f64>>) {
        let n = s.len();
        let d = 2 * n;
        let x: Vec<f64> = (0..d)
            .map(|a| f64::from(s.mean(a / 2).unwrap()[a % 2]))
            .collect();
        let pm: Vec<Vec<f64>> = (0..d)
            .map(|a| {
                (0..d)
                    .map(|b| f64::from(s.cov(a / 2, b / 2).unwrap()[(a % 2, b % 2)]))
                    .collect()
            })
            .collect();
        // G[a][t] = (P Hᵀ)[a][t], S = H P Hᵀ + r I.
        let g: Vec<Vec<f64>> = (0..d)
            .map(|a| {
                (0..n)
                    .map(|t| h[0] * pm[a][2 * t] + h[1] * pm[a][2 * t + 1])
                    .collect()
            })
            .collect();
        let sb: Vec<Vec<f64>> = (0..n)
            .map(|i| {
                (0..n)
                    .map(|t| {
                        h[0] * g[2 * i][t]
                            + h[1] * g[2 * i + 1][t]
                            + if i == t { f64::from(p.r) } else { 0.0 }
                    })
                    .collect()
            })
            .collect();
        let zh: Vec<f64> = (0..n)
            .map(|t| h[0] * x[2 * t] + h[1] * x[2 * t + 1])
            .collect();
        let valid: Vec<Vec<usize>> = (0..n)
            .map(|t| {
                (0..z.len())
                    .filter(|&j| (z[j] - zh[t]).powi(2) / sb[t][t] <= f64::from(p.gamma))
                    .collect()
            })
            .collect();
        let miss = 1.0 - f64::from(p.pd) * f64::from(p.pg);
        // Enumerate events: a[t] = Some(j) or None, injective.
        let mut events: Vec<Vec<Option<usize>>> = vec![vec![]];
        for t in 0..n {
            let mut next = Vec::new();
            for e in &events {
                next.push({
                    let mut v = e.clone();
                    v.push(None);
                    v
                });
                for &j in &valid[t] {
                    if !e.contains(&Some(j)) {
                        let mut v = e.clone();
                        v.push(Some(j));
                        next.push(v);
                    }
                }
            }
            events = next;
        }
        let mut lws = Vec::new();
        let mut posts = Vec::new();
        for e in &events {
            let idx: Vec<usize> = (0..n).filter(|&t| e[t].is_some()).collect();
            let k = idx.len();
            // Inverse of S_δ by Gauss-Jordan.
            let mut m: Vec<Vec<f64>> = idx
                .iter()
                .map(|&a| {
                    let mut row: Vec<f64> = idx.iter().map(|&b| sb[a][b]).collect();
                    row.extend((0..k).map(|c| {
                        if c == idx.iter().position(|&q| q == a).unwrap() {
                            1.0
                        } else {
                            0.0
                        }
                    }));
                    row
                })
                .collect();
            let mut det = 1.0;
            for c in 0..k {
                let piv = m[c][c];
                det *= piv;
                for v in m[c].iter_mut() {
                    *v /= piv;
                }
                for r in 0..k {
                    if r != c {
                        let f = m[r][c];
                        for q in 0..2 * k {
                            m[r][q] -= f * m[c][q];
                        }
                    }
                }
            }
            let sinv: Vec<Vec<f64>> = m.iter().map(|r| r[k..].to_vec()).collect();
            let nu: Vec<f64> = idx.iter().map(|&t| z[e[t].unwrap()] - zh[t]).collect();
            let sn: Vec<f64> = (0..k)
                .map(|a| (0..k).map(|b| sinv[a][b] * nu[b]).sum())
                .collect();
            let q: f64 = (0..k).map(|a| nu[a] * sn[a]).sum();
            let lw = -0.5 * q - 0.5 * det.ln() - 0.5 * k as f64 * (2.0 * std::f64::consts::PI).ln()
                + k as f64 * (f64::from(p.pd) / f64::from(p.clutter_density)).ln()
                + (n - k) as f64 * miss.ln();
            // x_A = x + G_δ S⁻¹ ν, P_δ = P − G_δ S⁻¹ G_δᵀ.
            let xa: Vec<f64> = (0..d)
                .map(|a| x[a] + (0..k).map(|c| g[a][idx[c]] * sn[c]).sum::<f64>())
                .collect();
            let pa: Vec<Vec<f64>> = (0..d)
                .map(|a| {
                    (0..d)
                        .map(|b| {
                            pm[a][b]
                                - (0..k)
                                    .map(|c| {
                                        (0..k)
                                            .map(|c2| g[a][idx[c]] * sinv[c][c2] * g[b][idx[c2]])
                                            .sum::<f64>()
                                    })
                                    .sum::<f64>()
                        })
                        .collect()
                })
                .collect();
            lws.push(lw);
            posts.push((xa, pa));
        }
        let mx = lws.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let w: Vec<f64> = lws.iter().map(|l| (l - mx).exp()).collect();
        let tot: f64 = w.iter().sum();
        let mut bmiss = vec![0.0; n];
        let mut beta = vec![vec![0.0; z.len()]; n];
        let mut xm = vec![0.0; d];
        for (e, (wi, (xa, _))) in events.iter().zip(w.iter().zip(posts.iter())) {
            for t in 0..n {
                match e[t] {
                    Some(j) => beta[t][j] += wi / tot,
                    None => bmiss[t] += wi / tot,
                }
            }
            for a in 0..d {
                xm[a] += wi / tot * xa[a];
            }
        }
        let mut pmx = vec![vec![0.0; d]; d];
        for (wi, (xa, pa)) in w.iter().zip(posts.iter()) {
            for a in 0..d {
                for b in 0..d {
                    pmx[a][b] += wi / tot * (pa[a][b] + (xa[a] - xm[a]) * (xa[b] - xm[b]));
                }
            }
        }
        (bmiss, beta, xm, pmx)
    }

    /// Three coupled tracks with shared candidates, under ordinary and extreme parameters (the
    /// extreme ones push the weights far from the first pass's reference, so the pass is redone):
    /// β, the mean and the covariance match the f64 oracle.
    #[test]
    #[allow(clippy::needless_range_loop)]
    fn row_step_matches_brute_force_oracle() {
        let mut s: Stacked<2, 3> = Stacked::new();
        let p0 = SMatrix::<f32, 2, 2>::new(1.0, 0.2, 0.2, 0.5);
        for (i, x0) in [-1.0f32, 0.2, 1.5].iter().enumerate() {
            s.push(SVector::from([*x0, 0.1 * i as f32]), &p0).unwrap();
        }
        let c01 = SMatrix::<f32, 2, 2>::new(0.6, 0.1, 0.1, 0.2);
        s.set_cross(0, 1, &c01);
        s.set_cross(1, 2, &c01);
        s.set_cross(0, 2, &(c01 * 0.5));
        let h = SVector::from([1.0f32, 1.0]);
        let pts = [-0.9f32, 0.0, 0.5, 1.4, 2.6];
        for (density, pd) in [(0.05f32, 0.9f32), (1e-30, 0.9), (1e-12, 0.999), (50.0, 0.5)] {
            let params = RowParams {
                clutter_density: density,
                pd,
                ..RowParams::default()
            };
            let mut st = s;
            let out = update(&mut st, &h, &pts, &params, 100_000);
            assert!(!out.failed && !out.approximated, "{density}");
            let z: Vec<f64> = pts.iter().map(|v| f64::from(*v)).collect();
            let (bmiss, beta, xm, pm) = oracle(&s, [1.0, 1.0], &z, &params);
            for t in 0..3 {
                assert!(
                    (f64::from(out.beta_miss[t]) - bmiss[t]).abs() < 2e-5,
                    "{density}: miss {t}"
                );
                for j in 0..pts.len() {
                    assert!(
                        (f64::from(out.beta[t][j]) - beta[t][j]).abs() < 2e-5,
                        "{density}: β {t} {j}"
                    );
                }
            }
            for a in 0..6 {
                let xv = f64::from(st.mean(a / 2).unwrap()[a % 2]);
                assert!(
                    (xv - xm[a]).abs() < 1e-4,
                    "{density}: x {a}: {xv} vs {}",
                    xm[a]
                );
                for b in 0..6 {
                    let pv = f64::from(st.cov(a / 2, b / 2).unwrap()[(a % 2, b % 2)]);
                    assert!(
                        (pv - pm[a][b]).abs() < 1e-4,
                        "{density}: P {a} {b}: {pv} vs {}",
                        pm[a][b]
                    );
                }
            }
        }
    }
}
