//! Averaged weights (SWA; Izmailov et al., 2018): the mean of the weights a run passed
//! through at the end of its last learning-rate cycle, where Adam still moves each recording's
//! output constant by about a milliradian a second per hundred epochs at a learning rate near
//! zero. BatchNorm's running statistics are then re-estimated for the mean weights
//! ([`super::fit::recalibrate_batch_norm`]).

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use tch::Tensor;

use super::checkpoint;

/// The element-wise mean of the model variables (`vs.`-prefixed, as in a checkpoint) of
/// `paths`; a non-floating-point variable is taken from the last checkpoint.
pub fn mean_of_checkpoints(paths: &[PathBuf]) -> anyhow::Result<BTreeMap<String, Tensor>> {
    let mut sum: BTreeMap<String, Tensor> = BTreeMap::new();
    let mut kinds: BTreeMap<String, tch::Kind> = BTreeMap::new();
    for (i, p) in paths.iter().enumerate() {
        let loaded = checkpoint::load(p).with_context(|| format!("averaging {}", p.display()))?;
        // Every checkpoint must hold every variable, or its mean would be divided by too many.
        if let Some(k) = sum.keys().find(|k| !loaded.tensors.contains_key(*k)) {
            anyhow::bail!("{k}: in {}, not in {}", paths[0].display(), p.display());
        }
        for (k, t) in loaded.tensors.into_iter().filter(|(k, _)| k.starts_with("vs.")) {
            match sum.get_mut(&k) {
                Some(acc) if acc.is_floating_point() => {
                    if acc.size() != t.size() {
                        anyhow::bail!("{k}: shape {:?} in {}, {:?} before", t.size(), p.display(), acc.size());
                    }
                    *acc = &*acc + t.to_kind(tch::Kind::Double);
                }
                Some(acc) => *acc = t,
                None if i == 0 => {
                    kinds.insert(k.clone(), t.kind());
                    let t = if t.is_floating_point() { t.to_kind(tch::Kind::Double) } else { t };
                    sum.insert(k, t);
                }
                None => anyhow::bail!("{k}: in {} only, not in {}", p.display(), paths[0].display()),
            }
        }
    }
    let n = paths.len().max(1) as f64;
    Ok(sum
        .into_iter()
        .map(|(k, t)| {
            let t = if t.is_floating_point() { (t / n).to_kind(kinds[&k]) } else { t };
            (k, t)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::checkpoint::{save, CheckpointMeta};
    use crate::train::optim::Adam;
    use crate::train::TrainConfig;
    use tch::{nn::VarStore, Device, Kind};

    /// Two checkpoints of a two-variable store, `w` at `a` and `b`: their mean is (a + b) / 2
    /// element by element; one whose `w` has another shape is refused, not broadcast.
    #[test]
    fn the_mean_of_two_checkpoints_is_their_elementwise_mean() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = TrainConfig::parse("model: {mode: fsda}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: 1}\n").unwrap();
        let write = |name: &str, w: &[f32], steps: i64| {
            let vs = VarStore::new(Device::Cpu);
            let _ = vs.root().var_copy("w", &Tensor::from_slice(w));
            let _ = vs.root().var_copy("b", &Tensor::from_slice(&[steps as f32]));
            let meta = CheckpointMeta::for_test(cfg.clone(), steps as usize);
            save(dir.path(), name, &vs, &Adam::new(&vs), None, None, &meta).unwrap()
        };
        let a = write("a", &[1.0, -2.0, 0.5], 10);
        let b = write("b", &[3.0, 2.0, 0.25], 20);
        let mean = mean_of_checkpoints(&[a.clone(), b]).unwrap();
        let w: Vec<f32> = Vec::try_from(&mean["vs.w"]).unwrap();
        assert_eq!(w, vec![2.0, 0.0, 0.375]);
        assert_eq!(mean["vs.b"].double_value(&[0]), 15.0);
        assert_eq!(mean["vs.w"].kind(), Kind::Float);
        assert!(mean.keys().all(|k| k.starts_with("vs.")), "{:?}", mean.keys().collect::<Vec<_>>());
        let c = write("c", &[1.0, 2.0], 30);
        let err = mean_of_checkpoints(&[a, c]).unwrap_err().to_string();
        assert!(err.contains("vs.w") && err.contains("shape"), "{err}");
    }
}
