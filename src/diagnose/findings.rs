//! The findings of a diagnosis: each fitted term with its evidence and uncertainty, judged
//! plausible or not on its 95 % interval, and the terms read off the samples.

use super::select::{SelectOptions, Selection};
use super::{bandwidth, catalogue, Finding};
use crate::physics::Term;

/// A fitted term waiting for its σ to be widened (by the residual's excess over its noise
/// model) before its plausibility is judged.
pub(super) struct Pending {
    finding: Finding,
    term: Term,
    /// 1 σ per parameter, before the widening.
    sd: Vec<f64>,
    /// The sensor's own rate, where plausibility is judged (not the comparison's).
    sample_rate_hz: f64,
}

/// The fitted terms (`fitted`: each with its σ per parameter) as findings to judge, with
/// their evidence from the selection's steps; a term no sensor can have (a gain 1 + s below
/// 0) is left out with a note. Returns them and the terms kept.
pub(super) fn fitted(
    sel: &Selection,
    fitted: &[(Term, Vec<f64>)],
    select: &SelectOptions,
    sample_rate_hz: f64,
    full_rate: bool,
    notes: &mut Vec<String>,
) -> (Vec<Pending>, Vec<Term>) {
    let mut pending = Vec::new();
    let mut terms = Vec::new();
    for (term, sd) in fitted {
        if let Err(e) = term.validate() {
            notes.push(format!(
                "{} was fitted to a value no sensor has ({e}) and is left out: the recordings may not show the same motion, or their frames differ",
                term.name()
            ));
            continue;
        }
        let step = sel.steps.iter().rev().find(|s| s.action == "add" && s.term == term.name());
        let mut evidence = serde_json::json!({
            "heldout_loglik_gain": step.map(|s| s.heldout_gain),
            "runner_up": step.and_then(|s| s.runner_up.clone()).map(|(t, g)| serde_json::json!({"term": t, "heldout_loglik_gain": g})),
            "rule": format!("added while the held-out log-likelihood gain exceeded {} + {} per parameter", select.threshold, select.per_param),
        });
        if let (Term::TimeOffset(t), false) = (term, full_rate) {
            if let Some(f_c) = bandwidth::equivalent_low_pass_hz(t.seconds, 1.0 / sample_rate_hz) {
                evidence["also_explained_by"] = serde_json::json!(format!(
                    "a first-order low-pass at {f_c:.1} Hz (its delay), or any mix of a delay and a filter: the two are one effect at the compared bandwidth; the delay is given once, and neither is a finding on its own"
                ));
            }
        }
        let finding = Finding {
            term: term.name().into(),
            params: catalogue::params_json(term),
            uncertainty: uncertainty_json(term, sd),
            interval_95: serde_json::Value::Null,
            evidence,
            implausible: None,
        };
        pending.push(Pending { finding, term: term.clone(), sd: sd.clone(), sample_rate_hz });
        terms.push(term.clone());
    }
    (pending, terms)
}

/// The terms read off the samples or taken out exactly before the fit (saturation,
/// quantisation, a gross rotation), with the rule that found each: findings without a σ.
pub(super) fn taken_out_exactly(direct: Vec<(Term, serde_json::Value)>) -> (Vec<Finding>, Vec<Term>) {
    direct
        .into_iter()
        .map(|(term, evidence)| {
            let f = Finding {
                term: term.name().into(),
                params: catalogue::params_json(&term),
                uncertainty: serde_json::json!(null),
                interval_95: serde_json::Value::Null,
                evidence,
                implausible: None,
            };
            (f, term)
        })
        .unzip()
}

/// Each pending term's σ widened by √`excess` (χ²/n of the residual after the fit, at least
/// 1), its 95 % intervals, and its plausibility judged on them: (findings, implausible).
pub(super) fn judge(pending: Vec<Pending>, excess: f64) -> (Vec<Finding>, Vec<Finding>) {
    let (mut findings, mut implausible) = (Vec::new(), Vec::new());
    for Pending { finding: mut f, term, sd, sample_rate_hz } in pending {
        scale_numbers(&mut f.uncertainty, excess.sqrt());
        f.interval_95 = interval(&f.params, &f.uncertainty, 1.96);
        let sd: Vec<f64> = sd.iter().map(|s| s * excess.sqrt()).collect();
        match plausibility(&term, &sd, sample_rate_hz) {
            Plausibility::Plausible => findings.push(f),
            Plausibility::WithinItsInterval(why) => {
                f.evidence["plausible_within_95"] = serde_json::json!(format!(
                    "its estimate is beyond the plausible range ({why}); its 95 % interval reaches into it, so it stands as a finding"
                ));
                findings.push(f);
            }
            Plausibility::Implausible(why) => {
                f.implausible = Some(why);
                implausible.push(f);
            }
        }
    }
    (findings, implausible)
}

/// A fitted term's size against its plausible range ([`catalogue::PLAUSIBLE`]).
enum Plausibility {
    Plausible,
    /// Its estimate is beyond the range, its 95 % interval reaches into it (why it is beyond).
    WithinItsInterval(String),
    /// Its whole 95 % interval is beyond the range (why).
    Implausible(String),
}

/// Judged on the estimate and, where it is beyond the range, on the value of its 95 %
/// interval (± 1.96 σ per parameter) nearest the range: a size a sensor can have that the
/// data do not rule out is not called implausible.
fn plausibility(term: &Term, sd: &[f64], sample_rate_hz: f64) -> Plausibility {
    let Some(why) = catalogue::implausible(term, sample_rate_hz) else { return Plausibility::Plausible };
    match catalogue::nearest_plausible(term, sd, 1.96) {
        Some(nearest) if catalogue::implausible(&nearest, sample_rate_hz).is_none() => Plausibility::WithinItsInterval(why),
        _ => Plausibility::Implausible(why),
    }
}

/// Every number in `v` times `k`.
fn scale_numbers(v: &mut serde_json::Value, k: f64) {
    match v {
        serde_json::Value::Number(n) => {
            if let Some(x) = n.as_f64() {
                *v = serde_json::json!(x * k);
            }
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(|x| scale_numbers(x, k)),
        serde_json::Value::Object(o) => o.values_mut().for_each(|x| scale_numbers(x, k)),
        _ => {}
    }
}

/// [p − z·σ, p + z·σ] for every parameter p of `params` with its σ in `sd` (same layout);
/// null where `sd` gives none.
fn interval(params: &serde_json::Value, sd: &serde_json::Value, z: f64) -> serde_json::Value {
    use serde_json::Value;
    match (params, sd) {
        (Value::Number(p), Value::Number(s)) => match (p.as_f64(), s.as_f64()) {
            (Some(p), Some(s)) => serde_json::json!([p - z * s, p + z * s]),
            _ => Value::Null,
        },
        (Value::Array(p), Value::Array(s)) if p.len() == s.len() => Value::Array(p.iter().zip(s).map(|(p, s)| interval(p, s, z)).collect()),
        (Value::Object(p), Value::Object(s)) => {
            let o: serde_json::Map<String, Value> =
                p.iter().filter_map(|(k, pv)| s.get(k).map(|sv| (k.clone(), interval(pv, sv, z)))).filter(|(_, v)| !v.is_null()).collect();
            if o.is_empty() {
                Value::Null
            } else {
                Value::Object(o)
            }
        }
        _ => Value::Null,
    }
}

/// Uncertainty in the layout of the term's params (per fitted parameter, 1 σ).
fn uncertainty_json(term: &Term, sd: &[f64]) -> serde_json::Value {
    use serde_json::json;
    if sd.is_empty() {
        return json!(null);
    }
    let v = |o: usize| json!([sd[o], sd[o + 1], sd[o + 2]]);
    match term {
        Term::GyroBias(_) | Term::AccelBias(_) => json!({"bias": v(0)}),
        Term::GyroScale(_) | Term::AccelScale(_) => json!({"scale": v(0)}),
        Term::GyroMisalignment(_) | Term::AccelMisalignment(_) => {
            let mut m = [[0.0; 3]; 3];
            for (k, &(r, c)) in catalogue::OFF_DIAGONAL.iter().enumerate() {
                m[r][c] = sd[k];
            }
            json!({ "matrix": m })
        }
        Term::GyroGSensitivity(_) => json!({"matrix": [[sd[0], sd[1], sd[2]], [sd[3], sd[4], sd[5]], [sd[6], sd[7], sd[8]]]}),
        Term::GyroBiasTemperature(_) => json!({"coefficient": v(0)}),
        Term::MountRotation(_) => json!({"rotvec": v(0)}),
        Term::LeverArm(_) => json!({"offset": v(0)}),
        Term::TimeOffset(_) => json!({"seconds": sd[0]}),
        Term::GravityMagnitude(_) => json!({"g": sd[0]}),
        Term::EarthRotation(e) => {
            // Delta method on φ = atan2(s, c) at unit magnitude.
            let (c, s) = (e.latitude_rad.cos(), e.latitude_rad.sin());
            json!({"latitude_rad": ((s * sd[0]).powi(2) + (c * sd[1]).powi(2)).sqrt()})
        }
        Term::Vibration(_) => {
            json!({"accel_amplitude": [sd[0].hypot(sd[3]) / std::f64::consts::SQRT_2, sd[1].hypot(sd[4]) / std::f64::consts::SQRT_2, sd[2].hypot(sd[5]) / std::f64::consts::SQRT_2]})
        }
        _ => json!(sd),
    }
}
