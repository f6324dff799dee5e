//! The ray test (docs/design.md §11.10): is a lane the image of a vertical structure?
//!
//! The inverse perspective maps a vertical image segment at column `c` to `x/u = (c − c_x)/f`:
//! a ray from the camera's foot point (the BEV origin), whatever the camera's height or horizon.
//! A vehicle's side, a pole or a barrier post seen by a front end that does not remove vertical
//! structures is therefore a straight line through `(0, 0)` running from its base to the end of
//! the window, which a tracker of BEV points cannot otherwise tell from paint.
//!
//! The test fits the line `x = a + b·t` (`t = u / u_s`, `u_s` the largest `|u|` used) to the
//! lane's positions `z` at its present index points by weighted least squares (weights `w_i`,
//! the inverse marginal variances), so the offset at the foot point `â = f_aᵀ z` is a fixed
//! linear functional of `z`, with variance `S_aa = f_aᵀ Cov(z) f_a`; likewise the curvature
//! term `ĉ = f_cᵀ z` of the weighted quadratic `x = a + b·s + c·s²` (`s ∈ [−1, 1]` over the
//! extent). A ray has `a = 0` and
//! `c = 0`. The lane is *consistent with a ray* when `â²/S_aa ≤ z²` and `ĉ²/S_cc ≤ z²`, and
//! the test is *decisive* when `√S_aa` is at most `resolution`. The curvature term keeps the
//! outer marking of a bend, whose fitted line can point at the camera where the line of sight
//! is tangent to it, from passing as a ray when its curvature is resolved; where it is not
//! (short or noisy), such a marking can still be taken for a ray (docs/design.md §11.10 gives
//! what that costs on the replay).
//!
//! # Cost
//! `n` present points (`n ≤ POINTS`): `8n` multiply-adds for the two normal matrices, their
//! 2×2 and 3×3 solves, `6n` for the functionals, and two quadratic forms of `Cov(z)` (`2n²`
//! with a dense covariance; `2(n·r + r²)` through `r` Gram coefficients in the tracker).

use nalgebra::SVector;

use crate::linalg::{get, set};
use crate::math;

/// The ray statistic of one lane.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RayStat {
    /// Fitted lateral offset at the camera's foot point `â`, metres.
    pub a: f32,
    /// Its standard deviation `√S_aa`, metres.
    pub sd_a: f32,
    /// `â² / S_aa`: the line's offset at the foot point against zero.
    pub chi2: f32,
    /// `ĉ² / S_cc` of the quadratic's curvature term against zero.
    pub chi2_curvature: f32,
}

/// What the test says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RayVerdict {
    /// Decisive and consistent with a ray: a vertical structure.
    Ray,
    /// Decisive and not a ray: a marking on the road.
    Paint,
    /// Consistent with a ray but not decisive: a ray or a marking near the foot point, which the
    /// lane's direction against the markings decides ([`vertical`]).
    Aligned,
    /// Not decisive and not consistent with a ray, or no statistic.
    #[default]
    Undecided,
}

impl RayStat {
    /// The verdict at `z` standard deviations (`χ² ≤ z²`) and `resolution` metres.
    pub fn verdict(&self, z: f32, resolution: f32) -> RayVerdict {
        // NaN is not decisive.
        let decisive = self.sd_a <= resolution;
        let consistent = self.chi2 <= z * z && self.chi2_curvature <= z * z;
        match (decisive, consistent) {
            (true, true) => RayVerdict::Ray,
            (true, false) => RayVerdict::Paint,
            (false, true) => RayVerdict::Aligned,
            (false, false) => RayVerdict::Undecided,
        }
    }
}

/// Whether a lane (or an observation) of ray verdict `verdict` is the image of a vertical
/// structure (docs/design.md §11.10), from its parallel tests against the lanes found to be
/// paint (`Some(true)`: parallel, `Some(false)`: not parallel, `None`: no test, fewer than 3
/// common index points):
/// * a [`RayVerdict::Ray`] is vertical unless it runs parallel to a paint lane (the marking
///   under the camera in a lane change);
/// * an [`RayVerdict::Aligned`] lane, with `aligned` set, is vertical when it is tested against
///   at least one paint lane and runs parallel to none: a marking runs parallel to the
///   markings, a vehicle's side, a ray from the foot point, does not;
/// * nothing else is.
///
/// Evaluates the tests lazily, at most one pass.
pub fn vertical(
    verdict: RayVerdict,
    aligned: bool,
    mut paint_tests: impl Iterator<Item = Option<bool>>,
) -> bool {
    match verdict {
        RayVerdict::Ray => !paint_tests.any(|t| t == Some(true)),
        RayVerdict::Aligned if aligned => apart(paint_tests),
        _ => false,
    }
}

/// Whether a lane runs parallel to none of the lanes found to be paint and is tested against at
/// least one of them (`paint_tests` as in [`vertical`]): markings are parallel curves, so such a
/// lane is not (yet) shown to be one (docs/design.md §11.10, §11.5).
///
/// Evaluates the tests lazily, at most one pass.
pub fn apart(paint_tests: impl Iterator<Item = Option<bool>>) -> bool {
    let mut tested = false;
    for t in paint_tests {
        match t {
            Some(true) => return false,
            Some(false) => tested = true,
            None => {}
        }
    }
    tested
}

/// The ray statistic of positions `z` at the index points `u` where `present`, fitted with
/// `weight`s, with `cov(p, q) = pᵀ Cov(z) q` (both vectors zero where absent). `None` with fewer
/// than 3 usable points (present, positive finite weight, finite `u` and `z`), when the extent
/// is too short for either fit in f32 (`det < 10⁻⁵ (Σw)²` for the line, `10⁻⁷ (Σw)³` for the
/// quadratic), or when a variance is not positive and finite.
#[inline(never)]
pub fn ray_stat<const POINTS: usize>(
    u: &SVector<f32, POINTS>,
    z: &SVector<f32, POINTS>,
    present: &[bool; POINTS],
    weight: &[f32; POINTS],
    cov: &dyn Fn(&[f32; POINTS], &[f32; POINTS]) -> f32,
) -> Option<RayStat> {
    // Tested once per point (the fits below walk the points five times).
    let ok: [bool; POINTS] = core::array::from_fn(|i| {
        get(present, i)
            && get(weight, i) > 0.0
            && get(weight, i).is_finite()
            && u.get(i).is_some_and(|v| v.is_finite())
            && z.get(i).is_some_and(|v| v.is_finite())
    });
    let usable = |i: usize| get(&ok, i);
    let LineMoments {
        scale,
        m0,
        m1,
        m2,
        det,
    } = line_moments(u, weight, &usable)?;
    let t = |i: usize| u.get(i).copied().unwrap_or(0.0) / scale;
    let mut wa = [0.0f32; POINTS];
    let mut a = 0.0f32;
    for i in (0..POINTS).filter(|&i| usable(i)) {
        let fa = get(weight, i) * (m2 - m1 * t(i)) / det;
        set(&mut wa, i, fa);
        a += fa * z.get(i).copied().unwrap_or(0.0);
    }
    let saa = cov(&wa, &wa);
    if !(saa.is_finite() && saa > 0.0) {
        return None;
    }
    let chi2 = a * a / saa;
    // The quadratic's curvature term does not depend on where `u` starts or on its scale: it is
    // fitted on `s = (u − u_mid)/u_half ∈ [−1, 1]`, which keeps its moment matrix well
    // conditioned in f32. Row 2 of that matrix's inverse gives the functional.
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for i in (0..POINTS).filter(|&i| usable(i)) {
        let ui = u.get(i).copied().unwrap_or(0.0);
        lo = lo.min(ui);
        hi = math::max(hi, ui);
    }
    let (mid, half) = ((lo + hi) / 2.0, (hi - lo) / 2.0);
    if half <= 0.0 {
        return None;
    }
    let t = |i: usize| (u.get(i).copied().unwrap_or(0.0) - mid) / half;
    let mut mm = [0.0f32; 5];
    for i in (0..POINTS).filter(|&i| usable(i)) {
        let (mut p, ti) = (get(weight, i), t(i));
        for e in &mut mm {
            *e += p;
            p *= ti;
        }
    }
    let g = |j: usize, k: usize| get(&mm, j + k);
    let det3 = g(0, 0) * (g(1, 1) * g(2, 2) - g(1, 2) * g(2, 1))
        - g(0, 1) * (g(1, 0) * g(2, 2) - g(1, 2) * g(2, 0))
        + g(0, 2) * (g(1, 0) * g(2, 1) - g(1, 1) * g(2, 0));
    if !(det3.is_finite() && det3 > 1e-7 * m0 * m0 * m0) {
        return None;
    }
    let inv2 = [
        (g(1, 0) * g(2, 1) - g(1, 1) * g(2, 0)) / det3,
        (g(0, 1) * g(2, 0) - g(0, 0) * g(2, 1)) / det3,
        (g(0, 0) * g(1, 1) - g(0, 1) * g(1, 0)) / det3,
    ];
    let mut wc = [0.0f32; POINTS];
    let mut c = 0.0f32;
    for i in (0..POINTS).filter(|&i| usable(i)) {
        let ti = t(i);
        let fc = get(weight, i) * (inv2[0] + inv2[1] * ti + inv2[2] * ti * ti);
        set(&mut wc, i, fc);
        c += fc * z.get(i).copied().unwrap_or(0.0);
    }
    let scc = cov(&wc, &wc);
    if !(scc.is_finite() && scc > 0.0) {
        return None;
    }
    let stat = RayStat {
        a,
        sd_a: math::sqrt(saa),
        chi2,
        chi2_curvature: c * c / scc,
    };
    (stat.a.is_finite()
        && stat.sd_a.is_finite()
        && stat.chi2.is_finite()
        && stat.chi2_curvature.is_finite())
    .then_some(stat)
}

/// The parallel test of docs/design.md §11.10: the weighted least-squares slope `b̂ = f_bᵀ d` of
/// the difference `d = z_s − z_t` of two lanes over the index points where `present`, with
/// `var(p) = pᵀ Cov(d) p`. `Some(true)` when `b̂² ≤ z²·var(f_b)`: the two run parallel;
/// `Some(false)` when not; `None` (no test) with fewer than 3 usable points, a singular fit or a
/// variance that is not positive and finite.
#[inline(never)]
pub fn parallel<const POINTS: usize>(
    u: &SVector<f32, POINTS>,
    d: &[f32; POINTS],
    present: &[bool; POINTS],
    weight: &[f32; POINTS],
    z: f32,
    var: &dyn Fn(&[f32; POINTS]) -> f32,
) -> Option<bool> {
    let ok: [bool; POINTS] = core::array::from_fn(|i| {
        get(present, i)
            && get(weight, i) > 0.0
            && get(weight, i).is_finite()
            && get(d, i).is_finite()
            && u.get(i).is_some_and(|v| v.is_finite())
    });
    let usable = |i: usize| get(&ok, i);
    let LineMoments {
        scale,
        m0,
        m1,
        m2: _,
        det,
    } = line_moments(u, weight, &usable)?;
    let t = |i: usize| u.get(i).copied().unwrap_or(0.0) / scale;
    let mut fb = [0.0f32; POINTS];
    let mut b = 0.0f32;
    for i in (0..POINTS).filter(|&i| usable(i)) {
        let f = get(weight, i) * (m0 * t(i) - m1) / det;
        set(&mut fb, i, f);
        b += f * get(d, i);
    }
    let v = var(&fb);
    (v.is_finite() && v > 0.0 && b.is_finite()).then_some(b * b <= z * z * v)
}

/// The weighted normal matrix `[[m0, m1], [m1, m2]] = [[Σw, Σwt], [Σwt, Σwt²]]` of the line
/// `x = a + b·t` over the usable points, `t = u / scale` with `scale = max |u|` there, and its
/// determinant.
struct LineMoments {
    scale: f32,
    m0: f32,
    m1: f32,
    m2: f32,
    det: f32,
}

/// [`LineMoments`] of the points `usable` accepts; `None` with fewer than 3 of them, no extent,
/// or a fit over less than about a twentieth of the distance (singular in f32).
fn line_moments<const POINTS: usize>(
    u: &SVector<f32, POINTS>,
    weight: &[f32; POINTS],
    usable: &dyn Fn(usize) -> bool,
) -> Option<LineMoments> {
    let mut n = 0usize;
    let mut scale = 0.0f32;
    for i in (0..POINTS).filter(|&i| usable(i)) {
        n += 1;
        scale = math::max(scale, u.get(i).copied().unwrap_or(0.0).abs());
    }
    if n < 3 || scale <= 0.0 {
        return None;
    }
    let (mut m0, mut m1, mut m2) = (0.0f32, 0.0f32, 0.0f32);
    for i in (0..POINTS).filter(|&i| usable(i)) {
        let (wi, ti) = (get(weight, i), u.get(i).copied().unwrap_or(0.0) / scale);
        m0 += wi;
        m1 += wi * ti;
        m2 += wi * ti * ti;
    }
    let det = m0 * m2 - m1 * m1;
    (det.is_finite() && det > 1e-5 * m0 * m0).then_some(LineMoments {
        scale,
        m0,
        m1,
        m2,
        det,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stat(sd_a: f32, chi2: f32, chi2_curvature: f32) -> RayStat {
        RayStat {
            a: 0.0,
            sd_a,
            chi2,
            chi2_curvature,
        }
    }

    #[test]
    fn verdicts() {
        assert_eq!(stat(0.4, 1.0, 1.0).verdict(3.0, 0.5), RayVerdict::Ray);
        assert_eq!(stat(0.4, 10.0, 1.0).verdict(3.0, 0.5), RayVerdict::Paint);
        assert_eq!(stat(0.4, 1.0, 10.0).verdict(3.0, 0.5), RayVerdict::Paint);
        assert_eq!(stat(0.6, 1.0, 1.0).verdict(3.0, 0.5), RayVerdict::Aligned);
        assert_eq!(
            stat(0.6, 10.0, 1.0).verdict(3.0, 0.5),
            RayVerdict::Undecided
        );
        assert_eq!(
            stat(f32::NAN, 1.0, 1.0).verdict(3.0, 0.5),
            RayVerdict::Aligned
        );
        assert_eq!(
            stat(f32::NAN, f32::NAN, 1.0).verdict(3.0, 0.5),
            RayVerdict::Undecided
        );
    }

    #[test]
    fn vertical_needs_a_paint_lane_for_an_aligned_one() {
        use RayVerdict::*;
        let none = core::iter::empty;
        // A ray: vertical unless parallel to a paint lane, with or without tests.
        assert!(vertical(Ray, true, none()));
        assert!(vertical(Ray, true, [None, Some(false)].into_iter()));
        assert!(!vertical(Ray, true, [Some(false), Some(true)].into_iter()));
        // Aligned: only when tested against a paint lane and parallel to none.
        assert!(!vertical(Aligned, true, none()));
        assert!(!vertical(Aligned, true, [None].into_iter()));
        assert!(vertical(Aligned, true, [None, Some(false)].into_iter()));
        assert!(!vertical(
            Aligned,
            true,
            [Some(false), Some(true)].into_iter()
        ));
        assert!(!vertical(Aligned, false, [Some(false)].into_iter()));
        // Paint and undecided lanes never are.
        assert!(!vertical(Paint, true, [Some(false)].into_iter()));
        assert!(!vertical(Undecided, true, [Some(false)].into_iter()));
    }
}
