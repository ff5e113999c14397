//! MIP codec: packets built by hand from the DCP manual's rules (field length counting its
//! own two bytes, big-endian floats, Fletcher-16), ACK/NACK replies counted as replies, a
//! changed IMU message format mid-stream, wrong checksums and fields that do not add up
//! counted and resynchronised, detection, and round trips with garbage and every split.

mod imucan_support;

use imucan_support::{assert_every_split, decode_all, stream_with_garbage};
use imulab_drivers::codec::mip::{
    field, MipDecoder, MipEncoder, MipGpsTime, MipImuData, MipPacket, STANDARD_GRAVITY,
};
use imulab_drivers::codec::{detect, Decoder, Protocol};
use proptest::prelude::*;

fn packet(set: u8, fields: &[(u8, Vec<u8>)]) -> Vec<u8> {
    let mut payload = Vec::new();
    for (descriptor, data) in fields {
        payload.push(data.len() as u8 + 2);
        payload.push(*descriptor);
        payload.extend_from_slice(data);
    }
    let mut p = vec![0x75, 0x65, set, payload.len() as u8];
    p.extend(payload);
    // Fletcher-16 by the manual's description, written out again here.
    let mut a: u32 = 0;
    let mut b: u32 = 0;
    for &x in &p {
        a = (a + u32::from(x)) % 256;
        b = (b + a) % 256;
    }
    p.push(a as u8);
    p.push(b as u8);
    p
}

fn be_f32s(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_be_bytes()).collect()
}

#[test]
fn hand_built_imu_packet_decodes_into_si() {
    let mut gps = 345_600.25f64.to_be_bytes().to_vec();
    gps.extend_from_slice(&2200u16.to_be_bytes());
    gps.extend_from_slice(&7u16.to_be_bytes());
    let bytes = packet(
        0x80,
        &[
            (field::SCALED_ACCEL, be_f32s(&[0.0, 0.5, -1.0])),
            (field::SCALED_GYRO, be_f32s(&[0.01, -0.02, 0.03])),
            (field::DELTA_THETA, be_f32s(&[1e-4, 2e-4, 3e-4])),
            (field::GPS_CORRELATION_TIMESTAMP, gps),
            (0x11, vec![0; 12]), // stabilised accel: not kept
        ],
    );
    let mut d = MipDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    assert_eq!(frames.len(), 1, "{:?}", d.stats());
    let sample = frames[0].to_imu_sample().unwrap();
    assert_eq!(sample.sensor_time, Some(345_600.25));
    assert_eq!(
        sample.accel,
        Some([0.0, 0.5 * STANDARD_GRAVITY, -STANDARD_GRAVITY])
    );
    assert_eq!(sample.gyro, Some([0.01f32, -0.02, 0.03].map(f64::from)));
    let MipPacket::Imu(data) = &frames[0] else {
        panic!()
    };
    assert_eq!(data.skipped_fields, 1);
    assert_eq!(
        data.gps_correlation_time,
        Some(MipGpsTime {
            tow_s: 345_600.25,
            week: 2200,
            valid_flags: 7
        })
    );
}

#[test]
fn replies_are_counted_not_samples_and_bad_packets_resync() {
    let ack = packet(0x0C, &[(0xF1, vec![0x64, 0x00])]);
    let nack = packet(0x0D, &[(0xF1, vec![0x45, 0x03])]);
    let imu = packet(0x80, &[(field::SCALED_GYRO, be_f32s(&[0.1, 0.2, 0.3]))]);
    let mut wrong = imu.clone();
    wrong[7] ^= 0x40;
    let stream = [&ack[..], &imu, &wrong, &nack, &imu].concat();
    let mut d = MipDecoder::new();
    let frames = decode_all(&mut d, &stream);
    assert_eq!(frames.len(), 4);
    assert!(matches!(
        frames[0],
        MipPacket::Reply {
            descriptor_set: 0x0C,
            command: 0x64,
            error_code: 0,
            ..
        }
    ));
    assert!(matches!(frames[2], MipPacket::Reply { error_code: 3, .. }));
    let samples = frames.iter().filter_map(|f| f.to_imu_sample()).count();
    assert_eq!(samples, 2);
    let s = d.stats();
    assert_eq!(
        (s.checksum_errors, s.resyncs, s.bytes_skipped),
        (1, 1, wrong.len() as u64)
    );
}

#[test]
fn message_format_changed_mid_stream() {
    let mut bytes = Vec::new();
    for k in 0..6u32 {
        let fields = if k < 3 {
            vec![
                (field::SCALED_ACCEL, be_f32s(&[0.0, 0.0, -1.0])),
                (field::SCALED_GYRO, be_f32s(&[0.1, 0.0, 0.0])),
                (field::INTERNAL_TIMESTAMP, (k * 16).to_be_bytes().to_vec()),
            ]
        } else {
            vec![
                (field::DELTA_THETA, be_f32s(&[0.001, 0.0, 0.0])),
                (field::DELTA_VELOCITY, be_f32s(&[0.0, 0.0, -0.01])),
                (field::SCALED_GYRO, be_f32s(&[0.1, 0.0, 0.0])),
                (
                    field::SHARED_REFERENCE_TIMESTAMP,
                    (u64::from(k) * 10_000_000).to_be_bytes().to_vec(),
                ),
            ]
        };
        bytes.extend(packet(0x80, &fields));
    }
    let mut d = MipDecoder::new();
    let samples: Vec<_> = decode_all(&mut d, &bytes)
        .iter()
        .filter_map(|p| p.to_imu_sample())
        .collect();
    assert_eq!(samples.len(), 6);
    assert_eq!(samples[2].sensor_time, Some(32.0));
    assert_eq!(samples[4].sensor_time, Some(0.04));
    assert_eq!(samples[4].accel, None);
    assert_eq!(d.stats().frames_malformed + d.stats().bytes_skipped, 0);
}

#[test]
fn mip_stream_is_detected() {
    let imu = packet(0x80, &[(field::SCALED_GYRO, be_f32s(&[0.1, 0.2, 0.3]))]);
    assert_eq!(detect(&imu.repeat(10)), Some(Protocol::Mip));
}

fn arb_triad() -> impl Strategy<Value = Option<[f32; 3]>> {
    proptest::option::of(proptest::array::uniform3(-100.0f32..100.0))
}

fn arb_packet() -> impl Strategy<Value = MipPacket> {
    prop_oneof![
        3 => (arb_triad(), arb_triad(), arb_triad(), arb_triad(), proptest::option::of(any::<u64>()),
              proptest::option::of((0.0f64..604_800.0, any::<u16>(), any::<u16>())))
            .prop_map(|(a, g, dt, dv, ns, gps)| MipPacket::Imu(MipImuData {
                scaled_accel_g: a,
                scaled_gyro: g,
                delta_theta: dt,
                delta_velocity_gs: dv,
                reference_time_ns: ns,
                gps_correlation_time: gps.map(|(tow_s, week, valid_flags)| MipGpsTime { tow_s, week, valid_flags }),
                ..MipImuData::default()
            })),
        1 => (0u8..0x80, any::<u8>(), any::<u8>()).prop_map(|(set, command, error_code)| MipPacket::Reply {
            descriptor_set: set,
            command,
            error_code,
            more_fields: Vec::new(),
        }),
    ]
}

fn arb_garbage() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>().prop_filter("no sync", |b| *b != 0x75), 0..6)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn round_trip_with_garbage_and_every_split(
        items in proptest::collection::vec((arb_garbage(), arb_packet()), 0..4),
        tail in arb_garbage(),
    ) {
        let (bytes, expected, garbage_len) = stream_with_garbage(&MipEncoder, &items, &tail);
        let d = assert_every_split(MipDecoder::new, &bytes, &expected);
        let s = d.stats();
        prop_assert_eq!(s.frames_ok, expected.len() as u64);
        prop_assert_eq!(s.checksum_errors, 0);
        prop_assert_eq!(s.bytes_skipped, garbage_len as u64);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut d = MipDecoder::new();
        let frames = decode_all(&mut d, &bytes);
        prop_assert_eq!(d.stats().frames_ok, frames.len() as u64);
        prop_assert!(d.stats().bytes_skipped <= bytes.len() as u64);
    }
}
