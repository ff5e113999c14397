//! Nonlinear least squares for the calibration fits: the `levenberg-marquardt` crate does
//! the minimisation; this file adapts a residual function on plain slices to it, forms the
//! Jacobian by central differences (or takes an analytic one from the caller), and turns the
//! Jacobian at the minimum into parameter standard errors (covariance σ̂²(JᵀJ)⁻¹ with
//! σ̂² = Σr²/(m − n)).

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector};
use nalgebra_lm::storage::Owned;
use nalgebra_lm::{DMatrix as LmMatrix, DVector as LmVector, Dyn};

/// The result of a fit.
#[derive(Debug, Clone)]
pub struct Fit {
    pub params: Vec<f64>,
    /// Residuals at the minimum.
    pub residuals: Vec<f64>,
    /// 1σ standard error of each parameter (NaN when the problem is singular).
    pub sigma: Vec<f64>,
    /// Parameter covariance.
    pub covariance: DMatrix<f64>,
    /// Root mean square of the residuals.
    pub rms: f64,
    /// Whether the minimiser reported convergence.
    pub converged: bool,
    /// Why it stopped, in its words.
    pub termination: String,
}

/// An analytic Jacobian: rows are residuals, columns parameters.
pub type JacobianFn<'a> = &'a dyn Fn(&[f64]) -> DMatrix<f64>;

struct Problem<'a> {
    x: Vec<f64>,
    f: &'a dyn Fn(&[f64]) -> Vec<f64>,
    /// Step per parameter for the central differences.
    steps: &'a [f64],
    /// The caller's Jacobian, used instead of the differences when given.
    jac: Option<JacobianFn<'a>>,
}

impl Problem<'_> {
    fn jacobian_at(&self, x: &[f64]) -> DMatrix<f64> {
        match self.jac {
            Some(j) => j(x),
            None => jacobian(self.f, x, self.steps),
        }
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &LmVector<f64>) {
        self.x.copy_from_slice(x.as_slice());
    }

    fn params(&self) -> LmVector<f64> {
        LmVector::from_column_slice(&self.x)
    }

    fn residuals(&self) -> Option<LmVector<f64>> {
        let r = (self.f)(&self.x);
        r.iter()
            .all(|v| v.is_finite())
            .then(|| LmVector::from_vec(r))
    }

    fn jacobian(&self) -> Option<LmMatrix<f64>> {
        let j = self.jacobian_at(&self.x);
        j.iter()
            .all(|v| v.is_finite())
            .then(|| LmMatrix::from_column_slice(j.nrows(), j.ncols(), j.as_slice()))
    }
}

/// The Jacobian of `f` at `x` by central differences with `steps`.
pub fn jacobian(f: &dyn Fn(&[f64]) -> Vec<f64>, x: &[f64], steps: &[f64]) -> DMatrix<f64> {
    let m = f(x).len();
    let mut j = DMatrix::zeros(m, x.len());
    let mut probe = x.to_vec();
    for (k, &h) in steps.iter().enumerate() {
        probe[k] = x[k] + h;
        let up = f(&probe);
        probe[k] = x[k] - h;
        let down = f(&probe);
        probe[k] = x[k];
        for i in 0..m {
            j[(i, k)] = (up[i] - down[i]) / (2.0 * h);
        }
    }
    j
}

/// Minimises Σ f(x)² from `x0`; `steps` are the difference steps per parameter.
pub fn minimise(f: &dyn Fn(&[f64]) -> Vec<f64>, x0: &[f64], steps: &[f64]) -> Fit {
    minimise_with(f, None, x0, steps)
}

/// Minimises Σ f(x)² from `x0` with the analytic Jacobian `jac` when given (else central
/// differences with `steps`).
pub fn minimise_with(
    f: &dyn Fn(&[f64]) -> Vec<f64>,
    jac: Option<JacobianFn<'_>>,
    x0: &[f64],
    steps: &[f64],
) -> Fit {
    let problem = Problem {
        x: x0.to_vec(),
        f,
        steps,
        jac,
    };
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(200)
        .minimize(problem);
    let residuals = f(&problem.x);
    let m = residuals.len();
    let n = problem.x.len();
    let ssr: f64 = residuals.iter().map(|r| r * r).sum();
    let j = problem.jacobian_at(&problem.x);
    let params = problem.x;
    let dof = m.saturating_sub(n).max(1) as f64;
    let covariance = (j.transpose() * &j)
        .try_inverse()
        .map(|inv| inv * (ssr / dof))
        .unwrap_or_else(|| DMatrix::from_element(n, n, f64::NAN));
    let sigma = (0..n).map(|k| covariance[(k, k)].max(0.0).sqrt()).collect();
    Fit {
        rms: (ssr / m.max(1) as f64).sqrt(),
        params,
        residuals,
        sigma,
        covariance,
        converged: report.termination.was_successful(),
        termination: format!("{:?}", report.termination),
    }
}

/// Smallest over largest singular value of JᵀJ at `x`: near 0 when the data cannot
/// separate some parameters.
pub fn conditioning(f: &dyn Fn(&[f64]) -> Vec<f64>, x: &[f64], steps: &[f64]) -> f64 {
    conditioning_of(&jacobian(f, x, steps))
}

/// Smallest over largest singular value of JᵀJ for a Jacobian `j`.
pub fn conditioning_of(j: &DMatrix<f64>) -> f64 {
    let sv = (j.transpose() * j).singular_values();
    let max = sv.max();
    if max > 0.0 {
        sv.min() / max
    } else {
        0.0
    }
}

/// A column vector from a slice (for callers that build nalgebra values from a fit).
pub fn vector(v: &[f64]) -> DVector<f64> {
    DVector::from_column_slice(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_an_exponential_with_its_uncertainty() {
        // y = a e^{b t} + noise of known size: the standard errors match the scatter.
        let t: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
        let noise: Vec<f64> = (0..50)
            .map(|i| 0.01 * ((i * 7919 % 13) as f64 - 6.0) / 3.7)
            .collect();
        let y: Vec<f64> = t
            .iter()
            .zip(&noise)
            .map(|(t, n)| 2.0 * (-0.5 * t).exp() + n)
            .collect();
        let f = |x: &[f64]| -> Vec<f64> {
            t.iter()
                .zip(&y)
                .map(|(t, y)| x[0] * (x[1] * t).exp() - y)
                .collect()
        };
        let fit = minimise(&f, &[1.0, 0.0], &[1e-6, 1e-6]);
        assert!(fit.converged, "{}", fit.termination);
        assert!(
            (fit.params[0] - 2.0).abs() < 4.0 * fit.sigma[0],
            "{:?}",
            fit
        );
        assert!(
            (fit.params[1] + 0.5).abs() < 4.0 * fit.sigma[1],
            "{:?}",
            fit
        );
        assert!(fit.sigma[0] > 0.0 && fit.sigma[0] < 0.02);
    }
}
