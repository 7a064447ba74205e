//! `gyro_scale`: per-axis gyro scale-factor error. real_i = (1 + s_i) ω_i.

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, left_multiply, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Gyro scale-factor error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GyroScale {
    /// Relative scale error per axis (dimensionless; 1e-3 = 1000 ppm).
    pub scale: [f64; 3],
}

impl GyroScale {
    /// The matrix I + diag(s).
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::from_diagonal(&vec3(self.scale).add_scalar(1.0))
    }
}

impl ErrorTerm for GyroScale {
    const NAME: &'static str = "gyro_scale";

    fn identity() -> Self {
        GyroScale { scale: [0.0; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "scale", &self.scale)?;
        self.scale.iter().try_for_each(|&s| check_range(Self::NAME, "scale", s, s > -1.0, "> -1 (a gain of 1 + s must stay positive)"))
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        left_multiply(&mut s.gyro, &self.matrix());
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn scales_each_axis() {
        let s = signals(10);
        let out = applied(&GyroScale { scale: [0.01, -0.02, 0.5] }, &s);
        let (a, b) = (s.gyro[3], out.gyro[3]);
        assert!((b.x - 1.01 * a.x).abs() < 1e-15 && (b.y - 0.98 * a.y).abs() < 1e-15 && (b.z - 1.5 * a.z).abs() < 1e-15);
        assert_eq!(out.accel, s.accel);
        assert!(GyroScale { scale: [-1.5, 0.0, 0.0] }.validate().is_err());
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(v3(0.01).prop_map(|scale| GyroScale { scale }));
    }
}
