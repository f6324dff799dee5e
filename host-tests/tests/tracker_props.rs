//! Properties of the whole `Tracker` for arbitrary frame sequences: arbitrary floats (NaN, ±inf,
//! huge, subnormal), any counts (beyond the M = 256 budget), any timestamps (repeats, reversals,
//! huge jumps). Invariants: no panic; ≤ LANES lanes; every published value finite; variances
//! ≥ 0; ids unique within a frame; a rejected step leaves the state untouched.

use proptest::prelude::*;
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker, StepError};
use stjpdacf_test_support::strategies;

/// A coordinate: mostly in the window, sometimes non-finite, huge or the subnormal 1e-42.
fn coord() -> impl Strategy<Value = f32> {
    strategies::coord(1e-42)
}

/// A frame: up to 4 noisy straight lanes plus junk; `dt_us` may be ≤ 0 (rejected) or huge.
fn frame() -> impl Strategy<Value = (i64, Vec<[f32; 2]>)> {
    let lanes = proptest::collection::vec((-8.0f32..8.0, -0.05f32..0.05), 0..5);
    let junk = proptest::collection::vec((coord(), coord()), 0..300);
    let dt = prop_oneof![6 => 10_000i64..300_000, 1 => Just(0i64), 1 => -100_000i64..0, 1 => 1_000_000i64..600_000_000];
    (dt, lanes, junk).prop_map(|(dt, lanes, junk)| {
        let mut pts = Vec::new();
        for (x0, slope) in lanes {
            for r in 0..61 {
                let u = 3.0 + r as f32 * 77.0 / 60.0;
                pts.push([u, x0 + slope * u]);
            }
        }
        pts.extend(junk.into_iter().map(|(u, x)| [u, x]));
        (dt, pts)
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(16))]

    #[test]
    fn tracker_is_total(frames in proptest::collection::vec(frame(), 1..8)) {
        let mut t = Box::new(ReferenceTracker::new(&DEFAULT));
        let mut now = 0i64;
        let mut first = true;
        for (dt, pts) in frames {
            let next = now.saturating_add(dt);
            let before = format!("{t:?}");
            match t.step(Instant::from_micros(next), &pts) {
                Err(StepError::NonIncreasingTime) => {
                    prop_assert!(!first && dt <= 0);
                    prop_assert_eq!(format!("{t:?}"), before);
                    continue;
                }
                Err(e) => prop_assert!(false, "unexpected error {:?}", e),
                Ok(out) => {
                    first = false;
                    now = next;
                    prop_assert!(out.filtered.len() <= 6 && out.smoothed.len() <= 6);
                    prop_assert_eq!(out.report.over_budget_points as usize, pts.len().saturating_sub(256));
                    let mut ids: Vec<u32> = out.filtered.iter().map(|l| l.id.0).collect();
                    ids.sort_unstable();
                    ids.dedup();
                    prop_assert_eq!(ids.len(), out.filtered.len());
                    for l in out.filtered.iter().chain(out.smoothed.iter()) {
                        prop_assert!(l.z.iter().all(|v| v.is_finite()), "{:?}", l.z);
                        prop_assert!(l.var.iter().all(|v| v.is_finite() && *v >= -1e-4), "{:?}", l.var);
                        prop_assert!((0.0..=1.0).contains(&l.existence));
                    }
                }
            }
        }
    }
}
