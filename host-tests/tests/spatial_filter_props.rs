//! Properties of the core's per-frame spatial filter for any input: no panic, at most `LANES`
//! lanes, every output finite, every covariance block symmetric PSD (to f32 round-off), counters
//! that add up, and the same output for the same input.

use nalgebra::DMatrix;
use proptest::prelude::*;
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter, Status};
use stjpdacf::tables::DEFAULT;
use stjpdacf_test_support::strategies;

type Filter = SpatialFilter<3, 6, 64, 16>;

const EMPTY: LaneObservation<16> = LaneObservation::EMPTY;

/// A coordinate: mostly in the window, sometimes non-finite, huge or the subnormal -1e-42.
fn coord() -> impl Strategy<Value = f32> {
    strategies::coord(-1e-42)
}

/// Points on up to four noisy straight lanes plus arbitrary junk, so that tracks really start.
fn frame() -> impl Strategy<Value = Vec<[f32; 2]>> {
    let lanes = proptest::collection::vec((-8.0f32..8.0, -0.05f32..0.05), 0..5);
    let junk = proptest::collection::vec((coord(), coord()), 0..60);
    (lanes, junk, any::<u64>()).prop_map(|(lanes, junk, seed)| {
        let mut pts = Vec::new();
        let mut s = seed;
        for (x0, slope) in lanes {
            for r in 0..61 {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                if (s >> 33) % 10 < 8 {
                    let u = 3.0 + r as f32 * 77.0 / 60.0;
                    let noise = ((s >> 40) % 200) as f32 / 1000.0 - 0.1;
                    pts.push([u, x0 + slope * u + noise]);
                }
            }
        }
        pts.extend(junk.into_iter().map(|(u, x)| [u, x]));
        pts
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn frame_filter_is_total(points in frame()) {
        let mut f = Box::new(Filter::new());
        let mut out = [EMPTY; 6];
        let (n, rep) = f.run(&DEFAULT, &Config::default(), &points, &mut out);
        prop_assert!(n <= 6);
        prop_assert!(!rep.bad_config);
        prop_assert_eq!(rep.points_in as usize, points.len());
        let non_finite = points.iter().filter(|p| !(p[0].is_finite() && p[1].is_finite())).count();
        prop_assert_eq!(rep.rejected_non_finite as usize, non_finite);
        for lane in &out[..n] {
            prop_assert!(lane.status != Status::Tentative);
            prop_assert!(lane.z.iter().chain(lane.cov.iter()).all(|v| v.is_finite()));
            prop_assert!(lane.u_first <= lane.u_last);
            prop_assert!((0.0..=1.0).contains(&lane.existence));
            let cov = DMatrix::from_fn(16, 16, |i, j| lane.cov[(i, j)] as f64);
            let scale = cov.abs().max().max(1e-12);
            prop_assert!((&cov - cov.transpose()).abs().max() <= 1e-6 * scale);
            prop_assert!(cov.symmetric_eigen().eigenvalues.min() >= -1e-4 * scale);
            for i in 0..16 {
                if !lane.present[i] {
                    prop_assert!(lane.z[i] == 0.0 && (0..16).all(|j| lane.cov[(i, j)] == 0.0));
                }
            }
        }
        // Ranks increase left to right.
        prop_assert!(out[..n].windows(2).all(|w| w[0].rank < w[1].rank));
        // Same input, same output (the filter keeps no state between frames).
        let mut out2 = [EMPTY; 6];
        let (n2, rep2) = f.run(&DEFAULT, &Config::default(), &points, &mut out2);
        prop_assert_eq!(n, n2);
        prop_assert_eq!(rep, rep2);
        prop_assert_eq!(&out[..n], &out2[..n2]);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Any finite positive row-noise scale is a valid model; zero, negative or non-finite is
    /// `bad_config` with no lane, and the filter stays usable.
    #[test]
    fn row_noise_scale_is_validated(points in frame(), s in prop_oneof![
        Just(0.0f32), Just(-1.0), Just(f32::NAN), Just(f32::INFINITY), 1e-6f32..100.0
    ]) {
        let mut f = Box::new(Filter::new());
        let mut out = [EMPTY; 6];
        let cfg = Config { row_noise_scale: s, ..Config::default() };
        let (n, rep) = f.run(&DEFAULT, &cfg, &points, &mut out);
        let valid = s.is_finite() && s > 0.0;
        prop_assert_eq!(rep.bad_config, !valid);
        if valid {
            prop_assert!(n <= 6);
            for lane in &out[..n] {
                prop_assert!(lane.z.iter().chain(lane.cov.iter()).all(|v| v.is_finite()));
            }
        } else {
            prop_assert_eq!(n, 0);
        }
        let (_, rep2) = f.run(&DEFAULT, &Config::default(), &points, &mut out);
        prop_assert!(!rep2.bad_config);
    }
}
