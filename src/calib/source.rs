//! A [`SampleSource`] whose gyro and accel channels pass through a [`Corrector`] on the way
//! in: how `allan`, `report` and `thermal` apply `--calibration` to sessions and to files
//! with `gyro_x … accel_z` columns. A correction mixes the three axes of a triad, so every
//! block is read with the whole triad even when fewer of its axes are wanted.

use super::file::Corrector;
use imulab_allan::input::{BlockVisitor, InputError, RowVisitor, SampleSource, Timing};
use imulab_allan::units::RateUnit;

/// The gyro and accel channel indices of `source`, by the names `gyro_x … accel_z`.
fn triads(source: &dyn SampleSource) -> (Option<[usize; 3]>, Option<[usize; 3]>) {
    let find = |names: [&str; 3]| -> Option<[usize; 3]> {
        let c = source.channels();
        let idx = names.map(|n| c.iter().position(|x| x == n));
        Some([idx[0]?, idx[1]?, idx[2]?])
    };
    (
        find(["gyro_x", "gyro_y", "gyro_z"]),
        find(["accel_x", "accel_y", "accel_z"]),
    )
}

pub struct CalibratedSource {
    inner: Box<dyn SampleSource>,
    corrector: Corrector,
    gyro: Option<[usize; 3]>,
    accel: Option<[usize; 3]>,
}

impl CalibratedSource {
    /// Wraps `inner`; errors when a triad the calibration corrects has no `*_x/y/z`
    /// channels, or when a file's channels are not in SI units (`to_si` of their unit ≠ 1).
    pub fn new(
        inner: Box<dyn SampleSource>,
        corrector: Corrector,
        units_si: bool,
    ) -> Result<CalibratedSource, InputError> {
        let (gyro, accel) = triads(inner.as_ref());
        let fail = |what: &str| {
            InputError::Channel(format!(
                "{}: --calibration corrects the {what} triad, which needs channels named {what}_x, {what}_y, {what}_z (channels: {})",
                inner.describe(),
                inner.channels().join(", ")
            ))
        };
        if corrector.corrects_gyro() && gyro.is_none() {
            return Err(fail("gyro"));
        }
        if corrector.corrects_accel() && accel.is_none() {
            return Err(fail("accel"));
        }
        if !units_si {
            return Err(InputError::Channel(format!(
                "{}: --calibration needs rad/s and m/s² (give --units rad/s or m/s2, or a session)",
                inner.describe()
            )));
        }
        Ok(CalibratedSource {
            inner,
            corrector,
            gyro,
            accel,
        })
    }
}

impl SampleSource for CalibratedSource {
    fn describe(&self) -> String {
        format!("{} (calibrated)", self.inner.describe())
    }

    fn channels(&self) -> &[String] {
        self.inner.channels()
    }

    fn for_each_row(&self, wanted: &[usize], visit: &mut RowVisitor<'_>) -> Result<(), InputError> {
        let mut values = vec![0.0; wanted.len()];
        self.for_each_block(wanted, &mut |first, columns| {
            let rows = columns.first().map_or(0, |c| c.len());
            for i in 0..rows {
                for (slot, column) in values.iter_mut().zip(columns) {
                    *slot = column[i];
                }
                visit(first + i as u64, &values)?;
            }
            Ok(())
        })
    }

    fn for_each_block(
        &self,
        wanted: &[usize],
        visit: &mut BlockVisitor<'_>,
    ) -> Result<(), InputError> {
        // Read the wanted channels plus every axis of each triad any of them belongs to.
        let mut read: Vec<usize> = wanted.to_vec();
        let gyro = self
            .gyro
            .filter(|t| self.corrector.corrects_gyro() && wanted.iter().any(|c| t.contains(c)));
        let accel = self
            .accel
            .filter(|t| self.corrector.corrects_accel() && wanted.iter().any(|c| t.contains(c)));
        for t in [gyro, accel].into_iter().flatten() {
            for c in t {
                if !read.contains(&c) {
                    read.push(c);
                }
            }
        }
        let slot = |c: usize, read: &[usize]| read.iter().position(|&x| x == c).unwrap_or(0);
        let mut columns: Vec<Vec<f64>> = vec![Vec::new(); read.len()];
        self.inner.for_each_block(&read, &mut |first, slices| {
            for (col, s) in columns.iter_mut().zip(slices) {
                col.clear();
                col.extend_from_slice(s);
            }
            let pick = |t: Option<[usize; 3]>, columns: &mut Vec<Vec<f64>>| {
                t.map(|t| t.map(|c| std::mem::take(&mut columns[slot(c, &read)])))
            };
            let mut g = pick(gyro, &mut columns);
            let mut a = pick(accel, &mut columns);
            self.corrector.apply_columns(
                g.as_mut()
                    .map(|[x, y, z]| [x.as_mut_slice(), y.as_mut_slice(), z.as_mut_slice()]),
                a.as_mut()
                    .map(|[x, y, z]| [x.as_mut_slice(), y.as_mut_slice(), z.as_mut_slice()]),
            );
            for (t, cols) in [(gyro, g), (accel, a)] {
                if let (Some(t), Some(cols)) = (t, cols) {
                    for (c, col) in t.into_iter().zip(cols) {
                        columns[slot(c, &read)] = col;
                    }
                }
            }
            let out: Vec<&[f64]> = wanted
                .iter()
                .map(|&c| columns[slot(c, &read)].as_slice())
                .collect();
            visit(first, &out)
        })
    }

    fn as_any_session(&self) -> Option<&str> {
        self.inner.as_any_session()
    }

    fn row_count_hint(&self) -> Option<u64> {
        self.inner.row_count_hint()
    }

    fn native_timing(&self) -> Option<Timing> {
        self.inner.native_timing()
    }

    fn channel_unit(&self, channel: usize) -> Option<RateUnit> {
        self.inner.channel_unit(channel)
    }
}
