//! Which gyro corrector the node and `replay` run: the model named by the `model`
//! parameter, or (empty) a pass-through with a loud warning.

use imu_fsda::infer::{BiasCorrector, GyroCorrector};

/// The corrector and a status line for /diagnostics ("ok" when the model is loaded).
pub fn load_corrector(model: &str) -> anyhow::Result<(Box<dyn GyroCorrector>, String)> {
    if model.is_empty() {
        tracing::warn!("no model configured: the gyro is passed through uncorrected");
        return Ok((Box::new(BiasCorrector { bias: nalgebra::Vector3::zeros() }), "no model: pass-through".into()));
    }
    anyhow::bail!("{model}: loading models is not built yet")
}
