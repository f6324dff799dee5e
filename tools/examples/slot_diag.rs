//! Where the candidates go when the lane table is full (docs/design.md §11.13): the demo's
//! replay (40 bundled labels × 20 frames, seed 1, low / mid / high) and held-out check (clutter
//! × 1 / × 2 / × 4 / × 8), default tracker configuration; per run the frames whose 6 slots are
//! all taken after the step, the candidates turned away for want of a slot
//! (`IdentityReport::dropped_no_slot`), the lanes that yielded their slot
//! (`IdentityReport::evicted`), the lanes started, and the live lanes' existence (lane-frames).
//!
//! `cargo run --release -p stjpdacf-tools --example slot_diag` (`slot_claims=0` for the rule of
//! before stop 43).
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::heldout::{self, HeldoutParams};
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track::{self, Space};
use stjpdacf_tools::tusimple::Frame;

fn main() -> anyhow::Result<()> {
    let mut config = TrackerConfig::DEFAULT;
    for a in std::env::args().skip(1) {
        match a.as_str() {
            "slot_claims=0" => config.persist.slot_claims = false,
            "slot_claims=1" => config.persist.slot_claims = true,
            _ => anyhow::bail!("unknown argument {a} (slot_claims=0|1)"),
        }
    }
    let cam = Camera::tusimple();
    let mut runs: Vec<(String, Vec<Frame>)> = Vec::new();
    let replay = stjpdacf_tools::demo::replay_labels()?;
    for level in [NoiseLevel::Low, NoiseLevel::Mid, NoiseLevel::High] {
        let o = synth::synthesize(&replay, &SynthParams::preset(level), &cam, 1)?;
        runs.push((format!("replay {level:?}"), o.frames));
    }
    let held = heldout::bundled_labels()?;
    for m in [1.0, 2.0, 4.0, 8.0] {
        let base = HeldoutParams::default();
        let params = HeldoutParams {
            clutter_density: base.clutter_density * m,
            ..base.clone()
        };
        let o = heldout::generate(&held, &params, &cam, 1)?;
        runs.push((format!("held-out × {m}"), o.frames));
    }
    println!("| run | frames | slots all taken | turned away (no slot) | yielded their slot | lanes started | live lanes P < 0.05 / 0.05–0.2 / 0.2–0.5 / 0.5–0.9 / ≥ 0.9 (lane-frames) |");
    println!("|---|---|---|---|---|---|---|");
    for (name, frames) in &runs {
        let (mut n, mut full, mut no_slot, mut evicted, mut started) =
            (0usize, 0usize, 0u64, 0u64, 0u64);
        let mut hist = [0usize; 5];
        track::track_with(
            frames,
            &stjpdacf::tables::DEFAULT,
            &cam,
            Space::Image,
            config,
            |v| {
                n += 1;
                let mut live = 0;
                for s in 0..6 {
                    let Some(l) = v.tracker.persist().lanes.get(s) else {
                        continue;
                    };
                    if v.tracker.lane_at(s, 10.0).is_none() {
                        continue;
                    }
                    live += 1;
                    let p = l.existence;
                    let b = [0.05, 0.2, 0.5, 0.9].iter().filter(|&&e| p >= e).count();
                    hist[b] += 1;
                }
                full += usize::from(live == 6);
                if let Some(out) = v.output {
                    let r = &out.report.identity;
                    no_slot += u64::from(r.dropped_no_slot);
                    evicted += u64::from(r.evicted);
                    started += u64::from(r.started);
                }
            },
        )?;
        println!(
            "| {name} | {n} | {:.0} % | {no_slot} | {evicted} | {started} | {} |",
            100.0 * full as f64 / n.max(1) as f64,
            hist.iter()
                .map(|h| h.to_string())
                .collect::<Vec<_>>()
                .join(" / ")
        );
    }
    Ok(())
}
