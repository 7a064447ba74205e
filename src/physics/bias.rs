//! `gyro_bias`, `accel_bias`: a constant offset of one sensor. real = x + b.

use std::marker::PhantomData;

use serde::{Deserialize, Serialize};

use super::sensor_kind::{Accel, Gyro, SensorKind};
use super::{add_constant, check_finite, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// A constant bias of sensor `S`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, bound = "")]
pub struct Bias<S: SensorKind> {
    /// Bias per axis: rad/s for the gyro, m/s² for the accelerometer.
    pub bias: [f64; 3],
    #[serde(skip)]
    sensor: PhantomData<S>,
}

/// `gyro_bias`: constant gyro bias, rad/s.
pub type GyroBias = Bias<Gyro>;
/// `accel_bias`: constant accelerometer bias, m/s².
pub type AccelBias = Bias<Accel>;

impl<S: SensorKind> Bias<S> {
    pub const fn new(bias: [f64; 3]) -> Self {
        Bias { bias, sensor: PhantomData }
    }
}

impl<S: SensorKind> ErrorTerm for Bias<S> {
    const NAME: &'static str = S::BIAS;

    fn identity() -> Self {
        Self::new([0.0; 3])
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "bias", &self.bias)
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        add_constant(S::channel(s), &vec3(self.bias));
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn adds_the_bias_to_its_sensor_alone() {
        let s = signals(10);
        let b = nalgebra::Vector3::new(0.01, -0.02, 0.03);
        let out = applied(&GyroBias::new([0.01, -0.02, 0.03]), &s);
        assert!((out.gyro[4] - s.gyro[4] - b).norm() < 1e-15);
        assert_eq!(out.accel, s.accel);
        let out = applied(&AccelBias::new([0.01, -0.02, 0.03]), &s);
        assert!((out.accel[4] - s.accel[4] - b).norm() < 1e-15);
        assert_eq!(out.gyro, s.gyro);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(v3(0.1).prop_map(GyroBias::new));
        super::super::test_support::suite(v3(1.0).prop_map(AccelBias::new));
    }
}
