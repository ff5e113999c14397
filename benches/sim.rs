//! Simulator benchmark: run time and throughput of one 6-axis IMU with the full error model
//! (6 h × 150 Hz target: under 1 s on one core), scaling with duration, the saving from
//! computing only what a scene needs, and the Allan-recovered noise terms of every preset
//! next to the configured ones, and serving throughput and pacing on ptys. Prints markdown
//! tables; see docs/bench/sim.md.
//!
//! Run: `cargo bench --bench sim` (release; single-threaded rayon pool for the timings);
//! `cargo bench --bench sim -- demo` times `imulab demo` as a user runs it.

#[path = "support/results.rs"]
mod results;

use imulab_test_support::allan_check as sim_support;
use serde_json::json;

use std::io::Read;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::time::Instant;

use anyhow::Result;
use imulab::sim::outputs::SimSink;
use imulab::sim::presets::IMU_PRESETS;
use imulab::sim::runner::run;
use imulab::sim::scene::Scene;
use imulab::sim::serve::{Sent, ServeOptions, ServeReport, Server, Speed, StartWhen};
use imulab::store::{EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord};

const DEG: f64 = std::f64::consts::PI / 180.0;
const G0: f64 = 9.806_65;

/// Counts records and folds one value of each so nothing is optimised away.
#[derive(Default)]
struct CountingSink {
    records: u64,
    checksum: f64,
}

impl SimSink for CountingSink {
    fn imu(&mut self, _: &str, r: &[ImuRecord]) -> Result<()> {
        self.records += r.len() as u64;
        self.checksum += r.iter().map(|x| x.gyro[0] + x.accel[2]).sum::<f64>();
        Ok(())
    }
    fn gnss(&mut self, _: &str, r: &[GnssRecord]) -> Result<()> {
        self.records += r.len() as u64;
        Ok(())
    }
    fn truth_nav(&mut self, r: &[TruthNavRecord]) -> Result<()> {
        self.records += r.len() as u64;
        Ok(())
    }
    fn truth_imu(&mut self, _: &str, r: &[TruthImuRecord]) -> Result<()> {
        self.records += r.len() as u64;
        Ok(())
    }
    fn event(&mut self, _: &EventRecord) -> Result<()> {
        Ok(())
    }
}

/// Keeps 10-sample block means of the six channels of one IMU (for the Allan table):
/// ten times less memory, and OADEV at τ = multiples of 10 samples is unaffected.
#[derive(Default)]
struct BlockMeanSink {
    acc: [f64; 6],
    count: usize,
    means: [Vec<f64>; 6],
}

const BLOCK: usize = 10;

impl SimSink for BlockMeanSink {
    fn imu(&mut self, _: &str, r: &[ImuRecord]) -> Result<()> {
        for x in r {
            let v = [
                x.gyro[0], x.gyro[1], x.gyro[2], x.accel[0], x.accel[1], x.accel[2],
            ];
            for (acc, x) in self.acc.iter_mut().zip(v) {
                *acc += x;
            }
            self.count += 1;
            if self.count == BLOCK {
                for (acc, means) in self.acc.iter_mut().zip(&mut self.means) {
                    means.push(*acc / BLOCK as f64);
                    *acc = 0.0;
                }
                self.count = 0;
            }
        }
        Ok(())
    }
    fn gnss(&mut self, _: &str, _: &[GnssRecord]) -> Result<()> {
        Ok(())
    }
    fn truth_nav(&mut self, _: &[TruthNavRecord]) -> Result<()> {
        Ok(())
    }
    fn truth_imu(&mut self, _: &str, _: &[TruthImuRecord]) -> Result<()> {
        Ok(())
    }
    fn event(&mut self, _: &EventRecord) -> Result<()> {
        Ok(())
    }
}

const FULL_IMU: &str = r#"
[[imu]]
name = "dut"
preset = "bench-cheap"
[imu.gyro]
rrw_dph_rth = [1.0, 1.0, 1.0]
rate_ramp_dph_per_h = [0.5, -0.5, 0.2]
turn_on_bias_sigma_dph = [20.0, 20.0, 20.0]
scale_factor_ppm = [500.0, -300.0, 200.0]
misalignment_mrad = [1.0, -0.5, 0.3, 0.8, -1.0, 0.2]
g_sensitivity_dph_per_g = [[10.0, 1.0, 0.0], [0.0, 10.0, 1.0], [1.0, 0.0, 10.0]]
bias_tempco_dph_per_c = [0.5, -0.4, 0.3]
scale_tempco_ppm_per_c = [20.0, 20.0, 20.0]
range_dps = 2000.0
lsb_dps = 0.001
[imu.accel]
rrw_mg_rth = [0.02, 0.02, 0.02]
rate_ramp_mg_per_h = [0.01, 0.01, -0.01]
turn_on_bias_sigma_mg = [2.0, 2.0, 2.0]
scale_factor_ppm = [300.0, 300.0, -300.0]
misalignment_mrad = [0.5, 0.5, -0.5, 0.5, 0.5, -0.5]
bias_tempco_mg_per_c = [0.02, 0.02, 0.02]
scale_tempco_ppm_per_c = [10.0, 10.0, 10.0]
range_g = 16.0
lsb_mg = 0.05
[imu.timing]
jitter_us = 50.0
drop_probability = 0.0001
"#;

fn scene(duration_s: f64, motion: &str, temperature: &str, sensors: &str, truth: bool) -> Scene {
    let text = format!(
        r#"
duration_s = {duration_s}
rate_hz = 150
seed = 1
[location]
lat_deg = 48.15
lon_deg = 11.57
height_m = 520
{motion}
{temperature}
[outputs]
truth_nav = {truth}
truth_imu = {truth}
{sensors}
"#
    );
    Scene::parse(&text, Path::new(".")).expect("benchmark scene")
}

const STATIC: &str = "[motion]\nkind = \"static\"";
const RAMP: &str =
    "[temperature]\nkind = \"ramp\"\nstart_c = 20\nend_c = 30\nstart_s = 0\nend_s = 21600";
const CONSTANT: &str = "[temperature]\nkind = \"constant\"\ncelsius = 25";

fn drive(duration_s: f64) -> String {
    // Repeating 10-minute laps: accelerate, cruise, turn, cruise, brake, stand.
    let laps = (duration_s / 600.0).ceil() as usize;
    let lap = r#"{ kind = "accelerate", dv_mps = 15, duration_s = 20 }, { kind = "cruise", duration_s = 200 }, { kind = "turn", angle_deg = 90, duration_s = 20 }, { kind = "cruise", duration_s = 300 }, { kind = "accelerate", dv_mps = -15, duration_s = 20 }, { kind = "stop", duration_s = 40 }"#;
    format!(
        "[motion]\nkind = \"segments\"\nsegments = [{}]",
        vec![lap; laps].join(", ")
    )
}

/// CPU time of this process, s (the machine is shared: wall time alone would also measure
/// the other users).
fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime only writes the timespec we pass.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Best of `reps` single-threaded runs: (CPU seconds, wall seconds, samples, records).
fn time_scene(s: &Scene, reps: usize) -> (f64, f64, u64, u64) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let (mut best_cpu, mut best_wall) = (f64::INFINITY, f64::INFINITY);
    let mut out = (0, 0);
    for _ in 0..reps {
        let mut sink = CountingSink::default();
        let (c, t) = (cpu_seconds(), Instant::now());
        let stats = pool.install(|| run(s, &mut sink)).expect("run");
        best_wall = best_wall.min(t.elapsed().as_secs_f64());
        best_cpu = best_cpu.min(cpu_seconds() - c);
        std::hint::black_box(sink.checksum);
        out = (stats.samples, sink.records);
    }
    (best_cpu, best_wall, out.0, out.1)
}

fn main() {
    // `cargo bench --bench sim -- SECTION...` runs only the named sections
    // (throughput, needs, allan, serve); no names runs all.
    let wanted: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let run_section = |name: &str| wanted.is_empty() || wanted.iter().any(|w| w == name);
    let six_h = 6.0 * 3600.0;
    if run_section("throughput") {
        throughput();
    }
    if run_section("needs") {
        needs(six_h);
    }
    if run_section("allan") {
        allan(six_h);
    }
    if run_section("serve") {
        serve();
    }
    // Not in the default set: it runs the whole demo through the release binaries.
    if wanted.iter().any(|w| w == "demo") {
        demo();
    }
}

/// `imulab demo` as a user runs it: the release binary (with the `imulogd` beside it) into a
/// temporary directory; wall time, CPU and peak RSS of the demo and its children.
fn demo() {
    let out = std::env::temp_dir().join(format!("imulab-demo-bench-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let start = Instant::now();
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(["demo", "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .status()
        .expect("run imulab demo");
    let wall = start.elapsed().as_secs_f64();
    assert!(status.success(), "imulab demo: {status}");
    // SAFETY: getrusage only writes the struct it is given.
    let usage = unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut u);
        u
    };
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    let cpu = seconds(usage.ru_utime) + seconds(usage.ru_stime);
    let peak_mb = usage.ru_maxrss as f64 / 1024.0;
    let _ = std::fs::remove_dir_all(&out);
    println!(
        "imulab demo: {wall:.1} s wall, {cpu:.1} s CPU (with imulogd), peak RSS {peak_mb:.0} MB"
    );
    let row = results::Row::new(
        "demo",
        results::FUSION,
        9,
        "`imulab demo`",
        "docs/bench/demo.md",
    )
    .data("30 sim. min through imulogd, report, replay, study")
    .ours(format!("{wall:.1} s, {peak_mb:.0} MB"))
    .target("≈ 2 min")
    .met(wall < 150.0)
    .timed()
    .command("cargo bench --bench sim -- demo");
    results::write(
        "sim",
        "demo",
        json!({ "command": "imulab demo --out TMP" }),
        json!({ "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": peak_mb }),
        &[row],
    );
}

/// Serves `scene` to one draining reader thread per endpoint; returns the report.
fn serve_with_readers(scene: Scene, speed: Speed) -> ServeReport {
    let mut server = Server::start(
        scene,
        ServeOptions {
            speed,
            start: StartWhen::ReadersAttached,
            record_sent: true,
            ..ServeOptions::default()
        },
    )
    .expect("serve");
    let readers: Vec<_> = server
        .endpoints()
        .iter()
        .map(|e| {
            let path = e.path().to_path_buf();
            std::thread::spawn(move || {
                let mut f = std::fs::OpenOptions::new()
                    .read(true)
                    .write(true)
                    .custom_flags(libc::O_NOCTTY)
                    .open(&path)
                    .expect("open pty");
                let mut buf = vec![0u8; 1 << 16];
                let mut total = 0u64;
                // Reads until the server closes the pty (EIO).
                while let Ok(n) = f.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    total += n as u64;
                }
                total
            })
        })
        .collect();
    let report = server.finish().expect("serve finished");
    // Let the readers take the last bytes, then hang up.
    std::thread::sleep(std::time::Duration::from_millis(200));
    drop(server);
    for (r, s) in readers.into_iter().zip(&report.streams) {
        let got = r.join().expect("reader");
        assert_eq!(got, s.bytes, "{}: every byte read", s.sensor);
    }
    report
}

fn serve() {
    let bench = |duration_s: f64| {
        let text = format!(
            r#"
duration_s = {duration_s}
rate_hz = 200
seed = 2
[location]
lat_deg = 48.15
lon_deg = 11.57
height_m = 520
[motion]
kind = "static"
[[imu]]
name = "wit"
preset = "bench-cheap"
[[imu]]
name = "mti"
preset = "industrial"
protocol = "xbus"
[[imu]]
name = "can"
preset = "tactical"
protocol = "slcan"
[[gnss]]
name = "rx"
preset = "standalone"
rate_hz = 10
"#
        );
        Scene::parse(&text, Path::new(".")).expect("serve scene")
    };
    println!("\n## Serving (`imulab sim --serve`): three 200 Hz IMUs (wit, xbus, slcan) + 10 Hz NMEA/UBX GNSS on ptys\n");
    println!("| speed | scene (s) | wall (s) | frames | bytes | frames/s | lateness median (ms) | p99 (ms) | max (ms) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut runs = Vec::new();
    for (speed, duration) in [
        (Speed::Max, 600.0),
        (Speed::Factor(1.0), 10.0),
        (Speed::Factor(20.0), 120.0),
    ] {
        let report = serve_with_readers(bench(duration), speed);
        let frames: u64 = report.streams.iter().map(|s| s.frames).sum();
        let bytes: u64 = report.streams.iter().map(|s| s.bytes).sum();
        let mut late: Vec<f64> = Vec::new();
        if let Speed::Factor(f) = speed {
            for s in &report.streams {
                let times: Vec<(i64, u64)> = match &s.sent {
                    Sent::Imu(v) => v.iter().map(|x| (x.t_ns, x.written_ns)).collect(),
                    Sent::Gnss(v) => v.iter().map(|x| (x.t_ns, x.written_ns)).collect(),
                };
                late.extend(times.iter().map(|&(t, w)| (w as f64 - t as f64 / f) * 1e-6));
            }
        }
        late.sort_by(f64::total_cmp);
        let q = |p: f64| {
            if late.is_empty() {
                "-".to_string()
            } else {
                format!("{:.2}", late[((late.len() - 1) as f64 * p) as usize])
            }
        };
        let wall = report.elapsed.as_secs_f64();
        println!(
            "| {} | {duration} | {wall:.3} | {frames} | {bytes} | {:.3e} | {} | {} | {} |",
            match speed {
                Speed::Max => "max".to_string(),
                Speed::Factor(f) => format!("{f}×"),
            },
            frames as f64 / wall,
            q(0.5),
            q(0.99),
            q(1.0)
        );
        let at = |p: f64| (!late.is_empty()).then(|| late[((late.len() - 1) as f64 * p) as usize]);
        runs.push(json!({
            "speed": match speed { Speed::Max => "max".to_string(), Speed::Factor(f) => format!("{f}") },
            "scene_s": duration, "wall_s": wall, "frames": frames, "bytes": bytes,
            "lateness_ms_p50": at(0.5), "lateness_ms_p99": at(0.99), "lateness_ms_max": at(1.0),
        }));
    }
    let max = &runs[0];
    let p99 = runs
        .iter()
        .filter_map(|r| r["lateness_ms_p99"].as_f64())
        .fold(0.0f64, f64::max);
    let row = results::Row::new(
        "sim-serve",
        results::SIM_CALIB_THERMAL,
        2,
        "serving ptys",
        "docs/bench/sim.md",
    )
    .data(format!("{} frames", max["frames"]))
    .ours(format!(
        "{:.2} s; p99 lateness {p99:.2} ms",
        max["wall_s"].as_f64().unwrap_or(f64::NAN)
    ))
    .command("cargo bench --bench sim -- serve");
    results::write(
        "sim",
        "serve",
        json!({ "imus": 3, "gnss": 1, "rate_hz": 200 }),
        json!({ "runs": runs }),
        &[row],
    );
}

fn throughput() {
    println!("## Full error model, one 6-axis IMU, 150 Hz, single thread\n");
    println!("| duration | samples | CPU (s) | wall (s) | samples/s (CPU) | CPU s per sim. hour |");
    println!("|---|---|---|---|---|---|");
    let mut runs = Vec::new();
    for hours in [0.75, 1.5, 3.0, 6.0] {
        let s = scene(hours * 3600.0, STATIC, RAMP, FULL_IMU, false);
        let (t, wall, n, _) = time_scene(&s, 3);
        println!(
            "| {hours} h | {n} | {t:.3} | {wall:.3} | {:.3e} | {:.4} |",
            n as f64 / t,
            t / hours
        );
        runs.push(json!({ "hours": hours, "samples": n, "cpu_s": t, "wall_s": wall }));
    }
    let six = runs
        .last()
        .and_then(|r| r["cpu_s"].as_f64())
        .unwrap_or(f64::NAN);
    let row = results::Row::new(
        "sim-model",
        results::SIM_CALIB_THERMAL,
        1,
        "error model",
        "docs/bench/sim.md",
    )
    .data("6 h × 150 Hz, both triads")
    .ours(format!("{six:.3} s CPU"))
    .target("< 1 s")
    .met(six < 1.0)
    .timed()
    .command("cargo bench --bench sim -- throughput");
    results::write(
        "sim",
        "throughput",
        json!({ "rate_hz": 150, "best_of": 3 }),
        json!({ "runs": runs }),
        &[row],
    );
}

fn needs(six_h: f64) {
    println!("\n## Compute only what the scene needs (6 h × 150 Hz, single thread)\n");
    println!("| scene | CPU (s) | wall (s) | records out | samples/s (CPU) |");
    println!("|---|---|---|---|---|");
    let cheap = "[[imu]]\nname = \"dut\"\npreset = \"bench-cheap\"";
    let gyro_only = "[[imu]]\nname = \"dut\"\npreset = \"bench-cheap\"\nchannels = [\"gyro\"]";
    let one_axis = "[[imu]]\nname = \"dut\"\npreset = \"bench-cheap\"\nchannels = [\"gyro.z\"]";
    let with_gnss =
        format!("{FULL_IMU}\n[[gnss]]\nname = \"rx\"\npreset = \"standalone\"\nrate_hz = 10");
    let cases: Vec<(&str, Scene)> = vec![
        (
            "static, bench-cheap, one axis (gyro.z)",
            scene(six_h, STATIC, CONSTANT, one_axis, false),
        ),
        (
            "static, bench-cheap, gyro only",
            scene(six_h, STATIC, CONSTANT, gyro_only, false),
        ),
        (
            "static, bench-cheap, gyro + accel",
            scene(six_h, STATIC, CONSTANT, cheap, false),
        ),
        (
            "static, full model, temperature ramp",
            scene(six_h, STATIC, RAMP, FULL_IMU, false),
        ),
        (
            "static, full model, + truth outputs",
            scene(six_h, STATIC, RAMP, FULL_IMU, true),
        ),
        (
            "static, full model, + 10 Hz GNSS",
            scene(six_h, STATIC, RAMP, &with_gnss, false),
        ),
        (
            "drive (segments), full model + GNSS + truth",
            scene(six_h, &drive(six_h), RAMP, &with_gnss, true),
        ),
    ];
    for (name, s) in &cases {
        let (t, wall, n, records) = time_scene(s, 2);
        println!(
            "| {name} | {t:.3} | {wall:.3} | {records} | {:.3e} |",
            n as f64 / t
        );
    }
}

fn allan(six_h: f64) {
    println!("\n## Allan-recovered noise terms of the presets (6 h × 150 Hz, seed 1)\n");
    println!("Fit of AVAR = N²/τ + F² + K²τ/3 + R²τ²/2 over τ = 0.067 s … 2160 s, B = F / 0.664");
    println!(
        "(IEEE Std 952, the presets' convention); \"min\" is the minimum of the ADEV curve.\n"
    );
    println!("| preset | axis | N set | N fit | B set | B fit | min ADEV | unit N / B |");
    println!("|---|---|---|---|---|---|---|---|");
    for preset in IMU_PRESETS {
        let sensors = format!("[[imu]]\nname = \"dut\"\npreset = \"{}\"", preset.name);
        let mut s = scene(six_h, STATIC, CONSTANT, &sensors, false);
        let spec = s.imus[0].spec.clone();
        // No drops, so each block mean covers 10 consecutive samples.
        s.imus[0].spec.timing.drop_probability = 0.0;
        let mut sink = BlockMeanSink::default();
        run(&s, &mut sink).expect("run");
        let dt = BLOCK as f64 / 150.0;
        for (ch, y) in sink.means.iter().enumerate() {
            let points: Vec<(f64, f64)> = sim_support::log_factors(y.len(), 5.0, 10)
                .into_iter()
                .map(|m| (m as f64 * dt, sim_support::oadev(y, dt, m)))
                .collect();
            let (n, floor, _, _) = sim_support::fit_terms(&points);
            let b = floor / imulab::allan::fit::BIAS_INSTABILITY_FACTOR;
            let min = points.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
            let axis = ch % 3;
            if ch < 3 {
                let g = &spec.gyro;
                let n_set = g
                    .arw_deg_rth
                    .map(|a| a[axis])
                    .or(g.noise_density_dps_rthz.map(|d| d[axis] * 60.0))
                    .unwrap_or(0.0);
                let k = DEG / 3600.0;
                println!(
                    "| {} | gyro {} | {n_set:.3} | {:.3} | {:.2} | {:.2} | {:.2} | °/√h / °/h |",
                    preset.name,
                    ["x", "y", "z"][axis],
                    n / (DEG / 60.0),
                    g.bias_instability_dph[axis],
                    b / k,
                    min / k
                );
            } else {
                let a = &spec.accel;
                let n_set = a
                    .vrw_mg_rth
                    .map(|v| v[axis])
                    .or(a.noise_density_ug_rthz.map(|d| d[axis] * 60.0 / 1000.0))
                    .unwrap_or(0.0);
                let mg = G0 * 1e-3;
                println!(
                    "| {} | accel {} | {n_set:.3} | {:.3} | {:.4} | {:.4} | {:.4} | mg/√h / mg |",
                    preset.name,
                    ["x", "y", "z"][axis],
                    n / (mg / 60.0),
                    a.bias_instability_mg[axis],
                    b / mg,
                    min / mg
                );
            }
        }
    }
}
