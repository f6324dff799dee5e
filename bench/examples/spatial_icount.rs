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

use nalgebra::{SMatrix, SVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stjpdacf::probe::{Probe, Stage};
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter, SpatialReport};
use stjpdacf::spatial::row::{self, RowOutcome, RowParams};
use stjpdacf::spatial::Stacked;
use stjpdacf::tables::DEFAULT;
use stjpdacf_tools::scenario::{Scenario, ScenarioConfig, Shape};

const NS: usize = 3;
const LANES: usize = 6;
const ROWS: usize = 64;
const PER_ROW: usize = 16;
const POINTS: usize = 16;
const MEAS: usize = 256;
const EVENTS: usize = 512;
const SPACING: f32 = 3.6;

type Filter = SpatialFilter<NS, LANES, ROWS, PER_ROW>;
type State = Stacked<NS, LANES>;
type Obs = [LaneObservation<POINTS>; LANES];

fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = 1.0 - rng.random::<f32>();
    let u2: f32 = rng.random::<f32>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
}

fn embed(m: &SMatrix<f32, 2, 2>, corner: f32) -> SMatrix<f32, NS, NS> {
    SMatrix::from_fn(|i, j| match (i, j) {
        (0, 0) => corner,
        (0, _) | (_, 0) => 0.0,
        _ => m[(i - 1, j - 1)],
    })
}

fn h() -> SVector<f32, NS> {
    SVector::from([1.0, 1.0, 0.0])
}

fn lane_x(t: usize, n: usize) -> f32 {
    (t as f32 - (n as f32 - 1.0) / 2.0) * SPACING
}

fn broad_state(n: usize) -> State {
    let pinf = &DEFAULT.spatial.model.p_inf;
    let b = &DEFAULT.coreg;
    let mut s = State::new();
    for t in 0..n {
        let p = embed(&(pinf * b[(t, t)]), DEFAULT.hyper.offset_variance);
        s.push(SVector::from([lane_x(t, n), 0.0, 0.0]), &p)
            .expect("fewer than LANES tracks");
    }
    for i in 0..n {
        for j in i + 1..n {
            s.set_cross(i, j, &embed(&(pinf * b[(i, j)]), 0.0));
        }
    }
    s
}

fn tracked_state(n: usize, rng: &mut ChaCha8Rng) -> State {
    let f = embed(&DEFAULT.spatial.f, 1.0);
    let q = embed(&DEFAULT.spatial.q, 0.0);
    let mut s = broad_state(n);
    for r in 0..12 {
        if r > 0 {
            s.predict(&f, &q, &DEFAULT.coreg);
        }
        for t in 0..n {
            let z = lane_x(t, n) + 0.1 * normal(rng);
            assert!(s.update_single(t, &h(), z, DEFAULT.hyper.meas_noise));
        }
    }
    s.predict(&f, &q, &DEFAULT.coreg);
    s
}

fn params() -> RowParams {
    let c = Config::DEFAULT;
    RowParams {
        pd: c.pd,
        pg: c.pg,
        gamma: c.gamma,
        clutter_density: c.clutter_density,
        r: DEFAULT.hyper.meas_noise,
        miss: row::MissModel::Gated,
    }
}

fn clustered(rng: &mut ChaCha8Rng, m: usize, half_width: f32) -> Vec<f32> {
    (0..m)
        .map(|_| (rng.random::<f32>() * 2.0 - 1.0) * half_width)
        .collect()
}

/// A row input: the predicted state, the points and the event budget.
struct RowInput {
    state: State,
    points: Vec<f32>,
    budget: usize,
}

/// The rows of `bench/benches/spatial.rs`, drawn in the bench's order from its seed.
fn row_inputs() -> Vec<(&'static str, RowInput)> {
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let typical = tracked_state(LANES, &mut rng);
    let mut pts: Vec<f32> = (0..LANES)
        .map(|t| lane_x(t, LANES) + 0.1 * normal(&mut rng))
        .collect();
    pts.extend((0..2).map(|_| (rng.random::<f32>() * 2.0 - 1.0) * 12.0));
    let broad = broad_state(LANES);
    let worst = clustered(&mut rng, PER_ROW, 3.0);
    let mut heavy: Vec<f32> = (0..LANES - 1)
        .flat_map(|t| [lane_x(t, LANES) - 0.15, lane_x(t, LANES) + 0.15])
        .collect();
    heavy.push(lane_x(LANES - 1, LANES) + 0.05);
    let dense_state = broad_state(4);
    let dense = clustered(&mut rng, 8, 2.0);
    vec![
        (
            "row_typical",
            RowInput {
                state: typical,
                points: pts,
                budget: EVENTS,
            },
        ),
        (
            "row_worst",
            RowInput {
                state: broad,
                points: worst,
                budget: EVENTS,
            },
        ),
        (
            "row_maxwork",
            RowInput {
                state: typical,
                points: heavy,
                budget: EVENTS,
            },
        ),
        (
            "row_dense512",
            RowInput {
                state: dense_state,
                points: dense.clone(),
                budget: EVENTS,
            },
        ),
        (
            "row_dense_exact",
            RowInput {
                state: dense_state,
                points: dense,
                budget: 4096,
            },
        ),
    ]
}

const LEAD_IN_ROWS: usize = 16;

fn worst_frame(rng: &mut ChaCha8Rng) -> Vec<[f32; 2]> {
    let du = (DEFAULT.hyper.u_max - DEFAULT.hyper.u_min) / 60.0;
    let mut pts = Vec::with_capacity(MEAS);
    let full_rows = (MEAS - LANES * LEAD_IN_ROWS) / PER_ROW;
    for r in 0..LEAD_IN_ROWS + full_rows {
        let u = DEFAULT.hyper.u_min + r as f32 * du;
        for t in 0..LANES {
            pts.push([u, lane_x(t, LANES) + 0.1 * normal(rng)]);
        }
        if r < LEAD_IN_ROWS {
            continue;
        }
        for _ in LANES..PER_ROW {
            let t = rng.random_range(0..LANES);
            pts.push([
                u,
                lane_x(t, LANES) + (rng.random::<f32>() * 2.0 - 1.0) * 0.4,
            ]);
        }
    }
    pts
}

fn to32(sc: &Scenario) -> Vec<[f32; 2]> {
    sc.points
        .iter()
        .map(|&(u, x)| [u as f32, x as f32])
        .collect()
}

/// The frame sequences of `bench/benches/tracker.rs` (`frames(cfg, seed, n)`), cut to M points.
fn sequence(cfg: &ScenarioConfig, seed: u64, n: u64) -> Vec<Vec<[f32; 2]>> {
    (0..n)
        .map(|k| {
            let mut p = to32(&Scenario::generate(cfg, seed * 1000 + k));
            p.truncate(MEAS);
            p
        })
        .collect()
}

fn frame_inputs(name: &str) -> Option<Vec<Vec<[f32; 2]>>> {
    Some(match name {
        "frame_typical" => {
            let scfg = ScenarioConfig {
                shape: Shape::Rbf {
                    variance: 4.0,
                    lengthscale: 35.0,
                },
                clutter_density: 0.05,
                ..ScenarioConfig::default()
            };
            vec![to32(&Scenario::generate(&scfg, 4))]
        }
        "frame_worst" => vec![worst_frame(&mut ChaCha8Rng::seed_from_u64(7))],
        "seq_typical" => sequence(
            &ScenarioConfig {
                clutter_density: 0.02,
                ..ScenarioConfig::default()
            },
            4,
            20,
        ),
        "seq_worst" => sequence(
            &ScenarioConfig {
                lanes: 6,
                spacing: (3.6, 3.6),
                left: -9.0,
                row_step: 77.0 / 40.0,
                clutter_density: 0.04,
                ..ScenarioConfig::default()
            },
            9,
            8,
        ),
        _ => return None,
    })
}

const FRAMES: [&str; 4] = ["frame_typical", "frame_worst", "seq_typical", "seq_worst"];

fn empty_out() -> Obs {
    [LaneObservation::EMPTY; LANES]
}

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
