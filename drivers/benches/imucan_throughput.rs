//! Decode throughput of the IMU and CAN codecs on one core: MB/s and frames/s for a long
//! synthetic stream fed in 4 KiB chunks (as a serial read loop would). Run with
//! `cargo bench -p imulab-drivers --bench imucan_throughput` (release profile).
//!
//! Rates are computed from the thread's CPU time (CLOCK_THREAD_CPUTIME_ID), so they measure
//! one core's throughput even on a loaded machine; wall-clock rates are printed beside them.

#[path = "../../benches/support/results.rs"]
mod results;

/// A codec's name, MB in, frames, frames expected, MB/s of CPU and MB/s of wall.
type Measured = (String, f64, usize, usize, f64, f64);

/// Every codec's figures as printed.
static MEASURED: std::sync::Mutex<Vec<Measured>> = std::sync::Mutex::new(Vec::new());

use std::hint::black_box;
use std::time::Instant;

use imulab_drivers::codec::can::CanFrame;
use imulab_drivers::codec::candump::{CandumpDecoder, CandumpEncoder, CandumpRecord, IfName};
use imulab_drivers::codec::csv_line::{CsvLineConfig, CsvLineDecoder, CsvLineEncoder};
use imulab_drivers::codec::dbc::{DbcImu, DbcImuMapping, DbcStreamDecoder};
use imulab_drivers::codec::mip::{MipDecoder, MipEncoder, MipGpsTime, MipImuData, MipPacket};
use imulab_drivers::codec::slcan::{SlcanDecoder, SlcanEncoder, SlcanMessage};
use imulab_drivers::codec::vectornav::{
    common, imu, VnAscii, VnAsciiKind, VnBinary, VnChecksum, VnDecoder, VnEncoder, VnFrame,
    VnOutputFields, VnValues,
};
use imulab_drivers::codec::witmotion::{WitDecoder, WitEncoder, WitImuDecoder, WitPacket};
use imulab_drivers::codec::xbus::{MtData2, XbusDecoder, XbusEncoder, XbusMessage, XbusValue};
use imulab_drivers::codec::{Decoder, Encoder};
use imulab_drivers::ImuSample;

const TARGET_BYTES: usize = 64 << 20;
const CHUNK: usize = 4096;
const RUNS: usize = 3;

/// Repeats encoded frames until the stream holds about TARGET_BYTES.
fn stream<F>(frames: &[F], encode: impl Fn(&F, &mut Vec<u8>)) -> (Vec<u8>, usize) {
    let mut one_cycle = Vec::new();
    for f in frames {
        encode(f, &mut one_cycle);
    }
    let repeats = (TARGET_BYTES / one_cycle.len()).max(1);
    (one_cycle.repeat(repeats), frames.len() * repeats)
}

fn thread_cpu_seconds() -> f64 {
    use nix::time::{clock_gettime, ClockId};
    let t = clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID).expect("thread CPU clock");
    t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9
}

/// Best of RUNS: (CPU seconds, wall seconds, frames decoded).
fn measure<D: Decoder>(make: impl Fn() -> D, bytes: &[u8]) -> (f64, f64, usize) {
    let mut best = f64::INFINITY;
    let mut best_wall = f64::INFINITY;
    let mut frames = 0;
    for _ in 0..RUNS {
        let mut decoder = make();
        let mut n = 0usize;
        let start = Instant::now();
        let cpu_start = thread_cpu_seconds();
        for chunk in bytes.chunks(CHUNK) {
            decoder.push(chunk);
            while let Some(frame) = decoder.poll() {
                black_box(&frame);
                n += 1;
            }
        }
        while let Some(frame) = decoder.finish() {
            black_box(&frame);
            n += 1;
        }
        best = best.min(thread_cpu_seconds() - cpu_start);
        best_wall = best_wall.min(start.elapsed().as_secs_f64());
        frames = n;
    }
    (best, best_wall, frames)
}

fn report(
    name: &str,
    bytes: &[u8],
    expected_frames: usize,
    (cpu, wall, frames): (f64, f64, usize),
) {
    MEASURED.lock().expect("measured").push((
        name.to_string(),
        bytes.len() as f64 / 1e6,
        frames,
        expected_frames,
        bytes.len() as f64 / cpu / 1e6,
        bytes.len() as f64 / wall / 1e6,
    ));
    // Assemblers emit one sample per cycle; the other decoders one frame per encoded frame.
    println!(
        "| {name:<28} | {:>6.1} | {:>9} | {:>9} | {:>7.0} | {:>9.2} | {:>7.0} |",
        bytes.len() as f64 / 1e6,
        frames,
        expected_frames,
        bytes.len() as f64 / cpu / 1e6,
        frames as f64 / cpu / 1e6,
        bytes.len() as f64 / wall / 1e6,
    );
}

fn fixture(name: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures")
        .join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn main() {
    println!(
        "| codec | MB in | frames out | expected | MB/s (CPU) | Mframes/s (CPU) | MB/s (wall) |"
    );
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: |");

    // WitMotion: one 100 Hz cycle = time, accel, gyro, angle packets.
    let wit: Vec<WitPacket> = (0..64)
        .flat_map(|i: i16| {
            [
                WitPacket::Time {
                    year: 26,
                    month: 11,
                    day: 23,
                    hour: 14,
                    minute: 0,
                    second: 0,
                    millisecond: i as u16,
                },
                WitPacket::Accel {
                    raw: [i, -i, 2048],
                    temp_raw: 2500,
                },
                WitPacket::Gyro {
                    raw: [3 * i, 0, -i],
                    temp_raw: 2500,
                },
                WitPacket::Angle {
                    raw: [i, i, i],
                    version: 1,
                },
            ]
        })
        .collect();
    let (bytes, n) = stream(&wit, |p, out| WitEncoder.encode(p, out).expect("valid"));
    report(
        "witmotion packets",
        &bytes,
        n,
        measure(WitDecoder::new, &bytes),
    );
    report(
        "witmotion -> ImuSample",
        &bytes,
        n / 4,
        measure(WitImuDecoder::new, &bytes),
    );

    // Xbus MTData2 as an MTi-630 sends at 400 Hz: counter, time, temp, acc, gyro, dq, dv, status.
    let xbus: Vec<XbusMessage> = (0..64u16)
        .map(|i| XbusMessage::MtData2 {
            bus_id: 0xFF,
            data: MtData2 {
                packet_counter: Some(i),
                sample_time_fine: Some(u32::from(i) * 25),
                temperature: Some(XbusValue {
                    data_id: 0x0810,
                    value: 31.5,
                }),
                acceleration: Some(XbusValue {
                    data_id: 0x4020,
                    value: [0.01, -0.02, 9.81],
                }),
                rate_of_turn: Some(XbusValue {
                    data_id: 0x8020,
                    value: [0.001, 0.002, -0.003],
                }),
                delta_q: Some(XbusValue {
                    data_id: 0x8030,
                    value: [1.0, 1e-5, -2e-5, 3e-5],
                }),
                delta_v: Some(XbusValue {
                    data_id: 0x4010,
                    value: [0.0, 0.0, 0.0245],
                }),
                status_word: Some(0x0000_0003),
                skipped_items: 0,
            },
        })
        .collect();
    let (bytes, n) = stream(&xbus, |m, out| XbusEncoder.encode(m, out).expect("valid"));
    report("xbus MTData2", &bytes, n, measure(XbusDecoder::new, &bytes));

    // VectorNav binary output: a bench configuration (Common TimeStartup, AngularRate, Accel,
    // MagPres; IMU UncompGyro, UncompAccel, ImuStatus: 86-byte packets) and the smallest
    // useful one (TimeStartup, AngularRate, Accel: 38 bytes).
    let vn_values = |i: u64| VnValues {
        time_startup_ns: Some(i * 1_250_000),
        angular_rate: Some([0.001, -0.002, i as f32 * 1e-4]),
        accel: Some([0.01, -0.02, -9.81]),
        mag: Some([0.2, 0.01, 0.45]),
        temp_c: Some(31.5),
        pressure_kpa: Some(101.3),
        uncomp_gyro: Some([0.0011, -0.0021, 0.0]),
        uncomp_accel: Some([0.011, -0.021, -9.805]),
        imu_status: Some(0),
        ..VnValues::default()
    };
    let bench_fields = VnOutputFields {
        common: common::TIME_STARTUP | common::ANGULAR_RATE | common::ACCEL | common::MAG_PRES,
        imu: imu::UNCOMP_GYRO | imu::UNCOMP_ACCEL | imu::IMU_STATUS,
        ..VnOutputFields::default()
    };
    let small_fields = VnOutputFields {
        common: common::TIME_STARTUP | common::ANGULAR_RATE | common::ACCEL,
        ..VnOutputFields::default()
    };
    for (name, fields) in [
        ("vectornav binary 86 B", bench_fields),
        ("vectornav binary 38 B", small_fields),
    ] {
        let frames: Vec<VnFrame> = (0..64)
            .map(|i| {
                VnFrame::Binary(VnBinary {
                    fields,
                    values: vn_values(i),
                    skipped_fields: 0,
                })
            })
            .collect();
        let (bytes, n) = stream(&frames, |f, out| VnEncoder.encode(f, out).expect("valid"));
        report(name, &bytes, n, measure(VnDecoder::new, &bytes));
    }
    let ymr: Vec<VnFrame> = (0..64)
        .map(|i| {
            VnFrame::Ascii(VnAscii {
                kind: VnAsciiKind::Ymr,
                checksum: VnChecksum::Xor8,
                values: VnValues {
                    ypr_deg: Some([10.071, -0.278, i as f32 * 0.01]),
                    ..vn_values(i)
                },
            })
        })
        .collect();
    let (bytes, n) = stream(&ymr, |f, out| VnEncoder.encode(f, out).expect("valid"));
    report(
        "vectornav $VNYMR",
        &bytes,
        n,
        measure(VnDecoder::new, &bytes),
    );

    // MIP IMU data set: accel, gyro, mag, delta theta, delta velocity, GPS correlation
    // time (90-byte packets), and accel, gyro, reference time (44 bytes).
    let full: Vec<MipPacket> = (0..64)
        .map(|i| {
            MipPacket::Imu(MipImuData {
                scaled_accel_g: Some([0.001, -0.002, -1.0]),
                scaled_gyro: Some([0.001, 0.002, i as f32 * 1e-4]),
                scaled_mag: Some([0.2, 0.01, 0.45]),
                delta_theta: Some([1e-5, 2e-5, 3e-5]),
                delta_velocity_gs: Some([0.0, 0.0, -0.001]),
                gps_correlation_time: Some(MipGpsTime {
                    tow_s: 345_600.0 + i as f64 * 0.001,
                    week: 2200,
                    valid_flags: 7,
                }),
                ..MipImuData::default()
            })
        })
        .collect();
    let small: Vec<MipPacket> = (0..64u64)
        .map(|i| {
            MipPacket::Imu(MipImuData {
                scaled_accel_g: Some([0.001, -0.002, -1.0]),
                scaled_gyro: Some([0.001, 0.002, 0.0]),
                reference_time_ns: Some(i * 1_000_000),
                ..MipImuData::default()
            })
        })
        .collect();
    for (name, packets) in [("mip IMU 90 B", &full), ("mip IMU 44 B", &small)] {
        let (bytes, n) = stream(packets, |p, out| MipEncoder.encode(p, out).expect("valid"));
        report(name, &bytes, n, measure(MipDecoder::new, &bytes));
    }

    // CSV lines, default layout.
    let config = CsvLineConfig::default();
    let encoder = CsvLineEncoder::new(config.clone()).expect("valid");
    let samples: Vec<ImuSample> = (0..64)
        .map(|i| ImuSample {
            sensor_time: Some(1000.0 + f64::from(i) * 0.005),
            gyro: Some([0.00123 * f64::from(i), -0.0456, 0.0789]),
            accel: Some([0.0123, -0.0456, 9.8123]),
            temp_c: Some(25.25),
            status: 0,
        })
        .collect();
    let (bytes, n) = stream(&samples, |s, out| encoder.encode(s, out).expect("valid"));
    report(
        "csv lines",
        &bytes,
        n,
        measure(
            || CsvLineDecoder::new(config.clone()).expect("valid"),
            &bytes,
        ),
    );

    // slcan frames with timestamps.
    let slcan: Vec<SlcanMessage> = (0..64u32)
        .map(|i| SlcanMessage::Frame {
            frame: CanFrame::data(0x180 + (i % 3), false, &[i as u8; 8]).expect("valid"),
            timestamp_ms: Some((i * 10) as u16),
        })
        .collect();
    let (bytes, n) = stream(&slcan, |m, out| SlcanEncoder.encode(m, out).expect("valid"));
    report(
        "slcan frames",
        &bytes,
        n,
        measure(SlcanDecoder::new, &bytes),
    );

    // candump log, and the same log through the fixture DBC to IMU samples.
    let mapping = DbcImuMapping::from_toml_str(&fixture("imu_can_mapping.toml")).expect("mapping");
    let imu = DbcImu::new(&fixture("imu_can.dbc"), &mapping).expect("dbc");
    let records: Vec<CandumpRecord> = (0..64u64)
        .flat_map(|i| {
            let sample = ImuSample {
                sensor_time: Some(i as f64 * 0.01),
                gyro: Some([0.01, -0.02, 0.03]),
                accel: Some([0.1, 0.2, 9.8]),
                temp_c: Some(30.0),
                status: 1,
            };
            imu.encode(&sample)
                .expect("in range")
                .into_iter()
                .map(move |frame| CandumpRecord {
                    timestamp_us: 1_700_000_000_000_000 + i * 10_000,
                    interface: IfName::new("can0").expect("valid"),
                    frame,
                })
        })
        .collect();
    let (bytes, n) = stream(&records, |r, out| {
        CandumpEncoder.encode(r, out).expect("valid")
    });
    report(
        "candump log",
        &bytes,
        n,
        measure(CandumpDecoder::new, &bytes),
    );
    report(
        "candump + DBC -> ImuSample",
        &bytes,
        n / 3,
        measure(
            || DbcStreamDecoder::new(CandumpDecoder::new(), |r| Some(r.frame), imu.clone()),
            &bytes,
        ),
    );
    write_results();
}

/// The row of the four IMU binary protocols (MB/s of CPU).
fn write_results() {
    use serde_json::json;
    let measured = MEASURED.lock().expect("measured").clone();
    let rate = |prefix: &str| {
        measured
            .iter()
            .find(|m| m.0.starts_with(prefix))
            .map_or(f64::NAN, |m| m.4)
    };
    let rates = [
        rate("witmotion packets"),
        rate("xbus MTData2"),
        rate("vectornav binary 86 B"),
        rate("mip IMU 90 B"),
    ];
    let row = results::Row::new(
        "decode-imu",
        results::ACQUISITION,
        7,
        "WitMotion / Xbus / VectorNav / MIP",
        "docs/bench/drivers.md",
    )
    .data("simulated streams")
    .ours(format!(
        "{} MB/s",
        rates.map(|r| format!("{r:.0}")).join(" / ")
    ))
    .target("≥ 500 MB/s")
    .met(rates.iter().all(|r| *r >= 500.0))
    .timed()
    .command("cargo bench -p imulab-drivers --bench imucan_throughput");
    results::write(
        "imucan_throughput",
        "imu",
        json!({}),
        json!({ "codecs": measured.iter().map(|m| json!({
            "codec": m.0, "mb": m.1, "frames": m.2, "expected_frames": m.3,
            "mb_per_cpu_s": m.4, "mb_per_wall_s": m.5,
        })).collect::<Vec<_>>() }),
        &[row],
    );
}
