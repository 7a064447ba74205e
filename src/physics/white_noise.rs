//! `white_noise`: the simulator's white measurement noise, from continuous-time densities.
//! Per sample and axis, x + σ_d w with w ~ N(0, 1) and σ_d = σ/√dt ([`super::discretise`]),
//! dt the mean sample interval (one σ_d per stream, as the message covariance states it).
//!
//! Random: the draw ([`WhiteNoise::draw`]) uses the `gyro_white` / `accel_white` streams of
//! the context and is recorded in `ctx.history`; adding it is deterministic.

use nalgebra::Vector3;
use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use super::{check_finite, check_range, discretise, Density, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// White noise on both sensors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WhiteNoise {
    /// Gyro noise density, rad/s/√Hz.
    pub gyro_noise_density: f64,
    /// Accelerometer noise density, m/s²/√Hz.
    pub accel_noise_density: f64,
}

/// `n` standard normal 3-vectors from `rng`, σ times.
pub fn normal_vectors(rng: &mut impl Rng, n: usize, sigma: f64) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|_| {
            let w: [f64; 3] = [rng.sample(StandardNormal), rng.sample(StandardNormal), rng.sample(StandardNormal)];
            Vector3::from(w) * sigma
        })
        .collect()
}

impl WhiteNoise {
    /// Per-sample standard deviations (gyro rad/s, accel m/s²) at sample interval `dt` s.
    pub fn per_sample_std(&self, dt: f64) -> (f64, f64) {
        (discretise(self.gyro_noise_density, dt, Density::White), discretise(self.accel_noise_density, dt, Density::White))
    }

    /// Draw the noise for `s` (gyro, accel), in physical units. Zero densities draw nothing.
    pub fn draw(&self, s: &ImuSignals, ctx: &mut TermContext) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let (sg, sa) = self.per_sample_std(s.nominal_dt());
        let mut one = |concern, sigma: f64| {
            if sigma > 0.0 && sigma.is_finite() {
                normal_vectors(&mut ctx.rng(concern), s.len(), sigma)
            } else {
                vec![Vector3::zeros(); s.len()]
            }
        };
        (one("gyro_white", sg), one("accel_white", sa))
    }
}

/// x ← x + noise, and the noise added to the recorded history.
pub fn add_recorded(x: &mut [Vector3<f64>], noise: Vec<Vector3<f64>>, history: &mut Vec<Vector3<f64>>) {
    x.iter_mut().zip(&noise).for_each(|(v, e)| *v += e);
    if history.len() == noise.len() {
        history.iter_mut().zip(&noise).for_each(|(h, e)| *h += e);
    } else {
        *history = noise;
    }
}

impl ErrorTerm for WhiteNoise {
    const NAME: &'static str = "white_noise";

    fn identity() -> Self {
        WhiteNoise { gyro_noise_density: 0.0, accel_noise_density: 0.0 }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        for (param, v) in [("gyro_noise_density", self.gyro_noise_density), ("accel_noise_density", self.accel_noise_density)] {
            check_finite(Self::NAME, param, &[v])?;
            check_range(Self::NAME, param, v, v >= 0.0, ">= 0")?;
        }
        Ok(())
    }

    fn apply(&self, s: &mut ImuSignals, ctx: &mut TermContext) {
        if s.len() < 2 {
            return;
        }
        let (g, a) = self.draw(s, ctx);
        add_recorded(&mut s.gyro, g, &mut ctx.history.gyro_white);
        add_recorded(&mut s.accel, a, &mut ctx.history.accel_white);
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    fn long_signals(n: usize) -> ImuSignals {
        let mut s = signals(2);
        s.stamps_ns = (0..n as i64).map(|k| k * 2_500_000).collect(); // 400 Hz
        s.world_from_imu = vec![s.world_from_imu[0]; n];
        s.alpha_in_imu = vec![Vector3::zeros(); n];
        s.temperature_c = vec![25.0; n];
        s.gyro = vec![Vector3::zeros(); n];
        s.accel = vec![Vector3::zeros(); n];
        s
    }

    fn std_of(x: &[Vector3<f64>], axis: usize) -> f64 {
        let m = x.iter().map(|v| v[axis]).sum::<f64>() / x.len() as f64;
        (x.iter().map(|v| (v[axis] - m).powi(2)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
    }

    /// Overlapping-free Allan deviation at cluster size m samples.
    fn allan(x: &[f64], m: usize) -> f64 {
        let means: Vec<f64> = x.chunks_exact(m).map(|c| c.iter().sum::<f64>() / m as f64).collect();
        let d: f64 = means.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum();
        (d / (2.0 * (means.len() - 1) as f64)).sqrt()
    }

    #[test]
    fn sample_std_and_allan_deviation_match_the_density() {
        let n = 200_000;
        let mut s = long_signals(n);
        let term = WhiteNoise { gyro_noise_density: 1.7e-4, accel_noise_density: 2e-3 };
        let mut ctx = TermContext::new(11);
        term.apply(&mut s, &mut ctx);
        let dt: f64 = 2.5e-3;
        for axis in 0..3 {
            let sg = std_of(&s.gyro, axis);
            assert!((sg / (1.7e-4 / dt.sqrt()) - 1.0).abs() < 0.01, "gyro std {sg}");
            let sa = std_of(&s.accel, axis);
            assert!((sa / (2e-3 / dt.sqrt()) - 1.0).abs() < 0.01, "accel std {sa}");
            // White noise: Allan deviation σ(τ) = N/√τ.
            let x: Vec<f64> = s.gyro.iter().map(|v| v[axis]).collect();
            for m in [1usize, 10, 100] {
                let tau = m as f64 * dt;
                let ad = allan(&x, m);
                assert!((ad / (1.7e-4 / tau.sqrt()) - 1.0).abs() < 0.05, "m {m}: {ad}");
            }
        }
        assert_eq!(ctx.history.gyro_white, s.gyro, "the history is exactly what was added");
        // Independent streams per sensor, and reproducible.
        let mut again = long_signals(n);
        term.apply(&mut again, &mut TermContext::new(11));
        assert_eq!(again.gyro, s.gyro);
        let corr: f64 =
            s.gyro.iter().zip(&s.accel).map(|(g, a)| g.x * a.x).sum::<f64>() / n as f64 / (std_of(&s.gyro, 0) * std_of(&s.accel, 0));
        assert!(corr.abs() < 0.01, "{corr}");
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(
            (0.0..1e-3f64, 0.0..1e-2f64)
                .prop_map(|(gyro_noise_density, accel_noise_density)| WhiteNoise { gyro_noise_density, accel_noise_density }),
        );
    }
}
