//! Process and measurement models of the loosely coupled error-state filter.
//!
//! Error state (estimate minus truth), N = 15 to 30 ([`Layout`]):
//! `δr` NED position error (m) 0..3, `δv` NED velocity error 3..6, `φ` attitude error 6..9
//! defined by C_b^n(est) = (I − [φ×]) C_b^n(true), gyro bias error 9..12 (rad/s), accel bias
//! error 12..15 (m/s²), and with 21 states gyro 15..18 and accel 18..21 scale-factor errors.
//! With `turn_on_states` six turn-on bias errors follow (gyro, then accel): the sensor's bias
//! is the bias state plus its turn-on state, which also carries the in-run bias's slow part
//! where the model has one (a random constant otherwise). With the GNSS position error
//! modelled (`config::GnssPositionError`) three more states come last: the error of the
//! receiver's correlated position-error estimate (estimate minus truth, NED, m).
//! The sensors are modelled as ω̃ = (I + diag s_g) ω + b_g + noise, f̃ likewise.
//!
//! The continuous error dynamics are the usual ψ-angle model in NED (Titterton & Weston,
//! *Strapdown Inertial Navigation Technology*, ch. 12; Shin 2005, ch. 2) including the
//! transport-rate couplings, the vertical gravity gradient and the Gauss-Markov sensor errors.

use crate::config::{Axes, FusionConfig, NhcOptions, VehicleOptions};
use crate::mechanisation::NavState;
use imulab_earth as earth;
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

pub const POS: usize = 0;
pub const VEL: usize = 3;
pub const ATT: usize = 6;
pub const BG: usize = 9;
pub const BA: usize = 12;
pub const SG: usize = 15;
pub const SA: usize = 18;

/// Which optional groups of states a filter carries, and where. After the 15 base states
/// come the scale factors (6, at [`SG`] and [`SA`]), then the turn-on biases (6: gyro, then
/// accelerometer), then the GNSS position error (3, always last). Each of the first two
/// groups adds 6 states and the last 3, so the count alone tells only whether the GNSS
/// states are there ([`gnss_error_index`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    pub states: usize,
    pub scale_factors: bool,
    /// First of the six turn-on bias states (gyro x, y, z, then accelerometer x, y, z).
    pub turn_on: Option<usize>,
    pub gnss_error: Option<usize>,
}

impl Layout {
    pub fn of(config: &FusionConfig) -> Self {
        let scale_factors = config.states == 21;
        let mut n = if scale_factors { 21 } else { 15 };
        let turn_on = config.turn_on_states.then_some(n);
        if turn_on.is_some() {
            n += 6;
        }
        let gnss_error = config.gnss.position_error.enabled().then_some(n);
        if gnss_error.is_some() {
            n += 3;
        }
        Self {
            states: n,
            scale_factors,
            turn_on,
            gnss_error,
        }
    }

    /// Gives the turn-on states the columns of the in-run bias states in `h`: the sensor's
    /// bias is their sum, so every model sees the two alike.
    pub fn share_bias_columns<const R: usize, const N: usize>(&self, h: &mut SMatrix<f64, R, N>) {
        if let Some(t) = self.turn_on {
            let gyro = h.fixed_columns::<3>(BG).into_owned();
            let accel = h.fixed_columns::<3>(BA).into_owned();
            h.fixed_columns_mut::<3>(t).copy_from(&gyro);
            h.fixed_columns_mut::<3>(t + 3).copy_from(&accel);
        }
    }
}

/// First of the three GNSS position-error states of a filter of `n` states: they are there
/// exactly when `n` is a multiple of 6 (15 base states and groups of 6, see [`Layout`]).
pub const fn gnss_error_index(n: usize) -> Option<usize> {
    if n.is_multiple_of(6) {
        Some(n - 3)
    } else {
        None
    }
}

/// Skew-symmetric cross-product matrix [v×].
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The continuous-time error dynamics matrix F for mean body rate `gyro_b` and specific force
/// `accel_b` (bias-corrected) over the interval.
pub fn dynamics_matrix<const N: usize>(
    nav: &NavState,
    gyro_b: &Vector3<f64>,
    accel_b: &Vector3<f64>,
    config: &FusionConfig,
) -> SMatrix<f64, N, N> {
    let mut f = SMatrix::<f64, N, N>::zeros();
    let (lat, h, v) = (nav.lat_rad, nav.height_m, nav.vel_ned);
    let (rm, rn) = nav.radii();
    let tan = lat.tan();
    let c_bn = nav.quat_nb.to_rotation_matrix().into_inner();
    let w_ie = earth::earth_rate_ned(lat);
    let w_en = earth::transport_rate_ned(lat, h, &v);
    let w_in = w_ie + w_en;
    let f_n = c_bn * accel_b;
    let g = earth::normal_gravity(lat, h);
    let omega = earth::OMEGA_IE;

    // Position error.
    let mut frr = Matrix3::zeros();
    frr[(0, 0)] = -v.z / rm;
    frr[(0, 2)] = v.x / rm;
    frr[(1, 0)] = v.y * tan / rm;
    frr[(1, 1)] = -(v.x * tan / rm + v.z / rn);
    frr[(1, 2)] = v.y / rn;
    f.fixed_view_mut::<3, 3>(POS, POS).copy_from(&frr);
    f.fixed_view_mut::<3, 3>(POS, VEL)
        .copy_from(&Matrix3::identity());

    // Velocity error: δv̇ = [fⁿ×]φ − C δb_a − (2ω_ie + ω_en)×δv + gravity gradient.
    let mut fvr = Matrix3::zeros();
    fvr[(2, 2)] = 2.0 * g / (rm.sqrt() * rn.sqrt());
    f.fixed_view_mut::<3, 3>(VEL, POS).copy_from(&fvr);
    f.fixed_view_mut::<3, 3>(VEL, VEL)
        .copy_from(&(-skew(&(2.0 * w_ie + w_en))));
    f.fixed_view_mut::<3, 3>(VEL, ATT).copy_from(&skew(&f_n));
    f.fixed_view_mut::<3, 3>(VEL, BA).copy_from(&(-c_bn));

    // Attitude error: φ̇ = −ω_in×φ + δω_in + C δb_g.
    let mut far = Matrix3::zeros();
    far[(0, 0)] = -omega * lat.sin() / rm;
    far[(2, 0)] = -omega * lat.cos() / rm - v.y / (rn * rm * lat.cos().powi(2));
    far[(0, 2)] = v.y / (rn * rn);
    far[(1, 2)] = -v.x / (rm * rm);
    far[(2, 2)] = -v.y * tan / (rn * rn);
    f.fixed_view_mut::<3, 3>(ATT, POS).copy_from(&far);
    let mut fav = Matrix3::zeros();
    fav[(0, 1)] = 1.0 / rn;
    fav[(1, 0)] = -1.0 / rm;
    fav[(2, 1)] = -tan / rn;
    f.fixed_view_mut::<3, 3>(ATT, VEL).copy_from(&fav);
    f.fixed_view_mut::<3, 3>(ATT, ATT)
        .copy_from(&(-skew(&w_in)));
    f.fixed_view_mut::<3, 3>(ATT, BG).copy_from(&c_bn);

    // Sensor errors as first-order Gauss-Markov processes.
    let imu = &config.imu;
    for i in 0..3 {
        f[(BG + i, BG + i)] = -imu.gyro_bias_state(i).decay();
        f[(BA + i, BA + i)] = -imu.accel_bias_state(i).decay();
    }
    if let Some(ge) = gnss_error_index(N) {
        let decay = 1.0 / config.gnss.position_error.tau_s;
        for i in 0..3 {
            f[(ge + i, ge + i)] = -decay;
        }
    }
    let layout = Layout::of(config);
    if let Some(t) = layout.turn_on {
        // They enter as the in-run biases do, and decay only as the slow bias they carry
        // changes (random constants without one).
        f.fixed_view_mut::<3, 3>(ATT, t).copy_from(&c_bn);
        f.fixed_view_mut::<3, 3>(VEL, t + 3).copy_from(&(-c_bn));
        for i in 0..3 {
            f[(BG + i, BG + i)] = -imu.gyro_in_run_state(i).decay();
            f[(BA + i, BA + i)] = -imu.accel_in_run_state(i).decay();
            f[(t + i, t + i)] = -imu.gyro_turn_on_state(i).decay();
            f[(t + 3 + i, t + 3 + i)] = -imu.accel_turn_on_state(i).decay();
        }
    }
    if layout.scale_factors {
        f.fixed_view_mut::<3, 3>(ATT, SG)
            .copy_from(&(c_bn * Matrix3::from_diagonal(gyro_b)));
        f.fixed_view_mut::<3, 3>(VEL, SA)
            .copy_from(&(-c_bn * Matrix3::from_diagonal(accel_b)));
        for i in 0..3 {
            f[(SG + i, SG + i)] = -imu.gyro_scale.decay();
            f[(SA + i, SA + i)] = -imu.accel_scale.decay();
        }
    }
    f
}

/// Continuous process noise spectral densities (diagonal of G Q Gᵀ): white noise on
/// velocity (VRW) and attitude (ARW) and the Gauss-Markov driving noises.
pub fn process_noise_psd<const N: usize>(config: &FusionConfig) -> SVector<f64, N> {
    let imu = &config.imu;
    let layout = Layout::of(config);
    let mut q = SVector::<f64, N>::zeros();
    for i in 0..3 {
        // Body-axis noise enters the navigation-frame velocity and attitude rotated, so the
        // per-axis densities are a full 3×3 block there; its diagonal, the mean of the three,
        // is what this diagonal form keeps (exact when the axes are alike).
        q[VEL + i] = mean_square(&imu.vrw_mps_per_sqrt_s);
        q[ATT + i] = mean_square(&imu.arw_rad_per_sqrt_s);
        let (gyro, accel) = if layout.turn_on.is_some() {
            (imu.gyro_in_run_state(i), imu.accel_in_run_state(i))
        } else {
            (imu.gyro_bias_state(i), imu.accel_bias_state(i))
        };
        q[BG + i] = gyro.driving_psd() + imu.gyro_rrw_rad_per_s_sqrt_s[i].powi(2);
        q[BA + i] = accel.driving_psd() + imu.accel_rrw_mps2_per_sqrt_s[i].powi(2);
        if let Some(t) = layout.turn_on {
            q[t + i] = imu.gyro_turn_on_state(i).driving_psd();
            q[t + 3 + i] = imu.accel_turn_on_state(i).driving_psd();
        }
        if layout.scale_factors {
            q[SG + i] = imu.gyro_scale.axis(i).driving_psd();
            q[SA + i] = imu.accel_scale.axis(i).driving_psd();
        }
    }
    if let Some(ge) = gnss_error_index(N) {
        let e = &config.gnss.position_error;
        for (i, s) in e.sigma_ned().iter().enumerate() {
            q[ge + i] = 2.0 * s * s / e.tau_s;
        }
    }
    q
}

/// The mean of the squares of a per-axis density: the diagonal of its rotation into the
/// navigation frame for any attitude when the axes are alike, its trace / 3 otherwise.
fn mean_square(a: &Axes) -> f64 {
    a.0.iter().map(|v| v * v).sum::<f64>() / 3.0
}

/// Navigation error states (position, velocity, attitude); the sensor-error states after
/// them evolve each on its own (first-order Gauss-Markov or random constant).
pub const NAV_STATES: usize = 9;

/// Discrete transition Φ ≈ I + FΔt + (FΔt)²/2 and process noise Q_d ≈ (Φ Q Φᵀ + Q) Δt / 2
/// (dense reference; the filter uses [`discretise_sparse`]).
pub fn discretise<const N: usize>(
    f: &SMatrix<f64, N, N>,
    q_psd: &SVector<f64, N>,
    dt: f64,
) -> (SMatrix<f64, N, N>, SMatrix<f64, N, N>) {
    let fdt = f * dt;
    let phi = SMatrix::<f64, N, N>::identity() + fdt + 0.5 * fdt * fdt;
    // Φ·diag(q) is a column scaling: one matrix product instead of two.
    let mut phi_q = phi;
    for (j, mut column) in phi_q.column_iter_mut().enumerate() {
        column *= q_psd[j];
    }
    let mut qd =
        (phi_q * phi.transpose() + SMatrix::<f64, N, N>::from_diagonal(q_psd)) * (0.5 * dt);
    qd = 0.5 * (qd + qd.transpose());
    (phi, qd)
}

/// [`discretise`] for the structure of [`dynamics_matrix`]: the sensor-error rows of F
/// (from [`NAV_STATES`] on) hold only their diagonal decay, so Φ = [[A, B], [0, D]] with
/// D diagonal. Same values as the dense form (up to rounding; tested) at about a fifth of
/// the products for 15 states.
pub fn discretise_sparse<const N: usize>(
    f: &SMatrix<f64, N, N>,
    q_psd: &SVector<f64, N>,
    dt: f64,
) -> (SMatrix<f64, N, N>, SMatrix<f64, N, N>) {
    debug_assert!(sensor_rows_diagonal(f), "F's sensor rows are not diagonal");
    let fdt = f * dt;
    // (FΔt)²: the navigation rows need the product; the sensor rows are the squared decay.
    let top = fdt.fixed_rows::<NAV_STATES>(0) * fdt;
    let mut phi = SMatrix::<f64, N, N>::identity() + fdt;
    let mut phi_top = phi.fixed_rows_mut::<NAV_STATES>(0);
    phi_top += 0.5 * top;
    for i in NAV_STATES..N {
        phi[(i, i)] += 0.5 * fdt[(i, i)] * fdt[(i, i)];
    }
    // Φ Q Φᵀ with Q diagonal.
    let mut top_q = phi.fixed_rows::<NAV_STATES>(0).into_owned();
    for (j, mut column) in top_q.column_iter_mut().enumerate() {
        column *= q_psd[j];
    }
    let nav_block = top_q * phi.fixed_rows::<NAV_STATES>(0).transpose();
    let mut qd = SMatrix::<f64, N, N>::from_diagonal(q_psd);
    for i in 0..NAV_STATES {
        for j in 0..NAV_STATES {
            qd[(i, j)] += nav_block[(i, j)];
        }
        for j in NAV_STATES..N {
            let v = phi[(i, j)] * q_psd[j] * phi[(j, j)];
            qd[(i, j)] += v;
            qd[(j, i)] += v;
        }
    }
    for j in NAV_STATES..N {
        qd[(j, j)] += phi[(j, j)] * phi[(j, j)] * q_psd[j];
    }
    qd *= 0.5 * dt;
    qd = 0.5 * (qd + qd.transpose());
    (phi, qd)
}

/// Φ P Φᵀ for a Φ of the structure [`discretise_sparse`] gives ([[A, B], [0, D]], D
/// diagonal): the navigation rows of Φ P and the navigation columns of (Φ P) Φᵀ are
/// products, the rest are scalings; 2·9·N² multiplications instead of 2·N³. The
/// result is symmetrised.
pub fn propagate_covariance_sparse<const N: usize>(
    phi: &SMatrix<f64, N, N>,
    p: &SMatrix<f64, N, N>,
) -> SMatrix<f64, N, N> {
    debug_assert!(
        sensor_rows_diagonal(phi),
        "Φ's sensor rows are not diagonal"
    );
    let phi_top = phi.fixed_rows::<NAV_STATES>(0);
    let mut m = *p;
    m.fixed_rows_mut::<NAV_STATES>(0).copy_from(&(phi_top * p));
    for i in NAV_STATES..N {
        let d = phi[(i, i)];
        m.row_mut(i).scale_mut(d);
    }
    let left = m * phi_top.transpose();
    let mut out = m;
    out.fixed_columns_mut::<NAV_STATES>(0).copy_from(&left);
    for j in NAV_STATES..N {
        let d = phi[(j, j)];
        out.column_mut(j).scale_mut(d);
    }
    0.5 * (out + out.transpose())
}

/// Whether the rows from [`NAV_STATES`] on hold nothing but their diagonal.
pub fn sensor_rows_diagonal<const N: usize>(m: &SMatrix<f64, N, N>) -> bool {
    (NAV_STATES..N).all(|i| (0..N).all(|j| i == j || m[(i, j)] == 0.0))
}

/// A linearised measurement: innovation z = h(estimate) − measurement, its Jacobian and noise.
#[derive(Debug, Clone)]
pub struct Measurement<const M: usize, const N: usize> {
    pub z: SVector<f64, M>,
    pub h: SMatrix<f64, M, N>,
    pub r: SMatrix<f64, M, M>,
}

/// GNSS antenna position: lever arm `lever_b` (m, body), measured lat/lon/height and NED σ
/// (of the white part); `receiver_error` is the estimate of the receiver's correlated
/// position error (NED, m; zero and without states when it is not modelled), which the
/// measurement model adds to the antenna position.
pub fn gnss_position<const N: usize>(
    nav: &NavState,
    lever_b: &Vector3<f64>,
    receiver_error: &Vector3<f64>,
    lat: f64,
    lon: f64,
    height: f64,
    sigma_ned: &Vector3<f64>,
) -> Measurement<3, N> {
    let lever_n = nav.quat_nb * lever_b;
    let z = nav.ned_offset_from(lat, lon, height) + lever_n + receiver_error;
    let mut h = SMatrix::<f64, 3, N>::zeros();
    h.fixed_view_mut::<3, 3>(0, POS)
        .copy_from(&Matrix3::identity());
    h.fixed_view_mut::<3, 3>(0, ATT).copy_from(&skew(&lever_n));
    if let Some(ge) = gnss_error_index(N) {
        h.fixed_view_mut::<3, 3>(0, ge)
            .copy_from(&Matrix3::identity());
    }
    Measurement {
        z,
        h,
        r: Matrix3::from_diagonal(&sigma_ned.component_mul(sigma_ned)),
    }
}

/// GNSS antenna velocity (NED) with the lever-arm rotation term; `gyro_b` bias-corrected.
pub fn gnss_velocity<const N: usize>(
    nav: &NavState,
    lever_b: &Vector3<f64>,
    gyro_b: &Vector3<f64>,
    vel_ned: &Vector3<f64>,
    sigma_ned: &Vector3<f64>,
) -> Measurement<3, N> {
    let c_bn = nav.quat_nb.to_rotation_matrix().into_inner();
    let w_in = earth::earth_rate_ned(nav.lat_rad)
        + earth::transport_rate_ned(nav.lat_rad, nav.height_m, &nav.vel_ned);
    let lever_n = c_bn * lever_b;
    let rot_b = c_bn * gyro_b.cross(lever_b);
    let v_ant = nav.vel_ned + rot_b - w_in.cross(&lever_n);
    let mut h = SMatrix::<f64, 3, N>::zeros();
    h.fixed_view_mut::<3, 3>(0, VEL)
        .copy_from(&Matrix3::identity());
    h.fixed_view_mut::<3, 3>(0, ATT)
        .copy_from(&(skew(&rot_b) - skew(&w_in) * skew(&lever_n)));
    h.fixed_view_mut::<3, 3>(0, BG)
        .copy_from(&(c_bn * skew(lever_b)));
    Measurement {
        z: v_ant - vel_ned,
        h,
        r: Matrix3::from_diagonal(&sigma_ned.component_mul(sigma_ned)),
    }
}

/// The velocity of the vehicle point in the vehicle frame, vᵛ = C_bᵛ (C_nᵇ vⁿ + ω×l), and its
/// Jacobian in the error state; `gyro_b` is the bias-corrected body rate, `vehicle` gives
/// C_bᵛ (mounting angles) and the lever arm l from the IMU to that point. The earth and
/// transport rates in ω_nb are left out of ω×l (10⁻⁴ rad/s: a tenth of a millimetre per
/// second for a metre of lever arm).
fn vehicle_velocity<const N: usize>(
    nav: &NavState,
    gyro_b: &Vector3<f64>,
    vehicle: &VehicleOptions,
) -> (Vector3<f64>, SMatrix<f64, 3, N>) {
    let c_nb = nav.quat_nb.inverse().to_rotation_matrix().into_inner();
    let c_bv = vehicle.imu_to_vehicle();
    let lever = Vector3::from(vehicle.lever_arm_m);
    let v_b = c_nb * nav.vel_ned + gyro_b.cross(&lever);
    let mut h = SMatrix::<f64, 3, N>::zeros();
    h.fixed_view_mut::<3, 3>(0, VEL).copy_from(&(c_bv * c_nb));
    h.fixed_view_mut::<3, 3>(0, ATT)
        .copy_from(&(-c_bv * c_nb * skew(&nav.vel_ned)));
    // ω̂ = ω − δb, so ω̂×l = ω×l + [l×] δb.
    h.fixed_view_mut::<3, 3>(0, BG)
        .copy_from(&(c_bv * skew(&lever)));
    (c_bv * v_b, h)
}

/// Non-holonomic constraint: the vehicle point's vertical velocity in the vehicle frame is
/// zero within `options.sigma_mps` and its lateral velocity is the side-slip's, within
/// `lateral_sigma_mps` (absent: `sigma_mps`). In a turn a car's body yaws further into the
/// turn than the velocity of its rear axle (the rear tyres slip to give the centripetal
/// force), by about `slip_deg_per_mps2` × the lateral
/// acceleration a = v·ω_z (from the filter's own speed and bias-corrected yaw rate), so the
/// lateral velocity there is −v·tan(slip·a) (right-handed FRD: a right turn slips left).
/// The gradient's own uncertainty, `slip_sigma_deg_per_mps2`, adds v·tan(σ_slip·|a|) to the
/// lateral σ in quadrature. `gyro_white_sigma` is the σ of the white noise in `gyro_b` per
/// body axis (rad/s, one IMU sample's: ARW/√dt): the yaw rate of the expected slip and the
/// lever arm's ω×l carry it into the measurement, and its covariance there is added to R.
pub fn non_holonomic<const N: usize>(
    nav: &NavState,
    gyro_b: &Vector3<f64>,
    gyro_white_sigma: &Vector3<f64>,
    vehicle: &VehicleOptions,
    options: &NhcOptions,
) -> Measurement<2, N> {
    let (v_v, h_v) = vehicle_velocity::<N>(nav, gyro_b, vehicle);
    let c_bv = vehicle.imu_to_vehicle();
    let yaw_rate = (c_bv * gyro_b).z;
    let lateral_accel = v_v.x * yaw_rate;
    let gradient = options.slip_deg_per_mps2.to_radians();
    let angle = |gradient_deg: f64| (gradient_deg.to_radians() * lateral_accel).clamp(-0.5, 0.5);
    let slip_angle = angle(options.slip_deg_per_mps2);
    let slip = -v_v.x * slip_angle.tan();
    let slip_sigma = v_v.x * angle(options.slip_sigma_deg_per_mps2).tan();
    let mut h = SMatrix::<f64, 2, N>::zeros();
    h.row_mut(0).copy_from(&h_v.row(1));
    h.row_mut(1).copy_from(&h_v.row(2));
    if slip_angle.abs() < 0.5 {
        // The expected slip moves with the forward speed and the yaw rate (ω̂ = ω − δb).
        let sec2 = 1.0 + slip_angle.tan().powi(2);
        let d_speed = -slip_angle.tan() - v_v.x * sec2 * gradient * yaw_rate;
        let d_yaw_rate = -v_v.x * sec2 * gradient * v_v.x;
        let mut row = h.row(0) - d_speed * h_v.row(0);
        for k in 0..3 {
            row[BG + k] += d_yaw_rate * c_bv[(2, k)];
        }
        h.row_mut(0).copy_from(&row);
    }
    let lateral = options.lateral_sigma_mps.unwrap_or(options.sigma_mps);
    // The measured rate's white noise enters where its bias error does (ω̂ = ω − δb).
    let d_gyro = h.fixed_view::<2, 3>(0, BG);
    let gyro_var = Matrix3::from_diagonal(&gyro_white_sigma.component_mul(gyro_white_sigma));
    let gyro_noise = d_gyro * gyro_var * d_gyro.transpose();
    Measurement {
        z: SVector::<f64, 2>::new(v_v.y - slip, v_v.z),
        h,
        r: SMatrix::<f64, 2, 2>::from_diagonal(&SVector::<f64, 2>::new(
            lateral * lateral + slip_sigma * slip_sigma,
            options.sigma_mps * options.sigma_mps,
        )) + gyro_noise,
    }
}

/// Odometer: the vehicle point's forward velocity in the vehicle frame is the wheel speed.
pub fn odometer<const N: usize>(
    nav: &NavState,
    gyro_b: &Vector3<f64>,
    vehicle: &VehicleOptions,
    speed_mps: f64,
    sigma: f64,
) -> Measurement<1, N> {
    let (v_v, h_v) = vehicle_velocity::<N>(nav, gyro_b, vehicle);
    Measurement {
        z: SVector::<f64, 1>::new(v_v.x - speed_mps),
        h: h_v.fixed_rows::<1>(0).into_owned(),
        r: SMatrix::<f64, 1, 1>::new(sigma * sigma),
    }
}

/// Zero-velocity update.
pub fn zero_velocity<const N: usize>(nav: &NavState, sigma: f64) -> Measurement<3, N> {
    let mut h = SMatrix::<f64, 3, N>::zeros();
    h.fixed_view_mut::<3, 3>(0, VEL)
        .copy_from(&Matrix3::identity());
    Measurement {
        z: nav.vel_ned,
        h,
        r: Matrix3::identity() * sigma * sigma,
    }
}

/// Zero angular rate update at a standstill: `mean_gyro_b` is the window-mean gyro output
/// with the estimated bias removed; still, the true rate is the earth rate in the body frame,
/// so the innovation is their difference and it observes the gyro bias error directly
/// (δb = b̂ − b; the scale-factor terms vanish at rest).
pub fn zero_angular_rate<const N: usize>(
    nav: &NavState,
    mean_gyro_b: &Vector3<f64>,
    sigma: f64,
) -> Measurement<3, N> {
    let earth_b = nav.quat_nb.inverse() * earth::earth_rate_ned(nav.lat_rad);
    let mut h = SMatrix::<f64, 3, N>::zeros();
    h.fixed_view_mut::<3, 3>(0, BG)
        .copy_from(&Matrix3::identity());
    Measurement {
        // ω̃ − b̂ = ω + b − b̂ = ω − δb, so h(estimate) − measurement = δb = earth_b − (ω̃ − b̂).
        z: earth_b - mean_gyro_b,
        h,
        r: Matrix3::identity() * sigma * sigma,
    }
}

/// Stacks two measurements into one (position and velocity of the same fix).
pub fn stack<const N: usize>(a: &Measurement<3, N>, b: &Measurement<3, N>) -> Measurement<6, N> {
    let mut z = SVector::<f64, 6>::zeros();
    let mut h = SMatrix::<f64, 6, N>::zeros();
    let mut r = SMatrix::<f64, 6, 6>::zeros();
    z.fixed_rows_mut::<3>(0).copy_from(&a.z);
    z.fixed_rows_mut::<3>(3).copy_from(&b.z);
    h.fixed_rows_mut::<3>(0).copy_from(&a.h);
    h.fixed_rows_mut::<3>(3).copy_from(&b.h);
    r.fixed_view_mut::<3, 3>(0, 0).copy_from(&a.r);
    r.fixed_view_mut::<3, 3>(3, 3).copy_from(&b.r);
    Measurement { z, h, r }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    fn nav() -> NavState {
        NavState {
            t_s: 0.0,
            lat_rad: 0.7,
            lon_rad: 0.1,
            height_m: 100.0,
            vel_ned: Vector3::new(10.0, -5.0, 0.3),
            quat_nb: UnitQuaternion::from_euler_angles(0.05, -0.02, 2.0),
        }
    }

    /// The position Jacobian against a numerical perturbation of the state.
    #[test]
    fn gnss_position_jacobian_matches_perturbation() {
        let n = nav();
        let lever = Vector3::new(1.0, -0.5, -1.5);
        let sigma = Vector3::repeat(1.0);
        let m0 = gnss_position::<15>(&n, &lever, &Vector3::zeros(), 0.7, 0.1, 100.0, &sigma);
        // Attitude error φ: est = (I − [φ×]) true  ⇒  perturbing the estimate by
        // q_est = exp(−φ) q changes z by H_att φ.
        let phi = Vector3::new(1e-4, -2e-4, 3e-4);
        let mut p = n;
        p.quat_nb = UnitQuaternion::from_scaled_axis(-phi) * n.quat_nb;
        let m1 = gnss_position::<15>(&p, &lever, &Vector3::zeros(), 0.7, 0.1, 100.0, &sigma);
        let predicted = m0.h.fixed_view::<3, 3>(0, ATT) * phi;
        assert!(
            (m1.z - m0.z - predicted).norm() < 1e-7,
            "{} vs {}",
            m1.z - m0.z,
            predicted
        );
        // Position: shifting the estimate by d changes z by d.
        let d = Vector3::new(0.3, -0.2, 0.1);
        let mut p = n;
        p.shift_position(&d);
        let m2 = gnss_position::<15>(&p, &lever, &Vector3::zeros(), 0.7, 0.1, 100.0, &sigma);
        assert!((m2.z - m0.z - d).norm() < 1e-6);
    }

    /// With the receiver's error as states (18), the fix predicts antenna position plus the
    /// estimated error: the Jacobian holds I on those states and matches a perturbation.
    #[test]
    fn gnss_position_with_receiver_error_states() {
        let n = nav();
        let lever = Vector3::new(1.0, -0.5, -1.5);
        let sigma = Vector3::repeat(0.7);
        let e0 = Vector3::new(1.0, -2.0, 0.5);
        let m0 = gnss_position::<18>(&n, &lever, &e0, 0.7, 0.1, 100.0, &sigma);
        let de = Vector3::new(0.2, 0.1, -0.3);
        let m1 = gnss_position::<18>(&n, &lever, &(e0 + de), 0.7, 0.1, 100.0, &sigma);
        let mut dx = SVector::<f64, 18>::zeros();
        dx.fixed_rows_mut::<3>(15).copy_from(&de);
        assert!((m1.z - m0.z - m0.h * dx).norm() < 1e-12);
        assert_eq!(gnss_error_index(18), Some(15));
        assert_eq!(gnss_error_index(24), Some(21));
        assert_eq!(gnss_error_index(21), None);
        assert_eq!(gnss_error_index(30), Some(27));
        // Every combination of the optional groups: the count and the index agree.
        for states in [15, 21] {
            for turn_on_states in [false, true] {
                for gnss in [false, true] {
                    let mut c = FusionConfig {
                        states,
                        turn_on_states,
                        ..FusionConfig::default()
                    };
                    if gnss {
                        c.gnss.position_error.horizontal_m = 2.0;
                        c.gnss.position_error.vertical_m = 3.0;
                        c.gnss.position_error.tau_s = 600.0;
                    }
                    let l = Layout::of(&c);
                    assert_eq!(gnss_error_index(l.states), l.gnss_error, "{l:?}");
                    assert_eq!(l.scale_factors, states == 21);
                    assert_eq!(l.turn_on.is_some(), turn_on_states);
                }
            }
        }
        // Without the states the estimate is not added (15 states have nowhere to put it).
        let m15 = gnss_position::<15>(&n, &lever, &Vector3::zeros(), 0.7, 0.1, 100.0, &sigma);
        assert!((m15.z + e0 - m0.z).norm() < 1e-9);
        // The error states decay with τ and are driven by 2σ²/τ.
        let mut config = FusionConfig {
            states: 15,
            ..FusionConfig::default()
        };
        config.gnss.position_error = crate::config::GnssPositionError {
            horizontal_m: 2.0,
            vertical_m: 3.5,
            tau_s: 600.0,
        };
        assert_eq!(config.filter_states(), 18);
        let f = dynamics_matrix::<18>(
            &n,
            &Vector3::zeros(),
            &Vector3::new(0.0, 0.0, -9.8),
            &config,
        );
        assert!((f[(15, 15)] + 1.0 / 600.0).abs() < 1e-15 && sensor_rows_diagonal(&f));
        let q = process_noise_psd::<18>(&config);
        assert!((q[17] - 2.0 * 3.5 * 3.5 / 600.0).abs() < 1e-15);
    }

    #[test]
    fn nhc_jacobian_matches_perturbation() {
        let n = nav();
        let gyro = Vector3::new(0.02, -0.01, 0.3);
        let m0 = non_holonomic::<21>(
            &n,
            &gyro,
            &Vector3::zeros(),
            &VehicleOptions::default(),
            &NhcOptions::default(),
        );
        // In a 0.3 rad/s turn the expected side-slip is part of the lateral row and moves
        // with the speed and the yaw rate's bias.
        assert!(m0.r[(0, 0)] > m0.r[(1, 1)]);
        let tight = NhcOptions {
            lateral_sigma_mps: Some(0.01),
            slip_sigma_deg_per_mps2: 0.0,
            ..NhcOptions::default()
        };
        let m = non_holonomic::<21>(
            &n,
            &gyro,
            &Vector3::zeros(),
            &VehicleOptions::default(),
            &tight,
        );
        assert!((m.r[(0, 0)] - 1e-4).abs() < 1e-15 && (m.r[(1, 1)] - 0.01).abs() < 1e-15);
        // The yaw rate's white noise adds (∂z/∂ω_z)² σ² to the lateral variance, with the
        // derivative taken here from the measurement itself by central differences.
        let sigma = Vector3::new(0.0, 0.0, 2e-3);
        let noisy = non_holonomic::<21>(&n, &gyro, &sigma, &VehicleOptions::default(), &tight);
        let eps = Vector3::new(0.0, 0.0, 1e-6);
        let lateral = |w: &Vector3<f64>| {
            non_holonomic::<21>(&n, w, &Vector3::zeros(), &VehicleOptions::default(), &tight).z[0]
        };
        let slope = (lateral(&(gyro + eps)) - lateral(&(gyro - eps))) / 2e-6;
        let added = noisy.r[(0, 0)] - m.r[(0, 0)];
        assert!(
            slope.abs() > 0.1,
            "the turn's slip moves with the yaw rate: {slope}"
        );
        assert!(
            (added - (slope * sigma.z).powi(2)).abs() < 1e-6 * added,
            "{added} vs {}",
            (slope * sigma.z).powi(2)
        );
        assert_eq!(noisy.r[(1, 1)], m.r[(1, 1)]);
        let phi = Vector3::new(-2e-4, 1e-4, 2e-4);
        let dv = Vector3::new(0.01, -0.02, 0.005);
        let db = Vector3::new(1e-4, -2e-4, 3e-4);
        let mut p = n;
        p.quat_nb = UnitQuaternion::from_scaled_axis(-phi) * n.quat_nb;
        p.vel_ned += dv;
        let m1 = non_holonomic::<21>(
            &p,
            &(gyro - db),
            &Vector3::zeros(),
            &VehicleOptions::default(),
            &NhcOptions::default(),
        );
        let mut dx = SVector::<f64, 21>::zeros();
        dx.fixed_rows_mut::<3>(ATT).copy_from(&phi);
        dx.fixed_rows_mut::<3>(VEL).copy_from(&dv);
        dx.fixed_rows_mut::<3>(BG).copy_from(&db);
        // First-order terms are up to 2·10⁻² m/s; the rest is second order.
        assert!(
            (m1.z - m0.z - m0.h * dx).norm() < 1e-5,
            "{}",
            m1.z - m0.z - m0.h * dx
        );
    }

    /// With mounting angles and a lever arm: the vehicle-frame velocity is what the
    /// rotation gives, and the Jacobian matches perturbations of velocity, attitude and
    /// gyro bias.
    #[test]
    fn vehicle_velocity_with_mounting_and_lever_arm() {
        let n = nav();
        let gyro = Vector3::new(0.02, -0.01, 0.3);
        let vehicle = VehicleOptions {
            mounting_deg: [2.0, -3.0, 90.0],
            lever_arm_m: [-1.2, 0.4, 0.8],
        };
        // Yaw 90: the IMU's x is the vehicle's right, so the forward speed is −v_b.y (about).
        let c_nb = n.quat_nb.inverse().to_rotation_matrix().into_inner();
        let v_b = c_nb * n.vel_ned + gyro.cross(&Vector3::from(vehicle.lever_arm_m));
        let m = odometer::<15>(&n, &gyro, &vehicle, 0.0, 0.05);
        assert!(
            (m.z[0] - (-v_b.y)).abs() < 0.1 * v_b.norm(),
            "{} vs {}",
            m.z[0],
            -v_b.y
        );
        let (v0, h) = vehicle_velocity::<15>(&n, &gyro, &vehicle);
        let mut dx = SVector::<f64, 15>::zeros();
        let phi = Vector3::new(1e-4, -2e-4, 1.5e-4);
        let dv = Vector3::new(0.01, -0.02, 0.005);
        let db = Vector3::new(1e-4, 2e-4, -1e-4);
        dx.fixed_rows_mut::<3>(ATT).copy_from(&phi);
        dx.fixed_rows_mut::<3>(VEL).copy_from(&dv);
        dx.fixed_rows_mut::<3>(BG).copy_from(&db);
        let mut p = n;
        p.quat_nb = UnitQuaternion::from_scaled_axis(-phi) * n.quat_nb;
        p.vel_ned += dv;
        let (v1, _) = vehicle_velocity::<15>(&p, &(gyro - db), &vehicle);
        // First-order terms are 3·10⁻⁴ (gyro bias) to 2·10⁻² m/s; the rest is second order.
        assert!((v1 - v0 - h * dx).norm() < 1e-5, "{}", v1 - v0 - h * dx);
    }

    /// The structured transition, noise and Φ P Φᵀ agree with the dense forms, for 15 and
    /// 21 states, and F keeps the structure they rely on.
    fn sparse_matches_dense<const N: usize>() {
        let config = FusionConfig {
            states: N,
            ..FusionConfig::default()
        };
        let f = dynamics_matrix::<N>(
            &nav(),
            &Vector3::new(0.1, -0.05, 0.2),
            &Vector3::new(0.8, 0.5, -9.8),
            &config,
        );
        assert!(sensor_rows_diagonal(&f));
        let q = process_noise_psd::<N>(&config);
        let (phi, qd) = discretise(&f, &q, 0.1);
        let (phi_s, qd_s) = discretise_sparse(&f, &q, 0.1);
        let close = |a: &SMatrix<f64, N, N>, b: &SMatrix<f64, N, N>| {
            (a - b)
                .iter()
                .all(|d| d.abs() <= 1e-13 * a.amax().max(1e-300))
        };
        assert!(close(&phi, &phi_s), "Φ differs");
        assert!(close(&qd, &qd_s), "Q differs");
        // A full, positive-definite P with every correlation non-zero.
        let a = SMatrix::<f64, N, N>::from_fn(|i, j| {
            ((i * 7 + j * 3) % 11) as f64 - 5.0 + 0.1 * j as f64
        });
        let p = a * a.transpose() + SMatrix::<f64, N, N>::identity();
        let dense = phi * p * phi.transpose();
        let sparse = propagate_covariance_sparse(&phi, &p);
        assert!(close(&dense, &sparse), "Φ P Φᵀ differs");
        // It does depend on the blocks it claims to use: a wrong sensor diagonal shows.
        let mut wrong = phi;
        wrong[(N - 1, N - 1)] *= 1.5;
        assert!(!close(&dense, &propagate_covariance_sparse(&wrong, &p)));
    }

    #[test]
    fn sparse_propagation_matches_dense_for_15_and_21_states() {
        sparse_matches_dense::<15>();
        sparse_matches_dense::<21>();
    }

    #[test]
    fn transition_is_identity_for_zero_interval_and_noise_is_symmetric() {
        let config = FusionConfig {
            states: 21,
            ..FusionConfig::default()
        };
        let f = dynamics_matrix::<21>(
            &nav(),
            &Vector3::new(0.1, 0.0, 0.2),
            &Vector3::new(0.0, 0.5, -9.8),
            &config,
        );
        let q = process_noise_psd::<21>(&config);
        let (phi, qd) = discretise(&f, &q, 0.0);
        assert_eq!(phi, SMatrix::<f64, 21, 21>::identity());
        assert!(qd.norm() == 0.0);
        let (_, qd) = discretise(&f, &q, 0.1);
        assert!((qd - qd.transpose()).norm() == 0.0 && qd[(3, 3)] > 0.0);
    }
}
