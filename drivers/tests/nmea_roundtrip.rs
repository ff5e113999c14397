//! Property tests for the NMEA codec: encode → decode is the identity for every sentence
//! type, whether the stream arrives whole, split at every byte boundary, or with garbage
//! between sentences; and arbitrary bytes never panic the decoder or grow its buffer.

use imulab_drivers::codec::nmea::*;
use imulab_drivers::codec::{Decoder, Encoder};
use proptest::prelude::*;

fn decimal(max_int: i64, max_scale: u8) -> impl Strategy<Value = Decimal> {
    (0..=max_scale).prop_flat_map(move |scale| {
        let limit = max_int * 10i64.pow(u32::from(scale));
        (-limit..=limit).prop_map(move |m| Decimal::new(m, scale))
    })
}

fn non_negative(max_int: i64, max_scale: u8) -> impl Strategy<Value = Decimal> {
    decimal(max_int, max_scale).prop_map(|d| Decimal::new(d.mantissa.abs(), d.scale))
}

fn coordinate(max_deg: i64, hemis: [char; 2]) -> impl Strategy<Value = Coordinate> {
    (0..max_deg, 0..60i64, 0..=6u8, any::<u32>(), any::<bool>()).prop_map(
        move |(deg, min, scale, frac, south)| {
            let unit = 10i64.pow(u32::from(scale));
            let mantissa = (deg * 100 + min) * unit + i64::from(frac) % unit;
            Coordinate {
                ddmm: Decimal::new(mantissa, scale),
                hemisphere: if south { hemis[1] } else { hemis[0] },
            }
        },
    )
}

fn time() -> impl Strategy<Value = TimeOfDay> {
    (0..24u8, 0..60u8, 0..60i64, 0..=3u8, any::<u16>()).prop_map(|(hour, minute, s, scale, f)| {
        let unit = 10i64.pow(u32::from(scale));
        TimeOfDay {
            hour,
            minute,
            second: Decimal::new(s * unit + i64::from(f) % unit, scale),
        }
    })
}

fn talker() -> impl Strategy<Value = Talker> {
    prop::sample::select(vec!["GP", "GN", "GL", "GA", "GB", "GQ", "BD"])
        .prop_map(|t| Talker([t.as_bytes()[0], t.as_bytes()[1]]))
}

fn letter() -> impl Strategy<Value = char> {
    prop::sample::select(vec!['A', 'D', 'E', 'N', 'V', 'F', 'R', 'S'])
}

fn gga() -> impl Strategy<Value = NmeaSentence> {
    (
        talker(),
        prop::option::of(time()),
        prop::option::of((coordinate(90, ['N', 'S']), coordinate(180, ['E', 'W']))),
        prop::option::of(0..9u8),
        prop::option::of(0..40u8),
        prop::option::of(non_negative(99, 2)),
        prop::option::of(decimal(9000, 3)),
        prop::option::of(decimal(200, 3)),
        prop::option::of(non_negative(999, 1)),
        prop::option::of(0..1024u16),
    )
        .prop_map(
            |(talker, time, pos, quality, num_sats, hdop, alt, sep, age, station)| {
                NmeaSentence::Gga(Gga {
                    talker,
                    time,
                    lat: pos.map(|p| p.0),
                    lon: pos.map(|p| p.1),
                    quality,
                    num_sats,
                    hdop,
                    alt_msl_m: alt,
                    geoid_sep_m: sep,
                    dgps_age_s: age,
                    dgps_station: station,
                })
            },
        )
}

fn rmc() -> impl Strategy<Value = NmeaSentence> {
    (
        talker(),
        prop::option::of(time()),
        prop::option::of(prop::sample::select(vec!['A', 'V'])),
        prop::option::of((coordinate(90, ['N', 'S']), coordinate(180, ['E', 'W']))),
        prop::option::of(non_negative(999, 3)),
        prop::option::of(non_negative(359, 2)),
        prop::option::of((1980..2080u16, 1..=12u8, 1..=28u8)),
        prop::option::of((non_negative(90, 1), prop::sample::select(vec!['E', 'W']))),
        prop::option::of(letter()),
        prop::option::of(letter()),
    )
        .prop_map(
            |(talker, time, status, pos, speed, track, date, var, mode, nav)| {
                NmeaSentence::Rmc(Rmc {
                    talker,
                    time,
                    status,
                    lat: pos.map(|p| p.0),
                    lon: pos.map(|p| p.1),
                    speed_knots: speed,
                    track_deg: track,
                    date: date.map(|(year, month, day)| Date { year, month, day }),
                    mag_var_deg: var.map(|v| v.0),
                    mag_var_dir: var.map(|v| v.1),
                    // NMEA 4.1 nav status only exists after a mode field.
                    mode: mode.or(nav.map(|_| 'A')),
                    nav_status: nav,
                })
            },
        )
}

fn gsa() -> impl Strategy<Value = NmeaSentence> {
    (
        talker(),
        prop::option::of(prop::sample::select(vec!['M', 'A'])),
        prop::option::of(1..=3u8),
        prop::array::uniform12(prop::option::of(1..400u16)),
        prop::array::uniform3(prop::option::of(non_negative(99, 2))),
        prop::option::of(non_negative(9, 0)),
    )
        .prop_map(|(talker, selection, fix_mode, sat_ids, dops, system_id)| {
            NmeaSentence::Gsa(Gsa {
                talker,
                selection,
                fix_mode,
                sat_ids,
                pdop: dops[0],
                hdop: dops[1],
                vdop: dops[2],
                system_id,
            })
        })
}

fn gsv() -> impl Strategy<Value = NmeaSentence> {
    let sat = (
        1..400u16,
        prop::option::of(decimal(90, 0)),
        prop::option::of(non_negative(359, 0)),
        prop::option::of(non_negative(99, 0)),
    )
        .prop_map(|(prn, elevation_deg, azimuth_deg, snr_dbhz)| SatInView {
            prn,
            elevation_deg,
            azimuth_deg,
            snr_dbhz,
        });
    (
        talker(),
        1..9u8,
        1..9u8,
        prop::option::of(0..99u16),
        prop::array::uniform4(prop::option::of(sat)),
        prop::option::of(prop::sample::select(vec!['1', '7', 'B'])),
    )
        .prop_map(
            |(talker, total_msgs, msg_num, sats_in_view, sats, signal_id)| {
                NmeaSentence::Gsv(Gsv {
                    talker,
                    total_msgs,
                    msg_num,
                    sats_in_view,
                    sats,
                    signal_id,
                })
            },
        )
}

fn others() -> impl Strategy<Value = NmeaSentence> {
    prop_oneof![
        (
            talker(),
            prop::array::uniform4(prop::option::of(non_negative(999, 2))),
            prop::option::of(letter())
        )
            .prop_map(|(talker, v, mode)| NmeaSentence::Vtg(Vtg {
                talker,
                track_true_deg: v[0],
                track_mag_deg: v[1],
                speed_knots: v[2],
                speed_kmh: v[3],
                mode,
            })),
        (
            talker(),
            prop::option::of(time()),
            prop::option::of((1..=31u8, 1..=12u8, 1980..2100u16)),
            prop::option::of((-13..=13i8, 0..60u8))
        )
            .prop_map(|(talker, time, date, zone)| NmeaSentence::Zda(Zda {
                talker,
                time,
                day: date.map(|d| d.0),
                month: date.map(|d| d.1),
                year: date.map(|d| d.2),
                zone_hours: zone.map(|z| z.0),
                zone_minutes: zone.map(|z| z.1),
            })),
        (
            talker(),
            prop::option::of(time()),
            prop::array::uniform7(prop::option::of(non_negative(999, 3)))
        )
            .prop_map(|(talker, time, v)| NmeaSentence::Gst(Gst {
                talker,
                time,
                rms: v[0],
                major_m: v[1],
                minor_m: v[2],
                orientation_deg: v[3],
                lat_sigma_m: v[4],
                lon_sigma_m: v[5],
                alt_sigma_m: v[6],
            })),
        (
            talker(),
            prop::option::of(time()),
            prop::option::of((coordinate(90, ['N', 'S']), coordinate(180, ['E', 'W']))),
            "[ADFNRE]{0,4}",
            prop::option::of(0..40u8),
            prop::array::uniform4(prop::option::of(non_negative(999, 2))),
            prop::option::of(0..1024u16),
            prop::option::of(prop::sample::select(vec!['S', 'C', 'U', 'V']))
        )
            .prop_map(
                |(talker, time, pos, letters, num_sats, v, station, nav_status)| {
                    let mut mode = ModeLetters::default();
                    mode.letters[..letters.len()].copy_from_slice(letters.as_bytes());
                    mode.len = letters.len() as u8;
                    NmeaSentence::Gns(Gns {
                        talker,
                        time,
                        lat: pos.map(|p| p.0),
                        lon: pos.map(|p| p.1),
                        mode,
                        num_sats,
                        hdop: v[0],
                        alt_msl_m: v[1],
                        geoid_sep_m: v[2],
                        dgps_age_s: v[3],
                        dgps_station: station,
                        nav_status,
                    })
                }
            ),
        (talker(), prop::option::of(non_negative(359, 3))).prop_map(|(talker, heading_deg)| {
            NmeaSentence::Hdt(Hdt {
                talker,
                heading_deg,
            })
        }),
        (
            talker(),
            prop::option::of((coordinate(90, ['N', 'S']), coordinate(180, ['E', 'W']))),
            prop::option::of(time()),
            prop::option::of(prop::sample::select(vec!['A', 'V'])),
            prop::option::of(letter())
        )
            .prop_map(|(talker, pos, time, status, mode)| NmeaSentence::Gll(Gll {
                talker,
                lat: pos.map(|p| p.0),
                lon: pos.map(|p| p.1),
                time,
                status,
                mode,
            })),
        "[A-Z]{4},[ \"#%-)+-~]{0,60}".prop_map(|body| NmeaSentence::Proprietary(RawSentence {
            start: '$',
            body: format!("P{body}"),
        })),
        "[A-OQ-Z][A-Z]TXT,[ \"#%-)+-~]{0,40}"
            .prop_map(|body| NmeaSentence::Other(RawSentence { start: '$', body })),
    ]
}

fn sentence() -> impl Strategy<Value = NmeaSentence> {
    prop_oneof![gga(), rmc(), gsa(), gsv(), others()]
}

/// Garbage that cannot start a sentence.
fn garbage() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        any::<u8>().prop_filter("no start", |b| *b != b'$' && *b != b'!'),
        0..20,
    )
}

fn decode_chunks(chunks: &[&[u8]]) -> (Vec<NmeaSentence>, imulab_drivers::DecoderStats) {
    let mut decoder = NmeaDecoder::new();
    let mut frames = Vec::new();
    for chunk in chunks {
        decoder.decode(chunk, |f| frames.push(f));
    }
    (frames, decoder.stats())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn encode_decode_identity_whole_split_and_with_garbage(
        items in prop::collection::vec((sentence(), garbage()), 1..6)
    ) {
        let mut clean = Vec::new();
        let mut dirty = Vec::new();
        let mut garbage_bytes = 0u64;
        let mut sentences = Vec::new();
        for (s, junk) in &items {
            let mut one = Vec::new();
            NmeaEncoder.encode(s, &mut one).map_err(|e| TestCaseError::fail(e.to_string()))?;
            clean.extend_from_slice(&one);
            dirty.extend_from_slice(&one);
            dirty.extend_from_slice(junk);
            garbage_bytes += junk.iter().filter(|&&b| b != b'\r' && b != b'\n').count() as u64;
            sentences.push(s.clone());
        }

        let (frames, stats) = decode_chunks(&[&clean]);
        prop_assert_eq!(&frames, &sentences);
        prop_assert_eq!(stats.frames_ok, sentences.len() as u64);
        prop_assert_eq!(stats.checksum_errors + stats.frames_malformed + stats.frames_too_long, 0);

        for split in 0..=clean.len() {
            let (frames, _) = decode_chunks(&[&clean[..split], &clean[split..]]);
            prop_assert_eq!(&frames, &sentences, "split at {}", split);
        }

        let (frames, stats) = decode_chunks(&[&dirty]);
        prop_assert_eq!(&frames, &sentences);
        // Junk right after a sentence's checksum is skipped byte for byte.
        prop_assert_eq!(stats.bytes_skipped, garbage_bytes);
    }

    #[test]
    fn arbitrary_bytes_never_panic_and_buffer_stays_bounded(
        chunks in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..300), 0..20)
    ) {
        let mut decoder = NmeaDecoder::new();
        for chunk in &chunks {
            decoder.decode(chunk, |_| {});
            // After polling, only one unfinished sentence may remain buffered.
            prop_assert!(decoder.buffered_len() < MAX_PROPRIETARY_LEN);
        }
        let stats = decoder.stats();
        let total: usize = chunks.iter().map(Vec::len).sum();
        prop_assert!(stats.bytes_skipped as usize <= total);
    }
}
