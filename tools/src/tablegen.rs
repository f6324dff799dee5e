//! The offline table generator: hyperparameter file → f64 model matrices → a Rust source file of
//! `static` f32 tables for the core (`stjpdacf::tables::Tables`).
//!
//! The f64 matrices come from the reference crate ([`ModelTables`]); the only f32 step is the
//! final rounding when the values are written as literals.

use std::fmt::Write as _;

use anyhow::{ensure, Result};
use nalgebra::{DMatrix, DVector, SVector};
use stjpdacf::kernel::{Matern32 as CoreMatern32, RbfStateSpace};
use stjpdacf::tables::{Hyper, SpatialTables, Tables, TemporalTables};

use stjpdacf_reference::hyper::HyperFile;
pub use stjpdacf_reference::model::ModelTables;

/// The layout version written into generated tables (must equal `stjpdacf::tables::FORMAT_VERSION`).
pub const FORMAT_VERSION: u32 = 1;

/// The core's tables `Tables<NT, LANES, POINTS>` (f32) for the f64 model tables `t`, validated.
///
/// The values are the same f32 roundings [`render`] writes as literals, so for the committed
/// hyperparameter file this equals `stjpdacf::tables::DEFAULT` bit for bit (a test checks it).
///
/// # Errors
/// When the hyperparameters' order, slot count or index point count differ from `NT`, `LANES`
/// or `POINTS`, or the core's [`Tables::validate`] refuses the result.
pub fn core_tables<const NT: usize, const LANES: usize, const POINTS: usize>(
    t: &ModelTables,
) -> Result<Tables<NT, LANES, POINTS>> {
    let h = &t.hyper;
    ensure!(
        h.spatial.order == NT,
        "hyperparameters have spatial order {}, the tables type {NT}",
        h.spatial.order
    );
    h.require_shape(LANES, POINTS)?;
    let f = |v: f64| v as f32;
    let m = |d: &DMatrix<f64>| d.map(|v| v as f32);
    let tables = Tables {
        version: stjpdacf::tables::FORMAT_VERSION,
        hyper: Hyper {
            spatial_order: u32::try_from(NT)?,
            spatial_variance: f(h.spatial.variance),
            spatial_lengthscale: f(h.spatial.lengthscale),
            offset_variance: f(h.spatial.offset_variance),
            temporal_variance: f(h.temporal.variance),
            temporal_lengthscale: f(h.temporal.lengthscale),
            meas_noise: f(h.noise.measurement),
            pseudo_noise: f(h.noise.pseudo),
            u_min: f(h.window.u_min),
            u_max: f(h.window.u_max),
            row_step: f(h.spatial.row_step),
            frame_step: f(h.temporal.frame_step),
            gram_variance_fraction: f(h.temporal.gram_variance_fraction),
        },
        spatial: SpatialTables {
            model: RbfStateSpace {
                A: m(&t.spatial_a).fixed_view::<NT, NT>(0, 0).into_owned(),
                qc: f(t.spatial_qc),
                p_inf: m(&t.spatial_p_inf).fixed_view::<NT, NT>(0, 0).into_owned(),
            },
            f: m(&t.spatial_f).fixed_view::<NT, NT>(0, 0).into_owned(),
            q: m(&t.spatial_q).fixed_view::<NT, NT>(0, 0).into_owned(),
        },
        temporal: TemporalTables {
            kernel: CoreMatern32::new(f(h.temporal.variance), f(h.temporal.lengthscale)),
            f: m(&t.temporal_f).fixed_view::<2, 2>(0, 0).into_owned(),
            q: m(&t.temporal_q).fixed_view::<2, 2>(0, 0).into_owned(),
            p_inf: m(&t.temporal_p_inf).fixed_view::<2, 2>(0, 0).into_owned(),
        },
        index_u: SVector::from_fn(|i, _| f(t.index_u[i])),
        gram: m(&t.gram).fixed_view::<POINTS, POINTS>(0, 0).into_owned(),
        gram_eigvec: m(&t.gram_eigvec)
            .fixed_view::<POINTS, POINTS>(0, 0)
            .into_owned(),
        gram_eigval: SVector::from_fn(|i, _| f(t.gram_eigval[i])),
        gram_rank: u32::try_from(t.gram_rank)?,
        coreg: m(&t.coreg).fixed_view::<LANES, LANES>(0, 0).into_owned(),
        coreg_chol: m(&t.coreg_chol)
            .fixed_view::<LANES, LANES>(0, 0)
            .into_owned(),
    };
    tables
        .validate()
        .map_err(|e| anyhow::anyhow!("generated tables are invalid: {e}"))?;
    Ok(tables)
}

/// Tables for any configuration, built at run time from a hyperparameter file and leaked to
/// `'static` (what `stjpdacf::tracker::Tracker::new` takes): for tools and benches that need
/// other `NT`, `LANES` or `POINTS` than the committed tables. Each call leaks one
/// `size_of::<Tables<NT, LANES, POINTS>>()` (2,648 B at the reference configuration).
///
/// # Errors
/// As [`ModelTables::from_hyper`] and [`core_tables`].
pub fn static_tables<const NT: usize, const LANES: usize, const POINTS: usize>(
    h: &HyperFile,
) -> Result<&'static Tables<NT, LANES, POINTS>> {
    let t = core_tables::<NT, LANES, POINTS>(&ModelTables::from_hyper(h)?)?;
    Ok(Box::leak(Box::new(t)))
}

fn lit(v: f64) -> Result<String> {
    let f = v as f32;
    ensure!(f.is_finite(), "value {v:?} does not fit an f32 table");
    Ok(format!("{f:?}"))
}

/// `SMatrix::from_array_storage(ArrayStorage([[col 0], [col 1], …]))` (column-major).
fn matrix(m: &DMatrix<f64>) -> Result<String> {
    let mut s = String::from("SMatrix::from_array_storage(ArrayStorage([\n");
    for c in m.column_iter() {
        let vals: Result<Vec<String>> = c.iter().map(|v| lit(*v)).collect();
        writeln!(s, "        [{}],", vals?.join(", "))?;
    }
    s.push_str("    ]))");
    Ok(s)
}

fn vector(v: &DVector<f64>) -> Result<String> {
    matrix(&DMatrix::from_column_slice(v.len(), 1, v.as_slice()))
}

/// Writes the tables as a Rust module defining `pub static {name}: Tables<NT, D, N>`.
///
/// `origin` names the hyperparameter file in the header (use a repository-relative path so the
/// output does not depend on where it was generated).
pub fn render(t: &ModelTables, name: &str, origin: &str) -> Result<String> {
    // The name goes into the source as is: it must be a Rust identifier.
    ensure!(
        name.chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
            && name != "_",
        "--name {name:?} is not a Rust identifier (letters, digits and `_`, not starting with a \
         digit)"
    );
    let h = &t.hyper;
    let (nt, d, n) = (h.spatial.order, h.lanes(), h.index_points);
    let mut s = String::new();
    writeln!(
        s,
        "//! Generated by `stjpdacf tables --hyper {origin}`: do not edit."
    )?;
    writeln!(
        s,
        "//! Regenerate with the same command; a host test fails when this file is stale."
    )?;
    writeln!(s, "//!")?;
    for line in h.description.split('\n') {
        writeln!(s, "//! {}", line.trim_end())?;
    }
    writeln!(s)?;
    writeln!(s, "use nalgebra::{{ArrayStorage, SMatrix}};")?;
    writeln!(s)?;
    writeln!(s, "use crate::kernel::{{Matern32, RbfStateSpace}};")?;
    writeln!(
        s,
        "use crate::tables::{{Hyper, SpatialTables, Tables, TemporalTables, FORMAT_VERSION}};"
    )?;
    writeln!(s)?;
    writeln!(
        s,
        "/// Tables generated from `{origin}` (NT = {nt}, LANES = {d}, POINTS = {n})."
    )?;
    writeln!(s, "pub static {name}: Tables<{nt}, {d}, {n}> = Tables {{")?;
    writeln!(s, "    version: FORMAT_VERSION,")?;
    writeln!(s, "    hyper: Hyper {{")?;
    writeln!(s, "        spatial_order: {nt},")?;
    for (field, v) in [
        ("spatial_variance", h.spatial.variance),
        ("spatial_lengthscale", h.spatial.lengthscale),
        ("offset_variance", h.spatial.offset_variance),
        ("temporal_variance", h.temporal.variance),
        ("temporal_lengthscale", h.temporal.lengthscale),
        ("meas_noise", h.noise.measurement),
        ("pseudo_noise", h.noise.pseudo),
        ("u_min", h.window.u_min),
        ("u_max", h.window.u_max),
        ("row_step", h.spatial.row_step),
        ("frame_step", h.temporal.frame_step),
        ("gram_variance_fraction", h.temporal.gram_variance_fraction),
    ] {
        // The core's `Tables::validate` refuses tables with a scalar that is not a positive
        // f32 (a window from u = 0, say): name it rather than write tables the core refuses.
        ensure!(
            (v as f32).is_finite() && v as f32 > 0.0,
            "{field} = {v:e} must be positive and fit an f32: the core refuses tables with it"
        );
        writeln!(s, "        {field}: {},", lit(v)?)?;
    }
    writeln!(s, "    }},")?;
    writeln!(s, "    spatial: SpatialTables {{")?;
    writeln!(s, "        model: RbfStateSpace {{")?;
    writeln!(s, "            A: {},", matrix(&t.spatial_a)?)?;
    writeln!(s, "            qc: {},", lit(t.spatial_qc)?)?;
    writeln!(s, "            p_inf: {},", matrix(&t.spatial_p_inf)?)?;
    writeln!(s, "        }},")?;
    writeln!(s, "        f: {},", matrix(&t.spatial_f)?)?;
    writeln!(s, "        q: {},", matrix(&t.spatial_q)?)?;
    writeln!(s, "    }},")?;
    writeln!(s, "    temporal: TemporalTables {{")?;
    writeln!(
        s,
        "        kernel: Matern32::new({}, {}),",
        lit(h.temporal.variance)?,
        lit(h.temporal.lengthscale)?
    )?;
    writeln!(s, "        f: {},", matrix(&t.temporal_f)?)?;
    writeln!(s, "        q: {},", matrix(&t.temporal_q)?)?;
    writeln!(s, "        p_inf: {},", matrix(&t.temporal_p_inf)?)?;
    writeln!(s, "    }},")?;
    writeln!(s, "    index_u: {},", vector(&t.index_u)?)?;
    writeln!(s, "    gram: {},", matrix(&t.gram)?)?;
    writeln!(s, "    gram_eigvec: {},", matrix(&t.gram_eigvec)?)?;
    writeln!(s, "    gram_eigval: {},", vector(&t.gram_eigval)?)?;
    writeln!(s, "    gram_rank: {},", t.gram_rank)?;
    writeln!(s, "    coreg: {},", matrix(&t.coreg)?)?;
    writeln!(s, "    coreg_chol: {},", matrix(&t.coreg_chol)?)?;
    writeln!(s, "}};")?;
    Ok(s)
}

/// The committed default hyperparameter file, relative to the repository root.
pub const DEFAULT_HYPER: &str = "data/hyper/default.json";
/// The committed generated tables, relative to the repository root.
pub const DEFAULT_TABLES: &str = "src/tables/default.rs";
/// The hyperparameter file of the uncoupled model (`B` replaced by `diag(B)`).
pub const UNCOUPLED_HYPER: &str = "data/hyper/ablation_diag_b.json";
/// The committed generated tables of the uncoupled model (`stjpdacf::tables::UNCOUPLED`).
pub const UNCOUPLED_TABLES: &str = "src/tables/uncoupled.rs";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::repo_root;

    #[test]
    fn generic_builder_reproduces_the_committed_tables() {
        let h = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).expect("default hyper file");
        let t = static_tables::<2, 6, 16>(&h).expect("tables");
        assert_eq!(*t, stjpdacf::tables::DEFAULT);
    }

    /// The static's name goes into the source: one that is no identifier is an error, not a
    /// file that does not compile.
    #[test]
    fn render_refuses_a_name_that_is_no_identifier() {
        let h = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).expect("default hyper file");
        let t = ModelTables::from_hyper(&h).expect("tables");
        for bad in ["bad name", "", "1ST", "A-B", "_"] {
            let e = render(&t, bad, DEFAULT_HYPER).unwrap_err();
            assert!(
                format!("{e}").contains("is not a Rust identifier"),
                "{bad}: {e}"
            );
        }
        assert!(render(&t, "MY_TABLES_2", DEFAULT_HYPER)
            .unwrap()
            .contains("pub static MY_TABLES_2: Tables<2, 6, 16>"));
    }

    #[test]
    fn generic_builder_refuses_a_wrong_shape() {
        let h = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).expect("default hyper file");
        let t = ModelTables::from_hyper(&h).expect("tables");
        assert!(core_tables::<2, 4, 16>(&t).is_err());
        assert!(core_tables::<2, 6, 12>(&t).is_err());
        assert!(core_tables::<3, 6, 16>(&t).is_err());
    }
}
