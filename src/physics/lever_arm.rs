//! `lever_arm`: the accelerometer sits at `offset` from the point whose motion the trajectory
//! describes, so it also feels the rotation: f + ω̇ × r + ω × (ω × r) (all in the sensor frame).
//!
//! Runs right after `mount_rotation`, so `s.gyro` and `s.alpha_in_imu` are still the true ω
//! and ω̇ of the sensor frame.

use serde::{Deserialize, Serialize};

use super::{check_finite, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Accelerometer lever arm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LeverArm {
    /// Position of the accelerometer relative to the reference point, sensor frame, m.
    pub offset: [f64; 3],
}

impl ErrorTerm for LeverArm {
    const NAME: &'static str = "lever_arm";

    fn identity() -> Self {
        LeverArm { offset: [0.0; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "offset", &self.offset)
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        let r = vec3(self.offset);
        for ((f, omega), alpha) in s.accel.iter_mut().zip(&s.gyro).zip(&s.alpha_in_imu) {
            *f += alpha.cross(&r) + omega.cross(&omega.cross(&r));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use nalgebra::Vector3;
    use proptest::prelude::*;

    #[test]
    fn centripetal_and_tangential() {
        let mut s = signals(3);
        s.gyro[1] = Vector3::new(0.0, 0.0, 2.0);
        s.alpha_in_imu[1] = Vector3::new(0.0, 0.0, 3.0);
        let out = applied(&LeverArm { offset: [0.5, 0.0, 0.0] }, &s);
        // Spinning about z at 2 rad/s, 0.5 m out on x: centripetal −ω²r = −2 on x;
        // tangential α r = 1.5 on y.
        assert!((out.accel[1] - s.accel[1] - Vector3::new(-2.0, 1.5, 0.0)).norm() < 1e-14);
        assert_eq!(out.gyro, s.gyro);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(v3(0.3).prop_map(|offset| LeverArm { offset }));
    }
}
