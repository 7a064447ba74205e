//! `imu-fsda adapt`: few-shot adaptation of a model to a new robot / IMU from one bag with
//! ground truth. The first `--support-seconds` (with ground truth) adapt the Embedding; the
//! rest (or `--query-seconds` of it) is held back to judge: the adapted model is written only
//! if its orientation error there is lower than the starting model's.

use std::path::{Path, PathBuf};

use anyhow::Context;
use imu_fsda::adapt::{adapt, keep_without_judge, save_adapted, split_recording, AdaptConfig, AdaptReport, CarryOver, FramePolicy};
use imu_fsda::bag::{read_recording, RecordingTopics, GROUND_TRUTH_TOPIC, IMU_TOPIC};
use imu_fsda::core::Recording;
use imu_fsda::model::export::{load_metadata, load_net};
use imu_fsda::model::predict::metadata_path;

#[derive(Debug, clap::Args)]
pub struct AdaptArgs {
    /// The model to adapt (`.pt`, `.ot` or `.json`; the three files must sit together).
    #[arg(long)]
    pub model: PathBuf,
    /// MCAP bag with the IMU and ground truth of the new robot / IMU.
    #[arg(long)]
    pub bag: PathBuf,
    /// Where to write the adapted model (`<dir>/<name>.pt`; `.ot`, `.json`, `.adapt.json` beside it).
    #[arg(short, long)]
    pub output: PathBuf,
    #[arg(long, default_value = IMU_TOPIC)]
    pub imu_topic: String,
    /// geometry_msgs/PoseStamped, nav_msgs/Odometry, or a reference sensor_msgs/Imu's orientation.
    #[arg(long, default_value = GROUND_TRUTH_TOPIC)]
    pub ground_truth_topic: String,
    /// Support set: this many seconds from the first ground-truth-covered IMU sample.
    #[arg(long, default_value_t = 60.0, value_parser = super::span_seconds)]
    pub support_seconds: f64,
    /// Query set (held back): this many seconds after the support set (default: the rest).
    #[arg(long, value_parser = super::span_seconds)]
    pub query_seconds: Option<f64>,
    /// Inner steps and learning rate (defaults: AdaptConfig's).
    #[arg(long)]
    pub steps: Option<usize>,
    #[arg(long, value_parser = super::non_negative)]
    pub lr: Option<f64>,
    /// Update rule of the inner loop: adam (default) or sgd (the paper's plain gradient step).
    #[arg(long, value_enum)]
    pub optimizer: Option<imu_fsda::adapt::Optimizer>,
    /// Ground truth in another frame than the IMU: error (the default, or the config's
    /// `frame_policy`), apply (re-express it), ignore.
    #[arg(long, value_enum)]
    pub frame: Option<FramePolicy>,
    /// Adapt the Embedding only (the paper's strategy), not the calibration head (Ĉ_ω and the
    /// Generator's output bias, adapted by default: docs/adaptation.md).
    #[arg(long)]
    pub embedding_only: bool,
    /// The IMU's name, for a model with a Ĉ_ω or correction gain per IMU (its `.json` lists
    /// them): adapt from that Ĉ_ω, and judge against the starting model run with that IMU's
    /// gain (default: a new IMU, I for a per-IMU model, gain 1). The adapted model keeps its
    /// adapted Ĉ_ω and applies its whole correction whatever IMU it is later run with.
    #[arg(long)]
    pub imu: Option<String>,
    /// Other recordings of this IMU (bags with ground truth: another power-on) to judge the
    /// adapted model on, beside raw, the gyro minus its power-on bias and the starting model;
    /// repeatable. With any, the model is written only if its AOE over them is below what the
    /// node runs without it (the power-on bias on a new IMU), as a geometric mean of the ratios.
    #[arg(long = "judge", value_name = "BAG")]
    pub judges: Vec<PathBuf>,
    /// Adapt on the gyro as recorded, its power-on bias inside: the model is then for this
    /// power-on only (it carries its turn-on constant; docs/poweron.md).
    #[arg(long)]
    pub keep_power_on_bias: bool,
    /// Which candidate may be kept: `auto` (with --judge the one that carries over better to
    /// the other power-ons; without it the gyro calibration where its query gain holds piece
    /// by piece, never the networks), `networks` (the inner loop only, kept on the query's
    /// evidence), `gyro-calibration` (Ĉ_ω alone, the networks off).
    #[arg(long, value_enum)]
    pub keep: Option<imu_fsda::adapt::Keep>,
    /// Adaptation settings as YAML (AdaptConfig); flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the report as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

fn output_name(out: &Path) -> anyhow::Result<(PathBuf, String)> {
    // `-o robots/` or an existing folder: the model's own name is wanted, not a file beside it.
    if out.is_dir() || out.as_os_str().to_string_lossy().ends_with('/') {
        anyhow::bail!("-o {}: a folder; name the model file, e.g. {}", out.display(), out.join("my-robot.pt").display());
    }
    if let Some(ext) = out.extension().map(|e| e.to_string_lossy()).filter(|e| e != "pt") {
        anyhow::bail!("-o {}: the adapted model is a TorchScript file, <name>.pt (not .{ext})", out.display());
    }
    let dir = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf();
    let name = out.file_stem().map(|s| s.to_string_lossy().into_owned()).filter(|s| !s.is_empty());
    let name = name.with_context(|| format!("-o {}: no file name", out.display()))?;
    Ok((dir, name))
}

/// What may be replaced at `-o`: nothing, or an earlier adapted model and its report. A trained
/// model, another model's metadata under the report's name (`-o x.pt` beside a model `x.adapt`),
/// or a folder in the way is refused before any work.
fn check_output(dir: &Path, name: &str) -> anyhow::Result<()> {
    for ext in ["pt", "ot", "json", "adapt.json"] {
        let p = dir.join(format!("{name}.{ext}"));
        if p.is_dir() {
            anyhow::bail!("{} is a folder: the adapted model cannot be written there; choose another -o", p.display());
        }
    }
    // An existing <name>.json that is not a model's metadata is some other record (a training
    // summary `<model>.train.json` beside `-o <model>.train.pt`): not this command's to replace.
    let out_json = dir.join(format!("{name}.json"));
    if out_json.exists() {
        match load_metadata(&out_json) {
            Err(_) => anyhow::bail!(
                "{} exists and is not a model's metadata: writing the adapted model there would replace it; choose another -o",
                out_json.display()
            ),
            Ok(m) if m.adapted_from.is_none() => anyhow::bail!(
                "{} is a trained model ({}), not an earlier adaptation: adapt does not replace it; choose another -o",
                out_json.display(),
                m.name
            ),
            Ok(_) => {}
        }
    }
    // A model's `.pt` or `.ot` without its `.json` (a deployed TorchScript file) is not known
    // to be an earlier adaptation either.
    if !out_json.exists() {
        if let Some(p) = ["pt", "ot"].iter().map(|ext| dir.join(format!("{name}.{ext}"))).find(|p| p.exists()) {
            anyhow::bail!(
                "{} exists and no {} says it is an earlier adaptation: adapt does not replace it; choose another -o",
                p.display(),
                out_json.display()
            );
        }
    }
    let report = dir.join(format!("{name}.adapt.json"));
    if report.exists() && load_metadata(&report).is_ok() {
        anyhow::bail!(
            "{} is the metadata of a model named {name}.adapt: the adaptation report of -o {name}.pt would replace it; choose another -o",
            report.display()
        );
    }
    imu_fsda::core::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(())
}

pub fn run(args: AdaptArgs) -> anyhow::Result<()> {
    tch::set_num_threads(1);
    let cfg = config_of(&args)?;
    // Before the model and the bag are read.
    cfg.validate().map_err(|e| anyhow::anyhow!("{e}{}", args.config.as_ref().map_or(String::new(), |p| format!(" ({})", p.display()))))?;
    let (dir, name) = output_name(&args.output)?;
    let meta = metadata_path(&args.model);
    let weights = args.model.with_extension("ot");
    let mut inputs = vec![args.model.as_path(), &meta, &weights, &args.bag];
    inputs.extend(args.judges.iter().map(PathBuf::as_path));
    for ext in ["pt", "ot", "json", "adapt.json"] {
        super::refuse_overwriting_input(&dir.join(format!("{name}.{ext}")), &inputs)?;
    }
    check_output(&dir, &name)?;
    // The node's start-up check (TorchScript against the weights, as run on this IMU): an
    // edited `.json` would otherwise adapt from another IMU's Ĉ_ω.
    super::corrector::check_model_files(&args.model, args.imu.as_deref())?;
    let loaded = load_net(&meta, tch::Device::Cpu).with_context(|| format!("loading model {}", args.model.display()))?;
    loaded.select_imu(args.imu.as_deref())?;
    super::refuse_imu_as_ground_truth(&args.imu_topic, &args.ground_truth_topic)?;
    let topics = RecordingTopics { imu: args.imu_topic.clone(), ground_truth: Some(args.ground_truth_topic.clone()), temperature: None };
    let (support, query) = support_and_query(&args, &topics, &cfg)?;
    // Ctrl-C: the adaptation runs to its end (seconds), then nothing is written.
    super::interrupts::catch();
    let mut outcome = adapt(&loaded, &support, &query, &cfg)?;
    if super::interrupts::requested() {
        return Err(super::interrupts::Interrupted("nothing written".into()).into());
    }
    if args.judges.is_empty() {
        outcome = keep_without_judge(outcome, &cfg);
    } else {
        judge_on_other_recordings(&args, &topics, &loaded, &mut outcome, &cfg)?;
    }
    let r = &outcome.report;
    if args.json {
        out!("{}", serde_json::to_string_pretty(r)?)?;
    }
    print_report(r, &cfg);
    let Some(adapted) = outcome.adapted else {
        anyhow::bail!("{} (nothing written)", r.verdict);
    };
    let paths = save_adapted(&adapted, r, &dir, &name)?;
    eprintln!("accepted: wrote {} (+ .ot, .json, .adapt.json)", paths.torchscript.display());
    Ok(())
}

/// The adaptation's settings: `--config`'s (or the defaults), the flags over them.
fn config_of(args: &AdaptArgs) -> anyhow::Result<AdaptConfig> {
    let mut cfg: AdaptConfig = match &args.config {
        Some(p) => serde_yaml::from_str(&std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?)
            .with_context(|| format!("{}: not an adaptation config", p.display()))?,
        None => AdaptConfig::default(),
    };
    if let Some(s) = args.steps {
        cfg.steps = s;
    }
    if let Some(lr) = args.lr {
        cfg.inner_lr = lr;
    }
    if let Some(o) = args.optimizer {
        cfg.optimizer = o;
    }
    if let Some(f) = args.frame {
        cfg.frame_policy = f;
    }
    if args.embedding_only {
        cfg.calibration = false;
    }
    if args.keep_power_on_bias {
        cfg.power_on_bias = false;
    }
    if let Some(k) = args.keep {
        cfg.keep = k;
    }
    Ok(cfg)
}

/// The bag read and checked (stamps, finite samples, ground truth present), split into the
/// support set and the query set the adaptation is judged on.
fn support_and_query(args: &AdaptArgs, topics: &RecordingTopics, cfg: &AdaptConfig) -> anyhow::Result<(Recording, Recording)> {
    let (rec, report) = read_recording(&args.bag, topics).with_context(|| format!("reading {}", args.bag.display()))?;
    if let Some(problem) = report.stamp_problem_above(0.1).or_else(|| imu_fsda::core::burst_stamps(&rec.imu)) {
        anyhow::bail!("{}: {problem}", args.bag.display());
    }
    if let Some(clipped) = imu_fsda::core::clipped_samples(&rec.imu) {
        tracing::warn!("{}: {clipped}; the adapted correction learns from them too", args.bag.display());
    }
    anyhow::ensure!(
        report.imu_non_finite == 0 && report.ground_truth_invalid == 0,
        "{}: {} non-finite IMU samples, {} invalid poses: fix the bag first",
        args.bag.display(),
        report.imu_non_finite,
        report.ground_truth_invalid
    );
    anyhow::ensure!(
        !rec.ground_truth.is_empty(),
        "{}: no ground truth on {} (give --ground-truth-topic: PoseStamped, Odometry or a reference Imu)",
        args.bag.display(),
        args.ground_truth_topic
    );
    let (support, query) = split_recording(&rec, args.support_seconds, args.query_seconds, cfg);
    anyhow::ensure!(
        !query.imu.is_empty(),
        "{}: nothing left after the {} s support set to judge the adaptation on (the bag has {:.1} s of IMU, {})",
        args.bag.display(),
        args.support_seconds,
        rec.imu_seconds(),
        match (rec.ground_truth.first(), rec.ground_truth.last()) {
            (Some(a), Some(b)) => format!("{:.1} s of ground truth", (b.stamp_ns - a.stamp_ns) as f64 * 1e-9),
            _ => "no ground truth".into(),
        }
    );
    Ok((support, query))
}

/// What the adaptation found, on stderr: the frame check, the power-on biases, the judged
/// recordings, the query's figures and each candidate's.
fn print_report(r: &AdaptReport, cfg: &AdaptConfig) {
    if r.frame.is_none() && cfg.frame_policy != FramePolicy::Ignore {
        eprintln!(
            "frame check: not possible (fewer than 3 of the support's 0.25- to 4-s increments turn by 0.05 rad): the motion is too gentle to tell another frame or inverted quaternions"
        );
    }
    if let Some(f) = &r.frame {
        eprintln!(
            "frame check: {:.2}° between the IMU and ground-truth frames ({} increments){}",
            f.angle_deg,
            f.increments,
            if r.frame_applied { ", ground truth re-expressed in the IMU frame" } else { "" }
        );
    }
    if let Some(b) = &r.support_power_on_bias {
        eprintln!(
            "support power-on bias [{:.5}, {:.5}, {:.5}] rad/s (σ {:.1e}, {:.1} s of standstill): removed before adapting; the node removes each power-on's before this model",
            b.bias.x,
            b.bias.y,
            b.bias.z,
            b.variance.max().sqrt(),
            b.still_s
        );
    }
    if let Some(p) = &r.query_power_on_bias {
        eprintln!("query: AOE of the gyro minus its power-on bias (what the node runs on a new IMU) {:.3}°", p.aoe_deg);
    }
    for j in &r.judged {
        eprintln!(
            "judged on {}: AOE raw {:.3}°, power-on bias {}, starting model {:.3}°, adapted {:.3}°",
            j.recording,
            j.raw.aoe_deg,
            j.power_on_bias.as_ref().map_or("– (no standstill)".to_string(), |e| format!("{:.3}°", e.aoe_deg)),
            j.before.aoe_deg,
            j.after.aoe_deg
        );
    }
    eprintln!(
        "adapted on {:.1} s ({} steps, α {}, {:.1} s; total {:.1} s); query {:.1} s: AOE raw {:.3}°, before {:.3}°, after {:.3}°",
        r.support_seconds,
        r.steps,
        r.inner_lr,
        r.step_seconds,
        r.total_seconds,
        r.query_seconds,
        r.query_raw.aoe_deg,
        r.query_before.aoe_deg,
        r.query_after.aoe_deg
    );
    if let (Some(c), Some(q)) = (&r.calibration, &r.query_calibrated) {
        let d = |k: usize| (c.matrix[k][k] - 1.0) * 100.0;
        eprintln!(
            "gyro calibration alone (Ĉ_ω on {} increments, diagonal {:+.2} / {:+.2} / {:+.2} %, the networks off{}): query AOE {:.3}°{}",
            c.increments,
            d(0),
            d(1),
            d(2),
            r.rotation_left_out_said().map_or(String::new(), |said| format!(", {said}")),
            q.aoe_deg,
            r.query_calibrated_pieces.map_or(String::new(), |p| format!(
                "; piece by piece against the power-on bias {:.3} over {} pieces of {:.0} s (95 % upper bound {:.3})",
                p.ratio, p.pieces, p.piece_seconds, p.upper_95
            ))
        );
    }
    if let Some(why) = &r.calibration_refused {
        eprintln!("gyro calibration alone: not a candidate: {why}");
    }
    if let (Some(c), Some(q)) = (&r.calibration, &r.query_calibrated_with_offset) {
        let (b, sd) = (c.leftover_bias_rad_s, c.leftover_bias_stddev_rad_s);
        eprintln!(
            "gyro calibration with the support's bias offset in motion [{:.5}, {:.5}, {:.5}] rad/s (σ {:.1e}): query AOE {:.3}°; kept only where other power-ons show it lasts (--judge)",
            b[0],
            b[1],
            b[2],
            sd.iter().copied().fold(0.0, f64::max),
            q.aoe_deg
        );
    }
    if let Some(k) = r.kind {
        eprintln!("kept: {}", k.name());
    }
    if r.accepted && r.query_after.aoe_deg > r.query_raw.aoe_deg {
        tracing::warn!(
            "the adapted model is better than the starting one but still worse than the raw gyro on the query data ({:.3}° against {:.3}°): on this IMU, running without a model is better",
            r.query_after.aoe_deg,
            r.query_raw.aoe_deg
        );
    }
}

/// `--judge`: scores each candidate that passed the query on each other recording, keeps the
/// one that carries over best, and rejects all (nothing written) when none's AOE there is
/// below what the node runs without it ([`imu_fsda::adapt::keep_judged`]).
fn judge_on_other_recordings(
    args: &AdaptArgs,
    topics: &RecordingTopics,
    start: &imu_fsda::model::export::LoadedNet,
    outcome: &mut imu_fsda::adapt::AdaptOutcome,
    cfg: &AdaptConfig,
) -> anyhow::Result<()> {
    if outcome.adapted.is_none() || args.judges.is_empty() {
        return Ok(());
    }
    let mut recordings = Vec::new();
    for bag in &args.judges {
        let (rec, _) = read_recording(bag, topics).with_context(|| format!("reading --judge {}", bag.display()))?;
        recordings.push(rec);
    }
    let tried = outcome.report.kind;
    let bar = super::progress::bar(recordings.len(), "judging on the other power-ons");
    imu_fsda::adapt::keep_judged(start, outcome, &recordings, cfg, |rec| {
        bar.set_message(rec.name.clone());
        bar.inc(1);
    })
    .context("judging on the other recordings")?;
    bar.finish_and_clear();
    let r = &outcome.report;
    let say = |what: &str, c: &CarryOver| {
        eprintln!(
            "on the other recordings: AOE with {what} / without adapting {:.3} (geometric mean {}; 95 % upper bound {:.3} over the recordings, {} over the pieces)",
            c.ratio,
            c.over(),
            c.upper_95,
            c.piece_bound_said()
        )
    };
    if let Some(c) = &r.carry_over {
        say(r.kind.or(tried).map_or("the adapted model", |k| k.name()), c);
    }
    for other in &r.judged_others {
        say(other.kind.name(), &other.carry_over);
    }
    Ok(())
}
