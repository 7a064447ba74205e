//! `saturation`: each axis clipped at ±range. Applied last, after quantisation, so the
//! output never exceeds the range.

use serde::{Deserialize, Serialize};

use super::{check_range, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Measurement range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Saturation {
    /// Gyro full-scale range, rad/s (+∞, `.inf` in YAML, for none).
    pub gyro_range: f64,
    /// Accelerometer full-scale range, m/s² (+∞ for none).
    pub accel_range: f64,
}

impl ErrorTerm for Saturation {
    const NAME: &'static str = "saturation";

    fn identity() -> Self {
        Saturation { gyro_range: f64::INFINITY, accel_range: f64::INFINITY }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_range(Self::NAME, "gyro_range", self.gyro_range, self.gyro_range > 0.0, "> 0 rad/s (or .inf for none)")?;
        check_range(Self::NAME, "accel_range", self.accel_range, self.accel_range > 0.0, "> 0 m/s² (or .inf for none)")
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        for (x, range) in [(&mut s.gyro, self.gyro_range), (&mut s.accel, self.accel_range)] {
            if range.is_finite() {
                x.iter_mut().for_each(|v| v.apply(|c| *c = c.clamp(-range, range)));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use nalgebra::Vector3;
    use proptest::prelude::*;

    #[test]
    fn clips_each_axis() {
        let mut s = signals(2);
        s.gyro[0] = Vector3::new(5.0, -5.0, 0.5);
        s.accel[0] = Vector3::new(200.0, 0.0, -200.0);
        let out = applied(&Saturation { gyro_range: 1.0, accel_range: 160.0 }, &s);
        assert_eq!(out.gyro[0], Vector3::new(1.0, -1.0, 0.5));
        assert_eq!(out.accel[0], Vector3::new(160.0, 0.0, -160.0));
        assert!(Saturation { gyro_range: -1.0, accel_range: 1.0 }.validate().is_err());
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(
            (0.1..40.0f64, 1.0..200.0f64).prop_map(|(gyro_range, accel_range)| Saturation { gyro_range, accel_range }),
        );
    }
}
