//! TuSimple file formats: the benchmark's label / prediction records and this project's frame
//! records, both as JSON lines (one JSON object per line).
//!
//! * [`TuSimpleRecord`] — a TuSimple ground-truth label or prediction:
//!   `{"raw_file": str, "lanes": [[x, ...], ...], "h_samples": [row, ...], "run_time": ms}`.
//!   `lanes[i][j]` is the column of lane `i` at image row `h_samples[j]`, `-2` (any negative value)
//!   where the lane has no point. Ground truth has no `run_time`; predictions must have it (the
//!   official scorer refuses predictions without it).
//! * [`Frame`] — one frame of feature points for the tracker:
//!   `{"clip": str, "t": seconds, "points": [[x, y], ...], "raw_file": str?, "h_samples": [row, ...]?,
//!   "camera": {...}?}`.
//!   Frames of one clip are consecutive and their times increase strictly (by at least the
//!   tracker's microsecond); `raw_file`/`h_samples`
//!   are present on frames for which a TuSimple prediction is to be written (`h_samples` needs
//!   `raw_file`, and a `raw_file` with `h_samples` appears once per file: the scorer joins on it).
//!   `camera` (the fields of [`crate::camera::Camera`]) is the camera the image points were
//!   found with, written by `stjpdacf frontend --camera estimate`; `stjpdacf track` maps each
//!   clip with the median of its frames' cameras when they have them (`track::clip_camera`).
//!
//! Readers skip blank lines and report malformed input as `FILE:LINE: ...` errors. Unknown keys
//! are ignored (submissions commonly carry extra keys).

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// The TuSimple value for "no lane point at this row".
pub const NO_POINT: f64 = -2.0;

/// A TuSimple label or prediction (one line of a TuSimple JSON-lines file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TuSimpleRecord {
    /// Image path relative to the dataset root, e.g. `clips/0313-1/6040/20.jpg`; the join key
    /// between predictions and ground truth.
    pub raw_file: String,
    /// For each lane, its column (pixels) at each of `h_samples`; negative (`-2`) = no point.
    pub lanes: Vec<Vec<f64>>,
    /// Image rows (pixels) at which the lanes are sampled. Required in ground truth; optional in
    /// predictions (the scorer samples predictions at the ground truth's rows), empty if absent.
    #[serde(default)]
    pub h_samples: Vec<f64>,
    /// Milliseconds spent on this frame (predictions only; ground truth has none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_time: Option<f64>,
}

/// Records (ground truth) as predictions that took `run_time_ms` each: what a perfect tracker
/// would submit, for checking the scorer.
pub fn as_predictions(gts: &[TuSimpleRecord], run_time_ms: f64) -> Vec<TuSimpleRecord> {
    gts.iter()
        .map(|g| TuSimpleRecord {
            run_time: Some(run_time_ms),
            ..g.clone()
        })
        .collect()
}

impl TuSimpleRecord {
    /// The lanes with at least one point (a column ≥ 0).
    pub fn lanes_with_points(&self) -> impl Iterator<Item = &Vec<f64>> {
        self.lanes.iter().filter(|l| l.iter().any(|x| *x >= 0.0))
    }

    /// The labelled points `(column, row)` of `lane` (one of [`Self::lanes`]) in `h_samples`
    /// order; the rows where the lane has no point (column < 0) are left out.
    pub fn points_of<'a>(&'a self, lane: &'a [f64]) -> impl Iterator<Item = (f64, f64)> + 'a {
        lane.iter()
            .zip(&self.h_samples)
            .filter(|(c, _)| **c >= 0.0)
            .map(|(&c, &r)| (c, r))
    }

    /// Multiply every column (≥ 0) and every row by `s`; negative "no point" values become
    /// [`NO_POINT`].
    pub fn scale_pixels(&mut self, s: f64) {
        for lane in &mut self.lanes {
            for x in lane.iter_mut() {
                *x = if *x >= 0.0 { *x * s } else { NO_POINT };
            }
        }
        for h in &mut self.h_samples {
            *h *= s;
        }
    }

    /// Check the shape: `h_samples` non-empty and every lane with one value per `h_samples` row.
    pub fn check_shape(&self) -> Result<()> {
        ensure!(
            !self.h_samples.is_empty(),
            "{}: h_samples is empty",
            self.raw_file
        );
        for (i, lane) in self.lanes.iter().enumerate() {
            ensure!(
                lane.len() == self.h_samples.len(),
                "{}: lane {i} has {} values but h_samples has {} rows",
                self.raw_file,
                lane.len(),
                self.h_samples.len()
            );
        }
        Ok(())
    }
}

/// One frame of feature points for the tracker (one line of a frames file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Clip identifier; frames of one clip are consecutive and a new clip resets the tracker.
    pub clip: String,
    /// Time stamp, seconds.
    pub t: f64,
    /// Feature points `[x, y]`: image pixels (x = column, y = row) or BEV metres, by context.
    pub points: Vec<[f64; 2]>,
    /// TuSimple image path, when a prediction is to be written for this frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raw_file: Option<String>,
    /// Image rows at which to report the lanes, when a prediction is to be written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub h_samples: Option<Vec<f64>>,
    /// The camera the image points were found with (`stjpdacf frontend` writes it on every
    /// frame: the calibration scaled to the image, or an estimated camera); `None`: the camera
    /// `track` is given (`--camera`, `--scale`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<crate::camera::Camera>,
}

/// The clips of `frames`: the runs of consecutive frames with the same [`Frame::clip`], in
/// order. This is how `track` splits its input (a clip name that comes back after another clip
/// starts a new run, and a new tracker).
pub fn clips(frames: &[Frame]) -> impl Iterator<Item = &[Frame]> {
    frames.chunk_by(|a, b| a.clip == b.clip)
}

impl Frame {
    /// The largest time (s, either sign) the tracker's clock holds: integer microseconds in an
    /// `i64` (about 292 000 years).
    pub const MAX_TIME_S: f64 = 9.2e12;

    /// The frame's time as the tracker gets it: integer microseconds.
    pub fn micros(&self) -> i64 {
        (self.t * 1e6).round() as i64
    }

    /// Check one frame's values: a finite time the tracker's microsecond clock holds
    /// ([`Self::MAX_TIME_S`]), finite points, `h_samples` (if any) non-empty, finite and with a
    /// `raw_file`, and the `camera` (if any) valid ([`crate::camera::Camera::check`]).
    pub fn check(&self) -> Result<()> {
        ensure!(
            self.t.is_finite() && self.t.abs() <= Self::MAX_TIME_S,
            "clip {}: time {} s is not finite or beyond the tracker's microsecond clock (±{:e} s); \
             times are seconds",
            self.clip,
            self.t,
            Self::MAX_TIME_S
        );
        if let Some(rows) = &self.h_samples {
            ensure!(
                self.raw_file.is_some(),
                "clip {}: h_samples without raw_file (a prediction needs both)",
                self.clip
            );
            ensure!(
                !rows.is_empty() && rows.iter().all(|r| r.is_finite()),
                "clip {}: h_samples must be a non-empty list of finite rows",
                self.clip
            );
        }
        if let Some((i, p)) = self
            .points
            .iter()
            .enumerate()
            .find(|(_, p)| !(p[0].is_finite() && p[1].is_finite()))
        {
            bail!("clip {}: point {i} {:?} is not finite", self.clip, p);
        }
        if let Some(cam) = &self.camera {
            cam.check()
                .with_context(|| format!("clip {}: bad camera", self.clip))?;
        }
        Ok(())
    }
}

/// Parse JSON lines from `reader`; `source` names the input in error messages. Blank lines are
/// skipped; a malformed line is an error `SOURCE:LINE: ...`.
pub fn parse_jsonl<T: DeserializeOwned, R: BufRead>(reader: R, source: &str) -> Result<Vec<T>> {
    parse_checked(reader, source, "record", |_: &T| Ok(()))
}

/// Parse JSON lines, checking each item with `check`; both failures name `source` and the line.
fn parse_checked<T, R, F>(reader: R, source: &str, what: &str, check: F) -> Result<Vec<T>>
where
    T: DeserializeOwned,
    R: BufRead,
    F: Fn(&T) -> Result<()>,
{
    Ok(parse_numbered(reader, source, what, check)?
        .into_iter()
        .map(|(_, item)| item)
        .collect())
}

/// [`parse_checked`], keeping each item's line number (1-based).
fn parse_numbered<T, R, F>(reader: R, source: &str, what: &str, check: F) -> Result<Vec<(usize, T)>>
where
    T: DeserializeOwned,
    R: BufRead,
    F: Fn(&T) -> Result<()>,
{
    let mut out = Vec::new();
    for (i, line) in reader.lines().enumerate() {
        let n = i + 1;
        let line = line.with_context(|| format!("{source}:{n}: reading line"))?;
        if line.trim().is_empty() {
            continue;
        }
        let item: T = serde_json::from_str(&line)
            .with_context(|| format!("{source}:{n}: malformed {what}"))?;
        check(&item).with_context(|| format!("{source}:{n}: bad {what}"))?;
        out.push((n, item));
    }
    Ok(out)
}

/// Open `path` and parse it with `parse`, which gets the buffered file and the path as the
/// source name of its error messages.
fn read_with<T>(path: &Path, parse: impl FnOnce(BufReader<File>, &str) -> Result<T>) -> Result<T> {
    let f = File::open(path).with_context(|| format!("opening {}", path.display()))?;
    parse(BufReader::new(f), &path.display().to_string())
}

/// Read a JSON-lines file (see [`parse_jsonl`]).
pub fn read_jsonl<T: DeserializeOwned>(path: &Path) -> Result<Vec<T>> {
    read_with(path, parse_jsonl)
}

/// Write items as JSON lines (one compact JSON object per line).
pub fn write_jsonl_to<T: Serialize, W: Write>(mut w: W, items: &[T]) -> Result<()> {
    for item in items {
        serde_json::to_writer(&mut w, item).context("serialising a record")?;
        w.write_all(b"\n").context("writing a record")?;
    }
    w.flush().context("flushing output")?;
    Ok(())
}

/// Write items to a JSON-lines file, replacing it.
pub fn write_jsonl<T: Serialize>(path: &Path, items: &[T]) -> Result<()> {
    let f = crate::create_output(path)?;
    write_jsonl_to(BufWriter::new(f), items).with_context(|| format!("writing {}", path.display()))
}

/// Parse TuSimple ground-truth labels and check each one's shape
/// ([`TuSimpleRecord::check_shape`]); errors name `source` and the line.
pub fn parse_labels<R: BufRead>(reader: R, source: &str) -> Result<Vec<TuSimpleRecord>> {
    parse_checked(
        reader,
        source,
        "TuSimple label",
        TuSimpleRecord::check_shape,
    )
}

/// Read a TuSimple ground-truth file (JSON lines), checking shapes.
pub fn read_labels(path: &Path) -> Result<Vec<TuSimpleRecord>> {
    read_with(path, parse_labels)
}

/// Parse TuSimple predictions. Like the official scorer, `raw_file`, `lanes` and `run_time` are
/// required and `h_samples` is not (lane lengths are checked against the ground truth when
/// scoring); errors name `source` and the line.
pub fn parse_predictions<R: BufRead>(reader: R, source: &str) -> Result<Vec<TuSimpleRecord>> {
    parse_checked(
        reader,
        source,
        "TuSimple prediction",
        |r: &TuSimpleRecord| {
            ensure!(r.run_time.is_some(), "{}: run_time missing", r.raw_file);
            Ok(())
        },
    )
}

/// Read a TuSimple prediction file (JSON lines); see [`parse_predictions`].
pub fn read_predictions(path: &Path) -> Result<Vec<TuSimpleRecord>> {
    read_with(path, parse_predictions)
}

/// Write TuSimple records as JSON lines.
pub fn write_records(path: &Path, records: &[TuSimpleRecord]) -> Result<()> {
    write_jsonl(path, records)
}

/// Parse frame records, check each one ([`Frame::check`]) and their order ([`check_sequence`]);
/// errors name `source` and the line.
pub fn parse_frames<R: BufRead>(reader: R, source: &str) -> Result<Vec<Frame>> {
    let numbered = parse_numbered(reader, source, "frame", Frame::check)?;
    check_sequence(&numbered, source)?;
    Ok(numbered.into_iter().map(|(_, f)| f).collect())
}

/// The order of a frames file: the frames of a clip are consecutive (a clip that reappears after
/// another clip is an error: the tracker would have been reset), times increase strictly within
/// a clip at the tracker's microsecond resolution ([`Frame::micros`]), the frames of a clip
/// that carry a `camera` agree on its image size (`track` maps the clip with one camera, the
/// median of theirs), and a `raw_file` that asks for a prediction (`h_samples` present)
/// appears once.
/// `frames` pairs each frame with its line number; errors are `SOURCE:LINE: ...`.
pub fn check_sequence(frames: &[(usize, Frame)], source: &str) -> Result<()> {
    use std::collections::HashMap;
    let mut clip_end: HashMap<&str, usize> = HashMap::new();
    let mut predicted: HashMap<&str, usize> = HashMap::new();
    let mut prev: Option<&(usize, Frame)> = None;
    // The image size of the first frame of the current clip that carries a camera, its line.
    let mut clip_size: Option<(usize, f64, f64)> = None;
    for item in frames {
        let (n, f) = item;
        if prev.is_none_or(|(_, p)| p.clip != f.clip) {
            clip_size = None;
        }
        if let Some(c) = &f.camera {
            match clip_size {
                Some((first, w, h)) => ensure!(
                    (c.width, c.height) == (w, h),
                    "{source}:{n}: the camera of clip {} is {}x{} here but {w}x{h} at line \
                     {first}; `track` maps a clip with one camera, so its images must have one \
                     size (put images of another size in a clip of their own)",
                    f.clip,
                    c.width,
                    c.height
                ),
                None => clip_size = Some((*n, c.width, c.height)),
            }
        }
        match prev {
            // The tracker's clock counts microseconds: times closer than that are one time.
            Some((pn, p)) if p.clip == f.clip => ensure!(
                f.micros() > p.micros(),
                "{source}:{n}: time {} s of clip {} is not after {} s (line {pn}); times must \
                 increase within a clip, by at least a microsecond",
                f.t,
                f.clip,
                p.t
            ),
            _ => {
                if let Some(last) = clip_end.get(f.clip.as_str()) {
                    bail!(
                        "{source}:{n}: clip {} appears again (its frames ended at line {last}); \
                         the frames of a clip must be consecutive",
                        f.clip
                    );
                }
            }
        }
        clip_end.insert(f.clip.as_str(), *n);
        if let (Some(raw), Some(_)) = (&f.raw_file, &f.h_samples) {
            if let Some(first) = predicted.insert(raw.as_str(), *n) {
                bail!(
                    "{source}:{n}: raw_file {raw} already asks for a prediction at line {first} \
                     (a frame with h_samples asks for one; the scorer pairs predictions with \
                     labels by raw_file, so each such frame needs its own)"
                );
            }
        }
        prev = Some(item);
    }
    Ok(())
}

/// Read a frames file (JSON lines), checking each frame.
pub fn read_frames(path: &Path) -> Result<Vec<Frame>> {
    read_with(path, parse_frames)
}

/// Write frames as JSON lines.
pub fn write_frames(path: &Path, frames: &[Frame]) -> Result<()> {
    write_jsonl(path, frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The error (with its causes) of parsing labels `s` named `gt.json`.
    fn labels_err(s: &str) -> String {
        format!("{:#}", parse_labels(s.as_bytes(), "gt.json").unwrap_err())
    }

    /// The error (with its causes) of parsing frames `s` named `f.jsonl`.
    fn frames_err(s: &str) -> String {
        format!("{:#}", parse_frames(s.as_bytes(), "f.jsonl").unwrap_err())
    }

    #[test]
    fn ground_truth_line_parses_without_run_time() {
        let s = r#"{"lanes": [[-2, 10, 12], [5, 6, -2]], "h_samples": [100, 110, 120], "raw_file": "clips/a/20.jpg"}"#;
        let v = parse_labels(s.as_bytes(), "gt").unwrap();
        assert_eq!(v.len(), 1);
        assert_eq!(v[0].raw_file, "clips/a/20.jpg");
        assert_eq!(v[0].lanes[0], vec![-2.0, 10.0, 12.0]);
        assert_eq!(v[0].h_samples, vec![100.0, 110.0, 120.0]);
        assert_eq!(v[0].run_time, None);
    }

    #[test]
    fn prediction_round_trips_with_run_time() {
        let rec = TuSimpleRecord {
            raw_file: "clips/b/20.jpg".into(),
            lanes: vec![vec![1.5, NO_POINT]],
            h_samples: vec![160.0, 170.0],
            run_time: Some(3.25),
        };
        let mut buf = Vec::new();
        write_jsonl_to(&mut buf, std::slice::from_ref(&rec)).unwrap();
        let text = String::from_utf8(buf).unwrap();
        assert!(text.contains("\"run_time\":3.25"), "{text}");
        assert_eq!(parse_predictions(text.as_bytes(), "p").unwrap(), vec![rec]);
    }

    #[test]
    fn ground_truth_serialises_without_run_time_key() {
        let rec = TuSimpleRecord {
            raw_file: "x".into(),
            lanes: vec![],
            h_samples: vec![1.0],
            run_time: None,
        };
        let s = serde_json::to_string(&rec).unwrap();
        assert!(!s.contains("run_time"), "{s}");
    }

    #[test]
    fn malformed_line_names_source_and_line() {
        let s = "{\"raw_file\": \"a\", \"lanes\": [], \"h_samples\": [1]}\n\n{\"raw_file\": \"b\", \"lanes\": 3}\n";
        let msg = labels_err(s);
        assert!(
            msg.starts_with("gt.json:3: malformed TuSimple label"),
            "{msg}"
        );
    }

    #[test]
    fn lane_length_mismatch_is_reported() {
        let s = "{\"raw_file\": \"a\", \"lanes\": [[1, 2]], \"h_samples\": [1, 2, 3]}";
        let msg = labels_err(s);
        assert!(msg.contains("gt.json:1: bad TuSimple label"), "{msg}");
        assert!(
            msg.contains("lane 0 has 2 values but h_samples has 3 rows"),
            "{msg}"
        );
    }

    #[test]
    fn prediction_needs_run_time_but_not_h_samples() {
        let ok = r#"{"raw_file": "a", "lanes": [[1, 2]], "run_time": 10}"#;
        let v = parse_predictions(ok.as_bytes(), "p.json").unwrap();
        assert!(v[0].h_samples.is_empty());
        assert_eq!(v[0].run_time, Some(10.0));
        let bad = format!("{ok}\n{}", r#"{"raw_file": "b", "lanes": [[1, 2]]}"#);
        let msg = format!(
            "{:#}",
            parse_predictions(bad.as_bytes(), "p.json").unwrap_err()
        );
        assert!(
            msg.starts_with("p.json:2: bad TuSimple prediction"),
            "{msg}"
        );
        assert!(msg.contains("run_time missing"), "{msg}");
    }

    #[test]
    fn label_without_h_samples_or_with_none_is_reported() {
        for s in [
            r#"{"raw_file": "a", "lanes": []}"#,
            "{\"raw_file\": \"a\", \"lanes\": [], \"h_samples\": []}",
        ] {
            let msg = labels_err(s);
            assert!(msg.contains("h_samples is empty"), "{s}: {msg}");
        }
    }

    #[test]
    fn frames_parse_with_and_without_optional_keys() {
        let s = concat!(
            r#"{"clip": "c1", "t": 0.0, "points": [[1, 2], [3.5, 4]]}"#,
            "\n",
            r#"{"clip": "c1", "t": 0.05, "points": [], "raw_file": "clips/c1/20.jpg", "h_samples": [160, 170]}"#,
            "\n"
        );
        let f = parse_frames(s.as_bytes(), "frames").unwrap();
        assert_eq!(f.len(), 2);
        assert_eq!(f[0].points, vec![[1.0, 2.0], [3.5, 4.0]]);
        assert_eq!(f[0].raw_file, None);
        assert_eq!(f[1].raw_file.as_deref(), Some("clips/c1/20.jpg"));
        assert_eq!(f[1].h_samples.as_deref(), Some(&[160.0, 170.0][..]));
        let mut buf = Vec::new();
        write_jsonl_to(&mut buf, &f).unwrap();
        let text = String::from_utf8(buf).unwrap();
        assert!(!text.lines().next().unwrap().contains("raw_file"), "{text}");
        assert_eq!(parse_frames(text.as_bytes(), "again").unwrap(), f);
    }

    #[test]
    fn malformed_frame_names_line() {
        let s = "{\"clip\": \"c\", \"t\": 0, \"points\": []}\n{\"clip\": \"c\", \"t\": 1, \"points\": [[1]]}\n";
        let msg = frames_err(s);
        assert!(msg.starts_with("f.jsonl:2: malformed frame"), "{msg}");
    }

    #[test]
    fn frame_order_errors_name_the_line() {
        let line =
            |clip: &str, t: f64| format!("{{\"clip\": \"{clip}\", \"t\": {t}, \"points\": []}}\n");
        let ok = line("a", 0.0) + &line("a", 0.05) + "\n" + &line("b", 0.0);
        assert_eq!(parse_frames(ok.as_bytes(), "f").unwrap().len(), 3);
        let back = line("a", 0.0) + &line("a", 0.05) + &line("a", 0.05);
        let msg = frames_err(&back);
        assert!(msg.starts_with("f.jsonl:3: time 0.05 s of clip a"), "{msg}");
        assert!(msg.contains("(line 2)"), "{msg}");
        let again = line("a", 0.0) + &line("b", 0.0) + "\n" + &line("a", 1.0);
        let msg = frames_err(&again);
        assert!(msg.starts_with("f.jsonl:4: clip a appears again"), "{msg}");
        assert!(msg.contains("ended at line 1"), "{msg}");
    }

    /// Times that differ in `f64` but not at the tracker's microsecond clock, or lie beyond it
    /// (microseconds written as seconds), are errors: the tracker would refuse those frames
    /// and their predictions would be missing.
    #[test]
    fn frame_times_are_checked_at_the_trackers_clock() {
        let line =
            |clip: &str, t: &str| format!("{{\"clip\": \"{clip}\", \"t\": {t}, \"points\": []}}\n");
        let close = line("a", "0.0000001") + &line("a", "0.0000002");
        let msg = frames_err(&close);
        assert!(
            msg.starts_with("f.jsonl:2: time 0.0000002 s of clip a"),
            "{msg}"
        );
        assert!(msg.contains("at least a microsecond"), "{msg}");
        let us = line("a", "1700000000000000") + &line("a", "1700000000050000");
        let msg = frames_err(&us);
        assert!(msg.starts_with("f.jsonl:1: bad frame"), "{msg}");
        assert!(msg.contains("microsecond clock"), "{msg}");
        let ok = line("a", "1700000000.0") + &line("a", "1700000000.000001");
        assert_eq!(parse_frames(ok.as_bytes(), "f").unwrap().len(), 2);
    }

    /// A frame's camera (written by `frontend --camera estimate`) is checked as a camera file
    /// is: a zero focal length or a negative height is an error, not an empty prediction.
    #[test]
    fn frame_camera_is_checked() {
        let cam = |field: &str, v: f64| {
            let mut c = serde_json::to_value(crate::camera::Camera::culane()).unwrap();
            c[field] = serde_json::json!(v);
            format!(r#"{{"clip": "c", "t": 0, "points": [], "camera": {c}}}"#)
        };
        let good = cam("focal_px", 1000.0);
        assert_eq!(parse_frames(good.as_bytes(), "f").unwrap().len(), 1);
        for (field, v) in [("focal_px", 0.0), ("height_m", -1.67), ("width", 0.0)] {
            let msg = frames_err(&cam(field, v));
            assert!(msg.starts_with("f.jsonl:1: bad frame"), "{field}: {msg}");
            assert!(msg.contains("bad camera"), "{field}: {msg}");
        }
    }

    #[test]
    fn frame_prediction_keys_are_checked() {
        let no_raw = r#"{"clip": "c", "t": 0, "points": [], "h_samples": [1, 2]}"#;
        let msg = frames_err(no_raw);
        assert!(msg.starts_with("f.jsonl:1: bad frame"), "{msg}");
        assert!(msg.contains("h_samples without raw_file"), "{msg}");
        let empty = r#"{"clip": "c", "t": 0, "points": [], "raw_file": "x", "h_samples": []}"#;
        let msg = frames_err(empty);
        assert!(msg.contains("non-empty"), "{msg}");
        let twice = concat!(
            r#"{"clip": "c", "t": 0, "points": [], "raw_file": "x", "h_samples": [1]}"#,
            "\n",
            r#"{"clip": "d", "t": 0, "points": [], "raw_file": "x", "h_samples": [1]}"#
        );
        let msg = frames_err(twice);
        assert!(
            msg.starts_with("f.jsonl:2: raw_file x already asks for a prediction at line 1"),
            "{msg}"
        );
        // A raw_file without h_samples asks for nothing and may repeat.
        let plain = concat!(
            r#"{"clip": "c", "t": 0, "points": [], "raw_file": "x"}"#,
            "\n",
            r#"{"clip": "c", "t": 1, "points": [], "raw_file": "x"}"#
        );
        assert_eq!(parse_frames(plain.as_bytes(), "f").unwrap().len(), 2);
    }

    #[test]
    fn files_round_trip_and_missing_file_is_named() {
        let dir = std::env::temp_dir().join(format!("stjpdacf-tusimple-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("frames.jsonl");
        let frame = Frame {
            clip: "c".into(),
            t: 0.5,
            points: vec![[1.0, 2.0]],
            raw_file: None,
            h_samples: None,
            camera: None,
        };
        // A frame with its camera round-trips too; one without writes no `camera` key.
        let frames = vec![
            frame.clone(),
            Frame {
                t: 0.55,
                camera: Some(crate::camera::Camera::culane()),
                ..frame
            },
        ];
        write_frames(&p, &frames).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(text.matches("\"camera\"").count(), 1, "{text}");
        assert_eq!(read_frames(&p).unwrap(), frames);
        let missing = dir.join("nope.json");
        let msg = format!("{:#}", read_labels(&missing).unwrap_err());
        assert!(msg.contains("nope.json"), "{msg}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn clips_are_runs_of_one_name_and_a_returning_name_starts_a_new_one() {
        let f = |clip: &str, t: f64| Frame {
            clip: clip.into(),
            t,
            points: Vec::new(),
            raw_file: None,
            h_samples: None,
            camera: None,
        };
        let frames = [f("a", 0.0), f("a", 0.1), f("b", 0.0), f("a", 0.5)];
        let runs: Vec<(&str, usize)> = clips(&frames)
            .map(|c| (c[0].clip.as_str(), c.len()))
            .collect();
        assert_eq!(runs, [("a", 2), ("b", 1), ("a", 1)]);
        assert_eq!(clips(&[]).count(), 0);
    }
}
