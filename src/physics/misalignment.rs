//! `gyro_misalignment`, `accel_misalignment`: one sensor's axes not orthogonal / not aligned
//! with the body axes. real = x + M x, M with a zero diagonal (the diagonal is `*_scale`).

use std::marker::PhantomData;

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use super::sensor_kind::{Accel, Gyro, SensorKind};
use super::{check_finite, check_range, flat, left_multiply, mat3, ErrorTerm, ImuSignals, PhysicsError, Sensor, TermContext};

/// The axis misalignment (cross-axis sensitivity) of sensor `S`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, bound = "")]
pub struct Misalignment<S: SensorKind> {
    /// M, row-major, dimensionless (rad for small angles), zero diagonal.
    pub matrix: [[f64; 3]; 3],
    #[serde(skip)]
    sensor: PhantomData<S>,
}

/// `gyro_misalignment`.
pub type GyroMisalignment = Misalignment<Gyro>;
/// `accel_misalignment`.
pub type AccelMisalignment = Misalignment<Accel>;

impl<S: SensorKind> Misalignment<S> {
    pub const fn new(matrix: [[f64; 3]; 3]) -> Self {
        Misalignment { matrix, sensor: PhantomData }
    }

    /// The matrix I + M.
    pub fn transform(&self) -> Matrix3<f64> {
        Matrix3::identity() + mat3(self.matrix)
    }
}

impl<S: SensorKind> ErrorTerm for Misalignment<S> {
    const NAME: &'static str = S::MISALIGNMENT;

    fn identity() -> Self {
        Self::new([[0.0; 3]; 3])
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "matrix", &flat(&self.matrix))?;
        let expected = match S::SENSOR {
            Sensor::Gyro => "zero on the diagonal (the diagonal is gyro_scale)",
            Sensor::Accel => "zero on the diagonal (the diagonal is accel_scale)",
        };
        (0..3).try_for_each(|i| check_range(Self::NAME, "matrix", self.matrix[i][i], self.matrix[i][i] == 0.0, expected))
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        left_multiply(S::channel(s), &self.transform());
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn adds_cross_axis_terms_to_its_sensor_alone() {
        let s = signals(10);
        let m = [[0.0, 0.01, 0.0], [0.0, 0.0, -0.02], [0.03, 0.0, 0.0]];
        let crossed = |w: nalgebra::Vector3<f64>, r: nalgebra::Vector3<f64>| {
            (r.x - (w.x + 0.01 * w.y)).abs() < 1e-15 && (r.y - (w.y - 0.02 * w.z)).abs() < 1e-15 && (r.z - (w.z + 0.03 * w.x)).abs() < 1e-15
        };
        let out = applied(&GyroMisalignment::new(m), &s);
        assert!(crossed(s.gyro[2], out.gyro[2]));
        assert_eq!(out.accel, s.accel);
        let out = applied(&AccelMisalignment::new(m), &s);
        assert!(crossed(s.accel[2], out.accel[2]));
        assert_eq!(out.gyro, s.gyro);
        let diagonal = [[0.1, 0.0, 0.0], [0.0; 3], [0.0; 3]];
        assert!(GyroMisalignment::new(diagonal).validate().is_err());
        assert!(AccelMisalignment::new(diagonal).validate().is_err());
    }

    #[test]
    fn suite() {
        let off_diagonal = || {
            m3(0.01).prop_map(|mut matrix| {
                (0..3).for_each(|i| matrix[i][i] = 0.0);
                matrix
            })
        };
        super::super::test_support::suite(off_diagonal().prop_map(GyroMisalignment::new));
        super::super::test_support::suite(off_diagonal().prop_map(AccelMisalignment::new));
    }
}
