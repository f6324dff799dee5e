//! Loopy belief propagation (LBP) marginals of a row's association (docs/design.md §11.3): the
//! approximation of the joint-event weights that costs `O(iterations · n · m)` instead of
//! enumerating the events (Williams & Lau, "Approximate evaluation of marginal association
//! probabilities with belief propagation", IEEE TAES 2014; Stone Soup's `JPDAwithLBP`).
//!
//! The graph is the bipartite one of tracks and points with the *uncoupled* likelihood: a
//! track's detection of point `j` weighs `ψ_tj = P_D N(z_j; ẑ_t, S̄_tt) / (λ_c · miss)` against
//! its miss (1), each point goes to at most one track. The cross-covariances between tracks
//! (coupled `B`) do not enter the weights: that is the approximation's modelling cost beyond
//! LBP's own error, both measured in docs/measurements.md ("Cheaper joint events").
//!
//! Messages (track → point `μ`, point → track `ν`, `ν = 1` at the start), one iteration:
//! `μ_tj = ψ_tj / (1 + Σ_{j' ≠ j} ψ_tj' ν_tj')`, `ν_tj = 1 / (1 + Σ_{t' ≠ t} μ_t'j)`; then
//! `β_tj = ψ_tj ν_tj / (1 + Σ_j' ψ_tj' ν_tj')` and `β_t,miss = 1 / (1 + Σ_j' ψ_tj' ν_tj')`.
//! The iteration stops when no `ν` moves by more than [`TOLERANCE`] or after
//! [`MAX_ITERATIONS`]; on a graph without cycles (no point gated by two tracks) the first
//! iteration is exact.

use super::*;

/// Largest number of message iterations of one row.
pub const MAX_ITERATIONS: u32 = 30;

/// The iteration stops once no point → track message moves by more than this.
pub const TOLERANCE: f32 = 1e-4;

/// `|ln ψ|` is clamped to this (natural-log units): a candidate `e^60` times more likely than
/// the miss is certain to f32 precision, and the sums of at most 32 such weights stay finite.
const LN_PSI_MAX: f32 = 60.0;

/// LBP marginals of the first `n` tracks into `out.beta` / `out.beta_miss` (the gates already
/// in `out.valid`; tracks of `skip` and tracks without candidates are missed). Returns the
/// iterations run, or `None` on a numerical failure (a non-finite weight or message).
///
/// `out.beta` must be zero on entry (as [`associate_into`](super::associate_into) leaves it):
/// the weights `ψ` are built in it and turned into the marginals in place. The messages are
/// kept only for a row with cycles; without them every `ν` is 1, and `ψ·1 = ψ` exactly, so the
/// marginals are the same bits either way.
///
/// # Complexity
/// `O(n · m)` exponentials and one `ln` per track with a gated point once, then at most
/// [`MAX_ITERATIONS`] × `2 n m` multiply-adds and `2 n m` divisions; `2 · LANES · 32` f32 of
/// stack for the messages.
// Not inlined: its frame replaces the event pass's, it does not add to it.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
pub(super) fn marginals<const LANES: usize>(
    out: &mut RowOutcome<LANES>,
    zhat: &[f32; LANES],
    sdiag: &[f32; LANES],
    points: &[f32],
    n: usize,
    (lg, odds): (&Logs, &[f32; LANES]),
    skip: u32,
) -> Option<u32> {
    let m = points.len().min(MAX_ROW_POINTS);
    // ψ_tj (0 outside the gate), in β.
    for (t, row) in out.beta.iter_mut().enumerate().take(n) {
        if skip & (1 << t) != 0 {
            continue;
        }
        let st = get(sdiag, t);
        let zt = get(zhat, t);
        let mask = get(&out.valid, t);
        if mask == 0 {
            // No gated point: its row of ψ stays 0, and no `ln`.
            continue;
        }
        let ln_norm =
            lg.ln_pd_lambda + get(odds, t) - lg.ln_miss - 0.5 * (lg.ln_2pi + math::ln(st));
        for (j, (p, z)) in row.iter_mut().zip(points.iter()).enumerate() {
            if mask & (1 << j) != 0 {
                let e = z - zt;
                let l = ln_norm - 0.5 * (e * e / st);
                if !l.is_finite() {
                    return None;
                }
                *p = math::exp_call(l.clamp(-LN_PSI_MAX, LN_PSI_MAX));
            }
        }
    }
    // Only points gated by two or more tracks make cycles; without them one pass is exact.
    let mut shared = 0u32;
    let mut seen = 0u32;
    for v in out.valid.iter().take(n) {
        shared |= seen & v;
        seen |= v;
    }
    if shared == 0 {
        // ν = 1: β_tj = ψ_tj / (1 + Σ_j' ψ_tj').
        for (t, (bm, brow)) in out
            .beta_miss
            .iter_mut()
            .zip(out.beta.iter_mut())
            .enumerate()
            .take(n)
        {
            if skip & (1 << t) != 0 {
                *bm = 1.0;
                continue;
            }
            *bm = alone(brow, m)?;
        }
        return Some(0);
    }
    let mut nu = [[1.0f32; MAX_ROW_POINTS]; LANES];
    let iterations = iterate(&out.beta, &mut nu, n, m)?;
    for (t, ((bm, brow), nrow)) in out
        .beta_miss
        .iter_mut()
        .zip(out.beta.iter_mut())
        .zip(nu.iter())
        .enumerate()
        .take(n)
    {
        if skip & (1 << t) != 0 {
            *bm = 1.0;
            continue;
        }
        let s = track_total(brow, nrow, m);
        if !(s.is_finite() && s >= 1.0) {
            return None;
        }
        let inv = 1.0 / s;
        *bm = inv;
        for (b, v) in brow.iter_mut().zip(nrow.iter()).take(m) {
            *b = *b * v * inv;
        }
    }
    Some(iterations)
}

/// The messages `ν` (1 on entry) of a row with cycles, from the weights `ψ` of its first `n`
/// tracks over `m` points; returns the iterations run, `None` when a message is not finite.
// Not inlined: its messages' frame is only taken by rows with cycles.
#[inline(never)]
fn iterate<const LANES: usize>(
    psi: &[[f32; MAX_ROW_POINTS]; LANES],
    nu: &mut [[f32; MAX_ROW_POINTS]; LANES],
    n: usize,
    m: usize,
) -> Option<u32> {
    let mut mu = [[0.0f32; MAX_ROW_POINTS]; LANES];
    let mut iterations = 0u32;
    while iterations < MAX_ITERATIONS {
        iterations += 1;
        // Track → point.
        for ((mrow, prow), nrow) in mu.iter_mut().zip(psi.iter()).zip(nu.iter()).take(n) {
            let s = track_total(prow, nrow, m);
            for ((mu_tj, p), v) in mrow.iter_mut().zip(prow.iter()).zip(nrow.iter()).take(m) {
                *mu_tj = if *p > 0.0 { p / (s - p * v) } else { 0.0 };
            }
        }
        // Point → track.
        let mut moved = 0.0f32;
        for j in 0..m {
            let col: f32 = 1.0 + mu.iter().take(n).map(|r| get(r, j)).sum::<f32>();
            for (nrow, mrow) in nu.iter_mut().zip(mu.iter()).take(n) {
                let new = 1.0 / (col - get(mrow, j));
                let old = get(nrow, j);
                moved = math::max(moved, (new - old).abs());
                set(nrow, j, new);
            }
        }
        if !moved.is_finite() {
            return None;
        }
        if moved <= TOLERANCE {
            break;
        }
    }
    Some(iterations)
}

/// A track's marginals when no other track gates its points (`ν = 1`): `ψ_tj` in `brow`
/// becomes `β_tj = ψ_tj / (1 + Σ_j' ψ_tj')`; returns `β_t,miss`, `None` when the sum is not
/// finite.
// Not inlined: one copy of the loops, not one per track (flash).
#[inline(never)]
fn alone(brow: &mut [f32; MAX_ROW_POINTS], m: usize) -> Option<f32> {
    let s = 1.0 + brow.iter().take(m).sum::<f32>();
    if !(s.is_finite() && s >= 1.0) {
        return None;
    }
    let inv = 1.0 / s;
    for b in brow.iter_mut().take(m) {
        *b *= inv;
    }
    Some(inv)
}

/// `1 + Σ_j ψ_tj ν_tj` over a track's first `m` points: its miss plus its messages-weighted
/// candidates (the normaliser of both message directions' track side and of its marginals).
#[inline(always)]
fn track_total(psi: &[f32; MAX_ROW_POINTS], nu: &[f32; MAX_ROW_POINTS], m: usize) -> f32 {
    1.0 + psi
        .iter()
        .zip(nu.iter())
        .take(m)
        .map(|(p, v)| p * v)
        .sum::<f32>()
}
