//! The one place where the core calls float intrinsics (`sqrt`, `exp`, `ln`, `expm1`), plus the
//! small dense-matrix helpers the kernels need (matrix exponential, exact discretisation).
//! Every intrinsic is `libm`'s.
//!
//! No function here panics, allocates or recurses; non-finite input gives `None` or a
//! non-finite output, never undefined state.

use nalgebra::SMatrix;

/// Square root (`libm::sqrtf`).
#[inline]
pub fn sqrt(x: f32) -> f32 {
    libm::sqrtf(x)
}

/// `e^x` (`libm::expf`).
#[inline]
pub fn exp(x: f32) -> f32 {
    libm::expf(x)
}

/// [`exp`] out of line, for loops that the optimiser unrolls with `libm::expf` inlined in every
/// copy (1.5 KB of flash each in the row kernels); a call costs a few instructions.
#[inline(never)]
pub fn exp_call(x: f32) -> f32 {
    libm::expf(x)
}

/// `e^x - 1`, accurate for small `x` (`libm::expm1f`).
#[inline]
pub fn expm1(x: f32) -> f32 {
    libm::expm1f(x)
}

/// `f32::max` without its call: the larger of `a` and `b`, the other when one is NaN, `a` when
/// they compare equal (`max(−0, +0) = −0`, as `libm::fmaxf`). On the Cortex-M4F `f32::max` is a
/// call of `fmaxf`; this is a compare and two conditional moves (stop 31: the calls were 2 % of a
/// typical frame).
#[inline(always)]
pub fn max(a: f32, b: f32) -> f32 {
    if a >= b || b.is_nan() {
        a
    } else {
        b
    }
}

/// Natural logarithm (`libm::logf`).
#[inline]
pub fn ln(x: f32) -> f32 {
    libm::logf(x)
}

/// Largest number of halvings the scaling-and-squaring methods accept. `‖A t‖₁ ≤ 2^MAX_SQUARINGS`
/// covers every step a lane model can meaningfully take; beyond it the result is `None`.
pub const MAX_SQUARINGS: u32 = 40;

/// Degree of the Taylor polynomials used after scaling (`‖A t / 2^s‖₁ ≤ 1`): the truncation error
/// is below `1 / (DEGREE+1)! ≈ 1.6e-10`, far under f32 resolution. A larger scaled norm with a
/// longer polynomial means fewer squarings, and each squaring roughly doubles f32 round-off.
const TAYLOR_DEGREE: u32 = 12;

/// Induced 1-norm (largest absolute column sum).
#[inline]
pub fn norm1<const N: usize>(a: &SMatrix<f32, N, N>) -> f32 {
    a.column_iter()
        .map(|c| c.iter().map(|v| v.abs()).sum::<f32>())
        .fold(0.0, f32::max)
}

/// Number of halvings that bring `norm` to at most 1, or `None` for non-finite or huge norms.
fn halvings(norm: f32) -> Option<u32> {
    if !norm.is_finite() {
        return None;
    }
    let mut s = 0;
    let mut n = norm;
    while n > 1.0 {
        if s >= MAX_SQUARINGS {
            return None;
        }
        n *= 0.5;
        s += 1;
    }
    Some(s)
}

/// Exact discretisation of the linear SDE `dx = A x dt + L dβ`, `E[dβ dβᵀ] = Qc dt` over a step `t`:
/// returns `(F, Q)` with `F = e^{A t}` and `Q = ∫₀ᵗ e^{A s} L Qc Lᵀ e^{Aᵀ s} ds`, given
/// `lql = L Qc Lᵀ`.
///
/// `Q` is built from its Taylor series on a scaled step and then doubled
/// (`Q(2h) = Q(h) + F(h) Q(h) F(h)ᵀ`, `F(2h) = F(h)²`), so it never forms `P∞ − F P∞ Fᵀ`, whose
/// cancellation loses most of f32's digits when the step is short against the length-scale.
///
/// # Complexity
/// At most `TAYLOR_DEGREE + 2·MAX_SQUARINGS` products of `N×N` matrices (O(N³) each). No recursion.
///
/// # Errors
/// `None` when `t` is not finite and positive, or `A t` is non-finite or too large to scale.
#[allow(non_snake_case)]
pub fn discretize<const N: usize>(
    A: &SMatrix<f32, N, N>,
    lql: &SMatrix<f32, N, N>,
    t: f32,
) -> Option<(SMatrix<f32, N, N>, SMatrix<f32, N, N>)> {
    if !(t.is_finite() && t > 0.0) {
        return None;
    }
    let at = A * t;
    let s = halvings(norm1(&at))?;
    let h = t * libm::ldexpf(1.0, -(s as i32));
    let x = A * h;
    // F(h) = Σ x^k / k!, Q(h) = Σ h^k/k! C_k with C_1 = LQcLᵀ, C_{k+1} = A C_k + C_k Aᵀ.
    let mut f = SMatrix::<f32, N, N>::identity();
    let mut term = SMatrix::<f32, N, N>::identity();
    let mut c = *lql;
    let mut q = lql * h;
    let mut hk = h; // h^k / k!
    for k in 1..=TAYLOR_DEGREE {
        term = term * x / k as f32;
        f += term;
        c = A * c + c * A.transpose();
        hk *= h / (k + 1) as f32;
        q += c * hk;
    }
    for _ in 0..s {
        q += f * q * f.transpose();
        f *= f;
    }
    let q = (q + q.transpose()) * 0.5;
    if f.iter().chain(q.iter()).all(|v| v.is_finite()) {
        Some((f, q))
    } else {
        None
    }
}

/// Matrix exponential `e^{A t}` by scaling and squaring with a degree-12 Taylor polynomial.
///
/// # Complexity
/// At most `TAYLOR_DEGREE + MAX_SQUARINGS` `N×N` products. No recursion.
///
/// # Errors
/// `None` when `t` or `A` is non-finite, or `A t` is too large to scale.
#[allow(non_snake_case)]
pub fn expm<const N: usize>(A: &SMatrix<f32, N, N>, t: f32) -> Option<SMatrix<f32, N, N>> {
    if !t.is_finite() {
        return None;
    }
    let at = A * t;
    let s = halvings(norm1(&at))?;
    let x = at * libm::ldexpf(1.0, -(s as i32));
    let mut f = SMatrix::<f32, N, N>::identity();
    let mut term = SMatrix::<f32, N, N>::identity();
    for k in 1..=TAYLOR_DEGREE {
        term = term * x / k as f32;
        f += term;
    }
    for _ in 0..s {
        f *= f;
    }
    if f.iter().all(|v| v.is_finite()) {
        Some(f)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix2;

    /// `max` is `f32::max` wherever `f32::max` is specified (not at a tie of ±0), and returns
    /// its first argument at that tie.
    #[test]
    fn max_is_f32_max() {
        let v = [
            f32::NEG_INFINITY,
            -3.5,
            -1e-38,
            0.0,
            1e-45,
            2.0,
            f32::MAX,
            f32::INFINITY,
            f32::NAN,
        ];
        for a in v {
            for b in v {
                let (m, want) = (max(a, b), a.max(b));
                assert!(
                    m.to_bits() == want.to_bits() || (m.is_nan() && want.is_nan()),
                    "{a} {b}"
                );
            }
        }
        assert_eq!(max(-0.0, 0.0).to_bits(), (-0.0f32).to_bits());
        assert_eq!(max(0.0, -0.0).to_bits(), 0.0f32.to_bits());
    }

    #[test]
    fn expm_of_nilpotent_is_exact() {
        let a = Matrix2::new(0.0, 1.0, 0.0, 0.0);
        let f = expm(&a, 3.0).unwrap();
        assert_eq!(f, Matrix2::new(1.0, 3.0, 0.0, 1.0));
    }

    #[test]
    fn discretize_of_integrator_matches_closed_form() {
        // Wiener velocity model: Q = qc [[t³/3, t²/2], [t²/2, t]].
        let a = Matrix2::new(0.0, 1.0, 0.0, 0.0);
        let lql = Matrix2::new(0.0, 0.0, 0.0, 2.0);
        for t in [1e-3f32, 0.1, 1.0, 7.5] {
            let (f, q) = discretize(&a, &lql, t).unwrap();
            assert!((f[(0, 1)] - t).abs() <= 1e-6 * t);
            let want = Matrix2::new(t * t * t / 3.0, t * t / 2.0, t * t / 2.0, t) * 2.0;
            for (g, w) in q.iter().zip(want.iter()) {
                assert!((g - w).abs() <= 1e-5 * w.abs(), "t={t} got {g} want {w}");
            }
        }
    }

    #[test]
    fn bad_steps_are_values_not_panics() {
        let a = Matrix2::new(0.0, 1.0, -1.0, -1.0);
        let lql = Matrix2::identity();
        for t in [0.0, -1.0, f32::NAN, f32::INFINITY, 1e30] {
            assert!(discretize(&a, &lql, t).is_none(), "t={t}");
        }
        assert!(expm(&a, f32::NAN).is_none());
        assert!(expm(&(a * f32::NAN), 1.0).is_none());
    }
}
