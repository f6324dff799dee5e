//! The ray test (docs/design.md §11.10): the core's statistic against the f64 reference, and the
//! tracker on two scenes that tell a vertical structure from a marking, the one a BEV tracker
//! would publish without the test (a vehicle's side, a ray from the camera's foot point) and the
//! one it must not lose (the marking under the camera in a lane change with yaw, which is a ray
//! too, but parallel to the other markings).
//! `cargo test -p stjpdacf-test-support --test ray -- --nocapture`

use nalgebra::{DMatrix, SMatrix, SVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use stjpdacf::persist::{ray_stat, RayVerdict};
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker, TrackerConfig};
use stjpdacf_reference::persist as refp;

const POINTS: usize = 16;

/// The core's f32 statistic against the f64 reference (measured: `â` within 3.0e-5·(1 + |â|),
/// `√S_aa` within 1.4e-5 relative, both χ² within 1.8e-4 relative or absolute; asserted at
/// about 10×) on random lanes, rays and covariances (a GP-like correlated covariance plus
/// point noise, random extents, random weights).
#[test]
fn core_ray_stat_matches_reference() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let u = DEFAULT.index_u;
    let (mut worst_a, mut worst_sd, mut worst_chi) = (0.0f64, 0.0f64, 0.0f64);
    let mut compared = 0;
    for _ in 0..400 {
        let lo = rng.random_range(0..10usize);
        let hi = rng.random_range(lo + 3..POINTS);
        let present: [bool; POINTS] = core::array::from_fn(|i| i >= lo && i <= hi);
        let (a0, b0, c0) = (
            rng.random_range(-6.0..6.0f64),
            rng.random_range(-0.2..0.2f64),
            rng.random_range(-2e-3..2e-3f64),
        );
        let ell = rng.random_range(10.0..60.0f64);
        let s2 = rng.random_range(1e-4..0.05f64);
        let r = rng.random_range(1e-4..0.02f64);
        let cov64 = DMatrix::from_fn(POINTS, POINTS, |i, j| {
            if present[i] && present[j] {
                let d = f64::from(u[i] - u[j]);
                s2 * (-d * d / (2.0 * ell * ell)).exp() + if i == j { r } else { 0.0 }
            } else {
                0.0
            }
        });
        let noise = Normal::new(0.0, s2.sqrt()).unwrap();
        let z64: Vec<f64> = (0..POINTS)
            .map(|i| {
                let ui = f64::from(u[i]);
                a0 + b0 * ui + c0 * ui * ui + noise.sample(&mut rng)
            })
            .collect();
        let w64: Vec<f64> = (0..POINTS).map(|i| 1.0 / cov64[(i, i)].max(r)).collect();
        let uu: Vec<f64> = u.iter().map(|&v| f64::from(v)).collect();
        let reference = refp::ray_stat(&uu, &z64, &present, &w64, &cov64);
        let z = SVector::<f32, POINTS>::from_fn(|i, _| z64[i] as f32);
        let w: [f32; POINTS] = core::array::from_fn(|i| w64[i] as f32);
        let cov = SMatrix::<f32, POINTS, POINTS>::from_fn(|i, j| cov64[(i, j)] as f32);
        let form = |p: &[f32; POINTS], q: &[f32; POINTS]| {
            let mut acc = 0.0f32;
            for i in 0..POINTS {
                for j in 0..POINTS {
                    acc += p[i] * cov[(i, j)] * q[j];
                }
            }
            acc
        };
        let core = ray_stat(&u, &z, &present, &w, &form);
        let (Some(c), Some((a, sd, chi, chi_c))) = (core, reference) else {
            assert!(
                core.is_none() || reference.is_none(),
                "{core:?} {reference:?}"
            );
            continue;
        };
        compared += 1;
        let rel = |x: f64, y: f64| (x - y).abs() / y.abs().max(1e-9);
        let ea = (f64::from(c.a) - a).abs() / (1.0 + a.abs());
        worst_a = worst_a.max(ea);
        worst_sd = worst_sd.max(rel(f64::from(c.sd_a), sd));
        let e = rel(f64::from(c.chi2), chi)
            .min((f64::from(c.chi2) - chi).abs())
            .max(
                rel(f64::from(c.chi2_curvature), chi_c)
                    .min((f64::from(c.chi2_curvature) - chi_c).abs()),
            );
        if e > 2e-3 {
            println!("lo {lo} hi {hi}: core {c:?} ref {:?}", (a, sd, chi, chi_c));
        }
        worst_chi = worst_chi.max(e);
    }
    println!(
        "{compared} cases: max |Δâ|/(1+|â|) {worst_a:.2e}, max rel Δsd {worst_sd:.2e}, \
         max Δχ² (rel or abs) {worst_chi:.2e}"
    );
    assert!(compared >= 300, "{compared}");
    assert!(worst_a < 3e-4 && worst_sd < 2e-4 && worst_chi < 2e-3);
}

/// Rows every 1.25 m over the window, a point per row per line with Gaussian noise `sigma`.
fn line_points(
    rng: &mut ChaCha8Rng,
    pts: &mut Vec<[f32; 2]>,
    (u0, u1): (f64, f64),
    x: impl Fn(f64) -> f64,
    sigma: f64,
) {
    let noise = Normal::new(0.0, sigma).unwrap();
    let mut u = 3.0;
    while u <= 77.0 {
        if u >= u0 && u <= u1 && rng.random_bool(0.9) {
            pts.push([u as f32, (x(u) + noise.sample(rng)) as f32]);
        }
        u += 1.25;
    }
}

fn lane_near(
    out: &[stjpdacf::tracker::LaneEstimate<POINTS>],
    x: impl Fn(f64) -> f64,
) -> Option<u32> {
    let u = DEFAULT.index_u;
    out.iter()
        .find(|l| {
            let inside: Vec<usize> = (0..POINTS)
                .filter(|&i| u[i] >= l.u_first && u[i] <= l.u_last && u[i] >= 25.0 && u[i] <= 70.0)
                .collect();
            inside.len() >= 3
                && inside
                    .iter()
                    .all(|&i| (f64::from(l.z[i]) - x(f64::from(u[i]))).abs() < 0.5)
        })
        .map(|l| l.id.0)
}

/// Two markings and a vehicle's side edge 2.4 m to the right at 20 m (its ray `x = 0.12 u` to
/// the end of the window, point noise growing with `u` as pixel noise does), 40 frames at
/// 20 Hz. Without the test the edge is published as a lane on most frames; with it, on none.
#[test]
fn a_vertical_structure_is_not_published() {
    // The edge from its base at 20 m: noise σ = 0.002·u (2 px at f ≈ 1000 px).
    let edge = |rng: &mut ChaCha8Rng, pts: &mut Vec<[f32; 2]>| {
        far_points(rng, pts, 20.0, 0.9, 0.002, |u| 0.12 * u)
    };
    let mut off = TrackerConfig::DEFAULT;
    off.persist.ray_z = 0.0;
    let (ray_on, lanes_on) = scene(TrackerConfig::DEFAULT, 5, &edge, &|u| 0.12 * u);
    let (ray_off, lanes_off) = scene(off, 5, &edge, &|u| 0.12 * u);
    println!("frames with the edge published: {ray_on} (test on), {ray_off} (off); both markings: {lanes_on} / {lanes_off}");
    assert!(
        ray_off >= 20,
        "the scene must fool the tracker without the test: {ray_off}"
    );
    assert_eq!(ray_on, 0);
    assert!(lanes_on >= 35 && lanes_off >= 35);
}

/// A lane change with yaw: the markings `x = c_k(t) − 0.04 u` move left at 1 m/s, so the one that
/// starts at 1.8 m passes under the camera at t = 1.8 s, where it is a ray through the foot
/// point. It is parallel to the other two, so it keeps its id from its first publication to the
/// end (80 frames at 20 Hz).
#[test]
fn the_marking_under_the_camera_in_a_lane_change_keeps_its_id() {
    let mut t = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut ids = Vec::new();
    let mut rays = 0;
    for k in 0..80i64 {
        let time = 0.05 * k as f64;
        // The markings move left at 1 m/s.
        let shift = -time;
        let mut pts = Vec::new();
        for base in [-1.8, 1.8, 5.4] {
            line_points(
                &mut rng,
                &mut pts,
                (3.0, 77.0),
                |u| base + shift - 0.04 * u,
                0.05,
            );
        }
        pts.sort_by(|a, b| a[0].total_cmp(&b[0]));
        let out = t
            .step(Instant::from_micros(50_000 * (k + 1)), &pts)
            .unwrap();
        rays += out.report.known.ray_deleted + out.report.known.ray_refused;
        if let Some(id) = lane_near(&out.filtered, |u| 1.8 + shift - 0.04 * u) {
            ids.push(id);
        } else if !ids.is_empty() {
            panic!(
                "frame {k}: the crossed marking is not published (x at the foot point {:.2})",
                1.8 + shift
            );
        }
    }
    println!(
        "crossed marking published on {} frames, ids {:?}; ray verdicts acted on {rays}",
        ids.len(),
        ids.first()
    );
    assert!(ids.len() >= 70, "{}", ids.len());
    assert!(ids.iter().all(|&i| i == ids[0]), "{ids:?}");
}

/// The same lane change with the neighbouring markings seen only far (from 55 m, the crossing one to 50 m: a worn or
/// occluded near field), so no paint lane shares index points with the crossing marking and
/// the parallel test cannot exempt it. Its offset at the foot point moves through 0 at 1 m/s,
/// which the temporal state's rates resolve (`PersistConfig::ray_motion`): it keeps its id.
/// Without that rule the ray test deletes it as it passes under the camera (measured: deleted
/// 4 times, 2 ids, published on 55 of 80 frames; with it on all 80 under one id).
#[test]
fn the_lone_marking_under_the_camera_in_a_lane_change_keeps_its_id() {
    let run = |cfg: TrackerConfig| {
        let mut t = Box::new(ReferenceTracker::with_config(&DEFAULT, cfg));
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let (mut ids, mut rays, mut moving_rays) = (Vec::new(), 0, 0);
        for k in 0..80i64 {
            let shift = -0.05 * k as f64;
            let mut pts = Vec::new();
            for (base, seen) in [
                (-1.8, (55.0, 77.0)),
                (1.8, (3.0, 50.0)),
                (5.4, (55.0, 77.0)),
            ] {
                line_points(&mut rng, &mut pts, seen, |u| base + shift - 0.04 * u, 0.05);
            }
            pts.sort_by(|a, b| a[0].total_cmp(&b[0]));
            let out = t
                .step(Instant::from_micros(50_000 * (k + 1)), &pts)
                .unwrap();
            rays += out.report.known.ray_deleted;
            ids.extend(lane_near(&out.filtered, |u| 1.8 + shift - 0.04 * u));
            // Lanes the ray test finds to be rays that the motion rule reads as moving.
            moving_rays += out
                .filtered
                .iter()
                .filter(|l| t.ray_diagnosis(usize::from(l.slot)) == (RayVerdict::Ray, true))
                .count();
        }
        let mut distinct = ids.clone();
        distinct.dedup();
        (ids.len(), distinct.len(), rays, moving_rays)
    };
    let mut off = TrackerConfig::DEFAULT;
    off.persist.ray_motion = false;
    let (frames, ids, rays, moving_rays) = run(TrackerConfig::DEFAULT);
    let (frames_off, ids_off, rays_off, _) = run(off);
    println!(
        "lone crossing marking: published on {frames} frames, {ids} ids, {rays} ray deletions, \
         {moving_rays} lane-frames a moving ray (without the motion rule: {frames_off}, \
         {ids_off}, {rays_off})"
    );
    // What kept it: a ray to the test that moves (`Tracker::ray_diagnosis`).
    assert!(moving_rays >= 1, "{moving_rays}");
    assert!(
        rays_off >= 1,
        "the scene must make the ray test delete it: {rays_off}"
    );
    assert_eq!(rays, 0);
    assert_eq!(ids, 1);
    assert!(
        frames >= 70 && frames > frames_off,
        "{frames} against {frames_off}"
    );
}

/// Points of the curve `x(u)` from `u0` to the end of the window, one per row of 1.25 m detected
/// with probability `detect`, with Gaussian noise σ = `sigma_per_m`·u (pixel noise grows with
/// the distance).
fn far_points(
    rng: &mut ChaCha8Rng,
    pts: &mut Vec<[f32; 2]>,
    u0: f64,
    detect: f64,
    sigma_per_m: f64,
    x: impl Fn(f64) -> f64,
) {
    let mut u = u0;
    while u <= 77.0 {
        if rng.random_bool(detect) {
            let n = Normal::new(0.0, sigma_per_m * u).unwrap();
            pts.push([u as f32, (x(u) + n.sample(rng)) as f32]);
        }
        u += 1.25;
    }
}

/// A scene: two markings at ±1.8 m, plus the points `extra` adds each frame, 40 frames at
/// 20 Hz; returns on how many frames a lane near `near` was published, and on how many both
/// markings were.
fn scene(
    cfg: TrackerConfig,
    seed: u64,
    extra: &dyn Fn(&mut ChaCha8Rng, &mut Vec<[f32; 2]>),
    near: &dyn Fn(f64) -> f64,
) -> (usize, usize) {
    let mut t = Box::new(ReferenceTracker::with_config(&DEFAULT, cfg));
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut near_frames, mut lane_frames) = (0, 0);
    for k in 0..40i64 {
        let mut pts = Vec::new();
        line_points(&mut rng, &mut pts, (3.0, 77.0), |_| -1.8, 0.05);
        line_points(&mut rng, &mut pts, (3.0, 77.0), |_| 1.8, 0.05);
        extra(&mut rng, &mut pts);
        pts.sort_by(|a, b| a[0].total_cmp(&b[0]));
        let out = t
            .step(Instant::from_micros(50_000 * (k + 1)), &pts)
            .unwrap();
        near_frames += usize::from(lane_near(&out.filtered, near).is_some());
        lane_frames += usize::from(
            lane_near(&out.filtered, |_| -1.8).is_some()
                && lane_near(&out.filtered, |_| 1.8).is_some(),
        );
    }
    (near_frames, lane_frames)
}

/// A vehicle's side edge seen from further away: base at 30 m, 4.5 m to the right (its ray
/// `x = 0.15 u`), pixel-like noise σ = 0.006·u and 70 % of rows detected, so its offset at the
/// foot point is often not resolved to 0.5 m (`RayVerdict::Aligned`). It is not parallel to the
/// two markings, so with `ray_aligned` it is refused or deleted once the markings are paint.
/// The ray rule alone (both runs without the newcomers' wait of §11.5, which also holds a lane
/// parallel to no marking, with the paint / gap chain's gap fixed, `chain_memory` 0: on two
/// solid markings the estimated gap shortens and the edge's misses cost it more, §11.5, and
/// without the lane-width rule of §11.14, which hides the edge's noisy early estimates where
/// they come within 2.5 m of the right-hand marking):
/// published on 10 of 40 frames (the first, before any lane is paint, and frames where its noisy
/// estimate is not aligned or its parallel test does not decide) against 26 with decisive rays
/// only; asserted: at most half. The default (all of them) shows it on no more frames than the
/// ray rule alone.
#[test]
fn an_unresolved_vertical_structure_is_not_published_when_it_crosses_the_markings_direction() {
    let edge = |rng: &mut ChaCha8Rng, pts: &mut Vec<[f32; 2]>| {
        far_points(rng, pts, 30.0, 0.7, 0.006, |u| 0.15 * u)
    };
    let near = |u: f64| 0.15 * u;
    let mut aligned = TrackerConfig::DEFAULT;
    aligned.persist.newcomer_wait = 0;
    aligned.persist.chain_memory = 0.0;
    aligned.persist.lane_width = 0.0;
    let mut before = aligned;
    before.persist.ray_aligned = false;
    let (on, lanes_on) = scene(aligned, 21, &edge, &near);
    let (off, lanes_off) = scene(before, 21, &edge, &near);
    let (default, lanes_default) = scene(TrackerConfig::DEFAULT, 21, &edge, &near);
    println!(
        "frames with the far edge published: {on} (aligned rule), {off} (decisive rays only), \
         {default} (default); both markings {lanes_on} / {lanes_off} / {lanes_default}"
    );
    assert!(
        off >= 20,
        "the scene must fool the decisive test alone: {off}"
    );
    assert!(on * 2 <= off, "{on} against {off}");
    assert!(default <= on, "{default} against {on}");
    assert!(lanes_on >= 35 && lanes_off >= 35 && lanes_default >= 35);
}

/// A marking seen only far away and noisy (from 35 m, 7.5 m to the right, σ = 0.006·u, 70 % of
/// rows), parallel to the two markings: the aligned rule leaves it alone, it is published on as
/// many frames as with decisive rays only.
#[test]
fn a_far_marking_parallel_to_the_others_is_kept() {
    let marking = |rng: &mut ChaCha8Rng, pts: &mut Vec<[f32; 2]>| {
        far_points(rng, pts, 35.0, 0.7, 0.006, |_| 7.5)
    };
    let near = |_: f64| 7.5;
    let mut before = TrackerConfig::DEFAULT;
    before.persist.ray_aligned = false;
    let (on, _) = scene(TrackerConfig::DEFAULT, 23, &marking, &near);
    let (off, _) = scene(before, 23, &marking, &near);
    println!(
        "frames with the far marking published: {on} (aligned rule), {off} (decisive rays only)"
    );
    assert!(off >= 30, "the far marking must be tracked at all: {off}");
    assert_eq!(on, off);
}
