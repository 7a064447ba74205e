//! On-demand few-shot adaptation (paper §III-B at test time): from a model's meta-learned
//! initialisation, a few to some tens of first-order steps of the inner loop on the
//! Embedding θ_e only (`θ_e ← θ_e − α ∇_{θ_e} L_support`, `L = L^R + γ L^D`, the trainer's own
//! [`crate::train::fit::embedding_inner_step`]) on a support recording with ground truth;
//! the Restructor, Generator and Ĉ_ω are frozen. The adapted model is accepted only if its
//! open-loop orientation error (AOE, [`crate::eval::evaluate`]) on a held-back query
//! recording is lower than the starting model's; otherwise it is rejected with the figures.
//!
//! Files: `config` (the settings), [`frame`] (is the ground truth in the IMU's frame?, in
//! `crate::ground_truth_frame`),
//! `networks` (the inner loop), [`calibration`] (Ĉ_ω in closed form) and
//! `calibration_candidate` (the model holding it), `report` (what was found), [`judge`]
//! (other power-ons), [`pieces`] and [`keep`] (what is kept without them), [`swap`] (the
//! node's between-two-samples model swap); this file runs them in order. See
//! docs/adaptation.md.

pub mod calibration;
mod calibration_candidate;
mod config;
/// The frame check lives below train and adapt, which both use it.
pub use crate::ground_truth_frame as frame;
pub mod judge;
pub mod keep;
mod networks;
pub mod pieces;
mod report;
pub mod swap;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use tch::{nn::VarStore, Device};

use crate::core::Recording;
use crate::eval::{EvalOptions, OrientationErrors};
use crate::model::export::{export_model, ExportInfo, ExportPaths, LoadedNet, ModelMetadata};
use crate::model::{ModelError, Net};
use crate::train::config::{DatasetConfig, SourceConfig};
use crate::train::data::{self, DataError, Task};
use crate::train::fit::{evaluate_net, evaluate_net_with_gain, evaluate_raw};

use calibration_candidate::{calibration_candidates, calibration_without_rotation, Calibrated, CalibrationCandidates};
use networks::{adapt_networks, AdaptedNetworks};

pub use config::{AdaptConfig, CancelFlag, FramePolicy, Keep, Optimizer};
pub use frame::{check_frame, FrameCheck};
pub use judge::{judge, judge_each, keep_judged, CarryOver, Judged};
pub use keep::keep_without_judge;
pub use pieces::PieceConfidence;
pub use report::{AdaptOutcome, AdaptReport, AdaptedKind, JudgedCandidate};

/// Why adaptation could not run.
#[derive(Debug, thiserror::Error)]
pub enum AdaptError {
    #[error("the model is {0:?}: only FSDA / FSDA-F models have an Embedding to adapt")]
    NoEmbedding(crate::model::Mode),
    #[error("{what}: {detail}")]
    TooLittleData { what: &'static str, detail: String },
    #[error(
        "ground truth is in another frame: a constant rotation of {:.1}° (quaternion w,x,y,z {:.4?}) takes the IMU's \
         increments onto the ground truth's (residual {:.2}° with it, {:.2}° without, {} increments{}); express the ground \
         truth in the IMU frame, or allow it to be re-expressed (frame policy `apply`)",
        .0.angle_deg, .0.gt_from_imu, .0.residual_deg, .0.residual_identity_deg, .0.increments,
        if .0.fully_observable { "" } else { "; only the tilt between the motion axes is observable" })]
    OtherFrame(Box<FrameCheck>),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Eval(#[from] crate::eval::EvalError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(
        "{0}: no standstill in the support set ({1}): its power-on gyro bias cannot be told from the IMU's lasting errors, \
         and adapting would write it into the model; record a few seconds at rest first, or adapt without the power-on \
         rule (power_on_bias: false: the model is then for this power-on only)"
    )]
    NoStandstill(String, String),
    #[error("cancelled (the node is shutting down): nothing was kept")]
    Cancelled,
    #[error("{0}")]
    Setting(#[from] crate::setting::InvalidSetting),
    /// The trainer's code the inner loop and the judges run (its data, its evaluations).
    #[error(transparent)]
    Train(#[from] crate::train::error::TrainError),
    #[error("step {step}: the support loss is {loss}: lower the inner learning rate")]
    Diverged { step: usize, loss: f64 },
    #[error("the adaptation report: {0}")]
    Report(#[from] serde_json::Error),
}

fn dataset_cfg(cfg: &AdaptConfig) -> DatasetConfig {
    DatasetConfig {
        root: PathBuf::from("."),
        train: vec![],
        validation: vec![],
        test: vec![],
        monitor: vec![],
        support_seconds: 0.0,
        max_interpolation_gap_ms: cfg.max_interpolation_gap_ms,
        max_nearest_gt_ms: cfg.max_nearest_gt_ms,
        power_on_bias: Default::default(),
    }
}

fn to_task(rec: &Recording, what: &'static str, cfg: &AdaptConfig) -> Result<Task, AdaptError> {
    if rec.imu.len() < 2 {
        return Err(AdaptError::TooLittleData { what, detail: format!("{} IMU samples", rec.imu.len()) });
    }
    if rec.ground_truth.is_empty() {
        return Err(AdaptError::Data(DataError::NoGroundTruth(format!("{what} {}", rec.name))));
    }
    let src = SourceConfig { bag: Some(rec.name.clone()), name: Some(rec.name.clone()), ..Default::default() };
    Ok(data::task_from_recording(rec.clone(), &src, &dataset_cfg(cfg), None)?)
}

/// At least `min_seconds` of the task covered by ground truth.
fn require_covered(task: &Task, what: &'static str, min_seconds: f64) -> Result<(), AdaptError> {
    if task.covered_seconds() >= min_seconds {
        return Ok(());
    }
    Err(AdaptError::TooLittleData {
        what,
        detail: format!(
            "{:.3} s of IMU with ground truth ({:.3} s span, {} samples), at least {min_seconds:.0} s needed",
            task.covered_seconds(),
            task.seconds(),
            task.len()
        ),
    })
}

/// A copy of `loaded` in a fresh VarStore (everything frozen: only the fast weights train).
fn copy_net(loaded: &LoadedNet) -> Result<(VarStore, Net), ModelError> {
    let mut vs = VarStore::new(Device::Cpu);
    let net = Net::new(&loaded.metadata.config, &vs.root())?;
    let src = loaded.vs.variables();
    tch::no_grad(|| -> Result<(), ModelError> {
        for (name, var) in vs.variables() {
            let s = src.get(&name).ok_or_else(|| ModelError::InvalidConfig(format!("variable {name} missing from the loaded model")))?;
            var.shallow_clone().f_copy_(s)?;
        }
        Ok(())
    })?;
    vs.freeze();
    Ok((vs, net))
}

/// Re-expresses the ground truth in the IMU's frame: `R_gt ← R_gt R_x`.
pub fn apply_frame(rec: &mut Recording, gt_from_imu: &nalgebra::UnitQuaternion<f64>) {
    for p in &mut rec.ground_truth {
        p.world_from_body *= gt_from_imu;
    }
}

/// Runs the frame check on a recording (ground truth slerped at the IMU stamps).
pub fn frame_check(rec: &Recording, cfg: &AdaptConfig) -> Option<FrameCheck> {
    let (gt, _) = data::ground_truth_at_imu(rec, &dataset_cfg(cfg));
    let rate = rec.nominal_imu_rate_hz().max(1.0);
    frame::check_frame_on(&frame::turning_increments(&rec.imu, &gt, rate, 0.05, 10), 0.05)
}

/// Adapts `loaded`'s Embedding on `support`, judges on `query` (see the module doc).
/// `loaded` is not modified. Errors: not an FSDA model, too little support or query data,
/// ground truth missing / not overlapping the IMU / in another frame (policy `error`).
pub fn adapt(loaded: &LoadedNet, support: &Recording, query: &Recording, cfg: &AdaptConfig) -> Result<AdaptOutcome, AdaptError> {
    adapt_knowing(loaded, support, query, cfg, None)
}

/// [`adapt`], with the power-on bias the caller measured earlier in this power-on (the node's,
/// from a standstill its buffer no longer holds): used where the support has no standstill.
pub fn adapt_knowing(
    loaded: &LoadedNet,
    support: &Recording,
    query: &Recording,
    cfg: &AdaptConfig,
    known_power_on_bias: Option<&crate::standstill::BiasEstimate>,
) -> Result<AdaptOutcome, AdaptError> {
    let t_all = Instant::now();
    cfg.validate()?;
    let meta = &loaded.metadata;
    let mode = loaded.metadata.mode;
    if !mode.has_embedding() {
        return Err(AdaptError::NoEmbedding(mode));
    }
    let AdaptSets { s_task, q_task, frame, frame_applied, support_power_on_bias, query_as_recorded } =
        AdaptSets::prepare(meta.rate_hz, support, query, cfg, known_power_on_bias)?;
    let eopts = EvalOptions { max_gap_ns: (cfg.max_interpolation_gap_ms * 1e6) as i64 };
    let (query_raw, query_power_on_bias) =
        query_baselines(&q_task, query_as_recorded, frame.as_ref().filter(|_| frame_applied), cfg, &eopts)?;
    let start_correction_gain = loaded.correction_gain();
    let query_before = evaluate_net_with_gain(&loaded.net, &q_task, &eopts, start_correction_gain)?;

    let AdaptedNetworks { vs, net, losses, step_seconds, initial_bias } = adapt_networks(loaded, &s_task, cfg)?;
    if cfg.cancel.is_cancelled() {
        return Err(AdaptError::Cancelled);
    }
    let query_after = evaluate_net(&net, &q_task, &eopts)?;
    // The other candidates: the lasting linear gyro error alone, the networks off; and with
    // the support's bias offset in motion.
    let (calibrated, with_offset, calibration_refused) = calibration_candidates_kept(loaded, &s_task, &q_task, &eopts, cfg)?;
    // Where no other power-on will judge: the same without the reference's rotation.
    let without_rotation = match frame.as_ref().filter(|_| !frame_applied) {
        Some(f) if cfg.power_on_bias && cfg.keep == Keep::Auto => {
            Some(calibration_without_rotation(loaded, &s_task, &q_task, &eopts, cfg, f)?)
        }
        _ => None,
    };
    if cfg.cancel.is_cancelled() {
        return Err(AdaptError::Cancelled);
    }
    // Better than the starting model, and than what the node runs without it on a new IMU.
    let floor = query_power_on_bias.as_ref().map_or(f64::INFINITY, |e| e.aoe_deg);
    let passes = |e: &OrientationErrors| e.aoe_deg < query_before.aoe_deg && e.aoe_deg < floor;
    let network_passes = cfg.keep != Keep::GyroCalibration && passes(&query_after);
    let calibration_passes = calibrated.as_ref().is_some_and(|c| passes(&c.query));
    let offset_passes = with_offset.as_ref().is_some_and(|c| passes(&c.query));
    let accepted = network_passes || calibration_passes || offset_passes;
    let others_aoe = [(AdaptedKind::Calibration, &calibrated), (AdaptedKind::CalibrationWithOffset, &with_offset)]
        .into_iter()
        .filter_map(|(k, c)| c.as_ref().map(|c| (k, c.query.aoe_deg)))
        .collect::<Vec<_>>();
    let verdict = if accepted { String::new() } else { query_verdict(query_before.aoe_deg, query_after.aoe_deg, &others_aoe, floor) };
    let mut report = AdaptReport {
        model: loaded.metadata.name.clone(),
        support: s_task.source.clone(),
        query: q_task.source.clone(),
        support_seconds: s_task.covered_seconds(),
        support_samples: s_task.len(),
        query_seconds: q_task.covered_seconds(),
        query_samples: q_task.len(),
        query_raw,
        query_before,
        query_after,
        accepted,
        start_correction_gain,
        initial_bias_rad_s: initial_bias,
        verdict,
        steps: losses.len(),
        losses,
        inner_lr: cfg.inner_lr,
        step_seconds,
        total_seconds: t_all.elapsed().as_secs_f64(),
        frame,
        frame_applied,
        support_power_on_bias,
        query_power_on_bias,
        judged: Vec::new(),
        judged_others: Vec::new(),
        carry_over: None,
        calibration: calibrated.as_ref().or(with_offset.as_ref()).map(|c| c.fit.clone()),
        query_calibrated: calibrated.as_ref().map(|c| c.query.clone()),
        query_calibrated_pieces: calibrated.as_ref().and_then(|c| c.pieces),
        query_calibrated_with_offset: with_offset.as_ref().map(|c| c.query.clone()),
        calibration_refused,
        calibration_rotation_left_out_deg: None,
        kind: None,
        requested_by: None,
        config: cfg.clone(),
    };
    let network = network_passes.then(|| {
        // Its own weights, all of its correction: the starting model's gains do not apply.
        let metadata =
            ModelMetadata { imu_correction_gains: BTreeMap::new(), power_on_bias_removed: cfg.power_on_bias, ..loaded.metadata.clone() };
        (AdaptedKind::Network, LoadedNet::new(vs, net, metadata))
    });
    let calibration = calibrated.filter(|_| calibration_passes).map(|c| (AdaptedKind::Calibration, c.net));
    let offset = with_offset.filter(|_| offset_passes).map(|c| (AdaptedKind::CalibrationWithOffset, c.net));
    // The calibration first (the query is this power-on's, where the networks' gain has not
    // carried over); `adapt --judge` keeps whichever carries over best, [`keep_without_judge`]
    // what lasts.
    let mut candidates = [calibration, offset, network].into_iter().flatten();
    let adapted = candidates.next();
    let others: Vec<_> = candidates.collect();
    report.kind = adapted.as_ref().map(|(k, _)| *k);
    Ok(AdaptOutcome { report, adapted: adapted.map(|(_, m)| m), others, without_rotation })
}

/// The query's AOE as recorded (its power-on bias added back, in the frame the sets were put
/// in) and, where the bias was removed, as the node runs a new IMU: the gyro minus it.
fn query_baselines(
    q_task: &Task,
    query_as_recorded: Option<Recording>,
    frame_applied: Option<&FrameCheck>,
    cfg: &AdaptConfig,
    eopts: &EvalOptions,
) -> Result<(OrientationErrors, Option<OrientationErrors>), AdaptError> {
    let query_power_on_bias = if cfg.power_on_bias { Some(evaluate_raw(q_task, eopts)?) } else { None };
    let query_raw = match query_as_recorded {
        Some(mut rec) => {
            if let Some(f) = frame_applied {
                apply_frame(&mut rec, &f.rotation());
            }
            evaluate_raw(&to_task(&rec, "query", cfg)?, eopts)?
        }
        None => evaluate_raw(q_task, eopts)?,
    };
    Ok((query_raw, query_power_on_bias))
}

/// The gyro calibration alone, with the support's bias offset in motion, and why the
/// calibration alone was refused.
type KeptCalibrations = (Option<Calibrated>, Option<Calibrated>, Option<String>);

/// The gyro calibration candidates, where `keep` and the power-on bias allow them.
fn calibration_candidates_kept(
    loaded: &LoadedNet,
    s_task: &Task,
    q_task: &Task,
    eopts: &EvalOptions,
    cfg: &AdaptConfig,
) -> Result<KeptCalibrations, AdaptError> {
    if !cfg.power_on_bias || cfg.keep == Keep::Networks {
        return Ok((None, None, None));
    }
    let CalibrationCandidates { alone, with_offset } = calibration_candidates(loaded, s_task, q_task, eopts, cfg)?;
    let with_offset = with_offset.filter(|_| cfg.keep == Keep::Auto);
    Ok(match alone {
        Ok(c) => (Some(c), with_offset, None),
        Err(why) => (None, with_offset, Some(why)),
    })
}

/// The support and query as the model adapts on them: at its rate, this power-on's bias
/// removed, checked, in the ground truth's frame (docs/adaptation.md, steps 1–2).
struct AdaptSets {
    s_task: Task,
    q_task: Task,
    frame: Option<FrameCheck>,
    frame_applied: bool,
    support_power_on_bias: Option<crate::standstill::BiasEstimate>,
    /// The query before its power-on bias was removed (when it was).
    query_as_recorded: Option<Recording>,
}

impl AdaptSets {
    fn prepare(
        model_rate_hz: f64,
        support: &Recording,
        query: &Recording,
        cfg: &AdaptConfig,
        known_power_on_bias: Option<&crate::standstill::BiasEstimate>,
    ) -> Result<Self, AdaptError> {
        let mut support = support.clone();
        let mut query = query.clone();
        // The model adapts at its own rate, on the input's periods, as the node runs it.
        for rec in [&mut support, &mut query] {
            let rate = rec.nominal_imu_rate_hz();
            if rec.imu.len() >= 2 && crate::model::rate_is_off(model_rate_hz, rate) {
                tracing::info!("{}: the {rate:.1} Hz IMU is adapted on in the model's {model_rate_hz:.0} Hz periods", rec.name);
                rec.imu = crate::resample::to_model_rate(&rec.imu, model_rate_hz).0;
            }
        }
        // This power-on's bias out of both sets, as the node removes it (causal over the recording).
        let query_as_recorded = cfg.power_on_bias.then(|| query.clone());
        let support_power_on_bias = if cfg.power_on_bias {
            Some(remove_power_on_bias(&mut support, &mut query, &cfg.standstill, known_power_on_bias)?)
        } else {
            None
        };
        let s_task0 = to_task(&support, "support", cfg)?;
        // Seconds with ground truth, not the span: gaps in it are not data to adapt on.
        require_covered(&s_task0, "support", cfg.min_support_seconds)?;
        // The query's length first: on a few seconds the clock check can find a false peak.
        let q_task0 = to_task(&query, "query", cfg)?;
        require_covered(&q_task0, "query", cfg.min_query_seconds)?;
        crate::train::data::check_clock(&support)?;
        crate::train::data::check_clock(&query)?;
        crate::train::data::check_plausible(&support)?;
        crate::train::data::check_plausible(&query)?;
        crate::train::data::check_accel_units(&support)?;
        crate::train::data::check_ground_truth_follows_gyro(&support, false)?;
        let (frame, frame_applied) = check_ground_truth_frame(&s_task0, &mut support, &mut query, cfg)?;
        let s_task = if frame_applied { to_task(&support, "support", cfg)? } else { s_task0 };
        let q_task = if frame_applied { to_task(&query, "query", cfg)? } else { q_task0 };
        Ok(AdaptSets { s_task, q_task, frame, frame_applied, support_power_on_bias, query_as_recorded })
    }
}

/// The frame check on the support (docs/adaptation.md, step 2): a rotation between the IMU
/// and ground-truth frames is an error, or re-expressed in both sets (`frame_policy`).
fn check_ground_truth_frame(
    s_task: &Task,
    support: &mut Recording,
    query: &mut Recording,
    cfg: &AdaptConfig,
) -> Result<(Option<FrameCheck>, bool), AdaptError> {
    let mut frame = None;
    let mut frame_applied = false;
    if cfg.frame_policy != FramePolicy::Ignore {
        frame = frame_check(&s_task.rec, cfg);
        if let Some(f) = frame.filter(|f| f.angle_deg > cfg.frame_tolerance_deg && !f.is_other_frame(cfg.frame_tolerance_deg)) {
            tracing::warn!(
                "a rotation of {:.1}° between the IMU and ground-truth frames fits, but explains little (residual {:.2}° with it, {:.2}° without): the gyro's own errors, not another frame",
                f.angle_deg,
                f.residual_deg,
                f.residual_identity_deg
            );
        }
        if let Some(f) = frame.filter(|f| f.is_other_frame(cfg.frame_tolerance_deg)) {
            match cfg.frame_policy {
                FramePolicy::Error => return Err(AdaptError::OtherFrame(Box::new(f))),
                FramePolicy::Apply => {
                    tracing::warn!("ground truth re-expressed in the IMU frame: rotation of {:.1}°", f.angle_deg);
                    apply_frame(support, &f.rotation());
                    apply_frame(query, &f.rotation());
                    frame_applied = true;
                }
                FramePolicy::Ignore => {}
            }
        }
    }
    Ok((frame, frame_applied))
}

/// Why neither candidate passed the query.
fn query_verdict(before: f64, after: f64, others: &[(AdaptedKind, f64)], floor: f64) -> String {
    let calibration: String = others.iter().map(|(k, aoe)| format!(", {} {aoe:.3}°", k.name())).collect();
    if after >= before {
        format!("rejected: the adapted model is not better on the query data (AOE {before:.3}° → {after:.3}°{calibration}); the previous model is kept")
    } else {
        format!(
            "rejected: the adapted model ({after:.3}°{calibration}) is not better on the query data than the gyro minus its power-on bias ({floor:.3}°), what the node runs on a new IMU; the previous model is kept"
        )
    }
}

/// Writes an accepted adapted model as `<dir>/<name>.{pt,ot,json}` (metadata: the original's
/// training data plus what it was adapted on; its metrics plus `adapt.*` figures) and the
/// full report as `<dir>/<name>.adapt.json`.
pub fn save_adapted(adapted: &LoadedNet, report: &AdaptReport, dir: &Path, name: &str) -> Result<ExportPaths, AdaptError> {
    let mut training_data = adapted.metadata.training_data.clone();
    let what = match report.kind {
        Some(AdaptedKind::Calibration) => {
            let c = report.calibration.as_ref().map_or(0, |c| c.increments);
            format!("gyro calibration (Ĉ_ω, the networks off) fitted on {c} increments")
        }
        Some(AdaptedKind::CalibrationWithOffset) => {
            let (n, b) = report.calibration.as_ref().map_or((0, [0.0; 3]), |c| (c.increments, c.leftover_bias_rad_s));
            format!(
                "gyro calibration (Ĉ_ω, the networks off) with a bias offset in motion of [{:.5}, {:.5}, {:.5}] rad/s, fitted on {n} increments",
                b[0], b[1], b[2]
            )
        }
        _ => format!("{} steps", report.steps),
    };
    let requested = report.requested_by.as_ref().map_or(String::new(), |who| format!("; requested by {who}"));
    training_data.push(format!(
        "few-shot adapted from {} on {} ({:.1} s support, {what}); judged on {} ({:.1} s){requested}",
        report.model, report.support, report.support_seconds, report.query, report.query_seconds
    ));
    // The starting model's figures (its test scores, its per-IMU gains) do not describe the
    // adapted one: only what the adaptation measured is kept.
    let mut metrics: BTreeMap<String, f64> = BTreeMap::new();
    metrics.insert("adapt.query_raw_aoe_deg".into(), report.query_raw.aoe_deg);
    metrics.insert("adapt.query_aoe_before_deg".into(), report.query_before.aoe_deg);
    metrics.insert("adapt.query_aoe_after_deg".into(), report.kept_query().unwrap_or(&report.query_after).aoe_deg);
    metrics.insert("adapt.support_seconds".into(), report.support_seconds);
    metrics.insert("adapt.query_seconds".into(), report.query_seconds);
    metrics.insert("adapt.steps".into(), report.steps as f64);
    metrics.insert("adapt.step_seconds".into(), report.step_seconds);
    let json = serde_json::to_string_pretty(report)?;
    let paths = export_model(
        dir,
        name,
        &adapted.vs,
        &adapted.net,
        &ExportInfo {
            training_data,
            metrics,
            code_revision: None,
            adapted_from: Some(report.model.clone()),
            power_on_bias_removed: report.support_power_on_bias.is_some(),
            side_files: vec![("adapt.json".into(), json + "\n")],
            ..Default::default()
        },
    )?;
    Ok(paths)
}

/// Removes the power-on bias in force at each sample (the node's [`crate::standstill`] rule,
/// run over support then query as one stream) from both sets, and the support's estimate from
/// the support's samples before its first standstill; returns that estimate. A
/// support without a standstill takes `known` (measured earlier in this power-on) off every
/// sample instead, or is refused with [`AdaptError::NoStandstill`].
pub fn remove_power_on_bias(
    support: &mut Recording,
    query: &mut Recording,
    cfg: &crate::standstill::StandstillConfig,
    known: Option<&crate::standstill::BiasEstimate>,
) -> Result<crate::standstill::BiasEstimate, AdaptError> {
    let in_support = crate::standstill::BiasTrack::over(&support.imu, cfg);
    let Some(estimate) = in_support.last else {
        let Some(known) = known else {
            return Err(AdaptError::NoStandstill(support.name.clone(), in_support.note()));
        };
        tracing::info!(
            "the support has no standstill: the power-on bias measured earlier ([{:.5}, {:.5}, {:.5}] rad/s) is removed",
            known.bias.x,
            known.bias.y,
            known.bias.z
        );
        for s in support.imu.iter_mut().chain(query.imu.iter_mut()) {
            s.gyro -= known.bias;
        }
        return Ok(*known);
    };
    // The bias in force at each sample of the one stream, as the node would have it …
    let whole: Vec<_> = support.imu.iter().chain(&query.imu).copied().collect();
    let track = crate::standstill::BiasTrack::over(&whole, cfg);
    // … but what is learned from, the support, is all past when adapting: before its first
    // standstill it takes the bias the support measured (a platform that sets off before it
    // stands would otherwise teach its whole turn-on bias as an offset in motion).
    let first_known = track.still.first().map_or(0, |&(_, end)| end).min(support.imu.len());
    for (i, (s, b)) in support.imu.iter_mut().chain(query.imu.iter_mut()).zip(&track.bias).enumerate() {
        s.gyro -= if i < first_known { estimate.bias } else { *b };
    }
    Ok(estimate)
}

/// Splits a recording at `support_seconds` after its first ground-truth-covered IMU sample:
/// (support, query), the query limited to `query_seconds` when given. Both keep all the
/// ground truth (it is only read at their IMU stamps).
pub fn split_recording(rec: &Recording, support_seconds: f64, query_seconds: Option<f64>, cfg: &AdaptConfig) -> (Recording, Recording) {
    let (gt, _) = data::ground_truth_at_imu(rec, &dataset_cfg(cfg));
    let first = gt.iter().position(Option::is_some).unwrap_or(0);
    let t0 = rec.imu.get(first).map_or(0, |s| s.stamp_ns);
    let cut = t0 + (support_seconds * 1e9) as i64;
    let end = query_seconds.map_or(i64::MAX, |q| cut + (q * 1e9) as i64);
    let part = |a: i64, b: i64, tag: &str| Recording {
        name: format!("{} [{tag}]", rec.name),
        imu: rec.imu.iter().filter(|s| s.stamp_ns >= a && s.stamp_ns < b).copied().collect(),
        ground_truth: rec.ground_truth.clone(),
        temperature: Vec::new(),
    };
    let q_tag = match query_seconds {
        Some(q) => format!("{support_seconds}–{} s", support_seconds + q),
        None => format!("{support_seconds} s–end"),
    };
    (part(t0, cut, &format!("0–{support_seconds} s")), part(cut, end, &q_tag))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::ImuSample;
    use nalgebra::Vector3;

    fn moving(from_s: f64, seconds: f64, bias: Vector3<f64>) -> Recording {
        let imu = (0..(seconds * 200.0) as i64)
            .map(|k| {
                let t = from_s + k as f64 * 0.005;
                ImuSample {
                    stamp_ns: (t * 1e9) as i64,
                    gyro: Vector3::new(0.5 * (3.0 * t).sin(), 0.4 * (2.0 * t).cos(), 0.3) + bias,
                    accel: Vector3::new(0.0, 0.0, 9.81) + Vector3::new(3.0 * (5.0 * t).sin(), 0.0, 0.0),
                }
            })
            .collect();
        Recording { name: "moving".into(), imu, ..Default::default() }
    }

    /// The node's buffer after its rest scrolled out: refused without what the node measured,
    /// that bias off every sample with it.
    #[test]
    fn a_support_without_a_standstill_takes_the_bias_measured_earlier() {
        let bias = Vector3::new(0.02, -0.01, 0.03);
        let cfg = crate::standstill::StandstillConfig { in_motion: crate::standstill::InMotion::Off, ..Default::default() };
        let (mut support, mut query) = (moving(1.0, 10.0, bias), moving(11.0, 5.0, bias));
        let err = remove_power_on_bias(&mut support.clone(), &mut query.clone(), &cfg, None).unwrap_err();
        assert!(matches!(err, AdaptError::NoStandstill(..)), "{err}");
        let known = crate::standstill::BiasEstimate { bias, variance: Vector3::repeat(1e-8), at_ns: 0, still_s: 3.0 };
        let raw = (support.clone(), query.clone());
        let used = remove_power_on_bias(&mut support, &mut query, &cfg, Some(&known)).unwrap();
        assert_eq!(used, known);
        for (after, before) in support.imu.iter().chain(&query.imu).zip(raw.0.imu.iter().chain(&raw.1.imu)) {
            assert!((before.gyro - after.gyro - bias).amax() < 1e-15);
        }
    }

    /// A platform that sets off, then stands: the support learns from its samples before the
    /// standstill with the bias the standstill measured (it is all past when adapting); the
    /// query keeps the bias in force as the node had it.
    #[test]
    fn a_support_that_moves_before_it_stands_is_debiased_from_its_start() {
        let bias = Vector3::new(0.02, -0.01, 0.03);
        let cfg = crate::standstill::StandstillConfig { in_motion: crate::standstill::InMotion::Off, ..Default::default() };
        let mut support = moving(1.0, 10.0, bias);
        let rest_from = support.imu.len();
        support.imu.extend((0..600).map(|k| ImuSample {
            stamp_ns: ((11.0 + k as f64 * 0.005) * 1e9) as i64,
            gyro: bias,
            accel: Vector3::new(0.0, 0.0, 9.81),
        }));
        let mut query = moving(14.0, 5.0, bias);
        let raw = (support.clone(), query.clone());
        let estimate = remove_power_on_bias(&mut support, &mut query, &cfg, None).unwrap();
        assert!((estimate.bias - bias).amax() < 1e-9, "{estimate:?}");
        for (after, before) in support.imu[..rest_from].iter().zip(&raw.0.imu) {
            assert!((before.gyro - after.gyro - estimate.bias).amax() < 1e-15, "before the standstill");
        }
        for (after, before) in query.imu.iter().zip(&raw.1.imu) {
            assert!((before.gyro - after.gyro - estimate.bias).amax() < 1e-9, "the query, after it");
        }
    }
}
