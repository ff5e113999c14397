//! The `floor` mode of the daemon load benchmark: how much CPU does *any* reader need on this
//! machine to take the bench's frames (the `pty` mode's simulator, same scene, same ptys)
//! one wake-up per frame with a host timestamp per read, doing nothing else (no decode, no
//! queue, no writer)? It separates what the kernel and the VM charge per wake-up from what
//! `imulogd` adds.
//!
//! The readers run in a process of their own (this benchmark again, `floor-reader KIND
//! PTY...`), as `imulogd` does, and their CPU is the on-CPU time of that process's threads
//! (`/proc/PID/task/*/schedstat`, ns) over the serve window, first frame to last frame, as
//! the `pty` mode reads the daemon's. With `--in-process` they are threads of the benchmark
//! (the simulator's process) instead, read through their CPU-time clocks
//! (`pthread_getcpuclockid`: the time `getrusage(RUSAGE_THREAD)` reports). The readers:
//!
//! - `threads`: one thread per pty, blocking `read(2)`, then `clock_gettime` on
//!   CLOCK_MONOTONIC and CLOCK_REALTIME (the pair the daemon takes per read);
//! - `epoll`: one thread, level-triggered `epoll_wait` on the three ptys (non-blocking), one
//!   `read` per ready pty, the same clock pair;
//! - `tokio`: a current-thread tokio runtime (`enable_all`, as `imulogd` builds it) on one
//!   thread, one task per pty reading through the drivers' `SerialStream` (the daemon's
//!   transport), the same clock pair; `tokio-io`: the same with the I/O driver only
//!   (`enable_io`: no timer wheel, no signal driver); `tokio-grid`: `tokio` plus the daemon's
//!   hand-over timer (each task's first read of a 250 ms grid period arms a timer for the
//!   next grid point, waited for beside the read), so a timer is pending at nearly every
//!   wait, as in `imulogd`; `tokio-tickMS` (e.g. `tokio-tick10`): not one wake-up per
//!   frame but a tokio interval of MS ms, each tick reading what every pty holds (a data
//!   point only: `imulogd` reads per frame so that each frame has its own arrival time);
//!   `tokio-fd`: `tokio` without the drivers' transport: raw descriptors in tokio's
//!   `AsyncFd`, a read short of the buffer clearing the readiness as the drivers'
//!   `SerialStream` does (without its busy-port clock read), no `StreamTransport` or
//!   `ByteSource::read` future: what the transport layer adds to a wake-up.
//!
//! In a child process each reader thread's schedstat (on-CPU time, times scheduled in) is
//! printed too: µs per wake-up. `--keep-awake` keeps the CPUs out of halt meanwhile
//! ([`super::awake`]).
//!
//! `cargo bench --bench daemon_load -- floor [--secs S] [--speed F] [--runs N]
//! [--readers threads,epoll,tokio,tokio-io,tokio-grid,tokio-fd,tokio-tickMS] [--nice N] [--in-process]
//! [--keep-awake]`

use std::os::fd::{AsRawFd, OwnedFd};
use std::os::unix::thread::JoinHandleExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use imulab::sim::serve::{ServeOptions, Server, Speed, StartWhen};
use imulab_drivers::transport::serial::{open_serial, SerialConfig};
use imulab_drivers::transport::ByteSource;
use nix::fcntl::{open, OFlag};
use nix::sys::stat::Mode;
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

use super::awake::KeepAwake;
use super::pty::scene;
use super::report::{loadavg, set_nice, thread_shares, thread_times, Load, Table, ThreadTimes};
use super::{parsed, positive_number};
use std::io::{BufRead, Write};

/// The daemon's read size.
const READ_BUFFER_BYTES: usize = 16 * 1024;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Threads,
    Epoll,
    Tokio,
    /// The same without tokio's time and signal drivers (`enable_io` only).
    TokioIo,
    /// `Tokio` with the daemon's hand-over timer pending beside each read.
    TokioGrid,
    /// `Tokio` without the drivers' transport: raw pty descriptors in tokio's `AsyncFd`, a
    /// read short of the buffer taken as draining the pty (readiness cleared at once).
    TokioFd,
    /// A tokio interval of this many ms; each tick reads whatever every pty holds (a data
    /// point for the docs: what batching reads by time would save, at the price of arrival
    /// times blurred by up to a period).
    TokioTick(u64),
}

impl Kind {
    fn parse(s: &str) -> Result<Kind, String> {
        let tick = s
            .strip_prefix("tokio-tick")
            .and_then(|ms| ms.parse::<u64>().ok())
            .filter(|&ms| ms > 0);
        match (s, tick) {
            (_, Some(ms)) => Ok(Kind::TokioTick(ms)),
            ("threads", _) => Ok(Kind::Threads),
            ("epoll", _) => Ok(Kind::Epoll),
            ("tokio", _) => Ok(Kind::Tokio),
            ("tokio-io", _) => Ok(Kind::TokioIo),
            ("tokio-grid", _) => Ok(Kind::TokioGrid),
            ("tokio-fd", _) => Ok(Kind::TokioFd),
            (other, _) => Err(format!(
                "--readers: unknown reader {other:?} (threads, epoll, tokio, tokio-io, tokio-grid, tokio-fd, tokio-tickMS e.g. tokio-tick10)"
            )),
        }
    }

    fn name(self) -> String {
        match self {
            Kind::Threads => "threads".into(),
            Kind::Epoll => "epoll".into(),
            Kind::Tokio => "tokio".into(),
            Kind::TokioIo => "tokio-io".into(),
            Kind::TokioGrid => "tokio-grid".into(),
            Kind::TokioFd => "tokio-fd".into(),
            Kind::TokioTick(ms) => format!("tokio-tick{ms}"),
        }
    }
}

struct Options {
    secs: f64,
    speed: f64,
    runs: usize,
    kinds: Vec<Kind>,
    nice: Option<i32>,
    /// `--in-process`: reader threads in this (the simulator's) process.
    in_process: bool,
    /// `--keep-awake`: busy `SCHED_IDLE` threads keep the CPUs out of halt during the runs.
    keep_awake: bool,
}

fn parse_options(args: Vec<String>) -> Result<Options, String> {
    let mut o = Options {
        secs: 60.0,
        speed: 1.0,
        runs: 3,
        kinds: vec![Kind::Threads, Kind::Epoll, Kind::Tokio, Kind::TokioIo],
        nice: None,
        in_process: false,
        keep_awake: false,
    };
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        let mut value = |name: &str| args.next().ok_or(format!("{name} needs a value"));
        match arg.as_str() {
            "--secs" => o.secs = positive_number("--secs", &value("--secs")?)?,
            "--speed" => o.speed = positive_number("--speed", &value("--speed")?)?,
            "--runs" => o.runs = parsed("--runs", &value("--runs")?)?,
            "--readers" => {
                o.kinds = value("--readers")?
                    .split(',')
                    .map(Kind::parse)
                    .collect::<Result<_, _>>()?
            }
            "--nice" => o.nice = Some(parsed("--nice", &value("--nice")?)?),
            "--in-process" => o.in_process = true,
            "--keep-awake" => o.keep_awake = true,
            "--bench" => {}
            other => return Err(format!("floor: unknown argument {other:?}")),
        }
    }
    Ok(o)
}

/// What the readers counted: reads that returned data, bytes, and a sum of the timestamps
/// (kept so the clock reads cannot be optimised away).
#[derive(Default)]
struct Counts {
    reads: AtomicU64,
    bytes: AtomicU64,
    stamp_sum: AtomicU64,
    /// `epoll_wait` returns (the `epoll` reader), ticks (`tokio-tick`).
    waits: AtomicU64,
}

impl Counts {
    fn add(&self, n: usize, stamp: u64) {
        self.reads.fetch_add(1, Ordering::Relaxed);
        self.bytes.fetch_add(n as u64, Ordering::Relaxed);
        self.stamp_sum.fetch_add(stamp, Ordering::Relaxed);
    }
}

/// The pair of host clocks the daemon reads per arrival, folded into one number.
fn stamp() -> u64 {
    let ns = |id| {
        nix::time::clock_gettime(id)
            .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
            .unwrap_or(0)
    };
    let mono = ns(nix::time::ClockId::CLOCK_MONOTONIC);
    let wall = ns(nix::time::ClockId::CLOCK_REALTIME);
    std::hint::black_box(mono ^ wall)
}

/// Opens a pty slave in raw mode (as `serialport` configures a port: `cfmakeraw`, VMIN 1).
fn open_raw(path: &Path, nonblocking: bool) -> OwnedFd {
    let mut flags = OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_CLOEXEC;
    if nonblocking {
        flags |= OFlag::O_NONBLOCK;
    }
    let fd = open(path, flags, Mode::empty())
        .unwrap_or_else(|e| panic!("floor: cannot open {}: {e}", path.display()));
    let mut termios =
        tcgetattr(&fd).unwrap_or_else(|e| panic!("floor: tcgetattr {}: {e}", path.display()));
    cfmakeraw(&mut termios);
    tcsetattr(&fd, SetArg::TCSANOW, &termios)
        .unwrap_or_else(|e| panic!("floor: tcsetattr {}: {e}", path.display()));
    fd
}

fn read_fd(fd: &OwnedFd, buf: &mut [u8]) -> isize {
    // SAFETY: `buf` is valid for writes of `buf.len()` bytes; the fd is open.
    unsafe { libc::read(fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) }
}

/// One thread per pty, blocking reads. Returns the threads once every pty is open.
fn start_threads(paths: &[PathBuf], counts: &Arc<Counts>) -> Vec<JoinHandle<()>> {
    let (opened_tx, opened_rx) = mpsc::channel();
    let threads: Vec<_> = paths
        .iter()
        .map(|path| {
            let path = path.clone();
            let counts = counts.clone();
            let opened = opened_tx.clone();
            std::thread::spawn(move || {
                let fd = open_raw(&path, false);
                let _ = opened.send(());
                let mut buf = vec![0u8; READ_BUFFER_BYTES];
                loop {
                    let n = read_fd(&fd, &mut buf);
                    if n <= 0 {
                        // EIO (or 0): the simulator closed the pty; EINTR does not occur
                        // (no signal handlers here), anything else also ends the reader.
                        break;
                    }
                    counts.add(n as usize, stamp());
                }
            })
        })
        .collect();
    for _ in paths {
        opened_rx.recv().expect("floor: a reader thread died");
    }
    threads
}

/// One thread, level-triggered epoll over all ptys, one read per ready pty.
fn start_epoll(paths: &[PathBuf], counts: &Arc<Counts>) -> Vec<JoinHandle<()>> {
    let fds: Vec<OwnedFd> = paths.iter().map(|p| open_raw(p, true)).collect();
    let counts = counts.clone();
    let thread = std::thread::spawn(move || {
        // SAFETY: plain syscalls on descriptors this thread owns; `events` is valid for
        // `events.len()` entries.
        let ep = unsafe { libc::epoll_create1(libc::EPOLL_CLOEXEC) };
        assert!(ep >= 0, "floor: epoll_create1 failed");
        for (i, fd) in fds.iter().enumerate() {
            let mut ev = libc::epoll_event {
                events: libc::EPOLLIN as u32,
                u64: i as u64,
            };
            let r = unsafe { libc::epoll_ctl(ep, libc::EPOLL_CTL_ADD, fd.as_raw_fd(), &mut ev) };
            assert!(r == 0, "floor: epoll_ctl failed");
        }
        let mut open = fds.len();
        let mut events = [libc::epoll_event { events: 0, u64: 0 }; 8];
        let mut buf = vec![0u8; READ_BUFFER_BYTES];
        while open > 0 {
            let n = unsafe { libc::epoll_wait(ep, events.as_mut_ptr(), events.len() as i32, -1) };
            if n < 0 {
                continue; // EINTR
            }
            counts.waits.fetch_add(1, Ordering::Relaxed);
            for ev in &events[..n as usize] {
                let fd = &fds[ev.u64 as usize];
                let got = read_fd(fd, &mut buf);
                if got > 0 {
                    counts.add(got as usize, stamp());
                } else if got == 0
                    || std::io::Error::last_os_error().kind() != std::io::ErrorKind::WouldBlock
                {
                    // Closed by the simulator: stop watching it.
                    unsafe {
                        libc::epoll_ctl(
                            ep,
                            libc::EPOLL_CTL_DEL,
                            fd.as_raw_fd(),
                            std::ptr::null_mut(),
                        )
                    };
                    open -= 1;
                }
            }
        }
        unsafe { libc::close(ep) };
    });
    vec![thread]
}

/// The daemon's hand-over period (its default flush interval's grid).
const GRID_PERIOD: Duration = Duration::from_millis(250);

/// Reads `port` until it vanishes; with `grid`, a timer for the next [`GRID_PERIOD`] point
/// after `epoch` is armed by the first read of each period and waited for beside the reads,
/// as the daemon's device tasks do.
async fn read_pty(
    mut port: imulab_drivers::transport::serial::SerialTransport,
    counts: Arc<Counts>,
    grid: bool,
    epoch: tokio::time::Instant,
) {
    let mut buf = vec![0u8; READ_BUFFER_BYTES];
    let timer = tokio::time::sleep_until(epoch);
    tokio::pin!(timer);
    let mut armed = false;
    loop {
        let read = if grid {
            tokio::select! {
                biased;
                _ = &mut timer, if armed => {
                    armed = false;
                    continue;
                }
                r = port.read(&mut buf) => r,
            }
        } else {
            port.read(&mut buf).await
        };
        // Ends when the simulator closes the pty (a vanish).
        let Ok(n) = read else { break };
        counts.add(n, stamp());
        if grid && !armed {
            let since = tokio::time::Instant::now().saturating_duration_since(epoch);
            let k = since.as_nanos() / GRID_PERIOD.as_nanos() + 1;
            let k = u32::try_from(k).unwrap_or(u32::MAX);
            timer.as_mut().reset(epoch + GRID_PERIOD * k);
            armed = true;
        }
    }
}

/// One thread with a current-thread tokio runtime, one task per pty through `SerialStream`.
/// With `all_drivers` the runtime is built as `imulogd` builds it (`enable_all`), else with
/// the I/O driver only; with `grid`, [`read_pty`]'s hand-over timer too.
fn start_tokio(
    paths: &[PathBuf],
    counts: &Arc<Counts>,
    all_drivers: bool,
    grid: bool,
) -> Vec<JoinHandle<()>> {
    let paths = paths.to_vec();
    let counts = counts.clone();
    on_runtime_thread("tokio", all_drivers, move |opened_tx| async move {
        let mut tasks = Vec::new();
        let epoch = tokio::time::Instant::now();
        for path in &paths {
            let port = open_serial(&SerialConfig::new(path.display().to_string(), 921600))
                .unwrap_or_else(|e| panic!("floor: {e}"));
            tasks.push(tokio::spawn(read_pty(port, counts.clone(), grid, epoch)));
        }
        let _ = opened_tx.send(());
        for t in tasks {
            let _ = t.await;
        }
    })
}

/// One thread with a current-thread tokio runtime (`enable_all`), one task per pty reading a
/// raw non-blocking descriptor through `AsyncFd`; a read short of the buffer clears the
/// readiness (the pty held no more), so a wake-up makes one `read`.
fn start_tokio_fd(paths: &[PathBuf], counts: &Arc<Counts>) -> Vec<JoinHandle<()>> {
    let paths = paths.to_vec();
    let counts = counts.clone();
    on_runtime_thread("tokio-fd", true, move |opened_tx| async move {
        let mut tasks = Vec::new();
        for path in &paths {
            // SAFETY: the descriptor is owned by the AsyncFd, open until it is dropped.
            let fd = unsafe {
                tokio::io::unix::AsyncFd::register_with_interest(
                    open_raw(path, true),
                    tokio::io::Interest::READABLE,
                )
            }
            .map_err(|e| e.into_parts().1)
            .expect("floor: AsyncFd");
            let counts = counts.clone();
            tasks.push(tokio::spawn(async move {
                let mut buf = vec![0u8; READ_BUFFER_BYTES];
                loop {
                    let Ok(mut guard) = fd.readable().await else {
                        break;
                    };
                    let got = read_fd(guard.get_inner(), &mut buf);
                    if got > 0 {
                        counts.add(got as usize, stamp());
                        if (got as usize) < buf.len() {
                            guard.clear_ready();
                        }
                    } else if got < 0
                        && std::io::Error::last_os_error().kind() == std::io::ErrorKind::WouldBlock
                    {
                        guard.clear_ready();
                    } else {
                        // Closed by the simulator.
                        break;
                    }
                }
            }));
        }
        let _ = opened_tx.send(());
        for t in tasks {
            let _ = t.await;
        }
    })
}

/// One thread with a current-thread tokio runtime (`enable_all`) and an interval of `period`
/// (missed ticks delayed, not bunched): at each tick, one non-blocking read of every pty
/// (again while a read fills the buffer), each read that returned data stamped.
fn start_tokio_tick(
    paths: &[PathBuf],
    counts: &Arc<Counts>,
    period: Duration,
) -> Vec<JoinHandle<()>> {
    let paths = paths.to_vec();
    let counts = counts.clone();
    on_runtime_thread("tokio-tick", true, move |opened_tx| async move {
        let mut fds: Vec<Option<OwnedFd>> = paths.iter().map(|p| Some(open_raw(p, true))).collect();
        let _ = opened_tx.send(());
        let mut buf = vec![0u8; READ_BUFFER_BYTES];
        let mut interval = tokio::time::interval(period);
        interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        while fds.iter().any(Option::is_some) {
            interval.tick().await;
            counts.waits.fetch_add(1, Ordering::Relaxed);
            for slot in &mut fds {
                let Some(fd) = slot else { continue };
                loop {
                    let got = read_fd(fd, &mut buf);
                    if got > 0 {
                        counts.add(got as usize, stamp());
                        if (got as usize) < buf.len() {
                            break;
                        }
                    } else {
                        if got == 0
                            || std::io::Error::last_os_error().kind()
                                != std::io::ErrorKind::WouldBlock
                        {
                            // Closed by the simulator.
                            *slot = None;
                        }
                        break;
                    }
                }
            }
        }
    })
}

/// Runs `reader` on a thread of its own, in a current-thread tokio runtime (all drivers, as
/// `imulogd` builds it, or the I/O driver only), and returns once `reader` has sent on its
/// channel that its ptys are open: the set-up the tokio floor readers share.
fn on_runtime_thread<R, F>(what: &'static str, all_drivers: bool, reader: R) -> Vec<JoinHandle<()>>
where
    R: FnOnce(mpsc::Sender<()>) -> F + Send + 'static,
    F: std::future::Future<Output = ()>,
{
    let (opened_tx, opened_rx) = mpsc::channel();
    let thread = std::thread::spawn(move || {
        let mut builder = tokio::runtime::Builder::new_current_thread();
        if all_drivers {
            builder.enable_all();
        } else {
            builder.enable_io();
        }
        let runtime = builder.build().expect("floor: runtime");
        runtime.block_on(reader(opened_tx));
    });
    opened_rx
        .recv()
        .unwrap_or_else(|_| panic!("floor: the {what} reader died"));
    vec![thread]
}

/// CPU time of a running thread, s (its CPU-time clock).
fn thread_cpu_s(handle: &JoinHandle<()>) -> f64 {
    let mut clock: libc::clockid_t = 0;
    // SAFETY: the thread is alive (joined only later); both calls write into locals we own.
    unsafe {
        if libc::pthread_getcpuclockid(handle.as_pthread_t(), &mut clock) != 0 {
            return f64::NAN;
        }
        let mut ts: libc::timespec = std::mem::zeroed();
        if libc::clock_gettime(clock, &mut ts) != 0 {
            return f64::NAN;
        }
        ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
    }
}

struct RunResult {
    wall_s: f64,
    cpu_s: f64,
    frames: u64,
    reads: u64,
    waits: u64,
    overflowed: u64,
    load: Load,
    /// Per reader thread over the serve (child process only): CPU %, wake-ups, µs per wake-up.
    threads: Option<String>,
}

/// Starts the readers of `kind` on `paths` in this process; returns their threads and
/// counters once every pty is open.
fn start(kind: Kind, paths: &[PathBuf]) -> (Vec<JoinHandle<()>>, Arc<Counts>) {
    let counts = Arc::new(Counts::default());
    let threads = match kind {
        Kind::Threads => start_threads(paths, &counts),
        Kind::Epoll => start_epoll(paths, &counts),
        Kind::Tokio => start_tokio(paths, &counts, true, false),
        Kind::TokioIo => start_tokio(paths, &counts, false, false),
        Kind::TokioGrid => start_tokio(paths, &counts, true, true),
        Kind::TokioTick(ms) => start_tokio_tick(paths, &counts, Duration::from_millis(ms)),
        Kind::TokioFd => start_tokio_fd(paths, &counts),
    };
    (threads, counts)
}

/// The readers, either threads of this process or a child process (this benchmark again,
/// `floor-reader KIND PTY...`): a separate process like `imulogd`, so that every wake-up also
/// switches address space as the daemon's do.
enum Readers {
    InProcess(Vec<JoinHandle<()>>, Arc<Counts>),
    Child(
        std::process::Child,
        std::io::BufReader<std::process::ChildStdout>,
    ),
}

impl Readers {
    fn start(kind: Kind, paths: &[PathBuf], in_process: bool) -> Readers {
        if in_process {
            let (threads, counts) = start(kind, paths);
            return Readers::InProcess(threads, counts);
        }
        let exe = std::env::current_exe().expect("floor: own executable");
        let mut child = std::process::Command::new(exe)
            .arg("floor-reader")
            .arg(kind.name())
            .args(paths)
            .stdout(std::process::Stdio::piped())
            .spawn()
            .expect("floor: cannot start the reader process");
        let mut out = std::io::BufReader::new(child.stdout.take().expect("piped stdout"));
        let mut line = String::new();
        out.read_line(&mut line).expect("floor: reader output");
        assert_eq!(
            line.trim(),
            "ready",
            "floor: the reader process did not start"
        );
        Readers::Child(child, out)
    }

    /// CPU time of the readers so far, s.
    fn cpu_s(&self) -> f64 {
        match self {
            Readers::InProcess(threads, _) => threads.iter().map(thread_cpu_s).sum(),
            Readers::Child(child, _) => thread_times(child.id())
                .iter()
                .map(|t| t.on_cpu_ns as f64 * 1e-9)
                .sum(),
        }
    }

    /// The readers' threads' schedstat counters (a child process only).
    fn thread_times(&self) -> Option<Vec<ThreadTimes>> {
        match self {
            Readers::InProcess(..) => None,
            Readers::Child(child, _) => Some(thread_times(child.id())),
        }
    }

    /// Waits for the readers to end (the ptys closed); returns (reads, epoll waits).
    fn join(self) -> (u64, u64) {
        match self {
            Readers::InProcess(threads, counts) => {
                for t in threads {
                    let _ = t.join();
                }
                (
                    counts.reads.load(Ordering::Relaxed),
                    counts.waits.load(Ordering::Relaxed),
                )
            }
            Readers::Child(mut child, mut out) => {
                let mut line = String::new();
                let _ = out.read_line(&mut line);
                let _ = child.wait();
                let mut numbers = line.split_whitespace().map(|v| v.parse().unwrap_or(0));
                (numbers.next().unwrap_or(0), numbers.next().unwrap_or(0))
            }
        }
    }
}

/// The reader process: `floor-reader KIND PTY...`. Says `ready` once the ptys are open, and
/// `READS WAITS` when they have all been closed.
pub fn reader_main(args: Vec<String>) {
    let Some(kind) = args.first().map(|k| Kind::parse(k)) else {
        eprintln!("daemon_load floor-reader: KIND PTY...");
        std::process::exit(2);
    };
    let kind = kind.unwrap_or_else(|e| {
        eprintln!("daemon_load floor-reader: {e}");
        std::process::exit(2);
    });
    let paths: Vec<PathBuf> = args[1..].iter().map(PathBuf::from).collect();
    // The simulator's pty masters are inherited (they are not close-on-exec): held open here,
    // the ptys would never close and the readers never end.
    let inherited: Vec<i32> = std::fs::read_dir("/proc/self/fd")
        .map(|d| {
            d.flatten()
                .filter_map(|e| e.file_name().to_str()?.parse().ok())
                .filter(|&fd| fd > 2)
                .collect()
        })
        .unwrap_or_default();
    for fd in inherited {
        // SAFETY: nothing in this process uses these descriptors (the directory listing's own
        // descriptor is closed already, so closing it again only fails with EBADF).
        unsafe { libc::close(fd) };
    }
    let (threads, counts) = start(kind, &paths);
    println!("ready");
    let _ = std::io::stdout().flush();
    for t in threads {
        let _ = t.join();
    }
    println!(
        "{} {}",
        counts.reads.load(Ordering::Relaxed),
        counts.waits.load(Ordering::Relaxed)
    );
}

fn one_run(o: &Options, kind: Kind) -> RunResult {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut server = Server::start(
        scene(o.secs * o.speed),
        ServeOptions {
            speed: Speed::Factor(o.speed),
            link_dir: Some(dir.path().join("dev")),
            start: StartWhen::OnDemand,
            record_sent: false,
            faults: Vec::new(),
        },
    )
    .unwrap_or_else(|e| panic!("serve: {e:#}"));
    let paths: Vec<PathBuf> = server
        .endpoints()
        .iter()
        .map(|e| e.path().to_path_buf())
        .collect();
    let readers = Readers::start(kind, &paths, o.in_process);
    let load_before = loadavg();
    let cpu0 = readers.cpu_s();
    let threads0 = readers.thread_times();
    let t0 = Instant::now();
    server.begin();
    while !server.is_finished() {
        std::thread::sleep(Duration::from_millis(20));
    }
    let cpu_s = readers.cpu_s() - cpu0;
    let wall_s = t0.elapsed().as_secs_f64();
    let threads = threads0
        .zip(readers.thread_times())
        .map(|(before, after)| thread_shares(&before, &after, wall_s));
    let load_after = loadavg();
    let report = server.finish().unwrap_or_else(|e| panic!("serve: {e:#}"));
    // Closing the ptys ends every reader.
    drop(server);
    // Counted over the readers' whole life: nothing arrives before the serve begins, and
    // after its end only what was still on its way.
    let (reads, waits) = readers.join();
    RunResult {
        wall_s,
        cpu_s,
        frames: report.streams.iter().map(|s| s.frames).sum(),
        reads,
        waits,
        overflowed: report.streams.iter().map(|s| s.frames_overflowed).sum(),
        load: Load {
            before: load_before,
            after: load_after,
        },
        threads,
    }
}

pub fn main(args: Vec<String>) {
    let o = match parse_options(args) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("daemon_load floor: {e}");
            std::process::exit(2);
        }
    };
    set_nice("floor", o.nice);
    println!("{}", super::report::platform());
    println!(
        "reader floor: the pty mode's simulator (wit + xbus at 150 Hz, mixed GNSS at 10 Hz) × {}, {} s per run; readers only read and timestamp, {}; keep-awake {}",
        o.speed,
        o.secs,
        if o.in_process {
            "in the simulator's process"
        } else {
            "in a process of their own"
        },
        if o.keep_awake { "on" } else { "off" }
    );
    let _awake = KeepAwake::start_if(o.keep_awake, "floor");
    let table = Table {
        columns: &[
            ("reader", 12),
            ("run", 4),
            ("wall s", 7),
            ("frames", 9),
            ("reads", 9),
            ("waits", 9),
            ("CPU%", 8),
            ("µs/read", 8),
            ("reads/s", 9),
            ("srv-ov", 6),
        ],
    };
    table.header();
    for run in 1..=o.runs {
        for &kind in &o.kinds {
            let r = one_run(&o, kind);
            table.row(
                &[
                    kind.name(),
                    run.to_string(),
                    format!("{:.1}", r.wall_s),
                    r.frames.to_string(),
                    r.reads.to_string(),
                    r.waits.to_string(),
                    format!("{:.3}", 100.0 * r.cpu_s / r.wall_s),
                    format!("{:.1}", 1e6 * r.cpu_s / r.reads.max(1) as f64),
                    format!("{:.1}", r.reads as f64 / r.wall_s),
                    r.overflowed.to_string(),
                ],
                &r.load,
            );
            if let Some(threads) = &r.threads {
                table.detail("reader threads (schedstat):", threads);
            }
        }
    }
}
