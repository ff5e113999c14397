//! TCP client and file replay transports: data arrive intact, a closed peer is a retryable
//! "vanished" error, silence is a timeout, and replay pacing follows the requested speed.

use std::time::{Duration, Instant};

use imulab_drivers::codec::can::CanFrame;
use imulab_drivers::codec::candump::{CandumpEncoder, CandumpRecord, IfName};
use imulab_drivers::codec::Encoder;
use imulab_drivers::transport::replay::{CandumpReplay, RawReplay, ReplaySpeed};
use imulab_drivers::transport::tcp::connect_tcp;
use imulab_drivers::transport::{ByteSource, TransportError};
use tokio::io::AsyncWriteExt;

fn temp_file(name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let path = std::env::temp_dir().join(format!("imulab-{}-{name}", std::process::id()));
    std::fs::write(&path, bytes).expect("write temp file");
    path
}

#[tokio::test]
async fn tcp_reads_until_peer_closes_then_vanishes() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let address = listener.local_addr().expect("addr").to_string();
    let payload: Vec<u8> = (0..10_000u32).map(|i| (i % 251) as u8).collect();
    let sent = payload.clone();
    let server = tokio::spawn(async move {
        let (mut socket, _) = listener.accept().await.expect("accept");
        socket.write_all(&sent).await.expect("send");
    });
    let mut client = connect_tcp(
        &address,
        Duration::from_secs(2),
        Some(Duration::from_secs(2)),
    )
    .await
    .expect("connect");
    let mut got = Vec::new();
    let mut buf = [0u8; 1000];
    let err = loop {
        match client.read(&mut buf).await {
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e) => break e,
        }
    };
    server.await.expect("server");
    assert_eq!(got, payload);
    assert!(matches!(err, TransportError::Vanished { .. }), "{err}");
    assert!(err.is_retryable());
}

#[tokio::test]
async fn tcp_silence_times_out_and_refused_connect_is_retryable() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let address = listener.local_addr().expect("addr").to_string();
    let server = tokio::spawn(async move {
        let (socket, _) = listener.accept().await.expect("accept");
        tokio::time::sleep(Duration::from_millis(600)).await;
        drop(socket);
    });
    let mut client = connect_tcp(
        &address,
        Duration::from_secs(2),
        Some(Duration::from_millis(100)),
    )
    .await
    .expect("connect");
    let mut buf = [0u8; 16];
    let err = client.read(&mut buf).await.expect_err("silent");
    assert!(matches!(err, TransportError::Timeout { .. }), "{err}");
    server.abort();
    // Nothing listens on the port of a dropped listener.
    let closed = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let closed_address = closed.local_addr().expect("addr").to_string();
    drop(closed);
    let err = connect_tcp(&closed_address, Duration::from_secs(2), None)
        .await
        .expect_err("refused");
    assert!(
        matches!(err, TransportError::Open { .. }) && err.is_retryable(),
        "{err}"
    );
}

#[tokio::test]
async fn raw_replay_fast_and_paced() {
    let bytes: Vec<u8> = (0..3000u32).map(|i| (i * 13) as u8).collect();
    let path = temp_file("raw.bin", &bytes);
    let mut fast = RawReplay::open(&path, None).await.expect("open");
    let mut got = Vec::new();
    let mut buf = [0u8; 512];
    loop {
        let n = fast.read(&mut buf).await.expect("read");
        if n == 0 {
            break;
        }
        got.extend_from_slice(&buf[..n]);
    }
    assert_eq!(got, bytes);
    // 3000 bytes at 20 kB/s take 150 ms.
    let start = Instant::now();
    let mut paced = RawReplay::open(&path, Some(20_000.0)).await.expect("open");
    let mut total = 0;
    loop {
        let n = paced.read(&mut buf).await.expect("read");
        if n == 0 {
            break;
        }
        total += n;
    }
    let elapsed = start.elapsed();
    assert_eq!(total, bytes.len());
    assert!(elapsed >= Duration::from_millis(140), "{elapsed:?}");
    assert!(elapsed < Duration::from_secs(2), "{elapsed:?}");
    assert!(RawReplay::open(&path, Some(0.0)).await.is_err());
    std::fs::remove_file(&path).ok();
    let missing = RawReplay::open(std::path::Path::new("/nonexistent/imulab.bin"), None)
        .await
        .expect_err("missing");
    assert!(matches!(missing, TransportError::Open { .. }));
}

#[tokio::test]
async fn candump_replay_follows_recorded_timing() {
    let records: Vec<CandumpRecord> = (0..11u64)
        .map(|i| CandumpRecord {
            timestamp_us: 1_700_000_000_000_000 + i * 100_000,
            interface: IfName::new("vcan0").expect("valid"),
            frame: CanFrame::data(0x180, false, &[i as u8; 8]).expect("valid"),
        })
        .collect();
    let mut log = Vec::new();
    for r in &records {
        CandumpEncoder.encode(r, &mut log).expect("ok");
    }
    log.pop(); // the last line has no '\n'
    let path = temp_file("replay.log", &log);
    // 1 s of recording at 10x: about 100 ms.
    let start = Instant::now();
    let mut replay = CandumpReplay::open(&path, ReplaySpeed::Recorded { factor: 10.0 })
        .await
        .expect("open");
    let mut got = Vec::new();
    while let Some(r) = replay.next().await.expect("read") {
        got.push(r);
    }
    let elapsed = start.elapsed();
    assert_eq!(got, records);
    assert!(elapsed >= Duration::from_millis(95), "{elapsed:?}");
    assert!(elapsed < Duration::from_millis(900), "{elapsed:?}");
    let start = Instant::now();
    let mut fast = CandumpReplay::open(&path, ReplaySpeed::AsFastAsPossible)
        .await
        .expect("open");
    let mut n = 0;
    while fast.next().await.expect("read").is_some() {
        n += 1;
    }
    assert_eq!(n, records.len());
    // Unpaced: far below the 1 s the log spans (generous bound for a loaded machine).
    assert!(
        start.elapsed() < Duration::from_millis(500),
        "{:?}",
        start.elapsed()
    );
    assert!(
        CandumpReplay::open(&path, ReplaySpeed::Recorded { factor: -1.0 })
            .await
            .is_err()
    );
    std::fs::remove_file(&path).ok();
}
