//! Bag input: a [`SampleSource`] over one `sensor_msgs/Imu` topic of a ROS bag or MCAP file
//! ([`imulab_bag`]), streamed message by message into blocks, so memory is a few chunks of
//! the file and one block of rows. Channels as for sessions: `t` (receive time, seconds from the
//! first message), `gyro_x…z` (`angular_velocity`, rad/s), `accel_x…z`
//! (`linear_acceleration`, m/s²) and `t_sensor` (the header stamp, seconds from the first
//! message's). Gaps are found on the header stamps; a topic whose stamps do not increase
//! (a driver that leaves them zero) is timed by its receive times instead.

use super::input::{
    BlockVisitor, InputError, RowVisitor, SampleSource, SensorClock, Timing, BLOCK_ROWS,
};
use super::units::RateUnit;
use imulab_bag::messages::{decode, MessageType, Reading};
use imulab_bag::{Bag, BagError};
use std::cell::Cell;
use std::path::Path;

const CHANNELS: [&str; 8] = [
    "t", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z", "t_sensor",
];
const T_SENSOR: usize = 7;

impl From<BagError> for InputError {
    fn from(e: BagError) -> Self {
        match e {
            BagError::Io { path, source } => InputError::Io { path, source },
            BagError::Format { path, message } => InputError::Format { path, message },
        }
    }
}

pub struct BagSource {
    bag: Bag,
    topic: String,
    messages: u64,
    stamps_increase: bool,
    channels: Vec<String>,
    /// Whether the damage and skip counts of a read were reported (once, not per pass).
    reported: Cell<bool>,
}

impl BagSource {
    /// Opens the `sensor_msgs/Imu` topic `topic` of the bag at `path` (the bag's only one
    /// when `None`); a missing or wrong topic is an error listing the bag's topics.
    pub fn open(path: &Path, topic: Option<&str>) -> Result<Self, InputError> {
        let bag = Bag::open(path)?;
        let info = bag.imu_topic(topic)?.clone();
        let mut source = BagSource {
            bag,
            topic: info.name.clone(),
            messages: info.messages,
            stamps_increase: true,
            channels: CHANNELS.iter().map(|c| c.to_string()).collect(),
            reported: Cell::new(true),
        };
        // Header stamps that do not increase over the first messages cannot time the series.
        let mut last: Option<f64> = None;
        let mut increasing = 0usize;
        let mut seen = 0usize;
        let result = source.for_each_row(&[T_SENSOR], &mut |_, v| {
            if let Some(prev) = last {
                if v[0] > prev {
                    increasing += 1;
                }
            }
            last = Some(v[0]);
            seen += 1;
            if seen >= 64 {
                return Err(InputError::Stopped);
            }
            Ok(())
        });
        match result {
            Ok(()) | Err(InputError::Stopped) => {}
            Err(e) => return Err(e),
        }
        source.stamps_increase = seen < 2 || increasing * 2 >= seen;
        source.reported.set(false);
        Ok(source)
    }

    pub fn topic(&self) -> &str {
        &self.topic
    }
}

impl SampleSource for BagSource {
    fn describe(&self) -> String {
        format!("{} [{}]", self.bag.path().display(), self.topic)
    }

    fn channels(&self) -> &[String] {
        &self.channels
    }

    fn as_any_session(&self) -> Option<&str> {
        Some(&self.topic)
    }

    fn row_count_hint(&self) -> Option<u64> {
        Some(self.messages)
    }

    fn native_timing(&self) -> Option<Timing> {
        Some(if self.stamps_increase {
            Timing::SensorTime {
                channel: T_SENSOR,
                clock: SensorClock {
                    unit_s: Some(1.0),
                    // Time stamps never wrap.
                    wrap: Some(f64::INFINITY),
                    name: "header stamps".into(),
                },
                arrival: 0,
                arrival_scale: 1.0,
            }
        } else {
            Timing::ArrivalTimes {
                channel: 0,
                scale: 1.0,
            }
        })
    }

    fn channel_unit(&self, channel: usize) -> Option<RateUnit> {
        match channel {
            1..=3 => Some(RateUnit::RadPerSecond),
            4..=6 => Some(RateUnit::MetrePerSecondSquared),
            _ => None,
        }
    }

    fn for_each_block(
        &self,
        wanted: &[usize],
        visit: &mut BlockVisitor<'_>,
    ) -> Result<(), InputError> {
        if let Some(&c) = wanted.iter().find(|&&c| c >= CHANNELS.len()) {
            return Err(InputError::Channel(format!(
                "{}: no channel index {c}",
                self.describe()
            )));
        }
        let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(BLOCK_ROWS); wanted.len()];
        let mut first_row = 0u64;
        let mut origin: Option<(i64, i64)> = None;
        let mut undecodable = 0u64;
        let mut first_problem: Option<String> = None;
        let flush = |columns: &mut Vec<Vec<f64>>,
                     first_row: &mut u64,
                     visit: &mut BlockVisitor<'_>|
         -> Result<(), InputError> {
            let n = columns.first().map_or(0, Vec::len);
            if n == 0 {
                return Ok(());
            }
            let slices: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
            visit(*first_row, &slices)?;
            *first_row += n as u64;
            columns.iter_mut().for_each(Vec::clear);
            Ok(())
        };
        let end = self.bag.read::<InputError>(&mut |m| {
            if m.topic != self.topic {
                return Ok(());
            }
            let reading = match m.encoding {
                Some(encoding) => decode(MessageType::Imu, encoding, m.data),
                None => Err("message encoding is neither CDR nor ROS 1".into()),
            };
            let (stamp_ns, gyro, accel) = match reading {
                Ok(Reading::Imu {
                    stamp_ns,
                    gyro,
                    accel,
                }) => (stamp_ns, gyro, accel),
                // decode(Imu) gives only Reading::Imu.
                Ok(_) => return Ok(()),
                Err(e) => {
                    undecodable += 1;
                    first_problem
                        .get_or_insert_with(|| format!("message {}: {e}", first_row + undecodable));
                    return Ok(());
                }
            };
            let (log0, stamp0) = *origin.get_or_insert((m.log_time_ns, stamp_ns));
            for (column, &c) in columns.iter_mut().zip(wanted) {
                column.push(match c {
                    0 => (m.log_time_ns - log0) as f64 * 1e-9,
                    1..=3 => gyro[c - 1],
                    4..=6 => accel[c - 4],
                    _ => (stamp_ns - stamp0) as f64 * 1e-9,
                });
            }
            if columns.first().is_some_and(|c| c.len() >= BLOCK_ROWS) {
                flush(&mut columns, &mut first_row, visit)?;
            }
            Ok(())
        })?;
        flush(&mut columns, &mut first_row, visit)?;
        if !self.reported.replace(true) {
            if undecodable > 0 {
                tracing::warn!(
                    "{}: {undecodable} message(s) could not be decoded and were skipped (first: {})",
                    self.describe(),
                    first_problem.unwrap_or_default()
                );
            }
            if let Some(cut) = end.cut {
                tracing::warn!(
                    "{}: {cut}; the {first_row} messages of the topic before it are analysed",
                    self.describe()
                );
            }
        }
        Ok(())
    }

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
