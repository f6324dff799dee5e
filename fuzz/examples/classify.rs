//! Classifies tracker_step crash inputs: does a frame up to the failing step give a spatial
//! pseudo-measurement covariance that is not PSD (finding F1)?
//! `cargo run --release --example classify -- FILE...`
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter, Status};
use stjpdacf::tables::DEFAULT;

fn main() {
    let (mut f1, mut other) = (0, 0);
    for path in std::env::args().skip(1) {
        let data = std::fs::read(&path).unwrap_or_default();
        let Err(msg) = stjpdacf_fuzz::tracker_step(&data) else {
            println!("{path}: passes");
            continue;
        };
        let step: usize = msg
            .strip_prefix("step ")
            .and_then(|s| s.split(':').next())
            .and_then(|s| s.parse().ok())
            .unwrap_or(usize::MAX);
        let mut worst = f64::INFINITY;
        for (_, pts) in stjpdacf_fuzz::decode_tracker_input(&data)
            .iter()
            .take(step.saturating_add(1))
        {
            let mut sf: Box<SpatialFilter<3, 6, 64, 16>> = Box::new(SpatialFilter::new());
            let empty = LaneObservation {
                status: Status::Tentative,
                present: [false; 16],
                z: nalgebra::SVector::zeros(),
                cov: nalgebra::SMatrix::zeros(),
                u_first: 0.0,
                u_last: 0.0,
                existence: 0.0,
                rank: 0,
            };
            let mut out = [empty; 6];
            let pts: Vec<[f32; 2]> = pts.iter().take(256).copied().collect();
            let (n, _) = sf.run(&DEFAULT, &Config::DEFAULT, &pts, &mut out);
            for o in out.iter().take(n) {
                let idx: Vec<usize> = (0..16).filter(|&i| o.present[i]).collect();
                worst =
                    worst.min(stjpdacf_fuzz::invariants::eigen_figures(&o.cov, &idx).min_eig_corr);
            }
        }
        if worst < -1e-3 {
            f1 += 1
        } else {
            other += 1;
            println!("{path}: NOT F1 (spatial min eig {worst:.3e}): {msg}");
        }
    }
    println!("F1: {f1}, other: {other}");
}
