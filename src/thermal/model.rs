//! The thermal compensation model: a versioned JSON document of bias-against-temperature
//! polynomials per device and axis with their valid temperature range (format in
//! docs/thermal.md), and [`AxisModel::compensate`], the one place it is applied (`allan
//! --compensate` and `report --compensate` call it through [`ThermalModel::compensate_series`],
//! `export --compensate` and `replay --compensate` through [`ImuCompensator`] block by block).
//!
//! Compensation removes the change of bias with temperature, bias(T) − bias(reference_c)
//! ([`AxisModel::thermal_bias_at`]), and keeps the constant term: fitted on a static bench
//! run it holds gravity and the Earth's rate, which exported rates and a navigation filter
//! must keep, and an Allan deviation does not change with a constant. Every command applies
//! this one rule, so an Allan curve and a replay see the same corrected samples.
//!
//! Outside the valid range the correction is held at its value at the nearest end of the
//! range, never extrapolated, and the samples so treated are counted for a warning.

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// `format` of the document.
pub const MODEL_FORMAT: &str = "imulab-thermal-model";
/// Version of the document layout; readers refuse others.
pub const MODEL_VERSION: u32 = 1;

/// The whole model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalModel {
    pub format: String,
    pub version: u32,
    pub generator: String,
    /// What the model was fitted on.
    pub source: String,
    /// Which temperature the polynomials take: the sensor's own (the `temp` column).
    pub temperature: String,
    pub devices: Vec<DeviceModel>,
}

/// One device's axes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceModel {
    pub device: String,
    pub axes: Vec<AxisModel>,
}

/// bias(T) = Σ coefficients[k] · (T − reference_c)^k, in `unit` (rad/s or m/s^2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisModel {
    /// Channel name, e.g. `gyro_x`.
    pub axis: String,
    pub unit: String,
    pub reference_c: f64,
    pub valid_range_c: [f64; 2],
    pub coefficients: Vec<f64>,
    /// 95 % half-widths of the coefficients.
    pub ci95: Vec<f64>,
}

/// What one compensation did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Compensation {
    pub samples: u64,
    /// Samples below / above the valid range (corrected with the value at the range end).
    pub below_range: u64,
    pub above_range: u64,
    /// Samples without a valid temperature (left uncorrected).
    pub no_temperature: u64,
}

impl Compensation {
    /// The warning a user must see, if any.
    pub fn warning(&self, device: &str, axis: &str, range: [f64; 2]) -> Option<String> {
        let outside = self.below_range + self.above_range;
        if outside == 0 && self.no_temperature == 0 {
            return None;
        }
        Some(format!(
            "{device} {axis}: thermal model valid for {:.1} to {:.1} °C; {} of {} samples below and {} above it were corrected with the value at the range end (not extrapolated){}",
            range[0],
            range[1],
            self.below_range,
            self.samples,
            self.above_range,
            if self.no_temperature > 0 {
                format!(", {} without a temperature were left uncorrected", self.no_temperature)
            } else {
                String::new()
            }
        ))
    }
}

impl AxisModel {
    /// The modelled bias at `t_c` (held at the range ends), in `unit`.
    pub fn bias_at(&self, t_c: f64) -> f64 {
        let t = t_c.clamp(self.valid_range_c[0], self.valid_range_c[1]);
        let u = t - self.reference_c;
        self.coefficients
            .iter()
            .rev()
            .fold(0.0, |acc, c| acc * u + c)
    }

    /// The change of the modelled bias from `reference_c` to `t_c` (held at the range ends),
    /// bias(T) − bias(reference_c), in `unit`: what compensation removes.
    pub fn thermal_bias_at(&self, t_c: f64) -> f64 {
        self.bias_at(t_c) - self.coefficients.first().copied().unwrap_or(0.0)
    }

    /// Subtracts the thermal change of bias ([`Self::thermal_bias_at`]) from `rate` (in the
    /// model's unit × `scale`, i.e. rate values are in a unit whose SI factor is 1/`scale`),
    /// sample by sample.
    pub fn compensate(&self, rate: &mut [f64], temperature: &[f32], scale: f64) -> Compensation {
        let mut c = Compensation {
            samples: rate.len() as u64,
            ..Compensation::default()
        };
        for (r, &t) in rate.iter_mut().zip(temperature) {
            let t = f64::from(t);
            if !t.is_finite() {
                c.no_temperature += 1;
                continue;
            }
            if t < self.valid_range_c[0] {
                c.below_range += 1;
            } else if t > self.valid_range_c[1] {
                c.above_range += 1;
            }
            *r -= self.thermal_bias_at(t) * scale;
        }
        c.no_temperature += rate.len().saturating_sub(temperature.len()) as u64;
        c
    }
}

impl ThermalModel {
    /// Reads and checks a model file; the error names the file and what is wrong.
    pub fn load(path: &Path) -> Result<ThermalModel> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read thermal model {}", path.display()))?;
        let model: ThermalModel = serde_json::from_str(&text)
            .with_context(|| format!("thermal model {}", path.display()))?;
        model
            .validate()
            .with_context(|| format!("thermal model {}", path.display()))?;
        Ok(model)
    }

    /// Checks format, version and every axis.
    pub fn validate(&self) -> Result<()> {
        if self.format != MODEL_FORMAT {
            bail!("format is {:?}, expected {MODEL_FORMAT:?}", self.format);
        }
        if self.version != MODEL_VERSION {
            bail!(
                "version {} is not known to this imulab (it reads version {MODEL_VERSION})",
                self.version
            );
        }
        for d in &self.devices {
            for a in &d.axes {
                let at = format!("device {} axis {}", d.device, a.axis);
                if a.coefficients.is_empty() || a.coefficients.iter().any(|c| !c.is_finite()) {
                    bail!("{at}: coefficients must be one or more finite numbers");
                }
                let [lo, hi] = a.valid_range_c;
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    bail!(
                        "{at}: valid_range_c must be [low, high] with low < high, got [{lo}, {hi}]"
                    );
                }
                if !a.reference_c.is_finite() {
                    bail!("{at}: reference_c must be finite");
                }
                if !matches!(a.unit.as_str(), "rad/s" | "m/s^2") {
                    bail!("{at}: unit must be rad/s or m/s^2, got {:?}", a.unit);
                }
            }
        }
        Ok(())
    }

    /// The model of `device`'s `axis`, if it has one.
    pub fn axis(&self, device: &str, axis: &str) -> Option<&AxisModel> {
        self.devices
            .iter()
            .find(|d| d.device == device)?
            .axes
            .iter()
            .find(|a| a.axis == axis)
    }

    /// Compensates one axis of `device` whose samples are in a unit of SI factor `to_si`
    /// (1 for rad/s and m/s²). Errors when the model has no such axis; returns the counts
    /// and the warning to show.
    pub fn compensate_axis(
        &self,
        device: &str,
        axis: &str,
        rate: &mut [f64],
        temperature: &[f32],
        to_si: f64,
    ) -> Result<(Compensation, Option<String>)> {
        let Some(m) = self.axis(device, axis) else {
            let known: Vec<String> = self
                .devices
                .iter()
                .flat_map(|d| {
                    d.axes
                        .iter()
                        .map(move |a| format!("{} {}", d.device, a.axis))
                })
                .collect();
            bail!(
                "the thermal model has no axis `{axis}` of device `{device}` (it has: {})",
                known.join(", ")
            );
        };
        let c = m.compensate(rate, temperature, 1.0 / to_si);
        Ok((c, c.warning(device, axis, m.valid_range_c)))
    }

    /// Compensates a series read with its temperature (segments in order, the temperature
    /// aligned with their concatenation), its samples in a unit of SI factor `to_si`.
    pub fn compensate_series(
        &self,
        device: &str,
        series: &mut imulab_allan::input::AxisSeries,
        to_si: f64,
    ) -> Result<(Compensation, Option<String>)> {
        let Some(temperature) = series.temperature.as_deref() else {
            bail!(
                "{device} {}: --compensate needs the temperature channel (give --temperature-column)",
                series.name
            );
        };
        let mut total = Compensation::default();
        let mut offset = 0;
        for segment in &mut series.segments {
            let end = (offset + segment.len()).min(temperature.len());
            let (c, _) = self.compensate_axis(
                device,
                &series.name,
                segment,
                &temperature[offset.min(end)..end],
                to_si,
            )?;
            offset += segment.len();
            total.samples += c.samples;
            total.below_range += c.below_range;
            total.above_range += c.above_range;
            total.no_temperature += c.no_temperature;
        }
        let range = self
            .axis(device, &series.name)
            .map_or([f64::NAN; 2], |m| m.valid_range_c);
        Ok((total, total.warning(device, &series.name, range)))
    }
}

/// Errors unless IMU `device` of `session` logged its temperature (some finite `temp`):
/// compensation needs the sensor's own temperature per sample.
pub fn require_session_temperature(session: &imulab_store::Session, device: &str) -> Result<()> {
    for block in session.imu_blocks(device, imulab_store::TimeRange::all(), 65_536)? {
        if block?.temp.iter().any(|t| t.is_finite()) {
            return Ok(());
        }
    }
    bail!(
        "{}: IMU `{device}` has no temperature (its `temp` column is empty or all NaN); --compensate needs the sensor's own temperature per sample",
        session.dir().display()
    )
}

/// The six IMU channels of a session block, in the order of `gyro` then `accel`.
pub const IMU_AXES: [&str; 6] = [
    "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z",
];

/// One session IMU's model axes, applied block by block to streamed rows (`export
/// --compensate`, `replay --compensate`) with [`AxisModel::compensate`]; counts accumulate
/// over the blocks for the warning.
#[derive(Debug, Clone)]
pub struct ImuCompensator {
    device: String,
    /// Per channel of [`IMU_AXES`]: its model and what was done so far.
    axes: Vec<Option<(AxisModel, Compensation)>>,
}

impl ImuCompensator {
    /// The channels of [`IMU_AXES`] the model has for `device`; errors when the model has no
    /// such device or names an axis a session IMU does not have.
    pub fn new(model: &ThermalModel, device: &str) -> Result<ImuCompensator> {
        let Some(d) = model.devices.iter().find(|d| d.device == device) else {
            let names: Vec<&str> = model.devices.iter().map(|d| d.device.as_str()).collect();
            bail!(
                "the thermal model has no device `{device}` (it has: {}); fit one on this device with `imulab thermal --model`",
                names.join(", ")
            );
        };
        if let Some(a) = d.axes.iter().find(|a| !IMU_AXES.contains(&a.axis.as_str())) {
            bail!(
                "the thermal model's device `{device}` has an axis `{}`; a session IMU has {}",
                a.axis,
                IMU_AXES.join(", ")
            );
        }
        let axes = IMU_AXES
            .iter()
            .map(|name| {
                d.axes
                    .iter()
                    .find(|a| a.axis == *name)
                    .map(|a| (a.clone(), Compensation::default()))
            })
            .collect();
        Ok(ImuCompensator {
            device: device.to_string(),
            axes,
        })
    }

    /// The channels the model corrects.
    pub fn axes(&self) -> Vec<&str> {
        IMU_AXES
            .iter()
            .zip(&self.axes)
            .filter(|(_, a)| a.is_some())
            .map(|(n, _)| *n)
            .collect()
    }

    /// Subtracts the thermal change of bias (SI units: rad/s, m/s²) from one block's rows.
    pub fn compensate_block(
        &mut self,
        gyro: &mut [[f64; 3]],
        accel: &mut [[f64; 3]],
        temp: &[f64],
    ) {
        let temperature: Vec<f32> = temp.iter().map(|&t| t as f32).collect();
        let mut column = Vec::with_capacity(temp.len());
        for (k, axis) in self.axes.iter_mut().enumerate() {
            let Some((model, total)) = axis else { continue };
            let rows: &mut [[f64; 3]] = if k < 3 { gyro } else { accel };
            column.clear();
            column.extend(rows.iter().map(|r| r[k % 3]));
            let c = model.compensate(&mut column, &temperature, 1.0);
            for (r, v) in rows.iter_mut().zip(&column) {
                r[k % 3] = *v;
            }
            total.samples += c.samples;
            total.below_range += c.below_range;
            total.above_range += c.above_range;
            total.no_temperature += c.no_temperature;
        }
    }

    /// The warnings to show after the last block, one per channel that needs one.
    pub fn warnings(&self) -> Vec<String> {
        IMU_AXES
            .iter()
            .zip(&self.axes)
            .filter_map(|(name, a)| {
                let (m, c) = a.as_ref()?;
                c.warning(&self.device, name, m.valid_range_c)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> ThermalModel {
        ThermalModel {
            format: MODEL_FORMAT.into(),
            version: MODEL_VERSION,
            generator: "test".into(),
            source: "test".into(),
            temperature: "sensor".into(),
            devices: vec![DeviceModel {
                device: "imu".into(),
                axes: vec![AxisModel {
                    axis: "accel_x".into(),
                    unit: "m/s^2".into(),
                    reference_c: 25.0,
                    valid_range_c: [0.0, 50.0],
                    coefficients: vec![0.1, 0.01, 0.001],
                    ci95: vec![0.0; 3],
                }],
            }],
        }
    }

    #[test]
    fn removes_the_bias_and_holds_outside_the_range() {
        let m = model();
        let mut rate = vec![1.0, 1.0, 1.0, 1.0];
        let temps = [25.0f32, 35.0, 80.0, f32::NAN];
        let (c, warning) = m
            .compensate_axis("imu", "accel_x", &mut rate, &temps, 1.0)
            .unwrap();
        // The constant term stays: at the reference nothing changes.
        assert_eq!(rate[0], 1.0);
        assert!((rate[1] - (1.0 - 0.1 - 0.1)).abs() < 1e-12);
        // 80 °C is held at 50 °C: 0.25 + 0.625.
        assert!((rate[2] - (1.0 - 0.875)).abs() < 1e-12);
        assert_eq!(rate[3], 1.0);
        assert_eq!((c.above_range, c.below_range, c.no_temperature), (1, 0, 1));
        let w = warning.unwrap();
        assert!(
            w.contains("0.0 to 50.0 °C") && w.contains("not extrapolated"),
            "{w}"
        );
        // In mg (SI factor 9.80665e-3) the correction is scaled.
        let mut mg = vec![0.0];
        m.compensate_axis("imu", "accel_x", &mut mg, &[35.0], 9.806_65e-3)
            .unwrap();
        assert!((mg[0] + 0.2 / 9.806_65e-3).abs() < 1e-9);
        let e = m
            .compensate_axis("imu", "gyro_x", &mut mg, &[25.0], 1.0)
            .unwrap_err();
        assert!(e.to_string().contains("imu accel_x"), "{e}");
    }

    #[test]
    fn allan_and_export_remove_the_same_correction() {
        // The same samples through the Allan path (a series) and the export/replay path
        // (session rows, block by block) come out identical.
        let m = model();
        let temps: Vec<f32> = (0..200).map(|i| -5.0 + 0.3 * i as f32).collect();
        let raw: Vec<f64> = (0..200).map(|i| 9.8 + 0.001 * i as f64).collect();
        let mut series = imulab_allan::input::AxisSeries::one_segment("accel_x", 0.01, raw.clone());
        series.segments = vec![raw[..120].to_vec(), raw[120..].to_vec()];
        series.temperature = Some(temps.clone());
        let (c, _) = m.compensate_series("imu", &mut series, 1.0).unwrap();
        assert_eq!(c.samples, 200);
        let allan: Vec<f64> = series.segments.concat();
        let mut compensator = ImuCompensator::new(&m, "imu").unwrap();
        let mut export = Vec::new();
        for (rows, temp) in raw.chunks(64).zip(temps.chunks(64)) {
            let mut gyro = vec![[0.0; 3]; rows.len()];
            let mut accel: Vec<[f64; 3]> = rows.iter().map(|&a| [a, 0.0, 0.0]).collect();
            let temp: Vec<f64> = temp.iter().map(|&t| f64::from(t)).collect();
            compensator.compensate_block(&mut gyro, &mut accel, &temp);
            export.extend(accel.iter().map(|r| r[0]));
        }
        assert_eq!(allan, export);
        // Both removed bias(T) − bias(25 °C), not the constant 0.1.
        let at = |k: usize| {
            raw[k] - 0.01 * f64::from(temps[k] - 25.0) - 0.001 * f64::from(temps[k] - 25.0).powi(2)
        };
        assert!(
            (allan[150] - at(150)).abs() < 1e-9,
            "{} {}",
            allan[150],
            at(150)
        );
    }

    #[test]
    fn bad_models_are_refused_with_the_reason() {
        let mut m = model();
        m.version = 9;
        assert!(m.validate().unwrap_err().to_string().contains("version 9"));
        let mut m = model();
        m.devices[0].axes[0].valid_range_c = [50.0, 0.0];
        assert!(m
            .validate()
            .unwrap_err()
            .to_string()
            .contains("valid_range_c"));
    }
}
