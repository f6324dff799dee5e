//! The frame sequences every bench uses, seeded and built before timing.
//!
//! A sequence is a list of frames (BEV points `(u, x)` in metres, near rows first as the scene
//! generator writes them); a bench cycles through it with frames 50 ms apart, so time always
//! increases. Each point exists in f32 (the core) and f64 (the reference), from the same f32
//! values.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stjpdacf_tools::scenario::{Scenario, ScenarioConfig};

/// Nominal frame step, µs.
pub const STEP_US: i64 = 50_000;

/// One frame's points for the core and the reference.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// `[u, x]` for the core.
    pub p32: Vec<[f32; 2]>,
    /// `(u, x)` for the reference (the same values).
    pub p64: Vec<(f64, f64)>,
}

impl Frame {
    /// A frame from f32 points.
    pub fn from_f32(p32: Vec<[f32; 2]>) -> Self {
        let p64 = p32
            .iter()
            .map(|p| (f64::from(p[0]), f64::from(p[1])))
            .collect();
        Self { p32, p64 }
    }

    /// The first `m` points only (what a tracker with `MEAS = m` uses).
    pub fn truncated(&self, m: usize) -> Self {
        Self::from_f32(self.p32.iter().copied().take(m).collect())
    }
}

/// `n` frames of `cfg`, frame `k` from seed `seed · 1000 + k`.
pub fn scenario_frames(cfg: &ScenarioConfig, seed: u64, n: u64) -> Vec<Frame> {
    (0..n)
        .map(|k| {
            let sc = Scenario::generate(cfg, seed * 1000 + k);
            Frame::from_f32(
                sc.points
                    .iter()
                    .map(|&(u, x)| [u as f32, x as f32])
                    .collect(),
            )
        })
        .collect()
}

/// **typical** — 20 frames of 3 straight lanes (x = −5.4, −1.8, 1.8 m), clutter 0.02 /m over
/// ±12 m, `P_D = 0.9`, σ = 0.1 m, all 61 rows: 186–203 points per frame (seed 4; the tracker
/// bench's input since the first tracker benches).
pub fn typical() -> Vec<Frame> {
    let cfg = ScenarioConfig {
        clutter_density: 0.02,
        ..ScenarioConfig::default()
    };
    scenario_frames(&cfg, 4, 20)
}

/// `lanes` straight lanes 3.6 m apart centred on x = 0 (x = −9 … 9 m for 6), rows every 77/40 m
/// (41 rows), clutter 0.04 /m over ±12 m, `P_D = 0.9`, σ = 0.1 m; 8 frames from seed 9.
pub fn lanes(lanes: usize) -> Vec<Frame> {
    let cfg = ScenarioConfig {
        lanes,
        spacing: (3.6, 3.6),
        left: -((lanes as f64 - 1.0) * 3.6) / 2.0,
        row_step: 77.0 / 40.0,
        clutter_density: 0.04,
        ..ScenarioConfig::default()
    };
    scenario_frames(&cfg, 9, 8)
}

/// **worst** — [`lanes`]`(6)`: 6 lanes, 246–267 points per frame, the first M = 256 used (the
/// tracker bench's worst case since the first tracker benches; no row exceeds E = 512 events).
pub fn worst() -> Vec<Frame> {
    lanes(6)
}

/// **dense** — 6 lanes 3.6 m apart on all 61 rows and uniform clutter 0.35 /m over ±12 m
/// (about 5.4 lane and 8.4 clutter points a row, 770–880 points a frame); 8 frames from seed 11.
/// The input of the M axis: a tracker with budget `M` uses the first `M` points (the nearest
/// rows), so every frame fills the budget.
pub fn dense() -> Vec<Frame> {
    let cfg = ScenarioConfig {
        lanes: 6,
        spacing: (3.6, 3.6),
        left: -9.0,
        clutter_density: 0.35,
        ..ScenarioConfig::default()
    };
    scenario_frames(&cfg, 11, 8)
}

fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = 1.0 - rng.random::<f32>();
    let u2: f32 = rng.random::<f32>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
}

/// Rows of an adversarial frame with only the 6 lane points (they let all 6 spatial tracks start
/// and confirm).
pub const LEAD_IN_ROWS: usize = 16;

/// **adversarial** — [`adversarial_points`]`(256)`: 8 frames of exactly 256 points, the spatial
/// bench's worst-case frame (`bench/benches/spatial.rs`): rows 0–15 hold one point per lane,
/// rows 16–25 hold 16 points each. Their events exceed E = 512 and are pruned: the input of the
/// E axis and the bounded worst case of a frame.
pub fn adversarial() -> Vec<Frame> {
    adversarial_points(256)
}

/// 8 frames (seeds 0–7) of exactly `m` points (`m ≤ 816`): 6 straight lanes 3.6 m apart
/// (x = −9 … 9 m); rows 0–15 ([`LEAD_IN_ROWS`]) hold one point per lane (σ = 0.1 m), the next
/// rows 16 points each, the 6 lane points and 10 points within ±0.4 m of a random lane (inside
/// its gate); the frame is cut after `m` points. The worst case of a budget of `m` points.
pub fn adversarial_points(m: usize) -> Vec<Frame> {
    const LANES: usize = 6;
    const PER_ROW: usize = 16;
    let du = 77.0f32 / 60.0;
    (0..8u64)
        .map(|seed| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut pts = Vec::with_capacity(m + PER_ROW);
            let lane_x = |t: usize| (t as f32 - (LANES as f32 - 1.0) / 2.0) * 3.6;
            let mut r = 0usize;
            while pts.len() < m && r < 61 {
                let u = 3.0 + r as f32 * du;
                for t in 0..LANES {
                    pts.push([u, lane_x(t) + 0.1 * normal(&mut rng)]);
                }
                if r >= LEAD_IN_ROWS {
                    for _ in LANES..PER_ROW {
                        let t = rng.random_range(0..LANES);
                        pts.push([u, lane_x(t) + (rng.random::<f32>() * 2.0 - 1.0) * 0.4]);
                    }
                }
                r += 1;
            }
            pts.truncate(m);
            Frame::from_f32(pts)
        })
        .collect()
}

/// A named sequence (for reports).
#[derive(Debug, Clone, PartialEq)]
pub struct Sequence {
    /// Short name (`typical`, `worst`, `adversarial`).
    pub name: &'static str,
    /// One-line description.
    pub what: &'static str,
    /// The frames.
    pub frames: Vec<Frame>,
}

/// The three sequences of the tracker and stage benches.
pub fn sequences() -> Vec<Sequence> {
    vec![
        Sequence {
            name: "typical",
            what: "3 straight lanes, clutter 0.02 /m, 61 rows, 186–203 points",
            frames: typical(),
        },
        Sequence {
            name: "worst",
            what: "6 lanes 3.6 m apart, 41 rows, clutter 0.04 /m, first 256 of 246–267 points",
            frames: worst(),
        },
        Sequence {
            name: "adversarial",
            what: "6 lanes, 16 lead-in rows + 10 rows of 16 points near the lanes: 256 points, rows over E",
            frames: adversarial(),
        },
    ]
}
