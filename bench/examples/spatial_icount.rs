//! Callgrind driver for the spatial JPDACF: runs one input of `bench/benches/spatial.rs` /
//! `bench/benches/tracker.rs` (same seeds, same construction) `N` times inside
//! `measure_spatial`, so that
//!
//! ```sh
//! valgrind --tool=callgrind --toggle-collect='*measure_spatial*' \
//!   target/release/examples/spatial_icount row_typical 10
//! ```
//!
//! counts exactly the instructions of the measured calls (divide by `N`, and by the frame count
//! for the `seq_*` inputs). `bench/icount.py` runs every input (and the per-stage split, `--stages`) and prints the table of
//! `docs/benchmarks.md`. Without valgrind it just runs (and prints the row/frame counters, which
//! tie each input to the bench's: events, patterns, approximated rows).
//!
//! Inputs (`spatial_icount --list`):
//! * `row_typical`, `row_worst`, `row_maxwork`, `row_dense512`, `row_dense_exact` — the rows of
//!   `bench/benches/spatial.rs` (`row::update` on a copy of the predicted state);
//! * `frame_typical`, `frame_worst` — the frames of `bench/benches/spatial.rs`
//!   (`SpatialFilter::run`);
//! * `seq_typical` (20 frames, 3 lanes + clutter) and `seq_worst` (8 frames, 6 lanes, first 256
//!   points) — the frames of `bench/benches/tracker.rs` through `SpatialFilter::run` alone.
//!
//! `spatial_icount --dump` prints every output (β, states, pseudo-measurements) with full
//! precision, to compare two builds.

use std::hint::black_box;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use stjpdacf::probe::{Probe, Stage};
use stjpdacf::spatial::filter::{Config, SpatialReport};
use stjpdacf::spatial::row::{self, RowOutcome};
use stjpdacf::tables::DEFAULT;
use stjpdacf_bench::inputs::{self, Frame};
use stjpdacf_bench::spatial::{
    core_params as params, empty_out, h, row_inputs, to_f32, typical_scenario, worst_frame, Filter,
    Obs, RowInput, State, LANES, MEAS,
};

/// The frame sequences of `bench/benches/tracker.rs`, cut to M points.
fn sequence(frames: &[Frame]) -> Vec<Vec<[f32; 2]>> {
    frames.iter().map(|f| f.truncated(MEAS).p32).collect()
}

fn frame_inputs(name: &str) -> Option<Vec<Vec<[f32; 2]>>> {
    Some(match name {
        "frame_typical" => vec![to_f32(&typical_scenario())],
        "frame_worst" => vec![worst_frame(&mut ChaCha8Rng::seed_from_u64(7))],
        "seq_typical" => sequence(&inputs::typical()),
        "seq_worst" => sequence(&inputs::worst()),
        _ => return None,
    })
}

const FRAMES: [&str; 4] = ["frame_typical", "frame_worst", "seq_typical", "seq_worst"];

/// The measured region of row inputs: `iters` row steps on copies of the predicted state.
#[inline(never)]
fn measure_spatial_rows(input: &RowInput, iters: usize) -> (State, RowOutcome<LANES>) {
    let p = params();
    let hv = h();
    let mut last = (input.state, RowOutcome::default());
    for _ in 0..iters {
        let mut s = black_box(input.state);
        let o = row::update(&mut s, &hv, black_box(&input.points), &p, input.budget);
        last = black_box((s, o));
    }
    last
}

/// The measured region of frame inputs: `iters` passes over the frames.
#[inline(never)]
fn measure_spatial_frames(
    f: &mut Filter,
    frames: &[Vec<[f32; 2]>],
    iters: usize,
    out: &mut Obs,
) -> Vec<(usize, SpatialReport)> {
    let mut reps = Vec::with_capacity(frames.len());
    for it in 0..iters {
        for fr in frames {
            let r = f.run(&DEFAULT, &Config::DEFAULT, black_box(fr), out);
            if it == 0 {
                reps.push(r);
            }
            black_box(&out);
        }
    }
    reps
}

macro_rules! marks {
    ($($name:ident = $stage:ident),* $(,)?) => {
        $(
            /// Marks the entry of a stage (callgrind `--dump-before` target).
            #[inline(never)]
            fn $name() {
                black_box(Stage::$stage as u8);
            }
        )*
        /// Calls the stage's marker on every transition, so that callgrind with
        /// `--dump-before='*stage_mark_*'` splits the counts by stage.
        struct Marks;
        impl Probe for Marks {
            fn enter(&mut self, stage: Stage) {
                match stage {
                    $(Stage::$stage => $name(),)*
                    _ => {}
                }
            }
        }
    };
}

marks! {
    stage_mark_binning = Binning,
    stage_mark_row_predict = RowPredict,
    stage_mark_gating = Gating,
    stage_mark_events = Events,
    stage_mark_update = Update,
    stage_mark_management = Management,
    stage_mark_backward = Backward,
    stage_mark_done = Done,
}

/// The frames again with stage markers (`--stages`): one pass, then [`Stage::Done`].
#[inline(never)]
fn measure_spatial_stages(f: &mut Filter, frames: &[Vec<[f32; 2]>], out: &mut Obs) {
    let mut marks = Marks;
    for fr in frames {
        black_box(f.run_probed(&DEFAULT, &Config::DEFAULT, black_box(fr), out, &mut marks));
        marks.enter(Stage::Done);
    }
}

fn dump_state(s: &State) {
    for i in 0..s.len() {
        println!("  x[{i}] = {:?}", s.mean(i).expect("track").as_slice());
        for j in 0..s.len() {
            println!(
                "  P[{i}][{j}] = {:?}",
                s.cov(i, j).expect("track").as_slice()
            );
        }
    }
}

fn dump_obs(out: &Obs, n: usize) {
    for (k, o) in out.iter().take(n).enumerate() {
        println!(
            "  lane {k}: status {:?} rank {} u {}..{} existence {} present {:?}",
            o.status, o.rank, o.u_first, o.u_last, o.existence, o.present
        );
        println!("   z = {:?}", o.z.as_slice());
        println!("   cov = {:?}", o.cov.as_slice());
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let rows = row_inputs();
    if args.first().map(String::as_str) == Some("--list") {
        for (n, _) in &rows {
            println!("{n}");
        }
        for n in FRAMES {
            println!("{n}");
        }
        return;
    }
    let dump = args.first().map(String::as_str) == Some("--dump");
    if args.first().map(String::as_str) == Some("--stages") {
        let name = args
            .get(1)
            .cloned()
            .unwrap_or_else(|| "frame_typical".into());
        let Some(frames) = frame_inputs(&name) else {
            eprintln!("--stages takes a frame input (frame_*, seq_*)");
            std::process::exit(2);
        };
        let mut f = Box::new(Filter::new());
        let mut out = empty_out();
        measure_spatial_stages(&mut f, &frames, &mut out);
        println!("{name}: frames {}", frames.len());
        return;
    }
    let names: Vec<String> = if dump {
        rows.iter()
            .map(|(n, _)| (*n).to_string())
            .chain(FRAMES.iter().map(|n| (*n).to_string()))
            .collect()
    } else {
        vec![args
            .first()
            .cloned()
            .unwrap_or_else(|| "row_typical".into())]
    };
    let iters: usize = if dump {
        1
    } else {
        args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1)
    };
    for name in names {
        if let Some((_, input)) = rows.iter().find(|(n, _)| *n == name) {
            let (s, o) = measure_spatial_rows(input, iters);
            println!(
                "{name}: iters {iters} frames 1 tracks {} points {} events {} patterns {} \
                 dropped {} approximated {} failed {}",
                input.state.len(),
                input.points.len(),
                o.events,
                o.patterns,
                o.dropped_candidates,
                o.approximated,
                o.failed
            );
            if dump {
                println!("  beta_miss = {:?}", o.beta_miss);
                for (t, b) in o.beta.iter().enumerate().take(s.len()) {
                    println!("  beta[{t}] = {:?}", &b[..input.points.len()]);
                }
                dump_state(&s);
            }
        } else if let Some(frames) = frame_inputs(&name) {
            let mut f = Box::new(Filter::new());
            let mut out = empty_out();
            if dump {
                println!("{name}:");
                for fr in &frames {
                    let (n, rep) = f.run(&DEFAULT, &Config::DEFAULT, fr, &mut out);
                    println!(" report {rep:?}");
                    dump_obs(&out, n);
                }
                continue;
            }
            let reps = measure_spatial_frames(&mut f, &frames, iters, &mut out);
            let events: u32 = reps.iter().map(|r| r.1.events).sum();
            let approx: u32 = reps.iter().map(|r| r.1.rows_approximated).sum();
            let lanes: usize = reps.iter().map(|r| r.0).sum();
            let points: usize = frames.iter().map(Vec::len).sum();
            println!(
                "{name}: iters {iters} frames {} points {points} events {events} \
                 rows_approximated {approx} lanes_out {lanes}",
                frames.len()
            );
        } else {
            eprintln!("unknown input {name}; --list lists them");
            std::process::exit(2);
        }
    }
}
