//! Watches a device path (inotify, through `nix`) so that a device that comes back is
//! reopened at once instead of at the end of its back-off delay.
//!
//! The watch is on the directory that holds the path (`/dev`, `/dev/serial/by-id`, the
//! directory of a udev symlink) for entries created, moved in (udev and `ln -sf` replace a
//! link by a rename) or changed in their attributes (udev sets a node's group and mode after
//! creating it, and the first open may fail before that). When that directory does not exist
//! (`/dev/serial/by-id` goes away with the last USB serial adapter), the nearest existing
//! ancestor is watched for the missing directory, and the watch moves down as the
//! directories appear. A bare pty path (`/dev/pts/N`) is watched the same way: devpts
//! reports a new pty's entry to inotify, so when the kernel hands the number to a new pty it
//! is reopened at once (`tests/daemon/pty.rs`). Events are only a reason to try again: the
//! back-off still bounds the wait, so a file system without inotify events loses nothing but
//! the speed-up.

use std::ffi::OsString;
use std::io;
use std::os::fd::{AsFd, AsRawFd, RawFd};
use std::path::{Path, PathBuf};

use nix::errno::Errno;
use nix::sys::inotify::{AddWatchFlags, InitFlags, Inotify};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

/// [`Inotify`] as a raw fd, for tokio's reactor.
struct Fd(Inotify);

impl AsRawFd for Fd {
    fn as_raw_fd(&self) -> RawFd {
        self.0.as_fd().as_raw_fd()
    }
}

/// A watch for `path` appearing (see the module doc).
pub struct PathWatch {
    path: PathBuf,
    fd: AsyncFd<Fd>,
    /// The directory watched and the entry in it that leads to `path`.
    dir: PathBuf,
    name: OsString,
}

/// The nearest existing ancestor directory of `path` and the name of its entry on the way
/// to `path`.
fn watch_point(path: &Path) -> Option<(PathBuf, OsString)> {
    let mut child = path;
    while let Some(parent) = child.parent() {
        if parent.as_os_str().is_empty() {
            return None;
        }
        if parent.is_dir() {
            return Some((parent.to_path_buf(), child.file_name()?.to_os_string()));
        }
        child = parent;
    }
    None
}

impl PathWatch {
    /// Watches for `path` (absolute). Must be called inside a tokio runtime.
    pub fn new(path: &Path) -> io::Result<Self> {
        let (dir, name) = watch_point(path).ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::NotFound,
                format!("no existing directory above {}", path.display()),
            )
        })?;
        let inotify = Inotify::init(InitFlags::IN_NONBLOCK | InitFlags::IN_CLOEXEC)?;
        inotify.add_watch(
            &dir,
            AddWatchFlags::IN_CREATE | AddWatchFlags::IN_MOVED_TO | AddWatchFlags::IN_ATTRIB,
        )?;
        // SAFETY: the inotify fd is owned by the `Fd` that the AsyncFd owns, stays open until
        // the AsyncFd is dropped, and `as_raw_fd` always returns that same fd.
        let fd = unsafe { AsyncFd::register_with_interest(Fd(inotify), Interest::READABLE) }
            .map_err(|e| e.into_parts().1)?;
        Ok(PathWatch {
            path: path.to_path_buf(),
            fd,
            dir,
            name,
        })
    }

    /// True when some queued event is about the entry leading to the path. Reads every
    /// queued event (none wait for later).
    fn take_events(&self) -> io::Result<bool> {
        let mut hit = false;
        loop {
            match self.fd.get_ref().0.read_events() {
                Ok(events) => {
                    hit |= events
                        .iter()
                        .any(|e| e.name.as_deref() == Some(self.name.as_os_str()));
                }
                Err(Errno::EAGAIN) => return Ok(hit),
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Forgets what happened so far: call before an open attempt, so that [`Self::changed`]
    /// then reports only what happened since.
    pub fn clear(&mut self) {
        let _ = self.take_events();
        self.descend();
    }

    /// Moves the watch down when a directory on the way to the path has appeared.
    fn descend(&mut self) {
        if self.dir.as_path() == self.path.parent().unwrap_or(Path::new("")) {
            return;
        }
        if let Some((dir, _)) = watch_point(&self.path) {
            if dir != self.dir {
                if let Ok(closer) = PathWatch::new(&self.path) {
                    *self = closer;
                }
            }
        }
    }

    /// Resolves when the entry leading to the path is created, moved in or changed; an
    /// inotify failure never resolves (the back-off still runs beside it).
    pub async fn changed(&mut self) {
        loop {
            let Ok(mut ready) = self.fd.readable().await else {
                return std::future::pending().await;
            };
            ready.clear_ready();
            match self.take_events() {
                Ok(true) => {
                    self.descend();
                    return;
                }
                Ok(false) => {}
                Err(e) => {
                    tracing::debug!("watching {}: {e}", self.path.display());
                    return std::future::pending().await;
                }
            }
        }
    }

    /// What is watched, for logs.
    pub fn describe(&self) -> String {
        format!("{} in {}", self.name.to_string_lossy(), self.dir.display())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test]
    async fn a_link_moved_into_place_and_a_directory_made_on_the_way_are_seen() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("by-id/imu-1");
        let mut watch = PathWatch::new(&path).unwrap();
        assert!(watch.describe().contains("by-id"));
        watch.clear();
        // Nothing happened: no wake-up.
        assert!(
            tokio::time::timeout(Duration::from_millis(50), watch.changed())
                .await
                .is_err()
        );
        std::fs::create_dir(dir.path().join("by-id")).unwrap();
        tokio::time::timeout(Duration::from_secs(2), watch.changed())
            .await
            .expect("the directory on the way was seen");
        // Now the directory itself is watched: an unrelated entry does not wake it.
        watch.clear();
        std::fs::write(dir.path().join("by-id/other"), b"").unwrap();
        assert!(
            tokio::time::timeout(Duration::from_millis(50), watch.changed())
                .await
                .is_err()
        );
        let tmp = dir.path().join("by-id/imu-1.new");
        std::os::unix::fs::symlink("/dev/null", &tmp).unwrap();
        std::fs::rename(&tmp, &path).unwrap();
        tokio::time::timeout(Duration::from_secs(2), watch.changed())
            .await
            .expect("the link moved into place was seen");
    }
}
