//! Lanes do not cross, and no marking joins two others (docs/design.md §11.11): on the soak's
//! synthetic drives (`stjpdacf_test_support::soak::Road`: straight to gently curved roads, uniform
//! clutter up to 0.05 /m per row, dashed lines, lane changes; a generator the replay's defaults
//! were not chosen on) the tracker with the connector rule against the same tracker without it.
//! `cargo test --release -p stjpdacf-test-support --test connectors -- --include-ignored --nocapture`

use stjpdacf::persist::PersistConfig;
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker, TrackerConfig};
use stjpdacf_test_support::soak::{match_truth, Road};

/// (false lane-frames, true line-frames, of which tracked, connectors deleted) over `frames`
/// frames of drive `seed`.
fn drive(seed: u64, frames: u64, cfg: TrackerConfig) -> (u64, u64, u64, u64) {
    let mut road = Road::new(seed);
    let mut t = Box::new(ReferenceTracker::with_config(&DEFAULT, cfg));
    let (mut false_lanes, mut lines, mut tracked, mut deleted) = (0, 0, 0, 0);
    for _ in 0..frames {
        let f = road.next_frame();
        let out = t
            .step(Instant::from_micros(f.t_us), &f.points)
            .expect("time increases");
        deleted += u64::from(out.report.known.connectors_deleted);
        if f.blackout {
            continue;
        }
        let (m, [unmatched, _]) = match_truth(&out.filtered, &f.truth);
        false_lanes += unmatched;
        lines += f.truth.len() as u64;
        tracked += m.len() as u64;
    }
    (false_lanes, lines, tracked, deleted)
}

/// Two drives of 15,000 frames (8.3 min each). Measured (stop 24): false lane-frames 3,408 →
/// 762 (0.114 → 0.025 per frame), true line-frames tracked 99.30 % → 99.77 %, 18 connectors
/// deleted. Since stop 35 a lane's existence is weighed against the other lanes' detections
/// (docs/design.md §11.5), so a connector's rows on the two markings it touches no longer
/// keep it alive and the rule has little left to do: 245 → 241 false lane-frames (0.004 per
/// frame), 99.90 % tracked either way, 1 connector deleted. Since stop 41 the rows' evidence
/// is the paint / gap chain (design §11.5), which scores a run of hits fully, so more
/// clutter-born lanes live on these drives: 889 →
/// 886 false lane-frames (0.030 per frame, as the 10⁶-frame soak), 99.92 % tracked either way,
/// 1 connector deleted. Asserted: the rule does not add false lanes or cost tracking (by more
/// than 0.2 points), and with the defaults the false lane-frames stay under the limit
/// of 0.05 per frame (until stop 40 this asserted 0.01, 0.4× the stop-24 figure with the rule,
/// which the 1/K evidence met with 241).
#[test]
#[ignore = "60,000 tracker frames: release only (`.ci/run` runs it with --include-ignored)"]
fn connectors_remove_false_lanes_and_keep_the_lines() {
    let off = TrackerConfig {
        persist: PersistConfig {
            connectors: false,
            ..PersistConfig::DEFAULT
        },
        ..TrackerConfig::DEFAULT
    };
    let mut with = (0, 0, 0, 0);
    let mut without = (0, 0, 0, 0);
    for seed in [0, 1] {
        for (acc, cfg) in [(&mut with, TrackerConfig::DEFAULT), (&mut without, off)] {
            let (a, b, c, d) = drive(seed, 15_000, cfg);
            *acc = (acc.0 + a, acc.1 + b, acc.2 + c, acc.3 + d);
        }
    }
    let frac = |x: (u64, u64, u64, u64)| x.2 as f64 / x.1 as f64;
    println!(
        "false lane-frames {} -> {}, line-frames tracked {:.2} % -> {:.2} %, connectors deleted {}",
        without.0,
        with.0,
        100.0 * frac(without),
        100.0 * frac(with),
        with.3
    );
    assert_eq!(without.3, 0);
    assert!(with.0 <= without.0, "{} vs {}", with.0, without.0);
    assert!(
        (with.0 as f64) <= 0.05 * 30_000.0,
        "{} false lane-frames in 30,000 frames",
        with.0
    );
    assert!(frac(with) >= frac(without) - 0.002);
}
