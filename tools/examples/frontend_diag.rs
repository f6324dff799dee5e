//! Diagnosis of the image front end's false points and missed label rows (issue 16), per frame
//! of the tuning and held-out halves of the bundled 512×288 TuSimple frames.
//!
//! `cargo run --release -p stjpdacf-tools --example frontend_diag [--png=DIR] [name=value …]`
//!
//! For each frame: every kept line of the parallel-lane filter with its points on the labelled
//! rows, how many are false (not within 6 px of a labelled lane), of those how many are ridge
//! peaks and how many filled samples of the fitted curve (`fill_gap`), and the signed column
//! offset to the nearest labelled lane; then every labelled lane's missed rows (no point within
//! 6 px and 2 rows, nearer than 80 m), each marked with whether any ridge peak (bright or dark,
//! before the parallel-lane filter) lies within 6 px and 2 rows there. `--png=DIR` writes a 2×
//! overlay: labels green, true points red, false points coloured by line (the colour is
//! printed), raw ridge peaks grey (bright) / dark blue (dark), missed label rows as yellow
//! crosses. With the environment variable `DIAG_VERBOSE` set to part of a frame's name, every
//! false point of that frame is listed (row, column, peak or fill, nearest label and offset).

use image::{Rgb, RgbImage};
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::frontend::{self, FrontendParams, HELD_OUT_SET, TUNING_SET};
use stjpdacf_tools::tusimple::{read_labels, TuSimpleRecord};

const TOL: f64 = 6.0;
const PALETTE: [(&str, [u8; 3]); 8] = [
    ("blue", [0, 80, 255]),
    ("magenta", [255, 0, 255]),
    ("cyan", [0, 255, 255]),
    ("orange", [255, 140, 0]),
    ("white", [255, 255, 255]),
    ("purple", [140, 0, 200]),
    ("pink", [255, 150, 180]),
    ("brown", [150, 90, 30]),
];

/// Column of labelled `lane` at row `y` (linear between label rows).
fn lane_x(l: &TuSimpleRecord, lane: &[f64], y: f64) -> Option<f64> {
    let pts: Vec<(f64, f64)> = l
        .h_samples
        .iter()
        .zip(lane)
        .filter(|(_, &x)| x >= 0.0)
        .map(|(&h, &x)| (h, x))
        .collect();
    pts.windows(2).find_map(|w| {
        let ((ya, xa), (yb, xb)) = (w[0], w[1]);
        (ya <= y && y <= yb).then(|| {
            if yb > ya {
                xa + (xb - xa) * (y - ya) / (yb - ya)
            } else {
                xa
            }
        })
    })
}

fn main() -> anyhow::Result<()> {
    let dir = stjpdacf_tools::repo_root().join("data/tusimple/sample_512x288");
    let labels = read_labels(&dir.join("label_data.json"))?;
    let mut p = FrontendParams::default();
    let mut png: Option<std::path::PathBuf> = None;
    for a in std::env::args().skip(1) {
        if let Some(d) = a.strip_prefix("--png=") {
            png = Some(d.into());
            continue;
        }
        let (k, v) = a
            .split_once('=')
            .ok_or_else(|| anyhow::anyhow!("expected name=value: {a}"))?;
        p.set(k, v.parse()?)?;
    }
    let score_cam = Camera::tusimple().scaled(0.4);
    let row_far = score_cam.row_at(80.0).unwrap_or(0.0);
    for (name, set) in [("tuning", TUNING_SET), ("held-out", HELD_OUT_SET)] {
        println!("== {name}");
        let (mut n_all, mut f_all, mut fp_all, mut ff_all) = (0, 0, 0, 0);
        for raw in set {
            let img = frontend::load_rgb(&dir.join(raw))?;
            let cam = frontend::camera_for(&img, None)?;
            let tagged = frontend::detect_tagged(&img, &cam, &p)?;
            let (pts, peaks) = (&tagged.points, &tagged.peaks);
            let l = labels.iter().find(|l| l.raw_file == raw).expect("label");
            let (ymin, ymax) = (l.h_samples[0], l.h_samples[l.h_samples.len() - 1]);
            let nearest = |q: [f64; 2]| {
                l.lanes
                    .iter()
                    .enumerate()
                    .filter_map(|(k, lane)| lane_x(l, lane, q[1]).map(|x| (k, q[0] - x)))
                    .min_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
            };
            let in_rows: Vec<_> = pts
                .iter()
                .filter(|q| q.px[1] >= ymin && q.px[1] <= ymax)
                .collect();
            let is_false =
                |q: &frontend::TaggedPoint| nearest(q.px).is_none_or(|n| n.1.abs() >= TOL);
            let nf = in_rows.iter().filter(|q| is_false(q)).count();
            println!(
                "-- {raw}: {} points on the labelled rows, {} false",
                in_rows.len(),
                nf
            );
            n_all += in_rows.len();
            f_all += nf;
            let nlines = pts
                .iter()
                .map(|q| q.line)
                .filter(|&k| k != usize::MAX)
                .max();
            for li in 0..nlines.map_or(0, |m| m + 1) {
                let lp: Vec<_> = in_rows.iter().filter(|q| q.line == li).collect();
                if lp.is_empty() {
                    continue;
                }
                let fl: Vec<_> = lp.iter().filter(|q| is_false(q)).collect();
                let fpk = fl.iter().filter(|q| q.peak).count();
                fp_all += fpk;
                ff_all += fl.len() - fpk;
                // Runs of false points (sorted by row, a gap of more than 3 rows or a change of
                // the nearest label starts a new run): rows, peaks+fill, nearest label, offsets.
                let mut fs: Vec<_> = fl.iter().map(|q| (q.px, q.peak, nearest(q.px))).collect();
                fs.sort_by(|a, b| a.0[1].total_cmp(&b.0[1]));
                let mut offs: Vec<String> = Vec::new();
                let mut i = 0;
                while i < fs.len() {
                    let mut j = i + 1;
                    while j < fs.len()
                        && fs[j].0[1] - fs[j - 1].0[1] <= 3.0
                        && fs[j].2.map(|n| n.0) == fs[i].2.map(|n| n.0)
                    {
                        j += 1;
                    }
                    let run = &fs[i..j];
                    let npk = run.iter().filter(|q| q.1).count();
                    let lab = match (run[0].2, run[run.len() - 1].2) {
                        (Some((k, a)), Some((_, b))) => format!("L{k} {a:+.0}..{b:+.0}"),
                        _ => "no label".to_string(),
                    };
                    offs.push(format!(
                        "[r{:.0}-{:.0} c{:.0}-{:.0} {}pk+{}f {lab}]",
                        run[0].0[1],
                        run[run.len() - 1].0[1],
                        run[0].0[0],
                        run[run.len() - 1].0[0],
                        npk,
                        run.len() - npk
                    ));
                    i = j;
                }
                if std::env::var("DIAG_VERBOSE").is_ok_and(|v| raw.contains(&v)) {
                    for q in &fs {
                        println!(
                            "      r{:.0} c{:.1} {} {:?}",
                            q.0[1],
                            q.0[0],
                            if q.1 { "peak" } else { "fill" },
                            q.2.map(|n| (n.0, (n.1 * 10.0).round() / 10.0))
                        );
                    }
                }
                let bottom = lp
                    .iter()
                    .max_by(|a, b| a.px[1].total_cmp(&b.px[1]))
                    .unwrap();
                let top = lp
                    .iter()
                    .min_by(|a, b| a.px[1].total_cmp(&b.px[1]))
                    .unwrap();
                let info = tagged.lines[li];
                println!(
                    "   line {li} ({}): at {:+.1} m, a {:+.2} b {:+.3}, evidence {:.1} m ({:.1} bright), median R {:.0}, u {:.0}–{:.0} m; {} pts (rows {:.0}–{:.0}, col {:.0}→{:.0}), false {} = {} peak + {} fill; {}",
                    PALETTE[li % PALETTE.len()].0,
                    info.offset,
                    info.correction.0,
                    info.correction.1,
                    info.evidence,
                    info.bright_evidence,
                    info.median_response,
                    info.u_range.0,
                    info.u_range.1,
                    lp.len(),
                    top.px[1],
                    bottom.px[1],
                    bottom.px[0],
                    top.px[0],
                    fl.len(),
                    fpk,
                    fl.len() - fpk,
                    offs.join(" ")
                );
            }
            let mut misses: Vec<(f64, f64)> = Vec::new();
            for (k, lane) in l.lanes.iter().enumerate() {
                let rows: Vec<(f64, f64)> = l
                    .h_samples
                    .iter()
                    .zip(lane)
                    .filter(|(&h, &x)| x >= 0.0 && h >= row_far)
                    .map(|(&h, &x)| (h, x))
                    .collect();
                let near = |v: &[f64; 2], y: f64, x: f64| {
                    (v[0] - x).abs() < TOL && (v[1] - y).abs() <= 2.0
                };
                let mut desc = Vec::new();
                let mut nm = 0;
                for &(y, x) in &rows {
                    if pts.iter().any(|q| near(&q.px, y, x)) {
                        continue;
                    }
                    nm += 1;
                    misses.push((x, y));
                    let pk = peaks
                        .iter()
                        .filter(|(v, _)| near(v, y, x))
                        .map(|(_, b)| if *b { 'B' } else { 'D' })
                        .collect::<std::collections::BTreeSet<_>>();
                    let u = score_cam.to_bev(x, y).map_or(f64::NAN, |b| b.0);
                    desc.push(format!(
                        "r{y:.0}c{x:.0}({u:.0}m){}",
                        pk.iter().collect::<String>()
                    ));
                }
                println!(
                    "   label L{k}: {} rows, missed {nm}: {}",
                    rows.len(),
                    desc.join(" ")
                );
            }
            if let Some(d) = &png {
                std::fs::create_dir_all(d)?;
                let s = 4u32;
                let mut out = RgbImage::from_fn(img.width() * s, img.height() * s, |c, r| {
                    *img.get_pixel(c / s, r / s)
                });
                let mut dot = |c: f64, r: f64, col: [u8; 3], rad: i64| {
                    let (c, r) = ((c * 4.0).round() as i64, (r * 4.0).round() as i64);
                    for dr in -rad..=rad {
                        for dc in -rad..=rad {
                            let (x, y) = (c + dc, r + dr);
                            if x >= 0
                                && y >= 0
                                && (x as u32) < out.width()
                                && (y as u32) < out.height()
                            {
                                out.put_pixel(x as u32, y as u32, Rgb(col));
                            }
                        }
                    }
                };
                for lane in &l.lanes {
                    for (&x, &y) in lane.iter().zip(&l.h_samples) {
                        if x >= 0.0 {
                            dot(x, y, [0, 255, 0], 3);
                        }
                    }
                }
                for (v, b) in peaks {
                    dot(
                        v[0],
                        v[1],
                        if *b { [128, 128, 128] } else { [0, 0, 128] },
                        0,
                    );
                }
                for q in pts {
                    let col = if is_false(q) {
                        PALETTE[q.line % PALETTE.len()].1
                    } else {
                        [255, 0, 0]
                    };
                    dot(q.px[0], q.px[1], col, if q.peak { 2 } else { 1 });
                }
                for &(x, y) in &misses {
                    for t in -6..=6 {
                        dot(x + t as f64 * 0.25, y + t as f64 * 0.25, [255, 255, 0], 0);
                        dot(x + t as f64 * 0.25, y - t as f64 * 0.25, [255, 255, 0], 0);
                    }
                }
                let stem = raw.replace('/', "_").replace(".jpg", "");
                let raw4 = RgbImage::from_fn(img.width() * s, img.height() * s, |c, r| {
                    *img.get_pixel(c / s, r / s)
                });
                // Quarter tiles of the road (rows 96–288) at 4×: overlay and plain image.
                for (ti, (c0, r0)) in [(0, 96), (256, 96), (0, 192), (256, 192)]
                    .iter()
                    .enumerate()
                {
                    for (kind, src) in [("ov", &out), ("img", &raw4)] {
                        let tile = image::imageops::crop_imm(src, c0 * s, r0 * s, 256 * s, 96 * s)
                            .to_image();
                        tile.save(d.join(format!("{stem}_{kind}{ti}.png")))?;
                    }
                }
                out.save(d.join(format!("{stem}.png")))?;
            }
        }
        println!("{name}: {n_all} points, {f_all} false ({fp_all} ridge peaks, {ff_all} filled)");
    }
    Ok(())
}
