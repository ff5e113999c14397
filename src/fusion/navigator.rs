//! The replay engine: feeds time-ordered IMU samples and GNSS fixes through alignment, the
//! strapdown INS and the error-state filter (GNSS position/velocity, optional NHC and ZUPT,
//! simulated outages), checks every input (non-finite values, time going backwards,
//! duplicate or out-of-order fixes are rejected and counted, never fatal) and collects the
//! trajectory at the output interval, optionally RTS-smoothed.

use crate::align::{self, StaticLeveller};
use crate::config::{Axes, FusionConfig};
use crate::eskf::{FilterStats, Ins, SensorErrors, UpdateOutcome};
use crate::mechanisation::{ImuInput, NavState};
use crate::metrics;
use crate::models::{self, Layout, ATT, BA, BG, SA, SG};
use crate::smoother;
use imulab_earth as earth;
use nalgebra::{SMatrix, Vector3};

/// A correction of IMU rows applied before the filter (a calibration: `imulab calibrate`'s
/// file in the main crate), SI units in place.
pub trait RowCorrection: std::fmt::Debug + Send + Sync {
    /// Corrects rows of gyro (rad/s) and accel (m/s²) samples in place.
    fn apply(&self, gyro: &mut [[f64; 3]], accel: &mut [[f64; 3]]);
}

/// Receivers that give no accuracy get these 1σ values: horizontal, vertical (m), velocity (m/s).
pub const FALLBACK_SIGMA: (f64, f64, f64) = (2.5, 5.0, 0.1);
/// IMU gaps longer than this restart the mechanisation history, s.
pub const MAX_IMU_GAP_S: f64 = 1.0;
/// A wheel-speed reading is used only this close to the filter's time, s.
pub const MAX_WHEEL_LAG_S: f64 = 0.02;

/// One GNSS fix as the filter uses it (antenna position).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GnssObservation {
    pub t_s: f64,
    pub lat_rad: f64,
    pub lon_rad: f64,
    pub height_m: f64,
    /// 1σ north, east, down position accuracy, m (NaN = unknown).
    pub sigma_ned_m: Vector3<f64>,
    /// Velocity north/east/down when the receiver gives it.
    pub vel_ned: Option<Vector3<f64>>,
    /// 1σ velocity accuracy, m/s (NaN = unknown).
    pub sigma_vel_mps: Vector3<f64>,
}

/// One output epoch of the trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavSolution {
    pub nav: NavState,
    pub sensors: SensorErrors,
    /// Covariance of (δr, δv, φ), 9×9.
    pub cov_nav: SMatrix<f64, 9, 9>,
    /// 1σ of gyro bias, accel bias, gyro scale, accel scale (NaN for scales with 15 states).
    pub sigma_sensors: [Vector3<f64>; 4],
}

/// Counts of what the replay accepted, rejected and did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ReplayStats {
    pub imu_samples: u64,
    pub imu_rejected_non_finite: u64,
    pub imu_rejected_time: u64,
    pub imu_gaps: u64,
    pub gnss_used: u64,
    pub gnss_withheld_outage: u64,
    pub gnss_rejected_invalid: u64,
    pub gnss_rejected_duplicate: u64,
    pub gnss_rejected_out_of_order: u64,
    pub gnss_gated: u64,
    /// Fixes whose position σ was zero, negative or missing: used with [`FALLBACK_SIGMA`].
    pub gnss_sigma_fallback: u64,
    /// Time of the first and last accepted IMU sample, s.
    pub imu_span_s: Option<(f64, f64)>,
    /// Time of the first and last valid GNSS fix, s.
    pub gnss_span_s: Option<(f64, f64)>,
    pub nhc_updates: u64,
    pub zupt_updates: u64,
    /// Detected standstills whose zero velocity the filter's velocity contradicted (χ² gate).
    pub zupt_gated: u64,
    pub zaru_updates: u64,
    pub odometer_updates: u64,
    /// Wheel-speed readings not finite or not at an IMU epoch.
    pub odometer_rejected: u64,
    /// Time the filter started (after alignment), s.
    pub aligned_at_s: Option<f64>,
    pub filter: FilterStats,
    /// Smoothed epochs that kept their filtered value (singular prediction).
    pub smoother_skipped: usize,
}

/// How a replay starts and what it withholds.
#[derive(Debug, Clone, Default)]
pub struct ReplayOptions {
    /// Start from this state (time, position, velocity, attitude) instead of aligning.
    pub initial: Option<NavState>,
    /// Initial sensor-error estimates (with `initial`).
    pub initial_sensors: SensorErrors,
    /// Withhold GNSS in these [start, end) windows, s.
    pub outages: Vec<(f64, f64)>,
    /// Run the RTS smoother and return the smoothed trajectory too.
    pub smooth: bool,
    /// IMU calibration applied to every session row before thermal compensation and the
    /// filter (`replay --calibration`).
    pub calibration: Option<std::sync::Arc<dyn RowCorrection>>,
}

/// Everything a replay produced.
#[derive(Debug, Clone, Default)]
pub struct ReplayResult {
    pub filtered: Vec<NavSolution>,
    pub smoothed: Vec<NavSolution>,
    pub stats: ReplayStats,
    /// The [start, end) windows the filter ran without GNSS after it started: the withheld
    /// outages merged with the stretches the data has no fix (see
    /// [`metrics::gnss_less_windows`]).
    pub gnss_less: Vec<(f64, f64)>,
}

/// Running sums of the current zero-velocity detection window.
#[derive(Debug, Clone, Copy, Default)]
struct ZuptWindow {
    duration_s: f64,
    sum_gyro: Vector3<f64>,
    sum_accel: Vector3<f64>,
    prev_mean_accel: Option<Vector3<f64>>,
}

/// The incremental replay engine for a filter with `N` states. Cloning it forks the replay
/// (the sensor-grade study runs each outage on a fork).
#[derive(Debug, Clone)]
pub struct Navigator<const N: usize> {
    config: FusionConfig,
    options: ReplayOptions,
    ins: Option<Ins<N>>,
    leveller: StaticLeveller,
    last_imu: Option<(f64, Vector3<f64>, Vector3<f64>)>,
    last_fix_t: Option<f64>,
    /// Time of the latest fix used in an update (for the correlated-error inflation).
    last_used_fix_t: Option<f64>,
    next_output_t: f64,
    last_nhc_t: f64,
    last_odometer_t: f64,
    zupt_window: ZuptWindow,
    /// Times of the valid fixes not withheld (for the GNSS-less windows).
    fix_times: Vec<f64>,
    result: ReplayResult,
}

fn solution<const N: usize>(ins: &Ins<N>) -> NavSolution {
    solution_from(ins.layout(), &ins.nav, &ins.sensors, &ins.p)
}

fn solution_from<const N: usize>(
    layout: &Layout,
    nav: &NavState,
    sensors: &SensorErrors,
    p: &SMatrix<f64, N, N>,
) -> NavSolution {
    // 1σ of the sum of state `i + k` and, with turn-on states, its turn-on partner `j + k`.
    let sigma = |i: usize, partner: Option<usize>| {
        Vector3::from_fn(|k, _| {
            let v = p[(i + k, i + k)];
            match partner {
                Some(j) => (v + p[(j + k, j + k)] + 2.0 * p[(i + k, j + k)]).sqrt(),
                None => v.sqrt(),
            }
        })
    };
    let scale = |i: usize| {
        if layout.scale_factors {
            sigma(i, None)
        } else {
            Vector3::repeat(f64::NAN)
        }
    };
    NavSolution {
        nav: *nav,
        sensors: *sensors,
        cov_nav: p.fixed_view::<9, 9>(0, 0).into_owned(),
        sigma_sensors: [
            sigma(BG, layout.turn_on),
            sigma(BA, layout.turn_on.map(|t| t + 3)),
            scale(SG),
            scale(SA),
        ],
    }
}

impl<const N: usize> Navigator<N> {
    pub fn new(config: &FusionConfig, options: ReplayOptions) -> Self {
        let mut nav = Self {
            config: *config,
            ins: None,
            leveller: StaticLeveller::default(),
            last_imu: None,
            last_fix_t: None,
            last_used_fix_t: None,
            next_output_t: f64::NEG_INFINITY,
            last_nhc_t: f64::NEG_INFINITY,
            last_odometer_t: f64::NEG_INFINITY,
            zupt_window: ZuptWindow::default(),
            fix_times: Vec::new(),
            result: ReplayResult::default(),
            options,
        };
        if let Some(initial) = nav.options.initial {
            nav.start(initial);
            if let Some(ins) = nav.ins.as_mut() {
                ins.sensors = nav.options.initial_sensors;
            }
        }
        nav
    }

    fn start(&mut self, nav: NavState) {
        self.ins = Some(Ins::new(nav, &self.config, self.options.smooth));
        self.result.stats.aligned_at_s = Some(nav.t_s);
        self.next_output_t = nav.t_s;
    }

    /// The running filter, once aligned.
    pub fn ins(&self) -> Option<&Ins<N>> {
        self.ins.as_ref()
    }

    /// Switches the filter's covariance propagation off or on (see
    /// [`Ins::set_covariance_propagation`]); for dead-reckoning forks that receive no
    /// further GNSS fix. Refused (returns false) while non-holonomic or zero-velocity
    /// updates are configured, since those still update the filter.
    pub fn set_covariance_propagation(&mut self, on: bool) -> bool {
        let c = &self.config;
        if !on && (c.nhc.enabled || c.zupt.enabled || c.zaru.enabled || c.odometer.enabled) {
            return false;
        }
        match self.ins.as_mut() {
            Some(ins) => {
                ins.set_covariance_propagation(on);
                true
            }
            None => false,
        }
    }

    /// Feeds one raw IMU input.
    pub fn push_imu(&mut self, raw: &ImuInput) {
        let (t, gyro, accel, dt_hint) = match *raw {
            ImuInput::Rates { t_s, gyro, accel } => (t_s, gyro, accel, None),
            ImuInput::Increments {
                t_s,
                dt_s,
                dtheta,
                dvel,
            } => (t_s, dtheta / dt_s, dvel / dt_s, Some(dt_s)),
        };
        let stats = &mut self.result.stats;
        if !(t.is_finite() && gyro.iter().chain(accel.iter()).all(|v| v.is_finite())) {
            stats.imu_rejected_non_finite += 1;
            return;
        }
        let dt = match (self.last_imu, dt_hint) {
            (Some((t0, _, _)), _) if t <= t0 => {
                stats.imu_rejected_time += 1;
                return;
            }
            (Some((t0, _, _)), None) => t - t0,
            (_, Some(d)) if d > 0.0 && d <= MAX_IMU_GAP_S => d,
            (_, Some(_)) => {
                stats.imu_rejected_time += 1;
                return;
            }
            (None, None) => 0.0,
        };
        stats.imu_samples += 1;
        stats.imu_span_s = Some(stats.imu_span_s.map_or((t, t), |(a, _)| (a, t)));
        let gap = matches!(self.last_imu, Some((t0, _, _)) if t - t0 > MAX_IMU_GAP_S);
        self.last_imu = Some((t, gyro, accel));
        let Some(ins) = self.ins.as_mut() else {
            let g = earth::normal_gravity(0.0, 0.0);
            self.leveller.add(
                &accel,
                &gyro,
                dt,
                g,
                align::LEVEL_GYRO_THRESHOLD,
                align::LEVEL_ACCEL_THRESHOLD,
            );
            return;
        };
        if t < ins.nav.t_s {
            return;
        }
        if gap {
            stats.imu_gaps += 1;
            ins.reset_history();
        }
        ins.propagate(raw);
        self.zupt(gyro, accel, dt);
        self.nhc(dt);
        self.output();
    }

    fn output(&mut self) {
        let Some(ins) = self.ins.as_ref() else { return };
        if ins.nav.t_s + 1e-9 >= self.next_output_t {
            self.result.filtered.push(solution(ins));
            let step = self.config.output_interval_s;
            self.next_output_t = ((ins.nav.t_s + 1e-9) / step).floor() * step + step;
        }
    }

    /// Zero-velocity detection on consecutive windows: the window-mean angular rate is small,
    /// the window-mean specific force has not changed since the previous window, and the INS
    /// itself is slow (a smooth straight cruise looks like a standstill to an IMU).
    fn zupt(&mut self, gyro: Vector3<f64>, accel: Vector3<f64>, dt: f64) {
        let z = self.config.zupt;
        let zaru = self.config.zaru;
        let Some(ins) = self.ins.as_mut() else { return };
        if !(z.enabled || zaru.enabled) {
            return;
        }
        let w = &mut self.zupt_window;
        w.duration_s += dt;
        w.sum_gyro += (gyro - ins.sensors.gyro_bias) * dt;
        w.sum_accel += accel * dt;
        if w.duration_s < z.window_s {
            return;
        }
        let mean_gyro = w.sum_gyro / w.duration_s;
        let mean_accel = w.sum_accel / w.duration_s;
        let steady = w
            .prev_mean_accel
            .is_some_and(|p| (mean_accel - p).norm() < z.accel_threshold_mps2);
        *w = ZuptWindow {
            prev_mean_accel: Some(mean_accel),
            ..ZuptWindow::default()
        };
        if steady
            && mean_gyro.norm() < z.gyro_threshold_rad_s
            && ins.nav.vel_ned.norm() < z.max_speed_mps
        {
            let mut still = true;
            if z.enabled {
                let m = models::zero_velocity::<N>(&ins.nav, z.sigma_mps);
                match ins.update(&m, z.innovation_gate) {
                    UpdateOutcome::Applied { .. } => self.result.stats.zupt_updates += 1,
                    UpdateOutcome::Gated { .. } => {
                        self.result.stats.zupt_gated += 1;
                        still = false;
                    }
                    UpdateOutcome::Rejected => {}
                }
            }
            // A window the velocity test says is moving is not a standstill for ZARU either.
            if zaru.enabled && still {
                let m = models::zero_angular_rate::<N>(&ins.nav, &mean_gyro, zaru.sigma_rad_s);
                if let UpdateOutcome::Applied { .. } = ins.update(&m, 0.0) {
                    self.result.stats.zaru_updates += 1;
                }
            }
        }
    }

    /// `dt`: the interval of the IMU sample just mechanised, whose gyro noise the
    /// constraint's expected slip carries.
    fn nhc(&mut self, dt: f64) {
        let c = self.config.nhc;
        let Some(ins) = self.ins.as_mut() else { return };
        if !c.enabled
            || ins.nav.vel_ned.norm() < c.min_speed_mps
            || ins.nav.t_s - self.last_nhc_t < c.interval_s
        {
            return;
        }
        self.last_nhc_t = ins.nav.t_s;
        let arw = self.config.imu.arw_rad_per_sqrt_s;
        let gyro_sigma = if dt > 0.0 {
            Vector3::from(arw.0) / dt.sqrt()
        } else {
            Vector3::zeros()
        };
        let m = models::non_holonomic::<N>(
            &ins.nav,
            &ins.last_gyro(),
            &gyro_sigma,
            &self.config.vehicle,
            &c,
        );
        if let UpdateOutcome::Applied { .. } = ins.update(&m, 0.0) {
            self.result.stats.nhc_updates += 1;
        }
    }

    /// Feeds one wheel-speed reading (forward speed of the vehicle point, m/s) taken at time
    /// `t_s`, the time of the IMU sample just pushed: an odometer update when
    /// `odometer.enabled`, at most every `odometer.interval_s`. A reading that is not finite
    /// or more than [`MAX_WHEEL_LAG_S`] from the filter's time is counted and skipped.
    pub fn push_wheel_speed(&mut self, t_s: f64, speed_mps: f64) {
        let c = self.config.odometer;
        let Some(ins) = self.ins.as_mut() else { return };
        let stats = &mut self.result.stats;
        if !c.enabled {
            return;
        }
        if !(speed_mps.is_finite() && (t_s - ins.nav.t_s).abs() <= MAX_WHEEL_LAG_S) {
            stats.odometer_rejected += 1;
            return;
        }
        if ins.nav.t_s - self.last_odometer_t < c.interval_s {
            return;
        }
        self.last_odometer_t = ins.nav.t_s;
        let m = models::odometer::<N>(
            &ins.nav,
            &ins.last_gyro(),
            &self.config.vehicle,
            speed_mps,
            c.sigma_mps,
        );
        if let UpdateOutcome::Applied { .. } = ins.update(&m, 0.0) {
            stats.odometer_updates += 1;
        }
    }

    /// Feeds one GNSS fix (its time should not be later than the next IMU sample's).
    pub fn push_gnss(&mut self, fix: &GnssObservation) {
        let stats = &mut self.result.stats;
        let valid = fix.t_s.is_finite()
            && fix.lat_rad.is_finite()
            && fix.lat_rad.abs() < 1.57
            && fix.lon_rad.is_finite()
            && fix.height_m.is_finite()
            && fix.height_m.abs() < 1e5;
        if !valid {
            stats.gnss_rejected_invalid += 1;
            return;
        }
        if let Some(last) = self.last_fix_t {
            if fix.t_s == last {
                stats.gnss_rejected_duplicate += 1;
                return;
            }
            if fix.t_s < last {
                stats.gnss_rejected_out_of_order += 1;
                return;
            }
        }
        self.last_fix_t = Some(fix.t_s);
        stats.gnss_span_s = Some(
            stats
                .gnss_span_s
                .map_or((fix.t_s, fix.t_s), |(a, _)| (a, fix.t_s)),
        );
        if !fix.sigma_ned_m.iter().all(|s| s.is_finite() && *s > 0.0) {
            stats.gnss_sigma_fallback += 1;
        }
        if self
            .options
            .outages
            .iter()
            .any(|&(a, b)| fix.t_s >= a && fix.t_s < b)
        {
            stats.gnss_withheld_outage += 1;
            return;
        }
        self.fix_times.push(fix.t_s);
        let vel = fix
            .vel_ned
            .filter(|v| v.iter().all(|x| x.is_finite()) && v.norm() < 1e3);
        let g = self.config.gnss;
        let floor = |s: f64, fallback: f64, min: f64| {
            if s.is_finite() && s > 0.0 {
                s.max(min)
            } else {
                fallback
            }
        };
        let reported = Vector3::new(
            floor(fix.sigma_ned_m.x, FALLBACK_SIGMA.0, g.min_position_sigma_m),
            floor(fix.sigma_ned_m.y, FALLBACK_SIGMA.0, g.min_position_sigma_m),
            floor(fix.sigma_ned_m.z, FALLBACK_SIGMA.1, g.min_position_sigma_m),
        );
        let sigma_pos = if g.position_error.enabled() {
            // The correlated part is a state: the rest of the reported variance is white.
            let correlated = Vector3::from(g.position_error.sigma_ned());
            reported.zip_map(&correlated, |r, c| {
                (r * r - c * c).max(0.0).sqrt().max(g.min_position_sigma_m)
            })
        } else {
            // Correlated receiver errors: fixes within one correlation time carry about one
            // fix's information (see `GnssOptions::position_correlation_s`).
            let inflation = match self.last_used_fix_t {
                Some(last) if g.position_correlation_s > 0.0 => (g.position_correlation_s
                    / (fix.t_s - last))
                    .max(1.0)
                    .sqrt(),
                _ => 1.0,
            };
            inflation * reported
        };
        let sigma_vel = fix
            .sigma_vel_mps
            .map(|s| floor(s, FALLBACK_SIGMA.2, g.min_velocity_sigma_mps));
        let lever = Vector3::from(g.lever_arm_m);

        let Some(ins) = self.ins.as_mut() else {
            if vel.is_some_and(|v| v.xy().norm() > align::STILL_SPEED_MPS) {
                self.leveller.stop();
            }
            self.try_align(fix, vel, &sigma_pos);
            return;
        };
        // Predict the state to the fix time (the fix lies within one IMU interval).
        let mut at_fix = ins.nav;
        let lag = fix.t_s - ins.nav.t_s;
        if lag.abs() < 1.0 {
            at_fix.shift_position(&(ins.nav.vel_ned * lag));
        }
        let pos = models::gnss_position::<N>(
            &at_fix,
            &lever,
            &ins.sensors.gnss_position_error,
            fix.lat_rad,
            fix.lon_rad,
            fix.height_m,
            &sigma_pos,
        );
        let outcome = match vel.filter(|_| g.use_velocity) {
            Some(v) => {
                let vm =
                    models::gnss_velocity::<N>(&at_fix, &lever, &ins.last_gyro(), &v, &sigma_vel);
                ins.update(&models::stack(&pos, &vm), g.innovation_gate)
            }
            None => ins.update(&pos, g.innovation_gate),
        };
        match outcome {
            UpdateOutcome::Applied { .. } => {
                stats.gnss_used += 1;
                self.last_used_fix_t = Some(fix.t_s);
                // An output already written at this IMU epoch predates the fix: replace it
                // with the updated solution, so the epoch reports what is known there.
                if let Some(last) = self.result.filtered.last_mut() {
                    if last.nav.t_s == ins.nav.t_s {
                        *last = solution(ins);
                    }
                }
            }
            UpdateOutcome::Gated { .. } => stats.gnss_gated += 1,
            UpdateOutcome::Rejected => {}
        }
    }

    /// Starts the filter at the fix once a heading is known; `sigma_white` is the fix's
    /// white position σ (NED, m). A still period of at least `alignment.level_s` before it
    /// gives roll, pitch and the initial gyro bias ([`align::static_gyro_bias`]).
    fn try_align(
        &mut self,
        fix: &GnssObservation,
        vel: Option<Vector3<f64>>,
        sigma_white: &Vector3<f64>,
    ) {
        let a = self.config.alignment;
        let Some((t_imu, _, _)) = self.last_imu else {
            return;
        };
        let heading = match (a.heading_deg, vel) {
            (Some(h), _) if self.leveller.duration_s() >= a.level_s || self.leveller.moved() => {
                h.to_radians()
            }
            (None, Some(v)) if v.xy().norm() >= a.min_speed_mps => align::heading_from_velocity(&v),
            _ => return,
        };
        let (roll, pitch) = self.leveller.roll_pitch().unwrap_or((0.0, 0.0));
        let quat_nb = align::attitude(roll, pitch, heading);
        let mut nav = NavState {
            t_s: t_imu,
            lat_rad: fix.lat_rad,
            lon_rad: fix.lon_rad,
            height_m: fix.height_m,
            vel_ned: vel.unwrap_or_else(Vector3::zeros),
            quat_nb,
        };
        nav.shift_position(&-(quat_nb * Vector3::from(self.config.gnss.lever_arm_m)));
        nav.shift_position(&(nav.vel_ned * (t_imu - fix.t_s)));
        self.start(nav);
        if let (Some(f_b), Some(ins)) = (self.leveller.mean_specific_force(), self.ins.as_mut()) {
            // The levelled tilt error is the accelerometer bias over g (fully correlated).
            if let Some(j) = align::levelling_tilt_jacobian(&f_b, &quat_nb) {
                // The bias is the in-run state plus, where it has states, the turn-on one.
                let turn_on = ins.layout().turn_on.map(|t| t + 3);
                let mut tilt = ins.p.fixed_view::<2, 2>(ATT, ATT).into_owned();
                for b in std::iter::once(BA).chain(turn_on) {
                    let cross = j * ins.p.fixed_view::<3, 3>(b, b);
                    tilt += cross * j.transpose();
                    ins.p.fixed_view_mut::<2, 3>(ATT, b).copy_from(&cross);
                    ins.p
                        .fixed_view_mut::<3, 2>(b, ATT)
                        .copy_from(&cross.transpose());
                }
                ins.p.fixed_view_mut::<2, 2>(ATT, ATT).copy_from(&tilt);
            }
        }
        if self.leveller.duration_s() >= a.level_s {
            if let (Some(mean), Some(ins)) = (self.leveller.mean_gyro(), self.ins.as_mut()) {
                let imu = &self.config.imu;
                // The heading while still: now less the turn since (the gyro's, over seconds).
                let heading_sigma = self.config.initial.heading_deg.to_radians();
                let b = align::static_gyro_bias(
                    &mean,
                    self.leveller.duration_s(),
                    roll,
                    pitch,
                    heading - self.leveller.turned_rad(),
                    heading_sigma,
                    fix.lat_rad,
                    &imu.arw_rad_per_sqrt_s,
                    &Axes(std::array::from_fn(|i| imu.gyro_bias_sigma0(i))),
                );
                ins.set_gyro_bias(b.bias, b.sigma);
            }
        }
        if let (Some(ge), Some(ins)) = (models::gnss_error_index(N), self.ins.as_mut()) {
            // The position is the fix's, so its error is the receiver's: δr = e + w for a
            // receiver error e and white noise w, while the error state starts at δe = −e.
            let correlated = self.config.gnss.position_error.sigma_ned();
            for (i, c) in correlated.iter().enumerate() {
                let (var_e, var_w) = (c * c, sigma_white[i] * sigma_white[i]);
                ins.p[(i, i)] = var_e + var_w;
                ins.p[(ge + i, ge + i)] = var_e;
                ins.p[(i, ge + i)] = -var_e;
                ins.p[(ge + i, i)] = -var_e;
            }
        }
        self.last_used_fix_t = Some(fix.t_s);
        self.last_nhc_t = t_imu;
    }

    /// Ends the replay: final output epoch, smoother pass, statistics.
    pub fn finish(mut self) -> ReplayResult {
        if let Some(mut ins) = self.ins.take() {
            let records = ins.finish();
            let layout = *ins.layout();
            if self.result.filtered.last().map(|s| s.nav.t_s) != Some(ins.nav.t_s) {
                self.result.filtered.push(solution(&ins));
            }
            if self.options.smooth {
                let (epochs, skipped) = smoother::smooth(&layout, &records);
                self.result.stats.smoother_skipped = skipped;
                let step = self.config.output_interval_s;
                let mut next = f64::NEG_INFINITY;
                for e in &epochs {
                    if e.nav.t_s + 1e-9 >= next {
                        self.result
                            .smoothed
                            .push(solution_from(&layout, &e.nav, &e.sensors, &e.p));
                        next = ((e.nav.t_s + 1e-9) / step).floor() * step + step;
                    }
                }
            }
            self.result.stats.filter = ins.stats;
            let from = self.result.stats.aligned_at_s.unwrap_or(ins.nav.t_s);
            self.result.gnss_less = metrics::gnss_less_windows(
                &self.fix_times,
                &self.options.outages,
                (from, ins.nav.t_s),
            );
        }
        self.result
    }
}

/// Runs a whole replay: IMU inputs and GNSS fixes, each in time order, merged by time.
pub fn replay(
    config: &FusionConfig,
    imu: impl IntoIterator<Item = ImuInput>,
    gnss: impl IntoIterator<Item = GnssObservation>,
    options: ReplayOptions,
) -> ReplayResult {
    replay_with_wheel_speed(config, imu, gnss, std::iter::empty(), options)
}

/// [`replay`] with wheel-speed readings (time, forward speed m/s; in time order, each at
/// the time of an IMU sample), fed after the IMU sample of their time.
pub fn replay_with_wheel_speed(
    config: &FusionConfig,
    imu: impl IntoIterator<Item = ImuInput>,
    gnss: impl IntoIterator<Item = GnssObservation>,
    wheel: impl IntoIterator<Item = (f64, f64)>,
    options: ReplayOptions,
) -> ReplayResult {
    match config.filter_states() {
        30 => run::<30>(config, imu, gnss, wheel, options),
        27 => run::<27>(config, imu, gnss, wheel, options),
        24 => run::<24>(config, imu, gnss, wheel, options),
        21 => run::<21>(config, imu, gnss, wheel, options),
        18 => run::<18>(config, imu, gnss, wheel, options),
        _ => run::<15>(config, imu, gnss, wheel, options),
    }
}

fn run<const N: usize>(
    config: &FusionConfig,
    imu: impl IntoIterator<Item = ImuInput>,
    gnss: impl IntoIterator<Item = GnssObservation>,
    wheel: impl IntoIterator<Item = (f64, f64)>,
    options: ReplayOptions,
) -> ReplayResult {
    let mut navigator = Navigator::<N>::new(config, options);
    let mut fixes = gnss.into_iter().peekable();
    let mut wheel = wheel.into_iter().peekable();
    for sample in imu {
        let t = sample.t_s();
        while let Some(fix) = fixes.next_if(|f| f.t_s < t || f.t_s.is_nan()) {
            navigator.push_gnss(&fix);
        }
        navigator.push_imu(&sample);
        while let Some((tw, v)) = wheel.next_if(|w| w.0 <= t || w.0.is_nan()) {
            navigator.push_wheel_speed(tw, v);
        }
    }
    for fix in fixes {
        navigator.push_gnss(&fix);
    }
    navigator.finish()
}
