//! Thermal-chamber analysis: bias against temperature (binned means with their spread and
//! a fitted temperature coefficient) and, for a stepped profile, the plateaus on which one
//! Allan curve each is computed (settling time at the start of each plateau excluded).

use serde::{Deserialize, Serialize};

/// One temperature bin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TemperatureBin {
    pub temperature: f64,
    pub mean: f64,
    /// Standard deviation of the samples in the bin.
    pub spread: f64,
    pub samples: u64,
}

/// Bias-versus-temperature summary of one axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThermalSummary {
    pub bin_width: f64,
    pub bins: Vec<TemperatureBin>,
    /// Least-squares slope of bias against temperature (input units per °C), weighted by
    /// samples per bin, and its standard error; `None` with fewer than two bins.
    pub coefficient: Option<f64>,
    pub coefficient_std_error: Option<f64>,
    pub plateaus: Vec<Plateau>,
}

/// A stretch of near-constant temperature.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Plateau {
    /// Sample range used (settling excluded), half-open.
    pub start: usize,
    pub end: usize,
    pub temperature: f64,
    /// Samples skipped at the start as settling time.
    pub settling_samples: usize,
}

/// Bins `(temperature, rate)` pairs by `bin_width` °C (Welford per bin) and fits a line.
pub fn bias_versus_temperature(
    rate: &[f64],
    temperature: &[f32],
    bin_width: f64,
) -> ThermalSummary {
    use std::collections::BTreeMap;
    let mut bins: BTreeMap<i64, (u64, f64, f64, f64)> = BTreeMap::new(); // n, mean, m2, temp sum
    for (&r, &t) in rate.iter().zip(temperature) {
        let t = f64::from(t);
        if !(t.is_finite() && r.is_finite()) {
            continue;
        }
        let key = (t / bin_width).floor() as i64;
        let e = bins.entry(key).or_insert((0, 0.0, 0.0, 0.0));
        e.0 += 1;
        let delta = r - e.1;
        e.1 += delta / e.0 as f64;
        e.2 += delta * (r - e.1);
        e.3 += t;
    }
    let bins: Vec<TemperatureBin> = bins
        .values()
        .map(|&(n, mean, m2, tsum)| TemperatureBin {
            temperature: tsum / n as f64,
            mean,
            spread: if n > 1 {
                (m2 / (n - 1) as f64).sqrt()
            } else {
                0.0
            },
            samples: n,
        })
        .collect();
    let (coefficient, coefficient_std_error) = weighted_slope(&bins);
    ThermalSummary {
        bin_width,
        bins,
        coefficient,
        coefficient_std_error,
        plateaus: Vec::new(),
    }
}

/// Slope of bin means against bin temperatures, weighted by sample count.
fn weighted_slope(bins: &[TemperatureBin]) -> (Option<f64>, Option<f64>) {
    if bins.len() < 2 {
        return (None, None);
    }
    let w: f64 = bins.iter().map(|b| b.samples as f64).sum();
    let tm = bins
        .iter()
        .map(|b| b.samples as f64 * b.temperature)
        .sum::<f64>()
        / w;
    let ym = bins.iter().map(|b| b.samples as f64 * b.mean).sum::<f64>() / w;
    let sxx: f64 = bins
        .iter()
        .map(|b| b.samples as f64 * (b.temperature - tm).powi(2))
        .sum();
    let sxy: f64 = bins
        .iter()
        .map(|b| b.samples as f64 * (b.temperature - tm) * (b.mean - ym))
        .sum();
    if sxx <= 0.0 {
        return (None, None);
    }
    let slope = sxy / sxx;
    // Standard error from the scatter of bin means about the line (bins as observations).
    let k = bins.len() as f64;
    let residual: f64 = bins
        .iter()
        .map(|b| b.samples as f64 * (b.mean - ym - slope * (b.temperature - tm)).powi(2))
        .sum();
    let se = if k > 2.0 {
        Some((residual / (k - 2.0) / sxx).sqrt())
    } else {
        None
    };
    (Some(slope), se)
}

/// Finds plateaus of a stepped temperature profile: runs where the temperature stays
/// within `tolerance` °C of its running median for at least `min_samples`; the first
/// `settling_samples` of each run are excluded.
pub fn find_plateaus(
    temperature: &[f32],
    tolerance: f64,
    min_samples: usize,
    settling_samples: usize,
) -> Vec<Plateau> {
    let mut plateaus = Vec::new();
    let mut start = 0;
    while start < temperature.len() {
        let reference = f64::from(temperature[start]);
        let mut end = start + 1;
        while end < temperature.len()
            && (f64::from(temperature[end]) - reference).abs() <= tolerance
        {
            end += 1;
        }
        let used_start = start + settling_samples;
        if end > used_start && end - used_start >= min_samples {
            let mean = temperature[used_start..end]
                .iter()
                .map(|&t| f64::from(t))
                .sum::<f64>()
                / (end - used_start) as f64;
            plateaus.push(Plateau {
                start: used_start,
                end,
                temperature: mean,
                settling_samples,
            });
        }
        start = end;
    }
    plateaus
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_linear_temperature_coefficient() {
        let temps: Vec<f32> = (0..6000).map(|i| -20.0 + (i / 100) as f32).collect();
        let rate: Vec<f64> = temps
            .iter()
            .enumerate()
            .map(|(i, &t)| 0.01 + 0.002 * f64::from(t) + if i % 2 == 0 { 1e-4 } else { -1e-4 })
            .collect();
        let s = bias_versus_temperature(&rate, &temps, 5.0);
        assert_eq!(s.bins.len(), 12);
        assert!((s.coefficient.unwrap() - 0.002).abs() < 1e-9);
        assert!(s.bins.iter().all(|b| b.spread > 0.0));
    }

    #[test]
    fn finds_steps_and_skips_settling() {
        let mut temps = vec![25.0f32; 1000];
        temps.extend(std::iter::repeat_n(60.0f32, 1000));
        temps.extend((0..100).map(|i| 59.0 - i as f32));
        let p = find_plateaus(&temps, 0.5, 500, 100);
        assert_eq!(p.len(), 2);
        assert_eq!((p[0].start, p[0].end), (100, 1000));
        assert_eq!((p[1].start, p[1].end), (1100, 2000));
        assert!((p[1].temperature - 60.0).abs() < 1e-9);
    }
}
