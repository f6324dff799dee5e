//! The per-frame repair of the temporal covariance (docs/design.md §4.2, §12: fuzz findings
//! F5–F7): a modified `LDLᵀ` of its correlation form over the active lanes, which only inflates
//! variances.

use super::*;

impl<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize>
    TemporalFilter<LANES, POINTS, RANK, NX>
{
    /// Makes the covariance over the active lanes positive definite again where f32 rounding
    /// broke it, and returns the number of pivots raised (0: nothing changed but the rounding of
    /// a mirror copy).
    ///
    /// Why it is needed: a lane update is `P −= G M Gᵀ`, a difference of two nearly equal
    /// matrices when the update is informative. At a lane's birth the prior variance of
    /// its first Gram component is ~190 m² and the posterior ~1e-3 m² (a 10⁵ reduction), so f32
    /// keeps about two significant digits of the posterior, and a posterior that is nearly
    /// singular in correlation form (strongly correlated components, as after a few points on a
    /// long lane) can come out indefinite (fuzzing found correlation-form eigenvalues of −0.77 and
    /// negative variances; the f64 reference keeps ten digits and never does). A square-root form
    /// would avoid it at several times the cost of the update.
    ///
    /// How: a modified `LDLᵀ` factorisation (Gill–Murray) of the correlation form
    /// `D^-1/2 P D^-1/2` (`D` the absolute diagonal) over the active indices raises every pivot
    /// below [`REPAIR_PIVOT`] (or too small for its column: multipliers stay within ±1), which
    /// factors `P + diag(e)` with `e ≥ 0` bounded; `e` is added to the variances. A covariance whose
    /// correlation form has its smallest eigenvalue above `REPAIR_PIVOT` (every pivot is at least
    /// that eigenvalue) is left as it is; otherwise the repair only inflates variances
    /// (conservative), by at most `REPAIR_PIVOT` relative where the matrix was PSD. The
    /// [`crate::tracker::Tracker`] calls it once per frame after its lane updates and counts the
    /// raised pivots in its step report. The window of the smoother is not touched: adding
    /// `diag(e)` to the current state's covariance is independent noise on `x_k`, which keeps the
    /// augmented covariance PSD.
    ///
    /// When it runs: after every frame with a lane update (it returns 0 at once when no lane was
    /// updated since the last call). An earlier version ran it only after strongly informative
    /// updates (`λ_max(M C) > 0.99` or a variance cut 100-fold), and fuzzing found an update
    /// under both thresholds that still broke positive definiteness (finding F7: nine precise
    /// points on a lane whose covariance one earlier point had left nearly singular in
    /// correlation form; eigenvalue −4.7e-3). The rounding of `P −= G M Gᵀ` depends on
    /// cancellation in `G M Gᵀ` as well as on the variance reduction, and a rigorous a-priori
    /// bound on it is far too loose to be a trigger (it exceeds `REPAIR_PIVOT` in 99.99 % of the
    /// soak's frames), while checking positive definiteness exactly costs what the repair costs.
    /// So the repair is the check. On a healthy covariance it raises nothing and changes nothing.
    ///
    /// # Complexity
    /// `n³/6` multiply-adds for `n = 2r·lanes` active state entries (98 k at 6 lanes, rank 7),
    /// on the lower triangle of `P` in place (the upper one keeps the original, mirrored back):
    /// no stack copy of `P`. Part of every frame with a lane update.
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub fn repair_covariance<const NT: usize>(&mut self, tables: &Tables<NT, LANES, POINTS>) -> u8 {
        if !self.repair_due {
            return 0;
        }
        self.repair_due = false;
        let r = Self::r_used(tables);
        if !self.coupled {
            // Block-diagonal: the factorisation of each lane's block alone is the same
            // factorisation (every cross entry is zero), at n·(2r)³/6 instead of (2r·n)³/6.
            let mut raised = 0u8;
            let active = self.active;
            for s in (0..LANES).filter(|&s| get(&active, s)) {
                let lo = Self::index(s, 0, 0);
                let run = lo..lo + 2 * r.min(RANK);
                raised = raised.saturating_add(repair_psd::<NX>(
                    self.p.as_mut_slice(),
                    NX,
                    core::slice::from_ref(&run),
                ));
            }
            return raised;
        }
        let sp = self.spans(r);
        let mut runs: [Range<usize>; LANES] = core::array::from_fn(|_| 0..0);
        let mut n = 0usize;
        for (dst, rg) in runs.iter_mut().zip(sp.iter()) {
            *dst = rg;
            n += 1;
        }
        repair_psd::<NX>(self.p.as_mut_slice(), NX, runs.get(..n).unwrap_or(&[]))
    }
}

/// Repairs the symmetric matrix stored column-major in `ps` (leading dimension `ld`), restricted
/// to the indices of `runs` (increasing, disjoint ranges, at most `N` indices in all), where
/// rounding made it indefinite; returns the pivots raised. See
/// [`TemporalFilter::repair_covariance`] for the method; the lower triangle is the work space, the
/// upper one keeps the original and is mirrored back, the diagonal gets `diag(e)`. `n³/6`
/// multiply-adds for `n` indices, the inner loop over contiguous slices.
pub(crate) fn repair_psd<const N: usize>(ps: &mut [f32], ld: usize, runs: &[Range<usize>]) -> u8 {
    let mut idx = [0usize; N];
    let mut n = 0usize;
    for i in runs.iter().cloned().flatten() {
        if let Some(e) = idx.get_mut(n) {
            *e = i;
            n += 1;
        }
    }
    let idx = idx.get(..n).unwrap_or(&[]);
    // Original diagonal and scale 1/sqrt|P_ii| (1 for a zero diagonal).
    let mut d0 = [0.0f32; N];
    let mut inv_s = [1.0f32; N];
    for (a, &i) in idx.iter().enumerate() {
        let d = ps.get(i + ld * i).copied().unwrap_or(0.0);
        if !d.is_finite() {
            // A non-finite state is not repairable here (the update checks keep it finite).
            return 0;
        }
        set(&mut d0, a, d);
        if d != 0.0 {
            set(&mut inv_s, a, 1.0 / math::sqrt(d.abs()));
        }
    }
    // Scaled lower triangle, in place (column-major: column idx[b] holds rows idx[a], a ≥ b).
    for (b, &j) in idx.iter().enumerate() {
        let sb = get(&inv_s, b);
        for (a, &i) in idx.iter().enumerate().skip(b) {
            if let Some(e) = ps.get_mut(i + ld * j) {
                *e *= get(&inv_s, a) * sb;
            }
        }
    }
    // Right-looking LDLᵀ of the lower triangle with modified pivots (Gill–Murray, β = 1):
    // `d_k ← max(REPAIR_PIVOT, |d_k|, max_i c_ik²)` for the column `c` below the pivot. This
    // factors `A + diag(e)`, `e ≥ 0`, keeps every multiplier `|L_ik| ≤ 1` so that `e` stays
    // bounded when `A` is far from PSD, and changes nothing for a correlation matrix whose
    // pivots are ≥ REPAIR_PIVOT (its Schur complements have `c_ik² ≤ d_k`).
    let mut raise = [0.0f32; N];
    let mut raised = 0u8;
    let mut col = [0.0f32; N];
    for (k, &c) in idx.iter().enumerate() {
        let dk = ps.get(c + ld * c).copied().unwrap_or(0.0);
        let mut theta2 = 0.0f32;
        for (a, &i) in idx.iter().enumerate().skip(k + 1) {
            let v = ps.get(i + ld * c).copied().unwrap_or(0.0);
            set(&mut col, a, v);
            theta2 = math::max(theta2, v * v);
        }
        let d = math::max(math::max(REPAIR_PIVOT, dk.abs()), theta2);
        if dk.is_nan() || dk < d {
            let e = d - dk;
            set(&mut raise, k, if e.is_finite() { e } else { 0.0 });
            raised = raised.saturating_add(1);
        }
        let inv_d = 1.0 / d;
        // A[i, j] −= c_i c_j / d for k < b ≤ a over the contiguous runs, two adjacent columns at
        // a time where possible (each `c_i` loaded once for both; the same operations, in the
        // same order, as column by column).
        let n = idx.len();
        let mut b = k + 1;
        while b < n {
            let j = idx.get(b).copied().unwrap_or(0);
            let lb = get(&col, b) * inv_d;
            let lb1 = get(&col, b + 1) * inv_d;
            if b + 1 < n && idx.get(b + 1) == Some(&(j + 1)) && lb != 0.0 && lb1 != 0.0 {
                // Row b of column b, then rows a > b of both columns.
                if let Some(x) = ps.get_mut(j + ld * j) {
                    *x -= get(&col, b) * lb;
                }
                if let Some(both) = ps.get_mut(ld * j..ld * (j + 2)) {
                    let (c0, c1) = both.split_at_mut(ld);
                    let mut a0 = 0usize;
                    for rg in runs {
                        let a1 = a0 + rg.len();
                        if a1 > b + 1 {
                            let from = (b + 1).max(a0);
                            let rows = rg.start + (from - a0)..rg.end;
                            if let (Some(d0), Some(d1), Some(src)) = (
                                c0.get_mut(rows.clone()),
                                c1.get_mut(rows),
                                col.get(from..a1),
                            ) {
                                for ((x0, x1), cv) in d0.iter_mut().zip(d1.iter_mut()).zip(src) {
                                    *x0 -= cv * lb;
                                    *x1 -= cv * lb1;
                                }
                            }
                        }
                        a0 = a1;
                    }
                }
                b += 2;
            } else {
                if lb != 0.0 {
                    column_update(ps, ld, j, b, runs, &col, lb);
                }
                b += 1;
            }
        }
    }
    // Restore: lower triangle from the upper one, the diagonal raised by diag(e) unscaled.
    for (b, &j) in idx.iter().enumerate() {
        for &i in idx.iter().skip(b + 1) {
            let up = ps.get(j + ld * i).copied().unwrap_or(0.0);
            if let Some(e) = ps.get_mut(i + ld * j) {
                *e = up;
            }
        }
        let sb = get(&inv_s, b);
        let add = get(&raise, b) / (sb * sb);
        if let Some(e) = ps.get_mut(j + ld * j) {
            *e = get(&d0, b) + if add.is_finite() { add } else { 0.0 };
        }
    }
    raised
}

/// Column `j` (the `b`-th index) of the lower triangle: `A[idx_a, j] −= c_a · lb` for `a ≥ b`,
/// over the contiguous runs (the work of [`repair_psd`]).
fn column_update(
    ps: &mut [f32],
    ld: usize,
    j: usize,
    b: usize,
    runs: &[Range<usize>],
    col: &[f32],
    lb: f32,
) {
    let mut a0 = 0usize;
    for rg in runs {
        let a1 = a0 + rg.len();
        if a1 > b {
            let from = b.max(a0);
            let dst = ps.get_mut(ld * j + rg.start + (from - a0)..ld * j + rg.end);
            if let (Some(dst), Some(src)) = (dst, col.get(from..a1)) {
                for (x, cv) in dst.iter_mut().zip(src) {
                    *x -= cv * lb;
                }
            }
        }
        a0 = a1;
    }
}
