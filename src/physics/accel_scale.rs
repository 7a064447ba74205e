//! `accel_scale`: per-axis accelerometer scale-factor error. real_i = (1 + s_i) f_i.

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, left_multiply, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Accelerometer scale-factor error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelScale {
    /// Relative scale error per axis (dimensionless; 1e-3 = 1000 ppm).
    pub scale: [f64; 3],
}

impl AccelScale {
    /// The matrix I + diag(s).
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::from_diagonal(&vec3(self.scale).add_scalar(1.0))
    }
}

impl ErrorTerm for AccelScale {
    const NAME: &'static str = "accel_scale";

    fn identity() -> Self {
        AccelScale { scale: [0.0; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "scale", &self.scale)?;
        self.scale.iter().try_for_each(|&s| check_range(Self::NAME, "scale", s, s > -1.0, "> -1 (a gain of 1 + s must stay positive)"))
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        left_multiply(&mut s.accel, &self.matrix());
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
        let out = applied(&AccelScale { scale: [0.01, -0.02, 0.5] }, &s);
        let (a, b) = (s.accel[3], out.accel[3]);
        assert!((b.x - 1.01 * a.x).abs() < 1e-15 && (b.y - 0.98 * a.y).abs() < 1e-15 && (b.z - 1.5 * a.z).abs() < 1e-15);
        assert_eq!(out.gyro, s.gyro);
        assert!(AccelScale { scale: [-1.5, 0.0, 0.0] }.validate().is_err());
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(v3(0.01).prop_map(|scale| AccelScale { scale }));
    }
}
