//! `accel_misalignment`: accelerometer axes not orthogonal / not aligned with the body axes.
//! real = f + M f, M with a zero diagonal (the diagonal is `accel_scale`).

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, flat, left_multiply, mat3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Accelerometer axis misalignment (cross-axis sensitivity).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelMisalignment {
    /// M, row-major, dimensionless (rad for small angles), zero diagonal.
    pub matrix: [[f64; 3]; 3],
}

impl AccelMisalignment {
    /// The matrix I + M.
    pub fn transform(&self) -> Matrix3<f64> {
        Matrix3::identity() + mat3(self.matrix)
    }
}

impl ErrorTerm for AccelMisalignment {
    const NAME: &'static str = "accel_misalignment";

    fn identity() -> Self {
        AccelMisalignment { matrix: [[0.0; 3]; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "matrix", &flat(&self.matrix))?;
        (0..3).try_for_each(|i| {
            check_range(
                Self::NAME,
                "matrix",
                self.matrix[i][i],
                self.matrix[i][i] == 0.0,
                "zero on the diagonal (the diagonal is accel_scale)",
            )
        })
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        left_multiply(&mut s.accel, &self.transform());
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn adds_cross_axis_terms() {
        let s = signals(10);
        let m = [[0.0, 0.01, 0.0], [0.0, 0.0, -0.02], [0.03, 0.0, 0.0]];
        let out = applied(&AccelMisalignment { matrix: m }, &s);
        let (w, r) = (s.accel[2], out.accel[2]);
        assert!((r.x - (w.x + 0.01 * w.y)).abs() < 1e-15);
        assert!((r.y - (w.y - 0.02 * w.z)).abs() < 1e-15);
        assert!((r.z - (w.z + 0.03 * w.x)).abs() < 1e-15);
        assert_eq!(out.gyro, s.gyro);
        assert!(AccelMisalignment { matrix: [[0.1, 0.0, 0.0], [0.0; 3], [0.0; 3]] }.validate().is_err());
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(m3(0.01).prop_map(|mut matrix| {
            (0..3).for_each(|i| matrix[i][i] = 0.0);
            AccelMisalignment { matrix }
        }));
    }
}
