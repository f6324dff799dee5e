use super::*;
use nalgebra::SMatrix;

fn min_eig_corr(p: &SMatrix<f32, 4, 4>) -> f64 {
    let m = p.map(f64::from);
    let d = m.diagonal().map(|v| 1.0 / v.abs().sqrt());
    let c = SMatrix::<f64, 4, 4>::from_fn(|i, j| m[(i, j)] * d[i] * d[j]);
    c.symmetric_eigenvalues().min()
}

#[test]
fn repair_leaves_a_well_conditioned_covariance_alone() {
    let l = SMatrix::<f32, 4, 4>::new(
        2.0, 0.0, 0.0, 0.0, 0.5, 1.0, 0.0, 0.0, -0.3, 0.2, 0.7, 0.0, 0.1, 0.4, -0.2, 0.5,
    );
    let p = l * l.transpose();
    let mut q = p;
    assert_eq!(
        repair_psd::<4>(q.as_mut_slice(), 4, core::slice::from_ref(&(0..4))),
        0
    );
    assert_eq!(q, p);
}

#[test]
fn repair_makes_an_indefinite_covariance_psd_by_inflating_variances_only() {
    // Correlations of 0.99 between all of 0..3 and −0.99 between 0 and 3: indefinite, with
    // very different scales (as a posterior after a strongly informative update).
    let s = [1e-3f32, 2e-1, 5.0, 3e-4];
    let mut p = SMatrix::<f32, 4, 4>::from_fn(|i, j| {
        let rho = if i == j {
            1.0
        } else if (i, j) == (0, 3) || (i, j) == (3, 0) {
            -0.99
        } else {
            0.99
        };
        rho * (s[i] * s[j]).sqrt()
    });
    assert!(min_eig_corr(&p) < -0.5);
    let before = p;
    let raised = repair_psd::<4>(p.as_mut_slice(), 4, core::slice::from_ref(&(0..4)));
    assert!(raised > 0);
    assert!(min_eig_corr(&p) > 0.0, "{}", min_eig_corr(&p));
    for i in 0..4 {
        assert!(p[(i, i)] >= before[(i, i)]);
        // Bounded inflation (the ladder stops within eightfold of the shift needed): at most a
        // few times the variance.
        assert!(p[(i, i)] <= 10.0 * before[(i, i)], "{i}: {}", p[(i, i)]);
        for j in 0..4 {
            if i != j {
                assert_eq!(p[(i, j)], before[(i, j)]);
            }
        }
    }
}

#[test]
fn repair_touches_only_the_given_indices() {
    let mut p = SMatrix::<f32, 4, 4>::identity();
    p[(0, 2)] = 2.0;
    p[(2, 0)] = 2.0;
    p[(1, 1)] = -1.0;
    let before = p;
    assert!(repair_psd::<4>(p.as_mut_slice(), 4, &[0..1, 2..3]) > 0);
    assert_eq!(p[(1, 1)], -1.0);
    assert!(p[(0, 0)] > 1.0 || p[(2, 2)] > 1.0);
    assert_eq!(p[(0, 2)], before[(0, 2)]);
}

/// The information-form update equals the innovation-form update for the same independent
/// measurements at the index points (`c` = rows of the Gram eigenvectors, `ω = 1/(R_ii + r₀²)`).
#[test]
fn information_update_matches_the_innovation_form() {
    use crate::observation::LaneObservation;
    use crate::tables::DEFAULT;
    let mut f = TemporalFilter::<6, 16, 7, 84>::new();
    f.start_lane(&DEFAULT, 0, 0, &[0; 6]).unwrap();
    f.start_lane(&DEFAULT, 1, 1, &[0, 1, 0, 0, 0, 0]).unwrap();
    let mut obs = LaneObservation::<16>::EMPTY;
    let r = TemporalFilter::<6, 16, 7, 84>::r_used(&DEFAULT);
    let r0 = DEFAULT.hyper.pseudo_noise;
    let noise = 0.04f32;
    let mut jm = SMatrix::<f32, 7, 7>::zeros();
    let mut iv = nalgebra::SVector::<f32, 7>::zeros();
    for i in 0..16 {
        let z = -1.8 + 0.01 * i as f32 + 0.002 * (i * i) as f32;
        obs.present[i] = i % 3 != 1;
        obs.z[i] = z;
        obs.cov[(i, i)] = noise;
        if obs.present[i] {
            let om = 1.0 / (noise + r0);
            for j in 0..r {
                let cj = DEFAULT.gram_eigvec[(i, j)];
                iv[j] += om * z * cj;
                for k in 0..r {
                    jm[(j, k)] += om * cj * DEFAULT.gram_eigvec[(i, k)];
                }
            }
        }
    }
    let mut a = UpdateParts::<7, 84>::EMPTY;
    let mut b = UpdateParts::<7, 84>::EMPTY;
    f.prepare_update(&DEFAULT, 0, &obs, &mut a).unwrap();
    f.prepare_info_update(&DEFAULT, 0, &jm, &iv, &mut b)
        .unwrap();
    let scale_m = a.m.abs().max();
    let scale_w = a.w.abs().max();
    assert!(
        (a.m - b.m).abs().max() <= 2e-3 * scale_m,
        "M {} vs {}",
        a.m,
        b.m
    );
    assert!(
        (a.w - b.w).abs().max() <= 2e-3 * scale_w,
        "w {} vs {}",
        a.w,
        b.w
    );
}

/// The repair inflates every variance of a block by one factor (`1 + τ`, design §4.2.4), the
/// smallest of its ladder that factors: no single coefficient takes the correction, so a lane
/// known at its index points through correlated coefficients stays known there.
#[test]
fn repair_inflates_a_block_by_one_factor() {
    let s = [1e-3f32, 2e-1, 5.0, 3e-4];
    // Correlations 0.6 and one pair at 0.999 with a third at −0.9 to both: slightly indefinite.
    let rho = |i: usize, j: usize| -> f32 {
        match (i.min(j), i.max(j)) {
            (a, b) if a == b => 1.0,
            (0, 1) => 0.999,
            (0, 2) | (1, 2) => -0.9,
            _ => 0.6,
        }
    };
    let mut p = SMatrix::<f32, 4, 4>::from_fn(|i, j| rho(i, j) * (s[i] * s[j]).sqrt());
    let before = p;
    let e0 = min_eig_corr(&p);
    assert!(e0 < 0.0, "{e0}");
    assert!(repair_psd::<4>(p.as_mut_slice(), 4, core::slice::from_ref(&(0..4))) > 0);
    assert!(min_eig_corr(&p) > 0.0, "{}", min_eig_corr(&p));
    let f0 = p[(0, 0)] / before[(0, 0)];
    for i in 0..4 {
        let f = p[(i, i)] / before[(i, i)];
        assert!((f - f0).abs() <= 1e-5 * f0, "{i}: {f} vs {f0}");
        for j in 0..4 {
            if i != j {
                assert_eq!(p[(i, j)], before[(i, j)]);
            }
        }
    }
    // The shift is of the order of what the matrix needs (its eigenvalue −e0), not more than
    // the ladder's last step (eightfold) above it.
    let tau = f64::from(f0) - 1.0;
    assert!(
        tau > -e0 && tau < 16.0 * (-e0 + f64::from(REPAIR_PIVOT)),
        "τ {tau}, λ {e0}"
    );
}

/// One lane's broken block is repaired by shifting that lane only: the other lane's variances do
/// not move (coupled covariance, so the whole-covariance check runs too).
#[test]
fn repair_shifts_only_the_broken_lane() {
    use crate::tables::DEFAULT;
    let mut f = TemporalFilter::<6, 16, 7, 84>::new();
    f.start_lane(&DEFAULT, 0, 0, &[0; 6]).unwrap();
    f.start_lane(&DEFAULT, 1, 1, &[0, 1, 0, 0, 0, 0]).unwrap();
    f.force_coupled_loops();
    // Lane 0's first two position coefficients correlated beyond 1: its own block indefinite.
    let (a, b) = (
        TemporalFilter::<6, 16, 7, 84>::index(0, 0, 0),
        TemporalFilter::<6, 16, 7, 84>::index(0, 1, 0),
    );
    let c = 1.5 * (f.p[(a, a)] * f.p[(b, b)]).sqrt();
    f.p[(a, b)] = c;
    f.p[(b, a)] = c;
    let before = f.p;
    f.repair_due = true;
    assert!(f.repair_covariance(&DEFAULT) > 0);
    let lane = |s: usize| (0..14).map(move |k| s * 14 + k);
    for i in lane(1) {
        assert_eq!(f.p[(i, i)], before[(i, i)], "lane 1, entry {i}");
    }
    assert!(lane(0).all(|i| f.p[(i, i)] > before[(i, i)]));
    let idx: Vec<usize> = lane(0).chain(lane(1)).collect();
    let m = SMatrix::<f64, 28, 28>::from_fn(|i, j| {
        let (pi, pj) = (idx[i], idx[j]);
        f64::from(f.p[(pi, pj)]) / (f64::from(f.p[(pi, pi)]) * f64::from(f.p[(pj, pj)])).sqrt()
    });
    assert!(m.symmetric_eigenvalues().min() > 0.0);
}

/// A matrix far from PSD (correlations of 3) runs the whole ladder and takes the Gershgorin
/// shift, which is positive definite without a factorisation: `REPAIR_ATTEMPTS` failures.
#[test]
fn repair_falls_back_to_the_gershgorin_shift() {
    let s = [2.0f32, 0.5, 1e-2, 7.0];
    let mut p =
        SMatrix::<f32, 4, 4>::from_fn(|i, j| if i == j { 1.0 } else { 3.0 } * (s[i] * s[j]).sqrt());
    let before = p;
    assert!(min_eig_corr(&p) < -1.9);
    let failed = repair_psd::<4>(p.as_mut_slice(), 4, core::slice::from_ref(&(0..4)));
    assert_eq!(failed, REPAIR_ATTEMPTS);
    assert!(min_eig_corr(&p) > 0.0, "{}", min_eig_corr(&p));
    for i in 0..4 {
        // 1 + τ_G with τ_G = 3·3 − 1 + REPAIR_PIVOT.
        let f = p[(i, i)] / before[(i, i)];
        assert!((f - (9.0 + REPAIR_PIVOT)).abs() < 1e-4, "{i}: {f}");
    }
}
