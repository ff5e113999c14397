//! Named IMU presets: the two IMUs of the motivating bench study and one consumer,
//! industrial and tactical-grade unit from their datasheets. GNSS presets live with the
//! GNSS model ([`super::gnss_model::GnssSpec::preset`]).
//!
//! Values are per axis X/Y/Z. Where a datasheet gives no value for a term, the term is
//! either left out or the assumed value is marked "assumed" below and in
//! docs/simulator.md. Bias instability is B as IEEE Std 952 and `imulab allan --fit` define
//! it (the simulated Allan floor is 0.664·B), so the fit of a simulated run reads the preset
//! back.

use super::imu_model::{AccelSpec, GyroSpec, ImuSpec, ThermalSpec, DEFAULT_BAND_S};
use imulab_noise::BIAS_INSTABILITY_FACTOR;

/// One IMU preset: its name, where its numbers come from, and the spec.
pub struct ImuPreset {
    pub name: &'static str,
    pub source: &'static str,
    pub spec: fn() -> ImuSpec,
}

/// Every IMU preset, in the order the docs list them.
pub const IMU_PRESETS: &[ImuPreset] = &[
    ImuPreset {
        name: "bench-cheap",
        source: "bench study, ~25 EUR IMU, per axis at 25 °C and 150 Hz (ARW printed as °/s/√hr, read as °/√h)",
        spec: bench_cheap,
    },
    ImuPreset {
        name: "bench-dear",
        source: "bench study, ~250 EUR IMU, per axis at 25 °C and 150 Hz (ARW printed as °/s/√hr, read as °/√h)",
        spec: bench_dear,
    },
    ImuPreset {
        name: "consumer",
        source: "InvenSense MPU-6000/MPU-6050 Product Specification PS-MPU-6000A-00 rev 3.4 (±250 °/s, ±2 g); bias instability assumed",
        spec: consumer,
    },
    ImuPreset {
        name: "industrial",
        source: "Xsens MTi-1 series datasheet (gyro 10 °/h, 0.007 °/s/√Hz; accel 0.03 mg, 120 µg/√Hz)",
        spec: industrial,
    },
    ImuPreset {
        name: "tactical",
        source: "Safran Sensonor STIM300 datasheet TS1524 (10 g accelerometers): gyro bias instability 0.5 °/h (the Allan minimum, per Sensonor's FAQ; B = 0.5/0.664), ARW 0.15 °/√h, bias repeatability 4 °/h as turn-on σ; accel bias instability 0.05 mg (Allan minimum; B = 0.05/0.664), VRW 0.07 m/s/√h (rev 9: 0.06; the larger used), bias on/off repeatability 0.75 mg as turn-on σ",
        spec: tactical,
    },
    ImuPreset {
        name: "icm20948-thermal",
        source: "TDK InvenSense ICM-20948 datasheet DS-000189 rev 1.3, accelerometer table (±2 g): zero-g change 0.80 mg/°C, sensitivity change 0.026 %/°C (260 ppm/°C), 230 µg/√Hz, initial zero-g ±25 mg as 3σ; second-order terms, hysteresis, warm-up, thermal time constant and every gyro figure assumed",
        spec: icm20948_thermal,
    },
];

/// The spec of preset `name`, or None.
pub fn imu_preset(name: &str) -> Option<ImuSpec> {
    IMU_PRESETS
        .iter()
        .find(|p| p.name == name)
        .map(|p| (p.spec)())
}

/// Names of every IMU preset, for error messages.
pub fn imu_preset_names() -> Vec<&'static str> {
    IMU_PRESETS.iter().map(|p| p.name).collect()
}

fn with_noise(gyro: GyroSpec, accel: AccelSpec) -> ImuSpec {
    ImuSpec {
        gyro: GyroSpec {
            bias_instability_band_s: DEFAULT_BAND_S,
            ..gyro
        },
        accel: AccelSpec {
            bias_instability_band_s: DEFAULT_BAND_S,
            ..accel
        },
        ..ImuSpec::default()
    }
}

fn bench_cheap() -> ImuSpec {
    with_noise(
        GyroSpec {
            arw_deg_rth: Some([0.36, 0.31, 0.30]),
            bias_instability_dph: [5.3, 4.8, 4.0],
            ..GyroSpec::default()
        },
        AccelSpec {
            vrw_mg_rth: Some([6.6, 7.9, 8.5]),
            bias_instability_mg: [0.029, 0.074, 0.043],
            ..AccelSpec::default()
        },
    )
}

fn bench_dear() -> ImuSpec {
    with_noise(
        GyroSpec {
            arw_deg_rth: Some([0.30, 0.26, 0.30]),
            bias_instability_dph: [4.1, 4.1, 4.7],
            ..GyroSpec::default()
        },
        AccelSpec {
            vrw_mg_rth: Some([2.8, 3.0, 2.8]),
            bias_instability_mg: [0.022, 0.037, 0.031],
            ..AccelSpec::default()
        },
    )
}

fn consumer() -> ImuSpec {
    with_noise(
        GyroSpec {
            noise_density_dps_rthz: Some([0.005; 3]),
            // Assumed: the datasheet gives no in-run stability.
            bias_instability_dph: [10.0; 3],
            // Initial zero-rate tolerance ±20 °/s, read as 3σ.
            turn_on_bias_sigma_dph: [20.0 / 3.0 * 3600.0; 3],
            // Linear acceleration sensitivity 0.1 °/s/g, on each axis's own input.
            g_sensitivity_dph_per_g: [[360.0, 0.0, 0.0], [0.0, 360.0, 0.0], [0.0, 0.0, 360.0]],
            range_dps: Some(250.0),
            lsb_dps: Some(1.0 / 131.0),
            ..GyroSpec::default()
        },
        AccelSpec {
            noise_density_ug_rthz: Some([400.0; 3]),
            // Assumed: the datasheet gives no in-run stability.
            bias_instability_mg: [0.1; 3],
            // Initial zero-g tolerance ±50 mg (X, Y) and ±80 mg (Z), read as 3σ.
            turn_on_bias_sigma_mg: [50.0 / 3.0, 50.0 / 3.0, 80.0 / 3.0],
            range_g: Some(2.0),
            lsb_mg: Some(1000.0 / 16384.0),
            ..AccelSpec::default()
        },
    )
}

fn industrial() -> ImuSpec {
    with_noise(
        GyroSpec {
            noise_density_dps_rthz: Some([0.007; 3]),
            bias_instability_dph: [10.0; 3],
            range_dps: Some(2000.0),
            ..GyroSpec::default()
        },
        AccelSpec {
            noise_density_ug_rthz: Some([120.0; 3]),
            bias_instability_mg: [0.03; 3],
            range_g: Some(16.0),
            ..AccelSpec::default()
        },
    )
}

fn tactical() -> ImuSpec {
    // STIM300 (tactical-grade MEMS) with its 10 g accelerometers. The datasheet separates
    // in-run bias instability (the Allan floor, measured over 20 h at 25 °C per Sensonor's
    // FAQ) from turn-on to turn-on repeatability; each goes to its own term here. An
    // earlier version used the Honeywell HG1700 brochure, whose 1 °/h and 1 mg are bias
    // repeatability only (no in-run stability given), wrongly as the Allan floor.
    // Sensonor's FAQ defines the datasheet's bias instability as the lowest point of the
    // Allan deviation; B (what the spec holds, see the module doc) is that minimum / 0.664.
    // VRW 0.07 m/s/√h in the bench study's mg/√h convention: 0.07 / 9.80665e-3 = 7.14.
    let b_per_floor = 1.0 / BIAS_INSTABILITY_FACTOR;
    let vrw_mg_rth = 0.07 / (super::imu_model::G0 * 1e-3);
    with_noise(
        GyroSpec {
            arw_deg_rth: Some([0.15; 3]),
            bias_instability_dph: [0.5 * b_per_floor; 3],
            // Bias repeatability (run to run), read as the 1σ of the turn-on bias.
            turn_on_bias_sigma_dph: [4.0; 3],
            // The datasheet specifies non-linearity up to 400 °/s (25/50 ppm at 200/400 °/s).
            range_dps: Some(400.0),
            ..GyroSpec::default()
        },
        AccelSpec {
            vrw_mg_rth: Some([vrw_mg_rth; 3]),
            bias_instability_mg: [0.05 * b_per_floor; 3],
            // Bias on/off repeatability ±0.75 mg (10 g range), read as the 1σ turn-on bias.
            turn_on_bias_sigma_mg: [0.75; 3],
            range_g: Some(10.0),
            ..AccelSpec::default()
        },
    )
}

fn icm20948_thermal() -> ImuSpec {
    // The datasheet gives first-order figures only ("±" typical values, read as the
    // coefficient of this unit); the rest makes the thermal analysis have something to find.
    let mut spec = with_noise(
        GyroSpec {
            // Assumed: consumer-grade gyro figures.
            noise_density_dps_rthz: Some([0.015; 3]),
            bias_instability_dph: [10.0; 3],
            bias_tempco_dph_per_c: [30.0, -20.0, 25.0],
            bias_tempco2_dph_per_c2: [0.4, 0.3, -0.2],
            scale_tempco_ppm_per_c: [150.0; 3],
            bias_hysteresis_dph: [20.0, 15.0, 10.0],
            warmup_bias_dph: [60.0, -40.0, 50.0],
            noise_tempco_percent_per_c: [0.3; 3],
            range_dps: Some(250.0),
            ..GyroSpec::default()
        },
        AccelSpec {
            noise_density_ug_rthz: Some([230.0; 3]),
            bias_instability_mg: [0.05; 3],
            turn_on_bias_sigma_mg: [25.0 / 3.0; 3],
            bias_tempco_mg_per_c: [0.80, -0.80, 0.80],
            bias_tempco2_mg_per_c2: [0.004, 0.003, -0.005],
            scale_tempco_ppm_per_c: [260.0; 3],
            bias_hysteresis_mg: [0.5, 0.4, 0.6],
            warmup_bias_mg: [2.0, -1.5, 3.0],
            noise_tempco_percent_per_c: [0.2; 3],
            range_g: Some(2.0),
            ..AccelSpec::default()
        },
    );
    spec.thermal = ThermalSpec {
        // Assumed: a 3×3 mm package on a small board in moving chamber air.
        time_constant_s: 120.0,
        hysteresis_width_c: 3.0,
        warmup_time_constant_s: 300.0,
        // The datasheet's temperature sensitivity, 333.87 LSB/°C.
        temp_lsb_c: 1.0 / 333.87,
    };
    spec
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_is_valid_and_named_once() {
        let names = imu_preset_names();
        for (i, p) in IMU_PRESETS.iter().enumerate() {
            (p.spec)()
                .validate()
                .unwrap_or_else(|e| panic!("{}: {e}", p.name));
            assert!(!names[..i].contains(&p.name), "duplicate {}", p.name);
        }
        assert!(imu_preset("nope").is_none());
    }

    #[test]
    fn bench_numbers_are_the_issue_numbers() {
        let cheap = imu_preset("bench-cheap").unwrap();
        assert_eq!(cheap.accel.bias_instability_mg, [0.029, 0.074, 0.043]);
        assert_eq!(cheap.accel.vrw_mg_rth, Some([6.6, 7.9, 8.5]));
        assert_eq!(cheap.gyro.bias_instability_dph, [5.3, 4.8, 4.0]);
        assert_eq!(cheap.gyro.arw_deg_rth, Some([0.36, 0.31, 0.30]));
        let dear = imu_preset("bench-dear").unwrap();
        assert_eq!(dear.accel.bias_instability_mg, [0.022, 0.037, 0.031]);
        assert_eq!(dear.accel.vrw_mg_rth, Some([2.8, 3.0, 2.8]));
        assert_eq!(dear.gyro.bias_instability_dph, [4.1, 4.1, 4.7]);
        assert_eq!(dear.gyro.arw_deg_rth, Some([0.30, 0.26, 0.30]));
    }

    #[test]
    fn tactical_keeps_in_run_floor_and_repeatability_apart() {
        let t = imu_preset("tactical").unwrap();
        // The datasheet's Allan minima (0.5 °/h, 0.05 mg) are 0.664·B.
        let floor_dph = t.gyro.bias_instability_dph[0] * BIAS_INSTABILITY_FACTOR;
        assert!((floor_dph - 0.5).abs() < 1e-12, "{floor_dph}");
        let floor_mg = t.accel.bias_instability_mg[0] * BIAS_INSTABILITY_FACTOR;
        assert!((floor_mg - 0.05).abs() < 1e-12, "{floor_mg}");
        assert_eq!(t.gyro.turn_on_bias_sigma_dph, [4.0; 3]);
        assert_eq!(t.gyro.arw_deg_rth, Some([0.15; 3]));
        assert_eq!(t.accel.turn_on_bias_sigma_mg, [0.75; 3]);
        let vrw = t.accel.vrw_mg_rth.unwrap()[0];
        assert!((vrw * 9.80665e-3 - 0.07).abs() < 1e-12, "{vrw}");
        // The grade ordering a navigation engineer expects: the tactical gyro floor is
        // below every MEMS preset's (gyro drift dominates outages beyond a few seconds).
        for other in ["bench-cheap", "bench-dear", "consumer", "industrial"] {
            let o = imu_preset(other).unwrap();
            let best = o
                .gyro
                .bias_instability_dph
                .iter()
                .cloned()
                .fold(f64::MAX, f64::min);
            assert!(t.gyro.bias_instability_dph[0] < best, "{other}");
        }
    }
}
