//! The step's later stages on the live lanes: the known-lane pass against the predictions,
//! existence, deletion and merging of duplicates (docs/design.md §11); the extent and id
//! histories, the filtered and smoothed lanes, lane ranks and a lane's position anywhere in the
//! window.

use heapless::Vec;
use nalgebra::{SMatrix, SVector};

use crate::linalg::{get, set};
use crate::math;
use crate::observation::LaneObservation;
use crate::persist::{self, ray_stat, Evidence, Explained, Lanes, Pass, RayVerdict};
use crate::probe::{Probe, Stage};
use crate::spatial::filter::SpatialFilter;
use crate::tables::Tables;
use crate::temporal::filter::TemporalFilter;
use crate::temporal::identity::SlotFate;

use super::{LaneEstimate, StepReport, Tracker, NO_INFO};

/// A lane's means and variances at the index points ([`TemporalFilter::lane`]).
type View<const POINTS: usize> = (SVector<f32, POINTS>, SVector<f32, POINTS>);

/// Every active lane's [`View`], projected once per filter state instead of once per use
/// (a projection is `POINTS·(RANK² + 2·RANK)` multiply-adds; the identity, maintenance and
/// output stages used ~40 a frame). Filled by [`Tracker::refresh_views`] at the two places where
/// the filter's state is final for what follows: before the identity stage (after the
/// known-lane updates) and after the temporal stage. Removing a lane clears its entry and
/// leaves the others valid (it zeroes only its own rows and columns); nothing else changes
/// the filter until the next refresh. Working memory, not state: each step starts with none.
#[derive(Debug, Clone)]
pub(super) struct Views<const LANES: usize, const POINTS: usize> {
    lanes: [View<POINTS>; LANES],
    /// Bit `s`: `lanes[s]` is lane `s`'s projection of the filter's current state.
    valid: u32,
}

impl<const LANES: usize, const POINTS: usize> Views<LANES, POINTS> {
    const ZERO: SVector<f32, POINTS> =
        SVector::from_array_storage(nalgebra::ArrayStorage([[0.0; POINTS]; 1]));

    /// No lane projected (all zero: `.bss`).
    pub(super) const NEW: Self = Self {
        lanes: [(Self::ZERO, Self::ZERO); LANES],
        valid: 0,
    };

    /// Forgets every projection.
    pub(super) fn clear(&mut self) {
        self.valid = 0;
    }

    /// Forgets lane `s`'s projection.
    pub(super) fn forget(&mut self, s: usize) {
        if s < 32 {
            self.valid &= !(1u32 << s);
        }
    }
}

impl_tracker! {
    /// Projects every active lane of the filter's current state into [`Views`].
    #[inline(never)]
    pub(super) fn refresh_views(&mut self) {
        self.views.clear();
        let Some(tables) = self.tables else {
            return;
        };
        for s in 0..LANES.min(32) {
            if let (Some(v), Some(slot)) = (
                self.temporal.filter().lane(tables, s),
                self.views.lanes.get_mut(s),
            ) {
                *slot = v;
                self.views.valid |= 1 << s;
            }
        }
    }

    /// Lane `s`'s [`View`]: [`TemporalFilter::lane`], from [`Views`] when it holds the lane
    /// (`None` for a free slot). A lane not in the views is projected here, so a missing
    /// refresh costs time, not correctness; a stale entry would, which is why every change of
    /// the filter's state is preceded by [`Views::clear`] or followed by a refresh.
    pub(super) fn view(&self, s: usize) -> Option<View<POINTS>> {
        if !self.temporal.filter().is_active(s) {
            return None;
        }
        if s < 32 && self.views.valid & (1 << s) != 0 {
            let v = self.views.lanes.get(s).copied();
            // Tests run with debug assertions: every use of a kept projection is checked
            // against a fresh one, bit for bit.
            debug_assert!(
                v.map(|(z, w)| (z.map(f32::to_bits), w.map(f32::to_bits)))
                    == self
                        .tables
                        .and_then(|t| self.temporal.filter().lane(t, s))
                        .map(|(z, w)| (z.map(f32::to_bits), w.map(f32::to_bits))),
                "stale projection of lane {s}"
            );
            return v;
        }
        self.temporal.filter().lane(self.tables?, s)
    }

    /// Step 3 (docs/design.md §11): the live lanes' row evidence against their prediction, the
    /// temporal update with it, their existence; the points they explain leave the rows.
    /// Returns the lanes seen (bit = slot).
    #[inline(never)]
    pub(super) fn known_lanes<P: Probe>(
        &mut self,
        tables: &'static Tables<NT, LANES, POINTS>,
        report: &mut StepReport,
        probe: &mut P,
    ) -> u32 {
        let Some(pass) = self.pass() else {
            return 0;
        };
        let mut live = 0u32;
        for s in 0..LANES {
            if self.temporal.filter().is_active(s) && self.ids.lane(s).is_some() {
                live |= 1 << s;
            }
        }
        self.basis.ensure(tables, &pass);
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
                tables,
                (&self.basis, &mut self.pass_memory),
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
        let chain = self
            .cfg
            .persist
            .paint_gap
            .and_then(|c| c.rates(pass.du))
            .is_some();
        // The frame offset's estimate (§11.4) from the lanes' mean innovations against the
        // prediction (before any lane's update: with coupled tables an update moves the others).
        let r = (tables.gram_rank as usize).min(RANK);
        let mut innovation = [[0.0f32; 2]; LANES];
        for ((s, e), inn) in ev.iter().enumerate().zip(innovation.iter_mut()) {
            let w = e.offset[0];
            // Published lanes through two passes only, as the process-noise score (§11.7): a
            // lane on a distractor or a new lane's unknown velocity is not the frame's offset.
            let counted = self.persist.counts(s, self.cfg.persist.p_publish);
            if !(counted && live & (1 << s) != 0 && e.weight > 0.0 && w > 0.0) {
                continue;
            }
            let kpk = self.temporal.filter().coefficient_var(s, e.k.as_slice(), r);
            *inn = [(e.offset[1] - e.offset[2]) / w, kpk / (w * w) + 1.0 / w];
        }
        self.persist
            .update_frame_offset(&innovation, self.cfg.persist.frame_offset_memory);
        // The chain's mean gap (§11.5) from the same lanes: the next frame's chain.
        if chain {
            let mut stats = [[0.0f32; 2]; LANES];
            for ((s, e), st) in ev.iter().enumerate().zip(stats.iter_mut()) {
                if self.persist.counts(s, self.cfg.persist.p_publish) && live & (1 << s) != 0 {
                    *st = e.chain_expectations();
                }
            }
            self.persist
                .update_chain_gap(&stats, pass.du, self.cfg.persist.chain_memory);
        }
        let offset_sd = self.persist.frame_offset_sd();
        for (s, e) in ev.iter().enumerate() {
            if live & (1 << s) == 0 {
                continue;
            }
            if e.weight > 0.0 {
                let (j, i) = e.offset_marginal(offset_sd);
                match self
                    .temporal
                    .update_info_probed(tables, s, &j, &i, probe)
                {
                    Ok(_) => {
                        let dof = (tables.gram_rank as usize).min(RANK) as f32;
                        self.persist.count_q_score(
                            s,
                            e.q_score,
                            dof,
                            self.cfg.persist.p_publish,
                        );
                    }
                    Err(_) => report.temporal_failures += 1,
                }
                probe.enter(Stage::Known);
            }
            // The chain's ratio is not discounted (§11.5): it models the runs of rows itself.
            let looks = if chain { 1.0 } else { k };
            self.persist
                .update_existence(s, e.llr, looks, self.cfg.persist.p_visible);
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
            tables,
            (&self.basis, &mut self.pass_memory),
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
        for i in self.info.iter_mut() {
            i.held = false;
        }
        self.new_lane_existence(slots);
        let (deleted, rays) = self.delete_unlikely();
        report.known.ray_deleted = rays;
        let merged = self.merge_duplicates();
        let connectors = if self.cfg.persist.connectors {
            self.remove_connectors()
        } else {
            0
        };
        report.known.deleted = deleted + connectors;
        report.known.connectors_deleted = connectors;
        report.known.merged = merged;
        if merged + deleted + connectors > 0 {
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
        let tables = self.tables?;
        let (rows, du) =
            SpatialFilter::<NS, LANES, ROWS, PER_ROW>::geometry(tables, &self.cfg.spatial)?;
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
                r: tables.hyper.meas_noise,
                miss: c.miss,
            },
            max_events: c.max_events,
        })
    }

    /// Slots by existence (docs/design.md §11.13): a live lane below `p_birth` (the evidence
    /// since its birth is against it) yields its slot, the lowest existence first, to a
    /// candidate whose track's evidence is positive (`llr ≥ 0`: a lane started from it begins
    /// at or above `p_birth`); the other lanes hold theirs (`∞`). `None` without the
    /// known-lane stage or with `slot_claims` off.
    #[inline(never)]
    pub(super) fn slot_holds(&self) -> Option<[f32; LANES]> {
        let pc = &self.cfg.persist;
        if !(pc.enabled && pc.slot_claims) {
            return None;
        }
        let mut hold = [f32::INFINITY; LANES];
        for (h, l) in hold.iter_mut().zip(self.persist.lanes.iter()) {
            if l.existence < pc.p_birth {
                *h = l.existence;
            }
        }
        Some(hold)
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
    /// higher slot) is removed. Returns how many were. The observed extents are those of the
    /// `LAG + 1` frames before this one; a lane started this frame has none, so a pair with one
    /// is compared over this frame's extents ([`Self::extent_this_frame`]) and the younger,
    /// when a duplicate, is only held back from publication this frame (`SlotInfo::held`);
    /// the next frame's test decides.
    ///
    /// # Complexity
    /// `LANES²/2` pairs, each `POINTS·(r² + 2r)` multiply-adds.
    #[inline(never)]
    fn merge_duplicates(&mut self) -> u32 {
        let Some(tables) = self.tables else {
            return 0;
        };
        let mut any = 0u32;
        // Each lane's positions and variances, copied once from the tracker's kept projections
        // when a pair first needs them (removing a lane zeroes only its own rows and columns:
        // the others' stay valid). Reading `self.view` per pair instead copies each lane's
        // 128 B up to five times: +2.5 k instructions a typical frame on the M4F (measured).
        let mut views: [Option<View<POINTS>>; LANES] = [None; LANES];
        let mut projected = 0u32;
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
                for l in [s, t] {
                    if projected & (1 << l) == 0 {
                        projected |= 1 << l;
                        if let Some(v) = views.get_mut(l) {
                            *v = self.view(l);
                        }
                    }
                }
                let (Some(Some((zs, vs))), Some(Some((zt, vt)))) = (views.get(s), views.get(t))
                else {
                    continue;
                };
                let (zs, vs, zt, vt) = (*zs, *vs, *zt, *vt);
                // A lane started this frame has no extent history yet: it is compared over
                // this frame's extents, and a duplicate is held back from publication (not
                // removed: the next frame's joint association decides between the two, then
                // the merge below).
                let newborn = lt.age == 0 || ls.age == 0;
                // The younger (on a tie, the higher slot) is the duplicate.
                let (drop, keep) = if lt.age <= ls.age { (t, s) } else { (s, t) };
                // A lane started this frame is held only against a lane tracked since an
                // earlier frame and published (two lanes of one frame are both kept, §11.5):
                // otherwise the test has nothing to decide.
                let p_publish = self.cfg.persist.p_publish;
                if newborn
                    && !(self.ids.lane(keep).is_some_and(|l| l.age > 0)
                        && self
                            .persist
                            .lanes
                            .get(keep)
                            .is_some_and(|l| l.existence >= p_publish))
                {
                    continue;
                }
                let ((as0, ae0), (at0, ate)) = if newborn {
                    (self.extent_this_frame(s), self.extent_this_frame(t))
                } else {
                    (self.extent_of(s, 0), self.extent_of(t, 0))
                };
                let (lo, hi) = (as0.max(at0), ae0.min(ate));
                let mut cost = 0.0f32;
                let mut dist = 0.0f32;
                let mut n = 0u32;
                for i in 0..POINTS {
                    let u = tables.index_u.get(i).copied().unwrap_or(f32::NAN);
                    if !(u >= lo && u <= hi) {
                        continue;
                    }
                    let (d, var) = self.difference_at(tables, (s, &zs, &vs), (t, &zt, &vt), i);
                    let var = math::max(var, tables.hyper.pseudo_noise);
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
                    if newborn {
                        if let Some(info) = self.info.get_mut(drop) {
                            info.held = true;
                        }
                    } else {
                        self.remove_slot(drop);
                        any += 1;
                    }
                }
            }
        }
        any
    }

    /// Removes the lane in slot `s` from every stage.
    pub(super) fn remove_slot(&mut self, s: usize) {
        self.views.forget(s);
        set(&mut self.connector_run, s, 0);
        self.ids.remove(s);
        self.temporal.remove_lane(s);
        self.persist.remove(s);
        set(&mut self.info, s, NO_INFO);
        for h in self.extent.iter_mut() {
            set(h, s, [f32::INFINITY, f32::NEG_INFINITY]);
        }
    }

    /// `z_s − z_t` at index point `i` and its variance `σ_s² + σ_t² − 2 Cov(z_s, z_t)` from
    /// the temporal covariance (`(slot, z, σ²)` of each lane).
    ///
    /// # Complexity
    /// `r² + 2r` multiply-adds (`r` Gram components).
    fn difference_at(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        (s, zs, vs): (usize, &SVector<f32, POINTS>, &SVector<f32, POINTS>),
        (t, zt, vt): (usize, &SVector<f32, POINTS>, &SVector<f32, POINTS>),
        i: usize,
    ) -> (f32, f32) {
        let r = (tables.gram_rank as usize).min(RANK).min(POINTS);
        // Row i of V_r: z_i = v_iᵀ a.
        let vi: [f32; RANK] = core::array::from_fn(|j| {
            tables.gram_eigvec.get((i, j)).copied().unwrap_or(0.0)
        });
        let cov = self.coefficient_form(s, t, &vi, &vi, r, 0);
        let at = |v: &SVector<f32, POINTS>| v.get(i).copied().unwrap_or(f32::NAN);
        (at(zs) - at(zt), at(vs) + at(vt) - 2.0 * cov)
    }

    /// Lanes do not cross, and no marking joins two others (docs/design.md §11.11). For each
    /// pair of published lanes seen this frame, over the index points both observed (at least
    /// `min_common`), with `d = z_s − z_t` and `V = Var(d) + 2r`: the pair is *apart* at a
    /// point where `d² > gate·V` and *together* where not. Two lanes **cross** when they are
    /// apart on both sides (`d > 0` at one point, `d < 0` at another); a lane **touches**
    /// another when they are together at two points or more and apart at one. A lane is a
    /// *connector* when two of the lanes it crosses or touches do not cross or touch each
    /// other: it runs from one marking to the next through their shared points, the track of
    /// no marking. A connector in `connector_frames` consecutive frames is removed, the one
    /// with the most crossings and touches first (on a tie the younger, then the higher slot),
    /// the relations recomputed without it. Returns how many were.
    ///
    /// # Complexity
    /// `LANES` lane read-outs (`POINTS·(r + r²)` each); `LANES²/2` pairs of `POINTS` bound
    /// tests, each pair's covariance term (`r² + 2r` multiply-adds) only at points the bounds
    /// do not decide; at most `LANES` rounds of `O(LANES³)` bit tests.
    #[inline(never)]
    fn remove_connectors(&mut self) -> u32 {
        let Some(tables) = self.tables else {
            return 0;
        };
        let gate = self.cfg.identity.gate;
        let rr = tables.hyper.meas_noise;
        let min_common = usize::from(self.cfg.identity.min_common.max(1));
        // Bit t of cross[s] / touch[s]: s crosses / touches t.
        let mut cross = [0u32; LANES];
        let mut touch = [0u32; LANES];
        // Published lanes seen this frame: a connector joins established markings.
        let p_publish = self.cfg.persist.p_publish;
        let live = |s: usize| {
            self.ids.lane(s).is_some()
                && get(&self.info, s).seen
                && self.persist.lanes.get(s).is_some_and(|l| l.existence >= p_publish)
        };
        // Each lane's positions, variances and observed points, once.
        let lanes: [Option<(SVector<f32, POINTS>, SVector<f32, POINTS>)>; LANES] =
            core::array::from_fn(|s| {
                if live(s) {
                    self.view(s)
                } else {
                    None
                }
            });
        let observed: [[bool; POINTS]; LANES] = core::array::from_fn(|s| self.observed(s));
        for s in 0..LANES {
            for t in s + 1..LANES {
                let (Some(Some((zs, vs))), Some(Some((zt, vt))), Some(os), Some(ot)) =
                    (lanes.get(s), lanes.get(t), observed.get(s), observed.get(t))
                else {
                    continue;
                };
                let (mut pos, mut neg, mut together, mut common) = (false, false, 0usize, 0usize);
                for i in (0..POINTS).filter(|&i| get(os, i) && get(ot, i)) {
                    // 2r ≤ V ≤ (σ_s + σ_t)² + 2r (|Cov| ≤ σ_s σ_t): the covariance term is
                    // computed only when the bounds do not decide.
                    let at = |v: &SVector<f32, POINTS>| v.get(i).copied().unwrap_or(f32::NAN);
                    let d = at(zs) - at(zt);
                    let sd = math::sqrt(math::max(at(vs), 0.0)) + math::sqrt(math::max(at(vt), 0.0));
                    if !(d.is_finite() && sd.is_finite()) {
                        continue;
                    }
                    let apart = if d * d <= gate * 2.0 * rr {
                        false
                    } else if d * d > gate * (sd * sd + 2.0 * rr) {
                        true
                    } else {
                        let (_, var) = self.difference_at(tables, (s, zs, vs), (t, zt, vt), i);
                        d * d > gate * (math::max(var, 0.0) + 2.0 * rr)
                    };
                    common += 1;
                    if apart {
                        pos |= d > 0.0;
                        neg |= d < 0.0;
                    } else {
                        together += 1;
                    }
                }
                if common < min_common {
                    continue;
                }
                let rel = if pos && neg {
                    &mut cross
                } else if together >= 2 && (pos || neg) {
                    &mut touch
                } else {
                    continue;
                };
                for (a, b) in [(s, t), (t, s)] {
                    if let Some(m) = rel.get_mut(a) {
                        *m |= 1 << b;
                    }
                }
            }
        }
        let rel = |c: &[u32; LANES], t: &[u32; LANES], x: usize| get(c, x) | get(t, x);
        // Two of the lanes it meets that do not meet each other: two markings.
        let joins = |c: &[u32; LANES], t: &[u32; LANES], s: usize| {
            let mine = rel(c, t, s);
            (0..LANES).any(|a| {
                mine & (1 << a) != 0
                    && (a + 1..LANES).any(|b| mine & (1 << b) != 0 && rel(c, t, a) & (1 << b) == 0)
            })
        };
        let persist = self.cfg.persist.connector_frames;
        for s in 0..LANES {
            let run = get(&self.connector_run, s);
            let now = if joins(&cross, &touch, s) {
                run.saturating_add(1)
            } else {
                0
            };
            set(&mut self.connector_run, s, now);
        }
        let mut removed = 0u32;
        for _ in 0..LANES {
            let mut pick: Option<(u32, u32, usize)> = None;
            for s in 0..LANES {
                if get(&self.connector_run, s) < persist || !joins(&cross, &touch, s) {
                    continue;
                }
                let degree = rel(&cross, &touch, s).count_ones();
                let age = self.ids.lane(s).map_or(0, |l| l.age);
                // Most relations first, then the younger, then the higher slot.
                let better = pick.is_none_or(|(d, a, _)| degree > d || (degree == d && age <= a));
                if better {
                    pick = Some((degree, age, s));
                }
            }
            let Some((_, _, s)) = pick else {
                break;
            };
            self.remove_slot(s);
            removed += 1;
            let gone = !(1u32 << s);
            set(&mut cross, s, 0);
            set(&mut touch, s, 0);
            for m in cross.iter_mut().chain(touch.iter_mut()) {
                *m &= gone;
            }
        }
        // A lane started this frame that already joins two markings is not published before
        // its second frame decides (as a duplicate is not, §11.9).
        for s in 0..LANES {
            let newborn = self.ids.lane(s).is_some_and(|l| l.age == 0);
            if newborn && joins(&cross, &touch, s) {
                if let Some(info) = self.info.get_mut(s) {
                    info.held = true;
                }
            }
        }
        removed
    }

    /// Lanes whose existence fell below `p_delete`, or that the ray test finds to be vertical
    /// structures, are removed; returns how many, and how many of them by the ray test.
    fn delete_unlikely(&mut self) -> (u32, u32) {
        // The ray test (docs/design.md §11.10): a lane seen as a ray through the camera's foot
        // point is a vertical structure, unless it runs parallel to a lane shown to be paint
        // (the marking under the camera in a lane change does; a vehicle's edge does not).
        let verdicts = self.lane_ray_verdicts();
        let aligned = self.cfg.persist.ray_aligned;
        let (mut any, mut rays) = (0u32, 0u32);
        // Bit s: lane s kept and found to be paint / kept, published before and seen this
        // frame / kept, of age 1 to `newcomer_wait`, never published and at `p_publish`.
        let (mut paint, mut shown, mut young) = (0u32, 0u32, 0u32);
        let wait = self.cfg.persist.newcomer_wait;
        for s in 0..LANES {
            let p = self.persist.lanes.get(s).map_or(1.0, |l| l.existence);
            let ray = persist::vertical(
                get(&verdicts, s),
                aligned,
                (0..LANES)
                    .filter(|&t| t != s && get(&verdicts, t) == RayVerdict::Paint)
                    .map(|t| self.parallel(s, t)),
            );
            let ray = ray && !(self.cfg.persist.ray_motion && self.lane_moving(s));
            if let Some(l) = self.ids.lane(s) {
                if p < self.cfg.persist.p_delete || ray {
                    self.remove_slot(s);
                    any += 1;
                    rays += u32::from(ray);
                } else {
                    let info = get(&self.info, s);
                    paint |= u32::from(get(&verdicts, s) == RayVerdict::Paint) << s;
                    // Seen this frame: a coasting lane is not a marking beside the lane that
                    // took its place (a bump, a jump: §11.9).
                    shown |= u32::from(info.shown && info.seen) << s;
                    // Only a lane this frame would publish for the first time: one that has
                    // been through one to `newcomer_wait` known-lane passes (§11.5), was never
                    // published and stands at `p_publish`.
                    let first = (1..=u32::from(wait)).contains(&l.age) && !info.shown;
                    young |= u32::from(first && p >= self.cfg.persist.p_publish) << s;
                }
            }
        }
        if young != 0 && self.tracking() {
            self.hold_newcomers(young, paint, shown);
        }
        (any, rays)
    }

    /// A lane at its first publication waits a frame more (up to `newcomer_wait` frames) when
    /// it is not yet shown to be a marking of its own (docs/design.md §11.5): it runs parallel
    /// to none of the paint lanes (a vehicle's edge joined to a marking's near points is
    /// decisive paint for a frame before it is seen as the ray it is), or it lies within twice
    /// `min_spacing` (the lower bound on the spacing of two markings) of a lane published
    /// before and seen this frame (a young track beside a marking, which the duplicate test of
    /// §11.9 takes in the next frame; a coasting lane is not compared, as in §11.9: after a
    /// jump the lanes that took the old ones' places are no duplicates). `young`: bit s for a
    /// kept lane of age 1 to `newcomer_wait`, never published, at `p_publish` (the only lanes
    /// this frame would publish for the first time while others are tracked); `paint` /
    /// `shown`: bit t for a kept lane found to be paint / published before and seen this frame
    /// (bits of [`Self::delete_unlikely`]).
    ///
    /// # Complexity
    /// Per such lane, one [`Self::parallel`] test against each paint lane (6 quadratic forms)
    /// and a mean distance over ≤ `POINTS` index points against each published lane.
    #[inline(never)]
    fn hold_newcomers(&mut self, young: u32, paint: u32, shown: u32) {
        for s in set_bits(young) {
            let others = !(1u32 << s);
            let hold = persist::apart(set_bits(paint & others).map(|t| self.parallel(s, t)))
                || self.view(s).is_some_and(|(zs, _)| {
                    let extent = self.extent_this_frame(s);
                    set_bits(shown & others).any(|t| self.within_spacing(&zs, extent, t))
                });
            if hold {
                if let Some(info) = self.info.get_mut(s) {
                    info.held = true;
                }
            }
        }
    }

    /// Whether a live lane at positions `zs` over observed extent `(a0, a1)` and live lane `t`
    /// are closer than two markings can be: their mean distance over the index points inside
    /// both observed extents (this frame's and the last `LAG`) is under `2 · min_spacing`, over
    /// at least `min_common` of them.
    #[inline(never)]
    fn within_spacing(&self, zs: &SVector<f32, POINTS>, (a0, a1): (f32, f32), t: usize) -> bool {
        let (Some(tables), Some((zt, _))) = (self.tables, self.view(t)) else {
            return false;
        };
        let (mut dist, mut n) = (0.0f32, 0u32);
        for i in common_points(&tables.index_u, (a0, a1), self.extent_this_frame(t)) {
            let at = |z: &SVector<f32, POINTS>| z.get(i).copied().unwrap_or(f32::NAN);
            dist += (at(zs) - at(&zt)).abs();
            n += 1;
        }
        // A non-finite distance compares false: no hold.
        n >= u32::from(self.cfg.identity.min_common.max(1))
            && dist < 2.0 * self.cfg.persist.min_spacing * n as f32
    }

    /// `(V_rᵀ p)ᵀ Cov(a_s, a_t) (V_rᵀ q)`: the covariance of `pᵀ z_s` and `qᵀ z_t` for the
    /// lanes' positions `z = V_r a` at the index points.
    #[inline(never)]
    fn position_cov(&self, s: usize, t: usize, p: &[f32; POINTS], q: &[f32; POINTS]) -> f32 {
        self.gram_form(s, t, p, q, 0)
    }

    /// [`Self::position_cov`] of the temporal state's block `c` (0: positions, 1: rates).
    fn gram_form(&self, s: usize, t: usize, p: &[f32; POINTS], q: &[f32; POINTS], c: usize) -> f32 {
        let Some(tables) = self.tables else {
            return 0.0;
        };
        if s != t && self.temporal.filter().uncoupled() {
            // Every cross-lane block is exactly zero (`TemporalFilter::uncoupled`).
            return 0.0;
        }
        let r = (tables.gram_rank as usize).min(RANK).min(POINTS);
        let v = &tables.gram_eigvec;
        let coef = |x: &[f32; POINTS]| -> [f32; RANK] {
            core::array::from_fn(|j| {
                if j < r {
                    (0..POINTS)
                        .map(|i| v.get((i, j)).copied().unwrap_or(0.0) * get(x, i))
                        .sum()
                } else {
                    0.0
                }
            })
        };
        // The tests ask for variances (`p` and `q` the same array): one projection then.
        let cp = coef(p);
        let cq = if core::ptr::eq(p, q) { cp } else { coef(q) };
        self.coefficient_form(s, t, &cp, &cq, r, c)
    }

    /// `cpᵀ Cov(a_s, a_t) cq` over the first `r` Gram coefficients of lanes `s` and `t`
    /// (the temporal covariance's position block, `c` = 0; its rate block, `c` = 1).
    /// `r²` multiply-adds.
    fn coefficient_form(
        &self,
        s: usize,
        t: usize,
        cp: &[f32; RANK],
        cq: &[f32; RANK],
        r: usize,
        c: usize,
    ) -> f32 {
        let filter = self.temporal.filter();
        if s != t && filter.uncoupled() {
            // Every cross-lane block is exactly zero (`TemporalFilter::uncoupled`).
            return 0.0;
        }
        let cov = filter.covariance();
        let mut acc = 0.0f32;
        for j in 0..r {
            let row = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, c);
            let mut inner = 0.0f32;
            for k in 0..r {
                let col = TemporalFilter::<LANES, POINTS, RANK, NX>::index(t, k, c);
                inner += cov.get((row, col)).copied().unwrap_or(0.0) * get(cq, k);
            }
            acc += get(cp, j) * inner;
        }
        acc
    }

    /// Index points inside lane `s`'s observed extent of this frame.
    fn observed(&self, s: usize) -> [bool; POINTS] {
        let Some(tables) = self.tables else {
            return [false; POINTS];
        };
        let info = get(&self.info, s);
        core::array::from_fn(|i| {
            let u = tables.index_u.get(i).copied().unwrap_or(f32::NAN);
            info.seen && u >= info.extent[0] && u <= info.extent[1]
        })
    }

    /// The ray test (docs/design.md §11.10) on live lane `s`'s filtered estimate over its
    /// observed extent of this frame, with the covariance of its Gram coefficients plus the
    /// point variance `r` on every index point.
    #[inline(never)]
    pub(super) fn lane_ray_verdict(&self, s: usize) -> RayVerdict {
        let Some(tables) = self.tables else {
            return RayVerdict::Undecided;
        };
        let c = &self.cfg.persist;
        let Some((z, var)) = self.view(s).filter(|_| c.ray_z > 0.0) else {
            return RayVerdict::Undecided;
        };
        let rr = tables.hyper.meas_noise;
        let w: [f32; POINTS] =
            core::array::from_fn(|i| 1.0 / (var.get(i).copied().unwrap_or(f32::NAN) + rr));
        let cov = |p: &[f32; POINTS], q: &[f32; POINTS]| {
            self.position_cov(s, s, p, q) + rr * dotp(p, q)
        };
        ray_stat(&tables.index_u, &z, &self.observed(s), &w, &cov)
            .map_or(RayVerdict::Undecided, |st| st.verdict(c.ray_z, c.ray_resolution))
    }

    /// Live lane `s` moves across the camera's foot point: the rate of its offset there,
    /// `dâ/dt = f_aᵀ ḟ_s` (the ray test's line functional applied to the temporal state's rates
    /// at the index points over this frame's observed extent), is more than `ray_z` standard
    /// deviations from zero (docs/design.md §11.10). A vertical structure's offset at the foot
    /// point is 0 in every frame; the marking under the camera in a lane change crosses it.
    #[inline(never)]
    pub(super) fn lane_moving(&self, s: usize) -> bool {
        let Some(tables) = self.tables else {
            return false;
        };
        let c = &self.cfg.persist;
        let (Some((_, var)), Some((zr, _))) = (
            self.view(s),
            self.temporal.filter().lane_rate(tables, s),
        ) else {
            return false;
        };
        let rr = tables.hyper.meas_noise;
        // The position fit's weights: the same functional f_a.
        let w: [f32; POINTS] =
            core::array::from_fn(|i| 1.0 / (var.get(i).copied().unwrap_or(f32::NAN) + rr));
        let cov = |p: &[f32; POINTS], q: &[f32; POINTS]| self.gram_form(s, s, p, q, 1);
        ray_stat(&tables.index_u, &zr, &self.observed(s), &w, &cov)
            .is_some_and(|st| st.chi2 > c.ray_z * c.ray_z)
    }

    /// Lanes `s` and `t` run parallel over the index points both observed this frame: the slope
    /// of their difference `z_s − z_t` (weighted line fit) is within `ray_z` standard deviations
    /// of zero, with `Cov(z_s − z_t)` from the temporal covariance plus `2r` per index point.
    /// `None` (no test) with fewer than 3 common points ([`persist::parallel`]).
    #[inline(never)]
    fn parallel(&self, s: usize, t: usize) -> Option<bool> {
        let tables = self.tables?;
        let (Some((zs, vs)), Some((zt, vt))) = (self.view(s), self.view(t)) else {
            return None;
        };
        let (os, ot) = (self.observed(s), self.observed(t));
        let rr = tables.hyper.meas_noise;
        let at = |v: &SVector<f32, POINTS>, i: usize| v.get(i).copied().unwrap_or(f32::NAN);
        let present: [bool; POINTS] = core::array::from_fn(|i| get(&os, i) && get(&ot, i));
        let d: [f32; POINTS] = core::array::from_fn(|i| at(&zs, i) - at(&zt, i));
        let w: [f32; POINTS] = core::array::from_fn(|i| 1.0 / (at(&vs, i) + at(&vt, i) + 2.0 * rr));
        persist::parallel(&tables.index_u, &d, &present, &w, self.cfg.persist.ray_z, &|f| {
            self.position_cov(s, s, f, f) + self.position_cov(t, t, f, f)
                - 2.0 * self.position_cov(s, t, f, f)
                + 2.0 * rr * dotp(f, f)
        })
    }

    /// An observation of this frame runs parallel to live lane `t` (its prediction) over the
    /// observation's present index points: [`Tracker::parallel`] with `Cov(z_obs − z_t)` =
    /// the observation's covariance plus the lane's plus `2r` per point (independent: the
    /// observation is this frame's points, the prediction the frames before).
    #[inline(never)]
    pub(super) fn obs_parallel(&self, ob: &LaneObservation<POINTS>, t: usize) -> Option<bool> {
        let tables = self.tables?;
        let (zt, vt) = self.view(t)?;
        let rr = tables.hyper.meas_noise;
        let at = |v: &SVector<f32, POINTS>, i: usize| v.get(i).copied().unwrap_or(f32::NAN);
        let d: [f32; POINTS] = core::array::from_fn(|i| at(&ob.z, i) - at(&zt, i));
        let w: [f32; POINTS] = core::array::from_fn(|i| {
            1.0 / (ob.cov.get((i, i)).copied().unwrap_or(f32::NAN) + at(&vt, i) + 2.0 * rr)
        });
        persist::parallel(&tables.index_u, &d, &ob.present, &w, self.cfg.persist.ray_z, &|f| {
            quadratic_form(&ob.cov, f, f) + self.position_cov(t, t, f, f) + 2.0 * rr * dotp(f, f)
        })
    }

    /// The verdicts of the ray test on every live lane (its estimate over this frame's extent).
    #[inline(never)]
    pub(super) fn lane_ray_verdicts(&self) -> [RayVerdict; LANES] {
        core::array::from_fn(|s| {
            if self.ids.lane(s).is_some() {
                self.lane_ray_verdict(s)
            } else {
                RayVerdict::Undecided
            }
        })
    }

    /// The ray test on one of this frame's observations (its smoothed covariance).
    #[inline(never)]
    pub(super) fn ray_verdict_obs(&self, ob: &LaneObservation<POINTS>) -> RayVerdict {
        let Some(tables) = self.tables else {
            return RayVerdict::Undecided;
        };
        let c = &self.cfg.persist;
        if c.ray_z.is_nan() || c.ray_z <= 0.0 {
            return RayVerdict::Undecided;
        }
        let cov = |p: &[f32; POINTS], q: &[f32; POINTS]| {
            quadratic_form(&ob.cov, p, q) + tables.hyper.meas_noise * dotp(p, q)
        };
        let rr = tables.hyper.meas_noise;
        let w: [f32; POINTS] =
            core::array::from_fn(|i| 1.0 / (ob.cov.get((i, i)).copied().unwrap_or(f32::NAN) + rr));
        ray_stat(&tables.index_u, &ob.z, &ob.present, &w, &cov)
            .map_or(RayVerdict::Undecided, |st| st.verdict(c.ray_z, c.ray_resolution))
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
    /// An established picture: a lane through two known-lane passes (docs/design.md §11.5).
    pub(super) fn tracking(&self) -> bool {
        (0..LANES).any(|t| self.ids.lane(t).is_some_and(|l| l.age > 1))
    }

    /// Whether live lane `s` passes the publication rules of docs/design.md §11.5: existence
    /// at least `p_publish`, not held, and not started this frame while `tracking` (an
    /// established picture); every lane without the known-lane stage.
    fn publishable(&self, s: usize, tracking: bool) -> bool {
        self.ids.lane(s).is_some_and(|lane| {
            let info = get(&self.info, s);
            !self.cfg.persist.enabled
                || (info.existence >= self.cfg.persist.p_publish
                    && !info.held
                    && !(lane.age == 0 && tracking))
        })
    }

    /// The lanes of `candidates` (bit s: slot s would be published) that bound no lane
    /// (docs/design.md §11.14). A candidate is close to one seen this frame (`seen`; a
    /// coasting lane hides none, as it merges none in §11.9) when their distance stays under
    /// `PersistConfig::lane_width` at every index point inside both observed extents (at least
    /// `min_common` of them). A candidate close to one on either side lies inside a lane; of
    /// the others, in a close pair, the one farther from the camera's foot (mean `|z|` over
    /// those points) with no other such candidate beyond it on its side of the other is outside
    /// the outermost lane. 0 with the rule off.
    ///
    /// # Complexity
    /// One pass over the index points per unordered pair of candidates (it fills both lanes'
    /// masks); for a close pair, one more per other candidate: at most `LANES³ · POINTS`
    /// subtractions, `LANES² · POINTS / 2` without a close pair.
    #[inline(never)]
    fn outer_kerbs(&self, candidates: u32, seen: u32) -> u32 {
        let width = self.cfg.persist.lane_width;
        let Some(tables) = self.tables else {
            return 0;
        };
        if width.is_nan() || width <= 0.0 {
            return 0;
        }
        let need = u32::from(self.cfg.identity.min_common.max(1));
        // Each candidate's positions and published extent, once.
        let mut zs = [SVector::<f32, POINTS>::zeros(); LANES];
        let mut ext = [(0.0f32, -1.0f32); LANES];
        for s in set_bits(candidates) {
            if let (Some(z), Some(e), Some((v, _))) = (zs.get_mut(s), ext.get_mut(s), self.view(s)) {
                *z = v;
                *e = self.extent_of(s, 0);
            }
        }
        let at = |s: usize, i: usize| {
            zs.get(s)
                .and_then(|z| z.get(i))
                .copied()
                .unwrap_or(f32::NAN)
        };
        // The index points inside both published extents.
        let common = |s: usize, t: usize| {
            let e = |s: usize| ext.get(s).copied().unwrap_or((0.0, -1.0));
            common_points(&tables.index_u, e(s), e(t))
        };
        // Per candidate, its close partners seen this frame below (−x) and above (+x) it, and
        // those of its close partners it is farther from the camera's foot than.
        let mut below = [0u32; LANES];
        let mut above = [0u32; LANES];
        let mut farther = [0u32; LANES];
        for s in set_bits(candidates) {
            for t in set_bits(candidates & !(2u32 << s).wrapping_sub(1)) {
                if !has_bit(seen, s) && !has_bit(seen, t) {
                    continue;
                }
                // Close: z_s − z_t of one sign and under the width at every common point
                // (a non-finite one is not close); the mean |z| of each over them.
                let (mut pos, mut neg, mut n) = (true, true, 0u32);
                let (mut fs, mut ft) = (0.0f32, 0.0f32);
                for i in common(s, t) {
                    let (a, b) = (at(s, i), at(t, i));
                    let d = a - b;
                    pos &= d > 0.0 && d < width;
                    neg &= d < 0.0 && d > -width;
                    if !(pos || neg) {
                        break;
                    }
                    fs += a.abs();
                    ft += b.abs();
                    n += 1;
                }
                if n < need || !(pos || neg) {
                    continue;
                }
                // s lies above t (pos) or below it.
                let (s_side, t_side) = if pos {
                    (&mut below, &mut above)
                } else {
                    (&mut above, &mut below)
                };
                if has_bit(seen, t) {
                    if let Some(m) = s_side.get_mut(s) {
                        *m |= 1 << t;
                    }
                }
                if has_bit(seen, s) {
                    if let Some(m) = t_side.get_mut(t) {
                        *m |= 1 << s;
                    }
                }
                let (far, near) = if fs > ft { (s, t) } else { (t, s) };
                if fs != ft {
                    if let Some(m) = farther.get_mut(far) {
                        *m |= 1 << near;
                    }
                }
            }
        }
        let get = |m: &[u32; LANES], s: usize| m.get(s).copied().unwrap_or(0);
        // Inside a lane: close to a lane on either side.
        let inside = set_bits(candidates)
            .filter(|&s| get(&below, s) != 0 && get(&above, s) != 0)
            .fold(0u32, |m, s| m | 1 << s);
        let rest = candidates & !inside;
        // The mean of z_r − z_s over their common points (`None` with none).
        let mean_diff = |r: usize, s: usize| {
            let (mut sum, mut n) = (0.0f32, 0u32);
            for i in common(r, s) {
                sum += at(r, i) - at(s, i);
                n += 1;
            }
            (n > 0).then(|| sum / n as f32)
        };
        let mut out = inside;
        for s in set_bits(rest) {
            let b = get(&below, s);
            // Outside the outermost lane: farther than a close partner in `rest`, with no lane
            // of `rest` beyond s on its side of that partner.
            let outer = set_bits((b | get(&above, s)) & get(&farther, s) & rest).any(|t| {
                let side = if has_bit(b, t) { 1.0 } else { -1.0 };
                !set_bits(rest & !(1u32 << s) & !(1u32 << t))
                    .any(|r| mean_diff(r, s).is_some_and(|d| d * side > 0.0))
            });
            if outer {
                out |= 1 << s;
            }
        }
        out
    }

    #[inline(never)]
    pub(super) fn estimates(
        &mut self,
        filtered: &mut Vec<LaneEstimate<POINTS>, LANES>,
        smoothed: &mut Vec<LaneEstimate<POINTS>, LANES>,
    ) {
        let Some(tables) = self.tables else {
            return;
        };
        // An established picture (a lane through two known-lane passes): a lane this frame's
        // points alone started then waits for its first confirming frame (docs/design.md
        // §11.5). In the first two frames after nothing was tracked every lane is published.
        let tracking = self.tracking();
        // The lanes this frame would publish, then those among them that bound no lane.
        let kerbs = if self.cfg.persist.enabled {
            let candidates = (0..LANES.min(32))
                .filter(|&s| self.view(s).is_some() && self.publishable(s, tracking))
                .fold(0u32, |m, s| m | 1 << s);
            let seen = set_bits(candidates)
                .filter(|&s| self.ids.lane(s).is_some_and(|l| l.misses == 0))
                .fold(0u32, |m, s| m | 1 << s);
            self.outer_kerbs(candidates, seen)
        } else {
            0
        };
        for s in 0..LANES {
            let mut published_now = false;
            if let (Some(lane), Some((z, var))) = (self.ids.lane(s), self.view(s)) {
                let (u_first, u_last) = self.extent_of(s, 0);
                if !self.publishable(s, tracking) || has_bit(kerbs, s) {
                    continue;
                }
                published_now = true;
                let info = get(&self.info, s);
                if let Some(info) = self.info.get_mut(s) {
                    info.shown = true;
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
            // The same lane's counters at the current frame (`None` once it is gone, also when
            // a new lane has taken its slot since).
            let now = id_then.and_then(|id| self.ids.lane(s).filter(|l| l.id == id));
            // With the known-lane stage, a smoothed lane is published while its lane is still
            // live and published now (a lane removed since was not one, or is gone).
            let publish_smoothed =
                !self.cfg.persist.enabled || (now.is_some() && published_now);
            if let (true, Some(id), Some((z, var))) = (
                publish_smoothed,
                id_then,
                self.temporal.lagged(tables, s, LAG),
            ) {
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

    /// Slot `s`'s observed extent as it will be published at this frame, before the frame's
    /// extent enters the history ([`Self::push_histories`]): the union of this frame's
    /// observed extent and the `LAG` frames before it, as [`Self::extent_of`]`(s, 0)` after the
    /// push. A lane started this frame has only this frame's.
    pub(super) fn extent_this_frame(&self, s: usize) -> (f32, f32) {
        self.extent_union(s, get(&self.info, s).extent, 0, LAG)
    }

    /// Union of slot `s`'s observed extents over the history frames `from..=from + LAG` (0 is
    /// the current frame once [`Self::push_histories`] has run).
    pub(super) fn extent_of(&self, s: usize, from: usize) -> (f32, f32) {
        self.extent_union(s, [f32::INFINITY, f32::NEG_INFINITY], from, LAG + 1)
    }

    /// Union of `start` and slot `s`'s extents in the history frames `from..from + frames`;
    /// an empty union is the point `u_min`.
    fn extent_union(&self, s: usize, start: [f32; 2], from: usize, frames: usize) -> (f32, f32) {
        let [mut lo, mut hi] = start;
        for h in self.extent.iter().skip(from).take(frames) {
            let [a, b] = get(h, s);
            lo = lo.min(a);
            hi = hi.max(b);
        }
        if lo > hi {
            let u = self.tables.map_or(0.0, |t| t.hyper.u_min);
            (u, u)
        } else {
            (lo, hi)
        }
    }

    /// Lateral position at the nearest index point: the observation's first present point, else
    /// the temporal filter's prediction.
    pub(super) fn bottom_position(&self, s: usize, obs: Option<usize>) -> f32 {
        let Some(tables) = self.tables else {
            return 0.0;
        };
        if let Some(o) = obs.and_then(|i| self.obs.get(i)) {
            if let Some(i) = (0..POINTS).find(|&i| get(&o.present, i)) {
                return o.z.get(i).copied().unwrap_or(0.0);
            }
        }
        self.temporal
            .filter()
            .position(tables, s, 0)
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
        let tables = self.tables?;
        let h = &tables.hyper;
        if !(u.is_finite() && u >= h.u_min && u <= h.u_max) {
            return None;
        }
        let (z, _) = self.temporal.filter().lane(tables, slot)?;
        let r = (tables.gram_rank as usize).min(RANK);
        let l2 = 2.0 * h.spatial_lengthscale * h.spatial_lengthscale;
        let k = SVector::<f32, POINTS>::from_fn(|i, _| {
            let d = u - tables.index_u.get(i).copied().unwrap_or(0.0);
            h.spatial_variance * crate::math::exp(-d * d / l2)
        });
        // c_j = k·v_j / λ_j; f(u) = Σ c_j a_j with a = V_rᵀ z (z = V_r a).
        let v = &tables.gram_eigvec;
        let mut mean = 0.0;
        let mut explained = 0.0;
        let mut cvec = [0.0f32; POINTS];
        for j in 0..r {
            let lam = tables.gram_eigval.get(j).copied().unwrap_or(0.0);
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
        let bss = tables.coreg.get((rank, rank)).copied().unwrap_or(0.0);
        let residual = (h.spatial_variance - explained).max(0.0) * bss;
        Some((mean, var_a + residual))
    }
}

/// The set bits of a slot mask, lowest first: a loop of unknown trip count, which the
/// optimiser leaves rolled.
fn set_bits(mut m: u32) -> impl Iterator<Item = usize> {
    core::iter::from_fn(move || {
        let b = m.trailing_zeros() as usize;
        m &= m.wrapping_sub(1);
        (b < 32).then_some(b)
    })
}

/// The index points inside both extents `(a0, a1)` and `(b0, b1)` (metres along `u`), lowest
/// first; none when they do not overlap.
fn common_points<const POINTS: usize>(
    index_u: &SVector<f32, POINTS>,
    (a0, a1): (f32, f32),
    (b0, b1): (f32, f32),
) -> impl Iterator<Item = usize> + '_ {
    let (lo, hi) = (a0.max(b0), a1.min(b1));
    index_u
        .iter()
        .enumerate()
        .filter(move |(_, u)| **u >= lo && **u <= hi)
        .map(|(i, _)| i)
}

/// Whether bit `s` of `mask` is set (`false` beyond 32 slots).
fn has_bit(mask: u32, s: usize) -> bool {
    s < 32 && mask & (1 << s) != 0
}

/// `pᵀ q`.
fn dotp<const N: usize>(p: &[f32; N], q: &[f32; N]) -> f32 {
    p.iter().zip(q).map(|(a, b)| a * b).sum()
}

/// `pᵀ M q` over the entries where `p` is not zero.
#[inline(never)]
fn quadratic_form<const N: usize>(m: &SMatrix<f32, N, N>, p: &[f32; N], q: &[f32; N]) -> f32 {
    let mut acc = 0.0f32;
    for (i, &pi) in p.iter().enumerate() {
        if pi != 0.0 {
            for (j, &qj) in q.iter().enumerate() {
                acc += pi * m.get((i, j)).copied().unwrap_or(0.0) * qj;
            }
        }
    }
    acc
}

#[cfg(test)]
mod tests {
    use crate::tables::{DEFAULT, UNCOUPLED};
    use crate::tracker::{Instant, ReferenceTracker, TrackerConfig};

    /// Slots by existence, wired: in heavy clutter the table fills with lanes the evidence
    /// turns against, and with `slot_claims` (the default) new candidates take their slots;
    /// with it off none does.
    #[test]
    fn weak_lanes_yield_their_slots_in_heavy_clutter() {
        let mut evicted = [0u32; 2];
        for (on, n) in [true, false].into_iter().zip(evicted.iter_mut()) {
            let mut cfg = TrackerConfig::DEFAULT;
            cfg.persist.slot_claims = on;
            let mut t = Box::new(ReferenceTracker::UNINIT);
            t.init(&DEFAULT, cfg);
            for k in 0..60u32 {
                let mut pts = heapless::Vec::<[f32; 2], 256>::new();
                // Two dashed markings (6 m of paint in 12 m, moving with the car) in dense
                // uniform clutter.
                for x0 in [-1.8f32, 1.8] {
                    for r in 0..40 {
                        let u = 4.0 + 1.5 * r as f32;
                        if (u + 1.2 * k as f32) % 12.0 < 6.0 {
                            let _ = pts.push([u, x0 + 0.03 * ((r * 7 + k as usize) as f32).sin()]);
                        }
                    }
                }
                for c in 0..200u32 {
                    let h = (k * 211 + c * 17) as f32;
                    let u = 4.0 + (h * 0.61).sin().abs() * 58.0;
                    let _ = pts.push([u, (h * 1.37).sin() * 9.0]);
                }
                let out = t.step(Instant::from_micros(i64::from(k) * 50_000), &pts);
                let Ok(out) = out else {
                    panic!("frame {k} refused");
                };
                let r = out.report.identity;
                // An evicted lane is a removed one, and its slot went to a started lane, which
                // the known-lane pass did not see (one hit: its birth).
                assert!(r.removed >= r.evicted && r.started >= r.evicted);
                for s in 0..6 {
                    if let Some(l) = t.ids.lane(s).filter(|l| l.age == 0) {
                        assert_eq!(l.hits, 1, "frame {k}, slot {s}");
                    }
                }
                *n += r.evicted;
            }
        }
        assert!(evicted[0] > 0, "no lane yielded its slot: {evicted:?}");
        assert_eq!(evicted[1], 0);
    }

    /// Every projection the step takes from its views equals a fresh one (the `debug_assert`
    /// in `Tracker::view`, on in tests), over frames that start, update, merge and lose lanes,
    /// on coupled and uncoupled tables; and the views were used.
    #[test]
    fn kept_projections_equal_fresh_ones() {
        for tables in [&DEFAULT, &UNCOUPLED] {
            let mut t = Box::new(ReferenceTracker::UNINIT);
            t.init(tables, TrackerConfig::DEFAULT);
            let mut used = 0u32;
            for k in 0..40u32 {
                let mut pts = heapless::Vec::<[f32; 2], 256>::new();
                // Three markings drifting sideways; the right one disappears after frame 25,
                // a fourth appears at frame 10; a few clutter points per frame.
                let drift = 0.02 * k as f32;
                for (i, x0) in [-3.6f32, 0.1, 3.7, 7.2].into_iter().enumerate() {
                    if (i == 2 && k > 25) || (i == 3 && k < 10) {
                        continue;
                    }
                    for r in 0..40 {
                        let u = 4.0 + 1.5 * r as f32;
                        let x = x0 + drift + 0.002 * u + 1e-4 * u * u;
                        let _ = pts.push([u, x + 0.03 * ((r * 7 + k as usize) as f32).sin()]);
                    }
                }
                for c in 0..12u32 {
                    let h = (k * 31 + c * 17) as f32;
                    let _ = pts.push([5.0 + (h * 0.61).sin().abs() * 60.0, (h * 1.3).sin() * 9.0]);
                }
                let out = t.step(Instant::from_micros(i64::from(k) * 50_000), &pts);
                assert!(out.is_ok());
                used |= t.views.valid;
            }
            assert_ne!(used, 0, "no projection was kept");
        }
    }
}

#[cfg(test)]
mod slot_tests {
    use crate::tables::DEFAULT;
    use crate::tracker::{Instant, ReferenceTracker, StepOutput, TrackerConfig};

    /// One straight marking at `x0` with a small wiggle, 50 rows from 4 m.
    fn lane(x0: f32, k: u32) -> heapless::Vec<[f32; 2], 256> {
        let mut pts = heapless::Vec::new();
        for r in 0..50 {
            let u = 4.0 + 1.2 * r as f32;
            let _ = pts.push([u, x0 + 0.03 * ((r * 7 + k as usize) as f32).sin()]);
        }
        pts
    }

    fn step(t: &mut ReferenceTracker, pts: &[[f32; 2]], k: &mut u32) -> StepOutput<6, 16> {
        let out = t.step(Instant::from_micros(i64::from(*k) * 50_000), pts);
        *k += 1;
        out.unwrap()
    }

    /// docs/design.md §11.5: a lane's smoothed estimate is published while the lane is
    /// published now. A lane removed, whose slot a new lane took within `LAG` frames, must not
    /// have its smoothed estimate published (it was, under the new lane's existence).
    #[test]
    fn a_removed_lanes_smoothed_estimate_is_not_published_after_its_slot_is_reused() {
        let mut t = Box::new(ReferenceTracker::UNINIT);
        t.init(&DEFAULT, TrackerConfig::DEFAULT);
        let mut k = 0u32;
        for _ in 0..12 {
            step(&mut t, &lane(-1.8, k), &mut k);
        }
        assert!(t.ids.lane(0).is_some(), "lane A in slot 0");
        // A disappears until it is removed.
        let mut n = 0;
        while t.ids.lane(0).is_some() {
            step(&mut t, &[], &mut k);
            n += 1;
            assert!(n < 30, "lane A never removed");
        }
        // B appears at once and takes slot 0 (A is in the smoother's window for `LAG` frames).
        let mut reused = false;
        for _ in 0..3 {
            let out = step(&mut t, &lane(1.8, k), &mut k);
            reused |= t.ids.lane(0).is_some();
            for sm in &out.smoothed {
                assert!(
                    out.filtered.iter().any(|l| l.id == sm.id),
                    "smoothed {:?} is not published now",
                    sm.id
                );
            }
        }
        assert!(
            reused,
            "B did not take slot 0: the test does not test the reuse"
        );
    }

    /// A lane the known-lane pass sees this frame has no miss (docs/design.md §11.8), so
    /// `identity.max_misses = 1` (removed at the first miss) must not remove it: it was removed
    /// and restarted with a new id every other frame.
    #[test]
    fn a_lane_the_known_pass_sees_is_not_removed_at_max_misses_one() {
        let mut cfg = TrackerConfig::DEFAULT;
        cfg.identity.max_misses = 1;
        let mut t = Box::new(ReferenceTracker::UNINIT);
        t.init(&DEFAULT, cfg);
        let mut ids = [None; 8];
        let mut k = 0u32;
        for id in &mut ids {
            step(&mut t, &lane(-1.8, k), &mut k);
            *id = t.ids.lane(0).map(|l| l.id);
        }
        assert!(
            ids[0].is_some() && ids.iter().all(|i| *i == ids[0]),
            "{ids:?}"
        );
    }
}
