//! The f64 JPDA / coupled JPDACF reference (`reference::jpda`) against the golden values of
//! `data/golden/jpda_marginals.json` (brute-force numpy enumeration, cross-checked with Stone Soup),
//! plus unit properties of the reference itself.

use nalgebra::{DMatrix, DVector};
use serde_json::Value;
use stjpdacf_reference::jpda::{
    block_diagonal, count_events_full_gating, enumerate_events, predict, row_step, stack_tracks,
    Estimate, Event, MissConvention, RowParams, RowResult,
};

/// Absolute/relative tolerance of every golden comparison: `|a − b| ≤ TOL · max(1, |b|)`.
const TOL: f64 = 1e-12;

// ---------------------------------------------------------------- JSON helpers

fn load_golden() -> Value {
    let path = stjpdacf_tools::repo_root().join("data/golden/jpda_marginals.json");
    let text =
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
    serde_json::from_str(&text).expect("valid JSON")
}

fn get<'a>(v: &'a Value, key: &str) -> &'a Value {
    v.get(key)
        .unwrap_or_else(|| panic!("missing field `{key}`"))
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn arr(v: &Value) -> &Vec<Value> {
    v.as_array().unwrap_or_else(|| panic!("not an array: {v}"))
}

fn vec1(v: &Value) -> Vec<f64> {
    arr(v).iter().map(num).collect()
}

fn vec2(v: &Value) -> Vec<Vec<f64>> {
    arr(v).iter().map(vec1).collect()
}

fn dvec(v: &Value) -> DVector<f64> {
    DVector::from_vec(vec1(v))
}

/// Row-major nested list → matrix (an empty list of rows gives 0 × 0, `[[]]`-style rows give r × 0).
fn dmat(v: &Value) -> DMatrix<f64> {
    let rows = vec2(v);
    let nr = rows.len();
    let nc = rows.first().map_or(0, Vec::len);
    assert!(rows.iter().all(|r| r.len() == nc), "ragged matrix");
    DMatrix::from_fn(nr, nc, |i, j| rows[i][j])
}

fn events_of(v: &Value) -> Vec<Event> {
    arr(v)
        .iter()
        .map(|e| {
            arr(e)
                .iter()
                .map(|a| {
                    let j = a.as_i64().expect("integer event entry");
                    usize::try_from(j).ok()
                })
                .collect()
        })
        .collect()
}

// ---------------------------------------------------------------- comparison helpers

/// Tracks the worst scaled error seen, so the tests can report it.
#[derive(Default)]
struct MaxErr(f64);

impl MaxErr {
    fn scalar(&mut self, what: &str, got: f64, want: f64) {
        let err = (got - want).abs() / want.abs().max(1.0);
        assert!(
            err <= TOL,
            "{what}: got {got:e}, want {want:e} (scaled error {err:e} > {TOL:e})"
        );
        self.0 = self.0.max(err);
    }
    fn slice(&mut self, what: &str, got: &[f64], want: &[f64]) {
        assert_eq!(got.len(), want.len(), "{what}: length");
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            self.scalar(&format!("{what}[{i}]"), *g, *w);
        }
    }
    fn mat(&mut self, what: &str, got: &DMatrix<f64>, want: &DMatrix<f64>) {
        assert_eq!(got.shape(), want.shape(), "{what}: shape");
        for i in 0..got.nrows() {
            for j in 0..got.ncols() {
                self.scalar(&format!("{what}[{i},{j}]"), got[(i, j)], want[(i, j)]);
            }
        }
    }
    fn nested(&mut self, what: &str, got: &[Vec<f64>], want: &[Vec<f64>]) {
        assert_eq!(got.len(), want.len(), "{what}: rows");
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            self.slice(&format!("{what}[{i}]"), g, w);
        }
    }
}

struct Scenario<'a> {
    id: i64,
    inputs: &'a Value,
    v: &'a Value,
    d: usize,
    nx: usize,
    h: DMatrix<f64>,
    zs: Vec<f64>,
}

impl<'a> Scenario<'a> {
    fn new(v: &'a Value) -> Self {
        let inputs = get(v, "inputs");
        let h = dmat(get(inputs, "H"));
        assert_eq!(h.nrows(), 1, "scalar measurements only");
        Scenario {
            id: get(v, "id").as_i64().expect("id"),
            inputs,
            v,
            d: get(inputs, "D").as_u64().expect("D") as usize,
            nx: get(inputs, "nx").as_u64().expect("nx") as usize,
            h,
            zs: vec1(get(inputs, "zs")),
        }
    }

    fn params(&self, miss: MissConvention) -> RowParams {
        let r = dmat(get(self.inputs, "R"));
        RowParams {
            pd: num(get(self.inputs, "pd")),
            pg: num(get(self.inputs, "pg")),
            gamma: num(get(self.inputs, "gamma")),
            clutter_density: num(get(self.inputs, "clutter_density")),
            r: r[(0, 0)],
            miss,
        }
    }

    /// The independent JPDA: per-track priors stacked block-diagonally (B = I).
    fn run_independent(&self, miss: MissConvention) -> RowResult {
        let xs: Vec<DVector<f64>> = arr(get(self.inputs, "x_pred")).iter().map(dvec).collect();
        let ps: Vec<DMatrix<f64>> = arr(get(self.inputs, "P_pred")).iter().map(dmat).collect();
        assert_eq!(xs.len(), self.d);
        let (xbar, pbar) = stack_tracks(&xs, &ps).expect("consistent tracks");
        row_step(&xbar, &pbar, &self.h, &self.zs, &self.params(miss)).expect("row step")
    }

    /// The coupled JPDACF on the golden non-diagonal `P̄`.
    fn run_coupled(&self) -> RowResult {
        let xbar = dvec(get(self.inputs, "xbar"));
        let pbar = dmat(get(self.inputs, "Pbar"));
        row_step(
            &xbar,
            &pbar,
            &self.h,
            &self.zs,
            &self.params(MissConvention::Textbook),
        )
        .expect("row step")
    }
}

fn gate_as_bools(v: &Value) -> Vec<Vec<bool>> {
    arr(v)
        .iter()
        .map(|row| {
            arr(row)
                .iter()
                .map(|g| g.as_i64().expect("0/1 gate") != 0)
                .collect()
        })
        .collect()
}

fn check_gating(err: &mut MaxErr, tag: &str, res: &RowResult, g: &Value, with_zhat: bool) {
    assert_eq!(
        res.gating.valid,
        gate_as_bools(get(g, "gate")),
        "{tag}: gate"
    );
    if with_zhat {
        err.slice(
            &format!("{tag}.zhat"),
            &res.gating.zhat,
            &vec1(get(g, "zhat")),
        );
        err.slice(&format!("{tag}.S"), &res.gating.s, &vec1(get(g, "S")));
        err.nested(&format!("{tag}.d2"), &res.gating.d2, &vec2(get(g, "d2")));
    }
}

fn check_events(err: &mut MaxErr, tag: &str, res: &RowResult, g: &Value) {
    let n = get(g, "n_events").as_u64().expect("n_events") as usize;
    assert_eq!(res.events.len(), n, "{tag}: n_events");
    // Same order as the golden enumeration (checked exactly, not just as sets).
    assert_eq!(res.events, events_of(get(g, "events")), "{tag}: events");
    err.slice(
        &format!("{tag}.event_probs"),
        &res.event_probs,
        &vec1(get(g, "event_probs")),
    );
}

/// The association probabilities and the PDA estimates of `res` against the section `g`.
fn check_beta_pda(err: &mut MaxErr, tag: &str, res: &RowResult, g: &Value) {
    err.nested(&format!("{tag}.beta"), &res.beta, &vec2(get(g, "beta")));
    check_pda(err, tag, &res.pda, g);
}

/// Stacks the per-track PDA estimates of the reference back into per-target lists.
fn check_pda(err: &mut MaxErr, tag: &str, pda: &[Estimate], g: &Value) {
    let xs = arr(get(g, "x_upd"));
    let ps = arr(get(g, "P_upd"));
    assert_eq!(pda.len(), xs.len(), "{tag}: tracks");
    for (t, est) in pda.iter().enumerate() {
        err.slice(
            &format!("{tag}.x_upd[{t}]"),
            est.x.as_slice(),
            &vec1(&xs[t]),
        );
        err.mat(&format!("{tag}.P_upd[{t}]"), &est.p, &dmat(&ps[t]));
    }
}

fn for_each_scenario(mut f: impl FnMut(&Scenario<'_>)) -> usize {
    let golden = load_golden();
    let scenarios = arr(get(&golden, "scenarios"));
    assert_eq!(scenarios.len(), 22, "golden scenario count");
    for v in scenarios {
        f(&Scenario::new(v));
    }
    scenarios.len()
}

/// Runs `f` on every scenario with one running maximum of the scaled errors, printed under
/// `what` at the end.
fn max_error_over_scenarios(what: &str, mut f: impl FnMut(&mut MaxErr, &Scenario<'_>)) {
    let mut err = MaxErr::default();
    for_each_scenario(|sc| f(&mut err, sc));
    println!("{what}: max scaled error {:e}", err.0);
}

// ---------------------------------------------------------------- golden tests

#[test]
fn golden_conventions_are_the_ones_implemented() {
    let golden = load_golden();
    let c = get(&golden, "conventions");
    let s = |k: &str| get(c, k).as_str().expect("string").to_owned();
    assert!(s("gating").contains("<= gamma (inclusive)"));
    assert!(s("beta_layout").starts_with("beta[t][0] = P(target t missed)"));
    assert!(s("event_encoding").contains("-1 = missed"));
    assert!(s("missf").contains("textbook: 1-PD; pg: 1-PD*PG"));
    assert!(s("stacking").contains("target-major"));
}

#[test]
fn independent_jpda_textbook_matches_golden() {
    max_error_over_scenarios("jpda_textbook", |err, sc| {
        let g = get(sc.v, "jpda_textbook");
        let tag = format!("scenario {} jpda_textbook", sc.id);
        let res = sc.run_independent(MissConvention::Textbook);
        check_gating(err, &tag, &res, g, true);
        check_events(err, &tag, &res, g);
        check_beta_pda(err, &tag, &res, g);
    });
}

#[test]
fn independent_jpda_pg_matches_golden_and_stonesoup() {
    max_error_over_scenarios("jpda_pg + stonesoup_pg", |err, sc| {
        let tag = format!("scenario {} jpda_pg", sc.id);
        let res = sc.run_independent(MissConvention::Pg);
        let g = get(sc.v, "jpda_pg");
        check_gating(err, &tag, &res, g, true);
        let n = get(g, "n_events").as_u64().expect("n_events") as usize;
        assert_eq!(res.events.len(), n, "{tag}: n_events");
        // The pg section has no `events`: the event set depends only on gating, which it shares
        // with the textbook section.
        let tb = get(sc.v, "jpda_textbook");
        assert_eq!(res.events, events_of(get(tb, "events")), "{tag}: events");
        check_beta_pda(err, &tag, &res, g);
        // Stone Soup 1.9.1 (an independent implementation of the same convention).
        let ss = get(sc.v, "stonesoup_pg");
        let tag = format!("scenario {} stonesoup_pg", sc.id);
        check_beta_pda(err, &tag, &res, ss);
    });
}

#[test]
fn independent_mixture_equals_pda_on_each_block() {
    // With a block-diagonal prior the exact mixture update is the PDA update on each block, and the
    // cross-covariances it creates are the only difference (golden self-check, here on our own code).
    max_error_over_scenarios("independent mixture vs pda", |err, sc| {
        for miss in [MissConvention::Textbook, MissConvention::Pg] {
            let res = sc.run_independent(miss);
            let tag = format!("scenario {} {miss:?} mixture vs pda", sc.id);
            for (t, est) in res.pda.iter().enumerate() {
                let (o, nx) = (t * sc.nx, sc.nx);
                let x = res.mixture.x.rows(o, nx).into_owned();
                err.slice(&format!("{tag}.x[{t}]"), x.as_slice(), est.x.as_slice());
                let p = res.mixture.p.view((o, o), (nx, nx)).into_owned();
                // Different algebra (event mixture vs. closed PDA form): allow 1e-12 as everywhere.
                err.mat(&format!("{tag}.P[{t}]"), &p, &est.p);
            }
        }
    });
}

#[test]
fn coupled_textbook_matches_golden() {
    max_error_over_scenarios("coupled_textbook", |err, sc| {
        let g = get(sc.v, "coupled_textbook");
        let tag = format!("scenario {} coupled_textbook", sc.id);
        let res = sc.run_coupled();
        check_gating(err, &tag, &res, g, false);
        err.slice(
            &format!("{tag}.S_diag"),
            &res.gating.s,
            &vec1(get(g, "S_diag")),
        );
        err.mat(&format!("{tag}.Sbar"), &res.sbar, &dmat(get(g, "Sbar")));
        check_events(err, &tag, &res, g);
        err.nested(&format!("{tag}.beta"), &res.beta, &vec2(get(g, "beta")));
        err.scalar(
            &format!("{tag}.beta0_all_missed"),
            res.beta0_all_missed,
            num(get(g, "beta0_all_missed")),
        );
        err.mat(&format!("{tag}.G"), &res.gain, &dmat(get(g, "G")));
        err.slice(
            &format!("{tag}.vbar"),
            res.vbar.as_slice(),
            &vec1(get(g, "vbar")),
        );
        err.mat(&format!("{tag}.Pc"), &res.pc, &dmat(get(g, "Pc")));
        for (name, est) in [
            ("mixture", &res.mixture),
            ("paper", &res.paper),
            ("masked", &res.masked),
        ] {
            err.slice(
                &format!("{tag}.x_{name}"),
                est.x.as_slice(),
                &vec1(get(g, &format!("x_{name}"))),
            );
            err.mat(
                &format!("{tag}.P_{name}"),
                &est.p,
                &dmat(get(g, &format!("P_{name}"))),
            );
        }
    });
}

#[test]
fn coupled_with_block_diagonal_prior_is_independent_jpda() {
    // Dropping the cross-covariances of the golden P̄ must give exactly the independent JPDA on
    // those blocks: same events, probabilities, beta and per-track update.
    max_error_over_scenarios("block-diagonal vs independent", |err, sc| {
        let xbar = dvec(get(sc.inputs, "xbar"));
        let pbar = block_diagonal(&dmat(get(sc.inputs, "Pbar")), sc.nx);
        let p = sc.params(MissConvention::Textbook);
        let blk = row_step(&xbar, &pbar, &sc.h, &sc.zs, &p).expect("row step");
        let ind = sc.run_independent(MissConvention::Textbook);
        let tag = format!("scenario {} block-diagonal", sc.id);
        assert_eq!(blk.events, ind.events, "{tag}: events");
        err.slice(
            &format!("{tag}.event_probs"),
            &blk.event_probs,
            &ind.event_probs,
        );
        err.nested(&format!("{tag}.beta"), &blk.beta, &ind.beta);
        for (t, (a, b)) in blk.pda.iter().zip(&ind.pda).enumerate() {
            err.slice(&format!("{tag}.x[{t}]"), a.x.as_slice(), b.x.as_slice());
            err.mat(&format!("{tag}.P[{t}]"), &a.p, &b.p);
        }
    });
}

// ---------------------------------------------------------------- unit properties

fn simple_params(miss: MissConvention) -> RowParams {
    RowParams {
        pd: 0.9,
        pg: 0.99,
        gamma: 9.21,
        clutter_density: 0.5,
        r: 0.05,
        miss,
    }
}

#[test]
fn single_track_is_pda_for_every_variant() {
    // D = 1: the coupled update, the paper form, the masked form and PDA are the same thing.
    let x = DVector::from_vec(vec![0.3, -0.2]);
    let p = DMatrix::from_row_slice(2, 2, &[0.4, 0.1, 0.1, 0.7]);
    let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
    let zs = [0.1, 0.5, 1.2, -0.4, 3.5];
    for miss in [MissConvention::Textbook, MissConvention::Pg] {
        let res = row_step(&x, &p, &h, &zs, &simple_params(miss)).expect("row step");
        let pda = &res.pda[0];
        let mut err = MaxErr::default();
        for est in [&res.mixture, &res.paper, &res.masked] {
            err.slice("x", est.x.as_slice(), pda.x.as_slice());
            err.mat("P", &est.p, &pda.p);
        }
        // Events: miss + one per gated point.
        let gated = res.gating.valid[0].iter().filter(|&&v| v).count();
        assert!(
            gated >= 3 && gated < zs.len(),
            "test scenario should gate some points out"
        );
        assert_eq!(res.events.len(), 1 + gated);
        let total: f64 = res.beta[0].iter().sum();
        assert!((total - 1.0).abs() < 1e-14);
    }
}

#[test]
fn single_track_beta_has_closed_form() {
    // Standard PDA: β_j ∝ P_D N(z_j; ẑ, S)/λ, β_0 ∝ missf.
    let x = DVector::from_vec(vec![0.0, 0.0]);
    let p = DMatrix::from_row_slice(2, 2, &[0.3, 0.0, 0.0, 0.2]);
    let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
    let zs = [0.2, -0.5];
    let prm = simple_params(MissConvention::Pg);
    let res = row_step(&x, &p, &h, &zs, &prm).expect("row step");
    let s = 0.3 + prm.r;
    let lik = |z: f64| (-0.5 * z * z / s).exp() / (2.0 * std::f64::consts::PI * s).sqrt();
    let w = [
        1.0 - prm.pd * prm.pg,
        prm.pd * lik(zs[0]) / prm.clutter_density,
        prm.pd * lik(zs[1]) / prm.clutter_density,
    ];
    let tot: f64 = w.iter().sum();
    for (b, wi) in res.beta[0].iter().zip(w) {
        assert!((b - wi / tot).abs() < 1e-14, "{b} vs {}", wi / tot);
    }
}

#[test]
fn full_gating_event_count_formula() {
    // Σ_k C(D,k) C(m,k) k!
    assert_eq!(count_events_full_gating(1, 0), 1);
    assert_eq!(count_events_full_gating(1, 5), 6);
    assert_eq!(count_events_full_gating(2, 2), 7);
    assert_eq!(
        count_events_full_gating(3, 8),
        1 + 3 * 8 + 3 * 8 * 7 + 8 * 7 * 6
    );
    assert_eq!(
        count_events_full_gating(4, 3),
        1 + 4 * 3 + 6 * 3 * 2 + 4 * 6
    );
    for d in 0..5 {
        for m in 0..7 {
            let n = enumerate_events(&vec![vec![true; m]; d]).len() as u128;
            assert_eq!(n, count_events_full_gating(d, m), "D={d} m={m}");
        }
    }
    // With wide gates the row step enumerates exactly that many events.
    let prm = RowParams {
        gamma: 1e9,
        ..simple_params(MissConvention::Textbook)
    };
    let (xbar, pbar) = stack_tracks(
        &[
            DVector::from_vec(vec![0.0, 0.0]),
            DVector::from_vec(vec![1.0, 0.0]),
            DVector::from_vec(vec![2.0, 0.0]),
        ],
        &[
            DMatrix::identity(2, 2),
            DMatrix::identity(2, 2),
            DMatrix::identity(2, 2),
        ],
    )
    .expect("stack");
    let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
    let res = row_step(&xbar, &pbar, &h, &[0.1, 0.9, 2.2, 5.0], &prm).expect("row step");
    assert_eq!(res.events.len() as u128, count_events_full_gating(3, 4));
}

#[test]
fn events_respect_gating_and_exclusivity() {
    let valid = vec![
        vec![true, false, true],
        vec![true, true, false],
        vec![false, false, false],
    ];
    let events = enumerate_events(&valid);
    // Track 0: {miss, 0, 2}; track 1: {miss, 0, 1}; track 2: miss; minus the (0, 0) conflict.
    assert_eq!(events.len(), 3 * 3 - 1);
    for e in &events {
        assert_eq!(e[2], None);
        for (t, a) in e.iter().enumerate() {
            if let Some(j) = a {
                assert!(valid[t][*j]);
                assert_eq!(e.iter().filter(|b| **b == Some(*j)).count(), 1);
            }
        }
    }
    assert_eq!(events[0], vec![None, None, None]);
    assert_eq!(events[1], vec![None, Some(0), None]);
    assert_eq!(events.last(), Some(&vec![Some(2), Some(1), None]));
}

#[test]
fn coupling_changes_probabilities_and_mixture_stays_psd() {
    // Two correlated tracks, each with a candidate point: the coupled event probabilities differ
    // from the independent ones, the marginals still sum to one and P⁺ is PSD.
    let b = DMatrix::from_row_slice(2, 2, &[1.0, 0.8, 0.8, 1.0]);
    let p1 = DMatrix::from_row_slice(2, 2, &[0.5, 0.1, 0.1, 0.3]);
    let pbar = b.kronecker(&p1);
    let xbar = DVector::from_vec(vec![0.0, 0.0, 1.0, 0.0]);
    let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
    let zs = [0.6, 1.6, 0.3];
    let prm = simple_params(MissConvention::Pg);
    let coupled = row_step(&xbar, &pbar, &h, &zs, &prm).expect("row step");
    let indep = row_step(&xbar, &block_diagonal(&pbar, 2), &h, &zs, &prm).expect("row step");
    assert_eq!(coupled.events, indep.events);
    let diff = coupled
        .event_probs
        .iter()
        .zip(&indep.event_probs)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(diff > 1e-3, "coupling should matter, max diff {diff}");
    for row in &coupled.beta {
        assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-14);
    }
    let eig = coupled.mixture.p.clone().symmetric_eigen();
    assert!(
        eig.eigenvalues.iter().all(|&l| l > 0.0),
        "{:?}",
        eig.eigenvalues
    );
    // The mixture covariance is never smaller than the prior minus a full update.
    let slack = (&coupled.mixture.p - &coupled.pc).symmetric_eigen();
    assert!(
        slack.eigenvalues.iter().all(|&l| l > -1e-12),
        "{:?}",
        slack.eigenvalues
    );
}

#[test]
fn masked_closed_form_is_the_event_mixture_of_joseph_updates() {
    // The `masked` variant written event by event: K_A = G M_A, Joseph covariance, moment matching.
    let b = DMatrix::from_row_slice(3, 3, &[1.0, 0.6, 0.3, 0.6, 1.0, 0.6, 0.3, 0.6, 1.0]);
    let p1 = DMatrix::from_row_slice(2, 2, &[0.4, 0.05, 0.05, 0.2]);
    let pbar = b.kronecker(&p1);
    let xbar = DVector::from_vec(vec![-1.0, 0.1, 0.0, 0.0, 1.2, -0.1]);
    let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
    let zs = [-0.7, 0.2, 0.5, 1.0, 2.5];
    let prm = simple_params(MissConvention::Pg);
    let res = row_step(&xbar, &pbar, &h, &zs, &prm).expect("row step");
    assert!(res.events.len() > 10);
    let hbar = DMatrix::<f64>::identity(3, 3).kronecker(&h);
    let n = xbar.len();
    let eye = DMatrix::<f64>::identity(n, n);
    let mut xs = Vec::new();
    let mut ps = Vec::new();
    for ev in &res.events {
        let mask = DMatrix::from_diagonal(&DVector::from_fn(3, |t, _| {
            if ev[t].is_some() {
                1.0
            } else {
                0.0
            }
        }));
        let nu = DVector::from_fn(3, |t, _| ev[t].map_or(0.0, |j| zs[j] - res.gating.zhat[t]));
        let k = &res.gain * &mask;
        let ikh = &eye - &k * &hbar;
        xs.push(&xbar + &k * nu);
        ps.push(&ikh * &pbar * ikh.transpose() + &k * k.transpose() * prm.r);
    }
    let x: DVector<f64> = xs.iter().zip(&res.event_probs).map(|(x, p)| x * *p).sum();
    let mut p = DMatrix::zeros(n, n);
    for ((xa, pa), w) in xs.iter().zip(&ps).zip(&res.event_probs) {
        let dx = xa - &x;
        p += (pa + &dx * dx.transpose()) * *w;
    }
    let mut err = MaxErr::default();
    err.slice("x_masked", res.masked.x.as_slice(), x.as_slice());
    err.mat("P_masked", &res.masked.p, &p);
    // And `paper` differs from it whenever some events detect only part of the tracks.
    assert!((&res.paper.p - &res.masked.p).abs().max() > 1e-6);
}

#[test]
fn predict_uses_kronecker_process_noise() {
    let f = DMatrix::from_row_slice(2, 2, &[1.0, 0.5, 0.0, 1.0]);
    let q = DMatrix::from_row_slice(2, 2, &[0.01, 0.02, 0.02, 0.1]);
    let b = DMatrix::from_row_slice(2, 2, &[2.0, 0.5, 0.5, 1.0]);
    let xbar = DVector::from_vec(vec![1.0, 2.0, 3.0, 4.0]);
    let pbar = b.kronecker(&DMatrix::identity(2, 2));
    let out = predict(&xbar, &pbar, &f, &q, &b);
    let mut err = MaxErr::default();
    err.slice("x", out.x.as_slice(), &[2.0, 2.0, 5.0, 4.0]);
    let fbar = DMatrix::<f64>::identity(2, 2).kronecker(&f);
    err.mat(
        "P",
        &out.p,
        &(&fbar * &pbar * fbar.transpose() + b.kronecker(&q)),
    );
    // Cross block = B_01 (F Fᵀ + Q).
    err.mat(
        "P01",
        &out.p.view((0, 2), (2, 2)).into_owned(),
        &((&f * f.transpose() + &q) * 0.5),
    );
}

#[test]
fn certain_detection_excludes_the_miss_and_zero_weights_are_reported() {
    // P_D = 1 with the textbook factor: a missed track has weight exactly zero (ln 0 = −∞).
    let x = DVector::from_vec(vec![0.0, 0.0]);
    let p = DMatrix::from_row_slice(2, 2, &[0.3, 0.0, 0.0, 0.2]);
    let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
    let prm = RowParams {
        pd: 1.0,
        ..simple_params(MissConvention::Textbook)
    };
    let res = row_step(&x, &p, &h, &[0.1, -0.2], &prm).expect("row step");
    assert_eq!(res.beta[0][0], 0.0);
    assert!(res.event_probs.iter().all(|v| v.is_finite()));
    assert!((res.beta[0][1] + res.beta[0][2] - 1.0).abs() < 1e-15);
    // No measurement at all: every event has zero weight, which is reported, not normalised to NaN.
    assert!(row_step(&x, &p, &h, &[], &prm).is_none());
}
