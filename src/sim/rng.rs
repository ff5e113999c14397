//! Deterministic random streams for the simulator.
//!
//! Every random quantity (one axis of one noise term of one sensor) draws from its own
//! xoshiro256++ stream, keyed by the scene seed and a stable label such as
//! `"imu/cheap/gyro/x/white"`. Streams therefore do not depend on the order in which sensors
//! are simulated or on the number of threads, and adding a sensor to a scene does not change
//! the noise of the others. Normal deviates come from rand_distr's ziggurat `StandardNormal`.

use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;

/// One independent random stream.
#[derive(Debug, Clone)]
pub struct Stream {
    rng: Xoshiro256PlusPlus,
}

impl Stream {
    /// The stream for `label` under scene seed `seed`.
    pub fn new(seed: u64, label: &str) -> Self {
        // Hand-written because std's hashers are not guaranteed stable across Rust
        // releases: FNV-1a of the label, then SplitMix64 finalisation with the seed.
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for b in label.bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        let key = splitmix64(seed ^ splitmix64(h));
        Self {
            rng: Xoshiro256PlusPlus::seed_from_u64(key),
        }
    }

    /// A standard normal deviate (mean 0, variance 1).
    #[inline]
    pub fn normal(&mut self) -> f64 {
        StandardNormal.sample(&mut self.rng)
    }

    /// A uniform deviate in [0, 1).
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        rand::RngExt::random::<f64>(&mut self.rng)
    }
}

fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_label_same_stream_other_label_other_stream() {
        let a: Vec<f64> = (0..8)
            .map({
                let mut s = Stream::new(7, "imu/a/gyro/x/white");
                move |_| s.normal()
            })
            .collect();
        let b: Vec<f64> = (0..8)
            .map({
                let mut s = Stream::new(7, "imu/a/gyro/x/white");
                move |_| s.normal()
            })
            .collect();
        let c: Vec<f64> = (0..8)
            .map({
                let mut s = Stream::new(7, "imu/a/gyro/y/white");
                move |_| s.normal()
            })
            .collect();
        let d: Vec<f64> = (0..8)
            .map({
                let mut s = Stream::new(8, "imu/a/gyro/x/white");
                move |_| s.normal()
            })
            .collect();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_ne!(a, d);
    }

    #[test]
    fn normal_has_unit_variance() {
        let mut s = Stream::new(1, "check");
        let n = 200_000;
        let (mut sum, mut sum2) = (0.0, 0.0);
        for _ in 0..n {
            let x = s.normal();
            sum += x;
            sum2 += x * x;
        }
        let mean = sum / n as f64;
        let var = sum2 / n as f64 - mean * mean;
        // Standard errors: mean 1/sqrt(n) = 0.0022, variance sqrt(2/n) = 0.0032.
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.015, "{var}");
    }
}
