//! Checkpoints: `<out>/<name>.ckpt.ot` (every VarStore variable as `vs.<path>`, Adam's
//! moments as `adam.{m,v}.<path>`, and, when a best model is being kept, its variables as
//! `best.<path>`) plus `<name>.ckpt.json` ([`CheckpointMeta`]: the epoch reached, Adam's step
//! count, the seed, the config, the loss history and evaluations so far).
//!
//! What resumes exactly: weights, BatchNorm statistics, Adam's moments and step count, the
//! learning-rate schedule position (a function of the epoch), and the random streams — every
//! epoch reseeds tch and the window sampler from (seed, epoch), so epoch k draws the same
//! windows, noise and dropout masks whether or not the run was interrupted before it. Not
//! bit-exact: libtorch's multi-threaded reductions may sum in another order.

use super::error::{refuse, TrainError};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tch::{nn::VarStore, Tensor};

use super::config::TrainConfig;
use super::optim::Adam;
use super::report::{EpochRecord, SequenceEvals};

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CheckpointMeta {
    pub format_version: u32,
    /// Epochs completed (the next epoch to run).
    pub epoch: usize,
    pub adam_step: i64,
    pub seed: u64,
    pub config: TrainConfig,
    pub history: Vec<EpochRecord>,
    pub validation: Vec<SequenceEvals>,
    /// `dataset.monitor`'s evaluations (absent in older checkpoints).
    #[serde(default)]
    pub monitor: Vec<SequenceEvals>,
    /// Epoch and mean validation AOE of the best model kept so far.
    pub best: Option<(usize, f64)>,
    /// Seconds of training before this checkpoint (for the time per epoch).
    pub train_seconds: f64,
    /// A number drawn at each save and written into both files (`ckpt.pair` in the `.ot`), so
    /// that a `.ckpt.ot` of another run or another save is refused, not resumed from. Set by
    /// [`save`]; absent in older checkpoints (not checked).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pair_token: Option<i64>,
    /// [`crate::train::data::Task::fingerprint`] of every recording, keyed `<list>.<name>`
    /// (absent in older checkpoints: not checked).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub data_fingerprints: BTreeMap<String, String>,
}

#[cfg(test)]
impl CheckpointMeta {
    /// A checkpoint of `epoch` epochs (as many Adam steps) with nothing recorded, for tests.
    pub(crate) fn for_test(config: TrainConfig, epoch: usize) -> Self {
        CheckpointMeta {
            format_version: 1,
            epoch,
            adam_step: epoch as i64,
            seed: 0,
            config,
            history: vec![],
            validation: vec![],
            monitor: vec![],
            best: None,
            train_seconds: 0.0,
            pair_token: None,
            data_fingerprints: BTreeMap::new(),
        }
    }
}

/// The `.ot` entry holding [`CheckpointMeta::pair_token`].
const PAIR_KEY: &str = "ckpt.pair";

/// The `.ot` entry holding the whole [`CheckpointMeta`] as JSON bytes: the `.ot` is renamed
/// into place first, so a run killed before its `.json` follows (a second Ctrl-C, kill -9)
/// leaves an `.ot` that resumes by itself instead of a pair that no longer matches.
const META_KEY: &str = "ckpt.meta";

pub fn paths(out_dir: &Path, name: &str) -> (PathBuf, PathBuf) {
    (out_dir.join(format!("{name}.ckpt.ot")), out_dir.join(format!("{name}.ckpt.json")))
}

/// Writes both files (each through a temporary and a rename).
pub fn save(
    out_dir: &Path,
    name: &str,
    vs: &VarStore,
    adam: &Adam,
    best: Option<&BTreeMap<String, Tensor>>,
    meta: &CheckpointMeta,
) -> Result<PathBuf, TrainError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| TrainError::Io { path, source }
    };
    crate::core::create_dir_all(out_dir).map_err(io(out_dir))?;
    let (ot, json) = paths(out_dir, name);
    let token = rand::random::<i64>();
    let meta = CheckpointMeta { pair_token: Some(token), ..meta.clone() };
    let mut named: Vec<(String, Tensor)> = vs.variables().into_iter().map(|(n, t)| (format!("vs.{n}"), t)).collect();
    named.extend(adam.state());
    if let Some(best) = best {
        named.extend(best.iter().map(|(n, t)| (format!("best.{n}"), t.shallow_clone())));
    }
    named.push((PAIR_KEY.to_string(), Tensor::from_slice(&[token])));
    let text = serde_json::to_string_pretty(&meta).map_err(|e| TrainError::refused("the checkpoint's record", e))?;
    named.push((META_KEY.to_string(), Tensor::from_slice(text.as_bytes())));
    let tmp = ot.with_extension("ot.tmp");
    Tensor::save_multi(&named, &tmp).map_err(|e| TrainError::Torch(format!("{}: {}", tmp.display(), crate::model::torch_message(&e))))?;
    std::fs::rename(&tmp, &ot).map_err(io(&ot))?;
    let tmp = json.with_extension("json.tmp");
    std::fs::write(&tmp, text).map_err(io(&tmp))?;
    std::fs::rename(&tmp, &json).map_err(io(&json))?;
    Ok(json)
}

/// Everything a checkpoint holds.
pub struct Loaded {
    pub meta: CheckpointMeta,
    pub tensors: BTreeMap<String, Tensor>,
}

/// Reads a checkpoint given its `.ckpt.json` or `.ckpt.ot` path.
pub fn load(path: &Path) -> Result<Loaded, TrainError> {
    let s = path.to_string_lossy();
    let stem = s.trim_end_matches(".json").trim_end_matches(".ot").to_string();
    let json = PathBuf::from(format!("{stem}.json"));
    let ot = PathBuf::from(format!("{stem}.ot"));
    let read_json = || -> Result<CheckpointMeta, TrainError> {
        let text = std::fs::read_to_string(&json)
            .map_err(|e| TrainError::Refused(format!("{}: {e} (resume takes the .ckpt.json path)", json.display())))?;
        serde_json::from_str(&text).map_err(|e| TrainError::Refused(format!("{}: not a checkpoint: {e}", json.display())))
    };
    // The `.json` is read first where the `.ot` cannot be: its error names what is wrong.
    if !ot.is_file() {
        read_json()?;
    }
    let mut tensors: BTreeMap<String, Tensor> = Tensor::load_multi(&ot)
        .map_err(|e| TrainError::Torch(format!("{}: {}", ot.display(), crate::model::torch_message(&e))))?
        .into_iter()
        .collect();
    let in_ot = tensors.remove(PAIR_KEY).and_then(|t| Vec::<i64>::try_from(&t).ok()).and_then(|v| v.first().copied());
    if let Some(embedded) = tensors.remove(META_KEY) {
        // The `.ot` carries its own metadata (saves since session 38): a `.json` left behind by
        // an interrupted save does not matter.
        let bytes = Vec::<u8>::try_from(&embedded).map_err(|e| TrainError::Torch(format!("{}: {META_KEY}: {e}", ot.display())))?;
        let meta: CheckpointMeta = serde_json::from_slice(&bytes)
            .map_err(|e| TrainError::Refused(format!("{}: its metadata is not a checkpoint's: {e}", ot.display())))?;
        if meta.format_version != 1 {
            refuse!("{}: checkpoint format {} (expected 1)", ot.display(), meta.format_version);
        }
        if read_json().ok().and_then(|j| j.pair_token) != meta.pair_token {
            tracing::warn!(
                "{} is not the save of {} (a save interrupted between the two files): the .ot's own record is read, epoch {}",
                json.display(),
                ot.display(),
                meta.epoch
            );
        }
        return Ok(Loaded { meta, tensors });
    }
    let meta = read_json()?;
    if meta.format_version != 1 {
        refuse!("{}: checkpoint format {} (expected 1)", json.display(), meta.format_version);
    }
    if let Some(token) = meta.pair_token {
        if in_ot != Some(token) {
            refuse!(
                "{} was not saved with {} (another run's, or an older or newer save of this one): the two files of a checkpoint go together",
                ot.display(),
                json.display()
            );
        }
    }
    Ok(Loaded { meta, tensors })
}

/// Copies the `prefix.`-named tensors into `vs`; every variable must be present.
pub fn restore_vars(vs: &VarStore, tensors: &BTreeMap<String, Tensor>, prefix: &str) -> Result<(), TrainError> {
    for (n, mut t) in vs.variables() {
        let key = format!("{prefix}.{n}");
        let src = tensors.get(&key).ok_or_else(|| TrainError::Refused(format!("checkpoint lacks {key}")))?;
        if src.size() != t.size() {
            refuse!("{key}: shape {:?} in the checkpoint, {:?} in the model", src.size(), t.size());
        }
        tch::no_grad(|| t.copy_(src));
    }
    Ok(())
}

/// Detached copies of every variable (for keeping the best model).
pub fn snapshot(vs: &VarStore) -> BTreeMap<String, Tensor> {
    vs.variables().into_iter().map(|(n, t)| (n, t.detach().copy())).collect()
}

/// Puts a snapshot back.
pub fn restore_snapshot(vs: &VarStore, snap: &BTreeMap<String, Tensor>) -> Result<(), TrainError> {
    let prefixed: BTreeMap<String, Tensor> = snap.iter().map(|(n, t)| (format!("s.{n}"), t.shallow_clone())).collect();
    restore_vars(vs, &prefixed, "s")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(epoch: usize) -> CheckpointMeta {
        CheckpointMeta::for_test(
            TrainConfig::parse("model: {mode: fsda}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: 9}\n").unwrap(),
            epoch,
        )
    }

    /// The `.ot` carries its own metadata: a save interrupted after the `.ot` was renamed and
    /// before the `.json` followed (a second Ctrl-C, kill -9) resumes from the `.ot`, whose
    /// weights and epoch agree. An `.ot` without it (older saves) must match its `.json`.
    #[test]
    fn the_weights_file_describes_itself() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, w: f32, epoch: usize| {
            let vs = VarStore::new(tch::Device::Cpu);
            let _ = vs.root().var_copy("w", &Tensor::from_slice(&[w, w]));
            save(dir.path(), name, &vs, &Adam::new(&vs), None, &meta(epoch)).unwrap()
        };
        let a = write("a", 1.0, 3);
        let b = write("b", 2.0, 6);
        let loaded = load(&a).unwrap();
        assert_eq!(loaded.meta.epoch, 3);
        assert!(!loaded.tensors.contains_key(PAIR_KEY) && !loaded.tensors.contains_key(META_KEY), "not variables");
        assert_eq!(Vec::<f32>::try_from(&loaded.tensors["vs.w"]).unwrap(), vec![1.0, 1.0]);
        // The next save's `.ot` in place, its `.json` never written.
        std::fs::copy(dir.path().join("b.ckpt.ot"), dir.path().join("a.ckpt.ot")).unwrap();
        let loaded = load(&a).unwrap();
        assert_eq!((loaded.meta.epoch, Vec::<f32>::try_from(&loaded.tensors["vs.w"]).unwrap()), (6, vec![2.0, 2.0]));
        // Killed before a first `.json` was written at all: the `.ot` alone resumes.
        let json_a = std::fs::read(&a).unwrap();
        std::fs::remove_file(&a).unwrap();
        assert_eq!(load(&a).unwrap().meta.epoch, 6);
        std::fs::write(&a, json_a).unwrap();
        // An older `.ot` (no metadata of its own) of another save is refused.
        let old: Vec<(String, Tensor)> =
            vec![("vs.w".into(), Tensor::from_slice(&[5.0f32, 5.0])), (PAIR_KEY.into(), Tensor::from_slice(&[7i64]))];
        Tensor::save_multi(&old, dir.path().join("a.ckpt.ot")).unwrap();
        let e = load(&a).err().expect("a mismatched pair loads").to_string();
        assert!(e.contains("was not saved with") && e.contains("a.ckpt.json"), "{e}");
        assert!(load(&b).is_ok());
    }
}
