//! What watching costs: CPU (% of one core) and memory (RSS) of an `imulab watch` process
//! following a session of two IMUs at 150 Hz and a GNSS receiver at 5 Hz, written by the
//! store's writer as imulogd writes it, with the page fetched at every refresh as an open
//! browser does.
//!
//! 1. Real time: the session grows by 1 s of data every second for
//!    `IMULAB_WATCH_BENCH_REAL_S` seconds (default 120); CPU over that time after the first
//!    look, and the RSS at the end.
//! 2. A day: `IMULAB_WATCH_BENCH_DAY_H` hours of data (default 24) written at
//!    `IMULAB_WATCH_BENCH_SPEEDUP` times real time (default 0: as fast as the writer goes;
//!    the speed-up reached is printed) while the same process follows; RSS at every few
//!    hours of data (the bound over a day) and the CPU per hour of data (the part of the
//!    cost that grows with rows).
//!
//! Run: `cargo bench --bench watch` (docs/bench/watch.md).

#[path = "support/results.rs"]
mod results;

use imulab_test_support::live_session as common;

use common::{mono_now, LiveSession, Served};
use std::time::{Duration, Instant};

fn env_f64(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// CPU seconds (user + system) of process `pid`.
fn cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // utime and stime are fields 14 and 15 of the line: 12 and 13 after the name.
    // SAFETY: sysconf only reads a constant of the system.
    let hz = match unsafe { libc::sysconf(libc::_SC_CLK_TCK) } {
        t if t > 0 => t as f64,
        _ => 100.0,
    };
    (ticks(11) + ticks(12)) / hz
}

/// A field of /proc/PID/status in MiB (VmRSS, VmHWM).
fn mem_mib(pid: u32, field: &str) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix(field))
        .and_then(|v| {
            v.trim_start_matches(':')
                .split_whitespace()
                .next()?
                .parse::<f64>()
                .ok()
        })
        .map_or(0.0, |kib| kib / 1024.0)
}

fn fetch_page(served: &Served) {
    let (code, _) = served.get("/fragment");
    assert_eq!(code, 200, "the watch page did not answer");
}

fn real_time(seconds: f64, refresh_s: f64) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("run");
    let mut live = LiveSession::create(&session, mono_now());
    live.append(1.0);
    let refresh = format!("{refresh_s}");
    let served = Served::start(
        env!("CARGO_BIN_EXE_imulab"),
        &session,
        &["--refresh", &refresh],
    );
    let pid = served.child.id();
    // Let the first look and the process start settle.
    std::thread::sleep(Duration::from_secs(2));
    let (cpu0, t0) = (cpu_s(pid), Instant::now());
    let mut next_fetch = Instant::now();
    let mut tick = Instant::now();
    while t0.elapsed().as_secs_f64() < seconds {
        tick += Duration::from_secs(1);
        live.append(1.0);
        if Instant::now() >= next_fetch {
            fetch_page(&served);
            next_fetch += Duration::from_secs_f64(refresh_s);
        }
        if let Some(wait) = tick.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    let wall = t0.elapsed().as_secs_f64();
    let cpu = cpu_s(pid) - cpu0;
    println!(
        "real time: {wall:.0} s of a 2 × 150 Hz IMU + 5 Hz GNSS session, refresh {refresh_s} s: \
         CPU {:.2} % of one core ({cpu:.2} s, {:.1} CPU s per real hour), RSS {:.1} MiB \
         (peak {:.1} MiB)",
        100.0 * cpu / wall,
        3600.0 * cpu / wall,
        mem_mib(pid, "VmRSS"),
        mem_mib(pid, "VmHWM")
    );
    let figures = serde_json::json!({
        "wall_s": wall, "cpu_s": cpu, "cpu_pct": 100.0 * cpu / wall,
        "rss_mib": mem_mib(pid, "VmRSS"), "peak_mib": mem_mib(pid, "VmHWM"),
    });
    live.close();
    figures
}

fn day(hours: f64, refresh_s: f64, speed_up: f64) -> serde_json::Value {
    let mut reports = Vec::new();
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("run");
    let mut live = LiveSession::create(&session, mono_now());
    live.append(60.0);
    let refresh = format!("{refresh_s}");
    let served = Served::start(
        env!("CARGO_BIN_EXE_imulab"),
        &session,
        &["--refresh", &refresh],
    );
    let pid = served.child.id();
    let started = Instant::now();
    let cpu0 = cpu_s(pid);
    let mut next_report = 1.0;
    let mut next_fetch = Instant::now();
    println!("a day: data hours, wall s, watch CPU s, RSS MiB, peak MiB");
    let mut paced = Instant::now();
    loop {
        live.append(60.0);
        if speed_up > 0.0 {
            paced += Duration::from_secs_f64(60.0 / speed_up);
            if let Some(wait) = paced.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
        }
        let data_h = live.rows as f64 / common::RATE_HZ / 3600.0;
        if Instant::now() >= next_fetch {
            fetch_page(&served);
            next_fetch += Duration::from_secs_f64(refresh_s);
        }
        if data_h + 1e-9 >= next_report || data_h >= hours {
            // One more refresh, so the watcher has caught up with what was written.
            std::thread::sleep(Duration::from_secs_f64(refresh_s * 2.0 + 1.0));
            fetch_page(&served);
            reports.push(serde_json::json!({
                "data_h": data_h, "wall_s": started.elapsed().as_secs_f64(),
                "cpu_s": cpu_s(pid) - cpu0, "rss_mib": mem_mib(pid, "VmRSS"),
                "peak_mib": mem_mib(pid, "VmHWM"),
            }));
            println!(
                "  {data_h:5.1} h  {:6.0} s  {:6.1} s  {:6.1}  {:6.1}",
                started.elapsed().as_secs_f64(),
                cpu_s(pid) - cpu0,
                mem_mib(pid, "VmRSS"),
                mem_mib(pid, "VmHWM")
            );
            next_report = if next_report < 6.0 {
                6.0
            } else {
                next_report + 6.0
            };
        }
        if data_h >= hours {
            break;
        }
    }
    let cpu = cpu_s(pid) - cpu0;
    let data_h = live.rows as f64 / common::RATE_HZ / 3600.0;
    println!(
        "a day: {data_h:.1} h of data in {:.0} s: {:.0}× real time, including the pauses for \
         the reports",
        started.elapsed().as_secs_f64(),
        data_h * 3600.0 / started.elapsed().as_secs_f64()
    );
    println!(
        "a day: {data_h:.1} h of data followed with {cpu:.1} CPU s = {:.3} % of one core per \
         real-time hour for the rows (plus the fixed refresh cost of the real-time run)",
        100.0 * cpu / (data_h * 3600.0)
    );
    live.close();
    serde_json::json!({ "data_h": data_h, "cpu_s": cpu, "reports": reports })
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` passes nothing we need.
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let refresh_s = env_f64("IMULAB_WATCH_BENCH_REFRESH_S", 5.0);
    let real_s = env_f64("IMULAB_WATCH_BENCH_REAL_S", 120.0);
    let live = real_time(real_s, refresh_s);
    let day_h = env_f64("IMULAB_WATCH_BENCH_DAY_H", 24.0);
    let speed_up = env_f64("IMULAB_WATCH_BENCH_SPEEDUP", 0.0);
    let a_day = day(day_h, refresh_s, speed_up);
    let pct = live["cpu_pct"].as_f64().unwrap_or(f64::NAN);
    let row = results::Row::new(
        "watch",
        results::ACQUISITION,
        12,
        "`imulab watch`",
        "docs/bench/watch.md",
    )
    .data(format!("live 2 IMUs + GNSS, page every {refresh_s} s"))
    .ours(format!(
        "{pct:.2} % of a core, {:.1} MiB",
        live["rss_mib"].as_f64().unwrap_or(f64::NAN)
    ))
    .target("< 2 %")
    .met(pct < 2.0)
    .timed()
    .command("cargo bench --bench watch");
    results::write(
        "watch",
        "live",
        serde_json::json!({ "refresh_s": refresh_s, "real_s": real_s, "day_h": day_h, "speed_up": speed_up }),
        serde_json::json!({ "real_time": live, "day": a_day }),
        &[row],
    );
}
