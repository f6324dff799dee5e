//! The temporal coupled filter and the fixed-lag coupled RTS smoother in dense f64 (docs/design.md §4.2, §5;
//! paper Eqs. 32 and 45–51 as corrected by docs/design.md §9).
//!
//! Three layers:
//!
//! 1. A generic dense linear-Gaussian Kalman filter: [`predict`], [`update`] (partial measurements:
//!    a `None` component is missing and its row of `H`, and row and column of `R`, are dropped),
//!    [`filter_step`] and [`run_filter`] with the golden convention — step 0 is the prior updated with
//!    `z_0` (no predict), step `k ≥ 1` is predict then update.
//! 2. Smoothers over the stored moments: the fixed-interval RTS smoother [`rts_smooth`] and the
//!    sliding-window fixed-lag smoother [`FixedLagSmoother`] (and its batch driver
//!    [`fixed_lag_smooth`]), which keeps only the last `L + 1` steps, as the embedded core does.
//! 3. The coupled temporal model [`CoupledTemporalModel`]: the stacked `F̄`, `Q̄`, `P̄₀`, `H̄`, `R` of
//!    docs/design.md §4.2 for `D` active lanes and `N` index points, with a Matérn-3/2 temporal kernel
//!    discretised exactly for any frame step `T` (dropped frames).
//!
//! Everything is dense and straightforward on purpose: this is the oracle the structured f32 core is
//! compared with. Nothing here uses the core crate.
//!
//! Factorisations: innovation covariances `S` are factorised by Cholesky (they contain `R`, which is
//! positive definite); the RTS gain solves with `P_{k+1|k}` by Cholesky and, when `P_{k+1|k}` is
//! numerically singular (a singular Gram matrix `K_u` makes it so), by the SVD pseudo-inverse
//! ([`rts_gain`]). No jitter is added anywhere.

use std::collections::VecDeque;

use anyhow::{bail, ensure, Context, Result};
use nalgebra::{DMatrix, DVector};

use crate::model::ModelTables;
use crate::statespace::Matern32;

/// Gaussian moments: a mean and a covariance.
#[derive(Debug, Clone, PartialEq)]
pub struct Gaussian {
    /// Mean.
    pub mean: DVector<f64>,
    /// Covariance (symmetric).
    pub cov: DMatrix<f64>,
}

impl Gaussian {
    /// Builds moments, checking that the shapes agree.
    pub fn new(mean: DVector<f64>, cov: DMatrix<f64>) -> Result<Self> {
        ensure!(
            cov.nrows() == mean.len() && cov.ncols() == mean.len(),
            "covariance is {}x{} for a mean of length {}",
            cov.nrows(),
            cov.ncols(),
            mean.len()
        );
        Ok(Self { mean, cov })
    }

    /// State dimension.
    pub fn dim(&self) -> usize {
        self.mean.len()
    }
}

/// A time-invariant linear-Gaussian model `x_k = F x_{k−1} + w`, `w ~ N(0, Q)`,
/// `z_k = H x_k + v`, `v ~ N(0, R)`.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearGaussianModel {
    /// Transition `F` (n×n).
    pub f: DMatrix<f64>,
    /// Process noise `Q` (n×n).
    pub q: DMatrix<f64>,
    /// Measurement matrix `H` (m×n).
    pub h: DMatrix<f64>,
    /// Measurement noise `R` (m×m).
    pub r: DMatrix<f64>,
}

/// One step of a filter run: the predicted and filtered moments of step `k` and the transition that
/// led into it (`None` at step 0, where the predicted moments are the prior).
#[derive(Debug, Clone, PartialEq)]
pub struct FilterStep {
    /// `F` used to predict from step `k − 1` to `k`; `None` at step 0.
    pub transition: Option<DMatrix<f64>>,
    /// `x_{k|k−1}`, `P_{k|k−1}` (the prior at step 0).
    pub predicted: Gaussian,
    /// `x_{k|k}`, `P_{k|k}`.
    pub filtered: Gaussian,
}

/// The fixed-interval RTS result for a run of `n` steps.
#[derive(Debug, Clone, PartialEq)]
pub struct RtsResult {
    /// `x_{k|n−1}`, `P_{k|n−1}` for `k = 0..n`.
    pub smoothed: Vec<Gaussian>,
    /// `G_k = P_{k|k} F_{k+1}ᵀ P_{k+1|k}⁻¹` for `k = 0..n−1`; the last entry is the zero matrix (there
    /// is no step after it), matching the golden file's convention.
    pub gains: Vec<DMatrix<f64>>,
}

/// A fixed-lag output: `x_{k−L|k}`, `P_{k−L|k}` published after step `k`.
#[derive(Debug, Clone, PartialEq)]
pub struct LaggedEstimate {
    /// The newest step `k` whose measurement has been used.
    pub k: usize,
    /// The step being estimated, `k − L`.
    pub target_step: usize,
    /// `x_{k−L|k}`, `P_{k−L|k}`.
    pub estimate: Gaussian,
}

fn symmetrize(p: &DMatrix<f64>) -> DMatrix<f64> {
    (p + p.transpose()) * 0.5
}

/// The two matrices of a Kalman step (`F` and `Q`, or `H` and `R`, with their names) against
/// the shapes the step needs; the error names the step, both shapes and `context()`.
fn check_step_shapes(
    step: &str,
    [(a_name, a), (b_name, b)]: [(&str, &DMatrix<f64>); 2],
    [a_want, b_want]: [(usize, usize); 2],
    context: impl FnOnce() -> String,
) -> Result<()> {
    ensure!(
        a.shape() == a_want && b.shape() == b_want,
        "{step}: {a_name} is {:?}, {b_name} is {:?} for {}",
        a.shape(),
        b.shape(),
        context()
    );
    Ok(())
}

/// Kalman predict (paper Eqs. 45–46): `x ← F x`, `P ← F P Fᵀ + Q` (symmetrised).
pub fn predict(x: &Gaussian, f: &DMatrix<f64>, q: &DMatrix<f64>) -> Result<Gaussian> {
    let n = x.dim();
    check_step_shapes("predict", [("F", f), ("Q", q)], [(n, n); 2], || {
        format!("state dimension {n}")
    })?;
    let mean = f * &x.mean;
    let cov = symmetrize(&(f * &x.cov * f.transpose() + q));
    Ok(Gaussian { mean, cov })
}

/// Keeps the observed components of a partial measurement: returns the rows of `H`, the rows and
/// columns of `R` and the entries of `z` whose component is `Some`, in their original order.
pub fn select_observed(
    h: &DMatrix<f64>,
    r: &DMatrix<f64>,
    z: &[Option<f64>],
) -> Result<(DMatrix<f64>, DMatrix<f64>, DVector<f64>)> {
    let m = z.len();
    ensure!(
        h.nrows() == m && r.shape() == (m, m),
        "measurement of length {m} with H {:?} and R {:?}",
        h.shape(),
        r.shape()
    );
    let idx: Vec<usize> = (0..m).filter(|&i| z[i].is_some()).collect();
    let hs = h.select_rows(idx.iter());
    let rs = r.select_rows(idx.iter()).select_columns(idx.iter());
    let zs = DVector::from_iterator(idx.len(), idx.iter().filter_map(|&i| z[i]));
    Ok((hs, rs, zs))
}

/// Kalman update with a full measurement (paper Eqs. 47–51), Joseph form:
/// `S = H P Hᵀ + R`, `K = P Hᵀ S⁻¹` (by a Cholesky solve, not an inverse),
/// `x⁺ = x + K (z − H x)`, `P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ` (symmetrised).
/// An empty measurement (`H` with no rows) returns the prior unchanged.
pub fn update_full(
    x: &Gaussian,
    h: &DMatrix<f64>,
    r: &DMatrix<f64>,
    z: &DVector<f64>,
) -> Result<Gaussian> {
    let n = x.dim();
    let m = z.len();
    check_step_shapes("update", [("H", h), ("R", r)], [(m, n), (m, m)], || {
        format!("z of length {m} and state dimension {n}")
    })?;
    if m == 0 {
        return Ok(x.clone());
    }
    let ph_t = &x.cov * h.transpose();
    let s = symmetrize(&(h * &ph_t + r));
    let chol = s
        .cholesky()
        .context("innovation covariance S is not positive definite")?;
    // K = P Hᵀ S⁻¹  ⇔  S Kᵀ = H P  (S and P symmetric).
    let k = chol.solve(&ph_t.transpose()).transpose();
    let innovation = z - h * &x.mean;
    let mean = &x.mean + &k * innovation;
    let i_kh = DMatrix::<f64>::identity(n, n) - &k * h;
    let cov = symmetrize(&(&i_kh * &x.cov * i_kh.transpose() + &k * r * k.transpose()));
    Ok(Gaussian { mean, cov })
}

/// Kalman update with a possibly partial measurement: `None` components are missing (their rows are
/// removed from `H`, rows and columns from `R`); all missing returns the prior unchanged.
pub fn update(
    x: &Gaussian,
    h: &DMatrix<f64>,
    r: &DMatrix<f64>,
    z: &[Option<f64>],
) -> Result<Gaussian> {
    let (hs, rs, zs) = select_observed(h, r, z)?;
    update_full(x, &hs, &rs, &zs)
}

/// One filter step. With `transition = None` (step 0) the moments in `prev` are the prior and are
/// only updated; with `Some((F, Q))` they are first predicted. `h`, `r`, `z` as in [`update`].
pub fn filter_step(
    prev: &Gaussian,
    transition: Option<(&DMatrix<f64>, &DMatrix<f64>)>,
    h: &DMatrix<f64>,
    r: &DMatrix<f64>,
    z: &[Option<f64>],
) -> Result<FilterStep> {
    let (predicted, transition) = match transition {
        None => (prev.clone(), None),
        Some((f, q)) => (predict(prev, f, q)?, Some(f.clone())),
    };
    let filtered = update(&predicted, h, r, z)?;
    Ok(FilterStep {
        transition,
        predicted,
        filtered,
    })
}

/// Runs the filter over `z_0..z_{n−1}` with the golden convention: step 0 updates the prior with
/// `z_0` (no predict); step `k ≥ 1` predicts with `(F, Q)` and updates with the observed components
/// of `z_k`.
pub fn run_filter(
    model: &LinearGaussianModel,
    prior: &Gaussian,
    z: &[Vec<Option<f64>>],
) -> Result<Vec<FilterStep>> {
    let mut out: Vec<FilterStep> = Vec::with_capacity(z.len());
    for (k, zk) in z.iter().enumerate() {
        let step = match out.last() {
            None => filter_step(prior, None, &model.h, &model.r, zk),
            Some(prev) => filter_step(
                &prev.filtered,
                Some((&model.f, &model.q)),
                &model.h,
                &model.r,
                zk,
            ),
        }
        .with_context(|| format!("filter step {k}"))?;
        out.push(step);
    }
    Ok(out)
}

/// The RTS gain `G_k = P_{k|k} Fᵀ P_{k+1|k}⁻¹`, computed by solving `P_{k+1|k} Gᵀ = F P_{k|k}`,
/// never by forming the inverse. Cholesky is used when `P_{k+1|k}` is numerically positive definite
/// (every pivot `L_ii² > n·ε·max L_jj²`); otherwise — e.g. with a numerically singular Gram matrix
/// `K_u`, as at the reference configuration — the minimum-norm solution through the SVD with
/// singular values below `n·ε·σ_max` treated as zero (the pseudo-inverse). That solution is exact:
/// the columns of `F P_{k|k}` lie in the range of `P_{k+1|k} = F P_{k|k} Fᵀ + Q`.
pub fn rts_gain(
    filtered_cov: &DMatrix<f64>,
    f: &DMatrix<f64>,
    predicted_cov: &DMatrix<f64>,
) -> Result<DMatrix<f64>> {
    let n = predicted_cov.nrows();
    ensure!(
        predicted_cov.shape() == (n, n) && f.shape() == (n, n) && filtered_cov.shape() == (n, n),
        "RTS gain: shapes P_k|k {:?}, F {:?}, P_k+1|k {:?}",
        filtered_cov.shape(),
        f.shape(),
        predicted_cov.shape()
    );
    let rhs = f * filtered_cov;
    let tol = n as f64 * f64::EPSILON;
    if let Some(c) = predicted_cov.clone().cholesky() {
        let d = c.l_dirty().diagonal().map(|v| v * v);
        if d.min() > tol * d.max() {
            return Ok(c.solve(&rhs).transpose());
        }
    }
    let svd = predicted_cov.clone().svd(true, true);
    let eps = tol * svd.singular_values.max();
    let gt = svd
        .solve(&rhs, eps)
        .map_err(|e| anyhow::anyhow!("pseudo-inverse solve with P_k+1|k: {e}"))?;
    Ok(gt.transpose())
}

/// One backward RTS step (paper Eq. 32): from the smoothed moments of step `k + 1` and the stored
/// moments of steps `k` (filtered) and `k + 1` (predicted, and the transition into it), returns the
/// smoothed moments of step `k` and the gain `G_k`:
/// `x_{k|N} = x_{k|k} + G_k (x_{k+1|N} − x_{k+1|k})`,
/// `P_{k|N} = P_{k|k} + G_k (P_{k+1|N} − P_{k+1|k}) G_kᵀ` (symmetrised).
pub fn rts_step(
    current: &FilterStep,
    next: &FilterStep,
    next_smoothed: &Gaussian,
) -> Result<(Gaussian, DMatrix<f64>)> {
    let f = next
        .transition
        .as_ref()
        .context("RTS step into a step without a transition (a step 0)")?;
    let g = rts_gain(&current.filtered.cov, f, &next.predicted.cov)?;
    let mean = &current.filtered.mean + &g * (&next_smoothed.mean - &next.predicted.mean);
    let cov = symmetrize(
        &(&current.filtered.cov + &g * (&next_smoothed.cov - &next.predicted.cov) * g.transpose()),
    );
    Ok((Gaussian { mean, cov }, g))
}

/// Fixed-interval RTS smoother over a whole run (steps must be consecutive: every step after the
/// first carries its transition).
pub fn rts_smooth(steps: &[FilterStep]) -> Result<RtsResult> {
    let Some(last) = steps.last() else {
        return Ok(RtsResult {
            smoothed: Vec::new(),
            gains: Vec::new(),
        });
    };
    let n = steps.len();
    let dim = last.filtered.dim();
    let mut smoothed = vec![last.filtered.clone(); n];
    let mut gains = vec![DMatrix::<f64>::zeros(dim, dim); n];
    for k in (0..n - 1).rev() {
        let (s, g) = rts_step(&steps[k], &steps[k + 1], &smoothed[k + 1])
            .with_context(|| format!("RTS step {k}"))?;
        smoothed[k] = s;
        gains[k] = g;
    }
    Ok(RtsResult { smoothed, gains })
}

/// Fixed-lag RTS smoother with lag `L` as a sliding window (docs/design.md §5): it keeps the filter moments of
/// the last `L + 1` steps, and after each new step runs the RTS recursion back over the window, so
/// that the oldest entry is `x_{k−L|k}`. It never looks at steps that left the window, which is
/// exact: `x_{j|k}` depends on steps before `j` only through `x_{j|j}`.
#[derive(Debug, Clone)]
pub struct FixedLagSmoother {
    lag: usize,
    /// Index of the newest step pushed (`None` before the first push).
    newest: Option<usize>,
    /// The last up to `L + 1` filter steps, oldest first.
    window: VecDeque<FilterStep>,
    /// Smoothed moments of the window entries given the newest step, oldest first.
    smoothed: Vec<Gaussian>,
}

impl FixedLagSmoother {
    /// A smoother with lag `L` (window of `L + 1` steps).
    pub fn new(lag: usize) -> Self {
        Self {
            lag,
            newest: None,
            window: VecDeque::with_capacity(lag + 1),
            smoothed: Vec::with_capacity(lag + 1),
        }
    }

    /// The lag `L`.
    pub fn lag(&self) -> usize {
        self.lag
    }

    /// Adds step `k` (the next step of the run; it must carry its transition unless it is the first
    /// step pushed) and re-smooths the window. Returns `x_{k−L|k}` once `k ≥ L`, else `None`.
    pub fn push(&mut self, step: FilterStep) -> Result<Option<LaggedEstimate>> {
        if self.newest.is_some() && step.transition.is_none() {
            bail!("fixed-lag smoother: a step after the first has no transition");
        }
        let k = self.newest.map_or(0, |k| k + 1);
        if self.window.len() == self.lag + 1 {
            self.window.pop_front();
        }
        self.window.push_back(step);
        self.newest = Some(k);

        let w = self.window.len();
        let newest = &self.window[w - 1];
        let mut smoothed = vec![newest.filtered.clone(); w];
        for j in (0..w - 1).rev() {
            let (s, _) = rts_step(&self.window[j], &self.window[j + 1], &smoothed[j + 1])
                .with_context(|| format!("fixed-lag RTS step {} at k = {k}", k + 1 + j - w))?;
            smoothed[j] = s;
        }
        self.smoothed = smoothed;
        Ok(self.lagged())
    }

    /// `x_{k−L|k}` for the newest step `k`, if `k ≥ L`.
    pub fn lagged(&self) -> Option<LaggedEstimate> {
        let k = self.newest?;
        if k < self.lag {
            return None;
        }
        Some(LaggedEstimate {
            k,
            target_step: k - self.lag,
            estimate: self.smoothed.first()?.clone(),
        })
    }

    /// The window's smoothed moments given the newest step `k`, oldest first, with their step
    /// indices: `(j, x_{j|k})` for `j = max(0, k − L)..=k`. Empty before the first push.
    pub fn window_smoothed(&self) -> Vec<(usize, Gaussian)> {
        let Some(k) = self.newest else {
            return Vec::new();
        };
        let first = k + 1 - self.smoothed.len();
        self.smoothed
            .iter()
            .enumerate()
            .map(|(i, g)| (first + i, g.clone()))
            .collect()
    }
}

/// Feeds a whole run through a [`FixedLagSmoother`] and collects `x_{k−L|k}` for `k = L..n−1`
/// (golden `conventions.fixed_lag`).
pub fn fixed_lag_smooth(steps: &[FilterStep], lag: usize) -> Result<Vec<LaggedEstimate>> {
    let mut sm = FixedLagSmoother::new(lag);
    let mut out = Vec::with_capacity(steps.len().saturating_sub(lag));
    for s in steps {
        if let Some(e) = sm.push(s.clone())? {
            out.push(e);
        }
    }
    Ok(out)
}

/// The per-lane fixed-lag smoother of docs/design.md §5.1, dense: the Kalman filter of the state
/// augmented with the lagged lane positions, with every lag's cross-covariance
/// `C_j = Cov(a_{k−j}, x_k)` projected onto its own-lane blocks (lagged positions of lane `t`
/// against the current state of lane `t` only) after each prediction and each lane update. Lane
/// updates are sequential, in the order they are applied (the projection makes the result
/// depend on it). The filter itself (`x`, `P`) is the exact one; it is owned by the caller, who
/// passes it to each call before changing it.
///
/// State layout as [`CoupledTemporalModel`]: lane-major, then index point, then `[f, ḟ]`; the
/// lagged vector `a` holds the positions `f` of every lane (`D·N`).
#[derive(Debug, Clone)]
pub struct PerLaneLagWindow {
    lag: usize,
    lanes: usize,
    points: usize,
    /// Most recent first: `(a, Σ = Cov(a), C = Cov(a, x))`.
    window: VecDeque<(DVector<f64>, DMatrix<f64>, DMatrix<f64>)>,
}

impl PerLaneLagWindow {
    /// An empty window of `lag` frames for `lanes` lanes of `points` index points.
    pub fn new(lag: usize, lanes: usize, points: usize) -> Self {
        Self {
            lag,
            lanes,
            points,
            window: VecDeque::new(),
        }
    }

    /// Zeroes `C` outside the own-lane blocks (`n` index points a lane).
    fn project(n: usize, c: &mut DMatrix<f64>) {
        for row in 0..c.nrows() {
            for col in 0..c.ncols() {
                if row / n != col / (2 * n) {
                    c[(row, col)] = 0.0;
                }
            }
        }
    }

    /// A frame step: the filtered state of the frame that ends (`filtered`) enters as lag 1, the
    /// oldest leaves, and every `C_j` becomes `C_j Fᵀ` (call before predicting the filter with `f`).
    pub fn predict(&mut self, filtered: &Gaussian, f: &DMatrix<f64>) -> Result<()> {
        let (m, dim) = (self.lanes * self.points, 2 * self.lanes * self.points);
        ensure!(
            filtered.dim() == dim && f.shape() == (dim, dim),
            "state of dimension {} and F of {:?} for {dim}",
            filtered.dim(),
            f.shape()
        );
        let idx: Vec<usize> = (0..m).map(|r| 2 * r).collect();
        let a = DVector::from_fn(m, |r, _| filtered.mean[idx[r]]);
        let sigma = DMatrix::from_fn(m, m, |r, q| filtered.cov[(idx[r], idx[q])]);
        let mut c = DMatrix::from_fn(m, dim, |r, col| filtered.cov[(idx[r], col)]);
        Self::project(self.points, &mut c);
        self.window.push_front((a, sigma, c));
        self.window.truncate(self.lag);
        for (_, _, c) in self.window.iter_mut() {
            *c = &*c * f.transpose();
        }
        Ok(())
    }

    /// One lane's update: `h` (rows: that lane's present points), `r` and the innovation `y`,
    /// against the filter's prior `prior` of this update. Every lag moves by `K_j = C_j Hᵀ`:
    /// `a += K S⁻¹ y`, `Σ −= K S⁻¹ Kᵀ`, `C −= K S⁻¹ H P`, then `C` is projected.
    pub fn update(
        &mut self,
        prior: &Gaussian,
        h: &DMatrix<f64>,
        r: &DMatrix<f64>,
        y: &DVector<f64>,
    ) -> Result<()> {
        let s = h * &prior.cov * h.transpose() + r;
        let s_inv = s
            .cholesky()
            .context("innovation covariance not positive definite")?
            .inverse();
        let hp = h * &prior.cov;
        for (a, sigma, c) in self.window.iter_mut() {
            let k = &*c * h.transpose();
            let ks = &k * &s_inv;
            *a += &ks * y;
            *sigma -= &ks * k.transpose();
            *c -= &ks * &hp;
            Self::project(self.points, c);
        }
        Ok(())
    }

    /// The lagged estimate `L` frames back once the window is full: mean and variance of lane
    /// `d`'s positions at the index points.
    pub fn lagged(&self, d: usize) -> Option<(Vec<f64>, Vec<f64>)> {
        if self.window.len() < self.lag || d >= self.lanes {
            return None;
        }
        let (a, sigma, _) = self.window.back()?;
        let rows = (0..self.points).map(|i| d * self.points + i);
        Some(rows.map(|r| (a[r], sigma[(r, r)])).unzip())
    }
}

/// One lane's pseudo-measurement for a frame: its positions at the `N` index points (`None` where the
/// lane gives no value, e.g. outside its extent) and their `N×N` covariance block from the spatial
/// smoother (rows and columns of missing points are ignored).
#[derive(Debug, Clone, PartialEq)]
pub struct LaneMeasurement {
    /// `f(u^f_i)` for `i = 0..N`.
    pub z: Vec<Option<f64>>,
    /// Pseudo-measurement covariance (N×N), before `r₀² I` is added.
    pub cov: DMatrix<f64>,
}

/// A frame's stacked measurement for all `D` lanes and `N` index points (`DN` rows, lane-major then
/// index-point-major); components that are `None` in `z` are dropped by [`update`].
#[derive(Debug, Clone, PartialEq)]
pub struct StackedMeasurement {
    /// `H̄ = I_{DN} ⊗ H_t` (DN × 2DN).
    pub h: DMatrix<f64>,
    /// Block-diagonal `R` (DN × DN).
    pub r: DMatrix<f64>,
    /// Stacked pseudo-measurements, `None` for unseen lanes and missing points.
    pub z: Vec<Option<f64>>,
}

/// The coupled temporal model of docs/design.md §4.2.
///
/// **State ordering** (lane-major, then index-point-major, then the Matérn state): for lane
/// `d ∈ 0..D`, index point `i ∈ 0..N` and component `c ∈ {0: f, 1: ḟ}` the entry is at
/// `(d·N + i)·2 + c` — that is `x̄ = [f¹(u₁), ḟ¹(u₁), …, f¹(u_N), ḟ¹(u_N), f²(u₁), …]`, of dimension
/// `2DN`. This is the ordering in which `(B_D ⊗ K_u) ⊗ Q_t` is written. Measurements are ordered
/// lane-major then index-point-major: row `d·N + i` of `H̄` observes `f^d(u_i)`.
#[derive(Debug, Clone, PartialEq)]
pub struct CoupledTemporalModel {
    /// Temporal Matérn-3/2 kernel (σ_t², ℓ_t); `F_t(T)`, `Q_t(T)`, `P∞_t` come from it for any `T`.
    pub temporal: Matern32,
    /// Spatial Gram matrix `K_u` at the index points (N×N).
    pub gram: DMatrix<f64>,
    /// Coregionalisation `B` over lane slots (D_max×D_max); `D` active lanes use the leading `D×D`
    /// block.
    pub coreg: DMatrix<f64>,
    /// `r₀²`, added to the diagonal of each lane's pseudo-measurement covariance.
    pub pseudo_noise: f64,
}

impl CoupledTemporalModel {
    /// Builds the model, checking that `K_u` and `B` are square and symmetric (relative 1e-12) and
    /// `r₀² ≥ 0`.
    pub fn new(
        temporal: Matern32,
        gram: DMatrix<f64>,
        coreg: DMatrix<f64>,
        pseudo_noise: f64,
    ) -> Result<Self> {
        for (name, m) in [("K_u", &gram), ("B", &coreg)] {
            ensure!(
                m.is_square() && m.nrows() > 0,
                "{name} must be square and non-empty"
            );
            let scale = m.amax().max(f64::MIN_POSITIVE);
            ensure!(
                (m - m.transpose()).amax() <= 1e-12 * scale,
                "{name} is not symmetric"
            );
        }
        ensure!(
            temporal.variance > 0.0 && temporal.lengthscale > 0.0,
            "temporal kernel needs positive variance and length-scale"
        );
        ensure!(
            pseudo_noise.is_finite() && pseudo_noise >= 0.0,
            "r0^2 must be finite and non-negative"
        );
        Ok(Self {
            temporal,
            gram,
            coreg,
            pseudo_noise,
        })
    }

    /// The model of a table set: σ_t², ℓ_t from its hyperparameters, `K_u = gram`, `B = coreg`,
    /// `r₀² = noise.pseudo`.
    pub fn from_tables(t: &ModelTables) -> Result<Self> {
        Self::new(
            Matern32 {
                variance: t.hyper.temporal.variance,
                lengthscale: t.hyper.temporal.lengthscale,
            },
            t.gram.clone(),
            t.coreg.clone(),
            t.hyper.noise.pseudo,
        )
    }

    /// Number of index points `N`.
    pub fn points(&self) -> usize {
        self.gram.nrows()
    }

    /// Number of lane slots `D_max`.
    pub fn max_lanes(&self) -> usize {
        self.coreg.nrows()
    }

    /// State dimension `2DN` for `D` active lanes.
    pub fn state_dim(&self, lanes: usize) -> usize {
        2 * lanes * self.points()
    }

    /// Index of component `c` (0: f, 1: ḟ) of lane `d` at index point `i` in the stacked state.
    pub fn state_index(&self, lane: usize, point: usize, component: usize) -> usize {
        (lane * self.points() + point) * 2 + component
    }

    fn check_lanes(&self, lanes: usize) -> Result<()> {
        ensure!(
            (1..=self.max_lanes()).contains(&lanes),
            "{lanes} active lanes, the model has {} slots",
            self.max_lanes()
        );
        Ok(())
    }

    /// `B_D ⊗ K_u` (DN×DN), the spatial-and-lane covariance factor.
    pub fn lane_space_cov(&self, lanes: usize) -> Result<DMatrix<f64>> {
        self.check_lanes(lanes)?;
        Ok(self
            .coreg
            .view((0, 0), (lanes, lanes))
            .clone_owned()
            .kronecker(&self.gram))
    }

    /// `F_t(T) = e^{A_t T}` and `Q_t(T) = P∞_t − F_t P∞_t F_tᵀ` for a frame step `T > 0`.
    pub fn temporal_transition(&self, t: f64) -> Result<(DMatrix<f64>, DMatrix<f64>)> {
        ensure!(
            t.is_finite() && t > 0.0,
            "frame step must be positive, got {t}"
        );
        Ok(self.temporal.transition(t))
    }

    /// `F̄ = I_D ⊗ I_N ⊗ F_t(T)`.
    pub fn transition(&self, lanes: usize, t: f64) -> Result<DMatrix<f64>> {
        self.check_lanes(lanes)?;
        let (f, _) = self.temporal_transition(t)?;
        let dn = lanes * self.points();
        Ok(DMatrix::<f64>::identity(dn, dn).kronecker(&f))
    }

    /// `Q̄ = (B_D ⊗ K_u) ⊗ Q_t(T)`.
    pub fn process_noise(&self, lanes: usize, t: f64) -> Result<DMatrix<f64>> {
        let (_, q) = self.temporal_transition(t)?;
        Ok(self.lane_space_cov(lanes)?.kronecker(&q))
    }

    /// `P̄₀ = (B_D ⊗ K_u) ⊗ P∞_t`.
    pub fn initial_cov(&self, lanes: usize) -> Result<DMatrix<f64>> {
        Ok(self
            .lane_space_cov(lanes)?
            .kronecker(&self.temporal.p_inf_closed()))
    }

    /// The prior `N(mean, P̄₀)`; `mean` of length `2DN` in the state ordering.
    pub fn prior(&self, lanes: usize, mean: DVector<f64>) -> Result<Gaussian> {
        Gaussian::new(mean, self.initial_cov(lanes)?)
    }

    /// `H̄ = I_{DN} ⊗ H_t` with `H_t = [1, 0]` (DN × 2DN), all lanes and points.
    pub fn measurement_matrix(&self, lanes: usize) -> Result<DMatrix<f64>> {
        self.check_lanes(lanes)?;
        let dn = lanes * self.points();
        Ok(DMatrix::<f64>::identity(dn, dn).kronecker(&self.temporal.h()))
    }

    /// The full measurement of a frame: `H̄` (all `DN` rows), `R` = block-diag over lanes of
    /// (pseudo-measurement covariance + `r₀² I`), and the stacked `z` in which unseen lanes
    /// (`None` in `observations`) and missing points are `None`, so that [`update`] drops their rows.
    /// Unseen lanes' blocks of `R` are `r₀² I` placeholders that are never used.
    pub fn measurement(
        &self,
        observations: &[Option<LaneMeasurement>],
    ) -> Result<StackedMeasurement> {
        let lanes = observations.len();
        let h = self.measurement_matrix(lanes)?;
        let n = self.points();
        let mut r = DMatrix::<f64>::identity(lanes * n, lanes * n) * self.pseudo_noise;
        let mut z = vec![None; lanes * n];
        for (d, obs) in observations.iter().enumerate() {
            let Some(m) = obs else { continue };
            ensure!(
                m.z.len() == n && m.cov.shape() == (n, n),
                "lane {d}: measurement of length {} with covariance {:?}, expected {n} points",
                m.z.len(),
                m.cov.shape()
            );
            let mut block = r.view_mut((d * n, d * n), (n, n));
            block += &m.cov;
            // A pseudo-measurement covariance that is not PSD over the present points is
            // repaired as the core does (docs/spatial-filter.md, "Temporal update"): a modified
            // Cholesky of `sym(R) + r₀² I` in index order raises every pivot below `r₀²/2` to
            // `max(|d|, r₀²)`; the amounts are added to the diagonal.
            let present: Vec<usize> = (0..n)
                .filter(|&i| m.z[i].is_some_and(f64::is_finite))
                .collect();
            let sub = DMatrix::from_fn(present.len(), present.len(), |a, b| {
                let (i, j) = (present[a], present[b]);
                0.5 * (m.cov[(i, j)] + m.cov[(j, i)]) + if a == b { self.pseudo_noise } else { 0.0 }
            });
            for (a, load) in repair_loads(&sub, self.pseudo_noise)
                .into_iter()
                .enumerate()
            {
                let i = d * n + present[a];
                r[(i, i)] += load;
            }
            z[d * n..(d + 1) * n].copy_from_slice(&m.z);
        }
        Ok(StackedMeasurement { h, r, z })
    }

    /// One frame of the coupled filter for `D = observations.len()` lanes: predict from `prev` over a
    /// frame step `t` (or, with `t = None`, take `prev` as the prior of the first frame), then update
    /// with the seen lanes; lanes that are `None` are predicted only.
    pub fn step(
        &self,
        prev: &Gaussian,
        t: Option<f64>,
        observations: &[Option<LaneMeasurement>],
    ) -> Result<FilterStep> {
        let lanes = observations.len();
        ensure!(
            prev.dim() == self.state_dim(lanes),
            "state of dimension {} for {lanes} lanes of {} points",
            prev.dim(),
            self.points()
        );
        let StackedMeasurement { h, r, z } = self.measurement(observations)?;
        match t {
            None => filter_step(prev, None, &h, &r, &z),
            Some(t) => {
                let f = self.transition(lanes, t)?;
                let q = self.process_noise(lanes, t)?;
                filter_step(prev, Some((&f, &q)), &h, &r, &z)
            }
        }
    }
}

/// The temporal update's repair of `R + r₀² I` (`a`): [`repair_loads_with`] with floor `r0/2`
/// and target `r0` (for a PSD `a − r0 I` every pivot is `≥ r0` and every load is 0).
pub fn repair_loads(a: &DMatrix<f64>, r0: f64) -> Vec<f64> {
    repair_loads_with(a, 0.5 * r0, r0)
}

/// Diagonal loads that make `a` positive definite: a modified Cholesky in index order, a pivot
/// `d < floor` becomes `max(|d|, target)` and the difference is its load.
pub fn repair_loads_with(a: &DMatrix<f64>, floor: f64, target: f64) -> Vec<f64> {
    let n = a.nrows();
    let mut l = DMatrix::<f64>::zeros(n, n);
    let mut loads = vec![0.0; n];
    for j in 0..n {
        let mut d = a[(j, j)];
        for k in 0..j {
            d -= l[(j, k)] * l[(j, k)];
        }
        if d < floor {
            let new = d.abs().max(target);
            loads[j] = new - d;
            d = new;
        }
        let dj = d.sqrt();
        l[(j, j)] = dj;
        for i in j + 1..n {
            let mut acc = a[(i, j)];
            for k in 0..j {
                acc -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = acc / dj;
        }
    }
    loads
}
