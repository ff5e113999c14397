//! Averaging-time grids: octave, decade, dense log (N per decade), all, or an explicit list.

use super::deviation::DeviationKind;
use std::str::FromStr;

/// How to choose the averaging factors m (τ = m·τ0).
#[derive(Debug, Clone, PartialEq)]
pub enum TauGrid {
    /// m = 1, 2, 4, 8, …
    Octave,
    /// m = 1, 2, 4, 10, 20, 40, 100, … (Stable32's decade grid).
    Decade,
    /// `n` log-spaced factors per decade, rounded to distinct integers.
    Dense(u32),
    /// Every m.
    All,
    /// Explicit τ values in seconds, each rounded to the nearest multiple of τ0.
    List(Vec<f64>),
}

impl FromStr for TauGrid {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        match s {
            "octave" => return Ok(TauGrid::Octave),
            "decade" => return Ok(TauGrid::Decade),
            "all" => return Ok(TauGrid::All),
            _ => {}
        }
        if let Some(n) = s.strip_prefix("dense:") {
            let n: u32 = n
                .parse()
                .map_err(|_| format!("tau grid `{s}`: `dense:N` needs a whole number N"))?;
            if !(1..=1000).contains(&n) {
                return Err(format!("tau grid `{s}`: N must be within 1..=1000"));
            }
            return Ok(TauGrid::Dense(n));
        }
        let list: Result<Vec<f64>, _> = s.split(',').map(|v| v.trim().parse::<f64>()).collect();
        match list {
            Ok(values) if !values.is_empty() && values.iter().all(|v| v.is_finite() && *v > 0.0) => {
                Ok(TauGrid::List(values))
            }
            _ => Err(format!(
                "tau grid `{s}`: expected octave, decade, dense:N, all, or a comma-separated list of positive taus in seconds"
            )),
        }
    }
}

impl TauGrid {
    /// The averaging factors for `kind` on `phase_points` phase points sampled every `tau0`.
    ///
    /// Generated grids stop at Stable32's limit (`m ≤ phase_points / stop_ratio`); `all` and
    /// explicit lists keep every factor for which the estimator has at least one term.
    pub fn factors(&self, kind: DeviationKind, phase_points: usize, tau0: f64) -> Vec<usize> {
        let defined = |m: usize| kind.term_count(m, phase_points) > 0;
        let stop = (phase_points / kind.stop_ratio()).max(1);
        let mut factors: Vec<usize> = match self {
            TauGrid::Octave => std::iter::successors(Some(1usize), |m| m.checked_mul(2))
                .take_while(|&m| m <= stop)
                .collect(),
            TauGrid::Decade => {
                let mut out = Vec::new();
                let mut decade = 1usize;
                'outer: loop {
                    for k in [1, 2, 4] {
                        let m = decade * k;
                        if m > stop {
                            break 'outer;
                        }
                        out.push(m);
                    }
                    match decade.checked_mul(10) {
                        Some(d) => decade = d,
                        None => break,
                    }
                }
                out
            }
            TauGrid::Dense(per_decade) => {
                let mut out = Vec::new();
                let mut k = 0u32;
                loop {
                    let m = 10f64.powf(k as f64 / *per_decade as f64).round() as usize;
                    if m > stop {
                        break;
                    }
                    out.push(m);
                    k += 1;
                }
                out
            }
            TauGrid::All => (1..=phase_points).take_while(|&m| defined(m)).collect(),
            TauGrid::List(taus) => taus
                .iter()
                .map(|t| (t / tau0).round().max(1.0) as usize)
                .collect(),
        };
        factors.sort_unstable();
        factors.dedup();
        factors.retain(|&m| defined(m));
        factors
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn octave_grid_stops_at_stable32_limit() {
        let f = TauGrid::Octave.factors(DeviationKind::Adev, 1001, 1.0);
        assert_eq!(f, vec![1, 2, 4, 8, 16, 32, 64, 128]);
        let f = TauGrid::Octave.factors(DeviationKind::Totdev, 1001, 1.0);
        assert_eq!(*f.last().unwrap(), 256);
    }

    #[test]
    fn dense_grid_is_distinct_and_log_spaced() {
        let f = TauGrid::Dense(10).factors(DeviationKind::Oadev, 100_001, 1.0);
        assert_eq!(&f[..6], &[1, 2, 3, 4, 5, 6]);
        assert!(f.windows(2).all(|w| w[0] < w[1]));
        assert!(*f.last().unwrap() <= 25_000);
    }

    #[test]
    fn parses_lists_and_rejects_garbage() {
        assert_eq!(
            "0.5, 1".parse::<TauGrid>().unwrap(),
            TauGrid::List(vec![0.5, 1.0])
        );
        assert!("dense:x".parse::<TauGrid>().is_err());
        assert!("-1".parse::<TauGrid>().is_err());
        assert!("NaN".parse::<TauGrid>().is_err());
        let f = TauGrid::List(vec![0.5, 1.0, 1e9]).factors(DeviationKind::Oadev, 101, 0.01);
        assert_eq!(f, vec![50]);
    }
}
