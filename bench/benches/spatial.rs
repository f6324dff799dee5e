//! Per-row and per-frame cost of the spatial JPDACF at the reference configuration (DESIGN 2:
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

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter, SpatialReport};
use stjpdacf::spatial::row::{self, RowParams};
use stjpdacf::spatial::Stacked;
use stjpdacf::tables::DEFAULT;
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_reference::jpda::{self, MissConvention};
use stjpdacf_reference::spatial::{self as refspatial, Model};
use stjpdacf_tools::repo_root;
use stjpdacf_tools::scenario::{Scenario, ScenarioConfig, Shape};
use stjpdacf_tools::tablegen::{ModelTables, DEFAULT_HYPER};

/// State entries per lane (offset + order-2 RBF state).
const NS: usize = 3;
/// Lane slots D.
const LANES: usize = 6;
/// Rows R_max.
const ROWS: usize = 64;
/// Points per row.
const PER_ROW: usize = 16;
/// Index points N.
const POINTS: usize = 16;
/// Measurement budget M of a frame.
const MEAS: usize = 256;
/// Event budget E.
const EVENTS: usize = 512;
/// Lane spacing of the row benches, m.
const SPACING: f32 = 3.6;

type Filter = SpatialFilter<NS, LANES, ROWS, PER_ROW>;
type State = Stacked<NS, LANES>;

fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = 1.0 - rng.random::<f32>();
    let u2: f32 = rng.random::<f32>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
}

/// `blockdiag(corner, m)`.
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

/// `n` tracks at the lane positions with the broad prior of a fresh frame: offset variance from
/// the tables, GP part `B ⊗ P∞`.
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

/// The broad state tracked over 12 rows with known associations (exact Kalman updates), then
/// predicted to the next row: the state of a typical row in the middle of a frame.
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

fn core_params() -> RowParams {
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

fn clustered(rng: &mut ChaCha8Rng, m: usize, half_width: f32) -> Vec<f32> {
    (0..m)
        .map(|_| (rng.random::<f32>() * 2.0 - 1.0) * half_width)
        .collect()
}

fn rows(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let params = core_params();
    let rparams = ref_params();
    let hv = h();
    let href = DMatrix::from_row_slice(1, NS, &[1.0, 1.0, 0.0]);

    // Typical row: 6 tracked lanes, one point per lane + 2 clutter.
    let typical = tracked_state(LANES, &mut rng);
    let mut pts: Vec<f32> = (0..LANES)
        .map(|t| lane_x(t, LANES) + 0.1 * normal(&mut rng))
        .collect();
    pts.extend((0..2).map(|_| (rng.random::<f32>() * 2.0 - 1.0) * 12.0));
    let mut s = typical;
    let o = row::update(&mut s, &hv, &pts, &params, EVENTS);
    println!(
        "typical row: {} tracks, {} points, {} events, {} patterns, approximated {}, failed {}",
        typical.len(),
        pts.len(),
        o.events,
        o.patterns,
        o.approximated,
        o.failed
    );
    let (tx, tp) = to_f64(&typical);
    let tz: Vec<f64> = pts.iter().map(|v| f64::from(*v)).collect();
    let r = jpda::row_step(&tx, &tp, &href, &tz, &rparams).expect("reference row");
    println!("typical row (reference): {} events", r.events.len());

    let mut g = c.benchmark_group("row_typical_6tracks_8points");
    g.bench_function("core_f32_E=512", |b| {
        b.iter(|| {
            let mut s = typical;
            row::update(&mut s, &hv, black_box(&pts), &params, EVENTS)
        })
    });
    g.bench_function("reference_f64", |b| {
        b.iter(|| jpda::row_step(&tx, &tp, &href, black_box(&tz), &rparams))
    });
    g.finish();

    // Worst-case row: 6 broad tracks, 16 points all valid for all tracks.
    let broad = broad_state(LANES);
    let worst = clustered(&mut rng, PER_ROW, 3.0);
    assert_all_gated(&broad, &worst, params.gamma);
    let mut s = broad;
    let o = row::update(&mut s, &hv, &worst, &params, EVENTS);
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
    g.bench_function("core_f32_E=512", |b| {
        b.iter(|| {
            let mut s = broad;
            row::update(&mut s, &hv, black_box(&worst), &params, EVENTS)
        })
    });
    g.finish();

    // Most work the budget allows: 5 tracked lanes with 2 points in their gates, one with 1 (no
    // point shared): 3⁵ · 2 = 486 ≤ 512 events, all 2⁶ = 64 patterns, nothing pruned.
    let mut heavy: Vec<f32> = (0..LANES - 1)
        .flat_map(|t| [lane_x(t, LANES) - 0.15, lane_x(t, LANES) + 0.15])
        .collect();
    heavy.push(lane_x(LANES - 1, LANES) + 0.05);
    let mut s = typical;
    let o = row::update(&mut s, &hv, &heavy, &params, EVENTS);
    println!(
        "max-work row: {} tracks, {} points, {} events, {} patterns, approximated {}, failed {}",
        typical.len(),
        heavy.len(),
        o.events,
        o.patterns,
        o.approximated,
        o.failed
    );
    assert!(o.events == 486 && o.patterns == 64 && !o.approximated);
    let mut g = c.benchmark_group("row_maxwork_6tracks_11points");
    g.bench_function("core_f32_E=512", |b| {
        b.iter(|| {
            let mut s = typical;
            row::update(&mut s, &hv, black_box(&heavy), &params, EVENTS)
        })
    });
    g.finish();

    // Dense row the reference can enumerate: 4 broad tracks, 8 points all valid for all.
    let dense_state = broad_state(4);
    let dense = clustered(&mut rng, 8, 2.0);
    assert_all_gated(&dense_state, &dense, params.gamma);
    let exact_budget = 4096;
    for e in [EVENTS, exact_budget] {
        let mut s = dense_state;
        let o = row::update(&mut s, &hv, &dense, &params, e);
        println!(
            "dense row, core E={e}: {} events, approximated {}, failed {}",
            o.events, o.approximated, o.failed
        );
    }
    let (dx, dp) = to_f64(&dense_state);
    let dz: Vec<f64> = dense.iter().map(|v| f64::from(*v)).collect();
    let r = jpda::row_step(&dx, &dp, &href, &dz, &rparams).expect("reference row");
    println!("dense row (reference): {} events", r.events.len());
    let mut g = c.benchmark_group("row_dense_4tracks_8points");
    g.bench_function("core_f32_E=512", |b| {
        b.iter(|| {
            let mut s = dense_state;
            row::update(&mut s, &hv, black_box(&dense), &params, EVENTS)
        })
    });
    g.bench_function("core_f32_exact_E=4096", |b| {
        b.iter(|| {
            let mut s = dense_state;
            row::update(&mut s, &hv, black_box(&dense), &params, exact_budget)
        })
    });
    g.bench_function("reference_f64", |b| {
        b.iter(|| jpda::row_step(&dx, &dp, &href, black_box(&dz), &rparams))
    });
    g.finish();
}

fn empty_out() -> [LaneObservation<POINTS>; LANES] {
    [LaneObservation::EMPTY; LANES]
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
        max_misses: usize::from(c.max_misses),
        merge_distance: f64::from(c.merge_distance),
        merge_rows: usize::from(c.merge_rows),
        ..refspatial::Config::from_tables(&t)
    };
    let model = Model::new(&t, usize::from(c.rows_per_interval)).expect("reference model");
    (model, cfg)
}

/// Rows of the worst-case frame that hold only the 6 lane points (they let all 6 tracks start:
/// at most `max_tentative = 2` tentative tracks at once, confirmed after `confirm_hits = 6`).
const LEAD_IN_ROWS: usize = 16;

/// M = 256 points: `LEAD_IN_ROWS` rows with one point per lane (6 straight lanes 3.6 m apart),
/// then `(256 − 6·LEAD_IN_ROWS)/16 = 10` consecutive full rows of 16 points: the 6 lane points
/// plus 10 clutter points each within ±0.4 m of a random lane (inside its gate).
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

fn frames(c: &mut Criterion) {
    let mut f = Box::new(Filter::new());
    let (model, rcfg) = reference_setup();

    let scfg = ScenarioConfig {
        shape: Shape::Rbf {
            variance: 4.0,
            lengthscale: 35.0,
        },
        clutter_density: 0.05,
        ..ScenarioConfig::default()
    };
    let sc = Scenario::generate(&scfg, 4);
    let typical: Vec<[f32; 2]> = sc
        .points
        .iter()
        .map(|&(u, x)| [u as f32, x as f32])
        .collect();
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
