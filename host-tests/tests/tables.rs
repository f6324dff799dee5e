//! The committed tables against the generator, and the f32 core kernels against the f64 reference.
//!
//! Tolerances (f32 core vs f64 reference), per entry, relative to the largest magnitude of the
//! matrix unless stated (plus 1e-30 absolute, below f32's range): stored tables 1e-6 (one f32
//! rounding); Matérn `F` (closed form) 2e-6 and `Q` (series) 2e-4 relative to each entry; RBF `F`
//! and `Q` (scaling and squaring / doubling, on the balanced companion form) 1e-5 for steps up to ℓ
//! and 1e-4 for steps up to 4ℓ (measured worst 4.5e-5: order 6, ℓ = 0.3, Δu = 4ℓ; without the
//! balancing, order 4 already reached 1.4e-4). The reference uses Van Loan's method here: its own
//! `P∞ − F P∞ Fᵀ` has no correct digits when `Q` is 1e-11 of `P∞` (order 6 at Δu = ℓ/20).

use nalgebra::{DMatrix, SMatrix};
use stjpdacf::kernel::{Matern32 as CoreMatern, RbfStateSpace};
use stjpdacf::tables::{DEFAULT, FORMAT_VERSION};
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_reference::statespace::{Matern32, RbfTaylor};
use stjpdacf_tools::repo_root;
use stjpdacf_tools::tablegen::{self, ModelTables};

fn default_model() -> ModelTables {
    let h = HyperFile::load(&repo_root().join(tablegen::DEFAULT_HYPER)).unwrap();
    ModelTables::from_hyper(&h).unwrap()
}

#[test]
fn committed_tables_are_regenerated_exactly() {
    let t = default_model();
    let want = tablegen::render(&t, "DEFAULT", tablegen::DEFAULT_HYPER).unwrap();
    let have = std::fs::read_to_string(repo_root().join(tablegen::DEFAULT_TABLES)).unwrap();
    assert!(
        want == have,
        "{} is stale: run `cargo run -p stjpdacf-tools -- tables --hyper {} --out {}`",
        tablegen::DEFAULT_TABLES,
        tablegen::DEFAULT_HYPER,
        tablegen::DEFAULT_TABLES
    );
    assert_eq!(tablegen::FORMAT_VERSION, FORMAT_VERSION);
}

#[test]
fn committed_uncoupled_tables_are_regenerated_exactly() {
    let h = HyperFile::load(&repo_root().join(tablegen::UNCOUPLED_HYPER)).unwrap();
    let t = ModelTables::from_hyper(&h).unwrap();
    let want = tablegen::render(&t, "UNCOUPLED", tablegen::UNCOUPLED_HYPER).unwrap();
    let have = std::fs::read_to_string(repo_root().join(tablegen::UNCOUPLED_TABLES)).unwrap();
    assert!(
        want == have,
        "{} is stale: run `cargo run -p stjpdacf-tools -- tables --hyper {} --out {} --name UNCOUPLED`",
        tablegen::UNCOUPLED_TABLES,
        tablegen::UNCOUPLED_HYPER,
        tablegen::UNCOUPLED_TABLES
    );
    // The uncoupled model is the default one with B's off-diagonal removed.
    let (d, u) = (&stjpdacf::tables::DEFAULT, &stjpdacf::tables::UNCOUPLED);
    assert_eq!(u.validate(), Ok(()));
    assert_eq!(d.gram, u.gram);
    assert_eq!(d.spatial.f, u.spatial.f);
    assert_eq!(d.temporal.p_inf, u.temporal.p_inf);
    for i in 0..6 {
        for j in 0..6 {
            let want = if i == j { d.coreg[(i, i)] } else { 0.0 };
            assert!(
                (u.coreg[(i, j)] - want).abs() <= 1e-5 * want.abs(),
                "B[{i},{j}]"
            );
        }
    }
}

/// How [`close`] bounds the error of an entry `w` of the reference.
#[derive(Debug, Clone, Copy)]
enum Tol {
    /// `tol × max |want|` (shapes must match).
    Scaled(f64),
    /// `tol × |w|`.
    Each(f64),
}

#[track_caller]
fn close<const R: usize, const C: usize>(
    got: &SMatrix<f32, R, C>,
    want: &DMatrix<f64>,
    tol: Tol,
    what: &str,
) {
    let scale = want.abs().max().max(f64::MIN_POSITIVE);
    if let Tol::Scaled(_) = tol {
        assert_eq!((R, C), want.shape(), "{what}: shape");
    }
    for i in 0..R {
        for j in 0..C {
            let (g, w) = (got[(i, j)] as f64, want[(i, j)]);
            let (bound, note) = match tol {
                Tol::Scaled(t) => (t * scale, format!(" (scale {scale:e})")),
                Tol::Each(t) => (t * w.abs(), String::new()),
            };
            assert!(
                (g - w).abs() <= bound + 1e-30,
                "{what}[{i},{j}]: {g:e} vs {w:e}{note}"
            );
        }
    }
}

fn dm<const R: usize, const C: usize>(m: &SMatrix<f32, R, C>) -> DMatrix<f64> {
    DMatrix::from_fn(R, C, |i, j| m[(i, j)] as f64)
}

#[test]
fn committed_tables_hold_the_f64_model() {
    let t = default_model();
    let d = &DEFAULT;
    assert_eq!(d.validate(), Ok(()));
    close(&d.spatial.model.A, &t.spatial_a, Tol::Scaled(1e-6), "A_u");
    close(
        &d.spatial.model.p_inf,
        &t.spatial_p_inf,
        Tol::Scaled(1e-6),
        "P∞_u",
    );
    close(&d.spatial.f, &t.spatial_f, Tol::Scaled(1e-6), "F_u");
    close(&d.spatial.q, &t.spatial_q, Tol::Scaled(1e-6), "Q_u");
    close(&d.temporal.f, &t.temporal_f, Tol::Scaled(1e-6), "F_t");
    close(&d.temporal.q, &t.temporal_q, Tol::Scaled(1e-6), "Q_t");
    close(&d.gram, &t.gram, Tol::Scaled(1e-6), "K_u");
    close(&d.gram_eigvec, &t.gram_eigvec, Tol::Scaled(1e-6), "V");
    close(&d.coreg, &t.coreg, Tol::Scaled(1e-6), "B");
    close(&d.coreg_chol, &t.coreg_chol, Tol::Scaled(1e-6), "chol B");
    assert_eq!(d.gram_rank as usize, t.gram_rank);
    // The eigenbasis reconstructs K_u and is orthonormal (in f32).
    let v = dm(&d.gram_eigvec);
    let lam = DMatrix::from_diagonal(&nalgebra::DVector::from_fn(16, |i, _| {
        d.gram_eigval[i] as f64
    }));
    assert!((&v * lam * v.transpose() - &t.gram).abs().max() < 1e-5);
    assert!((v.transpose() * &v - DMatrix::identity(16, 16)).abs().max() < 1e-5);
    // Leading blocks of chol(B) factor B's leading blocks (what k active lanes use).
    for k in 1..=6 {
        let l = dm(&d.coreg_chol).view((0, 0), (k, k)).into_owned();
        let b = t.coreg.view((0, 0), (k, k)).into_owned();
        assert!((&l * l.transpose() - b).abs().max() < 1e-5, "k = {k}");
    }
}

#[test]
fn core_matern_matches_reference_for_any_step() {
    for &(s2, l) in &[(1.0, 30.0), (0.5, 0.5), (4.0, 2.0), (1.0, 10.0)] {
        let core = CoreMatern::new(s2 as f32, l as f32);
        let reference = Matern32 {
            variance: s2,
            lengthscale: l,
        };
        // nominal 20 fps, dropped frames (2×, 5×), a jittered step, long blackouts
        for t in [0.05, 0.1, 0.25, 0.0371, 1.0, 3.0, 60.0] {
            let (f, q) = core.transition(t as f32).unwrap();
            let (fr, qr) = reference.transition(t);
            close(
                &f,
                &fr,
                Tol::Scaled(2e-6),
                &format!("F s2={s2} l={l} T={t}"),
            );
            close(&q, &qr, Tol::Each(2e-4), &format!("Q s2={s2} l={l} T={t}"));
            let p = core.p_inf();
            close(&p, &reference.p_inf_closed(), Tol::Scaled(1e-6), "P∞");
            assert!((core.eval(t as f32) as f64 - reference.kernel(t)).abs() < 1e-6 * s2);
        }
    }
}

fn check_rbf_order<const NT: usize>(s2: f64, l: f64) {
    let r = RbfTaylor {
        variance: s2,
        lengthscale: l,
        order: NT,
    };
    let p = r.p_inf().unwrap();
    let a = r.a();
    let core = RbfStateSpace::<NT> {
        A: SMatrix::from_fn(|i, j| a[(i, j)] as f32),
        qc: r.qc() as f32,
        p_inf: SMatrix::from_fn(|i, j| p[(i, j)] as f32),
    };
    for du in [0.05 * l, 0.2 * l, 1.203125, 0.5 * l, l, 3.0 * l] {
        let (f, q) = core.transition(du as f32).unwrap();
        let (fr, qr) = r.transition_van_loan(du);
        // Steps up to ℓ are the operating range (rows are ~ℓ/20 apart); longer steps take more
        // squarings of a decaying exponential, each of which roughly doubles f32 round-off.
        let tol = if du <= l { 1e-5 } else { 1e-4 };
        close(&f, &fr, Tol::Scaled(tol), &format!("order {NT} F du={du}"));
        close(&q, &qr, Tol::Scaled(tol), &format!("order {NT} Q du={du}"));
        let k = core.covariance(du as f32).unwrap() as f64;
        assert!(
            (k - r.kernel_statespace(du).unwrap()).abs() < 1e-5 * s2,
            "order {NT} k({du})"
        );
    }
}

#[test]
fn core_rbf_statespace_matches_reference_for_orders_2_to_6() {
    for (s2, l) in [(1.0, 25.0), (0.5, 2.0), (4.0, 0.3)] {
        check_rbf_order::<2>(s2, l);
        check_rbf_order::<3>(s2, l);
        check_rbf_order::<4>(s2, l);
        check_rbf_order::<5>(s2, l);
        check_rbf_order::<6>(s2, l);
    }
}

#[test]
fn readme_holds_the_current_approximation_table() {
    let readme = std::fs::read_to_string(repo_root().join("README.md")).unwrap();
    let table = stjpdacf_reference::statespace::approximation_table(2..=6);
    assert!(
        readme.contains(&table),
        "README.md's approximation table is stale; paste `stjpdacf kernels`:\n{table}"
    );
}

#[test]
fn tables_live_in_a_static() {
    // Compile-time proof that the tables type is const-constructible: copy it into a `static`.
    static COPY: stjpdacf::tables::ReferenceTables = stjpdacf::tables::DEFAULT;
    assert_eq!(COPY, DEFAULT);
    assert!(std::mem::size_of_val(&COPY) <= 4096);
}
