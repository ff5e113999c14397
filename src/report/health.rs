//! The data-health part of the report for session inputs: per device the samples, time
//! span, nominal and effective rate, gaps, temperature range and mean, and the daemon's events
//! from `/events` (resyncs, checksum errors, dropped frames, disconnects, …), plus the
//! session's unreadable files.
//!
//! Gaps and temperatures come from the analysis when it read them (one pass over the data);
//! what it did not read is read here: the temperature column of an IMU (whole rows, the only
//! reader the store has) and the time stamps of a GNSS receiver.

use crate::allan::analysis::{AllanReport, AxisResult};
use crate::store::{DeviceKind, EventKind, EventRecord, Session, TimeRange};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// Temperature statistics of one device, °C.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Temperature {
    pub min: f64,
    pub mean: f64,
    pub max: f64,
}

/// Health of one device of a session.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceHealth {
    pub name: String,
    pub kind: String,
    pub model: String,
    pub protocol: String,
    pub nominal_rate_hz: f64,
    pub rows: u64,
    pub span_s: f64,
    pub effective_rate_hz: Option<f64>,
    /// Gaps in the time stamps (IMUs: intervals ≥ 1.5 τ0 as the analysis counts them;
    /// GNSS: intervals > 2 nominal periods), and the samples missing in them (IMUs).
    pub gaps: Option<u64>,
    pub missing_samples: Option<u64>,
    /// NaN/Inf values over the analysed axes.
    pub invalid_values: Option<u64>,
    pub temperature: Option<Temperature>,
    /// Event kind → number of frames/occurrences (`count=N` in the detail, else 1 per event).
    pub events: BTreeMap<String, u64>,
}

/// Health of one session input.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SessionHealth {
    pub path: String,
    pub id: String,
    pub start_time: String,
    pub host: String,
    pub files: usize,
    pub devices: Vec<DeviceHealth>,
    /// Session-wide events (no device), by kind, counted as for devices.
    pub session_events: BTreeMap<String, u64>,
    /// One line per problem (unreadable file, unreadable part of a file).
    pub problems: Vec<String>,
}

/// Event kinds that say something went wrong (shown first, highlighted when non-zero).
pub const PROBLEM_EVENTS: [&str; 6] = [
    "gap",
    "resync",
    "checksum_error",
    "queue_overflow",
    "disconnect",
    "disk_low",
];

pub fn event_kind_name(kind: EventKind) -> &'static str {
    match kind {
        EventKind::SessionStart => "session_start",
        EventKind::SessionStop => "session_stop",
        EventKind::Rotation => "rotation",
        EventKind::Connect => "connect",
        EventKind::Disconnect => "disconnect",
        EventKind::Reconnect => "reconnect",
        EventKind::Resync => "resync",
        EventKind::ChecksumError => "checksum_error",
        EventKind::Gap => "gap",
        EventKind::QueueOverflow => "queue_overflow",
        EventKind::DiskLow => "disk_low",
        EventKind::Info => "info",
    }
}

/// The number an event stands for: `count=N` in its detail, else 1.
pub fn event_count(detail: &str) -> u64 {
    detail
        .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
        .find_map(|tok| tok.strip_prefix("count=").and_then(|n| n.parse().ok()))
        .unwrap_or(1)
}

fn count_events<'a>(events: impl Iterator<Item = &'a EventRecord>) -> BTreeMap<String, u64> {
    let mut out = BTreeMap::new();
    for e in events {
        *out.entry(event_kind_name(e.kind).to_string()).or_insert(0) += event_count(&e.detail);
    }
    out
}

/// Temperature of an IMU from the analysed axes, when the analysis carried the channel.
fn temperature_from_analysis(axes: &[&AxisResult]) -> Option<Temperature> {
    let a = axes.iter().find(|a| a.thermal.is_some())?;
    let (min, max) = (a.health.temperature_min?, a.health.temperature_max?);
    let bins = &a.thermal.as_ref()?.bins;
    let n: u64 = bins.iter().map(|b| b.samples).sum();
    // Bin temperatures are the means of their samples, so this is the exact mean.
    let mean = bins
        .iter()
        .map(|b| b.temperature * b.samples as f64)
        .sum::<f64>()
        / n.max(1) as f64;
    (n > 0).then_some(Temperature { min, mean, max })
}

/// Reads the temperature column of IMU `device` (finite values only).
fn read_temperature(
    session: &Session,
    device: &str,
    problems: &mut Vec<String>,
) -> Option<Temperature> {
    let blocks = match session.imu_blocks(device, TimeRange::all(), 65_536) {
        Ok(b) => b,
        Err(e) => {
            problems.push(format!("{device}: temperature not read: {e}"));
            return None;
        }
    };
    let (mut n, mut sum, mut min, mut max) = (0u64, 0.0f64, f64::INFINITY, f64::NEG_INFINITY);
    for block in blocks {
        match block {
            Ok(b) => {
                for t in b.temp.into_iter().filter(|t| t.is_finite()) {
                    n += 1;
                    sum += t;
                    min = min.min(t);
                    max = max.max(t);
                }
            }
            Err(e) => {
                let line = e.to_string();
                if !problems.contains(&line) {
                    problems.push(line);
                }
            }
        }
    }
    (n > 0).then(|| Temperature {
        min,
        mean: sum / n as f64,
        max,
    })
}

/// Gaps (> 2 nominal periods) in a device's time stamps.
fn scan_gaps(session: &Session, device: &str, rate_hz: f64, problems: &mut Vec<String>) -> u64 {
    let Ok(blocks) = session.time_blocks(device, TimeRange::all(), 65_536) else {
        return 0;
    };
    let limit = 2e9 / rate_hz;
    let (mut gaps, mut prev) = (0, None::<i64>);
    for block in blocks {
        match block {
            Ok(times) => {
                for t in times {
                    if prev.is_some_and(|p| (t - p) as f64 > limit) {
                        gaps += 1;
                    }
                    prev = Some(t);
                }
            }
            Err(e) => problems.push(e.to_string()),
        }
    }
    gaps
}

/// The health of session `path`, using what `report` already computed for its IMUs.
pub fn session_health(path: &Path, report: &AllanReport) -> Result<SessionHealth, String> {
    let session = Session::open(path).map_err(|e| e.to_string())?;
    let m = session.manifest();
    let mut problems = session.problems();
    let (events, event_problems) = session.events();
    for p in event_problems {
        if !problems.iter().any(|q| p.contains(q.as_str())) {
            problems.push(p);
        }
    }
    let shown = path.display().to_string();
    let mut devices = Vec::new();
    for d in &m.devices {
        let group = match d.kind {
            DeviceKind::Imu => crate::store::layout::imu_path(&d.name),
            DeviceKind::Gnss => crate::store::layout::gnss_path(&d.name),
        };
        let summary = session.stream_summary(&group);
        for p in summary.problems {
            if !problems.contains(&p) {
                problems.push(p);
            }
        }
        let span_s = match (summary.first_t_mono_ns, summary.last_t_mono_ns) {
            (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
            _ => 0.0,
        };
        // This session's axes of this device (the report may hold other sessions' devices of
        // the same name: match the input too).
        let axes: Vec<&AxisResult> = report
            .axes
            .iter()
            .filter(|a| a.device == d.name && !a.axis.contains(" @ "))
            .collect();
        let analysed = report.input.iter().any(|i| i == &shown) && !axes.is_empty();
        let (gaps, missing, invalid, temperature) = match d.kind {
            DeviceKind::Imu if analysed => {
                let h = &axes[0].health;
                // The analysis carried the channel: use it (a device without temperature
                // stays without); otherwise read it.
                let temperature = if axes.iter().any(|a| a.thermal.is_some()) {
                    temperature_from_analysis(&axes)
                } else {
                    read_temperature(&session, &d.name, &mut problems)
                };
                (
                    Some(h.gaps),
                    Some(h.missing_samples),
                    Some(axes.iter().map(|a| a.health.invalid_values).sum()),
                    temperature,
                )
            }
            DeviceKind::Imu => (
                None,
                None,
                None,
                read_temperature(&session, &d.name, &mut problems),
            ),
            DeviceKind::Gnss => (
                Some(scan_gaps(&session, &d.name, d.rate_hz, &mut problems)),
                None,
                None,
                None,
            ),
        };
        devices.push(DeviceHealth {
            name: d.name.clone(),
            kind: d.kind.as_str().to_string(),
            model: d.model.clone(),
            protocol: d.protocol.clone(),
            nominal_rate_hz: d.rate_hz,
            rows: summary.rows,
            span_s,
            effective_rate_hz: (summary.rows > 1 && span_s > 0.0)
                .then(|| (summary.rows - 1) as f64 / span_s),
            gaps,
            missing_samples: missing,
            invalid_values: invalid,
            temperature,
            events: count_events(events.iter().filter(|e| e.device == d.name)),
        });
    }
    Ok(SessionHealth {
        path: shown,
        id: m.id.clone(),
        start_time: m.start_time.to_rfc3339(),
        host: m.host.clone(),
        files: session.files().len(),
        devices,
        session_events: count_events(events.iter().filter(|e| e.device.is_empty())),
        problems,
    })
}

/// The health of every session directory among the report's inputs, in input order; an
/// input that cannot be read gives its error line instead.
pub fn sessions_of_report(report: &AllanReport) -> Vec<Result<SessionHealth, String>> {
    report
        .input
        .iter()
        .map(Path::new)
        .filter(|p| p.is_dir())
        .map(|p| session_health(p, report).map_err(|e| format!("{}: {e}", p.display())))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn event_counts_use_the_count_token() {
        assert_eq!(event_count("count=17 bad crc"), 17);
        assert_eq!(event_count("bad crc, count=3"), 3);
        assert_eq!(event_count("lost sync"), 1);
    }
}
