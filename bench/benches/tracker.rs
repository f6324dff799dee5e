//! Per-frame cost of the whole tracker (`Tracker::step`: spatial JPDACF → lane identity →
//! temporal coupled filter + fixed-lag smoother) at the reference configuration
//! (`ReferenceTracker`: D = 6, N = 16, M = 256, rank 7, L = 4), next to the dense f64 reference
//! pipeline (`reference::pipeline`: every index point, full `K_u`, fixed-lag output by RTS) on the
//! same frames in the same run. `cargo bench -p stjpdacf-bench --bench tracker`; the figures are
//! in `docs/benchmarks.md`.
//!
//! Inputs (seeded `scenario` frames, 50 ms apart, time always increasing; a bench iteration is
//! one frame, the sequence is cycled):
//! * **typical sequence** — 20 frames of 3 straight lanes (x = −5.4, −1.8, 1.8 m), clutter
//!   0.02 /m over ±12 m, `P_D = 0.9`, σ = 0.1 m, 61 rows: 160–210 points per frame;
//! * **worst-case sequence** — 8 frames of 6 straight lanes 3.6 m apart (x = −9 … 9 m), rows every
//!   77/40 m, clutter 0.04 /m: ≥ 256 points, cut to the first M = 256 by the tracker;
//! * per stage on the typical frames: the spatial filter alone (core `SpatialFilter::run` vs
//!   `reference::spatial::run_frame`), the temporal filter alone (3 lanes: core
//!   `Temporal::predict` + 3 × `Temporal::update`, smoother window included, vs the dense
//!   `CoupledTemporalModel::step`), and the reference's fixed-lag RTS output alone.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::DVector;
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter, Status};
use stjpdacf::tables::DEFAULT;
use stjpdacf::temporal::smoother::Temporal;
use stjpdacf::tracker::{Instant, ReferenceTracker};
use stjpdacf_host::hyper::HyperFile;
use stjpdacf_host::reference::pipeline::{PipelineConfig, ReferencePipeline};
use stjpdacf_host::reference::spatial::{self as refspatial, Model};
use stjpdacf_host::reference::temporal::{CoupledTemporalModel, Gaussian, LaneMeasurement};
use stjpdacf_host::repo_root;
use stjpdacf_host::scenario::{Scenario, ScenarioConfig};
use stjpdacf_host::tablegen::{ModelTables, DEFAULT_HYPER};

/// Spatial model: rows between index points.
const K: usize = 4;
/// Points per row.
const PER_ROW: usize = 16;
/// Nominal frame step, µs.
const STEP_US: i64 = 50_000;

type Points32 = Vec<[f32; 2]>;
type Points64 = Vec<(f64, f64)>;

fn frames(cfg: &ScenarioConfig, seed: u64, n: u64) -> Vec<(Points32, Points64)> {
    (0..n)
        .map(|k| {
            let sc = Scenario::generate(cfg, seed * 1000 + k);
            let p32: Points32 = sc
                .points
                .iter()
                .map(|&(u, x)| [u as f32, x as f32])
                .collect();
            let p64 = p32
                .iter()
                .map(|p| (f64::from(p[0]), f64::from(p[1])))
                .collect();
            (p32, p64)
        })
        .collect()
}

fn typical() -> Vec<(Points32, Points64)> {
    let cfg = ScenarioConfig {
        clutter_density: 0.02,
        ..ScenarioConfig::default()
    };
    frames(&cfg, 4, 20)
}

fn worst() -> Vec<(Points32, Points64)> {
    let cfg = ScenarioConfig {
        lanes: 6,
        spacing: (3.6, 3.6),
        left: -9.0,
        row_step: 77.0 / 40.0,
        clutter_density: 0.04,
        ..ScenarioConfig::default()
    };
    frames(&cfg, 9, 8)
}

fn tables() -> ModelTables {
    let h = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).expect("hyper file");
    ModelTables::from_hyper(&h).expect("tables")
}

const EMPTY_OBS: LaneObservation<16> = LaneObservation {
    status: Status::Tentative,
    present: [false; 16],
    z: nalgebra::SVector::from_array_storage(nalgebra::ArrayStorage([[0.0; 16]; 1])),
    cov: nalgebra::SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; 16]; 16])),
    u_first: 0.0,
    u_last: 0.0,
    existence: 0.0,
    rank: 0,
};

#[allow(clippy::too_many_lines)]
fn tracker(c: &mut Criterion) {
    let t = tables();
    let typ = typical();
    let wst = worst();
    let counts: Vec<usize> = typ.iter().map(|f| f.0.len()).collect();
    println!(
        "typical: {} frames, {}–{} points; worst: {} frames, {}–{} points (first 256 used)",
        typ.len(),
        counts.iter().min().unwrap_or(&0),
        counts.iter().max().unwrap_or(&0),
        wst.len(),
        wst.iter().map(|f| f.0.len()).min().unwrap_or(0),
        wst.iter().map(|f| f.0.len()).max().unwrap_or(0),
    );

    // Core tracker, typical: one warm-up pass so the lanes exist, then cycle.
    let mut core = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut now = 0i64;
    for (p, _) in &typ {
        now += STEP_US;
        let out = core.step(Instant::from_micros(now), p).expect("step");
        black_box(&out);
    }
    let out = core
        .step(Instant::from_micros(now + STEP_US), &typ[0].0)
        .expect("step");
    now += STEP_US;
    println!(
        "typical (core): {} filtered / {} smoothed lanes",
        out.filtered.len(),
        out.smoothed.len()
    );
    let mut g = c.benchmark_group("tracker_step_typical");
    let mut i = 0usize;
    g.bench_function("core_f32", |b| {
        b.iter(|| {
            now += STEP_US;
            i = (i + 1) % typ.len();
            black_box(core.step(Instant::from_micros(now), black_box(&typ[i].0)))
        })
    });
    let mut reference =
        ReferencePipeline::new(&t, K, PipelineConfig::from_tables(&t)).expect("reference");
    let mut rnow = 0i64;
    for (_, p) in &typ {
        rnow += STEP_US;
        reference
            .step(rnow as f64 * 1e-6, p)
            .expect("reference step");
    }
    println!(
        "typical (reference): {} filtered lanes, fixed-lag output comparable: {:?}",
        reference
            .step((rnow + STEP_US) as f64 * 1e-6, &typ[0].1)
            .expect("reference step")
            .filtered
            .len(),
        reference.window_comparable()
    );
    rnow += STEP_US;
    let mut j = 0usize;
    g.bench_function("reference_f64", |b| {
        b.iter(|| {
            rnow += STEP_US;
            j = (j + 1) % typ.len();
            let out = reference
                .step(rnow as f64 * 1e-6, black_box(&typ[j].1))
                .expect("reference step");
            let lagged = reference.lagged().expect("reference smoother");
            black_box((out, lagged))
        })
    });
    g.finish();

    // Core tracker, worst case.
    let mut core6 = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut now6 = 0i64;
    for (p, _) in &wst {
        now6 += STEP_US;
        black_box(core6.step(Instant::from_micros(now6), p).expect("step"));
    }
    now6 += STEP_US;
    let out = core6
        .step(Instant::from_micros(now6), &wst[0].0)
        .expect("step");
    println!(
        "worst (core): {} filtered lanes, {} points over budget, spatial {:?}",
        out.filtered.len(),
        out.report.over_budget_points,
        out.report.spatial
    );
    let mut g = c.benchmark_group("tracker_step_worst_6lanes_256points");
    let mut k6 = 0usize;
    g.bench_function("core_f32", |b| {
        b.iter(|| {
            now6 += STEP_US;
            k6 = (k6 + 1) % wst.len();
            black_box(core6.step(Instant::from_micros(now6), black_box(&wst[k6].0)))
        })
    });
    g.finish();

    // Stage: spatial filter alone.
    let model = Model::new(&t, K).expect("model");
    let rcfg = refspatial::Config::from_tables(&t);
    let mut sf = Box::new(SpatialFilter::<3, 6, 64, 16>::new());
    let scfg = Config::default();
    let mut g = c.benchmark_group("stage_spatial_typical");
    let mut s1 = 0usize;
    g.bench_function("core_f32", |b| {
        b.iter(|| {
            s1 = (s1 + 1) % typ.len();
            let mut obs = [EMPTY_OBS; 6];
            let r = sf.run(&DEFAULT, &scfg, black_box(&typ[s1].0), &mut obs);
            black_box((r, obs))
        })
    });
    let mut s2 = 0usize;
    g.bench_function("reference_f64", |b| {
        b.iter(|| {
            s2 = (s2 + 1) % typ.len();
            black_box(refspatial::run_frame(
                &model,
                &rcfg,
                black_box(&typ[s2].1),
                PER_ROW,
            ))
        })
    });
    g.finish();

    // Stage: temporal filter alone, 3 lanes, the typical frames' observations.
    let mut core_obs: Vec<Vec<LaneObservation<16>>> = Vec::new();
    let mut ref_obs: Vec<Vec<Option<LaneMeasurement>>> = Vec::new();
    for (p32, p64) in &typ {
        let mut obs = [EMPTY_OBS; 6];
        let (n, _) = sf.run(&DEFAULT, &scfg, p32, &mut obs);
        core_obs.push(obs[..n.min(3)].to_vec());
        let fr = refspatial::run_frame(&model, &rcfg, p64, PER_ROW);
        ref_obs.push(
            (0..3)
                .map(|d| {
                    fr.tracks.get(d).map(|tr| LaneMeasurement {
                        z: tr.pseudo.clone(),
                        cov: tr.pseudo_cov.clone(),
                    })
                })
                .collect(),
        );
    }
    let mut temporal = Box::new(Temporal::<6, 16, 7, 84, 42, 4>::new());
    let mut ranks = [0u8; 6];
    for s in 0..3u8 {
        ranks[usize::from(s)] = s;
        temporal
            .start_lane(&DEFAULT, usize::from(s), s, &ranks)
            .expect("start");
    }
    let mut g = c.benchmark_group("stage_temporal_3lanes");
    let mut t1 = 0usize;
    g.bench_function("core_f32_predict_update_window", |b| {
        b.iter(|| {
            t1 = (t1 + 1) % typ.len();
            let _ = temporal.predict(&DEFAULT, 0.05);
            for (s, o) in core_obs[t1].iter().enumerate() {
                let _ = temporal.update(&DEFAULT, s, black_box(o));
            }
            black_box(temporal.filter().mean()[0])
        })
    });
    let dense = CoupledTemporalModel::from_tables(&t).expect("dense model");
    let mut state = dense
        .prior(3, DVector::zeros(dense.state_dim(3)))
        .expect("prior");
    let mut t2 = 0usize;
    g.bench_function("reference_f64_predict_update", |b| {
        b.iter(|| {
            t2 = (t2 + 1) % typ.len();
            let step = dense
                .step(&state, Some(0.05), black_box(&ref_obs[t2]))
                .expect("dense step");
            state = Gaussian::new(step.filtered.mean, step.filtered.cov).expect("moments");
        })
    });
    g.bench_function("reference_f64_fixed_lag_rts", |b| {
        b.iter(|| black_box(reference.lagged().expect("reference smoother")))
    });
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    targets = tracker
}
criterion_main!(benches);
