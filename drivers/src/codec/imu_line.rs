//! `$IMU` lines: the NMEA 0183-style ASCII line a microcontroller IMU prints once per
//! sample, `$IMU,<t>,<gx>,<gy>,<gz>,<ax>,<ay>,<az>[,<temp>]*HH` and CR LF.
//!
//! `t` is the device clock in seconds, the rates rad/s, the specific forces m/s², the
//! optional temperature °C. A triad the device does not measure is three empty fields.
//! `HH` is the NMEA checksum: the XOR of every byte between `$` and `*`, two hex digits.
//! Numbers are plain decimals (`-0.0123`, `9.80665`, exponents allowed); the encoder writes
//! the shortest form that reads back to the same `f64`, so a sample survives the round trip
//! exactly.
//!
//! Framing follows the shared resync rule (`codec::StreamBuffer`): a line starts at `$` and
//! ends after its checksum; CR and LF between lines are framing; anything else outside a
//! line is skipped. A line with a bad checksum is a checksum error; a checksummed line that
//! is not an `$IMU` line, or whose fields do not parse, is malformed (dropped, the decoder
//! stays in sync).

use super::reading::DeviceClock;
use super::{accepted_frames, Decoder, EncodeError, Encoder, Reject, Scan, StreamBuffer};
use crate::types::{DecoderStats, ImuSample};

/// The address of the line, after `$`.
const ADDRESS: &[u8] = b"IMU,";
/// Longest line from `$` to the checksum digits: 8 fields of up to 24 characters.
pub const MAX_LINE_LEN: usize = 220;

/// Streaming decoder of `$IMU` lines into [`ImuSample`]s.
#[derive(Debug, Clone)]
pub struct ImuLineDecoder {
    buf: StreamBuffer,
}

impl Default for ImuLineDecoder {
    fn default() -> Self {
        ImuLineDecoder {
            buf: StreamBuffer::text(),
        }
    }
}

impl ImuLineDecoder {
    pub fn new() -> Self {
        Self::default()
    }
}

impl Decoder for ImuLineDecoder {
    type Frame = ImuSample;

    fn push(&mut self, bytes: &[u8]) {
        self.buf.push(bytes);
    }

    fn poll(&mut self) -> Option<ImuSample> {
        self.buf.next_scanned(b"$", scan_line)
    }

    fn stats(&self) -> DecoderStats {
        self.buf.stats()
    }
}

fn hex_digit(b: u8) -> Option<u8> {
    (b as char).to_digit(16).map(|d| d as u8)
}

/// Frames one line at the front of `buf` (which starts with `$`).
fn scan_line(buf: &[u8]) -> Scan<ImuSample> {
    let region = &buf[1..buf.len().min(MAX_LINE_LEN - 2)];
    let star = region.iter().position(|&b| b == b'*');
    let body = &region[..star.unwrap_or(region.len())];
    // A control byte or a new `$` before the star: not a line (noise, or a line cut short).
    if let Some(at) = body
        .iter()
        .position(|&b| !(0x20..0x7f).contains(&b) || b == b'$')
    {
        return Scan::Reject {
            len: 1 + at,
            reject: Reject::Malformed,
        };
    }
    let Some(star) = star else {
        return if buf.len() < MAX_LINE_LEN - 2 {
            Scan::Incomplete
        } else {
            Scan::Reject {
                len: 1,
                reject: Reject::TooLong,
            }
        };
    };
    let i = 1 + star;
    if buf.len() < i + 3 {
        return Scan::Incomplete;
    }
    let len = i + 3;
    let Some(given) = hex_digit(buf[i + 1]).zip(hex_digit(buf[i + 2])) else {
        return Scan::Reject {
            len: i + 1,
            reject: Reject::Malformed,
        };
    };
    if (given.0 << 4 | given.1) != checksum(body) {
        return Scan::Reject {
            len,
            reject: Reject::Checksum,
        };
    }
    match body.strip_prefix(ADDRESS).and_then(parse_fields) {
        Some(frame) => Scan::Frame { len, frame },
        None => Scan::Reject {
            len,
            reject: Reject::BadContent,
        },
    }
}

fn checksum(body: &[u8]) -> u8 {
    body.iter().fold(0, |acc, &b| acc ^ b)
}

/// `t,gx,gy,gz,ax,ay,az[,temp]`.
fn parse_fields(fields: &[u8]) -> Option<ImuSample> {
    let text = std::str::from_utf8(fields).ok()?;
    let values: Vec<&str> = text.split(',').collect();
    if !(7..=8).contains(&values.len()) {
        return None;
    }
    let number = |s: &str| -> Option<f64> { s.parse::<f64>().ok().filter(|v| v.is_finite()) };
    let triad = |s: &[&str]| -> Option<Option<[f64; 3]>> {
        if s.iter().all(|f| f.is_empty()) {
            return Some(None);
        }
        Some(Some([number(s[0])?, number(s[1])?, number(s[2])?]))
    };
    let gyro = triad(&values[1..4])?;
    let accel = triad(&values[4..7])?;
    if gyro.is_none() && accel.is_none() {
        return None;
    }
    let temp_c = match values.get(7) {
        None | Some(&"") => None,
        Some(t) => Some(number(t)?),
    };
    Some(ImuSample {
        sensor_time: Some(number(values[0])?),
        gyro,
        accel,
        temp_c,
        status: 0,
    })
}

/// Writes samples as `$IMU` lines. The sample needs its `sensor_time` and at least one
/// triad; every value must be finite.
#[derive(Debug, Default, Clone, Copy)]
pub struct ImuLineEncoder;

impl Encoder for ImuLineEncoder {
    type Frame = ImuSample;

    fn encode(&self, sample: &ImuSample, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        use std::fmt::Write;
        let finite = |field: &'static str, v: f64| {
            if v.is_finite() {
                Ok(v)
            } else {
                Err(EncodeError::OutOfRange { field, value: v })
            }
        };
        let t = sample.sensor_time.ok_or(EncodeError::Invalid {
            field: "sensor_time",
            reason: "an $IMU line starts with the device time",
        })?;
        if sample.gyro.is_none() && sample.accel.is_none() {
            return Err(EncodeError::Invalid {
                field: "gyro",
                reason: "an $IMU line carries at least one triad",
            });
        }
        // Writing into a String cannot fail.
        let mut body = String::from("IMU,");
        let _ = write!(body, "{}", finite("sensor_time", t)?);
        for (field, triad) in [("gyro", sample.gyro), ("accel", sample.accel)] {
            match triad {
                Some(v) => {
                    for x in v {
                        let _ = write!(body, ",{}", finite(field, x)?);
                    }
                }
                None => body.push_str(",,,"),
            }
        }
        if let Some(temp) = sample.temp_c {
            let _ = write!(body, ",{}", finite("temp_c", temp)?);
        }
        if body.len() + 4 > MAX_LINE_LEN {
            return Err(EncodeError::TooLong {
                len: body.len() + 4,
                max: MAX_LINE_LEN,
            });
        }
        out.push(b'$');
        out.extend_from_slice(body.as_bytes());
        out.extend_from_slice(format!("*{:02X}\r\n", checksum(body.as_bytes())).as_bytes());
        Ok(())
    }
}

/// The line a device prints for one sample: the clock's time in the time field.
pub fn encode_sample(
    sample: &ImuSample,
    clock: &DeviceClock,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let sample = ImuSample {
        sensor_time: Some(clock.time_s),
        ..*sample
    };
    ImuLineEncoder.encode(&sample, out)
}

/// Auto-detection score: checksummed `$IMU` lines in `sample`.
pub fn detect_score(sample: &[u8]) -> u32 {
    accepted_frames(ImuLineDecoder::new(), sample)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn line(body: &str) -> Vec<u8> {
        format!("${body}*{:02X}\r\n", checksum(body.as_bytes())).into_bytes()
    }

    fn decode_all(bytes: &[u8]) -> (Vec<ImuSample>, DecoderStats) {
        let mut d = ImuLineDecoder::new();
        let mut out = Vec::new();
        d.decode(bytes, |s| out.push(s));
        (out, d.stats())
    }

    #[test]
    fn decodes_a_line_with_and_without_temperature_and_triads() {
        let bytes = [
            line("IMU,12.5,0.01,-0.02,0.03,0.1,-0.2,9.81,24.5"),
            line("IMU,12.51,,,,0.1,-0.2,9.81"),
        ]
        .concat();
        let (samples, stats) = decode_all(&bytes);
        assert_eq!(stats.frames_ok, 2, "{stats:?}");
        assert_eq!(stats.bytes_skipped, 0);
        assert_eq!(samples[0].sensor_time, Some(12.5));
        assert_eq!(samples[0].gyro, Some([0.01, -0.02, 0.03]));
        assert_eq!(samples[0].accel, Some([0.1, -0.2, 9.81]));
        assert_eq!(samples[0].temp_c, Some(24.5));
        assert_eq!(samples[1].gyro, None);
        assert_eq!(samples[1].temp_c, None);
    }

    #[test]
    fn bad_checksum_other_sentences_and_noise_are_counted() {
        let good = line("IMU,1,0,0,0,0,0,9.8");
        let mut bad = good.clone();
        bad[5] = b'2';
        let gga = line("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,");
        let short = line("IMU,1,0,0");
        let stream = [&b"\x00\xffnoise"[..], &good, &bad, &gga, &short, &good].concat();
        let (samples, stats) = decode_all(&stream);
        assert_eq!(samples.len(), 2);
        assert_eq!(stats.checksum_errors, 1);
        assert_eq!(stats.frames_malformed, 2, "{stats:?}");
        // Every byte split gives the same counts.
        for split in 0..=stream.len() {
            let mut d = ImuLineDecoder::new();
            let mut n = 0;
            d.decode(&stream[..split], |_| n += 1);
            d.decode(&stream[split..], |_| n += 1);
            assert_eq!((n, d.stats()), (2, stats), "split at {split}");
        }
    }

    #[test]
    fn a_line_without_end_is_too_long_and_the_next_line_decodes() {
        let mut stream = b"$IMU,".to_vec();
        stream.extend(std::iter::repeat_n(b'1', 400));
        stream.extend(line("IMU,1,0,0,0,0,0,9.8"));
        let (samples, stats) = decode_all(&stream);
        assert_eq!(samples.len(), 1);
        assert!(stats.frames_too_long >= 1, "{stats:?}");
    }

    #[test]
    fn detected_from_its_own_lines_only() {
        let lines: Vec<u8> = (0..20)
            .flat_map(|k| line(&format!("IMU,{k},0.1,0.2,0.3,0,0,9.8")))
            .collect();
        assert_eq!(
            super::super::detect(&lines),
            Some(super::super::Protocol::ImuLine)
        );
        let gga = line("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,");
        assert_eq!(detect_score(&gga.repeat(20)), 0);
    }

    fn triad() -> impl Strategy<Value = Option<[f64; 3]>> {
        proptest::option::of(proptest::array::uniform3(-1e6f64..1e6))
    }

    proptest! {
        #[test]
        fn samples_round_trip_exactly(
            t in 0.0f64..1e7,
            gyro in triad(),
            accel in proptest::array::uniform3(-1e3f64..1e3),
            temp in proptest::option::of(-60.0f64..150.0),
        ) {
            let sample = ImuSample {
                sensor_time: Some(t),
                gyro,
                accel: Some(accel),
                temp_c: temp,
                status: 0,
            };
            let mut bytes = Vec::new();
            ImuLineEncoder.encode(&sample, &mut bytes).unwrap();
            let (samples, stats) = decode_all(&bytes);
            prop_assert_eq!(samples, vec![sample]);
            prop_assert_eq!(stats.bytes_skipped, 0);
        }
    }
}
