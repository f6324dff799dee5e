//! Why predictions are false positives: the replay of `stjpdacf demo` (40 bundled labels × 20
//! frames, seed 1, coupled B, default configuration; `FP_DIAG_INTERVAL=1`: the 1/K evidence)
//! scored on every labelled frame; each unmatched prediction is classified against the
//! ground-truth lane it fits best:
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
use stjpdacf_tools::tusimple::TuSimpleRecord;

/// The spurious predictions: outside every label (left of the leftmost or right of the
/// rightmost on most common rows) or between labels; the lane's age in frames and its existence.
#[derive(Default, Debug)]
struct Spurious {
    outside: usize,
    between: usize,
    no_common_rows: usize,
    age_0_4: usize,
    age_5_19: usize,
    age_20_plus: usize,
    existence_below_0_9: usize,
    mean_px_to_nearest: f64,
    n: usize,
    /// Near end of the observed extent, m: < 10, 10–20, ≥ 20.
    near_end: [usize; 3],
    /// Observed extent length, m: < 20, 20–40, ≥ 40.
    length: [usize; 3],
}

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
    let labels = stjpdacf_tools::demo::replay_labels()?;
    let cam = Camera::tusimple();
    println!("| noise | scored | frames | preds/frame | gts/frame | FP/pred | spurious | lateral | over-run | under-run | duplicate | over rows/FP | under rows/FP |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for level in levels {
        let mut params = SynthParams::preset(level);
        // FP_DIAG_OFF=cars,road_edge,shadows,clutter,merges: switch sources off (which source
        // makes the false lanes); FP_DIAG_DISTRACTORS=k: k short straight distractors a frame.
        params.switch_off(&std::env::var("FP_DIAG_OFF").unwrap_or_default())?;
        if let Some(k) = std::env::var("FP_DIAG_DISTRACTORS")
            .ok()
            .and_then(|v| v.parse().ok())
        {
            params.distractors = k;
        }
        let o = synth::synthesize(&labels, &params, &cam, 1)?;
        let gt_index = o.gt_index();
        let last: std::collections::HashSet<&str> =
            o.gt_last.iter().map(|g| g.raw_file.as_str()).collect();
        // FP_DIAG_INTERVAL=1: the existence evidence discounted 1/K per index interval instead
        // of the default paint / gap chain (design §11.5).
        let mut config = TrackerConfig::DEFAULT;
        if std::env::var("FP_DIAG_INTERVAL").is_ok_and(|v| v == "1") {
            config.persist.paint_gap = None;
        }
        // FP_DIAG_RAY_RES=m: the ray test's resolution (design §11.10; `inf`: every test decisive).
        if let Some(r) = std::env::var("FP_DIAG_RAY_RES")
            .ok()
            .and_then(|v| v.parse::<f32>().ok())
        {
            config.persist.ray_resolution = r;
        }
        let mut tallies = [Tally::default(), Tally::default()];
        let mut spur = Spurious::default();
        // FP_DIAG_DUMP=file: every scored frame's points, lanes and labels in BEV (JSON lines).
        let mut dump = std::env::var("FP_DIAG_DUMP")
            .ok()
            .and_then(|p| std::fs::File::create(p).ok())
            .map(std::io::BufWriter::new);
        track::track_with(
            &o.frames,
            &stjpdacf::tables::DEFAULT,
            &cam,
            Space::Image,
            config,
            |v| {
                let (Some(p), Some(out)) = (v.prediction, v.output) else {
                    return;
                };
                let Some(&j) = gt_index.get(p.raw_file.as_str()) else {
                    return;
                };
                let g = &o.gt_all[j];
                let is_last = last.contains(p.raw_file.as_str());
                if let Some(w) = dump.as_mut() {
                    use std::io::Write;
                    let m = metric::match_lanes(&p.lanes, &g.lanes, &g.h_samples);
                    let lanes: Vec<_> = out
                        .filtered
                        .iter()
                        .map(|l| {
                            let k = v.prediction_ids.iter().position(|id| *id == l.id.0);
                            serde_json::json!({
                                "id": l.id.0, "existence": l.existence, "age": l.age,
                                "misses": l.misses, "u_first": l.u_first, "u_last": l.u_last,
                                "z": l.z.iter().collect::<Vec<_>>(),
                                "published": k.is_some(),
                                "matched": k.map(|k| m.pred_matched[k]),
                            })
                        })
                        .collect();
                    let gt: Vec<Vec<(f64, f64)>> = g
                        .lanes
                        .iter()
                        .map(|l| {
                            l.iter()
                                .zip(&g.h_samples)
                                .filter(|(x, _)| **x >= 0.0)
                                .filter_map(|(x, y)| cam.to_bev(*x, *y))
                                .collect()
                        })
                        .collect();
                    let _ = writeln!(
                        w,
                        "{}",
                        serde_json::json!({
                            "clip": v.frame.clip, "index": v.index, "points": v.points,
                            "lanes": lanes, "gt": gt,
                            "index_u": stjpdacf::tables::DEFAULT.index_u.iter().collect::<Vec<_>>(),
                        })
                    );
                }
                for (k, t) in tallies.iter_mut().enumerate() {
                    if k == 0 && !is_last {
                        continue;
                    }
                    let sp = if k == 1 { Some(&mut spur) } else { None };
                    classify(t, sp, p, g, v.prediction_ids, &out.filtered);
                }
            },
        )?;
        for (scored, t) in ["last", "all"].iter().zip(&tallies) {
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
        println!("spurious ({level:?}, all frames): {spur:?}");
    }
    Ok(())
}

fn classify(
    t: &mut Tally,
    spur: Option<&mut Spurious>,
    p: &TuSimpleRecord,
    g: &TuSimpleRecord,
    ids: &[u32],
    lanes: &[stjpdacf::tracker::LaneEstimate<16>],
) {
    t.frames += 1;
    t.preds += p.lanes.len();
    t.gts += g.lanes.len();
    let m = metric::match_lanes(&p.lanes, &g.lanes, &g.h_samples);
    let mut spur = spur;
    for (i, pl) in p.lanes.iter().enumerate() {
        if m.pred_matched[i] {
            continue;
        }
        t.fp += 1;
        // The label this prediction fits best on the common rows.
        let mut best: Option<(f64, usize, usize, usize)> = None;
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
                best = Some((frac, k, over, under));
            }
        }
        match best {
            Some((f, k, over, under)) if f >= 0.5 => {
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
            _ => {
                t.spurious += 1;
                if let Some(sp) = spur.as_deref_mut() {
                    spurious(sp, pl, g, ids.get(i).copied(), lanes);
                }
            }
        }
    }
}

fn spurious(
    sp: &mut Spurious,
    pl: &[f64],
    g: &TuSimpleRecord,
    id: Option<u32>,
    lanes: &[stjpdacf::tracker::LaneEstimate<16>],
) {
    let (mut rows, mut outside, mut near) = (0usize, 0usize, 0.0f64);
    for (r, a) in pl.iter().enumerate() {
        if *a < 0.0 {
            continue;
        }
        let xs: Vec<f64> = g
            .lanes
            .iter()
            .filter_map(|l| l.get(r).copied())
            .filter(|x| *x >= 0.0)
            .collect();
        if xs.is_empty() {
            continue;
        }
        rows += 1;
        let lo = xs.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = xs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        if *a < lo || *a > hi {
            outside += 1;
        }
        near += xs
            .iter()
            .map(|x| (x - a).abs())
            .fold(f64::INFINITY, f64::min);
    }
    if rows == 0 {
        sp.no_common_rows += 1;
    } else if 2 * outside >= rows {
        sp.outside += 1;
    } else {
        sp.between += 1;
    }
    if rows > 0 {
        sp.mean_px_to_nearest =
            (sp.mean_px_to_nearest * sp.n as f64 + near / rows as f64) / (sp.n + 1) as f64;
        sp.n += 1;
    }
    if let Some(l) = id.and_then(|id| lanes.iter().find(|l| l.id.0 == id)) {
        match l.age {
            0..=4 => sp.age_0_4 += 1,
            5..=19 => sp.age_5_19 += 1,
            _ => sp.age_20_plus += 1,
        }
        if l.existence < 0.9 {
            sp.existence_below_0_9 += 1;
        }
        let b = |v: f32, a: f32, c: f32| {
            if v < a {
                0
            } else if v < c {
                1
            } else {
                2
            }
        };
        sp.near_end[b(l.u_first, 10.0, 20.0)] += 1;
        sp.length[b(l.u_last - l.u_first, 20.0, 40.0)] += 1;
    }
}
