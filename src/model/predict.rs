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

/// Samples per forward of a long recording (5.5 min at 200 Hz): the activations of one
/// forward grow with its length (1.45 kB a sample, 2.6 GB for 30 min at 1 kHz in one).
const FORWARD_CHUNK: usize = 1 << 16;

/// A causal net's output over `imu`, forwarded in chunks of [`FORWARD_CHUNK`] samples, each
/// after the `window − 1` samples before it: the net sees what the whole-sequence forward
/// sees, so the output is the same (bar float rounding), at a bounded memory.
fn forward_in_chunks(
    imu: &[ImuSample],
    window: usize,
    chunk: usize,
    forward: impl Fn(&[ImuSample]) -> Result<Vec<Vector3<f64>>, ModelError>,
) -> Result<Vec<Vector3<f64>>, ModelError> {
    let mut out = Vec::with_capacity(imu.len());
    let mut start = 0;
    while start < imu.len() {
        let end = (start + chunk).min(imu.len());
        let from = start.saturating_sub(window.saturating_sub(1));
        let part = forward(&imu[from..end])?;
        out.extend_from_slice(&part[start - from..]);
        start = end;
    }
    Ok(out)
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
    let corrected = forward_torchscript(&ts, imu)?;
    Ok((corrected, ts.metadata))
}

/// A model's corrected gyro for every input sample, as the node runs it.
pub struct AtModelRate {
    pub corrected: Vec<Vector3<f64>>,
    pub metadata: ModelMetadata,
    /// The input's rate, Hz, when it was off the model's and run in the model's periods.
    pub resampled_from_hz: Option<f64>,
}

/// [`correct_with_torchscript`] on an IMU at any rate, as the node runs it: off the model's
/// rate ([`crate::model::rate_is_off`]), the model runs on the input's periods at its rate and
/// each sample gets the last period's correction ([`crate::resample`]).
pub fn correct_with_torchscript_at_model_rate(model: &Path, imu: &[ImuSample], imu_name: Option<&str>) -> Result<AtModelRate, ModelError> {
    let mut ts = load_torchscript(&metadata_path(model))?;
    ts.select_imu(imu_name)?;
    let rate = crate::core::nominal_rate_hz(imu);
    if imu.len() < 2 || !crate::model::rate_is_off(ts.metadata.rate_hz, rate) {
        let corrected = forward_torchscript(&ts, imu)?;
        return Ok(AtModelRate { corrected, metadata: ts.metadata, resampled_from_hz: None });
    }
    let (periods, last_period) = crate::resample::to_model_rate(imu, ts.metadata.rate_hz);
    let corrected = forward_torchscript(&ts, &periods)?;
    let corrected = crate::resample::corrections_to_input(imu, &periods, &corrected, &last_period);
    Ok(AtModelRate { corrected, metadata: ts.metadata, resampled_from_hz: Some(rate) })
}

/// The TorchScript model's corrected gyro for every sample of `imu`, forwarded in chunks.
fn forward_torchscript(ts: &super::export::TorchScriptModel, imu: &[ImuSample]) -> Result<Vec<Vector3<f64>>, ModelError> {
    if imu.is_empty() {
        return Ok(Vec::new());
    }
    let window = ts.metadata.window_n.max(1) as usize;
    forward_in_chunks(imu, window, FORWARD_CHUNK, |part| to_vectors(&ts.forward(&imu_tensor(part, Kind::Float))?))
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
    let window = loaded.metadata.window_n.max(1) as usize;
    let corrected = forward_in_chunks(imu, window, FORWARD_CHUNK, |part| correct_with_net(&net, part))?;
    Ok((with_correction_gain(imu, corrected, gain), loaded.metadata))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Mode;

    /// In chunks with the window's history before each, a random causal net gives the
    /// whole-sequence forward's output.
    #[test]
    fn a_chunked_forward_is_the_whole_one() {
        let (_vs, net) = crate::model::net::tests::random_net(Mode::FsdaF, 3, Kind::Double);
        let window = net.receptive_field() as usize;
        let net = net.inference();
        let imu: Vec<ImuSample> = (0..3000)
            .map(|k| {
                let t = k as f64 * 5e-3;
                ImuSample {
                    stamp_ns: k * 5_000_000,
                    gyro: Vector3::new((t * 3.0).sin(), (t * 1.3).cos() * 0.5, 0.02 * t),
                    accel: Vector3::new(0.3 * (t * 7.0).sin(), 0.1, 9.81),
                }
            })
            .collect();
        let whole = correct_with_net(&net, &imu).unwrap();
        let chunked = forward_in_chunks(&imu, window, 700, |part| correct_with_net(&net, part)).unwrap();
        assert_eq!(chunked.len(), whole.len());
        let worst = whole.iter().zip(&chunked).map(|(a, b)| (a - b).norm()).fold(0.0, f64::max);
        assert!(worst < 1e-12, "{worst}");
        // One sample too little history and the chunks' starts differ.
        let short = forward_in_chunks(&imu, window - 1, 700, |part| correct_with_net(&net, part)).unwrap();
        assert!(whole.iter().zip(&short).any(|(a, b)| (a - b).norm() > 1e-9));
    }
}
