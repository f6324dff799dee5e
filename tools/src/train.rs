//! Training the spatial kernel, the coregionalisation `B` and the temporal length-scale from
//! labelled lanes (docs/design.md §6, the paper's Algorithm 2), in f64 on the host.
//!
//! # Spatial model (intrinsic coregionalisation, ICM)
//! A frame holds lanes `d = 0..D_f` (slots = rank from the left at the bottom of the BEV window,
//! docs/design.md §4.0), each observed as lateral positions `x` at longitudinal positions `u` (metres).
//! The lanes of one frame are jointly Gaussian with zero mean and
//!
//! `cov(x_d(u), x_d'(u')) = B[d,d']·σ²·exp(−(u−u')²/(2ℓ²)) + [d = d']·σ_c² + [same point]·noise`
//!
//! where `B = W Wᵀ + diag(κ)` (W is D×R, R ≤ D), `σ_c²` is the prior variance of the per-lane
//! offset `c` of docs/design.md §4.0 (marginalised analytically; `σ_c² = 0` disables it) and `noise` the
//! label noise. A frame with `D_f < D` lanes uses the leading `D_f×D_f` block of `B`. Frames are
//! independent: the objective is the sum of per-frame log marginal likelihoods (LML).
//!
//! The LML and its analytic gradient (w.r.t. `log ℓ`, `log noise`, `log κ`, the entries of `W`,
//! and optionally `log σ²`, `log σ_c²`) are computed from a Cholesky factor:
//! `LML = −½ yᵀα − Σ log L_ii − ½ n log 2π` with `α = K⁻¹y`, and
//! `∂LML/∂θ = ½ tr((ααᵀ − K⁻¹) ∂K/∂θ)`. For `B`, with `G[a,b] = Σ_{i∈a, j∈b} (ααᵀ − K⁻¹)_ij σ² k_ij`,
//! `∂LML/∂W = G W` and `∂LML/∂log κ_a = ½ κ_a G[a,a]`.
//!
//! The maximiser is argmin's L-BFGS (More–Thuente line search) on `−LML / n_points`, from several
//! seeded starting points.
//!
//! # Temporal model
//! A Matérn-3/2 GP in time, `k(τ) = σ_t² (1 + λ|τ|) e^{−λ|τ|}`, `λ = √3/ℓ_t`, plus a marginalised
//! constant offset and noise, fitted by the same machinery to per-index-point series; see
//! [`temporal_series`] for where the series come from (TuSimple labels one frame per clip).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Mutex;

use anyhow::{bail, ensure, Context, Result};
use argmin::core::{CostFunction, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;

const LN_2PI: f64 = 1.837_877_066_409_345_3;

// ---------------------------------------------------------------------------------------------
// Data
// ---------------------------------------------------------------------------------------------

/// One lane of a training frame: lateral positions `x` (m) at longitudinal positions `u` (m).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Lane {
    /// Longitudinal positions, metres ahead.
    pub u: Vec<f64>,
    /// Lateral positions, metres.
    pub x: Vec<f64>,
}

/// One training frame: its lanes in slot order (slot = index in `lanes`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Lanes, left to right.
    pub lanes: Vec<Lane>,
}

impl Frame {
    /// Total number of points.
    pub fn points(&self) -> usize {
        self.lanes.iter().map(|l| l.u.len()).sum()
    }
}

/// One line of a TuSimple label file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LabelFrame {
    /// The labelled image, e.g. `clips/0601/1494453497604532231/20.jpg`.
    pub raw_file: String,
    /// Image rows of the samples.
    pub h_samples: Vec<f64>,
    /// Per lane, the column at each row; negative (−2) means no point.
    pub lanes: Vec<Vec<f64>>,
}

impl LabelFrame {
    /// The lanes mapped to BEV: per lane, `(u, x)` points with `u` ascending (all of them, no
    /// window, no subsampling). Lanes without a point below the horizon are left out.
    pub fn bev_lanes(&self, cam: &Camera) -> Vec<Vec<(f64, f64)>> {
        self.lanes
            .iter()
            .map(|cols| {
                let mut pts: Vec<(f64, f64)> = cols
                    .iter()
                    .zip(&self.h_samples)
                    .filter(|(&c, _)| c >= 0.0)
                    .filter_map(|(&c, &r)| cam.to_bev(c, r))
                    .collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                pts
            })
            .filter(|p| !p.is_empty())
            .collect()
    }

    /// The recording session and time of the clip if its name is a nanosecond timestamp
    /// (`clips/0601/1494453497604532231/20.jpg` → `("0601", 1494453497.604532231)`); TuSimple's
    /// `0313-*` clips are numbered, not time-stamped, and give `None`.
    pub fn session_time(&self) -> Option<(String, f64)> {
        let mut parts = self.raw_file.split('/');
        let _clips = parts.next()?;
        let session = parts.next()?;
        let clip = parts.next()?;
        if clip.len() < 16 || !clip.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        let ns: u64 = clip.parse().ok()?;
        Some((session.to_string(), ns as f64 * 1e-9))
    }
}

/// Reads TuSimple label files (JSON lines), checking each label's shape as
/// `tusimple::read_labels` does (`TuSimpleRecord::check_shape`: `h_samples` non-empty, every
/// lane one value per row).
pub fn read_labels(path: &Path) -> Result<Vec<LabelFrame>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            let label: LabelFrame = serde_json::from_str(l).with_context(|| {
                format!("{}:{}: not a TuSimple label line", path.display(), i + 1)
            })?;
            crate::tusimple::TuSimpleRecord {
                raw_file: label.raw_file.clone(),
                lanes: label.lanes.clone(),
                h_samples: label.h_samples.clone(),
                run_time: None,
            }
            .check_shape()
            .with_context(|| format!("{}:{}: bad TuSimple label", path.display(), i + 1))?;
            Ok(label)
        })
        .collect()
}

/// How label frames become training frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameConfig {
    /// Near edge of the BEV window, m.
    pub u_min: f64,
    /// Far edge of the BEV window, m.
    pub u_max: f64,
    /// Minimum spacing in `u` between kept points of a lane, m (subsampling).
    pub spacing: f64,
    /// Lanes with fewer kept points are left out.
    pub min_points: usize,
    /// Frames with more lanes than this (the number of slots D) are left out.
    pub max_lanes: usize,
}

/// Linear extrapolation/interpolation of a lane's `x` at `u` from its two points nearest in `u`
/// (one point: that point's `x`).
fn lane_x_near(pts: &[(f64, f64)], u: f64) -> Option<f64> {
    let mut by_dist: Vec<&(f64, f64)> = pts.iter().collect();
    by_dist.sort_by(|a, b| (a.0 - u).abs().total_cmp(&(b.0 - u).abs()));
    match by_dist.as_slice() {
        [] => None,
        [p] => Some(p.1),
        [a, b, ..] if (b.0 - a.0).abs() > 1e-9 => Some(a.1 + (b.1 - a.1) * (u - a.0) / (b.0 - a.0)),
        [a, ..] => Some(a.1),
    }
}

/// Turns one label frame into a training frame: BEV points inside the window, subsampled to at
/// least `spacing` metres apart, lanes with at least `min_points` points, ordered left to right
/// by their lateral position at the bottom of the window (`u_min`, extrapolated from the two
/// nearest points). `None` if no lane is left or there are more than `max_lanes`.
pub fn label_to_frame(label: &LabelFrame, cam: &Camera, cfg: &FrameConfig) -> Option<Frame> {
    let mut lanes: Vec<(f64, Lane)> = label
        .bev_lanes(cam)
        .into_iter()
        .filter_map(|pts| {
            let inside: Vec<(f64, f64)> = pts
                .into_iter()
                .filter(|&(u, _)| u >= cfg.u_min && u <= cfg.u_max)
                .collect();
            let mut kept: Vec<(f64, f64)> = Vec::new();
            for p in &inside {
                if kept.last().is_none_or(|l| p.0 - l.0 >= cfg.spacing) {
                    kept.push(*p);
                }
            }
            if kept.len() < cfg.min_points.max(1) {
                return None;
            }
            let key = lane_x_near(&inside, cfg.u_min)?;
            Some((
                key,
                Lane {
                    u: kept.iter().map(|p| p.0).collect(),
                    x: kept.iter().map(|p| p.1).collect(),
                },
            ))
        })
        .collect();
    if lanes.is_empty() || lanes.len() > cfg.max_lanes {
        return None;
    }
    lanes.sort_by(|a, b| a.0.total_cmp(&b.0));
    Some(Frame {
        lanes: lanes.into_iter().map(|(_, l)| l).collect(),
    })
}

// ---------------------------------------------------------------------------------------------
// Shared GP core
// ---------------------------------------------------------------------------------------------

/// `LML = log N(y; 0, K)` and `M = ααᵀ − K⁻¹` (`α = K⁻¹ y`), from which
/// `∂LML/∂θ = ½ Σ_ij M_ij ∂K_ij/∂θ`. Fails if `K` is not numerically positive definite.
pub fn gaussian_lml(k: DMatrix<f64>, y: &DVector<f64>) -> Result<(f64, DMatrix<f64>)> {
    let n = y.len();
    ensure!(k.nrows() == n && k.ncols() == n, "K and y disagree in size");
    let chol = k
        .cholesky()
        .context("covariance is not positive definite (Cholesky failed)")?;
    let alpha = chol.solve(y);
    let logdet: f64 = chol.l_dirty().diagonal().iter().map(|v| v.ln()).sum();
    let lml = -0.5 * y.dot(&alpha) - logdet - 0.5 * n as f64 * LN_2PI;
    let m = &alpha * alpha.transpose() - chol.inverse();
    Ok((lml, m))
}

// ---------------------------------------------------------------------------------------------
// ICM model
// ---------------------------------------------------------------------------------------------

/// Parameters of the spatial ICM model (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct IcmParams {
    /// D×R factor of `B`.
    pub w: DMatrix<f64>,
    /// The D diagonal terms `κ` of `B`.
    pub kappa: DVector<f64>,
    /// RBF variance σ² (fixed at 1 in the coupled model: `B` carries the scale).
    pub variance: f64,
    /// RBF length-scale ℓ, metres.
    pub lengthscale: f64,
    /// Per-lane offset variance σ_c², m² (0 = no offset term).
    pub offset_variance: f64,
    /// Noise variance, m².
    pub noise: f64,
}

impl IcmParams {
    /// Number of slots D.
    pub fn lanes(&self) -> usize {
        self.kappa.len()
    }

    /// `B = W Wᵀ + diag(κ)`.
    pub fn b(&self) -> DMatrix<f64> {
        &self.w * self.w.transpose() + DMatrix::from_diagonal(&self.kappa)
    }

    /// The kernel of these parameters with `b` as `B` (normally [`Self::b`]).
    pub fn kernel<'a>(&self, b: &'a DMatrix<f64>) -> IcmKernel<'a> {
        IcmKernel {
            b,
            variance: self.variance,
            lengthscale: self.lengthscale,
            offset_variance: self.offset_variance,
            noise: self.noise,
        }
    }
}

/// The ICM kernel under an explicit `B` (any symmetric positive definite matrix): what the
/// covariance of a frame needs.
#[derive(Debug, Clone, Copy)]
pub struct IcmKernel<'a> {
    /// `B`, at least as large as the frames' lane counts.
    pub b: &'a DMatrix<f64>,
    /// RBF variance σ².
    pub variance: f64,
    /// RBF length-scale ℓ, metres.
    pub lengthscale: f64,
    /// Per-lane offset variance σ_c², m².
    pub offset_variance: f64,
    /// Noise variance, m².
    pub noise: f64,
}

/// The covariance of one frame's stacked points (lane-major) under the kernel `k`. `k.b` must
/// have at least as many rows as the frame has lanes.
pub fn icm_covariance(frame: &Frame, k: &IcmKernel<'_>) -> DMatrix<f64> {
    let (lane, u, _) = stack(frame);
    let n = u.len();
    DMatrix::from_fn(n, n, |i, j| {
        let (a, c) = (lane[i], lane[j]);
        let d = u[i] - u[j];
        let mut v =
            k.b[(a, c)] * k.variance * (-d * d / (2.0 * k.lengthscale * k.lengthscale)).exp();
        if a == c {
            v += k.offset_variance;
        }
        if i == j {
            v += k.noise;
        }
        v
    })
}

fn stack(frame: &Frame) -> (Vec<usize>, Vec<f64>, DVector<f64>) {
    let mut lane = Vec::new();
    let mut u = Vec::new();
    let mut x = Vec::new();
    for (d, l) in frame.lanes.iter().enumerate() {
        for (&ui, &xi) in l.u.iter().zip(&l.x) {
            lane.push(d);
            u.push(ui);
            x.push(xi);
        }
    }
    (lane, u, DVector::from_vec(x))
}

/// The summed LML of independent frames under the kernel `k`.
pub fn icm_lml(frames: &[Frame], k: &IcmKernel<'_>) -> Result<f64> {
    let mut total = 0.0;
    for f in frames {
        ensure!(f.lanes.len() <= k.b.nrows(), "frame has more lanes than B");
        let k = icm_covariance(f, k);
        let (_, _, y) = stack(f);
        total += gaussian_lml(k, &y)?.0;
    }
    Ok(total)
}

/// Which parameters are free and how the parameter vector θ is laid out:
/// `[log ℓ, log noise, log κ_0..κ_{D−1}, W (row-major, D×R), (log σ²), (log σ_c²)]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Layout {
    /// Number of slots D.
    pub lanes: usize,
    /// Columns R of `W`.
    pub rank: usize,
    /// Train σ² (otherwise fixed at its initial value).
    pub train_variance: bool,
    /// Train σ_c² (otherwise fixed at its initial value).
    pub train_offset: bool,
}

impl Layout {
    /// Length of θ.
    pub fn len(&self) -> usize {
        2 + self.lanes
            + self.lanes * self.rank
            + usize::from(self.train_variance)
            + usize::from(self.train_offset)
    }

    /// Never empty (ℓ and the noise are always free); provided for clippy's `len_without_is_empty`.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// θ from parameters (shapes must match the layout).
    pub fn pack(&self, p: &IcmParams) -> Vec<f64> {
        let mut t = vec![p.lengthscale.ln(), p.noise.ln()];
        t.extend(p.kappa.iter().map(|k| k.ln()));
        for i in 0..self.lanes {
            for j in 0..self.rank {
                t.push(p.w[(i, j)]);
            }
        }
        if self.train_variance {
            t.push(p.variance.ln());
        }
        if self.train_offset {
            t.push(p.offset_variance.ln());
        }
        t
    }

    /// Parameters from θ; the fixed ones are taken from `fixed`.
    pub fn unpack(&self, t: &[f64], fixed: &IcmParams) -> IcmParams {
        let d = self.lanes;
        let r = self.rank;
        let kappa = DVector::from_fn(d, |i, _| t[2 + i].exp());
        let w = DMatrix::from_fn(d, r, |i, j| t[2 + d + i * r + j]);
        let mut k = 2 + d + d * r;
        let variance = if self.train_variance {
            k += 1;
            t[k - 1].exp()
        } else {
            fixed.variance
        };
        let offset_variance = if self.train_offset {
            t[k].exp()
        } else {
            fixed.offset_variance
        };
        IcmParams {
            w,
            kappa,
            variance,
            lengthscale: t[0].exp(),
            offset_variance,
            noise: t[1].exp(),
        }
    }
}

/// Summed LML of the frames and its gradient w.r.t. θ (layout [`Layout`]).
pub fn icm_lml_grad(frames: &[Frame], p: &IcmParams, layout: &Layout) -> Result<(f64, Vec<f64>)> {
    let d = layout.lanes;
    ensure!(
        p.lanes() == d && p.w.nrows() == d && p.w.ncols() == layout.rank,
        "parameters do not match the layout"
    );
    let b = p.b();
    let l2 = p.lengthscale * p.lengthscale;
    let mut lml = 0.0;
    let (mut g_ell, mut g_noise, mut g_var, mut g_off) = (0.0, 0.0, 0.0, 0.0);
    let mut g_b = DMatrix::<f64>::zeros(d, d);
    for f in frames {
        ensure!(f.lanes.len() <= d, "frame has more lanes than slots");
        let (lane, u, y) = stack(f);
        let n = u.len();
        let kern = DMatrix::from_fn(n, n, |i, j| {
            let du = u[i] - u[j];
            (-du * du / (2.0 * l2)).exp()
        });
        let k = DMatrix::from_fn(n, n, |i, j| {
            let mut v = b[(lane[i], lane[j])] * p.variance * kern[(i, j)];
            if lane[i] == lane[j] {
                v += p.offset_variance;
            }
            if i == j {
                v += p.noise;
            }
            v
        });
        let (v, m) = gaussian_lml(k, &y)?;
        lml += v;
        for j in 0..n {
            for i in 0..n {
                let mij = m[(i, j)];
                let mk = mij * p.variance * kern[(i, j)];
                let bk = b[(lane[i], lane[j])] * mk;
                let du = u[i] - u[j];
                g_ell += bk * du * du / l2;
                g_var += bk;
                g_b[(lane[i], lane[j])] += mk;
                if lane[i] == lane[j] {
                    g_off += mij;
                }
            }
            g_noise += m[(j, j)];
        }
    }
    let mut g = vec![0.5 * g_ell, 0.5 * g_noise * p.noise];
    g.extend((0..d).map(|a| 0.5 * g_b[(a, a)] * p.kappa[a]));
    let gw = &g_b * &p.w;
    for i in 0..d {
        for j in 0..layout.rank {
            g.push(gw[(i, j)]);
        }
    }
    if layout.train_variance {
        g.push(0.5 * g_var);
    }
    if layout.train_offset {
        g.push(0.5 * g_off * p.offset_variance);
    }
    Ok((lml, g))
}

/// Draws frames from the ICM model (for recovery tests): lane `d` of frame `k` is observed at
/// `grids[k][d]`.
pub fn simulate_frames(p: &IcmParams, grids: &[Vec<Vec<f64>>], seed: u64) -> Result<Vec<Frame>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let b = p.b();
    grids
        .iter()
        .map(|lanes| {
            let mut f = Frame {
                lanes: lanes
                    .iter()
                    .map(|u| Lane {
                        u: u.clone(),
                        x: vec![0.0; u.len()],
                    })
                    .collect(),
            };
            let k = icm_covariance(&f, &p.kernel(&b));
            let l = k.cholesky().context("model covariance not PD")?.unpack();
            let z = DVector::from_fn(l.nrows(), |_, _| rng.sample::<f64, _>(StandardNormal));
            let y = l * z;
            let mut it = y.iter();
            for lane in &mut f.lanes {
                for x in &mut lane.x {
                    *x = *it.next().context("size mismatch")?;
                }
            }
            Ok(f)
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Optimisation
// ---------------------------------------------------------------------------------------------

/// An objective to maximise: θ ↦ (value, gradient).
pub type Objective<'a> = dyn Fn(&[f64]) -> Result<(f64, Vec<f64>)> + Sync + 'a;

/// The last evaluation: (θ, cost, gradient of the cost).
type Cached = Option<(Vec<f64>, f64, Vec<f64>)>;

/// A minimisation problem for argmin: `cost(θ) = −objective(θ)/scale`, with the gradient from the
/// same evaluation (cached, so argmin's separate cost and gradient calls cost one evaluation).
struct Problem<'a> {
    eval: &'a Objective<'a>,
    scale: f64,
    cache: Mutex<Cached>,
    on_eval: &'a (dyn Fn(f64) + Sync),
}

impl Problem<'_> {
    fn get(&self, t: &[f64]) -> Result<(f64, Vec<f64>), argmin::core::Error> {
        let mut cache = self
            .cache
            .lock()
            .map_err(|_| argmin::core::Error::msg("cache poisoned"))?;
        if let Some((ct, c, g)) = cache.as_ref() {
            if ct.as_slice() == t {
                return Ok((*c, g.clone()));
            }
        }
        let (v, g) = (self.eval)(t).map_err(|e| argmin::core::Error::msg(format!("{e:#}")))?;
        if !v.is_finite() || g.iter().any(|x| !x.is_finite()) {
            return Err(argmin::core::Error::msg("non-finite objective"));
        }
        (self.on_eval)(v);
        let c = -v / self.scale;
        let g: Vec<f64> = g.iter().map(|x| -x / self.scale).collect();
        *cache = Some((t.to_vec(), c, g.clone()));
        Ok((c, g))
    }
}

impl CostFunction for Problem<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, p: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        Ok(self.get(p)?.0)
    }
}

impl Gradient for Problem<'_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, p: &Vec<f64>) -> Result<Vec<f64>, argmin::core::Error> {
        Ok(self.get(p)?.1)
    }
}

/// Outcome of one L-BFGS run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunOutcome {
    /// Best θ found.
    pub theta: Vec<f64>,
    /// Objective (LML) at `theta`.
    pub lml: f64,
    /// L-BFGS iterations.
    pub iterations: u64,
    /// argmin's termination status, as text.
    pub status: String,
}

/// Maximises `objective` (value and gradient) from `init` with L-BFGS; `scale` divides the
/// objective (use the number of data points so that tolerances are per point).
pub fn maximise(
    objective: &Objective<'_>,
    init: Vec<f64>,
    scale: f64,
    max_iters: u64,
    on_eval: &(dyn Fn(f64) + Sync),
) -> Result<RunOutcome> {
    let problem = Problem {
        eval: objective,
        scale,
        cache: Mutex::new(None),
        on_eval,
    };
    let solver = LBFGS::new(MoreThuenteLineSearch::new(), 10)
        .with_tolerance_grad(1e-9)?
        .with_tolerance_cost(1e-13)?;
    let res = Executor::new(problem, solver)
        .configure(|s| s.param(init).max_iters(max_iters))
        .run()?;
    let state = res.state();
    let theta = state
        .get_best_param()
        .context("optimiser returned no parameters")?
        .clone();
    let (v, _) = objective(&theta)?;
    Ok(RunOutcome {
        theta,
        lml: v,
        iterations: state.get_iter(),
        status: format!("{}", state.get_termination_status()),
    })
}

/// Training configuration for the ICM model.
#[derive(Debug, Clone, PartialEq)]
pub struct FitConfig {
    /// Free parameters and the shape of `W`.
    pub layout: Layout,
    /// Start of restart 0, and the values of the fixed parameters.
    pub init: IcmParams,
    /// Number of starts (restart 0 from `init`, the others randomised around it).
    pub restarts: usize,
    /// Seed of the randomised starts.
    pub seed: u64,
    /// L-BFGS iterations per start.
    pub max_iters: u64,
}

/// One start of [`fit_icm`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RestartReport {
    /// Index of the start (0 = the given initial values).
    pub index: usize,
    /// LML at the starting point (`None` if it could not be evaluated).
    pub initial_lml: Option<f64>,
    /// LML reached (`None` if the run failed).
    pub lml: Option<f64>,
    /// L-BFGS iterations.
    pub iterations: u64,
    /// Termination status or the error.
    pub status: String,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// Result of [`fit_icm`].
#[derive(Debug, Clone, PartialEq)]
pub struct FitResult {
    /// Best parameters over all starts.
    pub params: IcmParams,
    /// Their LML.
    pub lml: f64,
    /// Per start.
    pub restarts: Vec<RestartReport>,
}

/// A randomised start around `init`: ℓ × e^{U(−1,1)}, noise × e^{U(−1.5,1.5)},
/// κ × e^{U(−1,1)}, W entries N(0, s²) with `s² = mean diag(B_init) / R`.
pub fn random_start(init: &IcmParams, layout: &Layout, rng: &mut ChaCha8Rng) -> IcmParams {
    let mut p = init.clone();
    let r = layout.rank.max(1);
    let mean_diag = init.b().diagonal().mean().max(1e-6);
    let s = (mean_diag / r as f64).sqrt();
    p.lengthscale *= rng.random_range(-1.0f64..1.0).exp();
    p.noise *= rng.random_range(-1.5f64..1.5).exp();
    p.kappa = p.kappa.map(|k| k * rng.random_range(-1.0f64..1.0).exp());
    p.w = DMatrix::from_fn(layout.lanes, layout.rank, |_, _| {
        s * rng.sample::<f64, _>(StandardNormal)
    });
    if layout.train_variance {
        p.variance *= rng.random_range(-0.5f64..0.5).exp();
    }
    if layout.train_offset {
        p.offset_variance *= rng.random_range(-1.0f64..1.0).exp();
    }
    p
}

/// Fits the ICM model to the frames: L-BFGS from `cfg.restarts` starts, keeps the best.
/// `progress(start, evaluations, current LML)` is called after every evaluation.
pub fn fit_icm(
    frames: &[Frame],
    cfg: &FitConfig,
    progress: &(dyn Fn(usize, usize, f64) + Sync),
) -> Result<FitResult> {
    ensure!(cfg.restarts >= 1, "need at least one start");
    ensure!(!frames.is_empty(), "no training frames");
    let layout = cfg.layout;
    let n_points: usize = frames.iter().map(Frame::points).sum();
    let objective = |t: &[f64]| icm_lml_grad(frames, &layout.unpack(t, &cfg.init), &layout);
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut best: Option<(f64, IcmParams)> = None;
    let mut reports = Vec::new();
    for index in 0..cfg.restarts {
        let start = if index == 0 {
            cfg.init.clone()
        } else {
            random_start(&cfg.init, &layout, &mut rng)
        };
        let theta0 = layout.pack(&start);
        let initial_lml = objective(&theta0).ok().map(|v| v.0);
        let evals = std::sync::atomic::AtomicUsize::new(0);
        let on_eval = |v: f64| {
            let k = evals.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress(index, k, v);
        };
        let t0 = std::time::Instant::now();
        let out = maximise(&objective, theta0, n_points as f64, cfg.max_iters, &on_eval);
        let seconds = t0.elapsed().as_secs_f64();
        match out {
            Ok(o) => {
                if best.as_ref().is_none_or(|(b, _)| o.lml > *b) {
                    best = Some((o.lml, layout.unpack(&o.theta, &cfg.init)));
                }
                reports.push(RestartReport {
                    index,
                    initial_lml,
                    lml: Some(o.lml),
                    iterations: o.iterations,
                    status: o.status,
                    seconds,
                });
            }
            Err(e) => reports.push(RestartReport {
                index,
                initial_lml,
                lml: None,
                iterations: 0,
                status: format!("failed: {e:#}"),
                seconds,
            }),
        }
    }
    let Some((lml, params)) = best else {
        bail!("every start failed: {reports:?}");
    };
    Ok(FitResult {
        params,
        lml,
        restarts: reports,
    })
}

/// The stationary form of `B`: `b_k` = mean of `B_ij` over `|i − j| = k`, `k = 0..D`.
pub fn stationary_profile(b: &DMatrix<f64>) -> Vec<f64> {
    let d = b.nrows();
    (0..d)
        .map(|k| (0..d - k).map(|i| b[(i, i + k)]).sum::<f64>() / (d - k) as f64)
        .collect()
}

/// The Toeplitz matrix of [`stationary_profile`].
pub fn stationary_b(b: &DMatrix<f64>) -> DMatrix<f64> {
    let p = stationary_profile(b);
    DMatrix::from_fn(b.nrows(), b.ncols(), |i, j| p[i.abs_diff(j)])
}

/// Extends a fitted `B` over `d_fit` slots to `d ≥ d_fit` slots for which the data hold no frame:
/// the leading block stays the fitted `B`; entries involving a new slot take the stationary
/// profile of the fitted `B` (the value at `|i − j|`, the last value beyond its length); new
/// slots get the mean of the fitted `κ`. If that is not positive definite, the cross terms of
/// the new slots are shrunk by 10 % steps until `B_ext − diag(κ_ext)` is positive semi-definite.
/// Returns `(W, κ)` with `W = V Λ^{1/2}` from the eigen-decomposition of `B_ext − diag(κ_ext)`,
/// so `W Wᵀ + diag(κ) = B_ext` (to rounding) and the fitted block is reproduced.
pub fn extend_stationary(
    b_fit: &DMatrix<f64>,
    kappa_fit: &DVector<f64>,
    d: usize,
) -> Result<(DMatrix<f64>, DVector<f64>)> {
    let df = b_fit.nrows();
    ensure!(df >= 1 && d >= df, "cannot extend {df} slots to {d}");
    ensure!(kappa_fit.len() == df, "κ and B disagree in size");
    let prof = stationary_profile(b_fit);
    let at = |k: usize| prof.get(k).or(prof.last()).copied().unwrap_or(0.0);
    let k_mean = kappa_fit.mean();
    let kappa = DVector::from_fn(d, |i, _| if i < df { kappa_fit[i] } else { k_mean });
    let mut shrink = 1.0;
    for attempt in 0..=60 {
        if attempt == 60 {
            shrink = 0.0;
        }
        let m = DMatrix::from_fn(d, d, |i, j| {
            let v = if i < df && j < df {
                b_fit[(i, j)]
            } else if i == j {
                at(0)
            } else {
                shrink * at(i.abs_diff(j))
            };
            v - if i == j { kappa[i] } else { 0.0 }
        });
        let eig = m.symmetric_eigen();
        let top = eig.eigenvalues.amax();
        if eig.eigenvalues.min() >= -1e-12 * top {
            let root = eig.eigenvalues.map(|v| v.max(0.0).sqrt());
            let w = &eig.eigenvectors * DMatrix::from_diagonal(&root);
            return Ok((w, kappa));
        }
        shrink *= 0.9;
    }
    bail!("could not extend B to {d} slots with B − diag(κ) positive semi-definite")
}

/// Correlation matrix `B_ij / sqrt(B_ii B_jj)`.
pub fn correlation(b: &DMatrix<f64>) -> DMatrix<f64> {
    DMatrix::from_fn(b.nrows(), b.ncols(), |i, j| {
        b[(i, j)] / (b[(i, i)] * b[(j, j)]).sqrt()
    })
}

// ---------------------------------------------------------------------------------------------
// Temporal Matérn-3/2
// ---------------------------------------------------------------------------------------------

/// A scalar time series: values `y` at times `t` (seconds).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Series {
    /// Times, seconds, ascending.
    pub t: Vec<f64>,
    /// Values.
    pub y: Vec<f64>,
}

/// Matérn-3/2 model of a series: `σ² (1+λ|τ|) e^{−λ|τ|} + σ_c² + noise·δ`, `λ = √3/ℓ`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MaternParams {
    /// σ².
    pub variance: f64,
    /// ℓ, seconds.
    pub lengthscale: f64,
    /// Constant-offset variance σ_c² (fixed, marginalised; 0 disables it).
    pub offset_variance: f64,
    /// Noise variance.
    pub noise: f64,
}

/// Summed LML of independent series and its gradient w.r.t.
/// `[log σ², log ℓ, log noise]`.
pub fn matern_lml_grad(series: &[Series], p: &MaternParams) -> Result<(f64, [f64; 3])> {
    let lam = 3f64.sqrt() / p.lengthscale;
    let mut lml = 0.0;
    let mut g = [0.0; 3];
    for s in series {
        let n = s.t.len();
        let r = DMatrix::from_fn(n, n, |i, j| (s.t[i] - s.t[j]).abs());
        let k = DMatrix::from_fn(n, n, |i, j| {
            let x = lam * r[(i, j)];
            p.variance * (1.0 + x) * (-x).exp()
                + p.offset_variance
                + if i == j { p.noise } else { 0.0 }
        });
        let (v, m) = gaussian_lml(k, &DVector::from_column_slice(&s.y))?;
        lml += v;
        for j in 0..n {
            for i in 0..n {
                let x = lam * r[(i, j)];
                let e = (-x).exp();
                g[0] += 0.5 * m[(i, j)] * p.variance * (1.0 + x) * e;
                g[1] += 0.5 * m[(i, j)] * p.variance * x * x * e;
            }
            g[2] += 0.5 * m[(j, j)] * p.noise;
        }
    }
    Ok((lml, g))
}

/// Fits σ², ℓ and the noise of [`MaternParams`] (σ_c² fixed) by L-BFGS from `starts`.
/// Returns the best parameters, their LML, and the LML reached from each start.
pub fn fit_matern(
    series: &[Series],
    starts: &[MaternParams],
    max_iters: u64,
) -> Result<(MaternParams, f64, Vec<Option<f64>>)> {
    ensure!(!series.is_empty(), "no series");
    let n: usize = series.iter().map(|s| s.t.len()).sum();
    let mut best: Option<(f64, MaternParams)> = None;
    let mut per = Vec::new();
    for s0 in starts {
        let fixed = *s0;
        let unpack = move |t: &[f64]| MaternParams {
            variance: t[0].exp(),
            lengthscale: t[1].exp(),
            offset_variance: fixed.offset_variance,
            noise: t[2].exp(),
        };
        let obj = |t: &[f64]| matern_lml_grad(series, &unpack(t)).map(|(v, g)| (v, g.to_vec()));
        let init = vec![s0.variance.ln(), s0.lengthscale.ln(), s0.noise.ln()];
        match maximise(&obj, init, n as f64, max_iters, &|_| {}) {
            Ok(o) => {
                per.push(Some(o.lml));
                if best.as_ref().is_none_or(|(b, _)| o.lml > *b) {
                    best = Some((o.lml, unpack(&o.theta)));
                }
            }
            Err(_) => per.push(None),
        }
    }
    let Some((lml, p)) = best else {
        bail!("every Matérn start failed");
    };
    Ok((p, lml, per))
}

/// Per-index-point time series from time-stamped label frames.
///
/// TuSimple labels only the 20th frame of each 1 s clip, so there are no labelled video
/// sequences. The clips of the `0531` and `0601` sessions are named by a nanosecond timestamp,
/// and consecutive labelled clips of one session are mostly 2–8 s apart; the `0313-*` clips are
/// numbered, not time-stamped, and are not used. For each session, frames are ordered by time and
/// cut into segments wherever two consecutive frames are more than `max_gap` seconds apart. In
/// every frame the two lanes bounding the ego lane (nearest to `x = 0` on the left and on the
/// right at `u_ref`) are followed; at each index point `u_i` their lateral position (linear
/// interpolation between label points; points outside a lane's extent are missing) forms one
/// series per (segment, side, index point). Series with fewer than `min_len` values are dropped.
/// Identity is by side only, so a lane change shows up as a jump of one lane width — that is
/// real lateral motion at the scale these series can see.
pub fn temporal_series(
    labels: &[LabelFrame],
    cam: &Camera,
    index_u: &[f64],
    u_ref: f64,
    max_gap: f64,
    min_len: usize,
) -> Vec<Series> {
    let mut sessions: BTreeMap<String, Vec<(f64, &LabelFrame)>> = BTreeMap::new();
    for l in labels {
        if let Some((s, t)) = l.session_time() {
            sessions.entry(s).or_default().push((t, l));
        }
    }
    let mut out = Vec::new();
    for (_, mut frames) in sessions {
        frames.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut segments: Vec<Vec<(f64, &LabelFrame)>> = Vec::new();
        for f in frames {
            match segments.last_mut() {
                Some(seg) if seg.last().is_some_and(|p| f.0 - p.0 <= max_gap) => seg.push(f),
                _ => segments.push(vec![f]),
            }
        }
        for seg in segments {
            let t0 = seg.first().map_or(0.0, |p| p.0);
            // series[side][i] = (t, x)
            let mut acc = vec![
                vec![
                    Series {
                        t: vec![],
                        y: vec![]
                    };
                    index_u.len()
                ];
                2
            ];
            for (t, l) in &seg {
                let lanes = l.bev_lanes(cam);
                let keyed: Vec<(f64, &Vec<(f64, f64)>)> = lanes
                    .iter()
                    .filter_map(|p| lane_x_near(p, u_ref).map(|x| (x, p)))
                    .collect();
                let left = keyed
                    .iter()
                    .filter(|(x, _)| *x < 0.0)
                    .max_by(|a, b| a.0.total_cmp(&b.0));
                let right = keyed
                    .iter()
                    .filter(|(x, _)| *x >= 0.0)
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                for (side, lane) in [left, right].into_iter().enumerate() {
                    let Some((_, pts)) = lane else { continue };
                    for (i, &u) in index_u.iter().enumerate() {
                        if let Some(x) = interpolate(pts, u) {
                            acc[side][i].t.push(t - t0);
                            acc[side][i].y.push(x);
                        }
                    }
                }
            }
            out.extend(acc.into_iter().flatten().filter(|s| s.t.len() >= min_len));
        }
    }
    out
}

/// Linear interpolation of `x` at `u` inside the lane's extent (points sorted by `u`).
fn interpolate(pts: &[(f64, f64)], u: f64) -> Option<f64> {
    pts.windows(2).find_map(|w| {
        let ((ua, xa), (ub, xb)) = (w[0], w[1]);
        (ua <= u && u <= ub && ub > ua).then(|| xa + (xb - xa) * (u - ua) / (ub - ua))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn label_frame_slots_left_to_right() {
        let cam = Camera::tusimple();
        let h: Vec<f64> = (0..48).map(|i| 240.0 + 10.0 * i as f64).collect();
        // Three straight lanes through the vanishing point, given right-to-left, one of them
        // too short to keep.
        let lane = |x_bottom: f64, rows: std::ops::Range<usize>| -> Vec<f64> {
            h.iter()
                .enumerate()
                .map(|(i, &r)| {
                    if rows.contains(&i) {
                        cam.to_image(cam.focal_px * cam.height_m / (r - cam.vp_row), x_bottom)
                            .unwrap()
                            .0
                    } else {
                        -2.0
                    }
                })
                .collect()
        };
        let label = LabelFrame {
            raw_file: "clips/x/1/20.jpg".into(),
            h_samples: h.clone(),
            lanes: vec![lane(1.8, 2..48), lane(-1.9, 2..48), lane(5.5, 46..48)],
        };
        let cfg = FrameConfig {
            u_min: 3.0,
            u_max: 80.0,
            spacing: 3.0,
            min_points: 3,
            max_lanes: 6,
        };
        let f = label_to_frame(&label, &cam, &cfg).unwrap();
        assert_eq!(f.lanes.len(), 2);
        assert!((f.lanes[0].x[0] + 1.9).abs() < 1e-9 && (f.lanes[1].x[0] - 1.8).abs() < 1e-9);
        for l in &f.lanes {
            assert!(l.u.windows(2).all(|w| w[1] - w[0] >= 3.0));
            assert!(l.u.iter().all(|&u| (3.0..=80.0).contains(&u)));
        }
        let one = FrameConfig {
            max_lanes: 1,
            ..cfg
        };
        assert!(label_to_frame(&label, &cam, &one).is_none());
    }

    #[test]
    fn session_time_only_for_timestamps() {
        let mut l = LabelFrame {
            raw_file: "clips/0601/1494453497604532231/20.jpg".into(),
            h_samples: vec![],
            lanes: vec![],
        };
        let (s, t) = l.session_time().unwrap();
        assert_eq!(s, "0601");
        assert!((t - 1_494_453_497.604_532).abs() < 1e-3);
        l.raw_file = "clips/0313-1/6040/20.jpg".into();
        assert!(l.session_time().is_none());
    }

    #[test]
    fn extension_keeps_fitted_block() {
        // Full-rank W, as the trainer fits (rank = number of fitted slots).
        let w = DMatrix::from_row_slice(3, 3, &[1.0, 0.2, 0.1, 0.9, -0.1, 0.2, 0.7, 0.3, -0.2]);
        let kappa = DVector::from_vec(vec![0.1, 0.2, 0.15]);
        let b = &w * w.transpose() + DMatrix::from_diagonal(&kappa);
        let (we, ke) = extend_stationary(&b, &kappa, 5).unwrap();
        let be = &we * we.transpose() + DMatrix::from_diagonal(&ke);
        assert!((be.view((0, 0), (3, 3)) - &b).amax() < 1e-12);
        assert_eq!(we.shape(), (5, 5));
        let prof = stationary_profile(&b);
        assert!((be[(4, 4)] - prof[0]).abs() < 1e-12);
        assert!(be.clone().cholesky().is_some());
        assert!((be[(3, 4)] - be[(4, 3)]).abs() < 1e-12);
        assert!(extend_stationary(&b, &kappa, 2).is_err());
    }

    #[test]
    fn stationary_profile_averages_diagonals() {
        let b = DMatrix::from_row_slice(3, 3, &[1.0, 0.5, 0.1, 0.5, 2.0, 0.7, 0.1, 0.7, 3.0]);
        let p = stationary_profile(&b);
        assert!((p[0] - 2.0).abs() < 1e-15 && (p[1] - 0.6).abs() < 1e-15);
        assert!((p[2] - 0.1).abs() < 1e-15);
        assert_eq!(stationary_b(&b)[(0, 2)], p[2]);
    }
}
