//! The turn-on bias remembered across power-ons (`imu-fsda bias-memory`, `eval --bias-memory`,
//! the node's `power_on_bias_memory`): on real recordings of one IMU whose bias repeats
//! (EuRoC's ADIS16448), a recording that starts moving gets its bias removed from the first
//! sample; on simulated power-ons of a consumer part, whose turn-on bias is drawn anew each
//! time, nothing is predicted and nothing changes.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::{bin, eval_power_on_bias, ok, shared_data};

fn import(data: &Path, seq: &str, dir: &Path) -> PathBuf {
    let bag = dir.join(format!("{seq}.mcap"));
    ok(Command::new(bin()).arg("import").arg(data.join("euroc").join(seq)).arg("-o").arg(&bag));
    bag
}

/// `eval --method power-on-bias` on `bag` (with `memory`, if given): (AOE °, the row's note).
fn power_on_bias(bag: &Path, memory: Option<&Path>, dir: &Path) -> (f64, String) {
    let extra: Vec<&OsStr> = memory.map(|m| vec![OsStr::new("--bias-memory"), m.as_os_str()]).unwrap_or_default();
    let row = eval_power_on_bias(bag, &extra, dir);
    (row["aoe_deg"].as_f64().unwrap_or_else(|| panic!("no AOE: {row}")), row["note"].as_str().unwrap_or_default().to_string())
}

#[test]
fn a_bias_that_repeats_is_removed_before_the_first_standstill_of_the_next_power_on() {
    let Some(data) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let earlier: Vec<PathBuf> = ["V1_01_easy", "V1_02_medium", "V2_01_easy"].iter().map(|s| import(&data, s, d)).collect();
    let memory = d.join("imu/bias.json");
    let said = ok(Command::new(bin()).arg("bias-memory").args(&earlier).arg("-o").arg(&memory));
    assert!(said.contains("3 power-ons"), "{said}");
    // MH_02 starts moving: its first standstill comes late.
    let mh02 = import(&data, "MH_02_easy", d);
    let (without, _) = power_on_bias(&mh02, None, d);
    let (with, note) = power_on_bias(&mh02, Some(&memory), d);
    eprintln!("MH_02_easy: power-on bias {without:.2}°, with 3 earlier power-ons remembered {with:.2}° ({note})");
    assert!(note.contains("before the first standstill") && note.contains("from 3 earlier power-ons"), "{note}");
    assert!(with < 0.5 * without, "{with}° with the memory against {without}° without");
    // A recording that starts at rest: its own standstill rules within a second.
    let (rest_without, _) = power_on_bias(&earlier[0], None, d);
    let (rest_with, _) = power_on_bias(&earlier[0], Some(&memory), d);
    assert!((rest_with - rest_without).abs() < 0.05 * rest_without, "V1_01: {rest_with}° against {rest_without}°");
}

#[test]
fn a_turn_on_bias_drawn_anew_each_power_on_is_not_predicted() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let bags: Vec<PathBuf> = (1..=4)
        .map(|k| {
            let bag = d.join(format!("p{k}.mcap"));
            let k = k.to_string();
            ok(Command::new(bin())
                .args(["simulate", "--profile", "handheld", "--grade", "mpu-9250", "--seconds", "40", "--seed", "3", "--power-on", &k])
                .args(["--rest-s", "2", "-o"])
                .arg(&bag));
            bag
        })
        .collect();
    let memory = d.join("bias.json");
    ok(Command::new(bin()).arg("bias-memory").args(&bags[..3]).arg("-o").arg(&memory));
    let (without, _) = power_on_bias(&bags[3], None, d);
    let (with, note) = power_on_bias(&bags[3], Some(&memory), d);
    assert!(note.contains("3 earlier power-ons do not predict"), "{note}");
    assert_eq!(with, without, "{note}");
    // A file that is not a bias memory is an error that names it.
    std::fs::write(&memory, "{").unwrap();
    let o =
        Command::new(bin()).arg("eval").arg(&bags[3]).args(["--method", "power-on-bias", "--bias-memory"]).arg(&memory).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("is not a bias memory"), "{err}");
}
