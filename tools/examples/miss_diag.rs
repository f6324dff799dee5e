//! Where the replay's scored accuracy goes: the demo's replay (40 bundled labels × 20 frames,
//! seed 1, coupled B, default configuration) at one noise level; every labelled row of every
//! labelled lane of the scored last frames that its best prediction gets wrong, classified as
//! under-run (label there, prediction not), over-run (prediction there, label not) or lateral
//! (both, ≥ the threshold apart), by image row band; lanes with no prediction on ≥ half their
//! rows are counted apart as absent. The over-run rows are split by where they lie against the
//! label: beyond its far end, in a gap of it, or below its near end (a label with no point, as
//! some of TuSimple's are, puts every row of its best prediction there; `V=1` lists them).
//!
//! `cargo run --release -p stjpdacf-tools --example miss_diag [-- low|mid|high]`
//! (`MISS_DIAG_DISTRACTORS=3`: the robustness curve's distractor segments per frame; `LOW=1`
//! prints each labelled lane whose best prediction scores below 0.6, with the predictions).
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::metric;
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track::{self, Space};

fn main() -> anyhow::Result<()> {
    let level = match std::env::args().nth(1).as_deref() {
        Some("low") => NoiseLevel::Low,
        Some("high") => NoiseLevel::High,
        _ => NoiseLevel::Mid,
    };
    let labels = stjpdacf_tools::demo::replay_labels()?;
    let cam = Camera::tusimple();
    let mut params = SynthParams::preset(level);
    if let Some(k) = std::env::var("MISS_DIAG_DISTRACTORS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        params.distractors = k;
    }
    let o = synth::synthesize(&labels, &params, &cam, 1)?;
    let gt_index = o.gt_index();
    let last: std::collections::HashSet<&str> =
        o.gt_last.iter().map(|g| g.raw_file.as_str()).collect();
    // bands of 100 px from y = 160 (the labels' 720p rows)
    let mut under = [0usize; 6];
    let mut over = [0usize; 6];
    let mut lateral = [0usize; 6];
    let mut rows_total = 0usize;
    let mut absent_rows = 0usize;
    let mut absent = 0usize;
    let mut lanes = 0usize;
    let mut acc_hist = [0usize; 6];
    // over-run rows above the label's top, inside its extent (a gap), below its bottom
    let mut over_where = [0usize; 3];
    track::track_with(
        &o.frames,
        &stjpdacf::tables::DEFAULT,
        &cam,
        Space::Image,
        TrackerConfig::DEFAULT,
        |v| {
            let Some(p) = v.prediction else { return };
            let Some(&j) = gt_index.get(p.raw_file.as_str()) else {
                return;
            };
            if !last.contains(p.raw_file.as_str()) {
                return;
            }
            let g = &o.gt_all[j];
            for gl in &g.lanes {
                lanes += 1;
                rows_total += gl.len();
                let th = metric::lane_threshold(metric::lane_angle(gl, &g.h_samples));
                let best = p
                    .lanes
                    .iter()
                    .map(|pl| (metric::line_accuracy(pl, gl, th), pl))
                    .max_by(|a, b| a.0.total_cmp(&b.0));
                let acc = best.as_ref().map_or(0.0, |b| b.0);
                let bin = if acc >= 0.99 {
                    5
                } else {
                    ((acc * 5.0) as usize).min(4)
                };
                acc_hist[bin] += 1;
                if acc < 0.6 && std::env::var("LOW").is_ok() {
                    // Every sixth labelled row of the label and of each prediction, `row:column`.
                    let cols = |l: &Vec<f64>| -> String {
                        l.iter()
                            .zip(&g.h_samples)
                            .filter(|(x, _)| **x >= 0.0)
                            .step_by(6)
                            .map(|(x, y)| format!("{y}:{x:.0}"))
                            .collect::<Vec<_>>()
                            .join(" ")
                    };
                    println!("LOW {} acc {acc:.2} label {}", p.raw_file, cols(gl));
                    for pl in &p.lanes {
                        println!("    prediction {}", cols(pl));
                    }
                }
                let Some((_, pl)) = best else {
                    absent += 1;
                    absent_rows += gl.iter().filter(|x| **x >= 0.0).count();
                    continue;
                };
                let common = pl
                    .iter()
                    .zip(gl)
                    .filter(|(a, b)| **a >= 0.0 && **b >= 0.0)
                    .count();
                let present = gl.iter().filter(|x| **x >= 0.0).count();
                if 2 * common < present {
                    absent += 1;
                    absent_rows += present;
                    continue;
                }
                let top = gl.iter().position(|x| *x >= 0.0).unwrap_or(0);
                let bottom = gl.iter().rposition(|x| *x >= 0.0).unwrap_or(0);
                for (r, ((a, b), y)) in pl.iter().zip(gl).zip(&g.h_samples).enumerate() {
                    if *a >= 0.0 && *b < 0.0 {
                        let k = if r < top {
                            0
                        } else if r > bottom {
                            2
                        } else {
                            1
                        };
                        over_where[k] += 1;
                        if r > bottom && std::env::var("V").is_ok() {
                            let xb = gl[bottom];
                            println!(
                                "{} lane bottom row {} x {xb:.0}, pred row {} x {a:.0}",
                                p.raw_file, g.h_samples[bottom], y
                            );
                        }
                    }
                    let band = (((*y - 160.0) / 100.0).max(0.0) as usize).min(5);
                    match (*a >= 0.0, *b >= 0.0) {
                        (false, true) => under[band] += 1,
                        (true, false) => over[band] += 1,
                        (true, true) if (a - b).abs() >= th => lateral[band] += 1,
                        _ => {}
                    }
                }
            }
        },
    )?;
    println!("level {level:?}: {lanes} labelled lanes, {rows_total} rows; absent lanes {absent} ({absent_rows} rows)");
    println!("accuracy of the best prediction: <0.2 {} | <0.4 {} | <0.6 {} | <0.8 {} | <0.99 {} | ≥0.99 {}", acc_hist[0], acc_hist[1], acc_hist[2], acc_hist[3], acc_hist[4], acc_hist[5]);
    println!("over-run rows: above the label's far end {}, in a gap of the label {}, below its near end {}", over_where[0], over_where[1], over_where[2]);
    println!("| rows wrong (720p rows) | 160–250 | 260–350 | 360–450 | 460–550 | 560–650 | 660–710 | total |");
    println!("|---|---|---|---|---|---|---|---|");
    for (name, a) in [
        ("under-run", under),
        ("over-run", over),
        ("lateral", lateral),
    ] {
        println!(
            "| {name} | {} | {} | {} | {} | {} | {} | {} |",
            a[0],
            a[1],
            a[2],
            a[3],
            a[4],
            a[5],
            a.iter().sum::<usize>()
        );
    }
    Ok(())
}
