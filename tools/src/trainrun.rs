//! The `stjpdacf train` pipeline: TuSimple labels → BEV training frames → ICM fit (and the
//! temporal Matérn-3/2 fit) → a complete `stjpdacf-hyper/v1` file with provenance, and an
//! optional report (B heat map PNG, JSON and markdown summaries).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use nalgebra::{DMatrix, DVector};
use plotters::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::json;

use crate::camera::Camera;
use crate::train::{
    correlation, fit_icm, fit_matern, label_to_frame, read_labels, stationary_b,
    stationary_profile, temporal_series, FitConfig, FitResult, Frame, FrameConfig, IcmParams,
    LabelFrame, Layout, MaternParams,
};
use stjpdacf_reference::hyper::{Coregionalization, HyperFile, SCHEMA};

/// Options of a training run.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    /// TuSimple label files (JSON lines).
    pub labels: Vec<PathBuf>,
    /// Base hyperparameter file: window, D, N and every field not trained come from it.
    pub base: PathBuf,
    /// Camera of the labels.
    pub camera: Camera,
    /// L-BFGS starts.
    pub restarts: usize,
    /// Seed of the frame subsampling and the random starts.
    pub seed: u64,
    /// At most this many frames (evenly spread over the usable ones).
    pub max_frames: usize,
    /// Minimum spacing in `u` of the points kept per lane, metres.
    pub spacing: f64,
    /// L-BFGS iterations per start.
    pub max_iters: u64,
    /// Per-lane offset variance σ_c² (m²); `None` = the base file's `spatial.offset_variance`.
    pub offset_variance: Option<f64>,
    /// Also train σ_c² (otherwise it stays fixed).
    pub train_offset: bool,
    /// Write the fitted temporal length-scale into the output (otherwise the base value is kept
    /// and the fit is only recorded in the provenance).
    pub use_fitted_temporal: bool,
    /// Temporal series are cut where consecutive labelled clips are further apart, seconds.
    pub max_gap: f64,
}

/// What a training run produced.
#[derive(Debug, Clone)]
pub struct TrainOutcome {
    /// The complete hyperparameter file (validated).
    pub hyper: HyperFile,
    /// The spatial fit.
    pub fit: FitResult,
    /// The training frames used.
    pub frames_used: usize,
    /// Everything recorded in `hyper.provenance`.
    pub summary: serde_json::Value,
}

fn matrix_rows(m: &DMatrix<f64>) -> Vec<Vec<f64>> {
    (0..m.nrows())
        .map(|i| (0..m.ncols()).map(|j| m[(i, j)]).collect())
        .collect()
}

/// Runs the training; `progress(start, evaluations, LML)` is called after each evaluation.
pub fn run(
    opts: &TrainOptions,
    progress: &(dyn Fn(usize, usize, f64) + Sync),
) -> Result<TrainOutcome> {
    let t0 = std::time::Instant::now();
    anyhow::ensure!(
        opts.spacing.is_finite() && opts.spacing >= 0.0,
        "the spacing of the points kept per lane must be finite and ≥ 0 m, not {}",
        opts.spacing
    );
    anyhow::ensure!(
        opts.max_frames >= 1,
        "the most frames to train on must be ≥ 1"
    );
    anyhow::ensure!(
        opts.max_gap.is_finite() && opts.max_gap >= 0.0,
        "the largest gap of a temporal series must be finite and ≥ 0 s, not {:?}",
        opts.max_gap
    );
    if let Some(v) = opts.offset_variance {
        anyhow::ensure!(
            v.is_finite() && v > 0.0,
            "the offset variance σ_c² must be finite and > 0 m², not {v:?}"
        );
    }
    let base = HyperFile::load(&opts.base)?;
    let d = base.lanes();
    let frame_cfg = FrameConfig {
        u_min: base.window.u_min,
        u_max: base.window.u_max,
        spacing: opts.spacing,
        min_points: 3,
        max_lanes: d,
    };
    let mut labels: Vec<LabelFrame> = Vec::new();
    let mut per_file = Vec::new();
    for p in &opts.labels {
        let l = read_labels(p)?;
        per_file.push(json!({ "path": crate::shown_path(p), "frames": l.len() }));
        labels.extend(l);
    }
    let mut too_many = 0usize;
    let mut usable: Vec<(usize, Frame)> = Vec::new();
    for (i, l) in labels.iter().enumerate() {
        match label_to_frame(
            l,
            &opts.camera,
            &FrameConfig {
                max_lanes: usize::MAX,
                ..frame_cfg
            },
        ) {
            Some(f) if f.lanes.len() <= d => usable.push((i, f)),
            Some(_) => too_many += 1,
            None => {}
        }
    }
    anyhow::ensure!(!usable.is_empty(), "no usable frames in the labels");
    // Evenly spread subset, with a seeded phase.
    let m = opts.max_frames.min(usable.len()).max(1);
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let phase: f64 = rng.random_range(0.0..1.0);
    let step = usable.len() as f64 / m as f64;
    let chosen: Vec<usize> = (0..m)
        .map(|k| (((k as f64 + phase) * step) as usize).min(usable.len() - 1))
        .collect();
    let frames: Vec<Frame> = chosen.iter().map(|&k| usable[k].1.clone()).collect();
    let used_files: Vec<&str> = chosen
        .iter()
        .map(|&k| labels[usable[k].0].raw_file.as_str())
        .collect();
    let mut lane_hist = vec![0usize; d + 1];
    for f in &frames {
        lane_hist[f.lanes.len()] += 1;
    }
    // Slots beyond the largest lane count in the data have no information: fit the leading
    // `d_fit` slots and extend B to D stationarily afterwards.
    let d_fit = frames.iter().map(|f| f.lanes.len()).max().unwrap_or(1);
    let n_points: usize = frames.iter().map(Frame::points).sum();

    // Initial values: the base file, with W widened to full rank by small seeded entries (a zero
    // column has zero gradient and would stay zero).
    let bw = &base.coregionalization.w;
    let r0 = bw.first().map_or(0, Vec::len);
    let mean_b = base.coreg().diagonal().mean();
    let small = 0.05 * (mean_b / d as f64).sqrt();
    let w = DMatrix::from_fn(d_fit, d_fit, |i, j| {
        if j < r0 {
            bw[i][j]
        } else {
            small * rng.sample::<f64, _>(rand_distr::StandardNormal)
        }
    });
    let init = IcmParams {
        w,
        kappa: DVector::from_fn(d_fit, |i, _| base.coregionalization.kappa[i]),
        variance: 1.0,
        lengthscale: base.spatial.lengthscale,
        offset_variance: opts.offset_variance.unwrap_or(base.spatial.offset_variance),
        noise: base.noise.measurement,
    };
    let cfg = FitConfig {
        layout: Layout {
            lanes: d_fit,
            rank: d_fit,
            train_variance: false,
            train_offset: opts.train_offset,
        },
        init,
        restarts: opts.restarts,
        seed: opts.seed,
        max_iters: opts.max_iters,
    };
    let fit = fit_icm(&frames, &cfg, progress)?;
    let spatial_seconds = t0.elapsed().as_secs_f64();

    // Temporal Matérn-3/2 from time-stamped sessions.
    let series = temporal_series(
        &labels,
        &opts.camera,
        &base.index_u(),
        base.window.u_min,
        opts.max_gap,
        3,
    );
    let series_points: usize = series.iter().map(|s| s.t.len()).sum();
    let temporal = if series.is_empty() {
        json!({ "fitted": null, "note": "no time-stamped label sessions in the input" })
    } else {
        let starts: Vec<MaternParams> = [5.0, 30.0, 120.0]
            .iter()
            .map(|&l| MaternParams {
                variance: 1.0,
                lengthscale: l,
                offset_variance: fit.params.offset_variance,
                noise: 0.01,
            })
            .collect();
        let (p, lml, per) = fit_matern(&series, &starts, 300)?;
        let gaps: Vec<f64> = series
            .iter()
            .flat_map(|s| s.t.windows(2).map(|w| w[1] - w[0]).collect::<Vec<_>>())
            .collect();
        let mut sorted = gaps.clone();
        sorted.sort_by(f64::total_cmp);
        let median_gap = sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN);
        json!({
            "series": series.len(),
            "points": series_points,
            "median_spacing_s": median_gap,
            "max_gap_s": opts.max_gap,
            "fitted": { "variance": p.variance, "lengthscale": p.lengthscale, "noise": p.noise,
                        "offset_variance": p.offset_variance, "lml": lml, "lml_per_start": per },
        })
    };
    let fitted_lt = temporal["fitted"]["lengthscale"].as_f64();

    let p = &fit.params;
    let b_fit = p.b();
    let (w_ext, kappa_ext) = crate::train::extend_stationary(&b_fit, &p.kappa, d)?;
    let b = &w_ext * w_ext.transpose() + DMatrix::from_diagonal(&kappa_ext);
    let mut hyper = base.clone();
    hyper.schema = SCHEMA.to_string();
    hyper.spatial.variance = p.variance;
    hyper.spatial.lengthscale = p.lengthscale;
    hyper.spatial.offset_variance = p.offset_variance;
    hyper.noise.measurement = p.noise;
    hyper.coregionalization = Coregionalization {
        w: matrix_rows(&w_ext),
        kappa: kappa_ext.iter().copied().collect(),
    };
    let temporal_used = match (opts.use_fitted_temporal, fitted_lt) {
        (true, Some(l)) => {
            hyper.temporal.lengthscale = l;
            "fitted"
        }
        _ => "base",
    };
    hyper.description = format!(
        "Trained by `stjpdacf train` on {m} TuSimple label frames ({n_points} BEV points, \
         {} restarts, seed {}): ICM kernel B ⊗ RBF with σ_u² = 1 fixed, per-lane offset \
         marginalised (σ_c² = {:.3} m²{}), LML {:.3}. Camera: flat-road IPM, f = {} px assumed. \
         Temporal length-scale: {}. Fields not trained come from {}.",
        opts.restarts,
        opts.seed,
        p.offset_variance,
        if opts.train_offset {
            ", trained"
        } else {
            ", fixed"
        },
        fit.lml,
        opts.camera.focal_px,
        if temporal_used == "fitted" {
            "fitted Matérn-3/2 on time-stamped label series (see provenance)"
        } else {
            "kept from the base file (the fit on label series is in the provenance)"
        },
        crate::shown_path(&opts.base),
    );
    let summary = json!({
        "tool": "stjpdacf train",
        "labels": per_file,
        "base": crate::shown_path(&opts.base),
        "camera": opts.camera,
        "frame_config": frame_cfg,
        "frames_total": labels.len(),
        "frames_usable": usable.len(),
        "frames_dropped_too_many_lanes": too_many,
        "frames_used": m,
        "frames_used_by_lane_count": lane_hist,
        "frames_used_files_first": used_files.iter().take(20).collect::<Vec<_>>(),
        "points": n_points,
        "seed": opts.seed,
        "restarts": fit.restarts,
        "max_iters": opts.max_iters,
        "lml": fit.lml,
        "lml_per_point": fit.lml / n_points as f64,
        "spatial": { "variance": p.variance, "lengthscale": p.lengthscale,
                     "offset_variance": p.offset_variance, "offset_trained": opts.train_offset,
                     "noise": p.noise },
        "slots_fitted": d_fit,
        "slots_written": d,
        "slot_note": if d_fit < d {
            format!("no frame has more than {d_fit} lanes: B is fitted on slots 0..{d_fit}; \
                     entries of slots {d_fit}..{d} are the stationary profile of the fitted B")
        } else {
            "all slots fitted".to_string()
        },
        "B_fitted": matrix_rows(&b_fit),
        "W_fitted": matrix_rows(&p.w),
        "kappa_fitted": p.kappa.iter().copied().collect::<Vec<_>>(),
        "B": matrix_rows(&b),
        "B_correlation": matrix_rows(&correlation(&b_fit)),
        "B_stationary_profile": stationary_profile(&b_fit),
        "B_stationary": matrix_rows(&stationary_b(&b_fit)),
        "temporal": temporal,
        "temporal_lengthscale_written": { "value": hyper.temporal.lengthscale, "source": temporal_used },
        "seconds_spatial": spatial_seconds,
        "seconds_total": t0.elapsed().as_secs_f64(),
    });
    hyper.provenance = Some(summary.clone());
    hyper.validate().context("trained file does not validate")?;
    Ok(TrainOutcome {
        hyper,
        fit,
        frames_used: m,
        summary,
    })
}

/// Diverging colour for `v` in `[−m, m]`: blue (negative), white (0), red (positive).
fn diverging(v: f64, m: f64) -> RGBColor {
    let t = if m > 0.0 {
        (v / m).clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let fade = |a: u8| (255.0 - (255.0 - f64::from(a)) * t.abs()).round() as u8;
    if t >= 0.0 {
        RGBColor(fade(178), fade(24), fade(43))
    } else {
        RGBColor(fade(33), fade(102), fade(172))
    }
}

/// Writes a heat map of `B` (left) and of its correlation matrix (right) as a PNG: one square
/// per entry, red positive, blue negative, white zero; `B` is scaled by its largest |entry|,
/// the correlation by 1. No text (no font dependency): the values are in the summary files.
pub fn heatmap_png(path: &Path, b: &DMatrix<f64>) -> Result<()> {
    let d = b.nrows();
    let cell = 60u32;
    let pad = 20u32;
    let side = cell * d as u32;
    let root = BitMapBackend::new(path, (3 * pad + 2 * side, 2 * pad + side)).into_drawing_area();
    root.fill(&WHITE)?;
    let corr = correlation(b);
    let bmax = b.amax();
    for (panel, (m, scale)) in [(b, bmax), (&corr, 1.0)].into_iter().enumerate() {
        let x0 = (pad + panel as u32 * (side + pad)) as i32;
        let y0 = pad as i32;
        for i in 0..d {
            for j in 0..d {
                let (x, y) = (x0 + (j as u32 * cell) as i32, y0 + (i as u32 * cell) as i32);
                root.draw(&Rectangle::new(
                    [(x, y), (x + cell as i32, y + cell as i32)],
                    diverging(m[(i, j)], scale).filled(),
                ))?;
                root.draw(&Rectangle::new(
                    [(x, y), (x + cell as i32, y + cell as i32)],
                    RGBColor(200, 200, 200).stroke_width(1),
                ))?;
            }
        }
    }
    root.present()?;
    Ok(())
}

fn fmt_matrix(m: &DMatrix<f64>) -> String {
    let mut s = String::from("| slot |");
    for j in 0..m.ncols() {
        s += &format!(" {j} |");
    }
    s += "\n|---|";
    for _ in 0..m.ncols() {
        s += "---|";
    }
    s += "\n";
    for i in 0..m.nrows() {
        s += &format!("| {i} |");
        for j in 0..m.ncols() {
            s += &format!(" {:.3} |", m[(i, j)]);
        }
        s += "\n";
    }
    s
}

/// Writes `b_heatmap.png`, `summary.json` and `summary.md` into `dir` (created if needed).
pub fn write_report(dir: &Path, out: &TrainOutcome, command: &str) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let b = out.fit.params.b();
    heatmap_png(&dir.join("b_heatmap.png"), &b)?;
    std::fs::write(
        dir.join("summary.json"),
        serde_json::to_string_pretty(&out.summary)? + "\n",
    )?;
    let s = &out.summary;
    let p = &out.fit.params;
    let mut md = String::new();
    md += "# Training report (`stjpdacf train`)\n\n";
    md += &format!("Command: `{command}`\n\n");
    md += &format!(
        "Frames used: {} of {} usable ({} labels read, {} dropped for more lanes than slots); \
         by lane count (0..=D): {}; {} BEV points. Wall time {:.1} s (spatial fit {:.1} s).\n\n",
        out.frames_used,
        s["frames_usable"],
        s["frames_total"],
        s["frames_dropped_too_many_lanes"],
        s["frames_used_by_lane_count"],
        s["points"],
        s["seconds_total"].as_f64().unwrap_or(f64::NAN),
        s["seconds_spatial"].as_f64().unwrap_or(f64::NAN),
    );
    md += "## Spatial kernel (BEV metres, f = ";
    md += &format!("{} px assumed)\n\n", s["camera"]["focal_px"]);
    md += &format!(
        "- LML {:.3} ({:.4} per point)\n- RBF variance σ_u² = {} (fixed; B carries the scale)\n\
         - length-scale ℓ_u = {:.3} m\n- per-lane offset variance σ_c² = {:.3} m² ({})\n\
         - label noise = {:.5} m² (std {:.3} m)\n\n",
        out.fit.lml,
        s["lml_per_point"].as_f64().unwrap_or(f64::NAN),
        p.variance,
        p.lengthscale,
        p.offset_variance,
        if s["spatial"]["offset_trained"] == true {
            "trained"
        } else {
            "fixed"
        },
        p.noise,
        p.noise.sqrt()
    );
    md += "### B = W Wᵀ + diag(κ) (m²)\n\n";
    md += &fmt_matrix(&b);
    md += &format!("\n{}\n", s["slot_note"].as_str().unwrap_or(""));
    if s["slots_fitted"] != s["slots_written"] {
        let rows: Vec<Vec<f64>> = serde_json::from_value(s["B"].clone())?;
        let bw = DMatrix::from_fn(rows.len(), rows.len(), |i, j| rows[i][j]);
        md += "\n### B as written to the file (extended)\n\n";
        md += &fmt_matrix(&bw);
    }
    md += "\n### Correlation of B\n\n";
    md += &fmt_matrix(&correlation(&b));
    md += "\n### Stationary form (mean of B over |i − j|)\n\n";
    md += &format!(
        "{}\n\n",
        stationary_profile(&b)
            .iter()
            .enumerate()
            .map(|(k, v)| format!("b_{k} = {v:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    md += "![B heat map](b_heatmap.png)\n\n";
    md += "Heat map: left B, right its correlation; red positive, blue negative, white zero \
           (B scaled by its largest entry, correlation by 1); rows/columns are slots 0..D−1 \
           from the left.\n\n";
    md += "## Restarts\n\n| start | initial LML | final LML | iterations | status | seconds |\n\
           |---|---|---|---|---|---|\n";
    for r in &out.fit.restarts {
        md += &format!(
            "| {} | {} | {} | {} | {} | {:.1} |\n",
            r.index,
            r.initial_lml.map_or("—".into(), |v| format!("{v:.3}")),
            r.lml.map_or("failed".into(), |v| format!("{v:.3}")),
            r.iterations,
            r.status,
            r.seconds
        );
    }
    md += "\n## Temporal Matérn-3/2\n\n";
    md += &format!(
        "```json\n{}\n```\n",
        serde_json::to_string_pretty(&s["temporal"])?
    );
    md += &format!(
        "\nWritten temporal length-scale: {} s ({}).\n",
        s["temporal_lengthscale_written"]["value"], s["temporal_lengthscale_written"]["source"]
    );
    std::fs::write(dir.join("summary.md"), md)?;
    Ok(())
}
