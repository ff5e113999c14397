//! systemd notification: READY=1 only once every device has opened or failed its first
//! attempt, WATCHDOG=1 fed while the writer thread turns over (and not while it is wedged),
//! also when every device is silent (the device thread answers the writer's nudge),
//! STOPPING=1 at shutdown. The test binds the notification socket itself and points
//! NOTIFY_SOCKET/WATCHDOG_USEC at it (own test binary: the environment is process-wide).

use imulab_test_support::daemon_support as common;

use std::os::unix::net::UnixDatagram;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{encode_imu, LineDecoder, QueueConnector};
use imulab::daemon::config::parse;
use imulab::daemon::sink::MemorySink;
use imulab::daemon::source::{Connector, DecoderFactory, FrameDecoder};
use imulab::daemon::{run, DaemonParts};
use tokio::io::AsyncWriteExt;

type Log = Arc<Mutex<Vec<(Instant, String)>>>;

/// Receives notifications on a thread, stamping each with its arrival time.
fn listen(socket: UnixDatagram) -> Log {
    let log: Log = Arc::default();
    let into = log.clone();
    socket
        .set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        loop {
            if let Ok(n) = socket.recv(&mut buf) {
                let text = String::from_utf8_lossy(&buf[..n]).trim().to_string();
                into.lock().unwrap().push((Instant::now(), text));
            }
        }
    });
    log
}

/// Messages that arrived after `t0`, with their time since `t0`.
fn since(log: &Log, t0: Instant) -> Vec<(Duration, String)> {
    log.lock()
        .unwrap()
        .iter()
        .filter(|(t, _)| *t >= t0)
        .map(|(t, m)| (*t - t0, m.clone()))
        .collect()
}

fn parts(
    config: &imulab::daemon::CheckedConfig,
    sink: MemorySink,
    connectors: Vec<QueueConnector>,
) -> DaemonParts {
    DaemonParts {
        sink: Box::new(sink),
        session_dir: config.session.output_dir.join("s"),
        decoders: connectors
            .iter()
            .map(|_| -> DecoderFactory {
                Box::new(|| Box::new(LineDecoder::default()) as Box<dyn FrameDecoder>)
            })
            .collect(),
        connectors: connectors
            .into_iter()
            .map(|c| Box::new(c) as Box<dyn Connector>)
            .collect(),
        free_space: Box::new(|| Ok(u64::MAX / 2)),
        status_path: config.status_path(),
    }
}

#[test]
fn ready_after_every_device_settled_watchdog_fed_only_while_both_threads_turn() {
    let dir = tempfile::tempdir().unwrap();
    let socket_path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    let log = listen(socket);
    // Set before any thread of the daemon exists.
    std::env::set_var("NOTIFY_SOCKET", &socket_path);
    std::env::set_var("WATCHDOG_USEC", "400000");
    std::env::remove_var("WATCHDOG_PID");

    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 50\n\
         [[device]]\nname = \"imu\"\nprotocol = \"csv\"\nrate_hz = 100\nserial = {{ port = \"/dev/a\" }}\n\
         [[device]]\nname = \"late\"\nprotocol = \"csv\"\nrate_hz = 100\nretry_initial_ms = 300\nretry_max_ms = 300\nserial = {{ port = \"/dev/b\" }}\n",
        dir.path().display()
    );
    let config = parse(&text, "test").unwrap();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();

    // Phase 1: a healthy run. The second device is absent; READY must still come (after its
    // first failed attempt), and the watchdog is fed every 200 ms.
    let imu = QueueConnector::default();
    let late = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::new();
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let t0 = Instant::now();
    let daemon_config = config.clone();
    let daemon_parts = parts(&config, sink, vec![imu, late]);
    let daemon = runtime.spawn(async move { run(&daemon_config, daemon_parts, stop_rx).await });
    runtime.block_on(async {
        for seq in 0..100 {
            port.write_all(&encode_imu(seq, [0.0; 3], [0.0; 3]))
                .await
                .unwrap();
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    });
    let _ = stop.send(true);
    let outcome = runtime.block_on(daemon).unwrap();
    assert_eq!(outcome.exit_code(), 0);
    std::thread::sleep(Duration::from_millis(100));
    let messages = since(&log, t0);
    let ready: Vec<_> = messages
        .iter()
        .filter(|(_, m)| m.contains("READY=1"))
        .collect();
    assert_eq!(ready.len(), 1, "{messages:?}");
    let watchdogs = messages.iter().filter(|(_, m)| m == "WATCHDOG=1").count();
    assert!(watchdogs >= 3, "fed every 200 ms for ~1 s: {messages:?}");
    assert!(
        messages
            .last()
            .is_some_and(|(_, m)| m.contains("STOPPING=1")),
        "{messages:?}"
    );

    // Phase 2: a wedged writer (each append takes 1.5 s): no WATCHDOG=1 while it hangs.
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::slow(Duration::from_millis(1500));
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon_config = config.clone();
    let daemon_parts = parts(&config, sink, vec![imu, QueueConnector::default()]);
    let daemon = runtime.spawn(async move { run(&daemon_config, daemon_parts, stop_rx).await });
    let t1 = Instant::now();
    runtime.block_on(async {
        tokio::time::sleep(Duration::from_millis(300)).await;
        port.write_all(&encode_imu(0, [0.0; 3], [0.0; 3]))
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(1300)).await;
    });
    let wedged = since(&log, t1);
    let _ = stop.send(true);
    let _ = runtime.block_on(daemon);
    // The writer took the row at ~0.3 s and is stuck until ~1.8 s: after the 200 ms grace
    // (half the watchdog interval), nothing may feed the watchdog.
    let fed_while_wedged: Vec<_> = wedged
        .iter()
        .filter(|(t, m)| m == "WATCHDOG=1" && *t > Duration::from_millis(650))
        .collect();
    assert!(fed_while_wedged.is_empty(), "{wedged:?}");
    assert!(
        wedged
            .iter()
            .any(|(t, m)| m == "WATCHDOG=1" && *t < Duration::from_millis(300)),
        "fed before the writer wedged: {wedged:?}"
    );

    // Phase 3: every device silent (one open, one absent): no hand-overs show the device
    // thread alive, so the writer nudges it and its answer feeds the watchdog, every 200 ms.
    let quiet = QueueConnector::default();
    let _port = quiet.plug();
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon_config = config.clone();
    let daemon_parts = parts(
        &config,
        MemorySink::new(),
        vec![quiet, QueueConnector::default()],
    );
    let t2 = Instant::now();
    let daemon = runtime.spawn(async move { run(&daemon_config, daemon_parts, stop_rx).await });
    std::thread::sleep(Duration::from_millis(1000));
    let _ = stop.send(true);
    assert_eq!(runtime.block_on(daemon).unwrap().exit_code(), 0);
    let silent = since(&log, t2);
    let fed: Vec<Duration> = silent
        .iter()
        .filter(|(_, m)| m == "WATCHDOG=1")
        .map(|(t, _)| *t)
        .collect();
    assert!(
        fed.len() >= 3,
        "fed while every device is silent: {silent:?}"
    );
    assert!(
        fed.windows(2)
            .all(|w| w[1] - w[0] < Duration::from_millis(300)),
        "fed about every 200 ms: {silent:?}"
    );
}
