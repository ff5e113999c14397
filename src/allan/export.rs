//! Exports of fitted noise terms for other tools: Kalibr's `imu.yaml` (continuous-time
//! noise densities and random walks) and MATLAB's `imuSensor` parameters (NoiseDensity,
//! BiasInstability, RandomWalk) as a runnable `.m` snippet.

use super::analysis::AxisResult;
use super::fit::Term;
use super::units::SensorKind;
use std::fmt::Write;

/// Mean over axes of a term (SI base units), for one sensor; `None` if no axis identified it.
fn mean_term(axes: &[&AxisResult], term: Term) -> Option<f64> {
    let values: Vec<f64> = axes
        .iter()
        .filter_map(|a| {
            let v = a.fit.as_ref()?.get(term)?.value?;
            Some(v * a.unit.to_si())
        })
        .collect();
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

fn axes_of(axes: &[AxisResult], sensor: SensorKind) -> Vec<&AxisResult> {
    axes.iter().filter(|a| a.sensor == Some(sensor)).collect()
}

/// Kalibr `imu.yaml`: noise densities (N) and random walks (K) averaged over the axes of
/// each sensor, SI units, plus the update rate. Terms not identified are written as
/// comments, not as numbers.
pub fn kalibr_yaml(axes: &[AxisResult], topic: &str) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# Kalibr IMU noise model, written by imulab (continuous-time, SI units)."
    );
    let _ = writeln!(
        out,
        "# Values are averages over the analysed axes of each sensor."
    );
    let rate = axes.first().map(|a| 1.0 / a.tau0).unwrap_or(0.0);
    let entries = [
        (
            "accelerometer_noise_density",
            SensorKind::Accel,
            Term::RandomWalk,
            "m/s^2/sqrt(Hz)",
        ),
        (
            "accelerometer_random_walk",
            SensorKind::Accel,
            Term::RateRandomWalk,
            "m/s^3/sqrt(Hz)",
        ),
        (
            "gyroscope_noise_density",
            SensorKind::Gyro,
            Term::RandomWalk,
            "rad/s/sqrt(Hz)",
        ),
        (
            "gyroscope_random_walk",
            SensorKind::Gyro,
            Term::RateRandomWalk,
            "rad/s^2/sqrt(Hz)",
        ),
    ];
    for (key, sensor, term, unit) in entries {
        match mean_term(&axes_of(axes, sensor), term) {
            Some(v) => {
                let _ = writeln!(out, "{key}: {v:.6e}  # {unit}");
            }
            None => {
                let _ = writeln!(out, "# {key}: not identified by the data");
            }
        }
    }
    let _ = writeln!(out, "rostopic: {topic}");
    let _ = writeln!(out, "update_rate: {rate:.6}  # Hz");
    out
}

/// MATLAB `imuSensor` parameters per sensor, as a script that builds the object.
pub fn matlab_imu_sensor(axes: &[AxisResult]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "% imuSensor parameters written by imulab (SI units, per axis x y z)."
    );
    let rate = axes.first().map(|a| 1.0 / a.tau0).unwrap_or(0.0);
    let _ = writeln!(
        out,
        "imu = imuSensor('accel-gyro', 'SampleRate', {rate:.6});"
    );
    for (sensor, property) in [
        (SensorKind::Accel, "Accelerometer"),
        (SensorKind::Gyro, "Gyroscope"),
    ] {
        let sensor_axes = axes_of(axes, sensor);
        if sensor_axes.is_empty() {
            continue;
        }
        let row = |term: Term| -> String {
            let values: Vec<String> = sensor_axes
                .iter()
                .map(|a| {
                    a.fit
                        .as_ref()
                        .and_then(|f| f.get(term)?.value)
                        .map(|v| format!("{:.6e}", v * a.unit.to_si()))
                        .unwrap_or_else(|| "0".into())
                })
                .collect();
            format!("[{}]", values.join(" "))
        };
        let params = if sensor == SensorKind::Accel {
            "accelparams"
        } else {
            "gyroparams"
        };
        let _ = writeln!(
            out,
            "% {}: not-identified terms are written as 0.",
            property
        );
        let _ = writeln!(
            out,
            "imu.{property} = {params}('NoiseDensity', {}, 'BiasInstability', {}, 'RandomWalk', {});",
            row(Term::RandomWalk),
            row(Term::BiasInstability),
            row(Term::RateRandomWalk)
        );
    }
    out
}
