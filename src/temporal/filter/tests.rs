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
