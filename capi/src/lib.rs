//! C API of the stjpdacf lane tracker: the header is `capi/include/stjpdacf.h`, generated from
//! this file by cbindgen (`capi/cbindgen.toml`). Three models, each with its own handle type:
//! * `stjpdacf_tracker` (`stjpdacf_init`, `stjpdacf_step`, …): the reference configuration,
//!   [`ReferenceTracker`] on the built-in coupled tables ([`DEFAULT`]) with the default
//!   configuration;
//! * `stjpdacf_small_tracker` (`stjpdacf_small_init`, `stjpdacf_small_step`, …): the smallest
//!   model measured on the Cortex-M4F, [`Rank4Tracker`] on the uncoupled tables ([`UNCOUPLED`])
//!   with LBP on every known-lane row (about 60 % of the memory and a fifth of the instructions
//!   of the reference model; docs/measurements.md "Fitting the MCU");
//! * `stjpdacf_rank5_tracker` (`stjpdacf_rank5_init`, `stjpdacf_rank5_step`, …): the reference
//!   model compiled for Gram rank 5, [`Rank5Tracker`] on the same tables and configuration
//!   (within 0.008 of its replay accuracy for about 70 % of its memory and 60 % of its
//!   instructions on the Cortex-M4F).
//!
//! All take the same frames and publish the same lane records; every function of the reference
//! model has its `small` and `rank5` twins with the same contract.
//!
//! # Contract
//! * **Caller-owned memory.** The tracker lives in a buffer the caller provides, of at least
//!   [`STJPDACF_TRACKER_SIZE`] bytes aligned to [`STJPDACF_TRACKER_ALIGN`] (a `static` on a
//!   microcontroller); [`stjpdacf_init`] initialises it. Nothing is allocated, ever; there is no
//!   destroy function (drop the buffer, or call `stjpdacf_init` on it again to restart).
//! * **Status codes.** Every function returns a [`stjpdacf_status`]: negative when the call was
//!   refused (nothing written, the tracker untouched), `STJPDACF_OK`, or `STJPDACF_DEGRADED`
//!   when a frame was processed but work was dropped or failed numerically (the report says
//!   which counter).
//! * **Pointers.** Null, misaligned pointers and oversized counts are refused with a status
//!   before anything is read. What cannot be checked is the caller's: a pointer must point to
//!   the memory it claims, and a tracker must not be used from two threads at once.
//! * **No panics.** The functions only check pointers, build slices and references, and call the
//!   safe core, which never panics (CI's no-panic link proof of the Cortex-M4F C example covers
//!   the entry points it calls: init, step, smoothed and `stjpdacf_decode_frame`; the others,
//!   `*_filtered`, `*_lane_at` and `stjpdacf_model_info`, link panic-free too, checked by hand
//!   at stop 73, not by CI).
//!
//! The unsafe operations are the four pointer helpers (`tracker_ref`, `tracker_mut`,
//! `slice_in`, `slice_out`), the out-parameter writes (`write_out`), the point buffer of
//! [`stjpdacf_decode_frame`] and, in [`stjpdacf_init`], the write of the all-zero handle, the
//! handle reference and the handle write; the entry points
//! call them after their checks, each call with its SAFETY comment.
#![no_std]

// The host staticlib (and the tests) take the panic handler from std; the bare-metal staticlibs
// have their own (`panic_halt` below), never reached: the core does not panic.
#[cfg(not(target_os = "none"))]
extern crate std;

use stjpdacf::persist::PersistConfig;
use stjpdacf::spatial::row::Association;
use stjpdacf::tables::{DEFAULT, UNCOUPLED};
use stjpdacf::tracker::{
    Instant, LaneEstimate, Rank4Tracker, Rank5Tracker, ReferenceTracker, StepError, StepOutput,
    StepReport, TrackerConfig,
};
use stjpdacf::wire::{self, WireError};

/// Lane slots of the reference tracker (lanes per read-out at most).
pub const STJPDACF_MAX_LANES: usize = 6;
/// Index points per lane.
pub const STJPDACF_INDEX_POINTS: usize = 16;
/// Points a frame uses at most; the excess is ignored and counted (`over_budget_points`).
pub const STJPDACF_MAX_POINTS: usize = 256;
/// Largest `n_points` [`stjpdacf_step`] accepts (larger counts are refused as
/// `STJPDACF_TOO_MANY_POINTS`, a guard against garbage counts).
pub const STJPDACF_MAX_POINTS_IN: usize = 65_536;
/// Smoother lag, frames: the smoothed lanes are this many frames back.
pub const STJPDACF_LAG: usize = 4;
/// Bytes of the tracker buffer (at least `sizeof` of the tracker on every supported target:
/// checked at compile time).
pub const STJPDACF_TRACKER_SIZE: usize = 155_600;
/// Alignment of the tracker buffer, bytes.
pub const STJPDACF_TRACKER_ALIGN: usize = 8;
/// Bytes of the small model's tracker buffer (`stjpdacf_small_init`; at least `sizeof` of its
/// tracker on every supported target: checked at compile time). Aligned as
/// `STJPDACF_TRACKER_ALIGN`.
pub const STJPDACF_SMALL_TRACKER_SIZE: usize = 93_344;
/// Bytes of the rank-5 model's tracker buffer (`stjpdacf_rank5_init`; at least `sizeof` of its
/// tracker on every supported target: checked at compile time). Aligned as
/// `STJPDACF_TRACKER_ALIGN`.
pub const STJPDACF_RANK5_TRACKER_SIZE: usize = 110_400;

const _: () = assert!(core::mem::size_of::<stjpdacf_tracker>() <= STJPDACF_TRACKER_SIZE);
const _: () = assert!(core::mem::align_of::<stjpdacf_tracker>() <= STJPDACF_TRACKER_ALIGN);
const _: () =
    assert!(core::mem::size_of::<stjpdacf_small_tracker>() <= STJPDACF_SMALL_TRACKER_SIZE);
const _: () = assert!(core::mem::align_of::<stjpdacf_small_tracker>() <= STJPDACF_TRACKER_ALIGN);
const _: () =
    assert!(core::mem::size_of::<stjpdacf_rank5_tracker>() <= STJPDACF_RANK5_TRACKER_SIZE);
const _: () = assert!(core::mem::align_of::<stjpdacf_rank5_tracker>() <= STJPDACF_TRACKER_ALIGN);
const _: () = assert!(STJPDACF_MAX_LANES == 6 && STJPDACF_INDEX_POINTS == 16);
// Every model's magic at the start of the buffer (see `Handle`).
const _: () = assert!(core::mem::offset_of!(stjpdacf_tracker, h.magic) == 0);
const _: () = assert!(core::mem::offset_of!(stjpdacf_small_tracker, h.magic) == 0);
const _: () = assert!(core::mem::offset_of!(stjpdacf_rank5_tracker, h.magic) == 0);
const _: () = assert!(STJPDACF_MAX_POINTS == 256 && STJPDACF_LAG == 4);

/// Marks an initialised tracker of the reference model (a guard against buffers never passed
/// to [`stjpdacf_init`]); each model has its own, at the start of the buffer (`Handle` is
/// `repr(C)`), so that a buffer initialised since for another model refuses the old handle.
const MAGIC: u32 = 0x5354_4A50;
/// [`MAGIC`] of the small model.
const SMALL_MAGIC: u32 = 0x5354_4A34;
/// [`MAGIC`] of the rank-5 model.
const RANK5_MAGIC: u32 = 0x5354_4A35;

/// Result of every function. Negative: refused, nothing written. Zero or positive: done.
#[repr(i32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub enum stjpdacf_status {
    /// Done.
    STJPDACF_OK = 0,
    /// The frame was processed, but some of its work was dropped or failed numerically: points
    /// beyond `STJPDACF_MAX_POINTS` (`over_budget_points`), temporal failures, failed spatial
    /// rows or backward passes, failed known-lane rows, or a configuration that does not fit
    /// (`spatial.bad_config`). The lanes are valid; the report says which counter.
    STJPDACF_DEGRADED = 1,
    /// A required pointer is null.
    STJPDACF_NULL_POINTER = -1,
    /// A pointer is not aligned for its type (the tracker: `STJPDACF_TRACKER_ALIGN`).
    STJPDACF_MISALIGNED = -2,
    /// The tracker buffer is smaller than `STJPDACF_TRACKER_SIZE` (`STJPDACF_SMALL_TRACKER_SIZE`
    /// for the small model, `STJPDACF_RANK5_TRACKER_SIZE` for the rank-5 model).
    STJPDACF_BUFFER_TOO_SMALL = -3,
    /// `n_points` exceeds `STJPDACF_MAX_POINTS_IN`.
    STJPDACF_TOO_MANY_POINTS = -4,
    /// A lane array is given with room for fewer than `STJPDACF_MAX_LANES` lanes.
    STJPDACF_CAPACITY_TOO_SMALL = -5,
    /// The tracker was not initialised by `stjpdacf_init` (or the buffer has been initialised
    /// since for another model: `stjpdacf_small_init`, `stjpdacf_rank5_init`).
    STJPDACF_NOT_INITIALISED = -6,
    /// The frame's time is not after the previous frame's (Rust `StepError::NonIncreasingTime`).
    STJPDACF_NON_INCREASING_TIME = -7,
    /// No lane in that slot, or `u` outside the BEV window or not finite.
    STJPDACF_NO_LANE = -8,
    /// Wire frame: fewer bytes than the frame (Rust `WireError::Truncated`).
    STJPDACF_WIRE_TRUNCATED = -20,
    /// Wire frame: bad magic.
    STJPDACF_WIRE_BAD_MAGIC = -21,
    /// Wire frame: unsupported version or flags.
    STJPDACF_WIRE_BAD_VERSION = -22,
    /// Wire frame: more points than the caller's capacity.
    STJPDACF_WIRE_OVERSIZED = -23,
    /// Wire frame: CRC mismatch.
    STJPDACF_WIRE_BAD_CRC = -24,
    /// Wire frame: sequence number does not increase (a receiver's check).
    STJPDACF_WIRE_NON_INCREASING_SEQUENCE = -25,
    /// Wire frame: timestamp does not increase (a receiver's check).
    STJPDACF_WIRE_NON_INCREASING_TIME = -26,
    /// An error this version of the API does not know (a newer core).
    STJPDACF_UNKNOWN_ERROR = -99,
}

use stjpdacf_status::*;

impl From<StepError> for stjpdacf_status {
    fn from(e: StepError) -> Self {
        match e {
            StepError::NonIncreasingTime => STJPDACF_NON_INCREASING_TIME,
            StepError::NotInitialised => STJPDACF_NOT_INITIALISED,
            #[allow(unreachable_patterns)]
            _ => STJPDACF_UNKNOWN_ERROR,
        }
    }
}

impl From<WireError> for stjpdacf_status {
    fn from(e: WireError) -> Self {
        match e {
            WireError::Truncated => STJPDACF_WIRE_TRUNCATED,
            WireError::BadMagic => STJPDACF_WIRE_BAD_MAGIC,
            WireError::BadVersion => STJPDACF_WIRE_BAD_VERSION,
            WireError::Oversized { .. } => STJPDACF_WIRE_OVERSIZED,
            WireError::BadCrc => STJPDACF_WIRE_BAD_CRC,
            WireError::NonIncreasingSequence => STJPDACF_WIRE_NON_INCREASING_SEQUENCE,
            WireError::NonIncreasingTime => STJPDACF_WIRE_NON_INCREASING_TIME,
            #[allow(unreachable_patterns)]
            _ => STJPDACF_UNKNOWN_ERROR,
        }
    }
}

/// One lane as published (Rust `LaneEstimate<16>`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(non_camel_case_types)]
pub struct stjpdacf_lane {
    /// Stable id.
    pub id: u32,
    /// Temporal slot, `0..STJPDACF_MAX_LANES` (for [`stjpdacf_lane_at`], which evaluates the
    /// lane's filtered estimate at the last frame, also for a smoothed lane).
    pub slot: u32,
    /// Lateral position at each index point, metres.
    pub z: [f32; STJPDACF_INDEX_POINTS],
    /// Its variance, m².
    pub var: [f32; STJPDACF_INDEX_POINTS],
    /// Near end of the observed extent, metres ahead: the union over the `STJPDACF_LAG + 1`
    /// frames ending at the lane's frame (the last frame for a filtered lane, `STJPDACF_LAG`
    /// frames back for a smoothed lane).
    pub u_first: f32,
    /// Far end of the observed extent, metres ahead.
    pub u_last: f32,
    /// Existence figure in [0, 1], at the last frame (also for a smoothed lane).
    pub existence: f32,
    /// Frames since the lane was last seen (0 when seen this frame). Always 0 for a smoothed
    /// lane: read a lane's misses from its filtered record (same `id`).
    pub misses: u32,
    /// Frames since the lane started (0 in its first frame); for a smoothed lane, its age at the
    /// last frame.
    pub age: u32,
    /// Frames in which the lane was observed, its first frame included (for a smoothed lane, at
    /// the last frame).
    pub hits: u32,
}

impl From<&LaneEstimate<16>> for stjpdacf_lane {
    fn from(l: &LaneEstimate<16>) -> Self {
        Self {
            id: l.id.0,
            slot: u32::from(l.slot),
            z: l.z.into(),
            var: l.var.into(),
            u_first: l.u_first,
            u_last: l.u_last,
            existence: l.existence,
            misses: u32::from(l.misses),
            age: l.age,
            hits: l.hits,
        }
    }
}

/// What one frame did: the lane counts and the core's `StepReport` as it is (`repr(C)`; its
/// `spatial`, `identity` and `known` parts are `stjpdacf_spatial_report`,
/// `stjpdacf_identity_report` and `stjpdacf_known_report`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(non_camel_case_types)]
pub struct stjpdacf_report {
    /// Filtered lanes at this frame (read them with [`stjpdacf_filtered`]).
    pub filtered_lanes: u32,
    /// Smoothed lanes `STJPDACF_LAG` frames back ([`stjpdacf_smoothed`]).
    pub smoothed_lanes: u32,
    /// The counters of every stage.
    pub step: StepReport,
}

impl stjpdacf_report {
    /// `STJPDACF_DEGRADED` when work was dropped or failed, else `STJPDACF_OK`.
    fn status(&self) -> stjpdacf_status {
        let r = &self.step;
        let degraded = r.over_budget_points > 0
            || r.temporal_failures > 0
            || r.spatial.rows_failed > 0
            || r.spatial.smoother_failed > 0
            || r.spatial.bad_config
            || r.known.failed_rows > 0;
        if degraded {
            STJPDACF_DEGRADED
        } else {
            STJPDACF_OK
        }
    }
}

/// The model's fixed geometry (from the built-in tables).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[allow(non_camel_case_types)]
pub struct stjpdacf_model {
    /// Near end of the BEV window, metres ahead.
    pub u_min: f32,
    /// Far end of the BEV window, metres ahead.
    pub u_max: f32,
    /// The index points' distances ahead, metres (where `stjpdacf_lane.z` lives).
    pub index_u: [f32; STJPDACF_INDEX_POINTS],
}

/// A decoded wire frame's header (Rust `FrameInfo`); its points are in the caller's array.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[allow(non_camel_case_types)]
pub struct stjpdacf_frame_info {
    /// Sequence number.
    pub seq: u32,
    /// Points written, `{u, x}` pairs.
    pub count: u32,
    /// Timestamp, microseconds.
    pub time_us: i64,
    /// Bytes the frame took (the next frame starts there).
    pub len: usize,
}

/// A handle's storage: the Rust tracker `T` and the lanes of the last frame. `repr(C)` with the
/// model's magic first: every model's init writes it at the same offset (0), whatever the sizes.
#[repr(C)]
struct Handle<T> {
    magic: u32,
    n_filtered: u8,
    n_smoothed: u8,
    tracker: T,
    filtered: [stjpdacf_lane; STJPDACF_MAX_LANES],
    smoothed: [stjpdacf_lane; STJPDACF_MAX_LANES],
}

/// The reference model's tracker (opaque to C): [`ReferenceTracker`] on the coupled tables and
/// the lanes of the last frame.
#[allow(non_camel_case_types)]
pub struct stjpdacf_tracker {
    h: Handle<ReferenceTracker>,
}

/// The small model's tracker (opaque to C): [`Rank4Tracker`] on the uncoupled tables with LBP on
/// every known-lane row, and the lanes of the last frame.
#[allow(non_camel_case_types)]
pub struct stjpdacf_small_tracker {
    h: Handle<Rank4Tracker>,
}

/// The rank-5 model's tracker (opaque to C): [`Rank5Tracker`] on the coupled tables with the
/// default configuration, and the lanes of the last frame.
#[allow(non_camel_case_types)]
pub struct stjpdacf_rank5_tracker {
    h: Handle<Rank5Tracker>,
}

/// The small model's configuration: LBP on every known-lane row.
const SMALL_CONFIG: TrackerConfig = TrackerConfig {
    persist: PersistConfig {
        association: Association::Lbp,
        ..PersistConfig::DEFAULT
    },
    ..TrackerConfig::DEFAULT
};

/// What the entry points need of a model: its tracker type, start, step and GP read-out.
trait Model: Sized + 'static {
    /// The Rust tracker.
    type T;
    /// The all-zero handle (`magic` 0, the tracker's `UNINIT`): [`stjpdacf_init`] writes it
    /// into the caller's buffer, which compiles to a `memset`, then initialises the tracker in
    /// place. Neither the value (~156 KB for the reference model) nor an image of it exists
    /// anywhere else (not on the stack, not in flash).
    const ZEROED: Self;
    /// The buffer size the C caller must give.
    const SIZE: usize;
    /// The model's magic (distinct per model).
    const MAGIC: u32;
    fn handle(&self) -> &Handle<Self::T>;
    fn handle_mut(&mut self) -> &mut Handle<Self::T>;
    /// Initialises the tracker in place with the model's tables and configuration.
    fn start(t: &mut Self::T);
    fn step(
        t: &mut Self::T,
        now: Instant,
        pts: &[[f32; 2]],
    ) -> Result<StepOutput<STJPDACF_MAX_LANES, STJPDACF_INDEX_POINTS>, StepError>;
    fn lane_at(t: &Self::T, slot: usize, u: f32) -> Option<(f32, f32)>;
}

/// `impl Model for $handle`: the Rust tracker `$tracker`, started on `$tables` with `$config`,
/// in a buffer of `$size` bytes (one implementation for the three models).
macro_rules! model {
    ($handle:ident, $tracker:ty, $tables:expr, $config:expr, $size:expr, $magic:expr) => {
        impl Model for $handle {
            type T = $tracker;
            const ZEROED: Self = $handle {
                h: Handle {
                    magic: 0,
                    tracker: <$tracker>::UNINIT,
                    filtered: [NO_LANE; STJPDACF_MAX_LANES],
                    smoothed: [NO_LANE; STJPDACF_MAX_LANES],
                    n_filtered: 0,
                    n_smoothed: 0,
                },
            };
            const SIZE: usize = $size;
            const MAGIC: u32 = $magic;
            fn handle(&self) -> &Handle<$tracker> {
                &self.h
            }
            fn handle_mut(&mut self) -> &mut Handle<$tracker> {
                &mut self.h
            }
            fn start(t: &mut $tracker) {
                t.init($tables, $config);
            }
            fn step(
                t: &mut $tracker,
                now: Instant,
                pts: &[[f32; 2]],
            ) -> Result<StepOutput<STJPDACF_MAX_LANES, STJPDACF_INDEX_POINTS>, StepError> {
                t.step(now, pts)
            }
            fn lane_at(t: &$tracker, slot: usize, u: f32) -> Option<(f32, f32)> {
                t.lane_at(slot, u)
            }
        }
    };
}

model!(
    stjpdacf_tracker,
    ReferenceTracker,
    &DEFAULT,
    TrackerConfig::DEFAULT,
    STJPDACF_TRACKER_SIZE,
    MAGIC
);
model!(
    stjpdacf_small_tracker,
    Rank4Tracker,
    &UNCOUPLED,
    SMALL_CONFIG,
    STJPDACF_SMALL_TRACKER_SIZE,
    SMALL_MAGIC
);
model!(
    stjpdacf_rank5_tracker,
    Rank5Tracker,
    &DEFAULT,
    TrackerConfig::DEFAULT,
    STJPDACF_RANK5_TRACKER_SIZE,
    RANK5_MAGIC
);

const NO_LANE: stjpdacf_lane = stjpdacf_lane {
    id: 0,
    slot: 0,
    z: [0.0; STJPDACF_INDEX_POINTS],
    var: [0.0; STJPDACF_INDEX_POINTS],
    u_first: 0.0,
    u_last: 0.0,
    existence: 0.0,
    misses: 0,
    age: 0,
    hits: 0,
};

/// Checks a tracker pointer: non-null, aligned, initialised.
///
/// # Safety
/// A non-null, aligned `t` must point to `M::SIZE` readable bytes that no one writes during
/// `'a`.
unsafe fn tracker_ref<'a, M: Model>(t: *const M) -> Result<&'a Handle<M::T>, stjpdacf_status> {
    if t.is_null() {
        return Err(STJPDACF_NULL_POINTER);
    }
    if !t.is_aligned() {
        return Err(STJPDACF_MISALIGNED);
    }
    // SAFETY: non-null and aligned (checked); the caller guarantees the memory is readable and
    // not written during 'a. The magic check below rejects buffers `stjpdacf_init` never wrote.
    let r = unsafe { &*t }.handle();
    if r.magic == M::MAGIC {
        Ok(r)
    } else {
        Err(STJPDACF_NOT_INITIALISED)
    }
}

/// [`tracker_ref`], mutable.
///
/// # Safety
/// A non-null, aligned `t` must point to `M::SIZE` writable bytes that nothing else accesses
/// during `'a`.
unsafe fn tracker_mut<'a, M: Model>(t: *mut M) -> Result<&'a mut Handle<M::T>, stjpdacf_status> {
    if t.is_null() {
        return Err(STJPDACF_NULL_POINTER);
    }
    if !t.is_aligned() {
        return Err(STJPDACF_MISALIGNED);
    }
    // SAFETY: non-null and aligned (checked); the caller guarantees exclusive access during 'a.
    let r = unsafe { &mut *t }.handle_mut();
    if r.magic == M::MAGIC {
        Ok(r)
    } else {
        Err(STJPDACF_NOT_INITIALISED)
    }
}

/// An input array as a slice: empty when `n == 0` (then `p` may be null), else `p` must be
/// non-null and aligned and `n ≤ max`.
///
/// # Safety
/// A non-null, aligned `p` must point to `n` initialised values that no one writes during `'a`.
unsafe fn slice_in<'a, T>(p: *const T, n: usize, max: usize) -> Result<&'a [T], stjpdacf_status> {
    if n == 0 {
        return Ok(&[]);
    }
    if p.is_null() {
        return Err(STJPDACF_NULL_POINTER);
    }
    if !p.is_aligned() {
        return Err(STJPDACF_MISALIGNED);
    }
    if n > max {
        return Err(STJPDACF_TOO_MANY_POINTS);
    }
    // SAFETY: non-null and aligned (checked); `n ≤ max` keeps `n · size_of::<T>()` far below
    // `isize::MAX`; the caller guarantees `n` readable, initialised values not written during 'a.
    Ok(unsafe { core::slice::from_raw_parts(p, n) })
}

/// An output lane array as a slice: `None` when `p` is null and `capacity == 0`; otherwise `p`
/// must be non-null and aligned with `capacity ≥ STJPDACF_MAX_LANES` (only the first
/// `STJPDACF_MAX_LANES` are ever written).
///
/// # Safety
/// A non-null, aligned `p` must point to `capacity` writable lanes that nothing else accesses
/// during `'a`.
unsafe fn slice_out<'a>(
    p: *mut stjpdacf_lane,
    capacity: usize,
) -> Result<Option<&'a mut [stjpdacf_lane]>, stjpdacf_status> {
    if p.is_null() {
        return if capacity == 0 {
            Ok(None)
        } else {
            Err(STJPDACF_NULL_POINTER)
        };
    }
    if !p.is_aligned() {
        return Err(STJPDACF_MISALIGNED);
    }
    if capacity < STJPDACF_MAX_LANES {
        return Err(STJPDACF_CAPACITY_TOO_SMALL);
    }
    // SAFETY: non-null and aligned (checked); only `STJPDACF_MAX_LANES ≤ capacity` lanes are
    // covered, which the caller guarantees are writable and not otherwise accessed during 'a.
    // `stjpdacf_lane` is plain old data: any bit pattern the caller left there is valid.
    Ok(Some(unsafe {
        core::slice::from_raw_parts_mut(p, STJPDACF_MAX_LANES)
    }))
}

/// Checks an optional out-parameter and writes `v` there (nothing when `p` is null).
///
/// # Safety
/// A non-null `p` must be valid for writes of one `T`.
unsafe fn write_out<T>(p: *mut T, v: T) -> Result<(), stjpdacf_status> {
    if p.is_null() {
        return Ok(());
    }
    if !p.is_aligned() {
        return Err(STJPDACF_MISALIGNED);
    }
    // SAFETY: non-null and aligned (checked), writable (the caller). `write` does not read or
    // drop the old value, which may be uninitialised.
    unsafe { p.write(v) };
    Ok(())
}

/// A required out-parameter: null is refused.
fn required<T>(p: *mut T) -> Result<*mut T, stjpdacf_status> {
    if p.is_null() {
        Err(STJPDACF_NULL_POINTER)
    } else if !p.is_aligned() {
        Err(STJPDACF_MISALIGNED)
    } else {
        Ok(p)
    }
}

/// Runs `f` and turns its refusal (`Err`) into the status returned.
fn checked(f: impl FnOnce() -> Result<stjpdacf_status, stjpdacf_status>) -> stjpdacf_status {
    f().unwrap_or_else(|e| e)
}

/// Initialises a tracker of model `M` in `memory` (see [`stjpdacf_init`]).
///
/// # Safety
/// As [`stjpdacf_init`], with `M::SIZE` for the size.
unsafe fn init_model<M: Model>(
    memory: *mut core::ffi::c_void,
    size: usize,
    tracker: *mut *mut M,
) -> stjpdacf_status {
    let t = memory.cast::<M>();
    let out = match required(tracker) {
        Ok(o) => o,
        Err(e) => return e,
    };
    if t.is_null() {
        return STJPDACF_NULL_POINTER;
    }
    if !t.is_aligned() {
        return STJPDACF_MISALIGNED;
    }
    if size < M::SIZE {
        return STJPDACF_BUFFER_TOO_SMALL;
    }
    // SAFETY: `t` is non-null, aligned and has room for a tracker (checked: `size ≥ M::SIZE ≥
    // size_of`, asserted at compile time); the caller guarantees it is writable and unshared.
    // The tracker has no `Drop`, so overwriting whatever was there leaks nothing.
    unsafe { t.write(M::ZEROED) };
    // SAFETY: `t` now holds a valid handle (written above) that nothing else accesses.
    let h = unsafe { &mut *t }.handle_mut();
    M::start(&mut h.tracker);
    h.magic = M::MAGIC;
    // SAFETY: `out` is non-null and aligned (checked), writable (the caller).
    unsafe { out.write(t) };
    STJPDACF_OK
}

/// Initialises a tracker in the caller's buffer `memory` of `size` bytes and stores the tracker
/// handle (`memory` itself) in `*tracker`. Call it again on the same buffer to start afresh
/// (a new clip).
///
/// Returns `STJPDACF_OK`, or `STJPDACF_NULL_POINTER`, `STJPDACF_MISALIGNED` (`memory` not
/// aligned to `STJPDACF_TRACKER_ALIGN`), `STJPDACF_BUFFER_TOO_SMALL` (`size <
/// STJPDACF_TRACKER_SIZE`), with nothing written.
///
/// Cost: a `memset` of the tracker (about `STJPDACF_TRACKER_SIZE` bytes) and a few hundred
/// bytes of stores; no image of the tracker is kept in flash.
///
/// # Safety
/// `memory` must be valid for writes of `size` bytes and not used otherwise while the tracker is
/// in use; `tracker` must be valid for one pointer write.
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_init(
    memory: *mut core::ffi::c_void,
    size: usize,
    tracker: *mut *mut stjpdacf_tracker,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe { init_model(memory, size, tracker) }
}

/// [`stjpdacf_init`] for the small model: a buffer of at least `STJPDACF_SMALL_TRACKER_SIZE`
/// bytes (else `STJPDACF_BUFFER_TOO_SMALL`), aligned to `STJPDACF_TRACKER_ALIGN`.
///
/// # Safety
/// As [`stjpdacf_init`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_small_init(
    memory: *mut core::ffi::c_void,
    size: usize,
    tracker: *mut *mut stjpdacf_small_tracker,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe { init_model(memory, size, tracker) }
}

/// [`stjpdacf_init`] for the rank-5 model: a buffer of at least `STJPDACF_RANK5_TRACKER_SIZE`
/// bytes (else `STJPDACF_BUFFER_TOO_SMALL`), aligned to `STJPDACF_TRACKER_ALIGN`.
///
/// # Safety
/// As [`stjpdacf_init`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_rank5_init(
    memory: *mut core::ffi::c_void,
    size: usize,
    tracker: *mut *mut stjpdacf_rank5_tracker,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe { init_model(memory, size, tracker) }
}

/// One frame of a tracker of model `M` (see [`stjpdacf_step`]).
///
/// # Safety
/// As [`stjpdacf_step`].
unsafe fn step_model<M: Model>(
    tracker: *mut M,
    time_us: i64,
    points: *const f32,
    n_points: usize,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    report: *mut stjpdacf_report,
) -> stjpdacf_status {
    checked(|| {
        // SAFETY: the caller's contract: `tracker` from `stjpdacf_init`, not shared.
        let t = unsafe { tracker_mut(tracker) }?;
        // `{u, x}` pairs: `[f32; 2]` has the alignment of `f32`.
        // SAFETY: the caller's contract: `points` holds `2 · n_points` floats.
        let pts = unsafe { slice_in(points.cast::<[f32; 2]>(), n_points, STJPDACF_MAX_POINTS_IN) }?;
        // SAFETY: the caller's contract: room for `capacity` lanes.
        let lanes = unsafe { slice_out(out_lanes, capacity) }?;
        let report = if report.is_null() {
            None
        } else {
            Some(required(report)?)
        };
        let out = M::step(&mut t.tracker, Instant::from_micros(time_us), pts)?;
        t.n_filtered = copy_lanes(&out.filtered, &mut t.filtered);
        t.n_smoothed = copy_lanes(&out.smoothed, &mut t.smoothed);
        if let Some(l) = lanes {
            for (d, s) in l.iter_mut().zip(&t.filtered) {
                *d = *s;
            }
        }
        let rep = stjpdacf_report {
            filtered_lanes: out.filtered.len() as u32,
            smoothed_lanes: out.smoothed.len() as u32,
            step: out.report,
        };
        if let Some(p) = report {
            // SAFETY: non-null and aligned (checked by `required`), writable (the caller).
            unsafe { write_out(p, rep) }?;
        }
        Ok(rep.status())
    })
}

/// One frame: `n_points` BEV feature points `{u, x}` (metres ahead, metres lateral) at
/// `points[2 i]`, `points[2 i + 1]`, taken at `time_us` microseconds (strictly increasing).
///
/// Writes the filtered lanes to `out_lanes` (NULL with `capacity` 0 to skip, else room for at
/// least `STJPDACF_MAX_LANES`) and the counters to `*report` (NULL to skip); the number of
/// filtered lanes is `report->filtered_lanes` (also from `stjpdacf_filtered`). The smoothed
/// lanes are read with `stjpdacf_smoothed`.
///
/// Returns `STJPDACF_OK` or `STJPDACF_DEGRADED` when the frame was processed. Refused, with the
/// tracker untouched: `STJPDACF_NULL_POINTER`, `STJPDACF_MISALIGNED`,
/// `STJPDACF_NOT_INITIALISED`, `STJPDACF_TOO_MANY_POINTS` (`n_points >
/// STJPDACF_MAX_POINTS_IN`), `STJPDACF_CAPACITY_TOO_SMALL`, `STJPDACF_NON_INCREASING_TIME`.
///
/// Cost: `Tracker::step` (bounded, see the core's docs) plus copies of at most 12 lanes.
///
/// # Safety
/// `tracker` comes from `stjpdacf_init` and is not used concurrently; `points` holds `2 ·
/// n_points` floats; `out_lanes` has room for `capacity` lanes; `report` is writable; none of
/// these overlap each other or the tracker's buffer.
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_step(
    tracker: *mut stjpdacf_tracker,
    time_us: i64,
    points: *const f32,
    n_points: usize,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    report: *mut stjpdacf_report,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe {
        step_model(
            tracker, time_us, points, n_points, out_lanes, capacity, report,
        )
    }
}

/// [`stjpdacf_step`] for the small model (`tracker` from `stjpdacf_small_init`).
///
/// # Safety
/// As [`stjpdacf_step`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_small_step(
    tracker: *mut stjpdacf_small_tracker,
    time_us: i64,
    points: *const f32,
    n_points: usize,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    report: *mut stjpdacf_report,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe {
        step_model(
            tracker, time_us, points, n_points, out_lanes, capacity, report,
        )
    }
}

/// [`stjpdacf_step`] for the rank-5 model (`tracker` from `stjpdacf_rank5_init`).
///
/// # Safety
/// As [`stjpdacf_step`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_rank5_step(
    tracker: *mut stjpdacf_rank5_tracker,
    time_us: i64,
    points: *const f32,
    n_points: usize,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    report: *mut stjpdacf_report,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe {
        step_model(
            tracker, time_us, points, n_points, out_lanes, capacity, report,
        )
    }
}

fn copy_lanes(src: &[LaneEstimate<16>], dst: &mut [stjpdacf_lane; STJPDACF_MAX_LANES]) -> u8 {
    let mut n = 0u8;
    for (d, s) in dst.iter_mut().zip(src) {
        *d = stjpdacf_lane::from(s);
        n += 1;
    }
    n
}

/// Reads out stored lanes (filtered or smoothed).
///
/// # Safety
/// As [`stjpdacf_filtered`].
unsafe fn read_lanes<M: Model>(
    tracker: *const M,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    count: *mut usize,
    smoothed: bool,
) -> Result<stjpdacf_status, stjpdacf_status> {
    // SAFETY: the caller's contract: `tracker` from `stjpdacf_init`, not written meanwhile.
    let t = unsafe { tracker_ref(tracker) }?;
    let count = required(count)?;
    // SAFETY: the caller's contract: room for `capacity` lanes.
    let lanes = unsafe { slice_out(out_lanes, capacity) }?.ok_or(STJPDACF_NULL_POINTER)?;
    let (src, n) = if smoothed {
        (&t.smoothed, t.n_smoothed)
    } else {
        (&t.filtered, t.n_filtered)
    };
    for (d, s) in lanes.iter_mut().zip(src) {
        *d = *s;
    }
    // SAFETY: the caller's contract: `count` is writable.
    unsafe { write_out(count, usize::from(n)) }?;
    Ok(STJPDACF_OK)
}

/// The filtered lanes of the last processed frame: writes them to `out_lanes` (room for
/// `capacity ≥ STJPDACF_MAX_LANES` lanes) and their number to `*count`.
///
/// Returns `STJPDACF_OK`, or `STJPDACF_NULL_POINTER`, `STJPDACF_MISALIGNED`,
/// `STJPDACF_NOT_INITIALISED`, `STJPDACF_CAPACITY_TOO_SMALL` with nothing written.
///
/// # Safety
/// `tracker` comes from `stjpdacf_init` and is not written concurrently; `out_lanes` has room
/// for `capacity` lanes; `count` is writable.
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_filtered(
    tracker: *const stjpdacf_tracker,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    count: *mut usize,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    checked(|| unsafe { read_lanes(tracker, out_lanes, capacity, count, false) })
}

/// The smoothed lanes (`STJPDACF_LAG` frames before the last processed frame; none until the
/// window is full), as [`stjpdacf_filtered`]: the smoothed estimates of the lanes published in
/// the last frame's filtered lanes only (a lane removed since is not published, also when a new
/// lane has taken its slot), so a lane of that earlier frame may be missing.
///
/// # Safety
/// As [`stjpdacf_filtered`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_smoothed(
    tracker: *const stjpdacf_tracker,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    count: *mut usize,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    checked(|| unsafe { read_lanes(tracker, out_lanes, capacity, count, true) })
}

/// [`stjpdacf_filtered`] for the small model (`tracker` from `stjpdacf_small_init`).
///
/// # Safety
/// As [`stjpdacf_filtered`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_small_filtered(
    tracker: *const stjpdacf_small_tracker,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    count: *mut usize,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    checked(|| unsafe { read_lanes(tracker, out_lanes, capacity, count, false) })
}

/// [`stjpdacf_smoothed`] for the small model (`tracker` from `stjpdacf_small_init`).
///
/// # Safety
/// As [`stjpdacf_filtered`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_small_smoothed(
    tracker: *const stjpdacf_small_tracker,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    count: *mut usize,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    checked(|| unsafe { read_lanes(tracker, out_lanes, capacity, count, true) })
}

/// [`stjpdacf_filtered`] for the rank-5 model (`tracker` from `stjpdacf_rank5_init`).
///
/// # Safety
/// As [`stjpdacf_filtered`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_rank5_filtered(
    tracker: *const stjpdacf_rank5_tracker,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    count: *mut usize,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    checked(|| unsafe { read_lanes(tracker, out_lanes, capacity, count, false) })
}

/// [`stjpdacf_smoothed`] for the rank-5 model (`tracker` from `stjpdacf_rank5_init`).
///
/// # Safety
/// As [`stjpdacf_filtered`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_rank5_smoothed(
    tracker: *const stjpdacf_rank5_tracker,
    out_lanes: *mut stjpdacf_lane,
    capacity: usize,
    count: *mut usize,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    checked(|| unsafe { read_lanes(tracker, out_lanes, capacity, count, true) })
}

/// A lane's GP read-out for a tracker of model `M` (see [`stjpdacf_lane_at`]).
///
/// # Safety
/// As [`stjpdacf_lane_at`].
unsafe fn lane_at_model<M: Model>(
    tracker: *const M,
    slot: u32,
    u: f32,
    x: *mut f32,
    var: *mut f32,
) -> stjpdacf_status {
    checked(|| {
        // SAFETY: the caller's contract: `tracker` from `stjpdacf_init`, not written meanwhile.
        let t = unsafe { tracker_ref(tracker) }?;
        let x = required(x)?;
        if !var.is_null() {
            required(var)?;
        }
        let (m, v) = M::lane_at(&t.tracker, slot as usize, u).ok_or(STJPDACF_NO_LANE)?;
        // SAFETY: the caller's contract: `x` and `var` (when not null) are writable.
        unsafe {
            write_out(x, m)?;
            write_out(var, v)?;
        }
        Ok(STJPDACF_OK)
    })
}

/// A lane's lateral position `*x` (metres) and its variance `*var` (m²) at `u` metres ahead,
/// anywhere inside the BEV window: the GP evaluation of the lane in `slot` (Rust
/// `Tracker::lane_at`). `var` may be NULL.
///
/// Returns `STJPDACF_OK`, `STJPDACF_NO_LANE` (free slot, `u` outside the window or not finite),
/// or `STJPDACF_NULL_POINTER`, `STJPDACF_MISALIGNED`, `STJPDACF_NOT_INITIALISED`; nothing is
/// written unless `STJPDACF_OK`.
///
/// Cost: O(`STJPDACF_INDEX_POINTS` · rank) plus one `exp` per index point.
///
/// # Safety
/// `tracker` comes from `stjpdacf_init` and is not written concurrently; `x` and `var` are
/// writable.
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_lane_at(
    tracker: *const stjpdacf_tracker,
    slot: u32,
    u: f32,
    x: *mut f32,
    var: *mut f32,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe { lane_at_model(tracker, slot, u, x, var) }
}

/// [`stjpdacf_lane_at`] for the small model (`tracker` from `stjpdacf_small_init`).
///
/// # Safety
/// As [`stjpdacf_lane_at`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_small_lane_at(
    tracker: *const stjpdacf_small_tracker,
    slot: u32,
    u: f32,
    x: *mut f32,
    var: *mut f32,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe { lane_at_model(tracker, slot, u, x, var) }
}

/// [`stjpdacf_lane_at`] for the rank-5 model (`tracker` from `stjpdacf_rank5_init`).
///
/// # Safety
/// As [`stjpdacf_lane_at`].
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_rank5_lane_at(
    tracker: *const stjpdacf_rank5_tracker,
    slot: u32,
    u: f32,
    x: *mut f32,
    var: *mut f32,
) -> stjpdacf_status {
    // SAFETY: the caller's contract above.
    unsafe { lane_at_model(tracker, slot, u, x, var) }
}

/// The BEV window and index points of the built-in model.
///
/// Returns `STJPDACF_OK`, or `STJPDACF_NULL_POINTER` / `STJPDACF_MISALIGNED` for `out`.
///
/// # Safety
/// `out` is writable.
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_model_info(out: *mut stjpdacf_model) -> stjpdacf_status {
    let h = &DEFAULT.hyper;
    let m = stjpdacf_model {
        u_min: h.u_min,
        u_max: h.u_max,
        index_u: DEFAULT.index_u.into(),
    };
    // SAFETY: the caller's contract: `out` is writable (null and alignment are checked).
    checked(|| unsafe { required(out).and_then(|p| write_out(p, m)) }.map(|()| STJPDACF_OK))
}

/// Decodes one frame of the SPI wire format (see `src/wire.rs`) from the start of `bytes`
/// (`len` bytes; bytes after the frame are ignored) into `points` (room for `capacity` `{u, x}`
/// pairs, i.e. `2 · capacity` floats) and `*info`. No sequence or time check: `stjpdacf_step`
/// refuses a non-increasing time itself.
///
/// Returns `STJPDACF_OK`, a `STJPDACF_WIRE_*` status for a bad frame, or
/// `STJPDACF_NULL_POINTER` / `STJPDACF_MISALIGNED` / `STJPDACF_TOO_MANY_POINTS` (`capacity >
/// STJPDACF_MAX_POINTS_IN`); `points` and `info` are untouched unless `STJPDACF_OK`.
///
/// Cost: O(`len`), one CRC pass.
///
/// # Safety
/// `bytes` holds `len` readable bytes; `points` has room for `2 · capacity` floats; `info` is
/// writable; the arrays do not overlap.
#[no_mangle]
pub unsafe extern "C" fn stjpdacf_decode_frame(
    bytes: *const u8,
    len: usize,
    points: *mut f32,
    capacity: usize,
    info: *mut stjpdacf_frame_info,
) -> stjpdacf_status {
    checked(|| {
        // SAFETY: the caller's contract: `len` readable bytes. The bound only rules out lengths no
        // object can have (`isize::MAX`).
        let bytes = unsafe { slice_in(bytes, len, isize::MAX as usize) }?;
        let info = required(info)?;
        let pts: &mut [[f32; 2]] = if capacity == 0 {
            &mut []
        } else {
            let p = required(points.cast::<[f32; 2]>())?;
            if capacity > STJPDACF_MAX_POINTS_IN {
                return Err(STJPDACF_TOO_MANY_POINTS);
            }
            // SAFETY: non-null and aligned (checked), `capacity` bounded (checked); the caller
            // guarantees room for `capacity` pairs, not overlapping `bytes`; floats are plain data.
            unsafe { core::slice::from_raw_parts_mut(p, capacity) }
        };
        let fi = wire::decode(bytes, pts)?;
        let v = stjpdacf_frame_info {
            seq: fi.seq,
            count: fi.count as u32,
            time_us: fi.time.as_micros(),
            len: wire::frame_len(fi.count),
        };
        // SAFETY: non-null and aligned (checked by `required`), writable (the caller).
        unsafe { write_out(info, v) }?;
        Ok(STJPDACF_OK)
    })
}

/// The panic handler of the bare-metal staticlibs. Never reached: the core does not panic
/// (the M4F C example's link shows no call to it survives).
#[cfg(all(target_os = "none", not(test)))]
#[panic_handler]
fn panic_halt(_: &core::panic::PanicInfo<'_>) -> ! {
    loop {
        core::hint::spin_loop();
    }
}

#[cfg(test)]
mod tests;
