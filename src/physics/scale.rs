//! `gyro_scale`, `accel_scale`: per-axis scale-factor error of one sensor. real_i = (1 + s_i) x_i.

use std::marker::PhantomData;

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use super::sensor_kind::{Accel, Gyro, SensorKind};
use super::{check_finite, check_range, left_multiply, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// The scale-factor error of sensor `S`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, bound = "")]
pub struct Scale<S: SensorKind> {
    /// Relative scale error per axis (dimensionless; 1e-3 = 1000 ppm).
    pub scale: [f64; 3],
    #[serde(skip)]
    sensor: PhantomData<S>,
}

/// `gyro_scale`.
pub type GyroScale = Scale<Gyro>;
/// `accel_scale`.
pub type AccelScale = Scale<Accel>;

impl<S: SensorKind> Scale<S> {
    pub const fn new(scale: [f64; 3]) -> Self {
        Scale { scale, sensor: PhantomData }
    }

    /// The matrix I + diag(s).
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::from_diagonal(&vec3(self.scale).add_scalar(1.0))
    }
}

impl<S: SensorKind> ErrorTerm for Scale<S> {
    const NAME: &'static str = S::SCALE;

    fn identity() -> Self {
        Self::new([0.0; 3])
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "scale", &self.scale)?;
        self.scale.iter().try_for_each(|&s| check_range(Self::NAME, "scale", s, s > -1.0, "> -1 (a gain of 1 + s must stay positive)"))
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        left_multiply(S::channel(s), &self.matrix());
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn scales_each_axis_of_its_sensor_alone() {
        let s = signals(10);
        let close = |a: nalgebra::Vector3<f64>, b: nalgebra::Vector3<f64>| {
            (b.x - 1.01 * a.x).abs() < 1e-15 && (b.y - 0.98 * a.y).abs() < 1e-15 && (b.z - 1.5 * a.z).abs() < 1e-15
        };
        let out = applied(&GyroScale::new([0.01, -0.02, 0.5]), &s);
        assert!(close(s.gyro[3], out.gyro[3]));
        assert_eq!(out.accel, s.accel);
        let out = applied(&AccelScale::new([0.01, -0.02, 0.5]), &s);
        assert!(close(s.accel[3], out.accel[3]));
        assert_eq!(out.gyro, s.gyro);
        assert!(GyroScale::new([-1.5, 0.0, 0.0]).validate().is_err());
        assert!(AccelScale::new([-1.5, 0.0, 0.0]).validate().is_err());
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(v3(0.01).prop_map(GyroScale::new));
        super::super::test_support::suite(v3(0.01).prop_map(AccelScale::new));
    }
}
