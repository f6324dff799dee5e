//! Does the tracker's persistence absorb the front end's per-frame fragility on real images? The
//! 10 bundled 512×288 TuSimple frames are single frames (the demo's real row), and the front
//! end's output moves with sub-pixel changes of the camera (`--example camera_sensitivity`).
//! Here each frame becomes a 20-frame clip of the same image whose camera pitches: frame `j`
//! is seen with the horizon `A·sin(2.3 j)` px off the calibration (`j` = 0…18; a vehicle's pitch
//! with a fixed calibration: the front end and the mapping to the BEV both use that frame's
//! camera), and the last, labelled frame with the calibration itself, so that its own points are
//! the single-frame row's. Front end → BEV points → the default tracker → official metric at
//! 1280×720, as the demo's real row. `A` = 0 repeats the same frame 20 times (persistence alone).
//!
//! The image does not move, so this is an optimistic stand-in for a real clip (dashes do not
//! advance, vehicles do not move): it measures what the camera's jitter costs and what the
//! tracker's persistence gives back, not a clip's accuracy.
//!
//! `cargo run --release -p stjpdacf-tools --example real_jitter` (about 30 s;
//! `REAL_JITTER_MODEL=rank5|small` for the other models of `track --model`). Also counted: the
//! frames on which the tracker repaired its temporal covariance (f32 rounding had made it
//! indefinite, docs/design.md §4.2.4) and the lanes it merged as duplicates (§11.9).
//! `REAL_JITTER_PER_FRAME=1` prints each frame's score; `REAL_JITTER_DUMP=F.jsonl` writes the
//! 20-frame clips of `A` = 0 as BEV frames (`stjpdacf track --space bev --lanes …` shows their
//! lanes frame by frame).
use std::collections::HashSet;

use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo::{self, REAL_TO_TUSIMPLE};
use stjpdacf_tools::frontend::{self, FrontendParams, TUNING_SET};
use stjpdacf_tools::metric;
use stjpdacf_tools::track::{self, Space};
use stjpdacf_tools::tusimple::{read_labels, Frame, TuSimpleRecord};

/// Frames per clip.
const FRAMES: usize = 20;

fn main() -> anyhow::Result<()> {
    let dir = stjpdacf_tools::repo_root().join("data/tusimple/sample_512x288");
    let labels = read_labels(&dir.join("label_data.json"))?;
    let p = FrontendParams::default();
    // `REAL_JITTER_MODEL=rank5|small` runs that model (`track::Model`) instead of the reference.
    let model = match std::env::var("REAL_JITTER_MODEL").as_deref() {
        Ok("rank5") => track::Model::Rank5,
        Ok("small") => track::Model::Small,
        _ => track::Model::Reference,
    };
    let base = Camera::tusimple().scaled(0.4);
    let images: Vec<_> = labels
        .iter()
        .map(|l| frontend::load_rgb(&dir.join(&l.raw_file)))
        .collect::<anyhow::Result<_>>()?;
    let scaled_gt: Vec<TuSimpleRecord> = labels
        .iter()
        .map(|g| demo::scale_record(g, REAL_TO_TUSIMPLE))
        .collect();
    println!("| clip | pitch amplitude A (px at 512×288) | accuracy / FP / FN | tuning half | held-out half | frames with a covariance repair (failed factorisations) | lanes merged | lanes started after a clip's 2nd frame |");
    println!("|---|---|---|---|---|---|---|---|");
    for (frames_per_clip, amp) in [
        (1, 0.0),
        (FRAMES, 0.0),
        (FRAMES, 0.5),
        (FRAMES, 1.0),
        (FRAMES, 2.0),
    ] {
        let mut frames = Vec::new();
        for (label, img) in labels.iter().zip(&images) {
            for j in 0..frames_per_clip {
                let last = j + 1 == frames_per_clip;
                let d = if last {
                    0.0
                } else {
                    amp * (2.3 * j as f64).sin()
                };
                let cam = Camera {
                    vp_row: base.vp_row + d,
                    ..base
                };
                let points = frontend::detect(img, &cam, &p)?
                    .iter()
                    .filter_map(|q| cam.to_bev(q[0], q[1]))
                    .map(|(u, x)| [x, u])
                    .collect();
                frames.push(Frame {
                    clip: label.raw_file.clone(),
                    t: j as f64 * 0.05,
                    points,
                    raw_file: last.then(|| label.raw_file.clone()),
                    h_samples: last.then(|| label.h_samples.clone()),
                    camera: None,
                });
            }
        }
        if let (Some(path), true) = (
            std::env::var_os("REAL_JITTER_DUMP"),
            frames_per_clip > 1 && amp == 0.0,
        ) {
            stjpdacf_tools::tusimple::write_frames(std::path::Path::new(&path), &frames)?;
        }
        // Frames whose temporal covariance the tracker repaired (failed factorisations), and the lanes
        // it merged as duplicates of another.
        let (mut repaired, mut pivots, mut merged) = (0usize, 0u64, 0u64);
        // Lane ids first published after a clip's second frame (every clip shows one static
        // scene: a lane started late is one re-born or one the first frames missed).
        let mut clip = String::new();
        let (mut in_clip, mut early, mut late) = (0usize, HashSet::new(), HashSet::new());
        let (preds, _) = track::track_with(
            &frames,
            model.tables(&DEFAULT),
            &base,
            Space::Bev,
            model.config(TrackerConfig::DEFAULT),
            |v| {
                if v.frame.clip != clip {
                    clip.clone_from(&v.frame.clip);
                    in_clip = 0;
                    early.clear();
                }
                if let Some(o) = v.output {
                    for l in o.filtered.iter() {
                        if in_clip < 2 {
                            early.insert(l.id.0);
                        } else if !early.contains(&l.id.0) {
                            late.insert((clip.clone(), l.id.0));
                        }
                    }
                    let r = &o.report;
                    repaired += usize::from(r.temporal_cov_repairs > 0);
                    pivots += u64::from(r.temporal_cov_repairs);
                    merged += u64::from(r.known.merged);
                }
                in_clip += 1;
            },
        )?;
        let preds: Vec<TuSimpleRecord> = preds
            .iter()
            .map(|r| {
                let mut r = demo::scale_record(r, REAL_TO_TUSIMPLE);
                r.run_time = Some(0.0);
                r
            })
            .collect();
        let all = metric::bench_one_submit(&preds, &scaled_gt)?;
        if std::env::var_os("REAL_JITTER_PER_FRAME").is_some() {
            for (pr, g) in preds.iter().zip(&scaled_gt) {
                let s = metric::bench(&pr.lanes, &g.lanes, &g.h_samples, 0.0)?;
                println!(
                    "  {} {} lanes / {} labelled: {:.3} / {:.3} / {:.3}",
                    pr.raw_file,
                    pr.lanes.len(),
                    g.lanes.len(),
                    s.accuracy,
                    s.fp,
                    s.fn_
                );
            }
        }
        let half = |tuning: bool| -> anyhow::Result<metric::Score> {
            let pick = |r: &&TuSimpleRecord| TUNING_SET.contains(&r.raw_file.as_str()) == tuning;
            let p: Vec<TuSimpleRecord> = preds.iter().filter(pick).cloned().collect();
            let g: Vec<TuSimpleRecord> = scaled_gt.iter().filter(pick).cloned().collect();
            metric::bench_one_submit(&p, &g)
        };
        let (t, h) = (half(true)?, half(false)?);
        println!(
            "| {frames_per_clip} frame{} | {amp} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {repaired} of {} ({pivots}) | {merged} | {} |",
            if frames_per_clip == 1 { "" } else { "s" },
            all.accuracy,
            all.fp,
            all.fn_,
            t.accuracy,
            t.fp,
            t.fn_,
            h.accuracy,
            h.fp,
            h.fn_,
            frames.len(),
            late.len()
        );
    }
    Ok(())
}
