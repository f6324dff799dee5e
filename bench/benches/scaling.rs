//! Scaling curves: `Tracker::step` time per frame against each capacity, the others at the
//! reference configuration (docs/design.md §2: D = 6, N = 16, M = 256, E = 512, L = 4; spatial order 2,
//! 16 points a row, 64 rows).
//!
//! ```sh
//! cargo bench -p stjpdacf-bench --bench scaling
//! cargo xtask bench-report   # docs/bench/scaling.png and tables
//! ```
//!
//! Const generics fix the points of each curve (`stjpdacf_bench::config`):
//! * **M** (points per frame, `MEAS`) ∈ 64, 128, 256, 512, 768, two curves: the `dense` frames
//!   (770–880 points: 6 lanes on all 61 rows and 0.35 /m clutter) of which the tracker uses the
//!   first M (the nearest rows), so every frame fills the budget; and `adversarial_points(M)`,
//!   the adversarial frames with M points (16 lead-in rows, then rows of 16 points inside the
//!   lanes' gates), the worst case of the budget;
//! * **D** (lane slots, `LANES`; `NX = 2·D·7`, `NA = 7·D`) ∈ 2, 3, 4, 6, 8 on `lanes(D)`: D lanes
//!   3.6 m apart, 41 rows, 0.04 /m clutter, the first 256 points (D = 6 is the `worst`
//!   sequence); tables from `config::hyper_with_lanes` (B's stationary profile);
//! * **N** (index points, `POINTS`; `RANK` = the tables' Gram rank, `NX`, `NA` follow) ∈ 6, 11,
//!   16, 21, 31 with `60 / (N − 1)` rows per interval, so the frame keeps the same 61 rows, on
//!   the `worst` sequence; tables from `config::hyper_with_points`;
//! * **E** (events per row, `Config::max_events`, a run-time setting) ∈ 64 … 2048 on the
//!   `adversarial` frames (rows of 16 points inside the gates of 6 lanes: the rows exceed E).
//!
//! Times are the bench thread's CPU time (`stjpdacf_bench::cputime`: the machine is shared).
//! The inputs' counters (points used, events, rows over E, lanes) go to
//! `target/stjpdacf-bench/scaling.json`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkGroup, BenchmarkId, Criterion};
use stjpdacf::probe::NoProbe;
use stjpdacf::spatial::filter::Config;
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{ReferenceTracker, Tracker, TrackerConfig};
use stjpdacf_bench::config::{
    hyper_with_lanes, hyper_with_points, rows_per_interval, D_AXIS, E_AXIS, M_AXIS, N_AXIS,
};
use stjpdacf_bench::cputime::{self, ThreadCpuTime};
use stjpdacf_bench::harness::{Driver, Step};
use stjpdacf_bench::inputs::{self, Frame};
use stjpdacf_bench::report::{self, Machine, ScalingInput, ScalingOut, Span};
use stjpdacf_tools::tablegen::static_tables;

/// One point of a curve: warm the tracker up on `frames`, record what a pass does, time it.
#[allow(clippy::too_many_arguments)]
fn point<S: Step>(
    g: &mut BenchmarkGroup<'_, ThreadCpuTime>,
    out: &mut Vec<ScalingInput>,
    axis: &str,
    value: usize,
    reference: bool,
    series: &str,
    sequence: &str,
    note: String,
    tracker: Box<S>,
    frames: &[Frame],
) {
    let mut d = Driver::new(tracker);
    d.warm_up(frames, 2);
    let summary = d.summaries(frames);
    println!(
        "{axis} = {value} ({series}): events {:?}, rows over E {:?}, lanes {:?}",
        summary.iter().map(|s| s.events).collect::<Vec<_>>(),
        summary
            .iter()
            .map(|s| s.rows_approximated)
            .collect::<Vec<_>>(),
        summary.iter().map(|s| s.lanes).collect::<Vec<_>>(),
    );
    let function = format!("core_f32_{series}");
    let id = BenchmarkId::new(&function, value);
    out.push(ScalingInput {
        axis: axis.to_string(),
        value,
        series: series.to_string(),
        id: format!("scaling_{axis}/{function}/{value}"),
        reference,
        sequence: sequence.to_string(),
        note,
        frames: summary,
    });
    g.bench_with_input(id, &value, |b, _| {
        b.iter(|| black_box(d.step(frames, &mut NoProbe)))
    });
}

fn reference_note() -> String {
    "D 6, N 16 (rank 7, K 4), M 256, E 512".to_string()
}

/// The M axis: `Tracker<…, MEAS = M, …>` at the reference configuration otherwise.
macro_rules! m_point {
    ($g:expr, $out:expr, $dense:expr, $m:literal) => {{
        type T = Tracker<2, 3, 6, 16, 64, 16, $m, 7, 84, 42, 4>;
        point(
            $g,
            $out,
            "M",
            $m,
            false,
            "dense",
            "dense",
            format!("M {}", $m),
            Box::new(T::new(&DEFAULT)),
            $dense,
        );
        point(
            $g,
            $out,
            "M",
            $m,
            $m == 256,
            "adversarial",
            &format!("adversarial_points({})", $m),
            format!("M {}", $m),
            Box::new(T::new(&DEFAULT)),
            &inputs::adversarial_points($m),
        );
    }};
}

/// The D axis: `LANES = D`, `NX = 14·D`, `NA = 7·D`, tables for D slots.
macro_rules! d_point {
    ($g:expr, $out:expr, $d:literal, $nx:literal, $na:literal) => {{
        const { assert!($nx == 14 * $d && $na == 7 * $d) };
        let tables = if $d == 6 {
            static_tables::<2, $d, 16>(&stjpdacf_bench::config::default_hyper().expect("hyper"))
        } else {
            static_tables::<2, $d, 16>(&hyper_with_lanes($d).expect("hyper"))
        }
        .expect("tables");
        let t: Box<Tracker<2, 3, $d, 16, 64, 16, 256, 7, $nx, $na, 4>> =
            Box::new(Tracker::new(tables));
        let frames = inputs::lanes($d);
        point(
            $g,
            $out,
            "D",
            $d,
            $d == 6,
            "lanes",
            &format!("lanes({})", $d),
            format!("D {}, NX {}, NA {}", $d, $nx, $na),
            t,
            &frames,
        );
    }};
}

/// The N axis: `POINTS = N`, `RANK = r`, `NX = 12·r`, `NA = 6·r`, `60 / (N − 1)` rows per
/// interval.
macro_rules! n_point {
    ($g:expr, $out:expr, $frames:expr, $n:literal, $r:literal, $nx:literal, $na:literal) => {{
        const { assert!($nx == 12 * $r && $na == 6 * $r) };
        assert!(
            N_AXIS.contains(&($n, $r)),
            "N = {} with rank {} is not on config::N_AXIS",
            $n,
            $r
        );
        let tables =
            static_tables::<2, 6, $n>(&hyper_with_points($n).expect("hyper")).expect("tables");
        assert_eq!(tables.gram_rank as usize, $r, "RANK must follow the tables");
        let k = rows_per_interval($n).expect("rows per interval");
        let cfg = TrackerConfig {
            spatial: Config {
                rows_per_interval: k,
                ..Config::DEFAULT
            },
            ..TrackerConfig::DEFAULT
        };
        let t: Box<Tracker<2, 3, 6, $n, 64, 16, 256, $r, $nx, $na, 4>> =
            Box::new(Tracker::with_config(tables, cfg));
        point(
            $g,
            $out,
            "N",
            $n,
            $n == 16,
            "worst",
            "worst",
            format!("N {}, rank {}, K {}", $n, $r, k),
            t,
            $frames,
        );
    }};
}

fn scaling(c: &mut Criterion<ThreadCpuTime>) {
    let machine_start = Machine::now();
    let mut out = Vec::new();

    let dense = inputs::dense();
    let mut g = c.benchmark_group("scaling_M");
    m_point!(&mut g, &mut out, &dense, 64);
    m_point!(&mut g, &mut out, &dense, 128);
    m_point!(&mut g, &mut out, &dense, 256);
    m_point!(&mut g, &mut out, &dense, 512);
    m_point!(&mut g, &mut out, &dense, 768);
    g.finish();
    assert_eq!(M_AXIS.len(), 5);

    let mut g = c.benchmark_group("scaling_D");
    d_point!(&mut g, &mut out, 2, 28, 14);
    d_point!(&mut g, &mut out, 3, 42, 21);
    d_point!(&mut g, &mut out, 4, 56, 28);
    d_point!(&mut g, &mut out, 6, 84, 42);
    d_point!(&mut g, &mut out, 8, 112, 56);
    g.finish();
    assert_eq!(D_AXIS, [2, 3, 4, 6, 8]);

    let worst = inputs::worst();
    let mut g = c.benchmark_group("scaling_N");
    n_point!(&mut g, &mut out, &worst, 6, 6, 72, 36);
    n_point!(&mut g, &mut out, &worst, 11, 7, 84, 42);
    n_point!(&mut g, &mut out, &worst, 16, 7, 84, 42);
    n_point!(&mut g, &mut out, &worst, 21, 7, 84, 42);
    n_point!(&mut g, &mut out, &worst, 31, 6, 72, 36);
    g.finish();

    let adversarial = inputs::adversarial();
    let mut g = c.benchmark_group("scaling_E");
    for e in E_AXIS {
        let cfg = TrackerConfig {
            spatial: Config {
                max_events: e,
                ..Config::DEFAULT
            },
            ..TrackerConfig::DEFAULT
        };
        point(
            &mut g,
            &mut out,
            "E",
            e,
            e == 512,
            "adversarial",
            "adversarial",
            if e == 512 {
                reference_note()
            } else {
                format!("E {e}")
            },
            Box::new(ReferenceTracker::with_config(&DEFAULT, cfg)),
            &adversarial,
        );
    }
    g.finish();

    report::write_side_file(
        "scaling.json",
        &ScalingOut {
            span: Span::since(machine_start),
            points: out,
        },
    )
    .expect("writing scaling.json");
}

criterion_group! {
    name = benches;
    config = cputime::criterion();
    targets = scaling
}
criterion_main!(benches);
