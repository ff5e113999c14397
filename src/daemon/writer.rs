//! The writer thread: the only place that touches the disk. Device tasks hand it batches
//! through one bounded queue with `try_send`, so a slow disk never blocks a reader; a batch
//! the queue has no room for is dropped, counted per device and written as a
//! `queue_overflow` event. The writer also flushes on the hand-over grid
//! ([`super::cadence`]), rotates on request and stops the session cleanly before the disk
//! reserve is reached; a run that ends by itself is checked against the reserve once more
//! after its last rows are written. Between those it sleeps until the next batch, flush or disk check is
//! due; it does not poll.

use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use imulab_store::{EventKind, EventRecord, GnssRecord, ImuRecord};

use super::cadence::{self, Cadence};
use super::clock;
use super::sink::RecordSink;
use super::status::{write_status_file, DeviceShared, StatusTracker, WriterShared};
use super::watchdog::Watchdog;

/// What one device produced over a few reads (a device task collects reads for a short
/// window before it hands them over, so the writer wakes per batch, not per frame).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Batch {
    /// Index of the device (into the daemon's device list).
    pub device: usize,
    pub imu: Vec<ImuRecord>,
    pub gnss: Vec<GnssRecord>,
    pub events: Vec<EventRecord>,
    /// The raw journal, when it is on: each read's arrival time and its bytes' range in
    /// [`Batch::raw_bytes`], in arrival order.
    pub raw: Vec<(i64, std::ops::Range<usize>)>,
    /// The undecoded bytes of every read in [`Batch::raw`], back to back.
    pub raw_bytes: Vec<u8>,
}

impl Batch {
    pub fn new(device: usize) -> Self {
        Batch {
            device,
            ..Batch::default()
        }
    }

    pub fn is_empty(&self) -> bool {
        self.imu.is_empty() && self.gnss.is_empty() && self.events.is_empty() && self.raw.is_empty()
    }

    /// An empty batch for the same device with room for as much as this one holds: the next
    /// period's batch of a steady device grows no more.
    pub fn sized_like(&self) -> Batch {
        Batch {
            device: self.device,
            imu: Vec::with_capacity(self.imu.len()),
            gnss: Vec::with_capacity(self.gnss.len()),
            events: Vec::new(),
            raw: Vec::with_capacity(self.raw.len()),
            raw_bytes: Vec::with_capacity(self.raw_bytes.len()),
        }
    }

    /// Adds one read's undecoded bytes to the raw journal part.
    pub fn push_raw(&mut self, t_mono_ns: i64, bytes: &[u8]) {
        let start = self.raw_bytes.len();
        self.raw_bytes.extend_from_slice(bytes);
        self.raw.push((t_mono_ns, start..self.raw_bytes.len()));
    }

    /// The raw journal entries: arrival time and bytes of each read.
    pub fn raw_reads(&self) -> impl Iterator<Item = (i64, &[u8])> + '_ {
        self.raw
            .iter()
            .map(|(t, range)| (*t, self.raw_bytes.get(range.clone()).unwrap_or_default()))
    }

    /// Rows (IMU and GNSS) in the batch.
    pub fn rows(&self) -> u64 {
        (self.imu.len() + self.gnss.len()) as u64
    }

    /// What writing the batch puts on disk, counted as the disk reserve's floor counts it
    /// ([`super::config::reserve_floor`]): every row twice (its HDF5 dataset and the
    /// journal) at its in-memory size, and the raw bytes.
    pub fn disk_bytes(&self) -> u64 {
        let imu = self.imu.len() * std::mem::size_of::<ImuRecord>();
        let gnss = self.gnss.len() * std::mem::size_of::<GnssRecord>();
        (2 * (imu + gnss) + self.raw_bytes.len()) as u64
    }
}

/// The writer thread is gone; the device task should stop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the writer thread has stopped")]
pub struct WriterGone;

/// A device task's end of the queue: never blocks, counts what it had to drop.
#[derive(Clone)]
pub struct QueueSender {
    tx: SyncSender<Batch>,
    device: Arc<DeviceShared>,
}

impl QueueSender {
    pub fn new(tx: SyncSender<Batch>, device: Arc<DeviceShared>) -> Self {
        QueueSender { tx, device }
    }

    /// Queues a batch, or drops and counts it when the queue is full.
    pub fn send(&self, batch: Batch) -> Result<(), WriterGone> {
        if batch.is_empty() {
            return Ok(());
        }
        match self.tx.try_send(batch) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(batch)) => {
                let mut c = self.device.counters();
                c.dropped_batches += 1;
                c.dropped_rows += batch.rows();
                c.dropped_events += batch.events.len() as u64;
                Ok(())
            }
            Err(TrySendError::Disconnected(_)) => Err(WriterGone),
        }
    }

    /// Queues a batch, waiting (a millisecond at a time, off the writer's thread) while the
    /// queue is full: for sources whose data can wait (a capture played back), so nothing is
    /// dropped.
    pub async fn send_waiting(&self, mut batch: Batch) -> Result<(), WriterGone> {
        if batch.is_empty() {
            return Ok(());
        }
        loop {
            match self.tx.try_send(batch) {
                Ok(()) => return Ok(()),
                Err(TrySendError::Full(back)) => {
                    batch = back;
                    tokio::time::sleep(Duration::from_millis(1)).await;
                }
                Err(TrySendError::Disconnected(_)) => return Err(WriterGone),
            }
        }
    }
}

/// Requests to the writer from the control side (signals, shutdown).
#[derive(Debug, Default)]
pub struct WriterControl {
    rotate: AtomicBool,
    stop: AtomicBool,
}

impl WriterControl {
    /// Rotate to a new chunk file at the writer's next turn (SIGHUP).
    pub fn request_rotate(&self) {
        self.rotate.store(true, Ordering::SeqCst);
    }

    /// Drain the queue, write the stop event, close and return (SIGTERM/SIGINT).
    pub fn request_stop(&self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// Returns the free bytes on the session's filesystem (statvfs in the daemon, injected in tests).
pub type FreeSpaceFn = Box<dyn FnMut() -> io::Result<u64> + Send>;

/// The longest the writer works through a backlog before it looks at stop and rotation
/// requests, the disk and the watchdog again.
const TURN: Duration = Duration::from_millis(50);

/// Writer timing and limits.
#[derive(Debug, Clone)]
pub struct WriterSettings {
    /// The grid the device tasks hand batches over on; the sink is flushed at each of its
    /// points, once the hand-overs there are written (or [`cadence::flush_lag`] after it).
    pub handover: Cadence,
    /// Stop cleanly when free space falls below this many bytes.
    pub reserve_bytes: u64,
    pub disk_check_interval: Duration,
    /// Free space is also checked as soon as this much has been written since the last
    /// check ([`Batch::disk_bytes`]), so a device writing faster than its configured rate (a
    /// `pace = "fast"` replay, a simulator run at a speed-up) cannot fill the disk between
    /// two timed checks; near the reserve, after every batch (`WriterState::check_due_by_volume`).
    pub disk_check_bytes: u64,
    /// Detail of the `session_start` event (config summary).
    pub start_detail: String,
    /// Once stopping, how long the writer may spend writing what is still queued; batches
    /// left after that are dropped and counted, so the session still closes in time.
    pub drain_budget: Duration,
    /// The status file, written by the writer about once a second at one of its turns.
    pub status: StatusFile,
    /// The systemd watchdog, if there is one: looked at every turn, fed when due.
    pub watchdog: Option<Arc<Watchdog>>,
}

/// Where and how often the status file is written.
///
/// The writer writes it, at the first of its turns (it wakes at least at every grid point)
/// that comes at least an interval less half a grid period after the previous report: the
/// writer is the thread that touches the disk anyway and is awake then, so the report costs
/// no wake-up of its own, and the device thread never waits for the file.
#[derive(Debug, Clone)]
pub struct StatusFile {
    pub path: std::path::PathBuf,
    /// About how often (the issue asks for every second).
    pub interval: Duration,
    /// Held while the file is written, so the daemon's final report after the writer's end
    /// (or after it timed out) never interleaves with one from the writer.
    pub lock: Arc<std::sync::Mutex<()>>,
}

/// Why the writer stopped.
#[derive(Debug)]
pub enum WriterExit {
    /// Asked to stop, or every device task ended; the session is closed.
    Clean,
    /// Free space fell below the reserve; the session is closed.
    DiskReserve { free_bytes: u64, reserve_bytes: u64 },
    /// The sink failed (disk error, full filesystem); the session was closed as far as possible.
    Failed(anyhow::Error),
}

/// Runs the writer loop until stopped; closes the sink in every case.
pub fn run_writer(
    mut sink: Box<dyn RecordSink>,
    rx: Receiver<Batch>,
    devices: Vec<Arc<DeviceShared>>,
    shared: Arc<WriterShared>,
    control: Arc<WriterControl>,
    settings: WriterSettings,
    mut free_space: FreeSpaceFn,
) -> WriterExit {
    let tracker = StatusTracker::new(devices.clone(), shared.clone(), clock::mono_ns());
    let mut state = WriterState {
        devices,
        shared,
        reported_drops: Vec::new(),
        tracker,
        last_status: None,
        status_failing: false,
        written_since_check: 0,
        free_seen: None,
        largest_drop: 0,
    };
    state.reported_drops = vec![(0, 0, 0); state.devices.len()];
    {
        let mut w = state.shared.counters();
        w.current_file = sink.current_file();
        w.reserve_bytes = settings.reserve_bytes;
    }
    let started = sink.append_event(&session_event(
        EventKind::SessionStart,
        settings.start_detail.clone(),
    ));
    let outcome = match started {
        Ok(()) => state.main_loop(&mut *sink, &rx, &control, &settings, &mut free_space),
        Err(e) => Err(e),
    };
    state.shared.counters().stopping = true;
    // Whatever stopped us, keep what is already queued (bounded: the queue's capacity plus
    // what the device tasks send while they stop).
    let mut outcome = match outcome {
        Ok(exit) => match state.drain(&mut *sink, &rx, &settings, &mut free_space) {
            Ok(()) => exit,
            Err(e) => WriterExit::Failed(e),
        },
        Err(e) => WriterExit::Failed(e),
    };
    let _ = state.report_drops(&mut *sink);
    // A run that ends by itself (every source done, or a stop) may have taken free space
    // below the reserve after the last check: with its last batches, or with the rows the
    // store still buffers (a short fast replay writes its chunks at the end). Those rows are
    // written now and free space read once more, so a session that ends below the reserve
    // says so (`disk_low`, exit status 3) whichever came first, the end or the check.
    if matches!(outcome, WriterExit::Clean) {
        outcome = match state.check_after_the_last_batch(&mut *sink, &settings, &mut free_space) {
            Ok(exit) => exit,
            Err(e) => WriterExit::Failed(e),
        };
    }
    let reason = match &outcome {
        WriterExit::Clean => "stopped".to_string(),
        WriterExit::DiskReserve {
            free_bytes,
            reserve_bytes,
        } => format!("disk reserve reached: {free_bytes} bytes free, reserve {reserve_bytes}"),
        WriterExit::Failed(e) if super::disk::is_disk_full(e) => {
            "disk full: no space left on device".to_string()
        }
        WriterExit::Failed(e) => format!("write failed: {}", crate::errors::render(e)),
    };
    let _ = sink.append_event(&session_event(EventKind::SessionStop, reason));
    if let Err(e) = sink.close() {
        let failed_before = matches!(outcome, WriterExit::Failed(_));
        if super::disk::is_disk_full(&e) {
            // Said once, by whoever reports the outcome (closing on a full disk fails too).
            tracing::debug!("closing the session on a full disk: {e:#}");
        } else {
            tracing::error!("closing the session failed: {}", crate::errors::render(&e));
        }
        if !failed_before {
            outcome = WriterExit::Failed(e);
        }
    }
    state.shared.counters().current_file = None;
    outcome
}

fn session_event(kind: EventKind, detail: String) -> EventRecord {
    let now = clock::now();
    EventRecord {
        t_mono_ns: now.mono_ns,
        t_wall_ns: now.wall_ns,
        device: String::new(),
        kind,
        detail,
    }
}

struct WriterState {
    devices: Vec<Arc<DeviceShared>>,
    shared: Arc<WriterShared>,
    /// Drop counts (batches, rows, events) already written as events, per device.
    reported_drops: Vec<(u64, u64, u64)>,
    tracker: StatusTracker,
    /// When the status file was last written.
    last_status: Option<Instant>,
    /// The last status write failed (said once, not every second).
    status_failing: bool,
    /// [`Batch::disk_bytes`] written since free space was last checked.
    written_since_check: u64,
    /// Free space at the last check.
    free_seen: Option<u64>,
    /// The most free space has fallen between two checks: what the files really grew by
    /// (HDF5 chunks and metadata, the journal), which the rows' count leaves out.
    largest_drop: u64,
}

impl WriterState {
    /// Notes a free-space reading: the free space and how much it fell since the last one.
    fn saw_free(&mut self, free_bytes: u64) {
        if let Some(before) = self.free_seen {
            self.largest_drop = self.largest_drop.max(before.saturating_sub(free_bytes));
        }
        self.free_seen = Some(free_bytes);
        self.shared.counters().free_bytes = Some(free_bytes);
    }

    /// Whether free space is due to be read again because of what was written since the last
    /// reading: after `check_bytes` of [`Batch::disk_bytes`], and after every batch once the
    /// last reading was within twice the reserve plus twice the largest real fall seen
    /// between two readings, so that the reserve is crossed by at most one batch whatever
    /// the store allocates besides the rows (one statvfs per batch, only near the reserve).
    fn check_due_by_volume(&self, reserve_bytes: u64, check_bytes: u64) -> bool {
        if self.written_since_check == 0 {
            return false;
        }
        let near = reserve_bytes
            .saturating_mul(2)
            .saturating_add(self.largest_drop.saturating_mul(2));
        self.written_since_check >= check_bytes || self.free_seen.is_some_and(|f| f < near)
    }

    fn main_loop(
        &mut self,
        sink: &mut dyn RecordSink,
        rx: &Receiver<Batch>,
        control: &WriterControl,
        settings: &WriterSettings,
        free_space: &mut FreeSpaceFn,
    ) -> anyhow::Result<WriterExit> {
        let lag = cadence::flush_lag(settings.handover.period());
        // The grid point the next flush is for: due once it has passed, and made at the
        // latest `lag` after it (normally the device tasks' hand-overs there wake the writer
        // first).
        let mut flush_point = settings.handover.next_after(Instant::now());
        let mut last_disk_check: Option<Instant> = None;
        let early = settings.handover.period() / 2;
        let early_ns = i64::try_from(early.as_nanos()).unwrap_or(i64::MAX);
        loop {
            // This turn is the writer's sign of life (a wedged writer never gets here).
            if let Some(watchdog) = &settings.watchdog {
                watchdog.writer_turn(clock::mono_ns(), early_ns);
            }
            if control.stop.load(Ordering::SeqCst) {
                return Ok(WriterExit::Clean);
            }
            if last_disk_check.is_none_or(|t| t.elapsed() + early >= settings.disk_check_interval)
                || self.check_due_by_volume(settings.reserve_bytes, settings.disk_check_bytes)
            {
                last_disk_check = Some(Instant::now());
                if let Some(exit) =
                    self.check_reserve(sink, settings, free_space, "closing the session")?
                {
                    return Ok(exit);
                }
            }
            // No wake-up of its own: the writer turns over at every grid point.
            if self
                .last_status
                .is_none_or(|t| t.elapsed() + early >= settings.status.interval)
            {
                self.last_status = Some(Instant::now());
                self.write_status(&settings.status);
            }
            if control.rotate.swap(false, Ordering::SeqCst) {
                self.report_drops(sink)?;
                sink.append_event(&session_event(
                    EventKind::Info,
                    "rotation requested (SIGHUP)".to_string(),
                ))?;
                sink.rotate()?;
                let mut w = self.shared.counters();
                w.rotations += 1;
                w.current_file = sink.current_file();
                tracing::info!("rotated to {:?}", w.current_file);
            }
            // Asleep until a batch comes or the flush is due. The disk check and the status
            // report wait for that turn rather than wake the writer themselves (at most one
            // period late).
            let wake = flush_point + lag;
            // Whether the queue was empty at the end of this turn.
            let mut caught_up = true;
            match rx.recv_timeout(wake.saturating_duration_since(Instant::now())) {
                Ok(batch) => {
                    self.write(sink, batch)?;
                    caught_up = false;
                    // More of a backlog, for up to one turn (or until the next free-space
                    // check is due by volume) before stop, rotation, disk and watchdog are
                    // looked at again.
                    let turn = Instant::now();
                    while turn.elapsed() < TURN
                        && !self
                            .check_due_by_volume(settings.reserve_bytes, settings.disk_check_bytes)
                        && !control.stop.load(Ordering::SeqCst)
                    {
                        match rx.try_recv() {
                            Ok(batch) => self.write(sink, batch)?,
                            Err(_) => {
                                caught_up = true;
                                break;
                            }
                        }
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                // Every device task has ended: nothing more will come.
                Err(RecvTimeoutError::Disconnected) => return Ok(WriterExit::Clean),
            }
            // The periodic flush tells the store that the current time has come, so that a
            // quiet device's last rows are written. Behind a backlog, rows still queued are
            // older than that: the store would write every table's partial chunk (and fsync)
            // at each append, which slowed a lagging writer further until it could never catch
            // up (the losses at 100× in docs/bench/daemon.md). So it waits until the queue is
            // empty; meanwhile the store writes whole chunks as they fill.
            let now = Instant::now();
            if caught_up && now >= flush_point {
                self.report_drops(sink)?;
                // The grid point on the monotonic clock the rows are stamped with.
                let point_mono_ns = clock::mono_ns()
                    - i64::try_from(now.duration_since(flush_point).as_nanos()).unwrap_or(0);
                sink.flush(point_mono_ns)?;
                flush_point = settings.handover.next_after(now);
                let mut w = self.shared.counters();
                w.flushes += 1;
                w.current_file = sink.current_file();
            }
        }
    }

    /// Reads free space; below the reserve, writes the `disk_low` event (its detail ending
    /// with `then`) and returns the exit that stops the session.
    fn check_reserve(
        &mut self,
        sink: &mut dyn RecordSink,
        settings: &WriterSettings,
        free_space: &mut FreeSpaceFn,
        then: &str,
    ) -> anyhow::Result<Option<WriterExit>> {
        self.written_since_check = 0;
        let free_bytes = match free_space() {
            Ok(free_bytes) => free_bytes,
            Err(e) => {
                tracing::warn!("cannot read free disk space: {e}");
                return Ok(None);
            }
        };
        self.saw_free(free_bytes);
        if free_bytes >= settings.reserve_bytes {
            return Ok(None);
        }
        let detail = format!(
            "{free_bytes} bytes free, below the reserve of {} bytes: {then}",
            settings.reserve_bytes
        );
        tracing::error!("{detail}");
        sink.append_event(&session_event(EventKind::DiskLow, detail))?;
        Ok(Some(WriterExit::DiskReserve {
            free_bytes,
            reserve_bytes: settings.reserve_bytes,
        }))
    }

    /// Once the run has ended by itself: writes every row the sink still buffers, then
    /// checks the reserve a last time ([`Self::check_reserve`]).
    fn check_after_the_last_batch(
        &mut self,
        sink: &mut dyn RecordSink,
        settings: &WriterSettings,
        free_space: &mut FreeSpaceFn,
    ) -> anyhow::Result<WriterExit> {
        sink.write_buffered()?;
        let then = "the last batches of the run took it there";
        Ok(self
            .check_reserve(sink, settings, free_space, then)?
            .unwrap_or(WriterExit::Clean))
    }

    /// Writes the status file; a failure is logged, never fatal.
    fn write_status(&mut self, status: &StatusFile) {
        let report = self.tracker.report(clock::mono_ns(), chrono::Utc::now());
        let written = {
            let _held = status.lock.lock().unwrap_or_else(|p| p.into_inner());
            write_status_file(&status.path, &report)
        };
        match written {
            Err(e) if self.status_failing => tracing::debug!("status file: {e}"),
            Err(e) => {
                self.status_failing = true;
                tracing::warn!(
                    "cannot write the status file {}: {e} (said once until it works again)",
                    status.path.display()
                );
            }
            Ok(()) => self.status_failing = false,
        }
    }

    fn write(&mut self, sink: &mut dyn RecordSink, batch: Batch) -> anyhow::Result<()> {
        let Some(device) = self.devices.get(batch.device) else {
            anyhow::bail!("batch for unknown device index {}", batch.device);
        };
        let name = device.name.as_str();
        for (t_mono_ns, bytes) in batch.raw_reads() {
            sink.append_raw(name, t_mono_ns, bytes)?;
        }
        if !batch.imu.is_empty() {
            sink.append_imu(device.imu_device.as_deref().unwrap_or(name), &batch.imu)?;
        }
        if !batch.gnss.is_empty() {
            sink.append_gnss(name, &batch.gnss)?;
        }
        for event in &batch.events {
            sink.append_event(event)?;
        }
        self.shared.counters().rows_written += batch.rows();
        self.written_since_check += batch.disk_bytes();
        Ok(())
    }

    /// Writes what is still queued, for up to the drain budget and while free space stays
    /// above half the reserve (checked after every eighth of the reserve written, and after
    /// every batch near the reserve: a fast replay's full queue could otherwise fill the
    /// disk after the reserve stopped it); what
    /// is left after that (a writer far behind, e.g. on a starved machine) is dropped,
    /// counted per device and written as a `queue_overflow` event, so the session still
    /// closes within the stop deadline and with room to close.
    fn drain(
        &mut self,
        sink: &mut dyn RecordSink,
        rx: &Receiver<Batch>,
        settings: &WriterSettings,
        free_space: &mut FreeSpaceFn,
    ) -> anyhow::Result<()> {
        let started = Instant::now();
        let check_bytes = settings.disk_check_bytes / 2;
        let why = loop {
            if started.elapsed() >= settings.drain_budget {
                break format!(
                    "still queued after {} ms of writing",
                    settings.drain_budget.as_millis()
                );
            }
            if self.check_due_by_volume(settings.reserve_bytes, check_bytes) {
                self.written_since_check = 0;
                match free_space() {
                    Ok(free) if free < settings.reserve_bytes / 2 => {
                        self.saw_free(free);
                        break format!(
                            "still queued with {free} bytes free, below half the reserve"
                        );
                    }
                    Ok(free) => self.saw_free(free),
                    Err(e) => tracing::warn!("cannot read free disk space: {e}"),
                }
            }
            match rx.try_recv() {
                Ok(batch) => self.write(sink, batch)?,
                Err(_) => return Ok(()),
            }
        };
        let mut left = vec![(0u64, 0u64, 0u64); self.devices.len()];
        while let Ok(batch) = rx.try_recv() {
            if let Some(l) = left.get_mut(batch.device) {
                l.0 += 1;
                l.1 += batch.rows();
                l.2 += batch.events.len() as u64;
            }
        }
        for ((device, l), reported) in self
            .devices
            .iter()
            .zip(&left)
            .zip(self.reported_drops.iter_mut())
        {
            if l.0 == 0 {
                continue;
            }
            let total = {
                let mut c = device.counters();
                c.dropped_batches += l.0;
                c.dropped_rows += l.1;
                c.dropped_events += l.2;
                (c.dropped_batches, c.dropped_rows, c.dropped_events)
            };
            let detail = format!(
                "stopping: {} batches ({} rows, {} events) {why} were dropped; {} rows in total",
                l.0, l.1, l.2, total.1
            );
            tracing::warn!(device = %device.name, "{detail}");
            let mut event = session_event(EventKind::QueueOverflow, detail);
            event.device = device.name.clone();
            sink.append_event(&event)?;
            // Counted here; earlier drops not yet reported are left to report_drops.
            reported.0 += l.0;
            reported.1 += l.1;
            reported.2 += l.2;
        }
        Ok(())
    }

    /// Writes a `queue_overflow` event for every device that dropped batches since the last call.
    fn report_drops(&mut self, sink: &mut dyn RecordSink) -> anyhow::Result<()> {
        for (device, reported) in self.devices.iter().zip(self.reported_drops.iter_mut()) {
            let now = {
                let c = device.counters();
                (c.dropped_batches, c.dropped_rows, c.dropped_events)
            };
            if now.0 > reported.0 {
                let detail = format!(
                    "writer queue full: dropped {} batches ({} rows, {} events) since the last report; {} rows in total",
                    now.0 - reported.0,
                    now.1 - reported.1,
                    now.2 - reported.2,
                    now.1
                );
                tracing::warn!(device = %device.name, "{detail}");
                let mut event = session_event(EventKind::QueueOverflow, detail);
                event.device = device.name.clone();
                sink.append_event(&event)?;
                *reported = now;
            }
        }
        Ok(())
    }
}

/// A queue pair sized for `capacity` batches.
pub fn queue(capacity: usize) -> (SyncSender<Batch>, Receiver<Batch>) {
    std::sync::mpsc::sync_channel(capacity)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU64;
    use std::sync::Mutex;

    /// Bytes one IMU row takes on the fake disk.
    const ROW_BYTES: u64 = 100;
    const RESERVE: u64 = 1 << 20;

    /// A sink on a fake disk of `capacity` bytes that, like the store, may keep rows
    /// buffered until `write_buffered` or `close` (when `buffers`), or writes them at once.
    struct FakeDisk {
        capacity: u64,
        used: Arc<AtomicU64>,
        pending: u64,
        buffers: bool,
        events: Arc<Mutex<Vec<EventRecord>>>,
    }

    impl FakeDisk {
        fn free_space(&self) -> FreeSpaceFn {
            let (capacity, used) = (self.capacity, self.used.clone());
            Box::new(move || Ok(capacity.saturating_sub(used.load(Ordering::SeqCst))))
        }

        fn land(&mut self) {
            self.used.fetch_add(self.pending, Ordering::SeqCst);
            self.pending = 0;
        }
    }

    impl RecordSink for FakeDisk {
        fn append_imu(&mut self, _: &str, rows: &[ImuRecord]) -> anyhow::Result<()> {
            self.pending += rows.len() as u64 * ROW_BYTES;
            if !self.buffers {
                self.land();
            }
            Ok(())
        }
        fn append_gnss(&mut self, _: &str, _: &[GnssRecord]) -> anyhow::Result<()> {
            Ok(())
        }
        fn append_event(&mut self, event: &EventRecord) -> anyhow::Result<()> {
            self.events.lock().unwrap().push(event.clone());
            Ok(())
        }
        fn append_raw(&mut self, _: &str, _: i64, _: &[u8]) -> anyhow::Result<()> {
            Ok(())
        }
        fn flush(&mut self, _: i64) -> anyhow::Result<()> {
            Ok(())
        }
        fn write_buffered(&mut self) -> anyhow::Result<()> {
            self.land();
            Ok(())
        }
        fn rotate(&mut self) -> anyhow::Result<()> {
            Ok(())
        }
        fn close(&mut self) -> anyhow::Result<()> {
            self.land();
            Ok(())
        }
        fn current_file(&self) -> Option<std::path::PathBuf> {
            None
        }
    }

    fn row(k: usize) -> ImuRecord {
        ImuRecord {
            t_mono_ns: k as i64 * 1_000_000,
            t_wall_ns: 0,
            t_sensor: k as f64,
            gyro: [0.0; 3],
            accel: [0.0, 0.0, 9.81],
            temp: f64::NAN,
            status: 0,
        }
    }

    /// Runs the writer over `batches` batches of 100 rows (10 000 bytes each) already
    /// queued, on a fake disk whose free space at the start is the reserve plus `above`.
    /// With `stop`, a stop is requested before the writer starts (it drains the queue);
    /// without, the sources have ended (the queue is closed). Returns the exit, the bytes
    /// free at the end and the `disk_low` events.
    fn run_on_fake_disk(
        batches: usize,
        above: u64,
        buffers: bool,
        stop: bool,
    ) -> (WriterExit, u64, Vec<String>) {
        let dir = tempfile::tempdir().unwrap();
        let events = Arc::new(Mutex::new(Vec::new()));
        let sink = FakeDisk {
            capacity: RESERVE + above,
            used: Arc::new(AtomicU64::new(0)),
            pending: 0,
            buffers,
            events: events.clone(),
        };
        let free_space = sink.free_space();
        let mut free_at_end = sink.free_space();
        let (tx, rx) = queue(batches + 1);
        for b in 0..batches {
            let mut batch = Batch::new(0);
            batch.imu = (b * 100..(b + 1) * 100).map(row).collect();
            tx.send(batch).unwrap();
        }
        drop(tx);
        let control = Arc::new(WriterControl::default());
        if stop {
            control.request_stop();
        }
        let settings = WriterSettings {
            handover: Cadence::new(Instant::now(), Duration::from_millis(25)),
            reserve_bytes: RESERVE,
            disk_check_interval: Duration::from_secs(1),
            disk_check_bytes: RESERVE / 4,
            start_detail: "test".into(),
            drain_budget: Duration::from_secs(5),
            status: StatusFile {
                path: dir.path().join("status.json"),
                interval: Duration::from_secs(1),
                lock: Arc::default(),
            },
            watchdog: None,
        };
        let exit = run_writer(
            Box::new(sink),
            rx,
            vec![DeviceShared::new("imu", "csv", "test", 1000.0)],
            Arc::new(WriterShared::default()),
            control,
            settings,
            free_space,
        );
        let low = events
            .lock()
            .unwrap()
            .iter()
            .filter(|e| e.kind == EventKind::DiskLow)
            .map(|e| e.detail.clone())
            .collect();
        (exit, free_at_end().unwrap(), low)
    }

    /// The sources end with the store still buffering their last rows, which take free
    /// space below the reserve when written: the session says so and stops as by the
    /// reserve (exit status 3), not as a clean stop.
    #[test]
    fn rows_written_at_the_end_that_pass_the_reserve_are_a_reserve_stop() {
        // 20 batches = 200 000 bytes on 100 000 above the reserve.
        let (exit, free, low) = run_on_fake_disk(20, 100_000, true, false);
        assert_eq!(free, RESERVE - 100_000);
        match exit {
            WriterExit::DiskReserve {
                free_bytes,
                reserve_bytes,
            } => assert_eq!((free_bytes, reserve_bytes), (RESERVE - 100_000, RESERVE)),
            other => panic!("{other:?}"),
        }
        assert_eq!(low.len(), 1, "{low:?}");
        assert!(
            low[0].contains("below the reserve") && low[0].contains("last batches"),
            "{}",
            low[0]
        );
    }

    /// A stop with a backlog that the drain writes past the reserve (but not past half of
    /// it, where the drain itself would stop): the same reserve stop.
    #[test]
    fn a_drained_backlog_that_passes_the_reserve_is_a_reserve_stop() {
        let (exit, free, low) = run_on_fake_disk(20, 100_000, false, true);
        assert_eq!(free, RESERVE - 100_000);
        assert!(matches!(exit, WriterExit::DiskReserve { .. }), "{exit:?}");
        assert_eq!(low.len(), 1, "{low:?}");
    }

    /// A run that ends above the reserve is a clean stop with no `disk_low`.
    #[test]
    fn a_run_that_ends_above_the_reserve_is_a_clean_stop() {
        for (buffers, stop) in [(true, false), (false, true)] {
            let (exit, free, low) = run_on_fake_disk(20, 300_000, buffers, stop);
            assert_eq!(free, RESERVE + 100_000);
            assert!(matches!(exit, WriterExit::Clean), "{exit:?}");
            assert!(low.is_empty(), "{low:?}");
        }
    }
}
