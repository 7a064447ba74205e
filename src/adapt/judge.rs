//! Judging an adapted model on *other* recordings of the same IMU: another power-on, the case
//! a robot that reboots meets. The query set judges the power-on adapted on; this judges
//! whether what was learned carries over, beside what the node would run without it.

use serde::{Deserialize, Serialize};

use super::{to_task, AdaptConfig, AdaptError, AdaptOutcome, AdaptedKind, JudgedCandidate};
use crate::core::Recording;
use crate::eval::{evaluate, EvalOptions, OrientationErrors};
use crate::model::export::LoadedNet;
use crate::model::predict::correct_with_net;
use crate::standstill::BiasTrack;
use crate::train::fit::{evaluate_net, evaluate_net_with_gain, evaluate_raw};

/// One other recording's figures (AOE over all of it).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Judged {
    pub recording: String,
    pub raw: OrientationErrors,
    /// The gyro minus this recording's own power-on bias, the attitude held over its still
    /// windows: what the node runs on a new IMU (`None`: no standstill in it).
    pub power_on_bias: Option<OrientationErrors>,
    /// The starting model as deployed on the IMU named (its correction gain).
    pub before: OrientationErrors,
    /// The adapted model, after this recording's power-on bias where it was adapted so, as
    /// the node runs it.
    pub after: OrientationErrors,
}

impl Judged {
    /// What the node runs without the adapted model: the power-on bias where there is one
    /// (a new IMU), else the better of raw and the starting model.
    pub fn without_adaptation_deg(&self) -> f64 {
        self.power_on_bias.as_ref().map_or(self.raw.aoe_deg.min(self.before.aoe_deg), |e| e.aoe_deg)
    }
}

/// Scores `start` and `adapted` on `rec` (the whole recording, covered by ground truth).
pub fn judge(start: &LoadedNet, adapted: &LoadedNet, rec: &Recording, cfg: &AdaptConfig) -> Result<Judged, AdaptError> {
    Ok(judge_each(start, &[adapted], rec, cfg)?.remove(0))
}

/// [`judge`] for several adapted models on one recording: what they share (raw, the starting
/// model, the power-on bias) is computed once.
pub fn judge_each(start: &LoadedNet, adapted: &[&LoadedNet], rec: &Recording, cfg: &AdaptConfig) -> Result<Vec<Judged>, AdaptError> {
    let mut rec = rec.clone();
    let rate = rec.nominal_imu_rate_hz();
    if rec.imu.len() >= 2 && crate::model::rate_is_off(start.metadata.rate_hz, rate) {
        rec.imu = crate::resample::to_model_rate(&rec.imu, start.metadata.rate_hz).0;
    }
    let eopts = EvalOptions { max_gap_ns: (cfg.max_interpolation_gap_ms * 1e6) as i64 };
    let task = to_task(&rec, "judge", cfg)?;
    let raw = evaluate_raw(&task, &eopts)?;
    let before = evaluate_net_with_gain(&start.net, &task, &eopts, start.correction_gain())?;
    // As deployed: this recording's power-on bias removed as the pipeline finds it, the
    // attitude held over its still windows (what `eval`'s rows score).
    let track = BiasTrack::over(&rec.imu, &cfg.standstill);
    let power_on_bias = match track.last {
        Some(_) => Some(evaluate(&rec, &track.corrected_gyro(&rec.imu), &eopts)?),
        None => None,
    };
    let debiased = track.debiased(&rec.imu);
    adapted
        .iter()
        .map(|model| {
            let after = if model.metadata.power_on_bias_removed {
                let mut gyro = correct_with_net(&model.net.inference(), &debiased)?;
                track.hold_still_windows(&rec.imu, &mut gyro);
                evaluate(&rec, &gyro, &eopts)?
            } else {
                evaluate_net(&model.net, &task, &eopts)?
            };
            Ok(Judged {
                recording: rec.name.clone(),
                raw: raw.clone(),
                power_on_bias: power_on_bias.clone(),
                before: before.clone(),
                after,
            })
        })
        .collect()
}

/// How an adaptation carries over to the judged recordings: the geometric mean over them of
/// AOE adapted / without adapting (an arithmetic mean would be decided by the largest AOE),
/// and its one-sided 95 % upper bound (Student's t on the log-ratios; with one recording, the
/// ratio itself).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CarryOver {
    pub ratio: f64,
    pub upper_95: f64,
    pub recordings: usize,
    /// Only the recordings with a standstill were used.
    #[serde(default)]
    pub with_standstill_only: bool,
}

impl CarryOver {
    /// Over the judged recordings with a standstill (where the power-on bias is known, so the
    /// AOE shows the lasting errors rather than an unremoved bias's 100°), or all of them where
    /// none has one.
    pub fn of(judged: &[Judged]) -> Self {
        let rested: Vec<&Judged> = judged.iter().filter(|j| j.power_on_bias.is_some()).collect();
        let with_standstill_only = !rested.is_empty();
        let used = if with_standstill_only { rested } else { judged.iter().collect() };
        let logs: Vec<f64> = used.iter().map(|j| (j.after.aoe_deg / j.without_adaptation_deg()).ln()).collect();
        CarryOver { with_standstill_only, ..Self::of_log_ratios(&logs) }
    }

    /// The geometric mean of `exp(logs)` and its one-sided 95 % upper bound.
    pub(crate) fn of_log_ratios(logs: &[f64]) -> Self {
        let n = logs.len();
        let mean = logs.iter().sum::<f64>() / n as f64;
        let upper = if n >= 2 {
            let var = logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            mean + crate::student_t::one_sided_95(n - 1) * (var / n as f64).sqrt()
        } else {
            mean
        };
        CarryOver { ratio: mean.exp(), upper_95: upper.exp(), recordings: n, with_standstill_only: false }
    }

    /// Better than not adapting with 95 % confidence over the judged recordings.
    pub fn carries_over(&self) -> bool {
        self.upper_95 < 1.0
    }

    /// "over N recordings[ with a standstill]", for messages.
    pub fn over(&self) -> String {
        format!(
            "over {} recording{}{}",
            self.recordings,
            if self.recordings == 1 { "" } else { "s" },
            if self.with_standstill_only { " with a standstill" } else { "" }
        )
    }
}

/// Judges every candidate of `outcome` (those that passed the query) on `recordings` (other
/// power-ons) and keeps the one that carries over best among those that carry over with
/// confidence; none does: all are refused (nothing to write), with the figures of the one
/// tried first. What is shared (raw, the starting model, the power-on bias) is computed once
/// per recording; `judged_one` is told after each (a progress bar).
pub fn keep_judged(
    start: &LoadedNet,
    outcome: &mut AdaptOutcome,
    recordings: &[Recording],
    cfg: &AdaptConfig,
    mut judged_one: impl FnMut(&Recording),
) -> Result<(), AdaptError> {
    let Some(first) = outcome.adapted.take() else { return Ok(()) };
    let r = &mut outcome.report;
    let mut candidates = vec![(r.kind.unwrap_or(AdaptedKind::Network), first)];
    candidates.append(&mut outcome.others);
    let models: Vec<&LoadedNet> = candidates.iter().map(|(_, m)| m).collect();
    let mut per_model: Vec<Vec<Judged>> = vec![Vec::new(); models.len()];
    for rec in recordings {
        for (k, j) in judge_each(start, &models, rec, cfg)?.into_iter().enumerate() {
            per_model[k].push(j);
        }
        judged_one(rec);
    }
    let mut judged: Vec<JudgedCandidate> = candidates
        .iter()
        .zip(per_model)
        .map(|((kind, _), judged)| JudgedCandidate { kind: *kind, carry_over: CarryOver::of(&judged), judged })
        .collect();
    let best = (0..judged.len())
        .filter(|&k| judged[k].carry_over.carries_over())
        .min_by(|&a, &b| judged[a].carry_over.ratio.total_cmp(&judged[b].carry_over.ratio));
    let chosen = best.unwrap_or(0);
    let kept = judged.remove(chosen);
    let (kind, model) = candidates.remove(chosen);
    r.judged = kept.judged;
    r.judged_others = judged;
    r.carry_over = Some(kept.carry_over);
    if best.is_some() {
        r.kind = Some(kind);
        outcome.adapted = Some(model);
    } else {
        let c = kept.carry_over;
        r.accepted = false;
        r.kind = None;
        r.verdict = format!(
            "rejected on the other recordings: AOE adapted / without adapting (the power-on bias) is {:.3} (geometric mean {}), its 95 % upper bound {:.3} is not below 1; the adaptation does not carry over to another power-on",
            c.ratio,
            c.over(),
            c.upper_95
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mixed_carry_over_is_not_confident_and_a_consistent_one_is() {
        // Better on four, worse on six (the networks adapted on one EuRoC recording): the
        // geometric mean is below 1, its bound is not.
        let mixed = [0.33, 0.52, 0.61, 0.48, 3.1, 1.6, 1.8, 1.02, 1.02, 1.09].map(f64::ln);
        let c = CarryOver::of_log_ratios(&mixed);
        assert!(c.ratio < 1.0 && !c.carries_over(), "{c:?}");
        let consistent = [0.36, 0.39, 0.21, 0.89, 0.58, 0.47, 0.77].map(f64::ln);
        let c = CarryOver::of_log_ratios(&consistent);
        assert!(c.carries_over() && (c.ratio - 0.5).abs() < 0.05, "{c:?}");
        let one = CarryOver::of_log_ratios(&[0.9f64.ln()]);
        assert!(one.carries_over() && (one.upper_95 - 0.9).abs() < 1e-12);
    }
}
