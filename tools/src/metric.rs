//! The official TuSimple lane-detection metric, reproduced exactly.
//!
//! Followed: `LaneEval` in `evaluate/lane.py` of the `TuSimple/tusimple-benchmark` repository
//! (version at commit `365c4cd1b0951b209da26446e413826f6aa5f5c9`, the one with the
//! `len(gt) + 2 < len(pred)` rule and `run_time` read from the predictions). Each function here
//! names the function of the original it reproduces; the order of operations is the original's.
//!
//! The rules, as the code has them (several differ from the usual prose description):
//!
//! * **Angle** (`get_angle`): for each ground-truth lane, a least-squares line with intercept
//!   (`sklearn.linear_model.LinearRegression().fit(ys[:, None], xs)`) of **x on y** over the rows
//!   where the ground truth has `x >= 0` (so `x = 0` is a valid point); `θ = arctan(k)` with `k`
//!   the slope dx/dy. With fewer than two valid points `θ = 0`.
//! * **Threshold**: `20 / cos θ` pixels (`pixel_thresh = 20`; the same 20 px at any image size).
//! * **Point accuracy** (`line_accuracy`): every negative value (the `-2` of "no point"), in the
//!   prediction or the ground truth, is replaced by `-100`; a row is correct when
//!   `|pred - gt| < thresh` (strictly); the count is divided by **all** rows. So a row where both
//!   are missing counts as correct, a row where only one is missing counts as wrong (unless the
//!   threshold exceeds 100 + x), and ground-truth `-2` rows stay in the denominator; they are
//!   excluded only from the angle fit.
//! * **Match** (`bench`): each ground-truth lane takes its best accuracy over **all** predicted
//!   lanes (not a one-to-one assignment; 0 with no predictions). Best `< 0.85` (`pt_thresh`) is a
//!   false negative, otherwise the lane is matched.
//! * **FP** = (predicted lanes − matched ground-truth lanes) / predicted lanes (0 with no
//!   predictions). It is negative when one prediction is the best match of several ground-truth
//!   lanes.
//! * **More than 4 ground-truth lanes**: if there is any false negative, one is forgiven
//!   (`fn -= 1`); the lowest best-accuracy is dropped from the sum.
//! * **Frame accuracy** = sum of best accuracies / max(min(4, gt lanes), 1);
//!   **FN** = false negatives / max(min(gt lanes, 4), 1) (so it can exceed 1 with 6+ lanes).
//! * **Penalty**: `run_time > 200` ms or more than `gt + 2` predicted lanes scores the frame
//!   (accuracy 0, FP 0, FN 1). Before that, a predicted lane whose length differs from the ground
//!   truth's `h_samples` is an error (the original raises "Format of lanes error.").
//! * **Submission** (`bench_one_submit`): as many predictions as ground-truth lines, or an
//!   error; every prediction needs `raw_file`, `lanes`, `run_time` and a `raw_file` present in
//!   the ground truth, or an error; frame scores are summed in prediction order and each sum is
//!   divided by the number of **distinct** ground-truth `raw_file`s (a repeated ground-truth
//!   `raw_file` keeps its last line).

use std::collections::{HashMap, HashSet};
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use serde::Serialize;

use crate::tusimple::{read_labels, read_predictions, TuSimpleRecord, NO_POINT};

/// `LaneEval.pixel_thresh`: the point threshold in pixels before the angle correction.
pub const PIXEL_THRESH: f64 = 20.0;
/// `LaneEval.pt_thresh`: share of correct points at which a lane counts as matched.
pub const PT_THRESH: f64 = 0.85;
/// A frame whose `run_time` exceeds this (milliseconds) scores accuracy 0, FP 0, FN 1.
pub const MAX_RUN_TIME_MS: f64 = 200.0;
/// A frame with more predicted lanes than ground-truth lanes plus this scores 0, 0, 1.
pub const MAX_EXTRA_LANES: usize = 2;
/// At most this many ground-truth lanes count in the accuracy and FN denominators.
pub const MAX_COUNTED_LANES: usize = 4;
/// The value `line_accuracy` substitutes for every negative ("no point") value.
const MISSING: f64 = -100.0;

/// Angle θ (radians) of a ground-truth lane: arctan of the least-squares slope dx/dy of x on y
/// (with intercept) over the rows where `xs >= 0`; 0 with fewer than two such rows.
/// Reproduces `LaneEval.get_angle` (sklearn `LinearRegression`; with all valid rows equal the
/// minimum-norm slope 0 is taken, as `lstsq` does). `xs` and `y_samples` pair up row by row.
pub fn lane_angle(xs: &[f64], y_samples: &[f64]) -> f64 {
    let pts: Vec<(f64, f64)> = xs
        .iter()
        .zip(y_samples)
        .filter(|(x, _)| **x >= 0.0)
        .map(|(x, y)| (*x, *y))
        .collect();
    if pts.len() <= 1 {
        return 0.0;
    }
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxy: f64 = pts.iter().map(|(x, y)| (y - my) * (x - mx)).sum();
    let syy: f64 = pts.iter().map(|(_, y)| (y - my) * (y - my)).sum();
    let k = if syy > 0.0 { sxy / syy } else { 0.0 };
    k.atan()
}

/// The point threshold of a lane with angle `angle`: `PIXEL_THRESH / cos(angle)` pixels.
pub fn lane_threshold(angle: f64) -> f64 {
    PIXEL_THRESH / angle.cos()
}

/// Share of rows where a predicted lane is within `thresh` of a ground-truth lane, as
/// `LaneEval.line_accuracy`: negative values on either side become −100, a row is correct when
/// `|pred − gt| < thresh`, and the count is divided by `gt.len()` (all rows). `pred` and `gt`
/// must have the same length (rows beyond the shorter one are not compared; [`bench()`] checks).
pub fn line_accuracy(pred: &[f64], gt: &[f64], thresh: f64) -> f64 {
    let fix = |v: f64| if v >= 0.0 { v } else { MISSING };
    let correct = pred
        .iter()
        .zip(gt)
        .filter(|(p, g)| (fix(**p) - fix(**g)).abs() < thresh)
        .count();
    correct as f64 / gt.len() as f64
}

/// Which lanes of a frame match, by the rule of [`bench()`]: a ground-truth lane's match is the
/// prediction with its best point accuracy when that is at least [`PT_THRESH`] (the first such
/// prediction among equals); a prediction matches a ground-truth lane when its accuracy on it is
/// at least [`PT_THRESH`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LaneMatches {
    /// Per ground-truth lane, the index of its matched prediction.
    pub gt_match: Vec<Option<usize>>,
    /// Per prediction, whether it matches any ground-truth lane.
    pub pred_matched: Vec<bool>,
}

/// The matches of `pred` and `gt` at `y_samples` (see [`LaneMatches`]; thresholds by the lanes'
/// angles as in [`bench()`]; lanes pair up row by row, no length check, no run-time or lane-count
/// penalty).
pub fn match_lanes(pred: &[Vec<f64>], gt: &[Vec<f64>], y_samples: &[f64]) -> LaneMatches {
    let mut pred_matched = vec![false; pred.len()];
    let gt_match = gt
        .iter()
        .map(|x_gts| {
            let thresh = lane_threshold(lane_angle(x_gts, y_samples));
            let best = first_best(pred.iter().enumerate().map(|(i, x_preds)| {
                let a = line_accuracy(x_preds, x_gts, thresh);
                if a >= PT_THRESH {
                    pred_matched[i] = true;
                }
                a
            }));
            best.filter(|&(_, a)| a >= PT_THRESH).map(|(i, _)| i)
        })
        .collect();
    LaneMatches {
        gt_match,
        pred_matched,
    }
}

/// The index and value of the first largest of `accuracies` (`None` when empty).
fn first_best(accuracies: impl Iterator<Item = f64>) -> Option<(usize, f64)> {
    accuracies
        .enumerate()
        .fold(None, |best, (i, a)| match best {
            Some((_, b)) if a > b => Some((i, a)),
            None => Some((i, a)),
            _ => best,
        })
}

/// How the metric sees one ground-truth lane of a frame (not part of the original: a diagnosis
/// of [`match_lanes`]): the prediction with its best point accuracy (the one it is matched to
/// when that reaches [`PT_THRESH`]; the first among equals) and that prediction's rows by kind.
/// `right + both_absent` are the rows [`line_accuracy`] counts as correct, so `accuracy` =
/// `(right + both_absent) / rows` (without a prediction in the frame the rows are counted against
/// an empty one and the accuracy is 0); the wrong rows are `off + missing + extra`. A lost lane with
/// mostly `missing` rows was not found; with mostly `off` / `extra` rows it was found and drawn
/// in the wrong place (and is also the frame's false lane).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LaneRows {
    /// Index of the ground-truth lane in its record.
    pub label: usize,
    /// Index of its best prediction (`None`: the frame has no prediction).
    pub pred: Option<usize>,
    /// Point accuracy against that prediction ([`line_accuracy`]; 0 without a prediction).
    pub accuracy: f64,
    /// The accuracy reaches [`PT_THRESH`]: the lane is matched.
    pub matched: bool,
    /// Its best prediction is matched to another ground-truth lane of the frame (so an unmatched
    /// lane's `off` rows are another lane's, not a misplaced drawing of this one).
    pub pred_taken: bool,
    /// Correct rows where the ground truth has a point.
    pub right: usize,
    /// Correct rows where neither has a point.
    pub both_absent: usize,
    /// Wrong rows where both have a point (farther apart than the threshold).
    pub off: usize,
    /// Wrong rows with a ground-truth point and no predicted one.
    pub missing: usize,
    /// Wrong rows with a predicted point and no ground-truth one.
    pub extra: usize,
}

/// [`LaneRows`] of every ground-truth lane of one frame (same thresholds and pairing as
/// [`match_lanes`]; rows pair up row by row).
pub fn lane_rows(pred: &[Vec<f64>], gt: &[Vec<f64>], y_samples: &[f64]) -> Vec<LaneRows> {
    let fix = |v: f64| if v >= 0.0 { v } else { MISSING };
    // Each ground-truth lane's threshold and best prediction, as `match_lanes` finds them.
    let bests: Vec<(f64, Option<(usize, f64)>)> = gt
        .iter()
        .map(|x_gts| {
            let thresh = lane_threshold(lane_angle(x_gts, y_samples));
            let best = first_best(pred.iter().map(|p| line_accuracy(p, x_gts, thresh)));
            (thresh, best)
        })
        .collect();
    let matched_to = |g: usize| match bests.get(g) {
        Some((_, Some((i, a)))) if *a >= PT_THRESH => Some(*i),
        _ => None,
    };
    gt.iter()
        .zip(&bests)
        .enumerate()
        .map(|(label, (x_gts, &(thresh, best)))| {
            let mut out = LaneRows {
                label,
                pred: best.map(|b| b.0),
                accuracy: best.map_or(0.0, |b| b.1),
                matched: matched_to(label).is_some(),
                pred_taken: best.is_some_and(|b| {
                    (0..gt.len()).any(|g| g != label && matched_to(g) == Some(b.0))
                }),
                right: 0,
                both_absent: 0,
                off: 0,
                missing: 0,
                extra: 0,
            };
            let none = vec![NO_POINT; x_gts.len()];
            let x_preds = best.and_then(|b| pred.get(b.0)).unwrap_or(&none);
            for (p, g) in x_preds.iter().zip(x_gts) {
                let counter = match ((fix(*p) - fix(*g)).abs() < thresh, *p >= 0.0, *g >= 0.0) {
                    (true, _, true) => &mut out.right,
                    (true, _, false) => &mut out.both_absent,
                    (false, true, true) => &mut out.off,
                    (false, false, true) => &mut out.missing,
                    (false, _, false) => &mut out.extra,
                };
                *counter += 1;
            }
            out
        })
        .collect()
}

impl LaneRows {
    /// Rows where the ground truth has a point (0: an empty ground-truth lane, which the scorer
    /// counts as a lane to find).
    pub fn labelled(&self) -> usize {
        self.right + self.off + self.missing
    }

    /// Unmatched, and drawn in the wrong place rather than not found: its best prediction is no
    /// other lane's match and has more `off` and `extra` rows than `missing` ones.
    pub fn misplaced(&self) -> bool {
        !self.matched && !self.pred_taken && self.off + self.extra > self.missing
    }
}

/// Scores of one frame, as returned by `LaneEval.bench`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FrameScore {
    /// Sum of the counted ground-truth lanes' best point accuracies / counted lanes.
    pub accuracy: f64,
    /// (predicted − matched) / predicted; 0 with no predictions.
    pub fp: f64,
    /// False negatives / max(min(gt lanes, 4), 1).
    pub fn_: f64,
}

/// The penalty score of a frame that is too slow or has too many lanes: accuracy 0, FP 0, FN 1.
pub const PENALTY: FrameScore = FrameScore {
    accuracy: 0.0,
    fp: 0.0,
    fn_: 1.0,
};

/// Fails when a lane of `lanes` does not have one value per row of `y_samples`; the message
/// starts with `what`.
fn check_lane_lengths(lanes: &[Vec<f64>], y_samples: &[f64], what: &str) -> Result<()> {
    if let Some((i, l)) = lanes
        .iter()
        .enumerate()
        .find(|(_, l)| l.len() != y_samples.len())
    {
        bail!(
            "{what} lane {i} has {} values, h_samples has {} rows",
            l.len(),
            y_samples.len()
        );
    }
    Ok(())
}

/// Score one frame: `LaneEval.bench(pred, gt, y_samples, running_time)`, in the original's order
/// (length check, penalty, angles and thresholds, best match per ground-truth lane, FP, the
/// more-than-4-lanes adjustments, the divisions). Errors: a predicted lane whose length is not
/// `y_samples.len()` (checked first, as the original does); after the penalty check, empty
/// `y_samples` or a ground-truth lane of the wrong length (the original fails on those too).
pub fn bench(
    pred: &[Vec<f64>],
    gt: &[Vec<f64>],
    y_samples: &[f64],
    running_time: f64,
) -> Result<FrameScore> {
    check_lane_lengths(pred, y_samples, "format of lanes error: predicted")?;
    if running_time > MAX_RUN_TIME_MS || gt.len() + MAX_EXTRA_LANES < pred.len() {
        return Ok(PENALTY);
    }
    ensure!(!y_samples.is_empty(), "ground truth h_samples is empty");
    check_lane_lengths(gt, y_samples, "ground-truth")?;
    let threshs: Vec<f64> = gt
        .iter()
        .map(|x_gts| lane_threshold(lane_angle(x_gts, y_samples)))
        .collect();
    let mut line_accs = Vec::with_capacity(gt.len());
    let mut fn_ = 0.0_f64;
    let mut matched = 0.0_f64;
    for (x_gts, &thresh) in gt.iter().zip(&threshs) {
        let max_acc = pred
            .iter()
            .map(|x_preds| line_accuracy(x_preds, x_gts, thresh))
            .fold(None, |m: Option<f64>, a| Some(m.map_or(a, |m| m.max(a))))
            .unwrap_or(0.0);
        if max_acc < PT_THRESH {
            fn_ += 1.0;
        } else {
            matched += 1.0;
        }
        line_accs.push(max_acc);
    }
    let fp = pred.len() as f64 - matched;
    if gt.len() > MAX_COUNTED_LANES && fn_ > 0.0 {
        fn_ -= 1.0;
    }
    let mut s = line_accs.iter().fold(0.0_f64, |s, a| s + a);
    if gt.len() > MAX_COUNTED_LANES {
        s -= line_accs.iter().copied().fold(f64::INFINITY, f64::min);
    }
    let counted = (MAX_COUNTED_LANES.min(gt.len()) as f64).max(1.0);
    Ok(FrameScore {
        accuracy: s / counted,
        fp: if pred.is_empty() {
            0.0
        } else {
            fp / pred.len() as f64
        },
        fn_: fn_ / counted,
    })
}

/// Scores of a whole submission, as `LaneEval.bench_one_submit` reports them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Score {
    /// Mean frame accuracy.
    #[serde(rename = "Accuracy")]
    pub accuracy: f64,
    /// Mean frame FP rate.
    #[serde(rename = "FP")]
    pub fp: f64,
    /// Mean frame FN rate.
    #[serde(rename = "FN")]
    pub fn_: f64,
    /// The divisor: the number of distinct ground-truth `raw_file`s.
    pub frames: usize,
}

/// Score predictions against ground truth: `LaneEval.bench_one_submit`, in its order. Errors, as
/// the original raises them: a prediction count different from the ground-truth line count; a
/// prediction without `run_time`; a prediction whose `raw_file` is not in the ground truth; a
/// frame that [`bench()`] rejects. Also an error (the original divides by zero): no ground truth.
/// Like the original, this accepts repeated `raw_file`s; [`check_one_to_one`] rejects them.
pub fn bench_one_submit(preds: &[TuSimpleRecord], gts: &[TuSimpleRecord]) -> Result<Score> {
    Ok(bench_frames(preds, gts)?.0)
}

/// One prediction's frame score ([`bench()`]) with what it was scored on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameResult {
    /// The prediction's `raw_file`.
    pub raw_file: String,
    /// The frame's accuracy.
    pub accuracy: f64,
    /// The frame's FP rate.
    pub fp: f64,
    /// The frame's FN rate.
    #[serde(rename = "fn")]
    pub fn_: f64,
    /// Ground-truth lanes of the frame.
    pub gt_lanes: usize,
    /// Predicted lanes of the frame.
    pub pred_lanes: usize,
    /// The frame got the metric's penalty (too slow, or more than 2 lanes too many).
    pub penalty: bool,
}

/// [`bench_one_submit`] and each prediction's frame score, in the predictions' order (same
/// checks and errors).
pub fn bench_frames(
    preds: &[TuSimpleRecord],
    gts: &[TuSimpleRecord],
) -> Result<(Score, Vec<FrameResult>)> {
    ensure!(
        gts.len() == preds.len(),
        "{} predictions for {} ground-truth frames: every ground-truth frame needs one prediction",
        preds.len(),
        gts.len()
    );
    let by_file: HashMap<&str, &TuSimpleRecord> =
        gts.iter().map(|g| (g.raw_file.as_str(), g)).collect();
    let (mut accuracy, mut fp, mut fn_) = (0.0_f64, 0.0_f64, 0.0_f64);
    let mut frames = Vec::with_capacity(preds.len());
    for (i, pred) in preds.iter().enumerate() {
        let Some(run_time) = pred.run_time else {
            bail!("prediction {} ({}): run_time missing", i + 1, pred.raw_file);
        };
        let Some(gt) = by_file.get(pred.raw_file.as_str()) else {
            bail!(
                "prediction {} ({}): raw_file not in the ground truth",
                i + 1,
                pred.raw_file
            );
        };
        let f = bench(&pred.lanes, &gt.lanes, &gt.h_samples, run_time)
            .with_context(|| format!("prediction {} ({})", i + 1, pred.raw_file))?;
        accuracy += f.accuracy;
        fp += f.fp;
        fn_ += f.fn_;
        frames.push(FrameResult {
            raw_file: pred.raw_file.clone(),
            accuracy: f.accuracy,
            fp: f.fp,
            fn_: f.fn_,
            gt_lanes: gt.lanes.len(),
            pred_lanes: pred.lanes.len(),
            penalty: run_time > MAX_RUN_TIME_MS
                || gt.lanes.len() + MAX_EXTRA_LANES < pred.lanes.len(),
        });
    }
    let num = by_file.len();
    ensure!(num > 0, "no ground-truth frames");
    let n = num as f64;
    let score = Score {
        accuracy: accuracy / n,
        fp: fp / n,
        fn_: fn_ / n,
        frames: num,
    };
    Ok((score, frames))
}

/// Stricter than the original (which would silently count a repeated prediction twice): every
/// `raw_file` appears once in the ground truth and once in the predictions, every prediction's
/// `raw_file` is in the ground truth, every ground-truth frame has a prediction, and a
/// prediction's `h_samples`, when it has them, are its ground truth's
/// ([`check_prediction_rows`]). Inputs that pass are scored by [`bench_one_submit`] exactly as the
/// original scores them.
pub fn check_one_to_one(preds: &[TuSimpleRecord], gts: &[TuSimpleRecord]) -> Result<()> {
    // The files of `records`, each once.
    let files = |records: &'_ [TuSimpleRecord], what: &str| -> Result<HashSet<String>> {
        let mut files = HashSet::new();
        for r in records {
            ensure!(
                files.insert(r.raw_file.clone()),
                "{what} {} more than once",
                r.raw_file
            );
        }
        Ok(files)
    };
    let gt_files = files(gts, "ground truth lists")?;
    let pred_files = files(preds, "predictions list")?;
    let unlabelled = preds
        .iter()
        .filter(|p| !gt_files.contains(&p.raw_file))
        .count();
    if let Some(p) = preds.iter().find(|p| !gt_files.contains(&p.raw_file)) {
        bail!(
            "prediction for {}: raw_file not in the ground truth ({unlabelled} of the {} \
             predictions are for frames it does not list; the official scorer refuses them: \
             score the labelled frames alone with `eval --labelled-only`, e.g. when the \
             ground truth labels each clip's last frame, as `synth --gt` writes it)",
            p.raw_file,
            preds.len()
        );
    }
    if let Some(missing) = gts.iter().find(|g| !pred_files.contains(&g.raw_file)) {
        bail!("no prediction for ground-truth frame {}", missing.raw_file);
    }
    check_prediction_rows(preds, gts)
}

/// Rows further apart than this (pixels) are different rows ([`check_prediction_rows`]).
const ROW_TOLERANCE: f64 = 0.5;

/// A prediction that states its rows (`h_samples`, which the scorer does not read: it pairs
/// the lanes' values with the ground truth's rows) states the ground truth's: otherwise its
/// columns would be scored at rows they were not found at (e.g. predictions of 512×288 frames
/// against 1280×720 labels, which `--pixel-scale` does not fix as it scales both files).
pub fn check_prediction_rows(preds: &[TuSimpleRecord], gts: &[TuSimpleRecord]) -> Result<()> {
    let by_file: HashMap<&str, &TuSimpleRecord> =
        gts.iter().map(|g| (g.raw_file.as_str(), g)).collect();
    for p in preds.iter().filter(|p| !p.h_samples.is_empty()) {
        let Some(g) = by_file.get(p.raw_file.as_str()) else {
            continue;
        };
        let same = p.h_samples.len() == g.h_samples.len()
            && p.h_samples
                .iter()
                .zip(&g.h_samples)
                .all(|(a, b)| (a - b).abs() <= ROW_TOLERANCE);
        if !same {
            let span = |h: &[f64]| match (h.first(), h.last()) {
                (Some(a), Some(b)) => format!("{} rows {a}–{b}", h.len()),
                _ => "no rows".to_string(),
            };
            bail!(
                "prediction for {}: its h_samples ({}) are not the ground truth's ({}); the \
                 files are of different image sizes or rows (--pixel-scale scales both files)",
                p.raw_file,
                span(&p.h_samples),
                span(&g.h_samples)
            );
        }
    }
    Ok(())
}

/// Read a prediction file and a ground-truth file (TuSimple JSON lines), check that they pair
/// one to one ([`check_one_to_one`]) and score them ([`bench_one_submit`]). Errors name the file.
pub fn evaluate_files(pred_path: &Path, gt_path: &Path) -> Result<Score> {
    evaluate_files_scaled(pred_path, gt_path, 1.0)
}

/// [`evaluate_files`] with every column and row of both files multiplied by `scale` first
/// (negative "no point" values stay as they are), e.g. 2.5 to score files of 512×288 frames at
/// TuSimple's 1280×720, where the metric's 20 px threshold is defined.
pub fn evaluate_files_scaled(pred_path: &Path, gt_path: &Path, scale: f64) -> Result<Score> {
    let (preds, gts, _) = read_scaled(pred_path, gt_path, scale, false)?;
    Ok(score_frames(&preds, &gts, (pred_path, gt_path))?.0)
}

/// [`bench_frames`] with the two files named in its error.
pub fn score_frames(
    preds: &[TuSimpleRecord],
    gts: &[TuSimpleRecord],
    (pred_path, gt_path): (&Path, &Path),
) -> Result<(Score, Vec<FrameResult>)> {
    bench_frames(preds, gts).with_context(|| scoring(pred_path, gt_path))
}

/// Every ground-truth lane's [`LaneRows`] (ground-truth order) against the prediction of its
/// frame (none when the predictions lack the frame).
pub fn frame_lane_rows(preds: &[TuSimpleRecord], gts: &[TuSimpleRecord]) -> Vec<FrameLaneRows> {
    let by_file: HashMap<&str, &TuSimpleRecord> =
        preds.iter().map(|p| (p.raw_file.as_str(), p)).collect();
    let mut out = Vec::new();
    for g in gts {
        let pred = by_file
            .get(g.raw_file.as_str())
            .map_or(&[][..], |p| &p.lanes);
        out.extend(
            lane_rows(pred, &g.lanes, &g.h_samples)
                .into_iter()
                .map(|lane| FrameLaneRows {
                    raw_file: g.raw_file.clone(),
                    lane,
                }),
        );
    }
    out
}

/// One ground-truth lane's [`LaneRows`] with its frame's `raw_file` (a line of `eval
/// --per-lane`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameLaneRows {
    /// The frame's `raw_file`.
    pub raw_file: String,
    /// The lane.
    #[serde(flatten)]
    pub lane: LaneRows,
}

fn scoring(pred_path: &Path, gt_path: &Path) -> String {
    format!(
        "scoring {} against {}",
        pred_path.display(),
        gt_path.display()
    )
}

/// The predictions whose `raw_file` the ground truth lists, in their order, and how many others
/// were left out: what `eval --labelled-only` scores (a clip's frames predicted, its last frame
/// labelled). The kept ones still go through [`check_one_to_one`].
pub fn labelled_only(
    preds: Vec<TuSimpleRecord>,
    gts: &[TuSimpleRecord],
) -> (Vec<TuSimpleRecord>, usize) {
    let files: HashSet<&str> = gts.iter().map(|g| g.raw_file.as_str()).collect();
    let n = preds.len();
    let kept: Vec<TuSimpleRecord> = preds
        .into_iter()
        .filter(|p| files.contains(p.raw_file.as_str()))
        .collect();
    let left_out = n - kept.len();
    (kept, left_out)
}

/// The predictions and labels of two files, every column and row multiplied by `scale`
/// (negative "no point" values stay), checked one to one (each labelled frame predicted once;
/// with `labelled_only` the predictions of frames the ground truth does not list are left out
/// first, [`labelled_only`], and counted in the third value).
pub fn read_scaled(
    pred_path: &Path,
    gt_path: &Path,
    scale: f64,
    labelled_only: bool,
) -> Result<(Vec<TuSimpleRecord>, Vec<TuSimpleRecord>, usize)> {
    let mut gts = read_labels(gt_path)?;
    let mut preds = read_predictions(pred_path)?;
    if scale != 1.0 {
        for r in gts.iter_mut().chain(preds.iter_mut()) {
            r.scale_pixels(scale);
        }
    }
    let (preds, left_out) = if labelled_only {
        self::labelled_only(preds, &gts)
    } else {
        (preds, 0)
    };
    check_one_to_one(&preds, &gts).with_context(|| scoring(pred_path, gt_path))?;
    Ok((preds, gts, left_out))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// 20 rows, 100, 110, ..., 290.
    fn rows20() -> Vec<f64> {
        (0..20).map(|j| 100.0 + 10.0 * f64::from(j)).collect()
    }

    /// A vertical lane (constant column `x`) over 20 rows: θ = 0, threshold 20 px.
    fn vertical(x: f64) -> Vec<f64> {
        vec![x; 20]
    }

    /// `n` vertical lanes 200 px apart, the first at column 100.
    fn spaced_verticals(n: u32) -> Vec<Vec<f64>> {
        (0..n)
            .map(|i| vertical(100.0 + 200.0 * f64::from(i)))
            .collect()
    }

    /// `lane` with the first `n` rows moved by `dx`.
    fn off(mut lane: Vec<f64>, n: usize, dx: f64) -> Vec<f64> {
        for v in lane.iter_mut().take(n) {
            *v += dx;
        }
        lane
    }

    fn score(accuracy: f64, fp: f64, fn_: f64) -> FrameScore {
        FrameScore { accuracy, fp, fn_ }
    }

    // ---- lane_rows (a diagnosis, not in the original) ----

    #[test]
    fn lane_rows_sorts_each_row_by_kind() {
        let ys = rows20();
        let mut gt0 = vertical(100.0);
        gt0[..5].fill(NO_POINT);
        let mut p0 = vertical(100.0);
        p0[..2].fill(NO_POINT);
        p0[10..13].fill(150.0);
        p0[18..].fill(NO_POINT);
        let gt = vec![gt0.clone(), vertical(300.0)];
        let pred = vec![p0.clone(), vertical(305.0)];
        let rows = lane_rows(&pred, &gt, &ys);
        let r = &rows[0];
        assert_eq!((r.label, r.pred), (0, Some(0)));
        assert_eq!(
            (r.right, r.both_absent, r.off, r.missing, r.extra),
            (10, 2, 3, 2, 3)
        );
        assert_relative_eq!(r.accuracy, 0.6);
        assert_relative_eq!(r.accuracy, line_accuracy(&p0, &gt0, 20.0));
        assert!(!r.matched && !r.pred_taken);
        assert_eq!(r.labelled(), 15);
        assert!(r.misplaced());
        let r = &rows[1];
        assert_eq!(
            (r.label, r.pred, r.right, r.matched),
            (1, Some(1), 20, true)
        );
        assert_eq!(r.off + r.missing + r.extra + r.both_absent, 0);
    }

    #[test]
    fn lane_rows_pair_as_match_lanes_does() {
        let ys = rows20();
        let gt = spaced_verticals(4);
        // Lane 0 well placed, lane 1 half off, lane 2 a little off on 2 rows (matched), lane 3
        // not predicted; a false lane between 2 and 3.
        let pred = vec![
            vertical(102.0),
            off(vertical(300.0), 10, 40.0),
            off(vertical(500.0), 2, 25.0),
            vertical(600.0),
        ];
        let m = match_lanes(&pred, &gt, &ys);
        let rows = lane_rows(&pred, &gt, &ys);
        assert_eq!(rows.len(), 4);
        for (r, g) in rows.iter().zip(&m.gt_match) {
            assert_eq!(r.matched, g.is_some());
            if let Some(i) = g {
                assert_eq!(r.pred, Some(*i));
            }
            assert_eq!(r.right + r.both_absent + r.off + r.missing + r.extra, 20);
            let correct = (r.right + r.both_absent) as f64 / 20.0;
            assert_relative_eq!(r.accuracy, correct);
        }
        assert_eq!(
            rows.iter().map(|r| r.matched).collect::<Vec<_>>(),
            vec![true, false, true, false]
        );
        assert_eq!((rows[1].off, rows[1].right), (10, 10));
        // Label 3 (at 700) is 0 against every prediction: its best is the first, lane 0's.
        assert_eq!((rows[3].pred, rows[3].pred_taken), (Some(0), true));
        assert_eq!(rows[3].off, 20);
        // A label between two matched lanes: its best prediction is a neighbour's.
        let gt2 = vec![vertical(100.0), vertical(130.0)];
        let rows = lane_rows(&[vertical(100.0)], &gt2, &ys);
        assert!(rows[0].matched && !rows[0].pred_taken);
        assert!(!rows[1].matched && rows[1].pred_taken && !rows[1].misplaced());
    }

    #[test]
    fn lane_rows_without_predictions_count_every_point_missing() {
        let ys = rows20();
        let mut gt0 = vertical(100.0);
        gt0[..4].fill(NO_POINT);
        let rows = lane_rows(&[], &[gt0], &ys);
        let r = &rows[0];
        assert_eq!((r.pred, r.matched), (None, false));
        assert_eq!((r.missing, r.both_absent, r.right), (16, 4, 0));
        assert_eq!(r.labelled(), 16);
        assert!(!r.misplaced());
        assert_relative_eq!(r.accuracy, 0.0);
    }

    // ---- get_angle ----

    #[test]
    fn angle_is_slope_of_x_on_y_with_intercept() {
        // x = 2 y + 5 exactly: dx/dy = 2 (y on x would give 0.5; no intercept would not give 2).
        let ys = [100.0, 110.0, 120.0, 130.0];
        let xs = [205.0, 225.0, 245.0, 265.0];
        assert_relative_eq!(lane_angle(&xs, &ys), 2f64.atan(), epsilon = 1e-12);
        assert_relative_eq!(
            lane_threshold(lane_angle(&xs, &ys)),
            20.0 * 5f64.sqrt(),
            epsilon = 1e-9
        );
    }

    #[test]
    fn angle_is_least_squares_over_points_with_x_at_least_zero() {
        // Valid (y, x): (0, 0), (1, 2), (2, 3); the -2 row is left out. Mean y 1, mean x 5/3:
        // k = ((-1)(-5/3) + 0 + (1)(4/3)) / 2 = 1.5. (Dropping x = 0 too would give k = 1;
        // keeping the -2 row would give k = 0.)
        let xs = [0.0, 2.0, 3.0, -2.0];
        let ys = [0.0, 1.0, 2.0, 3.0];
        assert_relative_eq!(lane_angle(&xs, &ys), 1.5f64.atan(), epsilon = 1e-12);
    }

    #[test]
    fn angle_is_zero_with_fewer_than_two_points() {
        let ys = [0.0, 1.0, 2.0];
        assert_eq!(lane_angle(&[-2.0, 7.0, -2.0], &ys), 0.0);
        assert_eq!(lane_angle(&[-2.0, -2.0, -2.0], &ys), 0.0);
        assert_eq!(lane_threshold(0.0), 20.0);
    }

    // ---- match_lanes ----

    #[test]
    fn matches_follow_the_best_accuracy_rule() {
        let ys = rows20();
        let (a, b) = (vertical(300.0), vertical(600.0));
        // Prediction 0 is 10 px off a on every row, prediction 1 exact on a, prediction 2 is
        // a with 4 rows off (0.8 < 0.85), prediction 3 far from both.
        let preds = vec![
            vertical(310.0),
            a.clone(),
            off(a.clone(), 4, 50.0),
            vertical(900.0),
        ];
        let m = match_lanes(&preds, &[a.clone(), b.clone()], &ys);
        assert_eq!(m.gt_match, vec![Some(0), None]);
        assert_eq!(m.pred_matched, vec![true, true, false, false]);
        // Only the 0.8 prediction: no match.
        let m = match_lanes(&[off(a.clone(), 4, 50.0)], std::slice::from_ref(&a), &ys);
        assert_eq!(m.gt_match, vec![None]);
        // 3 rows off: 0.85 matches (≥, as bench's pt_thresh).
        let m = match_lanes(&[off(a.clone(), 3, 50.0), b.clone()], &[a, b], &ys);
        assert_eq!(m.gt_match, vec![Some(0), Some(1)]);
        assert_eq!(m.pred_matched, vec![true, true]);
        assert_eq!(match_lanes(&[], &[vertical(1.0)], &ys).gt_match, vec![None]);
    }

    // ---- line_accuracy ----

    #[test]
    fn point_threshold_is_strict() {
        let gt = [300.0, 300.0];
        assert_eq!(line_accuracy(&[319.9, 280.1], &gt, 20.0), 1.0);
        assert_eq!(line_accuracy(&[320.0, 280.0], &gt, 20.0), 0.0);
        assert_eq!(line_accuracy(&[320.0, 300.0], &gt, 20.0), 0.5);
    }

    #[test]
    fn threshold_widens_with_the_lane_angle() {
        // x = 2 y + 5 over 20 rows: threshold 20·√5 ≈ 44.72 px.
        let ys = rows20();
        let gt: Vec<f64> = ys.iter().map(|y| 2.0 * y + 5.0).collect();
        let shift = |d: f64| gt.iter().map(|x| x + d).collect::<Vec<_>>();
        assert_eq!(
            bench(&[shift(44.0)], std::slice::from_ref(&gt), &ys, 0.0).unwrap(),
            score(1.0, 0.0, 0.0)
        );
        assert_eq!(
            bench(&[shift(45.0)], std::slice::from_ref(&gt), &ys, 0.0).unwrap(),
            score(0.0, 1.0, 1.0)
        );
        // The same 44 px shift on a vertical lane (threshold 20) misses everywhere.
        let v = vertical(300.0);
        assert_eq!(
            bench(&[off(v.clone(), 20, 44.0)], &[v], &ys, 0.0).unwrap(),
            score(0.0, 1.0, 1.0)
        );
    }

    #[test]
    fn missing_points_compare_as_minus_100_over_all_rows() {
        // row 0: gt 10, pred missing -> wrong; row 1: both missing -> correct;
        // row 2: gt missing, pred 50 -> |50 + 100| = 150, wrong; row 3: equal -> correct.
        let gt = [10.0, -2.0, -2.0, 30.0];
        let pred = [-2.0, -2.0, 50.0, 30.0];
        assert_eq!(line_accuracy(&pred, &gt, 20.0), 0.5);
        // Any negative value is "missing", not just -2.
        assert_eq!(line_accuracy(&[-1.0, -7.5], &[-2.0, -2.0], 20.0), 1.0);
        // A predicted point at column 0 next to a missing truth is |0 + 100| = 100 away: correct
        // only with a threshold above 100 (a lane at more than ~78° from vertical).
        assert_eq!(line_accuracy(&[0.0], &[-2.0], 20.0), 0.0);
        assert_eq!(line_accuracy(&[0.0], &[-2.0], 100.5), 1.0);
    }

    #[test]
    fn missing_rows_of_the_truth_stay_in_the_denominator() {
        // gt valid on 10 of 20 rows; pred exact where valid, missing elsewhere -> 20/20.
        let ys = rows20();
        let mut gt = vertical(300.0);
        gt.iter_mut().skip(10).for_each(|v| *v = -2.0);
        assert_eq!(
            bench(
                std::slice::from_ref(&gt),
                std::slice::from_ref(&gt),
                &ys,
                0.0
            )
            .unwrap(),
            score(1.0, 0.0, 0.0)
        );
        // pred exact where valid, but present (300) where the truth is missing -> 10/20.
        assert_eq!(
            bench(&[vertical(300.0)], std::slice::from_ref(&gt), &ys, 0.0).unwrap(),
            score(0.5, 1.0, 1.0)
        );
        // pred missing where the truth is valid: the 10 missing-missing rows count -> 10/20.
        assert_eq!(
            bench(&[vec![-2.0; 20]], &[gt], &ys, 0.0).unwrap(),
            score(0.5, 1.0, 1.0)
        );
    }

    // ---- bench ----

    #[test]
    fn lane_matches_at_85_percent_of_points() {
        let ys = rows20();
        let gt = vertical(300.0);
        // 17 of 20 rows correct: 0.85, matched.
        let p = off(gt.clone(), 3, 50.0);
        assert_eq!(
            bench(&[p], std::slice::from_ref(&gt), &ys, 0.0).unwrap(),
            score(0.85, 0.0, 0.0)
        );
        // 16 of 20 rows correct: 0.8, a false negative, and the prediction a false positive.
        let p = off(gt.clone(), 4, 50.0);
        assert_eq!(bench(&[p], &[gt], &ys, 0.0).unwrap(), score(0.8, 1.0, 1.0));
    }

    #[test]
    fn accuracy_averages_best_matches_and_fp_fn_count_lanes() {
        let ys = rows20();
        let gt = vec![vertical(100.0), vertical(300.0), vertical(500.0)];
        // Best accuracies 1.0, 0.9 (2 rows off), 0.0 (nothing near 500).
        let pred = vec![
            vertical(100.0),
            off(vertical(300.0), 2, 50.0),
            vertical(700.0),
        ];
        let f = bench(&pred, &gt, &ys, 0.0).unwrap();
        assert_relative_eq!(f.accuracy, 1.9 / 3.0, epsilon = 1e-15);
        assert_relative_eq!(f.fp, 1.0 / 3.0, epsilon = 1e-15);
        assert_relative_eq!(f.fn_, 1.0 / 3.0, epsilon = 1e-15);
    }

    #[test]
    fn best_match_is_not_one_to_one_so_fp_can_be_negative() {
        // One prediction within 20 px of two ground-truth lanes matches both:
        // matched 2, fp = 1 - 2 = -1, divided by 1 prediction.
        let ys = rows20();
        let gt = vec![vertical(300.0), vertical(310.0)];
        let f = bench(&[vertical(305.0)], &gt, &ys, 0.0).unwrap();
        assert_eq!(f, score(1.0, -1.0, 0.0));
    }

    #[test]
    fn more_than_four_lanes_drops_the_worst_and_forgives_one_fn() {
        let ys = rows20();
        let gt5 = spaced_verticals(5);
        // Fifth prediction far off: accs [1, 1, 1, 1, 0] -> s = 4 - 0, /4; fn 1 -> 0; fp 1/5.
        let mut pred = gt5.clone();
        pred[4] = vertical(1200.0);
        assert_eq!(bench(&pred, &gt5, &ys, 0.0).unwrap(), score(1.0, 0.2, 0.0));
        // Fifth prediction half right (0.5): still dropped from the sum although it exists.
        let mut pred = gt5.clone();
        pred[4] = off(gt5[4].clone(), 10, 50.0);
        assert_eq!(bench(&pred, &gt5, &ys, 0.0).unwrap(), score(1.0, 0.2, 0.0));
        // Fifth ground-truth lane matched at 0.9: no FN to forgive, the 0.9 is still dropped.
        let mut pred = gt5.clone();
        pred[4] = off(gt5[4].clone(), 2, 50.0);
        assert_eq!(bench(&pred, &gt5, &ys, 0.0).unwrap(), score(1.0, 0.0, 0.0));
        // Exactly 4 lanes: nothing dropped or forgiven: (1+1+1+0)/4, fp 1/4, fn 1/4.
        let gt4 = gt5[..4].to_vec();
        let mut pred = gt4.clone();
        pred[3] = vertical(1200.0);
        assert_eq!(
            bench(&pred, &gt4, &ys, 0.0).unwrap(),
            score(0.75, 0.25, 0.25)
        );
    }

    #[test]
    fn fn_is_divided_by_at_most_four_lanes() {
        let ys = rows20();
        let gt6 = spaced_verticals(6);
        // First 4 found: accs [1, 1, 1, 1, 0, 0]; fn 2 -> 1, / 4; s = 4 - 0, / 4; fp 0 / 4.
        let pred = gt6[..4].to_vec();
        assert_eq!(bench(&pred, &gt6, &ys, 0.0).unwrap(), score(1.0, 0.0, 0.25));
        // Nothing predicted: fn 6 -> 5, / 4 = 1.25 (above 1); accuracy 0; fp 0 (no predictions).
        assert_eq!(bench(&[], &gt6, &ys, 0.0).unwrap(), score(0.0, 0.0, 1.25));
    }

    #[test]
    fn empty_frames() {
        let ys = rows20();
        // No ground truth, two predictions: accuracy 0 / 1, fp 2 / 2, fn 0 / 1.
        let pred = vec![vertical(100.0), vertical(300.0)];
        assert_eq!(bench(&pred, &[], &ys, 0.0).unwrap(), score(0.0, 1.0, 0.0));
        assert_eq!(bench(&[], &[], &ys, 0.0).unwrap(), score(0.0, 0.0, 0.0));
        // Ground truth, no predictions: best accuracy 0 for each lane.
        assert_eq!(
            bench(&[], &[vertical(1.0)], &ys, 0.0).unwrap(),
            score(0.0, 0.0, 1.0)
        );
    }

    #[test]
    fn run_time_over_200_ms_is_penalised() {
        let ys = rows20();
        let gt = vec![vertical(300.0)];
        assert_eq!(bench(&gt, &gt, &ys, 200.0).unwrap(), score(1.0, 0.0, 0.0));
        assert_eq!(bench(&gt, &gt, &ys, 200.001).unwrap(), PENALTY);
        assert_eq!(PENALTY, score(0.0, 0.0, 1.0));
    }

    #[test]
    fn more_than_gt_plus_two_lanes_is_penalised() {
        let ys = rows20();
        let gt = vec![vertical(100.0), vertical(300.0)];
        let junk = |x: f64| vertical(x);
        // 4 = 2 + 2 predictions: scored normally (2 matched, 2 FP of 4).
        let pred4 = vec![gt[0].clone(), gt[1].clone(), junk(600.0), junk(900.0)];
        assert_eq!(bench(&pred4, &gt, &ys, 0.0).unwrap(), score(1.0, 0.5, 0.0));
        // 5 predictions: penalty, although both lanes are found.
        let mut pred5 = pred4;
        pred5.push(junk(1100.0));
        assert_eq!(bench(&pred5, &gt, &ys, 0.0).unwrap(), PENALTY);
    }

    #[test]
    fn wrong_lane_length_is_an_error_even_when_penalised() {
        let ys = rows20();
        let gt = vec![vertical(300.0)];
        let short = vec![300.0; 19];
        let e = bench(std::slice::from_ref(&short), &gt, &ys, 0.0).unwrap_err();
        assert!(
            format!("{e}").contains("predicted lane 0 has 19 values"),
            "{e}"
        );
        assert!(bench(&[short], &gt, &ys, 500.0).is_err());
        // A bad ground-truth lane is reported too (after the penalty check, like the original).
        assert!(bench(&gt, &[vec![300.0; 19]], &ys, 0.0).is_err());
    }

    // ---- bench_one_submit ----

    fn rec(name: &str, lanes: Vec<Vec<f64>>, run_time: Option<f64>) -> TuSimpleRecord {
        TuSimpleRecord {
            raw_file: name.into(),
            lanes,
            h_samples: rows20(),
            run_time,
        }
    }

    #[test]
    fn submission_averages_frames_over_ground_truth_frames() {
        let gts = vec![
            rec("a", vec![vertical(100.0), vertical(300.0)], None),
            rec("b", vec![vertical(100.0)], None),
        ];
        // Prediction order differs from the ground truth's; b is too slow (0, 0, 1);
        // a finds one of its two lanes: (1 + 0) / 2, fp 0 / 1, fn 1 / 2.
        let preds = vec![
            rec("b", vec![vertical(100.0)], Some(250.0)),
            rec("a", vec![vertical(100.0)], Some(5.0)),
        ];
        let s = bench_one_submit(&preds, &gts).unwrap();
        assert_eq!(s.frames, 2);
        assert_eq!(s.accuracy, 0.25);
        assert_eq!(s.fp, 0.0);
        assert_eq!(s.fn_, 0.75);
        check_one_to_one(&preds, &gts).unwrap();
    }

    #[test]
    fn submission_errors_like_the_original() {
        let gts = vec![rec("a", vec![vertical(1.0)], None), rec("b", vec![], None)];
        let ok = |n: &str| rec(n, vec![vertical(1.0)], Some(1.0));
        // Count mismatch.
        let e = bench_one_submit(&[ok("a")], &gts).unwrap_err();
        assert!(
            format!("{e}").contains("1 predictions for 2 ground-truth frames"),
            "{e}"
        );
        // Unknown raw_file.
        let e = bench_one_submit(&[ok("a"), ok("zzz")], &gts).unwrap_err();
        assert!(format!("{e}").contains("zzz"), "{e}");
        // Missing run_time.
        let e = bench_one_submit(&[ok("a"), rec("b", vec![], None)], &gts).unwrap_err();
        assert!(format!("{e}").contains("run_time missing"), "{e}");
        // Lane format error, with the frame named.
        let e =
            bench_one_submit(&[ok("a"), rec("b", vec![vec![1.0]], Some(1.0))], &gts).unwrap_err();
        assert!(
            format!("{e:#}").contains("(b): format of lanes error"),
            "{e:#}"
        );
        // Nothing at all.
        assert!(bench_one_submit(&[], &[]).is_err());
    }

    /// A prediction whose stated rows are not its ground truth's (here: a 512×288 frame's
    /// rows against 1280×720 labels) is an error, not a score of columns at the wrong rows;
    /// rows within half a pixel and predictions without `h_samples` pass.
    #[test]
    fn predictions_at_other_rows_are_rejected_by_the_check() {
        let gts = vec![rec("a", vec![vertical(100.0)], None)];
        let mut pred = rec("a", vec![vertical(100.0)], Some(1.0));
        check_one_to_one(std::slice::from_ref(&pred), &gts).unwrap();
        pred.h_samples.iter_mut().for_each(|h| *h += 0.25);
        check_one_to_one(std::slice::from_ref(&pred), &gts).unwrap();
        pred.h_samples.clear();
        check_one_to_one(std::slice::from_ref(&pred), &gts).unwrap();
        pred.h_samples = rows20().iter().map(|h| h * 0.4).collect();
        let e = check_one_to_one(std::slice::from_ref(&pred), &gts).unwrap_err();
        assert!(
            format!("{e}").contains("prediction for a: its h_samples (20 rows 40–116)"),
            "{e}"
        );
        assert!(format!("{e}").contains("(20 rows 100–290)"), "{e}");
    }

    #[test]
    fn repeated_raw_files_are_scored_as_the_original_does_but_rejected_by_the_check() {
        // Two ground-truth lines for "a" (the last, lane at 300, wins) and two predictions for
        // "a": 2 frames summed, divided by 1 distinct raw_file -> accuracy 2.
        let gts = vec![
            rec("a", vec![vertical(100.0)], None),
            rec("a", vec![vertical(300.0)], None),
        ];
        let preds = vec![
            rec("a", vec![vertical(300.0)], Some(1.0)),
            rec("a", vec![vertical(300.0)], Some(1.0)),
        ];
        let s = bench_one_submit(&preds, &gts).unwrap();
        assert_eq!((s.accuracy, s.fp, s.fn_, s.frames), (2.0, 0.0, 0.0, 1));
        assert!(check_one_to_one(&preds, &gts).is_err());
        // Distinct ground truth, a repeated prediction and a frame without one.
        let gts = vec![rec("a", vec![], None), rec("b", vec![], None)];
        let preds = vec![rec("a", vec![], Some(1.0)), rec("a", vec![], Some(1.0))];
        let e = check_one_to_one(&preds, &gts).unwrap_err();
        assert!(format!("{e}").contains("more than once"), "{e}");
        let preds = vec![rec("a", vec![], Some(1.0))];
        let e = check_one_to_one(&preds, &gts[..]).unwrap_err();
        assert!(
            format!("{e}").contains("no prediction for ground-truth frame b"),
            "{e}"
        );
    }
}
