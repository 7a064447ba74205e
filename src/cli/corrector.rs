//! Which gyro corrector the node and `replay` run: the model named by the `model`
//! parameter, or (empty) a pass-through with a loud warning.

use std::path::Path;

use anyhow::Context;
use imu_fsda::core::ImuSample;
use imu_fsda::infer::{GyroCorrector, ModelCorrector, PassThrough};
use imu_fsda::model::predict::{correct_with_torchscript, metadata_path};

/// Largest difference allowed between the deployed TorchScript file and the streaming form
/// at start-up (f32 vs f64 arithmetic), rad/s.
const SELF_CHECK_TOLERANCE: f64 = 1e-5;

/// The corrector and a status line for /diagnostics ("ok" when the model is loaded), with
/// IMU `imu`'s Ĉ_ω ("" = the model's own). A missing, corrupt or inconsistent model, or an
/// IMU it has no Ĉ_ω for, is an error here, before any input is read.
pub fn load_corrector(model: &str, imu: &str) -> anyhow::Result<(Box<dyn GyroCorrector>, String)> {
    if model.is_empty() {
        tracing::warn!("no model configured: the gyro is passed through uncorrected");
        return Ok((Box::new(PassThrough), "no model: pass-through".into()));
    }
    let path = Path::new(model);
    let imu = Some(imu).filter(|s| !s.is_empty());
    let (mut corrector, meta) = ModelCorrector::load_with_metadata(path, imu)
        .with_context(|| format!("loading model {model} (metadata {})", metadata_path(path).display()))?;
    self_check(path, imu, &mut corrector).with_context(|| format!("model {model} failed its start-up check"))?;
    let calib = match imu {
        None => "its own Ĉ_ω".to_string(),
        Some(n) => {
            let own = if meta.imu_gyro_calibrations.contains_key(n) { format!("IMU {n:?}'s Ĉ_ω") } else { "its own Ĉ_ω".into() };
            format!("{own}, IMU {n:?}'s correction gain {:.3}", corrector.denoiser.correction_gain())
        }
    };
    tracing::info!("model {} loaded: window N = {}, {} Hz, {calib}", corrector.name, corrector.window(), corrector.rate_hz);
    let known = meta.known_imus();
    if imu.is_none() && !known.is_empty() && meta.adapted_from.is_none() {
        // Unnamed, the IMU is a new one to the model: say which names it knows.
        tracing::info!(
            "model {} was trained on IMUs {known:?}: set imu_calibration to one of them to run as on that IMU; unnamed, the IMU is a new one to it (the power-on bias runs instead; model_on_new_imu runs it with its whole correction)",
            corrector.name
        );
    }
    Ok((Box::new(corrector), "ok".into()))
}

/// The node's start-up check for a model another command runs from its TorchScript file
/// (`eval`): the `.pt` must be the network its `.json` and `.ot` describe (a `.pt` of another
/// model beside them was scored silently before).
pub fn check_model_files(model: &Path, imu: Option<&str>) -> anyhow::Result<()> {
    let (mut corrector, _) = ModelCorrector::load_with_metadata(model, imu)
        .with_context(|| format!("loading model {} (metadata {})", model.display(), metadata_path(model).display()))?;
    self_check(model, imu, &mut corrector).with_context(|| format!("model {} failed its start-up check", model.display()))
}

/// Run the TorchScript file and the streaming form on the same synthetic input (longer
/// than the window) and require the same output: the `.pt` users deploy elsewhere and the
/// weights the node streams must be one model.
fn self_check(path: &Path, imu_name: Option<&str>, corrector: &mut ModelCorrector) -> anyhow::Result<()> {
    let n = corrector.window() + 64;
    let imu: Vec<ImuSample> = (0..n)
        .map(|k| {
            let t = k as f64 * 0.005;
            ImuSample {
                stamp_ns: k as i64 * 5_000_000,
                gyro: nalgebra::Vector3::new(0.3 * (1.3 * t).sin(), -0.2 * (0.7 * t).cos(), 0.1 * (2.1 * t).sin()),
                accel: nalgebra::Vector3::new(0.5 * (0.9 * t).sin(), 0.3 * (1.7 * t).cos(), 9.81),
            }
        })
        .collect();
    let (reference, _) = correct_with_torchscript(path, &imu, imu_name)?;
    // NaN-aware: a file that outputs NaN is not "within tolerance" (f64::max drops NaN).
    let worst = imu.iter().zip(&reference).map(|(s, r)| (corrector.step(&s.gyro, &s.accel) - r).amax()).fold(0.0, |w: f64, d| {
        if d.is_nan() || w.is_nan() {
            f64::NAN
        } else {
            w.max(d)
        }
    });
    corrector.reset();
    anyhow::ensure!(
        worst < SELF_CHECK_TOLERANCE,
        "TorchScript (.pt) and streaming (.json + .ot) outputs differ by {worst:.2e} rad/s (> {SELF_CHECK_TOLERANCE:e}): the files are not one model"
    );
    Ok(())
}
