//! Shape S_i(τ) of MODEL.md §3.2: S = 1 + σ exp(−ψ τ²). It multiplies only the target, in the
//! numerator of eq. 3. Behind [`Shape`] so that another closed form is one more enum arm.
//!
//! The value is written once over [`Lanes`] ([`gaussian_exp`], [`gaussian_shape`]), inlined into
//! the evaluator, the gradient's value pass, the physical-limit loop and the unit tests; the
//! derivatives are scalar, as the gradient's derivative pass is.

use crate::vector_math::Lanes;

/// The shape closed form.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// S ≡ 1 (MODEL.md eq. 1).
    None,
    /// MODEL.md §3.2: S = 1 + σ exp(−ψ τ²).
    Gaussian,
}

/// S at one (sample, segment) pair and its partial derivatives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShapeValue {
    /// S(τ).
    pub s: f64,
    /// ∂S/∂σ.
    pub d_sigma: f64,
    /// ∂S/∂ψ.
    pub d_psi: f64,
    /// ∂S/∂τ.
    pub d_tau: f64,
}

/// e = exp(−ψ τ²) on the lanes of τ: the transcendental part of the Gaussian shape.
#[inline(always)]
pub(crate) fn gaussian_exp<V: Lanes>(psi: f64, tau: V) -> V {
    crate::vector_math::exp_lanes(V::splat(-psi).mul(tau.mul(tau)))
}

/// S = 1 + σ e given e = [`gaussian_exp`].
#[inline(always)]
pub(crate) fn gaussian_shape<V: Lanes>(sigma: f64, e: V) -> V {
    V::splat(1.0).add(V::splat(sigma).mul(e))
}

impl Shape {
    /// S on the lanes of τ, value only. Skips the exponential when σ = 0 (S ≡ 1 exactly).
    #[inline(always)]
    pub(crate) fn value<V: Lanes>(self, tau: V, sigma: f64, psi: f64) -> V {
        match self {
            Shape::Gaussian if sigma != 0.0 => gaussian_shape(sigma, gaussian_exp(psi, tau)),
            _ => V::splat(1.0),
        }
    }

    /// S(τ) with its derivatives (the exponential is needed even at σ = 0, for ∂S/∂σ).
    pub fn value_grad(self, tau: f64, sigma: f64, psi: f64) -> ShapeValue {
        self.value_grad_from_exp(tau, sigma, psi, gaussian_exp(psi, tau))
    }

    /// As [`Shape::value_grad`] given e = [`gaussian_exp`] (computed four lanes at a time by the
    /// gradient's value pass; unused for [`Shape::None`]).
    #[inline(always)]
    pub fn value_grad_from_exp(self, tau: f64, sigma: f64, psi: f64, e: f64) -> ShapeValue {
        match self {
            Shape::None => ShapeValue {
                s: 1.0,
                d_sigma: 0.0,
                d_psi: 0.0,
                d_tau: 0.0,
            },
            Shape::Gaussian => {
                let tau2 = tau * tau;
                ShapeValue {
                    s: gaussian_shape(sigma, e),
                    d_sigma: e,
                    d_psi: -sigma * tau2 * e,
                    d_tau: -2.0 * sigma * psi * tau * e,
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_shape_and_derivatives() {
        let sh = Shape::Gaussian;
        assert_eq!(sh.value::<f64>(0.0, 0.3, 50.0), 1.3);
        assert_eq!(sh.value::<f64>(0.2, 0.0, 50.0), 1.0);
        let (tau, sigma, psi) = (0.04, -0.2, 300.0);
        let v = sh.value_grad(tau, sigma, psi);
        assert_eq!(v.s.to_bits(), sh.value::<f64>(tau, sigma, psi).to_bits());
        let h = 1e-7;
        let fd = |f: &dyn Fn(f64) -> f64, x: f64| (f(x + h) - f(x - h)) / (2.0 * h);
        assert!((v.d_sigma - fd(&|x| sh.value::<f64>(tau, x, psi), sigma)).abs() < 1e-8);
        assert!((v.d_psi - fd(&|x| sh.value::<f64>(tau, sigma, x), psi)).abs() < 1e-8);
        assert!((v.d_tau - fd(&|x| sh.value::<f64>(x, sigma, psi), tau)).abs() < 1e-7);
    }
}
