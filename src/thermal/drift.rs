//! The slow bias drift of one axis (bias instability and rate random walk) and the variance
//! it adds to a fitted quantity that is a linear combination of block means.
//!
//! A least-squares fit that assumes white residuals does not see the drift: over a
//! multi-hour run the bias wanders by more than the white noise of a block mean, and the
//! wander is correlated over hours. The drift is described by its structure function
//! D(Δ) = E[(b(t + Δ) − b(t))²] of the block means of width w,
//!
//! D(Δ) = (2B²/π)(γ + ln(πΔ/w)) + K²Δ, Δ > 0,
//!
//! for a flicker floor of bias instability B (Allan floor 0.664·B, one-sided spectrum
//! B²/(πf)) and a rate random walk K (γ is Euler's constant). A combination Σ wᵢ bᵢ whose
//! weights sum to 0 (a difference, a slope, the settled-minus-transient split of an
//! exponential) has the drift variance −½ ΣΣ wᵢ wⱼ D(|tᵢ − tⱼ|), which needs no stationary
//! variance of the drift (a random walk has none).

use imulab_allan::curve::Curve;
use imulab_allan::fit::{NoiseFit, Term, BIAS_INSTABILITY_FACTOR};

/// Euler's constant γ.
const EULER_GAMMA: f64 = 0.577_215_664_901_532_9;
/// The double sum runs over at most this many time bins.
pub const MAX_BINS: usize = 1000;
/// Curve points at the long-τ end that estimate B when the noise fit did not identify it.
const EXCESS_POINTS: usize = 4;

/// The drift terms of one axis, in the input unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Drift {
    /// B², unit².
    pub flicker: f64,
    /// K², unit²/s.
    pub random_walk: f64,
}

/// One plateau's Allan curve and noise fit, and how long it lasted (the weight of its terms).
pub struct PlateauCurve<'a> {
    pub curve: &'a Curve,
    pub fit: &'a NoiseFit,
    pub duration_s: f64,
}

impl Drift {
    /// The drift from the noise terms of the plateaus (duration-weighted mean of B² and K²).
    /// B comes from the fit where it identified B, otherwise from the EDF-weighted excess of
    /// the Allan variance over the fitted model of the other terms on the last
    /// `EXCESS_POINTS` points of the curve (an octave grid: the last 4 octaves); K is 0 where
    /// the fit did not identify it. `None` without a plateau.
    pub fn from_plateaus(plateaus: &[PlateauCurve]) -> Option<Drift> {
        let total: f64 = plateaus.iter().map(|p| p.duration_s).sum();
        if plateaus.is_empty() || total <= 0.0 {
            return None;
        }
        let (mut flicker, mut random_walk) = (0.0, 0.0);
        for p in plateaus {
            let share = p.duration_s / total;
            let identified = |term: Term| p.fit.get(term).and_then(|t| t.value);
            let b2 = match identified(Term::BiasInstability) {
                Some(b) => b * b,
                None => excess_flicker(p.curve, p.fit),
            };
            let k2 = identified(Term::RateRandomWalk).map_or(0.0, |k| k * k);
            flicker += share * b2;
            random_walk += share * k2;
        }
        Some(Drift {
            flicker,
            random_walk,
        })
    }

    /// D(Δ) of block means of width `block_s`; 0 for Δ ≤ 0, never negative.
    pub fn structure(&self, lag_s: f64, block_s: f64) -> f64 {
        if lag_s <= 0.0 {
            return 0.0;
        }
        let flicker = 2.0 * self.flicker / std::f64::consts::PI
            * (EULER_GAMMA + (std::f64::consts::PI * lag_s / block_s).ln());
        (flicker + self.random_walk * lag_s).max(0.0)
    }

    /// Drift variance of Σ wᵢ b(tᵢ) for weights that sum to 0 (block means of width
    /// `block_s` at `times`, s). The samples are gathered into at most [`MAX_BINS`] bins of
    /// equal width (weights summed per bin); two blocks in one bin count as a third of the
    /// bin apart on average (the mean lag of two uniform points: the mean log lag for the
    /// flicker term).
    pub fn variance(&self, times: &[f64], weights: &[f64], block_s: f64) -> f64 {
        let n = times.len().min(weights.len());
        if n < 2 {
            return 0.0;
        }
        let (lo, hi) = times[..n]
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &t| {
                (lo.min(t), hi.max(t))
            });
        let width = ((hi - lo) / MAX_BINS as f64)
            .max(block_s)
            .max(f64::MIN_POSITIVE);
        let count = (((hi - lo) / width).floor() as usize + 1).min(MAX_BINS + 1);
        let mut bins = vec![0.0; count];
        for (&t, &w) in times[..n].iter().zip(&weights[..n]) {
            let k = (((t - lo) / width).floor() as usize).min(count - 1);
            bins[k] += w;
        }
        // D per bin lag; lag 0 is the mean over two blocks of one bin (0 for one-block bins).
        let mut by_lag: Vec<f64> = (0..count)
            .map(|k| self.structure(k as f64 * width, block_s))
            .collect();
        by_lag[0] = if width > 1.5 * block_s {
            let flicker = 2.0 * self.flicker / std::f64::consts::PI
                * (EULER_GAMMA + (std::f64::consts::PI * width * (-1.5f64).exp() / block_s).ln());
            flicker.max(0.0) + self.random_walk * width / 3.0
        } else {
            0.0
        };
        let occupied: Vec<(usize, f64)> = bins
            .iter()
            .enumerate()
            .filter(|(_, &w)| w != 0.0)
            .map(|(k, &w)| (k, w))
            .collect();
        let mut sum = 0.0;
        for &(k, wk) in &occupied {
            for &(l, wl) in &occupied {
                sum += wk * wl * by_lag[k.abs_diff(l)];
            }
        }
        (-0.5 * sum).max(0.0)
    }

    /// Standard deviation of the drift of Σ wᵢ b(tᵢ) (see [`Drift::variance`]).
    pub fn sigma(&self, times: &[f64], weights: &[f64], block_s: f64) -> f64 {
        self.variance(times, weights, block_s).sqrt()
    }
}

/// B² from the EDF-weighted excess of the curve's Allan variance over the fitted model of
/// the identified terms (B not among them) on its last [`EXCESS_POINTS`] points; never
/// negative.
fn excess_flicker(curve: &Curve, fit: &NoiseFit) -> f64 {
    let points: Vec<(f64, f64)> = curve
        .points
        .iter()
        .filter_map(|p| {
            let edf = p.edf.filter(|e| *e > 0.0)?;
            (p.deviation.is_finite() && p.deviation > 0.0).then(|| {
                let model = fit.model_deviation(p.tau);
                (edf, p.deviation * p.deviation - model * model)
            })
        })
        .collect();
    let tail = &points[points.len().saturating_sub(EXCESS_POINTS)..];
    let edf: f64 = tail.iter().map(|p| p.0).sum();
    if edf <= 0.0 {
        return 0.0;
    }
    let excess = tail.iter().map(|p| p.0 * p.1).sum::<f64>() / edf;
    (excess / (BIAS_INSTABILITY_FACTOR * BIAS_INSTABILITY_FACTOR)).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use imulab_allan::analysis::{analyse_axis, AnalysisOptions};
    use imulab_allan::deviation::DeviationKind;
    use imulab_allan::input::AxisSeries;
    use imulab_allan::taus::TauGrid;
    use imulab_allan::units::RateUnit;
    use imulab_sim::flicker::{FlickerDesign, SlowProcess};
    use imulab_sim::rng::Stream;

    /// `n` samples at 1 Hz of a flicker process of bias instability `b` plus white noise.
    fn flicker_series(b: f64, white: f64, n: usize, seed: u64) -> Vec<f64> {
        let design = FlickerDesign::new(BIAS_INSTABILITY_FACTOR * b, [1.0, 5000.0]);
        let mut procs: Vec<SlowProcess> = design
            .taus_s
            .iter()
            .enumerate()
            .map(|(k, &t)| {
                SlowProcess::gauss_markov(design.sigma, t, 1.0, Stream::new(seed, &format!("f{k}")))
            })
            .collect();
        let mut noise = Stream::new(seed, "white");
        (0..n)
            .map(|_| procs.iter_mut().map(|p| p.step()).sum::<f64>() + white * noise.normal())
            .collect()
    }

    #[test]
    fn a_random_walk_difference_grows_with_the_lag() {
        let drift = Drift {
            flicker: 0.0,
            random_walk: 4.0,
        };
        let v = drift.variance(&[10.0, 110.0], &[1.0, -1.0], 1.0);
        assert!((v - 400.0).abs() < 1e-9, "{v}");
        // Weights that do not cancel a constant have no drift variance defined: a sum of 0.
        let zero = drift.variance(&[10.0, 110.0], &[0.0, 0.0], 1.0);
        assert_eq!(zero, 0.0);
        // Binning keeps the answer for points spread over far more than MAX_BINS blocks.
        let times: Vec<f64> = (0..20_000).map(|i| i as f64 + 0.5).collect();
        let weights: Vec<f64> = (0..20_000)
            .map(|i| match i {
                0..=99 => 0.01,
                19_900.. => -0.01,
                _ => 0.0,
            })
            .collect();
        let v = drift.variance(&times, &weights, 1.0);
        let exact = 4.0 * (19_950.0 - 50.0 - 100.0 / 3.0);
        assert!((v / exact - 1.0).abs() < 0.02, "{v} against {exact}");
    }

    #[test]
    fn the_difference_of_two_block_means_of_flicker_has_the_predicted_variance() {
        // Means of samples 0..200 and 1800..2000 of a flicker process (B = 1, 1 Hz blocks).
        let (n, a, b) = (2000, 0..200, 1800..2000);
        let realisations = 1500;
        let differences: Vec<f64> = (0..realisations)
            .map(|seed| {
                let x = flicker_series(1.0, 0.0, n, seed);
                let mean = |r: std::ops::Range<usize>| {
                    let len = r.len() as f64;
                    x[r].iter().sum::<f64>() / len
                };
                mean(a.clone()) - mean(b.clone())
            })
            .collect();
        let empirical = differences.iter().map(|d| d * d).sum::<f64>() / realisations as f64;
        let times: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let weights: Vec<f64> = (0..n)
            .map(|i| {
                if a.contains(&i) {
                    1.0 / a.len() as f64
                } else if b.contains(&i) {
                    -1.0 / b.len() as f64
                } else {
                    0.0
                }
            })
            .collect();
        let drift = Drift {
            flicker: 1.0,
            random_walk: 0.0,
        };
        let predicted = drift.variance(&times, &weights, 1.0);
        assert!(
            (predicted / empirical - 1.0).abs() < 0.10,
            "predicted {predicted}, empirical {empirical}"
        );
    }

    #[test]
    fn the_terms_come_from_the_plateau_fits() {
        let x = flicker_series(1e-3, 2e-3, 40_000, 7);
        let result = analyse_axis(
            "dut",
            AxisSeries::one_segment("gyro_x", 1.0, x),
            &AnalysisOptions {
                kind: DeviationKind::Oadev,
                grid: TauGrid::Octave,
                fit: true,
                unit: RateUnit::RadPerSecond,
                sensor: None,
            },
        );
        let fit = result.fit.expect("no noise fit");
        let plateau = PlateauCurve {
            curve: &result.curve,
            fit: &fit,
            duration_s: 40_000.0,
        };
        let drift = Drift::from_plateaus(&[plateau]).unwrap();
        let b = drift.flicker.sqrt();
        assert!((b / 1e-3 - 1.0).abs() < 0.3, "B {b}");
        // Without an identified B, the excess over the white line gives it.
        let mut white_only = fit.clone();
        for t in &mut white_only.terms {
            if t.term != Term::RandomWalk {
                t.value = None;
            }
        }
        let from_excess = excess_flicker(&result.curve, &white_only).sqrt();
        assert!(
            (from_excess / 1e-3 - 1.0).abs() < 0.3,
            "B from excess {from_excess}"
        );
        assert!(Drift::from_plateaus(&[]).is_none());
    }
}
