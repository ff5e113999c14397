//! The protocol table as the daemon and the simulator use it: every row's readings decoder
//! builds, and every row with an encoder reads back what it sent, through nothing but the
//! row.

use std::path::PathBuf;

use imulab_drivers::codec::reading::{DeviceClock, Input, Kind, Reading, ReadingDecoder};
use imulab_drivers::codec::{
    DecoderOptions, ImuOutput, NamedText, ProtocolEntry, RowsFrom, PROTOCOLS,
};
use imulab_drivers::types::{FixType, GnssFix, ImuSample};

fn fixture_text(name: &str) -> NamedText {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures")
        .join(name);
    NamedText {
        text: std::fs::read_to_string(&path).expect("fixture"),
        name: path.display().to_string(),
    }
}

/// The options a row needs: the project's IMU-over-CAN DBC and mapping where it takes one.
fn options(entry: &ProtocolEntry) -> DecoderOptions {
    if entry.dbc {
        DecoderOptions {
            dbc: Some(fixture_text("imu_can.dbc")),
            config: Some(fixture_text("imu_can_mapping.toml")),
            ..DecoderOptions::default()
        }
    } else {
        DecoderOptions::default()
    }
}

fn imu_reading(k: u32) -> (Reading, DeviceClock) {
    let t = f64::from(k) * 0.01;
    let sample = ImuSample {
        sensor_time: Some(f64::from(k)),
        gyro: Some([0.01 * f64::from(k % 7), -0.02, 0.03]),
        accel: Some([0.1, -0.2, 9.81]),
        temp_c: Some(25.0),
        status: 0,
    };
    let clock = DeviceClock {
        time_s: t,
        wall_ns: 1_764_000_000_000_000_000 + i64::from(k) * 10_000_000,
        interval_s: 0.01,
    };
    (Reading::Imu(sample), clock)
}

fn gnss_reading(k: u32) -> Reading {
    Reading::Gnss(GnssFix {
        tow_s: Some(302_400.0 + f64::from(k) * 0.1),
        utc_ns: Some(1_764_000_000_000_000_000 + i64::from(k) * 100_000_000),
        lat_deg: Some(48.1),
        lon_deg: Some(11.5 + f64::from(k) * 1e-6),
        height_m: Some(520.0),
        height_msl_m: Some(520.0),
        vel_ned: Some([1.0, 0.5, 0.0]),
        h_acc_m: Some(1.5),
        v_acc_m: Some(2.5),
        s_acc_mps: Some(0.2),
        fix: FixType::Fix3D,
        num_sats: Some(12),
        pdop: Some(1.4),
        hdop: Some(0.8),
        ..GnssFix::default()
    })
}

fn decode(decoder: &mut dyn ReadingDecoder, bytes: &[u8]) -> Vec<Reading> {
    let mut out = Vec::new();
    decoder.push(Input::Bytes(bytes));
    while let Some(r) = decoder.poll() {
        out.push(r);
    }
    while let Some(r) = decoder.finish() {
        out.push(r);
    }
    out
}

fn close(a: [f64; 3], b: [f64; 3], tolerance: f64) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tolerance)
}

#[test]
fn every_row_builds_its_readings_with_the_options_it_needs() {
    for entry in PROTOCOLS {
        let factory =
            (entry.readings)(&options(entry)).unwrap_or_else(|e| panic!("{}: {e}", entry.name));
        let decoder = factory();
        assert_eq!(decoder.stats().frames_ok, 0, "{}", entry.name);
        if entry.dbc {
            let err = (entry.readings)(&DecoderOptions::default())
                .err()
                .expect("a DBC protocol needs its DBC");
            assert!(err.to_string().contains("DBC"), "{err}");
        }
    }
}

#[test]
fn every_encoder_reads_back_through_its_own_row() {
    let mut served = 0;
    for entry in PROTOCOLS {
        let Some(open) = entry.encoder else {
            continue;
        };
        served += 1;
        let options = options(entry);
        let encoder = open(&options).unwrap_or_else(|e| panic!("{}: {e}", entry.name));
        let mut bytes = Vec::new();
        let sent: Vec<Reading> = (0..20)
            .map(|k| {
                let (reading, clock) = match entry.kind {
                    Kind::Imu => imu_reading(k),
                    Kind::Gnss => (gnss_reading(k), DeviceClock::default()),
                };
                encoder
                    .encode(&reading, &clock, &mut bytes)
                    .unwrap_or_else(|e| panic!("{}: {e}", entry.name));
                reading
            })
            .collect();
        // The wrong kind of reading is refused and leaves the output as it was.
        let before = bytes.len();
        let wrong = match entry.kind {
            Kind::Imu => gnss_reading(0),
            Kind::Gnss => imu_reading(0).0,
        };
        assert!(encoder
            .encode(&wrong, &DeviceClock::default(), &mut bytes)
            .is_err());
        assert_eq!(bytes.len(), before, "{}", entry.name);

        let mut decoder = (entry.readings)(&options).expect("opens")();
        let got = decode(decoder.as_mut(), &bytes);
        assert_eq!(got.len(), sent.len(), "{}: {got:?}", entry.name);
        assert_eq!(decoder.stats().bytes_skipped, 0, "{}", entry.name);
        for (s, g) in sent.iter().zip(&got) {
            match (s, g) {
                (Reading::Imu(s), Reading::Imu(g)) => {
                    // WitMotion's counts are the coarsest: 2000 °/s and 16 g over 32768.
                    assert!(
                        close(s.gyro.unwrap(), g.gyro.unwrap(), 2e-3),
                        "{}: {g:?}",
                        entry.name
                    );
                    assert!(
                        close(s.accel.unwrap(), g.accel.unwrap(), 5e-3),
                        "{}: {g:?}",
                        entry.name
                    );
                    if let Some(t) = g.temp_c {
                        assert!((t - 25.0).abs() < 0.01, "{}: {g:?}", entry.name);
                    }
                }
                (Reading::Gnss(s), Reading::Gnss(g)) => {
                    assert!(
                        (s.lat_deg.unwrap() - g.lat_deg.unwrap()).abs() < 1e-7,
                        "{}",
                        entry.name
                    );
                    assert!(
                        (s.lon_deg.unwrap() - g.lon_deg.unwrap()).abs() < 1e-7,
                        "{}",
                        entry.name
                    );
                    assert_eq!(g.fix, FixType::Fix3D, "{}", entry.name);
                    assert_eq!(g.num_sats, Some(12), "{}", entry.name);
                }
                _ => panic!("{}: sent {s:?}, read {g:?}", entry.name),
            }
        }
    }
    assert!(served >= 9, "{served} rows with an encoder");
}

/// A VectorNav or MIP device set to output delta theta / delta velocity instead of rates
/// (rows from the rates, the default, or from the deltas, the same here):
/// through the row's readings decoder (what `imulogd` logs) the same gyro and accelerometer
/// readings as from rates, the deltas taken over the message's own interval (VectorNav) or
/// the device-time interval since the previous packet (MIP, so its first packet gives none).
#[test]
fn delta_outputs_read_back_as_rates_through_their_rows() {
    use imulab_drivers::codec::{mip, vectornav};
    type EncodeDelta = fn(
        &ImuSample,
        &DeviceClock,
        f64,
        &mut Vec<u8>,
    ) -> Result<(), imulab_drivers::codec::EncodeError>;
    let rows: [(&str, EncodeDelta, usize); 2] = [
        ("vectornav", vectornav::encode_delta_sample, 0),
        ("mip", mip::encode_delta_sample, 1),
    ];
    for (name, encode, unrated) in rows {
        let entry = PROTOCOLS.iter().find(|e| e.name == name).expect("a row");
        let mut bytes = Vec::new();
        let sent: Vec<ImuSample> = (0..20)
            .map(|k| {
                let (Reading::Imu(sample), clock) = imu_reading(k) else {
                    unreachable!()
                };
                encode(&sample, &clock, 0.01, &mut bytes).expect("encodes");
                sample
            })
            .collect();
        let mut decoder = (entry.readings)(&options(entry)).expect("opens")();
        let got = decode(decoder.as_mut(), &bytes);
        assert_eq!(got.len(), sent.len() - unrated, "{name}: {got:?}");
        // Asked for rows from the deltas, the same rows.
        let deltas = DecoderOptions {
            rows_from: RowsFrom::Deltas,
            ..options(entry)
        };
        let mut decoder = (entry.readings)(&deltas).expect("opens")();
        assert_eq!(decode(decoder.as_mut(), &bytes), got, "{name}");
        for (s, g) in sent[unrated..].iter().zip(&got) {
            let Reading::Imu(g) = g else {
                panic!("{name}: {g:?}")
            };
            assert!(
                close(g.gyro.unwrap(), s.gyro.unwrap(), 1e-5),
                "{name}: {g:?} vs {s:?}"
            );
            assert!(
                close(g.accel.unwrap(), s.accel.unwrap(), 1e-4),
                "{name}: {g:?} vs {s:?}"
            );
        }
    }
}

/// The VectorNav and MIP rows' encoders set to send deltas or both (the simulator's
/// `output`): read back with rows from the deltas, the readings sent, within the f32 wire.
#[test]
fn vectornav_and_mip_encoders_send_deltas_when_asked() {
    for name in ["vectornav", "mip"] {
        let entry = PROTOCOLS.iter().find(|e| e.name == name).expect("a row");
        for output in [ImuOutput::Deltas, ImuOutput::Both] {
            let options = DecoderOptions {
                imu_output: output,
                rows_from: RowsFrom::Deltas,
                ..options(entry)
            };
            let encoder = (entry.encoder.expect("an encoder"))(&options).expect("opens");
            let mut bytes = Vec::new();
            let sent: Vec<ImuSample> = (0..20)
                .map(|k| {
                    let (reading, clock) = imu_reading(k);
                    encoder
                        .encode(&reading, &clock, &mut bytes)
                        .expect("encodes");
                    let Reading::Imu(sample) = reading else {
                        unreachable!()
                    };
                    sample
                })
                .collect();
            let mut decoder = (entry.readings)(&options).expect("opens")();
            let got = decode(decoder.as_mut(), &bytes);
            // MIP deltas alone need the interval since the previous packet.
            let unrated = usize::from(name == "mip" && output == ImuOutput::Deltas);
            assert_eq!(got.len(), sent.len() - unrated, "{name} {output:?}");
            for (s, g) in sent[unrated..].iter().zip(&got) {
                let Reading::Imu(g) = g else {
                    panic!("{name}: {g:?}")
                };
                assert!(
                    close(g.gyro.unwrap(), s.gyro.unwrap(), 1e-5),
                    "{name} {output:?}: {g:?}"
                );
                assert!(
                    close(g.accel.unwrap(), s.accel.unwrap(), 1e-4),
                    "{name} {output:?}: {g:?}"
                );
            }
        }
    }
}
