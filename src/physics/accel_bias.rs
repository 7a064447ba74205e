//! `accel_bias`: a constant accelerometer offset. real = f + b.

use serde::{Deserialize, Serialize};

use super::{add_constant, check_finite, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Constant accelerometer bias.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelBias {
    /// Bias per axis, m/s².
    pub bias: [f64; 3],
}

impl ErrorTerm for AccelBias {
    const NAME: &'static str = "accel_bias";

    fn identity() -> Self {
        AccelBias { bias: [0.0; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "bias", &self.bias)
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        add_constant(&mut s.accel, &vec3(self.bias));
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn adds_the_bias() {
        let s = signals(10);
        let out = applied(&AccelBias { bias: [0.01, -0.02, 0.03] }, &s);
        assert!((out.accel[4] - s.accel[4] - nalgebra::Vector3::new(0.01, -0.02, 0.03)).norm() < 1e-15);
        assert_eq!(out.gyro, s.gyro);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(v3(1.0).prop_map(|bias| AccelBias { bias }));
    }
}
