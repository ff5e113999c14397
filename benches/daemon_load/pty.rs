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

use super::common::daemon::connected_report;
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

/// utime + stime of a process, s; None once it is gone.
fn proc_cpu_s(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces) start after the last ')'.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of stat(5), i.e. 11 and 12 after the state.
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    Some(ticks / hz)
}

/// A kB line of `/proc/PID/status` (`key` with its colon, e.g. `VmRSS:`), in MiB.
fn proc_status_mib(pid: u32, key: &str) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with(key))?;
    Some(line.split_whitespace().nth(1)?.parse::<f64>().ok()? / 1024.0)
}

fn self_cpu_s() -> f64 {
    // SAFETY: getrusage writes into the zeroed struct we own.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return f64::NAN;
    }
    let t = |tv: libc::timeval| tv.tv_sec as f64 + tv.tv_usec as f64 * 1e-6;
    t(usage.ru_utime) + t(usage.ru_stime)
}

pub(super) fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "?".into())
}

/// Per thread of process `pid`: (tid, name, on-CPU ns, times scheduled in), from
/// `/proc/PID/task/TID/schedstat` (its first and third fields).
pub(super) fn thread_times(pid: u32) -> Vec<(u32, String, u64, u64)> {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for task in tasks.flatten() {
        let Some(tid) = task.file_name().to_str().and_then(|t| t.parse().ok()) else {
            continue;
        };
        let name = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
        let Ok(stat) = std::fs::read_to_string(task.path().join("schedstat")) else {
            continue;
        };
        let f: Vec<u64> = stat
            .split_whitespace()
            .filter_map(|v| v.parse().ok())
            .collect();
        if let (Some(&ns), Some(&runs)) = (f.first(), f.get(2)) {
            out.push((tid, name.trim().to_string(), ns, runs));
        }
    }
    out.sort();
    out
}

/// Each thread's share over a window: "name CPU % of one core, wake-ups a second".
fn thread_shares(
    before: &[(u32, String, u64, u64)],
    after: &[(u32, String, u64, u64)],
    wall_s: f64,
) -> String {
    after
        .iter()
        .map(|(tid, name, ns, runs)| {
            let (ns0, runs0) = before
                .iter()
                .find(|b| b.0 == *tid)
                .map_or((0, 0), |b| (b.2, b.3));
            format!(
                "{name}[{tid}] {:.3} % {:.0}/s",
                100.0 * ns.saturating_sub(ns0) as f64 * 1e-9 / wall_s,
                runs.saturating_sub(runs0) as f64 / wall_s
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
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
    load_before: String,
    load_after: String,
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
        load_before,
        load_after,
        threads,
    }
}

pub fn main(args: Vec<String>) {
    let o = match parse_options(args) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("daemon_load pty: {e}");
            std::process::exit(2);
        }
    };
    if let Some(nice) = o.nice {
        // Before any thread or child exists: the simulator's threads and the daemon inherit
        // it (on Linux the nice value is per thread).
        // SAFETY: setpriority has no memory preconditions.
        if unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, nice) } != 0 {
            eprintln!(
                "daemon_load pty: cannot set nice {nice}: {}",
                std::io::Error::last_os_error()
            );
            std::process::exit(2);
        }
    }
    println!(
        "imulogd over ptys: simulator bench (wit + xbus at {IMU_HZ} Hz, mixed GNSS at {GNSS_HZ} Hz) × speed, {} s wall per run, raw journal {}, nice {}; daemon {}",
        o.secs,
        if o.raw_journal { "on" } else { "off" },
        o.nice.unwrap_or(0),
        o.imulogd.display()
    );
    println!(
        "{:>6} {:>4} {:>9} {:>7} {:>11} {:>11} {:>8} {:>5} {:>6} {:>5} {:>5} {:>7} {:>8} {:>8} {:>6} {:>7}  load 1/5/15 min before → after",
        "speed", "run", "scene s", "wall s", "expected", "written", "dropped", "ovfl", "srv-ov", "bad", "gaps",
        "held", "d-CPU%", "CPU s/h", "sim%", "RSS MiB"
    );
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
    for &speed in &o.speeds {
        for run in 1..=o.runs {
            let r = one_run(&o, speed);
            let rss: Vec<f64> = r.samples.iter().map(|s| s.rss_mib).collect();
            let rss_max = rss.iter().copied().fold(f64::NAN, f64::max);
            println!(
                "{:>6} {:>4} {:>9.0} {:>7.1} {:>11} {:>11} {:>8} {:>5} {:>6} {:>5} {:>5} {:>7} {:>8.3} {:>8.3} {:>6.1} {:>7.1}  {} → {}",
                r.speed,
                run,
                r.scene_s,
                r.serve_wall_s,
                r.expected,
                r.written,
                r.dropped,
                r.overflow_events,
                r.server_overflowed,
                r.frames_bad,
                r.gaps,
                if r.held() { "yes" } else { "NO" },
                100.0 * r.daemon_cpu_s / r.serve_wall_s,
                r.daemon_cpu_s / (r.scene_s / 3600.0),
                100.0 * r.server_cpu_s / r.serve_wall_s,
                rss_max,
                r.load_before,
                r.load_after
            );
            println!(
                "       session {:.1} MiB, SIGTERM to exit {:.2} s (exit {:?}), pace: {:.0} s of scene in {:.1} s (×{:.1})",
                r.session_mib,
                r.stop_s,
                r.exit,
                r.scene_s,
                r.serve_wall_s,
                r.scene_s / r.serve_wall_s
            );
            let step = (r.samples.len() / 12).max(1);
            let shown: Vec<String> = r
                .samples
                .iter()
                .step_by(step)
                .map(|s| format!("{:.0}s:{:.1}", s.wall_s, s.rss_mib))
                .collect();
            println!("       RSS MiB (wall s:MiB) {}", shown.join(" "));
            println!("       daemon threads (schedstat): {}", r.threads);
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
        }
    }
}
