//! `gyro_noise_density`: the real gyro's white noise is `factor` times the simulator's. It
//! rescales the white noise the `white_noise` term drew just before (recorded in
//! `ctx.history.gyro_white`): x ← x + (factor − 1) n, and the history becomes factor · n.
//! Without a `white_noise` term there is no noise to scale and it does nothing.

use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Scale of the gyro white noise relative to the simulator's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GyroNoiseDensity {
    /// Ratio of noise densities (real / simulator), ≥ 0.
    pub factor: f64,
}

impl ErrorTerm for GyroNoiseDensity {
    const NAME: &'static str = "gyro_noise_density";

    fn identity() -> Self {
        GyroNoiseDensity { factor: 1.0 }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "factor", &[self.factor])?;
        check_range(Self::NAME, "factor", self.factor, self.factor >= 0.0, ">= 0")
    }

    fn apply(&self, s: &mut ImuSignals, ctx: &mut TermContext) {
        let noise = &mut ctx.history.gyro_white;
        if noise.len() != s.len() {
            return;
        }
        for (x, n) in s.gyro.iter_mut().zip(noise.iter_mut()) {
            *x += *n * (self.factor - 1.0);
            *n *= self.factor;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::super::{apply_terms, Term, WhiteNoise};
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn scales_the_white_noise() {
        let s = signals(5000);
        let white = Term::WhiteNoise(WhiteNoise { gyro_noise_density: 1e-3, accel_noise_density: 1e-2 });
        let mut base = s.clone();
        let mut c0 = TermContext::new(9);
        apply_terms(std::slice::from_ref(&white), &mut base, &mut c0).unwrap();
        let mut scaled = s.clone();
        let mut c1 = TermContext::new(9);
        // Listed first, applied after the noise anyway.
        apply_terms(&[Term::GyroNoiseDensity(GyroNoiseDensity { factor: 1.5 }), white], &mut scaled, &mut c1).unwrap();
        for i in 0..s.len() {
            let n0 = base.gyro[i] - s.gyro[i];
            let n1 = scaled.gyro[i] - s.gyro[i];
            assert!((n1 - 1.5 * n0).norm() < 1e-15);
        }
        assert_eq!(scaled.accel, base.accel);
        assert!(max_diff(&c1.history.gyro_white, &c0.history.gyro_white.iter().map(|n| n * 1.5).collect::<Vec<_>>()) < 1e-18);
        // Alone, there is nothing to scale.
        assert_eq!(applied(&GyroNoiseDensity { factor: 2.0 }, &s), s);
    }

    #[test]
    fn suite() {
        super::super::test_support::suite((0.0..3.0f64).prop_map(|factor| GyroNoiseDensity { factor }));
    }
}
