//! One row step of the coupled JPDACF (DESIGN 4.1 steps 2–5): gating, bounded joint-event
//! enumeration, joint-Gaussian event weights in the log domain, and the exact moment-matched update
//! of the event mixture.
//!
//! # The update, as computed
//! With `G = P̄ H̄ᵀ` (the covariance of every track's state with every track's predicted
//! measurement), a pattern `δ` (set of detected tracks) has gain `K_δ = G_δ S_δ⁻¹`. Summing the event
//! mixture `x̄_A = x̄ + K_δ ν_A`, `P_δ = P̄ − K_δ S_δ K_δᵀ` in closed form gives
//!
//! `x̄⁺ = x̄ + G y`, `P̄⁺ = P̄ − G C Gᵀ − (G y)(G y)ᵀ`, with
//! `y = Σ_δ E_δ S_δ⁻¹ m_δ`, `C = Σ_δ E_δ (W_δ S_δ⁻¹ − S_δ⁻¹ M_δ S_δ⁻¹) E_δᵀ`,
//!
//! where `W_δ = Σ_{A∈δ} β_A`, `m_δ = Σ β_A ν_A`, `M_δ = Σ β_A ν_A ν_Aᵀ`, and `E_δ` embeds the
//! pattern's `k` tracks among all `D`. So the state-sized work (`O(D² NS² · D)`) happens once per
//! row; per pattern there is one `D×D` Cholesky factorisation, per event one triangular solve.
//! This is algebraically identical to DESIGN's `Σ_A β_A (P_δ + x̄_A x̄_Aᵀ) − x̄⁺ x̄⁺ᵀ`.
//!
//! # Bounds and cost
//! * at most [`MAX_ROW_POINTS`] points per row (the rest are counted in `ignored_points`);
//! * at most `max_events` joint events are scored. The events are counted first (at most
//!   `max_events + 1` leaves visited); when there are more, (track, point) candidates are dropped
//!   in order of increasing single-track PDA probability (each track's candidates and its miss
//!   normalised among themselves, so no track loses its plausible points first), until
//!   `Π_t (1 + n_t) ≤ max_events` (a bound on the event count), and the row is flagged
//!   `approximated` (DESIGN 4.1 step 5: "drop the least likely candidates until it fits"). The
//!   coupled likelihood does not factor over clusters, so all tracks stay in one enumeration;
//!   the sort costs O(C log C) for C ≤ D·m candidates;
//! * at most `2^D` detection patterns, each factorised once (`D³/3` flops, padded to `D×D`);
//! * worst case per row: `2^D · (D³ + D²)` + `max_events · (D² + D)` + `D² · NS² · D` multiply-adds
//!   and no recursion (the enumeration is an explicit-stack backtracking of depth ≤ D).
//!
//! A numerical failure (a non-positive-definite `S_δ`, all event weights zero, a non-finite
//! result) leaves the state untouched and sets `failed`.

use nalgebra::{SMatrix, SVector};

use super::{get, set, Stacked};
use crate::math;
use crate::probe::{NoProbe, Probe, Stage};

/// Largest number of points one row can hold (the gate masks are `u32`).
pub const MAX_ROW_POINTS: usize = 32;

/// Largest number of (track, point) candidates (16 tracks × 32 points), the size of the pruning
/// list (3 KiB of stack when the budget forces pruning).
const CANDIDATES: usize = 16 * MAX_ROW_POINTS;

/// How a missed track is weighted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MissModel {
    /// `1 − P_D` (textbook JPDA).
    Textbook,
    /// `1 − P_D P_G`: a detection outside the gate is also a miss (DESIGN 4.1; the default).
    Gated,
}

/// Parameters of a row step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RowParams {
    /// Detection probability `P_D` of a lane in a row.
    pub pd: f32,
    /// Gate probability `P_G` (the χ² mass inside `gamma`).
    pub pg: f32,
    /// Gate threshold `γ` on the squared Mahalanobis distance (inclusive).
    pub gamma: f32,
    /// Poisson clutter density `λ_c`, points per metre of lateral extent in one row.
    pub clutter_density: f32,
    /// Variance of a point's lateral position, m².
    pub r: f32,
    /// Miss weighting.
    pub miss: MissModel,
}

impl Default for RowParams {
    /// `P_D = 0.9`, 99 % gate (`γ = 6.635`, one degree of freedom), `λ_c = 0.05 /m`,
    /// `r = 0.01 m²`, [`MissModel::Gated`].
    fn default() -> Self {
        Self {
            pd: 0.9,
            pg: 0.99,
            gamma: 6.634_897,
            clutter_density: 0.05,
            r: 0.01,
            miss: MissModel::Gated,
        }
    }
}

/// What a row step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowOutcome<const LANES: usize> {
    /// `P(track t missed)` per track.
    pub beta_miss: [f32; LANES],
    /// `P(point j from track t)`: `beta[t][j]`.
    pub beta: [[f32; MAX_ROW_POINTS]; LANES],
    /// Gate masks: bit `j` of `valid[t]` is set when point `j` is valid for track `t` (after any
    /// pruning).
    pub valid: [u32; LANES],
    /// Joint events scored.
    pub events: u32,
    /// Detection patterns factorised.
    pub patterns: u32,
    /// Candidates dropped to fit the event budget.
    pub dropped_candidates: u32,
    /// The event budget forced the approximation.
    pub approximated: bool,
    /// Points valid for no track.
    pub clutter_points: u32,
    /// Points beyond [`MAX_ROW_POINTS`] or with a non-finite coordinate (not used).
    pub ignored_points: u32,
    /// A numerical failure: the state was left untouched.
    pub failed: bool,
}

impl<const LANES: usize> Default for RowOutcome<LANES> {
    fn default() -> Self {
        Self {
            beta_miss: [1.0; LANES],
            beta: [[0.0; MAX_ROW_POINTS]; LANES],
            valid: [0; LANES],
            events: 0,
            patterns: 0,
            dropped_candidates: 0,
            approximated: false,
            clutter_points: 0,
            ignored_points: 0,
            failed: false,
        }
    }
}

/// Explicit-stack enumeration of the injective assignments of `k` tracks (in order) to points,
/// each track choosing among the bits of its mask. Depth ≤ `L`; no recursion.
struct Assignments<const L: usize> {
    masks: [u32; L],
    k: usize,
    rem: [u32; L],
    pick: [u8; L],
    used: u32,
    depth: usize,
    started: bool,
    done: bool,
}

impl<const L: usize> Assignments<L> {
    fn new(masks: [u32; L], k: usize) -> Self {
        Self {
            masks,
            k: k.min(L),
            rem: [0; L],
            pick: [0; L],
            used: 0,
            depth: 0,
            started: false,
            done: false,
        }
    }

    fn release(&mut self, d: usize) {
        self.used &= !(1u32.wrapping_shl(u32::from(get(&self.pick, d))));
    }

    /// The next assignment: `pick[a]` is the point of the `a`-th track.
    fn next(&mut self) -> Option<[u8; L]> {
        if self.done {
            return None;
        }
        if self.k == 0 {
            self.done = true;
            return Some(self.pick);
        }
        if self.started {
            self.depth = self.k - 1;
            self.release(self.depth);
        } else {
            self.started = true;
            self.depth = 0;
            set(&mut self.rem, 0, get(&self.masks, 0));
        }
        // Each pass either descends (≤ k), advances a candidate, or ascends: bounded by the tree.
        loop {
            let r = get(&self.rem, self.depth);
            if r == 0 {
                if self.depth == 0 {
                    self.done = true;
                    return None;
                }
                self.depth -= 1;
                self.release(self.depth);
                continue;
            }
            let j = r.trailing_zeros();
            set(&mut self.rem, self.depth, r & r.wrapping_sub(1));
            set(&mut self.pick, self.depth, j as u8);
            self.used |= 1u32.wrapping_shl(j);
            if self.depth + 1 >= self.k {
                return Some(self.pick);
            }
            self.depth += 1;
            set(
                &mut self.rem,
                self.depth,
                get(&self.masks, self.depth) & !self.used,
            );
        }
    }
}

/// Tracks of pattern `pattern` (bit `t` = track `t` detected), in order, and their masks.
fn pattern_tracks<const L: usize>(
    pattern: u32,
    valid: &[u32; L],
    n: usize,
) -> ([u8; L], [u32; L], usize) {
    let mut idx = [0u8; L];
    let mut masks = [0u32; L];
    let mut k = 0;
    for t in 0..n {
        if pattern & (1 << t) != 0 {
            set(&mut idx, k, t as u8);
            set(&mut masks, k, get(valid, t));
            k += 1;
        }
    }
    (idx, masks, k)
}

/// Counts joint events up to `limit + 1` (stops early).
fn count_events<const L: usize>(valid: &[u32; L], n: usize, limit: u64) -> u64 {
    let mut total = 0u64;
    for pattern in 0..(1u32 << n) {
        let (_, masks, k) = pattern_tracks(pattern, valid, n);
        if masks.iter().take(k).any(|m| *m == 0) {
            continue;
        }
        let mut it = Assignments::<L>::new(masks, k);
        while it.next().is_some() {
            total += 1;
            if total > limit {
                return total;
            }
        }
    }
    total
}

/// One row step on `state` with measurement row `h` (`z = hᵀ x_t + noise`, e.g. `[1, 1, 0, …]` for
/// the offset + curve state) and the row's lateral positions `points`.
///
/// # Complexity
/// See the module docs: bounded by `2^LANES` patterns and `max_events` events, no allocation, no
/// recursion.
pub fn update<const NS: usize, const LANES: usize>(
    state: &mut Stacked<NS, LANES>,
    h: &SVector<f32, NS>,
    points: &[f32],
    params: &RowParams,
    max_events: usize,
) -> RowOutcome<LANES> {
    update_masked(state, h, points, params, max_events, 0)
}

/// [`update`] with the tracks of `skip` (bit `t` = track `t`) excluded from gating and from the
/// events: they take no points and carry no miss factor, but the joint update still moves them
/// through their cross-covariances (the exact update for a lane that cannot be detected).
///
/// # Complexity
/// As [`update`].
pub fn update_masked<const NS: usize, const LANES: usize>(
    state: &mut Stacked<NS, LANES>,
    h: &SVector<f32, NS>,
    points: &[f32],
    params: &RowParams,
    max_events: usize,
    skip: u32,
) -> RowOutcome<LANES> {
    update_probed(state, h, points, params, max_events, skip, &mut NoProbe)
}

/// Local and global weights are kept relative to a reference log-weight that is raised only when
/// a new weight exceeds it by more than this (natural log units): rescaling is rare, and the
/// accumulated sums stay far from f32 overflow (`e^{2·16}` times at most `E` events).
const RESCALE: f32 = 16.0;

/// One member of the current detection pattern (the tracks of a pattern in increasing order):
/// its row of the `LDLᵀ` factor of `S_δ` and of `L⁻¹`. A pattern's factor is its parent's (the
/// pattern without its highest track) plus one row, so a pattern costs `O(k²)`, not `O(k³)`.
#[derive(Clone, Copy)]
struct Member<const L: usize> {
    /// Track index.
    tr: u8,
    /// Position in the list of eligible tracks.
    pos: u8,
    /// Gate mask.
    mask: u32,
    /// Predicted measurement `ẑ_t`.
    zh: f32,
    /// `1 / d_a`.
    invd: f32,
    /// `ln det` of the leading `a + 1` members' `S`.
    logdet: f32,
    /// Row `a` of the unit lower factor `L` (entries `b < a`, the rest 0).
    l: [f32; L],
    /// Row `a` of `L⁻¹` (entries `b ≤ a`, diagonal 1, the rest 0).
    li: [f32; L],
}

/// One level of the event enumeration: the candidates left, the pick, and the running forward
/// substitution (`u = L⁻¹ ν`, `q = Σ u_b² / d_b`, `r = Σ_b (u_b / d_b) (L⁻¹)_bᵀ = S⁻¹ ν` over the
/// members picked so far).
#[derive(Clone, Copy)]
struct Level<const L: usize> {
    rem: u32,
    pick: u32,
    u: f32,
    q: f32,
    r: [f32; L],
}

/// The working memory of the event stage: the pattern's members, the enumeration stack, and the
/// pattern's sums, in units of `e^{−q/2 − shift}`: `wd = Σ w`, `y = Σ w r`,
/// `c = wd S⁻¹ − Σ w r rᵀ` (lower triangle), in pattern coordinates, and
/// `bl[a][j] = Σ_{A: a→j} w`. RAM: `4·(L·(2L + 6) + L·(L + 4) + L² + 32·L + 4)` bytes
/// (1.8 KiB of stack at `L = 6`).
struct Work<const L: usize> {
    mem: [Member<L>; L],
    lev: [Level<L>; L],
    k: usize,
    wd: f32,
    y: [f32; L],
    c: [[f32; L]; L],
    bl: [[f32; MAX_ROW_POINTS]; L],
    shift: f32,
    started: bool,
    events: u32,
}

impl<const L: usize> Work<L> {
    const fn new() -> Self {
        Self {
            mem: [Member {
                tr: 0,
                pos: 0,
                mask: 0,
                zh: 0.0,
                invd: 0.0,
                logdet: 0.0,
                l: [0.0; L],
                li: [0.0; L],
            }; L],
            lev: [Level {
                rem: 0,
                pick: 0,
                u: 0.0,
                q: 0.0,
                r: [0.0; L],
            }; L],
            k: 0,
            wd: 0.0,
            y: [0.0; L],
            c: [[0.0; L]; L],
            bl: [[0.0; MAX_ROW_POINTS]; L],
            shift: 0.0,
            started: false,
            events: 0,
        }
    }

    /// The current pattern's members.
    fn members(&self) -> &[Member<L>] {
        self.mem.get(..self.k).unwrap_or(&[])
    }

    /// `ln det S_δ` of the current pattern.
    fn logdet(&self) -> f32 {
        self.members().last().map_or(0.0, |m| m.logdet)
    }

    /// Appends track `t` (eligible position `pos`, row `srow` of `S̄`) to the pattern and
    /// computes its factor row (`f_b = S_tb − Σ_{c<b} l_bc f_c`, `l_kb = f_b / d_b`,
    /// `d_k = S_tt − Σ_b l_kb f_b`) and its row of `L⁻¹` (`−Σ_b l_kb (L⁻¹)_b`, 1 on the
    /// diagonal). Returns `false` (nothing appended) when `d_k` is not positive and finite, i.e.
    /// `S_δ` is not positive definite.
    fn push(&mut self, pos: usize, t: usize, srow: &[f32; L], mask: u32, zhat: f32) -> bool {
        let k = self.k;
        let (done, rest) = self.mem.split_at_mut(k.min(L));
        let Some(new) = rest.first_mut() else {
            return false;
        };
        let mut f = [0.0f32; L];
        let mut l = [0.0f32; L];
        let mut dk = get(srow, t);
        for (b, mb) in done.iter().enumerate() {
            let mut fb = get(srow, usize::from(mb.tr));
            for (lbc, fc) in mb.l.iter().zip(f.iter()).take(b) {
                fb -= lbc * fc;
            }
            set(&mut f, b, fb);
            let lkb = fb * mb.invd;
            set(&mut l, b, lkb);
            dk -= lkb * fb;
        }
        if !(dk.is_finite() && dk > 0.0) {
            return false;
        }
        let mut li = [0.0f32; L];
        for (lkb, mb) in l.iter().zip(done.iter()) {
            for (v, w) in li.iter_mut().zip(mb.li.iter()) {
                *v -= lkb * w;
            }
        }
        set(&mut li, k, 1.0);
        *new = Member {
            tr: t as u8,
            pos: pos as u8,
            mask,
            zh: zhat,
            invd: 1.0 / dk,
            logdet: done.last().map_or(0.0, |m| m.logdet) + math::ln(dk),
            l,
            li,
        };
        self.k = k + 1;
        true
    }

    /// Enumerates the current pattern's events (injective assignments of its members to points
    /// of their masks; explicit stack, depth ≤ `k`) and, when `weighted`, accumulates their sums.
    /// A member's pick extends `u`, `q` and `r` by one term (`O(L)`); an event adds the `O(k²)`
    /// outer product `r rᵀ`; the pattern then adds `wd S⁻¹ = Σ_b (wd / d_b) (L⁻¹)_bᵀ (L⁻¹)_b`
    /// (`O(k³)`).
    fn score(&mut self, points: &[f32], weighted: bool) {
        let k = self.k.min(L);
        self.wd = 0.0;
        self.shift = 0.0;
        self.started = false;
        self.events = 0;
        for (a, (((y, c), bl), mb)) in self
            .y
            .iter_mut()
            .zip(self.c.iter_mut())
            .zip(self.bl.iter_mut())
            .zip(self.mem.iter())
            .enumerate()
            .take(k)
        {
            *y = 0.0;
            for v in c.iter_mut().take(a + 1) {
                *v = 0.0;
            }
            let mut mask = mb.mask;
            while mask != 0 {
                set(bl, mask.trailing_zeros() as usize, 0.0);
                mask &= mask - 1;
            }
        }
        if k == 0 {
            self.events = 1;
            if weighted {
                self.started = true;
                self.wd = 1.0;
            }
            return;
        }
        let mems = self.mem.get(..k).unwrap_or(&[]);
        let levs = self.lev.get_mut(..k).unwrap_or(&mut []);
        if let (Some(l0), Some(m0)) = (levs.first_mut(), mems.first()) {
            l0.rem = m0.mask;
        }
        let mut used = 0u32;
        let mut depth = 0usize;
        // Each pass descends (≤ k), takes a candidate or ascends: bounded by the event tree.
        loop {
            let (prev, cur) = levs.split_at_mut(depth);
            let (Some(lv), Some(mb)) = (cur.first_mut(), mems.get(depth)) else {
                break;
            };
            if lv.rem == 0 {
                let Some(p) = prev.last() else {
                    break;
                };
                used &= !(1u32.wrapping_shl(p.pick));
                depth -= 1;
                continue;
            }
            let j = lv.rem.trailing_zeros();
            lv.rem &= lv.rem.wrapping_sub(1);
            lv.pick = j;
            let mut ua = points.get(j as usize).copied().unwrap_or(0.0) - mb.zh;
            for (lb, pl) in mb.l.iter().zip(prev.iter()) {
                ua -= lb * pl.u;
            }
            let ea = ua * mb.invd;
            lv.u = ua;
            match prev.last() {
                Some(p) => {
                    lv.q = p.q + ua * ea;
                    for ((v, pv), w) in lv.r.iter_mut().zip(p.r.iter()).zip(mb.li.iter()) {
                        *v = pv + ea * w;
                    }
                }
                None => {
                    lv.q = ua * ea;
                    for (v, w) in lv.r.iter_mut().zip(mb.li.iter()) {
                        *v = ea * w;
                    }
                }
            }
            if depth + 1 < k {
                used |= 1u32.wrapping_shl(j);
                depth += 1;
                if let (Some(nl), Some(nm)) = (cur.get_mut(1), mems.get(depth)) {
                    nl.rem = nm.mask & !used;
                }
                continue;
            }
            // A leaf: one joint event.
            self.events += 1;
            let qa = lv.q;
            if !(weighted && qa.is_finite()) {
                continue; // weight 0 (e.g. ln 0 of a zero miss factor): contributes nothing
            }
            let lw = -0.5 * qa;
            if !self.started {
                self.started = true;
                self.shift = lw;
            } else if lw - self.shift > RESCALE {
                // Rare: rescale the pattern's sums (inline: `self.scale` would alias `levs`).
                let s = math::exp(self.shift - lw);
                self.wd *= s;
                for (a, (((y, c), bl), m)) in self
                    .y
                    .iter_mut()
                    .zip(self.c.iter_mut())
                    .zip(self.bl.iter_mut())
                    .zip(mems.iter())
                    .enumerate()
                {
                    *y *= s;
                    for v in c.iter_mut().take(a + 1) {
                        *v *= s;
                    }
                    let mut mask = m.mask;
                    while mask != 0 {
                        if let Some(v) = bl.get_mut(mask.trailing_zeros() as usize) {
                            *v *= s;
                        }
                        mask &= mask - 1;
                    }
                }
                self.shift = lw;
            }
            let w = math::exp(lw - self.shift);
            self.wd += w;
            let r = &lv.r;
            for (a, ((y, crow), ra)) in self
                .y
                .iter_mut()
                .zip(self.c.iter_mut())
                .zip(r.iter())
                .enumerate()
                .take(k)
            {
                let wr = w * ra;
                *y += wr;
                for (cv, rc) in crow.iter_mut().zip(r.iter()).take(a + 1) {
                    *cv -= wr * rc;
                }
            }
            for (p, brow) in prev
                .iter()
                .map(|p| p.pick)
                .chain(core::iter::once(j))
                .zip(self.bl.iter_mut())
            {
                if let Some(b) = brow.get_mut(p as usize) {
                    *b += w;
                }
            }
        }
        if self.wd > 0.0 {
            // wd S⁻¹ = Σ_b (wd / d_b) (L⁻¹)_bᵀ (L⁻¹)_b: row b of L⁻¹ has entries 0..=b.
            for (b, mb) in mems.iter().enumerate() {
                let coef = self.wd * mb.invd;
                for (a, (crow, lia)) in self.c.iter_mut().zip(mb.li.iter()).enumerate().take(b + 1)
                {
                    let s = coef * lia;
                    for (cv, lic) in crow.iter_mut().zip(mb.li.iter()).take(a + 1) {
                        *cv += s * lic;
                    }
                }
            }
        }
    }
}

/// [`update_masked`] reporting its stages ([`Stage::Gating`], [`Stage::Events`],
/// [`Stage::Update`]) to `probe`.
///
/// # Complexity
/// As [`update`].
#[allow(non_snake_case, clippy::too_many_lines)]
pub fn update_probed<const NS: usize, const LANES: usize, P: Probe>(
    state: &mut Stacked<NS, LANES>,
    h: &SVector<f32, NS>,
    points: &[f32],
    params: &RowParams,
    max_events: usize,
    skip: u32,
    probe: &mut P,
) -> RowOutcome<LANES> {
    probe.enter(Stage::Gating);
    let mut out = RowOutcome::<LANES>::default();
    let (xs, ps, n) = state.parts_mut();
    let n = n.min(LANES);
    let m = points.len().min(MAX_ROW_POINTS);
    out.ignored_points = (points.len() - m) as u32;
    let points = points.get(..m).unwrap_or(&[]);
    if n == 0 {
        out.ignored_points += points.iter().filter(|z| !z.is_finite()).count() as u32;
        out.clutter_points = points.iter().filter(|z| z.is_finite()).count() as u32;
        return out;
    }
    let n_skipped = (0..n).filter(|t| skip & (1 << t) != 0).count();

    // Gating on each track's marginal (step 2), and G = P̄ H̄ᵀ, S̄ = H̄ P̄ H̄ᵀ + r I, on plain
    // arrays (`[f32; NS]` vectors, column-major blocks) so the small products unroll.
    let [hv] = h.data.0;
    let mut zhat = [0.0f32; LANES];
    let mut g = [[[0.0f32; NS]; LANES]; LANES]; // g[i][t] = P_it h
    for ((grow, prow), (x, zh)) in g
        .iter_mut()
        .zip(ps.iter())
        .zip(xs.iter().zip(zhat.iter_mut()))
        .take(n)
    {
        let [xv] = x.data.0;
        *zh = dot(&hv, &xv);
        for (gi, p) in grow.iter_mut().zip(prow.iter()).take(n) {
            *gi = mat_vec(p, &hv);
        }
    }
    // S̄ is symmetric: its upper triangle, mirrored.
    let mut sbar = [[0.0f32; LANES]; LANES];
    for (i, grow) in g.iter().enumerate().take(n) {
        for (t, gi) in grow.iter().enumerate().take(n).skip(i) {
            let v = dot(&hv, gi) + if i == t { params.r } else { 0.0 };
            put(&mut sbar, i, t, v);
            put(&mut sbar, t, i, v);
        }
    }
    let mut any_valid = 0u32;
    for (t, (srow, (zt, valid))) in sbar
        .iter()
        .zip(zhat.iter().zip(out.valid.iter_mut()))
        .enumerate()
        .take(n)
    {
        let st = get(srow, t);
        if !(st.is_finite() && st > 0.0) {
            out.failed = true;
            return out;
        }
        if skip & (1 << t) != 0 {
            continue;
        }
        let mut mask = 0u32;
        for (j, z) in points.iter().enumerate() {
            let e = z - zt;
            // Inclusive gate; a non-finite point gives NaN or inf and never passes.
            if e * e / st <= params.gamma {
                mask |= 1 << j;
            }
        }
        *valid = mask;
        any_valid |= mask;
    }
    for (j, z) in points.iter().enumerate() {
        if !z.is_finite() {
            out.ignored_points += 1;
        } else if any_valid & (1 << j) == 0 {
            out.clutter_points += 1;
        }
    }

    probe.enter(Stage::Events);
    let ln_pd = math::ln(params.pd);
    let missf = match params.miss {
        MissModel::Textbook => 1.0 - params.pd,
        MissModel::Gated => 1.0 - params.pd * params.pg,
    };
    let ln_miss = math::ln(missf);
    let ln_lambda = math::ln(params.clutter_density);
    let ln_2pi = math::ln(2.0 * core::f32::consts::PI);

    // Bounded enumeration (step 5): when the events do not fit, drop candidates in order of their
    // single-track PDA probability `p_tj = L_tj / (1 − P_D P_G + Σ_j' L_tj')`,
    // `L_tj = P_D N(z_j; ẑ_t, S_t) / λ_c` — the least likely first, whatever track they belong to,
    // so a track keeps its plausible points — until the bound Π (1 + n_t) fits the budget.
    // The bound is an upper bound of the event count, so the exact count is only needed when it
    // exceeds the budget.
    let budget = max_events.max(1) as u64;
    let bound = |valid: &[u32; LANES]| -> u64 {
        valid
            .iter()
            .take(n)
            .map(|v| 1 + u64::from(v.count_ones()))
            .product()
    };
    if bound(&out.valid) > budget && count_events(&out.valid, n, budget) > budget {
        out.approximated = true;
        prune(
            &mut out,
            &sbar,
            &zhat,
            points,
            n,
            budget,
            ln_pd - ln_lambda,
            ln_miss,
            ln_2pi,
        );
    }

    // Event weights (step 3) and the mixture moments (step 4). The detection patterns are the
    // subsets of the eligible tracks (not skipped, at least one candidate), visited depth first
    // so that each extends its parent's factor by one row; a pattern without events has no
    // descendant with events, so its subtree is skipped. Weights are relative to a reference
    // raised only by more than `RESCALE` at a time (per pattern and over the patterns).
    let mut elig = [0u8; LANES];
    let mut na = 0usize;
    for (t, v) in out.valid.iter().enumerate().take(n) {
        if skip & (1 << t) == 0 && *v != 0 {
            set(&mut elig, na, t as u8);
            na += 1;
        }
    }
    let active = (n - n_skipped) as f32;
    let mut gstarted = false;
    let mut gmax = 0.0f32;
    let mut wtot = 0.0f32;
    let mut y = [0.0f32; LANES];
    let mut c = [[0.0f32; LANES]; LANES]; // lower triangle
    let mut bmiss = [0.0f32; LANES];
    let mut wk = Work::<LANES>::new();
    let mut next = 0usize;
    let mut descend = true;
    let mut first = true;
    loop {
        if first {
            first = false; // the empty pattern (every track missed)
        } else if descend && next < na {
            let t = usize::from(get(&elig, next));
            let srow = sbar.get(t).copied().unwrap_or([0.0; LANES]);
            if !wk.push(next, t, &srow, get(&out.valid, t), get(&zhat, t)) {
                return failed(out);
            }
        } else {
            let Some(last) = wk.members().last() else {
                break;
            };
            next = usize::from(last.pos) + 1;
            wk.k -= 1;
            descend = true;
            continue;
        }
        let k = wk.k;
        out.patterns += 1;
        let kf = k as f32;
        let base = -0.5 * wk.logdet() - 0.5 * kf * ln_2pi
            + kf * (ln_pd - ln_lambda)
            + (active - kf) * ln_miss;
        wk.score(points, base.is_finite());
        out.events += wk.events;
        descend = wk.events > 0;
        next = wk.members().last().map_or(0, |m| usize::from(m.pos) + 1);
        if !(wk.wd > 0.0 && wk.wd.is_finite()) {
            continue;
        }
        let eff = base + wk.shift;
        if !gstarted {
            gstarted = true;
            gmax = eff;
        } else if eff - gmax > RESCALE {
            let s = math::exp(gmax - eff);
            wtot *= s;
            for (t, (((yv, bm), crow), brow)) in y
                .iter_mut()
                .zip(bmiss.iter_mut())
                .zip(c.iter_mut())
                .zip(out.beta.iter_mut())
                .enumerate()
                .take(n)
            {
                *yv *= s;
                *bm *= s;
                for v in crow.iter_mut().take(t + 1) {
                    *v *= s;
                }
                for v in brow.iter_mut().take(m) {
                    *v *= s;
                }
            }
            gmax = eff;
        }
        let f = math::exp(eff - gmax);
        let wd = wk.wd * f;
        wtot += wd;
        let mut missed = !skip;
        for (a, mb) in wk.members().iter().enumerate() {
            let ta = usize::from(mb.tr);
            missed &= !(1 << ta);
            if let Some(v) = y.get_mut(ta) {
                *v += f * get(&wk.y, a);
            }
            if let (Some(crow), Some(src)) = (c.get_mut(ta), wk.c.get(a)) {
                for (mb2, s) in wk.mem.iter().zip(src.iter()).take(a + 1) {
                    if let Some(v) = crow.get_mut(usize::from(mb2.tr)) {
                        *v += f * s;
                    }
                }
            }
            if let (Some(brow), Some(src)) = (out.beta.get_mut(ta), wk.bl.get(a)) {
                let mut mask = mb.mask;
                while mask != 0 {
                    let j = mask.trailing_zeros() as usize;
                    if let (Some(d), Some(s)) = (brow.get_mut(j), src.get(j)) {
                        *d += f * s;
                    }
                    mask &= mask - 1;
                }
            }
        }
        for (t, b) in bmiss.iter_mut().enumerate().take(n) {
            if missed & (1 << t) != 0 {
                *b += wd;
            }
        }
    }
    probe.enter(Stage::Update);
    if !(wtot.is_finite() && wtot > 0.0) {
        return failed(out);
    }
    let inv = 1.0 / wtot;
    // C' = C + y yᵀ (full, symmetric), so that P⁺ = P̄ − G C' Gᵀ and x⁺ = x̄ + G y.
    for v in y.iter_mut().take(n) {
        *v *= inv;
    }
    for t in 0..n {
        let yt = get(&y, t);
        for tp in 0..=t {
            let v = at(&c, t, tp) * inv + yt * get(&y, tp);
            put(&mut c, t, tp, v);
            put(&mut c, tp, t, v);
        }
    }
    // u[i][t'] = Σ_t g[i][t] C'[t][t'], dx[i] = Σ_t g[i][t] y[t].
    let gn = g.get(..n).unwrap_or(&[]);
    let yn = y.get(..n).unwrap_or(&[]);
    let cn = c.get(..n).unwrap_or(&[]);
    let mut dx = [[0.0f32; NS]; LANES];
    let mut u = [[[0.0f32; NS]; LANES]; LANES];
    for ((gi, d), ui) in gn.iter().zip(dx.iter_mut()).zip(u.iter_mut()) {
        let ui = ui.get_mut(..n).unwrap_or(&mut []);
        for ((git, yt), crow) in gi.iter().zip(yn.iter()).zip(cn.iter()) {
            axpy(d, *yt, git);
            for (uit, ctt) in ui.iter_mut().zip(crow.iter()) {
                axpy(uit, *ctt, git);
            }
        }
    }
    // P⁺_ij = P̄_ij − Σ_t' u[i][t'] g[j][t']ᵀ for the upper blocks (diagonal blocks symmetrised),
    // staged and committed (with the mirrored lower blocks) only if everything is finite.
    let mut newp = [[[[0.0f32; NS]; NS]; LANES]; LANES];
    let mut bad = dx.iter().take(n).any(|d| d.iter().any(|v| !v.is_finite()));
    for (i, ((ui, prow), nrow)) in u
        .iter()
        .zip(ps.iter())
        .zip(newp.iter_mut())
        .enumerate()
        .take(n)
    {
        let ui = ui.get(..n).unwrap_or(&[]);
        for (j, ((gj, pij), blk)) in gn
            .iter()
            .zip(prow.iter())
            .zip(nrow.iter_mut())
            .enumerate()
            .skip(i)
        {
            *blk = pij.data.0;
            // Column b of the block: P_·b − Σ_t u_t g_t[b].
            for (uv, gv) in ui.iter().zip(gj.iter()) {
                for (col, gb) in blk.iter_mut().zip(gv.iter()) {
                    for (e, ua) in col.iter_mut().zip(uv.iter()) {
                        *e -= ua * gb;
                    }
                }
            }
            if i == j {
                for a in 0..NS {
                    for b in 0..a {
                        let v = 0.5 * (at(blk, a, b) + at(blk, b, a));
                        put(blk, a, b, v);
                        put(blk, b, a, v);
                    }
                }
            }
            bad |= blk.iter().any(|col| col.iter().any(|v| !v.is_finite()));
        }
    }
    if bad {
        return failed(out);
    }
    for (i, nrow) in newp.iter().enumerate().take(n) {
        for (j, blk) in nrow.iter().enumerate().take(n).skip(i) {
            let m = SMatrix::<f32, NS, NS>::from_data(nalgebra::ArrayStorage(*blk));
            if let Some(b) = ps.get_mut(i).and_then(|r| r.get_mut(j)) {
                *b = m;
            }
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
    for (t, (bm, brow)) in out
        .beta_miss
        .iter_mut()
        .zip(out.beta.iter_mut())
        .enumerate()
        .take(n)
    {
        *bm = if skip & (1 << t) != 0 {
            1.0
        } else {
            get(&bmiss, t) * inv
        };
        for v in brow.iter_mut().take(m) {
            *v *= inv;
        }
    }
    out
}

/// Drops (track, point) candidates in order of increasing single-track PDA probability until
/// the bound `Π (1 + n_t)` on the event count fits `budget` (step 5); `ln_pd_lambda` is
/// `ln P_D − ln λ_c`.
///
/// # Complexity
/// `O(C log C)` for the `C ≤ n·m` candidates; 4 KiB of stack for the candidate list.
#[allow(clippy::too_many_arguments)]
fn prune<const LANES: usize>(
    out: &mut RowOutcome<LANES>,
    sbar: &[[f32; LANES]; LANES],
    zhat: &[f32; LANES],
    points: &[f32],
    n: usize,
    budget: u64,
    ln_pd_lambda: f32,
    ln_miss: f32,
    ln_2pi: f32,
) {
    let mut cand = [(0.0f32, 0u8, 0u8); CANDIDATES];
    let mut nc = 0usize;
    for t in 0..n {
        let st = at(sbar, t, t);
        let zt = get(zhat, t);
        let ln_norm = ln_pd_lambda - 0.5 * (ln_2pi + math::ln(st));
        let mask = get(&out.valid, t);
        let first = nc;
        let mut lmax = ln_miss;
        for (j, z) in points.iter().enumerate() {
            if mask & (1 << j) != 0 {
                let e = z - zt;
                let l = ln_norm - 0.5 * (e * e / st);
                lmax = lmax.max(l);
                set(&mut cand, nc, (l, t as u8, j as u8));
                nc += 1;
            }
        }
        // log-sum-exp over the miss and the candidates, then normalise in place.
        let mut sum = math::exp(ln_miss - lmax);
        for c in cand.iter().take(nc).skip(first) {
            sum += math::exp(c.0 - lmax);
        }
        let ln_total = lmax + math::ln(sum);
        for c in cand.iter_mut().take(nc).skip(first) {
            c.0 -= ln_total;
        }
    }
    if let Some(c) = cand.get_mut(..nc) {
        c.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    }
    for &(_, t, j) in cand.iter().take(nc) {
        let bound: u64 = out
            .valid
            .iter()
            .take(n)
            .map(|v| 1 + u64::from(v.count_ones()))
            .product();
        if bound <= budget {
            break;
        }
        let t = usize::from(t);
        let mask = get(&out.valid, t) & !(1u32 << j);
        set(&mut out.valid, t, mask);
        out.dropped_candidates += 1;
    }
}

/// Marks `out` failed, with the weights of an untouched row (β cleared, every track missed).
fn failed<const LANES: usize>(mut out: RowOutcome<LANES>) -> RowOutcome<LANES> {
    out.failed = true;
    out.beta = [[0.0; MAX_ROW_POINTS]; LANES];
    out.beta_miss = [1.0; LANES];
    out
}

/// Element `(i, j)` of a fixed 2-D array, or 0 past its end.
#[inline]
fn at<const R: usize, const C: usize>(a: &[[f32; C]; R], i: usize, j: usize) -> f32 {
    a.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0)
}

/// `a · b`.
#[inline(always)]
fn dot<const N: usize>(a: &[f32; N], b: &[f32; N]) -> f32 {
    a.iter().zip(b.iter()).map(|(x, y)| x * y).sum()
}

/// `P h` for a column-major block `P` (columns where `h` is zero are skipped: `h = [1, 1, 0, …]`
/// has zeros).
#[inline(always)]
fn mat_vec<const N: usize>(p: &SMatrix<f32, N, N>, h: &[f32; N]) -> [f32; N] {
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
fn axpy<const N: usize>(y: &mut [f32; N], a: f32, x: &[f32; N]) {
    for (yv, xv) in y.iter_mut().zip(x.iter()) {
        *yv += a * xv;
    }
}

/// Sets element `(i, j)` of a fixed 2-D array (no-op past its end).
#[inline]
fn put<const R: usize, const C: usize>(a: &mut [[f32; C]; R], i: usize, j: usize, v: f32) {
    if let Some(e) = a.get_mut(i).and_then(|r| r.get_mut(j)) {
        *e = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assignments_enumerate_injective_maps() {
        // Two tracks, both valid for points 0 and 1: (0,1) and (1,0).
        let mut it = Assignments::<3>::new([0b11, 0b11, 0], 2);
        let mut got = heapless::Vec::<[u8; 2], 8>::new();
        while let Some(p) = it.next() {
            got.push([p[0], p[1]]).unwrap();
        }
        assert_eq!(got.as_slice(), &[[0, 1], [1, 0]]);
        let mut it = Assignments::<3>::new([0b1, 0b1, 0], 2);
        assert!(it.next().is_none());
        let mut it = Assignments::<3>::new([0; 3], 0);
        assert!(it.next().is_some() && it.next().is_none());
    }

    #[test]
    fn event_count_matches_formula_for_full_gating() {
        // Σ_k C(D,k) C(m,k) k!: D = 3, m = 4 → 1 + 12 + 36 + 24 = 73.
        assert_eq!(count_events(&[0b1111u32; 3], 3, 1000), 73);
        assert_eq!(count_events(&[0b1111u32; 3], 3, 10), 11);
    }
}
