//! End-to-end tests of the TuSimple metric and the `eval` subcommand on the bundled
//! 512×288 TuSimple labels (`data/tusimple/sample_512x288/label_data.json`, 10 frames).

mod common;

use std::path::{Path, PathBuf};

use approx::assert_relative_eq;
use common::{assert_failure_mentions, assert_success, stjpdacf};
use stjpdacf_tools::metric::{self, bench, bench_one_submit, lane_angle, lane_threshold};
use stjpdacf_tools::tusimple::{self, read_labels, write_records, TuSimpleRecord};

fn labels_path() -> PathBuf {
    stjpdacf_tools::repo_root().join("data/tusimple/sample_512x288/label_data.json")
}

fn labels() -> Vec<TuSimpleRecord> {
    read_labels(&labels_path()).unwrap()
}

/// The ground truth as predictions (run_time 0 ms).
fn as_predictions(gts: &[TuSimpleRecord]) -> Vec<TuSimpleRecord> {
    tusimple::as_predictions(gts, 0.0)
}

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("stjpdacf-tusimple-it-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn eval_cli(pred: &Path, gt: &Path, json: bool) -> std::process::Output {
    eval_with(pred, gt, if json { &["--json"] } else { &[] })
}

/// `stjpdacf eval --pred pred --gt gt args…`.
fn eval_with(pred: &Path, gt: &Path, args: &[&str]) -> std::process::Output {
    stjpdacf()
        .arg("eval")
        .arg("--pred")
        .arg(pred)
        .arg("--gt")
        .arg(gt)
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn bundled_labels_are_ten_frames_of_48_rows() {
    let g = labels();
    assert_eq!(g.len(), 10);
    for r in &g {
        assert_eq!(
            (r.h_samples.len(), r.run_time),
            (48, None),
            "{}",
            r.raw_file
        );
    }
}

#[test]
fn ground_truth_against_itself_is_perfect() {
    let gts = labels();
    let s = bench_one_submit(&as_predictions(&gts), &gts).unwrap();
    assert_eq!((s.accuracy, s.fp, s.fn_, s.frames), (1.0, 0.0, 0.0, 10));
}

#[test]
fn shifting_one_lane_past_its_threshold_makes_it_fn_and_fp() {
    let gts = labels();
    let g0 = &gts[0];
    // Lane 0 of frame 0 (x from 282 down to 172, -2 on its first 3 rows): its threshold is
    // 20 / cos(atan(slope)) ≈ 23.6 px, so a 60 px shift misses every valid point.
    let thresh = lane_threshold(lane_angle(&g0.lanes[0], &g0.h_samples));
    assert!(thresh > 22.0 && thresh < 60.0, "{thresh}");
    let mut preds = as_predictions(&gts);
    for x in preds[0].lanes[0].iter_mut().filter(|x| **x >= 0.0) {
        *x += 60.0;
    }
    let f = bench(&preds[0].lanes, &g0.lanes, &g0.h_samples, 0.0).unwrap();
    // Lane 0's best accuracy: 4/48, from predicted lane 1 (the 3 shared -2 rows, and row 108
    // where lane 1 is at 304 vs 282: 22 px < 23.6); the shifted lane itself gets only 3/48.
    // The other three lanes are exact: accuracy (3 + 4/48) / 4; 1 FN of 4; 1 FP of 4.
    assert_relative_eq!(f.accuracy, (3.0 + 4.0 / 48.0) / 4.0, epsilon = 1e-15);
    assert_eq!((f.fp, f.fn_), (0.25, 0.25));
    let s = bench_one_submit(&preds, &gts).unwrap();
    assert_relative_eq!(
        s.accuracy,
        (9.0 + (3.0 + 4.0 / 48.0) / 4.0) / 10.0,
        epsilon = 1e-15
    );
    assert_relative_eq!(s.fp, 0.025, epsilon = 1e-15);
    assert_relative_eq!(s.fn_, 0.025, epsilon = 1e-15);
    // A 10 px shift stays inside the threshold: that frame is still perfect on FP/FN.
    let mut preds = as_predictions(&gts);
    for x in preds[0].lanes[0].iter_mut().filter(|x| **x >= 0.0) {
        *x += 10.0;
    }
    let s = bench_one_submit(&preds, &gts).unwrap();
    assert_eq!((s.accuracy, s.fp, s.fn_), (1.0, 0.0, 0.0));
}

#[test]
fn eval_cli_prints_json_and_table() {
    let dir = temp_dir("cli");
    let pred = dir.join("pred.json");
    let gts = labels();
    let mut preds = as_predictions(&gts);
    preds[3].run_time = Some(250.0); // one frame penalised: (0, 0, 1)
    write_records(&pred, &preds).unwrap();
    let out = eval_cli(&pred, &labels_path(), true);
    assert_success(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["Accuracy"].as_f64(), Some(0.9));
    assert_eq!(v["FP"].as_f64(), Some(0.0));
    assert_eq!(v["FN"].as_f64(), Some(0.1));
    assert_eq!(v["frames"].as_u64(), Some(10));
    let out = eval_cli(&pred, &labels_path(), false);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("Accuracy  0.900000"), "{text}");
    assert!(text.contains("FN        0.100000"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn eval_cli_reports_bad_inputs() {
    let dir = temp_dir("bad");
    let gts = labels();
    // Unreadable prediction file.
    let missing = dir.join("missing.json");
    let out = eval_cli(&missing, &labels_path(), false);
    assert_failure_mentions(&out, "missing.json");
    // A prediction whose raw_file is not in the ground truth.
    let mut preds = as_predictions(&gts);
    preds[2].raw_file = "clips/nowhere/20.jpg".into();
    let pred = dir.join("pred.json");
    write_records(&pred, &preds).unwrap();
    let out = eval_cli(&pred, &labels_path(), false);
    assert_failure_mentions(
        &out,
        "clips/nowhere/20.jpg: raw_file not in the ground truth",
    );
    // Ground truth used as predictions: no run_time, named with file and line.
    let out = eval_cli(&labels_path(), &labels_path(), false);
    let err = assert_failure_mentions(&out, "label_data.json:1: bad TuSimple prediction");
    assert!(err.contains("run_time missing"), "{err}");
    // A predicted lane of the wrong length.
    let mut preds = as_predictions(&gts);
    preds[5].lanes[1].pop();
    write_records(&pred, &preds).unwrap();
    let err = metric::evaluate_files(&pred, &labels_path()).unwrap_err();
    assert!(
        format!("{err:#}").contains("format of lanes error"),
        "{err:#}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn labelled_only_scores_the_labelled_frames_and_counts_the_others() {
    // Predictions of the 10 labelled frames plus two unlabelled ones (as `track` writes for
    // every synth frame while `synth --gt` labels the last ones): refused as the official scorer
    // does, with the way out named; scored as the 10 alone with --labelled-only.
    let dir = temp_dir("labelled-only");
    let gts = labels();
    let mut preds = as_predictions(&gts);
    for k in 0..2 {
        let mut p = preds[k].clone();
        p.raw_file = format!("unlabelled/{k}.jpg");
        for lane in &mut p.lanes {
            for x in lane.iter_mut().filter(|x| **x >= 0.0) {
                *x += 100.0;
            }
        }
        preds.push(p);
    }
    let pred = dir.join("pred.json");
    write_records(&pred, &preds).unwrap();
    let out = eval_cli(&pred, &labels_path(), true);
    let err = assert_failure_mentions(&out, "2 of the 12 predictions");
    assert!(err.contains("--labelled-only"), "{err}");
    let out = eval_with(&pred, &labels_path(), &["--json", "--labelled-only"]);
    assert_success(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["Accuracy"], 1.0, "{v}");
    assert_eq!(v["frames"], 10, "{v}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("2 of unlabelled frames left out"), "{err}");
    // A labelled frame without a prediction is still refused.
    let (kept, left_out) = metric::labelled_only(preds[1..].to_vec(), &gts);
    assert_eq!((kept.len(), left_out), (9, 2));
    assert!(metric::check_one_to_one(&kept, &gts).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn pixel_scale_scores_512_files_at_1280() {
    // Every labelled point moved 15 px right at 512×288: within the 20 px threshold as is, but
    // 37.5 px at TuSimple's 1280×720, beyond 20 / cos θ for every lane less steep than 58°.
    let dir = temp_dir("scale");
    let gts = labels();
    let mut preds = as_predictions(&gts);
    for p in &mut preds {
        for lane in &mut p.lanes {
            for x in lane.iter_mut().filter(|x| **x >= 0.0) {
                *x += 15.0;
            }
        }
    }
    let pred = dir.join("pred.json");
    write_records(&pred, &preds).unwrap();
    let native = metric::evaluate_files(&pred, &labels_path()).unwrap();
    assert_eq!((native.accuracy, native.fp, native.fn_), (1.0, 0.0, 0.0));
    let full = metric::evaluate_files_scaled(&pred, &labels_path(), 2.5).unwrap();
    // Measured 0.563 accuracy, 0.475 FN (the steep outer lanes still match).
    assert!(full.accuracy < 0.7 && full.fn_ > 0.3, "{full:?}");
    // The same through the CLI.
    let out = eval_with(&pred, &labels_path(), &["--json", "--pixel-scale", "2.5"]);
    assert_success(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["Accuracy"].as_f64(), Some(full.accuracy));
    // Scaling keeps −2 and scales the rows.
    let mut r = gts[0].clone();
    r.scale_pixels(2.5);
    assert_eq!(r.h_samples[0], 240.0);
    assert_eq!(r.lanes[0][0], -2.0);
    assert_eq!(r.lanes[0][3], gts[0].lanes[0][3] * 2.5);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn per_frame_scores_average_to_the_score_and_list_the_worst_first() {
    let dir = temp_dir("per-frame");
    let gts = labels();
    let mut preds = as_predictions(&gts);
    // Frame 3: lane 0 shifted 60 px (one FN and one FP); frame 7: too slow (the penalty).
    for x in preds[3].lanes[0].iter_mut().filter(|x| **x >= 0.0) {
        *x += 60.0;
    }
    preds[7].run_time = Some(250.0);
    let (score, frames) = metric::bench_frames(&preds, &gts).unwrap();
    assert_eq!(score, bench_one_submit(&preds, &gts).unwrap());
    let mean = frames.iter().map(|f| f.accuracy).sum::<f64>() / 10.0;
    assert_relative_eq!(mean, score.accuracy, epsilon = 1e-15);
    assert!(frames[7].penalty && frames[7].accuracy == 0.0 && frames[7].fn_ == 1.0);
    assert!(!frames[3].penalty && frames[3].fp == 0.25 && frames[3].fn_ == 0.25);
    assert!(frames
        .iter()
        .enumerate()
        .all(|(i, f)| f.raw_file == gts[i].raw_file && f.gt_lanes == gts[i].lanes.len()));
    // The CLI writes them worst first.
    let pred = dir.join("pred.json");
    write_records(&pred, &preds).unwrap();
    let per = dir.join("frames.jsonl");
    let out = stjpdacf()
        .args(["eval", "--per-frame"])
        .arg(&per)
        .arg("--pred")
        .arg(&pred)
        .arg("--gt")
        .arg(labels_path())
        .output()
        .unwrap();
    assert_success(&out);
    let rows: Vec<serde_json::Value> = std::fs::read_to_string(&per)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(rows.len(), 10);
    assert_eq!(rows[0]["raw_file"], gts[7].raw_file.as_str());
    assert_eq!(rows[0]["penalty"], true);
    assert_eq!(rows[1]["raw_file"], gts[3].raw_file.as_str());
    assert_eq!(rows[1]["fn"].as_f64(), Some(0.25));
    assert!(rows[2..]
        .iter()
        .all(|r| r["accuracy"].as_f64() == Some(1.0)));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("10 frame scores to") && err.contains("penalty"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `convert`: the bundled 1280×720 train labels to CULane-style lane files and back give the
/// same columns at every labelled row; the frames it writes of them at another row step
/// (label points as a detector's lane files, TuSimple's camera) carry the labels' rows, track,
/// and score against the converted labels; a missing folder is refused.
#[test]
fn cli_converts_culane_lane_files_both_ways_and_tracks_them() {
    let d = temp_dir("culane");
    let labels_720 = stjpdacf_tools::repo_root().join("data/tusimple/train_subset.json");
    let lanes_dir = d.join("lanes");
    let o = stjpdacf()
        .args(["convert", "--to-culane"])
        .arg(&labels_720)
        .arg("--out")
        .arg(&lanes_dir)
        .output()
        .unwrap();
    assert_success(&o);
    let gts = read_labels(&labels_720).unwrap();
    let first = stjpdacf_tools::culane::lane_file_of(&lanes_dir, &gts[0].raw_file).unwrap();
    assert!(first.is_file(), "{} not written", first.display());
    let (gt, frames, pred) = (
        d.join("gt.json"),
        d.join("frames.jsonl"),
        d.join("pred.json"),
    );
    let o = stjpdacf()
        .args(["convert", "--culane"])
        .arg(&lanes_dir)
        .arg("--out")
        .arg(&gt)
        .args(["--camera", "tusimple"])
        .output()
        .unwrap();
    assert_success(&o);
    // The same files as a detector's output, sampled every 4 rows, as frames predicted at the
    // labels' rows.
    let o = stjpdacf()
        .args(["convert", "--culane"])
        .arg(&lanes_dir)
        .arg("--out")
        .arg(d.join("det.json"))
        .arg("--frames")
        .arg(&frames)
        .arg("--labels")
        .arg(&gt)
        .args(["--camera", "tusimple", "--row-step", "4"])
        .output()
        .unwrap();
    assert_success(&o);
    // Back again: every labelled point of a lane with two or more points, at its row (TuSimple
    // labels every 10 rows, the default row step).
    let back: Vec<TuSimpleRecord> = tusimple::read_jsonl(&gt).unwrap();
    assert_eq!(back.len(), gts.len());
    let mut compared = 0;
    for b in &back {
        let g = gts.iter().find(|g| g.raw_file == b.raw_file).unwrap();
        let lanes: Vec<&Vec<f64>> = g
            .lanes
            .iter()
            .filter(|l| g.points_of(l).count() >= 2)
            .collect();
        assert_eq!(lanes.len(), b.lanes.len(), "{}", g.raw_file);
        for (lg, lb) in lanes.iter().zip(&b.lanes) {
            for (x, h) in g.points_of(lg) {
                let i = b.h_samples.iter().position(|&r| r == h).unwrap();
                assert_relative_eq!(lb[i], x, epsilon = 0.01);
                compared += 1;
            }
        }
    }
    assert!(compared > 4000, "{compared} points compared");
    let o = stjpdacf()
        .args(["track", "--frames"])
        .arg(&frames)
        .arg("--out")
        .arg(&pred)
        .output()
        .unwrap();
    assert_success(&o);
    let (preds, gts2, _) = metric::read_scaled(&pred, &gt, 1.0, false).unwrap();
    let (s, _) = metric::score_frames(&preds, &gts2, (&pred, &gt)).unwrap();
    assert_eq!(s.frames, gts.len());
    // One cold-started frame a clip, label points as the detector: as the demo's label row.
    assert!(s.accuracy > 0.9, "accuracy {}", s.accuracy);
    // The lane files as they are, at the labels' rows, are predictions `eval` scores: the
    // labels' own lanes, every point matched.
    let det = d.join("det.json");
    let (preds, gts2, _) = metric::read_scaled(&det, &gt, 1.0, false).unwrap();
    let (s, _) = metric::score_frames(&preds, &gts2, (&det, &gt)).unwrap();
    assert_eq!((s.accuracy, s.fp, s.fn_), (1.0, 0.0, 0.0));
    // CULane's metric on them: every lane a true positive (TuSimple's 1280×720 image).
    let o = stjpdacf()
        .args([
            "eval",
            "--metric",
            "culane",
            "--image-size",
            "1280x720",
            "--json",
            "--pred",
        ])
        .arg(&det)
        .arg("--gt")
        .arg(&gt)
        .output()
        .unwrap();
    assert_success(&o);
    let f1: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let lanes: usize = gts2.iter().map(|g| g.lanes.len()).sum();
    assert_eq!(f1["tp"], lanes);
    assert_eq!((f1["fp"].as_u64(), f1["fn"].as_u64()), (Some(0), Some(0)));
    assert_eq!(f1["f1"], 1.0);
    // The default camera (CULane's 1640×590) leaves the rows below 590 out and says so.
    let o = stjpdacf()
        .args(["convert", "--culane"])
        .arg(&lanes_dir)
        .arg("--out")
        .arg(d.join("g590.json"))
        .output()
        .unwrap();
    assert_success(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("outside the 1640x590 image"), "{err}");
    // Lanes seen only up to row 420 of CULane's camera (11 m ahead) are too short to track:
    // `track` publishes none and says how far up they must reach.
    let short = d.join("short");
    std::fs::create_dir_all(short.join("clip")).unwrap();
    for k in 0..5 {
        let line = |x0: f64| {
            (0..18)
                .map(|i| format!("{:.1} {}", x0 + 3.0 * f64::from(i), 590 - 10 * i))
                .collect::<Vec<_>>()
                .join(" ")
        };
        let text = format!("{}\n{}\n", line(300.0), line(1300.0));
        std::fs::write(short.join(format!("clip/{:05}.lines.txt", 30 * k)), text).unwrap();
    }
    let sf = d.join("short.jsonl");
    let o = stjpdacf()
        .args(["convert", "--culane"])
        .arg(&short)
        .arg("--out")
        .arg(d.join("short_gt.json"))
        .arg("--frames")
        .arg(&sf)
        .output()
        .unwrap();
    assert_success(&o);
    let o = stjpdacf()
        .args(["track", "--frames"])
        .arg(&sf)
        .arg("--out")
        .arg(d.join("short_pred.json"))
        .output()
        .unwrap();
    assert_success(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("no lane was published") && err.contains("must reach row 343"),
        "{err}"
    );
    let o = stjpdacf()
        .args(["convert", "--culane"])
        .arg(d.join("nothing"))
        .arg("--out")
        .arg(d.join("x.json"))
        .output()
        .unwrap();
    assert_failure_mentions(&o, "reading folder");
    std::fs::remove_dir_all(&d).unwrap();
}
