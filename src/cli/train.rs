//! `imu-fsda train --config params/train/X.yaml`: train, evaluate and export a model.

use std::io::IsTerminal;
use std::path::PathBuf;

use imu_fsda::train::{fit, TrainConfig};

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    /// Training config (YAML with model, dataset and train sections; see params/train/).
    #[arg(long)]
    pub config: PathBuf,
    /// Seed (overrides train.seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Continue from a checkpoint (`<out-dir>/<name>.ckpt.json`).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Where the model, checkpoint and run summary go.
    #[arg(long, default_value = "models")]
    pub out_dir: PathBuf,
    /// Model name: writes <out-dir>/<name>.{pt,ot,json}, <name>.train.json, <name>.ckpt.*
    /// (default: the config file's stem).
    #[arg(long)]
    pub name: Option<String>,
    /// Override train.epochs (e.g. to time a few epochs of a full config).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let cfg = TrainConfig::load(&args.config)?;
    let name =
        args.name.clone().unwrap_or_else(|| args.config.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or("model".into()));
    let opts = fit::RunOptions {
        seed: args.seed,
        resume: args.resume.clone(),
        out_dir: args.out_dir.clone(),
        name,
        epochs: args.epochs,
        progress: !args.no_progress && std::io::stderr().is_terminal(),
    };
    let s = fit::train(&cfg, &opts)?;
    println!(
        "trained {} ({:?}, seed {}): {} epochs in {:.1} s ({:.3} s/epoch, {} threads); loss {:.4} → {:.4}",
        s.name, s.mode, s.seed, s.epochs, s.train_seconds, s.seconds_per_epoch, s.threads, s.loss_first, s.loss_last
    );
    for v in &s.validation {
        let last = v.evals.last().map_or(f64::NAN, |e| e.1.aoe_deg);
        println!("validation {:<24} AOE raw {:8.3}°  model {:8.3}°", v.name, v.raw.aoe_deg, last);
    }
    for t in &s.test {
        println!(
            "test {:<30} AOE raw {:8.3}°  model {:8.3}°  (roll {:.3} pitch {:.3} yaw {:.3}, tilt {:.3} heading {:.3})",
            t.name,
            t.raw.aoe_deg,
            t.model.aoe_deg,
            t.model.roll_rmse_deg,
            t.model.pitch_rmse_deg,
            t.model.yaw_rmse_deg,
            t.model.tilt_rmse_deg,
            t.model.heading_rmse_deg
        );
    }
    println!("model: {}", s.model_json);
    println!("summary: {}", fit::summary_path(&args.out_dir, &s.name).display());
    Ok(())
}
