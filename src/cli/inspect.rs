//! `imulab inspect SESSION`: what a session holds and how healthy it is: devices, time span,
//! sample counts, effective rates, gaps, dropped/errored frames, events and file sizes.
//! Unreadable chunk files are listed while the rest is still inspected.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;

use crate::store::{layout, DeviceKind, EventKind, Session, TimeRange};

#[derive(clap::Args, Debug)]
#[command(after_help = "Example: imulab inspect runs/2026-11-23-chamber --json > summary.json")]
pub struct InspectArgs {
    /// Session directory.
    pub session: PathBuf,
    /// Print the report as JSON (for scripts) instead of text.
    #[arg(long)]
    pub json: bool,
    /// List at most this many gaps per device.
    #[arg(long, default_value_t = 10)]
    pub max_gaps: usize,
}

#[derive(Debug, Serialize)]
pub struct FileReport {
    pub name: String,
    pub size_bytes: u64,
    pub partial: bool,
    pub problem: Option<String>,
}

#[derive(Debug, Serialize)]
pub struct Gap {
    /// Sample time just before the gap, ns (host monotonic).
    pub after_t_mono_ns: i64,
    pub duration_s: f64,
}

#[derive(Debug, Serialize)]
pub struct DeviceReport {
    pub name: String,
    pub kind: String,
    pub model: String,
    pub serial: String,
    pub port: String,
    pub protocol: String,
    pub axis_frame: String,
    pub nominal_rate_hz: f64,
    pub rows: u64,
    pub first_t_mono_ns: Option<i64>,
    pub last_t_mono_ns: Option<i64>,
    pub span_s: f64,
    pub effective_rate_hz: Option<f64>,
    /// Intervals longer than 2 nominal periods.
    pub gap_count: u64,
    pub gap_total_s: f64,
    pub longest_gap_s: f64,
    pub gaps: Vec<Gap>,
    /// Sum of `count=N` (or 1 per event) over checksum-error events of this device.
    pub frames_errored: u64,
    /// Sum of `count=N` (or 1 per event) over queue-overflow events of this device.
    pub frames_dropped: u64,
    pub events_by_kind: BTreeMap<String, u64>,
}

#[derive(Debug, Serialize)]
pub struct InspectReport {
    pub session: PathBuf,
    pub id: String,
    pub start_time: String,
    pub host: String,
    pub software_version: String,
    pub total_bytes: u64,
    pub files: Vec<FileReport>,
    pub devices: Vec<DeviceReport>,
    pub events_total: u64,
    pub events_by_kind: BTreeMap<String, u64>,
    /// Replay trajectories written into the session (`replay-<name>.h5`, see `imulab replay`).
    pub replays: Vec<FileReport>,
    /// One line per problem found (unreadable files, unreadable parts of files).
    pub problems: Vec<String>,
}

/// Rows per block while scanning a device.
const SCAN_BLOCK_ROWS: usize = 16384;

/// The number an event stands for: `count=N` in its detail, else 1.
fn event_count(detail: &str) -> u64 {
    detail
        .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
        .find_map(|tok| tok.strip_prefix("count=").and_then(|n| n.parse().ok()))
        .unwrap_or(1)
}

fn kind_name(kind: EventKind) -> String {
    serde_json::to_value(kind)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default()
}

/// Builds the report; per-file problems go into `problems` rather than failing.
pub fn inspect(session: &Session, max_gaps: usize) -> InspectReport {
    let m = session.manifest();
    let mut problems = session.problems();
    let files: Vec<FileReport> = session
        .files()
        .into_iter()
        .map(|f| FileReport {
            name: f
                .path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            size_bytes: f.size_bytes,
            partial: f.partial,
            problem: f.problem,
        })
        .collect();
    let (events, event_problems) = session.events();
    // The same unreadable files show up again from the event reader; list each problem once.
    for p in event_problems {
        if !problems
            .iter()
            .any(|q| p.contains(q.as_str()) || q.contains(p.as_str()))
        {
            problems.push(p);
        }
    }
    let mut events_by_kind = BTreeMap::new();
    for e in &events {
        *events_by_kind.entry(kind_name(e.kind)).or_insert(0) += 1;
    }

    let mut devices = Vec::new();
    for d in &m.devices {
        let group = match d.kind {
            DeviceKind::Imu => layout::imu_path(&d.name),
            DeviceKind::Gnss => layout::gnss_path(&d.name),
        };
        let summary = session.stream_summary(&group);
        let period_ns = 1e9 / d.rate_hz;
        let (mut gap_count, mut gap_total_ns, mut longest_ns) = (0u64, 0f64, 0f64);
        let mut gaps = Vec::new();
        let mut prev: Option<i64> = None;
        // Whole rows are read (not only the times) so that damage anywhere in the data shows.
        let mut scan = |times: &[i64]| {
            for &t in times {
                if let Some(p) = prev {
                    let dt = (t - p) as f64;
                    if dt > 2.0 * period_ns {
                        gap_count += 1;
                        gap_total_ns += dt;
                        longest_ns = longest_ns.max(dt);
                        if gaps.len() < max_gaps {
                            gaps.push(Gap {
                                after_t_mono_ns: p,
                                duration_s: dt * 1e-9,
                            });
                        }
                    }
                }
                prev = Some(t);
            }
        };
        let mut read_problems = Vec::new();
        match d.kind {
            DeviceKind::Imu => {
                if let Ok(blocks) = session.imu_blocks(&d.name, TimeRange::all(), SCAN_BLOCK_ROWS) {
                    for block in blocks {
                        match block {
                            Ok(b) => scan(&b.t_mono_ns),
                            Err(e) => read_problems.push(e.to_string()),
                        }
                    }
                }
            }
            DeviceKind::Gnss => {
                if let Ok(blocks) = session.gnss_blocks(&d.name, TimeRange::all(), SCAN_BLOCK_ROWS)
                {
                    for block in blocks {
                        match block {
                            Ok(b) => scan(&b.t_mono_ns),
                            Err(e) => read_problems.push(e.to_string()),
                        }
                    }
                }
            }
        }
        // Unreadable files were listed already; add only new problems.
        for p in read_problems {
            if !problems
                .iter()
                .any(|q| p.contains(q.as_str()) || q.contains(p.as_str()))
            {
                problems.push(p);
            }
        }
        let span_s = match (summary.first_t_mono_ns, summary.last_t_mono_ns) {
            (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
            _ => 0.0,
        };
        let effective_rate_hz =
            (summary.rows > 1 && span_s > 0.0).then(|| (summary.rows - 1) as f64 / span_s);
        let mut by_kind = BTreeMap::new();
        let (mut errored, mut dropped) = (0, 0);
        for e in events.iter().filter(|e| e.device == d.name) {
            *by_kind.entry(kind_name(e.kind)).or_insert(0) += 1;
            match e.kind {
                EventKind::ChecksumError => errored += event_count(&e.detail),
                EventKind::QueueOverflow => dropped += event_count(&e.detail),
                _ => {}
            }
        }
        for p in summary.problems {
            if !problems.contains(&p) {
                problems.push(p);
            }
        }
        devices.push(DeviceReport {
            name: d.name.clone(),
            kind: d.kind.as_str().into(),
            model: d.model.clone(),
            serial: d.serial.clone(),
            port: d.port.clone(),
            protocol: d.protocol.clone(),
            axis_frame: d.axis_frame.clone(),
            nominal_rate_hz: d.rate_hz,
            rows: summary.rows,
            first_t_mono_ns: summary.first_t_mono_ns,
            last_t_mono_ns: summary.last_t_mono_ns,
            span_s,
            effective_rate_hz,
            gap_count,
            gap_total_s: gap_total_ns * 1e-9,
            longest_gap_s: longest_ns * 1e-9,
            gaps,
            frames_errored: errored,
            frames_dropped: dropped,
            events_by_kind: by_kind,
        });
    }
    InspectReport {
        session: session.dir().to_path_buf(),
        id: m.id.clone(),
        start_time: m.start_time.to_rfc3339(),
        host: m.host.clone(),
        software_version: m.software_version.clone(),
        total_bytes: files.iter().map(|f| f.size_bytes).sum(),
        files,
        devices,
        events_total: events.len() as u64,
        events_by_kind,
        replays: replay_files(session.dir()),
        problems,
    }
}

/// The `replay-<name>.h5` files in the session directory, by name.
fn replay_files(dir: &std::path::Path) -> Vec<FileReport> {
    let mut out: Vec<FileReport> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            layout::parse_replay_file_name(&name)?;
            Some(FileReport {
                size_bytes: e.metadata().map(|m| m.len()).unwrap_or(0),
                name,
                partial: false,
                problem: None,
            })
        })
        .collect();
    out.sort_by(|a, b| a.name.cmp(&b.name));
    out
}

fn mb(bytes: u64) -> f64 {
    bytes as f64 / 1e6
}

fn print_text(r: &InspectReport) {
    println!("session   {}", r.session.display());
    println!(
        "id        {}  started {}  host {}  imulab {}",
        r.id, r.start_time, r.host, r.software_version
    );
    println!(
        "files     {} chunk file(s), {:.2} MB",
        r.files.len(),
        mb(r.total_bytes)
    );
    for f in &r.files {
        let state = match (&f.problem, f.partial) {
            (Some(_), _) => "UNREADABLE",
            (None, true) => "partial",
            (None, false) => "ok",
        };
        println!("  {:<26} {:>10.2} MB  {state}", f.name, mb(f.size_bytes));
    }
    for f in &r.replays {
        println!(
            "  {:<26} {:>10.2} MB  replay trajectory",
            f.name,
            mb(f.size_bytes)
        );
    }
    println!("devices");
    for d in &r.devices {
        println!(
            "  {} ({} {} s/n {}, {} on {}, axes {})",
            d.name, d.kind, d.model, d.serial, d.protocol, d.port, d.axis_frame
        );
        let eff = d
            .effective_rate_hz
            .map(|x| format!("{x:.3} Hz"))
            .unwrap_or_else(|| "-".into());
        println!(
            "    rows {}  span {:.3} s  rate {} (nominal {} Hz)",
            d.rows, d.span_s, eff, d.nominal_rate_hz
        );
        println!(
            "    gaps > 2 periods: {}  (total {:.3} s, longest {:.3} s)  frames errored {}  dropped {}",
            d.gap_count, d.gap_total_s, d.longest_gap_s, d.frames_errored, d.frames_dropped
        );
        for g in &d.gaps {
            println!(
                "      gap of {:.3} s after t_mono_ns {}",
                g.duration_s, g.after_t_mono_ns
            );
        }
        if d.gap_count as usize > d.gaps.len() {
            println!("      ... {} more", d.gap_count as usize - d.gaps.len());
        }
    }
    let kinds: Vec<String> = r
        .events_by_kind
        .iter()
        .map(|(k, n)| format!("{k} {n}"))
        .collect();
    println!("events    {} ({})", r.events_total, kinds.join(", "));
    for p in &r.problems {
        println!("PROBLEM   {p}");
    }
}

pub fn run(args: InspectArgs) -> anyhow::Result<()> {
    let session = Session::open(&args.session)?;
    let report = inspect(&session, args.max_gaps);
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&report).context("serialising the report")?
        );
    } else {
        print_text(&report);
    }
    match report.problems.first() {
        Some(first) => anyhow::bail!("{} problem(s); first: {first}", report.problems.len()),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::event_count;

    #[test]
    fn event_count_reads_count_token_or_defaults_to_one() {
        assert_eq!(event_count("count=17 bad crc"), 17);
        assert_eq!(event_count("bad crc, count=3"), 3);
        assert_eq!(event_count("bad crc"), 1);
        assert_eq!(event_count("count=x"), 1);
    }
}
