//! The dilated causal CNN shared by the Restructor and Generator (paper §III-A, "Module
//! Structure", after Brossard et al. 2020) and by DIGDL.
//!
//! Causality as in DIGDL: the input is padded once on the left by `N − 1` copies of its first
//! sample (replication padding), then every conv is a "valid" conv, so the output has the
//! input's length and `y_n` depends on `x_{n−N+1} … x_n` only.
//!
//! Weight paths: `<path>/conv{l}/{weight,bias}`, and `<path>/bn{l}/{weight,bias,running_mean,
//! running_var}` (BatchNorm) or `<path>/ln{l}/{weight,bias}` (channel LayerNorm) for layer `l`.

use tch::nn::{self, ModuleT};
use tch::Tensor;

use super::{CnnConfig, HiddenNorm};

/// ε of the channel LayerNorm (torch's default).
pub const LAYER_NORM_EPS: f64 = 1e-5;

/// The normalisation of one hidden layer.
#[derive(Debug)]
enum NormLayer {
    Batch(nn::BatchNorm),
    /// γ and β, `[C]` each.
    ChannelLayer(Tensor, Tensor),
}

/// One conv layer of the CNN with its optional normalisation.
#[derive(Debug)]
struct CnnLayer {
    weight: Tensor,
    bias: Tensor,
    norm: Option<NormLayer>,
    dilation: i64,
    /// Hidden layers are followed by (a norm), GELU and Dropout; the output layer is linear.
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
    /// Channel LayerNorm's γ and β after the conv, detached (it cannot be folded).
    pub layer_norm: Option<[Tensor; 2]>,
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
    pub fn new(cfg: &CnnConfig, in_channels: i64, out_channels: i64, norm: HiddenNorm, dropout: f64, path: &nn::Path) -> Self {
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
                let norm = match norm {
                    _ if !hidden => None,
                    HiddenNorm::None => None,
                    HiddenNorm::Batch => {
                        let bn_cfg = nn::BatchNormConfig { ws_init: nn::Init::Const(1.0), ..Default::default() };
                        Some(NormLayer::Batch(nn::batch_norm1d(path / format!("bn{l}"), c_out, bn_cfg)))
                    }
                    HiddenNorm::ChannelLayer => {
                        let ln = path / format!("ln{l}");
                        Some(NormLayer::ChannelLayer(
                            ln.var("weight", &[c_out], nn::Init::Const(1.0)),
                            ln.var("bias", &[c_out], nn::Init::Const(0.0)),
                        ))
                    }
                };
                CnnLayer { weight, bias, norm, dilation: cfg.dilations[l], hidden }
            })
            .collect();
        Self { layers, left_pad: cfg.receptive_field() - 1, dropout }
    }

    /// Receptive field in samples.
    pub fn receptive_field(&self) -> i64 {
        self.left_pad + 1
    }

    /// Number of trainable scalars (conv weights and biases, the norms' γ and β).
    pub fn parameter_count(&self) -> i64 {
        let numel = |t: &Tensor| t.numel() as i64;
        self.layers
            .iter()
            .map(|l| {
                let norm = match &l.norm {
                    None => 0,
                    Some(NormLayer::Batch(bn)) => bn.ws.as_ref().map_or(0, numel) + bn.bs.as_ref().map_or(0, numel),
                    Some(NormLayer::ChannelLayer(g, b)) => numel(g) + numel(b),
                };
                numel(&l.weight) + numel(&l.bias) + norm
            })
            .sum()
    }

    /// `x: [B, C_in, T]` → `[B, C_out, T]`. `train` selects batch statistics and dropout.
    pub fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        let mut h = x.replication_pad1d([self.left_pad, 0]);
        for layer in &self.layers {
            h = h.conv1d(&layer.weight, Some(&layer.bias), [1], [0], [layer.dilation], 1);
            if layer.hidden {
                match &layer.norm {
                    None => {}
                    Some(NormLayer::Batch(bn)) => h = bn.forward_t(&h, train),
                    Some(NormLayer::ChannelLayer(g, b)) => h = channel_layer_norm(&h, g, b),
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
                    let plain = || (layer.weight.detach().copy(), layer.bias.detach().copy());
                    let ((weight, bias), layer_norm) = match &layer.norm {
                        None => (plain(), None),
                        Some(NormLayer::ChannelLayer(g, b)) => (plain(), Some([g.detach().copy(), b.detach().copy()])),
                        Some(NormLayer::Batch(bn)) => {
                            let eps = 1e-5; // nn::BatchNormConfig::default().eps, used by forward_t
                            let mut scale = (&bn.running_var + eps).rsqrt();
                            if let Some(gamma) = &bn.ws {
                                scale *= gamma;
                            }
                            let mut bias = (&layer.bias - &bn.running_mean) * &scale;
                            if let Some(beta) = &bn.bs {
                                bias += beta;
                            }
                            ((&layer.weight * scale.unsqueeze(-1).unsqueeze(-1), bias), None)
                        }
                    };
                    FoldedConv { weight: weight.detach(), bias: bias.detach(), dilation: layer.dilation, layer_norm, gelu: layer.hidden }
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
        if let Some([g, b]) = &layer.layer_norm {
            h = channel_layer_norm(&h, g, b);
        }
        if layer.gelu {
            h = h.gelu("none");
        }
    }
    h
}

/// LayerNorm over the channels of each time step of `h: [B, C, T]` (γ, β: `[C]`). Uses no
/// other time step and no other batch element, so it is causal and the same in training and
/// inference.
pub fn channel_layer_norm(h: &Tensor, gamma: &Tensor, beta: &Tensor) -> Tensor {
    let c = h.size()[1];
    h.transpose(1, 2).layer_norm([c], Some(gamma), Some(beta), LAYER_NORM_EPS, false).transpose(1, 2)
}

/// Receptive field of folded layers.
pub fn folded_receptive_field(layers: &[FoldedConv]) -> i64 {
    1 + layers.iter().map(|l| (l.weight.size()[2] - 1) * l.dilation).sum::<i64>()
}

/// Test helper: every channel LayerNorm's γ and β of `vs` drawn away from (1, 0), so a
/// mix-up of the two or a norm left out shows in an output.
#[cfg(test)]
pub(crate) fn perturb_layer_norms(vs: &nn::VarStore) {
    tch::no_grad(|| {
        for (name, t) in vs.variables() {
            if name.contains(".ln") {
                let centre = if name.ends_with("weight") { 1.0 } else { 0.0 };
                t.shallow_clone().copy_(&(t.randn_like() * 0.3 + centre));
            }
        }
    });
}
