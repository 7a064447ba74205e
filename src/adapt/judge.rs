//! Judging an adapted model on *other* recordings of the same IMU: another power-on, the case
//! a robot that reboots meets. The query set judges the power-on adapted on; this judges
//! whether what was learned carries over, beside what the node would run without it.

use serde::{Deserialize, Serialize};

use super::pieces::{log_ratios, piece_aoe, QUERY_PIECE_S};
use super::{to_task, AdaptConfig, AdaptError, AdaptOutcome, AdaptedKind, JudgedCandidate};
use crate::core::Recording;
use crate::eval::{evaluate, EvalOptions, OrientationErrors};
use crate::model::export::LoadedNet;
use crate::model::predict::{correct_with_net, with_correction_gain};
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
    /// What the candidate is judged against here, AOE °: the power-on bias (a candidate with
    /// the networks off), or the better of it and the starting model (the adapted networks:
    /// their gain must be the adaptation's, not the starting model's). Absent in older
    /// reports: [`Self::without_adaptation_deg`] rules then.
    #[serde(default)]
    pub compared_with_deg: Option<f64>,
    /// ln(AOE with the candidate / with what it is compared with) over each 10-s piece from the
    /// end of this recording's first standstill (before it, both carry the unremoved bias);
    /// NaN where a piece could not be scored, so every candidate's pieces line up. Not written
    /// in the report (its `carry_over` sums them up).
    #[serde(skip)]
    pub piece_log_ratios: Vec<f64>,
}

impl Judged {
    /// What the node runs without the adapted model: the power-on bias where there is one
    /// (a new IMU), else the better of raw and the starting model.
    pub fn without_adaptation_deg(&self) -> f64 {
        self.power_on_bias.as_ref().map_or(self.raw.aoe_deg.min(self.before.aoe_deg), |e| e.aoe_deg)
    }

    /// What the candidate was judged against (see `compared_with_deg`).
    pub fn compared_with(&self) -> f64 {
        self.compared_with_deg.unwrap_or_else(|| self.without_adaptation_deg())
    }
}

/// Scores `start` and `adapted` (of `kind`) on `rec` (the whole recording, covered by ground truth).
pub fn judge(start: &LoadedNet, kind: AdaptedKind, adapted: &LoadedNet, rec: &Recording, cfg: &AdaptConfig) -> Result<Judged, AdaptError> {
    Ok(judge_each(start, &[(kind, adapted)], rec, cfg)?.remove(0))
}

/// [`judge`] for several adapted models on one recording: what they share (raw, the starting
/// model, the power-on bias) is computed once.
pub fn judge_each(
    start: &LoadedNet,
    adapted: &[(AdaptedKind, &LoadedNet)],
    rec: &Recording,
    cfg: &AdaptConfig,
) -> Result<Vec<Judged>, AdaptError> {
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
    let raw_gyro: Vec<_> = rec.imu.iter().map(|s| s.gyro).collect();
    let (power_on_bias, without_gyro) = match track.last {
        Some(_) => {
            let gyro = track.corrected_gyro(&rec.imu);
            (Some(evaluate(&rec, &gyro, &eopts)?), gyro)
        }
        None => (None, raw_gyro),
    };
    // Pieces from the end of the first standstill: before it neither side has the bias removed.
    let from = track.still.first().map_or(0, |&(_, end)| end);
    let without_pieces = piece_aoe(&rec, &without_gyro, &eopts, from);
    // The starting model piece by piece, for the adapted networks' comparison (only with them).
    let start_pieces = if adapted.iter().any(|(kind, _)| *kind == AdaptedKind::Network) {
        let gyro = correct_with_net(&inference(start, task.calibration_row), &rec.imu)?;
        Some(piece_aoe(&rec, &with_correction_gain(&rec.imu, gyro, start.correction_gain()), &eopts, from))
    } else {
        None
    };
    let without = power_on_bias.as_ref().map_or(raw.aoe_deg.min(before.aoe_deg), |e| e.aoe_deg);
    let debiased = track.debiased(&rec.imu);
    adapted
        .iter()
        .map(|&(kind, model)| {
            let after_gyro = if model.metadata.power_on_bias_removed {
                let mut gyro = correct_with_net(&model.net.inference(), &debiased)?;
                track.hold_still_windows(&rec.imu, &mut gyro);
                gyro
            } else {
                correct_with_net(&inference(model, task.calibration_row), &rec.imu)?
            };
            let after = if model.metadata.power_on_bias_removed {
                evaluate(&rec, &after_gyro, &eopts)?
            } else {
                evaluate_net(&model.net, &task, &eopts)?
            };
            // The adapted networks start from the starting model's: where it is the better of the
            // two here (an IMU it was trained on, left unnamed), their gain is not the adaptation's.
            let (compared_with, compared_pieces) = match &start_pieces {
                Some(p) if kind == AdaptedKind::Network && before.aoe_deg < without => (before.aoe_deg, p),
                _ => (without, &without_pieces),
            };
            Ok(Judged {
                recording: rec.name.clone(),
                raw: raw.clone(),
                power_on_bias: power_on_bias.clone(),
                before: before.clone(),
                after,
                compared_with_deg: Some(compared_with),
                piece_log_ratios: log_ratios(&piece_aoe(&rec, &after_gyro, &eopts, from), compared_pieces),
            })
        })
        .collect()
}

/// `model`'s networks for inference, with its Ĉ_ω row for the IMU named (as the trainer's
/// evaluation runs them).
fn inference(model: &LoadedNet, calibration_row: Option<i64>) -> crate::model::InferenceNet {
    match calibration_row {
        Some(row) => model.net.inference_for_row(row),
        None => model.net.inference(),
    }
}

/// How an adaptation carries over to the judged recordings: the geometric mean over them of
/// AOE adapted / what it is compared with (an arithmetic mean would be decided by the largest
/// AOE) with its one-sided 95 % upper bound (Student's t on the log-ratios; with one
/// recording, the ratio itself), and the same over the 10-s pieces of all of them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CarryOver {
    pub ratio: f64,
    pub upper_95: f64,
    pub recordings: usize,
    /// Only the recordings with a standstill were used.
    #[serde(default)]
    pub with_standstill_only: bool,
    /// Over the pieces: the geometric mean, its bound (none without a piece), and how many.
    #[serde(default)]
    pub piece_ratio: Option<f64>,
    #[serde(default)]
    pub piece_upper_95: Option<f64>,
    #[serde(default)]
    pub pieces: usize,
}

impl CarryOver {
    /// Over the judged recordings with a standstill (where the power-on bias is known, so the
    /// AOE shows the lasting errors rather than an unremoved bias's 100°), or all of them where
    /// none has one.
    pub fn of(judged: &[Judged]) -> Self {
        let with_standstill_only = any_with_standstill(judged);
        let used: Vec<&Judged> = judged.iter().filter(|j| counts(j, with_standstill_only)).collect();
        let logs: Vec<f64> = used.iter().map(|j| (j.after.aoe_deg / j.compared_with()).ln()).collect();
        let piece_logs: Vec<f64> = used.iter().flat_map(|j| j.piece_log_ratios.iter().copied()).filter(|l| l.is_finite()).collect();
        let pieces = (!piece_logs.is_empty()).then(|| Self::of_log_ratios(&piece_logs));
        CarryOver {
            with_standstill_only,
            piece_ratio: pieces.map(|p| p.ratio),
            piece_upper_95: pieces.map(|p| p.upper_95),
            pieces: piece_logs.len(),
            ..Self::of_log_ratios(&logs)
        }
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
        CarryOver {
            ratio: mean.exp(),
            upper_95: upper.exp(),
            recordings: n,
            with_standstill_only: false,
            piece_ratio: None,
            piece_upper_95: None,
            pieces: 0,
        }
    }

    /// Better than not adapting over the judged recordings (the geometric mean below 1) and,
    /// with 95 % confidence, piece by piece over all of them (at least two pieces): a few
    /// recordings whose motion shows a lasting error to different degrees (a 2 % scale error
    /// is three quarters of one recording's AOE and a twentieth of another's) leave the bound
    /// over whole recordings wide; the pieces judge the same gain where it shows.
    pub fn carries_over(&self) -> bool {
        self.ratio < 1.0 && self.pieces >= 2 && self.piece_upper_95.is_some_and(|b| b < 1.0)
    }

    /// The bound over the pieces for messages ("none" with fewer than two).
    pub fn piece_bound_said(&self) -> String {
        self.piece_upper_95.filter(|_| self.pieces >= 2).map_or("none".to_string(), |b| format!("{b:.3}"))
    }

    /// "over N recordings[ with a standstill] (M pieces of 10 s)", for messages.
    pub fn over(&self) -> String {
        format!(
            "over {} recording{}{}, {} piece{} of {:.0} s",
            self.recordings,
            if self.recordings == 1 { "" } else { "s" },
            if self.with_standstill_only { " with a standstill" } else { "" },
            self.pieces,
            if self.pieces == 1 { "" } else { "s" },
            QUERY_PIECE_S
        )
    }
}

/// Judges every candidate of `outcome` (those that passed the query) on `recordings` (other
/// power-ons) and keeps, among those that carry over, the plainest unless a richer one is
/// better with confidence ([`simplest_that_carries_over`]); none does: all are refused
/// (nothing to write), with the figures of the one tried first. What is shared (raw, the starting model, the power-on bias) is computed once
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
    let models: Vec<(AdaptedKind, &LoadedNet)> = candidates.iter().map(|(k, m)| (*k, m)).collect();
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
    let best = simplest_that_carries_over(&judged);
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
            "rejected on the other recordings: AOE adapted / without adapting is {:.3} (geometric mean {}; 95 % upper bound {:.3} over the recordings, {} over the pieces, which must be below 1); the adaptation does not carry over to another power-on",
            c.ratio,
            c.over(),
            c.upper_95,
            c.piece_bound_said()
        );
    }
    Ok(())
}

/// Some judged recording has a standstill: only those count then ([`CarryOver::of`]).
fn any_with_standstill(judged: &[Judged]) -> bool {
    judged.iter().any(|j| j.power_on_bias.is_some())
}

/// `j` counts toward a carry-over: it has a standstill, or none judged has one.
fn counts(j: &Judged, with_standstill_only: bool) -> bool {
    !with_standstill_only || j.power_on_bias.is_some()
}

/// The candidate kept among those that carry over: the plainest (fewest lasting parameters,
/// [`AdaptedKind::complexity`]), replaced by a richer one only where that is better than it
/// with 95 % confidence piece by piece on the same judged recordings and on their whole. A
/// richer candidate fits what a plainer one leaves of the support: a simulated MPU-9250 with
/// no offset in motion "determined" one on its support, and its 0.368 against the
/// calibration's 0.402 over three other power-ons is no evidence that the offset lasts.
fn simplest_that_carries_over(judged: &[JudgedCandidate]) -> Option<usize> {
    let mut order: Vec<usize> = (0..judged.len()).filter(|&k| judged[k].carry_over.carries_over()).collect();
    order.sort_by_key(|&k| judged[k].kind.complexity());
    let mut kept = *order.first()?;
    for &k in &order[1..] {
        let (richer, plainer) = (&judged[k], &judged[kept]);
        let better = paired_piece_gain(&richer.judged, &plainer.judged).is_some_and(|g| g.pieces >= 2 && g.upper_95 < 1.0);
        if better && richer.carry_over.ratio < plainer.carry_over.ratio {
            kept = k;
        }
    }
    Some(kept)
}

/// AOE of `richer` over that of `plainer`, piece by piece on the recordings both were judged on
/// (those with a standstill where any has one): its geometric mean and one-sided 95 % bound.
fn paired_piece_gain(richer: &[Judged], plainer: &[Judged]) -> Option<CarryOver> {
    let with_standstill_only = any_with_standstill(richer);
    let logs: Vec<f64> = richer
        .iter()
        .zip(plainer)
        .filter(|(j, _)| counts(j, with_standstill_only))
        .flat_map(|(a, b)| a.piece_log_ratios.iter().zip(&b.piece_log_ratios).map(|(x, y)| x - y))
        .filter(|d| d.is_finite())
        .collect();
    (!logs.is_empty()).then(|| {
        let c = CarryOver::of_log_ratios(&logs);
        CarryOver { pieces: logs.len(), ..c }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn aoe(deg: f64) -> OrientationErrors {
        OrientationErrors { aoe_deg: deg, ..Default::default() }
    }

    /// A judged recording: the candidate's AOE, what it is compared with, and its pieces' ratios.
    fn judged(after: f64, without: f64, pieces: &[f64]) -> Judged {
        Judged {
            recording: "r".into(),
            raw: aoe(100.0),
            power_on_bias: Some(aoe(without)),
            before: aoe(100.0),
            after: aoe(after),
            compared_with_deg: Some(without),
            piece_log_ratios: pieces.iter().map(|r| r.ln()).collect(),
        }
    }

    #[test]
    fn the_bound_of_a_geometric_mean_is_students() {
        // Better on four, worse on six (the networks adapted on one EuRoC recording): the
        // geometric mean is below 1, its bound is not.
        let mixed = [0.33, 0.52, 0.61, 0.48, 3.1, 1.6, 1.8, 1.02, 1.02, 1.09].map(f64::ln);
        let c = CarryOver::of_log_ratios(&mixed);
        assert!(c.ratio < 1.0 && c.upper_95 > 1.0, "{c:?}");
        let consistent = [0.36, 0.39, 0.21, 0.89, 0.58, 0.47, 0.77].map(f64::ln);
        let c = CarryOver::of_log_ratios(&consistent);
        assert!(c.upper_95 < 1.0 && (c.ratio - 0.5).abs() < 0.05, "{c:?}");
        let one = CarryOver::of_log_ratios(&[0.9f64.ln()]);
        assert!((one.upper_95 - 0.9).abs() < 1e-12);
    }

    /// A lasting scale error that is most of two recordings' error and little of a third's:
    /// the bound over three whole recordings is wide, the pieces show the gain where it is.
    #[test]
    fn a_gain_that_shows_unevenly_across_recordings_carries_over_piece_by_piece() {
        let j = [
            judged(4.96, 4.66, &[1.02, 0.97, 1.05, 0.99, 0.98, 1.01, 0.96, 1.03, 0.99, 1.0]),
            judged(2.39, 9.21, &[0.35, 0.41, 0.30, 0.52, 0.44, 0.38, 0.33, 0.47]),
            judged(1.87, 11.69, &[0.22, 0.31, 0.27, 0.35, 0.25, 0.19, 0.30]),
        ];
        let c = CarryOver::of(&j);
        assert!(c.upper_95 > 1.0, "the recordings' bound alone refuses it: {c:?}");
        assert!(c.carries_over() && c.pieces == 25 && c.piece_upper_95.unwrap() < 1.0, "{c:?}");
    }

    #[test]
    fn better_on_the_whole_but_not_piece_by_piece_or_the_reverse_is_refused() {
        let noisy = [judged(2.0, 3.0, &[0.5, 1.8, 0.6, 1.5]), judged(2.5, 3.0, &[1.6, 0.4, 1.2])];
        let c = CarryOver::of(&noisy);
        assert!(c.ratio < 1.0 && c.piece_upper_95.unwrap() > 1.0 && !c.carries_over(), "{c:?}");
        let worse_whole = [judged(3.5, 3.0, &[0.8, 0.7, 0.9]), judged(3.3, 3.0, &[0.8, 0.9])];
        assert!(!CarryOver::of(&worse_whole).carries_over());
        // One piece says nothing with confidence.
        assert!(!CarryOver::of(&[judged(1.0, 3.0, &[0.3])]).carries_over());
    }

    fn candidate(kind: AdaptedKind, judged: Vec<Judged>) -> JudgedCandidate {
        JudgedCandidate { kind, carry_over: CarryOver::of(&judged), judged }
    }

    /// A richer candidate a little lower on the whole is not kept over a plainer one unless it
    /// is better than it piece by piece; where it is, it is.
    #[test]
    fn the_plainest_candidate_that_carries_over_is_kept_unless_a_richer_one_is_surely_better() {
        let plain = [0.40, 0.45, 0.38, 0.50, 0.42, 0.36];
        let calibration = candidate(AdaptedKind::Calibration, vec![judged(1.2, 3.0, &plain)]);
        let near = plain.iter().enumerate().map(|(k, r)| r * if k % 2 == 0 { 0.7 } else { 1.25 }).collect::<Vec<_>>();
        let offset = candidate(AdaptedKind::CalibrationWithOffset, vec![judged(1.1, 3.0, &near)]);
        assert!(offset.carry_over.carries_over() && offset.carry_over.ratio < calibration.carry_over.ratio);
        assert_eq!(simplest_that_carries_over(&[offset.clone(), calibration.clone()]), Some(1), "the plainer kept");
        let surely = plain.iter().map(|r| r * 0.6).collect::<Vec<_>>();
        let networks = candidate(AdaptedKind::Network, vec![judged(0.7, 3.0, &surely)]);
        assert_eq!(simplest_that_carries_over(&[offset, calibration, networks.clone()]), Some(2), "the richer, better piece by piece");
        assert_eq!(simplest_that_carries_over(&[candidate(AdaptedKind::Calibration, vec![judged(3.5, 3.0, &plain)])]), None);
    }

    /// Recordings without a standstill (an unremoved bias's 100°) count only where none has one.
    #[test]
    fn recordings_without_a_standstill_are_left_out_where_others_have_one() {
        let mut no_rest = judged(110.0, 100.0, &[1.3, 1.4, 1.2]);
        no_rest.power_on_bias = None;
        let c = CarryOver::of(&[no_rest.clone(), judged(1.0, 2.0, &[0.5, 0.45, 0.55])]);
        assert!(c.with_standstill_only && c.recordings == 1 && c.pieces == 3 && c.carries_over(), "{c:?}");
        let c = CarryOver::of(&[no_rest]);
        assert!(!c.with_standstill_only && !c.carries_over(), "{c:?}");
    }
}
