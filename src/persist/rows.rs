//! A known lane at a BEV row: the GP conditional's row vector, the predicted mean and the
//! covariance terms (docs/design.md §11.2), and the point-variance estimate from the rows'
//! posterior residuals (§11.6).

use crate::linalg::get;
use crate::math;
use crate::spatial::row::{self, RowOutcome};
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
    /// components), computing them only if they are not already. The rows are keyed by the
    /// geometry only (`u_min`, `Δu`, `r`, rows): a basis serves one `Tables` (the tracker's,
    /// fixed from `init`, which starts a new basis); for other tables take a new one
    /// ([`RowBasis::NEW`]).
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

/// `cᵀ a_s` over the first `r` components: lane `s`'s predicted mean at the row (the strided
/// read that [`OwnBlock::mean`] replaces; its test oracle).
#[cfg(test)]
fn mean_at<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize>(
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

/// The known-lane pass's working memory, held by the [`crate::tracker::Tracker`] beside its
/// [`RowBasis`] rather than on the stack (the pass's frame is on the deepest stack path of a
/// step): every lane's position coefficients and covariance block, copied contiguously once
/// per pass for the rows that follow (`LANES·(RANK + RANK²)·4` bytes, 1,344 B at the reference
/// configuration; docs/design.md §11.2), and the rows' association outcome and event arrays
/// (about 3.7 KiB at 6 lanes). All zero when new, so a tracker holding it stays in `.bss`.
#[derive(Clone)]
pub struct PassMemory<const RANK: usize, const LANES: usize> {
    pub(super) lanes: [OwnBlock<RANK>; LANES],
    pub(super) out: RowOutcome<LANES>,
    pub(super) row: row::Scratch<LANES>,
}

impl<const RANK: usize, const LANES: usize> PassMemory<RANK, LANES> {
    /// All zero (every part is reset before it is read).
    pub const NEW: Self = Self {
        lanes: [OwnBlock::ZERO; LANES],
        out: RowOutcome::ZEROED,
        row: row::Scratch::ZEROED,
    };

    /// Copies the blocks of the active lanes among `slots` (bit `s`) out of `f`, over the
    /// first `r` components: `(r + r²)` loads a lane.
    pub(super) fn load<const POINTS: usize, const NX: usize>(
        &mut self,
        f: &TemporalFilter<LANES, POINTS, RANK, NX>,
        slots: u32,
        r: usize,
    ) {
        for (s, o) in self.lanes.iter_mut().enumerate() {
            if slots & (1 << s) != 0 && f.is_active(s) {
                *o = OwnBlock::of(f, s, r);
            }
        }
    }

    /// Lane `s`'s block (as last loaded).
    pub(super) fn get(&self, s: usize) -> Option<&OwnBlock<RANK>> {
        self.lanes.get(s)
    }
}

impl<const RANK: usize, const LANES: usize> core::fmt::Debug for PassMemory<RANK, LANES> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("PassMemory").finish_non_exhaustive()
    }
}

/// One lane's position coefficients and their covariance block, contiguous: [`OwnBlock::mean`]
/// and [`OwnBlock::quad`] are [`mean_at`] and [`quad`]`(s, s)` with the same products summed in
/// the same order (the same values bit for bit), without their strided reads of the stacked
/// filter (stop 31: the strided `quad` was 10 % of a typical uncoupled frame on the
/// Cortex-M4F).
#[derive(Debug, Clone, Copy)]
pub(super) struct OwnBlock<const RANK: usize> {
    /// `a_sj`, `j < r`.
    a: [f32; RANK],
    /// `p[j][k] = P[a_sk, a_sj]`, `j, k < r` (column `a_sj` as [`quad`] reads it).
    p: [[f32; RANK]; RANK],
}

impl<const RANK: usize> OwnBlock<RANK> {
    /// All zero (a lane not looked at).
    pub(super) const ZERO: Self = Self {
        a: [0.0; RANK],
        p: [[0.0; RANK]; RANK],
    };

    /// Lane `s`'s block over the first `r` components (entries out of the filter's range read
    /// as 0, which adds nothing). Not inlined: inlined into the loop over the lanes it was
    /// unrolled into 4 KB of flash.
    #[inline(never)]
    pub(super) fn of<const LANES: usize, const POINTS: usize, const NX: usize>(
        f: &TemporalFilter<LANES, POINTS, RANK, NX>,
        s: usize,
        r: usize,
    ) -> Self {
        let x = f.mean();
        let p = f.covariance().as_slice();
        let s0 = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, 0, 0);
        let mut b = Self::ZERO;
        for (j, (aj, col)) in b.a.iter_mut().zip(b.p.iter_mut()).enumerate().take(r) {
            let ij = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0);
            *aj = x.get(ij).copied().unwrap_or(0.0);
            let c0 = ij * NX + s0;
            for (k, v) in col.iter_mut().enumerate().take(r) {
                *v = p.get(c0 + 2 * k).copied().unwrap_or(0.0);
            }
        }
        b
    }

    /// `cᵀ a_s` over the first `r` components ([`mean_at`]).
    pub(super) fn mean(&self, c: &[f32; RANK], r: usize) -> f32 {
        if r >= RANK {
            // As in `quad`: the same terms, fixed trip count.
            return c.iter().zip(self.a.iter()).map(|(cj, aj)| cj * aj).sum();
        }
        c.iter()
            .zip(self.a.iter())
            .take(r)
            .map(|(cj, aj)| cj * aj)
            .sum()
    }

    /// `cᵀ P[a_s, a_s] c` over the first `r` components ([`quad`]`(s, s)`): `r²`
    /// multiply-adds.
    pub(super) fn quad(&self, c: &[f32; RANK], r: usize) -> f32 {
        if r >= RANK {
            // The same terms in the same order with fixed trip counts (a tracker compiled at
            // its model's rank, e.g. `Rank4Tracker`): unrolled.
            let mut acc = 0.0;
            for (cj, col) in c.iter().zip(self.p.iter()) {
                let inner: f32 = col.iter().zip(c.iter()).map(|(pv, ck)| pv * ck).sum();
                acc += cj * inner;
            }
            return acc;
        }
        let mut acc = 0.0;
        for (cj, col) in c.iter().zip(self.p.iter()).take(r) {
            let inner: f32 = col
                .iter()
                .zip(c.iter())
                .take(r)
                .map(|(pv, ck)| pv * ck)
                .sum();
            acc += cj * inner;
        }
        acc
    }
}

impl<const LANES: usize, const POINTS: usize, const ROWS: usize> Persist<LANES, POINTS, ROWS> {
    /// The point-variance estimate from this frame's posterior residuals of the lanes in
    /// `slots` (after their updates, docs/design.md §11.6): for every row where one point holds
    /// ≥ 90 % of the lane's weight and `β ≥ 0.5`, `r̂ = (e² − ρ_r B_ss + c_rᵀ P⁺ c_r)/0.973`,
    /// `e` = that point − `c_rᵀ a⁺` (`Var(e) = r + ρ_r B_ss − c_rᵀ P⁺ c_r`), counted when
    /// `e² ≤ 9 r_b` (0.973 corrects the 3σ truncation), summed per band with a memory of
    /// `memory` frames.
    pub fn estimate_noise<const NT: usize, const RANK: usize, const NX: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        (basis, mem): (&RowBasis<RANK, ROWS>, &mut PassMemory<RANK, LANES>),
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
        mem.load(filter, slots, r_used);
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
                let Some(o) = mem.get(s) else {
                    continue;
                };
                let z = o.mean(&c, r_used);
                let rk = usize::from(get(ranks, s));
                let bss = tables.coreg.get((rk, rk)).copied().unwrap_or(0.0);
                let e = zt - z;
                // Residuals beyond 3σ of the current estimate are not counted (clutter the
                // association took for the lane); the truncation's bias (×0.973 for a
                // Gaussian) is corrected.
                let cur = self.noise(b, pass.params.r);
                let est = (e * e - rho * bss + o.quad(&c, r_used)) / 0.973;
                if est.is_finite() && e * e <= 9.0 * cur {
                    if let Some(nb) = self.noise.get_mut(b) {
                        nb[0] += math::max(est, 0.0);
                        nb[1] += 1.0;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observation::{LaneObservation, Status};
    use crate::tables::DEFAULT;
    use crate::temporal::smoother::Temporal;

    /// The contiguous block gives the strided reads' values bit for bit, on a coupled
    /// covariance (lanes conditioned on each other, predicted), for every lane, rank and row.
    #[test]
    fn own_block_equals_the_strided_reads() {
        let mut t = Temporal::<6, 16, 7, 84, 42, 4>::new();
        let mut ranks = [0u8; 6];
        for (s, r) in [(0usize, 0u8), (1, 1), (3, 2), (5, 3)] {
            ranks[s] = r;
            t.start_lane(&DEFAULT, s, r, &ranks).unwrap();
            t.predict(&DEFAULT, 0.05 + 0.01 * s as f32).unwrap();
        }
        for (n, s) in [0usize, 1, 3, 5].into_iter().enumerate() {
            let mut o = LaneObservation::<16>::EMPTY;
            o.status = Status::Confirmed;
            for i in (0..16).filter(|i| (i + n) % 3 != 0) {
                o.present[i] = true;
                o.z[i] = -5.0 + 3.4 * n as f32 + 0.02 * DEFAULT.index_u[i];
                o.cov[(i, i)] = 0.0025;
            }
            t.update(&DEFAULT, s, &o).unwrap();
        }
        let f = t.filter();
        assert!(!f.uncoupled());
        let mut checked = 0;
        for s in [0usize, 1, 3, 5] {
            for r in 1..=7 {
                let block = OwnBlock::of(f, s, r);
                for row in 0..9 {
                    let c: [f32; 7] = core::array::from_fn(|j| {
                        ((row * 7 + j) as f32 * 0.37).sin() / (1.0 + j as f32)
                    });
                    assert_eq!(block.mean(&c, r).to_bits(), mean_at(f, s, &c, r).to_bits());
                    assert_eq!(block.quad(&c, r).to_bits(), quad(f, s, s, &c, r).to_bits());
                    assert!(block.quad(&c, r) >= 0.0);
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 4 * 7 * 9);
        // Not a comparison of zeros.
        let c = [0.3f32, -0.2, 0.1, 0.05, -0.04, 0.02, 0.01];
        let b = OwnBlock::of(f, 3, 7);
        assert!(b.mean(&c, 7).abs() > 0.1 && b.quad(&c, 7) > 0.0);
    }
}
