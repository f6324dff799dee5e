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
        // Bounded inflation (multipliers within ±1): at most a few times the variance.
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
