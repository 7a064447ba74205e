//! `earth_rotation`: the gyro also measures the Earth's rotation. With the world frame ENU at
//! latitude φ, Earth's rate in the world is Ω_E (0, cos φ, sin φ), and
//! real = ω + R_wiᵀ Ω_E (0, cos φ, sin φ), R_wi = world_from_imu.

use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, ErrorTerm, ImuSignals, PhysicsError, TermContext};
use nalgebra::Vector3;

/// Sidereal rotation rate of the Earth, rad/s (WGS-84).
pub const EARTH_RATE: f64 = 7.292_115e-5;

fn earth_rate() -> f64 {
    EARTH_RATE
}

fn is_earth_rate(r: &f64) -> bool {
    *r == EARTH_RATE
}

/// Earth rotation seen by the gyro.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EarthRotation {
    /// Geodetic latitude of the world origin, rad.
    pub latitude_rad: f64,
    /// Rotation rate, rad/s. Optional, defaults to [`EARTH_RATE`]; 0 gives the identity
    /// (an extension of the vocabulary, which has no identity for this term otherwise).
    #[serde(default = "earth_rate", skip_serializing_if = "is_earth_rate")]
    pub rate_rad_s: f64,
}

impl EarthRotation {
    /// Earth's angular velocity in the ENU world frame, rad/s.
    pub fn omega_in_world(&self) -> Vector3<f64> {
        self.rate_rad_s * Vector3::new(0.0, self.latitude_rad.cos(), self.latitude_rad.sin())
    }
}

impl ErrorTerm for EarthRotation {
    const NAME: &'static str = "earth_rotation";

    fn identity() -> Self {
        EarthRotation { latitude_rad: 0.0, rate_rad_s: 0.0 }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "latitude_rad", &[self.latitude_rad])?;
        check_finite(Self::NAME, "rate_rad_s", &[self.rate_rad_s])?;
        let half_pi = std::f64::consts::FRAC_PI_2;
        check_range(Self::NAME, "latitude_rad", self.latitude_rad, self.latitude_rad.abs() <= half_pi, "within [−π/2, π/2]")
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        let omega_earth_in_world = self.omega_in_world();
        for (omega, world_from_imu) in s.gyro.iter_mut().zip(&s.world_from_imu) {
            *omega += world_from_imu.inverse_transform_vector(&omega_earth_in_world);
        }
    }

    fn is_identity(&self) -> bool {
        self.rate_rad_s == 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use nalgebra::UnitQuaternion;
    use proptest::prelude::*;

    #[test]
    fn level_sensor_at_the_pole_and_equator() {
        let mut s = signals(2);
        s.world_from_imu = vec![UnitQuaternion::identity(); 2];
        let pole = applied(&EarthRotation { latitude_rad: std::f64::consts::FRAC_PI_2, rate_rad_s: EARTH_RATE }, &s);
        assert!((pole.gyro[0] - s.gyro[0] - Vector3::new(0.0, 0.0, EARTH_RATE)).norm() < 1e-15);
        let equator = applied(&EarthRotation { latitude_rad: 0.0, rate_rad_s: EARTH_RATE }, &s);
        assert!((equator.gyro[0] - s.gyro[0] - Vector3::new(0.0, EARTH_RATE, 0.0)).norm() < 1e-15);
        // Yawed by 90° (sensor x points north): the north component shows on x.
        s.world_from_imu = vec![UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2); 2];
        let yawed = applied(&EarthRotation { latitude_rad: 0.0, rate_rad_s: EARTH_RATE }, &s);
        assert!((yawed.gyro[0] - s.gyro[0] - Vector3::new(EARTH_RATE, 0.0, 0.0)).norm() < 1e-15);
    }

    #[test]
    fn default_rate_is_the_earths() {
        let t: EarthRotation = serde_yaml::from_str("latitude_rad: 0.8").unwrap();
        assert_eq!(t.rate_rad_s, EARTH_RATE);
        assert!(!serde_yaml::to_string(&t).unwrap().contains("rate_rad_s"));
        assert!(EarthRotation { latitude_rad: 2.0, rate_rad_s: EARTH_RATE }.validate().is_err());
    }

    #[test]
    fn suite() {
        super::super::test_support::suite((-1.5..1.5f64).prop_map(|latitude_rad| EarthRotation { latitude_rad, rate_rad_s: EARTH_RATE }));
    }
}
