//! One training run as an object with steps: [`TrainRun::start`] (every check that can fail,
//! the data, the network, a resumed checkpoint), [`TrainRun::run_epochs`] (one optimiser step
//! an epoch, held-out evaluations, checkpoints, the best epoch kept) and [`TrainRun::finish`]
//! (the exported weights chosen, the gains per IMU, the test scores, the summary and the
//! export). [`train`] runs the three.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tch::{nn::VarStore, Device, Tensor};

use super::checkpoint::{self, CheckpointMeta, Loaded};
use super::config::TrainConfig;
use super::data::{self, Task};
use super::error::{refuse, Context, TrainError};
use super::fit::{
    assign_calibration_rows, corrected_gyro, epoch_seed, eval_opts, evaluate_net, evaluate_net_with_gain, evaluate_raw,
    fit_correction_gains, flush_denormals_to_zero, init_from_model, load_datasets, maml_step, maml_step_batched, plain_step,
    refuse_to_restart_over_unfinished, task_weights, validation_score, with_overrides, zero_init_correction, Datasets, RunOptions,
    StepLosses, Stopped,
};
use super::optim::Adam;
use super::report::{EpochRecord, SequenceEvals, TaskInfo, TestResult, TrainSummary};
use crate::eval::{evaluate, EvalOptions};
use crate::model::export::{export_model, ExportInfo};
use crate::model::predict::with_correction_gain;
use crate::model::{Mode, Net};

/// Trains `cfg` as `opts` says: [`TrainRun::start`], [`TrainRun::run_epochs`],
/// [`TrainRun::finish`].
pub fn train(cfg: &TrainConfig, opts: &RunOptions) -> Result<TrainSummary, TrainError> {
    let mut run = TrainRun::start(cfg, opts)?;
    run.run_epochs()?;
    run.finish()
}

/// What a run has recorded besides its weights: what its checkpoint carries.
struct RunRecord {
    history: Vec<EpochRecord>,
    validation: Vec<SequenceEvals>,
    monitor: Vec<SequenceEvals>,
    /// The best validated epoch and its score, and its weights.
    best: Option<(usize, f64)>,
    best_vars: Option<BTreeMap<String, Tensor>>,
}

/// A run between its steps.
pub struct TrainRun<'o> {
    cfg: TrainConfig,
    opts: &'o RunOptions,
    /// Read at the start: the checkout can move during an hour of training, and the export
    /// must name the code that trained.
    code_revision: Option<String>,
    resumed_from_epoch: Option<usize>,
    data: Datasets,
    fingerprints: BTreeMap<String, String>,
    eopts: EvalOptions,
    vs: VarStore,
    net: Net,
    adam: Adam,
    record: RunRecord,
    start_epoch: usize,
    /// Seconds trained before a resumed checkpoint: the wall-time budget is the whole run's.
    prior_seconds: f64,
    started: Instant,
    /// Epochs run by this process.
    ran: usize,
    /// Where the wall-time budget stopped the run.
    stopped_at: Option<usize>,
    progress: ProgressBar,
}

impl<'o> TrainRun<'o> {
    /// Every check that can fail, then the data, the network and its optimiser, restored from
    /// `opts.resume` when given.
    pub fn start(cfg: &TrainConfig, opts: &'o RunOptions) -> Result<Self, TrainError> {
        let cfg = with_overrides(cfg, opts.seed, opts.epochs)?;
        let code_revision = crate::model::export::code_revision();
        set_up_threads(&cfg);
        tch::manual_seed(cfg.train.seed as i64);

        let resume = opts.resume.as_deref().map(checkpoint::load).transpose()?;
        match &resume {
            Some(r) => check_resume(r, &cfg)?,
            None => refuse_to_restart_over_unfinished(&opts.out_dir, &opts.name)?,
        }
        let mut data = load_datasets(&cfg)?;
        let fingerprints = data.fingerprints();
        if let Some(r) = &resume {
            check_resumed_data(r, &fingerprints)?;
        }
        let eopts = eval_opts(&cfg);

        let mut vs = VarStore::new(Device::Cpu);
        let net = Net::new(&cfg.model, &vs.root())?;
        assign_calibration_rows(&net, &mut data, &cfg.train.calibrated_imus)?;
        let (mean, std) = data::normalization(&data.train);
        net.set_normalization(&mean, &std)?;
        if cfg.train.zero_init_correction && resume.is_none() && cfg.train.init_from.is_none() {
            zero_init_correction(&vs, &net)?;
        }
        if let Some(path) = &cfg.train.init_from {
            init_from_model(&mut vs, &cfg, path)?;
        }
        if cfg.model.mode == Mode::FsdaF {
            let w = task_weights(&data.train, cfg.train.task_weighting);
            tracing::info!("task weights ({:?}): {:?}", cfg.train.task_weighting, w);
        }
        let mut adam = Adam::new(&vs);
        tracing::info!("normalisation from {} training recordings: mean {mean:?}, std {std:?}", data.train.len());

        let mut record = RunRecord { history: Vec::new(), validation: Vec::new(), monitor: Vec::new(), best: None, best_vars: None };
        let (mut start_epoch, mut prior_seconds) = (0, 0.0);
        if let Some(r) = &resume {
            restore(r, &vs, &mut adam, cfg.train.seed, &mut record)?;
            start_epoch = r.meta.epoch;
            prior_seconds = r.meta.train_seconds;
            tracing::info!(
                "resumed from {} at epoch {start_epoch}",
                opts.resume.as_ref().map_or(String::new(), |p| p.display().to_string())
            );
        }
        carry_evaluations(&mut record, &data, &eopts, resume.is_some())?;
        let progress = progress_bar(opts, &cfg, start_epoch);
        Ok(TrainRun {
            resumed_from_epoch: resume.as_ref().map(|r| r.meta.epoch),
            cfg,
            opts,
            code_revision,
            data,
            fingerprints,
            eopts,
            vs,
            net,
            adam,
            record,
            start_epoch,
            prior_seconds,
            started: Instant::now(),
            ran: 0,
            stopped_at: None,
            progress,
        })
    }

    /// Every epoch left, up to the configured count or the wall-time budget; a stop asked for
    /// (Ctrl-C) writes the checkpoint and returns [`Stopped`].
    pub fn run_epochs(&mut self) -> Result<(), TrainError> {
        for epoch in self.start_epoch..self.cfg.train.epochs {
            if !self.epoch(epoch)? {
                break;
            }
        }
        self.progress.finish();
        Ok(())
    }

    /// One optimiser step, its record, the held-out evaluation when due and a checkpoint when
    /// due. False: the wall-time budget is spent.
    fn epoch(&mut self, epoch: usize) -> Result<bool, TrainError> {
        let (cfg, epochs) = (&self.cfg, self.cfg.train.epochs);
        let t0 = Instant::now();
        tch::manual_seed(epoch_seed(cfg.train.seed, epoch));
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.train.seed);
        rng.set_stream(epoch as u64);
        let _: u32 = rng.gen();
        let lr = cfg.train.schedule.lr(cfg.train.lr, epoch);
        self.adam.zero_grad();
        let l = self.step(&mut rng);
        if !l.loss.is_finite() {
            refuse!("epoch {epoch}: the loss is {} — lower train.lr (or train.maml.inner_lr)", l.loss);
        }
        let grad_norm = self.adam.grad_norm();
        self.adam.step(lr, cfg.train.weight_decay);
        self.ran += 1;
        self.record.history.push(EpochRecord {
            epoch,
            lr,
            loss: l.loss,
            increment: l.increment,
            reconstruction: l.reconstruction,
            support_loss: l.support,
            grad_norm,
            seconds: t0.elapsed().as_secs_f64(),
        });
        let done = epoch + 1;
        let mut msg = format!(
            "loss {:.4} (L_D {:.4}{}) lr {lr:.2e}",
            l.loss,
            l.increment,
            l.reconstruction.map_or(String::new(), |r| format!(", L_R {r:.4}"))
        );
        if let Some(s) = l.support {
            msg.push_str(&format!(", support {s:.4}"));
        }
        let over_budget = self.cfg.train.max_train_seconds > 0.0 && self.seconds() > self.cfg.train.max_train_seconds && done < epochs;
        if over_budget {
            tracing::warn!(
                "epoch {done}: past the wall-time budget of {:.0} s; stopping and exporting this epoch",
                self.cfg.train.max_train_seconds
            );
            self.stopped_at = Some(done);
        }
        let eval_now = self.cfg.train.eval_every > 0 && done.is_multiple_of(self.cfg.train.eval_every) || done == epochs || over_budget;
        if eval_now && !(self.data.validation.is_empty() && self.data.monitor.is_empty()) {
            self.evaluate_held_out(done, &mut msg)?;
        } else if done.is_multiple_of((epochs / 20).max(1)) {
            tracing::info!("epoch {done}: {msg}");
        }
        self.progress.set_message(msg);
        self.progress.set_position(done as u64);
        if over_budget {
            return Ok(false);
        }
        let stop = done < epochs && self.opts.stop_requested.is_some_and(|f| f());
        let every = self.cfg.train.checkpoint_every;
        if stop || every > 0 && done.is_multiple_of(every) && done < epochs {
            let checkpoint = self.save_checkpoint(done, self.seconds())?;
            if stop {
                self.progress.abandon();
                return Err(Stopped { epoch: done, epochs, checkpoint }.into());
            }
        }
        Ok(true)
    }

    /// The strategy's step (losses back-propagated, not yet applied).
    fn step(&self, rng: &mut ChaCha8Rng) -> StepLosses {
        let (net, cfg, tasks) = (&self.net, &self.cfg, &self.data.train);
        match cfg.model.mode {
            Mode::FsdaF if cfg.train.maml.batch_tasks => maml_step_batched(net, cfg, tasks, rng),
            Mode::FsdaF => maml_step(net, cfg, tasks, rng),
            Mode::Fsda | Mode::Digdl => plain_step(net, cfg, tasks, rng),
        }
    }

    /// The validation and monitor recordings scored after epoch `done`; the best validated
    /// epoch kept.
    fn evaluate_held_out(&mut self, done: usize, msg: &mut String) -> Result<(), TrainError> {
        let (net, data, eopts) = (&self.net, &self.data, &self.eopts);
        let record = &mut self.record;
        let evals = |v: &mut Vec<SequenceEvals>, m: &mut Vec<SequenceEvals>| -> Result<(), TrainError> {
            for (v, task) in v.iter_mut().zip(&data.validation).chain(m.iter_mut().zip(&data.monitor)) {
                v.evals.push((done, evaluate_net(net, task, eopts)?));
            }
            Ok(())
        };
        evals(&mut record.validation, &mut record.monitor)?;
        let how = self.cfg.train.task_weighting;
        let m = validation_score(&record.validation, None, how).unwrap_or(f64::NAN);
        let mon = validation_score(&record.monitor, None, how).map_or(String::new(), |x| format!(", monitor {x:.3}°"));
        tracing::info!("epoch {done}: {msg}; validation AOE {m:.3}°{mon}");
        msg.push_str(&format!(", val AOE {m:.2}°"));
        if self.cfg.train.select_best && !data.validation.is_empty() && record.best.is_none_or(|(_, b)| m < b) {
            record.best = Some((done, m));
            record.best_vars = Some(checkpoint::snapshot(&self.vs));
        }
        Ok(())
    }

    /// Seconds trained, a resumed checkpoint's included.
    fn seconds(&self) -> f64 {
        self.prior_seconds + self.started.elapsed().as_secs_f64()
    }

    fn save_checkpoint(&self, epoch: usize, seconds: f64) -> Result<PathBuf, TrainError> {
        let r = &self.record;
        let meta = CheckpointMeta {
            format_version: 1,
            epoch,
            adam_step: self.adam.step,
            seed: self.cfg.train.seed,
            config: self.cfg.clone(),
            history: r.history.clone(),
            validation: r.validation.clone(),
            monitor: r.monitor.clone(),
            best: r.best,
            train_seconds: seconds,
            pair_token: None,
            data_fingerprints: self.fingerprints.clone(),
        };
        checkpoint::save(&self.opts.out_dir, &self.opts.name, &self.vs, &self.adam, r.best_vars.as_ref(), &meta)
    }

    /// The last checkpoint; the exported weights chosen; gains per IMU fitted; the test
    /// recordings scored; the model exported with its summary and curves.
    pub fn finish(mut self) -> Result<TrainSummary, TrainError> {
        let train_seconds = self.seconds();
        let epochs = self.cfg.train.epochs;
        let last_epoch = self.stopped_at.unwrap_or(epochs);
        let ckpt = self.save_checkpoint(last_epoch, train_seconds)?;
        tracing::info!("checkpoint {}", ckpt.display());
        let exported_epoch = self.choose_exported_weights(last_epoch)?;

        // `train.correction_gains`: one gain per IMU, fitted with the exported weights on the
        // validation recordings; the test recordings are then scored as deployed on their IMU.
        let gains = if self.cfg.train.correction_gains {
            fit_correction_gains(&self.net, &self.data.validation, &self.eopts)?
        } else {
            BTreeMap::new()
        };
        let validation_with_gain = self.validation_with_gain(&gains, exported_epoch)?;
        // A signal after the last epoch: the checkpoint above holds every epoch, and a resume
        // from it goes straight to the scoring and the export.
        let stopped = || Stopped { epoch: last_epoch, epochs, checkpoint: ckpt.clone() };
        let Some(test) = self.score_test(&gains)? else { return Err(stopped().into()) };

        let history = &self.record.history;
        let k = (history.len() / 4).clamp(1, 5);
        let mean_of = |h: &[EpochRecord]| h.iter().map(|r| r.loss).sum::<f64>() / h.len().max(1) as f64;
        let loss_first = mean_of(&history[..k.min(history.len())]);
        let loss_last = mean_of(&history[history.len().saturating_sub(k)..]);
        // A run resumed only to export (no new epoch) reports the whole run's mean.
        let seconds_per_epoch = if self.ran > 0 {
            self.started.elapsed().as_secs_f64() / self.ran as f64
        } else if last_epoch > 0 {
            train_seconds / last_epoch as f64
        } else {
            f64::NAN
        };
        let timing = Timing { exported_epoch, loss_first, loss_last, train_seconds, seconds_per_epoch };
        let metrics = self.metrics(&timing, &gains, &validation_with_gain, &test);
        let training_data = self.training_data();
        let files = crate::model::export::ExportPaths::new(&self.opts.out_dir, &self.opts.name);
        let imu_correction_gains = gains.clone();
        let summary = TrainSummary {
            name: self.opts.name.clone(),
            mode: self.cfg.model.mode,
            seed: self.cfg.train.seed,
            epochs: last_epoch,
            epochs_planned: self.stopped_at.map(|_| epochs),
            resumed_from_epoch: self.resumed_from_epoch,
            exported_epoch,
            loss_first,
            loss_last,
            train_seconds,
            seconds_per_epoch,
            threads: self.cfg.train.threads,
            tasks: self.data.train.iter().map(task_info).collect(),
            validation: std::mem::take(&mut self.record.validation),
            monitor: std::mem::take(&mut self.record.monitor),
            correction_gains: gains,
            validation_with_gain,
            test,
            history: std::mem::take(&mut self.record.history),
            model_json: files.metadata.display().to_string(),
            config: self.cfg.clone(),
        };
        if self.stop_requested() {
            return Err(stopped().into());
        }
        self.export(&summary, training_data, metrics, imu_correction_gains)?;
        Ok(summary)
    }

    fn stop_requested(&self) -> bool {
        self.opts.stop_requested.is_some_and(|f| f())
    }

    /// The best validated epoch's weights if asked, else the last, put in the network; returns
    /// their epoch.
    fn choose_exported_weights(&self, last_epoch: usize) -> Result<usize, TrainError> {
        if let (true, Some((e, _)), Some(snap)) = (self.cfg.train.select_best, self.record.best, self.record.best_vars.as_ref()) {
            checkpoint::restore_snapshot(&self.vs, snap)?;
            return Ok(e);
        }
        Ok(last_epoch)
    }

    /// The validation recordings scored with the fitted gains (none without gains).
    fn validation_with_gain(&self, gains: &BTreeMap<String, f64>, exported_epoch: usize) -> Result<Vec<SequenceEvals>, TrainError> {
        if gains.is_empty() {
            return Ok(Vec::new());
        }
        let mut out = Vec::new();
        for task in &self.data.validation {
            let errors = evaluate_net_with_gain(&self.net, task, &self.eopts, gain_of(gains, task))?;
            let raw = match self.record.validation.iter().find(|v| v.name == task.name) {
                Some(v) => v.raw.clone(),
                None => evaluate_raw(task, &self.eopts)?,
            };
            out.push(SequenceEvals { name: task.name.clone(), source: task.source.clone(), raw, evals: vec![(exported_epoch, errors)] });
        }
        Ok(out)
    }

    /// The test recordings scored as deployed (with their IMU's gain, and without it where it
    /// differs). `None`: a stop was asked for before one.
    fn score_test(&self, gains: &BTreeMap<String, f64>) -> Result<Option<Vec<TestResult>>, TrainError> {
        let mut test = Vec::new();
        for task in &self.data.test {
            if self.stop_requested() {
                return Ok(None);
            }
            let raw = evaluate_raw(task, &self.eopts)?;
            let gain = gain_of(gains, task);
            // One forward; scored with the gain, and without it when that differs.
            let gyro = corrected_gyro(&self.net, task)?;
            let model_without_gain = if gain == 1.0 { None } else { Some(evaluate(&task.rec, &gyro, &self.eopts)?) };
            let model = evaluate(&task.rec, &with_correction_gain(&task.rec.imu, gyro, gain), &self.eopts)?;
            tracing::info!(
                "test {}: AOE raw {:.2}° → model {:.2}°{}",
                task.name,
                raw.aoe_deg,
                model.aoe_deg,
                model_without_gain.as_ref().map_or(String::new(), |m| format!(" (gain {gain:.3}; {:.2}° at 1)", m.aoe_deg))
            );
            test.push(TestResult { name: task.name.clone(), source: task.source.clone(), raw, model, model_without_gain });
        }
        Ok(Some(test))
    }

    /// The figures the exported model's metadata carries.
    fn metrics(
        &self,
        timing: &Timing,
        gains: &BTreeMap<String, f64>,
        validation_with_gain: &[SequenceEvals],
        test: &[TestResult],
    ) -> BTreeMap<String, f64> {
        let (cfg, validation) = (&self.cfg, &self.record.validation);
        let exported_epoch = timing.exported_epoch;
        let mut metrics = BTreeMap::new();
        metrics.insert("epochs".to_string(), exported_epoch as f64);
        metrics.insert("loss_first".to_string(), timing.loss_first);
        metrics.insert("loss_last".to_string(), timing.loss_last);
        metrics.insert("train_seconds".to_string(), timing.train_seconds);
        metrics.insert("seconds_per_epoch".to_string(), timing.seconds_per_epoch);
        metrics.insert("threads".to_string(), cfg.train.threads as f64);
        metrics.insert("seed".to_string(), cfg.train.seed as f64);
        if let Some(e) = self.stopped_at {
            metrics.insert("stopped_at_budget".to_string(), e as f64);
        }
        let val_at_export: Vec<(f64, f64)> = validation
            .iter()
            .filter_map(|v| v.evals.iter().find(|(e, _)| *e == exported_epoch).map(|(_, e)| (v.raw.aoe_deg, e.aoe_deg)))
            .collect();
        for (v, (raw, m)) in validation.iter().zip(&val_at_export) {
            metrics.insert(format!("val.{}.raw_aoe_deg", v.name), *raw);
            metrics.insert(format!("val.{}.aoe_deg", v.name), *m);
        }
        if !val_at_export.is_empty() {
            let n = val_at_export.len() as f64;
            metrics.insert("val.mean_raw_aoe_deg".into(), val_at_export.iter().map(|x| x.0).sum::<f64>() / n);
            metrics.insert("val.mean_aoe_deg".into(), val_at_export.iter().map(|x| x.1).sum::<f64>() / n);
            if let Some(score) = validation_score(validation, Some(exported_epoch), cfg.train.task_weighting) {
                metrics.insert("val.score_deg".into(), score);
            }
        }
        if !gains.is_empty() {
            // The score of the model as deployed (with its gains) is the one seeds are chosen on.
            if let Some(score) = metrics.get("val.score_deg").copied() {
                metrics.insert("val.score_without_gain_deg".into(), score);
            }
            if let Some(score) = validation_score(validation_with_gain, Some(exported_epoch), cfg.train.task_weighting) {
                metrics.insert("val.score_deg".into(), score);
            }
            for v in validation_with_gain {
                metrics.insert(format!("val.{}.aoe_with_gain_deg", v.name), v.evals[0].1.aoe_deg);
            }
            for (imu, g) in gains {
                metrics.insert(format!("correction_gain.{imu}"), *g);
            }
        }
        for r in test {
            for (k, v) in [
                ("raw_aoe_deg", r.raw.aoe_deg),
                ("aoe_deg", r.model.aoe_deg),
                ("roll_rmse_deg", r.model.roll_rmse_deg),
                ("pitch_rmse_deg", r.model.pitch_rmse_deg),
                ("yaw_rmse_deg", r.model.yaw_rmse_deg),
                ("tilt_rmse_deg", r.model.tilt_rmse_deg),
                ("heading_rmse_deg", r.model.heading_rmse_deg),
            ] {
                metrics.insert(format!("test.{}.{k}", r.name), v);
            }
            if let Some(m) = &r.model_without_gain {
                metrics.insert(format!("test.{}.aoe_without_gain_deg", r.name), m.aoe_deg);
            }
        }
        if !test.is_empty() {
            let n = test.len() as f64;
            metrics.insert("test.mean_raw_aoe_deg".into(), test.iter().map(|r| r.raw.aoe_deg).sum::<f64>() / n);
            metrics.insert("test.mean_aoe_deg".into(), test.iter().map(|r| r.model.aoe_deg).sum::<f64>() / n);
        }
        metrics
    }

    /// The training recordings as the model's metadata names them.
    fn training_data(&self) -> Vec<String> {
        let few_shot = self.cfg.model.mode == Mode::FsdaF;
        self.data
            .train
            .iter()
            .map(|t| {
                if few_shot {
                    format!(
                        "{} (support {:.1} s + query {:.1} s)",
                        t.source,
                        t.support_end as f64 / t.rec.imu_rate_hz(),
                        (t.len() - t.support_end) as f64 / t.rec.imu_rate_hz()
                    )
                } else {
                    t.source.clone()
                }
            })
            .collect()
    }

    /// The IMUs of the training recordings, each once (`ModelMetadata::trained_imus`).
    fn trained_imus(&self) -> Vec<String> {
        let names: std::collections::BTreeSet<&str> = self.data.train.iter().map(|t| t.imu_name.as_str()).collect();
        names.into_iter().map(String::from).collect()
    }

    /// Each training recording's power-on bias its standstills measured, per IMU
    /// (`dataset.power_on_bias: remove`; none otherwise).
    fn trained_power_on_biases(&self) -> BTreeMap<String, Vec<crate::model::export::TrainedPowerOn>> {
        let mut out: BTreeMap<String, Vec<crate::model::export::TrainedPowerOn>> = BTreeMap::new();
        for t in &self.data.train {
            if let Some(super::power_on::RemovedConstant::Standstill { bias, stddev, still_s }) = &t.power_on_constant {
                out.entry(t.imu_name.clone()).or_default().push(crate::model::export::TrainedPowerOn {
                    recording: t.name.clone(),
                    bias_rad_s: (*bias).into(),
                    stddev_rad_s: (*stddev).into(),
                    still_s: *still_s,
                });
            }
        }
        out
    }

    /// The model and its summary written as one set, then the curves.
    fn export(
        &self,
        summary: &TrainSummary,
        training_data: Vec<String>,
        metrics: BTreeMap<String, f64>,
        imu_correction_gains: BTreeMap<String, f64>,
    ) -> Result<(), TrainError> {
        let (out_dir, name) = (&self.opts.out_dir, &self.opts.name);
        // A failure leaves the earlier pair whole.
        let summary_json = serde_json::to_string_pretty(summary).context("the run's summary")?;
        export_model(
            out_dir,
            name,
            &self.vs,
            &self.net,
            &ExportInfo {
                training_data,
                trained_imus: self.trained_imus(),
                metrics,
                code_revision: self.code_revision.clone(),
                adapted_from: None,
                power_on_bias_removed: self.cfg.dataset.power_on_bias == super::power_on::PowerOnBiasInTraining::Remove,
                trained_power_on_biases: self.trained_power_on_biases(),
                imu_correction_gains,
                side_files: vec![("train.json".into(), summary_json)],
            },
        )
        .with_context(|| format!("exporting {name} to {}", out_dir.display()))?;
        let curves = out_dir.join(format!("{name}.curves.png"));
        match super::curves::training_curves(summary, &curves) {
            Ok(()) => tracing::info!("curves {}", curves.display()),
            // The model and its summary are written; a figure is not worth failing the run.
            Err(e) => tracing::warn!("no training curves: {e}"),
        }
        Ok(())
    }
}

/// The run's losses and time, for its metrics.
struct Timing {
    exported_epoch: usize,
    loss_first: f64,
    loss_last: f64,
    train_seconds: f64,
    seconds_per_epoch: f64,
}

fn gain_of(gains: &BTreeMap<String, f64>, task: &Task) -> f64 {
    gains.get(&task.imu_name).copied().unwrap_or(1.0)
}

fn task_info(t: &Task) -> TaskInfo {
    TaskInfo {
        name: t.name.clone(),
        source: t.source.clone(),
        samples: t.len(),
        seconds: t.seconds(),
        support_samples: t.support_end,
        valid_fraction: t.valid_fraction,
    }
}

fn set_up_threads(cfg: &TrainConfig) {
    flush_denormals_to_zero();
    tch::set_num_threads(cfg.train.threads);
    if cfg.train.threads > 1 && !std::env::var("OMP_WAIT_POLICY").is_ok_and(|v| v.eq_ignore_ascii_case("passive")) {
        tracing::warn!(
            "train.threads = {} without OMP_WAIT_POLICY=passive: libgomp's spinning threads make epochs up to 6× slower \
             on a shared machine (docs/training.md); use threads: 1 or export OMP_WAIT_POLICY=passive",
            cfg.train.threads
        );
    }
}

/// A resume continues the same run: other data, losses or rates would make one model of two
/// runs and a summary that describes neither (train.init_from fine-tunes).
fn check_resume(r: &Loaded, cfg: &TrainConfig) -> Result<(), TrainError> {
    let changed = r.meta.config.run_differences(cfg);
    if !changed.is_empty() {
        refuse!(
            "--resume continues the run the checkpoint holds, and the config now differs in {}: start a new run (train.init_from fine-tunes from a model)",
            changed.join(", ")
        );
    }
    if cfg.train.epochs < r.meta.epoch {
        refuse!(
            "--resume: the checkpoint has {} epochs done, more than the {} asked for; a run cannot be shortened (its checkpoint and model are kept as they are)",
            r.meta.epoch,
            cfg.train.epochs
        );
    }
    Ok(())
}

/// Recordings of the same name only: the evaluation lists may change on a resume. The test
/// recordings are scored once, at the end: theirs may change.
fn check_resumed_data(r: &Loaded, fingerprints: &BTreeMap<String, String>) -> Result<(), TrainError> {
    if r.meta.data_fingerprints.is_empty() {
        return Ok(());
    }
    let changed: Vec<&str> = fingerprints
        .iter()
        .filter(|(k, _)| !k.starts_with("test."))
        .filter(|(k, v)| r.meta.data_fingerprints.get(*k).is_some_and(|was| was != *v))
        .map(|(k, _)| k.as_str())
        .collect();
    if !changed.is_empty() {
        refuse!(
            "--resume: the data of {} changed since the checkpoint (same paths and config, other samples): the run would continue on other data; restore the recordings, or delete the checkpoint to start a new run",
            changed.join(", ")
        );
    }
    Ok(())
}

/// The checkpoint's weights, optimiser state and record.
fn restore(r: &Loaded, vs: &VarStore, adam: &mut Adam, seed: u64, record: &mut RunRecord) -> Result<(), TrainError> {
    checkpoint::restore_vars(vs, &r.tensors, "vs")?;
    adam.load_state(r.meta.adam_step, &r.tensors)?;
    if r.meta.seed != seed {
        // The rest of the run would draw another seed's windows and be recorded as that seed's
        // run throughout.
        refuse!("--resume: the checkpoint was trained with seed {}, not {seed}: resume it with --seed {}", r.meta.seed, r.meta.seed);
    }
    record.history = r.meta.history.clone();
    record.validation = r.meta.validation.clone();
    record.monitor = r.meta.monitor.clone();
    record.best = r.meta.best;
    if record.best.is_some() && r.tensors.keys().any(|k| k.starts_with("best.")) {
        record.best_vars =
            Some(r.tensors.iter().filter_map(|(k, t)| k.strip_prefix("best.").map(|n| (n.to_string(), t.shallow_clone()))).collect());
    }
    Ok(())
}

/// The evaluation lists for this run's recordings: a resumed checkpoint's kept for the ones
/// still listed (by name and source), the others started with their raw score. The best epoch
/// is chosen again when the validation set is not the checkpoint's.
fn carry_evaluations(record: &mut RunRecord, data: &Datasets, eopts: &EvalOptions, resumed: bool) -> Result<(), TrainError> {
    let (validation, same_validation) = carry(std::mem::take(&mut record.validation), &data.validation, eopts)?;
    record.validation = validation;
    record.monitor = carry(std::mem::take(&mut record.monitor), &data.monitor, eopts)?.0;
    if resumed && !same_validation && record.best.is_some() {
        tracing::warn!(
            "--resume: the validation set is not the checkpoint's; the best epoch so far (epoch {}) was chosen on the other one, and the best is chosen again from here on",
            record.best.map_or(0, |b| b.0)
        );
        record.best = None;
        record.best_vars = None;
    }
    for v in &record.validation {
        tracing::info!("validation {}: raw AOE {:.2}°", v.name, v.raw.aoe_deg);
    }
    for v in &record.monitor {
        tracing::info!("monitor {} (never selected on): raw AOE {:.2}°", v.name, v.raw.aoe_deg);
    }
    Ok(())
}

/// `old` evaluations matched to `tasks` by name and source (before, they were paired by
/// position, and a new recording's figures were filed under the old one's name); true when
/// the list is the same.
fn carry(old: Vec<SequenceEvals>, tasks: &[Task], eopts: &EvalOptions) -> Result<(Vec<SequenceEvals>, bool), TrainError> {
    let same = old.len() == tasks.len() && old.iter().zip(tasks).all(|(o, t)| o.name == t.name && o.source == t.source);
    let mut old: BTreeMap<(String, String), SequenceEvals> = old.into_iter().map(|o| ((o.name.clone(), o.source.clone()), o)).collect();
    let list = tasks
        .iter()
        .map(|t| match old.remove(&(t.name.clone(), t.source.clone())) {
            Some(o) => Ok(o),
            None => Ok(SequenceEvals { name: t.name.clone(), source: t.source.clone(), raw: evaluate_raw(t, eopts)?, evals: vec![] }),
        })
        .collect::<Result<Vec<_>, TrainError>>()?;
    Ok((list, same))
}

fn progress_bar(opts: &RunOptions, cfg: &TrainConfig, start_epoch: usize) -> ProgressBar {
    let epochs = cfg.train.epochs as u64;
    let pb =
        if opts.progress { ProgressBar::new(epochs) } else { ProgressBar::with_draw_target(Some(epochs), ProgressDrawTarget::hidden()) };
    pb.set_style(
        ProgressStyle::with_template("{prefix} {elapsed_precise} [{bar:25}] {pos}/{len} epochs, ETA {eta_precise} {msg}")
            .expect("template")
            .progress_chars("=> "),
    );
    pb.set_prefix(format!("{} {:?}", opts.name, cfg.model.mode));
    pb.set_position(start_epoch as u64);
    pb
}
