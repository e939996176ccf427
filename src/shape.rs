//! Shape S_i(τ) of MODEL.md §3.2: S = 1 + σ exp(−ψ τ²). It multiplies only the target, in the
//! numerator of eq. 3. Behind [`Shape`] so that another closed form is one more enum arm.

use crate::vector_math::exp;

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

impl Shape {
    /// S(τ) only. Skips the exponential when σ = 0 (S ≡ 1 exactly).
    #[inline(always)]
    pub fn value(self, tau: f64, sigma: f64, psi: f64) -> f64 {
        match self {
            Shape::None => 1.0,
            Shape::Gaussian => {
                if sigma == 0.0 {
                    1.0
                } else {
                    1.0 + sigma * exp(-psi * (tau * tau))
                }
            }
        }
    }

    /// S(τ) with its derivatives (the exponential is needed even at σ = 0, for ∂S/∂σ).
    #[inline(always)]
    pub fn value_grad(self, tau: f64, sigma: f64, psi: f64) -> ShapeValue {
        match self {
            Shape::None => ShapeValue {
                s: 1.0,
                d_sigma: 0.0,
                d_psi: 0.0,
                d_tau: 0.0,
            },
            Shape::Gaussian => self.value_grad_from_exp(tau, sigma, psi, exp(-psi * (tau * tau))),
        }
    }

    /// As [`Shape::value_grad`] given e = exp(−ψ τ²) (computed four lanes at a time by the
    /// vectorised value pass; unused for [`Shape::None`]).
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
                    s: 1.0 + sigma * e,
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
        assert_eq!(sh.value(0.0, 0.3, 50.0), 1.3);
        assert_eq!(sh.value(0.2, 0.0, 50.0), 1.0);
        let (tau, sigma, psi) = (0.04, -0.2, 300.0);
        let v = sh.value_grad(tau, sigma, psi);
        let h = 1e-7;
        let fd = |f: &dyn Fn(f64) -> f64, x: f64| (f(x + h) - f(x - h)) / (2.0 * h);
        assert!((v.d_sigma - fd(&|x| sh.value(tau, x, psi), sigma)).abs() < 1e-8);
        assert!((v.d_psi - fd(&|x| sh.value(tau, sigma, x), psi)).abs() < 1e-8);
        assert!((v.d_tau - fd(&|x| sh.value(x, sigma, psi), tau)).abs() < 1e-7);
    }
}
