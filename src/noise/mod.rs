//! The IMU noise model that the Allan fit reads, the simulator generates and the filter's
//! process noise is built from: its five terms (quantization Q, random walk N, bias
//! instability B, rate random walk K, rate ramp R) and their Allan-variance signatures
//!
//! σ²(τ) = 3Q²/τ² + N²/τ + (2 ln2/π)B² + K²τ/3 + R²τ²/2
//!
//! (IEEE Std 952, annex C). One definition, so a preset's B is what the fit reads back.

use serde::{Deserialize, Serialize};

/// The five terms of the model, in base units of the input rate `u` (rad/s or m/s²).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Term {
    /// Q: quantization noise, u·s.
    Quantization,
    /// N: angle / velocity random walk (white rate noise density), u·√s = u/√Hz.
    RandomWalk,
    /// B: bias instability (flicker floor), u.
    BiasInstability,
    /// K: rate / acceleration random walk, u/√s.
    RateRandomWalk,
    /// R: rate ramp, u/s.
    RateRamp,
}

impl Term {
    pub const ALL: [Term; 5] = [
        Term::Quantization,
        Term::RandomWalk,
        Term::BiasInstability,
        Term::RateRandomWalk,
        Term::RateRamp,
    ];

    /// The term's contribution to the Allan variance σ²(τ) per unit of its squared
    /// coefficient.
    pub fn allan_variance(self, tau: f64) -> f64 {
        match self {
            Term::Quantization => 3.0 / (tau * tau),
            Term::RandomWalk => 1.0 / tau,
            Term::BiasInstability => BIAS_INSTABILITY_FACTOR * BIAS_INSTABILITY_FACTOR,
            Term::RateRandomWalk => tau / 3.0,
            Term::RateRamp => tau * tau / 2.0,
        }
    }

    /// The letter of the term in IEEE Std 952 notation.
    pub fn symbol(self) -> &'static str {
        match self {
            Term::Quantization => "Q",
            Term::RandomWalk => "N",
            Term::BiasInstability => "B",
            Term::RateRandomWalk => "K",
            Term::RateRamp => "R",
        }
    }
}

/// √(2 ln 2 / π) ≈ 0.664: the flicker floor of σ(τ) relative to B.
pub const BIAS_INSTABILITY_FACTOR: f64 = 0.664_282_470_267_960_1;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bias_instability_factor_is_the_flicker_floor_of_the_allan_deviation() {
        let exact = (2.0 * std::f64::consts::LN_2 / std::f64::consts::PI).sqrt();
        assert!((BIAS_INSTABILITY_FACTOR - exact).abs() < 1e-15);
        assert_eq!(
            Term::BiasInstability.allan_variance(1.0),
            Term::BiasInstability.allan_variance(1e4)
        );
    }

    #[test]
    fn each_term_has_its_allan_slope() {
        // log-log slope of σ²(τ): −2, −1, 0, +1, +2.
        for (term, slope) in Term::ALL.iter().zip([-2.0, -1.0, 0.0, 1.0, 2.0]) {
            let ratio = term.allan_variance(10.0) / term.allan_variance(1.0);
            assert!((ratio.log10() - slope).abs() < 1e-12, "{term:?}");
        }
    }
}
