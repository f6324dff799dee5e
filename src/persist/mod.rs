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
//! `P ← P·e^{−T/τ_s}`; updated from the rows where the lane is in view, under the paint / gap
//! chain ([`PaintGap`], the default) or with `L = (1/K) Σ_r ln Λ_r`,
//! `Λ_r = 1 − P_D,b P_G + (P_D,b / λ_b) Σ_{j gated} N(z_j; ẑ, S) λ_b/ρ_{s,j}`,
//! `ρ_{s,j} = λ_b + Σ_{t≠s gating j} P_D P_t N(z_j; ẑ_t, S_tt)` (a point counts against clutter
//! and the other lanes' detections), as
//! `logit P += ln(p_v e^L + 1 − p_v)` (a frame may not show the lane at all). `P_D,b` is the
//! lane's own detection probability in index band `b` (Beta(1, 1) posterior mean of discounted
//! row weights, fixed over a pass); `λ_b` the band's clutter density from the points no known
//! lane explains; `r_b` the band's point variance from posterior residuals (§11.6).
//!
//! Points a known lane explains leave the rows; the spatial JPDACF runs on the rest and may
//! start new lanes only from them, except those the ray test ([`ray`], §11.10) finds to be the
//! image of a vertical structure.
//!
//! # Cost
//! Per row: `n·r` for the predictions, `n·r²` for the variances, at most `n(n−1)/2·r²` for the
//! cross terms of lanes with candidates, one bounded event enumeration; `POINTS` exponentials
//! and `POINTS·r` multiply-adds for the row basis; then per lane `O(r³)` and the temporal update
//! (`n_act²·r/2`); the noise estimate another `n·r²` per row with evidence.

use nalgebra::{SMatrix, SVector};

use crate::linalg::{get, set};
use crate::math;
use crate::spatial::row::{Association, RowParams};

mod associate;
pub mod ray;
mod rows;

pub use associate::{Explained, Lanes};
pub use ray::{apart, parallel, ray_stat, vertical, RayStat, RayVerdict};
pub use rows::{row_basis, PassMemory, RowBasis};

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
    /// A lane is published while its existence is at least this (a new lane may wait up to
    /// `1 + newcomer_wait` frames, docs/design.md §11.5; see `StepOutput::filtered`).
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
    /// Consecutive misses that delete a tentative spatial track with a hit (the spatial
    /// filter's `tentative_gap_misses` while this stage is on): the rows of the longest dash gap
    /// a new lane's track bridges within a frame. 11 rows of the reference tables (1.283 m
    /// each) bridge 12 m, the longest gap of the common dash standards (docs/design.md §11.8);
    /// with the spatial default 8 (10.3 m) no lane with 12 m gaps and short dashes could start.
    pub gap_misses: u16,
    /// Scale of the spatial filter's row-to-row process noise while this stage is on (the
    /// spatial filter's `row_noise_scale`, docs/design.md §11.12): the maximum of the
    /// state-space likelihood of the bundled `0313` label lanes under the table's spatial model
    /// (`stjpdacf row-noise`, 0.0434; [`PersistConfig::DEFAULT`] rounds it to 0.043). Labelled lanes are about 23× smoother from row to row
    /// than the `N_T = 2` approximation of the RBF; with the table's noise a new lane's track
    /// bends so freely across a dash gap that the next dash's points do not count against
    /// clutter.
    pub row_noise_scale: f32,
    /// Frames of memory of the process-noise scale's adaptation (0: no adaptation; 1, the
    /// default since stop 57: `ln s` takes each frame's Fisher-scoring estimate, docs/design.md
    /// §11.7; 2 until then, which lets a vehicle's yaw outrun the scale).
    pub q_memory: f32,
    /// Probability that a lane that exists is visible in a frame (not occluded, not blurred
    /// out): the rows' evidence of a frame counts only in that case (docs/design.md §11.5).
    /// Default 0.9.
    pub p_visible: f32,
    /// Memory, in frames, of the estimate of a lane's lateral offset common to its rows in one
    /// frame (docs/design.md §11.4: the edge of a marking the detector sees, a camera's pitch
    /// or roll jitter): `σ_o` is estimated from the lanes' consecutive mean innovations and
    /// marginalised from each lane's row information before the temporal update, so that a
    /// frame's offset does not move the lane as motion. 20 by default (chosen a priori, about a
    /// second at 15–30 fps; not swept); 0 turns the term off (as before stop 59).
    pub frame_offset_memory: f32,
    /// Memory, in frames, of the estimate of the paint / gap chain's mean gap (docs/design.md
    /// §11.5, "The chain's gap, estimated"): the expected gap rows and gap → paint transitions
    /// of the published lanes' rows under the chain (forward-only smoothing, one EM step a
    /// frame), discounted by `1 − 1/chain_memory` a frame, with [`PaintGap::gap`] as the prior
    /// worth one transition. 20 by default (chosen a priori, as `frame_offset_memory`; not
    /// swept); 0 keeps the prior's gap (as before stop 60).
    pub chain_memory: f32,
    /// Two lanes closer than this on average over their common observed extent are one
    /// marking (docs/design.md §11.9), metres: half of a 2 m minimum spacing of markings.
    pub min_spacing: f32,
    /// The narrowest lane (docs/design.md §11.14), metres: two lane boundaries are at least a
    /// lane apart, so a lane that would be published closer than this (over the common observed
    /// extent) to a published lane on either side lies inside a lane, and of two such lanes
    /// with no published lane beyond the outer one, the outer bounds no lane (a kerb, a road
    /// edge or a vehicle's side beside the outermost marking): tracked, not published. 2.5 m
    /// by default (chosen a priori: the narrowest lanes of road design standards, 2.5–2.75 m;
    /// not swept); 0 turns the rule off (as before stop 63).
    pub lane_width: f32,
    /// Lowest detection probability per row of a lane that exists and is in view
    /// (docs/design.md §11.5): a lane's own `P_D,b` is used no lower than this. Without it a
    /// track that is never detected learns `P_D → 0` and its misses stop counting, so clutter
    /// keeps it alive: existence and detection probability cannot both be learned from the
    /// same misses.
    pub pd_floor: f32,
    /// The detection probability of a lane in its rows' joint events (docs/design.md §11.3):
    /// `true` (the default since stop 56), the lane's own `P_D,b` (the estimate above, no lower
    /// than `pd_floor`), so that a sparse dashed marking does not claim the clutter in its gaps
    /// as a solid line would; `false`, the spatial stage's `P_D` for every lane (until stop 55).
    pub own_pd: bool,
    /// How each row's joint events are weighed (docs/design.md §11.3): exact enumeration with
    /// pruning over the budget, LBP over the budget (the default, `ExactOrLbp`), or LBP
    /// everywhere.
    pub association: Association,
    /// The ray test (docs/design.md §11.10, [`ray`]): a lane consistent with a straight line
    /// through the camera's foot point (the BEV origin) within `ray_z` standard deviations, in
    /// offset and in curvature, is the image of a vertical structure (a vehicle's side, a pole),
    /// not paint: it starts no lane, and a live lane found so is deleted unless it runs parallel
    /// to a lane found to be paint (the marking under the camera in a lane change). 0 turns the
    /// test off; 3 by default (the conventional 3σ, not fitted).
    pub ray_z: f32,
    /// The test decides only when the line's offset at the foot point is known to this standard
    /// deviation or better, metres: 0.5, a third of 1.5 m, the smallest offset of a marking
    /// from a camera inside its lane.
    pub ray_resolution: f32,
    /// A lane consistent with a ray whose test is not decisive ([`RayVerdict::Aligned`]) is a
    /// vertical structure when it runs parallel to none of the lanes found to be paint and is
    /// tested against one at least ([`vertical`], docs/design.md §11.10): markings are
    /// parallel, a vehicle's side seen from 8 m or more is a ray whose offset at the foot point
    /// is not resolved to 0.5 m. `true` by default; `false` acts on decisive rays only (before
    /// stop 42).
    pub ray_aligned: bool,
    /// A live lane whose offset at the camera's foot point moves (its rate from the temporal
    /// state, `ray_z` standard deviations from zero) is not deleted as a vertical structure
    /// (docs/design.md §11.10): the marking under the camera in a lane change. `true` by default.
    pub ray_motion: bool,
    /// Slots by existence (docs/design.md §11.13): a new lane whose track's evidence is
    /// positive and that finds every slot taken takes the slot of the unmatched lane of lowest
    /// existence below `p_birth`. `true` by default; `false` turns such a lane away (before
    /// stop 43).
    pub slot_claims: bool,
    /// Lanes do not cross, and no marking joins two others (docs/design.md §11.11): a live lane
    /// that crosses or touches two published lanes which do not meet each other is the track
    /// of no marking and is removed. `true` by default.
    pub connectors: bool,
    /// Consecutive frames a lane must be a connector before it is removed: 2 (one frame can be
    /// a transient mis-association; chosen on the replay's robustness curve and the soak's
    /// drives, docs/design.md §11.11).
    pub connector_frames: u8,
    /// While other lanes are tracked, a lane at its first publication that is not yet shown to
    /// be a marking of its own — it runs parallel to none of the lanes found to be paint, or it
    /// lies within `2 · min_spacing` of a lane published before and seen this frame — is held,
    /// for at most this many frames (docs/design.md §11.5): 2 by default (a lane that passes
    /// the tests, or has waited this long, is published); 0 turns the rule off. Chosen on the
    /// bundled replay's lane ids (1 and 3 measured, design §11.5).
    pub newcomer_wait: u8,
    /// The existence evidence of a known lane's rows (docs/design.md §11.5): `Some` (the
    /// default, [`PaintGap::HIGHWAY`]), the likelihood ratio of the rows under a paint / gap
    /// chain along the lane ([`PaintGap`]), not discounted; `None`, `(1/K) Σ_r ln Λ_r` at the
    /// lane's learned `P_D,b`, the K rows of an index interval counted as one look (the
    /// default until stop 41: fewer lane ids on structured clutter, fewer sparse dashed lanes
    /// found in dense clutter; docs/measurements.md, "Held-out check").
    pub paint_gap: Option<PaintGap>,
}

/// A lane's rows as a two-state chain, paint and gap (docs/design.md §11.5): on paint a row
/// detects the marking with probability `p_on`, in a gap not at all; painted stretches and gaps
/// have mean lengths `paint` and `gap` metres (exponential), so that hits in runs count fully
/// and an isolated hit pays for a switch onto paint. The rows' likelihood ratio against "its
/// gated points are clutter or other lanes'" is the forward recursion's total.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PaintGap {
    /// Detection probability of a row on paint.
    pub p_on: f32,
    /// Mean length of a painted stretch, m.
    pub paint: f32,
    /// Mean length of a gap, m.
    pub gap: f32,
}

impl PaintGap {
    /// US highway dashes, 10 ft of paint and 30 ft of gap (3 m / 9 m, 25 % paint), seen by a
    /// detector that finds 80 % of the painted rows: the assumptions behind `pd_floor` = 0.2
    /// (docs/design.md §11.5). A solid line is a long run of paint. Not fitted to any data.
    pub const HIGHWAY: Self = Self {
        p_on: 0.8,
        paint: 3.0,
        gap: 9.0,
    };

    /// The chain's per-row constants for rows `du` metres apart, or `None` when a parameter is
    /// not a finite positive number (`p_on` in (0, 1]): the pass then uses the per-interval
    /// evidence.
    pub fn rates(&self, du: f32) -> Option<ChainRates> {
        let ok = |v: f32| v.is_finite() && v > 0.0;
        if !(ok(self.p_on) && self.p_on <= 1.0 && ok(self.paint) && ok(self.gap) && ok(du)) {
            return None;
        }
        let to_off = (du / self.paint).min(0.95);
        let to_on = (du / self.gap).min(0.95);
        Some(ChainRates {
            p_on: self.p_on,
            to_off,
            to_on,
            pi_on: self.paint / (self.paint + self.gap),
        })
    }
}

/// [`PaintGap`]'s per-row constants: the transition probabilities between neighbouring rows in
/// view (`du/paint` and `du/gap`, at most 0.95) and the stationary share of paint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChainRates {
    /// Detection probability of a row on paint.
    pub p_on: f32,
    /// P(gap at the next row | paint).
    pub to_off: f32,
    /// P(paint at the next row | gap).
    pub to_on: f32,
    /// Stationary P(paint), the chain's start.
    pub pi_on: f32,
}

impl PersistConfig {
    /// The defaults: 10 frames of detection memory, 5 of clutter memory, clutter floor
    /// 0.005 /m, `τ_s` = 10 s, `P_birth` = 0.1, publish at 0.5, delete below 0.01, a point
    /// explained at 0.5, the ray test at 3σ and 0.5 m with aligned lanes decided by their
    /// direction, new lanes' dash gaps of 11 rows and their row noise scaled by 0.043 (fitted,
    /// design §11.12), the rows' existence evidence under the highway paint / gap chain, the
    /// process-noise scale at each frame's Fisher-scoring estimate (`q_memory` 1).
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
        gap_misses: 11,
        row_noise_scale: 0.043,
        q_memory: 1.0,
        p_visible: 0.9,
        frame_offset_memory: 20.0,
        chain_memory: 20.0,
        min_spacing: 1.0,
        lane_width: 2.5,
        pd_floor: 0.2,
        own_pd: true,
        association: Association::ExactOrLbp,
        ray_z: 3.0,
        ray_resolution: 0.5,
        ray_aligned: true,
        ray_motion: true,
        slot_claims: true,
        connectors: true,
        connector_frames: 2,
        newcomer_wait: 2,
        paint_gap: Some(PaintGap::HIGHWAY),
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
    /// The last frame's mean innovation of the lane's rows and its predicted variance
    /// without the frame offset, `[m, a]` (`a = 0`: the lane had no rows that frame), for the
    /// frame offset's estimate ([`Persist::update_frame_offset`]).
    pub innovation: [f32; 2],
}

impl<const POINTS: usize> LaneState<POINTS> {
    /// A lane with no history.
    pub const NEW: Self = Self {
        passes: 0,
        hits: [0.0; POINTS],
        looks: [0.0; POINTS],
        existence: 0.0,
        innovation: [0.0; 2],
    };

    /// `P_D` in band `b`: the Beta(1, 1) posterior mean.
    pub fn pd(&self, b: usize) -> f32 {
        (get(&self.hits, b) + 1.0) / (get(&self.looks, b) + 2.0)
    }
}

/// `ln 10⁴`: the process-noise scale's upper bound (docs/design.md §11.7).
const LN_MAX_Q_SCALE: f32 = 9.210_34;

/// The frame offset's estimate winsorises `Δ²` at `WINSOR` times its variance (2 standard
/// deviations; docs/design.md §11.4).
const WINSOR: f32 = 4.0;

/// `E min(χ²₁, 4) = P(χ²₃ ≤ 4) + 4 P(χ²₁ > 4) = erf(√2) − √(8/π) e^{−2} + 4 erfc(√2)`: the
/// winsorised sample's mean in units of its variance.
const WINSOR_MEAN: f32 = 0.920_537;

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
    /// This frame's `(z_d, β_d)` per slot and row: the row's dominant point and its weight,
    /// when it holds ≥ 90 % of the lane's weight `W_r` (`β_d = 0`: nothing).
    rows: [[[f32; 2]; ROWS]; LANES],
    /// This frame's lateral span `[min, max]` of all points per band: where the sensor sees.
    pub span: [[f32; 2]; POINTS],
    /// `ln` of the process-noise scale (≥ 0).
    pub log_q_scale: f32,
    /// This frame's sums of the process-noise scale's score, its information and the degrees
    /// of freedom over the lanes counted ([`Persist::count_q_score`]).
    q_sums: [f32; 3],
    /// The estimate of the frame offset's variance `σ_o²` (m², ≥ 0) and its discounted
    /// information (docs/design.md §11.4).
    frame_offset: [f32; 2],
    /// The paint / gap chain's mean gap: discounted `[Σ E[metres in a gap], Σ E[gap → paint
    /// transitions]]` over the counted lanes' rows (docs/design.md §11.5).
    chain_gap: [f32; 2],
}

/// One frame's evidence for one lane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Evidence<const RANK: usize> {
    /// `J = Σ ω_r c_r c_rᵀ`.
    pub j: SMatrix<f32, RANK, RANK>,
    /// `i = Σ ω_r z̃_r c_r`.
    pub i: SVector<f32, RANK>,
    /// `Σ_r W_r` (expected detected rows) over the rows that gave information.
    pub weight: f32,
    /// `Σ_r ln Λ_r`, or with [`PersistConfig::paint_gap`] the log-likelihood ratio of the rows
    /// under the chain.
    pub llr: f32,
    /// `u` of the first and last rows with `W_r ≥ 0.5` that gave information (`[+∞, −∞]`
    /// when none): where the lane is seen (docs/design.md §11.8).
    pub extent: [f32; 2],
    /// With [`PersistConfig::paint_gap`]: the chain's forward probabilities (paint, gap) after
    /// the rows so far, normalised to sum 1 (their scale is in `llr`).
    pub chain: [f32; 2],
    /// Over the rows in view with `W_r > 0`, `[Σ_r f_r (Σ_j β_j ν_j²/S_r − W_r), Σ_r W_r f_r²]`
    /// with `f_r = (S_r − r_b)/S_r`: twice the score of the pass's likelihood in `ln s` (the
    /// process-noise scale) and twice its observed information (docs/design.md §11.7).
    pub q_score: [f32; 2],
    /// `k = Σ_r ω_r c_r` over the rows that gave information: the direction of a lateral offset
    /// common to the lane's rows in this frame (docs/design.md §11.4).
    pub k: SVector<f32, RANK>,
    /// `[w, ζ, ζ̂] = [Σ_r ω_r, Σ_r ω_r z̃_r, Σ_r ω_r ẑ_r]` over the same rows (`ẑ_r` the
    /// lane's predicted position in row `r`): `(ζ − ζ̂)/w` is the lane's mean innovation.
    pub offset: [f32; 3],
    /// With [`PersistConfig::paint_gap`]: the forward-only smoothing of the chain's additive
    /// statistics (Cappé 2011), `[ρ_N(paint), ρ_N(gap), ρ_T(paint), ρ_T(gap)]`: the expected
    /// gap → paint transitions and gap rows over the rows so far, given the current row's
    /// state and the rows (docs/design.md §11.5).
    pub chain_em: [f32; 4],
}

impl<const RANK: usize> Evidence<RANK> {
    /// `[E[T], E[N]]`: the expected gap rows and gap → paint transitions over the pass's rows
    /// in view under the chain, given all of them (docs/design.md §11.5): `Σ_x α(x) ρ(x)` of
    /// the forward-only smoothing in [`Evidence::chain_em`]. Zero without the chain.
    pub fn chain_expectations(&self) -> [f32; 2] {
        let [on, off] = self.chain;
        let [n_on, n_off, t_on, t_off] = self.chain_em;
        [on * t_on + off * t_off, on * n_on + off * n_off]
    }

    /// `(J', i')`: the information with the lane's frame offset `o ~ N(0, σ_o²)` marginalised
    /// (docs/design.md §11.4): the rows `z̃_r = c_rᵀ a + o + e_r` have the covariance
    /// `V + σ_o² 1 1ᵀ`, so `J' = J − σ_o² k kᵀ/(1 + σ_o² w)` and
    /// `i' = i − σ_o² ζ k/(1 + σ_o² w)`. `sd ≤ 0` (or not finite) returns `(J, i)`.
    ///
    /// # Complexity
    /// One outer product, `RANK²` multiply-adds.
    #[inline(never)]
    pub fn offset_marginal(&self, sd: f32) -> (SMatrix<f32, RANK, RANK>, SVector<f32, RANK>) {
        let s2 = sd * sd;
        let den = 1.0 + s2 * self.offset[0];
        if !(sd > 0.0 && s2.is_finite() && den.is_finite() && den > 0.0) {
            return (self.j, self.i);
        }
        let g = s2 / den;
        (
            self.j - self.k * self.k.transpose() * g,
            self.i - self.k * (g * self.offset[1]),
        )
    }

    /// No evidence.
    pub const NONE: Self = Self {
        j: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; RANK]; RANK])),
        i: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; RANK]; 1])),
        weight: 0.0,
        llr: 0.0,
        extent: [f32::INFINITY, f32::NEG_INFINITY],
        chain: [0.0, 1.0],
        q_score: [0.0; 2],
        k: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; RANK]; 1])),
        offset: [0.0; 3],
        chain_em: [0.0; 4],
    };
}

/// What one [`Persist::associate`] pass did over its rows.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PassCounts {
    /// Rows whose association failed numerically (every lane missed there).
    pub failed_rows: u32,
    /// Joint events scored by exact enumeration.
    pub events: u32,
    /// Rows over the event budget whose least likely candidates were dropped.
    pub pruned_rows: u32,
    /// Rows weighed by LBP marginals.
    pub lbp_rows: u32,
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
        let mut p = Self::ZEROED;
        p.mark_unestimated();
        p
    }

    /// Every byte zero (the tracker's all-zero constant, which lives in `.bss`): [`Persist::new`]
    /// before [`Persist::mark_unestimated`].
    pub(crate) const ZEROED: Self = Self {
        lanes: [LaneState::NEW; LANES],
        clutter: [0.0; POINTS],
        noise: [[0.0; 2]; POINTS],
        rows: [[[0.0; 2]; ROWS]; LANES],
        span: [[0.0; 2]; POINTS],
        log_q_scale: 0.0,
        q_sums: [0.0; 3],
        frame_offset: [0.0; 2],
        chain_gap: [0.0; 2],
    };

    /// The clutter densities not yet estimated (`NaN`), the spans empty. O(POINTS).
    pub(crate) const fn mark_unestimated(&mut self) {
        self.clutter = [f32::NAN; POINTS];
        self.span = [[f32::INFINITY, f32::NEG_INFINITY]; POINTS];
    }

    /// Whether slot `s` teaches the stage's shared estimates (the process-noise scale, the
    /// frame offset, the chain's gap): published (`P ≥ p_publish`) and through at least two
    /// known-lane passes (a new lane's velocity is unknown; a lane on a distractor is not
    /// published).
    pub fn counts(&self, s: usize, p_publish: f32) -> bool {
        self.lanes
            .get(s)
            .is_some_and(|l| l.passes >= 2 && l.existence >= p_publish)
    }

    /// The temporal process-noise scale `e^{log_q_scale}` (≥ 1).
    pub fn q_scale(&self) -> f32 {
        math::exp(self.log_q_scale.max(0.0))
    }

    /// Counts one lane's [`Evidence::q_score`] with `dof` degrees of freedom (lanes through at
    /// least two known-lane passes only: a new lane's velocity is unknown). Only lanes that are
    /// published (`P ≥ p_publish`) count, and each lane's score is capped at twice its
    /// information (its own estimate of the scale at most 3× the current one): one lane gone
    /// astray must not inflate every lane's process noise.
    pub fn count_q_score(&mut self, s: usize, score: [f32; 2], dof: f32, p_publish: f32) {
        let ok = self.counts(s, p_publish);
        let [g, i] = score;
        if ok && g.is_finite() && i.is_finite() && i > 0.0 {
            self.q_sums[0] += g.min(2.0 * i);
            self.q_sums[1] += i;
            self.q_sums[2] += dof;
        }
    }

    /// Adapts the process-noise scale `s` to this frame's rows (docs/design.md §11.7): one
    /// Fisher-scoring step of the rows' PDA likelihood in `s`, `ŝ = s·(1 + Σ score / Σ
    /// information)` (each row's points weighed by their association probabilities against its
    /// own predicted variance), then `ln s += (ln ŝ − ln s) / memory` with `ŝ` and `s` kept in
    /// `[1, 10⁴]`. Nothing changes with fewer than `min_dof` degrees of freedom.
    pub fn adapt_q_scale(&mut self, memory: f32, min_dof: f32) {
        let [g, i, n] = self.q_sums;
        if n >= min_dof && i > 0.0 && g.is_finite() && i.is_finite() {
            let ratio = math::max(1.0 + g / i, 0.0);
            let s = self.log_q_scale.clamp(0.0, LN_MAX_Q_SCALE);
            let target = math::ln(math::max(ratio * math::exp(s), 1.0)).clamp(0.0, LN_MAX_Q_SCALE);
            let step = (target - s) / memory.max(1.0);
            if step.is_finite() {
                self.log_q_scale = (s + step).clamp(0.0, LN_MAX_Q_SCALE);
            }
        }
        self.q_sums = [0.0; 3];
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
            let b = rows::band::<POINTS>(r, k_rows);
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
        math::max((s + 2.0 * fallback) / (n + 2.0), 1e-5)
    }

    /// The clutter density of band `b`, or `fallback` before the first estimate.
    pub fn clutter(&self, b: usize, fallback: f32, floor: f32) -> f32 {
        let c = get(&self.clutter, b);
        if c.is_finite() {
            math::max(c, floor)
        } else {
            math::max(fallback, floor)
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

    /// Seeds slot `s`'s detection counts from its birth track (docs/design.md §11.5): `k` looks
    /// (the rows of one index interval) at the track's hit rate `rate` in every band, so the
    /// lane's first known-lane pass uses the rate its own rows showed instead of the prior mean
    /// 0.5 (a sparse dashed marking is not charged a solid line's misses).
    #[inline(never)]
    pub fn seed_pd(&mut self, s: usize, rate: f32, k: f32) {
        if let Some(l) = self.lanes.get_mut(s) {
            let rate = if rate.is_finite() {
                rate.clamp(0.0, 1.0)
            } else {
                0.5
            };
            let k = if k.is_finite() { k.max(0.0) } else { 0.0 };
            for (h, n) in l.hits.iter_mut().zip(l.looks.iter_mut()) {
                *h = k * rate;
                *n = k;
            }
        }
    }

    /// The estimated standard deviation `σ_o` of a lane's frame offset, metres (0 until
    /// estimated; docs/design.md §11.4).
    pub fn frame_offset_sd(&self) -> f32 {
        math::sqrt(self.frame_offset[0].max(0.0))
    }

    /// One frame of the frame offset's estimate (docs/design.md §11.4) from `innovation[s] =
    /// [m_s, a_s]`: lane `s`'s mean innovation over its rows and its predicted variance without
    /// the offset (`a_s ≤ 0`: no rows this frame). Every lane with rows in this frame and the
    /// last gives `Δ = m_t − m_{t−1}`, whose variance is `V = a_t + a_{t−1} + 2σ_o²` (the
    /// innovations of a consistent filter are white; the offset is drawn anew each frame). The
    /// sample `e = ½(min(Δ², 4V)/0.9205 − a_t − a_{t−1})` (Δ² winsorised at 2 standard
    /// deviations, `0.9205 = E min(χ²₁, 4)` restoring the mean: a lane that jumps to another
    /// marking counts as a 2σ sample, not as its jump) enters a Fisher-scoring step with weight `1/V²`, its
    /// information discounted by `1 − 1/memory` a frame; the estimate stays ≥ 0. `memory ≤ 0`
    /// (or not finite) leaves the estimate as it is and only records the innovations.
    ///
    /// # Complexity
    /// `LANES` steps of a few flops.
    #[inline(never)]
    pub fn update_frame_offset(&mut self, innovation: &[[f32; 2]; LANES], memory: f32) {
        let [var, info] = self.frame_offset;
        let mut acc = [0.0f32; 2];
        for (l, &[m, a]) in self.lanes.iter_mut().zip(innovation.iter()) {
            let [m0, a0] = l.innovation;
            let ok = a > 0.0 && m.is_finite() && a.is_finite();
            l.innovation = if ok { [m, a] } else { [0.0; 2] };
            if !(ok && a0 > 0.0) {
                continue;
            }
            let a2 = a + a0;
            let v = a2 + 2.0 * var;
            let d2 = (m - m0) * (m - m0);
            let e = 0.5 * (d2.min(WINSOR * v) / WINSOR_MEAN - a2);
            let w = 1.0 / (v * v);
            let t = (e - var) * w;
            if t.is_finite() && w.is_finite() {
                acc[0] += t;
                acc[1] += w;
            }
        }
        if !(memory > 0.0 && memory.is_finite()) {
            return;
        }
        let info = info * (1.0 - 1.0 / memory.max(1.0)) + acc[1];
        let var = var + acc[0] / info;
        if info > 0.0 && info.is_finite() && var.is_finite() {
            self.frame_offset = [var.max(0.0), info];
        }
    }

    /// The paint / gap chain's mean gap, metres: `(Σ E[T] + gap0)/(Σ E[N] + 1)`, the discounted
    /// expected gap metres and gap → paint transitions of the lanes counted
    /// ([`Persist::update_chain_gap`]) with the prior `gap0` as one transition's worth
    /// (docs/design.md §11.5). `gap0` when the sums are not usable.
    pub fn chain_gap(&self, gap0: f32) -> f32 {
        let [t, n] = self.chain_gap;
        let g = (t + gap0) / (n + 1.0);
        if g.is_finite() && g > 0.0 {
            g
        } else {
            gap0
        }
    }

    /// One frame of the chain's gap estimate (docs/design.md §11.5): the sums are discounted
    /// by `1 − 1/memory` and gain each counted lane's `stats[s] = [E[T], E[N]]`, its expected
    /// gap rows and gap → paint transitions over this frame's rows in view
    /// ([`Evidence::chain_expectations`]; `[0, 0]` for a lane not counted), `T` in metres at
    /// `du` a row. `memory ≤ 0` (or not finite) leaves the estimate at its prior.
    ///
    /// # Complexity
    /// `LANES` steps of a few flops.
    pub fn update_chain_gap(&mut self, stats: &[[f32; 2]; LANES], du: f32, memory: f32) {
        if !(memory > 0.0 && memory.is_finite() && du > 0.0 && du.is_finite()) {
            return;
        }
        let d = 1.0 - 1.0 / memory.max(1.0);
        let [mut t, mut n] = self.chain_gap;
        t *= d;
        n *= d;
        for &[et, en] in stats {
            let (tm, nn) = (et * du, en);
            if tm.is_finite() && nn.is_finite() && tm >= 0.0 && nn >= 0.0 {
                t += tm;
                n += nn;
            }
        }
        if t.is_finite() && n.is_finite() {
            self.chain_gap = [t, n];
        }
    }

    /// Clears slot `s`.
    pub fn remove(&mut self, s: usize) {
        set(&mut self.lanes, s, LaneState::NEW);
    }
}

#[cfg(test)]
mod paint_gap_tests {
    use super::PaintGap;

    #[test]
    fn highway_rates_and_refused_parameters() {
        let c = PaintGap::HIGHWAY.rates(1.5).expect("valid");
        assert_eq!(
            (c.p_on, c.to_off, c.to_on, c.pi_on),
            (0.8, 0.5, 1.5 / 9.0, 0.25)
        );
        // Rows farther apart than a dash: the transitions are capped below 1.
        let far = PaintGap::HIGHWAY.rates(10.0).expect("valid");
        assert_eq!((far.to_off, far.to_on), (0.95, 0.95));
        for bad in [
            PaintGap {
                p_on: 1.5,
                ..PaintGap::HIGHWAY
            },
            PaintGap {
                p_on: 0.0,
                ..PaintGap::HIGHWAY
            },
            PaintGap {
                paint: f32::NAN,
                ..PaintGap::HIGHWAY
            },
            PaintGap {
                gap: 0.0,
                ..PaintGap::HIGHWAY
            },
            PaintGap {
                gap: f32::INFINITY,
                ..PaintGap::HIGHWAY
            },
        ] {
            assert_eq!(bad.rates(1.5), None, "{bad:?}");
        }
        assert_eq!(PaintGap::HIGHWAY.rates(0.0), None);
    }
}
