//! Experiment (docs/training.md, "v9 retrained on the AVX2 VM, and averaged weights"): scores
//! a run's checkpoints averaged over an epoch range against its last weights, the way `train`
//! scores its export (the correction gains fitted on the validation recordings, the validation
//! score with them, the test recordings as deployed).
//!
//! `cargo run --release --example average_weights -- CONFIG RECAL_STEPS CKPT.json...`
//! (RECAL_STEPS 0: the averaged running statistics, not re-estimated).

use anyhow::Context;
use imu_fsda::train::{average, checkpoint, fit, TrainConfig};
use tch::{nn::VarStore, Device};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() >= 4, "usage: average_weights CONFIG RECAL_STEPS CKPT.json...");
    let cfg = TrainConfig::load(std::path::Path::new(&args[1])).context("config")?;
    let recal: usize = args[2].parse().context("RECAL_STEPS")?;
    let paths: Vec<std::path::PathBuf> = args[3..].iter().map(Into::into).collect();
    fit::flush_denormals_to_zero();
    tch::set_num_threads(1);
    let mut data = fit::load_datasets(&cfg)?;
    let vs = VarStore::new(Device::Cpu);
    let net = imu_fsda::model::Net::new(&cfg.model, &vs.root())?;
    fit::assign_calibration_rows(&net, &mut data, &cfg.train.calibrated_imus)?;
    let mean = average::mean_of_checkpoints(&paths)?;
    checkpoint::restore_vars(&vs, &mean, "vs")?;
    if recal > 0 {
        fit::recalibrate_batch_norm(&vs, &net, &cfg, &data.train, recal, 12345)?;
    }
    let eopts = fit::eval_opts(&cfg);
    let gains = fit::fit_correction_gains(&net, &data.validation, &eopts)?;
    let gain_of = |t: &imu_fsda::train::data::Task| gains.get(&t.imu_name).copied().unwrap_or(1.0);
    // The validation score as `train` computes it: each recording's AOE, weighted like the tasks.
    let mut by_domain: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    let (mut aoe, mut domains) = (Vec::new(), Vec::new());
    for t in &data.validation {
        let a = fit::evaluate_net_with_gain(&net, t, &eopts, gain_of(t))?.aoe_deg;
        by_domain.entry(fit::task_domain(t)).or_default().push(a);
        aoe.push(a);
        domains.push(fit::task_domain(t));
    }
    let score: f64 = fit::domain_weights(&domains, cfg.train.task_weighting).iter().zip(&aoe).map(|(w, a)| w * a).sum();
    let mean_of = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let per_domain: Vec<String> = by_domain.iter().map(|(d, v)| format!("{d} {:.2}", mean_of(v))).collect();
    let mut line = format!("n {} recal {recal} gains {gains:?} score {score:.3} val {} test", paths.len(), per_domain.join(" / "));
    let mut test_by_domain: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    for t in &data.test {
        let a = fit::evaluate_net_with_gain(&net, t, &eopts, gain_of(t))?.aoe_deg;
        line.push_str(&format!(" {}={a:.2}", t.name));
        test_by_domain.entry(fit::task_domain(t)).or_default().push(a);
    }
    for (d, v) in &test_by_domain {
        line.push_str(&format!(" {d}_mean {:.3}", mean_of(v)));
    }
    println!("{line}");
    Ok(())
}
