//! Small allocation-free kernels shared by the spatial and the temporal stage: panic-free fixed
//! array access, a panic-free sort, and the in-place Cholesky factorisations (plain and with
//! pivot loading) with their triangular solve. No function here panics, for any input.

use nalgebra::SMatrix;

use crate::math;

/// Element `i` of a fixed array, or the default past its end (no panicking indexing in the core).
#[inline]
pub(crate) fn get<T: Copy + Default, const N: usize>(a: &[T; N], i: usize) -> T {
    a.get(i).copied().unwrap_or_default()
}

/// Sets element `i` of a fixed array (no-op past its end).
#[inline]
pub(crate) fn set<T, const N: usize>(a: &mut [T; N], i: usize, v: T) {
    if let Some(s) = a.get_mut(i) {
        *s = v;
    }
}

/// Sets the first `n` entries of each of the first `rows` rows of `m` to `+0.0`: the part of a
/// row's `β` that the last row wrote. A few entries a row: the zero is opaque to the optimiser
/// (`black_box`), which otherwise makes each row a call of `memset` (about 25 instructions of
/// call overhead for 4–16 bytes on the Cortex-M4F; the row resets were 2 % of a frame).
#[inline(never)]
pub(crate) fn zero_block<const C: usize>(m: &mut [[f32; C]], rows: usize, n: usize) {
    let zero = core::hint::black_box(0.0f32);
    for row in m.iter_mut().take(rows) {
        for v in row.iter_mut().take(n) {
            *v = zero;
        }
    }
}

/// Sorts `v` so that no element is `less` than the one before it: a stable insertion sort,
/// `O(n²)` comparisons for the short lists of the core (a row's free points, at most `D·m`
/// candidates when pruning). `sort_unstable_by` keeps a panic branch for inconsistent orders
/// that the optimiser cannot remove, which the no-panic proof (the `panic-never` firmware)
/// rejects.
pub(crate) fn sort_by<T>(v: &mut [T], mut less: impl FnMut(&T, &T) -> bool) {
    for i in 1..v.len() {
        let mut k = i;
        while k > 0 {
            match v.get_mut(k - 1..=k) {
                Some([a, b]) if less(b, a) => core::mem::swap(a, b),
                _ => break,
            }
            k -= 1;
        }
    }
}

/// `a · b` (a left fold of the products, as `Iterator::sum` does it).
#[inline(always)]
pub(crate) fn dot<const N: usize>(a: &[f32; N], b: &[f32; N]) -> f32 {
    a.iter().zip(b.iter()).map(|(x, y)| x * y).sum()
}

/// In-place Cholesky factorisation of the leading `n×n` block of `a` (the lower triangle is read
/// and replaced by `L`; the upper triangle is not used). `pivot(j, d)` sees each pivot `d` before
/// its square root and returns the pivot to use, or `None` to stop (then `false` is returned and
/// `a` is partly factorised).
///
/// # Complexity
/// `n³/6` multiply-adds and `n` square roots.
#[inline(always)]
fn cholesky_with<const N: usize>(
    a: &mut SMatrix<f32, N, N>,
    n: usize,
    mut pivot: impl FnMut(usize, f32) -> Option<f32>,
) -> bool {
    for j in 0..n.min(N) {
        let mut d = a.get((j, j)).copied().unwrap_or(0.0);
        for k in 0..j {
            let v = a.get((j, k)).copied().unwrap_or(0.0);
            d -= v * v;
        }
        let Some(d) = pivot(j, d) else {
            return false;
        };
        let d = math::sqrt(d);
        if let Some(e) = a.get_mut((j, j)) {
            *e = d;
        }
        for i in j + 1..n.min(N) {
            let mut acc = a.get((i, j)).copied().unwrap_or(0.0);
            for k in 0..j {
                acc -=
                    a.get((i, k)).copied().unwrap_or(0.0) * a.get((j, k)).copied().unwrap_or(0.0);
            }
            if let Some(e) = a.get_mut((i, j)) {
                *e = acc / d;
            }
        }
    }
    true
}

/// In-place Cholesky factorisation of the leading `n×n` block of `a` (see [`cholesky_with`]).
/// `false` when the block is not positive definite or not finite.
pub(crate) fn cholesky_lower<const N: usize>(a: &mut SMatrix<f32, N, N>, n: usize) -> bool {
    cholesky_with(a, n, |_, d| (d.is_finite() && d > 0.0).then_some(d))
}

/// Modified Cholesky of the leading `n×n` block of `a` (lower triangle read and replaced by `L`):
/// a pivot `d` below `floor` becomes `max(|d|, target)` and the amount added is written to `load`, so
/// `L Lᵀ = A + diag(load)`. Returns the number of raised pivots, or `u8::MAX` when a pivot or an
/// entry is not finite (or `target` is not positive).
pub(crate) fn cholesky_loaded<const N: usize>(
    a: &mut SMatrix<f32, N, N>,
    n: usize,
    floor: f32,
    target: f32,
    load: &mut [f32; N],
) -> u8 {
    if !(target.is_finite() && target > 0.0) {
        return u8::MAX;
    }
    let mut raised = 0u8;
    let done = cholesky_with(a, n, |j, d| {
        if !d.is_finite() {
            return None;
        }
        if d < floor {
            // Reflected and floored (|d| keeps the scale of a badly indefinite matrix, so the
            // repaired noise is not spuriously informative along the directions it was wrong).
            let new = d.abs().max(target);
            set(load, j, new - d);
            raised = raised.saturating_add(1);
            return Some(new);
        }
        Some(d)
    });
    if done {
        raised.min(u8::MAX - 1)
    } else {
        u8::MAX
    }
}

/// Solves `L y = b` in place, `L` the lower factor of [`cholesky_lower`], `b.len()` its order.
pub(crate) fn forward_subst<const N: usize>(l: &SMatrix<f32, N, N>, b: &mut [f32]) {
    for i in 0..b.len() {
        let mut acc = b.get(i).copied().unwrap_or(0.0);
        for k in 0..i {
            acc -= l.get((i, k)).copied().unwrap_or(0.0) * b.get(k).copied().unwrap_or(0.0);
        }
        if let Some(e) = b.get_mut(i) {
            *e = acc / l.get((i, i)).copied().unwrap_or(1.0);
        }
    }
}

/// Entry `(r, c)` of a column-major `N×N` array (`m[c][r]`), 0 past its end.
#[inline(always)]
pub(crate) fn cm_at<const N: usize>(m: &[[f32; N]; N], r: usize, c: usize) -> f32 {
    m.get(c).and_then(|col| col.get(r)).copied().unwrap_or(0.0)
}

/// Sets entry `(r, c)` of a column-major `N×N` array (no-op past its end).
#[inline(always)]
pub(crate) fn cm_set<const N: usize>(m: &mut [[f32; N]; N], r: usize, c: usize, v: f32) {
    if let Some(e) = m.get_mut(c).and_then(|col| col.get_mut(r)) {
        *e = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_block_clears_exactly_the_block() {
        let mut m = [[1.5f32; 5]; 4];
        zero_block(&mut m, 2, 3);
        for (i, row) in m.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                let want = if i < 2 && j < 3 { 0.0 } else { 1.5 };
                assert_eq!(v.to_bits(), f32::to_bits(want), "({i}, {j})");
            }
        }
        // Past the end is a no-op, not a panic; +0.0, not −0.0.
        let mut m = [[-1.0f32; 2]; 2];
        zero_block(&mut m, 9, 9);
        assert!(m.iter().flatten().all(|v| v.to_bits() == 0));
    }
}
