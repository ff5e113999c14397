//! Free space on the session's filesystem (statvfs), for the disk-reserve check.

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

#[cfg(test)]
mod tests {
    #[test]
    fn free_space_of_the_temp_dir_is_readable_and_a_missing_path_is_an_error() {
        let dir = std::env::temp_dir();
        assert!(super::free_bytes(&dir).is_ok());
        assert!(super::free_bytes(&dir.join("no/such/dir/imulogd")).is_err());
    }
}
