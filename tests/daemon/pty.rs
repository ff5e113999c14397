//! A real serial path with a real protocol: the daemon reads a WitMotion IMU on a pty
//! through the drivers' serial transport (by a stable symlink, as udev gives), the pty is
//! closed mid-run and a new one appears under the same name: a disconnect event, a reconnect
//! event, a gap event, and the data resume in the same session.

use std::path::Path;
use std::time::Duration;

use crate::common::encode::wit_sample;
use crate::common::pty::{point_link, Pty};
use crate::serial::{config, start};
use imulab::store::EventKind;

fn print_pty_paths(old: &Path, new: &Path) {
    println!(
        "pty before the unplug: {}, after: {}",
        old.display(),
        new.display()
    );
}

fn send(pty: &mut Pty, range: std::ops::Range<u64>) {
    for seq in range {
        pty.write(&wit_sample(seq));
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pty_closed_and_reopened_mid_run_resumes_in_the_same_session() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("imu-test");
    let mut first = Pty::open();
    point_link(&link, &first.slave_path);
    let devices = format!(
        "[[device]]\nname = \"imu\"\nprotocol = \"wit\"\nrate_hz = 200\nretry_initial_ms = 20\nretry_max_ms = 100\n\
         serial = {{ port = \"{}\", baud = 115200 }}\n",
        link.display()
    );
    let daemon = start(config(dir.path(), &devices));

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

    let mut second = Pty::open();
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
    let store = daemon.stop().await;
    drop(second);

    // Sensor time is the time of day in the time packet: seq × 10 ms.
    let seqs: Vec<u64> = store.imu["imu"]
        .iter()
        .map(|r| (r.t_sensor * 100.0).round() as u64)
        .collect();
    assert_eq!(
        seqs,
        (0..100).collect::<Vec<_>>(),
        "events: {:?}",
        store.events
    );
    let kinds: Vec<EventKind> = store
        .events
        .iter()
        .filter(|e| e.device == "imu" && e.kind != EventKind::Gap)
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
    assert!(
        store
            .events
            .iter()
            .any(|e| e.device == "imu" && e.kind == EventKind::Gap),
        "the time without data is a gap event: {:?}",
        store.events
    );
    assert!(store.imu["imu"]
        .windows(2)
        .all(|w| w[0].t_mono_ns <= w[1].t_mono_ns));
}
