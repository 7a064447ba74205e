//! A seeded random model exported as the node runs one, the EuRoC bag it is replayed on, and the
//! bundled simulated car: shared by tests/replay_cli.rs, tests/eval_cli.rs, tests/cli_contract.rs.

use std::path::{Path, PathBuf};
use std::process::Command;

use imu_fsda::bag::{read_recording, RecordingTopics};
use imu_fsda::model::export::{export_model, ExportInfo};
use imu_fsda::model::{Config, Mode, Net};
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

use super::bin;

/// A seeded model with random weights and EuRoC-like normalisation, exported to `dir`; with
/// `per_imu`, one random Ĉ_ω each for `euroc` and `tumvi`.
pub fn export_random_model(dir: &Path, mode: Mode, seed: i64, per_imu: bool) -> PathBuf {
    export_random_model_with_gains(dir, mode, seed, per_imu, Default::default())
}

/// [`export_random_model`] with per-IMU correction gains in its metadata.
pub fn export_random_model_with_gains(
    dir: &Path,
    mode: Mode,
    seed: i64,
    per_imu: bool,
    imu_correction_gains: std::collections::BTreeMap<String, f64>,
) -> PathBuf {
    tch::manual_seed(seed);
    let vs = VarStore::new(Device::Cpu);
    let imu_calibrations = if per_imu { vec!["euroc".into(), "tumvi".into()] } else { vec![] };
    let net = Net::new(&Config { imu_calibrations, ..Config::for_mode(mode) }, &vs.root()).unwrap();
    if let Some(per_imu) = vs.variables().get("gyro_calib.per_imu") {
        tch::no_grad(|| per_imu.shallow_clone().copy_(&(Tensor::randn([2, 3, 3], (Kind::Float, Device::Cpu)) * 0.02)));
    }
    net.set_normalization(&[0.0, 0.02, 0.08, 9.0, 0.0, -3.0], &[0.3, 0.3, 0.3, 1.0, 1.0, 1.0]).unwrap();
    for _ in 0..2 {
        let _ = net.forward_t(&(Tensor::randn([2, 600, 6], (Kind::Float, Device::Cpu)) * 0.5), true);
    }
    let paths = export_model(dir, "random", &vs, &net, &ExportInfo { imu_correction_gains, ..Default::default() }).unwrap();
    paths.torchscript
}

pub fn euroc_bag(dir: &Path) -> Option<PathBuf> {
    let seq = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/euroc/V1_01_easy");
    if !seq.is_dir() {
        super::skip_or_fail("the EuRoC bag", "../shared/data not found");
        return None;
    }
    let bag = dir.join("v101.mcap");
    let out = Command::new(bin()).arg("import").arg(&seq).arg("-o").arg(&bag).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    Some(bag)
}

/// The bundled simulated car, as read.
pub fn car_recording() -> imu_fsda::core::Recording {
    read_recording(Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap"), &RecordingTopics::default()).unwrap().0
}
