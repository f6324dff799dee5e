//! The benchmark harness's per-frame summary (`Driver::summaries`, the "events" and "rows over
//! E" columns of `docs/bench` and `scaling.csv`) against the tracker's own step report.

use stjpdacf::probe::NoProbe;
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker};
use stjpdacf_bench::harness::Driver;
use stjpdacf_bench::inputs::{self, STEP_US};

/// A frame's joint events and rows over E are the known-lane rows' (almost all of them at
/// steady state, where the known lanes explain most points) and the spatial walk's on the
/// points those leave: before stop 71 the summary counted the walk's alone.
#[test]
fn frame_summary_counts_the_known_lane_rows() {
    for seq in inputs::sequences() {
        let frames = &seq.frames;
        let mut d = Driver::new(Box::new(ReferenceTracker::new(&DEFAULT)));
        d.warm_up(frames, 2);
        let summary = d.summaries(frames);
        // The same frames at the same times on a second tracker, read from its full report.
        let mut t = Box::new(ReferenceTracker::new(&DEFAULT));
        let mut now = 0i64;
        for k in 0..2 * frames.len() {
            now += STEP_US;
            t.step_probed(
                Instant::from_micros(now),
                &frames[k % frames.len()].p32,
                &mut NoProbe,
            )
            .unwrap();
        }
        let mut known_events = 0;
        for (k, s) in summary.iter().enumerate() {
            now += STEP_US;
            let r = t
                .step_probed(Instant::from_micros(now), &frames[k].p32, &mut NoProbe)
                .unwrap()
                .report;
            known_events += r.known.events;
            assert_eq!(
                s.events,
                r.spatial.events + r.known.events,
                "{} frame {k}: summary {} events, spatial walk {}, known-lane rows {}",
                seq.name,
                s.events,
                r.spatial.events,
                r.known.events
            );
            assert_eq!(
                s.rows_approximated,
                r.spatial.rows_approximated + r.known.pruned_rows + r.known.lbp_rows,
                "{} frame {k}: rows over E",
                seq.name
            );
        }
        assert!(known_events > 0, "{}: no known-lane events", seq.name);
    }
}
