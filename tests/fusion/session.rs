//! `imulab replay SESSION` on a simulated session written with the session store: a noisy
//! MEMS IMU (rates), a GNSS receiver with its accuracies, and the truth trajectory; the replay
//! aligns itself, and its errors against the stored truth must be small and consistent.

use crate::support::{city_drive, mems_errors};
use imulab::sim::motion::MotionGenerator;
use imulab::store::{
    DeviceInfo, DeviceKind, GnssRecord, ImuRecord, Manifest, SessionWriter, TruthNavRecord,
    WriterOptions,
};
use imulab_drivers::types::FixType;
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;
use std::process::Command;

const T0_NS: i64 = 5_000_000_000;

fn device(name: &str, kind: DeviceKind, rate_hz: f64) -> DeviceInfo {
    DeviceInfo {
        name: name.into(),
        kind,
        model: "sim".into(),
        serial: String::new(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    }
}

/// Writes the simulated session; the receiver has no rows in `gnss_gap_s` ([start, end), s).
fn write_session_with_gap(dir: &Path, gnss_gap_s: Option<(f64, f64)>) {
    let mut manifest = Manifest::new(
        vec![
            device("imu0", DeviceKind::Imu, 100.0),
            device("gps0", DeviceKind::Gnss, 5.0),
        ],
        toml::Table::new(),
    );
    manifest.truth_nav_rate_hz = Some(10.0);
    let mut w =
        SessionWriter::create(dir, manifest, WriterOptions::default()).expect("create session");
    let e = mems_errors(31);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(31);
    let mut n3 = |s: f64| {
        Vector3::<f64>::from_fn(|_, _| {
            s * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng)
        })
    };
    let rate = 100.0;
    let mut imu = Vec::new();
    let (mut gnss, mut truth) = (Vec::new(), Vec::new());
    for (k, s) in MotionGenerator::new(&city_drive(), rate)
        .expect("plan")
        .enumerate()
    {
        let t_ns = T0_NS + k as i64 * 10_000_000;
        let gyro = s.gyro_b + e.gyro_bias + n3(e.arw * rate.sqrt());
        let accel = s.accel_b + e.accel_bias + n3(e.vrw * rate.sqrt());
        imu.push(ImuRecord {
            t_mono_ns: t_ns,
            t_wall_ns: t_ns,
            t_sensor: f64::NAN,
            gyro: gyro.into(),
            accel: accel.into(),
            temp: f64::NAN,
            status: 0,
        });
        if k % 10 == 0 {
            let q = s.quat_nb.coords;
            truth.push(TruthNavRecord {
                t_mono_ns: t_ns,
                lat_deg: s.lat_rad.to_degrees(),
                lon_deg: s.lon_rad.to_degrees(),
                height_m: s.height_m,
                vel_ned: s.vel_ned.into(),
                quat_nb: [q.w, q.x, q.y, q.z],
            });
        }
        let t = k as f64 / rate;
        if k % 20 == 0 && !gnss_gap_s.is_some_and(|(a, b)| t >= a && t < b) {
            let dp = n3(0.3);
            let dv = n3(0.05);
            let fix = if k == 400 {
                FixType::NoFix
            } else {
                FixType::Fix3D
            };
            gnss.push(GnssRecord {
                t_mono_ns: t_ns,
                t_wall_ns: t_ns,
                week: 2300,
                tow_s: 100_000.0 + k as f64 / rate,
                utc_ns: i64::MIN,
                lat_deg: (s.lat_rad + dp.x / 6.37e6).to_degrees(),
                lon_deg: (s.lon_rad + dp.y / (6.39e6 * s.lat_rad.cos())).to_degrees(),
                height_m: s.height_m + 2.0 * dp.z,
                vel_ned: (s.vel_ned + dv).into(),
                h_acc_m: 0.3,
                v_acc_m: 0.6,
                s_acc_mps: 0.05,
                fix_type: fix,
                num_sats: 12,
                pdop: 1.0,
                hdop: 0.8,
                vdop: 1.2,
                heading_deg: f64::NAN,
            });
        }
        if imu.len() == 1000 {
            w.append_imu("imu0", &imu).expect("imu");
            w.append_gnss("gps0", &gnss).expect("gnss");
            w.append_truth_nav(&truth).expect("truth");
            imu.clear();
            gnss.clear();
            truth.clear();
        }
    }
    w.append_imu("imu0", &imu).expect("imu");
    w.append_gnss("gps0", &gnss).expect("gnss");
    w.append_truth_nav(&truth).expect("truth");
    w.close().expect("close");
}

fn write_session(dir: &Path) {
    write_session_with_gap(dir, None);
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .expect("read dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn outages_are_reported_over_the_real_windows_without_gnss() {
    let dir = tempfile::tempdir().expect("tempdir");
    let session = dir.path().join("drive");
    // The data lacks fixes in 150..170 s; a withheld 160..190 s overlaps it and 60..80 s
    // stands alone.
    write_session_with_gap(&session, Some((150.0, 170.0)));
    let out_dir = dir.path().join("out");
    let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("replay")
        .arg(&session)
        .args([
            "--outage", "160:30", "--outage", "60:20", "--outage", "9000:10",
        ])
        .arg("--out")
        .arg(&out_dir)
        .output()
        .expect("run imulab");
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success());
    assert!(
        stdout.contains("outage at +60.0 s for 20.0 s (withheld)"),
        "{stdout}"
    );
    assert!(
        stdout.contains(
            "outage at +150.0 s for 40.0 s (30 s withheld, 10 s without fixes in the data)"
        ),
        "{stdout}"
    );
    assert!(
        stdout.contains("outage at +9000 s starts after the data ends"),
        "{stdout}"
    );
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join("errors.json")).expect("errors.json"),
    )
    .expect("json");
    let outages = report["filtered"]["outages"].as_array().expect("outages");
    assert_eq!(outages.len(), 2, "{outages:?}");
    let long = &outages[1];
    assert!((long["duration_s"].as_f64().expect("duration") - 40.0).abs() < 0.05);
    assert!((long["withheld_s"].as_f64().expect("withheld") - 30.0).abs() < 0.05);
    let drift = long["max_horizontal_m"].as_f64().expect("drift");
    assert!(drift.is_finite() && drift > 0.0, "{drift}");
    // --out: nothing written into the session.
    assert_eq!(
        files_in(&session)
            .iter()
            .filter(|f| f.starts_with("replay"))
            .count(),
        0,
        "{:?}",
        files_in(&session)
    );
}

#[test]
fn an_unwritable_output_place_is_one_clear_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    let session = dir.path().join("drive");
    write_session(&session);
    let run = |extra: &[&std::ffi::OsStr]| {
        let o = Command::new(env!("CARGO_BIN_EXE_imulab"))
            .arg("replay")
            .arg(&session)
            .args(extra)
            .output()
            .expect("run");
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    // A directory under a regular file cannot be created, even by root.
    let file = dir.path().join("plain-file");
    std::fs::write(&file, "x").expect("write");
    let under_file = file.join("out");
    let (ok, err) = run(&["--out".as_ref(), under_file.as_os_str()]);
    assert!(!ok, "{err}");
    assert!(
        err.contains("cannot write into") && err.contains("plain-file"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");

    // A read-only session: with --out elsewhere the replay succeeds and leaves it as it was;
    // without --out it fails with one line (where permissions bind, i.e. not as root).
    let before = files_in(&session);
    let set_mode = |mode: u32| {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&session, std::fs::Permissions::from_mode(mode)).expect("chmod");
    };
    set_mode(0o555);
    let out_dir = dir.path().join("elsewhere");
    let (ok, err) = run(&["--out".as_ref(), out_dir.as_os_str()]);
    let binds = std::fs::File::create(session.join("probe")).is_err();
    let (ok_in_session, err_in_session) = run(&[]);
    set_mode(0o755);
    assert!(ok, "{err}");
    assert!(out_dir.join("replay.h5").exists());
    if binds {
        assert!(!ok_in_session);
        assert!(
            err_in_session.contains("cannot write into"),
            "{err_in_session}"
        );
        assert_eq!(err_in_session.trim().lines().count(), 1, "{err_in_session}");
        assert_eq!(files_in(&session), before);
    } else {
        let _ = std::fs::remove_file(session.join("probe"));
        println!("running as root: read-only permissions do not bind, in-session case not checked");
    }
}

#[test]
fn replays_a_simulated_session_against_its_truth() {
    let dir = tempfile::tempdir().expect("tempdir");
    let session = dir.path().join("drive");
    write_session(&session);
    let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("replay")
        .arg(&session)
        .args(["--outages", "every:100:20", "--smooth"])
        .output()
        .expect("run imulab");
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success());
    assert!(
        stdout.contains("1 epochs without a fix skipped"),
        "{stdout}"
    );
    let res = session.join("replay");
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(res.join("errors.json")).expect("errors.json"),
    )
    .expect("json");
    let h = report["filtered"]["horizontal_with_gnss_m"]["rms"]
        .as_f64()
        .expect("rms");
    let inside = report["filtered"]["inside_3sigma"]
        .as_f64()
        .expect("inside");
    let drift = report["filtered"]["outages"][0]["max_horizontal_m"]
        .as_f64()
        .expect("drift");
    let drift_s = report["smoothed"]["outages"][0]["max_horizontal_m"]
        .as_f64()
        .expect("drift");
    assert!(h < 0.5, "horizontal RMS with GNSS {h}");
    assert!(inside > 0.95, "inside 3σ {inside}");
    assert!(
        drift > 0.01 && drift < 20.0 && drift_s < drift,
        "{drift} {drift_s}"
    );
    let f = hdf5::File::open(res.join("replay.h5")).expect("replay.h5");
    let lat = f
        .dataset("replay/filtered/lat_deg")
        .expect("lat")
        .read_raw::<f64>()
        .expect("read");
    assert!(lat.len() > 2000 && lat.iter().all(|v| v.is_finite()));
    let nav = std::fs::read_to_string(res.join("filtered_navresult.nav")).expect("navresult");
    assert!(
        nav.lines().next().expect("line").starts_with("2300 100"),
        "{}",
        &nav[..80]
    );
}

#[test]
fn bad_session_arguments_are_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_imulab"))
            .args(args)
            .output()
            .expect("run");
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    let missing = dir.path().join("nope");
    let (ok, err) = run(&["replay", missing.to_str().expect("utf8")]);
    assert!(!ok && err.contains("nope"), "{err}");
    let session = dir.path().join("s");
    write_session(&session);
    let (ok, err) = run(&["replay", session.to_str().expect("utf8"), "--imu", "imu9"]);
    assert!(!ok && err.contains("imu9") && err.contains("imu0"), "{err}");
    let (ok, err) = run(&[
        "replay",
        session.to_str().expect("utf8"),
        "--outages",
        "every:10:20",
    ]);
    assert!(!ok && err.contains("--outages"), "{err}");
    let (ok, _) = run(&["replay"]);
    assert!(!ok);
}
