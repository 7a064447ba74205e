//! `imu-fsda attitude BAG...`: the attitude a node published (`/imu/denoised`, from `replay`
//! or recorded beside the live node) against the bag's ground truth: its tilt, its heading
//! drift, and whether the covariance it stated covers them.

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::bag::{read_published_attitudes, read_recording, RecordingTopics, GROUND_TRUTH_TOPIC};
use imu_fsda::eval::{evaluate_published, EvalOptions, PublishedAttitudeErrors, CHI2_2DOF_95};

#[derive(Debug, clap::Args)]
pub struct AttitudeArgs {
    /// Bags with the node's output topic and a ground-truth topic (`imu-fsda replay` writes both).
    #[arg(required = true)]
    pub bags: Vec<PathBuf>,
    /// The node's output (sensor_msgs/Imu with orientation and orientation_covariance).
    #[arg(long, default_value = "/imu/denoised")]
    pub topic: String,
    /// Ground-truth topic (PoseStamped, Odometry, or an Imu carrying orientation).
    #[arg(long, default_value = GROUND_TRUTH_TOPIC)]
    pub ground_truth_topic: String,
    /// Longest ground-truth gap interpolated over, ms; attitudes in longer gaps are not scored.
    #[arg(long, default_value_t = 50.0, value_parser = super::positive)]
    pub max_gap_ms: f64,
    /// Also write the table as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Debug, serde::Serialize)]
pub struct Row {
    pub bag: String,
    pub errors: Option<PublishedAttitudeErrors>,
    pub note: String,
}

pub fn run(args: AttitudeArgs) -> anyhow::Result<()> {
    if let Some(out) = &args.json {
        let inputs: Vec<&std::path::Path> = args.bags.iter().map(PathBuf::as_path).collect();
        super::refuse_overwriting_input(out, &inputs)?;
    }
    anyhow::ensure!(
        args.topic != args.ground_truth_topic,
        "--topic and --ground-truth-topic are both {}: the attitude is scored against another source",
        args.topic
    );
    let opts = EvalOptions { max_gap_ns: (args.max_gap_ms * 1e6) as i64 };
    // The ground truth is read as every command reads it (log-time order, frozen poses left
    // out), with the node's output as the IMU stream that read needs.
    let topics = RecordingTopics { imu: args.topic.clone(), ground_truth: Some(args.ground_truth_topic.clone()), temperature: None };
    let mut rows = Vec::new();
    let mut failed = Vec::new();
    for bag in &args.bags {
        let name = bag.file_stem().map_or_else(|| bag.display().to_string(), |s| s.to_string_lossy().into_owned());
        let scored = (|| -> anyhow::Result<Row> {
            let published = read_published_attitudes(bag, &args.topic)?;
            anyhow::ensure!(
                !published.attitudes.is_empty(),
                "{}: none of the {} messages on {} carries an orientation (orientation_covariance[0] = -1 in all: a node without \
                 an attitude yet, or not this project's node)",
                bag.display(),
                published.messages,
                args.topic
            );
            let (rec, _) = read_recording(bag, &topics)?;
            anyhow::ensure!(
                !rec.ground_truth.is_empty(),
                "{}: no ground truth on {}; pass --ground-truth-topic",
                bag.display(),
                args.ground_truth_topic
            );
            let first = published.first_stamp_ns.unwrap_or(published.attitudes[0].stamp_ns);
            let e = evaluate_published(&name, &rec.ground_truth, &published.attitudes, first, &opts)?;
            let mut notes = Vec::new();
            if e.tilt_initial_deg > 90.0 {
                notes.push("tilt over 90° at the start: the ground truth's world z is not up, or its body is not the IMU's frame".into());
            }
            if e.in_gaps > 0 {
                notes.push(format!("{} attitudes in ground-truth gaps, not scored", e.in_gaps));
            }
            if published.skipped > 0 {
                notes.push(format!("{} orientations skipped (not finite, or stamped at or before the one before)", published.skipped));
            }
            if e.tilt_covariance_invalid > 0 {
                notes.push(format!("{} tilt covariances not positive definite: no NEES there", e.tilt_covariance_invalid));
            }
            Ok(Row { bag: name.clone(), errors: Some(e), note: notes.join("; ") })
        })();
        match scored {
            Ok(row) => rows.push(row),
            Err(e) if args.bags.len() == 1 => return Err(e),
            Err(e) => {
                let why = super::error_text(&e);
                tracing::error!("{why}");
                rows.push(Row { bag: name, errors: None, note: format!("not evaluated: {why}") });
                failed.push(bag.display().to_string());
            }
        }
    }
    let table = markdown_table(&rows);
    out!("{}", table.trim_end_matches('\n'))?;
    if let Some(p) = &args.json {
        let doc = serde_json::json!({"options": opts, "topic": args.topic, "chi2_2dof_95": CHI2_2DOF_95, "rows": rows});
        std::fs::write(p, serde_json::to_string_pretty(&doc)?).with_context(|| format!("writing {}", p.display()))?;
    }
    super::every_bag_scored(&failed, args.bags.len())
}

pub fn markdown_table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| bag | first attitude s | scored s | AOE° | tilt at start° | tilt RMS° | tilt max° | tilt last° | heading drift RMS° | heading drift last° \
         | stated tilt σ° (median) | tilt NEES (2: consistent) | within 95 % | note |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        match &r.errors {
            Some(e) => {
                s += &format!(
                    "| {} | {:.2} | {:.0} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.0} % | {} |\n",
                    r.bag,
                    e.first_attitude_s,
                    e.seconds,
                    e.aoe_deg,
                    e.tilt_initial_deg,
                    e.tilt_rmse_deg,
                    e.tilt_max_deg,
                    e.tilt_final_deg,
                    e.heading_rmse_deg,
                    e.heading_final_deg,
                    e.tilt_sigma_median_deg,
                    e.tilt_nees_mean,
                    100.0 * e.tilt_within_95,
                    r.note
                )
            }
            None => s += &format!("| {} | – | – | – | – | – | – | – | – | – | – | – | – | {} |\n", r.bag, r.note),
        }
    }
    s
}
