//! The `pty` mode of the daemon load benchmark: the simulator serves the bench (two IMUs at
//! 150 Hz, a 10 Hz GNSS receiver) on ptys at `--speed` times real time, the `imulogd`
//! binary logs it as a separate process, and the daemon is watched from outside
//! (`/proc/PID/stat` and `/proc/PID/status`). See the header of `daemon_load.rs`.
//!
//! For soaks: `--rotate-min M` rotates every M simulated minutes (the daemon rotates by its
//! own clock, so the configuration gets M / speed), and `--curve FILE.csv` also records
//! RssAnon and the number of finished chunk files at every sample.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use super::awake::KeepAwake;
use super::common::daemon::connected_report;
use super::report::{
    loadavg, proc_cpu_s, proc_status_mib, self_cpu_s, set_nice, thread_shares, thread_times, Load,
    Table,
};
use super::{parsed, positive_number};
use imulab::daemon::status::read_status_file;
use imulab::sim::scene::Scene;
use imulab::sim::serve::{Sent, ServeOptions, ServeReport, Server, Speed, StartWhen};
use imulab::store::{EventKind, Session};

const IMU_HZ: f64 = 150.0;
const GNSS_HZ: f64 = 10.0;
/// How long the daemon gets to read the last bytes after the simulator's last frame.
const DRAIN: Duration = Duration::from_secs(2);
/// SIGTERM must end the daemon within this (the issue asks for 2 s).
const STOP_LIMIT: Duration = Duration::from_secs(2);

struct Options {
    secs: f64,
    speeds: Vec<f64>,
    runs: usize,
    sample_s: f64,
    imulogd: PathBuf,
    curve: Option<PathBuf>,
    raw_journal: bool,
    nice: Option<i32>,
    /// `--rotate-min`: rotate every this many simulated minutes (None: the daemon default).
    rotate_sim_min: Option<f64>,
    /// `--keep-awake`: busy `SCHED_IDLE` threads keep the CPUs out of halt during the runs.
    keep_awake: bool,
}

fn parse_options(args: Vec<String>) -> Result<Options, String> {
    let mut o = Options {
        secs: 60.0,
        speeds: vec![100.0],
        runs: 1,
        sample_s: 5.0,
        imulogd: PathBuf::from(env!("CARGO_BIN_EXE_imulogd")),
        curve: None,
        raw_journal: false,
        nice: None,
        rotate_sim_min: None,
        keep_awake: false,
    };
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        let mut value = |name: &str| args.next().ok_or(format!("{name} needs a value"));
        match arg.as_str() {
            "--secs" => o.secs = positive_number("--secs", &value("--secs")?)?,
            "--sample-s" => o.sample_s = positive_number("--sample-s", &value("--sample-s")?)?,
            "--runs" => o.runs = parsed("--runs", &value("--runs")?)?,
            "--speed" => {
                o.speeds = value("--speed")?
                    .split(',')
                    .map(|v| positive_number("--speed", v))
                    .collect::<Result<_, _>>()?
            }
            "--imulogd" => o.imulogd = PathBuf::from(value("--imulogd")?),
            "--curve" => o.curve = Some(PathBuf::from(value("--curve")?)),
            "--raw-journal" => o.raw_journal = true,
            "--rotate-min" => {
                o.rotate_sim_min = Some(positive_number("--rotate-min", &value("--rotate-min")?)?)
            }
            "--nice" => o.nice = Some(parsed("--nice", &value("--nice")?)?),
            "--keep-awake" => o.keep_awake = true,
            "--bench" => {}
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    Ok(o)
}

/// The bench scene: `scene_s` seconds, static, two IMUs in two protocols and a mixed
/// UBX + NMEA receiver.
pub(super) fn scene(scene_s: f64) -> Scene {
    let text = format!(
        "duration_s = {scene_s}\nrate_hz = {IMU_HZ}\nseed = 7\n\
         [location]\nlat_deg = 48.1\nlon_deg = 11.6\nheight_m = 520.0\n\
         [motion]\nkind = \"static\"\n\
         [[imu]]\nname = \"wit\"\npreset = \"bench-cheap\"\nprotocol = \"wit\"\n\
         [[imu]]\nname = \"mti\"\npreset = \"industrial\"\nprotocol = \"xbus\"\n\
         [[gnss]]\nname = \"rx\"\npreset = \"standalone\"\nrate_hz = {GNSS_HZ}\nprotocol = \"gnss\"\n"
    );
    Scene::parse(&text, Path::new(".")).unwrap_or_else(|e| panic!("bench scene: {e:#}"))
}

/// One sample of the daemon from outside.
#[derive(Clone, Copy)]
struct Sample {
    wall_s: f64,
    cpu_s: f64,
    rss_mib: f64,
    /// RssAnon (heap and other private memory; RSS less mapped files and shmem).
    rss_anon_mib: f64,
    /// Completed chunk files in the session (rotations so far).
    chunk_files: usize,
}

/// One sample of daemon `pid` writing `session_dir`, `cpu_s` already measured.
fn take_sample(pid: u32, wall_s: f64, cpu_s: f64, session_dir: &Path) -> Sample {
    let status_mib = |key: &str| proc_status_mib(pid, key).unwrap_or(f64::NAN);
    Sample {
        wall_s,
        cpu_s,
        rss_mib: status_mib("VmRSS:"),
        rss_anon_mib: status_mib("RssAnon:"),
        chunk_files: std::fs::read_dir(session_dir).map_or(0, |d| {
            d.flatten()
                .filter(|e| e.file_name().to_string_lossy().ends_with(".h5"))
                .count()
        }),
    }
}

struct RunResult {
    speed: f64,
    scene_s: f64,
    serve_wall_s: f64,
    /// Daemon CPU over the serve (first frame to last frame), s.
    daemon_cpu_s: f64,
    /// This process (the simulator's threads) over the serve, s.
    server_cpu_s: f64,
    samples: Vec<Sample>,
    expected: u64,
    written: u64,
    dropped: u64,
    overflow_events: usize,
    server_overflowed: u64,
    undelivered: u64,
    frames_bad: u64,
    gaps: u64,
    exit: Option<i32>,
    stop_s: f64,
    session_mib: f64,
    load: Load,
    /// Per daemon thread over the serve: CPU % of one core and wake-ups a second.
    threads: String,
}

impl RunResult {
    fn held(&self) -> bool {
        self.exit == Some(0)
            && self.written == self.expected
            && self.dropped == 0
            && self.overflow_events == 0
            && self.server_overflowed == 0
            && self.undelivered == 0
            && self.frames_bad == 0
    }
}

fn dir_size(path: &Path) -> u64 {
    walk(path)
        .iter()
        .map(|p| p.metadata().map_or(0, |m| m.len()))
        .sum()
}

fn walk(path: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(entries) = std::fs::read_dir(path) {
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(walk(&p));
            } else {
                out.push(p);
            }
        }
    }
    out
}

fn start_daemon(imulogd: &Path, config: &Path, log: &Path) -> Child {
    let log = std::fs::File::create(log).expect("daemon log file");
    Command::new(imulogd)
        .arg("--config")
        .arg(config)
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", imulogd.display()))
}

fn wait_connected(status_path: &Path, child: &mut Child) {
    let t = Instant::now();
    while connected_report(status_path, 3).is_none() {
        if let Ok(Some(status)) = child.try_wait() {
            panic!("imulogd exited before opening the ptys: {status}");
        }
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "imulogd did not open the ptys within 20 s"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The `[session]` line for `--rotate-min` (simulated minutes, so wall minutes / speed:
/// rotation goes by the host clock), or nothing for the daemon's default.
fn rotation_line(o: &Options, speed: f64) -> String {
    o.rotate_sim_min
        .map(|m| format!("rotate_minutes = {}\n", m / speed))
        .unwrap_or_default()
}

fn one_run(o: &Options, speed: f64) -> RunResult {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene_s = o.secs * speed;
    let mut server = Server::start(
        scene(scene_s),
        ServeOptions {
            speed: Speed::Factor(speed),
            link_dir: Some(dir.path().join("dev")),
            start: StartWhen::OnDemand,
            // Hours of frames would not fit in memory: counts only.
            record_sent: false,
            faults: Vec::new(),
        },
    )
    .unwrap_or_else(|e| panic!("serve: {e:#}"));
    let mut devices = String::new();
    for e in server.endpoints() {
        // The configured rate sizes the store's chunks and the gap detector.
        let rate = speed * if e.sensor == "rx" { GNSS_HZ } else { IMU_HZ };
        devices.push_str(&format!(
            "[[device]]\nname = \"{}\"\nprotocol = \"{}\"\nrate_hz = {rate}\nserial = {{ port = \"{}\", baud = 921600 }}\n",
            e.sensor,
            e.protocol.name(),
            e.path().display()
        ));
    }
    let session_dir = dir.path().join("load");
    let status_path = dir.path().join("status.json");
    let config = dir.path().join("imulogd.toml");
    std::fs::write(
        &config,
        format!(
            "[session]\noutput_dir = \"{}\"\nname = \"load\"\nraw_journal = {}\nstatus_file = \"{}\"\n{}\n{devices}",
            dir.path().display(),
            o.raw_journal,
            status_path.display(),
            rotation_line(o, speed)
        ),
    )
    .expect("config");
    let mut child = start_daemon(&o.imulogd, &config, &dir.path().join("imulogd.log"));
    let pid = child.id();
    wait_connected(&status_path, &mut child);

    let load_before = loadavg();
    let cpu0 = proc_cpu_s(pid).unwrap_or(f64::NAN);
    let threads0 = thread_times(pid);
    let self0 = self_cpu_s();
    let t0 = Instant::now();
    server.begin();
    let mut samples = vec![take_sample(pid, 0.0, 0.0, &session_dir)];
    let mut next = o.sample_s;
    let deadline = Duration::from_secs_f64(o.secs * 3.0 + 60.0);
    while !server.is_finished() {
        assert!(t0.elapsed() < deadline, "the serve did not finish in time");
        if let Ok(Some(status)) = child.try_wait() {
            panic!("imulogd exited during the run: {status}");
        }
        let now = t0.elapsed().as_secs_f64();
        if now >= next {
            next += o.sample_s;
            let cpu_s = proc_cpu_s(pid).unwrap_or(f64::NAN) - cpu0;
            samples.push(take_sample(pid, now, cpu_s, &session_dir));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let report: ServeReport = server.finish().unwrap_or_else(|e| panic!("serve: {e:#}"));
    let serve_wall_s = t0.elapsed().as_secs_f64();
    let daemon_cpu_s = proc_cpu_s(pid).unwrap_or(f64::NAN) - cpu0;
    let threads = thread_shares(&threads0, &thread_times(pid), serve_wall_s);
    let server_cpu_s = self_cpu_s() - self0;
    samples.push(take_sample(pid, serve_wall_s, daemon_cpu_s, &session_dir));
    let load_after = loadavg();
    std::thread::sleep(DRAIN);
    // SAFETY: kill with a pid of our own child and a valid signal number.
    unsafe { libc::kill(pid as libc::pid_t, libc::SIGTERM) };
    let stop_t = Instant::now();
    let exit = loop {
        if let Ok(Some(status)) = child.try_wait() {
            break status.code();
        }
        if stop_t.elapsed() > Duration::from_secs(10) {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let stop_s = stop_t.elapsed().as_secs_f64();
    drop(server);
    if stop_s > STOP_LIMIT.as_secs_f64() {
        println!("  (SIGTERM took {stop_s:.2} s, over the 2 s limit)");
    }

    let status = read_status_file(&status_path).expect("final status");
    let session = Session::open(&session_dir).expect("session");
    let mut expected = 0;
    let mut written = 0;
    for stream in &report.streams {
        let (group, per_frame) = match stream.sent {
            Sent::Imu(_) => (format!("imu/{}", stream.sensor), 1),
            // The mixed receiver's UBX and NMEA messages of one epoch merge into one row.
            Sent::Gnss(_) => (format!("gnss/{}", stream.sensor), 1),
        };
        expected += stream.frames * per_frame;
        let summary = session.stream_summary(&group);
        assert!(summary.problems.is_empty(), "{:?}", summary.problems);
        written += summary.rows;
    }
    let (events, problems) = session.events();
    assert!(problems.is_empty(), "{problems:?}");
    RunResult {
        speed,
        scene_s: report.scene_end_s,
        serve_wall_s,
        daemon_cpu_s,
        server_cpu_s,
        samples,
        expected,
        written,
        dropped: status.devices.iter().map(|d| d.dropped_rows).sum(),
        overflow_events: events
            .iter()
            .filter(|e| e.kind == EventKind::QueueOverflow)
            .count(),
        server_overflowed: report.streams.iter().map(|s| s.frames_overflowed).sum(),
        undelivered: report.undelivered_bytes,
        frames_bad: status.devices.iter().map(|d| d.frames_bad).sum(),
        gaps: status.devices.iter().map(|d| d.gaps).sum(),
        exit,
        stop_s,
        session_mib: dir_size(&session_dir) as f64 / (1 << 20) as f64,
        load: Load {
            before: load_before,
            after: load_after,
        },
        threads,
    }
}

pub fn main(args: Vec<String>) {
    let given: Vec<String> = args.iter().filter(|a| *a != "--bench").cloned().collect();
    let o = match parse_options(args) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("daemon_load pty: {e}");
            std::process::exit(2);
        }
    };
    // Before any thread or child exists: the simulator's threads and the daemon inherit it
    // (on Linux the nice value is per thread).
    set_nice("pty", o.nice);
    println!("{}", super::report::platform());
    println!(
        "imulogd over ptys: simulator bench (wit + xbus at {IMU_HZ} Hz, mixed GNSS at {GNSS_HZ} Hz) × speed, {} s wall per run, raw journal {}, nice {}, keep-awake {}; daemon {}",
        o.secs,
        if o.raw_journal { "on" } else { "off" },
        o.nice.unwrap_or(0),
        if o.keep_awake { "on" } else { "off" },
        o.imulogd.display()
    );
    let _awake = KeepAwake::start_if(o.keep_awake, "pty");
    let table = Table {
        columns: &[
            ("speed", 6),
            ("run", 4),
            ("scene s", 9),
            ("wall s", 7),
            ("expected", 11),
            ("written", 11),
            ("dropped", 8),
            ("ovfl", 5),
            ("srv-ov", 6),
            ("bad", 5),
            ("gaps", 5),
            ("held", 7),
            ("d-CPU%", 8),
            ("CPU s/h", 8),
            ("sim%", 6),
            ("RSS MiB", 7),
        ],
    };
    table.header();
    let mut curve = o
        .curve
        .as_ref()
        .map(|p| std::fs::File::create(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())));
    if let Some(f) = curve.as_mut() {
        writeln!(
            f,
            "speed,run,wall_s,scene_h,daemon_cpu_s,rss_mib,rss_anon_mib,chunk_files"
        )
        .expect("curve");
    }
    let mut done: Vec<RunResult> = Vec::new();
    for &speed in &o.speeds {
        for run in 1..=o.runs {
            let r = one_run(&o, speed);
            let rss_max = r.samples.iter().map(|s| s.rss_mib).fold(f64::NAN, f64::max);
            table.row(
                &[
                    r.speed.to_string(),
                    run.to_string(),
                    format!("{:.0}", r.scene_s),
                    format!("{:.1}", r.serve_wall_s),
                    r.expected.to_string(),
                    r.written.to_string(),
                    r.dropped.to_string(),
                    r.overflow_events.to_string(),
                    r.server_overflowed.to_string(),
                    r.frames_bad.to_string(),
                    r.gaps.to_string(),
                    (if r.held() { "yes" } else { "NO" }).to_string(),
                    format!("{:.3}", 100.0 * r.daemon_cpu_s / r.serve_wall_s),
                    format!("{:.3}", r.daemon_cpu_s / (r.scene_s / 3600.0)),
                    format!("{:.1}", 100.0 * r.server_cpu_s / r.serve_wall_s),
                    format!("{rss_max:.1}"),
                ],
                &r.load,
            );
            table.detail(
                "session",
                &format!(
                    "{:.1} MiB, SIGTERM to exit {:.2} s (exit {:?}), pace: {:.0} s of scene in {:.1} s (×{:.1})",
                    r.session_mib,
                    r.stop_s,
                    r.exit,
                    r.scene_s,
                    r.serve_wall_s,
                    r.scene_s / r.serve_wall_s
                ),
            );
            let step = (r.samples.len() / 12).max(1);
            let shown: Vec<String> = r
                .samples
                .iter()
                .step_by(step)
                .map(|s| format!("{:.0}s:{:.1}", s.wall_s, s.rss_mib))
                .collect();
            table.detail("RSS MiB (wall s:MiB)", &shown.join(" "));
            table.detail("daemon threads (schedstat):", &r.threads);
            if let Some(f) = curve.as_mut() {
                for s in &r.samples {
                    writeln!(
                        f,
                        "{},{},{:.1},{:.4},{:.3},{:.2},{:.2},{}",
                        r.speed,
                        run,
                        s.wall_s,
                        s.wall_s * r.speed / 3600.0,
                        s.cpu_s,
                        s.rss_mib,
                        s.rss_anon_mib,
                        s.chunk_files
                    )
                    .expect("curve");
                }
            }
            done.push(r);
        }
    }
    write_results(&o, &done, &given);
}

/// The run's figures, and its BENCHMARKS.md row when it is one of the three the table has:
/// 1× (CPU), 100× (frames held), and a soak with rotation (RSS flat).
fn write_results(o: &Options, runs: &[RunResult], given: &[String]) {
    use super::results::{self, Row};
    use serde_json::json;
    let command = format!("cargo bench --bench daemon_load -- pty {}", given.join(" "));
    let figures = json!({ "runs": runs.iter().map(|r| {
        let rss: Vec<f64> = r.samples.iter().map(|s| s.rss_mib).collect();
        json!({
            "speed": r.speed, "scene_s": r.scene_s, "serve_wall_s": r.serve_wall_s,
            "daemon_cpu_s": r.daemon_cpu_s, "daemon_cpu_pct": 100.0 * r.daemon_cpu_s / r.serve_wall_s,
            "server_cpu_s": r.server_cpu_s, "expected": r.expected, "written": r.written,
            "dropped": r.dropped, "overflow_events": r.overflow_events,
            "server_overflowed": r.server_overflowed, "undelivered": r.undelivered,
            "frames_bad": r.frames_bad, "gaps": r.gaps, "exit": r.exit, "held": r.held(),
            "session_mib": r.session_mib, "load_before": r.load.before, "load_after": r.load.after,
            "rss_mib": rss,
        })
    }).collect::<Vec<_>>() });
    let args = json!({
        "secs": o.secs, "speeds": o.speeds, "runs": o.runs, "sample_s": o.sample_s,
        "raw_journal": o.raw_journal, "nice": o.nice, "rotate_sim_min": o.rotate_sim_min,
        "keep_awake": o.keep_awake, "imulogd": o.imulogd.display().to_string(),
    });
    let speed = match o.speeds[..] {
        [s] => s,
        _ => {
            results::write("daemon_load", "pty", args, figures, &[]);
            return;
        }
    };
    let held = runs.iter().all(RunResult::held);
    let minutes = o.secs / 60.0;
    let (row, mode) = if o.rotate_sim_min.is_some() {
        // Flat: the second half of the run peaks no more than 2 % above the first half.
        let flat = runs.iter().all(|r| {
            let half = r.samples.len() / 2;
            let peak = |v: &[Sample]| v.iter().map(|s| s.rss_mib).fold(f64::NAN, f64::max);
            peak(&r.samples[half..]) <= 1.02 * peak(&r.samples[..half])
        });
        let rss: Vec<f64> = runs
            .iter()
            .flat_map(|r| {
                r.samples
                    .iter()
                    .skip(r.samples.len() / 4)
                    .map(|s| s.rss_mib)
            })
            .collect();
        let (lo, hi) = results::min_max(&rss);
        let row = Row::new(
            "daemon-soak",
            results::ACQUISITION,
            11,
            "imulogd soak",
            "docs/bench/daemon.md",
        )
        .data(format!(
            "{:.0} sim. h at {speed}×, rotation",
            o.secs * speed / 3600.0
        ))
        .ours(format!(
            "RSS {} MiB after the first quarter, {}",
            results::range(lo, hi, 1),
            if flat { "flat" } else { "growing" }
        ))
        .target("flat")
        .met(flat && held)
        .command(command);
        (row, "pty-soak")
    } else if speed == 1.0 {
        let pct: Vec<f64> = runs
            .iter()
            .map(|r| 100.0 * r.daemon_cpu_s / r.serve_wall_s)
            .collect();
        let (lo, hi) = results::min_max(&pct);
        let ok = hi < 1.0;
        let row = Row::new(
            "daemon-1x",
            results::ACQUISITION,
            9,
            "imulogd at 1×",
            "docs/bench/daemon.md",
        )
        .data(format!("2 IMUs + GNSS on ptys, {:.0} s", o.secs))
        .ours(format!("{} % of a core", results::range(lo, hi, 2)))
        .target("< 1 %")
        .met_text(if ok { "yes" } else { "no (VM floor)" })
        .command(command);
        (row, "pty-1x")
    } else if speed >= 100.0 {
        let frames: u64 = runs.iter().map(|r| r.written).sum();
        let dropped: u64 = runs
            .iter()
            .map(|r| r.dropped + r.server_overflowed + r.undelivered)
            .sum();
        let row = Row::new(
            "daemon-100x",
            results::ACQUISITION,
            10,
            format!("imulogd at {speed}×").as_str(),
            "docs/bench/daemon.md",
        )
        .data(format!("same, {minutes:.0} min"))
        .ours(format!(
            "{:.1} M frames, {dropped} dropped",
            frames as f64 / 1e6
        ))
        .target(format!("{speed}×"))
        .met(held)
        .command(command);
        (row, "pty-100x")
    } else {
        results::write("daemon_load", "pty", args, figures, &[]);
        return;
    };
    results::write("daemon_load", mode, args, figures, &[row]);
}
