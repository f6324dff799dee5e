use super::*;
use nalgebra::SMatrix;

#[test]
fn event_count_matches_formula_for_full_gating() {
    // Σ_k C(D,k) C(m,k) k!: D = 3, m = 4 → 1 + 12 + 36 + 24 = 73.
    assert_eq!(count_events(&[0b1111u32; 3], 3, 1000), 73);
    assert_eq!(count_events(&[0b1111u32; 3], 3, 10), 11);
    assert_eq!(count_events(&[0b1111u32; 3], 3, 73), 73);
    // Shared single candidates: {}, {0→0}, {1→0}, {2→1}, {0→0, 2→1}, {1→0, 2→1}.
    assert_eq!(count_events(&[0b01u32, 0b01, 0b10], 3, 100), 6);
    assert_eq!(count_events(&[0u32; 3], 3, 100), 1);
    assert_eq!(count_events(&[0b111u32; 3], 0, 100), 1);
    assert_eq!(count_events(&[0b111u32; 3], 1, 100), 4);
}
/// Brute-force f64 oracle of a row step: every joint event, its weight from the joint
/// Gaussian, and the moment-matched mixture (docs/design.md §4.1), for `NS = 2` tracks.
#[allow(clippy::type_complexity, clippy::needless_range_loop)]
fn oracle(
    s: &Stacked<2, 3>,
    h: [f64; 2],
    z: &[f64],
    p: &RowParams,
) -> (Vec<f64>, Vec<Vec<f64>>, Vec<f64>, Vec<Vec<f64>>) {
    let n = s.len();
    let d = 2 * n;
    let x: Vec<f64> = (0..d)
        .map(|a| f64::from(s.mean(a / 2).unwrap()[a % 2]))
        .collect();
    let pm: Vec<Vec<f64>> = (0..d)
        .map(|a| {
            (0..d)
                .map(|b| f64::from(s.cov(a / 2, b / 2).unwrap()[(a % 2, b % 2)]))
                .collect()
        })
        .collect();
    // G[a][t] = (P Hᵀ)[a][t], S = H P Hᵀ + r I.
    let g: Vec<Vec<f64>> = (0..d)
        .map(|a| {
            (0..n)
                .map(|t| h[0] * pm[a][2 * t] + h[1] * pm[a][2 * t + 1])
                .collect()
        })
        .collect();
    let sb: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            (0..n)
                .map(|t| {
                    h[0] * g[2 * i][t]
                        + h[1] * g[2 * i + 1][t]
                        + if i == t { f64::from(p.r) } else { 0.0 }
                })
                .collect()
        })
        .collect();
    let zh: Vec<f64> = (0..n)
        .map(|t| h[0] * x[2 * t] + h[1] * x[2 * t + 1])
        .collect();
    let valid: Vec<Vec<usize>> = (0..n)
        .map(|t| {
            (0..z.len())
                .filter(|&j| (z[j] - zh[t]).powi(2) / sb[t][t] <= f64::from(p.gamma))
                .collect()
        })
        .collect();
    let miss = 1.0 - f64::from(p.pd) * f64::from(p.pg);
    let events = oracle_events(&valid);
    let mut lws = Vec::new();
    let mut posts = Vec::new();
    for e in &events {
        let idx: Vec<usize> = (0..n).filter(|&t| e[t].is_some()).collect();
        let k = idx.len();
        let (sinv, det) = oracle_inverse(&sb, &idx);
        let nu: Vec<f64> = idx.iter().map(|&t| z[e[t].unwrap()] - zh[t]).collect();
        let sn: Vec<f64> = (0..k)
            .map(|a| (0..k).map(|b| sinv[a][b] * nu[b]).sum())
            .collect();
        let q: f64 = (0..k).map(|a| nu[a] * sn[a]).sum();
        let lw = -0.5 * q - 0.5 * det.ln() - 0.5 * k as f64 * (2.0 * std::f64::consts::PI).ln()
            + k as f64 * (f64::from(p.pd) / f64::from(p.clutter_density)).ln()
            + (n - k) as f64 * miss.ln();
        // x_A = x + G_δ S⁻¹ ν, P_δ = P − G_δ S⁻¹ G_δᵀ.
        let xa: Vec<f64> = (0..d)
            .map(|a| x[a] + (0..k).map(|c| g[a][idx[c]] * sn[c]).sum::<f64>())
            .collect();
        let pa: Vec<Vec<f64>> = (0..d)
            .map(|a| {
                (0..d)
                    .map(|b| {
                        pm[a][b]
                            - (0..k)
                                .map(|c| {
                                    (0..k)
                                        .map(|c2| g[a][idx[c]] * sinv[c][c2] * g[b][idx[c2]])
                                        .sum::<f64>()
                                })
                                .sum::<f64>()
                    })
                    .collect()
            })
            .collect();
        lws.push(lw);
        posts.push((xa, pa));
    }
    let mx = lws.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let w: Vec<f64> = lws.iter().map(|l| (l - mx).exp()).collect();
    let tot: f64 = w.iter().sum();
    let mut bmiss = vec![0.0; n];
    let mut beta = vec![vec![0.0; z.len()]; n];
    let mut xm = vec![0.0; d];
    for (e, (wi, (xa, _))) in events.iter().zip(w.iter().zip(posts.iter())) {
        for t in 0..n {
            match e[t] {
                Some(j) => beta[t][j] += wi / tot,
                None => bmiss[t] += wi / tot,
            }
        }
        for a in 0..d {
            xm[a] += wi / tot * xa[a];
        }
    }
    let mut pmx = vec![vec![0.0; d]; d];
    for (wi, (xa, pa)) in w.iter().zip(posts.iter()) {
        for a in 0..d {
            for b in 0..d {
                pmx[a][b] += wi / tot * (pa[a][b] + (xa[a] - xm[a]) * (xa[b] - xm[b]));
            }
        }
    }
    (bmiss, beta, xm, pmx)
}

/// Every joint event of the oracle: `a[t] = Some(j)` (a point of `valid[t]`) or `None`, no
/// point used twice.
fn oracle_events(valid: &[Vec<usize>]) -> Vec<Vec<Option<usize>>> {
    let mut events: Vec<Vec<Option<usize>>> = vec![vec![]];
    for vt in valid {
        let mut next = Vec::new();
        for e in &events {
            next.push({
                let mut v = e.clone();
                v.push(None);
                v
            });
            for &j in vt {
                if !e.contains(&Some(j)) {
                    let mut v = e.clone();
                    v.push(Some(j));
                    next.push(v);
                }
            }
        }
        events = next;
    }
    events
}

/// The inverse and determinant of `sb` restricted to `idx`, by Gauss-Jordan.
#[allow(clippy::needless_range_loop)]
fn oracle_inverse(sb: &[Vec<f64>], idx: &[usize]) -> (Vec<Vec<f64>>, f64) {
    let k = idx.len();
    let mut m: Vec<Vec<f64>> = idx
        .iter()
        .enumerate()
        .map(|(ia, &a)| {
            let mut row: Vec<f64> = idx.iter().map(|&b| sb[a][b]).collect();
            row.extend((0..k).map(|c| if c == ia { 1.0 } else { 0.0 }));
            row
        })
        .collect();
    let mut det = 1.0;
    for c in 0..k {
        let piv = m[c][c];
        det *= piv;
        for v in m[c].iter_mut() {
            *v /= piv;
        }
        for r in 0..k {
            if r != c {
                let f = m[r][c];
                for q in 0..2 * k {
                    m[r][q] -= f * m[c][q];
                }
            }
        }
    }
    (m.iter().map(|r| r[k..].to_vec()).collect(), det)
}

/// Three coupled tracks with shared candidates, under ordinary and extreme parameters (the
/// extreme ones push the weights far from the first pass's reference, so the pass is redone):
/// β, the mean and the covariance match the f64 oracle.
#[test]
#[allow(clippy::needless_range_loop)]
fn row_step_matches_brute_force_oracle() {
    let mut s: Stacked<2, 3> = Stacked::new();
    let p0 = SMatrix::<f32, 2, 2>::new(1.0, 0.2, 0.2, 0.5);
    for (i, x0) in [-1.0f32, 0.2, 1.5].iter().enumerate() {
        s.push(SVector::from([*x0, 0.1 * i as f32]), &p0).unwrap();
    }
    let c01 = SMatrix::<f32, 2, 2>::new(0.6, 0.1, 0.1, 0.2);
    s.set_cross(0, 1, &c01);
    s.set_cross(1, 2, &c01);
    s.set_cross(0, 2, &(c01 * 0.5));
    let h = SVector::from([1.0f32, 1.0]);
    let pts = [-0.9f32, 0.0, 0.5, 1.4, 2.6];
    for (density, pd) in [(0.05f32, 0.9f32), (1e-30, 0.9), (1e-12, 0.999), (50.0, 0.5)] {
        let params = RowParams {
            clutter_density: density,
            pd,
            ..RowParams::default()
        };
        let mut st = s;
        let out = update(&mut st, &h, &pts, &params, 100_000);
        assert!(!out.failed && !out.approximated, "{density}");
        let z: Vec<f64> = pts.iter().map(|v| f64::from(*v)).collect();
        let (bmiss, beta, xm, pm) = oracle(&s, [1.0, 1.0], &z, &params);
        for t in 0..3 {
            assert!(
                (f64::from(out.beta_miss[t]) - bmiss[t]).abs() < 2e-5,
                "{density}: miss {t}"
            );
            for j in 0..pts.len() {
                assert!(
                    (f64::from(out.beta[t][j]) - beta[t][j]).abs() < 2e-5,
                    "{density}: β {t} {j}"
                );
            }
        }
        for a in 0..6 {
            let xv = f64::from(st.mean(a / 2).unwrap()[a % 2]);
            assert!(
                (xv - xm[a]).abs() < 1e-4,
                "{density}: x {a}: {xv} vs {}",
                xm[a]
            );
            for b in 0..6 {
                let pv = f64::from(st.cov(a / 2, b / 2).unwrap()[(a % 2, b % 2)]);
                assert!(
                    (pv - pm[a][b]).abs() < 1e-4,
                    "{density}: P {a} {b}: {pv} vs {}",
                    pm[a][b]
                );
            }
        }
    }
}

/// The row parameters of the cluster tests: clutter 0.2 /m, `P_D` = 0.8.
fn cluster_params() -> RowParams {
    RowParams {
        clutter_density: 0.2,
        pd: 0.8,
        ..RowParams::default()
    }
}

/// Six lanes 3.5 m apart with their points and clutter around them, `S̄_st = link` between
/// neighbours: association by [`associate`] with `(max_events, mode)`.
fn six_lane_row(link: f32, max_events: usize, mode: Association) -> RowOutcome<6> {
    let (zhat, sdiag, pts) = six_lanes(false);
    let params = cluster_params();
    associate::<6>(
        &zhat,
        &sdiag,
        |s, t| if t == s + 1 { link } else { 0.0 },
        6,
        &pts,
        &params,
        (max_events, mode),
        0,
    )
}

#[test]
fn uncorrelated_lanes_are_enumerated_cluster_by_cluster_exactly() {
    // Every lane has 3 candidates of its own: 4⁶ = 4096 events as one enumeration, 6 × 4 = 24
    // cluster by cluster. A link of 1e-30 (numerically nothing, but not zero) keeps one
    // enumeration: the marginals must agree.
    let split = six_lane_row(0.0, 100_000, Association::Exact);
    let joint = six_lane_row(1e-30, 100_000, Association::Exact);
    assert!(!split.failed && !joint.failed);
    assert_eq!(split.events, 24);
    assert_eq!(joint.events, 4096);
    for t in 0..6 {
        assert!(
            (split.beta_miss[t] - joint.beta_miss[t]).abs() < 1e-6,
            "{t}"
        );
        for j in 0..18 {
            assert!(
                (split.beta[t][j] - joint.beta[t][j]).abs() < 1e-6,
                "{t} {j}"
            );
        }
        let total: f32 = split.beta_miss[t] + split.beta[t].iter().sum::<f32>();
        assert!((total - 1.0).abs() < 1e-5, "{t}");
    }
    // Within the budget only as clusters: exact, not approximated, under both modes.
    for mode in [Association::Exact, Association::ExactOrLbp] {
        let small = six_lane_row(0.0, 512, mode);
        assert!(!small.approximated && small.lbp_iterations == 0, "{mode:?}");
        assert_eq!(small.events, 24);
        assert_eq!(small.beta, split.beta);
        // Correlated lanes stay one enumeration, over the budget.
        let coupled = six_lane_row(0.01, 512, mode);
        assert!(coupled.approximated, "{mode:?}");
    }
}

/// Four uncorrelated tracks 3.5 m apart, three candidates each, `link` on the neighbours'
/// cross-covariances: one row step with `(max_events, skip)`.
fn four_track_step(link: f32, max_events: usize, skip: u32) -> (Stacked<2, 4>, RowOutcome<4>) {
    let mut s: Stacked<2, 4> = Stacked::new();
    for i in 0..4 {
        let p0 = SMatrix::<f32, 2, 2>::new(0.3 + 0.05 * i as f32, 0.05, 0.05, 0.1);
        s.push(SVector::from([-5.25 + 3.5 * i as f32, 0.02]), &p0)
            .unwrap();
    }
    for i in 0..3 {
        s.set_cross(i, i + 1, &(SMatrix::<f32, 2, 2>::identity() * link));
    }
    let mut pts = [0.0f32; 12];
    for i in 0..4 {
        let z = -5.25 + 3.5 * i as f32;
        pts[3 * i] = z + 0.1 * (i as f32 - 1.5);
        pts[3 * i + 1] = z - 0.45 + 0.03 * i as f32;
        pts[3 * i + 2] = z + 0.5;
    }
    let params = cluster_params();
    let h = SVector::from([1.0f32, 1.0]);
    let mut st = s;
    let out = update_masked(&mut st, &h, &pts, &params, max_events, skip);
    (st, out)
}

#[test]
fn uncorrelated_tracks_update_cluster_by_cluster_exactly() {
    // 4⁴ = 256 events as one enumeration, 4 × 4 = 16 as clusters; a link of 1e-30 keeps one.
    for skip in [0u32, 0b0100] {
        let (split, so) = four_track_step(0.0, 100_000, skip);
        let (joint, jo) = four_track_step(1e-30, 100_000, skip);
        assert!(!so.failed && !jo.failed);
        let active = 4 - skip.count_ones();
        assert_eq!(so.events, 4 * active);
        assert_eq!(jo.events, 4u32.pow(active));
        for t in 0..4 {
            assert!((so.beta_miss[t] - jo.beta_miss[t]).abs() < 1e-6, "{t}");
            for j in 0..12 {
                assert!((so.beta[t][j] - jo.beta[t][j]).abs() < 1e-6, "{t} {j}");
            }
            let dx = split.mean(t).unwrap() - joint.mean(t).unwrap();
            assert!(dx.amax() < 1e-5, "{t}: {dx}");
            for u in 0..4 {
                let dp = split.cov(t, u).unwrap() - joint.cov(t, u).unwrap();
                assert!(dp.amax() < 1e-5, "{t} {u}: {dp}");
            }
            // The posterior moved (the step did something) and stayed uncorrelated.
            if skip & (1 << t) == 0 {
                assert!(so.beta_miss[t] < 0.9, "{t}");
            }
            for u in (0..4).filter(|&u| u != t) {
                assert_eq!(split.cov(t, u).unwrap().amax(), 0.0, "{t} {u}");
            }
        }
        // Within a budget of 64 only as clusters: not approximated, the same numbers.
        let (small, sm) = four_track_step(0.0, 64, skip);
        assert!(!sm.approximated);
        assert_eq!(sm.beta, so.beta);
        for t in 0..4 {
            assert_eq!(small.mean(t), split.mean(t));
        }
        let (_, coupled) = four_track_step(0.01, 64, skip);
        assert_eq!(coupled.approximated, skip == 0, "{skip}");
    }
}

/// A row sequence through one kept outcome and scratch gives every row's outcome (and state)
/// exactly as a fresh one does: the resets clear all that the rows before wrote. The rows vary
/// in tracks, points, clusters, the budget (LBP and pruning), the event scale's redo and
/// failures.
#[test]
fn kept_outcome_and_scratch_equal_fresh_ones_row_after_row() {
    let params = cluster_params();
    let mut seed = 0x2545_f491_u32;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        (seed >> 8) as f32 / (1u32 << 24) as f32
    };
    let h = SVector::from([1.0f32, 1.0]);
    let (mut out_a, mut scratch_a) = (RowOutcome::<4>::default(), Scratch::<4>::new());
    let (mut out_u, mut scratch_u) = (RowOutcome::<4>::default(), Scratch::<4>::new());
    let mut kinds = [0u32; 4];
    for row in 0..400 {
        let n = (next() * 5.0) as usize % 5;
        let m = (next() * 14.0) as usize;
        let link = if next() < 0.5 { 0.0 } else { 0.02 };
        let mut s: Stacked<2, 4> = Stacked::new();
        for i in 0..n {
            let v = if row % 37 == 5 {
                -1.0
            } else {
                0.05 + 0.3 * next()
            };
            let p0 = SMatrix::<f32, 2, 2>::new(v, 0.01, 0.01, 0.05);
            let _ = s.push(SVector::from([-3.0 + 2.0 * i as f32, 0.0]), &p0);
        }
        for i in 0..n.saturating_sub(1) {
            s.set_cross(i, i + 1, &(SMatrix::<f32, 2, 2>::identity() * link));
        }
        let pts: Vec<f32> = (0..m)
            .map(|_| {
                if row % 53 == 7 {
                    f32::NAN
                } else {
                    -4.0 + 7.0 * next()
                }
            })
            .collect();
        let budget = if row % 3 == 0 { 8 } else { 512 };
        let mode = [
            Association::Exact,
            Association::ExactOrLbp,
            Association::Lbp,
        ][row % 3];
        let skip = if row % 5 == 0 { 0b10 } else { 0 };
        // The known-lane form.
        let zhat: [f32; 4] = core::array::from_fn(|t| -3.0 + 2.0 * t as f32 + 0.2 * next());
        let sdiag: [f32; 4] = core::array::from_fn(|_| 0.05 + 0.4 * next());
        let cross = |a: usize, b: usize| if b == a + 1 { link } else { 0.0 };
        let fresh = associate(&zhat, &sdiag, cross, n, &pts, &params, (budget, mode), skip);
        associate_into(
            (&mut out_a, &mut scratch_a),
            &zhat,
            &sdiag,
            cross,
            n,
            &pts,
            (&params, &[0.0; 4]),
            (budget, mode),
            skip,
        );
        assert_eq!(out_a, fresh, "associate, row {row}");
        // The state-update form.
        let mut s_fresh = s;
        let fresh = update_masked(&mut s_fresh, &h, &pts, &params, budget, skip);
        update_into(
            (&mut out_u, &mut scratch_u),
            &mut s,
            &h,
            &pts,
            &params,
            (budget, skip),
            &mut NoProbe,
        );
        assert_eq!(out_u, fresh, "update, row {row}");
        for t in 0..n {
            assert_eq!(s.mean(t), s_fresh.mean(t), "row {row} track {t}");
        }
        kinds[0] += u32::from(fresh.failed);
        kinds[1] += u32::from(fresh.approximated);
        kinds[2] += u32::from(out_a.lbp_iterations > 0);
        kinds[3] += u32::from(fresh.events > 1 && !fresh.failed);
    }
    // The sequence met every path.
    assert!(kinds.iter().all(|&k| k > 0), "{kinds:?}");
}

/// Six lanes 3.5 m apart (`ẑ`, `S̄_tt`) with three points each; with `shared`, two of them
/// moved between neighbouring lanes (so that LBP iterates).
fn six_lanes(shared: bool) -> ([f32; 6], [f32; 6], [f32; 18]) {
    let zhat: [f32; 6] = core::array::from_fn(|t| -8.75 + 3.5 * t as f32);
    let sdiag = [0.09f32, 0.12, 0.1, 0.15, 0.11, 0.2];
    let mut pts = [0.0f32; 18];
    for (t, z) in zhat.iter().enumerate() {
        pts[3 * t] = z + 0.05 * (t as f32 - 2.0);
        pts[3 * t + 1] = z - 0.31 + 0.02 * t as f32;
        pts[3 * t + 2] = z + 0.42;
    }
    if shared {
        pts[2] = -5.3;
        pts[8] = 0.0;
    }
    (zhat, sdiag, pts)
}

/// `ln(P_D / miss)`: the detection odds' `P_D`-dependent part.
fn ln_odds(p: &RowParams, pd: f32) -> f32 {
    libm::logf(pd) - libm::logf(p.miss_at(pd))
}

/// The six-lane row of [`six_lane_row`] associated with per-lane odds offsets `odds`.
fn six_lane_row_with_odds(
    link: f32,
    (params, odds): (&RowParams, &[f32; 6]),
    (max_events, mode): (usize, Association),
) -> RowOutcome<6> {
    let (zhat, sdiag, pts) = six_lanes(true);
    let (mut out, mut scratch) = (RowOutcome::<6>::default(), Scratch::<6>::new());
    associate_into(
        (&mut out, &mut scratch),
        &zhat,
        &sdiag,
        |s, t| if t == s + 1 { link } else { 0.0 },
        6,
        &pts,
        (params, odds),
        (max_events, mode),
        0,
    );
    out
}

/// One odds offset for every lane is the same row at another `P_D` (the miss factors the
/// offset leaves out are common to all events): exact enumeration, clusters, pruning and LBP.
#[test]
fn a_common_odds_offset_is_a_change_of_the_rows_pd() {
    let at = RowParams {
        pd: 0.4,
        gamma: 16.0,
        ..cluster_params()
    };
    let base = cluster_params();
    let odds = [ln_odds(&at, 0.4) - ln_odds(&base, base.pd); 6];
    for (link, budget, mode) in [
        (0.0, 512, Association::Exact),
        (0.02, 512, Association::Exact),
        (0.02, 20, Association::Exact),
        (0.02, 20, Association::ExactOrLbp),
        (0.0, 512, Association::Lbp),
    ] {
        let want = six_lane_row_with_odds(link, (&at, &[0.0; 6]), (budget, mode));
        let base = RowParams {
            gamma: 16.0,
            ..base
        };
        let got = six_lane_row_with_odds(link, (&base, &odds), (budget, mode));
        assert!(!want.failed && !got.failed);
        assert_eq!(
            (want.approximated, want.events, want.lbp_iterations > 0),
            (got.approximated, got.events, got.lbp_iterations > 0),
            "{link} {budget} {mode:?}"
        );
        for t in 0..6 {
            assert!(
                (want.beta_miss[t] - got.beta_miss[t]).abs() < 1e-5,
                "{mode:?} {t}"
            );
            for j in 0..18 {
                assert!(
                    (want.beta[t][j] - got.beta[t][j]).abs() < 1e-5,
                    "{mode:?} {t} {j}"
                );
            }
        }
    }
}

/// Per-lane `P_D` by the odds offsets: `β` of the exact enumeration against an f64 oracle
/// that weighs each lane's detections at its own `P_D` and its misses at its own miss factor.
#[test]
#[allow(clippy::needless_range_loop)]
fn per_lane_pd_matches_the_oracle() {
    let params = RowParams {
        gamma: 16.0,
        ..cluster_params()
    };
    let pds = [0.9f32, 0.2, 0.55, 0.8, 0.3, 0.7];
    let odds: [f32; 6] =
        core::array::from_fn(|t| ln_odds(&params, pds[t]) - ln_odds(&params, params.pd));
    for link in [0.0f32, 0.02] {
        let got = six_lane_row_with_odds(link, (&params, &odds), (1 << 20, Association::Exact));
        assert!(!got.failed && !got.approximated);
        // The oracle: every joint event of the gated candidates.
        let (zh32, sd32, z32) = six_lanes(true);
        let zhat: Vec<f64> = zh32.iter().map(|v| f64::from(*v)).collect();
        let z: Vec<f64> = z32.iter().map(|v| f64::from(*v)).collect();
        let sb: Vec<Vec<f64>> = (0..6)
            .map(|a| {
                (0..6)
                    .map(|b| {
                        if a == b {
                            f64::from(sd32[a])
                        } else if b == a + 1 || a == b + 1 {
                            f64::from(link)
                        } else {
                            0.0
                        }
                    })
                    .collect()
            })
            .collect();
        let valid: Vec<Vec<usize>> = (0..6)
            .map(|t| {
                (0..18)
                    .filter(|&j| (z[j] - zhat[t]).powi(2) / sb[t][t] <= f64::from(params.gamma))
                    .collect()
            })
            .collect();
        let lam = f64::from(params.clutter_density);
        let pg = f64::from(params.pg);
        let events = oracle_events(&valid);
        let mut lws = Vec::new();
        for e in &events {
            let idx: Vec<usize> = (0..6).filter(|&t| e[t].is_some()).collect();
            let (sinv, det) = oracle_inverse(&sb, &idx);
            let nu: Vec<f64> = idx.iter().map(|&t| z[e[t].unwrap()] - zhat[t]).collect();
            let q: f64 = (0..idx.len())
                .map(|a| nu[a] * (0..idx.len()).map(|b| sinv[a][b] * nu[b]).sum::<f64>())
                .sum();
            let mut lw = -0.5 * q
                - 0.5 * det.ln()
                - 0.5 * idx.len() as f64 * (2.0 * std::f64::consts::PI).ln();
            for t in 0..6 {
                let pd = f64::from(pds[t]);
                lw += if e[t].is_some() {
                    (pd / lam).ln()
                } else {
                    (1.0 - pd * pg).ln()
                };
            }
            lws.push(lw);
        }
        let mx = lws.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let tot: f64 = lws.iter().map(|l| (l - mx).exp()).sum();
        let mut bmiss = [0.0f64; 6];
        let mut beta = [[0.0f64; 18]; 6];
        for (e, l) in events.iter().zip(lws.iter()) {
            let w = (l - mx).exp() / tot;
            for t in 0..6 {
                match e[t] {
                    Some(j) => beta[t][j] += w,
                    None => bmiss[t] += w,
                }
            }
        }
        for t in 0..6 {
            assert!(
                (f64::from(got.beta_miss[t]) - bmiss[t]).abs() < 1e-4,
                "{link} {t}"
            );
            for j in 0..18 {
                assert!(
                    (f64::from(got.beta[t][j]) - beta[t][j]).abs() < 1e-4,
                    "{link} {t} {j}"
                );
            }
        }
        // The weak lanes lose the points they share with strong ones.
        assert!(got.beta_miss[1] > got.beta_miss[0]);
    }
}
