//! What the `pty` and `floor` modes of the daemon load benchmark read from `/proc` about the
//! process they measure (CPU time, RSS, per-thread schedstat, the load average), and the one
//! printer both use for their tables: a header, one row per run with the load average before
//! and after it, then indented detail lines (the RSS curve, the per-thread on-CPU time,
//! wake-ups and µs per wake-up), plus a line on the platform, since the cost of a wake-up
//! depends on it more than on the reader.

/// utime + stime of a process, s; None once it is gone.
pub fn proc_cpu_s(pid: u32) -> Option<f64> {
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
pub fn proc_status_mib(pid: u32, key: &str) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with(key))?;
    Some(line.split_whitespace().nth(1)?.parse::<f64>().ok()? / 1024.0)
}

/// CPU time (user + system) of this process so far, s.
pub fn self_cpu_s() -> f64 {
    // SAFETY: getrusage writes into the zeroed struct we own.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return f64::NAN;
    }
    let t = |tv: libc::timeval| tv.tv_sec as f64 + tv.tv_usec as f64 * 1e-6;
    t(usage.ru_utime) + t(usage.ru_stime)
}

/// One line on what a wake-up costs here depends on: the CPU and how many, whether it is a
/// virtual machine (the `hypervisor` flag of `/proc/cpuinfo`), the kernel, the idle driver
/// and its halt polling (a vCPU that halts at once pays the hypervisor's exit and re-entry at
/// every wake-up), the clock source, and the CPU-bug mitigations in effect.
pub fn platform() -> String {
    let read = |path: &str| {
        std::fs::read_to_string(path)
            .map(|s| s.trim().to_string())
            .unwrap_or_else(|_| "?".into())
    };
    let cpuinfo = read("/proc/cpuinfo");
    let field = |key: &str| {
        cpuinfo
            .lines()
            .find(|l| l.starts_with(key))
            .and_then(|l| l.split_once(':'))
            .map_or("?", |(_, v)| v.trim())
            .to_string()
    };
    let virtual_machine = field("flags").split_whitespace().any(|f| f == "hypervisor");
    let halt_poll = read("/sys/module/haltpoll/parameters/guest_halt_poll_ns");
    let mitigations: Vec<String> = std::fs::read_dir("/sys/devices/system/cpu/vulnerabilities")
        .map(|dir| {
            let mut found: Vec<String> = dir
                .flatten()
                .filter_map(|e| {
                    let state = std::fs::read_to_string(e.path()).ok()?;
                    let state = state.trim();
                    (state != "Not affected")
                        .then(|| format!("{}: {state}", e.file_name().to_string_lossy()))
                })
                .collect();
            found.sort();
            found
        })
        .unwrap_or_default();
    format!(
        "platform: {}, {} CPUs, {}, kernel {}, cpuidle {}{}, clocksource {}; {}",
        field("model name"),
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        if virtual_machine {
            "virtual machine"
        } else {
            "no hypervisor flag"
        },
        read("/proc/sys/kernel/osrelease"),
        read("/sys/devices/system/cpu/cpuidle/current_driver"),
        if halt_poll == "?" {
            String::new()
        } else {
            format!(" (guest_halt_poll_ns {halt_poll})")
        },
        read("/sys/devices/system/clocksource/clocksource0/current_clocksource"),
        if mitigations.is_empty() {
            "no CPU-bug mitigation listed".to_string()
        } else {
            mitigations.join("; ")
        }
    )
}

/// The 1, 5 and 15 minute load averages, as `/proc/loadavg` writes them.
pub fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "?".into())
}

/// One thread's schedstat counters (`/proc/PID/task/TID/schedstat`).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct ThreadTimes {
    pub tid: u32,
    pub name: String,
    /// Time on a CPU, ns (the first field).
    pub on_cpu_ns: u64,
    /// Times the thread was scheduled in (the third field): its wake-ups, plus the times it
    /// was preempted and resumed.
    pub runs: u64,
}

/// Every thread of process `pid` now, by tid.
pub fn thread_times(pid: u32) -> Vec<ThreadTimes> {
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
        if let (Some(&on_cpu_ns), Some(&runs)) = (f.first(), f.get(2)) {
            out.push(ThreadTimes {
                tid,
                name: name.trim().to_string(),
                on_cpu_ns,
                runs,
            });
        }
    }
    out.sort();
    out
}

/// What each thread did between two [`thread_times`] readings `wall_s` apart: "name[tid]
/// CPU % of one core, wake-ups a second, µs on a CPU per wake-up", joined by "; ".
pub fn thread_shares(before: &[ThreadTimes], after: &[ThreadTimes], wall_s: f64) -> String {
    after
        .iter()
        .map(|a| {
            let (ns0, runs0) = before
                .iter()
                .find(|b| b.tid == a.tid)
                .map_or((0, 0), |b| (b.on_cpu_ns, b.runs));
            let ns = a.on_cpu_ns.saturating_sub(ns0) as f64;
            let runs = a.runs.saturating_sub(runs0);
            format!(
                "{}[{}] {:.3} % {:.0}/s {:.1} µs/wake",
                a.name,
                a.tid,
                100.0 * ns * 1e-9 / wall_s,
                runs as f64 / wall_s,
                ns * 1e-3 / runs.max(1) as f64
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// The load average before and after a run.
pub struct Load {
    pub before: String,
    pub after: String,
}

/// A table of runs: right-aligned columns of the given widths, then the load.
pub struct Table {
    pub columns: &'static [(&'static str, usize)],
}

impl Table {
    pub fn header(&self) {
        let cells: Vec<String> = self
            .columns
            .iter()
            .map(|(name, width)| format!("{name:>width$}"))
            .collect();
        println!("{}  load 1/5/15 min before → after", cells.join(" "));
    }

    /// One run: `cells` in column order (already formatted), then the load.
    pub fn row(&self, cells: &[String], load: &Load) {
        let cells: Vec<String> = self
            .columns
            .iter()
            .zip(cells)
            .map(|((_, width), cell)| format!("{cell:>width$}"))
            .collect();
        println!("{}  {} → {}", cells.join(" "), load.before, load.after);
    }

    /// A detail line under the latest row.
    pub fn detail(&self, label: &str, text: &str) {
        println!("       {label} {text}");
    }
}

/// Sets this process's nice value (`--nice`), or exits with a message naming `mode`.
pub fn set_nice(mode: &str, nice: Option<i32>) {
    let Some(nice) = nice else { return };
    // SAFETY: setpriority has no memory preconditions.
    if unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, nice) } != 0 {
        eprintln!(
            "daemon_load {mode}: cannot set nice {nice}: {}",
            std::io::Error::last_os_error()
        );
        std::process::exit(2);
    }
}
