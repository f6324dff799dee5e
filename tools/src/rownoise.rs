//! The within-frame row-noise scale of the spatial filter (docs/design.md §11.12), fitted to
//! labelled lanes by maximum likelihood.
//!
//! The spatial filter walks a lane row by row with the tables' state-space model: an offset
//! `c ~ N(0, σ_c²)` plus `g ~ B_dd · GP(0, k_u)` in its `N_T`-state approximation, `F(Δu)` and
//! `Q(Δu)` between rows, point noise `r`. The kernel and `B` are trained on whole frames through
//! the exact RBF (§6), but at `N_T = 2` the approximation's spectrum falls as `ω⁻⁴` where the
//! RBF's falls as `e^{−ω²ℓ²/2}`: from one row to the next the state-space lane bends far more
//! freely than a painted lane does. A scale `s` on `Q(Δu)` (the first row keeps `B_dd P∞`)
//! restores that; here `s` maximises the likelihood of label lanes run through exactly that
//! filter (a Kalman filter per lane, its innovations' log densities summed), with `B_dd`, `σ_c²`,
//! `r` and the row spacing of the tables. `stjpdacf row-noise` runs it.

use anyhow::{ensure, Context, Result};
use argmin::core::{CostFunction, Executor};
use argmin::solver::brent::BrentOpt;
use nalgebra::{DMatrix, DVector};
use stjpdacf_reference::model::ModelTables;
use stjpdacf_reference::statespace::discretize;

use crate::train::Lane;

/// The model the lanes are scored under.
#[derive(Debug, Clone)]
pub struct RowModel {
    /// `A_u`.
    pub a: DMatrix<f64>,
    /// `P∞_u` (unit variance).
    pub p_inf: DMatrix<f64>,
    /// The slot variance `B_dd`, m².
    pub b: f64,
    /// Offset prior variance `σ_c²`, m².
    pub offset_variance: f64,
    /// Point noise `r`, m².
    pub noise: f64,
}

impl RowModel {
    /// The model of a set of tables: `B_00` (the default B is stationary), their `σ_c²` and `r`.
    pub fn from_tables(t: &ModelTables) -> Self {
        Self {
            a: t.spatial_a.clone(),
            p_inf: t.spatial_p_inf.clone(),
            b: t.coreg[(0, 0)],
            offset_variance: t.hyper.spatial.offset_variance,
            noise: t.hyper.noise.measurement,
        }
    }

    /// Log-likelihood of one lane (points in increasing `u`) with the row noise scaled by `s`.
    /// `None` if a step is not increasing or an innovation variance is not positive.
    pub fn lane_log_likelihood(&self, lane: &Lane, s: f64) -> Option<f64> {
        let nt = self.a.nrows();
        let ns = nt + 1;
        let mut x = DVector::<f64>::zeros(ns);
        let mut p = DMatrix::<f64>::zeros(ns, ns);
        p[(0, 0)] = self.offset_variance;
        p.view_mut((1, 1), (nt, nt))
            .copy_from(&(&self.p_inf * self.b));
        let mut ll = 0.0;
        for (k, (&u, &z)) in lane.u.iter().zip(&lane.x).enumerate() {
            if k > 0 {
                let du = u - lane.u[k - 1];
                if du.is_nan() || du <= 0.0 {
                    return None;
                }
                let (f, q) = discretize(&self.a, &self.p_inf, du);
                let mut fb = DMatrix::<f64>::identity(ns, ns);
                fb.view_mut((1, 1), (nt, nt)).copy_from(&f);
                let mut qb = DMatrix::<f64>::zeros(ns, ns);
                qb.view_mut((1, 1), (nt, nt)).copy_from(&(q * (self.b * s)));
                x = &fb * x;
                p = &fb * &p * fb.transpose() + qb;
            }
            // h = [1, 1, 0, …]: the offset plus g.
            let ph = p.column(0) + p.column(1);
            let sv = ph[0] + ph[1] + self.noise;
            if sv.is_nan() || sv <= 0.0 {
                return None;
            }
            let e = z - (x[0] + x[1]);
            ll -= 0.5 * ((2.0 * std::f64::consts::PI * sv).ln() + e * e / sv);
            let gain = &ph / sv;
            x += &gain * e;
            p -= &gain * ph.transpose();
            p = (&p + p.transpose()) * 0.5;
        }
        Some(ll)
    }

    /// Summed log-likelihood of the lanes at scale `s`.
    pub fn log_likelihood(&self, lanes: &[Lane], s: f64) -> Result<f64> {
        lanes.iter().try_fold(0.0, |acc, l| {
            self.lane_log_likelihood(l, s)
                .map(|v| acc + v)
                .context("a lane's points are not increasing in u")
        })
    }
}

struct NegLogLikelihood<'a> {
    model: &'a RowModel,
    lanes: &'a [Lane],
}

impl CostFunction for NegLogLikelihood<'_> {
    type Param = f64;
    type Output = f64;
    fn cost(&self, log10_s: &f64) -> Result<f64, argmin::core::Error> {
        Ok(-self
            .model
            .log_likelihood(self.lanes, 10f64.powf(*log10_s))?)
    }
}

/// The fit: the scale, its log-likelihood and the profile it was bracketed from.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RowNoiseFit {
    /// The maximum-likelihood scale `s`.
    pub scale: f64,
    /// Log-likelihood at `scale`.
    pub log_likelihood: f64,
    /// Log-likelihood at `s = 1` (the tables' model).
    pub log_likelihood_unscaled: f64,
    /// `(s, log-likelihood)` on the bracketing grid, 10^(k/4) for k = −16..=4.
    pub profile: Vec<(f64, f64)>,
    /// Lanes and points scored.
    pub lanes: usize,
    /// Points scored.
    pub points: usize,
}

/// Fits `s` over 1e-4..10: a grid in log10 s brackets the maximum, Brent's method (argmin)
/// refines it in log10 s.
pub fn fit(model: &RowModel, lanes: &[Lane]) -> Result<RowNoiseFit> {
    ensure!(!lanes.is_empty(), "no lanes to fit the row noise on");
    let grid: Vec<f64> = (-16..=4).map(|k| f64::from(k) / 4.0).collect();
    let profile: Vec<(f64, f64)> = grid
        .iter()
        .map(|&g| Ok((10f64.powf(g), model.log_likelihood(lanes, 10f64.powf(g))?)))
        .collect::<Result<_>>()?;
    let best = profile
        .iter()
        .enumerate()
        .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
        .map(|(i, _)| i)
        .context("empty profile")?;
    let lo = grid[best.saturating_sub(1)];
    let hi = grid[(best + 1).min(grid.len() - 1)];
    let res = Executor::new(NegLogLikelihood { model, lanes }, BrentOpt::new(lo, hi))
        .configure(|st| st.max_iters(100))
        .run()
        .map_err(|e| anyhow::anyhow!("Brent's method: {e}"))?;
    let st = res.state();
    let log10_s = st.best_param.context("Brent's method returned no point")?;
    let scale = 10f64.powf(log10_s);
    Ok(RowNoiseFit {
        scale,
        log_likelihood: model.log_likelihood(lanes, scale)?,
        log_likelihood_unscaled: model.log_likelihood(lanes, 1.0)?,
        profile,
        lanes: lanes.len(),
        points: lanes.iter().map(|l| l.u.len()).sum(),
    })
}

/// The lanes of label frames as the spatial filter sees them: BEV points inside the tables'
/// window, at least one row step (`spatial.row_step`) apart, lanes with at least 3 points.
pub fn label_lanes(
    labels: &[crate::train::LabelFrame],
    camera: &crate::camera::Camera,
    t: &ModelTables,
) -> Vec<Lane> {
    let cfg = crate::train::FrameConfig {
        u_min: t.hyper.window.u_min,
        u_max: t.hyper.window.u_max,
        spacing: t.hyper.spatial.row_step,
        min_points: 3,
        max_lanes: usize::MAX,
    };
    labels
        .iter()
        .filter_map(|l| crate::train::label_to_frame(l, camera, &cfg))
        .flat_map(|f| f.lanes)
        .collect()
}
