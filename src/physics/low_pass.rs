//! `low_pass`: a first-order low-pass filter on one or both sensors (the sensor's internal
//! bandwidth), 1/(1 + s/ω_c), ω_c = 2π cutoff_hz. Discretised per sample with the real
//! interval: y_n = y_{n−1} + (1 − e^{−ω_c dt_n}) (x_n − y_{n−1}), y_0 = x_0 (started in
//! steady state). Unity DC gain; at low frequency it delays the signal by ≈ 1/ω_c − dt/2.
//!
//! Applied after the noise (a real sensor's filter filters its own noise too).

use serde::{Deserialize, Serialize};

use super::{check_range, ErrorTerm, ImuSignals, PhysicsError, Sensor, TermContext};

/// Which sensors a low-pass filter acts on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LowPassSensor {
    Gyro,
    Accel,
    Both,
}

impl LowPassSensor {
    /// The sensors selected.
    pub fn sensors(self) -> &'static [Sensor] {
        match self {
            LowPassSensor::Gyro => &[Sensor::Gyro],
            LowPassSensor::Accel => &[Sensor::Accel],
            LowPassSensor::Both => &[Sensor::Gyro, Sensor::Accel],
        }
    }
}

/// First-order low-pass filter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LowPass {
    /// −3 dB cutoff, Hz (+∞, `.inf` in YAML, is the identity).
    pub cutoff_hz: f64,
    /// The sensor(s) filtered.
    pub sensor: LowPassSensor,
}

impl ErrorTerm for LowPass {
    const NAME: &'static str = "low_pass";

    fn identity() -> Self {
        LowPass { cutoff_hz: f64::INFINITY, sensor: LowPassSensor::Both }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_range(Self::NAME, "cutoff_hz", self.cutoff_hz, self.cutoff_hz > 0.0, "> 0 Hz (or .inf for none)")
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        if self.cutoff_hz.is_infinite() {
            return;
        }
        let omega_c = std::f64::consts::TAU * self.cutoff_hz;
        let gains: Vec<f64> = s.stamps_ns.windows(2).map(|w| 1.0 - (-omega_c * (w[1] - w[0]) as f64 * 1e-9).exp()).collect();
        for &sensor in self.sensor.sensors() {
            let x = s.channel_mut(sensor);
            for (n, gain) in gains.iter().enumerate() {
                let prev = x[n];
                x[n + 1] = prev + (x[n + 1] - prev) * *gain;
            }
        }
    }

    fn is_identity(&self) -> bool {
        self.cutoff_hz.is_infinite()
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use nalgebra::Vector3;
    use proptest::prelude::*;

    #[test]
    fn step_response_is_exponential() {
        let mut s = signals(100);
        s.gyro = (0..100).map(|k| if k == 0 { Vector3::zeros() } else { Vector3::new(1.0, 2.0, 3.0) }).collect();
        let fc = 5.0;
        let out = applied(&LowPass { cutoff_hz: fc, sensor: LowPassSensor::Gyro }, &s);
        let a = (-std::f64::consts::TAU * fc * 5e-3).exp();
        for n in 1..100 {
            let want = 1.0 - a.powi(n as i32);
            assert!((out.gyro[n].x - want).abs() < 1e-12 && (out.gyro[n].z - 3.0 * want).abs() < 1e-12, "{n}");
        }
        assert_eq!(out.accel, s.accel);
        let both = applied(&LowPass { cutoff_hz: fc, sensor: LowPassSensor::Both }, &s);
        assert_ne!(both.accel, s.accel);
        assert!(LowPass { cutoff_hz: 0.0, sensor: LowPassSensor::Both }.validate().is_err());
        assert!(LowPass { cutoff_hz: f64::NAN, sensor: LowPassSensor::Both }.validate().is_err());
    }

    #[test]
    fn suite() {
        let sensor = prop_oneof![Just(LowPassSensor::Gyro), Just(LowPassSensor::Accel), Just(LowPassSensor::Both)];
        super::super::test_support::suite((1.0..200.0f64, sensor).prop_map(|(cutoff_hz, sensor)| LowPass { cutoff_hz, sensor }));
    }
}
