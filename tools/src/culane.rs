//! CULane-style lane files to and from the TuSimple records the tools read and write.
//!
//! CULane (and datasets in its format: CurveLanes, many detectors' outputs) stores the lanes of
//! image `a/b/00030.jpg` in `a/b/00030.lines.txt`: one lane a line, its points as `x y` pairs in
//! image pixels (column, row), usually every 10 rows from the bottom of the image up. The tools
//! score, train and track TuSimple records (one JSON line an image: the lanes' columns at shared
//! rows `h_samples`), so:
//!
//! - [`read_dir`] turns a folder of lane files into records: each image's rows are every
//!   `row_step` pixels over the rows its lanes cover, a lane's column at a row is interpolated
//!   linearly between its two nearest points (no point beyond its ends: `-2`);
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

/// Parses one lane file: a lane a non-empty line, `x y` pairs separated by white space. A line
/// with an odd count of numbers, a value that is not a finite number, or a lane of one point is
/// an error naming the line.
pub fn parse_lines(text: &str) -> Result<Vec<Lane>> {
    let mut lanes = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|w| {
                w.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .with_context(|| format!("line {}: {w:?} is not a finite number", i + 1))
            })
            .collect::<Result<_>>()?;
        if v.is_empty() {
            continue;
        }
        ensure!(
            v.len() % 2 == 0 && v.len() >= 4,
            "line {}: {} numbers; a lane is at least two `x y` pairs",
            i + 1,
            v.len()
        );
        lanes.push(v.chunks_exact(2).map(|p| [p[0], p[1]]).collect());
    }
    Ok(lanes)
}

/// The TuSimple record of an image's lanes: `h_samples` every `row_step` pixels (multiples of
/// it) from the topmost to the bottommost row any lane covers; each lane's column at each of
/// them, interpolated linearly between the two points around the row (in the row order of the
/// lane's points), [`NO_POINT`] outside the lane's rows. `row_step` must be positive.
pub fn to_record(raw_file: String, lanes: &[Lane], row_step: f64) -> TuSimpleRecord {
    let rows = || lanes.iter().flatten().map(|p| p[1]);
    let (top, bottom) = rows().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
        (a.min(y), b.max(y))
    });
    let h_samples: Vec<f64> = if top <= bottom {
        let first = (top / row_step).ceil() as i64;
        let last = (bottom / row_step).floor() as i64;
        (first..=last).map(|k| k as f64 * row_step).collect()
    } else {
        Vec::new()
    };
    let lanes = lanes
        .iter()
        .map(|lane| {
            let mut pts = lane.clone();
            pts.sort_by(|a, b| a[1].total_cmp(&b[1]));
            h_samples.iter().map(|&h| column_at(&pts, h)).collect()
        })
        .collect();
    TuSimpleRecord {
        raw_file,
        lanes,
        h_samples,
        run_time: None,
    }
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

/// The records of every lane file under `dir` (recursively), in the order `frontend` reads
/// images: by folder, then by frame number, then by name. `raw_file` is the image's path
/// relative to `dir` (the lane file's with `.jpg` for `.lines.txt`). An empty lane file is an
/// image without lanes; a folder without lane files is an error.
pub fn read_dir(dir: &Path, row_step: f64) -> Result<Vec<TuSimpleRecord>> {
    ensure!(
        row_step.is_finite() && row_step > 0.0,
        "the row step must be a positive number of pixels, not {row_step}"
    );
    let files = find_files(dir, |p| {
        p.file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.ends_with(SUFFIX))
    })?;
    if files.is_empty() {
        bail!("no *{SUFFIX} lane files under {}", dir.display());
    }
    files
        .iter()
        .map(|f| {
            let text = std::fs::read_to_string(f)
                .with_context(|| format!("reading lane file {}", f.display()))?;
            let lanes = parse_lines(&text).with_context(|| format!("{}", f.display()))?;
            Ok(to_record(image_of(dir, f), &lanes, row_step))
        })
        .collect()
}

/// The image a lane file belongs to, relative to `dir` (`a/00030.lines.txt` → `a/00030.jpg`).
fn image_of(dir: &Path, lane_file: &Path) -> String {
    let raw = raw_file_of(dir, lane_file);
    match raw.strip_suffix(SUFFIX) {
        Some(stem) => format!("{stem}.jpg"),
        None => raw,
    }
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
/// increase within a folder.
pub fn frames(
    records: &[TuSimpleRecord],
    fps: f64,
    camera: &Camera,
    labels: Option<&[TuSimpleRecord]>,
) -> Result<Vec<Frame>> {
    ensure!(
        fps.is_finite() && fps > 0.0,
        "fps must be a positive number, not {fps}"
    );
    let mut out: Vec<Frame> = Vec::with_capacity(records.len());
    let mut index = 0usize;
    for r in records {
        let mut f = crate::demo::label_points_frame(r);
        index = match out.last() {
            Some(prev) if prev.clip == f.clip => index + 1,
            _ => 0,
        };
        f.t = frame_number(Path::new(&r.raw_file)).map_or(index as f64, |n| n as f64) / fps;
        f.camera = Some(*camera);
        if let Some(labels) = labels {
            f.h_samples = labels
                .iter()
                .find(|l| l.raw_file == r.raw_file)
                .map(|l| l.h_samples.clone());
        }
        if let Some(prev) = out.last().filter(|prev| prev.clip == f.clip) {
            ensure!(
                f.t > prev.t,
                "{}: time {} s is not after {}'s {} s: a file named by a number n is frame n, \
                 other names are numbered in order, so a folder must not mix them",
                r.raw_file,
                f.t,
                prev.raw_file.as_deref().unwrap_or_default(),
                prev.t
            );
        }
        f.check().with_context(|| r.raw_file.clone())?;
        out.push(f);
    }
    Ok(out)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_lanes_and_refuses_broken_lines() {
        let lanes = parse_lines("100.5 590 110 580 120 570 \n\n600 590 590 580\n").unwrap();
        assert_eq!(lanes.len(), 2);
        assert_eq!(
            lanes[0],
            vec![[100.5, 590.0], [110.0, 580.0], [120.0, 570.0]]
        );
        let e = parse_lines("1 2 3\n").unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("3 numbers"), "{e}");
        let e = parse_lines("1 2 3 4\n1 x 3 4").unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("\"x\""), "{e}");
        assert!(parse_lines("1 2 NaN 4").is_err());
        assert!(parse_lines("1 2").is_err());
    }

    #[test]
    fn samples_lanes_at_shared_rows_between_their_points() {
        // Lane 0 from (100, 595) up to (130, 565); lane 1 from (600, 590) to (580, 580).
        let lanes = vec![
            vec![[100.0, 595.0], [130.0, 565.0]],
            vec![[600.0, 590.0], [580.0, 580.0]],
        ];
        let r = to_record("a/1.jpg".into(), &lanes, 10.0);
        assert_eq!(r.h_samples, vec![570.0, 580.0, 590.0]);
        assert_eq!(r.lanes[0], vec![125.0, 115.0, 105.0]);
        assert_eq!(r.lanes[1], vec![NO_POINT, 580.0, 600.0]);
        r.check_shape().unwrap();
        // Back to a lane file: bottom up, the lanes' sampled points.
        assert_eq!(
            lines_text(&r),
            "105.00 590 115.00 580 125.00 570\n600.00 590 580.00 580\n"
        );
        assert_eq!(
            parse_lines(&lines_text(&r)).unwrap()[1],
            vec![[600.0, 590.0], [580.0, 580.0]]
        );
    }

    #[test]
    fn reads_a_folder_and_makes_frames_timed_by_frame_number() {
        let dir = std::env::temp_dir().join(format!("stjpdacf-culane-{}", std::process::id()));
        let clip = dir.join("driver_1/clip.MP4");
        std::fs::create_dir_all(&clip).unwrap();
        // Frame numbers sort as numbers (30 before 120), not as names.
        std::fs::write(clip.join("120.lines.txt"), "100 590 110 580\n").unwrap();
        std::fs::write(clip.join("30.lines.txt"), "90 590 100 580\n").unwrap();
        std::fs::write(clip.join("30.jpg"), "not read").unwrap();
        let recs = read_dir(&dir, 10.0).unwrap();
        let names: Vec<&str> = recs.iter().map(|r| r.raw_file.as_str()).collect();
        assert_eq!(
            names,
            ["driver_1/clip.MP4/30.jpg", "driver_1/clip.MP4/120.jpg"]
        );
        assert_eq!(
            lane_file_of(&dir, &recs[1].raw_file).unwrap(),
            clip.join("120.lines.txt")
        );
        assert!(lane_file_of(&dir, "../x.jpg").is_err());
        assert!(lane_file_of(&dir, "/tmp/x.jpg").is_err());
        let cam = Camera::culane();
        let fr = frames(&recs, 30.0, &cam, None).unwrap();
        assert_eq!(fr[0].clip, "driver_1/clip.MP4");
        assert_eq!((fr[0].t, fr[1].t), (1.0, 4.0));
        // Every image row from 580 to 590: 11 points.
        assert_eq!(fr[1].points.len(), 11);
        assert_eq!(fr[1].camera, Some(cam));
        assert_eq!(fr[1].h_samples, Some(vec![580.0, 590.0]));
        // With labels: their rows, and none for an image they do not label.
        let mut label = recs[1].clone();
        label.h_samples = vec![500.0, 590.0];
        let fr = frames(&recs, 30.0, &cam, Some(&[label])).unwrap();
        assert_eq!(fr[0].h_samples, None);
        assert_eq!(fr[1].h_samples, Some(vec![500.0, 590.0]));
        assert!(read_dir(&dir.join("driver_1/none"), 10.0).is_err());
        assert!(read_dir(&dir, 0.0).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
