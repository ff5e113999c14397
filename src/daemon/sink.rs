//! Where the writer thread puts records: the [`RecordSink`] trait (the session writer of
//! `imulab::store` implements it through a thin adapter) and [`MemorySink`], an in-memory
//! sink for tests and dry runs.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use imulab_store::{EventRecord, GnssRecord, ImuRecord};

/// A session being written. Only the writer thread calls it, so it may block on disk I/O.
pub trait RecordSink: Send {
    fn append_imu(&mut self, device: &str, rows: &[ImuRecord]) -> anyhow::Result<()>;
    fn append_gnss(&mut self, device: &str, rows: &[GnssRecord]) -> anyhow::Result<()>;
    fn append_event(&mut self, event: &EventRecord) -> anyhow::Result<()>;
    fn append_raw(&mut self, device: &str, t_mono_ns: i64, bytes: &[u8]) -> anyhow::Result<()>;
    /// Called at every point of the hand-over grid ([`super::cadence`]) once the writer has
    /// written what the device tasks handed over there; `now_mono_ns` is that point
    /// (CLOCK_MONOTONIC). Afterwards, rows older than the store's flush interval at that time
    /// are durable (a sink that writes on chunk boundaries may keep younger rows buffered).
    fn flush(&mut self, now_mono_ns: i64) -> anyhow::Result<()>;
    /// Writes every row still buffered to disk now, however young: called once after the
    /// last batch, so the writer's last free-space check sees what the session takes before
    /// it closes.
    fn write_buffered(&mut self) -> anyhow::Result<()>;
    /// Closes the current chunk file and starts the next one, recording a `rotation` event.
    fn rotate(&mut self) -> anyhow::Result<()>;
    /// Flushes, closes and renames the last chunk file. Called once.
    fn close(&mut self) -> anyhow::Result<()>;
    /// The chunk file being written, for the status.
    fn current_file(&self) -> Option<PathBuf>;
}

/// Everything a [`MemorySink`] received.
#[derive(Debug, Default, Clone)]
pub struct MemoryStore {
    pub imu: BTreeMap<String, Vec<ImuRecord>>,
    pub gnss: BTreeMap<String, Vec<GnssRecord>>,
    pub events: Vec<EventRecord>,
    pub raw: BTreeMap<String, Vec<(i64, Vec<u8>)>>,
    /// Calls of `append_imu` and `append_gnss` (the writer makes one per batch and table).
    pub row_appends: u64,
    pub flushes: u64,
    pub rotations: u64,
    pub closed: bool,
}

/// An in-memory sink; clones share the same store, so a test keeps one to look inside.
#[derive(Debug, Clone, Default)]
pub struct MemorySink {
    store: Arc<Mutex<MemoryStore>>,
    /// Sleep this long in every append, to stand in for a slow disk.
    pub append_delay: Duration,
}

impl MemorySink {
    pub fn new() -> Self {
        Self::default()
    }

    /// A sink whose appends each take `delay` (a slow disk).
    pub fn slow(delay: Duration) -> Self {
        MemorySink {
            append_delay: delay,
            ..Self::default()
        }
    }

    /// A snapshot of what was received so far.
    pub fn snapshot(&self) -> MemoryStore {
        self.lock().clone()
    }

    fn lock(&self) -> MutexGuard<'_, MemoryStore> {
        // A panic while holding the lock cannot leave MemoryStore half-updated in a way that
        // matters for a test sink, so a poisoned lock is used as is.
        self.store
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
    }

    fn pause(&self) {
        if !self.append_delay.is_zero() {
            std::thread::sleep(self.append_delay);
        }
    }
}

impl RecordSink for MemorySink {
    fn append_imu(&mut self, device: &str, rows: &[ImuRecord]) -> anyhow::Result<()> {
        self.pause();
        let mut s = self.lock();
        s.row_appends += 1;
        s.imu
            .entry(device.to_string())
            .or_default()
            .extend_from_slice(rows);
        Ok(())
    }

    fn append_gnss(&mut self, device: &str, rows: &[GnssRecord]) -> anyhow::Result<()> {
        self.pause();
        let mut s = self.lock();
        s.row_appends += 1;
        s.gnss
            .entry(device.to_string())
            .or_default()
            .extend_from_slice(rows);
        Ok(())
    }

    fn append_event(&mut self, event: &EventRecord) -> anyhow::Result<()> {
        self.lock().events.push(event.clone());
        Ok(())
    }

    fn append_raw(&mut self, device: &str, t_mono_ns: i64, bytes: &[u8]) -> anyhow::Result<()> {
        self.lock()
            .raw
            .entry(device.to_string())
            .or_default()
            .push((t_mono_ns, bytes.to_vec()));
        Ok(())
    }

    fn flush(&mut self, _now_mono_ns: i64) -> anyhow::Result<()> {
        self.lock().flushes += 1;
        Ok(())
    }

    /// Holds nothing back: every append is already in the store.
    fn write_buffered(&mut self) -> anyhow::Result<()> {
        Ok(())
    }

    fn rotate(&mut self) -> anyhow::Result<()> {
        let mut s = self.lock();
        s.rotations += 1;
        let now = super::clock::now();
        let detail = format!("memory-{:05} started", s.rotations);
        s.events.push(EventRecord {
            t_mono_ns: now.mono_ns,
            t_wall_ns: now.wall_ns,
            device: String::new(),
            kind: imulab_store::EventKind::Rotation,
            detail,
        });
        Ok(())
    }

    fn close(&mut self) -> anyhow::Result<()> {
        let mut s = self.lock();
        if s.closed {
            anyhow::bail!("memory sink closed twice");
        }
        s.closed = true;
        Ok(())
    }

    fn current_file(&self) -> Option<PathBuf> {
        let rotations = self.lock().rotations;
        Some(PathBuf::from(format!("memory-{rotations:05}")))
    }
}
