//! What a training run is made of (the run itself, its loop, checkpoints and export, is
//! [`super::run`]): the datasets loaded and checked, evaluation and gains per IMU, the three
//! strategies' steps, the MAML inner loop and the initialisations.
//!
//! One epoch = one optimiser step (DIGDL's definition):
//! - `digdl`, `fsda`: one batch of `windows_per_sequence` random `window_samples`-sample
//!   windows from every training recording; `L = L^R + γ L^D` (`L^R` only for FSDA).
//! - `fsda_f` (paper Alg. 1): for every task i, windows from its support set (first
//!   `support_seconds`), `inner_steps` steps θ_e' = θ_e − α ∇_{θ_e} L_support (second order:
//!   the gradient is part of the graph; `first_order` detaches it); then windows from its query
//!   set give L_query(θ_e', θ_r, θ_g). The mean over tasks is back-propagated into θ_e, θ_r,
//!   θ_g (and Ĉ_ω) and Adam steps them with the outer rate β (`train.lr`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::error::{refuse, Context, TrainError};
use rand_chacha::ChaCha8Rng;
use tch::{nn::VarStore, Device, Kind, Tensor};

use super::checkpoint::{self, CheckpointMeta};
use super::config::{Augment, TaskWeighting, TrainConfig, TrainSettings};
use super::data::{self, Batch, Task};
use super::report::SequenceEvals;
use crate::eval::{evaluate, EvalOptions, OrientationErrors};
use crate::model::loss::total_loss;
use crate::model::predict::{correct_with_net, with_correction_gain};
use crate::model::{ForwardOptions, Mode, Net};

/// How to run (the CLI's flags).
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub seed: Option<u64>,
    pub resume: Option<PathBuf>,
    pub out_dir: PathBuf,
    pub name: String,
    /// Override `train.epochs`.
    pub epochs: Option<usize>,
    /// Draw the progress bar (on stderr, only when it is a terminal).
    pub progress: bool,
    /// Polled after every epoch: when it says so (Ctrl-C), the run writes its checkpoint and
    /// returns [`Stopped`].
    pub stop_requested: Option<fn() -> bool>,
}

/// A run stopped on request at an epoch's end, its checkpoint written.
#[derive(Debug, thiserror::Error)]
#[error("stopped after epoch {epoch} of {epochs}; checkpoint {}: continue with the same command and --resume {}", checkpoint.display(), checkpoint.display())]
pub struct Stopped {
    pub epoch: usize,
    pub epochs: usize,
    pub checkpoint: PathBuf,
}

/// All recordings of a run, loaded and checked.
pub struct Datasets {
    pub train: Vec<Task>,
    pub validation: Vec<Task>,
    pub test: Vec<Task>,
    /// Evaluated beside the validation set, never selected on (`dataset.monitor`).
    pub monitor: Vec<Task>,
}

/// Loads every source and runs every check that can fail, before anything is trained.
pub fn load_datasets(cfg: &TrainConfig) -> Result<Datasets, TrainError> {
    let d = &cfg.dataset;
    let t = &cfg.train;
    let maml = cfg.model.mode == Mode::FsdaF;
    let mut train = Vec::new();
    for src in &d.train {
        let task = data::load_task(&d.root, src, d, maml.then_some(d.support_seconds))?;
        if maml {
            if task.support_end >= task.len() {
                let needed = format!("the support set ({} s) plus a query window", d.support_seconds);
                data::check_length(&task, task.support_end + t.maml.query_window_samples, &needed, task.len())?;
            }
            data::check_length(&task, t.maml.support_window_samples, "the support window", task.support_end)?;
            data::check_length(
                &task,
                t.maml.query_window_samples,
                "the query window (after the support set)",
                task.len() - task.support_end,
            )?;
        } else {
            data::check_length(&task, t.window_samples, "the training window", task.len())?;
        }
        // The network counts samples: a recording at another rate is another time scale, and the
        // exported rate_hz (what the node checks its input against) would be wrong for it.
        let window = cfg.model.receptive_field();
        if let Some(why) = crate::model::rate_mismatch(cfg.model.rate_hz, task.rec.nominal_imu_rate_hz(), window) {
            refuse!("{}: {why}; resample it to model.rate_hz or train a model for its rate", task.name);
        }
        // Without one scored increment the run would train the reconstruction alone (L_D = 0).
        let shortest = t.loss.increments.iter().map(|i| i.samples).min().unwrap_or(1);
        if task.longest_valid_run < shortest as usize + 1 {
            return Err(data::DataError::NoScoredIncrement {
                name: task.name.clone(),
                increment: shortest,
                longest: task.longest_valid_run,
                needed: shortest as usize + 1,
                share: 100.0 * task.valid_fraction,
                nearest_ms: d.max_nearest_gt_ms,
            }
            .into());
        }
        tracing::info!(
            "train {}: {} samples, {:.1} s, support {} samples, {:.1}% with ground truth",
            task.name,
            task.len(),
            task.seconds(),
            task.support_end,
            100.0 * task.valid_fraction
        );
        train.push(task);
    }
    // Evaluation recordings at another rate would be scored, and chosen on (select_best,
    // train.seeds), with a model that cannot run them.
    let window = cfg.model.receptive_field();
    let load_eval = |list: &[super::config::SourceConfig], what: &str| -> Result<Vec<Task>, TrainError> {
        let tasks = list.iter().map(|src| Ok(data::load_task(&d.root, src, d, None)?)).collect::<Result<Vec<Task>, TrainError>>()?;
        for task in &tasks {
            if let Some(why) = crate::model::rate_mismatch(cfg.model.rate_hz, task.rec.nominal_imu_rate_hz(), window) {
                refuse!("{what} {}: {why}; resample it to model.rate_hz or leave it out", task.name);
            }
            // Shorter than one window, its AOE is the warm-up's alone (near 0°, whatever the
            // network does), and a validation score of it would pull the choice of seed and epoch.
            data::check_length(
                task,
                usize::try_from(window).unwrap_or(usize::MAX),
                &format!("the model's window, as a {what} recording"),
                task.len(),
            )
            .map_err(|e| TrainError::Refused(format!("dataset.{what}: {e}")))?;
        }
        Ok(tasks)
    };
    let data = Datasets {
        train,
        validation: load_eval(&d.validation, "validation")?,
        test: load_eval(&d.test, "test")?,
        monitor: load_eval(&d.monitor, "monitor")?,
    };
    // Results are filed by recording name (metrics `val.<name>.*`, `test.<name>.*`): two of one
    // name in a list would keep one's figures only.
    for (what, list) in [("train", &data.train), ("validation", &data.validation), ("test", &data.test), ("monitor", &data.monitor)] {
        let mut seen = std::collections::BTreeMap::new();
        for t in list.iter() {
            if let Some(other) = seen.insert(t.name.clone(), t.source.clone()) {
                refuse!("dataset.{what}: two recordings are named {} ({other} and {}): give one a `name:` of its own", t.name, t.source);
            }
        }
    }
    Ok(data)
}

impl Datasets {
    /// [`Task::fingerprint`] of every recording, keyed `<list>.<name>`.
    pub fn fingerprints(&self) -> BTreeMap<String, String> {
        [("train", &self.train), ("validation", &self.validation), ("test", &self.test), ("monitor", &self.monitor)]
            .into_iter()
            .flat_map(|(list, tasks)| tasks.iter().map(move |t| (format!("{list}.{}", t.name), t.fingerprint())))
            .collect()
    }
}

/// The evaluation options of a run's config.
pub fn eval_opts(cfg: &TrainConfig) -> EvalOptions {
    EvalOptions { max_gap_ns: (cfg.dataset.max_interpolation_gap_ms * 1e6) as i64 }
}

/// Raw-gyro errors of a recording.
pub fn evaluate_raw(task: &Task, opts: &EvalOptions) -> Result<OrientationErrors, TrainError> {
    let gyro: Vec<_> = task.rec.imu.iter().map(|s| s.gyro).collect();
    Ok(evaluate(&task.rec, &gyro, opts)?)
}

/// Errors of the model (eval mode, BatchNorm folded, the meta-learned θ_e as exported).
pub fn evaluate_net(net: &Net, task: &Task, opts: &EvalOptions) -> Result<OrientationErrors, TrainError> {
    evaluate_net_with_gain(net, task, opts, 1.0)
}

/// [`evaluate_net`] with the share `gain` of the model's correction applied (as deployed on an
/// IMU with a correction gain, `ModelMetadata::imu_correction_gains`).
pub fn evaluate_net_with_gain(net: &Net, task: &Task, opts: &EvalOptions, gain: f64) -> Result<OrientationErrors, TrainError> {
    let gyro = corrected_gyro(net, task)?;
    Ok(evaluate(&task.rec, &with_correction_gain(&task.rec.imu, gyro, gain), opts)?)
}

/// The model's corrected gyro over `task` (its IMU's Ĉ_ω row where it names one).
pub fn corrected_gyro(net: &Net, task: &Task) -> Result<Vec<nalgebra::Vector3<f64>>, TrainError> {
    let inf = match task.calibration_row {
        Some(row) => net.inference_for_row(row),
        None => net.inference(),
    };
    Ok(correct_with_net(&inf, &task.rec.imu)?)
}

/// `train.correction_gains`: for every IMU of the validation recordings, the share g of the
/// network's correction, `ω + g (ω̂ − ω)`, with the lowest mean full-length AOE over that
/// IMU's recordings — a 0.05 grid on [0, 1], then golden-section search within ±0.05 of its
/// best. g is a share: at most 1, shrinking the correction toward the raw gyro, never
/// extrapolating it (on EuRoC, where AOE is sharp in g, 1.004 fitted one recording's drift and
/// moved four of six the other way; docs/training.md, "v8"). The windowed loss fits
/// increments of at most a few seconds; the AOE integrates the whole recording: on a
/// calibrated IMU with mocap ground truth a correction that fits the short increments can add
/// more drift than it removes (docs/training.md).
pub fn fit_correction_gains(net: &Net, tasks: &[Task], opts: &EvalOptions) -> Result<BTreeMap<String, f64>, TrainError> {
    // Each recording with its corrected gyro (gain 1), computed once, grouped by IMU.
    type Corrected<'a> = (&'a Task, Vec<nalgebra::Vector3<f64>>);
    let mut by_imu: BTreeMap<&str, Vec<Corrected>> = BTreeMap::new();
    for task in tasks {
        by_imu.entry(task.imu_name.as_str()).or_default().push((task, corrected_gyro(net, task)?));
    }
    let mut gains = BTreeMap::new();
    for (imu, runs) in by_imu {
        let mean_aoe = |g: f64| -> Result<f64, TrainError> {
            let mut sum = 0.0;
            for (task, gyro) in &runs {
                sum += evaluate(&task.rec, &with_correction_gain(&task.rec.imu, gyro.clone(), g), opts)?.aoe_deg;
            }
            Ok(sum / runs.len() as f64)
        };
        let mut best = (1.0, mean_aoe(1.0)?);
        for k in 0..=20 {
            let g = 0.05 * k as f64;
            let a = mean_aoe(g)?;
            if a < best.1 {
                best = (g, a);
            }
        }
        let phi = (5f64.sqrt() - 1.0) / 2.0;
        let (mut lo, mut hi) = ((best.0 - 0.05).max(0.0), (best.0 + 0.05).min(1.0));
        let (mut x1, mut x2) = (hi - phi * (hi - lo), lo + phi * (hi - lo));
        let (mut f1, mut f2) = (mean_aoe(x1)?, mean_aoe(x2)?);
        for _ in 0..14 {
            if f1 < f2 {
                (hi, x2, f2) = (x2, x1, f1);
                x1 = hi - phi * (hi - lo);
                f1 = mean_aoe(x1)?;
            } else {
                (lo, x1, f1) = (x1, x2, f2);
                x2 = lo + phi * (hi - lo);
                f2 = mean_aoe(x2)?;
            }
        }
        for (g, a) in [(x1, f1), (x2, f2)] {
            if a < best.1 {
                best = (g, a);
            }
        }
        tracing::info!("correction gain for IMU {imu}: {:.3} (mean validation AOE {:.3}°, {:.3}° at 1)", best.0, best.1, mean_aoe(1.0)?);
        gains.insert(imu.to_string(), best.0);
    }
    Ok(gains)
}

/// DIGDL's noise and offsets on a batch of windows: white noise on every channel, a constant
/// gyro offset per window (and an accelerometer one when asked).
fn augment(u: &Tensor, a: &Augment) -> Tensor {
    let (b, t) = (u.size()[0], u.size()[1]);
    let opts = (Kind::Float, Device::Cpu);
    let (g, f) = (a.gyro_noise_std, a.accel_noise_std);
    let noise_std = Tensor::from_slice(&[g, g, g, f, f, f]).to_kind(Kind::Float).reshape([1, 1, 6]);
    let noise = Tensor::randn([b, t, 6], opts) * noise_std;
    let offset = (Tensor::rand([b, 1, 3], opts) * 2.0 - 1.0) * a.gyro_offset;
    // Drawn only when asked, so the random stream (and every recipe without it) is unchanged.
    let accel =
        if a.accel_offset > 0.0 { (Tensor::rand([b, 1, 3], opts) * 2.0 - 1.0) * a.accel_offset } else { Tensor::zeros([b, 1, 3], opts) };
    u + noise + Tensor::cat(&[offset, accel], 2)
}

pub(super) struct StepLosses {
    pub(super) loss: f64,
    pub(super) increment: f64,
    pub(super) reconstruction: Option<f64>,
    pub(super) support: Option<f64>,
}

fn scalar(t: &Tensor) -> f64 {
    t.double_value(&[])
}

/// The samples a DIGDL / FSDA window is drawn from in a recording of `len` samples: all of
/// it, or with `window_start_within` (DIGDL's `max_train_freq`) the first window and the few
/// samples after it.
fn plain_window_range(t: &TrainSettings, len: usize) -> (usize, usize) {
    match t.window_start_within {
        Some(first) => (0, len.min(first.saturating_sub(1) + t.window_samples)),
        None => (0, len),
    }
}

/// DIGDL / FSDA: one batch from all recordings, gradients accumulated into the variables.
pub(super) fn plain_step(net: &Net, cfg: &TrainConfig, tasks: &[Task], rng: &mut ChaCha8Rng) -> StepLosses {
    let t = &cfg.train;
    let refs: Vec<&Task> = tasks.iter().collect();
    let batch: Batch = data::sample_windows(&refs, |x| plain_window_range(t, x.len()), t.windows_per_sequence, t.window_samples, rng);
    let u = augment(&batch.imu, &t.augment);
    let reconstruct = cfg.model.mode.has_embedding();
    let calibration_rows = batch.calibration_rows.as_ref();
    let out =
        net.forward_with(&u, &ForwardOptions { train: true, reconstruct, embedding_params: None, calibration_rows, ..Default::default() });
    let terms = total_loss(&t.loss, &out, &batch.dt, &batch.gt, Some(&batch.valid));
    terms.total.backward();
    StepLosses {
        loss: scalar(&terms.total),
        increment: scalar(&terms.increment),
        reconstruction: terms.reconstruction.as_ref().map(scalar),
        support: None,
    }
}

/// FSDA-F: MAML on the Embedding (see the module doc).
pub(super) fn maml_step(net: &Net, cfg: &TrainConfig, tasks: &[Task], rng: &mut ChaCha8Rng) -> StepLosses {
    let t = &cfg.train;
    let m = &t.maml;
    let theta = net.embedding_parameters();
    let weights = task_weights(tasks, t.task_weighting);
    let (mut loss, mut inc, mut rec, mut sup) = (0.0, 0.0, 0.0, 0.0);
    for (task, &w) in tasks.iter().zip(&weights) {
        // `n` is the reciprocal of the task's weight (the number of tasks when uniform).
        let n = 1.0 / w;
        let s = data::sample_windows(&[task], |x| (0, x.support_end), m.support_windows, m.support_window_samples, rng);
        let q = data::sample_windows(&[task], |x| (x.support_end, x.len()), m.query_windows, m.query_window_samples, rng);
        let mut fast: Vec<Tensor> = theta.iter().map(Tensor::shallow_clone).collect();
        let su = augment(&s.imu, &t.augment);
        let mut support_at_meta: Option<Tensor> = None;
        for k in 0..m.inner_steps {
            let calibration_rows = s.calibration_rows.as_ref();
            let out = net.forward_with(
                &su,
                &ForwardOptions { train: true, reconstruct: true, embedding_params: Some(&fast), calibration_rows, ..Default::default() },
            );
            let l = total_loss(&t.loss, &out, &s.dt, &s.gt, Some(&s.valid)).total;
            if k == 0 {
                sup += scalar(&l) / n;
                if m.unadapted_support_weight > 0.0 {
                    support_at_meta = Some(&l * (m.unadapted_support_weight / n));
                }
            }
            let second = !m.first_order;
            let keep = second || (k == 0 && support_at_meta.is_some());
            let grads = Tensor::run_backward(&[&l], &fast, keep, second);
            fast = inner_sgd_step(&fast, &grads, m.inner_lr, second);
        }
        let qu = augment(&q.imu, &t.augment);
        let calibration_rows = q.calibration_rows.as_ref();
        let out = net.forward_with(
            &qu,
            &ForwardOptions { train: true, reconstruct: true, embedding_params: Some(&fast), calibration_rows, ..Default::default() },
        );
        let terms = total_loss(&t.loss, &out, &q.dt, &q.gt, Some(&q.valid));
        let mut parts = vec![&terms.total / n];
        parts.extend(support_at_meta);
        parts.into_iter().reduce(|a, b| a + b).expect("the query loss").backward();
        loss += scalar(&terms.total) / n;
        inc += scalar(&terms.increment) / n;
        rec += terms.reconstruction.as_ref().map_or(0.0, scalar) / n;
    }
    StepLosses { loss, increment: inc, reconstruction: Some(rec), support: Some(sup) }
}

/// The domain of a training source: the first path component (`euroc/MH_01_easy` → `euroc`).
pub fn task_domain(task: &Task) -> String {
    super::config::first_path_component(&task.source).to_string()
}

/// Weight of each task's query loss in the outer (meta) loss; they sum to 1.
pub fn task_weights(tasks: &[Task], how: TaskWeighting) -> Vec<f64> {
    domain_weights(&tasks.iter().map(task_domain).collect::<Vec<_>>(), how)
}

/// [`task_weights`] from the tasks' domains.
pub fn domain_weights(domains: &[String], how: TaskWeighting) -> Vec<f64> {
    let n = domains.len().max(1) as f64;
    match how {
        TaskWeighting::Uniform => vec![1.0 / n; domains.len()],
        TaskWeighting::PerDomain => {
            let mut uniq = domains.to_vec();
            uniq.sort();
            uniq.dedup();
            let nd = uniq.len() as f64;
            domains.iter().map(|d| 1.0 / (nd * domains.iter().filter(|x| *x == d).count() as f64)).collect()
        }
    }
}

/// Zeroes the last conv of the correction CNN (Generator or DIGDL's), so ω' starts at 0.
pub(super) fn zero_init_correction(vs: &VarStore, net: &Net) -> Result<(), TrainError> {
    let prefix = if net.config().mode == Mode::Digdl { "digdl" } else { "generator" };
    let layers =
        if net.config().mode == Mode::Digdl { net.config().digdl.kernel_sizes.len() } else { net.config().generator.kernel_sizes.len() };
    let vars = vs.variables();
    for leaf in ["weight", "bias"] {
        let name = format!("{prefix}.conv{}.{leaf}", layers - 1);
        let v = vars.get(&name).ok_or_else(|| TrainError::Refused(format!("zero_init_correction: no variable {name}")))?;
        tch::no_grad(|| {
            let _ = v.shallow_clone().zero_();
        });
    }
    Ok(())
}

/// Gives every task its Ĉ_ω row. With per-IMU calibrations a training recording of an IMU
/// the model has no Ĉ_ω for and not declared calibrated is an error (a misspelt name would
/// silently train with I); an evaluation one gets I, as a new IMU would in the node.
/// Recordings of `calibrated` IMUs get I (the last row) in training and evaluation.
pub fn assign_calibration_rows(net: &Net, data: &mut Datasets, calibrated: &[String]) -> Result<(), TrainError> {
    let names = &net.config().imu_calibrations;
    if names.is_empty() && calibrated.is_empty() {
        // One shared Ĉ_ω: the plain forward, as the models before per-IMU Ĉ_ω were trained
        // (bit-for-bit the same run from the same config and seed).
        return Ok(());
    }
    let identity_row = names.len() as i64 + i64::from(names.is_empty());
    let row = |imu: &String| if calibrated.contains(imu) { identity_row } else { net.calibration_row(imu) };
    for task in &mut data.train {
        if !names.is_empty() && !names.contains(&task.imu_name) && !calibrated.contains(&task.imu_name) {
            refuse!(
                "training recording {} is from IMU {:?}, which model.imu_calibrations {:?} does not list (set the source's imu: or add it)",
                task.source,
                task.imu_name,
                names
            );
        }
        task.calibration_row = Some(row(&task.imu_name));
    }
    for task in data.validation.iter_mut().chain(&mut data.test).chain(&mut data.monitor) {
        task.calibration_row = Some(row(&task.imu_name));
        if !names.is_empty() && !names.contains(&task.imu_name) {
            tracing::warn!("{}: IMU {:?} has no Ĉ_ω of its own in the model; evaluated with Ĉ_ω = I", task.name, task.imu_name);
        }
    }
    if !names.is_empty() || !calibrated.is_empty() {
        let per: Vec<String> = data.train.iter().map(|t| format!("{} → {}", t.name, t.imu_name)).collect();
        tracing::info!("Ĉ_ω per IMU {names:?}, calibrated (Ĉ_ω = I) {calibrated:?}: {}", per.join(", "));
    }
    Ok(())
}

/// Copies a trained model's variables (`TrainSettings::init_from`) into `vs`, normalisation
/// included; its config must be `cfg.model`.
pub(super) fn init_from_model(vs: &mut VarStore, cfg: &TrainConfig, model_path: &std::path::Path) -> Result<(), TrainError> {
    // The model may be named by any of its three files, as everywhere else.
    let metadata_path = &crate::model::predict::metadata_path(model_path);
    let loaded = crate::model::export::load_net(metadata_path, Device::Cpu)
        .map_err(|e| TrainError::Refused(format!("train.init_from {}: {e}", metadata_path.display())))?;
    if loaded.metadata.config != cfg.model {
        let (a, b) = (
            serde_json::to_value(&loaded.metadata.config).context("model config")?,
            serde_json::to_value(&cfg.model).context("model config")?,
        );
        let differing: std::collections::BTreeSet<String> = match (a.as_object(), b.as_object()) {
            (Some(a), Some(b)) => a.keys().chain(b.keys()).filter(|k| a.get(*k) != b.get(*k)).map(|k| format!("model.{k}")).collect(),
            _ => Default::default(),
        };
        let differing: Vec<String> = differing.into_iter().collect();
        refuse!(
            "train.init_from {}: the model's config differs from this config's `model` in {}",
            metadata_path.display(),
            differing.join(", ")
        );
    }
    vs.copy(&loaded.vs).map_err(|e| TrainError::Refused(format!("train.init_from {}: {e}", metadata_path.display())))?;
    tracing::info!(
        "weights and normalisation from {} (trained at {})",
        metadata_path.display(),
        loaded.metadata.code_revision.as_deref().unwrap_or("an unknown revision")
    );
    Ok(())
}

fn slice_out(out: &crate::model::NetOutput, start: i64, len: i64) -> crate::model::NetOutput {
    crate::model::NetOutput {
        gyro: out.gyro.narrow(0, start, len),
        reconstruction: out.reconstruction.as_ref().map(|r| r.narrow(0, start, len)),
        input_normalised: out.input_normalised.narrow(0, start, len),
        embedding: None,
    }
}

/// FSDA-F with every task in one batch through the Restructor and Generator (see
/// `MamlConfig::batch_tasks`): per-task fast Embedding weights; the inner gradient of task i
/// is that of the summed support losses w.r.t. task i's fast weights (the other tasks' losses
/// depend on them only through the shared BatchNorm statistics).
pub(super) fn maml_step_batched(net: &Net, cfg: &TrainConfig, tasks: &[Task], rng: &mut ChaCha8Rng) -> StepLosses {
    let t = &cfg.train;
    let m = &t.maml;
    let theta = net.embedding_parameters();
    let emb = net.embedding().expect("fsda_f has an Embedding");
    let weights = task_weights(tasks, t.task_weighting);
    let (mut s_list, mut q_list) = (Vec::new(), Vec::new());
    for task in tasks {
        s_list.push(data::sample_windows(&[task], |x| (0, x.support_end), m.support_windows, m.support_window_samples, rng));
        q_list.push(data::sample_windows(&[task], |x| (x.support_end, x.len()), m.query_windows, m.query_window_samples, rng));
    }
    let cat = |l: &[Batch], f: fn(&Batch) -> &Tensor| Tensor::cat(&l.iter().map(f).collect::<Vec<_>>(), 0);
    let rows = |l: &[Batch]| l.iter().map(|b| b.calibration_rows.as_ref()).collect::<Option<Vec<_>>>().map(|r| Tensor::cat(&r, 0));
    let stack = |l: &[Batch]| Batch {
        imu: cat(l, |b| &b.imu),
        dt: cat(l, |b| &b.dt),
        gt: cat(l, |b| &b.gt),
        valid: cat(l, |b| &b.valid),
        calibration_rows: rows(l),
    };
    let (s, q) = (stack(&s_list), stack(&q_list));
    let n = tasks.len();
    let forward = |u: &Tensor, rows: Option<&Tensor>, per: i64, fast: &[Vec<Tensor>]| {
        let un = net.normalize(u);
        let e: Vec<Tensor> = (0..n).map(|i| emb.forward_with(&un.narrow(0, i as i64 * per, per), &fast[i])).collect();
        let e = Tensor::cat(&e, 0);
        let opts = ForwardOptions { train: true, reconstruct: true, embedding: Some(&e), calibration_rows: rows, ..Default::default() };
        net.forward_with(u, &opts)
    };
    let task_losses = |out: &crate::model::NetOutput, b: &Batch, per: i64| -> Vec<crate::model::loss::LossTerms> {
        (0..n)
            .map(|i| {
                let (a, len) = (i as i64 * per, per);
                total_loss(
                    &t.loss,
                    &slice_out(out, a, len),
                    &b.dt.narrow(0, a, len),
                    &b.gt.narrow(0, a, len),
                    Some(&b.valid.narrow(0, a, len)),
                )
            })
            .collect()
    };
    let su = augment(&s.imu, &t.augment);
    let sper = m.support_windows as i64;
    let support_losses = |fast: &[Vec<Tensor>]| {
        task_losses(&forward(&su, s.calibration_rows.as_ref(), sper, fast), &s, sper).into_iter().map(|l| l.total).collect()
    };
    let (fast, sup, support_at_meta) = inner_adapt_batched(&theta, &weights, m, support_losses);
    let qu = augment(&q.imu, &t.augment);
    let qper = m.query_windows as i64;
    let out = forward(&qu, q.calibration_rows.as_ref(), qper, &fast);
    let ls = task_losses(&out, &q, qper);
    let outer = ls.iter().zip(&weights).map(|(l, w)| &l.total * *w).reduce(|a, b| a + b).expect("≥ 1 task");
    let mut parts = vec![outer.shallow_clone()];
    parts.extend(support_at_meta);
    parts.into_iter().reduce(|a, b| a + b).expect("the query loss").backward();
    let wsum = |f: &dyn Fn(&crate::model::loss::LossTerms) -> f64| ls.iter().zip(&weights).map(|(l, w)| f(l) * w).sum::<f64>();
    StepLosses {
        loss: scalar(&outer),
        increment: wsum(&|l| scalar(&l.increment)),
        reconstruction: Some(wsum(&|l| l.reconstruction.as_ref().map_or(0.0, scalar))),
        support: Some(sup),
    }
}

/// The inner loop of the batched step: `m.inner_steps` gradient steps, each task on its own
/// copy of the Embedding's weights θ_e. `support_losses(fast)` is every task's support loss with
/// task i's Embedding at `fast[i]`. Returns the adapted weights, the task-weighted support loss
/// at θ_e and, when `m.unadapted_support_weight` (λ_s) > 0, that loss in the graph times λ_s.
///
/// Each copy starts as a view of θ_e, its own autograd node, so the gradient with respect to
/// task i's copy is that of the summed losses through task i's Embedding. With
/// `m.shared_inner_step` the copies are shallow clones, which share θ_e's identity: every task
/// gets the gradient of all the tasks' losses, one shared step, the bundled v9 model's
/// (docs/training.md, "The inner step was shared").
fn inner_adapt_batched(
    theta: &[Tensor],
    weights: &[f64],
    m: &super::config::MamlConfig,
    support_losses: impl Fn(&[Vec<Tensor>]) -> Vec<Tensor>,
) -> (Vec<Vec<Tensor>>, f64, Option<Tensor>) {
    let (n, p) = (weights.len(), theta.len());
    let copy = |w: &Tensor| if m.shared_inner_step { w.shallow_clone() } else { w.view_as(w) };
    let mut fast: Vec<Vec<Tensor>> = (0..n).map(|_| theta.iter().map(copy).collect()).collect();
    let second = !m.first_order;
    let (mut sup, mut support_at_meta) = (0.0, None);
    for k in 0..m.inner_steps {
        let ls = support_losses(&fast);
        if k == 0 {
            sup = ls.iter().zip(weights).map(|(l, w)| scalar(l) * w).sum();
            if m.unadapted_support_weight > 0.0 {
                let l0 = ls.iter().zip(weights).map(|(l, w)| l * *w).reduce(|a, b| a + b).expect("≥ 1 task");
                support_at_meta = Some(l0 * m.unadapted_support_weight);
            }
        }
        let sum = ls.into_iter().reduce(|a, b| a + b).expect("≥ 1 task");
        let flat: Vec<&Tensor> = fast.iter().flatten().collect();
        let keep = second || (k == 0 && support_at_meta.is_some());
        let grads = Tensor::run_backward(&[&sum], &flat, keep, second);
        fast = fast.iter().zip(grads.chunks(p)).map(|(w, g)| inner_sgd_step(w, g, m.inner_lr, second)).collect();
    }
    (fast, sup, support_at_meta)
}

pub(super) fn epoch_seed(seed: u64, epoch: usize) -> i64 {
    // SplitMix64 of (seed, epoch): independent per-epoch streams, stable across resumes.
    let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15u64.wrapping_mul(epoch as u64 + 1));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 1) as i64
}

/// The validation score: the AOE of each recording's evaluation at `epoch` (`None`: its
/// latest) averaged over the recordings, weighted like the training tasks (`per_domain`: each
/// dataset's mean counts once); `None` when no recording was evaluated then.
pub fn validation_score(evals: &[SequenceEvals], epoch: Option<usize>, how: TaskWeighting) -> Option<f64> {
    let latest: Vec<(String, f64)> = evals
        .iter()
        .filter_map(|e| {
            let at = match epoch {
                None => e.evals.last(),
                Some(ep) => e.evals.iter().find(|x| x.0 == ep),
            };
            at.map(|x| (super::config::first_path_component(&e.source).to_string(), x.1.aoe_deg))
        })
        .collect();
    if latest.is_empty() {
        return None;
    }
    let domains: Vec<String> = latest.iter().map(|(d, _)| d.clone()).collect();
    Some(domain_weights(&domains, how).iter().zip(&latest).map(|(w, (_, a))| w * a).sum())
}

/// Sets the calling thread's SSE control register to flush denormal results to zero and treat
/// denormal inputs as zero (FTZ + DAZ, what `torch.set_flush_denormal(True)` does); threads
/// created afterwards (libtorch's intra-op pool) inherit it. Why: late in a cosine cycle a few
/// BatchNorm channels can die (running variance ≈ 1e-39) and every convolution over them then
/// runs on denormals, which x86 handles in microcode: one v9 run went from 1.7 to 6.3 s an epoch
/// (docs/training.md, "Speed"). Values below 1.2e-38 become 0; runs without denormals are
/// unchanged bit for bit. A no-op on other architectures.
pub fn flush_denormals_to_zero() {
    #[cfg(target_arch = "x86_64")]
    {
        const FTZ: u32 = 1 << 15;
        const DAZ: u32 = 1 << 6;
        let mut csr: u32 = 0;
        // SAFETY: stmxcsr / ldmxcsr read and write this thread's MXCSR through a valid pointer to a
        // local; setting FTZ and DAZ changes only how denormal floats are rounded.
        unsafe {
            std::arch::asm!("stmxcsr [{}]", in(reg) &mut csr, options(nostack));
            csr |= FTZ | DAZ;
            std::arch::asm!("ldmxcsr [{}]", in(reg) &csr, options(nostack, readonly));
        }
    }
}

/// A new run over a checkpoint of the same name that has epochs left to train would replace
/// it: after "stopped after epoch 116 of 300", the same command without `--resume` started
/// again from epoch 0 and the 116 epochs were gone. A finished run's checkpoint is replaced
/// (training a model again under its name).
pub(super) fn refuse_to_restart_over_unfinished(out_dir: &Path, name: &str) -> Result<(), TrainError> {
    let (ot, json) = checkpoint::paths(out_dir, name);
    if !ot.exists() && !json.exists() {
        return Ok(());
    }
    match checkpoint::load(&json) {
        // A run stopped by its time budget is finished as asked.
        Ok(c) if c.meta.epoch < c.meta.config.train.epochs && !budget_spent(&c.meta) => refuse!(
            "{} holds an unfinished run of {name} (epoch {} of {}): continue it with --resume {}, or delete it (or give another --name) to start over",
            json.display(),
            c.meta.epoch,
            c.meta.config.train.epochs,
            json.display()
        ),
        Ok(_) => Ok(()),
        Err(e) => {
            tracing::warn!("{}: unreadable ({e:#}); a new run replaces it", json.display());
            Ok(())
        }
    }
}

fn budget_spent(meta: &CheckpointMeta) -> bool {
    let budget = meta.config.train.max_train_seconds;
    budget > 0.0 && meta.train_seconds >= budget
}

/// The config with the command line's `--seed` / `--epochs` applied, checked again.
pub fn with_overrides(cfg: &TrainConfig, seed: Option<u64>, epochs: Option<usize>) -> Result<TrainConfig, TrainError> {
    let mut cfg = cfg.clone();
    if let Some(s) = seed {
        cfg.train.seed = s;
    }
    if let Some(e) = epochs {
        cfg.train.epochs = e;
    }
    cfg.validate().map_err(|e| TrainError::Refused(format!("config: {e}")))?;
    Ok(cfg)
}

/// Trains, evaluates and exports; returns the summary (also written to `<out>/<name>.train.json`).
/// `<out>/<name>.train.json`.
pub fn summary_path(out_dir: &Path, name: &str) -> PathBuf {
    out_dir.join(format!("{name}.train.json"))
}

/// One inner (task) step of the few-shot strategy on the Embedding, as in [`maml_step`]:
/// `L = total_loss(forward(batch, θ_e = fast))`, `fast' = fast − α ∇_fast L`. `second_order`
/// keeps the inner gradient in the graph (meta-training); `false` detaches the gradient (first
/// order; the fast weights stay connected to θ_e). Test-time adaptation (`crate::adapt`) runs
/// it first order in eval mode (`train: false`: BatchNorm running statistics, no dropout, none
/// of them updated) and detaches the result itself.
/// Returns the loss before the step and the new fast weights.
pub fn embedding_inner_step(
    net: &Net,
    loss: &crate::model::loss::LossConfig,
    batch: &Batch,
    fast: &[Tensor],
    inner_lr: f64,
    train: bool,
    second_order: bool,
) -> (crate::model::loss::LossTerms, Vec<Tensor>) {
    let (terms, grads) = embedding_inner_grads(net, loss, batch, fast, train, second_order);
    (terms, inner_sgd_step(fast, &grads, inner_lr, second_order))
}

/// θ' = θ − α g: with `second_order` the gradient stays in the graph, otherwise it is detached
/// (first order; θ' stays connected to θ).
fn inner_sgd_step(fast: &[Tensor], grads: &[Tensor], inner_lr: f64, second_order: bool) -> Vec<Tensor> {
    fast.iter().zip(grads).map(|(w, g)| if second_order { w - g * inner_lr } else { w - g.detach() * inner_lr }).collect()
}

/// The loss of [`embedding_inner_step`] and its gradient with respect to the fast weights
/// (in the graph when `second_order`), for callers that scale the step themselves (Adam).
pub fn embedding_inner_grads(
    net: &Net,
    loss: &crate::model::loss::LossConfig,
    batch: &Batch,
    fast: &[Tensor],
    train: bool,
    second_order: bool,
) -> (crate::model::loss::LossTerms, Vec<Tensor>) {
    embedding_and_extra_grads(net, loss, batch, fast, &[], train, second_order)
}

/// [`embedding_inner_grads`] followed by the gradients with respect to `extra`, variables of
/// the model itself that require grad (the adaptation's calibration head).
pub fn embedding_and_extra_grads(
    net: &Net,
    loss: &crate::model::loss::LossConfig,
    batch: &Batch,
    fast: &[Tensor],
    extra: &[Tensor],
    train: bool,
    second_order: bool,
) -> (crate::model::loss::LossTerms, Vec<Tensor>) {
    let out =
        net.forward_with(&batch.imu, &ForwardOptions { train, reconstruct: true, embedding_params: Some(fast), ..Default::default() });
    let terms = total_loss(loss, &out, &batch.dt, &batch.gt, Some(&batch.valid));
    let inputs: Vec<&Tensor> = fast.iter().chain(extra).collect();
    let grads = Tensor::run_backward(&[&terms.total], &inputs, second_order, second_order);
    (terms, grads)
}

#[cfg(test)]
mod tests {
    /// After the switch a denormal result is zero and a denormal input counts as zero, on this
    /// thread and on threads it starts (x86_64 only; elsewhere the call does nothing).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn denormals_are_flushed_after_the_switch() {
        let tiny = std::hint::black_box(f32::MIN_POSITIVE);
        std::thread::spawn(move || {
            assert!(tiny / 4.0 > 0.0, "a fresh thread keeps denormals");
            flush_denormals_to_zero();
            assert_eq!(std::hint::black_box(tiny) / 4.0, 0.0);
            let denormal = f32::from_bits(1);
            assert_eq!(std::hint::black_box(denormal) * 2.0, 0.0);
            assert!(std::thread::spawn(move || std::hint::black_box(tiny) / 4.0 == 0.0).join().unwrap(), "inherited");
            let t = tch::Tensor::from_slice(&[tiny]) / 4.0;
            assert_eq!(t.double_value(&[0]), 0.0);
        })
        .join()
        .unwrap();
    }

    use super::*;
    use rand::{Rng, SeedableRng};

    /// With `window_start_within: 32` a 16000-sample window starts at one of a recording's
    /// first 32 samples (DIGDL's `randint(0, max_train_freq)`); without it, anywhere; a short
    /// recording keeps a valid range.
    #[test]
    fn plain_windows_start_where_asked() {
        let mut t: TrainSettings = serde_yaml::from_str("{epochs: 1, window_samples: 16000}").unwrap();
        assert_eq!(plain_window_range(&t, 36000), (0, 36000));
        t.window_start_within = Some(32);
        let (a, b) = plain_window_range(&t, 36000);
        assert_eq!((a, b - t.window_samples), (0, 31));
        assert_eq!(plain_window_range(&t, 16010), (0, 16010));
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let starts: Vec<usize> = (0..500).map(|_| rng.gen_range(a..=b - t.window_samples)).collect();
        assert!(starts.iter().all(|&s| s < 32) && starts.contains(&0) && starts.contains(&31));
    }

    /// The noise has the stated size per channel, and an augmentation of zeros leaves the
    /// windows as they are.
    #[test]
    fn augmentation_has_its_stated_sizes() {
        let none = Augment { gyro_noise_std: 0.0, accel_noise_std: 0.0, gyro_offset: 0.0, accel_offset: 0.0 };
        let big = Augment { gyro_noise_std: 1.0, accel_noise_std: 10.0, gyro_offset: 0.5, accel_offset: 0.0 };
        let u = Tensor::zeros([3, 4000, 6], (Kind::Float, Device::Cpu));
        assert_eq!(augment(&u, &none).abs().max().double_value(&[]), 0.0, "nothing added");
        let got = augment(&u, &big);
        let std_of = |c: i64| got.narrow(2, c, 1).std(true).double_value(&[]);
        assert!((std_of(3) - 10.0).abs() < 0.2, "accel noise σ {}", std_of(3));
        // The gyro channels: σ 1 of noise plus a per-window offset within ±0.5.
        let offsets = got.narrow(2, 0, 3).mean_dim(1, false, Kind::Double);
        assert!(offsets.abs().max().double_value(&[]) < 0.6, "{offsets}");
        let residual = got.narrow(2, 0, 3) - offsets.unsqueeze(1).to_kind(Kind::Float);
        assert!((residual.std(true).double_value(&[]) - 1.0).abs() < 0.02);
        // An accelerometer offset alone: a constant per window within its bound.
        let accel = augment(&u, &Augment { gyro_noise_std: 0.0, accel_noise_std: 0.0, gyro_offset: 0.0, accel_offset: 0.3 });
        let per_window = accel.narrow(2, 3, 3).narrow(1, 0, 1);
        assert!((accel.narrow(2, 3, 3) - &per_window).abs().max().double_value(&[]) == 0.0, "constant in each window");
        let m = per_window.abs().max().double_value(&[]);
        assert!(m > 0.0 && m <= 0.3, "{m}");
        assert_eq!(accel.narrow(2, 0, 3).abs().max().double_value(&[]), 0.0, "the gyro untouched");
    }

    #[test]
    fn per_domain_weights_give_each_domain_the_same_total() {
        let d: Vec<String> = ["euroc", "euroc", "euroc", "euroc", "euroc", "euroc", "tumvi", "tumvi", "tumvi"].map(String::from).to_vec();
        let w = domain_weights(&d, TaskWeighting::PerDomain);
        assert!((w[..6].iter().sum::<f64>() - 0.5).abs() < 1e-12 && (w[6..].iter().sum::<f64>() - 0.5).abs() < 1e-12);
        let u = domain_weights(&d, TaskWeighting::Uniform);
        assert!(u.iter().all(|x| (x - 1.0 / 9.0).abs() < 1e-12));
    }

    /// A 200 Hz task turning about z at 0.3 rad/s, its gyro biased; ground truth at every
    /// sample, the query set's masked (so the outer loss's L^D sees nothing).
    fn turning_task(support_seconds: f64) -> Task {
        use crate::core::{ImuSample, PoseSample, Recording};
        use nalgebra::{UnitQuaternion, Vector3};
        let n = 4000;
        let stamp = |i: usize| i as i64 * 5_000_000;
        let imu = (0..n)
            .map(|i| ImuSample { stamp_ns: stamp(i), gyro: Vector3::new(0.01, -0.02, 0.3 + 0.05), accel: Vector3::new(0.0, 0.0, 9.81) })
            .collect();
        let ground_truth = (0..n)
            .map(|i| PoseSample {
                stamp_ns: stamp(i),
                position_in_world: Vector3::zeros(),
                world_from_body: UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3 * i as f64 * 0.005),
            })
            .collect();
        let rec = Recording { name: "turn".into(), imu, ground_truth, temperature: vec![] };
        let src = crate::train::config::SourceConfig { sequence: Some("sim/turn".into()), ..Default::default() };
        let dcfg = crate::train::config::DatasetConfig {
            root: ".".into(),
            train: vec![],
            validation: vec![],
            test: vec![],
            monitor: vec![],
            support_seconds,
            max_interpolation_gap_ms: 50.0,
            max_nearest_gt_ms: 10.0,
            power_on_bias: Default::default(),
        };
        let task = data::task_from_recording(rec, &src, &dcfg, Some(support_seconds)).unwrap();
        let _ = task.valid.narrow(0, task.support_end as i64, (task.len() - task.support_end) as i64).fill_(0.0);
        task
    }

    /// A model with its Generator zeroed whose correction `(Ĉ_ω − I) ω` is `share` times what
    /// the biased turning task needs (gyro (0.01, −0.02, 0.35), truth (0, 0, 0.3) rad/s).
    fn net_correcting_a_share(share: f32) -> (VarStore, Net) {
        let vs = VarStore::new(Device::Cpu);
        let net = Net::new(&crate::model::Config::for_mode(Mode::FsdaF), &vs.root()).unwrap();
        zero_init_correction(&vs, &net).unwrap();
        let delta = Tensor::from_slice(&[-share, 0.0, 0.0, 0.0, -share, 0.0, 0.0, 0.0, -share * 0.05 / 0.35]).reshape([3, 3]);
        tch::no_grad(|| vs.variables()["gyro_calib.delta"].shallow_clone().copy_(&delta));
        (vs, net)
    }

    /// A correction exactly twice what the task needs: the fitted gain is one half, where the
    /// task's AOE is zero.
    #[test]
    fn the_correction_gain_undoes_a_doubled_correction() {
        let task = turning_task(10.0);
        let (_vs, net) = net_correcting_a_share(2.0);
        let opts = EvalOptions { max_gap_ns: 50_000_000 };
        let gains = fit_correction_gains(&net, std::slice::from_ref(&task), &opts).unwrap();
        assert_eq!(gains.keys().collect::<Vec<_>>(), ["sim"]);
        assert!((gains["sim"] - 0.5).abs() < 0.01, "{gains:?}");
        let at = |g: f64| evaluate_net_with_gain(&net, &task, &opts, g).unwrap().aoe_deg;
        assert!(at(gains["sim"]) < 0.05 && at(1.0) > 10.0 * at(gains["sim"]) + 1.0, "{} vs {}", at(gains["sim"]), at(1.0));
    }

    /// A correction half of what the task needs would want g = 2; g is a share, so it stops
    /// at 1 (the network as trained), never extrapolating the correction.
    #[test]
    fn the_correction_gain_never_exceeds_one() {
        let task = turning_task(10.0);
        let (_vs, net) = net_correcting_a_share(0.5);
        let opts = EvalOptions { max_gap_ns: 50_000_000 };
        let at = |g: f64| evaluate_net_with_gain(&net, &task, &opts, g).unwrap().aoe_deg;
        assert!(at(2.0) < 0.05 && at(1.0) > 1.0, "{} vs {}", at(2.0), at(1.0));
        let gains = fit_correction_gains(&net, std::slice::from_ref(&task), &opts).unwrap();
        assert_eq!(gains["sim"], 1.0, "{gains:?}");
    }

    /// One batched MAML step of the model and `train.maml` given (YAML flow mappings) on the
    /// biased, turning task; the VarStore then holds the step's gradients.
    fn one_batched_step(model: &str, maml: &str) -> (VarStore, TrainConfig) {
        let text = format!(
            "model: {model}\ndataset: {{train: [{{sequence: a}}]}}\ntrain: {{epochs: 1, loss: {{skip_first_samples: 0}}, maml: {maml}}}\n"
        );
        let cfg = TrainConfig::parse(&text).unwrap();
        cfg.validate().unwrap();
        let tasks = vec![turning_task(10.0)];
        let vs = VarStore::new(tch::Device::Cpu);
        let net = Net::new(&cfg.model, &vs.root()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        maml_step_batched(&net, &cfg, &tasks, &mut rng);
        (vs, cfg)
    }

    /// Per-IMU Ĉ_ω in the batched step: the biased task of IMU `b` trains row `b` of
    /// `gyro_calib.per_imu` only (its support windows, scored at the meta weights, are the only
    /// ones with ground truth), and a training task of an unlisted IMU is refused.
    #[test]
    fn each_imu_trains_its_own_gyro_calibration() {
        let text = "model: {mode: fsda_f, imu_calibrations: [a, b]}\ndataset: {train: [{sequence: a}]}\n\
                    train: {epochs: 1, loss: {skip_first_samples: 0}, maml: {first_order: true, batch_tasks: true, \
                    support_window_samples: 700, query_window_samples: 700, unadapted_support_weight: 1}}\n";
        let cfg = TrainConfig::parse(text).unwrap();
        cfg.validate().unwrap();
        let mut task = turning_task(10.0);
        task.imu_name = "b".into();
        let vs = VarStore::new(tch::Device::Cpu);
        let net = Net::new(&cfg.model, &vs.root()).unwrap();
        let mut data = Datasets { train: vec![task], validation: vec![], test: vec![turning_task(10.0)], monitor: vec![] };
        data.test[0].imu_name = "robot".into();
        assign_calibration_rows(&net, &mut data, &[]).unwrap();
        assert_eq!((data.train[0].calibration_row, data.test[0].calibration_row), (Some(1), Some(2)));
        maml_step_batched(&net, &cfg, &data.train, &mut ChaCha8Rng::seed_from_u64(3));
        let g = vs.variables()["gyro_calib.per_imu"].grad();
        let norm = |k: i64| g.get(k).abs().sum(Kind::Double).double_value(&[]);
        assert_eq!(norm(0), 0.0, "IMU a has no data");
        assert!(norm(1) > 0.0, "IMU b's Ĉ_ω gets the gradient");
        data.train[0].imu_name = "c".into();
        let err = assign_calibration_rows(&net, &mut data, &[]).unwrap_err().to_string();
        assert!(err.contains("\"c\"") && err.contains("imu_calibrations"), "{err}");
        // A calibrated IMU trains with I: its own row gets no gradient.
        data.train[0].imu_name = "b".into();
        assign_calibration_rows(&net, &mut data, &["b".into()]).unwrap();
        assert_eq!(data.train[0].calibration_row, Some(2));
        for mut t in vs.trainable_variables() {
            t.zero_grad();
        }
        maml_step_batched(&net, &cfg, &data.train, &mut ChaCha8Rng::seed_from_u64(3));
        let g = vs.variables()["gyro_calib.per_imu"].grad();
        assert_eq!(g.abs().sum(Kind::Double).double_value(&[]), 0.0, "a calibrated IMU's Ĉ_ω stays I");
    }

    #[test]
    fn support_windows_are_scored_at_the_meta_weights_only_when_asked() {
        let generator_grad = |weight: f64| {
            let maml = format!(
                "{{first_order: true, batch_tasks: true, support_window_samples: 700, query_window_samples: 700, unadapted_support_weight: {weight}}}"
            );
            let (vs, _) = one_batched_step("{mode: fsda_f}", &maml);
            vs.variables()
                .iter()
                .filter(|(k, _)| k.starts_with("generator."))
                .map(|(_, v)| {
                    let g = v.grad();
                    if g.defined() {
                        g.abs().sum(tch::Kind::Double).double_value(&[])
                    } else {
                        0.0
                    }
                })
                .sum::<f64>()
        };
        // Without λ_s the Generator learns from the query set alone (masked here); with it, the
        // support windows' denoising loss at θ_e reaches it.
        assert_eq!(generator_grad(0.0), 0.0);
        assert!(generator_grad(1.0) > 0.0);
    }

    /// The selection score weights datasets like the training tasks: with `per_domain` three
    /// EuRoC sequences at 6° and one TUM-VI room at 1° score (6 + 1) / 2, not (18 + 1) / 4;
    /// only each recording's latest evaluation counts.
    #[test]
    fn the_validation_score_weights_datasets_like_the_tasks() {
        let seq = |source: &str, aoes: &[f64]| SequenceEvals {
            name: source.into(),
            source: source.into(),
            raw: OrientationErrors { aoe_deg: 100.0, ..Default::default() },
            evals: aoes.iter().enumerate().map(|(i, &a)| (10 * (i + 1), OrientationErrors { aoe_deg: a, ..Default::default() })).collect(),
        };
        let v = vec![
            seq("euroc/MH_01_easy", &[9.0, 6.0]),
            seq("euroc/MH_03_medium", &[9.0, 6.0]),
            seq("euroc/V1_02_medium", &[9.0, 6.0]),
            seq("tumvi/dataset-room1_512_16", &[3.0, 1.0]),
        ];
        assert!((validation_score(&v, None, TaskWeighting::PerDomain).unwrap() - 3.5).abs() < 1e-12);
        assert!((validation_score(&v, None, TaskWeighting::Uniform).unwrap() - 4.75).abs() < 1e-12);
        // At epoch 10: (9 + 3) / 2.
        assert!((validation_score(&v, Some(10), TaskWeighting::PerDomain).unwrap() - 6.0).abs() < 1e-12);
        assert_eq!(validation_score(&v, Some(30), TaskWeighting::PerDomain), None);
        assert_eq!(validation_score(&[], None, TaskWeighting::PerDomain), None);
        assert_eq!(validation_score(&[seq("euroc/MH_01_easy", &[])], None, TaskWeighting::Uniform), None);
    }

    /// The batched inner loop steps each task on its own copy of θ_e: with task i's loss
    /// c_i · Σ θ (task 1 also reading task 0's copy, as BatchNorm couples them), the first-order
    /// step moves copy 0 by α (c_0 + 0.1 c_1) and copy 1 by α c_1, not both by the gradient of the
    /// summed losses with respect to θ_e (what shallow clones of θ_e gave, v9's training).
    #[test]
    fn the_batched_inner_step_is_per_task() {
        let theta = vec![Tensor::ones([3], (Kind::Float, Device::Cpu)).set_requires_grad(true)];
        let (c0, c1, lr) = (1.0, 5.0, 0.1);
        let maml = |first_order: bool, unadapted_support_weight: f64| super::super::config::MamlConfig {
            inner_lr: lr,
            inner_steps: 1,
            first_order,
            unadapted_support_weight,
            ..Default::default()
        };
        let losses = |fast: &[Vec<Tensor>]| {
            let sum = |t: &Tensor| t.sum(Kind::Float);
            vec![sum(&fast[0][0]) * c0, (sum(&fast[1][0]) + sum(&fast[0][0]) * 0.1) * c1]
        };
        for first_order in [true, false] {
            let (fast, sup, at_meta) = inner_adapt_batched(&theta, &[0.25, 0.75], &maml(first_order, 2.0), losses);
            let v = |t: &Tensor| Vec::<f32>::try_from(t).unwrap();
            let want0 = 1.0 - lr * (c0 + 0.1 * c1);
            assert!(v(&fast[0][0]).iter().all(|x| (f64::from(*x) - want0).abs() < 1e-6), "{:?}", v(&fast[0][0]));
            assert!(v(&fast[1][0]).iter().all(|x| (f64::from(*x) - (1.0 - lr * c1)).abs() < 1e-6), "{:?}", v(&fast[1][0]));
            // Σ w_i L_i at θ_e = 1: 0.25 · 3 c0 + 0.75 · 3.3 c1.
            assert!((sup - (0.25 * 3.0 * c0 + 0.75 * 3.3 * c1)).abs() < 1e-4, "{sup}");
            // λ_s · Σ w_i L_i at θ_e stays in the graph and reaches θ_e: 2 (0.25 c0 + 0.75 · 1.1 c1).
            at_meta.unwrap().backward();
            let g = v(&theta[0].grad());
            assert!(g.iter().all(|x| (f64::from(*x) - 2.0 * (0.25 * c0 + 0.75 * 1.1 * c1)).abs() < 1e-5), "{g:?}");
            let _ = theta[0].grad().zero_();
        }
        let (_, _, at_meta) = inner_adapt_batched(&theta, &[0.5, 0.5], &maml(true, 0.0), losses);
        assert!(at_meta.is_none());
        // The shared step (v9's): both copies move by α ∂(Σ L_i)/∂θ_e = α (c0 + 1.1 c1).
        for first_order in [true, false] {
            let shared = super::super::config::MamlConfig { shared_inner_step: true, ..maml(first_order, 0.0) };
            let (fast, _, _) = inner_adapt_batched(&theta, &[0.5, 0.5], &shared, losses);
            let want = 1.0 - lr * (c0 + 1.1 * c1);
            for copy in &fast {
                let v = Vec::<f32>::try_from(&copy[0]).unwrap();
                assert!(v.iter().all(|x| (f64::from(*x) - want).abs() < 1e-6), "{v:?}");
            }
        }
    }

    /// `shared_inner_step` is one step for the whole batch: refused without `batch_tasks` or
    /// with more than one inner step, where "shared" would not say what is computed.
    #[test]
    fn a_shared_inner_step_needs_one_batched_step() {
        let parse = |maml: &str| {
            TrainConfig::parse(&format!(
                "model: {{mode: fsda_f}}\ndataset: {{train: [{{sequence: a}}]}}\ntrain: {{epochs: 1, maml: {maml}}}\n"
            ))
            .unwrap()
            .validate()
        };
        assert!(parse("{batch_tasks: true, shared_inner_step: true}").is_ok());
        for bad in ["{batch_tasks: false, shared_inner_step: true}", "{batch_tasks: true, inner_steps: 2, shared_inner_step: true}"] {
            let e = parse(bad).unwrap_err();
            assert!(e.to_string().contains("shared_inner_step"), "{bad}: {e}");
        }
    }

    /// The batched MAML step feeds the Generator `[embedding, IMU]` when the model asks for
    /// it: the skip columns of the Generator's first conv get a gradient.
    #[test]
    fn the_batched_step_trains_a_generator_that_sees_the_imu() {
        let (vs, cfg) = one_batched_step(
            "{mode: fsda_f, generator_sees_imu: true}",
            "{first_order: true, batch_tasks: true, support_window_samples: 700, query_window_samples: 700, unadapted_support_weight: 1.0}",
        );
        let w = &vs.variables()["generator.conv0.weight"];
        assert_eq!(w.size()[1], cfg.model.embedding.dim + 6);
        let skip_grad = w.grad().narrow(1, cfg.model.embedding.dim, 6).abs().sum(tch::Kind::Double).double_value(&[]);
        assert!(skip_grad > 0.0);
    }

    /// `restructor_batch_norm` reaches the batched step: the Restructor's
    /// BatchNorm is used (γ gets a gradient, the running mean moves) while the Generator has none.
    #[test]
    fn the_batched_step_uses_batch_norm_in_the_restructor_alone() {
        let (vs, _) = one_batched_step(
            "{mode: fsda_f, batch_norm: false, restructor_batch_norm: true}",
            "{first_order: true, batch_tasks: true, support_window_samples: 700, query_window_samples: 700, unadapted_support_weight: 1.0}",
        );
        let vars = vs.variables();
        assert!(!vars.keys().any(|k| k.starts_with("generator.bn")));
        let abs_sum = |t: &Tensor| t.abs().sum(tch::Kind::Double).double_value(&[]);
        assert!(abs_sum(&vars["restructor.bn0.weight"].grad()) > 0.0);
        assert!(abs_sum(&vars["restructor.bn0.running_mean"]) > 0.0);
    }

    /// An embedding given to `Net::forward_with` (the batched step's per-task embeddings) gives
    /// the modules' own training forward, whatever the normalisation: with dropout and the
    /// Restructor's noise off, the Generator's and the Restructor's outputs are equal.
    #[test]
    fn a_given_embedding_gives_the_modules_forward() {
        for model in [
            "{mode: fsda_f}",
            "{mode: fsda_f, batch_norm: false}",
            "{mode: fsda_f, batch_norm: false, restructor_batch_norm: true}",
            "{mode: fsda_f, batch_norm: false, layer_norm: true}",
            "{mode: fsda_f, batch_norm: false, layer_norm: true, restructor_batch_norm: true, generator_sees_imu: true}",
        ] {
            let model = model.replace('}', ", dropout: 0.0, restructor_noise_std: 0.0}");
            let cfg =
                TrainConfig::parse(&format!("model: {model}\ndataset: {{train: [{{sequence: a}}]}}\ntrain: {{epochs: 1}}\n")).unwrap();
            let vs = VarStore::new(Device::Cpu);
            let net = Net::new(&cfg.model, &vs.root()).unwrap();
            crate::model::cnn::perturb_layer_norms(&vs);
            let u = Tensor::randn([2, 800, 6], (Kind::Float, Device::Cpu));
            let module = net.forward_with(&u, &ForwardOptions { train: true, reconstruct: true, ..Default::default() });
            let e = net.embedding().unwrap().forward(&net.normalize(&u));
            let given = net.forward_with(&u, &ForwardOptions { train: true, reconstruct: true, embedding: Some(&e), ..Default::default() });
            let diff = |a: &Tensor, b: &Tensor| (a - b).abs().max().double_value(&[]);
            let d =
                [diff(&module.gyro, &given.gyro), diff(module.reconstruction.as_ref().unwrap(), given.reconstruction.as_ref().unwrap())];
            assert!(d[0] < 1e-6 && d[1] < 1e-5, "{model}: Generator {:e}, Restructor {:e}", d[0], d[1]);
            let other =
                net.forward_with(&u, &ForwardOptions { train: true, embedding: Some(&(&e + e.randn_like() * 0.5)), ..Default::default() });
            assert!(diff(&module.gyro, &other.gyro) > 1e-4, "{model}: the given embedding was not used");
        }
    }

    /// With `layer_norm`, one batched step gives every LayerNorm γ a gradient.
    #[test]
    fn the_batched_step_trains_the_channel_layer_norm() {
        let cfg = crate::model::Config::for_mode(Mode::FsdaF);
        let (vs, _) = one_batched_step(
            "{mode: fsda_f, batch_norm: false, layer_norm: true}",
            "{first_order: true, batch_tasks: true, support_window_samples: 700, query_window_samples: 700, unadapted_support_weight: 1.0}",
        );
        let vars = vs.variables();
        assert!(!vars.keys().any(|k| k.contains(".bn")));
        let lns: Vec<_> = vars.iter().filter(|(k, _)| k.contains(".ln") && k.ends_with("weight")).collect();
        assert_eq!(lns.len(), 2 * (cfg.generator.kernel_sizes.len() - 1));
        for (k, t) in lns {
            assert!(t.grad().abs().sum(Kind::Double).double_value(&[]) > 0.0, "{k} has no gradient");
        }
    }
}
