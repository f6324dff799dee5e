//! One row step of the coupled JPDACF (docs/design.md §4.1 steps 2–5): gating, bounded joint-event
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
//! the design's (docs/design.md §4.1 step 4) `Σ_A β_A (P_δ + x̄_A x̄_Aᵀ) − x̄⁺ x̄⁺ᵀ`; the state-sized work happens once per row and
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
//!   max_events`, and the row is flagged `approximated` (docs/design.md §4.1 step 5: "drop the least
//!   likely candidates until it fits"); the sort (a stable insertion sort, no panic branch) costs
//!   O(C²) compares for C ≤ D·m candidates;
//! * **clusters** (docs/design.md §4.1 step 5): tracks that share a candidate or are correlated
//!   (`S̄_st ≠ 0`) are enumerated together, each cluster on its own, exactly (events and weights
//!   factor between clusters; the mixture's `C + y yᵀ` has no block between them). The coupled
//!   likelihood correlates every pair, so with coupled tables a row is one enumeration; with a
//!   diagonal B a row costs `Σ_c Π_{t∈c} (1 + n_t)` events instead of `Π_t (1 + n_t)`, and the
//!   budget counts that sum. `O(D²)` pair checks a row find the clusters;
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

use nalgebra::SVector;

use super::{Blocks, Means, Stacked};
use crate::linalg::{dot, get, set};
use crate::math;
use crate::probe::{NoProbe, Probe, Stage};

mod events;
mod lbp;
mod mixture;
use events::{count_events, Acc, Ctx, WINDOW};
use mixture::{apply_mixture, at, eligible_gains, mat_vec, put};

/// Largest number of points one row can hold (the gate masks are `u32`).
pub const MAX_ROW_POINTS: usize = 32;

/// How a missed track is weighted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MissModel {
    /// `1 − P_D` (textbook JPDA).
    Textbook,
    /// `1 − P_D P_G`: a detection outside the gate is also a miss (docs/design.md §4.1; the default).
    Gated,
}

/// How [`associate`] weighs a row's joint events (the known-lane stage, docs/design.md §11.3;
/// the spatial row step always enumerates).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Association {
    /// Exact enumeration with the coupled likelihood; a row whose events exceed the budget
    /// loses its least likely candidates until it fits (§4.1 step 5).
    Exact,
    /// Exact enumeration within the budget; a row over it gets the LBP marginals of the
    /// uncoupled likelihood instead of pruning (`lbp` module).
    ExactOrLbp,
    /// The LBP marginals of the uncoupled likelihood on every row: `O(iterations · n · m)`, no
    /// event enumeration and no cross-covariances.
    Lbp,
}

/// Most message iterations of an LBP row ([`Association`]).
pub const LBP_MAX_ITERATIONS: u32 = lbp::MAX_ITERATIONS;

/// An LBP row stops once no message moves by more than this.
pub const LBP_TOLERANCE: f32 = lbp::TOLERANCE;

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

impl RowParams {
    /// The miss factor of [`RowParams::miss`] for a lane of detection probability `pd`:
    /// `1 − pd` or `1 − pd · P_G` (docs/design.md §4.1 step 3).
    pub fn miss_at(&self, pd: f32) -> f32 {
        match self.miss {
            MissModel::Textbook => 1.0 - pd,
            MissModel::Gated => 1.0 - pd * self.pg,
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
    /// Message iterations when the weights are LBP marginals ([`Association`]; at least 1, the
    /// final pass: a row without shared points needs no other); 0 when the events were
    /// enumerated.
    pub lbp_iterations: u32,
    /// Points valid for no track.
    pub clutter_points: u32,
    /// Points beyond [`MAX_ROW_POINTS`] or with a non-finite coordinate (not used).
    pub ignored_points: u32,
    /// A numerical failure: the state was left untouched.
    pub failed: bool,
    /// `Σ_{j gated} N(z_j; ẑ_t, S̄_tt) (1 − Σ_{t' ≠ t} β_{t'j})` per track, written by the
    /// update ([`update_probed`]; 0 after [`associate`]): the one-step-ahead likelihood of the
    /// track's gated points before the update, each as far as no other track claims it (the
    /// IPDA likelihood ratio of the row is `1 − P_D P_G + P_D · dens / λ_c`, docs/design.md
    /// §11.8). The known-lane pass weighs its rows against the other lanes instead (§11.5).
    pub dens: [f32; LANES],
}

impl<const LANES: usize> Default for RowOutcome<LANES> {
    /// No weights, every track missed.
    fn default() -> Self {
        Self {
            beta_miss: [1.0; LANES],
            ..Self::ZEROED
        }
    }
}

impl<const LANES: usize> RowOutcome<LANES> {
    /// Every byte zero: not an outcome (`β_miss` is 0), but a valid start for the outcome a
    /// [`Scratch`] resets before each row (held in `.bss`); [`RowOutcome::default`] is this with
    /// every track missed.
    pub(crate) const ZEROED: Self = Self {
        beta_miss: [0.0; LANES],
        beta: [[0.0; MAX_ROW_POINTS]; LANES],
        valid: [0; LANES],
        events: 0,
        patterns: 0,
        dropped_candidates: 0,
        approximated: false,
        lbp_iterations: 0,
        clutter_points: 0,
        ignored_points: 0,
        failed: false,
        dens: [0.0; LANES],
    };

    /// Back to [`RowOutcome::default`], given that every nonzero `β` entry lies in the first
    /// `rows` rows and `cols` columns (what a row's association writes: its tracks and points).
    /// Keep in step with `default`.
    fn reset(&mut self, rows: usize, cols: usize) {
        self.beta_miss = [1.0; LANES];
        self.valid = [0; LANES];
        self.events = 0;
        self.patterns = 0;
        self.dropped_candidates = 0;
        self.approximated = false;
        self.lbp_iterations = 0;
        self.clutter_points = 0;
        self.ignored_points = 0;
        self.failed = false;
        self.dens = [0.0; LANES];
        crate::linalg::zero_block(&mut self.beta, rows, cols);
    }
}

/// What a caller keeps for all the rows of a pass, beside one [`RowOutcome`] that only
/// [`associate_into`] or [`update_into`] with this scratch writes: the event pass's arrays, the
/// row's event accumulators, and how far the last row wrote `β` into each (its tracks and
/// points), so that each row resets the outcome and the accumulators to their defaults by
/// clearing that much, not ~1 KiB apiece (memclr was 8 % of a typical frame on the
/// Cortex-M4F).
#[derive(Clone)]
pub(crate) struct Scratch<const L: usize> {
    events: events::Scratch<L>,
    acc: Acc<L>,
    part: Acc<L>,
    /// `(rows, columns)` of `β` written since the last reset: of the outcome and `acc`, and of
    /// `part` (used by rows with more than one cluster only).
    extent: (usize, usize),
    part_extent: (usize, usize),
    /// The last row's log terms and the parameters they were taken of (`P_D`, `P_G`, `λ_c`
    /// bits and whether the miss model is the gated one), when `logs_kept`: a pass's rows
    /// share their band's parameters, so most rows reuse them (four `ln` a row otherwise).
    /// Plain integers and a `bool`, so that a zeroed scratch is all zero bytes (`.bss`).
    logs: Logs,
    logs_of: (u32, u32, u32, bool),
    logs_kept: bool,
}

impl<const L: usize> Scratch<L> {
    /// Every byte zero, for an outcome whose `β` is zero ([`RowOutcome::default`] or
    /// [`RowOutcome::ZEROED`]): each row resets what it reads.
    pub(crate) const ZEROED: Self = Self {
        events: events::Scratch::new(),
        acc: Acc::ZEROED,
        part: Acc::ZEROED,
        extent: (0, 0),
        part_extent: (0, 0),
        logs: Logs {
            ln_pd_lambda: 0.0,
            ln_miss: 0.0,
            ln_2pi: 0.0,
        },
        logs_of: (0, 0, 0, false),
        logs_kept: false,
    };

    /// For a [`RowOutcome::default`].
    pub(crate) const fn new() -> Self {
        Self::ZEROED
    }

    /// [`Logs::of`] `params`, taken again only when they differ from the last row's (the same
    /// bits in, the same bits out).
    fn logs(&mut self, params: &RowParams) -> Logs {
        let key = (
            params.pd.to_bits(),
            params.pg.to_bits(),
            params.clutter_density.to_bits(),
            params.miss == MissModel::Gated,
        );
        if !self.logs_kept || self.logs_of != key {
            self.logs = Logs::of(params);
            self.logs_of = key;
            self.logs_kept = true;
        }
        self.logs
    }

    /// Resets `out` and the row accumulator for a row of `n` tracks and `m` points.
    fn begin_row(&mut self, out: &mut RowOutcome<L>, n: usize, m: usize) {
        let (rows, cols) = self.extent;
        out.reset(rows, cols);
        self.acc.reset(rows, cols);
        self.extent = (n, m);
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

/// [`update_masked`] reporting its stages ([`Stage::Gating`], [`Stage::Events`],
/// [`Stage::Update`]) to `probe`.
///
/// # Complexity
/// As [`update`].
pub fn update_probed<const NS: usize, const LANES: usize, P: Probe>(
    state: &mut Stacked<NS, LANES>,
    h: &SVector<f32, NS>,
    points: &[f32],
    params: &RowParams,
    max_events: usize,
    skip: u32,
    probe: &mut P,
) -> RowOutcome<LANES> {
    let mut out = RowOutcome::<LANES>::default();
    update_into(
        (&mut out, &mut Scratch::new()),
        state,
        h,
        points,
        params,
        (max_events, skip),
        probe,
    );
    out
}

/// [`update_probed`] into `out` (reset first), with the event pass's arrays `scratch`: the
/// frame walk keeps one of each for all its rows, so that no ~1 KiB outcome is copied and no
/// pattern arrays are cleared per row (a memcpy and a memclr on the Cortex-M4F).
#[allow(non_snake_case)]
pub(crate) fn update_into<const NS: usize, const LANES: usize, P: Probe>(
    (out, scratch): (&mut RowOutcome<LANES>, &mut Scratch<LANES>),
    state: &mut Stacked<NS, LANES>,
    h: &SVector<f32, NS>,
    points: &[f32],
    params: &RowParams,
    (max_events, skip): (usize, u32),
    probe: &mut P,
) {
    probe.enter(Stage::Gating);
    let (xs, ps, n) = state.parts_mut();
    let n = n.min(LANES);
    let m = points.len().min(MAX_ROW_POINTS);
    scratch.begin_row(out, n, m);
    out.ignored_points = (points.len() - m) as u32;
    let points = points.get(..m).unwrap_or(&[]);
    if n == 0 {
        out.ignored_points += points.iter().filter(|z| !z.is_finite()).count() as u32;
        out.clutter_points = points.iter().filter(|z| z.is_finite()).count() as u32;
        return;
    }
    let n_skipped = (0..n).filter(|t| skip & (1 << t) != 0).count();

    // Gating on each track's marginal (step 2): ẑ_t = h·x_t and S̄_tt = hᵀ P_tt h + r, on plain
    // arrays (`[f32; NS]` vectors, column-major blocks) so the small products unroll. The rest
    // of G = P̄ H̄ᵀ and S̄ = H̄ P̄ H̄ᵀ + r I is only needed for the eligible tracks (below).
    let [hv] = h.data.0;
    let mut zhat = [0.0f32; LANES];
    let mut sbar = [[0.0f32; LANES]; LANES];
    if !gate(
        xs, ps, n, hv, points, params, skip, out, &mut zhat, &mut sbar,
    ) {
        return;
    }

    probe.enter(Stage::Events);
    let lg = scratch.logs(params);
    // The budget counts the events of the row's clusters (tracks that share a candidate or are
    // correlated, `S̄_st ≠ 0`; see [`associate`]): a row over it as one enumeration is tried as
    // clusters when its clusters by shared candidates fit and the first two are uncorrelated.
    let cross = |s: usize, t: usize| {
        ps.get(s)
            .and_then(|r| r.get(t))
            .map_or(0.0, |pst| dot(&hv, &mat_vec(pst, &hv)))
    };
    if over_budget(&out.valid, n, max_events) {
        let fits = cluster_bound(&out.valid, n, skip, &|_, _| false, max_events)
            <= max_events as u64
            && first_clusters_uncorrelated(&out.valid, n, skip, &cross)
            && cluster_bound(&out.valid, n, skip, &|a, b| cross(a, b) != 0.0, max_events)
                <= max_events as u64;
        if !fits {
            out.approximated = true;
            prune(
                out,
                (&sbar, &zhat, points),
                n,
                max_events.max(1) as u64,
                (&lg, &[0.0; LANES]),
            );
        }
    }

    // Event weights (step 3) and the mixture moments (step 4), in one pass over the detection
    // patterns and their events (`Ctx::pass`), redone once if the weights' scale was off.
    let mut elig = [0u8; LANES];
    let mut g = [[[0.0f32; NS]; LANES]; LANES];
    let na = eligible_gains(&out.valid, skip, ps, n, hv, &mut sbar, &mut elig, &mut g);
    let el = elig.get(..na).unwrap_or(&[]);
    let (label, clusters) =
        if first_clusters_uncorrelated(&out.valid, n, skip, &|a, b| at(&sbar, a, b)) {
            clusters(&out.valid, (&elig, na), &|a, b| at(&sbar, a, b) != 0.0)
        } else {
            ([0; LANES], 1)
        };
    let Some(inv) = weigh_row(
        &lg,
        (&elig, na, &label, clusters),
        (&sbar, &zhat, &out.valid),
        points,
        (n, n_skipped, skip),
        true,
        &[0.0; LANES],
        scratch,
    ) else {
        failed(out);
        return;
    };
    let acc = &scratch.acc;
    out.events = acc.events;
    out.patterns = acc.patterns;
    probe.enter(Stage::Update);
    if !apply_mixture(xs, ps, n, el, &g, &acc.y, &acc.c, inv) {
        failed(out);
        return;
    }
    normalise(out, &acc.beta, &acc.bmiss, inv, n, m, skip);
    let sdiag: [f32; LANES] = core::array::from_fn(|t| at(&sbar, t, t));
    exclusive_density(out, (&zhat, &sdiag), points, n, lg.ln_2pi);
}

/// The event weights of a row's eligible tracks `elig[..na]` into `acc`, and the factor `inv`
/// that normalises them (`Σ w · inv = 1`); `None` on a numerical failure. With one cluster (or
/// none) the row is one enumeration: `acc` holds the raw sums, `inv = 1 / Σ w`. With
/// `clusters > 1` uncorrelated clusters (`label` by position in `elig`) each cluster is weighed
/// on its own and `acc` holds the sums already normalised (`inv = 1`): `β`, `β_miss` (1 for the
/// tracks in no cluster) and, with `moments`, `y` and `C`. Each cluster's are exact: its events
/// and their weights factor from the others'. Between clusters the mixture's second moment
/// `C + y yᵀ` has no block (`E[r_c r_dᵀ] = y_c y_dᵀ`, `S_δ⁻¹` block-diagonal), so `C_cd = −y_c y_dᵀ`
/// there, and the one state update of [`apply_mixture`] is the product of the clusters' updates.
#[inline(never)]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn weigh_row<const LANES: usize>(
    lg: &Logs,
    (elig, na, label, clusters): (&[u8; LANES], usize, &[u8; LANES], usize),
    (sbar, zhat, valid): (&[[f32; LANES]; LANES], &[f32; LANES], &[u32; LANES]),
    points: &[f32],
    (n, n_skipped, skip): (usize, usize, u32),
    moments: bool,
    odds: &[f32; LANES],
    scratch: &mut Scratch<LANES>,
) -> Option<f32> {
    let Scratch {
        events: arrays,
        acc,
        part,
        part_extent,
        ..
    } = scratch;
    if clusters <= 1 {
        let ctx = lg.ctx(
            (*elig, na),
            sbar,
            zhat,
            valid,
            points,
            (n, n_skipped, skip),
            moments,
            odds,
        );
        let ok = weigh(&ctx, acc, arrays) && acc.wtot.is_finite() && acc.wtot > 0.0;
        return ok.then(|| 1.0 / acc.wtot);
    }
    let m = points.len();
    acc.bmiss = [1.0; LANES];
    // One accumulator for every cluster, cleared after each on its members alone.
    part.reset(part_extent.0, part_extent.1);
    *part_extent = (n, m);
    let mut ctx_prev_set = 0u32;
    for cl in 0..clusters {
        let (mem, k, set_c) = members((elig, na), label, cl);
        let mut ctx = lg.ctx(
            (mem, k),
            sbar,
            zhat,
            valid,
            points,
            (n, n_skipped, skip),
            moments,
            odds,
        );
        ctx.active_set = set_c;
        if cl > 0 {
            part.clear_tracks(ctx_prev_set);
        }
        ctx_prev_set = set_c;
        if !(weigh(&ctx, part, arrays) && part.wtot.is_finite() && part.wtot > 0.0) {
            return None;
        }
        acc.events += part.events;
        acc.patterns += part.patterns;
        let inv = 1.0 / part.wtot;
        for &t in mem.iter().take(k) {
            let t = usize::from(t);
            set(&mut acc.y, t, get(&part.y, t) * inv);
            set(&mut acc.bmiss, t, get(&part.bmiss, t) * inv);
            if let (Some(dst), Some(src)) = (acc.beta.get_mut(t), part.beta.get(t)) {
                for (v, w) in dst.iter_mut().zip(src.iter()).take(m) {
                    *v = w * inv;
                }
            }
            for &t2 in mem.iter().take(k).filter(|&&t2| usize::from(t2) <= t) {
                let t2 = usize::from(t2);
                put(&mut acc.c, t, t2, at(&part.c, t, t2) * inv);
            }
        }
    }
    if moments {
        // Between clusters C' = C + y yᵀ vanishes: C = −y yᵀ there (lower triangle, as the pass).
        for (a, &t1) in elig.iter().enumerate().take(na) {
            for (b, &t2) in elig.iter().enumerate().take(a) {
                if get(label, a) != get(label, b) {
                    let (t1, t2) = (usize::from(t1), usize::from(t2));
                    put(&mut acc.c, t1, t2, -(get(&acc.y, t1) * get(&acc.y, t2)));
                }
            }
        }
    }
    acc.wtot = 1.0;
    Some(1.0)
}

/// The event weights of one row given each track's predicted measurement, without a state to
/// update (docs/design.md §11: the known lanes' association against the temporal prediction):
/// `zhat[t]` and `sdiag[t] = S̄_tt` (with the point variance `r` included) for the first `n`
/// tracks, and `cross(s, t) = S̄_st` (`s < t`), asked only for pairs of tracks that both have
/// candidates. Gating, the event budget and its pruning, the detection patterns and the events
/// are those of [`update_probed`] (steps 2, 3 and 5) under [`Association::Exact`]; the other
/// modes replace the enumeration by LBP marginals of the uncoupled likelihood on every row or on
/// the rows over the budget. `out.beta`, `out.beta_miss` and the counters are filled,
/// `out.failed` set on a numerical failure (every track then missed).
///
/// Tracks that share a candidate or have `cross ≠ 0` form clusters, and each cluster is
/// enumerated on its own (docs/design.md §11.3): between clusters the events and their weights
/// factor, so the marginals are exact, at `Σ_c Π_{t∈c} (1 + n_t)` events instead of
/// `Π_t (1 + n_t)`; `out.events` counts the clusters' sum and the budget applies to it. A row
/// over the budget as one enumeration is tried as clusters only when its clusters by shared
/// candidates fit and the first two are uncorrelated. Only the weights are summed: neither the
/// moments of the state update nor the rows of `L⁻¹`.
///
/// # Complexity
/// Enumerated: as [`update_probed`] without the state update, `n(n−1)/2 + 1` calls of `cross`
/// at most, `O(n³)` comparisons for the clusters, `2^n` patterns and `max_events` events at
/// most. LBP: no call of `cross`, at most
/// [`LBP_MAX_ITERATIONS`] × `2 n m` multiply-adds and divisions.
#[allow(clippy::too_many_arguments)]
pub fn associate<const LANES: usize>(
    zhat: &[f32; LANES],
    sdiag: &[f32; LANES],
    cross: impl Fn(usize, usize) -> f32,
    n: usize,
    points: &[f32],
    params: &RowParams,
    budget: (usize, Association),
    skip: u32,
) -> RowOutcome<LANES> {
    let mut out = RowOutcome::<LANES>::default();
    associate_into(
        (&mut out, &mut Scratch::new()),
        zhat,
        sdiag,
        cross,
        n,
        points,
        (params, &[0.0; LANES]),
        budget,
        skip,
    );
    out
}

/// [`associate`] into `out` (reset first), with the event pass's arrays `scratch`: the caller
/// keeps one of each for all its rows, so that no ~1 KiB outcome is copied and no pattern
/// arrays are cleared per row (a memcpy and a memclr on the Cortex-M4F).
///
/// `odds[t]` is added to the log-weight of every event that detects track `t`: with
/// `ln[P_D,t / miss(P_D,t)] − ln[P_D / miss(P_D)]` the row weighs track `t` at its own
/// detection probability `P_D,t` (docs/design.md §11.3; 0 for every track: [`associate`]).
#[allow(clippy::too_many_arguments)]
pub(crate) fn associate_into<const LANES: usize>(
    (out, scratch): (&mut RowOutcome<LANES>, &mut Scratch<LANES>),
    zhat: &[f32; LANES],
    sdiag: &[f32; LANES],
    cross: impl Fn(usize, usize) -> f32,
    n: usize,
    points: &[f32],
    (params, odds): (&RowParams, &[f32; LANES]),
    (max_events, mode): (usize, Association),
    skip: u32,
) {
    let n = n.min(LANES);
    let m = points.len().min(MAX_ROW_POINTS);
    scratch.begin_row(out, n, m);
    out.ignored_points = (points.len() - m) as u32;
    let points = points.get(..m).unwrap_or(&[]);
    let mut sbar = [[0.0f32; LANES]; LANES];
    for (t, row) in sbar.iter_mut().enumerate().take(n) {
        set(row, t, get(sdiag, t));
    }
    if n == 0 || !masks(zhat, &sbar, n, points, params, skip, out) {
        if n == 0 {
            out.clutter_points = points.iter().filter(|z| z.is_finite()).count() as u32;
            out.ignored_points += m as u32 - out.clutter_points;
        }
        if out.failed {
            failed(out);
        }
        return;
    }
    let n_skipped = (0..n).filter(|t| skip & (1 << t) != 0).count();
    let lg = scratch.logs(params);
    // The event count is checked once: an over-budget row is weighed by LBP or pruned. A row
    // whose tracks fall into independent clusters (below) is enumerated cluster by cluster, so
    // its count is the clusters' sum: over the budget as one enumeration, it may fit as several.
    // Over the budget as one, the row is split only if its clusters by shared candidates fit
    // and the first two of them are uncorrelated (otherwise the cross terms, `n(n−1)/2` calls
    // of `cross`, are not asked for: a coupled model's rows stay one enumeration).
    let mut sbar_known = false;
    let mut over = mode != Association::Lbp && over_budget(&out.valid, n, max_events);
    if over
        && cluster_bound(&out.valid, n, skip, &|_, _| false, max_events) <= max_events as u64
        && first_clusters_uncorrelated(&out.valid, n, skip, &cross)
    {
        let (elig, na) = eligible(&out.valid, n, skip);
        fill_cross(&mut sbar, (&elig, na), &cross);
        sbar_known = true;
        over = cluster_bound(
            &out.valid,
            n,
            skip,
            &|a, b| at(&sbar, a, b) != 0.0,
            max_events,
        ) > max_events as u64;
    }
    out.approximated = over;
    if mode == Association::Lbp || (mode == Association::ExactOrLbp && out.approximated) {
        match lbp::marginals(out, zhat, sdiag, points, n, (&lg, odds), skip) {
            Some(it) => out.lbp_iterations = it.max(1),
            None => failed(out),
        }
        return;
    }
    if out.approximated {
        prune(
            out,
            (&sbar, zhat, points),
            n,
            max_events.max(1) as u64,
            (&lg, odds),
        );
    }
    let (elig, na) = eligible(&out.valid, n, skip);
    if !sbar_known {
        fill_cross(&mut sbar, (&elig, na), &cross);
    }
    // Clusters: tracks that share a candidate or whose innovations are correlated
    // (`S̄_st ≠ 0`) are enumerated together. Between clusters the joint events are the product
    // of the clusters' events and their weights the product of the clusters' weights, so each
    // cluster's marginals are exact on their own. A cluster's miss factors of the other
    // tracks are common to all its events and cancel.
    let (label, clusters) = clusters(&out.valid, (&elig, na), &|a, b| at(&sbar, a, b) != 0.0);
    let Some(inv) = weigh_row(
        &lg,
        (&elig, na, &label, clusters),
        (&sbar, zhat, &out.valid),
        points,
        (n, n_skipped, skip),
        false,
        odds,
        scratch,
    ) else {
        failed(out);
        return;
    };
    let acc = &scratch.acc;
    out.events = acc.events;
    out.patterns = acc.patterns;
    normalise(out, &acc.beta, &acc.bmiss, inv, n, m, skip);
}

/// The eligible tracks among the first `n` (not masked by `skip`, at least one candidate).
fn eligible<const LANES: usize>(valid: &[u32; LANES], n: usize, skip: u32) -> ([u8; LANES], usize) {
    let mut elig = [0u8; LANES];
    let mut na = 0usize;
    for (t, v) in valid.iter().enumerate().take(n) {
        if skip & (1 << t) == 0 && *v != 0 {
            set(&mut elig, na, t as u8);
            na += 1;
        }
    }
    (elig, na)
}

/// Whether the first eligible track and the first one that shares no candidate with it are
/// uncorrelated (`cross = 0`); `true` when there is no such pair.
#[inline(never)]
fn first_clusters_uncorrelated<const LANES: usize>(
    valid: &[u32; LANES],
    n: usize,
    skip: u32,
    cross: &dyn Fn(usize, usize) -> f32,
) -> bool {
    let (elig, na) = eligible(valid, n, skip);
    let Some(&first) = elig.get(..na).and_then(|e| e.first()) else {
        return true;
    };
    let (t1, m1) = (usize::from(first), get(valid, usize::from(first)));
    elig.iter()
        .take(na)
        .map(|&t| usize::from(t))
        .find(|&t| t != t1 && get(valid, t) & m1 == 0)
        .is_none_or(|t2| cross(t1.min(t2), t1.max(t2)) == 0.0)
}

/// `S̄_st = cross(s, t)` into `sbar` (both halves) for every pair of the eligible tracks.
#[inline(never)]
fn fill_cross<const LANES: usize>(
    sbar: &mut [[f32; LANES]; LANES],
    (elig, na): (&[u8; LANES], usize),
    cross: &dyn Fn(usize, usize) -> f32,
) {
    for (a, &t1) in elig.iter().enumerate().take(na) {
        for &t2 in elig.iter().take(na).skip(a + 1) {
            let (t1, t2) = (usize::from(t1), usize::from(t2));
            let v = cross(t1.min(t2), t1.max(t2));
            put(sbar, t1, t2, v);
            put(sbar, t2, t1, v);
        }
    }
}

/// The clusters of the eligible tracks `elig[..na]`: the connected components of "share a
/// candidate or `linked(s, t)`". Returns each eligible track's cluster (by position) and the
/// number of clusters, numbered in order of their first track. `na(na−1)/2` pair checks
/// (`linked` only for pairs not yet joined) and `O(na)` per join.
#[inline(never)]
fn clusters<const LANES: usize>(
    valid: &[u32; LANES],
    (elig, na): (&[u8; LANES], usize),
    linked: &dyn Fn(usize, usize) -> bool,
) -> ([u8; LANES], usize) {
    // Each cluster is labelled by its first position while joining.
    let mut label: [u8; LANES] = core::array::from_fn(|a| a as u8);
    for a in 0..na {
        for b in a + 1..na {
            let (la, lb) = (get(&label, a), get(&label, b));
            if la == lb {
                continue;
            }
            let (ta, tb) = (usize::from(get(elig, a)), usize::from(get(elig, b)));
            if get(valid, ta) & get(valid, tb) != 0 || linked(ta, tb) {
                let (keep, gone) = (la.min(lb), la.max(lb));
                for l in label.iter_mut().take(na) {
                    if *l == gone {
                        *l = keep;
                    }
                }
            }
        }
    }
    let mut number = [u8::MAX; LANES];
    let mut count = 0usize;
    for l in label.iter_mut().take(na) {
        let first = usize::from(*l);
        *l = match number.get(first) {
            Some(&c) if c != u8::MAX => c,
            _ => {
                set(&mut number, first, count as u8);
                count += 1;
                (count - 1) as u8
            }
        };
    }
    (label, count)
}

/// The members of cluster `c` (tracks, in increasing order), their number and their set.
fn members<const LANES: usize>(
    (elig, na): (&[u8; LANES], usize),
    label: &[u8; LANES],
    c: usize,
) -> ([u8; LANES], usize, u32) {
    let mut members = [0u8; LANES];
    let mut k = 0usize;
    let mut set_c = 0u32;
    for (&t, _) in elig
        .iter()
        .zip(label.iter())
        .take(na)
        .filter(|(_, l)| usize::from(**l) == c)
    {
        set(&mut members, k, t);
        k += 1;
        set_c |= 1 << t;
    }
    (members, k, set_c)
}

/// The joint events of a row enumerated cluster by cluster ([`clusters`] with `linked`),
/// counted up to `limit + 1`: `Σ_c` (events of cluster `c`).
#[inline(never)]
fn cluster_bound<const LANES: usize>(
    valid: &[u32; LANES],
    n: usize,
    skip: u32,
    linked: &dyn Fn(usize, usize) -> bool,
    limit: usize,
) -> u64 {
    let limit = limit.max(1) as u64;
    let (elig, na) = eligible(valid, n, skip);
    let (label, count) = clusters(valid, (&elig, na), linked);
    let mut total = 0u64;
    for c in 0..count {
        let (members, k, _) = members((&elig, na), &label, c);
        let masks: [u32; LANES] =
            core::array::from_fn(|a| get(valid, usize::from(get(&members, a))));
        total += count_events(&masks, k, limit);
        if total > limit {
            return limit + 1;
        }
    }
    total.max(1)
}

/// Gating (step 2) on each track's marginal: `ẑ_t = h·x_t` and `S̄_tt = hᵀ P_tt h + r`, the
/// validation masks in `out.valid`, and the ignored and clutter points counted. `false` (with
/// `out.failed` set) when a marginal variance is not positive and finite.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn gate<const NS: usize, const LANES: usize>(
    xs: &Means<NS, LANES>,
    ps: &Blocks<NS, LANES>,
    n: usize,
    hv: [f32; NS],
    points: &[f32],
    params: &RowParams,
    skip: u32,
    out: &mut RowOutcome<LANES>,
    zhat: &mut [f32; LANES],
    sbar: &mut [[f32; LANES]; LANES],
) -> bool {
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
    masks(zhat, sbar, n, points, params, skip, out)
}

/// The validation masks of the first `n` tracks (step 2) in `out.valid` from their predicted
/// measurements and marginal innovation variances `sbar[t][t]`, and the ignored and clutter
/// points counted. `false` (with `out.failed` set) when a variance is not positive and finite.
#[inline(always)]
fn masks<const LANES: usize>(
    zhat: &[f32; LANES],
    sbar: &[[f32; LANES]; LANES],
    n: usize,
    points: &[f32],
    params: &RowParams,
    skip: u32,
    out: &mut RowOutcome<LANES>,
) -> bool {
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
            return false;
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
    true
}

/// The constant log terms of a row's event weights (docs/design.md §4.1 step 3).
#[derive(Clone, Copy)]
struct Logs {
    /// `ln(P_D / λ_c)`.
    ln_pd_lambda: f32,
    /// `ln` of the miss factor of the miss model.
    ln_miss: f32,
    /// `ln 2π`.
    ln_2pi: f32,
}

impl Logs {
    /// The event pass's context: the eligible tracks `(elig, na)`, `S̄`, `ẑ`, the gates, the
    /// row's points, `(n, n_skipped, skip)`: tracks, masked tracks, and their mask, and
    /// whether the pass sums the update's moments.
    #[allow(clippy::too_many_arguments)]
    fn ctx<'a, const LANES: usize>(
        &self,
        (elig, na): ([u8; LANES], usize),
        sbar: &'a [[f32; LANES]; LANES],
        zhat: &'a [f32; LANES],
        valid: &'a [u32; LANES],
        points: &'a [f32],
        (n, n_skipped, skip): (usize, usize, u32),
        moments: bool,
        odds: &'a [f32; LANES],
    ) -> Ctx<'a, LANES> {
        Ctx {
            odds,
            elig,
            na,
            sbar,
            zhat,
            valid,
            points,
            ln_2pi: self.ln_2pi,
            ln_pd_lambda: self.ln_pd_lambda,
            ln_miss: self.ln_miss,
            active: (n - n_skipped) as f32,
            active_set: !skip & (u32::MAX >> (32 - n.clamp(1, 32))),
            moments,
        }
    }

    fn of(params: &RowParams) -> Self {
        Self {
            ln_pd_lambda: math::ln(params.pd) - math::ln(params.clutter_density),
            ln_miss: math::ln(params.miss_at(params.pd)),
            ln_2pi: math::ln(2.0 * core::f32::consts::PI),
        }
    }
}

/// Whether the first `n` tracks' gates `valid` make more joint events than `max_events` (at
/// least 1). The bound `Π (1 + n_t)` is checked first, so the events are only counted when it
/// exceeds the budget.
fn over_budget<const LANES: usize>(valid: &[u32; LANES], n: usize, max_events: usize) -> bool {
    let budget = max_events.max(1) as u64;
    event_bound(valid, n) > budget && count_events(valid, n, budget) > budget
}

/// `Π_t (1 + n_t)` over the first `n` tracks' gates: an upper bound of the joint events.
fn event_bound<const LANES: usize>(valid: &[u32; LANES], n: usize) -> u64 {
    valid
        .iter()
        .take(n)
        .map(|v| 1 + u64::from(v.count_ones()))
        .product()
}

/// `β_miss` and `β` of the first `n` tracks from the mixture sums (`inv = 1 / Σ w`); masked
/// tracks are missed.
#[inline(always)]
fn normalise<const LANES: usize>(
    out: &mut RowOutcome<LANES>,
    beta: &[[f32; MAX_ROW_POINTS]; LANES],
    bmiss: &[f32; LANES],
    inv: f32,
    n: usize,
    m: usize,
    skip: u32,
) {
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
            get(bmiss, t) * inv
        };
        for (v, s) in brow.iter_mut().zip(src.iter()).take(m) {
            *v = s * inv;
        }
    }
}

/// `out.dens[t] = Σ_{j gated} N(z_j; ẑ_t, S̄_tt) · (1 − Σ_{t' ≠ t} β_{t'j})` after the weights:
/// each point counts for a track as far as no other track claims it (a broad track overlapping
/// a known one gets no credit for the known one's points, as in JIPDA). `ln_2pi = ln 2π` (the
/// row's [`Logs`]). Out of line: inlined into
/// its one caller's row walk it adds 2.3 KB of flash.
#[inline(never)]
fn exclusive_density<const LANES: usize>(
    out: &mut RowOutcome<LANES>,
    (zhat, sdiag): (&[f32; LANES], &[f32; LANES]),
    points: &[f32],
    n: usize,
    ln_2pi: f32,
) {
    // Only the row's points are read below (a gate bit `j` has `j < m`).
    let m = points.len().min(MAX_ROW_POINTS);
    let mut claimed = [0.0f32; MAX_ROW_POINTS];
    for row in out.beta.iter().take(n) {
        for (c, b) in claimed.iter_mut().zip(row.iter()).take(m) {
            *c += b;
        }
    }
    for t in 0..n {
        let st = get(sdiag, t);
        let zt = get(zhat, t);
        let mask = get(&out.valid, t);
        // By reference: a copy of the row is a 128-byte memcpy on the Cortex-M4F.
        let own = out.beta.get(t).unwrap_or(&[0.0; MAX_ROW_POINTS]);
        let ln_st = math::ln(st);
        let norm = -0.5 * (ln_2pi + ln_st);
        // Over the gate's set bits only (a bit `j` has `j < m`).
        let mut bits = mask & if m >= 32 { u32::MAX } else { (1u32 << m) - 1 };
        let mut d = 0.0f32;
        while bits != 0 {
            let j = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let e = points.get(j).copied().unwrap_or(zt) - zt;
            let free = (1.0 - (get(&claimed, j) - get(own, j))).clamp(0.0, 1.0);
            d += math::exp_call(norm - 0.5 * e * e / st) * free;
        }
        set(&mut out.dens, t, if d.is_finite() { d } else { 0.0 });
    }
}

/// Event weights (step 3) and the mixture sums (step 4) in one pass over the patterns and their
/// events, redone once with a new reference if the weights' scale was off. `None` on a
/// numerical failure (`acc` then holds nothing meaningful).
#[inline(always)]
fn weigh<const LANES: usize>(
    ctx: &Ctx<'_, LANES>,
    acc: &mut Acc<LANES>,
    scratch: &mut events::Scratch<LANES>,
) -> bool {
    let empty = ctx.base(0, 0.0, 0.0);
    let mut reference = if empty.is_finite() { empty } else { 0.0 };
    if !ctx.pass(reference, acc, scratch) {
        return false;
    }
    if acc.lwmax.is_finite()
        && ((acc.lwmax - reference).abs() > WINDOW || !(acc.wtot.is_finite() && acc.wtot > 0.0))
    {
        reference = acc.lwmax;
        // The pass wrote β only at the row's points.
        acc.reset(LANES, ctx.points.len());
        if !ctx.pass(reference, acc, scratch) {
            return false;
        }
    }
    true
}

/// Drops (track, point) candidates in order of increasing single-track PDA probability until
/// the bound `Π (1 + n_t)` on the event count fits `budget` (step 5), given the first `n`
/// tracks' `S̄`, `ẑ` and the row's points.
///
/// # Complexity
/// `O(C²)` compares (insertion sort) for the `C ≤ n·m` candidates; `8·LANES·MAX_ROW_POINTS` bytes of
/// stack for the candidate list (1.5 KiB at 6 lanes).
fn prune<const LANES: usize>(
    out: &mut RowOutcome<LANES>,
    (sbar, zhat, points): (&[[f32; LANES]; LANES], &[f32; LANES], &[f32]),
    n: usize,
    budget: u64,
    (lg, odds): (&Logs, &[f32; LANES]),
) {
    let Logs {
        ln_pd_lambda,
        ln_miss,
        ln_2pi,
    } = *lg;
    // Every (track, point) candidate: `LANES × MAX_ROW_POINTS` entries of 8 bytes (1.5 KiB of
    // stack at 6 lanes when the budget forces pruning), one flat list.
    let mut cand2 = [[(0.0f32, 0u8, 0u8); MAX_ROW_POINTS]; LANES];
    let cand = cand2.as_flattened_mut();
    let mut nc = 0usize;
    for t in 0..n {
        let st = at(sbar, t, t);
        let zt = get(zhat, t);
        let ln_norm = ln_pd_lambda + get(odds, t) - 0.5 * (ln_2pi + math::ln(st));
        let mask = get(&out.valid, t);
        let first = nc;
        let mut lmax = ln_miss;
        for (j, z) in points.iter().enumerate() {
            if mask & (1 << j) != 0 {
                let e = z - zt;
                let l = ln_norm - 0.5 * (e * e / st);
                lmax = lmax.max(l);
                if let Some(c) = cand.get_mut(nc) {
                    *c = (l, t as u8, j as u8);
                }
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
        crate::linalg::sort_by(c, |a, b| a.0.total_cmp(&b.0).is_lt());
    }
    for &(_, t, j) in cand.iter().take(nc) {
        if event_bound(&out.valid, n) <= budget {
            break;
        }
        let t = usize::from(t);
        let mask = get(&out.valid, t) & !(1u32 << j);
        set(&mut out.valid, t, mask);
        out.dropped_candidates += 1;
    }
}

/// Marks `out` failed, with the weights of an untouched row (β cleared, every track missed).
fn failed<const LANES: usize>(out: &mut RowOutcome<LANES>) {
    out.failed = true;
    out.beta = [[0.0; MAX_ROW_POINTS]; LANES];
    out.beta_miss = [1.0; LANES];
}

#[cfg(test)]
mod tests;
