//! `imulab demo`: the bench workflow end to end on built-in simulated sensors, no hardware.
//!
//! 1. The simulator ([`crate::sim::serve`]) serves the motivating bench study on ptys: a
//!    ~25 EUR IMU (`cheap`, WitMotion protocol) and one ten times dearer (`dear`, Xsens Xbus),
//!    static in a 25 °C chamber at 150 Hz, and a u-blox-like receiver (`rx`, UBX and NMEA
//!    mixed, 10 Hz), accelerated by `--speed`. The `imulogd` binary found next to this one
//!    logs them into `OUT/session` from `OUT/imulogd.toml`, the production configuration
//!    format; it is stopped with SIGTERM once the scene has been served and must exit 0.
//! 2. The session is checked against the server's report: every IMU frame sent is one row,
//!    every mixed GNSS epoch one (its UBX and NMEA messages merge); the devices' own clocks have no
//!    gap; the daemon's events (resyncs, checksum errors, queue overflows) are counted.
//! 3. The Allan report comparing the two IMUs (`report.html`, `report.json`, PNG plots).
//!    imulogd stamps rows at host arrival, which an accelerated serve compresses by the speed
//!    factor, so the demo analyses on the devices' sample clock instead: row k at k / 150 s,
//!    valid because step 2 showed the rows are complete and the device clocks continuous.
//!    (For the same reason the configuration gives imulogd the rates the accelerated link
//!    carries, 150 Hz × speed: they size its chunks and its gap detector.)
//! 4. A fusion replay (`imulab replay`) of a simulated 15 minute drive with both IMUs and
//!    GNSS outages of 30 s every 120 s, the filter tuned from each IMU's Allan fit.
//! 5. A small sensor-grade study ([`crate::study::grades`]) whose grades are the two Allan
//!    fits just made: how long an outage each of these IMUs bridges within 0.1 m and 1 m.
//!
//! At the end: the paths of the session, report and JSON, and three lines of findings.

use crate::allan::analysis::{analyse_axis, AllanReport, AnalysisOptions};
use crate::allan::input::{read_axes, DataKind, GapPolicy, SampleSource, Timing};
use crate::allan::session_source::SessionSource;
use crate::allan::units::TermInUnits;
use crate::allan::{DeviationKind, TauGrid};
use crate::daemon::status::{read_status_file, DeviceState};
use crate::report::{
    datasheet_table_text, html_report, html_report_with_study, plot_groups, write_png_axes,
};
use crate::sim::scene::Scene;
use crate::sim::serve::{ServeOptions, ServeReport, Server, Speed, StartWhen};
use crate::store::{EventKind, Session, TimeRange};
use crate::study::grades::{fit_study, StudyResult};
use anyhow::{bail, Context};
use clap::Parser;
use rayon::prelude::*;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The built-in chamber scene; `--minutes` replaces its duration, the demo adds the wire
/// protocols and the GNSS receiver.
const CHAMBER_SCENE: &str = include_str!("../../fixtures/scenes/chamber_6h.toml");
/// Sample rate of the bench IMUs (the chamber scene's), Hz.
const IMU_HZ: f64 = 150.0;
/// The served GNSS receiver's rate, Hz.
const GNSS_HZ: f64 = 10.0;
/// Stages printed as `[n/STAGES]`.
const STAGES: u32 = 5;
/// How long imulogd may take to open the ptys, and to exit after SIGTERM.
const DAEMON_START_TIMEOUT: Duration = Duration::from_secs(30);
const DAEMON_STOP_TIMEOUT: Duration = Duration::from_secs(15);
/// How long the demo waits, after the last frame, for imulogd's writer to catch up.
const DAEMON_DRAIN_TIMEOUT: Duration = Duration::from_secs(120);
/// Outages of the replay: 30 s every 120 s.
const REPLAY_OUTAGES: &str = "every:120:30";
/// Title of the demo's report page.
const REPORT_TITLE: &str = "imulab demo: two bench IMUs in a 25 °C chamber";

/// The drive of the replay and the study (both bench IMUs, a 10 Hz standalone receiver).
const DRIVE_SCENE: &str = crate::study::grades::REFERENCE_DRIVE;
const STUDY_REQUIREMENTS_M: [f64; 2] = crate::study::grades::FIT_STUDY_REQUIREMENTS_M;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  imulab demo\n  imulab demo --minutes 360 --speed 60 --out /tmp/imulab-demo\n  imulab demo --minutes 3 --speed max"
)]
pub struct DemoArgs {
    /// Length of the simulated chamber run, minutes (360 reproduces the full six-hour run).
    #[arg(long, default_value_t = 30.0)]
    pub minutes: f64,
    /// Serving speed: simulated seconds per wall-clock second (1 = real time), or `max`
    /// (as fast as imulogd reads).
    #[arg(long, default_value = "20")]
    pub speed: Speed,
    /// Output directory (created; must not hold a previous demo's session). Default: a new
    /// `imulab-demo-<UTC date>-<time>` in the system's temporary directory, printed first.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Seed of the simulated sensors.
    #[arg(long, value_parser = clap::value_parser!(u64).range(0..=i64::MAX as u64))]
    pub seed: Option<u64>,
    /// Monte Carlo runs per IMU of the sensor-grade study.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub runs: u64,
}

/// Parses one subcommand's arguments exactly as the command line would.
#[derive(Parser)]
struct Sub<T: clap::Args> {
    #[command(flatten)]
    args: T,
}

fn sub_args<T: clap::Args>(argv: &[&str]) -> anyhow::Result<T> {
    Ok(Sub::<T>::try_parse_from(std::iter::once("imulab").chain(argv.iter().copied()))?.args)
}

/// Where the demo writes.
struct Paths {
    out: PathBuf,
    scene: PathBuf,
    config: PathBuf,
    status: PathBuf,
    log: PathBuf,
    links: PathBuf,
    session: PathBuf,
    serve_report: PathBuf,
    html: PathBuf,
    json: PathBuf,
    drive_scene: PathBuf,
    drive: PathBuf,
    study: PathBuf,
}

impl Paths {
    fn new(out: &Path) -> Self {
        Paths {
            out: out.to_path_buf(),
            scene: out.join("chamber.toml"),
            config: out.join("imulogd.toml"),
            status: out.join("imulogd-status.json"),
            log: out.join("imulogd.log"),
            links: out.join("dev"),
            session: out.join("session"),
            serve_report: out.join("served.json"),
            html: out.join("report.html"),
            json: out.join("report.json"),
            drive_scene: out.join("drive.toml"),
            drive: out.join("drive"),
            study: out.join("study.json"),
        }
    }
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    if !(args.minutes.is_finite() && (1.0..=7.0 * 24.0 * 60.0).contains(&args.minutes)) {
        bail!(
            "--minutes {}: give 1 to 10080 (the Allan curve needs some length; 360 is the six-hour run)",
            args.minutes
        );
    }
    let chosen = args.out.is_some();
    let out = args.out.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!(
            "imulab-demo-{}",
            chrono::Utc::now().format("%Y%m%d-%H%M%S")
        ))
    });
    std::fs::create_dir_all(&out)
        .with_context(|| format!("cannot create the output directory {}", out.display()))?;
    let out = out
        .canonicalize()
        .with_context(|| format!("{}", out.display()))?;
    path_str(&out)?;
    if !chosen {
        eprintln!(
            "imulab demo: writing to {} (--out to choose)",
            out.display()
        );
    }
    let paths = Paths::new(&out);
    for p in [&paths.session, &paths.drive] {
        if p.exists() {
            bail!(
                "{} is left from an earlier demo: remove it or give another --out",
                p.display()
            );
        }
    }
    let imulogd = imulogd_binary()?;
    let started = Instant::now();
    let ui = Ui::new();

    ui.stage(
        1,
        &format!(
            "serving {} of the 25 °C chamber over ptys (cheap: WitMotion, dear: Xsens Xbus, 150 Hz; rx: UBX+NMEA, 10 Hz) at {}; imulogd logs them",
            minutes_text(args.minutes),
            speed_text(args.speed)
        ),
    );
    let scene = write_chamber_scene(&paths.scene, args.minutes * 60.0, args.seed)?;
    let logged = serve_and_log(&ui, &paths, scene, args.speed, &imulogd)?;

    ui.stage(2, "checking the session against what the simulator sent");
    let health = check_session(&paths.session, &logged.report)?;
    for line in &health.lines {
        println!("  {line}");
    }
    if !health.complete {
        bail!(
            "the session {} does not hold every row the simulator sent (see above; imulogd's log: {})",
            paths.session.display(),
            paths.log.display()
        );
    }

    ui.stage(
        3,
        "Allan deviation and noise-term fit of both IMUs (12 axes) on the devices' 150 Hz sample clock",
    );
    let report = analyse(&ui, &paths.session, &health.imus)?;
    std::fs::write(&paths.html, html_report(&report, REPORT_TITLE))
        .with_context(|| format!("writing {}", paths.html.display()))?;
    let file = std::fs::File::create(&paths.json)
        .with_context(|| format!("creating {}", paths.json.display()))?;
    serde_json::to_writer_pretty(std::io::BufWriter::new(file), &report)
        .with_context(|| format!("writing {}", paths.json.display()))?;
    let pngs = write_pngs(&report, &out)?;
    let axes: Vec<_> = report.axes.iter().collect();
    print!("{}", indent(&datasheet_table_text(&axes)));

    ui.stage(
        4,
        "fusion replay of a simulated 15 min drive, GNSS withheld 30 s every 120 s, filter tuned from each Allan fit",
    );
    let replays = replay_drive(&paths, args.seed)?;

    ui.stage(
        5,
        &format!(
            "sensor-grade study: {} runs per IMU of the drive, outages of 1-60 s, grades = the two Allan fits",
            args.runs
        ),
    );
    let study = study(&ui, &report, args.runs as usize)?;
    print!("{}", indent(&study.summary_text()));
    std::fs::write(&paths.study, serde_json::to_string_pretty(&study)?)
        .with_context(|| format!("writing {}", paths.study.display()))?;
    // The report's GNSS-outage headline becomes the study's filter-based answer.
    std::fs::write(
        &paths.html,
        html_report_with_study(&report, REPORT_TITLE, &study),
    )
    .with_context(|| format!("writing {}", paths.html.display()))?;

    println!();
    println!("session  {}", paths.session.display());
    println!("report   {}", paths.html.display());
    println!("json     {}", paths.json.display());
    println!(
        "also     {} plots {}; imulogd config {}; replays {}; study {}",
        pngs.len(),
        out.join("report-*.png").display(),
        paths.config.display(),
        paths.drive.join("replay-*").display(),
        paths.study.display(),
    );
    println!(
        "         (the demo took {:.0} s)",
        started.elapsed().as_secs_f64()
    );
    println!();
    println!("Findings:");
    println!("1. {}", noise_finding(&report));
    println!("2. {}", bridging_finding(&study, &replays));
    println!("3. {}", health.summary);
    Ok(())
}

// --- Output ------------------------------------------------------------------------------

/// Stage lines and progress bars (bars only when stderr is a terminal).
struct Ui {
    terminal: bool,
}

impl Ui {
    fn new() -> Self {
        Ui {
            terminal: std::io::stderr().is_terminal(),
        }
    }

    fn stage(&self, n: u32, what: &str) {
        eprintln!("[{n}/{STAGES}] {what}");
    }

    /// A bar of `total` steps, or a hidden one off a terminal.
    fn bar(&self, total: u64, unit: &str) -> indicatif::ProgressBar {
        if !self.terminal {
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new(total);
        if let Ok(style) = indicatif::ProgressStyle::with_template(&format!(
            "      {{elapsed_precise}} [{{bar:30}}] {{pos}}/{{len}} {unit} {{msg}}"
        )) {
            bar.set_style(style);
        }
        bar
    }

    fn spinner(&self, what: &str) -> indicatif::ProgressBar {
        if !self.terminal {
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new_spinner();
        bar.set_message(what.to_string());
        bar.enable_steady_tick(Duration::from_millis(200));
        bar
    }

    /// A plain progress line off a terminal.
    fn plain(&self, line: &str) {
        if !self.terminal {
            eprintln!("      {line}");
        }
    }
}

fn indent(text: &str) -> String {
    text.lines().map(|l| format!("  {l}\n")).collect()
}

fn minutes_text(minutes: f64) -> String {
    if minutes >= 120.0 {
        format!("{:.1} h", minutes / 60.0)
    } else {
        format!("{minutes} min")
    }
}

fn speed_text(speed: Speed) -> String {
    match speed {
        Speed::Factor(1.0) => "real time".to_string(),
        Speed::Factor(f) => format!("{f}× real time"),
        Speed::Max => "the highest speed imulogd keeps up with".to_string(),
    }
}

fn path_str(p: &Path) -> anyhow::Result<&str> {
    p.to_str()
        .with_context(|| format!("{}: the demo needs a UTF-8 path", p.display()))
}

// --- Stage 1: serve and log ------------------------------------------------------------

/// `imulogd` next to the running binary (the same binary as in production).
fn imulogd_binary() -> anyhow::Result<PathBuf> {
    let exe = std::env::current_exe().context("cannot find the running imulab binary")?;
    let path = exe.with_file_name("imulogd");
    if !path.is_file() {
        bail!(
            "{} not found: the demo runs the imulogd binary next to imulab; build both with `cargo build --release --bins`",
            path.display()
        );
    }
    Ok(path)
}

/// Writes the chamber scene the demo serves and loads it back.
fn write_chamber_scene(path: &Path, duration_s: f64, seed: Option<u64>) -> anyhow::Result<Scene> {
    let mut scene: toml::Table = CHAMBER_SCENE.parse().context("the built-in scene")?;
    scene.insert("duration_s".into(), toml::Value::Float(duration_s));
    if let Some(seed) = seed {
        scene.insert("seed".into(), toml::Value::Integer(seed as i64));
    }
    // Only the device streams are served: no truth.
    scene.remove("outputs");
    if let Some(toml::Value::Array(imus)) = scene.get_mut("imu") {
        for imu in imus.iter_mut() {
            if let toml::Value::Table(t) = imu {
                let protocol = match t.get("name").and_then(|n| n.as_str()) {
                    Some("dear") => "xbus",
                    _ => "wit",
                };
                t.insert("protocol".into(), protocol.into());
            }
        }
    }
    let mut rx = toml::Table::new();
    rx.insert("name".into(), "rx".into());
    rx.insert("preset".into(), "standalone".into());
    rx.insert("rate_hz".into(), toml::Value::Float(GNSS_HZ));
    rx.insert("protocol".into(), "gnss".into());
    scene.insert("gnss".into(), toml::Value::Array(vec![rx.into()]));
    let text = format!(
        "# The bench scene `imulab demo` serves: {:.0} minutes of the chamber run\n\
         # (fixtures/scenes/chamber_6h.toml) with each IMU's wire protocol and a GNSS receiver.\n{}",
        duration_s / 60.0,
        toml::to_string(&scene)?
    );
    std::fs::write(path, &text).with_context(|| format!("writing {}", path.display()))?;
    let scene = Scene::load(path)?;
    if scene.rate_hz != IMU_HZ {
        bail!(
            "the built-in chamber scene runs at {} Hz, the demo expects {IMU_HZ} Hz",
            scene.rate_hz
        );
    }
    Ok(scene)
}

/// The imulogd configuration for the served endpoints, in the production format.
fn imulogd_config(paths: &Paths, server: &Server, link_factor: f64) -> anyhow::Result<String> {
    let mut session = toml::Table::new();
    session.insert("output_dir".into(), path_str(&paths.out)?.into());
    session.insert("name".into(), "session".into());
    session.insert("flush_interval_ms".into(), 1000.into());
    session.insert("status_file".into(), path_str(&paths.status)?.into());
    // The default (1024 batches) is sized for the devices' own rates; an accelerated serve
    // delivers as many batches per second as the speed factor times more.
    session.insert(
        "queue_capacity".into(),
        ((1024.0 * link_factor).min(65536.0) as i64).into(),
    );
    let mut devices = Vec::new();
    for e in server.endpoints() {
        let mut serial = toml::Table::new();
        serial.insert("port".into(), path_str(e.path())?.into());
        let gnss = e.protocol.is_gnss();
        serial.insert("baud".into(), (if gnss { 115_200 } else { 921_600 }).into());
        let mut d = toml::Table::new();
        d.insert("name".into(), e.sensor.clone().into());
        d.insert("protocol".into(), e.protocol.name().into());
        d.insert(
            "rate_hz".into(),
            toml::Value::Float(link_factor * if gnss { GNSS_HZ } else { IMU_HZ }),
        );
        d.insert("retry_initial_ms".into(), 100.into());
        d.insert("serial".into(), serial.into());
        devices.push(toml::Value::Table(d));
    }
    let mut config = toml::Table::new();
    config.insert("session".into(), session.into());
    config.insert("device".into(), devices.into());
    Ok(format!(
        "# imulogd configuration written by `imulab demo` (the format of a bench PC's\n\
         # /etc/imulogd/imulogd.toml, see docs/daemon.md). The ports are links to the ptys the\n\
         # simulator serves. rate_hz is the rate the link carries: the devices' own (150 Hz,\n\
         # 10 Hz) × {link_factor}, the serve's speed; it sizes the store's chunks (one flush\n\
         # interval each) and the gap detector, and the arrival stamps are as compressed.\n{}",
        toml::to_string(&config)?
    ))
}

/// What stage 1 produced.
struct Logged {
    report: ServeReport,
}

/// The running daemon; killed if the demo fails before stopping it.
struct Daemon {
    child: Option<Child>,
}

impl Daemon {
    fn pid(&self) -> Option<nix::unistd::Pid> {
        self.child
            .as_ref()
            .map(|c| nix::unistd::Pid::from_raw(c.id() as i32))
    }

    /// The exit status if the daemon has exited.
    fn exited(&mut self) -> anyhow::Result<Option<std::process::ExitStatus>> {
        match &mut self.child {
            Some(c) => Ok(c.try_wait().context("waiting for imulogd")?),
            None => Ok(None),
        }
    }

    /// SIGTERM, then waits for the exit status.
    fn stop(&mut self) -> anyhow::Result<std::process::ExitStatus> {
        if let Some(pid) = self.pid() {
            if self.exited()?.is_none() {
                nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM)
                    .context("cannot send SIGTERM to imulogd")?;
            }
        }
        let t = Instant::now();
        loop {
            if let Some(status) = self.exited()? {
                self.child = None;
                return Ok(status);
            }
            if t.elapsed() > DAEMON_STOP_TIMEOUT {
                bail!(
                    "imulogd did not exit within {} s of SIGTERM",
                    DAEMON_STOP_TIMEOUT.as_secs()
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if let Some(c) = &mut self.child {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn log_tail(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(5)..].join("\n")
}

/// Serves the chamber scene to an imulogd child process; returns the server's report.
fn serve_and_log(
    ui: &Ui,
    paths: &Paths,
    scene: Scene,
    speed: Speed,
    imulogd: &Path,
) -> anyhow::Result<Logged> {
    // Rows the session will hold: one per IMU sample, one per mixed GNSS epoch.
    let expected_rows = (scene.duration_s * scene.rate_hz).round() as u64 * scene.imus.len() as u64
        + (scene.duration_s * GNSS_HZ).round() as u64 * scene.gnss.len() as u64;
    // How much faster than the devices' own rates the link runs (`max`: taken as 100×).
    let link_factor = match speed {
        Speed::Factor(f) => f.max(1.0),
        Speed::Max => 100.0,
    };
    let mut server = Server::start(
        scene,
        ServeOptions {
            speed,
            link_dir: Some(paths.links.clone()),
            start: StartWhen::OnDemand,
            // Counts are enough (frames per device); the rows are checked by count and clock.
            record_sent: false,
            faults: Vec::new(),
        },
    )?;
    std::fs::write(&paths.config, imulogd_config(paths, &server, link_factor)?)
        .with_context(|| format!("writing {}", paths.config.display()))?;
    let _ = std::fs::remove_file(&paths.status);
    let log = std::fs::File::create(&paths.log)
        .with_context(|| format!("creating {}", paths.log.display()))?;
    println!(
        "  imulogd --config {} (log: {})",
        paths.config.display(),
        paths.log.display()
    );
    let child = Command::new(imulogd)
        .arg("--config")
        .arg(&paths.config)
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(log.try_clone().context("imulogd log")?)
        .stderr(log)
        .spawn()
        .with_context(|| format!("cannot start {}", imulogd.display()))?;
    let mut daemon = Daemon { child: Some(child) };
    let failed = |daemon: &mut Daemon, what: &str| -> anyhow::Error {
        let status = daemon.exited().ok().flatten();
        anyhow::anyhow!(
            "{what}{}; imulogd's log {} ends with:\n{}",
            status
                .map(|s| format!(" (imulogd exited: {s})"))
                .unwrap_or_default(),
            paths.log.display(),
            log_tail(&paths.log)
        )
    };

    // Serve once imulogd has every device open, so no frame goes out before a reader.
    let t = Instant::now();
    loop {
        if daemon.exited()?.is_some() {
            return Err(failed(
                &mut daemon,
                "imulogd stopped before opening the ptys",
            ));
        }
        let open = read_status_file(&paths.status).is_ok_and(|s| {
            s.devices.len() == server.endpoints().len()
                && s.devices.iter().all(|d| d.state == DeviceState::Connected)
        });
        if open {
            break;
        }
        if t.elapsed() > DAEMON_START_TIMEOUT {
            return Err(failed(
                &mut daemon,
                &format!(
                    "imulogd did not open the ptys within {} s",
                    DAEMON_START_TIMEOUT.as_secs()
                ),
            ));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    server.begin();
    let bar = ui.bar(expected_rows, "rows logged");
    let mut next_plain = 0.25;
    while !server.is_finished() {
        if daemon.exited()?.is_some() {
            return Err(failed(&mut daemon, "imulogd stopped while logging"));
        }
        if let Ok(s) = read_status_file(&paths.status) {
            bar.set_position(s.rows_written.min(expected_rows));
            let done = s.rows_written as f64 / expected_rows.max(1) as f64;
            if done >= next_plain && next_plain < 1.0 {
                ui.plain(&format!(
                    "{:.0} % of {expected_rows} rows logged",
                    100.0 * next_plain
                ));
                next_plain += 0.25;
            }
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let report = server.finish()?;
    // Let imulogd read the last bytes and its writer catch up (every device idle and the
    // rows written unchanged between two status reports), then stop it while the ptys are
    // still open: SIGTERM then only has to close the session.
    let sent_rows: u64 = report.streams.iter().map(|s| s.frames).sum();
    let t = Instant::now();
    let mut previous: Option<(String, u64)> = None;
    loop {
        if daemon.exited()?.is_some() {
            return Err(failed(&mut daemon, "imulogd stopped while logging"));
        }
        if let Ok(s) = read_status_file(&paths.status) {
            bar.set_position(s.rows_written.min(expected_rows));
            let idle = s
                .devices
                .iter()
                .all(|d| d.last_sample_age_s.is_some_and(|a| a >= 0.5));
            let settled = previous
                .as_ref()
                .is_some_and(|(at, rows)| *at != s.written_at && *rows == s.rows_written);
            if idle && (settled || s.rows_written >= sent_rows) {
                break;
            }
            if previous.as_ref().is_none_or(|(at, _)| *at != s.written_at) {
                previous = Some((s.written_at.clone(), s.rows_written));
            }
        }
        if t.elapsed() > DAEMON_DRAIN_TIMEOUT {
            ui.plain("imulogd's writer has not caught up; stopping it anyway");
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    bar.finish_and_clear();
    let status = daemon.stop()?;
    drop(server);
    if !status.success() {
        bail!(
            "imulogd exited with {status} after SIGTERM (expected 0); its log {} ends with:\n{}",
            paths.log.display(),
            log_tail(&paths.log)
        );
    }
    let served: Vec<serde_json::Value> = report
        .streams
        .iter()
        .map(|s| {
            serde_json::json!({
                "sensor": s.sensor, "protocol": s.protocol.name(), "frames": s.frames,
                "bytes": s.bytes, "frames_overflowed": s.frames_overflowed,
                "encode_errors": s.encode_errors,
            })
        })
        .collect();
    std::fs::write(
        &paths.serve_report,
        serde_json::to_string_pretty(&serde_json::json!({
            "elapsed_s": report.elapsed.as_secs_f64(),
            "scene_end_s": report.scene_end_s,
            "undelivered_bytes": report.undelivered_bytes,
            "streams": served,
        }))?,
    )
    .with_context(|| format!("writing {}", paths.serve_report.display()))?;
    println!(
        "  served {:.0} s of scene in {:.1} s; imulogd exited 0 after SIGTERM",
        report.scene_end_s,
        report.elapsed.as_secs_f64()
    );
    Ok(Logged { report })
}

// --- Stage 2: check the session ------------------------------------------------------------

/// What the session check found.
struct Health {
    /// Every row sent is logged (and nothing else).
    complete: bool,
    /// The IMU devices, in serve order.
    imus: Vec<String>,
    /// Per device and for the events, one line each.
    lines: Vec<String>,
    /// One line for the findings.
    summary: String,
}

/// Counts of a device's clock: intervals longer than 1.5 sample periods, and the span, s.
fn device_clock(session: &Session, device: &str) -> anyhow::Result<(u64, f64)> {
    let period = 1.0 / IMU_HZ;
    let mut last: Option<f64> = None;
    let (mut first, mut end) = (None, 0.0);
    let mut jumps = 0u64;
    for block in session.imu_blocks(device, TimeRange::all(), 1 << 16)? {
        let block = block.with_context(|| format!("reading {device}"))?;
        for &t in &block.t_sensor {
            if let Some(prev) = last {
                if !(t - prev > 0.0 && t - prev < 1.5 * period) {
                    jumps += 1;
                }
            }
            first.get_or_insert(t);
            end = t;
            last = Some(t);
        }
    }
    Ok((jumps, first.map_or(0.0, |f| end - f)))
}

fn check_session(dir: &Path, report: &ServeReport) -> anyhow::Result<Health> {
    let session = Session::open(dir)?;
    let mut lines = Vec::new();
    let mut complete = session.problems().is_empty();
    for p in session.problems() {
        lines.push(format!("problem: {p}"));
    }
    let mut imus = Vec::new();
    let mut counts = Vec::new();
    let mut clock_jumps = 0;
    let mut total_rows = 0;
    for s in &report.streams {
        let gnss = s.protocol.is_gnss();
        let group = if gnss {
            crate::store::layout::gnss_path(&s.sensor)
        } else {
            crate::store::layout::imu_path(&s.sensor)
        };
        let rows = session.stream_summary(&group).rows;
        let expected = s.frames;
        let lost = s.frames_overflowed + s.frames_unplugged + s.encode_errors;
        let ok = rows == expected && lost == 0;
        complete &= ok;
        total_rows += rows;
        let mut line = format!(
            "{:<6} {:<5} sent {} frames ({} bytes) → {} rows expected, {} logged{}",
            s.sensor,
            s.protocol.name(),
            s.frames,
            s.bytes,
            expected,
            rows,
            if ok { " ✓" } else { "  MISMATCH" }
        );
        if lost > 0 {
            line.push_str(&format!(
                "; not delivered by the server: {} overflowed, {} unplugged, {} encode errors",
                s.frames_overflowed, s.frames_unplugged, s.encode_errors
            ));
        }
        if !gnss {
            let (jumps, span) = device_clock(&session, &s.sensor)?;
            clock_jumps += jumps;
            line.push_str(&format!(
                "; device clock {span:.1} s for {rows} samples at {IMU_HZ} Hz ({:.1} s), {jumps} jumps",
                rows.saturating_sub(1) as f64 / IMU_HZ
            ));
            complete &= jumps == 0;
            imus.push(s.sensor.clone());
        }
        counts.push(format!("{} {}", s.sensor, rows));
        lines.push(line);
    }
    if report.undelivered_bytes > 0 {
        complete = false;
        lines.push(format!(
            "{} bytes were never read from the ptys",
            report.undelivered_bytes
        ));
    }
    let (events, problems) = session.events();
    lines.extend(problems.iter().map(|p| format!("events: {p}")));
    let count = |k: EventKind| events.iter().filter(|e| e.kind == k).count();
    let (resyncs, checksums, overflows, disconnects, gaps) = (
        count(EventKind::Resync),
        count(EventKind::ChecksumError),
        count(EventKind::QueueOverflow),
        count(EventKind::Disconnect),
        count(EventKind::Gap),
    );
    lines.push(format!(
        "imulogd events: {resyncs} resyncs, {checksums} checksum errors, {overflows} queue overflows, {disconnects} disconnects, {gaps} arrival pauses ≥ 50 ms{}",
        if gaps > 0 && clock_jumps == 0 {
            " (host-side pauses: the device clocks above show no sample missing)"
        } else {
            ""
        }
    ));
    let summary = format!(
        "Data health: {} rows the simulator sent, {} logged ({}); device clocks {}; {resyncs} resyncs, {checksums} checksum errors, {overflows} queue overflows; imulogd exited 0 on SIGTERM.",
        report
            .streams
            .iter()
            .map(|s| s.frames)
            .sum::<u64>(),
        if complete {
            "all".to_string()
        } else {
            total_rows.to_string()
        },
        counts.join(", "),
        if clock_jumps == 0 {
            "continuous".to_string()
        } else {
            format!("jump {clock_jumps} times")
        }
    );
    Ok(Health {
        complete,
        imus,
        lines,
        summary,
    })
}

// --- Stage 3: Allan report ---------------------------------------------------------------

/// OADEV on the octave grid with the noise fit, per device and axis, on the sample clock.
fn analyse(ui: &Ui, session: &Path, devices: &[String]) -> anyhow::Result<AllanReport> {
    let bar = ui.bar(6 * devices.len() as u64, "axes");
    let mut axes = Vec::new();
    for device in devices {
        let source = SessionSource::open(session, Some(device), None, None)?;
        let channels: Vec<usize> = [
            "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z",
        ]
        .iter()
        .map(|c| source.channel_index(c))
        .collect::<Result<_, _>>()?;
        let temp = source.channel_index("temp")?;
        let series = read_axes(
            &source,
            &channels,
            &Timing::Rate(IMU_HZ),
            GapPolicy::Error,
            DataKind::Rate,
            Some(temp),
        )
        .with_context(|| format!("reading {device} from {}", session.display()))?;
        let jobs: Vec<_> = series
            .into_iter()
            .zip(&channels)
            .map(|(mut s, &c)| {
                // Health keeps the temperature range; the samples are not needed further.
                s.temperature = None;
                let unit = source
                    .channel_unit(c)
                    .context("a session channel without a unit")?;
                Ok((
                    s,
                    AnalysisOptions {
                        kind: DeviationKind::Oadev,
                        grid: TauGrid::Octave,
                        fit: true,
                        unit,
                        sensor: unit.sensor(),
                    },
                ))
            })
            .collect::<anyhow::Result<_>>()?;
        let results: Vec<_> = jobs
            .into_par_iter()
            .map(|(s, o)| {
                let r = analyse_axis(device, s, &o);
                bar.inc(1);
                r
            })
            .collect();
        ui.plain(&format!("{device}: 6 axes analysed"));
        axes.extend(results);
    }
    bar.finish_and_clear();
    Ok(AllanReport::new(
        vec![format!("{} (sample clock {IMU_HZ} Hz)", session.display())],
        DeviationKind::Oadev,
        "octave",
        axes,
    ))
}

/// The report's plots as PNG files `report-<group>.png` in `out`.
fn write_pngs(report: &AllanReport, out: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for (title, axes) in plot_groups(report) {
        let name: String = title
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
            .collect();
        let path = out.join(format!("report-{name}.png"));
        write_png_axes(&axes, &title, &path)
            .with_context(|| format!("writing {}", path.display()))?;
        written.push(path);
    }
    Ok(written)
}

/// Mean over a device's axes of the named term in `unit`.
fn mean_term(
    report: &AllanReport,
    device: &str,
    sensor: &str,
    name: &str,
    unit: &str,
) -> Option<f64> {
    let values: Vec<f64> = report
        .axes
        .iter()
        .filter(|a| a.device == device && a.axis.starts_with(sensor))
        .filter_map(|a| {
            a.terms
                .iter()
                .find(|t: &&TermInUnits| t.name == name && t.identified)
        })
        .filter_map(|t| t.values.iter().find(|v| v.unit == unit))
        .filter_map(|v| v.value)
        .collect();
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

/// Which IMU is better and by how much, on the four headline terms (means over axes).
fn noise_finding(report: &AllanReport) -> String {
    let mut devices: Vec<&str> = report.axes.iter().map(|a| a.device.as_str()).collect();
    devices.dedup();
    let [a, b] = devices[..] else {
        return format!("{} IMUs analysed; nothing to compare", devices.len());
    };
    let rows = [
        ("accel", "VRW", "mg/sqrt(Hz)", "VRW", "mg/√Hz"),
        ("gyro", "ARW", "deg/sqrt(h)", "ARW", "°/√h"),
        (
            "accel",
            "bias instability",
            "mg",
            "accel bias instability",
            "mg",
        ),
        (
            "gyro",
            "bias instability",
            "deg/h",
            "gyro bias instability",
            "°/h",
        ),
    ];
    let mut wins = [0usize; 2];
    let mut parts = Vec::new();
    for (sensor, name, unit, label, shown) in rows {
        let (Some(va), Some(vb)) = (
            mean_term(report, a, sensor, name, unit),
            mean_term(report, b, sensor, name, unit),
        ) else {
            parts.push(format!("{label} not identified on both"));
            continue;
        };
        let (best, ratio) = if va <= vb { (0, vb / va) } else { (1, va / vb) };
        wins[best] += 1;
        parts.push(format!(
            "{label} {:.2}× lower on {} ({a} {va:.3}, {b} {vb:.3} {shown})",
            ratio,
            [a, b][best]
        ));
    }
    let better = if wins[1] > wins[0] { b } else { a };
    format!(
        "{better} is the better IMU ({} of {} terms): {}.",
        wins[0].max(wins[1]),
        wins[0] + wins[1],
        parts.join("; ")
    )
}

// --- Stage 4: replay ---------------------------------------------------------------------

/// The largest horizontal drift over the replay's outages, per IMU.
struct ReplayResult {
    device: String,
    max_drift_m: Option<f64>,
    mean_drift_m: Option<f64>,
    outages: usize,
}

fn replay_drive(paths: &Paths, seed: Option<u64>) -> anyhow::Result<Vec<ReplayResult>> {
    std::fs::write(&paths.drive_scene, DRIVE_SCENE)
        .with_context(|| format!("writing {}", paths.drive_scene.display()))?;
    let (scene_s, drive_s, json_s) = (
        path_str(&paths.drive_scene)?,
        path_str(&paths.drive)?,
        path_str(&paths.json)?,
    );
    let seed = seed.map(|s| s.to_string());
    let mut sim = vec![scene_s, "-o", drive_s];
    if let Some(seed) = &seed {
        sim.extend(["--seed", seed.as_str()]);
    }
    super::sim::run(sub_args(&sim)?)?;
    let mut results = Vec::new();
    for device in ["cheap", "dear"] {
        let out = paths.drive.join(format!("replay-{device}"));
        let noise = format!("{json_s}#{device}");
        let out_s = path_str(&out)?;
        println!("  -- {device}:");
        super::replay::run(sub_args(&[
            drive_s,
            "--imu",
            device,
            "--outages",
            REPLAY_OUTAGES,
            "--noise",
            &noise,
            "--name",
            device,
            "--out",
            out_s,
        ])?)?;
        let errors: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("errors.json"))
                .with_context(|| format!("reading {}/errors.json", out.display()))?,
        )?;
        let outages = errors["filtered"]["outages"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        let drifts: Vec<f64> = outages
            .iter()
            .filter_map(|o| o["max_horizontal_m"].as_f64())
            .collect();
        results.push(ReplayResult {
            device: device.to_string(),
            max_drift_m: drifts.iter().copied().reduce(f64::max),
            mean_drift_m: (!drifts.is_empty())
                .then(|| drifts.iter().sum::<f64>() / drifts.len() as f64),
            outages: outages.len(),
        });
    }
    Ok(results)
}

// --- Stage 5: study ----------------------------------------------------------------------

fn study(ui: &Ui, report: &AllanReport, runs: usize) -> anyhow::Result<StudyResult> {
    let spinner = ui.spinner(&format!("{} simulated drives and replays", 2 * runs));
    let result = fit_study(report, &["cheap", "dear"], runs, false);
    spinner.finish_and_clear();
    let result = result?;
    for g in &result.grades {
        for w in &g.warnings {
            println!("  note: {w}");
        }
    }
    Ok(result)
}

/// What the study and the replays say about outage bridging.
fn bridging_finding(study: &StudyResult, replays: &[ReplayResult]) -> String {
    let mut parts = Vec::new();
    for (k, req) in STUDY_REQUIREMENTS_M.iter().enumerate() {
        let per: Vec<String> = study
            .grades
            .iter()
            .map(|g| {
                let name = g.name.rsplit('#').next().unwrap_or(&g.name);
                match g.bridges.get(k) {
                    Some(b) => format!("{name} {}", b.text()),
                    None => format!("{name} n/a"),
                }
            })
            .collect();
        parts.push(format!("within {req} m {}", per.join(", ")));
    }
    let replay: Vec<String> = replays
        .iter()
        .map(|r| match (r.mean_drift_m, r.max_drift_m) {
            (Some(mean), Some(max)) => format!("{} {mean:.2} m (worst {max:.2} m)", r.device),
            _ => format!("{} n/a", r.device),
        })
        .collect();
    format!(
        "Outage bridging (study, p95 of {} outages per IMU): {}. In the drive replay, {} outages of 30 s drifted on average {}.",
        study
            .grades
            .first()
            .and_then(|g| g.lengths.first())
            .map_or(0, |l| l.count),
        parts.join("; "),
        replays.first().map_or(0, |r| r.outages),
        replay.join(", ")
    )
}
