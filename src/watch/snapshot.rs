//! What the page shows, computed from the follower's state: per device the health figures,
//! per IMU axis the curve, its fit and, for each noise term, the estimate, its interval and
//! the stop-time prediction. Serialised as `/state.json`.

use super::follow::{AxisState, DeviceState, Follower};
use super::stop::{relative_width, term_name, Prediction, Predictions, Target};
use crate::allan::analysis::AxisResult;
use crate::allan::fit::{fit_noise_terms, slope_readings, Term};
use crate::allan::input::Health;
use crate::allan::units::{fit_in_units, RateUnit, SensorKind};
use crate::daemon::status::{DeviceStatus, StatusReport};
use crate::store::DeviceKind;
use serde::Serialize;
use std::collections::BTreeMap;

/// The daemon's status file, when it describes this session.
#[derive(Debug, Clone, Serialize)]
pub struct DaemonView {
    pub state: String,
    pub written_at: String,
    /// Seconds since it was written.
    pub age_s: Option<f64>,
    pub free_bytes: Option<u64>,
}

/// One noise term of one axis.
#[derive(Debug, Clone, Serialize)]
pub struct TermView {
    pub term: Term,
    /// `--target` name, e.g. `bias-instability`.
    pub key: &'static str,
    /// Engineering name, e.g. `ARW`.
    pub name: String,
    pub unit: String,
    pub value: Option<f64>,
    /// 95 % interval in `unit`.
    pub low: f64,
    pub high: f64,
    /// Larger relative distance from the estimate to a bound.
    pub relative_width: Option<f64>,
    pub target: Option<f64>,
    pub prediction: Option<Prediction>,
}

/// One IMU axis.
#[derive(Debug, Clone, Serialize)]
pub struct AxisView {
    pub result: AxisResult,
    pub terms: Vec<TermView>,
    /// Values left out (NaN, infinite).
    pub invalid_values: u64,
}

/// One device.
#[derive(Debug, Clone, Serialize)]
pub struct DeviceView {
    pub name: String,
    pub kind: String,
    pub model: String,
    pub protocol: String,
    pub nominal_rate_hz: f64,
    pub rows: u64,
    pub span_s: f64,
    pub recent_rate_hz: Option<f64>,
    pub mean_rate_hz: Option<f64>,
    /// Seconds from the last sample in the files to now (live sessions only).
    pub last_sample_age_s: Option<f64>,
    pub gaps: u64,
    pub missing_samples: u64,
    pub events: BTreeMap<String, u64>,
    /// (seconds since the first sample, mean, min, max) per bin, °C.
    pub temperature: Vec<(f64, f64, f64, f64)>,
    /// The daemon's own line for the device, when its status file is there.
    pub daemon: Option<DeviceStatus>,
    pub axes: Vec<AxisView>,
}

/// The whole page's content.
#[derive(Debug, Clone, Serialize)]
pub struct Snapshot {
    pub session_id: String,
    pub dir: String,
    pub host: String,
    pub start_time: String,
    /// A writer holds the session's lock.
    pub live: bool,
    /// When this was computed, RFC 3339 UTC.
    pub generated_at: String,
    pub files: usize,
    pub partial_files: usize,
    pub looks: u64,
    pub devices: Vec<DeviceView>,
    pub session_events: BTreeMap<String, u64>,
    pub problems: Vec<String>,
    pub daemon: Option<DaemonView>,
    pub targets: Vec<Target>,
    /// Time this snapshot took to compute, ms.
    pub compute_ms: f64,
}

/// Builds the snapshot. `now_mono_ns`: the host's CLOCK_MONOTONIC now (sample ages);
/// `status`: the daemon's status file when it is this session's.
pub fn snapshot(
    follower: &Follower,
    predictions: &mut Predictions,
    live: bool,
    targets: &[Target],
    status: Option<&StatusReport>,
    now_mono_ns: i64,
) -> Snapshot {
    let started = std::time::Instant::now();
    let m = &follower.manifest;
    let now = chrono::Utc::now();
    let devices = follower
        .devices
        .iter()
        .map(|d| {
            let daemon = status.and_then(|s| s.devices.iter().find(|x| x.name == d.info.name));
            device_view(d, predictions, live, targets, daemon.cloned(), now_mono_ns)
        })
        .collect();
    let daemon = status.map(|s| DaemonView {
        state: s.state.clone(),
        written_at: s.written_at.clone(),
        age_s: chrono::DateTime::parse_from_rfc3339(&s.written_at)
            .ok()
            .map(|t| (now - t.with_timezone(&chrono::Utc)).num_milliseconds() as f64 * 1e-3),
        free_bytes: s.free_bytes,
    });
    Snapshot {
        session_id: m.id.clone(),
        dir: follower.dir().display().to_string(),
        host: m.host.clone(),
        start_time: m
            .start_time
            .to_rfc3339_opts(chrono::SecondsFormat::Secs, true),
        live,
        generated_at: now.to_rfc3339_opts(chrono::SecondsFormat::Secs, true),
        files: follower.file_count(),
        partial_files: follower.partial_files,
        looks: follower.looks,
        devices,
        session_events: follower.session_events.clone(),
        problems: follower.problems.clone(),
        daemon,
        targets: targets.to_vec(),
        compute_ms: started.elapsed().as_secs_f64() * 1e3,
    }
}

fn device_view(
    d: &DeviceState,
    predictions: &mut Predictions,
    live: bool,
    targets: &[Target],
    daemon: Option<DeviceStatus>,
    now_mono_ns: i64,
) -> DeviceView {
    let first = d.first_t_ns.unwrap_or(0);
    let temperature = d
        .temperature
        .bins
        .iter()
        .map(|b| {
            let mid = (b.start_ns + b.end_ns) / 2;
            ((mid - first) as f64 * 1e-9, b.mean(), b.min, b.max)
        })
        .collect();
    let tau0 = d.tau0();
    let axes = d
        .axes_with_data()
        .map(|a| axis_view(d, a, tau0, targets, predictions))
        .collect();
    DeviceView {
        name: d.info.name.clone(),
        kind: match d.info.kind {
            DeviceKind::Imu => "imu",
            DeviceKind::Gnss => "gnss",
        }
        .to_string(),
        model: d.info.model.clone(),
        protocol: d.info.protocol.clone(),
        nominal_rate_hz: d.info.rate_hz,
        rows: d.rows,
        span_s: d.span_s(),
        recent_rate_hz: d.recent_rate_hz(),
        mean_rate_hz: d.mean_rate_hz(),
        last_sample_age_s: d
            .last_t_ns
            .filter(|_| live)
            .map(|t| ((now_mono_ns - t) as f64 * 1e-9).max(0.0)),
        gaps: d.gaps,
        missing_samples: d.missing_samples,
        events: d.events.clone(),
        temperature,
        daemon,
        axes,
    }
}

fn axis_view(
    d: &DeviceState,
    axis: &AxisState,
    tau0: f64,
    targets: &[Target],
    predictions: &mut Predictions,
) -> AxisView {
    let (name, sensor, allan, invalid) = (axis.name, axis.sensor, &axis.allan, axis.invalid);
    let key = format!("{}/{name}", d.info.name);
    let curve = allan.curve(tau0);
    let samples = allan.samples() as usize;
    let unit = match sensor {
        SensorKind::Gyro => RateUnit::RadPerSecond,
        SensorKind::Accel => RateUnit::MetrePerSecondSquared,
    };
    let (fit, fit_error) = match fit_noise_terms(&curve) {
        Ok(f) => (Some(f), None),
        Err(e) => (None, Some(e.to_string())),
    };
    let mut terms = Vec::new();
    if let Some(fit) = &fit {
        for t in fit_in_units(fit, Some(sensor), unit) {
            let target = targets.iter().find(|x| x.term == t.term);
            if !t.identified && target.is_none() {
                continue;
            }
            let Some(v) = t.values.first() else { continue };
            let estimate = fit.get(t.term);
            terms.push(TermView {
                term: t.term,
                key: term_name(t.term),
                name: t.name.clone(),
                unit: v.unit.clone(),
                value: v.value,
                low: v.low,
                high: v.high,
                relative_width: estimate.and_then(relative_width),
                target: target.map(|x| x.relative),
                prediction: target.map(|x| predictions.get(&key, &curve, fit, samples, x)),
            });
        }
    }
    let health = Health {
        samples: samples as u64,
        duration_s: samples as f64 * tau0,
        gaps: d.gaps,
        missing_samples: d.missing_samples,
        invalid_values: invalid,
        segments: 1,
        ..Health::default()
    };
    let terms_in_units = fit
        .as_ref()
        .map(|f| fit_in_units(f, Some(sensor), unit))
        .unwrap_or_default();
    let slopes = Some(slope_readings(&curve));
    AxisView {
        result: AxisResult {
            device: d.info.name.clone(),
            axis: name.to_string(),
            sensor: Some(sensor),
            unit,
            tau0,
            mean: allan.mean(),
            health,
            curve,
            fit,
            terms: terms_in_units,
            fit_error,
            slopes,
            thermal: None,
        },
        terms,
        invalid_values: invalid,
    }
}
