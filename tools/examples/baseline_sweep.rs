//! The grid on which the RANSAC baseline's parameters were chosen (`stjpdacf_tools::baseline`):
//! the bundled replay (40 labels of `data/tusimple/train_subset.json`, seed 1, 20 frames per
//! clip) at the mid preset, official TuSimple metric on each clip's last frame and on every
//! frame, for every inlier tolerance × minimum inlier count × minimum extent of the grid.
//!
//! `cargo run --release -p stjpdacf-tools --example baseline_sweep`

use stjpdacf_tools::baseline::{self, BaselineParams};
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::metric;
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track::Space;
use stjpdacf_tools::tusimple::TuSimpleRecord;

fn score(preds: &[TuSimpleRecord], gts: &[TuSimpleRecord]) -> anyhow::Result<metric::Score> {
    let files: std::collections::HashSet<&str> = gts.iter().map(|g| g.raw_file.as_str()).collect();
    let kept: Vec<TuSimpleRecord> = preds
        .iter()
        .filter(|p| files.contains(p.raw_file.as_str()))
        .cloned()
        .collect();
    metric::bench_one_submit(&kept, gts)
}

fn main() -> anyhow::Result<()> {
    let labels = stjpdacf_tools::demo::replay_labels()?;
    let cam = Camera::tusimple();
    let o = synth::synthesize(&labels, &SynthParams::preset(NoiseLevel::Mid), &cam, 1)?;
    let tables = &stjpdacf::tables::DEFAULT;
    println!("| inlier tol (m) | min inliers | min extent (m) | last accuracy / FP / FN | all-frames accuracy | mean ms |");
    println!("|---|---|---|---|---|---|");
    for tol in [0.2, 0.3, 0.5, 0.75] {
        for min_inliers in [4, 6, 8, 10, 15] {
            for min_extent in [5.0, 10.0, 20.0] {
                let p = BaselineParams {
                    inlier_tol: tol,
                    min_inliers,
                    min_extent,
                    ..BaselineParams::default()
                };
                let (preds, stats) =
                    baseline::track(&o.frames, tables, &cam, Space::Image, &p, |_| {})?;
                let last = score(&preds, &o.gt_last)?;
                let all = score(&preds, &o.gt_all)?;
                println!(
                    "| {tol} | {min_inliers} | {min_extent} | {:.3} / {:.3} / {:.3} | {:.3} | {:.2} |",
                    last.accuracy, last.fp, last.fn_, all.accuracy, stats.run_mean_ms
                );
            }
        }
    }
    Ok(())
}
