//! The tracker's contract types: configuration, errors, published lanes and the step report.

use heapless::Vec;
use nalgebra::SVector;

use crate::persist::PersistConfig;
use crate::spatial::filter::{Config as SpatialConfig, SpatialReport};
use crate::spatial::row::{Association, MissModel};
use crate::temporal::identity::{IdentityConfig, IdentityReport, LaneId};

#[cfg(doc)]
use super::Tracker;

/// Error of [`Tracker::step`]; the tracker's state is untouched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum StepError {
    /// `now` is not after the previous frame's time.
    NonIncreasingTime,
    /// The tracker is [`Tracker::UNINIT`]: [`Tracker::init`] has not been called.
    NotInitialised,
}

impl core::fmt::Display for StepError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NonIncreasingTime => "frame time does not increase",
            Self::NotInitialised => "tracker not initialised",
        })
    }
}

impl core::error::Error for StepError {}

/// Tuning of the whole tracker.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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
    /// `true`: the fixed-lag smoother's per-lane approximation (a lane's smoothed past moves
    /// with its own innovations only; [`crate::temporal::smoother::Temporal::with_per_lane`]);
    /// `false` (the default): the exact coupled smoother. Experimental: its smoothed variances
    /// are not meaningful with coupled lanes (docs/design.md §5.1).
    pub smoother_per_lane: bool,
}

impl TrackerConfig {
    /// Defaults of the stages.
    pub const DEFAULT: Self = Self {
        spatial: SpatialConfig::DEFAULT,
        identity: IdentityConfig::DEFAULT,
        existence_decay: 0.8,
        persist: PersistConfig::DEFAULT,
        smoother_per_lane: false,
    };

    /// The round-1 pipeline: no temporal prior in the association (the ablation).
    pub const ROUND1: Self = Self {
        persist: PersistConfig::ROUND1,
        ..Self::DEFAULT
    };

    /// This configuration with `k` rows per index interval (K, docs/design.md §2) instead of
    /// its own, and every length it counts in rows rescaled so that it keeps its length in
    /// metres: the spatial filter's initiation rows, hits, misses and merge rows and the
    /// known-lane stage's hits and dash gap become `⌈n·k/K⌉` (at least 1), and the clutter
    /// densities, which are per row, `K/k` times theirs (a row then collects the points of
    /// `K/k` rows). Rows cost per frame in proportion to their number, `(N − 1)·k + 1`
    /// (docs/measurements.md "Fitting the MCU"); `k = 0` is taken as 1. The tracker needs
    /// `ROWS ≥ (POINTS − 1)·k + 1` (61 at k = 4 for the reference `ROWS` = 64, so k ≤ 4 there);
    /// a configuration that does not fit is not refused by [`crate::tracker::Tracker::init`]:
    /// every frame then reports `spatial.bad_config` and finds no lane.
    #[must_use]
    pub const fn with_rows_per_interval(self, k: u8) -> Self {
        let k = if k == 0 { 1 } else { k };
        let k0 = if self.spatial.rows_per_interval == 0 {
            1
        } else {
            self.spatial.rows_per_interval
        };
        let density = k0 as f32 / k as f32;
        let mut c = self;
        c.spatial.rows_per_interval = k;
        c.spatial.init_rows = {
            let v = rescale_rows(k0, k, self.spatial.init_rows as u16);
            if v > u8::MAX as u16 {
                u8::MAX
            } else {
                v as u8
            }
        };
        c.spatial.confirm_hits = rescale_rows(k0, k, self.spatial.confirm_hits);
        c.spatial.tentative_misses = rescale_rows(k0, k, self.spatial.tentative_misses);
        c.spatial.tentative_gap_misses = rescale_rows(k0, k, self.spatial.tentative_gap_misses);
        c.spatial.max_misses = rescale_rows(k0, k, self.spatial.max_misses);
        c.spatial.merge_rows = rescale_rows(k0, k, self.spatial.merge_rows);
        c.spatial.clutter_density = self.spatial.clutter_density * density;
        c.persist.confirm_hits = rescale_rows(k0, k, self.persist.confirm_hits);
        c.persist.gap_misses = rescale_rows(k0, k, self.persist.gap_misses);
        c.persist.clutter_floor = self.persist.clutter_floor * density;
        c
    }

    /// Every byte zero: the configuration of [`Tracker::UNINIT`], which never runs with it
    /// ([`Tracker::init`] replaces it). Not a usable configuration.
    pub(super) const ZEROED: Self = Self {
        spatial: SpatialConfig {
            pd: 0.0,
            pg: 0.0,
            gamma: 0.0,
            clutter_density: 0.0,
            miss: MissModel::Textbook,
            max_events: 0,
            rows_per_interval: 0,
            init_rows: 0,
            init_gate: 0.0,
            max_tentative: 0,
            confirm_hits: 0,
            tentative_misses: 0,
            tentative_gap_misses: 0,
            row_noise_scale: 0.0,
            max_misses: 0,
            merge_distance: 0.0,
            merge_rows: 0,
        },
        identity: IdentityConfig {
            gate: 0.0,
            min_common: 0,
            max_misses: 0,
        },
        existence_decay: 0.0,
        persist: PersistConfig {
            enabled: false,
            pd_memory: 0.0,
            clutter_memory: 0.0,
            clutter_floor: 0.0,
            survival_time: 0.0,
            p_birth: 0.0,
            p_publish: 0.0,
            p_delete: 0.0,
            explained: 0.0,
            confirm_hits: 0,
            gap_misses: 0,
            row_noise_scale: 0.0,
            q_memory: 0.0,
            p_visible: 0.0,
            frame_offset_memory: 0.0,
            chain_memory: 0.0,
            min_spacing: 0.0,
            lane_width: 0.0,
            pd_floor: 0.0,
            own_pd: false,
            association: Association::Exact,
            ray_z: 0.0,
            ray_resolution: 0.0,
            ray_aligned: false,
            ray_motion: false,
            slot_claims: false,
            connectors: false,
            connector_frames: 0,
            newcomer_wait: 0,
            paint_gap: None,
        },
        smoother_per_lane: false,
    };
}

/// `⌈n·k/k0⌉`, at least 1 (a length in rows at `k0` rows per interval, at `k`).
const fn rescale_rows(k0: u8, k: u8, n: u16) -> u16 {
    let v = (n as u32 * k as u32).div_ceil(k0 as u32);
    if v == 0 {
        1
    } else if v > u16::MAX as u32 {
        u16::MAX
    } else {
        v as u16
    }
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
    /// Lateral position at each index point ([`crate::tables::Tables::index_u`], evenly spaced
    /// over the window `u_min..=u_max`), metres.
    pub z: SVector<f32, POINTS>,
    /// Its variance, m².
    pub var: SVector<f32, POINTS>,
    /// Observed extent, metres ahead: the union over the `LAG + 1` frames ending at the lane's
    /// frame (the current one for filtered lanes, `LAG` frames back for smoothed lanes);
    /// `u_first == u_last ==` the window's `u_min` when the lane was observed in none of them.
    pub u_first: f32,
    /// Far end of the observed extent, metres ahead.
    pub u_last: f32,
    /// Existence in [0, 1]: with the known-lane stage (the default) the lane's existence
    /// probability (docs/design.md §11.5); in the round-1 pipeline the spatial existence when
    /// seen, decaying while coasting (`TrackerConfig::existence_decay`). For a smoothed lane,
    /// the lane's existence at the current frame.
    pub existence: f32,
    /// Frames since the lane was last seen (0 when seen this frame); always 0 for a smoothed
    /// lane (read its filtered lane's, same `id`).
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
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(C)]
pub struct StepReport {
    /// The spatial filter's counters.
    pub spatial: SpatialReport,
    /// Lane identity's counters, over this frame's spatial lanes: with the known-lane stage (the
    /// default) a lane its pass saw and no spatial lane matched is counted in `coasting`
    /// although it was seen (its `misses` is 0; [`KnownReport::seen`] counts those), and lanes
    /// the known-lane stage deletes or merges are in `known`, not in `removed`.
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
    /// Factorisations of the temporal covariance (and of the smoother's lag blocks) that failed
    /// after this frame's lane updates because f32 rounding had made it indefinite, each followed
    /// by a larger shift (see [`crate::temporal::filter::TemporalFilter::repair_covariance`]; 0
    /// on almost every frame: nothing was changed).
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
    /// Of those, lanes seen (a row with `W ≥ 0.5` that gave information, docs/design.md
    /// §11.8).
    pub seen: u32,
    /// Points the known lanes explained (removed before the spatial filter).
    pub explained_points: u32,
    /// Rows whose joint events failed numerically (every lane missed there).
    pub failed_rows: u32,
    /// Lanes deleted because their existence fell below `p_delete`, the ray test found them
    /// to be a vertical structure (`ray_deleted` of them) or they join two markings
    /// (`connectors_deleted`).
    pub deleted: u32,
    /// Lanes removed as duplicates of another (one lane, one track).
    pub merged: u32,
    /// The process-noise scale used by this frame's prediction.
    pub q_scale: f32,
    /// Joint events the rows enumerated.
    pub events: u32,
    /// Rows over the event budget whose least likely candidates were dropped
    /// ([`crate::spatial::row::Association::Exact`]).
    pub pruned_rows: u32,
    /// Rows weighed by LBP marginals ([`crate::spatial::row::Association`]).
    pub lbp_rows: u32,
    /// New lanes refused because the ray test found them to be a vertical structure
    /// ([`crate::persist::ray`]).
    pub ray_refused: u32,
    /// Live lanes deleted for the same reason (counted in `deleted` too).
    pub ray_deleted: u32,
    /// Live lanes deleted as connectors: they cross or touch two published lanes that do not
    /// meet each other (docs/design.md §11.11; counted in `deleted` too).
    pub connectors_deleted: u32,
}

/// The output of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct StepOutput<const LANES: usize, const POINTS: usize> {
    /// Filtered lanes at this frame: with the known-lane stage, the live lanes whose existence
    /// is at least `PersistConfig::p_publish`, except a lane started this frame while the
    /// tracker has an established picture (a lane of age ≥ 2) or that duplicates a tracked
    /// lane: it is published from its second frame (docs/design.md §11.5, §11.9); a newcomer
    /// held back (`PersistConfig::newcomer_wait`, §11.5) and a lane outside the outermost
    /// marking (`PersistConfig::lane_width`, §11.14) are not published either.
    pub filtered: Vec<LaneEstimate<POINTS>, LANES>,
    /// Smoothed lanes `LAG` frames back (empty until the window is full): with the known-lane
    /// stage, those of the lanes published in `filtered` now (a lane removed since is not
    /// published, also when a new lane has taken its slot).
    pub smoothed: Vec<LaneEstimate<POINTS>, LANES>,
    /// Counters.
    pub report: StepReport,
}

#[cfg(test)]
mod tests {
    use super::TrackerConfig;

    #[test]
    fn rows_per_interval_keeps_lengths_in_metres() {
        let d = TrackerConfig::DEFAULT;
        assert_eq!(d.with_rows_per_interval(d.spatial.rows_per_interval), d);
        let h = d.with_rows_per_interval(2);
        assert_eq!(h.spatial.rows_per_interval, 2);
        // K 4 → 2: every row count halves, rounded up, none below one.
        assert_eq!(h.spatial.confirm_hits, 3);
        assert_eq!(h.spatial.max_misses, 6);
        assert_eq!(h.spatial.tentative_misses, 4);
        assert_eq!(h.spatial.merge_rows, 2);
        assert_eq!(h.spatial.init_rows, 2);
        assert_eq!(h.persist.gap_misses, 6);
        assert_eq!(h.persist.confirm_hits, 2);
        // A row of twice the length holds twice the clutter.
        assert_eq!(h.spatial.clutter_density, 2.0 * d.spatial.clutter_density);
        assert_eq!(h.persist.clutter_floor, 2.0 * d.persist.clutter_floor);
        // The other parameters are untouched.
        assert_eq!(h.spatial.gamma, d.spatial.gamma);
        assert_eq!(h.persist.row_noise_scale, d.persist.row_noise_scale);
        let one = d.with_rows_per_interval(0);
        assert_eq!(one.spatial.rows_per_interval, 1);
        assert_eq!(one.spatial.merge_rows, 1);
    }
}
