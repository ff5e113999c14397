//! Where the filter's IMU noise model comes from: a simulator preset (the datasheet values in
//! `sim::presets`) or the Allan fit JSON that `imulab allan --json` / `imulab report --json`
//! writes. The same mapping builds the simulator spec of a grade given as an Allan fit, so a
//! study simulates and filters one and the same IMU description.
//!
//! Mapping (per body axis for a preset; for an Allan fit, whose axes are columns of a file, the
//! largest axis of each sensor on all three):
//! - white noise: ARW N (rad/√s) and VRW N (m/s/√s) as they are;
//! - bias instability: a flat Allan floor F (ADEV, = 0.664·B of the fit) becomes a first-order
//!   Gauss-Markov bias whose Allan deviation peaks at the floor where the floor is lowest:
//!   σ = F / 0.6174 and τ_c = τ_min / 1.89 (a GM process's ADEV peaks at 0.6174 σ at
//!   τ ≈ 1.89 τ_c). τ_min is the τ of the Allan minimum (the fit's slope reading, else the
//!   lowest curve point); for a preset, whose floor 0.664·B (B its bias instability, the
//!   same convention as the fit) is flat over a band [τ₁, τ₂], the band's geometric centre
//!   √(τ₁τ₂). A spec built from a fit gets B = F / 0.664 back.
//! - rate random walk K: white noise on the bias (`*_rrw_*`), besides the GM driving noise;
//! - the initial bias σ: √(σ_in-run² + turn-on σ² + constant bias²) for a preset, σ_in-run
//!   the larger of σ_GM and the flicker's spread over the band ([`flicker_band_sigma`],
//!   2.5·F for 1–5000 s); for an Allan fit, the GM σ (an Allan curve says nothing about the
//!   turn-on bias). The filter keeps this σ as its bias state's stationary σ and keeps the
//!   GM's driving noise (`config::bias_state_process`): the turn-on bias and the flicker's
//!   slow part are constants over a drive, which a GM of τ_c ≈ 37 s would forget. The
//!   slow part, √(σ_in-run² − σ_GM²), is kept too (`*_bias_slow`) as a GM whose Allan
//!   deviation peaks at the band's upper end (τ_c = τ₂ / 1.89): with the turn-on bias as
//!   states of its own (`turn_on_states`), the bias state is the GM alone and the turn-on
//!   state holds the rest of the initial σ, forgotten as slowly as the slow part changes.
//! - scale factors (21 states): the preset's scale-factor error as a random constant (100 ppm
//!   when the preset gives none); an Allan fit does not identify them, so they fall back.
//! - gyro g-sensitivity G (a preset's `g_sensitivity_dph_per_g`), which the 15/21-state
//!   filter has no state for: its part from the 1 g of gravity is a constant of unknown sign
//!   on each axis, added to the initial gyro bias σ (G·1 g); its part from the vehicle's own
//!   accelerations varies as the vehicle manoeuvres and drives the gyro bias of each body
//!   axis by that axis's sensitivity to the horizontal (body x, y) inputs times
//!   [`VEHICLE_ACCEL_SIGMA_G`] (`ImuModel::gyro_bias_g_sensitivity_sigma`): with a level
//!   mount, a z gyro sensitive only along z sees the constant 1 g and gets no in-run part.
//!   Without it the consumer preset (0.1 °/s/g) gave NEES 28 on `short_drive` (see
//!   docs/fusion.md).
//! - quantization is not mapped: for the presets it is far below the white noise (consumer
//!   gyro LSB 1/131 °/s: 0.002 °/s per sample against 0.05 °/s of white noise at 100 Hz).
//!
//! Terms an Allan fit did not identify fall back to the base model, each with a warning.

use anyhow::{bail, Context};
use imulab_allan::analysis::AllanReport;
use imulab_allan::fit::{Term, BIAS_INSTABILITY_FACTOR};
use imulab_allan::units::SensorKind;
use imulab_fusion::config::{Axes, GaussMarkov, GnssPositionError, ImuModel};
use imulab_sim::imu_model::{ImuSpec, TriadErrors, G0};
use std::path::Path;

/// Allan deviation peak of a first-order Gauss-Markov process, relative to its σ.
pub const GM_ADEV_PEAK: f64 = 0.6174;
/// τ of that peak, relative to the correlation time.
pub const GM_ADEV_PEAK_TAU: f64 = 1.89;
/// Scale-factor σ assumed when a preset gives none, fraction.
pub const DEFAULT_SCALE_SIGMA: f64 = 1e-4;
/// 1σ of a land vehicle's own specific-force changes (accelerating, braking, turning), in g,
/// assumed for the in-run part of the gyro g-sensitivity bias (`short_drive` peaks at
/// 0.15–0.3 g; the consumer preset's NEES there is 6.3 with it).
pub const VEHICLE_ACCEL_SIGMA_G: f64 = 0.2;

/// A noise model with where it came from and what had to be assumed.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseModel {
    pub model: ImuModel,
    /// Human-readable origin, e.g. `preset tactical` or `Allan fit imu.json (device imu0)`.
    pub origin: String,
    /// Terms that fell back to the base model, and other caveats.
    pub warnings: Vec<String>,
}

fn max3(v: [f64; 3]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// The Gauss-Markov bias whose Allan deviation peaks at `floor` at `tau_min`.
pub fn gauss_markov_from_floor(floor: f64, tau_min: f64) -> GaussMarkov {
    GaussMarkov {
        sigma: floor / GM_ADEV_PEAK,
        tau_s: tau_min / GM_ADEV_PEAK_TAU,
    }
}

/// 1σ of a bias instability whose Allan deviation is flat at `floor` over the band
/// `band_s` of τ: a flicker (1/f) bias, PSD h/f with Allan variance 2·ln 2·h, holds the
/// variance h·ln(τ₂/τ₁) between the band's frequencies, so σ = floor·√(ln(τ₂/τ₁) / (2 ln 2)).
/// For the default band 1–5000 s that is 2.5·floor, against 1.6·floor of the Gauss-Markov
/// process fitted to the Allan peak: the flicker's slow part (periods of minutes to hours)
/// that process leaves out is, over one drive, a nearly constant bias.
pub fn flicker_band_sigma(floor: f64, band_s: [f64; 2]) -> f64 {
    let ratio = band_s[1] / band_s[0];
    if !(floor > 0.0 && ratio.is_finite() && ratio > 1.0) {
        return 0.0;
    }
    floor * (ratio.ln() / (2.0 * std::f64::consts::LN_2)).sqrt()
}

/// The in-run bias of a flat Allan floor over a band, split in two first-order Gauss-Markov
/// processes per body axis: `fast`, the one whose Allan deviation peaks at the floor at the
/// band's geometric centre ([`gauss_markov_from_floor`]), and `slow`, the rest of the
/// flicker's spread over the band ([`flicker_band_sigma`]) as a process whose Allan deviation
/// peaks at the band's upper end: the flicker's periods of minutes to hours, which the fast
/// process leaves out and which over one drive are nearly a constant bias.
struct InRunBias {
    fast: GaussMarkov<Axes>,
    slow: Option<GaussMarkov<Axes>>,
    /// The stationary σ of the two together: the larger of the fast σ and the band's.
    sigma: Axes,
}

fn in_run_bias(t: &TriadErrors) -> InRunBias {
    let band = t.bias_instability_band_s;
    let floor = t.instability_floor.map(f64::abs);
    // No in-run instability on any axis: a random constant (τ = 0 means constant).
    let at = |tau_peak: f64| {
        if floor.iter().any(|f| *f > 0.0) {
            gauss_markov_from_floor(1.0, tau_peak).tau_s
        } else {
            0.0
        }
    };
    let centre = (band[0] * band[1]).sqrt();
    let fast = GaussMarkov {
        sigma: Axes(floor.map(|f| gauss_markov_from_floor(f, centre).sigma)),
        tau_s: at(centre),
    };
    let sigma = Axes(std::array::from_fn(|i| {
        fast.sigma[i].max(flicker_band_sigma(floor[i], band))
    }));
    let slow_sigma = Axes(std::array::from_fn(|i| {
        (sigma[i].powi(2) - fast.sigma[i].powi(2)).max(0.0).sqrt()
    }));
    let slow = (slow_sigma.max() > 0.0).then_some(GaussMarkov {
        sigma: slow_sigma,
        tau_s: at(band[1]),
    });
    InRunBias { fast, slow, sigma }
}

/// Per body axis: the in-run bias, the initial σ (in-run, turn-on and constant bias) and the
/// random walk.
fn triad_bias(t: &TriadErrors) -> (InRunBias, Axes, Axes) {
    let in_run = in_run_bias(t);
    let initial = Axes(std::array::from_fn(|i| {
        (in_run.sigma[i].powi(2) + t.turn_on_sigma[i].powi(2) + t.bias[i].powi(2)).sqrt()
    }));
    (in_run, initial, Axes(t.random_walk.map(f64::abs)))
}

fn scale(t: &TriadErrors) -> GaussMarkov<Axes> {
    GaussMarkov {
        sigma: Axes(t.scale_factor.map(|s| {
            if s != 0.0 {
                s.abs()
            } else {
                DEFAULT_SCALE_SIGMA
            }
        })),
        tau_s: 0.0,
    }
}

/// The filter's IMU model for a simulator spec (datasheet values: what a user would know).
pub fn model_from_spec(spec: &ImuSpec, origin: &str) -> anyhow::Result<NoiseModel> {
    let gyro = spec
        .gyro
        .to_si()
        .map_err(|e| anyhow::anyhow!("{origin}: gyro: {e}"))?;
    let accel = spec
        .accel
        .to_si()
        .map_err(|e| anyhow::anyhow!("{origin}: accel: {e}"))?;
    let (gyro_in_run, mut gyro_b0, gyro_rrw) = triad_bias(&gyro);
    let (accel_in_run, accel_b0, accel_rrw) = triad_bias(&accel);
    let mut gyro_bias = gyro_in_run.fast;
    let mut gyro_bias_g_sensitivity_sigma = [0.0; 3];
    if let Some(g) = spec.gyro.g_sensitivity_si() {
        // The bias each axis gets per m/s² of specific force in any direction, at 1 g.
        gyro_b0 = Axes(std::array::from_fn(|i| {
            gyro_b0[i].hypot(g.row(i).norm() * G0)
        }));
        // The vehicle's own specific-force changes are horizontal (body x and y of a level
        // mount): each axis's in-run part is its sensitivity to those two inputs.
        for (axis, sigma) in gyro_bias_g_sensitivity_sigma.iter_mut().enumerate() {
            let horizontal = g[(axis, 0)].hypot(g[(axis, 1)]);
            *sigma = horizontal * VEHICLE_ACCEL_SIGMA_G * G0;
        }
        if !(gyro_bias.tau_s.is_finite() && gyro_bias.tau_s > 0.0) {
            // A random constant cannot follow the manoeuvres: give it the flat band's τ.
            let band = gyro.bias_instability_band_s;
            gyro_bias.tau_s = (band[0] * band[1]).sqrt() / GM_ADEV_PEAK_TAU;
        }
    }
    let mut warnings = Vec::new();
    if max3(gyro.ramp) > 0.0 || max3(accel.ramp) > 0.0 {
        warnings.push(format!("{origin}: rate ramp is not modelled by the filter"));
    }
    if max3(gyro.bias_tempco) > 0.0 || max3(accel.bias_tempco) > 0.0 {
        warnings.push(format!(
            "{origin}: bias temperature coefficients are not modelled by the filter"
        ));
    }
    Ok(NoiseModel {
        model: ImuModel {
            arw_rad_per_sqrt_s: Axes(gyro.white_density.map(f64::abs)),
            vrw_mps_per_sqrt_s: Axes(accel.white_density.map(f64::abs)),
            gyro_bias,
            accel_bias: accel_in_run.fast,
            gyro_scale: scale(&gyro),
            accel_scale: scale(&accel),
            gyro_bias_initial_sigma: Some(gyro_b0),
            accel_bias_initial_sigma: Some(accel_b0),
            gyro_bias_slow: gyro_in_run.slow,
            accel_bias_slow: accel_in_run.slow,
            gyro_rrw_rad_per_s_sqrt_s: gyro_rrw,
            accel_rrw_mps2_per_sqrt_s: accel_rrw,
            gyro_bias_g_sensitivity_sigma,
        },
        origin: origin.to_string(),
        warnings,
    })
}

/// The filter's model of a receiver's correlated position error for a simulator GNSS spec:
/// the spec's Gauss-Markov position error (σ horizontal per axis, vertical, τ) as it is.
/// None when the spec has none (white position noise only).
pub fn gnss_error_from_spec(spec: &imulab_sim::gnss_model::GnssSpec) -> Option<GnssPositionError> {
    let e = GnssPositionError {
        horizontal_m: spec.horizontal_gm_m,
        vertical_m: spec.vertical_gm_m,
        tau_s: spec.position_gm_tau_s,
    };
    (e.enabled() && e.tau_s.is_finite() && e.tau_s > 0.0).then_some(e)
}

/// The simulator's GNSS preset whose receiver error stands for fixes of class `fix`: RTK fixed
/// → `rtk`; DGNSS/SBAS and RTK float → `sbas`; any other position fix (2-D, 3-D, dead
/// reckoning) → `standalone`. None for epochs without a position.
pub fn gnss_preset_for_fix(fix: imulab_drivers::types::FixType) -> Option<&'static str> {
    use imulab_drivers::types::FixType;
    match fix {
        FixType::NoFix | FixType::TimeOnly => None,
        FixType::RtkFixed => Some("rtk"),
        FixType::Dgnss | FixType::RtkFloat => Some("sbas"),
        FixType::DeadReckoning | FixType::Fix2D | FixType::Fix3D | FixType::GnssDeadReckoning => {
            Some("standalone")
        }
    }
}

/// The receiver's correlated position error assumed for fixes of class `fix`: that of the
/// GNSS preset of its class ([`gnss_preset_for_fix`]; standalone: σ 2 m per horizontal axis,
/// 3.5 m vertical, τ 600 s).
pub fn gnss_error_for_fix(fix: imulab_drivers::types::FixType) -> Option<GnssPositionError> {
    let preset = gnss_preset_for_fix(fix)?;
    gnss_error_from_spec(&imulab_sim::gnss_model::GnssSpec::preset(preset)?)
}

/// The filter's IMU model for simulator preset `name`.
pub fn model_from_preset(name: &str) -> anyhow::Result<NoiseModel> {
    let spec = imulab_sim::presets::imu_preset(name).with_context(|| {
        format!(
            "unknown IMU preset `{name}` (known: {})",
            imulab_sim::presets::imu_preset_names().join(", ")
        )
    })?;
    model_from_spec(&spec, &format!("preset {name}"))
}

/// The noise terms of one sensor (gyro or accel) read from an Allan fit, SI base units;
/// None = not identified on any axis.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FittedTerms {
    /// N: rad/√s or m/s/√s.
    pub white: Option<f64>,
    /// Allan floor 0.664·B: rad/s or m/s².
    pub floor: Option<f64>,
    /// τ of the Allan minimum, s.
    pub tau_min: Option<f64>,
    /// K: rad/s/√s or m/s²/√s.
    pub random_walk: Option<f64>,
    /// Axes of this sensor found.
    pub axes: usize,
}

/// One device's fitted terms, gyro and accel, from an Allan report.
#[derive(Debug, Clone, PartialEq)]
pub struct AllanDevice {
    pub device: String,
    pub gyro: FittedTerms,
    pub accel: FittedTerms,
    pub warnings: Vec<String>,
}

fn bigger(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(x), Some(y)) => Some(x.max(y)),
        (x, None) => x,
        (None, y) => y,
    }
}

/// Reads the terms of `device` (or of the only device) from an Allan report.
pub fn allan_device(
    report: &AllanReport,
    device: Option<&str>,
    origin: &str,
) -> anyhow::Result<AllanDevice> {
    let mut devices: Vec<&str> = report.axes.iter().map(|a| a.device.as_str()).collect();
    devices.dedup();
    let name = match device {
        Some(d) if devices.contains(&d) => d.to_string(),
        Some(d) => bail!("{origin}: no device `{d}` (have: {})", devices.join(", ")),
        None => match devices.as_slice() {
            [one] => one.to_string(),
            [] => bail!("{origin}: no axes in the Allan report"),
            many => bail!(
                "{origin}: several devices ({}); name one as FILE.json#DEVICE",
                many.join(", ")
            ),
        },
    };
    let mut out = AllanDevice {
        device: name.clone(),
        gyro: FittedTerms::default(),
        accel: FittedTerms::default(),
        warnings: Vec::new(),
    };
    for axis in report.axes.iter().filter(|a| a.device == name) {
        let Some(sensor) = axis.sensor.or(axis.unit.sensor()) else {
            out.warnings.push(format!(
                "{origin}: axis {} has no known sensor or unit, skipped",
                axis.axis
            ));
            continue;
        };
        let si = axis.unit.to_si();
        let terms = match sensor {
            SensorKind::Gyro => &mut out.gyro,
            SensorKind::Accel => &mut out.accel,
        };
        terms.axes += 1;
        let Some(fit) = &axis.fit else {
            out.warnings.push(format!(
                "{origin}: axis {} has no noise fit{}",
                axis.axis,
                axis.fit_error
                    .as_deref()
                    .map(|e| format!(" ({e})"))
                    .unwrap_or_default()
            ));
            continue;
        };
        let value = |t: Term| {
            fit.get(t)
                .and_then(|e| e.value)
                .filter(|v| v.is_finite() && *v >= 0.0)
                .map(|v| v * si)
        };
        terms.white = bigger(terms.white, value(Term::RandomWalk));
        terms.floor = bigger(
            terms.floor,
            value(Term::BiasInstability).map(|b| b * BIAS_INSTABILITY_FACTOR),
        );
        terms.random_walk = bigger(terms.random_walk, value(Term::RateRandomWalk));
        let tau_min = axis
            .slopes
            .as_ref()
            .and_then(|s| s.bias_instability_tau)
            .or_else(|| {
                axis.curve
                    .points
                    .iter()
                    .filter(|p| p.deviation.is_finite() && p.deviation > 0.0)
                    .min_by(|a, b| a.deviation.total_cmp(&b.deviation))
                    .map(|p| p.tau)
            })
            .filter(|t| t.is_finite() && *t > 0.0);
        terms.tau_min = bigger(terms.tau_min, tau_min);
    }
    Ok(out)
}

/// Reads an Allan report JSON file (`imulab allan --json` / `imulab report --json`).
pub fn read_allan_report(path: &Path) -> anyhow::Result<AllanReport> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let report: AllanReport = serde_json::from_str(&text).with_context(|| {
        format!(
            "{}: not an Allan report (the JSON `imulab allan --json` writes)",
            path.display()
        )
    })?;
    if report.schema_version != imulab_allan::analysis::SCHEMA_VERSION {
        bail!(
            "{}: Allan report schema_version {} (this build reads {})",
            path.display(),
            report.schema_version,
            imulab_allan::analysis::SCHEMA_VERSION
        );
    }
    Ok(report)
}

/// Splits `FILE.json#DEVICE` into the path and the device.
pub fn split_device(arg: &str) -> (&str, Option<&str>) {
    match arg.rsplit_once('#') {
        Some((p, d)) if !d.is_empty() => (p, Some(d)),
        _ => (arg, None),
    }
}

/// The filter's IMU model from an Allan fit: identified terms replace those of `base`, the
/// others stay with a warning each.
pub fn model_from_allan(fit: &AllanDevice, base: &ImuModel, origin: &str) -> NoiseModel {
    let mut m = *base;
    let mut warnings = fit.warnings.clone();
    let mut missing = |what: &str| {
        warnings.push(format!(
            "{origin}: {what} not identified by the Allan fit; kept the base value"
        ))
    };
    for (sensor, terms) in [("gyro", &fit.gyro), ("accel", &fit.accel)] {
        let gyro = sensor == "gyro";
        if terms.axes == 0 {
            missing(&format!("{sensor} (no {sensor} axes)"));
            continue;
        }
        match terms.white {
            Some(n) if gyro => m.arw_rad_per_sqrt_s = Axes::all(n),
            Some(n) => m.vrw_mps_per_sqrt_s = Axes::all(n),
            None => missing(&format!("{sensor} white noise (ARW/VRW)")),
        }
        match (terms.floor, terms.tau_min) {
            (Some(floor), Some(tau)) => {
                let one = gauss_markov_from_floor(floor, tau);
                let gm = GaussMarkov {
                    sigma: Axes::all(one.sigma),
                    tau_s: one.tau_s,
                };
                if gyro {
                    m.gyro_bias = gm;
                    m.gyro_bias_initial_sigma = None;
                } else {
                    m.accel_bias = gm;
                    m.accel_bias_initial_sigma = None;
                }
            }
            _ => missing(&format!("{sensor} bias instability")),
        }
        match terms.random_walk {
            Some(k) if gyro => m.gyro_rrw_rad_per_s_sqrt_s = Axes::all(k),
            Some(k) => m.accel_rrw_mps2_per_sqrt_s = Axes::all(k),
            None => {} // Not identified usually means below what the record shows: keep base.
        }
    }
    NoiseModel {
        model: m,
        origin: format!("{origin} (device {})", fit.device),
        warnings,
    }
}

/// Reads `--noise FILE.json[#DEVICE]` into a model over `base`.
pub fn model_from_allan_file(arg: &str, base: &ImuModel) -> anyhow::Result<NoiseModel> {
    let (path, device) = split_device(arg);
    let report = read_allan_report(Path::new(path))?;
    let fit = allan_device(&report, device, path)?;
    Ok(model_from_allan(&fit, base, &format!("Allan fit {path}")))
}

/// A simulator spec reproducing an Allan fit (for a study grade given as a fit): white
/// noise densities, the bias-instability floor over [τ_min/30, τ_min·30] and the random
/// walks. Unidentified terms are left out (zero), with the fit's warnings.
pub fn spec_from_allan(fit: &AllanDevice) -> anyhow::Result<ImuSpec> {
    let mut spec = ImuSpec::default();
    let deg = 1f64.to_degrees();
    let g = &fit.gyro;
    let a = &fit.accel;
    if g.white.is_none() && a.white.is_none() {
        bail!(
            "device {}: the Allan fit identifies no white noise on gyro or accel",
            fit.device
        );
    }
    spec.gyro.noise_density_dps_rthz = Some([g.white.unwrap_or(0.0) * deg; 3]);
    spec.accel.noise_density_ug_rthz = Some([a.white.unwrap_or(0.0) / (G0 * 1e-6); 3]);
    // The spec's bias instability is B (its simulated floor is 0.664·B): floor / 0.664.
    if let (Some(f), Some(t)) = (g.floor, g.tau_min) {
        spec.gyro.bias_instability_dph = [f / BIAS_INSTABILITY_FACTOR * deg * 3600.0; 3];
        spec.gyro.bias_instability_band_s = [(t / 30.0).max(1e-3), t * 30.0];
    }
    if let (Some(f), Some(t)) = (a.floor, a.tau_min) {
        spec.accel.bias_instability_mg = [f / BIAS_INSTABILITY_FACTOR / (G0 * 1e-3); 3];
        spec.accel.bias_instability_band_s = [(t / 30.0).max(1e-3), t * 30.0];
    }
    if let Some(k) = g.random_walk {
        spec.gyro.rrw_dph_rth = [k * deg * 3600.0 * 60.0; 3];
    }
    if let Some(k) = a.random_walk {
        spec.accel.rrw_mg_rth = [k * 60.0 / (G0 * 1e-3); 3];
    }
    spec.validate()
        .map_err(|e| anyhow::anyhow!("device {}: {e}", fit.device))?;
    Ok(spec)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn receiver_error_follows_the_fix_class() {
        use imulab_drivers::types::FixType;
        assert_eq!(gnss_preset_for_fix(FixType::NoFix), None);
        assert_eq!(gnss_preset_for_fix(FixType::Fix3D), Some("standalone"));
        assert_eq!(gnss_preset_for_fix(FixType::RtkFloat), Some("sbas"));
        let rtk = gnss_error_for_fix(FixType::RtkFixed).expect("rtk");
        assert_eq!(
            (rtk.horizontal_m, rtk.vertical_m, rtk.tau_s),
            (0.005, 0.008, 60.0)
        );
        let standalone = gnss_error_for_fix(FixType::Fix2D).expect("standalone");
        assert_eq!(
            (
                standalone.horizontal_m,
                standalone.vertical_m,
                standalone.tau_s
            ),
            (2.0, 3.5, 600.0)
        );
    }

    #[test]
    fn preset_mapping_uses_datasheet_values() {
        let m = model_from_preset("tactical").expect("preset").model;
        // ARW 0.15 °/√h = 0.15° / 60 per √s.
        assert!((m.arw_rad_per_sqrt_s[0] - 0.15f64.to_radians() / 60.0).abs() < 1e-12);
        // Gyro bias instability: the datasheet's Allan minimum 0.5 °/h is the floor (the
        // preset holds B = 0.5 / 0.664) → GM σ = floor / 0.6174, τ_c = √(1·5000) / 1.89.
        let floor = 0.5f64.to_radians() / 3600.0;
        assert!((m.gyro_bias.sigma[2] - floor / GM_ADEV_PEAK).abs() < 1e-12);
        assert!((m.gyro_bias.tau_s - 5000f64.sqrt() / GM_ADEV_PEAK_TAU).abs() < 1e-9);
        assert!(model_from_preset("nope").is_err());
        // The consumer preset's turn-on bias dominates its initial σ.
        let c = model_from_preset("consumer").expect("preset").model;
        assert!(c.gyro_bias_sigma0(0) > 10.0 * c.gyro_bias.sigma[0]);
        // Its g-sensitivity, 0.1 °/s/g on each axis's own input, is in the model: in-run
        // 0.1 °/s · 0.2 on x and y (horizontal inputs), none on z (its input is the constant
        // 1 g); initial σ = √(floor σ² + turn-on² + (0.1 °/s · 1)²).
        let floor_sigma = BIAS_INSTABILITY_FACTOR * 10f64.to_radians() / 3600.0 / GM_ADEV_PEAK;
        let dynamic = 0.1f64.to_radians() * VEHICLE_ACCEL_SIGMA_G;
        assert!((c.gyro_bias.sigma[0] - floor_sigma).abs() < 1e-12);
        let per_axis = c.gyro_bias_g_sensitivity_sigma;
        assert!((per_axis[0] - dynamic).abs() < 1e-12 && (per_axis[1] - dynamic).abs() < 1e-12);
        assert_eq!(per_axis[2], 0.0);
        assert!(c.gyro_bias_state(0).driving_psd() > 10.0 * c.gyro_bias_state(2).driving_psd());
        let band_sigma = flicker_band_sigma(floor_sigma * GM_ADEV_PEAK, [1.0, 5000.0]);
        let initial =
            (band_sigma.powi(2) + (20f64 / 3.0).to_radians().powi(2) + 0.1f64.to_radians().powi(2))
                .sqrt();
        assert!(
            (c.gyro_bias_sigma0(0) - initial).abs() < 1e-9,
            "{} vs {initial}",
            c.gyro_bias_sigma0(0)
        );
        // Presets without g-sensitivity keep the floor's σ on every axis.
        assert!((m.gyro_bias.sigma[2] - floor / GM_ADEV_PEAK).abs() < 1e-12);
        assert_eq!(m.gyro_bias_g_sensitivity_sigma, [0.0; 3]);
        // The initial σ holds the flicker's spread over the band and the turn-on bias.
        let band = floor * (5000f64.ln() / (2.0 * std::f64::consts::LN_2)).sqrt();
        assert!((band / floor - 2.48).abs() < 0.01, "{}", band / floor);
        let turn_on = 4f64.to_radians() / 3600.0;
        assert!((m.gyro_bias_sigma0(1) - band.hypot(turn_on)).abs() < 1e-12);
        // The band's spread beyond the Allan-peak GM is the slow part, a GM whose Allan
        // deviation peaks at the band's upper end (5000 s).
        let slow = m.gyro_bias_slow.expect("slow part");
        let fast = floor / GM_ADEV_PEAK;
        assert!((slow.sigma[0].hypot(fast) - band).abs() < 1e-15);
        assert!((slow.tau_s - 5000.0 / GM_ADEV_PEAK_TAU).abs() < 1e-9);
        // With turn-on states the bias state is the fast GM and the turn-on state holds the
        // rest, forgotten at the slow part's driving noise.
        assert_eq!(m.gyro_in_run_state(0), m.gyro_bias.axis(0));
        let on = m.gyro_turn_on_state(0);
        let rest = (band.powi(2) + turn_on.powi(2) - fast.powi(2)).sqrt();
        assert!((on.sigma - rest).abs() < 1e-9 * rest);
        assert!((on.driving_psd() / slow.axis(0).driving_psd() - 1.0).abs() < 1e-12);
        // Without a turn-on bias the initial σ is the band's, above the Allan-peak GM's.
        let i = model_from_preset("industrial").expect("preset").model;
        let floor = BIAS_INSTABILITY_FACTOR * 10f64.to_radians() / 3600.0;
        assert!((i.gyro_bias_sigma0(2) - flicker_band_sigma(floor, [1.0, 5000.0])).abs() < 1e-15);
        assert!(i.gyro_bias_sigma0(2) > 1.5 * i.gyro_bias.sigma[2]);
        assert_eq!(flicker_band_sigma(floor, [10.0, 10.0]), 0.0);
        assert_eq!(flicker_band_sigma(0.0, [1.0, 10.0]), 0.0);
        // Axes that differ keep their own figures: bench-cheap's accelerometer instability
        // is 0.029 / 0.074 / 0.043 mg and its VRW 6.6 / 7.9 / 8.5 mg/√h on x / y / z.
        let b = model_from_preset("bench-cheap").expect("preset").model;
        let s = b.accel_bias.sigma;
        assert!(
            (s[1] / s[0] - 0.074 / 0.029).abs() < 1e-9
                && (s[2] / s[0] - 0.043 / 0.029).abs() < 1e-9
        );
        let v = b.vrw_mps_per_sqrt_s;
        assert!((v[2] / v[0] - 8.5 / 6.6).abs() < 1e-9, "{v:?}");
        assert!(b.accel_bias_sigma0(0) < b.accel_bias_sigma0(1));
    }

    #[test]
    fn device_selector_splits() {
        assert_eq!(split_device("a/b.json#imu0"), ("a/b.json", Some("imu0")));
        assert_eq!(split_device("a/b.json"), ("a/b.json", None));
    }
}
