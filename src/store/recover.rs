//! `recover`: turns the `*.partial` chunk file a killed writer left behind into a normal,
//! readable chunk file, keeping every row that reached the disk intact.
//!
//! A SWMR writer marks the HDF5 superblock "open for (SWMR) write"; after `kill -9` the flag
//! stays set and the library refuses to open the file for writing. `h5clear -s` clears it,
//! but hdf5-tools may not be installed where a session is recovered and the HDF5 C API has
//! no call for it, so the superblock is patched here by hand: the flags byte is zeroed and
//! the superblock checksum (Jenkins lookup3, as HDF5 computes it) is recomputed.

use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::columns::{
    Block, Column, EventBlock, GnssBlock, ImuBlock, RawIndexBlock, TruthImuBlock, TruthNavBlock,
    RAW_BYTES,
};
use super::layout;
use super::manifest::{fsync_dir, try_writer_lock, Manifest};
use super::reader::valid_prefix;
use super::StoreError;

const HDF5_SIGNATURE: [u8; 8] = [0x89, b'H', b'D', b'F', b'\r', b'\n', 0x1a, b'\n'];

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
}

/// What `recover` did to one partial file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileRecovery {
    pub from: PathBuf,
    pub to: PathBuf,
    pub superblock_flags_cleared: bool,
    pub tables: Vec<TableRecovery>,
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
    })
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

fn member_names(file: &hdf5::File, group: &str) -> Vec<String> {
    file.group(group)
        .and_then(|g| g.member_names())
        .unwrap_or_default()
}

fn repair_file(path: &Path) -> Result<Vec<TableRecovery>, StoreError> {
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
            tables.push(repair_table::<ImuBlock>(&file, &layout::imu_path(&name))?);
        }
        for name in member_names(&file, layout::GNSS_GROUP) {
            tables.push(repair_table::<GnssBlock>(&file, &layout::gnss_path(&name))?);
        }
        if file.group(layout::TRUTH_NAV_GROUP).is_ok() {
            tables.push(repair_table::<TruthNavBlock>(
                &file,
                layout::TRUTH_NAV_GROUP,
            )?);
        }
        for name in member_names(&file, layout::TRUTH_IMU_GROUP) {
            tables.push(repair_table::<TruthImuBlock>(
                &file,
                &layout::truth_imu_path(&name),
            )?);
        }
        for name in member_names(&file, layout::RAW_GROUP) {
            tables.push(repair_raw(&file, &layout::raw_path(&name))?);
        }
        if file.group(layout::EVENTS_GROUP).is_ok() {
            tables.push(repair_table::<EventBlock>(&file, layout::EVENTS_GROUP)?);
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

/// Recovers every `*.partial` chunk file of the session in `dir` (see the module docs).
/// Files that cannot be recovered are left as they are and reported in the error, after
/// the others have been recovered.
pub fn recover(dir: &Path) -> Result<RecoverReport, StoreError> {
    Manifest::load(dir)?;
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
    for entry in std::fs::read_dir(dir).map_err(|e| StoreError::io(dir, e))? {
        let entry = entry.map_err(|e| StoreError::io(dir, e))?;
        if let Some((index, true)) = entry
            .file_name()
            .to_str()
            .and_then(layout::parse_chunk_file_name)
        {
            partials.push((index, entry.path()));
        }
    }
    partials.sort();
    let mut report = RecoverReport::default();
    let mut first_error = None;
    for (index, from) in partials {
        let to = dir.join(layout::chunk_file_name(index));
        let result = (|| {
            if to.exists() {
                return Err(StoreError::Corrupt {
                    path: from.clone(),
                    msg: format!(
                        "{} already exists; not overwriting completed data",
                        to.display()
                    ),
                });
            }
            let sb = clear_superblock_flags(&from)?;
            let tables = repair_file(&from)?;
            std::fs::rename(&from, &to).map_err(|e| StoreError::io(&to, e))?;
            fsync_dir(dir)?;
            Ok(FileRecovery {
                from: from.clone(),
                to: to.clone(),
                superblock_flags_cleared: sb.flags != 0,
                tables,
            })
        })();
        match result {
            Ok(r) => report.files.push(r),
            Err(e) => {
                tracing::error!("{e}");
                first_error.get_or_insert(e);
            }
        }
    }
    drop(lock);
    let _ = std::fs::remove_file(dir.join(layout::WRITER_LOCK_FILE));
    match first_error {
        Some(e) => Err(e),
        None => Ok(report),
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
