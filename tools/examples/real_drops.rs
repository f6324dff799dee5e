//! Where the real frames' lanes are lost between the front end and the published lanes: each of
//! the 10 bundled 512×288 TuSimple frames through the front end (TuSimple calibration with each
//! image's horizon refined, `CameraMode::Refine`, as the demo's real row; `fixed`: the
//! calibration fixed; default `FrontendParams`) and the default tracker, one frame per clip as
//! the demo runs them. Per frame:
//! the points handed to the tracker (after `track::preprocess`), the spatial filter's lanes
//! (`SpatialReport::lanes_out`), the lanes the identity stage started and those it dropped as
//! unusable (fewer than `identity::Config::min_common` index points present: a marking observed
//! over less than about two index intervals, ~10 m, starts no lane), the lanes published, and
//! each live slot's existence, position at 10 and 30 m and published extent. Then, per labelled
//! lane, how the official metric sees it (at 1280×720, as the demo scores): the prediction with
//! its best point accuracy and that prediction's rows — within the threshold (`right`; rows
//! where neither has a point count as right too, `both absent`), beyond it (`off`), labelled
//! but not predicted (`missing`), predicted but not labelled (`extra`) — and `FN` when the
//! accuracy is under 0.85: whether a lost lane was never found (`missing` rows) or found and
//! drawn in the wrong place (`off` / `extra`; unless its best prediction is another labelled
//! lane's match, `another lane's`). The same per lane for any prediction file:
//! `stjpdacf eval --per-lane`.
//!
//! `cargo run --release -p stjpdacf-tools --example real_drops [-- [fixed] [PART]]` (only the
//! frames whose file name contains `PART`, e.g. `37400`).
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo::{scale_record, REAL_FRAMES, REAL_TO_TUSIMPLE};
use stjpdacf_tools::frontend::{self, CameraMode, FrontendParams};
use stjpdacf_tools::metric;
use stjpdacf_tools::track::{self, Space};
use stjpdacf_tools::tusimple::{read_labels, TuSimpleRecord};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let fixed = args.iter().any(|a| a == "fixed");
    let part = args
        .iter()
        .find(|a| *a != "fixed")
        .cloned()
        .unwrap_or_default();
    let mode = if fixed {
        CameraMode::TuSimple
    } else {
        CameraMode::Refine(Camera::tusimple())
    };
    let dir = stjpdacf_tools::repo_root().join("data").join(REAL_FRAMES);
    let labels = read_labels(&dir.join("label_data.json"))?;
    let frames =
        frontend::run_dir_cameras(&dir, &mode, &labels, &FrontendParams::default(), |_, _| {})?;
    println!("| frame | points (tracker) | spatial lanes | started | dropped (< min_common) | published |");
    println!("|---|---|---|---|---|---|");
    let mut slots = Vec::new();
    let mut breakdown = Vec::new();
    for (frame, _, cam) in &frames {
        let name = frame.raw_file.clone().unwrap_or_default();
        if !name.contains(&part) {
            continue;
        }
        // One frame is one clip: a fresh tracker for each frame, as the demo runs them.
        track::track_with(
            std::slice::from_ref(frame),
            &DEFAULT,
            cam,
            Space::Image,
            TrackerConfig::DEFAULT,
            |v| {
                let Some(o) = v.output else {
                    println!("| {name} | refused | | | | |");
                    return;
                };
                if let (Some(pred), Some(gt)) =
                    (v.prediction, labels.iter().find(|l| l.raw_file == name))
                {
                    breakdown.extend(label_rows(
                        &name,
                        &scale_record(pred, REAL_TO_TUSIMPLE),
                        &scale_record(gt, REAL_TO_TUSIMPLE),
                    ));
                }
                let r = &o.report;
                println!(
                    "| {name} | {} | {} | {} | {} | {} |",
                    v.points.len(),
                    r.spatial.lanes_out,
                    r.identity.started,
                    r.identity.dropped_unusable,
                    o.filtered.len()
                );
                for (s, l) in v.tracker.persist().lanes.iter().enumerate() {
                    if l.existence <= 0.0 {
                        continue;
                    }
                    let at = |u: f32| {
                        v.tracker
                            .lane_at(s, u)
                            .map_or("—".to_string(), |(z, _)| format!("{z:+.2}"))
                    };
                    let published = o.filtered.iter().find(|e| usize::from(e.slot) == s);
                    slots.push(format!(
                        "{name} slot {s}: existence {:.3}, x at 10 / 30 m {} / {}, {}",
                        l.existence,
                        at(10.0),
                        at(30.0),
                        published.map_or("not published".to_string(), |e| format!(
                            "published over {:.1}–{:.1} m",
                            e.u_first, e.u_last
                        )),
                    ));
                }
            },
        )?;
    }
    println!();
    for s in slots {
        println!("{s}");
    }
    println!();
    println!("| frame | label | best prediction | accuracy | right (both absent) | off | missing | extra | |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for b in breakdown {
        println!("{b}");
    }
    Ok(())
}

/// One table row per labelled lane of `gt` (both records at the metric's 1280×720):
/// [`metric::lane_rows`].
fn label_rows(name: &str, pred: &TuSimpleRecord, gt: &TuSimpleRecord) -> Vec<String> {
    metric::lane_rows(&pred.lanes, &gt.lanes, &gt.h_samples)
        .into_iter()
        .filter(|l| l.labelled() > 0)
        .map(|l| {
            format!(
                "| {name} | {} | {}{} | {:.3} | {} ({}) | {} | {} | {} | {} |",
                l.label,
                l.pred.map_or("none".to_string(), |p| p.to_string()),
                if l.pred_taken {
                    " (another lane's)"
                } else {
                    ""
                },
                l.accuracy,
                l.right + l.both_absent,
                l.both_absent,
                l.off,
                l.missing,
                l.extra,
                if l.matched { "" } else { "FN" }
            )
        })
        .collect()
}
