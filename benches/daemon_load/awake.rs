//! `--keep-awake` of the daemon load benchmark: keeps every CPU busy with work that yields to
//! anything else, so that no vCPU halts between the frames the daemon (or a floor reader)
//! wakes up for. It separates what a wake-up costs because the CPU was halted (on a VM: the
//! exit and re-entry, caches and TLB cooled down under the host) from what the wake-up does.
//!
//! The busy threads live in a process of their own (this benchmark again, `keep-awake`), in a
//! session and autogroup of their own at nice 19 ([`own_autogroup`]), one per CPU, each
//! pinned to its CPU and scheduled `SCHED_IDLE`: they run on a CPU with nothing else to run
//! and are preempted as soon as a normal thread wakes there; against a busy machine's other
//! groups theirs weighs 15 to their 1024. So they take (almost) no time from the daemon, the
//! readers or the simulator, and their CPU time is in no figure (the modes measure the
//! daemon's or the readers' own process). They spin on plain arithmetic (no `pause`, which a
//! hypervisor may trap as a spin-lock loop). While they run, the load average counts them
//! (about +1 per CPU).
//!
//! The process ends when its standard input closes: when [`KeepAwake`] is dropped, or when the
//! benchmark dies.

use std::io::{BufRead, Read};
use std::process::{Child, Command, Stdio};

/// The running keep-awake process; dropping it stops it.
pub struct KeepAwake {
    child: Child,
}

impl KeepAwake {
    /// [`KeepAwake::start`] for a mode's `--keep-awake`, when `on`: a failure ends the
    /// benchmark with the reason (exit 2), under `mode`'s name.
    pub fn start_if(on: bool, mode: &str) -> Option<KeepAwake> {
        on.then(|| {
            KeepAwake::start().unwrap_or_else(|e| {
                eprintln!("daemon_load {mode}: {e}");
                std::process::exit(2);
            })
        })
    }

    /// Starts the busy threads and returns once all of them run.
    pub fn start() -> Result<KeepAwake, String> {
        let exe =
            std::env::current_exe().map_err(|e| format!("keep-awake: own executable: {e}"))?;
        let mut child = Command::new(exe)
            .arg("keep-awake")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .map_err(|e| format!("keep-awake: cannot start the process: {e}"))?;
        let mut line = String::new();
        let out = child.stdout.take().ok_or("keep-awake: no stdout")?;
        std::io::BufReader::new(out)
            .read_line(&mut line)
            .map_err(|e| format!("keep-awake: {e}"))?;
        if !line.starts_with("ready") {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("keep-awake: did not start: {line:?}"));
        }
        Ok(KeepAwake { child })
    }
}

impl Drop for KeepAwake {
    fn drop(&mut self) {
        // Closing its stdin ends it; kill in case it does not notice.
        drop(self.child.stdin.take());
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The CPUs this process may run on.
fn allowed_cpus() -> Vec<usize> {
    // SAFETY: sched_getaffinity writes into the zeroed set we own.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    if unsafe { libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) } != 0
    {
        return (0..std::thread::available_parallelism().map_or(1, |n| n.get())).collect();
    }
    (0..libc::CPU_SETSIZE as usize)
        .filter(|&cpu| unsafe { libc::CPU_ISSET(cpu, &set) })
        .collect()
}

/// Makes the calling thread `SCHED_IDLE` (threads it creates inherit it).
fn sched_idle() -> Result<(), String> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: `param` is a valid sched_param; pid 0 is the calling thread.
    if unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) } != 0 {
        return Err(format!(
            "sched_setscheduler(SCHED_IDLE): {}",
            std::io::Error::last_os_error()
        ));
    }
    Ok(())
}

/// Puts this process in a session, and so (with `kernel.sched_autogroup_enabled`) an
/// autogroup, of its own, with the autogroup's nice at 19. `SCHED_IDLE` only yields to the
/// threads of the same scheduling group: left in the benchmark's autogroup, the busy threads
/// kept that group always runnable, so it spent its share of the CPU on them and a waking
/// reader or daemon in it waited behind the other groups (a 10 ms tokio interval then ticked
/// 60-90 times a second instead of 99-113 on the loaded VM). In a group of their own at the
/// lowest weight they take only what the other groups leave.
fn own_autogroup() -> Result<(), String> {
    // SAFETY: setsid has no memory preconditions; it fails only for a group leader, which
    // this child (started by the benchmark) is not.
    if unsafe { libc::setsid() } < 0 {
        return Err(format!("setsid: {}", std::io::Error::last_os_error()));
    }
    match std::fs::write("/proc/self/autogroup", "19") {
        Ok(()) => Ok(()),
        // No autogroups in this kernel: nothing to do.
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(format!("/proc/self/autogroup: {e}")),
    }
}

/// Pins the calling thread to `cpu`.
fn pin_to(cpu: usize) -> Result<(), String> {
    // SAFETY: the set is ours and zeroed before CPU_SET; pid 0 is the calling thread.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    unsafe { libc::CPU_SET(cpu, &mut set) };
    if unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) } != 0 {
        return Err(format!(
            "sched_setaffinity(cpu {cpu}): {}",
            std::io::Error::last_os_error()
        ));
    }
    Ok(())
}

/// The keep-awake process: `keep-awake`. Says `ready N` once N busy threads run, and exits
/// when its standard input closes.
pub fn awake_main() {
    if let Err(e) = own_autogroup() {
        println!("error {e}");
        std::process::exit(2);
    }
    if let Err(e) = sched_idle() {
        println!("error {e}");
        std::process::exit(2);
    }
    let cpus = allowed_cpus();
    let (tx, rx) = std::sync::mpsc::channel();
    for &cpu in &cpus {
        let tx = tx.clone();
        std::thread::spawn(move || {
            let _ = tx.send(pin_to(cpu));
            let mut x = 0u64;
            loop {
                // Arithmetic the compiler cannot drop; no syscalls, no `pause`.
                for _ in 0..1_000_000 {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            }
        });
    }
    for _ in &cpus {
        match rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                println!("error {e}");
                std::process::exit(2);
            }
            Err(_) => std::process::exit(2),
        }
    }
    println!("ready {}", cpus.len());
    let mut sink = [0u8; 64];
    let mut stdin = std::io::stdin();
    while matches!(stdin.read(&mut sink), Ok(n) if n > 0) {}
    std::process::exit(0);
}
