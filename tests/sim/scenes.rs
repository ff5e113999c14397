//! Scene-level tests of the simulator: determinism across runs and thread counts, computing
//! only what a scene asks for, the GNSS model on a drive with outages, temperature-driven
//! biases, truth files, and that the shipped example scenes parse.

use std::path::{Path, PathBuf};

use imulab::earth;
use imulab::sim::motion::MotionGenerator;
use imulab::sim::outputs::MemorySink;
use imulab::sim::runner::run;
use imulab::sim::scene::{Motion, Scene};
use imulab_drivers::types::FixType;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/scenes")
        .join(name)
}

/// Bit-level equality of two runs (the records hold NaN for absent values, so `==` on
/// floats would call identical runs different).
fn same(a: &MemorySink, b: &MemorySink) -> bool {
    format!("{a:?}") == format!("{b:?}")
}

fn run_with_threads(scene: &Scene, threads: usize) -> MemorySink {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut sink = MemorySink::default();
        run(scene, &mut sink).unwrap();
        sink
    })
}

#[test]
fn example_scenes_parse() {
    for name in [
        "chamber_6h.toml",
        "drive_30min.toml",
        "drive_30min_open_sky.toml",
        "short_static.toml",
        "short_drive.toml",
        "serve_bench.toml",
        "tumble_15min.toml",
        "rate_table.toml",
        "rate_table_3axis.toml",
    ] {
        let scene = Scene::load(&fixture(name)).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        assert!(scene.samples() > 0);
    }
    let chamber = Scene::load(&fixture("chamber_6h.toml")).unwrap();
    assert_eq!(chamber.samples(), 6 * 3600 * 150);
    assert_eq!(chamber.imus.len(), 2);
    assert!(chamber.gnss.is_empty());
}

#[test]
fn identical_across_runs_and_thread_counts_and_seed_matters() {
    let scene = Scene::load(&fixture("short_static.toml")).unwrap();
    let one = run_with_threads(&scene, 1);
    let two = run_with_threads(&scene, 2);
    let again = run_with_threads(&scene, 2);
    assert!(same(&one, &two), "1 thread and 2 threads differ");
    assert!(same(&two, &again), "two runs differ");
    let mut other = scene.clone();
    other.seed += 1;
    let different = run_with_threads(&other, 2);
    assert!(
        one.imu["cheap"] != different.imu["cheap"],
        "seed has no effect"
    );
}

#[test]
fn a_sensor_does_not_change_when_another_is_added() {
    let scene = Scene::load(&fixture("short_static.toml")).unwrap();
    let full = run_with_threads(&scene, 2);
    let mut alone = scene.clone();
    alone.imus.retain(|i| i.name == "cheap");
    alone.gnss.clear();
    let alone = run_with_threads(&alone, 1);
    assert!(
        full.imu["cheap"] == alone.imu["cheap"],
        "adding sensors changed cheap"
    );
}

#[test]
fn only_what_the_scene_asks_for_is_produced() {
    let mut scene = Scene::load(&fixture("short_static.toml")).unwrap();
    scene.gnss.clear();
    scene.outputs.truth_imu = false;
    scene.outputs.truth_every = 10;
    let out = run_with_threads(&scene, 1);
    assert!(out.gnss.is_empty());
    assert!(out.truth_imu.is_empty());
    assert_eq!(out.truth_nav.len(), 200);
    // Static: the truth never moves.
    let first = &out.truth_nav[0];
    assert!(out
        .truth_nav
        .iter()
        .all(|r| (r.lat_deg, r.lon_deg, r.height_m, r.vel_ned, r.quat_nb)
            == (
                first.lat_deg,
                first.lon_deg,
                first.height_m,
                [0.0; 3],
                first.quat_nb
            )));
    // Gyro-only IMU: accel NaN; 1 % drops and increasing jittered timestamps.
    let g = &out.imu["gyro_only"];
    assert!(g
        .iter()
        .all(|r| r.accel.iter().all(|a| a.is_nan()) && r.gyro[0].is_finite()));
    assert!(g.len() < 2000 && g.len() > 1950, "{}", g.len());
    assert!(g.windows(2).all(|w| w[1].t_mono_ns > w[0].t_mono_ns));
    // Dropped samples leave a gap in the device counter.
    assert!(g.windows(2).any(|w| w[1].t_sensor - w[0].t_sensor > 1.5));
    assert_eq!(out.events.len(), 2);
}

#[test]
fn static_scene_sees_gravity_and_earth_rate() {
    let scene = Scene::load(&fixture("short_static.toml")).unwrap();
    let out = run_with_threads(&scene, 1);
    let truth = &out.truth_imu["cheap"][0];
    let lat = 45f64.to_radians();
    let g = earth::normal_gravity(lat, 250.0);
    let f = truth.accel_true;
    let w = truth.gyro_true;
    assert!(((f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt() - g).abs() < 1e-9);
    let rate = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    assert!((rate - earth::OMEGA_IE).abs() < 1e-15);
    // Output − truth − true bias is the white noise alone: zero mean, VRW spread.
    let cheap = &out.imu["cheap"];
    let truth = &out.truth_imu["cheap"];
    let n = cheap.len() as f64;
    let resid: Vec<f64> = cheap
        .iter()
        .zip(truth)
        .map(|(r, t)| r.accel[2] - t.accel_true[2] - t.accel_bias[2])
        .collect();
    let sigma = 8.5e-3 * 9.806_65 / 60.0 * 100f64.sqrt(); // VRW Z 8.5 mg/√h at 100 Hz
    let mean = resid.iter().sum::<f64>() / n;
    let sd = (resid.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    assert!(mean.abs() < 4.0 * sigma / n.sqrt(), "mean {mean}");
    assert!(
        (sd / sigma - 1.0).abs() < 4.0 / (2.0 * n).sqrt(),
        "sd {sd} vs {sigma}"
    );
}

#[test]
fn drive_gnss_follows_truth_with_outages_and_latency() {
    let scene = Scene::load(&fixture("short_drive.toml")).unwrap();
    let out = run_with_threads(&scene, 1);
    let fixes = &out.gnss["gnss"];
    assert_eq!(fixes.len(), 600);
    let Motion::Segments(spec) = &scene.motion else {
        panic!("segments scene")
    };
    let truth: Vec<_> = MotionGenerator::new(spec, 100.0).unwrap().collect();
    let mut sum2_n = 0.0;
    let mut count = 0;
    for (k, r) in fixes.iter().enumerate() {
        let t_s = k as f64 * 0.1;
        let outage = (25.0..35.0).contains(&t_s);
        assert_eq!(r.fix_type == FixType::NoFix, outage, "epoch {k}");
        // Latency: arrives 50 ms after its epoch.
        assert_eq!(
            r.t_mono_ns,
            1_000_000_000 + (t_s * 1e9).round() as i64 + 50_000_000
        );
        if outage {
            assert!(r.lat_deg.is_nan() && r.num_sats < 4);
            continue;
        }
        assert_eq!(r.fix_type, FixType::Dgnss);
        let tr = &truth[k * 10];
        let rn = earth::meridian_radius(tr.lat_rad) + tr.height_m;
        let dn = (r.lat_deg.to_radians() - tr.lat_rad) * rn;
        sum2_n += dn * dn;
        count += 1;
        let dv = (r.vel_ned[0] - tr.vel_ned.x).abs();
        assert!(dv < 5.0 * 0.05, "velocity error {dv} at epoch {k}");
    }
    // SBAS preset: 0.3 m white + 0.5 m GM (τ 300 s, so one minute sees only part of it).
    let rms = (sum2_n / count as f64).sqrt();
    assert!(
        rms > 0.1 && rms < 3.0 * 0.3f64.hypot(0.5),
        "north rms {rms}"
    );
    // The IMU saw the trajectory's true inputs.
    let ti = &out.truth_imu["imu"];
    for k in [0, 1500, 4999] {
        assert_eq!(ti[k].gyro_true, <[f64; 3]>::from(truth[k].gyro_b));
        assert_eq!(ti[k].accel_true, <[f64; 3]>::from(truth[k].accel_b));
    }
}

#[test]
fn temperature_ramp_drives_the_bias() {
    let text = r#"
        duration_s = 100
        rate_hz = 10
        [location]
        lat_deg = 10.0
        lon_deg = 20.0
        height_m = 0
        [motion]
        kind = "static"
        [temperature]
        kind = "ramp"
        start_c = 25
        end_c = 45
        start_s = 0
        end_s = 100
        [[imu]]
        name = "t"
        [imu.gyro]
        bias_tempco_dph_per_c = [2, 0, -1]
        [imu.accel]
        bias_tempco_mg_per_c = [0, 0.5, 0]
    "#;
    let scene = Scene::parse(text, Path::new(".")).unwrap();
    let out = run_with_threads(&scene, 1);
    let dph = std::f64::consts::PI / 180.0 / 3600.0;
    for (k, t) in out.truth_imu["t"].iter().enumerate() {
        let dtemp = 20.0 * k as f64 / 1000.0;
        assert!((t.gyro_bias[0] - 2.0 * dph * dtemp).abs() < 1e-15);
        assert!((t.gyro_bias[2] + dph * dtemp).abs() < 1e-15);
        assert!((t.accel_bias[1] - 0.5e-3 * 9.806_65 * dtemp).abs() < 1e-12);
        assert!((out.imu["t"][k].temp - (25.0 + dtemp)).abs() < 1e-12);
    }
}

#[test]
fn truth_file_scene_runs_and_short_file_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let mut csv = String::from(
        "t_s,lat_deg,lon_deg,height_m,vn,ve,vd,qw,qx,qy,qz,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n",
    );
    for k in 0..50 {
        csv.push_str(&format!(
            "{},50,8,100,1,0,0,1,0,0,0,0.01,0,0,0.5,0,-9.81\n",
            k as f64 / 10.0
        ));
    }
    std::fs::write(dir.path().join("truth.csv"), csv).unwrap();
    let scene_text = |duration: u32| {
        format!(
            r#"
            duration_s = {duration}
            rate_hz = 10
            [location]
            lat_deg = 50.0
            lon_deg = 8.0
            height_m = 100
            [motion]
            kind = "truth_file"
            path = "truth.csv"
            [[imu]]
            name = "i"
            [[gnss]]
            name = "g"
            rate_hz = 1
        "#
        )
    };
    let scene = Scene::parse(&scene_text(5), dir.path()).unwrap();
    let out = run_with_threads(&scene, 1);
    assert_eq!(out.imu["i"].len(), 50);
    assert_eq!(
        out.imu["i"][7].gyro[0], 0.01,
        "no errors configured: output = truth"
    );
    assert_eq!(out.gnss["g"].len(), 5);
    let long = Scene::parse(&scene_text(6), dir.path()).unwrap();
    let e = format!("{:#}", run(&long, &mut MemorySink::default()).unwrap_err());
    assert!(e.contains("ends after 50 samples"), "{e}");
}

#[test]
fn segments_shorter_than_the_scene_are_an_error() {
    let mut scene = Scene::load(&fixture("short_drive.toml")).unwrap();
    scene.duration_s = 61.0;
    let e = format!("{:#}", run(&scene, &mut MemorySink::default()).unwrap_err());
    assert!(e.contains("segments last 60"), "{e}");
}
