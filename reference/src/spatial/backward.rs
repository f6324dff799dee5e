//! The backward pass (docs/spatial-filter.md §4): a confirmed track's pseudo-measurements at the
//! index points with their covariance block.

use nalgebra::DMatrix;

use super::{Model, Track, TrackOutput};
use crate::jpda::Estimate;

/// §4: the backward RTS pass over one confirmed track and its pseudo-measurements.
pub(super) fn backward(model: &Model, t: &Track, rank: usize) -> Option<TrackOutput> {
    let n_rec = t.recs.len();
    let first_row = t.first_row?;
    let last_row = t.last_row?;
    if n_rec == 0 {
        return None;
    }
    let last_rec = t.start_row + n_rec - 1;
    // Smoothed moments and gains (gains[i] links recorded row i to i + 1).
    let mut sm: Vec<Estimate> = t.recs.iter().map(|rc| rc.filt.clone()).collect();
    let mut gains: Vec<DMatrix<f64>> = vec![DMatrix::zeros(0, 0); n_rec];
    for i in (0..n_rec.saturating_sub(1)).rev() {
        let pf = &t.recs[i].filt;
        let pp = &t.recs[i + 1].pred;
        let chol = pp.p.clone().cholesky()?;
        // G = P_f Fᵀ P_p⁻¹  ⇔  P_p Gᵀ = F P_f.
        let g = chol.solve(&(&model.f * &pf.p)).transpose();
        let x = &pf.x + &g * (&sm[i + 1].x - &pp.x);
        let p = &pf.p + &g * (&sm[i + 1].p - &pp.p) * g.transpose();
        sm[i] = Estimate {
            x,
            p: (&p + p.transpose()) * 0.5,
        };
        gains[i] = g;
    }
    let n = model.points;
    let present: Vec<usize> = (0..n)
        .filter(|&i| {
            let row = i * model.k;
            row >= first_row && row <= last_row
        })
        .collect();
    let h = &model.h;
    let mut pseudo = vec![None; n];
    let mut cov = DMatrix::zeros(n, n);
    for &a in &present {
        let ia = a * model.k - t.start_row;
        pseudo[a] = Some((h * &sm[ia].x)[(0, 0)]);
        // Walk forward: M = G_a ⋯ G_{b−1}.
        let mut m = DMatrix::<f64>::identity(model.ns(), model.ns());
        let mut ib_prev = ia;
        for &b in present.iter().filter(|&&b| b >= a) {
            let ib = b * model.k - t.start_row;
            for g in gains.iter().take(ib).skip(ib_prev) {
                m = &m * g;
            }
            ib_prev = ib;
            let c = (h * &m * &sm[ib].p * h.transpose())[(0, 0)];
            cov[(a, b)] = c;
            cov[(b, a)] = c;
        }
    }
    // The covariance over the present points is made positive definite as the core does
    // (docs/spatial-filter.md §4): modified Cholesky in index order, pivots below 1e-6 × the
    // largest present variance raised to max(|d|, that floor), the difference added to the
    // point's variance.
    let top = present
        .iter()
        .map(|&a| cov[(a, a)].abs())
        .fold(0.0, f64::max);
    let floor = 1e-6 * top;
    if floor > 0.0 && floor.is_finite() {
        let sub = DMatrix::from_fn(present.len(), present.len(), |i, j| {
            cov[(present[i], present[j])]
        });
        let loads = crate::temporal::repair_loads_with(&sub, floor, floor);
        for (i, l) in loads.into_iter().enumerate() {
            cov[(present[i], present[i])] += l;
        }
    }
    let total = t.hits + t.misses;
    Some(TrackOutput {
        id: t.id,
        rank,
        status: t.status,
        start_row: t.start_row,
        first_row,
        last_row,
        last_recorded_row: last_rec,
        hits: t.hits,
        misses: t.misses,
        existence: if total > 0 {
            t.hits as f64 / total as f64
        } else {
            0.0
        },
        extent: (model.row_u(first_row), model.row_u(last_row)),
        pseudo,
        pseudo_cov: cov,
        smoothed: sm,
    })
}
