//! Xbus / MTData2 codec: hand-built frames checked against the protocol's rules (checksum,
//! big-endian floats, fixed-point formats, extended length), round trips with splits at
//! every byte boundary and garbage between frames, and resync after bad frames.

mod imucan_support;

use imucan_support::{assert_every_split, decode_all, stream_with_garbage};
use imulab_drivers::codec::xbus::{
    data_id, MtData2, XbusDecoder, XbusEncoder, XbusMessage, XbusValue,
};
use imulab_drivers::codec::{Decoder, Encoder};
use proptest::prelude::*;

/// Builds a frame by hand: preamble, bus id, mid, length, payload, checksum.
fn frame(mid: u8, payload: &[u8]) -> Vec<u8> {
    let mut f = vec![0xFA, 0xFF, mid];
    if payload.len() < 255 {
        f.push(payload.len() as u8);
    } else {
        f.extend_from_slice(&[0xFF, (payload.len() >> 8) as u8, payload.len() as u8]);
    }
    f.extend_from_slice(payload);
    let sum: u32 = f[1..].iter().map(|&b| u32::from(b)).sum();
    f.push(((256 - sum % 256) % 256) as u8);
    f
}

#[test]
fn hand_built_mtdata2_decodes() {
    let mut p = Vec::new();
    p.extend_from_slice(&[0x10, 0x20, 2, 0x01, 0x02]); // PacketCounter 258
    p.extend_from_slice(&[0x10, 0x60, 4, 0, 0x01, 0x86, 0xA0]); // SampleTimeFine 100000
    p.extend_from_slice(&[0x40, 0x20, 12]); // Acceleration float32 ENU
    for v in [0.5f32, -1.25, 9.81] {
        p.extend_from_slice(&v.to_be_bytes());
    }
    p.extend_from_slice(&[0x80, 0x22, 18]); // RateOfTurn FP16.32
    p.extend_from_slice(&[0x80, 0, 0, 0, 0xFF, 0xFE]); // -2 + 0.5 = -1.5
    p.extend_from_slice(&[0, 0, 0, 0, 0, 1]); // 1.0
    p.extend_from_slice(&[0x40, 0, 0, 0, 0, 0]); // 0.25
    p.extend_from_slice(&[0x08, 0x11, 4, 0x01, 0x90, 0x00, 0x00]); // Temp FP12.20: 25.0
    p.extend_from_slice(&[0xE0, 0x20, 4, 0, 0, 0, 0x03]); // StatusWord
    p.extend_from_slice(&[0x20, 0x30, 6, 1, 2, 3, 4, 5, 6]); // EulerAngles: not interpreted
    let bytes = frame(0x36, &p);
    let mut d = XbusDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    assert_eq!(frames.len(), 1, "{:?}", d.stats());
    let XbusMessage::MtData2 { bus_id, data } = &frames[0] else {
        panic!("not MTData2: {:?}", frames[0]);
    };
    assert_eq!(*bus_id, 0xFF);
    assert_eq!(data.packet_counter, Some(258));
    assert_eq!(data.sample_time_fine, Some(100_000));
    assert_eq!(
        data.acceleration,
        Some(XbusValue {
            data_id: 0x4020,
            value: [0.5, -1.25, f64::from(9.81f32)]
        })
    );
    assert_eq!(data.rate_of_turn.map(|v| v.value), Some([-1.5, 1.0, 0.25]));
    assert_eq!(data.temperature.map(|v| v.value), Some(25.0));
    assert_eq!(data.status_word, Some(3));
    assert_eq!(data.skipped_items, 1);
    let s = data.to_imu_sample();
    assert_eq!(s.sensor_time, Some(10.0));
    assert_eq!(s.gyro, Some([-1.5, 1.0, 0.25]));
    assert_eq!(s.status, 3);
    // The encoder reproduces the interpreted items bit for bit.
    let mut again = Vec::new();
    XbusEncoder
        .encode(&frames[0], &mut again)
        .expect("encodable");
    let mut d2 = XbusDecoder::new();
    assert_eq!(
        decode_all(&mut d2, &again),
        frames
            .iter()
            .map(|f| {
                let XbusMessage::MtData2 { bus_id, data } = f else {
                    unreachable!()
                };
                XbusMessage::MtData2 {
                    bus_id: *bus_id,
                    data: MtData2 {
                        skipped_items: 0,
                        ..*data
                    },
                }
            })
            .collect::<Vec<_>>()
    );
}

#[test]
fn extended_length_and_other_messages() {
    let payload: Vec<u8> = (0..600u32).map(|i| (i * 7) as u8).collect();
    let bytes = frame(0x0D, &payload);
    assert_eq!(bytes[3], 0xFF, "extended length used");
    let mut d = XbusDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    assert_eq!(
        frames,
        vec![XbusMessage::Other {
            bus_id: 0xFF,
            mid: 0x0D,
            payload: payload.clone()
        }]
    );
    let mut encoded = Vec::new();
    XbusEncoder.encode(&frames[0], &mut encoded).expect("ok");
    assert_eq!(encoded, bytes);
}

#[test]
fn bad_frames_are_counted_and_resynced() {
    let good = frame(0x36, &[0x10, 0x20, 2, 0, 7]);
    let mut bytes = Vec::new();
    // Checksum error.
    let mut bad = good.clone();
    *bad.last_mut().expect("non-empty") ^= 0x55;
    bytes.extend_from_slice(&bad);
    // Valid checksum but an item overrunning the payload: malformed.
    bytes.extend_from_slice(&frame(0x36, &[0x10, 0x20, 9, 0, 7]));
    // Extended length beyond the 2048-byte maximum.
    bytes.extend_from_slice(&[0xFA, 0xFF, 0x36, 0xFF, 0x09, 0x00]);
    bytes.extend_from_slice(&good);
    let mut d = XbusDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    assert_eq!(frames.len(), 1);
    let s = d.stats();
    assert_eq!(s.checksum_errors, 1);
    assert_eq!(s.frames_malformed, 1);
    assert_eq!(s.frames_too_long, 1);
    assert_eq!(s.frames_ok, 1);
}

#[test]
fn encoder_rejects_unrepresentable_values() {
    let msg = |v: f64, id: u16| XbusMessage::MtData2 {
        bus_id: 0xFF,
        data: MtData2 {
            acceleration: Some(XbusValue {
                data_id: id,
                value: [v, 0.0, 0.0],
            }),
            ..MtData2::default()
        },
    };
    let mut out = Vec::new();
    assert!(
        XbusEncoder.encode(&msg(3000.0, 0x4021), &mut out).is_err(),
        "FP12.20 max ±2048"
    );
    assert!(XbusEncoder
        .encode(&msg(f64::NAN, 0x4022), &mut out)
        .is_err());
    assert!(
        XbusEncoder.encode(&msg(1.0, 0x8020), &mut out).is_err(),
        "wrong type id"
    );
    assert!(out.is_empty(), "nothing written on error");
    assert!(XbusEncoder.encode(&msg(3000.0, 0x4022), &mut out).is_ok());
}

fn arb_reals<const N: usize>(type_id: u16) -> impl Strategy<Value = XbusValue<[f64; N]>> {
    (0u16..4, prop_oneof![Just(0u16), Just(4), Just(8)]).prop_flat_map(move |(prec, frame)| {
        let id = type_id | frame | prec;
        let value = match prec {
            data_id::FLOAT32 => any::<f32>()
                .prop_filter("finite", |v| v.is_finite())
                .prop_map(f64::from)
                .boxed(),
            data_id::FP1220 => any::<i32>().prop_map(|c| f64::from(c) / 1048576.0).boxed(),
            data_id::FP1632 => (-(1i64 << 47)..(1i64 << 47))
                .prop_map(|c| c as f64 / 4294967296.0)
                .boxed(),
            _ => any::<f64>()
                .prop_filter("finite", |v| v.is_finite())
                .boxed(),
        };
        proptest::array::uniform::<_, N>(value)
            .prop_map(move |value| XbusValue { data_id: id, value })
    })
}

fn arb_mtdata2() -> impl Strategy<Value = MtData2> {
    (
        proptest::option::of(any::<u16>()),
        proptest::option::of(any::<u32>()),
        proptest::option::of(arb_reals::<1>(data_id::TEMPERATURE)),
        proptest::option::of(arb_reals::<3>(data_id::ACCELERATION)),
        proptest::option::of(arb_reals::<3>(data_id::DELTA_V)),
        proptest::option::of(arb_reals::<3>(data_id::RATE_OF_TURN)),
        proptest::option::of(arb_reals::<4>(data_id::DELTA_Q)),
        proptest::option::of(any::<u32>()),
    )
        .prop_map(|(pc, stf, t, a, dv, w, dq, st)| MtData2 {
            packet_counter: pc,
            sample_time_fine: stf,
            temperature: t.map(|v| XbusValue {
                data_id: v.data_id,
                value: v.value[0],
            }),
            acceleration: a,
            delta_v: dv,
            rate_of_turn: w,
            delta_q: dq,
            status_word: st,
            skipped_items: 0,
        })
}

fn arb_message() -> impl Strategy<Value = XbusMessage> {
    prop_oneof![
        3 => (any::<u8>(), arb_mtdata2()).prop_map(|(bus_id, data)| XbusMessage::MtData2 { bus_id, data }),
        1 => (any::<u8>(), any::<u8>().prop_filter("not MTData2", |m| *m != 0x36),
              proptest::collection::vec(any::<u8>(), 0..300))
            .prop_map(|(bus_id, mid, payload)| XbusMessage::Other { bus_id, mid, payload }),
    ]
}

fn arb_garbage() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>().prop_filter("no preamble", |b| *b != 0xFA), 0..6)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn round_trip_with_garbage_and_every_split(
        items in proptest::collection::vec((arb_garbage(), arb_message()), 0..4),
        tail in arb_garbage(),
    ) {
        let (bytes, expected, garbage_len) = stream_with_garbage(&XbusEncoder, &items, &tail);
        let d = assert_every_split(XbusDecoder::new, &bytes, &expected);
        let s = d.stats();
        prop_assert_eq!(s.frames_ok, expected.len() as u64);
        prop_assert_eq!(s.checksum_errors, 0);
        prop_assert_eq!(s.bytes_skipped, garbage_len as u64);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut d = XbusDecoder::new();
        let frames = decode_all(&mut d, &bytes);
        prop_assert_eq!(d.stats().frames_ok, frames.len() as u64);
        prop_assert!(d.stats().bytes_skipped <= bytes.len() as u64);
    }
}
