//! The within-frame row-noise fit (`stjpdacf_tools::rownoise`, docs/design.md §11.12) and its
//! command, `stjpdacf row-noise`.

mod common;

use common::{assert_failure_mentions, assert_success, stjpdacf};

use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use stjpdacf::persist::PersistConfig;
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_reference::model::ModelTables;
use stjpdacf_reference::statespace::{discretize, RbfTaylor};
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::rownoise::{self, RowModel};
use stjpdacf_tools::train::{gaussian_lml, read_labels, Lane};

fn tables() -> ModelTables {
    let root = stjpdacf_tools::repo_root();
    ModelTables::from_hyper(&HyperFile::load(&root.join("data/hyper/default.json")).unwrap())
        .unwrap()
}

/// At `s = 1` the filter's likelihood is the Gaussian likelihood of the state-space kernel's
/// dense covariance `σ_c² 11ᵀ + B_dd K_ss + r I`, `K_ss(d) = H e^{A|d|} P∞ Hᵀ`.
#[test]
fn unscaled_likelihood_is_the_dense_gaussian_one() {
    let t = tables();
    let m = RowModel::from_tables(&t);
    let rbf = RbfTaylor {
        variance: t.hyper.spatial.variance,
        lengthscale: t.hyper.spatial.lengthscale,
        order: t.hyper.spatial.order,
    };
    let u: Vec<f64> = [3.0, 4.5, 7.0, 12.0, 13.3, 20.0, 31.0, 47.5, 66.0, 79.0].to_vec();
    let x: Vec<f64> = u.iter().map(|v| 1.8 + 0.02 * v - 3e-4 * v * v).collect();
    let n = u.len();
    let k = DMatrix::from_fn(n, n, |i, j| {
        m.offset_variance
            + m.b * rbf.kernel_statespace(u[i] - u[j]).unwrap()
            + if i == j { m.noise } else { 0.0 }
    });
    let (dense, _) = gaussian_lml(k, &DVector::from_vec(x.clone())).unwrap();
    let filtered = m.lane_log_likelihood(&Lane { u, x }, 1.0).unwrap();
    assert!(
        (dense - filtered).abs() < 1e-6 * dense.abs().max(1.0),
        "dense {dense}, filter {filtered}"
    );
}

/// Lanes drawn from the model at a known scale give that scale back.
#[test]
fn fit_recovers_the_scale_of_simulated_lanes() {
    let t = tables();
    let m = RowModel::from_tables(&t);
    let nt = m.a.nrows();
    let h = &t.hyper;
    let u: Vec<f64> = (0..61)
        .map(|r| h.window.u_min + r as f64 * h.spatial.row_step)
        .collect();
    let (f, q) = discretize(&m.a, &m.p_inf, h.spatial.row_step);
    let chol = |p: DMatrix<f64>| {
        (p + DMatrix::identity(nt, nt) * 1e-12)
            .cholesky()
            .unwrap()
            .l()
    };
    let lp = chol(&m.p_inf * m.b);
    for (seed, s_true) in [(1u64, 0.05), (2, 0.5)] {
        let lq = chol(&q * (m.b * s_true));
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut normal =
            |k: usize| DVector::<f64>::from_fn(k, |_, _| StandardNormal.sample(&mut rng));
        let lanes: Vec<Lane> = (0..80)
            .map(|_| {
                let c = m.offset_variance.sqrt() * normal(1)[0];
                let mut g = &lp * normal(nt);
                let x = (0..u.len())
                    .map(|k| {
                        if k > 0 {
                            g = &f * &g + &lq * normal(nt);
                        }
                        c + g[0] + m.noise.sqrt() * normal(1)[0]
                    })
                    .collect();
                Lane { u: u.clone(), x }
            })
            .collect();
        let fit = rownoise::fit(&m, &lanes).unwrap();
        assert!(
            fit.scale > s_true / 1.3 && fit.scale < s_true * 1.3,
            "true {s_true}, fitted {}",
            fit.scale
        );
        assert!(fit.log_likelihood >= fit.profile.iter().map(|p| p.1).fold(f64::MIN, f64::max));
    }
}

/// The tracker's default is the fit on the bundled `0313` labels (rounded to two digits).
#[test]
fn tracker_default_is_the_fit_on_the_bundled_labels() {
    let t = tables();
    let root = stjpdacf_tools::repo_root();
    let labels = read_labels(&root.join("data/tusimple/train_subset.json")).unwrap();
    let lanes = rownoise::label_lanes(&labels, &Camera::tusimple(), &t);
    assert!(lanes.len() > 100, "{} lanes", lanes.len());
    let fit = rownoise::fit(&RowModel::from_tables(&t), &lanes).unwrap();
    let default = f64::from(PersistConfig::DEFAULT.row_noise_scale);
    assert!(
        (fit.scale - default).abs() <= 0.01 * fit.scale.max(default) + 5e-4,
        "fit {}, default {default}",
        fit.scale
    );
    // The tables' own noise (s = 1) is far less likely.
    assert!(fit.log_likelihood - fit.log_likelihood_unscaled > 100.0);
}

/// `stjpdacf row-noise <args>` run from a folder outside the checkout (its defaults, the
/// bundled labels and hyperparameters, are found from any working folder).
fn row_noise(args: &[&std::ffi::OsStr]) -> std::process::Output {
    stjpdacf()
        .current_dir(std::env::temp_dir())
        .arg("row-noise")
        .args(args)
        .output()
        .unwrap()
}

/// The command fits the bundled labels by default, prints the scale and writes the JSON; a
/// label file with no usable lane is refused.
#[test]
fn row_noise_command_fits_and_refuses_empty_labels() {
    let dir = std::env::temp_dir().join(format!("stjpdacf-rownoise-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("fit.json");
    let out = row_noise(&["--json".as_ref(), json.as_os_str()]);
    assert_success(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("row_noise_scale = 0.04"));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let s = v["scale"].as_f64().unwrap();
    assert!(
        (s - f64::from(PersistConfig::DEFAULT.row_noise_scale)).abs() < 1e-3,
        "{s}"
    );
    assert_eq!(v["profile"].as_array().unwrap().len(), 21);
    // The bundled labels fit TuSimple's camera; the 512×288 frames' labels do not (most of
    // their points lie above its horizon), which the user is told.
    assert!(!String::from_utf8_lossy(&out.stderr).contains("warning"));
    let small = stjpdacf_tools::repo_root().join("data/tusimple/sample_512x288/label_data.json");
    let out = row_noise(&["--labels".as_ref(), small.as_os_str()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("972 of the 1195 label points lie outside the 1280x720 image"),
        "{err}"
    );
    let empty = dir.join("empty.json");
    std::fs::write(
        &empty,
        r#"{"raw_file": "a.jpg", "h_samples": [300, 310], "lanes": [[-2, -2]]}"#.to_string() + "\n",
    )
    .unwrap();
    let out = row_noise(&["--labels".as_ref(), empty.as_os_str()]);
    assert_failure_mentions(&out, "no lanes");
    std::fs::remove_dir_all(&dir).ok();
}

/// A label whose lane has fewer values than `h_samples` rows is refused by `row-noise` (and
/// `train`, the same reader) as by `eval` and `synth` (the CLI audit: it was fitted silently,
/// each lane's values paired with the first rows).
#[test]
fn row_noise_and_train_refuse_labels_of_the_wrong_shape() {
    let dir = std::env::temp_dir().join(format!("stjpdacf-rownoise-shape-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let short = dir.join("short.json");
    std::fs::write(
        &short,
        r#"{"raw_file": "a.jpg", "h_samples": [300, 310, 320], "lanes": [[600, 610]]}"#.to_string()
            + "\n",
    )
    .unwrap();
    assert!(read_labels(&short).is_err());
    let out = row_noise(&["--labels".as_ref(), short.as_os_str()]);
    assert_failure_mentions(&out, "short.json:1: bad TuSimple label");
    let out = stjpdacf()
        .current_dir(stjpdacf_tools::repo_root())
        .args(["train", "--restarts", "1", "--labels"])
        .arg(&short)
        .arg("--out")
        .arg(dir.join("h.json"))
        .output()
        .unwrap();
    assert_failure_mentions(&out, "lane 0 has 2 values but h_samples has 3 rows");
    std::fs::remove_dir_all(&dir).ok();
}
