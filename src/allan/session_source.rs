//! Session input: a [`SampleSource`] over one IMU device of an `imulab` session, streamed
//! block by block through `imulab::store::Session::imu_blocks`. Channels are `t` (seconds
//! from the first sample in range), `gyro_x…z` (rad/s), `accel_x…z` (m/s²) and `temp` (°C).

use super::input::{BlockVisitor, InputError, RowVisitor, SampleSource};
use super::units::RateUnit;
use crate::store::manifest::DeviceKind;
use crate::store::{Session, TimeRange};
use std::path::{Path, PathBuf};

const CHANNELS: [&str; 8] = [
    "t", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z", "temp",
];
use super::input::BLOCK_ROWS;

pub struct SessionSource {
    dir: PathBuf,
    session: Session,
    device: String,
    range: TimeRange,
    channels: Vec<String>,
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
        let first = session
            .imu_blocks(&device, TimeRange::all(), 1)
            .map_err(|e| fail(e.to_string()))?
            .find_map(|b| b.ok().and_then(|b| b.t_mono_ns.first().copied()))
            .ok_or_else(|| fail(format!("device `{device}` has no readable IMU rows")))?;
        let to_ns = |s: f64| -> Result<i64, InputError> {
            if !(s.is_finite() && s >= 0.0) {
                return Err(fail(format!(
                    "time range bound {s} s must be a non-negative number"
                )));
            }
            Ok(first.saturating_add((s * 1e9) as i64))
        };
        let range = TimeRange::new(
            Some(from_s.map(to_ns).transpose()?.unwrap_or(first)),
            to_s.map(to_ns).transpose()?,
        );
        Ok(SessionSource {
            dir: dir.to_path_buf(),
            session,
            device,
            range,
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
            .stream_summary(&crate::store::layout::imu_path(&self.device));
        Some(summary.rows)
    }

    fn channel_unit(&self, channel: usize) -> Option<RateUnit> {
        match channel {
            1..=3 => Some(RateUnit::RadPerSecond),
            4..=6 => Some(RateUnit::MetrePerSecondSquared),
            _ => None,
        }
    }

    /// Each stored block becomes one column slice per wanted channel (no per-row callback).
    fn for_each_block(
        &self,
        wanted: &[usize],
        visit: &mut BlockVisitor<'_>,
    ) -> Result<(), InputError> {
        let fail = |message: String| InputError::Format {
            path: self.dir.clone(),
            message,
        };
        let start = self.range.start_ns.unwrap_or(0);
        let blocks = self
            .session
            .imu_blocks(&self.device, self.range, BLOCK_ROWS)
            .map_err(|e| fail(e.to_string()))?;
        let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(BLOCK_ROWS); wanted.len()];
        let mut row = 0u64;
        for block in blocks {
            let block = block.map_err(|e| fail(format!("device `{}`: {e}", self.device)))?;
            for (column, &c) in columns.iter_mut().zip(wanted) {
                column.clear();
                match c {
                    0 => column.extend(block.t_mono_ns.iter().map(|&t| (t - start) as f64 * 1e-9)),
                    1..=3 => column.extend(block.gyro.iter().map(|g| g[c - 1])),
                    4..=6 => column.extend(block.accel.iter().map(|a| a[c - 4])),
                    _ => column.extend_from_slice(&block.temp),
                }
            }
            let slices: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
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
