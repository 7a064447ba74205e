//! The dilated causal CNN shared by the Restructor and Generator (paper §III-A, "Module
//! Structure", after Brossard et al. 2020) and by DIGDL.
//!
//! Causality as in DIGDL: the input is padded once on the left by `N − 1` copies of its first
//! sample (replication padding), then every conv is a "valid" conv, so the output has the
//! input's length and `y_n` depends on `x_{n−N+1} … x_n` only.
//!
//! Weight paths: `<path>/conv{l}/{weight,bias}` and `<path>/bn{l}/{weight,bias,running_mean,
//! running_var}` for layer `l`.

use tch::nn::{self, ModuleT};
use tch::Tensor;

use super::CnnConfig;

/// One conv layer of the CNN with its optional BatchNorm.
#[derive(Debug)]
struct CnnLayer {
    weight: Tensor,
    bias: Tensor,
    batch_norm: Option<nn::BatchNorm>,
    dilation: i64,
    /// Hidden layers are followed by (BN), GELU and Dropout; the output layer is linear.
    hidden: bool,
}

/// A dilated causal CNN `[B, C_in, T] → [B, C_out, T]`.
#[derive(Debug)]
pub struct DilatedCausalCnn {
    layers: Vec<CnnLayer>,
    left_pad: i64,
    dropout: f64,
}

/// A conv layer in inference form: BatchNorm folded into the weights.
#[derive(Debug)]
pub struct FoldedConv {
    /// `[C_out, C_in, k]`, detached.
    pub weight: Tensor,
    /// `[C_out]`, detached.
    pub bias: Tensor,
    /// Dilation, samples.
    pub dilation: i64,
    /// GELU after the conv (hidden layers).
    pub gelu: bool,
}

/// PyTorch's default init for a conv or linear layer: U(−1/√fan_in, 1/√fan_in) for weight
/// and bias. (tch's own default is Kaiming with a zero bias; DIGDL used PyTorch's.)
pub(crate) fn torch_default_init(fan_in: i64) -> nn::Init {
    let bound = 1.0 / (fan_in as f64).sqrt();
    nn::Init::Uniform { lo: -bound, up: bound }
}

impl DilatedCausalCnn {
    /// Builds the layers under `path`. `in_channels` and `out_channels` are the first and last
    /// widths; `cfg.hidden_channels` the ones in between.
    pub fn new(cfg: &CnnConfig, in_channels: i64, out_channels: i64, batch_norm: bool, dropout: f64, path: &nn::Path) -> Self {
        let n = cfg.kernel_sizes.len();
        let mut widths = Vec::with_capacity(n + 1);
        widths.push(in_channels);
        widths.extend_from_slice(&cfg.hidden_channels);
        widths.push(out_channels);
        let layers = (0..n)
            .map(|l| {
                let (c_in, c_out, k) = (widths[l], widths[l + 1], cfg.kernel_sizes[l]);
                let conv = path / format!("conv{l}");
                let init = torch_default_init(c_in * k);
                let weight = conv.var("weight", &[c_out, c_in, k], init);
                let bias = conv.var("bias", &[c_out], init);
                let hidden = l + 1 < n;
                let batch_norm = (hidden && batch_norm).then(|| {
                    let bn_cfg = nn::BatchNormConfig { ws_init: nn::Init::Const(1.0), ..Default::default() };
                    nn::batch_norm1d(path / format!("bn{l}"), c_out, bn_cfg)
                });
                CnnLayer { weight, bias, batch_norm, dilation: cfg.dilations[l], hidden }
            })
            .collect();
        Self { layers, left_pad: cfg.receptive_field() - 1, dropout }
    }

    /// Receptive field in samples.
    pub fn receptive_field(&self) -> i64 {
        self.left_pad + 1
    }

    /// Number of trainable scalars (conv weights and biases, BatchNorm γ and β).
    pub fn parameter_count(&self) -> i64 {
        let numel = |t: &Tensor| t.numel() as i64;
        self.layers
            .iter()
            .map(|l| {
                let bn = l.batch_norm.as_ref().map_or(0, |bn| bn.ws.as_ref().map_or(0, numel) + bn.bs.as_ref().map_or(0, numel));
                numel(&l.weight) + numel(&l.bias) + bn
            })
            .sum()
    }

    /// `x: [B, C_in, T]` → `[B, C_out, T]`. `train` selects batch statistics and dropout.
    pub fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        let mut h = x.replication_pad1d([self.left_pad, 0]);
        for layer in &self.layers {
            h = h.conv1d(&layer.weight, Some(&layer.bias), [1], [0], [layer.dilation], 1);
            if layer.hidden {
                if let Some(bn) = &layer.batch_norm {
                    h = bn.forward_t(&h, train);
                }
                h = h.gelu("none").dropout(self.dropout, train);
            }
        }
        h
    }

    /// The layers with BatchNorm folded in (eval-mode statistics), as detached copies:
    /// `W' = s·W`, `b' = s·(b − μ) + β`, `s = γ / √(σ² + ε)`.
    pub fn folded(&self) -> Vec<FoldedConv> {
        tch::no_grad(|| {
            self.layers
                .iter()
                .map(|layer| {
                    let (weight, bias) = match &layer.batch_norm {
                        None => (layer.weight.detach().copy(), layer.bias.detach().copy()),
                        Some(bn) => {
                            let eps = 1e-5; // nn::BatchNormConfig::default().eps, used by forward_t
                            let mut scale = (&bn.running_var + eps).rsqrt();
                            if let Some(gamma) = &bn.ws {
                                scale *= gamma;
                            }
                            let mut bias = (&layer.bias - &bn.running_mean) * &scale;
                            if let Some(beta) = &bn.bs {
                                bias += beta;
                            }
                            (&layer.weight * scale.unsqueeze(-1).unsqueeze(-1), bias)
                        }
                    };
                    FoldedConv { weight: weight.detach(), bias: bias.detach(), dilation: layer.dilation, gelu: layer.hidden }
                })
                .collect()
        })
    }
}

/// Forward of folded layers, `[B, C_in, T] → [B, C_out, T]` (the same causal padding).
pub fn folded_forward(layers: &[FoldedConv], left_pad: i64, x: &Tensor) -> Tensor {
    let mut h = x.replication_pad1d([left_pad, 0]);
    for layer in layers {
        h = h.conv1d(&layer.weight, Some(&layer.bias), [1], [0], [layer.dilation], 1);
        if layer.gelu {
            h = h.gelu("none");
        }
    }
    h
}

/// Receptive field of folded layers.
pub fn folded_receptive_field(layers: &[FoldedConv]) -> i64 {
    1 + layers.iter().map(|l| (l.weight.size()[2] - 1) * l.dilation).sum::<i64>()
}
