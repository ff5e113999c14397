//! `imulab inspect/export/recover` on good and bad sessions, through the real binary:
//! reported figures, CSV contents, and one-line errors naming the file for bad input.

use std::path::Path;
use std::process::Command;

use crate::common::*;
use imulab::store::{EventKind, EventRecord, SessionWriter};

fn imulab(args: &[&str]) -> (bool, String, String) {
    let _serial = crate::common::child_process_guard();
    let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(args)
        .env("RUST_LOG", "off")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// 12 s at 100 Hz with one 0.5 s gap in imu_a and checksum-error events.
fn session_with_gap(dir: &Path) {
    let mut w = SessionWriter::create(dir, manifest(), fast_opts()).unwrap();
    for start in (0..1200).step_by(100) {
        let a: Vec<_> = (start..start + 100)
            .filter(|i| !(300..350).contains(i))
            .map(|i| imu_row(0, i))
            .collect();
        let b: Vec<_> = (start..start + 100).map(|i| imu_row(1, i)).collect();
        w.append_imu("imu_a", &a).unwrap();
        w.append_imu("imu_b", &b).unwrap();
        if start == 500 {
            for n in [3, 4] {
                w.append_event(&EventRecord {
                    t_mono_ns: imu_row(0, start).t_mono_ns,
                    t_wall_ns: 0,
                    device: "imu_a".into(),
                    kind: EventKind::ChecksumError,
                    detail: format!("count={n} crc mismatch"),
                })
                .unwrap();
            }
        }
    }
    w.close().unwrap();
}

fn one_line(stderr: &str) -> &str {
    let lines: Vec<&str> = stderr.trim().lines().collect();
    assert_eq!(lines.len(), 1, "expected one line of error, got: {stderr}");
    lines[0]
}

#[test]
fn inspect_reports_counts_rates_gaps_and_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("g");
    session_with_gap(&dir);
    let (ok, out, err) = imulab(&["inspect", dir.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let a = &v["devices"][0];
    assert_eq!(a["name"], "imu_a");
    assert_eq!(a["rows"], 1150);
    assert_eq!(a["gap_count"], 1);
    assert!((a["longest_gap_s"].as_f64().unwrap() - 0.51).abs() < 1e-9);
    assert_eq!(a["frames_errored"], 7);
    let b = &v["devices"][1];
    assert_eq!(b["rows"], 1200);
    assert_eq!(b["gap_count"], 0);
    assert!((b["effective_rate_hz"].as_f64().unwrap() - 100.0).abs() < 1e-6);
    assert_eq!(v["files"].as_array().unwrap().len(), 2);
    assert_eq!(v["events_by_kind"]["checksum_error"], 2);
    assert!(v["problems"].as_array().unwrap().is_empty());

    let (ok, text, _) = imulab(&["inspect", dir.to_str().unwrap()]);
    assert!(ok);
    assert!(text.contains("gaps > 3 periods: 1"), "{text}");
    // Gap times are seconds after the device's first sample: rows 300..350 are missing.
    assert!(text.contains("gap of 0.510 s at 2.990 s"), "{text}");
}

/// 12 s at 100 Hz as a USB serial link delivers it: rows in batches of 4 sharing one
/// arrival time (every 40 ms), after a start-up burst of 17 buffered rows arriving at once.
fn session_in_bursts(dir: &Path) {
    let mut w = SessionWriter::create(dir, manifest(), fast_opts()).unwrap();
    let arrival = |i: usize| -> i64 {
        let i = i.saturating_sub(16);
        imu_row(0, 16 + i / 4 * 4 + 3).t_mono_ns
    };
    for start in (0..1200).step_by(100) {
        for d in 0..2 {
            let rows: Vec<_> = (start..start + 100)
                .map(|i| {
                    let mut r = imu_row(d, i);
                    r.t_mono_ns = arrival(i);
                    r.t_sensor = i as f64; // a sample counter
                    r
                })
                .collect();
            w.append_imu(if d == 0 { "imu_a" } else { "imu_b" }, &rows)
                .unwrap();
        }
    }
    w.close().unwrap();
}

#[test]
fn inspect_rate_and_gaps_ignore_bursts_and_agree_with_allan() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bursts");
    session_in_bursts(&dir);
    let d = dir.to_str().unwrap();
    let (ok, out, err) = imulab(&["inspect", d, "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let a = &v["devices"][0];
    // rows / span would say (1200 - 1) / 11.84 s = 101.3 Hz.
    let rate = a["effective_rate_hz"].as_f64().unwrap();
    assert!((rate - 100.0).abs() < 0.05, "rate {rate}");
    // 40 ms between batches is no gap, for imulogd (gap_factor 3, at least 50 ms) and allan.
    assert_eq!(a["gap_count"], 0, "{a}");
    assert_eq!(a["gap_factor"], 3.0);
    let (ok, _, err) = imulab(&["allan", d, "--device", "imu_a", "--kind", "oadev"]);
    assert!(ok, "allan found a problem inspect did not: {err}");
}

#[test]
fn allan_on_an_hdf5_file_says_what_it_is_instead_of_parsing_csv() {
    let tmp = tempfile::tempdir().unwrap();
    let other = tmp.path().join("other.h5");
    {
        let f = hdf5::File::create(&other).unwrap();
        f.new_dataset::<f64>()
            .shape(10)
            .create("x")
            .unwrap()
            .write(&[0.0; 10])
            .unwrap();
    }
    let (ok, _, err) = imulab(&["allan", other.to_str().unwrap(), "--rate", "100"]);
    assert!(!ok);
    assert!(
        one_line(&err).contains("an HDF5 file that is not an imulab session"),
        "{err}"
    );
    let dir = tmp.path().join("s");
    write_session(&dir, 2, 100, fast_opts());
    let chunk = dir.join("chunk-000000.h5");
    let (ok, _, err) = imulab(&["allan", chunk.to_str().unwrap(), "--rate", "100"]);
    assert!(!ok);
    assert!(
        err.contains("give the session directory instead")
            && err.contains(&format!("imulab allan {}", dir.display())),
        "{err}"
    );
}

#[test]
fn export_streams_csv_with_exact_values_and_time_range() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("e");
    write_session(&dir, 12, 100, fast_opts());
    let csv_path = tmp.path().join("b.csv");
    let (ok, _, err) = imulab(&[
        "export",
        dir.to_str().unwrap(),
        "--device",
        "imu_b",
        "--format",
        "csv",
        "--start",
        "9.5",
        "--end",
        "10.5",
        "-o",
        csv_path.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let mut r = csv::Reader::from_path(&csv_path).unwrap();
    let rows: Vec<csv::StringRecord> = r.records().map(|x| x.unwrap()).collect();
    assert_eq!(rows.len(), 100);
    let expect = imu_row(1, 950);
    assert_eq!(rows[0][0].parse::<i64>().unwrap(), expect.t_mono_ns);
    assert_eq!(rows[0][3].parse::<f64>().unwrap(), expect.gyro[0]);
    assert_eq!(rows[0][8].parse::<f64>().unwrap(), expect.accel[2]);
    assert_eq!(
        rows[99][0].parse::<i64>().unwrap(),
        imu_row(1, 1049).t_mono_ns
    );

    let (ok, out, _) = imulab(&["export", dir.to_str().unwrap(), "--device", "gps"]);
    assert!(ok);
    assert_eq!(out.lines().count(), 1 + 60);
    let (ok, _, err) = imulab(&["export", dir.to_str().unwrap(), "--device", "nope"]);
    assert!(!ok);
    assert!(one_line(&err).contains("nope"), "{err}");
}

#[test]
fn bad_chunk_files_are_named_and_the_rest_still_inspected() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bad");
    write_session(&dir, 25, 100, fast_opts());
    // Truncate the first chunk file, replace none of the others.
    let first = dir.join("chunk-000000.h5");
    let len = std::fs::metadata(&first).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&first)
        .unwrap()
        .set_len(len / 2)
        .unwrap();
    // A stray file of garbage with a chunk name.
    std::fs::write(dir.join("chunk-000007.h5"), b"this is not hdf5 at all").unwrap();
    // A chunk file from an unknown future layout.
    {
        let f = hdf5::File::open_rw(dir.join("chunk-000002.h5")).unwrap();
        f.attr("schema_version")
            .unwrap()
            .write_scalar(&99u32)
            .unwrap();
    }
    let (ok, out, err) = imulab(&["inspect", dir.to_str().unwrap(), "--json"]);
    assert!(!ok);
    let line = one_line(&err);
    assert!(
        line.contains("3 problem(s)") && line.contains("chunk-000000.h5"),
        "{line}"
    );
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let problems: Vec<String> = v["problems"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap().to_string())
        .collect();
    assert_eq!(problems.len(), 3, "{problems:?}");
    assert!(
        problems[0].contains("chunk-000000.h5") && problems[0].contains("truncated or corrupt")
    );
    assert!(
        problems[1].contains("chunk-000002.h5")
            && problems[1].contains("unknown schema version 99")
    );
    assert!(problems[2].contains("chunk-000007.h5"));
    // chunk-000001.h5 (10 s..20 s of data) is still counted.
    assert_eq!(v["devices"][0]["rows"], 1000);

    // The library reader yields one error per bad file, in place, and carries on.
    let s = imulab::store::Session::open(&dir).unwrap();
    let results: Vec<_> = s
        .imu_blocks("imu_a", imulab::store::TimeRange::all(), 5000)
        .unwrap()
        .collect();
    assert_eq!(results.len(), 4);
    assert!(results[0]
        .as_ref()
        .unwrap_err()
        .to_string()
        .contains("chunk-000000.h5"));
    assert_eq!(results[1].as_ref().unwrap().record(0), imu_row(0, 1000));
}

#[test]
fn non_sessions_and_bad_manifests_give_one_line_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    for (args, expect) in [
        (
            vec!["inspect", empty.to_str().unwrap()],
            "not a session directory: no session.toml",
        ),
        (vec!["inspect", "/nonexistent/xyz"], "no such directory"),
        (vec!["recover", empty.to_str().unwrap()], "no session.toml"),
    ] {
        let (ok, _, err) = imulab(&args);
        assert!(!ok);
        assert!(one_line(&err).contains(expect), "{args:?}: {err}");
    }

    let dir = tmp.path().join("m");
    write_session(&dir, 2, 100, fast_opts());
    let manifest_path = dir.join("session.toml");
    let text = std::fs::read_to_string(&manifest_path).unwrap();
    std::fs::write(
        &manifest_path,
        text.replace("schema_version = 2", "schema_version = 99"),
    )
    .unwrap();
    let (ok, _, err) = imulab(&["inspect", dir.to_str().unwrap()]);
    assert!(!ok);
    let line = one_line(&err);
    assert!(
        line.contains("session.toml") && line.contains("unknown schema version 99"),
        "{line}"
    );

    std::fs::write(
        &manifest_path,
        text.replace("rate_hz = 100.0", "rate_hz = \"fast\""),
    )
    .unwrap();
    let (ok, _, err) = imulab(&["inspect", dir.to_str().unwrap()]);
    assert!(!ok);
    let line = one_line(&err);
    assert!(
        line.contains("session.toml") && line.contains("bad manifest"),
        "{line}"
    );

    std::fs::write(
        &manifest_path,
        text.replace("[[devices]]", "colour = \"red\"\n[[devices]]"),
    )
    .unwrap();
    let (ok, _, err) = imulab(&["inspect", dir.to_str().unwrap()]);
    assert!(!ok);
    assert!(one_line(&err).contains("colour"), "{err}");

    std::fs::write(&manifest_path, &text).unwrap();
    let (ok, out, _) = imulab(&["recover", dir.to_str().unwrap()]);
    assert!(ok);
    assert!(out.contains("nothing to recover"));
}

#[test]
fn corrupted_bytes_inside_a_chunk_give_errors_not_crashes() {
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join("good");
    write_session(&good, 12, 100, fast_opts());
    let original = std::fs::read(good.join("chunk-000000.h5")).unwrap();
    let mut detected = 0;
    for percent in [5, 20, 35, 50, 65, 80, 95] {
        let dir = tmp.path().join(format!("c{percent}"));
        std::fs::create_dir(&dir).unwrap();
        std::fs::copy(good.join("session.toml"), dir.join("session.toml")).unwrap();
        std::fs::copy(good.join("chunk-000001.h5"), dir.join("chunk-000001.h5")).unwrap();
        let mut bytes = original.clone();
        let at = bytes.len() * percent / 100;
        for b in &mut bytes[at..at + 64] {
            *b ^= 0x5a;
        }
        std::fs::write(dir.join("chunk-000000.h5"), &bytes).unwrap();
        let _serial = crate::common::child_process_guard();
        let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
            .args(["inspect", "--json", dir.to_str().unwrap()])
            .env("RUST_LOG", "off")
            .output()
            .unwrap();
        // Never a crash or a panic: either a clean report or a report plus one-line error.
        assert!(
            out.status.code().is_some(),
            "{percent}%: killed by a signal"
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!stderr.contains("panicked"), "{percent}%: {stderr}");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        // The undamaged second file is always counted.
        assert!(
            v["devices"][0]["rows"].as_u64().unwrap() >= 200,
            "{percent}%"
        );
        eprintln!(
            "{percent}%: rows {} problems {}",
            v["devices"][0]["rows"], v["problems"]
        );
        if !out.status.success() {
            assert!(one_line(&stderr).contains("chunk-000000.h5"), "{stderr}");
            detected += 1;
        }
    }
    // Damage in the compressed data or in the metadata inspect walks is found (a few bytes
    // in unused space may not be).
    assert!(
        detected >= 4,
        "only {detected} of 7 corruptions were reported"
    );
}
