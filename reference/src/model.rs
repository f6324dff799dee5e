//! The model matrices in f64: hyperparameter file → the spatial and temporal state-space
//! matrices, the Gram matrix of the index points and its eigenpairs, and `B` with its Cholesky
//! factor (docs/design.md §3). The table generator of `stjpdacf-tools` rounds them into the core's
//! static tables; the reference filters use them directly.

use anyhow::{Context, Result};
use nalgebra::{DMatrix, DVector};

use crate::hyper::HyperFile;
use crate::statespace::{Matern32, RbfTaylor};

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
