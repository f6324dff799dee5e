//! Runs the reference tracker over the seeded typical or worst-case frame sequence of the tracker
//! bench (`bench/benches/tracker.rs`), for instruction counting on the host:
//!
//! ```sh
//! cargo build --release -p stjpdacf-test-support --example step_profile
//! valgrind --tool=callgrind --callgrind-out-file=/tmp/cg.out \
//!   target/release/examples/step_profile typical 40
//! callgrind_annotate --inclusive=yes /tmp/cg.out | grep -E 'step_probed|run_probed|predict_probed|update_probed|associate'
//! ```
//!
//! Arguments: `typical|worst` and the number of frames (the sequence is cycled, time increases).

use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker};
use stjpdacf_tools::scenario::{Scenario, ScenarioConfig};

fn frames(cfg: &ScenarioConfig, seed: u64, n: u64) -> Vec<Vec<[f32; 2]>> {
    (0..n)
        .map(|k| {
            Scenario::generate(cfg, seed * 1000 + k)
                .points
                .iter()
                .map(|&(u, x)| [u as f32, x as f32])
                .collect()
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let which = args.get(1).map_or("typical", String::as_str);
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(40);
    let seq = match which {
        "worst" => frames(
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
        _ => frames(
            &ScenarioConfig {
                clutter_density: 0.02,
                ..ScenarioConfig::default()
            },
            4,
            20,
        ),
    };
    let mut t = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut lanes = 0usize;
    for k in 0..n {
        let pts = &seq[k % seq.len()];
        let out = t
            .step(Instant::from_micros(50_000 * (k as i64 + 1)), pts)
            .expect("time increases");
        lanes += out.filtered.len();
    }
    println!("{which}: {n} frames, {lanes} lane-frames");
}
