//! The one resync rule of [`StreamBuffer`](super::StreamBuffer), checked on every byte
//! decoder with the same stream shape: garbage, frame, garbage, frame, corrupt frame, frame.
//! Garbage before the first frame is skipped without a resync; each later run of garbage or
//! rejected frame is one resync; every dropped byte except line framing is skipped; the
//! counts do not depend on how the stream is split.

use super::candump::CandumpDecoder;
use super::csv_line::{CsvLineConfig, CsvLineDecoder};
use super::gnss::GnssDecoder;
use super::nmea::{Decimal, Hdt, NmeaDecoder, NmeaEncoder, NmeaSentence, Talker};
use super::slcan::SlcanDecoder;
use super::ubx::{Ack, UbxDecoder, UbxEncoder, UbxMessage};
use super::witmotion::{WitDecoder, WitEncoder, WitPacket};
use super::xbus::{XbusDecoder, XbusEncoder, XbusMessage};
use super::{Decoder, Encoder};
use crate::types::DecoderStats;

/// `garbage frame garbage frame corrupt frame`, decoded whole, split at every byte and fed
/// one byte at a time: all give `expected` and three frames.
fn check<D: Decoder>(
    new: impl Fn() -> D,
    frame: &[u8],
    garbage: &[u8],
    corrupt: &[u8],
    expected: DecoderStats,
) {
    let stream = [garbage, frame, garbage, frame, corrupt, frame].concat();
    let mut whole = new();
    let mut n = 0;
    whole.decode(&stream, |_| n += 1);
    assert_eq!(whole.stats(), expected, "whole stream");
    assert_eq!(n, 3);
    for split in 0..=stream.len() {
        let mut d = new();
        d.decode(&stream[..split], |_| {});
        d.decode(&stream[split..], |_| {});
        assert_eq!(d.stats(), expected, "split at {split}");
    }
    let mut d = new();
    for b in &stream {
        d.decode(std::slice::from_ref(b), |_| {});
    }
    assert_eq!(d.stats(), expected, "byte by byte");
}

fn stats(skipped: usize, checksum: u64, malformed: u64, too_long: u64) -> DecoderStats {
    DecoderStats {
        frames_ok: 3,
        checksum_errors: checksum,
        bytes_skipped: skipped as u64,
        frames_too_long: too_long,
        frames_malformed: malformed,
        resyncs: 2,
    }
}

fn nmea_frame() -> (Vec<u8>, Vec<u8>) {
    let sentence = NmeaSentence::Hdt(Hdt {
        talker: Talker(*b"GP"),
        heading_deg: Some(Decimal::new(27407, 2)),
    });
    let mut frame = Vec::new();
    NmeaEncoder.encode(&sentence, &mut frame).expect("valid");
    // Same sentence with a changed digit: the checksum no longer matches.
    let mut corrupt = frame.clone();
    corrupt[8] = b'9';
    (frame, corrupt)
}

#[test]
fn nmea_and_gnss() {
    let (frame, corrupt) = nmea_frame();
    let garbage = b"xy\x00\x01z\r\n";
    // Line ends are framing: 5 garbage bytes per run, the corrupt sentence without CR LF.
    let expected = stats(5 + 5 + corrupt.len() - 2, 1, 0, 0);
    check(NmeaDecoder::new, &frame, garbage, &corrupt, expected);
    check(GnssDecoder::new, &frame, garbage, &corrupt, expected);
}

#[test]
fn ubx() {
    let mut frame = Vec::new();
    let ack = UbxMessage::AckAck(Ack {
        class: 0x06,
        id: 0x01,
    });
    UbxEncoder.encode(&ack, &mut frame).expect("valid");
    let mut corrupt = frame.clone();
    corrupt[6] ^= 0x01;
    // Binary: CR LF in the garbage count too; the corrupt frame is skipped whole.
    let garbage = b"\x00\x11\r\n";
    let expected = stats(4 + 4 + corrupt.len(), 1, 0, 0);
    check(UbxDecoder::new, &frame, garbage, &corrupt, expected);
}

#[test]
fn witmotion() {
    let mut frame = Vec::new();
    let packet = WitPacket::Accel {
        raw: [100, -200, 300],
        temp_raw: 2500,
    };
    WitEncoder.encode(&packet, &mut frame).expect("valid");
    let mut corrupt = frame.clone();
    corrupt[3] ^= 0x01;
    let garbage = b"\x00\x11\x22";
    let expected = stats(3 + 3 + corrupt.len(), 1, 0, 0);
    check(WitDecoder::new, &frame, garbage, &corrupt, expected);
}

#[test]
fn xbus() {
    let mut frame = Vec::new();
    let message = XbusMessage::Other {
        bus_id: 0xFF,
        mid: 0x3E,
        payload: vec![1, 2, 3],
    };
    XbusEncoder.encode(&message, &mut frame).expect("valid");
    let mut corrupt = frame.clone();
    corrupt[5] ^= 0x01;
    let garbage = b"\x00\x11";
    let expected = stats(2 + 2 + corrupt.len(), 1, 0, 0);
    check(XbusDecoder::new, &frame, garbage, &corrupt, expected);
}

#[test]
fn csv_line() {
    let frame = b"0.01,1,2,3,4,5,6,25\n";
    let garbage = b"garbage\r\n";
    let corrupt = b"0.02,1,2,x,4,5,6,25\n";
    let decoder = || CsvLineDecoder::new(CsvLineConfig::default()).expect("valid");
    // In a line format, garbage is a line that does not parse: malformed, like the corrupt
    // one; line ends are framing.
    let expected = stats(7 + 7 + corrupt.len() - 1, 0, 3, 0);
    check(decoder, frame, garbage, corrupt, expected);
    // Comment and blank lines are framing too: no count at all.
    let mut d = decoder();
    d.decode(b"# header\n\n0.01,1,2,3,4,5,6,25\n", |_| {});
    assert_eq!(
        d.stats(),
        DecoderStats {
            frames_ok: 1,
            ..DecoderStats::default()
        }
    );
}

#[test]
fn slcan() {
    let frame = b"t1232AABB\r";
    let garbage = b"xyz\r";
    let corrupt = b"t12\r";
    let expected = stats(3 + 3 + 3, 0, 3, 0);
    check(SlcanDecoder::new, frame, garbage, corrupt, expected);
}

#[test]
fn candump() {
    let frame = b"(1.000000) can0 123#AABB\n";
    let garbage = b"garbage\n";
    let corrupt = b"(1.000000) can0 12Z#AABB\n";
    let expected = stats(7 + 7 + corrupt.len() - 1, 0, 3, 0);
    check(CandumpDecoder::new, frame, garbage, corrupt, expected);
}

#[test]
fn vectornav_binary_and_ascii() {
    use super::vectornav::{
        common, VnAscii, VnAsciiKind, VnBinary, VnChecksum, VnDecoder, VnEncoder, VnFrame,
        VnOutputFields, VnValues,
    };
    let packet = VnFrame::Binary(VnBinary {
        fields: VnOutputFields {
            common: common::TIME_STARTUP | common::ANGULAR_RATE,
            ..VnOutputFields::default()
        },
        values: VnValues {
            time_startup_ns: Some(1000),
            angular_rate: Some([0.5, -0.5, 1.0]),
            ..VnValues::default()
        },
        skipped_fields: 0,
    });
    let mut frame = Vec::new();
    VnEncoder.encode(&packet, &mut frame).expect("valid");
    let mut corrupt = frame.clone();
    corrupt[8] ^= 0x01;
    let garbage = b"\x00\x11";
    let expected = stats(2 + 2 + corrupt.len(), 1, 0, 0);
    check(VnDecoder::new, &frame, garbage, &corrupt, expected);

    let sentence = VnFrame::Ascii(VnAscii {
        kind: VnAsciiKind::Acc,
        checksum: VnChecksum::Crc16,
        values: VnValues {
            accel: Some([0.1, 0.2, -9.8]),
            ..VnValues::default()
        },
    });
    let mut frame = Vec::new();
    VnEncoder.encode(&sentence, &mut frame).expect("valid");
    let mut corrupt = frame.clone();
    corrupt[9] = b'7';
    assert_ne!(frame, corrupt);
    // Line ends are framing; the corrupt sentence is dropped up to its line end.
    let garbage = b"xy\x00\r\n";
    let expected = stats(3 + 3 + corrupt.len() - 2, 1, 0, 0);
    check(VnDecoder::new, &frame, garbage, &corrupt, expected);
}

#[test]
fn mip() {
    use super::mip::{MipDecoder, MipEncoder, MipImuData, MipPacket};
    let packet = MipPacket::Imu(MipImuData {
        scaled_accel_g: Some([0.0, 0.0, -1.0]),
        scaled_gyro: Some([0.25, 0.5, -0.5]),
        ..MipImuData::default()
    });
    let mut frame = Vec::new();
    MipEncoder.encode(&packet, &mut frame).expect("valid");
    let mut corrupt = frame.clone();
    corrupt[8] ^= 0x01;
    let garbage = b"\x00\x11\r\n";
    let expected = stats(4 + 4 + corrupt.len(), 1, 0, 0);
    check(MipDecoder::new, &frame, garbage, &corrupt, expected);
}
