//! Restarts (`train.seeds`): one run per seed, the exported model is the run with the lowest
//! validation score. The seed alone moves the bundled recipe's EuRoC test mean by 2.4–4.5°
//! (docs/training.md), and a run's full-length AOE on its own training sequences, which the
//! windowed loss does not see, tracks it across seeds: listing the training sequences as
//! `dataset.validation` lets that choose, without the test split.
//!
//! The runs themselves are ordinary `imu-fsda train --seed S --name <name>-s<S>` runs in
//! `<out>/<name>.runs/` (the CLI starts them, several at once); this module scores the finished
//! runs and promotes the winner's files to `<out>/<name>.*`, recording every candidate in
//! `<name>.seeds.json` and the winner's metadata.

use std::path::{Path, PathBuf};

use super::error::{refuse, Context, TrainError};
use serde::{Deserialize, Serialize};

use super::config::TrainConfig;
use super::fit::{summary_path, validation_score};
use super::report::TrainSummary;
use crate::model::export::{load_metadata, write_metadata, ExportFiles};

/// The run of one seed: `<name>-s<seed>`.
pub fn run_name(name: &str, seed: u64) -> String {
    format!("{name}-s{seed}")
}

/// Where the runs go: `<out>/<name>.runs/`, beside the promoted model.
pub fn runs_dir(out_dir: &Path, name: &str) -> PathBuf {
    out_dir.join(format!("{name}.runs"))
}

/// Whether run `run` in `runs` is complete at `epochs` epochs (its summary says so and its
/// model is there), so a restarted `train.seeds` command reuses it instead of training again.
/// A complete run trained under another config is an error naming the keys: reused, it would
/// export a model the config does not describe; retrained, its results would be lost.
pub fn finished(runs: &Path, run: &str, epochs: usize, cfg: &TrainConfig) -> Result<bool, TrainError> {
    let Some(summary) =
        std::fs::read_to_string(summary_path(runs, run)).ok().and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
    else {
        return Ok(false);
    };
    if summary["epochs"].as_u64() != Some(epochs as u64) || !runs.join(format!("{run}.pt")).exists() {
        return Ok(false);
    }
    if let Some(trained) = summary.get("config").and_then(|c| serde_json::from_value::<TrainConfig>(c.clone()).ok()) {
        let changed = trained.run_differences(cfg);
        if !changed.is_empty() {
            refuse!(
                "{}: {run} was trained under a config that differs in {}: move {} away (or use another --name or --out-dir) to train anew",
                runs.display(),
                changed.join(", "),
                runs.display()
            );
        }
    }
    Ok(true)
}

/// One finished run, as scored.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SeedRun {
    pub seed: u64,
    pub name: String,
    pub exported_epoch: usize,
    /// Validation score at the exported epoch, degrees (lower wins).
    pub validation_score_deg: f64,
    /// Mean test AOE, degrees: reported beside the score, never used to choose.
    pub test_mean_aoe_deg: Option<f64>,
    pub train_seconds: f64,
}

/// `<name>.seeds.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SeedSelection {
    pub name: String,
    pub chosen_seed: u64,
    pub chosen_run: String,
    pub criterion: String,
    pub candidates: Vec<SeedRun>,
}

/// Reads and scores a finished run's summary.
pub fn candidate(out_dir: &Path, name: &str, seed: u64) -> Result<SeedRun, TrainError> {
    let run = run_name(name, seed);
    let path = summary_path(&runs_dir(out_dir, name), &run);
    let text = std::fs::read_to_string(&path).with_context(|| format!("run {run}: reading {}", path.display()))?;
    let s: TrainSummary = serde_json::from_str(&text).with_context(|| format!("run {run}: parsing {}", path.display()))?;
    // The model as deployed: with its correction gains when it has some.
    let scored = if s.validation_with_gain.is_empty() { &s.validation } else { &s.validation_with_gain };
    let score = validation_score(scored, Some(s.exported_epoch), s.config.train.task_weighting)
        .filter(|x| x.is_finite())
        .with_context(|| format!("run {run} has no finite validation score at its exported epoch {}", s.exported_epoch))?;
    let test_mean_aoe_deg = (!s.test.is_empty()).then(|| s.test.iter().map(|t| t.model.aoe_deg).sum::<f64>() / s.test.len() as f64);
    Ok(SeedRun {
        seed,
        name: run,
        exported_epoch: s.exported_epoch,
        validation_score_deg: score,
        test_mean_aoe_deg,
        train_seconds: s.train_seconds,
    })
}

/// The candidate with the lowest validation score (the first on a tie).
pub fn choose(candidates: &[SeedRun]) -> Option<&SeedRun> {
    candidates.iter().fold(None, |best: Option<&SeedRun>, c| match best {
        Some(b) if b.validation_score_deg <= c.validation_score_deg => Some(b),
        _ => Some(c),
    })
}

/// Scores the runs of `seeds`, promotes the winner to `<name>.{pt,ot,json,train.json,curves.png}`
/// and writes `<name>.seeds.json`. Returns the selection and the promoted metadata's path.
pub fn select_and_promote(out_dir: &Path, name: &str, seeds: &[u64]) -> Result<(SeedSelection, PathBuf), TrainError> {
    let candidates = seeds.iter().map(|&s| candidate(out_dir, name, s)).collect::<Result<Vec<_>, TrainError>>()?;
    let chosen = choose(&candidates).context("no runs to choose from")?.clone();
    let selection = SeedSelection {
        name: name.to_string(),
        chosen_seed: chosen.seed,
        chosen_run: chosen.name.clone(),
        criterion: "lowest validation score (mean AOE over dataset.validation, weighted like train.task_weighting) at the exported epoch, \
                    with the run's correction gains when it has some"
            .into(),
        candidates,
    };
    let json = promote(out_dir, &chosen.name, name, &selection)?;
    let path = out_dir.join(format!("{name}.seeds.json"));
    let text = serde_json::to_string_pretty(&selection).context("the seed selection")?;
    std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    Ok((selection, json))
}

/// Copies run `from`'s model files (in the runs folder) to `to` (in `out_dir`), renaming them in
/// its metadata and summary.
fn promote(out_dir: &Path, from: &str, to: &str, selection: &SeedSelection) -> Result<PathBuf, TrainError> {
    let runs = runs_dir(out_dir, to);
    let src = |ext: &str| runs.join(format!("{from}.{ext}"));
    let file = |n: &str, ext: &str| out_dir.join(format!("{n}.{ext}"));
    for ext in ["pt", "ot"] {
        std::fs::copy(src(ext), file(to, ext)).with_context(|| format!("copying {} to {}", src(ext).display(), file(to, ext).display()))?;
    }
    let mut meta = load_metadata(&src("json")).with_context(|| format!("reading {}", src("json").display()))?;
    meta.name = to.to_string();
    meta.files = ExportFiles { torchscript: format!("{to}.pt"), weights: format!("{to}.ot") };
    meta.metrics.insert("seed_selection.candidates".into(), selection.candidates.len() as f64);
    for c in &selection.candidates {
        meta.metrics.insert(format!("seed_selection.s{}.validation_score_deg", c.seed), c.validation_score_deg);
    }
    let json = file(to, "json");
    write_metadata(&json, &meta)?;

    let summary_from = summary_path(&runs, from);
    let text = std::fs::read_to_string(&summary_from).with_context(|| format!("reading {}", summary_from.display()))?;
    let mut summary: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("parsing {}", summary_from.display()))?;
    summary["name"] = to.into();
    summary["model_json"] = json.display().to_string().into();
    summary["seed_selection"] = serde_json::to_value(selection).context("the seed selection")?;
    let to_summary = summary_path(out_dir, to);
    let text = serde_json::to_string_pretty(&summary).context("the run's summary")?;
    std::fs::write(&to_summary, text).with_context(|| format!("writing {}", to_summary.display()))?;
    let curves = src("curves.png");
    if curves.exists() {
        std::fs::copy(&curves, file(to, "curves.png")).with_context(|| format!("copying {}", curves.display()))?;
    }
    Ok(json)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(seed: u64, score: f64) -> SeedRun {
        SeedRun {
            seed,
            name: run_name("m", seed),
            exported_epoch: 10,
            validation_score_deg: score,
            test_mean_aoe_deg: Some(100.0 - score),
            train_seconds: 1.0,
        }
    }

    /// The lowest validation score wins whatever the test says; a tie keeps the first.
    #[test]
    fn the_lowest_validation_score_is_chosen() {
        assert_eq!(choose(&[c(0, 3.0), c(1, 2.0), c(2, 2.5)]).unwrap().seed, 1);
        assert_eq!(choose(&[c(4, 2.0), c(5, 2.0)]).unwrap().seed, 4);
        assert!(choose(&[]).is_none());
        assert_eq!(run_name("fsda-f", 3), "fsda-f-s3");
    }
}
