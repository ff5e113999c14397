//! Serving a scene as device byte streams: every sensor of a scene gets a pseudo-terminal
//! and its frames are written there in its device protocol ([`super::wire`]), paced by the
//! sensor timestamps at real time, accelerated, or as fast as the readers take them. A
//! stand-in for real hardware for the daemon, the demo and tests.
//!
//! # API
//!
//! ```no_run
//! # fn main() -> anyhow::Result<()> {
//! use imulab_sim::scene::Scene;
//! use imulab_sim::serve::{Server, ServeOptions, Speed, StartWhen};
//! let scene = Scene::load("fixtures/scenes/serve_bench.toml".as_ref())?;
//! let mut server = Server::start(
//!     scene,
//!     ServeOptions {
//!         speed: Speed::Factor(10.0),
//!         link_dir: Some("/tmp/imulab-devs".into()),
//!         start: StartWhen::OnDemand,
//!         ..ServeOptions::default()
//!     },
//! )?;
//! for e in server.endpoints() {
//!     println!("{} ({}) at {}", e.sensor, e.protocol.name(), e.path().display());
//! }
//! // ... point the reader (imulogd) at the paths, wait until it has opened them ...
//! server.begin();
//! let report = server.finish()?; // every frame written; the ptys stay open
//! // ... let the reader drain, compare its rows with report.streams[i].sent ...
//! drop(server); // closes the ptys: readers see a hang-up
//! # Ok(()) }
//! ```
//!
//! - [`Server::start`] creates one pty per sensor (raw mode) and, with
//!   [`ServeOptions::link_dir`], a symlink `DIR/<sensor>` → `/dev/pts/N` that stays valid
//!   across reopen faults (re-pointed atomically, like a udev rule). Simulation runs in a
//!   background thread, a block ahead of the writer.
//! - [`StartWhen`] says when the first frame goes out: at once, when a reader has opened
//!   every endpoint (detected as the pty master no longer reporting a hang-up, the way
//!   socat's `wait-slave` does), or when the caller calls [`Server::begin`].
//! - One clock for all sensors: frames of all endpoints are merged in timestamp order
//!   (the record's `t_mono_ns`, i.e. sample time plus jitter, GNSS epochs plus latency) and
//!   each is written when `t / speed` has elapsed since the start. With [`Speed::Max`] the
//!   writer blocks on the slowest reader, so streams stay in step.
//! - [`ServeReport`] (from [`Server::finish`]) says exactly what was sent per endpoint:
//!   with [`ServeOptions::record_sent`], every frame's simulated record and what the drivers'
//!   decoder makes of its bytes ([`SentImu::sample`], [`SentGnss::fixes`]: one merged
//!   fix per epoch, the mixed protocol's NMEA and UBX in one), the pty generation it went to, its scene time and
//!   when it was written; plus counts of frames, bytes, garbage, frames not sent while a
//!   pty was unplugged, frames dropped because a reader stopped reading (paced mode keeps
//!   at most [`PENDING_LIMIT`] bytes per endpoint), and encode errors.
//!   [`SentStream::expected_imu_rows`] / [`SentStream::expected_gnss_rows`] turn them into
//!   the session rows imulogd stores for them (values exact; host times are the simulated
//!   ones, not a reader's arrival times); `imulab sim --serve -o DIR` writes them as a
//!   reference session.
//! - Faults ([`Fault`], from the scene's `[[fault]]` tables and [`ServeOptions::faults`]):
//!   `garbage` writes `bytes` random bytes (deterministic from the seed) between two frames
//!   at `at_s`; `reopen` closes the pty master at `at_s` (the reader gets a hang-up, unread
//!   bytes are lost), removes the symlink, and after `down_s` opens a new pty and points
//!   the symlink at it. Frames due while unplugged are not sent.
//! - slcan endpoints answer the host's commands (`O`, `C`, `L`, `Sn`, ...) with the
//!   adapter's OK (`\r`); frames are sent whether or not the channel was opened.
//! - Bytes written while no reader has the pty open are kept by the kernel (about 64 KiB)
//!   and read by the next reader; start with [`StartWhen::ReadersAttached`] or
//!   [`StartWhen::OnDemand`] when every frame must reach the reader.

use std::collections::VecDeque;
use std::io;
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use imulab_drivers::codec::gnss::EpochFix;
use imulab_drivers::codec::Protocol;
use imulab_drivers::types::ImuSample;
use nix::errno::Errno;
use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::sys::termios;
use serde::{Deserialize, Serialize};

use super::outputs::SimSink;
use super::rng::Stream;
use super::runner;
use super::scene::{Scene, START_MONO_NS};
use super::wire::{GnssWire, ImuWire};
use imulab_ingest::clock::Arrival;
use imulab_ingest::mapping::{gnss_record, ImuMapping};
use imulab_store::{EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord};

/// Most bytes kept per endpoint for a reader that does not keep up (paced mode); frames
/// beyond are dropped and counted, as a UART overrun would lose them.
pub const PENDING_LIMIT: usize = 1 << 20;
/// With [`Speed::Max`], the writer waits for a reader once this much is pending.
const MAX_MODE_PENDING: usize = 64 * 1024;
/// Longest wait, at the end of the scene, for readers to take the last pending bytes.
const DRAIN_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest single sleep of the writer loop (bounds the reaction to stop and attach).
const TICK: Duration = Duration::from_millis(20);

/// How fast the scene is played.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Speed {
    /// Scene seconds per wall-clock second (1 = real time, 100 = a hundred times faster).
    Factor(f64),
    /// As fast as the slowest reader takes the bytes.
    Max,
}

impl FromStr for Speed {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s.eq_ignore_ascii_case("max") {
            return Ok(Speed::Max);
        }
        match s.parse::<f64>() {
            Ok(f) if f.is_finite() && f > 0.0 && f <= 1e9 => Ok(Speed::Factor(f)),
            _ => Err(format!(
                "speed must be a factor > 0 (1 = real time) or `max`, got {s:?}"
            )),
        }
    }
}

/// When the first frame is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StartWhen {
    Now,
    /// Once every endpoint's pty has been opened by a reader.
    ReadersAttached,
    /// When [`Server::begin`] is called.
    OnDemand,
}

/// What a fault does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// Write `bytes` random bytes between two frames.
    Garbage,
    /// Close the pty, and open a new one (same symlink) after `down_s`.
    Reopen,
}

/// A fault injected into one endpoint's stream at scene time `at_s` (a `[[fault]]` table).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Fault {
    /// The sensor (endpoint) name.
    pub sensor: String,
    pub at_s: f64,
    pub kind: FaultKind,
    /// Garbage: how many bytes.
    #[serde(default)]
    pub bytes: usize,
    /// Reopen: how long the device stays unplugged, s.
    #[serde(default)]
    pub down_s: f64,
}

impl Fault {
    /// Checks the fault; `sensors` are the scene's sensor names.
    pub fn check(&self, sensors: &[&str]) -> Result<()> {
        if !sensors.contains(&self.sensor.as_str()) {
            bail!(
                "sensor {:?} is not in the scene (sensors: {})",
                self.sensor,
                sensors.join(", ")
            );
        }
        if !(self.at_s.is_finite() && self.at_s >= 0.0) {
            bail!("at_s must be a time >= 0 s, got {}", self.at_s);
        }
        match self.kind {
            FaultKind::Garbage => {
                if !(1..=1 << 20).contains(&self.bytes) || self.down_s != 0.0 {
                    bail!("garbage: bytes must be 1..=1048576 and down_s is not used");
                }
            }
            FaultKind::Reopen => {
                if !(self.down_s.is_finite() && self.down_s >= 0.0) || self.bytes != 0 {
                    bail!("reopen: down_s must be >= 0 s and bytes is not used");
                }
            }
        }
        Ok(())
    }
}

/// How to serve.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    pub speed: Speed,
    /// Directory for the stable symlinks `<dir>/<sensor>` (created if missing).
    pub link_dir: Option<PathBuf>,
    pub start: StartWhen,
    /// Keep every sent frame in the report (memory grows with the scene).
    pub record_sent: bool,
    /// Faults in addition to the scene's.
    pub faults: Vec<Fault>,
}

impl Default for ServeOptions {
    fn default() -> Self {
        ServeOptions {
            speed: Speed::Factor(1.0),
            link_dir: None,
            start: StartWhen::Now,
            record_sent: true,
            faults: Vec::new(),
        }
    }
}

/// One served sensor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Endpoint {
    pub sensor: String,
    #[serde(serialize_with = "protocol_name")]
    pub protocol: Protocol,
    /// The pty's slave device at start (`/dev/pts/N`); a reopen fault changes it.
    pub pty: PathBuf,
    /// The stable symlink, when a link directory was given.
    pub link: Option<PathBuf>,
}

fn protocol_name<S: serde::Serializer>(p: &Protocol, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(p.name())
}

impl Endpoint {
    /// What a reader opens: the symlink when there is one, else the pty.
    pub fn path(&self) -> &Path {
        self.link.as_deref().unwrap_or(&self.pty)
    }
}

/// One IMU record as sent.
#[derive(Debug, Clone, PartialEq)]
pub struct SentImu {
    /// Scene time of the frame (its `t_mono_ns` from the scene start), ns.
    pub t_ns: i64,
    /// When it was written, ns since the first frame's start time.
    pub written_ns: u64,
    /// Which pty it went to (0 first, +1 per reopen).
    pub generation: u32,
    /// The simulated record.
    pub record: ImuRecord,
    /// What the drivers' decoder makes of the frame's bytes.
    pub sample: Option<ImuSample>,
}

/// One GNSS epoch as sent.
#[derive(Debug, Clone, PartialEq)]
pub struct SentGnss {
    pub t_ns: i64,
    pub written_ns: u64,
    pub generation: u32,
    pub record: GnssRecord,
    /// The merged epochs the drivers' GNSS decoder makes of the bytes: one per epoch (the
    /// mixed protocol's NMEA and UBX messages merged into one fix).
    pub fixes: Vec<EpochFix>,
}

/// The frames of one endpoint.
#[derive(Debug, Clone, PartialEq)]
pub enum Sent {
    Imu(Vec<SentImu>),
    Gnss(Vec<SentGnss>),
}

/// A fault as applied.
#[derive(Debug, Clone, PartialEq)]
pub struct AppliedFault {
    pub fault: Fault,
    /// Frames of this endpoint sent before it.
    pub after_frames: u64,
}

/// What was sent to one endpoint.
#[derive(Debug, Clone, PartialEq)]
pub struct SentStream {
    pub sensor: String,
    pub protocol: Protocol,
    /// Frames written (one per IMU record or GNSS epoch).
    pub frames: u64,
    pub bytes: u64,
    pub garbage_bytes: u64,
    /// Frames not sent because the pty was unplugged (reopen fault).
    pub frames_unplugged: u64,
    /// Frames dropped because the reader did not keep up.
    pub frames_overflowed: u64,
    /// Bytes written into a pty that was then closed before they were read... or not:
    /// the kernel does not say. Bytes still queued here at a close are counted.
    pub bytes_discarded_at_close: u64,
    pub encode_errors: u64,
    pub first_encode_error: Option<String>,
    pub faults: Vec<AppliedFault>,
    /// Every frame, when [`ServeOptions::record_sent`].
    pub sent: Sent,
}

impl SentStream {
    /// The IMU rows a reader that got every frame of this stream stores, mapped the way
    /// imulogd maps a sample (identity axes and scales): the decoded values, the record's
    /// simulated host timestamps. Empty for a GNSS stream or without `record_sent`.
    pub fn expected_imu_rows(&self) -> Vec<ImuRecord> {
        let Sent::Imu(frames) = &self.sent else {
            return Vec::new();
        };
        let mapping = ImuMapping {
            body_from_sensor: nalgebra::Matrix3::identity(),
            gyro_scale: 1.0,
            accel_scale: 1.0,
        };
        frames
            .iter()
            .filter_map(|f| {
                let at = Arrival {
                    mono_ns: f.record.t_mono_ns,
                    wall_ns: f.record.t_wall_ns,
                };
                f.sample.map(|s| mapping.imu_record(&s, at))
            })
            .collect()
    }

    /// The GNSS rows a reader that got every epoch stores: one per merged epoch (the mixed
    /// protocol's NMEA and UBX messages make one), with the epoch's simulated arrival
    /// times. Empty for an IMU stream or without `record_sent`.
    pub fn expected_gnss_rows(&self) -> Vec<GnssRecord> {
        let Sent::Gnss(frames) = &self.sent else {
            return Vec::new();
        };
        frames
            .iter()
            .flat_map(|f| {
                let at = Arrival {
                    mono_ns: f.record.t_mono_ns,
                    wall_ns: f.record.t_wall_ns,
                };
                f.fixes.iter().map(move |e| gnss_record(&e.fix, at))
            })
            .collect()
    }
}

/// What a serve did.
#[derive(Debug, Clone, PartialEq)]
pub struct ServeReport {
    /// One per endpoint, in [`Server::endpoints`] order.
    pub streams: Vec<SentStream>,
    /// Wall-clock time from the first frame's start time to the last write.
    pub elapsed: Duration,
    /// Scene time of the last frame, s.
    pub scene_end_s: f64,
    /// The serve was stopped before the scene ended.
    pub stopped: bool,
    /// Bytes still unread by a reader when the drain timeout expired.
    pub undelivered_bytes: u64,
}

/// A running serve. Dropping it stops the serve and closes the ptys.
pub struct Server {
    endpoints: Vec<Endpoint>,
    shared: Arc<Shared>,
    writer: Option<JoinHandle<Result<Served>>>,
    producer: Option<JoinHandle<()>>,
    ptys: Vec<Option<Pty>>,
}

/// What the writer thread hands back: the report and the ptys, kept open for readers.
type Served = (ServeReport, Vec<Option<Pty>>);

struct Shared {
    stop: AtomicBool,
    go: AtomicBool,
    finished: AtomicBool,
    /// Current pty of each endpoint.
    ptys: Mutex<Vec<PathBuf>>,
}

impl Server {
    /// Opens the ptys (and symlinks) and starts serving `scene` in background threads.
    pub fn start(mut scene: Scene, options: ServeOptions) -> Result<Server> {
        if let Speed::Factor(f) = options.speed {
            if !(f.is_finite() && f > 0.0) {
                bail!("speed must be > 0, got {f}");
            }
        }
        let names: Vec<&str> = scene
            .imus
            .iter()
            .map(|i| i.name.as_str())
            .chain(scene.gnss.iter().map(|g| g.name.as_str()))
            .collect();
        if names.is_empty() {
            bail!("the scene has no sensors to serve");
        }
        for (i, fault) in options.faults.iter().enumerate() {
            fault
                .check(&names)
                .with_context(|| format!("serve fault {i}"))?;
        }
        let mut faults: Vec<Fault> = scene
            .faults
            .iter()
            .chain(&options.faults)
            .cloned()
            .collect();
        faults.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        if let Some(dir) = &options.link_dir {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create link directory {}", dir.display()))?;
        }
        let mut wires = Vec::new();
        for imu in &scene.imus {
            wires.push(Wire::Imu(Box::new(
                ImuWire::with_output(imu.protocol, imu.channels, scene.rate_hz, imu.output)
                    .with_context(|| format!("imu {}", imu.name))?,
            )));
        }
        for rx in &scene.gnss {
            wires.push(Wire::Gnss(
                GnssWire::new(rx.protocol).with_context(|| format!("gnss {}", rx.name))?,
            ));
        }
        let mut endpoints = Vec::new();
        let mut ptys = Vec::new();
        for (name, wire) in names.iter().zip(&wires) {
            let pty = Pty::open().with_context(|| format!("cannot open a pty for {name}"))?;
            let link = match &options.link_dir {
                Some(dir) => {
                    let link = dir.join(name);
                    point_link(&link, &pty.path)?;
                    Some(link)
                }
                None => None,
            };
            endpoints.push(Endpoint {
                sensor: (*name).to_string(),
                protocol: wire.protocol(),
                pty: pty.path.clone(),
                link,
            });
            ptys.push(pty);
        }
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            go: AtomicBool::new(options.start == StartWhen::Now),
            finished: AtomicBool::new(false),
            ptys: Mutex::new(endpoints.iter().map(|e| e.pty.clone()).collect()),
        });
        // Only the records are needed: no truth.
        scene.outputs.truth_nav = false;
        scene.outputs.truth_imu = false;
        let (tx, rx) = sync_channel::<Vec<Item>>(4);
        let record = options.record_sent;
        let producer_scene = scene.clone();
        let producer_wires = wires;
        let producer = std::thread::Builder::new()
            .name("sim-serve-producer".into())
            .spawn(move || {
                let mut sink = ItemSink::new(&producer_scene, producer_wires, tx, record);
                if let Err(e) = runner::run(&producer_scene, &mut sink) {
                    sink.fail(e);
                }
            })
            .context("cannot start the simulation thread")?;
        let writer_shared = Arc::clone(&shared);
        let states: Vec<EndpointState> = endpoints
            .iter()
            .zip(ptys)
            .enumerate()
            .map(|(i, (e, pty))| EndpointState::new(e, pty, i < scene.imus.len()))
            .collect();
        let seed = scene.seed;
        let writer = std::thread::Builder::new()
            .name("sim-serve-writer".into())
            .spawn(move || {
                let mut w = Writer {
                    shared: writer_shared,
                    speed: options.speed,
                    start: options.start,
                    eps: states,
                    faults: faults.into(),
                    seed,
                    t0: Instant::now(),
                    record,
                    last_t_ns: 0,
                    garbage_count: 0,
                };
                let result = w.run(rx);
                w.shared.finished.store(true, Ordering::SeqCst);
                result
            })
            .context("cannot start the serve thread")?;
        Ok(Server {
            endpoints,
            shared,
            writer: Some(writer),
            producer: Some(producer),
            ptys: Vec::new(),
        })
    }

    pub fn endpoints(&self) -> &[Endpoint] {
        &self.endpoints
    }

    /// The pty endpoint `index` is served on now (changes with reopen faults).
    pub fn current_pty(&self, index: usize) -> Option<PathBuf> {
        self.shared.ptys.lock().ok()?.get(index).cloned()
    }

    /// Starts the stream ([`StartWhen::OnDemand`]); harmless otherwise.
    pub fn begin(&self) {
        self.shared.go.store(true, Ordering::SeqCst);
    }

    /// Asks the serve to stop after the current frame.
    pub fn stop(&self) {
        self.shared.stop.store(true, Ordering::SeqCst);
    }

    /// Every frame has been written (or the serve stopped or failed).
    pub fn is_finished(&self) -> bool {
        self.shared.finished.load(Ordering::SeqCst)
    }

    /// Waits until the scene has been served and returns what was sent. The ptys stay open
    /// (readers can drain them) until the server is dropped.
    pub fn finish(&mut self) -> Result<ServeReport> {
        let writer = self
            .writer
            .take()
            .ok_or_else(|| anyhow!("finish was already called"))?;
        let outcome = writer
            .join()
            .map_err(|_| anyhow!("the serve thread panicked"))?;
        if let Some(p) = self.producer.take() {
            // The producer ends once the writer dropped its receiver.
            let _ = p.join();
        }
        let (report, ptys) = outcome?;
        self.ptys = ptys;
        Ok(report)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop();
        if let Some(w) = self.writer.take() {
            let _ = w.join();
        }
        if let Some(p) = self.producer.take() {
            let _ = p.join();
        }
        for e in &self.endpoints {
            if let Some(link) = &e.link {
                let _ = std::fs::remove_file(link);
            }
        }
    }
}

enum Wire {
    Imu(Box<ImuWire>),
    Gnss(GnssWire),
}

impl Wire {
    fn protocol(&self) -> Protocol {
        match self {
            Wire::Imu(w) => w.protocol(),
            Wire::Gnss(w) => w.protocol(),
        }
    }
}

/// A pty whose master we write; the slave is closed so a hang-up tells "no reader".
struct Pty {
    master: OwnedFd,
    path: PathBuf,
}

impl Pty {
    fn open() -> Result<Pty> {
        let pair = nix::pty::openpty(None, None).context("openpty")?;
        let mut attrs = termios::tcgetattr(&pair.slave).context("tcgetattr")?;
        termios::cfmakeraw(&mut attrs);
        termios::tcsetattr(&pair.slave, termios::SetArg::TCSANOW, &attrs).context("tcsetattr")?;
        let path = nix::unistd::ttyname(&pair.slave).context("ttyname")?;
        let flags = fcntl(&pair.master, FcntlArg::F_GETFL).context("fcntl")?;
        fcntl(
            &pair.master,
            FcntlArg::F_SETFL(OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK),
        )
        .context("fcntl")?;
        // Closing our slave makes the master report a hang-up until a reader opens it.
        drop(pair.slave);
        Ok(Pty {
            master: pair.master,
            path,
        })
    }
}

/// Points `link` at `target` atomically (a new symlink renamed over the old one).
fn point_link(link: &Path, target: &Path) -> Result<()> {
    let tmp = link.with_extension("imulab-new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)
        .with_context(|| format!("cannot create symlink {}", tmp.display()))?;
    std::fs::rename(&tmp, link)
        .with_context(|| format!("cannot move symlink into place at {}", link.display()))
}

/// One frame ready to write.
struct Item {
    t_ns: i64,
    endpoint: usize,
    bytes: Vec<u8>,
    sent: Option<SentFrame>,
    /// Encoding failed: count it, send nothing.
    error: Option<String>,
}

impl Item {
    /// One record's frame: its bytes and, when recording, what a decoder makes of them; or, when
    /// encoding failed, why.
    fn encoded(
        endpoint: usize,
        t_ns: i64,
        bytes: Vec<u8>,
        result: Result<(), imulab_drivers::codec::EncodeError>,
        sent: impl FnOnce(&[u8]) -> Option<SentFrame>,
    ) -> Item {
        match result {
            Ok(()) => Item {
                t_ns,
                endpoint,
                sent: sent(&bytes),
                bytes,
                error: None,
            },
            Err(e) => Item {
                t_ns,
                endpoint,
                bytes,
                sent: None,
                error: Some(format!("t = {:.6} s: {e}", t_ns as f64 * 1e-9)),
            },
        }
    }
}

enum SentFrame {
    Imu(ImuRecord, Option<ImuSample>),
    Gnss(GnssRecord, Vec<EpochFix>),
}

/// The runner's sink on the producer side: encodes each record, merges all endpoints in
/// time order, and hands blocks to the writer.
struct ItemSink {
    wires: Vec<Wire>,
    names: Vec<String>,
    /// Per endpoint, the time of its latest record (its later records come after it).
    last_t: Vec<Option<i64>>,
    pending: Vec<(i64, usize, u64, Item)>,
    seq: u64,
    record: bool,
    tx: SyncSender<Vec<Item>>,
}

impl ItemSink {
    fn new(scene: &Scene, wires: Vec<Wire>, tx: SyncSender<Vec<Item>>, record: bool) -> Self {
        let names: Vec<String> = scene
            .imus
            .iter()
            .map(|i| i.name.clone())
            .chain(scene.gnss.iter().map(|g| g.name.clone()))
            .collect();
        ItemSink {
            last_t: vec![None; wires.len()],
            wires,
            names,
            pending: Vec::new(),
            seq: 0,
            record,
            tx,
        }
    }

    fn index(&self, device: &str) -> Result<usize> {
        self.names
            .iter()
            .position(|n| n == device)
            .ok_or_else(|| anyhow!("internal: unknown device {device}"))
    }

    fn push(&mut self, endpoint: usize, t_ns: i64, item: Item) {
        self.pending.push((t_ns, endpoint, self.seq, item));
        self.seq += 1;
        self.last_t[endpoint] = Some(t_ns);
    }

    /// Sends every item no later record can precede; `all` at the end of the run.
    fn flush(&mut self, all: bool) -> Result<()> {
        let horizon = if all {
            i64::MAX
        } else {
            match self.last_t.iter().flatten().min() {
                Some(&h) => h,
                None => return Ok(()),
            }
        };
        self.pending.sort_by_key(|(t, ep, seq, _)| (*t, *ep, *seq));
        let split = self.pending.partition_point(|(t, ..)| *t <= horizon);
        if split == 0 {
            return Ok(());
        }
        let rest = self.pending.split_off(split);
        let ready: Vec<Item> = std::mem::replace(&mut self.pending, rest)
            .into_iter()
            .map(|(.., item)| item)
            .collect();
        self.tx.send(ready).map_err(|_| anyhow!("serve stopped"))
    }

    fn fail(&mut self, error: anyhow::Error) {
        let item = Item {
            t_ns: i64::MAX,
            endpoint: usize::MAX,
            bytes: Vec::new(),
            sent: None,
            error: Some(format!("{error:#}")),
        };
        let _ = self.tx.send(vec![item]);
    }
}

impl SimSink for ItemSink {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()> {
        let ep = self.index(device)?;
        for r in records {
            let Wire::Imu(wire) = &self.wires[ep] else {
                bail!("internal: {device} is not an IMU");
            };
            let mut bytes = Vec::new();
            let t_ns = r.t_mono_ns - START_MONO_NS;
            let result = wire.encode(r, &mut bytes);
            let record = self.record;
            let item = Item::encoded(ep, t_ns, bytes, result, |b| {
                record.then(|| SentFrame::Imu(*r, wire.decode_one(b)))
            });
            self.push(ep, t_ns, item);
        }
        if ep + 1 == self.wires.len() {
            self.flush(false)?;
        }
        Ok(())
    }

    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()> {
        let ep = self.index(device)?;
        for r in records {
            let Wire::Gnss(wire) = &self.wires[ep] else {
                bail!("internal: {device} is not a GNSS receiver");
            };
            let mut bytes = Vec::new();
            let t_ns = r.t_mono_ns - START_MONO_NS;
            let result = wire.encode(r, &mut bytes);
            let record = self.record;
            let item = Item::encoded(ep, t_ns, bytes, result, |b| {
                record.then(|| SentFrame::Gnss(*r, wire.decode_one(b)))
            });
            self.push(ep, t_ns, item);
        }
        if ep + 1 == self.wires.len() {
            self.flush(false)?;
        }
        Ok(())
    }

    fn truth_nav(&mut self, _records: &[TruthNavRecord]) -> Result<()> {
        Ok(())
    }

    fn truth_imu(&mut self, _device: &str, _records: &[TruthImuRecord]) -> Result<()> {
        Ok(())
    }

    fn event(&mut self, _event: &EventRecord) -> Result<()> {
        // The runner's only event is the session stop: everything is in.
        self.flush(true)
    }
}

/// The writer's view of one endpoint.
struct EndpointState {
    pty: Option<Pty>,
    link: Option<PathBuf>,
    /// Bytes waiting for the reader, and how much of the front is written.
    pending: VecDeque<u8>,
    generation: u32,
    /// Unplugged until this scene time.
    down_until_ns: Option<i64>,
    attached: bool,
    slcan: bool,
    /// Partial host command line (slcan).
    command: Vec<u8>,
    stream: SentStream,
}

impl EndpointState {
    fn new(e: &Endpoint, pty: Pty, imu: bool) -> Self {
        EndpointState {
            pty: Some(pty),
            link: e.link.clone(),
            pending: VecDeque::new(),
            generation: 0,
            down_until_ns: None,
            attached: false,
            slcan: e.protocol == Protocol::Slcan,
            command: Vec::new(),
            stream: SentStream {
                sensor: e.sensor.clone(),
                protocol: e.protocol,
                frames: 0,
                bytes: 0,
                garbage_bytes: 0,
                frames_unplugged: 0,
                frames_overflowed: 0,
                bytes_discarded_at_close: 0,
                encode_errors: 0,
                first_encode_error: None,
                faults: Vec::new(),
                sent: if imu {
                    Sent::Imu(Vec::new())
                } else {
                    Sent::Gnss(Vec::new())
                },
            },
        }
    }

    /// Writes as much pending data as the pty takes.
    fn write_some(&mut self) {
        let Some(pty) = &self.pty else {
            return;
        };
        while !self.pending.is_empty() {
            let (front, _) = self.pending.as_slices();
            match nix::unistd::write(pty.master.as_fd(), front) {
                Ok(0) | Err(Errno::EAGAIN) => return,
                Ok(n) => {
                    self.pending.drain(..n);
                }
                Err(Errno::EINTR) => {}
                Err(_) => {
                    // The pty is unusable; what is queued is lost like bytes on a cut line.
                    self.stream.bytes_discarded_at_close += self.pending.len() as u64;
                    self.pending.clear();
                    return;
                }
            }
        }
    }

    /// Reads what the reader sent (echo, host commands) and answers slcan commands.
    fn read_some(&mut self) {
        let Some(pty) = &self.pty else {
            return;
        };
        let mut buf = [0u8; 512];
        loop {
            match nix::unistd::read(pty.master.as_fd(), &mut buf) {
                Ok(0) | Err(_) => return,
                Ok(n) => {
                    if !self.slcan {
                        continue;
                    }
                    for &b in &buf[..n] {
                        if b == b'\r' {
                            // Every command gets the adapter's OK; frames keep flowing.
                            if !self.command.is_empty() {
                                self.pending.push_back(b'\r');
                            }
                            self.command.clear();
                        } else if self.command.len() < 64 {
                            self.command.push(b);
                        }
                    }
                }
            }
        }
    }
}

struct Writer {
    shared: Arc<Shared>,
    speed: Speed,
    start: StartWhen,
    eps: Vec<EndpointState>,
    faults: VecDeque<Fault>,
    seed: u64,
    t0: Instant,
    record: bool,
    last_t_ns: i64,
    garbage_count: u64,
}

/// Poll on raw fds. nix's `poll` feature is not enabled in this workspace; `libc::poll` is
/// the same call.
fn poll(fds: &mut [libc::pollfd], timeout: Duration) -> io::Result<()> {
    let ms = i32::try_from(timeout.as_millis()).unwrap_or(i32::MAX);
    // SAFETY: `fds` is a valid, exclusively borrowed slice of pollfd for the whole call.
    let n = unsafe { libc::poll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, ms) };
    if n < 0 {
        let e = io::Error::last_os_error();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
    Ok(())
}

impl Writer {
    fn stopped(&self) -> bool {
        self.shared.stop.load(Ordering::SeqCst)
    }

    fn run(&mut self, rx: Receiver<Vec<Item>>) -> Result<Served> {
        self.wait_for_start()?;
        self.t0 = Instant::now();
        let mut stopped = false;
        'blocks: for block in rx.iter() {
            for item in block {
                if let Some(e) = &item.error {
                    if item.endpoint == usize::MAX {
                        bail!("simulation failed: {e}");
                    }
                }
                if !self.wait_until(item.t_ns)? {
                    stopped = true;
                    break 'blocks;
                }
                self.send(item)?;
            }
        }
        drop(rx);
        let elapsed = self.t0.elapsed();
        let undelivered = if stopped { 0 } else { self.drain()? };
        let report = ServeReport {
            streams: self.eps.iter().map(|e| e.stream.clone()).collect(),
            elapsed,
            scene_end_s: self.last_t_ns as f64 * 1e-9,
            stopped,
            undelivered_bytes: undelivered,
        };
        let ptys = self.eps.iter_mut().map(|e| e.pty.take()).collect();
        Ok((report, ptys))
    }

    fn wait_for_start(&mut self) -> Result<()> {
        loop {
            if self.stopped() {
                return Ok(());
            }
            match self.start {
                StartWhen::Now => return Ok(()),
                StartWhen::OnDemand if self.shared.go.load(Ordering::SeqCst) => return Ok(()),
                StartWhen::ReadersAttached => {
                    self.pump(Duration::ZERO)?;
                    if self.eps.iter().all(|e| e.attached) {
                        return Ok(());
                    }
                }
                StartWhen::OnDemand => {}
            }
            std::thread::sleep(TICK / 2);
        }
    }

    /// Waits until scene time `t_ns` is due, pumping I/O; `false` when stopped.
    fn wait_until(&mut self, t_ns: i64) -> Result<bool> {
        self.apply_faults(t_ns)?;
        loop {
            if self.stopped() {
                return Ok(false);
            }
            let wait = match self.speed {
                Speed::Max => Duration::ZERO,
                Speed::Factor(f) => {
                    let due = Duration::from_secs_f64((t_ns.max(0) as f64 * 1e-9) / f);
                    due.saturating_sub(self.t0.elapsed())
                }
            };
            if wait.is_zero() {
                self.pump(Duration::ZERO)?;
                return Ok(true);
            }
            self.pump(wait.min(TICK))?;
        }
    }

    /// One round of I/O: refreshes which endpoints have a reader, reads what readers sent,
    /// writes pending bytes; sleeps up to `timeout` waiting for any of that.
    fn pump(&mut self, timeout: Duration) -> Result<()> {
        let mut fds: Vec<libc::pollfd> = self
            .eps
            .iter()
            .map(|e| libc::pollfd {
                fd: e.pty.as_ref().map_or(-1, |p| p.master.as_raw_fd()),
                events: libc::POLLIN,
                revents: 0,
            })
            .collect();
        poll(&mut fds, Duration::ZERO)?;
        for (e, fd) in self.eps.iter_mut().zip(&fds) {
            e.attached = e.pty.is_some() && fd.revents & libc::POLLHUP == 0;
        }
        // Wait only on attached endpoints (a hung-up master is always "ready").
        let mut waiting: Vec<libc::pollfd> = Vec::new();
        let mut index = Vec::new();
        for (i, e) in self.eps.iter().enumerate() {
            if let (true, Some(p)) = (e.attached, &e.pty) {
                let mut events = libc::POLLIN;
                if !e.pending.is_empty() {
                    events |= libc::POLLOUT;
                }
                waiting.push(libc::pollfd {
                    fd: p.master.as_raw_fd(),
                    events,
                    revents: 0,
                });
                index.push(i);
            }
        }
        let any_detached = self.eps.iter().any(|e| !e.attached && e.pty.is_some());
        let timeout = if any_detached {
            timeout.min(TICK)
        } else {
            timeout
        };
        if waiting.is_empty() {
            if !timeout.is_zero() {
                std::thread::sleep(timeout);
            }
        } else {
            poll(&mut waiting, timeout)?;
        }
        for e in &mut self.eps {
            if e.attached {
                e.read_some();
            }
            // Unattached endpoints are written too: the kernel keeps the bytes for the
            // next reader, as documented.
            e.write_some();
        }
        Ok(())
    }

    fn send(&mut self, item: Item) -> Result<()> {
        self.last_t_ns = self.last_t_ns.max(item.t_ns);
        let written_ns = self.t0.elapsed().as_nanos() as u64;
        let max_mode = self.speed == Speed::Max;
        let ep = item.endpoint;
        if let Some(e) = item.error {
            let s = &mut self.eps[ep].stream;
            s.encode_errors += 1;
            s.first_encode_error.get_or_insert(e);
            return Ok(());
        }
        if self.eps[ep].pty.is_none() {
            self.eps[ep].stream.frames_unplugged += 1;
            return Ok(());
        }
        if max_mode {
            while self.eps[ep].pending.len() >= MAX_MODE_PENDING {
                if self.stopped() {
                    return Ok(());
                }
                self.pump(TICK)?;
            }
        } else if self.eps[ep].pending.len() + item.bytes.len() > PENDING_LIMIT {
            self.eps[ep].stream.frames_overflowed += 1;
            return Ok(());
        }
        let e = &mut self.eps[ep];
        e.pending.extend(&item.bytes);
        e.stream.frames += 1;
        e.stream.bytes += item.bytes.len() as u64;
        if self.record {
            let generation = e.generation;
            match (item.sent, &mut e.stream.sent) {
                (Some(SentFrame::Imu(record, sample)), Sent::Imu(v)) => v.push(SentImu {
                    t_ns: item.t_ns,
                    written_ns,
                    generation,
                    record,
                    sample,
                }),
                (Some(SentFrame::Gnss(record, fixes)), Sent::Gnss(v)) => v.push(SentGnss {
                    t_ns: item.t_ns,
                    written_ns,
                    generation,
                    record,
                    fixes,
                }),
                _ => {}
            }
        }
        e.write_some();
        Ok(())
    }

    /// Applies the faults due by scene time `t_ns`, and replugs endpoints whose down time
    /// is over.
    fn apply_faults(&mut self, t_ns: i64) -> Result<()> {
        for i in 0..self.eps.len() {
            if self.eps[i].down_until_ns.is_some_and(|until| until <= t_ns) {
                self.replug(i)?;
            }
        }
        while let Some(f) = self.faults.front() {
            if (f.at_s * 1e9).round() as i64 > t_ns {
                break;
            }
            let Some(fault) = self.faults.pop_front() else {
                break;
            };
            let Some(i) = self
                .eps
                .iter()
                .position(|e| e.stream.sensor == fault.sensor)
            else {
                continue;
            };
            let e = &mut self.eps[i];
            e.stream.faults.push(AppliedFault {
                fault: fault.clone(),
                after_frames: e.stream.frames,
            });
            match fault.kind {
                FaultKind::Garbage => {
                    let mut rng = Stream::new(
                        self.seed,
                        &format!("serve/garbage/{}/{}", fault.sensor, self.garbage_count),
                    );
                    self.garbage_count += 1;
                    let e = &mut self.eps[i];
                    e.pending
                        .extend((0..fault.bytes).map(|_| (rng.uniform() * 256.0) as u8));
                    e.stream.garbage_bytes += fault.bytes as u64;
                    e.write_some();
                }
                FaultKind::Reopen => {
                    let e = &mut self.eps[i];
                    e.write_some();
                    e.stream.bytes_discarded_at_close += e.pending.len() as u64;
                    e.pending.clear();
                    e.pty = None;
                    e.attached = false;
                    if let Some(link) = &e.link {
                        let _ = std::fs::remove_file(link);
                    }
                    let until = ((fault.at_s + fault.down_s) * 1e9).round() as i64;
                    e.down_until_ns = Some(until);
                    if until <= t_ns {
                        self.replug(i)?;
                    }
                }
            }
        }
        Ok(())
    }

    fn replug(&mut self, i: usize) -> Result<()> {
        let e = &mut self.eps[i];
        let pty =
            Pty::open().with_context(|| format!("cannot reopen a pty for {}", e.stream.sensor))?;
        if let Some(link) = &e.link {
            point_link(link, &pty.path)?;
        }
        if let Ok(mut paths) = self.shared.ptys.lock() {
            if let Some(p) = paths.get_mut(i) {
                *p = pty.path.clone();
            }
        }
        e.pty = Some(pty);
        e.generation += 1;
        e.down_until_ns = None;
        e.command.clear();
        Ok(())
    }

    /// Lets readers take the last pending bytes; returns what is left after
    /// [`DRAIN_TIMEOUT`] without progress.
    fn drain(&mut self) -> Result<u64> {
        let mut last_progress = Instant::now();
        let mut left: usize = self.eps.iter().map(|e| e.pending.len()).sum();
        while left > 0 && last_progress.elapsed() < DRAIN_TIMEOUT && !self.stopped() {
            self.pump(TICK)?;
            let now: usize = self.eps.iter().map(|e| e.pending.len()).sum();
            if now < left {
                last_progress = Instant::now();
            }
            left = now;
        }
        Ok(left as u64)
    }
}
