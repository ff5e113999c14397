//! [`Session`]: reads a session directory as one continuous, time-ordered stream per device,
//! across all chunk files, in blocks of bounded size with time-range selection. This is the
//! only way the analyses read data.
//!
//! A bad chunk file (truncated, corrupt, unknown schema version) does not stop the rest: it
//! is listed by [`Session::files`] with its problem, and a block iterator yields one `Err`
//! naming that file at its place in the stream, then carries on with the next file.

use std::marker::PhantomData;
use std::ops::Range;
use std::path::{Path, PathBuf};

use hdf5::Dataset;

use super::chunkio::ColumnReader;
pub use super::columns::{fix_type_from_code, GnssBlock, ImuBlock, TruthImuBlock, TruthNavBlock};
use super::columns::{
    read_bytes, Block, EventBlock, RawIndexBlock, TimeBlock, FILL_T_MONO, IMU_COLUMNS, RAW_BYTES,
};
use super::layout::{self, ATTR_SCHEMA_VERSION};
use super::manifest::{DeviceInfo, DeviceKind, Manifest};
use super::records::EventRecord;
use super::{StoreError, SCHEMA_VERSION};

/// A half-open range of host monotonic time `[start_ns, end_ns)`; `None` is unbounded.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TimeRange {
    pub start_ns: Option<i64>,
    pub end_ns: Option<i64>,
}

impl TimeRange {
    pub fn all() -> Self {
        TimeRange::default()
    }
    pub fn new(start_ns: Option<i64>, end_ns: Option<i64>) -> Self {
        TimeRange { start_ns, end_ns }
    }

    /// The rows of a table of `len` rows whose times (`t`, non-decreasing) fall in the range.
    fn rows(&self, t: &Dataset, len: usize) -> hdf5::Result<Range<usize>> {
        let start = match self.start_ns {
            Some(s) => lower_bound(t, len, s)?,
            None => 0,
        };
        let end = match self.end_ns {
            Some(e) => lower_bound(t, len, e)?,
            None => len,
        };
        Ok(start..end.max(start))
    }
}

/// One chunk file of a session and whether it can be read.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkFileInfo {
    pub path: PathBuf,
    pub index: u32,
    /// Still named `*.partial`: being written, or left by a writer that was killed.
    pub partial: bool,
    pub size_bytes: u64,
    /// Why the file cannot be read (one line naming the file), or `None` when it is fine.
    pub problem: Option<String>,
}

/// A chunk file of the session. It is opened when a reader reaches it and closed when the
/// reader moves on: HDF5 holds about half a MiB per open file, so a multi-day session kept
/// open whole would cost hundreds of MiB beside the data read.
#[derive(Clone)]
struct ChunkEntry {
    info: ChunkFileInfo,
    /// The hint for a partial file's open error (live writer or not), `None` for a final file.
    partial_hint: Option<String>,
}

/// A chunk file opened for reading, or why it was skipped.
type OpenedFile = Result<(ChunkFileInfo, hdf5::File), StoreError>;

impl ChunkEntry {
    /// The file opened, or the error that says why it is skipped: the problem found when
    /// the session was opened, or what went wrong opening it now.
    fn open(&self) -> OpenedFile {
        let skipped = |msg: String| StoreError::Corrupt {
            msg,
            path: self.info.path.clone(),
        };
        if let Some(problem) = &self.info.problem {
            return Err(skipped(format!("skipped: {problem}")));
        }
        match open_chunk(&self.info.path, self.partial_hint.as_deref()) {
            Ok(file) => Ok((self.info.clone(), file)),
            Err(problem) => Err(skipped(problem)),
        }
    }
}

/// The next file of `files` from `*pos` on (advancing `pos`): its index and the open file,
/// or the error that says why it was skipped; `None` past the last file.
fn next_file(files: &[ChunkEntry], pos: &mut usize) -> Option<(usize, OpenedFile)> {
    let fi = *pos;
    let entry = files.get(fi)?;
    *pos += 1;
    Some((fi, entry.open()))
}

/// A chunk file whose tables could not be opened.
fn file_error(info: ChunkFileInfo, e: &hdf5::Error) -> StoreError {
    StoreError::Corrupt {
        path: info.path,
        msg: short_h5_error(e),
    }
}

/// Rows `r` of table `/group` in a chunk file could not be read.
fn rows_error(info: &ChunkFileInfo, group: &str, r: &Range<usize>, e: &hdf5::Error) -> StoreError {
    StoreError::Corrupt {
        path: info.path.clone(),
        msg: format!(
            "/{group} rows {}..{}: {}",
            r.start,
            r.end,
            short_h5_error(e)
        ),
    }
}

/// Undecoded bytes from `/raw/<device>`: `len[i]` bytes arrived at `t_mono_ns[i]`; the reads
/// are concatenated in `bytes`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RawBlock {
    pub t_mono_ns: Vec<i64>,
    pub len: Vec<u32>,
    pub bytes: Vec<u8>,
}

/// Rows and time span of one stream, from file metadata and a few point reads (cheap).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StreamSummary {
    pub rows: u64,
    pub first_t_mono_ns: Option<i64>,
    pub last_t_mono_ns: Option<i64>,
    /// Files that could not be summarised, one line each.
    pub problems: Vec<String>,
}

/// An open session directory.
pub struct Session {
    dir: PathBuf,
    manifest: Manifest,
    files: Vec<ChunkEntry>,
}

fn short_h5_error(e: &hdf5::Error) -> String {
    let text = e.to_string();
    text.lines().next().unwrap_or("").trim().to_string()
}

/// True when a live writer (imulogd, `imulab sim`) holds the session's writer lock. Probed
/// with a shared, non-blocking `flock` on the existing lock file, released at once: no file
/// is created and a running writer is never disturbed.
pub fn writer_is_live(dir: &Path) -> bool {
    let Ok(file) = std::fs::File::open(dir.join(layout::WRITER_LOCK_FILE)) else {
        return false;
    };
    matches!(
        nix::fcntl::Flock::lock(file, nix::fcntl::FlockArg::LockSharedNonblock),
        Err((_, nix::errno::Errno::EWOULDBLOCK))
    )
}

/// What to do about a `*.partial` file that does not open, depending on whether its writer
/// is still running.
fn partial_hint(dir: &Path, live: bool) -> String {
    if live {
        format!(
            " (still being written: a live writer holds {}; the closed chunk files are readable now; \
             wait for the writer to close this one (at rotation or when it stops), or if it crashed run `imulab recover {}`)",
            layout::WRITER_LOCK_FILE,
            dir.display()
        )
    } else {
        format!(
            " (left by a writer that stopped without closing it: run `imulab recover {}`)",
            dir.display()
        )
    }
}

/// Metadata reads a SWMR reader makes before it gives up on a block whose checksum fails.
/// HDF5's default (100, each retry after a growing sleep in `H5C_protect`) is meant for a
/// writer that is about to finish the block; on a damaged or truncated file it made
/// `inspect` hang for more than 10 minutes. A live writer's torn block is rewritten within
/// one flush, and the reader's next call sees it.
const SWMR_METADATA_READ_ATTEMPTS: u32 = 2;

/// Opens `path` read-only for SWMR reading, with [`SWMR_METADATA_READ_ATTEMPTS`].
pub(crate) fn open_swmr(path: &Path) -> hdf5::Result<hdf5::File> {
    hdf5::File::with_options()
        .with_fapl(|p| p.metadata_read_attempts(SWMR_METADATA_READ_ATTEMPTS))
        .open_as(path, hdf5::file::OpenMode::ReadSWMR)
}

/// Checks, before HDF5 sees the file, that it starts with an HDF5 superblock and, for a
/// version 2/3 superblock, that the file is as long as the end-of-file address it records
/// (a truncated file is refused here with sizes, instead of failing deep inside HDF5).
/// The error is one line naming the file.
pub(crate) fn check_superblock(path: &Path) -> Result<(), String> {
    let shown = path.display();
    let bytes = {
        use std::io::Read;
        let mut head = Vec::with_capacity(64);
        std::fs::File::open(path)
            .and_then(|f| f.take(64).read_to_end(&mut head))
            .map_err(|e| format!("{shown}: {e}"))?;
        head
    };
    let size = std::fs::metadata(path)
        .map_err(|e| format!("{shown}: {e}"))?
        .len();
    if size == 0 {
        return Err(format!("{shown}: empty file (0 bytes), not an HDF5 file"));
    }
    if bytes.len() < 8 || bytes[..8] != super::recover::HDF5_SIGNATURE {
        return Err(format!(
            "{shown}: not an HDF5 file (no HDF5 signature at its start; {size} bytes)"
        ));
    }
    let (Some(&version), Some(&size_of_offsets)) = (bytes.get(8), bytes.get(9)) else {
        return Err(format!("{shown}: truncated HDF5 superblock ({size} bytes)"));
    };
    if version >= 2 && size_of_offsets == 8 {
        // signature 8, version, sizes, flags; base, extension, EOF, root addresses.
        let Some(eof) = bytes.get(12 + 16..12 + 24) else {
            return Err(format!("{shown}: truncated HDF5 superblock ({size} bytes)"));
        };
        let eof = u64::from_le_bytes(eof.try_into().unwrap_or_default());
        let base = u64::from_le_bytes(bytes[12..20].try_into().unwrap_or_default());
        if base.saturating_add(eof) > size {
            return Err(format!(
                "{shown}: truncated or corrupt: the file is {size} bytes, its superblock records {}",
                base.saturating_add(eof)
            ));
        }
    }
    Ok(())
}

/// Opens one chunk file and checks its schema version; the error is one line naming it.
/// `partial_hint` is appended when a `*.partial` file does not open.
fn open_chunk(path: &Path, partial: Option<&str>) -> Result<hdf5::File, String> {
    let shown = path.display();
    check_superblock(path).map_err(|e| format!("{e}{}", partial.unwrap_or("")))?;
    let file = if partial.is_some() {
        // A live file is read SWMR; a killed writer's file may also open that way.
        open_swmr(path).or_else(|_| hdf5::File::open(path))
    } else {
        hdf5::File::open(path)
    };
    let file = file.map_err(|e| {
        let hint = partial.unwrap_or("");
        format!(
            "{shown}: cannot open as HDF5, truncated or corrupt{hint}: {}",
            short_h5_error(&e)
        )
    })?;
    let version = file
        .attr(ATTR_SCHEMA_VERSION)
        .and_then(|a| a.read_scalar::<u32>())
        .map_err(|_| format!("{shown}: not an imulab chunk file (no schema_version attribute)"))?;
    if version != SCHEMA_VERSION {
        return Err(format!(
            "{shown}: unknown schema version {version} (this build reads version {SCHEMA_VERSION})"
        ));
    }
    Ok(file)
}

impl Session {
    /// Opens a session directory: reads the manifest and checks that every chunk file opens
    /// (the readers open each again when they reach it). Fails only when the directory is
    /// not a session or its manifest is bad; per-file problems are reported by
    /// [`Session::files`] and [`Session::problems`].
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        Self::open_files(dir, 0, true)
    }

    /// [`Session::open`] of the chunk files numbered `first_index` and up only, without
    /// the warning about a live writer: what a follower of a live session opens at every
    /// look (`imulab watch`), the files before being complete and read already.
    pub fn open_from(dir: &Path, first_index: u32) -> Result<Self, StoreError> {
        Self::open_files(dir, first_index, false)
    }

    fn open_files(dir: &Path, first_index: u32, warn_live: bool) -> Result<Self, StoreError> {
        // Says whether the path is missing, a file, or a directory without a manifest.
        let manifest = Manifest::load(dir)?;
        let live = writer_is_live(dir);
        if live && warn_live {
            tracing::warn!(
                "{}: still being written (a live writer holds {}): reading what it has flushed so far; \
                 rerun when the writer has stopped for the whole run",
                dir.display(),
                layout::WRITER_LOCK_FILE
            );
        }
        let hint = partial_hint(dir, live);
        let mut found: Vec<(u32, bool, PathBuf)> = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(|e| StoreError::io(dir, e))? {
            let entry = entry.map_err(|e| StoreError::io(dir, e))?;
            let name = entry.file_name();
            let Some(name) = name.to_str() else { continue };
            if let Some((index, partial)) = layout::parse_chunk_file_name(name) {
                if index < first_index {
                    continue;
                }
                found.push((index, partial, entry.path()));
            }
        }
        found.sort_by_key(|(index, partial, _)| (*index, *partial));
        let mut files = Vec::with_capacity(found.len());
        for (i, (index, partial, path)) in found.iter().enumerate() {
            let size_bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
            let duplicate = i > 0 && found[i - 1].0 == *index;
            let partial_hint = partial.then(|| hint.clone());
            let problem = if duplicate {
                Some(format!(
                    "{}: both a final and a partial file for chunk {index}; reading the final one",
                    path.display()
                ))
            } else {
                open_chunk(path, partial_hint.as_deref()).err()
            };
            files.push(ChunkEntry {
                info: ChunkFileInfo {
                    path: path.clone(),
                    index: *index,
                    partial: *partial,
                    size_bytes,
                    problem,
                },
                partial_hint,
            });
        }
        Ok(Session {
            dir: dir.to_path_buf(),
            manifest,
            files,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    pub fn devices(&self) -> &[DeviceInfo] {
        &self.manifest.devices
    }

    /// Every chunk file in order, with its problem if it cannot be read.
    pub fn files(&self) -> Vec<ChunkFileInfo> {
        self.files.iter().map(|f| f.info.clone()).collect()
    }

    /// One line per unreadable chunk file.
    pub fn problems(&self) -> Vec<String> {
        self.files
            .iter()
            .filter_map(|f| f.info.problem.clone())
            .collect()
    }

    fn blocks<B: Block>(&self, group: String, range: TimeRange, block_rows: usize) -> BlockIter<B> {
        BlockIter {
            files: self.files.clone(),
            group,
            range,
            block_rows: block_rows.max(1),
            pos: 0,
            cursor: None,
            optional: false,
            _block: PhantomData,
        }
    }

    /// IMU rows of `device` in `range`, in blocks of at most `block_rows` rows (a block never
    /// spans two chunk files).
    pub fn imu_blocks(
        &self,
        device: &str,
        range: TimeRange,
        block_rows: usize,
    ) -> Result<impl Iterator<Item = Result<ImuBlock, StoreError>> + use<>, StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Imu))?;
        Ok(self.blocks::<ImuBlock>(layout::imu_path(device), range, block_rows))
    }

    /// Chosen columns of IMU `device` in `range`, in blocks of at most `block_rows` rows,
    /// each vector axis as its own column: what an analysis of a few channels needs, at a
    /// fraction of the cost of whole rows (only the chosen datasets are read, their chunks
    /// decoded directly, and the blocks' buffers are reused; see [`ImuColumnReader`]).
    pub fn imu_columns(
        &self,
        device: &str,
        range: TimeRange,
        block_rows: usize,
        set: ImuColumnSet,
    ) -> Result<ImuColumnReader, StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Imu))?;
        Ok(ImuColumnReader {
            files: self.files.clone(),
            group: layout::imu_path(device),
            range,
            block_rows: block_rows.max(1),
            set,
            pos: 0,
            cursor: None,
        })
    }

    /// GNSS rows of `device` in `range`, in blocks of at most `block_rows` rows.
    pub fn gnss_blocks(
        &self,
        device: &str,
        range: TimeRange,
        block_rows: usize,
    ) -> Result<impl Iterator<Item = Result<GnssBlock, StoreError>> + use<>, StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Gnss))?;
        Ok(self.blocks::<GnssBlock>(layout::gnss_path(device), range, block_rows))
    }

    /// Only the `t_mono_ns` column of device `device` (IMU or GNSS), in blocks: what a gap
    /// scan needs, at a fraction of the cost of whole rows.
    pub fn time_blocks(
        &self,
        device: &str,
        range: TimeRange,
        block_rows: usize,
    ) -> Result<impl Iterator<Item = Result<Vec<i64>, StoreError>> + use<>, StoreError> {
        let d = self.manifest.device_of_kind(device, None)?;
        let group = match d.kind {
            DeviceKind::Imu => layout::imu_path(device),
            DeviceKind::Gnss => layout::gnss_path(device),
        };
        Ok(self
            .blocks::<TimeBlock>(group, range, block_rows)
            .map(|b| b.map(|b| b.0)))
    }

    /// True trajectory rows (simulated sessions).
    pub fn truth_nav_blocks(
        &self,
        range: TimeRange,
        block_rows: usize,
    ) -> Result<impl Iterator<Item = Result<TruthNavBlock, StoreError>> + use<>, StoreError> {
        if self.manifest.truth_nav_rate_hz.is_none() {
            return Err(StoreError::Invalid(format!(
                "{}: not a simulated session (no truth)",
                self.dir.display()
            )));
        }
        Ok(self.blocks::<TruthNavBlock>(layout::TRUTH_NAV_GROUP.to_string(), range, block_rows))
    }

    /// True IMU error states of IMU `device` (simulated sessions).
    pub fn truth_imu_blocks(
        &self,
        device: &str,
        range: TimeRange,
        block_rows: usize,
    ) -> Result<impl Iterator<Item = Result<TruthImuBlock, StoreError>> + use<>, StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Imu))?;
        if self.manifest.truth_nav_rate_hz.is_none() {
            return Err(StoreError::Invalid(format!(
                "{}: not a simulated session (no truth)",
                self.dir.display()
            )));
        }
        Ok(self.blocks::<TruthImuBlock>(layout::truth_imu_path(device), range, block_rows))
    }

    /// Events in `range`, in blocks of at most `block_rows`.
    pub fn event_blocks(
        &self,
        range: TimeRange,
        block_rows: usize,
    ) -> impl Iterator<Item = Result<Vec<EventRecord>, StoreError>> + use<> {
        self.blocks::<EventBlock>(layout::EVENTS_GROUP.to_string(), range, block_rows)
            .map(|b| b.map(|b| b.0))
    }

    /// All events of the readable files, in file order, and one line per file that failed.
    pub fn events(&self) -> (Vec<EventRecord>, Vec<String>) {
        let mut events = Vec::new();
        let mut problems = Vec::new();
        for block in self.event_blocks(TimeRange::all(), 4096) {
            match block {
                Ok(b) => events.extend(b),
                Err(e) => problems.push(e.to_string()),
            }
        }
        (events, problems)
    }

    /// Raw journal of `device` in `range` (empty when the session kept no raw journal).
    pub fn raw_blocks(
        &self,
        device: &str,
        range: TimeRange,
        block_rows: usize,
    ) -> Result<impl Iterator<Item = Result<RawBlock, StoreError>> + use<>, StoreError> {
        self.manifest.device_of_kind(device, None)?;
        let mut inner = self.blocks::<RawIndexBlock>(layout::raw_path(device), range, block_rows);
        inner.optional = true;
        Ok(RawIter { inner })
    }

    /// Rows of table `group` (`imu/<name>`, `gnss/<name>`...) that the write-ahead journal
    /// of a `*.partial` chunk file holds beyond the rows of that file's HDF5 table. Readers
    /// do not see them; the live writer moves them into the file as chunks complete, and
    /// `imulab recover` adds them after a crash. One (partial file, rows) per partial file
    /// whose journal holds such rows.
    pub fn journal_backlog(&self, group: &str) -> Vec<(PathBuf, u64)> {
        let mut out = Vec::new();
        for entry in self.files.iter().filter(|e| e.info.partial) {
            let paths = super::journal::journal_paths(&self.dir, entry.info.index);
            let Ok(contents) = super::journal::read(&paths) else {
                continue;
            };
            let mine = contents.records.iter().filter(|r| r.id == group);
            let Some(first) = mine.clone().map(|r| r.first).min() else {
                continue;
            };
            let end = mine
                .map(|r| r.first + u64::from(r.count))
                .max()
                .unwrap_or(0);
            let in_file = entry
                .open()
                .ok()
                .and_then(|(_, f)| open_table(&f, group, &[super::columns::T_MONO]).ok())
                .map_or(0, |(_, len)| len as u64);
            let rows = end.saturating_sub(in_file.max(first));
            if rows > 0 {
                out.push((entry.info.path.clone(), rows));
            }
        }
        out
    }

    /// Row count and time span of a stream (`imu/<name>`, `gnss/<name>`, `events`...), from
    /// dataset sizes and first/last times only.
    pub fn stream_summary(&self, group: &str) -> StreamSummary {
        let mut s = StreamSummary::default();
        for entry in &self.files {
            let Ok((_, file)) = entry.open() else {
                continue;
            };
            match open_table(&file, group, &[super::columns::T_MONO]) {
                Ok((ds, len)) => {
                    if len == 0 {
                        continue;
                    }
                    s.rows += len as u64;
                    match (t_at(&ds[0], 0), t_at(&ds[0], len - 1)) {
                        (Ok(first), Ok(last)) => {
                            s.first_t_mono_ns =
                                Some(s.first_t_mono_ns.map_or(first, |f| f.min(first)));
                            s.last_t_mono_ns = Some(s.last_t_mono_ns.map_or(last, |l| l.max(last)));
                        }
                        (Err(e), _) | (_, Err(e)) => s.problems.push(format!(
                            "{}: {group}: cannot read times: {}",
                            entry.info.path.display(),
                            short_h5_error(&e)
                        )),
                    }
                }
                Err(e) => s.problems.push(format!(
                    "{}: {group}: {}",
                    entry.info.path.display(),
                    short_h5_error(&e)
                )),
            }
        }
        s
    }
}

fn t_at(ds: &Dataset, i: usize) -> hdf5::Result<i64> {
    ds.read_slice_1d::<i64, _>(i..i + 1)?
        .first()
        .copied()
        .ok_or_else(|| "empty read".into())
}

/// Opens the datasets of a table; its usable length is the shortest column, less any tail
/// rows whose time never reached the disk (a live or recovered file).
fn open_table(
    file: &hdf5::File,
    group: &str,
    cols: &[super::columns::Column],
) -> hdf5::Result<(Vec<Dataset>, usize)> {
    let g = file
        .group(group)
        .map_err(|_| hdf5::Error::from(format!("no group /{group}")))?;
    let mut ds = Vec::with_capacity(cols.len());
    let mut len = usize::MAX;
    for c in cols {
        let d = match g.dataset(c.name) {
            Ok(d) => d,
            // A file written before the column: the block reader fills it in.
            Err(_) if c.optional => break,
            Err(_) => return Err(format!("no dataset /{group}/{}", c.name).into()),
        };
        let shape = d.shape();
        let rows = shape.first().copied().unwrap_or(0);
        if c.width != 0 && shape.get(1).copied() != Some(c.width) {
            return Err(format!(
                "/{group}/{} has shape {shape:?}, expected N×{}",
                c.name, c.width
            )
            .into());
        }
        len = len.min(rows);
        ds.push(d);
    }
    let len = if len == usize::MAX { 0 } else { len };
    let len = valid_prefix(&ds[0], len)?;
    Ok((ds, len))
}

/// Number of leading rows whose `t_mono_ns` is not the fill value. Unwritten rows only ever
/// sit at the end, so this is a binary search.
pub(crate) fn valid_prefix(t: &Dataset, len: usize) -> hdf5::Result<usize> {
    if len == 0 || t_at(t, len - 1)? != FILL_T_MONO {
        return Ok(len);
    }
    let (mut lo, mut hi) = (0, len - 1);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if t_at(t, mid)? == FILL_T_MONO {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    Ok(lo)
}

/// First row in `0..len` with time >= `x` (times are non-decreasing).
fn lower_bound(t: &Dataset, len: usize, x: i64) -> hdf5::Result<usize> {
    let (mut lo, mut hi) = (0, len);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if t_at(t, mid)? < x {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    Ok(lo)
}

struct Cursor {
    file_index: usize,
    /// Held while its datasets are read; the file closes when the cursor moves on.
    file: hdf5::File,
    ds: Vec<Dataset>,
    next: usize,
    end: usize,
}

/// Streams one table across chunk files.
struct BlockIter<B> {
    files: Vec<ChunkEntry>,
    group: String,
    range: TimeRange,
    block_rows: usize,
    pos: usize,
    cursor: Option<Cursor>,
    /// A missing group is not an error (the raw journal is optional).
    optional: bool,
    _block: PhantomData<B>,
}

impl<B: Block> BlockIter<B> {
    fn open_cursor(&self, file_index: usize, file: hdf5::File) -> hdf5::Result<Option<Cursor>> {
        if self.optional && file.group(&self.group).is_err() {
            return Ok(None);
        }
        let (ds, len) = open_table(&file, &self.group, B::COLUMNS)?;
        let rows = self.range.rows(&ds[0], len)?;
        Ok(Some(Cursor {
            file_index,
            file,
            ds,
            next: rows.start,
            end: rows.end,
        }))
    }

    /// Next block and the index of the file it came from.
    fn next_with_file(&mut self) -> Option<Result<(B, usize), StoreError>> {
        loop {
            if let Some(c) = &mut self.cursor {
                if c.next < c.end {
                    let r: Range<usize> = c.next..(c.next + self.block_rows).min(c.end);
                    c.next = r.end;
                    let fi = c.file_index;
                    let result = B::read(&c.ds, r.clone())
                        .map(|b| (b, fi))
                        .map_err(|e| rows_error(&self.files[fi].info, &self.group, &r, &e));
                    if result.is_err() {
                        self.cursor = None;
                    }
                    return Some(result);
                }
                self.cursor = None;
            }
            let (fi, opened) = next_file(&self.files, &mut self.pos)?;
            let (info, file) = match opened {
                Ok(opened) => opened,
                Err(e) => return Some(Err(e)),
            };
            match self.open_cursor(fi, file) {
                Ok(c) => self.cursor = c,
                Err(e) => return Some(Err(file_error(info, &e))),
            }
        }
    }
}

impl<B: Block> Iterator for BlockIter<B> {
    type Item = Result<B, StoreError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_with_file().map(|r| r.map(|(b, _)| b))
    }
}

/// Which IMU columns [`Session::imu_columns`] reads (`t_mono_ns` always).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ImuColumnSet {
    pub t_sensor: bool,
    pub gyro: bool,
    pub accel: bool,
    pub temp: bool,
}

/// A block of chosen IMU columns (see [`ImuBlock`] for units), vectors split per axis;
/// columns not chosen stay empty.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImuColumns {
    pub t_mono_ns: Vec<i64>,
    pub t_sensor: Vec<f64>,
    pub gyro: [Vec<f64>; 3],
    pub accel: [Vec<f64>; 3],
    pub temp: Vec<f64>,
}

impl ImuColumns {
    pub fn len(&self) -> usize {
        self.t_mono_ns.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t_mono_ns.is_empty()
    }
    fn clear(&mut self) {
        self.t_mono_ns.clear();
        self.t_sensor.clear();
        self.gyro.iter_mut().for_each(Vec::clear);
        self.accel.iter_mut().for_each(Vec::clear);
        self.temp.clear();
    }

    /// The chosen columns `rows` long, the others empty. What they held is kept (the reader
    /// overwrites every value), so a block as long as the one before costs no zeroing.
    fn fit(&mut self, set: ImuColumnSet, rows: usize) {
        fn fit<T: Copy + Default>(v: &mut Vec<T>, on: bool, rows: usize) {
            v.resize(if on { rows } else { 0 }, T::default());
        }
        fit(&mut self.t_mono_ns, true, rows);
        fit(&mut self.t_sensor, set.t_sensor, rows);
        self.gyro.iter_mut().for_each(|v| fit(v, set.gyro, rows));
        self.accel.iter_mut().for_each(|v| fit(v, set.accel, rows));
        fit(&mut self.temp, set.temp, rows);
    }
}

/// Positions of the IMU columns in `IMU_COLUMNS`.
const IMU_T_SENSOR: usize = 2;
const IMU_GYRO: usize = 3;
const IMU_ACCEL: usize = 4;
const IMU_TEMP: usize = 5;

/// The open datasets of one file for [`ImuColumnReader`].
struct ColumnCursor {
    file_index: usize,
    /// Held while its datasets are read; the file closes when the cursor moves on.
    _file: hdf5::File,
    t_mono: ColumnReader,
    t_sensor: Option<ColumnReader>,
    gyro: Option<ColumnReader>,
    accel: Option<ColumnReader>,
    temp: Option<ColumnReader>,
    next: usize,
    end: usize,
}

/// Streams chosen IMU columns across chunk files into a caller's [`ImuColumns`], reusing its
/// buffers. Like the row iterators, a file that cannot be read yields one `Err` naming it,
/// and the next call carries on with the next file.
pub struct ImuColumnReader {
    files: Vec<ChunkEntry>,
    group: String,
    range: TimeRange,
    block_rows: usize,
    set: ImuColumnSet,
    pos: usize,
    cursor: Option<ColumnCursor>,
}

impl ImuColumnReader {
    /// Replaces the contents of `out` with the next block: `None` at the end of the stream.
    pub fn next_into(&mut self, out: &mut ImuColumns) -> Option<Result<(), StoreError>> {
        loop {
            if let Some(c) = &mut self.cursor {
                if c.next < c.end {
                    let r =
                        c.next..block_end(c.next, c.end, self.block_rows, c.t_mono.chunk_rows());
                    c.next = r.end;
                    out.fit(self.set, r.len());
                    let result = read_columns(c, r.clone(), out).map_err(|e| {
                        rows_error(&self.files[c.file_index].info, &self.group, &r, &e)
                    });
                    if result.is_err() {
                        out.clear();
                        self.cursor = None;
                    }
                    return Some(result);
                }
                self.cursor = None;
            }
            let (fi, opened) = next_file(&self.files, &mut self.pos)?;
            let (info, file) = match opened {
                Ok(opened) => opened,
                Err(e) => return Some(Err(e)),
            };
            match self.open_cursor(fi, file, !info.partial) {
                Ok(c) => self.cursor = Some(c),
                Err(e) => return Some(Err(file_error(info, &e))),
            }
        }
    }

    fn open_cursor(
        &self,
        file_index: usize,
        file: hdf5::File,
        direct: bool,
    ) -> hdf5::Result<ColumnCursor> {
        let mut cols = vec![IMU_COLUMNS[0]];
        let chosen = [
            (self.set.t_sensor, IMU_T_SENSOR),
            (self.set.gyro, IMU_GYRO),
            (self.set.accel, IMU_ACCEL),
            (self.set.temp, IMU_TEMP),
        ];
        cols.extend(
            chosen
                .iter()
                .filter(|(on, _)| *on)
                .map(|&(_, i)| IMU_COLUMNS[i]),
        );
        let (ds, len) = open_table(&file, &self.group, &cols)?;
        let rows = self.range.rows(&ds[0], len)?;
        let mut ds = ds.into_iter();
        let mut next = |on: bool| -> hdf5::Result<Option<ColumnReader>> {
            if !on {
                return Ok(None);
            }
            let d = ds
                .next()
                .ok_or_else(|| hdf5::Error::from("missing dataset"))?;
            ColumnReader::new(d, len, direct).map(Some)
        };
        let t_mono = next(true)?.ok_or_else(|| hdf5::Error::from("missing t_mono_ns"))?;
        Ok(ColumnCursor {
            file_index,
            _file: file,
            t_mono,
            t_sensor: next(self.set.t_sensor)?,
            gyro: next(self.set.gyro)?,
            accel: next(self.set.accel)?,
            temp: next(self.set.temp)?,
            next: rows.start,
            end: rows.end,
        })
    }
}

/// Where the block of at most `block_rows` rows starting at row `next` of a file's `end`
/// ends. The rows left are split into blocks of even length, so that no block of a file is
/// longer than the one before and the caller's columns are never grown again (see
/// [`ImuColumns::fit`]; the old rule, full blocks and a short rest, grew them at every file);
/// each block ends on a chunk boundary where it can, so that no chunk is
/// split between two blocks (a split one is decoded apart, not in parallel).
fn block_end(next: usize, end: usize, block_rows: usize, chunk: usize) -> usize {
    let (left, chunk) = (end - next, chunk.max(1));
    let blocks = left.div_ceil(block_rows.max(1));
    let mut rows = left.div_ceil(blocks.max(1)).div_ceil(chunk) * chunk;
    if rows > block_rows {
        rows = block_rows / chunk * chunk;
    }
    if rows == 0 {
        rows = block_rows.max(1);
    }
    // Chunk boundaries are counted from row 0 of the file, not from `next`.
    let mut stop = (next + rows).min(end);
    if stop < end && stop / chunk * chunk > next {
        stop = stop / chunk * chunk;
    }
    stop
}

/// Rows `r` of the cursor's chosen columns into `out`, whose chosen columns are `r.len()`
/// long (every value is overwritten).
fn read_columns(c: &mut ColumnCursor, r: Range<usize>, out: &mut ImuColumns) -> hdf5::Result<()> {
    c.t_mono.read_i64_into(r.clone(), &mut out.t_mono_ns)?;
    if let Some(t) = &mut c.t_sensor {
        t.read_f64_into(r.clone(), &mut [&mut out.t_sensor])?;
    }
    if let Some(g) = &mut c.gyro {
        let [x, y, z] = &mut out.gyro;
        g.read_f64_into(r.clone(), &mut [x, y, z])?;
    }
    if let Some(a) = &mut c.accel {
        let [x, y, z] = &mut out.accel;
        a.read_f64_into(r.clone(), &mut [x, y, z])?;
    }
    if let Some(t) = &mut c.temp {
        t.read_f64_into(r, &mut [&mut out.temp])?;
    }
    Ok(())
}

struct RawIter {
    inner: BlockIter<RawIndexBlock>,
}

impl Iterator for RawIter {
    type Item = Result<RawBlock, StoreError>;
    fn next(&mut self) -> Option<Self::Item> {
        let (index, fi) = match self.inner.next_with_file()? {
            Ok(x) => x,
            Err(e) => return Some(Err(e)),
        };
        let path = self.inner.files[fi].info.path.clone();
        let corrupt = |msg: String| StoreError::Corrupt {
            path: path.clone(),
            msg,
        };
        let (Some(&first), Some(&last), Some(&last_len)) =
            (index.offset.first(), index.offset.last(), index.len.last())
        else {
            return Some(Ok(RawBlock::default()));
        };
        let start = usize::try_from(first).unwrap_or(usize::MAX);
        let end = usize::try_from(last.saturating_add(u64::from(last_len))).unwrap_or(usize::MAX);
        let file = match &self.inner.cursor {
            Some(c) if c.file_index == fi => &c.file,
            _ => return Some(Err(corrupt("file not open".into()))),
        };
        let bytes = file
            .dataset(&format!("{}/{}", self.inner.group, RAW_BYTES.name))
            .and_then(|ds| {
                if end > ds.shape().first().copied().unwrap_or(0) || start > end {
                    return Err(
                        format!("raw index points past the {}-byte journal", ds.size()).into(),
                    );
                }
                read_bytes(&ds, start..end)
            });
        Some(match bytes {
            Ok(bytes) => Ok(RawBlock {
                t_mono_ns: index.t_mono_ns,
                len: index.len,
                bytes,
            }),
            Err(e) => Err(corrupt(format!(
                "/{}: {}",
                self.inner.group,
                short_h5_error(&e)
            ))),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::block_end;

    /// Blocks cover the rows once, in order, never longer than asked nor than the block
    /// before, and end on chunk boundaries except at the end of the rows.
    #[test]
    fn blocks_are_even_and_end_on_chunks() {
        for (start, end, block, chunk) in [
            (0, 90_000, 65_536, 1500),
            (0, 3_240_000, 65_536, 1500),
            (700, 90_000, 65_536, 1500),
            (0, 1037, 73, 100),
            (0, 10, 65_536, 1500),
            (5, 999, 250, 1),
            (0, 500, 100, 300),
        ] {
            let mut next = start;
            let mut lengths = Vec::new();
            while next < end {
                let stop = block_end(next, end, block, chunk);
                assert!(
                    stop > next && stop <= end,
                    "{start}..{end}: {next} -> {stop}"
                );
                assert!(
                    stop - next <= block.max(chunk),
                    "{start}..{end}: {next} -> {stop}"
                );
                if stop < end && chunk <= block {
                    assert_eq!(stop % chunk, 0, "{start}..{end}: {next} -> {stop}");
                }
                lengths.push(stop - next);
                next = stop;
            }
            // No block longer than the one before (the columns are never grown again).
            if start == 0 && chunk <= block {
                assert!(
                    lengths.windows(2).all(|w| w[1] <= w[0]),
                    "{start}..{end}: {lengths:?}"
                );
            }
        }
    }
}
