//! `gyro_bias_temperature`: gyro bias that follows the die temperature.
//! real = ω + k (T − T_ref).

use serde::{Deserialize, Serialize};

use super::{check_finite, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Linear temperature coefficient of the gyro bias.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GyroBiasTemperature {
    /// Bias change per kelvin, per axis, rad/s/K.
    pub coefficient: [f64; 3],
    /// Temperature at which the bias change is zero, °C.
    pub reference_c: f64,
}

impl ErrorTerm for GyroBiasTemperature {
    const NAME: &'static str = "gyro_bias_temperature";

    fn identity() -> Self {
        GyroBiasTemperature { coefficient: [0.0; 3], reference_c: 25.0 }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "coefficient", &self.coefficient)?;
        check_finite(Self::NAME, "reference_c", &[self.reference_c])
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        let k = vec3(self.coefficient);
        s.gyro.iter_mut().zip(&s.temperature_c).for_each(|(omega, t)| *omega += k * (t - self.reference_c));
    }

    fn is_identity(&self) -> bool {
        self.coefficient == [0.0; 3]
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn follows_temperature() {
        let s = signals(100);
        let out = applied(&GyroBiasTemperature { coefficient: [1e-4, 0.0, -2e-4], reference_c: 25.0 }, &s);
        let n = 99;
        let dt = s.temperature_c[n] - 25.0;
        assert!(dt > 1.0);
        let d = out.gyro[n] - s.gyro[n];
        assert!((d.x - 1e-4 * dt).abs() < 1e-15 && d.y == 0.0 && (d.z + 2e-4 * dt).abs() < 1e-15);
        assert!(max_diff(&out.gyro[..1], &s.gyro[..1]) < 1e-15, "zero at the reference temperature");
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(
            (v3(1e-3), -20.0..60.0).prop_map(|(coefficient, reference_c)| GyroBiasTemperature { coefficient, reference_c }),
        );
    }
}
