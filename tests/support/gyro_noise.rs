//! The Allan benchmark's synthetic gyro data: white rate noise N plus rate random walk K at
//! 150 Hz from a seeded xoshiro256++ stream. One generator for `benches/allan.rs` (the
//! per-type table, `data.npy` for allantools, the session and memory runs) and
//! `examples/allan_probe.rs` (which times curves on the bench's axis 0), so both always
//! analyse the same series.

use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;

pub const RATE_HZ: f64 = 150.0;
/// 6 h at `RATE_HZ`.
pub const SAMPLES: usize = 6 * 3600 * 150;
/// Angle random walk coefficient of the white rate noise, rad/s/√Hz.
pub const N_TRUE: f64 = 2e-3;
/// Rate random walk coefficient, rad/s²/√Hz.
pub const K_TRUE: f64 = 5e-5;

/// The next rate sample: draws the white noise, then the walk's step, from `rng` and
/// advances `walk` (one per axis).
pub fn next_sample(rng: &mut Xoshiro256PlusPlus, walk: &mut f64) -> f64 {
    let tau0 = 1.0 / RATE_HZ;
    let white: f64 = StandardNormal.sample(rng);
    let step: f64 = StandardNormal.sample(rng);
    *walk += K_TRUE * tau0.sqrt() * step;
    N_TRUE / tau0.sqrt() * white + *walk
}

/// One axis of `SAMPLES` samples from `seed` (the bench's axis a uses seed 100 + a).
pub fn simulate(seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut walk = 0.0;
    (0..SAMPLES)
        .map(|_| next_sample(&mut rng, &mut walk))
        .collect()
}

/// Three axes of `rows` samples from seed 7, drawn row by row (x, y, z from one stream),
/// handed to `sink` in batches of `batch` rows without holding the whole series.
pub fn simulate_batches(rows: usize, batch: usize, mut sink: impl FnMut(&[[f64; 3]])) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let mut walk = [0.0f64; 3];
    let mut buffer = Vec::with_capacity(batch);
    let mut row = 0;
    while row < rows {
        buffer.clear();
        for _ in 0..batch.min(rows - row) {
            let mut gyro = [0.0; 3];
            for (g, w) in gyro.iter_mut().zip(walk.iter_mut()) {
                *g = next_sample(&mut rng, w);
            }
            buffer.push(gyro);
        }
        row += buffer.len();
        sink(&buffer);
    }
}
