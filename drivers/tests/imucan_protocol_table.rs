//! The IMU/CAN rows of the protocol table: names resolve, `auto` detection picks the right
//! protocol for each stream, and the JSON decoders (incl. slcan/candump through a DBC) print
//! SI samples with the counters at the end.

use std::path::PathBuf;

use imulab_drivers::codec::can::CanFrame;
use imulab_drivers::codec::candump::{CandumpEncoder, CandumpRecord, IfName};
use imulab_drivers::codec::dbc::{DbcImu, DbcImuMapping};
use imulab_drivers::codec::slcan::{SlcanEncoder, SlcanMessage};
use imulab_drivers::codec::witmotion::{WitEncoder, WitPacket};
use imulab_drivers::codec::xbus::{MtData2, XbusEncoder, XbusMessage};
use imulab_drivers::codec::{detect, DecoderOptions, Encoder, NamedText, Protocol};
use imulab_drivers::ImuSample;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures")
        .join(name)
}

/// A fixture's text as `imulab decode` passes it to the codecs.
fn fixture_text(name: &str) -> NamedText {
    let path = fixture(name);
    NamedText {
        text: std::fs::read_to_string(&path).expect("fixture"),
        name: path.display().to_string(),
    }
}

fn wit_stream() -> Vec<u8> {
    let mut out = Vec::new();
    for i in 0..20 {
        for p in [
            WitPacket::Accel {
                raw: [0, 0, 2048],
                temp_raw: 2000,
            },
            WitPacket::Gyro {
                raw: [i, 0, 0],
                temp_raw: 2000,
            },
        ] {
            WitEncoder.encode(&p, &mut out).expect("valid");
        }
    }
    out
}

fn can_frames() -> Vec<CanFrame> {
    let mapping = DbcImuMapping::from_toml_str(
        &std::fs::read_to_string(fixture("imu_can_mapping.toml")).expect("mapping"),
    )
    .expect("valid");
    let imu = DbcImu::new(
        &std::fs::read_to_string(fixture("imu_can.dbc")).expect("dbc"),
        &mapping,
    )
    .expect("resolves");
    (0..10)
        .flat_map(|i| {
            imu.encode(&ImuSample {
                sensor_time: Some(f64::from(i) * 0.01),
                gyro: Some([0.1, 0.0, -0.1]),
                accel: Some([0.0, 0.0, 9.8]),
                temp_c: Some(30.0),
                status: 0,
            })
            .expect("in range")
        })
        .collect()
}

fn json_lines(
    protocol: Protocol,
    options: &DecoderOptions,
    bytes: &[u8],
) -> Vec<serde_json::Value> {
    let mut decoder = protocol.open(options).expect("opens");
    decoder.push(bytes);
    let mut out = Vec::new();
    let mut values = Vec::new();
    while decoder.next_json(&mut out) || decoder.finish_json(&mut out) {
        values.push(serde_json::from_slice(&out).expect("valid JSON"));
        out.clear();
    }
    values
}

#[test]
fn names_resolve() {
    for (name, protocol) in [
        ("wit", Protocol::Wit),
        ("xbus", Protocol::Xbus),
        ("csv", Protocol::Csv),
        ("slcan", Protocol::Slcan),
        ("candump", Protocol::Candump),
    ] {
        assert_eq!(Protocol::from_name(name), Ok(protocol));
    }
}

#[test]
fn auto_detection_picks_each_protocol() {
    assert_eq!(detect(&wit_stream()), Some(Protocol::Wit));
    let mut xbus = Vec::new();
    for i in 0..10 {
        let m = XbusMessage::MtData2 {
            bus_id: 0xFF,
            data: MtData2 {
                packet_counter: Some(i),
                ..MtData2::default()
            },
        };
        XbusEncoder.encode(&m, &mut xbus).expect("valid");
    }
    assert_eq!(detect(&xbus), Some(Protocol::Xbus));
    let mut slcan = Vec::new();
    let mut candump = Vec::new();
    for frame in can_frames() {
        SlcanEncoder
            .encode(
                &SlcanMessage::Frame {
                    frame,
                    timestamp_ms: None,
                },
                &mut slcan,
            )
            .expect("classic");
        CandumpEncoder
            .encode(
                &CandumpRecord {
                    timestamp_us: 1,
                    interface: IfName::new("can0").expect("ok"),
                    frame,
                },
                &mut candump,
            )
            .expect("ok");
    }
    assert_eq!(detect(&slcan), Some(Protocol::Slcan));
    assert_eq!(detect(&candump), Some(Protocol::Candump));
    assert_eq!(
        detect(b"0.1,0,0,0,0,0,9.8,20\n"),
        None,
        "CSV is never auto-detected"
    );
}

#[test]
fn json_decoders_print_si_samples() {
    let samples = json_lines(Protocol::Wit, &DecoderOptions::default(), &wit_stream());
    assert_eq!(samples.len(), 20, "the last sample comes from finish()");
    let az = samples[0]["accel"][2].as_f64().expect("accel z");
    assert!((az - 9.80665).abs() < 1e-9, "{}", samples[0]);

    let mut candump = Vec::new();
    for frame in can_frames() {
        CandumpEncoder
            .encode(
                &CandumpRecord {
                    timestamp_us: 5,
                    interface: IfName::new("can0").expect("ok"),
                    frame,
                },
                &mut candump,
            )
            .expect("ok");
    }
    let raw = json_lines(Protocol::Candump, &DecoderOptions::default(), &candump);
    assert_eq!(raw.len(), 30);
    assert_eq!(raw[0]["frame"]["id"], 0x180);
    let options = DecoderOptions {
        dbc: Some(fixture_text("imu_can.dbc")),
        config: Some(fixture_text("imu_can_mapping.toml")),
        ..DecoderOptions::default()
    };
    let imu = json_lines(Protocol::Candump, &options, &candump);
    assert_eq!(imu.len(), 10);
    let gx = imu[3]["gyro"][0].as_f64().expect("gyro x");
    assert!((gx - 0.1).abs() < 0.01f64.to_radians(), "{}", imu[3]);
    // A DBC without a mapping is refused with a clear message.
    let err = Protocol::Slcan
        .open(&DecoderOptions {
            dbc: Some(fixture_text("imu_can.dbc")),
            config: None,
            ..DecoderOptions::default()
        })
        .err()
        .expect("needs mapping");
    assert!(err.to_string().contains("mapping"), "{err}");
}
