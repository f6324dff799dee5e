//! A per-frame baseline: sequential-RANSAC quadratics in the bird's-eye view, no tracking.
//!
//! What a lane-perception engineer would write instead of a tracker: each frame on its own, the
//! points the tracker gets ([`track::bev_points`] then [`track::preprocess`]: image → BEV, binned
//! to the spatial filter's rows, clustered, restricted to the window), then **sequential RANSAC**
//! ([`fit_frame`]):
//!
//! 1. Hypotheses: [`BaselineParams::iterations`] random triples of the remaining points (their
//!    `u` at least [`BaselineParams::min_sample_gap`] apart), each the quadratic
//!    `x(u) = a + b·u + c·u²` through its three points. A hypothesis's consensus is the points
//!    within [`BaselineParams::inlier_tol`] of it laterally; it counts only when they span at
//!    least [`BaselineParams::min_extent`] metres of `u`. The largest consensus wins (the first
//!    drawn among equals).
//! 2. The winner is refitted by least squares on its inliers, its inliers are collected again
//!    around the refit and it is refitted once more. It is a lane when it keeps at least
//!    [`BaselineParams::min_inliers`] inliers spanning at least `min_extent`; otherwise the search
//!    stops.
//! 3. Its inliers are removed and the search repeats, up to [`BaselineParams::max_lanes`] lanes.
//!
//! A lane is written ([`track()`]) at the frame's `h_samples` rows through the inverse IPM exactly
//! as the tracker's lanes are ([`track::lane_columns`], [`track::lanes_record`]), but only
//! within the `u` range of its inliers: no extrapolation, neither towards the horizon nor below
//! the window.
//!
//! Deterministic: every frame draws from a ChaCha8 generator seeded with
//! [`BaselineParams::seed`], so a frame's lanes depend on its points only.
//!
//! **Parameters** ([`BaselineParams::default`]), chosen once on the bundled replay at the mid
//! preset (the 40 labels of `data/tusimple/train_subset.json`, seed 1, 20 frames per clip), by
//! the best official accuracy on the clips' labelled last frames over the grid of the
//! `baseline_sweep` example (inlier tolerance 0.2 / 0.3 / 0.5 / 0.75 m, minimum inliers
//! 4 / 6 / 8 / 10 / 15, minimum extent 5 / 10 / 20 m), and not tuned per noise level, clutter
//! level or experiment: 0.2 m, 4 inliers, 10 m (last-frame accuracy 0.847; 5 m gives the same,
//! 20 m 0.845; 0.3 m 0.844; 6 inliers 0.843; 10 inliers 0.708 — dashed lanes with per-row misses
//! leave few points in the window). Fewer inliers are hardly a test: three points define a
//! hypothesis. The iteration count (1000) samples a lane holding a tenth of the remaining points
//! with probability 1 − (1 − 0.1³)¹⁰⁰⁰ ≈ 0.63, and almost surely for the larger shares lanes hold
//! in the bundled frames.

use std::time::Instant as WallClock;

use anyhow::Result;
use cpu_time::ThreadTime;
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use stjpdacf::tables::ReferenceTables;

use crate::camera::Camera;
use crate::track::{self, RunTimes, Space, TrackStats};
use crate::tusimple::{Frame, TuSimpleRecord};

/// The baseline's parameters (see the module doc for how the defaults were chosen).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BaselineParams {
    /// Lateral distance (m) within which a point is an inlier of a quadratic.
    pub inlier_tol: f64,
    /// Inliers a lane needs.
    pub min_inliers: usize,
    /// Extent ahead (m) a lane's inliers must span.
    pub min_extent: f64,
    /// Hypotheses per lane.
    pub iterations: usize,
    /// Most lanes per frame.
    pub max_lanes: usize,
    /// Smallest distance ahead (m) between two points of a hypothesis's sample.
    pub min_sample_gap: f64,
    /// Seed of every frame's generator.
    pub seed: u64,
}

impl Default for BaselineParams {
    fn default() -> Self {
        Self {
            inlier_tol: 0.2,
            min_inliers: 4,
            min_extent: 10.0,
            iterations: 1000,
            max_lanes: 6,
            min_sample_gap: 1.0,
            seed: 0,
        }
    }
}

/// One fitted lane: `x(u) = a + b·u + c·u²` over `[u_min, u_max]` (its inliers' extent).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Lane {
    /// Constant term, m.
    pub a: f64,
    /// Linear term.
    pub b: f64,
    /// Quadratic term, 1/m.
    pub c: f64,
    /// Nearest inlier, m ahead.
    pub u_min: f64,
    /// Farthest inlier, m ahead.
    pub u_max: f64,
    /// Number of inliers.
    pub inliers: usize,
}

impl Lane {
    /// The quadratic at `u` (no extent check).
    pub fn x_at(&self, u: f64) -> f64 {
        quad_at((self.a, self.b, self.c), u)
    }

    /// The lane at `u` inside its extent, `None` outside.
    pub fn x_within(&self, u: f64) -> Option<f64> {
        (u >= self.u_min && u <= self.u_max).then(|| self.x_at(u))
    }
}

type Quad = (f64, f64, f64);

fn quad_at((a, b, c): Quad, u: f64) -> f64 {
    a + u * (b + u * c)
}

/// The quadratic through three points with distinct `u` (Newton's divided differences).
fn through(p: [(f64, f64); 3]) -> Option<Quad> {
    let [(u0, x0), (u1, x1), (u2, x2)] = p;
    let f01 = (x1 - x0) / (u1 - u0);
    let f12 = (x2 - x1) / (u2 - u1);
    let c = (f12 - f01) / (u2 - u0);
    let q = (x0 - f01 * u0 + c * u0 * u1, f01 - c * (u0 + u1), c);
    (q.0.is_finite() && q.1.is_finite() && q.2.is_finite()).then_some(q)
}

/// Least-squares quadratic through `pts` (centred and scaled in `u` for conditioning); `None`
/// when they do not determine one (fewer than three distinct `u`).
fn least_squares(pts: &[(f64, f64)]) -> Option<Quad> {
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let m = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let s = pts
        .iter()
        .map(|p| (p.0 - m).abs())
        .fold(0.0_f64, f64::max)
        .max(1e-9);
    let mut ata = Matrix3::<f64>::zeros();
    let mut atx = Vector3::<f64>::zeros();
    for &(u, x) in pts {
        let t = (u - m) / s;
        let row = Vector3::new(1.0, t, t * t);
        ata += row * row.transpose();
        atx += row * x;
    }
    let sol = ata.cholesky()?.solve(&atx);
    let (al, be, ga) = (sol[0], sol[1], sol[2]);
    // x = al + be·t + ga·t², t = (u − m)/s.
    let c = ga / (s * s);
    let b = be / s - 2.0 * ga * m / (s * s);
    let a = al - be * m / s + ga * m * m / (s * s);
    (a.is_finite() && b.is_finite() && c.is_finite()).then_some((a, b, c))
}

/// The points of `pts` within `tol` of `q`, and their extent ahead.
fn consensus(pts: &[(f64, f64)], q: Quad, tol: f64) -> (usize, f64) {
    let (mut n, mut lo, mut hi) = (0, f64::INFINITY, f64::NEG_INFINITY);
    for &(u, x) in pts {
        if (x - quad_at(q, u)).abs() <= tol {
            n += 1;
            lo = lo.min(u);
            hi = hi.max(u);
        }
    }
    (n, if n > 0 { hi - lo } else { 0.0 })
}

fn inliers(pts: &[(f64, f64)], q: Quad, tol: f64) -> Vec<(f64, f64)> {
    pts.iter()
        .copied()
        .filter(|&(u, x)| (x - quad_at(q, u)).abs() <= tol)
        .collect()
}

/// The best-supported hypothesis among `p.iterations` random triples (see the module doc).
fn best_hypothesis(pts: &[(f64, f64)], p: &BaselineParams, rng: &mut ChaCha8Rng) -> Option<Quad> {
    let mut best: Option<(usize, Quad)> = None;
    for _ in 0..p.iterations {
        let i = rng.random_range(0..pts.len());
        let j = rng.random_range(0..pts.len());
        let k = rng.random_range(0..pts.len());
        let mut s = [pts[i], pts[j], pts[k]];
        s.sort_by(|a, b| a.0.total_cmp(&b.0));
        if s[1].0 - s[0].0 < p.min_sample_gap || s[2].0 - s[1].0 < p.min_sample_gap {
            continue;
        }
        let Some(q) = through(s) else { continue };
        let (n, extent) = consensus(pts, q, p.inlier_tol);
        if extent >= p.min_extent && best.is_none_or(|(m, _)| n > m) {
            best = Some((n, q));
        }
    }
    best.map(|(_, q)| q)
}

/// Sequential RANSAC on one frame's BEV points `(u, x)` (see the module doc): the lanes found, in
/// the order found. Non-finite points are ignored.
pub fn fit_frame(points: &[(f64, f64)], p: &BaselineParams) -> Vec<Lane> {
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let mut left: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|(u, x)| u.is_finite() && x.is_finite())
        .collect();
    let mut lanes = Vec::new();
    let need = p.min_inliers.max(3);
    while lanes.len() < p.max_lanes && left.len() >= need {
        let Some(q) = best_hypothesis(&left, p, &mut rng) else {
            break;
        };
        let Some(q) = least_squares(&inliers(&left, q, p.inlier_tol)) else {
            break;
        };
        let inl = inliers(&left, q, p.inlier_tol);
        let q = least_squares(&inl).unwrap_or(q);
        let inl = inliers(&left, q, p.inlier_tol);
        let lo = inl.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
        let hi = inl.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
        if inl.len() < need || hi - lo < p.min_extent {
            break;
        }
        left.retain(|&(u, x)| (x - quad_at(q, u)).abs() > p.inlier_tol);
        lanes.push(Lane {
            a: q.0,
            b: q.1,
            c: q.2,
            u_min: lo,
            u_max: hi,
            inliers: inl.len(),
        });
    }
    lanes
}

/// The TuSimple record of `lanes` at `rows` (each within its extent, through the inverse IPM of
/// `cam`, left to right by the position of its near end).
pub fn lanes_record(
    lanes: &[Lane],
    cam: &Camera,
    raw_file: &str,
    rows: &[f64],
    run_time: Option<f64>,
) -> TuSimpleRecord {
    track::lanes_record(
        raw_file,
        rows,
        lanes.iter().map(|l| {
            (
                l.x_at(l.u_min),
                track::lane_columns(cam, rows, |u| l.x_within(u)),
            )
        }),
        run_time,
    )
}

/// Runs the baseline over `frames` as [`track::track`] runs the tracker: the same points (BEV
/// through `cam`, [`track::preprocess`] with `tables`' window and rows), each frame on its own;
/// returns the predictions for the frames with `h_samples` (`run_time`: the wall time from the
/// frame's points to its lanes) and the counters (`step_*`: the RANSAC time; no step is ever
/// rejected). `progress(k)` is called after frame `k`.
///
/// # Errors
/// A frame that fails [`Frame::check`].
pub fn track(
    frames: &[Frame],
    tables: &ReferenceTables,
    cam: &Camera,
    space: Space,
    params: &BaselineParams,
    mut progress: impl FnMut(usize),
) -> Result<(Vec<TuSimpleRecord>, TrackStats)> {
    let mut stats = TrackStats::default();
    let mut out = Vec::new();
    let mut clip: Option<&str> = None;
    let mut times = RunTimes::default();
    for (k, f) in frames.iter().enumerate() {
        stats.begin_frame(k, f, &mut clip)?;
        let start = WallClock::now();
        let bev = track::bev_points(f, cam, space, &mut stats.unmapped_points);
        let pts: Vec<(f64, f64)> = track::preprocess(&bev, tables)
            .iter()
            .map(|p| (f64::from(p[0]), f64::from(p[1])))
            .collect();
        let fit_start = ThreadTime::now();
        let lanes = fit_frame(&pts, params);
        stats.add_step(&mut times, fit_start.elapsed().as_secs_f64() * 1e3);
        let prediction = match (&f.raw_file, &f.h_samples) {
            (Some(raw), Some(rows)) => Some(lanes_record(&lanes, cam, raw, rows, None)),
            _ => None,
        };
        let run_ms = start.elapsed().as_secs_f64() * 1e3;
        stats.add_run(&mut times, run_ms);
        if let Some(p) = prediction {
            out.push(TuSimpleRecord {
                run_time: Some(run_ms),
                ..p
            });
            stats.predictions += 1;
        }
        progress(k);
    }
    stats.finish(&times);
    Ok((out, stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    /// Three lanes 3.6 m apart on a gentle curve.
    const LANES: [Quad; 3] = [(-5.4, 0.012, 4e-4), (-1.8, 0.010, 4e-4), (1.8, 0.008, 4e-4)];

    /// The three lanes at the tracker's 61 rows over 3–80 m, plus `clutter` uniform points over
    /// the window and ±10 m.
    fn frame(clutter: usize, seed: u64) -> Vec<(f64, f64)> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut pts = Vec::new();
        for r in 0..=60 {
            let u = 3.0 + 77.0 * f64::from(r) / 60.0;
            for q in LANES {
                pts.push((u, quad_at(q, u)));
            }
        }
        for _ in 0..clutter {
            pts.push((rng.random_range(3.0..80.0), rng.random_range(-10.0..10.0)));
        }
        pts
    }

    #[test]
    fn three_exact_lanes_in_clutter_are_recovered() {
        for seed in 0..5 {
            let lanes = fit_frame(&frame(60, seed), &BaselineParams::default());
            // The three lanes come first (largest consensus); anything found after them in the
            // clutter is small.
            assert!((3..=6).contains(&lanes.len()), "seed {seed}: {lanes:?}");
            assert!(
                lanes[3..].iter().all(|l| l.inliers < 12),
                "seed {seed}: {lanes:?}"
            );
            for q in LANES {
                let l = lanes[..3]
                    .iter()
                    .min_by(|x, y| (x.a - q.0).abs().total_cmp(&(y.a - q.0).abs()))
                    .unwrap();
                assert!((l.a - q.0).abs() < 0.1, "seed {seed}: {l:?} vs {q:?}");
                assert!((l.b - q.1).abs() < 5e-3, "seed {seed}: {l:?} vs {q:?}");
                assert!((l.c - q.2).abs() < 5e-5, "seed {seed}: {l:?} vs {q:?}");
                assert!(l.inliers >= 61, "seed {seed}: {l:?}");
                assert!(l.u_min < 4.0 && l.u_max > 79.0, "seed {seed}: {l:?}");
                for u in [5.0, 40.0, 75.0] {
                    assert!((l.x_at(u) - quad_at(q, u)).abs() < 0.1, "{l:?} at {u}");
                }
            }
        }
    }

    #[test]
    fn empty_and_degenerate_frames_give_no_lanes() {
        let p = BaselineParams::default();
        assert!(fit_frame(&[], &p).is_empty());
        assert!(fit_frame(&[(10.0, 1.0), (20.0, 1.0), (f64::NAN, 0.0)], &p).is_empty());
        // A bar across the road (one u): no sample with distinct u, no lane.
        let bar: Vec<(f64, f64)> = (0..20).map(|i| (30.0, -5.0 + 0.5 * f64::from(i))).collect();
        assert!(fit_frame(&bar, &p).is_empty());
        // A short straight segment along the road (8 m < the minimum extent of 10 m).
        let short: Vec<(f64, f64)> = (0..20).map(|i| (30.0 + 0.4 * f64::from(i), 1.0)).collect();
        assert!(fit_frame(&short, &p).is_empty());
        let long: Vec<(f64, f64)> = (0..20).map(|i| (30.0 + 0.6 * f64::from(i), 1.0)).collect();
        assert_eq!(fit_frame(&long, &p).len(), 1);
    }

    #[test]
    fn deterministic_and_exact_through_three_points() {
        let p = BaselineParams::default();
        let f = frame(80, 9);
        assert_eq!(fit_frame(&f, &p), fit_frame(&f, &p));
        let q = through([(3.0, 1.0), (10.0, 2.0), (50.0, -1.0)]).unwrap();
        for (u, x) in [(3.0, 1.0), (10.0, 2.0), (50.0, -1.0)] {
            assert!((quad_at(q, u) - x).abs() < 1e-12);
        }
        let pts: Vec<(f64, f64)> = (0..30)
            .map(|i| {
                let u = 3.0 + 2.5 * f64::from(i);
                (u, quad_at((0.5, -0.02, 3e-4), u))
            })
            .collect();
        let l = least_squares(&pts).unwrap();
        assert!(
            (l.0 - 0.5).abs() < 1e-9 && (l.1 + 0.02).abs() < 1e-9 && (l.2 - 3e-4).abs() < 1e-12
        );
        assert!(least_squares(&pts[..2]).is_none());
    }

    #[test]
    fn written_only_within_the_inliers_extent() {
        let cam = Camera::tusimple();
        let lane = Lane {
            a: -1.8,
            b: 0.0,
            c: 0.0,
            u_min: 10.0,
            u_max: 30.0,
            inliers: 20,
        };
        let rows: Vec<f64> = (0..56).map(|i| 160.0 + 10.0 * f64::from(i)).collect();
        let r = lanes_record(&[lane], &cam, "a.jpg", &rows, Some(1.0));
        assert_eq!(r.lanes.len(), 1);
        for (row, col) in rows.iter().zip(&r.lanes[0]) {
            let u = cam.to_bev(cam.vp_col, *row).map(|b| b.0);
            match u {
                Some(u) if (10.0..=30.0).contains(&u) => {
                    let want = cam.to_image(u, -1.8).unwrap().0;
                    assert!((col - want).abs() < 1e-9, "row {row}");
                }
                _ => assert_eq!(*col, crate::tusimple::NO_POINT, "row {row}"),
            }
        }
        // A lane left of the image at every row is left out.
        let off = Lane { a: -500.0, ..lane };
        assert!(lanes_record(&[off], &cam, "a.jpg", &rows, None)
            .lanes
            .is_empty());
    }
}
