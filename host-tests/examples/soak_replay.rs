//! Replays one soak drive (`stjpdacf_test_support::soak::Road`, the seed of a shard is `seed + shard`)
//! through the core tracker and prints, per frame, the smallest eigenvalue of each spatial
//! pseudo-measurement covariance plus `r₀² I` (finding F1: negative means not positive
//! definite), the smallest eigenvalue of the temporal covariance in correlation form and the
//! smallest published variance: every frame with a non-PD `R + r₀² I` and the last 40 frames
//! (with a third argument, only the frames where the covariance breaks, and a summary).
//!
//! ```sh
//! cargo run --release -p stjpdacf-test-support --example soak_replay -- 1 2095
//! ```
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter};
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker};
use stjpdacf_test_support::invariants::{
    active_indices, eigen_figures, observation_cov_with_noise,
};
use stjpdacf_test_support::soak::Road;
fn main() {
    let arg = |i: usize| -> u64 {
        std::env::args()
            .nth(i)
            .and_then(|a| a.parse().ok())
            .expect("usage: soak_replay SEED FRAMES")
    };
    let (seed, until) = (arg(1), arg(2));
    let verbose = std::env::args().nth(3).is_none();
    let mut road = Road::new(seed);
    let mut a = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut sf: Box<SpatialFilter<3, 6, 64, 16>> = Box::new(SpatialFilter::new());
    let mut bad_obs = 0;
    let (mut breaks, mut breaks_at_bad_obs, mut was_ok) = (0, 0, true);
    for k in 0..until {
        let f = road.next_frame();
        let pts: Vec<[f32; 2]> = f.points.iter().take(256).copied().collect();
        let empty = LaneObservation::EMPTY;
        let mut out = [empty; 6];
        let (n, _) = sf.run(&DEFAULT, &Config::DEFAULT, &pts, &mut out);
        let mut worst = f64::INFINITY;
        for o in out.iter().take(n) {
            let r = observation_cov_with_noise(o, DEFAULT.hyper.pseudo_noise);
            worst = worst.min(r.symmetric_eigenvalues().min());
        }
        if worst < 0.0 {
            bad_obs += 1;
        }
        let out = a
            .step(Instant::from_micros(f.t_us), &f.points)
            .expect("time increases");
        let ft = a.temporal().filter();
        let h = eigen_figures(ft.covariance(), &active_indices(ft));
        let minvar = out
            .filtered
            .iter()
            .flat_map(|l| l.var.iter())
            .fold(f32::INFINITY, |m, v| m.min(*v));
        // NaN (no active lane) counts as healthy.
        let ok = h.min_eig_corr.is_nan() || h.min_eig_corr >= -1e-3;
        if was_ok && !ok {
            breaks += 1;
            if worst < 0.0 {
                breaks_at_bad_obs += 1;
            }
            println!("frame {k}: covariance breaks (R + r0² I min eig {worst:.2e})");
        }
        was_ok = ok;
        if verbose && (k + 40 >= until || worst < 0.0) {
            println!("frame {k}: obs R+r0² min eig {worst:.2e}; P corr min eig {:.3e}; min var {minvar:.2e}; temporal failures {}; lanes {}", h.min_eig_corr, out.report.temporal_failures, out.filtered.len());
        }
    }
    println!("frames with a non-PD R + r0²I: {bad_obs}; covariance breaks: {breaks}, of which on a frame with a non-PD R + r0²I: {breaks_at_bad_obs}");
}
