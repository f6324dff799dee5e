//! The row step's state update (docs/design.md §4.1 step 4): the gains `G` on the eligible tracks
//! and the moment-matched mixture applied to the stacked state, with the small kernels they use.

use nalgebra::SMatrix;

use super::super::{Blocks, Means};
use crate::linalg::{dot, get, set};

/// The eligible tracks (not masked, at least one candidate) in increasing order, `G` restricted
/// to their columns, `g[i][s] = P_{i,e_s} h`, and `S̄` among them (symmetric: the upper triangle,
/// mirrored into `sbar`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn eligible_gains<const NS: usize, const LANES: usize>(
    valid: &[u32; LANES],
    skip: u32,
    ps: &Blocks<NS, LANES>,
    n: usize,
    hv: [f32; NS],
    sbar: &mut [[f32; LANES]; LANES],
    elig: &mut [u8; LANES],
    g: &mut [[[f32; NS]; LANES]; LANES],
) -> usize {
    let mut na = 0usize;
    for (t, v) in valid.iter().enumerate().take(n) {
        if skip & (1 << t) == 0 && *v != 0 {
            set(elig, na, t as u8);
            na += 1;
        }
    }
    let el = elig.get(..na).unwrap_or(&[]);
    if na > 0 {
        for (gi, prow) in g.iter_mut().zip(ps.iter()).take(n) {
            for (gs, &ts) in gi.iter_mut().zip(el.iter()) {
                if let Some(p) = prow.get(usize::from(ts)) {
                    *gs = mat_vec(p, &hv);
                }
            }
        }
    }
    for (s1, &t1) in el.iter().enumerate() {
        let g1 = g
            .get(usize::from(t1))
            .copied()
            .unwrap_or([[0.0; NS]; LANES]);
        for (&t2, g12) in el.iter().zip(g1.iter()).skip(s1 + 1) {
            let v = dot(&hv, g12);
            put(sbar, usize::from(t1), usize::from(t2), v);
            put(sbar, usize::from(t2), usize::from(t1), v);
        }
    }
    na
}

/// The state update with the mixture sums (step 4): `C' = C/w + y yᵀ` compacted to the eligible
/// tracks `el`, `P⁺ = P̄ − G_e C'_e G_eᵀ`, `x⁺ = x̄ + G_e y_e`. `false`, with the state untouched,
/// when a correction could overflow.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn apply_mixture<const NS: usize, const LANES: usize>(
    xs: &mut Means<NS, LANES>,
    ps: &mut Blocks<NS, LANES>,
    n: usize,
    el: &[u8],
    g: &[[[f32; NS]; LANES]; LANES],
    y: &[f32; LANES],
    c: &[[f32; LANES]; LANES],
    inv: f32,
) -> bool {
    let na = el.len();
    // Only the eligible tracks (those in some detection pattern) have rows in y and C, so
    // C' = C + y yᵀ is compacted to them: P⁺ = P̄ − G_e C'_e G_eᵀ, x⁺ = x̄ + G_e y_e. With none
    // (every track missed for sure), the state does not move.
    let mut ye = [0.0f32; LANES];
    for (ys, &ts) in ye.iter_mut().zip(el.iter()) {
        *ys = get(y, usize::from(ts)) * inv;
    }
    let mut ce = [[0.0f32; LANES]; LANES];
    for (s1, &t1) in el.iter().enumerate() {
        let y1 = get(&ye, s1);
        for (s2, &t2) in el.iter().enumerate().take(s1 + 1) {
            let v = at(c, usize::from(t1), usize::from(t2)) * inv + y1 * get(&ye, s2);
            put(&mut ce, s1, s2, v);
            put(&mut ce, s2, s1, v);
        }
    }
    let gn = g.get(..if na > 0 { n } else { 0 }).unwrap_or(&[]);
    let yn = ye.get(..na).unwrap_or(&[]);
    let cn = ce.get(..na).unwrap_or(&[]);
    // u[i][s'] = Σ_s g[i][s] C'[s][s'], dx[i] = Σ_s g[i][s] y[s].
    let mut dx = [[0.0f32; NS]; LANES];
    let mut u = [[[0.0f32; NS]; LANES]; LANES];
    // (Sums go to locals, not through references into the arrays, so they stay in registers.)
    for ((gi, d), ui) in gn.iter().zip(dx.iter_mut()).zip(u.iter_mut()) {
        let gi = gi.get(..na).unwrap_or(&[]);
        let mut acc = [0.0f32; NS];
        for (git, yt) in gi.iter().zip(yn.iter()) {
            axpy(&mut acc, *yt, git);
        }
        *d = acc;
        for (s2, uis) in ui.iter_mut().enumerate().take(na) {
            let mut acc = [0.0f32; NS];
            for (git, crow) in gi.iter().zip(cn.iter()) {
                axpy(&mut acc, get(crow, s2), git);
            }
            *uis = acc;
        }
    }
    if na > 0 {
        // P⁺_ij = P̄_ij − Σ_s u[i][s] g[j][s]ᵀ for the upper blocks (diagonal blocks symmetrised),
        // written in place with the mirrored lower blocks. A row must leave the state untouched
        // when it fails, so the update is only done when it cannot produce a non-finite value:
        // with every u, g and dx entry finite and at most `LIMIT` in magnitude, each correction is
        // below `16·LIMIT² < 2^103` (half an ulp of f32::MAX), so subtracting it from a finite
        // entry cannot overflow, whatever the state's magnitude; beyond (absurd values) the row
        // fails.
        const LIMIT: f32 = 3e14;
        let small = |v: &f32| v.abs() <= LIMIT; // false for NaN and ±inf
        let mut ok = dx.iter().take(n).all(|d| d.iter().all(small));
        for (ui, gi) in u.iter().zip(gn.iter()) {
            ok &= ui.iter().take(na).all(|v| v.iter().all(small));
            ok &= gi.iter().take(na).all(|v| v.iter().all(small));
        }
        if !ok {
            return false;
        }
        for (i, ui) in u.iter().enumerate().take(n) {
            let ui = ui.get(..na).unwrap_or(&[]);
            for (j, gj) in gn.iter().enumerate().skip(i) {
                // Column b of the block: P_·b − Σ_s u_s g_s[b].
                let mut red = [[0.0f32; NS]; NS];
                for (uv, gv) in ui.iter().zip(gj.iter()) {
                    for (col, gb) in red.iter_mut().zip(gv.iter()) {
                        axpy(col, *gb, uv);
                    }
                }
                let Some(pij) = ps.get_mut(i).and_then(|r| r.get_mut(j)) else {
                    continue;
                };
                let mut blk = pij.data.0;
                for (col, rcol) in blk.iter_mut().zip(red.iter()) {
                    for (e, r) in col.iter_mut().zip(rcol.iter()) {
                        *e -= r;
                    }
                }
                if i == j {
                    for a in 0..NS {
                        for b in 0..a {
                            // (Halves first: cannot overflow.)
                            let v = 0.5 * at(&blk, a, b) + 0.5 * at(&blk, b, a);
                            put(&mut blk, a, b, v);
                            put(&mut blk, b, a, v);
                        }
                    }
                }
                let m = SMatrix::<f32, NS, NS>::from_data(nalgebra::ArrayStorage(blk));
                *pij = m;
                if i != j {
                    if let Some(b) = ps.get_mut(j).and_then(|r| r.get_mut(i)) {
                        *b = m.transpose();
                    }
                }
            }
        }
        for (x, d) in xs.iter_mut().zip(dx.iter()).take(n) {
            for (xv, dv) in x.iter_mut().zip(d.iter()) {
                *xv += dv;
            }
        }
    }
    true
}

/// Element `(i, j)` of a fixed 2-D array, or 0 past its end.
#[inline]
pub(super) fn at<const R: usize, const C: usize>(a: &[[f32; C]; R], i: usize, j: usize) -> f32 {
    a.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0)
}

/// `P h` for a column-major block `P` (columns where `h` is zero are skipped: `h = [1, 1, 0, …]`
/// has zeros).
#[inline(always)]
pub(super) fn mat_vec<const N: usize>(p: &SMatrix<f32, N, N>, h: &[f32; N]) -> [f32; N] {
    let mut out = [0.0f32; N];
    for (col, hb) in p.data.0.iter().zip(h.iter()) {
        if *hb != 0.0 {
            axpy(&mut out, *hb, col);
        }
    }
    out
}

/// `y += a x`.
#[inline(always)]
pub(super) fn axpy<const N: usize>(y: &mut [f32; N], a: f32, x: &[f32; N]) {
    for (yv, xv) in y.iter_mut().zip(x.iter()) {
        *yv += a * xv;
    }
}

/// Sets element `(i, j)` of a fixed 2-D array (no-op past its end).
#[inline]
pub(super) fn put<const R: usize, const C: usize>(
    a: &mut [[f32; C]; R],
    i: usize,
    j: usize,
    v: f32,
) {
    if let Some(e) = a.get_mut(i).and_then(|r| r.get_mut(j)) {
        *e = v;
    }
}
