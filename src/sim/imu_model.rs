//! The IMU error model: what a gyro or accelerometer triad adds to the true angular rate
//! and specific force, per axis, and the per-sample simulator that applies it.
//!
//! Specs are written in the units of datasheets (°/h, °/√h, mg, µg/√Hz, ppm, mrad) with the
//! unit in each field name, and converted once to SI. Output of one axis:
//!
//! y = sat_q( Σ_j M_ij (1 + k_s ΔT δ_ij) x_j + k_q x_i² + b_i(t) + [G a]_i + w_i )
//!
//! with M = I + diag(scale factor) + misalignment; k_q the quadratic scale-factor term
//! (gyros only); b the sum of constant, turn-on,
//! instability (Gauss-Markov processes, see [`super::flicker`], whose Allan floor is 0.664·B
//! for a spec's bias instability B: the convention of IEEE Std 952 and of the noise fit in
//! `imulab allan`'s fit ([`imulab_noise`]), so a preset's B is what `imulab allan --fit` reads back), rate random
//! walk, rate ramp and temperature coefficient × ΔT; G the gyro g-sensitivity (gyros only); w white
//! noise; then saturation at ±range and rounding to the LSB.

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::flicker::{FlickerDesign, SlowProcess};
use super::rng::Stream;
use imulab_noise::BIAS_INSTABILITY_FACTOR;
use imulab_store::{ImuRecord, TruthImuRecord};

/// Standard gravity used for g and mg units, m/s².
pub const G0: f64 = 9.806_65;
const DEG: f64 = std::f64::consts::PI / 180.0;
/// The random walk of a rate random walk term is updated once per this many seconds and
/// linearly interpolated between (see [`SlowProcess`]).
const RRW_UPDATE_INTERVAL_S: f64 = 1.0;

/// Status bit set when any gyro axis clipped at its range.
pub const STATUS_GYRO_SATURATED: u32 = 1 << 0;
/// Status bit set when any accelerometer axis clipped at its range.
pub const STATUS_ACCEL_SATURATED: u32 = 1 << 1;

/// Gyro triad errors, per axis X/Y/Z, in datasheet units. Zero (or absent) disables a term.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GyroSpec {
    /// Angle random walk, °/√h (= Allan deviation at τ = 1 h, in °/h). Alternative to
    /// `noise_density_dps_rthz`; at most one of the two may be given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub arw_deg_rth: Option<[f64; 3]>,
    /// White rate noise density, °/s/√Hz.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise_density_dps_rthz: Option<[f64; 3]>,
    /// Bias instability B, °/h, as IEEE Std 952 defines it and as `imulab allan --fit` reports
    /// it: the flat floor of the Allan deviation is 0.664·B (√(2 ln 2/π)·B). A datasheet that
    /// quotes the Allan minimum itself is entered as minimum / 0.664.
    pub bias_instability_dph: [f64; 3],
    /// The band of τ over which the instability floor is flat, s.
    pub bias_instability_band_s: [f64; 2],
    /// Rate random walk, °/h/√h.
    pub rrw_dph_rth: [f64; 3],
    /// Rate ramp (linear bias drift), °/h per hour.
    pub rate_ramp_dph_per_h: [f64; 3],
    /// Constant bias, °/h.
    pub bias_dph: [f64; 3],
    /// Standard deviation of the turn-on bias (drawn once per run), °/h.
    pub turn_on_bias_sigma_dph: [f64; 3],
    /// Scale-factor error, ppm.
    pub scale_factor_ppm: [f64; 3],
    /// Scale-factor non-linearity (a quadratic term), ppm of the reading per °/s: axis i
    /// adds k_i·10⁻⁶·(ω_i in °/s)·ω_i to its output, ω_i the true rate about it.
    #[serde(skip_serializing_if = "all_zero")]
    pub scale_quadratic_ppm_per_dps: [f64; 3],
    /// Axis misalignment (cross-coupling) M_xy, M_xz, M_yx, M_yz, M_zx, M_zy, mrad; M_ij is
    /// the sensitivity of axis i to rate about axis j.
    pub misalignment_mrad: [f64; 6],
    /// g-sensitivity: bias per specific force, row = gyro axis, column = accel axis, °/h/g.
    pub g_sensitivity_dph_per_g: [[f64; 3]; 3],
    /// Bias temperature coefficient, °/h per °C away from the reference temperature.
    pub bias_tempco_dph_per_c: [f64; 3],
    /// Scale-factor temperature coefficient, ppm/°C.
    pub scale_tempco_ppm_per_c: [f64; 3],
    /// Second-order bias temperature coefficient, °/h per °C² (bias += c2·ΔT²).
    pub bias_tempco2_dph_per_c2: [f64; 3],
    /// Second-order scale-factor temperature coefficient, ppm/°C².
    pub scale_tempco2_ppm_per_c2: [f64; 3],
    /// Thermal hysteresis: the bias on a rising temperature lies this far above the bias on
    /// a falling one, °/h (the branch switches over `thermal.hysteresis_width_c`).
    pub bias_hysteresis_dph: [f64; 3],
    /// Warm-up transient: extra bias at power-on, decaying with `thermal.warmup_time_constant_s`, °/h.
    pub warmup_bias_dph: [f64; 3],
    /// White-noise change with temperature, % per °C away from the reference.
    pub noise_tempco_percent_per_c: [f64; 3],
    /// Measurement range ±, °/s (absent: no saturation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range_dps: Option<f64>,
    /// Output resolution (one LSB), °/s (absent: no quantisation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lsb_dps: Option<f64>,
}

fn all_zero(v: &[f64; 3]) -> bool {
    v.iter().all(|&x| x == 0.0)
}

/// Accelerometer triad errors, per axis X/Y/Z, in datasheet units.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AccelSpec {
    /// Velocity random walk in the bench study's "mg/√h", read as 1 mg/√h = 9.80665e-3
    /// m/s/√h (so 6 mg/√h is a white noise density of 100 µg/√Hz; see docs/simulator.md).
    /// Alternative to `noise_density_ug_rthz`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vrw_mg_rth: Option<[f64; 3]>,
    /// White noise density, µg/√Hz.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise_density_ug_rthz: Option<[f64; 3]>,
    /// Bias instability B, mg (IEEE Std 952, as `imulab allan --fit` reports it): the flat
    /// floor of the Allan deviation is 0.664·B.
    pub bias_instability_mg: [f64; 3],
    /// The band of τ over which the instability floor is flat, s.
    pub bias_instability_band_s: [f64; 2],
    /// Bias random walk, mg/√h (bias spread after one hour).
    pub rrw_mg_rth: [f64; 3],
    /// Bias ramp, mg per hour.
    pub rate_ramp_mg_per_h: [f64; 3],
    /// Constant bias, mg.
    pub bias_mg: [f64; 3],
    /// Standard deviation of the turn-on bias, mg.
    pub turn_on_bias_sigma_mg: [f64; 3],
    /// Scale-factor error, ppm.
    pub scale_factor_ppm: [f64; 3],
    /// Axis misalignment M_xy, M_xz, M_yx, M_yz, M_zx, M_zy, mrad.
    pub misalignment_mrad: [f64; 6],
    /// Bias temperature coefficient, mg/°C.
    pub bias_tempco_mg_per_c: [f64; 3],
    /// Scale-factor temperature coefficient, ppm/°C.
    pub scale_tempco_ppm_per_c: [f64; 3],
    /// Second-order bias temperature coefficient, mg/°C².
    pub bias_tempco2_mg_per_c2: [f64; 3],
    /// Second-order scale-factor temperature coefficient, ppm/°C².
    pub scale_tempco2_ppm_per_c2: [f64; 3],
    /// Thermal hysteresis: rising-temperature bias minus falling-temperature bias, mg.
    pub bias_hysteresis_mg: [f64; 3],
    /// Warm-up transient: extra bias at power-on, mg.
    pub warmup_bias_mg: [f64; 3],
    /// White-noise change with temperature, % per °C away from the reference.
    pub noise_tempco_percent_per_c: [f64; 3],
    /// Measurement range ±, g (absent: no saturation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range_g: Option<f64>,
    /// Output resolution (one LSB), mg (absent: no quantisation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lsb_mg: Option<f64>,
}

/// Sampling imperfections of the device and its link.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TimingSpec {
    /// Standard deviation of the host arrival-time jitter, µs (clipped to ±0.45 sample
    /// periods so timestamps stay increasing). The signal itself is sampled on time.
    pub jitter_us: f64,
    /// Probability that a sample is lost on the link (its counter value is skipped).
    pub drop_probability: f64,
    /// The device counter counts samples modulo this value (0: never wraps).
    pub counter_modulo: u64,
}

impl Default for TimingSpec {
    fn default() -> Self {
        TimingSpec {
            jitter_us: 0.0,
            drop_probability: 0.0,
            counter_modulo: 65_536,
        }
    }
}

/// The device's thermal behaviour: how its own temperature follows the chamber, how it is
/// reported, and the shared constants of the hysteresis and warm-up terms of the triads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ThermalSpec {
    /// First-order time constant of the sensor temperature following the chamber, s
    /// (0: the sensor is at the chamber temperature).
    pub time_constant_s: f64,
    /// Temperature change over which the hysteresis moves from one branch to the other, °C.
    pub hysteresis_width_c: f64,
    /// Time constant of the warm-up bias transient after power-on, s.
    pub warmup_time_constant_s: f64,
    /// Resolution of the temperature the device reports, °C (0: not quantised).
    pub temp_lsb_c: f64,
}

impl Default for ThermalSpec {
    fn default() -> Self {
        ThermalSpec {
            time_constant_s: 0.0,
            hysteresis_width_c: 2.0,
            warmup_time_constant_s: 0.0,
            temp_lsb_c: 0.0,
        }
    }
}

/// A complete IMU: both triads, timing, thermal behaviour, and the temperature the
/// coefficients refer to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuSpec {
    pub gyro: GyroSpec,
    pub accel: AccelSpec,
    pub timing: TimingSpec,
    pub thermal: ThermalSpec,
    /// Temperature at which biases and scale factors are as specified, °C.
    pub reference_temp_c: f64,
}

impl Default for ImuSpec {
    fn default() -> Self {
        ImuSpec {
            gyro: GyroSpec {
                bias_instability_band_s: DEFAULT_BAND_S,
                ..GyroSpec::default()
            },
            accel: AccelSpec {
                bias_instability_band_s: DEFAULT_BAND_S,
                ..AccelSpec::default()
            },
            timing: TimingSpec::default(),
            thermal: ThermalSpec::default(),
            reference_temp_c: 25.0,
        }
    }
}

/// Default τ band of a flat bias-instability floor, s.
pub const DEFAULT_BAND_S: [f64; 2] = [1.0, 5000.0];

/// One triad's error terms in SI units (rad/s or m/s²), the form the simulator runs on.
#[derive(Debug, Clone, PartialEq)]
pub struct TriadErrors {
    /// White noise density, unit/√Hz.
    pub white_density: [f64; 3],
    /// Flat floor of the Allan deviation that the bias instability produces, unit: 0.664·B
    /// for a spec's bias instability B.
    pub instability_floor: [f64; 3],
    pub bias_instability_band_s: [f64; 2],
    /// Rate (bias) random walk, unit/√s.
    pub random_walk: [f64; 3],
    /// Bias ramp, unit/s.
    pub ramp: [f64; 3],
    pub bias: [f64; 3],
    pub turn_on_sigma: [f64; 3],
    /// Scale-factor error, fraction.
    pub scale_factor: [f64; 3],
    /// Quadratic scale-factor term, fraction of the reading per unit of input.
    pub scale_quadratic: [f64; 3],
    /// Misalignment xy, xz, yx, yz, zx, zy, rad.
    pub misalignment: [f64; 6],
    /// Bias temperature coefficient, unit/°C.
    pub bias_tempco: [f64; 3],
    /// Scale-factor temperature coefficient, fraction/°C.
    pub scale_tempco: [f64; 3],
    /// Second-order bias temperature coefficient, unit/°C².
    pub bias_tempco2: [f64; 3],
    /// Second-order scale-factor temperature coefficient, fraction/°C².
    pub scale_tempco2: [f64; 3],
    /// Rising minus falling branch of the bias, unit.
    pub hysteresis: [f64; 3],
    /// Warm-up bias at power-on, unit.
    pub warmup: [f64; 3],
    /// White-noise change, fraction per °C.
    pub noise_tempco: [f64; 3],
    /// Range ±, unit (infinite: none).
    pub range: f64,
    /// LSB, unit (0: none).
    pub lsb: f64,
}

fn scale3(v: [f64; 3], k: f64) -> [f64; 3] {
    [v[0] * k, v[1] * k, v[2] * k]
}

fn check_white(
    a: Option<[f64; 3]>,
    a_name: &str,
    b: Option<[f64; 3]>,
    b_name: &str,
) -> Result<(), String> {
    if a.is_some() && b.is_some() {
        return Err(format!(
            "give white noise as either {a_name} or {b_name}, not both"
        ));
    }
    Ok(())
}

impl GyroSpec {
    /// SI form, after checking every value (the error names the field).
    pub fn to_si(&self) -> Result<TriadErrors, String> {
        check_white(
            self.arw_deg_rth,
            "arw_deg_rth",
            self.noise_density_dps_rthz,
            "noise_density_dps_rthz",
        )?;
        let white = match (self.arw_deg_rth, self.noise_density_dps_rthz) {
            (Some(arw), _) => scale3(arw, DEG / 60.0),
            (None, Some(d)) => scale3(d, DEG),
            (None, None) => [0.0; 3],
        };
        let dph = DEG / 3600.0;
        let e = TriadErrors {
            white_density: white,
            instability_floor: scale3(self.bias_instability_dph, dph * BIAS_INSTABILITY_FACTOR),
            bias_instability_band_s: self.bias_instability_band_s,
            random_walk: scale3(self.rrw_dph_rth, dph / 60.0),
            ramp: scale3(self.rate_ramp_dph_per_h, dph / 3600.0),
            bias: scale3(self.bias_dph, dph),
            turn_on_sigma: scale3(self.turn_on_bias_sigma_dph, dph),
            scale_factor: scale3(self.scale_factor_ppm, 1e-6),
            scale_quadratic: scale3(self.scale_quadratic_ppm_per_dps, 1e-6 / DEG),
            misalignment: self.misalignment_mrad.map(|m| m * 1e-3),
            bias_tempco: scale3(self.bias_tempco_dph_per_c, dph),
            scale_tempco: scale3(self.scale_tempco_ppm_per_c, 1e-6),
            bias_tempco2: scale3(self.bias_tempco2_dph_per_c2, dph),
            scale_tempco2: scale3(self.scale_tempco2_ppm_per_c2, 1e-6),
            hysteresis: scale3(self.bias_hysteresis_dph, dph),
            warmup: scale3(self.warmup_bias_dph, dph),
            noise_tempco: scale3(self.noise_tempco_percent_per_c, 1e-2),
            range: self.range_dps.map_or(f64::INFINITY, |r| r * DEG),
            lsb: self.lsb_dps.map_or(0.0, |l| l * DEG),
        };
        e.validate()?;
        let g = self.g_sensitivity_dph_per_g;
        if g.iter().flatten().any(|x| !x.is_finite()) {
            return Err("g_sensitivity_dph_per_g must hold finite numbers".into());
        }
        Ok(e)
    }

    /// g-sensitivity matrix in rad/s per m/s², or None when all zero.
    pub fn g_sensitivity_si(&self) -> Option<Matrix3<f64>> {
        let g = self.g_sensitivity_dph_per_g;
        if g.iter().flatten().all(|&x| x == 0.0) {
            return None;
        }
        let k = DEG / 3600.0 / G0;
        Some(Matrix3::from_fn(|i, j| g[i][j] * k))
    }
}

impl AccelSpec {
    /// SI form, after checking every value (the error names the field).
    pub fn to_si(&self) -> Result<TriadErrors, String> {
        check_white(
            self.vrw_mg_rth,
            "vrw_mg_rth",
            self.noise_density_ug_rthz,
            "noise_density_ug_rthz",
        )?;
        let mg = G0 * 1e-3;
        let white = match (self.vrw_mg_rth, self.noise_density_ug_rthz) {
            (Some(vrw), _) => scale3(vrw, mg / 60.0),
            (None, Some(d)) => scale3(d, G0 * 1e-6),
            (None, None) => [0.0; 3],
        };
        let e = TriadErrors {
            white_density: white,
            instability_floor: scale3(self.bias_instability_mg, mg * BIAS_INSTABILITY_FACTOR),
            bias_instability_band_s: self.bias_instability_band_s,
            random_walk: scale3(self.rrw_mg_rth, mg / 60.0),
            ramp: scale3(self.rate_ramp_mg_per_h, mg / 3600.0),
            bias: scale3(self.bias_mg, mg),
            turn_on_sigma: scale3(self.turn_on_bias_sigma_mg, mg),
            scale_factor: scale3(self.scale_factor_ppm, 1e-6),
            scale_quadratic: [0.0; 3],
            misalignment: self.misalignment_mrad.map(|m| m * 1e-3),
            bias_tempco: scale3(self.bias_tempco_mg_per_c, mg),
            scale_tempco: scale3(self.scale_tempco_ppm_per_c, 1e-6),
            bias_tempco2: scale3(self.bias_tempco2_mg_per_c2, mg),
            scale_tempco2: scale3(self.scale_tempco2_ppm_per_c2, 1e-6),
            hysteresis: scale3(self.bias_hysteresis_mg, mg),
            warmup: scale3(self.warmup_bias_mg, mg),
            noise_tempco: scale3(self.noise_tempco_percent_per_c, 1e-2),
            range: self.range_g.map_or(f64::INFINITY, |r| r * G0),
            lsb: self.lsb_mg.map_or(0.0, |l| l * mg),
        };
        e.validate()?;
        Ok(e)
    }
}

impl TriadErrors {
    fn validate(&self) -> Result<(), String> {
        let non_negative = |v: &[f64], what: &str| -> Result<(), String> {
            match v.iter().find(|x| !(x.is_finite() && **x >= 0.0)) {
                Some(x) => Err(format!("{what} must be finite and >= 0, got {x}")),
                None => Ok(()),
            }
        };
        let finite = |v: &[f64], what: &str| -> Result<(), String> {
            match v.iter().find(|x| !x.is_finite()) {
                Some(x) => Err(format!("{what} must be finite, got {x}")),
                None => Ok(()),
            }
        };
        non_negative(&self.white_density, "white noise")?;
        non_negative(&self.instability_floor, "bias instability")?;
        non_negative(&self.random_walk, "random walk")?;
        non_negative(&self.turn_on_sigma, "turn-on bias sigma")?;
        finite(&self.ramp, "ramp")?;
        finite(&self.bias, "bias")?;
        finite(&self.scale_factor, "scale factor")?;
        finite(&self.scale_quadratic, "scale-factor non-linearity")?;
        finite(&self.misalignment, "misalignment")?;
        finite(&self.bias_tempco, "bias tempco")?;
        finite(&self.scale_tempco, "scale tempco")?;
        finite(&self.bias_tempco2, "second-order bias tempco")?;
        finite(&self.scale_tempco2, "second-order scale tempco")?;
        finite(&self.hysteresis, "bias hysteresis")?;
        finite(&self.warmup, "warm-up bias")?;
        finite(&self.noise_tempco, "noise tempco")?;
        let [lo, hi] = self.bias_instability_band_s;
        if self.instability_floor.iter().any(|&b| b > 0.0)
            && !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi > lo)
        {
            return Err(format!(
                "bias_instability_band_s must be [lo, hi] with 0 < lo < hi, got [{lo}, {hi}]"
            ));
        }
        if self.range.is_nan() || self.range <= 0.0 {
            return Err(format!("range must be > 0, got {}", self.range));
        }
        if !(self.lsb.is_finite() && self.lsb >= 0.0) {
            return Err(format!("lsb must be finite and >= 0, got {}", self.lsb));
        }
        Ok(())
    }
}

impl ImuSpec {
    /// Checks the whole spec; the error names the part and field.
    pub fn validate(&self) -> Result<(), String> {
        self.gyro.to_si().map_err(|e| format!("gyro: {e}"))?;
        self.accel.to_si().map_err(|e| format!("accel: {e}"))?;
        let t = &self.timing;
        if !(t.jitter_us.is_finite() && t.jitter_us >= 0.0) {
            return Err(format!(
                "timing.jitter_us must be >= 0, got {}",
                t.jitter_us
            ));
        }
        if !(0.0..1.0).contains(&t.drop_probability) {
            return Err(format!(
                "timing.drop_probability must be in [0, 1), got {}",
                t.drop_probability
            ));
        }
        if !self.reference_temp_c.is_finite() {
            return Err("reference_temp_c must be finite".into());
        }
        let th = &self.thermal;
        for (value, name) in [
            (th.time_constant_s, "thermal.time_constant_s"),
            (th.hysteresis_width_c, "thermal.hysteresis_width_c"),
            (th.warmup_time_constant_s, "thermal.warmup_time_constant_s"),
            (th.temp_lsb_c, "thermal.temp_lsb_c"),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(format!("{name} must be finite and >= 0, got {value}"));
            }
        }
        let warms = self.gyro.warmup_bias_dph.iter().any(|&w| w != 0.0)
            || self.accel.warmup_bias_mg.iter().any(|&w| w != 0.0);
        if warms && th.warmup_time_constant_s <= 0.0 {
            return Err(
                "a warm-up bias needs thermal.warmup_time_constant_s > 0 (how fast it decays)"
                    .into(),
            );
        }
        Ok(())
    }
}

/// Which axes of an IMU to simulate, per triad (x, y, z). Axes not simulated are NaN in the
/// output and cost nothing: no noise is drawn and no bias process advanced for them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Channels {
    pub gyro: [bool; 3],
    pub accel: [bool; 3],
}

impl Channels {
    /// Both triads, all axes.
    pub const ALL: Channels = Channels {
        gyro: [true; 3],
        accel: [true; 3],
    };
    /// The gyro triad only.
    pub const GYRO: Channels = Channels {
        gyro: [true; 3],
        accel: [false; 3],
    };
    /// The accelerometer triad only.
    pub const ACCEL: Channels = Channels {
        gyro: [false; 3],
        accel: [true; 3],
    };

    /// Some gyro axis is simulated.
    pub fn has_gyro(&self) -> bool {
        self.gyro.contains(&true)
    }

    /// Some accelerometer axis is simulated.
    pub fn has_accel(&self) -> bool {
        self.accel.contains(&true)
    }
}

/// The running error state of one triad.
#[derive(Debug, Clone)]
struct TriadSim {
    /// Axes simulated; the others are NaN.
    axes: [bool; 3],
    white_sigma: [f64; 3],
    white: [Stream; 3],
    /// Instability and random-walk processes of each axis.
    slow: [Vec<SlowProcess>; 3],
    fixed_bias: [f64; 3],
    ramp: [f64; 3],
    misalign_scale: Matrix3<f64>,
    scale_quadratic: [f64; 3],
    bias_tempco: [f64; 3],
    scale_tempco: [f64; 3],
    bias_tempco2: [f64; 3],
    scale_tempco2: [f64; 3],
    /// Half the hysteresis gap: the bias moves by ± this on the rising / falling branch.
    half_hysteresis: [f64; 3],
    warmup: [f64; 3],
    noise_tempco: [f64; 3],
    range: f64,
    lsb: f64,
}

/// The thermal state of one epoch, shared by both triads.
#[derive(Debug, Clone, Copy)]
struct ThermalState {
    /// Sensor temperature minus the reference temperature, °C.
    dtemp: f64,
    /// Hysteresis branch, from -1 (falling) to +1 (rising).
    branch: f64,
    /// Remaining fraction of the warm-up transient, e^(-t/τ).
    warmup: f64,
}

const AXES: [&str; 3] = ["x", "y", "z"];

impl TriadSim {
    fn new(e: &TriadErrors, axes: [bool; 3], seed: u64, prefix: &str, dt: f64) -> Self {
        let stream =
            |axis: usize, term: &str| Stream::new(seed, &format!("{prefix}/{}/{term}", AXES[axis]));
        let white = [0, 1, 2].map(|i| stream(i, "white"));
        let slow = [0, 1, 2].map(|i| {
            let mut procs = Vec::new();
            if axes[i] && e.instability_floor[i] > 0.0 {
                let d = FlickerDesign::new(e.instability_floor[i], e.bias_instability_band_s);
                for (k, &t) in d.taus_s.iter().enumerate() {
                    procs.push(SlowProcess::gauss_markov(
                        d.sigma,
                        t,
                        dt,
                        stream(i, &format!("instability{k}")),
                    ));
                }
            }
            if axes[i] && e.random_walk[i] > 0.0 {
                procs.push(SlowProcess::random_walk(
                    e.random_walk[i],
                    RRW_UPDATE_INTERVAL_S,
                    dt,
                    stream(i, "random_walk"),
                ));
            }
            procs
        });
        let fixed_bias = [0, 1, 2].map(|i| {
            let turn_on = if e.turn_on_sigma[i] > 0.0 {
                e.turn_on_sigma[i] * stream(i, "turn_on").normal()
            } else {
                0.0
            };
            e.bias[i] + turn_on
        });
        let m = e.misalignment;
        let s = e.scale_factor;
        let misalign_scale = Matrix3::new(
            1.0 + s[0],
            m[0],
            m[1], //
            m[2],
            1.0 + s[1],
            m[3], //
            m[4],
            m[5],
            1.0 + s[2],
        );
        TriadSim {
            axes,
            white_sigma: e.white_density.map(|d| d / dt.sqrt()),
            white,
            slow,
            fixed_bias,
            ramp: e.ramp,
            misalign_scale,
            scale_quadratic: e.scale_quadratic,
            bias_tempco: e.bias_tempco,
            scale_tempco: e.scale_tempco,
            bias_tempco2: e.bias_tempco2,
            scale_tempco2: e.scale_tempco2,
            half_hysteresis: e.hysteresis.map(|h| h / 2.0),
            warmup: e.warmup,
            noise_tempco: e.noise_tempco,
            range: e.range,
            lsb: e.lsb,
        }
    }

    /// Output and true total bias for input `x` at time `t_s` in thermal state `th`, with
    /// `extra_bias` (g-sensitivity) added. Returns (output, bias, saturated).
    #[inline]
    fn step(
        &mut self,
        x: &Vector3<f64>,
        t_s: f64,
        th: &ThermalState,
        extra_bias: &Vector3<f64>,
    ) -> ([f64; 3], [f64; 3], bool) {
        let mut scaled = self.misalign_scale * x;
        for i in 0..3 {
            scaled[i] += self.scale_quadratic[i] * x[i] * x[i];
        }
        let dtemp = th.dtemp;
        if dtemp != 0.0 {
            for i in 0..3 {
                scaled[i] += (self.scale_tempco[i] + self.scale_tempco2[i] * dtemp) * dtemp * x[i];
            }
        }
        let mut out = [f64::NAN; 3];
        let mut bias = [f64::NAN; 3];
        let mut saturated = false;
        for i in 0..3 {
            if !self.axes[i] {
                continue;
            }
            let mut b = self.fixed_bias[i]
                + self.ramp[i] * t_s
                + (self.bias_tempco[i] + self.bias_tempco2[i] * dtemp) * dtemp
                + self.half_hysteresis[i] * th.branch
                + self.warmup[i] * th.warmup;
            for p in &mut self.slow[i] {
                b += p.step();
            }
            b += extra_bias[i];
            bias[i] = b;
            let mut y = scaled[i] + b;
            if self.white_sigma[i] > 0.0 {
                let k = (1.0 + self.noise_tempco[i] * dtemp).max(0.0);
                y += k * self.white_sigma[i] * self.white[i].normal();
            }
            if y.abs() > self.range {
                y = self.range.copysign(y);
                saturated = true;
            }
            if self.lsb > 0.0 {
                y = (y / self.lsb).round() * self.lsb;
            }
            out[i] = y;
        }
        (out, bias, saturated)
    }
}

/// One simulated epoch of an IMU.
#[derive(Debug, Clone, Copy)]
pub struct ImuEpoch {
    /// The sample as logged, or None when it was dropped on the link.
    pub record: Option<ImuRecord>,
    /// True biases and error-free inputs at this epoch (NaN for triads not simulated).
    pub truth: TruthImuRecord,
}

/// Simulates one IMU sample by sample.
#[derive(Debug, Clone)]
pub struct ImuSimulator {
    gyro: Option<TriadSim>,
    accel: Option<TriadSim>,
    g_sensitivity: Option<Matrix3<f64>>,
    reference_temp_c: f64,
    thermal: ThermalSpec,
    /// Fraction of the chamber-sensor difference the sensor closes per sample.
    lag_gain: f64,
    /// Sensor temperature, °C (None before the first sample: it starts at the chamber's).
    sensor_temp_c: Option<f64>,
    branch: f64,
    jitter_sigma_ns: f64,
    jitter_clip_ns: f64,
    jitter: Stream,
    drop_probability: f64,
    drops: Stream,
    counter_modulo: u64,
    index: u64,
    dt_s: f64,
}

impl ImuSimulator {
    /// A simulator for `spec` sampled at `rate_hz`, its streams keyed by `seed` and `name`.
    pub fn new(
        spec: &ImuSpec,
        name: &str,
        seed: u64,
        rate_hz: f64,
        channels: Channels,
    ) -> Result<Self, String> {
        spec.validate()?;
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(format!("rate must be > 0 Hz, got {rate_hz}"));
        }
        let dt = 1.0 / rate_hz;
        let gyro = if channels.has_gyro() {
            Some(TriadSim::new(
                &spec.gyro.to_si()?,
                channels.gyro,
                seed,
                &format!("imu/{name}/gyro"),
                dt,
            ))
        } else {
            None
        };
        let accel = if channels.has_accel() {
            Some(TriadSim::new(
                &spec.accel.to_si()?,
                channels.accel,
                seed,
                &format!("imu/{name}/accel"),
                dt,
            ))
        } else {
            None
        };
        Ok(ImuSimulator {
            g_sensitivity: if channels.has_gyro() {
                spec.gyro.g_sensitivity_si()
            } else {
                None
            },
            gyro,
            accel,
            reference_temp_c: spec.reference_temp_c,
            thermal: spec.thermal.clone(),
            lag_gain: if spec.thermal.time_constant_s > 0.0 {
                -(-dt / spec.thermal.time_constant_s).exp_m1()
            } else {
                1.0
            },
            sensor_temp_c: None,
            branch: 0.0,
            jitter_sigma_ns: spec.timing.jitter_us * 1e3,
            jitter_clip_ns: 0.45 * dt * 1e9,
            jitter: Stream::new(seed, &format!("imu/{name}/jitter")),
            drop_probability: spec.timing.drop_probability,
            drops: Stream::new(seed, &format!("imu/{name}/drops")),
            counter_modulo: spec.timing.counter_modulo,
            index: 0,
            dt_s: dt,
        })
    }

    /// The sensor's temperature after one more sample at chamber temperature `chamber_c`
    /// (first-order lag), moving the hysteresis branch with it.
    fn follow_chamber(&mut self, chamber_c: f64) -> f64 {
        let previous = self.sensor_temp_c.unwrap_or(chamber_c);
        let now = previous + self.lag_gain * (chamber_c - previous);
        let change = now - previous;
        if change != 0.0 {
            let width = self.thermal.hysteresis_width_c;
            self.branch = if width > 0.0 {
                (self.branch + 2.0 * change / width).clamp(-1.0, 1.0)
            } else {
                change.signum()
            };
        }
        self.sensor_temp_c = Some(now);
        now
    }

    /// The next epoch given the true rate and specific force in the sensor frame, the
    /// chamber temperature, and the session's monotonic/wall-clock start times. The sensor
    /// temperature follows the chamber's through the thermal time constant; it is what the
    /// thermal terms use and what the record reports.
    pub fn step(
        &mut self,
        gyro_true: &Vector3<f64>,
        accel_true: &Vector3<f64>,
        chamber_c: f64,
        start_mono_ns: i64,
        start_wall_ns: i64,
    ) -> ImuEpoch {
        let k = self.index;
        self.index += 1;
        let t_s = k as f64 * self.dt_s;
        let temp_c = self.follow_chamber(chamber_c);
        let th = ThermalState {
            dtemp: temp_c - self.reference_temp_c,
            branch: self.branch,
            warmup: if self.thermal.warmup_time_constant_s > 0.0 {
                (-t_s / self.thermal.warmup_time_constant_s).exp()
            } else {
                0.0
            },
        };
        let nan3 = [f64::NAN; 3];
        let mut status = 0;
        let (gyro, gyro_bias) = match &mut self.gyro {
            Some(sim) => {
                let extra = match &self.g_sensitivity {
                    Some(g) => g * accel_true,
                    None => Vector3::zeros(),
                };
                let (y, b, sat) = sim.step(gyro_true, t_s, &th, &extra);
                if sat {
                    status |= STATUS_GYRO_SATURATED;
                }
                (y, b)
            }
            None => (nan3, nan3),
        };
        let (accel, accel_bias) = match &mut self.accel {
            Some(sim) => {
                let (y, b, sat) = sim.step(accel_true, t_s, &th, &Vector3::zeros());
                if sat {
                    status |= STATUS_ACCEL_SATURATED;
                }
                (y, b)
            }
            None => (nan3, nan3),
        };
        let t_ns = (t_s * 1e9).round() as i64;
        let jitter_ns = if self.jitter_sigma_ns > 0.0 {
            (self.jitter_sigma_ns * self.jitter.normal())
                .clamp(-self.jitter_clip_ns, self.jitter_clip_ns)
                .round() as i64
        } else {
            0
        };
        let dropped = self.drop_probability > 0.0 && self.drops.uniform() < self.drop_probability;
        let counter = if self.counter_modulo == 0 {
            k
        } else {
            k % self.counter_modulo
        };
        let truth = TruthImuRecord {
            t_mono_ns: start_mono_ns + t_ns,
            gyro_bias,
            accel_bias,
            gyro_true: if self.gyro.is_some() {
                (*gyro_true).into()
            } else {
                nan3
            },
            accel_true: if self.accel.is_some() {
                (*accel_true).into()
            } else {
                nan3
            },
        };
        let record = (!dropped).then(|| ImuRecord {
            t_mono_ns: start_mono_ns + t_ns + jitter_ns,
            t_wall_ns: start_wall_ns + t_ns + jitter_ns,
            t_sensor: counter as f64,
            gyro,
            accel,
            temp: if self.thermal.temp_lsb_c > 0.0 {
                (temp_c / self.thermal.temp_lsb_c).round() * self.thermal.temp_lsb_c
            } else {
                temp_c
            },
            status,
        });
        ImuEpoch { record, truth }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quiet() -> ImuSpec {
        ImuSpec::default()
    }

    #[test]
    fn unit_conversions() {
        let g = GyroSpec {
            arw_deg_rth: Some([0.3, 0.3, 0.3]),
            bias_dph: [3600.0 / DEG, 0.0, 0.0],
            ..quiet().gyro
        };
        let si = g.to_si().unwrap();
        // 0.3 °/√h = 0.005 °/√s.
        assert!((si.white_density[0] - 0.005 * DEG).abs() < 1e-15);
        assert!((si.bias[0] - 1.0).abs() < 1e-12);
        let a = AccelSpec {
            vrw_mg_rth: Some([6.0, 0.0, 0.0]),
            noise_density_ug_rthz: None,
            ..quiet().accel
        };
        // 6 mg/√h = 0.1 mg/√s = 100 µg/√Hz.
        let si = a.to_si().unwrap();
        assert!((si.white_density[0] - 100e-6 * G0).abs() < 1e-12);
    }

    #[test]
    fn both_white_forms_is_an_error() {
        let g = GyroSpec {
            arw_deg_rth: Some([0.3; 3]),
            noise_density_dps_rthz: Some([0.005; 3]),
            ..quiet().gyro
        };
        assert!(g.to_si().unwrap_err().contains("either"));
        let mut s = quiet();
        s.timing.drop_probability = 1.5;
        assert!(s.validate().unwrap_err().contains("drop_probability"));
        s.timing.drop_probability = 0.0;
        s.gyro.bias_instability_dph = [1.0; 3];
        s.gyro.bias_instability_band_s = [10.0, 1.0];
        assert!(s.validate().unwrap_err().contains("band"));
    }

    #[test]
    fn deterministic_errors_are_applied() {
        let mut s = quiet();
        s.gyro.bias_dph = [36.0, 0.0, 0.0];
        s.gyro.scale_factor_ppm = [0.0, 1000.0, 0.0];
        s.gyro.misalignment_mrad = [0.0, 0.0, 0.0, 0.0, 2.0, 0.0]; // z senses x
        s.accel.bias_tempco_mg_per_c = [1.0, 0.0, 0.0];
        s.accel.range_g = Some(2.0);
        s.accel.lsb_mg = Some(1.0);
        let both = Channels::ALL;
        let mut sim = ImuSimulator::new(&s, "t", 1, 100.0, both).unwrap();
        let w = Vector3::new(1.0, 2.0, 0.0);
        let f = Vector3::new(0.0, 0.00049, 30.0);
        let e = sim.step(&w, &f, 35.0, 0, 0);
        let r = e.record.unwrap();
        assert!((r.gyro[0] - (1.0 + 36.0 * DEG / 3600.0)).abs() < 1e-12);
        assert!((r.gyro[1] - 2.002).abs() < 1e-12);
        assert!((r.gyro[2] - 0.002).abs() < 1e-12);
        // 10 °C above reference: 10 mg of bias, quantised to 1 mg.
        assert!((r.accel[0] - 10e-3 * G0).abs() < 1e-12);
        assert_eq!(r.accel[1], 0.0, "0.05 mg rounds to 0");
        assert_eq!(r.accel[2], 2.0 * G0, "clipped at 2 g");
        assert_eq!(r.status, STATUS_ACCEL_SATURATED);
        assert!((e.truth.accel_bias[0] - 10e-3 * G0).abs() < 1e-12);
    }

    #[test]
    fn thermal_terms_follow_the_lagging_sensor_temperature() {
        let mut s = quiet();
        s.thermal.time_constant_s = 10.0;
        s.thermal.hysteresis_width_c = 1.0;
        s.thermal.warmup_time_constant_s = 5.0;
        s.thermal.temp_lsb_c = 0.125;
        s.accel.bias_tempco_mg_per_c = [1.0, 0.0, 0.0];
        s.accel.bias_tempco2_mg_per_c2 = [0.01, 0.0, 0.0];
        s.accel.bias_hysteresis_mg = [0.0, 2.0, 0.0];
        s.accel.warmup_bias_mg = [0.0, 0.0, 4.0];
        s.accel.scale_tempco_ppm_per_c = [0.0, 0.0, 100.0];
        s.validate().unwrap();
        let rate = 10.0;
        let mut sim = ImuSimulator::new(&s, "t", 1, rate, Channels::ACCEL).unwrap();
        let z = Vector3::zeros();
        // Power-on at 25 °C (the reference): warm-up bias 4 mg on z, decaying with τ = 5 s.
        let first = sim.step(&z, &z, 25.0, 0, 0);
        assert!((first.truth.accel_bias[2] - 4e-3 * G0).abs() < 1e-12);
        let mut last = first;
        for _ in 0..50 {
            last = sim.step(&z, &z, 25.0, 0, 0);
        }
        // The 51st sample is at t = 5 s: one warm-up time constant.
        let expected = 4e-3 * G0 * (-1.0f64).exp();
        assert!((last.truth.accel_bias[2] - expected).abs() < 1e-9);
        // Chamber steps to 35 °C: after one time constant the sensor is 63 % of the way.
        let mut rising = last;
        for _ in 0..100 {
            rising = sim.step(&z, &z, 35.0, 0, 0);
        }
        let sensor = 25.0 + 10.0 * (1.0 - (-1.0f64).exp());
        let r = rising.record.unwrap();
        assert!((r.temp - sensor).abs() <= 0.0625 + 1e-9, "{}", r.temp);
        assert_eq!((r.temp / 0.125).fract(), 0.0, "reported in 0.125 °C steps");
        let dt = sensor - 25.0;
        let bias_x = (dt + 0.01 * dt * dt) * 1e-3 * G0;
        assert!((rising.truth.accel_bias[0] - bias_x).abs() < 1e-3 * bias_x);
        // Rising: on the upper branch, +1 mg.
        assert!((rising.truth.accel_bias[1] - 1e-3 * G0).abs() < 1e-12);
        // Back down by more than the width: the lower branch, -1 mg.
        let mut falling = rising;
        for _ in 0..200 {
            falling = sim.step(&z, &z, 20.0, 0, 0);
        }
        assert!((falling.truth.accel_bias[1] + 1e-3 * G0).abs() < 1e-12);
        // Scale factor 100 ppm/°C on z with 1 g applied.
        let g = Vector3::new(0.0, 0.0, G0);
        let e = sim.step(&g, &g, 20.0, 0, 0);
        let r = e.record.unwrap();
        let scale = (r.accel[2] - e.truth.accel_bias[2]) / G0 - 1.0;
        let expected = 100e-6 * (r.temp - 25.0);
        assert!(
            (scale - expected).abs() < 100e-6 * 0.07,
            "{scale} vs {expected}"
        );
        let mut no_warm = s.clone();
        no_warm.thermal.warmup_time_constant_s = 0.0;
        assert!(no_warm
            .validate()
            .unwrap_err()
            .contains("warmup_time_constant_s"));
    }

    #[test]
    fn gyro_only_leaves_accel_nan_and_counter_wraps() {
        let mut s = quiet();
        s.timing.counter_modulo = 3;
        let mut sim = ImuSimulator::new(&s, "t", 1, 10.0, Channels::GYRO).unwrap();
        let z = Vector3::zeros();
        let counters: Vec<f64> = (0..5)
            .map(|_| {
                let r = sim.step(&z, &z, 25.0, 1_000, 0).record.unwrap();
                assert!(r.accel.iter().all(|a| a.is_nan()));
                r.t_sensor
            })
            .collect();
        assert_eq!(counters, vec![0.0, 1.0, 2.0, 0.0, 1.0]);
    }

    #[test]
    fn drops_happen_at_the_configured_rate() {
        let mut s = quiet();
        s.timing.drop_probability = 0.1;
        s.timing.jitter_us = 100.0;
        let mut sim = ImuSimulator::new(&s, "t", 9, 100.0, Channels::GYRO).unwrap();
        let z = Vector3::zeros();
        let n = 20_000;
        let mut dropped = 0;
        let mut last = i64::MIN;
        for _ in 0..n {
            match sim.step(&z, &z, 25.0, 0, 0).record {
                None => dropped += 1,
                Some(r) => {
                    assert!(r.t_mono_ns > last, "timestamps increase despite jitter");
                    last = r.t_mono_ns;
                }
            }
        }
        // Binomial: mean 2000, sd 42.
        assert!((dropped as i64 - 2000).abs() < 200, "{dropped}");
    }

    #[test]
    fn one_axis_alone_gives_the_same_values_as_in_the_full_imu() {
        let s = crate::presets::imu_preset("bench-cheap").unwrap();
        let z_only = Channels {
            gyro: [false, false, true],
            accel: [false; 3],
        };
        let mut alone = ImuSimulator::new(&s, "t", 4, 100.0, z_only).unwrap();
        let mut full = ImuSimulator::new(&s, "t", 4, 100.0, Channels::ALL).unwrap();
        let w = Vector3::new(0.1, -0.2, 0.3);
        let f = Vector3::new(0.0, 0.0, -9.8);
        for _ in 0..500 {
            let a = alone.step(&w, &f, 25.0, 0, 0);
            let b = full.step(&w, &f, 25.0, 0, 0);
            let (a, b) = (a.record.unwrap(), b.record.unwrap());
            assert!(a.gyro[0].is_nan() && a.gyro[1].is_nan());
            assert!(a.accel.iter().all(|x| x.is_nan()));
            // g-sensitivity uses the true specific force, so it is the same too.
            assert_eq!(a.gyro[2], b.gyro[2]);
        }
    }
}
