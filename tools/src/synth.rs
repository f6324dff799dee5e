//! The real-geometry replay generator (`stjpdacf synth`): real TuSimple lane shapes, animated into
//! short clips and rendered as noisy feature points, with ground truth for every frame.
//!
//! # What it does
//!
//! Each TuSimple label (one JSON line: `raw_file`, `h_samples`, `lanes`, −2 = no point) becomes one
//! clip of [`SynthParams::frames_per_clip`] frames (default 20) at `1 / frame_step` fps (default
//! 20 fps: t = 0, 0.05, …, 0.95 s). The labelled lanes are mapped to the bird's-eye view with the
//! flat-road camera ([`Camera::tusimple`] for 1280×720 labels) and animated **backwards in time
//! from the labelled frame**: the clip's LAST frame is the label itself (its ground truth equals
//! the source label exactly, apart from an appended merge/split lane, below), and the earlier frames
//! are the same road seen τ = t_last − t seconds before. Every effect below is a function of τ
//! that vanishes at τ = 0.
//!
//! Each clip draws its scenario from a ChaCha8 generator seeded with `seed` and the clip index
//! (`ChaCha8Rng::seed_from_u64`), so a clip does not depend on how many clips are generated and
//! the output is byte-for-byte reproducible.
//!
//! ## Lane motion (all lanes, lateral offset δ(u, τ) added to x in BEV metres)
//! * **Drift** `v·τ + A·(sin(ωτ + φ) − sin φ)`: lateral speed v ~ U(±[`SynthParams::lateral_speed`])
//!   (default 0.5 m/s), wobble A ~ U(0, [`SynthParams::wobble`]) (default 0.3 m), period
//!   2π/ω ~ U(1.5, 3) s, φ ~ U(0, 2π).
//! * **Heading change** `ψ̇·τ·u`, ψ̇ ~ U(±[`SynthParams::yaw_rate`]) (default 0.02 rad/s).
//! * **Curvature change** `κ̇·τ·u²/2`, κ̇ ~ U(±[`SynthParams::curvature_rate`]) (default
//!   2·10⁻⁴ 1/(m·s)).
//! * The three above are multiplied by [`SynthParams::motion`] (default 1; 0 = a static road).
//! * **Lane change**, with probability [`SynthParams::lane_change_prob`] (default 0.2): all lanes
//!   shift by ±[`SynthParams::lane_width`] (3.7 m) with a smoothstep over
//!   [`SynthParams::lane_change_duration`] (1 s) that ends at τ_a ~ U(0, 0.15) s before the last
//!   frame. Only the labelled lanes are moved; lanes the shift would bring into view are not
//!   invented.
//!
//! ## Lane extent
//! * **Far end appearing/disappearing**, with probability [`SynthParams::far_end_prob`] (0.3) for
//!   one random lane: its far end is `u_far + r·τ` with |r| ~ U([`SynthParams::far_end_rate`])
//!   (20–60 m/s) and a random sign: r < 0 means the lane grows out of the distance during the clip
//!   (it is absent while shorter than 5 m), r > 0 means it recedes (earlier frames extend it beyond
//!   the label by linear extrapolation of its last 4 BEV points, at most to 200 m).
//! * Where drift brings a lane's near end into the image (the label stopped because the lane left
//!   the image), the lane is extended by linear extrapolation of its first 4 BEV points.
//!
//! ## Merge / split
//! With probability [`SynthParams::merge_prob`] (0.15) an extra lane branches off the leftmost or
//! rightmost lane, outwards: it coincides with that lane for [`SynthParams::merge_shared`] (15 m)
//! before the branch point u_s and then moves out by ±0.9·lane width with a smoothstep over 30 m.
//! u_s ~ U(15, 40) m at the last frame and is fixed on the road (it approaches at the vehicle's
//! speed). Where the two lanes are within 2 px of each other their feature points are **shared**
//! (emitted once). The extra lane is appended to the ground truth (after the source lanes).
//!
//! ## Rendering (per frame)
//! * **Rows**: every lane is sampled at the image rows that are multiples of
//!   [`SynthParams::row_step`] (default 2 px, so all TuSimple `h_samples` rows are included),
//!   below the horizon and inside the image.
//! * **Dashed markings**, with probability [`SynthParams::dashed_prob`] (0.5) per lane: paint
//!   [`SynthParams::dash_paint`] (3 m), gap [`SynthParams::dash_gap`] (9 m), random phase; the
//!   pattern is fixed on the road and moves with the vehicle speed ~ U([`SynthParams::speed`])
//!   (20–30 m/s).
//! * **Occlusion**: cars (below) hide every lane, road-edge and shadow point inside their image box.
//! * **Misses**: each remaining row is detected with probability [`SynthParams::detect_prob`].
//! * **Pixel noise**: Gaussian, σ = [`SynthParams::pixel_noise`] px on the column (rows are the
//!   detector's rows, exact); points that fall outside the image are dropped.
//! * **Uniform clutter**: Poisson([`SynthParams::clutter_rate`]) points per frame, uniform over
//!   the image columns and the rows from the first `h_samples` row to the bottom.
//! * **Shadow edges**: Poisson([`SynthParams::shadows`]) per clip; a BEV segment fixed on the road
//!   (u ~ U(5, 50) m at the last frame, 2–8 m long across, slightly tilted), rendered as
//!   horizontal-ish image points every 8 px of column, each detected with `detect_prob`, noisy.
//! * **Cars**: Poisson([`SynthParams::cars`]) per clip, 1.8 m wide and 1.5 m high, between two
//!   lanes at u ~ U(8, 40) m moving ±3 m/s relative to us, visible over a random run of ≥ 6 frames;
//!   their two side edges are short vertical clusters of points (every `row_step` rows), and their
//!   box occludes what is behind.
//! * **Road edge**, with probability [`SynthParams::road_edge_prob`] (per clip): a curve parallel to
//!   the outermost lane, 0.5–1.5 m outside it, detected per row with
//!   [`SynthParams::road_edge_detect`]; it is clutter (not in the ground truth).
//! * **Short straight distractors** (tar seams, arrows, crosswalk bars):
//!   Poisson([`SynthParams::distractors`]) segments per frame, drawn independently in every frame
//!   (default 0 in every preset). Each is a straight BEV segment of length U(3, 10) m at a
//!   uniform orientation, its centre uniform laterally in ±[`DISTRACTOR_X`] m and ahead such that
//!   the whole segment lies in [`DISTRACTOR_U`] (the tracker's default window). It gives one
//!   point on every feature row it crosses (no per-row misses), with the usual column noise,
//!   hidden by cars; a segment across the road crosses one row or none. Its draws come from a
//!   second generator seeded from the clip's seed, so the other draws of a clip (and so the
//!   output with `distractors = 0`) do not depend on it.
//! * Points of a frame are sorted by row (bottom first), then column: their order says nothing about
//!   which lane they came from.
//!
//! ## Noise presets ([`NoiseLevel`])
//! | preset | pixel_noise (px) | detect_prob | clutter_rate (/frame) | shadows (/clip) | cars (/clip) | road_edge_prob |
//! |--------|-----------------:|------------:|----------------------:|----------------:|-------------:|---------------:|
//! | low    | 2                | 0.9         | 5                     | 0.5             | 0.5          | 0.2            |
//! | mid    | 5                | 0.75        | 25                    | 1.5             | 1            | 0.5            |
//! | high   | 10               | 0.55        | 60                    | 3               | 2            | 0.8            |
//!
//! Pixel quantities are for the camera's image size (1280×720 for [`Camera::tusimple`]).
//!
//! ## Outputs
//! * Frames ([`Frame`], JSON lines): `clip` = `synthNNNN` (NNNN = the clip index), `t` in seconds
//!   from 0, `raw_file` = the source label's `raw_file` on the last frame and
//!   `synth/synthNNNN/K.jpg` (K = 1..=19) on the others, `h_samples` of the label on every frame.
//! * Ground truth of the last frames (TuSimple JSON lines, what the official scorer reads).
//! * Ground truth of every frame (TuSimple JSON lines, `raw_file` as on the frames), for scoring a
//!   fixed-lag smoother. Lanes with no point in a frame are left out of that frame's record, so a
//!   lane's index in a record is not stable across a clip: [`SynthOutput::gt_lane_ids`] gives each
//!   record lane's true lane (the label's lane index; the merge/split lane is
//!   `label.lanes.len()`), the same true lane in every frame of the clip.

use std::f64::consts::PI;

use anyhow::{ensure, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson};
use serde::Serialize;

use crate::camera::Camera;
use crate::tusimple::{Frame, TuSimpleRecord, NO_POINT};

/// Farthest distance (m) to which a lane is extrapolated.
const U_CAP: f64 = 200.0;
/// Number of BEV points used for linear extrapolation at either end.
const EXTRAP_POINTS: usize = 4;
/// A lane shorter than this (m) is absent.
const MIN_LANE_LEN: f64 = 5.0;
/// Two lanes closer than this (px) share their feature points.
const SHARE_PX: f64 = 2.0;
/// Range ahead (m) that a distractor segment lies in (the tracker's default BEV window).
pub const DISTRACTOR_U: (f64, f64) = (3.0, 80.0);
/// Largest lateral distance (m) of a distractor segment's centre.
pub const DISTRACTOR_X: f64 = 8.0;
/// Range (uniform) of a distractor segment's length, m.
pub const DISTRACTOR_LEN: (f64, f64) = (3.0, 10.0);
/// Mixed into the clip seed for the distractor generator.
const DISTRACTOR_STREAM: u64 = 0xD157_AC70_5EED_0001;

/// The noise presets of the replay benchmark (see the module doc's table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum NoiseLevel {
    /// σ 2 px, P_D 0.9, 5 clutter points per frame, few structured distractors.
    Low,
    /// σ 5 px, P_D 0.75, 25 clutter points per frame (the default).
    Mid,
    /// σ 10 px, P_D 0.55, 60 clutter points per frame, many structured distractors.
    High,
}

/// Every parameter of the generator (units: pixels of the camera's image, metres, seconds).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SynthParams {
    /// Frames per clip (the last one is the labelled frame).
    pub frames_per_clip: usize,
    /// Time between frames, s.
    pub frame_step: f64,
    /// Feature rows are the image rows that are multiples of this, px.
    pub row_step: usize,
    /// Standard deviation of the column noise of every feature point, px.
    pub pixel_noise: f64,
    /// Probability that a lane (or shadow / car edge) point is detected.
    pub detect_prob: f64,
    /// Mean number of uniform clutter points per frame.
    pub clutter_rate: f64,
    /// Probability that a lane is a dashed marking.
    pub dashed_prob: f64,
    /// Length of a dash's paint, m.
    pub dash_paint: f64,
    /// Length of the gap between dashes, m.
    pub dash_gap: f64,
    /// Vehicle speed range (uniform), m/s.
    pub speed: (f64, f64),
    /// Scale of drift, heading and curvature change (0 = a static road).
    pub motion: f64,
    /// Maximum lateral drift speed, m/s.
    pub lateral_speed: f64,
    /// Maximum amplitude of the lateral wobble, m.
    pub wobble: f64,
    /// Maximum heading rate, rad/s.
    pub yaw_rate: f64,
    /// Maximum rate of curvature change, 1/(m·s).
    pub curvature_rate: f64,
    /// Probability of a lane change in a clip.
    pub lane_change_prob: f64,
    /// Lane width used by lane changes and merges, m.
    pub lane_width: f64,
    /// Duration of a lane change, s.
    pub lane_change_duration: f64,
    /// Probability that one lane's far end appears/disappears during the clip.
    pub far_end_prob: f64,
    /// Range (uniform) of the far end's speed, m/s.
    pub far_end_rate: (f64, f64),
    /// Probability of a merge/split lane in a clip.
    pub merge_prob: f64,
    /// Length over which a merge/split lane coincides with its parent before the branch point, m.
    pub merge_shared: f64,
    /// Mean number of shadow edges per clip.
    pub shadows: f64,
    /// Mean number of cars per clip.
    pub cars: f64,
    /// Probability of a road edge in a clip.
    pub road_edge_prob: f64,
    /// Per-row detection probability of a road edge.
    pub road_edge_detect: f64,
    /// Mean number of short straight distractor segments per frame (0 in every preset).
    pub distractors: f64,
}

impl SynthParams {
    /// The parameters of a noise preset (the other parameters take their defaults).
    pub fn preset(level: NoiseLevel) -> Self {
        let (pixel_noise, detect_prob, clutter_rate, shadows, cars, road_edge_prob) = match level {
            NoiseLevel::Low => (2.0, 0.9, 5.0, 0.5, 0.5, 0.2),
            NoiseLevel::Mid => (5.0, 0.75, 25.0, 1.5, 1.0, 0.5),
            NoiseLevel::High => (10.0, 0.55, 60.0, 3.0, 2.0, 0.8),
        };
        Self {
            frames_per_clip: 20,
            frame_step: 0.05,
            row_step: 2,
            pixel_noise,
            detect_prob,
            clutter_rate,
            dashed_prob: 0.5,
            dash_paint: 3.0,
            dash_gap: 9.0,
            speed: (20.0, 30.0),
            motion: 1.0,
            lateral_speed: 0.5,
            wobble: 0.3,
            yaw_rate: 0.02,
            curvature_rate: 2e-4,
            lane_change_prob: 0.2,
            lane_width: 3.7,
            lane_change_duration: 1.0,
            far_end_prob: 0.3,
            far_end_rate: (20.0, 60.0),
            merge_prob: 0.15,
            merge_shared: 15.0,
            shadows,
            cars,
            road_edge_prob,
            road_edge_detect: 0.6,
            distractors: 0.0,
        }
    }

    /// Switches the named sources of false points off, a comma-separated list of `cars`,
    /// `road_edge`, `shadows`, `clutter` and `merges` (the diagnostics' `*_DIAG_OFF` variables:
    /// which source makes the false lanes or the extra ids). The synth's random stream changes
    /// with its sources, so the clips differ from those with every source on. An unknown name is
    /// an error naming the known ones.
    pub fn switch_off(&mut self, sources: &str) -> Result<()> {
        for what in sources.split(',').map(str::trim).filter(|w| !w.is_empty()) {
            match what {
                "cars" => self.cars = 0.0,
                "road_edge" => self.road_edge_prob = 0.0,
                "shadows" => self.shadows = 0.0,
                "clutter" => self.clutter_rate = 0.0,
                "merges" => self.merge_prob = 0.0,
                _ => anyhow::bail!("unknown source {what} (cars|road_edge|shadows|clutter|merges)"),
            }
        }
        Ok(())
    }

    /// The most frames a clip, and the largest mean count of each source of false points
    /// (clutter points and distractor segments a frame, shadows and cars a clip): bounds far
    /// above any preset that keep a clip's points in memory (a mean of 10¹² clutter points
    /// exhausts it, one of 10¹² distractors runs for hours).
    pub const MAX_FRAMES_PER_CLIP: usize = 100_000;
    /// See [`Self::MAX_FRAMES_PER_CLIP`].
    pub const MAX_RATE: f64 = 10_000.0;

    /// Check ranges (probabilities in [0, 1], positive steps, non-negative rates, the clip
    /// length and the false-point rates at most [`Self::MAX_FRAMES_PER_CLIP`] and
    /// [`Self::MAX_RATE`]).
    pub fn validate(&self) -> Result<()> {
        ensure!(
            (1..=Self::MAX_FRAMES_PER_CLIP).contains(&self.frames_per_clip),
            "frames_per_clip = {} must be in 1..={}",
            self.frames_per_clip,
            Self::MAX_FRAMES_PER_CLIP
        );
        ensure!(self.row_step >= 1, "row_step must be ≥ 1");
        ensure!(
            self.frame_step > 0.0 && self.frame_step.is_finite(),
            "frame_step must be > 0"
        );
        for (name, p) in [
            ("detect_prob", self.detect_prob),
            ("dashed_prob", self.dashed_prob),
            ("lane_change_prob", self.lane_change_prob),
            ("far_end_prob", self.far_end_prob),
            ("merge_prob", self.merge_prob),
            ("road_edge_prob", self.road_edge_prob),
            ("road_edge_detect", self.road_edge_detect),
        ] {
            ensure!((0.0..=1.0).contains(&p), "{name} = {p:?} is not in [0, 1]");
        }
        for (name, v) in [
            ("pixel_noise", self.pixel_noise),
            ("clutter_rate", self.clutter_rate),
            ("shadows", self.shadows),
            ("cars", self.cars),
            ("motion", self.motion),
            ("lateral_speed", self.lateral_speed),
            ("wobble", self.wobble),
            ("yaw_rate", self.yaw_rate),
            ("curvature_rate", self.curvature_rate),
            ("lane_width", self.lane_width),
            ("merge_shared", self.merge_shared),
            ("distractors", self.distractors),
        ] {
            ensure!(
                v >= 0.0 && v.is_finite(),
                "{name} = {v:?} must be finite and ≥ 0"
            );
        }
        for (name, v) in [
            ("clutter_rate", self.clutter_rate),
            ("distractors", self.distractors),
            ("shadows", self.shadows),
            ("cars", self.cars),
        ] {
            ensure!(
                v <= Self::MAX_RATE,
                "{name} = {v:?} is above {} (a mean count of false points or structures)",
                Self::MAX_RATE
            );
        }
        ensure!(
            self.dash_paint > 0.0 && self.dash_gap >= 0.0,
            "dash_paint must be > 0 and dash_gap ≥ 0"
        );
        ensure!(
            self.lane_change_duration > 0.0,
            "lane_change_duration must be > 0"
        );
        for (name, (a, b)) in [("speed", self.speed), ("far_end_rate", self.far_end_rate)] {
            ensure!(
                a >= 0.0 && b >= a && b.is_finite(),
                "{name} range ({a}, {b}) is not a range of non-negative values"
            );
        }
        Ok(())
    }
}

impl Default for SynthParams {
    fn default() -> Self {
        Self::preset(NoiseLevel::Mid)
    }
}

/// Counts of what the generator did (summed over all clips and frames).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct SynthStats {
    /// Clips generated.
    pub clips: usize,
    /// Frames generated.
    pub frames: usize,
    /// Lane rows considered (a lane inside the image at a feature row).
    pub lane_rows: usize,
    /// Lane rows of a merge/split lane within 2 px of its parent (emitted once, by the parent).
    pub shared: usize,
    /// Lane rows in the gap of a dashed marking.
    pub dash_gaps: usize,
    /// Lane rows hidden by a car.
    pub occluded: usize,
    /// Visible lane rows not detected (per-row misses).
    pub missed: usize,
    /// Detected lane rows whose noisy point fell outside the image.
    pub off_image: usize,
    /// Lane feature points emitted.
    pub lane_points: usize,
    /// Uniform clutter points emitted.
    pub clutter_points: usize,
    /// Shadow-edge points emitted.
    pub shadow_points: usize,
    /// Car-edge points emitted.
    pub car_points: usize,
    /// Road-edge points emitted.
    pub road_edge_points: usize,
    /// Distractor segments drawn.
    pub distractors: usize,
    /// Distractor-segment points emitted.
    pub distractor_points: usize,
    /// Clips with a lane change.
    pub lane_changes: usize,
    /// Clips with a merge/split lane.
    pub merges: usize,
    /// Clips with a lane whose far end appears or disappears.
    pub far_end_changes: usize,
}

impl SynthStats {
    /// All feature points emitted.
    pub fn total_points(&self) -> usize {
        self.lane_points
            + self.clutter_points
            + self.shadow_points
            + self.car_points
            + self.road_edge_points
            + self.distractor_points
    }

    fn add(&mut self, o: &SynthStats) {
        self.clips += o.clips;
        self.frames += o.frames;
        self.lane_rows += o.lane_rows;
        self.shared += o.shared;
        self.dash_gaps += o.dash_gaps;
        self.occluded += o.occluded;
        self.missed += o.missed;
        self.off_image += o.off_image;
        self.lane_points += o.lane_points;
        self.clutter_points += o.clutter_points;
        self.shadow_points += o.shadow_points;
        self.car_points += o.car_points;
        self.road_edge_points += o.road_edge_points;
        self.distractors += o.distractors;
        self.distractor_points += o.distractor_points;
        self.lane_changes += o.lane_changes;
        self.merges += o.merges;
        self.far_end_changes += o.far_end_changes;
    }
}

/// The generator's output.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SynthOutput {
    /// Feature-point frames of all clips, clip after clip.
    pub frames: Vec<Frame>,
    /// Ground truth of the last frame of each clip (TuSimple records).
    pub gt_last: Vec<TuSimpleRecord>,
    /// Ground truth of every frame (TuSimple records, `raw_file` as on the frames).
    pub gt_all: Vec<TuSimpleRecord>,
    /// For each record of `gt_all`, the true lane of each of its lanes (see [`Clip::gt_lane_ids`]).
    pub gt_lane_ids: Vec<Vec<usize>>,
    /// What the generator did, per clip (in clip order; `stats` is their sum).
    pub clip_stats: Vec<SynthStats>,
    /// What the generator did.
    pub stats: SynthStats,
}

impl SynthOutput {
    /// Each `gt_all` record's index by its `raw_file` (the frames' and predictions' key).
    pub fn gt_index(&self) -> std::collections::HashMap<&str, usize> {
        self.gt_all
            .iter()
            .enumerate()
            .map(|(j, g)| (g.raw_file.as_str(), j))
            .collect()
    }
}

/// Generate one clip per label (labels in order), clip `i` seeded by (`seed`, `i`).
/// Errors: bad parameters, a label whose shape is wrong ([`TuSimpleRecord::check_shape`]) or
/// repeated `raw_file`s (the scorer joins on them).
pub fn synthesize(
    labels: &[TuSimpleRecord],
    params: &SynthParams,
    camera: &Camera,
    seed: u64,
) -> Result<SynthOutput> {
    synthesize_with_progress(labels, params, camera, seed, || {})
}

/// [`synthesize`], calling `progress` after each clip.
pub fn synthesize_with_progress(
    labels: &[TuSimpleRecord],
    params: &SynthParams,
    camera: &Camera,
    seed: u64,
    mut progress: impl FnMut(),
) -> Result<SynthOutput> {
    params.validate()?;
    let mut seen = std::collections::HashSet::new();
    for l in labels {
        l.check_shape()?;
        ensure!(
            seen.insert(l.raw_file.as_str()),
            "label raw_file {} appears twice",
            l.raw_file
        );
    }
    let mut out = SynthOutput::default();
    for (i, label) in labels.iter().enumerate() {
        let clip = synth_clip(label, i, params, camera, seed);
        out.frames.extend(clip.frames);
        out.gt_all.extend(clip.gt_all);
        out.gt_lane_ids.extend(clip.gt_lane_ids);
        out.gt_last.push(clip.gt_last);
        out.stats.add(&clip.stats);
        out.clip_stats.push(clip.stats);
        progress();
    }
    Ok(out)
}

/// One generated clip.
#[derive(Debug, Clone, PartialEq)]
pub struct Clip {
    /// Its frames, in time order.
    pub frames: Vec<Frame>,
    /// Ground truth of each frame.
    pub gt_all: Vec<TuSimpleRecord>,
    /// For each frame, the true lane of each lane of its `gt_all` record: the index of the
    /// label's lane it animates, or `label.lanes.len()` for the merge/split lane. Stable across
    /// the clip's frames (a record's own lane indices are not: lanes with no point in a frame
    /// are left out of it).
    pub gt_lane_ids: Vec<Vec<usize>>,
    /// Ground truth of the last frame.
    pub gt_last: TuSimpleRecord,
    /// What the generator did in this clip.
    pub stats: SynthStats,
}

/// A labelled lane in BEV: its label columns and its points (u, x) by increasing u.
#[derive(Debug, Clone)]
struct SrcLane {
    cols: Vec<f64>,
    pts: Vec<(f64, f64)>,
}

impl SrcLane {
    fn lo(&self) -> f64 {
        self.pts[0].0
    }
    fn hi(&self) -> f64 {
        self.pts[self.pts.len() - 1].0
    }

    /// x at `u` inside the labelled range (linear interpolation).
    fn interp(&self, u: f64) -> f64 {
        let i = self.pts.partition_point(|p| p.0 < u);
        if i == 0 {
            return self.pts[0].1;
        }
        if i >= self.pts.len() {
            return self.pts[self.pts.len() - 1].1;
        }
        let ((ua, xa), (ub, xb)) = (self.pts[i - 1], self.pts[i]);
        if ub > ua {
            xa + (xb - xa) * (u - ua) / (ub - ua)
        } else {
            xa
        }
    }

    /// x at any `u`: interpolation inside, least-squares line of the end points outside.
    fn x_at(&self, u: f64) -> f64 {
        let n = self.pts.len();
        let k = EXTRAP_POINTS.min(n);
        let seg = if u < self.lo() {
            &self.pts[..k]
        } else if u > self.hi() {
            &self.pts[n - k..]
        } else {
            return self.interp(u);
        };
        let (a, b) = line_fit(seg);
        a + b * u
    }
}

/// Least-squares line x = a + b·u through `pts` (b = 0 for a single point or equal u's).
fn line_fit(pts: &[(f64, f64)]) -> (f64, f64) {
    let n = pts.len() as f64;
    let mu = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let mx = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let suu: f64 = pts.iter().map(|p| (p.0 - mu).powi(2)).sum();
    let sux: f64 = pts.iter().map(|p| (p.0 - mu) * (p.1 - mx)).sum();
    let b = if suu > 0.0 { sux / suu } else { 0.0 };
    (mx - b * mu, b)
}

fn smoothstep(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// A merge/split lane's branch.
#[derive(Debug, Clone, Copy)]
struct Merge {
    /// Branch point at the last frame, m.
    u_s: f64,
    /// Outward lateral offset reached after the branch, m (signed).
    offset: f64,
    /// Length of the shared stretch before the branch point, m.
    shared: f64,
}

/// How a generated curve relates to its source lane.
#[derive(Debug, Clone, Copy)]
enum Kind {
    /// The source lane itself.
    Lane,
    /// A merge/split lane branching off the source lane.
    Branch(Merge),
    /// A road edge parallel to the source lane at this lateral offset (m).
    Edge(f64),
}

#[derive(Debug, Clone, Copy)]
struct Curve {
    src: usize,
    kind: Kind,
    /// Dash phase (m) if dashed.
    dash: Option<f64>,
}

#[derive(Debug, Clone, Copy)]
struct Car {
    u0: f64,
    x: f64,
    rel_speed: f64,
    first: usize,
    last: usize,
}

#[derive(Debug, Clone, Copy)]
struct Shadow {
    u0: f64,
    x0: f64,
    len: f64,
    tilt: f64,
}

/// The scenario of one clip (everything random, drawn once).
#[derive(Debug, Clone)]
struct Scenario {
    speed: f64,
    v_lat: f64,
    wobble: f64,
    omega: f64,
    phi: f64,
    yaw_rate: f64,
    curv_rate: f64,
    lane_change: Option<(f64, f64)>,
    far_end: Option<(usize, f64)>,
    curves: Vec<Curve>,
    cars: Vec<Car>,
    shadows: Vec<Shadow>,
}

impl Scenario {
    /// Lateral offset δ(u, τ) (m) of every lane at `tau` seconds before the last frame.
    fn delta(&self, p: &SynthParams, u: f64, tau: f64) -> f64 {
        let drift = self.v_lat * tau
            + self.wobble * ((self.omega * tau + self.phi).sin() - self.phi.sin())
            + self.yaw_rate * tau * u
            + self.curv_rate * tau * u * u / 2.0;
        let change = match self.lane_change {
            Some((shift, tau_a)) => shift * smoothstep((tau - tau_a) / p.lane_change_duration),
            None => 0.0,
        };
        p.motion * drift + change
    }
}

fn poisson(rng: &mut ChaCha8Rng, mean: f64) -> usize {
    if mean <= 0.0 {
        return 0;
    }
    Poisson::new(mean)
        .map(|d| d.sample(rng) as usize)
        .unwrap_or(0)
}

fn sym(rng: &mut ChaCha8Rng, a: f64) -> f64 {
    if a > 0.0 {
        rng.random_range(-a..=a)
    } else {
        0.0
    }
}

fn uniform(rng: &mut ChaCha8Rng, (a, b): (f64, f64)) -> f64 {
    if b > a {
        rng.random_range(a..=b)
    } else {
        a
    }
}

/// +1 or −1 with equal odds.
fn random_sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.random_bool(0.5) {
        1.0
    } else {
        -1.0
    }
}

/// The outermost lane of `order` (sorted left to right) on the left (`left`) or right side, and
/// the side's sign (−1 left, +1 right). `order` must not be empty.
fn outermost(order: &[usize], left: bool) -> (usize, f64) {
    if left {
        (order[0], -1.0)
    } else {
        (order[order.len() - 1], 1.0)
    }
}

/// The generator of one clip.
struct ClipGen<'a> {
    p: &'a SynthParams,
    cam: &'a Camera,
    label: &'a TuSimpleRecord,
    lanes: Vec<SrcLane>,
    sc: Scenario,
}

impl<'a> ClipGen<'a> {
    fn u_of_row(&self, row: f64) -> Option<f64> {
        // Exactly as `Camera::to_bev` computes u (the labelled extent comes from it).
        self.cam.to_bev(self.cam.vp_col, row).map(|(u, _)| u)
    }

    fn col_of(&self, u: f64, x: f64) -> f64 {
        self.cam.vp_col + self.cam.focal_px * x / u
    }

    fn in_image(&self, col: f64) -> bool {
        col >= 0.0 && col < self.cam.width
    }

    /// Far end (m) of source lane `i` at `tau`.
    fn far_end(&self, i: usize, tau: f64) -> f64 {
        let hi = self.lanes[i].hi();
        match self.sc.far_end {
            Some((j, r)) if j == i => (hi + r * tau).min(U_CAP.max(hi)),
            _ => hi,
        }
    }

    /// Extra lateral offset (m) of a curve at `u`, `tau`, and whether the curve exists there.
    fn extra(&self, kind: Kind, u: f64, tau: f64) -> Option<f64> {
        match kind {
            Kind::Lane => Some(0.0),
            Kind::Edge(o) => Some(o),
            Kind::Branch(m) => {
                let u_s = m.u_s + self.sc.speed * tau;
                (u >= u_s - m.shared).then(|| m.offset * smoothstep((u - u_s) / 30.0))
            }
        }
    }

    /// Column of curve `c` at image row `row`, `tau` seconds before the last frame (`None` where
    /// the curve is absent or outside the image). `label_col`: the label's column at this row if
    /// the row is a label row (used verbatim, shifted, so that τ = 0 reproduces the label).
    fn col_at(&self, c: &Curve, row: f64, tau: f64, label_col: Option<f64>) -> Option<f64> {
        if row < 0.0 || row >= self.cam.height {
            return None;
        }
        let Some(u) = self.u_of_row(row) else {
            // Above the horizon (u = ∞): only a labelled point, unshifted.
            return label_col.filter(|&v| v >= 0.0);
        };
        let lane = &self.lanes[c.src];
        let far = self.far_end(c.src, tau);
        if u > far * (1.0 + 1e-12) || (far < lane.hi() && far - lane.lo() < MIN_LANE_LEN) {
            return None;
        }
        let extra = self.extra(c.kind, u, tau)?;
        let shift = self.cam.focal_px * (self.sc.delta(self.p, u, tau) + extra) / u;
        let col = match label_col {
            Some(col) if col >= 0.0 => col + shift,
            _ => {
                let x = lane.x_at(u);
                if u < lane.lo() {
                    // Near extension only where the label stopped because the lane left the image.
                    if self.in_image(self.col_of(u, x)) {
                        return None;
                    }
                } else if u <= lane.hi() && label_col.is_some() {
                    // An unlabelled row inside the labelled range stays unlabelled.
                    return None;
                }
                self.col_of(u, x) + shift
            }
        };
        self.in_image(col).then_some(col)
    }

    /// Ground truth of frame `k`: the source lanes in the label's order, then the merge/split
    /// lane. A lane with no point in this frame is left out, unless the label itself has it
    /// empty (then it is kept as in the label, all −2). With it, each lane's true lane (see
    /// [`Clip::gt_lane_ids`]).
    fn ground_truth(&self, k: usize, raw_file: &str) -> (TuSimpleRecord, Vec<usize>) {
        let tau = self.tau(k);
        let mut lanes = Vec::new();
        let mut ids = Vec::new();
        let sample = |c: &Curve| -> Vec<f64> {
            self.label
                .h_samples
                .iter()
                .enumerate()
                .map(|(j, &row)| {
                    let lc = self.lanes[c.src].cols[j];
                    self.col_at(c, row, tau, Some(lc)).unwrap_or(NO_POINT)
                })
                .collect()
        };
        for (i, lane) in self.lanes.iter().enumerate() {
            if lane.pts.is_empty() {
                lanes.push(lane.cols.clone());
                ids.push(i);
                continue;
            }
            let c = Curve {
                src: i,
                kind: Kind::Lane,
                dash: None,
            };
            let xs = sample(&c);
            if xs.iter().any(|&v| v >= 0.0) {
                lanes.push(xs);
                ids.push(i);
            }
        }
        for c in self
            .sc
            .curves
            .iter()
            .filter(|c| matches!(c.kind, Kind::Branch(_)))
        {
            let xs = sample(c);
            if xs.iter().any(|&v| v >= 0.0) {
                lanes.push(xs);
                ids.push(self.lanes.len());
            }
        }
        let record = TuSimpleRecord {
            raw_file: raw_file.to_string(),
            lanes,
            h_samples: self.label.h_samples.clone(),
            run_time: None,
        };
        (record, ids)
    }

    fn tau(&self, k: usize) -> f64 {
        (self.p.frames_per_clip - 1 - k) as f64 * self.p.frame_step
    }

    /// The image boxes (col_left, col_right, row_top, row_bottom) of the cars visible in frame k.
    fn car_boxes(&self, k: usize) -> Vec<(f64, f64, f64, f64)> {
        let tau = self.tau(k);
        let mut boxes = Vec::new();
        for car in self
            .sc
            .cars
            .iter()
            .filter(|c| (c.first..=c.last).contains(&k))
        {
            let u = car.u0 - car.rel_speed * tau;
            if u <= 1.0 {
                continue;
            }
            let x = car.x + self.sc.delta(self.p, u, tau);
            let left = self.col_of(u, x - 0.9);
            let right = self.col_of(u, x + 0.9);
            let bottom = self.cam.vp_row + self.cam.focal_px * self.cam.height_m / u;
            let top = bottom - self.cam.focal_px * 1.5 / u;
            boxes.push((left, right, top, bottom));
        }
        boxes
    }

    /// Render frame `k`'s feature points; `drng` draws the distractor segments (its own
    /// stream, untouched when [`SynthParams::distractors`] is 0).
    fn render(
        &self,
        k: usize,
        rng: &mut ChaCha8Rng,
        drng: &mut ChaCha8Rng,
        st: &mut SynthStats,
    ) -> Vec<[f64; 2]> {
        let p = self.p;
        let tau = self.tau(k);
        let t = k as f64 * p.frame_step;
        let noise = Normal::new(0.0, p.pixel_noise.max(0.0)).expect("σ ≥ 0");
        let boxes = self.car_boxes(k);
        let occluded = |col: f64, row: f64| {
            boxes
                .iter()
                .any(|&(l, r, tp, b)| col >= l && col <= r && row >= tp && row <= b)
        };
        let mut pts: Vec<[f64; 2]> = Vec::new();
        let step = p.row_step;
        let first_row = (self.cam.vp_row.floor() as usize / step + 1) * step;
        let period = p.dash_paint + p.dash_gap;
        for c in &self.sc.curves {
            let is_edge = matches!(c.kind, Kind::Edge(_));
            let pd = if is_edge {
                p.road_edge_detect
            } else {
                p.detect_prob
            };
            let parent = Curve {
                kind: Kind::Lane,
                ..*c
            };
            for row in (first_row..self.cam.height.ceil() as usize).step_by(step) {
                let row = row as f64;
                let Some(col) = self.col_at(c, row, tau, None) else {
                    continue;
                };
                if !is_edge {
                    st.lane_rows += 1;
                }
                if let Kind::Branch(_) = c.kind {
                    if let Some(pc) = self.col_at(&parent, row, tau, None) {
                        if (pc - col).abs() < SHARE_PX {
                            st.shared += 1;
                            continue;
                        }
                    }
                }
                let u = self.u_of_row(row).expect("below the horizon");
                if let Some(phase) = c.dash {
                    if (u + self.sc.speed * t + phase).rem_euclid(period) >= p.dash_paint {
                        st.dash_gaps += 1;
                        continue;
                    }
                }
                if occluded(col, row) {
                    if !is_edge {
                        st.occluded += 1;
                    }
                    continue;
                }
                if !rng.random_bool(pd) {
                    if !is_edge {
                        st.missed += 1;
                    }
                    continue;
                }
                let cn = col + noise.sample(rng);
                if !self.in_image(cn) {
                    if !is_edge {
                        st.off_image += 1;
                    }
                    continue;
                }
                pts.push([cn, row]);
                if is_edge {
                    st.road_edge_points += 1;
                } else {
                    st.lane_points += 1;
                }
            }
        }
        // Shadow edges: horizontal-ish segments fixed on the road.
        for s in &self.sc.shadows {
            let u0 = s.u0 + self.sc.speed * tau;
            let (ua, xa) = (u0, s.x0 + self.sc.delta(p, u0, tau));
            let u1 = u0 + s.tilt * s.len;
            let (ub, xb) = (u1, s.x0 + s.len + self.sc.delta(p, u1, tau));
            let (Some((ca, ra)), Some((cb, rb))) =
                (self.cam.to_image(ua, xa), self.cam.to_image(ub, xb))
            else {
                continue;
            };
            let n = (((cb - ca).abs() / 8.0).ceil() as usize).max(2);
            for i in 0..=n {
                let f = i as f64 / n as f64;
                let (col, row) = (ca + f * (cb - ca), ra + f * (rb - ra));
                if row >= self.cam.height || !self.in_image(col) || occluded(col, row) {
                    continue;
                }
                if !rng.random_bool(p.detect_prob) {
                    continue;
                }
                let cn = col + noise.sample(rng);
                if self.in_image(cn) {
                    pts.push([cn, row.round()]);
                    st.shadow_points += 1;
                }
            }
        }
        // Car edges: short vertical clusters at the boxes' sides.
        for &(l, r, top, bottom) in &boxes {
            let r0 = ((top.max(0.0) / step as f64).ceil() as usize) * step;
            for row in (r0..=bottom.min(self.cam.height - 1.0) as usize).step_by(step) {
                for col in [l, r] {
                    if !self.in_image(col) || !rng.random_bool(p.detect_prob) {
                        continue;
                    }
                    let cn = col + noise.sample(rng);
                    if self.in_image(cn) {
                        pts.push([cn, row as f64]);
                        st.car_points += 1;
                    }
                }
            }
        }
        // Uniform clutter.
        let top = self
            .label
            .h_samples
            .first()
            .copied()
            .unwrap_or(self.cam.vp_row + 1.0)
            .max(self.cam.vp_row + 1.0)
            .min(self.cam.height - 1.0);
        for _ in 0..poisson(rng, p.clutter_rate) {
            let col = rng.random_range(0.0..self.cam.width);
            let row = rng.random_range(top..self.cam.height).floor();
            pts.push([col, row]);
            st.clutter_points += 1;
        }
        // Short straight distractor segments, independent per frame.
        for _ in 0..poisson(drng, p.distractors) {
            st.distractors += 1;
            let seg = Distractor::draw(drng);
            for row in (first_row..self.cam.height.ceil() as usize).step_by(step) {
                let row = row as f64;
                let Some((u, x)) = self.u_of_row(row).and_then(|u| seg.x_at(u).map(|x| (u, x)))
                else {
                    continue;
                };
                let col = self.col_of(u, x);
                if !self.in_image(col) || occluded(col, row) {
                    continue;
                }
                let cn = col + noise.sample(drng);
                if self.in_image(cn) {
                    pts.push([cn, row]);
                    st.distractor_points += 1;
                }
            }
        }
        pts.sort_by(|a, b| b[1].total_cmp(&a[1]).then(a[0].total_cmp(&b[0])));
        pts
    }
}

/// A short straight distractor segment in BEV, from (u0, x0) to (u1, x1).
#[derive(Debug, Clone, Copy)]
struct Distractor {
    u0: f64,
    x0: f64,
    u1: f64,
    x1: f64,
}

impl Distractor {
    /// A segment of length U([`DISTRACTOR_LEN`]) at a uniform orientation, centred laterally in
    /// ±[`DISTRACTOR_X`] and ahead such that it lies in [`DISTRACTOR_U`].
    fn draw(rng: &mut ChaCha8Rng) -> Self {
        let len = uniform(rng, DISTRACTOR_LEN);
        let theta = rng.random_range(0.0..PI);
        let (du, dx) = (0.5 * len * theta.cos(), 0.5 * len * theta.sin());
        let uc = uniform(rng, (DISTRACTOR_U.0 + du.abs(), DISTRACTOR_U.1 - du.abs()));
        let xc = sym(rng, DISTRACTOR_X);
        let (a, b) = ((uc - du, xc - dx), (uc + du, xc + dx));
        let ((u0, x0), (u1, x1)) = if a.0 <= b.0 { (a, b) } else { (b, a) };
        Self { u0, x0, u1, x1 }
    }

    /// Lateral position where the segment crosses `u` (`None` where it does not; a segment
    /// along a row crosses none).
    fn x_at(&self, u: f64) -> Option<f64> {
        (self.u1 - self.u0 > 1e-9 && u >= self.u0 && u <= self.u1)
            .then(|| self.x0 + (self.x1 - self.x0) * (u - self.u0) / (self.u1 - self.u0))
    }
}

/// The clip id (`Frame::clip`) of clip `index`.
pub fn clip_name(index: usize) -> String {
    format!("synth{index:04}")
}

/// The generator seed of clip `index` under `seed`.
fn clip_seed(seed: u64, index: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((index as u64).wrapping_mul(0xD1B5_4A32_D192_ED03))
        .rotate_left(17)
}

/// Generate the clip of `label` (clip index `index`; its generator is seeded from `seed` and
/// `index` only). Lanes of the label with no point produce no feature points and stay empty in
/// the ground truth.
pub fn synth_clip(
    label: &TuSimpleRecord,
    index: usize,
    params: &SynthParams,
    camera: &Camera,
    seed: u64,
) -> Clip {
    let p = params;
    let mut rng = ChaCha8Rng::seed_from_u64(clip_seed(seed, index));
    let mut drng = ChaCha8Rng::seed_from_u64(clip_seed(seed, index) ^ DISTRACTOR_STREAM);
    let lanes: Vec<SrcLane> = label
        .lanes
        .iter()
        .map(|cols| {
            let mut pts: Vec<(f64, f64)> = label
                .points_of(cols)
                .filter_map(|(c, r)| camera.to_bev(c, r))
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            SrcLane {
                cols: cols.clone(),
                pts,
            }
        })
        .collect();
    // The non-empty lanes, ordered from the left (x near the car).
    let mut order: Vec<usize> = (0..lanes.len())
        .filter(|&i| !lanes[i].pts.is_empty())
        .collect();
    let key = |l: &SrcLane| l.x_at(20.0_f64.clamp(l.lo(), l.hi()));
    order.sort_by(|&a, &b| key(&lanes[a]).total_cmp(&key(&lanes[b])));

    let two_pi = 2.0 * PI;
    let speed = uniform(&mut rng, p.speed);
    let v_lat = sym(&mut rng, p.lateral_speed);
    let wobble = uniform(&mut rng, (0.0, p.wobble));
    let omega = two_pi / rng.random_range(1.5..3.0);
    let phi = rng.random_range(0.0..two_pi);
    let yaw_rate = sym(&mut rng, p.yaw_rate);
    let curv_rate = sym(&mut rng, p.curvature_rate);
    let lane_change = rng.random_bool(p.lane_change_prob).then(|| {
        let sign = random_sign(&mut rng);
        (sign * p.lane_width, rng.random_range(0.0..0.15))
    });
    let far_end = (rng.random_bool(p.far_end_prob) && !order.is_empty()).then(|| {
        let i = order[rng.random_range(0..order.len())];
        let sign = random_sign(&mut rng);
        (i, sign * uniform(&mut rng, p.far_end_rate))
    });
    let mut curves: Vec<Curve> = Vec::new();
    for &i in &order {
        let dashed = rng.random_bool(p.dashed_prob);
        let phase = rng.random_range(0.0..(p.dash_paint + p.dash_gap));
        curves.push(Curve {
            src: i,
            kind: Kind::Lane,
            dash: dashed.then_some(phase),
        });
    }
    let merge = rng.random_bool(p.merge_prob) && !order.is_empty();
    let merge_left = rng.random_bool(0.5);
    let merge_u = rng.random_range(15.0..40.0);
    let merge_dashed = rng.random_bool(p.dashed_prob);
    let merge_phase = rng.random_range(0.0..(p.dash_paint + p.dash_gap));
    if merge {
        let (src, sign) = outermost(&order, merge_left);
        curves.push(Curve {
            src,
            kind: Kind::Branch(Merge {
                u_s: merge_u,
                offset: sign * 0.9 * p.lane_width,
                shared: p.merge_shared,
            }),
            dash: merge_dashed.then_some(merge_phase),
        });
    }
    let road_edge = rng.random_bool(p.road_edge_prob) && !order.is_empty();
    let edge_left = rng.random_bool(0.5);
    let edge_off = rng.random_range(0.5..1.5);
    if road_edge {
        let (src, sign) = outermost(&order, edge_left);
        curves.push(Curve {
            src,
            kind: Kind::Edge(sign * edge_off),
            dash: None,
        });
    }
    let n = p.frames_per_clip;
    let mut cars = Vec::new();
    for _ in 0..poisson(&mut rng, p.cars) {
        let u0: f64 = rng.random_range(8.0..40.0);
        // Between two adjacent lanes that both reach u0, else anywhere within ±6 m.
        let pairs: Vec<(usize, usize)> = order
            .windows(2)
            .map(|w| (w[0], w[1]))
            .filter(|&(a, b)| {
                (lanes[a].lo()..=lanes[a].hi()).contains(&u0)
                    && (lanes[b].lo()..=lanes[b].hi()).contains(&u0)
            })
            .collect();
        let x = if pairs.is_empty() {
            rng.random_range(-6.0..6.0)
        } else {
            let (a, b) = pairs[rng.random_range(0..pairs.len())];
            (lanes[a].interp(u0) + lanes[b].interp(u0)) / 2.0
        };
        let rel_speed = rng.random_range(-3.0..3.0);
        let len = rng.random_range(6.min(n)..=n);
        let first = rng.random_range(0..=n - len);
        cars.push(Car {
            u0,
            x,
            rel_speed,
            first,
            last: first + len - 1,
        });
    }
    let mut shadows = Vec::new();
    for _ in 0..poisson(&mut rng, p.shadows) {
        shadows.push(Shadow {
            u0: rng.random_range(5.0..50.0),
            x0: rng.random_range(-10.0..6.0),
            len: rng.random_range(2.0..8.0),
            tilt: rng.random_range(-0.3..0.3),
        });
    }
    let g = ClipGen {
        p,
        cam: camera,
        label,
        lanes,
        sc: Scenario {
            speed,
            v_lat,
            wobble,
            omega,
            phi,
            yaw_rate,
            curv_rate,
            lane_change,
            far_end,
            curves,
            cars,
            shadows,
        },
    };
    let mut stats = SynthStats {
        clips: 1,
        frames: n,
        lane_changes: usize::from(g.sc.lane_change.is_some()),
        merges: usize::from(merge),
        far_end_changes: usize::from(g.sc.far_end.is_some()),
        ..SynthStats::default()
    };
    let clip_id = clip_name(index);
    let mut frames = Vec::with_capacity(n);
    let mut gt_all = Vec::with_capacity(n);
    let mut gt_lane_ids = Vec::with_capacity(n);
    for k in 0..n {
        let raw_file = if k + 1 == n {
            label.raw_file.clone()
        } else {
            format!("synth/{clip_id}/{}.jpg", k + 1)
        };
        let points = g.render(k, &mut rng, &mut drng, &mut stats);
        let (gt, ids) = g.ground_truth(k, &raw_file);
        gt_all.push(gt);
        gt_lane_ids.push(ids);
        frames.push(Frame {
            clip: clip_id.clone(),
            t: k as f64 * p.frame_step,
            points,
            raw_file: Some(raw_file),
            h_samples: Some(label.h_samples.clone()),
            camera: None,
        });
    }
    let gt_last = gt_all.last().cloned().expect("frames_per_clip ≥ 1");
    Clip {
        frames,
        gt_all,
        gt_lane_ids,
        gt_last,
        stats,
    }
}
