//! Real datasets in the ASL layout: EuRoC MAV (ADIS16448, Vicon/Leica ground truth) and
//! TUM-VI (BMI160, mocap with dropouts). Columns are found by header name, so the 8- and
//! 17-column ground-truth files both read; gaps in the ground truth stay gaps.

use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

use crate::bag::{push_imu, LoadReport};
use crate::core::{ImuSample, PoseSample, Recording};

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}: not an EuRoC or TUM-VI sequence (expected mav0/imu0/data.csv and mav0/state_groundtruth_estimate0/data.csv or mav0/mocap0/data.csv)")]
    Layout(PathBuf),
    #[error("{path}: header has no column {column} (header: {header})")]
    MissingColumn { path: PathBuf, column: String, header: String },
    #[error("{path}:{line}: {what}")]
    Malformed { path: PathBuf, line: u64, what: String },
    #[error("{path}: no samples")]
    Empty { path: PathBuf },
}

/// Which benchmark a sequence folder belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum DatasetKind {
    /// EuRoC MAV: `state_groundtruth_estimate0` ground truth.
    Euroc,
    /// TUM-VI: `mocap0` ground truth with dropouts.
    TumVi,
}

/// Files of one sequence.
#[derive(Debug, Clone)]
pub struct Sequence {
    pub kind: DatasetKind,
    pub name: String,
    pub imu_csv: PathBuf,
    pub ground_truth_csv: PathBuf,
}

/// Find the `mav0` files under `dir` (the sequence folder or its `mav0`) and tell which
/// dataset it is.
pub fn detect(dir: &Path) -> Result<Sequence, DatasetError> {
    let mav0 = if dir.join("mav0").is_dir() { dir.join("mav0") } else { dir.to_path_buf() };
    let imu_csv = mav0.join("imu0/data.csv");
    let euroc_gt = mav0.join("state_groundtruth_estimate0/data.csv");
    let tumvi_gt = mav0.join("mocap0/data.csv");
    if !dir.exists() {
        // A relative `dataset.root` read from another folder lands here: say the path is not there.
        return Err(DatasetError::Io {
            path: dir.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such folder"),
        });
    }
    let (kind, ground_truth_csv) = if !imu_csv.is_file() {
        return Err(DatasetError::Layout(dir.to_path_buf()));
    } else if euroc_gt.is_file() {
        (DatasetKind::Euroc, euroc_gt)
    } else if tumvi_gt.is_file() {
        (DatasetKind::TumVi, tumvi_gt)
    } else {
        return Err(DatasetError::Layout(dir.to_path_buf()));
    };
    let seq_dir = if mav0.file_name().is_some_and(|n| n == "mav0") { mav0.parent().unwrap_or(&mav0) } else { &mav0 };
    let name =
        seq_dir.canonicalize().unwrap_or(seq_dir.to_path_buf()).file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    Ok(Sequence { kind, name, imu_csv, ground_truth_csv })
}

/// A CSV file with named columns (`#timestamp [ns], w_RS_S_x [rad s^-1], ...`).
struct AslCsv {
    path: PathBuf,
    columns: Vec<String>,
    reader: csv::Reader<std::fs::File>,
}

/// Column name without the leading `#`, spaces and the unit in brackets.
fn column_key(raw: &str) -> String {
    let s = raw.trim().trim_start_matches('#').trim();
    s.split([' ', '[']).next().unwrap_or("").to_string()
}

impl AslCsv {
    fn open(path: &Path) -> Result<Self, DatasetError> {
        let file = std::fs::File::open(path).map_err(|source| DatasetError::Io { path: path.to_path_buf(), source })?;
        let mut reader = csv::ReaderBuilder::new().has_headers(true).flexible(true).trim(csv::Trim::All).from_reader(file);
        let header = reader.headers().map_err(|e| DatasetError::Malformed { path: path.to_path_buf(), line: 1, what: e.to_string() })?;
        let columns = header.iter().map(column_key).collect();
        Ok(AslCsv { path: path.to_path_buf(), columns, reader })
    }

    fn index(&self, name: &str) -> Result<usize, DatasetError> {
        self.columns.iter().position(|c| c == name).ok_or_else(|| DatasetError::MissingColumn {
            path: self.path.clone(),
            column: name.into(),
            header: self.columns.join(","),
        })
    }

    /// Visit each data row as parsed numbers in the order of `cols`, with its line number.
    fn rows(&mut self, cols: &[usize], mut visit: impl FnMut(u64, i64, &[f64])) -> Result<(), DatasetError> {
        let mut values = vec![0.0; cols.len()];
        let mut record = csv::StringRecord::new();
        loop {
            let line = self.reader.position().line();
            match self.reader.read_record(&mut record) {
                Ok(false) => return Ok(()),
                Ok(true) => {}
                Err(e) => return Err(DatasetError::Malformed { path: self.path.clone(), line, what: e.to_string() }),
            }
            let line = record.position().map(|p| p.line()).unwrap_or(line);
            if record.iter().all(|f| f.is_empty()) {
                continue;
            }
            let field = |i: usize| {
                record.get(i).ok_or_else(|| DatasetError::Malformed {
                    path: self.path.clone(),
                    line,
                    what: format!("{} fields, expected {}", record.len(), self.columns.len()),
                })
            };
            // A row with more fields than the header is as damaged as one with fewer.
            if record.len() > self.columns.len() {
                return Err(DatasetError::Malformed {
                    path: self.path.clone(),
                    line,
                    what: format!("{} fields, expected {}", record.len(), self.columns.len()),
                });
            }
            let stamp_text = field(0)?;
            let stamp: i64 = stamp_text.parse().map_err(|_| DatasetError::Malformed {
                path: self.path.clone(),
                line,
                what: format!("timestamp {stamp_text:?} is not an integer of ns"),
            })?;
            if stamp < 0 {
                return Err(DatasetError::Malformed { path: self.path.clone(), line, what: format!("timestamp {stamp} ns is negative") });
            }
            for (v, &c) in values.iter_mut().zip(cols) {
                let text = field(c)?;
                // "nan"/"inf" parse as floats and are dealt with by the caller (skipped, counted).
                *v = text.parse().map_err(|_| DatasetError::Malformed {
                    path: self.path.clone(),
                    line,
                    what: format!("column {} value {text:?} is not a number", self.columns[c]),
                })?;
            }
            visit(line, stamp, &values);
        }
    }
}

/// Read `imu0/data.csv`. Non-finite rows and rows whose stamp repeats or goes back are
/// skipped and counted in `report`; a row that does not parse is an error naming the line.
pub fn read_imu_csv(path: &Path, report: &mut LoadReport) -> Result<Vec<ImuSample>, DatasetError> {
    let mut csv = AslCsv::open(path)?;
    if csv.columns.first().map(String::as_str) != Some("timestamp") {
        return Err(DatasetError::MissingColumn { path: path.into(), column: "timestamp (first)".into(), header: csv.columns.join(",") });
    }
    let cols = ["w_RS_S_x", "w_RS_S_y", "w_RS_S_z", "a_RS_S_x", "a_RS_S_y", "a_RS_S_z"]
        .map(|c| csv.index(c))
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;
    let mut imu = Vec::new();
    csv.rows(&cols, |_, stamp_ns, v| {
        report.imu_read += 1;
        let s = ImuSample { stamp_ns, gyro: Vector3::new(v[0], v[1], v[2]), accel: Vector3::new(v[3], v[4], v[5]) };
        push_imu(&mut imu, s, report);
    })?;
    if imu.is_empty() {
        return Err(DatasetError::Empty { path: path.into() });
    }
    Ok(imu)
}

/// Read a ground-truth CSV (EuRoC 8 or 17 columns, TUM-VI mocap): stamp, position and the
/// Hamilton quaternion (w first) of the IMU frame in the world.
pub fn read_ground_truth_csv(path: &Path, report: &mut LoadReport) -> Result<Vec<PoseSample>, DatasetError> {
    let mut csv = AslCsv::open(path)?;
    let cols = ["p_RS_R_x", "p_RS_R_y", "p_RS_R_z", "q_RS_w", "q_RS_x", "q_RS_y", "q_RS_z"]
        .map(|c| csv.index(c))
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;
    let mut out: Vec<PoseSample> = Vec::new();
    csv.rows(&cols, |_, stamp_ns, v| {
        report.ground_truth_read += 1;
        let q = Quaternion::new(v[3], v[4], v[5], v[6]);
        let ok = v.iter().all(|x| x.is_finite()) && q.norm() > 0.5;
        if !ok {
            report.ground_truth_invalid += 1;
            return;
        }
        if out.last().is_some_and(|l| stamp_ns <= l.stamp_ns) {
            report.ground_truth_out_of_order += 1;
            return;
        }
        out.push(PoseSample {
            stamp_ns,
            position_in_world: Vector3::new(v[0], v[1], v[2]),
            world_from_body: UnitQuaternion::new_normalize(q),
        });
    })?;
    if out.is_empty() {
        return Err(DatasetError::Empty { path: path.into() });
    }
    Ok(out)
}

/// Load a whole sequence folder.
pub fn load_sequence(dir: &Path) -> Result<(Sequence, Recording, LoadReport), DatasetError> {
    let seq = detect(dir)?;
    let mut report = LoadReport::default();
    let imu = read_imu_csv(&seq.imu_csv, &mut report)?;
    let ground_truth = read_ground_truth_csv(&seq.ground_truth_csv, &mut report)?;
    let mut rec = Recording { name: seq.name.clone(), imu, ground_truth, temperature: Vec::new() };
    report.ground_truth_frozen = crate::frozen_ground_truth::drop_frozen_ground_truth(&mut rec) as u64;
    if report.ground_truth_frozen > 0 {
        tracing::warn!("{}: {report}", dir.display());
    }
    Ok((seq, rec, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, rel: &str, text: &str) {
        let p = dir.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }

    const IMU_HEADER: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n";

    #[test]
    fn detects_and_reads_both_layouts() {
        let d = tempfile::tempdir().unwrap();
        let imu = format!("{IMU_HEADER}1000,0.1,0.2,0.3,9.8,0,0\n2000,nan,0.2,0.3,9.8,0,0\n2000,0.1,0.2,0.3,9.8,0,0\n3000,0.1,0.2,0.3,9.8,0,0\n2500,0.1,0.2,0.3,9.8,0,0\n100000003000,0.1,0.2,0.3,9.8,0,0\n90000000000,0.1,0.2,0.3,9.8,0,0\n");
        write(d.path(), "seqA/mav0/imu0/data.csv", &imu);
        write(d.path(), "seqA/mav0/state_groundtruth_estimate0/data.csv", "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1]\n1000,1,2,3,1,0,0,0,0.5\n2000,1,2,3,0,1,0,0,0.5\n");
        let (seq, rec, report) = load_sequence(&d.path().join("seqA")).unwrap();
        assert_eq!(seq.kind, DatasetKind::Euroc);
        assert_eq!(seq.name, "seqA");
        // 2500 is jittered (put back in order), 90 s is a clock stepped back 10 s (skipped).
        assert_eq!(rec.imu.iter().map(|s| s.stamp_ns).collect::<Vec<_>>(), vec![1000, 2000, 2500, 3000, 100000003000]);
        assert_eq!(report.imu_non_finite, 1);
        assert_eq!((report.imu_backwards_stamp, report.imu_reordered), (1, 1));
        assert_eq!(rec.ground_truth.len(), 2);

        write(d.path(), "room/mav0/imu0/data.csv", &imu);
        write(
            d.path(),
            "room/mav0/mocap0/data.csv",
            "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []\n1000,0,0,0,1,0,0,0\n",
        );
        let (seq, _, _) = load_sequence(&d.path().join("room/mav0")).unwrap();
        assert_eq!(seq.kind, DatasetKind::TumVi);
        assert_eq!(seq.name, "room");
    }

    #[test]
    fn malformed_line_names_file_and_line() {
        let d = tempfile::tempdir().unwrap();
        write(d.path(), "s/mav0/imu0/data.csv", &format!("{IMU_HEADER}1000,0.1,0.2,0.3,9.8,0,0\n2000,0.1,zz,0.3,9.8,0,0\n"));
        write(
            d.path(),
            "s/mav0/mocap0/data.csv",
            "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []\n1000,0,0,0,1,0,0,0\n",
        );
        let err = load_sequence(&d.path().join("s")).unwrap_err().to_string();
        assert!(err.contains("imu0/data.csv:3") && err.contains("w_RS_S_y"), "{err}");
        write(d.path(), "s/mav0/imu0/data.csv", &format!("{IMU_HEADER}1000,0.1,0.2\n"));
        let err = load_sequence(&d.path().join("s")).unwrap_err().to_string();
        assert!(err.contains("data.csv:2"), "{err}");
    }

    #[test]
    fn missing_layout_and_columns_are_errors() {
        let d = tempfile::tempdir().unwrap();
        assert!(matches!(detect(d.path()), Err(DatasetError::Layout(_))));
        write(d.path(), "s/mav0/imu0/data.csv", "#timestamp [ns],w_x\n1,2\n");
        write(d.path(), "s/mav0/mocap0/data.csv", "#timestamp\n");
        let err = load_sequence(&d.path().join("s")).unwrap_err();
        assert!(matches!(err, DatasetError::MissingColumn { .. }), "{err}");
    }
}
