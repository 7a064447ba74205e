//! Adam with PyTorch's semantics (`torch.optim.Adam`: L2 weight decay added to the
//! gradient, bias-corrected moments), written out here so that its state (the moments and
//! the step count) can be checkpointed by name and a resumed run continues exactly.

use std::collections::BTreeMap;

use tch::{nn::VarStore, Kind, Tensor};

use super::error::TrainError;

/// Adam over the trainable variables of a VarStore, by name.
#[derive(Debug)]
pub struct Adam {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    /// Steps taken.
    pub step: i64,
    params: Vec<(String, Tensor)>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
}

impl Adam {
    /// PyTorch's defaults (β = 0.9, 0.999; ε = 1e-8) over `vs`'s trainable variables.
    pub fn new(vs: &VarStore) -> Self {
        let mut params: Vec<(String, Tensor)> = vs.variables().into_iter().filter(|(_, t)| t.requires_grad()).collect();
        params.sort_by(|a, b| a.0.cmp(&b.0));
        let m = params.iter().map(|(_, p)| p.zeros_like().detach()).collect();
        let v = params.iter().map(|(_, p)| p.zeros_like().detach()).collect();
        Self { beta1: 0.9, beta2: 0.999, eps: 1e-8, step: 0, params, m, v }
    }

    pub fn zero_grad(&mut self) {
        for (_, p) in &mut self.params {
            p.zero_grad();
        }
    }

    /// Global L2 norm of the current gradients (for logs).
    pub fn grad_norm(&self) -> f64 {
        let mut s = 0.0;
        for (_, p) in &self.params {
            let g = p.grad();
            if g.defined() {
                s += g.to_kind(Kind::Double).square().sum(Kind::Double).double_value(&[]);
            }
        }
        s.sqrt()
    }

    /// One update with learning rate `lr` and weight decay `wd`.
    pub fn step(&mut self, lr: f64, wd: f64) {
        self.step += 1;
        let bc1 = 1.0 - self.beta1.powi(self.step as i32);
        let bc2 = 1.0 - self.beta2.powi(self.step as i32);
        tch::no_grad(|| {
            for (i, (_, p)) in self.params.iter_mut().enumerate() {
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                let g = if wd > 0.0 { &g + &*p * wd } else { g.shallow_clone() };
                let m = &mut self.m[i];
                let v = &mut self.v[i];
                let _ = m.g_mul_scalar_(self.beta1);
                let _ = m.g_add_(&(&g * (1.0 - self.beta1)));
                let _ = v.g_mul_scalar_(self.beta2);
                let _ = v.g_add_(&(g.square() * (1.0 - self.beta2)));
                let denom = v.sqrt() / bc2.sqrt() + self.eps;
                let update = &*m / denom * (lr / bc1);
                let _ = p.g_sub_(&update);
            }
        });
    }

    /// The moments by name (`adam.m.<var>`, `adam.v.<var>`) for a checkpoint.
    pub fn state(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::new();
        for (i, (n, _)) in self.params.iter().enumerate() {
            out.push((format!("adam.m.{n}"), self.m[i].shallow_clone()));
            out.push((format!("adam.v.{n}"), self.v[i].shallow_clone()));
        }
        out
    }

    /// Restores moments saved by [`Adam::state`]; every variable must be present (else the
    /// resume is refused, naming the missing or misshapen moment).
    pub fn load_state(&mut self, step: i64, saved: &BTreeMap<String, Tensor>) -> Result<(), TrainError> {
        for (i, (n, p)) in self.params.iter().enumerate() {
            for (which, dst) in [("m", &mut self.m[i]), ("v", &mut self.v[i])] {
                let key = format!("adam.{which}.{n}");
                let src = saved.get(&key).ok_or_else(|| TrainError::Refused(format!("--resume: the checkpoint lacks {key}")))?;
                if src.size() != p.size() {
                    return Err(TrainError::Refused(format!("--resume: {key}: shape {:?}, expected {:?}", src.size(), p.size())));
                }
                tch::no_grad(|| dst.copy_(src));
            }
        }
        self.step = step;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{nn, Device};

    /// Same trajectory as torch.optim.Adam(lr=0.1, weight_decay=0.1) on f(x) = Σ x², x0 = (1, −2):
    /// reference values computed by hand from PyTorch's update rule (first step moves each
    /// coordinate by exactly lr against its gradient's sign).
    #[test]
    fn first_step_is_lr_times_sign() {
        let vs = VarStore::new(Device::Cpu);
        let x = vs.root().var_copy("x", &Tensor::from_slice(&[1.0f32, -2.0]));
        let mut adam = Adam::new(&vs);
        let loss = x.square().sum(Kind::Float);
        loss.backward();
        adam.step(0.1, 0.1);
        let v = Vec::<f32>::try_from(&x).unwrap();
        assert!((v[0] - 0.9).abs() < 1e-6 && (v[1] + 1.9).abs() < 1e-6, "{v:?}");
        let _ = nn::Init::Const(0.0);
    }
}
