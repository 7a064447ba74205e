//! `vibration`: a mechanical vibration of the mount (motor, engine, gait) felt by the
//! accelerometer: real = f + a ⊙ sin(2π f_v t + φ), t in s since the first sample.

use std::f64::consts::TAU;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, vec3, ErrorTerm, ImuSignals, PhysicsError, TermContext};

fn is_zero3(a: &[f64; 3]) -> bool {
    *a == [0.0; 3]
}

/// Sinusoidal vibration on the accelerometer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Vibration {
    /// Vibration frequency, Hz.
    pub frequency_hz: f64,
    /// Amplitude per axis, m/s².
    pub accel_amplitude: [f64; 3],
    /// Phase per axis at the first sample, rad (optional, default 0: an extension of the
    /// vocabulary so a fit can state the phase it found).
    #[serde(default, skip_serializing_if = "is_zero3")]
    pub phase_rad: [f64; 3],
}

impl ErrorTerm for Vibration {
    const NAME: &'static str = "vibration";

    fn identity() -> Self {
        Vibration { frequency_hz: 0.0, accel_amplitude: [0.0; 3], phase_rad: [0.0; 3] }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "frequency_hz", &[self.frequency_hz])?;
        check_finite(Self::NAME, "accel_amplitude", &self.accel_amplitude)?;
        check_finite(Self::NAME, "phase_rad", &self.phase_rad)?;
        check_range(Self::NAME, "frequency_hz", self.frequency_hz, self.frequency_hz >= 0.0, ">= 0 Hz")
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        let a = vec3(self.accel_amplitude);
        let phase = vec3(self.phase_rad);
        for i in 0..s.len() {
            let wt = TAU * self.frequency_hz * s.seconds_since_start(i);
            s.accel[i] += a.component_mul(&phase.map(|p| (wt + p).sin()));
        }
    }

    fn is_identity(&self) -> bool {
        self.accel_amplitude == [0.0; 3]
    }
}

impl Vibration {
    /// The vibration acceleration at time `t` s since the first sample, m/s².
    pub fn at(&self, t: f64) -> Vector3<f64> {
        let wt = TAU * self.frequency_hz * t;
        vec3(self.accel_amplitude).component_mul(&vec3(self.phase_rad).map(|p| (wt + p).sin()))
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn sinusoid_on_accel_only() {
        let s = signals(40);
        let v = Vibration { frequency_hz: 10.0, accel_amplitude: [0.1, 0.0, 0.2], phase_rad: [0.0, 0.0, std::f64::consts::FRAC_PI_2] };
        let out = applied(&v, &s);
        // 5 ms steps at 10 Hz: sample 5 is a quarter period.
        let d = out.accel[5] - s.accel[5];
        assert!((d - Vector3::new(0.1, 0.0, 0.0)).norm() < 1e-12, "{d:?}");
        let d0 = out.accel[0] - s.accel[0];
        assert!((d0 - Vector3::new(0.0, 0.0, 0.2)).norm() < 1e-12, "{d0:?}");
        assert!((out.accel[5] - s.accel[5] - v.at(0.025)).norm() < 1e-15);
        assert_eq!(out.gyro, s.gyro);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(
            (0.5..150.0f64, v3(0.1), v3(3.0)).prop_map(|(frequency_hz, accel_amplitude, phase_rad)| Vibration {
                frequency_hz,
                accel_amplitude,
                phase_rad,
            }),
        );
    }
}
