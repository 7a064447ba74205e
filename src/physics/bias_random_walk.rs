//! `bias_random_walk`: the simulator's slowly wandering bias, a random walk driven by white
//! noise of density σ_b: b_0 = 0, b_k = b_{k−1} + σ_b √dt_k w_k ([`super::discretise`]),
//! dt_k the real interval between stamps, so Var b(t) = σ_b² t.
//!
//! Random: the walk is drawn from the `gyro_bias_walk` / `accel_bias_walk` streams of the
//! context and recorded in `ctx.history`; adding it is deterministic.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::white_noise::{add_recorded, normal_vectors};
use super::{check_finite, check_range, discretise, Density, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Bias random walk on both sensors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BiasRandomWalk {
    /// Gyro bias random-walk density, rad/s²/√Hz (rad/s/√s).
    pub gyro_bias_random_walk: f64,
    /// Accelerometer bias random-walk density, m/s³/√Hz.
    pub accel_bias_random_walk: f64,
}

impl BiasRandomWalk {
    /// Draw the walks for `s` (gyro rad/s, accel m/s²), starting at zero.
    pub fn draw(&self, s: &ImuSignals, ctx: &mut TermContext) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let mut one = |concern, density: f64| {
            if density <= 0.0 || s.is_empty() {
                return vec![Vector3::zeros(); s.len()];
            }
            let unit = normal_vectors(&mut ctx.rng(concern), s.len() - 1, 1.0);
            let mut walk = Vec::with_capacity(s.len());
            let mut b = Vector3::zeros();
            walk.push(b);
            for (w, stamps) in unit.iter().zip(s.stamps_ns.windows(2)) {
                let dt = (stamps[1] - stamps[0]) as f64 * 1e-9;
                b += w * discretise(density, dt, Density::RandomWalk);
                walk.push(b);
            }
            walk
        };
        (one("gyro_bias_walk", self.gyro_bias_random_walk), one("accel_bias_walk", self.accel_bias_random_walk))
    }
}

impl ErrorTerm for BiasRandomWalk {
    const NAME: &'static str = "bias_random_walk";

    fn identity() -> Self {
        BiasRandomWalk { gyro_bias_random_walk: 0.0, accel_bias_random_walk: 0.0 }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        for (param, v) in [("gyro_bias_random_walk", self.gyro_bias_random_walk), ("accel_bias_random_walk", self.accel_bias_random_walk)] {
            check_finite(Self::NAME, param, &[v])?;
            check_range(Self::NAME, param, v, v >= 0.0, ">= 0")?;
        }
        Ok(())
    }

    fn apply(&self, s: &mut ImuSignals, ctx: &mut TermContext) {
        let (g, a) = self.draw(s, ctx);
        add_recorded(&mut s.gyro, g, &mut ctx.history.gyro_bias_walk);
        add_recorded(&mut s.accel, a, &mut ctx.history.accel_bias_walk);
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn variance_grows_as_density_squared_times_time() {
        // 400 independent walks of 2000 steps at 100 Hz: Var b(t) = σ_b² t on every axis.
        let sigma_b = 4e-5;
        let mut s = signals(2000);
        s.stamps_ns = (0..2000i64).map(|k| k * 10_000_000).collect();
        let term = BiasRandomWalk { gyro_bias_random_walk: sigma_b, accel_bias_random_walk: 0.0 };
        let mut ctx = TermContext::new(3);
        let walks: Vec<Vec<Vector3<f64>>> = (0..400).map(|_| term.draw(&s, &mut ctx).0).collect();
        for k in [100usize, 500, 1999] {
            let t = k as f64 * 0.01;
            let var = walks.iter().map(|w| w[k].norm_squared()).sum::<f64>() / (3.0 * walks.len() as f64);
            assert!((var / (sigma_b * sigma_b * t) - 1.0).abs() < 0.12, "t {t}: {var} vs {}", sigma_b * sigma_b * t);
        }
        assert!(walks.iter().all(|w| w[0] == Vector3::zeros()));
        // Applying records the same walk it added.
        let mut ctx = TermContext::new(5);
        let out = {
            let mut o = s.clone();
            term.apply(&mut o, &mut ctx);
            o
        };
        let diff: Vec<_> = out.gyro.iter().zip(&s.gyro).map(|(a, b)| a - b).collect();
        assert!(max_diff(&diff, &ctx.history.gyro_bias_walk) < 1e-15);
        assert!(ctx.history.accel_bias_walk.iter().all(|b| *b == Vector3::zeros()));
    }

    #[test]
    fn suite() {
        super::super::test_support::suite(
            (0.0..1e-4f64, 0.0..1e-2f64).prop_map(|(gyro_bias_random_walk, accel_bias_random_walk)| BiasRandomWalk {
                gyro_bias_random_walk,
                accel_bias_random_walk,
            }),
        );
    }
}
