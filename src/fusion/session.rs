//! Replay of a recorded or simulated session (`imulab::store`): streams one IMU's rows
//! block by block through the navigator with one GNSS receiver's fixes, and reads the truth
//! trajectory of simulated sessions for the error statistics. Times are seconds since the
//! first IMU row (host monotonic clock). A thermal model, when given, removes its change of
//! bias with temperature, bias(T) − bias(reference), from the IMU rows (by their `temp`)
//! before the filter sees them.

use crate::config::FusionConfig;
use crate::mechanisation::{ImuInput, NavState};
use crate::navigator::{GnssObservation, Navigator, ReplayOptions, ReplayResult};
use anyhow::{bail, Context};
use imulab_drivers::types::FixType;
use imulab_store::{DeviceKind, GnssRecord, Session, StoreError, TimeRange};
use imulab_thermal::model::{require_session_temperature, ImuCompensator, ThermalModel};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// Rows per block read from the store.
const BLOCK_ROWS: usize = 65_536;

/// The blocks of a stream that read; each one that does not is noted in `problems` (its
/// error names the chunk file) and skipped, so one bad file does not stop a replay.
fn readable<'a, B: 'a>(
    blocks: impl Iterator<Item = Result<B, StoreError>> + 'a,
    problems: &'a mut Vec<String>,
) -> impl Iterator<Item = B> + 'a {
    blocks.filter_map(move |b| b.map_err(|e| problems.push(e.to_string())).ok())
}

/// What a session replay produced besides the trajectory.
#[derive(Debug, Clone, Default)]
pub struct SessionReplay {
    pub result: ReplayResult,
    pub imu_device: String,
    pub gnss_device: String,
    /// Host monotonic time of the first IMU row, ns (time zero of the trajectory).
    pub t0_mono_ns: i64,
    /// True trajectory (simulated sessions), on the same time axis.
    pub truth: Vec<NavState>,
    /// GNSS epochs without a position fix (no fix, time only), skipped.
    pub gnss_without_fix: u64,
    /// GPS week and the offset sow − t of the first fix with a known week, for navresult.
    pub gps_time: Option<(u32, f64)>,
    /// Unreadable files and blocks, one line each.
    pub problems: Vec<String>,
    /// Thermal compensation warnings (samples outside the model's range), one line each.
    pub compensation_warnings: Vec<String>,
}

/// The device of `kind` named `wanted`, or the only one of that kind.
pub fn pick(session: &Session, kind: DeviceKind, wanted: Option<&str>) -> anyhow::Result<String> {
    let of_kind: Vec<&str> = session
        .devices()
        .iter()
        .filter(|d| d.kind == kind)
        .map(|d| d.name.as_str())
        .collect();
    match wanted {
        Some(w) if of_kind.contains(&w) => Ok(w.to_string()),
        Some(w) => bail!(
            "{}: no {} device `{w}` (have: {})",
            session.dir().display(),
            kind.as_str(),
            of_kind.join(", ")
        ),
        None => match of_kind.as_slice() {
            [one] => Ok(one.to_string()),
            [] => bail!("{}: no {} device", session.dir().display(), kind.as_str()),
            many => bail!(
                "{}: several {} devices ({}); choose one with --{}",
                session.dir().display(),
                kind.as_str(),
                many.join(", "),
                kind.as_str()
            ),
        },
    }
}

fn seconds(t_ns: i64, t0_ns: i64) -> f64 {
    (t_ns.saturating_sub(t0_ns)) as f64 * 1e-9
}

/// Longest receiver latency believed when recovering a fix's epoch time, ns.
const MAX_LATENCY_NS: i64 = 2_000_000_000;

/// A GNSS row as the filter uses it, on the time axis starting at `t0_ns` (host monotonic);
/// None for epochs without a position fix.
///
/// Time: the row's host arrival time minus the receiver latency, where the latency is the
/// row's wall-clock arrival minus the fix's own UTC time (`t_wall_ns − utc_ns`) when that is
/// between 0 and 2 s; otherwise the arrival time. A 50 ms latency at 20 m/s would otherwise
/// put every fix a metre behind the vehicle.
/// Accuracy: `h_acc_m` is read as a horizontal (2-D) 1σ, so each of north and east gets
/// `h_acc_m / √2`; down gets `v_acc_m`.
pub fn observation(r: &GnssRecord, t0_ns: i64) -> Option<GnssObservation> {
    if matches!(r.fix_type, FixType::NoFix | FixType::TimeOnly) {
        return None;
    }
    let latency = r.t_wall_ns.saturating_sub(r.utc_ns);
    let t_ns = if r.utc_ns > 0 && (0..=MAX_LATENCY_NS).contains(&latency) {
        r.t_mono_ns - latency
    } else {
        r.t_mono_ns
    };
    let v = Vector3::from(r.vel_ned);
    let h = r.h_acc_m / std::f64::consts::SQRT_2;
    Some(GnssObservation {
        t_s: seconds(t_ns, t0_ns),
        lat_rad: r.lat_deg.to_radians(),
        lon_rad: r.lon_deg.to_radians(),
        height_m: r.height_m,
        sigma_ned_m: Vector3::new(h, h, r.v_acc_m),
        vel_ned: v.iter().all(|x| x.is_finite()).then_some(v),
        sigma_vel_mps: Vector3::repeat(r.s_acc_mps),
    })
}

/// The most frequent position-fix class among the rows of GNSS device `gnss` (the only one
/// when None); None when no row has a position fix.
pub fn dominant_fix_type(session: &Session, gnss: Option<&str>) -> anyhow::Result<Option<FixType>> {
    let device = pick(session, DeviceKind::Gnss, gnss)?;
    let mut counts = [0u64; 9];
    let mut problems = Vec::new();
    let blocks = session.gnss_blocks(&device, TimeRange::all(), BLOCK_ROWS)?;
    for block in readable(blocks, &mut problems) {
        for i in 0..block.len() {
            let fix = block.record(i).fix_type;
            if !matches!(fix, FixType::NoFix | FixType::TimeOnly) {
                counts[fix as usize] += 1;
            }
        }
    }
    const CLASSES: [FixType; 9] = [
        FixType::NoFix,
        FixType::DeadReckoning,
        FixType::Fix2D,
        FixType::Fix3D,
        FixType::GnssDeadReckoning,
        FixType::TimeOnly,
        FixType::Dgnss,
        FixType::RtkFloat,
        FixType::RtkFixed,
    ];
    Ok(CLASSES
        .into_iter()
        .filter(|f| counts[*f as usize] > 0)
        .max_by_key(|f| counts[*f as usize]))
}

/// Replays `session` with IMU `imu` and receiver `gnss` (each may be omitted when the session
/// has only one). Outage windows in `options` are in seconds since the first IMU row;
/// `thermal`, when given, compensates the IMU rows (see [`ImuCompensator`]).
pub fn replay_session(
    session: &Session,
    imu: Option<&str>,
    gnss: Option<&str>,
    config: &FusionConfig,
    options: ReplayOptions,
    thermal: Option<&ThermalModel>,
) -> anyhow::Result<SessionReplay> {
    let mut out = SessionReplay {
        imu_device: pick(session, DeviceKind::Imu, imu)?,
        gnss_device: pick(session, DeviceKind::Gnss, gnss)?,
        ..SessionReplay::default()
    };
    let mut compensator = match thermal {
        Some(model) => {
            let c = ImuCompensator::new(model, &out.imu_device)?;
            require_session_temperature(session, &out.imu_device)?;
            Some(c)
        }
        None => None,
    };
    let t0 = session
        .stream_summary(&imulab_store::layout::imu_path(&out.imu_device))
        .first_t_mono_ns
        .with_context(|| {
            format!(
                "{}: IMU `{}` has no rows",
                session.dir().display(),
                out.imu_device
            )
        })?;
    out.t0_mono_ns = t0;

    let mut fixes = Vec::new();
    let blocks = session.gnss_blocks(&out.gnss_device, TimeRange::all(), BLOCK_ROWS)?;
    for block in readable(blocks, &mut out.problems) {
        for i in 0..block.len() {
            let r = block.record(i);
            match observation(&r, t0) {
                Some(obs) => {
                    if out.gps_time.is_none() && r.week > 0 && r.tow_s.is_finite() {
                        out.gps_time = Some((u32::from(r.week), r.tow_s - obs.t_s));
                    }
                    fixes.push(obs);
                }
                None => out.gnss_without_fix += 1,
            }
        }
    }

    if session.manifest().truth_nav_rate_hz.is_some() {
        let blocks = session.truth_nav_blocks(TimeRange::all(), BLOCK_ROWS)?;
        for block in readable(blocks, &mut out.problems) {
            for i in 0..block.len() {
                let q = block.quat_nb[i];
                out.truth.push(NavState {
                    t_s: seconds(block.t_mono_ns[i], t0),
                    lat_rad: block.lat_deg[i].to_radians(),
                    lon_rad: block.lon_deg[i].to_radians(),
                    height_m: block.height_m[i],
                    vel_ned: Vector3::from(block.vel_ned[i]),
                    quat_nb: UnitQuaternion::from_quaternion(Quaternion::new(
                        q[0], q[1], q[2], q[3],
                    )),
                });
            }
        }
    }

    macro_rules! stream_with {
        ($n:literal) => {
            stream::<$n>(
                ImuStream {
                    session,
                    device: &out.imu_device,
                    t0,
                    thermal: compensator.as_mut(),
                },
                config,
                options,
                &fixes,
                &mut out.problems,
            )?
        };
    }
    out.result = match config.filter_states() {
        30 => stream_with!(30),
        27 => stream_with!(27),
        24 => stream_with!(24),
        21 => stream_with!(21),
        18 => stream_with!(18),
        _ => stream_with!(15),
    };
    out.compensation_warnings = compensator.map(|c| c.warnings()).unwrap_or_default();
    Ok(out)
}

/// The IMU rows a replay streams: the session's device, its time zero and the thermal
/// compensation applied to each block.
struct ImuStream<'a> {
    session: &'a Session,
    device: &'a str,
    t0: i64,
    thermal: Option<&'a mut ImuCompensator>,
}

fn stream<const N: usize>(
    imu: ImuStream<'_>,
    config: &FusionConfig,
    options: ReplayOptions,
    fixes: &[GnssObservation],
    problems: &mut Vec<String>,
) -> anyhow::Result<ReplayResult> {
    let ImuStream {
        session,
        device: imu,
        t0,
        mut thermal,
    } = imu;
    let calibration = options.calibration.clone();
    let mut nav = Navigator::<N>::new(config, options);
    let mut next_fix = fixes.iter().peekable();
    for block in readable(
        session.imu_blocks(imu, TimeRange::all(), BLOCK_ROWS)?,
        problems,
    ) {
        let mut block = block;
        if let Some(c) = &calibration {
            c.apply(&mut block.gyro, &mut block.accel);
        }
        if let Some(c) = thermal.as_deref_mut() {
            c.compensate_block(&mut block.gyro, &mut block.accel, &block.temp);
        }
        for i in 0..block.len() {
            let t = seconds(block.t_mono_ns[i], t0);
            while let Some(f) = next_fix.next_if(|f| f.t_s < t) {
                nav.push_gnss(f);
            }
            nav.push_imu(&ImuInput::Rates {
                t_s: t,
                gyro: Vector3::from(block.gyro[i]),
                accel: Vector3::from(block.accel[i]),
            });
        }
    }
    for f in next_fix {
        nav.push_gnss(f);
    }
    Ok(nav.finish())
}

/// The truth at time `t`, interpolated between the two nearest rows (at most 1 s apart).
pub fn truth_at(truth: &[NavState], t: f64) -> Option<NavState> {
    let i = truth.partition_point(|r| r.t_s < t);
    let b = truth.get(i)?;
    if (b.t_s - t).abs() < 1e-6 {
        return Some(*b);
    }
    let a = truth.get(i.checked_sub(1)?)?;
    let span = b.t_s - a.t_s;
    if !(span > 0.0 && span <= 1.0) {
        return None;
    }
    let w = (t - a.t_s) / span;
    Some(NavState {
        t_s: t,
        lat_rad: a.lat_rad + w * (b.lat_rad - a.lat_rad),
        lon_rad: a.lon_rad + w * crate::mechanisation::wrap_pi(b.lon_rad - a.lon_rad),
        height_m: a.height_m + w * (b.height_m - a.height_m),
        vel_ned: a.vel_ned + w * (b.vel_ned - a.vel_ned),
        quat_nb: a.quat_nb.slerp(&b.quat_nb, w),
    })
}
