//! `imu-fsda simulate`: simulate an IMU on a trajectory and write a ROS 2 bag with ground truth.
//!
//! The simulation is a [`SimConfig`]: from `--config FILE.yaml` if given, else the defaults;
//! the flags override its fields and `--term` appends error terms.

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::physics::Term;
use imu_fsda::sim::{simulate, write_bag_with_progress, Grade, Profile, SimConfig};

/// Bags with more messages than this get a progress bar.
const PROGRESS_ABOVE_MESSAGES: usize = 1_000_000;

#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Motion profile (default: the config's, else aerial).
    #[arg(long, value_enum)]
    pub profile: Option<Profile>,
    /// IMU grade: its noise densities drive the simulator's noise model (default: the config's, else mpu-9250).
    #[arg(long, value_enum)]
    pub grade: Option<Grade>,
    /// IMU rate, Hz (default: the config's, else 200).
    #[arg(long)]
    pub rate: Option<f64>,
    /// Duration, s (default: the config's, else 30).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Master seed: the same seed gives the same bag, byte for byte (default: the config's, else 0).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Which power-on of this IMU: the same lasting terms, a new turn-on bias, noise and
    /// motion for each N > 0 (default: the config's, else 0).
    #[arg(long)]
    pub power_on: Option<u64>,
    /// Seconds at rest before the motion starts (default: the config's, else 0).
    #[arg(long)]
    pub rest_s: Option<f64>,
    /// Simulation config (YAML, see params/sim/); flags override its fields.
    #[arg(long, value_name = "FILE.yaml")]
    pub config: Option<PathBuf>,
    /// Extra error term as inline YAML, e.g. '{term: gyro_bias, bias: [0.001, 0, 0]}'. Repeatable; appended to the config's terms.
    #[arg(long = "term", value_name = "YAML")]
    pub terms: Vec<String>,
    /// Also apply the grade's datasheet errors: a turn-on bias drawn in its range, quantisation at its LSB, saturation at its range.
    #[arg(long)]
    pub datasheet_errors: bool,
    /// Also write the effective config and every applied term (the simulation's truth) to this YAML file.
    #[arg(long, value_name = "FILE.yaml")]
    pub truth: Option<PathBuf>,
    /// Output bag (MCAP).
    #[arg(short, long, value_name = "OUT.mcap")]
    pub output: PathBuf,
}

/// The config the arguments describe.
fn config(args: &SimulateArgs) -> anyhow::Result<SimConfig> {
    let mut cfg = match &args.config {
        Some(path) => SimConfig::load(path)?,
        None => SimConfig::default(),
    };
    if let Some(p) = args.profile {
        cfg.profile = p;
    }
    if let Some(g) = args.grade {
        cfg.grade = g;
    }
    if let Some(r) = args.rate {
        cfg.rate_hz = r;
    }
    if let Some(s) = args.seconds {
        cfg.seconds = s;
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    if let Some(k) = args.power_on {
        cfg.power_on = k;
    }
    if let Some(r) = args.rest_s {
        cfg.rest_s = r;
    }
    cfg.datasheet_errors |= args.datasheet_errors;
    for (i, text) in args.terms.iter().enumerate() {
        let term: Term = serde_yaml::from_str(text).with_context(|| format!("--term #{} `{text}`", i + 1))?;
        cfg.terms.push(term);
    }
    Ok(cfg)
}

pub fn run(args: SimulateArgs) -> anyhow::Result<()> {
    let mut outputs = vec![("--output", args.output.as_path())];
    if let Some(t) = &args.truth {
        outputs.push(("--truth", t.as_path()));
    }
    super::refuse_shared_outputs(&outputs)?;
    for (_, out) in &outputs {
        super::refuse_overwriting_input(out, &args.config.iter().map(PathBuf::as_path).collect::<Vec<_>>())?;
    }
    let cfg = config(&args)?;
    let out = simulate(&cfg).context("simulation")?;
    let rec = &out.recording;
    let total = rec.imu.len() + rec.ground_truth.len() + rec.temperature.len();
    let bar = (total > PROGRESS_ABOVE_MESSAGES).then(|| {
        let bar = indicatif::ProgressBar::new(total as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("writing {bar:40} {pos}/{len} messages ({eta})")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    });
    write_bag_with_progress(&args.output, &out, |done, _| {
        if let Some(b) = &bar {
            b.set_position(done as u64);
        }
    })
    .with_context(|| format!("writing {}", args.output.display()))?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    if let Some(path) = &args.truth {
        let yaml = serde_yaml::to_string(&out.truth()).context("serialising the truth")?;
        std::fs::write(path, yaml).with_context(|| format!("writing {}", path.display()))?;
    }
    let terms: Vec<&str> = out.applied.iter().map(|t| t.name()).collect();
    out!(
        "wrote {}: {} / {}, {} Hz, {} s, seed {}: {} IMU, {} pose, {} temperature messages; terms: {}",
        args.output.display(),
        cfg.profile,
        cfg.grade,
        cfg.rate_hz,
        cfg.seconds,
        cfg.seed,
        rec.imu.len(),
        rec.ground_truth.len(),
        rec.temperature.len(),
        terms.join(", ")
    )?;
    Ok(())
}
