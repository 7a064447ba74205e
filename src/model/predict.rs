//! Offline, full-sequence inference: the corrected gyro of a whole recording in one batch
//! forward (what training-time evaluation and `imu-fsda eval --model` use). The node's
//! streaming form must reproduce it sample for sample.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use tch::{Device, Kind, Tensor};

use super::export::{load_net, load_torchscript, ModelMetadata};
use super::net::InferenceNet;
use super::ModelError;
use crate::core::ImuSample;

/// `[1, T, 6]` tensor of raw IMU (gyro, accel) in `kind`.
pub fn imu_tensor(imu: &[ImuSample], kind: Kind) -> Tensor {
    let flat: Vec<f64> = imu.iter().flat_map(|s| [s.gyro.x, s.gyro.y, s.gyro.z, s.accel.x, s.accel.y, s.accel.z]).collect();
    Tensor::from_slice(&flat).reshape([1, imu.len() as i64, 6]).to_kind(kind)
}

/// `[…, 3]` rows of a tensor as f64 vectors.
pub(crate) fn to_vectors(t: &Tensor) -> Result<Vec<Vector3<f64>>, ModelError> {
    let v = Vec::<f64>::try_from(t.to_kind(Kind::Double).reshape([-1]))?;
    Ok(v.chunks_exact(3).map(|c| Vector3::new(c[0], c[1], c[2])).collect())
}

/// Corrected gyro for every sample with an eval-mode net (f64 weights give the reference
/// the streaming denoiser is compared with).
pub fn correct_with_net(net: &InferenceNet, imu: &[ImuSample]) -> Result<Vec<Vector3<f64>>, ModelError> {
    if imu.is_empty() {
        return Ok(Vec::new());
    }
    let out = net.try_forward(&imu_tensor(imu, net.kind()))?;
    to_vectors(&out)
}

/// The share `gain` of each correction `ω̂ − ω` (see
/// [`super::export::ModelMetadata::imu_correction_gains`]); `corrected` as it is for 1.
pub fn with_correction_gain(imu: &[ImuSample], mut corrected: Vec<Vector3<f64>>, gain: f64) -> Vec<Vector3<f64>> {
    for (c, s) in corrected.iter_mut().zip(imu) {
        *c = super::streaming::apply_correction_gain(&s.gyro, c, gain);
    }
    corrected
}

/// A model file given as `.pt`, `.ot` or `.json`: the metadata path beside it. A folder is
/// returned as it is, for the loader to refuse by name (`models/` is not `models.json`).
pub fn metadata_path(model: &Path) -> PathBuf {
    if model.is_dir() {
        return model.to_path_buf();
    }
    model.with_extension("json")
}

/// Corrected gyro from an exported model's TorchScript file (f32, as deployed), with IMU
/// `imu_name`'s Ĉ_ω (`None`: the model's own).
pub fn correct_with_torchscript(
    model: &Path,
    imu: &[ImuSample],
    imu_name: Option<&str>,
) -> Result<(Vec<Vector3<f64>>, ModelMetadata), ModelError> {
    let mut ts = load_torchscript(&metadata_path(model))?;
    ts.select_imu(imu_name)?;
    if imu.is_empty() {
        return Ok((Vec::new(), ts.metadata));
    }
    let out = ts.forward(&imu_tensor(imu, Kind::Float))?;
    Ok((to_vectors(&out)?, ts.metadata))
}

/// Corrected gyro from an exported model's weights, in f64 (the exact reference).
pub fn correct_with_weights_f64(
    model: &Path,
    imu: &[ImuSample],
    imu_name: Option<&str>,
) -> Result<(Vec<Vector3<f64>>, ModelMetadata), ModelError> {
    let loaded = load_net(&metadata_path(model), Device::Cpu)?;
    loaded.select_imu(imu_name)?;
    let net = loaded.net.inference().to_kind(Kind::Double);
    let gain = loaded.correction_gain();
    let corrected = correct_with_net(&net, imu)?;
    Ok((with_correction_gain(imu, corrected, gain), loaded.metadata))
}
