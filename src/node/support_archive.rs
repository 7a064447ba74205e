//! `adapt_support_archive`: what each `~/adapt` call adapted on (the buffered IMU and ground
//! truth) kept as a bag, one folder per IMU, so that a later power-on's `~/adapt` judges what
//! it learns on the earlier power-ons (`adapt::keep_judged`) instead of on its own.
//!
//! A node run is one power-on of the IMU (as for `power_on_bias_memory`). The node writes
//! `support-<node start, unix s>-<call, unix s>.mcap` (`/imu/data`, `/ground_truth/pose`, as
//! [`crate::bag::write_recording`]); every other bag in the folder is an earlier power-on,
//! the node's own files grouped by their start (the newest of each), a bag a user put there
//! (`imu-fsda import`) one power-on by itself. Nothing in the folder is deleted.

use std::path::{Path, PathBuf};

use crate::bag::{read_recording, write_recording, BagError, RecordingTopics};
use crate::core::Recording;

pub(super) struct SupportArchive {
    dir: PathBuf,
    started_unix_s: u64,
    /// The newest this many earlier power-ons are judged on.
    judge_power_ons: usize,
}

/// What the archive could give to judge on.
pub(super) struct EarlierPowerOns {
    pub(super) recordings: Vec<Recording>,
    /// Bags left out, each with why (unreadable, no ground truth …): never a reason to fail.
    pub(super) skipped: Vec<String>,
}

impl SupportArchive {
    pub(super) fn new(dir: &str, judge_power_ons: usize) -> Option<Self> {
        (!dir.is_empty()).then(|| SupportArchive {
            dir: dir.into(),
            started_unix_s: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs()),
            judge_power_ons,
        })
    }

    pub(super) fn dir(&self) -> &Path {
        &self.dir
    }

    fn this_power_on(&self) -> String {
        format!("support-{}", self.started_unix_s)
    }

    /// Writes `rec` as this power-on's newest support (the writer renames a finished file into
    /// place: a power loss leaves no half bag under the final name).
    pub(super) fn save(&self, rec: &Recording) -> Result<PathBuf, BagError> {
        std::fs::create_dir_all(&self.dir).map_err(|e| BagError::Io { path: self.dir.clone(), source: e })?;
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
        let mut path = self.dir.join(format!("{}-{now}.mcap", self.this_power_on()));
        let mut k = 1;
        while path.exists() {
            path = self.dir.join(format!("{}-{now}-{k}.mcap", self.this_power_on()));
            k += 1;
        }
        write_recording(&path, rec)?;
        Ok(path)
    }

    /// The bags of earlier power-ons, newest first, one per power-on, at most `judge_power_ons`.
    pub(super) fn earlier(&self) -> Vec<PathBuf> {
        let Ok(entries) = std::fs::read_dir(&self.dir) else { return Vec::new() };
        let mut bags: Vec<(std::time::SystemTime, String, PathBuf)> = entries
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
            .filter_map(|p| {
                let power_on = power_on_of(p.file_name()?.to_str()?);
                let modified = std::fs::metadata(&p).and_then(|m| m.modified()).ok()?;
                Some((modified, power_on, p))
            })
            .filter(|(_, power_on, _)| *power_on != self.this_power_on())
            .collect();
        bags.sort_by(|a, b| b.0.cmp(&a.0).then_with(|| b.2.cmp(&a.2)));
        let mut seen = std::collections::BTreeSet::new();
        bags.into_iter().filter(|(_, power_on, _)| seen.insert(power_on.clone())).map(|(_, _, p)| p).take(self.judge_power_ons).collect()
    }

    /// [`SupportArchive::earlier`] read, each with its ground truth; a bag that cannot serve
    /// is skipped and named.
    pub(super) fn read_earlier(&self) -> EarlierPowerOns {
        let topics = RecordingTopics::default();
        let mut out = EarlierPowerOns { recordings: Vec::new(), skipped: Vec::new() };
        for path in self.earlier() {
            let name = path.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            match read_recording(&path, &topics) {
                Err(e) => out.skipped.push(format!("{name}: {e}")),
                Ok((rec, _)) if rec.ground_truth.is_empty() || rec.imu.len() < 2 => {
                    out.skipped.push(format!("{name}: no IMU or no ground truth on {}", crate::bag::GROUND_TRUTH_TOPIC))
                }
                Ok((rec, report)) => match report.stamp_problem_above(0.1) {
                    Some(problem) => out.skipped.push(format!("{name}: {problem}")),
                    None => out.recordings.push(Recording { name, ..rec }),
                },
            }
        }
        out
    }
}

/// The power-on a bag in the archive belongs to: `support-<start>` for the node's own files,
/// else the bag itself.
fn power_on_of(file_name: &str) -> String {
    let stem = file_name.strip_suffix(".mcap").unwrap_or(file_name);
    match stem.strip_prefix("support-").and_then(|rest| rest.split('-').next()) {
        Some(start) if !start.is_empty() && start.bytes().all(|b| b.is_ascii_digit()) => format!("support-{start}"),
        _ => stem.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::{ImuSample, PoseSample};
    use nalgebra::{UnitQuaternion, Vector3};

    fn recording(seconds: i64) -> Recording {
        let imu = (0..seconds * 100)
            .map(|k| ImuSample { stamp_ns: k * 10_000_000, gyro: Vector3::new(0.01, 0.0, 0.0), accel: Vector3::new(0.0, 0.0, 9.81) })
            .collect();
        let ground_truth = (0..seconds * 20)
            .map(|k| PoseSample {
                stamp_ns: k * 50_000_000,
                position_in_world: Vector3::zeros(),
                world_from_body: UnitQuaternion::identity(),
            })
            .collect();
        Recording { name: "buffer".into(), imu, ground_truth, temperature: Vec::new() }
    }

    fn archive(dir: &Path, started: u64, n: usize) -> SupportArchive {
        SupportArchive { dir: dir.into(), started_unix_s: started, judge_power_ons: n }
    }

    #[test]
    fn a_bag_belongs_to_the_power_on_that_wrote_it() {
        assert_eq!(power_on_of("support-1700-1800.mcap"), "support-1700");
        assert_eq!(power_on_of("support-1700-1800-2.mcap"), "support-1700");
        assert_eq!(power_on_of("V1_02_medium.mcap"), "V1_02_medium");
        assert_eq!(power_on_of("support-x-1.mcap"), "support-x-1");
    }

    /// This power-on's own supports are never judged on; of each earlier one the newest is;
    /// a bag that cannot serve is named and left out, not fatal.
    #[test]
    fn earlier_power_ons_are_judged_on_and_this_one_is_not() {
        let tmp = tempfile::tempdir().unwrap();
        let first = archive(tmp.path(), 100, 5);
        let a = first.save(&recording(3)).unwrap();
        let a2 = first.save(&recording(2)).unwrap();
        assert_ne!(a, a2);
        // Written a minute apart (a file system's mtime may be coarser than two saves).
        let earlier = std::time::SystemTime::now() - std::time::Duration::from_secs(60);
        std::fs::File::options().write(true).open(&a).unwrap().set_modified(earlier).unwrap();
        assert!(first.earlier().is_empty(), "its own power-on only");
        let second = archive(tmp.path(), 200, 5);
        let b = second.save(&recording(4)).unwrap();
        assert_eq!(second.earlier().len(), 1);
        let third = archive(tmp.path(), 300, 5);
        std::fs::write(tmp.path().join("broken.mcap"), b"not a bag").unwrap();
        let got = third.read_earlier();
        assert_eq!(got.recordings.len(), 2, "one per earlier power-on");
        assert_eq!(got.skipped.len(), 1, "{:?}", got.skipped);
        assert!(got.skipped[0].starts_with("broken.mcap"), "{:?}", got.skipped);
        let names: Vec<&str> = got.recordings.iter().map(|r| r.name.as_str()).collect();
        assert!(names.contains(&b.file_name().unwrap().to_str().unwrap()), "{names:?}");
        let from_first = got.recordings.iter().find(|r| r.name.starts_with("support-100")).unwrap();
        assert_eq!(from_first.imu.len(), recording(2).imu.len(), "the newest of power-on 100 ({})", a2.display());
        assert_eq!(from_first.ground_truth.len(), recording(2).ground_truth.len());
        assert_eq!(archive(tmp.path(), 300, 1).earlier().len(), 1, "at most judge_power_ons");
        assert!(!std::fs::read_dir(tmp.path()).unwrap().any(|e| e.unwrap().path().to_string_lossy().contains("partial")));
    }
}
