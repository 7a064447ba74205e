//! `imu-fsda inject`: a known error applied to a recorded bag. A real recording keeps its own
//! noise, bias and motion; the injected terms are the truth a diagnosis or an adaptation is
//! then scored against ("a real recording beats the simulator", with effects injected where
//! the truth must be known).
//!
//! The terms act on the recorded gyro and accelerometer; the attitude and angular
//! acceleration some terms need (g-sensitivity in the world, a lever arm) come from the
//! ground truth, differentiated with the diagnosis's smoother. Ground truth, temperature and
//! stamps are written unchanged.

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::bag::{read_recording, write_recording, RecordingTopics, GROUND_TRUTH_TOPIC, IMU_TOPIC};
use imu_fsda::diagnose::kinematics;
use imu_fsda::physics::{apply_terms, ImuSignals, Term, TermContext};

/// Ground-truth smoother half-width for the attitude and angular acceleration, s.
const SMOOTHING_S: f64 = 0.05;

#[derive(Debug, clap::Args)]
pub struct InjectArgs {
    /// The recorded bag (IMU and ground truth).
    #[arg(value_name = "IN.mcap")]
    pub input: PathBuf,
    /// Error term as inline YAML, e.g. '{term: gyro_scale, scale: [0.02, -0.01, 0.015]}'. Repeatable.
    #[arg(long = "term", value_name = "YAML", required = true)]
    pub terms: Vec<String>,
    /// Seed of the terms that draw (noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// IMU topic.
    #[arg(long, default_value = IMU_TOPIC)]
    pub imu_topic: String,
    /// Ground-truth topic.
    #[arg(long, default_value = GROUND_TRUTH_TOPIC)]
    pub ground_truth_topic: String,
    /// Output bag (MCAP).
    #[arg(short, long, value_name = "OUT.mcap")]
    pub output: PathBuf,
}

pub fn run(args: InjectArgs) -> anyhow::Result<()> {
    let terms = args
        .terms
        .iter()
        .enumerate()
        .map(|(i, text)| serde_yaml::from_str::<Term>(text).with_context(|| format!("--term #{} `{text}`", i + 1)))
        .collect::<anyhow::Result<Vec<Term>>>()?;
    super::refuse_overwriting_input(&args.output, &[args.input.as_path()])?;
    let topics = RecordingTopics { imu: args.imu_topic.clone(), ground_truth: Some(args.ground_truth_topic.clone()), temperature: None };
    let (mut rec, report) = read_recording(&args.input, &topics).with_context(|| format!("reading {}", args.input.display()))?;
    anyhow::ensure!(rec.imu.len() >= 2, "{}: {} IMU samples", args.input.display(), rec.imu.len());
    anyhow::ensure!(
        report.imu_non_finite == 0,
        "{}: {} non-finite IMU samples: fix the bag first",
        args.input.display(),
        report.imu_non_finite
    );
    let stamps: Vec<i64> = rec.imu.iter().map(|s| s.stamp_ns).collect();
    let mut signals = match kinematics::ideal_from_poses_with(&rec.ground_truth, &stamps, Some(SMOOTHING_S)) {
        Ok(ideal) => ideal,
        Err(e) => {
            tracing::warn!("{}: {e}; the terms see a level, unaccelerated attitude", args.input.display());
            let n = stamps.len();
            ImuSignals {
                stamps_ns: stamps.clone(),
                world_from_imu: vec![nalgebra::UnitQuaternion::identity(); n],
                alpha_in_imu: vec![nalgebra::Vector3::zeros(); n],
                temperature_c: vec![25.0; n],
                gyro: vec![],
                accel: vec![],
            }
        }
    };
    signals.gyro = rec.imu.iter().map(|s| s.gyro).collect();
    signals.accel = rec.imu.iter().map(|s| s.accel).collect();
    apply_terms(&terms, &mut signals, &mut TermContext::new(args.seed)).context("applying the terms")?;
    for (s, (g, a)) in rec.imu.iter_mut().zip(signals.gyro.iter().zip(&signals.accel)) {
        s.gyro = *g;
        s.accel = *a;
    }
    write_recording(&args.output, &rec).with_context(|| format!("writing {}", args.output.display()))?;
    eprintln!("{}: {} term(s) applied to {} IMU samples → {}", args.input.display(), terms.len(), rec.imu.len(), args.output.display());
    Ok(())
}
