//! `imu-fsda import DIR -o OUT.mcap`: an EuRoC or TUM-VI sequence folder to a ROS 2 bag.

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::bag::{write_recording, GROUND_TRUTH_TOPIC, IMU_TOPIC};
use imu_fsda::dataset::{detect, load_sequence};

#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// Sequence folder in the ASL layout (the folder holding `mav0/`, or `mav0/` itself).
    pub dir: PathBuf,
    /// Output bag (`/imu/data` sensor_msgs/Imu in `imu_link`, `/ground_truth/pose` PoseStamped in `world`).
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run(args: ImportArgs) -> anyhow::Result<()> {
    if let Ok(seq) = detect(&args.dir) {
        super::refuse_overwriting_input(&args.output, &[&seq.imu_csv, &seq.ground_truth_csv])?;
    }
    let (seq, rec, report) = load_sequence(&args.dir).with_context(|| format!("importing {}", args.dir.display()))?;
    // What no command could use is refused; what only some could is imported and said.
    if rec.imu.len() < 2 {
        anyhow::bail!("{}: {} usable IMU sample(s): nothing to import ({report})", seq.imu_csv.display(), rec.imu.len());
    }
    let (i0, i1) = (rec.imu[0].stamp_ns, rec.imu[rec.imu.len() - 1].stamp_ns);
    let (g0, g1) = (rec.ground_truth[0].stamp_ns, rec.ground_truth[rec.ground_truth.len() - 1].stamp_ns);
    if rec.ground_truth.len() < 2 {
        tracing::warn!(
            "{}: {} ground-truth pose: eval, train and adapt will have nothing to score",
            seq.ground_truth_csv.display(),
            rec.ground_truth.len()
        );
    } else if g1 < i0 || g0 > i1 {
        tracing::warn!(
            "{}: the ground truth ({:.3}–{:.3} s) does not overlap the IMU ({:.3}–{:.3} s) in time: eval, train and adapt will refuse this bag",
            seq.ground_truth_csv.display(),
            g0 as f64 * 1e-9,
            g1 as f64 * 1e-9,
            i0 as f64 * 1e-9,
            i1 as f64 * 1e-9
        );
    }
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
    // The bag is written in stamp order: the source's jitter would not show later.
    if let Some(note) = report.imu_stream_note() {
        out!("note: {note}")?;
    }
    Ok(())
}
