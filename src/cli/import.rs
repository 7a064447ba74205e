//! `imu-fsda import DIR -o OUT.mcap`: an EuRoC or TUM-VI sequence folder to a ROS 2 bag.

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::bag::{write_recording, GROUND_TRUTH_TOPIC, IMU_TOPIC};
use imu_fsda::dataset::load_sequence;

#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// Sequence folder in the ASL layout (the folder holding `mav0/`, or `mav0/` itself).
    pub dir: PathBuf,
    /// Output bag (`/imu/data` sensor_msgs/Imu in `imu_link`, `/ground_truth/pose` PoseStamped in `world`).
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run(args: ImportArgs) -> anyhow::Result<()> {
    let (seq, rec, report) = load_sequence(&args.dir).with_context(|| format!("importing {}", args.dir.display()))?;
    write_recording(&args.output, &rec).with_context(|| format!("writing {}", args.output.display()))?;
    out!(
        "{} ({:?}): {} IMU samples at {:.2} Hz over {:.1} s, {} ground-truth poses → {} ({IMU_TOPIC}, {GROUND_TRUTH_TOPIC})",
        seq.name,
        seq.kind,
        rec.imu.len(),
        rec.imu_rate_hz(),
        rec.imu_seconds(),
        rec.ground_truth.len(),
        args.output.display()
    )?;
    if report.skipped() > 0 {
        out!("skipped: {report}")?;
    }
    Ok(())
}
