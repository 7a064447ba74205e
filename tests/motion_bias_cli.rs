//! The bias seen in motion before its model check (`standstill.motion.apply_before_check`): a
//! real multirotor that starts moving (EuRoC's MH_01, its ADIS16448's 80 mrad/s turn-on bias
//! unremoved until its first standstill at 21 s) gets the bias across up removed within
//! seconds; a simulated car, whose sustained accelerations the filter takes for a bias until
//! its check refuses them, is why the switch is off by default and on only for the platforms
//! that declare it (`pipeline.platform: multirotor | legged | handheld`).

use std::ffi::OsStr;
use std::path::Path;
use std::process::Command;

mod common;

use common::{bin, eval_power_on_bias, ok, shared_data};

/// `eval --method power-on-bias` on `bag` (with `params`, if given): (AOE °, tilt RMS °).
fn power_on_bias(bag: &Path, params: Option<&Path>, dir: &Path) -> (f64, f64) {
    let extra: Vec<&OsStr> = params.map(|p| vec![OsStr::new("--params"), p.as_os_str()]).unwrap_or_default();
    let row = eval_power_on_bias(bag, &extra, dir);
    let deg = |k: &str| row[k].as_f64().unwrap_or_else(|| panic!("no {k}: {row}"));
    (deg("aoe_deg"), deg("tilt_rmse_deg"))
}

fn before_check_params(dir: &Path) -> std::path::PathBuf {
    let p = dir.join("before_check.yaml");
    std::fs::write(
        &p,
        "imu_fsda:\n  ros__parameters:\n    pipeline:\n      standstill:\n        motion:\n          apply_before_check: true\n",
    )
    .unwrap();
    p
}

/// A parameter file that declares what carries the IMU (`pipeline.platform`).
fn platform_params(dir: &Path, platform: &str) -> std::path::PathBuf {
    let p = dir.join(format!("{platform}.yaml"));
    std::fs::write(&p, format!("imu_fsda:\n  ros__parameters:\n    pipeline:\n      platform: {platform}\n")).unwrap();
    p
}

#[test]
fn a_multirotor_that_starts_moving_has_its_bias_removed_before_the_check() {
    let Some(data) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let bag = d.join("MH_01_easy.mcap");
    ok(Command::new(bin()).arg("import").arg(data.join("euroc/MH_01_easy")).arg("-o").arg(&bag));
    let (waits, _) = power_on_bias(&bag, None, d);
    let (applies, _) = power_on_bias(&bag, Some(&before_check_params(d)), d);
    let (declared, _) = power_on_bias(&bag, Some(&platform_params(d, "multirotor")), d);
    eprintln!(
        "MH_01_easy: power-on bias {waits:.2}° waiting for the check, {applies:.2}° applying before it, {declared:.2}° declared a multirotor"
    );
    assert!(applies < 0.8 * waits, "{applies}° before the check against {waits}° after it");
    assert_eq!(declared, applies, "`platform: multirotor` is the switch");
}

#[test]
fn a_car_that_starts_moving_is_why_the_switch_is_off_by_default() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let bag = d.join("car.mcap");
    ok(Command::new(bin())
        .args(["simulate", "--profile", "car", "--grade", "adis16448", "--datasheet-errors", "--seconds", "60"])
        .args(["--seed", "11", "--power-on", "12", "--rest-s", "0", "-o"])
        .arg(&bag));
    let (_, waits) = power_on_bias(&bag, None, d);
    let (_, applies) = power_on_bias(&bag, Some(&before_check_params(d)), d);
    let (_, declared) = power_on_bias(&bag, Some(&platform_params(d, "car")), d);
    eprintln!(
        "car, ADIS16448, no rest: tilt {waits:.2}° waiting for the check, {applies:.2}° applying before it, {declared:.2}° declared a car"
    );
    assert_eq!(declared, waits, "a car declared as one waits for the check");
    assert!(applies > 1.2 * waits, "{applies}° before the check against {waits}° after it");
}
