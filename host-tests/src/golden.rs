//! Reading the golden files (`data/golden/*.json`: values computed by GPy, scipy and numpy) in
//! tests. Every function panics, naming what it expected, when the file or value is not there.

use nalgebra::DMatrix;
use serde_json::Value;

/// `data/golden/<name>`, parsed.
///
/// # Panics
/// When the file cannot be read or is not JSON.
pub fn load(name: &str) -> Value {
    let path = stjpdacf_tools::repo_root().join("data/golden").join(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("bad JSON in {}: {e}", path.display()))
}

/// A number.
///
/// # Panics
/// When `v` is not a number.
pub fn num(v: &Value) -> f64 {
    v.as_f64()
        .unwrap_or_else(|| panic!("expected a number, got {v}"))
}

/// A list of numbers.
///
/// # Panics
/// When `v` is not one.
pub fn vecf(v: &Value) -> Vec<f64> {
    serde_json::from_value(v.clone())
        .unwrap_or_else(|e| panic!("expected a list of numbers ({e}), got {v}"))
}

/// A non-empty row-major list of rows as a matrix.
///
/// # Panics
/// When `v` is not a list of rows of numbers, or has no row.
pub fn mat(v: &Value) -> DMatrix<f64> {
    let rows: Vec<Vec<f64>> = serde_json::from_value(v.clone())
        .unwrap_or_else(|e| panic!("expected a matrix ({e}), got {v}"));
    DMatrix::from_fn(rows.len(), rows[0].len(), |i, j| rows[i][j])
}
