//! What a smaller model costs in accuracy (issue "Fit the MCU": if the instruction targets need
//! a model change, which one, at what accuracy), on the replay of `stjpdacf demo` (40 bundled
//! labels × 20 frames, seed 1, coupled B), scored with the official metric:
//!
//! 1. the default tables with the Gram truncation `gram_rank` lowered (the dropped components
//!    go to the residual variance `ρ_r`, docs/design.md §4.1), the labelled last frames;
//! 2. the exact fixed-lag smoother against the per-lane one (`TrackerConfig::smoother_per_lane`,
//!    docs/design.md §5.1): the filtered and the smoothed lanes on every frame that has a
//!    smoothed estimate (the demo's smoother table).
//!
//! The instructions per frame of the same models on the Cortex-M4F come from
//! `STJPDACF_FW_RANK=r` / `STJPDACF_FW_PER_LANE=1 cargo xtask firmware` (docs/measurements.md,
//! "Fitting the MCU").
//!
//! `cargo run --release -p stjpdacf-tools --example model_cost [rank ...]`
use stjpdacf::tables::{ReferenceTables, DEFAULT};
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo::{self, Coupling, DemoOptions, Input};
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};

/// The default tables truncated to `rank` Gram components, with the variance fraction they keep.
fn truncated(rank: u32) -> ReferenceTables {
    let mut t = DEFAULT;
    t.gram_rank = rank.clamp(1, DEFAULT.gram_rank);
    let ev = t.gram_eigval.as_slice();
    let total: f32 = ev.iter().sum();
    let kept: f32 = ev.iter().take(t.gram_rank as usize).sum();
    t.hyper.gram_variance_fraction = if total > 0.0 { kept / total } else { 1.0 };
    t
}

fn main() -> anyhow::Result<()> {
    let ranks: Vec<u32> = {
        let a: Vec<u32> = std::env::args()
            .skip(1)
            .map(|s| s.parse())
            .collect::<Result<_, _>>()?;
        if a.is_empty() {
            (3..=DEFAULT.gram_rank).rev().collect()
        } else {
            a
        }
    };
    let labels = demo::replay_labels()?;
    let cam = Camera::tusimple();
    let levels = [NoiseLevel::Low, NoiseLevel::Mid, NoiseLevel::High];
    let replays = levels
        .into_iter()
        .map(|l| synth::synthesize(&labels, &SynthParams::preset(l), &cam, 1).map(|o| (l, o)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    println!("Gram truncation (labelled last frames):\n");
    println!("| Gram rank | variance kept | noise | accuracy | FP | FN | host ms/frame |");
    println!("|---|---|---|---|---|---|---|");
    for rank in ranks {
        let tables: &'static ReferenceTables = Box::leak(Box::new(truncated(rank)));
        tables
            .validate()
            .map_err(|e| anyhow::anyhow!("rank {rank}: {e:?}"))?;
        for (level, o) in &replays {
            let (s, stats) = demo::score_replay_last(o, tables, TrackerConfig::DEFAULT)?;
            println!(
                "| {} | {:.6} | {level:?} | {:.3} | {:.3} | {:.3} | {:.3} |",
                tables.gram_rank,
                tables.hyper.gram_variance_fraction,
                s.accuracy,
                s.fp,
                s.fn_,
                stats.step_mean_ms
            );
        }
    }
    println!("\nSmoother (every frame with a smoothed estimate, coupled B):\n");
    println!("| smoother | noise | frames | filtered acc/FP/FN | smoothed acc/FP/FN |");
    println!("|---|---|---|---|---|");
    let out = std::env::temp_dir().join("stjpdacf_model_cost");
    for (name, per_lane) in [("exact", false), ("per lane", true)] {
        let opts = DemoOptions {
            out: out.clone(),
            levels: levels.to_vec(),
            images: false,
            score_run_time: false,
            robustness_clips: 0,
            config: TrackerConfig {
                smoother_per_lane: per_lane,
                ..TrackerConfig::DEFAULT
            },
            ..DemoOptions::default()
        };
        let report = demo::run(&opts, |_, _, _| {})?;
        for row in report
            .rows
            .iter()
            .filter(|r| matches!(r.input, Input::Replay) && matches!(r.coupling, Coupling::Coupled))
        {
            let Some(sm) = row.smoother else { continue };
            let (f, s) = (sm.filtered, sm.smoothed);
            println!(
                "| {name} | {:?} | {} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} |",
                row.noise.unwrap_or(NoiseLevel::Mid),
                sm.frames,
                f.accuracy,
                f.fp,
                f.fn_,
                s.accuracy,
                s.fp,
                s.fn_
            );
        }
    }
    Ok(())
}
