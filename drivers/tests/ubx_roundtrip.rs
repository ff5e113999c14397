//! Property tests for the UBX codec: for every decoded message type, random payloads of the
//! right layout are parsed, encoded and decoded again to the same message (frame-level
//! identity, so every raw value is recoverable from the SI fields); streams split at every
//! byte boundary or with garbage between frames decode the same; the mixed NMEA + UBX
//! decoder yields both; arbitrary bytes never panic and keep the buffer bounded.

use imulab_drivers::codec::gnss::{GnssDecoder, GnssFrame};
use imulab_drivers::codec::nmea::{Hdt, NmeaEncoder, NmeaSentence, Talker};
use imulab_drivers::codec::ubx::*;
use imulab_drivers::codec::{Decoder, Encoder};
use proptest::prelude::*;

/// A valid payload for one message type: (class, id, payload bytes).
fn payload() -> impl Strategy<Value = (u8, u8, Vec<u8>)> {
    let fixed = |class: u8, id: u8, len: usize| {
        prop::collection::vec(any::<u8>(), len).prop_map(move |p| (class, id, p))
    };
    prop_oneof![
        fixed(0x01, 0x07, 92),
        fixed(0x01, 0x07, 84),
        fixed(0x01, 0x03, 16),
        fixed(0x01, 0x02, 28),
        fixed(0x01, 0x12, 36),
        fixed(0x01, 0x21, 20),
        fixed(0x01, 0x36, 64),
        fixed(0x01, 0x04, 18),
        fixed(0x01, 0x06, 52),
        fixed(0x01, 0x01, 20),
        fixed(0x01, 0x11, 20),
        fixed(0x01, 0x20, 16),
        fixed(0x01, 0x14, 36),
        fixed(0x01, 0x3C, 40),
        fixed(0x01, 0x3C, 64),
        fixed(0x28, 0x00, 72),
        fixed(0x0A, 0x09, 60),
        fixed(0x05, 0x01, 2),
        fixed(0x05, 0x00, 2),
        // NAV-SAT: numSvs at byte 5.
        (0..6usize).prop_flat_map(|n| prop::collection::vec(any::<u8>(), 8 + 12 * n).prop_map(
            move |mut p| {
                p[5] = n as u8;
                (0x01, 0x35, p)
            }
        )),
        // RXM-RAWX: numMeas at byte 11.
        (0..4usize).prop_flat_map(
            |n| prop::collection::vec(any::<u8>(), 16 + 32 * n).prop_map(move |mut p| {
                p[11] = n as u8;
                (0x02, 0x15, p)
            })
        ),
        // ESF-RAW: 4 reserved bytes then 8-byte samples.
        (0..6usize).prop_flat_map(
            |n| prop::collection::vec(any::<u8>(), 4 + 8 * n).prop_map(|p| (0x10, 0x03, p))
        ),
        // ESF-MEAS: numMeas in flags bits 11..15, calibTtagValid bit 3.
        (0..8usize, any::<bool>()).prop_flat_map(|(n, calib)| {
            prop::collection::vec(any::<u8>(), 8 + 4 * n + if calib { 4 } else { 0 }).prop_map(
                move |mut p| {
                    let flags = (u16::from_le_bytes([p[4], p[5]]) & 0x07F7)
                        | ((n as u16) << 11)
                        | if calib { 0x08 } else { 0 };
                    p[4..6].copy_from_slice(&flags.to_le_bytes());
                    (0x10, 0x02, p)
                },
            )
        }),
        // Anything else stays raw.
        (
            any::<u8>(),
            any::<u8>(),
            prop::collection::vec(any::<u8>(), 0..40)
        ),
    ]
}

fn message() -> impl Strategy<Value = UbxMessage> {
    payload().prop_map(|(class, id, p)| parse_message(class, id, &p))
}

/// Compares through Debug: payload floats may be NaN, which is not equal to itself.
fn same(a: &[UbxMessage], b: &[UbxMessage]) -> bool {
    format!("{a:?}") == format!("{b:?}")
}

fn decode_chunks(chunks: &[&[u8]]) -> (Vec<UbxMessage>, imulab_drivers::DecoderStats) {
    let mut decoder = UbxDecoder::new();
    let mut frames = Vec::new();
    for chunk in chunks {
        decoder.decode(chunk, |f| frames.push(f));
    }
    (frames, decoder.stats())
}

fn garbage() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>().prop_filter("no sync", |b| *b != 0xB5), 0..20)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn encode_decode_identity_whole_split_and_with_garbage(
        items in prop::collection::vec((message(), garbage()), 1..5)
    ) {
        let mut clean = Vec::new();
        let mut dirty = Vec::new();
        let mut garbage_bytes = 0u64;
        let mut messages = Vec::new();
        for (m, junk) in &items {
            let mut one = Vec::new();
            UbxEncoder.encode(m, &mut one).map_err(|e| TestCaseError::fail(e.to_string()))?;
            // The class/id survives and the known types are not demoted to raw.
            prop_assert_eq!(parse_message(one[2], one[3], &one[6..one.len() - 2]).class_id(), m.class_id());
            clean.extend_from_slice(&one);
            dirty.extend_from_slice(&one);
            dirty.extend_from_slice(junk);
            garbage_bytes += junk.len() as u64;
            messages.push(m.clone());
        }

        let (frames, stats) = decode_chunks(&[&clean]);
        prop_assert!(same(&frames, &messages), "{:?} vs {:?}", frames, messages);
        prop_assert_eq!(stats.frames_ok, messages.len() as u64);

        for split in 0..=clean.len() {
            let (frames, _) = decode_chunks(&[&clean[..split], &clean[split..]]);
            prop_assert!(same(&frames, &messages), "split at {}", split);
        }

        let (frames, stats) = decode_chunks(&[&dirty]);
        prop_assert!(same(&frames, &messages));
        prop_assert_eq!(stats.bytes_skipped, garbage_bytes);
        prop_assert_eq!(stats.checksum_errors, 0);
    }

    #[test]
    fn mixed_stream_yields_every_nmea_and_ubx_frame(
        msgs in prop::collection::vec(message(), 1..5),
        headings in prop::collection::vec(0..36000i64, 1..5),
    ) {
        let mut stream = Vec::new();
        let mut want_nmea = Vec::new();
        for (i, m) in msgs.iter().enumerate() {
            UbxEncoder.encode(m, &mut stream).map_err(|e| TestCaseError::fail(e.to_string()))?;
            if let Some(&h) = headings.get(i) {
                let s = NmeaSentence::Hdt(Hdt {
                    talker: Talker(*b"GP"),
                    heading_deg: Some(imulab_drivers::codec::nmea::Decimal::new(h, 2)),
                });
                NmeaEncoder.encode(&s, &mut stream).map_err(|e| TestCaseError::fail(e.to_string()))?;
                want_nmea.push(s);
            }
        }
        let mut decoder = GnssDecoder::new();
        let (mut got_ubx, mut got_nmea) = (Vec::new(), Vec::new());
        for chunk in stream.chunks(7) {
            decoder.decode(chunk, |f| match f {
                GnssFrame::Ubx(m) => got_ubx.push(m),
                GnssFrame::Nmea(s) => got_nmea.push(s),
                GnssFrame::Fix(_) => {}
            });
        }
        prop_assert!(same(&got_ubx, &msgs));
        prop_assert_eq!(got_nmea, want_nmea);
        prop_assert_eq!(decoder.stats().bytes_skipped, 0);
    }

    #[test]
    fn arbitrary_bytes_never_panic_and_buffer_stays_bounded(
        chunks in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..300), 0..20)
    ) {
        let mut ubx = UbxDecoder::new();
        let mut mixed = GnssDecoder::new();
        for chunk in &chunks {
            ubx.decode(chunk, |_| {});
            mixed.decode(chunk, |_| {});
            prop_assert!(ubx.buffered_len() < MAX_PAYLOAD + 8);
            prop_assert!(mixed.buffered_len() < MAX_PAYLOAD + 8);
        }
        while mixed.finish().is_some() {}
    }
}

#[test]
fn nav_pvt_encodes_si_values_to_exact_raw_integers() {
    let mut payload = vec![0u8; 92];
    payload[24..28].copy_from_slice(&(-1_213_143_091i32).to_le_bytes()); // lon 1e-7 deg
    payload[28..32].copy_from_slice(&440_688_095i32.to_le_bytes()); // lat
    payload[64..68].copy_from_slice(&5_466_840i32.to_le_bytes()); // headMot 1e-5 deg
    let msg = parse_message(0x01, 0x07, &payload);
    let UbxMessage::NavPvt(pvt) = &msg else {
        panic!("not NAV-PVT: {msg:?}")
    };
    assert_eq!(pvt.lon_deg, -121.3143091);
    assert_eq!(pvt.lat_deg, 44.0688095);
    assert_eq!(pvt.head_mot_deg, 54.6684);
    let mut bytes = Vec::new();
    UbxEncoder.encode(&msg, &mut bytes).expect("encodes");
    assert_eq!(&bytes[6..bytes.len() - 2], &payload[..]);
}

/// Every message type of the codec's list decodes as itself, not as a raw message.
#[test]
fn navigation_messages_of_every_layout_are_decoded() {
    for (class, id, len, name) in [
        (0x01, 0x04, 18, "NAV-DOP"),
        (0x01, 0x06, 52, "NAV-SOL"),
        (0x01, 0x01, 20, "NAV-POSECEF"),
        (0x01, 0x11, 20, "NAV-VELECEF"),
        (0x01, 0x20, 16, "NAV-TIMEGPS"),
        (0x01, 0x14, 36, "NAV-HPPOSLLH"),
        (0x01, 0x3C, 40, "NAV-RELPOSNED"),
        (0x01, 0x3C, 64, "NAV-RELPOSNED"),
        (0x28, 0x00, 72, "HNR-PVT"),
    ] {
        let msg = parse_message(class, id, &vec![0u8; len]);
        let json = serde_json::to_string(&msg).unwrap_or_default();
        assert!(
            json.contains(&format!("\"msg\":\"{name}\"")),
            "{len} bytes: {json}"
        );
    }
}

#[test]
fn high_precision_and_relative_position_scale_to_si_and_back_to_the_same_bytes() {
    // NAV-HPPOSLLH: lat 44.0688095 deg + 37e-9, height 1110.687 m + 0.4 mm.
    let mut p = vec![0u8; 36];
    p[4..8].copy_from_slice(&1000u32.to_le_bytes());
    p[12..16].copy_from_slice(&440_688_095i32.to_le_bytes());
    p[16..20].copy_from_slice(&1_110_687i32.to_le_bytes());
    p[25] = 37;
    p[26] = 4;
    p[28..32].copy_from_slice(&141u32.to_le_bytes()); // hAcc 14.1 mm
    let msg = parse_message(0x01, 0x14, &p);
    let UbxMessage::NavHpposllh(m) = &msg else {
        panic!("not NAV-HPPOSLLH: {msg:?}")
    };
    assert!((m.lat_deg - 44.068_809_537).abs() < 1e-12, "{}", m.lat_deg);
    assert!((m.height_m - 1110.6874).abs() < 1e-9, "{}", m.height_m);
    assert!((m.h_acc_m - 0.0141).abs() < 1e-12);
    let mut bytes = Vec::new();
    UbxEncoder.encode(&msg, &mut bytes).expect("encodes");
    assert_eq!(&bytes[6..bytes.len() - 2], &p[..]);

    // NAV-RELPOSNED version 1: baseline 1.2345 m + 0.6 mm at heading 271.5 deg, valid.
    let mut p = vec![0u8; 64];
    p[0] = 1;
    p[20..24].copy_from_slice(&123i32.to_le_bytes());
    p[24..28].copy_from_slice(&27_150_000i32.to_le_bytes());
    p[35] = 6;
    p[60..64].copy_from_slice(&0x0000_0137u32.to_le_bytes());
    let msg = parse_message(0x01, 0x3C, &p);
    let UbxMessage::NavRelposned(m) = &msg else {
        panic!("not NAV-RELPOSNED: {msg:?}")
    };
    assert_eq!(m.valid_heading_deg(), Some(271.5));
    assert!((m.rel_pos_length_m.unwrap_or(0.0) - 1.2306).abs() < 1e-12);
    let mut bytes = Vec::new();
    UbxEncoder.encode(&msg, &mut bytes).expect("encodes");
    assert_eq!(&bytes[6..bytes.len() - 2], &p[..]);
    // Heading not marked valid: none.
    p[61] = 0;
    let UbxMessage::NavRelposned(m) = parse_message(0x01, 0x3C, &p) else {
        panic!("not NAV-RELPOSNED")
    };
    assert_eq!(m.valid_heading_deg(), None);
}
