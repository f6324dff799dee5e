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
//! Prediction `O(NX²)` (block-diagonal `F̄`, Kronecker `Q̄`), each lane update `O(NX²·m)` with
//! `m ≤ POINTS` present points, one `m×m` Cholesky (padded to `POINTS`). No allocation, no
//! recursion, no panicking indexing.

use nalgebra::{Matrix2, SMatrix, SVector};

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
#[derive(Debug, Clone, Copy)]
pub(crate) struct UpdateParts<const POINTS: usize, const NX: usize> {
    /// Updated slot.
    pub slot: usize,
    /// Gram components used.
    pub rank_used: usize,
    /// Index points used.
    pub used: [bool; POINTS],
    /// `P Hᵀ` (zero columns for unused points).
    pub ph: SMatrix<f32, NX, POINTS>,
    /// `S⁻¹ H P`.
    pub kt: SMatrix<f32, POINTS, NX>,
    /// `S⁻¹ ν`.
    pub w: SVector<f32, POINTS>,
    /// Cholesky factor of the (padded) innovation covariance `S`.
    pub chol: nalgebra::Cholesky<f32, nalgebra::Const<POINTS>>,
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
}

impl<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize> Default
    for TemporalFilter<LANES, POINTS, RANK, NX>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize>
    TemporalFilter<LANES, POINTS, RANK, NX>
{
    /// No lanes (`const`, so the filter can live in a `static`).
    pub const fn new() -> Self {
        const { assert!(NX == 2 * LANES * RANK, "NX must be 2·LANES·RANK") };
        const { assert!(RANK >= 1 && RANK <= POINTS, "RANK must be 1..=POINTS") };
        const { assert!(LANES >= 1 && LANES <= 16, "LANES must be 1..=16") };
        Self {
            x: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NX]; 1])),
            p: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NX]; NX])),
            active: [false; LANES],
            rank: [0; LANES],
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

    fn r_used<const NT: usize>(tables: &Tables<NT, LANES, POINTS>) -> usize {
        (tables.gram_rank as usize).min(RANK)
    }

    /// Starts a lane in the free slot `s` with rank `rank` among the lanes after it starts; the
    /// other active lanes' ranks are given in `ranks` (entry `s` is ignored). Its prior is the
    /// conditional of `(B ⊗ Λ_r) ⊗ P∞_t` given the other lanes' states (`Λ = B_{n+1}⁻¹` from the
    /// stored Cholesky factor of B, as in the spatial filter), which keeps `P̄` PSD.
    ///
    /// # Errors
    /// [`TemporalError::BadSlot`] for an active or out-of-range slot, [`TemporalError::BadRanks`]
    /// for ranks that are not a permutation after the start; the state is unchanged.
    ///
    /// Returns the conditioning coefficients `a_t` over the slots (`x_new = Σ_t a_t x_t + w`).
    #[allow(clippy::too_many_lines)]
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
        let others = |t: usize| t != s && self.is_active(t);
        // New rows: x_new[j,c] = Σ_t a_t x[t,j,c]; Cov(new[j,c], y) = Σ_t a_t Cov(x[t,j,c], y).
        let mut newx = self.x;
        let mut newp = self.p;
        for j in 0..RANK {
            for c in 0..2 {
                let row = Self::idx(s, j, c);
                let mut m = 0.0;
                for t in (0..LANES).filter(|&t| others(t)) {
                    m += get(&a, t) * self.xg(Self::idx(t, j, c));
                }
                if let Some(e) = newx.as_mut_slice().get_mut(row) {
                    *e = if j < r { m } else { 0.0 };
                }
                for col in 0..NX {
                    let cs = col / (2 * RANK);
                    let mut cv = 0.0;
                    if j < r && others(cs) {
                        for t in (0..LANES).filter(|&t| others(t)) {
                            cv += get(&a, t) * self.pg(Self::idx(t, j, c), col);
                        }
                    }
                    if let Some(e) = newp.as_mut_slice().get_mut(row + NX * col) {
                        *e = cv;
                    }
                    if let Some(e) = newp.as_mut_slice().get_mut(col + NX * row) {
                        *e = cv;
                    }
                }
            }
        }
        // The new lane's own block: Σ_tt' a_t a_t' Cov(x_t, x_t') + (Λ_r ⊗ P∞_t) / Λ_kk.
        let pinf = &tables.temporal.p_inf;
        for j in 0..r {
            for c in 0..2 {
                for j2 in 0..r {
                    for c2 in 0..2 {
                        let mut cv = 0.0;
                        for t in (0..LANES).filter(|&t| others(t)) {
                            for t2 in (0..LANES).filter(|&t| others(t)) {
                                cv += get(&a, t)
                                    * get(&a, t2)
                                    * self.pg(Self::idx(t, j, c), Self::idx(t2, j2, c2));
                            }
                        }
                        if j == j2 {
                            let lam = tables.gram_eigval.get(j).copied().unwrap_or(0.0);
                            cv += lam * pinf.get((c, c2)).copied().unwrap_or(0.0) / lkk;
                        }
                        if let Some(e) = newp
                            .as_mut_slice()
                            .get_mut(Self::idx(s, j, c) + NX * Self::idx(s, j2, c2))
                        {
                            *e = cv;
                        }
                    }
                }
            }
        }
        if !(newx.iter().all(|v| v.is_finite()) && newp.iter().all(|v| v.is_finite())) {
            (self.active, self.rank) = before;
            return Err(TemporalError::Numerical);
        }
        self.x = newx;
        self.p = newp;
        Ok(a)
    }

    /// Removes the lane in slot `s` (its rows and columns are zeroed); the caller re-ranks the
    /// remaining lanes with [`TemporalFilter::set_ranks`].
    pub fn remove_lane(&mut self, s: usize) {
        if !self.is_active(s) {
            return;
        }
        set(&mut self.active, s, false);
        let lo = Self::idx(s, 0, 0);
        let hi = lo + 2 * RANK;
        for i in lo..hi {
            if let Some(e) = self.x.as_mut_slice().get_mut(i) {
                *e = 0.0;
            }
            for j in 0..NX {
                if let Some(e) = self.p.as_mut_slice().get_mut(i + NX * j) {
                    *e = 0.0;
                }
                if let Some(e) = self.p.as_mut_slice().get_mut(j + NX * i) {
                    *e = 0.0;
                }
            }
        }
    }

    /// Prediction over a frame step `t` seconds (any `t > 0`: dropped frames are exact):
    /// `x ← F̄ x`, `P ← F̄ P F̄ᵀ + (B_π ⊗ Λ_r) ⊗ Q_t(t)` over the active lanes, `B_π` indexed by rank.
    ///
    /// # Errors
    /// [`TemporalError::BadStep`]; the state is unchanged.
    ///
    /// # Complexity
    /// `8·NX²` multiply-adds plus `(2·lanes·r)²` for the noise.
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
        let r = Self::r_used(tables);
        blockdiag_times(&mut self.x, &f);
        // P ← F̄ P F̄ᵀ: column pairs, then row pairs.
        times_blockdiag_t(&mut self.p, &f);
        blockdiag_times(&mut self.p, &f);
        let ps = self.p.as_mut_slice();
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
        Ok(())
    }

    /// Update with lane `s`'s pseudo-measurements: `y = V_r a_s + e`, `e ~ N(0, R + r₀² I)` over the
    /// present index points (`R` the observation's covariance block). Symmetric form, then
    /// symmetrised.
    ///
    /// # Errors
    /// [`TemporalError::BadSlot`], [`TemporalError::NoData`], [`TemporalError::Numerical`]; the
    /// state is unchanged.
    ///
    /// # Complexity
    /// `O(NX·POINTS·(RANK + POINTS) + NX²·POINTS)`.
    #[allow(non_snake_case)]
    pub fn update<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        obs: &LaneObservation<POINTS>,
    ) -> Result<(), TemporalError> {
        let g = self.prepare_update(tables, s, obs)?;
        self.commit_update(&g)
    }

    /// The gain parts of [`TemporalFilter::update`] (shared with the fixed-lag smoother).
    #[allow(non_snake_case)]
    pub(crate) fn prepare_update<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        obs: &LaneObservation<POINTS>,
    ) -> Result<UpdateParts<POINTS, NX>, TemporalError> {
        if !self.is_active(s) {
            return Err(TemporalError::BadSlot);
        }
        let r = Self::r_used(tables);
        let v = &tables.gram_eigvec;
        let vg = |i: usize, j: usize| v.get((i, j)).copied().unwrap_or(0.0);
        let usable = |i: usize| get(&obs.present, i) && obs.z.get(i).is_some_and(|z| z.is_finite());
        if !(0..POINTS).any(usable) {
            return Err(TemporalError::NoData);
        }
        // PH[:, i] = P Hᵀ e_i = Σ_j P[:, a_sj] V[i, j] for present i (zero columns otherwise).
        let mut PH = SMatrix::<f32, NX, POINTS>::zeros();
        for i in (0..POINTS).filter(|&i| usable(i)) {
            for row in 0..NX {
                let mut acc = 0.0;
                for j in 0..r {
                    acc += self.pg(row, Self::idx(s, j, 0)) * vg(i, j);
                }
                if let Some(e) = PH.get_mut((row, i)) {
                    *e = acc;
                }
            }
        }
        let r0 = tables.hyper.pseudo_noise;
        let S = SMatrix::<f32, POINTS, POINTS>::from_fn(|i, k| {
            if usable(i) && usable(k) {
                let mut acc =
                    obs.cov.get((i, k)).copied().unwrap_or(0.0) + if i == k { r0 } else { 0.0 };
                for j in 0..r {
                    acc += vg(i, j) * PH.get((Self::idx(s, j, 0), k)).copied().unwrap_or(0.0);
                }
                acc
            } else if i == k {
                1.0
            } else {
                0.0
            }
        });
        let S = (S + S.transpose()) * 0.5;
        let chol = S.cholesky().ok_or(TemporalError::Numerical)?;
        let nu = SVector::<f32, POINTS>::from_fn(|i, _| {
            if usable(i) {
                let mut pred = 0.0;
                for j in 0..r {
                    pred += vg(i, j) * self.xg(Self::idx(s, j, 0));
                }
                obs.z.get(i).copied().unwrap_or(0.0) - pred
            } else {
                0.0
            }
        });
        let w = chol.solve(&nu);
        let kt = chol.solve(&PH.transpose()); // S⁻¹ PHᵀ = S⁻¹ H P (POINTS × NX)
        let mut used = [false; POINTS];
        for (i, u) in used.iter_mut().enumerate() {
            *u = usable(i);
        }
        Ok(UpdateParts {
            slot: s,
            rank_used: r,
            used,
            ph: PH,
            kt,
            w,
            chol,
        })
    }

    /// Applies prepared gain parts: `x += PH w`, `P −= PH S⁻¹ PHᵀ`, symmetrised; the state is kept
    /// when the result is not finite.
    pub(crate) fn commit_update(
        &mut self,
        g: &UpdateParts<POINTS, NX>,
    ) -> Result<(), TemporalError> {
        let newx = self.x + g.ph * g.w;
        let newp = self.p - g.ph * g.kt;
        let newp = (newp + newp.transpose()) * 0.5;
        if !(newx.iter().all(|v| v.is_finite()) && newp.iter().all(|v| v.is_finite())) {
            return Err(TemporalError::Numerical);
        }
        self.x = newx;
        self.p = newp;
        Ok(())
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
        let v = &tables.gram_eigvec;
        let vg = |i: usize, j: usize| v.get((i, j)).copied().unwrap_or(0.0);
        let mean = SVector::<f32, POINTS>::from_fn(|i, _| {
            (0..r).map(|j| vg(i, j) * self.xg(Self::idx(s, j, 0))).sum()
        });
        let var = SVector::<f32, POINTS>::from_fn(|i, _| {
            let mut acc = 0.0;
            for j in 0..r {
                for j2 in 0..r {
                    acc += vg(i, j) * vg(i, j2) * self.pg(Self::idx(s, j, 0), Self::idx(s, j2, 0));
                }
            }
            acc
        });
        Some((mean, var))
    }

    /// `cᵀ Cov(a_s) c` over the first `r` position coefficients of slot `s` (0 for a free slot).
    pub fn coefficient_var(&self, s: usize, c: &[f32; POINTS], r: usize) -> f32 {
        if !self.is_active(s) {
            return 0.0;
        }
        let mut acc = 0.0;
        for j in 0..r.min(RANK) {
            for j2 in 0..r.min(RANK) {
                acc += get(c, j) * get(c, j2) * self.pg(Self::idx(s, j, 0), Self::idx(s, j2, 0));
            }
        }
        acc
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
}

/// `M ← M (I ⊗ f)ᵀ`: each pair of columns `(2b, 2b + 1)` mixed by `f` (the transition of every
/// `[position, rate]` block acting from the right).
pub(crate) fn times_blockdiag_t<const R: usize, const C: usize>(
    m: &mut SMatrix<f32, R, C>,
    f: &Matrix2<f32>,
) {
    let (f00, f01, f10, f11) = (f.m11, f.m12, f.m21, f.m22);
    let ms = m.as_mut_slice(); // column-major: (i, j) at i + R j
    for i in 0..R {
        for b in 0..C / 2 {
            let (c0, c1) = (i + R * (2 * b), i + R * (2 * b + 1));
            let (a, bv) = (
                ms.get(c0).copied().unwrap_or(0.0),
                ms.get(c1).copied().unwrap_or(0.0),
            );
            if let Some(e) = ms.get_mut(c0) {
                *e = f00 * a + f01 * bv;
            }
            if let Some(e) = ms.get_mut(c1) {
                *e = f10 * a + f11 * bv;
            }
        }
    }
}

/// `M ← (I ⊗ f) M`: each pair of rows `(2b, 2b + 1)` mixed by `f`.
pub(crate) fn blockdiag_times<const R: usize, const C: usize>(
    m: &mut SMatrix<f32, R, C>,
    f: &Matrix2<f32>,
) {
    let (f00, f01, f10, f11) = (f.m11, f.m12, f.m21, f.m22);
    let ms = m.as_mut_slice();
    for j in 0..C {
        for b in 0..R / 2 {
            let (r0, r1) = (2 * b + R * j, 2 * b + 1 + R * j);
            let (a, bv) = (
                ms.get(r0).copied().unwrap_or(0.0),
                ms.get(r1).copied().unwrap_or(0.0),
            );
            if let Some(e) = ms.get_mut(r0) {
                *e = f00 * a + f01 * bv;
            }
            if let Some(e) = ms.get_mut(r1) {
                *e = f10 * a + f11 * bv;
            }
        }
    }
}
