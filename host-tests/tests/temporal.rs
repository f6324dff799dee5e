//! Tests of the f64 temporal coupled filter and fixed-lag RTS smoother
//! (`stjpdacf_reference::temporal`) against `data/golden/rts.json` (filterpy / numpy dense
//! reference values), plus unit tests of the coupled model builder.
//!
//! Tolerance rule for every golden comparison: for each compared vector or matrix,
//! `max |got − expected| ≤ 1e-10 · max(1, max |expected|)` — relative to the largest entry of the
//! expected matrix, and absolute 1e-10 when all its entries are below 1 in magnitude (so tiny
//! entries and exact zeros are held to 1e-10 absolute).

use std::path::PathBuf;

use nalgebra::{DMatrix, DVector};
use serde_json::Value;
use stjpdacf_reference::statespace::Matern32;
use stjpdacf_reference::temporal::{
    fixed_lag_smooth, predict, rts_gain, rts_smooth, run_filter, update, CoupledTemporalModel,
    FilterStep, FixedLagSmoother, Gaussian, LaneMeasurement, LinearGaussianModel,
};

const TOL: f64 = 1e-10;

// ---------------------------------------------------------------- JSON helpers

fn golden_path(name: &str) -> PathBuf {
    stjpdacf_tools::repo_root()
        .join("data")
        .join("golden")
        .join(name)
}

fn load_golden(name: &str) -> Value {
    let path = golden_path(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("bad JSON in {}: {e}", path.display()))
}

fn num(v: &Value) -> f64 {
    v.as_f64()
        .unwrap_or_else(|| panic!("expected a number, got {v}"))
}

fn arr(v: &Value) -> &Vec<Value> {
    v.as_array()
        .unwrap_or_else(|| panic!("expected an array, got {v}"))
}

/// A row-major nested list as a matrix.
fn mat(v: &Value) -> DMatrix<f64> {
    let rows = arr(v);
    let nr = rows.len();
    let nc = if nr == 0 { 0 } else { arr(&rows[0]).len() };
    let flat: Vec<f64> = rows
        .iter()
        .flat_map(|r| {
            let r = arr(r);
            assert_eq!(r.len(), nc, "ragged matrix");
            r.iter().map(num)
        })
        .collect();
    DMatrix::from_row_slice(nr, nc, &flat)
}

fn vector(v: &Value) -> DVector<f64> {
    DVector::from_iterator(arr(v).len(), arr(v).iter().map(num))
}

/// Measurements with `null` for missing components.
fn measurements(v: &Value) -> Vec<Vec<Option<f64>>> {
    arr(v)
        .iter()
        .map(|zk| arr(zk).iter().map(Value::as_f64).collect())
        .collect()
}

// ---------------------------------------------------------------- comparison helpers

/// Max abs error of `got` against `expected`, asserting the tolerance rule of this file.
fn check(what: &str, got: &DMatrix<f64>, expected: &DMatrix<f64>) -> f64 {
    assert_eq!(got.shape(), expected.shape(), "{what}: shape");
    let err = (got - expected).amax();
    let scale = expected.amax().max(1.0);
    assert!(
        err <= TOL * scale,
        "{what}: max abs error {err:e} > {TOL:e} · {scale}\n got {got}\n expected {expected}"
    );
    err
}

fn check_vec(what: &str, got: &DVector<f64>, expected: &DVector<f64>) -> f64 {
    check(
        what,
        &DMatrix::from_column_slice(got.len(), 1, got.as_slice()),
        &DMatrix::from_column_slice(expected.len(), 1, expected.as_slice()),
    )
}

/// Running maxima of the errors per quantity, printed at the end of a golden test.
#[derive(Default)]
struct MaxErr(Vec<(String, f64)>);

impl MaxErr {
    fn add(&mut self, key: &str, e: f64) {
        match self.0.iter_mut().find(|(k, _)| k == key) {
            Some((_, m)) => *m = m.max(e),
            None => self.0.push((key.to_string(), e)),
        }
    }
    /// Checks `got`'s mean and covariance against `mean` and `cov` (messages `{key} mean {k}`,
    /// `{key} cov {k}`) and records the errors under `{key} mean` and `{key} cov`.
    fn gaussian(&mut self, key: &str, k: usize, got: &Gaussian, mean: &Value, cov: &Value) {
        let e = check_vec(&format!("{key} mean {k}"), &got.mean, &vector(mean));
        self.add(&format!("{key} mean"), e);
        let e = check(&format!("{key} cov {k}"), &got.cov, &mat(cov));
        self.add(&format!("{key} cov"), e);
    }
    fn print(&self, model: &str) {
        for (k, e) in &self.0 {
            eprintln!("golden rts.json [{model}] {k}: max abs error {e:.3e}");
        }
    }
}

fn golden_model<'a>(g: &'a Value, name: &str) -> &'a Value {
    arr(&g["models"])
        .iter()
        .find(|m| m["name"] == name)
        .unwrap_or_else(|| panic!("model {name} not in rts.json"))
}

fn model_inputs(m: &Value) -> (LinearGaussianModel, Gaussian, Vec<Vec<Option<f64>>>) {
    let i = &m["inputs"];
    let model = LinearGaussianModel {
        f: mat(&i["F"]),
        q: mat(&i["Q"]),
        h: mat(&i["H"]),
        r: mat(&i["R"]),
    };
    let prior = Gaussian::new(vector(&i["x0_prior_mean"]), mat(&i["P0"])).expect("prior");
    let z = measurements(&i["z"]);
    assert_eq!(z.len() as f64, num(&i["n"]));
    (model, prior, z)
}

/// The coupled model of the golden `stacked_coupled` parameters `p` (N = 1, `K_u = [1]`).
fn stacked_model(p: &Value) -> CoupledTemporalModel {
    CoupledTemporalModel::new(
        Matern32 {
            variance: num(&p["sigma2"]),
            lengthscale: num(&p["lengthscale"]),
        },
        DMatrix::from_element(1, 1, 1.0),
        mat(&p["B"]),
        num(&p["R"]),
    )
    .expect("model")
}

// ---------------------------------------------------------------- golden tests

fn golden_check_model(name: &str) {
    let g = load_golden("rts.json");
    let m = golden_model(&g, name);
    let (model, prior, z) = model_inputs(m);
    let n = z.len();
    let mut errs = MaxErr::default();

    let steps = run_filter(&model, &prior, &z).expect("filter");
    assert_eq!(steps.len(), n);
    for (k, s) in steps.iter().enumerate() {
        let (pm, pc) = (&m["predicted_mean"][k], &m["predicted_cov"][k]);
        errs.gaussian("predicted", k, &s.predicted, pm, pc);
        let (fm, fc) = (&m["filtered_mean"][k], &m["filtered_cov"][k]);
        errs.gaussian("filtered", k, &s.filtered, fm, fc);
    }

    let rts = rts_smooth(&steps).expect("rts");
    assert_eq!(rts.smoothed.len(), n);
    assert_eq!(rts.gains.len(), n);
    for k in 0..n {
        let (rm, rc) = (&m["rts_mean"][k], &m["rts_cov"][k]);
        errs.gaussian("rts", k, &rts.smoothed[k], rm, rc);
        let e = check(
            &format!("rts gain {k}"),
            &rts.gains[k],
            &mat(&m["rts_gain"][k]),
        );
        errs.add("rts gain", e);
        if let Some(fm) = m.get("filterpy_rts_mean") {
            let fc = &m["filterpy_rts_cov"][k];
            errs.gaussian("filterpy rts", k, &rts.smoothed[k], &fm[k], fc);
        }
    }

    let lags: Vec<usize> = arr(&m["inputs"]["lags"])
        .iter()
        .map(|l| l.as_u64().expect("lag") as usize)
        .collect();
    assert_eq!(lags, vec![1, 3, 5]);
    for lag in lags {
        let expected = arr(&m["fixed_lag"][lag.to_string()]);
        let got = fixed_lag_smooth(&steps, lag).expect("fixed lag");
        assert_eq!(got.len(), expected.len(), "L = {lag}: number of outputs");
        assert_eq!(got.len(), n - lag);
        for (o, e) in got.iter().zip(expected) {
            assert_eq!(o.k as f64, num(&e["k"]), "L = {lag}: k");
            assert_eq!(o.target_step as f64, num(&e["target_step"]), "L = {lag}");
            assert_eq!(o.target_step, o.k - lag);
            let err = check_vec(
                &format!("fixed-lag L={lag} mean k={}", o.k),
                &o.estimate.mean,
                &vector(&e["mean"]),
            );
            errs.add(&format!("fixed-lag L={lag} mean"), err);
            let err = check(
                &format!("fixed-lag L={lag} cov k={}", o.k),
                &o.estimate.cov,
                &mat(&e["cov"]),
            );
            errs.add(&format!("fixed-lag L={lag} cov"), err);
        }
    }
    errs.print(name);
}

#[test]
fn golden_matern32_filter_rts_fixed_lag() {
    golden_check_model("matern32");
}

#[test]
fn golden_stacked_coupled_filter_rts_fixed_lag() {
    golden_check_model("stacked_coupled");
}

/// The golden inputs are reproduced by the Matérn-3/2 model and by the coupled builder with N = 1
/// (K_u = [1]) and the golden B.
#[test]
fn golden_inputs_match_model_builder() {
    let g = load_golden("rts.json");

    let m = golden_model(&g, "matern32");
    let p = &m["model_params"];
    let mat32 = Matern32 {
        variance: num(&p["sigma2"]),
        lengthscale: num(&p["lengthscale"]),
    };
    let ts = num(&p["Ts"]);
    let (f, q) = mat32.transition(ts);
    check("matern32 F", &f, &mat(&m["inputs"]["F"]));
    check("matern32 Q", &q, &mat(&m["inputs"]["Q"]));
    check(
        "matern32 P0",
        &mat32.p_inf_closed(),
        &mat(&m["inputs"]["P0"]),
    );
    check("matern32 H", &mat32.h(), &mat(&m["inputs"]["H"]));

    let m = golden_model(&g, "stacked_coupled");
    let p = &m["model_params"];
    let d = num(&p["D"]) as usize;
    let model = stacked_model(p);
    let ts = num(&p["Ts"]);
    check(
        "stacked F",
        &model.transition(d, ts).unwrap(),
        &mat(&m["inputs"]["F"]),
    );
    check(
        "stacked Q",
        &model.process_noise(d, ts).unwrap(),
        &mat(&m["inputs"]["Q"]),
    );
    check(
        "stacked P0",
        &model.initial_cov(d).unwrap(),
        &mat(&m["inputs"]["P0"]),
    );
    check(
        "stacked H",
        &model.measurement_matrix(d).unwrap(),
        &mat(&m["inputs"]["H"]),
    );
}

/// Running the golden stacked data through `CoupledTemporalModel::step` (lane-wise measurements,
/// zero pseudo-measurement covariance plus r₀² = R) reproduces the golden filtered moments.
#[test]
fn golden_stacked_through_coupled_step() {
    let g = load_golden("rts.json");
    let m = golden_model(&g, "stacked_coupled");
    let p = &m["model_params"];
    let model = stacked_model(p);
    let ts = num(&p["Ts"]);
    let z = measurements(&m["inputs"]["z"]);
    let mut state = model
        .prior(3, vector(&m["inputs"]["x0_prior_mean"]))
        .expect("prior");
    let mut max_err: f64 = 0.0;
    for (k, zk) in z.iter().enumerate() {
        let obs: Vec<Option<LaneMeasurement>> = zk
            .iter()
            .map(|v| {
                v.map(|x| LaneMeasurement {
                    z: vec![Some(x)],
                    cov: DMatrix::zeros(1, 1),
                })
            })
            .collect();
        let t = if k == 0 { None } else { Some(ts) };
        let s = model.step(&state, t, &obs).expect("step");
        max_err = max_err.max(check_vec(
            &format!("coupled step mean {k}"),
            &s.filtered.mean,
            &vector(&m["filtered_mean"][k]),
        ));
        max_err = max_err.max(check(
            &format!("coupled step cov {k}"),
            &s.filtered.cov,
            &mat(&m["filtered_cov"][k]),
        ));
        state = s.filtered;
    }
    eprintln!("golden rts.json [stacked_coupled] via CoupledTemporalModel::step: max abs error {max_err:.3e}");
}

// ---------------------------------------------------------------- unit tests

fn test_b3() -> DMatrix<f64> {
    DMatrix::from_row_slice(3, 3, &[2.0, 0.7, 0.3, 0.7, 1.5, 0.6, 0.3, 0.6, 1.2])
}

fn test_k2() -> DMatrix<f64> {
    DMatrix::from_row_slice(2, 2, &[1.0, 0.8, 0.8, 1.0])
}

fn test_kernel() -> Matern32 {
    Matern32 {
        variance: 1.0,
        lengthscale: 3.0,
    }
}

/// Q̄ for D = 3, N = 2 equals (B ⊗ K_u) ⊗ Q_t written out element by element in the documented
/// ordering (lane, point, component), without nalgebra's Kronecker product.
#[test]
fn process_noise_is_explicit_kronecker_d3_n2() {
    let b = test_b3();
    let k = test_k2();
    let kern = test_kernel();
    let model = CoupledTemporalModel::new(kern, k.clone(), b.clone(), 0.01).unwrap();
    let t = 0.05;
    let (_, qt) = kern.transition(t);
    let qbar = model.process_noise(3, t).unwrap();
    assert_eq!(qbar.shape(), (12, 12));
    let mut explicit = DMatrix::<f64>::zeros(12, 12);
    for d in 0..3 {
        for i in 0..2 {
            for a in 0..2 {
                for e in 0..3 {
                    for j in 0..2 {
                        for c in 0..2 {
                            let row = d * 4 + i * 2 + a;
                            let col = e * 4 + j * 2 + c;
                            explicit[(row, col)] = b[(d, e)] * k[(i, j)] * qt[(a, c)];
                        }
                    }
                }
            }
        }
    }
    assert!((&qbar - &explicit).amax() <= 1e-15 * explicit.amax());
    // Spot checks against hand-picked entries and the index helper.
    let r = model.state_index(2, 1, 1);
    let c = model.state_index(0, 0, 0);
    assert_eq!((r, c), (11, 0));
    assert_eq!(qbar[(r, c)], b[(2, 0)] * k[(1, 0)] * qt[(1, 0)]);
    assert_eq!(qbar[(5, 2)], b[(1, 0)] * k[(0, 1)] * qt[(1, 0)]);
    // A D = 2 model uses the leading 2×2 block of B.
    let q2 = model.process_noise(2, t).unwrap();
    assert_eq!(q2, explicit.view((0, 0), (8, 8)).clone_owned());
    // F̄ is block-diagonal with F_t(T) blocks; P̄₀ uses P∞_t.
    let (ft, _) = kern.transition(t);
    let fbar = model.transition(3, t).unwrap();
    let p0 = model.initial_cov(3).unwrap();
    let pinf = kern.p_inf_closed();
    for blk in 0..6 {
        for other in 0..6 {
            let fb = fbar.view((2 * blk, 2 * other), (2, 2)).clone_owned();
            if blk == other {
                assert_eq!(fb, ft);
            } else {
                assert_eq!(fb, DMatrix::zeros(2, 2));
            }
            let (d, i, e, j) = (blk / 2, blk % 2, other / 2, other % 2);
            let pb = p0.view((2 * blk, 2 * other), (2, 2)).clone_owned();
            assert!((pb - &pinf * (b[(d, e)] * k[(i, j)])).amax() <= 1e-15);
        }
    }
    assert!(model.process_noise(4, t).is_err(), "only 3 lane slots");
}

fn lane_block(m: &DMatrix<f64>, n: usize, d: usize, e: usize) -> DMatrix<f64> {
    m.view((2 * n * d, 2 * n * e), (2 * n, 2 * n)).clone_owned()
}

/// With B = I and no measurement the lanes stay independent: cross-lane covariance blocks stay
/// exactly zero and each lane's moments equal a single-lane run. With a coupled B they do not.
#[test]
fn identity_coreg_keeps_lanes_independent() {
    let kern = test_kernel();
    let k = test_k2();
    let n = 2;
    let dims = 3;
    let model = CoupledTemporalModel::new(kern, k.clone(), DMatrix::identity(3, 3), 0.01).unwrap();
    let single = CoupledTemporalModel::new(kern, k.clone(), DMatrix::identity(1, 1), 0.01).unwrap();
    let mean = DVector::from_fn(12, |i, _| (i as f64 * 0.37).sin());
    let mut state = model.prior(dims, mean.clone()).unwrap();
    let mut singles: Vec<Gaussian> = (0..dims)
        .map(|d| {
            single
                .prior(1, mean.rows(2 * n * d, 2 * n).clone_owned())
                .unwrap()
        })
        .collect();
    let none: Vec<Option<LaneMeasurement>> = vec![None; dims];
    for (k_step, t) in [0.05, 0.05, 0.15, 0.05].into_iter().enumerate() {
        let s = model.step(&state, Some(t), &none).unwrap();
        assert_eq!(s.filtered, s.predicted, "no measurement: update is a no-op");
        state = s.filtered;
        for (d, sd) in singles.iter_mut().enumerate() {
            *sd = single.step(sd, Some(t), &[None]).unwrap().filtered;
            let blk = lane_block(&state.cov, n, d, d);
            assert!((&blk - &sd.cov).amax() <= 1e-14, "step {k_step} lane {d}");
            let mu = state.mean.rows(2 * n * d, 2 * n).clone_owned();
            assert!((&mu - &sd.mean).amax() <= 1e-14);
            for e in 0..dims {
                if e != d {
                    assert_eq!(
                        lane_block(&state.cov, n, d, e),
                        DMatrix::zeros(2 * n, 2 * n),
                        "cross-lane block ({d},{e}) at step {k_step}"
                    );
                }
            }
        }
    }

    // Measuring lane 1 only: with B = I lanes 0 and 2 are untouched; with a coupled B they move.
    let obs = vec![
        None,
        Some(LaneMeasurement {
            z: vec![Some(1.0), Some(1.2)],
            cov: DMatrix::from_row_slice(2, 2, &[0.02, 0.01, 0.01, 0.02]),
        }),
        None,
    ];
    let s = model.step(&state, Some(0.05), &obs).unwrap();
    for d in [0, 2] {
        let a = s.filtered.mean.rows(2 * n * d, 2 * n).clone_owned();
        let b = s.predicted.mean.rows(2 * n * d, 2 * n).clone_owned();
        assert_eq!(a, b);
        assert_eq!(
            lane_block(&s.filtered.cov, n, d, d),
            lane_block(&s.predicted.cov, n, d, d)
        );
    }
    assert!((s.filtered.mean.rows(4, 4) - s.predicted.mean.rows(4, 4)).amax() > 1e-3);

    let coupled = CoupledTemporalModel::new(kern, k, test_b3(), 0.01).unwrap();
    let prior = coupled.prior(3, DVector::zeros(12)).unwrap();
    let s = coupled.step(&prior, None, &obs).unwrap();
    assert!(
        s.filtered.mean.rows(0, 4).amax() > 1e-2,
        "coupled B: lane 0 must move"
    );
    assert!(lane_block(&s.filtered.cov, n, 0, 2).amax() > 1e-3);
}

/// Unseen lanes and missing index points are dropped from H̄, R and z: the coupled step equals an
/// update with the reduced matrices written out by hand.
#[test]
fn partial_lanes_and_points_match_reduced_update() {
    let kern = test_kernel();
    let k = test_k2();
    let r0 = 0.04;
    let model = CoupledTemporalModel::new(kern, k, test_b3(), r0).unwrap();
    let prior = model
        .prior(3, DVector::from_fn(12, |i, _| 0.1 * i as f64))
        .unwrap();
    let c0 = DMatrix::from_row_slice(2, 2, &[0.05, 0.02, 0.02, 0.06]);
    let c2 = DMatrix::from_row_slice(2, 2, &[0.03, 0.01, 0.01, 0.07]);
    let obs = vec![
        Some(LaneMeasurement {
            z: vec![Some(0.5), Some(-0.2)],
            cov: c0.clone(),
        }),
        None,
        Some(LaneMeasurement {
            z: vec![None, Some(2.0)],
            cov: c2.clone(),
        }),
    ];
    let s = model.step(&prior, Some(0.1), &obs).unwrap();

    // Observed: lane 0 points 0 and 1, lane 2 point 1 → state entries 0, 2, 10.
    let mut h = DMatrix::<f64>::zeros(3, 12);
    h[(0, 0)] = 1.0;
    h[(1, 2)] = 1.0;
    h[(2, 10)] = 1.0;
    let r = DMatrix::from_row_slice(
        3,
        3,
        &[
            c0[(0, 0)] + r0,
            c0[(0, 1)],
            0.0,
            c0[(1, 0)],
            c0[(1, 1)] + r0,
            0.0,
            0.0,
            0.0,
            c2[(1, 1)] + r0,
        ],
    );
    let z = [Some(0.5), Some(-0.2), Some(2.0)];
    let f = model.transition(3, 0.1).unwrap();
    let q = model.process_noise(3, 0.1).unwrap();
    let pred = predict(&prior, &f, &q).unwrap();
    let manual = update(&pred, &h, &r, &z).unwrap();
    assert!((&s.predicted.mean - &pred.mean).amax() <= 1e-14);
    assert!((&s.filtered.mean - &manual.mean).amax() <= 1e-13);
    assert!((&s.filtered.cov - &manual.cov).amax() <= 1e-13);

    // The partial update equals the textbook full-form update on the observed components.
    let s_mat = &h * &pred.cov * h.transpose() + &r;
    let gain = &pred.cov * h.transpose() * s_mat.clone().try_inverse().unwrap();
    let zv = DVector::from_vec(vec![0.5, -0.2, 2.0]);
    let mean = &pred.mean + &gain * (zv - &h * &pred.mean);
    let cov = &pred.cov - &gain * &s_mat * gain.transpose();
    assert!((&s.filtered.mean - mean).amax() <= 1e-12);
    assert!((&s.filtered.cov - cov).amax() <= 1e-12);
}

/// A dropped frame (T = 2 T₀) predicts exactly like two steps of T₀ without measurements.
#[test]
fn dropped_frame_equals_two_predicts() {
    let model = CoupledTemporalModel::new(test_kernel(), test_k2(), test_b3(), 0.01).unwrap();
    let prior = model
        .prior(3, DVector::from_fn(12, |i, _| (i as f64).cos()))
        .unwrap();
    let none: Vec<Option<LaneMeasurement>> = vec![None; 3];
    let once = model.step(&prior, Some(0.1), &none).unwrap().filtered;
    let a = model.step(&prior, Some(0.05), &none).unwrap().filtered;
    let twice = model.step(&a, Some(0.05), &none).unwrap().filtered;
    assert!((&once.mean - &twice.mean).amax() <= 1e-13);
    assert!((&once.cov - &twice.cov).amax() <= 1e-13);
    assert!(model.transition(3, 0.0).is_err());
    assert!(model.transition(3, -0.1).is_err());
}

/// Fixed-lag with L ≥ n − 1: at the last step its window holds the whole run, and its smoothed
/// window equals the fixed-interval RTS; with L = n − 1 the single lagged output is x_{0|n−1}.
#[test]
fn fixed_lag_with_long_lag_equals_rts_at_last_step() {
    let g = load_golden("rts.json");
    for name in ["matern32", "stacked_coupled"] {
        let (model, prior, z) = model_inputs(golden_model(&g, name));
        let steps = run_filter(&model, &prior, &z).unwrap();
        let n = steps.len();
        let rts = rts_smooth(&steps).unwrap();
        for lag in [n - 1, n, n + 3] {
            let mut sm = FixedLagSmoother::new(lag);
            let mut outputs = Vec::new();
            for s in &steps {
                if let Some(o) = sm.push(s.clone()).unwrap() {
                    outputs.push(o);
                }
            }
            let window = sm.window_smoothed();
            assert_eq!(
                window.len(),
                n,
                "{name} L={lag}: window holds the whole run"
            );
            for (j, est) in &window {
                check_vec(
                    &format!("{name} L={lag} mean {j}"),
                    &est.mean,
                    &rts.smoothed[*j].mean,
                );
                check(
                    &format!("{name} L={lag} cov {j}"),
                    &est.cov,
                    &rts.smoothed[*j].cov,
                );
            }
            if lag == n - 1 {
                assert_eq!(outputs.len(), 1);
                assert_eq!((outputs[0].k, outputs[0].target_step), (n - 1, 0));
                check_vec(
                    "x_{0|n-1}",
                    &outputs[0].estimate.mean,
                    &rts.smoothed[0].mean,
                );
            } else {
                assert!(outputs.is_empty());
            }
        }
    }
}

/// The sliding window really is bounded and the lag-0 smoother publishes the filtered estimate.
#[test]
fn fixed_lag_window_is_bounded_and_lag0_is_filter() {
    let g = load_golden("rts.json");
    let (model, prior, z) = model_inputs(golden_model(&g, "matern32"));
    let steps = run_filter(&model, &prior, &z).unwrap();
    let mut sm = FixedLagSmoother::new(3);
    for (k, s) in steps.iter().enumerate() {
        sm.push(s.clone()).unwrap();
        let w = sm.window_smoothed();
        assert_eq!(w.len(), (k + 1).min(4));
        assert_eq!(w.last().unwrap().0, k);
        assert_eq!(w.last().unwrap().1, s.filtered);
    }
    let lag0 = fixed_lag_smooth(&steps, 0).unwrap();
    assert_eq!(lag0.len(), steps.len());
    for (o, s) in lag0.iter().zip(&steps) {
        assert_eq!(o.estimate, s.filtered);
    }
    // A step without a transition after the first is rejected.
    let mut sm = FixedLagSmoother::new(2);
    sm.push(steps[0].clone()).unwrap();
    let bad = FilterStep {
        transition: None,
        ..steps[1].clone()
    };
    assert!(sm.push(bad).is_err());
}

/// At the reference configuration the RBF Gram matrix K_u is numerically singular, so P̄₀ and
/// P_{k+1|k} are only semi-definite and the RTS gain cannot use Cholesky. The smoother must still
/// give positive semi-definite smoothed covariances no larger than the filtered ones:
/// min eig(P_{k|N}) ≥ −1e-12·max|P_{k|N}| and min eig(P_{k|k} − P_{k|N}) ≥ −1e-12·max|P_{k|k}|.
#[test]
fn rts_with_singular_gram_stays_psd() {
    let path = stjpdacf_tools::repo_root().join(stjpdacf_tools::tablegen::DEFAULT_HYPER);
    let hyper = stjpdacf_reference::hyper::HyperFile::load(&path).unwrap();
    let tables = stjpdacf_tools::tablegen::ModelTables::from_hyper(&hyper).unwrap();
    let model = CoupledTemporalModel::from_tables(&tables).unwrap();
    let lanes = 4;
    let n = model.points();
    let mut state = model.prior(lanes, DVector::zeros(2 * lanes * n)).unwrap();
    assert!(
        state.cov.clone().cholesky().is_none(),
        "premise: P̄₀ is numerically singular at the reference configuration"
    );
    let mut steps = Vec::new();
    for k in 0..5 {
        let obs: Vec<Option<LaneMeasurement>> = (0..lanes)
            .map(|d| {
                (d != 2 && !(k == 1 && d == 3)).then(|| LaneMeasurement {
                    z: (0..n)
                        .map(|i| Some(3.7 * d as f64 + 0.01 * (i * k) as f64))
                        .collect(),
                    cov: DMatrix::identity(n, n) * 0.01,
                })
            })
            .collect();
        let t = (k > 0).then_some(hyper.temporal.frame_step);
        let s = model.step(&state, t, &obs).unwrap();
        state = s.filtered.clone();
        steps.push(s);
    }
    let rts = rts_smooth(&steps).unwrap();
    for (k, (s, sm)) in steps.iter().zip(&rts.smoothed).enumerate() {
        let min_sm = sm.cov.clone().symmetric_eigen().eigenvalues.min();
        assert!(
            min_sm >= -1e-12 * sm.cov.amax(),
            "step {k}: smoothed covariance has eigenvalue {min_sm:e}"
        );
        let shrink = (&s.filtered.cov - &sm.cov)
            .symmetric_eigen()
            .eigenvalues
            .min();
        assert!(
            shrink >= -1e-12 * s.filtered.cov.amax(),
            "step {k}: P_k|k - P_k|N has eigenvalue {shrink:e}"
        );
        assert!(sm.mean.iter().all(|v| v.is_finite()));
    }
}

/// With a rank-deficient P_{k+1|k} the gain is the minimum-norm solution of
/// P_{k+1|k} Gᵀ = F P_{k|k}: it solves the equation, is finite and bounded, and equals
/// P_{k|k} Fᵀ (P_{k+1|k})⁺ computed from an explicit eigen-decomposition.
#[test]
fn rts_gain_with_rank_deficient_prediction() {
    // P = V Vᵀ of rank 2 in 4 dimensions, F invertible, Q = 0.
    let v = DMatrix::from_row_slice(4, 2, &[1.0, 0.2, 0.5, -0.3, -0.4, 1.0, 0.3, 0.7]);
    let p = &v * v.transpose();
    let f = DMatrix::from_row_slice(
        4,
        4,
        &[
            0.9, 0.1, 0.0, 0.0, -0.1, 0.8, 0.05, 0.0, 0.0, 0.0, 1.0, 0.2, 0.0, 0.1, 0.0, 0.7,
        ],
    );
    let pp = &f * &p * f.transpose();
    let g = rts_gain(&p, &f, &pp).unwrap();
    assert!(g.iter().all(|x| x.is_finite()));
    let residual = (&pp * g.transpose() - &f * &p).amax();
    assert!(residual <= 1e-12, "residual {residual:e}");
    // Pseudo-inverse from the eigen-decomposition of the symmetric P_{k+1|k}.
    let eig = pp.clone().symmetric_eigen();
    let cut = 1e-10 * eig.eigenvalues.amax();
    let inv = eig.eigenvalues.map(|l| if l > cut { 1.0 / l } else { 0.0 });
    let pinv = &eig.eigenvectors * DMatrix::from_diagonal(&inv) * eig.eigenvectors.transpose();
    let expected = &p * f.transpose() * pinv;
    let err = (&g - &expected).amax();
    assert!(
        err <= 1e-10 * expected.amax().max(1.0),
        "gain error {err:e}"
    );
}
