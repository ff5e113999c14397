//! Logger CSVs through `imulab allan`/`imulab report` end to end: time, temperature and sensor
//! columns found by name, the time column's unit inferred (millis() stamps), per-column
//! units of a mixed gyro+accel file, semicolon, space-aligned and several inputs in one run,
//! and named-column errors when something cannot be decided. The files are white noise of
//! known density, so τ0 and the fitted ARW/VRW are checked against their true values.

use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Samples per file: 5 minutes at 100 Hz.
const N: usize = 30_000;
const RATE_HZ: f64 = 100.0;
/// White noise per sample of the gyro (deg/s) and accelerometer (g) columns.
const GYRO_SIGMA: f64 = 0.1;
const ACCEL_SIGMA: f64 = 0.002;

fn white(seed: u64, sigma: f64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    (0..N)
        .map(|_| {
            let w: f64 = StandardNormal.sample(&mut rng);
            sigma * w
        })
        .collect()
}

/// Writes a file with `header` (already joined) and one row per sample: `time(i)`, then
/// the columns, joined by `sep`; `decimal` replaces the decimal point (`,` for European
/// semicolon files).
fn write_file(
    dir: &Path,
    name: &str,
    header: &str,
    sep: &str,
    decimal: char,
    time: impl Fn(usize) -> String,
    columns: &[Vec<f64>],
) -> PathBuf {
    let mut text = format!("{header}\n");
    for i in 0..N {
        let mut row = vec![time(i)];
        row.extend(columns.iter().map(|c| format!("{:.7}", c[i])));
        let row: Vec<String> = row
            .into_iter()
            .map(|f| f.replace('.', &decimal.to_string()))
            .collect();
        text.push_str(&row.join(sep));
        text.push('\n');
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn seconds(i: usize) -> String {
    format!("{:.2}", i as f64 / RATE_HZ)
}

fn imulab(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(args: &[&str]) -> (String, String) {
    let out = imulab(args);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    );
    assert!(out.status.success(), "imulab {args:?}: {stderr}");
    (stdout, stderr)
}

fn fails(args: &[&str]) -> String {
    let out = imulab(args);
    assert!(!out.status.success(), "imulab {args:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn axes(doc: &serde_json::Value) -> Vec<String> {
    doc["axes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| {
            format!(
                "{} {}",
                a["device"].as_str().unwrap(),
                a["axis"].as_str().unwrap()
            )
        })
        .collect()
}

/// The value of term `name` in `unit` of axis `axis`.
fn term(doc: &serde_json::Value, axis: &str, name: &str, unit: &str) -> f64 {
    let a = doc["axes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["axis"] == axis)
        .unwrap_or_else(|| panic!("no axis {axis}"));
    let t = a["terms"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["name"] == name)
        .unwrap_or_else(|| panic!("{axis}: no {name}"));
    t["values"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["unit"] == unit)
        .and_then(|v| v["value"].as_f64())
        .unwrap_or_else(|| panic!("{axis} {name}: no value in {unit}"))
}

fn tau0(doc: &serde_json::Value, axis: usize) -> f64 {
    doc["axes"][axis]["tau0"].as_f64().unwrap()
}

/// ARW of the gyro columns, °/√h: σ/√fs °/s/√Hz × 60.
fn true_arw() -> f64 {
    GYRO_SIGMA / RATE_HZ.sqrt() * 60.0
}

/// VRW of the accelerometer columns, m/s/√h.
fn true_vrw() -> f64 {
    ACCEL_SIGMA * 9.806_65 / RATE_HZ.sqrt() * 60.0
}

fn close(got: f64, want: f64, rel: f64, what: &str) {
    assert!(
        (got / want - 1.0).abs() <= rel,
        "{what}: {got} vs {want} (±{rel})"
    );
}

#[test]
fn time_columns_found_by_name_and_temperature_is_not_an_axis() {
    let dir = tempfile::tempdir().unwrap();
    let temp: Vec<f64> = (0..N).map(|i| 20.0 + 10.0 * i as f64 / N as f64).collect();
    for (k, name) in ["time", "t", "timestamp"].iter().enumerate() {
        let file = write_file(
            dir.path(),
            &format!("{name}.csv"),
            &format!("{name},gx,Temp"),
            ",",
            '.',
            seconds,
            &[white(k as u64, GYRO_SIGMA), temp.clone()],
        );
        let out = dir.path().join(format!("{name}.json"));
        let (stdout, _) = ok(&[
            "allan",
            file.to_str().unwrap(),
            "--units",
            "deg/s",
            "--fit",
            "--json",
            out.to_str().unwrap(),
        ]);
        let doc = json(&out);
        assert_eq!(axes(&doc), vec![format!("{name} gx")], "{name}");
        close(tau0(&doc, 0), 0.01, 1e-9, name);
        close(
            term(&doc, "gx", "ARW", "deg/sqrt(h)"),
            true_arw(),
            0.05,
            name,
        );
        // The temperature column feeds the thermal summary, in °/h/°C on the terminal.
        assert!(doc["axes"][0]["thermal"]["bins"].as_array().unwrap().len() >= 2);
        assert!(stdout.contains("°/h/°C"), "{stdout}");
        assert!(stdout.contains("tau0 0.01 s"), "{stdout}");
        assert!(
            stdout.contains(&format!("wrote {}", out.display())),
            "{stdout}"
        );
    }
}

/// A phone app's epoch nanoseconds (1.7·10¹⁸, beyond f64's exact integers): read as
/// floats, 10 ms steps come out as 9.999872 or 10.000128 ms and τ0 as 0.00999999 s.
#[test]
fn epoch_nanosecond_stamps_give_the_exact_interval() {
    let dir = tempfile::tempdir().unwrap();
    let file = write_file(
        dir.path(),
        "phone.csv",
        "timestamp,gx",
        ",",
        '.',
        |i| (1_700_000_000_123_456_789u64 + 10_000_000 * i as u64).to_string(),
        &[white(14, GYRO_SIGMA)],
    );
    let out = dir.path().join("p.json");
    let (stdout, _) = ok(&[
        "allan",
        file.to_str().unwrap(),
        "--json",
        out.to_str().unwrap(),
    ]);
    close(tau0(&json(&out), 0), 0.01, 1e-12, "τ0");
    assert!(stdout.contains("tau0 0.01 s"), "{stdout}");
}

#[test]
fn millis_timestamps_are_read_as_milliseconds() {
    let dir = tempfile::tempdir().unwrap();
    // An Arduino sketch printing millis() every 10 ms, integer stamps from boot.
    let file = write_file(
        dir.path(),
        "arduino.csv",
        "millis,gx,gy",
        ",",
        '.',
        |i| (12_345 + 10 * i).to_string(),
        &[white(10, GYRO_SIGMA), white(11, GYRO_SIGMA)],
    );
    let out = dir.path().join("a.json");
    ok(&[
        "allan",
        file.to_str().unwrap(),
        "--units",
        "deg/s",
        "--fit",
        "--json",
        out.to_str().unwrap(),
    ]);
    let doc = json(&out);
    assert_eq!(axes(&doc), vec!["arduino gx", "arduino gy"]);
    close(tau0(&doc, 0), 0.01, 1e-9, "τ0");
    close(
        term(&doc, "gy", "ARW", "deg/sqrt(h)"),
        true_arw(),
        0.05,
        "ARW",
    );
    // The same stamps under a name without a unit: inferred from the step (10 → ms).
    let file = write_file(
        dir.path(),
        "stamp.csv",
        "timestamp,gx",
        ",",
        '.',
        |i| (10 * i).to_string(),
        &[white(12, GYRO_SIGMA)],
    );
    ok(&[
        "allan",
        file.to_str().unwrap(),
        "--json",
        out.to_str().unwrap(),
    ]);
    close(tau0(&json(&out), 0), 0.01, 1e-9, "τ0 from the step");
    // A stated rate decides a µs column too.
    let file = write_file(
        dir.path(),
        "micros.csv",
        "t,gx",
        ",",
        '.',
        |i| (1_000_000 + 10_000 * i).to_string(),
        &[white(13, GYRO_SIGMA)],
    );
    ok(&[
        "allan",
        file.to_str().unwrap(),
        "--json",
        out.to_str().unwrap(),
    ]);
    close(tau0(&json(&out), 0), 0.01, 1e-9, "τ0 from µs");
}

#[test]
fn ambiguous_time_unit_warns_and_says_how_to_decide() {
    let dir = tempfile::tempdir().unwrap();
    // Steps of 1000: 1 Hz in ms or 1 kHz in µs.
    let file = write_file(
        dir.path(),
        "odd.csv",
        "t,gx",
        ",",
        '.',
        |i| (1000 * i).to_string(),
        &[white(14, GYRO_SIGMA)],
    );
    let out = dir.path().join("o.json");
    let (_, stderr) = ok(&[
        "allan",
        file.to_str().unwrap(),
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(
        stderr.contains("warning") && stderr.contains("`t`") && stderr.contains("ambiguous"),
        "{stderr}"
    );
    // --rate settles it without a warning: the 1 Hz reading.
    let (_, stderr) = ok(&[
        "allan",
        file.to_str().unwrap(),
        "--rate",
        "1",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert!(!stderr.contains("warning"), "{stderr}");
    close(tau0(&json(&out), 0), 1.0, 1e-12, "τ0 with --rate 1");
}

#[test]
fn space_aligned_time_seconds_with_rate_is_not_analysed() {
    let dir = tempfile::tempdir().unwrap();
    let (g, a) = (white(20, GYRO_SIGMA), white(21, ACCEL_SIGMA));
    let mut text = String::from("  Time (s)        gx        ax\n");
    for i in 0..N {
        text.push_str(&format!(
            "{:>10.2}  {:>8.5}  {:>8.6}\n",
            i as f64 / RATE_HZ,
            g[i],
            a[i]
        ));
    }
    let file = dir.path().join("logger.txt");
    std::fs::write(&file, text).unwrap();
    let out = dir.path().join("l.json");
    ok(&[
        "allan",
        file.to_str().unwrap(),
        "--rate",
        "100",
        "--columns",
        "gx=deg/s ax=g",
        "--fit",
        "--json",
        out.to_str().unwrap(),
    ]);
    let doc = json(&out);
    assert_eq!(axes(&doc), vec!["logger gx", "logger ax"]);
    close(tau0(&doc, 0), 0.01, 1e-12, "τ0");
    close(
        term(&doc, "gx", "ARW", "deg/sqrt(h)"),
        true_arw(),
        0.05,
        "ARW",
    );
    close(
        term(&doc, "ax", "VRW", "m/s/sqrt(h)"),
        true_vrw(),
        0.05,
        "VRW",
    );
    // A rate the time column contradicts is refused, naming the column.
    let err = fails(&["allan", file.to_str().unwrap(), "--rate", "50"]);
    assert!(
        err.contains("`Time (s)`") && err.contains("100 Hz"),
        "{err}"
    );
}

/// A six-column logger file `t,gx,gy,gz,ax,ay,az` (deg/s and g).
fn mixed_file(dir: &Path, name: &str, seed: u64) -> PathBuf {
    let mut columns: Vec<Vec<f64>> = (0..3).map(|k| white(seed + k, GYRO_SIGMA)).collect();
    columns.extend((3..6).map(|k| white(seed + k, ACCEL_SIGMA)));
    write_file(
        dir,
        name,
        "t,gx,gy,gz,ax,ay,az",
        ",",
        '.',
        seconds,
        &columns,
    )
}

#[test]
fn mixed_gyro_accel_units_per_column_in_either_argument_order() {
    let dir = tempfile::tempdir().unwrap();
    let file = mixed_file(dir.path(), "imu.csv", 30);
    let file = file.to_str().unwrap();
    let out = dir.path().join("m.json");
    let out_s = out.to_str().unwrap();
    // Two occurrences after the input, and one quoted value before it.
    let orders: [Vec<&str>; 2] = [
        vec![
            "allan",
            file,
            "--columns",
            "gx,gy,gz=deg/s",
            "--columns",
            "ax,ay,az=g",
        ],
        vec!["allan", "--columns", "gx,gy,gz=deg/s ax,ay,az=g", file],
    ];
    for args in orders {
        let mut args = args.clone();
        args.extend(["--fit", "--json", out_s]);
        ok(&args);
        let doc = json(&out);
        let sensors: Vec<&str> = doc["axes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a["sensor"].as_str().unwrap())
            .collect();
        assert_eq!(sensors, ["gyro", "gyro", "gyro", "accel", "accel", "accel"]);
        for axis in ["gx", "gy", "gz"] {
            close(
                term(&doc, axis, "ARW", "deg/sqrt(h)"),
                true_arw(),
                0.05,
                axis,
            );
        }
        for axis in ["ax", "ay", "az"] {
            close(
                term(&doc, axis, "VRW", "m/s/sqrt(h)"),
                true_vrw(),
                0.05,
                axis,
            );
            let mg = term(&doc, axis, "VRW", "mg/sqrt(Hz)");
            close(mg, ACCEL_SIGMA * 1000.0 / RATE_HZ.sqrt(), 0.05, axis);
        }
    }
    // A second group the shell split off from --columns is explained, not opened as a file.
    let err = fails(&["allan", file, "--columns", "gx,gy,gz=deg/s", "ax,ay,az=g"]);
    assert!(
        err.contains("`ax,ay,az=g`") && err.contains("--columns"),
        "{err}"
    );
    // One unit for all of a mixed file names the column it does not fit.
    let err = fails(&["allan", file, "--units", "deg/s"]);
    assert!(err.contains("`ax`") && err.contains("--columns"), "{err}");
    // The report of the mixed file shows both sensors' datasheet rows in one run.
    let html = dir.path().join("r.html");
    let (stdout, _) = ok(&[
        "report",
        file,
        "--columns",
        "gx,gy,gz=deg/s ax,ay,az=g",
        "--html",
        html.to_str().unwrap(),
    ]);
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.contains("Gyro ARW") && page.contains("Accel VRW"));
    // Summary and "wrote" by default: no τ table.
    assert!(
        stdout.contains(&format!("wrote {}", html.display())),
        "{stdout}"
    );
    assert!(!stdout.contains("tau [s]"), "{stdout}");
    assert!(stdout.lines().count() < 40, "{stdout}");
    let (verbose, _) = ok(&[
        "report",
        file,
        "--columns",
        "gx,gy,gz=deg/s ax,ay,az=g",
        "--html",
        html.to_str().unwrap(),
        "-v",
    ]);
    assert!(
        verbose.contains("tau [s]") && verbose.contains("[°/s]"),
        "{verbose}"
    );
    let (quiet, _) = ok(&[
        "report",
        file,
        "--columns",
        "gx,gy,gz=deg/s ax,ay,az=g",
        "--html",
        html.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(quiet, "");
}

#[test]
fn semicolon_file_with_decimal_commas() {
    let dir = tempfile::tempdir().unwrap();
    let file = write_file(
        dir.path(),
        "phone.csv",
        "Timestamp;gyro_x;gyro_y",
        ";",
        ',',
        seconds,
        &[white(40, GYRO_SIGMA), white(41, GYRO_SIGMA)],
    );
    let out = dir.path().join("p.json");
    ok(&[
        "allan",
        file.to_str().unwrap(),
        "--units",
        "deg/s",
        "--fit",
        "--json",
        out.to_str().unwrap(),
    ]);
    let doc = json(&out);
    assert_eq!(axes(&doc), vec!["phone gyro_x", "phone gyro_y"]);
    close(tau0(&doc, 0), 0.01, 1e-9, "τ0");
    close(
        term(&doc, "gyro_y", "ARW", "deg/sqrt(h)"),
        true_arw(),
        0.05,
        "ARW",
    );
}

#[test]
fn two_inputs_in_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let a = mixed_file(dir.path(), "a.csv", 50);
    let b = write_file(
        dir.path(),
        "b.csv",
        "time,gx",
        ",",
        '.',
        seconds,
        &[white(60, 2.0 * GYRO_SIGMA)],
    );
    let out = dir.path().join("ab.json");
    ok(&[
        "allan",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--columns",
        "gx,gy,gz=deg/s ax,ay,az=g",
        "--fit",
        "--json",
        out.to_str().unwrap(),
    ]);
    let doc = json(&out);
    assert_eq!(
        axes(&doc),
        ["a gx", "a gy", "a gz", "a ax", "a ay", "a az", "b gx"]
    );
    let b_arw = doc["axes"][6]["terms"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["name"] == "ARW")
        .unwrap()["values"][0]["value"]
        .as_f64()
        .unwrap();
    close(b_arw, 2.0 * true_arw(), 0.05, "b ARW");
    assert_eq!(doc["input"].as_array().unwrap().len(), 2);
    // A --columns name that no input has is a typo, named.
    let err = fails(&[
        "allan",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--columns",
        "gq=deg/s",
    ]);
    assert!(err.contains("no input has a column `gq`"), "{err}");
}

#[test]
fn undecidable_columns_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let g = white(70, GYRO_SIGMA);
    let file = write_file(
        dir.path(),
        "two.csv",
        "time,timestamp,gx",
        ",",
        '.',
        seconds,
        &[(0..N).map(|i| i as f64 * 10.0).collect(), g.clone()],
    );
    let err = fails(&["allan", file.to_str().unwrap()]);
    assert!(
        err.contains("`time`, `timestamp`") && err.contains("--time-column"),
        "{err}"
    );
    // Naming one decides; the other time-like column is not analysed either.
    let out = dir.path().join("t.json");
    ok(&[
        "allan",
        file.to_str().unwrap(),
        "--time-column",
        "time",
        "--json",
        out.to_str().unwrap(),
    ]);
    assert_eq!(axes(&json(&out)), ["two gx"]);
    // No time column and no rate: the error lists the columns.
    let file = write_file(
        dir.path(),
        "none.csv",
        "sample,gx",
        ",",
        '.',
        |i| i.to_string(),
        &[g],
    );
    let err = fails(&["allan", file.to_str().unwrap()]);
    assert!(
        err.contains("sample, gx") && err.contains("--rate"),
        "{err}"
    );
}

#[test]
fn compare_of_two_six_axis_files_fits_100_columns() {
    let dir = tempfile::tempdir().unwrap();
    let cheap = mixed_file(dir.path(), "cheap.csv", 80);
    let dear = mixed_file(dir.path(), "dear.csv", 90);
    let (stdout, _) = ok(&[
        "compare",
        cheap.to_str().unwrap(),
        dear.to_str().unwrap(),
        "--columns",
        "gx,gy,gz=deg/s ax,ay,az=g",
    ]);
    let widest = stdout.lines().map(|l| l.chars().count()).max().unwrap();
    assert!(widest <= 100, "{widest} columns:\n{stdout}");
    // The ARW row shows, in input order, the values the fit gives (`allan --fit --json`).
    let json_path = dir.path().join("both.json");
    ok(&[
        "allan",
        cheap.to_str().unwrap(),
        dear.to_str().unwrap(),
        "--columns",
        "gx,gy,gz=deg/s ax,ay,az=g",
        "--fit",
        "--json",
        json_path.to_str().unwrap(),
    ]);
    let doc = json(&json_path);
    let fitted: Vec<f64> = doc["axes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["sensor"] == "gyro")
        .map(|a| {
            a["terms"]
                .as_array()
                .unwrap()
                .iter()
                .find(|t| t["name"] == "ARW")
                .unwrap()["values"][0]["value"]
                .as_f64()
                .unwrap()
        })
        .collect();
    let arw = stdout.lines().find(|l| l.starts_with("ARW")).unwrap();
    let cells: Vec<f64> = arw
        .split_whitespace()
        .skip(2)
        .map(|c| c.parse().unwrap())
        .collect();
    assert_eq!(cells.len(), 6, "{arw}");
    for (cell, value) in cells.iter().zip(&fitted) {
        close(*cell, *value, 5e-3, "ARW cell");
    }
    assert!(
        stdout.contains("cheap") && stdout.contains("dear"),
        "{stdout}"
    );
}

#[test]
fn phone_app_quoted_header_with_units_in_brackets() {
    let dir = tempfile::tempdir().unwrap();
    // A phone app's export: quoted names with units, seconds from start, gyro in rad/s.
    let sigma_rad = GYRO_SIGMA.to_radians();
    let file = write_file(
        dir.path(),
        "phone.csv",
        "\"Time (s)\",\"Gyroscope x (rad/s)\",\"Acceleration x (m/s^2)\"",
        ",",
        '.',
        |i| format!("{:.3}", i as f64 / RATE_HZ),
        &[white(100, sigma_rad), white(101, ACCEL_SIGMA * 9.806_65)],
    );
    let out = dir.path().join("p.json");
    ok(&[
        "allan",
        file.to_str().unwrap(),
        "--fit",
        "--json",
        out.to_str().unwrap(),
    ]);
    let doc = json(&out);
    assert_eq!(
        axes(&doc),
        ["phone Gyroscope x (rad/s)", "phone Acceleration x (m/s^2)"]
    );
    close(tau0(&doc, 0), 0.01, 1e-9, "τ0");
    close(
        term(&doc, "Gyroscope x (rad/s)", "ARW", "deg/sqrt(h)"),
        true_arw(),
        0.05,
        "ARW",
    );
    close(
        term(&doc, "Acceleration x (m/s^2)", "VRW", "m/s/sqrt(h)"),
        true_vrw(),
        0.05,
        "VRW",
    );
}
