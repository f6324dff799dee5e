//! `stjpdacf track`: runs the core `ReferenceTracker` over a file of frames and writes TuSimple
//! predictions.
//!
//! Per frame: image points → BEV through the camera (or BEV points as given with `--space bev`),
//! [`preprocess`] (row binning and lateral clustering, what a front end hands the MCU),
//! `Tracker::step` at the frame's time (a new clip resets the tracker), then, for frames that
//! carry `h_samples`, each lane seen within the last `MAX_REPORT_MISSES` frames is written at
//! those rows ([`lane_x`]): inside the BEV window by the tracker's GP evaluation
//! (`Tracker::lane_at`), nearer than the window by extending the lane linearly from its two
//! nearest index points, −2 beyond the window's far end (no evidence there: docs/design.md §8),
//! outside the lane's observed extent (one index interval of margin) and outside the image. Lanes are
//! written left to right (by their position at the nearest index point); a lane with no point in
//! the image is left out. `run_time` is the milliseconds spent on that frame from its points to
//! its lanes (see [`track_with`]).

use std::collections::HashSet;
use std::time::Instant as WallClock;

use anyhow::{bail, Context, Result};
use cpu_time::ThreadTime;

use serde::{Deserialize, Serialize};
use stjpdacf::tables::ReferenceTables;
use stjpdacf::tracker::{Instant, LaneEstimate, ReferenceTracker, StepOutput, TrackerConfig};

use crate::camera::Camera;
use crate::tablegen;
use crate::tusimple::{Frame, TuSimpleRecord, NO_POINT};
use stjpdacf_reference::hyper::HyperFile;

/// Lanes not seen for more frames than this are not written.
pub const MAX_REPORT_MISSES: u16 = 2;

/// Where the frames' points live.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Space {
    /// Image pixels `[column, row]` of the camera.
    Image,
    /// BEV metres `[x lateral, u ahead]`.
    Bev,
}

/// Counters of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TrackStats {
    /// Frames processed.
    pub frames: usize,
    /// Clips (tracker resets).
    pub clips: usize,
    /// Predictions written.
    pub predictions: usize,
    /// Points that did not map to BEV (at or above the horizon, non-finite).
    pub unmapped_points: usize,
    /// Image points ([`Space::Image`]) outside the image of the camera they were tracked with
    /// ([`outside_image`]): points found with another camera or image scale, mapped to the road
    /// by the wrong one (they are tracked as they are; `stjpdacf track` warns).
    pub outside_image_points: usize,
    /// Label rows (`h_samples`) of the predicted frames outside the image of the camera they
    /// were predicted with (below row 0 or beyond its height): labels of another image size
    /// (1280×720 rows with a 512×288 camera, say), whose predicted lanes are −2 there.
    pub outside_image_rows: usize,
    /// Steps the tracker rejected (non-increasing time within a clip).
    pub rejected_steps: usize,
    /// Mean `Tracker::step` time, ms: the thread's CPU time (`cpu_time::ThreadTime`), so
    /// other work on the machine does not inflate it (the baseline's fit likewise).
    pub step_mean_ms: f64,
    /// Largest `Tracker::step` time (thread CPU time), ms.
    pub step_max_ms: f64,
    /// Mean time spent on a frame (the predictions' `run_time`: mapping, preprocessing, step and
    /// evaluation at the `h_samples` rows; wall clock, as TuSimple's `run_time`), ms.
    pub run_mean_ms: f64,
    /// Largest time spent on a frame, ms.
    pub run_max_ms: f64,
    /// Joint events the known-lane stage enumerated, over all frames.
    pub known_events: u64,
    /// Known-lane rows pruned to the event budget, over all frames.
    pub known_pruned_rows: u64,
    /// Known-lane rows weighed by LBP, over all frames.
    pub known_lbp_rows: u64,
    /// Frames on which the tracker repaired its temporal covariance (f32 rounding had made it
    /// indefinite: `StepReport::temporal_cov_repairs` > 0, docs/design.md §4.2.4).
    pub repaired_frames: usize,
    /// Distinct lane ids published (seen within [`MAX_REPORT_MISSES`] frames), summed over the
    /// clips: divided by `clips`, the lane ids per clip (on a road with four markings and no
    /// lane change, 4 when every lane keeps its id and no false lane is published).
    pub lane_ids: usize,
    /// Lanes published (seen within [`MAX_REPORT_MISSES`] frames), summed over the frames.
    pub published_lanes: usize,
    /// Points that mapped to the road but lie outside the tracker's BEV window (nearer than its
    /// first row or beyond its last, [`outside_window`]): [`preprocess`] drops them.
    pub outside_window_points: usize,
    /// Preprocessed points left out by [`fit_budget`] (frames over the core's budgets).
    pub over_budget_points: usize,
    /// Frames [`fit_budget`] left points out of.
    pub over_budget_frames: usize,
}

impl TrackStats {
    /// Checks frame `k` of a run and, when its clip is not `clip` (the previous frame's), counts
    /// a new clip and names it in `clip`; `Ok(true)` when the frame starts a clip.
    pub(crate) fn begin_frame<'a>(
        &mut self,
        k: usize,
        f: &'a Frame,
        clip: &mut Option<&'a str>,
    ) -> Result<bool> {
        f.check()
            .with_context(|| format!("frame {k} (clip {})", f.clip))?;
        if *clip == Some(f.clip.as_str()) {
            return Ok(false);
        }
        *clip = Some(f.clip.as_str());
        self.clips += 1;
        Ok(true)
    }

    /// Counts a frame whose step took `ms`.
    pub(crate) fn add_step(&mut self, times: &mut RunTimes, ms: f64) {
        times.step += ms;
        self.step_max_ms = self.step_max_ms.max(ms);
        self.frames += 1;
    }

    /// Counts `ms` spent on a frame.
    pub(crate) fn add_run(&mut self, times: &mut RunTimes, ms: f64) {
        times.run += ms;
        self.run_max_ms = self.run_max_ms.max(ms);
    }

    /// Adds another run's figures (means weighted by frames, maxima, counts).
    pub fn merge(&mut self, o: &TrackStats) {
        let n = (self.frames + o.frames).max(1) as f64;
        let mean = |a: f64, b: f64| (a * self.frames as f64 + b * o.frames as f64) / n;
        self.step_mean_ms = mean(self.step_mean_ms, o.step_mean_ms);
        self.run_mean_ms = mean(self.run_mean_ms, o.run_mean_ms);
        self.step_max_ms = self.step_max_ms.max(o.step_max_ms);
        self.run_max_ms = self.run_max_ms.max(o.run_max_ms);
        self.frames += o.frames;
        self.clips += o.clips;
        self.predictions += o.predictions;
        self.unmapped_points += o.unmapped_points;
        self.outside_image_points += o.outside_image_points;
        self.outside_image_rows += o.outside_image_rows;
        self.rejected_steps += o.rejected_steps;
        self.known_events += o.known_events;
        self.known_pruned_rows += o.known_pruned_rows;
        self.known_lbp_rows += o.known_lbp_rows;
        self.repaired_frames += o.repaired_frames;
        self.lane_ids += o.lane_ids;
        self.published_lanes += o.published_lanes;
    }

    /// Sets the means from the run's sums.
    pub(crate) fn finish(&mut self, times: &RunTimes) {
        if self.frames > 0 {
            self.step_mean_ms = times.step / self.frames as f64;
            self.run_mean_ms = times.run / self.frames as f64;
        }
    }
}

/// The sums of a run's step and frame times, ms (for [`TrackStats`]' means).
#[derive(Debug, Default)]
pub(crate) struct RunTimes {
    step: f64,
    run: f64,
}

/// The models the firmware and the C API offer, as the host tools run them: the
/// [`ReferenceTracker`] on tables truncated to the model's Gram rank gives the same lanes, bit
/// for bit, as the tracker compiled for that rank (`host-tests/tests/rank_capacity.rs` checks
/// it), so a model's accuracy can be measured on the host before it is flashed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Model {
    /// `ReferenceTracker` on the given tables, the given configuration (C: `stjpdacf_init`).
    #[default]
    Reference,
    /// `Rank5Tracker`: the given tables at Gram rank 5 (C: `stjpdacf_rank5_init`).
    Rank5,
    /// The smallest model measured on the MCU, `Rank4Tracker` on the built-in uncoupled tables
    /// with LBP on every known-lane row (C: `stjpdacf_small_init`); it ignores the given tables.
    Small,
    /// The cheapest model the firmware measures (`bench/firmware/budget-rank3.json`):
    /// `Rank3Tracker` on the built-in uncoupled tables with LBP on every known-lane row (no C
    /// init of its own); it ignores the given tables.
    Rank3,
}

impl Model {
    /// The tables the model runs: `base` (the default or a hyperparameter file's), truncated to
    /// the model's rank, or the uncoupled tables at rank 4 for [`Model::Small`] and 3 for
    /// [`Model::Rank3`]. A truncated
    /// copy is leaked to `'static` (2.6 KB a call: a command-line run makes one).
    pub fn tables(self, base: &'static ReferenceTables) -> &'static ReferenceTables {
        match self {
            Model::Reference => base,
            Model::Rank5 => Box::leak(Box::new(truncated(base, 5))),
            Model::Small => Box::leak(Box::new(truncated(&stjpdacf::tables::UNCOUPLED, 4))),
            Model::Rank3 => Box::leak(Box::new(truncated(&stjpdacf::tables::UNCOUPLED, 3))),
        }
    }

    /// The configuration the model runs: `base`, with LBP on every known-lane row for
    /// [`Model::Small`] and [`Model::Rank3`].
    pub fn config(self, base: TrackerConfig) -> TrackerConfig {
        match self {
            Model::Reference | Model::Rank5 => base,
            Model::Small | Model::Rank3 => TrackerConfig {
                persist: stjpdacf::persist::PersistConfig {
                    association: stjpdacf::spatial::row::Association::Lbp,
                    ..base.persist
                },
                ..base
            },
        }
    }
}

/// `base` truncated to its first `rank` Gram components (at least 1, at most its own): the
/// dropped components' variance goes to the residual (`hyper.gram_variance_fraction`,
/// docs/design.md §4.1).
pub fn truncated(base: &ReferenceTables, rank: u32) -> ReferenceTables {
    let mut t = *base;
    t.gram_rank = rank.clamp(1, base.gram_rank);
    let ev = t.gram_eigval.as_slice();
    let total: f32 = ev.iter().sum();
    let kept: f32 = ev.iter().take(t.gram_rank as usize).sum();
    t.hyper.gram_variance_fraction = if total > 0.0 { kept / total } else { 1.0 };
    t
}

/// Builds f32 tables for the reference configuration from a hyperparameter file at run time (the
/// same computation as `stjpdacf tables`, without the Rust source round trip:
/// [`tablegen::static_tables`]), leaked to `'static`.
pub fn tables_from_hyper(h: &HyperFile) -> Result<&'static ReferenceTables> {
    if h.spatial.order != 2 || h.lanes() != 6 || h.index_points != 16 {
        bail!("the reference tracker needs N_T = 2, 6 lane slots and 16 index points");
    }
    tablegen::static_tables::<2, 6, 16>(h)
}

/// Lateral gap (metres) that separates two feature-point clusters in one BEV row.
pub const CLUSTER_GAP: f64 = 0.25;

/// Preprocessing the core expects (docs/design.md §1: "on the MCU the feature points arrive
/// preprocessed"): BEV points are binned to the spatial filter's rows (K = 4 rows per index
/// interval) and, within a row, points closer than [`CLUSTER_GAP`] laterally are merged into their
/// mean. An edge detector returns many points per marking in near rows (one BEV row spans tens of
/// image rows there); without this they would fill the row budget and look like clutter.
/// Points outside the window are dropped (the core would reject them).
///
/// **Support.** A BEV row near the camera spans many feature rows (image rows), so a painted
/// marking gives a cluster of many points there while uniform clutter gives clusters of one or
/// two; merged into one point each, they would look alike. A cluster is kept only when it holds
/// at least [`MIN_SUPPORT_FRACTION`] of the feature rows present in its BEV row (at least one
/// point): a marking detected in a quarter of the rows it crosses passes, an isolated clutter
/// point in a row that spans eight or more feature rows does not. Far rows (one or two feature
/// rows each) keep every cluster.
pub fn preprocess(points: &[(f64, f64)], tables: &ReferenceTables) -> Vec<[f32; 2]> {
    preprocess_with(points, tables, MIN_SUPPORT_FRACTION)
}

/// The support a cluster needs, as a fraction of the feature rows in its BEV row (see
/// [`preprocess`]). Chosen on the bundled replay (mid preset): with 0 (no support rule) the
/// near rows hold three to four clutter points per marking point and the lanes' near ends are
/// pulled by them.
pub const MIN_SUPPORT_FRACTION: f64 = 0.25;

/// [`preprocess`] with a given support fraction (0 keeps every cluster).
pub fn preprocess_with(
    points: &[(f64, f64)],
    tables: &ReferenceTables,
    min_support_fraction: f64,
) -> Vec<[f32; 2]> {
    let (u0, du, rows) = window(tables);
    let mut bins: Vec<Vec<f64>> = vec![Vec::new(); rows + 1];
    let mut urows: Vec<Vec<f64>> = vec![Vec::new(); rows + 1];
    for &(u, x) in points {
        if !(u.is_finite() && x.is_finite()) {
            continue;
        }
        if let Some(r) = row_of(u, (u0, du, rows)) {
            bins[r].push(x);
            urows[r].push(u);
        }
    }
    let mut out = Vec::new();
    for (r, xs) in bins.iter_mut().enumerate() {
        let k = distinct_u(&urows[r]) as f64;
        let min_support = ((k * min_support_fraction).floor() as usize).max(1);
        xs.sort_by(f64::total_cmp);
        let u = u0 + r as f64 * du;
        let mut start = 0;
        for i in 1..=xs.len() {
            if i == xs.len() || xs[i] - xs[i - 1] > CLUSTER_GAP {
                let c = &xs[start..i];
                if c.len() >= min_support {
                    out.push([u as f32, (c.iter().sum::<f64>() / c.len() as f64) as f32]);
                }
                start = i;
            }
        }
    }
    out
}

/// How far up the image a lane must be seen to be tracked at all: the row at which a lane seen
/// from the bottom of `cam`'s image covers `need` of the tables' index points (a lane is started
/// from at least [`stjpdacf::temporal::identity::IdentityConfig::min_common`] of them), and the
/// distance ahead there, metres. `None` when the bottom row is at or above the horizon or the
/// window has fewer index points beyond it.
pub fn lane_reach_needed(
    cam: &Camera,
    tables: &ReferenceTables,
    need: usize,
) -> Option<(f64, f64)> {
    let (u0, _) = cam.to_bev(cam.vp_col, cam.height - 1.0)?;
    let u = tables
        .index_u
        .iter()
        .map(|&u| f64::from(u))
        .filter(|&u| u >= u0)
        .nth(need.checked_sub(1)?)?;
    Some((cam.row_at(u)?, u))
}

/// The most points the [`ReferenceTracker`] takes in a frame (its `MEAS`; the core keeps the first
/// ones and counts the rest, `StepReport::over_budget_points`).
pub const POINT_BUDGET: usize = 256;

/// The most points the [`ReferenceTracker`] takes in one BEV row (its `PER_ROW`; the core keeps
/// the first ones in input order and counts the rest as the row being full).
pub const ROW_BUDGET: usize = 16;

/// Fits a frame of preprocessed points ([`preprocess`]: one `u` a row) to the core's budgets, [`ROW_BUDGET`] a row and [`POINT_BUDGET`] a frame, and returns
/// how many points it left out. Within the budgets it changes nothing. Over them, the core
/// would keep the first points in input order: a full row would lose its right-hand markings
/// and a full frame its far rows, every lane's far end. Instead a row keeps the points nearest
/// the car laterally (`|x|` ascending: the markings of the car's own and next lanes before the
/// outer ones and the clutter beyond them), and the frame's budget is shared out over its rows
/// max-min fairly: every row keeps `min(n_r, ℓ)` points for the largest level `ℓ` that fits,
/// and the rest of the budget goes one point each to the fullest rows' next points, the
/// nearest rows first. The kept points stay in their input order. No threshold is chosen here:
/// the budgets are the core's capacities.
pub fn fit_budget(points: &mut Vec<[f32; 2]>) -> usize {
    fit_budget_to(points, ROW_BUDGET, POINT_BUDGET)
}

/// [`fit_budget`] with given budgets.
pub fn fit_budget_to(points: &mut Vec<[f32; 2]>, per_row: usize, budget: usize) -> usize {
    // The rows (points of equal u), nearest first, each with its points' indices by |x|
    // ascending (ties: input order), cut to the row budget.
    let mut by_u: std::collections::BTreeMap<OrderedU, Vec<usize>> = Default::default();
    for (i, p) in points.iter().enumerate() {
        by_u.entry(OrderedU(p[0])).or_default().push(i);
    }
    let mut rows: Vec<Vec<usize>> = by_u
        .into_values()
        .map(|mut idx| {
            idx.sort_by(|&a, &b| points[a][1].abs().total_cmp(&points[b][1].abs()));
            idx.truncate(per_row);
            idx
        })
        .collect();
    let total: usize = rows.iter().map(Vec::len).sum();
    if total > budget {
        // The largest level ℓ with Σ min(n_r, ℓ) ≤ budget, then one more point for the first
        // rows over it while the budget lasts.
        let kept_at = |l: usize| rows.iter().map(|r| r.len().min(l)).sum::<usize>();
        let mut level = 0;
        while level < per_row && kept_at(level + 1) <= budget {
            level += 1;
        }
        let mut spare = budget - kept_at(level);
        for r in &mut rows {
            let extra = usize::from(spare > 0 && r.len() > level);
            spare -= extra;
            r.truncate(level + extra);
        }
    }
    let mut keep = vec![false; points.len()];
    for &i in rows.iter().flatten() {
        keep[i] = true;
    }
    let before = points.len();
    let mut k = keep.iter();
    points.retain(|_| k.next().copied().unwrap_or(false));
    before - points.len()
}

/// A row's `u` as a map key, in `f32::total_cmp` order.
#[derive(Clone, Copy)]
struct OrderedU(f32);

impl PartialEq for OrderedU {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == std::cmp::Ordering::Equal
    }
}

impl Eq for OrderedU {}

impl PartialOrd for OrderedU {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for OrderedU {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// How many of `points` (BEV `(u, x)`) lie outside the tracker's window: their row, as
/// [`preprocess`] bins them, nearer than the first or beyond the last.
pub fn outside_window(points: &[(f64, f64)], tables: &ReferenceTables) -> usize {
    let w = window(tables);
    points
        .iter()
        .filter(|(u, _)| row_of(*u, w).is_none())
        .count()
}

/// The tracker's BEV rows as [`preprocess`] bins to them: the first row's `u`, the spacing and
/// the last row's index (K = 4 rows per index interval).
fn window(tables: &ReferenceTables) -> (f64, f64, usize) {
    let h = &tables.hyper;
    let (u0, u1) = (f64::from(h.u_min), f64::from(h.u_max));
    let rows = 15 * 4;
    (u0, (u1 - u0) / rows as f64, rows)
}

/// The row of a point `u` metres ahead ([`window`]), `None` outside the window.
fn row_of(u: f64, (u0, du, rows): (f64, f64, usize)) -> Option<usize> {
    let r = ((u - u0) / du).round();
    (r >= 0.0 && r <= rows as f64).then_some(r as usize)
}

/// Number of distinct values (feature rows) among a BEV row's `u`s.
fn distinct_u(us: &[f64]) -> usize {
    let mut v: Vec<f64> = us.to_vec();
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    v.len()
}

/// The smoother lag of the [`ReferenceTracker`] (`StepOutput::smoothed` is this many frames
/// back).
pub const REFERENCE_LAG: usize = 4;

/// Whether `u` lies in the part of a lane that predictions report: within its observed extent
/// (one index interval of margin) and not beyond the far end of the window, where the tracker
/// has no evidence (the lane's extent ends there at the latest); nearer than the window only for
/// a lane observed down to it (the margin).
fn reported(tables: &ReferenceTables, lane: &LaneEstimate<16>, u: f64) -> bool {
    let h = &tables.hyper;
    let u_max = f64::from(h.u_max);
    let interval = (u_max - f64::from(h.u_min)) / 15.0;
    let (first, last) = (f64::from(lane.u_first), f64::from(lane.u_last));
    u.is_finite() && u >= first - interval && u <= (last + interval).min(u_max)
}

/// A lane nearer than the window: the line through its two nearest index points.
fn extension(tables: &ReferenceTables, lane: &LaneEstimate<16>, u: f64) -> f64 {
    let (u0, u1) = (f64::from(tables.index_u[0]), f64::from(tables.index_u[1]));
    let (x0, x1) = (f64::from(lane.z[0]), f64::from(lane.z[1]));
    x0 + (u - u0) * (x0 - x1) / (u0 - u1)
}

fn inside(tables: &ReferenceTables, u: f64) -> bool {
    u >= f64::from(tables.hyper.u_min) && u <= f64::from(tables.hyper.u_max)
}

/// Where a lane is at `u` metres ahead, by the rules of the predictions: inside the BEV window
/// the tracker's GP evaluation ([`ReferenceTracker::lane_at`], with its variance); nearer than
/// the window the line through the two nearest index points (no variance), for a lane observed
/// down to the window's near end. `None` beyond the window's far end (no evidence there:
/// docs/design.md §8), outside the lane's observed extent (one index interval of margin) or for
/// a free slot.
pub fn lane_x(
    tr: &ReferenceTracker,
    tables: &ReferenceTables,
    lane: &LaneEstimate<16>,
    u: f64,
) -> Option<(f64, Option<f64>)> {
    if !reported(tables, lane, u) {
        None
    } else if inside(tables, u) {
        let (x, var) = tr.lane_at(usize::from(lane.slot), u as f32)?;
        Some((f64::from(x), Some(f64::from(var))))
    } else {
        Some((extension(tables, lane, u), None))
    }
}

/// [`lane_x`] from the lane's index-point values alone (linear between index points; for
/// lanes the tracker no longer holds, e.g. the smoothed ones), with the same extent rules.
pub fn lane_x_from_points(
    tables: &ReferenceTables,
    lane: &LaneEstimate<16>,
    u: f64,
) -> Option<f64> {
    if !reported(tables, lane, u) {
        return None;
    }
    if !inside(tables, u) {
        return Some(extension(tables, lane, u));
    }
    let us = &tables.index_u;
    let j = (1..16).find(|&j| f64::from(us[j]) >= u).unwrap_or(15);
    let (u0, u1) = (f64::from(us[j - 1]), f64::from(us[j]));
    let (x0, x1) = (f64::from(lane.z[j - 1]), f64::from(lane.z[j]));
    Some(x0 + (x1 - x0) * (u - u0) / (u1 - u0))
}

/// The TuSimple record of image `raw_file` sampled at `h_samples`, from lanes `(offset,
/// columns)`: the lanes with at least one point, left to right by offset.
pub fn lanes_record(
    raw_file: &str,
    h_samples: &[f64],
    lanes: impl Iterator<Item = (f64, Vec<f64>)>,
    run_time: Option<f64>,
) -> TuSimpleRecord {
    let mut lanes: Vec<(f64, Vec<f64>)> = lanes
        .filter(|(_, xs)| xs.iter().any(|v| *v >= 0.0))
        .collect();
    lanes.sort_by(|a, b| a.0.total_cmp(&b.0));
    TuSimpleRecord {
        raw_file: raw_file.to_string(),
        lanes: lanes.into_iter().map(|(_, xs)| xs).collect(),
        h_samples: h_samples.to_vec(),
        run_time,
    }
}

/// A lane's columns at image rows `rows` through the camera, `x_at(u)` giving its lateral
/// position at `u` metres ahead; −2 where it gives none, above the horizon and outside the
/// image.
pub fn lane_columns(cam: &Camera, rows: &[f64], x_at: impl Fn(f64) -> Option<f64>) -> Vec<f64> {
    rows.iter()
        .map(|&row| {
            let Some((u, _)) = cam.to_bev(cam.vp_col, row) else {
                return NO_POINT;
            };
            match x_at(u).and_then(|x| cam.to_image(u, x)) {
                Some((col, _)) if col >= 0.0 && col < cam.width => col,
                _ => NO_POINT,
            }
        })
        .collect()
}

/// One point of a [`LaneBand`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BandPoint {
    /// Metres ahead.
    pub u: f64,
    /// Lateral position, metres.
    pub x: f64,
    /// Standard deviation of `x` (the tracker's posterior), metres; `None` where the lane is
    /// extrapolated nearer than the window.
    pub sd: Option<f64>,
}

/// A published lane sampled along `u` for drawing: mean and ±σ inside the window, the linear
/// extension nearer than it (see [`lane_x`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LaneBand {
    /// The lane's stable id.
    pub id: u32,
    /// Frames since the lane was last seen.
    pub misses: u16,
    /// Samples by increasing `u`.
    pub points: Vec<BandPoint>,
}

/// Samples a published lane at the distances `us` (metres ahead), leaving out those where
/// [`lane_x`] does not define it.
pub fn lane_band(
    tr: &ReferenceTracker,
    tables: &ReferenceTables,
    lane: &LaneEstimate<16>,
    us: impl IntoIterator<Item = f64>,
) -> LaneBand {
    let points = us
        .into_iter()
        .filter_map(|u| {
            lane_x(tr, tables, lane, u).map(|(x, var)| BandPoint {
                u,
                x,
                sd: var.map(|v| v.max(0.0).sqrt()),
            })
        })
        .collect();
    LaneBand {
        id: lane.id.0,
        misses: lane.misses,
        points,
    }
}

/// What [`track_with`] shows its observer after each frame.
pub struct FrameView<'a> {
    /// Index of the frame in the input.
    pub index: usize,
    /// The frame.
    pub frame: &'a Frame,
    /// The points handed to the tracker (BEV `[u, x]`, after [`preprocess`]).
    pub points: &'a [[f32; 2]],
    /// The tracker after the step.
    pub tracker: &'a ReferenceTracker,
    /// The camera of the frame's clip ([`clip_camera`]: from its frames' [`Frame::camera`], else
    /// the one the run was given).
    pub camera: &'a Camera,
    /// The step's output (`None` when the tracker refused the frame).
    pub output: Option<&'a StepOutput<6, 16>>,
    /// The prediction written for this frame, if any.
    pub prediction: Option<&'a TuSimpleRecord>,
    /// The tracker ids of the prediction's lanes, in the order they are written.
    pub prediction_ids: &'a [u32],
}

/// A frame's points in BEV `(u, x)`, metres: through the inverse IPM for image points
/// ([`Space::Image`]) or as given (`[x, u]`, [`Space::Bev`]); points that do not map to a finite
/// BEV point are counted in `unmapped`.
pub fn bev_points(f: &Frame, cam: &Camera, space: Space, unmapped: &mut usize) -> Vec<(f64, f64)> {
    let mut bev_pts: Vec<(f64, f64)> = Vec::with_capacity(f.points.len());
    for p in &f.points {
        let bev = match space {
            Space::Image => cam.to_bev(p[0], p[1]),
            Space::Bev => Some((p[1], p[0])),
        };
        match bev {
            Some((u, x)) if u.is_finite() && x.is_finite() => bev_pts.push((u, x)),
            _ => *unmapped += 1,
        }
    }
    bev_pts
}

/// How many of `points` (image pixels `[column, row]`) lie outside `cam`'s image: a column or
/// row below 0 or beyond its width or height (a non-finite one counts too). A point detector
/// writes none, so any means the points come from another camera or another image scale than
/// `cam` (e.g. a 512×288 front end's points tracked with the 1280×720 camera, `--scale`
/// missing, or the other way round).
pub fn outside_image(points: &[[f64; 2]], cam: &Camera) -> usize {
    let inside = |v: f64, n: f64| (0.0..=n).contains(&v);
    points
        .iter()
        .filter(|p| !(inside(p[0], cam.width) && inside(p[1], cam.height)))
        .count()
}

/// How many of the labelled points of `labels` the camera they are to be read with cannot map
/// to the road (outside its image, or at or above its horizon), and how many there are: labels
/// drawn in another camera or image size (512×288 labels read with TuSimple's 1280×720 camera
/// have their upper half above its horizon) when the first is not 0.
pub fn labels_off_camera(labels: &[TuSimpleRecord], cam: &Camera) -> (usize, usize) {
    let points: Vec<[f64; 2]> = labels
        .iter()
        .flat_map(|r| {
            r.lanes
                .iter()
                .flat_map(|l| r.points_of(l).map(|(c, w)| [c, w]))
        })
        .collect();
    let off = outside_image(&points, cam)
        + points
            .iter()
            .filter(|p| (0.0..=cam.width).contains(&p[0]) && (0.0..=cam.height).contains(&p[1]))
            .filter(|p| cam.to_bev(p[0], p[1]).is_none())
            .count();
    (off, points.len())
}

/// The warning for [`labels_off_camera`]'s count when it is more than a tenth of the points,
/// else `None`; `flag` names the option that gives the camera. (TuSimple's own train labels
/// with its camera have 0.8–1.6 % of their points at or above its horizon, on crests of the
/// road; a 512×288 label file read with that camera 81 %.)
pub fn labels_off_camera_warning(
    labels: &[TuSimpleRecord],
    cam: &Camera,
    flag: &str,
) -> Option<String> {
    let (off, n) = labels_off_camera(labels, cam);
    (10 * off > n).then(|| {
        format!(
            "warning: {off} of the {n} label points lie outside the {}x{} image of {flag} or at \
             or above its horizon (row {:.1}), so they cannot be mapped to the road: {flag} is \
             the camera the labels were drawn in (tusimple for TuSimple's 1280x720 labels; a \
             camera file of their size for resized ones)",
            cam.width, cam.height, cam.vp_row
        )
    })
}

/// TuSimple's label rows (160–710 px every 10 px of a 720-row image) scaled to an image
/// `height` rows high: the rows a prediction is written at when a frame names none.
pub fn tusimple_rows(height: f64) -> Vec<f64> {
    let s = height / 720.0;
    (0..56).map(|i| (160.0 + 10.0 * f64::from(i)) * s).collect()
}

/// Make every frame ask for a prediction: a frame without `h_samples` gets
/// [`tusimple_rows`] of its camera's height (its own camera, else `cam`), one without
/// `raw_file` the name `clip/k` (`k` its index in its clip, from 0). For frames of an
/// unlabelled sequence, which [`track_with`] otherwise passes without a prediction.
pub fn predict_every_frame(frames: &mut [Frame], cam: &Camera) {
    let mut k = 0usize;
    let mut clip: Option<String> = None;
    for f in frames.iter_mut() {
        k = if clip.as_deref() == Some(f.clip.as_str()) {
            k + 1
        } else {
            clip = Some(f.clip.clone());
            0
        };
        if f.h_samples.is_none() {
            f.h_samples = Some(tusimple_rows(f.camera.map_or(cam.height, |c| c.height)));
        }
        if f.raw_file.is_none() {
            f.raw_file = Some(format!("{}/{k}", f.clip));
        }
    }
}

/// One frame of `stjpdacf track --lanes`: the lanes the tracker publishes (as the predictions:
/// seen within [`MAX_REPORT_MISSES`] frames) with their ids, in the BEV.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LanesFrame {
    /// The frame's clip.
    pub clip: String,
    /// The frame's time, seconds.
    pub t: f64,
    /// The frame's image, if it names one.
    pub raw_file: Option<String>,
    /// Whether the tracker refused the frame (then `lanes` is empty and the state is the
    /// previous frame's).
    pub rejected: bool,
    /// Metres ahead of the index points at which [`LaneRecord::x`] and [`LaneRecord::var`] are
    /// given.
    pub index_u: Vec<f64>,
    /// The published lanes, left to right at the nearest index point.
    pub lanes: Vec<LaneRecord>,
    /// Time of the frame [`REFERENCE_LAG`] accepted frames back in this clip, which
    /// [`LanesFrame::smoothed`] describes (`None` until the clip has that many frames).
    #[serde(default)]
    pub smoothed_t: Option<f64>,
    /// That frame's image, if it names one.
    #[serde(default)]
    pub smoothed_raw_file: Option<String>,
    /// The fixed-lag smoother's estimate of the lanes published at that frame, with what this
    /// frame and the [`REFERENCE_LAG`] − 1 between have added (same ids, left to right;
    /// `u_first`/`u_last` are that frame's extent, `age`/`hits`/`misses` the lane's now).
    #[serde(default)]
    pub smoothed: Vec<LaneRecord>,
}

/// One published lane of a [`LanesFrame`] ([`LaneEstimate`]'s fields).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaneRecord {
    /// Stable id: the same lane keeps it from frame to frame.
    pub id: u32,
    /// Existence probability.
    pub existence: f64,
    /// Frames since the lane started (0 in its first frame).
    pub age: u32,
    /// Frames in which it was observed.
    pub hits: u32,
    /// Frames since it was last seen.
    pub misses: u16,
    /// Observed extent, metres ahead: nearest.
    pub u_first: f64,
    /// Observed extent: farthest.
    pub u_last: f64,
    /// Lateral position at each index point, metres (positive to the right of the camera
    /// axis, as the points' `x`).
    pub x: Vec<f64>,
    /// Its variance, m².
    pub var: Vec<f64>,
}

impl LaneRecord {
    fn new(l: &LaneEstimate<16>) -> Self {
        LaneRecord {
            id: l.id.0,
            existence: f64::from(l.existence),
            age: l.age,
            hits: l.hits,
            misses: l.misses,
            u_first: f64::from(l.u_first),
            u_last: f64::from(l.u_last),
            x: l.z.iter().map(|&z| f64::from(z)).collect(),
            var: l.var.iter().map(|&z| f64::from(z)).collect(),
        }
    }
}

/// Lane records left to right at the nearest index point.
fn left_to_right(mut lanes: Vec<LaneRecord>) -> Vec<LaneRecord> {
    lanes.sort_by(|a, b| {
        let x0 = |l: &LaneRecord| l.x.first().copied().unwrap_or(0.0);
        x0(a).total_cmp(&x0(b))
    });
    lanes
}

/// One accepted frame of the clip being recorded: its time, its image and the ids it published.
type Published = (f64, Option<String>, Vec<u32>);

/// Builds the [`LanesFrame`] of every frame of a run (`stjpdacf track --lanes`), remembering
/// the last [`REFERENCE_LAG`] + 1 accepted frames of the clip to pair the smoothed lanes with
/// the frame they describe (the same rule as the demo's smoother row: the smoothed lanes of
/// frame k are those whose ids the filter published at frame k).
#[derive(Debug, Default)]
pub struct LanesRecorder {
    clip: Option<String>,
    history: std::collections::VecDeque<Published>,
}

impl LanesRecorder {
    /// The [`LanesFrame`] of frame `v` (frames in the order the tracker saw them).
    pub fn record(&mut self, v: &FrameView<'_>, tables: &ReferenceTables) -> LanesFrame {
        if self.clip.as_deref() != Some(v.frame.clip.as_str()) {
            self.clip = Some(v.frame.clip.clone());
            self.history.clear();
        }
        let published = |l: &&LaneEstimate<16>| l.misses <= MAX_REPORT_MISSES;
        let lanes = v
            .output
            .map(|o| {
                o.filtered
                    .iter()
                    .filter(published)
                    .map(LaneRecord::new)
                    .collect()
            })
            .unwrap_or_default();
        let mut smoothed = Vec::new();
        let (mut smoothed_t, mut smoothed_raw_file) = (None, None);
        if let Some(o) = v.output {
            let ids = o
                .filtered
                .iter()
                .filter(published)
                .map(|l| l.id.0)
                .collect();
            self.history
                .push_back((v.frame.t, v.frame.raw_file.clone(), ids));
            if self.history.len() > REFERENCE_LAG + 1 {
                self.history.pop_front();
            }
            if let (true, Some((t, raw, ids))) = (
                self.history.len() == REFERENCE_LAG + 1,
                self.history.front(),
            ) {
                smoothed_t = Some(*t);
                smoothed_raw_file.clone_from(raw);
                smoothed = o
                    .smoothed
                    .iter()
                    .filter(|l| ids.contains(&l.id.0))
                    .map(LaneRecord::new)
                    .collect();
            }
        }
        LanesFrame {
            clip: v.frame.clip.clone(),
            t: v.frame.t,
            raw_file: v.frame.raw_file.clone(),
            rejected: v.output.is_none(),
            index_u: tables.index_u.iter().map(|&u| f64::from(u)).collect(),
            lanes: left_to_right(lanes),
            smoothed_t,
            smoothed_raw_file,
            smoothed: left_to_right(smoothed),
        }
    }
}

/// A frame's time stamp as the tracker gets it, integer microseconds.
pub fn frame_micros(f: &Frame) -> i64 {
    f.micros()
}

/// Writes the header of a points file (`stjpdacf track --export-points`): the input of the C
/// example `capi/examples/track.c`, which must write the same predictions. Text, one record a
/// line, numbers in Rust's shortest round-trip form (`strtod`/`strtof` read them back exactly):
///
/// ```text
/// stjpdacf-points 1
/// camera <width> <height> <vp_col> <vp_row> <height_m> <focal_px>
/// frame <clip number> <time µs> <points> <rows> <raw_file or ->   (then, per frame:)
/// <u> <x>                                                         (points lines: f32, after preprocess)
/// <row>                                                           (rows lines: h_samples, f64)
/// ```
///
/// # Errors
/// Writing.
pub fn write_points_header(w: &mut impl std::io::Write, cam: &Camera) -> std::io::Result<()> {
    writeln!(w, "stjpdacf-points 1")?;
    writeln!(
        w,
        "camera {} {} {} {} {} {}",
        cam.width, cam.height, cam.vp_col, cam.vp_row, cam.height_m, cam.focal_px
    )
}

/// Writes one frame of a points file (see [`write_points_header`]): the points the tracker got
/// and, when a prediction is due, the rows it is written at. `clip` numbers the clips (a change
/// resets the tracker).
///
/// # Errors
/// Writing.
pub fn write_points_frame(
    w: &mut impl std::io::Write,
    clip: usize,
    v: &FrameView<'_>,
) -> std::io::Result<()> {
    let rows = match (&v.frame.raw_file, &v.frame.h_samples) {
        (Some(raw), Some(rows)) => Some((raw.as_str(), rows.as_slice())),
        _ => None,
    };
    if rows.is_some_and(|r| r.0.is_empty() || r.0.contains(char::is_whitespace)) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "a raw_file with white space (or empty) cannot go into a points file",
        ));
    }
    writeln!(
        w,
        "frame {clip} {} {} {} {}",
        frame_micros(v.frame),
        v.points.len(),
        rows.map_or(0, |r| r.1.len()),
        rows.map_or("-", |r| r.0)
    )?;
    for p in v.points {
        writeln!(w, "{} {}", p[0], p[1])?;
    }
    for r in rows.map_or(&[][..], |r| r.1) {
        writeln!(w, "{r}")?;
    }
    Ok(())
}

/// Runs the tracker over `frames`; returns the predictions for the frames with `h_samples`.
/// `progress(k)` is called after frame `k`.
///
/// # Errors
/// A frame that fails [`Frame::check`].
pub fn track(
    frames: &[Frame],
    tables: &'static ReferenceTables,
    cam: &Camera,
    space: Space,
    mut progress: impl FnMut(usize),
) -> Result<(Vec<TuSimpleRecord>, TrackStats)> {
    track_with(
        frames,
        tables,
        cam,
        space,
        TrackerConfig::DEFAULT,
        |v: FrameView<'_>| progress(v.index),
    )
}

/// The camera a clip's `frames` are mapped with: where they carry cameras ([`Frame::camera`],
/// e.g. each image's estimate), the median of each of their quantities (horizon row, vanishing
/// column, height, focal length; a fixed camera estimated on every frame, so one frame whose
/// estimate missed does not move the clip's BEV); else `fallback`.
pub fn clip_camera(frames: &[Frame], fallback: &Camera) -> Camera {
    let cams: Vec<Camera> = frames.iter().filter_map(|f| f.camera).collect();
    Camera::median(&cams).unwrap_or(*fallback)
}

/// [`track`] with a tracker configuration, calling `observe` after every frame (for overlays and
/// progress). `run_time` of a prediction (and the `run_*` statistics) is the wall time spent on
/// the frame from its points to its lanes: mapping to BEV, [`preprocess`], `Tracker::step` and
/// the evaluation at the `h_samples` rows; `observe` is not counted. `cam` maps the points and
/// the lanes of every clip whose frames carry no camera ([`Frame::camera`]); a clip whose frames
/// do (estimated cameras, `stjpdacf frontend --camera estimate`) is mapped with one camera
/// throughout, [`clip_camera`] (a camera that changed from frame to frame would move the lanes
/// the tracker holds).
///
/// # Errors
/// A frame that fails [`Frame::check`].
pub fn track_with(
    frames: &[Frame],
    tables: &'static ReferenceTables,
    cam: &Camera,
    space: Space,
    config: TrackerConfig,
    mut observe: impl FnMut(FrameView<'_>),
) -> Result<(Vec<TuSimpleRecord>, TrackStats)> {
    let mut stats = TrackStats::default();
    let mut out = Vec::new();
    let mut tracker: Option<Box<ReferenceTracker>> = None;
    let mut clip: Option<&str> = None;
    let mut times = RunTimes::default();
    let mut clip_cam = *cam;
    // The lane ids published in the current clip (a new clip's tracker starts its ids anew).
    let mut clip_ids: HashSet<u32> = HashSet::new();
    for (k, f) in frames.iter().enumerate() {
        if stats.begin_frame(k, f, &mut clip)? {
            stats.lane_ids += clip_ids.len();
            clip_ids.clear();
            tracker = Some(Box::new(ReferenceTracker::with_config(tables, config)));
            let clip_frames = crate::tusimple::clips(&frames[k..]).next().unwrap_or(&[]);
            clip_cam = clip_camera(clip_frames, cam);
        }
        let cam = &clip_cam;
        let Some(tr) = tracker.as_mut() else { continue };
        let start = WallClock::now();
        let bev_pts = bev_points(f, cam, space, &mut stats.unmapped_points);
        if space == Space::Image {
            stats.outside_image_points += outside_image(&f.points, cam);
        }
        stats.outside_window_points += outside_window(&bev_pts, tables);
        let mut pts = preprocess(&bev_pts, tables);
        let left_out = fit_budget(&mut pts);
        stats.over_budget_points += left_out;
        stats.over_budget_frames += usize::from(left_out > 0);
        let step_start = ThreadTime::now();
        let res = tr.step(Instant::from_micros(frame_micros(f)), &pts);
        stats.add_step(&mut times, step_start.elapsed().as_secs_f64() * 1e3);
        let output = match res {
            Ok(o) => {
                let kr = &o.report.known;
                stats.known_events += u64::from(kr.events);
                stats.known_pruned_rows += u64::from(kr.pruned_rows);
                stats.known_lbp_rows += u64::from(kr.lbp_rows);
                stats.repaired_frames += usize::from(o.report.temporal_cov_repairs > 0);
                for l in o.filtered.iter().filter(|l| l.misses <= MAX_REPORT_MISSES) {
                    clip_ids.insert(l.id.0);
                    stats.published_lanes += 1;
                }
                Some(o)
            }
            Err(_) => {
                stats.rejected_steps += 1;
                None
            }
        };
        let mut prediction_ids: Vec<u32> = Vec::new();
        let prediction = match (&output, &f.raw_file, &f.h_samples) {
            (Some(output), Some(raw), Some(rows)) => {
                stats.outside_image_rows += rows
                    .iter()
                    .filter(|r| !(0.0..=cam.height).contains(*r))
                    .count();
                let mut lanes: Vec<(f64, Vec<f64>, u32)> = output
                    .filtered
                    .iter()
                    .filter(|l| l.misses <= MAX_REPORT_MISSES)
                    .map(|l| {
                        (
                            f64::from(l.z[0]),
                            lane_columns(cam, rows, |u| lane_x(tr, tables, l, u).map(|(x, _)| x)),
                            l.id.0,
                        )
                    })
                    .filter(|(_, xs, _)| xs.iter().any(|v| *v >= 0.0))
                    .collect();
                // The order `lanes_record` writes (by lateral position at the nearest index point).
                lanes.sort_by(|a, b| a.0.total_cmp(&b.0));
                prediction_ids = lanes.iter().map(|l| l.2).collect();
                Some(lanes_record(
                    raw,
                    rows,
                    lanes.into_iter().map(|(z, xs, _)| (z, xs)),
                    None,
                ))
            }
            _ => None,
        };
        let run_ms = start.elapsed().as_secs_f64() * 1e3;
        stats.add_run(&mut times, run_ms);
        let prediction = prediction.map(|p| TuSimpleRecord {
            run_time: Some(run_ms),
            ..p
        });
        observe(FrameView {
            index: k,
            frame: f,
            points: &pts,
            tracker: tr,
            camera: cam,
            output: output.as_ref(),
            prediction: prediction.as_ref(),
            prediction_ids: &prediction_ids,
        });
        if let Some(p) = prediction {
            out.push(p);
            stats.predictions += 1;
        }
    }
    stats.lane_ids += clip_ids.len();
    stats.finish(&times);
    Ok((out, stats))
}
