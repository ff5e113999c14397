//! Thermal analysis benchmark: recovery of known thermal coefficients from simulated
//! chamber runs over seeds and two grades, and the run time of the whole analysis of a
//! 24 h, 150 Hz, 6-axis run (one axis in memory at a time). Method and tables:
//! docs/bench/thermal.md. Run: `cargo bench --bench thermal`.

use imulab::allan::input::AxisSeries;
use imulab::allan::units::{RateUnit, SensorKind};
use imulab::sim::imu_model::{Channels, ImuSimulator, ImuSpec, G0};
use imulab::sim::presets::imu_preset;
use imulab::sim::temperature::{ProgramSegment, TemperatureProfile};
use imulab::thermal::analysis::{analyse_axis_thermal, AxisThermal, ThermalOptions};
use nalgebra::Vector3;
use std::time::Instant;

fn chamber(cycles: u32) -> TemperatureProfile {
    TemperatureProfile::program(
        25.0,
        vec![
            ProgramSegment::Soak { duration_s: 1200.0 },
            ProgramSegment::Ramp {
                to_c: 60.0,
                c_per_min: 1.0,
            },
            ProgramSegment::Soak { duration_s: 1200.0 },
            ProgramSegment::Ramp {
                to_c: -10.0,
                c_per_min: 1.0,
            },
            ProgramSegment::Soak { duration_s: 1200.0 },
            ProgramSegment::Ramp {
                to_c: 25.0,
                c_per_min: 1.0,
            },
        ],
        cycles,
    )
}

/// One axis (x of `sensor`) of `spec` through `profile`: the series with its temperature.
fn simulate(
    spec: &ImuSpec,
    sensor: SensorKind,
    seed: u64,
    rate_hz: f64,
    duration_s: f64,
    profile: &TemperatureProfile,
) -> AxisSeries {
    let channels = match sensor {
        SensorKind::Gyro => Channels {
            gyro: [true, false, false],
            accel: [false; 3],
        },
        SensorKind::Accel => Channels {
            gyro: [false; 3],
            accel: [true, false, false],
        },
    };
    let mut sim = ImuSimulator::new(spec, "bench", seed, rate_hz, channels).unwrap();
    let n = (duration_s * rate_hz) as usize;
    let (w, f) = (Vector3::zeros(), Vector3::new(0.0, 0.0, -G0));
    let mut rate = Vec::with_capacity(n);
    let mut temp = Vec::with_capacity(n);
    for k in 0..n {
        let r = sim
            .step(&w, &f, profile.at(k as f64 / rate_hz), 0, 0)
            .record
            .unwrap();
        rate.push(match sensor {
            SensorKind::Gyro => r.gyro[0],
            SensorKind::Accel => r.accel[0],
        });
        temp.push(r.temp as f32);
    }
    let name = match sensor {
        SensorKind::Gyro => "gyro_x",
        SensorKind::Accel => "accel_x",
    };
    let mut s = AxisSeries::one_segment(name, 1.0 / rate_hz, rate);
    s.temperature = Some(temp);
    s
}

fn analyse(series: AxisSeries, sensor: SensorKind, profile: &TemperatureProfile) -> AxisThermal {
    let unit = match sensor {
        SensorKind::Gyro => RateUnit::RadPerSecond,
        SensorKind::Accel => RateUnit::MetrePerSecondSquared,
    };
    let chamber = |t: f64| profile.at(t);
    analyse_axis_thermal(
        "bench",
        series,
        sensor,
        unit,
        Some(&chamber),
        &ThermalOptions::default(),
    )
    .unwrap()
    .0
}

/// Within 5 % of the truth, or the truth inside the stated 95 % interval.
fn recovered(a: &AxisThermal, order: usize, truth: f64) -> (bool, f64) {
    let Some(c) = a.coefficients.get(order) else {
        return (false, f64::NAN);
    };
    let error = (c.value - truth) / truth;
    (
        error.abs() <= 0.05 || (c.low..=c.high).contains(&truth),
        error,
    )
}

/// A term's name, its true value, and per seed (recovered, relative error).
type TermResults<'a> = (&'a str, f64, Vec<(bool, f64)>);

fn quiet_grade() -> ImuSpec {
    let mut s = imu_preset("icm20948-thermal").unwrap();
    s.gyro.noise_density_dps_rthz = Some([0.005; 3]);
    s.gyro.bias_instability_dph = [2.0; 3];
    s.accel.noise_density_ug_rthz = Some([100.0; 3]);
    s.accel.bias_instability_mg = [0.01; 3];
    s
}

fn main() {
    let seeds: Vec<u64> = (1..=10).collect();
    let profile = chamber(1);
    let rate = 50.0;
    let duration = 12_000.0;
    println!(
        "| grade | sensor | term | truth | median error | seeds ok (5 % or in 95 % CI) | worst |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (grade, spec) in [
        ("icm20948-thermal", imu_preset("icm20948-thermal").unwrap()),
        ("quiet", quiet_grade()),
    ] {
        for sensor in [SensorKind::Accel, SensorKind::Gyro] {
            let (c1, c2, hyst, tau_w) = match sensor {
                SensorKind::Accel => (
                    spec.accel.bias_tempco_mg_per_c[0],
                    spec.accel.bias_tempco2_mg_per_c2[0],
                    spec.accel.bias_hysteresis_mg[0],
                    spec.thermal.warmup_time_constant_s,
                ),
                SensorKind::Gyro => (
                    spec.gyro.bias_tempco_dph_per_c[0],
                    spec.gyro.bias_tempco2_dph_per_c2[0],
                    spec.gyro.bias_hysteresis_dph[0],
                    spec.thermal.warmup_time_constant_s,
                ),
            };
            let mut rows: Vec<TermResults> = vec![
                ("c1", c1, vec![]),
                ("c2", c2, vec![]),
                ("hysteresis gap", hyst, vec![]),
                ("warm-up τ", tau_w, vec![]),
                ("thermal lag τ", spec.thermal.time_constant_s, vec![]),
            ];
            for &seed in &seeds {
                let a = analyse(
                    simulate(&spec, sensor, seed, rate, duration, &profile),
                    sensor,
                    &profile,
                );
                rows[0].2.push(recovered(&a, 1, c1));
                rows[1].2.push(recovered(&a, 2, c2));
                let gap = a
                    .hysteresis
                    .as_ref()
                    .map_or(f64::NAN, |h| (h.largest_gap - hyst) / hyst);
                rows[2].2.push((gap.abs() <= 0.10, gap));
                let tau = a
                    .warmup
                    .as_ref()
                    .map_or(f64::NAN, |w| (w.time_constant_s - tau_w) / tau_w);
                rows[3].2.push((tau.abs() <= 0.10, tau));
                let chamber_c: Vec<f64> = a.trace.t_s.iter().map(|&t| profile.at(t)).collect();
                let lag =
                    imulab::thermal::analysis::fit_lag(&a.trace.t_s, &chamber_c, &a.trace.temp_c)
                        .map_or(f64::NAN, |l| {
                            (l.0 - spec.thermal.time_constant_s) / spec.thermal.time_constant_s
                        });
                rows[4].2.push((lag.abs() <= 0.10, lag));
            }
            for (term, truth, results) in rows {
                let mut errors: Vec<f64> = results.iter().map(|r| r.1).collect();
                errors.sort_by(f64::total_cmp);
                let ok = results.iter().filter(|r| r.0).count();
                let worst = errors
                    .iter()
                    .copied()
                    .max_by(|a, b| a.abs().total_cmp(&b.abs()))
                    .unwrap_or(f64::NAN);
                println!(
                    "| {grade} | {sensor:?} | {term} | {truth} | {:+.1} % | {ok}/{} | {:+.1} % |",
                    errors[errors.len() / 2] * 100.0,
                    results.len(),
                    worst * 100.0
                );
            }
        }
    }

    // Run time: 24 h at 150 Hz, 6 axes, one axis simulated and analysed at a time.
    let profile = chamber(3);
    let spec = imu_preset("icm20948-thermal").unwrap();
    let mut total = 0.0;
    for (i, sensor) in [
        SensorKind::Gyro,
        SensorKind::Gyro,
        SensorKind::Gyro,
        SensorKind::Accel,
        SensorKind::Accel,
        SensorKind::Accel,
    ]
    .into_iter()
    .enumerate()
    {
        let series = simulate(&spec, sensor, 100 + i as u64, 150.0, 86_400.0, &profile);
        let start = Instant::now();
        let a = analyse(series, sensor, &profile);
        let secs = start.elapsed().as_secs_f64();
        total += secs;
        assert!(a.fit.order >= 1);
    }
    println!("\nwhole thermal analysis of 24 h x 150 Hz x 6 axes (12.96 M samples per axis, in memory; session reading not included): {total:.2} s (target < 2 s)");
}
