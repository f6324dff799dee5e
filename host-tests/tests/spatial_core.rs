//! The f32 core's coupled row step (`stjpdacf::spatial::row`) against the golden JPDA / JPDACF
//! values of `data/golden/jpda_marginals.json` (the f64 reference reproduces them to 1e-12 in
//! `tests/jpda.rs`).
//!
//! Tolerances (f32): β within 2e-5 absolute; means within 1e-4 × (1 + |x|); covariances within
//! 1e-4 × the largest magnitude of the golden matrix.

use nalgebra::{SMatrix, SVector};
use serde_json::Value;
use stjpdacf::spatial::row::{self, MissModel, RowParams};
use stjpdacf::spatial::Stacked;
use stjpdacf_tools::repo_root;

const LANES: usize = 4;

fn golden() -> Value {
    let p = repo_root().join("data/golden/jpda_marginals.json");
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

fn vecf(v: &Value) -> Vec<f64> {
    serde_json::from_value(v.clone()).unwrap()
}

fn matf(v: &Value) -> Vec<Vec<f64>> {
    serde_json::from_value(v.clone()).unwrap()
}

/// The `2d × 2d` block-diagonal covariance of per-target 2×2 blocks (a JSON list).
fn block_diag(v: &Value, d: usize) -> Vec<Vec<f64>> {
    let ps: Vec<Vec<Vec<f64>>> = serde_json::from_value(v.clone()).unwrap();
    let mut p = vec![vec![0.0; 2 * d]; 2 * d];
    for (t, pt) in ps.iter().enumerate() {
        for a in 0..2 {
            for b in 0..2 {
                p[2 * t + a][2 * t + b] = pt[a][b];
            }
        }
    }
    p
}

/// Loads a stacked mean and covariance (nx = 2) into the core's block form.
fn stacked(x: &[f64], p: &[Vec<f64>], d: usize) -> Stacked<2, LANES> {
    let mut s = Stacked::<2, LANES>::new();
    let blk =
        |i: usize, j: usize| SMatrix::<f32, 2, 2>::from_fn(|a, b| p[2 * i + a][2 * j + b] as f32);
    for i in 0..d {
        s.push(
            SVector::from([x[2 * i] as f32, x[2 * i + 1] as f32]),
            &blk(i, i),
        )
        .unwrap();
    }
    for i in 0..d {
        for j in 0..d {
            if i != j {
                s.set_cross(i, j, &blk(i, j));
            }
        }
    }
    s
}

fn params(inp: &Value, miss: MissModel) -> RowParams {
    RowParams {
        pd: f(&inp["pd"]) as f32,
        pg: f(&inp["pg"]) as f32,
        gamma: f(&inp["gamma"]) as f32,
        clutter_density: f(&inp["clutter_density"]) as f32,
        r: f(&inp["R"][0][0]) as f32,
        miss,
    }
}

#[track_caller]
fn check(
    s: &Stacked<2, LANES>,
    out: &row::RowOutcome<LANES>,
    want: &Value,
    xkey: &str,
    pkey: &str,
    what: &str,
) {
    assert!(!out.failed, "{what}: failed");
    let beta = matf(&want["beta"]);
    for (t, bt) in beta.iter().enumerate() {
        assert!(
            (out.beta_miss[t] as f64 - bt[0]).abs() < 2e-5,
            "{what}: beta_miss[{t}] {} vs {}",
            out.beta_miss[t],
            bt[0]
        );
        for (j, b) in bt.iter().skip(1).enumerate() {
            assert!(
                (out.beta[t][j] as f64 - b).abs() < 2e-5,
                "{what}: beta[{t}][{j}] {} vs {b}",
                out.beta[t][j]
            );
        }
    }
    let d = beta.len();
    let (xw, pw): (Vec<f64>, Vec<Vec<f64>>) = if xkey.is_empty() {
        // Independent JPDA: per-target x_upd / P_upd.
        let xs = matf(&want["x_upd"]);
        (xs.concat(), block_diag(&want["P_upd"], d))
    } else {
        (vecf(&want[xkey]), matf(&want[pkey]))
    };
    let scale = pw.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for t in 0..d {
        let x = s.mean(t).unwrap();
        for a in 0..2 {
            let (g, w) = (x[a] as f64, xw[2 * t + a]);
            assert!(
                (g - w).abs() <= 1e-4 * (1.0 + w.abs()),
                "{what}: x[{t}][{a}] {g} vs {w}"
            );
        }
        for u in 0..d {
            // Independent JPDA updates each target alone: only its diagonal blocks are defined
            // (the exact mixture also has the cross-covariance that mutually exclusive
            // assignments create, which per-target JPDA drops).
            if xkey.is_empty() && t != u {
                continue;
            }
            let p = s.cov(t, u).unwrap();
            for a in 0..2 {
                for b in 0..2 {
                    let (g, w) = (p[(a, b)] as f64, pw[2 * t + a][2 * u + b]);
                    assert!(
                        (g - w).abs() <= 1e-4 * scale,
                        "{what}: P[{t},{u}][{a},{b}] {g} vs {w}"
                    );
                }
            }
        }
    }
}

#[test]
fn coupled_row_step_matches_golden_mixture() {
    let g = golden();
    let mut checked = 0;
    for sc in g["scenarios"].as_array().unwrap() {
        let inp = &sc["inputs"];
        let d = inp["D"].as_u64().unwrap() as usize;
        assert_eq!(inp["nx"].as_u64(), Some(2));
        let zs: Vec<f32> = vecf(&inp["zs"]).iter().map(|v| *v as f32).collect();
        let mut s = stacked(&vecf(&inp["xbar"]), &matf(&inp["Pbar"]), d);
        let h = SVector::from([1.0f32, 0.0]);
        let want = &sc["coupled_textbook"];
        let out = row::update(&mut s, &h, &zs, &params(inp, MissModel::Textbook), 100_000);
        assert_eq!(
            u64::from(out.events),
            want["n_events"].as_u64().unwrap(),
            "scenario {}",
            sc["id"]
        );
        assert!(!out.approximated);
        check(
            &s,
            &out,
            want,
            "x_mixture",
            "P_mixture",
            &format!("coupled scenario {}", sc["id"]),
        );
        checked += 1;
    }
    assert_eq!(checked, 22);
}

#[test]
fn independent_row_step_matches_golden_jpda_both_conventions() {
    let g = golden();
    for sc in g["scenarios"].as_array().unwrap() {
        let inp = &sc["inputs"];
        let d = inp["D"].as_u64().unwrap() as usize;
        let xs: Vec<Vec<f64>> = matf(&inp["x_pred"]);
        let p = block_diag(&inp["P_pred"], d);
        let zs: Vec<f32> = vecf(&inp["zs"]).iter().map(|v| *v as f32).collect();
        let h = SVector::from([1.0f32, 0.0]);
        for (key, miss) in [
            ("jpda_textbook", MissModel::Textbook),
            ("jpda_pg", MissModel::Gated),
        ] {
            let mut s = stacked(&xs.concat(), &p, d);
            let out = row::update(&mut s, &h, &zs, &params(inp, miss), 100_000);
            check(
                &s,
                &out,
                &sc[key],
                "",
                "",
                &format!("{key} scenario {}", sc["id"]),
            );
        }
    }
}

mod properties {
    use super::*;
    use nalgebra::{DMatrix, DVector};
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use stjpdacf_reference::jpda as reference;

    /// A coupled 3-entry-per-lane state ([c, g, g']) of `d` lanes 3.5 m apart, prior from B ⊗ P.
    fn lanes(d: usize, rho: f64, rng: &mut ChaCha8Rng) -> (DVector<f64>, DMatrix<f64>) {
        let b = DMatrix::from_fn(d, d, |i, j| rho.powi((i as i32 - j as i32).abs()));
        let p1 = DMatrix::from_row_slice(3, 3, &[0.04, 0.0, 0.0, 0.0, 0.09, 0.01, 0.0, 0.01, 0.02]);
        let p = b.kronecker(&p1);
        let x = DVector::from_fn(3 * d, |k, _| match k % 3 {
            0 => 3.5 * (k / 3) as f64 + rng.random_range(-0.1..0.1),
            _ => rng.random_range(-0.1..0.1),
        });
        (x, p)
    }

    fn to_core<const L: usize>(x: &DVector<f64>, p: &DMatrix<f64>, d: usize) -> Stacked<3, L> {
        let mut s = Stacked::<3, L>::new();
        let blk = |i: usize, j: usize| {
            SMatrix::<f32, 3, 3>::from_fn(|a, b| p[(3 * i + a, 3 * j + b)] as f32)
        };
        for i in 0..d {
            s.push(SVector::from_fn(|a, _| x[3 * i + a] as f32), &blk(i, i))
                .unwrap();
        }
        for i in 0..d {
            for j in 0..d {
                if i != j {
                    s.set_cross(i, j, &blk(i, j));
                }
            }
        }
        s
    }

    fn dense<const L: usize>(s: &Stacked<3, L>) -> DMatrix<f64> {
        let n = s.len();
        DMatrix::from_fn(3 * n, 3 * n, |r, c| {
            s.cov(r / 3, c / 3).unwrap()[(r % 3, c % 3)] as f64
        })
    }

    fn psd_error(p: &DMatrix<f64>) -> (f64, f64) {
        let sym = (p - p.transpose()).abs().max();
        let min_eig = p.clone().symmetric_eigen().eigenvalues.min();
        (sym, min_eig)
    }

    const H: [f32; 3] = [1.0, 1.0, 0.0];

    #[test]
    fn prediction_matches_reference() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (x, p) = lanes(4, 0.8, &mut rng);
        let f = DMatrix::from_row_slice(3, 3, &[1.0, 0.0, 0.0, 0.0, 0.99, 1.1, 0.0, -0.01, 0.97]);
        let q = DMatrix::from_row_slice(3, 3, &[0.0, 0.0, 0.0, 0.0, 1e-3, 1e-3, 0.0, 1e-3, 2e-3]);
        let b = DMatrix::from_fn(4, 4, |i, j| 0.9f64.powi((i as i32 - j as i32).abs()));
        let want = reference::predict(&x, &p, &f, &q, &b);
        let mut s = to_core::<6>(&x, &p, 4);
        let fc = SMatrix::<f32, 3, 3>::from_fn(|i, j| f[(i, j)] as f32);
        let qc = SMatrix::<f32, 3, 3>::from_fn(|i, j| q[(i, j)] as f32);
        let bc = SMatrix::<f32, 6, 6>::from_fn(|i, j| {
            if i < 4 && j < 4 {
                b[(i, j)] as f32
            } else {
                0.0
            }
        });
        s.predict(&fc, &qc, &bc);
        assert!((dense(&s) - &want.p).abs().max() < 1e-6);
        for i in 0..4 {
            for a in 0..3 {
                assert!((s.mean(i).unwrap()[a] as f64 - want.x[3 * i + a]).abs() < 1e-6);
            }
        }
    }

    /// Largest |β_core − β_exact| over tracks and points (β_exact: the unbounded f64 reference).
    fn beta_error(out: &row::RowOutcome<6>, exact: &reference::RowResult) -> f64 {
        let mut e = 0.0f64;
        for (t, bt) in exact.beta.iter().enumerate() {
            e = e.max((out.beta_miss[t] as f64 - bt[0]).abs());
            for (j, b) in bt.iter().skip(1).enumerate() {
                e = e.max((out.beta[t][j] as f64 - b).abs());
            }
        }
        e
    }

    /// Dense rows (every point valid for every lane) under an event budget that forces the bounded
    /// approximation: how far β moves from the exact (unbounded f64) answer. Returns (max, mean).
    fn truncation_error(
        d: usize,
        clutter: usize,
        budget: usize,
        scenes: usize,
        seed: u64,
    ) -> (f64, f64, usize) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (mut worst, mut sum, mut min_exact) = (0.0f64, 0.0f64, usize::MAX);
        for _ in 0..scenes {
            let (x, p) = lanes(d, 0.9, &mut rng);
            // One point near each lane and `clutter` competitors within ±0.5 m of random lanes:
            // the ambiguous case, where the pruning has to drop plausible candidates.
            let mut zs: Vec<f64> = (0..d)
                .map(|i| 3.5 * i as f64 + rng.random_range(-0.3..0.3))
                .collect();
            zs.extend(
                (0..clutter)
                    .map(|_| 3.5 * rng.random_range(0..d) as f64 + rng.random_range(-0.5..0.5)),
            );
            let params = reference::RowParams {
                pd: 0.9,
                pg: 0.99,
                gamma: 1e6,
                clutter_density: 0.05,
                r: 0.01,
                miss: reference::MissConvention::Pg,
            };
            let h = DMatrix::from_row_slice(1, 3, &[1.0, 1.0, 0.0]);
            let exact = reference::row_step(&x, &p, &h, &zs, &params).unwrap();
            min_exact = min_exact.min(exact.events.len());
            let zf: Vec<f32> = zs.iter().map(|v| *v as f32).collect();
            let rp = RowParams {
                pd: 0.9,
                pg: 0.99,
                gamma: 1e6,
                clutter_density: 0.05,
                r: 0.01,
                miss: MissModel::Gated,
            };
            let mut s = to_core::<6>(&x, &p, d);
            let out = row::update(&mut s, &SVector::from(H), &zf, &rp, budget);
            assert!(out.approximated && !out.failed && out.events as usize <= budget);
            let e = beta_error(&out, &exact);
            worst = worst.max(e);
            sum += e;
            // With the whole budget the core is exact and agrees with the reference.
            let mut s2 = to_core::<6>(&x, &p, d);
            let out2 = row::update(&mut s2, &SVector::from(H), &zf, &rp, 1_000_000);
            assert!(!out2.approximated);
            assert!(beta_error(&out2, &exact) < 1e-4);
        }
        (worst, sum / scenes as f64, min_exact)
    }

    /// The figures are printed (README): `cargo test --release -p stjpdacf-test-support --test spatial_core
    /// truncation -- --nocapture`.
    #[test]
    fn truncation_error_on_dense_rows() {
        for (d, clutter, budget, scenes, seed) in [
            (4, 4, 64, 40, 2024),
            (4, 4, 256, 40, 2024),
            (4, 4, 512, 40, 2024),
            (5, 3, 512, 12, 7),
            (5, 5, 512, 6, 9),
        ] {
            let (worst, mean, exact) = truncation_error(d, clutter, budget, scenes, seed);
            println!("β truncation: D = {d}, m = {}, E = {budget}, {scenes} dense rows (≥ {exact} exact events): max |Δβ| = {worst:.4}, mean = {mean:.4}", d + clutter);
            // From E = 256 on, the pruned events carry no measurable mass on these scenes; E = 64
            // is reported only (about three plausible points per lane cannot fit 64 events).
            if budget >= 256 {
                assert!(worst < 1e-3, "D = {d}, E = {budget}: max |Δβ| = {worst}");
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// Any points (NaN, ±inf, huge, subnormal), any lane count: no panic, no NaN, P symmetric
        /// PSD (to f32 round-off), events within budget; a failure leaves the state untouched.
        #[test]
        fn row_update_is_total(
            d in 1usize..=6,
            seed in any::<u64>(),
            pts in proptest::collection::vec(
                prop_oneof![
                    -5.0f32..25.0,
                    Just(f32::NAN), Just(f32::INFINITY), Just(f32::NEG_INFINITY),
                    Just(f32::MAX), Just(1e-40f32),
                ],
                0..40,
            ),
            budget in 1usize..600,
        ) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let (x, p) = lanes(d, 0.9, &mut rng);
            let mut s = to_core::<6>(&x, &p, d);
            let before = s;
            let out = row::update(&mut s, &SVector::from(H), &pts, &RowParams::default(), budget);
            prop_assert!(out.events as usize <= budget);
            if out.failed {
                prop_assert_eq!(s, before);
            } else {
                let pd = dense(&s);
                prop_assert!(pd.iter().all(|v| v.is_finite()));
                let (sym, min_eig) = psd_error(&pd);
                let scale = pd.abs().max();
                prop_assert!(sym <= 1e-6 * scale, "asymmetry {}", sym);
                prop_assert!(min_eig >= -1e-5 * scale, "min eigenvalue {}", min_eig);
                for t in 0..d {
                    let total: f32 = out.beta_miss[t] + out.beta[t].iter().sum::<f32>();
                    prop_assert!((total - 1.0).abs() < 1e-4, "β of track {} sums to {}", t, total);
                }
            }
        }
    }
}
