//! One row step of the coupled JPDACF (DESIGN 4.1 steps 2–5): gating, bounded joint-event
//! enumeration, joint-Gaussian event weights in the log domain, and the exact moment-matched update
//! of the event mixture.
//!
//! # The update, as computed
//! With `G = P̄ H̄ᵀ` (the covariance of every track's state with every track's predicted
//! measurement), a pattern `δ` (set of detected tracks) has gain `K_δ = G_δ S_δ⁻¹`. Summing the event
//! mixture `x̄_A = x̄ + K_δ ν_A`, `P_δ = P̄ − K_δ S_δ K_δᵀ` in closed form gives
//!
//! `x̄⁺ = x̄ + G y`, `P̄⁺ = P̄ − G C Gᵀ − (G y)(G y)ᵀ`, with
//! `y = Σ_δ E_δ S_δ⁻¹ m_δ`, `C = Σ_δ E_δ (W_δ S_δ⁻¹ − S_δ⁻¹ M_δ S_δ⁻¹) E_δᵀ`,
//!
//! where `W_δ = Σ_{A∈δ} β_A`, `m_δ = Σ β_A ν_A`, `M_δ = Σ β_A ν_A ν_Aᵀ`, and `E_δ` embeds the
//! pattern's `k` tracks among all `D`. So the state-sized work (`O(D² NS² · D)`) happens once per
//! row; per pattern there is one `D×D` Cholesky factorisation, per event one triangular solve.
//! This is algebraically identical to DESIGN's `Σ_A β_A (P_δ + x̄_A x̄_Aᵀ) − x̄⁺ x̄⁺ᵀ`.
//!
//! # Bounds and cost
//! * at most [`MAX_ROW_POINTS`] points per row (the rest are counted in `ignored_points`);
//! * at most `max_events` joint events are scored. The events are counted first (at most
//!   `max_events + 1` leaves visited); when there are more, (track, point) candidates are dropped
//!   in order of increasing single-track PDA probability (each track's candidates and its miss
//!   normalised among themselves, so no track loses its plausible points first), until
//!   `Π_t (1 + n_t) ≤ max_events` (a bound on the event count), and the row is flagged
//!   `approximated` (DESIGN 4.1 step 5: "drop the least likely candidates until it fits"). The
//!   coupled likelihood does not factor over clusters, so all tracks stay in one enumeration;
//!   the sort costs O(C log C) for C ≤ D·m candidates;
//! * at most `2^D` detection patterns, each factorised once (`D³/3` flops, padded to `D×D`);
//! * worst case per row: `2^D · (D³ + D²)` + `max_events · (D² + D)` + `D² · NS² · D` multiply-adds
//!   and no recursion (the enumeration is an explicit-stack backtracking of depth ≤ D).
//!
//! A numerical failure (a non-positive-definite `S_δ`, all event weights zero, a non-finite
//! result) leaves the state untouched and sets `failed`.

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
    /// Detection patterns factorised.
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

/// Explicit-stack enumeration of the injective assignments of `k` tracks (in order) to points,
/// each track choosing among the bits of its mask. Depth ≤ `L`; no recursion.
struct Assignments<const L: usize> {
    masks: [u32; L],
    k: usize,
    rem: [u32; L],
    pick: [u8; L],
    used: u32,
    depth: usize,
    started: bool,
    done: bool,
}

impl<const L: usize> Assignments<L> {
    fn new(masks: [u32; L], k: usize) -> Self {
        Self {
            masks,
            k: k.min(L),
            rem: [0; L],
            pick: [0; L],
            used: 0,
            depth: 0,
            started: false,
            done: false,
        }
    }

    fn release(&mut self, d: usize) {
        self.used &= !(1u32.wrapping_shl(u32::from(get(&self.pick, d))));
    }

    /// The next assignment: `pick[a]` is the point of the `a`-th track.
    fn next(&mut self) -> Option<[u8; L]> {
        if self.done {
            return None;
        }
        if self.k == 0 {
            self.done = true;
            return Some(self.pick);
        }
        if self.started {
            self.depth = self.k - 1;
            self.release(self.depth);
        } else {
            self.started = true;
            self.depth = 0;
            set(&mut self.rem, 0, get(&self.masks, 0));
        }
        // Each pass either descends (≤ k), advances a candidate, or ascends: bounded by the tree.
        loop {
            let r = get(&self.rem, self.depth);
            if r == 0 {
                if self.depth == 0 {
                    self.done = true;
                    return None;
                }
                self.depth -= 1;
                self.release(self.depth);
                continue;
            }
            let j = r.trailing_zeros();
            set(&mut self.rem, self.depth, r & r.wrapping_sub(1));
            set(&mut self.pick, self.depth, j as u8);
            self.used |= 1u32.wrapping_shl(j);
            if self.depth + 1 >= self.k {
                return Some(self.pick);
            }
            self.depth += 1;
            set(
                &mut self.rem,
                self.depth,
                get(&self.masks, self.depth) & !self.used,
            );
        }
    }
}

/// Tracks of pattern `pattern` (bit `t` = track `t` detected), in order, and their masks.
fn pattern_tracks<const L: usize>(
    pattern: u32,
    valid: &[u32; L],
    n: usize,
) -> ([u8; L], [u32; L], usize) {
    let mut idx = [0u8; L];
    let mut masks = [0u32; L];
    let mut k = 0;
    for t in 0..n {
        if pattern & (1 << t) != 0 {
            set(&mut idx, k, t as u8);
            set(&mut masks, k, get(valid, t));
            k += 1;
        }
    }
    (idx, masks, k)
}

/// Counts joint events up to `limit + 1` (stops early).
fn count_events<const L: usize>(valid: &[u32; L], n: usize, limit: u64) -> u64 {
    let mut total = 0u64;
    for pattern in 0..(1u32 << n) {
        let (_, masks, k) = pattern_tracks(pattern, valid, n);
        if masks.iter().take(k).any(|m| *m == 0) {
            continue;
        }
        let mut it = Assignments::<L>::new(masks, k);
        while it.next().is_some() {
            total += 1;
            if total > limit {
                return total;
            }
        }
    }
    total
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
    let m = points.len().min(MAX_ROW_POINTS);
    out.ignored_points = (points.len() - m) as u32;
    if n == 0 {
        out.ignored_points += points.iter().take(m).filter(|z| !z.is_finite()).count() as u32;
        out.clutter_points = points.iter().take(m).filter(|z| z.is_finite()).count() as u32;
        return out;
    }
    let n_skipped = (0..n).filter(|t| skip & (1 << t) != 0).count();

    // Gating on each track's marginal (step 2), and G = P̄ H̄ᵀ, S̄ = H̄ P̄ H̄ᵀ + r I.
    let mut zhat = [0.0f32; LANES];
    let mut g = [[SVector::<f32, NS>::zeros(); LANES]; LANES]; // g[i][t] = P_it h
    let mut sbar = SMatrix::<f32, LANES, LANES>::zeros();
    for (i, grow) in g.iter_mut().enumerate().take(n) {
        set(&mut zhat, i, xs.get(i).map_or(0.0, |x| h.dot(x)));
        for (t, gi) in grow.iter_mut().enumerate().take(n) {
            if let Some(p) = ps.get(i).and_then(|r| r.get(t)) {
                *gi = p * h;
            }
        }
    }
    for i in 0..n {
        for t in 0..n {
            let v = g.get(i).and_then(|r| r.get(t)).map_or(0.0, |gi| h.dot(gi))
                + if i == t { params.r } else { 0.0 };
            if let Some(s) = sbar.get_mut((i, t)) {
                *s = v;
            }
        }
    }
    let sbar = (sbar + sbar.transpose()) * 0.5;
    let mut d2 = [[f32::INFINITY; MAX_ROW_POINTS]; LANES];
    let mut any_valid = 0u32;
    for t in 0..n {
        let st = sbar.get((t, t)).copied().unwrap_or(0.0);
        if !(st.is_finite() && st > 0.0) {
            out.failed = true;
            return out;
        }
        let zt = get(&zhat, t);
        let mut mask = 0u32;
        for (j, z) in points.iter().take(m).enumerate() {
            if !z.is_finite() {
                continue;
            }
            let e = z - zt;
            let dj = e * e / st;
            if let Some(v) = d2.get_mut(t).and_then(|r| r.get_mut(j)) {
                *v = dj;
            }
            if dj <= params.gamma && skip & (1 << t) == 0 {
                mask |= 1 << j;
            }
        }
        set(&mut out.valid, t, mask);
        any_valid |= mask;
    }
    for (j, z) in points.iter().take(m).enumerate() {
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
    let budget = max_events.max(1) as u64;
    if count_events(&out.valid, n, budget) > budget {
        out.approximated = true;
        let mut cand = [(0.0f32, 0u8, 0u8); CANDIDATES];
        let mut nc = 0usize;
        for t in 0..n {
            let st = sbar.get((t, t)).copied().unwrap_or(1.0);
            let ln_norm = ln_pd - ln_lambda - 0.5 * (ln_2pi + math::ln(st));
            let mask = get(&out.valid, t);
            let first = nc;
            let mut lmax = ln_miss;
            for j in 0..m {
                if mask & (1 << j) != 0 {
                    let dj = d2
                        .get(t)
                        .and_then(|r| r.get(j))
                        .copied()
                        .unwrap_or(f32::INFINITY);
                    let l = ln_norm - 0.5 * dj;
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
            c.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
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

    // Event weights (step 3) and the mixture moments (step 4), streamed with a running maximum.
    let mut run_max = f32::NEG_INFINITY;
    let mut wtot = 0.0f32;
    let mut y = SVector::<f32, LANES>::zeros();
    let mut c = SMatrix::<f32, LANES, LANES>::zeros();
    let mut bmiss = [0.0f32; LANES];
    let mut beta = [[0.0f32; MAX_ROW_POINTS]; LANES];
    for pattern in 0..(1u32 << n) {
        if pattern & skip != 0 {
            continue;
        }
        let (idx, masks, k) = pattern_tracks(pattern, &out.valid, n);
        if masks.iter().take(k).any(|v| *v == 0) {
            continue;
        }
        let s = SMatrix::<f32, LANES, LANES>::from_fn(|a, b| {
            if a < k && b < k {
                sbar.get((usize::from(get(&idx, a)), usize::from(get(&idx, b))))
                    .copied()
                    .unwrap_or(0.0)
            } else if a == b {
                1.0
            } else {
                0.0
            }
        });
        let Some(chol) = s.cholesky() else {
            out.failed = true;
            return out;
        };
        out.patterns += 1;
        let logdet: f32 = chol
            .l_dirty()
            .diagonal()
            .iter()
            .take(k)
            .map(|v| 2.0 * math::ln(*v))
            .sum();
        let kf = k as f32;
        let base = -0.5 * logdet - 0.5 * kf * ln_2pi
            + kf * (ln_pd - ln_lambda)
            + (n - n_skipped - k) as f32 * ln_miss;
        let mut wd = 0.0f32;
        let mut m1 = SVector::<f32, LANES>::zeros();
        let mut m2 = SMatrix::<f32, LANES, LANES>::zeros();
        let mut it = Assignments::<LANES>::new(masks, k);
        while let Some(pick) = it.next() {
            out.events += 1;
            let nu = SVector::<f32, LANES>::from_fn(|a, _| {
                if a < k {
                    let j = usize::from(get(&pick, a));
                    points.get(j).copied().unwrap_or(0.0) - get(&zhat, usize::from(get(&idx, a)))
                } else {
                    0.0
                }
            });
            let maha = nu.dot(&chol.solve(&nu));
            let lw = base - 0.5 * maha;
            if !lw.is_finite() {
                continue; // weight 0 (e.g. ln 0 of a zero miss factor): contributes nothing
            }
            if lw > run_max {
                let sc = math::exp(run_max - lw);
                wtot *= sc;
                wd *= sc;
                y *= sc;
                c *= sc;
                m1 *= sc;
                m2 *= sc;
                for v in bmiss.iter_mut() {
                    *v *= sc;
                }
                for r in beta.iter_mut() {
                    for v in r.iter_mut() {
                        *v *= sc;
                    }
                }
                run_max = lw;
            }
            let w = math::exp(lw - run_max);
            wd += w;
            m1 += nu * w;
            m2 += nu * nu.transpose() * w;
            for a in 0..k {
                let t = usize::from(get(&idx, a));
                let j = usize::from(get(&pick, a));
                if let Some(b) = beta.get_mut(t).and_then(|r| r.get_mut(j)) {
                    *b += w;
                }
            }
        }
        if wd == 0.0 {
            continue;
        }
        wtot += wd;
        for t in 0..n {
            if pattern & (1 << t) == 0 && skip & (1 << t) == 0 {
                if let Some(b) = bmiss.get_mut(t) {
                    *b += wd;
                }
            }
        }
        let sinv = chol.inverse();
        let yd = sinv * m1;
        let cd = sinv * wd - sinv * m2 * sinv;
        for a in 0..k {
            let ta = usize::from(get(&idx, a));
            if let (Some(dst), Some(src)) = (y.get_mut(ta), yd.get(a)) {
                *dst += *src;
            }
            for b in 0..k {
                let tb = usize::from(get(&idx, b));
                if let (Some(dst), Some(src)) = (c.get_mut((ta, tb)), cd.get((a, b))) {
                    *dst += *src;
                }
            }
        }
    }
    probe.enter(Stage::Update);
    if !(wtot.is_finite() && wtot > 0.0) {
        out.failed = true;
        return out;
    }
    let y = y / wtot;
    let c = c / wtot;

    // x⁺ = x̄ + G y;  P⁺ = P̄ − G C Gᵀ − (G y)(G y)ᵀ, computed into copies and committed if finite.
    let mut dx = [SVector::<f32, NS>::zeros(); LANES];
    let mut u = [[SVector::<f32, NS>::zeros(); LANES]; LANES]; // u[i][t'] = Σ_t g[i][t] C[t][t']
    for i in 0..n {
        let gi = g.get(i).copied().unwrap_or([SVector::zeros(); LANES]);
        let mut d = SVector::<f32, NS>::zeros();
        for (t, git) in gi.iter().enumerate().take(n) {
            d += git * y.get(t).copied().unwrap_or(0.0);
        }
        set(&mut dx, i, d);
        for tp in 0..n {
            let mut acc = SVector::<f32, NS>::zeros();
            for (t, git) in gi.iter().enumerate().take(n) {
                acc += git * c.get((t, tp)).copied().unwrap_or(0.0);
            }
            if let Some(v) = u.get_mut(i).and_then(|r| r.get_mut(tp)) {
                *v = acc;
            }
        }
    }
    let mut newp = *ps;
    for i in 0..n {
        for j in i..n {
            let mut red = SMatrix::<f32, NS, NS>::zeros();
            for tp in 0..n {
                let uit = u
                    .get(i)
                    .and_then(|r| r.get(tp))
                    .copied()
                    .unwrap_or_else(SVector::zeros);
                let gjt = g
                    .get(j)
                    .and_then(|r| r.get(tp))
                    .copied()
                    .unwrap_or_else(SVector::zeros);
                red += uit * gjt.transpose();
            }
            let di = dx.get(i).copied().unwrap_or_else(SVector::zeros);
            let dj = dx.get(j).copied().unwrap_or_else(SVector::zeros);
            red += di * dj.transpose();
            let pij = ps
                .get(i)
                .and_then(|r| r.get(j))
                .copied()
                .unwrap_or_else(SMatrix::zeros);
            let pji = ps
                .get(j)
                .and_then(|r| r.get(i))
                .copied()
                .unwrap_or_else(SMatrix::zeros);
            // Symmetrise: the (i, j) block and the transpose of the (j, i) block.
            let blk = (pij + pji.transpose()) * 0.5
                - (red + red.transpose_if(i == j)) * if i == j { 0.5 } else { 1.0 };
            if let Some(b) = newp.get_mut(i).and_then(|r| r.get_mut(j)) {
                *b = blk;
            }
            if let Some(b) = newp.get_mut(j).and_then(|r| r.get_mut(i)) {
                *b = blk.transpose();
            }
        }
    }
    let finite = newp
        .iter()
        .take(n)
        .all(|r| r.iter().take(n).all(|b| b.iter().all(|v| v.is_finite())))
        && dx.iter().take(n).all(|d| d.iter().all(|v| v.is_finite()));
    if !finite {
        out.failed = true;
        return out;
    }
    *ps = newp;
    for (x, d) in xs.iter_mut().zip(dx.iter()).take(n) {
        *x += d;
    }
    for t in 0..n {
        let miss = if skip & (1 << t) != 0 {
            1.0
        } else {
            get(&bmiss, t) / wtot
        };
        set(&mut out.beta_miss, t, miss);
        if let (Some(dst), Some(src)) = (out.beta.get_mut(t), beta.get(t)) {
            for (d, s) in dst.iter_mut().zip(src.iter()) {
                *d = s / wtot;
            }
        }
    }
    out
}

trait TransposeIf {
    fn transpose_if(&self, cond: bool) -> Self;
}

impl<const N: usize> TransposeIf for SMatrix<f32, N, N> {
    fn transpose_if(&self, cond: bool) -> Self {
        if cond {
            self.transpose()
        } else {
            SMatrix::zeros()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assignments_enumerate_injective_maps() {
        // Two tracks, both valid for points 0 and 1: (0,1) and (1,0).
        let mut it = Assignments::<3>::new([0b11, 0b11, 0], 2);
        let mut got = heapless::Vec::<[u8; 2], 8>::new();
        while let Some(p) = it.next() {
            got.push([p[0], p[1]]).unwrap();
        }
        assert_eq!(got.as_slice(), &[[0, 1], [1, 0]]);
        let mut it = Assignments::<3>::new([0b1, 0b1, 0], 2);
        assert!(it.next().is_none());
        let mut it = Assignments::<3>::new([0; 3], 0);
        assert!(it.next().is_some() && it.next().is_none());
    }

    #[test]
    fn event_count_matches_formula_for_full_gating() {
        // Σ_k C(D,k) C(m,k) k!: D = 3, m = 4 → 1 + 12 + 36 + 24 = 73.
        assert_eq!(count_events(&[0b1111u32; 3], 3, 1000), 73);
        assert_eq!(count_events(&[0b1111u32; 3], 3, 10), 11);
    }
}
