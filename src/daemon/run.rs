//! The daemon's top level: starts the writer thread (which also writes the status file) and
//! one task per device; handles SIGTERM/SIGINT (flush, close, exit 0 within 2 s) and SIGHUP
//! (rotate); tells systemd READY once every device has opened or failed its first attempt.
//! Under a systemd watchdog the writer feeds it at its grid turns while the device thread
//! shows life ([`super::watchdog`]): no timer of its own.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::signal::unix::{signal, SignalKind};
use tokio::sync::{mpsc, oneshot, watch};

use super::cadence::{self, Cadence};
use super::clock;
use super::config::CheckedConfig;
use super::device::{self, DeviceTask};
use super::sink::RecordSink;
use super::source::{Connector, DecoderFactory};
use super::status::{write_status_file, DeviceShared, StatusTracker, WriterShared};
use super::watchdog::Watchdog;
use super::writer::{
    self, FreeSpaceFn, QueueSender, StatusFile, WriterControl, WriterExit, WriterSettings,
};

/// How long device tasks get to stop before they are aborted.
const DEVICE_STOP_TIMEOUT: Duration = Duration::from_millis(300);
/// How long the writer gets to drain, flush, close and rename (the whole stop must fit in 2 s).
const WRITER_STOP_TIMEOUT: Duration = Duration::from_millis(1500);
/// Of that, the most it spends writing a backlog; the rest is dropped and counted, so that
/// flushing, closing and renaming still fit.
const WRITER_DRAIN_BUDGET: Duration = Duration::from_millis(1000);
/// How often free space is checked.
const DISK_CHECK_INTERVAL: Duration =
    Duration::from_millis(super::config::RESERVE_CHECK_INTERVAL_MS);
/// Free space below which a failed write is taken for a full disk (less than one chunk of a
/// table can be written).
const FULL_DISK_BYTES: u64 = 1 << 20;
/// How often the status file is written.
const STATUS_INTERVAL: Duration = Duration::from_secs(1);

/// The store's flush interval for a configured flush interval: the interval less the
/// hand-over period ([`device::batch_window`]) and the writer's flush lag
/// ([`cadence::flush_lag`]). The store writes a row once it is this old at a grid point;
/// the writer flushes the store at every grid point (at most the lag after it) and the
/// device tasks hand rows over at the next one after their arrival, so a row is on disk at
/// most the configured interval after it arrived (what a SIGKILL can lose).
pub fn writer_flush_interval(flush_interval_ms: u64) -> Duration {
    let configured = Duration::from_millis(flush_interval_ms);
    let period = device::batch_window(configured);
    configured - period - cadence::flush_lag(period)
}

/// What the daemon runs with, built from the config (or by a test).
pub struct DaemonParts {
    pub sink: Box<dyn RecordSink>,
    pub session_dir: PathBuf,
    /// One connector and decoder factory per configured device, in config order.
    pub connectors: Vec<Box<dyn Connector>>,
    pub decoders: Vec<DecoderFactory>,
    pub free_space: FreeSpaceFn,
    /// Where the status JSON is written every second.
    pub status_path: PathBuf,
}

/// How the daemon ended; [`Outcome::exit_code`] is the process exit status.
#[derive(Debug)]
pub enum Outcome {
    /// Stopped by a signal (or the caller) with the session closed cleanly.
    Stopped,
    /// Free space fell below the reserve; the session was closed cleanly.
    DiskReserve { free_bytes: u64, reserve_bytes: u64 },
    /// The file system filled up (ENOSPC) before the reserve check could stop the session:
    /// what could be closed is closed; the chunk file being written needs `imulab recover`.
    DiskFull { session_dir: PathBuf },
    /// Writing failed, or the writer did not finish in time.
    Failed(anyhow::Error),
}

impl Outcome {
    /// 0 after a clean stop, 3 when the disk reserve was reached or the disk is full (a
    /// restart cannot help), 1 on another failure.
    pub fn exit_code(&self) -> u8 {
        match self {
            Outcome::Stopped => 0,
            Outcome::DiskReserve { .. } | Outcome::DiskFull { .. } => 3,
            Outcome::Failed(_) => 1,
        }
    }

    /// The one line that says how the run ended, for the log and the terminal.
    pub fn message(&self) -> String {
        match self {
            Outcome::Stopped => "stopped; the session is closed".to_string(),
            Outcome::DiskReserve {
                free_bytes,
                reserve_bytes,
            } => format!(
                "stopped: {free_bytes} bytes free is below the reserve of {reserve_bytes}; the session is closed cleanly"
            ),
            Outcome::DiskFull { session_dir } => format!(
                "disk full: no space left on the file system of {dir}; the session was closed as far as it could be: free some space, then run `imulab recover {dir}`",
                dir = session_dir.display()
            ),
            Outcome::Failed(e) => format!(
                "stopped on an error: {}",
                crate::errors::render(e)
            ),
        }
    }
}

fn notify(states: &[sd_notify::NotifyState<'_>]) {
    // Without NOTIFY_SOCKET (not under systemd) this does nothing.
    if let Err(e) = sd_notify::notify(states) {
        tracing::debug!("sd_notify failed: {e}");
    }
}

/// Runs the daemon until SIGTERM/SIGINT, `stop` turning true, the disk reserve, or a write
/// failure. Must be called inside a tokio runtime.
pub async fn run(
    config: &CheckedConfig,
    parts: DaemonParts,
    mut stop: watch::Receiver<bool>,
) -> Outcome {
    // The final status (written after the writer stopped) reports uptime and mean rates
    // over the whole run from here.
    let started_mono_ns = clock::mono_ns();
    let DaemonParts {
        sink,
        session_dir,
        connectors,
        decoders,
        free_space,
        status_path,
    } = parts;
    let shared: Vec<Arc<DeviceShared>> = config.devices.iter().map(DeviceShared::of).collect();
    let writer_shared = Arc::new(WriterShared::default());
    writer_shared.counters().session_dir = Some(session_dir.clone());
    let control = Arc::new(WriterControl::default());

    // Signal handlers first, so a signal during start-up is not the default (fatal) action.
    let signals = (
        signal(SignalKind::terminate()),
        signal(SignalKind::interrupt()),
        signal(SignalKind::hangup()),
    );
    let (mut sigterm, mut sigint, mut sighup) = match signals {
        (Ok(t), Ok(i), Ok(h)) => (t, i, h),
        _ => return Outcome::Failed(anyhow::anyhow!("cannot install signal handlers")),
    };

    // Held while the status file is written: the writer's last report, if it is still writing
    // one (e.g. it timed out), finishes before the final report below is written.
    let status_lock = Arc::new(std::sync::Mutex::new(()));
    let (tx, rx) = writer::queue(config.session.queue_capacity);
    let watchdog = Watchdog::from_env().map(Arc::new);
    // One grid for every device task and the writer.
    let handover = Cadence::new(
        std::time::Instant::now(),
        device::batch_window(Duration::from_millis(config.session.flush_interval_ms)),
    );
    let settings = WriterSettings {
        handover,
        reserve_bytes: config.session.disk_reserve_mb.saturating_mul(1 << 20),
        disk_check_interval: DISK_CHECK_INTERVAL,
        disk_check_bytes: config.session.disk_reserve_mb.saturating_mul(1 << 20)
            / super::config::RESERVE_CHECKS_PER_RESERVE,
        drain_budget: WRITER_DRAIN_BUDGET,
        watchdog: watchdog.clone(),
        status: StatusFile {
            path: status_path.clone(),
            interval: STATUS_INTERVAL,
            lock: status_lock.clone(),
        },
        start_detail: format!(
            "imulogd {} started: {} devices ({})",
            env!("CARGO_PKG_VERSION"),
            config.devices.len(),
            config
                .devices
                .iter()
                .map(|d| format!(
                    "{} {} {}{}",
                    d.name,
                    d.protocol.name(),
                    d.transport.describe(),
                    d.imu
                        .as_ref()
                        .map(|imu| format!(", its IMU {}", imu.name))
                        .unwrap_or_default()
                ))
                .collect::<Vec<_>>()
                .join("; ")
        ),
    };
    let (writer_done_tx, mut writer_done) = oneshot::channel::<WriterExit>();
    let writer_thread = {
        let shared = shared.clone();
        let writer_shared = writer_shared.clone();
        let control = control.clone();
        std::thread::Builder::new()
            .name("imulogd-writer".into())
            .spawn(move || {
                let exit = writer::run_writer(
                    sink,
                    rx,
                    shared,
                    writer_shared,
                    control,
                    settings,
                    free_space,
                );
                let _ = writer_done_tx.send(exit);
            })
    };
    if let Err(e) = writer_thread {
        return Outcome::Failed(anyhow::anyhow!("cannot start the writer thread: {e}"));
    }

    let (shutdown_tx, shutdown_rx) = watch::channel(false);
    let (settled_tx, mut settled_rx) = mpsc::unbounded_channel();
    let mut device_tasks = Vec::new();
    for (index, ((spec, connector), decoders)) in config
        .devices
        .iter()
        .zip(connectors)
        .zip(decoders)
        .enumerate()
    {
        let task = DeviceTask {
            index,
            spec: spec.clone(),
            connector,
            decoders,
            queue: QueueSender::new(tx.clone(), shared[index].clone()),
            shared: shared[index].clone(),
            raw_journal: spec.raw_journal,
            handover,
            settled: Some(settled_tx.clone()),
            watchdog: watchdog.clone(),
        };
        device_tasks.push(tokio::spawn(task.run(shutdown_rx.clone())));
    }
    // Only the device tasks hold senders now: when they all end, the writer sees it.
    drop(tx);
    drop(settled_tx);

    let device_count = config.devices.len();
    let ready_task = tokio::spawn(async move {
        let mut settled = 0;
        while settled < device_count && settled_rx.recv().await.is_some() {
            settled += 1;
        }
        tracing::info!("all {device_count} devices opened or retrying: ready");
        notify(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status("logging"),
        ]);
    });

    // Only under a systemd watchdog: the device thread's answer when the writer nudges it
    // (the writer feeds the watchdog itself while hand-overs show the device thread alive).
    let watchdog_task = watchdog.map(|w| tokio::spawn(async move { w.answer_nudges().await }));

    // Wait for a reason to stop.
    let early_exit: Option<WriterExit> = loop {
        tokio::select! {
            _ = sigterm.recv() => { tracing::info!("SIGTERM: stopping"); break None; }
            _ = sigint.recv() => { tracing::info!("SIGINT: stopping"); break None; }
            _ = sighup.recv() => { tracing::info!("SIGHUP: rotating"); control.request_rotate(); }
            changed = stop.changed() => {
                if changed.is_err() || *stop.borrow() { break None; }
            }
            exit = &mut writer_done => {
                break Some(exit.unwrap_or_else(|_| WriterExit::Failed(anyhow::anyhow!("the writer thread panicked"))));
            }
        }
    };

    // Stop: devices first (so the queue stops growing), then the writer drains and closes.
    notify(&[sd_notify::NotifyState::Stopping]);
    let _ = shutdown_tx.send(true);
    for task in &mut device_tasks {
        if tokio::time::timeout(DEVICE_STOP_TIMEOUT, &mut *task)
            .await
            .is_err()
        {
            task.abort();
        }
    }
    ready_task.abort();
    control.request_stop();
    let writer_exit = match early_exit {
        Some(exit) => exit,
        None => match tokio::time::timeout(WRITER_STOP_TIMEOUT, &mut writer_done).await {
            Ok(Ok(exit)) => exit,
            Ok(Err(_)) => WriterExit::Failed(anyhow::anyhow!("the writer thread panicked")),
            Err(_) => WriterExit::Failed(anyhow::anyhow!(
                "the writer did not close the session within {} ms",
                WRITER_STOP_TIMEOUT.as_millis()
            )),
        },
    };
    if let Some(task) = watchdog_task {
        task.abort();
    }
    let mut tracker = StatusTracker::new(shared, writer_shared, started_mono_ns);
    let mut report = tracker.report(clock::mono_ns(), chrono::Utc::now());
    report.state = "stopped".to_string();
    let written = {
        let _held = status_lock.lock().unwrap_or_else(|p| p.into_inner());
        write_status_file(&status_path, &report)
    };
    // HDF5 does not always pass the errno on (`H5Dwrite_chunk ... failed`): a failed write
    // with the session's file system out of room is a full disk too.
    let disk_full = matches!(&writer_exit, WriterExit::Failed(e) if super::disk::is_disk_full(e))
        || (matches!(writer_exit, WriterExit::Failed(_))
            && super::disk::free_bytes(&session_dir).is_ok_and(|f| f < FULL_DISK_BYTES));
    match written {
        // On a full disk this fails too; the outcome says it once.
        Err(e) if disk_full => tracing::debug!("final status file: {e}"),
        Err(e) => tracing::warn!(
            "cannot write the status file {}: {e}",
            status_path.display()
        ),
        Ok(()) => {}
    }
    match writer_exit {
        WriterExit::Clean => Outcome::Stopped,
        WriterExit::DiskReserve {
            free_bytes,
            reserve_bytes,
        } => Outcome::DiskReserve {
            free_bytes,
            reserve_bytes,
        },
        WriterExit::Failed(_) if disk_full => Outcome::DiskFull { session_dir },
        WriterExit::Failed(e) => Outcome::Failed(e),
    }
}
