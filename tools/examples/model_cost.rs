//! What a smaller model costs in accuracy (issue "Fit the MCU": if the instruction targets need
//! a model change, which one, at what accuracy), on the replay of `stjpdacf demo` (40 bundled
//! labels × 20 frames, seed 1, coupled B), scored with the official metric:
//!
//! 1. the default tables with the Gram truncation `gram_rank` lowered (the dropped components
//!    go to the residual variance `ρ_r`, docs/design.md §4.1), the labelled last frames;
//! 2. the exact fixed-lag smoother against the per-lane one (`TrackerConfig::smoother_per_lane`,
//!    docs/design.md §5.1): the filtered and the smoothed lanes on every frame that has a
//!    smoothed estimate (the demo's smoother table);
//! 3. the known-lane rows' association (`PersistConfig::association`, docs/design.md §11.3):
//!    exact enumeration (pruned over the budget), LBP over the budget, LBP on every row; the
//!    labelled last frames, with the events enumerated and the rows pruned or weighed by LBP;
//! 4. the uncoupled model (`tables::UNCOUPLED`, docs/design.md §4.2.6) alone and with the
//!    cheaper options of 1 and 3 on top (LBP on every row, Gram rank 5, 4, 3): the labelled
//!    last frames;
//! 5. fewer rows: K = 4 (the default), 3 and 2 rows per index interval
//!    (`TrackerConfig::with_rows_per_interval`, every row count rescaled to keep its metres),
//!    uncoupled and coupled B: the labelled last frames;
//! 6. the smaller uncoupled models (LBP on every row, Gram rank 7, 5, 4, 3) and the coupled
//!    model at Gram rank 5 and 4 on the demo's robustness curve and held-out check, next to the
//!    per-frame RANSAC fit.
//!
//! The instructions per frame of the same models on the Cortex-M4F come from
//! `STJPDACF_FW_RANK=r` / `STJPDACF_FW_PER_LANE=1` / `STJPDACF_FW_ASSOC=lbp|hybrid` /
//! `STJPDACF_FW_TABLES=uncoupled cargo xtask firmware` (docs/measurements.md,
//! "Fitting the MCU").
//!
//! `cargo run --release -p stjpdacf-tools --example model_cost [rank ...]` (all sections; the
//! ranks given, or 7 down to 3), `... --example model_cost assoc` (section 3 only),
//! `... --example model_cost uncoupled` (section 4 only), `... --example model_cost rows`
//! (section 5 only), `... --example model_cost small` (section 6 only). `MODEL_COST_SEED=N`
//! replays synth seed N instead of the demo's 1 in sections 1 to 5.
use stjpdacf::persist::PersistConfig;
use stjpdacf::spatial::row::Association;
use stjpdacf::tables::{ReferenceTables, DEFAULT, UNCOUPLED};
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo::{self, Coupling, DemoOptions, Input};
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track;

/// The default tables truncated to `rank` Gram components, with the variance fraction they keep.
fn truncated(rank: u32) -> ReferenceTables {
    track::truncated(&DEFAULT, rank)
}

fn main() -> anyhow::Result<()> {
    let only_assoc = std::env::args().nth(1).as_deref() == Some("assoc");
    let only_uncoupled = std::env::args().nth(1).as_deref() == Some("uncoupled");
    let only_rows = std::env::args().nth(1).as_deref() == Some("rows");
    let only_small = std::env::args().nth(1).as_deref() == Some("small");
    let ranks: Vec<u32> = {
        let a: Vec<u32> = std::env::args()
            .skip(1)
            .filter(|s| s != "assoc" && s != "uncoupled" && s != "rows" && s != "small")
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
    // MODEL_COST_SEED=N: the replay's synth seed (default 1, the demo's) for sections 1 to 5.
    let seed: u64 = match std::env::var("MODEL_COST_SEED") {
        Ok(v) => v.parse()?,
        Err(_) => 1,
    };
    let replays = levels
        .into_iter()
        .map(|l| synth::synthesize(&labels, &SynthParams::preset(l), &cam, seed).map(|o| (l, o)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    if only_uncoupled {
        return uncoupled(&replays);
    }
    if only_rows {
        return rows(&replays);
    }
    if only_small {
        return small();
    }
    if !only_assoc {
        gram(&ranks, &replays)?;
    }
    association(&replays)?;
    if !only_assoc {
        smoother(&levels)?;
        uncoupled(&replays)?;
        rows(&replays)?;
        small()?;
    }
    Ok(())
}

/// Section 4.
fn uncoupled(replays: &Replays) -> anyhow::Result<()> {
    println!("\nThe uncoupled model and cheaper options on top (labelled last frames):\n");
    println!("| model | noise | accuracy | FP | FN | host ms/frame |");
    println!("|---|---|---|---|---|---|");
    let lbp = TrackerConfig {
        persist: PersistConfig {
            association: Association::Lbp,
            ..PersistConfig::DEFAULT
        },
        ..TrackerConfig::DEFAULT
    };
    let r5: &'static ReferenceTables = Box::leak(Box::new(track::truncated(&UNCOUPLED, 5)));
    let r4: &'static ReferenceTables = Box::leak(Box::new(track::truncated(&UNCOUPLED, 4)));
    let r3: &'static ReferenceTables = Box::leak(Box::new(track::truncated(&UNCOUPLED, 3)));
    let models: [(&str, &'static ReferenceTables, TrackerConfig); 6] = [
        ("coupled B (default)", &DEFAULT, TrackerConfig::DEFAULT),
        ("uncoupled B", &UNCOUPLED, TrackerConfig::DEFAULT),
        ("uncoupled B, LBP every row", &UNCOUPLED, lbp),
        ("uncoupled B, LBP every row, rank 5", r5, lbp),
        ("uncoupled B, LBP every row, rank 4", r4, lbp),
        ("uncoupled B, LBP every row, rank 3", r3, lbp),
    ];
    for (name, tables, config) in models {
        for (level, o) in replays {
            let (s, st) = demo::score_replay_last(o, tables, config)?;
            println!(
                "| {name} | {level:?} | {:.3} | {:.3} | {:.3} | {:.3} |",
                s.accuracy, s.fp, s.fn_, st.step_mean_ms
            );
        }
    }
    Ok(())
}

/// Section 6: the smaller models on the demo's robustness curve and held-out check,
/// next to the per-frame RANSAC fit (their accuracy and margin over it).
fn small() -> anyhow::Result<()> {
    let lbp = TrackerConfig {
        persist: PersistConfig {
            association: Association::Lbp,
            ..PersistConfig::DEFAULT
        },
        ..TrackerConfig::DEFAULT
    };
    let mut variants = vec![
        demo::Variant::new("coupled B (default)", TrackerConfig::DEFAULT),
        demo::Variant {
            tables: &UNCOUPLED,
            ..demo::Variant::new("uncoupled B", TrackerConfig::DEFAULT)
        },
    ];
    for rank in [7u32, 5, 4, 3] {
        let tables: &'static ReferenceTables =
            Box::leak(Box::new(track::truncated(&UNCOUPLED, rank)));
        variants.push(demo::Variant {
            tables,
            ..demo::Variant::new(&format!("uncoupled B, LBP every row, rank {rank}"), lbp)
        });
    }
    for rank in [5u32, 4] {
        let tables: &'static ReferenceTables = Box::leak(Box::new(truncated(rank)));
        variants.push(demo::Variant {
            tables,
            ..demo::Variant::new(&format!("coupled B, rank {rank}"), TrackerConfig::DEFAULT)
        });
    }
    let opts = DemoOptions {
        out: std::env::temp_dir().join("stjpdacf_model_cost_small"),
        levels: vec![NoiseLevel::Mid],
        images: false,
        score_run_time: false,
        robustness_variants: variants,
        ..DemoOptions::default()
    };
    let report = demo::run(&opts, |_, _, _| {})?;
    println!("\nSmaller models: accuracy (margin over the per-frame RANSAC fit) per condition\n");
    let print = |section: &str, rows: Vec<(String, Vec<demo::VariantScore>, f64)>| {
        for (cond, trackers, base) in rows {
            for t in trackers {
                println!(
                    "| {section} | {cond} | {} | {:.3} / {:.3} / {:.3} | {:+.3} | {base:.3} |",
                    t.name, t.score.accuracy, t.score.fp, t.score.fn_, t.accuracy_minus_baseline
                );
            }
        }
    };
    println!("| section | condition | model | accuracy / FP / FN | margin | RANSAC |");
    println!("|---|---|---|---|---|---|");
    if let Some(r) = report.robustness {
        print(
            "robustness",
            r.rows
                .into_iter()
                .map(|row| (row.condition, row.trackers, row.baseline.accuracy))
                .collect(),
        );
    }
    if let Some(h) = report.heldout {
        // The held-out check's bar is against the baseline capped at the lanes a road has.
        print(
            "held-out (margin over the capped RANSAC fit)",
            h.rows
                .into_iter()
                .map(|row| {
                    let base = row.baseline_capped.accuracy;
                    let trackers = row
                        .trackers
                        .into_iter()
                        .map(|t| demo::VariantScore {
                            accuracy_minus_baseline: t.score.accuracy - base,
                            ..t
                        })
                        .collect();
                    (row.condition, trackers, base)
                })
                .collect(),
        );
    }
    Ok(())
}

/// Section 5.
fn rows(replays: &Replays) -> anyhow::Result<()> {
    println!(
        "\nRows per index interval K (TrackerConfig::with_rows_per_interval; labelled last frames):\n"
    );
    println!("| tables | K | rows | noise | accuracy | FP | FN | host ms/frame |");
    println!("|---|---|---|---|---|---|---|---|");
    for (name, tables) in [("uncoupled B", &UNCOUPLED), ("coupled B", &DEFAULT)] {
        for k in [4u8, 3, 2] {
            let config = TrackerConfig::DEFAULT.with_rows_per_interval(k);
            for (level, o) in replays {
                let (s, st) = demo::score_replay_last(o, tables, config)?;
                println!(
                    "| {name} | {k} | {} | {level:?} | {:.3} | {:.3} | {:.3} | {:.3} |",
                    (DEFAULT.gram_eigval.len() - 1) * usize::from(k) + 1,
                    s.accuracy,
                    s.fp,
                    s.fn_,
                    st.step_mean_ms
                );
            }
        }
    }
    Ok(())
}

type Replays = [(NoiseLevel, synth::SynthOutput)];

/// Section 1.
fn gram(ranks: &[u32], replays: &Replays) -> anyhow::Result<()> {
    println!("Gram truncation (labelled last frames):\n");
    println!("| Gram rank | variance kept | noise | accuracy | FP | FN | host ms/frame |");
    println!("|---|---|---|---|---|---|---|");
    for &rank in ranks {
        let tables: &'static ReferenceTables = Box::leak(Box::new(truncated(rank)));
        tables
            .validate()
            .map_err(|e| anyhow::anyhow!("rank {rank}: {e:?}"))?;
        for (level, o) in replays {
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
    Ok(())
}

/// Section 3.
fn association(replays: &Replays) -> anyhow::Result<()> {
    println!(
        "\nKnown-lane association (labelled last frames, events per frame over all frames):\n"
    );
    println!("| association | noise | accuracy | FP | FN | events / frame | pruned rows / frame | LBP rows / frame | host ms/frame |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for (name, association) in [
        ("exact (pruned over budget)", Association::Exact),
        ("exact, LBP over budget", Association::ExactOrLbp),
        ("LBP every row", Association::Lbp),
    ] {
        let config = TrackerConfig {
            persist: PersistConfig {
                association,
                ..PersistConfig::DEFAULT
            },
            ..TrackerConfig::DEFAULT
        };
        for (level, o) in replays {
            let (s, st) = demo::score_replay_last(o, &DEFAULT, config)?;
            let per = |v: u64| v as f64 / st.frames.max(1) as f64;
            println!(
                "| {name} | {level:?} | {:.3} | {:.3} | {:.3} | {:.1} | {:.3} | {:.3} | {:.3} |",
                s.accuracy,
                s.fp,
                s.fn_,
                per(st.known_events),
                per(st.known_pruned_rows),
                per(st.known_lbp_rows),
                st.step_mean_ms
            );
        }
    }
    Ok(())
}

/// Section 2.
fn smoother(levels: &[NoiseLevel]) -> anyhow::Result<()> {
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
            heldout_clips: 0,
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
