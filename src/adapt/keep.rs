//! Which adaptation candidate is kept where no other power-on judges them (`adapt` without
//! `--judge`, the node's `~/adapt`). With `--judge`, `imu-fsda adapt` keeps the one that
//! carries over better ([`super::judge`]).

use super::calibration_candidate::WithoutRotation;
use super::{AdaptConfig, AdaptOutcome, AdaptedKind, Keep};
use crate::model::export::LoadedNet;

/// What is kept where no other power-on judges the candidates (`adapt` without `--judge`, the
/// node's `~/adapt`): the query is this power-on's, so it is evidence only for what lasts.
/// The gyro calibration where its gain holds piece by piece ([`super::pieces`]); the adapted
/// networks only where the user asked for them (`keep: networks`) or for this power-on alone
/// (`power_on_bias: false`): their query gain did not carry over to another power-on in
/// any measured case (docs/poweron.md). A candidate asked for by `keep` is kept on the
/// query's evidence alone. The calibration with the support's bias offset in motion never:
/// within one power-on, an offset that lasts on the platform and a drift of this power-on's
/// bias look the same. The calibration is the one fitted with the rotation between the
/// reference's frame and the IMU's taken out: against one reference, a rotated gyro and a
/// reference mounted a degree off fit the same Ĉ_ω (EuRoC V1_01's 1.1° did, and cost every
/// other power-on 16 %). Otherwise nothing, with the reason.
pub fn keep_without_judge(mut outcome: AdaptOutcome, cfg: &AdaptConfig) -> AdaptOutcome {
    let mut candidates: Vec<(AdaptedKind, LoadedNet)> = Vec::new();
    if let (Some(kind), Some(model)) = (outcome.report.kind, outcome.adapted.take()) {
        candidates.push((kind, model));
    }
    candidates.append(&mut outcome.others);
    let mut why_not = Vec::new();
    if let Some(w) = outcome.without_rotation.take() {
        if let Some(why) = calibration_without_rotation(w, &mut candidates, &mut outcome.report) {
            why_not.push(why);
        }
    }
    let r = &mut outcome.report;
    let networks_asked = cfg.keep == Keep::Networks || !cfg.power_on_bias;
    let mut kept = Vec::new();
    for (kind, model) in candidates {
        let reason = match kind {
            AdaptedKind::Calibration if cfg.keep == Keep::GyroCalibration => None,
            AdaptedKind::Calibration => match r.query_calibrated_pieces {
                Some(p) if p.holds() => None,
                Some(p) => Some(format!(
                    "{}the gyro calibration's query gain does not hold piece by piece (AOE ratio {:.3} over {} pieces of {:.0} s, 95 % upper bound {:.3}, not below 1)",
                    r.calibration_rotation_left_out_deg.map_or(String::new(), |d| format!("{}, ", rotation_left_out(d))),
                    p.ratio,
                    p.pieces,
                    p.piece_seconds,
                    p.upper_95
                )),
                None => Some("the gyro calibration could not be judged piece by piece on the query".to_string()),
            },
            AdaptedKind::CalibrationWithOffset => Some(format!(
                "the bias offset in motion the support shows ({}) is this power-on's until another power-on shows it lasts (--judge OTHER.mcap): a drift of this power-on's bias looks the same",
                offset_said(r)
            )),
            AdaptedKind::Network if networks_asked => None,
            AdaptedKind::Network => Some(format!(
                "the adapted networks' query gain ({:.3}° against {:.3}° {}) is this power-on's: it has not carried over to another power-on in the measured cases, so they are kept only when judged on one (--judge OTHER.mcap) or asked for (keep: networks)",
                r.query_after.aoe_deg,
                r.query_power_on_bias.as_ref().map_or(r.query_before.aoe_deg, |e| e.aoe_deg),
                if r.query_power_on_bias.is_some() { "for the gyro minus its power-on bias" } else { "for the starting model" }
            )),
        };
        match reason {
            None => kept.push((kind, model)),
            Some(why) => why_not.push(why),
        }
    }
    let mut kept = kept.into_iter();
    match kept.next() {
        Some((kind, model)) => {
            r.accepted = true;
            r.verdict.clear();
            r.kind = Some(kind);
            outcome.adapted = Some(model);
            outcome.others = kept.collect();
        }
        None => {
            if r.accepted {
                r.verdict = format!("rejected without other power-ons to judge on: {}; the previous model is kept", why_not.join("; "));
            }
            r.accepted = false;
            r.kind = None;
        }
    }
    outcome
}

/// Puts the calibration fitted without the reference's rotation in place of the one fitted
/// with it (the report's calibration figures follow), where it passes the query as the
/// others had to; otherwise says why there is none.
fn calibration_without_rotation(
    w: WithoutRotation,
    candidates: &mut Vec<(AdaptedKind, LoadedNet)>,
    r: &mut super::AdaptReport,
) -> Option<String> {
    candidates.retain(|(kind, _)| *kind != AdaptedKind::Calibration);
    r.calibration_rotation_left_out_deg = Some(w.rotation_deg);
    let left_out = rotation_left_out(w.rotation_deg);
    let c = match w.calibration {
        Ok(c) => c,
        Err(why) => return Some(format!("{left_out}, the gyro calibration is not determined: {why}")),
    };
    let floor = r.query_power_on_bias.as_ref().map_or(f64::INFINITY, |e| e.aoe_deg);
    let passes = c.query.aoe_deg < r.query_before.aoe_deg && c.query.aoe_deg < floor;
    let said = format!(
        "{left_out}, the gyro calibration's query AOE is {:.3}° against {:.3}° for the gyro minus its power-on bias",
        c.query.aoe_deg, floor
    );
    r.calibration = Some(c.fit);
    r.query_calibrated = Some(c.query);
    r.query_calibrated_pieces = c.pieces;
    if !passes {
        return Some(said);
    }
    tracing::info!("{said}");
    candidates.insert(0, (AdaptedKind::Calibration, c.net));
    None
}

fn rotation_left_out(deg: f64) -> String {
    format!(
        "with {} (one power-on cannot tell its mounting from a rotation of the gyro; --judge OTHER.mcap can)",
        super::report::rotation_left_out_said(deg)
    )
}

fn offset_said(r: &super::AdaptReport) -> String {
    r.calibration.as_ref().map_or(String::new(), |c| {
        let b = c.leftover_bias_rad_s;
        format!("[{:.5}, {:.5}, {:.5}] rad/s", b[0], b[1], b[2])
    })
}
