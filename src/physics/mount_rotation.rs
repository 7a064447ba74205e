//! `mount_rotation`: the IMU is mounted rotated by R = Exp(rotvec) with respect to the body
//! frame the trajectory describes. Both sensors see the motion in the rotated frame:
//! ω_imu = Rᵀ ω, f_imu = Rᵀ f, and world_from_imu = world_from_body · R.

use serde::{Deserialize, Serialize};

use super::{check_finite, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Rotation of the sensor frame relative to the body frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MountRotation {
    /// Rotation vector (axis × angle) of body_from_imu, rad.
    pub rotvec: [f64; 3],
}

impl ErrorTerm for MountRotation {
    const NAME: &'static str = "mount_rotation";

    fn identity() -> Self {
        MountRotation { rotvec: [0.0; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "rotvec", &self.rotvec)
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        let body_from_imu = crate::so3::exp(&vec3(self.rotvec));
        let imu_from_body = body_from_imu.inverse().to_rotation_matrix().into_inner();
        for v in s.gyro.iter_mut().chain(s.accel.iter_mut()).chain(s.alpha_in_imu.iter_mut()) {
            *v = imu_from_body * *v;
        }
        s.world_from_imu.iter_mut().for_each(|q| *q *= body_from_imu);
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use nalgebra::Vector3;
    use proptest::prelude::*;

    #[test]
    fn quarter_turn_about_z_swaps_axes() {
        let s = signals(10);
        let out = applied(&MountRotation { rotvec: [0.0, 0.0, std::f64::consts::FRAC_PI_2] }, &s);
        // The sensor x axis is the body y axis: ω_imu = (ω_y, −ω_x, ω_z).
        let (w, r) = (s.gyro[3], out.gyro[3]);
        assert!((r - Vector3::new(w.y, -w.x, w.z)).norm() < 1e-14);
        let (f, g) = (s.accel[3], out.accel[3]);
        assert!((g - Vector3::new(f.y, -f.x, f.z)).norm() < 1e-14);
        // The world sees the same vector either way.
        assert!((out.world_from_imu[3] * g - s.world_from_imu[3] * f).norm() < 1e-12);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(v3(0.2).prop_map(|rotvec| MountRotation { rotvec }));
    }
}
