//! The known-lane stage in dense f64 (docs/design.md §11.3–11.5): the temporal prediction of the
//! live lanes is the prior of a frame's association, each lane's row evidence is summed in
//! information form on its Gram components, and the lane's existence gets the rows' likelihood
//! ratios.
//!
//! Written from the design text with dynamic nalgebra matrices; nothing here uses the core crate.
//! Everything is exact: all joint events of a row are enumerated ([`crate::jpda::row_step_with_pd`], no
//! budget `E`, no pruning; or, as the core's `Association::Lbp`, every row weighed by LBP,
//! [`RowWeights::Lbp`]), the basis is computed in f64 from the Gram eigenpairs of
//! [`ModelTables`], and the temporal update ([`info_update`]) is the textbook Kalman update of the
//! whole dense state with an equivalent measurement, not the core's Woodbury algebra.
//!
//! * [`row_basis`] — the GP conditional at `u` on the Gram eigenbasis (§11.3, §4.2.5):
//!   `k_i = σ_u² exp(−(u − u^f_i)²/2ℓ_u²)`, `c_j = (k·v_j)/λ_j` (`j < r`, the tables'
//!   `gram_rank`), `ρ = (σ_u² − Σ_j (k·v_j)²/λ_j)⁺`;
//! * [`bin_rows`], [`band_spans`] — the frame's rows (§4.1, §7.1: row `round((u − u_min)/Δu)`,
//!   ties to even) with their bands `b = ⌊(r + K/2)/K⌋` and each band's lateral span (§11.1);
//! * [`known_lane_pass`] — per row the lanes' predictions `ẑ_s = c_rᵀ a_s` with the joint
//!   innovation covariance (`S_ss = c_rᵀ Cov(a_s) c_r + ρ_r B_ρ(s)ρ(s) + r_b`, `S_st = c_rᵀ
//!   Cov(a_s, a_t) c_r + ρ_r B_ρ(s)ρ(t)`), the exact JPDA probabilities `β` of §4.1 step 3 with the
//!   band's clutter density `λ_b` and point variance `r_b`, each lane's equivalent measurement
//!   `(v, z̃)` and information `J_s = Σ_r c_r c_rᵀ / v_r`, `i_s = Σ_r c_r z̃_r / v_r`, its
//!   existence log-likelihood ratio `Σ_r ln Λ_r` over the rows in view (§11.5), and the points
//!   the known lanes explain (`Σ_s β_{s,j} ≥ explained`);
//! * [`info_update`] — the Kalman update of a dense Gaussian state by information `(J, i)` on a
//!   subset of its entries (a lane's position coefficients), §11.4.

use anyhow::{ensure, Context, Result};
use nalgebra::{DMatrix, DVector};

use crate::jpda::{self, MissConvention, RowParams};
use crate::model::ModelTables;

/// The GP conditional's row vector at `u` (docs/design.md §11.3 and §4.2.5): with
/// `k_i = σ_u² exp(−(u − u^f_i)²/2ℓ_u²)` over the index points and the Gram eigenpairs
/// `(λ_j, v_j)` (decreasing), `c_j = (k·v_j)/λ_j` for `j < r` (`r` = the tables' `gram_rank`) and
/// the prior's residual variance `ρ = (σ_u² − Σ_j (k·v_j)²/λ_j)⁺`. The lane's position at `u` is
/// `cᵀ a`, its variance `cᵀ Cov(a) c + ρ B_ρρ`. A component with `λ_j ≤ 0` (none within the
/// rank) gets `c_j = 0` and explains nothing.
pub fn row_basis(model: &ModelTables, u: f64) -> (DVector<f64>, f64) {
    let var = model.hyper.spatial.variance;
    let l = model.hyper.spatial.lengthscale;
    let n = model.index_u.len();
    let r = model.gram_rank.min(n);
    let k = DVector::from_fn(n, |i, _| {
        let d = u - model.index_u[i];
        var * (-d * d / (2.0 * l * l)).exp()
    });
    let mut c = DVector::zeros(r);
    let mut explained = 0.0;
    for j in 0..r {
        let lam = model.gram_eigval[j];
        if lam <= 0.0 {
            continue;
        }
        let kv = k.dot(&model.gram_eigvec.column(j));
        c[j] = kv / lam;
        explained += kv * kv / lam;
    }
    (c, (var - explained).max(0.0))
}

/// One BEV row of a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// `u_r = u_min + r·Δu`, metres.
    pub u: f64,
    /// Its band: the nearest index point, `⌊(r + K/2)/K⌋` (at most `N − 1`).
    pub band: usize,
    /// The row's points (lateral positions), in input order.
    pub points: Vec<f64>,
}

/// The rows of docs/design.md §4.0/§4.1: `R = (N − 1)·K + 1` rows `u_r = u_min + r·Δu`,
/// `Δu = (u_max − u_min)/((N − 1)·K)`.
pub fn row_geometry(model: &ModelTables, k_rows: usize) -> (usize, f64) {
    let n = model.index_u.len();
    let k = k_rows.max(1);
    let w = &model.hyper.window;
    (
        (n - 1) * k + 1,
        (w.u_max - w.u_min) / ((n.max(2) - 1) * k) as f64,
    )
}

/// The band of row `r`: `⌊(r + K/2)/K⌋`, at most `bands − 1` (docs/design.md §11.1).
pub fn band_of(r: usize, k_rows: usize, bands: usize) -> usize {
    let k = k_rows.max(1);
    ((r + k / 2) / k).min(bands.saturating_sub(1))
}

/// Bins a frame's points `(u, x)` into the rows (docs/design.md §4.1, §7.1): row
/// `round((u − u_min)/Δu)` (ties to even); rejected, in this order: a non-finite coordinate, a row
/// outside `0..R`, a point within 1 mm laterally of one already kept in its row, a row already
/// holding `per_row` points.
pub fn bin_rows(
    model: &ModelTables,
    k_rows: usize,
    per_row: usize,
    points: &[(f64, f64)],
) -> Vec<Row> {
    let (n_rows, du) = row_geometry(model, k_rows);
    let u_min = model.hyper.window.u_min;
    let bands = model.index_u.len();
    let mut rows: Vec<Row> = (0..n_rows)
        .map(|r| Row {
            u: u_min + r as f64 * du,
            band: band_of(r, k_rows, bands),
            points: Vec::new(),
        })
        .collect();
    for &(u, x) in points {
        if !(u.is_finite() && x.is_finite()) {
            continue;
        }
        let rf = ((u - u_min) / du).round_ties_even();
        if !(rf >= 0.0 && rf < n_rows as f64) {
            continue;
        }
        let row = &mut rows[rf as usize];
        if row.points.iter().any(|y| (x - y).abs() <= 1e-3) || row.points.len() >= per_row {
            continue;
        }
        row.points.push(x);
    }
    rows
}

/// Each band's lateral span `[min x, max x]` over all its rows' points (docs/design.md §11.1):
/// where the sensor sees at that distance; `None` for a band without points.
pub fn band_spans(rows: &[Row], bands: usize) -> Vec<Option<(f64, f64)>> {
    let mut spans: Vec<Option<(f64, f64)>> = vec![None; bands];
    for row in rows {
        let Some(sp) = spans.get_mut(row.band) else {
            continue;
        };
        for &z in row.points.iter().filter(|z| z.is_finite()) {
            *sp = Some(match *sp {
                None => (z, z),
                Some((lo, hi)) => (lo.min(z), hi.max(z)),
            });
        }
    }
    spans
}

/// One live lane as the known-lane pass sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct KnownLane {
    /// Predicted Gram coefficient mean `a_s` (length `r`).
    pub mean: DVector<f64>,
    /// B index (rank from the left, docs/design.md §4.0).
    pub rank: usize,
    /// Rows looked at, `[lo, hi]` inclusive (indices into the pass's rows).
    pub rows: (usize, usize),
    /// The lane's detection probability `P_D,b` per band (§11.5): its detections' weight in
    /// the joint events (§11.3) and in the existence update.
    pub pd: Vec<f64>,
    /// `P(exists)` before the pass: the weight `P_D · P` of the lane's detections as the other
    /// lanes' competitor in their existence evidence (§11.5).
    pub existence: f64,
}

/// A band's estimates (docs/design.md §11.6) and span (§11.1), inputs of the pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Band {
    /// Clutter density `λ_b`, points per metre per row.
    pub clutter: f64,
    /// Point variance `r_b`, m².
    pub noise: f64,
    /// Lateral span `[min, max]` of the frame's points in the band (`None`: no point).
    pub span: Option<(f64, f64)>,
}

/// The association constants of the pass (docs/design.md §4.1 steps 2–3, §11.3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassParams {
    /// `P_D` of the other lanes' detections as a lane's competitor in its existence evidence
    /// (§11.5), and of every lane in the joint events unless `own_pd`.
    pub pd: f64,
    /// The joint events weigh each lane's detections at its own [`KnownLane::pd`] (§11.3).
    pub own_pd: bool,
    /// `P_G`.
    pub pg: f64,
    /// Gate `γ` (inclusive, on each lane's marginal).
    pub gamma: f64,
    /// Miss factor convention.
    pub miss: MissConvention,
    /// A point whose `Σ_s β_{s,j}` reaches this is explained by the known lanes.
    pub explained: f64,
    /// How each row's marginals `β` are weighed.
    pub weights: RowWeights,
}

/// How the pass weighs a row's association (docs/design.md §11.3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RowWeights {
    /// Every joint event of the coupled likelihood, no budget.
    Exact,
    /// Loopy belief propagation on the uncoupled likelihood on every row
    /// ([`jpda::lbp_marginals_with_pd`]; the core's `Association::Lbp`).
    Lbp {
        /// Most message iterations.
        max_iterations: u32,
        /// The iteration stops once no point → track message moves by more than this.
        tolerance: f64,
    },
}

/// The paint / gap chain of a lane's rows for its existence evidence (docs/design.md §11.5):
/// on paint a row detects the marking with probability `p_on`, in a gap not at all; paint and
/// gap stretches of mean lengths `paint` and `gap` metres; rows `du` metres apart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaintGap {
    /// Detection probability of a row on paint.
    pub p_on: f64,
    /// Mean length of a painted stretch, m.
    pub paint: f64,
    /// Mean length of a gap, m.
    pub gap: f64,
    /// Row spacing, m.
    pub du: f64,
}

impl PaintGap {
    /// `(P(paint → gap), P(gap → paint), stationary paint share)` from one row in view to the
    /// next (each transition at most 0.95).
    pub fn rates(&self) -> (f64, f64, f64) {
        (
            (self.du / self.paint).min(0.95),
            (self.du / self.gap).min(0.95),
            self.paint / (self.paint + self.gap),
        )
    }
}

/// Everything [`known_lane_pass`] reads.
#[derive(Debug, Clone, Copy)]
pub struct PassInput<'a> {
    /// The lanes, in any order (outputs follow it).
    pub lanes: &'a [KnownLane],
    /// Joint covariance of the lanes' coefficients, `lanes.len()·r` square, block `(s, t)` =
    /// `Cov(a_s, a_t)` in the order of `lanes`.
    pub cov: &'a DMatrix<f64>,
    /// `B` (indexed by the lanes' ranks).
    pub coreg: &'a DMatrix<f64>,
    /// The frame's rows.
    pub rows: &'a [Row],
    /// Per band.
    pub bands: &'a [Band],
    /// Association constants.
    pub params: PassParams,
    /// `None`: the lanes' `llr` is `Σ_r ln Λ_r` at their `P_D,b`; `Some`: the log-likelihood
    /// ratio of their rows in view under the paint / gap chain (§11.5).
    pub paint_gap: Option<PaintGap>,
}

/// One lane in one row of the pass.
#[derive(Debug, Clone, PartialEq)]
pub struct LaneRow {
    /// Index of the row in the pass's rows.
    pub row: usize,
    /// Predicted position `ẑ = c_rᵀ a_s`.
    pub zhat: f64,
    /// Prior variance of the position, `p = c_rᵀ Cov(a_s) c_r + ρ_r B_ρρ`.
    pub p: f64,
    /// Marginal innovation variance `S_ss = p + r_b`.
    pub s: f64,
    /// `β_{s,j}` per point of the row.
    pub beta: Vec<f64>,
    /// `β_{s,miss}`.
    pub beta_miss: f64,
    /// `W = 1 − β_{s,miss}`.
    pub w: f64,
    /// `ν̄ = Σ_j β_{s,j} (z_j − ẑ)`.
    pub nu_bar: f64,
    /// `q₂ = Σ_j β_{s,j} (z_j − ẑ)² − ν̄²`.
    pub spread: f64,
    /// The equivalent measurement `(v, z̃)`: `1/(p + v) = W/S − q₂/S²`, `z̃ = ẑ + ν̄ (p + v)/S`;
    /// `None` when `W/S − q₂/S² ≤ 0` (no information).
    pub equivalent: Option<(f64, f64)>,
    /// Points in the lane's gate (`(z_j − ẑ)²/S_ss ≤ γ`).
    pub gated: Vec<bool>,
    /// `Σ_{j gated} N(z_j; ẑ, S_ss) · λ / (λ + Σ_{t ≠ s gating j} P_D P_t N(z_j; ẑ_t, S_tt))`:
    /// each point against clutter and the other lanes' detections (§11.5).
    pub gated_likelihood: f64,
    /// `ẑ` inside its band's span (§11.1).
    pub in_view: bool,
    /// `ln Λ_r` with the lane's `P_D,b` ([`log_likelihood_ratio`]); it enters the lane's `llr`
    /// only when `in_view`.
    pub log_lr: f64,
}

/// One lane's evidence of the pass.
#[derive(Debug, Clone, PartialEq)]
pub struct LaneEvidence {
    /// `J_s = Σ_r c_r c_rᵀ / v_r` (`r×r`).
    pub j: DMatrix<f64>,
    /// `i_s = Σ_r c_r z̃_r / v_r`.
    pub i: DVector<f64>,
    /// `Σ_r W_r` over the rows that gave information.
    pub weight: f64,
    /// `Σ_r ln Λ_r` over the rows in view.
    pub llr: f64,
    /// The process-noise scale's score and information over the rows in view with `W_r > 0`
    /// (docs/design.md §11.7): `(Σ_r f_r (Σ_j β_{s,j} ν_j²/S_ss − W_r), Σ_r W_r f_r²)`,
    /// `f_r = p/S_ss`.
    pub q_score: (f64, f64),
    /// `k_s = Σ_r c_r / v_r`, `w_s = Σ_r 1/v_r`, `ζ_s = Σ_r z̃_r / v_r` and `ζ̂_s = Σ_r ẑ_r /
    /// v_r` over the same rows as `J_s`: what [`offset_marginal`] needs, and the lane's mean
    /// innovation `(ζ_s − ζ̂_s)/w_s` ([`FrameOffset`]).
    pub offset: (DVector<f64>, f64, f64, f64),
    /// With the paint / gap chain: `ln` of the paint state's emission (the row's likelihood
    /// ratio at `p_on`) of each row in view, in order (§11.5: what [`chain_expectations`]
    /// needs).
    pub chain_lr: Vec<f64>,
    /// The lane's rows (those in its row range).
    pub rows: Vec<LaneRow>,
}

/// The lane's information with a lateral offset common to its rows in the frame marginalised
/// (docs/design.md §11.4): the rows are `z̃_r = c_rᵀ a + o + e_r`, `o ~ N(0, σ_o²)`, `e_r ~ N(0,
/// v_r)`, so the stacked rows have the covariance `V + σ_o² 1 1ᵀ`, whose inverse (Sherman–Morrison)
/// is `V⁻¹ − σ_o² V⁻¹1 1ᵀV⁻¹/(1 + σ_o² 1ᵀV⁻¹1)`; with `C` the rows' `c_rᵀ`,
/// `J' = Cᵀ(V + σ_o² 11ᵀ)⁻¹C = J − σ_o² k kᵀ/(1 + σ_o² w)`, `i' = i − σ_o² ζ k/(1 + σ_o² w)`.
pub fn offset_marginal(ev: &LaneEvidence, sd: f64) -> (DMatrix<f64>, DVector<f64>) {
    let (k, w, zeta, _) = &ev.offset;
    let s2 = sd * sd;
    let g = s2 / (1.0 + s2 * w);
    (&ev.j - k * k.transpose() * g, &ev.i - k * (g * zeta))
}

/// The estimate of the frame offset's variance `σ_o²` (docs/design.md §11.4), written from the
/// design: per lane with rows in two consecutive frames, `Δ = m_t − m_{t−1}` (its mean
/// innovations) has the variance `V = a_t + a_{t−1} + 2σ_o²` (`a` the mean innovation's predicted
/// variance without the offset); the moment sample `e = ½(min(Δ², 4V)/E min(χ²₁, 4) − a_t −
/// a_{t−1})` enters one Fisher-scoring step for `σ_o²` with weight `1/V²` (the Fisher information
/// of `σ_o²` in `N(0, V)` up to a constant factor), the information being discounted by
/// `1 − 1/memory` a frame; `σ_o² ≥ 0`.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameOffset {
    /// `σ_o²`, m².
    pub var: f64,
    /// Its discounted information.
    pub info: f64,
    /// Per lane, the last frame's `(m, a)`.
    pub last: Vec<Option<(f64, f64)>>,
}

impl FrameOffset {
    /// No estimate yet (`σ_o = 0`), `lanes` lanes.
    pub fn new(lanes: usize) -> Self {
        Self {
            var: 0.0,
            info: 0.0,
            last: vec![None; lanes],
        }
    }

    /// One frame: `innovation[s] = Some((m_s, a_s))` for the lanes with rows in it.
    pub fn update(&mut self, innovation: &[Option<(f64, f64)>], memory: f64) {
        // E min(χ²₁, c) = P(χ²₃ ≤ c) + c P(χ²₁ > c), at c = 4: erf(√2) − √(8/π) e^{−2} +
        // 4 erfc(√2) (evaluated with Python's math.erf).
        let c = 4.0;
        let mean = 0.920_536_925_636_323;
        let (mut num, mut den) = (0.0, 0.0);
        for (last, inn) in self.last.iter_mut().zip(innovation) {
            if let (Some((m0, a0)), Some((m, a))) = (*last, *inn) {
                let v = a + a0 + 2.0 * self.var;
                let e = 0.5 * (((m - m0) * (m - m0)).min(c * v) / mean - a - a0);
                num += (e - self.var) / (v * v);
                den += 1.0 / (v * v);
            }
            *last = *inn;
        }
        self.info = self.info * (1.0 - 1.0 / memory) + den;
        if self.info > 0.0 {
            self.var = (self.var + num / self.info).max(0.0);
        }
    }
}

/// The result of [`known_lane_pass`].
#[derive(Debug, Clone, PartialEq)]
pub struct PassOutput {
    /// Per lane, in the input order.
    pub lanes: Vec<LaneEvidence>,
    /// Per row, per point: `Σ_s β_{s,j} ≥ explained` (over the lanes looking at the row).
    pub explained: Vec<Vec<bool>>,
    /// Per row, per point: `Σ_s β_{s,j}`.
    pub beta_sum: Vec<Vec<f64>>,
}

/// `ln Λ_r = ln(1 − P_D P_G + (P_D/λ) Σ_{j gated} N(z_j; ẑ, S_ss))`, the IPDA likelihood ratio of
/// one row (docs/design.md §11.5): "the lane exists" against "its gated points are clutter".
pub fn log_likelihood_ratio(pd: f64, pg: f64, clutter: f64, gated_likelihood: f64) -> f64 {
    (1.0 - pd * pg + pd * gated_likelihood / clutter).ln()
}

/// `N(x; 0, s)`.
fn normal_pdf(x: f64, s: f64) -> f64 {
    (-0.5 * x * x / s).exp() / (2.0 * std::f64::consts::PI * s).sqrt()
}

/// The known-lane pass (docs/design.md §11.3 and the existence evidence of §11.5), exact.
///
/// For every row, the lanes whose row range holds it are predicted from their coefficients
/// ([`row_basis`]); the joint events are all of them (§4.1 steps 2–3 without the budget of step
/// 5: [`jpda::row_step_with_pd`] on the lanes' predicted positions with covariance `P_row`
/// (`P_row,st = c_rᵀ Cov(a_s, a_t) c_r + ρ_r B_ρ(s)ρ(t)`), point variance `r_b` and each lane's
/// `P_D,b`, so that its `S̄` is the joint `S` of §11.3). A lane that gates no point is missed in every event: its constant miss
/// factor changes no `β`, so including it equals enumerating only the lanes with candidates.
/// With [`RowWeights::Lbp`] the `β` are instead the LBP marginals of the uncoupled likelihood
/// ([`jpda::lbp_marginals_with_pd`] on each lane's marginal gate and `S_ss`, its `P_D,b`).
///
/// # Errors
/// Shapes that disagree (coefficients of another length than the tables' rank, a covariance of
/// the wrong size, a lane's `P_D` or a row's band outside the bands, a rank outside `B`), or a
/// row whose events cannot be weighed (a joint `S_δ` not positive definite).
pub fn known_lane_pass(model: &ModelTables, input: &PassInput<'_>) -> Result<PassOutput> {
    let r = model.gram_rank.min(model.index_u.len());
    let n = input.lanes.len();
    ensure!(
        input.cov.nrows() == n * r && input.cov.ncols() == n * r,
        "joint covariance is {}x{}, expected {}",
        input.cov.nrows(),
        input.cov.ncols(),
        n * r
    );
    for (s, lane) in input.lanes.iter().enumerate() {
        ensure!(
            lane.mean.len() == r,
            "lane {s}: coefficients not of length {r}"
        );
        ensure!(
            lane.rank < input.coreg.nrows() && lane.rank < input.coreg.ncols(),
            "lane {s}: rank {} outside B",
            lane.rank
        );
        ensure!(
            lane.pd.len() >= input.bands.len(),
            "lane {s}: P_D for {} bands, expected {}",
            lane.pd.len(),
            input.bands.len()
        );
    }
    let prm = input.params;
    let cov_st = |s: usize, t: usize, c: &DVector<f64>| -> f64 {
        let block = input.cov.view((s * r, t * r), (r, r));
        (c.transpose() * block * c)[(0, 0)]
    };
    let mut lanes: Vec<LaneEvidence> = (0..n)
        .map(|_| LaneEvidence {
            j: DMatrix::zeros(r, r),
            i: DVector::zeros(r),
            weight: 0.0,
            llr: 0.0,
            q_score: (0.0, 0.0),
            offset: (DVector::zeros(r), 0.0, 0.0, 0.0),
            chain_lr: Vec::new(),
            rows: Vec::new(),
        })
        .collect();
    // The chain (§11.5) in the log domain: per lane `[ln α_paint, ln α_gap]`, from the stationary
    // shares; one transition and one emission per row in view.
    let chain = input.paint_gap.map(|c| {
        let (to_off, to_on, pi_on) = c.rates();
        (c.p_on, to_off, to_on, pi_on)
    });
    let lse = |a: f64, b: f64| {
        let m = a.max(b);
        m + ((a - m).exp() + (b - m).exp()).ln()
    };
    let mut alpha: Vec<[f64; 2]> = match chain {
        Some((_, _, _, pi_on)) => vec![[pi_on.ln(), (1.0 - pi_on).ln()]; n],
        None => Vec::new(),
    };
    let mut explained = Vec::with_capacity(input.rows.len());
    let mut beta_sum = Vec::with_capacity(input.rows.len());
    for (ri, row) in input.rows.iter().enumerate() {
        let m = row.points.len();
        let band = input
            .bands
            .get(row.band)
            .with_context(|| format!("row {ri}: band {} outside the bands", row.band))?;
        let idx: Vec<usize> = (0..n)
            .filter(|&s| {
                let (lo, hi) = input.lanes[s].rows;
                ri >= lo && ri <= hi
            })
            .collect();
        let mut sums = vec![0.0; m];
        if idx.is_empty() {
            explained.push(vec![false; m]);
            beta_sum.push(sums);
            continue;
        }
        let (c, rho) = row_basis(model, row.u);
        let nr = idx.len();
        let zhat = DVector::from_fn(nr, |a, _| c.dot(&input.lanes[idx[a]].mean));
        let p_row = DMatrix::from_fn(nr, nr, |a, b| {
            let (s, t) = (idx[a], idx[b]);
            let (bs, bt) = (input.lanes[s].rank, input.lanes[t].rank);
            cov_st(s, t, &c) + rho * input.coreg[(bs, bt)]
        });
        let p_row = (&p_row + p_row.transpose()) * 0.5;
        let params = RowParams {
            pd: prm.pd,
            pg: prm.pg,
            gamma: prm.gamma,
            clutter_density: band.clutter,
            r: band.noise,
            miss: prm.miss,
        };
        let one = DMatrix::from_element(1, 1, 1.0);
        // Each lane's detections weighed at its own `P_D,b` (§11.3).
        let pds: Vec<f64> = idx
            .iter()
            .map(|&s| {
                if prm.own_pd {
                    input.lanes[s].pd[row.band]
                } else {
                    prm.pd
                }
            })
            .collect();
        let (beta_all, gating) = match prm.weights {
            RowWeights::Exact => {
                let res =
                    jpda::row_step_with_pd(&zhat, &p_row, &one, &row.points, &params, &pds)
                        .with_context(|| format!("row {ri}: the joint events cannot be weighed"))?;
                (res.beta, res.gating)
            }
            RowWeights::Lbp {
                max_iterations,
                tolerance,
            } => {
                let gating = jpda::gate(&zhat, &p_row, &one, band.noise, &row.points, prm.gamma);
                let (beta, _) = jpda::lbp_marginals_with_pd(
                    &gating,
                    &row.points,
                    &params,
                    &pds,
                    max_iterations,
                    tolerance,
                );
                (beta, gating)
            }
        };
        // Each point's density under the other lanes' detections: λ + Σ_t P_D P_t N(z_j; ẑ_t,
        // S_tt) over the lanes that gate it; a lane's own term is taken out below (§11.5).
        let lane_density = |a: usize, j: usize| -> f64 {
            if gating.valid[a][j] {
                normal_pdf(row.points[j] - zhat[a], gating.s[a])
            } else {
                0.0
            }
        };
        let weight = |a: usize| prm.pd * input.lanes[idx[a]].existence.clamp(0.0, 1.0);
        let others: Vec<f64> = (0..m)
            .map(|j| (0..nr).map(|a| weight(a) * lane_density(a, j)).sum())
            .collect();
        for (a, &s) in idx.iter().enumerate() {
            let lane = &input.lanes[s];
            let beta: Vec<f64> = beta_all[a].iter().skip(1).copied().collect();
            let beta_miss = beta_all[a][0];
            for (sum, b) in sums.iter_mut().zip(&beta) {
                *sum += b;
            }
            let zh = zhat[a];
            let p = p_row[(a, a)];
            let st = gating.s[a];
            let w = 1.0 - beta_miss;
            let nu_bar: f64 = beta
                .iter()
                .zip(&row.points)
                .map(|(b, z)| b * (z - zh))
                .sum();
            let n2: f64 = beta
                .iter()
                .zip(&row.points)
                .map(|(b, z)| b * (z - zh) * (z - zh))
                .sum();
            let spread = n2 - nu_bar * nu_bar;
            let q = w / st - spread / (st * st);
            let equivalent = (q > 0.0).then(|| (1.0 / q - p, zh + nu_bar / (q * st)));
            let gated = gating.valid[a].clone();
            let gated_likelihood: f64 = (0..m)
                .filter(|&j| gated[j])
                .map(|j| {
                    let own = lane_density(a, j);
                    let rest = (others[j] - weight(a) * own).max(0.0);
                    own * band.clutter / (band.clutter + rest)
                })
                .sum();
            let in_view = band.span.is_some_and(|(lo, hi)| zh >= lo && zh <= hi);
            let log_lr =
                log_likelihood_ratio(lane.pd[row.band], prm.pg, band.clutter, gated_likelihood);
            let ev = &mut lanes[s];
            // §11.7: every row in view with `W_r > 0` (no threshold of the design's; the core
            // skips `W_r ≤ 1e-6`, which moves the sums by at most `γ·1e-6` a row).
            if in_view && w > 0.0 {
                let f = (p / st).clamp(0.0, 1.0);
                ev.q_score.0 += f * (n2 / st - w);
                ev.q_score.1 += w * f * f;
            }
            if let Some((v, zt)) = equivalent {
                ev.j += &c * c.transpose() / v;
                ev.i += &c * (zt / v);
                ev.offset.0 += &c / v;
                ev.offset.1 += 1.0 / v;
                ev.offset.2 += zt / v;
                ev.offset.3 += zh / v;
                ev.weight += w;
            }
            if in_view {
                match chain {
                    None => ev.llr += log_lr,
                    Some((p_on, to_off, to_on, _)) => {
                        let on_lr =
                            log_likelihood_ratio(p_on, prm.pg, band.clutter, gated_likelihood);
                        ev.chain_lr.push(on_lr);
                        let [on, off] = alpha[s];
                        alpha[s] = [
                            lse(on + (1.0 - to_off).ln(), off + to_on.ln()) + on_lr,
                            lse(on + to_off.ln(), off + (1.0 - to_on).ln()),
                        ];
                    }
                }
            }
            ev.rows.push(LaneRow {
                row: ri,
                zhat: zh,
                p,
                s: st,
                beta,
                beta_miss,
                w,
                nu_bar,
                spread,
                equivalent,
                gated,
                gated_likelihood,
                in_view,
                log_lr,
            });
        }
        explained.push(sums.iter().map(|&b| b >= prm.explained).collect());
        beta_sum.push(sums);
    }
    for (ev, a) in lanes.iter_mut().zip(&alpha) {
        ev.llr = lse(a[0], a[1]);
    }
    Ok(PassOutput {
        lanes,
        explained,
        beta_sum,
    })
}

/// The result of [`info_update`].
#[derive(Debug, Clone, PartialEq)]
pub struct InfoUpdate {
    /// Posterior mean.
    pub mean: DVector<f64>,
    /// Posterior covariance.
    pub cov: DMatrix<f64>,
    /// `M = Hᵀ S⁻¹ H` on the lane's coefficients (`r×r`), `(Cov(a) + J⁻¹)⁻¹` when `J` is
    /// invertible.
    pub m: DMatrix<f64>,
    /// `w = Hᵀ S⁻¹ ν` on the lane's coefficients.
    pub w: DVector<f64>,
    /// `q = wᵀ M⁻¹ w` (docs/design.md §11.4: `M⁻¹` by a Cholesky factorisation of `M` with
    /// pivots floored at `10⁻⁶ max_j M_jj`; 0 when `M` is zero).
    pub nis: f64,
}

/// One frame's step of the process-noise scale (docs/design.md §11.7): `lanes` holds each
/// published lane's `(score, information, dof)` ([`LaneEvidence::q_score`] and the lane's rank;
/// a lane with no information is not counted); each score is capped at twice its information; with `Σ dof ≥ min_dof` and `Σ information
/// > 0`, `ŝ = s (1 + Σ score / Σ information)` (at least 0), then `ln s` moves `1/memory` of
/// the way to `ln ŝ`, both in `[0, ln 10⁴]`. Returns the new `ln s`.
pub fn q_scale_step(log_s: f64, lanes: &[(f64, f64, f64)], memory: f64, min_dof: f64) -> f64 {
    let (g, i, dof) = lanes
        .iter()
        .filter(|l| l.1 > 0.0)
        .fold((0.0, 0.0, 0.0), |(g, i, d), &(gs, is, ds)| {
            (g + gs.min(2.0 * is), i + is, d + ds)
        });
    let top = 1e4f64.ln();
    let s = log_s.clamp(0.0, top);
    if dof < min_dof || i <= 0.0 {
        return s;
    }
    let ratio = (1.0 + g / i).max(0.0);
    let target = (ratio * s.exp()).max(1.0).ln().clamp(0.0, top);
    (s + (target - s) / memory.max(1.0)).clamp(0.0, top)
}

/// The Kalman update of the Gaussian `N(x, P)` by measurements whose information on the entries
/// `idx` of the state (a lane's position coefficients `a_s`, in component order) is `(J, i)`:
/// the likelihood `∝ exp(−½ aᵀ J a + iᵀ a)` (docs/design.md §11.3–11.4). The exact posterior is
/// `P⁺ = (P⁻¹ + Eᵀ J E)⁻¹`, `x⁺ = P⁺ (P⁻¹ x + Eᵀ i)` (`E` selects `idx`); it is computed without
/// inverting `P` (which may be singular, e.g. zero rows of free slots), from the **whitened
/// equivalent measurement** of `J`'s eigen-decomposition `J = U diag(d) Uᵀ`: for every `d_k > 0`,
/// `y_k = u_kᵀ i / √d_k = √d_k u_kᵀ a + e_k`, `e_k ~ N(0, 1)`, so that `Hᵀ H = J` and `Hᵀ y = i`
/// (a component of `i` outside `J`'s range carries no information and is dropped). Then
/// `S = H P Hᵀ + I` (`⪰ I`), `K = P Hᵀ S⁻¹` by Cholesky, `x⁺ = x + K (y − H x)` and the Joseph
/// form `P⁺ = (I − K H) P (I − K H)ᵀ + K Kᵀ`, symmetrised.
///
/// Any state layout works: the core's (slot `s`, component `j`, `[a, ȧ]` at `(s·RANK + j)·2`,
/// docs/design.md §4.2.1) is `idx = [(s·RANK + j)·2 for j < r]`.
///
/// # Errors
/// Shapes that disagree, an index outside the state, `J` or `i` not finite, or `S` not positive
/// definite (only for a `P` that is not PSD).
pub fn info_update(
    x: &DVector<f64>,
    p: &DMatrix<f64>,
    idx: &[usize],
    j: &DMatrix<f64>,
    i: &DVector<f64>,
) -> Result<InfoUpdate> {
    let n = x.len();
    let r = idx.len();
    ensure!(
        p.nrows() == n && p.ncols() == n,
        "covariance is {}x{} for a state of {n}",
        p.nrows(),
        p.ncols()
    );
    ensure!(
        j.nrows() == r && j.ncols() == r && i.len() == r,
        "information of the wrong size"
    );
    ensure!(idx.iter().all(|&k| k < n), "index outside the state");
    ensure!(
        j.iter().chain(i.iter()).all(|v| v.is_finite()),
        "information not finite"
    );
    let eig = ((j + j.transpose()) * 0.5).symmetric_eigen();
    let dmax = eig.eigenvalues.iter().copied().fold(0.0f64, f64::max);
    let keep: Vec<usize> = (0..r)
        .filter(|&k| eig.eigenvalues[k] > dmax * 1e-15 && eig.eigenvalues[k] > 0.0)
        .collect();
    let mk = keep.len();
    // Whitened equivalent measurement on the lane's coefficients: H_a (mk×r), y (mk).
    let h_a = DMatrix::from_fn(mk, r, |k, q| {
        let e = keep[k];
        eig.eigenvalues[e].sqrt() * eig.eigenvectors[(q, e)]
    });
    let y = DVector::from_fn(mk, |k, _| {
        let e = keep[k];
        eig.eigenvectors.column(e).dot(i) / eig.eigenvalues[e].sqrt()
    });
    let mut h = DMatrix::zeros(mk, n);
    for (q, &col) in idx.iter().enumerate() {
        for k in 0..mk {
            h[(k, col)] = h_a[(k, q)];
        }
    }
    let p = (p + p.transpose()) * 0.5;
    let pht = &p * h.transpose();
    let s = &h * &pht + DMatrix::identity(mk, mk);
    let s = (&s + s.transpose()) * 0.5;
    let chol = s
        .cholesky()
        .context("innovation covariance not positive definite")?;
    let gain = chol.solve(&pht.transpose()).transpose();
    let nu = &y - &h * x;
    let mean = x + &gain * &nu;
    let ikh = DMatrix::identity(n, n) - &gain * &h;
    let cov = &ikh * &p * ikh.transpose() + &gain * gain.transpose();
    let cov = (&cov + cov.transpose()) * 0.5;
    // M = H_aᵀ S⁻¹ H_a, w = H_aᵀ S⁻¹ ν.
    let m = h_a.transpose() * chol.solve(&h_a);
    let m = (&m + m.transpose()) * 0.5;
    let w = h_a.transpose() * chol.solve(&nu);
    let nis = floored_quadratic(&m, &w, 1e-6);
    Ok(InfoUpdate {
        mean,
        cov,
        m,
        w,
        nis,
    })
}

/// `wᵀ M⁻¹ w` with `M⁻¹` from a Cholesky factorisation whose pivots are floored at
/// `rel · max_j M_jj` (0 when that is not positive).
fn floored_quadratic(m: &DMatrix<f64>, w: &DVector<f64>, rel: f64) -> f64 {
    let r = m.nrows();
    let mmax = (0..r).map(|k| m[(k, k)]).fold(0.0f64, f64::max);
    if mmax.is_nan() || mmax <= 0.0 {
        return 0.0;
    }
    let floor = rel * mmax;
    let mut l = DMatrix::<f64>::zeros(r, r);
    for k in 0..r {
        let mut d = m[(k, k)];
        for q in 0..k {
            d -= l[(k, q)] * l[(k, q)];
        }
        let d = d.max(floor).sqrt();
        l[(k, k)] = d;
        for a in k + 1..r {
            let mut v = m[(a, k)];
            for q in 0..k {
                v -= l[(a, q)] * l[(k, q)];
            }
            l[(a, k)] = v / d;
        }
    }
    // z = L⁻¹ w.
    let mut z = w.clone();
    for k in 0..r {
        let mut v = z[k];
        for q in 0..k {
            v -= l[(k, q)] * z[q];
        }
        z[k] = v / l[(k, k)];
    }
    z.norm_squared()
}

/// The ray statistic of docs/design.md §11.10 in f64: over the index points `i` where
/// `present[i]` (finite `u`, `z`, positive finite `weight`), the weighted least-squares line
/// `x = a + b t` (`t = u / max|u|`) and quadratic `x = a' + b' s + c s²` (`s = (u − u_mid)/u_half`
/// over the points used), each solved as
/// `θ = (Hᵀ W H)⁻¹ Hᵀ W z` (dense LU, `W = diag(weight)`); `â` and `ĉ` are the rows
/// `f = e_kᵀ (Hᵀ W H)⁻¹ Hᵀ W` applied to `z`, with variances `fᵀ C f` for the covariance `C` of
/// `z` (full `POINTS × POINTS`, zero where absent). Returns `(â, √(fₐᵀ C fₐ), â²/S_aa, ĉ²/S_cc)`,
/// or `None` with fewer than 3 points or a singular fit.
pub fn ray_stat(
    u: &[f64],
    z: &[f64],
    present: &[bool],
    weight: &[f64],
    cov: &DMatrix<f64>,
) -> Option<(f64, f64, f64, f64)> {
    let idx: Vec<usize> = (0..u.len())
        .filter(|&i| {
            present.get(i) == Some(&true)
                && u[i].is_finite()
                && z.get(i).is_some_and(|v| v.is_finite())
                && weight.get(i).is_some_and(|w| w.is_finite() && *w > 0.0)
        })
        .collect();
    if idx.len() < 3 {
        return None;
    }
    let scale = idx.iter().map(|&i| u[i].abs()).fold(0.0, f64::max);
    if scale <= 0.0 {
        return None;
    }
    // The functional of coefficient `k` of the polynomial of degree `deg`, over all index points.
    let (lo, hi) = idx
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &i| {
            (l.min(u[i]), h.max(u[i]))
        });
    let functional = |deg: usize, k: usize| -> Option<DVector<f64>> {
        // The line in `u / max|u|`; the quadratic in `(u − u_mid)/u_half` (its curvature term
        // does not depend on the origin, and the χ² not on the scale).
        let x = |i: usize| {
            if deg == 1 {
                u[i] / scale
            } else {
                (u[i] - (lo + hi) / 2.0) / ((hi - lo) / 2.0)
            }
        };
        let h = DMatrix::from_fn(idx.len(), deg + 1, |r, c| x(idx[r]).powi(c as i32));
        let w = DMatrix::from_diagonal(&DVector::from_iterator(
            idx.len(),
            idx.iter().map(|&i| weight[i]),
        ));
        let normal = h.transpose() * &w * &h;
        let inv = normal.lu().try_inverse()?;
        let rows = inv * h.transpose() * w;
        let mut f = DVector::zeros(u.len());
        for (r, &i) in idx.iter().enumerate() {
            f[i] = rows[(k, r)];
        }
        Some(f)
    };
    let zv = DVector::from_column_slice(z).map(|v| if v.is_finite() { v } else { 0.0 });
    let fa = functional(1, 0)?;
    let fc = functional(2, 2)?;
    let a = fa.dot(&zv);
    let c = fc.dot(&zv);
    let saa = (fa.transpose() * cov * &fa)[(0, 0)];
    let scc = (fc.transpose() * cov * &fc)[(0, 0)];
    (saa > 0.0 && scc > 0.0).then(|| (a, saa.sqrt(), a * a / saa, c * c / scc))
}

/// The expected gap rows `E[T]` and gap → paint transitions `E[N]` of one lane's rows in view
/// under the paint / gap chain, given all of them (docs/design.md §11.5), written from the
/// design by the forward–backward recursions: the chain starts at its stationary shares
/// before the first row; row `r` is reached by one transition `A` and emits `e_r = (Λ_r, 1)`
/// (`ln Λ_r = ln_lr[r]`: paint at `p_on`; a gap emits nothing); `E[T] = Σ_r P(x_r = gap | all)`,
/// `E[N] = Σ_r P(x_{r−1} = gap, x_r = paint | all)`, `x_{−1}` the start.
pub fn chain_expectations(ln_lr: &[f64], c: &PaintGap) -> (f64, f64) {
    let (to_off, to_on, pi_on) = c.rates();
    // A[i][j]: from i to j, 0 = paint, 1 = gap.
    let a = [[1.0 - to_off, to_off], [to_on, 1.0 - to_on]];
    let n = ln_lr.len();
    if n == 0 {
        return (0.0, 0.0);
    }
    // Emissions scaled by each row's larger one (the scale cancels in the posteriors).
    let em: Vec<[f64; 2]> = ln_lr
        .iter()
        .map(|&l| {
            let m = l.max(0.0);
            [(l - m).exp(), (-m).exp()]
        })
        .collect();
    // Forward, normalised: alpha[r] ∝ p(x_r, rows ≤ r); alpha_prev[0] the start.
    let mut alpha = vec![[0.0f64; 2]; n + 1];
    alpha[0] = [pi_on, 1.0 - pi_on];
    for r in 0..n {
        let mut v = [0.0; 2];
        for j in 0..2 {
            v[j] = (alpha[r][0] * a[0][j] + alpha[r][1] * a[1][j]) * em[r][j];
        }
        let z = v[0] + v[1];
        alpha[r + 1] = [v[0] / z, v[1] / z];
    }
    // Backward, normalised: beta[r] ∝ p(rows > r | x_r).
    let mut beta = vec![[1.0f64; 2]; n + 1];
    for r in (0..n).rev() {
        let mut v = [0.0; 2];
        for (i, vi) in v.iter_mut().enumerate() {
            *vi = a[i][0] * em[r][0] * beta[r + 1][0] + a[i][1] * em[r][1] * beta[r + 1][1];
        }
        let z = v[0] + v[1];
        beta[r] = [v[0] / z, v[1] / z];
    }
    let (mut t, mut nn) = (0.0, 0.0);
    for r in 0..n {
        // Row r is alpha[r + 1], beta[r + 1]; its predecessor alpha[r].
        let g = [
            alpha[r + 1][0] * beta[r + 1][0],
            alpha[r + 1][1] * beta[r + 1][1],
        ];
        t += g[1] / (g[0] + g[1]);
        let mut xi = [[0.0f64; 2]; 2];
        let mut z = 0.0;
        for i in 0..2 {
            for j in 0..2 {
                xi[i][j] = alpha[r][i] * a[i][j] * em[r][j] * beta[r + 1][j];
                z += xi[i][j];
            }
        }
        nn += xi[1][0] / z;
    }
    (t, nn)
}

/// The estimate of the paint / gap chain's mean gap (docs/design.md §11.5), written from the
/// design: one EM step a frame, the M-step `gap = (Σ E[T]·du + gap0)/(Σ E[N] + 1)` over the
/// counted lanes' expectations ([`chain_expectations`]) summed with a discount of
/// `1 − 1/memory` a frame, the prior gap `gap0` worth one transition.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainGap {
    /// Discounted expected gap metres.
    pub t: f64,
    /// Discounted expected gap → paint transitions.
    pub n: f64,
}

impl ChainGap {
    /// No data yet: the prior.
    pub fn new() -> Self {
        Self { t: 0.0, n: 0.0 }
    }

    /// The mean gap, metres.
    pub fn gap(&self, gap0: f64) -> f64 {
        (self.t + gap0) / (self.n + 1.0)
    }

    /// One frame: `stats[s] = Some((E[T], E[N]))` for the lanes counted, rows `du` metres apart.
    pub fn update(&mut self, stats: &[Option<(f64, f64)>], du: f64, memory: f64) {
        let d = 1.0 - 1.0 / memory.max(1.0);
        self.t *= d;
        self.n *= d;
        for (et, en) in stats.iter().flatten() {
            self.t += et * du;
            self.n += en;
        }
    }
}

impl Default for ChainGap {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tables() -> ModelTables {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/hyper/default.json");
        let h = crate::hyper::HyperFile::load(&path).unwrap_or_else(|e| panic!("{e:#}"));
        ModelTables::from_hyper(&h).unwrap_or_else(|e| panic!("{e:#}"))
    }

    #[test]
    fn row_basis_interpolates_the_index_points() {
        let t = tables();
        let r = t.gram_rank;
        // At an index point the conditional reproduces the truncated basis: c = V_rᵀ e_i
        // (f = V_r a), and the residual is what the truncation drops.
        for i in [0usize, 5, 15] {
            let (c, rho) = row_basis(&t, t.index_u[i]);
            for jj in 0..r {
                assert!((c[jj] - t.gram_eigvec[(i, jj)]).abs() < 1e-6, "{i} {jj}");
            }
            assert!((0.0..1e-4).contains(&rho), "{rho}");
        }
        // Between index points the variance is split between the basis and the residual.
        let (c, rho) = row_basis(&t, 40.0);
        let expl: f64 = (0..r).map(|jj| c[jj] * c[jj] * t.gram_eigval[jj]).sum();
        assert!((expl + rho - t.hyper.spatial.variance).abs() < 1e-9);
    }

    #[test]
    fn info_update_equals_the_information_form() {
        // A 4-entry state, information on entries 0 and 2.
        let p = DMatrix::from_row_slice(
            4,
            4,
            &[
                4.0, 1.0, 0.5, 0.2, 1.0, 3.0, 0.3, 0.1, 0.5, 0.3, 2.0, 0.4, 0.2, 0.1, 0.4, 1.0,
            ],
        );
        let x = DVector::from_vec(vec![1.0, -1.0, 0.5, 2.0]);
        let j = DMatrix::from_row_slice(2, 2, &[2.0, 0.5, 0.5, 1.0]);
        let i = DVector::from_vec(vec![1.0, -0.5]);
        let out = info_update(&x, &p, &[0, 2], &j, &i).unwrap_or_else(|e| panic!("{e:#}"));
        let mut e = DMatrix::zeros(2, 4);
        e[(0, 0)] = 1.0;
        e[(1, 2)] = 1.0;
        let pinv = p
            .clone()
            .try_inverse()
            .unwrap_or_else(|| panic!("singular"));
        let info = &pinv + e.transpose() * &j * &e;
        let cov = info
            .clone()
            .try_inverse()
            .unwrap_or_else(|| panic!("singular"));
        let mean = &cov * (&pinv * &x + e.transpose() * &i);
        assert!((&out.cov - &cov).amax() < 1e-12);
        assert!((&out.mean - &mean).amax() < 1e-12);
        // M = (P_a + J⁻¹)⁻¹, w = M (J⁻¹ i − a), q = wᵀ M⁻¹ w.
        let pa = e.clone() * &p * e.transpose();
        let jinv = j
            .clone()
            .try_inverse()
            .unwrap_or_else(|| panic!("singular"));
        let m = (&pa + &jinv)
            .try_inverse()
            .unwrap_or_else(|| panic!("singular"));
        let w = &m * (&jinv * &i - &e * &x);
        assert!((&out.m - &m).amax() < 1e-12);
        assert!((&out.w - &w).amax() < 1e-12);
        let q = (w.transpose() * (&pa + &jinv) * &w)[(0, 0)];
        assert!((out.nis - q).abs() < 1e-12);
    }
}
