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

use crate::linalg::{get, set};
use crate::observation::LaneObservation;
use crate::persist::{PassMemory, Persist, RayVerdict, RowBasis};
use crate::probe::{NoProbe, Probe, Stage};
use crate::spatial::filter::{SpatialFilter, SpatialReport};
use crate::tables::Tables;
use crate::temporal::identity::{
    DropReason, IdentityOutcome, IdentityReport, LaneId, LanePrediction, LaneTable, ObsFate,
    SlotFate,
};
use crate::temporal::smoother::{Temporal, MAX_LAG};
pub use crate::time::Instant;

#[derive(Debug, Clone, Copy, PartialEq)]
struct SlotInfo {
    existence: f32,
    extent: [f32; 2],
    seen: bool,
    /// A lane started this frame as a duplicate of a live lane (docs/design.md §11.9): not
    /// published this frame.
    held: bool,
    /// The lane has been published (in a frame's filtered output) since it started.
    shown: bool,
}

const NO_INFO: SlotInfo = SlotInfo {
    existence: 0.0,
    extent: [f32::INFINITY, f32::NEG_INFINITY],
    seen: false,
    held: false,
    shown: false,
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
    /// `None`: [`Tracker::UNINIT`], before [`Tracker::init`].
    tables: Option<&'static Tables<NT, LANES, POINTS>>,
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
    /// Consecutive frames each slot's lane has been a connector (docs/design.md §11.11).
    connector_run: [u8; LANES],
    /// Known lanes' existence and detection probabilities, the clutter estimate.
    persist: Persist<LANES, POINTS, ROWS>,
    /// The known-lane stage's row vectors (computed once for the row geometry).
    basis: RowBasis<RANK, ROWS>,
    /// The known-lane pass's working memory (not state).
    pass_memory: PassMemory<RANK, LANES>,
    /// The lanes' projections at the index points, once per filter state (not state).
    views: Views<LANES, POINTS>,
    last: Option<Instant>,
    frames: u32,
}

/// The reference configuration (docs/design.md §2): D = 6, N = 16, M = 256 (16 per row), R_max = 64,
/// E = 512, L = 4, spatial order 2, Gram rank ≤ 7.
pub type ReferenceTracker = Tracker<2, 3, 6, 16, 64, 16, 256, 7, 84, 42, 4>;

/// The reference configuration compiled for Gram rank 5 (`RANK` = 5, `NX` = 60, `NA` = 30): with
/// [`crate::tables::DEFAULT`] (coupled B) the default model's accuracy within 0.008 on the
/// replay at about 60 % of its Cortex-M4F instructions on the typical clip (3.42 M against 5.79 M,
/// stop 63)
/// and 71 % of [`ReferenceTracker`]'s memory (docs/measurements.md "Fitting the MCU"). On any
/// tables it runs `r = min(gram_rank, 5)` components, bit for bit what [`ReferenceTracker`]
/// publishes on the same tables truncated to rank 5 (host test `rank_capacity`).
pub type Rank5Tracker = Tracker<2, 3, 6, 16, 64, 16, 256, 5, 60, 30, 4>;

/// The reference configuration compiled for Gram rank 4 (`RANK` = 4, `NX` = 48, `NA` = 24): the
/// tracker of the smallest model measured on the Cortex-M4F (with [`crate::tables::UNCOUPLED`]
/// and LBP on every known-lane row, docs/measurements.md "Fitting the MCU"), about 60 % of
/// [`ReferenceTracker`]'s memory and 9 % fewer instructions a frame. On any tables it runs
/// `r = min(gram_rank, 4)` components, bit for bit what [`ReferenceTracker`] publishes on the
/// same tables truncated to rank 4 (host test `rank_capacity`).
pub type Rank4Tracker = Tracker<2, 3, 6, 16, 64, 16, 256, 4, 48, 24, 4>;

/// The reference configuration compiled for Gram rank 3 (`RANK` = 3, `NX` = 36, `NA` = 18): with
/// [`crate::tables::UNCOUPLED`] and LBP on every known-lane row, the cheapest model measured on
/// the Cortex-M4F (1.24 M instructions the typical clip's worst frame, stop 63; 0.99 M before
/// each lane's own `P_D` in its joint events; docs/measurements.md "Fitting the MCU"), at
/// a further accuracy cost against [`Rank4Tracker`]'s. Bit for bit [`ReferenceTracker`] on the
/// same tables truncated to rank 3 (host test `rank_capacity`).
pub type Rank3Tracker = Tracker<2, 3, 6, 16, 64, 16, 256, 3, 36, 18, 4>;

/// An `impl` block of [`Tracker`] over all its parameters: the eleven-parameter header is written
/// once, here, for the files of this module (`impl_tracker! { fn … }`).
macro_rules! impl_tracker {
    ($($item:item)*) => {
        impl<const NT: usize, const NS: usize, const LANES: usize, const POINTS: usize,
             const ROWS: usize, const PER_ROW: usize, const MEAS: usize, const RANK: usize,
             const NX: usize, const NA: usize, const LAG: usize>
            Tracker<NT, NS, LANES, POINTS, ROWS, PER_ROW, MEAS, RANK, NX, NA, LAG>
        {
            $($item)*
        }
    };
}

impl_tracker! {
    const EMPTY_OBS: LaneObservation<POINTS> = LaneObservation::EMPTY;

    /// A tracker on `tables` with the default configuration (`const`: it can live in a `static`).
    pub const fn new(tables: &'static Tables<NT, LANES, POINTS>) -> Self {
        Self::with_config(tables, TrackerConfig::DEFAULT)
    }

    /// A tracker with a given configuration: [`Tracker::UNINIT`] after [`Tracker::init`].
    pub const fn with_config(
        tables: &'static Tables<NT, LANES, POINTS>,
        cfg: TrackerConfig,
    ) -> Self {
        let mut t = Self::UNINIT;
        t.init(tables, cfg);
        t
    }

    /// A tracker with no tables, every byte zero, so that a `static` of it is placed in `.bss`
    /// and takes no flash (a `static` of [`Tracker::new`] is in `.data`: its ~154 KB initial
    /// image is stored in flash). It must be given its tables with [`Tracker::init`] before it
    /// runs; until then [`Tracker::step`] returns [`StepError::NotInitialised`] and it has no
    /// lanes.
    ///
    /// ```
    /// use stjpdacf::tracker::{ReferenceTracker, StepError, TrackerConfig, Instant};
    /// let mut t: Box<ReferenceTracker> = Box::new(ReferenceTracker::UNINIT);
    /// assert_eq!(t.step(Instant::from_micros(0), &[]).err(), Some(StepError::NotInitialised));
    /// t.init(&stjpdacf::tables::DEFAULT, TrackerConfig::DEFAULT);
    /// assert!(t.step(Instant::from_micros(0), &[]).is_ok());
    /// ```
    pub const UNINIT: Self = {
        const { assert!(LAG >= 1 && LAG <= MAX_LAG, "LAG must be 1..=MAX_LAG") };
        const { assert!(MEAS >= 1, "MEAS must be at least 1") };
        const ZERO_INFO: SlotInfo = SlotInfo {
            existence: 0.0,
            extent: [0.0; 2],
            seen: false,
            held: false,
            shown: false,
        };
        Self {
            tables: None,
            cfg: TrackerConfig::ZEROED,
            spatial: SpatialFilter::ZEROED,
            obs: [Self::EMPTY_OBS; LANES],
            ids: LaneTable::new(),
            temporal: Temporal::new(),
            info: [ZERO_INFO; LANES],
            extent: [[[0.0; 2]; LANES]; EXTENT_HISTORY],
            id_hist: [[None; LANES]; MAX_LAG + 1],
            ranks: [0; LANES],
            connector_run: [0; LANES],
            persist: Persist::ZEROED,
            basis: RowBasis::NEW,
            pass_memory: PassMemory::NEW,
            views: Views::NEW,
            last: None,
            frames: 0,
        }
    };

    /// Makes this tracker a fresh one on `tables` with `cfg`, in place: what
    /// [`Tracker::with_config`] returns, without building a ~154 KB value on the stack (so a
    /// `static` [`Tracker::UNINIT`] is set up with a few hundred bytes of stack). Also restarts
    /// a running tracker (a new drive): every lane, estimate and id is forgotten, ids start at
    /// 0 again.
    ///
    /// # Complexity
    /// A `memset` of the tracker (`size_of`, ~154 KB at the reference configuration) and
    /// `O(LANES·(LAG + POINTS))` stores.
    pub const fn init(&mut self, tables: &'static Tables<NT, LANES, POINTS>, cfg: TrackerConfig) {
        *self = Self::UNINIT;
        self.tables = Some(tables);
        self.cfg = cfg;
        self.spatial.clear_meta();
        self.temporal.set_per_lane(cfg.smoother_per_lane);
        self.info = [NO_INFO; LANES];
        self.extent = [[[f32::INFINITY, f32::NEG_INFINITY]; LANES]; EXTENT_HISTORY];
        self.persist.mark_unestimated();
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

    /// The ray test (docs/design.md §11.10) on the lane in `slot` as it stands now (its
    /// estimate over the last frame's observed extent), and whether its offset at the camera's
    /// foot point moves (the motion rule): for diagnostics, e.g. why a lane was or was not taken
    /// for a vertical structure. The step applies the same test before its last stages (merges,
    /// output), so a lane changed by those may read differently here. `(Undecided, false)` for a
    /// free or out-of-range slot.
    ///
    /// # Complexity
    /// One ray test (see [`crate::persist::ray`]) and one motion test.
    pub fn ray_diagnosis(&self, slot: usize) -> (RayVerdict, bool) {
        if slot >= LANES || self.ids.lane(slot).is_none() {
            return (RayVerdict::Undecided, false);
        }
        (self.lane_ray_verdict(slot), self.lane_moving(slot))
    }

    /// One frame: BEV feature points `(u, x)` in metres at time `now`.
    ///
    /// # Errors
    /// [`StepError::NonIncreasingTime`], [`StepError::NotInitialised`]; the state is untouched.
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
        let Some(tables) = self.tables else {
            return Err(StepError::NotInitialised);
        };
        probe.enter(Stage::Binning);
        let dt_us = match self.last {
            Some(last) if now <= last => return Err(StepError::NonIncreasingTime),
            Some(last) => Some(now.as_micros().saturating_sub(last.as_micros())),
            None => None,
        };
        // The filter moves below (prediction, known-lane updates) before the views are taken
        // again; a refused frame (above) leaves everything as it was.
        self.views.clear();
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
            tables,
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
                .predict_scaled_probed(tables, dt, q_scale, probe)
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
            self.known_lanes(tables, &mut report, probe)
        } else {
            0
        };
        // 4. The spatial JPDACF on the remaining points.
        let mut scfg = self.cfg.spatial;
        if self.cfg.persist.enabled {
            scfg.confirm_hits = self.cfg.persist.confirm_hits;
            scfg.tentative_gap_misses = self.cfg.persist.gap_misses;
            scfg.row_noise_scale = self.cfg.persist.row_noise_scale;
        }
        let (n_obs, srep) =
            self.spatial
                .walk_probed(tables, &scfg, srep, &mut self.obs, probe);
        report.spatial = srep;
        probe.enter(Stage::Identity);
        // 5. Identity against the predictions (a lane the known-lane pass saw has no miss).
        for s in 0..LANES {
            if known & (1 << s) != 0 {
                self.ids.reset_misses(s);
            }
        }
        let outcome = self.associate(n_obs, known);
        report.identity = outcome.report;
        report.known.ray_refused = outcome
            .obs
            .iter()
            .filter(|f| matches!(f, ObsFate::Dropped(DropReason::Refused)))
            .count() as u32;
        // A slot yielded this frame (docs/design.md §11.13) holds a new lane: the known-lane
        // pass saw the lane it replaced, not this one.
        let mut known = known;
        for (s, fate) in outcome.slots.iter().enumerate() {
            if matches!(fate, SlotFate::New { replaced: Some(_), .. }) {
                known &= !(1 << s);
            }
        }
        for s in 0..LANES {
            if known & (1 << s) != 0 {
                let counted = matches!(outcome.slots.get(s), Some(SlotFate::Matched { .. }));
                self.ids.mark_seen(s, counted);
            }
        }
        probe.enter(Stage::Temporal);
        // 6. Removed lanes leave the temporal filter, new lanes start, seen lanes are updated.
        // The filter changes here: its projections are taken again after.
        self.views.clear();
        self.temporal_stage(tables, &outcome.slots, known, &mut report, probe);
        self.refresh_views();
        if self.cfg.persist.enabled {
            probe.enter(Stage::Known);
            self.maintain_known(&outcome.slots, &mut report);
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
    fn associate(&mut self, n_obs: usize, known: u32) -> IdentityOutcome<LANES> {
        self.refresh_views();
        let mut preds = [LanePrediction::<POINTS>::EMPTY; LANES];
        for (s, p) in preds.iter_mut().enumerate() {
            if let Some((z, var)) = self.view(s) {
                *p = LanePrediction {
                    present: [true; POINTS],
                    z,
                    var,
                };
            }
        }
        let obs = self.obs.get(..n_obs).unwrap_or(&[]);
        let mut may_start = [true; LANES];
        if self.cfg.persist.enabled {
            // A vertical structure starts no lane: a ray unless it runs parallel to a lane
            // that is paint (the marking under the camera), an aligned observation when it runs
            // parallel to none of them (docs/design.md §11.10).
            let mut verdicts = None;
            let aligned = self.cfg.persist.ray_aligned;
            for (m, ob) in may_start.iter_mut().zip(obs) {
                let own = self.ray_verdict_obs(ob);
                if matches!(own, RayVerdict::Ray | RayVerdict::Aligned) {
                    let v = *verdicts.get_or_insert_with(|| self.lane_ray_verdicts());
                    *m = !crate::persist::vertical(
                        own,
                        aligned,
                        (0..LANES)
                            .filter(|&t| get(&v, t) == RayVerdict::Paint)
                            .map(|t| self.obs_parallel(ob, t)),
                    );
                }
            }
        }
        let hold = self.slot_holds();
        self.ids.associate_claims(
            &preds,
            obs,
            &self.cfg.identity,
            &may_start,
            hold.as_ref(),
            known,
        )
    }

    /// Steps 4 and 5: removed lanes leave the temporal filter; new lanes start in rank order among
    /// the lanes present (B's slots); the seen lanes are updated; the covariance is repaired and
    /// the lanes present are re-ranked (slots = rank from the left at the bottom of the window).
    /// Inlined: the stages of one step share its stack frame, as before they were split.
    #[inline(always)]
    fn temporal_stage<P: Probe>(
        &mut self,
        tables: &'static Tables<NT, LANES, POINTS>,
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
                set(&mut self.connector_run, s, 0);
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
                let rate = self.obs.get(usize::from(*obs)).map_or(0.5, |o| o.existence);
                let k = f32::from(self.cfg.spatial.rows_per_interval.max(1));
                self.persist.seed_pd(s, rate, k);
                let x = self.bottom_position(s, Some(usize::from(*obs)));
                let ranks = self.ranks_of(Some((s, x)));
                if self
                    .temporal
                    .start_lane(tables, s, get(&ranks, s), &ranks)
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
                        match self.temporal.update_probed(tables, s, ob, probe) {
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
        report.temporal_cov_repairs = self.temporal.repair_covariance(tables);
        // The ranks of the active lanes are a permutation by construction, so this does not fail;
        // if it did, the filter would keep its ranks and the failure would be counted.
        let ranks = self.ranks_of(None);
        match self.temporal.set_ranks(&ranks) {
            Ok(()) => self.ranks = ranks,
            Err(_) => report.temporal_failures += 1,
        }
    }
}

mod stages;
mod types;

use stages::Views;

pub use types::{KnownReport, LaneEstimate, StepError, StepOutput, StepReport, TrackerConfig};
