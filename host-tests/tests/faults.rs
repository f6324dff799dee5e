//! Fault injection: one named test per fault, on the `ReferenceTracker` (default tables) fed a
//! seeded three-lane road at 30 fps (lines at −3.6, 0 and 3.6 m with a gentle curve, 61 rows,
//! detection 0.9, σ = 5 cm, light clutter 0.005 /m/row). Each test states the expected behaviour
//! in its doc comment and checks, after the fault: the state is valid (the shared invariants of
//! `stjpdacf_host::invariants`: finite output, variances ≥ 0, covariance symmetric PSD within
//! tolerance), the counters say what happened, and tracking resumes within a stated number of
//! frames (measured, printed with `--nocapture`, asserted with margin).
//!
//! "Tracking" means: every true line has a published lane with `misses == 0` whose mean |Δx|
//! against the line over the index points inside its extent is below 0.3 m.
//!
//! Not here yet: corrupted SPI frames mid-stream (the frame decoder is written in another
//! branch; see the reliability report).
//!
//! `cargo test -p stjpdacf-host --test faults -- --nocapture`

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker, StepError, StepOutput};
use stjpdacf_host::invariants::{self, PsdCheck, POINTS};

/// Nominal frame step, µs (30 fps).
const FRAME_US: i64 = 33_333;
/// Lines of the road at u = 0.
const LINES: [f64; 3] = [-3.6, 0.0, 3.6];

type Out = StepOutput<6, POINTS>;

/// The road and its time.
struct Road {
    rng: ChaCha8Rng,
    t_us: i64,
    frame: u64,
    /// Lateral shift of the whole scene (bump tests), metres.
    shift: f64,
}

/// What one frame shows.
#[derive(Clone, Copy)]
struct Show {
    /// Which lines produce points.
    lines: [bool; 3],
    /// Lines produce points only at u ≥ this (near-range occlusion), metres.
    from_u: f64,
    /// Uniform clutter, points per metre per row over ±12 m.
    clutter: f64,
}

const NORMAL: Show = Show {
    lines: [true; 3],
    from_u: 0.0,
    clutter: 0.005,
};

impl Road {
    fn new(seed: u64) -> Self {
        Self {
            rng: ChaCha8Rng::seed_from_u64(seed),
            t_us: 0,
            frame: 0,
            shift: 0.0,
        }
    }

    /// True position of line `l` at `u`, now: a gentle curve that slowly changes.
    fn x(&self, l: usize, u: f64) -> f64 {
        let ts = self.t_us as f64 * 1e-6;
        let curv = 2e-4 * (0.2 * ts).sin();
        LINES[l] + self.shift + 0.1 * (0.3 * ts).sin() + 0.5 * curv * u * u
    }

    /// The points of one frame at the current time.
    fn points(&mut self, show: Show) -> Vec<[f32; 2]> {
        let noise = Normal::new(0.0, 0.05).expect("sigma");
        let (u0, du) = (
            f64::from(DEFAULT.hyper.u_min),
            f64::from(DEFAULT.hyper.row_step),
        );
        let mut pts = Vec::new();
        for r in 0..61 {
            let u = u0 + r as f64 * du;
            for l in 0..3 {
                if show.lines[l] && u >= show.from_u && self.rng.random_bool(0.9) {
                    pts.push([
                        u as f32,
                        (self.x(l, u) + noise.sample(&mut self.rng)) as f32,
                    ]);
                }
            }
            let n = (show.clutter * 24.0).floor() as usize
                + usize::from(self.rng.random_bool((show.clutter * 24.0).fract()));
            for _ in 0..n {
                pts.push([u as f32, self.rng.random_range(-12.0f32..12.0)]);
            }
        }
        pts
    }

    /// Advances the clock by `dt_us` (not on the first frame) and returns the frame time.
    fn tick(&mut self, dt_us: i64) -> Instant {
        if self.frame > 0 {
            self.t_us += dt_us;
        }
        self.frame += 1;
        Instant::from_micros(self.t_us)
    }
}

/// Steps the tracker and checks every invariant of the output and the state.
fn step(t: &mut ReferenceTracker, at: Instant, pts: &[[f32; 2]]) -> Out {
    let out = t.step(at, pts).expect("time increases");
    invariants::check_output(&out, pts.len()).expect("output invariants");
    invariants::check_tracker(t, PsdCheck::Cholesky).expect("state invariants");
    out
}

/// Whether every true line (of those in `lines`) is tracked (module docs).
fn tracking(out: &Out, road: &Road, lines: [bool; 3]) -> bool {
    (0..3).filter(|&l| lines[l]).all(|l| {
        out.filtered.iter().any(|lane| {
            let used: Vec<usize> = (0..POINTS)
                .filter(|&i| {
                    let u = DEFAULT.index_u[i];
                    u >= lane.u_first - 1.0 && u <= lane.u_last + 1.0
                })
                .collect();
            let err = used
                .iter()
                .map(|&i| (f64::from(lane.z[i]) - road.x(l, f64::from(DEFAULT.index_u[i]))).abs())
                .sum::<f64>()
                / used.len().max(1) as f64;
            lane.misses == 0 && !used.is_empty() && err < 0.3
        })
    })
}

fn ids(out: &Out) -> Vec<u32> {
    let mut v: Vec<u32> = out.filtered.iter().map(|l| l.id.0).collect();
    v.sort_unstable();
    v
}

/// Ids of the lanes that track the true lines (sorted).
fn tracked_ids(out: &Out, road: &Road) -> Vec<u32> {
    let mut v: Vec<u32> = (0..3)
        .filter_map(|l| {
            out.filtered
                .iter()
                .filter(|lane| lane.misses == 0)
                .min_by(|a, b| {
                    let ea = (f64::from(a.z[4]) - road.x(l, f64::from(DEFAULT.index_u[4]))).abs();
                    let eb = (f64::from(b.z[4]) - road.x(l, f64::from(DEFAULT.index_u[4]))).abs();
                    ea.total_cmp(&eb)
                })
                .map(|lane| lane.id.0)
        })
        .collect();
    v.sort_unstable();
    v
}

/// A tracker that has followed the road for 60 frames (2 s) and tracks all three lines.
fn settled(seed: u64) -> (Box<ReferenceTracker>, Road, Out) {
    let mut t = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut road = Road::new(seed);
    let mut last = None;
    for _ in 0..60 {
        let at = road.tick(FRAME_US);
        let pts = road.points(NORMAL);
        last = Some(step(&mut t, at, &pts));
    }
    let last = last.expect("frames");
    assert!(tracking(&last, &road, [true; 3]), "not settled");
    (t, road, last)
}

/// Runs normal frames until all lines are tracked; returns the number of frames it took
/// (1 = tracked on the first frame after the fault) or panics after `limit`.
fn recover(t: &mut ReferenceTracker, road: &mut Road, limit: usize) -> (usize, Out) {
    for k in 1..=limit {
        let at = road.tick(FRAME_US);
        let pts = road.points(NORMAL);
        let out = step(t, at, &pts);
        if tracking(&out, road, [true; 3]) {
            return (k, out);
        }
    }
    panic!("no recovery within {limit} frames");
}

/// **Camera blackout** of N empty frames, then the camera returns.
///
/// Expected: every blackout frame is accepted with 0 points in; the lanes coast (identity
/// `coasting` = 3, `misses` counting up, existence × 0.8 a frame) with finite, growing
/// variances; a blackout of ≤ 9 frames keeps the ids; at the 10th consecutive miss the lanes are
/// removed (`identity.removed` = 3) and the output is empty. When the camera returns, all lines
/// are tracked again within 1 frame (asserted ≤ 2), with the same ids after a short blackout
/// and new ids after a long one.
#[test]
fn camera_blackout_and_recovery() {
    for (n, keep_ids) in [(5usize, true), (9, true), (30, false)] {
        let (mut t, mut road, before) = settled(1);
        let mut removed = 0;
        let mut last_var = 0.0f32;
        for k in 1..=n {
            let at = road.tick(FRAME_US);
            let out = step(&mut t, at, &[]);
            assert_eq!(out.report.spatial.points_in, 0);
            removed += out.report.identity.removed;
            if k < 10 {
                assert_eq!(out.filtered.len(), 3, "blackout frame {k}");
                assert_eq!(out.report.identity.coasting, 3);
                assert!(out.filtered.iter().all(|l| usize::from(l.misses) == k));
                let v = out.filtered[0].var[8];
                assert!(v > last_var, "coasting variance grows");
                last_var = v;
            } else {
                assert!(out.filtered.is_empty(), "removed at the 10th miss");
            }
        }
        assert_eq!(removed, if n >= 10 { 3 } else { 0 });
        let (frames, after) = recover(&mut t, &mut road, 10);
        println!(
            "blackout of {n} frames: tracking again after {frames} frame(s), ids kept: {}",
            ids(&after) == ids(&before)
        );
        assert!(frames <= 2, "{frames}");
        assert_eq!(tracked_ids(&after, &road) == ids(&before), keep_ids);
    }
}

/// **All-clutter frames**: 30 frames (1 s) with no lane points, only uniform clutter at
/// 0.05 points per metre per row (≈ 73 points a frame), then the lanes return.
///
/// Expected: the clutter is counted (`spatial.clutter_points`), the true lanes coast and are
/// removed at their 10th miss; clutter may confirm false lanes (the known open problem of
/// dashed-tolerant confirmation, README "Open problems"), which are published with valid
/// state; nothing panics or goes non-finite. When the lanes return, all three are tracked within
/// 3 frames (measured; asserted ≤ 6: a lane whose last clutter-era state is far off is removed
/// and restarted).
#[test]
fn all_clutter_frames() {
    let (mut t, mut road, _) = settled(2);
    let mut clutter = 0;
    let mut false_lanes = 0;
    let show = Show {
        lines: [false; 3],
        from_u: 0.0,
        clutter: 0.05,
    };
    for _ in 0..30 {
        let at = road.tick(FRAME_US);
        let pts = road.points(show);
        let out = step(&mut t, at, &pts);
        clutter += out.report.spatial.clutter_points;
        false_lanes += out.filtered.iter().filter(|l| l.misses == 0).count();
    }
    assert!(clutter > 0);
    let (frames, _) = recover(&mut t, &mut road, 10);
    println!("all-clutter 30 frames: {clutter} clutter points, {false_lanes} false lane-frames; tracking again after {frames} frame(s)");
    assert!(frames <= 6, "{frames}");
}

/// **Frame rate 5× and 0.2× the nominal**: 150 frames at 150 fps (6.7 ms steps), then 30 frames
/// at 6 fps (167 ms steps), then nominal again.
///
/// Expected: every frame accepted with its own `dt` reported (the temporal model is exact for
/// any step); all three lines stay tracked on every frame with the same ids; no temporal
/// failure. Recovery: 0 frames (tracking is never lost).
#[test]
fn frame_rate_five_times_and_one_fifth() {
    let (mut t, mut road, before) = settled(3);
    for (dt, n) in [(FRAME_US / 5, 150), (FRAME_US * 5, 30)] {
        for k in 0..n {
            let at = road.tick(dt);
            let pts = road.points(NORMAL);
            let out = step(&mut t, at, &pts);
            assert!((f64::from(out.report.dt) - dt as f64 * 1e-6).abs() < 1e-6);
            assert_eq!(out.report.temporal_failures, 0);
            assert!(tracking(&out, &road, [true; 3]), "dt {dt} µs, frame {k}");
            assert_eq!(
                tracked_ids(&out, &road),
                ids(&before),
                "dt {dt} µs, frame {k}"
            );
        }
    }
    println!("5× and 0.2× frame rate: tracked on every frame, ids kept");
}

/// **Timestamp reversal and duplicates**: a frame with the previous frame's time, a frame 1 s in
/// the past, then normal frames; and a clock that jumps back for good (camera restart).
///
/// Expected: the duplicate and the reversed frame are refused with
/// `StepError::NonIncreasingTime` and leave the state bit for bit untouched (`frames()` does
/// not count them); the next normal frame is accepted and all lines are still tracked with the
/// same ids (recovery 0 frames). A clock that jumps back for good is refused on every frame
/// until it passes the last accepted time: the caller must detect it (every step returns the
/// error) and start a new tracker, which tracks all lines within 1 frame (asserted ≤ 2).
#[test]
fn timestamp_reversal_and_duplicates() {
    let (mut t, mut road, before) = settled(4);
    let frames = t.frames();
    let state = format!("{t:?}");
    let pts = road.points(NORMAL);
    let now = road.t_us;
    for bad in [now, now - 1_000_000, i64::MIN] {
        assert_eq!(
            t.step(Instant::from_micros(bad), &pts),
            Err(StepError::NonIncreasingTime)
        );
        assert_eq!(format!("{t:?}"), state, "refused step changed the state");
        assert_eq!(t.frames(), frames);
    }
    let at = road.tick(FRAME_US);
    let pts = road.points(NORMAL);
    let out = step(&mut t, at, &pts);
    assert!(tracking(&out, &road, [true; 3]));
    assert_eq!(tracked_ids(&out, &road), ids(&before));
    // The clock restarts at 0: refused while it is behind, a new tracker takes over.
    let mut refused = 0;
    let restart = Instant::from_micros(0);
    for k in 0..30i64 {
        if t.step(
            Instant::from_micros(restart.as_micros() + k * FRAME_US),
            &pts,
        ) == Err(StepError::NonIncreasingTime)
        {
            refused += 1;
        }
    }
    assert_eq!(refused, 30);
    let mut fresh = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut k = 0;
    loop {
        k += 1;
        road.t_us += FRAME_US;
        let pts = road.points(NORMAL);
        let out = step(
            &mut fresh,
            Instant::from_micros(restart.as_micros() + 30 * FRAME_US + k as i64 * FRAME_US),
            &pts,
        );
        if tracking(&out, &road, [true; 3]) || k > 5 {
            break;
        }
    }
    println!("timestamp faults: duplicate/reversed refused with the state intact; clock restart: {refused} frames refused, new tracker tracking after {k} frame(s)");
    assert!(k <= 2, "{k}");
}

/// **A burst of over-budget frames**: 10 frames of ~1,100 points each (the three lanes plus
/// dense clutter 0.6 /m/row), four times the M = 256 budget, given near rows first.
///
/// Expected: only the first 256 points are used, the rest counted in `over_budget_points`
/// (exactly `len − 256`); bounded work; the lanes are still published with valid state (the
/// cut loses the far rows, so they coast or are seen over the near range only). After the
/// burst all three lines are tracked within 1 frame (asserted ≤ 3).
#[test]
fn burst_of_over_budget_frames() {
    let (mut t, mut road, _) = settled(5);
    let show = Show {
        clutter: 0.6,
        ..NORMAL
    };
    let mut over = 0u64;
    for _ in 0..10 {
        let at = road.tick(FRAME_US);
        let pts = road.points(show);
        assert!(pts.len() > 1000);
        let out = step(&mut t, at, &pts);
        assert_eq!(out.report.over_budget_points as usize, pts.len() - 256);
        assert_eq!(out.report.spatial.points_in, 256);
        over += u64::from(out.report.over_budget_points);
    }
    let (frames, _) = recover(&mut t, &mut road, 10);
    println!("over-budget burst: {over} points over budget in 10 frames; tracking again after {frames} frame(s)");
    assert!(frames <= 3, "{frames}");
}

/// **A lane disappears under a truck for 2 s** (60 frames): the right line produces no points
/// at all; separately, a truck that hides only the near 30 m of the right line.
///
/// Expected, whole line hidden: the other two lines keep their ids and stay tracked on every
/// frame; the hidden line's lane coasts (misses 1…9) and is removed at its 10th miss
/// (`identity.removed` = 1); when the truck has passed it is tracked again within 1 frame
/// (asserted ≤ 2) under a new id. Near range hidden: the line is still seen beyond 30 m, so it
/// stays tracked with its id on every frame (recovery 0).
#[test]
fn lane_hidden_by_truck_for_two_seconds() {
    let (mut t, mut road, before) = settled(6);
    let hidden = Show {
        lines: [true, true, false],
        ..NORMAL
    };
    let mut removed = 0;
    for k in 1..=60 {
        let at = road.tick(FRAME_US);
        let pts = road.points(hidden);
        let out = step(&mut t, at, &pts);
        removed += out.report.identity.removed;
        assert!(tracking(&out, &road, [true, true, false]), "frame {k}");
    }
    assert_eq!(removed, 1);
    let (frames, after) = recover(&mut t, &mut road, 10);
    let kept: Vec<u32> = tracked_ids(&after, &road)
        .into_iter()
        .filter(|id| ids(&before).contains(id))
        .collect();
    assert_eq!(kept.len(), 2, "the two visible lines keep their ids");
    println!("truck hides a line for 2 s: other ids kept, hidden line tracked again after {frames} frame(s) with a new id");
    assert!(frames <= 2, "{frames}");

    let (mut t, mut road, before) = settled(7);
    let near = Show {
        from_u: 30.0,
        lines: [true; 3],
        ..NORMAL
    };
    for k in 1..=60 {
        let at = road.tick(FRAME_US);
        let mut pts = road.points(NORMAL);
        let far = road.points(near);
        // Right line: only its far part; others: everything.
        pts.retain(|p| f64::from(p[1]) < road.x(2, f64::from(p[0])) - 1.0);
        pts.extend(
            far.into_iter()
                .filter(|p| (f64::from(p[1]) - road.x(2, f64::from(p[0]))).abs() < 1.0),
        );
        let out = step(&mut t, at, &pts);
        assert!(
            tracking(&out, &road, [true; 3]),
            "near-range truck, frame {k}"
        );
        assert_eq!(tracked_ids(&out, &road), ids(&before), "frame {k}");
    }
    println!("truck hides the near 30 m of a line for 2 s: tracked with its id on every frame");
}

/// **A sudden 1 m lateral jump (bump)**: every point moves 1 m to the right from one frame to
/// the next; once as a transient (3 frames, then back) and once for good.
///
/// Expected: the jump is 1 m against predicted variances of a few cm², far outside the
/// identity gate (cost ≫ 9), so the shifted lanes do not match: they start under new ids while
/// the old lanes coast (identity `gated_out` > 0, `started` = 3). A transient bump: when the
/// points return, the coasting lanes match again and keep their ids (tracking resumes within 1
/// frame after the bump, asserted ≤ 2); the bump's lanes coast and are removed at their 10th
/// miss. A permanent jump: the new lanes track the shifted lines from the first shifted frame
/// (asserted ≤ 2) and the old ones are removed at their 10th miss.
#[test]
fn sudden_lateral_jump_of_one_metre() {
    // Transient.
    let (mut t, mut road, before) = settled(8);
    road.shift = 1.0;
    let mut gated = 0;
    for _ in 0..3 {
        let at = road.tick(FRAME_US);
        let pts = road.points(NORMAL);
        let out = step(&mut t, at, &pts);
        gated += out.report.identity.gated_out;
    }
    assert!(gated > 0);
    road.shift = 0.0;
    let (frames, after) = recover(&mut t, &mut road, 10);
    assert_eq!(
        tracked_ids(&after, &road),
        ids(&before),
        "ids kept after a transient bump"
    );
    println!("transient 1 m bump (3 frames): tracking with the old ids after {frames} frame(s)");
    assert!(frames <= 2, "{frames}");
    for _ in 0..12 {
        let at = road.tick(FRAME_US);
        let pts = road.points(NORMAL);
        step(&mut t, at, &pts);
    }
    // Permanent.
    let (mut t, mut road, before) = settled(9);
    road.shift = 1.0;
    let (frames, after) = recover(&mut t, &mut road, 10);
    let new_ids = tracked_ids(&after, &road);
    assert!(
        new_ids.iter().all(|id| !ids(&before).contains(id)),
        "new ids after a permanent jump"
    );
    let mut removed = 0;
    for _ in 0..12 {
        let at = road.tick(FRAME_US);
        let pts = road.points(NORMAL);
        let out = step(&mut t, at, &pts);
        removed += out.report.identity.removed;
        assert_eq!(tracked_ids(&out, &road), new_ids);
    }
    assert_eq!(removed, 3);
    println!("permanent 1 m jump: shifted lines tracked under new ids after {frames} frame(s), old lanes removed");
    assert!(frames <= 2, "{frames}");
}

/// **Points at the window edge and outside it**: on top of the normal lanes, points exactly at
/// `u_min` and `u_max`, half a row step inside and outside them, far outside (−1e6, 1e6 m),
/// lateral positions of ±1e3 m and ±1e30 m, non-finite coordinates, and subnormals.
///
/// Expected: a point is binned to its nearest row and accepted when that row is in the
/// window (`u_min − Δu/2 ≤ u < u_max + Δu/2`); the others are counted in
/// `spatial.rejected_window`, non-finite ones in `rejected_non_finite`; lateral positions are
/// not limited (a far lateral point is clutter for the gates). The three lines stay tracked
/// with their ids on every frame (recovery 0).
#[test]
fn points_at_window_edge_and_outside() {
    let (mut t, mut road, before) = settled(10);
    let (u0, u1, du) = (
        DEFAULT.hyper.u_min,
        DEFAULT.hyper.u_max,
        DEFAULT.hyper.row_step,
    );
    let outside = [
        [u0 - 0.51 * du, 0.5],
        [u1 + 0.51 * du, 0.5],
        [-1e6, 0.5],
        [1e6, 0.5],
        [f32::MIN, 0.5],
        [-1e-42, 0.5],
    ];
    let inside = [
        [u0, 7.0],
        [u1, 7.0],
        [u0 - 0.49 * du, -7.0],
        [u1 + 0.49 * du, -7.0],
        [40.0, 1e3],
        [41.0, -1e3],
        [42.0, 1e30],
        [43.0, -1e30],
        [44.0, 1e-42],
    ];
    let non_finite = [
        [f32::NAN, 0.0],
        [20.0, f32::INFINITY],
        [f32::NEG_INFINITY, f32::NAN],
    ];
    for k in 0..30 {
        let at = road.tick(FRAME_US);
        let mut pts = road.points(NORMAL);
        pts.extend(outside);
        pts.extend(inside);
        pts.extend(non_finite);
        let out = step(&mut t, at, &pts);
        assert_eq!(
            out.report.spatial.rejected_window as usize,
            outside.len(),
            "frame {k}"
        );
        assert_eq!(
            out.report.spatial.rejected_non_finite as usize,
            non_finite.len()
        );
        assert!(tracking(&out, &road, [true; 3]), "frame {k}");
        assert_eq!(tracked_ids(&out, &road), ids(&before), "frame {k}");
    }
    println!("window edges: {} rejected as outside, {} non-finite, lanes tracked with their ids on every frame", outside.len(), non_finite.len());
}
