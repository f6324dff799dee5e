//! The no-panic proof: every public entry point of the core, called on opaque inputs
//! (`core::hint::black_box`, so nothing is constant-folded), in a binary whose panic handler is
//! `panic-never`. That handler refers to a symbol that does not exist, so the binary links only
//! if the optimiser removed every path to a panic: `cargo build --release --bin nopanic`
//! succeeding is the proof (for the release profile: LTO, `opt-level = 3`, no overflow checks).
//!
//! Never run: the objects live on its stack (the reference tracker alone is ≈148 KB), which keeps
//! the proof independent of the RAM budget that the other binaries check.
#![no_std]
#![no_main]

use core::fmt::Write;
use core::hint::black_box;

use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};
use nalgebra::{SMatrix, SVector};
#[cfg(not(feature = "trace-panics"))]
use panic_never as _;
use stjpdacf::kernel::{Matern32, RbfStateSpace};
use stjpdacf::math;
use stjpdacf::probe::{NoProbe, Probe, Stage};
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter, Status};
use stjpdacf::spatial::row::{self, RowParams};
use stjpdacf::spatial::Stacked;
use stjpdacf::tables::{ReferenceTables, DEFAULT};
use stjpdacf::temporal::filter::TemporalFilter;
use stjpdacf::temporal::identity::{pair_cost, IdentityConfig, LanePrediction, LaneTable};
use stjpdacf::temporal::smoother::Temporal;
use stjpdacf::tracker::{Instant, Rank4Tracker, ReferenceTracker, TrackerConfig};
use stjpdacf::wire::{self, Receiver};

/// With `trace-panics`: a plain handler, so the binary links and its panics can be located.
#[cfg(feature = "trace-panics")]
#[panic_handler]
#[inline(never)]
fn on_panic(_: &core::panic::PanicInfo) -> ! {
    loop {
        cortex_m::asm::nop();
    }
}

/// An SPI device whose bytes and failures the optimiser cannot predict.
struct Opaque;

impl ErrorType for Opaque {
    type Error = ErrorKind;
}

impl SpiDevice for Opaque {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        if black_box(false) {
            return Err(ErrorKind::Other);
        }
        for op in ops.iter_mut() {
            match op {
                Operation::Read(buf) | Operation::TransferInPlace(buf) => {
                    for b in buf.iter_mut() {
                        *b = black_box(0);
                    }
                }
                Operation::Transfer(read, _) => {
                    for b in read.iter_mut() {
                        *b = black_box(0);
                    }
                }
                Operation::Write(_) | Operation::DelayNs(_) => {}
            }
        }
        Ok(())
    }
}

/// A text sink for the errors' `Display` impls.
struct Sink;

impl Write for Sink {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        black_box(s);
        Ok(())
    }
}

/// Counts probe calls (a probe other than `NoProbe`).
struct Counter(u32);

impl Probe for Counter {
    fn enter(&mut self, stage: Stage) {
        self.0 = self.0.wrapping_add(stage as u32);
        black_box(stage.name());
    }
}

fn f() -> f32 {
    black_box(0.0)
}

fn u() -> usize {
    black_box(0)
}

fn mat<const R: usize, const C: usize>() -> SMatrix<f32, R, C> {
    black_box(SMatrix::from_array_storage(nalgebra::ArrayStorage(
        [[0.0; R]; C],
    )))
}

fn observation() -> LaneObservation<16> {
    black_box(LaneObservation {
        status: if black_box(true) {
            Status::Confirmed
        } else {
            Status::Tentative
        },
        present: black_box([true; 16]),
        z: mat(),
        cov: mat(),
        u_first: f(),
        u_last: f(),
        existence: f(),
        rank: black_box(0),
        llr: 0.0,
    })
}

#[allow(clippy::too_many_lines)]
#[cortex_m_rt::entry]
fn main() -> ! {
    let tables: &'static ReferenceTables = black_box(&DEFAULT);
    let mut sink = Sink;
    let _ = write!(sink, "{:?}", tables.validate().err());
    if let Err(e) = tables.validate() {
        let _ = write!(sink, "{e}");
    }

    // Kernels and math.
    let m = Matern32::new(f(), f());
    black_box((m.lambda(), m.eval(f()), m.p_inf(), m.transition(f())));
    let rbf: RbfStateSpace<2> = black_box(tables.spatial.model);
    black_box((rbf.lql(), rbf.transition(f()), rbf.covariance(f())));
    black_box((
        math::sqrt(f()),
        math::exp(f()),
        math::expm1(f()),
        math::ln(f()),
    ));
    let a3: SMatrix<f32, 3, 3> = mat();
    black_box((
        math::norm1(&a3),
        math::expm(&a3, f()),
        math::discretize(&a3, &mat(), f()),
    ));

    // Spatial: the stacked state, a row, a frame.
    let mut st: Stacked<3, 6> = black_box(Stacked::new());
    let _ = st.push(mat(), &mat());
    let _ = st.insert(u(), mat(), &mat(), &[mat(); 6]);
    st.set_cross(u(), u(), &mat());
    st.predict::<6>(&mat(), &mat(), &mat());
    black_box(st.update_single(u(), &mat(), f(), f()));
    black_box((st.len(), st.is_empty(), st.mean(u()), st.cov(u(), u())));
    st.remove(u());
    let params = black_box(RowParams::default());
    let row_pts: [f32; 40] = black_box([0.0; 40]);
    let n_row = u();
    let row_pts = row_pts.get(..n_row).unwrap_or(&[]);
    let h: SVector<f32, 3> = mat();
    let skip: u32 = black_box(0);
    black_box(row::update(&mut st, &h, row_pts, &params, u()));
    black_box(row::update_masked(&mut st, &h, row_pts, &params, u(), skip));
    let mut counter = Counter(0);
    let probed = row::update_probed(&mut st, &h, row_pts, &params, u(), skip, &mut counter);
    black_box(probed);

    let points: [[f32; 2]; 300] = black_box([[0.0; 2]; 300]);
    let n_pts = u();
    let pts = points.get(..n_pts).unwrap_or(&[]);
    let cfg: Config = black_box(Config::DEFAULT);
    let mut sf: SpatialFilter<3, 6, 64, 16> = black_box(SpatialFilter::new());
    let mut obs = [observation(); 6];
    black_box(sf.run(tables, &cfg, pts, &mut obs));
    black_box(sf.run_probed(tables, &cfg, pts, &mut obs, &mut counter));

    // Identity.
    let pred = black_box(LanePrediction::from_observation(&observation(), f()));
    let _ = black_box(pair_cost(&observation(), &pred, black_box(3)));
    let icfg: IdentityConfig = black_box(IdentityConfig::DEFAULT);
    let mut ids: LaneTable<6> = black_box(LaneTable::starting_at(black_box(7)));
    let n_obs = u();
    let outcome = ids.associate(&[pred; 6], obs.get(..n_obs).unwrap_or(&[]), &icfg);
    black_box((outcome.obs_fates(), outcome.report));
    black_box((ids.lane(u()), ids.len(), ids.is_empty(), ids.next_id()));
    for l in ids.lanes() {
        black_box(l);
    }
    ids.clear();
    black_box(LaneTable::<6>::new());

    // Temporal filter and smoother.
    let ranks: [u8; 6] = black_box([0; 6]);
    let mut tf: TemporalFilter<6, 16, 7, 84> = black_box(TemporalFilter::new());
    let _ = tf.start_lane(tables, u(), black_box(0), &ranks);
    if let Err(e) = tf.set_ranks(&ranks) {
        let _ = write!(sink, "{e}");
    }
    let _ = tf.predict(tables, f());
    let _ = tf.update(tables, u(), &observation());
    black_box((tf.lane(tables, u()), tf.is_active(u()), tf.lanes()));
    black_box(tf.coefficient_var(u(), &black_box([0.0; 16]), u()));
    black_box((tf.mean().get(u()), tf.covariance().get((u(), u()))));
    black_box(TemporalFilter::<6, 16, 7, 84>::index(u(), u(), u()));
    black_box((tf.repair_due(), tf.repair_covariance(tables)));
    tf.remove_lane(u());
    let mut tp: Temporal<6, 16, 7, 84, 42, 4> = black_box(Temporal::new());
    let _ = tp.start_lane(tables, u(), black_box(0), &ranks);
    let _ = tp.set_ranks(&ranks);
    let _ = tp.predict(tables, f());
    if let Err(e) = tp.predict_probed(tables, f(), &mut counter) {
        let _ = write!(sink, "{e}");
    }
    let _ = tp.update(tables, u(), &observation());
    let _ = tp.update_probed(tables, u(), &observation(), &mut counter);
    black_box((
        tp.lagged(tables, u(), u()),
        tp.frames(),
        tp.filter().lanes(),
    ));
    black_box(tp.repair_covariance(tables));
    tp.remove_lane(u());

    // The tracker.
    let mut tr = ReferenceTracker::with_config(tables, black_box(TrackerConfig::DEFAULT));
    let now = Instant::from_micros(black_box(0));
    match tr.step(now, pts) {
        Ok(out) => {
            black_box(out);
        }
        Err(e) => {
            let _ = write!(sink, "{e}");
        }
    }
    let _ = black_box(tr.step_probed(Instant::from_millis(black_box(1)), pts, &mut counter));
    let _ = black_box(tr.step_probed(now, pts, &mut NoProbe));
    black_box((tr.lane_at(u(), f()), tr.frames(), now.as_micros()));
    black_box(ReferenceTracker::new(tables).frames());
    // The smallest model's capacity (Gram rank 4): another instantiation of every stage.
    let mut small = Rank4Tracker::with_config(tables, black_box(TrackerConfig::DEFAULT));
    let _ = black_box(small.step_probed(now, pts, &mut counter));
    black_box((small.lane_at(u(), f()), small.frames()));

    // The wire format: encoder, decoder, receiver, SPI reader.
    let mut bytes: [u8; wire::frame_len(300)] = black_box([0; wire::frame_len(300)]);
    let n_bytes = u();
    match wire::encode(black_box(1), now, pts, &mut bytes) {
        Ok(n) => {
            black_box(n);
        }
        Err(e) => {
            let _ = write!(sink, "{e}");
        }
    }
    let mut out = [[0.0f32; 2]; 256];
    let frame = bytes.get(..n_bytes).unwrap_or(&[]);
    if let Err(e) = wire::decode(frame, &mut out) {
        let _ = write!(sink, "{e}");
    }
    black_box(wire::crc32(frame));
    let mut rx = Receiver::new();
    let _ = black_box(rx.accept(frame, &mut out));
    match rx.read(&mut Opaque, &mut bytes, &mut out) {
        Ok(info) => {
            black_box(info);
        }
        Err(e) => {
            let _ = write!(sink, "{e}");
        }
    }
    black_box((rx.stats().rejected(), *rx.stats()));
    rx.reset();
    black_box((&mut tr, &mut st, &mut sf, &mut tf, &mut tp, &out, counter.0));

    loop {
        cortex_m::asm::nop();
    }
}
