//! The hyperparameter file (`stjpdacf-hyper/v1`, JSON): what the table generator reads and the
//! trainer writes. Units: BEV metres (lateral `x`, longitudinal `u`) and seconds.
//!
//! ```json
//! {
//!   "schema": "stjpdacf-hyper/v1",
//!   "description": "free text: where the values come from",
//!   "window": { "u_min": 3.0, "u_max": 80.0 },
//!   "index_points": 16,
//!   "spatial": { "order": 2, "variance": 1.0, "lengthscale": 25.0,
//!                "offset_variance": 25.0, "row_step": 1.2833333333333334 },
//!   "temporal": { "variance": 1.0, "lengthscale": 30.0, "frame_step": 0.05,
//!                 "gram_variance_fraction": 0.999999 },
//!   "coregionalization": { "W": [[0.95], [0.95], ...], "kappa": [0.1, 0.1, ...] },
//!   "noise": { "measurement": 0.01, "pseudo": 0.0025 },
//!   "provenance": { ... any JSON ... }
//! }
//! ```
//!
//! * `window` — the BEV range tracked, metres ahead of the camera; `index_points` (N) are spread
//!   evenly over it (docs/design.md §4.0).
//! * `spatial` — RBF kernel of a lane's curve `g(u)`: Taylor `order` N_T (2..=6), `variance` σ_u²,
//!   `lengthscale` ℓ_u (m); `offset_variance` is the prior variance of the lane offset `c` (m²);
//!   `row_step` is the nominal spacing of BEV rows (m) for which `F_u`, `Q_u` are tabulated; the
//!   spatial filter puts `K` rows in each index interval (docs/spatial-filter.md), so it should be
//!   `(u_max − u_min) / ((index_points − 1)·K)` (77/60 m for the defaults, K = 4).
//! * `temporal` — Matérn-3/2 kernel of each index point over time: `variance` σ_t², `lengthscale`
//!   ℓ_t (s), nominal `frame_step` T (s); `gram_variance_fraction` is the share of the Gram matrix's
//!   trace kept by the truncated eigenbasis of the temporal filter.
//! * `coregionalization` — `B = W Wᵀ + diag(kappa)` over lane slots (rank from the left); `W` is
//!   D×rank, `kappa` has D entries (D = number of slots).
//! * `noise` — `measurement`: variance of a feature point's lateral position (m²); `pseudo`: r₀²
//!   added to the pseudo-measurement covariance in the temporal filter (m²).

use anyhow::{bail, ensure, Context, Result};
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// The schema tag this module reads and writes.
pub const SCHEMA: &str = "stjpdacf-hyper/v1";

/// BEV window.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Window {
    /// Near edge, metres ahead.
    pub u_min: f64,
    /// Far edge, metres ahead.
    pub u_max: f64,
}

/// Spatial RBF kernel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Spatial {
    /// Taylor order N_T (2..=6).
    pub order: usize,
    /// σ_u².
    pub variance: f64,
    /// ℓ_u, metres.
    pub lengthscale: f64,
    /// Prior variance of the lane offset state, m².
    pub offset_variance: f64,
    /// Nominal row step, metres.
    pub row_step: f64,
}

/// Temporal Matérn-3/2 kernel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Temporal {
    /// σ_t².
    pub variance: f64,
    /// ℓ_t, seconds.
    pub lengthscale: f64,
    /// Nominal frame step, seconds.
    pub frame_step: f64,
    /// Share of the Gram matrix's trace kept by the truncated eigenbasis.
    pub gram_variance_fraction: f64,
}

/// Coregionalisation `B = W Wᵀ + diag(kappa)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Coregionalization {
    /// D×rank factor.
    #[serde(rename = "W")]
    pub w: Vec<Vec<f64>>,
    /// D diagonal terms.
    pub kappa: Vec<f64>,
}

/// Noise variances.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Noise {
    /// Feature-point lateral variance, m².
    pub measurement: f64,
    /// r₀² added to pseudo-measurements, m².
    pub pseudo: f64,
}

/// A whole hyperparameter file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HyperFile {
    /// Must be [`SCHEMA`].
    pub schema: String,
    /// Free text: where the values come from.
    pub description: String,
    /// BEV window.
    pub window: Window,
    /// Number of index points N.
    pub index_points: usize,
    /// Spatial kernel.
    pub spatial: Spatial,
    /// Temporal kernel.
    pub temporal: Temporal,
    /// Coregionalisation over lane slots.
    pub coregionalization: Coregionalization,
    /// Noise variances.
    pub noise: Noise,
    /// Anything the producer wants to record (training data, dates, scores).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub provenance: Option<serde_json::Value>,
}

fn positive(name: &str, v: f64) -> Result<()> {
    ensure!(
        v.is_finite() && v > 0.0,
        "{name} must be finite and > 0, got {v}"
    );
    Ok(())
}

impl HyperFile {
    /// Reads and validates a file.
    pub fn load(path: &std::path::Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let h: Self = serde_json::from_str(&text)
            .with_context(|| format!("parsing {} as {SCHEMA}", path.display()))?;
        h.validate()
            .with_context(|| format!("checking {}", path.display()))?;
        Ok(h)
    }

    /// Checks ranges and shapes; the error says which field is wrong.
    pub fn validate(&self) -> Result<()> {
        ensure!(
            self.schema == SCHEMA,
            "schema must be {SCHEMA:?}, got {:?}",
            self.schema
        );
        ensure!(
            self.window.u_min.is_finite()
                && self.window.u_max.is_finite()
                && self.window.u_min < self.window.u_max,
            "window must have u_min < u_max"
        );
        ensure!(
            (2..=64).contains(&self.index_points),
            "index_points must be 2..=64"
        );
        ensure!(
            (2..=6).contains(&self.spatial.order),
            "spatial.order must be 2..=6"
        );
        positive("spatial.variance", self.spatial.variance)?;
        positive("spatial.lengthscale", self.spatial.lengthscale)?;
        positive("spatial.offset_variance", self.spatial.offset_variance)?;
        positive("spatial.row_step", self.spatial.row_step)?;
        positive("temporal.variance", self.temporal.variance)?;
        positive("temporal.lengthscale", self.temporal.lengthscale)?;
        positive("temporal.frame_step", self.temporal.frame_step)?;
        let f = self.temporal.gram_variance_fraction;
        ensure!(
            f > 0.0 && f <= 1.0,
            "temporal.gram_variance_fraction must be in (0, 1]"
        );
        positive("noise.measurement", self.noise.measurement)?;
        positive("noise.pseudo", self.noise.pseudo)?;
        let d = self.coregionalization.kappa.len();
        ensure!(
            (1..=16).contains(&d),
            "coregionalization.kappa must have 1..=16 entries"
        );
        ensure!(
            self.coregionalization.w.len() == d,
            "coregionalization.W must have {d} rows (one per slot)"
        );
        let rank = self.coregionalization.w.first().map_or(0, Vec::len);
        ensure!(
            self.coregionalization
                .w
                .iter()
                .all(|r| r.len() == rank && r.iter().all(|v| v.is_finite())),
            "coregionalization.W rows must have equal length and finite entries"
        );
        for k in &self.coregionalization.kappa {
            positive("coregionalization.kappa", *k)?;
        }
        Ok(())
    }

    /// Number of lane slots D.
    pub fn lanes(&self) -> usize {
        self.coregionalization.kappa.len()
    }

    /// `B = W Wᵀ + diag(kappa)`.
    pub fn coreg(&self) -> DMatrix<f64> {
        let d = self.lanes();
        let rank = self.coregionalization.w.first().map_or(0, Vec::len);
        let w = DMatrix::from_fn(d, rank, |i, j| self.coregionalization.w[i][j]);
        &w * w.transpose()
            + DMatrix::from_diagonal(&nalgebra::DVector::from_vec(
                self.coregionalization.kappa.clone(),
            ))
    }

    /// Index points, evenly spaced over the window.
    pub fn index_u(&self) -> Vec<f64> {
        let n = self.index_points;
        let (a, b) = (self.window.u_min, self.window.u_max);
        (0..n)
            .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
            .collect()
    }

    /// Fails unless the file describes `lanes` slots and `points` index points (the capacities of
    /// the tables type being generated).
    pub fn require_shape(&self, lanes: usize, points: usize) -> Result<()> {
        if self.lanes() != lanes || self.index_points != points {
            bail!(
                "file has D = {} slots and N = {} index points, expected D = {lanes}, N = {points}",
                self.lanes(),
                self.index_points
            );
        }
        Ok(())
    }
}
