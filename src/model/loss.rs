//! Losses (paper §III-A "Loss function" and §III-B: `L = L^R + γ L^D`):
//!
//! - `L^R = mean ‖R(E(norm(u)) + noise) − norm(u)‖²`, the Restructor's reconstruction MSE on the
//!   normalised input (gyro and accel on one scale);
//! - `L^D = Σ_j w_j · s · mean_{valid m, axes} ρ_δ(Log(δR^gt_{m,j} δR̂_{m,j}ᵀ))`, over
//!   non-overlapping increments of `j` samples (`m·j … (m+1)·j`), `ρ_δ` the Huber function.
//!   DIGDL's settings are the defaults: j ∈ {16, 32} with weights 1 and ½, δ = 0.005 rad,
//!   s = 10⁶, the first 5 increments of each sequence skipped (they see the padding). The
//!   residual is the paper's; DIGDL's code takes `Log(δR̂ᵀ δR^gt)` (`LossConfig::residual_frame`).
//!
//! `δR̂` integrates the corrected gyro with the real per-sample `dt` (`dt_k = t_{k+1} − t_k`),
//! never a fixed period. `δR^gt = R_{mj}ᵀ R_{(m+1)j}` from the ground-truth attitudes at the
//! IMU stamps; an increment counts only if every sample it spans has a valid ground truth
//! (the mask, e.g. false where the mocap had a gap) and a finite `dt > 0`.

use crate::setting::InvalidSetting;
use serde::{Deserialize, Serialize};
use tch::{Kind, Reduction, Tensor};

use super::net::NetOutput;
use super::so3_tensor::{
    increment_residual, increment_residual_at_end, increments_from_attitudes, increments_from_gyro, num_increments, quat_identity_like,
    so3_kind,
};

/// One term of `L^D`: increments over `samples` IMU samples, weighted by `weight`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IncrementTerm {
    /// j, samples (16 ≈ 80 ms at 200 Hz).
    pub samples: i64,
    /// w_j.
    pub weight: f64,
    /// This term's Huber threshold δ, rad (absent: the loss's `huber_delta_rad`). A long
    /// increment sums a bias error over its length: with DIGDL's δ its residual sits in the
    /// Huber function's linear part, whose minimum over recordings with different biases is a
    /// median — flat between the middle two — where a larger δ keeps it quadratic (a mean).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub huber_delta_rad: Option<f64>,
}

impl IncrementTerm {
    /// j samples weighted w, with the loss's Huber threshold.
    pub const fn new(samples: i64, weight: f64) -> Self {
        Self { samples, weight, huber_delta_rad: None }
    }
}

/// The body frame an increment's residual rotation vector is expressed in. Both give the same
/// angle; the Huber function is applied per axis, so in its linear part the two weigh a
/// residual differently (and give different gradients) when the body turns within the increment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResidualFrame {
    /// `Log(δR_gt δR̂ᵀ)`, the frame at the increment's start: the paper's formula.
    #[default]
    Start,
    /// `Log(δR̂ᵀ δR_gt)`, the frame at its end: what DIGDL's published code computes.
    End,
}

/// Loss hyper-parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LossConfig {
    /// The increment lengths and their weights (DIGDL: 16 → 1, 32 → ½).
    pub increments: Vec<IncrementTerm>,
    /// Huber threshold δ, rad (DIGDL: 0.005).
    pub huber_delta_rad: f64,
    /// Scale s of `L^D` (DIGDL: 10⁶).
    pub scale: f64,
    /// Increments skipped at the start of each sequence, whose window is mostly padding
    /// (DIGDL: 5).
    pub skip_first_increments: i64,
    /// When > 0, replaces `skip_first_increments`: every increment that starts within this
    /// many samples of the window's start is skipped (0: DIGDL's rule). Set to the network's receptive field so that no increment is scored
    /// on an output computed partly from padding: DIGDL's 5 × 16 samples suit its 16000-sample
    /// windows, but a 3000-sample window would otherwise score 17 % of its samples on
    /// outputs the deployed streaming model never produces.
    pub skip_first_samples: i64,
    /// With `skip_first_samples` > 0: every increment length starts counting at that sample
    /// (the first output computed without padding) instead of at the window's start, so no
    /// increment is lost to the alignment. The same outputs are scored, but a 3000-sample window
    /// after a 517-sample skip holds two increments of 1024 samples instead of one, and one of
    /// 2048 instead of none: the long terms, which see a residual bias, get the data.
    pub increments_from_skip: bool,
    /// γ in `L = w_R L^R + γ L^D`.
    pub gamma: f64,
    /// w_R in `L = w_R L^R + γ L^D` (the paper: 1). Unlike γ it leaves the orientation
    /// loss's scale, and so its balance against weight decay, unchanged; 0 trains the
    /// Embedding for the denoising alone (an ablation of the Restructor).
    pub reconstruction_weight: f64,
    /// Run the SO(3) part in f64 (as DIGDL does) whatever the network's kind.
    pub so3_f64: bool,
    /// The frame of each increment's residual (the paper's start frame by default).
    pub residual_frame: ResidualFrame,
}

impl Default for LossConfig {
    fn default() -> Self {
        Self {
            increments: vec![IncrementTerm::new(16, 1.0), IncrementTerm::new(32, 0.5)],
            huber_delta_rad: 0.005,
            scale: 1e6,
            skip_first_increments: 5,
            skip_first_samples: 0,
            increments_from_skip: false,
            gamma: 1.0,
            reconstruction_weight: 1.0,
            so3_f64: true,
            residual_frame: ResidualFrame::Start,
        }
    }
}

impl LossConfig {
    /// Refuses a loss that cannot be computed or scores nothing; `key` prefixes the message
    /// (`train.loss`, `adapt.loss`).
    pub fn validate(&self, key: &str) -> Result<(), InvalidSetting> {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        let non_negative = |x: f64| x.is_finite() && x >= 0.0;
        if self.increments.is_empty()
            || self.increments.iter().any(|i| i.samples < 1 || !non_negative(i.weight) || i.huber_delta_rad.is_some_and(|d| !positive(d)))
        {
            return Err(
                format!("{key}.increments: at least one, each with samples ≥ 1, a finite weight ≥ 0 and any huber_delta_rad > 0").into()
            );
        }
        if self.skip_first_samples < 0 || self.skip_first_increments < 0 {
            return Err(format!(
                "{key}.skip_first_samples ({}) and skip_first_increments ({}) must be ≥ 0",
                self.skip_first_samples, self.skip_first_increments
            )
            .into());
        }
        if !positive(self.huber_delta_rad)
            || !positive(self.scale)
            || !non_negative(self.gamma)
            || !non_negative(self.reconstruction_weight)
        {
            return Err(format!("{key}: huber_delta_rad and scale must be > 0, gamma and reconstruction_weight ≥ 0").into());
        }
        Ok(())
    }

    /// Increments of `j` samples skipped at the start of each window.
    pub fn skipped_increments(&self, j: i64) -> i64 {
        if self.skip_first_samples > 0 {
            (self.skip_first_samples + j - 1) / j
        } else {
            self.skip_first_increments
        }
    }

    /// Where increments of `j` samples are counted from in a window, and how many of them are
    /// then skipped: `(offset, skipped)`.
    pub fn increment_layout(&self, j: i64) -> (i64, i64) {
        if self.increments_from_skip && self.skip_first_samples > 0 {
            (self.skip_first_samples, 0)
        } else {
            (0, self.skipped_increments(j))
        }
    }

    /// A training window must be longer than this many samples for every increment length to
    /// score at least one increment.
    pub fn min_window_samples(&self) -> i64 {
        self.increments.iter().map(|i| self.min_window_samples_for(i.samples)).max().unwrap_or(1)
    }

    /// A window must be longer than this many samples to score one increment of `j` samples.
    pub fn min_window_samples_for(&self, j: i64) -> i64 {
        let (offset, skipped) = self.increment_layout(j);
        offset + j * (skipped + 1)
    }
}

/// The loss and its parts (scalars).
#[derive(Debug)]
pub struct LossTerms {
    /// `L^R + γ L^D` (just `γ L^D` without a reconstruction).
    pub total: Tensor,
    /// `L^R`, when the forward ran the Restructor.
    pub reconstruction: Option<Tensor>,
    /// `L^D` (before γ).
    pub increment: Tensor,
}

/// `L^R`: mean squared error over all elements.
pub fn reconstruction_loss(reconstruction: &Tensor, target: &Tensor) -> Tensor {
    (reconstruction - target).square().mean(None)
}

/// `L^D` for corrected gyro `gyro_hat: [B, T, 3]` (rad/s), `dt: [B, T]` (s), ground-truth
/// attitudes `gt_attitude: [B, T, 4]` (w, x, y, z; `world_from_body` at the IMU stamps;
/// non-finite entries count as invalid) and an optional validity mask `gt_valid: [B, T]`
/// (bool or 0/1). Returns a scalar of `gyro_hat`'s kind.
pub fn increment_loss(cfg: &LossConfig, gyro_hat: &Tensor, dt: &Tensor, gt_attitude: &Tensor, gt_valid: Option<&Tensor>) -> Tensor {
    let [omega, dt, gt, sample_bad, dt_bad] = sanitised(cfg, gyro_hat, dt, gt_attitude, gt_valid);
    let kind = omega.kind();
    let mut terms = Vec::with_capacity(cfg.increments.len());
    for term in &cfg.increments {
        let Some(Scored { residual, valid3, .. }) = scored_increments(cfg, term.samples, &omega, &dt, &gt, &sample_bad, &dt_bad) else {
            continue;
        };
        let huber = residual.huber_loss(&residual.zeros_like(), Reduction::None, term.huber_delta_rad.unwrap_or(cfg.huber_delta_rad));
        let count = valid3.sum(kind).clamp_min(1.0);
        terms.push((huber * &valid3).sum(kind) / count * (cfg.scale * term.weight));
    }
    let total = terms.into_iter().fold(Tensor::zeros([], (kind, omega.device())), |acc, t| acc + t);
    total.to_kind(gyro_hat.kind())
}

/// One increment length's residuals in a window, as `increment_loss` scores them.
struct Scored {
    /// `[B, M, 3]` rotation vectors, zero where not scored.
    residual: Tensor,
    /// `[B, M, 3]`, 1 where scored.
    valid3: Tensor,
}

/// The scored increments of `j` samples (layout and mask of `increment_loss`), from sanitised
/// inputs (`omega`, `dt`, `gt` of the SO(3) kind; `sample_bad`, `dt_bad`: `[B, 1, T]`, 1 where
/// bad); `None` when the window holds none.
fn scored_increments(
    cfg: &LossConfig,
    j: i64,
    omega: &Tensor,
    dt: &Tensor,
    gt: &Tensor,
    sample_bad: &Tensor,
    dt_bad: &Tensor,
) -> Option<Scored> {
    assert!(j >= 1, "increment length must be ≥ 1");
    let (kind, b, t) = (omega.kind(), omega.size()[0], omega.size()[1]);
    let (offset, skipped) = cfg.increment_layout(j);
    if t <= offset {
        return None;
    }
    let tw = t - offset;
    let (omega, dt, gt) = (omega.narrow(1, offset, tw), dt.narrow(1, offset, tw), gt.narrow(1, offset, tw));
    let (sample_bad, dt_bad) = (sample_bad.narrow(2, offset, tw), dt_bad.narrow(2, offset, tw));
    let m = num_increments(tw, j);
    if m <= skipped {
        return None;
    }
    let estimate = increments_from_gyro(&omega, &dt, j);
    let truth = increments_from_attitudes(&gt, j);
    // Rotation vectors, [B, M, 3].
    let residual = match cfg.residual_frame {
        ResidualFrame::Start => increment_residual(&truth, &estimate),
        ResidualFrame::End => increment_residual_at_end(&truth, &estimate),
    };
    // Increment m is valid when samples mj … (m+1)j have ground truth and mj … (m+1)j − 1 a good dt.
    let gt_gap = sample_bad.narrow(2, 0, m * j + 1).max_pool1d([j + 1], [j], [0], [1], false).squeeze_dim(1);
    let dt_gap = dt_bad.narrow(2, 0, m * j).max_pool1d([j], [j], [0], [1], false).squeeze_dim(1);
    let not_skipped = Tensor::arange(m, (kind, omega.device())).ge(skipped as f64).to_kind(kind).expand([b, m], false);
    let valid = (gt_gap.maximum(&dt_gap) * -1.0 + 1.0) * not_skipped; // [B, M]
    let valid3 = valid.unsqueeze(-1).expand([b, m, 3], false);
    let residual = residual.where_self(&valid3.gt(0.5), &residual.zeros_like());
    Some(Scored { residual, valid3 })
}

/// Sanitised SO(3)-kind inputs of the increment terms: `(omega, dt, gt, sample_bad, dt_bad)`.
fn sanitised(cfg: &LossConfig, gyro_hat: &Tensor, dt: &Tensor, gt_attitude: &Tensor, gt_valid: Option<&Tensor>) -> [Tensor; 5] {
    let kind = so3_kind(gyro_hat.kind(), cfg.so3_f64);
    let omega = gyro_hat.to_kind(kind);
    let gt = gt_attitude.to_kind(kind);
    let dt = dt.to_kind(kind);
    let mut sample_ok = gt.isfinite().all_dim(-1, false);
    if let Some(mask) = gt_valid {
        sample_ok = sample_ok.logical_and(&mask.to_kind(Kind::Bool));
    }
    let dt_ok = dt.isfinite().logical_and(&dt.gt(0.0));
    // Invalid entries get harmless values (and are masked), so no NaN reaches the graph.
    let gt = gt.where_self(&sample_ok.unsqueeze(-1), &quat_identity_like(&gt));
    let dt = dt.where_self(&dt_ok, &dt.zeros_like());
    let sample_bad = sample_ok.logical_not().to_kind(kind).unsqueeze(1); // [B, 1, T]
    let dt_bad = dt_ok.logical_not().to_kind(kind).unsqueeze(1);
    [omega, dt, gt, sample_bad, dt_bad]
}

/// `L = w_R L^R + γ L^D` from a forward's output.
pub fn total_loss(cfg: &LossConfig, out: &NetOutput, dt: &Tensor, gt_attitude: &Tensor, gt_valid: Option<&Tensor>) -> LossTerms {
    let increment = increment_loss(cfg, &out.gyro, dt, gt_attitude, gt_valid);
    let reconstruction = out.reconstruction.as_ref().map(|r| reconstruction_loss(r, &out.input_normalised));
    let total = match &reconstruction {
        Some(r) => r * cfg.reconstruction_weight + &increment * cfg.gamma,
        None => &increment * cfg.gamma,
    };
    LossTerms { total, reconstruction, increment }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::so3_tensor::{prefix_products, quat_exp};
    use tch::Device;

    const F64: (Kind, Device) = (Kind::Double, Device::Cpu);

    /// Attitudes integrated from `omega` with `dt` (R_{n+1} = R_n Exp(ω_n dt_n)), `[B, T, 4]`.
    fn integrate(omega: &Tensor, dt: &Tensor) -> Tensor {
        let t = omega.size()[1];
        let steps = quat_exp(&(omega.narrow(1, 0, t - 1) * dt.narrow(1, 0, t - 1).unsqueeze(-1)));
        let id = quat_identity_like(&steps.narrow(1, 0, 1));
        prefix_products(&Tensor::cat(&[id, steps], 1))
    }

    /// Two recordings of 65 samples at 5 ms, random rates of scale `rate` rad/s, and their
    /// exact attitudes: `(omega, dt, gt)`.
    fn random_motion(seed: i64, rate: f64) -> (Tensor, Tensor, Tensor) {
        tch::manual_seed(seed);
        let omega = Tensor::randn([2, 65, 3], F64) * rate;
        let dt = Tensor::full([2, 65], 0.005, F64);
        let gt = integrate(&omega, &dt);
        (omega, dt, gt)
    }

    fn small_cfg() -> LossConfig {
        LossConfig {
            increments: vec![IncrementTerm::new(4, 1.0), IncrementTerm::new(8, 0.5)],
            skip_first_increments: 1,
            ..Default::default()
        }
    }

    #[test]
    fn zero_for_the_true_gyro_and_positive_otherwise() {
        tch::manual_seed(3);
        let omega = Tensor::randn([2, 41, 3], F64);
        let dt = Tensor::rand([2, 41], F64) * 0.002 + 0.004;
        let gt = integrate(&omega, &dt);
        let cfg = small_cfg();
        assert!(increment_loss(&cfg, &omega, &dt, &gt, None).double_value(&[]) < 1e-12);
        let biased = &omega + 0.01;
        assert!(increment_loss(&cfg, &biased, &dt, &gt, None).double_value(&[]) > 1e-3);
        // The real dt matters: a fixed 5 ms is wrong here.
        let fixed = dt.full_like(0.005);
        assert!(increment_loss(&cfg, &omega, &fixed, &gt, None).double_value(&[]) > 1e-3);
    }

    /// Two recordings whose gyros need different constant corrections b₁, b₂ (a bias that
    /// changes from day to day), scored as one batch with a common correction c: with δ far
    /// below the long increment's residual every c between b₁ and b₂ costs the same (a median
    /// of two), with a per-term δ above it only the mean is the minimum.
    #[test]
    fn a_per_term_delta_turns_the_flat_median_into_a_mean() {
        let (omega, dt, gt) = random_motion(5, 0.3);
        let need = Tensor::from_slice(&[0.0, 0.02]).reshape([2, 1, 1]); // b₁, b₂ rad/s
        let loss_at = |delta: Option<f64>, c: f64| {
            let cfg = LossConfig {
                increments: vec![IncrementTerm { samples: 64, weight: 1.0, huber_delta_rad: delta }],
                skip_first_increments: 0,
                huber_delta_rad: 1e-5,
                ..Default::default()
            };
            increment_loss(&cfg, &(&omega - &need + c), &dt, &gt, None).double_value(&[])
        };
        let (quarter, mean) = (0.005, 0.01);
        let (flat_q, flat_m) = (loss_at(None, quarter), loss_at(None, mean));
        assert!((flat_q - flat_m).abs() < 1e-3 * flat_m, "linear part: {flat_q} vs {flat_m}");
        let (quad_q, quad_m) = (loss_at(Some(1.0), quarter), loss_at(Some(1.0), mean));
        assert!(quad_q > 1.2 * quad_m, "quadratic: {quad_q} vs {quad_m}");
    }

    /// The residual's frame only matters in the Huber function's linear part: with δ above every
    /// residual the loss is half the mean squared angle in either frame; with a small δ and a
    /// turning body the per-axis sums differ.
    #[test]
    fn the_residual_frame_matters_only_in_the_linear_part() {
        let (omega, dt, gt) = random_motion(8, 2.0);
        let biased = &omega + Tensor::from_slice(&[0.05, -0.03, 0.02]);
        let loss = |frame: ResidualFrame, delta: f64| {
            let cfg = LossConfig {
                increments: vec![IncrementTerm::new(32, 1.0)],
                skip_first_increments: 0,
                huber_delta_rad: delta,
                residual_frame: frame,
                ..Default::default()
            };
            increment_loss(&cfg, &biased, &dt, &gt, None).double_value(&[])
        };
        let (qs, qe) = (loss(ResidualFrame::Start, 1.0), loss(ResidualFrame::End, 1.0));
        assert!((qs - qe).abs() < 1e-9 * qs, "quadratic part: {qs} vs {qe}");
        let (ls, le) = (loss(ResidualFrame::Start, 1e-4), loss(ResidualFrame::End, 1e-4));
        assert!((ls - le).abs() > 1e-3 * ls, "linear part: {ls} vs {le}");
    }

    #[test]
    fn gaps_are_masked_and_never_nan() {
        tch::manual_seed(4);
        let omega = Tensor::randn([1, 33, 3], F64);
        let dt = Tensor::full([1, 33], 0.005, F64);
        let gt = integrate(&omega, &dt);
        // Corrupt the ground truth in the 3rd 4-sample increment (samples 8…12) and mark it.
        let _ = gt.narrow(1, 10, 1).fill_(f64::NAN);
        let cfg = LossConfig { increments: vec![IncrementTerm::new(4, 1.0)], skip_first_increments: 0, ..Default::default() };
        let wrong = omega.copy();
        let _ = wrong.narrow(1, 9, 1).fill_(5.0); // a wrong estimate inside the gap only
        let w = wrong.set_requires_grad(true);
        let loss = increment_loss(&cfg, &w, &dt, &gt, None);
        assert!(loss.double_value(&[]) < 1e-12, "the gap must be masked: {}", loss.double_value(&[]));
        let g = Tensor::run_backward(&[&loss], &[&w], false, false).pop().unwrap();
        assert!(bool::try_from(g.isfinite().all()).unwrap());
        // An explicit mask does the same.
        let gt_clean = integrate(&omega, &dt);
        let mask = Tensor::ones([1, 33], F64);
        let _ = mask.narrow(1, 10, 1).fill_(0.0);
        assert!(increment_loss(&cfg, &wrong, &dt, &gt_clean, Some(&mask)).double_value(&[]) < 1e-12);
        assert!(increment_loss(&cfg, &wrong, &dt, &gt_clean, None).double_value(&[]) > 1.0);
    }

    #[test]
    fn gradient_matches_finite_differences() {
        tch::manual_seed(5);
        let truth = Tensor::randn([1, 25, 3], F64) * 0.5;
        let dt = Tensor::rand([1, 25], F64) * 0.002 + 0.004;
        let gt = integrate(&truth, &dt);
        // Errors on both sides of δ: quadratic and linear Huber branches.
        let estimate = &truth + Tensor::randn([1, 25, 3], F64) * 0.3;
        let cfg = LossConfig { scale: 1.0, skip_first_increments: 0, ..small_cfg() };
        let x = estimate.detach().set_requires_grad(true);
        let loss = increment_loss(&cfg, &x, &dt, &gt, None);
        let g = Vec::<f64>::try_from(&Tensor::run_backward(&[&loss], &[&x], false, false)[0].flatten(0, -1)).unwrap();
        let base = Vec::<f64>::try_from(&estimate.flatten(0, -1)).unwrap();
        let h = 1e-6;
        for (i, gi) in g.iter().enumerate() {
            let at = |d: f64| {
                let mut v = base.clone();
                v[i] += d;
                increment_loss(&cfg, &Tensor::from_slice(&v).reshape([1, 25, 3]), &dt, &gt, None).double_value(&[])
            };
            let fd = (at(h) - at(-h)) / (2.0 * h);
            assert!((fd - gi).abs() < 1e-7 * (1.0 + fd.abs()), "[{i}]: autograd {gi} vs fd {fd}");
        }
    }

    #[test]
    fn warm_up_samples_are_not_scored() {
        tch::manual_seed(5);
        let omega = Tensor::randn([1, 60, 3], F64) * 0.5;
        let dt = Tensor::full([1, 60], 0.005, F64);
        let gt = integrate(&omega, &dt);
        // A gross error at sample 10 only: inside the first 12 samples.
        let wrong = omega.copy();
        let _ = wrong.narrow(1, 10, 1).fill_(3.0);
        let cfg = LossConfig { skip_first_increments: 0, ..small_cfg() };
        assert!(increment_loss(&cfg, &wrong, &dt, &gt, None).double_value(&[]) > 1.0);
        // Increments of 4 starting at 0, 4, 8 and of 8 starting at 0, 8 are skipped: all of them.
        let warm = LossConfig { skip_first_samples: 12, ..cfg.clone() };
        assert_eq!((warm.skipped_increments(4), warm.skipped_increments(8)), (3, 2));
        assert!(increment_loss(&warm, &wrong, &dt, &gt, None).double_value(&[]).abs() < 1e-12);
        // Elsewhere it is still scored.
        let late = omega.copy();
        let _ = late.narrow(1, 30, 1).fill_(3.0);
        assert!(increment_loss(&warm, &late, &dt, &gt, None).double_value(&[]) > 1.0);
        // It replaces DIGDL's count, per increment length.
        let rf = LossConfig { skip_first_samples: 517, ..Default::default() };
        assert_eq!((rf.skipped_increments(16), rf.skipped_increments(1024)), (33, 1));
        assert_eq!(LossConfig::default().skipped_increments(1024), 5);
    }

    /// Counted from the skip, the increments are those of the window cut at the skip, and the
    /// warm-up is still never scored; a window too short for one after its skip scores none.
    #[test]
    fn increments_counted_from_the_skip() {
        tch::manual_seed(6);
        let omega = Tensor::randn([2, 61, 3], F64) * 0.5;
        let dt = Tensor::rand([2, 61], F64) * 0.002 + 0.004;
        let gt = integrate(&omega, &dt);
        let estimate = &omega + Tensor::randn([2, 61, 3], F64) * 0.05;
        let terms = vec![IncrementTerm::new(4, 1.0), IncrementTerm::new(16, 0.25)];
        let from_skip = LossConfig { increments: terms.clone(), skip_first_samples: 13, increments_from_skip: true, ..Default::default() };
        let cut = LossConfig { increments: terms, skip_first_increments: 0, ..Default::default() };
        let narrow = |x: &Tensor| x.narrow(1, 13, 48);
        let a = increment_loss(&from_skip, &estimate, &dt, &gt, None).double_value(&[]);
        let b = increment_loss(&cut, &narrow(&estimate), &narrow(&dt), &narrow(&gt), None).double_value(&[]);
        assert!(a > 1e-3 && (a - b).abs() < 1e-12 * a, "{a} vs {b}");
        // Counted from sample 13, none skipped; aligned to the window, 16 would skip its first.
        assert_eq!(from_skip.increment_layout(16), (13, 0));
        assert_eq!(from_skip.min_window_samples(), 13 + 16);
        assert_eq!(LossConfig { increments_from_skip: false, ..from_skip.clone() }.min_window_samples(), 32);
        let wrong = omega.copy();
        let _ = wrong.narrow(1, 12, 1).fill_(3.0);
        assert!(increment_loss(&from_skip, &wrong, &dt, &gt, None).double_value(&[]).abs() < 1e-12);
        let short = |x: &Tensor| x.narrow(1, 0, 29);
        assert!(increment_loss(&from_skip, &short(&estimate), &short(&dt), &short(&gt), None).double_value(&[]) > 0.0);
        let shorter = |x: &Tensor| x.narrow(1, 0, 12);
        assert_eq!(increment_loss(&from_skip, &shorter(&estimate), &shorter(&dt), &shorter(&gt), None).double_value(&[]), 0.0);
    }

    #[test]
    fn finite_gradient_at_zero_rotation() {
        let omega = Tensor::zeros([1, 40, 3], F64).set_requires_grad(true);
        let dt = Tensor::full([1, 40], 0.005, F64);
        let gt = quat_identity_like(&Tensor::zeros([1, 40, 4], F64));
        let loss = increment_loss(&LossConfig { skip_first_increments: 0, ..small_cfg() }, &omega, &dt, &gt, None);
        assert_eq!(loss.double_value(&[]), 0.0);
        let g = Tensor::run_backward(&[&loss], &[&omega], false, false).pop().unwrap();
        assert!(bool::try_from(g.isfinite().all()).unwrap());
        assert_eq!(g.abs().max().double_value(&[]), 0.0);
    }

    #[test]
    fn defaults_are_digdl() {
        let cfg = LossConfig::default();
        assert_eq!(cfg.increments, [IncrementTerm::new(16, 1.0), IncrementTerm::new(32, 0.5)]);
        assert_eq!((cfg.huber_delta_rad, cfg.scale, cfg.skip_first_increments), (0.005, 1e6, 5));
    }

    /// `L = w_R L^R + γ L^D`: each weight scales its own term only.
    #[test]
    fn total_weights_each_term() {
        tch::manual_seed(5);
        let omega = Tensor::randn([1, 41, 3], F64);
        let dt = Tensor::rand([1, 41], F64) * 0.002 + 0.004;
        let gt = integrate(&omega, &dt);
        let input = Tensor::randn([1, 41, 6], F64);
        let out = NetOutput { gyro: &omega + 0.01, reconstruction: Some(&input + 0.1), input_normalised: input, embedding: None };
        let total = |w_r: f64, gamma: f64| {
            let cfg = LossConfig { reconstruction_weight: w_r, gamma, ..small_cfg() };
            total_loss(&cfg, &out, &dt, &gt, None)
        };
        let base = total(1.0, 1.0);
        let (r, d) = (base.reconstruction.as_ref().unwrap().double_value(&[]), base.increment.double_value(&[]));
        assert!((r - 0.01).abs() < 1e-12 && d > 0.0);
        for (w_r, gamma) in [(0.0, 1.0), (0.25, 3.0), (2.0, 0.0)] {
            let t = total(w_r, gamma).total.double_value(&[]);
            assert!((t - (w_r * r + gamma * d)).abs() < 1e-9 * (1.0 + t.abs()), "w_R {w_r} γ {gamma}: {t}");
        }
    }
}
