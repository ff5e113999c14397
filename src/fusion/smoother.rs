//! Rauch-Tung-Striebel fixed-interval smoother for the error-state filter, run backwards over
//! the covariance epochs the filter recorded.
//!
//! With closed-loop feedback the filtered error mean is zero after every epoch, so the RTS
//! recursion works on the error of the filtered nominal state: with A = P(k|k) Φᵀ P(k+1|k)⁻¹,
//! the smoothed error of the predicted nominal at k+1 is d(k+1) + δx_update(k+1) and
//! d(k) = A (d(k+1) + δx_update(k+1)); P_s(k) = P(k|k) + A (P_s(k+1) − P(k+1|k)) Aᵀ.
//! The smoothed state is the filtered nominal with d(k) removed.

use crate::eskf::{corrected, SensorErrors, SmootherRecord};
use crate::mechanisation::NavState;
use crate::models::Layout;
use nalgebra::{Cholesky, SMatrix, SVector};

/// One smoothed epoch.
#[derive(Debug, Clone)]
pub struct SmoothedEpoch<const N: usize> {
    pub nav: NavState,
    pub sensors: SensorErrors,
    pub p: SMatrix<f64, N, N>,
}

/// Runs the backward pass over the records of a filter laid out as `layout`. Epochs whose
/// predicted covariance cannot be factorised keep their filtered values (counted in the
/// returned number).
pub fn smooth<const N: usize>(
    layout: &Layout,
    records: &[SmootherRecord<N>],
) -> (Vec<SmoothedEpoch<N>>, usize) {
    let mut out: Vec<SmoothedEpoch<N>> = Vec::with_capacity(records.len());
    let mut skipped = 0;
    let Some(last) = records.last() else {
        return (out, 0);
    };
    // d(k+1) and P_s(k+1) of the epoch after the one being processed.
    let mut d_next = SVector::<f64, N>::zeros();
    let mut p_next = last.p_post;
    let mut dx_update_next = last.dx_update;
    out.push(SmoothedEpoch {
        nav: last.nav,
        sensors: last.sensors,
        p: last.p_post,
    });
    for rec in records.iter().rev().skip(1) {
        let gain = Cholesky::new(rec.p_prior_next)
            .map(|c| c.solve(&(rec.phi_next * rec.p_post)).transpose());
        let (d, p) = match gain {
            Some(a) => {
                let d = a * (d_next + dx_update_next);
                let mut p = rec.p_post + a * (p_next - rec.p_prior_next) * a.transpose();
                p = 0.5 * (p + p.transpose());
                if d.iter().chain(p.iter()).all(|v| v.is_finite()) {
                    (d, p)
                } else {
                    skipped += 1;
                    (SVector::zeros(), rec.p_post)
                }
            }
            None => {
                skipped += 1;
                (SVector::zeros(), rec.p_post)
            }
        };
        let (nav, sensors) = corrected(layout, &rec.nav, &rec.sensors, &d);
        out.push(SmoothedEpoch { nav, sensors, p });
        d_next = d;
        p_next = p;
        dx_update_next = rec.dx_update;
    }
    out.reverse();
    (out, skipped)
}
