//! Device bytes made with the drivers' encoders (WitMotion, Xbus, UBX) for the daemon tests
//! and the load benchmark, from test signals that are distinct per device, axis and sample.
#![allow(dead_code)]

use imulab_drivers::codec::ubx::{NavPvt, RawMessage, UbxEncoder, UbxMessage};
use imulab_drivers::codec::witmotion::{WitEncoder, WitPacket};
use imulab_drivers::codec::xbus::{data_id, MtData2, XbusEncoder, XbusMessage, XbusValue};
use imulab_drivers::codec::Encoder;

/// Device `i`'s test signal at sample `seq`: distinct per axis and sample (periodic, so it
/// stays in range at any rate), within every
/// protocol's range (rad/s, m/s², °C).
pub fn gyro_of(i: u64, seq: u64) -> [f64; 3] {
    let t = seq as f64 * 0.01 + i as f64;
    [
        0.3 * t.sin(),
        -0.2 * (1.3 * t).cos(),
        0.05 + 0.001 * (seq % 1000) as f64,
    ]
}
pub fn accel_of(i: u64, seq: u64) -> [f64; 3] {
    let t = seq as f64 * 0.01 + i as f64;
    [
        0.5 * t.cos(),
        0.4 * t.sin(),
        9.80665 - 0.01 * (seq % 1000) as f64,
    ]
}
pub fn temp_of(seq: u64) -> f64 {
    25.0 + 0.01 * (seq % 1000) as f64
}

/// WitMotion: one time, accel and gyro packet per sample; time of day = seq × 10 ms.
pub fn wit_sample(seq: u64) -> Vec<u8> {
    let ms = seq * 10;
    let packets = [
        WitPacket::Time {
            year: 26,
            month: 11,
            day: 23,
            hour: 0,
            minute: (ms / 60_000) as u8,
            second: ((ms / 1000) % 60) as u8,
            millisecond: (ms % 1000) as u16,
        },
        WitPacket::accel_from_si(accel_of(0, seq), temp_of(seq)).unwrap(),
        WitPacket::gyro_from_si(gyro_of(0, seq), temp_of(seq)).unwrap(),
    ];
    let mut out = Vec::new();
    for p in &packets {
        WitEncoder.encode(p, &mut out).unwrap();
    }
    out
}

/// Xbus MTData2 with SampleTimeFine = seq × 100 (10 ms), float32 values.
pub fn xbus_sample(seq: u64) -> Vec<u8> {
    let float = |id: u16| id | data_id::FLOAT32;
    let data = MtData2 {
        packet_counter: Some(seq as u16),
        sample_time_fine: Some((seq * 100) as u32),
        temperature: Some(XbusValue {
            data_id: float(data_id::TEMPERATURE),
            value: temp_of(seq),
        }),
        acceleration: Some(XbusValue {
            data_id: float(data_id::ACCELERATION),
            value: accel_of(1, seq),
        }),
        rate_of_turn: Some(XbusValue {
            data_id: float(data_id::RATE_OF_TURN),
            value: gyro_of(1, seq),
        }),
        ..MtData2::default()
    };
    let mut out = Vec::new();
    XbusEncoder
        .encode(&XbusMessage::MtData2 { bus_id: 0xFF, data }, &mut out)
        .unwrap();
    out
}

/// A u-blox receiver's default output at 10 Hz: NMEA GGA + RMC and UBX NAV-PVT + NAV-EOE
/// interleaved. The NMEA sentences are written here with their checksums (the receiver's
/// text); NAV-PVT comes from the drivers' UBX encoder.
pub fn gnss_cycle(k: u64) -> (Vec<u8>, f64, f64) {
    let lat = 48.1 + k as f64 * 1e-5;
    let lon = 11.5 - k as f64 * 2e-5;
    let ms = 45_000_000 + k * 100; // 12:30:00.0 + k × 100 ms
    let (h, m, s, cs) = (
        ms / 3_600_000,
        (ms / 60_000) % 60,
        (ms / 1000) % 60,
        (ms % 1000) / 10,
    );
    let lat_nmea = format!("{:02}{:08.5}", lat.trunc() as u32, lat.fract() * 60.0);
    let lon_nmea = format!("{:03}{:08.5}", lon.trunc() as u32, lon.fract() * 60.0);
    let sentence = |body: String| {
        let sum = body.bytes().fold(0u8, |a, b| a ^ b);
        format!("${body}*{sum:02X}\r\n").into_bytes()
    };
    let mut out = Vec::new();
    out.extend(sentence(format!(
        "GNGGA,{h:02}{m:02}{s:02}.{cs:02},{lat_nmea},N,{lon_nmea},E,1,12,0.8,500.0,M,47.0,M,,"
    )));
    let pvt = NavPvt {
        itow_ms: 216_000_000 + (k * 100) as u32,
        year: 2026,
        month: 11,
        day: 23,
        hour: h as u8,
        min: m as u8,
        sec: s as u8,
        valid: 0x07,
        t_acc_ns: 20,
        nano_ns: (cs * 10_000_000) as i32,
        fix_type: 3,
        flags: 0x01,
        flags2: 0,
        num_sv: 12,
        lon_deg: lon,
        lat_deg: lat,
        height_m: 547.0,
        height_msl_m: 500.0,
        h_acc_m: 1.5,
        v_acc_m: 2.5,
        vel_n_mps: 0.1,
        vel_e_mps: -0.2,
        vel_d_mps: 0.0,
        ground_speed_mps: 0.2236,
        head_mot_deg: 0.0,
        s_acc_mps: 0.1,
        head_acc_deg: 10.0,
        pdop: 1.2,
        flags3: 0,
        head_veh_deg: Some(0.0),
        mag_dec_deg: Some(0.0),
        mag_acc_deg: Some(0.0),
    };
    UbxEncoder
        .encode(&UbxMessage::NavPvt(pvt), &mut out)
        .unwrap();
    let eoe = RawMessage {
        class: 0x01,
        id: 0x61,
        payload: pvt.itow_ms.to_le_bytes().to_vec(),
    };
    UbxEncoder
        .encode(&UbxMessage::Other(eoe), &mut out)
        .unwrap();
    out.extend(sentence(format!(
        "GNRMC,{h:02}{m:02}{s:02}.{cs:02},A,{lat_nmea},N,{lon_nmea},E,0.43,296.6,231126,,,A"
    )));
    (out, lat, lon)
}
