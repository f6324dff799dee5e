//! The per-frame repair of the temporal covariance (docs/design.md §4.2.4, §12: fuzz findings
//! F5–F7): the smallest shift of its correlation form that factors, which inflates every variance
//! by the same small factor.

use super::*;

impl<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize>
    TemporalFilter<LANES, POINTS, RANK, NX>
{
    /// Makes the covariance over the active lanes positive definite again where f32 rounding
    /// broke it, and returns the number of factorisations that failed (0: nothing changed but the
    /// rounding of a mirror copy).
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
    /// How: the smallest shift `τ ≥ 0` of a short ladder for which the correlation form
    /// `C + τI`, `C = D^-1/2 P D^-1/2` (`D` the absolute diagonal) over the active indices,
    /// factors (`LDLᵀ`) with every pivot at least [`REPAIR_PIVOT`]; then `P_ii += τ·D_ii`, every
    /// variance inflated by the same factor `1 + τ` and no covariance touched. A covariance whose
    /// correlation form has all its pivots `≥ REPAIR_PIVOT` (so its smallest eigenvalue above
    /// `REPAIR_PIVOT`'s order) is left as it is (`τ = 0`, one factorisation). The ladder: after a
    /// failed pivot `d`, `τ ← min(max(2τ, τ + 2(REPAIR_PIVOT − d)), 8τ)` (first `4·REPAIR_PIVOT`
    /// at most): that pivot grows at least as fast as `τ`, so the step is what lifts it in exact
    /// arithmetic, while the bounds keep the ladder geometric and stop it overshooting (a pivot of
    /// an indefinite matrix can be far more negative than its smallest eigenvalue). After
    /// [`REPAIR_ATTEMPTS`] failed factorisations `τ` is the Gershgorin bound of `C`, which is
    /// positive definite without a factorisation. The inflation is uniform and bounded where it
    /// matters: a lane's variance at an index point grows by `τ·Σ_j V_ij² D_jj ≤ τ·max_j D_jj`
    /// (the rows of `V` have norm ≤ 1). An earlier repair (Gill–Murray's modified `LDLᵀ`,
    /// raising single pivots, until stop 52) kept multipliers within ±1 but could add up to the
    /// whole variance of one coefficient, undoing the cancellation that made a lane precise where
    /// it was observed (a stopped vehicle's lanes went from 0.01 to 58 m² there and were merged
    /// away; docs/design.md §4.2.4). The [`crate::tracker::Tracker`] calls it once per frame
    /// after its lane updates and counts the failed factorisations in its step report. The
    /// window of the smoother is not touched: adding `τ·D` to the current state's covariance is
    /// independent noise on `x_k`, which keeps the augmented covariance PSD.
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
    /// So the repair is the check. On a healthy covariance it changes nothing.
    ///
    /// # Complexity
    /// `n³/6` multiply-adds per factorisation for `n = 2r·lanes` active state entries (98 k at 6
    /// lanes, rank 7), on the lower triangle of `P` in place (the upper one keeps the original,
    /// mirrored back): no stack copy of `P`. Coupled, one factorisation of the whole on every
    /// frame with a lane update (uncoupled, one of each lane's block, `(2r)³/6` = 457 each); on a
    /// frame that fails it, each lane's block and then the whole again, each with up to
    /// [`REPAIR_ATTEMPTS`] rungs of its ladder and `n²` for a Gershgorin bound: at most
    /// `(1 + 6)·n³/6 + 6·lanes·(2r)³/6` = 708 k multiply-adds at 6 lanes, rank 7 (the stopped
    /// vehicle's frames: 2.8 failed factorisations a repaired frame, most of single lanes).
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub fn repair_covariance<const NT: usize>(&mut self, tables: &Tables<NT, LANES, POINTS>) -> u8 {
        if !self.repair_due {
            return 0;
        }
        self.repair_due = false;
        let r = Self::r_used(tables);
        let mut runs: [Range<usize>; LANES] = core::array::from_fn(|_| 0..0);
        let mut n = 0usize;
        for (dst, rg) in runs.iter_mut().zip(self.spans(r).iter()) {
            *dst = rg;
            n += 1;
        }
        let runs = runs.get(..n).unwrap_or(&[]);
        // Coupled: a check of the whole active covariance first (one factorisation, nothing
        // changed when it passes: almost every frame).
        let mut failed = 0u8;
        if self.coupled {
            if check_psd::<NX>(self.p.as_mut_slice(), NX, runs) {
                return 0;
            }
            failed = 1;
        }
        // Each lane's own block (its shift inflates only that lane: one lane's broken block must
        // not loosen the others), then, coupled, the whole active covariance on top.
        // Block-diagonal (uncoupled), the own blocks are the whole factorisation (every cross
        // entry is zero), at n·(2r)³/6 instead of (2r·n)³/6.
        let active = self.active;
        for s in (0..LANES).filter(|&s| get(&active, s)) {
            let lo = Self::index(s, 0, 0);
            let run = lo..lo + 2 * r.min(RANK);
            failed = failed.saturating_add(repair_psd::<NX>(
                self.p.as_mut_slice(),
                NX,
                core::slice::from_ref(&run),
            ));
        }
        if self.coupled {
            failed = failed.saturating_add(repair_psd::<NX>(self.p.as_mut_slice(), NX, runs));
        }
        failed
    }
}

/// Repairs the symmetric matrix stored column-major in `ps` (leading dimension `ld`), restricted
/// to the indices of `runs` (increasing, disjoint ranges, at most `N` indices in all), where
/// rounding made it indefinite; returns the factorisations that failed (0: nothing changed but
/// the rounding of a mirror copy). See [`TemporalFilter::repair_covariance`] for the method: the
/// smallest shift `τ` of a short ladder for which the correlation form `C + τI` factors with
/// every pivot `≥ REPAIR_PIVOT`, applied as `P_ii += τ·|P_ii|`. The lower triangle is the work
/// space, the upper one keeps the original and is mirrored back. `n³/6` multiply-adds for `n`
/// indices per factorisation (one on a healthy matrix), at most [`REPAIR_ATTEMPTS`] of them.
pub(crate) fn repair_psd<const N: usize>(ps: &mut [f32], ld: usize, runs: &[Range<usize>]) -> u8 {
    let mut work = [[0.0f32; N]; 3];
    let mut idx = [0usize; N];
    repair_in(ps, ld, runs, &mut idx, &mut work, false)
}

/// `true` when the symmetric matrix of [`repair_psd`] factors as it is (every pivot of its
/// correlation form `≥ REPAIR_PIVOT`); nothing is changed but the rounding of a mirror copy.
pub(crate) fn check_psd<const N: usize>(ps: &mut [f32], ld: usize, runs: &[Range<usize>]) -> bool {
    let mut work = [[0.0f32; N]; 3];
    let mut idx = [0usize; N];
    repair_in(ps, ld, runs, &mut idx, &mut work, true) == 0
}

/// The work of [`repair_psd`] (`check`: one factorisation, no shift; returns 1 when it fails),
/// on slices so that the repairs of every size share one copy of the code (flash).
fn repair_in<const N: usize>(
    ps: &mut [f32],
    ld: usize,
    runs: &[Range<usize>],
    idx: &mut [usize; N],
    work: &mut [[f32; N]; 3],
    check: bool,
) -> u8 {
    let mut n = 0usize;
    for i in runs.iter().cloned().flatten() {
        if let Some(e) = idx.get_mut(n) {
            *e = i;
            n += 1;
        }
    }
    let idx = idx.get(..n).unwrap_or(&[]);
    let [d0, inv_s, col] = work;
    repair_slices(ps, ld, runs, idx, (d0, inv_s, col), check)
}

/// [`repair_in`] on slices.
fn repair_slices(
    ps: &mut [f32],
    ld: usize,
    runs: &[Range<usize>],
    idx: &[usize],
    (d0, inv_s, col): (&mut [f32], &mut [f32], &mut [f32]),
    check: bool,
) -> u8 {
    // Original diagonal and scale 1/sqrt|P_ii| (1 for a zero diagonal).
    let mut flipped = 0u8;
    for (a, &i) in idx.iter().enumerate() {
        let d = ps.get(i + ld * i).copied().unwrap_or(0.0);
        if !d.is_finite() {
            // A non-finite state is not repairable here (the update checks keep it finite).
            return 0;
        }
        // A negative variance has no digit left: its magnitude is the variance (as in a
        // modified Cholesky), the only change at that index before the shift.
        if d < 0.0 {
            if check {
                return 1;
            }
            flipped = 1;
        }
        put(d0, a, d.abs());
        put(
            inv_s,
            a,
            if d != 0.0 {
                1.0 / math::sqrt(d.abs())
            } else {
                1.0
            },
        );
    }
    let scale = Scale {
        idx,
        runs,
        d0: &*d0,
        inv_s: &*inv_s,
    };
    let mut tau = 0.0f32;
    let mut failed = flipped;
    while let Some(d) = shifted_ldl(ps, ld, &scale, tau, col) {
        failed = failed.saturating_add(1);
        if check {
            break;
        }
        // The failed pivot of `C + τI` grows at least as fast as `τ` (its derivative is
        // `1 + bᵀ(C_k + τI)⁻² b ≥ 1` while the leading block stays positive definite, and the
        // pivots before it only grow), so `τ + (ε − d)` lifts it to `ε` in exact arithmetic:
        // twice that gap for rounding, at least a doubling (the ladder is geometric), and at
        // most `4ε` first and eightfold after (the pivot of an indefinite matrix can be far more
        // negative than its smallest eigenvalue, and the shift should not overshoot that).
        let most = if tau > 0.0 {
            8.0 * tau
        } else {
            4.0 * REPAIR_PIVOT
        };
        let lift = math::max(2.0 * tau, tau + 2.0 * (REPAIR_PIVOT - d));
        let next = if lift <= most { lift } else { most };
        if failed.saturating_sub(flipped) >= REPAIR_ATTEMPTS || !next.is_finite() {
            tau = gershgorin_shift(ps, ld, &scale);
            break;
        }
        tau = next;
    }
    if check {
        tau = 0.0;
    }
    // Restore: lower triangle from the upper one, the diagonal shifted by τ·|P_ii| (in a check,
    // the original diagonal).
    for (b, &j) in idx.iter().enumerate() {
        for &i in idx.iter().skip(b + 1) {
            let up = ps.get(j + ld * i).copied().unwrap_or(0.0);
            if let Some(e) = ps.get_mut(i + ld * j) {
                *e = up;
            }
        }
        let sb = at(scale.inv_s, b);
        let add = tau / (sb * sb);
        if let Some(e) = ps.get_mut(j + ld * j) {
            *e = at(scale.d0, b) + if add.is_finite() { add } else { 0.0 };
        }
    }
    failed
}

/// The indices a repair works on and the scaling to their correlation form.
struct Scale<'a> {
    idx: &'a [usize],
    runs: &'a [Range<usize>],
    d0: &'a [f32],
    inv_s: &'a [f32],
}

/// A shift that makes the correlation form diagonally dominant by `REPAIR_PIVOT` (Gershgorin:
/// positive definite without a factorisation): `max_a (Σ_{b≠a} |C_ab| − C_aa) + REPAIR_PIVOT`,
/// at least 0; from the upper triangle (the original), `n²` operations.
fn gershgorin_shift(ps: &[f32], ld: usize, sc: &Scale<'_>) -> f32 {
    let mut worst = 0.0f32;
    for (a, &i) in sc.idx.iter().enumerate() {
        let sa = at(sc.inv_s, a);
        let mut off = 0.0f32;
        for (b, &j) in sc.idx.iter().enumerate() {
            if b != a {
                let (lo, hi) = if j < i { (j, i) } else { (i, j) };
                off += (ps.get(lo + ld * hi).copied().unwrap_or(0.0) * sa * at(sc.inv_s, b)).abs();
            }
        }
        worst = math::max(worst, off - at(sc.d0, a) * sa * sa);
    }
    worst + REPAIR_PIVOT
}

/// Fills the lower triangle with the correlation form shifted by `tau` (from the upper
/// triangle and `d0`) and factors it in place (right-looking `LDLᵀ`, unmodified); returns the
/// first pivot below `REPAIR_PIVOT` (or not a number), `None` when every pivot is at least that.
fn shifted_ldl(
    ps: &mut [f32],
    ld: usize,
    sc: &Scale<'_>,
    tau: f32,
    col: &mut [f32],
) -> Option<f32> {
    let (idx, runs) = (sc.idx, sc.runs);
    for (b, &j) in idx.iter().enumerate() {
        let sb = at(sc.inv_s, b);
        if let Some(e) = ps.get_mut(j + ld * j) {
            *e = at(sc.d0, b) * sb * sb + tau;
        }
        for (a, &i) in idx.iter().enumerate().skip(b + 1) {
            let up = ps.get(j + ld * i).copied().unwrap_or(0.0);
            if let Some(e) = ps.get_mut(i + ld * j) {
                *e = up * at(sc.inv_s, a) * sb;
            }
        }
    }
    let n = idx.len();
    for (k, &c) in idx.iter().enumerate() {
        let d = ps.get(c + ld * c).copied().unwrap_or(0.0);
        // NaN compares false: a pivot that is not a number fails.
        if d.is_nan() || d < REPAIR_PIVOT {
            return Some(d);
        }
        for (a, &i) in idx.iter().enumerate().skip(k + 1) {
            put(col, a, ps.get(i + ld * c).copied().unwrap_or(0.0));
        }
        let inv_d = 1.0 / d;
        // A[i, j] −= c_i c_j / d for k < b ≤ a over the contiguous runs, two adjacent columns at
        // a time where possible (each `c_i` loaded once for both; the same operations, in the
        // same order, as column by column).
        let mut b = k + 1;
        while b < n {
            let j = idx.get(b).copied().unwrap_or(0);
            let lb = at(col, b) * inv_d;
            let lb1 = at(col, b + 1) * inv_d;
            if b + 1 < n && idx.get(b + 1) == Some(&(j + 1)) && lb != 0.0 && lb1 != 0.0 {
                // Row b of column b, then rows a > b of both columns.
                if let Some(x) = ps.get_mut(j + ld * j) {
                    *x -= at(col, b) * lb;
                }
                if let Some((c0, c1)) = ps
                    .get_mut(ld * j..ld * (j + 2))
                    .and_then(|both| both.split_at_mut_checked(ld))
                {
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
                    column_update(ps, ld, j, b, runs, col, lb);
                }
                b += 1;
            }
        }
    }
    None
}

/// Column `j` (the `b`-th index) of the lower triangle: `A[idx_a, j] −= c_a · lb` for `a ≥ b`,
/// over the contiguous runs (the work of [`shifted_ldl`]).
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

/// `v[i]`, 0 out of range.
#[inline(always)]
fn at(v: &[f32], i: usize) -> f32 {
    v.get(i).copied().unwrap_or(0.0)
}

/// `v[i] = x` (nothing out of range).
#[inline(always)]
fn put(v: &mut [f32], i: usize, x: f32) {
    if let Some(e) = v.get_mut(i) {
        *e = x;
    }
}
