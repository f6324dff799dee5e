//! The robustness curve over several synth seeds: the demo's robustness section (mid preset,
//! clutter × 1 / × 2 / × 4 / × 8, × 1 with distractors and × 1 with the pixel noise × 2 / × 4,
//! the tracker against the per-frame RANSAC fit on the same frames) on all 40 replay labels for
//! each seed, then the mean over the seeds. The demo's own curve is 20 clips of seed 1 (one lost lane is 0.0125 of accuracy there);
//! this is the curve over 8× the clips that docs/measurements.md quotes as "the 4-seed curve".
//!
//! `cargo run --release -p stjpdacf-tools --example robustness_seeds [clips] [seed ...]`
//! (default: 40 clips, seeds 1 2 3 4; about a minute per seed on one core).
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::demo::{self, Variant};

fn main() -> anyhow::Result<()> {
    let args: Vec<u64> = std::env::args()
        .skip(1)
        .map(|a| a.parse())
        .collect::<Result<_, _>>()?;
    let clips = args.first().copied().unwrap_or(40) as usize;
    let seeds: Vec<u64> = if args.len() > 1 {
        args[1..].to_vec()
    } else {
        vec![1, 2, 3, 4]
    };
    let labels = demo::replay_labels()?;
    let variants = [Variant::new("tracker", TrackerConfig::DEFAULT)];
    // Per condition: (name, Σ tracker accuracy, Σ baseline accuracy).
    let mut sums: Vec<(String, f64, f64)> = Vec::new();
    println!(
        "| seed | condition | tracker accuracy / FP / FN | RANSAC accuracy / FP / FN | margin |"
    );
    println!("|---|---|---|---|---|");
    for &seed in &seeds {
        let r = demo::robustness(&labels, clips, None, seed, &variants, false, |_| {})?;
        for (k, row) in r.rows.iter().enumerate() {
            let Some(t) = row.trackers.first() else {
                continue;
            };
            let (a, b) = (t.score.accuracy, row.baseline.accuracy);
            println!(
                "| {seed} | {} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {:+.3} |",
                row.condition,
                a,
                t.score.fp,
                t.score.fn_,
                b,
                row.baseline.fp,
                row.baseline.fn_,
                a - b
            );
            if sums.len() <= k {
                sums.push((row.condition.clone(), 0.0, 0.0));
            }
            if let Some(s) = sums.get_mut(k) {
                s.1 += a;
                s.2 += b;
            }
        }
    }
    let n = seeds.len().max(1) as f64;
    println!();
    println!(
        "| condition (mean over {} seeds × {clips} clips) | tracker | RANSAC | margin |",
        seeds.len()
    );
    println!("|---|---|---|---|");
    for (c, a, b) in &sums {
        println!(
            "| {c} | {:.3} | {:.3} | {:+.3} |",
            a / n,
            b / n,
            (a - b) / n
        );
    }
    Ok(())
}
