//! The per-lane smoother (`TrackerConfig::smoother_per_lane`, docs/design.md §5.1) against the
//! exact one, whole tracker on replay clips: it never changes the filtered lanes; with diag(B)
//! tables (no cross-lane covariance, so the exact cross-covariances are block-diagonal) it
//! gives the exact smoothed lanes; with the coupled tables it gives different smoothed lanes
//! (the approximation is not a no-op).
use stjpdacf::tables::{ReferenceTables, DEFAULT};
use stjpdacf::tracker::{LaneEstimate, TrackerConfig};
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track::{self, Space};
use stjpdacf_tools::{demo, repo_root};

type Lanes = Vec<LaneEstimate<16>>;

/// Per frame, the filtered and the smoothed lanes of 6 replay clips (mid noise, seed 3).
fn run(tables: &'static ReferenceTables, per_lane: bool) -> Vec<(Lanes, Lanes)> {
    let mut labels = demo::replay_labels().expect("replay labels");
    labels.truncate(6);
    let cam = Camera::tusimple();
    let o =
        synth::synthesize(&labels, &SynthParams::preset(NoiseLevel::Mid), &cam, 3).expect("synth");
    let cfg = TrackerConfig {
        smoother_per_lane: per_lane,
        ..TrackerConfig::DEFAULT
    };
    let mut out = Vec::new();
    track::track_with(&o.frames, tables, &cam, Space::Image, cfg, |v| {
        if let Some(s) = v.output {
            out.push((s.filtered.to_vec(), s.smoothed.to_vec()));
        }
    })
    .expect("track");
    out
}

/// Largest |difference| of the smoothed index-point values, same ids required.
fn max_smoothed_diff(a: &[(Lanes, Lanes)], b: &[(Lanes, Lanes)]) -> f32 {
    assert_eq!(a.len(), b.len());
    let mut worst = 0.0f32;
    for ((_, sa), (_, sb)) in a.iter().zip(b) {
        assert_eq!(sa.len(), sb.len());
        for (la, lb) in sa.iter().zip(sb) {
            assert_eq!(la.id, lb.id);
            for (x, y) in la.z.iter().zip(lb.z.iter()) {
                worst = worst.max((x - y).abs());
            }
            for (x, y) in la.var.iter().zip(lb.var.iter()) {
                worst = worst.max((x - y).abs());
            }
        }
    }
    worst
}

fn smoothed_frames(r: &[(Lanes, Lanes)]) -> usize {
    r.iter().filter(|(_, s)| !s.is_empty()).count()
}

#[test]
fn per_lane_leaves_the_filter_alone_and_approximates_only_the_coupled_smoother() {
    let exact = run(&DEFAULT, false);
    let per_lane = run(&DEFAULT, true);
    assert!(smoothed_frames(&exact) > 60, "too few smoothed frames");
    // The filter does not read the smoother: identical filtered lanes, bit for bit.
    for ((fa, _), (fb, _)) in exact.iter().zip(&per_lane) {
        assert_eq!(fa, fb);
    }
    // Coupled B: the per-lane smoother drops what other lanes' innovations say about a lane's
    // past, so the smoothed lanes move (by a bounded amount: the filtered-to-smoothed change).
    let d = max_smoothed_diff(&exact, &per_lane);
    eprintln!("max smoothed difference: {d}");
    assert!(
        d > 1e-4,
        "per-lane smoothing changed nothing on coupled B ({d})"
    );
}

#[test]
fn per_lane_is_exact_when_the_lanes_are_uncoupled() {
    let h = HyperFile::load(&repo_root().join("data").join(demo::ABLATION_HYPER)).expect("hyper");
    let diag = track::tables_from_hyper(&h).expect("diag tables");
    let exact = run(diag, false);
    let per_lane = run(diag, true);
    assert!(smoothed_frames(&exact) > 60, "too few smoothed frames");
    let d = max_smoothed_diff(&exact, &per_lane);
    eprintln!("max smoothed difference: {d}");
    // f32: same products, the per-lane pass only skips exact zeros.
    assert!(
        d <= 1e-5,
        "diag(B): per-lane smoother differs from the exact one by {d}"
    );
}
