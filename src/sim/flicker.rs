//! Bias instability (flicker, 1/f) as a sum of first-order Gauss-Markov processes.
//!
//! A 1/f spectrum has a flat Allan deviation. A sum of first-order Gauss-Markov (GM)
//! processes of equal variance whose correlation times T_k are evenly spaced in log T
//! has a spectrum that is 1/f between the slowest and fastest corners (the sum of
//! Lorentzians samples ∫ T/(1+(ωT)²) d ln T = π/(2ω)). We place `POLES_PER_DECADE` poles
//! between `0.07·band[0]` and `5·band[1]` (the overhang on both sides flattens the edges of
//! the band; the factors were chosen by minimising the ripple numerically over bands from
//! 3 to 5 decades wide) and scale them so that the geometric mean of the *analytic*
//! Allan deviation of the sum over the band equals the requested floor. The analytic
//! Allan variance of one GM process of variance q² and correlation time T is
//! (IEEE Std 952-1997, annex C)
//!
//! σ²(τ) = (2 q² T / τ) · [1 − (T / 2τ)(3 − 4 e^{−τ/T} + e^{−2τ/T})],
//!
//! and independent processes add. [`FlickerDesign::ripple_db`] reports the worst deviation
//! of the sum from the flat floor inside the band (below 0.2 dB, i.e. 2 %, for bands of 3 to
//! 5 decades: 9 to 11 processes per axis).
//!
//! Slow processes are not advanced at every sample: process k steps exactly (AR(1) over its
//! own interval) every `stride_k ≈ T_k / 16` samples and is linearly interpolated in
//! between, which keeps the cost per sample low. The interpolation only removes content at
//! τ < T_k/16, where that process's Allan deviation is below 0.15 of its peak and far below
//! the white noise of any real sensor.

use super::rng::Stream;

/// Poles (GM processes) per decade of correlation time.
pub const POLES_PER_DECADE: f64 = 1.5;
/// The poles span [`LOW_OVERHANG`·band[0], `HIGH_OVERHANG`·band[1]].
const LOW_OVERHANG: f64 = 0.07;
const HIGH_OVERHANG: f64 = 5.0;
/// A slow process is updated every T/`STRIDE_DIVISOR` seconds (at least every sample).
const STRIDE_DIVISOR: f64 = 16.0;

/// The GM processes that together reproduce a flat Allan floor over a band of τ.
#[derive(Debug, Clone, PartialEq)]
pub struct FlickerDesign {
    /// Correlation times T_k, s.
    pub taus_s: Vec<f64>,
    /// Standard deviation of each process (all equal), in the unit of the floor.
    pub sigma: f64,
}

impl FlickerDesign {
    /// Processes whose summed Allan deviation is `floor` (flat) for τ in `band_s`.
    /// `band_s` must satisfy 0 < band[0] < band[1]; callers validate.
    pub fn new(floor: f64, band_s: [f64; 2]) -> Self {
        let (t_lo, t_hi) = (band_s[0] * LOW_OVERHANG, band_s[1] * HIGH_OVERHANG);
        let decades = (t_hi / t_lo).log10();
        let n = ((decades * POLES_PER_DECADE).round() as usize).max(1) + 1;
        let taus_s: Vec<f64> = (0..n)
            .map(|k| {
                if n == 1 {
                    t_lo
                } else {
                    t_lo * (t_hi / t_lo).powf(k as f64 / (n - 1) as f64)
                }
            })
            .collect();
        let unit = FlickerDesign { taus_s, sigma: 1.0 };
        let gm = unit.geometric_mean_adev(band_s);
        FlickerDesign {
            sigma: if gm > 0.0 { floor / gm } else { 0.0 },
            taus_s: unit.taus_s,
        }
    }

    /// Analytic Allan deviation of the sum at averaging time `tau_s`.
    pub fn adev(&self, tau_s: f64) -> f64 {
        let q2 = self.sigma * self.sigma;
        self.taus_s
            .iter()
            .map(|&t| gm_avar(q2, t, tau_s))
            .sum::<f64>()
            .sqrt()
    }

    /// Worst |20 log10(adev/floor)| over the band, where floor is the design's target.
    pub fn ripple_db(&self, band_s: [f64; 2]) -> f64 {
        let floor = self.geometric_mean_adev(band_s);
        log_grid(band_s)
            .map(|tau| (20.0 * (self.adev(tau) / floor).log10()).abs())
            .fold(0.0, f64::max)
    }

    fn geometric_mean_adev(&self, band_s: [f64; 2]) -> f64 {
        let (sum, n) = log_grid(band_s).fold((0.0, 0usize), |(s, n), tau| {
            (s + self.adev(tau).ln(), n + 1)
        });
        (sum / n as f64).exp()
    }
}

/// 64 log-spaced points across the band, ends included.
fn log_grid(band_s: [f64; 2]) -> impl Iterator<Item = f64> {
    let ratio = band_s[1] / band_s[0];
    (0..64).map(move |i| band_s[0] * ratio.powf(i as f64 / 63.0))
}

/// Allan variance of a first-order GM process with variance `q2` and correlation time `t`.
pub fn gm_avar(q2: f64, t: f64, tau: f64) -> f64 {
    let x = tau / t;
    if x < 1e-4 {
        // Series form avoids cancellation: (2/3) q² τ/T for τ ≪ T.
        return 2.0 * q2 * x / 3.0;
    }
    let bracket = 3.0 - 4.0 * (-x).exp() + (-2.0 * x).exp();
    2.0 * q2 / x * (1.0 - bracket / (2.0 * x))
}

/// A slowly varying random process advanced every `stride` samples and linearly
/// interpolated in between: a first-order GM process (`phi` < 1) or a random walk
/// (`phi` = 1).
#[derive(Debug, Clone)]
pub struct SlowProcess {
    phi: f64,
    step_sigma: f64,
    stride: u32,
    count: u32,
    next: f64,
    value: f64,
    slope: f64,
    stream: Stream,
}

impl SlowProcess {
    /// A GM process of standard deviation `sigma`, correlation time `t_s`, started in its
    /// stationary distribution, sampled every `dt_s`.
    pub fn gauss_markov(sigma: f64, t_s: f64, dt_s: f64, mut stream: Stream) -> Self {
        let stride = stride_for(t_s / STRIDE_DIVISOR, dt_s);
        let phi = (-(f64::from(stride) * dt_s) / t_s).exp();
        let step_sigma = sigma * (1.0 - phi * phi).max(0.0).sqrt();
        let start = sigma * stream.normal();
        Self::started(phi, step_sigma, stride, start, stream)
    }

    /// A random walk starting at 0 whose increments have standard deviation
    /// `k · sqrt(Δt)` (k in unit/√s), updated every `interval_s` and sampled every `dt_s`.
    pub fn random_walk(k: f64, interval_s: f64, dt_s: f64, stream: Stream) -> Self {
        let stride = stride_for(interval_s, dt_s);
        let step_sigma = k * (f64::from(stride) * dt_s).sqrt();
        Self::started(1.0, step_sigma, stride, 0.0, stream)
    }

    fn started(phi: f64, step_sigma: f64, stride: u32, start: f64, stream: Stream) -> Self {
        let mut p = SlowProcess {
            phi,
            step_sigma,
            stride,
            count: 0,
            next: start,
            value: start,
            slope: 0.0,
            stream,
        };
        p.advance_knot();
        p
    }

    fn advance_knot(&mut self) {
        let prev = self.next;
        self.value = prev;
        self.next = self.phi * prev + self.step_sigma * self.stream.normal();
        self.slope = (self.next - prev) / f64::from(self.stride);
        self.count = 0;
    }

    /// The value at the current sample; then moves to the next sample.
    #[inline]
    pub fn step(&mut self) -> f64 {
        let v = self.value;
        self.count += 1;
        if self.count >= self.stride {
            self.advance_knot();
        } else {
            self.value += self.slope;
        }
        v
    }
}

fn stride_for(interval_s: f64, dt_s: f64) -> u32 {
    let s = (interval_s / dt_s).floor();
    if s.is_finite() {
        s.clamp(1.0, f64::from(u32::MAX / 2)) as u32
    } else {
        1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gm_avar_limits() {
        // τ ≪ T: random-walk-like (2/3) q² τ/T; τ ≫ T: white-like 2 q² T/τ.
        let (q2, t) = (4.0, 100.0);
        let small = gm_avar(q2, t, 0.01);
        assert!((small / (2.0 / 3.0 * q2 * 0.01 / t) - 1.0).abs() < 1e-3);
        let large = gm_avar(q2, t, 1e6);
        assert!((large / (2.0 * q2 * t / 1e6) - 1.0).abs() < 1e-3);
    }

    #[test]
    fn design_is_flat_over_its_band() {
        for band in [[1.0, 3600.0], [0.5, 20_000.0], [1.0, 5000.0]] {
            let d = FlickerDesign::new(2.0, band);
            assert!(d.ripple_db(band) < 0.2, "ripple {} dB", d.ripple_db(band));
            for tau in [1.0, 10.0, 100.0, 1000.0, 3600.0] {
                let r = d.adev(tau) / 2.0;
                assert!((r - 1.0).abs() < 0.025, "tau {tau}: ratio {r}");
            }
        }
    }

    #[test]
    fn slow_gm_process_has_its_variance() {
        // Many short independent runs of a GM process: the stationary spread is sigma.
        let mut sum2 = 0.0;
        let n = 4000;
        for i in 0..n {
            let mut p = SlowProcess::gauss_markov(3.0, 5.0, 0.01, Stream::new(i, "gm"));
            for _ in 0..37 {
                p.step();
            }
            let v = p.step();
            sum2 += v * v;
        }
        let sd = (sum2 / n as f64).sqrt();
        // Std error of a sd estimate from n samples: sd/sqrt(2n) ≈ 1.1 %.
        assert!((sd / 3.0 - 1.0).abs() < 0.05, "{sd}");
    }
}
