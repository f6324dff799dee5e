//! Why predictions are false positives: the replay of `stjpdacf demo` (40 bundled labels × 20
//! frames, seed 1, coupled B, default configuration) scored on every labelled frame; each
//! unmatched prediction is classified against the ground-truth lane it fits best:
//! * `spurious`: fewer than half of the rows both have are within the threshold (no marking
//!   there: clutter, a distractor, a lane on the wrong side);
//! * `lateral`: at least half, but fewer than 85 %, of the common rows are within the threshold
//!   (the right marking, off by more than 20 px in places);
//! * `over-run` / `under-run`: ≥ 85 % of the common rows are within the threshold, so the
//!   extent decides: the prediction has rows the label does not (over-run) or misses rows it
//!   has (under-run), whichever costs more;
//! * `duplicate` is counted as well when that label is matched by another prediction.
//!
//! `cargo run --release -p stjpdacf-tools --example fp_diag [low|mid|high ...]`
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::metric;
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track::{self, Space};
use stjpdacf_tools::tusimple;

#[derive(Default, Debug)]
struct Tally {
    frames: usize,
    preds: usize,
    gts: usize,
    fp: usize,
    spurious: usize,
    lateral: usize,
    over_run: usize,
    under_run: usize,
    duplicate: usize,
    over_rows: usize,
    under_rows: usize,
}

fn main() -> anyhow::Result<()> {
    let levels: Vec<NoiseLevel> = {
        let a: Vec<String> = std::env::args().skip(1).collect();
        if a.is_empty() {
            vec![NoiseLevel::Low, NoiseLevel::Mid, NoiseLevel::High]
        } else {
            a.iter()
                .map(|s| match s.as_str() {
                    "low" => NoiseLevel::Low,
                    "high" => NoiseLevel::High,
                    _ => NoiseLevel::Mid,
                })
                .collect()
        }
    };
    let labels = tusimple::read_labels(
        &stjpdacf_tools::repo_root().join("data/tusimple/train_subset.json"),
    )?;
    let cam = Camera::tusimple();
    println!("| noise | scored | frames | preds/frame | gts/frame | FP/pred | spurious | lateral | over-run | under-run | duplicate | over rows/FP | under rows/FP |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for level in levels {
        let o = synth::synthesize(&labels, &SynthParams::preset(level), &cam, 1)?;
        let (preds, _) = track::track_with(
            &o.frames,
            &stjpdacf::tables::DEFAULT,
            &cam,
            Space::Image,
            TrackerConfig::DEFAULT,
            |_| {},
        )?;
        for (scored, gts) in [("last", &o.gt_last), ("all", &o.gt_all)] {
            let mut t = Tally::default();
            for g in gts.iter() {
                let Some(p) = preds.iter().find(|p| p.raw_file == g.raw_file) else {
                    continue;
                };
                t.frames += 1;
                t.preds += p.lanes.len();
                t.gts += g.lanes.len();
                let m = metric::match_lanes(&p.lanes, &g.lanes, &g.h_samples);
                for (i, pl) in p.lanes.iter().enumerate() {
                    if m.pred_matched[i] {
                        continue;
                    }
                    t.fp += 1;
                    // The label this prediction fits best on the common rows.
                    let mut best: Option<(f64, usize, usize, usize, usize)> = None;
                    for (k, gl) in g.lanes.iter().enumerate() {
                        let th = metric::lane_threshold(metric::lane_angle(gl, &g.h_samples));
                        let (mut common, mut ok, mut over, mut under) = (0, 0, 0, 0);
                        for (a, b) in pl.iter().zip(gl) {
                            match (*a >= 0.0, *b >= 0.0) {
                                (true, true) => {
                                    common += 1;
                                    if (a - b).abs() < th {
                                        ok += 1;
                                    }
                                }
                                (true, false) => over += 1,
                                (false, true) => under += 1,
                                _ => {}
                            }
                        }
                        let frac = if common > 0 {
                            ok as f64 / common as f64
                        } else {
                            0.0
                        };
                        if best.is_none_or(|b| frac > b.0) {
                            best = Some((frac, k, over, under, common));
                        }
                    }
                    match best {
                        Some((f, k, over, under, _)) if f >= 0.5 => {
                            if m.gt_match.get(k).copied().flatten().is_some() {
                                t.duplicate += 1;
                            }
                            if f < 0.85 {
                                t.lateral += 1;
                            } else if over >= under {
                                t.over_run += 1;
                            } else {
                                t.under_run += 1;
                            }
                            t.over_rows += over;
                            t.under_rows += under;
                        }
                        _ => t.spurious += 1,
                    }
                }
            }
            let f = t.frames.max(1) as f64;
            let fp = t.fp.max(1) as f64;
            println!(
                "| {level:?} | {scored} | {} | {:.2} | {:.2} | {:.3} | {} | {} | {} | {} | {} | {:.1} | {:.1} |",
                t.frames,
                t.preds as f64 / f,
                t.gts as f64 / f,
                t.fp as f64 / t.preds.max(1) as f64,
                t.spurious,
                t.lateral,
                t.over_run,
                t.under_run,
                t.duplicate,
                t.over_rows as f64 / fp,
                t.under_rows as f64 / fp,
            );
        }
    }
    Ok(())
}
