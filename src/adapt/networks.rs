//! The adapted networks (docs/adaptation.md, steps 3–4): the calibration head's closed-form
//! first step, then the inner loop on the Embedding's fast weights (and the head), by Adam or
//! SGD, within the time budget.

use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{nn::VarStore, Tensor};

use super::{copy_net, dataset_cfg, AdaptConfig, AdaptError, Optimizer};
use crate::model::export::LoadedNet;
use crate::model::{ModelError, Net};
use crate::train::data::{self, Task};
use crate::train::fit::{embedding_and_extra_grads, embedding_inner_step};

/// The calibration head's VarStore names: Ĉ_ω's `gyro_calib.delta` and the bias of the
/// Generator's last conv (its output is scaled by σ and added to the gyro: a constant offset).
pub(super) fn calibration_head_names(vs: &VarStore) -> Vec<String> {
    let vars = vs.variables();
    let last_conv = vars.keys().filter_map(|n| n.strip_prefix("generator.conv")?.strip_suffix(".bias")?.parse::<usize>().ok()).max();
    let mut names: Vec<String> = last_conv.map(|l| format!("generator.conv{l}.bias")).into_iter().collect();
    if vars.contains_key("gyro_calib.delta") {
        names.push("gyro_calib.delta".into());
    }
    names
}

/// Closed-form first step of the calibration head: the constant gyro error e of the model on
/// the support set, from 0.25 s increments (`Log(δR_gtᵀ δR̂) ≈ j·dt·e` for a small constant
/// e), removed from the Generator's output bias (`ω̂ = Ĉ_ω ω + σ ⊙ g`, so bias −= e / σ). A
/// gradient step moves that bias by about lr·σ, far too slowly for a new IMU's bias of
/// several °/s; the steps that follow refine it. Returns e (rad/s).
fn init_output_bias(vs: &VarStore, head_names: &[String], net: &Net, support: &Task, cfg: &AdaptConfig) -> Result<[f64; 3], AdaptError> {
    const J: usize = 50;
    let rec = &support.rec;
    let corrected = crate::model::predict::correct_with_net(&net.inference(), &rec.imu)?;
    let (gt, valid) = data::ground_truth_at_imu(rec, &dataset_cfg(cfg));
    let mut sum = nalgebra::Vector3::zeros();
    let mut count = 0usize;
    let mut k = 0usize;
    while k + J < rec.imu.len() {
        let span_ok = valid[k..=k + J].iter().all(|v| *v);
        if let (true, Some(a), Some(b)) = (span_ok, gt[k], gt[k + J]) {
            let mut est = nalgebra::UnitQuaternion::identity();
            let mut secs = 0.0;
            for (w, pair) in corrected[k..k + J].iter().zip(rec.imu[k..=k + J].windows(2)) {
                let dt = (pair[1].stamp_ns - pair[0].stamp_ns) as f64 * 1e-9;
                est *= crate::so3::exp(&(w * dt));
                secs += dt;
            }
            let r = crate::so3::log(&((a.inverse() * b).inverse() * est));
            if secs > 0.0 && r.iter().all(|x| x.is_finite()) {
                sum += r / secs;
                count += 1;
            }
        }
        k += J;
    }
    if count < 10 {
        return Err(AdaptError::TooLittleData {
            what: "support",
            detail: format!(
                "{count} ground-truth-covered 0.25 s increments to estimate the gyro bias from, at least 10 needed (a ground truth \
                 slower than {:.0} Hz covers none: raise max_nearest_gt_ms in an `adapt --config` to half its period)",
                500.0 / cfg.max_nearest_gt_ms.max(1e-3)
            ),
        });
    }
    let e = sum / count as f64;
    let sigma = Vec::<f64>::try_from(&net.output_scale().to_kind(tch::Kind::Double)).map_err(ModelError::from)?;
    if let Some(bias_name) = head_names.iter().find(|n| n.starts_with("generator.")) {
        let vars = vs.variables();
        let delta: Vec<f64> = (0..3).map(|i| -e[i] / sigma[i].max(1e-12)).collect();
        let var = &vars[bias_name];
        tch::no_grad(|| {
            let d = Tensor::from_slice(&delta).to_kind(var.kind());
            let _ = var.shallow_clone().g_add_(&d);
        });
    }
    tracing::info!(
        "calibration head: constant gyro error of the model on the support set ({count} increments): [{:.4}, {:.4}, {:.4}] °/s, removed before the steps",
        e[0].to_degrees(),
        e[1].to_degrees(),
        e[2].to_degrees()
    );
    Ok([e[0], e[1], e[2]])
}

/// The networks adapted by the inner loop, with what it did.
pub(super) struct AdaptedNetworks {
    pub(super) vs: VarStore,
    pub(super) net: Net,
    pub(super) losses: Vec<f64>,
    pub(super) step_seconds: f64,
    pub(super) initial_bias: Option<[f64; 3]>,
}

/// The inner loop (docs/adaptation.md, step 4): first order, eval mode, on a copy's fast
/// weights only (θ_e, and the calibration head with `calibration`).
pub(super) fn adapt_networks(loaded: &LoadedNet, s_task: &Task, cfg: &AdaptConfig) -> Result<AdaptedNetworks, AdaptError> {
    let (mut vs, net) = copy_net(loaded)?;
    let mut fast: Vec<Tensor> = net.embedding_parameters().iter().map(|p| p.detach().copy().set_requires_grad(true)).collect();
    let head_names = if cfg.calibration { calibration_head_names(&vs) } else { Vec::new() };
    let head: Vec<Tensor> = {
        let vars = vs.variables();
        head_names.iter().map(|n| vars[n].shallow_clone().set_requires_grad(true)).collect()
    };
    let initial_bias = if cfg.calibration { Some(init_output_bias(&vs, &head_names, &net, s_task, cfg)?) } else { None };
    let mut head_adam = TensorAdam::new(&head);
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let win = cfg.window_samples.min(s_task.len());
    let refs = [s_task];
    let mut losses = Vec::with_capacity(cfg.steps);
    let mut adam = TensorAdam::new(&fast);
    let t_steps = Instant::now();
    for step in 0..cfg.steps {
        if cfg.cancel.is_cancelled() {
            return Err(AdaptError::Cancelled);
        }
        if t_steps.elapsed().as_secs_f64() > cfg.max_seconds {
            tracing::warn!("adaptation stopped after {step} steps: time budget of {} s reached", cfg.max_seconds);
            break;
        }
        let count = if win == s_task.len() { 1 } else { cfg.windows.max(1) };
        let batch = data::sample_windows(&refs, |t| (0, t.len()), count, win, &mut rng);
        let (l, next) = match cfg.optimizer {
            Optimizer::Sgd => {
                let (terms, next) = embedding_inner_step(&net, &cfg.loss, &batch, &fast, cfg.inner_lr, false, false);
                (terms.total.double_value(&[]), next)
            }
            Optimizer::Adam => {
                let (terms, grads) = embedding_and_extra_grads(&net, &cfg.loss, &batch, &fast, &head, false, false);
                let (g_fast, g_head) = grads.split_at(fast.len());
                let new_head = head_adam.step(&head, g_head, cfg.inner_lr);
                tch::no_grad(|| {
                    for (h, n) in head.iter().zip(&new_head) {
                        h.shallow_clone().copy_(n);
                    }
                });
                (terms.total.double_value(&[]), adam.step(&fast, g_fast, cfg.inner_lr))
            }
        };
        if !l.is_finite() {
            return Err(AdaptError::Diverged { step, loss: l });
        }
        losses.push(l);
        fast = next.iter().map(|t| t.detach().set_requires_grad(true)).collect();
        tracing::debug!("adapt step {step}: support loss {l:.4}");
    }
    let step_seconds = t_steps.elapsed().as_secs_f64();
    {
        let vars = vs.variables();
        tch::no_grad(|| -> Result<(), ModelError> {
            for (name, f) in net.embedding_parameter_names().iter().zip(&fast) {
                vars[name].shallow_clone().f_copy_(f)?;
            }
            Ok(())
        })?;
    }
    vs.unfreeze();
    Ok(AdaptedNetworks { vs, net, losses, step_seconds, initial_bias })
}

/// Adam (PyTorch's, no weight decay) over a list of plain tensors (the fast weights).
struct TensorAdam {
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    t: i32,
}

impl TensorAdam {
    fn new(params: &[Tensor]) -> Self {
        let z = || params.iter().map(|p| p.detach().zeros_like()).collect();
        TensorAdam { m: z(), v: z(), t: 0 }
    }

    fn step(&mut self, params: &[Tensor], grads: &[Tensor], lr: f64) -> Vec<Tensor> {
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8);
        self.t += 1;
        let (c1, c2) = (1.0 - b1.powi(self.t), 1.0 - b2.powi(self.t));
        tch::no_grad(|| {
            params
                .iter()
                .zip(grads)
                .zip(self.m.iter_mut().zip(self.v.iter_mut()))
                .map(|((p, g), (m, v))| {
                    let g = g.detach();
                    *m = &*m * b1 + &g * (1.0 - b1);
                    *v = &*v * b2 + g.square() * (1.0 - b2);
                    p.detach() - (&*m / c1) / ((&*v / c2).sqrt() + eps) * lr
                })
                .collect()
        })
    }
}
