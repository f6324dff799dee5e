//! Per-row and per-frame cost of the spatial JPDACF at the reference configuration (docs/design.md §2:
//! D = 6, N = 16, M = 256 with at most 16 per row, R_max = 64, E = 512), the f32 core next to the
//! f64 reference in the same run. `cargo bench -p stjpdacf-bench --bench spatial`; the figures
//! are in `docs/benchmarks.md`.
//!
//! Inputs (all seeded, `ChaCha8Rng`):
//! * **typical row** — 6 tracks 3.6 m apart (x = −9 … 9 m), each tracked over 12 rows with known
//!   associations and then predicted one row; 8 points: one per lane (truth + 0.1 m noise) and 2
//!   clutter points uniform in ±12 m;
//! * **worst-case row** — the same 6 tracks with their broad prior (offset variance 25 m², GP part
//!   `B ⊗ P∞`: gates of ±16–20 m), 16 points clustered in [−3, 3] m, so every point is inside every
//!   gate (checked at setup): 9,636,817 joint events, `E = 512` bites;
//! * **max-work row** — the typical row's 6 tracked lanes with 2 points inside each of 5 gates
//!   and 1 inside the sixth, no point shared: 3⁵ · 2 = 486 events ≤ E and all 2⁶ = 64 patterns,
//!   the most work one row can do under `E = 512` (the worst-case row above is pruned to fewer
//!   patterns);
//! * **dense row** — the reference is unbounded and cannot enumerate the worst case, so the
//!   reference-vs-core comparison of a dense row uses 4 of those broad tracks and 8 clustered
//!   points (all valid for all: 3,393 events), the core exact (`E = 4096`) and bounded (`E = 512`);
//! * **typical frame** — `scenario`: 3 curved lanes (RBF shape, σ² = 4 m², ℓ = 35 m), clutter
//!   0.05 /m over ±12 m, 61 rows (≈ 240 points);
//! * **worst-case frame** — M = 256 points: 6 straight lanes 3.6 m apart, rows 0–15 with one
//!   point per lane (so that all 6 tracks get started), then rows 16–25 full with 16 points each
//!   (the 6 lane points and 10 clutter points each within ±0.4 m of a random lane, inside that
//!   lane's gate); rows 26–60 are empty (M is spent).

use std::hint::black_box;
use std::time::Duration;

use criterion::measurement::WallTime;
use criterion::{criterion_group, criterion_main, BenchmarkGroup, Criterion};
use nalgebra::{DMatrix, DVector, SVector};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use stjpdacf::spatial::filter::{Config, SpatialReport};
use stjpdacf::spatial::row::{self, RowOutcome, RowParams};
use stjpdacf::tables::DEFAULT;
use stjpdacf_bench::spatial::{
    core_params, empty_out, h, row_inputs, to_f32, typical_scenario, worst_frame, Filter, State,
    EVENTS, LANES, MEAS, NS, PER_ROW,
};
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_reference::jpda::{self, MissConvention};
use stjpdacf_reference::spatial::{self as refspatial, Model};
use stjpdacf_tools::repo_root;
use stjpdacf_tools::tablegen::{ModelTables, DEFAULT_HYPER};

fn ref_params() -> jpda::RowParams {
    let p = core_params();
    jpda::RowParams {
        pd: f64::from(p.pd),
        pg: f64::from(p.pg),
        gamma: f64::from(p.gamma),
        clutter_density: f64::from(p.clutter_density),
        r: f64::from(p.r),
        miss: MissConvention::Pg,
    }
}

/// The stacked state in f64 (target-major), for the reference.
fn to_f64(s: &State) -> (DVector<f64>, DMatrix<f64>) {
    let n = s.len();
    let x = DVector::from_fn(n * NS, |k, _| {
        f64::from(s.mean(k / NS).expect("track")[k % NS])
    });
    let p = DMatrix::from_fn(n * NS, n * NS, |a, b| {
        f64::from(s.cov(a / NS, b / NS).expect("track")[(a % NS, b % NS)])
    });
    (x, p)
}

/// Asserts that every point is inside every track's gate (the setup of a worst-case row).
fn assert_all_gated(s: &State, points: &[f32], gamma: f32) {
    let hv = h();
    for t in 0..s.len() {
        let zh = hv.dot(s.mean(t).expect("track"));
        let st = hv.dot(&(s.cov(t, t).expect("track") * hv)) + DEFAULT.hyper.meas_noise;
        for z in points {
            assert!((z - zh).powi(2) / st <= gamma, "point {z} outside gate {t}");
        }
    }
}

/// The core's row step with the defaults: `h` and the row parameters.
struct CoreRow {
    hv: SVector<f32, NS>,
    params: RowParams,
}

impl CoreRow {
    /// One row step on a copy of `state`.
    fn run(&self, state: &State, pts: &[f32], budget: usize) -> RowOutcome<LANES> {
        let mut s = *state;
        row::update(&mut s, &self.hv, pts, &self.params, budget)
    }

    /// Benches [`CoreRow::run`] as `name` in `g`.
    fn bench(
        &self,
        g: &mut BenchmarkGroup<'_, WallTime>,
        name: &str,
        state: &State,
        pts: &[f32],
        budget: usize,
    ) {
        g.bench_function(name, |b| b.iter(|| self.run(state, black_box(pts), budget)));
    }

    /// Runs the row (E = 512) and prints its counts under `what`.
    fn print(&self, what: &str, state: &State, pts: &[f32]) -> RowOutcome<LANES> {
        let o = self.run(state, pts, EVENTS);
        println!(
            "{what}: {} tracks, {} points, {} events, {} patterns, approximated {}, failed {}",
            state.len(),
            pts.len(),
            o.events,
            o.patterns,
            o.approximated,
            o.failed
        );
        o
    }
}

/// The reference's input of a row (state and points in f64), after one reference row step
/// whose event count it prints under `what`.
fn reference_row(
    what: &str,
    state: &State,
    pts: &[f32],
    href: &DMatrix<f64>,
    rparams: &jpda::RowParams,
) -> (DVector<f64>, DMatrix<f64>, Vec<f64>) {
    let (x, p) = to_f64(state);
    let z: Vec<f64> = pts.iter().map(|v| f64::from(*v)).collect();
    let r = jpda::row_step(&x, &p, href, &z, rparams).expect("reference row");
    println!("{what} (reference): {} events", r.events.len());
    (x, p, z)
}

fn rows(c: &mut Criterion) {
    let [(_, typical), (_, worst), (_, heavy), (_, dense), (_, exact)] = row_inputs();
    let (typical, pts) = (typical.state, typical.points);
    let (broad, worst) = (worst.state, worst.points);
    let heavy = heavy.points;
    let (dense_state, dense) = (dense.state, dense.points);
    let core = CoreRow {
        hv: h(),
        params: core_params(),
    };
    let rparams = ref_params();
    let href = DMatrix::from_row_slice(1, NS, &[1.0, 1.0, 0.0]);

    // Typical row: 6 tracked lanes, one point per lane + 2 clutter.
    core.print("typical row", &typical, &pts);
    let (tx, tp, tz) = reference_row("typical row", &typical, &pts, &href, &rparams);

    let mut g = c.benchmark_group("row_typical_6tracks_8points");
    core.bench(&mut g, "core_f32_E=512", &typical, &pts, EVENTS);
    g.bench_function("reference_f64", |b| {
        b.iter(|| jpda::row_step(&tx, &tp, &href, black_box(&tz), &rparams))
    });
    g.finish();

    // Worst-case row: 6 broad tracks, 16 points all valid for all tracks.
    assert_all_gated(&broad, &worst, core.params.gamma);
    let o = core.run(&broad, &worst, EVENTS);
    println!(
        "worst-case row: {} tracks, {} points (all valid for all), {} events, {} patterns, \
         {} candidates dropped, approximated {}, failed {}",
        broad.len(),
        worst.len(),
        o.events,
        o.patterns,
        o.dropped_candidates,
        o.approximated,
        o.failed
    );
    let mut g = c.benchmark_group("row_worst_6tracks_16points");
    core.bench(&mut g, "core_f32_E=512", &broad, &worst, EVENTS);
    g.finish();

    // Most work the budget allows: 5 tracked lanes with 2 points in their gates, one with 1 (no
    // point shared): 3⁵ · 2 = 486 ≤ 512 events, all 2⁶ = 64 patterns, nothing pruned.
    let o = core.print("max-work row", &typical, &heavy);
    assert!(o.events == 486 && o.patterns == 64 && !o.approximated);
    let mut g = c.benchmark_group("row_maxwork_6tracks_11points");
    core.bench(&mut g, "core_f32_E=512", &typical, &heavy, EVENTS);
    g.finish();

    // Dense row the reference can enumerate: 4 broad tracks, 8 points all valid for all.
    assert_all_gated(&dense_state, &dense, core.params.gamma);
    let exact_budget = exact.budget;
    for e in [EVENTS, exact_budget] {
        let o = core.run(&dense_state, &dense, e);
        println!(
            "dense row, core E={e}: {} events, approximated {}, failed {}",
            o.events, o.approximated, o.failed
        );
    }
    let (dx, dp, dz) = reference_row("dense row", &dense_state, &dense, &href, &rparams);
    let mut g = c.benchmark_group("row_dense_4tracks_8points");
    core.bench(&mut g, "core_f32_E=512", &dense_state, &dense, EVENTS);
    let name = "core_f32_exact_E=4096";
    core.bench(&mut g, name, &dense_state, &dense, exact_budget);
    g.bench_function("reference_f64", |b| {
        b.iter(|| jpda::row_step(&dx, &dp, &href, black_box(&dz), &rparams))
    });
    g.finish();
}

fn run_core(f: &mut Filter, pts: &[[f32; 2]]) -> (usize, SpatialReport) {
    let mut out = empty_out();
    f.run(&DEFAULT, &Config::DEFAULT, pts, &mut out)
}

/// The reference walk with the core's defaults (`Config::DEFAULT`, the tables' offset variance).
fn reference_setup() -> (Model, refspatial::Config) {
    let hf = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).expect("default hyper file");
    let t = ModelTables::from_hyper(&hf).expect("model tables");
    let c = Config::DEFAULT;
    let cfg = refspatial::Config {
        lanes: LANES,
        pd: f64::from(c.pd),
        pg: f64::from(c.pg),
        gamma: f64::from(c.gamma),
        clutter_density: f64::from(c.clutter_density),
        max_events: c.max_events,
        init_rows: usize::from(c.init_rows),
        init_gate: f64::from(c.init_gate),
        max_tentative: usize::from(c.max_tentative),
        confirm_hits: usize::from(c.confirm_hits),
        tentative_misses: usize::from(c.tentative_misses),
        tentative_gap_misses: usize::from(c.tentative_gap_misses),
        row_noise_scale: f64::from(c.row_noise_scale),
        max_misses: usize::from(c.max_misses),
        merge_distance: f64::from(c.merge_distance),
        merge_rows: usize::from(c.merge_rows),
        ..refspatial::Config::from_tables(&t)
    };
    let model = Model::new(&t, usize::from(c.rows_per_interval)).expect("reference model");
    (model, cfg)
}

fn frames(c: &mut Criterion) {
    let mut f = Box::new(Filter::new());
    let (model, rcfg) = reference_setup();

    let sc = typical_scenario();
    let typical = to_f32(&sc);
    assert!(typical.len() <= MEAS);
    let (n, rep) = run_core(&mut f, &typical);
    println!(
        "typical frame: {} points, core {n} lanes, {} events, {} rows approximated, report {rep:?}",
        typical.len(),
        rep.events,
        rep.rows_approximated
    );
    let res = refspatial::run_frame(&model, &rcfg, &sc.points, PER_ROW);
    println!(
        "typical frame (reference): {} lanes, {} events, {} rows over budget, counters {:?}",
        res.tracks.len(),
        res.rows.iter().map(|d| d.events).sum::<usize>(),
        res.counters.over_budget_rows,
        res.counters
    );

    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let worst = worst_frame(&mut rng);
    assert_eq!(worst.len(), MEAS);
    let (n, rep) = run_core(&mut f, &worst);
    assert_eq!(rep.rejected_row_full + rep.rejected_window, 0);
    println!(
        "worst-case frame: {} points, core {n} lanes, {} events scored, {} rows approximated, \
         report {rep:?}",
        worst.len(),
        rep.events,
        rep.rows_approximated
    );

    let mut g = c.benchmark_group("frame_typical_3lanes");
    g.bench_function("core_f32", |b| {
        b.iter(|| run_core(&mut f, black_box(&typical)))
    });
    g.bench_function("reference_f64", |b| {
        b.iter(|| refspatial::run_frame(&model, &rcfg, black_box(&sc.points), PER_ROW))
    });
    g.finish();

    let mut g = c.benchmark_group("frame_worst_256points");
    g.bench_function("core_f32", |b| {
        b.iter(|| run_core(&mut f, black_box(&worst)))
    });
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    targets = rows, frames
}
criterion_main!(benches);
