//! The `Tracker` facade end to end on seeded multi-frame BEV scenes: lanes found and kept with
//! stable ids, dropped frames, blackouts, lanes appearing, bad input rejected with the state
//! intact, and the size budget of the reference configuration.

use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker, StepError};
use stjpdacf_tools::scenario::{Scenario, ScenarioConfig};

/// `size_of` the whole reference tracker must stay within 160 KiB (issue budget; pinned here).
#[test]
fn reference_tracker_fits_160_kib() {
    let size = std::mem::size_of::<ReferenceTracker>();
    println!("size_of::<ReferenceTracker>() = {size} B");
    assert!(size <= 160 * 1024, "{size} B");
}

fn tracker() -> Box<ReferenceTracker> {
    Box::new(ReferenceTracker::new(&DEFAULT))
}

fn frame(seed: u64, shift: f64, lanes: usize) -> Vec<[f32; 2]> {
    let cfg = ScenarioConfig {
        lanes,
        left: -5.4 + shift,
        clutter_density: 0.02,
        ..ScenarioConfig::default()
    };
    Scenario::generate(&cfg, seed)
        .points
        .iter()
        .map(|&(u, x)| [u as f32, x as f32])
        .collect()
}

/// Three lanes with clutter (0.02 /m per row), lateral drift and two dropped frames: the three
/// lines are tracked on every frame with the same ids. With the known-lane stage (docs/design.md
/// §11) a candidate that splits off a line can be published for a frame before it is merged or
/// its existence falls (measured: 1 frame of 30 with a fourth lane); at most 2 are allowed, and
/// the extra lane never replaces one of the three.
#[test]
fn keeps_lanes_and_ids_over_frames() {
    let mut t = tracker();
    let mut ids = Vec::new();
    let mut us = 0i64;
    let mut extra_frames = 0;
    for k in 0..30u64 {
        // Lateral drift of 2 cm a frame; frame 10 and 20 are dropped (2× and 5× steps).
        let step = match k {
            10 => 100_000,
            20 => 250_000,
            _ => 50_000,
        };
        us += step;
        let out = t
            .step(Instant::from_micros(us), &frame(k, 0.02 * k as f64, 3))
            .unwrap();
        assert!(out.filtered.len() >= 3, "frame {k}: {:?}", out.report);
        if out.filtered.len() > 3 {
            extra_frames += 1;
        }
        // The lane nearest each true line (mean |Δx| over the first 8 index points, where the
        // lines are near straight) is the one compared.
        let drift = 0.02 * k as f32;
        let nearest = |want: f32| {
            let d = |l: &stjpdacf::tracker::LaneEstimate<16>| {
                l.z.iter().take(8).map(|z| (z - want).abs()).sum::<f32>()
            };
            out.filtered
                .iter()
                .min_by(|a, b| d(a).total_cmp(&d(b)))
                .copied()
        };
        let lanes: Vec<_> = [-5.4f32, -1.8, 1.8]
            .iter()
            .filter_map(|w| nearest(w + drift))
            .collect();
        let mut frame_ids: Vec<u32> = lanes.iter().map(|l| l.id.0).collect();
        frame_ids.sort_unstable();
        if k == 0 {
            ids = frame_ids.clone();
        }
        assert_eq!(frame_ids, ids, "frame {k}: ids changed");
        for l in &lanes {
            assert_eq!(
                (l.age, l.hits),
                (k as u32, k as u32 + 1),
                "frame {k}: {l:?}"
            );
        }
        // Positions near the truth at the nearest index point (lanes at −5.4, −1.8, 1.8 + drift).
        let mut z0: Vec<f32> = lanes.iter().map(|l| l.z[0]).collect();
        z0.sort_by(f32::total_cmp);
        for (z, want) in z0.iter().zip([-5.4f32, -1.8, 1.8]) {
            assert!(
                (z - want - drift).abs() < 0.5,
                "frame {k}: {z} vs {}",
                want + drift
            );
        }
        if k >= 4 {
            assert!(out.smoothed.len() >= 3, "frame {k}: smoothed lanes");
        }
    }
    println!("frames with a fourth lane: {extra_frames} of 30");
    assert!(extra_frames <= 2, "{extra_frames}");
}

#[test]
fn blackout_coasts_then_recovers_with_the_same_ids() {
    let mut t = tracker();
    let mut us = 0;
    let mut first = Vec::new();
    for k in 0..20u64 {
        us += 50_000;
        let pts = if (8..12).contains(&k) {
            Vec::new()
        } else {
            frame(k, 0.0, 3)
        };
        let out = t.step(Instant::from_micros(us), &pts).unwrap();
        let mut ids: Vec<u32> = out.filtered.iter().map(|l| l.id.0).collect();
        ids.sort_unstable();
        if k == 0 {
            first = ids.clone();
        }
        // Four empty frames: the lanes coast (fewer than max_misses) and keep their ids.
        assert_eq!(ids, first, "frame {k}");
        if (8..12).contains(&k) {
            assert!(out.filtered.iter().all(|l| l.misses > 0));
        }
    }
}

/// A lane that appears while others are tracked gets a new id and is published from its second
/// frame.
#[test]
fn new_lane_gets_a_new_id() {
    let mut t = tracker();
    let mut us = 0;
    let mut seen = std::collections::BTreeSet::new();
    for k in 0..12u64 {
        us += 50_000;
        let lanes = if k < 6 { 2 } else { 3 };
        // No clutter here: this test is about ids. With clutter the spatial filter can lose a lane
        // inside a frame and restart it further out, which shows as an extra lane (seed 0 of this
        // scene with 0.02 /m clutter: two clutter points at 57–58 m pull the track 0.4 m off;
        // known issue, see the open problems in docs/measurements.md).
        let cfg = ScenarioConfig {
            lanes,
            clutter_density: 0.0,
            ..ScenarioConfig::default()
        };
        let pts: Vec<[f32; 2]> = Scenario::generate(&cfg, k)
            .points
            .iter()
            .map(|&(u, x)| [u as f32, x as f32])
            .collect();
        let out = t.step(Instant::from_micros(us), &pts).unwrap();
        let z0: Vec<(f32, f32, f32)> = out
            .filtered
            .iter()
            .map(|l| (l.z[0], l.u_first, l.u_last))
            .collect();
        // The first frame's lanes are published at once (nothing is tracked yet); the third
        // lane, started at frame 6 while two are tracked, from its second frame (§11.5).
        let published = if k == 6 { 2 } else { lanes };
        assert_eq!(
            out.filtered.len(),
            published,
            "frame {k}: {z0:?} {:?}",
            out.report.spatial
        );
        if k == 6 {
            assert_eq!(
                out.report.identity.started, 1,
                "frame 6: the third lane starts"
            );
        }
        seen.extend(out.filtered.iter().map(|l| l.id.0));
    }
    assert_eq!(seen.len(), 3);
}

/// A line that appears while two markings are tracked (straight, at x ≈ −5.4 and −1.8 m) and is
/// not yet shown to be a marking of its own is held for `PersistConfig::newcomer_wait` frames
/// (docs/design.md §11.5): published from its second frame with the rule off (0), from its
/// third with 1, from its fourth with 2 (the default):
/// * a line that runs parallel to neither (diverging at 0.08 rad, 3 m right of the camera at
///   its foot);
/// * a line parallel to them 1.4–1.6 m right of the second (closer than two markings can be).
///
/// A line parallel to them at a marking's spacing (3.5–3.7 m) is published from its second
/// frame whatever the wait.
#[test]
fn a_newcomer_that_is_not_yet_a_marking_waits() {
    use stjpdacf::tracker::TrackerConfig;
    // (line x(u), where its lane is at the first index point, whether the rule holds it)
    type Line = fn(f32) -> f32;
    let cases: [(Line, f32, bool); 3] = [
        (|u| 3.0 + 0.08 * u, 3.24, true),
        (|_| -0.3, -0.3, true),
        (|_| 1.8, 1.8, false),
    ];
    for (line, z0, held) in cases {
        for wait in [0u8, 1, 2] {
            let mut cfg = TrackerConfig::DEFAULT;
            cfg.persist.newcomer_wait = wait;
            let mut t: Box<ReferenceTracker> =
                Box::new(ReferenceTracker::with_config(&DEFAULT, cfg));
            let mut first_published = None;
            for k in 0..12u64 {
                let scene = ScenarioConfig {
                    lanes: 2,
                    clutter_density: 0.0,
                    ..ScenarioConfig::default()
                };
                let mut pts: Vec<[f32; 2]> = Scenario::generate(&scene, k)
                    .points
                    .iter()
                    .map(|&(u, x)| [u as f32, x as f32])
                    .collect();
                if k >= 6 {
                    pts.extend((0..50).map(|i| {
                        let u = 4.0 + 1.2 * i as f32;
                        [u, line(u)]
                    }));
                }
                let out = t
                    .step(Instant::from_micros(50_000 * (k as i64 + 1)), &pts)
                    .unwrap();
                let shown = out.filtered.iter().any(|l| (l.z[0] - z0).abs() < 0.5);
                if shown && first_published.is_none() {
                    first_published = Some(k);
                }
                assert!(out.filtered.len() >= 2, "frame {k}: {:?}", out.report);
            }
            // The line appears in frame 6; its lane is at its first publication in frame 7.
            let expected = 7 + if held { u64::from(wait) } else { 0 };
            assert_eq!(
                first_published,
                Some(expected),
                "line at {z0} m, newcomer_wait = {wait}"
            );
        }
    }
}

#[test]
fn bad_time_and_bad_points_leave_the_state_intact() {
    let mut t = tracker();
    t.step(Instant::from_millis(100), &frame(1, 0.0, 3))
        .unwrap();
    let before = format!("{t:?}");
    assert_eq!(
        t.step(Instant::from_millis(100), &frame(2, 0.0, 3)),
        Err(StepError::NonIncreasingTime)
    );
    assert_eq!(
        t.step(Instant::from_millis(50), &frame(2, 0.0, 3)),
        Err(StepError::NonIncreasingTime)
    );
    assert_eq!(format!("{t:?}"), before);
    // Junk and an over-budget frame are counted, not fatal.
    let mut pts = frame(3, 0.0, 3);
    pts.extend([[f32::NAN, 0.0], [10.0, f32::INFINITY], [500.0, 0.0]]);
    pts.extend((0..400).map(|i| [30.0 + (i % 40) as f32 * 0.1, 20.0]));
    let out = t.step(Instant::from_millis(150), &pts).unwrap();
    assert!(out.report.over_budget_points > 0);
    assert!(out
        .filtered
        .iter()
        .all(|l| l.z.iter().all(|v| v.is_finite())));
}

#[test]
fn lane_at_interpolates_between_index_points() {
    let mut t = tracker();
    let out = t.step(Instant::from_millis(0), &frame(5, 0.0, 3)).unwrap();
    let lane = out.filtered[0];
    let u_mid = (DEFAULT.index_u[2] + DEFAULT.index_u[3]) / 2.0;
    let (x, var) = t.lane_at(usize::from(lane.slot), u_mid).unwrap();
    let (a, b) = (lane.z[2], lane.z[3]);
    assert!(
        x >= a.min(b) - 0.2 && x <= a.max(b) + 0.2,
        "{x} between {a} and {b}"
    );
    assert!(var > 0.0 && var.is_finite());
    // At an index point it reproduces the lane.
    let (x2, _) = t
        .lane_at(usize::from(lane.slot), DEFAULT.index_u[4])
        .unwrap();
    assert!((x2 - lane.z[4]).abs() < 0.05, "{x2} vs {}", lane.z[4]);
    assert!(t.lane_at(usize::from(lane.slot), f32::NAN).is_none());
    assert!(t.lane_at(usize::from(lane.slot), 500.0).is_none());
}

/// Records the order of stage transitions.
struct Trace(Vec<stjpdacf::probe::Stage>);

impl stjpdacf::probe::Probe for Trace {
    fn enter(&mut self, stage: stjpdacf::probe::Stage) {
        self.0.push(stage);
    }
}

#[test]
fn probed_step_reports_every_stage_and_changes_nothing() {
    use stjpdacf::probe::Stage;
    let mut plain = tracker();
    let mut probed = tracker();
    let mut us = 0i64;
    for k in 0..8u64 {
        us += 50_000;
        let pts = frame(k, 0.0, 3);
        let a = plain.step(Instant::from_micros(us), &pts).unwrap();
        let mut trace = Trace(Vec::new());
        let b = probed
            .step_probed(Instant::from_micros(us), &pts, &mut trace)
            .unwrap();
        assert_eq!(a, b, "frame {k}: the probe changed the result");
        let t = &trace.0;
        assert_eq!(t.first(), Some(&Stage::Binning));
        assert_eq!(t.last(), Some(&Stage::Done));
        assert_eq!(t.iter().filter(|s| **s == Stage::Done).count(), 1);
        // Every row of the 61 is gated; from the second frame on, the temporal filter predicts
        // and the smoother's window moves.
        assert_eq!(t.iter().filter(|s| **s == Stage::Gating).count(), 61);
        assert_eq!(t.iter().filter(|s| **s == Stage::RowPredict).count(), 60);
        for s in [
            Stage::Events,
            Stage::Update,
            Stage::Management,
            Stage::Backward,
            Stage::Identity,
            Stage::Temporal,
            Stage::Output,
        ] {
            assert!(t.contains(&s), "frame {k}: {s:?} never entered");
        }
        if k > 0 {
            assert!(
                t.contains(&Stage::Smoother),
                "frame {k}: smoother never entered"
            );
        }
        // The spatial stages come before identity, identity before the output.
        let pos = |s: Stage| t.iter().position(|x| *x == s).unwrap();
        let last = |s: Stage| t.iter().rposition(|x| *x == s).unwrap();
        assert!(last(Stage::Backward) < pos(Stage::Identity));
        assert!(last(Stage::Identity) < pos(Stage::Output));
    }
    // A refused frame still ends with Done.
    let mut trace = Trace(Vec::new());
    assert!(probed
        .step_probed(Instant::from_micros(us), &frame(0, 0.0, 3), &mut trace)
        .is_err());
    assert_eq!(trace.0.last(), Some(&Stage::Done));
}

/// The smoothed lanes (frame k − L) carry the extent the lanes had then, not the current one:
/// lanes seen only up to 40 m for 10 frames, then up to the end of the window.
#[test]
fn smoothed_lanes_carry_the_extent_of_their_frame() {
    const LAG: usize = 4;
    let mut t = tracker();
    for k in 0..20u64 {
        let mut pts = frame(k, 0.0, 3);
        if k < 10 {
            pts.retain(|p| p[0] <= 40.0);
        }
        let out = t
            .step(Instant::from_micros(50_000 * (k as i64 + 1)), &pts)
            .unwrap();
        let far = |ls: &[stjpdacf::tracker::LaneEstimate<16>]| {
            ls.iter()
                .map(|l| l.u_last)
                .fold(f32::NEG_INFINITY, f32::max)
        };
        assert_eq!(out.filtered.len(), 3, "frame {k}");
        // Filtered: frames k−L..=k; the far end jumps as soon as the far points come.
        if k >= 10 {
            assert!(
                far(&out.filtered) > 70.0,
                "frame {k}: {}",
                far(&out.filtered)
            );
        } else {
            assert!(
                far(&out.filtered) <= 41.0,
                "frame {k}: {}",
                far(&out.filtered)
            );
        }
        // Smoothed (frame k − L): frames k−2L..=k−L, so the far end follows L frames later.
        if k as usize >= LAG {
            assert_eq!(out.smoothed.len(), 3, "frame {k}");
            if (k as usize) < 10 + LAG {
                assert!(
                    far(&out.smoothed) <= 41.0,
                    "frame {k}: {}",
                    far(&out.smoothed)
                );
            } else {
                assert!(
                    far(&out.smoothed) > 70.0,
                    "frame {k}: {}",
                    far(&out.smoothed)
                );
            }
        }
    }
}

/// The all-zero tracker (`UNINIT`, for a `static` in `.bss`) refuses frames until `init`, and
/// `init` makes any tracker — fresh or after 20 frames with lanes and ids — the tracker
/// `with_config` builds: the same state (compared through `Debug`, every field) and the same
/// outputs, bit for bit, over the next 20 frames. A per-lane smoother configuration is carried
/// over too.
#[test]
fn init_in_place_is_with_config_and_restarts() {
    use stjpdacf::tracker::TrackerConfig;
    let cfg = TrackerConfig {
        smoother_per_lane: true,
        ..TrackerConfig::DEFAULT
    };
    let mut z: Box<ReferenceTracker> = Box::new(ReferenceTracker::UNINIT);
    assert_eq!(
        z.step(Instant::from_micros(0), &frame(1, 0.0, 3)).err(),
        Some(StepError::NotInitialised)
    );
    assert_eq!(z.frames(), 0);
    assert!(z.lane_at(0, 10.0).is_none());
    let frames: Vec<_> = (0..20u64).map(|k| frame(k, 0.02 * k as f64, 3)).collect();
    for cfg in [TrackerConfig::DEFAULT, cfg] {
        let fresh: Box<ReferenceTracker> = Box::new(ReferenceTracker::with_config(&DEFAULT, cfg));
        let mut used = tracker();
        for (k, f) in frames.iter().enumerate() {
            used.step(Instant::from_micros(50_000 * k as i64), f)
                .unwrap();
        }
        assert!(used.frames() == 20 && used.lane_at(0, 10.0).is_some());
        z.init(&DEFAULT, cfg);
        used.init(&DEFAULT, cfg);
        let want = format!("{fresh:?}");
        assert_eq!(format!("{z:?}"), want);
        assert_eq!(format!("{used:?}"), want);
        let mut fresh = fresh;
        for (k, f) in frames.iter().enumerate() {
            let at = Instant::from_micros(1_000_000 + 50_000 * k as i64);
            let a = fresh.step(at, f).unwrap();
            let b = used.step(at, f).unwrap();
            assert_eq!(format!("{a:?}"), format!("{b:?}"), "frame {k}");
            assert!(!a.filtered.is_empty() || k < 6, "frame {k}");
        }
    }
}

/// One lane, one track (docs/design.md §11.9): a second stroke appears 0.8 m beside a tracked
/// line (a double marking, a road edge). The tracks started on it duplicate the line, and a
/// lane started this frame has no extent history to be merged on: it is held back from
/// publication in its first frame, so no published lane of age 0 lies within `min_spacing`
/// (mean over the index points both observed) of another published lane.
#[test]
fn a_duplicate_is_not_published_in_its_first_frame() {
    let mut t = tracker();
    let spacing = stjpdacf::persist::PersistConfig::DEFAULT.min_spacing;
    let (mut started, mut checked) = (0, 0);
    for k in 0..40u64 {
        let mut pts = frame(k, 0.0, 3);
        if k >= 10 {
            // The second stroke: the points of the line at 1.8 m, moved 0.8 m out.
            let stroke: Vec<[f32; 2]> = pts
                .iter()
                .filter(|p| (p[1] - 1.8).abs() < 0.3 && p[0] < 40.0)
                .map(|p| [p[0], p[1] + 0.8])
                .collect();
            pts.extend(stroke);
        }
        let out = t
            .step(Instant::from_micros(50_000 * (k as i64 + 1)), &pts)
            .unwrap();
        if k >= 10 {
            started += out.report.identity.started;
        }
        for a in out.filtered.iter().filter(|l| l.age == 0) {
            for b in out.filtered.iter().filter(|b| b.id != a.id) {
                let (lo, hi) = (a.u_first.max(b.u_first), a.u_last.min(b.u_last));
                let d: Vec<f32> = DEFAULT
                    .index_u
                    .iter()
                    .zip(a.z.iter().zip(b.z.iter()))
                    .filter(|(u, _)| **u >= lo && **u <= hi)
                    .map(|(_, (za, zb))| (za - zb).abs())
                    .collect();
                if d.len() >= 3 {
                    checked += 1;
                    let mean = d.iter().sum::<f32>() / d.len() as f32;
                    assert!(mean > spacing, "frame {k}: {a:?} duplicates {b:?}");
                }
            }
        }
    }
    println!("lanes started on the stroke: {started}; new lanes checked: {checked}");
    assert!(
        started > 0,
        "the stroke started no lane: the test saw no duplicate"
    );
}
