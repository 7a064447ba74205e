//! The classical baselines `eval` compares with: the raw gyro, the mean over the initial
//! rest subtracted ([`RestDetector`]), and the pipeline's own power-on bias.

use nalgebra::Vector3;

use crate::core::{ImuSample, Recording, STANDARD_GRAVITY};

use super::EvalError;

/// How rest is detected for the static-bias baseline. Rest is judged on the means of short
/// blocks, not on sample spread: a robot on the ground with motors or engine running
/// vibrates (EuRoC's MAV: accel std ≈ 0.3 m/s² at rest) but its block means stay put.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub struct RestDetector {
    /// Window judged at once, s.
    pub window_s: f64,
    /// Blocks per window whose means are compared.
    pub blocks: usize,
    /// Rest while the block means of every gyro axis span less than this, rad/s …
    pub max_gyro_spread: f64,
    /// … and those of every accelerometer axis less than this, m/s² …
    pub max_accel_spread: f64,
    /// … and ‖mean accel‖ is within this of 9.81 m/s² (not in free fall or accelerating).
    pub max_gravity_error: f64,
    /// The bias is averaged over at most this many seconds from the start.
    pub max_seconds: f64,
    /// Less rest than this and the baseline is not available.
    pub min_seconds: f64,
}

impl Default for RestDetector {
    fn default() -> Self {
        // 0.1 s block means of a vibrating robot at rest (σ ≈ 0.02 rad/s per sample at 200 Hz)
        // scatter by ~0.005 rad/s; walking or driving moves them by far more than 0.02 rad/s.
        RestDetector {
            window_s: 0.5,
            blocks: 5,
            max_gyro_spread: 0.02,
            max_accel_spread: 0.2,
            max_gravity_error: 0.5,
            max_seconds: 10.0,
            min_seconds: 0.5,
        }
    }
}

/// The initial rest interval as IMU indices [0, end), if at least `min_seconds` long.
/// Windows are consecutive from the first sample; rest ends at the first window that moves.
pub fn detect_initial_rest(imu: &[ImuSample], det: &RestDetector) -> Option<usize> {
    let t0 = imu.first()?.stamp_ns;
    let block_ns = (det.window_s / det.blocks.max(1) as f64 * 1e9) as i64;
    let mut start = 0;
    let mut end = 0;
    'windows: while start < imu.len() {
        let mut lo = (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::INFINITY));
        let mut hi = (Vector3::repeat(f64::NEG_INFINITY), Vector3::repeat(f64::NEG_INFINITY));
        let mut accel_sum = Vector3::zeros();
        let mut b0 = start;
        for _ in 0..det.blocks.max(1) {
            let stop_ns = imu.get(b0)?.stamp_ns + block_ns;
            let b1 = imu[b0..].iter().position(|s| s.stamp_ns >= stop_ns).map_or(imu.len(), |k| b0 + k);
            if b1 - b0 < 2 || (imu[b1 - 1].stamp_ns - t0) as f64 * 1e-9 > det.max_seconds {
                break 'windows;
            }
            let n = (b1 - b0) as f64;
            let g = imu[b0..b1].iter().map(|s| s.gyro).sum::<Vector3<f64>>() / n;
            let a = imu[b0..b1].iter().map(|s| s.accel).sum::<Vector3<f64>>() / n;
            accel_sum += a;
            lo = (lo.0.inf(&g), lo.1.inf(&a));
            hi = (hi.0.sup(&g), hi.1.sup(&a));
            b0 = b1;
        }
        let mean_accel = accel_sum / det.blocks.max(1) as f64;
        let still = (hi.0 - lo.0).max() < det.max_gyro_spread
            && (hi.1 - lo.1).max() < det.max_accel_spread
            && (mean_accel.norm() - STANDARD_GRAVITY).abs() < det.max_gravity_error;
        if !still {
            break;
        }
        end = b0;
        start = b0;
    }
    // Duration covered by the rest samples, each counted with its own interval.
    let secs = if end > 0 { (imu[end.min(imu.len() - 1)].stamp_ns - t0) as f64 * 1e-9 } else { 0.0 };
    (secs >= det.min_seconds).then_some(end)
}

fn mean(it: impl Iterator<Item = Vector3<f64>>) -> Vector3<f64> {
    let (sum, n) = it.fold((Vector3::zeros(), 0usize), |(s, n), v| (s + v, n + 1));
    sum / n.max(1) as f64
}

/// A gyro method that needs no model: what a user has before learning anything.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BaselineMethod {
    /// The gyro as recorded.
    Raw,
    /// The gyro minus its mean over the initial rest (see [`RestDetector`]).
    StaticBias,
    /// The pipeline's own: the gyro minus this power-on's bias as the node measures it at
    /// standstills, causally (the initial one and any later), the attitude held at standstills
    /// ([`crate::standstill`]).
    PowerOnBias,
}

impl BaselineMethod {
    pub fn name(self) -> &'static str {
        match self {
            BaselineMethod::Raw => "raw",
            BaselineMethod::StaticBias => "static-bias",
            BaselineMethod::PowerOnBias => "power-on-bias",
        }
    }

    /// Corrected gyro for each IMU sample, and a note on what was done.
    /// `standstill`: how the power-on bias finds standstills (the node's `pipeline.standstill`).
    pub fn apply(
        self,
        rec: &Recording,
        det: &RestDetector,
        standstill: &crate::standstill::StandstillConfig,
    ) -> Result<(Vec<Vector3<f64>>, String), EvalError> {
        let raw = rec.imu.iter().map(|s| s.gyro);
        match self {
            BaselineMethod::Raw => Ok((raw.collect(), String::new())),
            BaselineMethod::StaticBias => {
                let end = detect_initial_rest(&rec.imu, det).ok_or_else(|| EvalError::Method {
                    name: rec.name.clone(),
                    method: self.name().into(),
                    why: format!(
                        "no initial rest of at least {} s (0.1 s block means spreading < {} rad/s gyro, < {} m/s² accel)",
                        det.min_seconds, det.max_gyro_spread, det.max_accel_spread
                    ),
                })?;
                let bias = mean(rec.imu[..end].iter().map(|s| s.gyro));
                let secs = (rec.imu[end - 1].stamp_ns - rec.imu[0].stamp_ns) as f64 * 1e-9;
                let note = format!("rest {secs:.1} s, bias [{:.5}, {:.5}, {:.5}] rad/s", bias.x, bias.y, bias.z);
                Ok((raw.map(|g| g - bias).collect(), note))
            }
            BaselineMethod::PowerOnBias => {
                let track = crate::standstill::BiasTrack::over(&rec.imu, standstill);
                Ok((track.corrected_gyro(&rec.imu), track.note()))
            }
        }
    }
}
