//! The query cut into pieces, each judged from its own start: a gain on the query is taken
//! as the IMU's only where it holds piece after piece, not where one stretch decides the whole
//! query's AOE. Without other power-ons to judge on, this is the evidence `adapt` keeps a
//! calibration on (docs/adaptation.md, step 7).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::judge::CarryOver;
use crate::core::Recording;
use crate::eval::{evaluate, EvalOptions};

/// Length of one piece, s: long enough that a few-per-cent scale error turns the attitude by
/// more than the reference's own error, short enough for a minute's query to give several.
pub const QUERY_PIECE_S: f64 = 10.0;

/// A candidate's AOE over the pieces of the query, against the gyro without it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PieceConfidence {
    /// Geometric mean over the pieces of AOE with the candidate / without it.
    pub ratio: f64,
    /// Its one-sided 95 % upper bound (Student's t on the log-ratios).
    pub upper_95: f64,
    pub pieces: usize,
    pub piece_seconds: f64,
}

impl PieceConfidence {
    /// The gain holds with confidence: the bound below 1 over at least two pieces.
    pub fn holds(&self) -> bool {
        self.pieces >= 2 && self.upper_95 < 1.0
    }
}

/// `candidate` and `without` (one corrected gyro per IMU sample of `rec`) scored on each
/// `QUERY_PIECE_S` piece of `rec`, the attitude integrated from the ground truth at the
/// piece's start. A piece the evaluation cannot score (no ground truth over it) is left out;
/// a last piece shorter than half is joined to the one before. `None`: no piece scored.
pub fn piece_confidence(
    rec: &Recording,
    candidate: &[Vector3<f64>],
    without: &[Vector3<f64>],
    opts: &EvalOptions,
) -> Option<PieceConfidence> {
    let logs: Vec<f64> = piece_log_ratios(rec, candidate, without, opts, 0).into_iter().filter(|l| l.is_finite()).collect();
    if logs.is_empty() {
        return None;
    }
    let c = CarryOver::of_log_ratios(&logs);
    Some(PieceConfidence { ratio: c.ratio, upper_95: c.upper_95, pieces: logs.len(), piece_seconds: QUERY_PIECE_S })
}

/// ln(AOE with `candidate` / AOE with `without`) on each piece of `rec` that starts at sample
/// `from` or later (the pieces as [`piece_confidence`] cuts them); NaN for a piece that could
/// not be scored, so two candidates' pieces line up.
fn piece_log_ratios(rec: &Recording, candidate: &[Vector3<f64>], without: &[Vector3<f64>], opts: &EvalOptions, from: usize) -> Vec<f64> {
    log_ratios(&piece_aoe(rec, candidate, opts, from), &piece_aoe(rec, without, opts, from))
}

/// AOE of `gyro` on each piece of `rec` from sample `from` on, each integrated from the ground
/// truth at its start; NaN where a piece cannot be scored.
pub(super) fn piece_aoe(rec: &Recording, gyro: &[Vector3<f64>], opts: &EvalOptions, from: usize) -> Vec<f64> {
    piece_bounds(rec)
        .into_iter()
        .filter(|&(a, _)| a >= from)
        .map(|(a, b)| evaluate(&piece_of(rec, a, b), &gyro[a..b], opts).map_or(f64::NAN, |e| e.aoe_deg))
        .collect()
}

/// ln(with / base) piece by piece; NaN where either is not a positive finite AOE.
pub(super) fn log_ratios(with: &[f64], base: &[f64]) -> Vec<f64> {
    with.iter()
        .zip(base)
        .map(|(&w, &b)| if w > 0.0 && b > 0.0 && w.is_finite() && b.is_finite() { (w / b).ln() } else { f64::NAN })
        .collect()
}

/// Index ranges `[a, b)` of the IMU samples in each piece.
fn piece_bounds(rec: &Recording) -> Vec<(usize, usize)> {
    let Some(first) = rec.imu.first() else { return Vec::new() };
    let piece_ns = (QUERY_PIECE_S * 1e9) as i64;
    let mut bounds: Vec<(usize, usize)> = Vec::new();
    let mut a = 0;
    while a < rec.imu.len() {
        let end = first.stamp_ns + piece_ns * ((rec.imu[a].stamp_ns - first.stamp_ns) / piece_ns + 1);
        let b = a + rec.imu[a..].partition_point(|s| s.stamp_ns < end);
        bounds.push((a, b));
        a = b;
    }
    // A short tail judges little on its own.
    if let [.., _, (tail_a, tail_b)] = bounds[..] {
        let tail_s = (rec.imu[tail_b - 1].stamp_ns - rec.imu[tail_a].stamp_ns) as f64 * 1e-9;
        if tail_s < QUERY_PIECE_S / 2.0 {
            bounds.pop();
            if let Some(last) = bounds.last_mut() {
                last.1 = tail_b;
            }
        }
    }
    bounds
}

/// The IMU samples `[a, b)` with the ground truth over them (and a second either side, for
/// interpolation at the ends).
fn piece_of(rec: &Recording, a: usize, b: usize) -> Recording {
    let (t0, t1) = (rec.imu[a].stamp_ns - 1_000_000_000, rec.imu[b - 1].stamp_ns + 1_000_000_000);
    let lo = rec.ground_truth.partition_point(|p| p.stamp_ns < t0);
    let hi = rec.ground_truth.partition_point(|p| p.stamp_ns <= t1);
    Recording {
        name: rec.name.clone(),
        imu: rec.imu[a..b].to_vec(),
        ground_truth: rec.ground_truth[lo..hi.max(lo)].to_vec(),
        temperature: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::{ImuSample, PoseSample};
    use nalgebra::{UnitQuaternion, Vector3};

    /// A body turning at a steady 0.5 rad/s about z for `seconds`, 100 Hz, ground truth exact.
    fn turning(seconds: f64) -> Recording {
        let n = (seconds * 100.0) as usize;
        let rate = Vector3::new(0.0, 0.0, 0.5);
        let stamp = |k: usize| (k as i64) * 10_000_000;
        let imu = (0..n).map(|k| ImuSample { stamp_ns: stamp(k), gyro: rate, accel: Vector3::new(0.0, 0.0, 9.81) }).collect();
        let ground_truth = (0..n)
            .map(|k| PoseSample {
                stamp_ns: stamp(k),
                position_in_world: Vector3::zeros(),
                world_from_body: UnitQuaternion::from_scaled_axis(rate * k as f64 * 0.01),
            })
            .collect();
        Recording { name: "turning".into(), imu, ground_truth, temperature: Vec::new() }
    }

    fn with_scale(rec: &Recording, scale: f64) -> Vec<Vector3<f64>> {
        rec.imu.iter().map(|s| s.gyro * scale).collect()
    }

    #[test]
    fn a_gain_that_holds_in_every_piece_is_confident() {
        let rec = turning(60.0);
        let opts = EvalOptions::default();
        // Without: a 3 % scale error; the candidate: 0.3 %.
        let c = piece_confidence(&rec, &with_scale(&rec, 1.003), &with_scale(&rec, 1.03), &opts).unwrap();
        assert_eq!(c.pieces, 6, "{c:?}");
        assert!(c.holds() && c.ratio < 0.2, "{c:?}");
    }

    #[test]
    fn no_gain_is_not_confident() {
        let rec = turning(60.0);
        let opts = EvalOptions::default();
        let c = piece_confidence(&rec, &with_scale(&rec, 1.02), &with_scale(&rec, 0.98), &opts).unwrap();
        assert!(!c.holds(), "{c:?}");
        // One piece alone never is.
        let short = turning(12.0);
        let c = piece_confidence(&short, &with_scale(&short, 1.001), &with_scale(&short, 1.03), &opts).unwrap();
        assert_eq!(c.pieces, 1, "{c:?}");
        assert!(!c.holds(), "{c:?}");
    }

    #[test]
    fn a_short_tail_joins_the_piece_before() {
        let rec = turning(34.0);
        assert_eq!(piece_bounds(&rec), vec![(0, 1000), (1000, 2000), (2000, 3400)]);
        let rec = turning(36.0);
        assert_eq!(piece_bounds(&rec).len(), 4);
    }
}
