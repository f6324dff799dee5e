//! The static model tables: everything the filters need from the kernels, computed offline in f64
//! by `stjpdacf tables` and stored as f32 so that they live in flash.
//!
//! The core never factorises a fixed model matrix at run time: the Cholesky factor of `B`, the
//! eigen-decomposition of the Gram matrix `K_u`, and the state-space forms come from here.
//!
//! ```
//! use stjpdacf::tables::{DEFAULT, FORMAT_VERSION};
//! assert_eq!(DEFAULT.version, FORMAT_VERSION);
//! DEFAULT.validate()?;
//! let (f, q) = DEFAULT.spatial.model.transition(DEFAULT.hyper.row_step).unwrap_or_default();
//! assert!((f - DEFAULT.spatial.f).abs().max() < 1e-5);
//! assert!(q[(0, 0)] > 0.0);
//! # Ok::<(), stjpdacf::tables::TablesError>(())
//! ```

use nalgebra::{Matrix2, SMatrix, SVector};

use crate::kernel::{Matern32, RbfStateSpace};

#[rustfmt::skip]
mod default;
pub use default::DEFAULT;

#[rustfmt::skip]
mod uncoupled;
/// The uncoupled model: [`DEFAULT`] with `B` replaced by `diag(B)` (the same per-lane variance,
/// no coupling between lanes; generated from `data/hyper/ablation_diag_b.json`). With it the
/// temporal filter's covariance stays block-diagonal and every temporal and smoother loop runs
/// on the lanes' own blocks (`TemporalFilter::uncoupled`, docs/design.md §4.2.6): the choice
/// for a controller that cannot spend the coupled model's instructions, at the accuracy cost
/// measured in docs/measurements.md ("The uncoupled model").
pub use uncoupled::UNCOUPLED;

/// Version of the table layout; the generator writes it and [`Tables::validate`] checks it.
pub const FORMAT_VERSION: u32 = 1;

/// Tables of the reference configuration (docs/design.md §2): spatial Taylor order 2, `LANES = 6`,
/// `POINTS = 16`.
pub type ReferenceTables = Tables<2, 6, 16>;

/// Hyperparameters and model constants the tables were generated from (f32 copies; units are BEV
/// metres and seconds).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Hyper {
    /// Taylor order `NT` of the RBF state-space approximation.
    pub spatial_order: u32,
    /// RBF variance `σ_u²` (1 in the coupled model: `B` carries the variance).
    pub spatial_variance: f32,
    /// RBF length-scale `ℓ_u`, metres.
    pub spatial_lengthscale: f32,
    /// Prior variance of a lane's lateral offset state `c`, m² (docs/design.md §4.0).
    pub offset_variance: f32,
    /// Matérn-3/2 variance `σ_t²` (1 in the coupled model).
    pub temporal_variance: f32,
    /// Matérn-3/2 length-scale `ℓ_t`, seconds.
    pub temporal_lengthscale: f32,
    /// Variance of one feature point's lateral position, m².
    pub meas_noise: f32,
    /// Extra variance `r₀²` added to pseudo-measurements in the temporal filter, m².
    pub pseudo_noise: f32,
    /// Near edge of the BEV window, metres ahead of the camera.
    pub u_min: f32,
    /// Far edge of the BEV window, metres ahead of the camera.
    pub u_max: f32,
    /// Nominal row step `Δu` of the spatial filter, metres (`spatial.f`, `spatial.q` are for it).
    pub row_step: f32,
    /// Nominal frame step `T`, seconds (`temporal.f`, `temporal.q` are for it).
    pub frame_step: f32,
    /// Fraction of the Gram matrix's variance kept by the truncated eigenbasis.
    pub gram_variance_fraction: f32,
}

/// The spatial (along-the-road) model of one lane's curve part `g(u)`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(non_snake_case)]
pub struct SpatialTables<const NT: usize> {
    /// State-space form of the RBF kernel (companion `A`, `Qc`, Lyapunov `P∞`).
    pub model: RbfStateSpace<NT>,
    /// `F_u = e^{A Δu}` at the nominal row step.
    pub f: SMatrix<f32, NT, NT>,
    /// `Q_u = P∞ − F_u P∞ F_uᵀ` at the nominal row step (computed in f64, no cancellation).
    pub q: SMatrix<f32, NT, NT>,
}

/// The temporal model of one index point `[f, ∂f/∂t]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TemporalTables {
    /// The Matérn-3/2 kernel (variance, length-scale).
    pub kernel: Matern32,
    /// `F_t(T)` at the nominal frame step.
    pub f: Matrix2<f32>,
    /// `Q_t(T)` at the nominal frame step.
    pub q: Matrix2<f32>,
    /// `P∞_t = diag(σ_t², λ² σ_t²)`.
    pub p_inf: Matrix2<f32>,
}

/// All static model tables for spatial order `NT`, `LANES` lane slots and `POINTS` index points.
///
/// Constructible in `const`/`static` context (every field is a plain value or a nalgebra matrix
/// built with `from_array_storage`), so generated tables live in flash.
///
/// RAM/flash cost: `4·(4·NT² + 30 + POINTS·(2·POINTS + 2) + 2·LANES²)` bytes (2,648 at the
/// reference configuration, `size_of::<ReferenceTables>()`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tables<const NT: usize, const LANES: usize, const POINTS: usize> {
    /// Layout version ([`FORMAT_VERSION`]).
    pub version: u32,
    /// Hyperparameters and model constants.
    pub hyper: Hyper,
    /// Spatial RBF model.
    pub spatial: SpatialTables<NT>,
    /// Temporal Matérn-3/2 model.
    pub temporal: TemporalTables,
    /// Index points `u^f_1 < … < u^f_N`, evenly spaced over the BEV window, metres.
    pub index_u: SVector<f32, POINTS>,
    /// Gram matrix `K_u[i][j] = k_u(u^f_i, u^f_j)` (true RBF, no jitter).
    pub gram: SMatrix<f32, POINTS, POINTS>,
    /// Orthonormal eigenvectors of `K_u` as columns, by decreasing eigenvalue.
    pub gram_eigvec: SMatrix<f32, POINTS, POINTS>,
    /// Eigenvalues of `K_u`, decreasing (tiny negative round-off clamped to 0).
    pub gram_eigval: SVector<f32, POINTS>,
    /// Number of leading eigenpairs that hold `gram_variance_fraction` of the trace.
    pub gram_rank: u32,
    /// Coregionalisation matrix `B = W Wᵀ + diag(κ)` over lane slots (rank from the left).
    pub coreg: SMatrix<f32, LANES, LANES>,
    /// Lower Cholesky factor of `B`; its leading `k×k` block is the factor of `B`'s leading block,
    /// which is what `k` active lanes use.
    pub coreg_chol: SMatrix<f32, LANES, LANES>,
}

/// Error returned by [`Tables::validate`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum TablesError {
    /// `version` is not [`FORMAT_VERSION`].
    Version,
    /// `hyper.spatial_order` differs from the type's `NT`.
    Order,
    /// A value is NaN or infinite.
    NonFinite,
    /// A variance, length-scale, step or window edge (`u_min`, `u_max`) is not positive,
    /// `gram_variance_fraction` is not in (0, 1], or the window is empty.
    NonPositive,
    /// Index points are not increasing inside the window.
    IndexPoints,
    /// A covariance or factor has a non-positive diagonal, or `B` ≠ `L Lᵀ`, or is not symmetric,
    /// or `L` is not lower triangular.
    NotPositiveDefinite,
    /// `gram_rank` is 0 or larger than `POINTS`, or an eigenvalue is negative, or the
    /// eigenvalues are not decreasing.
    GramBasis,
    /// A stored matrix disagrees with the model it is derived from: `gram_eigvec` not orthonormal
    /// or not eigenvectors of `gram` with `gram_eigval`; the temporal `f`, `q`, `p_inf` not those
    /// of `temporal.kernel` at `frame_step`; the spatial `f`, `q` not those of `spatial.model` at
    /// `row_step`.
    Inconsistent,
    /// The largest prior variance of a temporal state (`max_k B_kk · λ₁ · σ_t²`), or of a
    /// lane at a point in the spatial filter (`σ_c² + max_k B_kk · σ_u²`, the most a
    /// pseudo-measurement can carry), exceeds [`MAX_PRIOR_OVER_NOISE`] times the
    /// pseudo-measurement noise floor `r₀²`: the f32 Kalman update of a new lane would lose its
    /// posterior to rounding (fuzz findings F3 and F9); or either prior is below
    /// [`MIN_PRIOR_VARIANCE`], where the filters' products of variances leave f32's normal
    /// range (F10).
    IllConditioned,
}

impl core::fmt::Display for TablesError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let s = match self {
            Self::Version => "table format version mismatch",
            Self::Order => "table spatial order differs from the type's NT",
            Self::NonFinite => "table holds a non-finite value",
            Self::NonPositive => "table holds a non-positive variance, length-scale or step",
            Self::IndexPoints => "index points are not increasing inside the window",
            Self::NotPositiveDefinite => {
                "a covariance or factor is not symmetric positive definite"
            }
            Self::GramBasis => "Gram eigenbasis is inconsistent",
            Self::IllConditioned => "prior variance too large for f32 against the noise floor",
            Self::Inconsistent => "a stored matrix disagrees with the model it is derived from",
        };
        f.write_str(s)
    }
}

impl core::error::Error for TablesError {}

/// Relative tolerance of the consistency checks in [`Tables::validate`] (f32 storage of f64 values).
const CHECK_TOL: f32 = 1e-4;

/// Relative tolerance of [`TablesError::Inconsistent`]: stored f64-derived matrices against the
/// same quantity recomputed in f32 (orthonormality, eigen-equation, discretisation); the
/// generated tables agree to ~1e-5 (see the `nominal_tables_match_runtime_discretisation` test).
const MODEL_TOL: f32 = 1e-3;

fn max_abs_diff<const R: usize, const C: usize>(
    a: &SMatrix<f32, R, C>,
    b: &SMatrix<f32, R, C>,
) -> f32 {
    a.iter()
        .zip(b.iter())
        .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()))
}

/// Largest ratio of a temporal state's prior variance (`max_k B_kk · λ₁ · σ_t²`, m²), and of a
/// lane's spatial prior variance at a point (`σ_c² + max_k B_kk · σ_u²`, m²), to the
/// pseudo-measurement noise floor `r₀²` that [`Tables::validate`] accepts.
///
/// The first update of a new lane takes its covariance from the prior down to about the noise;
/// in f32 the posterior is the difference of two numbers that large, so a ratio near `1/ε`
/// leaves nothing of it. Measured with the fuzz target `tables_validate` (the default tables
/// with the Gram matrix and its eigenvalues scaled by `2^k`, three clean lanes): the default
/// ratio is 7.5e4; the temporal covariance stays PSD up to a ratio of 3.8e7 (×512) and loses
/// it at 7.7e7 (×1024). 1e7 keeps a margin of ~4 below the failure and ~130 above the default.
///
/// The spatial ratio bounds the pseudo-measurements' covariance `R_m` against the floor added
/// to it (`R̃ = R_m + r₀² I`, design §4.2.3): with `r₀²` far below `R_m` the update inverts an
/// `R̃` whose condition is `R_m / r₀²` (fuzz finding F9: `B` and `r₀²` scaled down together by
/// 2⁻⁴⁵ passed the temporal ratio; an `R_m` of 2e-4 m² against `r₀²` = 7e-17 m² made the
/// posterior variance −5e-11 m² from a prior of 5e-12). On F9's points, with `B` and `r₀²`
/// scaled together, the ratio first failed at 7e14; the default ratio is 1.6e4 (41 m² / 0.0025 m²).
pub const MAX_PRIOR_OVER_NOISE: f32 = 1e7;

/// Smallest largest prior variance, temporal (`max_k B_kk · λ₁ · σ_t²`) or spatial
/// (`σ_c² + max_k B_kk · σ_u²`), that [`Tables::validate`] accepts, m²: a lateral prior of 1 mm.
///
/// The filters multiply variances (gains, `G M Gᵀ`, the repair's correlation form), and the
/// smallest variances they reach are the noise floor, up to [`MAX_PRIOR_OVER_NOISE`] below the
/// prior: at a prior of 1e-6 m² those products stay above 1e-26, far inside f32's normal range
/// (from 1.2e-38). Fuzz finding F10: `B` scaled by 3e-22 and the Gram matrix by 1e-19 put the
/// whole temporal prior below it (6e-39 m², subnormal), and the repaired covariance was not
/// positive definite. The defaults are 186 m² and 41 m².
pub const MIN_PRIOR_VARIANCE: f32 = 1e-6;

fn all_finite<'a>(it: impl IntoIterator<Item = &'a f32>) -> bool {
    it.into_iter().all(|v| v.is_finite())
}

fn symmetric_pos_diag<const N: usize>(m: &SMatrix<f32, N, N>) -> bool {
    let scale = m.abs().max();
    (m - m.transpose()).abs().max() <= CHECK_TOL * scale && m.diagonal().iter().all(|d| *d > 0.0)
}

impl<const NT: usize, const LANES: usize, const POINTS: usize> Tables<NT, LANES, POINTS> {
    /// Checks the tables for internal consistency: version, order, finiteness, positive scalars,
    /// increasing index points, symmetric positive-diagonal covariances, `B = L Lᵀ` with `L`
    /// lower, a sound Gram basis, the stored matrices against their models, and priors that f32
    /// can update ([`TablesError::IllConditioned`]). Generated tables always pass; use it on
    /// tables loaded at run time (the tracker does not call it). `NT` must be 2..=6, `LANES`
    /// 1..=16 and `POINTS` 2..=64 (checked at compile time).
    ///
    /// # Complexity
    /// O(NT³·log + POINTS³ + LANES³) (two discretisations, the eigen-equation), no allocation.
    ///
    /// # Errors
    /// The first [`TablesError`] found.
    pub fn validate(&self) -> Result<(), TablesError> {
        const { assert!(NT >= 2 && NT <= 6, "spatial Taylor order NT must be 2..=6") };
        const { assert!(LANES >= 1 && LANES <= 16, "LANES must be 1..=16") };
        const { assert!(POINTS >= 2 && POINTS <= 64, "POINTS must be 2..=64") };
        if self.version != FORMAT_VERSION {
            return Err(TablesError::Version);
        }
        if self.hyper.spatial_order as usize != NT {
            return Err(TablesError::Order);
        }
        let h = &self.hyper;
        let scalars = [
            h.spatial_variance,
            h.spatial_lengthscale,
            h.offset_variance,
            h.temporal_variance,
            h.temporal_lengthscale,
            h.meas_noise,
            h.pseudo_noise,
            h.u_min,
            h.u_max,
            h.row_step,
            h.frame_step,
            h.gram_variance_fraction,
            self.spatial.model.qc,
            self.temporal.kernel.variance,
            self.temporal.kernel.lengthscale,
        ];
        let sp = &self.spatial;
        let tp = &self.temporal;
        if !(all_finite(&scalars)
            && all_finite(sp.model.A.iter())
            && all_finite(sp.model.p_inf.iter())
            && all_finite(sp.f.iter())
            && all_finite(sp.q.iter())
            && all_finite(tp.f.iter())
            && all_finite(tp.q.iter())
            && all_finite(tp.p_inf.iter())
            && all_finite(self.index_u.iter())
            && all_finite(self.gram.iter())
            && all_finite(self.gram_eigvec.iter())
            && all_finite(self.gram_eigval.iter())
            && all_finite(self.coreg.iter())
            && all_finite(self.coreg_chol.iter()))
        {
            return Err(TablesError::NonFinite);
        }
        if scalars.iter().any(|v| *v <= 0.0) || h.u_max <= h.u_min || h.gram_variance_fraction > 1.0
        {
            return Err(TablesError::NonPositive);
        }
        let inside = self.index_u.iter().all(|u| *u >= h.u_min && *u <= h.u_max);
        let increasing = self
            .index_u
            .iter()
            .zip(self.index_u.iter().skip(1))
            .all(|(a, b)| a < b);
        if !(inside && increasing) {
            return Err(TablesError::IndexPoints);
        }
        self.check_structure()?;
        let b_max = self.coreg.diagonal().iter().fold(0.0f32, |m, v| m.max(*v));
        let lam1 = self.gram_eigval.get(0).copied().unwrap_or(0.0);
        let prior = b_max * lam1 * self.temporal.kernel.variance;
        // The most a pseudo-measurement can carry: a lane's spatial prior at a point (F9).
        let spatial_prior = h.offset_variance + b_max * h.spatial_variance;
        // Finite positive factors (checked above): the products are finite or +inf, never NaN.
        if prior > MAX_PRIOR_OVER_NOISE * h.pseudo_noise
            || spatial_prior > MAX_PRIOR_OVER_NOISE * h.pseudo_noise
            || prior < MIN_PRIOR_VARIANCE
            || spatial_prior < MIN_PRIOR_VARIANCE
        {
            return Err(TablesError::IllConditioned);
        }
        Ok(())
    }

    /// The structural checks of [`Tables::validate`]: covariances symmetric with a positive
    /// diagonal, the Cholesky factor of B lower and reproducing B, the Gram eigenbasis
    /// orthonormal with `K V = V Λ` and decreasing non-negative eigenvalues, and the nominal
    /// transitions and stationary covariances equal to their models'.
    fn check_structure(&self) -> Result<(), TablesError> {
        let h = &self.hyper;
        let sp = &self.spatial;
        let tp = &self.temporal;
        // Lower: the lane starts (§4.1 step 6, §4.2.2) read only its lower triangle, so every
        // entry above the diagonal is 0 (any factor L·G, G orthogonal, also reproduces B).
        // (Column-major storage: entry k is row k % LANES, column k / LANES.)
        let lower = self
            .coreg_chol
            .iter()
            .enumerate()
            .all(|(k, v)| k / LANES <= k % LANES || *v == 0.0);
        let recon = (self.coreg_chol * self.coreg_chol.transpose() - self.coreg)
            .abs()
            .max()
            <= CHECK_TOL * self.coreg.abs().max();
        if !(symmetric_pos_diag(&sp.model.p_inf)
            && symmetric_pos_diag(&sp.q)
            && symmetric_pos_diag(&tp.q)
            && symmetric_pos_diag(&tp.p_inf)
            && symmetric_pos_diag(&self.gram)
            && symmetric_pos_diag(&self.coreg)
            && self.coreg_chol.diagonal().iter().all(|d| *d > 0.0)
            && lower
            && recon)
        {
            return Err(TablesError::NotPositiveDefinite);
        }
        let rank = self.gram_rank as usize;
        let decreasing = self
            .gram_eigval
            .iter()
            .zip(self.gram_eigval.iter().skip(1))
            .all(|(a, b)| a >= b);
        let nonneg = self.gram_eigval.iter().all(|v| *v >= 0.0);
        if rank == 0 || rank > POINTS || !decreasing || !nonneg {
            return Err(TablesError::GramBasis);
        }
        // The eigenbasis: orthonormal, and K V = V Λ.
        let v = &self.gram_eigvec;
        let vtv = v.transpose() * v;
        let kv = self.gram * v;
        let vl = SMatrix::<f32, POINTS, POINTS>::from_fn(|i, j| {
            v.get((i, j)).copied().unwrap_or(0.0) * self.gram_eigval.get(j).copied().unwrap_or(0.0)
        });
        let k_scale = self.gram.abs().max();
        if max_abs_diff(&vtv, &SMatrix::identity()) > MODEL_TOL
            || max_abs_diff(&kv, &vl) > MODEL_TOL * k_scale
        {
            return Err(TablesError::Inconsistent);
        }
        // The nominal transitions and stationary covariance against their models.
        let close =
            |a: &Matrix2<f32>, b: &Matrix2<f32>| max_abs_diff(a, b) <= MODEL_TOL * b.abs().max();
        let Some((tf, tq)) = tp.kernel.transition(h.frame_step) else {
            return Err(TablesError::Inconsistent);
        };
        let Some((sf, sq)) = sp.model.transition(h.row_step) else {
            return Err(TablesError::Inconsistent);
        };
        let sp_close = max_abs_diff(&sp.f, &sf) <= MODEL_TOL * sf.abs().max()
            && max_abs_diff(&sp.q, &sq) <= MODEL_TOL * sq.abs().max();
        if !(close(&tp.f, &tf)
            && close(&tp.q, &tq)
            && close(&tp.p_inf, &tp.kernel.p_inf())
            && sp_close)
        {
            return Err(TablesError::Inconsistent);
        }
        Ok(())
    }
}

#[cfg(feature = "defmt")]
impl<const NT: usize, const LANES: usize, const POINTS: usize> defmt::Format
    for Tables<NT, LANES, POINTS>
{
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(
            f,
            "Tables {{ version: {}, NT: {}, LANES: {}, POINTS: {}, hyper: {} }}",
            self.version,
            NT,
            LANES,
            POINTS,
            self.hyper
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_tables_are_valid() {
        assert_eq!(DEFAULT.validate(), Ok(()));
    }

    #[test]
    fn validate_catches_broken_tables() {
        let mut t = DEFAULT;
        t.version += 1;
        assert_eq!(t.validate(), Err(TablesError::Version));
        let mut t = DEFAULT;
        t.hyper.spatial_order = 3;
        assert_eq!(t.validate(), Err(TablesError::Order));
        let mut t = DEFAULT;
        t.gram[(3, 4)] = f32::NAN;
        assert_eq!(t.validate(), Err(TablesError::NonFinite));
        let mut t = DEFAULT;
        t.hyper.row_step = 0.0;
        assert_eq!(t.validate(), Err(TablesError::NonPositive));
        let mut t = DEFAULT;
        t.index_u[2] = t.index_u[1];
        assert_eq!(t.validate(), Err(TablesError::IndexPoints));
        let mut t = DEFAULT;
        t.coreg[(0, 1)] += 1.0;
        assert_eq!(t.validate(), Err(TablesError::NotPositiveDefinite));
        // A factor of B that is not lower: L·G with G a rotation by 0.1 rad in the (0, 1) plane
        // reproduces B (to 2e-6) but the starts read only L's lower triangle.
        let mut t = DEFAULT;
        let (c, s) = (libm::cosf(0.1), libm::sinf(0.1));
        let mut g = SMatrix::<f32, 6, 6>::identity();
        g[(0, 0)] = c;
        g[(1, 1)] = c;
        g[(0, 1)] = -s;
        g[(1, 0)] = s;
        t.coreg_chol = DEFAULT.coreg_chol * g;
        assert!(
            (t.coreg_chol * t.coreg_chol.transpose() - t.coreg)
                .abs()
                .max()
                < 1e-4
        );
        assert_eq!(t.validate(), Err(TablesError::NotPositiveDefinite));
        let mut t = DEFAULT;
        t.gram_rank = 0;
        assert_eq!(t.validate(), Err(TablesError::GramBasis));
        // A consistent rescale of the Gram matrix by 1218 (fuzz finding F3) is beyond f32.
        let mut t = DEFAULT;
        t.gram *= 1218.0;
        t.gram_eigval *= 1218.0;
        assert_eq!(t.validate(), Err(TablesError::IllConditioned));
        let mut t = DEFAULT;
        t.hyper.pseudo_noise = 1e-9;
        assert_eq!(t.validate(), Err(TablesError::IllConditioned));
        // Fuzz finding F9's bound alone: B and r₀² scaled down together by 2⁻²⁰ keep the
        // temporal ratio (7.5e4) and a temporal prior above `MIN_PRIOR_VARIANCE` (1.8e-4 m²),
        // but leave the offset prior σ_c² = 25 m² against r₀² = 2.4e-9 m² (1e10). (F9's input
        // itself, scaled by 2⁻⁴⁵, is refused by F10's bound too.)
        let mut t = DEFAULT;
        let f = libm::exp2f(-10.0);
        t.coreg *= f * f;
        t.coreg_chol *= f;
        t.hyper.pseudo_noise *= f * f;
        let prior = t.coreg.diagonal().max() * t.gram_eigval[0] * t.temporal.kernel.variance;
        assert!(
            prior >= MIN_PRIOR_VARIANCE && prior <= MAX_PRIOR_OVER_NOISE * t.hyper.pseudo_noise
        );
        assert_eq!(t.validate(), Err(TablesError::IllConditioned));
        // Fuzz finding F10: B and the Gram matrix scaled down until the temporal prior is
        // subnormal (B by 2⁻⁷², the Gram matrix and its eigenvalues by 2⁻⁶³: 6e-39 m²).
        let mut t = DEFAULT;
        t.coreg = DEFAULT.coreg * libm::exp2f(-72.0);
        t.coreg_chol = DEFAULT.coreg_chol * libm::exp2f(-36.0);
        t.gram *= libm::exp2f(-63.0);
        t.gram_eigval *= libm::exp2f(-63.0);
        assert_eq!(t.validate(), Err(TablesError::IllConditioned));
        // Only B scaled down, to a temporal prior of 1e-5 m² (by 2⁻²⁴): both ratios shrink, the
        // tables are still accepted.
        let mut t = DEFAULT;
        t.coreg *= libm::exp2f(-24.0);
        t.coreg_chol *= libm::exp2f(-12.0);
        assert_eq!(t.validate(), Ok(()));
        // Fuzz finding F4: stored matrices that disagree with their models.
        let mut t = DEFAULT;
        t.gram_eigvec[(3, 2)] = 80.0;
        assert_eq!(t.validate(), Err(TablesError::Inconsistent));
        let mut t = DEFAULT;
        t.temporal.p_inf *= 860.0;
        assert_eq!(t.validate(), Err(TablesError::Inconsistent));
        let mut t = DEFAULT;
        t.spatial.q *= 0.5;
        assert_eq!(t.validate(), Err(TablesError::Inconsistent));
    }

    #[test]
    fn default_prior_over_noise_has_margin() {
        let b = DEFAULT.coreg.diagonal().max();
        let ratio = b * DEFAULT.gram_eigval[0] * DEFAULT.temporal.kernel.variance
            / DEFAULT.hyper.pseudo_noise;
        assert!(
            ratio > 1e4 && ratio < MAX_PRIOR_OVER_NOISE / 100.0,
            "{ratio}"
        );
    }

    /// `F` within `f_tol` (absolute) and `Q` within 1e-4 of its largest entry.
    fn assert_close<const N: usize>(
        got: Option<(SMatrix<f32, N, N>, SMatrix<f32, N, N>)>,
        f: &SMatrix<f32, N, N>,
        q: &SMatrix<f32, N, N>,
        f_tol: f32,
    ) {
        let (gf, gq) = got.unwrap();
        assert!((gf - f).abs().max() < f_tol);
        assert!((gq - q).abs().max() <= 1e-4 * q.abs().max());
    }

    #[test]
    fn nominal_tables_match_runtime_discretisation() {
        let t = &DEFAULT.temporal;
        assert_close(
            t.kernel.transition(DEFAULT.hyper.frame_step),
            &t.f,
            &t.q,
            1e-6,
        );
        let s = &DEFAULT.spatial;
        assert_close(s.model.transition(DEFAULT.hyper.row_step), &s.f, &s.q, 1e-5);
    }
}
