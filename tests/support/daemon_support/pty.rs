//! Pseudo-terminals standing in for serial devices: the test writes the device's bytes on
//! the master side, the daemon opens the slave path (or a stable symlink to it, as udev
//! gives) through its real serial transport.
#![allow(dead_code)]

use std::io::{Read, Write};
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};

use nix::sys::termios;

/// A pty pair in raw mode. The slave fd is kept so the pty lives until the pair is dropped.
pub struct Pty {
    pub master: std::fs::File,
    _slave: OwnedFd,
    pub slave_path: PathBuf,
}

impl Pty {
    pub fn open() -> Pty {
        let pty = nix::pty::openpty(None, None).expect("openpty");
        let mut attrs = termios::tcgetattr(&pty.slave).expect("tcgetattr");
        termios::cfmakeraw(&mut attrs);
        termios::tcsetattr(&pty.slave, termios::SetArg::TCSANOW, &attrs).expect("tcsetattr");
        let slave_path = nix::unistd::ttyname(&pty.slave).expect("ttyname");
        Pty {
            master: std::fs::File::from(pty.master),
            _slave: pty.slave,
            slave_path,
        }
    }

    pub fn write(&mut self, bytes: &[u8]) {
        self.master
            .write_all(bytes)
            .expect("write to the pty master");
    }

    /// Plays an slcan adapter's side of the open handshake: answers `\r` (OK) to each of
    /// the `commands` command lines the daemon sends, and returns what it sent.
    pub fn answer_slcan_commands(&mut self, commands: usize) -> String {
        let mut seen = Vec::new();
        let mut answered = 0;
        let mut byte = [0u8; 64];
        while answered < commands {
            let n = self
                .master
                .read(&mut byte)
                .expect("read from the pty master");
            assert!(n > 0, "pty closed during the slcan handshake");
            for &b in &byte[..n] {
                seen.push(b);
                if b == b'\r' {
                    self.master.write_all(b"\r").expect("slcan OK");
                    answered += 1;
                }
            }
        }
        String::from_utf8_lossy(&seen).into_owned()
    }
}

/// Points `link` at `target` atomically (as udev re-creates a by-id link on replug).
pub fn point_link(link: &Path, target: &Path) {
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp).unwrap();
    std::fs::rename(&tmp, link).unwrap();
}
