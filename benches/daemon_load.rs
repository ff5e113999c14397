//! imulogd load benchmark, two modes.
//!
//! **`pty` mode** (the issue's benchmark): the simulator serves two IMUs at 150 Hz
//! (WitMotion and Xsens Xbus) and a 10 Hz GNSS receiver (UBX and NMEA mixed) on ptys,
//! accelerated `--speed` times, and the real `imulogd` binary (a child process, started
//! from a generated configuration: the defaults, raw journal off unless asked) logs them
//! into an HDF5 session. Measured from outside: the daemon's CPU (utime + stime from
//! `/proc/PID/stat`) and RSS (`/proc/PID/status`) every `--sample-s` seconds; the simulator
//! side's CPU (this process) and whether it kept its pace; then, after SIGTERM, the rows in
//! the session (store reader) against the frames the simulator sent, the daemon's dropped
//! rows (status file) and `queue_overflow` events, and the simulator's overflows (a reader
//! that did not keep up). "held" = every frame sent is a row, nothing dropped on either
//! side, the daemon exited 0 after SIGTERM.
//!
//! `cargo bench --bench daemon_load -- pty [--secs S] [--speed F[,F...]] [--runs N]
//! [--sample-s S] [--imulogd PATH] [--curve FILE.csv] [--raw-journal] [--nice N]
//! [--keep-awake]`
//! (`--nice` sets the nice value of the simulator and the daemon, e.g. -10 to stand in for
//! a bench PC that runs nothing else; `--imulogd` compares another build; `--keep-awake`
//! keeps every CPU busy with `SCHED_IDLE` threads in a process of their own, so no vCPU
//! halts between frames: `daemon_load/awake.rs`.) Per daemon thread the schedstat line
//! gives CPU %, wake-ups a second and µs on a CPU per wake-up.
//!
//! **`floor` mode** (`daemon_load/floor.rs`): the same simulator and ptys read by minimal
//! readers (blocking threads, one epoll thread, a tokio current-thread runtime) that only read
//! and timestamp: the CPU any reader needs here, to compare `imulogd` with.
//! `cargo bench --bench daemon_load -- floor [--secs S] [--speed F] [--runs N]
//! [--readers threads,epoll,tokio,tokio-io,tokio-grid,tokio-fd,tokio-tickMS] [--nice N] [--in-process]
//! [--keep-awake]`
//!
//! Both modes print through one table printer (`daemon_load/report.rs`).
//!
//! **memory mode** (the default; rounds 1-2): the daemon loop in-process, fed from
//! in-memory streams by a generator thread with pre-encoded frames in 1 ms bursts; prints,
//! per rate: rows sent, written and dropped, whether the rate was held, the daemon's CPU as
//! % of one core (the generator's own CPU subtracted), and the RSS over the run.
//! `cargo bench --bench daemon_load -- [--secs S] [RATE_HZ ...]`
//! (default: 10 s at 150, 1500, 15000, 30000 and 60000 Hz per IMU). The devices speak real
//! protocols (imu0 WitMotion, imu1 Xsens Xbus MTData2, the receiver NMEA GGA + RMC and UBX
//! NAV-PVT + NAV-EOE each cycle), encoded with the drivers' encoders and decoded with the
//! daemon's own decoders; a stream that cannot be read fast enough pushes back on the
//! generator, which then falls behind its schedule: that counts as not holding the rate.

use imulab_test_support::daemon_support as common;

use std::time::{Duration, Instant};

use common::encode::{gnss_cycle, wit_sample, xbus_sample};
use common::QueueConnector;
use imulab::daemon::config::parse;
use imulab::daemon::session::open_session_sink;
use imulab::daemon::source::{decoder_for, Connector};
use imulab::daemon::status::read_status_file;
use imulab::daemon::{run, DaemonParts};
use imulab::store::{Session, TimeRange};
use tokio::io::AsyncWriteExt;

#[path = "daemon_load/pty.rs"]
mod pty;
#[path = "support/results.rs"]
mod results;

#[path = "daemon_load/floor.rs"]
mod floor;

#[path = "daemon_load/report.rs"]
mod report;

#[path = "daemon_load/awake.rs"]
mod awake;

/// The value of option `name` as a positive finite number (the modes' option parsers).
fn positive_number(name: &str, v: &str) -> Result<f64, String> {
    v.parse::<f64>()
        .ok()
        .filter(|x| x.is_finite() && *x > 0.0)
        .ok_or(format!("{name}: {v:?} is not a positive number"))
}

/// The value of option `name` parsed as a `T`.
fn parsed<T: std::str::FromStr>(name: &str, v: &str) -> Result<T, String>
where
    T::Err: std::fmt::Display,
{
    v.parse().map_err(|e| format!("{name}: {e}"))
}

fn cpu_seconds(who: libc::c_int) -> f64 {
    // SAFETY: getrusage writes into the zeroed struct we own; `who` is RUSAGE_SELF/THREAD.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(who, &mut usage) } != 0 {
        return f64::NAN;
    }
    let t = |tv: libc::timeval| tv.tv_sec as f64 + tv.tv_usec as f64 * 1e-6;
    t(usage.ru_utime) + t(usage.ru_stime)
}

fn rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map(|kib| kib / 1024.0)
        .unwrap_or(f64::NAN)
}

struct RunResult {
    clean_stop: bool,
    rate_hz: f64,
    secs: f64,
    sent: u64,
    written: u64,
    dropped: u64,
    generator_lag_s: f64,
    cpu_percent: f64,
    rss_curve: Vec<f64>,
    session_mib: f64,
}

fn dir_size(path: &std::path::Path) -> u64 {
    std::fs::read_dir(path)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok()?.metadata().ok())
                .map(|m| m.len())
                .sum()
        })
        .unwrap_or(0)
}

fn one_run(rate_hz: f64, secs: f64) -> RunResult {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nraw_journal = true\ndeflate_level = 4\nqueue_capacity = 1024\n\
         [[device]]\nname = \"imu0\"\nprotocol = \"wit\"\nrate_hz = {rate_hz}\nserial = {{ port = \"/dev/a\" }}\n\
         [[device]]\nname = \"imu1\"\nprotocol = \"xbus\"\nrate_hz = {rate_hz}\nserial = {{ port = \"/dev/b\" }}\n\
         [[device]]\nname = \"gnss\"\nprotocol = \"gnss\"\nrate_hz = 10\nserial = {{ port = \"/dev/c\" }}\n",
        dir.path().display()
    );
    let config = parse(&text, "bench").expect("config");
    let session_dir = dir.path().join("session");
    let sink = open_session_sink(&config, &session_dir).expect("session");
    let connectors: Vec<QueueConnector> = (0..3).map(|_| QueueConnector::default()).collect();
    let ports: Vec<_> = connectors.iter().map(|c| c.plug()).collect();
    let status_path = config.status_path();
    let parts = DaemonParts {
        sink: Box::new(sink),
        session_dir: session_dir.clone(),
        connectors: connectors
            .into_iter()
            .map(|c| Box::new(c) as Box<dyn Connector>)
            .collect(),
        decoders: config
            .devices
            .iter()
            .map(|d| decoder_for(d).expect("decoder"))
            .collect(),
        free_space: Box::new(|| Ok(u64::MAX / 2)),
        status_path: status_path.clone(),
    };

    // Pre-encoded 1 ms bursts, so the generator costs little.
    let per_ms = rate_hz / 1000.0;
    let total_ms = (secs * 1000.0) as u64;
    let imu_frames = (rate_hz * secs) as u64;
    let gnss_frames = (10.0 * secs) as u64;
    let mut bursts: Vec<[Vec<u8>; 3]> = Vec::with_capacity(total_ms as usize);
    let (mut done_imu, mut done_gnss) = (0u64, 0u64);
    for ms in 0..total_ms {
        let due_imu = (((ms + 1) as f64 * per_ms) as u64).min(imu_frames);
        let due_gnss = ((ms + 1) / 100).min(gnss_frames);
        let mut burst: [Vec<u8>; 3] = Default::default();
        for seq in done_imu..due_imu {
            burst[0].extend_from_slice(&wit_sample(seq));
            burst[1].extend_from_slice(&xbus_sample(seq));
        }
        for k in done_gnss..due_gnss {
            burst[2].extend_from_slice(&gnss_cycle(k).0);
        }
        done_imu = due_imu;
        done_gnss = due_gnss;
        bursts.push(burst);
    }

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let cpu_start = cpu_seconds(libc::RUSAGE_SELF);
    let started = Instant::now();
    let daemon = runtime.spawn(async move { run(&config, parts, stop_rx).await });
    let generator = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("generator runtime");
        let cpu0 = cpu_seconds(libc::RUSAGE_THREAD);
        let lag = rt.block_on(async move {
            let mut ports = ports;
            let start = tokio::time::Instant::now();
            for (ms, burst) in bursts.iter().enumerate() {
                for (port, bytes) in ports.iter_mut().zip(burst) {
                    if !bytes.is_empty() {
                        port.write_all(bytes).await.expect("write");
                    }
                }
                tokio::time::sleep_until(start + Duration::from_millis(ms as u64 + 1)).await;
            }
            let lag = start.elapsed().as_secs_f64() - bursts.len() as f64 / 1000.0;
            tokio::time::sleep(Duration::from_millis(300)).await;
            drop(ports);
            lag
        });
        (lag, cpu_seconds(libc::RUSAGE_THREAD) - cpu0)
    });
    let mut rss_curve = vec![rss_mib()];
    let samples = 10;
    for k in 1..=samples {
        let until = started + Duration::from_secs_f64(secs * k as f64 / samples as f64);
        std::thread::sleep(until.saturating_duration_since(Instant::now()));
        rss_curve.push(rss_mib());
    }
    let (lag, generator_cpu) = generator.join().expect("generator");
    let _ = stop.send(true);
    let outcome = runtime.block_on(daemon).expect("daemon");
    let wall = started.elapsed().as_secs_f64();
    let cpu = cpu_seconds(libc::RUSAGE_SELF) - cpu_start - generator_cpu;
    let clean_stop = outcome.exit_code() == 0;
    if !clean_stop {
        println!("  (rate {rate_hz} Hz: the daemon did not stop cleanly: {outcome:?})");
    }
    let status = read_status_file(&status_path).expect("status");
    let dropped = status.devices.iter().map(|d| d.dropped_rows).sum();
    let session = Session::open(&session_dir).expect("session");
    let mut written = 0u64;
    for device in ["imu0", "imu1"] {
        for block in session
            .imu_blocks(device, TimeRange::all(), 1 << 16)
            .expect("blocks")
        {
            written += block.expect("block").len() as u64;
        }
    }
    for block in session
        .gnss_blocks("gnss", TimeRange::all(), 1 << 16)
        .expect("blocks")
    {
        written += block.expect("block").week.len() as u64;
    }
    RunResult {
        clean_stop,
        rate_hz,
        secs,
        // Each GNSS cycle (NMEA and UBX) is merged into one fix: one row.
        sent: 2 * imu_frames + gnss_frames,
        written,
        dropped,
        generator_lag_s: lag,
        cpu_percent: 100.0 * cpu / wall,
        rss_curve,
        session_mib: dir_size(&session_dir) as f64 / (1 << 20) as f64,
    }
}

/// What `--help` prints (and a bad argument, after the error).
const USAGE: &str = "\
usage: daemon_load pty [--secs S] [--speed F[,F...]] [--runs N] [--sample-s S] [--imulogd PATH]
                       [--curve FILE.csv] [--raw-journal] [--nice N] [--keep-awake]
       daemon_load floor [--secs S] [--speed F] [--runs N] [--readers LIST] [--nice N]
                         [--in-process] [--keep-awake]
       daemon_load [--secs S] [RATE_HZ ...]     (memory mode: the daemon loop in-process)
(through cargo: cargo bench --bench daemon_load -- ARGS; the module doc of
benches/daemon_load.rs says what each mode measures)";

/// Prints `error` and the usage, and exits 2.
fn usage_error(error: &str) -> ! {
    eprintln!("daemon_load: {error}\n{USAGE}");
    std::process::exit(2)
}

fn main() {
    match std::env::args().nth(1).as_deref() {
        Some("-h" | "--help") => {
            println!("{USAGE}");
            return;
        }
        Some("pty") => return pty::main(std::env::args().skip(2).collect()),
        Some("floor") => return floor::main(std::env::args().skip(2).collect()),
        Some("floor-reader") => return floor::reader_main(std::env::args().skip(2).collect()),
        Some("keep-awake") => return awake::awake_main(),
        _ => {}
    }
    let mut secs = 10.0;
    let mut rates = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--secs" => {
                secs = args
                    .next()
                    .and_then(|s| s.parse().ok())
                    .filter(|s: &f64| *s > 0.0)
                    .unwrap_or_else(|| usage_error("--secs takes a positive number of seconds"))
            }
            "--bench" => {}
            other => match other.parse::<f64>() {
                Ok(rate) if rate > 0.0 => rates.push(rate),
                _ => usage_error(&format!("{other:?} is neither an option nor a rate in Hz")),
            },
        }
    }
    if rates.is_empty() {
        rates = vec![150.0, 1500.0, 15_000.0, 30_000.0, 60_000.0];
    }
    println!("imulogd load: 2 IMUs at RATE each + GNSS 10 Hz, {secs} s per rate, HDF5 deflate 4 + raw journal");
    println!(
        "{:>9} {:>6} {:>10} {:>10} {:>8} {:>7} {:>9} {:>6} {:>8}  RSS MiB (start … every 10 %)",
        "rate/Hz", "secs", "sent", "written", "dropped", "lag/s", "held", "CPU%", "MiB"
    );
    for rate in rates {
        let r = one_run(rate, secs);
        let held = r.clean_stop
            && r.dropped == 0
            && r.written == r.sent
            && r.generator_lag_s < 0.05 * r.secs;
        let curve: Vec<String> = r.rss_curve.iter().map(|m| format!("{m:.1}")).collect();
        println!(
            "{:>9} {:>6} {:>10} {:>10} {:>8} {:>7.3} {:>9} {:>6.2} {:>8.1}  {}",
            r.rate_hz,
            r.secs,
            r.sent,
            r.written,
            r.dropped,
            r.generator_lag_s,
            if held { "yes" } else { "NO" },
            r.cpu_percent,
            r.session_mib,
            curve.join(" ")
        );
    }
}
