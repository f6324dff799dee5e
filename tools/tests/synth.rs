//! Tests of the real-geometry replay generator (`stjpdacf_tools::synth`, `stjpdacf synth`) on the
//! bundled subset of TuSimple training labels (`data/tusimple/train_subset.json`: 40 labels of
//! `label_data_0313.json`, every 71st line; 1280×720).

mod common;

use std::path::PathBuf;

use common::{assert_failure_mentions, assert_success, stjpdacf};
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::metric::bench_one_submit;
use stjpdacf_tools::synth::{synth_clip, synthesize, NoiseLevel, SynthOutput, SynthParams};
use stjpdacf_tools::tusimple::{as_predictions, read_labels, write_jsonl_to, TuSimpleRecord};

fn labels() -> Vec<TuSimpleRecord> {
    read_labels(&stjpdacf_tools::repo_root().join("data/tusimple/train_subset.json")).unwrap()
}

fn run(params: &SynthParams, seed: u64) -> SynthOutput {
    synthesize(&labels(), params, &Camera::tusimple(), seed).unwrap()
}

fn bytes(o: &SynthOutput) -> Vec<u8> {
    let mut b = Vec::new();
    write_jsonl_to(&mut b, &o.frames).unwrap();
    write_jsonl_to(&mut b, &o.gt_all).unwrap();
    b
}

fn as_pred(gts: &[TuSimpleRecord]) -> Vec<TuSimpleRecord> {
    as_predictions(gts, 1.0)
}

/// No structured clutter, no dashes, no occlusion, no merges, no pixel noise.
fn clean(detect_prob: f64, clutter_rate: f64) -> SynthParams {
    SynthParams {
        pixel_noise: 0.0,
        detect_prob,
        clutter_rate,
        dashed_prob: 0.0,
        merge_prob: 0.0,
        shadows: 0.0,
        cars: 0.0,
        road_edge_prob: 0.0,
        ..SynthParams::default()
    }
}

#[test]
fn bundled_subset_is_40_four_lane_labels() {
    let l = labels();
    assert_eq!(l.len(), 40);
    assert!(l
        .iter()
        .all(|r| r.lanes.len() == 4 && r.h_samples.len() >= 48));
}

#[test]
fn deterministic_per_seed() {
    let p = SynthParams::preset(NoiseLevel::High);
    let a = bytes(&run(&p, 7));
    assert_eq!(a, bytes(&run(&p, 7)), "same seed, different output");
    assert_ne!(a, bytes(&run(&p, 8)), "different seeds, same output");
    // A clip depends on its index and the seed only, not on how many clips are generated.
    let l = labels();
    let cam = Camera::tusimple();
    let all = synthesize(&l, &p, &cam, 7).unwrap();
    let c5 = synth_clip(&l[5], 5, &p, &cam, 7);
    assert_eq!(&all.frames[100..120], &c5.frames[..]);
}

#[test]
fn frames_and_ground_truth_layout() {
    let l = labels();
    let o = run(&SynthParams::default(), 1);
    assert_eq!(o.frames.len(), 40 * 20);
    assert_eq!(o.gt_all.len(), o.frames.len());
    assert_eq!(o.gt_last.len(), 40);
    for (c, label) in l.iter().enumerate() {
        let clip = &o.frames[c * 20..(c + 1) * 20];
        for (k, f) in clip.iter().enumerate() {
            assert_eq!(f.clip, clip[0].clip);
            assert!((f.t - 0.05 * k as f64).abs() < 1e-12);
            assert_eq!(f.h_samples.as_ref(), Some(&label.h_samples));
            let raw = f.raw_file.as_deref().unwrap();
            assert_eq!(raw, o.gt_all[c * 20 + k].raw_file);
            if k == 19 {
                assert_eq!(raw, label.raw_file);
            } else {
                assert_eq!(raw, format!("synth/{}/{}.jpg", f.clip, k + 1));
            }
        }
        assert_ne!(clip[0].clip, if c > 0 { &o.frames[0].clip } else { "" });
        assert_eq!(o.gt_last[c], o.gt_all[c * 20 + 19]);
    }
    assert_eq!(
        o.stats.total_points(),
        o.frames.iter().map(|f| f.points.len()).sum::<usize>()
    );
}

#[test]
fn last_frame_ground_truth_is_the_label() {
    let l = labels();
    // Default parameters: every animation vanishes at the last frame; merge lanes are appended.
    let o = run(&SynthParams::preset(NoiseLevel::High), 3);
    assert!(o.stats.merges > 0 && o.stats.lane_changes > 0 && o.stats.far_end_changes > 0);
    for (g, s) in o.gt_last.iter().zip(&l) {
        assert_eq!(g.raw_file, s.raw_file);
        assert_eq!(g.h_samples, s.h_samples);
        assert_eq!(&g.lanes[..s.lanes.len()], &s.lanes[..], "{}", s.raw_file);
        assert!(g.lanes.len() <= s.lanes.len() + 1);
    }
    // Without merges the record is the label itself.
    let p = SynthParams {
        merge_prob: 0.0,
        ..SynthParams::default()
    };
    assert_eq!(run(&p, 3).gt_last, l);
}

#[test]
fn points_lie_inside_the_image_below_the_horizon() {
    let cam = Camera::tusimple();
    for level in [NoiseLevel::Low, NoiseLevel::Mid, NoiseLevel::High] {
        let o = run(&SynthParams::preset(level), 11);
        for f in &o.frames {
            for p in &f.points {
                assert!(
                    p[0] >= 0.0 && p[0] < cam.width && p[1] > cam.vp_row && p[1] < cam.height,
                    "{level:?} {} t={}: {p:?}",
                    f.clip,
                    f.t
                );
            }
            // Sorted bottom-up: the order does not tell lanes apart.
            assert!(f.points.windows(2).all(|w| w[0][1] >= w[1][1]));
        }
        for g in &o.gt_all {
            for lane in &g.lanes {
                assert!(lane
                    .iter()
                    .all(|&x| x == -2.0 || (0.0..cam.width).contains(&x)));
            }
        }
    }
}

/// Lane points and clutter measured independently of the generator's counters: on the
/// `h_samples` rows, a point exactly (1e-6 px) on a ground-truth lane is a lane point, anything
/// else is clutter.
#[test]
fn miss_and_clutter_rates_match_parameters() {
    let (pd, lambda) = (0.7, 25.0);
    let o = run(&clean(pd, lambda), 5);
    let (mut expected, mut found, mut clutter, mut clutter_rows) = (0usize, 0usize, 0usize, 0f64);
    for (f, g) in o.frames.iter().zip(&o.gt_all) {
        for (j, &row) in g.h_samples.iter().enumerate() {
            let on_row: Vec<f64> = f
                .points
                .iter()
                .filter(|p| p[1] == row)
                .map(|p| p[0])
                .collect();
            let lane_cols: Vec<f64> = g.lanes.iter().map(|l| l[j]).filter(|&x| x >= 0.0).collect();
            expected += lane_cols.len();
            found += lane_cols
                .iter()
                .filter(|&&x| on_row.iter().any(|&c| (c - x).abs() < 1e-6))
                .count();
            clutter += on_row
                .iter()
                .filter(|&&c| !lane_cols.iter().any(|&x| (c - x).abs() < 1e-6))
                .count();
        }
        // Clutter rows are uniform over the integer rows from the first h_sample to the bottom.
        let top = g.h_samples[0];
        let n_rows = 720.0 - top;
        clutter_rows += lambda * g.h_samples.iter().filter(|&&r| r >= top).count() as f64 / n_rows;
    }
    let rate = found as f64 / expected as f64;
    eprintln!("detected {found} of {expected} ({rate}); clutter {clutter} vs {clutter_rows}");
    let sd = (pd * (1.0 - pd) / expected as f64).sqrt();
    assert!(
        (rate - pd).abs() < 5.0 * sd,
        "detection rate {rate} (of {expected}) vs P_D {pd} ± {sd}"
    );
    let sdc = clutter_rows.sqrt();
    assert!(
        (clutter as f64 - clutter_rows).abs() < 5.0 * sdc,
        "clutter on h_samples rows {clutter} vs expected {clutter_rows} ± {sdc}"
    );
    // The counters agree with the measurement's scale.
    let s = &o.stats;
    assert_eq!(s.dash_gaps + s.occluded + s.shared + s.off_image, 0);
    let pd_all = s.lane_points as f64 / s.lane_rows as f64;
    assert!((pd_all - pd).abs() < 5.0 * (pd * (1.0 - pd) / s.lane_rows as f64).sqrt());
    let per_frame = s.clutter_points as f64 / s.frames as f64;
    assert!(
        (per_frame - lambda).abs() < 5.0 * (lambda / s.frames as f64).sqrt(),
        "{per_frame}"
    );
}

#[test]
fn pixel_noise_has_the_given_sigma() {
    let sigma = 6.0;
    let p = SynthParams {
        pixel_noise: sigma,
        ..clean(1.0, 0.0)
    };
    let o = run(&p, 9);
    let mut resid = Vec::new();
    for (f, g) in o.frames.iter().zip(&o.gt_all) {
        for (j, &row) in g.h_samples.iter().enumerate() {
            for c in f.points.iter().filter(|p| p[1] == row).map(|p| p[0]) {
                let d = g
                    .lanes
                    .iter()
                    .map(|l| l[j])
                    .filter(|&x| x >= 0.0)
                    .map(|x| c - x)
                    .min_by(|a, b| a.abs().total_cmp(&b.abs()));
                if let Some(d) = d {
                    resid.push(d);
                }
            }
        }
    }
    let n = resid.len() as f64;
    let mean = resid.iter().sum::<f64>() / n;
    let sd = (resid.iter().map(|d| d * d).sum::<f64>() / n).sqrt();
    eprintln!("{n} residuals: mean {mean}, sd {sd}");
    assert!(n > 10_000.0);
    assert!(mean.abs() < 0.2, "mean residual {mean}");
    // Lanes are far apart (≫ σ) except near the horizon, so the nearest-lane residual is the noise.
    assert!(
        (sd - sigma).abs() < 0.1 * sigma,
        "residual sd {sd} vs σ {sigma}"
    );
}

#[test]
fn dashes_occlusion_and_structured_clutter_happen() {
    let p = SynthParams {
        dashed_prob: 1.0,
        cars: 2.0,
        shadows: 2.0,
        road_edge_prob: 1.0,
        ..SynthParams::default()
    };
    let s = run(&p, 13).stats;
    // Paint 3 m of every 12 m: about 3/4 of the rows fall in gaps.
    let gap = s.dash_gaps as f64 / (s.lane_rows - s.shared) as f64;
    eprintln!("dash gap share {gap}; {s:?}");
    assert!((0.65..0.85).contains(&gap), "dash gap share {gap}");
    assert!(s.occluded > 0 && s.car_points > 0 && s.shadow_points > 0);
    assert!(s.road_edge_points > 0);
    let none = run(&clean(0.8, 0.0), 13).stats;
    assert_eq!(
        none.dash_gaps + none.occluded + none.car_points + none.shadow_points,
        0
    );
    assert_eq!(none.road_edge_points + none.clutter_points, 0);
}

#[test]
fn merge_lanes_share_points_then_diverge() {
    let p = SynthParams {
        merge_prob: 1.0,
        ..clean(1.0, 0.0)
    };
    let l = labels();
    let o = run(&p, 17);
    assert_eq!(o.stats.merges, 40);
    assert!(o.stats.shared > 0);
    let mut both = 0;
    for (g, s) in o.gt_last.iter().zip(&l) {
        assert_eq!(g.lanes.len(), s.lanes.len() + 1);
        let m = &g.lanes[s.lanes.len()];
        let near = |lane: &Vec<f64>, j: usize| lane[j] >= 0.0 && (lane[j] - m[j]).abs() < 2.0;
        let shared = (0..m.len()).any(|j| m[j] >= 0.0 && s.lanes.iter().any(|l| near(l, j)));
        let apart = (0..m.len()).any(|j| {
            m[j] >= 0.0
                && s.lanes
                    .iter()
                    .all(|l| l[j] < 0.0 || (l[j] - m[j]).abs() > 20.0)
        });
        both += usize::from(shared && apart);
    }
    eprintln!("{both} of 40 merge lanes share and diverge");
    assert!(
        both >= 30,
        "only {both} of 40 merge lanes share and diverge"
    );
}

#[test]
fn scorer_on_ground_truth() {
    let o = run(&SynthParams::default(), 2);
    let s = bench_one_submit(&as_pred(&o.gt_last), &o.gt_last).unwrap();
    assert_eq!((s.accuracy, s.fp, s.fn_), (1.0, 0.0, 0.0));
    let s = bench_one_submit(&as_pred(&o.gt_all), &o.gt_all).unwrap();
    assert_eq!(s.accuracy, 1.0);
    // A clip's first-frame ground truth scored as the prediction of its last frame.
    let first_as_last = |o: &SynthOutput| -> f64 {
        let preds: Vec<TuSimpleRecord> = (0..40)
            .map(|c| TuSimpleRecord {
                raw_file: o.gt_last[c].raw_file.clone(),
                run_time: Some(1.0),
                ..o.gt_all[c * 20].clone()
            })
            .collect();
        bench_one_submit(&preds, &o.gt_last).unwrap().accuracy
    };
    let moving = first_as_last(&o);
    eprintln!("first-frame GT scored against last-frame GT: accuracy {moving}");
    assert!(moving < 0.9, "first vs last frame accuracy {moving}");
    // Control: a static road (no drift, lane change, far-end change or merge) does not move.
    let still = SynthParams {
        motion: 0.0,
        lane_change_prob: 0.0,
        far_end_prob: 0.0,
        merge_prob: 0.0,
        ..SynthParams::default()
    };
    assert_eq!(first_as_last(&run(&still, 2)), 1.0);
}

#[test]
fn presets_are_ordered_and_bad_parameters_rejected() {
    let [l, m, h] = [NoiseLevel::Low, NoiseLevel::Mid, NoiseLevel::High].map(SynthParams::preset);
    assert!(l.pixel_noise < m.pixel_noise && m.pixel_noise < h.pixel_noise);
    assert!(l.detect_prob > m.detect_prob && m.detect_prob > h.detect_prob);
    assert!(l.clutter_rate < m.clutter_rate && m.clutter_rate < h.clutter_rate);
    let bad = SynthParams {
        detect_prob: 1.5,
        ..SynthParams::default()
    };
    let e = synthesize(&labels(), &bad, &Camera::tusimple(), 0).unwrap_err();
    assert!(format!("{e:#}").contains("detect_prob"), "{e:#}");
    let mut dup = labels();
    dup[1].raw_file = dup[0].raw_file.clone();
    let e = synthesize(&dup, &SynthParams::default(), &Camera::tusimple(), 0).unwrap_err();
    assert!(format!("{e:#}").contains("appears twice"), "{e:#}");
}

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("stjpdacf-synth-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn cli_writes_frames_and_ground_truth() {
    let d = temp_dir("cli");
    let labels = stjpdacf_tools::repo_root().join("data/tusimple/train_subset.json");
    let gen = |name: &str, seed: &str| {
        let out = stjpdacf()
            .args(["synth", "--labels"])
            .arg(&labels)
            .arg("--out")
            .arg(d.join(format!("{name}.jsonl")))
            .arg("--gt")
            .arg(d.join(format!("{name}-gt.jsonl")))
            .arg("--gt-all")
            .arg(d.join(format!("{name}-gt-all.jsonl")))
            .args(["--seed", seed, "--clips", "5", "--noise", "low"])
            .output()
            .unwrap();
        assert_success(&out);
        // The labels fit the default camera: no warning.
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("outside"), "{err}");
        std::fs::read(d.join(format!("{name}.jsonl"))).unwrap()
    };
    let a = gen("a", "4");
    assert_eq!(a, gen("b", "4"));
    let frames = stjpdacf_tools::tusimple::read_frames(&d.join("a.jsonl")).unwrap();
    assert_eq!(frames.len(), 100);
    let gt = read_labels(&d.join("a-gt.jsonl")).unwrap();
    assert_eq!(gt.len(), 5);
    assert_eq!(read_labels(&d.join("a-gt-all.jsonl")).unwrap().len(), 100);
    // The library with the same settings writes the same bytes.
    let p = SynthParams::preset(NoiseLevel::Low);
    let o = synthesize(&labels_first(5), &p, &Camera::tusimple(), 4).unwrap();
    let mut b = Vec::new();
    write_jsonl_to(&mut b, &o.frames).unwrap();
    assert_eq!(a, b);
    let bad = stjpdacf()
        .args(["synth", "--labels", "/nonexistent/labels.json", "--out"])
        .arg(d.join("x.jsonl"))
        .output()
        .unwrap();
    assert_failure_mentions(&bad, "/nonexistent/labels.json");
    // TuSimple's 1280x720 labels through a 1640x590 camera: their rows below 590 are outside
    // its image, which the user is told.
    let other = stjpdacf()
        .args(["synth", "--clips", "3", "--camera", "culane", "--labels"])
        .arg(&labels)
        .arg("--out")
        .arg(d.join("culane.jsonl"))
        .output()
        .unwrap();
    assert_success(&other);
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(
        err.contains("label points lie outside the 1640x590 image of --camera"),
        "{err}"
    );
    std::fs::remove_dir_all(&d).unwrap();
}

fn labels_first(k: usize) -> Vec<TuSimpleRecord> {
    labels().into_iter().take(k).collect()
}

#[test]
fn true_lane_ids_are_stable_across_a_clip() {
    let l = labels();
    let o = run(&SynthParams::preset(NoiseLevel::High), 3);
    assert_eq!(o.gt_lane_ids.len(), o.gt_all.len());
    assert_eq!(o.clip_stats.len(), 40);
    assert_eq!(
        o.clip_stats.iter().map(|s| s.merges).sum::<usize>(),
        o.stats.merges
    );
    assert_eq!(
        o.clip_stats.iter().map(|s| s.lane_points).sum::<usize>(),
        o.stats.lane_points
    );
    // Mean column distance of two lanes over the rows where both have a point.
    let dist = |a: &[f64], b: &[f64]| -> Option<f64> {
        let d: Vec<f64> = a
            .iter()
            .zip(b)
            .filter(|(x, y)| **x >= 0.0 && **y >= 0.0)
            .map(|(x, y)| (x - y).abs())
            .collect();
        (!d.is_empty()).then(|| d.iter().sum::<f64>() / d.len() as f64)
    };
    let (mut left_out, mut checked) = (0, 0);
    for (c, label) in l.iter().enumerate() {
        let n = label.lanes.len();
        let merge = o.clip_stats[c].merges > 0;
        for k in 0..20 {
            let j = c * 20 + k;
            let (ids, g) = (&o.gt_lane_ids[j], &o.gt_all[j]);
            assert_eq!(ids.len(), g.lanes.len());
            assert!(ids.windows(2).all(|w| w[0] < w[1]), "{ids:?}");
            assert!(ids.iter().all(|&t| t < n + usize::from(merge)), "{ids:?}");
            left_out += usize::from(ids.iter().take_while(|&&t| t < n).count() < n);
            if k == 19 {
                assert_eq!(&ids[..n], &(0..n).collect::<Vec<_>>()[..]);
            }
            if k == 0 {
                continue;
            }
            // The same true lane in the previous frame is nearer than any other lane there (a
            // merge/split lane coincides with its parent over its shared stretch: those two
            // are not compared).
            let (pids, pg) = (&o.gt_lane_ids[j - 1], &o.gt_all[j - 1]);
            for (t, lane) in ids.iter().zip(&g.lanes) {
                let Some(same) = pids
                    .iter()
                    .position(|p| p == t)
                    .and_then(|i| dist(lane, &pg.lanes[i]))
                else {
                    continue;
                };
                for (p, other) in pids.iter().zip(&pg.lanes) {
                    if p != t && *p < n && *t < n {
                        if let Some(d) = dist(lane, other) {
                            assert!(same < d, "clip {c} frame {k} lane {t}: {same} vs {p}: {d}");
                        }
                    }
                }
                checked += 1;
            }
        }
    }
    eprintln!("{left_out} frames leave a label lane out; {checked} lane pairs checked");
    // Some frames leave a lane out of the record: a record index would not be a stable lane.
    assert!(left_out > 0 && checked > 2500);
}

#[test]
fn distractors_add_points_and_change_nothing_else() {
    for level in [NoiseLevel::Low, NoiseLevel::Mid, NoiseLevel::High] {
        assert_eq!(SynthParams::preset(level).distractors, 0.0);
    }
    let p0 = SynthParams::default();
    let p3 = SynthParams {
        distractors: 3.0,
        ..p0.clone()
    };
    let (a, b) = (run(&p0, 5), run(&p3, 5));
    assert_eq!(a.gt_all, b.gt_all);
    assert_eq!(a.gt_lane_ids, b.gt_lane_ids);
    assert_eq!((a.stats.distractors, a.stats.distractor_points), (0, 0));
    let mut without = b.stats.clone();
    (without.distractors, without.distractor_points) = (0, 0);
    assert_eq!(without, a.stats);
    let cam = Camera::tusimple();
    let mut extra = 0;
    for (fa, fb) in a.frames.iter().zip(&b.frames) {
        assert_eq!(
            (&fa.clip, fa.t, &fa.raw_file),
            (&fb.clip, fb.t, &fb.raw_file)
        );
        let mut rest = fb.points.clone();
        for p in &fa.points {
            let i = rest.iter().position(|q| q == p).unwrap();
            rest.swap_remove(i);
        }
        extra += rest.len();
        for q in rest {
            let (u, x) = cam.to_bev(q[0], q[1]).unwrap();
            assert!((3.0..=80.0).contains(&u), "{q:?}: u = {u}");
            assert!(x.abs() < 15.0, "{q:?}: x = {x}");
            assert!((0.0..1280.0).contains(&q[0]) && q[1] % 2.0 == 0.0, "{q:?}");
        }
    }
    assert_eq!(extra, b.stats.distractor_points);
    let per_frame = b.stats.distractors as f64 / b.frames.len() as f64;
    assert!((2.7..3.3).contains(&per_frame), "{per_frame}");
    assert!(b.stats.distractor_points > 2 * b.stats.distractors);
    let bad = SynthParams {
        distractors: -1.0,
        ..SynthParams::default()
    };
    let e = synthesize(&labels(), &bad, &cam, 0).unwrap_err();
    assert!(format!("{e:#}").contains("distractors"), "{e:#}");
}

#[test]
fn sources_switched_off_make_no_points() {
    let mut p = SynthParams::preset(NoiseLevel::High);
    let all = synthesize(&labels_first(4), &p, &Camera::tusimple(), 5)
        .unwrap()
        .stats;
    assert!(all.car_points > 0 && all.road_edge_points > 0 && all.shadow_points > 0);
    p.switch_off("cars, road_edge,,shadows").unwrap();
    let o = synthesize(&labels_first(4), &p, &Camera::tusimple(), 5).unwrap();
    let s = &o.stats;
    assert_eq!(
        (s.car_points, s.road_edge_points, s.shadow_points),
        (0, 0, 0)
    );
    assert!(s.clutter_points > 0 && s.lane_points > 0);
    p.switch_off("clutter").unwrap();
    let o = synthesize(&labels_first(4), &p, &Camera::tusimple(), 5).unwrap();
    assert_eq!(o.stats.clutter_points, 0);
    let e = p.switch_off("cars,trees").unwrap_err().to_string();
    assert!(e.contains("trees") && e.contains("road_edge"), "{e}");
}

/// Rates and clip lengths far beyond any preset are refused up front (the CLI audit: `synth
/// --clutter-rate 1e12` exhausted the memory, `--distractors 1e12` ran for hours, `demo
/// --frames-per-clip 1e11` aborted on a 16 TB allocation); the error shows the value as
/// `1e300`, not in its 301 digits.
#[test]
fn huge_rates_and_clip_lengths_are_refused() {
    for (name, p) in [
        (
            "clutter_rate",
            SynthParams {
                clutter_rate: 1e12,
                ..SynthParams::default()
            },
        ),
        (
            "distractors",
            SynthParams {
                distractors: 1e12,
                ..SynthParams::default()
            },
        ),
        (
            "frames_per_clip",
            SynthParams {
                frames_per_clip: 100_000_000_000,
                ..SynthParams::default()
            },
        ),
    ] {
        let e = synthesize(&labels_first(1), &p, &Camera::tusimple(), 0).unwrap_err();
        assert!(format!("{e:#}").contains(name), "{e:#}");
    }
    let at_bound = SynthParams {
        clutter_rate: SynthParams::MAX_RATE,
        ..SynthParams::default()
    };
    assert!(synthesize(&labels_first(1), &at_bound, &Camera::tusimple(), 0).is_ok());
    let d = temp_dir("huge");
    let labels = stjpdacf_tools::repo_root().join("data/tusimple/train_subset.json");
    for flag in ["--clutter-rate", "--distractors"] {
        let out = stjpdacf()
            .args(["synth", "--clips", "1", "--labels"])
            .arg(&labels)
            .arg("--out")
            .arg(d.join("x.jsonl"))
            .args([flag, "1e300"])
            .output()
            .unwrap();
        // The value as given, not its 301 digits.
        assert_failure_mentions(&out, "= 1e300 is above 10000");
    }
    std::fs::remove_dir_all(&d).unwrap();
}
