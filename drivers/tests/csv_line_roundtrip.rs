//! CSV line codec: column maps, scales, separators and comments; bad-line rules; round trips
//! with splits at every byte boundary and junk lines between samples.

mod imucan_support;

use imucan_support::{assert_every_split, decode_all};
use imulab_drivers::codec::csv_line::{CsvColumn, CsvLineConfig, CsvLineDecoder, CsvLineEncoder};
use imulab_drivers::codec::{Decoder, Encoder};
use imulab_drivers::ImuSample;
use proptest::prelude::*;

#[test]
fn default_layout_decodes_with_comments_and_crlf() {
    let text = b"# time,gx,gy,gz,ax,ay,az,temp\r\n\
                 0.01,0.1,-0.2,0.3,0.0,0.0,9.81,24.5\r\n\
                 \n\
                 0.02, 0.1 ,-0.2,0.3,0.0,0.0,9.81,24.5,extra,fields\n";
    let mut d = CsvLineDecoder::new(CsvLineConfig::default()).expect("valid");
    let samples = decode_all(&mut d, text);
    assert_eq!(samples.len(), 2);
    assert_eq!(samples[0].sensor_time, Some(0.01));
    assert_eq!(samples[0].gyro, Some([0.1, -0.2, 0.3]));
    assert_eq!(samples[1].accel, Some([0.0, 0.0, 9.81]));
    assert_eq!(samples[1].temp_c, Some(24.5));
    assert_eq!(d.stats().frames_malformed, 0);
}

#[test]
fn toml_config_with_scales_offsets_and_status() {
    let config: CsvLineConfig = toml::from_str(
        r#"
        separator = ";"
        comment_prefix = "//"
        time = { index = 0, scale = 1e-6 }
        gyro = [ { index = 3, scale = 0.0174532925199432957 },
                 { index = 4, scale = 0.0174532925199432957 },
                 { index = 5, scale = 0.0174532925199432957 } ]
        accel = [ { index = 6, scale = 0.001 }, { index = 7, scale = 0.001 }, { index = 8, scale = 0.001 } ]
        temp = { index = 1, scale = 0.01, offset = -40.0 }
        status = 2
        "#,
    )
    .expect("valid TOML");
    let mut d = CsvLineDecoder::new(config.clone()).expect("valid");
    let samples = decode_all(&mut d, b"// header\n1500000;6500;0x1F;90;0;-180;0;0;9807\n");
    assert_eq!(samples.len(), 1, "{:?}", d.stats());
    let s = samples[0];
    assert_eq!(s.sensor_time, Some(1.5));
    assert_eq!(s.temp_c, Some(25.0));
    assert_eq!(s.status, 0x1F);
    let g = s.gyro.expect("gyro");
    assert!((g[0] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    assert!((g[2] + std::f64::consts::PI).abs() < 1e-12);
    assert!((s.accel.expect("accel")[2] - 9.807).abs() < 1e-12);
    // Unknown keys are rejected with the key name.
    let err = toml::from_str::<CsvLineConfig>("separatr = \",\"").expect_err("typo");
    assert!(err.to_string().contains("separatr"), "{err}");
}

#[test]
fn bad_lines_follow_the_documented_rules() {
    let config = CsvLineConfig {
        max_line_len: 64,
        ..CsvLineConfig::default()
    };
    let mut d = CsvLineDecoder::new(config).expect("valid");
    let mut text = Vec::new();
    text.extend_from_slice(b"time,gx,gy,gz,ax,ay,az,temp\n"); // header not commented
    text.extend_from_slice(b"0.1,NaN,0,0,0,0,9.8,20\n"); // not finite
    text.extend_from_slice(b"0.1,1,2\n"); // too few fields
    text.extend_from_slice(b"0.1,\xff\xfe,0,0,0,0,9.8,20\n"); // not UTF-8
    text.extend_from_slice(&[b'7'; 200]); // over-long line
    text.push(b'\n');
    text.extend_from_slice(b"0.2,0,0,0,0,0,9.8,20\n");
    let samples = decode_all(&mut d, &text);
    assert_eq!(samples.len(), 1);
    assert_eq!(samples[0].sensor_time, Some(0.2));
    let s = d.stats();
    assert_eq!(s.frames_malformed, 4);
    assert_eq!(s.frames_too_long, 1);
    assert_eq!(s.frames_ok, 1);
    // An unterminated over-long line is cut off without growing the buffer without bound.
    let mut d = CsvLineDecoder::new(CsvLineConfig {
        max_line_len: 64,
        ..CsvLineConfig::default()
    })
    .expect("valid");
    for _ in 0..1000 {
        d.push(&[b'1'; 100]);
        assert!(d.poll().is_none());
    }
    d.push(b"\n0,0,0,0,0,0,0,0\n");
    assert!(d.poll().is_some());
    assert_eq!(d.stats().frames_too_long, 1);
}

#[test]
fn invalid_configs_name_the_key() {
    let dup = CsvLineConfig {
        temp: Some(CsvColumn::at(1)),
        ..CsvLineConfig::default()
    };
    assert!(CsvLineDecoder::new(dup)
        .expect_err("duplicate")
        .contains("same column"));
    let zero = CsvLineConfig {
        time: Some(CsvColumn::scaled(0, 0.0)),
        ..CsvLineConfig::default()
    };
    assert!(CsvLineDecoder::new(zero)
        .expect_err("zero scale")
        .contains("csv.time"));
}

#[test]
fn whitespace_separated_with_unmapped_columns() {
    let config = CsvLineConfig {
        separator: ' ',
        time: None,
        gyro: Some([CsvColumn::at(2), CsvColumn::at(3), CsvColumn::at(4)]),
        accel: None,
        temp: None,
        ..CsvLineConfig::default()
    };
    let sample = ImuSample {
        gyro: Some([0.5, -0.25, 1e-9]),
        ..ImuSample::default()
    };
    let mut line = Vec::new();
    CsvLineEncoder::new(config.clone())
        .expect("valid")
        .encode(&sample, &mut line)
        .expect("encodable");
    assert_eq!(line, b"0 0 0.5 -0.25 1e-9\n");
    let mut d = CsvLineDecoder::new(config).expect("valid");
    assert_eq!(
        decode_all(&mut d, b"  17   x  0.5\t-0.25   1e-9 \n"),
        vec![sample]
    );
}

fn finite() -> impl Strategy<Value = f64> {
    any::<f64>().prop_filter("finite", |v| v.is_finite())
}

fn arb_sample() -> impl Strategy<Value = ImuSample> {
    (
        finite(),
        [finite(), finite(), finite()],
        [finite(), finite(), finite()],
        finite(),
        any::<u32>(),
    )
        .prop_map(|(t, g, a, temp, status)| ImuSample {
            sensor_time: Some(t),
            gyro: Some(g),
            accel: Some(a),
            temp_c: Some(temp),
            status,
        })
}

fn arb_junk_line() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        "[a-z ,]{0,20}".prop_map(|s| format!("{s}\n").into_bytes()),
        "[a-z ,]{0,20}".prop_map(|s| format!("# {s}\n").into_bytes()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn round_trip_with_junk_lines_and_every_split(
        items in proptest::collection::vec((proptest::option::of(arb_junk_line()), arb_sample()), 0..4),
        status_col in any::<bool>(),
    ) {
        let config = CsvLineConfig {
            separator: ';',
            status: status_col.then_some(8),
            time: Some(CsvColumn::scaled(0, 0.5)),
            ..CsvLineConfig::default()
        };
        let encoder = CsvLineEncoder::new(config.clone()).expect("valid");
        let mut bytes = Vec::new();
        let mut expected = Vec::new();
        for (junk, sample) in &items {
            if let Some(j) = junk {
                bytes.extend_from_slice(j);
            }
            // Halving then doubling is exact unless it overflows or underflows.
            let mut sample = *sample;
            if !status_col {
                sample.status = 0;
            }
            if (sample.sensor_time.unwrap_or(0.0) / 0.5 * 0.5) != sample.sensor_time.unwrap_or(0.0) {
                continue;
            }
            encoder.encode(&sample, &mut bytes).expect("encodable");
            expected.push(sample);
        }
        assert_every_split(|| CsvLineDecoder::new(config.clone()).expect("valid"), &bytes, &expected);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let mut d = CsvLineDecoder::new(CsvLineConfig::default()).expect("valid");
        let frames = decode_all(&mut d, &bytes);
        prop_assert_eq!(d.stats().frames_ok, frames.len() as u64);
    }
}
