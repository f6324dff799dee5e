//! How far off the guess of the per-image camera estimate (`CameraMode::Estimate`, `stjpdacf
//! frontend --camera estimate`) may be: the 10 bundled 512×288 TuSimple frames through front
//! end → tracker → official metric with the estimate started from guesses whose horizon row,
//! vanishing column, focal length or height are off by large amounts, and the horizon it finds
//! (largest |row − calibration| over the frames), and the same with one camera for all 10
//! frames (`CameraMode::EstimateShared`, `--share all`: they come from one camera), the median of
//! the 10 estimates.
//!
//! `cargo run --release -p stjpdacf-tools --example camera_guess_range` (about 10 s)
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo;
use stjpdacf_tools::frontend::{self, CameraMode, FrontendParams, Share};
use stjpdacf_tools::tusimple::read_labels;

fn main() -> anyhow::Result<()> {
    let dir = stjpdacf_tools::repo_root().join("data/tusimple/sample_512x288");
    let labels = read_labels(&dir.join("label_data.json"))?;
    let p = FrontendParams::default();
    let calib = Camera::tusimple().scaled(0.4);
    // Guesses as 1280×720 cameras (the estimate scales them to the image); the row and column
    // offsets below are 1280×720 pixels (× 0.4 at 512×288).
    let base = Camera::guess(1280.0, 720.0);
    let mut cases: Vec<(String, Camera)> = vec![("Camera::guess".into(), base)];
    let tus = Camera::tusimple();
    cases.push(("the calibration".into(), tus));
    for d in [-100.0, -60.0, -30.0, 30.0, 60.0, 100.0] {
        cases.push((
            format!("calibration, horizon {d:+} rows"),
            Camera {
                vp_row: tus.vp_row + d,
                ..tus
            },
        ));
    }
    for d in [-100.0, -50.0, 50.0, 100.0] {
        cases.push((
            format!("calibration, vanishing column {d:+}"),
            Camera {
                vp_col: tus.vp_col + d,
                ..tus
            },
        ));
    }
    for r in [-0.3, -0.15, 0.15, 0.3] {
        cases.push((
            format!("calibration, focal length {:+}%", r * 100.0),
            Camera {
                focal_px: tus.focal_px * (1.0 + r),
                ..tus
            },
        ));
    }
    for r in [-0.2, 0.2] {
        cases.push((
            format!("calibration, height {:+}%", r * 100.0),
            Camera {
                height_m: tus.height_m * (1.0 + r),
                ..tus
            },
        ));
    }
    println!("| guess (1280×720 px) | accuracy / FP / FN | horizon found: largest / median \\|row − calibration\\| (512×288 rows) | height found, m | one camera for the 10 frames (`--share all`): accuracy / FP / FN | its horizon, \\|row − calibration\\| | its height, m |");
    println!("|---|---|---|---|---|---|---|");
    for (what, guess) in &cases {
        let mode = CameraMode::Estimate(*guess);
        let cams: Vec<Camera> = frontend::run_dir_cameras(&dir, &mode, &labels, &p, |_, _| {})?
            .into_iter()
            .map(|(_, _, c)| c)
            .collect();
        let mut errs: Vec<f64> = cams
            .iter()
            .map(|c| (c.vp_row - calib.vp_row).abs())
            .collect();
        errs.sort_by(f64::total_cmp);
        let (hmin, hmax) = cams.iter().fold((f64::INFINITY, 0.0f64), |a, c| {
            (a.0.min(c.height_m), a.1.max(c.height_m))
        });
        let s = demo::run_real(&dir, &labels, &mode, &p, false)?.score;
        // The same estimates pooled: the 10 frames come from one camera.
        let shared = CameraMode::EstimateShared {
            guess: *guess,
            share: Share::All,
            every: 1,
            fit: frontend::Fit::Camera,
        };
        let run = demo::run_real(&dir, &labels, &shared, &p, false)?;
        let sc = run.camera;
        println!(
            "| {what} | {:.3} / {:.3} / {:.3} | {:.1} / {:.1} | {hmin:.2}–{hmax:.2} | {:.3} / {:.3} / {:.3} | {:.1} | {:.2} |",
            s.accuracy,
            s.fp,
            s.fn_,
            errs[errs.len() - 1],
            errs[errs.len() / 2],
            run.score.accuracy,
            run.score.fp,
            run.score.fn_,
            (sc.vp_row - calib.vp_row).abs(),
            sc.height_m
        );
    }
    Ok(())
}
