//! A short soak in CI (`stjpdacf_test_support::soak`, the long run is the `soak` example): two seeded
//! 30 fps drives of 300 frames (10 s each, with the road's dashed lines, clutter, dropped frames
//! and lane wander), the core tracker never reset and, on every frame, the same frames through
//! a fresh core tracker and the dense f64 reference on the core's own model.
//!
//! The reference costs ~0.3 s a frame in a debug build, so this test is `#[ignore]`d in the
//! debug `cargo test --workspace` and `.ci/run` runs it in release
//! (`cargo test --release -p stjpdacf-test-support --test soak -- --ignored`, ~5 s of CPU);
//! `short_soak_core` runs in every build (the core alone, 150 frames).
//!
//! Asserted: no refused frame, no output or covariance invariant violated, no negative
//! published variance, no discrete disagreement with the reference, filtered and smoothed
//! positions within 1e-3 m of the f64 reference (measured 3.2e-4 m on the 600-frame run of
//! seed 0), variances within 5e-3 relative, every true line tracked with a mean error
//! below 0.1 m. The figures are printed (`cargo test -p stjpdacf-test-support --test soak -- --nocapture`).

use stjpdacf_test_support::invariants::{ASYM_TOL, PSD_TOL};
use stjpdacf_test_support::soak::{run, SoakConfig};

#[test]
fn short_soak_core() {
    let cfg = SoakConfig {
        frames: 150,
        seed: 7,
        shards: 1,
        threads: 1,
        reference: false,
        health_every: 15,
        ..SoakConfig::default()
    };
    let s = run(&cfg, &|_| {}).expect("soak runs");
    assert_eq!(s.refused, 0);
    assert_eq!(s.output_violations, 0, "{:?}", s.violations);
    assert_eq!(s.covariance_violations, 0, "{:?}", s.violations);
    assert_eq!(s.negative_variance_frames, 0);
    assert!(s.health_checks >= 9);
    assert!(s.line_frames_matched as f64 >= 0.9 * s.line_frames as f64);
    assert!(s.reference.is_none());
}

/// The uncoupled tables (design §4.2.6: the filter and smoother on each lane's own block): the
/// same output and covariance invariants on the same drive.
#[test]
fn short_soak_core_uncoupled() {
    let cfg = SoakConfig {
        frames: 150,
        seed: 7,
        shards: 1,
        threads: 1,
        reference: false,
        health_every: 15,
        uncoupled: true,
        ..SoakConfig::default()
    };
    let s = run(&cfg, &|_| {}).expect("soak runs");
    assert_eq!(s.refused, 0);
    assert_eq!(s.temporal_failures, 0);
    assert_eq!(s.output_violations, 0, "{:?}", s.violations);
    assert_eq!(s.covariance_violations, 0, "{:?}", s.violations);
    assert_eq!(s.negative_variance_frames, 0);
    assert!(s.health_checks >= 9);
    assert!(s.line_frames_matched as f64 >= 0.9 * s.line_frames as f64);
}

#[test]
#[ignore = "release only: .ci/run runs it with `cargo test --release -p stjpdacf-test-support --test soak -- --ignored`"]
fn short_soak_against_the_f64_reference() {
    let cfg = SoakConfig {
        frames: 600,
        seed: 0,
        shards: 2,
        threads: 2,
        reference: true,
        episode: 300,
        compare_every: 1,
        smooth_every: 10,
        health_every: 5,
        uncoupled: false,
    };
    let s = run(&cfg, &|_| {}).expect("soak runs");
    println!("{}", serde_json::to_string_pretty(&s).expect("json"));
    assert_eq!(s.frames, 600);
    assert_eq!(s.refused, 0);
    assert_eq!(s.output_violations, 0, "{:?}", s.violations);
    assert_eq!(s.covariance_violations, 0, "{:?}", s.violations);
    assert_eq!(s.negative_variance_frames, 0);
    assert!(s.health_checks >= 100, "{}", s.health_checks);
    assert!(s.max_asymmetry <= ASYM_TOL);
    assert!(s.min_eig_corr >= -PSD_TOL);
    assert_eq!(s.temporal_failures, 0);
    assert!(s.line_frames > 1000);
    assert!(
        s.line_frames_matched as f64 >= 0.95 * s.line_frames as f64,
        "{} of {}",
        s.line_frames_matched,
        s.line_frames
    );
    assert!(s.mean_truth_error < 0.1, "{}", s.mean_truth_error);
    let r = s.reference.expect("reference ran");
    assert_eq!(r.discrete_disagreements, 0, "{:?}", r.disagreements);
    assert_eq!(r.frames_compared, 600);
    assert!(r.lanes_compared > 1000);
    assert!(r.smoothed_compared > 50, "{}", r.smoothed_compared);
    assert!(r.max_dz < 1e-3, "{}", r.max_dz);
    assert!(r.max_dz_smoothed < 1e-3, "{}", r.max_dz_smoothed);
    assert!(r.max_dvar_rel < 5e-3, "{}", r.max_dvar_rel);
    assert!(r.max_dexistence < 1e-5, "{}", r.max_dexistence);
}

/// Forced conditions hold: without clutter no point lies off a line; with 0.05 /m/row about
/// 64 rows × 24 m × 0.05 ≈ 77 clutter points a frame, of which the part off the lines
/// (at most six lines × 2 m of the 24 m) shows; dashed lines keep fewer points on the lines.
#[test]
fn forced_conditions_hold() {
    use stjpdacf_test_support::soak::{Forced, Road, RoadFrame};
    let road = |clutter, dashed| {
        Road::with_forced(
            7,
            Forced {
                clutter: Some(clutter),
                dashed: Some(dashed),
                ..Forced::default()
            },
        )
    };
    // Points within 1 m of a line (noise ≤ 15 cm; the truth is read at the next index point,
    // ≤ 5.1 m ahead, where a line moves by ≤ 0.3 m) and the others, over 300 frames.
    let count = |mut r: Road| {
        let (mut on, mut off, mut frames) = (0usize, 0usize, 0usize);
        for _ in 0..300 {
            let f: RoadFrame = r.next_frame();
            if f.blackout {
                continue;
            }
            frames += 1;
            for p in &f.points {
                let u = f64::from(p[0]);
                let i = stjpdacf::tables::DEFAULT
                    .index_u
                    .iter()
                    .position(|&ui| f64::from(ui) >= u)
                    .unwrap_or(15);
                if f.truth
                    .iter()
                    .any(|(_, xs)| (f64::from(p[1]) - xs[i]).abs() < 1.0)
                {
                    on += 1;
                } else {
                    off += 1;
                }
            }
        }
        (on as f64 / frames as f64, off as f64 / frames as f64)
    };
    let (solid_on, solid_off) = count(road(0.0, false));
    assert!(
        solid_on > 100.0 && solid_off == 0.0,
        "{solid_on} {solid_off}"
    );
    let (dashed_on, dashed_off) = count(road(0.05, true));
    assert!(
        (0.4 * 77.0..1.05 * 77.0).contains(&dashed_off),
        "{dashed_off}"
    );
    assert!(dashed_on < 0.6 * solid_on, "{dashed_on} {solid_on}");
}

/// Id switches count a line whose matched id changed since the last frame it was matched in
/// while it stayed visible, and forget a line that was not visible.
#[test]
fn id_switches_follow_each_line() {
    use std::collections::BTreeMap;
    use stjpdacf_test_support::soak::id_switches;
    let mut last = BTreeMap::new();
    let both = [0, 1];
    assert_eq!(
        id_switches(&mut last, &both, &[(0, 5, 0.1), (1, 6, 0.1)]),
        0
    );
    // Line 0 keeps its id, line 1 changes: one switch.
    assert_eq!(
        id_switches(&mut last, &both, &[(0, 5, 0.1), (1, 7, 0.1)]),
        1
    );
    // Line 1 is not visible: forgotten, so a new id after the gap is not a switch.
    assert_eq!(id_switches(&mut last, &[0], &[(0, 5, 0.1)]), 0);
    assert_eq!(
        id_switches(&mut last, &both, &[(0, 9, 0.1), (1, 8, 0.1)]),
        1
    );
    // Line 1 visible but not matched: it keeps id 8, so id 4 after it is a switch.
    assert_eq!(id_switches(&mut last, &both, &[(0, 9, 0.1)]), 0);
    assert_eq!(
        id_switches(&mut last, &both, &[(0, 9, 0.1), (1, 4, 0.1)]),
        1
    );
}

/// The process-noise scale (docs/design.md §11.7) on a drive whose dashed lines sit in dense
/// uniform clutter (0.08 points /m/row): before stop 55 covariance matching of the lanes'
/// innovations held itself up there (clutter in a wide gate gives innovations as wide as the
/// gate) and `q_scale` reached 2,369 within these 300 frames (10⁴ is its bound); with the score
/// of the rows' PDA likelihood the scale stays within 100 (measured over the first 300 frames
/// of the seeds 100 / 101 / 102 at stop 55: at most 12.9 / 40.8 / 15.1; seed 100 at most 3.5
/// with each lane's own `P_D` in its joint events, stop 56, and 21.0 since the scale takes each
/// frame's whole Fisher-scoring step, stop 57).
#[test]
fn process_noise_scale_does_not_run_away_in_clutter() {
    use stjpdacf::tables::DEFAULT;
    use stjpdacf::tracker::{Instant, ReferenceTracker};
    use stjpdacf_test_support::soak::{Forced, Road};
    let forced = Forced {
        clutter: Some(0.08),
        dashed: Some(true),
        ..Forced::default()
    };
    let mut road = Road::with_forced(100, forced);
    let mut t = Box::new(ReferenceTracker::new(&DEFAULT));
    let (mut worst, mut stepped, mut inflated) = (0.0f32, 0usize, 0usize);
    for _ in 0..300 {
        let f = road.next_frame();
        if let Ok(out) = t.step(Instant::from_micros(f.t_us), &f.points) {
            let q = out.report.known.q_scale;
            worst = worst.max(q);
            stepped += 1;
            inflated += usize::from(q > 1.0);
        }
    }
    println!("q_scale over {stepped} frames: max {worst}, above 1 on {inflated}");
    assert!(stepped > 250, "only {stepped} frames stepped");
    // The scale does adapt on this drive (it is not switched off)…
    assert!(inflated > 0, "q_scale never left 1");
    // …and does not run away.
    assert!(worst < 100.0, "q_scale reached {worst}");
}

/// Every check of `invariants::check_output` and `cov_health` rejects a corrupted input (the
/// soak's "0 violations" can fail).
#[test]
fn invariant_checks_reject_corrupted_output() {
    use nalgebra::SMatrix;
    use stjpdacf::tables::DEFAULT;
    use stjpdacf::tracker::{Instant, ReferenceTracker};
    use stjpdacf_test_support::invariants::{check_output, cov_health, PsdCheck};
    let pts: Vec<[f32; 2]> = (0..120)
        .map(|i| {
            let u = 3.0 + (i / 2) as f32 * 77.0 / 60.0;
            [u, if i % 2 == 0 { -1.8 } else { 1.8 }]
        })
        .collect();
    let mut t = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut out = None;
    for k in 0..8 {
        out = Some(t.step(Instant::from_millis(50 * k), &pts).unwrap());
    }
    let good = out.unwrap();
    assert!(good.filtered.len() == 2 && good.smoothed.len() == 2);
    check_output(&good, pts.len()).unwrap();
    type Corrupt = Box<dyn Fn(&mut stjpdacf::tracker::StepOutput<6, 16>)>;
    let bad: Vec<(&str, Corrupt)> = vec![
        ("over budget", Box::new(|o| o.report.over_budget_points = 1)),
        ("points_in", Box::new(|o| o.report.spatial.points_in += 1)),
        (
            "rejected",
            Box::new(|o| o.report.spatial.rejected_window = 1000),
        ),
        ("dt", Box::new(|o| o.report.dt = f32::NAN)),
        ("dup id", Box::new(|o| o.filtered[1].id = o.filtered[0].id)),
        (
            "dup slot",
            Box::new(|o| o.filtered[1].slot = o.filtered[0].slot),
        ),
        ("slot", Box::new(|o| o.filtered[1].slot = 6)),
        ("z", Box::new(|o| o.filtered[0].z[3] = f32::INFINITY)),
        ("var", Box::new(|o| o.smoothed[0].var[3] = -1e-9)),
        ("existence", Box::new(|o| o.filtered[0].existence = 1.01)),
        ("extent", Box::new(|o| o.filtered[0].u_last = 82.0)),
        (
            "extent order",
            Box::new(|o| o.filtered[0].u_first = o.filtered[0].u_last + 1.0),
        ),
        (
            "smoothed not published",
            Box::new(|o| {
                o.filtered.pop();
            }),
        ),
    ];
    for (what, f) in bad {
        let mut o = good.clone();
        f(&mut o);
        assert!(check_output(&o, pts.len()).is_err(), "{what} passed");
    }
    let idx = [0usize, 1];
    let ok = SMatrix::<f32, 2, 2>::new(1.0, 0.5, 0.5, 1.0);
    for c in [PsdCheck::Cholesky, PsdCheck::Eigen] {
        cov_health(&ok, &idx, c).unwrap();
        let asym = SMatrix::<f32, 2, 2>::new(1.0, 0.5, 0.5001, 1.0);
        assert!(cov_health(&asym, &idx, c).is_err());
        let indefinite = SMatrix::<f32, 2, 2>::new(1.0, 1.01, 1.01, 1.0);
        assert!(cov_health(&indefinite, &idx, c).is_err());
        let neg = SMatrix::<f32, 2, 2>::new(-1.0, 0.0, 0.0, 1.0);
        assert!(cov_health(&neg, &idx, c).is_err());
        let nan = SMatrix::<f32, 2, 2>::new(1.0, f32::NAN, f32::NAN, 1.0);
        assert!(cov_health(&nan, &idx, c).is_err());
    }
}
