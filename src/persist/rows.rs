//! A known lane at a BEV row: the GP conditional's row vector, the predicted mean and the
//! covariance terms (docs/design.md §11.2), and the point-variance estimate from the rows'
//! posterior residuals (§11.6).

use crate::linalg::get;
use crate::math;
use crate::tables::Tables;
use crate::temporal::filter::TemporalFilter;

use super::{Pass, Persist};

/// The index band of row `r` (`k_rows` rows per index interval, bands centred on the index
/// points), clamped to the last band.
pub(super) fn band<const POINTS: usize>(r: usize, k_rows: usize) -> usize {
    ((r + k_rows / 2) / k_rows.max(1)).min(POINTS - 1)
}

/// The GP conditional's row vector at `u`: `c_j = k(u, U)·v_j / λ_j` for the first `r`
/// components, and the prior's residual variance `ρ = (σ_u² − Σ_j (k·v_j)²/λ_j)⁺`.
pub fn row_basis<const NT: usize, const LANES: usize, const POINTS: usize, const RANK: usize>(
    tables: &Tables<NT, LANES, POINTS>,
    u: f32,
    r: usize,
) -> ([f32; RANK], f32) {
    let h = &tables.hyper;
    let l2 = 2.0 * h.spatial_lengthscale * h.spatial_lengthscale;
    let mut k = [0.0f32; POINTS];
    for (i, kv) in k.iter_mut().enumerate() {
        let d = u - tables.index_u.get(i).copied().unwrap_or(0.0);
        *kv = h.spatial_variance * math::exp(-d * d / l2);
    }
    let mut c = [0.0f32; RANK];
    let mut explained = 0.0;
    for (j, cj) in c.iter_mut().enumerate().take(r) {
        let lam = tables.gram_eigval.get(j).copied().unwrap_or(0.0);
        if lam <= 0.0 {
            continue;
        }
        let kv: f32 = k
            .iter()
            .enumerate()
            .map(|(i, ki)| ki * tables.gram_eigvec.get((i, j)).copied().unwrap_or(0.0))
            .sum();
        *cj = kv / lam;
        explained += kv * kv / lam;
    }
    (c, (h.spatial_variance - explained).max(0.0))
}

/// The row vectors `c_r` and residual variances `ρ_r` of [`row_basis`] at every BEV row
/// `u_r = u_min + r·Δu`. They depend only on the tables and the row geometry, so the tracker
/// computes them on its first known-lane pass (`rows·POINTS` exponentials and
/// `rows·POINTS·r` multiply-adds) and again only when the geometry changes, instead of twice a
/// frame. RAM: `4·ROWS·(RANK + 1)` bytes and the key.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowBasis<const RANK: usize, const ROWS: usize> {
    c: [[f32; RANK]; ROWS],
    rho: [f32; ROWS],
    /// `(u_min, Δu, r, rows)` the rows were computed for (`rows = 0`: none yet).
    key: (f32, f32, usize, usize),
}

impl<const RANK: usize, const ROWS: usize> Default for RowBasis<RANK, ROWS> {
    fn default() -> Self {
        Self::NEW
    }
}

impl<const RANK: usize, const ROWS: usize> RowBasis<RANK, ROWS> {
    /// Nothing computed yet.
    pub const NEW: Self = Self {
        c: [[0.0; RANK]; ROWS],
        rho: [0.0; ROWS],
        key: (0.0, 0.0, 0, 0),
    };

    /// Makes the rows those of `tables` and `pass` (`r = min(gram_rank, RANK, POINTS)`
    /// components), computing them only if they are not already.
    pub fn ensure<const NT: usize, const LANES: usize, const POINTS: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        pass: &Pass,
    ) {
        let r_used = (tables.gram_rank as usize).min(RANK).min(POINTS);
        let rows = pass.rows.min(ROWS);
        let key = (tables.hyper.u_min, pass.du, r_used, rows);
        if key == self.key {
            return;
        }
        for (r, (c, rho)) in self
            .c
            .iter_mut()
            .zip(self.rho.iter_mut())
            .enumerate()
            .take(rows)
        {
            let u = tables.hyper.u_min + r as f32 * pass.du;
            (*c, *rho) = row_basis::<NT, LANES, POINTS, RANK>(tables, u, r_used);
        }
        self.key = key;
    }

    /// Row `r`'s `(c_r, ρ_r)` (zeros outside the rows computed).
    pub fn at(&self, r: usize) -> ([f32; RANK], f32) {
        (
            self.c.get(r).copied().unwrap_or([0.0; RANK]),
            get(&self.rho, r),
        )
    }
}

/// `cᵀ a_s` over the first `r` components: lane `s`'s predicted mean at the row.
pub(super) fn mean_at<
    const LANES: usize,
    const POINTS: usize,
    const RANK: usize,
    const NX: usize,
>(
    f: &TemporalFilter<LANES, POINTS, RANK, NX>,
    s: usize,
    c: &[f32; RANK],
    r: usize,
) -> f32 {
    let x = f.mean();
    (0..r)
        .map(|j| {
            get(c, j)
                * x.get(TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0))
                    .copied()
                    .unwrap_or(0.0)
        })
        .sum()
}

/// `cᵀ P[a_s, a_t] c` over the first `r` components. `P` is symmetric, so the inner sum
/// `Σ_k P[a_sj, a_tk] c_k` is read down column `a_sj` (lane `t`'s position coefficients sit
/// every second entry of it): contiguous, one bounds check per column. `r²` multiply-adds.
pub(super) fn quad<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize>(
    f: &TemporalFilter<LANES, POINTS, RANK, NX>,
    s: usize,
    t: usize,
    c: &[f32; RANK],
    r: usize,
) -> f32 {
    let p = f.covariance().as_slice();
    let t0 = TemporalFilter::<LANES, POINTS, RANK, NX>::index(t, 0, 0);
    let mut acc = 0.0;
    for (j, cj) in c.iter().enumerate().take(r) {
        let col = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0) * NX + t0;
        let Some(v) = p.get(col..col + 2 * r) else {
            continue;
        };
        let inner: f32 = v
            .iter()
            .step_by(2)
            .zip(c.iter())
            .map(|(pv, ck)| pv * ck)
            .sum();
        acc += cj * inner;
    }
    acc
}

impl<const LANES: usize, const POINTS: usize, const ROWS: usize> Persist<LANES, POINTS, ROWS> {
    /// The point-variance estimate from this frame's posterior residuals of the lanes in
    /// `slots` (after their updates, docs/design.md §11.6): for every row where one point holds
    /// ≥ 90 % of the lane's weight `W_r ≥ 0.5`, `r̂ = (e² − ρ_r B_ss + c_rᵀ P⁺ c_r)/0.973`,
    /// `e` = that point − `c_rᵀ a⁺` (`Var(e) = r + ρ_r B_ss − c_rᵀ P⁺ c_r`), counted when
    /// `e² ≤ 9 r_b` (0.973 corrects the 3σ truncation), summed per band with a memory of
    /// `memory` frames.
    pub fn estimate_noise<const NT: usize, const RANK: usize, const NX: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        basis: &RowBasis<RANK, ROWS>,
        filter: &TemporalFilter<LANES, POINTS, RANK, NX>,
        (slots, ranks): (u32, &[u8; LANES]),
        pass: &Pass,
        memory: f32,
    ) {
        let r_used = (tables.gram_rank as usize).min(RANK).min(POINTS);
        let decay = if memory > 1.0 {
            1.0 - 1.0 / memory
        } else {
            0.0
        };
        for nb in &mut self.noise {
            nb[0] *= decay;
            nb[1] *= decay;
        }
        let row_of = |s: usize, r: usize| -> [f32; 2] {
            self.rows
                .get(s)
                .and_then(|rs| rs.get(r))
                .copied()
                .unwrap_or([0.0; 2])
        };
        for r in 0..pass.rows.min(ROWS) {
            let any = (0..LANES).any(|s| slots & (1 << s) != 0 && row_of(s, r)[1] >= 0.5);
            if !any {
                continue;
            }
            let b = band::<POINTS>(r, pass.k_rows);
            let (c, rho) = basis.at(r);
            for s in 0..LANES {
                let [zt, w] = row_of(s, r);
                if slots & (1 << s) == 0 || w < 0.5 || !filter.is_active(s) {
                    continue;
                }
                let z = mean_at(filter, s, &c, r_used);
                let rk = usize::from(get(ranks, s));
                let bss = tables.coreg.get((rk, rk)).copied().unwrap_or(0.0);
                let e = zt - z;
                // Residuals beyond 3σ of the current estimate are not counted (clutter the
                // association took for the lane); the truncation's bias (×0.973 for a
                // Gaussian) is corrected.
                let cur = self.noise(b, pass.params.r);
                let est = (e * e - rho * bss + quad(filter, s, s, &c, r_used)) / 0.973;
                if est.is_finite() && e * e <= 9.0 * cur {
                    if let Some(nb) = self.noise.get_mut(b) {
                        nb[0] += est.max(0.0);
                        nb[1] += 1.0;
                    }
                }
            }
        }
    }
}
