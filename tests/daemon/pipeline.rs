//! The daemon pipeline end to end with in-memory devices and sink: every frame sent arrives
//! exactly once with its values, garbage becomes resync/checksum events, a vanished device is
//! reconnected with back-off and a gap, a device that never appears is an error in the
//! status, a slow writer's losses are counted and logged, and the disk reserve stops the
//! session cleanly with a non-zero exit.

use std::time::{Duration, Instant};

use crate::common::{encode_gnss, encode_imu, LineDecoder, QueueConnector};
use imulab::daemon::config::{parse, CheckedConfig};
use imulab::daemon::sink::{MemorySink, MemoryStore};
use imulab::daemon::source::{Connector, DecoderFactory, FrameDecoder};
use imulab::daemon::status::{read_status_file, DeviceState, StatusReport};
use imulab::daemon::writer::FreeSpaceFn;
use imulab::daemon::{run, DaemonParts, Outcome};
use imulab::store::EventKind;
use tokio::io::AsyncWriteExt;
use tokio::sync::watch;

fn config(dir: &std::path::Path, session_extra: &str, devices: &[(&str, f64)]) -> CheckedConfig {
    let mut text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 50\n{session_extra}\n",
        dir.display()
    );
    for (name, rate) in devices {
        let protocol = if name.starts_with("gnss") {
            "gnss"
        } else {
            "csv"
        };
        text.push_str(&format!(
            "[[device]]\nname = \"{name}\"\nprotocol = \"{protocol}\"\nrate_hz = {rate}\ngap_factor = 10\nretry_initial_ms = 20\nretry_max_ms = 160\nserial = {{ port = \"/dev/test-{name}\" }}\n"
        ));
    }
    parse(&text, "test").unwrap_or_else(|e| panic!("{e}"))
}

fn line_decoders() -> DecoderFactory {
    Box::new(|| Box::new(LineDecoder::default()) as Box<dyn FrameDecoder>)
}

struct Running {
    stop: watch::Sender<bool>,
    handle: tokio::task::JoinHandle<Outcome>,
    status_path: std::path::PathBuf,
}

fn start(
    config: CheckedConfig,
    sink: MemorySink,
    connectors: Vec<QueueConnector>,
    free_space: FreeSpaceFn,
) -> Running {
    let status_path = config.status_path();
    let parts = DaemonParts {
        sink: Box::new(sink),
        session_dir: config.session.output_dir.join("session"),
        decoders: connectors.iter().map(|_| line_decoders()).collect(),
        connectors: connectors
            .into_iter()
            .map(|c| Box::new(c) as Box<dyn Connector>)
            .collect(),
        free_space,
        status_path: status_path.clone(),
    };
    let (stop, stop_rx) = watch::channel(false);
    let handle = tokio::spawn(async move { run(&config, parts, stop_rx).await });
    Running {
        stop,
        handle,
        status_path,
    }
}

impl Running {
    async fn finish(self) -> (Outcome, StatusReport) {
        let _ = self.stop.send(true);
        let t = Instant::now();
        let outcome = self.handle.await.expect("daemon task");
        assert!(
            t.elapsed() < Duration::from_secs(2),
            "stop took {:?}",
            t.elapsed()
        );
        let status = read_status_file(&self.status_path).expect("status file");
        (outcome, status)
    }
}

fn plenty_of_space() -> FreeSpaceFn {
    Box::new(|| Ok(u64::MAX / 2))
}

fn events(store: &MemoryStore, kind: EventKind) -> Vec<String> {
    store
        .events
        .iter()
        .filter(|e| e.kind == kind)
        .map(|e| format!("[{}] {}", e.device, e.detail))
        .collect()
}

fn gyro_of(seq: u64) -> [f64; 3] {
    [seq as f64 * 1e-3, -0.25, 1.5e-7 * seq as f64]
}
fn accel_of(seq: u64) -> [f64; 3] {
    [0.125, -9.80665, seq as f64]
}

/// Sends frames `range` at `rate_hz`, with `garbage` written before frame numbers in `dirty`.
async fn send_imu(
    port: &mut tokio::io::DuplexStream,
    range: std::ops::Range<u64>,
    rate_hz: f64,
    dirty: &[u64],
    garbage: &[u8],
) {
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let start = tokio::time::Instant::now();
    for (k, seq) in range.enumerate() {
        if dirty.contains(&seq) {
            port.write_all(garbage).await.unwrap();
        }
        port.write_all(&encode_imu(seq, gyro_of(seq), accel_of(seq)))
            .await
            .unwrap();
        tokio::time::sleep_until(start + period * (k as u32 + 1)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_arrive_once_with_values_and_garbage_becomes_events() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "", &[("imu", 150.0), ("gnss", 10.0)]);
    let imu = QueueConnector::default();
    let gnss = QueueConnector::default();
    let mut imu_port = imu.plug();
    let mut gnss_port = gnss.plug();
    let sink = MemorySink::new();
    let running = start(config, sink.clone(), vec![imu, gnss], plenty_of_space());

    let gnss_sender = tokio::spawn(async move {
        for k in 0..6u32 {
            let fix = encode_gnss(2400, 100.0 + f64::from(k) * 0.1, 48.1 + f64::from(k), 11.5);
            gnss_port.write_all(&fix).await.unwrap();
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        gnss_port
    });
    // Garbage: random-ish bytes, a frame with a wrong checksum, and a frame cut short.
    let mut garbage = b"\x00\xff\x13garbage".to_vec();
    garbage.extend_from_slice(b"$I,999,1,2,3,4,5,6*00\n");
    garbage.extend_from_slice(b"$I,998,1,2");
    send_imu(&mut imu_port, 0..120, 150.0, &[30, 31, 80], &garbage).await;
    let _gnss_port = gnss_sender.await.unwrap();
    tokio::time::sleep(Duration::from_millis(150)).await;
    let (outcome, status) = running.finish().await;
    assert!(matches!(outcome, Outcome::Stopped), "{outcome:?}");
    assert_eq!(outcome.exit_code(), 0);

    let store = sink.snapshot();
    assert!(store.closed);
    assert!(store.flushes >= 2, "flushes {}", store.flushes);
    let rows = &store.imu["imu"];
    let seqs: Vec<u64> = rows.iter().map(|r| r.t_sensor as u64).collect();
    assert_eq!(
        seqs,
        (0..120).collect::<Vec<_>>(),
        "every frame exactly once, in order"
    );
    for r in rows {
        let seq = r.t_sensor as u64;
        assert_eq!(r.gyro, gyro_of(seq));
        assert_eq!(r.accel, accel_of(seq));
        assert!(r.temp.is_nan());
    }
    assert!(rows.windows(2).all(|w| w[0].t_mono_ns <= w[1].t_mono_ns));
    assert!(rows
        .windows(2)
        .all(|w| w[0].t_wall_ns <= w[1].t_wall_ns + 1_000_000));
    let span_s = (rows[119].t_mono_ns - rows[0].t_mono_ns) as f64 * 1e-9;
    let rate = 119.0 / span_s;
    assert!((rate - 150.0).abs() < 15.0, "rate {rate}");

    let fixes = &store.gnss["gnss"];
    assert_eq!(fixes.len(), 6);
    assert_eq!(fixes[3].week, 2400);
    assert!((fixes[3].tow_s - 100.3).abs() < 1e-9);
    assert_eq!(fixes[3].lat_deg, 51.1);
    assert_eq!(fixes[3].utc_ns, i64::MIN);

    assert_eq!(events(&store, EventKind::SessionStart).len(), 1);
    assert_eq!(events(&store, EventKind::SessionStop).len(), 1);
    assert_eq!(store.events.last().unwrap().kind, EventKind::SessionStop);
    assert_eq!(events(&store, EventKind::Connect).len(), 2);
    let resyncs = events(&store, EventKind::Resync);
    let checksums = events(&store, EventKind::ChecksumError);
    assert!(!resyncs.is_empty(), "{:?}", store.events);
    // One event per read that saw checksum failures, with their count: under load two
    // injections one frame apart can arrive in one read and share an event.
    let failed: u64 = checksums
        .iter()
        .map(|e| {
            let count = e
                .split_whitespace()
                .nth(1)
                .and_then(|n| n.parse::<u64>().ok());
            count.unwrap_or_else(|| panic!("no count in {e:?}"))
        })
        .sum();
    assert_eq!(failed, 3, "{checksums:?}");
    assert!((1..=3).contains(&checksums.len()), "{checksums:?}");
    assert!(
        checksums.last().unwrap().ends_with("(3 in total)"),
        "{checksums:?}"
    );
    assert!(
        events(&store, EventKind::Gap).is_empty(),
        "{:?}",
        events(&store, EventKind::Gap)
    );

    assert_eq!(status.state, "stopped");
    let imu_status = &status.devices[0];
    assert_eq!(imu_status.frames_ok, 120);
    assert_eq!(imu_status.frames_bad, 6, "3 checksum + 3 cut frames");
    assert_eq!(imu_status.resyncs, 3);
    assert_eq!(status.devices[1].frames_ok, 6);
    assert_eq!(status.rows_written, 126);
    // The final status covers the whole run: its uptime spans the frames, and its rate is
    // the run's mean (below the burst rate, never the count over a few nanoseconds).
    assert!(status.uptime_s >= span_s, "uptime {} s", status.uptime_s);
    assert!(
        imu_status.rate_hz > 0.0 && imu_status.rate_hz <= 165.0,
        "final rate {} Hz",
        imu_status.rate_hz
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn vanished_device_reconnects_into_the_same_session() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "", &[("imu", 100.0)]);
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::new();
    let running = start(config, sink.clone(), vec![imu.clone()], plenty_of_space());

    send_imu(&mut port, 0..30, 100.0, &[], b"").await;
    drop(port); // unplugged
    tokio::time::sleep(Duration::from_millis(400)).await;
    let attempts_while_down = imu.attempt_count();
    let mut port = imu.plug(); // plugged back
    tokio::time::sleep(Duration::from_millis(250)).await;
    send_imu(&mut port, 30..60, 100.0, &[], b"").await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    let (outcome, status) = running.finish().await;
    assert_eq!(outcome.exit_code(), 0);

    let store = sink.snapshot();
    let seqs: Vec<u64> = store.imu["imu"].iter().map(|r| r.t_sensor as u64).collect();
    assert_eq!(seqs, (0..60).collect::<Vec<_>>());
    let disconnects = events(&store, EventKind::Disconnect);
    let reconnects = events(&store, EventKind::Reconnect);
    assert_eq!(disconnects.len(), 1, "{:?}", store.events);
    assert!(
        disconnects[0].contains("vanished: end of stream"),
        "{disconnects:?}"
    );
    assert_eq!(reconnects.len(), 1, "{:?}", store.events);
    assert!(reconnects[0].contains("s down"), "{reconnects:?}");
    // Back-off 20, 40, 80, 160 ms: in 400 ms about 4 to 5 attempts, not hundreds.
    assert!(
        (3..=7).contains(&attempts_while_down),
        "{attempts_while_down} attempts"
    );
    let times = imu.attempts.lock().unwrap().clone();
    let deltas: Vec<Duration> = times.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(deltas[2] > deltas[1], "back-off grows: {deltas:?}");
    assert_eq!(status.devices[0].reconnects, 1);
    assert_eq!(status.devices[0].state, DeviceState::Stopped);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_that_never_appears_is_an_error_in_the_status_not_a_crash() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "", &[("imu", 100.0), ("ghost", 100.0)]);
    let imu = QueueConnector::default();
    let ghost = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::new();
    let running = start(
        config,
        sink.clone(),
        vec![imu, ghost.clone()],
        plenty_of_space(),
    );
    send_imu(&mut port, 0..120, 100.0, &[], b"").await;
    let live = read_status_file(&running.status_path).expect("status written while running");
    assert_eq!(live.state, "running");
    assert_eq!(live.devices[1].state, DeviceState::Absent);
    assert!(
        live.devices[1]
            .last_error
            .as_deref()
            .is_some_and(|e| e.contains("no such device")),
        "{live:?}"
    );
    assert_eq!(live.devices[0].state, DeviceState::Connected);
    assert!(live.devices[0].rate_hz > 50.0, "{live:?}");
    assert!(live.devices[0].last_sample_age_s.is_some_and(|a| a < 0.5));
    let (outcome, _) = running.finish().await;
    assert_eq!(outcome.exit_code(), 0);
    let store = sink.snapshot();
    assert_eq!(store.imu["imu"].len(), 120);
    let info = events(&store, EventKind::Info);
    assert_eq!(info.len(), 1, "said once, not per retry: {info:?}");
    assert!(
        info[0].starts_with("[ghost] cannot open memory"),
        "{info:?}"
    );
    assert!(ghost.attempt_count() >= 5);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pause_longer_than_the_gap_factor_is_a_gap_event() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "", &[("imu", 100.0)]);
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::new();
    let running = start(config, sink.clone(), vec![imu], plenty_of_space());
    send_imu(&mut port, 0..20, 100.0, &[], b"").await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    send_imu(&mut port, 20..40, 100.0, &[], b"").await;
    let (_, status) = running.finish().await;
    let gaps = events(&sink.snapshot(), EventKind::Gap);
    assert_eq!(gaps.len(), 1, "{gaps:?}");
    // About 300 ms at 100 Hz (threshold 10 periods): ~30 missing (scheduling adds a few ms).
    let missing: u64 = gaps[0]
        .split("about ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap();
    assert!((28..=36).contains(&missing), "{gaps:?}");
    assert_eq!(status.devices[0].gaps, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_writer_drops_are_counted_and_logged_never_silent() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "queue_capacity = 2", &[("imu", 1000.0)]);
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::slow(Duration::from_millis(15));
    let running = start(config, sink.clone(), vec![imu], plenty_of_space());
    // 400 frames at 1 kHz into a writer that takes 15 ms per batch and a 2-batch queue.
    send_imu(&mut port, 0..400, 1000.0, &[], b"").await;
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (outcome, status) = running.finish().await;
    assert_eq!(outcome.exit_code(), 0);
    let store = sink.snapshot();
    let written = store.imu["imu"].len() as u64;
    let dropped = status.devices[0].dropped_rows;
    assert!(dropped > 0, "the test must overload the writer");
    assert_eq!(
        written + dropped,
        400,
        "written {written} + dropped {dropped}"
    );
    let overflow = events(&store, EventKind::QueueOverflow);
    assert!(!overflow.is_empty());
    let logged: u64 = overflow
        .iter()
        .map(|e| {
            e.split(" batches (")
                .nth(1)
                .and_then(|s| s.split(' ').next())
                .and_then(|s| s.parse::<u64>().ok())
                .unwrap()
        })
        .sum();
    assert_eq!(
        logged, dropped,
        "every dropped row is in an event: {overflow:?}"
    );
}

/// A writer far behind at SIGTERM (a large queue full of batches, a sink that takes 100 ms per
/// append) writes what it can for its drain budget, then drops the rest and counts it as a
/// `queue_overflow` event: the session still closes, exit 0, within the 2 s stop deadline.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_backlog_at_stop_is_dropped_and_counted_so_the_session_closes_in_time() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "queue_capacity = 100000", &[("imu", 1000.0)]);
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::slow(Duration::from_millis(100));
    let running = start(config, sink.clone(), vec![imu], plenty_of_space());
    // 1.5 s at 1 kHz in 5 ms batches (~300) into a writer that takes ~10 a second.
    send_imu(&mut port, 0..1500, 1000.0, &[], b"").await;
    let (outcome, status) = running.finish().await;
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
    let store = sink.snapshot();
    assert!(store.closed);
    let written = store.imu["imu"].len() as u64;
    let dropped = status.devices[0].dropped_rows;
    assert!(dropped > 0, "the test must leave a backlog");
    assert_eq!(
        written + dropped,
        1500,
        "written {written} + dropped {dropped}"
    );
    let at_stop: Vec<String> = events(&store, EventKind::QueueOverflow)
        .into_iter()
        .filter(|e| e.contains("stopping:"))
        .collect();
    assert_eq!(at_stop.len(), 1, "{:?}", store.events);
    assert!(
        at_stop[0].contains(&format!("{dropped} rows in total")),
        "{at_stop:?}"
    );
    assert_eq!(store.events.last().unwrap().kind, EventKind::SessionStop);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disk_reserve_closes_the_session_and_exits_non_zero() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "disk_reserve_mb = 10", &[("imu", 100.0)]);
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::new();
    // Free space shrinks by 4 MiB a second from 18 MiB, in steps, from the first check on
    // (near the reserve the writer checks after every batch, so the count of checks says
    // nothing about time).
    let mut first_check: Option<Instant> = None;
    let free_space: FreeSpaceFn = Box::new(move || {
        let seconds = first_check
            .get_or_insert_with(Instant::now)
            .elapsed()
            .as_secs();
        Ok((18u64 << 20).saturating_sub(seconds.saturating_mul(4 << 20)))
    });
    let running = start(config, sink.clone(), vec![imu], free_space);
    let sender = tokio::spawn(async move {
        send_imu(&mut port, 0..400, 100.0, &[], b"").await;
    });
    let t = Instant::now();
    let outcome = tokio::time::timeout(Duration::from_secs(5), running.handle)
        .await
        .expect("daemon stops on its own")
        .unwrap();
    sender.abort();
    // 18, 14, 10 MiB are >= the reserve; 6 MiB at the 4th check (t ≈ 3 s) is not.
    assert!(
        t.elapsed() > Duration::from_millis(2500),
        "{:?}",
        t.elapsed()
    );
    match &outcome {
        Outcome::DiskReserve {
            free_bytes,
            reserve_bytes,
        } => {
            assert_eq!(*free_bytes, 6 << 20);
            assert_eq!(*reserve_bytes, 10 << 20);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(outcome.exit_code(), 3);
    let store = sink.snapshot();
    assert!(store.closed);
    let low = events(&store, EventKind::DiskLow);
    assert_eq!(low.len(), 1);
    let stop = events(&store, EventKind::SessionStop);
    assert!(stop[0].contains("disk reserve reached"), "{stop:?}");
    let seqs: Vec<u64> = store.imu["imu"].iter().map(|r| r.t_sensor as u64).collect();
    assert!(seqs.len() > 250);
    assert_eq!(seqs, (0..seqs.len() as u64).collect::<Vec<_>>());
    let status = read_status_file(&running.status_path).unwrap();
    assert_eq!(status.state, "stopped");
}

/// Reads are handed to the writer in batches at the points of the hand-over grid (here every
/// 250 ms, with the default 1 s flush interval), not one per read: 200 frames written one by
/// one at 500 Hz reach the writer in a few appends, each read keeping its own arrival time
/// (and raw journal entry); and a lone frame of a device that then goes quiet reaches the
/// writer at the next grid point, not at the next read.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reads_reach_the_writer_in_batches_and_a_lone_frame_within_the_window() {
    let dir = tempfile::tempdir().unwrap();
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 1000\nraw_journal = true\n\
         [[device]]\nname = \"imu\"\nprotocol = \"csv\"\nrate_hz = 500\nserial = {{ port = \"/dev/test-imu\" }}\n",
        dir.path().display()
    );
    let config = parse(&text, "test").unwrap_or_else(|e| panic!("{e}"));
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let sink = MemorySink::new();
    let running = start(config, sink.clone(), vec![imu], plenty_of_space());
    tokio::time::sleep(Duration::from_millis(100)).await;

    send_imu(&mut port, 0..200, 500.0, &[], b"").await;
    tokio::time::sleep(Duration::from_millis(400)).await;
    let store = sink.snapshot();
    let rows = &store.imu["imu"];
    assert_eq!(
        rows.len(),
        200,
        "every frame is at the writer one grid period (250 ms) and a margin later"
    );
    // Each read is in the journal with its arrival time, and its frames carry that time.
    let reads = &store.raw["imu"];
    let mut read_times: Vec<i64> = reads.iter().map(|(t, _)| *t).collect();
    let mut row_times: Vec<i64> = rows.iter().map(|r| r.t_mono_ns).collect();
    read_times.dedup();
    row_times.dedup();
    assert!(
        row_times
            .iter()
            .all(|t| read_times.binary_search(t).is_ok()),
        "rows carry their read's arrival time"
    );
    // ~0.4 s of frames on a 250 ms grid: 2 or 3 appends; one per read would be one per
    // frame on an idle machine (fewer when a loaded machine bunches frames into reads).
    assert!(
        (2..=6).contains(&store.row_appends) && store.row_appends < row_times.len() as u64,
        "{} appends for {} reads ({} arrival times)",
        store.row_appends,
        reads.len(),
        row_times.len()
    );

    // A lone frame, then silence: handed over at the next grid point.
    let sent_at = Instant::now();
    port.write_all(&encode_imu(200, gyro_of(200), accel_of(200)))
        .await
        .unwrap();
    loop {
        if sink.snapshot().imu["imu"].len() == 201 {
            break;
        }
        assert!(
            sent_at.elapsed() < Duration::from_secs(2),
            "a lone frame did not reach the writer"
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let waited = sent_at.elapsed();
    assert!(
        waited <= Duration::from_millis(400),
        "the lone frame is handed over at the next grid point, 250 ms apart ({waited:?})"
    );
    let (outcome, _) = running.finish().await;
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
}
