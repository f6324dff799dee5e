//! Fault injection: one named test per fault, on the `ReferenceTracker` (default tables) fed a
//! seeded three-lane road at 30 fps (lines at −3.6, 0 and 3.6 m with a gentle curve, 61 rows,
//! detection 0.9, σ = 5 cm, light clutter 0.005 /m/row). Each test states the expected behaviour
//! in its doc comment and checks, after the fault: the state is valid (the shared invariants of
//! `stjpdacf_test_support::invariants`: finite output, variances ≥ 0, covariance symmetric PSD within
//! tolerance), the counters say what happened, and tracking resumes within a stated number of
//! frames (measured, printed with `--nocapture`, asserted with margin).
//!
//! "Tracking" means: every true line has a published lane with `misses == 0` whose mean |Δx|
//! against the line over the index points inside its extent is below 0.3 m.
//!
//! The last test sends the road through the SPI frame format (`stjpdacf::wire`) with corrupted
//! frames mid-stream.
//!
//! `cargo test -p stjpdacf-test-support --test faults -- --nocapture`

use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker, StepError, StepOutput};
use stjpdacf::wire::{self, LinkStats, ReadError, Receiver, WireError};
use stjpdacf_test_support::invariants::{self, PsdCheck, POINTS};

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

/// Runs normal frames until all lines are tracked ([`recover`], at most 10); prints `what` with
/// the number of frames that took and asserts it is at most `max`.
fn assert_recovers(t: &mut ReferenceTracker, road: &mut Road, max: usize, what: &str) {
    let (frames, _) = recover(t, road, 10);
    println!("{what}; tracking again after {frames} frame(s)");
    assert!(frames <= max, "{frames}");
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
            removed += out.report.identity.removed + out.report.known.deleted;
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
/// dashed-tolerant confirmation, docs/measurements.md, "Open problems"), which are published with valid
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
    let what =
        format!("all-clutter 30 frames: {clutter} clutter points, {false_lanes} false lane-frames");
    assert_recovers(&mut t, &mut road, 6, &what);
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
    let what = format!("over-budget burst: {over} points over budget in 10 frames");
    assert_recovers(&mut t, &mut road, 3, &what);
}

/// **A lane disappears under a truck for 2 s** (60 frames): the right line produces no points
/// at all; separately, a truck that hides only the near 30 m of the right line.
///
/// Expected, whole line hidden: the other two lines keep their ids and stay tracked on every
/// frame; the hidden line's lane coasts and is removed once its existence falls below
/// `p_delete` (docs/design.md §11.5; at the latest at its 10th miss: `identity.removed +
/// known.deleted` = 1); when the truck has passed it is tracked again within 1 frame
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
        removed += out.report.identity.removed + out.report.known.deleted;
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
/// frame after the bump, asserted ≤ 2: three frames of seeing nothing cost a lane at most
/// 3·ln(1 − p_visible) of existence, docs/design.md §11.5); the bump's lanes coast and are
/// removed. A permanent jump: the new lanes track the shifted lines from the first shifted frame
/// (asserted ≤ 2) and the old ones are removed (existence below `p_delete` or 10th miss).
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
        removed += out.report.identity.removed + out.report.known.deleted;
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

/// A vision front end on SPI as `stjpdacf::wire` describes it: every chip-select window reads the
/// frame it currently publishes from its first byte (zeros past its end). The test publishes one
/// buffer per `Receiver::read`; `fail` makes the next transaction fail.
struct FrontEnd {
    current: Vec<u8>,
    fail: bool,
}

impl ErrorType for FrontEnd {
    type Error = ErrorKind;
}

impl SpiDevice for FrontEnd {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        if std::mem::take(&mut self.fail) {
            return Err(ErrorKind::Overrun);
        }
        for op in ops.iter_mut() {
            let Operation::Read(buf) = op else {
                panic!("the receiver only reads")
            };
            for (i, b) in buf.iter_mut().enumerate() {
                *b = self.current.get(i).copied().unwrap_or(0);
            }
        }
        Ok(())
    }
}

/// One buffer on the link and what each receiver must make of it.
struct Sent {
    bytes: Vec<u8>,
    /// `Receiver::accept` (the whole buffer at once).
    accept: Result<(), WireError>,
    /// `Receiver::read` (two SPI windows; a cut frame reads as zeros past its end).
    read: Result<(), ReadError<ErrorKind>>,
    /// Offered only to the SPI path, whose transaction fails.
    spi_fails: bool,
}

impl Sent {
    fn good(bytes: Vec<u8>) -> Self {
        Self::bad(bytes, Ok(()), Ok(()))
    }

    fn bad(bytes: Vec<u8>, accept: Result<(), WireError>, read: Result<(), WireError>) -> Self {
        Self {
            bytes,
            accept,
            read: read.map_err(ReadError::Frame),
            spi_fails: false,
        }
    }
}

fn encode(seq: u32, t_us: i64, pts: &[[f32; 2]]) -> Vec<u8> {
    let mut f = vec![0u8; wire::frame_len(pts.len())];
    wire::encode(seq, Instant::from_micros(t_us), pts, &mut f).expect("encodable frame");
    f
}

/// Rewrites the CRC of a frame after an edit.
fn reseal(f: &mut [u8]) {
    let body = f.len() - wire::CRC_LEN;
    let crc = wire::crc32(&f[..body]);
    f[body..].copy_from_slice(&crc.to_le_bytes());
}

/// Checks what one receiver path (`path`: accept or read) answered for frame `k` against what
/// was expected: an accepted frame carries the sent `(seq, time, count)`; a refused one gives the
/// expected error and leaves the points `p` unwritten. Returns the answer.
fn check_path<E: PartialEq + std::fmt::Debug>(
    k: u32,
    path: &str,
    r: Result<wire::FrameInfo, E>,
    expected: Result<(), E>,
    sent: (u32, Instant, usize),
    p: &[[f32; 2]],
) -> Result<wire::FrameInfo, E> {
    match (r, expected) {
        (Ok(i), Ok(())) => {
            assert_eq!((i.seq, i.time, i.count), sent);
            Ok(i)
        }
        (Err(e), Err(w)) => {
            assert_eq!(e, w, "frame {k}");
            assert!(p.iter().all(|v| v[0].is_nan()), "refused, points written");
            Err(e)
        }
        (r, w) => panic!("frame {k}: {path} gives {r:?}, expected {w:?}"),
    }
}

/// Adds `e` to the counter `LinkStats` keeps for it.
fn count(s: &mut LinkStats, e: WireError) {
    let c = match e {
        WireError::Truncated => &mut s.truncated,
        WireError::BadMagic => &mut s.bad_magic,
        WireError::BadVersion => &mut s.bad_version,
        WireError::Oversized { .. } => &mut s.oversized,
        WireError::BadCrc => &mut s.bad_crc,
        WireError::NonIncreasingSequence => &mut s.non_increasing_seq,
        WireError::NonIncreasingTime => &mut s.non_increasing_time,
        _ => panic!("unknown error {e:?}"),
    };
    *c += 1;
}

/// **Corrupted SPI frames mid-stream**: after 60 good frames the road is sent for 90 more in the
/// SPI frame format (`stjpdacf::wire`, sequence numbers from 1000), with 18 faulty frames
/// mid-stream, each sent before the frame's good copy or instead of it (the frame is then lost,
/// 9 of 90): a flipped payload bit, 8 flipped payload/CRC bits, a flipped magic bit, a frame cut
/// in half or to 10 bytes, 64–1,100 random bytes (twice, and a flood of five), the previous
/// frame again, a new frame with the previous sequence number, a timestamp 1 s back and one
/// equal to the previous frame's, 300 points (over M = 256), a header announcing 65,535 points,
/// version 2 (CRC resealed where the fault is not the CRC's business), three frames in a row
/// lost to bit flips; and on the SPI path a failed transaction (the frame is read again). The
/// stream goes to three trackers cloned from the
/// same settled tracker: one through `Receiver::accept`, one through `Receiver::read` on an
/// `embedded-hal` SPI front-end mock, and one fed directly with the good frames that arrived.
///
/// Expected: every bad buffer is refused with its typed error (through SPI a cut frame reads as
/// zeros past its end, so it fails the CRC: `BadCrc` instead of `Truncated`; a failed transaction
/// is `ReadError::Spi`), counted in `LinkStats` (counters exactly as scheduled, lost frames in
/// `skipped`), and leaves the point buffer untouched, so the trackers never see it; every good
/// frame is accepted; both trackers behind a receiver publish exactly the output of the tracker
/// fed only the good frames, and every frame keeps the invariants. Tracking is never lost (all
/// lines tracked with their ids on every accepted frame): recovery 0 frames.
#[test]
fn corrupted_spi_frames_mid_stream() {
    let (settled_tracker, mut road, before) = settled(11);
    let mut direct = settled_tracker.clone();
    let mut via_accept = settled_tracker.clone();
    let mut via_spi = settled_tracker;
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let mut rx = Receiver::new();
    let mut rx_spi = Receiver::new();
    let mut fe = FrontEnd {
        current: Vec::new(),
        fail: false,
    };
    let mut spi_buf = vec![0u8; wire::frame_len(256)];
    let mut want = LinkStats::default();
    let mut want_spi = LinkStats::default();
    let mut prev: Option<(u32, i64, Vec<u8>)> = None;
    let (mut faults, mut lost, mut accepted) = (0, 0, 0);
    for k in 0..90u32 {
        let seq = 1000 + k;
        let at = road.tick(FRAME_US);
        let t_us = at.as_micros();
        let pts = road.points(NORMAL);
        assert!(pts.len() <= 256, "{} points", pts.len());
        let good = encode(seq, t_us, &pts);
        let len = good.len();
        let flip = |f: &mut Vec<u8>, rng: &mut ChaCha8Rng, bits: usize| {
            for _ in 0..bits {
                let bit = rng.random_range(8 * wire::HEADER_LEN..8 * len);
                f[bit / 8] ^= 1 << (bit % 8);
            }
        };
        let garbage = |rng: &mut ChaCha8Rng| {
            let mut g = vec![0u8; rng.random_range(64..1100)];
            rng.fill(&mut g[..]);
            g
        };
        let (pseq, pt, pframe) = prev.clone().unwrap_or((seq, t_us, good.clone()));
        // The fault, and whether the good frame follows it (else it is lost).
        let (bad, then_good): (Vec<Sent>, bool) = match k {
            10 | 12 | 74..=76 => {
                let mut f = good.clone();
                flip(&mut f, &mut rng, if k == 10 { 1 } else { 8 });
                let e = Err(WireError::BadCrc);
                (vec![Sent::bad(f, e, e)], k == 10)
            }
            14 => {
                let mut f = good.clone();
                f[2] ^= 0x40;
                let e = Err(WireError::BadMagic);
                (vec![Sent::bad(f, e, e)], true)
            }
            20 | 22 => {
                let cut = if k == 20 { len / 2 } else { 10 };
                let f = good[..cut].to_vec();
                let (ea, er) = (Err(WireError::Truncated), Err(WireError::BadCrc));
                (vec![Sent::bad(f, ea, er)], k == 20)
            }
            30 | 32 | 80 => {
                let n = if k == 80 { 5 } else { 1 };
                let e = Err(WireError::BadMagic);
                let v = (0..n).map(|_| Sent::bad(garbage(&mut rng), e, e)).collect();
                (v, k != 30)
            }
            40 => {
                let e = Err(WireError::NonIncreasingSequence);
                (vec![Sent::bad(pframe, e, e)], true)
            }
            42 => {
                let e = Err(WireError::NonIncreasingSequence);
                (vec![Sent::bad(encode(pseq, t_us, &pts), e, e)], false)
            }
            50 | 52 => {
                let stale = if k == 50 { pt - 1_000_000 } else { pt };
                let e = Err(WireError::NonIncreasingTime);
                (vec![Sent::bad(encode(seq, stale, &pts), e, e)], k == 50)
            }
            60 => {
                let mut more = pts.clone();
                while more.len() < 300 {
                    more.push([rng.random_range(3.0..80.0), rng.random_range(-12.0..12.0)]);
                }
                let e = Err(WireError::Oversized { count: 300 });
                (vec![Sent::bad(encode(seq, t_us, &more), e, e)], true)
            }
            62 => {
                let mut f = good.clone();
                f[6..8].copy_from_slice(&u16::MAX.to_le_bytes());
                reseal(&mut f);
                let e = Err(WireError::Oversized { count: u16::MAX });
                (vec![Sent::bad(f, e, e)], false)
            }
            70 => {
                let mut f = good.clone();
                f[4] = 2;
                reseal(&mut f);
                let e = Err(WireError::BadVersion);
                (vec![Sent::bad(f, e, e)], true)
            }
            72 => {
                // An SPI transaction fails; the MCU reads the frame again.
                let mut s = Sent::good(good.clone());
                s.read = Err(ReadError::Spi(ErrorKind::Overrun));
                s.spi_fails = true;
                (vec![s], true)
            }
            _ => (Vec::new(), true),
        };
        faults += usize::from(!bad.is_empty());
        let mut sent = bad;
        if then_good {
            sent.push(Sent::good(good.clone()));
        } else {
            lost += 1;
        }
        // The direct tracker sees the good frame (as decoded: the receivers' points are
        // quantised to 1/256 m) if it arrives.
        let mut q = [[0.0f32; 2]; 256];
        let info = wire::decode(&good, &mut q).expect("good frame");
        let clean = then_good.then(|| step(&mut direct, at, &q[..info.count]));
        let mut outs = Vec::new();
        for s in &sent {
            let mut p = [[f32::NAN; 2]; 256];
            let r = if s.spi_fails {
                Err(WireError::BadMagic) // not offered
            } else {
                rx.accept(&s.bytes, &mut p)
            };
            if !s.spi_fails {
                match check_path(k, "accept", r, s.accept, (seq, at, info.count), &p) {
                    Ok(i) => outs.push(("accept", step(&mut via_accept, i.time, &p[..i.count]))),
                    Err(e) => count(&mut want, e),
                }
            }
            fe.current.clone_from(&s.bytes);
            fe.fail = s.spi_fails;
            let mut p = [[f32::NAN; 2]; 256];
            let r = rx_spi.read(&mut fe, &mut spi_buf, &mut p);
            match check_path(k, "read", r, s.read, (seq, at, info.count), &p) {
                Ok(i) => outs.push(("read", step(&mut via_spi, i.time, &p[..i.count]))),
                Err(ReadError::Frame(e)) => count(&mut want_spi, e),
                Err(ReadError::Spi(_)) => want_spi.spi_errors += 1,
            }
        }
        assert_eq!(outs.len(), if then_good { 2 } else { 0 }, "frame {k}");
        for (path, out) in &outs {
            assert_eq!(
                Some(out),
                clean.as_ref(),
                "frame {k}: {path} output differs"
            );
        }
        if let Some(out) = &clean {
            accepted += 1;
            assert!(tracking(out, &road, [true; 3]), "frame {k}");
            assert_eq!(tracked_ids(out, &road), ids(&before), "frame {k}");
            if let Some((s, _, _)) = &prev {
                want.skipped += seq - s - 1;
                want_spi.skipped += seq - s - 1;
            }
            want.frames += 1;
            want_spi.frames += 1;
            prev = Some((seq, t_us, good.clone()));
        }
        assert_eq!(*rx.stats(), want, "frame {k}: accept counters");
        assert_eq!(*rx_spi.stats(), want_spi, "frame {k}: read counters");
    }
    assert_eq!(accepted + lost, 90);
    // 18 faulty frames, one of them a flood of five garbage buffers: 22 refusals; 9 frames lost.
    assert_eq!((faults, want.rejected(), lost), (19, 22, 9));
    assert_eq!(
        (
            want.skipped as usize,
            want_spi.truncated,
            want_spi.spi_errors
        ),
        (lost, 0, 1)
    );
    println!(
        "corrupted SPI frames: {faults} faults, {lost} frames lost, {accepted} accepted; \
         accept: {:?}; read: {:?}; output identical to the good frames only, tracked with the \
         same ids on every accepted frame (recovery 0)",
        rx.stats(),
        rx_spi.stats()
    );
}
