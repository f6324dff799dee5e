//! Kernels in state-space form, at run time (f32).
//!
//! * [`Matern32`] — the temporal kernel `k_t(τ) = σ² (1 + λ|τ|) e^{−λ|τ|}`, `λ = √3/ℓ`, with the
//!   closed-form transition `F(T)` and process noise `Q(T)` for any frame step `T > 0`
//!   (frames can be dropped). `Q(T)` is evaluated by a series where `P∞ − F P∞ Fᵀ` would cancel.
//! * [`RbfStateSpace`] — the Taylor-order-`NT` state-space approximation of the RBF spatial kernel
//!   (docs/design.md §3). Its companion matrix `A`, `Qc` and `P∞` come from the offline tables (the spectral
//!   factorisation needs polynomial roots, which the core never computes); the core discretises it
//!   exactly for any row step `Δu` with [`crate::math::discretize`].
//!
//! ```
//! use stjpdacf::kernel::Matern32;
//! let m = Matern32::new(1.0, 30.0);
//! let (f, q) = m.transition(0.05).unwrap_or_default();
//! assert!(f[(0, 0)] < 1.0 && q[(0, 0)] > 0.0);
//! ```

use nalgebra::{Matrix2, SMatrix};

use crate::math;

/// Matérn ν = 3/2 kernel with variance `σ²` and length-scale `ℓ` (seconds in the temporal role).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Matern32 {
    /// Variance σ².
    pub variance: f32,
    /// Length-scale ℓ.
    pub lengthscale: f32,
}

/// Terms of the series used for `1 − e^{−2x} p(x)` when `x = λT < SERIES_BELOW`.
const SERIES_TERMS: u32 = 14;
/// Below this `x = λT` the Matérn process noise is evaluated by its Taylor series.
const SERIES_BELOW: f32 = 0.5;

impl Matern32 {
    /// A kernel with variance `variance` and length-scale `lengthscale`.
    pub const fn new(variance: f32, lengthscale: f32) -> Self {
        Self {
            variance,
            lengthscale,
        }
    }

    /// `λ = √3 / ℓ`.
    pub fn lambda(&self) -> f32 {
        math::sqrt(3.0) / self.lengthscale
    }

    /// Kernel value `k(τ)`.
    pub fn eval(&self, tau: f32) -> f32 {
        let x = self.lambda() * tau.abs();
        self.variance * (1.0 + x) * math::exp(-x)
    }

    /// Stationary covariance `P∞ = diag(σ², λ² σ²)` of the state `[f, ḟ]`.
    pub fn p_inf(&self) -> Matrix2<f32> {
        let l = self.lambda();
        Matrix2::new(self.variance, 0.0, 0.0, l * l * self.variance)
    }

    /// `F(T) = e^{A T}` and `Q(T) = P∞ − F P∞ Fᵀ` in closed form, for any step `T > 0`.
    ///
    /// With `x = λT`: `Q₁₁ = σ² g₊(x)`, `Q₁₂ = 2σ²λ³T² e^{−2x}`, `Q₂₂ = σ²λ² g₋(x)`, where
    /// `g±(x) = 1 − e^{−2x}(1 ± 2x + 2x²)`; `g±` are summed as series for `x < 0.5`, because the
    /// difference loses up to all of f32's digits for short steps (`g₊ ≈ 4x³/3`).
    ///
    /// # Complexity
    /// O(1): two exponentials and at most 2 × 14 series terms.
    ///
    /// # Errors
    /// `None` when `T` is not finite and positive or the hyperparameters are not finite and positive.
    pub fn transition(&self, t: f32) -> Option<(Matrix2<f32>, Matrix2<f32>)> {
        let s2 = self.variance;
        let l = self.lambda();
        if !(t.is_finite() && t > 0.0 && s2.is_finite() && s2 > 0.0 && l.is_finite() && l > 0.0) {
            return None;
        }
        let x = l * t;
        let e1 = math::exp(-x);
        let f = Matrix2::new(1.0 + x, t, -l * l * t, 1.0 - x) * e1;
        let e2 = e1 * e1;
        let (gp, gm) = if x < SERIES_BELOW {
            one_minus_exp_poly(x)
        } else {
            (
                1.0 - e2 * (1.0 + 2.0 * x + 2.0 * x * x),
                1.0 - e2 * (1.0 - 2.0 * x + 2.0 * x * x),
            )
        };
        let q12 = 2.0 * s2 * l * l * l * t * t * e2;
        let q = Matrix2::new(s2 * gp, q12, q12, s2 * l * l * gm);
        if f.iter().chain(q.iter()).all(|v| v.is_finite()) {
            Some((f, q))
        } else {
            None
        }
    }
}

/// `(g₊(x), g₋(x))` with `g±(x) = 1 − e^{−2x}(1 ± 2x + 2x²)`, summed from their Taylor series.
///
/// With `a_k = (−2)^k / k!` (the series of `e^{−2x}`), the coefficients are
/// `c±_k = a_k ± 2 a_{k−1} + 2 a_{k−2}`, and `g± = −Σ_{k≥1} c±_k x^k` (`c±_0 = 1` cancels the 1).
fn one_minus_exp_poly(x: f32) -> (f32, f32) {
    // (a_{k-2}, a_{k-1}) at k = 1: a_{-1} = 0, a_0 = 1.
    let mut prev = (0.0f32, 1.0f32);
    let mut xk = 1.0f32;
    let (mut gp, mut gm) = (0.0f32, 0.0f32);
    for k in 1..=SERIES_TERMS {
        let (am2, am1) = prev;
        let ak = am1 * -2.0 / k as f32;
        xk *= x;
        gp -= (ak + 2.0 * am1 + 2.0 * am2) * xk;
        gm -= (ak - 2.0 * am1 + 2.0 * am2) * xk;
        prev = (am1, ak);
    }
    (gp, gm)
}

/// The Taylor-order-`NT` state-space form of the RBF kernel: `dg = A g du + L dβ`, `L = e_NT`,
/// spectral density `Qc`, stationary covariance `P∞` (the Lyapunov solution, not `σ²`: the
/// approximation's own variance, 14 % above `σ²` at order 2), `H = [1, 0, …, 0]`.
///
/// Built offline ([`crate::tables`]); the core only discretises it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[allow(non_snake_case)]
pub struct RbfStateSpace<const NT: usize> {
    /// Companion matrix `A` (last row `[−a₀, …, −a_{NT−1}]`).
    pub A: SMatrix<f32, NT, NT>,
    /// White-noise spectral density `Qc`.
    pub qc: f32,
    /// Stationary covariance `P∞`.
    pub p_inf: SMatrix<f32, NT, NT>,
}

impl<const NT: usize> RbfStateSpace<NT> {
    /// `L Qc Lᵀ`: `Qc` in the last diagonal entry.
    pub fn lql(&self) -> SMatrix<f32, NT, NT> {
        let mut m = SMatrix::<f32, NT, NT>::zeros();
        if let Some(v) = m.get_mut((NT.wrapping_sub(1), NT.wrapping_sub(1))) {
            *v = self.qc;
        }
        m
    }

    /// Balancing scale `ρ = |a₀|^{1/NT}` (1 if degenerate): with `D = diag(ρ⁰, …, ρ^{NT−1})` every
    /// entry of `D⁻¹ A D` is O(ρ), whereas the raw companion matrix mixes `1` with `a₀ ~ ρ^NT`, which
    /// costs f32 digits at high orders and short length-scales.
    fn balance(&self) -> f32 {
        let a0 = self.A.get((NT.wrapping_sub(1), 0)).map_or(1.0, |v| v.abs());
        let rho = libm::powf(a0, 1.0 / NT as f32);
        if rho.is_finite() && rho > 0.0 {
            rho
        } else {
            1.0
        }
    }

    /// Exact `F(Δu) = e^{A Δu}` and `Q(Δu) = ∫ e^{As} L Qc Lᵀ e^{Aᵀs} ds` for any row step `Δu > 0`,
    /// computed on the balanced form `D⁻¹ A D` and scaled back (`F = D F_b D⁻¹`, `Q = D Q_b D`).
    ///
    /// # Complexity
    /// O(NT³ · (12 + 2 log₂‖A Δu‖₁)) flops, no allocation.
    ///
    /// # Errors
    /// `None` for a non-finite or non-positive step.
    pub fn transition(&self, du: f32) -> Option<(SMatrix<f32, NT, NT>, SMatrix<f32, NT, NT>)> {
        let rho = self.balance();
        let pw = |k: f32| libm::powf(rho, k);
        let ab = self
            .A
            .map_with_location(|i, j, v| v * pw(j as f32 - i as f32));
        let lqlb = self
            .lql()
            .map_with_location(|i, j, v| v * pw(-(i as f32) - j as f32));
        let (fb, qb) = math::discretize(&ab, &lqlb, du)?;
        let f = fb.map_with_location(|i, j, v| v * pw(i as f32 - j as f32));
        let q = qb.map_with_location(|i, j, v| v * pw(i as f32 + j as f32));
        if f.iter().chain(q.iter()).all(|v| v.is_finite()) {
            Some((f, q))
        } else {
            None
        }
    }

    /// Implied covariance `H e^{A|d|} P∞ Hᵀ` of the approximated process at lag `d`.
    pub fn covariance(&self, d: f32) -> Option<f32> {
        let rho = self.balance();
        let pw = |k: f32| libm::powf(rho, k);
        let ab = self
            .A
            .map_with_location(|i, j, v| v * pw(j as f32 - i as f32));
        let fb = math::expm(&ab, d.abs())?;
        let f = fb.map_with_location(|i, j, v| v * pw(i as f32 - j as f32));
        let c = f * self.p_inf;
        c.get((0, 0)).copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn series_matches_direct_form_where_both_are_accurate() {
        // At x = 0.5 the direct difference is well conditioned (no more than ~1 digit lost).
        let x = 0.5f32;
        let e2 = (-2.0 * x).exp();
        let (gp, gm) = one_minus_exp_poly(x);
        let dp = 1.0 - e2 * (1.0 + 2.0 * x + 2.0 * x * x);
        let dm = 1.0 - e2 * (1.0 - 2.0 * x + 2.0 * x * x);
        assert!((gp - dp).abs() < 2e-6, "{gp} {dp}");
        assert!((gm - dm).abs() < 2e-6, "{gm} {dm}");
    }

    #[test]
    fn short_step_noise_keeps_its_digits() {
        // Q₁₁ ≈ (4/3) σ² x³ for small x = λT (lengthscale 30 s, 20 fps: x ≈ 2.9e-3).
        let m = Matern32::new(1.0, 30.0);
        let t = 0.05;
        let (_, q) = m.transition(t).unwrap();
        let x = m.lambda() * t;
        let lead = 4.0 / 3.0 * x * x * x * (1.0 - 1.5 * x);
        assert!(
            (q[(0, 0)] / lead - 1.0).abs() < 1e-4,
            "{} vs {}",
            q[(0, 0)],
            lead
        );
        assert!(q.determinant() > 0.0);
    }

    #[test]
    fn transition_rejects_bad_steps() {
        let m = Matern32::new(1.0, 2.0);
        for t in [0.0, -0.1, f32::NAN, f32::INFINITY] {
            assert!(m.transition(t).is_none());
        }
        assert!(Matern32::new(f32::NAN, 1.0).transition(0.1).is_none());
        assert!(Matern32::new(1.0, 0.0).transition(0.1).is_none());
    }
}
