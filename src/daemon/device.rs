//! One device task: open the transport, read bytes, timestamp each arrival with both host
//! clocks, decode, map frames to rows, detect gaps, turn decoder counters into events, and
//! when the device vanishes (or never appears) retry with exponential back-off. Data after a
//! reconnect continue in the same session. The task never touches the disk: it hands
//! batches to the writer queue, which drops and counts rather than block.
//!
//! Every frame keeps its own arrival time, but reads are handed to the writer in batches,
//! at the points of a grid shared with the writer and the other devices
//! ([`super::cadence`], period [`batch_window`]): one queue hand-over per device and
//! period rather than per frame, and one writer wake-up per period for all devices; at
//! high rates the batch size limits also keep the number of queued batches, and with it the
//! time the bounded queue can bridge, independent of the rate (one batch per read held
//! ~0.35 s at 100×, see docs/bench/daemon.md).

use std::future::Future;
use std::sync::Arc;
use std::task::Poll;
use std::time::Duration;

use imulab_drivers::codec::candump::{CandumpEncoder, CandumpRecord, IfName};
use imulab_drivers::codec::Encoder;
use imulab_drivers::transport::TransportError;
use imulab_drivers::types::DecoderStats;
use tokio::sync::{mpsc, watch};

use imulab_store::{EventKind, EventRecord};

use super::backoff::Backoff;
use super::cadence::{Cadence, HandoverTimer};
use super::clock::{self, Arrival};
use super::config::{DeviceSpec, Transport};
use super::gap::{Gap, GapDetector};
use super::mapping::{gnss_record, ImuMapping};
use super::pathwatch::PathWatch;
use super::source::{Connector, DecoderFactory, Frame, FrameDecoder, Input, Link, Received};
use super::status::{DeviceShared, DeviceState};
use super::timerel::{gps_time_ns, TimeRelationTracker};
use super::watchdog::Watchdog;
use super::writer::{Batch, QueueSender, WriterGone};

/// Size of one read; at 15 kHz × ~40 bytes a read rarely holds more than a few ms of data.
const READ_BUFFER_BYTES: usize = 16 * 1024;
/// Longest hand-over period: how long a batch collects reads at most before it goes to the
/// writer (see [`batch_window`]).
pub const BATCH_WINDOW_MAX: Duration = Duration::from_millis(250);
/// A batch goes to the writer early once it holds this many rows...
const BATCH_MAX_ROWS: u64 = 1024;
/// ...or this many raw journal bytes (so the queue's memory stays bounded at any rate).
const BATCH_MAX_RAW_BYTES: usize = 64 * 1024;
/// Fewest bytes of input a decoded row takes in any protocol (a WitMotion packet is 11
/// bytes and a row takes several; CSV, NMEA, MIP, VectorNav and UBX frames are longer).
const MIN_INPUT_BYTES_PER_ROW: usize = 8;

/// The most one batch can put on disk by [`super::writer::Batch::disk_bytes`]'s count: a batch
/// is handed over once it holds [`BATCH_MAX_ROWS`] rows or [`BATCH_MAX_RAW_BYTES`] raw bytes,
/// so it holds at most that and one more read ([`READ_BUFFER_BYTES`]).
pub fn max_batch_disk_bytes() -> u64 {
    let rows = BATCH_MAX_ROWS as usize + READ_BUFFER_BYTES / MIN_INPUT_BYTES_PER_ROW;
    let row_bytes = std::mem::size_of::<imulab_store::ImuRecord>()
        .max(std::mem::size_of::<imulab_store::GnssRecord>());
    (2 * rows * row_bytes + BATCH_MAX_RAW_BYTES + READ_BUFFER_BYTES) as u64
}

/// The hand-over period for a flush interval: [`BATCH_WINDOW_MAX`], or a quarter of the
/// flush interval when that is shorter. The store gets the rest of the interval
/// ([`super::run::writer_flush_interval`]): a row still reaches the disk within one flush
/// interval of its arrival (what a SIGKILL can lose).
pub fn batch_window(flush_interval: Duration) -> Duration {
    BATCH_WINDOW_MAX.min(flush_interval / 4)
}

/// Length of one GNSS-time ↔ host-time window.
const TIME_RELATION_WINDOW_S: f64 = 60.0;

/// Quick retries of an open that failed right after the device path appeared, and their
/// spacing (see [`DeviceTask::run`]).
const QUICK_RETRIES: u32 = 10;
const QUICK_RETRY_DELAY: Duration = Duration::from_millis(50);

/// Frames that were waiting in a buffer (the kernel's, a USB adapter's, the device's) when a
/// device was opened arrive together in the first reads after the open, all stamped at read
/// time: their arrival times say nothing about when they were sampled. A read is part of
/// such a burst while it delivers more frames than the device can have sent since the read
/// before (twice the nominal rate, plus one frame); the burst ends at the first read that
/// does not. One `info` event per burst says how many rows and which arrival times
/// (`t_mono_ns` range) it covers.
#[derive(Debug)]
struct BurstTracker {
    rate_hz: f64,
    /// The previous read with frames (at first: when the device was opened).
    prev_mono_ns: i64,
    /// Still in the burst (no read yet within the rate).
    open: bool,
    frames: u64,
    first_mono_ns: i64,
    last_mono_ns: i64,
}

impl BurstTracker {
    fn new(rate_hz: f64, opened_mono_ns: i64) -> Self {
        BurstTracker {
            rate_hz,
            prev_mono_ns: opened_mono_ns,
            open: true,
            frames: 0,
            first_mono_ns: 0,
            last_mono_ns: 0,
        }
    }

    /// A read at `at_mono_ns` that delivered `frames` frames; the finished burst, when this
    /// read ended it.
    fn observe(&mut self, at_mono_ns: i64, frames: u64) -> Option<(u64, i64, i64)> {
        if !self.open || frames == 0 {
            return None;
        }
        let dt_s = (at_mono_ns - self.prev_mono_ns).max(0) as f64 * 1e-9;
        self.prev_mono_ns = at_mono_ns;
        if frames as f64 > 2.0 * self.rate_hz * dt_s + 1.0 {
            if self.frames == 0 {
                self.first_mono_ns = at_mono_ns;
            }
            self.frames += frames;
            self.last_mono_ns = at_mono_ns;
            return None;
        }
        self.finish()
    }

    /// Ends the burst (at its first read within the rate, or when the connection ends).
    fn finish(&mut self) -> Option<(u64, i64, i64)> {
        if !std::mem::replace(&mut self.open, false) || self.frames == 0 {
            return None;
        }
        Some((self.frames, self.first_mono_ns, self.last_mono_ns))
    }
}

/// Everything one device task needs.
pub struct DeviceTask {
    /// Index into the daemon's device list (and the writer's).
    pub index: usize,
    pub spec: DeviceSpec,
    pub connector: Box<dyn Connector>,
    pub decoders: DecoderFactory,
    pub queue: QueueSender,
    pub shared: Arc<DeviceShared>,
    pub raw_journal: bool,
    /// When batches are handed to the writer (the grid the writer flushes on; period
    /// [`batch_window`]).
    pub handover: Cadence,
    /// Told this device's index once: after the first open, or the first failed attempt.
    pub settled: Option<mpsc::UnboundedSender<usize>>,
    /// The systemd watchdog, if any: each hand-over tells it the device thread is alive.
    pub watchdog: Option<Arc<Watchdog>>,
}

/// How a connection ended.
enum ConnectionEnd {
    /// Shutdown requested.
    Stop,
    /// The writer is gone (it failed or stopped): nothing to read for.
    WriterGone,
    /// The device vanished: end of stream or a read error.
    Vanished(String),
    /// A capture file reached its end.
    Finished,
}

/// Reads a device task still makes after shutdown is requested, for what the device had
/// already delivered (see `read_connection`).
const STOP_DRAIN_READS: u32 = 64;

/// Resolves when shutdown is requested (or the sender is gone).
async fn stopped(rx: &mut watch::Receiver<bool>) {
    loop {
        if *rx.borrow_and_update() {
            return;
        }
        if rx.changed().await.is_err() {
            return;
        }
    }
}

/// What woke the read loop.
enum Wake {
    Stop,
    /// The hand-over timer fired (or failed).
    Handover(std::io::Result<()>),
    Read(Result<Received, TransportError>),
}

/// Counters a device task updates at every read, published to its shared status cell at each
/// hand-over (about once per grid period), so the read path takes no lock. The status file is
/// written by the writer right after the hand-overs at a grid point, so it sees them fresh.
#[derive(Debug, Default)]
struct Tally {
    /// Since the last publication.
    bytes: u64,
    gaps: u64,
    ignored_frames: u64,
    imu_rows: u64,
    gnss_rows: u64,
    /// The decoder's totals at the latest read, and the latest sample's arrival.
    decoder: Option<DecoderStats>,
    last_sample_mono_ns: Option<i64>,
}

impl Tally {
    fn publish(&mut self, shared: &DeviceShared) {
        let mut c = shared.counters();
        c.bytes += std::mem::take(&mut self.bytes);
        c.gaps += std::mem::take(&mut self.gaps);
        c.ignored_frames += std::mem::take(&mut self.ignored_frames);
        c.imu_rows += std::mem::take(&mut self.imu_rows);
        c.gnss_rows += std::mem::take(&mut self.gnss_rows);
        if let Some(total) = self.decoder.take() {
            c.frames_ok = total.frames_ok;
            c.frames_bad = total.checksum_errors + total.frames_malformed + total.frames_too_long;
            c.resyncs = total.resyncs;
        }
        if let Some(t) = self.last_sample_mono_ns.take() {
            c.last_sample_mono_ns = Some(t);
        }
    }
}

/// The gap detectors of a device task: the device's own rows, and a receiver's IMU rows
/// (at the IMU's rate) when it has one.
struct Gaps {
    device: GapDetector,
    imu: Option<GapDetector>,
}

/// Per-connection decoding state.
struct Decoding {
    decoder: Box<dyn FrameDecoder>,
    /// Counters of the previous connections' decoders and links.
    base: DecoderStats,
    /// Counters of the current link's own decoding (an slcan adapter's lines).
    link: DecoderStats,
    /// Counters already turned into events.
    reported: DecoderStats,
}

impl Decoding {
    fn total(&self) -> DecoderStats {
        let mut total = self.base;
        total.add(&self.decoder.stats());
        total.add(&self.link);
        total
    }
}

impl DeviceTask {
    fn event(&self, kind: EventKind, at: Arrival, detail: String) -> EventRecord {
        EventRecord {
            t_mono_ns: at.mono_ns,
            t_wall_ns: at.wall_ns,
            device: self.spec.name.clone(),
            kind,
            detail,
        }
    }

    /// The event for a burst of `frames` buffered frames read from `first` to `last` ns.
    fn burst_event(
        &self,
        (frames, first, last): (u64, i64, i64),
        opened_mono_ns: i64,
    ) -> EventRecord {
        let detail = format!(
            "burst after the open: {frames} frames that waited in a buffer arrived {:.1} ms after it, within {:.1} ms; their rows' arrival times (t_mono_ns {first}..={last}) are read times, not sample times",
            (first - opened_mono_ns) as f64 * 1e-6,
            (last - first) as f64 * 1e-6,
        );
        tracing::info!(device = %self.spec.name, "{detail}");
        let now = clock::now();
        EventRecord {
            t_mono_ns: first,
            t_wall_ns: now.wall_ns - (now.mono_ns - first),
            device: self.spec.name.clone(),
            kind: EventKind::Info,
            detail,
        }
    }

    /// Sends one event on its own.
    fn send_event(&self, kind: EventKind, detail: String) -> bool {
        let mut batch = Batch::new(self.index);
        batch.events.push(self.event(kind, clock::now(), detail));
        self.queue.send(batch).is_ok()
    }

    fn settle(&mut self) {
        if let Some(tx) = self.settled.take() {
            let _ = tx.send(self.index);
        }
    }

    /// Runs until shutdown or until the writer is gone.
    pub async fn run(mut self, mut shutdown: watch::Receiver<bool>) {
        let mut backoff = Backoff::new(
            Duration::from_millis(self.spec.retry_initial_ms),
            Duration::from_millis(self.spec.retry_max_ms),
        );
        let mapping = self.spec.imu_mapping();
        let mut gaps = Gaps {
            device: GapDetector::new(self.spec.rate_hz, self.spec.gap_factor),
            imu: self
                .spec
                .imu
                .as_ref()
                .map(|imu| GapDetector::new(imu.rate_hz, self.spec.gap_factor)),
        };
        let mut time_relation = TimeRelationTracker::new(TIME_RELATION_WINDOW_S);
        let mut decoding = Decoding {
            decoder: (self.decoders)(),
            base: DecoderStats::default(),
            link: DecoderStats::default(),
            reported: DecoderStats::default(),
        };
        let mut tally = Tally::default();
        let mut ever_connected = false;
        let mut failed_attempts: u32 = 0;
        let mut down_since_mono_ns: Option<i64> = None;
        let where_ = self.connector.describe();
        let mut path_watch = match &self.spec.transport {
            Transport::Serial(s) => Some(&s.port),
            Transport::Slcan(s) => Some(&s.port),
            _ => None,
        }
        .and_then(|port| match PathWatch::new(port) {
            Ok(w) => Some(w),
            Err(e) => {
                tracing::debug!(device = %self.spec.name, "not watching {}: {e}", port.display());
                None
            }
        });
        // Whether the last wait ended because the device path changed (or is a quick retry
        // after such a wake-up), and how many quick retries are left.
        let mut woken_by_watch = false;
        let mut quick_left: u32 = 0;
        loop {
            if let Some(w) = &mut path_watch {
                w.clear();
            }
            let opened = tokio::select! {
                r = self.connector.connect() => r,
                _ = stopped(&mut shutdown) => break,
            };
            let open_failed = opened.is_err();
            match opened {
                Ok(stream) => {
                    self.settle();
                    backoff.reset();
                    let detail = if ever_connected {
                        let down_s = down_since_mono_ns
                            .map(|t| (clock::mono_ns() - t) as f64 * 1e-9)
                            .unwrap_or(0.0);
                        self.shared.counters().reconnects += 1;
                        let how = if woken_by_watch {
                            ", at once when its path appeared"
                        } else {
                            ""
                        };
                        format!("reopened {where_} after {down_s:.3} s down ({failed_attempts} failed attempts{how})")
                    } else if failed_attempts > 0 {
                        format!("opened {where_} after {failed_attempts} failed attempts")
                    } else {
                        format!("opened {where_}")
                    };
                    tracing::info!(device = %self.spec.name, "{detail}");
                    let kind = if ever_connected {
                        EventKind::Reconnect
                    } else {
                        EventKind::Connect
                    };
                    if !self.send_event(kind, detail) {
                        break;
                    }
                    {
                        let mut c = self.shared.counters();
                        c.state = DeviceState::Connected;
                        c.last_error = None;
                    }
                    ever_connected = true;
                    failed_attempts = 0;
                    // A fresh decoder: a frame cut by the disconnect is not glued to new bytes.
                    decoding.base = decoding.total();
                    decoding.link = DecoderStats::default();
                    decoding.decoder = (self.decoders)();
                    // The gap detector keeps the last arrival: the outage, from the last
                    // sample before the vanish to the first after the reopen, is a gap event
                    // (with its estimate of missing samples) besides the reconnect event.
                    let end = self
                        .read_connection(
                            stream,
                            &mut decoding,
                            &mapping,
                            &mut gaps,
                            &mut time_relation,
                            &mut tally,
                            &mut shutdown,
                        )
                        .await;
                    // Frames the decoder held back (an epoch waiting for its cycle to close).
                    let mut held = Batch::new(self.index);
                    self.decode_chunk(
                        Input::Bytes(&[]),
                        clock::now(),
                        &mut held,
                        &mut decoding,
                        &mapping,
                        &mut gaps,
                        &mut time_relation,
                        &mut tally,
                        true,
                    );
                    let _ = self.hand_over(&mut held, &mut tally).await;
                    match end {
                        ConnectionEnd::Stop | ConnectionEnd::WriterGone => break,
                        ConnectionEnd::Finished => {
                            let detail = format!("{where_}: end of the capture, device done");
                            tracing::info!(device = %self.spec.name, "{detail}");
                            self.send_event(EventKind::Info, detail);
                            break;
                        }
                        // A capture is not reopened: that would play it again.
                        ConnectionEnd::Vanished(why) if self.spec.transport.is_file() => {
                            let detail = format!("{where_}: replay stopped: {why}");
                            tracing::error!(device = %self.spec.name, "{detail}");
                            self.shared.counters().last_error = Some(why);
                            self.send_event(EventKind::Info, detail);
                            break;
                        }
                        ConnectionEnd::Vanished(why) => {
                            let detail = format!("{where_} vanished: {why}; retrying");
                            tracing::warn!(device = %self.spec.name, "{detail}");
                            down_since_mono_ns = Some(clock::mono_ns());
                            {
                                let mut c = self.shared.counters();
                                c.state = DeviceState::Reconnecting;
                                c.last_error = Some(why);
                            }
                            if !self.send_event(EventKind::Disconnect, detail) {
                                break;
                            }
                        }
                    }
                }
                Err(e) if self.spec.transport.is_file() => {
                    let why = format!("cannot open {where_}: {e}");
                    tracing::error!(device = %self.spec.name, "{why}");
                    self.shared.counters().last_error = Some(why.clone());
                    self.send_event(EventKind::Info, why);
                    break;
                }
                Err(e) => {
                    failed_attempts += 1;
                    let why = format!("cannot open {where_}: {e}");
                    {
                        let mut c = self.shared.counters();
                        c.state = if ever_connected {
                            DeviceState::Reconnecting
                        } else {
                            DeviceState::Absent
                        };
                        c.last_error = Some(why.clone());
                    }
                    if !ever_connected && failed_attempts == 1 {
                        // Said once, not on every retry; the status keeps saying it.
                        tracing::error!(device = %self.spec.name, "{why}; retrying with back-off");
                        if !self.send_event(EventKind::Info, format!("{why}; retrying")) {
                            break;
                        }
                    }
                    self.settle();
                }
            }
            // A path that has just appeared may not open yet (a new pty is locked until its
            // creator unlocks it, udev sets a node's mode after creating it, and neither
            // need raise another event): a failed open after a wake-up is tried again soon,
            // a few times, before the back-off resumes.
            let quick = open_failed && quick_left > 0;
            let delay = if quick {
                quick_left -= 1;
                QUICK_RETRY_DELAY
            } else {
                quick_left = 0;
                backoff.next_delay()
            };
            // The back-off bounds the wait; the device path appearing ends it at once.
            let appeared = async {
                match &mut path_watch {
                    Some(w) => w.changed().await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                _ = tokio::time::sleep(delay) => woken_by_watch &= quick,
                _ = appeared => {
                    woken_by_watch = true;
                    quick_left = QUICK_RETRIES;
                }
                _ = stopped(&mut shutdown) => break,
            }
        }
        self.settle();
        self.shared.counters().state = DeviceState::Stopped;
    }

    /// Hands `batch` to the writer (replacing it by an empty one sized like it) and
    /// publishes the counters collected since the last hand-over. A live device's batch is
    /// dropped and counted when the queue is full; a capture's waits for room (its bytes can
    /// wait, and a fast replay outruns any writer).
    async fn hand_over(&self, batch: &mut Batch, tally: &mut Tally) -> Result<(), WriterGone> {
        tally.publish(&self.shared);
        if let Some(watchdog) = &self.watchdog {
            watchdog.device_alive(clock::mono_ns());
        }
        let next = batch.sized_like();
        let batch = std::mem::replace(batch, next);
        if self.spec.transport.is_file() {
            self.queue.send_waiting(batch).await
        } else {
            self.queue.send(batch)
        }
    }

    #[allow(clippy::too_many_arguments)]
    async fn read_connection(
        &self,
        mut link: Box<dyn Link>,
        decoding: &mut Decoding,
        mapping: &ImuMapping,
        gaps: &mut Gaps,
        time_relation: &mut TimeRelationTracker,
        tally: &mut Tally,
        shutdown: &mut watch::Receiver<bool>,
    ) -> ConnectionEnd {
        let mut buffer = vec![0u8; READ_BUFFER_BYTES];
        let opened_mono_ns = clock::mono_ns();
        // A capture has no buffer of the device's: its pieces come as paced.
        let mut burst = (!self.spec.transport.is_file())
            .then(|| BurstTracker::new(self.spec.rows_rate_hz(), opened_mono_ns));
        // The batch being collected, and the grid point it is due at the writer (set by its
        // first read): one timer expiry per period, shared with the other devices' tasks.
        let mut batch = Batch::new(self.index);
        // (The point in CLOCK_MONOTONIC ns, the clock of the arrival times; `timer` holds it as
        // a deadline.)
        let mut due: Option<i64> = None;
        let timer = match HandoverTimer::new() {
            Ok(timer) => timer,
            Err(e) => {
                return ConnectionEnd::Vanished(format!("cannot make the hand-over timer: {e}"))
            }
        };
        // Made once per connection: a fresh one per read registered and removed a waiter on
        // the shutdown channel at every frame. Polled once to register this task's waker,
        // then only when `probe` (an atomic version read) sees the channel changed: polling
        // it at every wake-up locked the channel's waiter list each time. (A task's waker
        // does not change between polls, so the registered one stays valid.)
        let probe = shutdown.clone();
        let stop = stopped(shutdown);
        tokio::pin!(stop);
        let mut stop_polled = false;
        // Whether this wake-up has delivered a read yet, and whether the timer has this
        // task's waker since it was last armed or fired (the same argument as for `stop`).
        let mut read_in_wake = false;
        let mut timer_polled = false;
        // Once shutdown is seen, what the device already delivered (in the kernel's buffer or
        // the link's queue) is still read, without waiting for more: up to this many reads,
        // so a device streaming faster than it is read cannot hold the stop up.
        let mut stopping = false;
        let mut stop_reads_left = STOP_DRAIN_READS;
        let end = loop {
            // One future for the three events, polled in a fixed order: shutdown, the device,
            // then the hand-over timer. The timer is looked at only when a wake-up brought no
            // data (or to register the waker after arming): a read that finds the grid point
            // passed hands over itself, so the timer matters only for a quiet device. A busy
            // device cannot starve the other tasks: tokio's budget makes its reads return
            // `Pending` now and then.
            let wake = std::future::poll_fn(|cx| {
                if !stopping && (!stop_polled || probe.has_changed().unwrap_or(true)) {
                    stop_polled = true;
                    stopping = stop.as_mut().poll(cx).is_ready();
                }
                if stopping {
                    if stop_reads_left == 0 {
                        return Poll::Ready(Wake::Stop);
                    }
                    stop_reads_left -= 1;
                    return match link.poll_receive(cx, &mut buffer) {
                        Poll::Ready(received) => Poll::Ready(Wake::Read(received)),
                        Poll::Pending => Poll::Ready(Wake::Stop),
                    };
                }
                if let Poll::Ready(received) = link.poll_receive(cx, &mut buffer) {
                    read_in_wake = true;
                    return Poll::Ready(Wake::Read(received));
                }
                // Nothing more to read: this wake-up ends here, unless the timer fired.
                let look = due.is_some() && (!read_in_wake || !timer_polled);
                read_in_wake = false;
                if look {
                    timer_polled = true;
                    if let Poll::Ready(fired) = timer.poll_fired(cx) {
                        timer_polled = false;
                        return Poll::Ready(Wake::Handover(fired));
                    }
                }
                Poll::Pending
            })
            .await;
            let received = match wake {
                Wake::Stop => break ConnectionEnd::Stop,
                // A quiet device: what was collected goes out at its grid point.
                Wake::Handover(Err(e)) => {
                    break ConnectionEnd::Vanished(format!("the hand-over timer failed: {e}"))
                }
                Wake::Handover(Ok(())) => {
                    due = None;
                    if self.hand_over(&mut batch, tally).await.is_err() {
                        break ConnectionEnd::WriterGone;
                    }
                    continue;
                }
                Wake::Read(received) => received,
            };
            let at = clock::now();
            decoding.link = link.stats();
            let input = match &received {
                Ok(Received::Bytes(n)) => Input::Bytes(buffer.get(..*n).unwrap_or(&buffer[..])),
                Ok(Received::Can(frame)) => Input::Can(frame),
                Ok(Received::End) => break ConnectionEnd::Finished,
                Err(e) if e.is_retryable() => break ConnectionEnd::Vanished(e.to_string()),
                // Not a vanish (an I/O or protocol error on an open device): reopening is
                // still the only way to carry on, so it is retried the same way.
                Err(e) => break ConnectionEnd::Vanished(format!("error: {e}")),
            };
            let rows_before = batch.rows();
            self.decode_chunk(
                input,
                at,
                &mut batch,
                decoding,
                mapping,
                gaps,
                time_relation,
                tally,
                false,
            );
            if let Some(b) = burst.as_mut() {
                if let Some(done) = b.observe(at.mono_ns, batch.rows() - rows_before) {
                    batch.events.push(self.burst_event(done, opened_mono_ns));
                }
            }
            if batch.is_empty() {
                continue;
            }
            let full =
                batch.rows() >= BATCH_MAX_ROWS || batch.raw_bytes.len() >= BATCH_MAX_RAW_BYTES;
            // A read that finds its grid point passed before the timer fired hands over too
            // (judged on the read's own arrival time: no further clock read per frame).
            if full || due.is_some_and(|d_mono_ns| at.mono_ns >= d_mono_ns) {
                due = None;
                if self.hand_over(&mut batch, tally).await.is_err() {
                    break ConnectionEnd::WriterGone;
                }
            } else if due.is_none() {
                // The grid point on the clock the arrival times are read from (both are
                // CLOCK_MONOTONIC; `at` was read just before `now`).
                let now = std::time::Instant::now();
                let ahead = self.handover.next_after(now).saturating_duration_since(now);
                let d_mono_ns = at
                    .mono_ns
                    .saturating_add(i64::try_from(ahead.as_nanos()).unwrap_or(i64::MAX));
                if let Err(e) = timer.arm(d_mono_ns) {
                    break ConnectionEnd::Vanished(format!("cannot arm the hand-over timer: {e}"));
                }
                timer_polled = false;
                due = Some(d_mono_ns);
            }
        };
        if let Some(done) = burst.as_mut().and_then(BurstTracker::finish) {
            batch.events.push(self.burst_event(done, opened_mono_ns));
        }
        // What was collected is not lost with the connection (nor at shutdown).
        if !matches!(end, ConnectionEnd::WriterGone) {
            let _ = self.hand_over(&mut batch, tally).await;
        }
        end
    }

    /// Adds the raw journal entry for one input to `batch`: the bytes as read, or a CAN
    /// frame as one candump log line (the format `imulab decode --protocol candump --dbc`
    /// reads back).
    fn journal(&self, input: Input<'_>, at: Arrival, batch: &mut Batch) {
        match input {
            Input::Bytes([]) => {}
            Input::Bytes(bytes) => batch.push_raw(at.mono_ns, bytes),
            Input::Can(frame) => {
                let interface = match &self.spec.transport {
                    Transport::Can(c) => c.interface.as_str(),
                    Transport::File(_) => "can0",
                    _ => "slcan0",
                };
                let Ok(interface) = IfName::new(interface).or_else(|_| IfName::new("can")) else {
                    return;
                };
                let record = CandumpRecord {
                    timestamp_us: u64::try_from(at.wall_ns / 1000).unwrap_or(0),
                    interface,
                    frame: *frame,
                };
                let mut line = Vec::with_capacity(48);
                if CandumpEncoder.encode(&record, &mut line).is_ok() {
                    batch.push_raw(at.mono_ns, &line);
                }
            }
        }
    }

    /// Decodes one read's bytes into `batch` and updates the counters; with `finish`, takes
    /// the frames the decoder held back because the input ended.
    #[allow(clippy::too_many_arguments)]
    fn decode_chunk(
        &self,
        input: Input<'_>,
        at: Arrival,
        batch: &mut Batch,
        decoding: &mut Decoding,
        mapping: &ImuMapping,
        gaps: &mut Gaps,
        time_relation: &mut TimeRelationTracker,
        tally: &mut Tally,
        finish: bool,
    ) {
        if self.raw_journal {
            self.journal(input, at, batch);
        }
        let (imu_before, gnss_before) = (batch.imu.len(), batch.gnss.len());
        let input_len = match input {
            Input::Bytes(bytes) => {
                if !bytes.is_empty() {
                    decoding.decoder.push(input);
                }
                bytes.len()
            }
            Input::Can(frame) => {
                decoding.decoder.push(input);
                frame.len()
            }
        };
        // Each gap with whether it is of a receiver's IMU rows.
        let mut new_gaps: Vec<(Gap, bool)> = Vec::new();
        let mut ignored = 0u64;
        let gnss_device = self.spec.protocol.is_gnss();
        let decoder = &mut decoding.decoder;
        while let Some(frame) = if finish {
            decoder.finish()
        } else {
            decoder.poll()
        } {
            // A receiver's IMU samples go to its IMU device; other frames of the other kind
            // than the device's have no table.
            let detector = match (&frame, gnss_device, gaps.imu.as_mut()) {
                (Frame::Imu(_), false, _) | (Frame::Gnss(_), true, _) => Some(&mut gaps.device),
                (Frame::Imu(_), true, imu) => imu,
                (Frame::Gnss(_), false, _) => None,
            };
            let Some(detector) = detector else {
                ignored += 1;
                continue;
            };
            if let Some(gap) = detector.observe(at.mono_ns) {
                new_gaps.push((gap, gnss_device && matches!(frame, Frame::Imu(_))));
            }
            match frame {
                Frame::Imu(sample) => batch.imu.push(mapping.imu_record(&sample, at)),
                Frame::Gnss(fix) => {
                    let gps_ns = fix.week.zip(fix.tow_s).and_then(|(w, t)| gps_time_ns(w, t));
                    if let Some(gps_ns) = gps_ns {
                        if let Some(relation) =
                            time_relation.observe(gps_ns, at.mono_ns, at.wall_ns)
                        {
                            batch.events.push(self.event(
                                EventKind::Info,
                                at,
                                relation.event_detail(),
                            ));
                        }
                    }
                    batch.gnss.push(gnss_record(&fix, at));
                }
            }
        }
        for (gap, of_imu) in &new_gaps {
            let receiver_imu = self.spec.imu.as_ref().filter(|_| *of_imu);
            let detail = format!(
                "no samples for {:.3} s (about {} samples missing at {} Hz)",
                gap.duration_s(),
                gap.missing_estimate,
                receiver_imu.map_or(self.spec.rate_hz, |imu| imu.rate_hz)
            );
            let mut event = self.event(EventKind::Gap, at, detail);
            event.t_mono_ns = gap.from_mono_ns;
            if let Some(imu) = receiver_imu {
                event.device = imu.name.clone();
            }
            batch.events.push(event);
        }
        let total = decoding.total();
        let before = decoding.reported;
        if total.resyncs > before.resyncs
            || total.frames_malformed > before.frames_malformed
            || total.frames_too_long > before.frames_too_long
        {
            batch.events.push(self.event(
                EventKind::Resync,
                at,
                format!(
                    "{} resyncs, {} bytes skipped, {} malformed and {} over-long frames since the last report",
                    total.resyncs - before.resyncs,
                    total.bytes_skipped - before.bytes_skipped,
                    total.frames_malformed - before.frames_malformed,
                    total.frames_too_long - before.frames_too_long
                ),
            ));
        }
        if total.checksum_errors > before.checksum_errors {
            batch.events.push(self.event(
                EventKind::ChecksumError,
                at,
                format!(
                    "{} frames failed their checksum ({} in total)",
                    total.checksum_errors - before.checksum_errors,
                    total.checksum_errors
                ),
            ));
        }
        decoding.reported = total;
        tally.bytes += input_len as u64;
        tally.decoder = Some(total);
        tally.gaps += new_gaps.len() as u64;
        tally.ignored_frames += ignored;
        let new_imu = batch.imu.len() - imu_before;
        let new_gnss = batch.gnss.len() - gnss_before;
        tally.imu_rows += new_imu as u64;
        tally.gnss_rows += new_gnss as u64;
        if new_imu + new_gnss > 0 {
            tally.last_sample_mono_ns = Some(at.mono_ns);
        }
    }
}
