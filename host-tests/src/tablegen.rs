//! The offline table generator: hyperparameter file → f64 model matrices → a Rust source file of
//! `static` f32 tables for the core (`stjpdacf::tables::Tables`).
//!
//! Everything here is f64 and uses [`crate::reference`]; the only f32 step is the final rounding
//! when the values are written as literals.

use std::fmt::Write as _;

use anyhow::{ensure, Context, Result};
use nalgebra::{DMatrix, DVector, SVector};
use stjpdacf::kernel::{Matern32 as CoreMatern32, RbfStateSpace};
use stjpdacf::tables::{Hyper, SpatialTables, Tables, TemporalTables};

use crate::hyper::HyperFile;
use crate::reference::statespace::{Matern32, RbfTaylor};

/// The layout version written into generated tables (must equal `stjpdacf::tables::FORMAT_VERSION`).
pub const FORMAT_VERSION: u32 = 1;

/// Everything the tables hold, in f64.
#[derive(Debug, Clone)]
pub struct ModelTables {
    /// The hyperparameters the tables come from.
    pub hyper: HyperFile,
    /// Spatial companion matrix `A_u`.
    pub spatial_a: DMatrix<f64>,
    /// Spatial `Qc`.
    pub spatial_qc: f64,
    /// Spatial `P∞` (Lyapunov).
    pub spatial_p_inf: DMatrix<f64>,
    /// `F_u` at the nominal row step.
    pub spatial_f: DMatrix<f64>,
    /// `Q_u` at the nominal row step.
    pub spatial_q: DMatrix<f64>,
    /// `F_t` at the nominal frame step.
    pub temporal_f: DMatrix<f64>,
    /// `Q_t` at the nominal frame step.
    pub temporal_q: DMatrix<f64>,
    /// `P∞_t`.
    pub temporal_p_inf: DMatrix<f64>,
    /// Index points.
    pub index_u: DVector<f64>,
    /// Gram matrix `K_u`.
    pub gram: DMatrix<f64>,
    /// Eigenvectors of `K_u` (columns, decreasing eigenvalue, largest-magnitude entry positive).
    pub gram_eigvec: DMatrix<f64>,
    /// Eigenvalues of `K_u`, decreasing, clamped at 0.
    pub gram_eigval: DVector<f64>,
    /// Leading eigenpairs that hold `gram_variance_fraction` of the trace.
    pub gram_rank: usize,
    /// `B`.
    pub coreg: DMatrix<f64>,
    /// Lower Cholesky factor of `B`.
    pub coreg_chol: DMatrix<f64>,
}

impl ModelTables {
    /// Computes the tables from a validated hyperparameter file.
    pub fn from_hyper(h: &HyperFile) -> Result<Self> {
        h.validate()?;
        let rbf = RbfTaylor {
            variance: h.spatial.variance,
            lengthscale: h.spatial.lengthscale,
            order: h.spatial.order,
        };
        let spatial_p_inf = rbf
            .p_inf()
            .context("spatial Lyapunov equation is singular")?;
        let (spatial_f, spatial_q) = rbf
            .transition(h.spatial.row_step)
            .context("spatial model")?;
        let mat = Matern32 {
            variance: h.temporal.variance,
            lengthscale: h.temporal.lengthscale,
        };
        let (temporal_f, temporal_q) = mat.transition(h.temporal.frame_step);
        let index_u = DVector::from_vec(h.index_u());
        let n = index_u.len();
        let gram = DMatrix::from_fn(n, n, |i, j| rbf.kernel(index_u[i] - index_u[j]));
        let eig = gram.clone().symmetric_eigen();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let gram_eigval = DVector::from_fn(n, |i, _| eig.eigenvalues[order[i]].max(0.0));
        let mut gram_eigvec = DMatrix::from_fn(n, n, |i, j| eig.eigenvectors[(i, order[j])]);
        for mut col in gram_eigvec.column_iter_mut() {
            let imax = col.iamax();
            if col[imax] < 0.0 {
                col.neg_mut();
            }
        }
        let total: f64 = gram_eigval.sum();
        let mut acc = 0.0;
        let mut gram_rank = n;
        for (i, v) in gram_eigval.iter().enumerate() {
            acc += v;
            if acc >= h.temporal.gram_variance_fraction * total {
                gram_rank = i + 1;
                break;
            }
        }
        let coreg = h.coreg();
        let coreg_chol = coreg
            .clone()
            .cholesky()
            .context("B is not positive definite")?
            .l();
        Ok(Self {
            hyper: h.clone(),
            spatial_a: rbf.a(),
            spatial_qc: rbf.qc(),
            spatial_p_inf,
            spatial_f,
            spatial_q,
            temporal_f,
            temporal_q,
            temporal_p_inf: mat.p_inf_closed(),
            index_u,
            gram,
            gram_eigvec,
            gram_eigval,
            gram_rank,
            coreg,
            coreg_chol,
        })
    }
}

impl ModelTables {
    /// The core's tables `Tables<NT, LANES, POINTS>` (f32) for these f64 tables, validated.
    ///
    /// The values are the same f32 roundings [`render`] writes as literals, so for the committed
    /// hyperparameter file this equals `stjpdacf::tables::DEFAULT` bit for bit (a test checks it).
    ///
    /// # Errors
    /// When the hyperparameters' order, slot count or index point count differ from `NT`, `LANES`
    /// or `POINTS`, or the core's [`Tables::validate`] refuses the result.
    pub fn to_core<const NT: usize, const LANES: usize, const POINTS: usize>(
        &self,
    ) -> Result<Tables<NT, LANES, POINTS>> {
        let h = &self.hyper;
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
                    A: m(&self.spatial_a).fixed_view::<NT, NT>(0, 0).into_owned(),
                    qc: f(self.spatial_qc),
                    p_inf: m(&self.spatial_p_inf)
                        .fixed_view::<NT, NT>(0, 0)
                        .into_owned(),
                },
                f: m(&self.spatial_f).fixed_view::<NT, NT>(0, 0).into_owned(),
                q: m(&self.spatial_q).fixed_view::<NT, NT>(0, 0).into_owned(),
            },
            temporal: TemporalTables {
                kernel: CoreMatern32::new(f(h.temporal.variance), f(h.temporal.lengthscale)),
                f: m(&self.temporal_f).fixed_view::<2, 2>(0, 0).into_owned(),
                q: m(&self.temporal_q).fixed_view::<2, 2>(0, 0).into_owned(),
                p_inf: m(&self.temporal_p_inf)
                    .fixed_view::<2, 2>(0, 0)
                    .into_owned(),
            },
            index_u: SVector::from_fn(|i, _| f(self.index_u[i])),
            gram: m(&self.gram)
                .fixed_view::<POINTS, POINTS>(0, 0)
                .into_owned(),
            gram_eigvec: m(&self.gram_eigvec)
                .fixed_view::<POINTS, POINTS>(0, 0)
                .into_owned(),
            gram_eigval: SVector::from_fn(|i, _| f(self.gram_eigval[i])),
            gram_rank: u32::try_from(self.gram_rank)?,
            coreg: m(&self.coreg).fixed_view::<LANES, LANES>(0, 0).into_owned(),
            coreg_chol: m(&self.coreg_chol)
                .fixed_view::<LANES, LANES>(0, 0)
                .into_owned(),
        };
        tables
            .validate()
            .map_err(|e| anyhow::anyhow!("generated tables are invalid: {e}"))?;
        Ok(tables)
    }
}

/// Tables for any configuration, built at run time from a hyperparameter file and leaked to
/// `'static` (what `stjpdacf::tracker::Tracker::new` takes): for tools and benches that need
/// other `NT`, `LANES` or `POINTS` than the committed tables. Each call leaks one
/// `size_of::<Tables<NT, LANES, POINTS>>()` (2,648 B at the reference configuration).
///
/// # Errors
/// As [`ModelTables::from_hyper`] and [`ModelTables::to_core`].
pub fn static_tables<const NT: usize, const LANES: usize, const POINTS: usize>(
    h: &HyperFile,
) -> Result<&'static Tables<NT, LANES, POINTS>> {
    let t = ModelTables::from_hyper(h)?.to_core::<NT, LANES, POINTS>()?;
    Ok(Box::leak(Box::new(t)))
}

fn lit(v: f64) -> Result<String> {
    let f = v as f32;
    ensure!(f.is_finite(), "value {v} does not fit an f32 table");
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

    #[test]
    fn generic_builder_refuses_a_wrong_shape() {
        let h = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).expect("default hyper file");
        let t = ModelTables::from_hyper(&h).expect("tables");
        assert!(t.to_core::<2, 4, 16>().is_err());
        assert!(t.to_core::<2, 6, 12>().is_err());
        assert!(t.to_core::<3, 6, 16>().is_err());
    }
}
