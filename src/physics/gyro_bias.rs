//! `gyro_bias`: a constant gyro offset. real = ω + b.

use serde::{Deserialize, Serialize};

use super::{add_constant, check_finite, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Constant gyro bias.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GyroBias {
    /// Bias per axis, rad/s.
    pub bias: [f64; 3],
}

impl ErrorTerm for GyroBias {
    const NAME: &'static str = "gyro_bias";

    fn identity() -> Self {
        GyroBias { bias: [0.0; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "bias", &self.bias)
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        add_constant(&mut s.gyro, &vec3(self.bias));
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
        let out = applied(&GyroBias { bias: [0.01, -0.02, 0.03] }, &s);
        assert!((out.gyro[4] - s.gyro[4] - nalgebra::Vector3::new(0.01, -0.02, 0.03)).norm() < 1e-15);
        assert_eq!(out.accel, s.accel);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(v3(0.1).prop_map(|bias| GyroBias { bias }));
    }
}
