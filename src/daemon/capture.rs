//! Captures played back as a device (`[device.file]`): a raw byte capture, a candump log, or
//! a session's raw record (`/raw/<device>`, written with `raw_journal`), delivered through
//! the same [`Link`] as a live device, so their bytes go through the same decode, stamp and
//! store path.
//!
//! A reader thread reads the file (blocking file and HDF5 reads stay off the device
//! thread) and hands pieces, each with its recorded time, through a small bounded channel;
//! the link releases each piece at its recorded time divided by the pace factor, or at once
//! with `pace = "fast"`. What the recorded time of a piece is:
//!
//! - a session's raw record: the arrival time of each read (`t_mono_ns`), one piece per read,
//!   so the decoder sees the same reads as the live daemon did;
//! - a candump log: each line's time stamp, one piece per frame;
//! - a raw byte capture: no time stamps, so the time the bytes take on a serial line at
//!   `baud` (8N1, baud / 10 bytes per second), in pieces of about 10 ms of bytes.
//!
//! At the end of the file the link reports [`Received::End`]: the device ends (it is not
//! reopened, which would play the file again).

use std::future::Future;
use std::io::{BufRead, Read};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use imulab_drivers::codec::can::CanFrame;
use imulab_drivers::codec::candump::parse_line;
use imulab_drivers::transport::TransportError;
use imulab_drivers::types::DecoderStats;
use tokio::sync::mpsc;
use tokio::time::{Instant, Sleep};

use super::config::{FileSource, Pace};
use super::source::{BoxFuture, Connector, Link, Received};
use imulab_store::{Session, TimeRange};

/// Pieces waiting between the reader thread and the link.
const CHANNEL_PIECES: usize = 64;
/// Largest piece of a raw capture played fast (one read of the daemon's buffer).
const FAST_PIECE_BYTES: usize = 16 * 1024;
/// Raw reads per block read from a session's raw record.
const SESSION_BLOCK_READS: usize = 4096;

/// What a file source holds, found from the file system and the protocol.
#[derive(Debug, Clone, PartialEq)]
pub enum CaptureKind {
    /// A session directory: the raw record of this device.
    Session { device: String },
    /// A candump log (`(time) interface id#data` lines).
    Candump,
    /// Undecoded bytes, paced at `baud` / 10 bytes per second when given.
    Raw { baud: Option<u32> },
}

/// Decides what `source` is and checks that it can be played: the file exists, a session
/// has a raw record of the device, a raw capture played at a recorded pace has a baud.
/// `device_name` is the configured device's own name (the default session device), `can`
/// whether its protocol takes CAN frames.
pub fn capture_kind(
    source: &FileSource,
    device_name: &str,
    can: bool,
) -> Result<CaptureKind, String> {
    let path = &source.path;
    let meta = std::fs::metadata(path)
        .map_err(|e| format!("cannot read the capture {}: {e}", path.display()))?;
    if meta.is_dir() {
        let device = source
            .device
            .clone()
            .unwrap_or_else(|| device_name.to_string());
        let session = Session::open(path).map_err(|e| e.to_string())?;
        if !session.devices().iter().any(|d| d.name == device) {
            let names: Vec<&str> = session.devices().iter().map(|d| d.name.as_str()).collect();
            return Err(format!(
                "session {} has no device `{device}` (it has: {}); set file.device",
                path.display(),
                names.join(", ")
            ));
        }
        let has_raw = session
            .raw_blocks(&device, TimeRange::all(), 1)
            .map_err(|e| e.to_string())?
            .any(|b| b.is_ok_and(|b| !b.t_mono_ns.is_empty()));
        if !has_raw {
            return Err(format!(
                "session {} holds no raw bytes of `{device}`: it was recorded without raw_journal, so it cannot be replayed",
                path.display()
            ));
        }
        return Ok(CaptureKind::Session { device });
    }
    if source.device.is_some() {
        return Err(format!(
            "file.device names a session device, but {} is a file, not a session directory",
            path.display()
        ));
    }
    if can {
        return Ok(CaptureKind::Candump);
    }
    if source.baud.is_none() && source.pace != Pace::Fast {
        return Err(format!(
            "{} is a raw byte capture, which has no time stamps: give file.baud (played at baud / 10 bytes per second) or pace = \"fast\"",
            path.display()
        ));
    }
    Ok(CaptureKind::Raw { baud: source.baud })
}

/// One piece of a capture with its recorded time (ns on the capture's own clock).
enum Piece {
    Bytes { at_ns: Option<i64>, bytes: Vec<u8> },
    Can { at_ns: i64, frame: CanFrame },
}

impl Piece {
    fn at_ns(&self) -> Option<i64> {
        match self {
            Piece::Bytes { at_ns, .. } => *at_ns,
            Piece::Can { at_ns, .. } => Some(*at_ns),
        }
    }
}

/// Opens a capture for each connection (there is one: the device ends at its end).
pub struct CaptureConnector {
    pub source: FileSource,
    pub kind: CaptureKind,
}

impl Connector for CaptureConnector {
    fn connect(&self) -> BoxFuture<'_, Result<Box<dyn Link>, TransportError>> {
        Box::pin(async move {
            let (tx, rx) = mpsc::channel(CHANNEL_PIECES);
            let stats = Arc::new(Mutex::new(DecoderStats::default()));
            let path = self.source.path.clone();
            let kind = self.kind.clone();
            let pace = self.source.pace;
            let thread_stats = stats.clone();
            std::thread::Builder::new()
                .name("imulogd-capture".into())
                .spawn(move || read_capture(&path, &kind, pace, &tx, &thread_stats))
                .map_err(|e| TransportError::Open {
                    device: self.source.path.display().to_string(),
                    source: e,
                })?;
            Ok(Box::new(CaptureLink {
                rx,
                pace: self.source.pace,
                origin: None,
                sleep: None,
                pending: None,
                offset: 0,
                stats,
                path: self.source.path.clone(),
            }) as Box<dyn Link>)
        })
    }

    fn describe(&self) -> String {
        super::config::Transport::File(self.source.clone()).describe()
    }
}

type Sender = mpsc::Sender<Result<Piece, String>>;

/// The reader thread: reads the capture into pieces until its end, an error (sent on), or
/// the link is gone.
fn read_capture(
    path: &Path,
    kind: &CaptureKind,
    pace: Pace,
    tx: &Sender,
    stats: &Mutex<DecoderStats>,
) {
    let result = match kind {
        CaptureKind::Session { device } => read_session(path, device, tx),
        CaptureKind::Candump => read_candump(path, tx, stats),
        CaptureKind::Raw { baud } => read_raw(path, *baud, pace, tx),
    };
    if let Err(e) = result {
        let _ = tx.blocking_send(Err(e));
    }
}

/// False once the link is gone (the daemon stopped): the thread ends.
fn send(tx: &Sender, piece: Piece) -> bool {
    tx.blocking_send(Ok(piece)).is_ok()
}

fn read_session(path: &Path, device: &str, tx: &Sender) -> Result<(), String> {
    let session = Session::open(path).map_err(|e| e.to_string())?;
    let blocks = session
        .raw_blocks(device, TimeRange::all(), SESSION_BLOCK_READS)
        .map_err(|e| e.to_string())?;
    for block in blocks {
        // A damaged chunk file is skipped (and said); the others still play.
        let block = match block {
            Ok(b) => b,
            Err(e) => {
                tracing::warn!("replaying {}: skipped: {e}", path.display());
                continue;
            }
        };
        let mut start = 0usize;
        for (&t, &len) in block.t_mono_ns.iter().zip(&block.len) {
            let end = start + len as usize;
            let Some(bytes) = block.bytes.get(start..end) else {
                return Err(format!(
                    "{}: the raw index of `{device}` points past its bytes",
                    path.display()
                ));
            };
            start = end;
            let piece = Piece::Bytes {
                at_ns: Some(t),
                bytes: bytes.to_vec(),
            };
            if !send(tx, piece) {
                return Ok(());
            }
        }
    }
    Ok(())
}

fn open(path: &Path) -> Result<std::fs::File, String> {
    std::fs::File::open(path).map_err(|e| format!("cannot open {}: {e}", path.display()))
}

fn read_candump(path: &Path, tx: &Sender, stats: &Mutex<DecoderStats>) -> Result<(), String> {
    let mut reader = std::io::BufReader::new(open(path)?);
    let mut line = Vec::new();
    loop {
        line.clear();
        let n = reader
            .read_until(b'\n', &mut line)
            .map_err(|e| format!("reading {}: {e}", path.display()))?;
        if n == 0 {
            return Ok(());
        }
        let text = line.trim_ascii();
        if text.is_empty() {
            continue;
        }
        let Some(record) = parse_line(text) else {
            // Counted as the decoder would: the daemon turns it into a resync event.
            let mut s = stats.lock().unwrap_or_else(|p| p.into_inner());
            s.frames_malformed += 1;
            s.bytes_skipped += n as u64;
            continue;
        };
        let at_ns = i64::try_from(record.timestamp_us)
            .unwrap_or(i64::MAX / 1000)
            .saturating_mul(1000);
        if !send(
            tx,
            Piece::Can {
                at_ns,
                frame: record.frame,
            },
        ) {
            return Ok(());
        }
    }
}

fn read_raw(path: &Path, baud: Option<u32>, pace: Pace, tx: &Sender) -> Result<(), String> {
    let mut file = open(path)?;
    let bytes_per_s = baud.map(|b| f64::from(b) / 10.0);
    // About 10 ms of line time per piece when paced.
    let piece = match (pace, bytes_per_s) {
        (Pace::Factor(_), Some(rate)) => ((rate / 100.0) as usize).clamp(1, FAST_PIECE_BYTES),
        _ => FAST_PIECE_BYTES,
    };
    let mut sent = 0u64;
    loop {
        let mut buf = vec![0u8; piece];
        let n = file
            .read(&mut buf)
            .map_err(|e| format!("reading {}: {e}", path.display()))?;
        if n == 0 {
            return Ok(());
        }
        buf.truncate(n);
        sent += n as u64;
        // The time the last byte of the piece has arrived on the line.
        let at_ns = bytes_per_s.map(|rate| (sent as f64 / rate * 1e9) as i64);
        if !send(tx, Piece::Bytes { at_ns, bytes: buf }) {
            return Ok(());
        }
    }
}

/// The device end of a capture: releases the reader thread's pieces at their paced times.
struct CaptureLink {
    rx: mpsc::Receiver<Result<Piece, String>>,
    pace: Pace,
    /// (first recorded time, the instant it was released).
    origin: Option<(i64, Instant)>,
    /// Waiting for the pending piece's time.
    sleep: Option<std::pin::Pin<Box<Sleep>>>,
    pending: Option<Piece>,
    /// Bytes of the pending piece already delivered (a piece larger than the read buffer).
    offset: usize,
    stats: Arc<Mutex<DecoderStats>>,
    path: PathBuf,
}

impl CaptureLink {
    /// When `at_ns` is due: the origin plus the recorded time since the first piece divided
    /// by the pace factor; `None` for at once (fast, no time, or time going backwards).
    fn due(&mut self, at_ns: Option<i64>) -> Option<Instant> {
        let Pace::Factor(factor) = self.pace else {
            return None;
        };
        let at = at_ns?;
        let (t0, start) = *self.origin.get_or_insert((at, Instant::now()));
        let since_ns = at.checked_sub(t0).filter(|d| *d > 0)?;
        Some(start + Duration::from_secs_f64(since_ns as f64 * 1e-9 / factor))
    }
}

impl Link for CaptureLink {
    fn poll_receive(
        &mut self,
        cx: &mut Context<'_>,
        buffer: &mut [u8],
    ) -> Poll<Result<Received, TransportError>> {
        if self.pending.is_none() {
            let piece = match self.rx.poll_recv(cx) {
                Poll::Pending => return Poll::Pending,
                Poll::Ready(None) => return Poll::Ready(Ok(Received::End)),
                Poll::Ready(Some(Err(reason))) => {
                    return Poll::Ready(Err(TransportError::Protocol {
                        device: self.path.display().to_string(),
                        reason,
                    }))
                }
                Poll::Ready(Some(Ok(piece))) => piece,
            };
            if let Some(due) = self.due(piece.at_ns()) {
                if due > Instant::now() {
                    self.sleep = Some(Box::pin(tokio::time::sleep_until(due)));
                }
            }
            self.pending = Some(piece);
            self.offset = 0;
        }
        if let Some(sleep) = &mut self.sleep {
            if sleep.as_mut().poll(cx).is_pending() {
                return Poll::Pending;
            }
            self.sleep = None;
        }
        match self.pending.take() {
            Some(Piece::Can { frame, .. }) => Poll::Ready(Ok(Received::Can(frame))),
            Some(Piece::Bytes { at_ns, bytes }) => {
                let rest = bytes.get(self.offset..).unwrap_or_default();
                let n = rest.len().min(buffer.len());
                buffer[..n].copy_from_slice(&rest[..n]);
                self.offset += n;
                if self.offset < bytes.len() {
                    self.pending = Some(Piece::Bytes { at_ns, bytes });
                }
                Poll::Ready(Ok(Received::Bytes(n)))
            }
            None => Poll::Ready(Ok(Received::End)),
        }
    }

    fn stats(&self) -> DecoderStats {
        *self.stats.lock().unwrap_or_else(|p| p.into_inner())
    }
}
