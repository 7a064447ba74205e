//! The recording-drift memory (`train.recording_drift`, [`super::config::RecordingDrift`]): a
//! moving average, across steps, of each training recording's mean gyro error. One window's
//! mean error is noise-dominated at the level of a recording's residual bias (a few tenths of
//! a mrad/s, which a 100-s recording integrates into degrees); averaged over steps it is not.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use tch::Tensor;

/// Per training task (in `dataset.train` order), the moving average of its windows' mean gyro
/// error ω̂ − ω, rad/s, before bias correction; kept in the checkpoint so a resumed run goes on
/// with it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftMemory {
    /// Steps folded in.
    pub steps: u64,
    pub ema: Vec<Vector3<f64>>,
}

impl DriftMemory {
    pub fn new(tasks: usize) -> Self {
        Self { steps: 0, ema: vec![Vector3::zeros(); tasks] }
    }

    /// Folds in this step's errors (one per task) and returns the bias-corrected memory
    /// `ema / (1 − decay^steps)`, so the first steps are not pulled towards zero.
    pub fn update(&mut self, now: &[Vector3<f64>], decay: f64) -> Vec<Vector3<f64>> {
        assert_eq!(now.len(), self.ema.len(), "one error per task");
        self.steps += 1;
        let correction = 1.0 - decay.powi(self.steps.min(i32::MAX as u64) as i32);
        self.ema
            .iter_mut()
            .zip(now)
            .map(|(m, e)| {
                *m = *m * decay + e * (1.0 - decay);
                *m / correction
            })
            .collect()
    }

    /// The task-weighted RMS of a memory's norms, mrad/s (for the log).
    pub fn rms_mrad_s(memory: &[Vector3<f64>], weights: &[f64]) -> f64 {
        let total: f64 = weights.iter().sum();
        let sq: f64 = memory.iter().zip(weights).map(|(m, w)| w * m.norm_squared()).sum();
        (sq / total.max(f64::MIN_POSITIVE)).sqrt() * 1e3
    }
}

/// `weight · scale · Σ_i w_i clamp(b̄_i, ±delta)ᵀ ē_i` for this step's per-task errors
/// `errors: [n, 3]` (in the graph) and the memory `memory` (constants): its gradient is that of
/// `weight · scale · Σ_i w_i ρ_delta(b̄_i)` (ρ the Huber function, per axis) when the memory
/// tracks the errors' mean.
pub fn drift_term(errors: &Tensor, memory: &[Vector3<f64>], weights: &[f64], weight: f64, delta: f64, scale: f64) -> Tensor {
    let n = memory.len() as i64;
    let (kind, device) = (errors.kind(), errors.device());
    let flat: Vec<f64> = memory.iter().zip(weights).flat_map(|(m, w)| m.iter().map(move |v| v.clamp(-delta, delta) * w)).collect();
    let target = Tensor::from_slice(&flat).view([n, 3]).to_kind(kind).to_device(device);
    (errors * target).sum(kind) * (weight * scale)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::predict::to_vectors;

    #[test]
    fn the_memory_is_unbiased_from_the_first_step() {
        let mut m = DriftMemory::new(2);
        let first = m.update(&[Vector3::new(1e-3, 0.0, -2e-3), Vector3::zeros()], 0.95);
        assert!((first[0][0] - 1e-3).abs() < 1e-15 && (first[0][2] + 2e-3).abs() < 1e-15, "{first:?}");
        // A constant error stays the memory whatever the decay.
        for _ in 0..50 {
            let now = m.update(&[Vector3::new(1e-3, 0.0, -2e-3), Vector3::zeros()], 0.95);
            assert!((now[0][0] - 1e-3).abs() < 1e-12, "{now:?}");
        }
        // Noise averages out: ±1 alternating gives a memory far below 1.
        let mut m = DriftMemory::new(1);
        let mut last = Vector3::zeros();
        for k in 0..200 {
            let s = if k % 2 == 0 { 1.0 } else { -1.0 };
            last = m.update(&[Vector3::new(s, s, s)], 0.95)[0];
        }
        assert!(last[0].abs() < 0.03, "{last:?}");
    }

    #[test]
    fn the_term_pushes_each_task_against_its_own_memory() {
        let errors = Tensor::from_slice(&[1e-3f64, 0.0, 0.0, 0.0, 2e-3, 0.0]).view([2, 3]).set_requires_grad(true);
        let memory = [Vector3::new(5e-4, 0.0, 0.0), Vector3::new(0.0, -1e-3, 0.0)];
        let term = drift_term(&errors, &memory, &[0.25, 0.75], 2.0, 1e-3, 1e6);
        term.backward();
        let g = to_vectors(&errors.grad()).unwrap();
        // d/dē_i = weight · scale · w_i · b̄_i.
        assert!((g[0][0] - 2.0 * 1e6 * 0.25 * 5e-4).abs() < 1e-9, "{g:?}");
        assert!((g[1][1] + 2.0 * 1e6 * 0.75 * 1e-3).abs() < 1e-9, "{g:?}");
        assert_eq!(g[0][1], 0.0);
        // Beyond delta the push stops growing.
        let errors = errors.detach().set_requires_grad(true);
        drift_term(&errors, &memory, &[0.25, 0.75], 2.0, 2e-4, 1e6).backward();
        let g = to_vectors(&errors.grad()).unwrap();
        assert!((g[0][0] - 2.0 * 1e6 * 0.25 * 2e-4).abs() < 1e-9 && (g[1][1] + 2.0 * 1e6 * 0.75 * 2e-4).abs() < 1e-9, "{g:?}");
        assert!((DriftMemory::rms_mrad_s(&memory, &[1.0, 1.0]) - (0.5f64.powi(2) / 2.0 + 0.5).sqrt()).abs() < 1e-12);
    }
}
