//! The filter's noise model from what a user knows: per simulator preset, the replay of the
//! simulator's `short_drive` scene is consistent (NEES, share inside 3σ); an Allan fit made
//! by our own analyser on simulated static data gives the preset's noise back, and
//! `imulab replay --noise FIT.json` uses it.

use imulab::allan::analysis::{analyse_axis, AllanReport, AnalysisOptions};
use imulab::allan::deviation::DeviationKind;
use imulab::allan::input::AxisSeries;
use imulab::allan::taus::TauGrid;
use imulab::allan::units::{RateUnit, SensorKind};
use imulab::fusion::config::{Axes, FusionConfig};
use imulab::fusion::metrics::{errors, summarise, ErrorSummary};
use imulab::fusion::navigator::ReplayOptions;
use imulab::fusion::session::{replay_session, truth_at};
use imulab::sim::outputs::{MemorySink, SessionSink};
use imulab::sim::scene::Scene;
use imulab::store::Session;
use imulab::study::noise;
use imulab::study::simulated_imu_preset;
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/scenes")
        .join(name)
}

/// Simulates `short_drive` with IMU preset `preset` into a session under `dir`.
fn short_drive_session(dir: &Path, preset: &str) -> PathBuf {
    let text = std::fs::read_to_string(fixture("short_drive.toml")).expect("fixture");
    let text = text.replace("preset = \"tactical\"", &format!("preset = \"{preset}\""));
    let scene = Scene::parse(&text, dir).expect("scene");
    let out = dir.join(preset);
    let mut sink = SessionSink::create(&out, &scene).expect("session");
    imulab::sim::runner::run(&scene, &mut sink).expect("simulate");
    sink.close().expect("close")
}

fn replay_with(session_dir: &Path, config: &FusionConfig) -> ErrorSummary {
    let session = Session::open(session_dir).expect("open");
    let r = replay_session(&session, None, None, config, ReplayOptions::default(), None)
        .expect("replay");
    summarise(&errors(&r.result.filtered, |t| truth_at(&r.truth, t)), &[])
}

#[test]
fn replay_with_each_preset_noise_is_consistent() {
    let dir = tempfile::tempdir().expect("tempdir");
    for preset in [
        "bench-cheap",
        "bench-dear",
        "industrial",
        "tactical",
        "consumer",
    ] {
        let path = short_drive_session(dir.path(), preset);
        let session = Session::open(&path).expect("open");
        assert_eq!(
            simulated_imu_preset(&session, "imu").as_deref(),
            Some(preset)
        );
        let config = FusionConfig {
            imu: noise::model_from_preset(preset).expect("preset").model,
            ..FusionConfig::default()
        };
        let s = replay_with(&path, &config);
        println!(
            "{preset}: NEES {:.2}, inside 3σ {:.1} %, horizontal RMS {:.3} m",
            s.nees_mean,
            100.0 * s.inside_3sigma,
            s.horizontal.rms
        );
        assert!(s.epochs > 500, "{preset}: {} epochs", s.epochs);
        // Every preset, the consumer one too since its turn-on bias and g-sensitivity are
        // in the filter's model (it was NEES 28, 89 % inside 3σ before).
        assert!(
            s.inside_3sigma > 0.96,
            "{preset}: inside 3σ {}",
            s.inside_3sigma
        );
        assert!(s.nees_mean < 18.0, "{preset}: NEES {}", s.nees_mean);
    }
}

/// The Allan report our analyser makes of a simulated static record of `preset`.
fn allan_report_of(preset: &str, minutes: f64) -> AllanReport {
    let text = format!(
        "duration_s = {}\nrate_hz = 100\nseed = 4\n[location]\nlat_deg = 48.0\nlon_deg = 11.0\nheight_m = 500\n[motion]\nkind = \"static\"\n[[imu]]\nname = \"unit\"\npreset = \"{preset}\"\n[outputs]\ntruth_nav = false\ntruth_imu = false\n",
        minutes * 60.0
    );
    let scene = Scene::parse(&text, Path::new(".")).expect("scene");
    let mut sink = MemorySink::default();
    imulab::sim::runner::run(&scene, &mut sink).expect("simulate");
    let rows = &sink.imu["unit"];
    let mut axes = Vec::new();
    for (k, name) in [
        "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z",
    ]
    .iter()
    .enumerate()
    {
        let gyro = k < 3;
        let values: Vec<f64> = rows
            .iter()
            .map(|r| if gyro { r.gyro[k] } else { r.accel[k - 3] })
            .collect();
        let series = AxisSeries::one_segment(*name, 0.01, values);
        let options = AnalysisOptions {
            kind: DeviationKind::Oadev,
            grid: TauGrid::Dense(8),
            fit: true,
            unit: if gyro {
                RateUnit::RadPerSecond
            } else {
                RateUnit::MetrePerSecondSquared
            },
            sensor: Some(if gyro {
                SensorKind::Gyro
            } else {
                SensorKind::Accel
            }),
        };
        axes.push(analyse_axis("unit", series, &options));
    }
    AllanReport::new(
        vec!["simulated".into()],
        DeviationKind::Oadev,
        "dense:8",
        axes,
    )
}

#[test]
fn allan_fit_of_simulated_data_gives_the_preset_noise_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    let report = allan_report_of("industrial", 20.0);
    let json = dir.path().join("fit.json");
    std::fs::write(&json, serde_json::to_string(&report).expect("json")).expect("write");
    let base = FusionConfig::default().imu;
    let from_fit =
        noise::model_from_allan_file(json.to_str().expect("utf-8"), &base).expect("read fit");
    let preset = noise::model_from_preset("industrial")
        .expect("preset")
        .model;
    let m = from_fit.model;
    println!(
        "fit: {m:?}\nwarnings: {:?}\npreset: {preset:?}",
        from_fit.warnings
    );
    // The fit gives one figure per sensor (its largest axis); the industrial preset's axes
    // are alike.
    let ratio = |a: Axes, b: Axes| a.max() / b.max();
    assert!((ratio(m.arw_rad_per_sqrt_s, preset.arw_rad_per_sqrt_s) - 1.0).abs() < 0.1);
    assert!((ratio(m.vrw_mps_per_sqrt_s, preset.vrw_mps_per_sqrt_s) - 1.0).abs() < 0.1);
    // Bias instability from 20 minutes of data: the right order of magnitude, or a
    // fallback with a warning.
    for (fit_gm, preset_gm, name) in [
        (m.gyro_bias, preset.gyro_bias, "gyro"),
        (m.accel_bias, preset.accel_bias, "accel"),
    ] {
        let identified = !from_fit
            .warnings
            .iter()
            .any(|w| w.contains(&format!("{name} bias instability")));
        if identified {
            let r = ratio(fit_gm.sigma, preset_gm.sigma);
            assert!(r > 0.33 && r < 3.0, "{name} bias σ ratio {r}");
            assert!(fit_gm.tau_s > 0.0 && fit_gm.tau_s.is_finite());
        } else {
            assert_eq!(
                fit_gm,
                if name == "gyro" {
                    base.gyro_bias
                } else {
                    base.accel_bias
                }
            );
        }
    }
    // A simulator spec from the fit reproduces the white noise.
    let fit = noise::allan_device(&report, None, "fit").expect("device");
    let spec = noise::spec_from_allan(&fit).expect("spec");
    let back = noise::model_from_spec(&spec, "round trip")
        .expect("model")
        .model;
    assert!((ratio(back.arw_rad_per_sqrt_s, m.arw_rad_per_sqrt_s) - 1.0).abs() < 1e-9);
    // And the bias instability: the spec holds B = floor / 0.664 and simulates the floor.
    if fit.gyro.floor.is_some() && fit.gyro.tau_min.is_some() {
        let r = ratio(back.gyro_bias.sigma, m.gyro_bias.sigma);
        assert!((r - 1.0).abs() < 1e-9, "gyro bias σ round trip {r}");
    }
    // Several devices need a choice; a wrong name is named.
    let e = noise::allan_device(&report, Some("other"), "fit").expect_err("no such device");
    assert!(e.to_string().contains("unit"), "{e}");
    // Garbage is not an Allan report.
    std::fs::write(dir.path().join("bad.json"), "{\"axes\": 3}").expect("write");
    let e =
        noise::model_from_allan_file(dir.path().join("bad.json").to_str().expect("utf-8"), &base)
            .expect_err("bad json");
    assert!(e.to_string().contains("not an Allan report"), "{e}");
}

#[test]
fn replay_command_reads_noise_from_an_allan_fit_and_writes_into_the_session() {
    let dir = tempfile::tempdir().expect("tempdir");
    let session = short_drive_session(dir.path(), "industrial");
    let json = dir.path().join("fit.json");
    let report = allan_report_of("industrial", 5.0);
    std::fs::write(&json, serde_json::to_string(&report).expect("json")).expect("write");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("replay")
        .arg(&session)
        .arg("--noise")
        .arg(format!("{}#unit", json.display()))
        .output()
        .expect("run imulab");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("IMU noise: Allan fit"), "{stdout}");
    // The short drive's receiver is the simulator's SBAS one (DGNSS fixes): its error model.
    assert!(
        stdout.contains("GNSS: receiver position error as 3 filter states, σ 0.5 m horizontal, 0.9 m vertical, τ 300 s, from the sbas receiver class of its Dgnss fixes"),
        "{stdout}"
    );
    let white = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("replay")
        .arg(&session)
        .arg("--white-gnss")
        .arg("--out")
        .arg(dir.path().join("white"))
        .output()
        .expect("run imulab");
    let white_out = String::from_utf8_lossy(&white.stdout);
    assert!(white.status.success(), "{white_out}");
    assert!(
        white_out.contains("GNSS: fixes white, correlation time 60 s (--white-gnss)"),
        "{white_out}"
    );
    let h5 = session.join("replay-filter.h5");
    let file = hdf5::File::open(&h5).expect("replay file");
    let lat = file
        .dataset("replay/filtered/lat_deg")
        .expect("lat dataset")
        .read_raw::<f64>()
        .expect("read");
    assert!(lat.len() > 500 && lat.iter().all(|v| v.is_finite()));
    // `imulab inspect` lists it.
    let inspect = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("inspect")
        .arg(&session)
        .output()
        .expect("run imulab");
    assert!(String::from_utf8_lossy(&inspect.stdout).contains("replay-filter.h5"));
}
