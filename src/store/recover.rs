//! `recover`: turns the `*.partial` chunk file a killed writer left behind into a normal,
//! readable chunk file, keeping every row that reached the disk intact.
//!
//! A SWMR writer marks the HDF5 superblock "open for (SWMR) write"; after `kill -9` the flag
//! stays set and the library refuses to open the file for writing. `h5clear -s` clears it,
//! but hdf5-tools may not be installed where a session is recovered and the HDF5 C API has
//! no call for it, so the superblock is patched here by hand: the flags byte is zeroed and
//! the superblock checksum (Jenkins lookup3, as HDF5 computes it) is recomputed.
//!
//! Rows the writer had only in its write-ahead journal (`chunk-NNNNNN.h5.journal{0,1}`, see
//! `journal`) are then appended to each table, from the first row the HDF5 file does not
//! hold; rows it already holds are skipped, so recovering twice gives the same file. A
//! partial file without a journal (sessions written before it, schema 1) recovers as before.
//!
//! Recover never makes a session worse: it checks the free space first (the copy and the
//! journal's rows must fit), works on a copy named `chunk-NNNNNN.h5.recovering` and renames
//! it into place only when it is complete and durable; on any failure the copy goes and the
//! partial file and its journal are as they were. A truncated copy is padded to the size its
//! superblock records so HDF5 opens it and what is still there is read; when HDF5 cannot
//! open it at all, the chunk is rebuilt in a new file from the journal's rows, and the rows
//! of each table that neither holds are reported as dropped.

use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::columns::{
    create_column, put_1d, put_str_attr, Block, ChunkSink, Column, EventBlock, EventRow, GnssBlock,
    ImuBlock, RawIndexBlock, RawIndexRow, Row, TruthImuBlock, TruthNavBlock, RAW_BYTES,
};
use super::journal::{self, Cursor, Record};
use super::layout;
use super::manifest::{fsync_dir, try_writer_lock, Manifest};
use super::reader::valid_prefix;
use super::records::{GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord};
use super::StoreError;

pub(crate) const HDF5_SIGNATURE: [u8; 8] = [0x89, b'H', b'D', b'F', b'\r', b'\n', 0x1a, b'\n'];

/// Jenkins' lookup3 `hashlittle`, byte-at-a-time as HDF5's `H5_checksum_lookup3`.
pub fn lookup3(key: &[u8], initval: u32) -> u32 {
    fn mix(a: &mut u32, b: &mut u32, c: &mut u32) {
        *a = a.wrapping_sub(*c);
        *a ^= c.rotate_left(4);
        *c = c.wrapping_add(*b);
        *b = b.wrapping_sub(*a);
        *b ^= a.rotate_left(6);
        *a = a.wrapping_add(*c);
        *c = c.wrapping_sub(*b);
        *c ^= b.rotate_left(8);
        *b = b.wrapping_add(*a);
        *a = a.wrapping_sub(*c);
        *a ^= c.rotate_left(16);
        *c = c.wrapping_add(*b);
        *b = b.wrapping_sub(*a);
        *b ^= a.rotate_left(19);
        *a = a.wrapping_add(*c);
        *c = c.wrapping_sub(*b);
        *c ^= b.rotate_left(4);
        *b = b.wrapping_add(*a);
    }
    fn final_mix(a: &mut u32, b: &mut u32, c: &mut u32) {
        *c ^= *b;
        *c = c.wrapping_sub(b.rotate_left(14));
        *a ^= *c;
        *a = a.wrapping_sub(c.rotate_left(11));
        *b ^= *a;
        *b = b.wrapping_sub(a.rotate_left(25));
        *c ^= *b;
        *c = c.wrapping_sub(b.rotate_left(16));
        *a ^= *c;
        *a = a.wrapping_sub(c.rotate_left(4));
        *b ^= *a;
        *b = b.wrapping_sub(a.rotate_left(14));
        *c ^= *b;
        *c = c.wrapping_sub(b.rotate_left(24));
    }
    fn word(bytes: &[u8]) -> u32 {
        // Little-endian of up to 4 bytes; missing high bytes count as zero.
        bytes
            .iter()
            .enumerate()
            .fold(0u32, |acc, (i, &b)| acc | (u32::from(b) << (8 * i)))
    }
    let init = 0xdead_beef_u32
        .wrapping_add(key.len() as u32)
        .wrapping_add(initval);
    let (mut a, mut b, mut c) = (init, init, init);
    let mut rest = key;
    while rest.len() > 12 {
        a = a.wrapping_add(word(&rest[0..4]));
        b = b.wrapping_add(word(&rest[4..8]));
        c = c.wrapping_add(word(&rest[8..12]));
        mix(&mut a, &mut b, &mut c);
        rest = &rest[12..];
    }
    if rest.is_empty() {
        return c;
    }
    a = a.wrapping_add(word(&rest[..rest.len().min(4)]));
    if rest.len() > 4 {
        b = b.wrapping_add(word(&rest[4..rest.len().min(8)]));
    }
    if rest.len() > 8 {
        c = c.wrapping_add(word(&rest[8..]));
    }
    final_mix(&mut a, &mut b, &mut c);
    c
}

/// Where the superblock is and what its flags byte says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SuperblockState {
    pub offset: u64,
    pub version: u8,
    pub flags: u8,
}

/// Clears the file-consistency flags of a version 2/3 superblock (what `h5clear -s` does).
/// Returns the state found before clearing. Versions 0/1 keep no such flags and are left.
pub fn clear_superblock_flags(path: &Path) -> Result<SuperblockState, StoreError> {
    let corrupt = |msg: String| StoreError::Corrupt {
        path: path.to_path_buf(),
        msg,
    };
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .map_err(|e| StoreError::io(path, e))?;
    let size = f.metadata().map_err(|e| StoreError::io(path, e))?.len();
    // The superblock sits at 0, 512, 1024, 2048... (after a user block).
    let mut offset = 0u64;
    loop {
        if offset + 8 > size {
            return Err(corrupt("no HDF5 superblock signature found".into()));
        }
        let mut sig = [0u8; 8];
        f.seek(SeekFrom::Start(offset))
            .and_then(|_| f.read_exact(&mut sig))
            .map_err(|e| StoreError::io(path, e))?;
        if sig == HDF5_SIGNATURE {
            break;
        }
        offset = if offset == 0 { 512 } else { offset * 2 };
    }
    let mut head = [0u8; 4];
    f.read_exact(&mut head)
        .map_err(|e| StoreError::io(path, e))?;
    let [version, size_of_offsets, _size_of_lengths, flags] = head;
    let state = SuperblockState {
        offset,
        version,
        flags,
    };
    if version < 2 {
        return Ok(state);
    }
    if version > 3 {
        return Err(corrupt(format!(
            "superblock version {version} is not supported"
        )));
    }
    if !matches!(size_of_offsets, 2 | 4 | 8) {
        return Err(corrupt(format!(
            "superblock: bad size of offsets {size_of_offsets}"
        )));
    }
    // signature, version, sizes, flags, then base, extension, EOF and root addresses.
    let body_len = 12 + 4 * usize::from(size_of_offsets);
    let mut sb = vec![0u8; body_len + 4];
    f.seek(SeekFrom::Start(offset))
        .and_then(|_| f.read_exact(&mut sb))
        .map_err(|e| corrupt(format!("superblock is truncated: {e}")))?;
    let stored = u32::from_le_bytes([
        sb[body_len],
        sb[body_len + 1],
        sb[body_len + 2],
        sb[body_len + 3],
    ]);
    if lookup3(&sb[..body_len], 0) != stored {
        return Err(corrupt(
            "superblock checksum does not match; not touching it".into(),
        ));
    }
    if flags == 0 {
        return Ok(state);
    }
    sb[11] = 0;
    let sum = lookup3(&sb[..body_len], 0).to_le_bytes();
    sb[body_len..].copy_from_slice(&sum);
    f.seek(SeekFrom::Start(offset))
        .and_then(|_| f.write_all(&sb))
        .and_then(|_| f.sync_all())
        .map_err(|e| StoreError::io(path, e))?;
    Ok(state)
}

/// What `recover` did to one table of one file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TableRecovery {
    pub group: String,
    pub rows_kept: u64,
    /// Rows whose time had reached the disk but which were cut (a column shorter than the
    /// time column, or a block that does not read back). Rows the writer had only grown
    /// its datasets for, or whose time was never written, were never rows and are not counted.
    pub rows_dropped: u64,
    /// Of `rows_kept`, the rows taken from the write-ahead journal.
    pub rows_from_journal: u64,
}

/// What `recover` did to one partial file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileRecovery {
    pub from: PathBuf,
    pub to: PathBuf,
    pub superblock_flags_cleared: bool,
    pub tables: Vec<TableRecovery>,
    /// Bytes at the end of the journal dropped as torn or corrupt (0 without a journal).
    pub journal_bytes_dropped: u64,
    /// Why the HDF5 file was beyond repair, when the chunk was rebuilt from its journal
    /// into a new file (the rows the journal did not hold are counted as dropped).
    pub rebuilt: Option<String>,
}

/// What `recover` did to a session.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RecoverReport {
    pub files: Vec<FileRecovery>,
}

/// Rows of a table to check per read while verifying it.
const VERIFY_ROWS: usize = 8192;

/// Makes a table consistent: all columns the same length, no unwritten tail, every row
/// readable. Returns rows kept and dropped.
fn repair_table<B: Block>(file: &hdf5::File, group: &str) -> hdf5::Result<TableRecovery> {
    let g = file.group(group)?;
    let ds: Vec<hdf5::Dataset> = B::COLUMNS
        .iter()
        .map(|c: &Column| g.dataset(c.name))
        .collect::<hdf5::Result<_>>()?;
    let lens: Vec<usize> = ds
        .iter()
        .map(|d| d.shape().first().copied().unwrap_or(0))
        .collect();
    let timed = valid_prefix(&ds[0], lens.first().copied().unwrap_or(0)).unwrap_or(0);
    let mut len = lens.iter().copied().min().unwrap_or(0);
    len = valid_prefix(&ds[0], len).unwrap_or(0);
    // Read every row back; stop at the first block that does not read.
    let mut good = 0;
    while good < len {
        let end = (good + VERIFY_ROWS).min(len);
        if B::read(&ds, good..end).is_err() {
            break;
        }
        good = end;
    }
    let len = good;
    for (d, c) in ds.iter().zip(B::COLUMNS) {
        if d.shape().first().copied().unwrap_or(0) != len {
            if c.width == 0 {
                d.resize(len)?;
            } else {
                d.resize((len, c.width))?;
            }
        }
    }
    Ok(TableRecovery {
        group: group.to_string(),
        rows_kept: len as u64,
        rows_dropped: timed.saturating_sub(len) as u64,
        rows_from_journal: 0,
    })
}

/// The rows of table `id` in `records` from row `from` on, and how many rows were skipped
/// because no record holds them (rows the HDF5 file had but lost, when it was damaged and
/// rebuilt). A record that does not decode ends them (it passed its CRC, so that is a writer
/// bug, and reported in the log).
fn journal_rows<R: Row>(records: &[Record], id: &str, from: usize) -> (Vec<R>, u64) {
    let mut rows = Vec::new();
    let mut lost = 0;
    let mut next = from as u64;
    // The two journal files' records, in row order (they may overlap; overlaps are skipped).
    let mut mine: Vec<&Record> = records.iter().filter(|r| r.id == id).collect();
    mine.sort_by_key(|r| r.first);
    for rec in mine {
        let end = rec.first + u64::from(rec.count);
        if end <= next {
            continue;
        }
        if rec.first > next {
            tracing::warn!(
                "{id}: rows {next}..{} are neither in the HDF5 file nor in the journal",
                rec.first
            );
            lost += rec.first - next;
            next = rec.first;
        }
        let mut c = Cursor {
            bytes: &rec.payload,
            version: rec.version,
        };
        let decoded: Result<Vec<R>, String> = (0..rec.count).map(|_| R::decode(&mut c)).collect();
        match decoded {
            Ok(d) => {
                rows.extend(d.into_iter().skip((next - rec.first) as usize));
                next = end;
            }
            Err(e) => {
                tracing::error!("journal of {id}: record at row {}: {e}", rec.first);
                break;
            }
        }
    }
    (rows, lost)
}

/// Appends `rows` at row `at` of the table `group` (whose columns all hold `at` rows).
fn append_rows<R: Row>(file: &hdf5::File, group: &str, at: usize, rows: &[R]) -> hdf5::Result<()> {
    if rows.is_empty() {
        return Ok(());
    }
    let g = file.group(group)?;
    let ds: Vec<hdf5::Dataset> = R::COLUMNS
        .iter()
        .map(|c| g.dataset(c.name))
        .collect::<hdf5::Result<_>>()?;
    let end = at + rows.len();
    for (d, c) in ds.iter().zip(R::COLUMNS) {
        if c.width == 0 {
            d.resize(end)?;
        } else {
            d.resize((end, c.width))?;
        }
    }
    R::write(rows, &ds, at, &mut ChunkSink::through_pipeline())
}

/// [`repair_table`], then the journal's rows beyond those kept appended.
fn repair_and_replay<B: Block, R: Row>(
    file: &hdf5::File,
    group: &str,
    records: &[Record],
) -> hdf5::Result<TableRecovery> {
    debug_assert_eq!(B::COLUMNS.len(), R::COLUMNS.len());
    let mut t = repair_table::<B>(file, group)?;
    let at = t.rows_kept as usize;
    let (rows, lost): (Vec<R>, u64) = journal_rows(records, group, at);
    append_rows(file, group, at, &rows)?;
    t.rows_kept += rows.len() as u64;
    t.rows_from_journal = rows.len() as u64;
    t.rows_dropped += lost;
    Ok(t)
}

/// Repairs `/raw/<name>`: the index like any table, then the bytes cut to what it covers.
fn repair_raw(file: &hdf5::File, group: &str) -> hdf5::Result<TableRecovery> {
    let mut t = repair_table::<RawIndexBlock>(file, group)?;
    let g = file.group(group)?;
    let bytes = g.dataset(RAW_BYTES.name)?;
    let n_bytes = bytes.shape().first().copied().unwrap_or(0);
    let rows = t.rows_kept as usize;
    let idx = if rows > 0 {
        RawIndexBlock::read(
            &RawIndexBlock::COLUMNS
                .iter()
                .map(|c| g.dataset(c.name))
                .collect::<hdf5::Result<Vec<_>>>()?,
            0..rows,
        )?
    } else {
        RawIndexBlock::default()
    };
    // Keep index rows whose bytes are all present.
    let keep = idx
        .offset
        .iter()
        .zip(&idx.len)
        .take_while(|(o, l)| o.saturating_add(u64::from(**l)) <= n_bytes as u64)
        .count();
    if keep < rows {
        for c in RawIndexBlock::COLUMNS {
            g.dataset(c.name)?.resize(keep)?;
        }
        t.rows_dropped += (rows - keep) as u64;
        t.rows_kept = keep as u64;
    }
    let covered = if keep > 0 {
        (idx.offset[keep - 1] + u64::from(idx.len[keep - 1])) as usize
    } else {
        0
    };
    if covered < n_bytes {
        bytes.resize(covered)?;
    }
    Ok(t)
}

/// [`repair_raw`], then the journal's bytes beyond those kept, and its index rows whose
/// bytes are all present, appended.
fn repair_and_replay_raw(
    file: &hdf5::File,
    group: &str,
    records: &[Record],
) -> hdf5::Result<TableRecovery> {
    let mut t = repair_raw(file, group)?;
    let g = file.group(group)?;
    let bytes = g.dataset(RAW_BYTES.name)?;
    let mut n_bytes = bytes.shape().first().copied().unwrap_or(0) as u64;
    let bytes_id = format!("{group}/{}", RAW_BYTES.name);
    let mut new_bytes = Vec::new();
    let mut mine: Vec<&Record> = records.iter().filter(|r| r.id == bytes_id).collect();
    mine.sort_by_key(|r| r.first);
    for rec in mine {
        let end = rec.first + rec.payload.len() as u64;
        if end <= n_bytes + new_bytes.len() as u64 {
            continue;
        }
        let next = n_bytes + new_bytes.len() as u64;
        if rec.first > next {
            break;
        }
        new_bytes.extend_from_slice(&rec.payload[(next - rec.first) as usize..]);
    }
    if !new_bytes.is_empty() {
        put_1d(&bytes, n_bytes as usize, &new_bytes)?;
        n_bytes += new_bytes.len() as u64;
    }
    let at = t.rows_kept as usize;
    // Byte offsets are positions in the bytes column: only rows that follow on are kept.
    let (mut rows, lost): (Vec<RawIndexRow>, u64) = journal_rows(records, group, at);
    if lost > 0 {
        rows.clear();
    }
    let complete = rows
        .iter()
        .take_while(|r| r.offset.saturating_add(u64::from(r.len)) <= n_bytes)
        .count();
    rows.truncate(complete);
    append_rows(file, group, at, &rows)?;
    t.rows_kept += rows.len() as u64;
    t.rows_from_journal = rows.len() as u64;
    Ok(t)
}

/// Gives a table of a file written before its optional columns existed those columns,
/// NaN in every row it has, so the journal's rows (which have them) can be appended.
fn add_optional_columns<B: Block>(file: &hdf5::File, group: &str) -> hdf5::Result<()> {
    let g = file.group(group)?;
    let t = g.dataset(B::COLUMNS[0].name)?;
    let rows = t.shape().first().copied().unwrap_or(0);
    let chunk_rows = t
        .chunk()
        .and_then(|c| c.first().copied())
        .unwrap_or(layout::EVENT_CHUNK_ROWS);
    for c in B::COLUMNS.iter().filter(|c| c.optional) {
        if g.dataset(c.name).is_ok() {
            continue;
        }
        let d = create_column(&g, c, chunk_rows, 1)?;
        put_str_attr(&d, layout::ATTR_AXIS_FRAME, "NED")?;
        put_1d(&d, 0, &vec![f64::NAN; rows])?;
    }
    Ok(())
}

fn member_names(file: &hdf5::File, group: &str) -> Vec<String> {
    file.group(group)
        .and_then(|g| g.member_names())
        .unwrap_or_default()
}

/// Repairs the partial chunk file at `path` in place (its superblock flags already cleared)
/// and appends the rows of its journal `records` the file does not hold.
fn repair_file(path: &Path, records: &[Record]) -> Result<Vec<TableRecovery>, StoreError> {
    let file = hdf5::File::open_rw(path).map_err(|e| StoreError::Corrupt {
        path: path.to_path_buf(),
        msg: format!(
            "cannot open after clearing the superblock flags: {}",
            e.to_string().lines().next().unwrap_or("")
        ),
    })?;
    let mut tables = Vec::new();
    let mut go = || -> hdf5::Result<()> {
        for name in member_names(&file, layout::IMU_GROUP) {
            let group = layout::imu_path(&name);
            tables.push(repair_and_replay::<ImuBlock, ImuRecord>(
                &file, &group, records,
            )?);
        }
        for name in member_names(&file, layout::GNSS_GROUP) {
            let group = layout::gnss_path(&name);
            add_optional_columns::<GnssBlock>(&file, &group)?;
            tables.push(repair_and_replay::<GnssBlock, GnssRecord>(
                &file, &group, records,
            )?);
        }
        if file.group(layout::TRUTH_NAV_GROUP).is_ok() {
            tables.push(repair_and_replay::<TruthNavBlock, TruthNavRecord>(
                &file,
                layout::TRUTH_NAV_GROUP,
                records,
            )?);
        }
        for name in member_names(&file, layout::TRUTH_IMU_GROUP) {
            let group = layout::truth_imu_path(&name);
            tables.push(repair_and_replay::<TruthImuBlock, TruthImuRecord>(
                &file, &group, records,
            )?);
        }
        for name in member_names(&file, layout::RAW_GROUP) {
            let group = layout::raw_path(&name);
            tables.push(repair_and_replay_raw(&file, &group, records)?);
        }
        if file.group(layout::EVENTS_GROUP).is_ok() {
            tables.push(repair_and_replay::<EventBlock, EventRow>(
                &file,
                layout::EVENTS_GROUP,
                records,
            )?);
        }
        file.flush()
    };
    go().map_err(|e| StoreError::Corrupt {
        path: path.to_path_buf(),
        msg: format!(
            "repairing datasets: {}",
            e.to_string().lines().next().unwrap_or("")
        ),
    })?;
    file.close()
        .map_err(|e| StoreError::h5(path, "closing", e))?;
    std::fs::File::open(path)
        .and_then(|f| f.sync_all())
        .map_err(|e| StoreError::io(path, e))?;
    Ok(tables)
}

/// Makes the partial chunk file at `path` readable in place, without renaming it: clears
/// its superblock flags, repairs its tables and appends the rows of its write-ahead journal
/// (the files `journal`; missing ones count as empty) that the file does not hold. Running
/// it again changes nothing. [`recover`] does this to a copy of every partial file of a
/// session, then renames the copy. Returns what it did and the bytes dropped from torn journal tails.
pub fn repair_partial(
    path: &Path,
    journal: &[PathBuf],
) -> Result<(SuperblockState, Vec<TableRecovery>, u64), StoreError> {
    let contents = journal::read(journal)?;
    if contents.dropped_bytes > 0 {
        tracing::warn!(
            "{}: dropped a torn or corrupt journal tail of {} bytes",
            path.display(),
            contents.dropped_bytes
        );
    }
    let sb = clear_superblock_flags(path)?;
    let tables = repair_file(path, &contents.records)?;
    Ok((sb, tables, contents.dropped_bytes))
}

/// Recovers every `*.partial` chunk file of the session in `dir` (see the module docs).
/// Files that cannot be recovered are left as they are and reported in the error, after
/// the others have been recovered.
pub fn recover(dir: &Path) -> Result<RecoverReport, StoreError> {
    let manifest = Manifest::load(dir)?;
    let Some(lock) = try_writer_lock(dir)? else {
        // A live writer: nothing crashed, so nothing to recover; say how to finish instead.
        return Err(StoreError::io(
            dir,
            std::io::Error::new(
                std::io::ErrorKind::ResourceBusy,
                format!(
                    "still being written (a live writer is still running and holds {}); nothing to recover: the closed \
                     chunk files are readable now.\nStop the writer to close the session (systemctl \
                     stop imulogd, or kill -TERM its PID); `imulab recover` is for a writer that crashed",
                    layout::WRITER_LOCK_FILE
                ),
            ),
        ));
    };
    let mut partials: Vec<(u32, PathBuf)> = Vec::new();
    let mut journals: Vec<(u32, PathBuf)> = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| StoreError::io(dir, e))? {
        let entry = entry.map_err(|e| StoreError::io(dir, e))?;
        let name = entry.file_name();
        let name = name.to_str().unwrap_or("");
        if let Some((index, true)) = layout::parse_chunk_file_name(name) {
            partials.push((index, entry.path()));
        } else if let Some(index) = layout::parse_journal_file_name(name) {
            journals.push((index, entry.path()));
        }
    }
    partials.sort();
    let mut report = RecoverReport::default();
    let mut first_error = None;
    for (index, from) in partials {
        match recover_one(dir, &manifest, index, &from) {
            Ok(r) => report.files.push(r),
            // The first error is returned (and shown); the others are logged.
            Err(e) if first_error.is_some() => tracing::error!("{e}"),
            Err(e) => first_error = Some(e),
        }
    }
    // A journal whose chunk file is complete is left over from a crash between the writer's
    // rename and its removal of the journal: every row is in the file, so it goes.
    for (index, path) in journals {
        if dir.join(layout::chunk_file_name(index)).exists() {
            if let Err(e) = remove_if_present(&path) {
                first_error.get_or_insert(e);
            }
        } else if !dir.join(layout::partial_file_name(index)).exists() {
            let e = StoreError::Corrupt {
                path: path.clone(),
                msg: "journal without its chunk file; left as it is".into(),
            };
            tracing::error!("{e}");
            first_error.get_or_insert(e);
        }
    }
    drop(lock);
    let _ = std::fs::remove_file(dir.join(layout::WRITER_LOCK_FILE));
    match first_error {
        Some(e) => Err(e),
        None => Ok(report),
    }
}

/// Room kept free beyond the recovered file's own size: HDF5 metadata and the file system.
const SPACE_MARGIN_BYTES: u64 = 1 << 20;

/// Recovers partial chunk file number `index` at `from`, never touching it or its journal
/// until the recovered file is complete: a copy is repaired (or, when the HDF5 file is
/// beyond repair, a new file is rebuilt from the journal) under a temporary name, made
/// durable and renamed to the final name; only then do the partial file and the journal go.
/// On any failure the temporary file is removed and the session is as it was.
fn recover_one(
    dir: &Path,
    manifest: &Manifest,
    index: u32,
    from: &Path,
) -> Result<FileRecovery, StoreError> {
    let to = dir.join(layout::chunk_file_name(index));
    if to.exists() {
        return Err(StoreError::Corrupt {
            path: from.to_path_buf(),
            msg: format!(
                "{} already exists; not overwriting completed data",
                to.display()
            ),
        });
    }
    let journal = journal::journal_paths(dir, index);
    let journal_size: u64 = journal
        .iter()
        .filter_map(|j| std::fs::metadata(j).ok())
        .map(|m| m.len())
        .sum();
    let partial_size = std::fs::metadata(from)
        .map_err(|e| StoreError::io(from, e))?
        .len();
    let recorded_size = recorded_file_size(from).unwrap_or(0);
    let need = partial_size.max(recorded_size) + journal_size + SPACE_MARGIN_BYTES;
    check_free_space(dir, need, from)?;

    let work = dir.join(layout::recovering_file_name(index));
    let result = repair_copy(from, &work, manifest, &journal).or_else(|repair_error| {
        let _ = std::fs::remove_file(&work);
        // Out of room meanwhile (another writer on the disk): say so, do not rebuild.
        check_free_space(dir, need, from)?;
        let why = repair_error.to_string();
        tracing::warn!("{why}; rebuilding the chunk from its journal");
        rebuild(&work, index, manifest, &journal).map(|(tables, dropped)| {
            let sb = SuperblockState {
                offset: 0,
                version: 0,
                flags: 0,
            };
            (sb, tables, dropped, Some(why))
        })
    });
    let (sb, tables, journal_bytes_dropped, rebuilt) = match result {
        Ok(r) => r,
        Err(e) => {
            let _ = std::fs::remove_file(&work);
            return Err(no_space_if_full(dir, need, from, e));
        }
    };
    let finish = || -> Result<(), StoreError> {
        std::fs::File::open(&work)
            .and_then(|f| f.sync_all())
            .map_err(|e| StoreError::io(&work, e))?;
        std::fs::rename(&work, &to).map_err(|e| StoreError::io(&to, e))?;
        fsync_dir(dir)
    };
    if let Err(e) = finish() {
        let _ = std::fs::remove_file(&work);
        return Err(no_space_if_full(dir, need, from, e));
    }
    // Only now, with the rows durable under the final name, may the partial file and the
    // journal go.
    remove_if_present(from)?;
    for j in &journal {
        remove_if_present(j)?;
    }
    fsync_dir(dir)?;
    Ok(FileRecovery {
        from: from.to_path_buf(),
        to,
        superblock_flags_cleared: sb.flags != 0,
        tables,
        journal_bytes_dropped,
        rebuilt,
    })
}

/// What recovering one file gives: the superblock found, the tables, the torn journal
/// bytes dropped and, when rebuilt, why.
type Recovered = (SuperblockState, Vec<TableRecovery>, u64, Option<String>);

/// Copies `from` to `work` and repairs the copy ([`repair_partial`]). A copy shorter than
/// the size its superblock records (a truncated file) is first padded with zeros to it, so
/// that HDF5 opens it and the rows whose blocks are still there can be read; the missing
/// blocks fail their checksums and end their tables, the journal supplies the rows after.
fn repair_copy(
    from: &Path,
    work: &Path,
    manifest: &Manifest,
    journal: &[PathBuf],
) -> Result<Recovered, StoreError> {
    std::fs::copy(from, work).map_err(|e| StoreError::io(work, e))?;
    if let Some(recorded) = recorded_file_size(work) {
        let f = std::fs::OpenOptions::new()
            .write(true)
            .open(work)
            .map_err(|e| StoreError::io(work, e))?;
        let size = f.metadata().map_err(|e| StoreError::io(work, e))?.len();
        if size < recorded {
            f.set_len(recorded).map_err(|e| StoreError::io(work, e))?;
        }
    }
    let (sb, tables, dropped) = repair_partial(work, journal).map_err(|e| named(e, from))?;
    check_layout(work, manifest).map_err(|msg| StoreError::Corrupt {
        path: from.to_path_buf(),
        msg,
    })?;
    Ok((sb, tables, dropped, None))
}

/// Checks that the repaired file at `path` is a chunk file of this build with a table for
/// every device of `manifest` (damage can leave HDF5 able to open a file whose groups or
/// attributes are gone, and the rows of its journal would then have nowhere to go).
fn check_layout(path: &Path, manifest: &Manifest) -> Result<(), String> {
    let file = hdf5::File::open(path).map_err(|e| e.to_string())?;
    let version = file
        .attr(layout::ATTR_SCHEMA_VERSION)
        .and_then(|a| a.read_scalar::<u32>())
        .map_err(|_| "no schema_version attribute left".to_string())?;
    if version != super::SCHEMA_VERSION {
        return Err(format!("schema version {version} after repair"));
    }
    for d in &manifest.devices {
        let group = match d.kind {
            super::DeviceKind::Imu => layout::imu_path(&d.name),
            super::DeviceKind::Gnss => layout::gnss_path(&d.name),
        };
        if file.group(&group).is_err() {
            return Err(format!("table /{group} is gone"));
        }
    }
    if file.group(layout::EVENTS_GROUP).is_err() {
        return Err(format!("table /{} is gone", layout::EVENTS_GROUP));
    }
    Ok(())
}

/// Rebuilds chunk `index` into a new file `work` from the rows of its journal alone.
fn rebuild(
    work: &Path,
    index: u32,
    manifest: &Manifest,
    journal: &[PathBuf],
) -> Result<(Vec<TableRecovery>, u64), StoreError> {
    let contents = journal::read(journal)?;
    let raw = contents.records.iter().any(|r| r.id.starts_with("raw/"));
    super::chunkfile::create_empty_chunk(work, index, manifest, raw)?;
    let tables = repair_file(work, &contents.records)?;
    Ok((tables, contents.dropped_bytes))
}

/// An error about the temporary copy, said of the file the user has (`from`).
fn named(e: StoreError, from: &Path) -> StoreError {
    match e {
        StoreError::Corrupt { msg, .. } => StoreError::Corrupt {
            path: from.to_path_buf(),
            msg,
        },
        other => other,
    }
}

/// The file size a version 2/3 superblock at the start of `path` records (base address +
/// end-of-file address), or `None` when there is no such superblock.
fn recorded_file_size(path: &Path) -> Option<u64> {
    let mut head = [0u8; 12 + 4 * 8];
    std::fs::File::open(path).ok()?.read_exact(&mut head).ok()?;
    if head[..8] != HDF5_SIGNATURE || head[8] < 2 || head[9] != 8 {
        return None;
    }
    let word = |at: usize| u64::from_le_bytes(head[at..at + 8].try_into().unwrap_or_default());
    Some(word(12).saturating_add(word(12 + 16)))
}

/// Free bytes for an unprivileged writer on the file system of `dir`.
fn free_bytes(dir: &Path) -> Option<u64> {
    let st = nix::sys::statvfs::statvfs(dir).ok()?;
    Some((st.blocks_available() as u64).saturating_mul(st.fragment_size() as u64))
}

/// The mount point of the file system holding `dir` (the last ancestor on the same device).
fn mount_point(dir: &Path) -> PathBuf {
    use std::os::unix::fs::MetadataExt;
    let dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf());
    let Ok(dev) = std::fs::metadata(&dir).map(|m| m.dev()) else {
        return dir;
    };
    let mut top = dir.clone();
    for a in dir.ancestors().skip(1) {
        match std::fs::metadata(a) {
            Ok(m) if m.dev() == dev => top = a.to_path_buf(),
            _ => break,
        }
    }
    top
}

fn mib(bytes: u64) -> String {
    if bytes < 1 << 20 {
        format!("{} KiB", bytes.div_ceil(1 << 10))
    } else {
        format!("{:.1} MiB", bytes as f64 / (1u64 << 20) as f64)
    }
}

/// Refuses to start when the file system of `dir` has less than `need` bytes free, saying
/// how much is missing.
fn check_free_space(dir: &Path, need: u64, from: &Path) -> Result<(), StoreError> {
    match free_bytes(dir) {
        Some(have) if have < need => Err(no_space(dir, need, have, from)),
        _ => Ok(()),
    }
}

fn no_space(dir: &Path, need: u64, have: u64, from: &Path) -> StoreError {
    StoreError::io(
        from,
        std::io::Error::new(
            std::io::ErrorKind::StorageFull,
            format!(
                "no space left on {}: need {} to recover it, have {} (free {} and run \
                 `imulab recover {}` again; the file and its journal are untouched)",
                mount_point(dir).display(),
                mib(need),
                mib(have),
                mib(need - have),
                dir.display()
            ),
        ),
    )
}

/// `e`, or the no-space error when the disk has filled up meanwhile (HDF5 then only says
/// "file write failed").
fn no_space_if_full(dir: &Path, need: u64, from: &Path, e: StoreError) -> StoreError {
    match free_bytes(dir) {
        Some(have) if have < need => no_space(dir, need, have, from),
        _ => e,
    }
}

fn remove_if_present(path: &Path) -> Result<(), StoreError> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(StoreError::io(path, e)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup3_matches_the_reference_vectors() {
        // From Bob Jenkins' lookup3.c driver5().
        assert_eq!(lookup3(b"", 0), 0xdeadbeef);
        assert_eq!(lookup3(b"", 0xdeadbeef), 0xbd5b7dde);
        assert_eq!(lookup3(b"Four score and seven years ago", 0), 0x17770551);
        assert_eq!(lookup3(b"Four score and seven years ago", 1), 0xcd628161);
    }
}
