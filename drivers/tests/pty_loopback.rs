//! Pty loopback per serial protocol: an encoder writes into the master end of a pty, the
//! serial transport reads the slave end, the decoder gets every frame intact. Then the master
//! is closed and the transport must report a retryable "vanished" error promptly, not hang.
//! The slcan case also runs the adapter handshake (C, S6, O) against an emulated adapter.

use std::io::{Read, Write};
use std::time::Duration;

use imulab_drivers::codec::can::CanFrame;
use imulab_drivers::codec::csv_line::{CsvLineConfig, CsvLineDecoder, CsvLineEncoder};
use imulab_drivers::codec::slcan::{SlcanEncoder, SlcanMessage};
use imulab_drivers::codec::witmotion::{WitDecoder, WitEncoder, WitPacket};
use imulab_drivers::codec::xbus::{MtData2, XbusDecoder, XbusEncoder, XbusMessage, XbusValue};
use imulab_drivers::codec::{Decoder, Encoder};
use imulab_drivers::transport::serial::{open_serial, SerialConfig, SerialTransport};
use imulab_drivers::transport::slcan::SlcanTransport;
use imulab_drivers::transport::{ByteSource, TransportError};
use imulab_drivers::ImuSample;

struct Pty {
    master: std::fs::File,
    slave: std::os::fd::OwnedFd,
    slave_path: String,
}

fn open_pty() -> Pty {
    let pty = nix::pty::openpty(None, None).expect("openpty");
    let slave_path = nix::unistd::ttyname(&pty.slave)
        .expect("ttyname")
        .to_string_lossy()
        .into_owned();
    Pty {
        master: std::fs::File::from(pty.master),
        slave: pty.slave,
        slave_path,
    }
}

fn config(path: &str) -> SerialConfig {
    SerialConfig {
        idle_timeout: Some(Duration::from_secs(5)),
        ..SerialConfig::new(path, 115_200)
    }
}

/// After the master closes, the next read must fail as Vanished within a second.
async fn assert_vanishes(port: &mut SerialTransport) {
    let mut buf = [0u8; 64];
    let result = tokio::time::timeout(Duration::from_secs(2), async {
        loop {
            // Drain anything still buffered, then expect the error.
            match port.read(&mut buf).await {
                Ok(_) => continue,
                Err(e) => return e,
            }
        }
    })
    .await
    .expect("closed pty must not hang the reader");
    assert!(
        matches!(result, TransportError::Vanished { .. }),
        "expected Vanished, got {result}"
    );
    assert!(result.is_retryable());
}

/// Writes `bytes` into the master in odd-sized chunks, reads them through the transport
/// into `decoder` until `count` frames arrived, then closes the pty.
async fn loopback<D: Decoder>(bytes: Vec<u8>, mut decoder: D, count: usize) -> Vec<D::Frame> {
    let pty = open_pty();
    let mut port = open_serial(&config(&pty.slave_path)).expect("open pty slave");
    let mut master = pty.master;
    let writer = std::thread::spawn(move || {
        for chunk in bytes.chunks(37) {
            master.write_all(chunk).expect("write master");
        }
        master
    });
    let mut frames = Vec::new();
    let mut buf = [0u8; 256];
    while frames.len() < count {
        let n = port.read(&mut buf).await.expect("read pty");
        decoder.decode(&buf[..n], |f| frames.push(f));
    }
    let master = writer.join().expect("writer thread");
    drop(master);
    drop(pty.slave);
    assert_vanishes(&mut port).await;
    frames
}

#[tokio::test]
async fn witmotion_over_pty() {
    let packets: Vec<WitPacket> = (0..300)
        .map(|i: i16| WitPacket::Gyro {
            raw: [i, i.wrapping_mul(7), -i],
            temp_raw: 2500,
        })
        .collect();
    let mut bytes = Vec::new();
    for p in &packets {
        WitEncoder.encode(p, &mut bytes).expect("valid");
    }
    let frames = loopback(bytes, WitDecoder::new(), packets.len()).await;
    assert_eq!(frames, packets);
}

#[tokio::test]
async fn xbus_over_pty() {
    let messages: Vec<XbusMessage> = (0..200u16)
        .map(|i| XbusMessage::MtData2 {
            bus_id: 0xFF,
            data: MtData2 {
                packet_counter: Some(i),
                sample_time_fine: Some(u32::from(i) * 25),
                rate_of_turn: Some(XbusValue {
                    data_id: 0x8020,
                    value: [f64::from(i) * 0.125, -0.5, 0.0],
                }),
                acceleration: Some(XbusValue {
                    data_id: 0x4023,
                    value: [0.1, 0.2, 9.80665],
                }),
                ..MtData2::default()
            },
        })
        .collect();
    let mut bytes = Vec::new();
    for m in &messages {
        XbusEncoder.encode(m, &mut bytes).expect("valid");
    }
    let frames = loopback(bytes, XbusDecoder::new(), messages.len()).await;
    assert_eq!(frames, messages);
}

#[tokio::test]
async fn csv_lines_over_pty() {
    let samples: Vec<ImuSample> = (0..200)
        .map(|i| ImuSample {
            sensor_time: Some(f64::from(i) * 0.01),
            gyro: Some([0.001 * f64::from(i), -0.002, 0.003]),
            accel: Some([0.0, 0.0, 9.81]),
            temp_c: Some(25.5),
            status: 0,
        })
        .collect();
    let encoder = CsvLineEncoder::new(CsvLineConfig::default()).expect("valid");
    let mut bytes = b"# time,gx,gy,gz,ax,ay,az,temp\r\n".to_vec();
    for s in &samples {
        encoder.encode(s, &mut bytes).expect("valid");
    }
    let decoder = CsvLineDecoder::new(CsvLineConfig::default()).expect("valid");
    let frames = loopback(bytes, decoder, samples.len()).await;
    assert_eq!(frames, samples);
}

#[tokio::test]
async fn slcan_adapter_over_pty() {
    let frames: Vec<(CanFrame, Option<u16>)> = (0..150u32)
        .map(|i| {
            let frame = if i % 3 == 0 {
                CanFrame::remote(i, true, (i % 9) as u8).expect("valid")
            } else {
                CanFrame::data(0x100 + i, false, &i.to_le_bytes()[..(i % 5) as usize])
                    .expect("valid")
            };
            (frame, (i % 2 == 0).then_some(i as u16 * 10))
        })
        .collect();
    let mut stream = Vec::new();
    for (frame, timestamp_ms) in &frames {
        SlcanEncoder
            .encode(
                &SlcanMessage::Frame {
                    frame: *frame,
                    timestamp_ms: *timestamp_ms,
                },
                &mut stream,
            )
            .expect("valid");
        // A transmit ack and an error bell in between, as adapters send them.
        if frame.id() % 10 == 1 {
            stream.extend_from_slice(b"z\r\x07");
        }
    }
    let pty = open_pty();
    let mut master = pty.master;
    // The emulated adapter: answers each command with CR, then streams the frames.
    let adapter = std::thread::spawn(move || {
        let mut received = Vec::new();
        let mut buf = [0u8; 64];
        while received.iter().filter(|&&b| b == b'\r').count() < 3 {
            let n = master.read(&mut buf).expect("read commands");
            for &b in &buf[..n] {
                received.push(b);
                if b == b'\r' {
                    master.write_all(b"\r").expect("ack");
                }
            }
        }
        master.write_all(&stream).expect("write frames");
        (master, received)
    });
    let mut can = SlcanTransport::open(&config(&pty.slave_path), 500_000, false)
        .await
        .expect("handshake");
    let mut got = Vec::new();
    while got.len() < frames.len() {
        got.push(can.recv().await.expect("frame"));
    }
    let (master, commands) = adapter.join().expect("adapter thread");
    assert_eq!(commands, b"C\rS6\rO\r");
    assert_eq!(got, frames);
    assert_eq!(can.stats().frames_malformed, 0);
    drop(master);
    drop(pty.slave);
    let err = tokio::time::timeout(Duration::from_secs(2), can.recv())
        .await
        .expect("no hang")
        .expect_err("vanished");
    assert!(matches!(err, TransportError::Vanished { .. }), "{err}");
}

#[tokio::test]
async fn slcan_adapter_refusal_is_a_protocol_error() {
    let pty = open_pty();
    let mut master = pty.master;
    let adapter = std::thread::spawn(move || {
        let mut buf = [0u8; 64];
        let mut crs = 0;
        while crs < 2 {
            let n = master.read(&mut buf).expect("read");
            for &b in &buf[..n] {
                if b == b'\r' {
                    crs += 1;
                    // OK to "C", BEL to the bitrate command.
                    master
                        .write_all(if crs == 1 { b"\r" } else { b"\x07" })
                        .expect("reply");
                }
            }
        }
        master
    });
    let err = SlcanTransport::open(&config(&pty.slave_path), 250_000, false)
        .await
        .expect_err("refused");
    assert!(matches!(err, TransportError::Protocol { .. }), "{err}");
    drop(adapter.join());
    let bad = SlcanTransport::open(&config(&pty.slave_path), 123_456, false)
        .await
        .expect_err("bad bitrate");
    assert!(matches!(bad, TransportError::Config(_)), "{bad}");
}

#[tokio::test]
async fn silent_port_times_out_and_missing_port_fails_to_open() {
    let pty = open_pty();
    let mut port = open_serial(&SerialConfig {
        idle_timeout: Some(Duration::from_millis(150)),
        ..SerialConfig::new(&pty.slave_path, 9600)
    })
    .expect("open");
    let mut buf = [0u8; 8];
    let err = port.read(&mut buf).await.expect_err("silent");
    assert!(matches!(err, TransportError::Timeout { .. }), "{err}");
    let missing =
        open_serial(&SerialConfig::new("/dev/imulab-no-such-tty", 9600)).expect_err("missing");
    assert!(
        matches!(missing, TransportError::Open { .. }) && missing.is_retryable(),
        "{missing}"
    );
    let bad = open_serial(&SerialConfig {
        data_bits: 9,
        ..SerialConfig::new(&pty.slave_path, 9600)
    })
    .expect_err("bad config");
    assert!(matches!(bad, TransportError::Config(_)) && !bad.is_retryable());
    drop(pty.master);
}
