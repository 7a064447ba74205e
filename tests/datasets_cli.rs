//! `imu-fsda import` + `imu-fsda eval` on the real EuRoC and TUM-VI recordings in
//! ../shared/data, checked against an independent computation (tests/python/independent_eval.py).

use std::path::Path;
use std::process::Command;

mod common;

use common::{bin, shared_data, venv_python as python};

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().expect("spawn");
    assert!(out.status.success(), "{cmd:?} failed: {}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn eval_json(bag: &Path, dir: &Path, method: &str) -> serde_json::Value {
    let json = dir.join(format!("{method}.json"));
    run(Command::new(bin()).args(["eval", "--method", method, "--json"]).arg(&json).arg(bag));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    v["rows"][0].clone()
}

/// Import a sequence, evaluate the raw gyro, and compare with the independent numbers.
fn check_sequence(rel: &str, expect_aoe: (f64, f64)) {
    let (Some(data), Some(py)) = (shared_data(), python()) else { return };
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("seq.mcap");
    let seq = data.join(rel);
    let printed = run(Command::new(bin()).arg("import").arg(&seq).arg("-o").arg(&bag));
    assert!(printed.contains("IMU samples"), "{printed}");

    let ours = eval_json(&bag, dir.path(), "raw");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/independent_eval.py");
    let theirs: serde_json::Value = serde_json::from_str(&run(Command::new(py).arg(script).arg(&seq))).unwrap();
    for key in ["aoe_deg", "roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg"] {
        let (a, b) = (ours[key].as_f64().unwrap(), theirs[key].as_f64().unwrap());
        assert!((a - b).abs() <= 1e-3 * b.max(1.0), "{rel} {key}: ours {a} independent {b}");
    }
    assert_eq!(ours["evaluated_samples"], theirs["evaluated_samples"], "{rel}");
    // The row says how much of the span the ground truth's gaps left unscored.
    let (gaps, scored) = (ours["samples_in_gaps"].as_u64().unwrap(), ours["evaluated_samples"].as_u64().unwrap());
    let note = ours["note"].as_str().unwrap();
    if gaps > 0 {
        let share = format!("{:.1} % of the span in ground-truth gaps", 100.0 * gaps as f64 / (gaps + scored) as f64);
        assert!(note.contains(&share), "{rel}: note {note:?} lacks {share:?}");
    } else {
        assert!(!note.contains("gaps"), "{rel}: note {note:?}");
    }
    let aoe = ours["aoe_deg"].as_f64().unwrap();
    assert!(aoe > expect_aoe.0 && aoe < expect_aoe.1, "{rel}: raw AOE {aoe} outside the measured range {expect_aoe:?}");
}

#[test]
fn euroc_mh04_raw_matches_independent_computation() {
    // toolchain/anchors measurement: raw EuRoC gyro gives AOE ≈ 115–130° on MH_04/V1_03/V2_02.
    check_sequence("euroc/MH_04_difficult", (110.0, 140.0));
}

#[test]
fn tumvi_room4_raw_matches_independent_computation() {
    // Calibrated TUM-VI gyro: 1–3° AOE; room4 has mocap dropouts that must stay gaps.
    check_sequence("tumvi/dataset-room4_512_16", (1.0, 3.0));
}

#[test]
fn static_bias_baseline_beats_raw_on_euroc_v1_03() {
    let Some(data) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("v103.mcap");
    run(Command::new(bin()).arg("import").arg(data.join("euroc/V1_03_difficult")).arg("-o").arg(&bag));
    let raw = eval_json(&bag, dir.path(), "raw")["aoe_deg"].as_f64().unwrap();
    let row = eval_json(&bag, dir.path(), "static-bias");
    let sb = row["aoe_deg"].as_f64().unwrap_or(f64::NAN);
    assert!(sb < raw / 10.0, "static-bias {sb} vs raw {raw}: {row}");
    assert!(row["note"].as_str().unwrap().contains("rest"), "{row}");
}

#[test]
fn oracle_bias_bound_matches_independent_computation() {
    let (Some(data), Some(py)) = (shared_data(), python()) else { return };
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("v202.mcap");
    let seq = data.join("euroc/V2_02_medium");
    run(Command::new(bin()).arg("import").arg(&seq).arg("-o").arg(&bag));
    let json = dir.path().join("o.json");
    run(Command::new(bin()).args(["eval", "--method", "raw", "--oracle-bias", "--json"]).arg(&json).arg(&bag));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    let (raw, ours) = (&v["rows"][0], &v["rows"][1]);
    assert_eq!(ours["method"], "raw − oracle bias", "{v}");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/independent_eval.py");
    let theirs: serde_json::Value = serde_json::from_str(&run(Command::new(py).arg(script).arg(&seq).arg("--oracle-bias"))).unwrap();
    let (a, b) = (ours["aoe_deg"].as_f64().unwrap(), theirs["aoe_deg"].as_f64().unwrap());
    assert!((a - b).abs() <= 1e-3 * b.max(1.0), "oracle AOE: ours {a} independent {b}");
    // The ADIS16448's uncalibrated bias is most of the raw error: the oracle is far below raw.
    assert!(a < raw["aoe_deg"].as_f64().unwrap() / 20.0, "{v}");
    let bias = theirs["bias"].as_array().unwrap();
    let note = ours["note"].as_str().unwrap();
    assert!(note.contains(&format!("{:.5}", bias[2].as_f64().unwrap())), "{note} vs {bias:?}");
}

#[test]
fn import_errors_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(bin()).arg("import").arg(dir.path()).arg("-o").arg(dir.path().join("x.mcap")).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("not an EuRoC or TUM-VI sequence"), "{err}");
    // A path that is not there says so (it read as "not an EuRoC or TUM-VI sequence").
    let out = Command::new(bin()).arg("import").arg(dir.path().join("nowhere")).arg("-o").arg(dir.path().join("x.mcap")).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("nowhere: no such folder"), "{err}");
    // A bag without ground truth cannot be evaluated: a clear error, not a panic.
    let csv_dir = dir.path().join("s/mav0/imu0");
    std::fs::create_dir_all(&csv_dir).unwrap();
    std::fs::write(csv_dir.join("data.csv"), "#timestamp [ns],w_RS_S_x,w_RS_S_y,w_RS_S_z,a_RS_S_x,a_RS_S_y,a_RS_S_z\n1,0,0,0,0,0,9.8\n")
        .unwrap();
    let gt = dir.path().join("s/mav0/mocap0");
    std::fs::create_dir_all(&gt).unwrap();
    std::fs::write(gt.join("data.csv"), "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []\n1,0,0,0,1,0,0,0\n2,0,0,0,bad,0,0,0\n").unwrap();
    let out = Command::new(bin()).arg("import").arg(dir.path().join("s")).arg("-o").arg(dir.path().join("x.mcap")).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("mocap0/data.csv:3"), "{err}");
    assert_eq!(out.status.code(), Some(1));

    // Rows that no recorder writes: a negative stamp (clamped to 0 in the bag before), a row
    // with more fields than the header (accepted before), a single usable sample.
    std::fs::write(gt.join("data.csv"), "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []\n1,0,0,0,1,0,0,0\n9,0,0,0,1,0,0,0\n").unwrap();
    let header = "#timestamp [ns],w_RS_S_x,w_RS_S_y,w_RS_S_z,a_RS_S_x,a_RS_S_y,a_RS_S_z\n";
    let import_fails = |rows: &str, needle: &str| {
        std::fs::write(csv_dir.join("data.csv"), format!("{header}{rows}")).unwrap();
        let out = Command::new(bin()).arg("import").arg(dir.path().join("s")).arg("-o").arg(dir.path().join("x.mcap")).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{rows}: {err}");
        assert!(err.contains(needle), "{rows}: {err}");
    };
    import_fails("-5,0,0,0,0,0,9.8\n5,0,0,0,0,0,9.8\n", "data.csv:2: timestamp -5 ns is negative");
    import_fails("1,0,0,0,0,0,9.8\n5,0,0,0,0,0,9.8,1,2,3\n", "data.csv:3: 10 fields, expected 7");
    // A stamp 5 s back is a clock step, left out (a few ms back is jitter, put back in order).
    import_fails("5000000005,0,0,0,0,0,9.8\n1,0,0,0,0,0,9.8\n", "1 usable IMU sample(s)");
    // The output at the CSV being read: the CSV was replaced by the bag before.
    let source = csv_dir.join("data.csv");
    std::fs::write(&source, format!("{header}1,0,0,0,0,0,9.8\n5,0,0,0,0,0,9.8\n")).unwrap();
    let before = std::fs::read(&source).unwrap();
    let out = Command::new(bin()).arg("import").arg(dir.path().join("s")).arg("-o").arg(&source).output().unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("is also an input"), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(std::fs::read(&source).unwrap(), before);
}
