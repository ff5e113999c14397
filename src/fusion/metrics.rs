//! Accuracy and consistency of a trajectory against the truth: position, velocity and attitude
//! errors, normalised estimation error squared (NEES), the share of error components inside
//! the filter's 3σ, horizontal/vertical RMS, p95 and max, and the drift during each outage.

use crate::mechanisation::NavState;
use crate::navigator::NavSolution;
use nalgebra::{Cholesky, SVector, Vector3};

/// The errors of one output epoch (estimate minus truth).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorEpoch {
    pub t_s: f64,
    /// NED position error, m.
    pub pos_ned: Vector3<f64>,
    pub vel_ned: Vector3<f64>,
    /// Attitude error φ (rad) with C(est) = (I − [φ×]) C(true).
    pub att: Vector3<f64>,
    /// NEES of the 9 navigation error states (NaN when the covariance is not PD).
    pub nees: f64,
    /// Number of the 9 error components inside ±3σ.
    pub inside_3sigma: u8,
    /// The filter's horizontal position 1σ (√(σ_N² + σ_E²)), m.
    pub horizontal_sigma_m: f64,
}

/// Above this horizontal 1σ the filter's position is reported as unbounded (an INS left
/// without GNSS for a long time; its covariance is capped, its position meaningless), m.
pub const UNBOUNDED_SIGMA_M: f64 = 1000.0;

impl ErrorEpoch {
    pub fn horizontal_m(&self) -> f64 {
        self.pos_ned.xy().norm()
    }
}

/// Errors of `solution` against the true state `truth` (same time).
pub fn epoch_error(solution: &NavSolution, truth: &NavState) -> ErrorEpoch {
    let est = &solution.nav;
    let pos = est.ned_offset_from(truth.lat_rad, truth.lon_rad, truth.height_m);
    let vel = est.vel_ned - truth.vel_ned;
    let att = (truth.quat_nb * est.quat_nb.inverse()).scaled_axis();
    let mut e = SVector::<f64, 9>::zeros();
    e.fixed_rows_mut::<3>(0).copy_from(&pos);
    e.fixed_rows_mut::<3>(3).copy_from(&vel);
    e.fixed_rows_mut::<3>(6).copy_from(&att);
    let nees = Cholesky::new(solution.cov_nav)
        .map(|c| e.dot(&c.solve(&e)))
        .unwrap_or(f64::NAN);
    let inside = (0..9)
        .filter(|&i| e[i].abs() <= 3.0 * solution.cov_nav[(i, i)].sqrt())
        .count() as u8;
    ErrorEpoch {
        t_s: est.t_s,
        pos_ned: pos,
        vel_ned: vel,
        att,
        nees,
        inside_3sigma: inside,
        horizontal_sigma_m: (solution.cov_nav[(0, 0)] + solution.cov_nav[(1, 1)]).sqrt(),
    }
}

/// The errors of each solution that has a truth; `truth_at` gives the true state at a time.
pub fn errors(
    solutions: &[NavSolution],
    mut truth_at: impl FnMut(f64) -> Option<NavState>,
) -> Vec<ErrorEpoch> {
    solutions
        .iter()
        .filter_map(|s| truth_at(s.nav.t_s).map(|t| epoch_error(s, &t)))
        .collect()
}

/// RMS, 95th percentile (nearest rank) and maximum of a set of non-negative errors.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Spread {
    pub rms: f64,
    pub p95: f64,
    pub max: f64,
}

impl Spread {
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        let rank = ((0.95 * v.len() as f64).ceil() as usize).clamp(1, v.len());
        Self {
            rms,
            p95: v[rank - 1],
            max: v[v.len() - 1],
        }
    }
}

/// Horizontal error growth during one GNSS outage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutageDrift {
    pub start_s: f64,
    pub duration_s: f64,
    /// Largest horizontal error inside the outage, m (over the bounded epochs).
    pub max_horizontal_m: f64,
    /// The filter's position became unbounded during the outage.
    pub unbounded: bool,
}

/// Shortest stretch without fixes counted as an outage when the data itself lacks them, s.
pub const MIN_DATA_GAP_S: f64 = 1.0;

/// The windows [start, end) in which the filter had no GNSS: the `withheld` windows (clipped
/// to the replayed `span`) merged with the stretches where the data has no usable fix (a gap
/// between consecutive `fix_times` of at least [`MIN_DATA_GAP_S`] beyond the receiver's
/// interval, and the tail after the last fix). A window starts one receiver interval (the
/// median spacing of the fixes) after the last fix before it and ends at the next fix, so a
/// withheld 60 s window of a 10 Hz receiver is reported as 60 s, not 60.1 s.
pub fn gnss_less_windows(
    fix_times: &[f64],
    withheld: &[(f64, f64)],
    span: (f64, f64),
) -> Vec<(f64, f64)> {
    let (from, to) = span;
    if !(from.is_finite() && to.is_finite() && to > from) {
        return Vec::new();
    }
    let mut diffs: Vec<f64> = fix_times
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .collect();
    diffs.sort_by(f64::total_cmp);
    let interval = diffs.get(diffs.len() / 2).copied().unwrap_or(1.0);
    let mut windows: Vec<(f64, f64)> = withheld
        .iter()
        .map(|&(a, b)| (a.max(from), b.min(to)))
        .filter(|(a, b)| b > a)
        .collect();
    let gap = |a: f64, b: f64| b - a - interval >= MIN_DATA_GAP_S && b - a > 2.5 * interval;
    for w in fix_times.windows(2) {
        if gap(w[0], w[1]) && w[1] > from && w[0] < to {
            windows.push(((w[0] + interval).max(from), w[1].min(to)));
        }
    }
    match fix_times.last() {
        Some(&last) if gap(last, to) => windows.push(((last + interval).max(from), to)),
        None => windows.push((from, to)),
        _ => {}
    }
    if let Some(&first) = fix_times.first() {
        if gap(from - interval, first) {
            windows.push((from, first));
        }
    }
    windows.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut merged: Vec<(f64, f64)> = Vec::with_capacity(windows.len());
    for (a, b) in windows {
        match merged.last_mut() {
            // Windows that overlap or are at most about one fix apart are one blackout.
            Some(last) if a <= last.1 + 1.5 * interval => last.1 = last.1.max(b),
            _ => merged.push((a, b)),
        }
    }
    merged
}

/// Seconds of `window` covered by `withheld` windows (assumed not to overlap each other).
pub fn overlap_s(window: (f64, f64), withheld: &[(f64, f64)]) -> f64 {
    withheld
        .iter()
        .map(|&(a, b)| (b.min(window.1) - a.max(window.0)).max(0.0))
        .sum()
}

/// Summary of a run against the truth.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ErrorSummary {
    pub epochs: usize,
    pub horizontal: Spread,
    pub vertical: Spread,
    /// Horizontal error over epochs outside outages only.
    pub horizontal_gnss: Spread,
    /// Roll, pitch, heading error RMS, degrees (about NED axes).
    pub attitude_rms_deg: [f64; 3],
    /// Mean NEES of the 9 navigation states (9 for a consistent filter).
    pub nees_mean: f64,
    /// Share of all error components inside ±3σ (≈ 0.997 for a consistent filter).
    pub inside_3sigma: f64,
    pub outages: Vec<OutageDrift>,
    /// Epochs whose horizontal σ exceeded [`UNBOUNDED_SIGMA_M`]: left out of the position
    /// statistics above (their position error is unbounded, not a number to average).
    pub unbounded_epochs: usize,
    /// Time of the first such epoch, s.
    pub unbounded_from_s: Option<f64>,
}

/// Summarises epoch errors; `outages` are the [start, end) windows GNSS was withheld.
pub fn summarise(all: &[ErrorEpoch], outages: &[(f64, f64)]) -> ErrorSummary {
    // A NaN σ counts as unbounded.
    let unbounded =
        |e: &ErrorEpoch| e.horizontal_sigma_m.is_nan() || e.horizontal_sigma_m > UNBOUNDED_SIGMA_M;
    let bounded: Vec<ErrorEpoch> = all.iter().filter(|e| !unbounded(e)).copied().collect();
    let errors = &bounded[..];
    let in_outage = |t: f64| outages.iter().any(|&(a, b)| t >= a && t < b);
    let n = errors.len().max(1) as f64;
    let att_rms = |i: usize| {
        (errors.iter().map(|e| e.att[i].powi(2)).sum::<f64>() / n)
            .sqrt()
            .to_degrees()
    };
    let nees: Vec<f64> = errors
        .iter()
        .map(|e| e.nees)
        .filter(|x| x.is_finite())
        .collect();
    ErrorSummary {
        epochs: errors.len(),
        horizontal: Spread::of(errors.iter().map(|e| e.horizontal_m())),
        vertical: Spread::of(errors.iter().map(|e| e.pos_ned.z.abs())),
        horizontal_gnss: Spread::of(
            errors
                .iter()
                .filter(|e| !in_outage(e.t_s))
                .map(|e| e.horizontal_m()),
        ),
        attitude_rms_deg: [att_rms(0), att_rms(1), att_rms(2)],
        nees_mean: nees.iter().sum::<f64>() / nees.len().max(1) as f64,
        inside_3sigma: errors.iter().map(|e| e.inside_3sigma as f64).sum::<f64>() / (9.0 * n),
        outages: outages
            .iter()
            .map(|&(a, b)| OutageDrift {
                start_s: a,
                duration_s: b - a,
                max_horizontal_m: errors
                    .iter()
                    .filter(|e| e.t_s >= a && e.t_s < b)
                    .map(|e| e.horizontal_m())
                    .fold(0.0, f64::max),
                unbounded: all.iter().any(|e| e.t_s >= a && e.t_s < b && unbounded(e)),
            })
            .collect(),
        unbounded_epochs: all.len() - bounded.len(),
        unbounded_from_s: all.iter().find(|e| unbounded(e)).map(|e| e.t_s),
    }
}

/// Average NEES over Monte Carlo runs (Bar-Shalom, Li, Kirubarajan, *Estimation with
/// Applications to Tracking and Navigation*, §5.4.2): at each epoch the mean NEES of M runs
/// times M is χ² with M·n degrees of freedom for a consistent filter of n states, so the
/// epoch's ANEES lies in [χ²(0.025; Mn)/M, χ²(0.975; Mn)/M] with 95 % probability.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Anees {
    pub runs: usize,
    pub epochs: usize,
    /// Mean over epochs of the per-epoch ANEES (n expected).
    pub mean: f64,
    /// The 95 % two-sided band of one epoch's ANEES.
    pub band: (f64, f64),
    /// Share of epochs whose ANEES lies inside the band (0.95 expected), below it and above it.
    pub inside: f64,
    pub below: f64,
    pub above: f64,
    /// Largest per-epoch ANEES.
    pub max: f64,
}

/// [`Anees`] of `nees[run][epoch]` (NaN = no value) for `dof` states; only epochs where every
/// run has a finite NEES count. None without runs or common epochs.
pub fn anees(nees: &[Vec<f64>], dof: usize) -> Option<Anees> {
    let m = nees.len();
    let len = nees.iter().map(Vec::len).min()?;
    let per_epoch: Vec<f64> = (0..len)
        .filter(|&k| nees.iter().all(|r| r[k].is_finite()))
        .map(|k| nees.iter().map(|r| r[k]).sum::<f64>() / m as f64)
        .collect();
    if m == 0 || per_epoch.is_empty() {
        return None;
    }
    let nu = (m * dof) as f64;
    let lo = imulab_allan::edf::chi_squared_quantile(nu, 0.025)? / m as f64;
    let hi = imulab_allan::edf::chi_squared_quantile(nu, 0.975)? / m as f64;
    let n = per_epoch.len() as f64;
    let share = |f: &dyn Fn(f64) -> bool| per_epoch.iter().filter(|x| f(**x)).count() as f64 / n;
    Some(Anees {
        runs: m,
        epochs: per_epoch.len(),
        mean: per_epoch.iter().sum::<f64>() / n,
        band: (lo, hi),
        inside: share(&|x| x >= lo && x <= hi),
        below: share(&|x| x < lo),
        above: share(&|x| x > hi),
        max: per_epoch.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_of_known_values() {
        let s = Spread::of((1..=100).map(f64::from));
        assert_eq!(s.max, 100.0);
        assert_eq!(s.p95, 95.0);
        assert!((s.rms - (338350.0f64 / 100.0).sqrt()).abs() < 1e-12);
        assert_eq!(Spread::of([f64::NAN]), Spread::default());
    }

    #[test]
    fn gnss_less_windows_merge_withheld_and_missing_fixes() {
        // 10 Hz fixes over 0..300 s, none in 100..160 (the data's own outage) nor after 280.
        let fixes: Vec<f64> = (0..2800)
            .map(|k| k as f64 * 0.1)
            .filter(|t| !(100.0..160.0).contains(t))
            .collect();
        // Withheld 150..170 overlaps the data's outage; 200..260 stands alone.
        let w = gnss_less_windows(&fixes, &[(150.0, 170.0), (200.0, 260.0)], (0.0, 300.0));
        assert_eq!(w.len(), 3, "{w:?}");
        assert!((w[0].0 - 100.0).abs() < 1e-6 && (w[0].1 - 170.0).abs() < 1e-9);
        assert!((w[1].0 - 200.0).abs() < 1e-9 && (w[1].1 - 260.0).abs() < 1e-9);
        assert!((w[2].0 - 280.0).abs() < 1e-6 && w[2].1 == 300.0);
        assert!((overlap_s(w[0], &[(150.0, 170.0), (200.0, 260.0)]) - 20.0).abs() < 1e-9);
        // A single missing fix is not an outage; no fix at all is one window.
        let dropped: Vec<f64> = (0..100)
            .filter(|k| *k != 50)
            .map(|k| k as f64 * 0.1)
            .collect();
        assert!(gnss_less_windows(&dropped, &[], (0.0, 9.9)).is_empty());
        assert_eq!(gnss_less_windows(&[], &[], (5.0, 9.0)), vec![(5.0, 9.0)]);
        // A withheld window beyond the data is clipped to it.
        assert_eq!(
            gnss_less_windows(&dropped, &[(9.0, 100.0)], (0.0, 9.9)),
            vec![(9.0, 9.9)]
        );
    }
    /// χ² samples of the right dimension fall inside the band 95 % of the time; scaled
    /// by 2 (an over-confident filter) they fall above it.
    #[test]
    fn anees_band_holds_for_chi_squared_samples() {
        use rand::SeedableRng;
        use rand_distr::{ChiSquared, Distribution};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let chi = ChiSquared::new(9.0).expect("dof");
        let runs: Vec<Vec<f64>> = (0..50)
            .map(|_| (0..2000).map(|_| chi.sample(&mut rng)).collect())
            .collect();
        let a = anees(&runs, 9).expect("anees");
        assert!((a.mean - 9.0).abs() < 0.05, "{a:?}");
        assert!(
            (a.band.0 - 7.86).abs() < 0.03 && (a.band.1 - 10.21).abs() < 0.03,
            "{a:?}"
        );
        assert!((a.inside - 0.95).abs() < 0.015, "{a:?}");
        let doubled: Vec<Vec<f64>> = runs
            .iter()
            .map(|r| r.iter().map(|x| 2.0 * x).collect())
            .collect();
        assert!(anees(&doubled, 9).expect("anees").above > 0.99);
        assert!(anees(&[], 9).is_none());
    }
}
