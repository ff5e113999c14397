//! slcan codec: Lawicel reference strings, commands and replies, bad-line rules, and round
//! trips with splits at every byte boundary and junk lines between messages.

mod imucan_support;

use imucan_support::{assert_every_split, decode_all, decode_split};
use imulab_drivers::codec::can::{CanFrame, CanKind};
use imulab_drivers::codec::slcan::{bitrate_code, SlcanDecoder, SlcanEncoder, SlcanMessage};
use imulab_drivers::codec::{Decoder, Encoder};
use proptest::prelude::*;

fn frame_of(m: &SlcanMessage) -> (CanFrame, Option<u16>) {
    match m {
        SlcanMessage::Frame {
            frame,
            timestamp_ms,
        } => (*frame, *timestamp_ms),
        other => panic!("not a frame: {other:?}"),
    }
}

#[test]
fn reference_strings_decode() {
    let mut d = SlcanDecoder::new();
    let msgs = decode_all(
        &mut d,
        b"S6\rO\rt1230\rt12381122334455667788\rT1FFFFFFF2AABB1234\rr7FF8\rR000000013EA5F\r\r\x07z\rV1013\rC\r",
    );
    assert_eq!(msgs.len(), 12, "{msgs:?} {:?}", d.stats());
    assert_eq!(msgs[0], SlcanMessage::Bitrate(6));
    assert_eq!(bitrate_code(500_000), Some(6));
    assert_eq!(msgs[1], SlcanMessage::Open);
    let (f, t) = frame_of(&msgs[2]);
    assert_eq!(
        (f.id(), f.is_extended(), f.payload(), t),
        (0x123, false, &[][..], None)
    );
    let (f, _) = frame_of(&msgs[3]);
    assert_eq!(
        f.payload(),
        &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88]
    );
    let (f, t) = frame_of(&msgs[4]);
    assert_eq!(
        (f.id(), f.is_extended(), f.payload(), t),
        (0x1FFF_FFFF, true, &[0xAA, 0xBB][..], Some(0x1234))
    );
    let (f, t) = frame_of(&msgs[5]);
    assert_eq!(
        (f.id(), f.kind(), f.len(), t),
        (0x7FF, CanKind::Remote, 8, None)
    );
    let (f, t) = frame_of(&msgs[6]);
    assert_eq!(
        (f.id(), f.is_extended(), f.kind(), f.len(), t),
        (1, true, CanKind::Remote, 3, Some(0xEA5F))
    );
    assert_eq!(msgs[7], SlcanMessage::Ok);
    assert_eq!(msgs[8], SlcanMessage::Error);
    assert_eq!(msgs[9], SlcanMessage::TransmitAck { extended: false });
    assert_eq!(msgs[10], SlcanMessage::Other("V1013".into()));
    assert_eq!(msgs[11], SlcanMessage::Close);
    assert_eq!(d.stats().frames_ok, 12);
}

#[test]
fn bad_lines_are_counted() {
    let mut d = SlcanDecoder::new();
    let mut input = Vec::new();
    input.extend_from_slice(b"t8000\r"); // 11-bit id out of range
    input.extend_from_slice(b"t1239\r"); // DLC 9
    input.extend_from_slice(b"t1232001\r"); // 2 data bytes declared, 3 digits follow
    input.extend_from_slice(b"t1231GG\r"); // not hex
    input.extend_from_slice(b"S9\r"); // no such bitrate
    input.extend_from_slice(b"?\r"); // not a command
    input.extend_from_slice(&[b'T'; 50]); // over-long
    input.extend_from_slice(b"\rt1231AB\r");
    let msgs = decode_all(&mut d, &input);
    assert_eq!(msgs.len(), 1);
    assert_eq!(frame_of(&msgs[0]).0.payload(), &[0xAB]);
    let s = d.stats();
    assert_eq!(s.frames_malformed, 6);
    assert_eq!(s.frames_too_long, 1);
}

#[test]
fn encoder_output_is_exact_and_refuses_fd() {
    let mut out = Vec::new();
    let frame = CanFrame::data(0x0AB, false, &[0xDE, 0xAD]).expect("valid");
    SlcanEncoder
        .encode(
            &SlcanMessage::Frame {
                frame,
                timestamp_ms: Some(0x00FF),
            },
            &mut out,
        )
        .expect("ok");
    assert_eq!(out, b"t0AB2DEAD00FF\r");
    let fd = CanFrame::fd(1, false, true, false, &[0; 12]).expect("valid");
    assert!(SlcanEncoder
        .encode(
            &SlcanMessage::Frame {
                frame: fd,
                timestamp_ms: None
            },
            &mut out
        )
        .is_err());
    assert!(SlcanEncoder
        .encode(&SlcanMessage::Other("hello".into()), &mut out)
        .is_err());
}

fn arb_frame() -> impl Strategy<Value = CanFrame> {
    prop_oneof![
        (0u32..=0x7FF, proptest::collection::vec(any::<u8>(), 0..=8))
            .prop_map(|(id, d)| CanFrame::data(id, false, &d).expect("valid")),
        (
            0u32..=0x1FFF_FFFF,
            proptest::collection::vec(any::<u8>(), 0..=8)
        )
            .prop_map(|(id, d)| CanFrame::data(id, true, &d).expect("valid")),
        (0u32..=0x7FF, 0u8..=8).prop_map(|(id, n)| CanFrame::remote(id, false, n).expect("valid")),
        (0u32..=0x1FFF_FFFF, 0u8..=8)
            .prop_map(|(id, n)| CanFrame::remote(id, true, n).expect("valid")),
    ]
}

fn arb_message() -> impl Strategy<Value = SlcanMessage> {
    prop_oneof![
        6 => (arb_frame(), proptest::option::of(any::<u16>()))
            .prop_map(|(frame, timestamp_ms)| SlcanMessage::Frame { frame, timestamp_ms }),
        1 => Just(SlcanMessage::Open),
        1 => Just(SlcanMessage::ListenOnly),
        1 => Just(SlcanMessage::Close),
        1 => (0u8..=8).prop_map(SlcanMessage::Bitrate),
        1 => Just(SlcanMessage::Ok),
        1 => Just(SlcanMessage::Error),
        1 => any::<bool>().prop_map(|extended| SlcanMessage::TransmitAck { extended }),
        1 => "V[0-9]{4}|N[A-F0-9]{4}|F[0-9]{2}|Z[01]".prop_map(SlcanMessage::Other),
    ]
}

/// A junk line: characters that start no slcan command, then CR.
fn arb_junk() -> impl Strategy<Value = Vec<u8>> {
    "[xyq!%&*+=_~ghijk0-9]{1,12}".prop_map(|s| format!("{s}\r").into_bytes())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn round_trip_with_junk_and_every_split(
        items in proptest::collection::vec((proptest::option::of(arb_junk()), arb_message()), 0..8),
    ) {
        let mut bytes = Vec::new();
        let mut expected = Vec::new();
        let mut junk_lines = 0;
        for (junk, message) in &items {
            if let Some(j) = junk {
                bytes.extend_from_slice(j);
                junk_lines += 1;
            }
            SlcanEncoder.encode(message, &mut bytes).expect("valid");
            expected.push(message.clone());
        }
        let d = assert_every_split(SlcanDecoder::new, &bytes, &expected);
        prop_assert_eq!(d.stats().frames_ok, expected.len() as u64);
        prop_assert_eq!(d.stats().frames_malformed, junk_lines);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let mut d = SlcanDecoder::new();
        let frames = decode_all(&mut d, &bytes);
        prop_assert_eq!(d.stats().frames_ok, frames.len() as u64);
    }
}

#[test]
fn long_line_ended_by_bel_counts_the_same_however_split() {
    let mut input = vec![b'x'; 40];
    input.push(0x07);
    input.extend_from_slice(b"t1230\r");
    let (_, whole) = decode_split(SlcanDecoder::new(), &input, input.len());
    assert_eq!(whole.stats().frames_too_long, 1);
    for split in 0..=input.len() {
        let (frames, d) = decode_split(SlcanDecoder::new(), &input, split);
        assert_eq!(frames.len(), 2, "split {split}");
        assert_eq!(d.stats(), whole.stats(), "split {split}");
    }
}
