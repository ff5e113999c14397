//! candump log codec: can-utils reference lines (data, extended, remote, FD, error frames),
//! exact writer output, bad-line rules, and round trips with splits at every byte boundary
//! and junk lines between records.

mod imucan_support;

use imucan_support::{assert_every_split, decode_all};
use imulab_drivers::codec::can::{CanFrame, CanKind};
use imulab_drivers::codec::candump::{CandumpDecoder, CandumpEncoder, CandumpRecord, IfName};
use imulab_drivers::codec::{Decoder, Encoder};
use proptest::prelude::*;

#[test]
fn reference_lines_decode() {
    let log = b"(1700000000.123456) can0 123#DEADBEEF\n\
                (1700000000.200000) vcan0 1F334455#R\n\
                (1700000000.300000) can0 7FF#R3 R\n\
                (1700000001.000001) can1 0A1##1AABBCCDDEEFF001122334455\n\
                (1700000002.5) can0 20000080#0000000000000000\n\
                (1700000003.000000) can0 00000042#11.22.33\r\n";
    let mut d = CandumpDecoder::new();
    let r = decode_all(&mut d, log);
    assert_eq!(r.len(), 6, "{:?}", d.stats());
    assert_eq!(r[0].timestamp_us, 1_700_000_000_123_456);
    assert_eq!(r[0].interface.as_str(), "can0");
    assert_eq!(
        r[0].frame,
        CanFrame::data(0x123, false, &[0xDE, 0xAD, 0xBE, 0xEF]).expect("valid")
    );
    assert_eq!(
        r[1].frame,
        CanFrame::remote(0x1F33_4455, true, 0).expect("valid")
    );
    assert_eq!(
        r[2].frame,
        CanFrame::remote(0x7FF, false, 3).expect("valid")
    );
    assert_eq!(
        r[3].frame.kind(),
        CanKind::Fd {
            brs: true,
            esi: false
        }
    );
    assert_eq!(r[3].frame.len(), 12);
    assert_eq!(r[4].timestamp_us, 1_700_000_002_500_000);
    assert_eq!(r[4].frame.kind(), CanKind::Error);
    assert_eq!(r[4].frame.id(), 0x80);
    assert_eq!(
        r[5].frame,
        CanFrame::data(0x42, true, &[0x11, 0x22, 0x33]).expect("valid")
    );
    assert!((r[0].timestamp_s() - 1_700_000_000.123_456).abs() < 1e-6);
}

#[test]
fn writer_matches_can_utils_format() {
    let rec = |frame| CandumpRecord {
        timestamp_us: 1_700_000_000_000_042,
        interface: IfName::new("can0").expect("valid"),
        frame,
    };
    let mut out = Vec::new();
    for frame in [
        CanFrame::data(0x123, false, &[0xDE, 0xAD, 0xBE, 0xEF]).expect("valid"),
        CanFrame::data(0x123, true, &[]).expect("valid"),
        CanFrame::remote(0x10, false, 2).expect("valid"),
        CanFrame::fd(0x10, false, false, true, &[1; 12]).expect("valid"),
        CanFrame::error(0x04, &[0, 0, 0x80, 0, 0, 0, 0, 0]).expect("valid"),
    ] {
        CandumpEncoder.encode(&rec(frame), &mut out).expect("ok");
    }
    assert_eq!(
        String::from_utf8(out).expect("ascii"),
        "(1700000000.000042) can0 123#DEADBEEF\n\
         (1700000000.000042) can0 00000123#\n\
         (1700000000.000042) can0 010#R2\n\
         (1700000000.000042) can0 010##2010101010101010101010101\n\
         (1700000000.000042) can0 20000004#0000800000000000\n"
    );
}

#[test]
fn bad_lines_are_counted() {
    let log = b"(1700000000.1) can0 1234#00\n\
                (1700000000.1) can0 123#0\n\
                (1700000000.1) can0 123#001122334455667788\n\
                1700000000.1 can0 123#00\n\
                (1700000000.1) thisnameistoolong0 123#00\n\
                (1700000000.1) can0 123#00 extra junk\n\
                # a comment\n\
                \n\
                (1700000000.1) can0 123#00\n";
    let mut d = CandumpDecoder::new();
    assert_eq!(decode_all(&mut d, log).len(), 1);
    assert_eq!(d.stats().frames_malformed, 6);
}

fn arb_frame() -> impl Strategy<Value = CanFrame> {
    let fd_len = proptest::sample::select(imulab_drivers::codec::can::FD_LENGTHS.to_vec());
    prop_oneof![
        (0u32..=0x7FF, proptest::collection::vec(any::<u8>(), 0..=8))
            .prop_map(|(id, d)| CanFrame::data(id, false, &d).expect("valid")),
        (
            0u32..=0x1FFF_FFFF,
            proptest::collection::vec(any::<u8>(), 0..=8)
        )
            .prop_map(|(id, d)| CanFrame::data(id, true, &d).expect("valid")),
        (0u32..=0x1FFF_FFFF, any::<bool>(), 0u8..=8).prop_map(|(id, ext, n)| CanFrame::remote(
            if ext { id } else { id & 0x7FF },
            ext,
            n
        )
        .expect("valid")),
        (
            0u32..=0x1FFF_FFFF,
            any::<bool>(),
            any::<bool>(),
            any::<bool>(),
            fd_len,
            any::<u8>()
        )
            .prop_map(|(id, ext, brs, esi, n, fill)| {
                let data: Vec<u8> = (0..n).map(|i| fill.wrapping_add(i as u8)).collect();
                CanFrame::fd(if ext { id } else { id & 0x7FF }, ext, brs, esi, &data)
                    .expect("valid")
            }),
        (
            0u32..=0x1FFF_FFFF,
            proptest::collection::vec(any::<u8>(), 0..=8)
        )
            .prop_map(|(class, d)| CanFrame::error(class, &d).expect("valid")),
    ]
}

fn arb_record() -> impl Strategy<Value = CandumpRecord> {
    (
        0u64..4_000_000_000_000_000,
        "[a-z]{1,6}[0-9]{0,2}",
        arb_frame(),
    )
        .prop_map(|(t, name, frame)| CandumpRecord {
            timestamp_us: t,
            interface: IfName::new(&name).expect("valid"),
            frame,
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn round_trip_with_junk_and_every_split(
        items in proptest::collection::vec((proptest::option::of("[a-z ]{1,20}"), arb_record()), 0..5),
    ) {
        let mut bytes = Vec::new();
        let mut expected = Vec::new();
        let mut junk = 0;
        for (j, record) in &items {
            if let Some(j) = j {
                bytes.extend_from_slice(format!("junk {j}\n").as_bytes());
                junk += 1;
            }
            CandumpEncoder.encode(record, &mut bytes).expect("valid");
            expected.push(*record);
        }
        let d = assert_every_split(CandumpDecoder::new, &bytes, &expected);
        prop_assert_eq!(d.stats().frames_ok, expected.len() as u64);
        prop_assert_eq!(d.stats().frames_malformed, junk);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let mut d = CandumpDecoder::new();
        let frames = decode_all(&mut d, &bytes);
        prop_assert_eq!(d.stats().frames_ok, frames.len() as u64);
    }
}
