//! The session adapter: an IMU written with the store's writer is analysed through
//! `SessionSource` exactly as the same samples from memory, gaps are detected from the
//! time stamps, and `imulab allan SESSION` runs end to end.

use clap::Parser;
use imulab::allan::input::{read_axes, read_axis, DataKind, GapPolicy, SampleSource, Timing};
use imulab::allan::pipeline::{analyse_inputs, AsRecorded, Options, Progress};
use imulab::allan::session_source::SessionSource;
use imulab::allan::{compute_curve, DeviationKind, Phase, TauGrid};
use imulab::store::{DeviceInfo, DeviceKind, ImuRecord, Manifest, SessionWriter, WriterOptions};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;

fn write_session(dir: &Path, rows: usize, skip: Option<std::ops::Range<usize>>) -> Vec<ImuRecord> {
    write_session_with(dir, rows, skip, |_| {})
}

/// As [`write_session`], with `edit` applied to every record before it is written.
fn write_session_with(
    dir: &Path,
    rows: usize,
    skip: Option<std::ops::Range<usize>>,
    edit: impl Fn(&mut ImuRecord),
) -> Vec<ImuRecord> {
    let device = DeviceInfo {
        name: "imu0".into(),
        kind: DeviceKind::Imu,
        model: "sim".into(),
        serial: String::new(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz: 100.0,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    };
    let manifest = Manifest::new(vec![device], toml::Table::new());
    let options = WriterOptions {
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    let mut writer = SessionWriter::create(dir, manifest, options).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    let mut n = || -> f64 { StandardNormal.sample(&mut rng) };
    let records: Vec<ImuRecord> = (0..rows)
        .filter(|i| skip.as_ref().is_none_or(|s| !s.contains(i)))
        .map(|i| ImuRecord {
            t_mono_ns: 5_000_000_000 + i as i64 * 10_000_000,
            t_wall_ns: 1_700_000_000_000_000_000 + i as i64 * 10_000_000,
            t_sensor: f64::NAN,
            gyro: [1e-3 * n(), 1e-3 * n(), 1e-3 * n()],
            accel: [0.01 * n(), 0.01 * n(), -9.80665 + 0.01 * n()],
            temp: 25.0 + (i / 1000) as f64,
            status: 0,
        })
        .map(|mut r| {
            edit(&mut r);
            r
        })
        .collect();
    for chunk in records.chunks(500) {
        writer.append_imu("imu0", chunk).unwrap();
    }
    writer.close().unwrap();
    records
}

#[test]
fn session_axis_matches_in_memory_analysis() {
    let dir = tempfile::tempdir().unwrap();
    let session_dir = dir.path().join("run");
    let records = write_session(&session_dir, 6000, None);
    let source = SessionSource::open(&session_dir, None, None, None).unwrap();
    assert_eq!(source.device(), "imu0");
    let axis = source.channel_index("accel_z").unwrap();
    let t = source.channel_index("t").unwrap();
    let series = read_axis(
        &source,
        axis,
        &Timing::TimeChannel {
            channel: t,
            scale: 1.0,
        },
        GapPolicy::Error,
        DataKind::Rate,
        None,
    )
    .unwrap();
    assert!((series.tau0 - 0.01).abs() < 1e-12);
    let expected: Vec<f64> = records.iter().map(|r| r.accel[2]).collect();
    assert_eq!(series.segments, vec![expected.clone()]);
    let from_session = compute_curve(
        &Phase::from_rate(series.segments[0].clone()),
        0.01,
        DeviationKind::Oadev,
        &TauGrid::Octave,
    );
    let direct = compute_curve(
        &Phase::from_rate(expected),
        0.01,
        DeviationKind::Oadev,
        &TauGrid::Octave,
    );
    assert_eq!(from_session.points, direct.points);
    // A time range selects seconds after the first sample.
    let ranged = SessionSource::open(&session_dir, Some("imu0"), Some(10.0), Some(20.0)).unwrap();
    let part = read_axis(
        &ranged,
        axis,
        &Timing::TimeChannel {
            channel: t,
            scale: 1.0,
        },
        GapPolicy::Error,
        DataKind::Rate,
        None,
    )
    .unwrap();
    assert_eq!(part.sample_count(), 1000);
    assert!(SessionSource::open(&session_dir, Some("nope"), None, None).is_err());
}

#[test]
fn session_gap_is_detected_and_cli_runs() {
    let dir = tempfile::tempdir().unwrap();
    let session_dir = dir.path().join("gappy");
    write_session(&session_dir, 4000, Some(2000..2050));
    let exe = env!("CARGO_BIN_EXE_imulab");
    let refused = std::process::Command::new(exe)
        .args([
            "allan",
            session_dir.to_str().unwrap(),
            "--sensor",
            "gyro",
            "--axes",
            "x",
        ])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(
        stderr.contains("gap of 0.510000 s") && stderr.contains("50 samples missing"),
        "{stderr}"
    );
    let json = dir.path().join("s.json");
    let ok = std::process::Command::new(exe)
        .args([
            "allan",
            session_dir.to_str().unwrap(),
            "--gaps",
            "split",
            "--fit",
            "--temperature-column",
            "temp",
        ])
        .args(["--json", json.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let axes = doc["axes"].as_array().unwrap();
    assert_eq!(axes.len(), 6);
    assert_eq!(axes[0]["axis"], "gyro_x");
    assert_eq!(axes[0]["sensor"], "gyro");
    assert_eq!(axes[3]["sensor"], "accel");
    assert_eq!(axes[0]["health"]["segments"], 2);
    assert_eq!(axes[0]["health"]["missing_samples"], 50);
    assert_eq!(axes[0]["health"]["policy"], "split");
}

#[derive(clap::Parser)]
struct AnalysisCli {
    #[command(flatten)]
    options: Options,
}

/// Counts what the pipeline says of its progress.
#[derive(Default)]
struct Counted {
    planned: usize,
    analysed: Vec<String>,
}

impl Progress for Counted {
    fn planned(&mut self, axes: usize) {
        self.planned = axes;
    }
    fn analysed(&mut self, label: &str) {
        self.analysed.push(label.to_string());
    }
}

#[test]
fn one_reading_pass_for_all_axes_equals_one_pass_per_axis() {
    let dir = tempfile::tempdir().unwrap();
    let session_dir = dir.path().join("run");
    // A gap for every axis and a NaN in gyro_y only: the gap bookkeeping is per axis.
    let records = write_session_with(&session_dir, 5000, Some(3000..3010), |r| {
        if r.t_mono_ns == 5_000_000_000 + 1234 * 10_000_000 {
            r.gyro[1] = f64::NAN;
        }
    });
    let source = SessionSource::open(&session_dir, None, None, None).unwrap();
    assert_eq!(source.row_count_hint(), Some(records.len() as u64));
    let timing = Timing::TimeChannel {
        channel: source.channel_index("t").unwrap(),
        scale: 1.0,
    };
    let axes: Vec<usize> = (1..=6).collect();
    let together = read_axes(
        &source,
        &axes,
        &timing,
        GapPolicy::Split,
        DataKind::Rate,
        Some(7),
    )
    .unwrap();
    assert_eq!(together.len(), 6);
    for (&axis, joint) in axes.iter().zip(&together) {
        let alone = read_axis(
            &source,
            axis,
            &timing,
            GapPolicy::Split,
            DataKind::Rate,
            Some(7),
        )
        .unwrap();
        assert_eq!(joint.name, alone.name);
        assert_eq!(joint.segments, alone.segments);
        assert_eq!(joint.temperature, alone.temperature);
        assert_eq!(joint.health, alone.health);
    }
    assert_eq!(together[1].health.invalid_values, 1);
    assert_eq!(together[1].segments.len(), 3);
    assert_eq!(together[0].segments.len(), 2);

    // Through the pipeline: a budget too small for two axes reads one axis per pass; the
    // document is identical to the single pass, and each axis is reported as analysed.
    let input = vec![session_dir.clone()];
    let parse = |extra: &[&str]| {
        let mut argv = vec!["test", "--gaps", "split", "--fit"];
        argv.extend_from_slice(extra);
        AnalysisCli::parse_from(argv).options
    };
    let mut progress = Counted::default();
    let one_pass = analyse_inputs(&input, &parse(&[]), &AsRecorded, &mut progress).unwrap();
    assert_eq!(progress.planned, 6);
    assert_eq!(progress.analysed.len(), 6);
    assert_eq!(progress.analysed[0], "imu0 gyro_x");
    let per_axis =
        analyse_inputs(&input, &parse(&["--memory-mib", "0"]), &AsRecorded, &mut ()).unwrap();
    assert_eq!(
        serde_json::to_value(&one_pass.axes).unwrap(),
        serde_json::to_value(&per_axis.axes).unwrap()
    );
    assert_eq!(one_pass.axes.len(), 6);
}

/// A simulated 150 Hz IMU whose frames reach the host in batches of 5 with 0-20 ms of
/// latency, its sample counter (`t_sensor`) wrapping at 1000, with sample 3999 (counter 999,
/// just before a wrap) lost on the link. Returns the gyro x values written.
fn write_counter_session(dir: &Path, with_counter: bool) -> Vec<f64> {
    let device = DeviceInfo {
        name: "imu0".into(),
        kind: DeviceKind::Imu,
        model: "simulated".into(),
        serial: String::new(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz: 150.0,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    };
    let config: toml::Table = toml::from_str(
        "[[imu]]\nname = \"imu0\"\n[imu.timing]\ncounter_modulo = 1000\ndrop_probability = 0.0\n",
    )
    .unwrap();
    let options = WriterOptions {
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    let mut writer =
        SessionWriter::create(dir, Manifest::new(vec![device], config), options).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
    let mut n = || -> f64 { StandardNormal.sample(&mut rng) };
    let period = 1e9 / 150.0;
    let mut last_arrival = 0i64;
    let mut records = Vec::new();
    for k in 0..9000usize {
        let latency = 20e6 * ((k / 5 * 7919) % 100) as f64 / 100.0;
        let arrival = (5e9 + (k / 5 * 5 + 4) as f64 * period + latency) as i64;
        last_arrival = last_arrival.max(arrival);
        let record = ImuRecord {
            t_mono_ns: last_arrival,
            t_wall_ns: 1_700_000_000_000_000_000 + last_arrival,
            t_sensor: if with_counter {
                (k % 1000) as f64
            } else {
                f64::NAN
            },
            gyro: [1e-3 * n(), 1e-3 * n(), 1e-3 * n()],
            accel: [0.01 * n(), 0.01 * n(), -9.80665 + 0.01 * n()],
            temp: 25.0,
            status: 0,
        };
        if k != 3999 {
            records.push(record);
        }
    }
    for chunk in records.chunks(75) {
        writer.append_imu("imu0", chunk).unwrap();
    }
    writer.close().unwrap();
    records.iter().map(|r| r.gyro[0]).collect()
}

#[test]
fn one_dropped_sample_is_found_on_the_sensor_counter() {
    let dir = tempfile::tempdir().unwrap();
    let session_dir = dir.path().join("dropped");
    let gyro_x = write_counter_session(&session_dir, true);
    let source = SessionSource::open(&session_dir, None, None, None).unwrap();
    let timing = source.native_timing().unwrap();
    assert!(
        matches!(timing, Timing::SensorTime { .. }),
        "a sim session has a sample counter: {timing:?}"
    );
    let x = source.channel_index("gyro_x").unwrap();
    let read = |policy| read_axis(&source, x, &timing, policy, DataKind::Rate, None);

    // Refused by default, naming the clock and the one missing sample.
    let err = read(GapPolicy::Error).unwrap_err().to_string();
    assert!(
        err.contains("sample 3999: gap of") && err.contains("(1 samples missing"),
        "{err}"
    );
    assert!(err.contains("sensor sample counter"), "{err}");

    let split = read(GapPolicy::Split).unwrap();
    assert!((split.tau0 * 150.0 - 1.0).abs() < 1e-3, "τ0 {}", split.tau0);
    assert_eq!(split.health.gaps, 1, "{:?}", split.health);
    assert_eq!(split.health.missing_samples, 1);
    assert_eq!(split.health.nonuniform_intervals, 0, "{:?}", split.health);
    assert_eq!(
        split.health.clock.as_deref(),
        Some("sensor sample counter (t_sensor)")
    );
    assert_eq!(
        split.segments,
        vec![gyro_x[..3999].to_vec(), gyro_x[3999..].to_vec()]
    );

    let fill = read(GapPolicy::Fill).unwrap();
    assert_eq!(fill.segments.len(), 1);
    assert_eq!(fill.segments[0].len(), 9000);
    assert_eq!(
        fill.segments[0][3999],
        gyro_x[3998] + 0.5 * (gyro_x[3999] - gyro_x[3998])
    );

    let ignore = read(GapPolicy::Ignore).unwrap();
    assert_eq!(ignore.segments, vec![gyro_x.clone()]);
    assert_eq!(ignore.health.missing_samples, 1);

    // The host arrival times alone cannot see it (the loss is under the batching latency).
    let arrival = Timing::ArrivalTimes {
        channel: source.channel_index("t").unwrap(),
        scale: 1.0,
    };
    let blind = read_axis(&source, x, &arrival, GapPolicy::Error, DataKind::Rate, None).unwrap();
    assert_eq!(blind.health.gaps, 0);

    // Through the command: refused by default, and the report says which clock found it.
    let exe = env!("CARGO_BIN_EXE_imulab");
    let refused = std::process::Command::new(exe)
        .args(["allan", session_dir.to_str().unwrap(), "--sensor", "gyro"])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(stderr.contains("1 samples missing"), "{stderr}");
    let ok = std::process::Command::new(exe)
        .args(["allan", session_dir.to_str().unwrap(), "--gaps", "split"])
        .args(["--sensor", "gyro", "--axes", "x"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    assert!(
        stdout.contains("1 gap(s) found on the sensor sample counter (t_sensor)"),
        "{stdout}"
    );
}

#[test]
fn without_a_sensor_clock_the_arrival_times_decide() {
    let dir = tempfile::tempdir().unwrap();
    let session_dir = dir.path().join("nocounter");
    write_counter_session(&session_dir, false);
    let source = SessionSource::open(&session_dir, None, None, None).unwrap();
    let timing = source.native_timing().unwrap();
    assert!(matches!(timing, Timing::ArrivalTimes { .. }), "{timing:?}");
    let x = source.channel_index("gyro_x").unwrap();
    let s = read_axis(&source, x, &timing, GapPolicy::Error, DataKind::Rate, None).unwrap();
    assert_eq!(s.health.gaps, 0);
    assert!(
        s.health
            .clock
            .as_deref()
            .unwrap_or("")
            .starts_with("host arrival times"),
        "{:?}",
        s.health.clock
    );
}
