//! Precision and recall of the image front end on the tuning and held-out halves of the bundled
//! 512×288 TuSimple frames (`frontend::TUNING_SET`, `frontend::HELD_OUT_SET`), with the default
//! parameters, or with `name=value` overrides given as arguments (for tuning on the tuning set);
//! with the calibrated camera and with its horizon refined from each image.
//!
//! `cargo run --release -p stjpdacf-tools --example frontend_eval [--png=DIR] [name=value …]`
//! (`--png=DIR`: also write each frame's overlay, feature points red and labels green, to DIR;
//! `--bev=DIR`: each frame's bird's-eye view with its feature points; `--no-tracker`: skip the
//! end-to-end part)

use std::time::Instant;

use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::frontend::{self, CameraMode, FrontendParams, Share, HELD_OUT_SET, TUNING_SET};
use stjpdacf_tools::tusimple::read_labels;

fn main() -> anyhow::Result<()> {
    let dir = stjpdacf_tools::repo_root().join("data/tusimple/sample_512x288");
    let labels = read_labels(&dir.join("label_data.json"))?;
    let mut p = FrontendParams::default();
    let mut png: Option<std::path::PathBuf> = None;
    let mut bev: Option<std::path::PathBuf> = None;
    let mut tracker = true;
    for a in std::env::args().skip(1) {
        if a == "--no-tracker" {
            tracker = false;
            continue;
        }
        if let Some(d) = a.strip_prefix("--bev=") {
            bev = Some(d.into());
            continue;
        }
        if let Some(d) = a.strip_prefix("--png=") {
            png = Some(d.into());
            continue;
        }
        let (k, v) = a
            .split_once('=')
            .ok_or_else(|| anyhow::anyhow!("expected name=value: {a}"))?;
        p.set(k, v.parse()?)?;
    }
    // Each half with the calibrated camera, then with its horizon refined from each image
    // (`CameraMode::Refine`, `frontend --refine-horizon`); the calibrated run also writes the
    // BEV views and overlays asked for.
    for refined in [false, true] {
        for (name, set) in [("tuning", TUNING_SET), ("held-out", HELD_OUT_SET)] {
            let (mut t, mut ms) = (frontend::PointTally::default(), 0.0);
            for raw in set {
                let img = frontend::load_rgb(&dir.join(raw))?;
                let t0 = Instant::now();
                let (cam, pts) = if refined {
                    frontend::refine_and_detect(&img, &Camera::tusimple(), &p)?
                } else {
                    let cam = frontend::camera_for(&img, None)?;
                    (cam, frontend::detect(&img, &cam, &p)?)
                };
                ms += t0.elapsed().as_secs_f64() * 1e3;
                let l = labels.iter().find(|l| l.raw_file == raw).expect("label");
                if !refined {
                    write_outputs(raw, &img, &cam, &pts, l, (&bev, &png), &dir)?;
                }
                println!("{}", t.add(raw, frontend::score(&pts, l, 1.0, 6.0)));
            }
            let mode = if refined { ", horizon refined" } else { "" };
            summary(&format!("{name}{mode}"), &t, ms / set.len() as f64);
        }
    }
    if !tracker {
        return Ok(());
    }
    // End to end: front end → tracker → official metric, all 10 frames, with the calibrated
    // camera, with its horizon refined from each image, and with the horizon estimated from
    // each image (no calibration: Camera::guess).
    let guess = Camera::guess(1280.0, 720.0);
    let calibrated = Camera::tusimple().scaled(0.4);
    let shared = |every| CameraMode::EstimateShared {
        guess,
        share: Share::All,
        every,
        fit: frontend::Fit::Camera,
    };
    for (name, mode) in [
        ("calibrated", CameraMode::TuSimple),
        (
            "calibrated, horizon refined",
            CameraMode::Refine(Camera::tusimple()),
        ),
        ("horizon estimated", CameraMode::Estimate(guess)),
        ("one camera estimated for the 10 frames", shared(1)),
        ("one camera estimated on every 5th frame", shared(5)),
    ] {
        let real = stjpdacf_tools::demo::run_real(&dir, &labels, &mode, &p, false)?;
        for (r, f) in real.results.iter().zip(&real.frames) {
            let img = frontend::load_rgb(&dir.join(f.raw_file.as_deref().unwrap_or("")))?;
            let cam = match f.camera {
                Some(c) => c,
                None => frontend::camera_with(&img, &mode)?,
            };
            println!(
                "  {}: accuracy {:.3}, FP {:.3}, FN {:.3} ({} / {} lanes), points P {:.2} R {:.2}, vanishing point ({:.1}, {:.1}), row {:+.1} from the calibration, height {:.2} m",
                r.raw_file, r.score.accuracy, r.score.fp, r.score.fn_, r.lanes, r.gt_lanes,
                r.precision, r.recall, cam.vp_col, cam.vp_row, cam.vp_row - calibrated.vp_row,
                cam.height_m
            );
        }
        let n = real.results.len() as f64;
        // The camera alone (estimating it is part of the front end's time above; with one
        // camera shared, the time of one image's estimate, not amortised).
        let mut cam_ms = 0.0;
        for f in &real.frames {
            let img = frontend::load_rgb(&dir.join(f.raw_file.as_deref().unwrap_or("")))?;
            let t0 = Instant::now();
            frontend::camera_with(&img, &mode)?;
            cam_ms += t0.elapsed().as_secs_f64() * 1e3;
        }
        println!(
            "tracker on the front end's points ({name}): accuracy {:.3}, FP {:.3}, FN {:.3}, front end {:.1} ms per image ({:.1} ms the camera)",
            real.score.accuracy,
            real.score.fp,
            real.score.fn_,
            real.results.iter().map(|r| r.frontend_ms).sum::<f64>() / n,
            cam_ms / n
        );
    }
    Ok(())
}

/// `--bev=DIR` (the frame's bird's-eye view, u 3..43 m at 0.1 m with the far end at the top,
/// x ±8 m at 0.04 m, its feature points red) and `--png=DIR` (the overlay of points and labels).
fn write_outputs(
    raw: &str,
    img: &image::RgbImage,
    cam: &Camera,
    pts: &[[f64; 2]],
    l: &stjpdacf_tools::tusimple::TuSimpleRecord,
    (bev, png): (&Option<std::path::PathBuf>, &Option<std::path::PathBuf>),
    dir: &std::path::Path,
) -> anyhow::Result<()> {
    let name = raw.replace('/', "_").replace(".jpg", ".png");
    if let Some(d) = bev {
        std::fs::create_dir_all(d)?;
        let mut out = image::RgbImage::from_fn(400, 400, |c, r| {
            let u = 43.0 - f64::from(r) * 0.1;
            let x = -8.0 + f64::from(c) * 0.04;
            cam.to_image(u, x)
                .filter(|&(c, r)| {
                    c >= 0.0 && r >= 0.0 && c < cam.width - 1.0 && r < cam.height - 1.0
                })
                .map_or(image::Rgb([0, 0, 0]), |(c, r)| {
                    *img.get_pixel(c as u32, r as u32)
                })
        });
        for &q in pts {
            if let Some((u, x)) = cam.to_bev(q[0], q[1]) {
                let (c, r) = ((x + 8.0) / 0.04, (43.0 - u) / 0.1);
                if c >= 0.0 && r >= 0.0 && c < 400.0 && r < 400.0 {
                    out.put_pixel(c as u32, r as u32, image::Rgb([255, 0, 0]));
                }
            }
        }
        out.save(d.join(&name))?;
    }
    if let Some(d) = png {
        std::fs::create_dir_all(d)?;
        frontend::overlay_png(&dir.join(raw), pts, Some(l), &d.join(name))?;
    }
    Ok(())
}

/// One half's feature points: precision, mean lane recall, lanes found, time per image.
fn summary(name: &str, t: &frontend::PointTally, ms: f64) {
    println!(
        "{name}: precision {:.3} ({}/{}), mean lane recall {:.3}, {} of {} lanes ≥ 0.25, {ms:.1} ms per image",
        t.precision(),
        t.tp,
        t.n,
        t.mean_recall(),
        t.covered(),
        t.recalls.len(),
    );
}
