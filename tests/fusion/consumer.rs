//! A consumer-grade IMU (MPU-6000 preset: turn-on gyro bias σ 6.7 °/s, accelerometer zero-g
//! offset σ 17-27 mg) aided by GNSS alone over the 30-minute open-sky drive, with 60 s
//! outages every 180 s: the filter's NEES must stay within a small multiple of its expected
//! value. Left to find a 6.7 °/s gyro bias in motion, the filter diverges (ANEES 1843 over
//! these four seeds, attitude block 1249): the heading error passes 60° within 10 s of the
//! start, beyond the filter's small-angle model, and the bias it then settles on is wrong by
//! 0.6 °/s. The drive's first minute stands still, and the alignment takes the gyro bias from
//! it (`align::static_gyro_bias`). The g-sensitivity's in-run part drives only the x and y
//! gyro biases (`ImuModel::gyro_bias_g_sensitivity_sigma`), so the yaw bias is not let
//! wander on a long straight.

use imulab::fusion::config::FusionConfig;
use imulab::fusion::mechanisation::ImuInput;
use imulab::fusion::metrics::{anees, epoch_error};
use imulab::fusion::navigator::{Navigator, ReplayOptions};
use imulab::fusion::session::{observation, truth_at};
use imulab::sim::scene::{Scene, START_MONO_NS};
use imulab::study::grades::StudyDrive;
use nalgebra::Vector3;
use std::path::Path;

/// NEES once a second of one seed: the 9 navigation states, and the attitude block alone.
fn nees_per_second(drive: &StudyDrive, config: &FusionConfig, seed: u64) -> [Vec<f64>; 2] {
    let spec = imulab::sim::presets::imu_preset("consumer").expect("preset");
    let end = drive.end_s();
    let outages = (1..)
        .map(|k| k as f64 * 180.0)
        .take_while(|a| *a < end)
        .map(|a| (a, a + 60.0))
        .collect();
    let fixes: Vec<_> = drive
        .gnss_records(seed)
        .expect("gnss")
        .iter()
        .filter_map(|r| observation(r, START_MONO_NS))
        .collect();
    let options = ReplayOptions {
        outages,
        ..Default::default()
    };
    let mut nav = Navigator::<18>::new(config, options);
    let mut fixes = fixes.iter().peekable();
    for r in drive.imu_records(&spec, seed).expect("imu") {
        let sample = ImuInput::Rates {
            t_s: (r.t_mono_ns - START_MONO_NS) as f64 * 1e-9,
            gyro: Vector3::from(r.gyro),
            accel: Vector3::from(r.accel),
        };
        while let Some(f) = fixes.next_if(|f| f.t_s < sample.t_s()) {
            nav.push_gnss(f);
        }
        nav.push_imu(&sample);
    }
    let result = nav.finish();
    let mut all = vec![f64::NAN; end as usize + 1];
    let mut attitude = all.clone();
    for s in &result.filtered {
        let k = s.nav.t_s.round();
        if (s.nav.t_s - k).abs() > 1e-6 || k < 0.0 || k as usize >= all.len() {
            continue;
        }
        let Some(truth) = truth_at(drive.truth_nav(), s.nav.t_s) else {
            continue;
        };
        let e = epoch_error(s, &truth);
        let p = s.cov_nav.fixed_view::<3, 3>(6, 6).into_owned();
        all[k as usize] = e.nees;
        attitude[k as usize] =
            nalgebra::Cholesky::new(p).map_or(f64::NAN, |c| e.att.dot(&c.solve(&e.att)));
    }
    [all, attitude]
}

#[test]
fn consumer_imu_with_gnss_only_stays_bounded_over_a_drive() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes/drive_30min_open_sky.toml");
    let scene = Scene::load(&path).expect("scene");
    let drive = StudyDrive::new(&scene).expect("drive");
    let spec = imulab::sim::presets::imu_preset("consumer").expect("preset");
    let mut config = FusionConfig {
        imu: imulab::study::noise::model_from_spec(&spec, "consumer")
            .expect("noise")
            .model,
        output_interval_s: 1.0,
        ..FusionConfig::default()
    };
    config.gnss.position_error =
        imulab::study::noise::gnss_error_from_spec(&scene.gnss[0].spec).expect("receiver");
    let runs: Vec<[Vec<f64>; 2]> = (0..4)
        .map(|k| nees_per_second(&drive, &config, scene.seed + k))
        .collect();
    let part = |i: usize| -> Vec<Vec<f64>> { runs.iter().map(|r| r[i].clone()).collect() };
    let all = anees(&part(0), 9).expect("common epochs");
    let attitude = anees(&part(1), 3).expect("common epochs");
    println!(
        "consumer, GNSS only, 4 seeds: ANEES {:.2} (band [{:.2}, {:.2}]), attitude {:.2}, largest epoch {:.1}, epochs above the band {:.0} %",
        all.mean,
        all.band.0,
        all.band.1,
        attitude.mean,
        all.max,
        100.0 * all.above
    );
    assert!(all.epochs > 1600, "{} common epochs", all.epochs);
    // The ANEES within its 95 % band for 4 seeds (6.83 on these seeds), the attitude block
    // within 1.5 times its 3 expected (2.33). With the g-sensitivity's in-run part on the
    // yaw bias as well, whose input is the constant 1 g, the heading on the drive's 760 s
    // straight was over-confident: ANEES 16.0, attitude 9.9 (docs/bench/fusion.md,
    // "Consumer preset without constraints").
    assert!(
        all.mean > all.band.0 && all.mean < all.band.1,
        "ANEES {:.2} outside [{:.2}, {:.2}]",
        all.mean,
        all.band.0,
        all.band.1
    );
    assert!(attitude.mean < 4.5, "attitude ANEES {:.2}", attitude.mean);
}
