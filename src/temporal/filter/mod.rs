//! The temporal coupled filter (docs/design.md §4.2) in the eigenbasis of the Gram matrix.
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
//! and columns stay zero): prediction about `2·n_act²` multiply-adds (`F̄ P F̄ᵀ` on one triangle
//! of 2×2 blocks, 16 a block, Kronecker noise), each lane update a rank-`r` correction `P −= G M Gᵀ` in
//! `n_act²·r/2` (one triangle, mirrored) plus `m³/6 + m²·r` for its gain (`m ≤ POINTS` present
//! points, one `m×m` Cholesky). At 3 lanes, rank 7: ≈ 3.5 k + 3 × 6.2 k multiply-adds. Updates
//! are checked (bounds on every product) before anything is written, then applied in place: no
//! copy of the 28 KiB covariance on the stack. No allocation, no recursion, no panicking indexing.

use core::ops::Range;

use nalgebra::{Matrix2, SMatrix, SVector};

use crate::linalg::{self, cholesky_lower, forward_subst, get, set};
use crate::math;
use crate::observation::LaneObservation;
use crate::tables::Tables;

mod repair;
mod update;
pub(crate) use repair::repair_psd;
pub(crate) use update::{dot, project, times_sym};

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
    /// `wᵀ M⁻¹ w` (row-evidence updates only).
    pub nis: f32,
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
        nis: 0.0,
    };
}

/// What a lane update did besides updating.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UpdateInfo {
    /// Pivots of the pseudo-measurement covariance `R + r₀² I` that were raised to `r₀²`
    /// because it was not positive definite (0 for a valid covariance; see
    /// [`TemporalFilter::update`]).
    pub repaired_pivots: u8,
    /// For an update by row evidence (`TemporalFilter::prepare_info_update`): the
    /// normalised innovation `wᵀ M⁻¹ w` on the lane's Gram components (χ² with `r` degrees of
    /// freedom when the model holds); 0 otherwise.
    pub nis: f32,
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
    /// Some cross-lane block of `P` may be non-zero (`false`: all are exactly zero, see
    /// [`TemporalFilter::uncoupled`]; `false` is the all-zero state of a `static` in `.bss`).
    coupled: bool,
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

/// Factorisations [`TemporalFilter::repair_covariance`] tries before it takes the Gershgorin
/// shift (which needs none): its worst case is this many `n³/6` factorisations.
pub const REPAIR_ATTEMPTS: u8 = 6;

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
            coupled: false,
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

    /// `true` while every cross-lane block of the covariance is exactly zero: no lane start
    /// has been conditioned on another lane and no prediction has added cross-lane noise since
    /// the filter was last empty. That is the case for every frame when `B` is diagonal (the
    /// uncoupled model, [`crate::tables::UNCOUPLED`]): starts then condition on nothing
    /// (`a_t = −Ω_{k,π(t)}/Ω_kk = 0`), the noise `(B_π ⊗ Λ_r) ⊗ Q_t` has no cross-lane block,
    /// and an update's gain columns `G = P[:, a_s]` vanish outside lane `s`. The filter then
    /// runs every loop on the lanes' own blocks (docs/design.md §4.2.6): the same numbers, at
    /// `n·(2r)²` instead of `(2r·n)²` per covariance pass.
    pub fn uncoupled(&self) -> bool {
        !self.coupled
    }

    /// Runs the coupled loops from now on, whatever the covariance's structure (tests of the
    /// own-block loops against them).
    #[cfg(test)]
    pub(crate) fn force_coupled_loops(&mut self) {
        self.coupled = true;
    }

    /// The state range of slot `s` for `r` components, `[s·2·RANK, s·2·RANK + 2r)` (empty when
    /// `s` is out of range).
    pub(crate) fn own_span(&self, s: usize, r: usize) -> Spans<LANES> {
        let mut sp = Spans::new();
        if s < LANES {
            let lo = Self::idx(s, 0, 0);
            sp.push(lo, lo + 2 * r.min(RANK));
        }
        sp
    }

    /// The state ranges an update of slot `s` touches: every active slot's, or slot `s`'s own
    /// while the filter is [`uncoupled`](TemporalFilter::uncoupled) (its gain columns are exactly
    /// zero elsewhere).
    pub(crate) fn update_spans(&self, s: usize, r: usize) -> Spans<LANES> {
        if !self.coupled {
            self.own_span(s, r)
        } else {
            self.spans(r)
        }
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
        // The lanes the new one is conditioned on: the other active lanes with `a_t ≠ 0`, in slot
        // order. A term `0 · v` of a finite `v` is ±0 and adding it to a sum that starts at +0 changes
        // no bit, so the sums below skip those lanes (all of them on the uncoupled tables).
        let mut on = [0usize; LANES];
        let mut n_on = 0usize;
        for t in (0..LANES).filter(|&t| t != s && self.is_active(t) && get(&a, t) != 0.0) {
            set(&mut on, n_on, t);
            n_on += 1;
        }
        let on = on.get(..n_on).unwrap_or(&[]);
        // Slot s's rows and columns are zero (free slot). New rows:
        // x_new[j,c] = Σ_t a_t x[t,j,c]; Cov(new[j,c], y) = Σ_t a_t Cov(x[t,j,c], y) for the other
        // lanes' y, written into row and column (s, j, c).
        for e in own.clone() {
            let off = e - Self::idx(s, 0, 0);
            let mut m = 0.0;
            for &t in on {
                m += get(&a, t) * self.xg(Self::idx(t, 0, 0) + off);
            }
            if let Some(v) = self.x.as_mut_slice().get_mut(e) {
                *v = m;
            }
            for col in sp.indices().filter(|c| !own.contains(c)) {
                let mut cv = 0.0;
                for &t in on {
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
                for &t in on {
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
        // Conditioned on another lane: the new lane's cross blocks are no longer zero.
        if a.iter().any(|&v| v != 0.0) {
            self.coupled = true;
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
        if self.lanes() == 0 {
            // Nothing left to be coupled to (free slots' rows and columns are zero).
            self.coupled = false;
        }
    }

    /// Prediction over a frame step `t` seconds (any `t > 0`: dropped frames are exact):
    /// `x ← F̄ x`, `P ← F̄ P F̄ᵀ + (B_π ⊗ Λ_r) ⊗ Q_t(t)` over the active lanes, `B_π` indexed by rank.
    ///
    /// # Errors
    /// [`TemporalError::BadStep`]; the state is unchanged.
    ///
    /// # Complexity
    /// About `2·n_act²` multiply-adds for `F̄ P F̄ᵀ` on one triangle of 2×2 blocks (16 a
    /// block), plus `(lanes·r)·lanes` noise blocks; `n_act = 2r·lanes`.
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
        // F B Fᵀ on every 2×2 block of the upper triangle (block rows ≤ block columns), mirrored;
        // uncoupled, on the lanes' own blocks only (the cross blocks are zero and stay zero).
        let own_only = !self.coupled;
        let ps = self.p.as_mut_slice();
        for c in sp.indices().step_by(2) {
            let first = if own_only { c - c % (2 * RANK) } else { 0 };
            for a in sp
                .indices()
                .step_by(2)
                .skip_while(|&a| a < first)
                .take_while(|&a| a <= c)
            {
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
                // (F B) Fᵀ; a diagonal block takes its (1, 0) entry from its (0, 1) one, so that
                // P stays exactly symmetric (the two products round differently).
                let v01 = m00 * f10 + m01 * f11;
                let v10 = if a == c { v01 } else { m10 * f00 + m11 * f01 };
                let n = [
                    (a, c, m00 * f00 + m01 * f01),
                    (a, c + 1, v01),
                    (a + 1, c, v10),
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
        let mut cross_noise = false;
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
                if s != s2 {
                    if bij == 0.0 {
                        continue;
                    }
                    cross_noise = true;
                }
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
        if cross_noise {
            self.coupled = true;
        }
    }

    /// Lane `s`'s positions at the index points, `f = V_r a_s`, and their variances
    /// `diag(V_r P_aa V_rᵀ)`; `None` for an inactive slot.
    pub fn lane<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
    ) -> Option<(SVector<f32, POINTS>, SVector<f32, POINTS>)> {
        self.component(tables, s, 0)
    }

    /// Lane `s`'s rates of change at the index points, `ḟ = V_r ȧ_s` (the Matérn state's rate
    /// components, per second), and their variances; `None` for an inactive slot.
    pub fn lane_rate<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
    ) -> Option<(SVector<f32, POINTS>, SVector<f32, POINTS>)> {
        self.component(tables, s, 1)
    }

    /// [`Self::lane`] (`c` = 0) or [`Self::lane_rate`] (`c` = 1).
    fn component<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        c: usize,
    ) -> Option<(SVector<f32, POINTS>, SVector<f32, POINTS>)> {
        if !self.is_active(s) {
            return None;
        }
        let r = Self::r_used(tables);
        let a: [f32; RANK] = core::array::from_fn(|j| {
            if j < r {
                self.xg(Self::idx(s, j, c))
            } else {
                0.0
            }
        });
        let p: [[f32; RANK]; RANK] = core::array::from_fn(|j| {
            core::array::from_fn(|j2| {
                if j < r && j2 < r {
                    self.pg(Self::idx(s, j, c), Self::idx(s, j2, c))
                } else {
                    0.0
                }
            })
        });
        Some(project(&tables.gram_eigvec, r, &a, &p))
    }

    /// `cᵀ Cov(a_s) c` over the first `r` position coefficients of slot `s` (0 for a free slot),
    /// not below the rounding bound of its f32 computation (see [`TemporalFilter::lane`]).
    /// `c` holds the coefficients (any length: entries past its end count as 0).
    pub fn coefficient_var(&self, s: usize, c: &[f32], r: usize) -> f32 {
        if !self.is_active(s) {
            return 0.0;
        }
        let cj = |j: usize| c.get(j).copied().unwrap_or(0.0);
        let mut acc = 0.0f32;
        let mut bound = 0.0f32;
        for j in 0..r.min(RANK) {
            let ij = Self::idx(s, j, 0);
            bound += cj(j).abs() * math::sqrt(self.pg(ij, ij).abs());
            for j2 in 0..r.min(RANK) {
                acc += cj(j) * cj(j2) * self.pg(ij, Self::idx(s, j2, 0));
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
}

#[cfg(test)]
mod tests;
