//! Training (issue 6): the ICM log marginal likelihood against the golden values computed with
//! numpy/GPy (`data/golden/coreg_train.json`), its analytic gradient against finite differences,
//! the optimiser against GPy's optimum, recovery of known hyperparameters, and the Matérn-3/2
//! temporal likelihood.

use nalgebra::{DMatrix, DVector};
use serde_json::Value;
use stjpdacf_tools::train::{
    fit_icm, fit_matern, icm_lml, icm_lml_grad, matern_lml_grad, simulate_frames, FitConfig, Frame,
    IcmKernel, IcmParams, Lane, Layout, MaternParams, Series,
};

fn golden() -> Value {
    let path = stjpdacf_tools::repo_root().join("data/golden/coreg_train.json");
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn mat(v: &Value) -> DMatrix<f64> {
    let rows: Vec<Vec<f64>> = serde_json::from_value(v.clone()).unwrap();
    DMatrix::from_fn(rows.len(), rows[0].len(), |i, j| rows[i][j])
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// The golden dataset as one frame with three lanes (outputs), stacked output-major as in GPy.
fn golden_frame(g: &Value) -> Frame {
    let ds = &g["dataset"];
    let xu: Vec<f64> = serde_json::from_value(ds["stacked_X_u"].clone()).unwrap();
    let xo: Vec<usize> = serde_json::from_value(ds["stacked_X_output"].clone()).unwrap();
    let y: Vec<f64> = serde_json::from_value(ds["stacked_Y"].clone()).unwrap();
    let d = ds["D"].as_u64().unwrap() as usize;
    let mut lanes = vec![
        Lane {
            u: vec![],
            x: vec![]
        };
        d
    ];
    for ((u, o), y) in xu.iter().zip(&xo).zip(&y) {
        lanes[*o].u.push(*u);
        lanes[*o].x.push(*y);
    }
    // Output-major stacking must reproduce the golden order exactly.
    let mut k = 0;
    for (o, l) in lanes.iter().enumerate() {
        for _ in &l.u {
            assert_eq!(xo[k], o);
            k += 1;
        }
    }
    Frame { lanes }
}

/// The LML of `frame` at a golden point (`B`, `variance`, `lengthscale`, `noise_variance`; no
/// offset term).
fn golden_lml(frame: &Frame, point: &Value) -> f64 {
    let b = mat(&point["B"]);
    let kernel = IcmKernel {
        b: &b,
        variance: f(&point["variance"]),
        lengthscale: f(&point["lengthscale"]),
        offset_variance: 0.0,
        noise: f(&point["noise_variance"]),
    };
    icm_lml(std::slice::from_ref(frame), &kernel).unwrap()
}

#[test]
fn golden_lml_at_stored_points() {
    let g = golden();
    let frame = golden_frame(&g);
    let points = g["lml_points"].as_array().unwrap();
    assert_eq!(points.len(), 5);
    for p in points {
        let lml = golden_lml(&frame, p);
        let want = f(&p["lml_numpy"]);
        assert!(
            (lml - want).abs() < 1e-8,
            "{}: LML {lml} vs numpy {want} (diff {:e})",
            p["label"],
            lml - want
        );
    }
    let truth = &points[0];
    assert_eq!(truth["label"], "truth");
    assert!((f(&truth["lml_numpy"]) - 41.414201).abs() < 1e-6);
}

#[test]
fn golden_lml_at_gpy_optimum() {
    let g = golden();
    let frame = golden_frame(&g);
    for key in ["fit_fixed_variance", "fit_free_variance"] {
        let fit = &g[key];
        let lml = golden_lml(&frame, fit);
        let want = f(&fit["lml_numpy_at_fitted"]);
        assert!((lml - want).abs() < 1e-8, "{key}: {lml} vs {want}");
    }
}

/// Index grids of simulated frames: frame `f` has `lanes[f]` lanes of `points` points, point
/// `i` of lane `l` at `3 + step·i + shift·l` m.
fn grids(
    lanes: impl IntoIterator<Item = usize>,
    points: usize,
    step: f64,
    shift: f64,
) -> Vec<Vec<Vec<f64>>> {
    lanes
        .into_iter()
        .map(|d| {
            (0..d)
                .map(|l| {
                    (0..points)
                        .map(|i| 3.0 + step * i as f64 + shift * l as f64)
                        .collect()
                })
                .collect()
        })
        .collect()
}

/// The layout of a `lanes × rank` factor `W` with σ² and σ_c² fixed (override what is trained).
fn layout(lanes: usize, rank: usize) -> Layout {
    Layout {
        lanes,
        rank,
        train_variance: false,
        train_offset: false,
    }
}

/// Central finite differences of the summed LML w.r.t. θ, compared with the analytic gradient.
fn check_gradient(frames: &[Frame], p: &IcmParams, layout: &Layout) {
    let theta = layout.pack(p);
    let (_, grad) = icm_lml_grad(frames, p, layout).unwrap();
    assert_eq!(grad.len(), layout.len());
    let h = 1e-5;
    for k in 0..theta.len() {
        let mut tp = theta.clone();
        let mut tm = theta.clone();
        tp[k] += h;
        tm[k] -= h;
        let lp = icm_lml_grad(frames, &layout.unpack(&tp, p), layout)
            .unwrap()
            .0;
        let lm = icm_lml_grad(frames, &layout.unpack(&tm, p), layout)
            .unwrap()
            .0;
        let fd = (lp - lm) / (2.0 * h);
        assert!(
            (fd - grad[k]).abs() <= 1e-6 * grad[k].abs().max(1.0),
            "θ[{k}]: analytic {} vs finite difference {fd}",
            grad[k]
        );
    }
}

#[test]
fn gradient_matches_finite_differences_golden() {
    let g = golden();
    let frame = golden_frame(&g);
    let p = IcmParams {
        w: DMatrix::from_row_slice(3, 3, &[0.5, -0.7, 0.1, 0.6, -1.0, 0.2, 0.55, -0.8, 0.3]),
        kappa: DVector::from_vec(vec![0.05, 0.15, 0.1]),
        variance: 1.3,
        lengthscale: 0.35,
        offset_variance: 0.0,
        noise: 0.012,
    };
    let layout = Layout {
        train_variance: true,
        ..layout(3, 3)
    };
    check_gradient(std::slice::from_ref(&frame), &p, &layout);
}

#[test]
fn gradient_matches_finite_differences_with_offset_and_sub_blocks() {
    // Frames with 1, 2 and 3 of the 4 slots (leading sub-blocks), per-lane offset trained, rank 2.
    let truth = IcmParams {
        w: DMatrix::from_row_slice(4, 2, &[1.0, 0.2, 0.9, -0.1, 0.8, 0.3, 0.6, 0.0]),
        kappa: DVector::from_vec(vec![0.1, 0.2, 0.15, 0.3]),
        variance: 1.0,
        lengthscale: 12.0,
        offset_variance: 4.0,
        noise: 0.02,
    };
    let frames = simulate_frames(&truth, &grids(1..=3, 8, 7.0, 1.0), 7).unwrap();
    let layout = Layout {
        train_variance: true,
        train_offset: true,
        ..layout(4, 2)
    };
    let mut p = truth.clone();
    p.lengthscale = 9.0;
    p.offset_variance = 2.5;
    p.noise = 0.05;
    check_gradient(&frames, &p, &layout);
}

#[test]
fn optimiser_reaches_gpy_optimum() {
    let g = golden();
    let frame = golden_frame(&g);
    let fit = &g["fit_fixed_variance"];
    let layout = layout(3, 3);
    let cfg = FitConfig {
        layout,
        init: IcmParams {
            w: DMatrix::from_element(3, 3, 0.5),
            kappa: DVector::from_element(3, 0.5),
            variance: 1.0,
            lengthscale: 1.0,
            offset_variance: 0.0,
            noise: 0.1,
        },
        restarts: 6,
        seed: 11,
        max_iters: 500,
    };
    let res = fit_icm(std::slice::from_ref(&frame), &cfg, &|_, _, _| {}).unwrap();
    let gpy = f(&fit["lml_gpy_final"]);
    eprintln!(
        "golden fit: LML {} (GPy {gpy}), ℓ {}, noise {}, B {}, restarts {:?}",
        res.lml,
        res.params.lengthscale,
        res.params.noise,
        res.params.b(),
        res.restarts
    );
    assert!(
        res.lml >= gpy - 1e-3,
        "LML {} below GPy's optimum {gpy}; restarts {:?}",
        res.lml,
        res.restarts
    );
    // The optimum is unique up to W's rotation: compare B, ℓ and the noise.
    let b = res.params.b();
    let b_gpy = mat(&fit["B_times_variance"]);
    assert!(
        (&b - &b_gpy).amax() < 2e-3 * b_gpy.amax(),
        "B {b} vs GPy {b_gpy}"
    );
    let ell = f(&fit["lengthscale"]);
    assert!((res.params.lengthscale - ell).abs() < 1e-3 * ell);
    let nv = f(&fit["noise_variance"]);
    assert!((res.params.noise - nv).abs() < 1e-3 * nv);
}

#[test]
fn recovers_known_hyperparameters() {
    // Three slots with strongly shared shape, BEV-like scales, frames with 1..=3 lanes.
    let truth = IcmParams {
        w: DMatrix::from_row_slice(3, 1, &[1.0, 0.9, 0.7]),
        kappa: DVector::from_vec(vec![0.05, 0.1, 0.08]),
        variance: 1.0,
        lengthscale: 15.0,
        offset_variance: 9.0,
        noise: 0.01,
    };
    let lanes = (0..150).map(|k| 1 + k % 3);
    let frames = simulate_frames(&truth, &grids(lanes, 14, 5.8, 0.0), 2024).unwrap();
    let layout = Layout {
        train_offset: true,
        ..layout(3, 3)
    };
    let cfg = FitConfig {
        layout,
        init: IcmParams {
            w: DMatrix::from_fn(3, 3, |i, j| if i == j { 0.5 } else { 0.2 }),
            kappa: DVector::from_element(3, 0.3),
            variance: 1.0,
            lengthscale: 30.0,
            offset_variance: 25.0,
            noise: 0.05,
        },
        restarts: 2,
        seed: 5,
        max_iters: 400,
    };
    let res = fit_icm(&frames, &cfg, &|_, _, _| {}).unwrap();
    let truth_theta = Layout { rank: 1, ..layout };
    let (lml_truth, _) = icm_lml_grad(&frames, &truth, &truth_theta).unwrap();
    assert!(
        res.lml >= lml_truth,
        "optimum {} below the LML at the truth {lml_truth}",
        res.lml
    );
    let p = &res.params;
    eprintln!(
        "recovery: LML {} (truth {lml_truth}), ℓ {}, noise {}, σ_c² {}, B {}, restarts {:?}",
        res.lml,
        p.lengthscale,
        p.noise,
        p.offset_variance,
        p.b(),
        res.restarts
    );
    let rel = |a: f64, b: f64| (a - b).abs() / b;
    assert!(rel(p.lengthscale, 15.0) < 0.1, "ℓ = {}", p.lengthscale);
    assert!(rel(p.noise, 0.01) < 0.1, "noise = {}", p.noise);
    assert!(
        rel(p.offset_variance, 9.0) < 0.3,
        "σ_c² = {}",
        p.offset_variance
    );
    let (b, bt) = (p.b(), truth.b());
    for i in 0..3 {
        for j in 0..3 {
            let scale = (bt[(i, i)] * bt[(j, j)]).sqrt();
            assert!(
                (b[(i, j)] - bt[(i, j)]).abs() < 0.3 * scale,
                "B[{i},{j}] = {} vs {}\n{b}",
                b[(i, j)],
                bt[(i, j)]
            );
        }
    }
}

/// Matérn-3/2 draws at irregular times (seeded), used by the temporal tests.
fn matern_series(p: &MaternParams, count: usize, seed: u64) -> Vec<Series> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let lam = 3f64.sqrt() / p.lengthscale;
    (0..count)
        .map(|_| {
            let mut t: Vec<f64> = vec![0.0];
            for _ in 0..24 {
                let last = *t.last().unwrap();
                t.push(last + rng.random_range(2.0..8.0));
            }
            let n = t.len();
            let k = DMatrix::from_fn(n, n, |i, j| {
                let x = lam * (t[i] - t[j]).abs();
                p.variance * (1.0 + x) * (-x).exp()
                    + p.offset_variance
                    + if i == j { p.noise } else { 0.0 }
            });
            let l = k.cholesky().unwrap().unpack();
            let z = DVector::from_fn(n, |_, _| rng.sample::<f64, _>(rand_distr::StandardNormal));
            let y = l * z;
            Series {
                t,
                y: y.iter().copied().collect(),
            }
        })
        .collect()
}

#[test]
fn matern_gradient_and_recovery() {
    let truth = MaternParams {
        variance: 2.0,
        lengthscale: 25.0,
        offset_variance: 4.0,
        noise: 0.05,
    };
    let series = matern_series(&truth, 120, 99);
    // Gradient vs central differences in log space.
    let p = MaternParams {
        variance: 1.5,
        lengthscale: 18.0,
        offset_variance: 4.0,
        noise: 0.08,
    };
    let (_, g) = matern_lml_grad(&series, &p).unwrap();
    let h = 1e-5;
    for (k, gk) in g.iter().enumerate() {
        let shift = |s: f64| {
            let mut q = p;
            match k {
                0 => q.variance *= s.exp(),
                1 => q.lengthscale *= s.exp(),
                _ => q.noise *= s.exp(),
            }
            matern_lml_grad(&series, &q).unwrap().0
        };
        let fd = (shift(h) - shift(-h)) / (2.0 * h);
        assert!(
            (fd - gk).abs() <= 1e-6 * gk.abs().max(1.0),
            "k = {k}: {gk} vs {fd}"
        );
    }
    let (fit, lml, _) = fit_matern(&series, &[p], 300).unwrap();
    eprintln!("matern: {fit:?}, LML {lml}");
    assert!(lml >= matern_lml_grad(&series, &truth).unwrap().0);
    assert!(
        (fit.lengthscale - 25.0).abs() < 0.2 * 25.0,
        "ℓ_t = {}",
        fit.lengthscale
    );
    assert!(
        (fit.variance - 2.0).abs() < 0.3 * 2.0,
        "σ² = {}",
        fit.variance
    );
}

/// Training options on the bundled label subset with the default base file (spacing 4 m, no
/// offset variance, the fitted temporal scales off, series gaps up to 10 s).
fn subset_options() -> stjpdacf_tools::trainrun::TrainOptions {
    let root = stjpdacf_tools::repo_root();
    stjpdacf_tools::trainrun::TrainOptions {
        labels: vec![root.join("data/tusimple/train_subset/label_data_0601_subset.json")],
        base: root.join("data/hyper/default.json"),
        camera: stjpdacf_tools::camera::Camera::tusimple(),
        restarts: 1,
        seed: 0,
        max_frames: 2,
        spacing: 4.0,
        max_iters: 1,
        offset_variance: None,
        train_offset: false,
        use_fitted_temporal: false,
        max_gap: 10.0,
    }
}

#[test]
fn pipeline_on_label_subset_writes_a_valid_file_and_report() {
    use stjpdacf_tools::trainrun::{run, write_report, TrainOptions};
    let opts = TrainOptions {
        restarts: 2,
        seed: 3,
        max_frames: 8,
        max_iters: 60,
        use_fitted_temporal: true,
        ..subset_options()
    };
    let out = run(&opts, &|_, _, _| {}).unwrap();
    let base = stjpdacf_reference::hyper::HyperFile::load(&opts.base).unwrap();
    out.hyper.validate().unwrap();
    assert_eq!(out.frames_used, 8);
    assert_eq!(out.hyper.lanes(), base.lanes());
    assert_eq!(out.hyper.index_points, base.index_points);
    assert_eq!(out.hyper.noise.pseudo, base.noise.pseudo);
    assert_eq!(
        out.hyper.spatial.offset_variance,
        base.spatial.offset_variance
    );
    assert_eq!(out.hyper.spatial.variance, 1.0);
    assert_eq!(out.hyper.spatial.lengthscale, out.fit.params.lengthscale);
    let s = &out.summary;
    assert_eq!(s["frames_total"], 12);
    assert_eq!(s["restarts"].as_array().unwrap().len(), 2);
    // The fitted block of B is what the file holds.
    let b_file = out.hyper.coreg();
    let b_fit = out.fit.params.b();
    let df = b_fit.nrows();
    assert!((b_file.view((0, 0), (df, df)) - &b_fit).amax() < 1e-9 * b_fit.amax());
    // Time-stamped clips give temporal series, and the fitted ℓ_t was written.
    assert!(s["temporal"]["series"].as_u64().unwrap() > 0);
    assert_eq!(
        out.hyper.temporal.lengthscale,
        s["temporal"]["fitted"]["lengthscale"].as_f64().unwrap()
    );
    // The best start is at least as good as its own starting point.
    let r0 = &out.fit.restarts[0];
    assert!(r0.lml.unwrap() >= r0.initial_lml.unwrap());
    let dir = std::env::temp_dir().join(format!("stjpdacf-train-report-{}", std::process::id()));
    write_report(&dir, &out, "test").unwrap();
    let png = std::fs::read(dir.join("b_heatmap.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert!(std::fs::read_to_string(dir.join("summary.md"))
        .unwrap()
        .contains("Restarts"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Options out of range are refused before training (the CLI audit: a negative spacing, a
/// NaN gap or `--max-frames 0` were taken silently, a NaN offset variance failed as "every
/// start failed").
#[test]
fn out_of_range_options_are_refused() {
    use stjpdacf_tools::trainrun::{run, TrainOptions};
    let good = subset_options();
    for (opts, needle) in [
        (
            TrainOptions {
                spacing: -1.0,
                ..good.clone()
            },
            "spacing",
        ),
        (
            TrainOptions {
                max_frames: 0,
                ..good.clone()
            },
            "most frames",
        ),
        (
            TrainOptions {
                max_gap: f64::NAN,
                ..good.clone()
            },
            "largest gap",
        ),
        (
            TrainOptions {
                offset_variance: Some(f64::NAN),
                ..good.clone()
            },
            "offset variance",
        ),
    ] {
        let e = run(&opts, &|_, _, _| {}).unwrap_err();
        assert!(format!("{e:#}").contains(needle), "{e:#}");
    }
    assert!(run(&good, &|_, _, _| {}).is_ok());
}
