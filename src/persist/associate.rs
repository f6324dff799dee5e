//! One association pass of the known lanes over the binned rows (docs/design.md §11.3–§11.5):
//! per row the predicted lanes, the joint events, and each lane's evidence and detection
//! counts; the points the lanes explain; the clutter estimate from the rest.

use crate::linalg::{get, set};
use crate::math;
use crate::spatial::row::{self, RowOutcome, RowParams, MAX_ROW_POINTS};
use crate::tables::Tables;
use crate::temporal::filter::TemporalFilter;

use super::rows::{band, quad, PassMemory, RowBasis};
use super::{ChainRates, Evidence, Pass, PassCounts, Persist, PersistConfig};

/// The rows' points a known lane explains, per row (bit `j` = point `j`).
pub type Explained<const ROWS: usize> = [u32; ROWS];

/// Inputs of one association pass.
pub struct Lanes<'a, const LANES: usize> {
    /// Slots looked at (bit `s`).
    pub slots: u32,
    /// B index (rank) of every slot.
    pub ranks: &'a [u8; LANES],
    /// Row range `[lo, hi]` per slot (inclusive).
    pub rows: [(u16, u16); LANES],
}

/// The lanes looked at in one row, predicted: slot, mean `ẑ` and variance `S` (with the
/// band's point variance) for the first `n`.
struct Predicted<const LANES: usize> {
    idx: [usize; LANES],
    zhat: [f32; LANES],
    sdiag: [f32; LANES],
    n: usize,
}

/// Where a row is: its index, band, `u`, the GP row vector `c` over the first `r_used`
/// components, and the row's parameters (the band's clutter density and point variance).
struct RowAt<const RANK: usize> {
    r: usize,
    b: usize,
    u: f32,
    /// The paint / gap chain's constants when it scores the existence evidence.
    chain: Option<ChainRates>,
    c: [f32; RANK],
    r_used: usize,
    params: RowParams,
}

/// `(ν̄, Σ β_j ν_j²)` of a lane's row: the first and second moments of its innovations
/// `ν_j = z_j − ẑ` under the association weights.
fn moments(pts: &[f32], brow: &[f32; MAX_ROW_POINTS], zh: f32) -> (f32, f32) {
    let mut nbar = 0.0f32;
    let mut n2 = 0.0f32;
    for (z, bj) in pts.iter().zip(brow.iter()) {
        let d = z - zh;
        nbar += bj * d;
        n2 += bj * d * d;
    }
    (nbar, n2)
}

/// The row's PDA update of a lane's marginal as one equivalent measurement (docs/design.md
/// §11.3): with the row prior variance `p = S − r`, `ν̄ = Σ β_j ν_j` and the spread
/// `Σ β_j ν_j² − ν̄²`, the PDA posterior variance `p − W p²/S + p² spread/S²` equals that of a
/// measurement of variance `v`, `1/(p + v) = W/S − spread/S²`, at `ẑ + ν̄ (p + v)/S`.
/// `(nbar, n2)` are the row's [`moments`]. Returns `(1/v, z̃)`, or `None` when the row carries
/// no information.
fn equivalent_measurement(
    (nbar, n2): (f32, f32),
    (zh, st, w): (f32, f32, f32),
    r: f32,
) -> Option<(f32, f32)> {
    let spread = math::max(n2 - nbar * nbar, 0.0);
    let q = w / st - spread / (st * st);
    let p_row = st - r;
    let var = if q > 0.0 {
        1.0 / q - p_row
    } else {
        f32::INFINITY
    };
    let zt = zh + nbar / (q * st);
    let om = 1.0 / var;
    (om.is_finite() && om > 0.0 && zt.is_finite()).then_some((om, zt))
}

/// The row's dominant point of one lane, `(j, β_j)`, the first of the largest.
fn dominant(brow: &[f32; MAX_ROW_POINTS], m: usize) -> (usize, f32) {
    brow.iter().take(m).enumerate().fold(
        (0usize, 0.0f32),
        |acc, (j, v)| if *v > acc.1 { (j, *v) } else { acc },
    )
}

/// The density of a row's gated points for each lane's existence (docs/design.md §11.5),
/// against clutter **and the other lanes** (LMIPDA, Mušicki & La Scala 2008): under "lane `a`
/// does not exist" a point it gates is clutter or a detection of another lane `t`, of density
/// `λ + Σ_{t≠a} q_t N(z_j; ẑ_t, S_tt)` with `q_t = P_D P(t exists)`. So
/// `out.dens[a] = λ Σ_{j gated} N(z_j; ẑ_a, S_aa) / (λ + Σ_{t≠a, j gated by t} q_t N(z_j; ẑ_t, S_tt))`
/// replaces the exclusive density of the spatial rows (each point as far as no other lane
/// claims it by `β`), which gave a lane that runs on another lane's marking for a few rows the
/// evidence of a marking of its own there (a split `β ≈ ½` still counted half of a point
/// worth `N/λ ≫ 1`). `dens / λ` enters `Λ_r` as before.
///
/// # Complexity
/// One `exp` per lane and gated point, and one more per lane and point that another lane gates
/// as well; one `√` per lane with a gated point in the row, and one more per lane with a shared
/// point (those are recomputed, not stored: storing them cost 1.1 KB of flash, stop 35),
/// `O(n·m)`; 128 B of stack. Out of line, as the row's other kernels.
#[inline(never)]
fn joint_density<const LANES: usize>(
    out: &mut RowOutcome<LANES>,
    pred: &Predicted<LANES>,
    pts: &[f32],
    lam: f32,
    q: &[f32; LANES],
) {
    let m = pts.len().min(MAX_ROW_POINTS);
    // Opaque to the optimiser: without it the lane loops are unrolled and the firmware's
    // flash grows by 1.6 KB (262,584 B against 260,968 B, over the 256 KiB limit; stop 35).
    let n = core::hint::black_box(pred.n.min(LANES));
    let in_row = if m >= 32 { u32::MAX } else { (1u32 << m) - 1 };
    // N(z_j; ẑ_a, S_aa) of a gated pair: `(ẑ, 1/S, 1/√(2πS))` per lane.
    let lane = |a: usize| {
        let st = get(&pred.sdiag, a);
        let c = 1.0 / math::sqrt(2.0 * core::f32::consts::PI * st);
        (get(&pred.zhat, a), 1.0 / st, c)
    };
    // The points that more than one lane gates: only there do the other lanes enter the
    // density (a point only lane a gates counts N_a(z_j) λ/λ = N_a(z_j)).
    let (mut seen, mut shared) = (0u32, 0u32);
    for a in 0..n {
        let v = get(&out.valid, a) & in_row;
        shared |= seen & v;
        seen |= v;
    }
    // Σ_t q_t N(z_j; ẑ_t, S_tt) per shared point, over the lanes that gate it.
    let mut tot = [0.0f32; MAX_ROW_POINTS];
    for a in 0..n {
        let mut mask = get(&out.valid, a) & shared;
        if mask == 0 {
            // Most rows: no shared point, and no `√` for the lane's constants.
            continue;
        }
        let ((zt, inv, c), qa) = (lane(a), get(q, a));
        while mask != 0 {
            let j = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let e = pts.get(j).copied().unwrap_or(zt) - zt;
            let v = c * math::exp_call(-0.5 * e * e * inv);
            if let Some(t) = tot.get_mut(j) {
                *t += qa * v;
            }
        }
    }
    // Each lane's density against clutter and the others.
    for a in 0..n {
        let mut mask = get(&out.valid, a) & in_row;
        if mask == 0 {
            // A lane with no gated point in the row: no `√`, and its density is 0.
            set(&mut out.dens, a, 0.0);
            continue;
        }
        let ((zt, inv, c), qa) = (lane(a), get(q, a));
        let mut d = 0.0f32;
        while mask != 0 {
            let j = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let e = pts.get(j).copied().unwrap_or(zt) - zt;
            let v = c * math::exp_call(-0.5 * e * e * inv);
            d += if shared & (1 << j) != 0 {
                // `tot − q_a v ≥ 0` up to rounding: the denominator is at least `λ`.
                lam * v / math::max(lam + get(&tot, j) - qa * v, lam)
            } else {
                v
            };
        }
        set(&mut out.dens, a, if d.is_finite() { d } else { 0.0 });
    }
}

impl<const LANES: usize, const POINTS: usize, const ROWS: usize> Persist<LANES, POINTS, ROWS> {
    /// One pass of the known lanes over the binned rows: per row the predicted lanes, the
    /// joint events, and each lane's evidence (`ev[s]`) and detection counts; the points each
    /// row's lanes explain (`explained[r]`), and the clutter estimate from the rest
    /// (`estimate_clutter`). `row_points(r)` gives row `r`'s points. Returns what the rows'
    /// association did (`cfg.association`): failed rows, events scored, rows pruned to the
    /// budget, rows weighed by LBP.
    #[allow(clippy::too_many_arguments)]
    pub fn associate<'p, const NT: usize, const RANK: usize, const NX: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        (basis, mem): (&RowBasis<RANK, ROWS>, &mut PassMemory<RANK, LANES>),
        filter: &TemporalFilter<LANES, POINTS, RANK, NX>,
        lanes: &Lanes<'_, LANES>,
        pass: &Pass,
        cfg: &PersistConfig,
        row_points: impl Fn(usize) -> &'p [f32],
        estimate_clutter: bool,
        ev: &mut [Evidence<RANK>; LANES],
        explained: &mut Explained<ROWS>,
    ) -> PassCounts {
        let h = &tables.hyper;
        let r_used = (tables.gram_rank as usize).min(RANK).min(POINTS);
        let (slot, n) = self.begin_pass(filter, lanes.slots, cfg.pd_memory);
        // P_D,b of every lane for this pass: the discounted estimate before this frame's rows
        // (docs/design.md §11.5; the counts of this pass take effect from the next one).
        let mut pd0 = [[0.5f32; POINTS]; LANES];
        for (l, row) in self.lanes.iter().zip(pd0.iter_mut()) {
            for (b, v) in row.iter_mut().enumerate() {
                *v = math::max(l.pd(b), cfg.pd_floor);
            }
        }
        // With `own_pd`, each lane's detection odds in each band against the pass's `P_D`
        // (docs/design.md §11.3): the rows' joint events weigh a lane's detections at its own
        // `P_D,b` (two `ln` per lane and band, once a pass).
        let mut odds0 = [[0.0f32; POINTS]; LANES];
        if cfg.own_pd {
            let ln_odds = |pd: f32| math::ln(pd) - math::ln(pass.params.miss_at(pd));
            let own = ln_odds(pass.params.pd);
            for &s in slot.iter().take(n) {
                if let (Some(o), Some(p)) = (odds0.get_mut(s), pd0.get(s)) {
                    for (ob, pb) in o.iter_mut().zip(p.iter()) {
                        let v = ln_odds(*pb) - own;
                        *ob = if v.is_finite() { v } else { 0.0 };
                    }
                }
            }
        }
        let bss = |s: usize, t: usize| {
            let a = usize::from(get(lanes.ranks, s));
            let b = usize::from(get(lanes.ranks, t));
            tables.coreg.get((a, b)).copied().unwrap_or(0.0)
        };
        let uncoupled = filter.uncoupled();
        // The paint / gap chain (§11.5) at the estimated mean gap: every lane of the pass
        // starts at its stationary share.
        let chain = cfg
            .paint_gap
            .map(|c| super::PaintGap {
                gap: self.chain_gap(c.gap),
                ..c
            })
            .and_then(|c| c.rates(pass.du));
        if let Some(c) = chain {
            for &s in slot.iter().take(n) {
                if let Some(e) = ev.get_mut(s) {
                    e.chain = [c.pi_on, 1.0 - c.pi_on];
                }
            }
        }
        // Each lane's own block, read once for all rows.
        mem.load(filter, lanes.slots, r_used);
        let mut unexplained = [0.0f32; POINTS];
        let mut band_rows = [0.0f32; POINTS];
        let mut counts = PassCounts::default();
        // One outcome and scratch for every row (the outcome reset by each row's association).
        let PassMemory {
            lanes: blocks,
            out,
            row: scratch,
        } = mem;
        for r in 0..pass.rows.min(ROWS) {
            let pts = row_points(r);
            let m = pts.len().min(MAX_ROW_POINTS);
            let pts = pts.get(..m).unwrap_or(&[]);
            let b = band::<POINTS>(r, pass.k_rows);
            if let Some(br) = band_rows.get_mut(b) {
                *br += 1.0;
            }
            let u = h.u_min + r as f32 * pass.du;
            let (c, rho) = basis.at(r);
            // The lanes looked at in this row (their row range), predicted.
            let mut pred = Predicted {
                idx: [0; LANES],
                zhat: [0.0; LANES],
                sdiag: [0.0; LANES],
                n: 0,
            };
            let mut odds = [0.0f32; LANES];
            for &s in slot.iter().take(n) {
                let (lo, hi) = get(&lanes.rows, s);
                if r < usize::from(lo) || r > usize::from(hi) {
                    continue;
                }
                let Some(o) = blocks.get(s) else {
                    continue;
                };
                let k = pred.n;
                set(&mut pred.zhat, k, o.mean(&c, r_used));
                set(
                    &mut pred.sdiag,
                    k,
                    o.quad(&c, r_used) + rho * bss(s, s) + self.noise(b, pass.params.r),
                );
                set(&mut pred.idx, k, s);
                set(&mut odds, k, odds0.get(s).map_or(0.0, |o| get(o, b)));
                pred.n += 1;
            }
            let at = RowAt {
                r,
                b,
                u,
                chain,
                c,
                r_used,
                params: RowParams {
                    clutter_density: self.clutter(
                        b,
                        pass.params.clutter_density,
                        cfg.clutter_floor,
                    ),
                    r: self.noise(b, pass.params.r),
                    ..pass.params
                },
            };
            row::associate_into(
                (&mut *out, &mut *scratch),
                &pred.zhat,
                &pred.sdiag,
                |a, bb| {
                    let (s, t) = (get(&pred.idx, a), get(&pred.idx, bb));
                    // While the filter is uncoupled (docs/design.md §4.2.6) the lanes'
                    // cross-covariance blocks are exactly zero, and so is their quadratic form.
                    let prior = if uncoupled {
                        0.0
                    } else {
                        quad(filter, s, t, &c, r_used)
                    };
                    prior + rho * bss(s, t)
                },
                pred.n,
                pts,
                (&at.params, &odds),
                (pass.max_events, cfg.association),
                0,
            );
            counts.failed_rows += u32::from(out.failed);
            counts.events += out.events;
            counts.pruned_rows += u32::from(out.approximated && out.lbp_iterations == 0);
            counts.lbp_rows += u32::from(out.lbp_iterations > 0);
            // Explained points.
            let mut ex = 0u32;
            for j in 0..m {
                let tot: f32 = out.beta.iter().take(pred.n).map(|row| get(row, j)).sum();
                if tot >= cfg.explained {
                    ex |= 1 << j;
                }
            }
            if let Some(e) = explained.get_mut(r) {
                *e |= ex;
            }
            if let Some(un) = unexplained.get_mut(b) {
                *un += (m as u32 - ex.count_ones()) as f32;
            }
            if !out.failed {
                // Each lane's detection weight as another lane's competitor: P_D · P(exists).
                let mut q = [0.0f32; LANES];
                for (a, qa) in q.iter_mut().enumerate().take(pred.n) {
                    let s = get(&pred.idx, a);
                    let p = self.lanes.get(s).map_or(0.0, |l| l.existence);
                    *qa = pass.params.pd * p.clamp(0.0, 1.0);
                }
                joint_density(out, &pred, pts, at.params.clutter_density, &q);
            }
            for a in 0..pred.n {
                let s = get(&pred.idx, a);
                let pd = pd0.get(s).map_or(0.5, |row| get(row, b));
                if let Some(e) = ev.get_mut(s) {
                    self.lane_row(e, (s, a, pd), &pred, out, pts, &at);
                }
            }
        }
        if estimate_clutter {
            self.update_clutter(&unexplained, &band_rows, cfg.clutter_memory);
        }
        counts
    }

    /// Collects the active slots among `slots` and discounts their detection counts with a
    /// memory of `pd_memory` frames.
    fn begin_pass<const RANK: usize, const NX: usize>(
        &mut self,
        filter: &TemporalFilter<LANES, POINTS, RANK, NX>,
        slots: u32,
        pd_memory: f32,
    ) -> ([usize; LANES], usize) {
        let mut slot = [0usize; LANES];
        let mut n = 0usize;
        for s in 0..LANES {
            if slots & (1 << s) != 0 && filter.is_active(s) {
                set(&mut slot, n, s);
                n += 1;
            }
        }
        let pd_decay = if pd_memory > 1.0 {
            1.0 - 1.0 / pd_memory
        } else {
            0.0
        };
        // This frame's dominant points only: rows outside a lane's row range this frame, and
        // lanes not in this pass, must not keep an earlier frame's (the noise estimate reads
        // every row of the lanes it is given).
        for rs in self.rows.iter_mut() {
            *rs = [[0.0; 2]; ROWS];
        }
        for s in slot.iter().take(n) {
            if let Some(l) = self.lanes.get_mut(*s) {
                l.passes = l.passes.saturating_add(1);
                for (hb, lb) in l.hits.iter_mut().zip(l.looks.iter_mut()) {
                    *hb *= pd_decay;
                    *lb *= pd_decay;
                }
            }
        }
        (slot, n)
    }

    /// One lane's share of a row: `s` is its slot, `a` its place in the row's events, `pd` its
    /// `P_D` in the row's band. Adds the row's IPDA likelihood ratio and equivalent
    /// measurement to `e`, records the row's dominant point for the noise estimate, and counts
    /// the row for the lane's `P_D` when the lane is in view.
    fn lane_row<const RANK: usize>(
        &mut self,
        e: &mut Evidence<RANK>,
        (s, a, pd): (usize, usize, f32),
        pred: &Predicted<LANES>,
        out: &RowOutcome<LANES>,
        pts: &[f32],
        at: &RowAt<RANK>,
    ) {
        let (r, b, m) = (at.r, at.b, pts.len());
        let w = (1.0 - get(&out.beta_miss, a)).clamp(0.0, 1.0);
        let brow = out.beta.get(a).unwrap_or(&[0.0; MAX_ROW_POINTS]);
        let st = get(&pred.sdiag, a);
        let zh = get(&pred.zhat, a);
        // In view: inside the band's span of points this frame.
        let [vlo, vhi] = self.span.get(b).copied().unwrap_or([0.0; 2]);
        let in_view = zh >= vlo && zh <= vhi;
        // IPDA likelihood ratio of the row, each gated point against clutter and the other
        // lanes' detections ([`joint_density`]).
        let lambda = at.params.clutter_density;
        if let Some(c) = at.chain {
            // One forward step of the paint / gap chain: on paint the row's ratio at `p_on`, in
            // a gap 1 (no detection expected); normalised, the scale into `llr`.
            if in_view {
                let lr_on = 1.0 - c.p_on * at.params.pg + c.p_on * get(&out.dens, a) / lambda;
                let [on, off] = e.chain;
                // The forward weights of the step's four transitions, paint / gap to paint / gap.
                let (w_oo, w_fo) = (on * (1.0 - c.to_off), off * c.to_on);
                let (w_of, w_ff) = (on * c.to_off, off * (1.0 - c.to_on));
                let (p_on, p_off) = (w_oo + w_fo, w_of + w_ff);
                let a_on = p_on * lr_on;
                let a_off = p_off;
                let sum = a_on + a_off;
                if sum.is_finite() && sum > 0.0 {
                    e.chain = [a_on / sum, a_off / sum];
                    e.llr += math::ln(sum);
                    // Forward-only smoothing of the gap statistics (§11.5): with the backward
                    // kernel p(x' | x, rows before) = α(x') A(x', x) / Σ, ρ(x) ← Σ_x' p(x' | x)
                    // (ρ(x') + s(x', x)), s counting a gap → paint step (N) and a gap row (T).
                    let div = |v: f32, p: f32| if p > 0.0 { v / p } else { 0.0 };
                    let [n_on, n_off, t_on, t_off] = e.chain_em;
                    e.chain_em = [
                        div(w_oo * n_on + w_fo * (n_off + 1.0), p_on),
                        div(w_of * n_on + w_ff * n_off, p_off),
                        div(w_oo * t_on + w_fo * t_off, p_on),
                        div(w_of * t_on + w_ff * t_off, p_off) + 1.0,
                    ];
                }
            }
        } else {
            let lr = 1.0 - pd * at.params.pg + pd * get(&out.dens, a) / lambda;
            if in_view && lr.is_finite() && lr > 0.0 {
                e.llr += math::ln(lr);
            }
        }
        // The share of `S` that the lane's prediction holds (the rest is point noise).
        let f = if st > 0.0 {
            ((st - at.params.r) / st).clamp(0.0, 1.0)
        } else {
            0.0
        };
        if w > 1e-6 && !out.failed {
            let zbar: f32 = pts
                .iter()
                .zip(brow.iter())
                .map(|(z, bj)| z * bj)
                .sum::<f32>()
                / w;
            // For the noise estimate: the row's dominant point and its β, when it holds ≥ 90 %
            // of the lane's weight (a mixture with clutter would count clutter as noise); the
            // estimate takes it when β ≥ 0.5 (docs/design.md §11.6).
            let (jd, bd) = dominant(brow, m);
            if bd >= 0.9 * w {
                if let Some(rw) = self.rows.get_mut(s).and_then(|rs| rs.get_mut(r)) {
                    *rw = [pts.get(jd).copied().unwrap_or(zbar), bd];
                }
            }
            let mom = moments(pts, brow, zh);
            if in_view {
                // The score of the process-noise scale (§11.7): ∂ ln L_r / ∂ ln S_r = ½ (Σ β_j
                // ν_j²/S − W), times the share f of S that the prediction holds.
                e.q_score[0] += f * (mom.1 / st - w);
                e.q_score[1] += w * f * f;
            }
            if let Some((om, zt)) = equivalent_measurement(mom, (zh, st, w), at.params.r) {
                let ru = at.r_used.min(RANK);
                let mut oc = [0.0f32; RANK];
                for ((o, iv), cj) in oc.iter_mut().zip(e.i.iter_mut()).zip(at.c.iter()).take(ru) {
                    *iv += om * zt * cj;
                    *o = om * cj;
                }
                for (kv, o) in e.k.iter_mut().zip(oc.iter()) {
                    *kv += o;
                }
                e.offset[0] += om;
                e.offset[1] += om * zt;
                e.offset[2] += om * zh;
                // J is column-major: column k holds (om c_j) c_k down j. Each entry is its own
                // sum, so the fixed trip counts at `ru = RANK` (a tracker compiled at its
                // model's rank) give the same bits, unrolled.
                let cols = e.j.as_mut_slice().chunks_exact_mut(RANK).zip(at.c.iter());
                if ru >= RANK {
                    for (col, ck) in cols {
                        for (jv, o) in col.iter_mut().zip(oc.iter()) {
                            *jv += o * ck;
                        }
                    }
                } else {
                    for (col, ck) in cols.take(ru) {
                        for (jv, o) in col.iter_mut().zip(oc.iter()).take(ru) {
                            *jv += o * ck;
                        }
                    }
                }
                e.weight += w;
                // Seen in this row (docs/design.md §11.8): W ≥ 0.5 and a position learnt. A row
                // whose weight is split around the prediction, so that its equivalent
                // measurement carries no information, is not (clutter on both sides).
                if w >= 0.5 {
                    e.extent[0] = e.extent[0].min(at.u);
                    e.extent[1] = math::max(e.extent[1], at.u);
                }
            }
        }
        if let (true, Some(ls)) = (in_view, self.lanes.get_mut(s)) {
            if let (Some(hb), Some(lb)) = (ls.hits.get_mut(b), ls.looks.get_mut(b)) {
                *hb += w;
                *lb += 1.0;
            }
        }
    }

    /// The clutter density per band from this pass's unexplained points (points per metre
    /// per row over the band's span), smoothed with a memory of `memory` frames.
    fn update_clutter(
        &mut self,
        unexplained: &[f32; POINTS],
        band_rows: &[f32; POINTS],
        memory: f32,
    ) {
        let a = if memory > 1.0 { 1.0 / memory } else { 1.0 };
        for b in 0..POINTS {
            let rows = get(band_rows, b);
            if rows <= 0.0 {
                continue;
            }
            let [lo, hi] = self.span.get(b).copied().unwrap_or([0.0; 2]);
            let width = if hi > lo {
                math::max(hi - lo, 1.0)
            } else {
                1.0
            };
            let est = get(unexplained, b) / (rows * width);
            if let Some(c) = self.clutter.get_mut(b) {
                *c = if c.is_finite() {
                    *c + a * (est - *c)
                } else {
                    est
                };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tables::DEFAULT;
    use crate::temporal::smoother::Temporal;

    const ROWS: usize = 16;
    type Filter = Temporal<6, 16, 7, 84, 42, 4>;

    /// One lane in slot 2 from the prior, predicted 50 ms; a pass of 16 rows 2 m apart, one a
    /// band, with `params`; its row basis and the lane's own block.
    fn one_lane(params: RowParams) -> (Filter, Pass, RowBasis<7, ROWS>, PassMemory<7, 6>) {
        let mut t = Filter::new();
        t.start_lane(&DEFAULT, 2, 0, &[0; 6]).unwrap();
        t.predict(&DEFAULT, 0.05).unwrap();
        let pass = Pass {
            rows: ROWS,
            du: 2.0,
            k_rows: 1,
            params,
            max_events: 64,
        };
        let mut basis = RowBasis::NEW;
        basis.ensure(&DEFAULT, &pass);
        let mut mem = PassMemory::NEW;
        mem.load(t.filter(), 1 << 2, 7);
        (t, pass, basis, mem)
    }

    /// One pass of the lanes `slots` over the rows `0..=hi` with `points(r)`.
    fn pass_over<'p>(
        ps: &mut Persist<6, 16, ROWS>,
        (t, pass, basis, mem): (&Filter, &Pass, &RowBasis<7, ROWS>, &mut PassMemory<7, 6>),
        (slots, hi): (u32, u16),
        points: impl Fn(usize) -> &'p [f32],
    ) -> (PassCounts, [Evidence<7>; 6]) {
        let lanes = Lanes {
            slots,
            ranks: &[0; 6],
            rows: [(0, hi); 6],
        };
        let mut ev = [Evidence::<7>::NONE; 6];
        let mut explained: Explained<ROWS> = [0; ROWS];
        let counts = ps.associate(
            &DEFAULT,
            (basis, mem),
            t.filter(),
            &lanes,
            pass,
            &PersistConfig::default(),
            points,
            false,
            &mut ev,
            &mut explained,
        );
        (counts, ev)
    }

    /// The noise estimate of slot 2 on `ps`'s row records: the rows it counted.
    fn noise_rows(
        ps: &mut Persist<6, 16, ROWS>,
        (t, pass, basis): (&Filter, &Pass, &RowBasis<7, ROWS>),
    ) -> f32 {
        let mut mem = PassMemory::NEW;
        ps.estimate_noise(
            &DEFAULT,
            (basis, &mut mem),
            t.filter(),
            (1 << 2, &[0; 6]),
            pass,
            10.0,
        );
        ps.noise.iter().map(|nb| nb[1]).sum()
    }

    /// A lane whose row range shrinks from one pass to the next keeps no dominant point of the
    /// earlier pass in the rows it no longer covers: the noise estimate reads every row.
    #[test]
    fn rows_out_of_a_lanes_range_hold_no_earlier_point() {
        let (t, pass, basis, mut mem) = one_lane(RowParams::default());
        let mut ps = Persist::<6, 16, ROWS>::new();
        // One point a row on the lane's predicted mean (the prior's, 0).
        let pts = [0.0f32];
        let ctx = (&t, &pass, &basis, &mut mem);
        assert_eq!(
            pass_over(&mut ps, ctx, (1 << 2, 15), |_| &pts[..])
                .0
                .failed_rows,
            0
        );
        assert!(ps.rows[2].iter().all(|rw| rw[1] >= 0.5), "{:?}", ps.rows[2]);
        let ctx = (&t, &pass, &basis, &mut mem);
        assert_eq!(
            pass_over(&mut ps, ctx, (1 << 2, 5), |_| &pts[..])
                .0
                .failed_rows,
            0
        );
        assert!(ps.rows[2][..6].iter().all(|rw| rw[1] >= 0.5));
        assert!(ps.rows[2][6..].iter().all(|rw| *rw == [0.0; 2]));
    }

    /// `estimate_noise` uses this frame's posterior residuals of the lanes in `slots`: a lane
    /// given to it that was not in this frame's pass has none (its rows of the last pass it
    /// was in were counted again).
    #[test]
    fn the_noise_estimate_reads_no_rows_of_a_lane_left_out_of_the_pass() {
        let (t, pass, basis, mut mem) = one_lane(RowParams::default());
        let mut ps = Persist::<6, 16, ROWS>::new();
        let pts = [0.0f32];
        // Frame 1: the lane in the pass, its rows recorded and counted.
        pass_over(&mut ps, (&t, &pass, &basis, &mut mem), (1 << 2, 15), |_| {
            &pts[..]
        });
        assert!(noise_rows(&mut ps.clone(), (&t, &pass, &basis)) > 0.0);
        // Frame 2: the lane left out of the pass.
        pass_over(
            &mut ps,
            (&t, &pass, &basis, &mut mem),
            (0, 15),
            |_| &pts[..],
        );
        assert_eq!(
            noise_rows(&mut ps, (&t, &pass, &basis)),
            0.0,
            "{:?}",
            ps.noise
        );
    }

    /// `Evidence::extent` holds the rows with `W_r ≥ 0.5` whose equivalent measurement carries
    /// information (docs/design.md §11.8): a row whose weight is split between two points on
    /// either side of the prediction (spread ≥ W·S) is not in it, a row with one point on the
    /// prediction is. Measured: counting the split rows as seen (as §11.8 said until stop 70)
    /// lets clutter on both sides keep a lane seen (replay high 0.904 / 0.187 / 0.150 →
    /// 0.898 / 0.204 / 0.169).
    #[test]
    fn a_row_split_around_the_prediction_is_not_in_the_extent() {
        let params = RowParams {
            clutter_density: 0.005,
            ..RowParams::default()
        };
        let (t, pass, basis, mut mem) = one_lane(params);
        let mut ps = Persist::<6, 16, ROWS>::new();
        // Rows 0–7: two points at ±1.3 √S around the lane's prediction (the prior's, 0); rows
        // 8–15: one point on it and one far outside its gate.
        let bss = DEFAULT.coreg[(0, 0)];
        let pts: [[f32; 2]; ROWS] = core::array::from_fn(|r| {
            let (c, rho) = basis.at(r);
            let o = mem.get(2).unwrap();
            let st = o.quad(&c, 7) + rho * bss + ps.noise(r, pass.params.r);
            let (z, d) = (o.mean(&c, 7), 1.3 * st.sqrt());
            if r < 8 {
                [z - d, z + d]
            } else {
                [z, z + 100.0]
            }
        });
        ps.observe_spans(ROWS, 1, |r| &pts[r][..]);
        let ctx = (&t, &pass, &basis, &mut mem);
        let (counts, ev) = pass_over(&mut ps, ctx, (1 << 2, 15), |r| &pts[r][..]);
        assert_eq!(counts.failed_rows, 0);
        // One pass from zero counts, one row a band: `hits[b]` is row b's W (all in view).
        let w: [f32; ROWS] = core::array::from_fn(|r| ps.lanes[2].hits[r]);
        assert!(w.iter().all(|v| *v >= 0.5), "{w:?}");
        let u = |r: usize| DEFAULT.hyper.u_min + r as f32 * pass.du;
        assert_eq!(ev[2].extent, [u(8), u(15)]);
    }

    /// The point-variance estimate counts a row's dominant point when it holds ≥ 90 % of the
    /// lane's weight W and is more likely than not the lane's detection, β ≥ 0.5
    /// (docs/design.md §11.6, which said "W ≥ 0.5" until stop 70): a row with W = 0.52 whose
    /// dominant point holds 0.47 is not counted, one whose point holds 0.5 is.
    #[test]
    fn a_rows_dominant_point_counts_for_the_noise_when_more_likely_than_not() {
        let (t, pass, basis, mem) = one_lane(RowParams::default());
        let r = 3usize;
        let (c, _) = basis.at(r);
        let zh = mem.get(2).unwrap().mean(&c, 7);
        // The lane's row: W = 0.52, the point on its prediction β, a far one 0.52 − β.
        let pts = [zh, zh + 0.5];
        let row = |beta: f32| {
            let mut out = RowOutcome::<6>::default();
            out.beta_miss[0] = 0.48;
            out.beta[0][0] = beta;
            out.beta[0][1] = 0.52 - beta;
            out.valid[0] = 0b11;
            out
        };
        let mut pred = Predicted::<6> {
            idx: [0; 6],
            zhat: [0.0; 6],
            sdiag: [0.0; 6],
            n: 1,
        };
        pred.idx[0] = 2;
        pred.zhat[0] = zh;
        pred.sdiag[0] = 1.0;
        let at = RowAt::<7> {
            r,
            b: r,
            u: DEFAULT.hyper.u_min + r as f32 * pass.du,
            chain: None,
            c,
            r_used: 7,
            params: pass.params,
        };
        let counted = [0.47f32, 0.5].map(|beta| {
            let mut ps = Persist::<6, 16, ROWS>::new();
            let mut e = Evidence::<7>::NONE;
            ps.lane_row(&mut e, (2, 0, 0.5), &pred, &row(beta), &pts, &at);
            noise_rows(&mut ps, (&t, &pass, &basis))
        });
        assert_eq!(counted, [0.0, 1.0]);
    }
}
