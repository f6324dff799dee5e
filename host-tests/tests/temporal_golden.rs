//! The core's temporal filter and fixed-lag smoother (`stjpdacf::temporal::smoother::Temporal`) on
//! the golden Kalman / fixed-lag values of `data/golden/rts.json` (filterpy-checked), in f32: the
//! Matérn-3/2 model (one lane) and the coupled D = 3 model (Q̄ = B ⊗ Q), with one index point
//! (`K_u = [1]`, rank 1) so that the core's state is exactly the golden state.
//!
//! Tolerances (f32): means within 2e-5·(1 + |x|), covariances within 2e-5 × the matrix's largest
//! entry; the f64 reference reproduces the same values to 1e-10 (`tests/temporal.rs`).

use nalgebra::{SMatrix, SVector};
use serde_json::Value;
use stjpdacf::kernel::Matern32;
use stjpdacf::spatial::filter::{LaneObservation, Status};
use stjpdacf::tables::{Tables, TemporalTables, DEFAULT};
use stjpdacf::temporal::smoother::Temporal;
use stjpdacf_tools::repo_root;

fn golden() -> Value {
    serde_json::from_str(
        &std::fs::read_to_string(repo_root().join("data/golden/rts.json")).unwrap(),
    )
    .unwrap()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// Tables with one index point and the golden temporal model and B (leaked: the core wants
/// `'static` tables, as in flash).
fn tables<const D: usize>(m: &Value) -> &'static Tables<2, D, 1> {
    let p = &m["model_params"];
    let (s2, l, r) = (f(&p["sigma2"]), f(&p["lengthscale"]), f(&p["R"]));
    let b: SMatrix<f32, D, D> = if D == 1 {
        SMatrix::identity()
    } else {
        SMatrix::from_fn(|i, j| f(&p["B"][i][j]) as f32)
    };
    let chol = b.cholesky().unwrap().l();
    let kernel = Matern32::new(s2 as f32, l as f32);
    let mut hyper = DEFAULT.hyper;
    hyper.temporal_variance = s2 as f32;
    hyper.temporal_lengthscale = l as f32;
    hyper.pseudo_noise = r as f32;
    hyper.frame_step = f(&p["Ts"]) as f32;
    let (ft, qt) = kernel.transition(hyper.frame_step).unwrap();
    Box::leak(Box::new(Tables {
        version: DEFAULT.version,
        hyper,
        spatial: DEFAULT.spatial,
        temporal: TemporalTables {
            kernel,
            f: ft,
            q: qt,
            p_inf: kernel.p_inf(),
        },
        index_u: SVector::from([3.0]),
        gram: SMatrix::from([[1.0]]),
        gram_eigvec: SMatrix::from([[1.0]]),
        gram_eigval: SVector::from([1.0]),
        gram_rank: 1,
        coreg: b,
        coreg_chol: chol,
    }))
}

fn observation(z: Option<f64>) -> Option<LaneObservation<1>> {
    z.map(|z| LaneObservation {
        status: Status::Confirmed,
        present: [true],
        z: SVector::from([z as f32]),
        cov: SMatrix::zeros(),
        u_first: 3.0,
        u_last: 3.0,
        existence: 1.0,
        rank: 0,
        llr: 0.0,
    })
}

#[track_caller]
fn close(got: f32, want: f64, scale: f64, what: &str) {
    assert!(
        (got as f64 - want).abs() <= 2e-5 * scale,
        "{what}: {got} vs {want}"
    );
}

fn run<const D: usize, const NX: usize, const LAG: usize>(m: &Value) -> (f64, f64) {
    let t = tables::<D>(m);
    let inp = &m["inputs"];
    let ts = f(&m["model_params"]["Ts"]) as f32;
    let mut core = Box::new(Temporal::<D, 1, 1, NX, D, LAG>::new());
    let mut ranks = [0u8; D];
    for s in 0..D {
        ranks[s] = s as u8;
        core.start_lane(t, s, s as u8, &ranks).unwrap();
    }
    let zs = inp["z"].as_array().unwrap();
    let filt_mean = m["filtered_mean"].as_array().unwrap();
    let filt_cov = m["filtered_cov"].as_array().unwrap();
    let lagged: Vec<&Value> = m["fixed_lag"][LAG.to_string()]
        .as_array()
        .unwrap()
        .iter()
        .collect();
    let (mut max_m, mut max_c) = (0.0f64, 0.0f64);
    for (k, z) in zs.iter().enumerate() {
        if k > 0 {
            core.predict(t, ts).unwrap();
        }
        for s in 0..D {
            if let Some(obs) = observation(z[s].as_f64()) {
                core.update(t, s, &obs).unwrap();
            }
        }
        // Filtered state = the golden filtered moments.
        let x = core.filter().mean();
        let p = core.filter().covariance();
        let scale = filt_cov[k]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|r| r.as_array().unwrap().iter().map(|v| f(v).abs()))
            .fold(0.0, f64::max);
        for i in 0..2 * D {
            let w = f(&filt_mean[k][i]);
            close(x[i], w, 1.0 + w.abs(), &format!("k {k} filtered mean {i}"));
            max_m = max_m.max((x[i] as f64 - w).abs());
            for j in 0..2 * D {
                let w = f(&filt_cov[k][i][j]);
                close(p[(i, j)], w, scale, &format!("k {k} filtered cov {i},{j}"));
                max_c = max_c.max((p[(i, j)] as f64 - w).abs() / scale);
            }
        }
        // Fixed lag: x_{k−L|k} of each lane's position.
        if k >= LAG {
            let g = lagged
                .iter()
                .find(|e| e["k"].as_u64() == Some(k as u64))
                .unwrap();
            assert_eq!(g["target_step"].as_u64(), Some((k - LAG) as u64));
            for s in 0..D {
                let (mean, var) = core.lagged(t, s, LAG).unwrap();
                let (wm, wv) = (f(&g["mean"][2 * s]), f(&g["cov"][2 * s][2 * s]));
                close(
                    mean[0],
                    wm,
                    1.0 + wm.abs(),
                    &format!("k {k} lag {LAG} lane {s} mean"),
                );
                close(var[0], wv, wv, &format!("k {k} lag {LAG} lane {s} var"));
                max_m = max_m.max((mean[0] as f64 - wm).abs());
                max_c = max_c.max((var[0] as f64 - wv).abs() / wv);
            }
        } else {
            assert!(core.lagged(t, 0, LAG).is_none());
        }
    }
    (max_m, max_c)
}

/// Golden model `index` (named `name`) at L = 1, 3 and 5; prints the largest differences under
/// `label`.
fn check_lags<const D: usize, const NX: usize>(index: usize, name: &str, label: &str) {
    let g = golden();
    let m = &g["models"][index];
    assert_eq!(m["name"], name);
    for (lag, (dm, dc)) in [
        (1, run::<D, NX, 1>(m)),
        (3, run::<D, NX, 3>(m)),
        (5, run::<D, NX, 5>(m)),
    ] {
        println!("{label}, L = {lag}: max |Δmean| {dm:.2e}, max rel |Δcov| {dc:.2e}");
    }
}

#[test]
fn matern_model_filter_and_fixed_lag_match_golden() {
    check_lags::<1, 2>(0, "matern32", "matern32");
}

#[test]
fn coupled_model_filter_and_fixed_lag_match_golden() {
    check_lags::<3, 6>(1, "stacked_coupled", "coupled D = 3");
}
