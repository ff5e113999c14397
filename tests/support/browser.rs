//! Headless Chromium (Debian's `chromium`) for the tests that render a page: the path, a
//! command with the flags of a throw-away offline profile, and a run bounded in time. Where
//! the browser is absent the tests skip and say so.

use std::io::Read;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Where Debian installs Chromium (`apt-get install chromium`; `.ci/setup` does).
pub const CHROMIUM: &str = "/usr/bin/chromium";

/// Whether Chromium is absent; if so, says on stderr that `what` is skipped and why.
pub fn chromium_missing(what: &str) -> bool {
    let missing = !Path::new(CHROMIUM).exists();
    if missing {
        eprintln!("skipped {what}: {CHROMIUM} not found (install Debian's `chromium`)");
    }
    missing
}

/// Chromium, headless, with a throw-away profile in `profile` and no network of its own
/// (no background updates, sync or first-run pages); add the page and what to do with it.
pub fn chromium(profile: &Path) -> Command {
    let mut c = Command::new(CHROMIUM);
    c.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
    ])
    .arg(format!("--user-data-dir={}", profile.display()))
    .stdin(Stdio::null());
    c
}

/// Runs Chromium to its end, at most 90 s; panics with its stderr if it fails. Its output
/// is read while it runs (a page's DOM outgrows a pipe's buffer).
pub fn run(mut c: Command) -> Output {
    let mut child = c
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start chromium");
    let drain = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(mut pipe) = pipe {
                let _ = pipe.read_to_end(&mut bytes);
            }
            bytes
        })
    };
    let stdout = drain(
        child
            .stdout
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let stderr = drain(
        child
            .stderr
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let deadline = Instant::now() + Duration::from_secs(90);
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for chromium") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("chromium did not finish within 90 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let out = Output {
        status,
        stdout: stdout.join().expect("chromium's stdout"),
        stderr: stderr.join().expect("chromium's stderr"),
    };
    assert!(
        out.status.success(),
        "chromium: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}
