//! The WGS-84 earth model shared by the simulator and the fusion filter: normal gravity,
//! radii of curvature, earth rotation and transport rate in the local-level NED frame.
//!
//! Formulas: Somigliana normal gravity with the second-order height correction, and the
//! usual meridian / prime-vertical radii (Groves, *Principles of GNSS, Inertial, and
//! Multisensor Integrated Navigation Systems*, 2nd ed., ch. 2).

use nalgebra::Vector3;

/// Semi-major axis, m.
pub const A: f64 = 6_378_137.0;
/// Flattening.
pub const F: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared.
pub const E2: f64 = F * (2.0 - F);
/// Semi-minor axis, m.
pub const B: f64 = A * (1.0 - F);
/// Earth rotation rate, rad/s.
pub const OMEGA_IE: f64 = 7.292_115e-5;
/// Earth's gravitational constant GM, m³/s².
pub const GM: f64 = 3.986_004_418e14;
/// Normal gravity at the equator, m/s².
const GAMMA_E: f64 = 9.780_325_335_9;
/// Somigliana's constant k = (b γ_p − a γ_e) / (a γ_e).
const SOMIGLIANA_K: f64 = 0.001_931_852_652_41;

/// Meridian (north-south) radius of curvature R_N at geodetic latitude `lat` (rad), m.
pub fn meridian_radius(lat: f64) -> f64 {
    Latitude::new(lat).meridian_radius()
}

/// Prime-vertical (east-west) radius of curvature R_E at latitude `lat` (rad), m.
pub fn prime_vertical_radius(lat: f64) -> f64 {
    Latitude::new(lat).prime_vertical_radius()
}

/// Magnitude of normal gravity (gravitation plus centrifugal) at latitude `lat` (rad) and
/// ellipsoidal height `h` (m), m/s².
pub fn normal_gravity(lat: f64, h: f64) -> f64 {
    Latitude::new(lat).normal_gravity(h)
}

/// Gravity vector in NED (down positive), m/s².
pub fn gravity_ned(lat: f64, h: f64) -> Vector3<f64> {
    Vector3::new(0.0, 0.0, normal_gravity(lat, h))
}

/// Earth rotation rate expressed in NED at latitude `lat`, rad/s.
pub fn earth_rate_ned(lat: f64) -> Vector3<f64> {
    Latitude::new(lat).earth_rate_ned()
}

/// Transport rate (rotation of NED relative to the earth) for velocity `v_ned` at `lat`, `h`.
pub fn transport_rate_ned(lat: f64, h: f64, v_ned: &Vector3<f64>) -> Vector3<f64> {
    Latitude::new(lat).transport_rate_ned(h, v_ned)
}

/// Largest latitude step, rad, that [`Latitude::shifted`] takes by its Taylor series
/// (error below d³/6 = 1.7·10⁻¹⁶); larger steps evaluate the sine and cosine anew.
pub const LATITUDE_SERIES_MAX_RAD: f64 = 1e-5;

/// Sine and cosine of a geodetic latitude, and the earth-model terms that depend on it. A
/// strapdown step needs them at several latitudes within a few 10⁻⁸ rad of each other:
/// [`Latitude::shifted`] gets those from one `sin_cos` to within rounding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Latitude {
    pub rad: f64,
    pub sin: f64,
    pub cos: f64,
}

impl Latitude {
    pub fn new(lat: f64) -> Self {
        let (sin, cos) = lat.sin_cos();
        Self { rad: lat, sin, cos }
    }

    /// The latitude `d` rad further north: second-order Taylor series of the sine and
    /// cosine for |d| ≤ [`LATITUDE_SERIES_MAX_RAD`], a new `sin_cos` beyond.
    pub fn shifted(&self, d: f64) -> Self {
        if d.is_nan() || d.abs() > LATITUDE_SERIES_MAX_RAD {
            return Self::new(self.rad + d);
        }
        let c2 = 1.0 - 0.5 * d * d;
        Self {
            rad: self.rad + d,
            sin: self.sin * c2 + self.cos * d,
            cos: self.cos * c2 - self.sin * d,
        }
    }

    /// Meridian radius of curvature R_N, m.
    pub fn meridian_radius(&self) -> f64 {
        // d^1.5 as d·√d: a square root instead of `powf` (a tenth of a replay's time).
        let d = 1.0 - E2 * self.sin * self.sin;
        A * (1.0 - E2) / (d * d.sqrt())
    }

    /// Prime-vertical radius of curvature R_E, m.
    pub fn prime_vertical_radius(&self) -> f64 {
        A / (1.0 - E2 * self.sin * self.sin).sqrt()
    }

    /// Normal gravity at ellipsoidal height `h` (m), m/s².
    pub fn normal_gravity(&self, h: f64) -> f64 {
        let s2 = self.sin * self.sin;
        let g0 = GAMMA_E * (1.0 + SOMIGLIANA_K * s2) / (1.0 - E2 * s2).sqrt();
        let m = OMEGA_IE * OMEGA_IE * A * A * B / GM;
        g0 * (1.0 - 2.0 / A * (1.0 + F + m - 2.0 * F * s2) * h + 3.0 / (A * A) * h * h)
    }

    /// Earth rotation rate in NED, rad/s.
    pub fn earth_rate_ned(&self) -> Vector3<f64> {
        Vector3::new(OMEGA_IE * self.cos, 0.0, -OMEGA_IE * self.sin)
    }

    /// Transport rate for velocity `v_ned` at height `h`, rad/s.
    pub fn transport_rate_ned(&self, h: f64, v_ned: &Vector3<f64>) -> Vector3<f64> {
        let re = self.prime_vertical_radius() + h;
        let rn = self.meridian_radius() + h;
        Vector3::new(
            v_ned.y / re,
            -v_ned.x / rn,
            -v_ned.y * (self.sin / self.cos) / re,
        )
    }
}

/// Geodetic latitude, longitude (rad) and height (m) to ECEF, m.
pub fn lla_to_ecef(lat: f64, lon: f64, h: f64) -> Vector3<f64> {
    let re = prime_vertical_radius(lat);
    let (sl, cl) = lat.sin_cos();
    let (so, co) = lon.sin_cos();
    Vector3::new(
        (re + h) * cl * co,
        (re + h) * cl * so,
        (re * (1.0 - E2) + h) * sl,
    )
}

/// ECEF (m) to geodetic latitude, longitude (rad) and height (m), by Bowring's iteration
/// (converges to well below a micrometre in three steps anywhere near the surface).
pub fn ecef_to_lla(p: &Vector3<f64>) -> (f64, f64, f64) {
    let lon = p.y.atan2(p.x);
    let rho = (p.x * p.x + p.y * p.y).sqrt();
    let mut lat = p.z.atan2(rho * (1.0 - E2));
    let mut h = 0.0;
    for _ in 0..5 {
        let re = prime_vertical_radius(lat);
        h = if lat.cos().abs() > 1e-9 {
            rho / lat.cos() - re
        } else {
            p.z.abs() - B
        };
        lat = p.z.atan2(rho * (1.0 - E2 * re / (re + h)));
    }
    (lat, lon, h)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Latitude terms reached by the series equal those evaluated anew, within rounding,
    /// and a large step evaluates anew.
    #[test]
    fn shifted_latitude_matches_direct_evaluation() {
        let base = Latitude::new(0.84);
        for d in [0.0, 1e-9, -3e-8, 5e-7, 9e-6, -2e-4, 0.1] {
            let s = base.shifted(d);
            let e = Latitude::new(0.84 + d);
            assert!((s.sin - e.sin).abs() < 4e-16, "{d}: sin");
            assert!((s.cos - e.cos).abs() < 4e-16, "{d}: cos");
            assert!((s.meridian_radius() - meridian_radius(0.84 + d)).abs() < 1e-8);
            assert!((s.normal_gravity(500.0) - normal_gravity(0.84 + d, 500.0)).abs() < 1e-14);
        }
    }

    #[test]
    fn gravity_matches_published_values() {
        // WGS-84 normal gravity: 9.7803253359 at the equator, 9.8321849379 at the poles.
        assert!((normal_gravity(0.0, 0.0) - 9.780_325_335_9).abs() < 1e-9);
        assert!((normal_gravity(std::f64::consts::FRAC_PI_2, 0.0) - 9.832_184_937_9).abs() < 1e-8);
        // Free-air gradient about -3.086e-6 /s² per metre.
        let grad = (normal_gravity(0.8, 100.0) - normal_gravity(0.8, 0.0)) / 100.0;
        assert!((grad + 3.086e-6).abs() < 0.01e-6, "{grad}");
    }

    #[test]
    fn ecef_round_trip() {
        for &(lat, lon, h) in &[
            (0.7, 0.2, 100.0),
            (-1.2, 3.0, -50.0),
            (0.0, 0.0, 0.0),
            (1.5, -2.0, 9000.0),
        ] {
            let (la, lo, hh) = ecef_to_lla(&lla_to_ecef(lat, lon, h));
            assert!((la - lat).abs() < 1e-12 && (lo - lon).abs() < 1e-12 && (hh - h).abs() < 1e-6);
        }
    }

    #[test]
    fn radii_at_equator_and_pole() {
        assert!((prime_vertical_radius(0.0) - A).abs() < 1e-6);
        assert!((meridian_radius(0.0) - A * (1.0 - E2)).abs() < 1e-6);
        let pole = std::f64::consts::FRAC_PI_2;
        assert!((meridian_radius(pole) - prime_vertical_radius(pole)).abs() < 1e-6);
    }
}
