//! The core's per-frame spatial filter (`stjpdacf::spatial::filter`) on seeded BEV scenarios:
//! lanes found, pseudo-measurements near the true curves, covariance blocks symmetric PSD,
//! counters for bad input. Tolerances: a pseudo-measurement within 4σ + 0.1 m of the truth.

use nalgebra::DMatrix;
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter};
use stjpdacf::tables::DEFAULT;
use stjpdacf_tools::scenario::{Scenario, ScenarioConfig};

type Filter = SpatialFilter<3, 6, 64, 16>;

fn run(
    points: &[(f64, f64)],
) -> (
    Vec<LaneObservation<16>>,
    stjpdacf::spatial::filter::SpatialReport,
) {
    let mut f = Box::new(Filter::new());
    let pts: Vec<[f32; 2]> = points.iter().map(|&(u, x)| [u as f32, x as f32]).collect();
    let mut out = [LaneObservation::EMPTY; 6];
    let (n, rep) = f.run(&DEFAULT, &Config::default(), &pts, &mut out);
    (out[..n].to_vec(), rep)
}

fn check_lanes(sc: &Scenario, lanes: &[LaneObservation<16>], what: &str) {
    let idx: Vec<f64> = (0..16).map(|i| 3.0 + 77.0 * i as f64 / 15.0).collect();
    for (k, lane) in lanes.iter().enumerate() {
        let cov = DMatrix::from_fn(16, 16, |i, j| lane.cov[(i, j)] as f64);
        assert!(
            (&cov - cov.transpose()).abs().max() <= 1e-6 * cov.abs().max().max(1e-12),
            "{what}: lane {k} cov asymmetric"
        );
        let min_eig = cov.clone().symmetric_eigen().eigenvalues.min();
        assert!(
            min_eig >= -1e-5 * cov.abs().max(),
            "{what}: lane {k} min eigenvalue {min_eig}"
        );
        // The nearest true lane at its first present index point.
        let first = (0..16).find(|&i| lane.present[i]).unwrap();
        let truth = (0..sc.config.lanes)
            .min_by(|&a, &b| {
                let da = (sc.lane_x(a, idx[first]) - lane.z[first] as f64).abs();
                let db = (sc.lane_x(b, idx[first]) - lane.z[first] as f64).abs();
                da.total_cmp(&db)
            })
            .unwrap();
        for i in (0..16).filter(|&i| lane.present[i]) {
            let want = sc.lane_x(truth, idx[i]);
            let sd = (lane.cov[(i, i)] as f64).sqrt();
            let err = (lane.z[i] as f64 - want).abs();
            assert!(
                err <= 4.0 * sd + 0.1,
                "{what}: lane {k} (true {truth}) index {i}: {} vs {want:.3} (sd {sd:.3})",
                lane.z[i]
            );
        }
    }
}

#[test]
fn finds_parallel_lanes() {
    for seed in [1, 2, 3] {
        let sc = Scenario::generate(&ScenarioConfig::default(), seed);
        let (lanes, rep) = run(&sc.points);
        println!("seed {seed}: {} lanes, {rep:?}", lanes.len());
        assert_eq!(lanes.len(), 3, "seed {seed}: {rep:?}");
        check_lanes(&sc, &lanes, &format!("parallel seed {seed}"));
        for l in &lanes {
            assert!(l.existence > 0.75 && l.u_last > 75.0, "{l:?}");
        }
    }
}

#[test]
fn finds_curved_lanes_in_clutter() {
    for seed in [4, 5] {
        let cfg = ScenarioConfig::curved();
        let sc = Scenario::generate(&cfg, seed);
        let (lanes, rep) = run(&sc.points);
        println!("seed {seed}: {} lanes, {rep:?}", lanes.len());
        assert_eq!(lanes.len(), 3, "seed {seed}: {rep:?}");
        check_lanes(&sc, &lanes, &format!("curved seed {seed}"));
    }
}

/// Uniform clutter alone. The defaults tolerate a dashed marking's 9 m gap (8 consecutive misses
/// before a tentative track is deleted), which lets dense uniform clutter confirm false lanes:
/// measured over 20 seeds, 0 per frame at 0.02 /m, 0.85 at 0.05 /m and 3.65 at 0.1 /m (with the
/// earlier 3-miss rule: 0, 0, 0.2 — but every dashed lane was lost and replay accuracy fell from
/// 0.84 to 0.14). Asserted at 0.02 /m; the trade-off is an open problem (docs/measurements.md).
#[test]
fn sparse_clutter_alone_confirms_nothing() {
    for seed in [6, 7, 8, 9, 10] {
        let cfg = ScenarioConfig {
            lanes: 0,
            clutter_density: 0.02,
            ..ScenarioConfig::default()
        };
        let sc = Scenario::generate(&cfg, seed);
        let (lanes, rep) = run(&sc.points);
        assert!(lanes.is_empty(), "seed {seed}: {rep:?}");
    }
}

#[test]
fn bad_points_are_counted_not_used() {
    let sc = Scenario::generate(&ScenarioConfig::default(), 1);
    let mut pts = sc.points.clone();
    pts.extend([
        (f64::NAN, 0.0),
        (10.0, f64::INFINITY),
        (200.0, 0.0),
        (-5.0, 1.0),
    ]);
    let (lanes, rep) = run(&pts);
    assert_eq!(rep.rejected_non_finite, 2);
    assert_eq!(rep.rejected_window, 2);
    assert_eq!(lanes.len(), 3);
}
