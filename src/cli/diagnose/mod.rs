//! `imu-fsda diagnose`: sim-vs-real diagnosis (see `imu_fsda::diagnose`).

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::bag::{read_recording, RecordingTopics};
use imu_fsda::diagnose::{align, diagnose, report, DiagnoseOptions, Sensors};

/// Default half-width (s) of the ground-truth smoother with --noise-model: ±10 poses at
/// EuRoC's 200 Hz, passing motion up to ≈ 15 Hz (see `kinematics::ideal_from_poses_with`).
const NOISE_MODEL_GT_SMOOTHING_S: f64 = 0.05;

#[derive(Debug, clap::Args)]
pub struct DiagnoseArgs {
    /// The simulated bag (ROS 2 MCAP: /imu/data with the sim's white-noise variance on the
    /// covariance diagonals, /ground_truth/pose, optional /imu/temperature).
    #[arg(long, required_unless_present_any = ["noise_model", "score_generated", "score_injected"])]
    pub sim: Option<PathBuf>,
    /// The real bag of the same motion. Repeated (with --noise-model): recordings of one IMU,
    /// each diagnosed into OUT/<its file name>, then pooled (OUT/pooled.json, pooled.md): the
    /// scale and cross-axis error they share, the bias each power-on brings.
    #[arg(long, required_unless_present_any = ["score_generated", "score_injected"])]
    pub real: Vec<PathBuf>,
    /// Instead of --sim: simulate the real bag's ground truth with this noise model (YAML:
    /// gyro_noise_density, accel_noise_density, gyro_bias_random_walk, accel_bias_random_walk).
    #[arg(long, conflicts_with = "sim")]
    pub noise_model: Option<PathBuf>,
    /// IMU topic of both bags (sensor_msgs/Imu).
    #[arg(long, default_value = imu_fsda::bag::IMU_TOPIC)]
    pub imu_topic: String,
    /// Ground-truth topic of both bags (PoseStamped, Odometry, or an Imu carrying orientation).
    #[arg(long, default_value = imu_fsda::bag::GROUND_TRUTH_TOPIC)]
    pub ground_truth_topic: String,
    /// Temperature topic of both bags (sensor_msgs/Temperature), if any.
    #[arg(long, default_value = imu_fsda::bag::TEMPERATURE_TOPIC)]
    pub temperature_topic: String,
    /// The simulated bag's IMU topic, where it differs from the real one's (default:
    /// --imu-topic).
    #[arg(long, conflicts_with_all = ["noise_model", "score_generated"])]
    pub sim_imu_topic: Option<String>,
    /// The simulated bag's ground-truth topic (default: --ground-truth-topic).
    #[arg(long, conflicts_with_all = ["noise_model", "score_generated"])]
    pub sim_ground_truth_topic: Option<String>,
    /// The simulated bag's temperature topic (default: --temperature-topic).
    #[arg(long, conflicts_with_all = ["noise_model", "score_generated"])]
    pub sim_temperature_topic: Option<String>,
    /// Output directory: report.json, report.md, patch.yaml, CSVs, PNG figures (psd, allan,
    /// residual), corrected_sim.mcap.
    #[arg(short, long)]
    pub out: PathBuf,
    /// The sensors judged. `gyro`: the accelerometer's residual and every accelerometer term
    /// are left out (listed under not_judged), e.g. when the simulated accelerometer comes
    /// from a measured ground truth differentiated twice.
    #[arg(long, value_enum, default_value_t = Sensors::Both)]
    pub sensors: Sensors,
    /// Half-width (s) of the local cubic fitted to the ground-truth poses before they are
    /// differentiated (a measured ground truth's noise would otherwise be amplified by 1/dt
    /// and 1/dt²). Default: 0.05 with --noise-model (or 3 of the reference's intervals if
    /// longer: 0.15 s at 20 Hz), none with --sim (a simulator's ground truth is noise-free);
    /// 0 turns it off.
    #[arg(long, value_parser = super::non_negative)]
    pub gt_smoothing: Option<f64>,
    /// Compare the recordings as means over windows of this many seconds (the bandwidth where
    /// a measured reference is good: its jitter, differentiated, would otherwise dominate the
    /// residual and pull every scale towards −1). Default with --noise-model: 0.2 s, or 4 of
    /// the reference's intervals if longer; with --sim (a simulator's exact ground truth):
    /// sample by sample. 0: sample by sample. low_pass, vibration, gyro_noise_density,
    /// quantization and saturation are not judged on window means (a low-pass's delay is
    /// time_offset, with the filter named beside it).
    #[arg(long, value_parser = super::non_negative)]
    pub compare_window: Option<f64>,
    /// Estimate the real sensor's white-noise level from the residual (third differences)
    /// instead of taking the simulator's: for a real sensor whose in-use noise is not the
    /// stated one (vibration). gyro_noise_density is then not judged. Implied when the
    /// recordings are compared over windows (--compare-window): there the residual's white
    /// part is mostly the reference's own error, which no sensor model states.
    #[arg(long)]
    pub real_noise_from_data: bool,
    /// Seed of the simulation from ground truth.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Held-out log-likelihood gain a term needs (plus 0.5 per parameter).
    #[arg(long, default_value_t = 12.0, value_parser = super::non_negative)]
    pub threshold: f64,
    /// Score the diagnosis on this many generated cases (the project's simulator, random
    /// profiles, rates, grades, durations, terms near the detection limit); prints recall,
    /// spurious-term rate and parameter error, writes `score.json` and `cases.csv` to --out.
    #[arg(long, hide = true)]
    pub score_generated: Option<usize>,
    /// Score the diagnosis on real recordings with effects injected by the physics code
    /// (needs --noise-model, the IMU's stated noise): each bag is diagnosed as recorded (the
    /// control) and with --score-draws random injected cases; prints recall, spurious-term
    /// rate beyond the control and parameter error, writes `score.json` and `cases.csv`.
    #[arg(long, hide = true, num_args = 1.., requires = "noise_model", conflicts_with_all = ["sim", "real", "score_generated"])]
    pub score_injected: Vec<PathBuf>,
    /// With --score-injected: injected cases per recording.
    #[arg(long, hide = true, default_value_t = 6)]
    pub score_draws: usize,
    /// With --score-generated: draw the left-out terms only from these names.
    #[arg(long, hide = true, value_delimiter = ',')]
    pub score_only: Vec<String>,
    /// With --score-generated: fixed duration (s) and rate (Hz) instead of random ones.
    #[arg(long, hide = true, value_parser = super::positive)]
    pub score_seconds: Option<f64>,
    #[arg(long, hide = true, value_parser = super::positive)]
    pub score_rate: Option<f64>,
    /// With --score-generated: diagnose only these case indices (the others are still drawn,
    /// so every case is the same as in the full run; for development).
    #[arg(long, hide = true, value_delimiter = ',')]
    pub score_cases: Vec<usize>,
}

pub fn run(args: DiagnoseArgs) -> anyhow::Result<()> {
    let mut opts = DiagnoseOptions::default();
    opts.select.threshold = args.threshold;
    opts.sensors = args.sensors;
    anyhow::ensure!(
        !args.out.exists() || args.out.is_dir(),
        "--out {}: exists and is not a directory (the report is a directory of files)",
        args.out.display()
    );
    if let Some(n) = args.score_generated {
        return generated::run(n, args.seed, &args.out, &opts, &args.score_only, (args.score_seconds, args.score_rate), &args.score_cases);
    }
    if !args.score_injected.is_empty() {
        return score_injected(&args, &opts);
    }
    anyhow::ensure!(!args.real.is_empty(), "--real is required");
    if args.real.len() > 1 {
        return pooled::run(&args, &opts);
    }
    diagnose_reporting_failure(&args, &args.real[0], &args.out, &opts).map(|_| ())
}

/// [`diagnose_to`] into `out`, refusing to overwrite an input; on failure a report.json that
/// says what failed, where the report would be.
pub(super) fn diagnose_reporting_failure(
    args: &DiagnoseArgs,
    real_path: &std::path::Path,
    out: &std::path::Path,
    opts: &DiagnoseOptions,
) -> anyhow::Result<Diagnosed> {
    // A report directory rewritten over one of its inputs (the last run's corrected_sim.mcap
    // given back as --sim) would destroy it: refused before anything is written.
    let inputs: Vec<&std::path::Path> =
        [&args.sim, &args.noise_model].into_iter().flatten().map(|p| p.as_path()).chain(args.real.iter().map(|p| p.as_path())).collect();
    for name in report::FILES {
        super::refuse_overwriting_input(&out.join(name), &inputs)?;
    }
    diagnose_to(args, real_path, out, opts).inspect_err(|e| {
        std::fs::create_dir_all(out).ok();
        let j = serde_json::json!({"error": super::error_text(e), "findings": [], "located": [], "residual_before": null, "residual_after": null});
        if let Ok(text) = serde_json::to_string_pretty(&j) {
            std::fs::write(out.join("report.json"), text).ok();
        }
    })
}

/// What one recording's diagnosis gives the pooling: its plain calibration (against a measured
/// reference) and the terms it found.
pub(super) struct Diagnosed {
    pub plain: Option<imu_fsda::diagnose::plain_calibration::PlainCalibration>,
    pub terms: Vec<String>,
}

/// The ground-truth smoother's half-width: the option's, else the default for a measured
/// reference (--noise-model), else none.
fn gt_smoothing(args: &DiagnoseArgs) -> Option<f64> {
    match (args.gt_smoothing, &args.noise_model) {
        (Some(h), _) => Some(h).filter(|h| *h > 0.0),
        (None, Some(_)) => Some(NOISE_MODEL_GT_SMOOTHING_S),
        (None, None) => None,
    }
}

/// Poses the local cubic needs on each side of the pose it smooths: with fewer in its
/// window it falls back to differences (`kinematics::by_local_cubic`, 6 in all), which round a
/// coarse reference's motion (a 20 Hz one read as gyro scales of +0.2 to +1.6 %).
const SMOOTHER_POSES_PER_SIDE: f64 = 3.0;

/// The default smoother widened to hold [`SMOOTHER_POSES_PER_SIDE`] of this reference's
/// intervals (0.15 s for a 20 Hz one; 120–200 Hz references keep 0.05 s). An explicit
/// `--gt-smoothing` is kept.
fn smoothing_for(args: &DiagnoseArgs, gt: &[imu_fsda::core::PoseSample]) -> Option<f64> {
    let h = gt_smoothing(args)?;
    Some(if args.gt_smoothing.is_some() {
        h
    } else {
        h.max(SMOOTHER_POSES_PER_SIDE * imu_fsda::diagnose::kinematics::median_interval_s(gt))
    })
}

fn read_noise_model(path: &std::path::Path) -> anyhow::Result<imu_fsda::physics::NoiseModel> {
    let text = std::fs::read_to_string(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::InvalidData => anyhow::anyhow!(
            "{}: not a text file; --noise-model takes YAML (gyro_noise_density, accel_noise_density, gyro_bias_random_walk, accel_bias_random_walk), a simulated bag goes to --sim",
            path.display()
        ),
        _ => anyhow::Error::new(e).context(format!("reading {}", path.display())),
    })?;
    serde_yaml::from_str(&text).with_context(|| format!("{}: not a noise model", path.display()))
}

fn score_injected(args: &DiagnoseArgs, opts: &DiagnoseOptions) -> anyhow::Result<()> {
    let mut opts = *opts;
    opts.gt_smoothing_s = gt_smoothing(args);
    let set = injected::InjectedSet {
        bags: &args.score_injected,
        topics: RecordingTopics {
            imu: args.imu_topic.clone(),
            ground_truth: Some(args.ground_truth_topic.clone()),
            temperature: Some(args.temperature_topic.clone()),
        },
        noise: read_noise_model(args.noise_model.as_deref().context("--score-injected needs --noise-model")?)?,
        smoothing: opts.gt_smoothing_s,
        compare_window: args.compare_window,
        real_noise_from_data: args.real_noise_from_data,
        draws: args.score_draws,
        seed: args.seed,
        only: args.score_only.clone(),
    };
    injected::run(&set, &args.out, &opts)
}

/// The window a measured reference is compared over: the option's, else
/// [`bandwidth::window_for`] its pose interval with --noise-model, else sample by sample.
pub(super) fn compare_window(option: Option<f64>, measured_reference: bool, gt: &[imu_fsda::core::PoseSample]) -> f64 {
    match (option, measured_reference) {
        (Some(w), _) => w,
        (None, true) => imu_fsda::diagnose::bandwidth::window_for(imu_fsda::diagnose::kinematics::median_interval_s(gt)),
        (None, false) => 0.0,
    }
}

fn diagnose_to(
    args: &DiagnoseArgs,
    real_path: &std::path::Path,
    out: &std::path::Path,
    opts: &DiagnoseOptions,
) -> anyhow::Result<Diagnosed> {
    let mut opts = *opts;
    let mut smoothing = gt_smoothing(args);
    let topics = RecordingTopics {
        imu: args.imu_topic.clone(),
        ground_truth: Some(args.ground_truth_topic.clone()),
        temperature: Some(args.temperature_topic.clone()),
    };
    let sim_topics = RecordingTopics {
        imu: args.sim_imu_topic.clone().unwrap_or_else(|| topics.imu.clone()),
        ground_truth: args.sim_ground_truth_topic.clone().or_else(|| topics.ground_truth.clone()),
        temperature: args.sim_temperature_topic.clone().or_else(|| topics.temperature.clone()),
    };
    // The plain per-axis calibration beside the diagnosis, where the reference is measured.
    let mut plain = None;
    let mut aligned = match (&args.sim, &args.noise_model) {
        (Some(sim), _) => align::load_each_on(sim, &sim_topics, real_path, &topics)?,
        (None, Some(model)) => {
            let noise = read_noise_model(model)?;
            let (mut real, _) = read_recording(real_path, &topics)?;
            smoothing = smoothing_for(args, &real.ground_truth);
            let clock = align_reference_clock(&mut real, smoothing)?;
            // Outside the ground truth's span there is nothing to simulate (and its first
            // samples fix the bias walk's start, W₀ = 0, which the bias estimate rests on).
            let (cut0, cut1) = imu_fsda::diagnose::kinematics::crop_to_ground_truth(&mut real, smoothing.unwrap_or(0.0));
            let (sim, var) = imu_fsda::diagnose::kinematics::simulate_from_ground_truth(&real, &noise, args.seed, smoothing)?;
            let window = compare_window(args.compare_window, true, &real.ground_truth);
            plain = match imu_fsda::diagnose::plain_calibration::of_recording(&real, smoothing, window) {
                Ok(p) => Some(p),
                Err(e) => {
                    tracing::warn!("the plain per-axis calibration beside the diagnosis: {e}");
                    None
                }
            };
            let how = match smoothing {
                Some(h) => format!("poses smoothed by a local cubic over ±{h} s, then differentiated"),
                None => "poses differentiated sample to sample".into(),
            };
            let notes = vec![
                format!("sim side simulated from the real bag's ground truth ({how}) with {noise:?} (seed {})", args.seed),
                format!("real IMU samples outside the ground truth's span (less the smoother's half-width) left out: {cut0} at the start, {cut1} at the end"),
            ];
            let mut a = align::align(sim, real, Some(var), notes)?;
            a.artefacts.extend(clock);
            leave_out_reference_dropouts(&mut a, smoothing);
            a
        }
        (None, None) => anyhow::bail!("give --sim SIM.mcap or --noise-model FILE.yaml"),
    };
    opts.gt_smoothing_s = smoothing;
    let opts = &opts;
    let window = compare_window(args.compare_window, args.noise_model.is_some(), &aligned.sim_recording.ground_truth);
    aligned = over_windows(aligned, window);
    if args.real_noise_from_data || aligned.samples_per_point > 1 {
        aligned.estimate_real_white_noise();
    }
    let d = diagnose(&aligned, opts)?;
    report::write_all(out, &aligned, &d)?;
    if let Some(p) = &plain {
        std::fs::write(out.join("plain_calibration.json"), serde_json::to_string_pretty(&p.json())?)?;
        let md = out.join("report.md");
        let text = std::fs::read_to_string(&md)? + &p.markdown(&d);
        std::fs::write(&md, text)?;
    }
    // The verdict first: when the catalogue does not explain the recording, the terms below
    // are its best fit, and must not read as a diagnosis.
    for a in &d.artefacts {
        out!("recording artefact: {a}")?;
    }
    out!("{}", d.verdict.statement)?;
    let label = if d.verdict.explained { "" } else { "best catalogue fit, not a diagnosis: " };
    for f in &d.findings {
        out!("{label}{}: {}", f.term, f.params)?;
    }
    for f in &d.implausible {
        out!("implausible, not a finding: {}: {} ({})", f.term, f.params, f.implausible.as_deref().unwrap_or_default())?;
    }
    if let Some(p) = &plain {
        let names: Vec<&str> = p.terms().iter().map(|t| t.name()).collect();
        let scale: Vec<String> = (0..3).map(|k| format!("{:+.2}", 100.0 * (p.matrix[(k, k)] - 1.0))).collect();
        let bias: Vec<String> = (0..3).map(|k| format!("{:+.1}", 1e3 * p.bias[k])).collect();
        out!(
            "beside it, the plain per-axis calibration (plain_calibration.json): [{}]; scale {} %, bias {} mrad/s",
            names.join(", "),
            scale.join(" / "),
            bias.join(" / ")
        )?;
    }
    out!("report: {} ({:.2} s)", out.join("report.md").display(), d.seconds)?;
    let fit = if d.verdict.explained { "" } else { " (best catalogue fit, not a diagnosis)" };
    let terms = d.findings.iter().map(|f| format!("{}{fit}", f.term)).collect();
    Ok(Diagnosed { plain, terms })
}

/// The recordings as window means of `window` s (none: as they are).
pub(super) fn over_windows(a: align::Aligned, window: f64) -> align::Aligned {
    if window <= 0.0 {
        return a;
    }
    a.block_means(window)
}

/// The largest clock offset between a reference and the IMU searched for, s.
const MAX_REFERENCE_LAG_S: f64 = 2.0;

/// A ground truth stamped on another clock than the IMU's (a motion-capture system's own):
/// its lag in whole IMU samples is found from the gyro's norm and taken out of its stamps; a
/// lag that drifts along the recording is taken out about its middle
/// ([`imu_fsda::diagnose::reference_clock`]); each said as an artefact of the recording. What is
/// left, constant and below a sample, is `time_offset`'s.
pub(super) fn align_reference_clock(real: &mut imu_fsda::core::Recording, smoothing: Option<f64>) -> anyhow::Result<Vec<String>> {
    let mut said = Vec::new();
    let lag = imu_fsda::diagnose::kinematics::reference_lag_s(real, smoothing, MAX_REFERENCE_LAG_S)?;
    if lag != 0.0 {
        let shift = (lag * 1e9).round() as i64;
        real.ground_truth.iter_mut().for_each(|p| p.stamp_ns -= shift);
        said.push(format!(
            "the ground truth's stamps lag the IMU's by {:.1} ms (whole IMU samples, from the gyro's norm against the rate differentiated from the poses; searched within ±{MAX_REFERENCE_LAG_S} s): taken out of its stamps before the comparison; a remainder below one sample is left to time_offset",
            lag * 1e3
        ));
    }
    if let Some(drift) = imu_fsda::diagnose::reference_clock::reference_clock_drift(real, smoothing)? {
        if drift.significant(1.0 / real.nominal_imu_rate_hz()) {
            drift.take_out(real);
            said.push(drift.sentence());
        } else {
            tracing::info!(
                "reference clock: {:+.1} ± {:.1} ppm over {} pieces, not taken out",
                drift.rate * 1e6,
                drift.rate_sigma * 1e6,
                drift.pieces.len()
            );
        }
    }
    Ok(said)
}

/// Where the ground truth lost tracking, the sim made from it is interpolated across the hole
/// (and differentiated there: spikes of rad/s), so those stamps, and those whose smoother
/// window or interpolant reaches into a hole, leave the fit; the dropouts are a recording
/// artefact of the reference, said in the report.
pub(super) fn leave_out_reference_dropouts(a: &mut align::Aligned, smoothing: Option<f64>) {
    use imu_fsda::diagnose::kinematics::{near_dropouts, reference_dropouts};
    let gt = &a.sim_recording.ground_truth;
    let dropouts = reference_dropouts(gt);
    if dropouts.is_empty() {
        return;
    }
    let span = |(a, b): &(i64, i64)| (b - a) as f64 * 1e-9;
    let longest = dropouts.iter().map(span).fold(0.0, f64::max);
    let total: f64 = dropouts.iter().map(span).sum();
    let margin = imu_fsda::diagnose::kinematics::dropout_margin_s(gt, smoothing);
    a.in_reference_gap = near_dropouts(&a.stamps_ns, &dropouts, margin);
    a.artefacts.push(format!(
        "the ground truth has {} dropouts (intervals over {} times its median; longest {longest:.3} s, {total:.1} s in all): the stamps within {margin:.3} s of one are left out of the fit",
        dropouts.len(),
        imu_fsda::diagnose::kinematics::DROPOUT_INTERVALS
    ));
}

mod generated;
mod injected;
mod pooled;
