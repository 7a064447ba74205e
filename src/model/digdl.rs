//! DIGDL's CNN (Brossard, Bonnabel, Barrau, "Denoising IMU Gyroscopes with Deep Learning for
//! Open-Loop Attitude Estimation", RA-L 2020, §III): Conv1d 6→16 (k7, d1), 16→32 (k7, d4),
//! 32→64 (k7, d16), 64→128 (k7, d64), 128→3 (k1); BatchNorm, GELU, Dropout 0.1 after each
//! hidden conv; causal replication padding of 510 samples (receptive field 511). The model
//! output `ω̂ = (I + C) ω + σ ⊙ CNN(norm(u))` is assembled in [`super::net`].
//!
//! Weight paths: `<path>/conv{l}`, `<path>/bn{l}` (see [`super::cnn`]).

use tch::{nn, Tensor};

use super::cnn::{DilatedCausalCnn, FoldedConv};
use super::{Config, INPUT_CHANNELS, OUTPUT_CHANNELS};

/// `norm(u) [B, T, 6] → unscaled correction [B, T, 3]`.
#[derive(Debug)]
pub struct DigdlCnn {
    cnn: DilatedCausalCnn,
}

impl DigdlCnn {
    /// Builds the CNN under `path` from `cfg.digdl`.
    pub fn new(cfg: &Config, path: &nn::Path) -> Self {
        Self { cnn: DilatedCausalCnn::new(&cfg.digdl, INPUT_CHANNELS, OUTPUT_CHANNELS, cfg.generator_norm(), cfg.dropout, path) }
    }

    /// Number of trainable scalars.
    pub fn parameter_count(&self) -> i64 {
        self.cnn.parameter_count()
    }

    /// Receptive field, samples (511 with DIGDL's shape).
    pub fn receptive_field(&self) -> i64 {
        self.cnn.receptive_field()
    }

    /// `u_normalised: [B, T, 6]` → `[B, T, 3]`.
    pub fn forward_t(&self, u_normalised: &Tensor, train: bool) -> Tensor {
        self.cnn.forward_t(&u_normalised.transpose(1, 2), train).transpose(1, 2)
    }

    /// Inference form (BatchNorm folded).
    pub fn folded(&self) -> Vec<FoldedConv> {
        self.cnn.folded()
    }
}
