//! The lane update of the temporal filter (docs/design.md §4.2): the gain parts from a lane's
//! pseudo-measurements (shared with the fixed-lag smoother), their check, and the rank-r
//! covariance update in place; and the small kernels the update and the smoother share.

use super::*;

impl<const LANES: usize, const POINTS: usize, const RANK: usize, const NX: usize>
    TemporalFilter<LANES, POINTS, RANK, NX>
{
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
            nis: g.nis,
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
        let r0 = tables.hyper.pseudo_noise;
        let mut l = SMatrix::<f32, POINTS, POINTS>::zeros();
        let repaired = innovation_factor(&obs.cov, &t, &us, m, r, r0, &vg, &mut l)?;
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
        self.write_parts(parts, (s, r), M, w, (repaired, 0.0))
    }

    /// Writes lane `s`'s gain parts over its first `r` components: `M` and `w` (both checked
    /// finite: [`TemporalError::Numerical`] otherwise, `parts` then holds nothing meaningful),
    /// `G = P[:, a_s]` (only the active rows are non-zero; row-major, written in place: the
    /// parts are 2.6 KiB, no copy on the stack), the repaired pivots and the NIS.
    #[inline(always)]
    fn write_parts(
        &self,
        parts: &mut UpdateParts<RANK, NX>,
        (s, r): (usize, usize),
        m: SMatrix<f32, RANK, RANK>,
        w: SVector<f32, RANK>,
        (repaired, nis): (u8, f32),
    ) -> Result<(), TemporalError> {
        if !(m.iter().chain(w.iter()).all(|v| v.is_finite())) {
            return Err(TemporalError::Numerical);
        }
        let a0 = Self::idx(s, 0, 0);
        for (i, row) in parts.g.iter_mut().enumerate() {
            for (k, e) in row.iter_mut().enumerate() {
                *e = if k < r { self.pg(i, a0 + 2 * k) } else { 0.0 };
            }
        }
        parts.slot = s;
        parts.r = r;
        parts.m = m;
        parts.w = w;
        parts.repaired = repaired;
        parts.nis = nis;
        Ok(())
    }

    /// The gain parts of an update of lane `s` by **row evidence in information form**
    /// (docs/design.md §11.3): measurements `z̃_r = c_rᵀ a_s + e_r`, independent, with
    /// `J = Σ_r ω_r c_r c_rᵀ` and `i = Σ_r ω_r z̃_r c_r` (`ω_r` the inverse noise variances;
    /// `jm`, `iv` on the first `r` components). With `P_a = Cov(a_s) = L Lᵀ`,
    /// `A = I + Lᵀ J L = L_A L_Aᵀ`, `K = J L`, `Y = L_A⁻¹ Kᵀ`:
    /// `M = Hᵀ S⁻¹ H = J − Yᵀ Y` and `w = Hᵀ S⁻¹ ν = b − Yᵀ L_A⁻¹ Lᵀ b`, `b = i − J a_s`
    /// (Woodbury; `A ⪰ I` is always well conditioned). A pivot of `P_a` below `1e-9 × max P_a`
    /// is raised to that floor (rounding only; `P_a` is a covariance).
    ///
    /// # Errors
    /// [`TemporalError::BadSlot`], [`TemporalError::NoData`] (`J` zero or not finite),
    /// [`TemporalError::Numerical`]; `parts` then holds nothing meaningful.
    ///
    /// # Complexity
    /// `O(r³)` (three `r×r` factorisations and products) plus `G` (`n_act·r`).
    #[inline(never)]
    pub(crate) fn prepare_info_update<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        jm: &SMatrix<f32, RANK, RANK>,
        iv: &SVector<f32, RANK>,
        parts: &mut UpdateParts<RANK, NX>,
    ) -> Result<(), TemporalError> {
        if !self.is_active(s) {
            return Err(TemporalError::BadSlot);
        }
        let r = Self::r_used(tables);
        // The same code with `r` a constant where it is the capacity (a tracker compiled at its
        // model's rank): fixed trip counts, the same operations in the same order.
        if r >= RANK {
            self.prepare_info_update_r(RANK, s, jm, iv, parts)
        } else {
            self.prepare_info_update_r(r, s, jm, iv, parts)
        }
    }

    /// [`Self::prepare_info_update`] over the first `r` components.
    #[allow(non_snake_case)]
    #[inline(always)]
    fn prepare_info_update_r(
        &self,
        r: usize,
        s: usize,
        jm: &SMatrix<f32, RANK, RANK>,
        iv: &SVector<f32, RANK>,
        parts: &mut UpdateParts<RANK, NX>,
    ) -> Result<(), TemporalError> {
        let jr = |j: usize, k: usize| {
            if j < r && k < r {
                jm.get((j, k)).copied().unwrap_or(0.0)
            } else {
                0.0
            }
        };
        let jmax = (0..r).map(|j| jr(j, j)).fold(0.0f32, f32::max);
        if !(jmax.is_finite() && jmax > 0.0) {
            return Err(TemporalError::NoData);
        }
        let a0 = Self::idx(s, 0, 0);
        let mut L = SMatrix::<f32, RANK, RANK>::from_fn(|j, k| {
            if j < r && k < r {
                self.pg(a0 + 2 * j, a0 + 2 * k)
            } else {
                0.0
            }
        });
        let pmax = (0..r)
            .map(|j| L.get((j, j)).copied().unwrap_or(0.0))
            .fold(0.0f32, f32::max);
        let floor = 1e-9 * pmax;
        let mut load = [0.0f32; RANK];
        if !(pmax.is_finite() && pmax > 0.0)
            || linalg::cholesky_loaded(&mut L, r, floor, floor, &mut load) == u8::MAX
        {
            return Err(TemporalError::Numerical);
        }
        let l = |j: usize, k: usize| {
            if k <= j {
                L.get((j, k)).copied().unwrap_or(0.0)
            } else {
                0.0
            }
        };
        // K = J L (r×r).
        let K =
            SMatrix::<f32, RANK, RANK>::from_fn(|j, k| (0..r).map(|q| jr(j, q) * l(q, k)).sum());
        // A = I + Lᵀ K, factored.
        let mut A = SMatrix::<f32, RANK, RANK>::from_fn(|j, k| {
            if j < r && k < r {
                let v: f32 = (0..r)
                    .map(|q| l(q, j) * K.get((q, k)).copied().unwrap_or(0.0))
                    .sum();
                v + if j == k { 1.0 } else { 0.0 }
            } else {
                0.0
            }
        });
        let Some(Y) = factor_and_solve(&mut A, &K, r) else {
            return Err(TemporalError::Numerical);
        };
        // b = i − J a, t = L_A⁻¹ Lᵀ b.
        let a: [f32; RANK] =
            core::array::from_fn(|j| if j < r { self.xg(a0 + 2 * j) } else { 0.0 });
        let b: [f32; RANK] = core::array::from_fn(|j| {
            if j < r {
                iv.get(j).copied().unwrap_or(0.0)
                    - (0..r).map(|q| jr(j, q) * get(&a, q)).sum::<f32>()
            } else {
                0.0
            }
        });
        let mut t = [0.0f32; RANK];
        for (j, tv) in t.iter_mut().enumerate().take(r) {
            *tv = (0..r).map(|q| l(q, j) * get(&b, q)).sum();
        }
        if let Some(ts) = t.get_mut(..r) {
            forward_subst(&A, ts);
        }
        let mut M = SMatrix::<f32, RANK, RANK>::zeros();
        let mut w = SVector::<f32, RANK>::zeros();
        let y = |q: usize, j: usize| Y.get((q, j)).copied().unwrap_or(0.0);
        for j in 0..r {
            if let Some(e) = w.get_mut(j) {
                *e = get(&b, j) - (0..r).map(|q| y(q, j) * get(&t, q)).sum::<f32>();
            }
            for k in j..r {
                let v = jr(j, k) - (0..r).map(|q| y(q, j) * y(q, k)).sum::<f32>();
                if let Some(e) = M.get_mut((j, k)) {
                    *e = v;
                }
                if let Some(e) = M.get_mut((k, j)) {
                    *e = v;
                }
            }
        }
        let nis = normalised_innovation(&M, &w, r);
        self.write_parts(parts, (s, r), M, w, (0, nis))
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
        let sp = self.update_spans(g.slot, g.r);
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
        // Uncoupled, G is exactly zero outside the lane's own block (`update_spans`).
        let sp = self.update_spans(g.slot, g.r);
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
}

/// The lower Cholesky factor `L` (into `l`, leading `m×m` block) of the innovation covariance
/// `S = T V_mᵀ + R̃ + diag(e)` of a lane update on the used index points `us[..m]`, with `R̃` the
/// symmetrised pseudo-measurement covariance plus `r₀² I`, repaired where it is not PSD
/// (`e ≥ 0`, see [`TemporalFilter::update`]). Returns the number of raised pivots.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn innovation_factor<const POINTS: usize, const RANK: usize>(
    cov: &SMatrix<f32, POINTS, POINTS>,
    t: &SMatrix<f32, POINTS, RANK>,
    us: &[u8; POINTS],
    m: usize,
    r: usize,
    r0: f32,
    vg: &impl Fn(usize, usize) -> f32,
    l: &mut SMatrix<f32, POINTS, POINTS>,
) -> Result<u8, TemporalError> {
    let u = |a: usize| usize::from(get(us, a));
    // R̃ = sym(R) + r₀² I on the used points (lower triangle). With R PSD every pivot of its
    // Cholesky factorisation is ≥ r₀²; a pivot below r₀²/2 means R is not PSD (the spatial
    // pseudo-measurement covariance can be slightly indefinite: moment-matched mixtures make
    // the per-lane RTS cross-covariances inconsistent). Such pivots are raised to r₀² (a
    // modified Cholesky: R̃ + diag(e), e ≥ 0), so the noise used is PSD and the posterior
    // stays PSD; they are counted.
    for b in 0..m {
        for a in b..m {
            let acc = cov.get((u(a), u(b))).copied().unwrap_or(0.0);
            let acc2 = cov.get((u(b), u(a))).copied().unwrap_or(0.0);
            if let Some(e) = l.get_mut((a, b)) {
                *e = 0.5 * (acc + acc2) + if a == b { r0 } else { 0.0 };
            }
        }
    }
    let mut rt = *l;
    let mut load = [0.0f32; POINTS];
    let repaired = linalg::cholesky_loaded(&mut rt, m, 0.5 * r0, r0, &mut load);
    if repaired == u8::MAX {
        return Err(TemporalError::Numerical);
    }
    // S = T V_mᵀ + R̃ + diag(e) on the leading m×m block (lower triangle, then factored).
    for b in 0..m {
        for a in b..m {
            let mut acc =
                l.get((a, b)).copied().unwrap_or(0.0) + if a == b { get(&load, a) } else { 0.0 };
            for k in 0..r {
                acc += t.get((a, k)).copied().unwrap_or(0.0) * vg(u(b), k);
            }
            if let Some(e) = l.get_mut((a, b)) {
                *e = acc;
            }
        }
    }
    if !cholesky_lower(l, m) {
        return Err(TemporalError::Numerical);
    }
    Ok(repaired)
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

/// [`dot`] over the first `n` entries.
#[inline(always)]
fn dot_first<const R: usize>(a: &[f32; R], b: &[f32; R], n: usize) -> f32 {
    let mut acc = 0.0;
    for (x, y) in a.iter().zip(b).take(n) {
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
        let s: f32 = vi.iter().zip(&sd).map(|(v, d)| v.abs() * d).sum();
        // Both branches give the same bits; the fixed-length sums are faster at full rank (the
        // coupled default: the truncated loops ran it 0.2 % slower on the M4F).
        if r >= RANK {
            *m = dot(&vi, a);
            let pv: [f32; RANK] =
                core::array::from_fn(|j| p.get(j).map_or(0.0, |row| dot(row, &vi)));
            *w = math::max(dot(&pv, &vi), tol * s * s);
        } else {
            // The sums stop at `r`: beyond it `vi` is zero and both callers zero `a` and `P`, so
            // the terms they would add after the first `r` are ±0 and change no bit of a sum
            // that starts at +0 (it is never −0).
            *m = dot_first(&vi, a, r);
            let pv: [f32; RANK] = core::array::from_fn(|j| {
                if j < r {
                    p.get(j).map_or(0.0, |row| dot_first(row, &vi, r))
                } else {
                    0.0
                }
            });
            *w = math::max(dot_first(&pv, &vi, r), tol * s * s);
        }
    }
    (mean, var)
}

/// Symmetrises the leading `r×r` block of `a` (rounding), factors it in place (`a = L_A L_Aᵀ`)
/// and returns `Y = L_A⁻¹ Kᵀ` (column `k` of `Y` solves `L_A y = (row k of K)ᵀ`); `None` when
/// `a` is not positive definite.
#[allow(non_snake_case)]
fn factor_and_solve<const RANK: usize>(
    a: &mut SMatrix<f32, RANK, RANK>,
    K: &SMatrix<f32, RANK, RANK>,
    r: usize,
) -> Option<SMatrix<f32, RANK, RANK>> {
    for j in 0..r {
        for k in 0..j {
            let v = 0.5
                * (a.get((j, k)).copied().unwrap_or(0.0) + a.get((k, j)).copied().unwrap_or(0.0));
            if let Some(e) = a.get_mut((j, k)) {
                *e = v;
            }
        }
    }
    if !cholesky_lower(a, r) {
        return None;
    }
    let mut Y = SMatrix::<f32, RANK, RANK>::zeros();
    for k in 0..r {
        let mut col = [0.0f32; RANK];
        for (q, c) in col.iter_mut().enumerate().take(r) {
            *c = K.get((k, q)).copied().unwrap_or(0.0);
        }
        if let Some(cs) = col.get_mut(..r) {
            forward_subst(a, cs);
        }
        for (q, c) in col.iter().enumerate().take(r) {
            if let Some(e) = Y.get_mut((q, k)) {
                *e = *c;
            }
        }
    }
    Some(Y)
}

/// `wᵀ M⁻¹ w` on the leading `r` components by a loaded Cholesky of `M` (directions the rows
/// barely inform are floored at `1e-6 × max M_jj`); 0 when `M` has no positive diagonal.
fn normalised_innovation<const RANK: usize>(
    m: &SMatrix<f32, RANK, RANK>,
    w: &SVector<f32, RANK>,
    r: usize,
) -> f32 {
    let mmax = (0..r)
        .map(|j| m.get((j, j)).copied().unwrap_or(0.0))
        .fold(0.0f32, f32::max);
    let mut mf = *m;
    let mut mload = [0.0f32; RANK];
    let mfloor = 1e-6 * mmax;
    if mmax > 0.0 && linalg::cholesky_loaded(&mut mf, r, mfloor, mfloor, &mut mload) != u8::MAX {
        let mut z: [f32; RANK] = core::array::from_fn(|j| w.get(j).copied().unwrap_or(0.0));
        if let Some(zs) = z.get_mut(..r) {
            forward_subst(&mf, zs);
        }
        z.iter().take(r).map(|v| v * v).sum()
    } else {
        0.0
    }
}
