//! `quantization`: the ADC rounds each axis to a multiple of its least significant bit:
//! real = lsb · round(x / lsb) (halves away from zero). An LSB of 0 means no rounding.

use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Output resolution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Quantization {
    /// Gyro resolution, rad/s (0 for none).
    pub gyro_lsb: f64,
    /// Accelerometer resolution, m/s² (0 for none).
    pub accel_lsb: f64,
}

impl ErrorTerm for Quantization {
    const NAME: &'static str = "quantization";

    fn identity() -> Self {
        Quantization { gyro_lsb: 0.0, accel_lsb: 0.0 }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "gyro_lsb", &[self.gyro_lsb])?;
        check_finite(Self::NAME, "accel_lsb", &[self.accel_lsb])?;
        check_range(Self::NAME, "gyro_lsb", self.gyro_lsb, self.gyro_lsb >= 0.0, ">= 0 rad/s")?;
        check_range(Self::NAME, "accel_lsb", self.accel_lsb, self.accel_lsb >= 0.0, ">= 0 m/s²")
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        for (x, lsb) in [(&mut s.gyro, self.gyro_lsb), (&mut s.accel, self.accel_lsb)] {
            if lsb > 0.0 {
                x.iter_mut().for_each(|v| v.apply(|c| *c = (*c / lsb).round() * lsb));
            }
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
    fn rounds_to_the_step() {
        let mut s = signals(2);
        s.gyro[0] = Vector3::new(0.26, -0.26, 0.24);
        let out = applied(&Quantization { gyro_lsb: 0.5, accel_lsb: 0.0 }, &s);
        assert_eq!(out.gyro[0], Vector3::new(0.5, -0.5, 0.0));
        assert_eq!(out.accel, s.accel);
        let fine = applied(&Quantization { gyro_lsb: 1e-3, accel_lsb: 1e-2 }, &s);
        assert!(max_diff(&fine.gyro, &s.gyro) <= 0.5e-3 + 1e-15);
        assert!(max_diff(&fine.accel, &s.accel) <= 0.5e-2 + 1e-15);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(
            (0.0..1e-2f64, 0.0..1e-1f64).prop_map(|(gyro_lsb, accel_lsb)| Quantization { gyro_lsb, accel_lsb }),
        );
    }
}
