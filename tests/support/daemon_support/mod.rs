//! Test helpers for the daemon tests: a tiny checksummed line protocol with its decoder
//! (for the pipeline tests that check the daemon's own logic: queueing, gaps, back-off,
//! losses; the real codecs are tested over ptys in `tests/daemon/serial.rs` and `end_to_end.rs`), and
//! connectors that hand out in-memory streams. [`daemon`] builds a daemon from a
//! configuration as `imulogd` does, [`pty`] stands in for serial devices.

pub mod daemon;
pub mod encode;
pub mod pty;

use std::collections::VecDeque;
use std::io;
use std::sync::{Arc, Mutex};

use imulab::daemon::source::{BoxFuture, Connector, Frame, FrameDecoder, Input, Link};
use imulab::store::{GnssRecord, ImuRecord, Session, TimeRange};
use imulab_drivers::transport::{StreamTransport, TransportError};
use imulab_drivers::types::{DecoderStats, GnssFix, ImuSample};

/// Encodes an IMU sample as `$I,seq,gx,gy,gz,ax,ay,az*CS\n` (CS = XOR of the body, hex).
pub fn encode_imu(seq: u64, gyro: [f64; 3], accel: [f64; 3]) -> Vec<u8> {
    let body = format!(
        "I,{seq},{},{},{},{},{},{}",
        gyro[0], gyro[1], gyro[2], accel[0], accel[1], accel[2]
    );
    frame(&body)
}

/// Encodes a GNSS epoch as `$G,week,tow,lat,lon*CS\n`.
pub fn encode_gnss(week: u16, tow_s: f64, lat: f64, lon: f64) -> Vec<u8> {
    frame(&format!("G,{week},{tow_s},{lat},{lon}"))
}

fn frame(body: &str) -> Vec<u8> {
    let cs = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{cs:02X}\n").into_bytes()
}

/// Decoder of the test line protocol; counts resyncs, skipped bytes and checksum errors
/// the way the real codecs do.
#[derive(Default)]
pub struct LineDecoder {
    buffer: Vec<u8>,
    stats: DecoderStats,
    in_sync: bool,
}

impl LineDecoder {
    fn parse(body: &str) -> Option<Frame> {
        let fields: Vec<&str> = body.split(',').collect();
        let num = |i: usize| fields.get(i).and_then(|s| s.parse::<f64>().ok());
        match *fields.first()? {
            "I" if fields.len() == 8 => Some(Frame::Imu(ImuSample {
                sensor_time: num(1),
                gyro: Some([num(2)?, num(3)?, num(4)?]),
                accel: Some([num(5)?, num(6)?, num(7)?]),
                temp_c: None,
                status: 0,
            })),
            "G" if fields.len() == 5 => Some(Frame::Gnss(GnssFix {
                week: fields[1].parse().ok(),
                tow_s: num(2),
                lat_deg: num(3),
                lon_deg: num(4),
                ..GnssFix::default()
            })),
            _ => None,
        }
    }
}

impl FrameDecoder for LineDecoder {
    fn push(&mut self, input: Input<'_>) {
        match input {
            Input::Bytes(bytes) => self.buffer.extend_from_slice(bytes),
            Input::Can(_) => self.stats.frames_malformed += 1,
        }
    }

    fn poll(&mut self) -> Option<Frame> {
        loop {
            // Find a frame start.
            let start = self.buffer.iter().position(|&b| b == b'$');
            match start {
                None => {
                    if !self.buffer.is_empty() {
                        self.lose_sync(self.buffer.len());
                        self.buffer.clear();
                    }
                    return None;
                }
                Some(s) if s > 0 => {
                    self.lose_sync(s);
                    self.buffer.drain(..s);
                }
                Some(_) => {}
            }
            let end = self.buffer.iter().position(|&b| b == b'\n')?;
            let line: Vec<u8> = self.buffer.drain(..=end).collect();
            if let Some(inner) = line[1..].iter().rposition(|&b| b == b'$') {
                // A frame start inside the line: the earlier frame was cut; keep the later one.
                self.stats.frames_malformed += 1;
                let mut again = line[inner + 1..].to_vec();
                again.extend_from_slice(&self.buffer);
                self.buffer = again;
                continue;
            }
            let text = String::from_utf8_lossy(&line[1..line.len() - 1]).into_owned();
            let Some((body, cs)) = text.rsplit_once('*') else {
                self.stats.frames_malformed += 1;
                continue;
            };
            let want = body.bytes().fold(0u8, |a, b| a ^ b);
            if u8::from_str_radix(cs, 16).ok() != Some(want) {
                self.stats.checksum_errors += 1;
                continue;
            }
            match Self::parse(body) {
                Some(frame) => {
                    self.stats.frames_ok += 1;
                    self.in_sync = true;
                    return Some(frame);
                }
                None => self.stats.frames_malformed += 1,
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        self.stats
    }
}

impl LineDecoder {
    fn lose_sync(&mut self, skipped: usize) {
        self.stats.bytes_skipped += skipped as u64;
        if self.in_sync {
            self.stats.resyncs += 1;
            self.in_sync = false;
        }
    }
}

/// A connector that hands out queued in-memory streams, and fails (as a vanished device
/// would) when none is queued.
#[derive(Clone, Default)]
pub struct QueueConnector {
    streams: Arc<Mutex<VecDeque<tokio::io::DuplexStream>>>,
    pub attempts: Arc<Mutex<Vec<std::time::Instant>>>,
}

impl QueueConnector {
    /// Queues a new stream and returns the test's (writing) end.
    pub fn plug(&self) -> tokio::io::DuplexStream {
        let (device_end, test_end) = tokio::io::duplex(1 << 20);
        self.streams.lock().unwrap().push_back(device_end);
        test_end
    }

    pub fn attempt_count(&self) -> usize {
        self.attempts.lock().unwrap().len()
    }
}

impl Connector for QueueConnector {
    fn connect(&self) -> BoxFuture<'_, Result<Box<dyn Link>, TransportError>> {
        Box::pin(async move {
            self.attempts
                .lock()
                .unwrap()
                .push(std::time::Instant::now());
            match self.streams.lock().unwrap().pop_front() {
                Some(s) => Ok(Box::new(StreamTransport::new(s, "memory", None)) as Box<dyn Link>),
                None => Err(TransportError::Open {
                    device: "memory".into(),
                    source: io::Error::new(io::ErrorKind::NotFound, "no such device"),
                }),
            }
        })
    }

    fn describe(&self) -> String {
        "memory".to_string()
    }
}

/// A minimal valid config text with the given device tables appended.
pub fn config_text(output_dir: &str, devices: &str) -> String {
    format!("[session]\noutput_dir = \"{output_dir}\"\nflush_interval_ms = 100\n\n{devices}")
}

/// Every IMU row of device `name` in `session`, in order.
pub fn imu_rows(session: &Session, name: &str) -> Vec<ImuRecord> {
    let mut rows = Vec::new();
    for block in session.imu_blocks(name, TimeRange::all(), 4096).unwrap() {
        let block = block.unwrap();
        rows.extend((0..block.len()).map(|i| block.record(i)));
    }
    rows
}

/// Every GNSS row of device `name` in `session`, in order.
pub fn gnss_rows(session: &Session, name: &str) -> Vec<GnssRecord> {
    let mut rows = Vec::new();
    for block in session.gnss_blocks(name, TimeRange::all(), 4096).unwrap() {
        let block = block.unwrap();
        rows.extend((0..block.len()).map(|i| block.record(i)));
    }
    rows
}
