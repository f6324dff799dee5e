//! The long soak: seeded drives through the core tracker (never reset) and, side by side in
//! episodes, the dense f64 reference (`stjpdacf_test_support::soak`). Prints and writes a JSON summary.
//!
//! ```sh
//! cargo run --release -p stjpdacf-test-support --example soak -- --frames 1000000 --threads 2 --out soak.json
//! ```

use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use stjpdacf_test_support::soak::{run, SoakConfig};

/// Soak of the core tracker against the f64 reference.
#[derive(Debug, Parser)]
struct Args {
    /// Frames in total (30 fps: 1,000,000 frames ≈ 9.3 h of driving).
    #[arg(long, default_value_t = 1_000_000)]
    frames: u64,
    /// Base seed (shard i drives with seed + i).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Independent drives the frames are split into.
    #[arg(long, default_value_t = 8)]
    shards: usize,
    /// Worker threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Core only (no f64 reference).
    #[arg(long)]
    no_reference: bool,
    /// Frames per comparison episode.
    #[arg(long, default_value_t = 3_000)]
    episode: u64,
    /// Run the f64 reference in one episode out of this many (1: compare every frame).
    #[arg(long, default_value_t = 1)]
    compare_every: u64,
    /// Compare the smoothed lanes every this many frames (0: never).
    #[arg(long, default_value_t = 30)]
    smooth_every: u64,
    /// Full eigen-decomposition of the covariance every this many frames.
    #[arg(long, default_value_t = 10)]
    health_every: u64,
    /// Track with the uncoupled tables (`tables::UNCOUPLED`, docs/design.md §4.2.6).
    #[arg(long)]
    uncoupled: bool,
    /// Write the JSON summary here.
    #[arg(long)]
    out: Option<PathBuf>,
}

fn main() -> Result<()> {
    let a = Args::parse();
    let cfg = SoakConfig {
        frames: a.frames,
        seed: a.seed,
        shards: a.shards,
        threads: a.threads,
        reference: !a.no_reference,
        episode: a.episode,
        compare_every: a.compare_every,
        smooth_every: a.smooth_every,
        health_every: a.health_every,
        uncoupled: a.uncoupled,
    };
    let bar = ProgressBar::new(cfg.frames);
    bar.set_style(ProgressStyle::with_template(
        "{elapsed_precise} [{bar:40}] {pos}/{len} frames ({per_sec}, eta {eta})",
    )?);
    let t0 = std::time::Instant::now();
    // Without a terminal the bar is hidden: log a line a minute to stderr instead.
    let hidden = bar.is_hidden();
    let last_log = std::sync::Mutex::new(std::time::Instant::now());
    let summary = run(&cfg, &|n| {
        bar.set_position(n);
        if let Ok(mut l) = last_log.lock() {
            if hidden && l.elapsed().as_secs() >= 60 {
                *l = std::time::Instant::now();
                eprintln!(
                    "{:.0} s: {n}/{} frames",
                    t0.elapsed().as_secs_f64(),
                    cfg.frames
                );
            }
        }
    })?;
    bar.finish();
    let json = serde_json::json!({
        "config": cfg,
        "wall_seconds": t0.elapsed().as_secs_f64(),
        "summary": summary,
    });
    let text = serde_json::to_string_pretty(&json)?;
    println!("{text}");
    if let Some(p) = a.out {
        std::fs::write(p, text)?;
    }
    Ok(())
}
