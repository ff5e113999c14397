//! Where simulated data goes: the [`SimSink`] trait the runner emits into, an in-memory
//! sink for tests and studies, and a summary sink that keeps only counts and moments.
//! The session writer (HDF5) and the byte-stream server are further sinks.

use std::collections::BTreeMap;

use anyhow::Result;

use crate::store::{EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord};

/// Receives simulated records block by block, in a deterministic order: per block, first
/// truth/nav, then each IMU (records, then its truth) in scene order, then each GNSS.
pub trait SimSink {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()>;
    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()>;
    fn truth_nav(&mut self, records: &[TruthNavRecord]) -> Result<()>;
    fn truth_imu(&mut self, device: &str, records: &[TruthImuRecord]) -> Result<()>;
    fn event(&mut self, event: &EventRecord) -> Result<()>;
}

/// Keeps everything in memory (for tests, studies and short runs).
#[derive(Debug, Default, Clone, PartialEq)]
pub struct MemorySink {
    pub imu: BTreeMap<String, Vec<ImuRecord>>,
    pub gnss: BTreeMap<String, Vec<GnssRecord>>,
    pub truth_nav: Vec<TruthNavRecord>,
    pub truth_imu: BTreeMap<String, Vec<TruthImuRecord>>,
    pub events: Vec<EventRecord>,
}

impl SimSink for MemorySink {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()> {
        self.imu
            .entry(device.to_owned())
            .or_default()
            .extend_from_slice(records);
        Ok(())
    }
    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()> {
        self.gnss
            .entry(device.to_owned())
            .or_default()
            .extend_from_slice(records);
        Ok(())
    }
    fn truth_nav(&mut self, records: &[TruthNavRecord]) -> Result<()> {
        self.truth_nav.extend_from_slice(records);
        Ok(())
    }
    fn truth_imu(&mut self, device: &str, records: &[TruthImuRecord]) -> Result<()> {
        self.truth_imu
            .entry(device.to_owned())
            .or_default()
            .extend_from_slice(records);
        Ok(())
    }
    fn event(&mut self, event: &EventRecord) -> Result<()> {
        self.events.push(event.clone());
        Ok(())
    }
}

/// Running mean and spread of six channels (Welford's update).
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct Moments {
    pub count: u64,
    pub mean: [f64; 6],
    m2: [f64; 6],
}

impl Moments {
    fn add(&mut self, x: &[f64; 6]) {
        self.count += 1;
        let n = self.count as f64;
        for ((xi, mean), m2) in x.iter().zip(&mut self.mean).zip(&mut self.m2) {
            let d = xi - *mean;
            *mean += d / n;
            *m2 += d * (xi - *mean);
        }
    }

    /// Sample standard deviation of each channel (NaN with fewer than two samples).
    pub fn std(&self) -> [f64; 6] {
        let n = self.count as f64;
        self.m2.map(|m| {
            if self.count > 1 {
                (m / (n - 1.0)).sqrt()
            } else {
                f64::NAN
            }
        })
    }
}

/// Keeps counts and the mean/spread of each IMU's six channels: what `imulab sim` prints.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct SummarySink {
    pub imu: BTreeMap<String, Moments>,
    /// Per receiver: (epochs with a fix, epochs without).
    pub gnss: BTreeMap<String, (u64, u64)>,
    pub truth_nav_rows: u64,
    pub truth_imu_rows: u64,
}

impl SimSink for SummarySink {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()> {
        let m = self.imu.entry(device.to_owned()).or_default();
        for r in records {
            let [a, b, c] = r.gyro;
            let [d, e, f] = r.accel;
            m.add(&[a, b, c, d, e, f]);
        }
        Ok(())
    }
    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()> {
        let c = self.gnss.entry(device.to_owned()).or_default();
        for r in records {
            if r.lat_deg.is_nan() {
                c.1 += 1;
            } else {
                c.0 += 1;
            }
        }
        Ok(())
    }
    fn truth_nav(&mut self, records: &[TruthNavRecord]) -> Result<()> {
        self.truth_nav_rows += records.len() as u64;
        Ok(())
    }
    fn truth_imu(&mut self, _device: &str, records: &[TruthImuRecord]) -> Result<()> {
        self.truth_imu_rows += records.len() as u64;
        Ok(())
    }
    fn event(&mut self, _event: &EventRecord) -> Result<()> {
        Ok(())
    }
}
