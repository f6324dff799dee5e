//! The step's later stages on the live lanes: the known-lane pass against the predictions,
//! existence, deletion and merging of duplicates (docs/design.md §11); the extent and id
//! histories, the filtered and smoothed lanes, lane ranks and a lane's position anywhere in the
//! window.

use heapless::Vec;
use nalgebra::SVector;

use crate::linalg::{get, set};
use crate::persist::{Evidence, Explained, Lanes, Pass};
use crate::probe::{Probe, Stage};
use crate::spatial::filter::SpatialFilter;
use crate::temporal::filter::TemporalFilter;
use crate::temporal::identity::SlotFate;

use super::{LaneEstimate, StepReport, Tracker, NO_INFO};

impl_tracker! {
    /// Step 3 (docs/design.md §11): the live lanes' row evidence against their prediction, the
    /// temporal update with it, their existence; the points they explain leave the rows.
    /// Returns the lanes seen (bit = slot).
    #[inline(never)]
    pub(super) fn known_lanes<P: Probe>(&mut self, report: &mut StepReport, probe: &mut P) -> u32 {
        let Some(pass) = self.pass() else {
            return 0;
        };
        let mut live = 0u32;
        for s in 0..LANES {
            if self.temporal.filter().is_active(s) && self.ids.lane(s).is_some() {
                live |= 1 << s;
            }
        }
        self.basis.ensure(self.tables, &pass);
        let mut explained: Explained<ROWS> = [0; ROWS];
        let mut ev = [Evidence::<RANK>::NONE; LANES];
        if live != 0 {
            let last = pass.rows.saturating_sub(1).min(usize::from(u16::MAX)) as u16;
            let lanes = Lanes {
                slots: live,
                ranks: &self.ranks,
                rows: [(0, last); LANES],
            };
            let spatial = &self.spatial;
            let counts = self.persist.associate(
                self.tables,
                &self.basis,
                self.temporal.filter(),
                &lanes,
                &pass,
                &self.cfg.persist,
                |r| spatial.row_points(r),
                true,
                &mut ev,
                &mut explained,
            );
            report.known.failed_rows = counts.failed_rows;
            report.known.events = counts.events;
            report.known.pruned_rows = counts.pruned_rows;
            report.known.lbp_rows = counts.lbp_rows;
            report.known.lanes = live.count_ones();
        }
        let mut seen = 0u32;
        let k = pass.k_rows as f32;
        for (s, e) in ev.iter().enumerate() {
            if live & (1 << s) == 0 {
                continue;
            }
            if e.weight > 0.0 {
                match self
                    .temporal
                    .update_info_probed(self.tables, s, &e.j, &e.i, probe)
                {
                    Ok(u) => {
                        let dof = (self.tables.gram_rank as usize).min(RANK) as f32;
                        self.persist
                            .count_nis(s, u.nis, dof, self.cfg.persist.p_publish);
                    }
                    Err(_) => report.temporal_failures += 1,
                }
                probe.enter(Stage::Known);
            }
            self.persist
                .update_existence(s, e.llr, k, self.cfg.persist.p_visible);
            let seen_now = e.extent[0] <= e.extent[1];
            if let Some(info) = self.info.get_mut(s) {
                info.existence = self.persist.lanes.get(s).map_or(0.0, |l| l.existence);
                info.seen = seen_now;
                info.extent = e.extent;
            }
            if seen_now {
                seen |= 1 << s;
            }
        }
        if self.cfg.persist.q_memory > 0.0 {
            self.persist.adapt_q_scale(self.cfg.persist.q_memory, 10.0);
        }
        self.persist.estimate_noise(
            self.tables,
            &self.basis,
            self.temporal.filter(),
            (live, &self.ranks),
            &pass,
            self.cfg.persist.pd_memory,
        );
        report.known.seen = seen.count_ones();
        report.known.explained_points = explained.iter().map(|m| m.count_ones()).sum();
        for (r, mask) in explained.iter().enumerate().take(pass.rows) {
            if *mask != 0 {
                self.spatial.remove_points(r, *mask);
            }
        }
        seen
    }

    /// After the temporal stage: new lanes' existence, deletion of unlikely lanes and merging
    /// of duplicates (the ranks follow when a lane left), existence into the published figures.
    pub(super) fn maintain_known(&mut self, slots: &[SlotFate; LANES], report: &mut StepReport) {
        self.new_lane_existence(slots);
        let deleted = self.delete_unlikely();
        let merged = self.merge_duplicates();
        report.known.deleted = deleted;
        report.known.merged = merged;
        if merged + deleted > 0 {
            let ranks = self.ranks_of(None);
            match self.temporal.set_ranks(&ranks) {
                Ok(()) => self.ranks = ranks,
                Err(_) => report.temporal_failures += 1,
            }
        }
        for (info, l) in self.info.iter_mut().zip(self.persist.lanes.iter()) {
            info.existence = l.existence;
        }
    }

    /// The row pass parameters of the known-lane stage.
    pub(super) fn pass(&self) -> Option<Pass> {
        let (rows, du) =
            SpatialFilter::<NS, LANES, ROWS, PER_ROW>::geometry(self.tables, &self.cfg.spatial)?;
        let c = &self.cfg.spatial;
        Some(Pass {
            rows,
            du,
            k_rows: usize::from(c.rows_per_interval.max(1)),
            params: crate::spatial::row::RowParams {
                pd: c.pd,
                pg: c.pg,
                gamma: c.gamma,
                clutter_density: c.clutter_density,
                r: self.tables.hyper.meas_noise,
                miss: c.miss,
            },
            max_events: c.max_events,
        })
    }

    /// The existence of lanes started this frame: the birth prior updated by the evidence of
    /// their spatial track over its observed extent (`LaneObservation::llr`: one-step-ahead
    /// predictions along the rows, so the points a track was fitted to do not confirm it).
    fn new_lane_existence(&mut self, slots: &[SlotFate; LANES]) {
        let k = f32::from(self.cfg.spatial.rows_per_interval.max(1));
        for (s, fate) in slots.iter().enumerate() {
            if let SlotFate::New { obs, .. } = fate {
                let llr = self.obs.get(usize::from(*obs)).map_or(0.0, |o| o.llr);
                self.persist
                    .update_existence(s, llr, k, self.cfg.persist.p_visible);
            }
        }
    }

    /// One lane, one track (docs/design.md §11.9): two live lanes, both seen this frame, whose
    /// positions agree over the
    /// index points inside both observed extents — at least `min_common` of them, mean
    /// `(z_s − z_t)² / Var(z_s − z_t)` at most the identity gate, with
    /// `Var = σ_s² + σ_t² − 2 Cov(z_s, z_t)` from the temporal covariance — describe one
    /// marking, and so do two lanes closer than `min_spacing` on average there (no two
    /// markings run that close; a double line is one marking); the younger (on a tie, the
    /// higher slot) is removed. Returns how many were.
    ///
    /// # Complexity
    /// `LANES²/2` pairs, each `POINTS·(r² + 2r)` multiply-adds.
    #[inline(never)]
    fn merge_duplicates(&mut self) -> u32 {
        let mut any = 0u32;
        let r = (self.tables.gram_rank as usize).min(RANK).min(POINTS);
        for s in 0..LANES {
            for t in s + 1..LANES {
                let (Some(ls), Some(lt)) = (self.ids.lane(s), self.ids.lane(t)) else {
                    continue;
                };
                // Only lanes both seen this frame: a coasting lane is not a duplicate of the
                // lane that took its place (a bump, a jump), it is decided by its existence.
                if !(get(&self.info, s).seen && get(&self.info, t).seen) {
                    continue;
                }
                let (Some((zs, vs)), Some((zt, vt))) = (
                    self.temporal.filter().lane(self.tables, s),
                    self.temporal.filter().lane(self.tables, t),
                ) else {
                    continue;
                };
                let (as0, ae0) = self.extent_of(s, 0);
                let (at0, ate) = self.extent_of(t, 0);
                let (lo, hi) = (as0.max(at0), ae0.min(ate));
                let p = self.temporal.filter().covariance();
                let mut cost = 0.0f32;
                let mut dist = 0.0f32;
                let mut n = 0u32;
                for i in 0..POINTS {
                    let u = self.tables.index_u.get(i).copied().unwrap_or(f32::NAN);
                    if !(u >= lo && u <= hi) {
                        continue;
                    }
                    let vi = |j: usize| self.tables.gram_eigvec.get((i, j)).copied().unwrap_or(0.0);
                    let mut cov = 0.0f32;
                    for j in 0..r {
                        let ij = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0);
                        let mut inner = 0.0f32;
                        for k in 0..r {
                            let ik = TemporalFilter::<LANES, POINTS, RANK, NX>::index(t, k, 0);
                            inner += p.get((ij, ik)).copied().unwrap_or(0.0) * vi(k);
                        }
                        cov += vi(j) * inner;
                    }
                    let d = zs.get(i).copied().unwrap_or(0.0) - zt.get(i).copied().unwrap_or(0.0);
                    let var = vs.get(i).copied().unwrap_or(0.0) + vt.get(i).copied().unwrap_or(0.0)
                        - 2.0 * cov;
                    let var = var.max(self.tables.hyper.pseudo_noise);
                    cost += d * d / var;
                    dist += d.abs();
                    n += 1;
                }
                let nf = n as f32;
                if n >= u32::from(self.cfg.identity.min_common.max(1))
                    && cost.is_finite()
                    && (cost / nf <= self.cfg.identity.gate
                        || dist / nf <= self.cfg.persist.min_spacing)
                {
                    let drop = if lt.age <= ls.age { t } else { s };
                    self.remove_slot(drop);
                    any += 1;
                }
            }
        }
        any
    }

    /// Removes the lane in slot `s` from every stage.
    pub(super) fn remove_slot(&mut self, s: usize) {
        self.ids.remove(s);
        self.temporal.remove_lane(s);
        self.persist.remove(s);
        set(&mut self.info, s, NO_INFO);
        for h in self.extent.iter_mut() {
            set(h, s, [f32::INFINITY, f32::NEG_INFINITY]);
        }
    }

    /// Lanes whose existence fell below `p_delete` are removed; returns how many.
    fn delete_unlikely(&mut self) -> u32 {
        let mut any = 0u32;
        for s in 0..LANES {
            let p = self.persist.lanes.get(s).map_or(1.0, |l| l.existence);
            if self.ids.lane(s).is_some() && p < self.cfg.persist.p_delete {
                self.remove_slot(s);
                any += 1;
            }
        }
        any
    }

    /// Step 6: this frame's extents and ids enter the histories (newest first).
    #[inline(always)]
    pub(super) fn push_histories(&mut self) {
        for j in (1..self.extent.len()).rev() {
            if let Some(prev) = self.extent.get(j - 1).copied() {
                if let Some(h) = self.extent.get_mut(j) {
                    *h = prev;
                }
            }
        }
        if let Some(h) = self.extent.get_mut(0) {
            for (s, e) in h.iter_mut().enumerate() {
                *e = get(&self.info, s).extent;
            }
        }
        for j in (1..self.id_hist.len()).rev() {
            if let Some(prev) = self.id_hist.get(j - 1).copied() {
                if let Some(h) = self.id_hist.get_mut(j) {
                    *h = prev;
                }
            }
        }
        if let Some(h) = self.id_hist.get_mut(0) {
            for (s, e) in h.iter_mut().enumerate() {
                *e = self.ids.lane(s).map(|l| l.id);
            }
        }
    }

    /// Step 7: the filtered lanes of this frame and the smoothed lanes `LAG` frames back.
    // Not inlined: its frame must not add to the step's (stack budget).
    #[inline(never)]
    pub(super) fn estimates(
        &self,
        filtered: &mut Vec<LaneEstimate<POINTS>, LANES>,
        smoothed: &mut Vec<LaneEstimate<POINTS>, LANES>,
    ) {
        for s in 0..LANES {
            if let (Some(lane), Some((z, var))) = (
                self.ids.lane(s),
                self.temporal.filter().lane(self.tables, s),
            ) {
                let (u_first, u_last) = self.extent_of(s, 0);
                let info = get(&self.info, s);
                if self.cfg.persist.enabled && info.existence < self.cfg.persist.p_publish {
                    continue;
                }
                // At most one estimate per slot: the vectors hold `LANES`, so no push fails.
                if filtered
                    .push(LaneEstimate {
                        id: lane.id,
                        slot: s as u8,
                        z,
                        var,
                        u_first,
                        u_last,
                        existence: info.existence,
                        misses: lane.misses,
                        age: lane.age,
                        hits: lane.hits,
                    })
                    .is_err()
                {
                    break;
                }
            }
            let id_then = self
                .id_hist
                .get(LAG)
                .and_then(|h| h.get(s))
                .copied()
                .flatten();
            // With the known-lane stage, a smoothed lane is published while its lane is still
            // live and published now (a lane removed since was not one, or is gone).
            let publish_smoothed = !self.cfg.persist.enabled
                || get(&self.info, s).existence >= self.cfg.persist.p_publish;
            if let (true, Some(id), Some((z, var))) = (
                publish_smoothed,
                id_then,
                self.temporal.lagged(self.tables, s, LAG),
            ) {
                // The same lane's counters at the current frame (0 once it is gone).
                let now = self.ids.lane(s).filter(|l| l.id == id);
                let (u_first, u_last) = self.extent_of(s, LAG);
                if smoothed
                    .push(LaneEstimate {
                        id,
                        slot: s as u8,
                        z,
                        var,
                        u_first,
                        u_last,
                        existence: get(&self.info, s).existence,
                        misses: 0,
                        age: now.map_or(0, |l| l.age),
                        hits: now.map_or(0, |l| l.hits),
                    })
                    .is_err()
                {
                    break;
                }
            }
        }
    }

    /// Union of slot `s`'s observed extents over the history frames `from..=from + LAG` (0 is
    /// the current frame).
    pub(super) fn extent_of(&self, s: usize, from: usize) -> (f32, f32) {
        let mut lo = f32::INFINITY;
        let mut hi = f32::NEG_INFINITY;
        for h in self.extent.iter().skip(from).take(LAG + 1) {
            let [a, b] = get(h, s);
            lo = lo.min(a);
            hi = hi.max(b);
        }
        if lo > hi {
            (self.tables.hyper.u_min, self.tables.hyper.u_min)
        } else {
            (lo, hi)
        }
    }

    /// Lateral position at the nearest index point: the observation's first present point, else
    /// the temporal filter's prediction.
    pub(super) fn bottom_position(&self, s: usize, obs: Option<usize>) -> f32 {
        if let Some(o) = obs.and_then(|i| self.obs.get(i)) {
            if let Some(i) = (0..POINTS).find(|&i| get(&o.present, i)) {
                return o.z.get(i).copied().unwrap_or(0.0);
            }
        }
        self.temporal
            .filter()
            .position(self.tables, s, 0)
            .unwrap_or(0.0)
    }

    /// Ranks (0 = leftmost at the bottom of the window) of the active lanes, plus a new lane in
    /// slot `s` at lateral `x` when `new = Some((s, x))`: a permutation of `0..lanes`, ties broken
    /// by slot, a lane without a position ranked after those with one.
    pub(super) fn ranks_of(&self, new: Option<(usize, f32)>) -> [u8; LANES] {
        let on = |t: usize| new.is_some_and(|(s, _)| s == t) || self.temporal.filter().is_active(t);
        let mut pos = [f32::NAN; LANES];
        for (t, p) in pos.iter_mut().enumerate() {
            if self.temporal.filter().is_active(t) {
                *p = self.bottom_position(t, None);
            }
        }
        if let Some((s, x)) = new {
            set(&mut pos, s, x);
        }
        let mut ranks = [0u8; LANES];
        for t in (0..LANES).filter(|&t| on(t)) {
            let pt = get(&pos, t);
            let r = (0..LANES).filter(|&o| on(o) && o != t).filter(|&o| {
                let po = get(&pos, o);
                po < pt || (po == pt && o < t) || (pt.is_nan() && !po.is_nan())
            });
            set(&mut ranks, t, r.count() as u8);
        }
        ranks
    }

    /// A lane's position and variance at any `u` inside the window: the GP conditional of the lane
    /// (RBF along `u`, its slot's variance from B) given its coefficients on the Gram eigenbasis,
    /// `f(u) = Σ_j (k(u, U)·v_j / λ_j) a_j`, plus the prior's residual variance at `u`.
    /// `None` for a free slot, or `u` outside the window or not finite.
    pub fn lane_at(&self, slot: usize, u: f32) -> Option<(f32, f32)> {
        let h = &self.tables.hyper;
        if !(u.is_finite() && u >= h.u_min && u <= h.u_max) {
            return None;
        }
        let (z, _) = self.temporal.filter().lane(self.tables, slot)?;
        let r = (self.tables.gram_rank as usize).min(RANK);
        let l2 = 2.0 * h.spatial_lengthscale * h.spatial_lengthscale;
        let k = SVector::<f32, POINTS>::from_fn(|i, _| {
            let d = u - self.tables.index_u.get(i).copied().unwrap_or(0.0);
            h.spatial_variance * crate::math::exp(-d * d / l2)
        });
        // c_j = k·v_j / λ_j; f(u) = Σ c_j a_j with a = V_rᵀ z (z = V_r a).
        let v = &self.tables.gram_eigvec;
        let mut mean = 0.0;
        let mut explained = 0.0;
        let mut cvec = [0.0f32; POINTS];
        for j in 0..r {
            let lam = self.tables.gram_eigval.get(j).copied().unwrap_or(0.0);
            if lam <= 0.0 {
                continue;
            }
            let kv: f32 = (0..POINTS)
                .map(|i| k.get(i).copied().unwrap_or(0.0) * v.get((i, j)).copied().unwrap_or(0.0))
                .sum();
            let aj: f32 = (0..POINTS)
                .map(|i| z.get(i).copied().unwrap_or(0.0) * v.get((i, j)).copied().unwrap_or(0.0))
                .sum();
            let cj = kv / lam;
            mean += cj * aj;
            explained += kv * kv / lam;
            set(&mut cvec, j, cj);
        }
        // Variance: cᵀ Cov(a_slot) c from the filter's coefficient block.
        let var_a = self.temporal.filter().coefficient_var(slot, &cvec, r);
        let rank = usize::from(get(&self.ranks, slot));
        let bss = self.tables.coreg.get((rank, rank)).copied().unwrap_or(0.0);
        let residual = (h.spatial_variance - explained).max(0.0) * bss;
        Some((mean, var_a + residual))
    }
}
