//! Seeded synthetic BEV frames for the spatial filter: a few lanes with a shared smooth shape,
//! per-row detections, lateral noise, uniform clutter, missed rows and merges or splits.
//!
//! Lane `d` sits at `x_d(u) = base_d + g(u)`, where the bases are spaced uniformly in
//! [`ScenarioConfig::spacing`] from [`ScenarioConfig::left`] and `g` is one shared curve
//! ([`Shape`]): straight, a draw from the RBF prior (sampled on a 1 m grid by an eigen
//! decomposition of the Gram matrix, linearly interpolated), or a clothoid
//! `g(u) = κ₀ (u − u_min)²/2 + κ₁ (u − u_min)³/6`. A [`Junction`] moves lane `lane + 1` onto lane
//! `lane` (merge) or away from it (split) with a smoothstep; where the two coincide only lane
//! `lane` produces points (they share points).
//!
//! Points are generated on rows `u_r = u_min + r·row_step` (`u_r ≤ u_max`), optionally jittered in
//! `u`: each lane present at the row and not in a [`Gap`] is detected with probability `pd`, at
//! `x_d(u_r) + N(0, σ²)`; clutter is Poisson with mean `clutter_density · (x_max − x_min)` per row,
//! uniform in `clutter_x`. A row's points are shuffled. Everything is drawn from one
//! `ChaCha8Rng::seed_from_u64(seed)`, so a seed gives the same frame on every platform.

use nalgebra::{DMatrix, DVector};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The shared shape `g(u)` of the lanes.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// `g = 0`.
    Straight,
    /// A draw from the zero-mean RBF prior `σ² exp(−d²/(2ℓ²))`.
    Rbf {
        /// σ², m².
        variance: f64,
        /// ℓ, m.
        lengthscale: f64,
    },
    /// A clothoid with curvature `κ₀` drawn uniformly in `±max_curvature` (1/m) and curvature rate
    /// `κ₁` uniformly in `±max_rate` (1/m²).
    Clothoid {
        /// Largest |κ₀|.
        max_curvature: f64,
        /// Largest |κ₁|.
        max_rate: f64,
    },
}

/// A merge or a split of two neighbouring lanes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Junction {
    /// The lane that stays; lane `lane + 1` moves onto (merge) or away from (split) it.
    pub lane: usize,
    /// `true`: merge (separate below `u_start`, one lane above `u_end`); `false`: split (one lane
    /// below `u_start`, separate above `u_end`).
    pub merge: bool,
    /// Start of the transition, m.
    pub u_start: f64,
    /// End of the transition, m.
    pub u_end: f64,
}

/// An interval of `u` in which a lane (or every lane) produces no points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// The lane, or `None` for all lanes.
    pub lane: Option<usize>,
    /// Start, m.
    pub u0: f64,
    /// End, m.
    pub u1: f64,
}

/// What to generate.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioConfig {
    /// Number of true lanes.
    pub lanes: usize,
    /// Spacing between neighbouring lanes is uniform in this range, m.
    pub spacing: (f64, f64),
    /// Lateral position of the leftmost lane's base, m.
    pub left: f64,
    /// Shared lane shape.
    pub shape: Shape,
    /// Window start, m.
    pub u_min: f64,
    /// Window end, m.
    pub u_max: f64,
    /// Spacing of the generated rows, m.
    pub row_step: f64,
    /// Each row's `u` is jittered uniformly by `± row_jitter · row_step / 2`.
    pub row_jitter: f64,
    /// Detection probability of a lane in a row.
    pub pd: f64,
    /// Lateral noise σ, m.
    pub sigma: f64,
    /// Clutter points per metre of lateral extent per row.
    pub clutter_density: f64,
    /// Lateral range of the clutter, m.
    pub clutter_x: (f64, f64),
    /// Missed stretches.
    pub gaps: Vec<Gap>,
    /// Optional merge or split.
    pub junction: Option<Junction>,
    /// Per-lane `u` range in which the lane exists (`None`: the whole window).
    pub lane_ranges: Vec<Option<(f64, f64)>>,
}

impl ScenarioConfig {
    /// The default lanes curved (RBF shape, σ² = 4 m², ℓ = 35 m), with clutter 0.05 /m over
    /// ±12 m: the typical frame of the spatial benches and tests.
    pub fn curved() -> Self {
        Self {
            shape: Shape::Rbf {
                variance: 4.0,
                lengthscale: 35.0,
            },
            clutter_density: 0.05,
            ..Self::default()
        }
    }
}

impl Default for ScenarioConfig {
    /// Three straight lanes 3.5–3.7 m apart from x = −5.4 m over 3–80 m, rows every 77/60 m,
    /// `P_D = 0.9`, σ = 0.1 m, no clutter, no gaps, no junction.
    fn default() -> Self {
        Self {
            lanes: 3,
            spacing: (3.5, 3.7),
            left: -5.4,
            shape: Shape::Straight,
            u_min: 3.0,
            u_max: 80.0,
            row_step: 77.0 / 60.0,
            row_jitter: 0.0,
            pd: 0.9,
            sigma: 0.1,
            clutter_density: 0.0,
            clutter_x: (-12.0, 12.0),
            gaps: Vec::new(),
            junction: None,
            lane_ranges: Vec::new(),
        }
    }
}

/// The shared curve as drawn.
#[derive(Debug, Clone, PartialEq)]
pub enum Curve {
    /// `g = 0`.
    Straight,
    /// Samples `values[i] = g(u0 + i·step)`, linearly interpolated (held constant outside).
    Grid {
        /// First sample's `u`.
        u0: f64,
        /// Sample spacing.
        step: f64,
        /// Samples.
        values: Vec<f64>,
    },
    /// `κ₀ (u − u0)²/2 + κ₁ (u − u0)³/6`.
    Clothoid {
        /// Origin.
        u0: f64,
        /// Curvature κ₀.
        k0: f64,
        /// Curvature rate κ₁.
        k1: f64,
    },
}

impl Curve {
    /// `g(u)`.
    pub fn at(&self, u: f64) -> f64 {
        match self {
            Curve::Straight => 0.0,
            Curve::Grid { u0, step, values } => {
                let Some(&last) = values.last() else {
                    return 0.0;
                };
                let t = (u - u0) / step;
                if t <= 0.0 {
                    return values[0];
                }
                let i = t.floor() as usize;
                if i + 1 >= values.len() {
                    return last;
                }
                let f = t - i as f64;
                values[i] * (1.0 - f) + values[i + 1] * f
            }
            Curve::Clothoid { u0, k0, k1 } => {
                let d = u - u0;
                k0 * d * d / 2.0 + k1 * d * d * d / 6.0
            }
        }
    }
}

/// A generated frame and its ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// The points `(u, x)`, row by row (shuffled within a row).
    pub points: Vec<(f64, f64)>,
    /// For each point, the lane it came from (`None`: clutter).
    pub source: Vec<Option<usize>>,
    /// Lane bases, left to right.
    pub bases: Vec<f64>,
    /// The shared curve.
    pub curve: Curve,
    /// The configuration the frame was drawn from.
    pub config: ScenarioConfig,
}

fn smoothstep(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller.
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

fn poisson(rng: &mut ChaCha8Rng, mean: f64) -> usize {
    // Knuth's method (the means used here are small).
    if mean <= 0.0 {
        return 0;
    }
    let l = (-mean).exp();
    let mut k = 0;
    let mut p = 1.0;
    loop {
        p *= rng.random::<f64>();
        if p <= l {
            return k;
        }
        k += 1;
    }
}

impl Scenario {
    /// Generates the frame of `cfg` for `seed`.
    pub fn generate(cfg: &ScenarioConfig, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut bases = Vec::with_capacity(cfg.lanes);
        let mut x = cfg.left;
        for d in 0..cfg.lanes {
            if d > 0 {
                x += rng.random_range(cfg.spacing.0..=cfg.spacing.1);
            }
            bases.push(x);
        }
        let curve = match cfg.shape {
            Shape::Straight => Curve::Straight,
            Shape::Rbf {
                variance,
                lengthscale,
            } => {
                let step = 1.0;
                let n = ((cfg.u_max - cfg.u_min) / step).ceil() as usize + 2;
                let k = DMatrix::from_fn(n, n, |i, j| {
                    let d = (i as f64 - j as f64) * step;
                    variance * (-d * d / (2.0 * lengthscale * lengthscale)).exp()
                });
                let eig = k.symmetric_eigen();
                let z = DVector::from_fn(n, |_, _| normal(&mut rng));
                let scaled = DVector::from_fn(n, |i, _| eig.eigenvalues[i].max(0.0).sqrt() * z[i]);
                let v = &eig.eigenvectors * scaled;
                Curve::Grid {
                    u0: cfg.u_min,
                    step,
                    values: v.iter().copied().collect(),
                }
            }
            Shape::Clothoid {
                max_curvature,
                max_rate,
            } => Curve::Clothoid {
                u0: cfg.u_min,
                k0: rng.random_range(-max_curvature..=max_curvature),
                k1: rng.random_range(-max_rate..=max_rate),
            },
        };
        let mut sc = Scenario {
            points: Vec::new(),
            source: Vec::new(),
            bases,
            curve,
            config: cfg.clone(),
        };
        let mut r = 0usize;
        loop {
            let u_nom = cfg.u_min + r as f64 * cfg.row_step;
            if u_nom > cfg.u_max + 1e-9 {
                break;
            }
            r += 1;
            let u = u_nom + (rng.random::<f64>() - 0.5) * cfg.row_jitter * cfg.row_step;
            let mut row: Vec<((f64, f64), Option<usize>)> = Vec::new();
            for d in 0..cfg.lanes {
                let detected = rng.random::<f64>() < cfg.pd;
                let noise = normal(&mut rng) * cfg.sigma;
                if detected && sc.emits(d, u) {
                    row.push(((u, sc.lane_x(d, u) + noise), Some(d)));
                }
            }
            let width = cfg.clutter_x.1 - cfg.clutter_x.0;
            for _ in 0..poisson(&mut rng, cfg.clutter_density * width) {
                let x = cfg.clutter_x.0 + rng.random::<f64>() * width;
                row.push(((u, x), None));
            }
            row.shuffle(&mut rng);
            for (p, s) in row {
                sc.points.push(p);
                sc.source.push(s);
            }
        }
        sc
    }

    /// Transition weight of the junction's moving lane at `u`: 0 = at its own position,
    /// 1 = on the staying lane.
    fn junction_weight(&self, lane: usize, u: f64) -> Option<f64> {
        let j = self.config.junction?;
        if lane != j.lane + 1 {
            return None;
        }
        let s = smoothstep((u - j.u_start) / (j.u_end - j.u_start));
        Some(if j.merge { s } else { 1.0 - s })
    }

    /// True lateral position of lane `lane` at `u`.
    pub fn lane_x(&self, lane: usize, u: f64) -> f64 {
        let own = self.bases.get(lane).copied().unwrap_or(0.0) + self.curve.at(u);
        match self.junction_weight(lane, u) {
            Some(s) => {
                let stay = self.lane_x(lane - 1, u);
                own + s * (stay - own)
            }
            None => own,
        }
    }

    /// Whether lane `lane` exists at `u` (its range).
    pub fn lane_present(&self, lane: usize, u: f64) -> bool {
        match self.config.lane_ranges.get(lane).copied().flatten() {
            Some((a, b)) => u >= a && u <= b,
            None => true,
        }
    }

    /// Whether lane `lane` produces a point at `u` when detected: present, not in a gap, and not
    /// coinciding with the lane it merges into (shared points).
    pub fn emits(&self, lane: usize, u: f64) -> bool {
        self.lane_present(lane, u)
            && !self
                .config
                .gaps
                .iter()
                .any(|g| g.lane.is_none_or(|l| l == lane) && u >= g.u0 && u <= g.u1)
            && self.junction_weight(lane, u).is_none_or(|s| s < 1.0 - 1e-9)
    }
}

/// The seeded 25-frame sequences of the tracker equivalence tests (and the rank study): 20 fps,
/// lanes drifting 2 cm a frame to the right, the frames after 6 and 15 coming after steps of
/// 100 ms and 250 ms (2× and 5×), frames 10–12 empty (blackout), a third lane appearing at frame
/// `appear`. `(timestamp µs, points [u, x])` per frame.
pub fn equivalence_sequence(seed: u64, clutter: f64, appear: usize) -> Vec<(i64, Vec<[f32; 2]>)> {
    let mut us = 0i64;
    let mut frames = Vec::new();
    for k in 0..25usize {
        us += match k {
            0 => 0,
            7 => 100_000,
            16 => 250_000,
            _ => 50_000,
        };
        let pts = if (10..13).contains(&k) {
            Vec::new()
        } else {
            let cfg = ScenarioConfig {
                lanes: if k < appear { 2 } else { 3 },
                left: -5.4 + 0.02 * k as f64,
                clutter_density: clutter,
                ..ScenarioConfig::default()
            };
            Scenario::generate(&cfg, seed * 1000 + k as u64)
                .points
                .iter()
                .map(|&(u, x)| [u as f32, x as f32])
                .collect()
        };
        frames.push((us, pts));
    }
    frames
}
