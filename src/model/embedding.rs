//! Embedding module (paper §III-A "Framework" / "Module Structure"): a per-sample MLP that
//! maps the 6 normalised IMU channels to a representation shared across domains. It is the
//! module the few-shot strategy (§III-B, MAML) adapts, so its forward also runs on
//! functional "fast weights": [`Embedding::forward_with`] takes the parameters as a slice
//! (ordered as [`Embedding::parameter_names`]) instead of reading its own.
//!
//! Layers: `Linear → GELU` per hidden width, then `Linear → tanh` to `dim`; the bounded output
//! makes the Restructor's input noise (`Config::restructor_noise_std`) a fixed fraction of
//! the embedding's range, so the MLP cannot drown it by growing its output.
//!
//! Weight paths: `<path>/fc{l}/{weight,bias}`.

use tch::{nn, Tensor};

use super::cnn::torch_default_init;
use super::EmbeddingConfig;

/// The Embedding MLP, `[..., C_in] → [..., dim]`.
#[derive(Debug)]
pub struct Embedding {
    /// `[w0, b0, w1, b1, …]`: weights `[out, in]`, biases `[out]`.
    params: Vec<Tensor>,
    names: Vec<String>,
}

impl Embedding {
    /// Builds the MLP under `path` for `in_dim` input channels.
    pub fn new(cfg: &EmbeddingConfig, in_dim: i64, path: &nn::Path) -> Self {
        let mut widths = vec![in_dim];
        widths.extend_from_slice(&cfg.hidden);
        widths.push(cfg.dim);
        let mut params = Vec::new();
        let mut names = Vec::new();
        for (l, pair) in widths.windows(2).enumerate() {
            let (c_in, c_out) = (pair[0], pair[1]);
            let fc = path / format!("fc{l}");
            let init = torch_default_init(c_in);
            params.push(fc.var("weight", &[c_out, c_in], init));
            params.push(fc.var("bias", &[c_out], init));
            names.push(format!("fc{l}.weight"));
            names.push(format!("fc{l}.bias"));
        }
        Self { params, names }
    }

    /// Number of linear layers.
    pub fn num_layers(&self) -> usize {
        self.params.len() / 2
    }

    /// Output size.
    pub fn dim(&self) -> i64 {
        self.params[self.params.len() - 2].size()[0]
    }

    /// The module's own parameters (shallow clones sharing storage and gradients), in the
    /// order `forward_with` expects: `[fc0.weight, fc0.bias, fc1.weight, …]`.
    pub fn parameters(&self) -> Vec<Tensor> {
        self.params.iter().map(Tensor::shallow_clone).collect()
    }

    /// Names of [`Embedding::parameters`], relative to the module's path.
    pub fn parameter_names(&self) -> &[String] {
        &self.names
    }

    /// Forward with the module's own parameters.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        self.forward_with(x, &self.params)
    }

    /// Forward with the given parameters (e.g. MAML fast weights `θ_e − α∇L`), which must
    /// have the shapes of [`Embedding::parameters`]. `x: [..., C_in]` → `[..., dim]`.
    pub fn forward_with(&self, x: &Tensor, params: &[Tensor]) -> Tensor {
        assert_eq!(params.len(), self.params.len(), "embedding: {} parameters given, {} expected", params.len(), self.params.len());
        mlp_forward(x, params)
    }

    /// Number of trainable scalars.
    pub fn parameter_count(&self) -> i64 {
        self.params.iter().map(|p| p.numel() as i64).sum()
    }

    /// Detached copies of the parameters (for inference and export).
    pub fn detached(&self) -> Vec<Tensor> {
        tch::no_grad(|| self.params.iter().map(|p| p.detach().copy()).collect())
    }
}

/// The Embedding's function on explicit parameters `[w0, b0, w1, b1, …]`: GELU after every
/// layer but the last, tanh after the last.
pub fn mlp_forward(x: &Tensor, params: &[Tensor]) -> Tensor {
    let n = params.len() / 2;
    let mut h = x.shallow_clone();
    for l in 0..n {
        h = h.linear(&params[2 * l], Some(&params[2 * l + 1]));
        h = if l + 1 < n { h.gelu("none") } else { h.tanh() };
    }
    h
}
