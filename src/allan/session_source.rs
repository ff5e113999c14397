//! Session input: a [`SampleSource`] over one IMU device of an `imulab` session, streamed
//! block by block through `imulab::store::Session::imu_columns`. Channels are `t` (seconds
//! from the first sample in range), `gyro_x…z` (rad/s), `accel_x…z` (m/s²), `temp` (°C) and
//! `t_sensor` (the device's own clock, as stored).

use super::input::{BlockVisitor, InputError, RowVisitor, SampleSource, SensorClock, Timing};
use super::units::RateUnit;
use imulab_store::manifest::DeviceKind;
use imulab_store::Manifest;
use imulab_store::{ImuColumnSet, ImuColumns, Session, TimeRange};
use std::path::{Path, PathBuf};

const CHANNELS: [&str; 9] = [
    "t", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z", "temp", "t_sensor",
];
const TEMP: usize = 7;
const T_SENSOR: usize = 8;
use super::input::BLOCK_ROWS;

pub struct SessionSource {
    dir: PathBuf,
    session: Session,
    device: String,
    range: TimeRange,
    /// Time 0 of channel `t`: the start of the range, or the device's first `t_mono_ns`.
    first_ns: i64,
    /// The device's own clock in `t_sensor`, when its protocol defines one and it was logged.
    sensor_clock: Option<SensorClock>,
    channels: Vec<String>,
}

/// Xsens SampleTimeFine: a u32 of 1/10 000 s, stored as seconds (docs/protocols-imu-can.md).
const XBUS_WRAP_S: f64 = 4_294_967_296.0 / 10_000.0;
/// The simulator's default counter modulus (docs/simulator.md, `[imu.timing]`).
const SIM_COUNTER_MODULO: i64 = 65_536;

/// What `t_sensor` holds for `device`, by protocol (docs/session-format.md): the simulator's
/// sample counter (wrapping at the scene's `counter_modulo`), Xsens' SampleTimeFine in
/// seconds, an imported ROS topic's header stamps in seconds. Other protocols' sensor times (WitMotion's time of day at 1 ms resolution, CSV
/// and CAN fields of user-defined meaning) are not used: `None`, the arrival times decide.
fn sensor_clock(manifest: &Manifest, device: &str) -> Option<SensorClock> {
    let info = manifest.device(device)?;
    match info.protocol.as_str() {
        "sim" => {
            // The scene is the session's config: [[imu]] name = device, [imu.timing].
            let modulo = manifest
                .config
                .get("imu")
                .and_then(|v| v.as_array())
                .and_then(|imus| {
                    imus.iter()
                        .find(|t| t.get("name").and_then(|n| n.as_str()) == Some(device))
                })
                .and_then(|t| t.get("timing"))
                .and_then(|t| t.get("counter_modulo"))
                .and_then(|m| m.as_integer())
                .unwrap_or(SIM_COUNTER_MODULO);
            Some(SensorClock {
                unit_s: None,
                wrap: (modulo > 0).then_some(modulo as f64),
                name: "sensor sample counter (t_sensor)".into(),
            })
        }
        // Imported ROS messages: the header stamp in seconds (docs/import.md).
        "ros" => Some(SensorClock {
            unit_s: Some(1.0),
            wrap: Some(f64::INFINITY),
            name: "header stamps (t_sensor)".into(),
        }),
        "xbus" => Some(SensorClock {
            unit_s: Some(1.0),
            wrap: Some(XBUS_WRAP_S),
            name: "sensor clock (t_sensor, Xsens SampleTimeFine)".into(),
        }),
        _ => None,
    }
}

impl SessionSource {
    /// Opens `device` (or the session's only IMU when `None`) limited to seconds
    /// `[from, to)` after the device's first sample.
    pub fn open(
        dir: &Path,
        device: Option<&str>,
        from_s: Option<f64>,
        to_s: Option<f64>,
    ) -> Result<Self, InputError> {
        let fail = |message: String| InputError::Format {
            path: dir.to_path_buf(),
            message,
        };
        let session = Session::open(dir).map_err(|e| fail(e.to_string()))?;
        let imus: Vec<String> = session
            .devices()
            .iter()
            .filter(|d| d.kind == DeviceKind::Imu)
            .map(|d| d.name.clone())
            .collect();
        let device = match device {
            Some(d) => d.to_string(),
            None if imus.len() == 1 => imus[0].clone(),
            None => {
                return Err(fail(format!(
                    "choose an IMU with --device (this session has: {})",
                    if imus.is_empty() {
                        "none".to_string()
                    } else {
                        imus.join(", ")
                    }
                )))
            }
        };
        let (first, first_sensor) = session
            .imu_blocks(&device, TimeRange::all(), 1)
            .map_err(|e| fail(e.to_string()))?
            .find_map(|b| {
                b.ok()
                    .and_then(|b| Some((*b.t_mono_ns.first()?, *b.t_sensor.first()?)))
            })
            .ok_or_else(|| fail(format!("device `{device}` has no readable IMU rows")))?;
        let sensor_clock = first_sensor
            .is_finite()
            .then(|| sensor_clock(session.manifest(), &device))
            .flatten();
        let to_ns = |s: f64| -> Result<i64, InputError> {
            if !(s.is_finite() && s >= 0.0) {
                return Err(fail(format!(
                    "time range bound {s} s must be a non-negative number"
                )));
            }
            Ok(first.saturating_add((s * 1e9) as i64))
        };
        // No lower bound unless asked: every row is at or after the first one anyway.
        let range = TimeRange::new(from_s.map(to_ns).transpose()?, to_s.map(to_ns).transpose()?);
        let first = range.start_ns.unwrap_or(first);
        Ok(SessionSource {
            dir: dir.to_path_buf(),
            session,
            device,
            range,
            first_ns: first,
            sensor_clock,
            channels: CHANNELS.iter().map(|c| c.to_string()).collect(),
        })
    }

    pub fn device(&self) -> &str {
        &self.device
    }
}

impl SampleSource for SessionSource {
    fn describe(&self) -> String {
        format!("{} [{}]", self.dir.display(), self.device)
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn as_any_session(&self) -> Option<&str> {
        Some(&self.device)
    }

    fn row_count_hint(&self) -> Option<u64> {
        // All rows of the device (the time range can only make it fewer).
        let summary = self
            .session
            .stream_summary(&imulab_store::layout::imu_path(&self.device));
        Some(summary.rows)
    }

    /// The sensor's own clock where the protocol defines one (gaps of a single sample are
    /// found), otherwise the host arrival times.
    fn native_timing(&self) -> Option<Timing> {
        Some(match &self.sensor_clock {
            Some(clock) => Timing::SensorTime {
                channel: T_SENSOR,
                clock: clock.clone(),
                arrival: 0,
                arrival_scale: 1.0,
            },
            None => Timing::ArrivalTimes {
                channel: 0,
                scale: 1.0,
            },
        })
    }

    fn channel_unit(&self, channel: usize) -> Option<RateUnit> {
        match channel {
            1..=3 => Some(RateUnit::RadPerSecond),
            4..=6 => Some(RateUnit::MetrePerSecondSquared),
            _ => None,
        }
    }

    /// Only the datasets of the wanted channels are read (`Session::imu_columns`), into
    /// buffers reused from block to block; each channel is handed on as the reader's own
    /// per-axis vector, with no copy (the time column is converted to seconds).
    fn for_each_block(
        &self,
        wanted: &[usize],
        visit: &mut BlockVisitor<'_>,
    ) -> Result<(), InputError> {
        let fail = |message: String| InputError::Format {
            path: self.dir.clone(),
            message,
        };
        if let Some(&c) = wanted.iter().find(|&&c| c >= CHANNELS.len()) {
            return Err(fail(format!("no channel index {c}")));
        }
        let set = ImuColumnSet {
            t_sensor: wanted.contains(&T_SENSOR),
            gyro: wanted.iter().any(|c| (1..=3).contains(c)),
            accel: wanted.iter().any(|c| (4..=6).contains(c)),
            temp: wanted.contains(&TEMP),
        };
        let mut reader = self
            .session
            .imu_columns(&self.device, self.range, BLOCK_ROWS, set)
            .map_err(|e| fail(e.to_string()))?;
        let mut block = ImuColumns::default();
        let mut seconds: Vec<f64> = Vec::with_capacity(BLOCK_ROWS);
        let mut row = 0u64;
        while let Some(result) = reader.next_into(&mut block) {
            result.map_err(|e| fail(format!("device `{}`: {e}", self.device)))?;
            if wanted.contains(&0) {
                let first = self.first_ns;
                seconds.clear();
                seconds.extend(block.t_mono_ns.iter().map(|&t| (t - first) as f64 * 1e-9));
            }
            let slices: Vec<&[f64]> = wanted
                .iter()
                .map(|&c| match c {
                    0 => seconds.as_slice(),
                    1..=3 => block.gyro[c - 1].as_slice(),
                    4..=6 => block.accel[c - 4].as_slice(),
                    TEMP => block.temp.as_slice(),
                    _ => block.t_sensor.as_slice(),
                })
                .collect();
            visit(row, &slices)?;
            row += block.len() as u64;
        }
        Ok(())
    }

    /// The rows of [`Self::for_each_block`]'s blocks, one at a time.
    fn for_each_row(&self, wanted: &[usize], visit: &mut RowVisitor<'_>) -> Result<(), InputError> {
        let mut values = vec![0.0; wanted.len()];
        self.for_each_block(wanted, &mut |first_row, columns| {
            let rows = columns.first().map_or(0, |c| c.len());
            for i in 0..rows {
                for (slot, column) in values.iter_mut().zip(columns) {
                    *slot = column[i];
                }
                visit(first_row + i as u64, &values)?;
            }
            Ok(())
        })
    }
}
