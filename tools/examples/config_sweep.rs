//! The demo's tables (replay, identity, robustness curve of seed 1, held-out check) for one
//! configuration given on the command line, without images: how a design choice moves every
//! figure the issues quote, in one run (~4 min on one core).
//!
//! `cargo run --release -p stjpdacf-tools --example config_sweep -- [seed=N] [field=value ...]`
//! (`seed`: the replay's and the robustness curve's synth seed, default 1)
//! with fields of `PersistConfig`: `ray_z`, `ray_resolution` (`inf` allowed),
//! `ray_aligned` / `ray_motion` (0 or 1), `lane_width` (metres, 0: off), `gap_misses`, `chain_gap` / `chain_paint` / `chain_p_on` (the paint /
//! gap chain's mean gap and paint in metres, its detection on paint), `chain_memory` (frames;
//! 0 keeps the configured gap); of the spatial `Config`: `max_tentative`; of the identity
//! `Config`: `min_common` (the index points a lane needs to start and to be matched).
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::demo::{self, DemoOptions, Variant};

fn main() -> anyhow::Result<()> {
    let mut config = TrackerConfig::DEFAULT;
    let mut seed = 1u64;
    for arg in std::env::args().skip(1) {
        let (k, v) = arg
            .split_once('=')
            .ok_or_else(|| anyhow::anyhow!("expected field=value, got {arg}"))?;
        let x: f32 = v.parse()?;
        match k {
            "seed" => seed = v.parse()?,
            "ray_z" => config.persist.ray_z = x,
            "ray_resolution" => config.persist.ray_resolution = x,
            "ray_aligned" => config.persist.ray_aligned = x != 0.0,
            "ray_motion" => config.persist.ray_motion = x != 0.0,
            "lane_width" => config.persist.lane_width = x,
            "slot_claims" => config.persist.slot_claims = x != 0.0,
            "own_pd" => config.persist.own_pd = x != 0.0,
            "newcomer_wait" => config.persist.newcomer_wait = x as u8,
            "max_tentative" => config.spatial.max_tentative = x as u8,
            "min_common" => config.identity.min_common = x as u8,
            "gap_misses" => config.persist.gap_misses = x as u16,
            "chain_memory" => config.persist.chain_memory = x,
            "chain_gap" | "chain_paint" | "chain_p_on" => {
                let c = config
                    .persist
                    .paint_gap
                    .as_mut()
                    .ok_or_else(|| anyhow::anyhow!("no paint / gap chain"))?;
                match k {
                    "chain_gap" => c.gap = x,
                    "chain_paint" => c.paint = x,
                    _ => c.p_on = x,
                }
            }
            _ => anyhow::bail!("unknown field {k}"),
        }
    }
    let opts = DemoOptions {
        out: std::env::temp_dir().join("stjpdacf_config_sweep"),
        images: false,
        score_run_time: false,
        seed,
        robustness_variants: vec![Variant::new("tracker", config)],
        config,
        ..DemoOptions::default()
    };
    let report = demo::run(&opts, |_, _, _| {})?;
    println!("{}", demo::render_markdown(&report));
    Ok(())
}
