//! Known lanes persist (docs/design.md §11): the temporal prediction is the prior of this frame's
//! association, existence is a probability, and the clutter density, the point variance and
//! every lane's detection probability are estimated, not set.
//!
//! Each frame, before the spatial JPDACF, every live temporal lane is predicted at every BEV row
//! `u_r` from its Gram coefficients (the GP conditional of [`crate::tracker::Tracker::lane_at`]):
//! `ẑ = c_rᵀ a_s`, `c_rj = k(u_r, U)·v_j / λ_j`, with variance `p = c_rᵀ Cov(a_s) c_r + ρ_r B_ss`
//! (`ρ_r = σ_u² − Σ_j (k·v_j)²/λ_j`) plus the band's point variance `r_b`. The lanes'
//! cross-covariances at the row, `c_rᵀ Cov(a_s, a_t) c_r + ρ_r B_st`, couple them: one
//! joint-event enumeration per row ([`crate::spatial::row::associate`]) gives `β_{s,j}` and
//! `β_{s,miss}`. A row's PDA update of a lane's marginal is replaced by the equivalent
//! measurement with the same posterior variance (§11.3: `1/(p + v) = W/S − q₂/S²`,
//! `z̃ = ẑ + ν̄ (p + v)/S`), and the rows are summed in information form on the lane's Gram
//! components, `J_s = Σ_r c_r c_rᵀ / v_r`, `i_s = Σ_r c_r z̃_r / v_r`. The temporal filter is then
//! updated with `(J_s, i_s)` ([`crate::temporal::smoother::Temporal::update_info_probed`]): the
//! frame's points enter the temporal filter once.
//!
//! **Existence** (IPDA, Mušicki, Evans & Stanković 1994, per row, §11.5): predicted by
//! `P ← P·e^{−T/τ_s}`; updated with `L = (1/K) Σ_r ln Λ_r` over the rows where the lane is in
//! view, `Λ_r = 1 − P_D,b P_G + (P_D,b / λ_b) Σ_{j gated} N(z_j; ẑ, S)(1 − Σ_{t≠s} β_{t,j})`, as
//! `logit P += ln(p_v e^L + 1 − p_v)` (a frame may not show the lane at all). `P_D,b` is the
//! lane's own detection probability in index band `b` (Beta(1, 1) posterior mean of discounted
//! row weights, fixed over a pass); `λ_b` the band's clutter density from the points no known
//! lane explains; `r_b` the band's point variance from posterior residuals (§11.6).
//!
//! Points a known lane explains leave the rows; the spatial JPDACF runs on the rest and may
//! start new lanes only from them.
//!
//! # Cost
//! Per row: `n·r` for the predictions, `n·r²` for the variances, at most `n(n−1)/2·r²` for the
//! cross terms of lanes with candidates, one bounded event enumeration; `POINTS` exponentials
//! and `POINTS·r` multiply-adds for the row basis; then per lane `O(r³)` and the temporal update
//! (`n_act²·r/2`); the noise estimate another `n·r²` per row with evidence.

use nalgebra::{SMatrix, SVector};

use crate::linalg::{get, set};
use crate::math;
use crate::spatial::row::{self, RowParams, MAX_ROW_POINTS};
use crate::tables::Tables;
use crate::temporal::filter::TemporalFilter;

/// Tuning of the known-lane stage. Values are model constants, not fitted to a data set
/// (docs/design.md §11 says which data chose which).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PersistConfig {
    /// `true`: known lanes are associated against their temporal prediction (this module);
    /// `false`: the round-1 pipeline (every frame's lanes found afresh, matched afterwards), kept
    /// for the ablation.
    pub enabled: bool,
    /// Frames of memory of a lane's per-band detection counts.
    pub pd_memory: f32,
    /// Frames of memory of the clutter density estimate.
    pub clutter_memory: f32,
    /// Smallest clutter density used, points per metre per row.
    pub clutter_floor: f32,
    /// Mean survival time of a lane that is no longer supported, seconds (`τ_s`).
    pub survival_time: f32,
    /// Existence of a lane before its first frame's evidence.
    pub p_birth: f32,
    /// A lane is published while its existence is at least this.
    pub p_publish: f32,
    /// A lane is deleted when its existence falls below this.
    pub p_delete: f32,
    /// A point whose summed association probability to the known lanes reaches this is theirs
    /// and leaves the rows before the spatial filter runs.
    pub explained: f32,
    /// Hits that make a spatial track a lane candidate (the spatial filter's `confirm_hits`
    /// while this stage is on): a candidate starts with existence `p_birth`, and the frames
    /// that follow decide, so a dashed marking needs only a few hits in one frame.
    pub confirm_hits: u16,
    /// Frames of memory of the process-noise scale's adaptation (0: no adaptation).
    pub q_memory: f32,
    /// Probability that a lane that exists is visible in a frame (not occluded, not blurred
    /// out): the rows' evidence of a frame counts only in that case (docs/design.md §11.5).
    pub p_visible: f32,
    /// Two lanes closer than this on average over their common observed extent are one
    /// marking (docs/design.md §11.9), metres: half of a 2 m minimum spacing of markings.
    pub min_spacing: f32,
}

impl PersistConfig {
    /// The defaults: 10 frames of detection memory, 5 of clutter memory, clutter floor
    /// 0.005 /m, `τ_s` = 10 s, `P_birth` = 0.1, publish at 0.5, delete below 0.01, a point
    /// explained at 0.5.
    pub const DEFAULT: Self = Self {
        enabled: true,
        pd_memory: 10.0,
        clutter_memory: 5.0,
        clutter_floor: 0.005,
        survival_time: 10.0,
        p_birth: 0.1,
        p_publish: 0.5,
        p_delete: 0.01,
        explained: 0.5,
        confirm_hits: 3,
        q_memory: 2.0,
        p_visible: 0.9,
        min_spacing: 1.0,
    };

    /// The round-1 pipeline (ablation "no temporal prior").
    pub const ROUND1: Self = Self {
        enabled: false,
        ..Self::DEFAULT
    };
}

impl Default for PersistConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One lane's estimated detection probability per index band and its existence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneState<const POINTS: usize> {
    /// Known-lane passes this lane has been through.
    pub passes: u16,
    /// Discounted row weights `Σ W_r` per band.
    pub hits: [f32; POINTS],
    /// Discounted rows per band.
    pub looks: [f32; POINTS],
    /// `P(exists)`.
    pub existence: f32,
}

impl<const POINTS: usize> LaneState<POINTS> {
    /// A lane with no history.
    pub const NEW: Self = Self {
        passes: 0,
        hits: [0.0; POINTS],
        looks: [0.0; POINTS],
        existence: 0.0,
    };

    /// `P_D` in band `b`: the Beta(1, 1) posterior mean.
    pub fn pd(&self, b: usize) -> f32 {
        (get(&self.hits, b) + 1.0) / (get(&self.looks, b) + 2.0)
    }
}

/// The stage's state: per slot [`LaneState`], per band the clutter density and the point
/// variance, and this frame's row evidence per slot (for the noise estimate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Persist<const LANES: usize, const POINTS: usize, const ROWS: usize> {
    /// Per slot.
    pub lanes: [LaneState<POINTS>; LANES],
    /// Clutter density per band, points per metre per row (`NaN` until first estimated).
    pub clutter: [f32; POINTS],
    /// Discounted sums of the point-variance estimates per band, and their counts.
    pub noise: [[f32; 2]; POINTS],
    /// This frame's `(z̃_r, W_r)` per slot and row (`W_r = 0`: nothing).
    rows: [[[f32; 2]; ROWS]; LANES],
    /// This frame's lateral span `[min, max]` of all points per band: where the sensor sees.
    pub span: [[f32; 2]; POINTS],
    /// `ln` of the process-noise scale (≥ 0).
    pub log_q_scale: f32,
    /// This frame's sum of `ν²/S` and count over the confidently associated rows of lanes
    /// older than one frame.
    nis: [f32; 2],
    /// The last frame's ratio `Σ nis / Σ dof` (0 when not enough was counted).
    pub last_nis_ratio: f32,
}

/// One frame's evidence for one lane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evidence<const RANK: usize> {
    /// `J = Σ ω_r c_r c_rᵀ`.
    pub j: SMatrix<f32, RANK, RANK>,
    /// `i = Σ ω_r z̃_r c_r`.
    pub i: SVector<f32, RANK>,
    /// `Σ_r W_r` (expected detected rows).
    pub weight: f32,
    /// `Σ_r ln Λ_r`.
    pub llr: f32,
    /// `u` of the first and last rows with `W_r ≥ 0.5` (`[+∞, −∞]` when none).
    pub extent: [f32; 2],
}

impl<const RANK: usize> Evidence<RANK> {
    /// No evidence.
    pub const NONE: Self = Self {
        j: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; RANK]; RANK])),
        i: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; RANK]; 1])),
        weight: 0.0,
        llr: 0.0,
        extent: [f32::INFINITY, f32::NEG_INFINITY],
    };
}

/// What [`Persist::associate`] needs besides the lanes.
#[derive(Debug, Clone, Copy)]
pub struct Pass {
    /// Rows and their spacing.
    pub rows: usize,
    /// Row spacing, metres.
    pub du: f32,
    /// Rows per index interval (`K`).
    pub k_rows: usize,
    /// Row parameters (`P_D`, `P_G`, `γ`, `r`, miss model); the clutter density is the band's.
    pub params: RowParams,
    /// Events per row.
    pub max_events: usize,
}

impl<const LANES: usize, const POINTS: usize, const ROWS: usize> Default
    for Persist<LANES, POINTS, ROWS>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const LANES: usize, const POINTS: usize, const ROWS: usize> Persist<LANES, POINTS, ROWS> {
    /// No lanes, no clutter or noise estimate.
    pub const fn new() -> Self {
        Self {
            lanes: [LaneState::NEW; LANES],
            clutter: [f32::NAN; POINTS],
            noise: [[0.0; 2]; POINTS],
            rows: [[[0.0; 2]; ROWS]; LANES],
            span: [[f32::INFINITY, f32::NEG_INFINITY]; POINTS],
            log_q_scale: 0.0,
            nis: [0.0; 2],
            last_nis_ratio: 0.0,
        }
    }

    /// The temporal process-noise scale `e^{log_q_scale}` (≥ 1).
    pub fn q_scale(&self) -> f32 {
        math::exp(self.log_q_scale.max(0.0))
    }

    /// Counts one lane update's normalised innovation `nis` with `dof` degrees of freedom
    /// (lanes through at least two known-lane passes only: a new lane's velocity is unknown).
    /// Only lanes that are published (`P ≥ p_publish`) count, and each lane's `nis` is capped at
    /// `3·dof` (about the χ² 99.9 % point for 7 degrees of freedom): one lane gone astray must
    /// not inflate every lane's process noise.
    pub fn count_nis(&mut self, s: usize, nis: f32, dof: f32, p_publish: f32) {
        let ok = self
            .lanes
            .get(s)
            .is_some_and(|l| l.passes >= 2 && l.existence >= p_publish);
        if ok && nis.is_finite() && nis >= 0.0 {
            self.nis[0] += nis.min(3.0 * dof);
            self.nis[1] += dof;
        }
    }

    /// Adapts the process-noise scale to this frame's normalised innovations (covariance
    /// matching): with `ρ = Σ nis / Σ dof` over the lane updates counted (1 when the model
    /// holds), `ln s += ln ρ / memory`, `s` kept in `[1, 10⁴]`. Nothing changes with fewer than
    /// `min_dof` degrees of freedom.
    pub fn adapt_q_scale(&mut self, memory: f32, min_dof: f32) {
        let [sum, n] = self.nis;
        self.last_nis_ratio = 0.0;
        if n >= min_dof && sum > 0.0 && sum.is_finite() {
            let rho = sum / n;
            self.last_nis_ratio = rho;
            let step = math::ln(rho) / memory.max(1.0);
            if step.is_finite() {
                self.log_q_scale = (self.log_q_scale + step).clamp(0.0, 9.21);
            }
        }
        self.nis = [0.0; 2];
    }

    /// Records this frame's lateral span per band from all its binned points (call once per
    /// frame, before any association): a lane predicted outside its band's span is not in
    /// view there, so the row counts neither as a detection nor as a miss.
    pub fn observe_spans<'p>(
        &mut self,
        rows: usize,
        k_rows: usize,
        row_points: impl Fn(usize) -> &'p [f32],
    ) {
        self.span = [[f32::INFINITY, f32::NEG_INFINITY]; POINTS];
        for r in 0..rows {
            let b = ((r + k_rows / 2) / k_rows.max(1)).min(POINTS - 1);
            if let Some(sp) = self.span.get_mut(b) {
                for z in row_points(r).iter().filter(|z| z.is_finite()) {
                    sp[0] = sp[0].min(*z);
                    sp[1] = sp[1].max(*z);
                }
            }
        }
    }

    /// The point variance of band `b`: `(S_b + n₀ r₀) / (N_b + n₀)` with the prior `r₀` =
    /// `fallback` worth `n₀ = 2` rows, floored at `1e-5` m².
    pub fn noise(&self, b: usize, fallback: f32) -> f32 {
        let [s, n] = self.noise.get(b).copied().unwrap_or([0.0; 2]);
        ((s + 2.0 * fallback) / (n + 2.0)).max(1e-5)
    }

    /// The clutter density of band `b`, or `fallback` before the first estimate.
    pub fn clutter(&self, b: usize, fallback: f32, floor: f32) -> f32 {
        let c = get(&self.clutter, b);
        if c.is_finite() {
            c.max(floor)
        } else {
            fallback.max(floor)
        }
    }

    /// Existence prediction over `dt` seconds for every live slot.
    pub fn predict(&mut self, dt: f32, cfg: &PersistConfig) {
        let ps = if cfg.survival_time > 0.0 {
            math::exp(-dt / cfg.survival_time)
        } else {
            1.0
        };
        for l in &mut self.lanes {
            l.existence *= ps;
        }
    }

    /// Existence update of slot `s` with a frame's summed row log-likelihood ratio `llr`
    /// (docs/design.md §11.5): the rows of an index interval count as one look, `L = llr / k`,
    /// and the frame is a mixture of "the lane is visible" (probability `p_visible`, the rows'
    /// evidence holds) and "it is not" (occlusion, glare, a bump: no information), so
    /// `logit P += ln(p_v e^L + 1 − p_v)` — a frame that sees nothing of a lane costs at most
    /// `ln(1 − p_v)`; the change is bounded by ±30.
    pub fn update_existence(&mut self, s: usize, llr: f32, k: f32, p_visible: f32) {
        if let Some(l) = self.lanes.get_mut(s) {
            let big = (llr / k.max(1.0)).clamp(-60.0, 60.0);
            let pv = p_visible.clamp(0.0, 1.0);
            // ln(p_v e^L + 1 − p_v), evaluated without overflow.
            let mixed = if big > 0.0 {
                big + math::ln(pv + (1.0 - pv) * math::exp(-big))
            } else {
                math::ln(1.0 - pv + pv * math::exp(big))
            };
            let d = mixed.clamp(-30.0, 30.0);
            let p = l.existence.clamp(1e-6, 1.0 - 1e-6);
            let lo = math::ln(p / (1.0 - p)) + if d.is_finite() { d } else { 0.0 };
            l.existence = 1.0 / (1.0 + math::exp(-lo));
        }
    }

    /// Clears slot `s` and gives it the birth existence.
    pub fn start(&mut self, s: usize, cfg: &PersistConfig) {
        set(
            &mut self.lanes,
            s,
            LaneState {
                existence: cfg.p_birth,
                ..LaneState::NEW
            },
        );
    }

    /// Clears slot `s`.
    pub fn remove(&mut self, s: usize) {
        set(&mut self.lanes, s, LaneState::NEW);
    }
}

impl<const LANES: usize, const POINTS: usize, const ROWS: usize> Persist<LANES, POINTS, ROWS> {
    /// The point-variance estimate from this frame's posterior residuals of the lanes in
    /// `slots` (after their updates, docs/design.md §11.6): for every row where one point holds
    /// ≥ 90 % of the lane's weight `W_r ≥ 0.5`, `r̂ = (e² − ρ_r B_ss + c_rᵀ P⁺ c_r)/0.973`,
    /// `e` = that point − `c_rᵀ a⁺` (`Var(e) = r + ρ_r B_ss − c_rᵀ P⁺ c_r`), counted when
    /// `e² ≤ 9 r_b` (0.973 corrects the 3σ truncation), summed per band with a memory of
    /// `memory` frames.
    #[allow(clippy::too_many_arguments)]
    pub fn estimate_noise<const NT: usize, const RANK: usize, const NX: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        filter: &TemporalFilter<LANES, POINTS, RANK, NX>,
        slots: u32,
        ranks: &[u8; LANES],
        pass: &Pass,
        memory: f32,
    ) {
        let h = &tables.hyper;
        let r_used = (tables.gram_rank as usize).min(RANK).min(POINTS);
        let decay = if memory > 1.0 {
            1.0 - 1.0 / memory
        } else {
            0.0
        };
        for nb in &mut self.noise {
            nb[0] *= decay;
            nb[1] *= decay;
        }
        let x = filter.mean();
        for r in 0..pass.rows.min(ROWS) {
            let any = (0..LANES).any(|s| {
                slots & (1 << s) != 0
                    && self
                        .rows
                        .get(s)
                        .and_then(|rs| rs.get(r))
                        .is_some_and(|v| v[1] >= 0.5)
            });
            if !any {
                continue;
            }
            let b = ((r + pass.k_rows / 2) / pass.k_rows.max(1)).min(POINTS - 1);
            let u = h.u_min + r as f32 * pass.du;
            let (c, rho) = row_basis::<NT, LANES, POINTS, RANK>(tables, u, r_used);
            for s in 0..LANES {
                let [zt, w] = self
                    .rows
                    .get(s)
                    .and_then(|rs| rs.get(r))
                    .copied()
                    .unwrap_or([0.0; 2]);
                if slots & (1 << s) == 0 || w < 0.5 || !filter.is_active(s) {
                    continue;
                }
                let z: f32 = (0..r_used)
                    .map(|j| {
                        get(&c, j)
                            * x.get(TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0))
                                .copied()
                                .unwrap_or(0.0)
                    })
                    .sum();
                let rk = usize::from(get(ranks, s));
                let bss = tables.coreg.get((rk, rk)).copied().unwrap_or(0.0);
                let e = zt - z;
                // Residuals beyond 3σ of the current estimate are not counted (clutter the
                // association took for the lane); the truncation's bias (×0.973 for a
                // Gaussian) is corrected.
                let cur = self.noise(b, pass.params.r);
                let est = (e * e - rho * bss + quad(filter, s, s, &c, r_used)) / 0.973;
                if est.is_finite() && e * e <= 9.0 * cur {
                    if let Some(nb) = self.noise.get_mut(b) {
                        nb[0] += est.max(0.0);
                        nb[1] += 1.0;
                    }
                }
            }
        }
    }
}

/// The GP conditional's row vector at `u`: `c_j = k(u, U)·v_j / λ_j` for the first `r`
/// components, and the prior's residual variance `ρ = (σ_u² − Σ_j (k·v_j)²/λ_j)⁺`.
pub fn row_basis<const NT: usize, const LANES: usize, const POINTS: usize, const RANK: usize>(
    tables: &Tables<NT, LANES, POINTS>,
    u: f32,
    r: usize,
) -> ([f32; RANK], f32) {
    let h = &tables.hyper;
    let l2 = 2.0 * h.spatial_lengthscale * h.spatial_lengthscale;
    let mut k = [0.0f32; POINTS];
    for (i, kv) in k.iter_mut().enumerate() {
        let d = u - tables.index_u.get(i).copied().unwrap_or(0.0);
        *kv = h.spatial_variance * math::exp(-d * d / l2);
    }
    let mut c = [0.0f32; RANK];
    let mut explained = 0.0;
    for (j, cj) in c.iter_mut().enumerate().take(r) {
        let lam = tables.gram_eigval.get(j).copied().unwrap_or(0.0);
        if lam <= 0.0 {
            continue;
        }
        let kv: f32 = k
            .iter()
            .enumerate()
            .map(|(i, ki)| ki * tables.gram_eigvec.get((i, j)).copied().unwrap_or(0.0))
            .sum();
        *cj = kv / lam;
        explained += kv * kv / lam;
    }
    (c, (h.spatial_variance - explained).max(0.0))
}

/// `cᵀ P[a_s, a_t] c` over the first `r` components.
fn quad<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize>(
    f: &TemporalFilter<LANES, POINTS, RANK, NX>,
    s: usize,
    t: usize,
    c: &[f32; RANK],
    r: usize,
) -> f32 {
    let p = f.covariance();
    let mut acc = 0.0;
    for (j, cj) in c.iter().enumerate().take(r) {
        let ij = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0);
        let mut inner = 0.0;
        for (k, ck) in c.iter().enumerate().take(r) {
            let ik = TemporalFilter::<LANES, POINTS, RANK, NX>::index(t, k, 0);
            inner += p.get((ij, ik)).copied().unwrap_or(0.0) * ck;
        }
        acc += cj * inner;
    }
    acc
}

/// The rows' points a known lane explains, per row (bit `j` = point `j`).
pub type Explained<const ROWS: usize> = [u32; ROWS];

/// Inputs of one association pass.
pub struct Lanes<'a, const LANES: usize> {
    /// Slots looked at (bit `s`).
    pub slots: u32,
    /// B index (rank) of every slot.
    pub ranks: &'a [u8; LANES],
    /// Row range `[lo, hi]` per slot (inclusive).
    pub rows: [(u16, u16); LANES],
}

impl<const LANES: usize, const POINTS: usize, const ROWS: usize> Persist<LANES, POINTS, ROWS> {
    /// One pass of the known lanes over the binned rows: per row the predicted lanes, the
    /// joint events, and each lane's evidence (`ev[s]`) and detection counts; the points each
    /// row's lanes explain (`explained[r]`), and the clutter estimate from the rest
    /// (`estimate_clutter`). `row_points(r)` gives row `r`'s points.
    #[allow(clippy::too_many_arguments, clippy::too_many_lines)]
    pub fn associate<'p, const NT: usize, const RANK: usize, const NX: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        filter: &TemporalFilter<LANES, POINTS, RANK, NX>,
        lanes: &Lanes<'_, LANES>,
        pass: &Pass,
        cfg: &PersistConfig,
        row_points: impl Fn(usize) -> &'p [f32],
        estimate_clutter: bool,
        ev: &mut [Evidence<RANK>; LANES],
        explained: &mut Explained<ROWS>,
    ) -> u32 {
        let h = &tables.hyper;
        let r_used = (tables.gram_rank as usize).min(RANK).min(POINTS);
        let mut slot = [0usize; LANES];
        let mut n = 0usize;
        for s in 0..LANES {
            if lanes.slots & (1 << s) != 0 && filter.is_active(s) {
                set(&mut slot, n, s);
                n += 1;
            }
        }
        let pd_decay = if cfg.pd_memory > 1.0 {
            1.0 - 1.0 / cfg.pd_memory
        } else {
            0.0
        };
        for s in slot.iter().take(n) {
            if let Some(l) = self.lanes.get_mut(*s) {
                l.passes = l.passes.saturating_add(1);
                for (hb, lb) in l.hits.iter_mut().zip(l.looks.iter_mut()) {
                    *hb *= pd_decay;
                    *lb *= pd_decay;
                }
            }
        }
        // P_D,b of every lane for this pass: the discounted estimate before this frame's rows
        // (docs/design.md §11.5; the counts of this pass take effect from the next one).
        let mut pd0 = [[0.5f32; POINTS]; LANES];
        for (l, row) in self.lanes.iter().zip(pd0.iter_mut()) {
            for (b, v) in row.iter_mut().enumerate() {
                *v = l.pd(b);
            }
        }
        let bss = |s: usize, t: usize| {
            let a = usize::from(get(lanes.ranks, s));
            let b = usize::from(get(lanes.ranks, t));
            tables.coreg.get((a, b)).copied().unwrap_or(0.0)
        };
        let mut unexplained = [0.0f32; POINTS];
        let mut band_rows = [0.0f32; POINTS];
        let mut failed = 0u32;
        for r in 0..pass.rows.min(ROWS) {
            let pts = row_points(r);
            let m = pts.len().min(MAX_ROW_POINTS);
            let pts = pts.get(..m).unwrap_or(&[]);
            let b = ((r + pass.k_rows / 2) / pass.k_rows.max(1)).min(POINTS - 1);
            if let Some(br) = band_rows.get_mut(b) {
                *br += 1.0;
            }
            let u = h.u_min + r as f32 * pass.du;
            let (c, rho) = row_basis::<NT, LANES, POINTS, RANK>(tables, u, r_used);
            // The lanes looked at in this row (their row range), predicted.
            let mut idx = [0usize; LANES];
            let mut nr = 0usize;
            let mut zhat = [0.0f32; LANES];
            let mut sdiag = [0.0f32; LANES];
            for &s in slot.iter().take(n) {
                let (lo, hi) = get(&lanes.rows, s);
                if r < usize::from(lo) || r > usize::from(hi) {
                    continue;
                }
                let x = filter.mean();
                let z: f32 = (0..r_used)
                    .map(|j| {
                        get(&c, j)
                            * x.get(TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0))
                                .copied()
                                .unwrap_or(0.0)
                    })
                    .sum();
                set(&mut zhat, nr, z);
                set(
                    &mut sdiag,
                    nr,
                    quad(filter, s, s, &c, r_used) + rho * bss(s, s) + self.noise(b, pass.params.r),
                );
                set(&mut idx, nr, s);
                nr += 1;
            }
            let lambda = self.clutter(b, pass.params.clutter_density, cfg.clutter_floor);
            let params = RowParams {
                clutter_density: lambda,
                r: self.noise(b, pass.params.r),
                ..pass.params
            };
            let out = row::associate(
                &zhat,
                &sdiag,
                |a, bb| {
                    let (s, t) = (get(&idx, a), get(&idx, bb));
                    quad(filter, s, t, &c, r_used) + rho * bss(s, t)
                },
                nr,
                pts,
                &params,
                pass.max_events,
                0,
            );
            failed += u32::from(out.failed);
            // Explained points.
            let mut ex = 0u32;
            for j in 0..m {
                let tot: f32 = out.beta.iter().take(nr).map(|row| get(row, j)).sum();
                if tot >= cfg.explained {
                    ex |= 1 << j;
                }
            }
            if let Some(e) = explained.get_mut(r) {
                *e |= ex;
            }
            if let Some(un) = unexplained.get_mut(b) {
                *un += (m as u32 - ex.count_ones()) as f32;
            }
            // Evidence and detection counts per lane.
            for a in 0..nr {
                let s = get(&idx, a);
                let Some(e) = ev.get_mut(s) else {
                    continue;
                };
                let w = (1.0 - get(&out.beta_miss, a)).clamp(0.0, 1.0);
                let brow = out.beta.get(a).copied().unwrap_or([0.0; MAX_ROW_POINTS]);
                let st = get(&sdiag, a);
                let zh = get(&zhat, a);
                // In view: inside the band's span of points this frame.
                let [vlo, vhi] = self.span.get(b).copied().unwrap_or([0.0; 2]);
                let in_view = zh >= vlo && zh <= vhi;
                // IPDA likelihood ratio of the row.
                let pd = pd0.get(s).map_or(0.5, |row| get(row, b));
                // Each gated point counts as far as no other lane claims it (JIPDA-style).
                let lr = 1.0 - pd * params.pg + pd * get(&out.dens, a) / lambda;
                if in_view && lr.is_finite() && lr > 0.0 {
                    e.llr += math::ln(lr);
                }
                if let Some(rw) = self.rows.get_mut(s).and_then(|rs| rs.get_mut(r)) {
                    *rw = [0.0; 2];
                }
                if w > 1e-6 && !out.failed {
                    let zbar: f32 = pts
                        .iter()
                        .zip(brow.iter())
                        .map(|(z, bj)| z * bj)
                        .sum::<f32>()
                        / w;
                    // For the noise estimate: the row's dominant point, when it holds ≥ 90 % of
                    // the lane's weight (a mixture with clutter would count clutter as noise).
                    let (jd, bd) =
                        brow.iter()
                            .take(m)
                            .enumerate()
                            .fold(
                                (0usize, 0.0f32),
                                |acc, (j, v)| if *v > acc.1 { (j, *v) } else { acc },
                            );
                    if bd >= 0.9 * w {
                        if let Some(rw) = self.rows.get_mut(s).and_then(|rs| rs.get_mut(r)) {
                            *rw = [pts.get(jd).copied().unwrap_or(zbar), bd];
                        }
                    }
                    // The row's PDA update of this lane's marginal as one equivalent
                    // measurement (docs/design.md §11.3): with the row prior variance
                    // p = S − r, ν̄ = Σ β_j ν_j and the spread Σ β_j ν_j² − ν̄², the PDA
                    // posterior variance p − W p²/S + p² spread/S² equals that of a
                    // measurement of variance v, 1/(p + v) = W/S − spread/S², at
                    // ẑ + ν̄ (p + v)/S.
                    let mut nbar = 0.0f32;
                    let mut n2 = 0.0f32;
                    for (z, bj) in pts.iter().zip(brow.iter()) {
                        let d = z - zh;
                        nbar += bj * d;
                        n2 += bj * d * d;
                    }
                    let spread = (n2 - nbar * nbar).max(0.0);
                    let q = w / st - spread / (st * st);
                    let p_row = st - params.r;
                    let var = if q > 0.0 {
                        1.0 / q - p_row
                    } else {
                        f32::INFINITY
                    };
                    let zt = zh + nbar / (q * st);
                    let om = 1.0 / var;
                    if om.is_finite() && om > 0.0 && zt.is_finite() {
                        for j in 0..r_used {
                            let cj = get(&c, j);
                            if let Some(iv) = e.i.get_mut(j) {
                                *iv += om * zt * cj;
                            }
                            for k in 0..r_used {
                                if let Some(jv) = e.j.get_mut((j, k)) {
                                    *jv += om * cj * get(&c, k);
                                }
                            }
                        }
                        e.weight += w;
                        if w >= 0.5 {
                            e.extent[0] = e.extent[0].min(u);
                            e.extent[1] = e.extent[1].max(u);
                        }
                    }
                }
                if let (true, Some(ls)) = (in_view, self.lanes.get_mut(s)) {
                    if let (Some(hb), Some(lb)) = (ls.hits.get_mut(b), ls.looks.get_mut(b)) {
                        *hb += w;
                        *lb += 1.0;
                    }
                }
            }
        }
        if estimate_clutter {
            let a = if cfg.clutter_memory > 1.0 {
                1.0 / cfg.clutter_memory
            } else {
                1.0
            };
            for b in 0..POINTS {
                let rows = get(&band_rows, b);
                if rows <= 0.0 {
                    continue;
                }
                let [lo, hi] = self.span.get(b).copied().unwrap_or([0.0; 2]);
                let width = if hi > lo { (hi - lo).max(1.0) } else { 1.0 };
                let est = get(&unexplained, b) / (rows * width);
                if let Some(c) = self.clutter.get_mut(b) {
                    *c = if c.is_finite() {
                        *c + a * (est - *c)
                    } else {
                        est
                    };
                }
            }
        }
        failed
    }
}
