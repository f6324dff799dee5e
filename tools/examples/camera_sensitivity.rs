//! How much the real-frame figures depend on the camera: the 10 bundled 512×288 TuSimple frames
//! through front end → tracker → official metric (the demo's real row, `demo::run_real`) with
//! the calibration perturbed — the horizon row, the vanishing column, the camera height and the
//! focal length, one at a time — both as the camera itself (`CameraMode::Given`: what a fixed
//! calibration gives when the vehicle pitches or the calibration is slightly off) and as the
//! guess of the per-image estimate (`CameraMode::Estimate`: the horizon, the vanishing column
//! and the height found in each image, the focal length from the guess) and as the calibration
//! the image refines (`CameraMode::Refine`, `frontend --refine-horizon`: the vanishing point of
//! the marking lines where it is within 1° of the camera's pitch). The last column is
//! the tracker alone: the labelled points as feature points, mapped with the perturbed camera.
//! The last lines average the perturbed-calibration runs over all the cameras, per half of the
//! frames (the front end's tuning half and its held-out half), with the feature points'
//! precision and recall: a smoother figure than one camera's for judging a front-end change.
//!
//! `cargo run --release -p stjpdacf-tools --example camera_sensitivity [name=value ...]` (about
//! 5 s; `name=value` overrides a front-end parameter, [`FrontendParams::set`])
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo::{self, REAL_TO_TUSIMPLE};
use stjpdacf_tools::frontend::{CameraMode, FrontendParams, TUNING_SET};
use stjpdacf_tools::metric;
use stjpdacf_tools::track::{self, Space};
use stjpdacf_tools::tusimple::{read_labels, Frame, TuSimpleRecord};

fn main() -> anyhow::Result<()> {
    let dir = stjpdacf_tools::repo_root().join("data/tusimple/sample_512x288");
    let labels = read_labels(&dir.join("label_data.json"))?;
    // `name=value` arguments override the front end's parameters (as `frontend_eval`).
    let mut p = FrontendParams::default();
    for a in std::env::args().skip(1) {
        let (name, v) = a
            .split_once('=')
            .ok_or_else(|| anyhow::anyhow!("expected name=value, got {a}"))?;
        p.set(name, v.parse()?)?;
    }
    let base = Camera::tusimple().scaled(0.4);
    // (what, perturbed camera at 512×288)
    let mut cases: Vec<(String, Camera)> = vec![("calibration".into(), base)];
    for d in [-2.0, -1.0, -0.5, -0.2, 0.2, 0.5, 1.0, 2.0] {
        cases.push((
            format!("horizon row {d:+} px"),
            Camera {
                vp_row: base.vp_row + d,
                ..base
            },
        ));
    }
    for d in [-4.0, -2.0, -1.0, 1.0, 2.0, 4.0] {
        cases.push((
            format!("vanishing column {d:+} px"),
            Camera {
                vp_col: base.vp_col + d,
                ..base
            },
        ));
    }
    for r in [-0.03, -0.01, 0.01, 0.03] {
        cases.push((
            format!("height {:+}%", r * 100.0),
            Camera {
                height_m: base.height_m * (1.0 + r),
                ..base
            },
        ));
    }
    for r in [-0.05, -0.02, 0.02, 0.05] {
        cases.push((
            format!("focal length {:+}%", r * 100.0),
            Camera {
                focal_px: base.focal_px * (1.0 + r),
                ..base
            },
        ));
    }
    let label_frames: Vec<Frame> = labels.iter().map(demo::label_points_frame).collect();
    let scaled_gt: Vec<TuSimpleRecord> = labels
        .iter()
        .map(|g| demo::scale_record(g, REAL_TO_TUSIMPLE))
        .collect();
    println!(
        "| camera (512×288 px) | calibration perturbed: accuracy / FP / FN | per-image estimate from the perturbed guess | perturbed calibration, horizon refined | label points, perturbed camera |"
    );
    println!("|---|---|---|---|---|");
    let (mut given, mut est, mut refined) = (Vec::new(), Vec::new(), Vec::new());
    // Over every camera of the table (calibration included), per half of the frames (tuning,
    // held-out: `frontend::TUNING_SET`): sums of accuracy, FP, FN, point precision and recall.
    let mut halves = [[0.0f64; 5]; 2];
    let mut counts = [0usize; 2];
    for (what, cam) in &cases {
        let run = demo::run_real(&dir, &labels, &CameraMode::Given(*cam), &p, false)?;
        for f in &run.results {
            let h = usize::from(!TUNING_SET.contains(&f.raw_file.as_str()));
            let s = &mut halves[h];
            s[0] += f.score.accuracy;
            s[1] += f.score.fp;
            s[2] += f.score.fn_;
            s[3] += f.precision;
            s[4] += f.recall;
            counts[h] += 1;
        }
        let g = run.score;
        // The guess is a 1280×720 camera (the estimate scales it to the image's width).
        let guess = cam.scaled(1.0 / 0.4);
        let e = demo::run_real(&dir, &labels, &CameraMode::Estimate(guess), &p, false)?.score;
        let r = demo::run_real(&dir, &labels, &CameraMode::Refine(guess), &p, false)?.score;
        let (lp, _) = track::track_with(
            &label_frames,
            &stjpdacf::tables::DEFAULT,
            cam,
            Space::Image,
            TrackerConfig::DEFAULT,
            |_| {},
        )?;
        let lp: Vec<TuSimpleRecord> = lp
            .iter()
            .map(|r| {
                let mut r = demo::scale_record(r, REAL_TO_TUSIMPLE);
                r.run_time = Some(0.0);
                r
            })
            .collect();
        let l = metric::bench_one_submit(&lp, &scaled_gt)?;
        println!(
            "| {what} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} |",
            g.accuracy, g.fp, g.fn_, e.accuracy, e.fp, e.fn_, r.accuracy, r.fp, r.fn_, l.accuracy, l.fp, l.fn_
        );
        if what != "calibration" {
            given.push(g.accuracy);
            est.push(e.accuracy);
            refined.push(r.accuracy);
        }
    }
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        (v[0], v[n / 2], v[n - 1])
    };
    let (g0, g1, g2) = stats(&mut given);
    let (e0, e1, e2) = stats(&mut est);
    let (r0, r1, r2) = stats(&mut refined);
    println!();
    println!(
        "over the {} perturbations, accuracy min / median / max: calibration perturbed {g0:.3} / {g1:.3} / {g2:.3}; per-image estimate {e0:.3} / {e1:.3} / {e2:.3}; horizon refined {r0:.3} / {r1:.3} / {r2:.3}",
        given.len()
    );
    for (h, name) in ["tuning", "held-out"].iter().enumerate() {
        let n = counts[h].max(1) as f64;
        let m = halves[h].map(|v| v / n);
        println!(
            "{name} half, mean over the {} cameras (calibration perturbed): accuracy {:.3}, FP {:.3}, FN {:.3}; feature points precision {:.3}, recall {:.3}",
            cases.len(),
            m[0],
            m[1],
            m[2],
            m[3],
            m[4]
        );
    }
    Ok(())
}
