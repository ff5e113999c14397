//! File replay: a raw byte capture (what a serial device sent, e.g. the daemon's raw
//! journal or a `cat /dev/ttyUSB0 > file`) fed back in chunks, either as fast as possible or
//! paced at a byte rate (the link's baud / 10); and a candump log replayed at its recorded
//! timing (scaled by a speed factor) or as fast as possible.

use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::io::AsyncReadExt;
use tokio::time::Instant;

use super::{ByteSource, TransportError};
use crate::codec::candump::{CandumpDecoder, CandumpRecord};
use crate::codec::Decoder;
use crate::types::DecoderStats;

/// How fast to replay.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReplaySpeed {
    /// No pacing.
    AsFastAsPossible,
    /// Recorded timing divided by `factor` (2.0 = twice as fast). For raw files, which
    /// have no timestamps, this is a byte rate instead: see [`RawReplay::open`].
    Recorded { factor: f64 },
}

impl ReplaySpeed {
    fn check(self) -> Result<Self, TransportError> {
        match self {
            ReplaySpeed::Recorded { factor } if !(factor.is_finite() && factor > 0.0) => Err(
                TransportError::Config(format!("replay speed factor {factor} must be positive")),
            ),
            s => Ok(s),
        }
    }
}

const CHUNK: usize = 4096;

/// Replays a raw byte file.
#[derive(Debug)]
pub struct RawReplay {
    file: tokio::fs::File,
    path: PathBuf,
    bytes_per_second: Option<f64>,
    start: Instant,
    sent: u64,
}

/// Opens a recorded log for replay; a failure names the file.
async fn open_log(path: &Path) -> Result<tokio::fs::File, TransportError> {
    tokio::fs::File::open(path)
        .await
        .map_err(|e| TransportError::Open {
            device: path.display().to_string(),
            source: e,
        })
}

impl RawReplay {
    /// Opens `path`. With `bytes_per_second` the bytes come no faster than that (a serial
    /// link at B baud, 8N1, carries B/10 bytes per second); `None` is as fast as possible.
    pub async fn open(path: &Path, bytes_per_second: Option<f64>) -> Result<Self, TransportError> {
        if let Some(r) = bytes_per_second {
            if !(r.is_finite() && r > 0.0) {
                return Err(TransportError::Config(format!(
                    "replay byte rate {r} must be positive"
                )));
            }
        }
        let file = open_log(path).await?;
        Ok(RawReplay {
            file,
            path: path.to_path_buf(),
            bytes_per_second,
            start: Instant::now(),
            sent: 0,
        })
    }
}

impl ByteSource for RawReplay {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, TransportError> {
        let limit = match self.bytes_per_second {
            // Chunks of ~10 ms worth of bytes keep the pacing smooth.
            Some(rate) => buf.len().min(((rate / 100.0) as usize).max(1)),
            None => buf.len(),
        };
        let n = self
            .file
            .read(&mut buf[..limit])
            .await
            .map_err(|e| TransportError::Io {
                device: self.path.display().to_string(),
                source: e,
            })?;
        if let Some(rate) = self.bytes_per_second {
            self.sent += n as u64;
            let due = self.start + Duration::from_secs_f64(self.sent as f64 / rate);
            tokio::time::sleep_until(due).await;
        }
        Ok(n)
    }
}

/// Replays a candump log, frame by frame.
#[derive(Debug)]
pub struct CandumpReplay {
    file: tokio::fs::File,
    path: PathBuf,
    decoder: CandumpDecoder,
    speed: ReplaySpeed,
    /// (first record's timestamp, wall-clock instant it was released).
    origin: Option<(u64, Instant)>,
    buf: Vec<u8>,
    eof: bool,
    flushed: bool,
}

impl CandumpReplay {
    pub async fn open(path: &Path, speed: ReplaySpeed) -> Result<Self, TransportError> {
        let speed = speed.check()?;
        let file = open_log(path).await?;
        Ok(CandumpReplay {
            file,
            path: path.to_path_buf(),
            decoder: CandumpDecoder::new(),
            speed,
            origin: None,
            buf: vec![0u8; CHUNK],
            eof: false,
            flushed: false,
        })
    }

    /// The next record, released at its recorded time (scaled); `None` at end of file.
    /// Timestamps going backwards are released at once.
    pub async fn next(&mut self) -> Result<Option<CandumpRecord>, TransportError> {
        let record = loop {
            if let Some(r) = self.decoder.poll() {
                break r;
            }
            if self.eof {
                // A last line without '\n' is completed once; after that the file is done.
                if self.flushed {
                    return Ok(None);
                }
                self.flushed = true;
                self.decoder.push(b"\n");
                continue;
            }
            let n = self
                .file
                .read(&mut self.buf)
                .await
                .map_err(|e| TransportError::Io {
                    device: self.path.display().to_string(),
                    source: e,
                })?;
            if n == 0 {
                self.eof = true;
            }
            self.decoder.push(&self.buf[..n]);
        };
        if let ReplaySpeed::Recorded { factor } = self.speed {
            let (t0, wall0) = *self
                .origin
                .get_or_insert((record.timestamp_us, Instant::now()));
            let offset_us = record.timestamp_us.saturating_sub(t0) as f64 / factor;
            tokio::time::sleep_until(wall0 + Duration::from_secs_f64(offset_us * 1e-6)).await;
        }
        Ok(Some(record))
    }

    /// The candump decoder's counters (malformed lines etc.).
    pub fn stats(&self) -> DecoderStats {
        self.decoder.stats()
    }
}
