//! `imulab inspect SESSION`: what a session holds and how healthy it is: devices, time span,
//! sample counts, effective rates, gaps, dropped/errored frames, events and file sizes.
//! Unreadable chunk files are listed while the rest is still inspected.
//!
//! A gap is what imulogd calls one (`daemon::gap`): a pause between two arrivals longer than
//! `gap_factor` nominal periods (from the configuration the session recorded, default 3) and
//! never shorter than 50 ms, the host latency `allan` also allows on arrival times. The rate
//! is the median over windows of rows, so a start-up burst of buffered frames does not pass
//! for a faster device. Rows that a killed writer left only in its journal are counted and
//! `imulab recover` is pointed at.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;

use crate::daemon::config::DEFAULT_GAP_FACTOR;
use crate::daemon::gap::GapDetector;
use crate::store::{layout, DeviceKind, EventKind, Manifest, Session, TimeRange};

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
    /// Sample time just before the gap, seconds after the device's first sample (the time
    /// `imulab export --start` takes).
    pub after_s: f64,
    /// The same time, ns (host monotonic, `t_mono_ns`).
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
    /// Median over windows of rows (see [`steady_rate_hz`]).
    pub effective_rate_hz: Option<f64>,
    /// `gap_factor` the gaps are counted with (as imulogd's gap events).
    pub gap_factor: f64,
    /// Pauses longer than `gap_factor` nominal periods and at least 50 ms.
    pub gap_count: u64,
    pub gap_total_s: f64,
    pub longest_gap_s: f64,
    pub gaps: Vec<Gap>,
    /// Sum of `count=N` (or 1 per event) over checksum-error events of this device.
    pub frames_errored: u64,
    /// Sum of `count=N` (or 1 per event) over queue-overflow events of this device.
    pub frames_dropped: u64,
    pub events_by_kind: BTreeMap<String, u64>,
    /// Rows only in the write-ahead journal of a partial chunk file (not counted in `rows`).
    pub journal_rows: u64,
    /// GNSS rows with a heading (`heading_deg` not NaN); `None` for IMUs.
    pub heading_rows: Option<u64>,
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

/// `gap_factor` of device `name` in the daemon configuration the session recorded
/// (`[[device]]` tables; a receiver's IMU, `imu.name`, has its receiver's), else imulogd's
/// default.
fn gap_factor(m: &Manifest, name: &str) -> f64 {
    fn name_of(t: Option<&toml::Value>) -> Option<&str> {
        t.and_then(|t| t.get("name")).and_then(|n| n.as_str())
    }
    let names =
        |d: &toml::Value| name_of(Some(d)) == Some(name) || name_of(d.get("imu")) == Some(name);
    m.config
        .get("device")
        .and_then(|v| v.as_array())
        .and_then(|devices| devices.iter().find(|d| names(d)))
        .and_then(|d| d.get("gap_factor"))
        .and_then(|g| g.as_float().or_else(|| g.as_integer().map(|i| i as f64)))
        .unwrap_or(DEFAULT_GAP_FACTOR)
}

/// Rows per window of the rate estimate, at most.
const RATE_WINDOW_ROWS: usize = 1000;

/// The rate of a device from the times of every `window`-th row (`marks`): the median of
/// the windows' rates. Frames buffered before the start (or after a reconnect) arrive in a
/// burst and make `rows / span` too high (101.7 Hz for 100); the median ignores the window
/// holding the burst, as it does one holding a gap. `None` for fewer than two rows.
fn steady_rate_hz(marks: &[i64], window: usize, rows: u64, span_s: f64) -> Option<f64> {
    let mut rates: Vec<f64> = marks
        .windows(2)
        .filter(|w| w[1] > w[0])
        .map(|w| window as f64 / ((w[1] - w[0]) as f64 * 1e-9))
        .collect();
    if rates.len() < 3 {
        return (rows > 1 && span_s > 0.0).then(|| (rows - 1) as f64 / span_s);
    }
    rates.sort_by(f64::total_cmp);
    Some(rates[rates.len() / 2])
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
        let factor = gap_factor(m, &d.name);
        let mut detector = GapDetector::new(d.rate_hz, factor);
        let (mut gap_count, mut gap_total_ns, mut longest_ns) = (0u64, 0i64, 0i64);
        let mut gaps = Vec::new();
        let first_t = summary.first_t_mono_ns.unwrap_or(0);
        let window = (summary.rows as usize / 5).clamp(10, RATE_WINDOW_ROWS);
        let mut marks = Vec::new();
        let mut heading_rows = None;
        let mut seen = 0usize;
        // Whole rows are read (not only the times) so that damage anywhere in the data shows.
        let mut scan = |times: &[i64]| {
            for &t in times {
                if seen.is_multiple_of(window) {
                    marks.push(t);
                }
                seen += 1;
                if let Some(g) = detector.observe(t) {
                    let dt = g.to_mono_ns - g.from_mono_ns;
                    gap_count += 1;
                    gap_total_ns += dt;
                    longest_ns = longest_ns.max(dt);
                    if gaps.len() < max_gaps {
                        gaps.push(Gap {
                            after_s: (g.from_mono_ns - first_t) as f64 * 1e-9,
                            after_t_mono_ns: g.from_mono_ns,
                            duration_s: g.duration_s(),
                        });
                    }
                }
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
                    let mut with_heading = 0u64;
                    for block in blocks {
                        match block {
                            Ok(b) => {
                                scan(&b.t_mono_ns);
                                with_heading +=
                                    b.heading_deg.iter().filter(|h| !h.is_nan()).count() as u64;
                            }
                            Err(e) => read_problems.push(e.to_string()),
                        }
                    }
                    heading_rows = Some(with_heading);
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
        let effective_rate_hz = steady_rate_hz(&marks, window, summary.rows, span_s);
        let backlog = session.journal_backlog(&group);
        let journal_rows = backlog.iter().map(|(_, n)| n).sum();
        if !backlog.is_empty() && !crate::store::reader::writer_is_live(session.dir()) {
            for (file, n) in &backlog {
                problems.push(format!(
                    "{}: its journal holds {n} more rows of {} than the HDF5 file (the writer \
                     was killed); run `imulab recover {}` to add them",
                    file.display(),
                    d.name,
                    session.dir().display()
                ));
            }
        }
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
            gap_factor: factor,
            gap_count,
            gap_total_s: gap_total_ns as f64 * 1e-9,
            longest_gap_s: longest_ns as f64 * 1e-9,
            gaps,
            frames_errored: errored,
            frames_dropped: dropped,
            events_by_kind: by_kind,
            journal_rows,
            heading_rows,
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
        let journal = if d.journal_rows > 0 {
            format!(" (+{} only in the journal)", d.journal_rows)
        } else {
            String::new()
        };
        println!(
            "    rows {}{journal}  span {:.3} s  rate {} (nominal {} Hz)",
            d.rows, d.span_s, eff, d.nominal_rate_hz
        );
        println!(
            "    gaps > {} periods: {}  (total {:.3} s, longest {:.3} s)  frames errored {}  dropped {}",
            d.gap_factor, d.gap_count, d.gap_total_s, d.longest_gap_s, d.frames_errored, d.frames_dropped
        );
        if let Some(n) = d.heading_rows {
            println!("    heading in {n} of {} rows", d.rows);
        }
        for g in &d.gaps {
            println!(
                "      gap of {:.3} s at {:.3} s (after the first sample)",
                g.duration_s, g.after_s
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
