//! The ablation "no temporal prior" (docs/design.md §11): the replay of `stjpdacf demo` (40
//! bundled labels × 20 frames, seed 1, coupled B) tracked with `TrackerConfig::DEFAULT` and
//! with `TrackerConfig::ROUND1`, scored on the labelled last frames with the official metric.
//! `cargo run --release -p stjpdacf-tools --example ablation`
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo;
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};

fn main() -> anyhow::Result<()> {
    let labels = demo::replay_labels()?;
    let cam = Camera::tusimple();
    println!("| noise | configuration | accuracy | FP | FN |");
    println!("|---|---|---|---|---|");
    for level in [NoiseLevel::Low, NoiseLevel::Mid, NoiseLevel::High] {
        let o = synth::synthesize(&labels, &SynthParams::preset(level), &cam, 1)?;
        for (name, cfg) in [
            ("known lanes (default)", TrackerConfig::DEFAULT),
            ("no temporal prior (ROUND1)", TrackerConfig::ROUND1),
        ] {
            let (s, _) = demo::score_replay_last(&o, &stjpdacf::tables::DEFAULT, cfg)?;
            println!(
                "| {level:?} | {name} | {:.3} | {:.3} | {:.3} |",
                s.accuracy, s.fp, s.fn_
            );
        }
    }
    Ok(())
}
