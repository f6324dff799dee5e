//! Kernels and their state-space forms in f64 (docs/design.md §3).

use nalgebra::{DMatrix, DVector};
use num_complex::Complex64;

/// Solves the continuous Lyapunov equation `A P + P Aᵀ + Q = 0` by vectorisation:
/// `(I ⊗ A + A ⊗ I) vec(P) = −vec(Q)`, then symmetrises. `None` if the system is singular.
pub fn lyapunov(a: &DMatrix<f64>, q: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let n = a.nrows();
    let eye = DMatrix::<f64>::identity(n, n);
    let m = eye.kronecker(a) + a.kronecker(&eye);
    let rhs = -DVector::from_column_slice(q.as_slice());
    let x = m.lu().solve(&rhs)?;
    let p = DMatrix::from_column_slice(n, n, x.as_slice());
    Some((&p + p.transpose()) * 0.5)
}

/// `F = e^{A t}` and `Q = P∞ − F P∞ Fᵀ` (f64 keeps enough digits for this form).
pub fn discretize(a: &DMatrix<f64>, p_inf: &DMatrix<f64>, t: f64) -> (DMatrix<f64>, DMatrix<f64>) {
    let f = (a * t).exp();
    let q = p_inf - &f * p_inf * f.transpose();
    let q = (&q + q.transpose()) * 0.5;
    (f, q)
}

/// Van Loan's method: `F = e^{A t}` and `Q = ∫₀ᵗ e^{As} L Qc Lᵀ e^{Aᵀs} ds` from one exponential of
/// the block matrix `[[−A, LQcLᵀ], [0, Aᵀ]] t` (no cancellation, unlike `P∞ − F P∞ Fᵀ` for short
/// steps, where `Q` can be 1e-11 of `P∞`).
pub fn van_loan(a: &DMatrix<f64>, lql: &DMatrix<f64>, t: f64) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = a.nrows();
    let mut m = DMatrix::<f64>::zeros(2 * n, 2 * n);
    m.view_mut((0, 0), (n, n)).copy_from(&(-a));
    m.view_mut((0, n), (n, n)).copy_from(lql);
    m.view_mut((n, n), (n, n)).copy_from(&a.transpose());
    let e = (m * t).exp();
    let f = e.view((n, n), (n, n)).transpose();
    let q = &f * e.view((0, n), (n, n));
    let q = (&q + q.transpose()) * 0.5;
    (f, q)
}

/// Matérn ν = 3/2: `k(τ) = σ² (1 + λ|τ|) e^{−λ|τ|}`, `λ = √3/ℓ`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Matern32 {
    /// σ².
    pub variance: f64,
    /// ℓ.
    pub lengthscale: f64,
}

impl Matern32 {
    /// `λ = √3/ℓ`.
    pub fn lambda(&self) -> f64 {
        3f64.sqrt() / self.lengthscale
    }
    /// Kernel value.
    pub fn kernel(&self, tau: f64) -> f64 {
        let x = self.lambda() * tau.abs();
        self.variance * (1.0 + x) * (-x).exp()
    }
    /// `A = [[0, 1], [−λ², −2λ]]`.
    pub fn a(&self) -> DMatrix<f64> {
        let l = self.lambda();
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -l * l, -2.0 * l])
    }
    /// `L = [0, 1]ᵀ`.
    pub fn l(&self) -> DMatrix<f64> {
        DMatrix::from_row_slice(2, 1, &[0.0, 1.0])
    }
    /// `H = [1, 0]`.
    pub fn h(&self) -> DMatrix<f64> {
        DMatrix::from_row_slice(1, 2, &[1.0, 0.0])
    }
    /// `Qc = 4 λ³ σ²`.
    pub fn qc(&self) -> f64 {
        4.0 * self.lambda().powi(3) * self.variance
    }
    /// `P∞ = diag(σ², λ² σ²)`.
    pub fn p_inf_closed(&self) -> DMatrix<f64> {
        let l = self.lambda();
        DMatrix::from_row_slice(2, 2, &[self.variance, 0.0, 0.0, l * l * self.variance])
    }
    /// `P∞` from the Lyapunov equation.
    pub fn p_inf_lyapunov(&self) -> Option<DMatrix<f64>> {
        let l = self.l();
        lyapunov(&self.a(), &(&l * self.qc() * l.transpose()))
    }
    /// `F(T)` by the closed form `e^{−λT} [[1 + λT, T], [−λ²T, 1 − λT]]`.
    pub fn f_closed(&self, t: f64) -> DMatrix<f64> {
        let l = self.lambda();
        let x = l * t;
        DMatrix::from_row_slice(2, 2, &[1.0 + x, t, -l * l * t, 1.0 - x]) * (-x).exp()
    }
    /// `F(T) = e^{AT}` (matrix exponential) and `Q(T) = P∞ − F P∞ Fᵀ`.
    pub fn transition(&self, t: f64) -> (DMatrix<f64>, DMatrix<f64>) {
        discretize(&self.a(), &self.p_inf_closed(), t)
    }
    /// Spectral density `S(ω) = 4λ³σ² / (λ² + ω²)²`.
    pub fn spectrum(&self, w: f64) -> f64 {
        let l = self.lambda();
        self.qc() / (l * l + w * w).powi(2)
    }
}

/// The Taylor-order-N state-space approximation of the RBF kernel `k(d) = σ² e^{−d²/(2ℓ²)}`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RbfTaylor {
    /// σ².
    pub variance: f64,
    /// ℓ.
    pub lengthscale: f64,
    /// Taylor order N (state size).
    pub order: usize,
}

fn factorial(n: usize) -> f64 {
    (1..=n).map(|k| k as f64).product()
}

/// Evaluates `Σ c_k z^k` (ascending coefficients) at complex `z` by Horner's rule.
fn poly_eval(c: &[f64], z: Complex64) -> Complex64 {
    c.iter()
        .rev()
        .fold(Complex64::new(0.0, 0.0), |acc, &ck| acc * z + ck)
}

/// All roots of `Σ c_k y^k` (ascending, leading coefficient non-zero) by the Aberth–Ehrlich
/// simultaneous iteration (at most 500 sweeps), each root then polished by Newton's method.
pub fn poly_roots(c: &[f64]) -> Vec<Complex64> {
    let n = c.len() - 1;
    let lead = c[n];
    let monic: Vec<f64> = c.iter().map(|v| v / lead).collect();
    let dc: Vec<f64> = (1..=n).map(|k| k as f64 * monic[k]).collect();
    // Cauchy bound on the root moduli; start on a circle inside it, off the real axis.
    let bound = 1.0 + monic[..n].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut z: Vec<Complex64> = (0..n)
        .map(|k| {
            Complex64::from_polar(
                0.5 * bound,
                0.4 + 2.0 * std::f64::consts::PI * k as f64 / n as f64,
            )
        })
        .collect();
    for _ in 0..500 {
        let mut moved = 0.0f64;
        for i in 0..n {
            let ratio = poly_eval(&monic, z[i]) / poly_eval(&dc, z[i]);
            let repulsion: Complex64 = (0..n)
                .filter(|&j| j != i)
                .map(|j| 1.0 / (z[i] - z[j]))
                .sum();
            let step = ratio / (1.0 - ratio * repulsion);
            if step.is_finite() {
                z[i] -= step;
                moved = moved.max(step.norm() / z[i].norm().max(1e-300));
            }
        }
        if moved < 1e-15 {
            break;
        }
    }
    z.into_iter()
        .map(|mut r| {
            for _ in 0..4 {
                let step = poly_eval(&monic, r) / poly_eval(&dc, r);
                if !step.is_finite() {
                    break;
                }
                r -= step;
            }
            r
        })
        .collect()
}

impl RbfTaylor {
    /// `κ = 1/(2ℓ²)`.
    pub fn kappa(&self) -> f64 {
        1.0 / (2.0 * self.lengthscale * self.lengthscale)
    }
    /// True kernel value `σ² e^{−d²/(2ℓ²)}`.
    pub fn kernel(&self, d: f64) -> f64 {
        self.variance * (-d * d * self.kappa()).exp()
    }
    /// True spectral density `σ² √(π/κ) e^{−ω²/(4κ)}`.
    pub fn spectrum(&self, w: f64) -> f64 {
        self.variance
            * (std::f64::consts::PI / self.kappa()).sqrt()
            * (-w * w / (4.0 * self.kappa())).exp()
    }
    /// `Qc = σ² N! (4κ)^N √(π/κ)`.
    pub fn qc(&self) -> f64 {
        let n = self.order;
        self.variance
            * factorial(n)
            * (4.0 * self.kappa()).powi(n as i32)
            * (std::f64::consts::PI / self.kappa()).sqrt()
    }
    /// Denominator coefficients in `ω²`, ascending: `c_n = N! (4κ)^{N−n} / n!`, n = 0..=N.
    pub fn coeffs_w2_ascending(&self) -> Vec<f64> {
        let n = self.order;
        (0..=n)
            .map(|k| factorial(n) * (4.0 * self.kappa()).powi((n - k) as i32) / factorial(k))
            .collect()
    }
    /// The Taylor spectral density `Qc / Σ c_n ω^{2n}`.
    pub fn spectrum_taylor(&self, w: f64) -> f64 {
        let c = self.coeffs_w2_ascending();
        let den: f64 = c
            .iter()
            .enumerate()
            .map(|(k, ck)| ck * w.powi(2 * k as i32))
            .sum();
        self.qc() / den
    }
    /// The denominator with `ω² = −s²`, ascending in `s` (degree 2N, odd terms zero).
    pub fn poly_s_ascending(&self) -> Vec<f64> {
        let c = self.coeffs_w2_ascending();
        let mut p = vec![0.0; 2 * self.order + 1];
        for (k, ck) in c.iter().enumerate() {
            p[2 * k] = if k % 2 == 0 { *ck } else { -*ck };
        }
        p
    }
    /// The denominator with `ω² = −s²` as a polynomial in `y = s²`, ascending: `(−1)^n c_n`.
    pub fn poly_y_ascending(&self) -> Vec<f64> {
        self.coeffs_w2_ascending()
            .iter()
            .enumerate()
            .map(|(k, ck)| if k % 2 == 0 { *ck } else { -*ck })
            .collect()
    }
    /// All 2N roots in `s`: `±√y` for the N roots `y` of the polynomial in `s²`.
    pub fn roots_all(&self) -> Vec<Complex64> {
        poly_roots(&self.poly_y_ascending())
            .into_iter()
            .flat_map(|y| {
                let r = y.sqrt();
                [r, -r]
            })
            .collect()
    }
    /// The N roots with negative real part, sorted by imaginary part.
    pub fn roots_stable(&self) -> Vec<Complex64> {
        let mut r: Vec<Complex64> = self
            .roots_all()
            .into_iter()
            .filter(|z| z.re < 0.0)
            .collect();
        r.sort_by(|a, b| a.im.total_cmp(&b.im));
        r
    }
    /// `a_0..a_{N−1}` of `Π (s − r_k) = s^N + a_{N−1} s^{N−1} + … + a_0` (real parts; the imaginary
    /// parts cancel between conjugate roots).
    pub fn a_ascending(&self) -> Vec<f64> {
        let mut p = vec![Complex64::new(1.0, 0.0)]; // ascending
        for r in self.roots_stable() {
            let mut q = vec![Complex64::new(0.0, 0.0); p.len() + 1];
            for (k, pk) in p.iter().enumerate() {
                q[k + 1] += pk;
                q[k] -= pk * r;
            }
            p = q;
        }
        p[..self.order].iter().map(|z| z.re).collect()
    }
    /// Companion matrix: superdiagonal ones, last row `[−a_0, …, −a_{N−1}]`.
    pub fn a(&self) -> DMatrix<f64> {
        let n = self.order;
        let a = self.a_ascending();
        let mut m = DMatrix::<f64>::zeros(n, n);
        for i in 0..n - 1 {
            m[(i, i + 1)] = 1.0;
        }
        for j in 0..n {
            m[(n - 1, j)] = -a[j];
        }
        m
    }
    /// `L = e_N`.
    pub fn l(&self) -> DMatrix<f64> {
        let mut l = DMatrix::<f64>::zeros(self.order, 1);
        l[(self.order - 1, 0)] = 1.0;
        l
    }
    /// `H = e_1ᵀ`.
    pub fn h(&self) -> DMatrix<f64> {
        let mut h = DMatrix::<f64>::zeros(1, self.order);
        h[(0, 0)] = 1.0;
        h
    }
    /// `P∞` from `A P + P Aᵀ + L Qc Lᵀ = 0`.
    pub fn p_inf(&self) -> Option<DMatrix<f64>> {
        let l = self.l();
        lyapunov(&self.a(), &(&l * self.qc() * l.transpose()))
    }
    /// `F(Δu)` and `Q(Δu) = P∞ − F P∞ Fᵀ`.
    pub fn transition(&self, du: f64) -> Option<(DMatrix<f64>, DMatrix<f64>)> {
        Some(discretize(&self.a(), &self.p_inf()?, du))
    }
    /// `F(Δu)` and `Q(Δu)` by Van Loan's method (accurate for steps far shorter than ℓ).
    pub fn transition_van_loan(&self, du: f64) -> (DMatrix<f64>, DMatrix<f64>) {
        let l = self.l();
        van_loan(&self.a(), &(&l * self.qc() * l.transpose()), du)
    }
    /// Implied covariance `H e^{A|d|} P∞ Hᵀ` of the approximated process.
    pub fn kernel_statespace(&self, d: f64) -> Option<f64> {
        let p = self.p_inf()?;
        Some(((self.a() * d.abs()).exp() * p)[(0, 0)])
    }
    /// Spectral density of the state-space model, `Qc / |Π (iω − r_k)|²`.
    pub fn spectrum_statespace(&self, w: f64) -> f64 {
        let iw = Complex64::new(0.0, w);
        let den: Complex64 = self.roots_stable().iter().map(|r| iw - r).product();
        self.qc() / den.norm_sqr()
    }
}

/// Lags, as multiples of ℓ, at which [`approximation_table`] compares kernels.
pub const TABLE_LAGS: [f64; 6] = [0.0, 0.5, 1.0, 1.5, 2.0, 3.0];

/// Markdown table of the RBF state-space approximation error for Taylor orders `orders`: for each
/// lag `d/ℓ` in [`TABLE_LAGS`] the relative error `(k_ss(d) − k(d)) / k(d)` of the implied
/// covariance `H e^{A|d|} P∞ Hᵀ` against the true RBF, in percent, and the largest absolute error
/// over `d ∈ [0, 4ℓ]` as a fraction of σ². Independent of σ² and ℓ (both only rescale).
pub fn approximation_table(orders: std::ops::RangeInclusive<usize>) -> String {
    let mut s = String::from("| N_T |");
    for r in TABLE_LAGS {
        s.push_str(&format!(" d = {r}ℓ |"));
    }
    s.push_str(" max abs err / σ² |\n|---|");
    for _ in TABLE_LAGS {
        s.push_str("---|");
    }
    s.push_str("---|\n");
    for order in orders {
        let m = RbfTaylor {
            variance: 1.0,
            lengthscale: 1.0,
            order,
        };
        s.push_str(&format!("| {order} |"));
        for r in TABLE_LAGS {
            let k = m.kernel(r);
            let ks = m.kernel_statespace(r).unwrap_or(f64::NAN);
            s.push_str(&format!(" {:+.2} % |", 100.0 * (ks - k) / k));
        }
        let max_abs = (0..=400)
            .map(|i| {
                let d = i as f64 * 0.01;
                (m.kernel_statespace(d).unwrap_or(f64::NAN) - m.kernel(d)).abs()
            })
            .fold(0.0, f64::max);
        s.push_str(&format!(" {max_abs:.4} |\n"));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poly_roots_of_known_quadratic() {
        // (y − 1)(y − 2) = y² − 3y + 2
        let mut r: Vec<f64> = poly_roots(&[2.0, -3.0, 1.0]).iter().map(|z| z.re).collect();
        r.sort_by(f64::total_cmp);
        assert!((r[0] - 1.0).abs() < 1e-14 && (r[1] - 2.0).abs() < 1e-14);
    }

    #[test]
    fn van_loan_agrees_with_lyapunov_form_for_moderate_steps() {
        let r = RbfTaylor {
            variance: 1.5,
            lengthscale: 2.0,
            order: 3,
        };
        let (f, q) = r.transition(0.7).unwrap();
        let (fv, qv) = r.transition_van_loan(0.7);
        assert!((f - fv).abs().max() < 1e-13);
        assert!((&q - qv).abs().max() < 1e-12 * q.abs().max());
    }

    #[test]
    fn matern_lyapunov_equals_closed_form() {
        let m = Matern32 {
            variance: 2.0,
            lengthscale: 0.7,
        };
        let d = m.p_inf_lyapunov().unwrap() - m.p_inf_closed();
        assert!(d.abs().max() < 1e-12);
        let d = m.transition(0.3).0 - m.f_closed(0.3);
        assert!(d.abs().max() < 1e-14);
    }

    #[test]
    fn rbf_statespace_is_stable_for_all_orders() {
        for order in 2..=6 {
            let r = RbfTaylor {
                variance: 1.0,
                lengthscale: 3.0,
                order,
            };
            assert_eq!(r.roots_stable().len(), order);
            let p = r.p_inf().unwrap();
            assert!(p.clone().cholesky().is_some(), "order {order}");
            // Higher orders approximate k(0) = σ² better.
            let k0 = r.kernel_statespace(0.0).unwrap();
            assert!(k0 > 0.9 && k0 < 1.2, "order {order}: {k0}");
        }
    }
}
