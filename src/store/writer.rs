//! [`SessionWriter`]: appends rows to the current chunk file of a session, flushes on chunk
//! boundaries every flush interval of *data* time, rotates files by data time or size, and
//! finalises each file (flush, fsync, rename from `*.partial`, fsync the directory).
//!
//! Flushing and rotation happen inside the `append_*` calls, driven by the rows' `t_mono_ns`
//! (so a simulator writing 6 h of data in seconds rotates every 10 min of *data*). A live
//! writer whose devices go quiet should also call [`SessionWriter::maybe_flush_and_rotate`]
//! from a timer with the current monotonic time, so buffered rows still reach the disk and a
//! stalled device's incomplete chunk reaches the HDF5 file (appends write whole chunks only).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::chunkfile::{ChunkFile, Table};
use super::columns::{EventRow, RawIndexRow, FILL_T_MONO};
use super::layout;
use super::manifest::{try_writer_lock, DeviceKind, Manifest};
use super::records::{
    EventKind, EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord,
};
use super::StoreError;

/// How the writer chunks, compresses, flushes and rotates.
#[derive(Debug, Clone, PartialEq)]
pub struct WriterOptions {
    /// Start a new chunk file after this much data time (default 10 min).
    pub rotate_after: Duration,
    /// ... or once the current file reaches this many bytes (default 512 MiB).
    pub rotate_bytes: u64,
    /// Rows older than this (in data time) are always on disk: the most a crash can lose
    /// (default 1 s). Rows are appended to the write-ahead journal this often.
    pub flush_interval: Duration,
    /// Sets the HDF5 chunk size: rows per chunk = rate × this interval (default 10 s). When
    /// it is longer than `flush_interval`, rows wait in the journal until their chunk is
    /// complete, so a live `*.partial` file is up to this much behind (see `journal`). When
    /// it is not, the journal is off and every flush writes chunks of one flush interval
    /// (the layout before the journal; kept for comparison: docs/bench/store.md).
    pub chunk_interval: Duration,
    /// Deflate level 0..=9 (0 = no shuffle/deflate filters at all). Default 1: on IMU noise
    /// level 4 saves about 3.5 % of space for about 85 % more CPU (docs/bench/store.md).
    pub deflate_level: u8,
    /// Create `/raw/<device>` for every device so undecoded bytes can be kept (default off).
    pub raw_journal: bool,
    /// Override rows per HDF5 chunk for every device (default: rate_hz × chunk_interval).
    pub rows_per_chunk: Option<usize>,
    /// fsync the file after every periodic flush (protects against power loss, not only
    /// against a killed process). Default on. Finalised files are always fsynced.
    pub fsync_on_flush: bool,
}

impl Default for WriterOptions {
    fn default() -> Self {
        WriterOptions {
            rotate_after: Duration::from_secs(600),
            rotate_bytes: 512 << 20,
            flush_interval: Duration::from_secs(1),
            chunk_interval: Duration::from_secs(10),
            deflate_level: 1,
            raw_journal: false,
            rows_per_chunk: None,
            fsync_on_flush: true,
        }
    }
}

/// Writes a session: see the module documentation for when it flushes and rotates.
pub struct SessionWriter {
    dir: PathBuf,
    manifest: Manifest,
    opts: WriterOptions,
    current: Option<ChunkFile>,
    next_index: u32,
    /// Newest data time seen, ns.
    max_t: Option<i64>,
    /// Data time of the last check of the file size against `rotate_bytes`.
    last_size_check_t: Option<i64>,
    /// Last row time per stream (`imu/name`...), to refuse rows going back in time.
    last_t: HashMap<String, i64>,
    rotate_pending: bool,
    /// Events at or past the time the current file is due to rotate, while no data row has
    /// come for the next file yet: they go into the next file when it starts, or into the
    /// current one when the session closes first (see [`SessionWriter::append_event`]).
    held_events: Vec<EventRow>,
    /// The session's writer lock, held while this writer lives.
    lock: Option<nix::fcntl::Flock<std::fs::File>>,
}

impl SessionWriter {
    /// Creates the session directory `dir` (which must not exist or be empty), writes the
    /// manifest and opens chunk file 0.
    pub fn create(dir: &Path, manifest: Manifest, opts: WriterOptions) -> Result<Self, StoreError> {
        manifest.validate(&dir.join(super::manifest::MANIFEST_FILE))?;
        if opts.flush_interval.is_zero()
            || opts.rotate_after.is_zero()
            || opts.chunk_interval.is_zero()
        {
            return Err(StoreError::Invalid(
                "flush_interval, chunk_interval and rotate_after must be positive".into(),
            ));
        }
        std::fs::create_dir_all(dir).map_err(|e| StoreError::io(dir, e))?;
        let not_empty = std::fs::read_dir(dir)
            .map_err(|e| StoreError::io(dir, e))?
            .next()
            .is_some();
        if not_empty {
            return Err(StoreError::Invalid(format!(
                "{} is not empty; a new session needs a new directory",
                dir.display()
            )));
        }
        manifest.save(dir)?;
        keep_freed_heap();
        let lock = try_writer_lock(dir)?.ok_or_else(|| {
            StoreError::Invalid(format!(
                "{}: another writer holds the session lock",
                dir.display()
            ))
        })?;
        let first = ChunkFile::create(dir, 0, &manifest, &opts)?;
        Ok(SessionWriter {
            dir: dir.to_path_buf(),
            manifest,
            opts,
            current: Some(first),
            next_index: 1,
            max_t: None,
            last_size_check_t: None,
            last_t: HashMap::new(),
            rotate_pending: false,
            held_events: Vec::new(),
            lock: Some(lock),
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// Path of the chunk file being written.
    pub fn current_file(&self) -> Option<&Path> {
        self.current.as_ref().map(|c| c.partial_path.as_path())
    }

    fn flush_ns(&self) -> i64 {
        i64::try_from(self.opts.flush_interval.as_nanos()).unwrap_or(i64::MAX)
    }

    /// Checks that `times` are usable and do not go back in time for `stream`.
    fn check_times(
        &mut self,
        stream: &str,
        times: impl Iterator<Item = i64>,
    ) -> Result<(), StoreError> {
        let mut last = self.last_t.get(stream).copied();
        for (i, t) in times.enumerate() {
            if t == FILL_T_MONO {
                return Err(StoreError::Invalid(format!(
                    "{stream}: row {i}: t_mono_ns = i64::MIN is reserved"
                )));
            }
            if let Some(l) = last {
                if t < l {
                    return Err(StoreError::Invalid(format!(
                        "{stream}: row {i}: t_mono_ns {t} goes back in time (previous {l})"
                    )));
                }
            }
            last = Some(t);
        }
        if let Some(l) = last {
            self.last_t.insert(stream.to_string(), l);
        }
        Ok(())
    }

    /// Makes sure a file is open for rows starting at data time `t`, rotating first if the
    /// current file is due (by data time or size).
    fn file_for(&mut self, t: i64) -> Result<&mut ChunkFile, StoreError> {
        let span_start = self.next_span_start(t);
        if self.current.is_none() || span_start.is_some() || self.rotate_pending {
            self.rotate_at(Some(t))?;
        }
        let chunk = self
            .current
            .as_mut()
            .ok_or_else(|| StoreError::Invalid("writer has no open chunk file".into()))?;
        match span_start {
            Some(start) => chunk.first_t = Some(start),
            None => {
                chunk.first_t.get_or_insert(t);
            }
        }
        Ok(chunk)
    }

    /// Whether a row at data time `t` is past the current file's time span (`rotate_after`
    /// from its start).
    fn due_by_time(&self, t: i64) -> bool {
        self.next_span_start(t).is_some()
    }

    /// When data time `t` is past the current file's span: the start of the span that holds
    /// `t` on the grid the first file started (its start + k × `rotate_after`). Rotations by
    /// data time keep to that grid, so the spans follow each other whatever the times of the
    /// rows that happen to start the files (arrival jitter, latency) and the sizes of the
    /// appends; a writer that hands rows over in pieces ending at those times (the
    /// simulator: [`SessionWriter::rotate_after`]) gets files of exactly `rotate_after`.
    fn next_span_start(&self, t: i64) -> Option<i64> {
        let rotate_ns = i64::try_from(self.opts.rotate_after.as_nanos())
            .unwrap_or(i64::MAX)
            .max(1);
        let first = self.current.as_ref()?.first_t?;
        let since = t.saturating_sub(first);
        (since >= rotate_ns).then(|| first.saturating_add(since / rotate_ns * rotate_ns))
    }

    /// The data time after which a new chunk file starts (see [`WriterOptions::rotate_after`]).
    pub fn rotate_after(&self) -> Duration {
        self.opts.rotate_after
    }

    fn note_time(&mut self, t: i64) {
        self.max_t = Some(self.max_t.map_or(t, |m| m.max(t)));
    }

    /// Appends IMU rows for `device` (rows must be in time order).
    pub fn append_imu(&mut self, device: &str, rows: &[ImuRecord]) -> Result<(), StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Imu))?;
        self.check_times(&layout::imu_path(device), rows.iter().map(|r| r.t_mono_ns))?;
        let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
            return Ok(());
        };
        let chunk = self.file_for(first.t_mono_ns)?;
        table_of(&mut chunk.imu, device)?
            .buf
            .extend_from_slice(rows);
        self.note_time(last.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends GNSS rows for `device` (rows must be in time order).
    pub fn append_gnss(&mut self, device: &str, rows: &[GnssRecord]) -> Result<(), StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Gnss))?;
        self.check_times(&layout::gnss_path(device), rows.iter().map(|r| r.t_mono_ns))?;
        let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
            return Ok(());
        };
        let chunk = self.file_for(first.t_mono_ns)?;
        table_of(&mut chunk.gnss, device)?
            .buf
            .extend_from_slice(rows);
        self.note_time(last.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends one event to `/events` (written at the next flush).
    ///
    /// An event never starts a file by itself: one timed at or past the current file's
    /// rotation time is held until a data row starts the next file (or a live writer's
    /// timer does), and goes into the current file if the session closes first. So a run
    /// that ends exactly on a rotation time (a simulation of 20 min with 10 min files, whose
    /// `session_stop` is timed at its end) has no last file holding only that event.
    pub fn append_event(&mut self, ev: &EventRecord) -> Result<(), StoreError> {
        let row = EventRow::from_record(ev).map_err(StoreError::Invalid)?;
        if self.due_by_time(ev.t_mono_ns) && !self.rotate_pending {
            self.held_events.push(row);
            self.note_time(ev.t_mono_ns);
            return Ok(());
        }
        let chunk = self.file_for(ev.t_mono_ns)?;
        chunk.events.buf.push(row);
        self.note_time(ev.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends one read of undecoded bytes to `/raw/<device>` (needs `raw_journal`).
    pub fn append_raw(
        &mut self,
        device: &str,
        t_mono_ns: i64,
        bytes: &[u8],
    ) -> Result<(), StoreError> {
        self.manifest.device_of_kind(device, None)?;
        if !self.opts.raw_journal {
            return Err(StoreError::Invalid(format!(
                "raw bytes for {device:?} but the writer was created without raw_journal"
            )));
        }
        let len = u32::try_from(bytes.len()).map_err(|_| {
            StoreError::Invalid(format!("raw read of {} bytes is too long", bytes.len()))
        })?;
        self.check_times(&layout::raw_path(device), std::iter::once(t_mono_ns))?;
        let chunk = self.file_for(t_mono_ns)?;
        let raw = chunk
            .raw
            .get_mut(device)
            .ok_or_else(|| StoreError::UnknownDevice {
                device: device.into(),
                msg: "no raw journal group".into(),
            })?;
        let offset = (raw.bytes_written + raw.bytes_buf.len()) as u64;
        raw.index.buf.push(RawIndexRow {
            t_mono_ns,
            offset,
            len,
        });
        raw.bytes_buf.extend_from_slice(bytes);
        self.note_time(t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends true trajectory epochs (simulated sessions: manifest `truth_nav_rate_hz`).
    pub fn append_truth_nav(&mut self, rows: &[TruthNavRecord]) -> Result<(), StoreError> {
        if self.manifest.truth_nav_rate_hz.is_none() {
            return Err(StoreError::Invalid(
                "truth rows for a session whose manifest has no truth_nav_rate_hz".into(),
            ));
        }
        self.check_times(layout::TRUTH_NAV_GROUP, rows.iter().map(|r| r.t_mono_ns))?;
        let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
            return Ok(());
        };
        let chunk = self.file_for(first.t_mono_ns)?;
        chunk
            .truth_nav
            .as_mut()
            .ok_or_else(|| StoreError::Invalid("no /truth/nav in this file".into()))?
            .buf
            .extend_from_slice(rows);
        self.note_time(last.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends true IMU error states for IMU `device` (simulated sessions).
    pub fn append_truth_imu(
        &mut self,
        device: &str,
        rows: &[TruthImuRecord],
    ) -> Result<(), StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Imu))?;
        if self.manifest.truth_nav_rate_hz.is_none() {
            return Err(StoreError::Invalid(
                "truth rows for a session whose manifest has no truth_nav_rate_hz".into(),
            ));
        }
        self.check_times(
            &layout::truth_imu_path(device),
            rows.iter().map(|r| r.t_mono_ns),
        )?;
        let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
            return Ok(());
        };
        let chunk = self.file_for(first.t_mono_ns)?;
        table_of(&mut chunk.truth_imu, device)?
            .buf
            .extend_from_slice(rows);
        self.note_time(last.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Writes what is due after every append (and, with `timer`, from the idle timer):
    /// completed chunks at once, and any table's rows once the oldest has waited a flush
    /// interval (so at most one interval of data is ever only in memory; see
    /// [`ChunkFile::tick`]). Checks the file size for rotation once per flush interval.
    fn maybe_flush(&mut self, timer: bool) -> Result<(), StoreError> {
        let Some(now) = self.max_t else { return Ok(()) };
        let (flush_ns, fsync) = (self.flush_ns(), self.opts.fsync_on_flush);
        let chunk_ns = i64::try_from(self.opts.chunk_interval.as_nanos()).unwrap_or(i64::MAX);
        let Some(chunk) = self.current.as_mut() else {
            return Ok(());
        };
        chunk.tick(now, flush_ns, chunk_ns, fsync, timer)?;
        let size_check_due = self
            .last_size_check_t
            .is_none_or(|last| now.saturating_sub(last) >= flush_ns);
        if size_check_due {
            self.last_size_check_t = Some(now);
            let size = std::fs::metadata(&chunk.partial_path)
                .map_err(|e| StoreError::io(&chunk.partial_path, e))?
                .len();
            if size >= self.opts.rotate_bytes {
                self.rotate_pending = true;
            }
        }
        Ok(())
    }

    /// For a live writer's idle timer: treats `now_mono_ns` as the current data time, so
    /// rows of a device that went quiet still reach the disk within a flush interval, and a
    /// file due for rotation by time is finalised even when no new rows arrive. The caller
    /// says that every device's rows are in up to `now_mono_ns`: only here is a stalled or
    /// slow device's incomplete chunk written to the HDF5 file early (see `Early`; appends
    /// alone write whole chunks).
    pub fn maybe_flush_and_rotate(&mut self, now_mono_ns: i64) -> Result<(), StoreError> {
        self.note_time(now_mono_ns);
        self.maybe_flush(true)?;
        let span_start = self.next_span_start(now_mono_ns);
        if span_start.is_some() || self.rotate_pending {
            self.rotate_at(None)?;
        }
        if let (Some(start), Some(c)) = (span_start, self.current.as_mut()) {
            c.first_t = Some(start);
        }
        Ok(())
    }

    /// Writes every buffered row to the current HDF5 file and flushes (and fsyncs) it now,
    /// so it is readable there (not only in the journal).
    pub fn flush(&mut self) -> Result<(), StoreError> {
        let fsync = self.opts.fsync_on_flush;
        if let Some(chunk) = self.current.as_mut() {
            chunk.write_all(fsync, true)?;
        }
        self.last_size_check_t = self.max_t;
        Ok(())
    }

    /// Finalises the current chunk file and starts the next one now.
    pub fn rotate(&mut self) -> Result<(), StoreError> {
        self.rotate_at(None)
    }

    fn rotate_at(&mut self, t: Option<i64>) -> Result<(), StoreError> {
        let previous = match self.current.take() {
            Some(c) => {
                let idx = c.index;
                c.finish(&self.dir)?;
                release_freed_memory();
                Some(idx)
            }
            None => None,
        };
        self.rotate_pending = false;
        let index = self.next_index;
        let chunk = ChunkFile::create(&self.dir, index, &self.manifest, &self.opts)?;
        self.next_index += 1;
        self.current = Some(chunk);
        // Held events (see `append_event`) are the first rows of the new file.
        let t = t
            .or(self.max_t)
            .map(|t| self.held_events.first().map_or(t, |h| h.t_mono_ns.min(t)));
        if let (Some(prev), Some(t)) = (previous, t) {
            let detail = format!(
                "{} finished; {} started",
                layout::chunk_file_name(prev),
                layout::chunk_file_name(index)
            );
            let ev = EventRecord {
                t_mono_ns: t,
                t_wall_ns: wall_clock_ns(),
                device: String::new(),
                kind: EventKind::Rotation,
                detail,
            };
            let row = EventRow::from_record(&ev).map_err(StoreError::Invalid)?;
            if let Some(c) = self.current.as_mut() {
                c.events.buf.push(row);
            }
        }
        if let Some(c) = self.current.as_mut() {
            if let Some(first) = self.held_events.first() {
                c.first_t.get_or_insert(first.t_mono_ns);
            }
            c.events.buf.append(&mut self.held_events);
        }
        Ok(())
    }

    /// Writes everything, finalises the current chunk file and returns the session directory.
    pub fn close(mut self) -> Result<PathBuf, StoreError> {
        self.finish_current()?;
        self.release_lock();
        Ok(std::mem::take(&mut self.dir))
    }

    /// Finalises the current chunk file, with the events held for a next file that never
    /// came (see [`SessionWriter::append_event`]).
    fn finish_current(&mut self) -> Result<(), StoreError> {
        match self.current.take() {
            Some(mut c) => {
                c.events.buf.append(&mut self.held_events);
                c.finish(&self.dir).map(|_| ())
            }
            None => Ok(()),
        }
    }

    fn release_lock(&mut self) {
        if self.lock.take().is_some() {
            let _ = std::fs::remove_file(self.dir.join(layout::WRITER_LOCK_FILE));
        }
    }
}

fn table_of<'a, R>(
    map: &'a mut HashMap<String, Table<R>>,
    device: &str,
) -> Result<&'a mut Table<R>, StoreError> {
    map.get_mut(device)
        .ok_or_else(|| StoreError::UnknownDevice {
            device: device.into(),
            msg: "no group for it in the current chunk file".into(),
        })
}

/// HDF5's deflate filter sets up a fresh zlib stream (about 256 KiB, partly zeroed) for
/// every chunk it compresses (now only partial chunks; whole ones go through `chunkio`).
/// With glibc's default trim threshold each free shrinks the heap and the next chunk faults
/// the pages back in: measured in the first pass, that churn cost 15 % of the writer's CPU
/// on 30 min of data. Keeping up to 64 MiB of freed heap stops it. Process-wide and
/// harmless for other code; done once.
fn keep_freed_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        static ONCE: std::sync::Once = std::sync::Once::new();
        ONCE.call_once(|| {
            // SAFETY: mallopt only changes allocator tuning parameters; any value is valid.
            unsafe {
                libc::mallopt(libc::M_TRIM_THRESHOLD, 64 << 20);
                libc::mallopt(libc::M_TOP_PAD, 16 << 20);
            }
        });
    }
}

/// Called after each rotation, when the finished file's HDF5 state (metadata cache, chunk
/// index, B-tree nodes) has just been freed: gives freed memory back to the system so a
/// daemon's RSS stays flat over days. Measured (docs/bench/daemon.md, soak): the heap in use
/// was flat across rotations, but RSS crept up because nothing freed was ever returned:
/// HDF5 keeps every block it frees on its own free lists (no limit by default; ~1.4 MiB
/// here) and glibc keeps up to 64 MiB of freed heap (see [`keep_freed_heap`]), whose
/// resident pages wander up with fragmentation. `H5garbage_collect` hands HDF5's free
/// lists to malloc, `malloc_trim` unmaps every whole free page. Once per rotation (10 min by
/// default) the cost is a walk over the free lists and some page faults later.
fn release_freed_memory() {
    // SAFETY: H5garbage_collect takes no arguments and only frees blocks on HDF5's own free
    // lists (no live object uses them); the global HDF5 lock is held.
    let rc = hdf5::sync::sync(|| unsafe { hdf5_sys::h5::H5garbage_collect() });
    if rc < 0 {
        tracing::warn!("H5garbage_collect failed after rotation; memory kept, data unaffected");
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free memory of the allocator; any pad is valid.
    unsafe {
        libc::malloc_trim(0);
    }
}

fn wall_clock_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
        .unwrap_or(0)
}

impl Drop for SessionWriter {
    /// A writer dropped without `close` (e.g. on an error path) still finalises its file.
    fn drop(&mut self) {
        if let Err(e) = self.finish_current() {
            tracing::error!("closing session {}: {e}", self.dir.display());
        }
        self.release_lock();
    }
}
