//! Per-stage split of `Tracker::step` at the reference configuration from a timing probe
//! (`stjpdacf_bench::harness::profile`): the wall-clock time between two stage transitions is
//! charged to the stage entered first; the same frames also run on a tracker without a probe and
//! on one with a probe that only counts calls, so the probe's own overhead is measured in the
//! same run. Not a criterion bench (one pass gives every stage at once).
//!
//! ```sh
//! cargo bench -p stjpdacf-bench --bench stages
//! cargo xtask bench-report
//! ```
//!
//! Writes `target/stjpdacf-bench/stages.json`. Every figure is the mean over the sequence's
//! frames of the frame's median over `PASSES` timed passes (after 2 warm-up passes).

use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::ReferenceTracker;
use stjpdacf_bench::harness::profile;
use stjpdacf_bench::inputs;
use stjpdacf_bench::report::{self, Machine, Span, StagesOut};

/// Timed passes over each sequence.
const PASSES: usize = 101;

fn main() {
    // `cargo bench` passes `--bench`; a filter argument restricts the sequences.
    let filter: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let machine_start = Machine::now();
    let mut profiles = Vec::new();
    for seq in inputs::sequences() {
        if !filter.is_empty() && !filter.iter().any(|f| seq.name.contains(f.as_str())) {
            continue;
        }
        let p = profile(
            seq.name,
            || Box::new(ReferenceTracker::new(&DEFAULT)),
            &seq.frames,
            2,
            PASSES,
        );
        println!(
            "{:<12} step {:>8.1} µs (count probe {:>8.1}, timing probe {:>8.1}; {:.0} calls/frame \
             at {:.1} ns = {:.1} µs)",
            p.sequence,
            p.total_no_probe_us,
            p.total_count_probe_us,
            p.total_timing_probe_us,
            p.calls_per_frame,
            p.timer_call_ns,
            p.calls_per_frame * p.timer_call_ns * 1e-3
        );
        for (s, v) in &p.stage_us {
            println!("    {s:<12} {v:>9.1} µs");
        }
        for (s, v) in &p.group_us {
            println!("  = {s:<12} {v:>9.1} µs");
        }
        profiles.push(p);
    }
    let out = StagesOut {
        span: Span::since(machine_start),
        profiles,
    };
    if filter.is_empty() {
        report::write_side_file("stages.json", &out).expect("writing stages.json");
    } else {
        println!("(filtered run: stages.json not written)");
    }
}
