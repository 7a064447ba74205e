//! The model's Embedding on samples of recordings, mapped to 2-D by t-SNE (the paper's
//! t-SNE figure: do EuRoC and TUM-VI samples share one representation?).
//!
//! The Embedding is a per-sample MLP on the normalised 6-channel IMU sample, so the points
//! are the Embedding of individual samples drawn uniformly (seeded) from each recording.
//! Weights come from `<model>.ot` + `<model>.json` (the TorchScript file only exposes
//! `forward`).

use std::path::Path;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Kind, Tensor};

use crate::core::ImuSample;
use crate::model::embedding::mlp_forward;
use crate::model::export::load_net;
use crate::model::predict::{imu_tensor, metadata_path};
use crate::model::ModelError;

/// The Embedding of an exported model, eval mode, f64.
pub struct EmbeddingModel {
    pub name: String,
    mean: Tensor,
    std: Tensor,
    params: Vec<Tensor>,
}

impl EmbeddingModel {
    /// Load `<model>.json` + `<model>.ot`; a model without an Embedding (DIGDL) is an error.
    pub fn load(model: &Path) -> Result<Self, ModelError> {
        let meta = metadata_path(model);
        let loaded = load_net(&meta, Device::Cpu)?;
        let inf = loaded.net.inference().to_kind(Kind::Double);
        if inf.embedding.is_empty() {
            return Err(ModelError::WrongKind {
                path: meta,
                detail: format!("a {:?} model has no Embedding to show (only FSDA and FSDA-F models have one)", loaded.metadata.mode),
            });
        }
        Ok(EmbeddingModel { name: loaded.metadata.name, mean: inf.mean, std: inf.std, params: inf.embedding })
    }

    /// Embedding of each sample, `[n][dim]`.
    pub fn embed(&self, samples: &[ImuSample]) -> Result<Vec<Vec<f64>>, ModelError> {
        if samples.is_empty() {
            return Ok(Vec::new());
        }
        let u = imu_tensor(samples, Kind::Double);
        let h = tch::no_grad(|| mlp_forward(&((u - &self.mean) / &self.std), &self.params));
        let dim = h.size().last().copied().unwrap_or(0) as usize;
        let flat = Vec::<f64>::try_from(h.reshape([-1]))?;
        Ok(flat.chunks_exact(dim.max(1)).map(<[f64]>::to_vec).collect())
    }
}

/// Up to `n` indices of `len` drawn without replacement, sorted; deterministic for `seed`.
/// Non-finite samples are never drawn.
pub fn sample_indices(samples: &[ImuSample], n: usize, seed: u64) -> Vec<usize> {
    let finite: Vec<usize> = samples.iter().enumerate().filter(|(_, s)| s.is_finite()).map(|(i, _)| i).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut idx: Vec<usize> =
        rand::seq::index::sample(&mut rng, finite.len(), n.min(finite.len())).into_iter().map(|k| finite[k]).collect();
    idx.sort_unstable();
    idx
}

/// A short label for a sequence folder: `dataset-room4_512_16` → `room4`.
pub fn short_name(name: &str) -> String {
    let n = name.strip_prefix("dataset-").unwrap_or(name);
    n.strip_suffix("_512_16").unwrap_or(n).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn sampling_is_seeded_sorted_and_skips_nan() {
        let mut s: Vec<ImuSample> =
            (0..1000).map(|k| ImuSample { stamp_ns: k, gyro: Vector3::zeros(), accel: Vector3::new(0.0, 0.0, 9.8) }).collect();
        s[10].gyro.x = f64::NAN;
        let a = sample_indices(&s, 300, 4);
        assert_eq!(a.len(), 300);
        assert!(a.windows(2).all(|w| w[0] < w[1]) && !a.contains(&10));
        assert_eq!(a, sample_indices(&s, 300, 4));
        assert_ne!(a, sample_indices(&s, 300, 5));
        assert_eq!(sample_indices(&s, 5000, 0).len(), 999);
        assert_eq!(short_name("dataset-room4_512_16"), "room4");
        assert_eq!(short_name("V1_01_easy"), "V1_01_easy");
    }
}
