//! Configuration of the GNSS/INS filter: IMU noise and sensor-error processes, GNSS handling,
//! constraints, alignment and initial uncertainty. Read from TOML (`[fusion]`-style file) with
//! unknown keys rejected; every number is checked before the filter starts.
//!
//! Units are in the key names: `_rad_per_sqrt_s`, `_mps`, `_deg`, `_ppm` and so on.

use crate::mechanisation::MechanisationOptions;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A first-order Gauss-Markov process: stationary σ and correlation time τ. τ = ∞ (or any
/// τ ≤ 0 written as `0`) makes it a random constant with initial σ. The IMU's processes have
/// one σ per body axis (`GaussMarkov<Axes>`) and one τ; [`GaussMarkov::axis`] gives one
/// axis's scalar process.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GaussMarkov<S = f64> {
    pub sigma: S,
    pub tau_s: f64,
}

impl GaussMarkov<Axes> {
    /// The process of body axis `axis` (0 = x, 1 = y, 2 = z).
    pub fn axis(&self, axis: usize) -> GaussMarkov {
        GaussMarkov {
            sigma: self.sigma[axis],
            tau_s: self.tau_s,
        }
    }

    /// The decay rate 1/τ (0 for a random constant), the same on every axis.
    pub fn decay(&self) -> f64 {
        self.axis(0).decay()
    }
}

impl GaussMarkov {
    /// Continuous driving-noise spectral density 2σ²/τ (0 for a random constant).
    pub fn driving_psd(&self) -> f64 {
        if self.is_constant() {
            0.0
        } else {
            2.0 * self.sigma * self.sigma / self.tau_s
        }
    }

    /// The decay rate 1/τ (0 for a random constant).
    pub fn decay(&self) -> f64 {
        if self.is_constant() {
            0.0
        } else {
            1.0 / self.tau_s
        }
    }

    fn is_constant(&self) -> bool {
        !(self.tau_s.is_finite() && self.tau_s > 0.0)
    }
}

/// One figure per body axis x, y, z. In TOML a number is the same figure on every axis and a
/// list of three is one per axis; it is written back as a number when the three are equal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axes(pub [f64; 3]);

impl Axes {
    /// The same figure on every axis.
    pub const fn all(v: f64) -> Self {
        Self([v; 3])
    }

    /// The largest of the three.
    pub fn max(&self) -> f64 {
        self.0.iter().copied().fold(f64::NEG_INFINITY, f64::max)
    }

    /// Each axis through `f`.
    pub fn map(self, f: impl Fn(f64) -> f64) -> Self {
        Self(self.0.map(f))
    }
}

impl From<f64> for Axes {
    fn from(v: f64) -> Self {
        Self::all(v)
    }
}

impl std::ops::Index<usize> for Axes {
    type Output = f64;
    fn index(&self, axis: usize) -> &f64 {
        &self.0[axis]
    }
}

impl std::ops::Mul<f64> for Axes {
    type Output = Axes;
    fn mul(self, k: f64) -> Axes {
        self.map(|v| v * k)
    }
}

impl std::ops::Mul<Axes> for f64 {
    type Output = Axes;
    fn mul(self, a: Axes) -> Axes {
        a * self
    }
}

impl std::ops::MulAssign<f64> for Axes {
    fn mul_assign(&mut self, k: f64) {
        *self = *self * k;
    }
}

impl Serialize for Axes {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let [x, y, z] = self.0;
        if x == y && y == z {
            x.serialize(s)
        } else {
            self.0.serialize(s)
        }
    }
}

impl<'de> Deserialize<'de> for Axes {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged, expecting = "a number, or a list of three numbers (x, y, z)")]
        enum OneOrThree {
            One(f64),
            Three([f64; 3]),
        }
        Ok(match OneOrThree::deserialize(d)? {
            OneOrThree::One(v) => Axes::all(v),
            OneOrThree::Three(v) => Axes(v),
        })
    }
}

/// IMU noise and sensor-error model. Gyro quantities in rad, accel in m/s, scale factors as
/// fractions (1e-3 = 1000 ppm). Every σ and noise density is per body axis ([`Axes`]: one
/// number for all three, or a list x, y, z).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuModel {
    /// Angle random walk, rad/√s.
    pub arw_rad_per_sqrt_s: Axes,
    /// Velocity random walk, m/s/√s.
    pub vrw_mps_per_sqrt_s: Axes,
    /// Gyro bias, rad/s.
    pub gyro_bias: GaussMarkov<Axes>,
    /// Accelerometer bias, m/s².
    pub accel_bias: GaussMarkov<Axes>,
    /// Gyro scale-factor error (used with 21 states), fraction.
    pub gyro_scale: GaussMarkov<Axes>,
    /// Accelerometer scale-factor error (used with 21 states), fraction.
    pub accel_scale: GaussMarkov<Axes>,
    /// Initial 1σ of the gyro bias, rad/s (turn-on bias and in-run bias together); absent:
    /// `gyro_bias.sigma`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gyro_bias_initial_sigma: Option<Axes>,
    /// Initial 1σ of the accelerometer bias, m/s²; absent: `accel_bias.sigma`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accel_bias_initial_sigma: Option<Axes>,
    /// The in-run gyro bias's slow part beyond `gyro_bias`, rad/s: a flicker bias's periods
    /// of minutes to hours, which the Gauss-Markov process fitted to the Allan peak leaves
    /// out, as a slow Gauss-Markov process of its own; absent: none. With `turn_on_states` it
    /// shares the turn-on state (both are nearly constant over a drive, see
    /// [`ImuModel::gyro_turn_on_state`]); with one state per axis the initial σ carries it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gyro_bias_slow: Option<GaussMarkov<Axes>>,
    /// The in-run accelerometer bias's slow part beyond `accel_bias`, m/s²; absent: none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accel_bias_slow: Option<GaussMarkov<Axes>>,
    /// Gyro rate random walk (Allan K), rad/s/√s: white noise on the bias besides the
    /// Gauss-Markov driving noise.
    pub gyro_rrw_rad_per_s_sqrt_s: Axes,
    /// Accelerometer bias random walk (Allan K), m/s²/√s.
    pub accel_rrw_mps2_per_sqrt_s: Axes,
    /// In-run gyro bias from g-sensitivity per body axis (x, y, z), rad/s 1σ: the bias each
    /// axis gets from the vehicle's own specific-force changes, a Gauss-Markov part with
    /// `gyro_bias.tau_s` added to `gyro_bias` on that axis only.
    pub gyro_bias_g_sensitivity_sigma: [f64; 3],
}

impl ImuModel {
    /// Initial 1σ of the gyro bias state of body axis `axis` (0 = x, 1 = y, 2 = z).
    pub fn gyro_bias_sigma0(&self, axis: usize) -> f64 {
        self.gyro_bias_initial_sigma.unwrap_or(self.gyro_bias.sigma)[axis]
    }

    /// Initial 1σ of the accelerometer bias state of body axis `axis`.
    pub fn accel_bias_sigma0(&self, axis: usize) -> f64 {
        self.accel_bias_initial_sigma
            .unwrap_or(self.accel_bias.sigma)[axis]
    }

    /// The process the filter's gyro bias state of body axis `axis` follows: the in-run bias
    /// with that axis's g-sensitivity part, see [`bias_state_process`].
    pub fn gyro_bias_state(&self, axis: usize) -> GaussMarkov {
        bias_state_process(&self.gyro_bias_in_run(axis), self.gyro_bias_sigma0(axis))
    }

    /// The process the filter's accelerometer bias state of body axis `axis` follows, see
    /// [`bias_state_process`].
    pub fn accel_bias_state(&self, axis: usize) -> GaussMarkov {
        bias_state_process(&self.accel_bias.axis(axis), self.accel_bias_sigma0(axis))
    }

    /// The in-run gyro bias GM of body axis `axis` (with its g-sensitivity part).
    fn gyro_bias_in_run(&self, axis: usize) -> GaussMarkov {
        GaussMarkov {
            sigma: self.gyro_bias.sigma[axis].hypot(self.gyro_bias_g_sensitivity_sigma[axis]),
            tau_s: self.gyro_bias.tau_s,
        }
    }

    /// The process of the gyro bias state of body axis `axis` when the turn-on bias has
    /// states of its own ([`FusionConfig::turn_on_states`]): the in-run Gauss-Markov process
    /// with that axis's g-sensitivity part, as it is.
    pub fn gyro_in_run_state(&self, axis: usize) -> GaussMarkov {
        self.gyro_bias_in_run(axis)
    }

    /// The accelerometer's counterpart of [`ImuModel::gyro_in_run_state`].
    pub fn accel_in_run_state(&self, axis: usize) -> GaussMarkov {
        self.accel_bias.axis(axis)
    }

    /// Initial 1σ of the gyro turn-on state of body axis `axis`: the part of the initial σ
    /// the in-run state does not hold, √(σ0² − σ²) (0 when it holds it all).
    pub fn gyro_turn_on_sigma(&self, axis: usize) -> f64 {
        excess_sigma(
            self.gyro_bias_sigma0(axis),
            self.gyro_in_run_state(axis).sigma,
        )
    }

    /// Initial 1σ of the accelerometer turn-on state of body axis `axis`, as
    /// [`ImuModel::gyro_turn_on_sigma`].
    pub fn accel_turn_on_sigma(&self, axis: usize) -> f64 {
        excess_sigma(
            self.accel_bias_sigma0(axis),
            self.accel_in_run_state(axis).sigma,
        )
    }

    /// The process of the gyro turn-on state of body axis `axis`: the turn-on bias, and
    /// with it the in-run bias's slow part (`gyro_bias_slow`), which over a drive is
    /// nearly as constant. Without a slow part a random constant of
    /// [`ImuModel::gyro_turn_on_sigma`]; with one, that σ as stationary σ with the slow
    /// part's driving noise ([`bias_state_process`]): the state is then forgotten only as
    /// fast as the slow bias really changes.
    pub fn gyro_turn_on_state(&self, axis: usize) -> GaussMarkov {
        turn_on_process(
            self.gyro_bias_slow.map(|s| s.axis(axis)),
            self.gyro_turn_on_sigma(axis),
        )
    }

    /// The accelerometer's counterpart of [`ImuModel::gyro_turn_on_state`].
    pub fn accel_turn_on_state(&self, axis: usize) -> GaussMarkov {
        turn_on_process(
            self.accel_bias_slow.map(|s| s.axis(axis)),
            self.accel_turn_on_sigma(axis),
        )
    }
}

/// The turn-on state's process for a slow in-run part `slow` and the state's initial σ.
fn turn_on_process(slow: Option<GaussMarkov>, sigma0: f64) -> GaussMarkov {
    match slow {
        Some(slow) if slow.sigma > 0.0 => bias_state_process(&slow, sigma0),
        _ => GaussMarkov {
            sigma: sigma0,
            tau_s: 0.0,
        },
    }
}

/// √(total² − part²), 0 when the part is the larger (NaN-safe: a NaN total gives 0).
fn excess_sigma(total: f64, part: f64) -> f64 {
    let d = total * total - part * part;
    if d > 0.0 {
        d.sqrt()
    } else {
        0.0
    }
}

/// The first-order Gauss-Markov process of the filter's one bias state per axis, which
/// carries both the in-run bias `in_run` and, when the initial 1σ `sigma0` is larger, the
/// turn-on bias (constant for the run). A Gauss-Markov state whose initial variance is above
/// its stationary one relaxes to the stationary variance within τ/2 whether anything was
/// observed or not: with the in-run process as it is (STIM300: 0.8 °/h, τ 37 s, turn-on
/// 4 °/h) the filter told itself within a minute that it knew the turn-on bias to 0.8 °/h,
/// never estimated the yaw bias, and its heading was 4–15× over-confident on a long
/// straight (docs/bench/fusion.md, "Heading consistency"). So the state keeps `sigma0` as
/// its stationary σ and gets the correlation time that keeps the in-run driving noise
/// 2σ²/τ: short-term bias changes are modelled as before, and the turn-on part is forgotten
/// only over τ·(σ0/σ)² instead of τ. A process that is already a random constant, or whose
/// initial σ is not above its stationary σ, is returned as it is; a process with no in-run
/// noise (σ = 0) becomes a random constant of σ0.
pub fn bias_state_process(in_run: &GaussMarkov, sigma0: f64) -> GaussMarkov {
    // Written so that a NaN σ0 keeps the in-run process.
    let carries_more = sigma0 > in_run.sigma;
    if in_run.is_constant() || !carries_more {
        *in_run
    } else if in_run.sigma > 0.0 {
        let ratio = sigma0 / in_run.sigma;
        GaussMarkov {
            sigma: sigma0,
            tau_s: in_run.tau_s * ratio * ratio,
        }
    } else {
        GaussMarkov {
            sigma: sigma0,
            tau_s: 0.0,
        }
    }
}

impl Default for ImuModel {
    /// A consumer MEMS IMU: 0.3°/√h ARW, 0.1 m/s/√h VRW, 20°/h and 5 mg biases that wander
    /// over 5 minutes (MEMS biases are not stable over an hour; an hour made the filter
    /// overconfident on simulated drives), scale factors 1000 ppm over 1 h.
    fn default() -> Self {
        Self {
            arw_rad_per_sqrt_s: Axes::all(0.3f64.to_radians() / 60.0),
            vrw_mps_per_sqrt_s: Axes::all(0.1 / 60.0),
            gyro_bias: GaussMarkov {
                sigma: Axes::all(20f64.to_radians() / 3600.0),
                tau_s: 300.0,
            },
            accel_bias: GaussMarkov {
                sigma: Axes::all(5e-3 * 9.81),
                tau_s: 300.0,
            },
            gyro_scale: GaussMarkov {
                sigma: Axes::all(1e-3),
                tau_s: 3600.0,
            },
            accel_scale: GaussMarkov {
                sigma: Axes::all(1e-3),
                tau_s: 3600.0,
            },
            gyro_bias_initial_sigma: None,
            accel_bias_initial_sigma: None,
            gyro_bias_slow: None,
            accel_bias_slow: None,
            gyro_rrw_rad_per_s_sqrt_s: Axes::all(0.0),
            accel_rrw_mps2_per_sqrt_s: Axes::all(0.0),
            gyro_bias_g_sensitivity_sigma: [0.0; 3],
        }
    }
}

/// How GNSS fixes are used.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GnssOptions {
    /// Antenna position relative to the IMU centre, body frame (forward, right, down), m.
    pub lever_arm_m: [f64; 3],
    /// Use the receiver's velocity when the fix has one.
    pub use_velocity: bool,
    /// Floor under the receiver's position σ, m (receivers are optimistic).
    pub min_position_sigma_m: f64,
    /// Floor under the receiver's velocity σ, m/s.
    pub min_velocity_sigma_mps: f64,
    /// Reject fixes whose normalised innovation squared exceeds this (0 = no gating).
    pub innovation_gate: f64,
    /// Correlation time of the receiver's position error, s (0 = white). Receiver position
    /// errors (atmosphere, multipath) are correlated over minutes; treating 10 fixes a second
    /// as independent makes the filter believe its position far better than the receiver's σ.
    /// With a correlation time T the position variance of a fix is inflated by T / Δt (Δt =
    /// time since the previous used fix, at least 1), so the fixes within one correlation
    /// time together carry about one fix's worth of information.
    pub position_correlation_s: f64,
    /// The receiver's slowly varying position error, carried as three filter states when
    /// its σ is positive (then `position_correlation_s` is not used).
    pub position_error: GnssPositionError,
}

/// The slowly varying part of a receiver's position error (atmosphere, orbit and clock
/// errors, multipath): a first-order Gauss-Markov process on each NED axis with 1σ
/// `horizontal_m` (north and east each) and `vertical_m` and correlation time `tau_s`.
/// Over a drive shorter than a few τ it is nearly a bias that no number of fixes averages
/// out; a filter that takes the fixes as white noise of the receiver's total σ (or inflates
/// them by a correlation time) ends up believing its position better than the receiver's
/// bias. With a σ > 0 the filter estimates the process as three more states (18 or 24 in
/// all) and takes only the rest of the receiver's reported variance, √(σ_reported² − σ²)
/// (at least `min_position_sigma_m`), as white. σ = 0 on both (the default) leaves it out.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GnssPositionError {
    pub horizontal_m: f64,
    pub vertical_m: f64,
    pub tau_s: f64,
}

impl GnssPositionError {
    /// Whether the filter carries the error as states.
    pub fn enabled(&self) -> bool {
        self.horizontal_m > 0.0 || self.vertical_m > 0.0
    }

    /// 1σ on north, east and down, m.
    pub fn sigma_ned(&self) -> [f64; 3] {
        [self.horizontal_m, self.horizontal_m, self.vertical_m]
    }
}

impl Default for GnssOptions {
    fn default() -> Self {
        Self {
            lever_arm_m: [0.0; 3],
            use_velocity: true,
            min_position_sigma_m: 0.01,
            min_velocity_sigma_mps: 0.005,
            innovation_gate: 0.0,
            position_correlation_s: 60.0,
            position_error: GnssPositionError::default(),
        }
    }
}

/// Non-holonomic constraint: a land vehicle does not slide sideways or jump.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NhcOptions {
    pub enabled: bool,
    /// σ of the vertical body velocity (road heave, bounce), and of the lateral one unless
    /// `lateral_sigma_mps` is given, m/s.
    pub sigma_mps: f64,
    /// σ of the lateral body velocity beyond the expected side-slip, m/s; absent: `sigma_mps`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lateral_sigma_mps: Option<f64>,
    /// Side-slip gradient at the vehicle point, degrees per m/s² of lateral acceleration: in
    /// a turn a car's body yaws this much further into the turn than the velocity of its rear
    /// axle per m/s², so the lateral velocity there is −speed × tan(gradient × lateral
    /// acceleration), which the constraint expects (a passenger car: 0.1-0.4; 0 for a vehicle
    /// that does not slip, such as a rail vehicle).
    pub slip_deg_per_mps2: f64,
    /// 1σ of that gradient, same unit: how well it is known (a car not measured: half of it).
    pub slip_sigma_deg_per_mps2: f64,
    /// Apply only above this speed, m/s.
    pub min_speed_mps: f64,
    /// Apply at most this often, s.
    pub interval_s: f64,
}

impl Default for NhcOptions {
    fn default() -> Self {
        Self {
            enabled: false,
            sigma_mps: 0.1,
            lateral_sigma_mps: None,
            slip_deg_per_mps2: 0.2,
            slip_sigma_deg_per_mps2: 0.1,
            min_speed_mps: 1.0,
            interval_s: 0.2,
        }
    }
}

/// Zero-velocity update when the IMU looks stationary over a window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ZuptOptions {
    pub enabled: bool,
    /// σ of the zero-velocity pseudo-measurement, m/s.
    pub sigma_mps: f64,
    /// Stationary when the window-mean angular rate (bias-corrected) is below this, rad/s …
    pub gyro_threshold_rad_s: f64,
    /// … the window-mean specific force differs from the previous window's by less than
    /// this, m/s² …
    pub accel_threshold_mps2: f64,
    /// Window length, s; also the update interval.
    pub window_s: f64,
    /// … and the INS speed is below this, m/s (an IMU alone cannot tell a standstill from
    /// a smooth straight cruise).
    pub max_speed_mps: f64,
    /// χ² gate on the normalised innovation vᵀ(P_v + R)⁻¹v (3 degrees of freedom; 0 = off):
    /// the zero-velocity hypothesis must agree with the filter's own velocity and its σ.
    /// Without it the end of a smooth braking (0.5 m/s, steady deceleration, no rotation)
    /// passes the IMU tests and is pinned to zero at σ 0.01 m/s.
    pub innovation_gate: f64,
}

impl Default for ZuptOptions {
    fn default() -> Self {
        Self {
            enabled: false,
            sigma_mps: 0.01,
            gyro_threshold_rad_s: 0.01,
            accel_threshold_mps2: 0.05,
            window_s: 0.5,
            max_speed_mps: 1.0,
            innovation_gate: 16.27,
        }
    }
}

/// Zero angular rate update: at a detected standstill (the [`ZuptOptions`] detector) the
/// bias-corrected gyro mean must equal the earth rate, which observes the gyro biases
/// (including the vertical one, which GNSS hardly observes). Valid only when the vehicle is
/// truly still, not merely slow (a car idling with the engine on is; a ship is not).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ZaruOptions {
    pub enabled: bool,
    /// σ of the zero-angular-rate pseudo-measurement (window-mean rate), rad/s.
    pub sigma_rad_s: f64,
}

impl Default for ZaruOptions {
    fn default() -> Self {
        Self {
            enabled: false,
            sigma_rad_s: 2e-4,
        }
    }
}

/// Where the IMU sits in the vehicle: the rotation from the IMU's body frame to the vehicle
/// frame (forward, right, down) and the point the non-holonomic constraint and the
/// odometer hold at. Both are given, not estimated.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VehicleOptions {
    /// IMU mounting angles: the IMU's roll, pitch and yaw relative to the vehicle frame
    /// (degrees; as the attitude is relative to NED): a yaw of 90 means the IMU's x axis
    /// points to the vehicle's right.
    pub mounting_deg: [f64; 3],
    /// From the IMU to the vehicle point without sideslip or vertical motion (the middle of
    /// the rear axle on the ground for a car), in the IMU frame, m.
    pub lever_arm_m: [f64; 3],
}

impl VehicleOptions {
    /// The rotation from the IMU frame to the vehicle frame, C_b^v.
    pub fn imu_to_vehicle(&self) -> nalgebra::Matrix3<f64> {
        let [r, p, y] = self.mounting_deg.map(f64::to_radians);
        nalgebra::Rotation3::from_euler_angles(r, p, y).into_inner()
    }
}

impl Default for VehicleOptions {
    fn default() -> Self {
        Self {
            mounting_deg: [0.0; 3],
            lever_arm_m: [0.0; 3],
        }
    }
}

/// Odometer (wheel speed): the vehicle's forward speed at [`VehicleOptions::lever_arm_m`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometerOptions {
    pub enabled: bool,
    /// σ of one speed reading, m/s.
    pub sigma_mps: f64,
    /// Apply at most this often, s.
    pub interval_s: f64,
    /// KF-GINS IMU files: the (1-based) column holding the forward wheel speed, m/s.
    pub column: usize,
}

impl Default for OdometerOptions {
    fn default() -> Self {
        Self {
            enabled: false,
            sigma_mps: 0.05,
            interval_s: 0.2,
            column: 8,
        }
    }
}

/// The motion constraints of a land vehicle, the part of the configuration a KF-GINS replay
/// takes from a TOML file (`imulab replay --kf-gins CONFIG.yaml --config constraints.toml`):
/// `[nhc]`, `[zupt]`, `[zaru]`, `[odometer]` and `[vehicle]`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Constraints {
    pub nhc: NhcOptions,
    pub zupt: ZuptOptions,
    pub zaru: ZaruOptions,
    pub odometer: OdometerOptions,
    pub vehicle: VehicleOptions,
}

impl Constraints {
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
            path: path.display().to_string(),
            source: e,
        })?;
        toml::from_str(&text).map_err(|e| ConfigError::Constraints {
            path: path.display().to_string(),
            message: e.message().to_string(),
        })
    }

    /// Applies these constraints to `config`.
    pub fn apply(&self, config: &mut FusionConfig) {
        config.nhc = self.nhc;
        config.zupt = self.zupt;
        config.zaru = self.zaru;
        config.odometer = self.odometer;
        config.vehicle = self.vehicle;
    }
}

/// Initial alignment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AlignmentOptions {
    /// Heading given by the user, degrees from north; otherwise from GNSS velocity.
    pub heading_deg: Option<f64>,
    /// Speed above which the GNSS track gives the heading, m/s.
    pub min_speed_mps: f64,
    /// Minimum static data for levelling before starting with a given heading, s.
    pub level_s: f64,
}

impl Default for AlignmentOptions {
    fn default() -> Self {
        Self {
            heading_deg: None,
            min_speed_mps: 3.0,
            level_s: 5.0,
        }
    }
}

/// Initial 1σ uncertainty of the navigation states.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InitialSigma {
    pub position_m: f64,
    pub velocity_mps: f64,
    pub roll_pitch_deg: f64,
    pub heading_deg: f64,
}

impl Default for InitialSigma {
    fn default() -> Self {
        Self {
            position_m: 2.0,
            velocity_mps: 0.2,
            roll_pitch_deg: 1.0,
            heading_deg: 5.0,
        }
    }
}

/// Everything the filter needs besides data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FusionConfig {
    /// 15 states (position, velocity, attitude, gyro and accel bias) or 21 (plus scale factors).
    pub states: usize,
    /// The turn-on bias of each gyro and accelerometer axis as a random-constant state of its
    /// own (6 states more), beside the in-run bias state. With one state per axis, that state
    /// carries both: it keeps the initial σ as its stationary σ, so once the bias is estimated
    /// its σ grows back towards the whole turn-on σ wherever it is not observed (a long
    /// straight, an outage), while the true turn-on bias stays constant; the filter is then
    /// cautious. With these states only the in-run part wanders.
    pub turn_on_states: bool,
    pub mechanisation: MechanisationOptions,
    pub imu: ImuModel,
    pub gnss: GnssOptions,
    pub nhc: NhcOptions,
    pub zupt: ZuptOptions,
    pub zaru: ZaruOptions,
    pub odometer: OdometerOptions,
    pub vehicle: VehicleOptions,
    pub alignment: AlignmentOptions,
    pub initial: InitialSigma,
    /// Covariance propagation interval, s (the mechanisation runs at the IMU rate).
    pub covariance_interval_s: f64,
    /// Output interval of the trajectory, s.
    pub output_interval_s: f64,
}

impl FusionConfig {
    /// States of the filter: `states` (15 or 21), plus 6 for the turn-on biases
    /// ([`FusionConfig::turn_on_states`]), plus 3 for the GNSS position error when it is
    /// modelled ([`GnssPositionError`]): 15 to 30 (see [`crate::models::Layout`]).
    pub fn filter_states(&self) -> usize {
        crate::models::Layout::of(self).states
    }
}

impl Default for FusionConfig {
    fn default() -> Self {
        Self {
            states: 15,
            turn_on_states: false,
            mechanisation: MechanisationOptions::default(),
            imu: ImuModel::default(),
            gnss: GnssOptions::default(),
            nhc: NhcOptions::default(),
            zupt: ZuptOptions::default(),
            zaru: ZaruOptions::default(),
            odometer: OdometerOptions::default(),
            vehicle: VehicleOptions::default(),
            alignment: AlignmentOptions::default(),
            initial: InitialSigma::default(),
            covariance_interval_s: 0.05,
            output_interval_s: 0.1,
        }
    }
}

/// A configuration value that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("fusion config {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("fusion config {path}: {source}")]
    Parse {
        path: String,
        source: Box<toml::de::Error>,
    },
    #[error("constraints {path}: {message} (with --kf-gins the IMU noise, lever arm and initial state come from the YAML; this file may set [nhc], [zupt] and [zaru] only)")]
    Constraints { path: String, message: String },
    #[error("fusion config: {key} = {value} is invalid: {why}")]
    Invalid {
        key: &'static str,
        value: String,
        why: &'static str,
    },
}

fn check(key: &'static str, value: f64, ok: bool, why: &'static str) -> Result<(), ConfigError> {
    if value.is_finite() && ok {
        Ok(())
    } else {
        Err(ConfigError::Invalid {
            key,
            value: value.to_string(),
            why,
        })
    }
}

impl FusionConfig {
    /// Reads and validates a TOML configuration file.
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// Parses and validates TOML text; `origin` names it in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let config: Self = toml::from_str(text).map_err(|source| ConfigError::Parse {
            path: origin.to_string(),
            source: Box::new(source),
        })?;
        config.validate()?;
        Ok(config)
    }

    /// Checks every number for sense.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.states != 15 && self.states != 21 {
            return Err(ConfigError::Invalid {
                key: "states",
                value: self.states.to_string(),
                why: "must be 15 or 21",
            });
        }
        let nonneg = "must be finite and ≥ 0";
        let pos = "must be finite and > 0";
        let imu = &self.imu;
        let per_axis = |key: &'static str, v: Axes| -> Result<(), ConfigError> {
            v.0.iter()
                .try_for_each(|&x| check(key, x, x >= 0.0, nonneg))
        };
        per_axis("imu.arw_rad_per_sqrt_s", imu.arw_rad_per_sqrt_s)?;
        per_axis("imu.vrw_mps_per_sqrt_s", imu.vrw_mps_per_sqrt_s)?;
        for (key, gm) in [
            ("imu.gyro_bias.sigma", imu.gyro_bias),
            ("imu.accel_bias.sigma", imu.accel_bias),
            ("imu.gyro_scale.sigma", imu.gyro_scale),
            ("imu.accel_scale.sigma", imu.accel_scale),
        ]
        .into_iter()
        .chain(
            imu.gyro_bias_slow
                .map(|gm| ("imu.gyro_bias_slow.sigma", gm)),
        )
        .chain(
            imu.accel_bias_slow
                .map(|gm| ("imu.accel_bias_slow.sigma", gm)),
        ) {
            per_axis(key, gm.sigma)?;
            if gm.tau_s.is_nan() {
                return Err(ConfigError::Invalid {
                    key: "imu.*.tau_s",
                    value: "NaN".into(),
                    why: "must be a number (inf or 0 = random constant)",
                });
            }
        }
        for (key, v) in [
            ("imu.gyro_bias_initial_sigma", imu.gyro_bias_initial_sigma),
            ("imu.accel_bias_initial_sigma", imu.accel_bias_initial_sigma),
        ] {
            if let Some(v) = v {
                per_axis(key, v)?;
            }
        }
        per_axis(
            "imu.gyro_rrw_rad_per_s_sqrt_s",
            imu.gyro_rrw_rad_per_s_sqrt_s,
        )?;
        per_axis(
            "imu.accel_rrw_mps2_per_sqrt_s",
            imu.accel_rrw_mps2_per_sqrt_s,
        )?;
        for v in imu.gyro_bias_g_sensitivity_sigma {
            check("imu.gyro_bias_g_sensitivity_sigma", v, v >= 0.0, nonneg)?;
        }
        let follows_manoeuvres = imu.gyro_bias.tau_s.is_finite() && imu.gyro_bias.tau_s > 0.0;
        if imu.gyro_bias_g_sensitivity_sigma.iter().any(|&v| v > 0.0) && !follows_manoeuvres {
            return Err(ConfigError::Invalid {
                key: "imu.gyro_bias.tau_s",
                value: imu.gyro_bias.tau_s.to_string(),
                why: "must be finite and > 0 when imu.gyro_bias_g_sensitivity_sigma is set",
            });
        }
        check(
            "gnss.position_correlation_s",
            self.gnss.position_correlation_s,
            self.gnss.position_correlation_s >= 0.0,
            nonneg,
        )?;
        let e = &self.gnss.position_error;
        check(
            "gnss.position_error.horizontal_m",
            e.horizontal_m,
            e.horizontal_m >= 0.0,
            nonneg,
        )?;
        check(
            "gnss.position_error.vertical_m",
            e.vertical_m,
            e.vertical_m >= 0.0,
            nonneg,
        )?;
        if e.enabled() {
            check(
                "gnss.position_error.tau_s",
                e.tau_s,
                e.tau_s > 0.0,
                "must be positive and finite when a σ is set",
            )?;
        }
        for (i, l) in self.gnss.lever_arm_m.iter().enumerate() {
            let key = [
                "gnss.lever_arm_m[0]",
                "gnss.lever_arm_m[1]",
                "gnss.lever_arm_m[2]",
            ][i];
            check(key, *l, l.abs() < 100.0, "must be finite and within ±100 m")?;
        }
        let g = &self.gnss;
        check(
            "gnss.min_position_sigma_m",
            g.min_position_sigma_m,
            g.min_position_sigma_m > 0.0,
            pos,
        )?;
        check(
            "gnss.min_velocity_sigma_mps",
            g.min_velocity_sigma_mps,
            g.min_velocity_sigma_mps > 0.0,
            pos,
        )?;
        check(
            "gnss.innovation_gate",
            g.innovation_gate,
            g.innovation_gate >= 0.0,
            nonneg,
        )?;
        check(
            "nhc.sigma_mps",
            self.nhc.sigma_mps,
            self.nhc.sigma_mps > 0.0,
            pos,
        )?;
        if let Some(v) = self.nhc.lateral_sigma_mps {
            check("nhc.lateral_sigma_mps", v, v > 0.0, pos)?;
        }
        check(
            "nhc.slip_deg_per_mps2",
            self.nhc.slip_deg_per_mps2,
            (0.0..=5.0).contains(&self.nhc.slip_deg_per_mps2),
            "must be within [0, 5]",
        )?;
        check(
            "nhc.slip_sigma_deg_per_mps2",
            self.nhc.slip_sigma_deg_per_mps2,
            (0.0..=5.0).contains(&self.nhc.slip_sigma_deg_per_mps2),
            "must be within [0, 5]",
        )?;
        check(
            "nhc.min_speed_mps",
            self.nhc.min_speed_mps,
            self.nhc.min_speed_mps >= 0.0,
            nonneg,
        )?;
        check(
            "nhc.interval_s",
            self.nhc.interval_s,
            self.nhc.interval_s >= 0.0,
            nonneg,
        )?;
        let z = &self.zupt;
        check("zupt.sigma_mps", z.sigma_mps, z.sigma_mps > 0.0, pos)?;
        check(
            "zupt.gyro_threshold_rad_s",
            z.gyro_threshold_rad_s,
            z.gyro_threshold_rad_s > 0.0,
            pos,
        )?;
        check(
            "zupt.accel_threshold_mps2",
            z.accel_threshold_mps2,
            z.accel_threshold_mps2 > 0.0,
            pos,
        )?;
        check("zupt.window_s", z.window_s, z.window_s > 0.0, pos)?;
        check(
            "zupt.innovation_gate",
            z.innovation_gate,
            z.innovation_gate >= 0.0,
            nonneg,
        )?;
        check(
            "zaru.sigma_rad_s",
            self.zaru.sigma_rad_s,
            self.zaru.sigma_rad_s > 0.0,
            pos,
        )?;
        check(
            "zupt.max_speed_mps",
            z.max_speed_mps,
            z.max_speed_mps > 0.0,
            pos,
        )?;
        let o = &self.odometer;
        check("odometer.sigma_mps", o.sigma_mps, o.sigma_mps > 0.0, pos)?;
        check(
            "odometer.interval_s",
            o.interval_s,
            o.interval_s >= 0.0,
            nonneg,
        )?;
        if o.column < 8 {
            return Err(ConfigError::Invalid {
                key: "odometer.column",
                value: o.column.to_string(),
                why: "must be 8 or more (columns 1-7 are time and increments)",
            });
        }
        for (i, m) in self.vehicle.mounting_deg.iter().enumerate() {
            let key = [
                "vehicle.mounting_deg[0]",
                "vehicle.mounting_deg[1]",
                "vehicle.mounting_deg[2]",
            ][i];
            check(key, *m, m.abs() <= 180.0, "must be finite and within ±180°")?;
        }
        for (i, l) in self.vehicle.lever_arm_m.iter().enumerate() {
            let key = [
                "vehicle.lever_arm_m[0]",
                "vehicle.lever_arm_m[1]",
                "vehicle.lever_arm_m[2]",
            ][i];
            check(key, *l, l.abs() < 100.0, "must be finite and within ±100 m")?;
        }
        let a = &self.alignment;
        if let Some(h) = a.heading_deg {
            check("alignment.heading_deg", h, true, "must be finite")?;
        }
        check(
            "alignment.min_speed_mps",
            a.min_speed_mps,
            a.min_speed_mps > 0.0,
            pos,
        )?;
        check("alignment.level_s", a.level_s, a.level_s >= 0.0, nonneg)?;
        let i = &self.initial;
        check("initial.position_m", i.position_m, i.position_m > 0.0, pos)?;
        check(
            "initial.velocity_mps",
            i.velocity_mps,
            i.velocity_mps > 0.0,
            pos,
        )?;
        check(
            "initial.roll_pitch_deg",
            i.roll_pitch_deg,
            i.roll_pitch_deg > 0.0,
            pos,
        )?;
        check(
            "initial.heading_deg",
            i.heading_deg,
            i.heading_deg > 0.0,
            pos,
        )?;
        check(
            "covariance_interval_s",
            self.covariance_interval_s,
            self.covariance_interval_s > 0.0 && self.covariance_interval_s <= 1.0,
            "must be in (0, 1] s",
        )?;
        check(
            "output_interval_s",
            self.output_interval_s,
            self.output_interval_s > 0.0,
            pos,
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_toml_overrides_parse() {
        FusionConfig::default()
            .validate()
            .expect("defaults are valid");
        let c = FusionConfig::from_toml_str(
            "states = 21\n[gnss]\nlever_arm_m = [0.5, 0.0, -1.2]\n[imu.gyro_bias]\nsigma = 1e-5\ntau_s = 100.0\n",
            "test",
        )
        .expect("valid");
        assert_eq!(c.states, 21);
        assert_eq!(c.gnss.lever_arm_m, [0.5, 0.0, -1.2]);
        assert!((c.imu.gyro_bias.axis(2).driving_psd() - 2e-10 / 100.0).abs() < 1e-20);
    }

    #[test]
    fn imu_figures_are_one_number_or_one_per_axis() {
        let c = FusionConfig::from_toml_str(
            "[imu]\narw_rad_per_sqrt_s = 1e-4\nvrw_mps_per_sqrt_s = [1e-3, 2e-3, 3e-3]\n[imu.accel_bias]\nsigma = [1e-4, 5e-4, 2e-4]\ntau_s = 300.0\n",
            "test",
        )
        .expect("valid");
        assert_eq!(c.imu.arw_rad_per_sqrt_s, Axes::all(1e-4));
        assert_eq!(c.imu.vrw_mps_per_sqrt_s, Axes([1e-3, 2e-3, 3e-3]));
        assert_eq!(c.imu.accel_bias_state(1).sigma, 5e-4);
        assert_eq!(c.imu.accel_bias_sigma0(2), 2e-4);
        // Written back: equal axes as one number, different ones as a list.
        let text = toml::to_string(&c).expect("serialise");
        assert!(text.contains("arw_rad_per_sqrt_s = 0.0001\n"), "{text}");
        assert!(
            text.contains("vrw_mps_per_sqrt_s = [0.001, 0.002, 0.003]"),
            "{text}"
        );
        let back = FusionConfig::from_toml_str(&text, "back").expect("reads back");
        assert_eq!(back.imu, c.imu);
        let e = FusionConfig::from_toml_str("[imu]\narw_rad_per_sqrt_s = [1e-4, 2e-4]\n", "x")
            .expect_err("two axes");
        assert!(e.to_string().contains("list of three"), "{e}");
        let e =
            FusionConfig::from_toml_str("[imu]\nvrw_mps_per_sqrt_s = [1e-3, -1e-3, 1e-3]\n", "x")
                .expect_err("negative axis");
        assert!(e.to_string().contains("imu.vrw_mps_per_sqrt_s"), "{e}");
    }

    #[test]
    fn bad_keys_and_values_are_named() {
        let e = FusionConfig::from_toml_str("stats = 15\n", "cfg.toml").expect_err("unknown key");
        assert!(
            e.to_string().contains("cfg.toml") && e.to_string().contains("stats"),
            "{e}"
        );
        let e = FusionConfig::from_toml_str("states = 16\n", "x").expect_err("bad count");
        assert!(e.to_string().contains("states"), "{e}");
        let e =
            FusionConfig::from_toml_str("covariance_interval_s = -1.0\n", "x").expect_err("neg");
        assert!(e.to_string().contains("covariance_interval_s"), "{e}");
        let e = FusionConfig::from_toml_str("[nhc]\nsigma_mps = nan\n", "x").expect_err("nan");
        assert!(e.to_string().contains("nhc.sigma_mps"), "{e}");
        let e = FusionConfig::from_toml_str("[nhc]\nlateral_sigma_mps = -0.1\n", "x")
            .expect_err("negative");
        assert!(e.to_string().contains("nhc.lateral_sigma_mps"), "{e}");
        let e = FusionConfig::from_toml_str(
            "[imu]\naccel_bias_slow = { sigma = -1.0, tau_s = 100.0 }\n",
            "x",
        )
        .expect_err("negative");
        assert!(e.to_string().contains("imu.accel_bias_slow.sigma"), "{e}");
        let c = FusionConfig::from_toml_str(
            "[imu]\ngyro_bias_slow = { sigma = [1e-5, 2e-5, 3e-5], tau_s = 2645.0 }\n",
            "x",
        )
        .expect("slow part");
        let slow = c.imu.gyro_bias_slow.expect("read");
        assert_eq!((slow.sigma[1], slow.tau_s), (2e-5, 2645.0));
    }

    /// The bias state keeps the initial σ as its stationary σ and the in-run driving noise;
    /// without that it relaxed to the in-run σ whatever was observed.
    #[test]
    fn bias_state_keeps_the_initial_sigma_and_the_in_run_driving_noise() {
        let in_run = GaussMarkov {
            sigma: 1.0,
            tau_s: 40.0,
        };
        let s = bias_state_process(&in_run, 5.0);
        assert_eq!(s.sigma, 5.0);
        assert!((s.tau_s - 1000.0).abs() < 1e-9, "{}", s.tau_s);
        assert!((s.driving_psd() - in_run.driving_psd()).abs() < 1e-15);
        // Nothing to carry: unchanged.
        assert_eq!(bias_state_process(&in_run, 1.0), in_run);
        assert_eq!(bias_state_process(&in_run, 0.5), in_run);
        assert_eq!(bias_state_process(&in_run, f64::NAN), in_run);
        let constant = GaussMarkov {
            sigma: 1.0,
            tau_s: 0.0,
        };
        assert_eq!(bias_state_process(&constant, 5.0), constant);
        // No in-run noise: a random constant of the initial σ (it decayed to zero before).
        let quiet = GaussMarkov {
            sigma: 0.0,
            tau_s: 40.0,
        };
        let s = bias_state_process(&quiet, 5.0);
        assert_eq!((s.sigma, s.decay(), s.driving_psd()), (5.0, 0.0, 0.0));
        // What the filter uses.
        let model = ImuModel {
            gyro_bias: GaussMarkov {
                sigma: Axes::all(in_run.sigma),
                tau_s: in_run.tau_s,
            },
            gyro_bias_initial_sigma: Some(Axes::all(5.0)),
            ..ImuModel::default()
        };
        assert_eq!(model.gyro_bias_state(2), bias_state_process(&in_run, 5.0));
        // The g-sensitivity part drives only the axes it is given for.
        let sensitive = ImuModel {
            gyro_bias_g_sensitivity_sigma: [3.0, 0.0, 0.0],
            ..model
        };
        assert!(
            sensitive.gyro_bias_state(0).driving_psd() > model.gyro_bias_state(0).driving_psd()
        );
        assert_eq!(sensitive.gyro_bias_state(1), model.gyro_bias_state(1));
        assert_eq!(sensitive.gyro_bias_state(2), model.gyro_bias_state(2));
        assert_eq!(model.accel_bias_state(1), model.accel_bias.axis(1));
        // With the turn-on bias as states of its own, the bias state is the in-run process as
        // it is and the turn-on state holds the rest of the initial σ: a random constant, or
        // with a slow in-run part that part's driving noise.
        assert_eq!(model.gyro_in_run_state(2), in_run);
        assert!((model.gyro_turn_on_sigma(2).hypot(in_run.sigma) - 5.0).abs() < 1e-12);
        assert_eq!(model.gyro_turn_on_state(2).decay(), 0.0);
        let slow = GaussMarkov {
            sigma: 2.0,
            tau_s: 2000.0,
        };
        let split = ImuModel {
            gyro_bias_slow: Some(GaussMarkov {
                sigma: Axes::all(slow.sigma),
                tau_s: slow.tau_s,
            }),
            ..model
        };
        assert_eq!(split.gyro_in_run_state(2), in_run);
        let s = split.gyro_turn_on_state(2);
        assert!((s.sigma - split.gyro_turn_on_sigma(2)).abs() < 1e-12);
        assert!((s.driving_psd() / slow.driving_psd() - 1.0).abs() < 1e-12);
        // A slow part larger than the turn-on σ is its own process.
        let large = ImuModel {
            gyro_bias_initial_sigma: Some(Axes::all(1.5)),
            ..split
        };
        assert_eq!(large.gyro_turn_on_state(0), slow);
        assert_eq!(sensitive.gyro_turn_on_sigma(1), model.gyro_turn_on_sigma(1));
    }
}
