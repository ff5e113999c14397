//! Offset invariance, f32 promotion and bad-input rules of the Allan analyser, plus an
//! end-to-end run of `imulab allan` checking the JSON document's documented fields.

use imulab::allan::input::{open_file, read_axis, DataKind, GapPolicy, Timing};
use imulab::allan::{compute_curve, DeviationKind, Phase, TauGrid};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;

fn noise(n: usize, scale: f64, seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut walk = 0.0;
    (0..n)
        .map(|_| {
            let w: f64 = StandardNormal.sample(&mut rng);
            let s: f64 = StandardNormal.sample(&mut rng);
            walk += 1e-3 * s;
            scale * (w + walk)
        })
        .collect()
}

#[test]
fn one_g_offset_changes_no_deviation_beyond_1e9() {
    let y = noise(100_000, 1e-3, 3);
    let shifted: Vec<f64> = y.iter().map(|v| v + 9.806_65).collect();
    let base = Phase::from_rate(y);
    let offset = Phase::from_rate(shifted);
    for kind in DeviationKind::ALL {
        let a = compute_curve(&base, 0.01, kind, &TauGrid::Octave);
        let b = compute_curve(&offset, 0.01, kind, &TauGrid::Octave);
        assert_eq!(a.points.len(), b.points.len());
        for (p, q) in a.points.iter().zip(&b.points) {
            let rel = (p.deviation - q.deviation).abs() / p.deviation;
            assert!(
                rel < 1e-9,
                "{kind:?} tau {}: relative change {rel:e}",
                p.tau
            );
        }
    }
}

#[test]
fn huge_clock_phase_offset_changes_nothing_beyond_1e9() {
    // Phase in seconds: 1e-9-level noise riding on a 1e-3 s offset and a 1e-6 frequency offset.
    let y = noise(20_001, 1e-9, 4);
    let mut x = vec![0.0];
    for v in &y {
        let last = *x.last().unwrap();
        x.push(last + v);
    }
    let shifted: Vec<f64> = x
        .iter()
        .enumerate()
        .map(|(i, v)| v + 1e-3 + 1e-6 * i as f64)
        .collect();
    let a = Phase::from_phase(&x, 1.0);
    let b = Phase::from_phase(&shifted, 1.0);
    for kind in DeviationKind::ALL {
        let ca = compute_curve(&a, 1.0, kind, &TauGrid::Octave);
        let cb = compute_curve(&b, 1.0, kind, &TauGrid::Octave);
        for (p, q) in ca.points.iter().zip(&cb.points) {
            let rel = (p.deviation - q.deviation).abs() / p.deviation;
            assert!(
                rel < 1e-9,
                "{kind:?} tau {}: relative change {rel:e}",
                p.tau
            );
        }
    }
}

fn write_npy_f32(path: &Path, data: &[f32]) {
    use npyz::WriterBuilder;
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[data.len() as u64])
        .writer(file)
        .begin_nd()
        .unwrap();
    w.extend(data.iter().copied()).unwrap();
    w.finish().unwrap();
}

#[test]
fn f32_input_is_promoted_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f32.npy");
    let y32: Vec<f32> = noise(10_000, 1e-2, 5)
        .iter()
        .map(|&v| v as f32 + 9.80665)
        .collect();
    write_npy_f32(&path, &y32);
    let source = open_file(&path).unwrap();
    let series = read_axis(
        source.as_ref(),
        0,
        &Timing::Rate(100.0),
        GapPolicy::Error,
        DataKind::Rate,
        None,
    )
    .unwrap();
    let promoted: Vec<f64> = y32.iter().map(|&v| f64::from(v)).collect();
    assert_eq!(series.segments[0], promoted);
}

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn bad_inputs_give_clear_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    // Empty file.
    let empty = write(dir.path(), "empty.csv", "");
    assert!(open_file(&empty)
        .err()
        .unwrap()
        .to_string()
        .contains("no data rows"));
    // Non-uniform sampling.
    let jitter = write(
        dir.path(),
        "jitter.csv",
        "t,g\n0,1\n0.1,1\n0.25,1\n0.3,1\n0.4,1\n",
    );
    let src = open_file(&jitter).unwrap();
    let err = read_axis(
        src.as_ref(),
        1,
        &Timing::TimeChannel {
            channel: 0,
            scale: 1.0,
        },
        GapPolicy::Error,
        DataKind::Rate,
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("non-uniform") && err.contains("sample 2"),
        "{err}"
    );
    // Time going backwards.
    let back = write(
        dir.path(),
        "back.csv",
        "t,g\n0,1\n0.1,1\n0.05,1\n0.15,1\n0.25,1\n",
    );
    let src = open_file(&back).unwrap();
    let err = read_axis(
        src.as_ref(),
        1,
        &Timing::TimeChannel {
            channel: 0,
            scale: 1.0,
        },
        GapPolicy::Error,
        DataKind::Rate,
        None,
    )
    .unwrap_err();
    assert!(
        err.to_string()
            .contains("sample 2: time stamp 0.050000 s does not increase"),
        "{err}"
    );
    // Inf value.
    let inf = write(dir.path(), "inf.csv", "g\n1\ninf\n2\n");
    let src = open_file(&inf).unwrap();
    let err = read_axis(
        src.as_ref(),
        0,
        &Timing::Rate(1.0),
        GapPolicy::Error,
        DataKind::Rate,
        None,
    )
    .unwrap_err();
    assert!(err.to_string().contains("sample 1: value is inf"), "{err}");
    // Not an npy file.
    let fake = write(dir.path(), "fake.npy", "definitely not numpy");
    assert!(open_file(&fake).is_err());
    // Nonsense rate.
    let ok = write(dir.path(), "ok.csv", "1\n2\n3\n");
    let src = open_file(&ok).unwrap();
    assert!(read_axis(
        src.as_ref(),
        0,
        &Timing::Rate(-5.0),
        GapPolicy::Error,
        DataKind::Rate,
        None
    )
    .is_err());
    assert!(read_axis(
        src.as_ref(),
        0,
        &Timing::Rate(f64::NAN),
        GapPolicy::Error,
        DataKind::Rate,
        None
    )
    .is_err());
    // Too short for anything: curves are empty, not a panic.
    let phase = Phase::from_rate(vec![1.0]);
    for kind in DeviationKind::ALL {
        assert!(compute_curve(&phase, 1.0, kind, &TauGrid::All)
            .points
            .is_empty());
    }
}

#[test]
fn cli_writes_documented_json() {
    let dir = tempfile::tempdir().unwrap();
    let y = noise(20_000, 1e-3, 6);
    let mut text = String::from("t,gx,temp\n");
    for (i, v) in y.iter().enumerate() {
        text.push_str(&format!(
            "{},{v},{}\n",
            i as f64 * 0.01,
            20.0 + (i / 2000) as f64
        ));
    }
    let input = write(dir.path(), "gyro.csv", &text);
    let json = dir.path().join("out.json");
    let html = dir.path().join("out.html");
    let kalibr = dir.path().join("imu.yaml");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args([
            "allan",
            input.to_str().unwrap(),
            "--time-column",
            "t",
            "--temperature-column",
            "temp",
            "--axes",
            "gx",
        ])
        .args([
            "--units",
            "rad/s",
            "--fit",
            "--json",
            json.to_str().unwrap(),
            "--html",
            html.to_str().unwrap(),
        ])
        .args(["--kalibr", kalibr.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(doc["schema_version"], 1);
    let axis = &doc["axes"][0];
    assert_eq!(axis["axis"], "gx");
    assert_eq!(axis["sensor"], "gyro");
    let point = &axis["curve"]["points"][0];
    for key in [
        "tau",
        "deviation",
        "low",
        "high",
        "edf",
        "count",
        "alpha",
        "m",
    ] {
        assert!(!point[key].is_null(), "missing {key}");
    }
    assert!(axis["terms"]
        .as_array()
        .unwrap()
        .iter()
        .any(|t| t["name"] == "ARW" && t["identified"] == true));
    assert!(axis["thermal"]["bins"].as_array().unwrap().len() >= 2);
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.contains("<svg"));
    assert!(!page.contains("<script") && !page.contains("src=\"http"));
    assert!(std::fs::read_to_string(&kalibr)
        .unwrap()
        .contains("gyroscope_noise_density:"));
    // A bad column name is a clear error with a non-zero exit.
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args([
            "allan",
            input.to_str().unwrap(),
            "--rate",
            "100",
            "--axes",
            "nope",
        ])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("no channel `nope`"));
}
