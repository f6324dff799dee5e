//! The held-out check over several generator seeds: the demo's held-out check (second generator,
//! 40 held-out labels, clutter × 1 / × 2 / × 4 / × 8, × 1 with segments and × 1 with the column
//! noise × 2 / × 4; the tracker against the better of the RANSAC fit and the fit capped at 4
//! lanes) for each seed, then the mean over the seeds. The demo's check is seed 1 alone (a lost
//! lane is 0.006 of accuracy there).
//!
//! `cargo run --release -p stjpdacf-tools --example heldout_seeds [seed ...]` (default seeds 1–5;
//! about 15 s a seed), the default tracker configuration.

use std::collections::BTreeMap;

use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::demo::{heldout_check, Variant};
use stjpdacf_tools::heldout;

fn main() -> anyhow::Result<()> {
    let seeds: Vec<u64> = std::env::args()
        .skip(1)
        .map(|a| a.parse())
        .collect::<Result<_, _>>()?;
    let seeds = if seeds.is_empty() {
        vec![1, 2, 3, 4, 5]
    } else {
        seeds
    };
    let labels = heldout::bundled_labels()?;
    let variants = [Variant::new("tracker", TrackerConfig::DEFAULT)];
    // Per condition, in order: the sums of the tracker's accuracy, the better baseline's and
    // the margin.
    let mut order: Vec<String> = Vec::new();
    let mut sums: BTreeMap<String, [f64; 3]> = BTreeMap::new();
    println!("| seed | condition | tracker accuracy / FP / FN | better RANSAC accuracy | margin |");
    println!("|---|---|---|---|---|");
    for &seed in &seeds {
        let r = heldout_check(&labels, 40, seed, &variants, false, |_| {})?;
        for row in &r.rows {
            let Some(t) = row.trackers.first() else {
                continue;
            };
            let b = row.baseline.accuracy.max(row.baseline_capped.accuracy);
            let margin = t.score.accuracy - b;
            println!(
                "| {seed} | {} | {:.3} / {:.3} / {:.3} | {b:.3} | {margin:+.3} |",
                row.condition, t.score.accuracy, t.score.fp, t.score.fn_
            );
            if !order.contains(&row.condition) {
                order.push(row.condition.clone());
            }
            let s = sums.entry(row.condition.clone()).or_default();
            s[0] += t.score.accuracy;
            s[1] += b;
            s[2] += margin;
        }
    }
    let n = seeds.len().max(1) as f64;
    println!();
    println!(
        "| condition (mean over {} seeds × 40 clips) | tracker | better RANSAC | margin |",
        seeds.len()
    );
    println!("|---|---|---|---|");
    for c in &order {
        let s = sums.get(c).copied().unwrap_or_default();
        println!(
            "| {c} | {:.3} | {:.3} | {:+.3} |",
            s[0] / n,
            s[1] / n,
            s[2] / n
        );
    }
    Ok(())
}
