//! A real serial path: the daemon reads a pty through its serial connector (by a stable
//! symlink, as udev gives), the pty is closed mid-run and a new one appears under the same
//! name: a disconnect event, a reconnect event, and the data resume in the same session.

use std::io::Write;
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::common::{encode_imu, LineDecoder};
use imulab::daemon::config::parse;
use imulab::daemon::sink::MemorySink;
use imulab::daemon::source::{connector_for, DecoderFactory, FrameDecoder};
use imulab::daemon::{run, DaemonParts};
use imulab::store::EventKind;
use nix::sys::termios;

/// A pty pair in raw mode: the master (the "device" side, written by the test) and the slave
/// path the daemon opens. The slave fd is kept so the pty lives until the pair is dropped.
struct Pty {
    master: std::fs::File,
    _slave: OwnedFd,
    slave_path: PathBuf,
}

fn open_pty() -> Pty {
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

fn print_pty_paths(old: &Path, new: &Path) {
    println!(
        "pty before the unplug: {}, after: {}",
        old.display(),
        new.display()
    );
}

fn point_link(link: &Path, target: &Path) {
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp).unwrap();
    std::fs::rename(&tmp, link).unwrap();
}

fn send(pty: &mut Pty, range: std::ops::Range<u64>) {
    for seq in range {
        let frame = encode_imu(seq, [seq as f64, 0.5, -0.5], [0.0, 0.0, 9.81]);
        pty.master.write_all(&frame).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pty_closed_and_reopened_mid_run_resumes_in_the_same_session() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("imu-test");
    let mut first = open_pty();
    point_link(&link, &first.slave_path);
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 50\n\
         [[device]]\nname = \"imu\"\nprotocol = \"csv\"\nrate_hz = 200\nretry_initial_ms = 20\nretry_max_ms = 100\n\
         serial = {{ port = \"{}\", baud = 115200 }}\n",
        dir.path().display(),
        link.display()
    );
    let config = parse(&text, "test").unwrap_or_else(|e| panic!("{e}"));
    let connector = connector_for(&config.devices[0]).expect("serial connector");
    let decoders: DecoderFactory =
        Box::new(|| Box::new(LineDecoder::default()) as Box<dyn FrameDecoder>);
    let sink = MemorySink::new();
    let parts = DaemonParts {
        sink: Box::new(sink.clone()),
        session_dir: dir.path().join("session"),
        connectors: vec![connector],
        decoders: vec![decoders],
        free_space: Box::new(|| Ok(u64::MAX / 2)),
        status_path: config.status_path(),
    };
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });

    // Let the daemon open the port, then stream, then pull the plug.
    tokio::time::sleep(Duration::from_millis(200)).await;
    let first = tokio::task::spawn_blocking(move || {
        send(&mut first, 0..50);
        std::thread::sleep(Duration::from_millis(100));
        first
    })
    .await
    .unwrap();
    let old_path = first.slave_path.clone();
    drop(first);
    tokio::time::sleep(Duration::from_millis(300)).await;

    let mut second = open_pty();
    // The kernel may hand out the same pts number again once every holder closed it.
    print_pty_paths(&old_path, &second.slave_path);
    point_link(&link, &second.slave_path);
    tokio::time::sleep(Duration::from_millis(400)).await;
    let second = tokio::task::spawn_blocking(move || {
        send(&mut second, 50..100);
        std::thread::sleep(Duration::from_millis(100));
        second
    })
    .await
    .unwrap();
    let _ = stop.send(true);
    let outcome = daemon.await.unwrap();
    drop(second);
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");

    let store = sink.snapshot();
    let seqs: Vec<u64> = store.imu["imu"].iter().map(|r| r.t_sensor as u64).collect();
    assert_eq!(
        seqs,
        (0..100).collect::<Vec<_>>(),
        "events: {:?}",
        store.events
    );
    let kinds: Vec<EventKind> = store
        .events
        .iter()
        .filter(|e| e.device == "imu")
        .map(|e| e.kind)
        .collect();
    assert_eq!(
        kinds,
        [
            EventKind::Connect,
            EventKind::Disconnect,
            EventKind::Reconnect
        ],
        "{:?}",
        store.events
    );
    assert!(store.imu["imu"]
        .windows(2)
        .all(|w| w[0].t_mono_ns <= w[1].t_mono_ns));
}
