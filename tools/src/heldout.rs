//! A second replay generator, written independently of [`crate::synth`], for held-out checks:
//! held-out lane geometry (TuSimple labels of the sessions `0531` and `0601`, [`LABELS`]; every threshold of the tracker was chosen on the `0313` labels and
//! this generator's output) rendered by a different simulator. Where [`crate::synth`] makes one
//! modelling choice, this one makes another, so that a tracker tuned to the first's habits is
//! found out:
//!
//! | | [`crate::synth`] | this generator |
//! |---|---|---|
//! | frame rate, clip | 20 fps, 20 frames | 15 fps, 16 frames |
//! | rows | every 2nd image row | every 3rd image row |
//! | vehicle motion | drift + sine wobble, heading and curvature rates, lane changes | lateral offset integrating an Ornstein–Uhlenbeck velocity, heading random walk, no lane change |
//! | misses | independent per row | bursts: a two-state (Gilbert–Elliott) chain along each lane's rows |
//! | dashes | 3 m paint / 9 m gap | paint U(2, 4) m, gap U(6, 12) m per lane |
//! | point noise | Gaussian in pixels | Student-t (ν = 3) in pixels, plus the marking's edge: ±half its width on the road, per lane and frame |
//! | clutter | uniform over the image | uniform over the road area (BEV), denser |
//! | distractors | cars, shadows, road edges; short segments drawn anew each frame | short straight segments fixed on the road (seams, arrows, crosswalk bars), seen for as long as they are in view |
//!
//! The last frame of each clip shows the label's road exactly (its ground truth is the label),
//! the earlier frames the same road seen τ seconds before: the vehicle's pose relative to the
//! road (lateral offset, heading) is a random process that is 0 at τ = 0, and what is fixed on
//! the road (dashes, segments) comes nearer at the vehicle's speed. Byte-for-byte reproducible
//! from its seed; clip `i` depends only on (`seed`, `i`).

use anyhow::{ensure, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson, StudentT};

use crate::camera::Camera;
use crate::tusimple::{Frame, TuSimpleRecord};

/// The held-out labels, relative to the repository's `data` folder: 40 TuSimple train labels
/// of the sessions `0531` (every 18th line) and `0601` (every 20th line), verbatim.
pub const LABELS: &str = "tusimple/heldout/labels.json";

/// The bundled held-out labels ([`LABELS`] under the repository's `data` folder).
///
/// # Errors
/// The file cannot be read or parsed.
pub fn bundled_labels() -> Result<Vec<TuSimpleRecord>> {
    crate::tusimple::read_labels(&crate::repo_root().join("data").join(LABELS))
}

/// The generator's parameters (see the module doc for what each does).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct HeldoutParams {
    /// Frames per clip.
    pub frames_per_clip: usize,
    /// Seconds between frames.
    pub frame_step: f64,
    /// Feature rows: every `row_step`-th image row from the label's first `h_samples` row down.
    pub row_step: usize,
    /// Scale of the Student-t column noise, pixels.
    pub pixel_noise: f64,
    /// Degrees of freedom of the column noise (heavy tails).
    pub noise_dof: f64,
    /// Width of the painted marking, metres: a lane's points sit on one edge of it or the other
    /// (uniform across the width, drawn per lane and frame).
    pub marking_width: f64,
    /// Detection probability of a row in the good state of the miss chain.
    pub detect_good: f64,
    /// Detection probability of a row in the bad state.
    pub detect_bad: f64,
    /// Probability of going from the good to the bad state from one row to the next.
    pub good_to_bad: f64,
    /// Probability of going from the bad to the good state.
    pub bad_to_good: f64,
    /// Probability that a lane is dashed.
    pub dashed_prob: f64,
    /// Paint length of a dashed lane, metres (uniform range).
    pub dash_paint: (f64, f64),
    /// Gap of a dashed lane, metres (uniform range).
    pub dash_gap: (f64, f64),
    /// Vehicle speed, m/s (uniform range).
    pub speed: (f64, f64),
    /// Stationary standard deviation of the lateral velocity, m/s (the offset is its integral).
    pub lateral_sd: f64,
    /// Time constant of the lateral velocity, seconds.
    pub lateral_tau: f64,
    /// Heading random walk, rad/√s.
    pub heading_rw: f64,
    /// Camera pitch jitter: the standard deviation of the pitch in each frame but a clip's last,
    /// radians, independent from frame to frame (bumps; 0 by default). The frame's points are
    /// projected through the pitched camera, the tracker maps them with the nominal one, so the
    /// BEV fans in and out.
    pub pitch_jitter: f64,
    /// Uniform clutter, points per square metre of road in [`HeldoutParams::clutter_box`].
    pub clutter_density: f64,
    /// The clutter's road area: (u from, u to, |x| up to), metres.
    pub clutter_box: (f64, f64, f64),
    /// Short straight segments fixed on the road, per clip (Poisson mean).
    pub segments: f64,
    /// Segment length, metres (uniform range).
    pub segment_len: (f64, f64),
    /// Detection probability of a segment's row crossing.
    pub segment_detect: f64,
}

impl Default for HeldoutParams {
    /// The reference condition: mid noise, 0.02 clutter points per m² (about 30 in view a
    /// frame), no segments.
    fn default() -> Self {
        Self {
            frames_per_clip: 16,
            frame_step: 1.0 / 15.0,
            row_step: 3,
            pixel_noise: 3.0,
            noise_dof: 3.0,
            marking_width: 0.15,
            detect_good: 0.9,
            detect_bad: 0.15,
            good_to_bad: 0.05,
            bad_to_good: 0.2,
            dashed_prob: 0.5,
            dash_paint: (2.0, 4.0),
            dash_gap: (6.0, 12.0),
            speed: (15.0, 35.0),
            lateral_sd: 0.4,
            lateral_tau: 1.0,
            heading_rw: 0.01,
            pitch_jitter: 0.0,
            clutter_density: 0.02,
            clutter_box: (5.0, 70.0, 15.0),
            segments: 0.0,
            segment_len: (2.0, 8.0),
            segment_detect: 0.9,
        }
    }
}

impl HeldoutParams {
    /// Check ranges: probabilities in [0, 1], positive steps and scales, ordered ranges.
    ///
    /// # Errors
    /// The first parameter out of range.
    pub fn validate(&self) -> Result<()> {
        let probs = [
            ("detect_good", self.detect_good),
            ("detect_bad", self.detect_bad),
            ("good_to_bad", self.good_to_bad),
            ("bad_to_good", self.bad_to_good),
            ("dashed_prob", self.dashed_prob),
            ("segment_detect", self.segment_detect),
        ];
        for (name, p) in probs {
            ensure!((0.0..=1.0).contains(&p), "{name} {p:?} is not in [0, 1]");
        }
        ensure!(
            (1..=crate::synth::SynthParams::MAX_FRAMES_PER_CLIP).contains(&self.frames_per_clip),
            "frames_per_clip = {} must be in 1..={}",
            self.frames_per_clip,
            crate::synth::SynthParams::MAX_FRAMES_PER_CLIP
        );
        ensure!(self.row_step >= 1, "row_step must be ≥ 1");
        let positive = [
            ("frame_step", self.frame_step),
            ("noise_dof", self.noise_dof),
            ("lateral_tau", self.lateral_tau),
        ];
        for (name, v) in positive {
            ensure!(v.is_finite() && v > 0.0, "{name} {v:?} must be > 0");
        }
        let non_negative = [
            ("pixel_noise", self.pixel_noise),
            ("marking_width", self.marking_width),
            ("lateral_sd", self.lateral_sd),
            ("heading_rw", self.heading_rw),
            ("pitch_jitter", self.pitch_jitter),
            ("clutter_density", self.clutter_density),
            ("segments", self.segments),
        ];
        for (name, v) in non_negative {
            ensure!(v.is_finite() && v >= 0.0, "{name} {v:?} must be ≥ 0");
        }
        let ranges = [
            ("dash_paint", self.dash_paint),
            ("dash_gap", self.dash_gap),
            ("speed", self.speed),
            ("segment_len", self.segment_len),
        ];
        for (name, (a, b)) in ranges {
            ensure!(
                a.is_finite() && b.is_finite() && 0.0 < a && a <= b,
                "{name} ({a}, {b}) must satisfy 0 < from ≤ to"
            );
        }
        let (u0, u1, xm) = self.clutter_box;
        ensure!(
            0.0 < u0 && u0 < u1 && u1.is_finite() && xm.is_finite() && xm > 0.0,
            "clutter_box ({u0}, {u1}, {xm}) must satisfy 0 < u from < u to, |x| > 0"
        );
        Ok(())
    }
}

/// The generator's output: frames clip after clip, and each clip's last-frame ground truth (the
/// label itself).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HeldoutOutput {
    /// Feature-point frames (image pixels), clip after clip; the last frame of each clip carries
    /// the label's `raw_file` and `h_samples`.
    pub frames: Vec<Frame>,
    /// Ground truth of each clip's last frame: the labels, in order.
    pub gt_last: Vec<TuSimpleRecord>,
    /// Points per frame that came from lanes, from clutter and from segments (sums).
    pub lane_points: usize,
    /// See [`HeldoutOutput::lane_points`].
    pub clutter_points: usize,
    /// See [`HeldoutOutput::lane_points`].
    pub segment_points: usize,
}

/// A label's lane in BEV, sorted by u.
struct BevLane(Vec<(f64, f64)>);

impl BevLane {
    /// x at `u` by linear interpolation, `None` outside the labelled extent.
    fn x_at(&self, u: f64) -> Option<f64> {
        let p = &self.0;
        let (first, last) = (p.first()?, p.last()?);
        if u < first.0 || u > last.0 {
            return None;
        }
        let k = p.partition_point(|q| q.0 < u).max(1).min(p.len() - 1);
        let (a, b) = (p[k - 1], p[k]);
        let w = if b.0 > a.0 {
            (u - a.0) / (b.0 - a.0)
        } else {
            0.0
        };
        Some(a.1 + w * (b.1 - a.1))
    }
}

/// A segment fixed on the road: centre (u at the last frame, x), direction, half length.
struct Segment {
    u: f64,
    x: f64,
    dir: (f64, f64),
    half: f64,
}

fn uniform(rng: &mut ChaCha8Rng, (a, b): (f64, f64)) -> f64 {
    if b > a {
        rng.random_range(a..b)
    } else {
        a
    }
}

fn poisson(rng: &mut ChaCha8Rng, mean: f64) -> usize {
    if mean > 0.0 {
        Poisson::new(mean).map_or(0, |d| d.sample(rng) as usize)
    } else {
        0
    }
}

/// Generate one clip per label (in order); clip `i` is seeded by (`seed`, `i`) only.
///
/// # Errors
/// Bad parameters, a label of the wrong shape, a repeated `raw_file`.
pub fn generate(
    labels: &[TuSimpleRecord],
    params: &HeldoutParams,
    camera: &Camera,
    seed: u64,
) -> Result<HeldoutOutput> {
    params.validate()?;
    let mut seen = std::collections::HashSet::new();
    let mut out = HeldoutOutput::default();
    for (i, label) in labels.iter().enumerate() {
        label.check_shape()?;
        ensure!(
            seen.insert(label.raw_file.as_str()),
            "label raw_file {} appears twice",
            label.raw_file
        );
        clip(label, i, params, camera, seed, &mut out);
        out.gt_last.push(label.clone());
    }
    Ok(out)
}

/// The clip of `label`, appended to `out`.
#[allow(clippy::too_many_lines)]
fn clip(
    label: &TuSimpleRecord,
    index: usize,
    p: &HeldoutParams,
    cam: &Camera,
    seed: u64,
    out: &mut HeldoutOutput,
) {
    let clip_seed = seed.wrapping_mul(0xA24B_AED4_963E_E407)
        ^ (index as u64).wrapping_mul(0x9FB2_1C65_1E98_DF25);
    let mut rng = ChaCha8Rng::seed_from_u64(clip_seed);
    let lanes: Vec<BevLane> = label
        .lanes
        .iter()
        .map(|cols| {
            let mut pts: Vec<(f64, f64)> = label
                .points_of(cols)
                .filter_map(|(c, r)| cam.to_bev(c, r))
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            BevLane(pts)
        })
        .filter(|l| l.0.len() >= 2)
        .collect();
    let k = p.frames_per_clip;
    let speed = uniform(&mut rng, p.speed);
    // The pose relative to the road at τ = (k − 1 − f)·step before the last frame, simulated
    // from the last frame backwards: the lateral offset integrates an Ornstein–Uhlenbeck lateral
    // velocity (a vehicle's offset is smooth: an OU offset itself, with a white velocity, would
    // jump ~10 cm a frame, ~4 g of lateral acceleration), the heading is a random walk (camera
    // yaw jitter); both are 0 at τ = 0.
    let a = (-p.frame_step / p.lateral_tau).exp();
    let ou_sd = p.lateral_sd * (1.0 - a * a).sqrt();
    let rw_sd = p.heading_rw * p.frame_step.sqrt();
    let mut pose = vec![(0.0f64, 0.0f64); k];
    let std = Normal::new(0.0, 1.0).ok();
    let gauss = |rng: &mut ChaCha8Rng| std.map_or(0.0, |d| d.sample(rng));
    let (mut e, mut psi, mut v) = (0.0f64, 0.0f64, p.lateral_sd * gauss(&mut rng));
    for f in (0..k.saturating_sub(1)).rev() {
        e -= v * p.frame_step;
        v = a * v + ou_sd * gauss(&mut rng);
        psi += rw_sd * gauss(&mut rng);
        pose[f] = (e, psi);
    }
    // Per lane: dashed (paint, period, phase) or solid.
    let dashes: Vec<Option<(f64, f64, f64)>> = lanes
        .iter()
        .map(|_| {
            rng.random_bool(p.dashed_prob).then(|| {
                let paint = uniform(&mut rng, p.dash_paint);
                let period = paint + uniform(&mut rng, p.dash_gap);
                (paint, period, rng.random_range(0.0..period))
            })
        })
        .collect();
    let segments: Vec<Segment> = (0..poisson(&mut rng, p.segments))
        .map(|_| {
            let th = rng.random_range(0.0..std::f64::consts::PI);
            Segment {
                u: rng.random_range(5.0..70.0),
                x: rng.random_range(-8.0..8.0),
                dir: (th.cos(), th.sin()),
                half: 0.5 * uniform(&mut rng, p.segment_len),
            }
        })
        .collect();
    let tdist = StudentT::new(p.noise_dof).ok();
    // Feature rows: every `row_step`-th image row from the first labelled row below the horizon
    // (so that every `row_step`-th labelled row is a feature row).
    let first_row = label
        .h_samples
        .iter()
        .copied()
        .find(|&r| r > cam.vp_row + 1.0)
        .unwrap_or(cam.height);
    let rows: Vec<f64> = (0..)
        .map(|j| first_row + (j * p.row_step) as f64)
        .take_while(|&r| r < cam.height)
        .collect();
    // The camera of each frame: pitched by `pitch_jitter` but in the last frame, from a stream
    // of its own (so that the other draws do not depend on it).
    let mut pitch_rng = ChaCha8Rng::seed_from_u64(clip_seed.rotate_left(17) ^ 0x005E_ED0F_F1C4);
    let cams: Vec<Camera> = (0..k)
        .map(|f| {
            let dz = if p.pitch_jitter > 0.0 && f + 1 < k {
                p.pitch_jitter * gauss(&mut pitch_rng)
            } else {
                0.0
            };
            Camera {
                vp_row: cam.vp_row + cam.focal_px * dz.tan(),
                ..*cam
            }
        })
        .collect();
    for (f, &(e, psi)) in pose.iter().enumerate() {
        let fcam = cams.get(f).unwrap_or(cam);
        let tau = (k - 1 - f) as f64 * p.frame_step;
        // What is fixed on the road was this much farther away τ before the last frame.
        let travelled = speed * tau;
        let mut points: Vec<[f64; 2]> = Vec::new();
        let noise = |rng: &mut ChaCha8Rng| tdist.map_or(0.0, |d| p.pixel_noise * d.sample(rng));
        for (lane, dash) in lanes.iter().zip(&dashes) {
            let edge = (rng.random::<f64>() - 0.5) * p.marking_width;
            let mut good =
                rng.random_bool(p.bad_to_good / (p.bad_to_good + p.good_to_bad).max(1e-9));
            for &row in &rows {
                good = if good {
                    !rng.random_bool(p.good_to_bad)
                } else {
                    rng.random_bool(p.bad_to_good)
                };
                let pd = if good { p.detect_good } else { p.detect_bad };
                let detected = rng.random_bool(pd);
                let Some((u, _)) = fcam.to_bev(fcam.vp_col, row) else {
                    continue;
                };
                let Some(xl) = lane.x_at(u) else {
                    continue;
                };
                if let Some((paint, period, phase)) = dash {
                    if (u - travelled + phase).rem_euclid(*period) >= *paint {
                        continue;
                    }
                }
                let x = xl + e + psi * u + edge;
                let n = noise(&mut rng);
                if !detected {
                    continue;
                }
                if let Some((col, r)) = fcam.to_image(u, x) {
                    let col = col + n;
                    if (0.0..cam.width).contains(&col) {
                        points.push([col, r]);
                        out.lane_points += 1;
                    }
                }
            }
        }
        for s in &segments {
            let (cu, cx) = (s.u + travelled, s.x);
            for &row in &rows {
                let Some((u, _)) = fcam.to_bev(fcam.vp_col, row) else {
                    continue;
                };
                // Where the row's line u = const crosses the segment.
                let t = if s.dir.0.abs() > 1e-9 {
                    (u - cu) / s.dir.0
                } else {
                    continue;
                };
                if t.abs() > s.half || !rng.random_bool(p.segment_detect) {
                    continue;
                }
                let x = cx + t * s.dir.1 + e + psi * u;
                let n = noise(&mut rng);
                if let Some((col, r)) = fcam.to_image(u, x) {
                    let col = col + n;
                    if (0.0..cam.width).contains(&col) {
                        points.push([col, r]);
                        out.segment_points += 1;
                    }
                }
            }
        }
        let (u0, u1, xm) = p.clutter_box;
        let area = (u1 - u0) * 2.0 * xm;
        for _ in 0..poisson(&mut rng, p.clutter_density * area) {
            let u = rng.random_range(u0..u1);
            let x = rng.random_range(-xm..xm);
            if let Some((col, r)) = fcam.to_image(u, x) {
                // On the detector's rows: the nearest feature row.
                let j = ((r - first_row) / p.row_step as f64).round();
                let r = first_row + j * p.row_step as f64;
                if (0.0..cam.width).contains(&col) && r < cam.height && j >= 0.0 {
                    points.push([col, r]);
                    out.clutter_points += 1;
                }
            }
        }
        // The order of points must not tell the tracker which are clutter (a stream of its own:
        // the main one's draws do not depend on how many points fell outside the image).
        let mut shuffle = ChaCha8Rng::seed_from_u64(clip_seed ^ (f as u64 + 1).rotate_left(32));
        for i in (1..points.len()).rev() {
            let j = shuffle.random_range(0..=i);
            points.swap(i, j);
        }
        let last = f + 1 == k;
        out.frames.push(Frame {
            clip: format!("heldout{index:04}"),
            t: f as f64 * p.frame_step,
            points,
            raw_file: last.then(|| label.raw_file.clone()),
            h_samples: last.then(|| label.h_samples.clone()),
            camera: None,
        });
    }
}
