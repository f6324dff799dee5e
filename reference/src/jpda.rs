//! Spatial JPDA and the coupled JPDACF, one row step, in f64 (docs/design.md §4.1).
//!
//! This is the oracle for the embedded core: it enumerates **all** joint association events (no
//! bound `E`, no clustering), so it is exact and only meant for small scenarios. Measurements are
//! scalar (`nz = 1`, a lateral position). With `D` tracks of state size `nx` the stacked state is
//! `x̄ = [x¹; …; x^D]` (target-major), `H̄ = I_D ⊗ H` and `R̄ = r I_D`.
//!
//! Conventions (shared with the golden file `data/golden/jpda_marginals.json`):
//! - gating is inclusive, `d² = (z − H x_d)² / S_d ≤ γ` with `S_d = H P̄_dd Hᵀ + r`;
//! - an [`Event`] holds, per track, `Some(j)` (measurement `j`, 0-based) or `None` (missed);
//!   events are listed in lexicographic order over the tracks (track 0 most significant), with the
//!   miss before the measurements, ascending;
//! - `beta[d][0]` is P(track `d` missed) and `beta[d][1 + j]` is P(measurement `j` is from `d`).
//!
//! The independent JPDA is the special case of a block-diagonal `P̄` (no cross-covariance between
//! tracks, e.g. `B = I`): see [`stack_tracks`] and [`block_diagonal`].

use std::collections::BTreeMap;
use std::f64::consts::PI;

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};

/// The probability factor of a missed track.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MissConvention {
    /// Textbook JPDA: `1 − P_D`.
    Textbook,
    /// `1 − P_D P_G`, which accounts for a detection that fell outside the gate (docs/design.md §4.1 uses
    /// this; Stone Soup too).
    Pg,
}

impl MissConvention {
    /// The miss factor for detection probability `pd` and gate probability `pg`.
    pub fn miss_factor(self, pd: f64, pg: f64) -> f64 {
        match self {
            MissConvention::Textbook => 1.0 - pd,
            MissConvention::Pg => 1.0 - pd * pg,
        }
    }
}

/// Parameters of one row step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowParams {
    /// Detection probability `P_D`.
    pub pd: f64,
    /// Gate probability `P_G` (only used by [`MissConvention::Pg`]).
    pub pg: f64,
    /// Gate threshold `γ` on the squared Mahalanobis distance (inclusive).
    pub gamma: f64,
    /// Poisson clutter density `λ_c` per unit of `x`.
    pub clutter_density: f64,
    /// Measurement noise variance `r` (`R̄ = r I`).
    pub r: f64,
    /// Which miss factor to use.
    pub miss: MissConvention,
}

/// A joint association event: for each track, the measurement it takes or `None` if missed.
pub type Event = Vec<Option<usize>>;

/// A mean and covariance.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Mean.
    pub x: DVector<f64>,
    /// Covariance.
    pub p: DMatrix<f64>,
}

/// Per-track gating on the marginal of each track (docs/design.md §4.1 step 2).
#[derive(Debug, Clone, PartialEq)]
pub struct Gating {
    /// Predicted measurement `ẑ_d = H x̄_d` per track.
    pub zhat: Vec<f64>,
    /// Marginal innovation variance `S_d = H P̄_dd Hᵀ + r` per track.
    pub s: Vec<f64>,
    /// `d2[d][j] = (z_j − ẑ_d)² / S_d`.
    pub d2: Vec<Vec<f64>>,
    /// `valid[d][j]`: measurement `j` is in the gate of track `d` (`d2 ≤ γ`).
    pub valid: Vec<Vec<bool>>,
}

/// Everything one exact row step computes.
#[derive(Debug, Clone, PartialEq)]
pub struct RowResult {
    /// The gating of every (track, measurement) pair.
    pub gating: Gating,
    /// Joint innovation covariance of all tracks, `S̄ = H̄ P̄ H̄ᵀ + r I` (`D × D`).
    pub sbar: DMatrix<f64>,
    /// All joint events, in the order described in the module documentation.
    pub events: Vec<Event>,
    /// Unnormalised log weight of each event (docs/design.md §4.1 step 3).
    pub log_weights: Vec<f64>,
    /// Normalised event probabilities `β_A`.
    pub event_probs: Vec<f64>,
    /// Marginal association probabilities, `beta[d][0]` = missed, `beta[d][1 + j]` = measurement `j`.
    pub beta: Vec<Vec<f64>>,
    /// Probability of the event in which every track is missed.
    pub beta0_all_missed: f64,
    /// Full stacked gain `G = P̄ H̄ᵀ S̄⁻¹` (`D·nx × D`), used by the `paper` and `masked` updates.
    pub gain: DMatrix<f64>,
    /// Combined innovation per track, `v̄_d = Σ_j β_dj (z_j − ẑ_d)`.
    pub vbar: DVector<f64>,
    /// `P_c = P̄ − G S̄ Gᵀ`, the covariance after a full detection of every track.
    pub pc: DMatrix<f64>,
    /// Exact moment matching of the event mixture (docs/design.md §4.1 step 4; the design's update).
    pub mixture: Estimate,
    /// The paper's update (Eqs. 29–31 carried to the stacked state, docs/design.md §9): `x̄ + G v̄` and
    /// `β₀ P̄ + (1 − β₀) P_c + G (Σ_A β_A ν_A ν_Aᵀ − v̄ v̄ᵀ) Gᵀ` with `β₀` = all missed.
    pub paper: Estimate,
    /// The stacked gain masked per event: each event uses `K_A = G M_A` (`M_A = diag(δ(A))`),
    /// `x̄_A = x̄ + G M_A ν_A` and the Joseph covariance of that (suboptimal) gain,
    /// `(I − K_A H̄) P̄ (I − K_A H̄)ᵀ + K_A R̄ K_Aᵀ`; the mixture is then moment matched. In closed
    /// form: `x̄ + G v̄` and `P̄ − G Λ S̄ Gᵀ − G S̄ Λ Gᵀ + G (S̄ ∘ Π) Gᵀ + G (Σ_A β_A ν_A ν_Aᵀ − v̄ v̄ᵀ) Gᵀ`
    /// with `Π_st = P(s and t detected)` and `Λ = diag(Π)`.
    pub masked: Estimate,
    /// Independent per-track PDA update of each track's marginal with the marginal `β`
    /// (the classic JPDA update; with a block-diagonal `P̄` it is the exact independent answer).
    pub pda: Vec<Estimate>,
}

/// `H̄ = I_D ⊗ H`.
pub fn stack_h(d: usize, h: &DMatrix<f64>) -> DMatrix<f64> {
    DMatrix::<f64>::identity(d, d).kronecker(h)
}

/// Stacks per-track means and covariances into `x̄` and a block-diagonal `P̄` (independent tracks).
/// `None` if the slices have different lengths or the tracks different state sizes.
pub fn stack_tracks(
    xs: &[DVector<f64>],
    ps: &[DMatrix<f64>],
) -> Option<(DVector<f64>, DMatrix<f64>)> {
    if xs.len() != ps.len() {
        return None;
    }
    let nx = xs.first().map_or(0, |x| x.len());
    let n = nx * xs.len();
    let mut xbar = DVector::zeros(n);
    let mut pbar = DMatrix::zeros(n, n);
    for (d, (x, p)) in xs.iter().zip(ps).enumerate() {
        if x.len() != nx || p.nrows() != nx || p.ncols() != nx {
            return None;
        }
        xbar.rows_mut(d * nx, nx).copy_from(x);
        pbar.view_mut((d * nx, d * nx), (nx, nx)).copy_from(p);
    }
    Some((xbar, pbar))
}

/// Keeps only the `nx × nx` diagonal blocks of `P̄` (drops the cross-covariances between tracks).
pub fn block_diagonal(pbar: &DMatrix<f64>, nx: usize) -> DMatrix<f64> {
    let n = pbar.nrows();
    DMatrix::from_fn(n, n, |i, j| {
        if nx > 0 && i / nx == j / nx {
            pbar[(i, j)]
        } else {
            0.0
        }
    })
}

/// docs/design.md §4.1 step 1: `x̄ ← (I_D ⊗ F) x̄`, `P̄ ← (I_D ⊗ F) P̄ (I_D ⊗ F)ᵀ + B ⊗ Q`.
pub fn predict(
    xbar: &DVector<f64>,
    pbar: &DMatrix<f64>,
    f: &DMatrix<f64>,
    q: &DMatrix<f64>,
    b: &DMatrix<f64>,
) -> Estimate {
    let fbar = DMatrix::<f64>::identity(b.nrows(), b.nrows()).kronecker(f);
    let p = &fbar * pbar * fbar.transpose() + b.kronecker(q);
    Estimate {
        x: &fbar * xbar,
        p: (&p + p.transpose()) * 0.5,
    }
}

/// docs/design.md §4.1 step 2: gate every measurement against every track on the track's marginal.
/// `h` is the `1 × nx` measurement row of one track.
pub fn gate(
    xbar: &DVector<f64>,
    pbar: &DMatrix<f64>,
    h: &DMatrix<f64>,
    r: f64,
    zs: &[f64],
    gamma: f64,
) -> Gating {
    let nx = h.ncols();
    let d = xbar.len().checked_div(nx).unwrap_or(0);
    let mut g = Gating {
        zhat: Vec::new(),
        s: Vec::new(),
        d2: Vec::new(),
        valid: Vec::new(),
    };
    for t in 0..d {
        let xt = xbar.rows(t * nx, nx);
        let pt = pbar.view((t * nx, t * nx), (nx, nx));
        let zhat = (h * xt)[(0, 0)];
        let s = (h * pt * h.transpose())[(0, 0)] + r;
        let d2: Vec<f64> = zs.iter().map(|z| (z - zhat) * (z - zhat) / s).collect();
        g.valid.push(d2.iter().map(|&v| v <= gamma).collect());
        g.d2.push(d2);
        g.zhat.push(zhat);
        g.s.push(s);
    }
    g
}

/// docs/design.md §4.1 step 3: every joint event given the validation matrix `valid[d][j]` (each track takes
/// at most one valid measurement, each measurement at most one track), in lexicographic order
/// (track 0 most significant; miss first, then measurements ascending).
pub fn enumerate_events(valid: &[Vec<bool>]) -> Vec<Event> {
    fn rec(
        valid: &[Vec<bool>],
        t: usize,
        used: &mut Vec<bool>,
        cur: &mut Event,
        out: &mut Vec<Event>,
    ) {
        let Some(row) = valid.get(t) else {
            out.push(cur.clone());
            return;
        };
        cur.push(None);
        rec(valid, t + 1, used, cur, out);
        cur.pop();
        for (j, &ok) in row.iter().enumerate() {
            if ok && !used.get(j).copied().unwrap_or(true) {
                used[j] = true;
                cur.push(Some(j));
                rec(valid, t + 1, used, cur, out);
                cur.pop();
                used[j] = false;
            }
        }
    }
    let m = valid.iter().map(Vec::len).max().unwrap_or(0);
    let mut out = Vec::new();
    rec(valid, 0, &mut vec![false; m], &mut Vec::new(), &mut out);
    out
}

/// Number of joint events when every measurement is valid for every track:
/// `Σ_k C(D, k) C(m, k) k!` (partial injections of `k` tracks into `m` measurements).
pub fn count_events_full_gating(d: usize, m: usize) -> u128 {
    let mut total = 0u128;
    // term_k = C(d, k) · m!/(m − k)!, built incrementally.
    let mut term = 1u128;
    for k in 0..=d.min(m) {
        total += term;
        let k = k as u128;
        term = term * (d as u128 - k) / (k + 1) * (m as u128 - k);
    }
    total
}

/// The detection pattern `δ(A)`: which tracks are detected in the event.
pub fn detection_pattern(event: &[Option<usize>]) -> Vec<bool> {
    event.iter().map(Option::is_some).collect()
}

/// Per-pattern quantities (factorised once per detection pattern and cached).
struct Pattern {
    /// Indices of the detected tracks, ascending.
    det: Vec<usize>,
    /// `ln det S_δ`.
    log_det: f64,
    /// Cholesky factor of `S_δ`.
    chol: Option<Cholesky<f64, Dyn>>,
    /// `K_δ = P̄ H_δᵀ S_δ⁻¹`.
    gain: DMatrix<f64>,
    /// `P_δ = P̄ − K_δ S_δ K_δᵀ`.
    p: DMatrix<f64>,
}

impl Pattern {
    fn new(
        pattern: &[bool],
        pbar: &DMatrix<f64>,
        sbar: &DMatrix<f64>,
        pht: &DMatrix<f64>,
    ) -> Option<Self> {
        let det: Vec<usize> = pattern
            .iter()
            .enumerate()
            .filter(|(_, &b)| b)
            .map(|(i, _)| i)
            .collect();
        if det.is_empty() {
            return Some(Pattern {
                det,
                log_det: 0.0,
                chol: None,
                gain: DMatrix::zeros(pbar.nrows(), 0),
                p: pbar.clone(),
            });
        }
        let s = sbar.select_rows(&det).select_columns(&det);
        let pht_d = pht.select_columns(&det);
        let chol = s.clone().cholesky()?;
        let log_det = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
        // K = P Hᵀ S⁻¹  ⇔  S Kᵀ = H P  (S symmetric).
        let gain = chol.solve(&pht_d.transpose()).transpose();
        let p = pbar - &gain * &s * gain.transpose();
        let p = (&p + p.transpose()) * 0.5;
        Some(Pattern {
            det,
            log_det,
            chol: Some(chol),
            gain,
            p,
        })
    }
}

/// Maps an innovation per detected track to `ln N(ν; 0, S_δ)`.
fn log_normal(pat: &Pattern, nu: &DVector<f64>) -> f64 {
    match &pat.chol {
        None => 0.0,
        Some(chol) => {
            let k = nu.len() as f64;
            let w = chol.solve(nu);
            -0.5 * (k * (2.0 * PI).ln() + pat.log_det + nu.dot(&w))
        }
    }
}

/// One exact row step of the coupled JPDACF (docs/design.md §4.1 steps 2–4), after the prediction.
///
/// `xbar`, `pbar`: predicted stacked state and covariance (`D·nx`); `h`: the `1 × nx` measurement
/// row of one track; `zs`: the row's measurements. A block-diagonal `pbar` gives the independent
/// JPDA. Returns `None` if the dimensions disagree, an `S_δ` is not positive definite, or every
/// event has zero weight.
pub fn row_step(
    xbar: &DVector<f64>,
    pbar: &DMatrix<f64>,
    h: &DMatrix<f64>,
    zs: &[f64],
    params: &RowParams,
) -> Option<RowResult> {
    let d = if h.ncols() == 0 {
        0
    } else {
        xbar.len() / h.ncols()
    };
    row_step_with_pd(xbar, pbar, h, zs, params, &vec![params.pd; d])
}

/// [`row_step`] with a detection probability per track (`pd[t]`, in place of `params.pd`;
/// docs/design.md §11.3): a detected track's factor is `pd[t] / λ_c` and a missed one's its
/// miss factor at `pd[t]`. `None` as [`row_step`], or when `pd` does not hold one value per track.
pub fn row_step_with_pd(
    xbar: &DVector<f64>,
    pbar: &DMatrix<f64>,
    h: &DMatrix<f64>,
    zs: &[f64],
    params: &RowParams,
    pd: &[f64],
) -> Option<RowResult> {
    let nx = h.ncols();
    if h.nrows() != 1 || nx == 0 || xbar.len() % nx != 0 {
        return None;
    }
    if pbar.nrows() != xbar.len() || pbar.ncols() != xbar.len() {
        return None;
    }
    let d = xbar.len() / nx;
    if pd.len() != d {
        return None;
    }
    let m = zs.len();
    let hbar = stack_h(d, h);
    let pht = pbar * hbar.transpose();
    let sbar = &hbar * &pht + DMatrix::<f64>::identity(d, d) * params.r;
    let sbar = (&sbar + sbar.transpose()) * 0.5;
    let zhat_all = &hbar * xbar;

    let gating = gate(xbar, pbar, h, params.r, zs, params.gamma);
    let events = enumerate_events(&gating.valid);

    // Step 3: log weights, one factorisation per detection pattern.
    let ln_pd: Vec<f64> = pd.iter().map(|p| p.ln()).collect();
    let ln_miss: Vec<f64> = pd
        .iter()
        .map(|&p| params.miss.miss_factor(p, params.pg).ln())
        .collect();
    let ln_lambda = params.clutter_density.ln();
    let mut cache: BTreeMap<Vec<bool>, Pattern> = BTreeMap::new();
    let mut log_weights = Vec::with_capacity(events.len());
    // Stacked per-track innovation of each event (zero for missed tracks), and its x̄_A.
    let mut innovations: Vec<DVector<f64>> = Vec::with_capacity(events.len());
    let mut means: Vec<DVector<f64>> = Vec::with_capacity(events.len());
    for ev in &events {
        let pat = cache_or_new(&mut cache, &detection_pattern(ev), pbar, &sbar, &pht)?;
        let mut nu_full = DVector::zeros(d);
        let mut nu = DVector::zeros(pat.det.len());
        for (k, &t) in pat.det.iter().enumerate() {
            let j = (*ev.get(t)?)?;
            let v = zs.get(j)? - zhat_all[t];
            nu[k] = v;
            nu_full[t] = v;
        }
        // Summed per track (not `n · ln p`) so that a zero factor gives −∞, never 0 · (−∞) = NaN.
        let lw = log_normal(pat, &nu)
            + ev.iter()
                .enumerate()
                .map(|(t, a)| {
                    if a.is_some() {
                        ln_pd[t] - ln_lambda
                    } else {
                        ln_miss[t]
                    }
                })
                .sum::<f64>();
        log_weights.push(lw);
        means.push(xbar + &pat.gain * &nu);
        innovations.push(nu_full);
    }
    let max_lw = log_weights
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    if !max_lw.is_finite() {
        return None;
    }
    let unnorm: Vec<f64> = log_weights.iter().map(|w| (w - max_lw).exp()).collect();
    let total: f64 = unnorm.iter().sum();
    let event_probs: Vec<f64> = unnorm.iter().map(|w| w / total).collect();

    // Marginals.
    let mut beta = vec![vec![0.0; m + 1]; d];
    let mut beta0_all_missed = 0.0;
    for (ev, &p) in events.iter().zip(&event_probs) {
        if ev.iter().all(Option::is_none) {
            beta0_all_missed += p;
        }
        for (row, a) in beta.iter_mut().zip(ev) {
            let col = a.map_or(0, |j| j + 1);
            if let Some(b) = row.get_mut(col) {
                *b += p;
            }
        }
    }

    // Step 4: exact moment matching of the mixture.
    let n = xbar.len();
    let mut x_mix = DVector::zeros(n);
    for (x_a, &p) in means.iter().zip(&event_probs) {
        x_mix += x_a * p;
    }
    let mut p_mix = DMatrix::zeros(n, n);
    for ((ev, x_a), &p) in events.iter().zip(&means).zip(&event_probs) {
        let pat = cache.get(&detection_pattern(ev))?;
        let dx = x_a - &x_mix;
        p_mix += (&pat.p + &dx * dx.transpose()) * p;
    }
    let mixture = Estimate {
        x: x_mix,
        p: (&p_mix + p_mix.transpose()) * 0.5,
    };

    // The stacked-gain forms (paper / masked).
    let full = cache_or_new(&mut cache, &vec![true; d], pbar, &sbar, &pht)?;
    let gain = full.gain.clone();
    let pc = full.p.clone();
    let vbar = DVector::from_fn(d, |t, _| {
        beta.get(t)
            .map(|row| {
                row.iter()
                    .skip(1)
                    .zip(zs)
                    .map(|(b, z)| b * (z - zhat_all[t]))
                    .sum()
            })
            .unwrap_or(0.0)
    });
    let mut spread = DMatrix::zeros(d, d);
    let mut both = DMatrix::zeros(d, d);
    for ((ev, nu), &p) in events.iter().zip(&innovations).zip(&event_probs) {
        spread += nu * nu.transpose() * p;
        let del = DVector::from_iterator(d, ev.iter().map(|a| if a.is_some() { 1.0 } else { 0.0 }));
        both += &del * del.transpose() * p;
    }
    let spread_term = &gain * (&spread - &vbar * vbar.transpose()) * gain.transpose();
    let x_g = xbar + &gain * &vbar;
    let p_paper = pbar * beta0_all_missed + &pc * (1.0 - beta0_all_missed) + &spread_term;
    // Σ_A β_A (I − G M_A H̄) P̄ (I − G M_A H̄)ᵀ + G M_A R̄ M_A Gᵀ, using H̄ P̄ = S̄ Gᵀ and
    // Σ_A β_A M_A (H̄ P̄ H̄ᵀ + R̄) M_A = S̄ ∘ Π.
    let lam = DMatrix::from_diagonal(&both.diagonal());
    let g_lam_s_gt = &gain * &lam * &sbar * gain.transpose();
    let p_masked = pbar - &g_lam_s_gt - g_lam_s_gt.transpose()
        + &gain * sbar.component_mul(&both) * gain.transpose()
        + &spread_term;
    let paper = Estimate {
        x: x_g.clone(),
        p: (&p_paper + p_paper.transpose()) * 0.5,
    };
    let masked = Estimate {
        x: x_g,
        p: (&p_masked + p_masked.transpose()) * 0.5,
    };

    let pda = (0..d)
        .map(|t| pda_track(xbar, pbar, h, zs, &gating, beta.get(t)?, t))
        .collect::<Option<Vec<_>>>()?;

    Some(RowResult {
        gating,
        sbar,
        events,
        log_weights,
        event_probs,
        beta,
        beta0_all_missed,
        gain,
        vbar,
        pc,
        mixture,
        paper,
        masked,
        pda,
    })
}

fn cache_or_new<'a>(
    cache: &'a mut BTreeMap<Vec<bool>, Pattern>,
    key: &[bool],
    pbar: &DMatrix<f64>,
    sbar: &DMatrix<f64>,
    pht: &DMatrix<f64>,
) -> Option<&'a Pattern> {
    if !cache.contains_key(key) {
        let pat = Pattern::new(key, pbar, sbar, pht)?;
        cache.insert(key.to_vec(), pat);
    }
    cache.get(key)
}

/// The PDA update of track `t` on its marginal (golden `pda_update`):
/// `x = x + K Σ_j β_j ν_j`,
/// `P = β₀ P + (1 − β₀)(P − K S Kᵀ) + K (Σ_j β_j ν_j ν_jᵀ − ν νᵀ) Kᵀ`.
fn pda_track(
    xbar: &DVector<f64>,
    pbar: &DMatrix<f64>,
    h: &DMatrix<f64>,
    zs: &[f64],
    gating: &Gating,
    beta: &[f64],
    t: usize,
) -> Option<Estimate> {
    let nx = h.ncols();
    let x = xbar.rows(t * nx, nx).into_owned();
    let p = pbar.view((t * nx, t * nx), (nx, nx)).into_owned();
    let s = *gating.s.get(t)?;
    let zhat = *gating.zhat.get(t)?;
    let k = &p * h.transpose() / s;
    let b0 = *beta.first()?;
    let (mut nu, mut nu2) = (0.0, 0.0);
    for (b, z) in beta.iter().skip(1).zip(zs) {
        nu += b * (z - zhat);
        nu2 += b * (z - zhat) * (z - zhat);
    }
    let x_new = &x + &k * nu;
    let kkt = &k * k.transpose();
    let p_new = &p * b0 + (&p - &kkt * s) * (1.0 - b0) + kkt * (nu2 - nu * nu);
    Some(Estimate {
        x: x_new,
        p: (&p_new + p_new.transpose()) * 0.5,
    })
}

/// Loopy belief propagation marginals of one row's association with the *uncoupled* likelihood
/// (docs/design.md §11.3, Williams & Lau 2014): `ψ_dj = P_D N(z_j; ẑ_d, S_d) / (λ_c · miss)`
/// for `j` in the gate of track `d` (0 elsewhere), messages `ν_dj = 1` at the start, then per
/// iteration `μ_dj = ψ_dj / (1 + Σ_{j' ≠ j} ψ_dj' ν_dj')` and
/// `ν_dj = 1 / (1 + Σ_{d' ≠ d} μ_d'j)`, until no `ν` moves by more than `tolerance` or after
/// `max_iterations`; `β_d0 = 1 / (1 + Σ_j ψ_dj ν_dj)`, `β_dj = ψ_dj ν_dj β_d0`. Returns the
/// marginals in [`RowResult::beta`]'s layout and the iterations run (at least 1). Every track at
/// `params.pd`: [`lbp_marginals_with_pd`].
pub fn lbp_marginals(
    gating: &Gating,
    zs: &[f64],
    params: &RowParams,
    max_iterations: u32,
    tolerance: f64,
) -> (Vec<Vec<f64>>, u32) {
    let pd = vec![params.pd; gating.zhat.len()];
    lbp_marginals_with_pd(gating, zs, params, &pd, max_iterations, tolerance)
}

/// [`lbp_marginals`] with a detection probability per track (`pd[t]` in place of `params.pd`;
/// docs/design.md §11.3, the known-lane pass's rows): `ψ_dj = P_D,d N(z_j; ẑ_d, S_d) / (λ_c ·
/// miss(P_D,d))`, with `|ln ψ_dj|` clamped to 60 as the design states.
///
/// # Panics
/// When `pd` does not hold one value per track of `gating`.
pub fn lbp_marginals_with_pd(
    gating: &Gating,
    zs: &[f64],
    params: &RowParams,
    pd: &[f64],
    max_iterations: u32,
    tolerance: f64,
) -> (Vec<Vec<f64>>, u32) {
    let d = gating.zhat.len();
    assert_eq!(pd.len(), d, "one P_D per track");
    let m = zs.len();
    let psi: Vec<Vec<f64>> = (0..d)
        .map(|t| {
            let s = gating.s[t];
            let ln_norm = pd[t].ln()
                - 0.5 * (2.0 * PI * s).ln()
                - params.clutter_density.ln()
                - params.miss.miss_factor(pd[t], params.pg).ln();
            (0..m)
                .map(|j| {
                    if gating.valid[t][j] {
                        let e = zs[j] - gating.zhat[t];
                        (ln_norm - 0.5 * e * e / s).clamp(-60.0, 60.0).exp()
                    } else {
                        0.0
                    }
                })
                .collect()
        })
        .collect();
    let mut nu = vec![vec![1.0; m]; d];
    let mut iterations = 0;
    let shared = (0..m).any(|j| (0..d).filter(|&t| gating.valid[t][j]).count() > 1);
    if shared {
        while iterations < max_iterations {
            iterations += 1;
            let mu: Vec<Vec<f64>> = (0..d)
                .map(|t| {
                    let s: f64 = 1.0 + (0..m).map(|j| psi[t][j] * nu[t][j]).sum::<f64>();
                    (0..m)
                        .map(|j| psi[t][j] / (s - psi[t][j] * nu[t][j]))
                        .collect()
                })
                .collect();
            let mut moved = 0.0f64;
            for j in 0..m {
                let col: f64 = 1.0 + (0..d).map(|t| mu[t][j]).sum::<f64>();
                for t in 0..d {
                    let new = 1.0 / (col - mu[t][j]);
                    moved = moved.max((new - nu[t][j]).abs());
                    nu[t][j] = new;
                }
            }
            if moved <= tolerance {
                break;
            }
        }
    }
    let beta = (0..d)
        .map(|t| {
            let s: f64 = 1.0 + (0..m).map(|j| psi[t][j] * nu[t][j]).sum::<f64>();
            std::iter::once(1.0 / s)
                .chain((0..m).map(|j| psi[t][j] * nu[t][j] / s))
                .collect()
        })
        .collect();
    (beta, iterations.max(1))
}
