//! `gyro_g_sensitivity`: gyro output that depends on the specific force (a MEMS proof mass
//! deflected by acceleration). real = ω + G f, f the true specific force at the sensor.
//!
//! Applied before the accelerometer intrinsics (see the order in [`super`]), so `s.accel`
//! is still the true specific force when it runs.

use serde::{Deserialize, Serialize};

use super::{check_finite, flat, mat3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Gyro g-sensitivity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GyroGSensitivity {
    /// G, row-major, rad/s per m/s².
    pub matrix: [[f64; 3]; 3],
}

impl ErrorTerm for GyroGSensitivity {
    const NAME: &'static str = "gyro_g_sensitivity";

    fn identity() -> Self {
        GyroGSensitivity { matrix: [[0.0; 3]; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "matrix", &flat(&self.matrix))
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        let g = mat3(self.matrix);
        s.gyro.iter_mut().zip(&s.accel).for_each(|(omega, f)| *omega += g * f);
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn adds_g_times_specific_force() {
        let s = signals(10);
        // Only the z row, picking f_z: a level sensor at rest sees +9.81 on z.
        let out = applied(&GyroGSensitivity { matrix: [[0.0; 3], [0.0; 3], [0.0, 0.0, 1e-3]] }, &s);
        let d = out.gyro[5] - s.gyro[5];
        assert!(d.x == 0.0 && d.y == 0.0 && (d.z - 1e-3 * s.accel[5].z).abs() < 1e-15);
        assert_eq!(out.accel, s.accel);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(m3(1e-3).prop_map(|matrix| GyroGSensitivity { matrix }));
    }
}
