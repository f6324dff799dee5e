//! The per-frame facade: feature points in, lanes out.
//!
//! `Tracker::step(now, points)` runs the whole pipeline of docs/design.md §1 on one frame: the spatial
//! JPDACF ([`crate::spatial::filter`]) turns the BEV points into confirmed lanes with
//! pseudo-measurements at the index points; lane identity ([`crate::temporal::identity`]) matches
//! them to the temporal lanes; the temporal coupled filter with its fixed-lag smoother
//! ([`crate::temporal::smoother`]) predicts over the frame step and updates. It returns the
//! filtered lanes at this frame, the smoothed lanes `LAG` frames back, and a report.
//!
//! # Contract
//! * `now` must increase strictly: otherwise [`StepError::NonIncreasingTime`] and the state is
//!   untouched. Any positive step works (dropped frames).
//! * At most `MEAS` points are used; the excess is counted (`over_budget_points`). Non-finite,
//!   out-of-window and duplicated points are rejected and counted by the spatial filter.
//! * Numerical failures of the temporal filter are counted and leave its state as it was.
//! * No allocation, no panics, no recursion; bounded work (the sum of the stages' bounds).
//!
//! ```
//! use stjpdacf::tracker::{Instant, ReferenceTracker};
//! let mut t: Box<ReferenceTracker> = Box::new(ReferenceTracker::new(&stjpdacf::tables::DEFAULT));
//! // Two straight lanes, 3.6 m apart, one point per BEV row.
//! let pts: Vec<[f32; 2]> = (0..60)
//!     .flat_map(|r| { let u = 3.0 + r as f32 * 77.0 / 60.0; [[u, -1.8], [u, 1.8]] })
//!     .collect();
//! let out = t.step(Instant::from_micros(0), &pts)?;
//! assert_eq!(out.filtered.len(), 2);
//! assert!(t.step(Instant::from_micros(0), &pts).is_err()); // time must increase
//! # Ok::<(), stjpdacf::tracker::StepError>(())
//! ```

use heapless::Vec;
use nalgebra::SVector;

use crate::linalg::{get, set};
use crate::observation::LaneObservation;
use crate::persist::{Evidence, Explained, Lanes, Pass, Persist, PersistConfig};
use crate::probe::{NoProbe, Probe, Stage};
use crate::spatial::filter::{Config as SpatialConfig, SpatialFilter, SpatialReport};
use crate::tables::Tables;
use crate::temporal::filter::TemporalFilter;
use crate::temporal::identity::{
    IdentityConfig, IdentityOutcome, IdentityReport, LaneId, LanePrediction, LaneTable, SlotFate,
};
use crate::temporal::smoother::{Temporal, MAX_LAG};
pub use crate::time::Instant;

/// Error of [`Tracker::step`]; the tracker's state is untouched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum StepError {
    /// `now` is not after the previous frame's time.
    NonIncreasingTime,
}

impl core::fmt::Display for StepError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("frame time does not increase")
    }
}

impl core::error::Error for StepError {}

/// Tuning of the whole tracker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerConfig {
    /// The spatial JPDACF.
    pub spatial: SpatialConfig,
    /// Lane identity.
    pub identity: IdentityConfig,
    /// Each frame a lane is not seen multiplies its existence by this factor (round-1
    /// pipeline only, `persist.enabled == false`).
    pub existence_decay: f32,
    /// Known lanes, existence probability, estimated clutter (docs/design.md §11).
    pub persist: PersistConfig,
}

impl TrackerConfig {
    /// Defaults of the stages.
    pub const DEFAULT: Self = Self {
        spatial: SpatialConfig::DEFAULT,
        identity: IdentityConfig::DEFAULT,
        existence_decay: 0.8,
        persist: PersistConfig::DEFAULT,
    };

    /// The round-1 pipeline: no temporal prior in the association (the ablation).
    pub const ROUND1: Self = Self {
        persist: PersistConfig::ROUND1,
        ..Self::DEFAULT
    };
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One lane as published.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneEstimate<const POINTS: usize> {
    /// Stable id.
    pub id: LaneId,
    /// Temporal slot (for [`Tracker::lane_at`]).
    pub slot: u8,
    /// Lateral position at each index point, metres.
    pub z: SVector<f32, POINTS>,
    /// Its variance, m².
    pub var: SVector<f32, POINTS>,
    /// Observed extent, metres ahead: the union over the `LAG + 1` frames ending at the lane's
    /// frame (the current one for filtered lanes, `LAG` frames back for smoothed lanes).
    pub u_first: f32,
    /// Far end of the observed extent.
    pub u_last: f32,
    /// Existence figure in [0, 1] (spatial existence when seen, decaying while coasting).
    pub existence: f32,
    /// Frames since the lane was last seen (0 when seen this frame).
    pub misses: u16,
    /// Frames since the lane started (0 in its first frame); for a smoothed lane, its age at the
    /// current frame (0 once it is gone).
    pub age: u32,
    /// Frames in which the lane was observed, its first frame included (same convention as
    /// `age` for smoothed lanes).
    pub hits: u32,
}

/// What one frame did (`repr(C)`: the C API hands it to C as is).
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C)]
pub struct StepReport {
    /// The spatial filter's counters.
    pub spatial: SpatialReport,
    /// Lane identity's counters.
    pub identity: IdentityReport,
    /// Points beyond `MEAS`, ignored.
    pub over_budget_points: u32,
    /// Temporal operations that failed numerically (state kept).
    pub temporal_failures: u32,
    /// Frame step used, seconds (0 for the first frame).
    pub dt: f32,
    /// Lane updates whose pseudo-measurement covariance was not positive definite and was
    /// repaired (see [`crate::temporal::filter::TemporalFilter::update`]).
    pub pseudo_cov_repairs: u32,
    /// Pivots of the temporal covariance raised after this frame's lane updates because f32
    /// rounding had made it indefinite (see
    /// [`crate::temporal::filter::TemporalFilter::repair_covariance`]; 0 on almost every frame).
    pub temporal_cov_repairs: u32,
    /// The known-lane stage's counters (all 0 when it is off).
    pub known: KnownReport,
}

/// What the known-lane stage (docs/design.md §11) did in one frame (`repr(C)`: the C API hands
/// it to C as is).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(C)]
pub struct KnownReport {
    /// Live lanes associated against their prediction.
    pub lanes: u32,
    /// Of those, lanes seen (a row with `W ≥ 0.5`).
    pub seen: u32,
    /// Points the known lanes explained (removed before the spatial filter).
    pub explained_points: u32,
    /// Rows whose joint events failed numerically (every lane missed there).
    pub failed_rows: u32,
    /// Lanes deleted because their existence fell below `p_delete`.
    pub deleted: u32,
    /// Lanes removed as duplicates of another (one lane, one track).
    pub merged: u32,
    /// The process-noise scale used by this frame's prediction.
    pub q_scale: f32,
}

/// The output of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct StepOutput<const LANES: usize, const POINTS: usize> {
    /// Filtered lanes at this frame.
    pub filtered: Vec<LaneEstimate<POINTS>, LANES>,
    /// Smoothed lanes `LAG` frames back (empty until the window is full).
    pub smoothed: Vec<LaneEstimate<POINTS>, LANES>,
    /// Counters.
    pub report: StepReport,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct SlotInfo {
    existence: f32,
    extent: [f32; 2],
    seen: bool,
}

const NO_INFO: SlotInfo = SlotInfo {
    existence: 0.0,
    extent: [f32::INFINITY, f32::NEG_INFINITY],
    seen: false,
};

impl Default for SlotInfo {
    fn default() -> Self {
        NO_INFO
    }
}

/// Frames of extent history the tracker keeps: `2·LAG + 1` at the largest lag.
const EXTENT_HISTORY: usize = 2 * MAX_LAG + 1;

/// The tracker. Type parameters: `NT` spatial Taylor order, `NS = NT + 1`, `LANES`, `POINTS`
/// index points, `ROWS`/`PER_ROW` the spatial filter's capacities, `MEAS` points per frame,
/// `RANK` retained Gram components, `NX = 2·LANES·RANK`, `NA = LANES·RANK`, `LAG` frames. Use the
/// [`ReferenceTracker`] alias for the reference configuration.
#[derive(Debug, Clone)]
pub struct Tracker<
    const NT: usize,
    const NS: usize,
    const LANES: usize,
    const POINTS: usize,
    const ROWS: usize,
    const PER_ROW: usize,
    const MEAS: usize,
    const RANK: usize,
    const NX: usize,
    const NA: usize,
    const LAG: usize,
> {
    tables: &'static Tables<NT, LANES, POINTS>,
    cfg: TrackerConfig,
    spatial: SpatialFilter<NS, LANES, ROWS, PER_ROW>,
    obs: [LaneObservation<POINTS>; LANES],
    ids: LaneTable<LANES>,
    temporal: Temporal<LANES, POINTS, RANK, NX, NA, LAG>,
    info: [SlotInfo; LANES],
    /// Extent history per slot: `[u_first, u_last]` of the last `2·LAG + 1` frames'
    /// observations: the filtered lanes' extents cover frames `k−LAG..=k`, the smoothed lanes'
    /// (frame `k − LAG`) frames `k−2·LAG..=k−LAG`.
    extent: [[[f32; 2]; LANES]; EXTENT_HISTORY],
    /// Slot → id `j` frames back, `j = 0..=LAG` (for the smoothed output).
    id_hist: [[Option<LaneId>; LANES]; MAX_LAG + 1],
    /// B slot (rank from the left) of each active lane after the last step.
    ranks: [u8; LANES],
    /// Known lanes' existence and detection probabilities, the clutter estimate.
    persist: Persist<LANES, POINTS, ROWS>,
    last: Option<Instant>,
    frames: u32,
}

/// The reference configuration (docs/design.md §2): D = 6, N = 16, M = 256 (16 per row), R_max = 64,
/// E = 512, L = 4, spatial order 2, Gram rank ≤ 7.
pub type ReferenceTracker = Tracker<2, 3, 6, 16, 64, 16, 256, 7, 84, 42, 4>;

impl<
        const NT: usize,
        const NS: usize,
        const LANES: usize,
        const POINTS: usize,
        const ROWS: usize,
        const PER_ROW: usize,
        const MEAS: usize,
        const RANK: usize,
        const NX: usize,
        const NA: usize,
        const LAG: usize,
    > Tracker<NT, NS, LANES, POINTS, ROWS, PER_ROW, MEAS, RANK, NX, NA, LAG>
{
    const EMPTY_OBS: LaneObservation<POINTS> = LaneObservation::EMPTY;

    /// A tracker on `tables` with the default configuration (`const`: it can live in a `static`).
    pub const fn new(tables: &'static Tables<NT, LANES, POINTS>) -> Self {
        Self::with_config(tables, TrackerConfig::DEFAULT)
    }

    /// A tracker with a given configuration.
    pub const fn with_config(
        tables: &'static Tables<NT, LANES, POINTS>,
        cfg: TrackerConfig,
    ) -> Self {
        const { assert!(LAG >= 1 && LAG <= MAX_LAG, "LAG must be 1..=MAX_LAG") };
        const { assert!(MEAS >= 1, "MEAS must be at least 1") };
        Self {
            tables,
            cfg,
            spatial: SpatialFilter::new(),
            obs: [Self::EMPTY_OBS; LANES],
            ids: LaneTable::new(),
            temporal: Temporal::new(),
            info: [NO_INFO; LANES],
            extent: [[[f32::INFINITY, f32::NEG_INFINITY]; LANES]; EXTENT_HISTORY],
            id_hist: [[None; LANES]; MAX_LAG + 1],
            ranks: [0; LANES],
            persist: Persist::new(),
            last: None,
            frames: 0,
        }
    }

    /// Frames processed.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// The temporal stage (filter with its covariance, fixed-lag window), read-only: for
    /// diagnostics and the reliability checks (covariance symmetry and PSD, soak).
    pub fn temporal(&self) -> &Temporal<LANES, POINTS, RANK, NX, NA, LAG> {
        &self.temporal
    }

    /// The known-lane stage's estimates (existence, detection, clutter, point variance).
    pub fn persist(&self) -> &Persist<LANES, POINTS, ROWS> {
        &self.persist
    }

    /// One frame: BEV feature points `(u, x)` in metres at time `now`.
    ///
    /// # Errors
    /// [`StepError::NonIncreasingTime`]; the state is untouched.
    ///
    /// # Complexity
    /// The spatial filter's bound (see [`crate::spatial::filter`]) + identity (≤ 13,327 leaves at
    /// D = 6) + the temporal filter and smoother (`O(NX²·POINTS·LAG)` per seen lane).
    pub fn step(
        &mut self,
        now: Instant,
        points: &[[f32; 2]],
    ) -> Result<StepOutput<LANES, POINTS>, StepError> {
        self.step_probed(now, points, &mut NoProbe)
    }

    /// [`Tracker::step`] reporting every stage transition to `probe` (see [`crate::probe`]); the
    /// last call is `probe.enter(Stage::Done)`, also when the frame is refused.
    ///
    /// # Errors
    /// As [`Tracker::step`].
    ///
    /// # Complexity
    /// As [`Tracker::step`], plus one `probe.enter` per stage transition (a few per BEV row).
    pub fn step_probed<P: Probe>(
        &mut self,
        now: Instant,
        points: &[[f32; 2]],
        probe: &mut P,
    ) -> Result<StepOutput<LANES, POINTS>, StepError> {
        let out = self.step_inner(now, points, probe);
        probe.enter(Stage::Done);
        out
    }

    fn step_inner<P: Probe>(
        &mut self,
        now: Instant,
        points: &[[f32; 2]],
        probe: &mut P,
    ) -> Result<StepOutput<LANES, POINTS>, StepError> {
        probe.enter(Stage::Binning);
        let dt_us = match self.last {
            Some(last) if now <= last => return Err(StepError::NonIncreasingTime),
            Some(last) => Some(now.as_micros().saturating_sub(last.as_micros())),
            None => None,
        };
        let dt = dt_us.map_or(0.0, |us| us as f32 * 1e-6);
        let used = points.len().min(MEAS);
        let mut report = StepReport {
            spatial: SpatialReport::default(),
            identity: IdentityReport::default(),
            over_budget_points: (points.len() - used) as u32,
            temporal_failures: 0,
            dt,
            pseudo_cov_repairs: 0,
            temporal_cov_repairs: 0,
            known: KnownReport::default(),
        };
        // 1. The points into BEV rows.
        for o in &mut self.obs {
            *o = Self::EMPTY_OBS;
        }
        let srep = self.spatial.bin(
            self.tables,
            &self.cfg.spatial,
            points.get(..used).unwrap_or(&[]),
        );
        // 2. Temporal prediction to now.
        let q_scale = if self.cfg.persist.enabled {
            self.persist.q_scale()
        } else {
            1.0
        };
        report.known.q_scale = if self.cfg.persist.enabled {
            q_scale
        } else {
            0.0
        };
        if dt > 0.0
            && self
                .temporal
                .predict_scaled_probed(self.tables, dt, q_scale, probe)
                .is_err()
        {
            report.temporal_failures += 1;
        }
        // 3. Known lanes against their prediction; the points they explain leave the rows.
        let known = if self.cfg.persist.enabled {
            probe.enter(Stage::Known);
            self.persist.predict(dt, &self.cfg.persist);
            if let Some(pass) = self.pass() {
                let spatial = &self.spatial;
                self.persist
                    .observe_spans(pass.rows, pass.k_rows, |r| spatial.row_points(r));
            }
            self.known_lanes(&mut report, probe)
        } else {
            0
        };
        // 4. The spatial JPDACF on the remaining points.
        let mut scfg = self.cfg.spatial;
        if self.cfg.persist.enabled {
            scfg.confirm_hits = self.cfg.persist.confirm_hits;
        }
        let (n_obs, srep) =
            self.spatial
                .walk_probed(self.tables, &scfg, srep, &mut self.obs, probe);
        report.spatial = srep;
        probe.enter(Stage::Identity);
        // 5. Identity against the predictions (a lane the known-lane pass saw has no miss).
        for s in 0..LANES {
            if known & (1 << s) != 0 {
                self.ids.reset_misses(s);
            }
        }
        let outcome = self.associate(n_obs);
        report.identity = outcome.report;
        for s in 0..LANES {
            if known & (1 << s) != 0 {
                let counted = matches!(outcome.slots.get(s), Some(SlotFate::Matched { .. }));
                self.ids.mark_seen(s, counted);
            }
        }
        probe.enter(Stage::Temporal);
        // 6. Removed lanes leave the temporal filter, new lanes start, seen lanes are updated.
        self.temporal_stage(&outcome.slots, known, &mut report, probe);
        if self.cfg.persist.enabled {
            probe.enter(Stage::Known);
            self.new_lane_existence(&outcome.slots);
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
        // 6. Extent and id histories.
        self.push_histories();
        // 7. Output.
        probe.enter(Stage::Output);
        let mut filtered = Vec::new();
        let mut smoothed = Vec::new();
        self.estimates(&mut filtered, &mut smoothed);
        self.last = Some(now);
        self.frames = self.frames.saturating_add(1);
        Ok(StepOutput {
            filtered,
            smoothed,
            report,
        })
    }

    /// Step 3: this frame's observations against the temporal predictions.
    // Not inlined: its predictions (~0.9 KiB) must not add to the temporal stage's stack.
    #[inline(never)]
    fn associate(&mut self, n_obs: usize) -> IdentityOutcome<LANES> {
        let mut preds = [LanePrediction::<POINTS>::EMPTY; LANES];
        for (s, p) in preds.iter_mut().enumerate() {
            if let Some((z, var)) = self.temporal.filter().lane(self.tables, s) {
                *p = LanePrediction {
                    present: [true; POINTS],
                    z,
                    var,
                };
            }
        }
        self.ids.associate(
            &preds,
            self.obs.get(..n_obs).unwrap_or(&[]),
            &self.cfg.identity,
        )
    }

    /// Steps 4 and 5: removed lanes leave the temporal filter; new lanes start in rank order among
    /// the lanes present (B's slots); the seen lanes are updated; the covariance is repaired and
    /// the lanes present are re-ranked (slots = rank from the left at the bottom of the window).
    /// Inlined: the stages of one step share its stack frame, as before they were split.
    #[inline(always)]
    fn temporal_stage<P: Probe>(
        &mut self,
        slots: &[SlotFate; LANES],
        known: u32,
        report: &mut StepReport,
        probe: &mut P,
    ) {
        for (s, fate) in slots.iter().enumerate() {
            let removed = matches!(fate, SlotFate::Removed { .. })
                || matches!(
                    fate,
                    SlotFate::New {
                        replaced: Some(_),
                        ..
                    }
                );
            if removed {
                self.temporal.remove_lane(s);
                self.persist.remove(s);
                set(&mut self.info, s, NO_INFO);
                for h in self.extent.iter_mut() {
                    set(h, s, [f32::INFINITY, f32::NEG_INFINITY]);
                }
            }
        }
        for (s, fate) in slots.iter().enumerate() {
            if let SlotFate::New { obs, .. } = fate {
                self.persist.start(s, &self.cfg.persist);
                let x = self.bottom_position(s, Some(usize::from(*obs)));
                let ranks = self.ranks_of(Some((s, x)));
                if self
                    .temporal
                    .start_lane(self.tables, s, get(&ranks, s), &ranks)
                    .is_err()
                {
                    report.temporal_failures += 1;
                }
            }
        }
        for (s, fate) in slots.iter().enumerate() {
            let o = match fate {
                SlotFate::Matched { obs } | SlotFate::New { obs, .. } => Some(usize::from(*obs)),
                _ => None,
            };
            let info = self.info.get_mut(s);
            match (o.and_then(|i| self.obs.get(i)), info) {
                (Some(ob), Some(info)) => {
                    if self.temporal.filter().is_active(s) {
                        match self.temporal.update_probed(self.tables, s, ob, probe) {
                            Ok(u) => {
                                report.pseudo_cov_repairs += u32::from(u.repaired_pivots > 0);
                            }
                            Err(_) => report.temporal_failures += 1,
                        }
                    }
                    info.existence = ob.existence;
                    info.seen = true;
                    if known & (1 << s) != 0 {
                        info.extent = [
                            info.extent[0].min(ob.u_first),
                            info.extent[1].max(ob.u_last),
                        ];
                    } else {
                        info.extent = [ob.u_first, ob.u_last];
                    }
                }
                (None, Some(info)) if known & (1 << s) == 0 => {
                    info.existence *= self.cfg.existence_decay;
                    info.seen = false;
                    info.extent = [f32::INFINITY, f32::NEG_INFINITY];
                }
                _ => {}
            }
        }
        probe.enter(Stage::Temporal);
        report.temporal_cov_repairs = self.temporal.repair_covariance(self.tables);
        // The ranks of the active lanes are a permutation by construction, so this does not fail;
        // if it did, the filter would keep its ranks and the failure would be counted.
        let ranks = self.ranks_of(None);
        match self.temporal.set_ranks(&ranks) {
            Ok(()) => self.ranks = ranks,
            Err(_) => report.temporal_failures += 1,
        }
    }

    /// Step 3 (docs/design.md §11): the live lanes' row evidence against their prediction, the
    /// temporal update with it, their existence; the points they explain leave the rows.
    /// Returns the lanes seen (bit = slot).
    #[inline(never)]
    fn known_lanes<P: Probe>(&mut self, report: &mut StepReport, probe: &mut P) -> u32 {
        let Some(pass) = self.pass() else {
            return 0;
        };
        let mut live = 0u32;
        for s in 0..LANES {
            if self.temporal.filter().is_active(s) && self.ids.lane(s).is_some() {
                live |= 1 << s;
            }
        }
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
            report.known.failed_rows = self.persist.associate(
                self.tables,
                self.temporal.filter(),
                &lanes,
                &pass,
                &self.cfg.persist,
                |r| spatial.row_points(r),
                true,
                &mut ev,
                &mut explained,
            );
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
            self.temporal.filter(),
            live,
            &self.ranks,
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

    /// The row pass parameters of the known-lane stage.
    fn pass(&self) -> Option<Pass> {
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
    fn remove_slot(&mut self, s: usize) {
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
    fn push_histories(&mut self) {
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
    fn estimates(
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
    fn extent_of(&self, s: usize, from: usize) -> (f32, f32) {
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
    fn bottom_position(&self, s: usize, obs: Option<usize>) -> f32 {
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
    fn ranks_of(&self, new: Option<(usize, f32)>) -> [u8; LANES] {
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
