//! KF-GINS text formats end to end: a simulated drive written as KF-GINS IMU, GNSS, truth
//! `.nav` and YAML configuration files, replayed through the library and the `imulab replay
//! --kf-gins` command; the navresult output compares with the truth line by line. A public
//! dataset in that layout under the external data directory is replayed when present.

use crate::support::{city_drive, mems_errors, simulate, SimData};
use imulab::fusion::kfgins::{self, format_nav_line, KfGinsConfig};
use imulab::fusion::mechanisation::{ImuInput, NavState};
use imulab::fusion::metrics::{errors, summarise};
use nalgebra::Vector3;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

const SOW0: f64 = 456_300.0;
const WEEK: u32 = 2200;
const LEVER: [f64; 3] = [0.136, -0.301, -0.184];

fn write_dataset(dir: &Path) -> SimData {
    let mut e = mems_errors(21);
    e.gyro_scale = Vector3::new(4e-4, -2e-4, 6e-4);
    e.accel_scale = Vector3::new(-3e-4, 5e-4, 2e-4);
    let d = simulate(
        &city_drive(),
        100.0,
        100,
        &e,
        (0.02, 0.03, 0.01),
        Vector3::from(LEVER),
        21,
    );
    let mut imu = String::new();
    for s in &d.imu {
        if let ImuInput::Increments {
            t_s, dtheta, dvel, ..
        } = s
        {
            writeln!(
                imu,
                "{:.5} {:.12e} {:.12e} {:.12e} {:.12e} {:.12e} {:.12e}",
                SOW0 + t_s,
                dtheta.x,
                dtheta.y,
                dtheta.z,
                dvel.x,
                dvel.y,
                dvel.z
            )
            .expect("fmt");
        }
    }
    std::fs::write(dir.join("imu.txt"), imu).expect("write imu");
    let mut gnss = String::new();
    for g in d.gnss.iter().skip(1) {
        writeln!(
            gnss,
            "{:.3} {:.10} {:.10} {:.4} {} {} {}",
            SOW0 + g.t_s,
            g.lat_rad.to_degrees(),
            g.lon_rad.to_degrees(),
            g.height_m,
            g.sigma_ned_m.x,
            g.sigma_ned_m.y,
            g.sigma_ned_m.z
        )
        .expect("fmt");
    }
    std::fs::write(dir.join("gnss.txt"), gnss).expect("write gnss");
    let mut truth = String::new();
    for t in d.truth.iter().step_by(10) {
        let mut nav = imulab::study::nav_state(t);
        nav.t_s += SOW0;
        writeln!(truth, "{}", format_nav_line(WEEK, &nav)).expect("fmt");
    }
    std::fs::write(dir.join("truth.nav"), truth).expect("write truth");
    let t0 = &d.truth[0];
    let (r, p, y) = t0.quat_nb.euler_angles();
    let yaml = format!(
        "# written by the imulab test\nimupath: \"imu.txt\"\ngnsspath: \"gnss.txt\"\noutputpath: \"out\"\nimudatalen: 7\nimudatarate: 100\nstarttime: {SOW0}\nendtime: -1\n\
         initpos: [ {:.10}, {:.10}, {:.4} ]\ninitvel: [ 0, 0, 0 ]\ninitatt: [ {:.8}, {:.8}, {:.8} ]\n\
         initposstd: [ 0.05, 0.05, 0.1 ]\ninitvelstd: [ 0.05, 0.05, 0.05 ]\ninitattstd: [ 0.1, 0.1, 0.5 ]\n\
         imunoise:\n  arw: [0.3, 0.3, 0.3]\n  vrw: [0.1, 0.1, 0.1]\n  gbstd: [20.0, 20.0, 20.0]\n  abstd: [4905.0, 4905.0, 4905.0]\n  gsstd: [1000.0, 1000.0, 1000.0]\n  asstd: [1000.0, 1000.0, 1000.0]\n  corrtime: 1.0\n\
         antlever: [ {}, {}, {} ]\n",
        t0.lat_rad.to_degrees(), t0.lon_rad.to_degrees(), t0.height_m,
        r.to_degrees(), p.to_degrees(), y.to_degrees(), LEVER[0], LEVER[1], LEVER[2],
    );
    std::fs::write(dir.join("kf-gins.yaml"), yaml).expect("write yaml");
    d
}

fn truth_lookup(rows: &[kfgins::NavRow]) -> impl FnMut(f64) -> Option<NavState> + '_ {
    |t| {
        let i = rows.partition_point(|r| r.nav.t_s < t - 1e-4);
        rows.get(i)
            .filter(|r| (r.nav.t_s - t).abs() < 1e-4)
            .map(|r| r.nav)
    }
}

#[test]
fn simulated_drive_in_kf_gins_format_replays_to_the_truth() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_dataset(dir.path());
    let cfg =
        KfGinsConfig::from_file(&dir.path().join("kf-gins.yaml"), dir.path()).expect("config");
    assert_eq!(cfg.lever_arm_m, Vector3::from(LEVER));
    let r = kfgins::replay_files(&cfg, &[(SOW0 + 100.0, SOW0 + 120.0)], false).expect("replay");
    let out = dir.path().join("navresult.nav");
    kfgins::write_navresult(&out, WEEK, &r.filtered).expect("write");
    let back = kfgins::read_nav(&out).expect("read back");
    assert_eq!(back.len(), r.filtered.len());
    assert!(back.iter().all(|row| row.week == WEEK));
    let truth = kfgins::read_nav(&dir.path().join("truth.nav")).expect("truth");
    let e = errors(&r.filtered, truth_lookup(&truth));
    let s = summarise(&e, &[(SOW0 + 100.0, SOW0 + 120.0)]);
    println!("{s:?}\n{:?}", r.stats);
    assert!(s.epochs > 2500, "{}", s.epochs);
    assert!(s.horizontal_gnss.rms < 0.05, "{:?}", s.horizontal_gnss);
    assert!(s.outages[0].max_horizontal_m > 0.01 && s.outages[0].max_horizontal_m < 5.0);
    assert!(s.inside_3sigma > 0.97, "{}", s.inside_3sigma);
}

#[test]
fn replay_command_writes_navresult_csv_geojson_and_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_dataset(dir.path());
    let out = dir.path().join("results");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .current_dir(dir.path())
        .args([
            "replay",
            "--kf-gins",
            "kf-gins.yaml",
            "--truth",
            "truth.nav",
            "--outages",
            "every:100:20",
            "--smooth",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("run imulab");
    let stdout = String::from_utf8_lossy(&status.stdout);
    println!("{stdout}\n{}", String::from_utf8_lossy(&status.stderr));
    assert!(status.status.success());
    for f in [
        "filtered_navresult.nav",
        "smoothed_navresult.nav",
        "filtered_trajectory.csv",
        "smoothed_trajectory.geojson",
        "errors.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("errors.json")).expect("json"))
            .expect("valid json");
    let filt = report["filtered"]["outages"][0]["max_horizontal_m"]
        .as_f64()
        .expect("number");
    let smooth = report["smoothed"]["outages"][0]["max_horizontal_m"]
        .as_f64()
        .expect("number");
    assert!(smooth < filt, "smoothed {smooth} filtered {filt}");
    let geo: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("smoothed_trajectory.geojson")).expect("geojson"),
    )
    .expect("valid");
    assert_eq!(geo["geometry"]["type"], "LineString");
    // A bad configuration fails with the file and key named.
    std::fs::write(
        dir.path().join("bad.yaml"),
        "imupath: x\nimudatarate: fast\n",
    )
    .expect("write");
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .current_dir(dir.path())
        .args(["replay", "--kf-gins", "bad.yaml"])
        .output()
        .expect("run imulab");
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("bad.yaml"), "{err}");
}

fn external_dir() -> Option<PathBuf> {
    let candidates = [
        std::env::var_os("IMULAB_EXTERNAL").map(PathBuf::from),
        Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/external")),
        Some(PathBuf::from("/work/shared/external")),
    ];
    candidates.into_iter().flatten().find(|p| p.is_dir())
}

/// A public KF-GINS-layout dataset: `<external>/kf-gins/kf-gins.yaml` (paths inside relative
/// to that directory) with `truth.nav` beside it.
#[test]
fn public_kf_gins_dataset_when_present() {
    let Some(base) = external_dir()
        .map(|d| d.join("kf-gins"))
        .filter(|d| d.join("kf-gins.yaml").is_file())
    else {
        println!("SKIPPED: no <external>/kf-gins/kf-gins.yaml (set IMULAB_EXTERNAL to the external data directory)");
        return;
    };
    let cfg = KfGinsConfig::from_file(&base.join("kf-gins.yaml"), &base).expect("config");
    let r = kfgins::replay_files(&cfg, &[], false).expect("replay");
    let truth = kfgins::read_nav(&base.join("truth.nav")).expect("truth");
    let s = summarise(&errors(&r.filtered, truth_lookup(&truth)), &[]);
    println!("public dataset: {s:?}");
    assert!(s.epochs > 0 && s.horizontal.rms.is_finite());
}

/// Runs `imulab replay --kf-gins kf-gins.yaml --truth truth.nav` in `dir` with `extra`
/// arguments: (success, stdout, stderr).
fn replay_in(dir: &Path, extra: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .current_dir(dir)
        .args([
            "replay",
            "--kf-gins",
            "kf-gins.yaml",
            "--truth",
            "truth.nav",
            "--out",
            "res",
        ])
        .args(extra)
        .output()
        .expect("run imulab");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Rewrites each line of `file` in `dir` with `edit` (None drops the line).
fn edit_lines(dir: &Path, file: &str, mut edit: impl FnMut(usize, &str) -> Option<String>) {
    let p = dir.join(file);
    let text = std::fs::read_to_string(&p).expect("read");
    let out: Vec<String> = text
        .lines()
        .enumerate()
        .filter_map(|(i, l)| edit(i, l))
        .collect();
    std::fs::write(&p, out.join("\n") + "\n").expect("write");
}

fn assert_no_nan(dir: &Path) {
    for f in [
        "filtered_navresult.nav",
        "errors.json",
        "filtered_trajectory.csv",
    ] {
        let text = std::fs::read_to_string(dir.join("res").join(f)).expect(f);
        assert!(!text.to_lowercase().contains("nan"), "NaN in {f}");
    }
}

#[test]
fn gnss_without_standard_deviations_uses_the_stated_fallback() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_dataset(dir.path());
    // σ columns zero on even lines, negative on the others.
    edit_lines(dir.path(), "gnss.txt", |i, l| {
        let mut c: Vec<String> = l.split_whitespace().map(String::from).collect();
        for s in &mut c[4..7] {
            *s = if i % 2 == 0 { "0".into() } else { "-1".into() };
        }
        Some(c.join(" "))
    });
    let (ok, stdout, stderr) = replay_in(dir.path(), &[]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("had a zero, negative or missing position σ: used 2.5 m horizontal"),
        "{stdout}"
    );
    assert_no_nan(dir.path());
}

#[test]
fn imu_time_going_backwards_or_jumping_is_rejected_and_counted() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_dataset(dir.path());
    // Rows 5000..5003 repeated (time going backwards) and rows 9000..9500 removed (a 5 s jump).
    let text = std::fs::read_to_string(dir.path().join("imu.txt")).expect("imu");
    let rows: Vec<&str> = text.lines().collect();
    let mut out: Vec<&str> = Vec::new();
    for (i, r) in rows.iter().enumerate() {
        if (9000..9500).contains(&i) {
            continue;
        }
        out.push(r);
        if i == 5003 {
            out.extend_from_slice(&rows[5000..5003]);
        }
    }
    std::fs::write(dir.path().join("imu.txt"), out.join("\n") + "\n").expect("write");
    let (ok, stdout, stderr) = replay_in(dir.path(), &[]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("IMU samples rejected: time not after the previous sample's"),
        "{stdout}"
    );
    assert!(stdout.contains("1 IMU time jumps over 1 s"), "{stdout}");
    assert_no_nan(dir.path());
}

#[test]
fn gnss_not_overlapping_the_imu_is_one_clear_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_dataset(dir.path());
    edit_lines(dir.path(), "gnss.txt", |_, l| {
        let mut c: Vec<String> = l.split_whitespace().map(String::from).collect();
        c[0] = format!("{:.3}", c[0].parse::<f64>().expect("time") + 10_000.0);
        Some(c.join(" "))
    });
    let (ok, stdout, stderr) = replay_in(dir.path(), &[]);
    assert!(!ok, "{stdout}");
    assert!(
        stderr.contains("gnss.txt") && stderr.contains("do not overlap"),
        "{stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
    assert!(!dir
        .path()
        .join("res")
        .join("filtered_navresult.nav")
        .exists());
}

#[test]
fn an_outage_longer_than_the_data_is_counted_to_its_end_and_said() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_dataset(dir.path());
    let (ok, stdout, stderr) = replay_in(dir.path(), &["--outage", "200:5000"]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("runs past the end of the data"), "{stdout}");
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("res/errors.json")).expect("errors.json"),
    )
    .expect("json");
    let o = &report["filtered"]["outages"][0];
    let dur = o["duration_s"].as_f64().expect("duration");
    assert!(dur > 50.0 && dur < 200.0, "clipped to the data: {o}");
    assert!(o["max_horizontal_m"].as_f64().expect("drift").is_finite());
    assert_no_nan(dir.path());
}

#[test]
fn motion_constraints_are_usable_with_kf_gins_from_a_toml_or_flags() {
    let dir = tempfile::tempdir().expect("tempdir");
    write_dataset(dir.path());
    std::fs::write(
        dir.path().join("constraints.toml"),
        "[nhc]\nenabled = true\nsigma_mps = 0.1\n[zaru]\nenabled = true\n",
    )
    .expect("write");
    let (ok, stdout, stderr) = replay_in(
        dir.path(),
        &["--config", "constraints.toml", "--outages", "every:100:20"],
    );
    assert!(ok, "{stderr}");
    assert!(stdout.contains("motion constraints: NHC, ZARU"), "{stdout}");
    let updates = stdout
        .split("NHC/ZUPT/ZARU/odometer updates ")
        .nth(1)
        .and_then(|s| s.split(',').next())
        .expect("update counts");
    let n: Vec<u64> = updates
        .split('/')
        .map(|x| x.trim().parse().expect("count"))
        .collect();
    assert!(n[0] > 100 && n[1] == 0 && n[2] > 0, "{updates}");
    assert_no_nan(dir.path());
    // Flags do the same; anything but constraints in the TOML is refused in one line.
    let (ok, stdout, _) = replay_in(dir.path(), &["--nhc", "--zupt"]);
    assert!(
        ok && stdout.contains("motion constraints: NHC, ZUPT"),
        "{stdout}"
    );
    std::fs::write(
        dir.path().join("bad.toml"),
        "[imu]\narw_rad_per_sqrt_s = 1.0\n",
    )
    .expect("write");
    let (ok, _, stderr) = replay_in(dir.path(), &["--config", "bad.toml"]);
    assert!(
        !ok && stderr.contains("bad.toml") && stderr.contains("[nhc], [zupt] and [zaru] only"),
        "{stderr}"
    );
}

/// Wheel speed in column 8 of the KF-GINS IMU file, turned on by a constraints TOML beside
/// the YAML: the odometer updates run, and with NHC they hold the outage drift below NHC
/// alone's.
#[test]
fn odometer_column_with_nhc_cuts_outage_drift() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = write_dataset(dir.path());
    // Column 8: the true forward speed with 2 cm/s of noise.
    let imu = std::fs::read_to_string(dir.path().join("imu.txt")).expect("imu");
    let mut with_speed = String::new();
    for (k, (line, t)) in imu.lines().zip(d.truth.iter().skip(1)).enumerate() {
        let v_b = t.quat_nb.inverse() * t.vel_ned;
        let noise = 0.02 * ((k as f64 * 0.7).sin());
        writeln!(with_speed, "{line} {:.4}", v_b.x + noise).expect("fmt");
    }
    std::fs::write(dir.path().join("imu.txt"), with_speed).expect("write imu");
    let toml = dir.path().join("constraints.toml");
    std::fs::write(
        &toml,
        "[nhc]\nenabled = true\n[odometer]\nenabled = true\nsigma_mps = 0.05\ncolumn = 8\n",
    )
    .expect("toml");
    let cfg =
        KfGinsConfig::from_file(&dir.path().join("kf-gins.yaml"), dir.path()).expect("config");
    let truth = kfgins::read_nav(&dir.path().join("truth.nav")).expect("truth");
    let outages = [(SOW0 + 60.0, SOW0 + 90.0), (SOW0 + 150.0, SOW0 + 180.0)];
    let drift = |fusion: &imulab::fusion::config::FusionConfig| {
        let r = kfgins::replay_files_with(&cfg, fusion, &outages, false).expect("replay");
        let s = summarise(&errors(&r.filtered, truth_lookup(&truth)), &outages);
        let worst = s
            .outages
            .iter()
            .map(|o| o.max_horizontal_m)
            .fold(0.0, f64::max);
        (worst, s, r.stats)
    };
    let mut nhc = cfg.fusion_config();
    nhc.nhc.enabled = true;
    let mut both = cfg.fusion_config();
    imulab::fusion::config::Constraints::from_file(&toml)
        .expect("constraints")
        .apply(&mut both);
    both.validate().expect("valid");
    let (d_nhc, _, _) = drift(&nhc);
    let (d_both, s_both, stats) = drift(&both);
    println!("worst outage drift: NHC {d_nhc:.3} m, NHC + odometer {d_both:.3} m; {stats:?}");
    assert!(stats.odometer_updates > 1000, "{stats:?}");
    assert_eq!(stats.odometer_rejected, 0);
    assert!(d_both < 0.7 * d_nhc, "{d_both} vs {d_nhc}");
    assert!(s_both.inside_3sigma > 0.97, "{}", s_both.inside_3sigma);
    // A missing column is an error naming the file and line.
    std::fs::write(dir.path().join("imu.txt"), imu).expect("write imu");
    let e = kfgins::replay_files_with(&cfg, &both, &outages, false).expect_err("no column 8");
    assert!(
        e.to_string().contains("imu.txt:1") && e.to_string().contains("8 columns"),
        "{e}"
    );
}
