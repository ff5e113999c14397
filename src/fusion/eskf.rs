//! The error-state (indirect) Kalman filter around the strapdown solution: covariance
//! propagation at `covariance_interval_s`, Joseph-form updates with symmetry enforced and
//! positive-definiteness checked (a failed check rejects the update and counts an event; the
//! covariance is never left non-finite), closed-loop feedback of the estimated errors into the
//! navigation state and sensor-error estimates, and the records an RTS smoother needs.
//!
//! `N` is 15 to 30 (see [`crate::models::Layout`] for the state layout); all matrices are
//! fixed-size, so the filter loop does not allocate (smoother records aside).

use crate::config::FusionConfig;
use crate::mechanisation::{ImuInput, Mechaniser, NavState};
use crate::models::{self, Layout, Measurement, ATT, BA, BG, POS, SA, SG, VEL};
use nalgebra::{Cholesky, SMatrix, SVector, UnitQuaternion, Vector3};

/// Estimated sensor errors (subtracted from the raw IMU data before mechanisation).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SensorErrors {
    pub gyro_bias: Vector3<f64>,
    pub accel_bias: Vector3<f64>,
    /// Scale-factor errors as fractions (zero with 15 states).
    pub gyro_scale: Vector3<f64>,
    pub accel_scale: Vector3<f64>,
    /// The receiver's correlated position error, NED, m (zero unless modelled, see
    /// `config::GnssPositionError`).
    pub gnss_position_error: Vector3<f64>,
}

impl SensorErrors {
    /// Applies the correction ω = (ω̃ − b) / (1 + s) to an IMU input.
    pub fn correct(&self, raw: &ImuInput) -> ImuInput {
        let fix = |v: Vector3<f64>, b: Vector3<f64>, s: Vector3<f64>| {
            (v - b).component_div(&(Vector3::repeat(1.0) + s))
        };
        match *raw {
            ImuInput::Rates { t_s, gyro, accel } => ImuInput::Rates {
                t_s,
                gyro: fix(gyro, self.gyro_bias, self.gyro_scale),
                accel: fix(accel, self.accel_bias, self.accel_scale),
            },
            ImuInput::Increments {
                t_s,
                dt_s,
                dtheta,
                dvel,
            } => ImuInput::Increments {
                t_s,
                dt_s,
                dtheta: fix(dtheta, self.gyro_bias * dt_s, self.gyro_scale),
                dvel: fix(dvel, self.accel_bias * dt_s, self.accel_scale),
            },
        }
    }
}

/// Kinds of measurement update, for counting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UpdateKind {
    GnssPosition,
    GnssPositionVelocity,
    NonHolonomic,
    ZeroVelocity,
}

/// What happened to one update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UpdateOutcome {
    Applied {
        nis: f64,
    },
    /// Innovation failed the χ² gate.
    Gated {
        nis: f64,
    },
    /// Innovation covariance or updated covariance not positive definite, or non-finite
    /// numbers: the update was dropped and the covariance left as it was.
    Rejected,
}

/// Event counters of a filter run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FilterStats {
    pub imu_steps: u64,
    pub covariance_steps: u64,
    pub updates: u64,
    pub gated: u64,
    /// Updates dropped because a covariance lost positive-definiteness or went non-finite.
    pub pd_events: u64,
    /// Covariance propagations that produced non-finite numbers and were replaced.
    pub propagation_repairs: u64,
    /// Covariance rows scaled down because a variance passed its cap (unaided divergence).
    pub covariance_caps: u64,
    /// Navigation states that left the sane envelope and were reset to the last sane one.
    pub divergence_resets: u64,
}

/// Largest 1σ the covariance may hold for position (m), velocity (m/s) and attitude (rad); an
/// INS without aiding for hours diverges (the vertical channel exponentially) and this keeps
/// the numbers finite.
pub const SIGMA_CAP: (f64, f64, f64) = (1e5, 1e3, std::f64::consts::PI);

/// A navigation state the mechanisation can continue from: finite, away from the poles,
/// below 100 km and 10 km/s.
pub fn is_sane(nav: &NavState) -> bool {
    nav.lat_rad.is_finite()
        && nav.lat_rad.abs() < 89.5f64.to_radians()
        && nav.lon_rad.is_finite()
        && nav.height_m.abs() < 1e5
        && nav.vel_ned.iter().all(|v| v.is_finite())
        && nav.vel_ned.norm() < 1e4
        && nav.quat_nb.coords.iter().all(|v| v.is_finite())
}

/// Scales the rows and columns of variances above their caps down (a congruence with a
/// positive diagonal matrix, so positive-definiteness is kept). Returns whether it did.
fn cap_covariance<const N: usize>(p: &mut SMatrix<f64, N, N>) -> bool {
    let mut capped = false;
    for i in 0..9 {
        let cap = [SIGMA_CAP.0, SIGMA_CAP.1, SIGMA_CAP.2][i / 3].powi(2);
        if p[(i, i)] > cap {
            let s = (cap / p[(i, i)]).sqrt();
            for j in 0..N {
                p[(i, j)] *= s;
                p[(j, i)] *= s;
            }
            capped = true;
        }
    }
    capped
}

/// One covariance epoch as the RTS smoother needs it.
#[derive(Debug, Clone)]
pub struct SmootherRecord<const N: usize> {
    /// Filtered nominal state at the epoch (after updates).
    pub nav: NavState,
    pub sensors: SensorErrors,
    /// Filtered covariance P(k|k).
    pub p_post: SMatrix<f64, N, N>,
    /// Sum of the error-state corrections applied by updates at this epoch.
    pub dx_update: SVector<f64, N>,
    /// Transition to the next epoch and the predicted covariance P(k+1|k).
    pub phi_next: SMatrix<f64, N, N>,
    pub p_prior_next: SMatrix<f64, N, N>,
}

/// Strapdown INS with its error-state Kalman filter.
#[derive(Debug, Clone)]
pub struct Ins<const N: usize> {
    pub nav: NavState,
    pub sensors: SensorErrors,
    pub p: SMatrix<f64, N, N>,
    pub stats: FilterStats,
    config: FusionConfig,
    layout: Layout,
    /// The in-run parts of the gyro and accelerometer bias estimates when the turn-on biases
    /// have states of their own: they decay as their process does, within the sums in
    /// `sensors`.
    in_run_bias: (Vector3<f64>, Vector3<f64>),
    mech: Mechaniser,
    q_psd: SVector<f64, N>,
    /// Accumulated over the current covariance interval: time, ∫ω dt, ∫f dt.
    acc_dt: f64,
    acc_dtheta: Vector3<f64>,
    acc_dvel: Vector3<f64>,
    /// Last bias-corrected rate, for the lever-arm velocity term.
    last_gyro: Vector3<f64>,
    /// The latest state that passed [`is_sane`], to fall back on.
    last_sane: NavState,
    /// Whether the covariance is propagated (off only for pure dead reckoning, see
    /// [`Ins::set_covariance_propagation`]).
    covariance_on: bool,
    smoother: Option<SmootherLog<N>>,
}

#[derive(Debug, Clone)]
struct SmootherLog<const N: usize> {
    records: Vec<SmootherRecord<N>>,
    /// The epoch under construction: nominal snapshot taken lazily before the next IMU step.
    current_nav: Option<(NavState, SensorErrors)>,
    current_dx: SVector<f64, N>,
}

/// Builds the initial covariance from the configuration.
pub fn initial_covariance<const N: usize>(config: &FusionConfig) -> SMatrix<f64, N, N> {
    let i = &config.initial;
    let imu = &config.imu;
    let layout = Layout::of(config);
    let mut d = SVector::<f64, N>::zeros();
    for k in 0..3 {
        d[POS + k] = i.position_m.powi(2);
        d[VEL + k] = i.velocity_mps.powi(2);
        if let Some(t) = layout.turn_on {
            // The in-run states start at their process's σ, the turn-on ones at the rest.
            d[BG + k] = imu
                .gyro_in_run_state(k)
                .sigma
                .min(imu.gyro_bias_sigma0(k))
                .powi(2);
            d[BA + k] = imu
                .accel_in_run_state(k)
                .sigma
                .min(imu.accel_bias_sigma0(k))
                .powi(2);
            d[t + k] = imu.gyro_turn_on_sigma(k).powi(2);
            d[t + 3 + k] = imu.accel_turn_on_sigma(k).powi(2);
        } else {
            d[BG + k] = imu.gyro_bias_sigma0(k).powi(2);
            d[BA + k] = imu.accel_bias_sigma0(k).powi(2);
        }
        if layout.scale_factors {
            d[SG + k] = imu.gyro_scale.sigma[k].powi(2);
            d[SA + k] = imu.accel_scale.sigma[k].powi(2);
        }
    }
    if let Some(ge) = layout.gnss_error {
        for (k, s) in config.gnss.position_error.sigma_ned().iter().enumerate() {
            d[ge + k] = s * s;
        }
    }
    d[ATT] = i.roll_pitch_deg.to_radians().powi(2);
    d[ATT + 1] = i.roll_pitch_deg.to_radians().powi(2);
    d[ATT + 2] = i.heading_deg.to_radians().powi(2);
    // A zero σ (e.g. a perfectly known bias) would make P singular; keep a tiny floor.
    SMatrix::from_diagonal(&d.map(|v| v.max(1e-24)))
}

impl<const N: usize> Ins<N> {
    /// Starts the filter at `nav` with the configured initial uncertainty. `N` must match
    /// `config.filter_states()` (15 to 30, [`Layout`]).
    pub fn new(nav: NavState, config: &FusionConfig, smoothing: bool) -> Self {
        let layout = Layout::of(config);
        debug_assert_eq!(N, layout.states);
        Self {
            nav,
            sensors: SensorErrors::default(),
            p: initial_covariance::<N>(config),
            stats: FilterStats::default(),
            config: *config,
            layout,
            in_run_bias: (Vector3::zeros(), Vector3::zeros()),
            mech: Mechaniser::new(config.mechanisation),
            q_psd: models::process_noise_psd::<N>(config),
            acc_dt: 0.0,
            acc_dtheta: Vector3::zeros(),
            acc_dvel: Vector3::zeros(),
            last_gyro: Vector3::zeros(),
            last_sane: nav,
            covariance_on: true,
            smoother: smoothing.then(|| SmootherLog {
                records: Vec::new(),
                current_nav: None,
                current_dx: SVector::zeros(),
            }),
        }
    }

    pub fn config(&self) -> &FusionConfig {
        &self.config
    }

    /// Where each group of states sits.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// Sets the gyro bias estimate and its covariance from a measurement of the whole bias
    /// (the static alignment): `sigma` is each axis's 1σ after it. With turn-on states, the
    /// in-run and turn-on states are updated jointly, as a Kalman update of their sum would.
    pub fn set_gyro_bias(&mut self, bias: Vector3<f64>, sigma: Vector3<f64>) {
        self.sensors.gyro_bias = bias;
        self.in_run_bias.0 = Vector3::zeros();
        for (i, s) in sigma.iter().enumerate() {
            let post = s.powi(2).max(1e-24);
            let Some(t) = self.layout.turn_on else {
                self.p[(BG + i, BG + i)] = post;
                continue;
            };
            let (pg, pc) = (self.p[(BG + i, BG + i)], self.p[(t + i, t + i)]);
            let prior = pg + pc;
            if post >= prior {
                continue;
            }
            // The measurement variance r that takes the sum from `prior` to `post`, and the
            // update of [g, c] by z = g + c + noise: P − P Hᵀ (H P Hᵀ + r)⁻¹ H P, H = [1 1].
            let s_inv = (prior - post) / (prior * prior);
            self.in_run_bias.0[i] = bias[i] * pg / prior;
            self.p[(BG + i, BG + i)] = pg - pg * pg * s_inv;
            self.p[(t + i, t + i)] = pc - pc * pc * s_inv;
            self.p[(BG + i, t + i)] = -pg * pc * s_inv;
            self.p[(t + i, BG + i)] = -pg * pc * s_inv;
        }
    }

    /// Bias-corrected angular rate of the latest IMU step, rad/s.
    pub fn last_gyro(&self) -> Vector3<f64> {
        self.last_gyro
    }

    /// Mechanises one raw IMU input and propagates the covariance when the interval is full.
    pub fn propagate(&mut self, raw: &ImuInput) {
        if let Some(log) = self.smoother.as_mut() {
            if log.current_nav.is_none() {
                log.current_nav = Some((self.nav, self.sensors));
            }
        }
        let corrected = self.sensors.correct(raw);
        let step = self.mech.step(&mut self.nav, &corrected);
        if !is_sane(&self.nav) {
            self.stats.divergence_resets += 1;
            let t = self.nav.t_s;
            self.nav = self.last_sane;
            self.nav.t_s = t;
            self.nav.vel_ned = Vector3::zeros();
            self.mech.reset_history();
            for i in 0..6 {
                let cap = if i < 3 { SIGMA_CAP.0 } else { SIGMA_CAP.1 };
                self.p[(i, i)] = self.p[(i, i)].max(cap * cap);
            }
            return;
        }
        if let Some(step) = step {
            self.stats.imu_steps += 1;
            self.last_gyro = step.gyro_b;
            self.acc_dt += step.dt_s;
            self.acc_dtheta += step.gyro_b * step.dt_s;
            self.acc_dvel += step.accel_b * step.dt_s;
            if self.acc_dt >= self.config.covariance_interval_s - 1e-9 {
                self.propagate_covariance();
            }
        }
    }

    /// Switches the covariance propagation off (or back on). The nominal navigation
    /// solution does not depend on the covariance between updates (the filter is closed-loop:
    /// the covariance acts only through the gain of an update), so a run that applies no
    /// further update — a dead-reckoning fork of the sensor-grade study — gives the same
    /// trajectory with it off, at a fraction of the cost. While it is off the covariance
    /// stays as it was; switching it back on resumes from that stale value, so do not mix it
    /// with updates.
    pub fn set_covariance_propagation(&mut self, on: bool) {
        self.covariance_on = on;
    }

    /// Forgets the mechanisation history (after an IMU data gap).
    pub fn reset_history(&mut self) {
        self.mech.reset_history();
    }

    /// Brings the covariance up to the current time.
    pub fn propagate_covariance(&mut self) {
        if self.acc_dt <= 0.0 {
            return;
        }
        if !self.covariance_on {
            // Same cadence of the fall-back state as with the covariance on.
            self.last_sane = self.nav;
            self.acc_dt = 0.0;
            self.acc_dtheta = Vector3::zeros();
            self.acc_dvel = Vector3::zeros();
            return;
        }
        let dt = self.acc_dt;
        if self.layout.gnss_error.is_some() {
            // The estimate follows the process's mean, so that F's decay holds for the
            // error state too.
            self.sensors.gnss_position_error *= (-dt / self.config.gnss.position_error.tau_s).exp();
        }
        let gyro = self.acc_dtheta / dt;
        let accel = self.acc_dvel / dt;
        let f = models::dynamics_matrix::<N>(&self.nav, &gyro, &accel, &self.config);
        if let Some(t) = self.layout.turn_on {
            // Both parts of each bias estimate follow their process's mean, as the error
            // states do (F's diagonal): the in-run part and the turn-on part, the rest of the
            // sum.
            let keep = |k: usize| (f[(k, k)] * dt).exp();
            for i in 0..3 {
                let (gyro, accel) = (&mut self.sensors.gyro_bias, &mut self.sensors.accel_bias);
                let in_run = &mut self.in_run_bias;
                decay_parts(&mut gyro[i], &mut in_run.0[i], keep(BG + i), keep(t + i));
                decay_parts(
                    &mut accel[i],
                    &mut in_run.1[i],
                    keep(BA + i),
                    keep(t + 3 + i),
                );
            }
        }
        let (phi, qd) = models::discretise_sparse(&f, &self.q_psd, dt);
        let p_prev = self.p;
        let mut p = models::propagate_covariance_sparse(&phi, &self.p) + qd;
        if !p.iter().all(|v| v.is_finite()) || (0..N).any(|i| p[(i, i)] <= 0.0) {
            // Only absurd (finite but overflowing) inputs get here: keep the old covariance
            // plus white process noise rather than ever storing a non-finite number.
            self.stats.propagation_repairs += 1;
            p = p_prev + SMatrix::from_diagonal(&(self.q_psd * dt));
        }
        if cap_covariance(&mut p) {
            self.stats.covariance_caps += 1;
        }
        self.p = p;
        self.last_sane = self.nav;
        self.stats.covariance_steps += 1;
        self.acc_dt = 0.0;
        self.acc_dtheta = Vector3::zeros();
        self.acc_dvel = Vector3::zeros();
        if let Some(log) = self.smoother.as_mut() {
            let (nav, sensors) = log.current_nav.take().unwrap_or((self.nav, self.sensors));
            log.records.push(SmootherRecord {
                nav,
                sensors,
                p_post: p_prev,
                dx_update: log.current_dx,
                phi_next: phi,
                p_prior_next: p,
            });
            log.current_dx = SVector::zeros();
        }
    }

    /// Joseph-form update with measurement `m`; `gate` > 0 rejects NIS above it.
    pub fn update<const M: usize>(&mut self, m: &Measurement<M, N>, gate: f64) -> UpdateOutcome {
        self.propagate_covariance();
        let mut h = m.h;
        self.layout.share_bias_columns(&mut h);
        let m = &Measurement { z: m.z, h, r: m.r };
        let ht = m.h.transpose();
        let s = m.h * self.p * ht + m.r;
        let s = 0.5 * (s + s.transpose());
        let finite = m.z.iter().chain(s.iter()).all(|v| v.is_finite());
        let Some(chol) = finite.then(|| Cholesky::new(s)).flatten() else {
            self.stats.pd_events += 1;
            return UpdateOutcome::Rejected;
        };
        let nis = m.z.dot(&chol.solve(&m.z));
        if gate > 0.0 && nis > gate {
            self.stats.gated += 1;
            return UpdateOutcome::Gated { nis };
        }
        // K = P Hᵀ S⁻¹, computed as (S⁻¹ H P)ᵀ since S and P are symmetric.
        let hp = m.h * self.p;
        let k = chol.solve(&hp).transpose();
        let dx = k * m.z;
        // Joseph form (I − KH) P (I − KH)ᵀ + K R Kᵀ, multiplied out with H P Hᵀ + R = S:
        // P − K(HP) − (K(HP))ᵀ + K S Kᵀ. Equal for any K, at 2·M·N² products instead of 2·N³.
        let khp = k * hp;
        let mut p = self.p - khp - khp.transpose() + (k * s) * k.transpose();
        p = 0.5 * (p + p.transpose());
        let ok = dx.iter().all(|v| v.is_finite())
            && p.iter().all(|v| v.is_finite())
            && Cholesky::new(p).is_some();
        if !ok {
            self.stats.pd_events += 1;
            return UpdateOutcome::Rejected;
        }
        let (nav, sensors) = corrected(&self.layout, &self.nav, &self.sensors, &dx);
        if !is_sane(&nav) {
            self.stats.divergence_resets += 1;
            return UpdateOutcome::Rejected;
        }
        if self.layout.turn_on.is_some() {
            self.in_run_bias.0 -= dx.fixed_rows::<3>(BG);
            self.in_run_bias.1 -= dx.fixed_rows::<3>(BA);
        }
        self.p = p;
        self.nav = nav;
        self.sensors = sensors;
        if let Some(log) = self.smoother.as_mut() {
            log.current_dx += dx;
        }
        self.stats.updates += 1;
        UpdateOutcome::Applied { nis }
    }

    /// Finishes the run: closes the last covariance epoch and returns the smoother records
    /// (empty when smoothing was off).
    pub fn finish(&mut self) -> Vec<SmootherRecord<N>> {
        self.propagate_covariance();
        match self.smoother.as_mut() {
            Some(log) => {
                let (nav, sensors) = log.current_nav.take().unwrap_or((self.nav, self.sensors));
                let mut records = std::mem::take(&mut log.records);
                records.push(SmootherRecord {
                    nav,
                    sensors,
                    p_post: self.p,
                    dx_update: log.current_dx,
                    phi_next: SMatrix::identity(),
                    p_prior_next: self.p,
                });
                records
            }
            None => Vec::new(),
        }
    }
}

/// Decays a bias estimate `total`, the sum of an in-run part `in_run` and a turn-on part, by
/// each part's own factor over one interval.
fn decay_parts(total: &mut f64, in_run: &mut f64, keep_in_run: f64, keep_turn_on: f64) {
    *total = *in_run * keep_in_run + (*total - *in_run) * keep_turn_on;
    *in_run *= keep_in_run;
}

/// The nominal state and sensor errors after removing the estimated error `dx`
/// (estimate minus truth) of a filter laid out as `layout`.
pub fn corrected<const N: usize>(
    layout: &Layout,
    nav: &NavState,
    sensors: &SensorErrors,
    dx: &SVector<f64, N>,
) -> (NavState, SensorErrors) {
    let mut nav = *nav;
    let mut s = *sensors;
    let v3 = |i: usize| Vector3::new(dx[i], dx[i + 1], dx[i + 2]);
    nav.shift_position(&(-v3(POS)));
    nav.vel_ned -= v3(VEL);
    // C(true) = (I + [φ×]) C(est).
    nav.quat_nb = UnitQuaternion::from_scaled_axis(v3(ATT)) * nav.quat_nb;
    s.gyro_bias -= v3(BG);
    s.accel_bias -= v3(BA);
    if let Some(t) = layout.turn_on {
        s.gyro_bias -= v3(t);
        s.accel_bias -= v3(t + 3);
    }
    if layout.scale_factors {
        s.gyro_scale -= v3(SG);
        s.accel_scale -= v3(SA);
    }
    if let Some(ge) = layout.gnss_error {
        s.gnss_position_error -= v3(ge);
    }
    (nav, s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Axes, GaussMarkov};

    /// A level body at rest at 46° N.
    fn still_nav() -> NavState {
        NavState {
            t_s: 0.0,
            lat_rad: 0.8,
            lon_rad: 0.2,
            height_m: 100.0,
            vel_ned: Vector3::zeros(),
            quat_nb: UnitQuaternion::identity(),
        }
    }

    /// A measurement of the whole gyro bias leaves the sum of the in-run and turn-on states
    /// with the measured σ, shares the rest as a Kalman update of the sum would, and
    /// correlates the two negatively.
    #[test]
    fn the_aligned_gyro_bias_updates_both_parts_of_the_bias() {
        let mut config = FusionConfig {
            turn_on_states: true,
            ..FusionConfig::default()
        };
        config.imu.gyro_bias_initial_sigma = Some(5.0 * config.imu.gyro_bias.sigma);
        let nav = still_nav();
        let mut ins = Ins::<21>::new(nav, &config, false);
        let t = ins.layout().turn_on.expect("turn-on states");
        let sigma = Vector3::from((0.5 * config.imu.gyro_bias.sigma).0);
        let bias = Vector3::new(1e-4, -2e-4, 3e-4);
        ins.set_gyro_bias(bias, sigma);
        assert_eq!(ins.sensors.gyro_bias, bias);
        for i in 0..3 {
            let (g, c, gc) = (
                ins.p[(BG + i, BG + i)],
                ins.p[(t + i, t + i)],
                ins.p[(BG + i, t + i)],
            );
            let sum = g + c + 2.0 * gc;
            assert!(
                (sum - sigma[i].powi(2)).abs() < 1e-9 * sum,
                "{sum} {}",
                sigma[i]
            );
            assert!(gc < 0.0 && gc == ins.p[(t + i, BG + i)]);
            assert!(g < config.imu.gyro_bias.sigma[i].powi(2));
        }
        assert!(Cholesky::new(ins.p).is_some());
        // One state per axis: the state takes the σ as it is.
        let one = FusionConfig {
            turn_on_states: false,
            ..config
        };
        let mut ins = Ins::<15>::new(nav, &one, false);
        ins.set_gyro_bias(bias, sigma);
        assert!((ins.p[(BG, BG)] - sigma.x.powi(2)).abs() < 1e-30);
    }

    /// With a slow in-run part the turn-on state decays too: each part of the bias estimate
    /// follows the mean of its own process between updates, and the two decay apart.
    #[test]
    fn each_part_of_the_bias_estimate_decays_as_its_process() {
        let mut config = FusionConfig {
            turn_on_states: true,
            ..FusionConfig::default()
        };
        let in_run = config.imu.gyro_bias.sigma;
        config.imu.gyro_bias_initial_sigma = Some(Axes::all(5.0 * in_run[0]));
        config.imu.gyro_bias_slow = Some(GaussMarkov {
            sigma: Axes::all(2.0 * in_run[0]),
            tau_s: 1000.0,
        });
        let nav = still_nav();
        let mut ins = Ins::<21>::new(nav, &config, false);
        let bias = Vector3::new(1e-4, -2e-4, 3e-4);
        ins.set_gyro_bias(bias, Vector3::from((0.5 * in_run).0));
        let (fast0, slow0) = (ins.in_run_bias.0, bias - ins.in_run_bias.0);
        assert!(fast0
            .iter()
            .zip(slow0.iter())
            .all(|(f, s)| *f != 0.0 && *s != 0.0));
        for k in 0..=1000 {
            ins.propagate(&ImuInput::Rates {
                t_s: k as f64 * 0.01,
                gyro: Vector3::zeros(),
                accel: Vector3::new(0.0, 0.0, -9.8),
            });
        }
        ins.propagate_covariance();
        let imu = &config.imu;
        let (tau, tau_on) = (
            imu.gyro_in_run_state(0).tau_s,
            imu.gyro_turn_on_state(0).tau_s,
        );
        assert!(tau_on > 10.0 * tau && tau_on.is_finite(), "{tau} {tau_on}");
        for i in 0..3 {
            let fast = fast0[i] * (-10.0 / tau).exp();
            let slow = slow0[i] * (-10.0 / tau_on).exp();
            assert!((ins.in_run_bias.0[i] - fast).abs() < 1e-12 * fast.abs());
            let b = ins.sensors.gyro_bias[i];
            assert!(
                (b - fast - slow).abs() < 1e-12 * b.abs(),
                "{b} vs {}",
                fast + slow
            );
        }
    }
}
