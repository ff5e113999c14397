//! `imulab status`: prints imulogd's status file as a table (per device: state, measured
//! and nominal rate, last-sample age, frames ok/bad, bytes, reconnects, gaps, drops).

use std::path::{Path, PathBuf};

use crate::daemon::status::{read_status_file, DeviceState, StatusReport};

/// Status file name imulogd uses inside its output directory by default.
const DEFAULT_FILE_NAME: &str = "imulogd-status.json";

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example: imulab status /run/imulogd/status.json\n         imulab status /var/lib/imulogd   (reads imulogd-status.json in it)"
)]
pub struct StatusArgs {
    /// The status file, or the directory holding `imulogd-status.json`.
    #[arg(default_value = "/run/imulogd/status.json")]
    pub path: PathBuf,
}

pub fn run(args: StatusArgs) -> anyhow::Result<()> {
    let file = resolve(&args.path);
    let report = read_status_file(&file)?;
    print!("{}", format_status(&report, chrono::Utc::now()));
    Ok(())
}

/// The status file a path names: the path itself, or the default file inside a directory.
pub fn resolve(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join(DEFAULT_FILE_NAME)
    } else {
        path.to_path_buf()
    }
}

fn state_name(state: DeviceState) -> &'static str {
    match state {
        DeviceState::Opening => "opening",
        DeviceState::Connected => "ok",
        DeviceState::Reconnecting => "RECONNECTING",
        DeviceState::Absent => "ABSENT",
        DeviceState::Stopped => "stopped",
    }
}

fn human_bytes(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

/// The report as text; `now` decides whether it is stale.
pub fn format_status(report: &StatusReport, now: chrono::DateTime<chrono::Utc>) -> String {
    let mut out = String::new();
    let age = chrono::DateTime::parse_from_rfc3339(&report.written_at)
        .map(|t| (now - t.with_timezone(&chrono::Utc)).num_milliseconds() as f64 / 1000.0)
        .ok();
    out.push_str(&format!(
        "imulogd pid {}  {}  up {:.0} s  written {}",
        report.pid, report.state, report.uptime_s, report.written_at
    ));
    match age {
        Some(a) if a > 5.0 && report.state != "stopped" => {
            out.push_str(&format!("  (STALE: {a:.0} s old; is imulogd running?)"))
        }
        Some(_) => {}
        None => out.push_str("  (unreadable time stamp)"),
    }
    out.push('\n');
    let path_text = |p: &Option<PathBuf>| {
        p.as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "-".to_string())
    };
    out.push_str(&format!("session  {}\n", path_text(&report.session_dir)));
    out.push_str(&format!("file     {}\n", path_text(&report.current_file)));
    out.push_str(&format!(
        "rows     {}   free {} (reserve {})\n\n",
        report.rows_written,
        report
            .free_bytes
            .map(human_bytes)
            .unwrap_or_else(|| "?".to_string()),
        human_bytes(report.reserve_bytes)
    ));
    let header = [
        "DEVICE", "PROTO", "STATE", "RATE/Hz", "NOMINAL", "AGE/s", "OK", "BAD", "BYTES", "RECONN",
        "GAPS", "DROPPED",
    ];
    let mut rows: Vec<Vec<String>> = vec![header.iter().map(|s| s.to_string()).collect()];
    for d in &report.devices {
        rows.push(vec![
            d.name.clone(),
            d.protocol.clone(),
            state_name(d.state).to_string(),
            format!("{:.1}", d.rate_hz),
            format!("{}", d.expected_rate_hz),
            d.last_sample_age_s
                .map(|a| format!("{a:.2}"))
                .unwrap_or_else(|| "-".to_string()),
            d.frames_ok.to_string(),
            d.frames_bad.to_string(),
            human_bytes(d.bytes),
            d.reconnects.to_string(),
            d.gaps.to_string(),
            d.dropped_rows.to_string(),
        ]);
    }
    let widths: Vec<usize> = (0..header.len())
        .map(|c| rows.iter().map(|r| r[c].chars().count()).max().unwrap_or(0))
        .collect();
    for row in &rows {
        let line: Vec<String> = row
            .iter()
            .zip(&widths)
            .enumerate()
            .map(|(c, (cell, w))| {
                if c < 3 {
                    format!("{cell:<w$}")
                } else {
                    format!("{cell:>w$}")
                }
            })
            .collect();
        out.push_str(line.join("  ").trim_end());
        out.push('\n');
    }
    for d in &report.devices {
        if let Some(e) = &d.last_error {
            out.push_str(&format!("{}: {e}\n", d.name));
        }
    }
    out
}
