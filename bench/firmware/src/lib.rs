//! The firmware benchmark: the reference tracker on a Cortex-M4F (QEMU `mps2-an386`), fed
//! frames in the SPI wire format, with instruction counts per frame and per stage, the stack
//! high-water mark, and an exit status through semihosting.
//!
//! Each scenario is its own binary (`src/bin/<name>.rs`, the frames from
//! `scenarios/<name>.stjf` embedded with `include_bytes!`), so every scenario starts from reset
//! with a fresh tracker in its `static`. [`run`] decodes the frames one by one with a
//! [`Receiver`] (as they would come from SPI), steps the tracker with a [`TickProbe`], and prints
//! one line per frame on the semihosting stdout (text only, no defmt):
//!
//! ```text
//! SCENARIO <name> frames=<n> instr_per_tick=5 probe_overhead=<instr per call> calibration=<instr>
//! FRAME <k> points=<n> lanes=<filtered> events=<spatial events> approx=<rows pruned> decode=<instr> total=<instr> binning=<instr> ... output=<instr>
//! STACK used=<bytes> size=<bytes>
//! DONE ok
//! ```
//!
//! # Instruction counts
//! QEMU runs with `-icount shift=3,align=off,sleep=off`: virtual time advances 2³ = 8 ns per
//! executed instruction, and SysTick counts the 25 MHz CPU clock (40 ns), so one SysTick tick is
//! 5 instructions ([`INSTR_PER_TICK`]; with `shift=0`, 1 ns per instruction, it would be 40).
//! [`TickProbe`] reads the (down-counting, 24-bit, free-running) SysTick at every stage transition
//! and charges the ticks since the previous transition to the stage that was running; an interval
//! must stay under 2²⁴ ticks (84 M instructions). Counts are identical from run to run; each
//! reading is quantised to 5 instructions, and every probe call costs a few instructions itself
//! (measured and printed as `probe_overhead`). `calibration` is what the probe's clock measures
//! for a loop of exactly 2,000,000 instructions (`cortex_m::asm::delay`): it checks the clock
//! assumption on every run.
//!
//! # Stack
//! cortex-m-rt's `paint-stack` fills the stack with `0xCCCC_CCCC` at reset; after the last frame
//! the stack is scanned from its far end for the first overwritten word. With flip-link the
//! stack sits below the statics at the bottom of RAM, so an overflow faults instead of
//! corrupting them.
#![no_std]

use core::cell::RefCell;

use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::{exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprint, hprintln};
use stjpdacf::persist::PersistConfig;
use stjpdacf::probe::{Probe, Stage};
use stjpdacf::spatial::filter::{Config as SpatialConfig, LaneObservation, SpatialFilter};
use stjpdacf::spatial::row::Association;
use stjpdacf::tables::{ReferenceTables, DEFAULT, UNCOUPLED};
use stjpdacf::tracker::{LaneEstimate, StepOutput, Tracker, TrackerConfig};
use stjpdacf::wire::{self, frame_len, Receiver};

/// Instructions per SysTick tick: `-icount shift=3` makes an instruction 8 ns of virtual time and
/// SysTick ticks every 40 ns (25 MHz). Keep in step with the runner in `.cargo/config.toml`.
pub const INSTR_PER_TICK: u32 = 5;
/// Points per frame (the reference tracker's M).
pub const MEAS: usize = 256;
const SYST_MASK: u32 = 0x00FF_FFFF;
const PAINT: u32 = 0xCCCC_CCCC;

/// The tracker's tables: [`DEFAULT`] ([`UNCOUPLED`] when the build-time variable
/// `STJPDACF_FW_TABLES` is `uncoupled`), with its Gram truncation lowered to the digit in the
/// build-time variable `STJPDACF_FW_RANK` (a smaller model's cost, docs/measurements.md
/// "Fitting the MCU"; the budget check builds without either).
static TABLES: ReferenceTables = if uncoupled_override() {
    ReferenceTables {
        gram_rank: rank_override(UNCOUPLED.gram_rank),
        ..UNCOUPLED
    }
} else {
    ReferenceTables {
        gram_rank: rank_override(DEFAULT.gram_rank),
        ..DEFAULT
    }
};

/// Whether `STJPDACF_FW_TABLES` is `uncoupled`.
const fn uncoupled_override() -> bool {
    match option_env!("STJPDACF_FW_TABLES") {
        Some(s) => matches!(s.as_bytes(), b"uncoupled"),
        None => false,
    }
}

/// Whether `STJPDACF_FW_PER_LANE` is `1`.
const fn per_lane_override() -> bool {
    match option_env!("STJPDACF_FW_PER_LANE") {
        Some(s) => matches!(s.as_bytes(), [b'1']),
        None => false,
    }
}

/// `STJPDACF_FW_RANK` when it is one digit `1..=default`, else `default`.
const fn rank_override(default: u32) -> u32 {
    match option_env!("STJPDACF_FW_RANK") {
        Some(s) => match s.as_bytes() {
            [d @ b'1'..=b'9'] if ((*d - b'0') as u32) <= default => (*d - b'0') as u32,
            _ => default,
        },
        None => default,
    }
}

/// The known-lane association of the build-time variable `STJPDACF_FW_ASSOC` (`exact`,
/// `hybrid`: LBP over the budget, `lbp`: LBP every row), else the default's.
const fn association_override(default: Association) -> Association {
    match option_env!("STJPDACF_FW_ASSOC") {
        Some(s) => match s.as_bytes() {
            b"exact" => Association::Exact,
            b"hybrid" => Association::ExactOrLbp,
            b"lbp" => Association::Lbp,
            _ => default,
        },
        None => default,
    }
}

/// `false` when the build-time variable `STJPDACF_FW_OWN_PD` is `0` (the joint events at the
/// spatial stage's `P_D`, as until stop 55: `PersistConfig::own_pd`), else `default`.
const fn own_pd_override(default: bool) -> bool {
    match option_env!("STJPDACF_FW_OWN_PD") {
        Some(s) => !matches!(s.as_bytes(), [b'0']) && default,
        None => default,
    }
}

/// `STJPDACF_FW_K` when it is one digit `1..=default`, else `default`.
const fn rows_override(default: u8) -> u8 {
    match option_env!("STJPDACF_FW_K") {
        Some(s) => match s.as_bytes() {
            [d @ b'1'..=b'9'] if *d - b'0' <= default => *d - b'0',
            _ => default,
        },
        None => default,
    }
}

/// The tracker's configuration: [`TrackerConfig::DEFAULT`], with the per-lane smoother when the
/// build-time variable `STJPDACF_FW_PER_LANE` is `1`, the known-lane association of
/// `STJPDACF_FW_ASSOC`, the lanes' own `P_D` unless `STJPDACF_FW_OWN_PD` is `0`, and the rows
/// per index interval of `STJPDACF_FW_K` ([`TrackerConfig::with_rows_per_interval`];
/// docs/measurements.md "Fitting the MCU").
const CONFIG: TrackerConfig = TrackerConfig {
    smoother_per_lane: per_lane_override(),
    persist: PersistConfig {
        association: association_override(PersistConfig::DEFAULT.association),
        own_pd: own_pd_override(PersistConfig::DEFAULT.own_pd),
        ..PersistConfig::DEFAULT
    },
    ..TrackerConfig::DEFAULT
}
.with_rows_per_interval(rows_override(
    TrackerConfig::DEFAULT.spatial.rows_per_interval,
));

/// Whether `STJPDACF_FW_RANK_CAP` is `1`.
const fn rank_cap_override() -> bool {
    match option_env!("STJPDACF_FW_RANK_CAP") {
        Some(s) => matches!(s.as_bytes(), [b'1']),
        None => false,
    }
}

/// The tracker's Gram-rank capacity, its const `RANK`: the reference configuration's 7, or,
/// when the build-time variable `STJPDACF_FW_RANK_CAP` is `1`, the rank the tables are
/// truncated to (`STJPDACF_FW_RANK`): the tracker compiled for the model it runs, so every
/// per-lane loop, state vector and covariance is sized by that rank (docs/measurements.md
/// "Fitting the MCU").
pub const CAP_RANK: usize = if rank_cap_override() {
    rank_override(7) as usize
} else {
    7
};

/// The firmware's tracker: [`stjpdacf::tracker::ReferenceTracker`] (D = 6, N = 16, M = 256,
/// E = 512, L = 4) with the Gram-rank capacity [`CAP_RANK`] (7 unless `STJPDACF_FW_RANK_CAP`).
pub type FwTracker =
    Tracker<2, 3, 6, 16, 64, 16, 256, CAP_RANK, { 2 * 6 * CAP_RANK }, { 6 * CAP_RANK }, 4>;

/// The tracker (≈148 KB at rank capacity 7) lives in a static, never on the stack; all zero
/// ([`Tracker::UNINIT`]), so it is in `.bss` and takes no flash. [`run_tracker_with`]
/// initialises it in place.
static TRACKER: Mutex<RefCell<FwTracker>> = Mutex::new(RefCell::new(FwTracker::UNINIT));

/// Starts SysTick free-running on the CPU clock (no interrupt), reload `2²⁴ − 1`.
pub fn start_systick(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(SYST_MASK);
    syst.clear_current();
    syst.disable_interrupt();
    syst.enable_counter();
}

/// Ticks elapsed from SysTick reading `from` to reading `to` (it counts down and wraps at 2²⁴;
/// valid for intervals under 2²⁴ ticks, 671 M instructions).
#[inline(always)]
fn elapsed(from: u32, to: u32) -> u32 {
    from.wrapping_sub(to) & SYST_MASK
}

/// A [`Probe`] that charges SysTick ticks to stages.
pub struct TickProbe {
    last: u32,
    current: Option<Stage>,
    /// Ticks per stage (indexed by `Stage as usize`).
    pub ticks: [u32; Stage::COUNT],
    /// Probe calls.
    pub calls: u32,
}

impl TickProbe {
    /// A probe whose clock starts now.
    #[inline(always)]
    pub fn start() -> Self {
        Self {
            last: SYST::get_current(),
            current: None,
            ticks: [0; Stage::COUNT],
            calls: 0,
        }
    }

    /// Ticks over all stages.
    pub fn total(&self) -> u32 {
        self.ticks.iter().sum()
    }
}

impl Probe for TickProbe {
    #[inline(always)]
    fn enter(&mut self, stage: Stage) {
        let now = SYST::get_current();
        if let Some(s) = self.current {
            if let Some(t) = self.ticks.get_mut(s as usize) {
                *t += elapsed(self.last, now);
            }
        }
        self.current = Some(stage);
        self.calls += 1;
        self.last = now;
    }
}

/// Instructions per probe call, measured on 4,096 calls.
fn probe_overhead() -> u32 {
    let mut p = TickProbe::start();
    let t0 = SYST::get_current();
    for i in 0..4096u32 {
        p.enter(core::hint::black_box(if i & 1 == 0 {
            Stage::Gating
        } else {
            Stage::Events
        }));
    }
    let t1 = SYST::get_current();
    core::hint::black_box(&p);
    elapsed(t0, t1) * INSTR_PER_TICK / 4096
}

/// Number of frames in `frames` (wire-format frames back to back), from their headers.
fn frame_count(frames: &[u8]) -> usize {
    let mut count = 0usize;
    let mut off = 0usize;
    while let Some(rest) = frames.get(off..).filter(|r| r.len() >= 8) {
        let n = u16::from_le_bytes([
            rest.get(6).copied().unwrap_or(0),
            rest.get(7).copied().unwrap_or(0),
        ]);
        off += frame_len(usize::from(n));
        count += 1;
    }
    count
}

/// What one frame did, besides its instruction counts.
struct FrameFacts {
    points: usize,
    lanes: usize,
    events: u32,
    approx: u32,
    decode_ticks: u32,
}

fn print_frame(k: usize, f: &FrameFacts, probe: &TickProbe) {
    let i = |s: Stage| probe.ticks.get(s as usize).copied().unwrap_or(0) * INSTR_PER_TICK;
    hprintln!(
        "FRAME {} points={} lanes={} events={} approx={} calls={} decode={} total={} \
         binning={} row_predict={} gating={} events_stage={} update={} management={} \
         backward={} identity={} temporal={} smoother={} output={} known={}",
        k,
        f.points,
        f.lanes,
        f.events,
        f.approx,
        probe.calls,
        f.decode_ticks * INSTR_PER_TICK,
        probe.total() * INSTR_PER_TICK,
        i(Stage::Binning),
        i(Stage::RowPredict),
        i(Stage::Gating),
        i(Stage::Events),
        i(Stage::Update),
        i(Stage::Management),
        i(Stage::Backward),
        i(Stage::Identity),
        i(Stage::Temporal),
        i(Stage::Smoother),
        i(Stage::Output),
        i(Stage::Known)
    );
}

/// Decodes the frames of one scenario in order and hands each to `step` (which returns the
/// frame's facts and fills the probe); prints one `FRAME` line each. `false` when a frame is
/// rejected or `step` fails.
fn run_frames(
    name: &str,
    frames: &[u8],
    points: &mut [[f32; 2]; MEAS],
    overhead: u32,
    mut step: impl FnMut(&wire::FrameInfo, &[[f32; 2]], &mut TickProbe) -> Option<(usize, u32, u32)>,
) -> bool {
    hprintln!(
        "SCENARIO {} frames={} instr_per_tick={} probe_overhead={} calibration={}",
        name,
        frame_count(frames),
        INSTR_PER_TICK,
        overhead,
        calibration()
    );
    let mut rx = Receiver::new();
    let mut off = 0usize;
    let mut k = 0usize;
    while let Some(rest) = frames.get(off..).filter(|r| !r.is_empty()) {
        let t0 = SYST::get_current();
        let info = match rx.accept(rest, &mut points[..]) {
            Ok(i) => i,
            Err(e) => {
                hprintln!("ERROR {} frame {} rejected: {}", name, k, e);
                return false;
            }
        };
        let decode_ticks = elapsed(t0, SYST::get_current());
        off += frame_len(info.count);
        let pts = points.get(..info.count).unwrap_or(&[]);
        let mut probe = TickProbe::start();
        let Some((lanes, events, approx)) = step(&info, pts, &mut probe) else {
            hprintln!("ERROR {} frame {} step failed", name, k);
            return false;
        };
        let facts = FrameFacts {
            points: info.count,
            lanes,
            events,
            approx,
            decode_ticks,
        };
        print_frame(k, &facts, &probe);
        k += 1;
    }
    true
}

/// Prints the stack line and exits QEMU (success when `ok`).
fn finish(ok: bool) -> ! {
    let (used, size) = stack_usage();
    hprintln!("STACK used={} size={}", used, size);
    if ok {
        hprintln!("DONE ok");
        debug::exit(debug::EXIT_SUCCESS);
    } else {
        debug::exit(debug::EXIT_FAILURE);
    }
    loop {
        cortex_m::asm::nop();
    }
}

/// Instructions measured for a loop of exactly 2,000,000 (1,000,000 × `subs` + `bne`), plus the
/// few instructions around it.
fn calibration() -> u32 {
    let t0 = SYST::get_current();
    cortex_m::asm::delay(999_999);
    elapsed(t0, SYST::get_current()) * INSTR_PER_TICK
}

/// Runs the scenario `frames` (wire-format frames back to back) through the whole tracker (the
/// `static` [`FwTracker`], initialised in place), prints the figures and exits QEMU with
/// success, or failure when a frame is rejected or a step fails.
pub fn run_tracker(name: &str, frames: &[u8], syst: SYST) -> ! {
    run_tracker_with(name, frames, syst, |_, _| {})
}

/// [`run_tracker`], handing each frame's output to `each(frame index, output)` after the
/// frame's instructions are counted (so the counts do not include it).
pub fn run_tracker_with(
    name: &str,
    frames: &[u8],
    syst: SYST,
    mut each: impl FnMut(usize, &StepOutput<6, 16>),
) -> ! {
    start_systick(syst);
    let overhead = probe_overhead();
    let ok = cortex_m::interrupt::free(|cs| {
        let mut tracker = TRACKER.borrow(cs).borrow_mut();
        tracker.init(&TABLES, CONFIG);
        let mut points = POINTS.borrow(cs).borrow_mut();
        let mut k = 0usize;
        run_frames(name, frames, &mut points, overhead, |info, pts, probe| {
            let out = tracker.step_probed(info.time, pts, probe).ok()?;
            each(k, &out);
            k += 1;
            Some((
                out.filtered.len(),
                out.report.spatial.events,
                out.report.spatial.rows_approximated,
            ))
        })
    });
    finish(ok)
}

/// Runs the scenario as [`run_tracker`] does and prints every filtered and smoothed lane of
/// every frame, exactly (floats as their IEEE-754 bits in hex):
///
/// ```text
/// LANE <F|S> <frame> <id> <slot> <misses> <age> <hits> <u_first> <u_last> <existence> <z[0..16]> <var[0..16]>
/// ```
///
/// The C API's Cortex-M4F example (`capi/examples/m4f`) prints the same lines on the same
/// frames; `cargo xtask capi` compares them.
pub fn run_lanes(name: &str, frames: &[u8], syst: SYST) -> ! {
    run_tracker_with(name, frames, syst, |k, out| {
        for (tag, lanes) in [("F", &out.filtered), ("S", &out.smoothed)] {
            for l in lanes {
                print_lane(tag, k, l);
            }
        }
    })
}

fn print_lane(tag: &str, k: usize, l: &LaneEstimate<16>) {
    let b = f32::to_bits;
    hprint!(
        "LANE {} {} {} {} {} {} {} {:08x} {:08x} {:08x}",
        tag,
        k,
        l.id.0,
        l.slot,
        l.misses,
        l.age,
        l.hits,
        b(l.u_first),
        b(l.u_last),
        b(l.existence)
    );
    for v in l.z.iter().chain(l.var.iter()) {
        hprint!(" {:08x}", b(*v));
    }
    hprintln!("");
}

/// The decoded points of the current frame (2 KiB: a static, not stack).
static POINTS: Mutex<RefCell<[[f32; 2]; MEAS]>> = Mutex::new(RefCell::new([[0.0; 2]; MEAS]));

/// The spatial filter's output when it runs alone (6.6 KiB: a static, not stack).
static OBS: Mutex<RefCell<[LaneObservation<16>; 6]>> = Mutex::new(RefCell::new([EMPTY_OBS; 6]));

/// The spatial JPDACF alone (≈42 KB, in a static): it starts afresh every frame.
static SPATIAL: Mutex<RefCell<SpatialFilter<3, 6, 64, 16>>> =
    Mutex::new(RefCell::new(SpatialFilter::new()));

/// Runs every scenario of `scenarios` (name, frames) through the spatial filter alone
/// (`SpatialFilter::run_probed`, stages binning to backward), prints the figures and exits QEMU.
pub fn run_spatial(scenarios: &[(&str, &[u8])], syst: SYST) -> ! {
    start_systick(syst);
    let overhead = probe_overhead();
    let cfg = SpatialConfig::DEFAULT;
    let ok = cortex_m::interrupt::free(|cs| {
        let mut filter = SPATIAL.borrow(cs).borrow_mut();
        let mut points = POINTS.borrow(cs).borrow_mut();
        let mut obs = OBS.borrow(cs).borrow_mut();
        scenarios.iter().all(|(name, frames)| {
            run_frames(name, frames, &mut points, overhead, |_, pts, probe| {
                let (n, rep) = filter.run_probed(&DEFAULT, &cfg, pts, &mut obs, probe);
                probe.enter(Stage::Done);
                Some((n, rep.events, rep.rows_approximated))
            })
        })
    });
    finish(ok)
}

const EMPTY_OBS: LaneObservation<16> = LaneObservation::EMPTY;

#[doc(hidden)]
pub use cortex_m as __cortex_m;
#[doc(hidden)]
pub use cortex_m_rt::entry as __entry;

/// The entry point of a scenario binary: `scenario_main!(run_tracker("typical", frames))`
/// expands to the `#[entry] fn main` that takes the peripherals and calls
/// `stjpdacf_firmware::run_tracker("typical", frames, SYST)` (likewise [`run_spatial`]). The
/// binary itself names its panic handler (`use panic_semihosting as _;`) and embeds its frames
/// with `include_bytes!` (a path relative to the binary's source).
#[macro_export]
macro_rules! scenario_main {
    ($run:ident($($arg:expr),* $(,)?)) => {
        #[$crate::__entry]
        fn main() -> ! {
            match $crate::__cortex_m::Peripherals::take() {
                Some(p) => $crate::$run($($arg,)* p.SYST),
                None => loop {
                    $crate::__cortex_m::asm::nop();
                },
            }
        }
    };
}

/// Bytes of stack ever used (painted words overwritten, scanning from the far end) and the
/// stack's size.
fn stack_usage() -> (usize, usize) {
    extern "C" {
        static _stack_start: u32;
        static _stack_end: u32;
    }
    // Linker symbols: only their addresses are taken.
    let (top, bottom) = (
        core::ptr::addr_of!(_stack_start) as usize,
        core::ptr::addr_of!(_stack_end) as usize,
    );
    let mut p = bottom;
    while p < top {
        // SAFETY: `bottom..top` is the stack region, word-aligned RAM (cortex-m-rt asserts it).
        let w = unsafe { core::ptr::read_volatile(p as *const u32) };
        if w != PAINT {
            break;
        }
        p += 4;
    }
    (top - p, top - bottom)
}

#[exception]
unsafe fn HardFault(ef: &ExceptionFrame) -> ! {
    hprintln!("HARDFAULT pc={:#010x} lr={:#010x}", ef.pc(), ef.lr());
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::nop();
    }
}
