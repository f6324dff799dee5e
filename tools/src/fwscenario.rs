//! The scenarios of the firmware benchmark (`bench/firmware`): frame sequences in the SPI wire
//! format (`stjpdacf::wire`), one file per scenario, generated here and committed under
//! [`SCENARIO_DIR`]; the firmware embeds them with `include_bytes!`.
//!
//! ```sh
//! cargo xtask firmware-scenarios
//! ```
//!
//! rewrites the files byte for byte (the test `committed_firmware_scenarios_are_regenerated_exactly`
//! fails when they differ). Frames are numbered from 1 and 50 ms apart (20 fps); every frame
//! carries at most [`MEAS`] points, the reference tracker's budget.
//!
//! * **typical** — the real-geometry replay (`stjpdacf synth`, [`NoiseLevel::Mid`]): the 4 lanes
//!   of the first bundled TuSimple label (`data/tusimple/train_subset.json`) animated over one
//!   60-frame clip (3 s: drift, heading and curvature change, maybe a lane change; dashed
//!   markings, misses, clutter, shadows, cars, road edge), mapped to BEV by the TuSimple camera
//!   and preprocessed as `stjpdacf track` does (row binning, lateral clustering).
//! * **worst** — adversarial, 12 frames: 6 straight lanes 3.6 m apart (x = −9 … 9 m), every frame
//!   exactly M = 256 points: 16 lead-in rows with one point per lane (so that all 6 spatial tracks
//!   start and confirm), then 10 full rows of 16 points each (the 6 lane points and 10 more each
//!   within ±0.4 m of a random lane, inside its gate: rows whose joint events exceed E = 512 and
//!   are pruned). All 6 temporal lanes are updated every frame.
//! * **worst_patterns** — adversarial, 12 frames: the same 6 lanes and lead-in, then rows of 11
//!   points: 2 within ±0.3 m of each of 5 lanes and 1 on the sixth (the lane that has one point
//!   rotates), 3⁵·2 = 486 events ≤ E per row with all 2⁶ = 64 detection patterns — the most
//!   work a row can do without pruning — for as many rows as M allows (14), then the remaining
//!   points one per lane.
//!
//! Everything is seeded (`ChaCha8Rng`), so the files are reproducible on every platform.

use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::Instant;
use stjpdacf::wire;

use crate::camera::Camera;
use crate::synth::{synth_clip, NoiseLevel, SynthParams};
use crate::track::preprocess;

/// Where the scenario files live, relative to the repository root.
pub const SCENARIO_DIR: &str = "bench/firmware/scenarios";
/// File extension of a scenario (frames in the wire format, back to back).
pub const EXTENSION: &str = "stjf";
/// Points per frame at most (the reference tracker's M).
pub const MEAS: usize = 256;
/// Frame step, µs.
pub const STEP_US: i64 = 50_000;
/// Lane slots of the reference configuration.
const LANES: usize = 6;
/// Points per BEV row at most (the reference `PER_ROW`).
const PER_ROW: usize = 16;
/// Lead-in rows with one point per lane (enough for all 6 spatial tracks to start and confirm).
const LEAD_IN_ROWS: usize = 16;

/// One scenario: a name and its frames (BEV `[u, x]` metres).
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// File stem and binary name.
    pub name: &'static str,
    /// Frames, in time order.
    pub frames: Vec<Vec<[f32; 2]>>,
}

impl Scenario {
    /// The scenario in the wire format: frame `k` (from 0) has sequence number `k + 1` and time
    /// `(k + 1)·STEP_US` µs.
    ///
    /// # Errors
    /// A frame the format cannot carry (more than `u16::MAX` points, a point beyond ±128 m).
    pub fn encode(&self) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        for (k, f) in self.frames.iter().enumerate() {
            let mut buf = vec![0u8; wire::frame_len(f.len())];
            let n = u32::try_from(k + 1)?;
            wire::encode(n, Instant::from_micros(i64::from(n) * STEP_US), f, &mut buf)
                .map_err(|e| anyhow::anyhow!("scenario {} frame {k}: {e}", self.name))?;
            out.extend_from_slice(&buf);
        }
        Ok(out)
    }

    /// Its file under `dir`.
    pub fn path(&self, dir: &Path) -> PathBuf {
        dir.join(format!("{}.{EXTENSION}", self.name))
    }
}

/// All scenarios, in order.
///
/// # Errors
/// The bundled labels cannot be read.
pub fn scenarios() -> Result<Vec<Scenario>> {
    Ok(vec![typical()?, worst(), worst_patterns()])
}

/// Writes every scenario file into `dir`; returns the paths.
///
/// # Errors
/// I/O, or a scenario that cannot be encoded.
pub fn write_all(dir: &Path) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut paths = Vec::new();
    for s in scenarios()? {
        let p = s.path(dir);
        std::fs::write(&p, s.encode()?).with_context(|| format!("writing {}", p.display()))?;
        paths.push(p);
    }
    Ok(paths)
}

fn typical() -> Result<Scenario> {
    let labels = crate::demo::replay_labels()?;
    let label = labels.first().context("no bundled label")?;
    let params = SynthParams {
        frames_per_clip: 60,
        ..SynthParams::preset(NoiseLevel::Mid)
    };
    let cam = Camera::tusimple();
    let clip = synth_clip(label, 0, &params, &cam, 1);
    let frames = clip
        .frames
        .iter()
        .map(|f| {
            let bev: Vec<(f64, f64)> = f
                .points
                .iter()
                .filter_map(|p| cam.to_bev(p[0], p[1]))
                .collect();
            let mut pts = preprocess(&bev, &DEFAULT);
            pts.truncate(MEAS);
            pts
        })
        .collect();
    Ok(Scenario {
        name: "typical",
        frames,
    })
}

fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = 1.0 - rng.random::<f32>();
    let u2: f32 = rng.random::<f32>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
}

fn lane_x(t: usize) -> f32 {
    -9.0 + 3.6 * t as f32
}

fn row_u(r: usize) -> f32 {
    DEFAULT.hyper.u_min + r as f32 * (DEFAULT.hyper.u_max - DEFAULT.hyper.u_min) / 60.0
}

/// Lead-in rows: one point per lane, σ = 0.1 m.
fn lead_in(rng: &mut ChaCha8Rng, pts: &mut Vec<[f32; 2]>) {
    for r in 0..LEAD_IN_ROWS {
        for t in 0..LANES {
            pts.push([row_u(r), lane_x(t) + 0.1 * normal(rng)]);
        }
    }
}

/// 12 frames from `seed`: each the lead-in, then the rows `fill(rng, pts, r)` adds from row
/// `r = LEAD_IN_ROWS` on.
fn after_lead_in(
    seed: u64,
    mut fill: impl FnMut(&mut ChaCha8Rng, &mut Vec<[f32; 2]>, usize),
) -> Vec<Vec<[f32; 2]>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..12)
        .map(|_| {
            let mut pts = Vec::with_capacity(MEAS);
            lead_in(&mut rng, &mut pts);
            fill(&mut rng, &mut pts, LEAD_IN_ROWS);
            pts
        })
        .collect()
}

fn worst() -> Scenario {
    let frames = after_lead_in(9, |rng, pts, mut r| {
        while pts.len() + PER_ROW <= MEAS {
            let u = row_u(r);
            for t in 0..LANES {
                pts.push([u, lane_x(t) + 0.1 * normal(rng)]);
            }
            for _ in LANES..PER_ROW {
                let t = rng.random_range(0..LANES);
                pts.push([u, lane_x(t) + (rng.random::<f32>() * 2.0 - 1.0) * 0.4]);
            }
            r += 1;
        }
    });
    Scenario {
        name: "worst",
        frames,
    }
}

fn worst_patterns() -> Scenario {
    let frames = after_lead_in(10, |rng, pts, mut r| {
        while pts.len() + 2 * LANES - 1 <= MEAS && r <= 60 {
            let u = row_u(r);
            let single = r % LANES;
            for t in 0..LANES {
                let x = lane_x(t);
                if t == single {
                    pts.push([u, x + 0.1 * normal(rng)]);
                } else {
                    pts.push([u, x - 0.3 * rng.random::<f32>()]);
                    pts.push([u, x + 0.3 * rng.random::<f32>()]);
                }
            }
            r += 1;
        }
        while pts.len() + LANES <= MEAS && r <= 60 {
            for t in 0..LANES {
                pts.push([row_u(r), lane_x(t) + 0.1 * normal(rng)]);
            }
            r += 1;
        }
    });
    Scenario {
        name: "worst_patterns",
        frames,
    }
}

/// Checks that the files under `dir` are what [`scenarios`] generates; returns the names.
///
/// # Errors
/// A missing or different file.
pub fn check_all(dir: &Path) -> Result<Vec<&'static str>> {
    let mut names = Vec::new();
    for s in scenarios()? {
        let p = s.path(dir);
        let have = std::fs::read(&p).with_context(|| format!("reading {}", p.display()))?;
        ensure!(
            have == s.encode()?,
            "{} is not what the generator writes: run `cargo xtask firmware-scenarios`",
            p.display()
        );
        names.push(s.name);
    }
    Ok(names)
}
