//! Test-only data maker for the fusion tests: truth from `sim::motion`, IMU increments with
//! constant biases, scale factors and white noise, GNSS fixes with white noise (the fusion
//! tests and `benches/fusion.rs`).

use imulab::fusion::mechanisation::{ImuInput, NavState};
use imulab::fusion::navigator::GnssObservation;
use imulab::sim::motion::{MotionGenerator, MotionSpec, Segment, TruthSample};
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;

/// The error-free to noisy IMU model of the test data.
#[derive(Debug, Clone, Copy)]
pub struct ImuErrors {
    pub arw: f64,
    pub vrw: f64,
    pub gyro_bias: Vector3<f64>,
    pub accel_bias: Vector3<f64>,
    pub gyro_scale: Vector3<f64>,
    pub accel_scale: Vector3<f64>,
}

pub struct SimData {
    /// Truth at the IMU epochs.
    pub truth: Vec<TruthSample>,
    pub imu: Vec<ImuInput>,
    pub gnss: Vec<GnssObservation>,
    pub imu_rate: f64,
}

impl SimData {
    /// The true state at time `t` (nearest IMU epoch within a microsecond).
    pub fn truth_at(&self, t: f64) -> Option<NavState> {
        let k = (t * self.imu_rate).round();
        if k < 0.0 || (k / self.imu_rate - t).abs() > 1e-6 {
            return None;
        }
        self.truth.get(k as usize).map(imulab::study::nav_state)
    }
}

fn normal3(rng: &mut Xoshiro256PlusPlus) -> Vector3<f64> {
    Vector3::new(
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
    )
}

/// Simulates `spec` with IMU increments at `imu_rate` and GNSS every `gnss_every` IMU epochs
/// with per-axis σ (horizontal, vertical, velocity); the antenna at `lever_b` (body, m).
pub fn simulate(
    spec: &MotionSpec,
    imu_rate: f64,
    gnss_every: usize,
    errors: &ImuErrors,
    gnss_sigma: (f64, f64, f64),
    lever_b: Vector3<f64>,
    seed: u64,
) -> SimData {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    // Truth at twice the IMU rate, streamed: each IMU interval is Simpson-integrated from
    // its start, middle and end sample.
    let mut fine = MotionGenerator::new(spec, 2.0 * imu_rate).expect("valid motion");
    let dt = 1.0 / imu_rate;
    let mut truth = Vec::with_capacity(fine.size_hint().0 / 2 + 1);
    let mut imu = Vec::with_capacity(truth.capacity());
    let Some(mut a) = fine.next() else {
        return SimData {
            truth,
            imu,
            gnss: Vec::new(),
            imu_rate,
        };
    };
    truth.push(a);
    while let (Some(m), Some(b)) = (fine.next(), fine.next()) {
        let simpson =
            |x: Vector3<f64>, y: Vector3<f64>, z: Vector3<f64>| (x + 4.0 * y + z) * dt / 6.0;
        let dth = simpson(a.gyro_b, m.gyro_b, b.gyro_b);
        let dv = simpson(a.accel_b, m.accel_b, b.accel_b);
        let dtheta = dth
            + errors.gyro_scale.component_mul(&dth)
            + errors.gyro_bias * dt
            + errors.arw * dt.sqrt() * normal3(&mut rng);
        let dvel = dv
            + errors.accel_scale.component_mul(&dv)
            + errors.accel_bias * dt
            + errors.vrw * dt.sqrt() * normal3(&mut rng);
        imu.push(ImuInput::Increments {
            t_s: b.t_s,
            dt_s: dt,
            dtheta,
            dvel,
        });
        truth.push(b);
        a = b;
    }
    let mut gnss = Vec::new();
    for t in truth.iter().step_by(gnss_every.max(1)) {
        let mut nav = imulab::study::nav_state(t);
        let lever_n = t.quat_nb * lever_b;
        let omega_b = t.gyro_b;
        let noise_p = normal3(&mut rng);
        let noise_v = normal3(&mut rng);
        nav.shift_position(
            &(lever_n
                + Vector3::new(
                    gnss_sigma.0 * noise_p.x,
                    gnss_sigma.0 * noise_p.y,
                    gnss_sigma.1 * noise_p.z,
                )),
        );
        gnss.push(GnssObservation {
            t_s: t.t_s,
            lat_rad: nav.lat_rad,
            lon_rad: nav.lon_rad,
            height_m: nav.height_m,
            sigma_ned_m: Vector3::new(gnss_sigma.0, gnss_sigma.0, gnss_sigma.1),
            // Earth-rate part of ω×l is below a micrometre per second and left out.
            vel_ned: Some(t.vel_ned + t.quat_nb * omega_b.cross(&lever_b) + gnss_sigma.2 * noise_v),
            sigma_vel_mps: Vector3::repeat(gnss_sigma.2),
        });
    }
    SimData {
        truth,
        imu,
        gnss,
        imu_rate,
    }
}

/// A 5-minute drive: start, figure of turns, climb, stop and go.
pub fn city_drive() -> MotionSpec {
    MotionSpec {
        // A car's body: side-slip in the turns and road heave (docs/simulator.md), as the
        // filter's default NHC expects of a car.
        vehicle: imulab::sim::motion::VehicleDynamics {
            slip_deg_per_mps2: 0.2,
            heave_mps: 0.03,
        },
        lat_deg: 48.1,
        lon_deg: 11.6,
        height_m: 520.0,
        heading_deg: 45.0,
        speed_mps: 0.0,
        segments: vec![
            Segment::Cruise { duration_s: 10.0 },
            Segment::Accelerate {
                dv_mps: 12.0,
                duration_s: 10.0,
            },
            Segment::Turn {
                angle_deg: 90.0,
                duration_s: 8.0,
            },
            Segment::Cruise { duration_s: 20.0 },
            Segment::Turn {
                angle_deg: -180.0,
                duration_s: 14.0,
            },
            Segment::Climb {
                dh_m: 8.0,
                duration_s: 15.0,
            },
            Segment::Accelerate {
                dv_mps: 6.0,
                duration_s: 8.0,
            },
            Segment::Cruise { duration_s: 30.0 },
            Segment::Turn {
                angle_deg: 120.0,
                duration_s: 10.0,
            },
            Segment::Cruise { duration_s: 25.0 },
            Segment::Stop { duration_s: 10.0 },
            Segment::Cruise { duration_s: 10.0 },
            Segment::Accelerate {
                dv_mps: 10.0,
                duration_s: 10.0,
            },
            Segment::Turn {
                angle_deg: -90.0,
                duration_s: 8.0,
            },
            Segment::Cruise { duration_s: 40.0 },
            Segment::Turn {
                angle_deg: 60.0,
                duration_s: 6.0,
            },
            Segment::Cruise { duration_s: 40.0 },
            Segment::Stop { duration_s: 10.0 },
            Segment::Cruise { duration_s: 5.0 },
        ],
    }
}

/// A consumer MEMS IMU's errors (drawn once) matching `FusionConfig::default()`'s model.
pub fn mems_errors(seed: u64) -> ImuErrors {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x5eed);
    let cfg = imulab::fusion::config::FusionConfig::default().imu;
    ImuErrors {
        arw: cfg.arw_rad_per_sqrt_s.max(),
        vrw: cfg.vrw_mps_per_sqrt_s.max(),
        gyro_bias: Vector3::from(cfg.gyro_bias.sigma.0).component_mul(&normal3(&mut rng)),
        accel_bias: Vector3::from(cfg.accel_bias.sigma.0).component_mul(&normal3(&mut rng)),
        gyro_scale: Vector3::from(cfg.gyro_scale.sigma.0).component_mul(&normal3(&mut rng)),
        accel_scale: Vector3::from(cfg.accel_scale.sigma.0).component_mul(&normal3(&mut rng)),
    }
}
