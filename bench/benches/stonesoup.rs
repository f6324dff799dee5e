//! The 200 Stone Soup JPDA scans (`bench/data/stonesoup/stonesoup_bench.json`: 4 lane-like
//! targets, 10–30 points per scan, 2–144 joint events) replayed through the core's row JPDA
//! ([`stjpdacf_bench::stonesoup::Core`]: predict, `spatial::row::associate`, PDA update).
//! `cargo bench -p stjpdacf-bench --bench stonesoup`; criterion's time is per replay of 200 scans,
//! measured twice: wall clock (`stonesoup_200_scans_wall`, with a scans/s throughput line) and the
//! bench thread's CPU time (`stonesoup_200_scans_cpu`, [`stjpdacf_bench::cputime`]: on the shared
//! 2-core machine the wall clock also counts the time spent waiting for a core). Stone Soup itself is timed on the same scans by
//! `cargo run --release -p stjpdacf-bench --example stonesoup_report`; the figures are in
//! `docs/benchmarks.md` ("Stone Soup JPDA, same scans").

use std::hint::black_box;
use std::time::Duration;

use criterion::measurement::Measurement;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use stjpdacf_bench::cputime::ThreadCpuTime;
use stjpdacf_bench::stonesoup::{replay, Core, Scans};

fn wall(c: &mut Criterion) {
    bench(c, "stonesoup_200_scans_wall", true);
}

fn cpu(c: &mut Criterion<ThreadCpuTime>) {
    bench(c, "stonesoup_200_scans_cpu", false);
}

/// One iteration: a fresh copy of the initial tracks, then the 200 scans in order. `scans_per_s`:
/// a throughput line (the CPU-time formatter has none).
fn bench<M: Measurement>(c: &mut Criterion<M>, group: &str, scans_per_s: bool) {
    let scans = Scans::load().expect("bench/data/stonesoup/stonesoup_bench.json");
    let rep = replay(&scans);
    assert!(rep.approximated == 0 && rep.failed == 0, "every scan exact");
    let start = Core::new(&scans);
    let mut g = c.benchmark_group(group);
    if scans_per_s {
        g.throughput(Throughput::Elements(scans.points.len() as u64));
    }
    g.bench_function("core_f32_replay", |b| {
        b.iter(|| {
            let mut core = start.clone();
            let mut events = 0u32;
            for pts in &scans.points {
                events += core.step(black_box(pts)).events;
            }
            black_box((core.x, events))
        })
    });
    g.finish();
}

criterion_group! {
    name = wall_clock;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = wall
}
criterion_group! {
    name = cpu_time;
    config = Criterion::default()
        .with_measurement(ThreadCpuTime)
        .sample_size(30)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = cpu
}
criterion_main!(wall_clock, cpu_time);
