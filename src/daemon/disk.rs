//! Free space on the session's filesystem (statvfs), for the disk-reserve check, and
//! telling a full disk (ENOSPC) apart from other write failures.

use std::io;
use std::path::Path;

/// Bytes an unprivileged writer can still use on the filesystem holding `path`.
// fsblkcnt_t and c_ulong are u64 here but u32 on 32-bit targets.
#[allow(clippy::useless_conversion)]
pub fn free_bytes(path: &Path) -> io::Result<u64> {
    let stats = nix::sys::statvfs::statvfs(path).map_err(io::Error::from)?;
    Ok(u64::from(stats.blocks_available()).saturating_mul(u64::from(stats.fragment_size())))
}

/// Free bytes on the filesystem `path` will be created on: that of its nearest existing
/// ancestor (the session directory does not exist before the session starts).
pub fn free_bytes_for_new(path: &Path) -> io::Result<u64> {
    let existing = path
        .ancestors()
        .find(|p| !p.as_os_str().is_empty() && p.exists())
        .unwrap_or(Path::new("."));
    free_bytes(existing)
}

/// True when `error` (anywhere in its chain) says the file system is full: an `ENOSPC` I/O
/// error, or an HDF5 error whose text carries it (HDF5 reports the C library's errno as text).
pub fn is_disk_full(error: &anyhow::Error) -> bool {
    error.chain().any(|cause| {
        if let Some(io) = cause.downcast_ref::<io::Error>() {
            if io.raw_os_error() == Some(libc::ENOSPC) || io.kind() == io::ErrorKind::StorageFull {
                return true;
            }
        }
        let text = cause.to_string();
        text.contains("No space left on device") || text.contains("errno = 28,")
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn enospc_is_a_full_disk_and_other_errors_are_not() {
        let full = anyhow::Error::new(std::io::Error::from_raw_os_error(libc::ENOSPC))
            .context("writing the journal");
        assert!(super::is_disk_full(&full));
        let hdf5_text = anyhow::anyhow!(
            "H5Fflush(): file write failed: time = Thu Dec  3, filename = 'x.h5', errno = 28, error message = 'No space left on device'"
        );
        assert!(super::is_disk_full(&hdf5_text));
        let other = anyhow::Error::new(std::io::Error::from_raw_os_error(libc::EIO));
        assert!(!super::is_disk_full(&other));
    }

    #[test]
    fn free_space_of_the_temp_dir_is_readable_and_a_missing_path_is_an_error() {
        let dir = std::env::temp_dir();
        assert!(super::free_bytes(&dir).is_ok());
        assert!(super::free_bytes(&dir.join("no/such/dir/imulogd")).is_err());
    }
}
