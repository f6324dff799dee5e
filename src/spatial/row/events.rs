//! Joint-event enumeration and scoring of one row (docs/design.md §4.1 steps 3–5): the event
//! count, the detection-pattern tree with its incremental `L D Lᵀ` factors, and the one-pass
//! accumulation of the mixture sums (see the parent module for the method and its bounds).

use super::*;

/// Counts the joint events (each of the first `n` tracks missed or assigned one point of its
/// mask, no point twice) up to `limit + 1`: an explicit-stack walk over the tracks (depth ≤ n)
/// whose last level is counted in one step (`1 + |mask ∖ used|`), stopping once past `limit`.
///
/// # Complexity
/// `O(min(events, limit) / (1 + m_last))` steps, no recursion.
pub(super) fn count_events<const L: usize>(valid: &[u32; L], n: usize, limit: u64) -> u64 {
    const MISS: u64 = 1 << 32;
    let n = n.min(L);
    let Some(last) = n.checked_sub(1) else {
        return 1;
    };
    let last_mask = get(valid, last);
    let mut opt = [0u64; L]; // options left per level: bit 32 = missed, bits 0..32 = points
    let mut pick = [0u32; L];
    let mut used = 0u32;
    let mut depth = 0usize;
    let mut total = 0u64;
    set(&mut opt, 0, MISS | u64::from(get(valid, 0)));
    loop {
        if depth == last {
            total += 1 + u64::from((last_mask & !used).count_ones());
            if total > limit {
                return limit + 1;
            }
        } else {
            let o = get(&opt, depth);
            if o != 0 {
                set(&mut opt, depth, o & o.wrapping_sub(1));
                let bit = match o.trailing_zeros() {
                    32 => 0,
                    b => 1u32.wrapping_shl(b),
                };
                set(&mut pick, depth, bit);
                used |= bit;
                depth += 1;
                set(&mut opt, depth, MISS | u64::from(get(valid, depth) & !used));
                continue;
            }
        }
        // This level is done: back to the previous one.
        let Some(up) = depth.checked_sub(1) else {
            return total;
        };
        depth = up;
        used &= !get(&pick, depth);
    }
}

/// A pass weighs events by `e^{lw − ref}`; when its largest log-weight `lw` ends up more than
/// this (natural-log units) away from `ref`, the pass is redone with `ref` at that maximum. The
/// first pass takes `ref` = the all-missed event's log-weight, which no event undercuts by more
/// than the sum of the per-track detection gains (≈ 6.5 per track with the defaults), so the
/// redo only happens with extreme parameters.
pub(super) const WINDOW: f32 = 60.0;

/// One member of the current detection pattern (its tracks in increasing order): its row of the
/// `LDLᵀ` factor of `S_δ` and of `L⁻¹`. A pattern's factor is its parent's (the pattern without
/// its highest track) plus one row, so a pattern costs `O(k²)`, not `O(k³)`.
#[derive(Clone, Copy)]
struct Member<const L: usize> {
    /// Track index.
    tr: u8,
    /// Position in the list of eligible tracks.
    pos: u8,
    /// Gate mask.
    mask: u32,
    /// The tracks of the pattern ending with this member (bit `t` = track `t`).
    set: u32,
    /// Predicted measurement `ẑ_t`.
    zh: f32,
    /// `1 / d_a`.
    invd: f32,
    /// `ln det` of the leading `a + 1` members' `S`.
    logdet: f32,
    /// The leading `a + 1` members' detection-odds offsets summed ([`Ctx::odds`]).
    odds: f32,
    /// Row `a` of the unit lower factor `L`, in member coordinates (entries `b < a`).
    l: [f32; L],
    /// Row `a` of `L⁻¹` in track coordinates (`li[tr_b] = (L⁻¹)_ab`, `li[tr] = 1`, the rest 0).
    li: [f32; L],
    /// Total event weight of the patterns in this member's subtree of the pattern tree (the
    /// pattern ending with this member and its descendants), for `Σ_δ wd_δ S_δ⁻¹`.
    wsub: f32,
}

impl<const L: usize> Member<L> {
    const EMPTY: Self = Self {
        tr: 0,
        pos: 0,
        mask: 0,
        set: 0,
        zh: 0.0,
        invd: 0.0,
        logdet: 0.0,
        odds: 0.0,
        l: [0.0; L],
        li: [0.0; L],
        wsub: 0.0,
    };
}

/// One node of a pattern's event tree (members `0..=a` assigned): the candidates left at this
/// level, the pick, the running forward substitution (`u_a`, `e_a = u_a / d_a`,
/// `q = Σ u_b e_b`, `r = Σ_b e_b (L⁻¹)_bᵀ`, i.e. `S⁻¹ ν` of the members so far, in track
/// coordinates) and the weight of the node's finished subtree.
#[derive(Clone, Copy)]
struct Level<const L: usize> {
    rem: u32,
    pick: u32,
    u: f32,
    q: f32,
    w: f32,
    r: [f32; L],
}

impl<const L: usize> Level<L> {
    const EMPTY: Self = Self {
        rem: 0,
        pick: 0,
        u: 0.0,
        q: 0.0,
        w: 0.0,
        r: [0.0; L],
    };
}

/// The mixture sums of a row, in track coordinates and units of `e^{−ref}`:
/// `wtot = Σ w`, `y = Σ w S_δ⁻¹ ν`, `c = Σ w (S_δ⁻¹ − S_δ⁻¹ ν νᵀ S_δ⁻¹)` (lower triangle, padded
/// with zeros outside the pattern), `bmiss[t] = Σ_{t missed} w`, `beta[t][j] = Σ_{t→j} w`.
#[derive(Clone)]
pub(super) struct Acc<const L: usize> {
    pub(super) wtot: f32,
    pub(super) y: [f32; L],
    pub(super) c: [[f32; L]; L],
    pub(super) bmiss: [f32; L],
    pub(super) beta: [[f32; MAX_ROW_POINTS]; L],
    pub(super) lwmax: f32,
    pub(super) events: u32,
    pub(super) patterns: u32,
}

impl<const L: usize> Acc<L> {
    /// Every byte zero: reset ([`Acc::reset`]) before a pass reads it. A fresh accumulator is
    /// all zero but `lwmax = −∞`.
    pub(super) const ZEROED: Self = Self {
        wtot: 0.0,
        y: [0.0; L],
        c: [[0.0; L]; L],
        bmiss: [0.0; L],
        beta: [[0.0; MAX_ROW_POINTS]; L],
        lwmax: 0.0,
        events: 0,
        patterns: 0,
    };

    /// Back to a fresh accumulator, given that every nonzero `β` entry lies in the first `rows`
    /// rows and `cols` columns (a row's tracks and points: [`Acc::pick`] writes nothing else):
    /// clearing all `LANES × MAX_ROW_POINTS` is a memclr of about 1 KiB on the Cortex-M4F, where
    /// a row has a few points.
    pub(super) fn reset(&mut self, rows: usize, cols: usize) {
        self.wtot = 0.0;
        self.y = [0.0; L];
        self.c = [[0.0; L]; L];
        self.bmiss = [0.0; L];
        self.lwmax = f32::NEG_INFINITY;
        self.events = 0;
        self.patterns = 0;
        crate::linalg::zero_block(&mut self.beta, rows, cols);
    }

    /// Back to a fresh accumulator after a pass over the tracks of `set` (bit `t`): a pass
    /// writes only its members' rows and columns (`y`, `C`, `β_miss`, `β`; a non-member's
    /// entries stay `+0.0`), so only those are cleared.
    pub(super) fn clear_tracks(&mut self, set: u32) {
        self.wtot = 0.0;
        self.lwmax = f32::NEG_INFINITY;
        self.events = 0;
        self.patterns = 0;
        let mut rest = set;
        while rest != 0 {
            let t = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            if let Some(v) = self.y.get_mut(t) {
                *v = 0.0;
            }
            if let Some(v) = self.bmiss.get_mut(t) {
                *v = 0.0;
            }
            if let Some(row) = self.beta.get_mut(t) {
                *row = [0.0; MAX_ROW_POINTS];
            }
            if let Some(row) = self.c.get_mut(t) {
                *row = [0.0; L];
            }
            for row in self.c.iter_mut() {
                if let Some(v) = row.get_mut(t) {
                    *v = 0.0;
                }
            }
        }
    }

    /// `β[t][j] += w` for member `mb` picking point `j` in events of total weight `w`.
    #[inline(always)]
    fn pick(&mut self, mb: &Member<L>, j: u32, w: f32) {
        if let Some(b) = self
            .beta
            .get_mut(usize::from(mb.tr))
            .and_then(|r| r.get_mut(j as usize))
        {
            *b += w;
        }
    }

    /// Adds an event of weight `w` with `r = S_δ⁻¹ ν`: `y += w r`, `c −= w r rᵀ` over the
    /// tracks `0..hi` (`r` is zero past the pattern's highest track).
    #[inline(always)]
    fn event(&mut self, r: &[f32; L], hi: usize, w: f32) {
        let r = r.get(..hi).unwrap_or(&[]);
        for (p, ((yp, crow), rp)) in self
            .y
            .iter_mut()
            .zip(self.c.iter_mut())
            .zip(r.iter())
            .enumerate()
        {
            let wr = w * rp;
            *yp += wr;
            for (cv, rq) in crow.iter_mut().zip(r.iter()).take(p + 1) {
                *cv -= wr * rq;
            }
        }
    }

    /// Adds `w (L⁻¹)_aᵀ (1/d_a) (L⁻¹)_a` for member `mb` (`w` the weight of the patterns
    /// containing the member's prefix): summed over the pattern tree, `Σ_δ wd_δ S_δ⁻¹`, at one
    /// `O(t²)` outer product per pattern instead of `O(k³)`.
    #[inline(always)]
    fn inverse_term(&mut self, mb: &Member<L>, w: f32) {
        if w == 0.0 {
            return;
        }
        let hi = (usize::from(mb.tr) + 1).min(L);
        let li = mb.li.get(..hi).unwrap_or(&[]);
        let s = w * mb.invd;
        for (p, (crow, lip)) in self.c.iter_mut().zip(li.iter()).enumerate() {
            let a = s * lip;
            for (cv, liq) in crow.iter_mut().zip(li.iter()).take(p + 1) {
                *cv += a * liq;
            }
        }
    }
}

/// The pattern and event-tree arrays of [`Ctx::pass`], kept by the caller for all the passes of
/// row and from row to row: every entry is written before it is read, and clearing them for
/// each pass was a ~800-byte memclr per cluster on the Cortex-M4F.
#[derive(Clone)]
pub(crate) struct Scratch<const L: usize> {
    mems: [Member<L>; L],
    lev: [Level<L>; L],
}

impl<const L: usize> Scratch<L> {
    /// Arrays for the passes of any number of rows.
    pub(crate) const fn new() -> Self {
        Self {
            mems: [Member::<L>::EMPTY; L],
            lev: [Level::<L>::EMPTY; L],
        }
    }
}

/// What a row's event pass needs: the tracks, their predicted measurements and joint
/// innovation covariance, gate masks, points and the log-weight constants.
pub(super) struct Ctx<'a, const L: usize> {
    pub(super) elig: [u8; L],
    pub(super) na: usize,
    pub(super) sbar: &'a [[f32; L]; L],
    pub(super) zhat: &'a [f32; L],
    pub(super) valid: &'a [u32; L],
    pub(super) points: &'a [f32],
    pub(super) ln_2pi: f32,
    pub(super) ln_pd_lambda: f32,
    pub(super) ln_miss: f32,
    /// Per track, `ln` of its detection odds `P_D,t / (λ_c · miss_t)` less the row's
    /// `P_D / (λ_c · miss)`: 0 for a track at the row's `P_D` (docs/design.md §11.3).
    pub(super) odds: &'a [f32; L],
    pub(super) active: f32,
    /// The tracks that can be missed (bit `t`): the first `n`, not masked.
    pub(super) active_set: u32,
    /// `true`: the pass also sums the moments `y` and `C` of the state update; `false`: only
    /// the association probabilities (`β`, `β_miss`, `Σ w`), which need neither `r = S_δ⁻¹ ν`
    /// nor the `S_δ⁻¹` terms (the known-lane stage).
    pub(super) moments: bool,
}

impl<const L: usize> Ctx<'_, L> {
    /// Log-weight of a pattern with `k` detected tracks, `ln det S_δ = logdet` and the
    /// detected tracks' odds offsets summed `odds`, before the events' Mahalanobis terms
    /// (docs/design.md §4.1 step 3).
    pub(super) fn base(&self, k: usize, logdet: f32, odds: f32) -> f32 {
        let kf = k as f32;
        -0.5 * logdet - 0.5 * kf * self.ln_2pi
            + kf * self.ln_pd_lambda
            + (self.active - kf) * self.ln_miss
            + odds
    }

    /// Appends eligible track `pos` to the pattern `mems[..k]` as member `k` and computes its
    /// factor row (`f_b = S_tb − Σ_{c<b} l_bc f_c`, `l_kb = f_b / d_b`,
    /// `d_k = S_tt − Σ_b l_kb f_b`) and, when the pass sums moments, its row of `L⁻¹`
    /// (`e_t − Σ_b l_kb (L⁻¹)_b`). `false` when
    /// `d_k` is not positive and finite (`S_δ` not positive definite).
    fn push(&self, mems: &mut [Member<L>; L], k: usize, pos: usize) -> bool {
        let t = usize::from(get(&self.elig, pos));
        let Some((done, rest)) = mems.split_at_mut_checked(k) else {
            return false;
        };
        let (Some(new), Some(srow)) = (rest.first_mut(), self.sbar.get(t)) else {
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
        if self.moments {
            for (lkb, mb) in l.iter().zip(done.iter()) {
                let hi = usize::from(mb.tr) + 1;
                for (v, w) in li.iter_mut().zip(mb.li.iter()).take(hi) {
                    *v -= lkb * w;
                }
            }
            set(&mut li, t, 1.0);
        }
        *new = Member {
            tr: t as u8,
            pos: pos as u8,
            mask: get(self.valid, t),
            set: done.last().map_or(0, |m| m.set) | (1 << t),
            zh: get(self.zhat, t),
            invd: 1.0 / dk,
            logdet: done.last().map_or(0.0, |m| m.logdet) + math::ln(dk),
            odds: done.last().map_or(0.0, |m| m.odds) + get(self.odds, t),
            l,
            li,
            wsub: 0.0,
        };
        true
    }

    /// Scores the events of the pattern `mems` (injective assignments of its members to points
    /// of their masks; explicit stack, depth ≤ k) into `acc`; returns the number of events and
    /// their total weight. A member's pick extends `u`, `e`, `q` and `r` by one term; a node's
    /// sums are added once its subtree is finished ([`Acc::finish`]).
    fn score(
        &self,
        mems: &[Member<L>],
        base: f32,
        reference: f32,
        lev: &mut [Level<L>; L],
        acc: &mut Acc<L>,
    ) -> (u32, f32) {
        let weighted = base.is_finite();
        let k = mems.len().min(L);
        let Some(m0) = mems.first() else {
            // The all-missed event.
            if !weighted {
                return (1, 0.0);
            }
            acc.lwmax = math::max(acc.lwmax, base);
            return (1, math::exp(base - reference));
        };
        let levs = lev.get_mut(..k).unwrap_or(&mut []);
        if let Some(l0) = levs.first_mut() {
            l0.rem = m0.mask;
        }
        let mut events = 0u32;
        let mut wd = 0.0f32;
        let mut used = 0u32;
        let mut depth = 0usize;
        // Each pass descends (≤ k), takes a candidate or ascends: bounded by the event tree.
        while let Some((prev, cur)) = levs.split_at_mut_checked(depth) {
            let (Some((lv, below)), Some(mb)) = (cur.split_first_mut(), mems.get(depth)) else {
                break;
            };
            if lv.rem == 0 {
                // Every child of the node one level up is done: finish it.
                let Some((pl, upper)) = prev.split_last_mut() else {
                    break;
                };
                if let Some(pm) = mems.get(depth - 1) {
                    acc.pick(pm, pl.pick, pl.w);
                }
                match upper.last_mut() {
                    Some(gp) => gp.w += pl.w,
                    None => wd += pl.w,
                }
                used &= !(1u32.wrapping_shl(pl.pick));
                depth -= 1;
                continue;
            }
            let hi = (usize::from(mb.tr) + 1).min(L);
            if below.is_empty() {
                // The last member: every remaining candidate is a leaf (one joint event) and the
                // forward substitution's prefix `ẑ + Σ_b l_b u_b` is shared by all of them.
                let mut c = mb.zh;
                for (lb, pl) in mb.l.iter().zip(prev.iter()) {
                    c += lb * pl.u;
                }
                let (q0, r0) = prev.last().map_or((0.0, [0.0; L]), |p| (p.q, p.r));
                let mut rem = lv.rem;
                lv.rem = 0;
                let mut wsum = 0.0f32;
                while rem != 0 {
                    let j = rem.trailing_zeros();
                    rem &= rem.wrapping_sub(1);
                    events += 1;
                    let ua = self.points.get(j as usize).copied().unwrap_or(0.0) - c;
                    let ea = ua * mb.invd;
                    let q = q0 + ua * ea;
                    if !(weighted && q.is_finite()) {
                        continue; // weight 0 (e.g. ln 0 of a zero miss factor): no contribution
                    }
                    let lw = base - 0.5 * q;
                    acc.lwmax = math::max(acc.lwmax, lw);
                    let w = math::exp(lw - reference);
                    acc.pick(mb, j, w);
                    if self.moments {
                        for ((v, pv), li) in lv.r.iter_mut().zip(r0.iter()).zip(mb.li.iter()) {
                            *v = pv + ea * li;
                        }
                        acc.event(&lv.r, hi, w);
                    }
                    wsum += w;
                }
                match prev.last_mut() {
                    Some(p) => p.w += wsum,
                    None => wd += wsum,
                }
                continue;
            }
            let j = lv.rem.trailing_zeros();
            lv.rem &= lv.rem.wrapping_sub(1);
            lv.pick = j;
            let mut ua = self.points.get(j as usize).copied().unwrap_or(0.0) - mb.zh;
            for (lb, pl) in mb.l.iter().zip(prev.iter()) {
                ua -= lb * pl.u;
            }
            let ea = ua * mb.invd;
            lv.u = ua;
            // All L entries, so that r stays zero past the highest member's track.
            match prev.last() {
                Some(p) => {
                    lv.q = p.q + ua * ea;
                    if self.moments {
                        for ((v, pv), w) in lv.r.iter_mut().zip(p.r.iter()).zip(mb.li.iter()) {
                            *v = pv + ea * w;
                        }
                    }
                }
                None => {
                    lv.q = ua * ea;
                    if self.moments {
                        for (v, w) in lv.r.iter_mut().zip(mb.li.iter()) {
                            *v = ea * w;
                        }
                    }
                }
            }
            if let Some(next) = below.first_mut() {
                lv.w = 0.0;
                used |= 1u32.wrapping_shl(j);
                depth += 1;
                next.rem = mems.get(depth).map_or(0, |m| m.mask) & !used;
            }
        }
        (events, wd)
    }

    /// One pass over the detection patterns (the subsets of the eligible tracks, depth first, so
    /// that each extends its parent's factor by one row; a pattern without events has no
    /// descendant with events, so its subtree is skipped), weights `e^{lw − reference}`.
    /// `false` when some `S_δ` is not positive definite.
    pub(super) fn pass(&self, reference: f32, acc: &mut Acc<L>, scratch: &mut Scratch<L>) -> bool {
        let Scratch { mems, lev } = scratch;
        let mut k = 0usize;
        let mut next = 0usize;
        let mut descend = true;
        let mut first = true;
        loop {
            if first {
                first = false; // the empty pattern (every track missed)
            } else if descend && next < self.na {
                if !self.push(mems, k, next) {
                    return false;
                }
                k += 1;
            } else {
                // Pattern tree: the member's subtree is done; add its S⁻¹ term, pass its weight up.
                let Some(a) = k.checked_sub(1) else {
                    break;
                };
                let Some((head, tail)) = mems.split_at_mut_checked(a) else {
                    break;
                };
                let Some(last) = tail.first() else {
                    break;
                };
                if self.moments {
                    acc.inverse_term(last, last.wsub);
                }
                if let Some(parent) = head.last_mut() {
                    parent.wsub += last.wsub;
                }
                next = usize::from(last.pos) + 1;
                k = a;
                descend = true;
                continue;
            }
            acc.patterns += 1;
            let pattern = mems.get(..k).unwrap_or(&[]);
            let (logdet, odds) = pattern.last().map_or((0.0, 0.0), |m| (m.logdet, m.odds));
            let base = self.base(k, logdet, odds);
            let (events, wd) = self.score(pattern, base, reference, lev, acc);
            acc.events += events;
            descend = events > 0;
            next = pattern.last().map_or(0, |m| usize::from(m.pos) + 1);
            if wd > 0.0 {
                let mut missed = self.active_set;
                if let Some(last) = k.checked_sub(1).and_then(|a| mems.get_mut(a)) {
                    last.wsub += wd;
                    missed &= !last.set;
                }
                acc.wtot += wd;
                while missed != 0 {
                    if let Some(b) = acc.bmiss.get_mut(missed.trailing_zeros() as usize) {
                        *b += wd;
                    }
                    missed &= missed - 1;
                }
            }
        }
        true
    }
}
