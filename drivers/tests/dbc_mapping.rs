//! IMU over CAN via DBC: the fixture DBC and mapping resolve; hand-computed frames
//! (Intel and Motorola order, signed values, extended id) decode to the right SI values;
//! samples encode back to frames and decode within one LSB; bad mappings give clear errors.

use imulab_drivers::codec::can::CanFrame;
use imulab_drivers::codec::dbc::{DbcImu, DbcImuMapping};
use imulab_drivers::ImuSample;
use proptest::prelude::*;

fn fixture(name: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures")
        .join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn fixture_imu() -> DbcImu {
    let mapping = DbcImuMapping::from_toml_str(&fixture("imu_can_mapping.toml")).expect("mapping");
    DbcImu::new(&fixture("imu_can.dbc"), &mapping).expect("resolves")
}

const G: f64 = 9.806_65;

#[test]
fn hand_computed_frames_decode_to_si() {
    let mut imu = fixture_imu();
    // RateX = 1000 counts = 10 °/s, RateY = -250 = -2.5 °/s, RateZ = 0; status 0x05.
    let rate =
        CanFrame::data(0x180, false, &[0xE8, 0x03, 0x06, 0xFF, 0, 0, 7, 0x05]).expect("valid");
    // AccZ = 2000 counts = 1 g; Temp (Motorola, bytes 6..7 big-endian) = 0x047E = 1150
    // -> 1150 * 0.01 + 25 = 36.5 °C.
    let accel = CanFrame::data(0x181, false, &[0, 0, 0, 0, 0xD0, 0x07, 0x04, 0x7E]).expect("valid");
    // TimeUs = 1_500_000 µs = 0x0016E360, little-endian.
    let time = CanFrame::data(0x18FF_1200, true, &[0x60, 0xE3, 0x16, 0x00]).expect("valid");
    let other = CanFrame::data(0x123, false, &[1, 2, 3]).expect("valid");
    for f in [&rate, &accel, &other] {
        assert!(imu.push_frame(f).is_none());
    }
    assert_eq!(imu.frames_ignored(), 1);
    // The frame that closes the mapped message set completes the sample, not the next
    // cycle's first frame.
    let sample = imu.push_frame(&time).expect("sample complete");
    let g = sample.gyro.expect("gyro");
    assert!((g[0] - 10f64.to_radians()).abs() < 1e-12);
    assert!((g[1] + 2.5f64.to_radians()).abs() < 1e-12);
    assert_eq!(g[2], 0.0);
    let a = sample.accel.expect("accel");
    assert!((a[2] - G).abs() < 1e-12, "{a:?}");
    assert!((sample.temp_c.expect("temp") - 36.5).abs() < 1e-12);
    assert!((sample.sensor_time.expect("time") - 1.5).abs() < 1e-12);
    assert_eq!(sample.status, 5);
    // Negative Motorola value: -10 °C -> raw -3500 = 0xF254.
    let cold = CanFrame::data(0x181, false, &[0, 0, 0, 0, 0, 0, 0xF2, 0x54]).expect("valid");
    assert!(imu.push_frame(&rate).is_none(), "a new group starts");
    assert!(imu.push_frame(&cold).is_none());
    // The next rate frame finds the group (time lost) already holding a rate: the partial
    // group comes out then, time absent.
    let s = imu
        .push_frame(&rate)
        .expect("partial group ended by a repeat");
    assert_eq!(s.sensor_time, None);
    assert!((s.temp_c.expect("temp") + 10.0).abs() < 1e-12);
    // A mapped frame that is too short is counted, not decoded.
    imu.push_frame(&CanFrame::data(0x180, false, &[1, 2]).expect("valid"));
    assert_eq!(imu.stats().frames_malformed, 1);
}

#[test]
fn mapping_scale_offset_and_unit_override() {
    let mapping = DbcImuMapping::from_toml_str(
        r#"
        gyro = [ { message = "IMU_Rate", signal = "RateX", scale = -1.0 },
                 { message = "IMU_Rate", signal = "RateY" },
                 { message = "IMU_Rate", signal = "RateZ", unit = "rad/s", scale = 0.001 } ]
        "#,
    )
    .expect("mapping");
    let mut imu = DbcImu::new(&fixture("imu_can.dbc"), &mapping).expect("resolves");
    // One mapped message: each frame of it is a whole sample.
    let s = imu
        .push_frame(
            &CanFrame::data(0x180, false, &[0xE8, 0x03, 0, 0, 0xE8, 0x03, 0, 0]).expect("valid"),
        )
        .expect("sample");
    let g = s.gyro.expect("gyro");
    assert!(
        (g[0] + 10f64.to_radians()).abs() < 1e-12,
        "sign flipped by scale"
    );
    assert!((g[2] - 0.01).abs() < 1e-15, "1000 * 0.01 * 0.001 rad/s");
    assert!(s.accel.is_none());
}

#[test]
fn bad_mappings_give_clear_errors() {
    let dbc = fixture("imu_can.dbc");
    let err = |toml: &str| {
        let mapping = DbcImuMapping::from_toml_str(toml).expect("toml");
        DbcImu::new(&dbc, &mapping).expect_err("must fail")
    };
    let e = err(r#"temp = { message = "IMU_Nope", signal = "Temp" }"#);
    assert!(e.contains("temp") && e.contains("IMU_Nope"), "{e}");
    let e = err(r#"temp = { message = "IMU_Accel", signal = "Tmp" }"#);
    assert!(e.contains("Tmp"), "{e}");
    let e = err(r#"temp = { message = "IMU_Accel", signal = "AccX" }"#);
    assert!(e.contains("unit") && e.contains("\"g\""), "{e}");
    let e = err(
        r#"gyro = [ { message = "IMU_Rate", signal = "RateCounter" },
                    { message = "IMU_Rate", signal = "RateY" },
                    { message = "IMU_Rate", signal = "RateZ" } ]"#,
    );
    assert!(e.contains("gyro[0]") && e.contains("no unit"), "{e}");
    assert!(DbcImuMapping::from_toml_str("gyros = []")
        .expect_err("unknown key")
        .contains("gyros"));
    assert!(DbcImu::new("BO_ garbage", &DbcImuMapping::default()).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn encode_then_decode_is_within_one_lsb(
        g in proptest::array::uniform3(-5.0f64..5.0),
        a in proptest::array::uniform3(-150.0f64..150.0),
        temp in -40.0f64..85.0,
        t in 0.0f64..4000.0,
        status in 0u32..256,
    ) {
        let mut imu = fixture_imu();
        let sample = ImuSample { sensor_time: Some(t), gyro: Some(g), accel: Some(a), temp_c: Some(temp), status };
        let frames = imu.encode(&sample).expect("in range");
        prop_assert_eq!(frames.len(), 3);
        let (last, first) = frames.split_last().expect("three frames");
        for f in first {
            prop_assert!(imu.push_frame(f).is_none());
        }
        let back = imu.push_frame(last).expect("the last frame completes the sample");
        prop_assert!(imu.finish().is_none(), "nothing held after a complete sample");
        let gyro_lsb = 0.01f64.to_radians();
        for i in 0..3 {
            prop_assert!((back.gyro.expect("gyro")[i] - g[i]).abs() <= gyro_lsb / 2.0 + 1e-12);
            prop_assert!((back.accel.expect("accel")[i] - a[i]).abs() <= 0.0005 * G / 2.0 + 1e-12);
        }
        prop_assert!((back.temp_c.expect("temp") - temp).abs() <= 0.005 + 1e-9);
        prop_assert!((back.sensor_time.expect("time") - t).abs() <= 0.5e-6 + 1e-9);
        prop_assert_eq!(back.status, status);
    }
}

#[test]
fn encoder_rejects_out_of_range() {
    let imu = fixture_imu();
    let sample = ImuSample {
        sensor_time: Some(0.0),
        gyro: Some([10.0, 0.0, 0.0]), // 573 °/s > 327.67 °/s full scale
        accel: Some([0.0; 3]),
        temp_c: Some(20.0),
        status: 0,
    };
    assert!(imu.encode(&sample).is_err());
    assert!(imu
        .encode(&ImuSample {
            gyro: None,
            ..sample
        })
        .is_err());
}
