//! VectorNav codec: packets built by hand from the manual's rules (field sizes, little-endian
//! floats, big-endian CRC16-CCITT computed here bit by bit), async ASCII sentences with
//! both checksum kinds, output configuration changed mid-stream, wrong checksums and
//! unsupported groups counted and resynchronised, detection against NMEA, and round trips
//! with garbage and every split.

mod imucan_support;

use imucan_support::{assert_every_split, decode_all, stream_with_garbage};
use imulab_drivers::codec::vectornav::{
    attitude, common, imu, time, VnAscii, VnAsciiKind, VnBinary, VnChecksum, VnDecoder, VnEncoder,
    VnFrame, VnOutputFields, VnValues,
};
use imulab_drivers::codec::{detect, Decoder, Encoder, Protocol, RowsFrom};
use proptest::prelude::*;

/// CRC16-CCITT as the manual's C routine computes it, byte by byte.
fn crc16(bytes: &[u8]) -> u16 {
    let mut crc: u16 = 0;
    for &b in bytes {
        crc = crc.rotate_left(8);
        crc ^= u16::from(b);
        crc ^= (crc & 0xFF) >> 4;
        crc ^= crc << 12;
        crc ^= (crc & 0xFF) << 5;
    }
    crc
}

fn packet(groups: u8, words: &[u16], payload: &[u8]) -> Vec<u8> {
    let mut p = vec![0xFA, groups];
    for w in words {
        p.extend_from_slice(&w.to_le_bytes());
    }
    p.extend_from_slice(payload);
    let crc = crc16(&p[1..]);
    p.extend_from_slice(&crc.to_be_bytes());
    p
}

fn le_f32s(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

#[test]
fn hand_built_common_and_imu_packet_decodes() {
    // Common: TimeStartup, AngularRate, Accel; IMU: Temp, Pres.
    let mut payload = 123_456_789u64.to_le_bytes().to_vec();
    payload.extend(le_f32s(&[0.01, -0.02, 0.03]));
    payload.extend(le_f32s(&[0.1, 0.2, -9.81]));
    payload.extend(le_f32s(&[24.5]));
    payload.extend(le_f32s(&[101.3]));
    let bytes = packet(
        0x05,
        &[
            common::TIME_STARTUP | common::ANGULAR_RATE | common::ACCEL,
            imu::TEMP | imu::PRES,
        ],
        &payload,
    );
    let mut d = VnDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    assert_eq!(frames.len(), 1, "{:?}", d.stats());
    let sample = frames[0].to_imu_sample(RowsFrom::Rates).expect("a sample");
    assert_eq!(sample.sensor_time, Some(0.123456789));
    assert_eq!(sample.gyro, Some([0.01f32, -0.02, 0.03].map(f64::from)));
    assert_eq!(sample.accel, Some([0.1f32, 0.2, -9.81].map(f64::from)));
    assert_eq!(sample.temp_c, Some(f64::from(24.5f32)));
    let VnFrame::Binary(b) = &frames[0] else {
        panic!("{:?}", frames[0])
    };
    assert_eq!(b.values.pressure_kpa, Some(101.3));
    // The encoder writes the same bytes.
    let mut again = Vec::new();
    VnEncoder.encode(&frames[0], &mut again).unwrap();
    assert_eq!(again, bytes);
}

#[test]
fn attitude_and_time_groups_and_skipped_fields() {
    // Time: GpsTow, GpsWeek, TimeUtc (kept as skipped); Attitude: YawPitchRoll, DCM (skipped).
    let mut payload = 345_600_000_000_000u64.to_le_bytes().to_vec();
    payload.extend_from_slice(&2200u16.to_le_bytes());
    payload.extend_from_slice(&[26, 12, 3, 16, 0, 0, 0, 0]);
    payload.extend(le_f32s(&[90.0, 1.0, -2.0]));
    payload.extend(le_f32s(&[0.0; 9]));
    let bytes = packet(
        0x12,
        &[
            time::GPS_TOW | time::GPS_WEEK | time::TIME_UTC,
            attitude::YAW_PITCH_ROLL | attitude::DCM,
        ],
        &payload,
    );
    let mut d = VnDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    let VnFrame::Binary(b) = &frames[0] else {
        panic!("{frames:?} {:?}", d.stats())
    };
    assert_eq!(b.values.gps_week, Some(2200));
    assert_eq!(b.values.ypr_deg, Some([90.0, 1.0, -2.0]));
    assert_eq!(b.skipped_fields, 2);
    // Attitude only: no sample.
    assert_eq!(frames[0].to_imu_sample(RowsFrom::Rates), None);
    // Fields not kept cannot be encoded.
    assert!(VnEncoder.encode(&frames[0], &mut Vec::new()).is_err());
}

fn sentence(body: &str, crc: bool) -> Vec<u8> {
    if crc {
        format!("${body}*{:04X}\r\n", crc16(body.as_bytes())).into_bytes()
    } else {
        let x = body.bytes().fold(0u8, |a, b| a ^ b);
        format!("${body}*{x:02X}\r\n").into_bytes()
    }
}

#[test]
fn ascii_sentences_with_both_checksums_and_a_wrong_one() {
    let imu_body = "VNIMU,+00.1234,-00.5678,+01.0000,+00.123,-00.456,-09.807,+00.001000,-00.002000,+00.003000,+25.1,+101.325";
    let mut bytes = sentence(imu_body, false);
    bytes.extend(sentence(imu_body, true));
    let mut wrong = sentence(imu_body, true);
    let at = wrong.len() - 4;
    wrong[at] = if wrong[at] == b'0' { b'1' } else { b'0' };
    bytes.extend(&wrong);
    bytes.extend(sentence("VNERR,03", false));
    let mut d = VnDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    assert_eq!(frames.len(), 3, "{:?}", d.stats());
    let s = d.stats();
    assert_eq!((s.checksum_errors, s.resyncs), (1, 1));
    assert_eq!(s.bytes_skipped, wrong.len() as u64 - 2);
    let VnFrame::Ascii(a) = &frames[1] else {
        panic!("{:?}", frames[1])
    };
    assert_eq!((a.kind, a.checksum), (VnAsciiKind::Imu, VnChecksum::Crc16));
    let sample = frames[0].to_imu_sample(RowsFrom::Rates).unwrap();
    assert_eq!(sample.gyro, Some([0.001f32, -0.002, 0.003].map(f64::from)));
    assert_eq!(sample.temp_c, Some(f64::from(25.1f32)));
    assert!(matches!(&frames[2], VnFrame::AsciiOther { body, .. } if body == "VNERR,03"));
    // A sentence whose fields do not parse: counted, sync kept.
    let mut d = VnDecoder::new();
    decode_all(
        &mut d,
        &[sentence("VNYPR,1,2", false), sentence("VNYPR,1,2,3", false)].concat(),
    );
    let s = d.stats();
    assert_eq!((s.frames_ok, s.frames_malformed, s.resyncs), (1, 1, 0));
}

fn imu_packet(fields: VnOutputFields, k: u64) -> VnFrame {
    let x = k as f32 * 0.001;
    VnFrame::Binary(VnBinary {
        fields,
        values: VnValues {
            time_startup_ns: Some(k * 5_000_000),
            angular_rate: Some([x, -x, 0.5]),
            accel: Some([0.1, x, -9.8]),
            uncomp_accel: Some([0.1, x, -9.8]),
            uncomp_gyro: Some([x, -x, 0.5]),
            mag: Some([0.2, 0.0, 0.4]),
            temp_c: Some(25.0),
            pressure_kpa: Some(101.0),
            imu_status: Some(3),
            ..VnValues::default()
        },
        skipped_fields: 0,
    })
}

#[test]
fn output_configuration_changed_mid_stream() {
    let a = VnOutputFields {
        common: common::TIME_STARTUP | common::ANGULAR_RATE | common::ACCEL,
        ..VnOutputFields::default()
    };
    let b = VnOutputFields {
        common: common::TIME_STARTUP | common::IMU | common::MAG_PRES,
        imu: imu::IMU_STATUS,
        ..VnOutputFields::default()
    };
    let mut bytes = Vec::new();
    let mut expected = Vec::new();
    for k in 0..10 {
        let frame = imu_packet(if k < 5 { a } else { b }, k);
        VnEncoder.encode(&frame, &mut bytes).unwrap();
        expected.push(frame);
    }
    // Then a GNSS-group packet (not sized here) and one more known packet.
    bytes.extend(packet(0x08, &[0x0001], &[0; 8]));
    let last = imu_packet(a, 10);
    VnEncoder.encode(&last, &mut bytes).unwrap();
    let mut d = VnDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    let decoded: Vec<_> = frames
        .iter()
        .map(|f| f.to_imu_sample(RowsFrom::Rates).unwrap())
        .collect();
    assert_eq!(decoded.len(), 11, "{:?}", d.stats());
    // After the change the uncompensated values are the sample, status from ImuStatus.
    assert_eq!(decoded[7].status, 3);
    assert_eq!(decoded[7].sensor_time, Some(0.035));
    let s = d.stats();
    assert_eq!(
        (s.frames_malformed, s.checksum_errors, s.resyncs),
        (1, 0, 1)
    );
    assert_eq!(s.bytes_skipped, 2 + 2 + 8 + 2);
}

#[test]
fn vectornav_ascii_stream_is_detected_as_vectornav_not_nmea() {
    let mut bytes = Vec::new();
    for k in 0..20 {
        let body = format!(
            "VNYMR,+{:07.3},-000.278,-000.636,+01.0267,-00.2052,+02.7264,-00.497,+00.154,-09.802,-00.003823,+00.000159,-00.000344",
            k as f64
        );
        bytes.extend(sentence(&body, false));
    }
    assert_eq!(detect(&bytes), Some(Protocol::Vectornav));
    // Binary only.
    let fields = VnOutputFields {
        common: common::TIME_STARTUP | common::ANGULAR_RATE | common::ACCEL,
        ..VnOutputFields::default()
    };
    let mut bin = Vec::new();
    for k in 0..20 {
        VnEncoder.encode(&imu_packet(fields, k), &mut bin).unwrap();
    }
    assert_eq!(detect(&bin), Some(Protocol::Vectornav));
    // Two sentences are below the confidence threshold: not claimed.
    let two = sentence("VNYPR,+1.000,+2.000,+3.000", false).repeat(2);
    assert_ne!(detect(&two), Some(Protocol::Vectornav));
}

/// Values with at most `decimals` decimals, as the nearest float32 (what the ASCII text
/// of that many decimals decodes to).
fn arb_triad_dec(decimals: i32) -> impl Strategy<Value = [f32; 3]> {
    let scale = 10f32.powi(decimals);
    [
        -999_999i32..999_999,
        -999_999i32..999_999,
        -999_999i32..999_999,
    ]
    .prop_map(move |c| c.map(|c| c as f32 / scale))
}

fn arb_triad() -> impl Strategy<Value = [f32; 3]> {
    arb_triad_dec(3)
}

fn arb_binary() -> impl Strategy<Value = VnFrame> {
    (
        any::<u64>(),
        arb_triad(),
        arb_triad(),
        arb_triad(),
        -40.0f32..85.0,
        0u16..4,
        any::<u16>(),
    )
        .prop_map(|(t, g, a, m, temp, config, status)| {
            let fields = match config {
                0 => VnOutputFields {
                    common: common::TIME_STARTUP | common::ANGULAR_RATE,
                    ..Default::default()
                },
                1 => VnOutputFields {
                    common: common::TIME_STARTUP | common::ACCEL | common::MAG_PRES,
                    ..Default::default()
                },
                2 => VnOutputFields {
                    time: time::TIME_STARTUP,
                    imu: imu::UNCOMP_GYRO | imu::UNCOMP_ACCEL | imu::TEMP | imu::IMU_STATUS,
                    ..Default::default()
                },
                _ => VnOutputFields {
                    common: common::TIME_STARTUP | common::DELTA_THETA_VEL,
                    attitude: attitude::YAW_PITCH_ROLL | attitude::VPE_STATUS,
                    ..Default::default()
                },
            };
            let mut v = VnValues {
                time_startup_ns: Some(t),
                ..VnValues::default()
            };
            match config {
                0 => v.angular_rate = Some(g),
                1 => {
                    v.accel = Some(a);
                    v.mag = Some(m);
                    v.temp_c = Some(temp);
                    v.pressure_kpa = Some(101.0);
                }
                2 => {
                    v.uncomp_gyro = Some(g);
                    v.uncomp_accel = Some(a);
                    v.temp_c = Some(temp);
                    v.imu_status = Some(status);
                }
                _ => {
                    v.delta_time_s = Some(0.005);
                    v.delta_theta_deg = Some(g);
                    v.delta_velocity = Some(a);
                    v.ypr_deg = Some(m);
                    v.vpe_status = Some(status);
                }
            }
            VnFrame::Binary(VnBinary {
                fields,
                values: v,
                skipped_fields: 0,
            })
        })
}

fn arb_ascii() -> impl Strategy<Value = VnFrame> {
    (
        arb_triad_dec(6),
        arb_triad_dec(3),
        arb_triad_dec(4),
        any::<bool>(),
    )
        .prop_map(|(g, a, m, crc)| {
            VnFrame::Ascii(VnAscii {
                kind: VnAsciiKind::Mar,
                checksum: if crc {
                    VnChecksum::Crc16
                } else {
                    VnChecksum::Xor8
                },
                values: VnValues {
                    mag: Some(m),
                    accel: Some(a),
                    angular_rate: Some(g),
                    ..VnValues::default()
                },
            })
        })
}

fn arb_garbage() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(
        any::<u8>().prop_filter("no frame start or line end", |b| {
            !matches!(*b, 0xFA | b'$' | b'\r' | b'\n')
        }),
        0..6,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn round_trip_with_garbage_and_every_split(
        items in proptest::collection::vec((arb_garbage(), prop_oneof![arb_binary(), arb_ascii()]), 0..4),
        tail in arb_garbage(),
    ) {
        let (bytes, expected, garbage_len) = stream_with_garbage(&VnEncoder, &items, &tail);
        let d = assert_every_split(VnDecoder::new, &bytes, &expected);
        let s = d.stats();
        prop_assert_eq!(s.frames_ok, expected.len() as u64);
        prop_assert_eq!(s.checksum_errors, 0);
        prop_assert_eq!(s.bytes_skipped, garbage_len as u64);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut d = VnDecoder::new();
        let frames = decode_all(&mut d, &bytes);
        prop_assert_eq!(d.stats().frames_ok, frames.len() as u64);
        prop_assert!(d.stats().bytes_skipped <= bytes.len() as u64);
    }
}
