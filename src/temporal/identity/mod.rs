//! Lane identity (docs/design.md §4.3): this frame's spatial lanes are assigned to the temporal lanes
//! of the previous frames; unassigned spatial lanes start lanes with fresh ids, temporal lanes
//! without a spatial lane coast and are removed after a miss budget.
//!
//! # Cost and gate
//! For an observation `o` (a [`LaneObservation`]) and a temporal lane's prediction `p` (a
//! [`LanePrediction`]), over the index points present in both (the *common* points `C`):
//!
//! `cost(o, p) = (1/|C|) Σ_{i∈C} (z_o,i − z_p,i)² / (σ²_o,i + σ²_p,i)`,
//!
//! a normalised squared distance in curve space (`σ²_o,i` is the diagonal of the observation's
//! covariance). A pair is *allowed* only if `|C| ≥ min_common`, every value it reads is finite,
//! both variances are `≥ 0` with a positive sum, and `cost ≤ gate`. A pair that reads a non-finite
//! value (or a negative or zero-sum variance) is not allowed and is counted in
//! [`IdentityReport::non_finite_pairs`].
//!
//! # Assignment
//! Among all assignments (each observation to at most one lane, each lane to at most one
//! observation, allowed pairs only) the one with the least total
//!
//! `Σ_{matched (o,p)} cost(o, p) + gate · (#unmatched observations + #unmatched live lanes)`
//!
//! is chosen. It is found by exhaustive depth-first search over the injective partial maps from
//! observations to lanes, with an explicit stack of depth ≤ `LANES` (no recursion) and
//! branch-and-bound pruning (a partial total already `≥` the best total is abandoned; all terms
//! are `≥ 0`). Candidates are tried observation by observation, in slot order `0, 1, …` and then
//! "unmatched"; a leaf replaces the best only when strictly cheaper, so ties go to the first
//! assignment in that order — the result is deterministic.
//!
//! # Complexity
//! With `n` observations and `m` live lanes, the search visits at most
//! `Σ_k C(n,k)·C(m,k)·k!` leaves, each O(1) (a popcount and a compare), and at most `LANES + 1`
//! candidate steps per internal node; pruning and gating usually cut this to a few dozen. Worst
//! cases (every pair allowed, no pruning): `LANES = 4`: 209 leaves; `6`: 13 327; `7`: 130 922;
//! `8` ([`MAX_LANES`]): 1 441 729. The cost matrix costs `n·m·POINTS` divisions. The number of
//! leaves visited is reported in [`IdentityReport::leaves`]. No allocation, no recursion.
//!
//! # Ids
//! Ids come from a `u32` counter that only increases: an id is never reused while the lane lives,
//! and never reused at all until the counter wraps after 2³² lane starts (at 30 fps and one
//! start per frame, 4.5 years; at six starts every frame, 0.75 years). On wrap the counter
//! continues at 0 and skips any id still held by a live lane, so live ids stay unique.
//!
//! ```
//! use nalgebra::{SMatrix, SVector};
//! use stjpdacf::spatial::filter::{LaneObservation, Status};
//! use stjpdacf::temporal::identity::{IdentityConfig, LanePrediction, LaneTable, ObsFate};
//!
//! let obs = LaneObservation::<4> {
//!     status: Status::Confirmed,
//!     present: [true; 4],
//!     z: SVector::from([1.8, 1.8, 1.9, 2.0]),
//!     cov: SMatrix::from_diagonal_element(0.05),
//!     u_first: 3.0,
//!     u_last: 80.0,
//!     existence: 1.0,
//!     rank: 0,
//!     llr: 0.0,
//! };
//! let mut table: LaneTable<2> = LaneTable::new();
//! let cfg = IdentityConfig::default();
//! let none = [LanePrediction::EMPTY; 2];
//! let first = table.associate(&none, &[obs], &cfg);
//! assert_eq!(first.obs_fates()[0], ObsFate::New { slot: 0 });
//! let id = table.lane(0).map(|l| l.id);
//!
//! // Next frame: predict slot 0 where it was seen, and the same lane matches it.
//! let preds = [LanePrediction::from_observation(&obs, 0.1), LanePrediction::EMPTY];
//! let second = table.associate(&preds, &[obs], &cfg);
//! assert_eq!(second.obs_fates()[0], ObsFate::Matched { slot: 0 });
//! assert_eq!(table.lane(0).map(|l| l.id), id);
//! ```

use nalgebra::SVector;

use crate::observation::LaneObservation;

mod search;
use search::search;

/// Largest supported `LANES` (lane masks are `u32`; the search bound grows as `Σ C(D,k)² k!`).
pub const MAX_LANES: usize = 8;

/// Marker for "no lane" in the search.
const NONE: u8 = u8::MAX;

/// Id of a temporal lane, unique among live lanes (see the module docs for wrapping).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LaneId(pub u32);

/// A temporal lane's prediction for this frame at the `POINTS` index points (the matcher's input).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LanePrediction<const POINTS: usize> {
    /// Index point `i` carries a valid prediction.
    pub present: [bool; POINTS],
    /// Predicted lateral position at each index point, metres.
    pub z: SVector<f32, POINTS>,
    /// Variance of each predicted position, m².
    pub var: SVector<f32, POINTS>,
}

impl<const POINTS: usize> LanePrediction<POINTS> {
    /// A prediction with no valid point (for free slots).
    pub const EMPTY: Self = Self {
        present: [false; POINTS],
        z: SVector::from_array_storage(nalgebra::ArrayStorage([[0.0; POINTS]; 1])),
        var: SVector::from_array_storage(nalgebra::ArrayStorage([[0.0; POINTS]; 1])),
    };

    /// The "nothing moved" prediction: the observation's positions and diagonal variances plus
    /// `extra_var` (m²) at every point. O(POINTS).
    pub fn from_observation(obs: &LaneObservation<POINTS>, extra_var: f32) -> Self {
        let mut var = obs.cov.diagonal();
        var.iter_mut().for_each(|v| *v += extra_var);
        Self {
            present: obs.present,
            z: obs.z,
            var,
        }
    }
}

/// Parameters of lane identity.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IdentityConfig {
    /// Largest allowed pair cost (mean normalised squared distance per common point). Default
    /// 9.0: a 3σ mean discrepancy. It is also the price of leaving an observation or a lane
    /// unmatched. A non-finite or negative value is treated as 0.
    pub gate: f32,
    /// Fewest index points an observation and a prediction must share to be compared, and the
    /// fewest valid points an observation needs to start a lane. Default 3; 0 is treated as 1.
    pub min_common: u8,
    /// A lane is removed at its `max_misses`-th consecutive frame without an observation, so a
    /// lane missing for fewer frames keeps its id. Default 10 (a third of a second at 30 fps);
    /// 0 is treated as 1.
    pub max_misses: u16,
}

impl IdentityConfig {
    /// The defaults: gate 9.0, `min_common` 3, `max_misses` 10.
    pub const DEFAULT: Self = Self {
        gate: 9.0,
        min_common: 3,
        max_misses: 10,
    };
}

impl Default for IdentityConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Bookkeeping of one live temporal lane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LaneInfo {
    /// The lane's id.
    pub id: LaneId,
    /// Frames since the lane started (0 in the frame it starts).
    pub age: u32,
    /// Frames with an observation, the first one included (saturating).
    pub hits: u32,
    /// Consecutive frames without an observation (0 when matched this frame).
    pub misses: u16,
}

/// Why an observation was not assigned a lane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DropReason {
    /// No lane matched and every slot is in use.
    NoSlot,
    /// No lane matched and it has fewer than `min_common` valid points (present, finite position,
    /// finite variance `≥ 0`), too few to start a lane.
    Unusable,
    /// No lane matched and the caller refused it a lane (the tracker's ray test: a line through
    /// the camera's foot point, docs/design.md §11.10).
    Refused,
}

/// What happened to one observation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ObsFate {
    /// Assigned to the live lane in `slot`.
    Matched {
        /// The lane's slot.
        slot: u8,
    },
    /// Started a new lane (fresh id) in `slot`.
    New {
        /// The new lane's slot.
        slot: u8,
    },
    /// Not assigned.
    Dropped(DropReason),
}

/// What happened to one lane slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SlotFate {
    /// Empty before and after this frame.
    Free,
    /// The live lane was assigned observation `obs`.
    Matched {
        /// Index of the observation in the slice given.
        obs: u8,
    },
    /// A new lane started from observation `obs`.
    New {
        /// Index of the observation in the slice given.
        obs: u8,
        /// The lane removed from this slot earlier in the same frame, if any.
        replaced: Option<LaneId>,
    },
    /// The live lane had no observation and coasts; `misses` is its new miss count.
    Coasting {
        /// Consecutive misses including this frame.
        misses: u16,
    },
    /// The live lane reached `max_misses` and was removed; the slot is free.
    Removed {
        /// The removed lane's id.
        id: LaneId,
    },
}

/// Counters of one [`LaneTable::associate`] call (`repr(C)`: the C API hands it to C as is).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(C)]
pub struct IdentityReport {
    /// Observations considered (at most `LANES`).
    pub observations: u32,
    /// Observations beyond the first `LANES`, ignored.
    pub excess_observations: u32,
    /// (observation, lane) pairs not allowed because they read a non-finite value.
    pub non_finite_pairs: u32,
    /// (observation, lane) pairs with fewer than `min_common` common points.
    pub too_few_common: u32,
    /// (observation, lane) pairs with a finite cost above the gate.
    pub gated_out: u32,
    /// Allowed pairs.
    pub allowed_pairs: u32,
    /// Observations matched to a lane.
    pub matched: u32,
    /// Lanes started.
    pub started: u32,
    /// Observations dropped for want of a slot.
    pub dropped_no_slot: u32,
    /// Observations dropped as unusable.
    pub dropped_unusable: u32,
    /// Lanes coasting after this frame.
    pub coasting: u32,
    /// Lanes removed this frame.
    pub removed: u32,
    /// Of them, lanes that yielded their slot to a new lane (slots by existence,
    /// docs/design.md §11.13).
    pub evicted: u32,
    /// Leaves visited by the assignment search.
    pub leaves: u32,
    /// Total cost of the chosen assignment (the minimised objective).
    pub total_cost: f32,
}

/// Result of one [`LaneTable::associate`] call.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IdentityOutcome<const LANES: usize> {
    /// Fate of observation `i` for `i < report.observations`; later entries are
    /// `Dropped(NoSlot)` placeholders (use [`IdentityOutcome::obs_fates`]).
    pub obs: [ObsFate; LANES],
    /// Fate of each lane slot.
    pub slots: [SlotFate; LANES],
    /// Counters.
    pub report: IdentityReport,
}

impl<const LANES: usize> IdentityOutcome<LANES> {
    /// The fates of the observations considered, in input order.
    pub fn obs_fates(&self) -> &[ObsFate] {
        let n = usize::try_from(self.report.observations).unwrap_or(LANES);
        self.obs.get(..n).unwrap_or(&self.obs)
    }
}

/// Why a pair has no cost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PairReject {
    /// Fewer than `min_common` index points present in both.
    TooFewCommon,
    /// A non-finite value, a negative variance or a zero variance sum at a common point.
    NonFinite,
}

impl core::fmt::Display for PairReject {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooFewCommon => f.write_str("too few common index points"),
            Self::NonFinite => f.write_str("non-finite value or invalid variance"),
        }
    }
}

impl core::error::Error for PairReject {}

/// The cost of pairing `obs` with `pred` (module docs), before the gate. O(POINTS).
///
/// # Errors
/// [`PairReject`] when the pair cannot be compared; `min_common` 0 is treated as 1.
pub fn pair_cost<const POINTS: usize>(
    obs: &LaneObservation<POINTS>,
    pred: &LanePrediction<POINTS>,
    min_common: u8,
) -> Result<f32, PairReject> {
    let mut sum = 0.0f32;
    let mut common = 0u32;
    let mut bad = false;
    let diag = obs.cov.diagonal();
    let points = obs
        .present
        .iter()
        .zip(obs.z.iter())
        .zip(diag.iter())
        .zip(pred.present.iter().zip(pred.z.iter()).zip(pred.var.iter()));
    for (((&po, &zo), &vo), ((&pp, &zp), &vp)) in points {
        if !(po && pp) {
            continue;
        }
        common += 1;
        let d = zo - zp;
        let s = vo + vp;
        let term = d * d / s;
        let ok = zo.is_finite()
            && zp.is_finite()
            && vo.is_finite()
            && vp.is_finite()
            && vo >= 0.0
            && vp >= 0.0
            && s > 0.0
            && term.is_finite();
        if ok {
            sum += term;
        } else {
            bad = true;
        }
    }
    if common < u32::from(min_common.max(1)) {
        return Err(PairReject::TooFewCommon);
    }
    if bad {
        return Err(PairReject::NonFinite);
    }
    #[allow(clippy::cast_precision_loss)]
    let mean = sum / common as f32;
    if mean.is_finite() {
        Ok(mean)
    } else {
        Err(PairReject::NonFinite)
    }
}

/// Valid points of an observation: present, finite position, finite variance `≥ 0`.
fn valid_points<const POINTS: usize>(obs: &LaneObservation<POINTS>) -> u32 {
    let diag = obs.cov.diagonal();
    let valid = obs
        .present
        .iter()
        .zip(obs.z.iter())
        .zip(diag.iter())
        .filter(|((&p, &z), &v)| p && z.is_finite() && v.is_finite() && v >= 0.0)
        .count();
    u32::try_from(valid).unwrap_or(u32::MAX)
}

/// The temporal lanes' identities: up to `LANES` slots with id, age and miss count.
///
/// RAM: 124 B for `LANES = 6` (`size_of`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LaneTable<const LANES: usize> {
    slots: [Option<LaneInfo>; LANES],
    next_id: u32,
}

impl<const LANES: usize> Default for LaneTable<LANES> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const LANES: usize> LaneTable<LANES> {
    /// An empty table; the first lane gets id 0.
    pub const fn new() -> Self {
        Self::starting_at(0)
    }

    /// An empty table whose first lane gets id `next_id` (e.g. to resume after a reset without
    /// reusing ids).
    pub const fn starting_at(next_id: u32) -> Self {
        const {
            assert!(
                LANES > 0 && LANES <= MAX_LANES,
                "LANES must be 1..=MAX_LANES (8)"
            )
        };
        Self {
            slots: [None; LANES],
            next_id,
        }
    }

    /// The live lane in `slot`, if any.
    pub fn lane(&self, slot: usize) -> Option<LaneInfo> {
        self.slots.get(slot).copied().flatten()
    }

    /// The live lanes with their slots, in slot order.
    pub fn lanes(&self) -> impl Iterator<Item = (usize, LaneInfo)> + '_ {
        self.slots
            .iter()
            .enumerate()
            .filter_map(|(s, l)| l.map(|l| (s, l)))
    }

    /// Number of live lanes.
    pub fn len(&self) -> usize {
        self.slots.iter().flatten().count()
    }

    /// No live lane.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The id the next lane will get (unless it is held by a live lane after a wrap).
    pub const fn next_id(&self) -> u32 {
        self.next_id
    }

    /// Removes every lane; the id counter keeps going, so ids are not reused.
    pub fn clear(&mut self) {
        self.slots = [None; LANES];
    }

    /// Lane `slot` was seen this frame by other means than an observation (the known-lane
    /// association, docs/design.md §11): its miss count is reset and, unless `counted` (already
    /// matched this frame), its hits counted. `false` for a free slot.
    pub fn mark_seen(&mut self, slot: usize, counted: bool) -> bool {
        match self.slots.get_mut(slot) {
            Some(Some(l)) => {
                if !counted {
                    l.hits = l.hits.saturating_add(1);
                }
                l.misses = 0;
                true
            }
            _ => false,
        }
    }

    /// Resets the miss count of the lane in `slot` (seen this frame before identity runs);
    /// `false` for a free slot.
    pub fn reset_misses(&mut self, slot: usize) -> bool {
        match self.slots.get_mut(slot) {
            Some(Some(l)) => {
                l.misses = 0;
                true
            }
            _ => false,
        }
    }

    /// Removes the lane in `slot` (its existence fell below the deletion threshold); returns
    /// its id.
    pub fn remove(&mut self, slot: usize) -> Option<LaneId> {
        self.slots
            .get_mut(slot)
            .and_then(Option::take)
            .map(|l| l.id)
    }

    fn id_live(&self, id: u32) -> bool {
        self.slots.iter().flatten().any(|l| l.id.0 == id)
    }

    /// A fresh id not held by a live lane (at most `LANES + 1` tries, then the pigeonhole holds).
    fn fresh_id(&mut self) -> LaneId {
        let mut id = self.next_id;
        for _ in 0..=LANES {
            id = self.next_id;
            self.next_id = self.next_id.wrapping_add(1);
            if !self.id_live(id) {
                break;
            }
        }
        LaneId(id)
    }

    /// One frame of lane identity: assigns `obs` (this frame's spatial lanes; only the first
    /// `LANES` are considered, the rest are counted) to the live lanes, whose predictions are
    /// `preds[slot]` (entries of free slots are ignored), updates ids, ages and miss counts, and
    /// reports every observation's and slot's fate.
    ///
    /// Order: optimal assignment (module docs); matched lanes reset their miss count; unmatched
    /// lanes coast or, at `max_misses`, are removed; then unmatched usable observations, in input
    /// order, start lanes in the lowest free slots (including slots freed this frame).
    ///
    /// # Complexity
    /// `n·m·POINTS` for the costs plus the search bound of the module docs (13 327 leaves at
    /// `LANES = 6`), `O(LANES²)` bookkeeping. No allocation, no recursion, no panic.
    pub fn associate<const POINTS: usize>(
        &mut self,
        preds: &[LanePrediction<POINTS>; LANES],
        obs: &[LaneObservation<POINTS>],
        cfg: &IdentityConfig,
    ) -> IdentityOutcome<LANES> {
        self.associate_births(preds, obs, cfg, &[true; LANES])
    }

    /// [`LaneTable::associate`], where an unmatched observation `i` may start a lane only if
    /// `may_start[i]`; the others are dropped ([`DropReason::Refused`]).
    pub fn associate_births<const POINTS: usize>(
        &mut self,
        preds: &[LanePrediction<POINTS>; LANES],
        obs: &[LaneObservation<POINTS>],
        cfg: &IdentityConfig,
        may_start: &[bool; LANES],
    ) -> IdentityOutcome<LANES> {
        self.associate_claims(preds, obs, cfg, may_start, None, 0)
    }

    /// [`LaneTable::associate_births`] with slots by existence: an observation `i` that may
    /// start a lane, has positive evidence (`llr ≥ 0`) and finds no free slot takes the slot of
    /// the unmatched (coasting) lane of lowest `hold` among those below `∞`; the lane it
    /// replaces is removed (`SlotFate::New { replaced }`, counted in `removed` and `evicted`).
    /// Observations are served in input order. The lanes of `seen` (bit = slot) were seen
    /// this frame before identity ran (the tracker's known-lane pass, docs/design.md §11.8):
    /// unmatched, they coast but are not removed at `max_misses` (their miss is not one; the
    /// tracker marks them seen after). `hold = None` and `seen = 0` are
    /// [`LaneTable::associate_births`].
    ///
    /// # Complexity
    /// That of [`LaneTable::associate`] plus `LANES` comparisons per observation that finds
    /// no free slot.
    pub fn associate_claims<const POINTS: usize>(
        &mut self,
        preds: &[LanePrediction<POINTS>; LANES],
        obs: &[LaneObservation<POINTS>],
        cfg: &IdentityConfig,
        may_start: &[bool; LANES],
        hold: Option<&[f32; LANES]>,
        seen: u32,
    ) -> IdentityOutcome<LANES> {
        let gate = if cfg.gate.is_finite() && cfg.gate >= 0.0 {
            cfg.gate
        } else {
            0.0
        };
        let min_common = cfg.min_common.max(1);
        let max_misses = cfg.max_misses.max(1);
        let n_obs = obs.len().min(LANES);
        let mut report = IdentityReport {
            observations: u32::try_from(n_obs).unwrap_or(u32::MAX),
            excess_observations: u32::try_from(obs.len() - n_obs).unwrap_or(u32::MAX),
            ..IdentityReport::default()
        };

        let (cost, allowed) = self.gated_costs(preds, obs, min_common, gate, &mut report);
        let n_lanes = u32::try_from(self.len()).unwrap_or(u32::MAX);
        let best = search(&cost, &allowed, n_obs, n_lanes, gate);
        report.leaves = best.leaves;
        report.total_cost = best.total;

        let mut obs_fates = [ObsFate::Dropped(DropReason::NoSlot); LANES];
        let mut slot_fates = [SlotFate::Free; LANES];
        let mut lane_taken = [false; LANES];

        // Matched pairs.
        for (i, (&lane, fate)) in best.assign.iter().zip(obs_fates.iter_mut()).enumerate() {
            if lane == NONE {
                continue;
            }
            let i = u8::try_from(i).unwrap_or(NONE);
            let l = usize::from(lane);
            if let (Some(Some(info)), Some(sf), Some(t)) = (
                self.slots.get_mut(l),
                slot_fates.get_mut(l),
                lane_taken.get_mut(l),
            ) {
                info.misses = 0;
                info.age = info.age.saturating_add(1);
                info.hits = info.hits.saturating_add(1);
                *sf = SlotFate::Matched { obs: i };
                *t = true;
                *fate = ObsFate::Matched { slot: lane };
                report.matched += 1;
            }
        }

        self.coast_or_remove(&mut slot_fates, &lane_taken, max_misses, seen, &mut report);

        // Unmatched observations start lanes.
        for (i, (o, &lane)) in obs.iter().zip(best.assign.iter()).enumerate() {
            if lane != NONE {
                continue;
            }
            let Some(fate) = obs_fates.get_mut(i) else {
                break;
            };
            if valid_points(o) < u32::from(min_common) {
                *fate = ObsFate::Dropped(DropReason::Unusable);
                report.dropped_unusable += 1;
                continue;
            }
            if !may_start.get(i).copied().unwrap_or(true) {
                *fate = ObsFate::Dropped(DropReason::Refused);
                continue;
            }
            let mut free = self.slots.iter().position(Option::is_none);
            if let (None, Some(hold), true) = (free, hold, o.llr >= 0.0) {
                free = yielding_slot(hold, &slot_fates);
                if let Some(l) = free {
                    if let (Some(slot), Some(sf)) = (self.slots.get_mut(l), slot_fates.get_mut(l)) {
                        if let Some(info) = slot.take() {
                            *sf = SlotFate::Removed { id: info.id };
                        }
                    }
                    report.removed += 1;
                    report.evicted += 1;
                    report.coasting = report.coasting.saturating_sub(1);
                }
            }
            let Some(free) = free else {
                *fate = ObsFate::Dropped(DropReason::NoSlot);
                report.dropped_no_slot += 1;
                continue;
            };
            let id = self.fresh_id();
            if let (Some(slot), Some(sf)) = (self.slots.get_mut(free), slot_fates.get_mut(free)) {
                *slot = Some(LaneInfo {
                    id,
                    age: 0,
                    hits: 1,
                    misses: 0,
                });
                let replaced = match *sf {
                    SlotFate::Removed { id } => Some(id),
                    _ => None,
                };
                *sf = SlotFate::New {
                    obs: u8::try_from(i).unwrap_or(NONE),
                    replaced,
                };
                *fate = ObsFate::New {
                    slot: u8::try_from(free).unwrap_or(NONE),
                };
                report.started += 1;
            }
        }

        IdentityOutcome {
            obs: obs_fates,
            slots: slot_fates,
            report,
        }
    }

    /// The cost of every (observation, lane) pair that passes the gate, and per observation the
    /// mask of its allowed lanes; the rejected pairs are counted in `report`.
    #[inline(always)]
    fn gated_costs<const POINTS: usize>(
        &self,
        preds: &[LanePrediction<POINTS>; LANES],
        obs: &[LaneObservation<POINTS>],
        min_common: u8,
        gate: f32,
        report: &mut IdentityReport,
    ) -> ([[f32; MAX_LANES]; MAX_LANES], [u32; MAX_LANES]) {
        let mut cost = [[f32::INFINITY; MAX_LANES]; MAX_LANES];
        let mut allowed = [0u32; MAX_LANES];
        // Only the first `LANES` observations are considered (the rest are only counted).
        for ((o, row), mask) in obs
            .iter()
            .take(LANES)
            .zip(cost.iter_mut())
            .zip(allowed.iter_mut())
        {
            for (lane, ((slot, p), c)) in self
                .slots
                .iter()
                .zip(preds.iter())
                .zip(row.iter_mut())
                .enumerate()
            {
                if slot.is_none() {
                    continue;
                }
                match pair_cost(o, p, min_common) {
                    Ok(v) if v <= gate => {
                        *c = v;
                        *mask |= 1u32 << lane;
                        report.allowed_pairs += 1;
                    }
                    Ok(_) => report.gated_out += 1,
                    Err(PairReject::TooFewCommon) => report.too_few_common += 1,
                    Err(PairReject::NonFinite) => report.non_finite_pairs += 1,
                }
            }
        }
        (cost, allowed)
    }

    /// The lanes no observation matched coast, or are removed after `max_misses` misses unless
    /// the lanes of `seen` saw them this frame.
    #[inline(always)]
    fn coast_or_remove(
        &mut self,
        slot_fates: &mut [SlotFate; LANES],
        lane_taken: &[bool; LANES],
        max_misses: u16,
        seen: u32,
        report: &mut IdentityReport,
    ) {
        for (l, ((slot, sf), &taken)) in self
            .slots
            .iter_mut()
            .zip(slot_fates.iter_mut())
            .zip(lane_taken.iter())
            .enumerate()
        {
            if taken {
                continue;
            }
            if let Some(info) = slot {
                info.misses = info.misses.saturating_add(1);
                info.age = info.age.saturating_add(1);
                if info.misses >= max_misses && (l >= 32 || seen & (1 << l) == 0) {
                    *sf = SlotFate::Removed { id: info.id };
                    *slot = None;
                    report.removed += 1;
                } else {
                    *sf = SlotFate::Coasting {
                        misses: info.misses,
                    };
                    report.coasting += 1;
                }
            }
        }
    }
}

/// The coasting slot of lowest finite `hold`, if any ([`LaneTable::associate_claims`]).
#[inline(never)]
fn yielding_slot(hold: &[f32], fates: &[SlotFate]) -> Option<usize> {
    let mut best: Option<(usize, f32)> = None;
    for (l, (&h, sf)) in hold.iter().zip(fates).enumerate() {
        if matches!(sf, SlotFate::Coasting { .. })
            && h < f32::INFINITY
            && best.is_none_or(|(_, b)| h < b)
        {
            best = Some((l, h));
        }
    }
    best.map(|(l, _)| l)
}

#[cfg(test)]
mod tests;
