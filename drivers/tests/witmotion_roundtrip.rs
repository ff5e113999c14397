//! WitMotion codec: datasheet vectors, round trips with splits at every byte boundary and
//! garbage between packets, corrupt-packet resync, and the packet-to-sample assembler.

mod imucan_support;

use imucan_support::{assert_every_split, decode_all, stream_with_garbage};
use imulab_drivers::codec::witmotion::{
    WitAssembler, WitDecoder, WitEncoder, WitImuDecoder, WitPacket,
};
use imulab_drivers::codec::{Decoder, Encoder};
use imulab_drivers::types::ImuSample;
use proptest::prelude::*;

const G: f64 = 9.806_65;

fn encode(packets: &[WitPacket]) -> Vec<u8> {
    let mut out = Vec::new();
    for p in packets {
        WitEncoder.encode(p, &mut out).expect("valid packet");
    }
    out
}

#[test]
fn datasheet_accel_packet_decodes_to_si() {
    // 0x55 0x51, ax=0, ay=0, az=2048 counts (= 1 g), T=2500 (25.00 °C), sum 0x7B, computed
    // by hand from the datasheet formula Sum = 0x55+0x51+AxH+AxL+...+TH+TL.
    let bytes = [0x55, 0x51, 0, 0, 0, 0, 0x00, 0x08, 0xC4, 0x09, 0x7B];
    let mut d = WitDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    assert_eq!(frames.len(), 1);
    let a = frames[0].accel_mps2().expect("accel");
    assert_eq!(a[0], 0.0);
    assert!((a[2] - G).abs() < 1e-12, "{a:?}");
    assert_eq!(frames[0].temp_c(), Some(25.0));
    assert_eq!(d.stats().frames_ok, 1);
}

#[test]
fn gyro_and_angle_scales() {
    let gyro = WitPacket::Gyro {
        raw: [16384, -32768, 0],
        temp_raw: -550,
    };
    let w = gyro.gyro_radps().expect("gyro");
    assert!((w[0] - 1000f64.to_radians()).abs() < 1e-12);
    assert!((w[1] + 2000f64.to_radians()).abs() < 1e-12);
    assert_eq!(gyro.temp_c(), Some(-5.5));
    let angle = WitPacket::Angle {
        raw: [16384, -8192, 32767],
        version: 0x1234,
    };
    let deg = angle.angle_deg().expect("angle");
    assert_eq!(deg[0], 90.0);
    assert_eq!(deg[1], -45.0);
    assert!((deg[2] - 179.994_506_835_937_5).abs() < 1e-12);
    // Encoded words are little-endian, version last.
    let bytes = encode(&[angle]);
    assert_eq!(&bytes[..4], &[0x55, 0x53, 0x00, 0x40]);
    assert_eq!(&bytes[8..10], &[0x34, 0x12]);
}

#[test]
fn si_encoding_rounds_and_rejects_out_of_range() {
    let p = WitPacket::accel_from_si([G, -G, 0.0], 21.37).expect("in range");
    assert_eq!(
        p,
        WitPacket::Accel {
            raw: [2048, -2048, 0],
            temp_raw: 2137
        }
    );
    assert!(WitPacket::accel_from_si([17.0 * G, 0.0, 0.0], 0.0).is_err());
    assert!(WitPacket::gyro_from_si([f64::NAN, 0.0, 0.0], 0.0).is_err());
    let q = WitPacket::gyro_from_si([1.0, -1.0, 0.5], 30.0).expect("in range");
    let back = q.gyro_radps().expect("gyro");
    let lsb = 2000f64.to_radians() / 32768.0;
    assert!((back[0] - 1.0).abs() <= lsb / 2.0 + 1e-15);
}

#[test]
fn corrupt_packet_is_counted_and_neighbours_survive() {
    let packets: Vec<WitPacket> = (0..6)
        .map(|i| WitPacket::Gyro {
            raw: [i, 2 * i, -3 * i],
            temp_raw: 2000 + i,
        })
        .collect();
    let mut bytes = encode(&packets);
    bytes[3 * 11 + 4] ^= 0x01; // payload byte of packet 3: checksum now fails
    let mut d = WitDecoder::new();
    let frames = decode_all(&mut d, &bytes);
    let expected: Vec<WitPacket> = packets
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != 3)
        .map(|(_, p)| *p)
        .collect();
    assert_eq!(frames, expected);
    let s = d.stats();
    assert_eq!(s.checksum_errors, 1);
    assert_eq!(s.frames_ok, 5);
    assert_eq!(s.bytes_skipped, 11);
    assert_eq!(s.resyncs, 1);
}

#[test]
fn truncated_stream_keeps_the_partial_packet_pending() {
    let bytes = encode(&[WitPacket::Accel {
        raw: [1, 2, 3],
        temp_raw: 4,
    }]);
    let mut d = WitDecoder::new();
    assert!(decode_all(&mut d, &bytes[..10]).is_empty());
    assert_eq!(d.stats().bytes_skipped, 0);
    assert_eq!(decode_all(&mut d, &bytes[10..]).len(), 1);
}

#[test]
fn assembler_groups_one_cycle_per_sample() {
    let cycle = |k: i16| {
        [
            WitPacket::Time {
                year: 26,
                month: 11,
                day: 23,
                hour: 14,
                minute: 30,
                second: k as u8,
                millisecond: 250,
            },
            WitPacket::Accel {
                raw: [0, 0, 2048],
                temp_raw: 2500,
            },
            WitPacket::Gyro {
                raw: [k, 0, 0],
                temp_raw: 2510,
            },
            WitPacket::Angle {
                raw: [0, 0, 0],
                version: 1,
            },
        ]
    };
    let mut assembler = WitAssembler::new();
    let mut samples = Vec::new();
    for k in 0..3 {
        for p in cycle(k) {
            samples.extend(assembler.push(&p).into_iter().flatten());
        }
    }
    assert_eq!(
        samples.len(),
        3,
        "after the first cycle, each closes on its angle packet"
    );
    assert!(
        assembler.finish().is_none(),
        "nothing held after a closed cycle"
    );
    for (k, s) in samples.iter().enumerate() {
        assert_eq!(
            s.sensor_time,
            Some(14.0 * 3600.0 + 30.0 * 60.0 + k as f64 + 0.25)
        );
        assert!((s.accel.expect("accel")[2] - G).abs() < 1e-12);
        let expected_rate = (k as f64 / 32768.0 * 2000.0).to_radians();
        assert!((s.gyro.expect("gyro")[0] - expected_rate).abs() < 1e-15);
        assert_eq!(s.temp_c, Some(25.1), "gyro temperature wins");
    }
    assert!(assembler.finish().is_none());
}

/// One output cycle `k`: time (second = k), accel (z counts = k), gyro (x counts = k), and
/// optionally a magnetometer packet.
fn wit_cycle(k: i16, with_mag: bool) -> Vec<WitPacket> {
    let mut packets = vec![
        WitPacket::Time {
            year: 26,
            month: 11,
            day: 23,
            hour: 0,
            minute: 0,
            second: k as u8,
            millisecond: 0,
        },
        WitPacket::Accel {
            raw: [0, 0, k],
            temp_raw: 2500,
        },
        WitPacket::Gyro {
            raw: [k, 0, 0],
            temp_raw: 2500,
        },
    ];
    if with_mag {
        packets.push(WitPacket::Other {
            kind: 0x54,
            data: [0; 8],
        });
    }
    packets
}

/// The cycle number a sample came from, checking its three parts agree (a sample mixed
/// from two cycles, or missing a part, fails).
fn cycle_of(s: &ImuSample) -> i16 {
    let second = s.sensor_time.expect("time part") as i16;
    let accel = (s.accel.expect("accel part")[2] / G * 2048.0).round() as i16;
    let gyro = (s.gyro.expect("gyro part")[0].to_degrees() / 2000.0 * 32768.0).round() as i16;
    assert_eq!((second, second), (accel, gyro), "one cycle's parts: {s:?}");
    second
}

/// Feeds `packets` one at a time to a [`WitImuDecoder`]; returns, per sample, its cycle
/// number and the index of the packet whose bytes made it come out.
fn emitted_at(packets: &[WitPacket]) -> (Vec<(i16, usize)>, WitImuDecoder) {
    let mut d = WitImuDecoder::new();
    let mut out = Vec::new();
    for (i, p) in packets.iter().enumerate() {
        for s in decode_all(&mut d, &encode(&[*p])) {
            out.push((cycle_of(&s), i));
        }
    }
    (out, d)
}

#[test]
fn sample_comes_out_on_its_closing_packet() {
    let mut d = WitImuDecoder::new();
    let first = encode(&wit_cycle(0, false));
    assert!(decode_all(&mut d, &first).is_empty(), "cycle not known yet");
    // The second cycle's time packet shows the first was whole; its gyro closes it.
    let second = encode(&wit_cycle(1, false));
    let got: Vec<i16> = decode_all(&mut d, &second).iter().map(cycle_of).collect();
    assert_eq!(got, [0, 1]);
    // From now on: exactly one cycle's bytes give its sample, not a byte earlier.
    for k in 2..5 {
        let bytes = encode(&wit_cycle(k, false));
        let (head, last) = bytes.split_at(bytes.len() - 1);
        assert!(
            decode_all(&mut d, head).is_empty(),
            "cycle {k} before its last byte"
        );
        let got: Vec<i16> = decode_all(&mut d, last).iter().map(cycle_of).collect();
        assert_eq!(got, [k], "cycle {k} on its last byte");
    }
    assert!(d.finish().is_none());
    assert_eq!(d.stats().frames_malformed, 0);
}

#[test]
fn gyro_only_cycle_is_learned_and_emitted_per_packet() {
    let packets: Vec<WitPacket> = (0..4)
        .map(|k| WitPacket::Gyro {
            raw: [k, 0, 0],
            temp_raw: 0,
        })
        .collect();
    let mut d = WitImuDecoder::new();
    let mut counts = Vec::new();
    for p in &packets {
        counts.push(decode_all(&mut d, &encode(&[*p])).len());
    }
    // The second packet completes the first (learning) and itself.
    assert_eq!(counts, [0, 2, 1, 1]);
}

#[test]
fn changed_packet_set_is_relearned_without_partial_samples() {
    // Cycles 0..4 with a magnetometer packet (closing type 0x54), then the device is
    // reconfigured without it: cycles 4..10 close on the gyro packet.
    let mut packets = Vec::new();
    let mut closing_index = Vec::new();
    for k in 0..10 {
        packets.extend(wit_cycle(k, k < 4));
        closing_index.push(packets.len() - 1);
    }
    let (emitted, d) = emitted_at(&packets);
    let cycles: Vec<i16> = emitted.iter().map(|(k, _)| *k).collect();
    // Cycle 4 lacks the learned closing packet when cycle 5's time packet repeats a type:
    // as for a lost packet it is dropped, not emitted as whole. Cycle 5 relearns the set
    // (emitted when cycle 6 starts); from cycle 6 on, samples close on the gyro packet.
    assert_eq!(cycles, [0, 1, 2, 3, 5, 6, 7, 8, 9]);
    for &(k, at) in &emitted {
        let k = k as usize;
        if k != 0 && k != 5 {
            assert_eq!(at, closing_index[k], "cycle {k} on its closing packet");
        }
    }
    assert_eq!(d.stats().frames_malformed, 1);
}

#[test]
fn lost_packet_drops_only_its_cycle() {
    for lost_part in 0..3 {
        let mut packets = Vec::new();
        let mut closing_index = Vec::new();
        for k in 0..8 {
            let mut cycle = wit_cycle(k, false);
            if k == 3 {
                cycle.remove(lost_part);
            }
            packets.extend(cycle);
            closing_index.push(packets.len() - 1);
        }
        let (emitted, d) = emitted_at(&packets);
        let cycles: Vec<i16> = emitted.iter().map(|(k, _)| *k).collect();
        assert_eq!(cycles, [0, 1, 2, 4, 5, 6, 7], "lost part {lost_part}");
        assert_eq!(d.stats().frames_malformed, 1, "lost part {lost_part}");
        // Relearned on cycle 4 (emitted when cycle 5 starts), on time again from cycle 5.
        for &(k, at) in &emitted[4..] {
            assert_eq!(
                at, closing_index[k as usize],
                "lost part {lost_part}, cycle {k}"
            );
        }
    }
}

fn arb_packet() -> impl Strategy<Value = WitPacket> {
    let words = any::<[i16; 3]>();
    prop_oneof![
        (any::<[u8; 6]>(), any::<u16>()).prop_map(|(b, ms)| WitPacket::Time {
            year: b[0],
            month: b[1],
            day: b[2],
            hour: b[3],
            minute: b[4],
            second: b[5],
            millisecond: ms,
        }),
        (words, any::<i16>()).prop_map(|(raw, temp_raw)| WitPacket::Accel { raw, temp_raw }),
        (words, any::<i16>()).prop_map(|(raw, temp_raw)| WitPacket::Gyro { raw, temp_raw }),
        (words, any::<u16>()).prop_map(|(raw, version)| WitPacket::Angle { raw, version }),
        (0x54u8..=0x5F, any::<[u8; 8]>()).prop_map(|(kind, data)| WitPacket::Other { kind, data }),
    ]
}

/// Garbage without the 0x55 header byte, so it cannot start a false packet.
fn arb_garbage() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>().prop_filter("no header", |b| *b != 0x55), 0..6)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn round_trip_with_garbage_and_every_split(
        items in proptest::collection::vec((arb_garbage(), arb_packet()), 0..8),
        tail in arb_garbage(),
    ) {
        let (bytes, expected, garbage_len) = stream_with_garbage(&WitEncoder, &items, &tail);
        let d = assert_every_split(WitDecoder::new, &bytes, &expected);
        let s = d.stats();
        prop_assert_eq!(s.frames_ok, expected.len() as u64);
        prop_assert_eq!(s.checksum_errors, 0);
        prop_assert_eq!(s.bytes_skipped, garbage_len as u64);
    }

    #[test]
    fn arbitrary_bytes_never_panic_and_are_accounted(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let mut d = WitDecoder::new();
        let frames = decode_all(&mut d, &bytes);
        let s = d.stats();
        prop_assert_eq!(s.frames_ok, frames.len() as u64);
        // Every byte is either in a packet, skipped, or (at most 10) still pending.
        let accounted = s.frames_ok * 11 + s.bytes_skipped;
        prop_assert!(accounted <= bytes.len() as u64);
        prop_assert!(bytes.len() as u64 - accounted <= 10);
    }
}
