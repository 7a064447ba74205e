//! The offline reference a DDS peer's run is compared with: a slice of an EuRoC recording,
//! imported and replayed by `imu-fsda` (tests/dds_interop.rs, tests/dds_fastdds.rs).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use imu_fsda::bag::BagReader;
use imu_fsda::msg::{Imu, RosMessage, Vector3Stamped};

use super::{manifest_dir, run_cli};

/// Bound of one `import` / `replay`.
const CLI_TIMEOUT: Duration = Duration::from_secs(30);

/// The EuRoC imu0/data.csv of `preferred`, else of the other candidate.
pub fn euroc_csv(preferred: &str) -> Result<PathBuf, String> {
    let root = manifest_dir().join("../shared/data/euroc");
    [preferred, "MH_04_difficult", "V1_01_easy"]
        .iter()
        .map(|s| root.join(s).join("mav0/imu0/data.csv"))
        .find(|p| p.is_file())
        .ok_or_else(|| format!("no EuRoC sequence under {}", root.display()))
}

/// Write rows `start..start+count` of `csv` as a sequence folder (`mav0/imu0/data.csv` plus
/// the ground truth over the same span) that `imu-fsda import` reads; returns the slice file.
pub fn slice_sequence(csv: &Path, start: usize, count: usize, dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(csv).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let rows: Vec<&str> = lines.filter(|l| !l.trim().is_empty()).skip(start).take(count).collect();
    assert_eq!(rows.len(), count, "{}: fewer than {} rows from {start}", csv.display(), count);
    let stamp = |l: &str| l.split(',').next().unwrap().trim().parse::<i64>().unwrap();
    let (t0, t1) = (stamp(rows[0]), stamp(rows[count - 1]));
    let imu = dir.join("seq/mav0/imu0/data.csv");
    std::fs::create_dir_all(imu.parent().unwrap()).unwrap();
    let mut f = std::fs::File::create(&imu).unwrap();
    writeln!(f, "{header}").unwrap();
    for r in &rows {
        writeln!(f, "{r}").unwrap();
    }
    let gt_src = csv.parent().unwrap().parent().unwrap().join("state_groundtruth_estimate0/data.csv");
    let gt = dir.join("seq/mav0/state_groundtruth_estimate0/data.csv");
    std::fs::create_dir_all(gt.parent().unwrap()).unwrap();
    let gt_text = std::fs::read_to_string(&gt_src).unwrap();
    let mut g = std::fs::File::create(&gt).unwrap();
    let mut gl = gt_text.lines();
    writeln!(g, "{}", gl.next().unwrap()).unwrap();
    for l in gl.filter(|l| l.split(',').next().and_then(|s| s.trim().parse::<i64>().ok()).is_some_and(|t| t >= t0 && t <= t1)) {
        writeln!(g, "{l}").unwrap();
    }
    imu
}

/// The reference: replay's /imu/denoised and /imu/gyro_correction, and the bag's /imu/data.
pub struct Reference {
    pub inputs: Vec<Imu>,
    pub denoised: Vec<Imu>,
    pub corrections: Vec<Vector3Stamped>,
}

pub fn reference(seq_dir: &Path, dir: &Path) -> Reference {
    let raw = dir.join("in.mcap");
    let out = dir.join("replayed.mcap");
    run_cli(&["import", seq_dir.to_str().unwrap(), "-o", raw.to_str().unwrap()], "import", CLI_TIMEOUT);
    run_cli(&["replay", raw.to_str().unwrap(), "-o", out.to_str().unwrap(), "--model", ""], "replay", CLI_TIMEOUT);
    let mut r = Reference { inputs: vec![], denoised: vec![], corrections: vec![] };
    for m in BagReader::open(&out).unwrap() {
        let m = m.unwrap();
        match &*m.topic {
            "/imu/data" => r.inputs.push(Imu::decode(&m.data).unwrap()),
            "/imu/denoised" => r.denoised.push(Imu::decode(&m.data).unwrap()),
            "/imu/gyro_correction" => r.corrections.push(Vector3Stamped::decode(&m.data).unwrap()),
            _ => {}
        }
    }
    r
}

pub fn imu_fields(m: &Imu) -> [(&'static str, Vec<f64>); 6] {
    let v = |x: &imu_fsda::msg::Vector3| vec![x.x, x.y, x.z];
    let q = &m.orientation;
    [
        ("orientation", vec![q.x, q.y, q.z, q.w]),
        ("orientation_covariance", m.orientation_covariance.0.to_vec()),
        ("angular_velocity", v(&m.angular_velocity)),
        ("angular_velocity_covariance", m.angular_velocity_covariance.0.to_vec()),
        ("linear_acceleration", v(&m.linear_acceleration)),
        ("linear_acceleration_covariance", m.linear_acceleration_covariance.0.to_vec()),
    ]
}
