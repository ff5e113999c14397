//! The daemon writing a real session through the session store: rows, events, the raw
//! journal and the manifest read back with the store's reader, every chunk file finalised.

use std::time::Duration;

use crate::common::{encode_gnss, encode_imu, LineDecoder, QueueConnector};
use imulab::daemon::config::parse;
use imulab::daemon::session::open_session_sink;
use imulab::daemon::source::{Connector, DecoderFactory, FrameDecoder};
use imulab::daemon::{run, DaemonParts};
use imulab::store::{EventKind, Session, TimeRange};
use tokio::io::AsyncWriteExt;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_daemon_run_reads_back_from_the_session_store() {
    let dir = tempfile::tempdir().unwrap();
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 100\nraw_journal = true\ndeflate_level = 1\n\
         [[device]]\nname = \"imu\"\nprotocol = \"csv\"\nrate_hz = 200\nserial = {{ port = \"/dev/imu\" }}\n\
         axes = {{ map = [\"-y\", \"x\", \"z\"] }}\nunits = {{ gyro = \"deg/s\" }}\n\
         [[device]]\nname = \"gnss\"\nprotocol = \"gnss\"\nrate_hz = 10\nserial = {{ port = \"/dev/gnss\" }}\n",
        dir.path().display()
    );
    let config = parse(&text, "test").unwrap_or_else(|e| panic!("{e}"));
    let session_dir = dir.path().join("session-1");
    let sink = open_session_sink(&config, &session_dir).expect("session created");
    let imu = QueueConnector::default();
    let gnss = QueueConnector::default();
    let mut imu_port = imu.plug();
    let mut gnss_port = gnss.plug();
    let decoders = || -> DecoderFactory {
        Box::new(|| Box::new(LineDecoder::default()) as Box<dyn FrameDecoder>)
    };
    let parts = DaemonParts {
        sink: Box::new(sink),
        session_dir: session_dir.clone(),
        connectors: vec![
            Box::new(imu) as Box<dyn Connector>,
            Box::new(gnss) as Box<dyn Connector>,
        ],
        decoders: vec![decoders(), decoders()],
        free_space: Box::new(|| Ok(u64::MAX / 2)),
        status_path: config.status_path(),
    };
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });

    let mut sent = Vec::new();
    for seq in 0..100u64 {
        let frame = encode_imu(seq, [seq as f64, 90.0, 0.0], [0.0, 1.0, 9.81]);
        imu_port.write_all(&frame).await.unwrap();
        sent.extend_from_slice(&frame);
        if seq % 20 == 0 {
            let fix = encode_gnss(2400, 1000.0 + seq as f64 / 200.0, 48.0, 11.0);
            gnss_port.write_all(&fix).await.unwrap();
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    let _ = stop.send(true);
    let outcome = daemon.await.unwrap();
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");

    let session = Session::open(&session_dir).expect("session opens");
    assert!(session.problems().is_empty(), "{:?}", session.problems());
    assert!(
        session.files().iter().all(|f| !f.partial),
        "every chunk file finalised: {:?}",
        session.files()
    );
    let manifest = session.manifest();
    assert_eq!(manifest.devices.len(), 2);
    assert_eq!(manifest.devices[0].axis_frame, "body");
    assert_eq!(manifest.devices[1].protocol, "gnss");
    assert!(manifest.config.contains_key("session"));

    let mut seqs = Vec::new();
    for block in session.imu_blocks("imu", TimeRange::all(), 64).unwrap() {
        let block = block.unwrap();
        for i in 0..block.len() {
            let seq = block.t_sensor[i] as u64;
            seqs.push(seq);
            // body = (-sensor y, sensor x, z) and deg/s → rad/s.
            let d2r = std::f64::consts::PI / 180.0;
            assert!((block.gyro[i][0] + 90.0 * d2r).abs() < 1e-12);
            assert!((block.gyro[i][1] - seq as f64 * d2r).abs() < 1e-12);
            assert_eq!(block.accel[i], [-1.0, 0.0, 9.81]);
        }
    }
    assert_eq!(seqs, (0..100).collect::<Vec<_>>());
    let fixes: usize = session
        .gnss_blocks("gnss", TimeRange::all(), 64)
        .unwrap()
        .map(|b| b.unwrap().week.len())
        .sum();
    assert_eq!(fixes, 5);

    let mut raw = Vec::new();
    for block in session.raw_blocks("imu", TimeRange::all(), 64).unwrap() {
        raw.extend_from_slice(&block.unwrap().bytes);
    }
    assert_eq!(raw, sent, "the raw journal holds exactly the bytes sent");

    let (events, problems) = session.events();
    assert!(problems.is_empty(), "{problems:?}");
    let kinds: Vec<EventKind> = events.iter().map(|e| e.kind).collect();
    assert!(kinds.contains(&EventKind::SessionStart), "{kinds:?}");
    assert_eq!(
        kinds.iter().filter(|k| **k == EventKind::Connect).count(),
        2
    );
    assert!(kinds.contains(&EventKind::SessionStop), "{kinds:?}");
}
