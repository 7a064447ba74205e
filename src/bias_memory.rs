//! The gyro's turn-on bias remembered across power-ons of one IMU: a robot that reboots meets
//! the next power-on knowing what the earlier ones measured at their standstills. Part of a
//! turn-on bias repeats (an IMU's lasting offset: EuRoC's ADIS16448 reads z 78–82 mrad/s in
//! each of its eleven recordings) and part is drawn anew (a consumer part's repeatability).
//! Before this power-on's first standstill, an axis's remembered mean is removed only where
//! the earlier power-ons predict this one's bias with confidence: the 95 % prediction interval
//! (Student's t over their spread, at least `floor_stddev`) excludes zero. An IMU whose bias
//! changes sign from one power-on to the next (a hand-held rig: z +8.8, −4.1, −3.9, +8.0
//! mrad/s) gets nothing removed. The file is JSON; a standstill of this power-on replaces
//! the prediction at once (docs/poweron.md).

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::standstill::BiasEstimate;
pub use crate::standstill::BiasPrediction;

/// Power-ons kept in the file (the oldest dropped first).
pub const MAX_POWER_ONS: usize = 50;

#[derive(Debug, thiserror::Error)]
pub enum BiasMemoryError {
    #[error("reading the bias memory {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a bias memory (JSON with `power_ons`): {source}; move it aside or name another file")]
    Parse { path: PathBuf, source: serde_json::Error },
    #[error("{path}: power-on {index} has a non-finite or negative value")]
    Invalid { path: PathBuf, index: usize },
    #[error("writing the bias memory {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
}

/// One earlier power-on's bias, as its standstills measured it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RememberedBias {
    /// rad/s, IMU axes.
    pub bias_rad_s: [f64; 3],
    /// Its own 1σ per axis, rad/s.
    pub stddev_rad_s: [f64; 3],
    /// Seconds of standstill it rests on.
    pub still_s: f64,
    /// Which power-on: a node's start time, a bag's name.
    pub power_on: String,
}

/// The file's content.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BiasMemory {
    pub power_ons: Vec<RememberedBias>,
}

impl BiasMemory {
    /// The file at `path`; none there is an empty memory (the first power-on).
    pub fn load(path: &Path) -> Result<Self, BiasMemoryError> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Self::default()),
            Err(source) => return Err(BiasMemoryError::Read { path: path.into(), source }),
        };
        let memory: Self = serde_json::from_str(&text).map_err(|source| BiasMemoryError::Parse { path: path.into(), source })?;
        for (index, p) in memory.power_ons.iter().enumerate() {
            let values = p.bias_rad_s.iter().chain(&p.stddev_rad_s).chain(std::iter::once(&p.still_s));
            if values.clone().any(|v| !v.is_finite()) || p.stddev_rad_s.iter().any(|&s| s < 0.0) || p.still_s < 0.0 {
                return Err(BiasMemoryError::Invalid { path: path.into(), index });
            }
        }
        Ok(memory)
    }

    /// [`Self::load`] for a node that must start: a file that is not a bias memory is moved
    /// aside (`<file>.corrupt-<unix s>`, kept, nothing lost) and the memory starts empty; the
    /// note says so. An unreadable file (permissions) is still an error.
    pub fn load_or_set_aside(path: &Path) -> Result<(Self, Option<String>), BiasMemoryError> {
        match Self::load(path) {
            Ok(m) => Ok((m, None)),
            Err(e @ (BiasMemoryError::Parse { .. } | BiasMemoryError::Invalid { .. })) => {
                let unix = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
                let aside = PathBuf::from(format!("{}.corrupt-{unix}", path.display()));
                std::fs::rename(path, &aside).map_err(|source| BiasMemoryError::Write { path: aside.clone(), source })?;
                Ok((Self::default(), Some(format!("{e}: moved to {}, starting with no earlier power-ons", aside.display()))))
            }
            Err(e) => Err(e),
        }
    }

    /// Writes to `path` whole or not at all (a temporary file renamed over it): a reboot
    /// mid-write leaves the earlier file.
    pub fn save(&self, path: &Path) -> Result<(), BiasMemoryError> {
        let err = |source| BiasMemoryError::Write { path: path.into(), source };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(err)?;
        }
        let tmp = path.with_extension("json.tmp");
        let text = serde_json::to_string_pretty(self).map_err(|e| err(std::io::Error::other(e)))?;
        std::fs::write(&tmp, text + "\n").map_err(err)?;
        std::fs::rename(&tmp, path).map_err(err)
    }

    /// Records (or, for the same `power_on`, replaces) one power-on's standstill estimate.
    pub fn remember(&mut self, power_on: &str, estimate: &BiasEstimate) {
        let entry = RememberedBias {
            bias_rad_s: estimate.bias.into(),
            stddev_rad_s: estimate.variance.map(f64::sqrt).into(),
            still_s: estimate.still_s,
            power_on: power_on.to_string(),
        };
        match self.power_ons.iter_mut().find(|p| p.power_on == power_on) {
            Some(p) => *p = entry,
            None => self.power_ons.push(entry),
        }
        let excess = self.power_ons.len().saturating_sub(MAX_POWER_ONS);
        self.power_ons.drain(..excess);
    }

    /// The prediction for a new power-on from the others (`except`: this one's own entry, if
    /// it is already in the file). `floor_stddev`: the least spread assumed between power-ons,
    /// rad/s (two that agree by chance do not make a certainty). `None`: fewer than two.
    pub fn predict(&self, except: Option<&str>, floor_stddev: f64) -> Option<BiasPrediction> {
        let used: Vec<&RememberedBias> = self.power_ons.iter().filter(|p| Some(p.power_on.as_str()) != except).collect();
        let n = used.len();
        if n < 2 {
            return None;
        }
        let t = crate::student_t::two_sided_95(n - 1);
        let mut prediction = BiasPrediction { bias: Vector3::zeros(), variance: Vector3::zeros(), applied: [false; 3], power_ons: n };
        for axis in 0..3 {
            let mean = used.iter().map(|p| p.bias_rad_s[axis]).sum::<f64>() / n as f64;
            let spread = (used.iter().map(|p| (p.bias_rad_s[axis] - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
            let own = (used.iter().map(|p| p.stddev_rad_s[axis].powi(2)).sum::<f64>() / n as f64).sqrt();
            let predictive = spread.max(own).max(floor_stddev) * (1.0 + 1.0 / n as f64).sqrt();
            if mean.abs() > t * predictive {
                prediction.bias[axis] = mean;
                prediction.variance[axis] = predictive * predictive;
                prediction.applied[axis] = true;
            } else {
                prediction.variance[axis] = mean * mean + predictive * predictive;
            }
        }
        Some(prediction)
    }
}

/// What the memory at `path` predicts for a power-on starting now, and a note saying it
/// (logged, and on /diagnostics). `set_aside`: a corrupt file is moved aside and the run starts
/// with none (the node, which must start), else it is an error (`replay`).
pub fn prediction_at_start(path: &Path, floor_stddev: f64, set_aside: bool) -> Result<(Option<BiasPrediction>, String), BiasMemoryError> {
    let (memory, aside) = if set_aside { BiasMemory::load_or_set_aside(path)? } else { (BiasMemory::load(path)?, None) };
    let prediction = memory.predict(None, floor_stddev);
    let said = match prediction {
        Some(p) => p.describe(),
        None => format!(
            "{} earlier power-on{}: nothing predicted yet (two are needed)",
            memory.power_ons.len(),
            if memory.power_ons.len() == 1 { "" } else { "s" }
        ),
    };
    Ok((prediction, aside.map_or(said.clone(), |a| format!("{a}; {said}"))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn memory(biases: &[[f64; 3]]) -> BiasMemory {
        BiasMemory {
            power_ons: biases
                .iter()
                .enumerate()
                .map(|(k, b)| RememberedBias { bias_rad_s: *b, stddev_rad_s: [2e-4; 3], still_s: 5.0, power_on: format!("p{k}") })
                .collect(),
        }
    }

    #[test]
    fn a_bias_that_repeats_is_predicted_and_one_that_changes_sign_is_not() {
        // EuRoC-like: x small, y and z repeat.
        let m = memory(&[[-0.002, 0.020, 0.078], [-0.003, 0.021, 0.079], [-0.001, 0.024, 0.082], [-0.002, 0.019, 0.078]]);
        let p = m.predict(None, 0.002).unwrap();
        assert_eq!(p.applied, [false, true, true], "{p:?}");
        assert!((p.bias.z - 0.07925).abs() < 1e-9 && p.bias.x == 0.0, "{p:?}");
        // The stated σ is at least the floor's, grown by the prediction.
        assert!((p.variance.z.sqrt() - 0.002 * (1.25f64).sqrt()).abs() < 1e-12, "{p:?}");
        // The rig of the issue: z +8.8, −4.1, −3.9, +8.0 mrad/s.
        let rig = memory(&[[0.0, 0.0, 0.0088], [0.0, 0.0, -0.0041], [0.0, 0.0, -0.0039], [0.0, 0.0, 0.0080]]);
        let p = rig.predict(None, 0.002).unwrap();
        assert!(!p.applies_any(), "{p:?}");
        assert!(p.variance.z > 0.0088f64.powi(2) - 0.0087f64.powi(2), "{p:?}");
    }

    #[test]
    fn two_power_ons_that_agree_by_chance_are_not_a_certainty() {
        // 30 mrad/s twice: with the 2 mrad/s floor and t(1) = 12.7 the interval holds zero.
        let p = memory(&[[0.0, 0.0, 0.030], [0.0, 0.0, 0.0301]]).predict(None, 0.002).unwrap();
        assert!(!p.applied[2], "{p:?}");
        // Five of them do predict it.
        let p = memory(&[[0.0, 0.0, 0.030]; 5]).predict(None, 0.002).unwrap();
        assert!(p.applied[2], "{p:?}");
        assert!(memory(&[[0.0, 0.0, 0.03]]).predict(None, 0.002).is_none());
    }

    #[test]
    fn this_power_on_is_left_out_of_its_own_prediction_and_replaced_in_place() {
        let mut m = memory(&[[0.0, 0.0, 0.03]; 3]);
        let e = BiasEstimate { bias: Vector3::new(0.0, 0.0, 0.5), variance: Vector3::repeat(1e-8), at_ns: 0, still_s: 2.0 };
        m.remember("now", &e);
        m.remember("now", &BiasEstimate { still_s: 3.0, ..e });
        assert_eq!(m.power_ons.len(), 4);
        assert_eq!(m.power_ons[3].still_s, 3.0);
        let p = m.predict(Some("now"), 0.002).unwrap();
        assert_eq!(p.power_ons, 3);
        assert!((p.bias.z - 0.03).abs() < 1e-12, "{p:?}");
    }

    #[test]
    fn the_file_round_trips_a_missing_one_is_empty_and_a_corrupt_one_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("sub/bias.json");
        assert_eq!(BiasMemory::load(&path).unwrap(), BiasMemory::default());
        let m = memory(&[[0.001, 0.002, 0.003]; 2]);
        m.save(&path).unwrap();
        assert_eq!(BiasMemory::load(&path).unwrap(), m);
        std::fs::write(&path, "{\"power_ons\": [").unwrap();
        let e = BiasMemory::load(&path).unwrap_err().to_string();
        assert!(e.contains("not a bias memory"), "{e}");
        std::fs::write(&path, r#"{"power_ons": [{"bias_rad_s": [0, 0, 0], "stddev_rad_s": [-1, 0, 0], "still_s": 1, "power_on": "x"}]}"#)
            .unwrap();
        assert!(matches!(BiasMemory::load(&path), Err(BiasMemoryError::Invalid { index: 0, .. })));
    }

    #[test]
    fn a_node_sets_a_corrupt_file_aside_and_starts_empty() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("bias.json");
        std::fs::write(&path, "not json").unwrap();
        let (m, note) = BiasMemory::load_or_set_aside(&path).unwrap();
        assert!(m.power_ons.is_empty() && !path.exists());
        let note = note.unwrap();
        let aside: Vec<_> = std::fs::read_dir(tmp.path()).unwrap().map(|e| e.unwrap().path()).collect();
        assert_eq!(aside.len(), 1, "{aside:?}");
        assert_eq!(std::fs::read_to_string(&aside[0]).unwrap(), "not json", "{note}");
        assert!(note.contains("corrupt-"), "{note}");
    }

    #[test]
    fn only_the_latest_power_ons_are_kept() {
        let mut m = BiasMemory::default();
        let e = BiasEstimate { bias: Vector3::zeros(), variance: Vector3::zeros(), at_ns: 0, still_s: 1.0 };
        for k in 0..MAX_POWER_ONS + 5 {
            m.remember(&format!("p{k}"), &e);
        }
        assert_eq!(m.power_ons.len(), MAX_POWER_ONS);
        assert_eq!(m.power_ons[0].power_on, "p5");
    }
}
