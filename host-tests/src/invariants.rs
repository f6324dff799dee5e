//! Invariants of the core's published state, shared by the fuzz targets (`host-tests/src/fuzz.rs`
//! includes this file), the soak (`stjpdacf_test_support::soak`) and the fault-injection tests: finite
//! published numbers, variances ≥ 0, existence in [0, 1], extents inside the window, ≤ `LANES`
//! lanes with unique ids and slots, counters consistent with the input, and the temporal
//! covariance finite, symmetric within [`ASYM_TOL`] and PSD within [`PSD_TOL`] in correlation
//! form ([`cov_health`]). Depends only on `stjpdacf` and `nalgebra`.

use nalgebra::{DMatrix, SMatrix};
use stjpdacf::spatial::filter::LaneObservation;
use stjpdacf::tables::{ReferenceTables, DEFAULT};
use stjpdacf::temporal::filter::TemporalFilter;
use stjpdacf::temporal::smoother::Temporal;
use stjpdacf::tracker::{ReferenceTracker, StepOutput};

/// Lane slots of the reference configuration.
pub const LANES: usize = 6;
/// Index points of the reference configuration.
pub const POINTS: usize = 16;
/// Retained Gram components of the reference configuration.
pub const RANK: usize = 7;
/// Temporal state size `2·LANES·RANK`.
pub const NX: usize = 84;
/// Points per frame the reference tracker uses (`MEAS`).
pub const MEAS: usize = 256;

/// Largest asymmetry `|P_ij − P_ji| / √(P_ii P_jj)` accepted. The filter symmetrises after every
/// update and its prediction `F̄ P F̄ᵀ + Q` is symmetric up to one rounding per entry (≈ 6e-8
/// relative); 1e-5 is two orders of magnitude above that and still far below anything that
/// could move a published variance.
pub const ASYM_TOL: f64 = 1e-5;

/// Most negative eigenvalue accepted for the correlation form `D^{-1/2} P D^{-1/2}` of the active
/// block (`D = diag P`). One f32 rounding of the update `P − PH S⁻¹ PHᵀ` perturbs entry `(i, j)`
/// by about `n·ε·√(P_ii P_jj)` with `n = 84`, `ε = 6e-8`, so the correlation form by
/// `‖δC‖₂ ≤ n·max|δC_ij| ≈ n²ε ≈ 4e-4`; the filter's update is a contraction, so the error does
/// not accumulate. 1e-3 is that bound with a margin of 2.5; the soak measures the real figure.
pub const PSD_TOL: f64 = 1e-3;

/// Scale-free health figures of a covariance matrix (restricted to a set of indices).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CovHealth {
    /// Dimension checked.
    pub dim: usize,
    /// Largest `|P_ij − P_ji| / √(P_ii P_jj)`.
    pub asym: f64,
    /// Smallest eigenvalue of the correlation form (1 for a diagonal matrix; `NaN` when not
    /// computed).
    pub min_eig_corr: f64,
    /// Smallest eigenvalue of `P` over its largest diagonal entry (`NaN` when not computed).
    pub min_eig_rel: f64,
}

/// How [`cov_health`] tests positive semi-definiteness.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PsdCheck {
    /// Cholesky of `C + PSD_TOL·I` (cheap yes/no; the eigenvalue fields are `NaN`).
    Cholesky,
    /// Full symmetric eigen-decomposition (fills the eigenvalue fields).
    Eigen,
}

/// The health figures of `p` restricted to `idx` without judging them (asymmetry and both
/// smallest eigenvalues; `NaN` figures for a non-finite matrix).
pub fn eigen_figures<const N: usize>(p: &SMatrix<f32, N, N>, idx: &[usize]) -> CovHealth {
    let n = idx.len();
    let m = DMatrix::<f64>::from_fn(n, n, |a, b| {
        p.get((idx[a], idx[b])).copied().map_or(f64::NAN, f64::from)
    });
    let mut h = CovHealth {
        dim: n,
        asym: 0.0,
        min_eig_corr: f64::NAN,
        min_eig_rel: f64::NAN,
    };
    if n == 0 || m.iter().any(|v| !v.is_finite()) {
        return h;
    }
    let s: Vec<f64> = (0..n)
        .map(|i| {
            if m[(i, i)] > 0.0 {
                m[(i, i)].sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let c = DMatrix::<f64>::from_fn(n, n, |a, b| m[(a, b)] / (s[a] * s[b]));
    for a in 0..n {
        for b in 0..a {
            h.asym = h.asym.max((c[(a, b)] - c[(b, a)]).abs());
        }
    }
    let cs = (&c + c.transpose()) * 0.5;
    h.min_eig_corr = cs
        .symmetric_eigenvalues()
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let scale = (0..n).map(|i| m[(i, i)]).fold(0.0, f64::max);
    let lo = ((&m + m.transpose()) * 0.5)
        .symmetric_eigenvalues()
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    h.min_eig_rel = if scale > 0.0 { lo / scale } else { 0.0 };
    h
}

/// Checks `p` restricted to `idx`: finite, non-negative diagonal, symmetric within [`ASYM_TOL`],
/// PSD within [`PSD_TOL`] in correlation form (entries with a zero diagonal count as scale 1).
///
/// # Errors
/// A description of the first violation.
pub fn cov_health<const N: usize>(
    p: &SMatrix<f32, N, N>,
    idx: &[usize],
    check: PsdCheck,
) -> Result<CovHealth, String> {
    let n = idx.len();
    let mut h = CovHealth {
        dim: n,
        min_eig_corr: f64::NAN,
        min_eig_rel: f64::NAN,
        ..CovHealth::default()
    };
    if n == 0 {
        return Ok(h);
    }
    let m = DMatrix::<f64>::from_fn(n, n, |a, b| {
        p.get((idx[a], idx[b])).copied().map_or(f64::NAN, f64::from)
    });
    if m.iter().any(|v| !v.is_finite()) {
        return Err("covariance holds a non-finite entry".into());
    }
    let d: Vec<f64> = (0..n).map(|i| m[(i, i)]).collect();
    if let Some(i) = d.iter().position(|v| *v < 0.0) {
        return Err(format!("covariance diagonal {i} is negative: {}", d[i]));
    }
    let s: Vec<f64> = d
        .iter()
        .map(|v| if *v > 0.0 { v.sqrt() } else { 1.0 })
        .collect();
    let c = DMatrix::<f64>::from_fn(n, n, |a, b| m[(a, b)] / (s[a] * s[b]));
    for a in 0..n {
        for b in 0..a {
            h.asym = h.asym.max((c[(a, b)] - c[(b, a)]).abs());
        }
    }
    if h.asym > ASYM_TOL {
        return Err(format!(
            "covariance asymmetry {:.3e} > {ASYM_TOL:e}",
            h.asym
        ));
    }
    let cs = (&c + c.transpose()) * 0.5;
    match check {
        PsdCheck::Cholesky => {
            let shifted = &cs + DMatrix::<f64>::identity(n, n) * PSD_TOL;
            if shifted.cholesky().is_none() {
                return Err(format!(
                    "covariance not PSD within {PSD_TOL:e} (correlation form, dim {n})"
                ));
            }
        }
        PsdCheck::Eigen => {
            let e = eigen_figures(p, idx);
            h.min_eig_corr = e.min_eig_corr;
            h.min_eig_rel = e.min_eig_rel;
            if h.min_eig_corr < -PSD_TOL {
                return Err(format!(
                    "covariance min eigenvalue {:.3e} < -{PSD_TOL:e} (correlation form, dim {n})",
                    h.min_eig_corr
                ));
            }
        }
    }
    Ok(h)
}

/// The index points present in a spatial observation.
pub fn present_indices(o: &LaneObservation<POINTS>) -> Vec<usize> {
    (0..POINTS).filter(|&i| o.present[i]).collect()
}

/// `R + r₀² I` over the present index points of `o` (`R` its pseudo-measurement covariance,
/// `r₀² = pseudo_noise`): the measurement covariance the temporal update takes (finding F1: not
/// positive definite when its smallest eigenvalue is negative).
pub fn observation_cov_with_noise(o: &LaneObservation<POINTS>, pseudo_noise: f32) -> DMatrix<f64> {
    let idx = present_indices(o);
    DMatrix::<f64>::from_fn(idx.len(), idx.len(), |a, b| {
        f64::from(o.cov[(idx[a], idx[b])]) + if a == b { f64::from(pseudo_noise) } else { 0.0 }
    })
}

/// State indices of the active slots of a temporal filter.
pub fn active_indices(f: &TemporalFilter<LANES, POINTS, RANK, NX>) -> Vec<usize> {
    let mut idx = Vec::new();
    for s in (0..LANES).filter(|&s| f.is_active(s)) {
        for j in 0..RANK {
            for c in 0..2 {
                idx.push(TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, c));
            }
        }
    }
    idx
}

/// Checks the temporal stage: covariance health over the active slots, finite mean, every
/// active lane's positions finite and variances ≥ 0, every smoothed lane likewise.
///
/// # Errors
/// A description of the first violation.
pub fn check_temporal(
    t: &Temporal<LANES, POINTS, RANK, NX, 42, 4>,
    tables: &ReferenceTables,
    check: PsdCheck,
) -> Result<CovHealth, String> {
    let f = t.filter();
    if f.mean().iter().any(|v| !v.is_finite()) {
        return Err("temporal mean holds a non-finite entry".into());
    }
    let h = cov_health(f.covariance(), &active_indices(f), check)?;
    for s in 0..LANES {
        if let Some((z, var)) = f.lane(tables, s) {
            check_lane_values("filtered", s, z.as_slice(), var.as_slice())?;
        }
        for lag in 1..=4 {
            if let Some((z, var)) = t.lagged(tables, s, lag) {
                check_lane_values("smoothed", s, z.as_slice(), var.as_slice())?;
            }
        }
    }
    Ok(h)
}

/// Checks one lane's published positions (finite) and variances (finite, ≥ 0).
///
/// # Errors
/// A description of the first violation.
pub fn check_lane_values(what: &str, s: usize, z: &[f32], var: &[f32]) -> Result<(), String> {
    if let Some(i) = z.iter().position(|v| !v.is_finite()) {
        return Err(format!("{what} lane {s}: position {i} is {}", z[i]));
    }
    if let Some(i) = var.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(format!("{what} lane {s}: variance {i} is {:e}", var[i]));
    }
    Ok(())
}

/// Checks one published step output of the reference tracker given `n_points` input points,
/// in its default configuration (with the known-lane stage: every caller's), so also that every
/// smoothed lane is a lane published now, in the same slot (docs/design.md §11.5).
///
/// # Errors
/// A description of the first violation.
pub fn check_output(out: &StepOutput<LANES, POINTS>, n_points: usize) -> Result<(), String> {
    let (u_min, u_max) = (DEFAULT.hyper.u_min, DEFAULT.hyper.u_max);
    let rep = &out.report;
    let used = n_points.min(MEAS);
    if rep.over_budget_points as usize != n_points - used {
        return Err(format!(
            "over_budget_points {} for {n_points} points",
            rep.over_budget_points
        ));
    }
    let sp = &rep.spatial;
    if sp.points_in as usize != used {
        return Err(format!(
            "spatial points_in {} for {used} used",
            sp.points_in
        ));
    }
    let rejected = sp.rejected_non_finite as usize
        + sp.rejected_window as usize
        + sp.rejected_duplicate as usize
        + sp.rejected_row_full as usize;
    if rejected > used {
        return Err(format!("{rejected} points rejected of {used}"));
    }
    if !(rep.dt.is_finite() && rep.dt >= 0.0) {
        return Err(format!("dt {}", rep.dt));
    }
    for (what, lanes) in [("filtered", &out.filtered), ("smoothed", &out.smoothed)] {
        if lanes.len() > LANES {
            return Err(format!("{} {what} lanes", lanes.len()));
        }
        let mut ids: Vec<u32> = lanes.iter().map(|l| l.id.0).collect();
        let mut slots: Vec<u8> = lanes.iter().map(|l| l.slot).collect();
        ids.sort_unstable();
        ids.dedup();
        slots.sort_unstable();
        slots.dedup();
        if ids.len() != lanes.len() || slots.len() != lanes.len() {
            return Err(format!("{what}: ids or slots not unique"));
        }
        for l in lanes {
            let s = usize::from(l.slot);
            if s >= LANES {
                return Err(format!("{what}: slot {s}"));
            }
            check_lane_values(what, s, l.z.as_slice(), l.var.as_slice())?;
            if !(l.existence.is_finite() && (0.0..=1.0).contains(&l.existence)) {
                return Err(format!("{what} lane {s}: existence {}", l.existence));
            }
            let ext_ok = l.u_first.is_finite()
                && l.u_last.is_finite()
                && l.u_first <= l.u_last
                && l.u_first >= u_min - 1.0
                && l.u_last <= u_max + 1.0;
            if !ext_ok {
                return Err(format!(
                    "{what} lane {s}: extent {} .. {}",
                    l.u_first, l.u_last
                ));
            }
        }
    }
    if let Some(l) = out.smoothed.iter().find(|l| {
        !out.filtered
            .iter()
            .any(|f| f.id == l.id && f.slot == l.slot)
    }) {
        return Err(format!(
            "smoothed lane {:?} (slot {}) is not published now",
            l.id, l.slot
        ));
    }
    Ok(())
}

/// Checks the tracker's temporal state and `lane_at` after a step.
///
/// # Errors
/// A description of the first violation.
pub fn check_tracker(t: &ReferenceTracker, check: PsdCheck) -> Result<CovHealth, String> {
    let h = check_temporal(t.temporal(), &DEFAULT, check)?;
    for s in 0..LANES {
        for u in [DEFAULT.hyper.u_min, 17.5, 41.0, DEFAULT.hyper.u_max] {
            if let Some((m, v)) = t.lane_at(s, u) {
                if !(m.is_finite() && v.is_finite() && v >= 0.0) {
                    return Err(format!("lane_at({s}, {u}) = ({m}, {v})"));
                }
            }
        }
    }
    Ok(h)
}
