//! Signals, sent to this test process while the daemon runs in it: SIGHUP rotates the
//! session at once, SIGTERM flushes, closes and returns exit status 0 within 2 s. (Its own
//! test binary: signal handlers are process-wide.) Also the `imulogd` binary's
//! `--check-config` on good and bad files.

use imulab_test_support::daemon_support as common;

use std::process::Command;
use std::time::{Duration, Instant};

use common::{encode_imu, LineDecoder, QueueConnector};
use imulab::daemon::config::parse;
use imulab::daemon::sink::MemorySink;
use imulab::daemon::source::{Connector, DecoderFactory, FrameDecoder};
use imulab::daemon::{run, DaemonParts};
use imulab::store::EventKind;
use nix::sys::signal::{kill, Signal};
use nix::unistd::getpid;
use tokio::io::AsyncWriteExt;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_rotates_and_sigterm_stops_cleanly_within_two_seconds() {
    let dir = tempfile::tempdir().unwrap();
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 5000\n\
         [[device]]\nname = \"imu\"\nprotocol = \"csv\"\nrate_hz = 200\nserial = {{ port = \"/dev/x\" }}\n",
        dir.path().display()
    );
    let config = parse(&text, "test").unwrap();
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let decoders: DecoderFactory =
        Box::new(|| Box::new(LineDecoder::default()) as Box<dyn FrameDecoder>);
    let sink = MemorySink::new();
    let parts = DaemonParts {
        sink: Box::new(sink.clone()),
        session_dir: dir.path().join("s"),
        connectors: vec![Box::new(imu) as Box<dyn Connector>],
        decoders: vec![decoders],
        free_space: Box::new(|| Ok(u64::MAX / 2)),
        status_path: config.status_path(),
    };
    let (_stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });
    // Keep data flowing the whole time, as a device would.
    let sender = tokio::spawn(async move {
        for seq in 0.. {
            if port
                .write_all(&encode_imu(seq, [0.0; 3], [0.0; 3]))
                .await
                .is_err()
            {
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    });
    tokio::time::sleep(Duration::from_millis(300)).await;
    kill(getpid(), Signal::SIGHUP).unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let after_hup = sink.snapshot();
    assert_eq!(after_hup.rotations, 1, "SIGHUP rotates at once");
    assert!(!after_hup.closed);
    // The store is looked at on the hand-over grid (250 ms apart with a 5 s flush
    // interval; it writes rows only once they are old enough), not on every batch.
    assert!(
        (1..=4).contains(&after_hup.flushes),
        "{} flushes in 600 ms on a 250 ms grid",
        after_hup.flushes
    );

    let t = Instant::now();
    kill(getpid(), Signal::SIGTERM).unwrap();
    let outcome = tokio::time::timeout(Duration::from_secs(2), daemon)
        .await
        .expect("stopped within 2 s")
        .unwrap();
    let took = t.elapsed();
    sender.abort();
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
    assert!(took < Duration::from_secs(2), "{took:?}");
    let store = sink.snapshot();
    assert!(store.closed, "SIGTERM closes the session");
    let kinds: Vec<EventKind> = store.events.iter().map(|e| e.kind).collect();
    assert!(kinds.contains(&EventKind::Rotation));
    assert_eq!(kinds.last(), Some(&EventKind::SessionStop));
    let rows = &store.imu["imu"];
    assert!(rows.len() > 40, "{} rows", rows.len());
    let seqs: Vec<u64> = rows.iter().map(|r| r.t_sensor as u64).collect();
    assert_eq!(
        seqs,
        (0..rows.len() as u64).collect::<Vec<_>>(),
        "nothing lost at stop"
    );
}

#[test]
fn check_config_accepts_the_example_and_rejects_a_bad_file_with_status_2() {
    let bin = env!("CARGO_BIN_EXE_imulogd");
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/systemd/imulogd.toml");
    let out = Command::new(bin)
        .args(["--check-config", example])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("configuration is valid"), "{stdout}");
    assert!(
        stdout.contains("device imu-wit: wit over serial /dev/imu-wit @ 115200, 150 Hz"),
        "{stdout}"
    );

    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "[session]\noutput_dir = \"/tmp\"\n[[device]]\nname = \"a\"\nprotocol = \"wit\"\nrate_hz = 150\nserial = { port = \"/dev/x\", baud = 115200, parity = \"none\" }\n",
    )
    .unwrap();
    let out = Command::new(bin)
        .args(["--check-config"])
        .arg(&bad)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("bad.toml"), "{stderr}");
    assert!(
        stderr.contains("device[0].serial.parity: unknown field `parity`"),
        "{stderr}"
    );

    let out = Command::new(bin)
        .args(["--config", "/no/such/file.toml"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot read the file"));
}
