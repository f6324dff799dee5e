//! Long-run soak of the core tracker, side by side with the dense f64 reference.
//!
//! A **drive** is a continuous, seeded stream of BEV frames at 30 fps from a synthetic road
//! ([`Road`]): lane lines every 3.4–3.8 m that wander laterally (in-lane weave, lane changes of
//! one lane width over 4 s every few minutes, so lines appear on one side and leave on the
//! other), with a smoothly varying heading (±0.01 rad) and curvature (≤ 6e-4 1/m), each a sum of three
//! sinusoids with seeded periods of 15–90 s (smooth, as the Matérn-3/2 model assumes), and conditions
//! that change every 10–60 s: visible half-width (2–5 lanes), detection rate 0.6–0.97, point
//! noise 3–15 cm, dashed or solid lines (3 m dashes, 9 m gaps, moving at 25 m/s), uniform clutter
//! 0–0.05 points per metre per row; camera blackouts of 1–15 frames (about one a minute) and
//! dropped frames (steps of 2–5×, about one every 20 s); frame-time jitter ±2 ms.
//!
//! Two trackers see every frame of a drive:
//! * **A, the soak proper**: one `ReferenceTracker` for the whole drive, never reset. Every
//!   frame: the published-output invariants ([`crate::invariants::check_output`]); every
//!   `health_every`-th frame the temporal covariance's health ([`crate::invariants::cov_health`]:
//!   asymmetry, smallest eigenvalue of the correlation form and of `P` over its largest
//!   diagonal entry). Id churn against the truth: published lanes are matched to true lines
//!   (mean |Δx| over the observed index points < 0.5 m); a line visible without interruption
//!   that changes its matched id counts as an id switch.
//! * **B, the comparison**: a `ReferenceTracker` and the dense f64 `ReferencePipeline` on the
//!   core's own model (rank-r Gram truncation, so only f32 separates them) in **episodes** of
//!   `episode` frames, both fresh at the start of each. Per frame: lane slots, the core ↔
//!   reference id bijection and misses must agree (a discrete disagreement, e.g. a threshold
//!   decided differently in f32 and f64, ends the episode's comparison and is counted); the
//!   filtered means and variances at the 16 index points are compared; the smoothed lanes every
//!   `smooth_every`-th frame (the reference's RTS costs ~14 ms a frame, see the module docs of
//!   `reference::pipeline`).
//!
//! The work is split into `shards` independent drives (seeds `seed + shard`) run on `threads`
//! threads; [`SoakSummary`] merges them. The long run is the `soak` example
//! (`cargo run --release -p stjpdacf-test-support --example soak -- --help`).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Mutex;

use anyhow::{Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson};
use serde::Serialize;
use stjpdacf::tables::{ReferenceTables, DEFAULT, UNCOUPLED};
use stjpdacf::tracker::{Instant, LaneEstimate, ReferenceTracker, TrackerConfig};

use crate::invariants::{self, active_indices, PsdCheck, POINTS};
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_reference::model::ModelTables;
use stjpdacf_reference::pipeline::{PipelineConfig, RefLane, ReferencePipeline};
use stjpdacf_tools::tablegen::{DEFAULT_HYPER, UNCOUPLED_HYPER};

/// Nominal frame step, µs (30 fps).
pub const FRAME_US: i64 = 33_333;
/// Spatial rows between index points (the tables' layout).
const K_ROWS: usize = 4;

/// What to run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SoakConfig {
    /// Frames in total (over all shards).
    pub frames: u64,
    /// Base seed; shard `i` drives with `seed + i`.
    pub seed: u64,
    /// Independent drives.
    pub shards: usize,
    /// Worker threads.
    pub threads: usize,
    /// Compare with the f64 reference (tracker B); off: tracker A only.
    pub reference: bool,
    /// Frames per comparison episode.
    pub episode: u64,
    /// Run the reference in one episode out of this many (1: every frame is compared). The
    /// dense f64 reference costs ~4 ms of CPU a frame against ~1 ms for the core with its
    /// checks; the temporal model forgets in ℓ_t = 30 s (900 frames), so a 3,000-frame episode
    /// reaches the steady state of the f32 error and a sample of episodes measures it.
    pub compare_every: u64,
    /// Compare the smoothed lanes every this many frames (0: never).
    pub smooth_every: u64,
    /// Full eigen-decomposition of tracker A's covariance every this many frames.
    pub health_every: u64,
    /// Track with the uncoupled tables (`tables::UNCOUPLED`, docs/design.md §4.2.6) instead of
    /// the default ones (the reference, when it runs, on the same model).
    pub uncoupled: bool,
}

impl Default for SoakConfig {
    fn default() -> Self {
        Self {
            frames: 10_000,
            seed: 0,
            shards: 2,
            threads: 2,
            reference: true,
            episode: 3_000,
            compare_every: 1,
            smooth_every: 30,
            health_every: 10,
            uncoupled: false,
        }
    }
}

impl SoakConfig {
    /// The core's tables: [`UNCOUPLED`] or [`DEFAULT`].
    pub fn tables(&self) -> &'static ReferenceTables {
        if self.uncoupled {
            &UNCOUPLED
        } else {
            &DEFAULT
        }
    }
}

/// Conditions of one stretch of road.
#[derive(Debug, Clone, Copy)]
struct Conditions {
    half_width: f64,
    pd: f64,
    sigma: f64,
    dashed: bool,
    clutter: f64,
    until: i64,
}

/// Conditions held fixed over a whole drive instead of drawn for each stretch (`None`: drawn as
/// the soak draws them; `Forced::default()` is the soak's drive bit for bit). A forced value
/// replaces the drawn one after the draw, but the points then draw differently from the random
/// stream, so a forced drive is another sample of the same road model, not the soak's drive
/// with other conditions.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Forced {
    /// Uniform clutter, points per metre per BEV row over ±12 m.
    pub clutter: Option<f64>,
    /// Dashed lines (3 m dashes, 9 m gaps: in effect every visible line, see `Road::next_frame`)
    /// or solid.
    pub dashed: Option<bool>,
    /// Lateral point noise, standard deviation in metres (the soak draws 0.03–0.15).
    pub sigma: Option<f64>,
    /// Detection probability of a line's point in a row (the soak draws 0.6–0.97).
    pub pd: Option<f64>,
}

/// The synthetic road of a drive (see the module docs).
#[derive(Debug, Clone)]
pub struct Road {
    rng: ChaCha8Rng,
    /// Time, µs.
    pub now: i64,
    spacing: f64,
    offset: f64,
    heading: f64,
    curvature: f64,
    /// (amplitude, angular frequency, phase) of the heading's and the curvature's sinusoids.
    waves: [[(f64, f64, f64); 3]; 2],
    lane_change: Option<(i64, f64)>,
    next_change: i64,
    weave_phase: f64,
    cond: Conditions,
    blackout_left: u32,
    frames: u64,
    forced: Forced,
}

/// One frame of a drive.
#[derive(Debug, Clone)]
pub struct RoadFrame {
    /// Time, µs.
    pub t_us: i64,
    /// BEV points `(u, x)`.
    pub points: Vec<[f32; 2]>,
    /// True lateral position of each visible line at the index points (`None` outside the
    /// window), one entry per line, left to right, with the line's road index (stable over a
    /// drive: a lane change shifts which indices are visible).
    pub truth: Vec<(i64, Vec<f64>)>,
    /// The frame is empty because of a camera blackout.
    pub blackout: bool,
}

impl RoadFrame {
    /// The road indices of the lines visible in this frame ([`RoadFrame::truth`]'s), none in a
    /// blackout: the `visible` of [`id_switches`].
    pub fn visible_lines(&self) -> Vec<i64> {
        if self.blackout {
            Vec::new()
        } else {
            self.truth.iter().map(|(k, _)| *k).collect()
        }
    }
}

impl Road {
    /// A new drive.
    pub fn new(seed: u64) -> Self {
        Self::with_forced(seed, Forced::default())
    }

    /// A new drive with some conditions held fixed ([`Forced`]); the same drive as
    /// [`Road::new`] otherwise.
    pub fn with_forced(seed: u64, forced: Forced) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let spacing = rng.random_range(3.4..3.8);
        let offset = rng.random_range(-0.5..0.5) * spacing;
        let mut wave = |amp: f64| {
            let period: f64 = rng.random_range(15.0..90.0);
            (
                amp * rng.random_range(0.3..1.0),
                std::f64::consts::TAU / period,
                rng.random_range(0.0..std::f64::consts::TAU),
            )
        };
        let waves = [
            [wave(0.004), wave(0.004), wave(0.002)],
            [wave(2.5e-4), wave(2e-4), wave(1.5e-4)],
        ];
        let mut r = Self {
            rng,
            now: 0,
            spacing,
            offset,
            heading: 0.0,
            curvature: 0.0,
            waves,
            lane_change: None,
            next_change: 0,
            weave_phase: 0.0,
            cond: Conditions {
                half_width: 6.0,
                pd: 0.9,
                sigma: 0.08,
                dashed: false,
                clutter: 0.0,
                until: 0,
            },
            blackout_left: 0,
            frames: 0,
            forced,
        };
        r.next_change = r.rng.random_range(60_000_000..240_000_000);
        r.new_conditions();
        r
    }

    fn new_conditions(&mut self) {
        let rng = &mut self.rng;
        let clutter = [0.0, 0.0, 0.005, 0.01, 0.02, 0.05][rng.random_range(0..6)];
        self.cond = Conditions {
            half_width: rng.random_range(4.0..9.5),
            pd: rng.random_range(0.6..0.97),
            sigma: rng.random_range(0.03..0.15),
            dashed: rng.random_bool(0.4),
            clutter,
            until: self.now + rng.random_range(10_000_000..60_000_000),
        };
        if let Some(c) = self.forced.clutter {
            self.cond.clutter = c;
        }
        if let Some(d) = self.forced.dashed {
            self.cond.dashed = d;
        }
        if let Some(sigma) = self.forced.sigma {
            self.cond.sigma = sigma;
        }
        if let Some(pd) = self.forced.pd {
            self.cond.pd = pd;
        }
    }

    /// Lateral position of road line `k` at `u` metres ahead, now.
    fn line_x(&self, k: i64, u: f64) -> f64 {
        let shift = match self.lane_change {
            Some((start, dir)) => {
                let s = ((self.now - start) as f64 / 4e6).clamp(0.0, 1.0);
                dir * self.spacing * s * s * (3.0 - 2.0 * s)
            }
            None => 0.0,
        };
        let weave = 0.3 * (self.weave_phase).sin();
        self.offset
            + shift
            + weave
            + k as f64 * self.spacing
            + self.heading * u
            + 0.5 * self.curvature * u * u
    }

    /// The next frame.
    pub fn next_frame(&mut self) -> RoadFrame {
        // Time step: nominal ± 2 ms, sometimes a dropped frame (2–5×).
        let mut dt = FRAME_US + self.rng.random_range(-2_000..=2_000);
        if self.frames > 0 && self.rng.random_bool(1.0 / 600.0) {
            dt *= self.rng.random_range(2..=5);
        }
        if self.frames > 0 {
            self.now += dt;
        }
        self.frames += 1;
        let dts = dt as f64 * 1e-6;
        // Heading and curvature: sums of sinusoids.
        let ts = self.now as f64 * 1e-6;
        let wave =
            |w: &[(f64, f64, f64); 3]| w.iter().map(|(a, f, p)| a * (f * ts + p).sin()).sum();
        self.heading = wave(&self.waves[0]);
        self.curvature = wave(&self.waves[1]);
        self.weave_phase += dts * std::f64::consts::TAU / 20.0;
        if self.now >= self.cond.until {
            self.new_conditions();
        }
        // Lane changes.
        if let Some((start, dir)) = self.lane_change {
            if self.now - start >= 4_000_000 {
                self.offset += dir * self.spacing;
                self.lane_change = None;
            }
        } else if self.now >= self.next_change {
            let dir = if self.rng.random_bool(0.5) { 1.0 } else { -1.0 };
            self.lane_change = Some((self.now, dir));
            self.next_change = self.now + self.rng.random_range(60_000_000..240_000_000);
        }
        // Blackouts: about one a minute, 1–15 frames.
        if self.blackout_left == 0 && self.rng.random_bool(1.0 / 1800.0) {
            self.blackout_left = self.rng.random_range(1..=15);
        }
        let blackout = self.blackout_left > 0;
        if blackout {
            self.blackout_left -= 1;
        }
        let (u_min, u_max) = (
            f64::from(DEFAULT.hyper.u_min),
            f64::from(DEFAULT.hyper.u_max),
        );
        let row = f64::from(DEFAULT.hyper.row_step);
        let rows = ((u_max - u_min) / row).round() as usize + 1;
        let k_lo = ((-self.cond.half_width - self.offset) / self.spacing).ceil() as i64 - 1;
        let k_hi = ((self.cond.half_width - self.offset) / self.spacing).floor() as i64 + 1;
        let visible: Vec<i64> = (k_lo..=k_hi)
            .filter(|&k| self.line_x(k, u_min).abs() <= self.cond.half_width)
            .collect();
        let mut points = Vec::new();
        if !blackout {
            let noise = Normal::new(0.0, self.cond.sigma).expect("positive sigma");
            let travelled = self.now as f64 * 1e-6 * 25.0;
            for r in 0..rows {
                let u = u_min + r as f64 * row;
                for &k in &visible {
                    // Dashed: every line but `k_lo`, the first candidate, one spacing beyond
                    // the window's left edge and so almost never visible (meant as the leftmost
                    // visible line; kept, as every soak figure since stop 54 was drawn with it).
                    if self.cond.dashed
                        && k != k_lo
                        && (u + travelled + 5.0 * k as f64) % 12.0 >= 3.0
                    {
                        continue;
                    }
                    if self.rng.random_bool(self.cond.pd) {
                        let x = self.line_x(k, u) + noise.sample(&mut self.rng);
                        points.push([u as f32, x as f32]);
                    }
                }
                if self.cond.clutter > 0.0 {
                    let lam = self.cond.clutter * 24.0;
                    let c = Poisson::new(lam).map_or(0.0, |p| p.sample(&mut self.rng)) as usize;
                    for _ in 0..c {
                        let x = self.rng.random_range(-12.0..12.0);
                        points.push([u as f32, x as f32]);
                    }
                }
            }
        }
        let truth = visible
            .iter()
            .map(|&k| {
                let xs = DEFAULT
                    .index_u
                    .iter()
                    .map(|&u| self.line_x(k, f64::from(u)))
                    .collect();
                (k, xs)
            })
            .collect();
        RoadFrame {
            t_us: self.now,
            points,
            truth,
            blackout,
        }
    }
}

/// Health and divergence figures of one or more drives.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SoakSummary {
    /// Frames driven (tracker A).
    pub frames: u64,
    /// Hours of driving they represent.
    pub hours: f64,
    /// Blackout frames among them.
    pub blackout_frames: u64,
    /// Frames refused by the tracker (must be 0: the road's time increases).
    pub refused: u64,
    /// Published-output invariant violations (first few kept in `violations`).
    pub output_violations: u64,
    /// Covariance health violations (asymmetry or PSD beyond tolerance).
    pub covariance_violations: u64,
    /// Frames whose published variances include a negative value.
    pub negative_variance_frames: u64,
    /// Most negative published variance seen, m².
    pub min_published_variance: f64,
    /// The first violations, with shard and frame.
    pub violations: Vec<String>,
    /// Covariance checks with the full eigen-decomposition.
    pub health_checks: u64,
    /// Largest asymmetry (correlation form).
    pub max_asymmetry: f64,
    /// Smallest eigenvalue of the correlation form.
    pub min_eig_corr: f64,
    /// Smallest eigenvalue of `P` over its largest diagonal entry.
    pub min_eig_rel: f64,
    /// Temporal operations that failed numerically (state kept).
    pub temporal_failures: u64,
    /// Frames on which the temporal covariance was repaired (its check failed:
    /// `StepReport::temporal_cov_repairs > 0`, docs/design.md §4.2.4).
    pub repaired_frames: u64,
    /// Spatial row updates that failed numerically.
    pub spatial_rows_failed: u64,
    /// Spatial backward passes that failed.
    pub spatial_smoother_failed: u64,
    /// Ids created.
    pub ids_created: u64,
    /// Ids switched on a continuously visible line.
    pub id_switches: u64,
    /// Line-frames with a true line visible (not in blackout).
    pub line_frames: u64,
    /// Of which matched by a published lane.
    pub line_frames_matched: u64,
    /// Published lanes matched to no line (lane-frames).
    pub false_lane_frames: u64,
    /// Of which lanes not seen this frame (coasting, `misses > 0`).
    pub false_lane_frames_coasting: u64,
    /// Mean |Δx| of matched lanes against the truth over the observed index points, m.
    pub mean_truth_error: f64,
    /// Tracker B vs the f64 reference.
    pub reference: Option<RefSummary>,
}

/// Tracker B against the f64 reference.
#[derive(Debug, Clone, Default, Serialize)]
pub struct RefSummary {
    /// Episodes started.
    pub episodes: u64,
    /// Frames compared (before any discrete disagreement).
    pub frames_compared: u64,
    /// Frames not compared (after a discrete disagreement in their episode).
    pub frames_not_compared: u64,
    /// Episodes ended by a discrete disagreement.
    pub discrete_disagreements: u64,
    /// Episodes whose comparison ended at a spatial row over the event budget `E`: the core
    /// approximates such a row (docs/design.md §4.1 step 5) and the reference enumerates it
    /// exactly, so from that frame on they may differ by more than f32 rounding. Not counted in
    /// `discrete_disagreements`; the frame is not compared.
    pub episodes_ended_over_budget: u64,
    /// The first few disagreements.
    pub disagreements: Vec<String>,
    /// Lane-frames compared (filtered).
    pub lanes_compared: u64,
    /// Largest |Δz| of a filtered lane at an index point, m.
    pub max_dz: f64,
    /// 99.9th percentile of the per-lane-frame largest |Δz|, m.
    pub p999_dz: f64,
    /// Median of the per-lane-frame largest |Δz|, m.
    pub p50_dz: f64,
    /// Largest relative variance difference.
    pub max_dvar_rel: f64,
    /// 99.9th percentile of the per-lane-frame largest relative variance difference.
    pub p999_dvar_rel: f64,
    /// Smoothed lane-frames compared.
    pub smoothed_compared: u64,
    /// Largest |Δz| of a smoothed lane, m.
    pub max_dz_smoothed: f64,
    /// 99.9th percentile, smoothed.
    pub p999_dz_smoothed: f64,
    /// Largest |Δexistence|.
    pub max_dexistence: f64,
    /// Per-lane-frame largest |Δz| (merged, then summarised).
    #[serde(skip)]
    pub dz: Vec<f64>,
    /// Per-lane-frame relative variance differences (merged, then summarised).
    #[serde(skip)]
    pub dvar: Vec<f64>,
    /// Per-lane-frame smoothed |Δz| (merged, then summarised).
    #[serde(skip)]
    pub dz_smoothed: Vec<f64>,
}

fn percentile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let i = ((v.len() as f64 - 1.0) * q).round() as usize;
    v[i.min(v.len() - 1)]
}

impl RefSummary {
    fn merge(&mut self, o: RefSummary) {
        self.episodes += o.episodes;
        self.frames_compared += o.frames_compared;
        self.frames_not_compared += o.frames_not_compared;
        self.discrete_disagreements += o.discrete_disagreements;
        self.episodes_ended_over_budget += o.episodes_ended_over_budget;
        for d in o.disagreements {
            if self.disagreements.len() < 20 {
                self.disagreements.push(d);
            }
        }
        self.lanes_compared += o.lanes_compared;
        self.smoothed_compared += o.smoothed_compared;
        self.max_dexistence = self.max_dexistence.max(o.max_dexistence);
        self.dz.extend(o.dz);
        self.dvar.extend(o.dvar);
        self.dz_smoothed.extend(o.dz_smoothed);
    }

    fn finish(&mut self) {
        self.max_dz = self.dz.iter().copied().fold(0.0, f64::max);
        self.max_dvar_rel = self.dvar.iter().copied().fold(0.0, f64::max);
        self.max_dz_smoothed = self.dz_smoothed.iter().copied().fold(0.0, f64::max);
        self.p999_dz = percentile(&mut self.dz, 0.999);
        self.p50_dz = percentile(&mut self.dz, 0.5);
        self.p999_dvar_rel = percentile(&mut self.dvar, 0.999);
        self.p999_dz_smoothed = percentile(&mut self.dz_smoothed, 0.999);
    }
}

impl SoakSummary {
    fn merge(&mut self, o: SoakSummary) {
        let w = (self.line_frames_matched, o.line_frames_matched);
        if w.0 + w.1 > 0 {
            self.mean_truth_error = (self.mean_truth_error * w.0 as f64
                + o.mean_truth_error * w.1 as f64)
                / (w.0 + w.1) as f64;
        }
        self.frames += o.frames;
        self.hours += o.hours;
        self.blackout_frames += o.blackout_frames;
        self.refused += o.refused;
        self.output_violations += o.output_violations;
        self.covariance_violations += o.covariance_violations;
        self.negative_variance_frames += o.negative_variance_frames;
        self.min_published_variance = self.min_published_variance.min(o.min_published_variance);
        for v in o.violations {
            if self.violations.len() < 20 {
                self.violations.push(v);
            }
        }
        self.health_checks += o.health_checks;
        self.max_asymmetry = self.max_asymmetry.max(o.max_asymmetry);
        self.min_eig_corr = self.min_eig_corr.min(o.min_eig_corr);
        self.min_eig_rel = self.min_eig_rel.min(o.min_eig_rel);
        self.temporal_failures += o.temporal_failures;
        self.repaired_frames += o.repaired_frames;
        self.spatial_rows_failed += o.spatial_rows_failed;
        self.spatial_smoother_failed += o.spatial_smoother_failed;
        self.ids_created += o.ids_created;
        self.id_switches += o.id_switches;
        self.line_frames += o.line_frames;
        self.line_frames_matched += o.line_frames_matched;
        self.false_lane_frames += o.false_lane_frames;
        self.false_lane_frames_coasting += o.false_lane_frames_coasting;
        match (&mut self.reference, o.reference) {
            (Some(a), Some(b)) => a.merge(b),
            (None, Some(b)) => self.reference = Some(b),
            _ => {}
        }
    }
}

/// The reference tables on the core's model (rank-r truncated Gram matrix).
///
/// # Errors
/// When the default hyperparameter file cannot be read or the tables not built.
pub fn truncated_tables() -> Result<ModelTables> {
    truncated_tables_of(DEFAULT_HYPER)
}

/// [`truncated_tables`] of the hyperparameter file `hyper` (relative to the repository).
///
/// # Errors
/// When the file cannot be read or the tables not built.
pub fn truncated_tables_of(hyper: &str) -> Result<ModelTables> {
    let h = HyperFile::load(&stjpdacf_tools::repo_root().join(hyper))?;
    let mut t = ModelTables::from_hyper(&h)?;
    let r = t.gram_rank;
    let v = t.gram_eigvec.columns(0, r).into_owned();
    let l = nalgebra::DMatrix::from_diagonal(&t.gram_eigval.rows(0, r).into_owned());
    let g = &v * l * v.transpose();
    t.gram = (&g + g.transpose()) * 0.5;
    Ok(t)
}

/// Episode state of tracker B and the reference.
struct Episode {
    core: Box<ReferenceTracker>,
    reference: ReferencePipeline,
    c2r: BTreeMap<u32, u32>,
    r2c: BTreeMap<u32, u32>,
    broken: bool,
}

fn lane_diff(c: &LaneEstimate<POINTS>, r: &RefLane) -> (f64, f64) {
    let mut dz: f64 = 0.0;
    let mut dv: f64 = 0.0;
    for i in 0..POINTS {
        dz = dz.max((f64::from(c.z[i]) - r.z[i]).abs());
        dv = dv.max((f64::from(c.var[i]) - r.var[i]).abs() / r.var[i].abs().max(1e-12));
    }
    (dz, dv)
}

/// Why a frame ends its episode's comparison.
enum Stop {
    /// The reference reports a spatial row over the event budget: the core approximated it.
    OverBudget,
    /// A discrete disagreement (lane slots, ids, misses) or a refused step.
    Disagreement(String),
}

impl From<String> for Stop {
    fn from(s: String) -> Self {
        Self::Disagreement(s)
    }
}

/// Compares one frame of tracker B with the reference; `Err` when the episode's comparison
/// ends there.
fn compare_frame(
    ep: &mut Episode,
    frame: &RoadFrame,
    k: u64,
    smooth: bool,
    out: &mut RefSummary,
) -> Result<(), Stop> {
    let co = ep
        .core
        .step(Instant::from_micros(frame.t_us), &frame.points)
        .map_err(|e| format!("core refused: {e}"))?;
    let pts64: Vec<(f64, f64)> = frame
        .points
        .iter()
        .map(|p| (f64::from(p[0]), f64::from(p[1])))
        .collect();
    let ro = ep
        .reference
        .step(frame.t_us as f64 * 1e-6, &pts64)
        .map_err(|e| format!("reference: {e:#}"))?;
    if ro.spatial.counters.over_budget_rows > 0 {
        return Err(Stop::OverBudget);
    }
    let cs: Vec<usize> = co.filtered.iter().map(|l| usize::from(l.slot)).collect();
    let rs: Vec<usize> = ro.filtered.iter().map(|l| l.slot).collect();
    if cs != rs {
        return Err(format!("lane slots {cs:?} vs {rs:?}").into());
    }
    for (c, r) in co.filtered.iter().zip(&ro.filtered) {
        let (ci, ri) = (c.id.0, r.id);
        if *ep.c2r.entry(ci).or_insert(ri) != ri || *ep.r2c.entry(ri).or_insert(ci) != ci {
            return Err(format!("id {ci} ↔ {ri} breaks the bijection").into());
        }
        if usize::from(c.misses) != r.misses {
            return Err(format!("slot {}: misses {} vs {}", r.slot, c.misses, r.misses).into());
        }
        let (dz, dv) = lane_diff(c, r);
        out.dz.push(dz);
        out.dvar.push(dv);
        out.lanes_compared += 1;
        out.max_dexistence = out
            .max_dexistence
            .max((f64::from(c.existence) - r.existence).abs());
    }
    if smooth && ep.reference.window_comparable() == Some(true) {
        let sm = ep
            .reference
            .lagged()
            .map_err(|e| format!("reference smoother: {e:#}"))?;
        if let Some(sm) = sm {
            let cs: Vec<usize> = co.smoothed.iter().map(|l| usize::from(l.slot)).collect();
            let rs: Vec<usize> = sm.iter().map(|l| l.slot).collect();
            if cs != rs {
                return Err(format!("smoothed slots {cs:?} vs {rs:?}").into());
            }
            for (c, r) in co.smoothed.iter().zip(&sm) {
                let (dz, _) = lane_diff(c, r);
                out.dz_smoothed.push(dz);
                out.smoothed_compared += 1;
            }
        }
    }
    let _ = k;
    Ok(())
}

/// Matches published lanes to true lines: mean |Δx| over the lane's observed index points
/// < 0.5 m, greedy by error. Returns (line index, lane id, error) per match and the count of
/// unmatched lanes.
pub fn match_truth(
    lanes: &[LaneEstimate<POINTS>],
    truth: &[(i64, Vec<f64>)],
) -> (Vec<(i64, u32, f64)>, [u64; 2]) {
    let mut cands = Vec::new();
    for (li, l) in lanes.iter().enumerate() {
        let used: Vec<usize> = (0..POINTS)
            .filter(|&i| {
                let u = DEFAULT.index_u[i];
                u >= l.u_first - 1.0 && u <= l.u_last + 1.0
            })
            .collect();
        if used.is_empty() {
            continue;
        }
        for (ti, (_, xs)) in truth.iter().enumerate() {
            let e = used
                .iter()
                .map(|&i| (f64::from(l.z[i]) - xs[i]).abs())
                .sum::<f64>()
                / used.len() as f64;
            if e < 0.5 {
                cands.push((e, li, ti));
            }
        }
    }
    cands.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut lane_used, mut line_used) = (vec![false; lanes.len()], vec![false; truth.len()]);
    let mut m = Vec::new();
    for (e, li, ti) in cands {
        if !lane_used[li] && !line_used[ti] {
            lane_used[li] = true;
            line_used[ti] = true;
            m.push((truth[ti].0, lanes[li].id.0, e));
        }
    }
    let unmatched = lane_used.iter().filter(|u| !**u).count() as u64;
    let coasting = lane_used
        .iter()
        .zip(lanes)
        .filter(|(u, l)| !**u && l.misses > 0)
        .count() as u64;
    (m, [unmatched, coasting])
}

/// Counts the id switches of one frame's matches ([`match_truth`]) among its `visible` lines (the
/// road indices of `RoadFrame::truth`): a line whose matched lane id differs from the one it had
/// in the last frame it was matched while it stayed visible (a frame where it is visible but not
/// matched does not end its run: a new id after it is a switch). A line that is not visible
/// forgets its id (a blackout frame: call with no visible line). `last` carries each line's id
/// from frame to frame.
pub fn id_switches(
    last: &mut BTreeMap<i64, u32>,
    visible: &[i64],
    matches: &[(i64, u32, f64)],
) -> u64 {
    let switches = matches
        .iter()
        .filter(|(line, id, _)| last.get(line).is_some_and(|prev| prev != id))
        .count() as u64;
    last.retain(|line, _| visible.contains(line));
    last.extend(matches.iter().map(|&(line, id, _)| (line, id)));
    switches
}

/// One drive of `frames` frames (shard `shard`); `progress` counts frames done.
///
/// # Errors
/// When the reference cannot be built.
pub fn run_drive(
    cfg: &SoakConfig,
    shard: usize,
    frames: u64,
    tables: Option<&ModelTables>,
    progress: &AtomicU64,
) -> Result<SoakSummary> {
    let mut road = Road::new(cfg.seed.wrapping_add(shard as u64));
    let mut a = Box::new(ReferenceTracker::new(cfg.tables()));
    let mut s = SoakSummary {
        min_eig_corr: f64::INFINITY,
        min_eig_rel: f64::INFINITY,
        min_published_variance: f64::INFINITY,
        ..SoakSummary::default()
    };
    let mut rs = RefSummary::default();
    let mut ep: Option<Episode> = None;
    let mut episode_index = 0u64;
    let mut last_id: BTreeMap<i64, u32> = BTreeMap::new();
    let mut max_id: Option<u32> = None;
    let mut err_sum = 0.0;
    let note = |s: &mut SoakSummary, msg: String| {
        if s.violations.len() < 20 {
            s.violations.push(format!("shard {shard}: {msg}"));
        }
    };
    for k in 0..frames {
        let f = road.next_frame();
        if f.blackout {
            s.blackout_frames += 1;
        }
        // Tracker A.
        match a.step(Instant::from_micros(f.t_us), &f.points) {
            Err(e) => {
                s.refused += 1;
                note(&mut s, format!("frame {k}: refused: {e}"));
            }
            Ok(out) => {
                let rep = &out.report;
                s.temporal_failures += u64::from(rep.temporal_failures);
                s.repaired_frames += u64::from(rep.temporal_cov_repairs > 0);
                s.spatial_rows_failed += u64::from(rep.spatial.rows_failed);
                s.spatial_smoother_failed += u64::from(rep.spatial.smoother_failed);
                let minvar = out
                    .filtered
                    .iter()
                    .chain(out.smoothed.iter())
                    .flat_map(|l| l.var.iter())
                    .fold(f64::INFINITY, |m, v| m.min(f64::from(*v)));
                s.min_published_variance = s.min_published_variance.min(minvar);
                if minvar < 0.0 {
                    s.negative_variance_frames += 1;
                }
                if let Err(e) = invariants::check_output(&out, f.points.len()) {
                    s.output_violations += 1;
                    note(&mut s, format!("frame {k}: {e}"));
                }
                let check = if cfg.health_every > 0 && k % cfg.health_every == 0 {
                    PsdCheck::Eigen
                } else {
                    PsdCheck::Cholesky
                };
                let f_t = a.temporal().filter();
                match invariants::cov_health(f_t.covariance(), &active_indices(f_t), check) {
                    Ok(h) => {
                        s.max_asymmetry = s.max_asymmetry.max(h.asym);
                        if check == PsdCheck::Eigen && h.dim > 0 {
                            s.health_checks += 1;
                            s.min_eig_corr = s.min_eig_corr.min(h.min_eig_corr);
                            s.min_eig_rel = s.min_eig_rel.min(h.min_eig_rel);
                        }
                    }
                    Err(e) => {
                        s.covariance_violations += 1;
                        note(&mut s, format!("frame {k}: {e}"));
                        if check == PsdCheck::Eigen {
                            // Still record how far it went.
                            let h =
                                invariants::eigen_figures(f_t.covariance(), &active_indices(f_t));
                            s.min_eig_corr = s.min_eig_corr.min(h.min_eig_corr);
                            s.min_eig_rel = s.min_eig_rel.min(h.min_eig_rel);
                            s.max_asymmetry = s.max_asymmetry.max(h.asym);
                        }
                    }
                }
                // Ids against the truth.
                for l in &out.filtered {
                    max_id = max_id.max(Some(l.id.0));
                }
                if f.blackout {
                    // No line is visible: each forgets its id.
                    id_switches(&mut last_id, &f.visible_lines(), &[]);
                } else {
                    let (m, [unmatched, coasting]) = match_truth(&out.filtered, &f.truth);
                    s.line_frames += f.truth.len() as u64;
                    s.line_frames_matched += m.len() as u64;
                    s.false_lane_frames += unmatched;
                    s.false_lane_frames_coasting += coasting;
                    for (_, _, e) in &m {
                        err_sum += e;
                    }
                    s.id_switches += id_switches(&mut last_id, &f.visible_lines(), &m);
                }
            }
        }
        // Tracker B and the reference.
        if let Some(tables) = tables {
            if k % cfg.episode.max(1) == 0 {
                let on = episode_index % cfg.compare_every.max(1) == 0;
                episode_index += 1;
                ep = if on {
                    rs.episodes += 1;
                    Some(Episode {
                        // The reference pipeline is the round-1 pipeline (docs/design.md
                        // §1–§4.3): compared on that configuration; the known-lane stage
                        // has its own reference (tests/persist_reference.rs).
                        core: Box::new(ReferenceTracker::with_config(
                            cfg.tables(),
                            TrackerConfig::ROUND1,
                        )),
                        reference: ReferencePipeline::new(
                            tables,
                            K_ROWS,
                            PipelineConfig::from_tables(tables),
                        )?,
                        c2r: BTreeMap::new(),
                        r2c: BTreeMap::new(),
                        broken: false,
                    })
                } else {
                    None
                };
            }
            if let Some(e) = ep.as_mut() {
                if e.broken {
                    rs.frames_not_compared += 1;
                } else {
                    let smooth = cfg.smooth_every > 0 && k % cfg.smooth_every == 0;
                    match compare_frame(e, &f, k, smooth, &mut rs) {
                        Ok(()) => rs.frames_compared += 1,
                        Err(Stop::OverBudget) => {
                            e.broken = true;
                            rs.episodes_ended_over_budget += 1;
                            rs.frames_not_compared += 1;
                        }
                        Err(Stop::Disagreement(msg)) => {
                            e.broken = true;
                            rs.discrete_disagreements += 1;
                            rs.frames_not_compared += 1;
                            if rs.disagreements.len() < 20 {
                                rs.disagreements
                                    .push(format!("shard {shard} frame {k}: {msg}"));
                            }
                        }
                    }
                }
            }
        }
        progress.fetch_add(1, Ordering::Relaxed);
    }
    s.frames = frames;
    s.ids_created = max_id.map_or(0, |m| u64::from(m) + 1);
    s.hours = road.now as f64 * 1e-6 / 3600.0;
    s.mean_truth_error = if s.line_frames_matched > 0 {
        err_sum / s.line_frames_matched as f64
    } else {
        0.0
    };
    if tables.is_some() {
        s.reference = Some(rs);
    }
    Ok(s)
}

/// Runs the whole soak: `cfg.shards` drives over `cfg.threads` threads. `on_progress` is called
/// about every 200 ms with the frames done (for a progress bar).
///
/// # Errors
/// When the reference tables cannot be built or a drive fails to start its reference.
pub fn run(cfg: &SoakConfig, on_progress: &(dyn Fn(u64) + Sync)) -> Result<SoakSummary> {
    let tables = if cfg.reference {
        let hyper = if cfg.uncoupled {
            UNCOUPLED_HYPER
        } else {
            DEFAULT_HYPER
        };
        Some(truncated_tables_of(hyper).context("reference tables")?)
    } else {
        None
    };
    let shards = cfg.shards.max(1);
    let per = cfg.frames / shards as u64;
    let extra = cfg.frames % shards as u64;
    let progress = AtomicU64::new(0);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Result<SoakSummary>>> = Mutex::new(Vec::new());
    let done = AtomicUsize::new(0);
    std::thread::scope(|sc| {
        for _ in 0..cfg.threads.max(1) {
            sc.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= shards {
                    break;
                }
                let n = per + u64::from((i as u64) < extra);
                let r = run_drive(cfg, i, n, tables.as_ref(), &progress);
                if let Ok(mut v) = results.lock() {
                    v.push(r);
                }
            });
        }
        sc.spawn(|| {
            while done.load(Ordering::Relaxed) == 0 {
                on_progress(progress.load(Ordering::Relaxed));
                if results.lock().map(|v| v.len() >= shards).unwrap_or(true) {
                    break;
                }
                std::thread::sleep(std::time::Duration::from_millis(200));
            }
        });
    });
    done.store(1, Ordering::Relaxed);
    on_progress(progress.load(Ordering::Relaxed));
    let mut total = SoakSummary {
        min_eig_corr: f64::INFINITY,
        min_eig_rel: f64::INFINITY,
        min_published_variance: f64::INFINITY,
        ..SoakSummary::default()
    };
    let results = results.into_inner().unwrap_or_default();
    for r in results {
        total.merge(r?);
    }
    if let Some(r) = total.reference.as_mut() {
        r.finish();
    }
    Ok(total)
}
