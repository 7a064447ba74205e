//! Generator module (paper §III-A "Module Structure", eq. for `ω'_n`): a dilated causal CNN
//! (five layers, kernel 7, dilations 1, 4, 16, 64, 1; receptive field 517 samples) from the
//! embedding window to the gyro correction, before the fixed per-axis scale σ.
//!
//! Weight paths: `<path>/conv{l}`, `<path>/bn{l}` (see [`super::cnn`]).

use tch::{nn, Tensor};

use super::cnn::{DilatedCausalCnn, FoldedConv};
use super::{Config, INPUT_CHANNELS, OUTPUT_CHANNELS};

/// `embedding [B, T, E] → unscaled correction [B, T, 3]` (with `generator_sees_imu`, the
/// input is `[embedding, normalised IMU]`, `[B, T, E + 6]`).
#[derive(Debug)]
pub struct Generator {
    cnn: DilatedCausalCnn,
}

impl Generator {
    /// Builds the CNN under `path` (`cfg.generator`; input `cfg.embedding.dim` channels, plus
    /// the 6 normalised IMU channels when `cfg.generator_sees_imu`).
    pub fn new(cfg: &Config, path: &nn::Path) -> Self {
        let inputs = cfg.embedding.dim + if cfg.generator_sees_imu { INPUT_CHANNELS } else { 0 };
        Self { cnn: DilatedCausalCnn::new(&cfg.generator, inputs, OUTPUT_CHANNELS, cfg.generator_norm(), cfg.dropout, path) }
    }

    /// Number of trainable scalars.
    pub fn parameter_count(&self) -> i64 {
        self.cnn.parameter_count()
    }

    /// Receptive field, samples: the model's window N.
    pub fn receptive_field(&self) -> i64 {
        self.cnn.receptive_field()
    }

    /// `embedding: [B, T, E]` → `[B, T, 3]`.
    pub fn forward_t(&self, embedding: &Tensor, train: bool) -> Tensor {
        self.cnn.forward_t(&embedding.transpose(1, 2), train).transpose(1, 2)
    }

    /// Inference form (BatchNorm folded).
    pub fn folded(&self) -> Vec<FoldedConv> {
        self.cnn.folded()
    }
}
