//! The report a person reads: `imulab report SESSION` on a short two-IMU session writes one
//! self-contained page (no URL in it) in the order summary → datasheet → curves → data
//! health, with the logger's events, temperatures and the outage horizons; one valid PNG per
//! plot; and the page renders in a real browser (headless Chromium screenshot; skipped with
//! the reason when Chromium is absent).

use imulab::store::{
    DeviceInfo, DeviceKind, EventKind, EventRecord, ImuRecord, Manifest, SessionWriter,
    WriterOptions,
};
use imulab_test_support::browser::{chromium, chromium_missing, run};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;
use std::process::Command;

const RATE_HZ: f64 = 100.0;
const ROWS: usize = 30_000;

fn imu(name: &str) -> DeviceInfo {
    DeviceInfo {
        name: name.into(),
        kind: DeviceKind::Imu,
        model: format!("test-{name}"),
        serial: String::new(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz: RATE_HZ,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    }
}

/// Two static IMUs, 300 s at 100 Hz: "cheap" with 4× the white noise of "dear" and a slow
/// bias wander, temperatures around 25 °C, and logger events for "cheap".
fn write_session(dir: &Path) {
    let manifest = Manifest::new(vec![imu("cheap"), imu("dear")], toml::Table::new());
    let options = WriterOptions {
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    let mut writer = SessionWriter::create(dir, manifest, options).unwrap();
    for (device, scale, seed) in [("cheap", 4.0, 1u64), ("dear", 1.0, 2u64)] {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut n = || -> f64 { StandardNormal.sample(&mut rng) };
        let mut walk = [0.0f64; 6];
        let records: Vec<ImuRecord> = (0..ROWS)
            .map(|i| {
                for w in &mut walk {
                    *w += scale * 2e-7 * n();
                }
                let t = i as i64 * 10_000_000;
                ImuRecord {
                    t_mono_ns: 1_000_000_000 + t,
                    t_wall_ns: 1_700_000_000_000_000_000 + t,
                    t_sensor: f64::NAN,
                    gyro: [0, 1, 2].map(|k| scale * 2e-4 * n() + walk[k]),
                    accel: [0, 1, 2].map(|k| {
                        scale * 2e-3 * n() + 100.0 * walk[3 + k] - if k == 2 { 9.81 } else { 0.0 }
                    }),
                    temp: 24.5 + i as f64 / ROWS as f64,
                    status: 0,
                }
            })
            .collect();
        for chunk in records.chunks(1000) {
            writer.append_imu(device, chunk).unwrap();
        }
    }
    for (kind, detail) in [
        (EventKind::ChecksumError, "bad checksum count=5"),
        (EventKind::Resync, "lost frame sync"),
    ] {
        writer
            .append_event(&EventRecord {
                t_mono_ns: 2_000_000_000,
                t_wall_ns: 1_700_000_001_000_000_000,
                device: "cheap".into(),
                kind,
                detail: detail.into(),
            })
            .unwrap();
    }
    writer.close().unwrap();
}

/// Width and height from a PNG's IHDR, after checking the signature.
fn png_size(path: &Path) -> (u32, u32, usize) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(
        bytes.len() > 24 && bytes.starts_with(b"\x89PNG\r\n\x1a\n") && &bytes[12..16] == b"IHDR",
        "{} is not a PNG",
        path.display()
    );
    let be = |i: usize| u32::from_be_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
    (be(16), be(20), bytes.len())
}

#[test]
fn session_report_is_complete_self_contained_and_renders() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("bench");
    write_session(&session);
    let html_path = dir.path().join("report.html");
    let png_path = dir.path().join("plots.png");
    let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("report")
        .arg(&session)
        .arg("--html")
        .arg(&html_path)
        .arg("--png")
        .arg(&png_path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let html = std::fs::read_to_string(&html_path).unwrap();

    // Self-contained: no URL, no script, nothing fetched.
    assert!(!html.contains("http"), "a URL in the page");
    assert!(!html.contains("<script") && !html.contains("<link"));

    // The order a reader needs.
    let at = |needle: &str| {
        html.find(needle)
            .unwrap_or_else(|| panic!("`{needle}` missing from the page"))
    };
    let order = [
        at("1. Summary"),
        at("bridging a GNSS outage"),
        at("2. Noise terms"),
        at("3. Allan deviation curves"),
        at("4. Data health"),
    ];
    assert!(order.windows(2).all(|w| w[0] < w[1]), "{order:?}");

    // Summary: the quieter IMU wins, by a factor near its 4× lower noise on the random walks.
    assert!(
        html.contains("<b>dear</b> is the better IMU"),
        "verdict missing"
    );
    let arw_row = &html[at("Gyro angle random walk")..];
    let arw_row = &arw_row[..arw_row.find("</tr>").unwrap()];
    let factor: f64 = arw_row
        .split("<b>dear</b> ")
        .nth(1)
        .and_then(|s| s.split('×').next())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or_else(|| panic!("no factor in {arw_row}"));
    assert!((3.0..5.3).contains(&factor), "ARW factor {factor}");
    assert!(html.contains("within 0.1 m (lane level)") && html.contains("imulab study"));

    // Data health: the logger's events, temperatures and rates of each device.
    let health = &html[at("4. Data health")..];
    assert!(
        health.contains("<b>checksum error 5</b>") && health.contains("<b>resync 1</b>"),
        "events missing from the health table"
    );
    assert!(health.contains("24.5 / 25.0 / 25.5 °C"), "temperature");
    assert!(health.contains("100 / 100 Hz"), "rates");

    // One PNG per plot (device × sensor), slide-sized.
    for name in [
        "plots-cheap-gyro.png",
        "plots-cheap-accel.png",
        "plots-dear-gyro.png",
        "plots-dear-accel.png",
    ] {
        let (w, h, bytes) = png_size(&dir.path().join(name));
        assert!(w >= 1000 && h >= 700, "{name}: {w}×{h}");
        assert!(bytes > 20_000, "{name}: only {bytes} bytes");
    }

    // A real browser.
    if chromium_missing("the browser check") {
        return;
    }
    let profile = tempfile::tempdir().unwrap();
    let shot = dir.path().join("screenshot.png");
    let mut c = chromium(profile.path());
    c.arg(format!("--screenshot={}", shot.display()))
        .arg("--window-size=1280,2400")
        .arg(format!("file://{}", html_path.display()));
    run(c);
    let (w, h, bytes) = png_size(&shot);
    assert_eq!((w, h), (1280, 2400));
    // A blank page compresses to a few kB; text, tables and four plots do not.
    assert!(bytes > 100_000, "screenshot only {bytes} bytes");
    if let Some(keep) = std::env::var_os("IMULAB_REPORT_SCREENSHOT") {
        std::fs::copy(&shot, &keep).unwrap();
    }
}

/// A study result as `imulab study --json` writes it, for grades `fit#cheap` and `fit#dear`
/// with these (longest within 1 m, 95 % interval) answers.
fn study_json(cheap: (f64, [f64; 2]), dear: (f64, [f64; 2])) -> serde_json::Value {
    let grade = |name: &str, (l, ci): (f64, [f64; 2])| {
        serde_json::json!({
            "name": name, "noise_origin": "Allan fit fit.json", "warnings": [], "lengths": [],
            "skipped": 0,
            "bridges": [
                {"requirement_m": 0.1, "longest_s": l / 4.0, "beyond_horizon": false,
                 "ci95_s": [ci[0] / 4.0, ci[1] / 4.0], "std_s": 0.1, "runs_for_5pct": 30},
                {"requirement_m": 1.0, "longest_s": l, "beyond_horizon": false,
                 "ci95_s": ci, "std_s": 0.4, "runs_for_5pct": 25}
            ]
        })
    };
    serde_json::json!({
        "scene_duration_s": 1800.0, "runs": 20, "seed": 7, "outages_per_run": 12,
        "turning_share": 0.2, "standstill_share": 0.0,
        "grades": [grade("fit#cheap", cheap), grade("fit#dear", dear)]
    })
}

#[test]
fn report_headline_is_the_studys_answer_and_better_needs_separate_intervals() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("bench");
    write_session(&session);
    let report = |study: &serde_json::Value| {
        let study_path = dir.path().join("study.json");
        std::fs::write(&study_path, study.to_string()).unwrap();
        let html_path = dir.path().join("report.html");
        let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
            .arg("report")
            .arg(&session)
            .arg("--html")
            .arg(&html_path)
            .arg("--study")
            .arg(&study_path)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        std::fs::read_to_string(&html_path).unwrap()
    };
    let verdict = |html: &str| {
        let a = html.find("class=\"verdict\"").expect("verdict");
        html[a..a + html[a..].find("</p>").unwrap()].to_string()
    };
    // Separate intervals: the ratio of the filter-based answers.
    let html = report(&study_json((8.2, [6.5, 8.8]), (18.1, [17.1, 18.8])));
    let v = verdict(&html);
    assert!(v.contains("filter-based study (20 runs)"), "{v}");
    assert!(v.contains("18.1 s [17.1, 18.8]"), "{v}");
    assert!(
        v.contains("2.2× as long as <b>cheap</b>") || v.contains("2.2× as long as cheap"),
        "{v}"
    );
    assert!(!v.contains("analytic"), "{v}");
    // The closed form stays, labelled as a bound.
    assert!(
        html.contains("analytic bound, within 1 m"),
        "analytic column missing"
    );
    assert!(html.contains("Filter-based answer"));
    // Overlapping intervals: no "as long as".
    let v = verdict(&report(&study_json(
        (16.5, [15.0, 17.5]),
        (18.1, [17.1, 18.8]),
    )));
    assert!(v.contains("not established against cheap"), "{v}");
    assert!(!v.contains("as long as"), "{v}");
    // A file that is not a study: one clear line.
    let bad = dir.path().join("not-a-study.json");
    std::fs::write(&bad, "{\"axes\": []}").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("report")
        .arg(&session)
        .arg("--html")
        .arg(dir.path().join("x.html"))
        .arg("--study")
        .arg(&bad)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("not-a-study.json"),
        "{err}"
    );
}
