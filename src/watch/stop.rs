//! "When can I stop": how much more run time makes a noise term's interval as narrow as a
//! target the user sets (`--target bias-instability=10%`).
//!
//! A term's interval is the 95 % interval of the weighted fit ([`fit_noise_terms`]), whose
//! weights are the EDFs of the curve points. Its width is taken as the larger relative
//! distance from the estimate to a bound, max(high/value − 1, 1 − low/value); the target
//! is reached when that is at most the target.
//!
//! A run T' = f·T long has, at every τ of the curve, the EDF that [`edf`] gives for
//! f·N samples (Greenhall–Riley: about proportional to T/τ, so the widths of the squared
//! coefficients shrink roughly as 1/√f), and more octave τ (up to T'/5) where the longer
//! run reaches them. The prediction refits the fitted model's own curve with those EDFs
//! for a run f times as long, and scales the current width by how much that refit's width
//! shrank against the refit at f = 1; f is found by doubling, then bisection. The extra
//! run time is (f − 1)·T. Rough by nature: it assumes the noise keeps the fitted model
//! (no new term appears at the longer τ).

use crate::allan::curve::{point_with_interval, Curve};
use crate::allan::deviation::DeviationKind;
use crate::allan::fit::{fit_noise_terms, NoiseFit, Term, TermEstimate};
use crate::allan::TauGrid;
use serde::Serialize;
use std::collections::HashMap;
use std::str::FromStr;

/// Longest run considered, as a multiple of the current one.
pub const MAX_FACTOR: f64 = 4096.0;

/// A target width for one term.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Target {
    pub term: Term,
    /// Relative width, e.g. 0.1 for ±10 %.
    pub relative: f64,
}

/// The term names `--target` takes.
pub const TERM_NAMES: [(&str, Term); 5] = [
    ("quantization", Term::Quantization),
    ("random-walk", Term::RandomWalk),
    ("bias-instability", Term::BiasInstability),
    ("rate-random-walk", Term::RateRandomWalk),
    ("rate-ramp", Term::RateRamp),
];

/// The `--target` name of a term.
pub fn term_name(term: Term) -> &'static str {
    TERM_NAMES
        .iter()
        .find(|(_, t)| *t == term)
        .map_or("?", |(n, _)| n)
}

impl FromStr for Target {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let names = TERM_NAMES.map(|(n, _)| n).join(", ");
        let (name, value) = s.split_once('=').ok_or_else(|| {
            format!("target `{s}`: expected TERM=WIDTH, e.g. bias-instability=10% (terms: {names})")
        })?;
        let term = TERM_NAMES
            .iter()
            .find(|(n, _)| *n == name.trim())
            .map(|(_, t)| *t)
            .ok_or_else(|| {
                format!(
                    "target `{s}`: unknown term `{}` (terms: {names})",
                    name.trim()
                )
            })?;
        let value = value.trim();
        let relative = match value.strip_suffix('%') {
            Some(p) => p.trim().parse::<f64>().map(|p| p / 100.0),
            None => value.parse::<f64>(),
        }
        .map_err(|_| format!("target `{s}`: width `{value}` is not a number (e.g. 10% or 0.1)"))?;
        if !(relative > 0.0 && relative < 1.0) {
            return Err(format!(
                "target `{s}`: width must be above 0 and below 100 %"
            ));
        }
        Ok(Target { term, relative })
    }
}

/// The answer for one term.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum Prediction {
    /// The interval is already as narrow as the target.
    Reached,
    /// About this much more run time, seconds.
    After { extra_s: f64 },
    /// Not within [`MAX_FACTOR`] times the current run.
    Beyond,
    /// The term is not identified yet (no estimate to narrow).
    NotIdentified,
}

/// Relative width of a term's interval (see the module docs); `None` when unidentified.
pub fn relative_width(t: &TermEstimate) -> Option<f64> {
    let v = t.value.filter(|v| *v > 0.0)?;
    Some((t.high / v - 1.0).max(1.0 - t.low / v))
}

/// The state of `target` that needs no prediction: not identified, or reached; else the
/// current width.
fn current(fit: &NoiseFit, target: &Target) -> Result<f64, Prediction> {
    let Some(now) = fit.get(target.term).and_then(relative_width) else {
        return Err(Prediction::NotIdentified);
    };
    if now <= target.relative {
        return Err(Prediction::Reached);
    }
    Ok(now)
}

/// The prediction for `target` from the axis's current `curve` (of `samples` samples) and
/// its `fit`.
pub fn predict(curve: &Curve, fit: &NoiseFit, samples: usize, target: &Target) -> Prediction {
    let now = match current(fit, target) {
        Ok(now) => now,
        Err(done) => return done,
    };
    let Some(base) = model_width(curve, fit, samples, 1.0, target.term) else {
        return Prediction::NotIdentified;
    };
    let width = |f: f64| model_width(curve, fit, samples, f, target.term).map(|w| now * w / base);
    let reached = |f: f64| width(f).is_some_and(|w| w <= target.relative);
    let mut low = 1.0;
    let mut high = 2.0;
    while !reached(high) {
        if high >= MAX_FACTOR {
            return Prediction::Beyond;
        }
        low = high;
        high *= 2.0;
    }
    // To about 3 % of the factor.
    while high / low > 1.03 {
        let mid = (low * high).sqrt();
        if reached(mid) {
            high = mid;
        } else {
            low = mid;
        }
    }
    let run_s = samples as f64 * curve.tau0;
    Prediction::After {
        extra_s: (high - 1.0) * run_s,
    }
}

/// An axis grows by this fraction before its predictions are computed again.
pub const RECOMPUTE_GROWTH: f64 = 0.05;

/// Predictions kept between refreshes (each costs a few dozen fits): one is computed again
/// once its axis has [`RECOMPUTE_GROWTH`] more samples, and in between its extra run time
/// is counted down by the run time since. Whether a target is reached or its term
/// identified is always decided from the current fit.
#[derive(Debug, Default)]
pub struct Predictions {
    kept: HashMap<(String, Term), (usize, Prediction)>,
}

impl Predictions {
    /// The prediction for `target` on the axis named `axis` (unique within the session).
    pub fn get(
        &mut self,
        axis: &str,
        curve: &Curve,
        fit: &NoiseFit,
        samples: usize,
        target: &Target,
    ) -> Prediction {
        if let Err(done) = current(fit, target) {
            return done;
        }
        let key = (axis.to_string(), target.term);
        if let Some(&(at, kept)) = self.kept.get(&key) {
            let fresh = samples >= at && (samples as f64) < at as f64 * (1.0 + RECOMPUTE_GROWTH);
            match kept {
                Prediction::After { extra_s } if fresh => {
                    let since = (samples - at) as f64 * curve.tau0;
                    return Prediction::After {
                        extra_s: (extra_s - since).max(0.0),
                    };
                }
                Prediction::Beyond if fresh => return kept,
                _ => {}
            }
        }
        let p = predict(curve, fit, samples, target);
        self.kept.insert(key, (samples, p));
        p
    }
}

/// Width of `term` fitted on the model curve of a run `factor` times as long.
fn model_width(
    curve: &Curve,
    fit: &NoiseFit,
    samples: usize,
    factor: f64,
    term: Term,
) -> Option<f64> {
    let kind = DeviationKind::Adev;
    let n = (samples as f64 * factor).round() as usize;
    let phase_points = n + 1;
    let mut last_alpha = curve.points.first()?.alpha;
    let points = TauGrid::Octave
        .factors(kind, phase_points, curve.tau0)
        .into_iter()
        .filter_map(|m| {
            let alpha = match curve.points.iter().find(|p| p.m == m) {
                Some(p) => p.alpha,
                None => last_alpha,
            };
            last_alpha = alpha;
            let tau = m as f64 * curve.tau0;
            let deviation = fit.model_deviation(tau);
            let count = kind.term_count(m, phase_points);
            (deviation > 0.0 && count > 0)
                .then(|| point_with_interval(kind, alpha, m, tau, deviation, count, phase_points))
        })
        .collect();
    let model = Curve {
        kind,
        tau0: curve.tau0,
        points,
    };
    let refit = fit_noise_terms(&model).ok()?;
    refit.get(term).and_then(relative_width)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_parse_and_refuse_nonsense() {
        let t: Target = "bias-instability=10%".parse().unwrap();
        assert_eq!(t.term, Term::BiasInstability);
        assert!((t.relative - 0.1).abs() < 1e-15);
        let t: Target = "random-walk=0.05".parse().unwrap();
        assert_eq!(t.term, Term::RandomWalk);
        for bad in [
            "bias=10%",
            "bias-instability",
            "bias-instability=ten",
            "random-walk=150%",
        ] {
            let e = bad.parse::<Target>().unwrap_err();
            assert!(e.contains(bad), "{e}");
        }
    }
}
