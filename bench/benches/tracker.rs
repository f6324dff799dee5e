//! Per-frame cost of the whole tracker (`Tracker::step`: spatial JPDACF → lane identity →
//! temporal coupled filter + fixed-lag smoother) and of each stage at the reference configuration
//! (`ReferenceTracker`: D = 6, N = 16, M = 256, rank 7, L = 4, E = 512), next to the dense f64
//! reference pipeline (`reference::pipeline`: every index point, full `K_u`, fixed-lag output by
//! RTS) on the same frames in the same run.
//!
//! ```sh
//! cargo bench -p stjpdacf-bench --bench tracker
//! cargo xtask bench-report   # tables and plot in docs/bench/
//! ```
//!
//! Every bench measures the bench thread's **CPU time** (`stjpdacf_bench::cputime`), not wall
//! time: the machine's 2 cores are shared with other builds, and wall time would count the time
//! the thread waits for a core.
//!
//! Inputs: `stjpdacf_bench::inputs` (`typical`, `worst`, `adversarial`); a bench iteration is
//! one frame, the sequence is cycled with frames 50 ms apart, after warm-up passes. Groups:
//! * `tracker_step_typical` — core (also with the counting and the timing probe: the probe's
//!   overhead) and reference, step + fixed-lag output; every sequence also runs the core on the
//!   uncoupled tables (`core_f32_uncoupled`), the default tables in `Rank5Tracker`
//!   (`core_f32_rank5`) and the smallest model (`core_f32_smallest_rank4`:
//!   uncoupled tables, LBP on every known-lane row, `Rank4Tracker`; `core_f32_smallest_rank3`:
//!   the same in `Rank3Tracker`);
//! * `tracker_step_worst_6lanes_256points` — core and reference;
//! * `tracker_step_adversarial_256points` — core only (its rows exceed E: the reference would
//!   enumerate every event of them);
//! * `stage_<stage>_<sequence>` for spatial, identity, temporal, smoother — `core_f32_in_step`:
//!   the stage's time inside the core's full step, from the timing probe (spatial: the
//!   known-lane rows, `Stage::Known`, and the JPDACF walk on the points they leave)
//!   (`Bencher::iter_custom` returns the time charged to the stage, over frames the thread ran
//!   throughout); `reference_f64`: the
//!   reference's piece of that stage alone on the same frames (spatial `run_frame`; identity
//!   `assign` against the dense predictions; dense predict + update; the fixed-lag RTS output);
//!   for the spatial stage also `core_f32`, the core's `SpatialFilter::run` alone;
//! * `stage_temporal_3lanes` — kept from the first tracker benches: core `Temporal::predict` +
//!   3 updates (smoother window included) vs dense predict + update, 3 lanes, typical frames.
//!
//! What the inputs did (lanes, events, rows over E, whether the reference's fixed-lag output was
//! computed) is written to `target/stjpdacf-bench/tracker.json`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::DVector;
use stjpdacf::persist::PersistConfig;
use stjpdacf::probe::NoProbe;
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter};
use stjpdacf::spatial::row::Association;
use stjpdacf::tables::{DEFAULT, UNCOUPLED};
use stjpdacf::temporal::smoother::Temporal;
use stjpdacf::tracker::{
    Rank3Tracker, Rank4Tracker, Rank5Tracker, ReferenceTracker, TrackerConfig,
};
use stjpdacf_bench::cputime::{self, ThreadCpuTime};
use stjpdacf_bench::harness::Driver;
use stjpdacf_bench::inputs::{self, Frame, STEP_US};
use stjpdacf_bench::probes::{CallCounter, StageGroup, StageTimer};
use stjpdacf_bench::report::{self, Machine, SequenceMeta, Span, TrackerMeta};
use stjpdacf_reference::identity::{self, Curve, Gate};
use stjpdacf_reference::pipeline::{PipelineConfig, ReferencePipeline};
use stjpdacf_reference::spatial::{self as refspatial, FrameResult, Model};
use stjpdacf_reference::temporal::{CoupledTemporalModel, Gaussian, LaneMeasurement};
use stjpdacf_tools::repo_root;
use stjpdacf_tools::tablegen::{ModelTables, DEFAULT_HYPER};

/// Spatial model: rows between index points.
const K: usize = 4;
/// Points per row.
const PER_ROW: usize = 16;
/// Warm-up passes over a sequence before measuring.
const WARM: usize = 2;

fn tables() -> ModelTables {
    let h = stjpdacf_reference::hyper::HyperFile::load(&repo_root().join(DEFAULT_HYPER))
        .expect("hyper file");
    ModelTables::from_hyper(&h).expect("tables")
}

const EMPTY_OBS: LaneObservation<16> = LaneObservation::EMPTY;

fn core_driver(frames: &[Frame]) -> Driver<ReferenceTracker> {
    let mut d = Driver::new(Box::new(ReferenceTracker::new(&DEFAULT)));
    d.warm_up(frames, WARM);
    d
}

/// The reference pipeline and its clock, cycling through a sequence.
struct RefDriver {
    p: ReferencePipeline,
    now: i64,
    next: usize,
}

impl RefDriver {
    fn new(t: &ModelTables, frames: &[Frame]) -> Self {
        let mut d = Self {
            p: ReferencePipeline::new(t, K, PipelineConfig::from_tables(t)).expect("reference"),
            now: 0,
            next: 0,
        };
        for _ in 0..WARM * frames.len() {
            d.step(frames);
        }
        d
    }

    /// One frame and the fixed-lag output; whether the output was computed (the window was
    /// comparable), the lanes and the events.
    fn step(&mut self, frames: &[Frame]) -> (bool, usize, usize) {
        self.now += STEP_US;
        let f = &frames[self.next % frames.len()];
        self.next = (self.next + 1) % frames.len();
        let out = self
            .p
            .step(self.now as f64 * 1e-6, &f.p64)
            .expect("reference step");
        let lagged = self.p.lagged().expect("reference smoother");
        let events = out.spatial.rows.iter().map(|r| r.events).sum();
        (lagged.is_some(), out.filtered.len(), events)
    }
}

/// Inputs of the reference's stage pieces over one pass of a sequence: the spatial frames, and
/// a dense coupled filter over the first `lanes` tracks of each frame (lanes in rank order, as
/// the existing temporal stage bench does), with its prior before each frame.
struct RefStages {
    lanes: usize,
    curves: Vec<Vec<Curve>>,
    preds: Vec<Vec<Option<Curve>>>,
    meas: Vec<Vec<Option<LaneMeasurement>>>,
    before: Vec<Gaussian>,
}

fn ref_frames(model: &Model, rcfg: &refspatial::Config, frames: &[Frame]) -> Vec<FrameResult> {
    frames
        .iter()
        .map(|f| {
            let used = &f.p64[..f.p64.len().min(256)];
            refspatial::run_frame(model, rcfg, used, PER_ROW)
        })
        .collect()
}

impl RefStages {
    fn build(dense: &CoupledTemporalModel, fr: &[FrameResult], lanes: usize) -> Self {
        let n = dense.points();
        let curves = fr
            .iter()
            .map(|f| {
                f.tracks
                    .iter()
                    .take(6)
                    .map(|t| Curve {
                        present: t.pseudo.iter().map(Option::is_some).collect(),
                        z: t.pseudo.iter().map(|p| p.unwrap_or(0.0)).collect(),
                        var: (0..n).map(|i| t.pseudo_cov[(i, i)]).collect(),
                    })
                    .collect()
            })
            .collect();
        let meas: Vec<Vec<Option<LaneMeasurement>>> = fr
            .iter()
            .map(|f| {
                (0..lanes)
                    .map(|d| {
                        f.tracks.get(d).map(|tr| LaneMeasurement {
                            z: tr.pseudo.clone(),
                            cov: tr.pseudo_cov.clone(),
                        })
                    })
                    .collect()
            })
            .collect();
        let mut state = dense
            .prior(lanes, DVector::zeros(dense.state_dim(lanes)))
            .expect("prior");
        let mut before = Vec::new();
        let mut preds = Vec::new();
        // Two passes: the second pass's moments are the bench inputs.
        for pass in 0..2 {
            for m in &meas {
                let step = dense.step(&state, Some(0.05), m).expect("dense step");
                if pass == 1 {
                    before.push(state.clone());
                    let p = &step.predicted;
                    preds.push(
                        (0..6)
                            .map(|d| {
                                (d < lanes).then(|| Curve {
                                    present: vec![true; n],
                                    z: (0..n).map(|i| p.mean[(d * n + i) * 2]).collect(),
                                    var: (0..n)
                                        .map(|i| p.cov[((d * n + i) * 2, (d * n + i) * 2)])
                                        .collect(),
                                })
                            })
                            .collect(),
                    );
                }
                state = Gaussian::new(step.filtered.mean, step.filtered.cov).expect("moments");
            }
        }
        Self {
            lanes,
            curves,
            preds,
            meas,
            before,
        }
    }
}

/// The stage's time inside full steps: the timing probe's wall-clock time of the stage, over
/// frames that ran without the thread being descheduled (`Driver::step_clean`), so that it is
/// comparable with the thread CPU time the other benches measure.
fn in_step(
    g: &mut criterion::BenchmarkGroup<'_, ThreadCpuTime>,
    driver: &mut Driver<ReferenceTracker>,
    frames: &[Frame],
    groups: &[StageGroup],
) {
    g.bench_function("core_f32_in_step", |b| {
        b.iter_custom(|iters| {
            let mut acc = Duration::ZERO;
            for _ in 0..iters {
                let p = driver.step_clean(frames, StageTimer::new);
                acc += groups.iter().map(|gr| gr.of(&p)).sum::<Duration>();
            }
            acc
        })
    });
}

/// Benches `f(k)` as `name`, `k` cycling through `1, 2, …, n − 1, 0, 1, …` (one step per
/// iteration).
fn bench_cycling<R>(
    g: &mut criterion::BenchmarkGroup<'_, ThreadCpuTime>,
    name: &str,
    n: usize,
    mut f: impl FnMut(usize) -> R,
) {
    let mut k = 0usize;
    g.bench_function(name, |b| {
        b.iter(|| {
            k = (k + 1) % n;
            black_box(f(k))
        })
    });
}

#[allow(clippy::too_many_lines)]
fn tracker(c: &mut Criterion<ThreadCpuTime>) {
    let machine_start = Machine::now();
    let mut sequences = Vec::new();
    let t = tables();
    let model = Model::new(&t, K).expect("model");
    let rcfg = refspatial::Config::from_tables(&t);
    let dense = CoupledTemporalModel::from_tables(&t).expect("dense model");
    let gate = Gate {
        gate: 9.0,
        min_common: 3,
    };

    for seq in inputs::sequences() {
        let frames = &seq.frames;
        let name = seq.name;
        let with_reference = name != "adversarial";
        let group_name = match name {
            "typical" => "tracker_step_typical".to_string(),
            "worst" => "tracker_step_worst_6lanes_256points".to_string(),
            other => format!("tracker_step_{other}_256points"),
        };
        let mut core = core_driver(frames);
        let core_summary = core.summaries(frames);
        let counts: Vec<usize> = frames.iter().map(|f| f.p32.len()).collect();
        let mut m = SequenceMeta {
            name: name.to_string(),
            what: seq.what.to_string(),
            frames: frames.len(),
            points_min: counts.iter().copied().min().unwrap_or(0),
            points_max: counts.iter().copied().max().unwrap_or(0),
            core: core_summary.clone(),
            reference_run: with_reference,
            reference_lanes: Vec::new(),
            reference_events: Vec::new(),
            reference_fixed_lag_computed: Vec::new(),
            reference_dense_lanes: 0,
        };
        println!(
            "{name}: {} frames, {}–{} points; core lanes {:?}, events {:?}, rows over E {:?}",
            frames.len(),
            m.points_min,
            m.points_max,
            core_summary.iter().map(|s| s.lanes).collect::<Vec<_>>(),
            core_summary.iter().map(|s| s.events).collect::<Vec<_>>(),
            core_summary
                .iter()
                .map(|s| s.rows_approximated)
                .collect::<Vec<_>>(),
        );

        // Full step.
        let mut g = c.benchmark_group(&group_name);
        g.bench_function("core_f32", |b| {
            b.iter(|| black_box(core.step(frames, &mut NoProbe)))
        });
        // The uncoupled model (B diagonal: the temporal stage on each lane's own block, design
        // §4.2.6) on the same frames.
        let mut uncoupled = Driver::new(Box::new(ReferenceTracker::new(&UNCOUPLED)));
        uncoupled.warm_up(frames, WARM);
        g.bench_function("core_f32_uncoupled", |b| {
            b.iter(|| black_box(uncoupled.step(frames, &mut NoProbe)))
        });
        // The default (coupled) tables in a tracker compiled for Gram rank 5 (`Rank5Tracker`):
        // the default's accuracy within 0.008 on the replay (docs/measurements.md "Fitting the
        // MCU").
        let mut rank5 = Driver::new(Box::new(Rank5Tracker::new(&DEFAULT)));
        rank5.warm_up(frames, WARM);
        g.bench_function("core_f32_rank5", |b| {
            b.iter(|| black_box(rank5.step(frames, &mut NoProbe)))
        });
        // The smallest model measured on the MCU (docs/measurements.md "Fitting the MCU"): the
        // uncoupled tables, LBP on every known-lane row, in a tracker compiled for Gram rank 4
        // (`Rank4Tracker`; the same bits as rank-4 tables in the reference tracker).
        let mut smallest = Driver::new(Box::new(Rank4Tracker::with_config(
            &UNCOUPLED,
            TrackerConfig {
                persist: PersistConfig {
                    association: Association::Lbp,
                    ..PersistConfig::DEFAULT
                },
                ..TrackerConfig::DEFAULT
            },
        )));
        smallest.warm_up(frames, WARM);
        g.bench_function("core_f32_smallest_rank4", |b| {
            b.iter(|| black_box(smallest.step(frames, &mut NoProbe)))
        });
        // The same at Gram rank 3 (`Rank3Tracker`): the model that meets the MCU's typical
        // 1 M-instruction frame.
        let mut rank3 = Driver::new(Box::new(Rank3Tracker::with_config(
            &UNCOUPLED,
            TrackerConfig {
                persist: PersistConfig {
                    association: Association::Lbp,
                    ..PersistConfig::DEFAULT
                },
                ..TrackerConfig::DEFAULT
            },
        )));
        rank3.warm_up(frames, WARM);
        g.bench_function("core_f32_smallest_rank3", |b| {
            b.iter(|| black_box(rank3.step(frames, &mut NoProbe)))
        });
        if name == "typical" {
            g.bench_function("core_f32_count_probe", |b| {
                b.iter(|| {
                    let mut p = CallCounter::default();
                    black_box(core.step(frames, &mut p));
                    black_box(p.total())
                })
            });
            g.bench_function("core_f32_timing_probe", |b| {
                b.iter(|| {
                    let mut p = StageTimer::new();
                    black_box(core.step(frames, &mut p));
                    black_box(p.calls())
                })
            });
        }
        let mut rdrv = with_reference.then(|| RefDriver::new(&t, frames));
        if let Some(r) = rdrv.as_mut() {
            for _ in 0..frames.len() {
                let (lagged, lanes, events) = r.step(frames);
                m.reference_fixed_lag_computed.push(lagged);
                m.reference_lanes.push(lanes);
                m.reference_events.push(events);
            }
            println!(
                "{name} (reference): lanes {:?}, events {:?}, fixed-lag output computed {:?}",
                m.reference_lanes, m.reference_events, m.reference_fixed_lag_computed
            );
            g.bench_function("reference_f64", |b| b.iter(|| black_box(r.step(frames))));
        }
        g.finish();

        // Stages.
        let fr = with_reference.then(|| ref_frames(&model, &rcfg, frames));
        let lanes = m.reference_lanes.iter().copied().max().unwrap_or(0);
        let rs = fr
            .as_ref()
            .map(|fr| RefStages::build(&dense, fr, lanes.max(1)));
        m.reference_dense_lanes = rs.as_ref().map_or(0, |r| r.lanes);

        let mut g = c.benchmark_group(format!("stage_spatial_{name}"));
        let mut sf = Box::new(SpatialFilter::<3, 6, 64, 16>::new());
        let scfg = Config::default();
        bench_cycling(&mut g, "core_f32", frames.len(), |s1| {
            let mut obs = [EMPTY_OBS; 6];
            let p = &frames[s1].p32;
            let r = sf.run(&DEFAULT, &scfg, black_box(&p[..p.len().min(256)]), &mut obs);
            (r, obs)
        });
        // The core's spatial association of a frame is the known-lane rows (`Stage::Known`,
        // which explain most points at steady state) and the JPDACF walk on the rest: both,
        // as the reference's `run_frame` and the core's `SpatialFilter::run` alone do it all.
        in_step(
            &mut g,
            &mut core,
            frames,
            &[StageGroup::Spatial, StageGroup::Known],
        );
        if with_reference {
            bench_cycling(&mut g, "reference_f64", frames.len(), |s2| {
                let p = &frames[s2].p64;
                refspatial::run_frame(&model, &rcfg, black_box(&p[..p.len().min(256)]), PER_ROW)
            });
        }
        g.finish();

        let mut g = c.benchmark_group(format!("stage_identity_{name}"));
        in_step(&mut g, &mut core, frames, &[StageGroup::Identity]);
        if let Some(rs) = rs.as_ref() {
            bench_cycling(&mut g, "reference_f64", rs.curves.len(), |k| {
                identity::assign(black_box(&rs.curves[k]), &rs.preds[k], gate)
            });
        }
        g.finish();

        let mut g = c.benchmark_group(format!("stage_temporal_{name}"));
        in_step(&mut g, &mut core, frames, &[StageGroup::Temporal]);
        if let Some(rs) = rs.as_ref() {
            bench_cycling(&mut g, "reference_f64_predict_update", rs.meas.len(), |k| {
                dense
                    .step(&rs.before[k], Some(0.05), black_box(&rs.meas[k]))
                    .expect("dense step")
            });
        }
        g.finish();

        let mut g = c.benchmark_group(format!("stage_smoother_{name}"));
        in_step(&mut g, &mut core, frames, &[StageGroup::Smoother]);
        if let Some(r) = rdrv.as_mut() {
            // The newest window whose fixed-lag output is computable.
            let mut tries = 0;
            while r.p.window_comparable() != Some(true) && tries < 4 * frames.len() {
                r.step(frames);
                tries += 1;
            }
            if r.p.window_comparable() == Some(true) {
                let p = &r.p;
                g.bench_function("reference_f64_fixed_lag_rts", |b| {
                    b.iter(|| black_box(p.lagged().expect("reference smoother")))
                });
            } else {
                println!("{name}: the reference's fixed-lag output is never computable");
            }
        }
        g.finish();

        if name == "typical" {
            temporal_3lanes(c, &t, frames);
        }
        sequences.push(m);
    }
    let meta = TrackerMeta {
        span: Span::since(machine_start),
        sequences,
    };
    report::write_side_file("tracker.json", &meta).expect("writing tracker.json");
}

/// The temporal stage alone with 3 lanes on the typical frames (kept from the first benches).
fn temporal_3lanes(c: &mut Criterion<ThreadCpuTime>, t: &ModelTables, frames: &[Frame]) {
    let model = Model::new(t, K).expect("model");
    let rcfg = refspatial::Config::from_tables(t);
    let mut sf = Box::new(SpatialFilter::<3, 6, 64, 16>::new());
    let scfg = Config::default();
    let mut core_obs: Vec<Vec<LaneObservation<16>>> = Vec::new();
    let mut ref_obs: Vec<Vec<Option<LaneMeasurement>>> = Vec::new();
    for f in frames {
        let mut obs = [EMPTY_OBS; 6];
        let (n, _) = sf.run(&DEFAULT, &scfg, &f.p32, &mut obs);
        core_obs.push(obs[..n.min(3)].to_vec());
        let fr = refspatial::run_frame(&model, &rcfg, &f.p64, PER_ROW);
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
            t1 = (t1 + 1) % frames.len();
            let _ = temporal.predict(&DEFAULT, 0.05);
            for (s, o) in core_obs[t1].iter().enumerate() {
                let _ = temporal.update(&DEFAULT, s, black_box(o));
            }
            black_box(temporal.filter().mean()[0])
        })
    });
    let dense = CoupledTemporalModel::from_tables(t).expect("dense model");
    let mut state = dense
        .prior(3, DVector::zeros(dense.state_dim(3)))
        .expect("prior");
    let mut t2 = 0usize;
    g.bench_function("reference_f64_predict_update", |b| {
        b.iter(|| {
            t2 = (t2 + 1) % frames.len();
            let step = dense
                .step(&state, Some(0.05), black_box(&ref_obs[t2]))
                .expect("dense step");
            state = Gaussian::new(step.filtered.mean, step.filtered.cov).expect("moments");
        })
    });
    g.finish();
}

criterion_group! {
    name = benches;
    config = cputime::criterion();
    targets = tracker
}
criterion_main!(benches);
