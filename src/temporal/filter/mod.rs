//! The temporal coupled filter (DESIGN 4.2) in the eigenbasis of the Gram matrix.
//!
//! The model: each lane's positions at the N index points, `f ∈ R^N`, evolve as independent
//! Matérn-3/2 processes in time, coupled across index points by `K_u` and across lanes by `B`:
//! prior `(B_D ⊗ K_u) ⊗ P∞_t`, process noise `(B_D ⊗ K_u) ⊗ Q_t(T)`. `K_u` is badly conditioned
//! (16 points, ℓ_u = 35.8 m: numerically rank 7), so the state holds the coefficients on its
//! leading eigenvectors, `f = V_r a`, `r = min(gram_rank, RANK)` (the tables keep the eigenpairs
//! holding `gram_variance_fraction` = 1 − 1e-6 of the trace). In that basis
//! `K_u → Λ_r` is diagonal: prior `(B_D ⊗ Λ_r) ⊗ P∞_t`, process noise `(B_D ⊗ Λ_r) ⊗ Q_t(T)`, and
//! `F̄ = I ⊗ F_t(T)` acts on 2×2 blocks. The dropped components carry ≤ 1e-6 of the prior variance.
//!
//! # State layout and capacities
//! `TemporalFilter<LANES, POINTS, RANK, NX>` with `NX = 2·LANES·RANK`: slot `s`, component `j`,
//! `[a, ȧ]` at `(s·RANK + j)·2 + c`. RAM `4·(NX + NX²)` bytes (28.6 KiB at 6 lanes, rank 7).
//!
//! # Cost per frame
//! Only the active slots are touched (`n` lanes, `n_act = 2·r·n` state entries; free slots' rows
//! and columns stay zero): prediction about `8·n_act²/2` multiply-adds (`F̄ P F̄ᵀ` on one triangle
//! of 2×2 blocks, Kronecker noise), each lane update a rank-`r` correction `P −= G M Gᵀ` in
//! `n_act²·r/2` (one triangle, mirrored) plus `m³/6 + m²·r` for its gain (`m ≤ POINTS` present
//! points, one `m×m` Cholesky). At 3 lanes, rank 7: ≈ 3.5 k + 3 × 6.2 k multiply-adds. Updates
//! are checked (bounds on every product) before anything is written, then applied in place: no
//! copy of the 28 KiB covariance on the stack. No allocation, no recursion, no panicking indexing.

use core::ops::Range;

use nalgebra::{Matrix2, SMatrix, SVector};

use crate::math;
use crate::spatial::filter::LaneObservation;
use crate::spatial::{get, set};
use crate::tables::Tables;

/// Error of [`TemporalFilter`] operations; the state is unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum TemporalError {
    /// The frame step is not finite and positive, or the transition failed.
    BadStep,
    /// The slot is out of range, already active (start) or inactive (update).
    BadSlot,
    /// The lane ranks are not a permutation of `0..active lanes`.
    BadRanks,
    /// A factorisation failed or the result was not finite.
    Numerical,
    /// The observation has no present, finite point.
    NoData,
}

impl core::fmt::Display for TemporalError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::BadStep => "frame step is not finite and positive",
            Self::BadSlot => "lane slot out of range or in the wrong state",
            Self::BadRanks => "lane ranks are not a permutation of 0..active lanes",
            Self::Numerical => "numerical failure (state kept)",
            Self::NoData => "observation without usable points",
        })
    }
}

impl core::error::Error for TemporalError {}

/// The gain parts of one lane update (crate-internal: the fixed-lag smoother reuses them).
///
/// With `G = P[:, a_s]` (the covariance of the whole state with the slot's position
/// coefficients), `V_m` the rows of the Gram eigenvectors at the `m` used index points and
/// `S = V_m Cov(a_s) V_mᵀ + R`, the update is `x += G w`, `P −= G M Gᵀ` with `M = V_mᵀ S⁻¹ V_m`
/// (`r×r`) and `w = V_mᵀ S⁻¹ ν`: a rank-`r` correction whatever the number of points.
#[derive(Debug, Clone, Copy)]
pub(crate) struct UpdateParts<const RANK: usize, const NX: usize> {
    /// Updated slot.
    pub slot: usize,
    /// Gram components used.
    pub r: usize,
    /// `G = P[:, a_s]` before the update, row-major: `g[i][k] = P[i, a_sk]` (`k ≥ r` zero).
    pub g: [[f32; RANK]; NX],
    /// `M = V_mᵀ S⁻¹ V_m`.
    pub m: SMatrix<f32, RANK, RANK>,
    /// `w = V_mᵀ S⁻¹ ν`.
    pub w: SVector<f32, RANK>,
    /// Pivots of `R + r₀² I` raised because it was not positive definite there.
    pub repaired: u8,
}

impl<const RANK: usize, const NX: usize> UpdateParts<RANK, NX> {
    /// Zeroed parts, to be filled by [`TemporalFilter::prepare_update`].
    pub const EMPTY: Self = Self {
        slot: 0,
        r: 0,
        g: [[0.0; RANK]; NX],
        m: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; RANK]; RANK])),
        w: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; RANK]; 1])),
        repaired: 0,
    };
}

/// What a lane update did besides updating.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UpdateInfo {
    /// Pivots of the pseudo-measurement covariance `R + r₀² I` that were raised to `r₀²`
    /// because it was not positive definite (0 for a valid covariance; see
    /// [`TemporalFilter::update`]).
    pub repaired_pivots: u8,
}

/// Disjoint, increasing index ranges, adjacent ones merged (at most `L`): the active parts of the
/// state (or of a lag's rows), so that inner loops run over long contiguous slices.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Spans<const L: usize> {
    lo: [usize; L],
    hi: [usize; L],
    n: usize,
}

impl<const L: usize> Spans<L> {
    /// No ranges.
    pub const fn new() -> Self {
        Self {
            lo: [0; L],
            hi: [0; L],
            n: 0,
        }
    }

    /// Appends `lo..hi` (after every range so far; merged with the last one when adjacent).
    pub fn push(&mut self, lo: usize, hi: usize) {
        if hi <= lo {
            return;
        }
        if self.n > 0 && self.hi.get(self.n - 1) == Some(&lo) {
            set(&mut self.hi, self.n - 1, hi);
        } else if self.n < L {
            set(&mut self.lo, self.n, lo);
            set(&mut self.hi, self.n, hi);
            self.n += 1;
        }
    }

    /// The ranges, in order.
    pub fn iter(&self) -> impl Iterator<Item = Range<usize>> + '_ {
        self.lo
            .iter()
            .zip(self.hi.iter())
            .take(self.n)
            .map(|(&lo, &hi)| lo..hi)
    }

    /// Every index, in order.
    pub fn indices(&self) -> impl Iterator<Item = usize> + '_ {
        self.iter().flatten()
    }
}

/// The coupled temporal filter over `LANES` slots of `POINTS` index points, `RANK` retained Gram
/// components, state size `NX = 2·LANES·RANK`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TemporalFilter<
    const LANES: usize,
    const POINTS: usize,
    const RANK: usize,
    const NX: usize,
> {
    x: SVector<f32, NX>,
    p: SMatrix<f32, NX, NX>,
    active: [bool; LANES],
    rank: [u8; LANES],
    /// A lane was updated since the last repair: f32 rounding may have broken positive
    /// definiteness.
    repair_due: bool,
}

impl<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize> Default
    for TemporalFilter<LANES, POINTS, RANK, NX>
{
    fn default() -> Self {
        Self::new()
    }
}

/// A product of finite factors stays far from overflow below this bound (f32 max is 3.4e38).
const SAFE: f32 = 1e30;

/// Smallest pivot [`TemporalFilter::repair_covariance`] accepts in the correlation form of the
/// covariance: well above the f32 rounding of an 84×84 factorisation (`n·ε ≈ 5e-6` per entry),
/// well below any correlation structure the model produces on purpose.
pub const REPAIR_PIVOT: f32 = 1e-4;

/// `sqrt(Σ v²)`, a bound on every `|v|` (infinite or NaN when some value is not finite).
fn norm_bound(v: &[f32]) -> f32 {
    math::sqrt(v.iter().map(|x| x * x).sum::<f32>())
}

impl<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize>
    TemporalFilter<LANES, POINTS, RANK, NX>
{
    /// No lanes (`const`, so the filter can live in a `static`).
    pub const fn new() -> Self {
        const { assert!(NX == 2 * LANES * RANK, "NX must be 2·LANES·RANK") };
        const { assert!(RANK >= 1 && RANK <= POINTS, "RANK must be 1..=POINTS") };
        const { assert!(LANES >= 1 && LANES <= 16, "LANES must be 1..=16") };
        const { assert!(POINTS <= 64, "POINTS must be at most 64") };
        Self {
            x: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NX]; 1])),
            p: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NX]; NX])),
            active: [false; LANES],
            rank: [0; LANES],
            repair_due: false,
        }
    }

    #[inline]
    fn idx(s: usize, j: usize, c: usize) -> usize {
        (s * RANK + j) * 2 + c
    }

    #[inline]
    fn pg(&self, i: usize, j: usize) -> f32 {
        self.p.as_slice().get(i + NX * j).copied().unwrap_or(0.0)
    }

    #[inline]
    fn xg(&self, i: usize) -> f32 {
        self.x.as_slice().get(i).copied().unwrap_or(0.0)
    }

    /// `true` when slot `s` holds a lane.
    pub fn is_active(&self, s: usize) -> bool {
        get(&self.active, s)
    }

    /// Number of active lanes.
    pub fn lanes(&self) -> usize {
        self.active.iter().filter(|a| **a).count()
    }

    /// The active slots' state ranges for `r` components: slot `s` holds
    /// `[s·2·RANK, s·2·RANK + 2r)` (the components `j ≥ r` are always zero and skipped).
    pub(crate) fn spans(&self, r: usize) -> Spans<LANES> {
        let mut sp = Spans::new();
        for s in 0..LANES {
            if self.is_active(s) {
                let lo = Self::idx(s, 0, 0);
                sp.push(lo, lo + 2 * r.min(RANK));
            }
        }
        sp
    }

    /// Lane `s`'s position at index point `i`, `Σ_j V[i, j] a_sj`; `None` for a free slot.
    pub fn position<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        i: usize,
    ) -> Option<f32> {
        if !self.is_active(s) {
            return None;
        }
        let r = Self::r_used(tables);
        Some(
            (0..r)
                .map(|j| {
                    tables.gram_eigvec.get((i, j)).copied().unwrap_or(0.0)
                        * self.xg(Self::idx(s, j, 0))
                })
                .sum(),
        )
    }

    /// Sets the B slot (rank from the left, `0..lanes()`) of every active lane.
    ///
    /// # Errors
    /// [`TemporalError::BadRanks`] unless the active lanes' ranks are a permutation of `0..lanes()`.
    pub fn set_ranks(&mut self, ranks: &[u8; LANES]) -> Result<(), TemporalError> {
        let n = self.lanes();
        let mut seen = 0u32;
        for s in 0..LANES {
            if self.is_active(s) {
                let r = usize::from(get(ranks, s));
                if r >= n || seen & (1 << r) != 0 {
                    return Err(TemporalError::BadRanks);
                }
                seen |= 1 << r;
            }
        }
        for s in 0..LANES {
            if self.is_active(s) {
                set(&mut self.rank, s, get(ranks, s));
            }
        }
        Ok(())
    }

    pub(crate) fn r_used<const NT: usize>(tables: &Tables<NT, LANES, POINTS>) -> usize {
        (tables.gram_rank as usize).min(RANK)
    }

    /// Starts a lane in the free slot `s` with rank `rank` among the lanes after it starts; the
    /// other active lanes' ranks are given in `ranks` (entry `s` is ignored). Its prior is the
    /// conditional of `(B ⊗ Λ_r) ⊗ P∞_t` given the other lanes' states (`Λ = B_{n+1}⁻¹` from the
    /// stored Cholesky factor of B, as in the spatial filter), which keeps `P̄` PSD.
    ///
    /// # Errors
    /// [`TemporalError::BadSlot`] for an active or out-of-range slot, [`TemporalError::BadRanks`]
    /// for ranks that are not a permutation after the start, [`TemporalError::Numerical`]; the
    /// state is unchanged.
    ///
    /// Returns the conditioning coefficients `a_t` over the slots (`x_new = Σ_t a_t x_t + w`).
    ///
    /// # Complexity
    /// `O(n_act · 2r · lanes)` with `n_act = 2r·lanes` the active state size; in place.
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub fn start_lane<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        rank: u8,
        ranks: &[u8; LANES],
    ) -> Result<[f32; LANES], TemporalError> {
        if s >= LANES || self.is_active(s) {
            return Err(TemporalError::BadSlot);
        }
        let mut all = *ranks;
        set(&mut all, s, rank);
        let before = (self.active, self.rank);
        set(&mut self.active, s, true);
        if let Err(e) = self.set_ranks(&all) {
            (self.active, self.rank) = before;
            return Err(e);
        }
        let n = self.lanes(); // including the new lane
        let k = usize::from(rank);
        // Row k of Λ = B_n⁻¹: L v = e_k, Lᵀ y = v.
        let l = &tables.coreg_chol;
        let lg = |i: usize, j: usize| l.get((i, j)).copied().unwrap_or(0.0);
        let mut v = [0.0f32; LANES];
        for i in 0..n {
            let mut acc = if i == k { 1.0 } else { 0.0 };
            for j in 0..i {
                acc -= lg(i, j) * get(&v, j);
            }
            set(&mut v, i, acc / lg(i, i));
        }
        let mut yv = [0.0f32; LANES];
        for i in (0..n).rev() {
            let mut acc = get(&v, i);
            for j in i + 1..n {
                acc -= lg(j, i) * get(&yv, j);
            }
            set(&mut yv, i, acc / lg(i, i));
        }
        let lkk = get(&yv, k);
        if !(lkk.is_finite() && lkk > 0.0) {
            (self.active, self.rank) = before;
            return Err(TemporalError::Numerical);
        }
        // a over slots: a_t = −Λ_{k, rank(t)} / Λ_kk for the other active slots.
        let mut a = [0.0f32; LANES];
        for t in 0..LANES {
            if t != s && self.is_active(t) {
                set(&mut a, t, -get(&yv, usize::from(get(&self.rank, t))) / lkk);
            }
        }
        let r = Self::r_used(tables);
        let sp = self.spans(r);
        let own = Self::idx(s, 0, 0)..Self::idx(s, 0, 0) + 2 * r;
        // Slot s's rows and columns are zero (free slot). New rows:
        // x_new[j,c] = Σ_t a_t x[t,j,c]; Cov(new[j,c], y) = Σ_t a_t Cov(x[t,j,c], y) for the other
        // lanes' y, written into row and column (s, j, c).
        for e in own.clone() {
            let off = e - Self::idx(s, 0, 0);
            let mut m = 0.0;
            for t in (0..LANES).filter(|&t| t != s && self.is_active(t)) {
                m += get(&a, t) * self.xg(Self::idx(t, 0, 0) + off);
            }
            if let Some(v) = self.x.as_mut_slice().get_mut(e) {
                *v = m;
            }
            for col in sp.indices().filter(|c| !own.contains(c)) {
                let mut cv = 0.0;
                for t in (0..LANES).filter(|&t| t != s && self.is_active(t)) {
                    cv += get(&a, t) * self.pg(Self::idx(t, 0, 0) + off, col);
                }
                let ps = self.p.as_mut_slice();
                if let Some(v) = ps.get_mut(e + NX * col) {
                    *v = cv;
                }
                if let Some(v) = ps.get_mut(col + NX * e) {
                    *v = cv;
                }
            }
        }
        // The new lane's own block: Σ_t' a_t' Cov(new, x_t') + (Λ_r ⊗ P∞_t) / Λ_kk.
        let pinf = &tables.temporal.p_inf;
        for e in own.clone() {
            let off = e - Self::idx(s, 0, 0);
            let (j, c) = (off / 2, off % 2);
            for e2 in own.clone() {
                let off2 = e2 - Self::idx(s, 0, 0);
                let (j2, c2) = (off2 / 2, off2 % 2);
                let mut cv = 0.0;
                for t in (0..LANES).filter(|&t| t != s && self.is_active(t)) {
                    cv += get(&a, t) * self.pg(e, Self::idx(t, 0, 0) + off2);
                }
                if j == j2 {
                    let lam = tables.gram_eigval.get(j).copied().unwrap_or(0.0);
                    cv += lam * pinf.get((c, c2)).copied().unwrap_or(0.0) / lkk;
                }
                if let Some(v) = self.p.as_mut_slice().get_mut(e + NX * e2) {
                    *v = cv;
                }
            }
        }
        let finite = own
            .clone()
            .all(|e| self.xg(e).is_finite() && sp.indices().all(|c| self.pg(e, c).is_finite()));
        if !finite {
            self.zero_slot(s);
            (self.active, self.rank) = before;
            return Err(TemporalError::Numerical);
        }
        Ok(a)
    }

    /// Zeroes slot `s`'s mean, rows and columns.
    fn zero_slot(&mut self, s: usize) {
        let lo = Self::idx(s, 0, 0);
        let hi = lo + 2 * RANK;
        if let Some(seg) = self.x.as_mut_slice().get_mut(lo..hi) {
            seg.fill(0.0);
        }
        let ps = self.p.as_mut_slice();
        for j in 0..NX {
            if let Some(seg) = ps.get_mut(j * NX + lo..j * NX + hi) {
                seg.fill(0.0);
            }
        }
        if let Some(seg) = ps.get_mut(lo * NX..hi * NX) {
            seg.fill(0.0);
        }
    }

    /// Removes the lane in slot `s` (its rows and columns are zeroed); the caller re-ranks the
    /// remaining lanes with [`TemporalFilter::set_ranks`].
    pub fn remove_lane(&mut self, s: usize) {
        if !self.is_active(s) {
            return;
        }
        set(&mut self.active, s, false);
        self.zero_slot(s);
    }

    /// Prediction over a frame step `t` seconds (any `t > 0`: dropped frames are exact):
    /// `x ← F̄ x`, `P ← F̄ P F̄ᵀ + (B_π ⊗ Λ_r) ⊗ Q_t(t)` over the active lanes, `B_π` indexed by rank.
    ///
    /// # Errors
    /// [`TemporalError::BadStep`]; the state is unchanged.
    ///
    /// # Complexity
    /// About `8·n_act²` multiply-adds for `F̄ P F̄ᵀ` on one triangle of 2×2 blocks, plus
    /// `(lanes·r)·lanes` noise blocks; `n_act = 2r·lanes`.
    pub fn predict<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        t: f32,
    ) -> Result<(), TemporalError> {
        let (f, q) = tables
            .temporal
            .kernel
            .transition(t)
            .ok_or(TemporalError::BadStep)?;
        self.predict_with(tables, &f, &q);
        Ok(())
    }

    /// [`TemporalFilter::predict`] with a transition `f` and noise `q` already computed.
    pub(crate) fn predict_with<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        f: &Matrix2<f32>,
        q: &Matrix2<f32>,
    ) {
        let r = Self::r_used(tables);
        let sp = self.spans(r);
        let (f00, f01, f10, f11) = (f.m11, f.m12, f.m21, f.m22);
        let xs = self.x.as_mut_slice();
        for rg in sp.iter() {
            if let Some(seg) = xs.get_mut(rg) {
                for pair in seg.chunks_exact_mut(2) {
                    if let [a, b] = pair {
                        let (x0, x1) = (*a, *b);
                        *a = f00 * x0 + f01 * x1;
                        *b = f10 * x0 + f11 * x1;
                    }
                }
            }
        }
        // F B Fᵀ on every 2×2 block of the upper triangle (block rows ≤ block columns), mirrored.
        let ps = self.p.as_mut_slice();
        for c in sp.indices().step_by(2) {
            for a in sp.indices().step_by(2).take_while(|&a| a <= c) {
                let g = |ps: &[f32], i: usize, j: usize| ps.get(i + NX * j).copied().unwrap_or(0.0);
                let (b00, b01, b10, b11) = (
                    g(ps, a, c),
                    g(ps, a, c + 1),
                    g(ps, a + 1, c),
                    g(ps, a + 1, c + 1),
                );
                // F B
                let (m00, m01) = (f00 * b00 + f01 * b10, f00 * b01 + f01 * b11);
                let (m10, m11) = (f10 * b00 + f11 * b10, f10 * b01 + f11 * b11);
                // (F B) Fᵀ
                let n = [
                    (a, c, m00 * f00 + m01 * f01),
                    (a, c + 1, m00 * f10 + m01 * f11),
                    (a + 1, c, m10 * f00 + m11 * f01),
                    (a + 1, c + 1, m10 * f10 + m11 * f11),
                ];
                for (i, j, v) in n {
                    if let Some(e) = ps.get_mut(i + NX * j) {
                        *e = v;
                    }
                    if a != c {
                        if let Some(e) = ps.get_mut(j + NX * i) {
                            *e = v;
                        }
                    }
                }
            }
        }
        for s in 0..LANES {
            if !get(&self.active, s) {
                continue;
            }
            for s2 in 0..LANES {
                if !get(&self.active, s2) {
                    continue;
                }
                let bij = tables
                    .coreg
                    .get((
                        usize::from(get(&self.rank, s)),
                        usize::from(get(&self.rank, s2)),
                    ))
                    .copied()
                    .unwrap_or(0.0);
                for j in 0..r {
                    let lam = tables.gram_eigval.get(j).copied().unwrap_or(0.0);
                    let qq: Matrix2<f32> = q * (bij * lam);
                    for c in 0..2 {
                        for c2 in 0..2 {
                            if let Some(e) =
                                ps.get_mut(Self::idx(s, j, c) + NX * Self::idx(s2, j, c2))
                            {
                                *e += qq.get((c, c2)).copied().unwrap_or(0.0);
                            }
                        }
                    }
                }
            }
        }
    }

    /// Update with lane `s`'s pseudo-measurements: `y = V_r a_s + e`, `e ~ N(0, R + r₀² I)` over the
    /// present index points (`R` the observation's covariance block), as the rank-`r` correction
    /// of `UpdateParts`; the covariance keeps one computed triangle, mirrored (symmetric).
    ///
    /// A pseudo-measurement covariance that is not positive semi-definite is repaired, not
    /// trusted: its factorisation raises every pivot of `R + r₀² I` that falls below `r₀²/2` to
    /// `r₀²` (a PSD `R` has all its pivots `≥ r₀²`), so the posterior stays PSD; the count is in
    /// the returned [`UpdateInfo`].
    ///
    /// # Errors
    /// [`TemporalError::BadSlot`], [`TemporalError::NoData`], [`TemporalError::Numerical`]; the
    /// state is unchanged.
    ///
    /// # Complexity
    /// `m³/6 + m²·r + m·r²` for the gain (`m ≤ POINTS` present points, one `m×m` Cholesky) and
    /// `n_act²·r/2` for the covariance, `n_act = 2r·lanes`.
    pub fn update<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        obs: &LaneObservation<POINTS>,
    ) -> Result<UpdateInfo, TemporalError> {
        let mut g = UpdateParts::EMPTY;
        self.prepare_update(tables, s, obs, &mut g)?;
        self.check_update(&g)?;
        self.apply_update(&g);
        Ok(UpdateInfo {
            repaired_pivots: g.repaired,
        })
    }

    /// The gain parts of [`TemporalFilter::update`] (shared with the fixed-lag smoother), written
    /// into `parts`; on error `parts` holds nothing meaningful.
    #[allow(non_snake_case, clippy::too_many_lines)]
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub(crate) fn prepare_update<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        obs: &LaneObservation<POINTS>,
        parts: &mut UpdateParts<RANK, NX>,
    ) -> Result<(), TemporalError> {
        if !self.is_active(s) {
            return Err(TemporalError::BadSlot);
        }
        let r = Self::r_used(tables);
        let v = &tables.gram_eigvec;
        let vg = |i: usize, j: usize| v.get((i, j)).copied().unwrap_or(0.0);
        // The used index points, in order.
        let mut us = [0u8; POINTS];
        let mut m = 0usize;
        for i in 0..POINTS {
            if get(&obs.present, i) && obs.z.get(i).is_some_and(|z| z.is_finite()) {
                set(&mut us, m, i as u8);
                m += 1;
            }
        }
        if m == 0 {
            return Err(TemporalError::NoData);
        }
        let u = |a: usize| usize::from(get(&us, a));
        let a0 = Self::idx(s, 0, 0);
        // Cov(a_s) (r×r) and T = V_m Cov(a_s) (m×r).
        let pss = SMatrix::<f32, RANK, RANK>::from_fn(|j, k| {
            if j < r && k < r {
                self.pg(a0 + 2 * j, a0 + 2 * k)
            } else {
                0.0
            }
        });
        let mut t = SMatrix::<f32, POINTS, RANK>::zeros();
        for a in 0..m {
            for k in 0..r {
                let mut acc = 0.0;
                for j in 0..r {
                    acc += vg(u(a), j) * pss.get((j, k)).copied().unwrap_or(0.0);
                }
                if let Some(e) = t.get_mut((a, k)) {
                    *e = acc;
                }
            }
        }
        // R̃ = sym(R) + r₀² I on the used points (lower triangle). With R PSD every pivot of its
        // Cholesky factorisation is ≥ r₀²; a pivot below r₀²/2 means R is not PSD (the spatial
        // pseudo-measurement covariance can be slightly indefinite: moment-matched mixtures make
        // the per-lane RTS cross-covariances inconsistent). Such pivots are raised to r₀² (a
        // modified Cholesky: R̃ + diag(e), e ≥ 0), so the noise used is PSD and the posterior
        // stays PSD; they are counted.
        let r0 = tables.hyper.pseudo_noise;
        let mut l = SMatrix::<f32, POINTS, POINTS>::zeros();
        for b in 0..m {
            for a in b..m {
                let acc = obs.cov.get((u(a), u(b))).copied().unwrap_or(0.0);
                let acc2 = obs.cov.get((u(b), u(a))).copied().unwrap_or(0.0);
                if let Some(e) = l.get_mut((a, b)) {
                    *e = 0.5 * (acc + acc2) + if a == b { r0 } else { 0.0 };
                }
            }
        }
        let mut rt = l;
        let mut load = [0.0f32; POINTS];
        let repaired = math::cholesky_loaded(&mut rt, m, 0.5 * r0, r0, &mut load);
        if repaired == u8::MAX {
            return Err(TemporalError::Numerical);
        }
        // S = T V_mᵀ + R̃ + diag(e) on the leading m×m block (lower triangle, then factored).
        for b in 0..m {
            for a in b..m {
                let mut acc = l.get((a, b)).copied().unwrap_or(0.0)
                    + if a == b { get(&load, a) } else { 0.0 };
                for k in 0..r {
                    acc += t.get((a, k)).copied().unwrap_or(0.0) * vg(u(b), k);
                }
                if let Some(e) = l.get_mut((a, b)) {
                    *e = acc;
                }
            }
        }
        if !cholesky_lower(&mut l, m) {
            return Err(TemporalError::Numerical);
        }
        // A = L⁻¹ V_m (m×r), b = L⁻¹ ν.
        let mut A =
            SMatrix::<f32, POINTS, RANK>::from_fn(
                |a, k| {
                    if a < m && k < r {
                        vg(u(a), k)
                    } else {
                        0.0
                    }
                },
            );
        for k in 0..r {
            if let Some(col) = A.as_mut_slice().get_mut(k * POINTS..k * POINTS + m) {
                forward_subst(&l, col);
            }
        }
        let mut b = [0.0f32; POINTS];
        for (a, bv) in b.iter_mut().enumerate().take(m) {
            let mut pred = 0.0;
            for j in 0..r {
                pred += vg(u(a), j) * self.xg(a0 + 2 * j);
            }
            *bv = obs.z.get(u(a)).copied().unwrap_or(0.0) - pred;
        }
        if let Some(bs) = b.get_mut(..m) {
            forward_subst(&l, bs);
        }
        // M = AᵀA, w = Aᵀb.
        let mut M = SMatrix::<f32, RANK, RANK>::zeros();
        let mut w = SVector::<f32, RANK>::zeros();
        let As = A.as_slice();
        let col = |k: usize| As.get(k * POINTS..k * POINTS + m).unwrap_or(&[]);
        for k in 0..r {
            let ck = col(k);
            if let Some(e) = w.get_mut(k) {
                *e = ck.iter().zip(b.iter()).map(|(x, y)| x * y).sum();
            }
            for k2 in k..r {
                let d: f32 = ck.iter().zip(col(k2)).map(|(x, y)| x * y).sum();
                if let Some(e) = M.get_mut((k, k2)) {
                    *e = d;
                }
                if let Some(e) = M.get_mut((k2, k)) {
                    *e = d;
                }
            }
        }
        if !(M.iter().chain(w.iter()).all(|v| v.is_finite())) {
            return Err(TemporalError::Numerical);
        }
        // G = P[:, a_s] (only the active rows are non-zero), row-major, written in place (the
        // parts are 2.6 KiB: no copy on the stack).
        for (i, row) in parts.g.iter_mut().enumerate() {
            for (k, e) in row.iter_mut().enumerate() {
                *e = if k < r { self.pg(i, a0 + 2 * k) } else { 0.0 };
            }
        }
        parts.slot = s;
        parts.r = r;
        parts.m = M;
        parts.w = w;
        parts.repaired = repaired;
        Ok(())
    }

    /// Checks that applying `g` keeps the state finite (bounds on the products, before anything
    /// is written).
    ///
    /// # Errors
    /// [`TemporalError::Numerical`].
    pub(crate) fn check_update(&self, g: &UpdateParts<RANK, NX>) -> Result<(), TemporalError> {
        let r = g.r as f32;
        let gmax = self.g_max(g);
        let mmax = norm_bound(g.m.as_slice());
        let wmax = norm_bound(g.w.as_slice());
        let ok = r * gmax * wmax < SAFE && r * r * gmax * mmax * gmax < SAFE;
        // NaN compares false: a non-finite bound fails the check.
        if ok {
            Ok(())
        } else {
            Err(TemporalError::Numerical)
        }
    }

    /// A bound on `|G|` over the active rows (`sqrt` of the sum of squares; not finite when some
    /// entry is not).
    pub(crate) fn g_max(&self, g: &UpdateParts<RANK, NX>) -> f32 {
        let sp = self.spans(g.r);
        let ss: f32 = sp
            .indices()
            .filter_map(|i| g.g.get(i))
            .map(|row| dot(row, row))
            .sum();
        math::sqrt(ss)
    }

    /// Applies checked gain parts in place: `x += G w`, `P −= G M Gᵀ` over the active block
    /// (one triangle computed, mirrored).
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub(crate) fn apply_update(&mut self, g: &UpdateParts<RANK, NX>) {
        let sp = self.spans(g.r);
        let w: [f32; RANK] = core::array::from_fn(|k| g.w.get(k).copied().unwrap_or(0.0));
        // x += G w.
        for i in sp.indices() {
            if let (Some(xv), Some(gi)) = (self.x.as_mut_slice().get_mut(i), g.g.get(i)) {
                *xv += dot(gi, &w);
            }
        }
        // U = G M, row-major, active rows.
        let mut u = [[0.0f32; RANK]; NX];
        for i in sp.indices() {
            if let (Some(ui), Some(gi)) = (u.get_mut(i), g.g.get(i)) {
                *ui = times_sym(gi, &g.m);
            }
        }
        // P[i, j] −= U_i · G_j for active i ≤ j (column j of P is contiguous), two columns (a
        // component's position j and rate j + 1) at a time: rows i ≤ j for both, then the
        // diagonal entry (j + 1, j + 1).
        let ps = self.p.as_mut_slice();
        for j in sp.indices().step_by(2) {
            let (Some(g0), Some(g1)) = (g.g.get(j), g.g.get(j + 1)) else {
                continue;
            };
            let Some(pair) = ps.get_mut(j * NX..(j + 2) * NX) else {
                continue;
            };
            let (c0, c1) = pair.split_at_mut(NX);
            for rg in sp.iter() {
                if rg.start > j {
                    break;
                }
                let rg = rg.start..rg.end.min(j + 1);
                if let (Some(d0), Some(d1), Some(ur)) =
                    (c0.get_mut(rg.clone()), c1.get_mut(rg.clone()), u.get(rg))
                {
                    for ((v0, v1), ui) in d0.iter_mut().zip(d1.iter_mut()).zip(ur) {
                        *v0 -= dot(ui, g0);
                        *v1 -= dot(ui, g1);
                    }
                }
            }
            if let (Some(v), Some(ui)) = (c1.get_mut(j + 1), u.get(j + 1)) {
                *v -= dot(ui, g1);
            }
        }
        // Mirror the upper triangle into the lower one.
        for j in sp.indices() {
            for i in sp.indices().take_while(|&i| i < j) {
                let v = ps.get(i + NX * j).copied().unwrap_or(0.0);
                if let Some(e) = ps.get_mut(j + NX * i) {
                    *e = v;
                }
            }
        }
        // Any update can leave the covariance indefinite in f32 (see `repair_covariance`).
        self.repair_due = true;
    }

    /// Lane `s`'s positions at the index points, `f = V_r a_s`, and their variances
    /// `diag(V_r P_aa V_rᵀ)`; `None` for an inactive slot.
    pub fn lane<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
    ) -> Option<(SVector<f32, POINTS>, SVector<f32, POINTS>)> {
        if !self.is_active(s) {
            return None;
        }
        let r = Self::r_used(tables);
        let a: [f32; RANK] = core::array::from_fn(|j| {
            if j < r {
                self.xg(Self::idx(s, j, 0))
            } else {
                0.0
            }
        });
        let p: [[f32; RANK]; RANK] = core::array::from_fn(|j| {
            core::array::from_fn(|j2| {
                if j < r && j2 < r {
                    self.pg(Self::idx(s, j, 0), Self::idx(s, j2, 0))
                } else {
                    0.0
                }
            })
        });
        Some(project(&tables.gram_eigvec, r, &a, &p))
    }

    /// `cᵀ Cov(a_s) c` over the first `r` position coefficients of slot `s` (0 for a free slot),
    /// not below the rounding bound of its f32 computation (see [`TemporalFilter::lane`]).
    pub fn coefficient_var(&self, s: usize, c: &[f32; POINTS], r: usize) -> f32 {
        if !self.is_active(s) {
            return 0.0;
        }
        let mut acc = 0.0f32;
        let mut bound = 0.0f32;
        for j in 0..r.min(RANK) {
            let ij = Self::idx(s, j, 0);
            bound += get(c, j).abs() * math::sqrt(self.pg(ij, ij).abs());
            for j2 in 0..r.min(RANK) {
                acc += get(c, j) * get(c, j2) * self.pg(ij, Self::idx(s, j2, 0));
            }
        }
        // Not below the rounding bound of its computation (see `project`).
        acc.max(2.0 * r as f32 * f32::EPSILON * bound * bound)
    }

    /// The stacked mean (for the smoother and diagnostics).
    pub fn mean(&self) -> &SVector<f32, NX> {
        &self.x
    }

    /// State index of slot `s`, Gram component `j`, Matérn component `c` (0: position, 1: rate).
    pub fn index(s: usize, j: usize, c: usize) -> usize {
        Self::idx(s, j, c)
    }

    /// The stacked covariance (for tests and diagnostics).
    pub fn covariance(&self) -> &SMatrix<f32, NX, NX> {
        &self.p
    }

    /// `true` when a lane was updated since the last repair (see
    /// [`TemporalFilter::repair_covariance`]).
    pub fn repair_due(&self) -> bool {
        self.repair_due
    }

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
        let sp = self.spans(Self::r_used(tables));
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
            theta2 = theta2.max(v * v);
        }
        let d = REPAIR_PIVOT.max(dk.abs()).max(theta2);
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

/// `a · b` over a fixed length (unrolled by the compiler).
#[inline(always)]
pub(crate) fn dot<const R: usize>(a: &[f32; R], b: &[f32; R]) -> f32 {
    let mut acc = 0.0;
    for (x, y) in a.iter().zip(b) {
        acc += x * y;
    }
    acc
}

/// `a M` for a row `a` and a square `M` (`(a M)_k = Σ_j a_j M[j, k]`).
#[inline(always)]
pub(crate) fn times_sym<const R: usize>(a: &[f32; R], m: &SMatrix<f32, R, R>) -> [f32; R] {
    let ms = m.as_slice();
    core::array::from_fn(|k| {
        let col = ms.get(k * R..(k + 1) * R).unwrap_or(&[]);
        a.iter().zip(col).map(|(x, y)| x * y).sum()
    })
}

/// A lane from its coefficients: positions `f_i = v_i · a` and variances `v_i P v_iᵀ` at every
/// index point, `v_i` the first `r` entries of row `i` of the Gram eigenvectors `v`.
/// `POINTS · (RANK² + 2·RANK)` multiply-adds.
/// Positions `V_r a` and variances `diag(V_r P V_rᵀ)` at the index points. A variance is not
/// published below a bound on the rounding error of its own f32 computation,
/// `2r·ε·(Σ_j |v_j| √P_jj)²` (`≥ 2r·ε·|v|ᵀ|P||v|` for a PSD `P`): where the
/// exact value is smaller than that (a direction measured ~10⁵ times more precisely than the
/// components' prior scale), the computed one is rounding noise and can come out negative.
pub(crate) fn project<const POINTS: usize, const RANK: usize>(
    v: &SMatrix<f32, POINTS, POINTS>,
    r: usize,
    a: &[f32; RANK],
    p: &[[f32; RANK]; RANK],
) -> (SVector<f32, POINTS>, SVector<f32, POINTS>) {
    let mut mean = SVector::<f32, POINTS>::zeros();
    let mut var = SVector::<f32, POINTS>::zeros();
    let sd: [f32; RANK] = core::array::from_fn(|j| {
        p.get(j)
            .and_then(|row| row.get(j))
            .map_or(0.0, |d| math::sqrt(d.abs()))
    });
    let tol = 2.0 * r as f32 * f32::EPSILON;
    for (i, (m, w)) in mean.iter_mut().zip(var.iter_mut()).enumerate() {
        let vi: [f32; RANK] = core::array::from_fn(|j| {
            if j < r {
                v.get((i, j)).copied().unwrap_or(0.0)
            } else {
                0.0
            }
        });
        *m = dot(&vi, a);
        let pv: [f32; RANK] = core::array::from_fn(|j| p.get(j).map_or(0.0, |row| dot(row, &vi)));
        let s: f32 = vi.iter().zip(&sd).map(|(v, d)| v.abs() * d).sum();
        *w = dot(&pv, &vi).max(tol * s * s);
    }
    (mean, var)
}

/// In-place Cholesky factorisation of the leading `n×n` block of `a` (the lower triangle is read
/// and replaced by `L`; the upper triangle is not used). `false` when the block is not positive
/// definite or not finite.
fn cholesky_lower<const N: usize>(a: &mut SMatrix<f32, N, N>, n: usize) -> bool {
    for j in 0..n.min(N) {
        let mut d = a.get((j, j)).copied().unwrap_or(0.0);
        for k in 0..j {
            let v = a.get((j, k)).copied().unwrap_or(0.0);
            d -= v * v;
        }
        if !(d.is_finite() && d > 0.0) {
            return false;
        }
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

/// Solves `L y = b` in place, `L` the lower factor of [`cholesky_lower`], `b.len()` its order.
fn forward_subst<const N: usize>(l: &SMatrix<f32, N, N>, b: &mut [f32]) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::SMatrix;

    fn min_eig_corr(p: &SMatrix<f32, 4, 4>) -> f64 {
        let m = p.map(f64::from);
        let d = m.diagonal().map(|v| 1.0 / v.abs().sqrt());
        let c = SMatrix::<f64, 4, 4>::from_fn(|i, j| m[(i, j)] * d[i] * d[j]);
        c.symmetric_eigenvalues().min()
    }

    #[test]
    fn repair_leaves_a_well_conditioned_covariance_alone() {
        let l = SMatrix::<f32, 4, 4>::new(
            2.0, 0.0, 0.0, 0.0, 0.5, 1.0, 0.0, 0.0, -0.3, 0.2, 0.7, 0.0, 0.1, 0.4, -0.2, 0.5,
        );
        let p = l * l.transpose();
        let mut q = p;
        assert_eq!(
            repair_psd::<4>(q.as_mut_slice(), 4, core::slice::from_ref(&(0..4))),
            0
        );
        assert_eq!(q, p);
    }

    #[test]
    fn repair_makes_an_indefinite_covariance_psd_by_inflating_variances_only() {
        // Correlations of 0.99 between all of 0..3 and −0.99 between 0 and 3: indefinite, with
        // very different scales (as a posterior after a strongly informative update).
        let s = [1e-3f32, 2e-1, 5.0, 3e-4];
        let mut p = SMatrix::<f32, 4, 4>::from_fn(|i, j| {
            let rho = if i == j {
                1.0
            } else if (i, j) == (0, 3) || (i, j) == (3, 0) {
                -0.99
            } else {
                0.99
            };
            rho * (s[i] * s[j]).sqrt()
        });
        assert!(min_eig_corr(&p) < -0.5);
        let before = p;
        let raised = repair_psd::<4>(p.as_mut_slice(), 4, core::slice::from_ref(&(0..4)));
        assert!(raised > 0);
        assert!(min_eig_corr(&p) > 0.0, "{}", min_eig_corr(&p));
        for i in 0..4 {
            assert!(p[(i, i)] >= before[(i, i)]);
            // Bounded inflation (multipliers within ±1): at most a few times the variance.
            assert!(p[(i, i)] <= 10.0 * before[(i, i)], "{i}: {}", p[(i, i)]);
            for j in 0..4 {
                if i != j {
                    assert_eq!(p[(i, j)], before[(i, j)]);
                }
            }
        }
    }

    #[test]
    fn repair_touches_only_the_given_indices() {
        let mut p = SMatrix::<f32, 4, 4>::identity();
        p[(0, 2)] = 2.0;
        p[(2, 0)] = 2.0;
        p[(1, 1)] = -1.0;
        let before = p;
        assert!(repair_psd::<4>(p.as_mut_slice(), 4, &[0..1, 2..3]) > 0);
        assert_eq!(p[(1, 1)], -1.0);
        assert!(p[(0, 0)] > 1.0 || p[(2, 2)] > 1.0);
        assert_eq!(p[(0, 2)], before[(0, 2)]);
    }
}
