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

/// The tests here take turns: the bare-path test opens ptys until the kernel hands its number
/// out again, which takes numbers from under a test running beside it.
static PTY_TESTS: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

fn send(pty: &mut Pty, range: std::ops::Range<u64>) {
    for seq in range {
        pty.write(&wit_sample(seq));
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Sends the samples `range` on a blocking thread, lets the daemon read them, and hands the
/// pty back.
async fn stream(mut pty: Pty, range: std::ops::Range<u64>) -> Pty {
    tokio::task::spawn_blocking(move || {
        send(&mut pty, range);
        std::thread::sleep(Duration::from_millis(100));
        pty
    })
    .await
    .unwrap()
}

/// One WitMotion device named `imu` on the serial `port`.
fn wit_device(port: &Path, rate_hz: u32, retry_initial_ms: u32, retry_max_ms: u32) -> String {
    format!(
        "[[device]]\nname = \"imu\"\nprotocol = \"wit\"\nrate_hz = {rate_hz}\nretry_initial_ms = {retry_initial_ms}\nretry_max_ms = {retry_max_ms}\n\
         serial = {{ port = \"{}\", baud = 115200 }}\n",
        port.display()
    )
}

/// `imu`'s reconnect event and how long after `since_mono_ns` it came, in ms.
fn reconnect_after(
    store: &imulab::daemon::sink::MemoryStore,
    since_mono_ns: i64,
) -> (&imulab::store::EventRecord, f64) {
    let reopen = store
        .events
        .iter()
        .find(|e| e.device == "imu" && e.kind == EventKind::Reconnect)
        .unwrap_or_else(|| panic!("no reconnect: {:?}", store.events));
    (reopen, (reopen.t_mono_ns - since_mono_ns) as f64 * 1e-6)
}

/// The sample numbers of `imu`'s rows: sensor time is the time of day in the time packet,
/// seq × 10 ms.
fn sensor_seqs(store: &imulab::daemon::sink::MemoryStore) -> Vec<u64> {
    store.imu["imu"]
        .iter()
        .map(|r| (r.t_sensor * 100.0).round() as u64)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pty_closed_and_reopened_mid_run_resumes_in_the_same_session() {
    let _one_at_a_time = PTY_TESTS.lock().await;
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("imu-test");
    let first = Pty::open();
    point_link(&link, &first.slave_path);
    let devices = wit_device(&link, 200, 20, 100);
    let daemon = start(config(dir.path(), &devices));

    // Once the daemon has opened the port, stream, then pull the plug.
    daemon.wait_for_event("imu", EventKind::Connect, 1).await;
    let first = stream(first, 0..50).await;
    let old_path = first.slave_path.clone();
    drop(first);
    daemon.wait_for_event("imu", EventKind::Disconnect, 1).await;

    let second = Pty::open();
    // The kernel may hand out the same pts number again once every holder closed it.
    print_pty_paths(&old_path, &second.slave_path);
    point_link(&link, &second.slave_path);
    daemon.wait_for_event("imu", EventKind::Reconnect, 1).await;
    let second = stream(second, 50..100).await;
    let store = daemon.stop().await;
    drop(second);

    let seqs: Vec<u64> = sensor_seqs(&store);
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

/// A device that returns is reopened when its path appears (the path watch), not at the end
/// of its back-off delay (4 s here); the samples it buffered while the daemon had it closed
/// arrive in one burst after the reopen, which an event marks with its rows' arrival times.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_returning_device_is_reopened_at_once_and_its_buffered_burst_is_marked() {
    let _one_at_a_time = PTY_TESTS.lock().await;
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("imu-test");
    let first = Pty::open();
    point_link(&link, &first.slave_path);
    let devices = wit_device(&link, 100, 4000, 8000);
    let daemon = start(config(dir.path(), &devices));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let first = stream(first, 0..30).await;
    drop(first);
    // The daemon sees the vanish and waits (4 s of back-off) for the device.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let mut second = Pty::open();
    // 40 samples the device "buffered" while nobody had it open.
    for seq in 30..70 {
        second.write(&wit_sample(seq));
    }
    let back_mono_ns = imulab::daemon::clock::mono_ns();
    point_link(&link, &second.slave_path);
    tokio::time::sleep(Duration::from_millis(500)).await;
    let second = stream(second, 70..100).await;
    let store = daemon.stop().await;
    drop(second);

    let (reopen, late_ms) = reconnect_after(&store, back_mono_ns);
    println!(
        "reopened {late_ms:.1} ms after the path appeared: {}",
        reopen.detail
    );
    assert!(
        late_ms < 500.0,
        "reopened {late_ms:.1} ms after the path appeared"
    );
    assert!(
        reopen.detail.contains("at once when its path appeared"),
        "{}",
        reopen.detail
    );

    let seqs: Vec<u64> = sensor_seqs(&store);
    assert_eq!(seqs, (0..100).collect::<Vec<_>>());
    let bursts: Vec<_> = store
        .events
        .iter()
        .filter(|e| e.device == "imu" && e.detail.starts_with("burst after the open"))
        .collect();
    assert_eq!(bursts.len(), 1, "{:?}", store.events);
    println!("{}", bursts[0].detail);
    // The buffered samples are the burst's rows (the last may complete with the next read).
    let range = bursts[0]
        .detail
        .split("t_mono_ns ")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .unwrap();
    let (a, b) = range.split_once("..=").unwrap();
    let (a, b): (i64, i64) = (a.parse().unwrap(), b.parse().unwrap());
    let in_burst: Vec<u64> = store.imu["imu"]
        .iter()
        .filter(|r| (a..=b).contains(&r.t_mono_ns))
        .map(|r| (r.t_sensor * 100.0).round() as u64)
        .collect();
    assert!(
        in_burst.len() >= 38 && in_burst.iter().all(|s| (29..70).contains(s)),
        "burst rows {in_burst:?}"
    );
}

/// A device configured by its bare pty path (`/dev/pts/N`, no symlink): when the pty goes
/// away and the kernel hands the same number to a new one, the watch on `/dev/pts` (devpts
/// reports new entries to inotify) reopens it at once, not at the end of the 4 s back-off.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bare_pts_path_given_to_a_new_pty_is_reopened_at_once() {
    let _one_at_a_time = PTY_TESTS.lock().await;
    let dir = tempfile::tempdir().unwrap();
    let first = Pty::open();
    let path = first.slave_path.clone();
    assert!(path.starts_with("/dev/pts"), "{}", path.display());
    let devices = wit_device(&path, 100, 4000, 8000);
    let daemon = start(config(dir.path(), &devices));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let first = stream(first, 0..30).await;
    drop(first);
    // The daemon sees the vanish and closes its end, which frees the number.
    tokio::time::sleep(Duration::from_millis(300)).await;
    // The kernel gives the lowest free number: open ptys until ours comes back (others may
    // hold lower numbers for a while; keep them so each try gets a new number).
    let mut held = Vec::new();
    let mut second = None;
    for _ in 0..64 {
        let pty = Pty::open();
        if pty.slave_path == path {
            second = Some(pty);
            break;
        }
        held.push(pty);
    }
    let back_mono_ns = imulab::daemon::clock::mono_ns();
    let Some(second) = second else {
        let _ = daemon.stop().await;
        println!(
            "SKIPPED a_bare_pts_path_given_to_a_new_pty: {} was not handed out again in 64 tries (another process holds it)",
            path.display()
        );
        return;
    };
    drop(held);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let second = stream(second, 30..60).await;
    let store = daemon.stop().await;
    drop(second);

    let (reopen, late_ms) = reconnect_after(&store, back_mono_ns);
    println!(
        "{} reopened {late_ms:.1} ms after the new pty got its number: {}",
        path.display(),
        reopen.detail
    );
    assert!(
        reopen.detail.contains("at once when its path appeared"),
        "{}",
        reopen.detail
    );
    assert!(
        late_ms < 1000.0,
        "reopened {late_ms:.1} ms after the path appeared"
    );
    let seqs: Vec<u64> = sensor_seqs(&store);
    assert_eq!(seqs, (0..60).collect::<Vec<_>>(), "{:?}", store.events);
}

/// A device path that appears before it can be opened (a new pty stays locked until its
/// creator unlocks it, and unlocking raises no inotify event): the failed open right after
/// the wake-up is tried again soon, so the device is reopened once unlocked, not at the end
/// of the 4 s back-off.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_path_that_appears_locked_is_reopened_once_it_unlocks() {
    use nix::fcntl::OFlag;
    use nix::pty::{grantpt, posix_openpt, ptsname_r, unlockpt};

    let _one_at_a_time = PTY_TESTS.lock().await;
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("imu-test");
    let first = Pty::open();
    point_link(&link, &first.slave_path);
    let devices = wit_device(&link, 100, 4000, 8000);
    let daemon = start(config(dir.path(), &devices));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let first = stream(first, 0..30).await;
    drop(first);
    tokio::time::sleep(Duration::from_millis(300)).await;

    // A pty whose slave is still locked: opening it fails (EIO) until `unlockpt`.
    let master = posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY).expect("posix_openpt");
    grantpt(&master).expect("grantpt");
    let slave_path = std::path::PathBuf::from(ptsname_r(&master).expect("ptsname"));
    assert!(
        std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&slave_path)
            .is_err(),
        "a locked pty opened"
    );
    point_link(&link, &slave_path);
    // The daemon wakes on the link, fails to open the locked pty, and tries again soon.
    tokio::time::sleep(Duration::from_millis(150)).await;
    let unlocked_mono_ns = imulab::daemon::clock::mono_ns();
    unlockpt(&master).expect("unlockpt");
    tokio::time::sleep(Duration::from_millis(400)).await;
    let mut master = std::fs::File::from(std::os::fd::OwnedFd::from(master));
    let second = tokio::task::spawn_blocking(move || {
        for seq in 30..60 {
            std::io::Write::write_all(&mut master, &wit_sample(seq)).unwrap();
            std::thread::sleep(Duration::from_millis(5));
        }
        std::thread::sleep(Duration::from_millis(100));
        master
    })
    .await
    .unwrap();
    let store = daemon.stop().await;
    drop(second);

    let (reopen, late_ms) = reconnect_after(&store, unlocked_mono_ns);
    println!(
        "reopened {late_ms:.1} ms after the pty was unlocked: {}",
        reopen.detail
    );
    assert!(
        reopen.detail.contains("at once when its path appeared"),
        "{}",
        reopen.detail
    );
    assert!(late_ms < 300.0, "reopened {late_ms:.1} ms after the unlock");
    assert_eq!(sensor_seqs(&store), (0..60).collect::<Vec<_>>());
}
