//! The spatial JPDACF: a coupled multi-lane filter that walks the BEV rows near to far
//! (docs/design.md §4.1), with `u` (metres ahead) as its "time" axis.
//!
//! * [`Stacked`] — the joint Gaussian of up to `LANES` lane tracks, each with `NS` state entries
//!   (`[c, g, dg/du, …]`: the lane offset and the RBF state, `NS = NT + 1`), kept as `LANES × LANES`
//!   blocks so the Kronecker-structured prediction costs O(D² NS³), not O((D NS)³).
//! * [`row`] — one row step: gating, bounded joint-event enumeration, joint-Gaussian event
//!   weights, and the exact moment-matched update of the event mixture.
//!
//! ```
//! use nalgebra::{SMatrix, SVector};
//! use stjpdacf::spatial::{row, Stacked};
//! let mut s: Stacked<2, 2> = Stacked::new();
//! s.push(SVector::from([0.0, 0.0]), &SMatrix::identity())?;
//! s.push(SVector::from([3.5, 0.0]), &SMatrix::identity())?;
//! let h = SVector::from([1.0, 0.0]);
//! let params = row::RowParams::default();
//! let out = row::update(&mut s, &h, &[0.1, 3.4, 9.0], &params, 512);
//! assert!(!out.failed && out.beta_miss[0] < 0.5);
//! # Ok::<(), stjpdacf::spatial::Full>(())
//! ```

pub mod filter;
pub mod row;

use nalgebra::{ArrayStorage, SMatrix, SVector};

use crate::linalg::{cm_at, cm_set};

/// Error returned by [`Stacked::push`]: all `LANES` slots are in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Full;

impl core::fmt::Display for Full {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("all lane slots are in use")
    }
}

impl core::error::Error for Full {}

/// Entry `r` of a column, 0 past its end.
#[inline(always)]
fn mat_col<const N: usize>(col: &[f32; N], r: usize) -> f32 {
    col.get(r).copied().unwrap_or(0.0)
}

/// Per-track means.
pub(crate) type Means<const NS: usize, const LANES: usize> = [SVector<f32, NS>; LANES];
/// Covariance blocks `p[i][j] = Cov(x_i, x_j)`.
pub(crate) type Blocks<const NS: usize, const LANES: usize> =
    [[SMatrix<f32, NS, NS>; LANES]; LANES];

/// Joint Gaussian of `len() ≤ LANES` tracks with `NS` entries each: means `x[i]` and covariance
/// blocks `p[i][j] = Cov(x_i, x_j)` (only `i, j < len()` are meaningful; the rest are zero).
///
/// RAM: `4 · (LANES · NS + LANES² · NS²) + 8` bytes (1,376 B for `NS = 3`, `LANES = 6`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stacked<const NS: usize, const LANES: usize> {
    x: [SVector<f32, NS>; LANES],
    p: [[SMatrix<f32, NS, NS>; LANES]; LANES],
    len: usize,
}

impl<const NS: usize, const LANES: usize> Default for Stacked<NS, LANES> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const NS: usize, const LANES: usize> Stacked<NS, LANES> {
    const ZV: SVector<f32, NS> = SMatrix::from_array_storage(ArrayStorage([[0.0; NS]; 1]));
    const ZM: SMatrix<f32, NS, NS> = SMatrix::from_array_storage(ArrayStorage([[0.0; NS]; NS]));

    /// No tracks. `const`, so a filter can live in a `static`.
    pub const fn new() -> Self {
        const { assert!(LANES >= 1 && LANES <= 16, "LANES must be 1..=16") };
        const { assert!(NS >= 1 && NS <= 8, "NS must be 1..=8") };
        Self {
            x: [Self::ZV; LANES],
            p: [[Self::ZM; LANES]; LANES],
            len: 0,
        }
    }

    /// Number of tracks.
    pub fn len(&self) -> usize {
        self.len.min(LANES)
    }

    /// `true` when there are no tracks.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Mean of track `i` (`None` past `len()`).
    pub fn mean(&self, i: usize) -> Option<&SVector<f32, NS>> {
        if i < self.len() {
            self.x.get(i)
        } else {
            None
        }
    }

    /// Covariance block `Cov(x_i, x_j)` (`None` past `len()`).
    pub fn cov(&self, i: usize, j: usize) -> Option<&SMatrix<f32, NS, NS>> {
        if i < self.len() && j < self.len() {
            self.p.get(i).and_then(|r| r.get(j))
        } else {
            None
        }
    }

    /// Appends a track with mean `x`, covariance `p` and zero cross-covariance to the others (set
    /// those with [`Stacked::set_cross`] to condition the new track on the existing ones).
    ///
    /// # Errors
    /// [`Full`] when `LANES` tracks exist; the state is unchanged.
    pub fn push(&mut self, x: SVector<f32, NS>, p: &SMatrix<f32, NS, NS>) -> Result<usize, Full> {
        let i = self.len();
        if i >= LANES {
            return Err(Full);
        }
        if let Some(v) = self.x.get_mut(i) {
            *v = x;
        }
        for (r, row) in self.p.iter_mut().enumerate() {
            for (c, b) in row.iter_mut().enumerate() {
                if r == i || c == i {
                    *b = if r == c { *p } else { Self::ZM };
                }
            }
        }
        self.len = i + 1;
        Ok(i)
    }

    /// Sets `Cov(x_i, x_j) = c` and `Cov(x_j, x_i) = cᵀ` (no-op past `len()` or for `i == j`).
    pub fn set_cross(&mut self, i: usize, j: usize, c: &SMatrix<f32, NS, NS>) {
        if i == j || i >= self.len() || j >= self.len() {
            return;
        }
        if let Some(b) = self.p.get_mut(i).and_then(|r| r.get_mut(j)) {
            *b = *c;
        }
        if let Some(b) = self.p.get_mut(j).and_then(|r| r.get_mut(i)) {
            *b = c.transpose();
        }
    }

    /// Prediction along `u` (docs/design.md §4.1 step 1): `x_i ← F x_i`,
    /// `P_ij ← F P_ij Fᵀ + B_ij Q` for the active tracks, `B_ij` from the leading block of `b`.
    /// Only the upper blocks are computed (the lower ones are their transposes, so the stacked
    /// covariance stays exactly symmetric), and when `F = blockdiag(1, F_u)`,
    /// `Q = blockdiag(0, Q_u)` (the lane offset has no dynamics) its first row and column are
    /// copied instead of multiplied.
    ///
    /// # Complexity
    /// `len()·(len() + 1)/2 · 2 NS³` multiply-adds at most (`2 (NS − 1)² NS` with the offset
    /// structure), no allocation.
    #[allow(non_snake_case)]
    #[inline(never)]
    pub fn predict<const D: usize>(
        &mut self,
        F: &SMatrix<f32, NS, NS>,
        Q: &SMatrix<f32, NS, NS>,
        b: &SMatrix<f32, D, D>,
    ) {
        let f = F.data.0; // f[c][r] = F_rc (column-major)
        let q = Q.data.0;
        let static_offset = (0..NS).all(|k| {
            let (f0k, fk0) = (cm_at(&f, 0, k), cm_at(&f, k, 0));
            let (q0k, qk0) = (cm_at(&q, 0, k), cm_at(&q, k, 0));
            q0k == 0.0
                && qk0 == 0.0
                && if k == 0 {
                    f0k == 1.0
                } else {
                    f0k == 0.0 && fk0 == 0.0
                }
        });
        if static_offset {
            self.predict_from::<1, D>(&f, &q, b);
        } else {
            self.predict_from::<0, D>(&f, &q, b);
        }
    }

    /// [`Stacked::predict`] with rows and columns `0..S` of `F` and `Q` known to be those of the
    /// identity and of zero (`S` a constant, so the small products unroll).
    #[inline(always)]
    fn predict_from<const S: usize, const D: usize>(
        &mut self,
        f: &[[f32; NS]; NS],
        q: &[[f32; NS]; NS],
        b: &SMatrix<f32, D, D>,
    ) {
        let n = self.len();
        for x in self.x.iter_mut().take(n) {
            let [old] = x.data.0;
            let [xv] = &mut x.data.0;
            for (r, xr) in xv.iter_mut().enumerate().skip(S) {
                let mut acc = 0.0f32;
                for (fc, oc) in f.iter().zip(old.iter()).skip(S) {
                    acc += mat_col(fc, r) * oc;
                }
                *xr = acc;
            }
        }
        for i in 0..n {
            for j in i..n {
                let Some(m) = self.p.get(i).and_then(|r| r.get(j)).map(|m| m.data.0) else {
                    continue;
                };
                // T = M Fᵀ: column c of T is Σ_k F_ck (column k of M).
                let mut t = m;
                for (c, tc) in t.iter_mut().enumerate().skip(S) {
                    let mut acc = [0.0f32; NS];
                    for (k, mk) in m.iter().enumerate().skip(S) {
                        let fck = cm_at(f, c, k);
                        for (a, v) in acc.iter_mut().zip(mk.iter()) {
                            *a += fck * v;
                        }
                    }
                    *tc = acc;
                }
                // R = F T + B_ij Q: rows r ≥ S are Σ_k F_rk (row k of T).
                let bij = b.get((i, j)).copied().unwrap_or(0.0);
                let mut out = t;
                for (rc, (tc, qc)) in out.iter_mut().zip(t.iter().zip(q.iter())) {
                    for (r, v) in rc.iter_mut().enumerate().skip(S) {
                        let mut acc = 0.0f32;
                        for (fk, tk) in f.iter().zip(tc.iter()).skip(S) {
                            acc += mat_col(fk, r) * tk;
                        }
                        *v = acc + bij * mat_col(qc, r);
                    }
                }
                if i == j {
                    // Exactly symmetric diagonal blocks: the upper triangle, mirrored.
                    for c in 0..NS {
                        for r in c + 1..NS {
                            let v = cm_at(&out, c, r);
                            cm_set(&mut out, r, c, v);
                        }
                    }
                }
                let blk = SMatrix::<f32, NS, NS>::from_data(ArrayStorage(out));
                if let Some(p) = self.p.get_mut(i).and_then(|r| r.get_mut(j)) {
                    *p = blk;
                }
                if i != j {
                    if let Some(p) = self.p.get_mut(j).and_then(|r| r.get_mut(i)) {
                        *p = blk.transpose();
                    }
                }
            }
        }
    }

    /// Inserts a track at rank `k ≤ len()` with mean `x`, covariance `p` and cross-covariances
    /// `cross[j] = Cov(x_new, x_j)` for the existing ranks `j < len()` (before insertion). Tracks
    /// at ranks `≥ k` move one rank right.
    ///
    /// # Errors
    /// [`Full`] when `LANES` tracks exist or `k > len()`; the state is unchanged.
    ///
    /// # Complexity
    /// O(LANES² · NS²) copies.
    pub fn insert(
        &mut self,
        k: usize,
        x: SVector<f32, NS>,
        p: &SMatrix<f32, NS, NS>,
        cross: &[SMatrix<f32, NS, NS>; LANES],
    ) -> Result<(), Full> {
        let n = self.len();
        if n >= LANES || k > n {
            return Err(Full);
        }
        let old_x = self.x;
        let old_p = self.p;
        // new rank i ← old rank (i if i < k, i − 1 if i > k); rank k is the new track.
        let old = |i: usize| {
            if i < k {
                Some(i)
            } else if i > k {
                Some(i - 1)
            } else {
                None
            }
        };
        for (i, xi) in self.x.iter_mut().enumerate().take(n + 1) {
            *xi = match old(i) {
                Some(o) => old_x.get(o).copied().unwrap_or_else(SVector::zeros),
                None => x,
            };
        }
        for (i, row) in self.p.iter_mut().enumerate().take(n + 1) {
            for (j, blk) in row.iter_mut().enumerate().take(n + 1) {
                *blk = match (old(i), old(j)) {
                    (Some(oi), Some(oj)) => old_p
                        .get(oi)
                        .and_then(|r| r.get(oj))
                        .copied()
                        .unwrap_or_else(SMatrix::zeros),
                    (None, Some(oj)) => cross.get(oj).copied().unwrap_or_else(SMatrix::zeros),
                    (Some(oi), None) => {
                        cross.get(oi).map_or_else(SMatrix::zeros, |c| c.transpose())
                    }
                    (None, None) => *p,
                };
            }
        }
        self.len = n + 1;
        Ok(())
    }

    /// Removes the track at rank `k` (no-op past `len()`); tracks to its right move one rank left.
    ///
    /// # Complexity
    /// O(LANES² · NS²) copies.
    pub fn remove(&mut self, k: usize) {
        let n = self.len();
        if k >= n {
            return;
        }
        let old_x = self.x;
        let old_p = self.p;
        let old = |i: usize| if i < k { i } else { i + 1 };
        for (i, xi) in self.x.iter_mut().enumerate() {
            *xi = if i + 1 < n {
                old_x.get(old(i)).copied().unwrap_or_else(SVector::zeros)
            } else {
                SVector::zeros()
            };
        }
        for (i, row) in self.p.iter_mut().enumerate() {
            for (j, blk) in row.iter_mut().enumerate() {
                *blk = if i + 1 < n && j + 1 < n {
                    old_p
                        .get(old(i))
                        .and_then(|r| r.get(old(j)))
                        .copied()
                        .unwrap_or_else(SMatrix::zeros)
                } else {
                    SMatrix::zeros()
                };
            }
        }
        self.len = n - 1;
    }

    /// Kalman update of the whole stacked state with one point `z` known to belong to track `k`
    /// (`z = hᵀ x_k + v`, `v ~ N(0, r)`): every track moves through its cross-covariance with `k`.
    /// Returns `false` (state unchanged) for `k ≥ len()` or a non-positive innovation variance.
    ///
    /// # Complexity
    /// O(len()² · NS²).
    pub fn update_single(&mut self, k: usize, h: &SVector<f32, NS>, z: f32, r: f32) -> bool {
        let n = self.len();
        let (Some(xk), Some(pkk)) = (self.mean(k), self.cov(k, k)) else {
            return false;
        };
        let s = h.dot(&(pkk * h)) + r;
        let nu = z - h.dot(xk);
        if !(s.is_finite() && s > 0.0 && nu.is_finite()) {
            return false;
        }
        let mut g = [SVector::<f32, NS>::zeros(); LANES];
        for (i, gi) in g.iter_mut().enumerate().take(n) {
            if let Some(pik) = self.cov(i, k) {
                *gi = pik * h;
            }
        }
        for (x, gi) in self.x.iter_mut().zip(g.iter()).take(n) {
            *x += gi * (nu / s);
        }
        for (row, gi) in self.p.iter_mut().zip(g.iter()).take(n) {
            for (blk, gj) in row.iter_mut().zip(g.iter()).take(n) {
                *blk -= gi * gj.transpose() / s;
            }
        }
        true
    }

    /// Mutable access for the row update (crate-internal).
    pub(crate) fn parts_mut(&mut self) -> (&mut Means<NS, LANES>, &mut Blocks<NS, LANES>, usize) {
        let n = self.len();
        (&mut self.x, &mut self.p, n)
    }
}
