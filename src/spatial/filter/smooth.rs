//! The backward pass of the spatial filter: per confirmed track, an RTS smoother along `u` and
//! the pseudo-measurements at the index points (docs/design.md §4.1 step 7), made positive
//! definite at output (finding F1).

use super::*;
use crate::linalg::{cm_at, cm_set};

impl<const NS: usize, const LANES: usize, const ROWS: usize, const PER_ROW: usize>
    SpatialFilter<NS, LANES, ROWS, PER_ROW>
{
    /// §4: backward RTS pass per confirmed track and pseudo-measurements at the index points.
    ///
    /// Per row one `NS×NS` `LDLᵀ` solve for the gain `G_r = P_{r|r} Fᵀ P_{r+1|r}⁻¹`. The
    /// cross-covariances with the index points already passed are only needed through `h`, so
    /// each is kept as the vector `Cov(x_r, x_b) h` and the gains of an index interval are
    /// composed once (`Γ = G_r Γ`) and applied to those vectors at the next index row:
    /// `O(NS³)` per row plus `O(NS²)` per (index point, index interval).
    #[allow(non_snake_case, clippy::too_many_arguments)]
    #[inline(never)]
    pub(super) fn smooth<const NT: usize, const POINTS: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        F: &SMatrix<f32, NS, NS>,
        hv: &SVector<f32, NS>,
        k_rows: usize,
        du: f32,
        out: &mut [LaneObservation<POINTS>; LANES],
        rep: &mut SpatialReport,
    ) -> usize {
        // The callers pass `k_rows ≥ 1`; the guard lets every build prove `r % k_rows` cannot
        // divide by zero (`smooth` is not inlined: the C API's staticlib kept that panic path).
        let k_rows = k_rows.max(1);
        let f = F.data.0;
        let [h] = hv.data.0;
        let mut n_out = 0usize;
        for (rank, mt) in self.meta.iter().enumerate().take(self.state.len()) {
            if mt.status == Status::Tentative || mt.first_row == NO_ROW {
                continue;
            }
            let Some(hist) = self.hist.get(usize::from(mt.store)) else {
                continue;
            };
            let (a, b) = (usize::from(mt.start_row), usize::from(mt.last_rec));
            let (first, last) = (usize::from(mt.first_row), usize::from(mt.last_row));
            let mut obs = LaneObservation {
                status: mt.status,
                present: [false; POINTS],
                z: SVector::zeros(),
                cov: SMatrix::zeros(),
                u_first: tables.hyper.u_min + du * f32::from(mt.first_row),
                u_last: tables.hyper.u_min + du * f32::from(mt.last_row),
                existence: f32::from(mt.hits) / f32::from(mt.hits.saturating_add(mt.misses).max(1)),
                rank: rank as u8,
                llr: mt.llr_last,
            };
            let mut reg = Registered::<NS, POINTS>::new();
            let mut xs = [0.0f32; NS];
            let mut ps = [[0.0f32; NS]; NS];
            let mut ok = true;
            for r in (a..=b).rev() {
                let Some(rec) = hist.get(r) else { continue };
                let [xf] = rec.xf.data.0;
                let pf = rec.pf.data.0;
                if r == b {
                    xs = xf;
                    ps = pf;
                } else {
                    let Some(next) = hist.get(r + 1) else {
                        continue;
                    };
                    let Some(g) = rts_step(&mut xs, &mut ps, xf, pf, next, &f) else {
                        ok = false;
                        break;
                    };
                    reg.step_back(&g);
                }
                if r % k_rows == 0 {
                    let i = r / k_rows;
                    let inside = r >= first && r <= last;
                    if i < POINTS && i < 64 && inside {
                        reg.add(i, h, (&xs, &ps), &mut obs);
                    }
                }
            }
            // NaN-propagating sum: 0 exactly when every entry is finite.
            let probe = obs.z.iter().fold(0.0f32, |acc, v| acc + v * 0.0)
                + obs.cov.iter().fold(0.0f32, |acc, v| acc + v * 0.0);
            let finite = probe == 0.0;
            if !(ok && finite) {
                rep.smoother_failed += 1;
                continue;
            }
            if repair_psd(&mut obs) {
                rep.cov_repaired += 1;
            }
            if let Some(o) = out.get_mut(n_out) {
                *o = obs;
                n_out += 1;
            }
        }
        n_out
    }
}

/// The index points a track's backward pass has registered: `v[i] = Cov(x_{r'}, x_{iK}) h` for
/// the registered points, at the last index row `r'` passed, and `gam = G_r ⋯ G_{r'−1}` since
/// then when the gains are composed (composing costs `NS³` per row, propagating `NS²` per
/// vector: composition pays once `NS` points are registered).
struct Registered<const NS: usize, const POINTS: usize> {
    v: [[f32; NS]; POINTS],
    registered: u64,
    gam: [[f32; NS]; NS],
    compose: bool,
}

impl<const NS: usize, const POINTS: usize> Registered<NS, POINTS> {
    fn new() -> Self {
        Self {
            v: [[0.0; NS]; POINTS],
            registered: 0,
            gam: ident::<NS>(),
            compose: false,
        }
    }

    /// One row back with the RTS gain `g`.
    fn step_back(&mut self, g: &[[f32; NS]; NS]) {
        if self.compose {
            self.gam = mat_mul(g, &self.gam);
        } else {
            let mut m = self.registered;
            while m != 0 {
                if let Some(vj) = self.v.get_mut(m.trailing_zeros() as usize) {
                    *vj = mat_vec(g, vj);
                }
                m &= m - 1;
            }
        }
    }

    /// At index point `i`'s row (smoothed moments `xs`, `ps`): brings the registered vectors to
    /// this row, writes their covariances with point `i` and point `i`'s mean and variance into
    /// `obs`, and registers `i`.
    fn add<const NT1: usize>(
        &mut self,
        i: usize,
        h: [f32; NS],
        (xs, ps): (&[f32; NS], &[[f32; NS]; NS]),
        obs: &mut LaneObservation<NT1>,
    ) {
        for (j, vj) in self.v.iter_mut().enumerate() {
            if self.registered & (1 << j) != 0 {
                if self.compose {
                    *vj = mat_vec(&self.gam, vj);
                }
                let e = dot(&h, vj);
                if let Some(c) = obs.cov.get_mut((i, j)) {
                    *c = e;
                }
                if let Some(c) = obs.cov.get_mut((j, i)) {
                    *c = e;
                }
            }
        }
        self.gam = ident::<NS>();
        self.compose = (self.registered | 1 << i).count_ones() as usize >= NS;
        let vi = mat_vec(ps, &h);
        if let Some(c) = obs.cov.get_mut((i, i)) {
            *c = dot(&h, &vi);
        }
        set(&mut self.v, i, vi);
        self.registered |= 1 << i;
        set(&mut obs.present, i, true);
        if let Some(z) = obs.z.get_mut(i) {
            *z = dot(&h, xs);
        }
    }
}

/// One backward RTS step along `u`, from row `r + 1` (its predicted moments in `next`) to row
/// `r` (filtered moments `xf`, `pf`): `xs ← x_f + G (xs − x_p)`, `ps ← P_f + G (ps − P_p) Gᵀ`
/// with `Gᵀ = P_{r+1|r}⁻¹ F P_{r|r}`. Returns `G`, or `None` when `P_{r+1|r}` is not positive
/// definite.
#[inline(always)]
fn rts_step<const NS: usize>(
    xs: &mut [f32; NS],
    ps: &mut [[f32; NS]; NS],
    xf: [f32; NS],
    pf: [[f32; NS]; NS],
    next: &Rec<NS>,
    f: &[[f32; NS]; NS],
) -> Option<[[f32; NS]; NS]> {
    // Gᵀ = P_{r+1|r}⁻¹ F P_{r|r}.
    let gt = spd_solve(&next.pp.data.0, &mat_mul(f, &pf))?;
    let g = transpose(&gt);
    let [xp] = next.xp.data.0;
    // xs ← x_f + G (xs − x_p);  ps ← P_f + G (ps − P_p) Gᵀ (symmetric).
    let mut dxs = *xs;
    for (d, p) in dxs.iter_mut().zip(xp.iter()) {
        *d -= p;
    }
    let gd = mat_vec(&g, &dxs);
    for ((x, f0), d) in xs.iter_mut().zip(xf.iter()).zip(gd.iter()) {
        *x = f0 + d;
    }
    let mut dp = *ps;
    for (dc, pc) in dp.iter_mut().zip(next.pp.data.0.iter()) {
        for (dv, pv) in dc.iter_mut().zip(pc.iter()) {
            *dv -= pv;
        }
    }
    let t = mat_mul(&g, &dp);
    *ps = pf;
    for c in 0..NS {
        for rr in 0..=c {
            // (T Gᵀ)[rr][c] = Σ_k T[rr][k] G[c][k]
            let mut acc = 0.0f32;
            for k in 0..NS {
                acc += cm_at(&t, rr, k) * cm_at(&g, c, k);
            }
            let s = 0.5 * (cm_at(ps, rr, c) + cm_at(ps, c, rr)) + acc;
            cm_set(ps, rr, c, s);
            cm_set(ps, c, rr, s);
        }
    }
    Some(g)
}

/// The `N×N` identity (column-major).
#[inline(always)]
fn ident<const N: usize>() -> [[f32; N]; N] {
    let mut m = [[0.0f32; N]; N];
    for (c, col) in m.iter_mut().enumerate() {
        set(col, c, 1.0);
    }
    m
}

/// `M v` (column-major `M`).
#[inline(always)]
fn mat_vec<const N: usize>(m: &[[f32; N]; N], v: &[f32; N]) -> [f32; N] {
    let mut out = [0.0f32; N];
    for (col, vc) in m.iter().zip(v.iter()) {
        for (o, e) in out.iter_mut().zip(col.iter()) {
            *o += e * vc;
        }
    }
    out
}

/// `A B` (column-major): column `c` of the product is `A` times column `c` of `B`.
#[inline(always)]
fn mat_mul<const N: usize>(a: &[[f32; N]; N], b: &[[f32; N]; N]) -> [[f32; N]; N] {
    let mut out = [[0.0f32; N]; N];
    for (oc, bc) in out.iter_mut().zip(b.iter()) {
        *oc = mat_vec(a, bc);
    }
    out
}

/// `Mᵀ` (column-major).
#[inline(always)]
fn transpose<const N: usize>(m: &[[f32; N]; N]) -> [[f32; N]; N] {
    let mut out = [[0.0f32; N]; N];
    for (c, col) in m.iter().enumerate() {
        for (r, v) in col.iter().enumerate() {
            cm_set(&mut out, c, r, *v);
        }
    }
    out
}

/// Solves `A X = B` for a symmetric positive definite `A` (column-major `N×N` arrays) by
/// `A = L D Lᵀ`; `None` when a pivot is not positive and finite (`A` not positive definite).
///
/// # Complexity
/// `N³/6` for the factor and `N³` for the `N` right-hand sides; no square root.
#[inline(always)]
fn spd_solve<const N: usize>(a: &[[f32; N]; N], b: &[[f32; N]; N]) -> Option<[[f32; N]; N]> {
    let mut l = [[0.0f32; N]; N]; // l[c][r] = L_rc, unit diagonal implied
    let mut d = [0.0f32; N];
    let mut invd = [0.0f32; N];
    for j in 0..N {
        let mut dj = cm_at(a, j, j);
        for k in 0..j {
            let ljk = cm_at(&l, j, k);
            dj -= ljk * ljk * get(&d, k);
        }
        if !(dj.is_finite() && dj > 0.0) {
            return None;
        }
        let ij = 1.0 / dj;
        set(&mut d, j, dj);
        set(&mut invd, j, ij);
        for i in j + 1..N {
            // L_ij d_j = A_ij − Σ_{k<j} L_ik L_jk d_k
            let mut s = cm_at(a, i, j);
            for k in 0..j {
                s -= cm_at(&l, i, k) * cm_at(&l, j, k) * get(&d, k);
            }
            cm_set(&mut l, i, j, s * ij);
        }
    }
    let mut x = *b;
    for col in x.iter_mut() {
        for i in 0..N {
            let mut s = get(col, i);
            for k in 0..i {
                s -= cm_at(&l, i, k) * get(col, k);
            }
            set(col, i, s);
        }
        for (v, id) in col.iter_mut().zip(invd.iter()) {
            *v *= id;
        }
        for i in (0..N).rev() {
            let mut s = get(col, i);
            for k in i + 1..N {
                s -= cm_at(&l, k, i) * get(col, k);
            }
            set(col, i, s);
        }
    }
    Some(x)
}

/// Makes a lane's pseudo-measurement covariance positive definite over its present points
/// (`docs/spatial-filter.md` §4): a modified Cholesky in index order raises every pivot below
/// `1e-6 ×` the largest present variance to `max(|d|, that floor)` and adds the difference to
/// that point's variance. A positive definite block is left as it is. Returns whether anything
/// was added. `O(m³/6)` for `m` present points.
fn repair_psd<const POINTS: usize>(obs: &mut LaneObservation<POINTS>) -> bool {
    let mut idx = [0u8; POINTS];
    let mut m = 0usize;
    for (i, &p) in obs.present.iter().enumerate() {
        if p {
            set(&mut idx, m, i as u8);
            m += 1;
        }
    }
    let at = |a: usize| usize::from(get(&idx, a));
    let mut c = SMatrix::<f32, POINTS, POINTS>::zeros();
    let mut top = 0.0f32;
    for b in 0..m {
        for a in b..m {
            let v = 0.5
                * (obs.cov.get((at(a), at(b))).copied().unwrap_or(0.0)
                    + obs.cov.get((at(b), at(a))).copied().unwrap_or(0.0));
            if let Some(e) = c.get_mut((a, b)) {
                *e = v;
            }
            if a == b {
                top = top.max(v.abs());
            }
        }
    }
    let floor = 1e-6 * top;
    if !(floor.is_finite() && floor > 0.0) {
        return false;
    }
    let mut load = [0.0f32; POINTS];
    let raised = crate::linalg::cholesky_loaded(&mut c, m, floor, floor, &mut load);
    if raised == 0 || raised == u8::MAX {
        return false;
    }
    for (a, l) in load.iter().enumerate().take(m) {
        if let Some(e) = obs.cov.get_mut((at(a), at(a))) {
            *e += l;
        }
    }
    true
}
