//! The C API's rejection paths, and one frame against the Rust tracker.

use super::*;
use core::ptr::{null, null_mut};
use std::boxed::Box;
use std::vec;
use std::vec::Vec;

/// An 8-aligned buffer of `STJPDACF_TRACKER_SIZE` bytes (plus one word for misaligned views).
fn buffer() -> Vec<u64> {
    vec![0u64; STJPDACF_TRACKER_SIZE / 8 + 1]
}

fn init(buf: &mut [u64]) -> *mut stjpdacf_tracker {
    let mut t = null_mut();
    // SAFETY: `buf` holds `STJPDACF_TRACKER_SIZE` writable, aligned bytes; `t` is writable.
    let st = unsafe { stjpdacf_init(buf.as_mut_ptr().cast(), STJPDACF_TRACKER_SIZE, &mut t) };
    assert_eq!(st, STJPDACF_OK);
    assert_eq!(t.cast::<u64>(), buf.as_mut_ptr());
    t
}

/// A report of zeros (what no step wrote).
fn zero_report() -> stjpdacf_report {
    stjpdacf_report {
        filtered_lanes: 0,
        smoothed_lanes: 0,
        step: StepReport {
            spatial: Default::default(),
            identity: Default::default(),
            over_budget_points: 0,
            temporal_failures: 0,
            dt: 0.0,
            pseudo_cov_repairs: 0,
            temporal_cov_repairs: 0,
            known: Default::default(),
        },
    }
}

/// Two straight lanes 3.6 m apart, one point per BEV row (the core's doc example).
fn two_lanes() -> Vec<f32> {
    (0..60)
        .flat_map(|r| {
            let u = 3.0 + r as f32 * 77.0 / 60.0;
            [u, -1.8, u, 1.8]
        })
        .collect()
}

#[test]
fn the_size_constants_cover_the_tracker() {
    let size = core::mem::size_of::<stjpdacf_tracker>();
    std::println!("size_of::<stjpdacf_tracker>() = {size}");
    assert!(size <= STJPDACF_TRACKER_SIZE);
    // Not wastefully large either (a few hundred bytes of slack for 32-bit targets).
    assert!(STJPDACF_TRACKER_SIZE - size < 1024);
}

#[test]
fn init_rejects_bad_buffers() {
    let mut buf = buffer();
    let mut t = null_mut();
    let p = buf.as_mut_ptr().cast::<u8>();
    // SAFETY: all calls: the pointers are null, or into `buf`, or to `t`.
    unsafe {
        assert_eq!(
            stjpdacf_init(null_mut(), STJPDACF_TRACKER_SIZE, &mut t),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            stjpdacf_init(p.cast(), STJPDACF_TRACKER_SIZE, null_mut()),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            stjpdacf_init(p.add(4).cast(), STJPDACF_TRACKER_SIZE, &mut t),
            STJPDACF_MISALIGNED
        );
        assert_eq!(
            stjpdacf_init(p.cast(), STJPDACF_TRACKER_SIZE - 1, &mut t),
            STJPDACF_BUFFER_TOO_SMALL
        );
    }
    assert!(t.is_null(), "nothing written on refusal");
    assert!(buf.iter().all(|&w| w == 0), "buffer untouched on refusal");
}

#[test]
fn step_rejects_bad_arguments_and_leaves_the_tracker_untouched() {
    let pts = two_lanes();
    let n = pts.len() / 2;
    let mut lanes = [NO_LANE; STJPDACF_MAX_LANES];
    let mut rep = zero_report();
    // An aligned, zeroed buffer never initialised.
    let mut raw = buffer();
    let mut buf = buffer();
    let t = init(&mut buf);
    let unaligned_pts = pts.as_ptr().cast::<u8>().wrapping_add(1).cast::<f32>();
    // SAFETY: all calls: every pointer is null, valid for its claimed size, or deliberately
    // misaligned / uninitialised (refused before any read).
    unsafe {
        let step = |t, time, p, n, l, c, r| stjpdacf_step(t, time, p, n, l, c, r);
        let lp = lanes.as_mut_ptr();
        assert_eq!(
            step(null_mut(), 0, pts.as_ptr(), n, lp, 6, &mut rep),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            step(raw.as_mut_ptr().cast(), 0, pts.as_ptr(), n, lp, 6, &mut rep),
            STJPDACF_NOT_INITIALISED
        );
        assert_eq!(
            step(
                buf.as_mut_ptr().cast::<u8>().add(4).cast(),
                0,
                pts.as_ptr(),
                n,
                lp,
                6,
                &mut rep
            ),
            STJPDACF_MISALIGNED
        );
        assert_eq!(
            step(t, 0, null(), n, lp, 6, &mut rep),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            step(t, 0, unaligned_pts, n, lp, 6, &mut rep),
            STJPDACF_MISALIGNED
        );
        assert_eq!(
            step(
                t,
                0,
                pts.as_ptr(),
                STJPDACF_MAX_POINTS_IN + 1,
                lp,
                6,
                &mut rep
            ),
            STJPDACF_TOO_MANY_POINTS
        );
        assert_eq!(
            step(t, 0, pts.as_ptr(), n, lp, 5, &mut rep),
            STJPDACF_CAPACITY_TOO_SMALL
        );
        assert_eq!(
            step(t, 0, pts.as_ptr(), n, null_mut(), 6, &mut rep),
            STJPDACF_NULL_POINTER
        );
        let bad_report = (&mut rep as *mut stjpdacf_report)
            .cast::<u8>()
            .add(1)
            .cast();
        assert_eq!(
            step(t, 0, pts.as_ptr(), n, lp, 6, bad_report),
            STJPDACF_MISALIGNED
        );
        assert_eq!(lanes, [NO_LANE; STJPDACF_MAX_LANES], "no lane written");
        assert_eq!(rep, zero_report(), "no report written");
        assert_eq!((*t).h.tracker.frames(), 0, "tracker untouched");
        // The first valid frame, then the same time again.
        assert_eq!(
            step(t, 1_000, pts.as_ptr(), n, lp, 6, &mut rep),
            STJPDACF_OK
        );
        assert_eq!(rep.filtered_lanes, 2);
        let before = rep;
        assert_eq!(
            step(t, 1_000, pts.as_ptr(), n, null_mut(), 0, &mut rep),
            STJPDACF_NON_INCREASING_TIME
        );
        assert_eq!(rep, before, "no report written on refusal");
        assert_eq!((*t).h.tracker.frames(), 1);
    }
    raw.clear();
}

#[test]
fn readouts_reject_bad_arguments() {
    let mut buf = buffer();
    let t = init(&mut buf);
    let mut lanes = [NO_LANE; STJPDACF_MAX_LANES];
    let mut n = 99usize;
    let (mut x, mut var) = (0.0f32, 0.0f32);
    let mut model = stjpdacf_model::default();
    // SAFETY: all calls: pointers valid for their claims, or null.
    unsafe {
        let lp = lanes.as_mut_ptr();
        assert_eq!(
            stjpdacf_filtered(null(), lp, 6, &mut n),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            stjpdacf_filtered(t, null_mut(), 0, &mut n),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            stjpdacf_smoothed(t, lp, 2, &mut n),
            STJPDACF_CAPACITY_TOO_SMALL
        );
        assert_eq!(
            stjpdacf_smoothed(t, lp, 6, null_mut()),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(n, 99);
        assert_eq!(stjpdacf_filtered(t, lp, 6, &mut n), STJPDACF_OK);
        assert_eq!(n, 0);
        assert_eq!(
            stjpdacf_lane_at(t, 0, 10.0, &mut x, &mut var),
            STJPDACF_NO_LANE
        );
        assert_eq!(
            stjpdacf_lane_at(t, 0, 10.0, null_mut(), &mut var),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            stjpdacf_lane_at(null(), 0, 10.0, &mut x, null_mut()),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(stjpdacf_model_info(null_mut()), STJPDACF_NULL_POINTER);
        assert_eq!(stjpdacf_model_info(&mut model), STJPDACF_OK);
    }
    assert!(model.u_min < model.u_max && model.index_u[0] >= model.u_min);
}

#[test]
fn decode_maps_every_wire_error() {
    let pts = [[10.0f32, 1.5], [20.0, -1.5]];
    let mut frame = [0u8; 64];
    let len = wire::encode(7, Instant::from_micros(42), &pts, &mut frame).unwrap();
    let mut out = [0.0f32; 4];
    let mut info = stjpdacf_frame_info::default();
    // SAFETY: all calls: pointers valid for their claims, or null.
    unsafe {
        let op = out.as_mut_ptr();
        assert_eq!(
            stjpdacf_decode_frame(frame.as_ptr(), len, op, 2, &mut info),
            STJPDACF_OK
        );
        assert_eq!(
            (info.seq, info.count, info.time_us, info.len),
            (7, 2, 42, len)
        );
        assert_eq!(out, [10.0, 1.5, 20.0, -1.5]);
        assert_eq!(
            stjpdacf_decode_frame(frame.as_ptr(), len - 1, op, 2, &mut info),
            STJPDACF_WIRE_TRUNCATED
        );
        assert_eq!(
            stjpdacf_decode_frame(frame.as_ptr(), len, op, 1, &mut info),
            STJPDACF_WIRE_OVERSIZED
        );
        assert_eq!(
            stjpdacf_decode_frame(frame.as_ptr(), len, null_mut(), 2, &mut info),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            stjpdacf_decode_frame(null(), len, op, 2, &mut info),
            STJPDACF_NULL_POINTER
        );
        assert_eq!(
            stjpdacf_decode_frame(frame.as_ptr(), len, op, 2, null_mut()),
            STJPDACF_NULL_POINTER
        );
        let mut bad = frame;
        bad[0] ^= 1;
        assert_eq!(
            stjpdacf_decode_frame(bad.as_ptr(), len, op, 2, &mut info),
            STJPDACF_WIRE_BAD_MAGIC
        );
        let mut bad = frame;
        bad[len - 1] ^= 1;
        assert_eq!(
            stjpdacf_decode_frame(bad.as_ptr(), len, op, 2, &mut info),
            STJPDACF_WIRE_BAD_CRC
        );
    }
    let all = [
        (WireError::BadVersion, STJPDACF_WIRE_BAD_VERSION),
        (
            WireError::NonIncreasingSequence,
            STJPDACF_WIRE_NON_INCREASING_SEQUENCE,
        ),
        (
            WireError::NonIncreasingTime,
            STJPDACF_WIRE_NON_INCREASING_TIME,
        ),
    ];
    for (e, s) in all {
        assert_eq!(stjpdacf_status::from(e), s);
    }
}

/// One frame of a Rust tracker, as the C API should give it back.
struct Want {
    filtered: Vec<stjpdacf_lane>,
    smoothed: Vec<stjpdacf_lane>,
    report: StepReport,
    /// `lane_at(slot, 30 m)` of each filtered lane.
    at_30: Vec<Option<(f32, f32)>>,
}

/// A Rust tracker's step on `two_lanes`, as a [`Want`].
macro_rules! want_of {
    ($rust:expr, $time:expr, $pairs:expr) => {{
        let out = $rust.step(Instant::from_micros($time), $pairs).unwrap();
        Want {
            filtered: out.filtered.iter().map(stjpdacf_lane::from).collect(),
            smoothed: out.smoothed.iter().map(stjpdacf_lane::from).collect(),
            report: out.report,
            at_30: out
                .filtered
                .iter()
                .map(|r| $rust.lane_at(usize::from(r.slot), 30.0))
                .collect(),
        }
    }};
}

/// The C entry points of one model.
struct Entry<H> {
    step: unsafe extern "C" fn(
        *mut H,
        i64,
        *const f32,
        usize,
        *mut stjpdacf_lane,
        usize,
        *mut stjpdacf_report,
    ) -> stjpdacf_status,
    filtered:
        unsafe extern "C" fn(*const H, *mut stjpdacf_lane, usize, *mut usize) -> stjpdacf_status,
    smoothed:
        unsafe extern "C" fn(*const H, *mut stjpdacf_lane, usize, *mut usize) -> stjpdacf_status,
    lane_at: unsafe extern "C" fn(*const H, u32, f32, *mut f32, *mut f32) -> stjpdacf_status,
}

/// Steps the C tracker `t` through 8 frames of `two_lanes` and checks every frame against
/// `rust` (the same model's Rust tracker, stepped by the closure): the step's lanes and report,
/// the filtered and smoothed read-outs and `lane_at` at 30 m. Returns the last report and the
/// lanes published over the run.
fn lanes_match<H>(
    t: *mut H,
    api: &Entry<H>,
    mut rust: impl FnMut(i64, &[[f32; 2]]) -> Want,
) -> (stjpdacf_report, usize) {
    let pts = two_lanes();
    let pairs: Vec<[f32; 2]> = pts.chunks(2).map(|c| [c[0], c[1]]).collect();
    let mut rep = zero_report();
    let mut published = 0;
    for k in 0..8i64 {
        let time = k * 50_000;
        let want = rust(time, &pairs);
        let mut lanes = [NO_LANE; STJPDACF_MAX_LANES];
        // SAFETY: `t` is an initialised tracker of this model; the arrays are valid for their
        // sizes.
        let st = unsafe {
            (api.step)(
                t,
                time,
                pts.as_ptr(),
                pairs.len(),
                lanes.as_mut_ptr(),
                lanes.len(),
                &mut rep,
            )
        };
        assert_eq!(st, STJPDACF_OK);
        assert_eq!(
            rep,
            stjpdacf_report {
                filtered_lanes: want.filtered.len() as u32,
                smoothed_lanes: want.smoothed.len() as u32,
                step: want.report,
            }
        );
        assert_eq!(&lanes[..want.filtered.len()], &want.filtered[..]);
        let mut got = [NO_LANE; STJPDACF_MAX_LANES];
        let mut n = 0;
        // SAFETY: as above.
        let st = unsafe { (api.filtered)(t, got.as_mut_ptr(), got.len(), &mut n) };
        assert_eq!(st, STJPDACF_OK);
        assert_eq!(&got[..n], &want.filtered[..]);
        for (c, at) in want.filtered.iter().zip(&want.at_30) {
            let (mut x, mut var) = (0.0, 0.0);
            // SAFETY: as above.
            let st = unsafe { (api.lane_at)(t, c.slot, 30.0, &mut x, &mut var) };
            assert_eq!(st, STJPDACF_OK);
            assert_eq!(Some((x, var)), *at);
            published += 1;
        }
        let mut sm = [NO_LANE; STJPDACF_MAX_LANES];
        // SAFETY: as above.
        let st = unsafe { (api.smoothed)(t, sm.as_mut_ptr(), sm.len(), &mut n) };
        assert_eq!(st, STJPDACF_OK);
        assert_eq!(&sm[..n], &want.smoothed[..]);
    }
    (rep, published)
}

/// The reference model through the C API equals `ReferenceTracker` on the default tables,
/// frame by frame.
#[test]
fn lanes_match_the_rust_tracker() {
    let mut rust = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut buf = buffer();
    let api = Entry {
        step: stjpdacf_step,
        filtered: stjpdacf_filtered,
        smoothed: stjpdacf_smoothed,
        lane_at: stjpdacf_lane_at,
    };
    let (rep, published) = lanes_match(init(&mut buf), &api, |time, pairs| {
        want_of!(rust, time, pairs)
    });
    assert!(published >= 8, "lanes were published ({published})");
    assert_eq!(
        rep.smoothed_lanes, 2,
        "the smoother window is full after 5 frames"
    );
}

#[test]
fn over_budget_points_are_degraded_not_refused() {
    let mut buf = buffer();
    let t = init(&mut buf);
    let pts = vec![0.0f32; 2 * (STJPDACF_MAX_POINTS + 10)];
    let mut rep = zero_report();
    // SAFETY: `t` from `init`; `pts` holds the floats claimed.
    let st = unsafe { stjpdacf_step(t, 0, pts.as_ptr(), pts.len() / 2, null_mut(), 0, &mut rep) };
    assert_eq!(st, STJPDACF_DEGRADED);
    assert_eq!(rep.step.over_budget_points, 10);
}

#[test]
fn the_small_size_constant_covers_its_tracker() {
    let size = core::mem::size_of::<stjpdacf_small_tracker>();
    std::println!("size_of::<stjpdacf_small_tracker>() = {size}");
    assert!(size <= STJPDACF_SMALL_TRACKER_SIZE);
    assert!(STJPDACF_SMALL_TRACKER_SIZE - size < 1024);
}

#[test]
fn small_init_and_readouts_reject_bad_arguments() {
    let mut buf = vec![0u64; STJPDACF_SMALL_TRACKER_SIZE / 8 + 1];
    let mut t = null_mut();
    // SAFETY: `buf` holds more than the sizes given; `t` is writable.
    unsafe {
        assert_eq!(
            stjpdacf_small_init(
                buf.as_mut_ptr().cast(),
                STJPDACF_SMALL_TRACKER_SIZE - 1,
                &mut t
            ),
            STJPDACF_BUFFER_TOO_SMALL
        );
        assert!(t.is_null(), "nothing written");
        assert_eq!(
            stjpdacf_small_init(
                buf.as_mut_ptr().cast::<u8>().add(4).cast(),
                STJPDACF_SMALL_TRACKER_SIZE,
                &mut t
            ),
            STJPDACF_MISALIGNED
        );
        assert_eq!(
            stjpdacf_small_init(null_mut(), STJPDACF_SMALL_TRACKER_SIZE, &mut t),
            STJPDACF_NULL_POINTER
        );
    }
    // A buffer never initialised is refused by every entry point.
    let raw = buf.as_mut_ptr().cast::<stjpdacf_small_tracker>();
    let pts = two_lanes();
    let mut lanes = [NO_LANE; STJPDACF_MAX_LANES];
    let mut n = 0usize;
    let (mut x, mut var) = (0.0f32, 0.0f32);
    // SAFETY: `raw` points to writable, aligned memory of the small tracker's size; the arrays
    // are valid for their sizes.
    unsafe {
        let st = stjpdacf_small_step(raw, 0, pts.as_ptr(), 60, null_mut(), 0, null_mut());
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
        let st = stjpdacf_small_filtered(raw, lanes.as_mut_ptr(), lanes.len(), &mut n);
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
        let st = stjpdacf_small_smoothed(raw, lanes.as_mut_ptr(), lanes.len(), &mut n);
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
        let st = stjpdacf_small_lane_at(raw, 0, 30.0, &mut x, &mut var);
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
    }
    let mut t = null_mut();
    // SAFETY: as above, the full size.
    let st = unsafe {
        stjpdacf_small_init(buf.as_mut_ptr().cast(), STJPDACF_SMALL_TRACKER_SIZE, &mut t)
    };
    assert_eq!(st, STJPDACF_OK);
    // SAFETY: `t` from `stjpdacf_small_init`; the arrays are valid for their sizes.
    unsafe {
        let st = stjpdacf_small_step(t, 0, pts.as_ptr(), 60, lanes.as_mut_ptr(), 5, null_mut());
        assert_eq!(st, STJPDACF_CAPACITY_TOO_SMALL);
        assert_eq!((*t).h.tracker.frames(), 0, "tracker untouched");
        let st = stjpdacf_small_step(t, 0, pts.as_ptr(), 60, null_mut(), 0, null_mut());
        assert_eq!(st, STJPDACF_OK);
        let st = stjpdacf_small_step(t, 0, pts.as_ptr(), 60, null_mut(), 0, null_mut());
        assert_eq!(st, STJPDACF_NON_INCREASING_TIME);
        assert_eq!((*t).h.tracker.frames(), 1);
    }
}

/// The small model through the C API equals `Rank4Tracker` on the uncoupled tables with LBP on
/// every row, frame by frame: filtered and smoothed lanes, the report and the GP read-out.
#[test]
fn small_lanes_match_the_rust_tracker() {
    let mut rust = Box::new(Rank4Tracker::with_config(&UNCOUPLED, SMALL_CONFIG));
    let mut buf = vec![0u64; STJPDACF_SMALL_TRACKER_SIZE / 8 + 1];
    let mut t = null_mut();
    // SAFETY: `buf` holds `STJPDACF_SMALL_TRACKER_SIZE` writable, aligned bytes.
    let st = unsafe {
        stjpdacf_small_init(buf.as_mut_ptr().cast(), STJPDACF_SMALL_TRACKER_SIZE, &mut t)
    };
    assert_eq!(st, STJPDACF_OK);
    let api = Entry {
        step: stjpdacf_small_step,
        filtered: stjpdacf_small_filtered,
        smoothed: stjpdacf_small_smoothed,
        lane_at: stjpdacf_small_lane_at,
    };
    let (rep, published) = lanes_match(t, &api, |time, pairs| want_of!(rust, time, pairs));
    assert!(published >= 8, "lanes were published ({published})");
    // `stjpdacf_model_info` describes both models: the same window and index points.
    assert_eq!(UNCOUPLED.index_u, DEFAULT.index_u);
    assert_eq!(UNCOUPLED.hyper.u_min, DEFAULT.hyper.u_min);
    assert_eq!(UNCOUPLED.hyper.u_max, DEFAULT.hyper.u_max);
    assert_eq!(rep.smoothed_lanes, 2, "the smoother window is full");
}

#[test]
fn the_rank5_size_constant_covers_its_tracker() {
    let size = core::mem::size_of::<stjpdacf_rank5_tracker>();
    std::println!("size_of::<stjpdacf_rank5_tracker>() = {size}");
    assert!(size <= STJPDACF_RANK5_TRACKER_SIZE);
    assert!(STJPDACF_RANK5_TRACKER_SIZE - size < 1024);
}

/// The rank-5 model's entry points refuse a short buffer and a buffer never initialised, and
/// equal `Rank5Tracker` on the default tables frame by frame (filtered and smoothed lanes, the
/// report and the GP read-out).
#[test]
fn rank5_refuses_bad_buffers_and_matches_the_rust_tracker() {
    let mut buf = vec![0u64; STJPDACF_RANK5_TRACKER_SIZE / 8 + 1];
    let mut t = null_mut();
    // SAFETY: `buf` holds more than the size given; `t` is writable.
    let st = unsafe {
        stjpdacf_rank5_init(
            buf.as_mut_ptr().cast(),
            STJPDACF_RANK5_TRACKER_SIZE - 1,
            &mut t,
        )
    };
    assert_eq!((st, t.is_null()), (STJPDACF_BUFFER_TOO_SMALL, true));
    let raw = buf.as_mut_ptr().cast::<stjpdacf_rank5_tracker>();
    let pts = two_lanes();
    let mut lanes = [NO_LANE; STJPDACF_MAX_LANES];
    let mut n = 0usize;
    let (mut x, mut var) = (0.0f32, 0.0f32);
    // SAFETY: `raw` points to writable, aligned memory of the tracker's size; the arrays are
    // valid for their sizes.
    unsafe {
        let st = stjpdacf_rank5_step(raw, 0, pts.as_ptr(), 60, null_mut(), 0, null_mut());
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
        let st = stjpdacf_rank5_filtered(raw, lanes.as_mut_ptr(), lanes.len(), &mut n);
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
        let st = stjpdacf_rank5_smoothed(raw, lanes.as_mut_ptr(), lanes.len(), &mut n);
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
        let st = stjpdacf_rank5_lane_at(raw, 0, 30.0, &mut x, &mut var);
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
    }
    let mut rust = Box::new(Rank5Tracker::new(&DEFAULT));
    // SAFETY: `buf` holds `STJPDACF_RANK5_TRACKER_SIZE` writable, aligned bytes.
    let st = unsafe {
        stjpdacf_rank5_init(buf.as_mut_ptr().cast(), STJPDACF_RANK5_TRACKER_SIZE, &mut t)
    };
    assert_eq!(st, STJPDACF_OK);
    let api = Entry {
        step: stjpdacf_rank5_step,
        filtered: stjpdacf_rank5_filtered,
        smoothed: stjpdacf_rank5_smoothed,
        lane_at: stjpdacf_rank5_lane_at,
    };
    let (rep, published) = lanes_match(t, &api, |time, pairs| want_of!(rust, time, pairs));
    assert!(published >= 8, "lanes were published ({published})");
    assert_eq!(rep.smoothed_lanes, 2, "the smoother window is full");
}

/// A stale handle of one model on a buffer since initialised for another model is refused
/// (`STJPDACF_NOT_INITIALISED`), not read as the wrong tracker type. The buffer is the union of
/// the three models (the reference model's size), as a firmware that picks its model at start-up
/// would declare it.
#[test]
fn a_buffer_reinitialised_for_another_model_refuses_the_old_handle() {
    let mut buf = buffer();
    let mem = buf.as_mut_ptr().cast::<core::ffi::c_void>();
    let (mut reference, mut small) = (null_mut(), null_mut());
    let mut lanes = [NO_LANE; STJPDACF_MAX_LANES];
    let mut n = 99usize;
    // SAFETY: `buf` holds `STJPDACF_TRACKER_SIZE` writable, aligned bytes; the out-parameters
    // and `lanes` are valid for their sizes.
    unsafe {
        assert_eq!(
            stjpdacf_init(mem, STJPDACF_TRACKER_SIZE, &mut reference),
            STJPDACF_OK
        );
        assert_eq!(
            stjpdacf_small_init(mem, STJPDACF_TRACKER_SIZE, &mut small),
            STJPDACF_OK
        );
        // The old reference handle: the buffer now holds a small tracker.
        let st = stjpdacf_filtered(reference, lanes.as_mut_ptr(), lanes.len(), &mut n);
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
        assert_eq!(n, 99, "nothing written");
        // And the other way round.
        assert_eq!(
            stjpdacf_init(mem, STJPDACF_TRACKER_SIZE, &mut reference),
            STJPDACF_OK
        );
        let st = stjpdacf_small_filtered(small, lanes.as_mut_ptr(), lanes.len(), &mut n);
        assert_eq!(st, STJPDACF_NOT_INITIALISED);
    }
}

/// A smoothed lane's `misses` is not the lane's misses: the smoothed lanes of a lane that has
/// gone unseen (coasting, still published) report 0, which the header documented as "seen this
/// frame". Pins what the C docs now say.
#[test]
fn smoothed_lanes_report_no_misses_while_their_lane_coasts() {
    let mut buf = buffer();
    let t = init(&mut buf);
    let both = two_lanes();
    // The left lane only (x = -1.8).
    let left: Vec<f32> = both.chunks(4).flat_map(|c| [c[0], c[1]]).collect();
    let mut seen = false;
    for k in 0..12i64 {
        let pts = if k < 8 { &both } else { &left };
        let mut rep = zero_report();
        let mut f = [NO_LANE; STJPDACF_MAX_LANES];
        let mut s = [NO_LANE; STJPDACF_MAX_LANES];
        let mut ns = 0usize;
        // SAFETY: `t` from `init`; the arrays are valid for their sizes.
        unsafe {
            let st = stjpdacf_step(
                t,
                k * 50_000,
                pts.as_ptr(),
                pts.len() / 2,
                f.as_mut_ptr(),
                6,
                &mut rep,
            );
            assert!(st == STJPDACF_OK || st == STJPDACF_DEGRADED);
            assert_eq!(
                stjpdacf_smoothed(t, s.as_mut_ptr(), 6, &mut ns),
                STJPDACF_OK
            );
        }
        for l in &f[..rep.filtered_lanes as usize] {
            if l.misses > 0 {
                let sm = s[..ns].iter().find(|m| m.id == l.id);
                std::println!(
                    "frame {k}: filtered id {} misses {}; smoothed {:?}",
                    l.id,
                    l.misses,
                    sm.map(|m| m.misses)
                );
                if let Some(sm) = sm {
                    seen = true;
                    assert_eq!(sm.misses, 0, "a smoothed lane's misses are always 0");
                }
            }
        }
    }
    assert!(
        seen,
        "no coasting lane with a smoothed estimate: the test tests nothing"
    );
}
