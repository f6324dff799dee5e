//! CULane-style lane files to and from the TuSimple records the tools read and write.
//!
//! CULane (and datasets in its format: CurveLanes, many detectors' outputs) stores the lanes of
//! image `a/b/00030.jpg` in `a/b/00030.lines.txt`: one lane a line, its points as `x y` pairs in
//! image pixels (column, row), usually every 10 rows from the bottom of the image up. The tools
//! score, train and track TuSimple records (one JSON line an image: the lanes' columns at shared
//! rows `h_samples`), so:
//!
//! - [`read_dir`] turns a folder of lane files into records: each image's rows are every
//!   `row_step` pixels over the rows its lanes cover (or a labels file's rows for the same
//!   image), a lane's column at a row is interpolated linearly between its two nearest points
//!   (no point beyond its ends, or outside the camera's image: `-2`);
//! - [`frames`] turns those records into frames of points for `stjpdacf track` (every image row
//!   between a lane's points, like the demo's "label points" row): labels as a perfect detector,
//!   or a per-frame detector's own lane files, tracked over time;
//! - [`lines_text`] writes a record back as a lane file, for CULane's own evaluator.
//!
//! `stjpdacf convert` is the command-line face of this module.
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};

use crate::camera::Camera;
use crate::frontend::{find_files, frame_number, raw_file_of};
use crate::tusimple::{Frame, TuSimpleRecord, NO_POINT};

/// The suffix of a CULane lane file (`00030.lines.txt` beside `00030.jpg`).
pub const SUFFIX: &str = ".lines.txt";

/// A lane: its points `[x, y]` (column, row; image pixels).
pub type Lane = Vec<[f64; 2]>;

/// Parses one lane file: a lane a non-empty line, `x y` pairs separated by white space (a
/// byte-order mark at the start is skipped). A line with an odd count of numbers or a value
/// that is not a finite number is an error naming the line. A lane of one point is returned
/// (CULane's evaluator cannot draw it; [`to_record`] leaves it out).
pub fn parse_lines(text: &str) -> Result<Vec<Lane>> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lanes = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|w| {
                w.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .with_context(|| {
                        let hint = if w.contains(',') || w.contains(';') {
                            " (values are separated by spaces: `x y x y …`)"
                        } else {
                            ""
                        };
                        format!("line {}: {w:?} is not a finite number{hint}", i + 1)
                    })
            })
            .collect::<Result<_>>()?;
        if v.is_empty() {
            continue;
        }
        ensure!(
            v.len() % 2 == 0,
            "line {}: {} numbers; a lane is `x y` pairs",
            i + 1,
            v.len()
        );
        lanes.push(v.chunks_exact(2).map(|p| [p[0], p[1]]).collect());
    }
    Ok(lanes)
}

/// The rows a record is sampled at.
#[derive(Debug, Clone, Copy)]
pub enum Rows<'a> {
    /// Every `step` pixels (multiples of it) from the topmost to the bottommost row the lanes
    /// cover inside the image; an image without such lanes gets the multiples of `step` from
    /// the camera's horizon down, so that it has rows to be scored at.
    Step(f64),
    /// These rows (a label's `h_samples`).
    Given(&'a [f64]),
}

/// What [`to_record`] left out.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Dropped {
    /// Lane points outside the camera's image (columns `< 0` or `≥ width`, rows `< 0` or
    /// `> height`): a lane is sampled only inside it.
    pub outside_points: usize,
    /// Lanes with fewer than two points, or without a point at any of the rows.
    pub lanes: usize,
}

/// The TuSimple record of an image's lanes, sampled at `rows` (see [`Rows`]): each lane's
/// column at each row, interpolated linearly between the two points around the row (in the row
/// order of the lane's points), [`NO_POINT`] outside the lane's rows or outside `camera`'s
/// image. Lanes with fewer than two points, or no point at any row, are left out; what was
/// left out is counted in the second value.
pub fn to_record(
    raw_file: String,
    lanes: &[Lane],
    rows: Rows,
    camera: &Camera,
) -> (TuSimpleRecord, Dropped) {
    let inside_x = |x: f64| (0.0..camera.width).contains(&x);
    // Row `height` is the bottom edge (CULane labels its 590-row images at row 590).
    let inside_y = |y: f64| (0.0..=camera.height).contains(&y);
    let mut dropped = Dropped {
        outside_points: lanes
            .iter()
            .flatten()
            .filter(|p| !(inside_x(p[0]) && inside_y(p[1])))
            .count(),
        lanes: 0,
    };
    let grid = |top: f64, bottom: f64, step: f64| -> Vec<f64> {
        let first = (top / step).ceil() as i64;
        let last = (bottom / step).floor() as i64;
        (first..=last).map(|k| k as f64 * step).collect()
    };
    let h_samples: Vec<f64> = match rows {
        Rows::Given(h) => h.to_vec(),
        Rows::Step(step) => {
            let (top, bottom) = lanes
                .iter()
                .filter(|l| l.len() >= 2)
                .flatten()
                .map(|p| p[1].clamp(0.0, camera.height))
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
                    (a.min(y), b.max(y))
                });
            let rows = if top <= bottom {
                grid(top, bottom, step)
            } else {
                Vec::new()
            };
            if rows.is_empty() {
                grid(camera.vp_row.max(0.0), camera.height - 1.0, step)
            } else {
                rows
            }
        }
    };
    let mut out = Vec::with_capacity(lanes.len());
    for lane in lanes {
        let mut pts = lane.clone();
        pts.sort_by(|a, b| a[1].total_cmp(&b[1]));
        let xs: Vec<f64> = h_samples
            .iter()
            .map(|&h| {
                let x = if pts.len() >= 2 && inside_y(h) {
                    column_at(&pts, h)
                } else {
                    NO_POINT
                };
                if inside_x(x) {
                    x
                } else {
                    NO_POINT
                }
            })
            .collect();
        if xs.iter().any(|&x| x >= 0.0) {
            out.push(xs);
        } else {
            dropped.lanes += 1;
        }
    }
    let record = TuSimpleRecord {
        raw_file,
        lanes: out,
        h_samples,
        run_time: None,
    };
    (record, dropped)
}

/// The column of a lane (points sorted by row) at row `h`, [`NO_POINT`] outside its rows.
fn column_at(pts: &[[f64; 2]], h: f64) -> f64 {
    pts.windows(2)
        .find(|w| w[0][1] <= h && h <= w[1][1])
        .map_or(NO_POINT, |w| {
            let ([x0, y0], [x1, y1]) = (w[0], w[1]);
            if y1 > y0 {
                x0 + (x1 - x0) * (h - y0) / (y1 - y0)
            } else {
                x0
            }
        })
}

/// What [`read_dir`] read and left out.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ReadReport {
    /// Lane files read (images).
    pub files: usize,
    /// Lanes kept.
    pub lanes: usize,
    /// Summed over the files ([`to_record`]).
    pub dropped: Dropped,
    /// With labels: the lane files whose image the labels name.
    pub labelled: usize,
    /// With labels: the first lane file's image the labels do not name.
    pub unlabelled_example: Option<String>,
    /// With labels: the first labelled image without a lane file here, and how many there are.
    pub missing_example: Option<(String, usize)>,
}

/// The records of every lane file under `dir` (recursively), in the order `frontend` reads
/// images: by folder, then by frame number, then by name. `raw_file` is the image's path
/// relative to `dir` (the lane file's, with the extension of an image beside it, `.jpg` when
/// there is none). Each is sampled every `row_step` rows ([`Rows::Step`]) or, with `labels`,
/// at the rows of the label of the same `raw_file` (an image the labels do not name: its own
/// rows), inside `camera`'s image. An empty lane file is an image without lanes; a folder
/// without lane files is an error.
pub fn read_dir(
    dir: &Path,
    row_step: f64,
    camera: &Camera,
    labels: Option<&[TuSimpleRecord]>,
) -> Result<(Vec<TuSimpleRecord>, ReadReport)> {
    ensure!(
        row_step.is_finite() && row_step > 0.0 && row_step < camera.height,
        "the row step must be a positive number of pixels under the image's {} rows, not \
         {row_step}",
        camera.height
    );
    let files = find_files(dir, |p| {
        p.file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.ends_with(SUFFIX))
    })?;
    if files.is_empty() {
        bail!("no *{SUFFIX} lane files under {}", dir.display());
    }
    let mut rep = ReadReport::default();
    let mut records = Vec::with_capacity(files.len());
    for f in &files {
        let text = std::fs::read_to_string(f)
            .with_context(|| format!("reading lane file {}", f.display()))?;
        let lanes = parse_lines(&text).with_context(|| format!("{}", f.display()))?;
        let raw_file = image_of(dir, f);
        let label = labels.and_then(|l| l.iter().find(|l| l.raw_file == raw_file));
        match (labels, label) {
            (Some(_), Some(_)) => rep.labelled += 1,
            (Some(_), None) if rep.unlabelled_example.is_none() => {
                rep.unlabelled_example = Some(raw_file.clone())
            }
            _ => {}
        }
        let rows = label.map_or(Rows::Step(row_step), |l| Rows::Given(&l.h_samples));
        let (r, d) = to_record(raw_file, &lanes, rows, camera);
        rep.files += 1;
        rep.lanes += r.lanes.len();
        rep.dropped.outside_points += d.outside_points;
        rep.dropped.lanes += d.lanes;
        records.push(r);
    }
    if let Some(labels) = labels {
        let missing: Vec<&TuSimpleRecord> = labels
            .iter()
            .filter(|l| !records.iter().any(|r| r.raw_file == l.raw_file))
            .collect();
        rep.missing_example = missing.first().map(|l| (l.raw_file.clone(), missing.len()));
    }
    Ok((records, rep))
}

/// The image a lane file belongs to, relative to `dir` (`a/00030.lines.txt` → `a/00030.jpg`,
/// or the extension of an image with that stem beside it: `png`, `jpeg`, any case).
fn image_of(dir: &Path, lane_file: &Path) -> String {
    let raw = raw_file_of(dir, lane_file);
    let Some(stem) = raw.strip_suffix(SUFFIX) else {
        return raw;
    };
    let name = lane_file
        .file_name()
        .and_then(|n| n.to_str())
        .and_then(|n| n.strip_suffix(SUFFIX))
        .unwrap_or_default();
    let ext = ["jpg", "png", "jpeg", "JPG", "PNG", "JPEG"]
        .into_iter()
        .find(|e| lane_file.with_file_name(format!("{name}.{e}")).is_file())
        .unwrap_or("jpg");
    format!("{stem}.{ext}")
}

/// The lane file of a record's image, under `dir` (`a/00030.jpg` → `dir/a/00030.lines.txt`).
/// A `raw_file` that would leave `dir` (absolute, or with a `..` component) is an error.
pub fn lane_file_of(dir: &Path, raw_file: &str) -> Result<PathBuf> {
    let rel = Path::new(raw_file);
    ensure!(
        rel.components().all(|c| matches!(
            c,
            std::path::Component::Normal(_) | std::path::Component::CurDir
        )),
        "raw_file {raw_file:?} is not a relative path inside the output folder"
    );
    let stem = raw_file
        .rsplit_once('.')
        .filter(|(_, ext)| !ext.contains('/'))
        .map_or(raw_file, |(stem, _)| stem);
    Ok(dir.join(format!("{stem}{SUFFIX}")))
}

/// Frames of the records' lanes as feature points (image pixels): every image row between two
/// of a lane's points at its `h_samples` (linear interpolation), `clip` = the image's folder,
/// `t` = its frame number / `fps` (CULane's `00030.jpg`: frame 30, 1 s at 30 fps) or its index
/// in the folder / `fps` for other names, `raw_file` the record's, `camera` the given one.
/// `h_samples` (the rows `track` writes a prediction at): with `labels`, those of the label of
/// the same `raw_file` (none without one: no prediction), else the record's own. Times must
/// increase within a folder. Also returns how many files had no frame number (timed by their
/// order).
pub fn frames(
    records: &[TuSimpleRecord],
    fps: f64,
    camera: &Camera,
    labels: Option<&[TuSimpleRecord]>,
) -> Result<(Vec<Frame>, usize)> {
    ensure!(
        fps.is_finite() && fps > 0.0,
        "fps must be a positive number, not {fps}"
    );
    let mut out: Vec<Frame> = Vec::with_capacity(records.len());
    let mut index = 0usize;
    let mut unnumbered = 0usize;
    for r in records {
        let mut f = crate::demo::label_points_frame(r);
        index = match out.last() {
            Some(prev) if prev.clip == f.clip => index + 1,
            _ => 0,
        };
        let number = frame_number(Path::new(&r.raw_file));
        unnumbered += usize::from(number.is_none());
        f.t = number.map_or(index as f64, |n| n as f64) / fps;
        f.camera = Some(*camera);
        if let Some(labels) = labels {
            f.h_samples = labels
                .iter()
                .find(|l| l.raw_file == r.raw_file)
                .map(|l| l.h_samples.clone());
        }
        if let Some(prev) = out.last().filter(|prev| prev.clip == f.clip) {
            let prev_file = prev.raw_file.as_deref().unwrap_or_default();
            ensure!(
                f.t > prev.t,
                "{}: time {} s is not after {prev_file}'s {} s: {}",
                r.raw_file,
                f.t,
                prev.t,
                if number.is_some() && number == frame_number(Path::new(prev_file)) {
                    "two files of one folder have the same frame number"
                } else {
                    "a file named by a number n is frame n, other names are numbered in order, \
                     so a folder must not mix them"
                }
            );
        }
        f.check().with_context(|| r.raw_file.clone())?;
        out.push(f);
    }
    Ok((out, unnumbered))
}

/// A record's lanes as a CULane lane file: a lane a line, its points (`x ≥ 0`) as `x y` pairs
/// from the bottom row up, as CULane writes them; lanes with fewer than two points are left
/// out (CULane's evaluator draws a lane through its points).
pub fn lines_text(r: &TuSimpleRecord) -> String {
    let mut s = String::new();
    for lane in &r.lanes {
        let mut pts: Vec<(f64, f64)> = r.points_of(lane).collect();
        if pts.len() < 2 {
            continue;
        }
        pts.sort_by(|a, b| b.1.total_cmp(&a.1));
        let line: Vec<String> = pts.iter().map(|(x, y)| format!("{x:.2} {y:.0}")).collect();
        s.push_str(&line.join(" "));
        s.push('\n');
    }
    s
}

/// CULane's metric over a set of images: lanes drawn `width` px wide (30 in CULane's evaluator)
/// on the image, a predicted and a labelled lane match when the intersection over union of
/// their pixels exceeds `iou` (0.5), predictions and labels paired one to one for the largest
/// summed IoU (Hungarian); true positives, false positives and misses summed over the images.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct F1Score {
    /// Predicted lanes matched to a labelled one.
    pub tp: usize,
    /// Predicted lanes not matched.
    pub fp: usize,
    /// Labelled lanes not matched.
    #[serde(rename = "fn")]
    pub fn_: usize,
    /// `tp / (tp + fp)` (1 without predictions).
    pub precision: f64,
    /// `tp / (tp + fn)` (1 without labels).
    pub recall: f64,
    /// Harmonic mean of precision and recall (0 when both are 0).
    pub f1: f64,
}

/// The pixels of an image `size = (columns, rows)` within `width / 2` of a lane's polyline
/// (its points at their integer pixel, as CULane's evaluators draw them), as a bit set.
fn lane_mask(points: &[(f64, f64)], width: f64, size: (usize, usize)) -> Vec<u64> {
    let (w, h) = size;
    let mut bits = vec![0u64; (w * h).div_ceil(64)];
    let r = width / 2.0;
    let pts: Vec<(f64, f64)> = points
        .iter()
        .map(|&(x, y)| (x.trunc(), y.trunc()))
        .collect();
    let segments: Vec<((f64, f64), (f64, f64))> = if pts.len() == 1 {
        vec![(pts[0], pts[0])]
    } else {
        pts.windows(2).map(|s| (s[0], s[1])).collect()
    };
    for ((x0, y0), (x1, y1)) in segments {
        let (dx, dy) = (x1 - x0, y1 - y0);
        let len2 = dx * dx + dy * dy;
        let clip = |v: f64, n: usize| v.clamp(0.0, n as f64 - 1.0) as usize;
        let (cx0, cx1) = (clip(x0.min(x1) - r, w), clip(x0.max(x1) + r, w));
        let (cy0, cy1) = (clip(y0.min(y1) - r, h), clip(y0.max(y1) + r, h));
        for py in cy0..=cy1 {
            for px in cx0..=cx1 {
                let (qx, qy) = (px as f64 - x0, py as f64 - y0);
                let t = if len2 > 0.0 {
                    ((qx * dx + qy * dy) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let (ex, ey) = (qx - t * dx, qy - t * dy);
                if ex * ex + ey * ey <= r * r {
                    let k = py * w + px;
                    bits[k / 64] |= 1 << (k % 64);
                }
            }
        }
    }
    bits
}

/// Intersection over union of two pixel sets (0 when both are empty).
fn iou_of(a: &[u64], b: &[u64]) -> f64 {
    let (mut inter, mut union) = (0u64, 0u64);
    for (x, y) in a.iter().zip(b) {
        inter += u64::from((x & y).count_ones());
        union += u64::from((x | y).count_ones());
    }
    if union == 0 {
        0.0
    } else {
        inter as f64 / union as f64
    }
}

/// The lanes of one image matched by [`F1Score`]'s rule: `(tp, fp, fn)`.
fn match_image(
    pred: &[Vec<(f64, f64)>],
    gt: &[Vec<(f64, f64)>],
    width: f64,
    iou: f64,
    size: (usize, usize),
) -> Result<(usize, usize, usize)> {
    if pred.is_empty() || gt.is_empty() {
        return Ok((0, pred.len(), gt.len()));
    }
    let pm: Vec<Vec<u64>> = pred.iter().map(|l| lane_mask(l, width, size)).collect();
    let gm: Vec<Vec<u64>> = gt.iter().map(|l| lane_mask(l, width, size)).collect();
    // Rows the smaller set (the solver assigns every row), IoU in millionths.
    let (rows, cols) = if pm.len() <= gm.len() {
        (&pm, &gm)
    } else {
        (&gm, &pm)
    };
    let ious: Vec<Vec<f64>> = rows
        .iter()
        .map(|a| cols.iter().map(|b| iou_of(a, b)).collect())
        .collect();
    let weights = pathfinding::matrix::Matrix::from_rows(ious.iter().map(|r| {
        r.iter()
            .map(|v| (v * 1e6).round() as i64)
            .collect::<Vec<_>>()
    }))
    .map_err(|e| anyhow::anyhow!("the IoU matrix: {e:?}"))?;
    let (_, assignment) = pathfinding::kuhn_munkres::kuhn_munkres(&weights);
    let tp = assignment
        .iter()
        .enumerate()
        .filter(|&(r, &c)| ious[r][c] > iou)
        .count();
    Ok((tp, pred.len() - tp, gt.len() - tp))
}

/// [`F1Score`] of predictions against labels (one prediction a labelled image, as
/// [`crate::metric::read_scaled`] checks): each record's lanes are the polylines through their
/// points at `h_samples` (`x ≥ 0`), drawn on an image of `size = (columns, rows)`. CULane's
/// evaluator draws cubic splines through the points; on lanes sampled every 10 rows the
/// polyline is within a pixel of them.
pub fn f1_score(
    preds: &[TuSimpleRecord],
    gts: &[TuSimpleRecord],
    width: f64,
    iou: f64,
    size: (usize, usize),
) -> Result<F1Score> {
    let lanes = |r: &TuSimpleRecord| -> Vec<Vec<(f64, f64)>> {
        r.lanes
            .iter()
            .map(|l| r.points_of(l).collect::<Vec<_>>())
            .filter(|l: &Vec<(f64, f64)>| !l.is_empty())
            .collect()
    };
    let (mut tp, mut fp, mut fn_) = (0, 0, 0);
    for g in gts {
        let pred = preds
            .iter()
            .find(|p| p.raw_file == g.raw_file)
            .map(|p| {
                // A prediction's lanes at the label's rows when it names none of its own.
                let mut p = p.clone();
                if p.h_samples.is_empty() {
                    p.h_samples = g.h_samples.clone();
                }
                lanes(&p)
            })
            .unwrap_or_default();
        let (t, f, n) = match_image(&pred, &lanes(g), width, iou, size)?;
        tp += t;
        fp += f;
        fn_ += n;
    }
    let ratio = |a: usize, b: usize| {
        if a + b == 0 {
            1.0
        } else {
            a as f64 / (a + b) as f64
        }
    };
    let (precision, recall) = (ratio(tp, fp), ratio(tp, fn_));
    let f1 = if precision + recall > 0.0 {
        2.0 * precision * recall / (precision + recall)
    } else {
        0.0
    };
    Ok(F1Score {
        tp,
        fp,
        fn_,
        precision,
        recall,
        f1,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_lanes_and_refuses_broken_lines() {
        let lanes = parse_lines("\u{feff}100.5 590 110 580 120 570 \r\n\n600 590\n").unwrap();
        assert_eq!(lanes.len(), 2);
        assert_eq!(
            lanes[0],
            vec![[100.5, 590.0], [110.0, 580.0], [120.0, 570.0]]
        );
        assert_eq!(lanes[1], vec![[600.0, 590.0]]);
        let e = parse_lines("1 2 3\n").unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("3 numbers"), "{e}");
        let e = parse_lines("1 2 3 4\n1 x 3 4").unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("\"x\""), "{e}");
        let e = parse_lines("1,2 3,4").unwrap_err().to_string();
        assert!(e.contains("separated by spaces"), "{e}");
        assert!(parse_lines("1 2 NaN 4").is_err());
    }

    #[test]
    fn samples_lanes_at_shared_rows_inside_the_image() {
        let cam = Camera::culane(); // 1640 × 590
                                    // Lane 0 from (100, 585) up to (130, 555); lane 1 from (600, 580) to (580, 570); lane
                                    // 2 leaves the image on the left (as CULane's labels do); lane 3 has one point.
        let lanes = vec![
            vec![[100.0, 585.0], [130.0, 555.0]],
            vec![[600.0, 580.0], [580.0, 570.0]],
            vec![[5.0, 580.0], [-15.0, 560.0]],
            vec![[800.0, 580.0]],
        ];
        let (r, d) = to_record("a/1.jpg".into(), &lanes, Rows::Step(10.0), &cam);
        assert_eq!(r.h_samples, vec![560.0, 570.0, 580.0]);
        assert_eq!(r.lanes[0], vec![125.0, 115.0, 105.0]);
        assert_eq!(r.lanes[1], vec![NO_POINT, 580.0, 600.0]);
        assert_eq!(r.lanes[2], vec![NO_POINT, NO_POINT, 5.0]);
        assert_eq!(r.lanes.len(), 3);
        assert_eq!(
            d,
            Dropped {
                outside_points: 1,
                lanes: 1
            }
        );
        r.check_shape().unwrap();
        // At given rows; a row below the image gives no point.
        let (g, _) = to_record("a/1.jpg".into(), &lanes, Rows::Given(&[575.0, 600.0]), &cam);
        assert_eq!(g.lanes[0], vec![110.0, NO_POINT]);
        // An image without lanes still has rows (to be scored at): from the horizon down.
        let (e, _) = to_record("a/2.jpg".into(), &[], Rows::Step(10.0), &cam);
        assert!(e.lanes.is_empty());
        assert_eq!(e.h_samples.first(), Some(&240.0));
        assert_eq!(e.h_samples.last(), Some(&580.0));
        // Back to a lane file: bottom up, the lanes' sampled points.
        assert_eq!(
            lines_text(&r),
            "105.00 580 115.00 570 125.00 560\n600.00 580 580.00 570\n"
        );
        assert_eq!(
            parse_lines(&lines_text(&r)).unwrap()[1],
            vec![[600.0, 580.0], [580.0, 570.0]]
        );
    }

    #[test]
    fn reads_a_folder_and_makes_frames_timed_by_frame_number() {
        let dir = std::env::temp_dir().join(format!("stjpdacf-culane-{}", std::process::id()));
        let clip = dir.join("driver_1/clip.MP4");
        std::fs::create_dir_all(&clip).unwrap();
        // Frame numbers sort as numbers (30 before 120), not as names; an image beside its
        // lane file names the extension.
        std::fs::write(clip.join("120.lines.txt"), "100 580 110 570\n").unwrap();
        std::fs::write(clip.join("30.lines.txt"), "90 580 100 570\n").unwrap();
        std::fs::write(clip.join("30.png"), "not read").unwrap();
        let cam = Camera::culane();
        let (recs, rep) = read_dir(&dir, 10.0, &cam, None).unwrap();
        let names: Vec<&str> = recs.iter().map(|r| r.raw_file.as_str()).collect();
        assert_eq!(
            names,
            ["driver_1/clip.MP4/30.png", "driver_1/clip.MP4/120.jpg"]
        );
        assert_eq!((rep.files, rep.lanes), (2, 2));
        assert_eq!(
            lane_file_of(&dir, &recs[1].raw_file).unwrap(),
            clip.join("120.lines.txt")
        );
        assert!(lane_file_of(&dir, "../x.jpg").is_err());
        assert!(lane_file_of(&dir, "/tmp/x.jpg").is_err());
        let (fr, unnumbered) = frames(&recs, 30.0, &cam, None).unwrap();
        assert_eq!(unnumbered, 0);
        assert_eq!(fr[0].clip, "driver_1/clip.MP4");
        assert_eq!((fr[0].t, fr[1].t), (1.0, 4.0));
        // Every image row from 570 to 580: 11 points.
        assert_eq!(fr[1].points.len(), 11);
        assert_eq!(fr[1].camera, Some(cam));
        assert_eq!(fr[1].h_samples, Some(vec![570.0, 580.0]));
        // With labels: their rows, and none for an image they do not label; the mismatches
        // are reported.
        let mut label = recs[1].clone();
        label.h_samples = vec![500.0, 575.0];
        let mut other = label.clone();
        other.raw_file = "driver_2/x/1.jpg".into();
        let labels = [label, other];
        let (recs, rep) = read_dir(&dir, 10.0, &cam, Some(&labels)).unwrap();
        assert_eq!(recs[1].h_samples, vec![500.0, 575.0]);
        assert_eq!(recs[1].lanes[0], vec![NO_POINT, 105.0]);
        assert_eq!(rep.labelled, 1);
        assert_eq!(
            rep.unlabelled_example.as_deref(),
            Some("driver_1/clip.MP4/30.png")
        );
        assert_eq!(
            rep.missing_example,
            Some(("driver_2/x/1.jpg".to_string(), 1))
        );
        let (fr, _) = frames(&recs, 30.0, &cam, Some(&labels)).unwrap();
        assert_eq!(fr[0].h_samples, None);
        assert_eq!(fr[1].h_samples, Some(vec![500.0, 575.0]));
        // Two files of one frame number.
        std::fs::write(clip.join("030.lines.txt"), "90 580 100 570\n").unwrap();
        let (recs, _) = read_dir(&dir, 10.0, &cam, None).unwrap();
        let e = frames(&recs, 30.0, &cam, None).unwrap_err().to_string();
        assert!(e.contains("same frame number"), "{e}");
        assert!(read_dir(&dir.join("driver_1/none"), 10.0, &cam, None).is_err());
        assert!(read_dir(&dir, 0.0, &cam, None).is_err());
        assert!(read_dir(&dir, 590.0, &cam, None).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn f1_matches_lanes_by_the_iou_of_30_px_strokes() {
        let size = (1640, 590);
        let line = |x0: f64| -> Vec<(f64, f64)> {
            (0..30)
                .map(|i| (x0 + 2.0 * f64::from(i), 580.0 - 10.0 * f64::from(i)))
                .collect()
        };
        // A lane against itself: IoU 1.
        let a = lane_mask(&line(300.0), 30.0, size);
        assert_eq!(iou_of(&a, &a), 1.0);
        // Shifted sideways by d px, two 30 px strokes overlap by about (30 − d) / (30 + d).
        for (d, want) in [(10.0, 0.5), (5.0, 25.0 / 35.0), (40.0, 0.0)] {
            let b = lane_mask(&line(300.0 + d), 30.0, size);
            let v = iou_of(&a, &b);
            assert!((v - want).abs() < 0.03, "shift {d}: IoU {v}, about {want}");
        }
        // Two labelled lanes; the prediction has one right, one 40 px off, one extra.
        let rows: Vec<f64> = (0..30).map(|i| 580.0 - 10.0 * f64::from(i)).collect();
        let rec = |xs: &[f64], time: Option<f64>| TuSimpleRecord {
            raw_file: "a/1.jpg".into(),
            lanes: xs
                .iter()
                .map(|&x0| (0..30).map(|i| x0 + 2.0 * f64::from(i)).collect())
                .collect(),
            h_samples: rows.clone(),
            run_time: time,
        };
        let gt = rec(&[300.0, 900.0], None);
        let pred = rec(&[940.0, 301.0, 1400.0], Some(0.0));
        let s = f1_score(&[pred], std::slice::from_ref(&gt), 30.0, 0.5, size).unwrap();
        assert_eq!((s.tp, s.fp, s.fn_), (1, 2, 1));
        assert!((s.precision - 1.0 / 3.0).abs() < 1e-12 && (s.recall - 0.5).abs() < 1e-12);
        assert!((s.f1 - 0.4).abs() < 1e-12);
        // No prediction for a labelled image: its lanes are misses.
        let s = f1_score(&[], &[gt], 30.0, 0.5, size).unwrap();
        assert_eq!((s.tp, s.fp, s.fn_, s.f1), (0, 0, 2, 0.0));
    }
}
