//! The session follower: at every look it reads what the session's files hold beyond what
//! it read before (the readers of files still being written: SWMR), and keeps per device
//! the counts, rates, gaps, events and temperature, and per IMU axis the incremental Allan
//! state ([`AxisAllan`]). Chunk files that are complete are never opened again; a look
//! opens only the file being written (and any that appeared since).
//!
//! Rows are found by time: a look reads the rows at or after the last time it read, and
//! skips the rows at exactly that time it has already taken (times never decrease).

use super::allan::AxisAllan;
use super::trend::Trend;
use crate::allan::units::SensorKind;
use crate::report::health::event_count;
use crate::report::health::event_kind_name;
use crate::store::{
    DeviceInfo, DeviceKind, ImuColumnSet, ImuColumns, Manifest, Session, StoreError, TimeRange,
};
use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};

/// Rows per block read.
const BLOCK_ROWS: usize = 16_384;
/// Data time over which the current rate is measured.
const RATE_WINDOW_NS: i64 = 10_000_000_000;
/// Temperature bins start this long (they double as the run grows: [`Trend`]).
const TEMPERATURE_BIN_NS: i64 = 1_000_000_000;
/// Problem lines kept (the first ones).
const MAX_PROBLEMS: usize = 32;

/// The six IMU channels the Allan curves are computed on.
pub const AXES: [(&str, SensorKind); 6] = [
    ("gyro_x", SensorKind::Gyro),
    ("gyro_y", SensorKind::Gyro),
    ("gyro_z", SensorKind::Gyro),
    ("accel_x", SensorKind::Accel),
    ("accel_y", SensorKind::Accel),
    ("accel_z", SensorKind::Accel),
];

/// One IMU axis.
#[derive(Debug, Clone)]
pub struct AxisState {
    pub name: &'static str,
    pub sensor: SensorKind,
    pub allan: AxisAllan,
    /// NaN or infinite values (left out of the curve).
    pub invalid: u64,
}

/// Where reading a stream stopped: the last time read and how many rows at that time.
#[derive(Debug, Clone, Copy, Default)]
struct Mark {
    t_ns: Option<i64>,
    taken_at_t: usize,
}

impl Mark {
    fn range(&self) -> TimeRange {
        TimeRange::new(self.t_ns, None)
    }

    /// How many of `times` were read already; moves the mark past the rest. `resume`: the
    /// first block of a look (its first rows may be at the mark's time and read before);
    /// the blocks after it follow on.
    fn advance(&mut self, times: &[i64], resume: bool) -> usize {
        let mut skip = 0;
        if let (Some(t), true) = (self.t_ns, resume) {
            while skip < times.len() && skip < self.taken_at_t && times[skip] == t {
                skip += 1;
            }
        }
        let Some(&last) = times.last() else { return 0 };
        if skip == times.len() {
            return skip;
        }
        let at_last = times.iter().rev().take_while(|&&t| t == last).count();
        if Some(last) == self.t_ns {
            self.taken_at_t += at_last.min(times.len() - skip);
        } else {
            self.t_ns = Some(last);
            self.taken_at_t = at_last;
        }
        skip
    }
}

/// Everything kept about one device.
#[derive(Debug, Clone)]
pub struct DeviceState {
    pub info: DeviceInfo,
    pub rows: u64,
    pub first_t_ns: Option<i64>,
    pub last_t_ns: Option<i64>,
    /// Intervals of at least 1.5 nominal periods, and the samples missing in them.
    pub gaps: u64,
    pub missing_samples: u64,
    /// Events by kind (`count=N` details counted N times).
    pub events: BTreeMap<String, u64>,
    pub temperature: Trend,
    /// IMU axes with at least one finite value (empty for GNSS receivers).
    pub axes: Vec<AxisState>,
    /// (time, rows so far) over the last [`RATE_WINDOW_NS`] of data.
    recent: VecDeque<(i64, u64)>,
    mark: Mark,
}

impl DeviceState {
    fn new(info: DeviceInfo) -> Self {
        let axes = match info.kind {
            DeviceKind::Imu => AXES
                .iter()
                .map(|&(name, sensor)| AxisState {
                    name,
                    sensor,
                    allan: AxisAllan::new(),
                    invalid: 0,
                })
                .collect(),
            DeviceKind::Gnss => Vec::new(),
        };
        DeviceState {
            info,
            rows: 0,
            first_t_ns: None,
            last_t_ns: None,
            gaps: 0,
            missing_samples: 0,
            events: BTreeMap::new(),
            temperature: Trend::new(TEMPERATURE_BIN_NS),
            axes,
            recent: VecDeque::new(),
            mark: Mark::default(),
        }
    }

    /// Rows per second over the last [`RATE_WINDOW_NS`] of data time.
    pub fn recent_rate_hz(&self) -> Option<f64> {
        let (&(t0, r0), &(t1, r1)) = (self.recent.front()?, self.recent.back()?);
        (t1 > t0).then(|| (r1 - r0) as f64 / ((t1 - t0) as f64 * 1e-9))
    }

    /// Mean rate over the whole run.
    pub fn mean_rate_hz(&self) -> Option<f64> {
        let (t0, t1) = (self.first_t_ns?, self.last_t_ns?);
        (t1 > t0 && self.rows > 1).then(|| (self.rows - 1) as f64 / ((t1 - t0) as f64 * 1e-9))
    }

    /// Mean sample interval, s (the Allan τ0): from the data, else the nominal rate.
    pub fn tau0(&self) -> f64 {
        match self.mean_rate_hz() {
            Some(r) if r > 0.0 => 1.0 / r,
            _ => 1.0 / self.info.rate_hz.max(1e-9),
        }
    }

    /// Data time covered, s.
    pub fn span_s(&self) -> f64 {
        match (self.first_t_ns, self.last_t_ns) {
            (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
            _ => 0.0,
        }
    }

    /// Axes that have data.
    pub fn axes_with_data(&self) -> impl Iterator<Item = &AxisState> {
        self.axes.iter().filter(|a| a.allan.samples() > 0)
    }

    /// Takes in new time stamps: counts, gaps and the rate window.
    fn take_times(&mut self, times: &[i64]) {
        let gap_ns = 1.5e9 / self.info.rate_hz.max(1e-9);
        let period_ns = 1e9 / self.info.rate_hz.max(1e-9);
        for &t in times {
            if let Some(p) = self.last_t_ns {
                let dt = (t - p) as f64;
                if dt >= gap_ns {
                    self.gaps += 1;
                    self.missing_samples += ((dt / period_ns).round() as u64).saturating_sub(1);
                }
            }
            self.first_t_ns.get_or_insert(t);
            self.last_t_ns = Some(t);
        }
        self.rows += times.len() as u64;
        if let Some(&t) = times.last() {
            self.recent.push_back((t, self.rows));
            while self
                .recent
                .front()
                .is_some_and(|&(t0, _)| t - t0 > RATE_WINDOW_NS)
                && self.recent.len() > 2
            {
                self.recent.pop_front();
            }
        }
    }

    /// Takes in a block of IMU columns from row `from` on.
    fn take_imu(&mut self, block: &ImuColumns, from: usize) {
        let times = &block.t_mono_ns[from..];
        self.take_times(times);
        let values = block.gyro.iter().chain(block.accel.iter());
        let mut finite: Vec<f64> = Vec::with_capacity(times.len());
        for (axis, column) in self.axes.iter_mut().zip(values) {
            let column = &column[from..];
            finite.clear();
            finite.extend(column.iter().copied().filter(|v| v.is_finite()));
            axis.invalid += (column.len() - finite.len()) as u64;
            axis.allan.extend(&finite);
        }
        for (&t, &v) in times.iter().zip(&block.temp[from..]) {
            self.temperature.push(t, v);
        }
    }
}

/// The followed session.
pub struct Follower {
    dir: PathBuf,
    pub manifest: Manifest,
    pub devices: Vec<DeviceState>,
    /// Session-wide events by kind.
    pub session_events: BTreeMap<String, u64>,
    /// One line per problem met (unreadable files or rows), the first [`MAX_PROBLEMS`].
    pub problems: Vec<String>,
    /// Chunk files numbered below this are complete and read.
    first_file: u32,
    events: Mark,
    /// Complete chunk files read, files the last look opened, and how many of those are
    /// still being written.
    done_files: usize,
    files_open: usize,
    pub partial_files: usize,
    /// Looks taken.
    pub looks: u64,
}

impl Follower {
    /// Opens the session (its manifest); nothing is read until [`Follower::look`].
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        let manifest = Manifest::load(dir)?;
        let devices = manifest
            .devices
            .iter()
            .cloned()
            .map(DeviceState::new)
            .collect();
        Ok(Follower {
            dir: dir.to_path_buf(),
            manifest,
            devices,
            session_events: BTreeMap::new(),
            problems: Vec::new(),
            first_file: 0,
            events: Mark::default(),
            done_files: 0,
            files_open: 0,
            partial_files: 0,
            looks: 0,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Reads what was added since the last look. Per-file problems are kept in
    /// [`Follower::problems`]; only a session that can no longer be opened is an error.
    pub fn look(&mut self) -> Result<(), StoreError> {
        let session = Session::open_from(&self.dir, self.first_file)?;
        let files = session.files();
        for f in &files {
            // A partial file that does not open yet is normal while its writer starts it.
            if let (Some(p), false) = (&f.problem, f.partial) {
                self.problem(p.clone());
            }
        }
        for i in 0..self.devices.len() {
            self.read_device(&session, i);
        }
        self.read_events(&session);
        // Files before the first partial one (or before the last) are complete and read.
        let next_first = files
            .iter()
            .find(|f| f.partial)
            .or(files.last())
            .map(|f| f.index);
        let done_before = next_first.unwrap_or(self.first_file);
        let newly_done = files.iter().filter(|f| f.index < done_before).count();
        self.done_files += newly_done;
        self.partial_files = files.iter().filter(|f| f.partial).count();
        self.files_open = files.len() - newly_done;
        self.first_file = done_before;
        self.looks += 1;
        Ok(())
    }

    /// Chunk files in the session: the complete ones read and those of the last look.
    pub fn file_count(&self) -> usize {
        self.done_files + self.files_open
    }

    fn problem(&mut self, line: String) {
        if self.problems.len() < MAX_PROBLEMS && !self.problems.contains(&line) {
            self.problems.push(line);
        }
    }

    fn read_device(&mut self, session: &Session, i: usize) {
        let name = self.devices[i].info.name.clone();
        let range = self.devices[i].mark.range();
        match self.devices[i].info.kind {
            DeviceKind::Imu => {
                let set = ImuColumnSet {
                    t_sensor: false,
                    gyro: true,
                    accel: true,
                    temp: true,
                };
                let mut reader = match session.imu_columns(&name, range, BLOCK_ROWS, set) {
                    Ok(r) => r,
                    Err(e) => return self.problem(e.to_string()),
                };
                let mut block = ImuColumns::default();
                let mut resume = true;
                while let Some(result) = reader.next_into(&mut block) {
                    if let Err(e) = result {
                        if is_partial(&e) {
                            // Being written: read it again at the next look.
                            return;
                        }
                        self.problem(e.to_string());
                        continue;
                    }
                    let device = &mut self.devices[i];
                    let skip = device.mark.advance(&block.t_mono_ns, resume);
                    resume = false;
                    device.take_imu(&block, skip);
                }
            }
            DeviceKind::Gnss => {
                let blocks = match session.time_blocks(&name, range, BLOCK_ROWS) {
                    Ok(b) => b,
                    Err(e) => return self.problem(e.to_string()),
                };
                let mut resume = true;
                for result in blocks {
                    match result {
                        Ok(times) => {
                            let device = &mut self.devices[i];
                            let skip = device.mark.advance(&times, resume);
                            resume = false;
                            device.take_times(&times[skip..]);
                        }
                        Err(e) if is_partial(&e) => return,
                        Err(e) => self.problem(e.to_string()),
                    }
                }
            }
        }
    }

    fn read_events(&mut self, session: &Session) {
        let mut resume = true;
        for result in session.event_blocks(self.events.range(), 4096) {
            let events = match result {
                Ok(events) => events,
                Err(e) if is_partial(&e) => return,
                Err(e) => {
                    self.problem(e.to_string());
                    continue;
                }
            };
            let times: Vec<i64> = events.iter().map(|e| e.t_mono_ns).collect();
            let skip = self.events.advance(&times, resume);
            resume = false;
            for e in &events[skip..] {
                let kind = event_kind_name(e.kind).to_string();
                let count = event_count(&e.detail);
                let target = match self.devices.iter_mut().find(|d| d.info.name == e.device) {
                    Some(d) => &mut d.events,
                    None => &mut self.session_events,
                };
                *target.entry(kind).or_insert(0) += count;
            }
        }
    }
}

/// Whether a read error is about a `*.partial` file (being written: retried later).
fn is_partial(e: &StoreError) -> bool {
    match e {
        StoreError::Corrupt { path, .. }
        | StoreError::Hdf5 { path, .. }
        | StoreError::Io { path, .. } => path
            .to_string_lossy()
            .ends_with(crate::store::layout::PARTIAL_SUFFIX),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::Mark;

    #[test]
    fn mark_skips_rows_already_read_at_its_time() {
        let mut m = Mark::default();
        assert_eq!(m.advance(&[1, 2, 2], true), 0);
        // The next read starts at t = 2 and sees both rows at 2 again, then new ones.
        assert_eq!(m.advance(&[2, 2, 2, 3], true), 2);
        assert_eq!(m.advance(&[3, 3], true), 1);
        assert_eq!(m.t_ns, Some(3));
        assert_eq!(m.taken_at_t, 2);
        // Nothing new.
        assert_eq!(m.advance(&[3, 3], true), 2);
        assert_eq!(m.taken_at_t, 2);
        // A block that follows on within a look skips nothing, even at the mark's time.
        assert_eq!(m.advance(&[3, 4], false), 0);
        assert_eq!((m.t_ns, m.taken_at_t), (Some(4), 1));
    }
}
