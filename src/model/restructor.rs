//! Restructor module (paper §III-A "Module Structure" and the reconstruction loss `L^R`): a
//! dilated causal CNN (five layers, kernel 7, dilations 1, 4, 16, 64, 1) that reconstructs the
//! normalised IMU input from the embedding with Gaussian noise added. Training only: it
//! shapes the Embedding through `L^R` and is not part of the exported model.
//!
//! Weight paths: `<path>/conv{l}`, `<path>/bn{l}` (see [`super::cnn`]).

use tch::{nn, Tensor};

use super::cnn::DilatedCausalCnn;
use super::{Config, INPUT_CHANNELS};

/// `embedding [B, T, E] → reconstruction of norm(u) [B, T, 6]`.
#[derive(Debug)]
pub struct Restructor {
    cnn: DilatedCausalCnn,
    noise_std: f64,
}

impl Restructor {
    /// Builds the CNN under `path` (`cfg.restructor`, input `cfg.embedding.dim` channels).
    pub fn new(cfg: &Config, path: &nn::Path) -> Self {
        let cnn = DilatedCausalCnn::new(&cfg.restructor, cfg.embedding.dim, INPUT_CHANNELS, cfg.restructor_norm(), cfg.dropout, path);
        Self { cnn, noise_std: cfg.restructor_noise_std }
    }

    /// Number of trainable scalars.
    pub fn parameter_count(&self) -> i64 {
        self.cnn.parameter_count()
    }

    /// Receptive field, samples.
    pub fn receptive_field(&self) -> i64 {
        self.cnn.receptive_field()
    }

    /// `embedding: [B, T, E]` → `[B, T, 6]`. With `train`, adds N(0, noise_std²) to the
    /// embedding first (torch's global RNG: seed it with `tch::manual_seed`).
    pub fn forward_t(&self, embedding: &Tensor, train: bool) -> Tensor {
        let input =
            if train && self.noise_std > 0.0 { embedding + embedding.randn_like() * self.noise_std } else { embedding.shallow_clone() };
        self.cnn.forward_t(&input.transpose(1, 2), train).transpose(1, 2)
    }
}
