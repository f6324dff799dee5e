//! The firmware benchmark's scenario files (`bench/firmware/scenarios`): byte for byte what the
//! generator writes, decodable by the core's receiver at M = 256, wired into the firmware's
//! binaries, and as adversarial as `stjpdacf_tools::fwscenario` says.

use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter};
use stjpdacf::tables::DEFAULT;
use stjpdacf::wire::{frame_len, Receiver};
use stjpdacf_tools::fwscenario::{self, check_all, scenarios, MEAS, SCENARIO_DIR, STEP_US};
use stjpdacf_tools::repo_root;

const EMPTY_OBS: LaneObservation<16> = LaneObservation::EMPTY;

#[test]
fn committed_firmware_scenarios_are_regenerated_exactly() {
    let names = check_all(&repo_root().join(SCENARIO_DIR)).unwrap();
    assert_eq!(names, ["typical", "worst", "worst_patterns"]);
}

#[test]
fn scenario_files_decode_in_order_at_the_reference_capacity() {
    for s in scenarios().unwrap() {
        let bytes = s.encode().unwrap();
        let mut rx = Receiver::new();
        let mut pts = [[0.0f32; 2]; MEAS];
        let mut off = 0;
        for (k, want) in s.frames.iter().enumerate() {
            let info = rx.accept(&bytes[off..], &mut pts).unwrap();
            assert_eq!(info.seq as usize, k + 1);
            assert_eq!(info.time.as_micros(), (k as i64 + 1) * STEP_US);
            assert_eq!(info.count, want.len());
            for (a, b) in want.iter().zip(&pts) {
                assert!((a[0] - b[0]).abs() <= 1.0 / 512.0 && (a[1] - b[1]).abs() <= 1.0 / 512.0);
            }
            off += frame_len(info.count);
        }
        assert_eq!(off, bytes.len(), "{}: trailing bytes", s.name);
        assert_eq!(rx.stats().rejected(), 0);
    }
}

#[test]
fn every_scenario_has_its_firmware_binaries() {
    let bin = repo_root().join("bench/firmware/src/bin");
    let spatial = std::fs::read_to_string(bin.join("spatial.rs")).unwrap();
    for s in scenarios().unwrap() {
        let file = format!("scenarios/{}.{}", s.name, fwscenario::EXTENSION);
        assert!(spatial.contains(&file), "spatial.rs does not run {file}");
        let tracker = std::fs::read_to_string(bin.join(format!("tracker_{}.rs", s.name))).unwrap();
        assert!(tracker.contains(&file));
    }
}

/// The claims of the module docs, checked with the core's spatial filter: typical frames carry
/// realistic point counts; the worst-case frames are full, keep 6 lanes, and either overflow the
/// event budget (`worst`) or score the most events a row can without pruning
/// (`worst_patterns`: 14 rows of 486 events).
#[test]
fn scenarios_are_what_they_claim() {
    let mut f = Box::new(SpatialFilter::<3, 6, 64, 16>::new());
    let cfg = Config::DEFAULT;
    for s in scenarios().unwrap() {
        let mut lanes = Vec::new();
        let mut pruned = Vec::new();
        let mut events = Vec::new();
        for fr in &s.frames {
            let mut obs = [EMPTY_OBS; 6];
            let (n, rep) = f.run(&DEFAULT, &cfg, fr, &mut obs);
            lanes.push(n);
            pruned.push(rep.rows_approximated);
            events.push(rep.events);
        }
        let counts: Vec<usize> = s.frames.iter().map(Vec::len).collect();
        match s.name {
            "typical" => {
                assert_eq!(s.frames.len(), 60);
                assert!(
                    counts.iter().all(|&c| (50..=MEAS).contains(&c)),
                    "{counts:?}"
                );
                assert!(lanes.iter().filter(|&&n| n >= 3).count() >= 40, "{lanes:?}");
            }
            "worst" => {
                assert!(counts.iter().all(|&c| c == MEAS));
                assert!(lanes.iter().all(|&n| n == 6), "{lanes:?}");
                assert!(pruned.iter().all(|&p| p >= 8), "{pruned:?}");
            }
            "worst_patterns" => {
                assert!(counts.iter().all(|&c| c == MEAS));
                assert!(lanes.iter().all(|&n| n == 6), "{lanes:?}");
                assert!(pruned.iter().all(|&p| p == 0), "{pruned:?}");
                assert!(events.iter().all(|&e| e >= 14 * 486), "{events:?}");
            }
            other => panic!("unexpected scenario {other}"),
        }
    }
}
