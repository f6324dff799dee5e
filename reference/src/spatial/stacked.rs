//! Operations on the stacked state of all tracks: blocks and marginals, removing a track,
//! inserting one and conditioning on its point (docs/spatial-filter.md §3.2d), the exact mixture
//! update with ended tracks in the state (reading 1 of the parent module).

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};

use super::Model;
use crate::jpda::{self, Estimate};

/// Marginal block `(i, j)` of a stacked covariance.
fn block(p: &DMatrix<f64>, ns: usize, i: usize, j: usize) -> DMatrix<f64> {
    p.view((i * ns, j * ns), (ns, ns)).into_owned()
}

/// Marginal moments of track `i`.
pub(super) fn marginal(e: &Estimate, ns: usize, i: usize) -> Estimate {
    Estimate {
        x: e.x.rows(i * ns, ns).into_owned(),
        p: block(&e.p, ns, i, i),
    }
}

/// Removes track `k` from a stacked state.
pub(super) fn remove_track(e: &Estimate, ns: usize, k: usize) -> Estimate {
    Estimate {
        x: e.x.clone().remove_rows(k * ns, ns),
        p: e.p
            .clone()
            .remove_rows(k * ns, ns)
            .remove_columns(k * ns, ns),
    }
}

/// Stacked indices of a subset of tracks.
pub(super) fn indices(tracks: &[usize], ns: usize) -> Vec<usize> {
    tracks
        .iter()
        .flat_map(|&t| (t * ns)..(t * ns + ns))
        .collect()
}

/// §3.2d: the prior of a new track at rank `k` among `n + 1` (after insertion), started from the
/// point `x`, appended into the stacked state at rank `k`.
///
/// `Λ = B_{n+1}⁻¹`, `a_j = −Λ_kj/Λ_kk`, `g_new = Σ a_j g_j + w`, `w ~ N(0, P∞_u/Λ_kk)`,
/// `c_new ~ N(x, σ_c²)` independent of everything.
pub fn insert_track(
    state: &Estimate,
    model: &Model,
    k: usize,
    x: f64,
    offset_variance: f64,
) -> Option<Estimate> {
    let ns = model.ns();
    let nt = ns - 1;
    let n = state.x.len() / ns;
    if k > n || n + 1 > model.b.nrows() {
        return None;
    }
    let bn = model.b.view((0, 0), (n + 1, n + 1)).into_owned();
    let lam = bn.cholesky()?.inverse();
    let lkk = lam[(k, k)];
    // a over the existing tracks (old indices): old i has new rank i (i < k) or i + 1.
    let a: Vec<f64> = (0..n)
        .map(|i| {
            let j = if i < k { i } else { i + 1 };
            -lam[(k, j)] / lkk
        })
        .collect();
    // A: the NT × (n·NS) map x̄ ↦ Σ a_i g_i.
    let mut amap = DMatrix::zeros(nt, n * ns);
    for (i, &ai) in a.iter().enumerate() {
        for c in 0..nt {
            amap[(c, i * ns + 1 + c)] = ai;
        }
    }
    let g_mean = &amap * &state.x;
    let cov_g_x = &amap * &state.p; // NT × n·NS
    let var_g = &cov_g_x * amap.transpose() + &model.p_inf_u / lkk;

    let m = (n + 1) * ns;
    let old = |new_idx: usize| -> Option<usize> {
        let t = new_idx / ns;
        match t.cmp(&k) {
            std::cmp::Ordering::Less => Some(new_idx),
            std::cmp::Ordering::Equal => None,
            std::cmp::Ordering::Greater => Some(new_idx - ns),
        }
    };
    let mut xn = DVector::zeros(m);
    let mut pn = DMatrix::zeros(m, m);
    for i in 0..m {
        xn[i] = match old(i) {
            Some(oi) => state.x[oi],
            None => {
                let c = i - k * ns;
                if c == 0 {
                    x
                } else {
                    g_mean[c - 1]
                }
            }
        };
    }
    for i in 0..m {
        for j in 0..m {
            pn[(i, j)] = match (old(i), old(j)) {
                (Some(oi), Some(oj)) => state.p[(oi, oj)],
                (None, Some(oj)) => {
                    let c = i - k * ns;
                    if c == 0 {
                        0.0
                    } else {
                        cov_g_x[(c - 1, oj)]
                    }
                }
                (Some(oi), None) => {
                    let c = j - k * ns;
                    if c == 0 {
                        0.0
                    } else {
                        cov_g_x[(c - 1, oi)]
                    }
                }
                (None, None) => {
                    let (ci, cj) = (i - k * ns, j - k * ns);
                    match (ci, cj) {
                        (0, 0) => offset_variance,
                        (0, _) | (_, 0) => 0.0,
                        _ => var_g[(ci - 1, cj - 1)],
                    }
                }
            };
        }
    }
    Some(Estimate {
        x: xn,
        p: (&pn + pn.transpose()) * 0.5,
    })
}

/// §3.2d: the Kalman update of the whole stacked state with the point `z` known to come from the
/// track at rank `k` (`z = h·x_k + v`, `v ~ N(0, r)`); every track moves through its
/// cross-covariance with `k`. `None` when `k` is out of range or `h P_kk hᵀ + r ≤ 0`.
pub fn condition_on_point(
    state: &Estimate,
    h: &DMatrix<f64>,
    k: usize,
    z: f64,
    r: f64,
) -> Option<Estimate> {
    let ns = h.ncols();
    let n = state.x.len() / ns;
    if k >= n {
        return None;
    }
    let mut hk = DMatrix::zeros(1, n * ns);
    hk.view_mut((0, k * ns), (1, ns)).copy_from(h);
    let g = &state.p * hk.transpose(); // n·NS × 1
    let s = (&hk * &g)[(0, 0)] + r;
    let nu = z - (&hk * &state.x)[(0, 0)];
    if !(s.is_finite() && s > 0.0 && nu.is_finite()) {
        return None;
    }
    let x = &state.x + g.column(0) * (nu / s);
    let p = &state.p - &g * g.transpose() / s;
    Some(Estimate {
        x,
        p: (&p + p.transpose()) * 0.5,
    })
}

/// The exact mixture update of the whole stacked state when only the tracks `active` (ascending
/// stacked positions) can be detected: the events and their probabilities come from
/// `jpda::row_step` on the active tracks' marginal; each event's mean is
/// `x̄ + P̄ H_δᵀ S_δ⁻¹ ν_A` and its covariance `P̄ − P̄ H_δᵀ S_δ⁻¹ H_δ P̄` over the full state.
/// With every track active this equals `row_step`'s `mixture`.
pub fn mixture_update_full(
    pred: &Estimate,
    h: &DMatrix<f64>,
    r: f64,
    zs: &[f64],
    active: &[usize],
    row: &jpda::RowResult,
) -> Option<Estimate> {
    let ns = h.ncols();
    let n = pred.x.len();
    let d = pred.x.len() / ns;
    let hbar = jpda::stack_h(d, h);
    let pht = &pred.p * hbar.transpose(); // n × d
    let zhat = &hbar * &pred.x;
    let sfull = &hbar * &pht + DMatrix::<f64>::identity(d, d) * r;
    type Pat = (DMatrix<f64>, DMatrix<f64>); // gain, covariance
    let mut cache: BTreeMap<Vec<usize>, Pat> = BTreeMap::new();
    let mut means = Vec::with_capacity(row.events.len());
    let mut keys = Vec::with_capacity(row.events.len());
    for ev in &row.events {
        let det: Vec<usize> = ev
            .iter()
            .enumerate()
            .filter(|(_, a)| a.is_some())
            .map(|(t, _)| *active.get(t).unwrap_or(&usize::MAX))
            .collect();
        if det.iter().any(|&t| t >= d) {
            return None;
        }
        if !cache.contains_key(&det) {
            let pat = if det.is_empty() {
                (DMatrix::zeros(n, 0), pred.p.clone())
            } else {
                let s = sfull.select_rows(&det).select_columns(&det);
                let g = pht.select_columns(&det);
                let chol = s.clone().cholesky()?;
                let gain = chol.solve(&g.transpose()).transpose();
                let p = &pred.p - &gain * &s * gain.transpose();
                (gain, (&p + p.transpose()) * 0.5)
            };
            cache.insert(det.clone(), pat);
        }
        let (gain, _) = cache.get(&det)?;
        let nu = DVector::from_iterator(
            det.len(),
            ev.iter()
                .enumerate()
                .filter_map(|(t, a)| a.map(|j| (t, j)))
                .map(|(t, j)| zs[j] - zhat[active[t]]),
        );
        means.push(&pred.x + gain * nu);
        keys.push(det);
    }
    let mut x = DVector::zeros(n);
    for (m, &p) in means.iter().zip(&row.event_probs) {
        x += m * p;
    }
    let mut p = DMatrix::zeros(n, n);
    for ((m, key), &w) in means.iter().zip(&keys).zip(&row.event_probs) {
        let dx = m - &x;
        p += (&cache.get(key)?.1 + &dx * dx.transpose()) * w;
    }
    Some(Estimate {
        x,
        p: (&p + p.transpose()) * 0.5,
    })
}
