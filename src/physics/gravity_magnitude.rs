//! `gravity_magnitude`: the local gravity is `g` instead of the nominal 9.81 m/s² the true
//! kinematics were made with. With g_world = (0, 0, −g) (ENU), f = R_wiᵀ (a + g e_z), so
//! real = f + (g − 9.81) R_wiᵀ e_z.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, ErrorTerm, ImuSignals, PhysicsError, TermContext, NOMINAL_GRAVITY};

/// Local gravity magnitude.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GravityMagnitude {
    /// Local gravity, m/s².
    pub g: f64,
}

impl ErrorTerm for GravityMagnitude {
    const NAME: &'static str = "gravity_magnitude";

    fn identity() -> Self {
        GravityMagnitude { g: NOMINAL_GRAVITY }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "g", &[self.g])?;
        check_range(Self::NAME, "g", self.g, self.g > 0.0, "> 0 m/s²")
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        let extra_up_in_world = Vector3::z() * (self.g - NOMINAL_GRAVITY);
        for (f, world_from_imu) in s.accel.iter_mut().zip(&s.world_from_imu) {
            *f += world_from_imu.inverse_transform_vector(&extra_up_in_world);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use nalgebra::UnitQuaternion;
    use proptest::prelude::*;

    #[test]
    fn level_and_upside_down() {
        let mut s = signals(2);
        s.world_from_imu = vec![UnitQuaternion::identity(), UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0)];
        let out = applied(&GravityMagnitude { g: 9.80 }, &s);
        assert!((out.accel[0] - s.accel[0] - Vector3::new(0.0, 0.0, -0.01)).norm() < 1e-12);
        assert!((out.accel[1] - s.accel[1] - Vector3::new(0.0, 0.0, 0.01)).norm() < 1e-12);
        assert!(GravityMagnitude { g: -1.0 }.validate().is_err());
    }

    #[test]
    fn suite() {
        super::super::test_support::suite((9.7..9.9f64).prop_map(|g| GravityMagnitude { g }));
    }
}
