//! Model configurations off the reference point, for the scaling curves: hyperparameter files
//! derived from `data/hyper/default.json` with another number of lane slots D or index points N.
//! Tables for them are built at run time by `stjpdacf_tools::tablegen::static_tables`.

use anyhow::{ensure, Context, Result};
use nalgebra::DMatrix;
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_tools::repo_root;
use stjpdacf_tools::tablegen::DEFAULT_HYPER;

/// BEV rows of the reference configuration (16 index points, 4 rows per interval).
pub const REFERENCE_ROWS: usize = 61;

/// The committed default hyperparameters (D = 6, N = 16).
///
/// # Errors
/// When the file cannot be read.
pub fn default_hyper() -> Result<HyperFile> {
    HyperFile::load(&repo_root().join(DEFAULT_HYPER))
}

/// The stationary profile `b_k` (mean of `B_ij` over `|i − j| = k`) of a `B`.
pub fn stationary_profile(b: &DMatrix<f64>) -> Vec<f64> {
    let d = b.nrows();
    (0..d)
        .map(|k| (0..d - k).map(|i| b[(i, i + k)]).sum::<f64>() / (d - k) as f64)
        .collect()
}

/// The default hyperparameters with `lanes` slots: `B_ij = b_|i−j|` from the default's stationary
/// profile, extended beyond the default's 6 slots with its last value (7.23 m²), written as
/// `W Wᵀ + diag(κ)` with κ = half of the smallest eigenvalue and `W` the Cholesky factor of
/// `B − κ I` (as the default file does). For `lanes ≤ 6` this is the default's leading block.
///
/// # Errors
/// When the extended `B` is not positive definite.
pub fn hyper_with_lanes(lanes: usize) -> Result<HyperFile> {
    let mut h = default_hyper()?;
    let b = stationary_profile(&h.coreg());
    let last = *b.last().context("empty B")?;
    let bm = DMatrix::from_fn(lanes, lanes, |i, j| {
        b.get(i.abs_diff(j)).copied().unwrap_or(last)
    });
    let lmin = bm.clone().symmetric_eigen().eigenvalues.min();
    ensure!(
        lmin > 0.0,
        "B extended to {lanes} slots is not positive definite"
    );
    let kappa = lmin / 2.0;
    let w = (bm - DMatrix::identity(lanes, lanes) * kappa)
        .cholesky()
        .context("B − κI is not positive definite")?
        .l();
    h.coregionalization.w = (0..lanes)
        .map(|i| (0..lanes).map(|j| w[(i, j)]).collect())
        .collect();
    h.coregionalization.kappa = vec![kappa; lanes];
    h.description = format!("bench: default with {lanes} lane slots");
    h.validate()?;
    Ok(h)
}

/// The N axis of the scaling bench: index points and the Gram rank its tables keep
/// (`gram_variance_fraction` 1 − 1e-6), which the temporal filter's `RANK` follows (a test
/// checks these against the generated tables).
pub const N_AXIS: [(usize, usize); 5] = [(6, 6), (11, 7), (16, 7), (21, 7), (31, 6)];

/// The D axis of the scaling bench (lane slots).
pub const D_AXIS: [usize; 5] = [2, 3, 4, 6, 8];

/// The M axis of the scaling bench (points per frame).
pub const M_AXIS: [usize; 5] = [64, 128, 256, 512, 768];

/// The E axis of the scaling bench (events per row).
pub const E_AXIS: [usize; 6] = [64, 128, 256, 512, 1024, 2048];

/// Rows per index interval that keep the reference's 61 rows (row step 77/60 m) with `points`
/// index points: `60 / (points − 1)`, `None` unless `points − 1` divides 60.
pub fn rows_per_interval(points: usize) -> Option<u8> {
    let n = points.checked_sub(1)?;
    if n == 0 || (REFERENCE_ROWS - 1) % n != 0 {
        return None;
    }
    u8::try_from((REFERENCE_ROWS - 1) / n).ok()
}

/// The default hyperparameters with `points` index points over the same window and the same
/// 61 rows (row step 77/60 m: `K = 60 / (points − 1)` rows per interval).
///
/// # Errors
/// When `points − 1` does not divide 60.
pub fn hyper_with_points(points: usize) -> Result<HyperFile> {
    let k = rows_per_interval(points).context("points − 1 must divide 60")?;
    let mut h = default_hyper()?;
    h.index_points = points;
    h.spatial.row_step = (h.window.u_max - h.window.u_min) / ((points - 1) * usize::from(k)) as f64;
    h.description = format!("bench: default with {points} index points, {k} rows per interval");
    h.validate()?;
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stjpdacf_tools::tablegen::{static_tables, ModelTables};

    #[test]
    fn lane_variants_keep_the_default_block_and_extend_it() {
        let b6 = default_hyper().unwrap().coreg();
        for d in [2, 3, 4, 6] {
            let b = hyper_with_lanes(d).unwrap().coreg();
            let diff = (b - b6.view((0, 0), (d, d))).abs().max();
            assert!(diff < 1e-9, "D = {d}: {diff}");
        }
        let b8 = hyper_with_lanes(8).unwrap().coreg();
        assert!((b8[(0, 7)] - b6[(0, 5)]).abs() < 1e-9);
        static_tables::<2, 2, 16>(&hyper_with_lanes(2).unwrap()).unwrap();
        static_tables::<2, 8, 16>(&hyper_with_lanes(8).unwrap()).unwrap();
    }

    #[test]
    fn point_variants_keep_61_rows() {
        assert_eq!(rows_per_interval(16), Some(4));
        assert_eq!(rows_per_interval(31), Some(2));
        assert_eq!(rows_per_interval(15), None);
        for (n, rank) in N_AXIS {
            let h = hyper_with_points(n).unwrap();
            let t = ModelTables::from_hyper(&h).unwrap();
            assert_eq!(t.gram_rank, rank, "N = {n}");
            assert!((h.spatial.row_step - 77.0 / 60.0).abs() < 1e-12);
        }
    }
}
