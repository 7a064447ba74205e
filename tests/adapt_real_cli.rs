//! `imu-fsda adapt` on real recordings, judged on another real power-on of the same IMU:
//! EuRoC's ADIS16448 in V1_01 (support and query) and V1_03 (the other power-on), with a
//! consumer part's scale and cross-axis errors injected into both by `imu-fsda inject` (the
//! truth known). The bundled model is run as on a new IMU (no
//! `--imu`). The lasting error found on one power-on must carry to the other.
//! (Over all ten other EuRoC recordings the calibration alone is kept: docs/poweron.md.)

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;

use common::{bin, manifest_dir, shared_data};
use nalgebra::Matrix3;

const SCALE: [f64; 3] = [0.021, -0.027, 0.014];
const MISALIGNMENT: [[f64; 3]; 3] = [[0.0, 0.012, -0.008], [-0.015, 0.0, 0.010], [0.006, -0.011, 0.0]];

fn output(cmd: &mut Command) -> Output {
    cmd.output().expect("spawn imu-fsda")
}

fn ok(cmd: &mut Command) {
    let o = output(cmd);
    assert!(o.status.success(), "{cmd:?} failed:\n{}", String::from_utf8_lossy(&o.stderr));
}

fn import(data: &Path, seq: &str, dir: &Path) -> PathBuf {
    let bag = dir.join(format!("{seq}.mcap"));
    ok(Command::new(bin()).arg("import").arg(data.join("euroc").join(seq)).arg("-o").arg(&bag));
    bag
}

fn inject(bag: &Path, dir: &Path) -> PathBuf {
    let out = dir.join(format!("injected-{}", bag.file_name().unwrap().to_string_lossy()));
    ok(Command::new(bin())
        .arg("inject")
        .arg(bag)
        .arg("--term")
        .arg(format!("{{term: gyro_scale, scale: {SCALE:?}}}"))
        .arg("--term")
        .arg(format!("{{term: gyro_misalignment, matrix: {MISALIGNMENT:?}}}"))
        .arg("-o")
        .arg(&out));
    out
}

fn bundled_model() -> PathBuf {
    manifest_dir().join("models/fsda-f.pt")
}

/// `adapt --json` on `support`, judged on `others` (none: as the node's `~/adapt`, on the
/// query alone): the report (written also when rejected).
fn adapt(support: &Path, others: &[&Path], out: &Path) -> (serde_json::Value, String) {
    let mut cmd = Command::new(bin());
    cmd.args(["adapt", "--json", "--model"]).arg(bundled_model()).arg("--bag").arg(support).arg("-o").arg(out);
    for other in others {
        cmd.arg("--judge").arg(other);
    }
    let o = output(&mut cmd);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    (serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("no report ({e}):\n{err}")), err)
}

fn matrix(report: &serde_json::Value) -> Matrix3<f64> {
    let m = &report["calibration"]["matrix"];
    Matrix3::from_fn(|r, c| m[r][c].as_f64().unwrap_or_else(|| panic!("no calibration in {report}")))
}

#[test]
fn a_gyro_calibration_learned_on_one_real_power_on_carries_to_another() {
    let Some(data) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (v101, v103) = (import(&data, "V1_01_easy", d), import(&data, "V1_03_difficult", d));
    let (i101, i103) = (inject(&v101, d), inject(&v103, d));
    let out = d.join("injected.pt");
    let (injected, err) = adapt(&i101, &[&i103], &out);

    // Every diagonal entry is determined on V1_01 and reads the injected scale (the inverse
    // of I + E, E = diag(scale) + misalignment) to within the unit's own few tenths of a per
    // cent; an off-diagonal entry is kept only where determined (it then also holds the 1°
    // between the mocap body and the IMU), the rest stay exactly I.
    let e = Matrix3::from_diagonal(&SCALE.into()) + Matrix3::from_fn(|r, c| MISALIGNMENT[r][c]);
    let injected_inverse = (Matrix3::identity() + e).try_inverse().unwrap();
    let found = matrix(&injected);
    let kept = &injected["calibration"]["kept"];
    for r in 0..3 {
        assert_eq!(kept[r][r], true, "the diagonal is determined on V1_01: {injected}");
        for c in 0..3 {
            let (f, identity) = (found[(r, c)], f64::from(u8::from(r == c)));
            if r == c {
                assert!((f - injected_inverse[(r, c)]).abs() < 0.01, "Ĉ_ω[{r}][{c}] = {f}, injected {}\n{err}", injected_inverse[(r, c)]);
            } else if kept[r][c] != true {
                assert!((f - identity).abs() < 1e-9, "Ĉ_ω[{r}][{c}] = {f} not kept, yet not I");
            }
        }
    }

    // Every candidate that passed the query was judged on the other power-on; the plainest
    // that carries over is kept (a richer one only where surely better), and the calibration
    // alone is far better than the rest calibration there.
    assert!(out.exists(), "{err}");
    let aoe = |judged: &serde_json::Value| judged[0]["after"]["aoe_deg"].as_f64().unwrap_or_else(|| panic!("no figures in {injected}"));
    let others = injected["judged_others"].as_array().unwrap_or_else(|| panic!("no judged_others in {injected}"));
    let rank = |kind: &serde_json::Value| ["calibration", "calibration_with_offset", "network"].iter().position(|k| kind == k);
    for other in others {
        let carries =
            other["carry_over"]["ratio"].as_f64().unwrap() < 1.0 && other["carry_over"]["piece_upper_95"].as_f64().is_some_and(|b| b < 1.0);
        assert!(
            !carries || rank(&other["kind"]) > rank(&injected["kind"]),
            "{} carries over and is plainer than the kept {}\n{err}",
            other["kind"],
            injected["kind"]
        );
    }
    let calibration = match others.iter().find(|o| o["kind"] == "calibration") {
        Some(o) => aoe(&o["judged"]),
        None => {
            assert_eq!(injected["kind"], "calibration", "the calibration alone was judged: {injected}");
            aoe(&injected["judged"])
        }
    };
    let pob = injected["judged"][0]["power_on_bias"]["aoe_deg"].as_f64().unwrap();
    assert!(calibration < 0.7 * pob, "V1_03: the calibration alone {calibration}° against the power-on bias {pob}°\n{err}");
}

/// `eval --json` of `model` as deployed (`--model`) and of the power-on bias on `bag`: AOE °.
fn deployed_and_power_on_bias(model: &Path, bag: &Path, dir: &Path) -> (f64, f64) {
    let json = dir.join("eval.json");
    ok(Command::new(bin()).arg("eval").arg(bag).args(["--method", "power-on-bias", "--model"]).arg(model).arg("--json").arg(&json));
    let rows: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = rows["rows"].as_array().unwrap_or_else(|| panic!("no rows in {rows}"));
    let aoe = |pick: &dyn Fn(&serde_json::Value) -> bool| {
        rows.iter().find(|r| pick(r)).and_then(|r| r["aoe_deg"].as_f64()).unwrap_or_else(|| panic!("row not found in {rows:?}"))
    };
    (aoe(&|r| r["method"] != "power-on-bias"), aoe(&|r| r["method"] == "power-on-bias"))
}

/// The user's protocol with nothing to judge on but the support's own power-on (`adapt`
/// without `--judge`, as the node's `~/adapt`): the adapted networks are never what is kept,
/// the calibration is fitted with the rotation between the reference's frame and the IMU's
/// left to the reference, and with the injected errors it is kept and carries to the other
/// power-on. V1_01's ground truth is turned 1.1° from its IMU (the other recordings' ≤ 0.2°):
/// fitted with that rotation, Ĉ_ω held it and was kept, 16 % worse than the power-on bias on
/// the other power-ons (docs/poweron.md); left to the reference, nothing is kept.
#[test]
fn without_another_power_on_only_what_lasts_is_kept() {
    let Some(data) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (v101, v103) = (import(&data, "V1_01_easy", d), import(&data, "V1_03_difficult", d));
    let (i101, i103) = (inject(&v101, d), inject(&v103, d));

    let out = d.join("recorded.pt");
    let (recorded, err) = adapt(&v101, &[], &out);
    let left_out = recorded["calibration_rotation_left_out_deg"].as_f64().unwrap_or_else(|| panic!("no rotation left out: {recorded}"));
    assert!(left_out > 0.8, "V1_01's ground truth is turned {left_out}° from the IMU\n{err}");
    assert!(recorded["kind"].is_null(), "V1_01 as recorded keeps nothing of its own power-on: {}\n{err}", recorded["kind"]);
    assert!(err.contains("left to the reference"), "the refusal says the rotation was left to the reference:\n{err}");
    assert!(!out.exists(), "{err}");

    let out = d.join("injected.pt");
    let (injected, err) = adapt(&i101, &[], &out);
    assert_eq!(injected["kind"], "calibration", "{err}");
    let pieces = &injected["query_calibrated_pieces"];
    assert!(pieces["pieces"].as_u64().unwrap() >= 2 && pieces["upper_95"].as_f64().unwrap() < 1.0, "{pieces}");
    let (adapted, pob) = deployed_and_power_on_bias(&out, &i103, d);
    eprintln!("V1_03 with the injected errors: adapted on V1_01 without a judge {adapted:.3}°, power-on bias {pob:.3}°");
    assert!(adapted < 0.7 * pob, "V1_03: adapted on V1_01 {adapted}° against the power-on bias {pob}°\n{err}");
}

/// EuRoC as recorded: V1_03's bias in flight is off the one its rest measured (the offset its
/// support shows, a few mrad/s). Judged on the three power-ons before it (as the node's
/// `adapt_support_archive` judges), the calibration with that offset carries over piece by
/// piece and is kept, and on a later power-on that neither fitted nor judged it (V2_01) it
/// is better than the power-on bias. The adapted networks are better than the power-on bias
/// on those three too, but not better than the model they started from, which was trained on
/// this IMU: not kept (held out, they were 2–3× the power-on bias). Adapted on V1_03 alone
/// the offset is never kept (within one power-on a lasting offset and a drift look the same).
#[test]
fn a_bias_offset_in_motion_is_kept_only_where_other_power_ons_show_it_lasts() {
    let Some(data) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let support = import(&data, "V1_03_difficult", d);
    let earlier = [import(&data, "MH_05_difficult", d), import(&data, "V1_01_easy", d), import(&data, "V1_02_medium", d)];
    let later = import(&data, "V2_01_easy", d);

    let out = d.join("judged.pt");
    let (judged, err) = adapt(&support, &earlier.iter().map(PathBuf::as_path).collect::<Vec<_>>(), &out);
    assert!(judged["query_calibrated_with_offset"]["aoe_deg"].is_f64(), "the support determines an offset: {judged}");
    assert_eq!(judged["kind"], "calibration_with_offset", "{err}");
    let carry = &judged["carry_over"];
    assert!(carry["recordings"] == 3 && carry["ratio"].as_f64().unwrap() < 1.0, "{carry}");
    assert!(carry["pieces"].as_u64().unwrap() >= 10 && carry["piece_upper_95"].as_f64().unwrap() < 1.0, "{carry}");
    let networks = judged["judged_others"].as_array().unwrap().iter().find(|o| o["kind"] == "network");
    let networks = networks.unwrap_or_else(|| panic!("the networks passed the query and were judged: {judged}"));
    for j in networks["judged"].as_array().unwrap() {
        let (before, pob) = (j["before"]["aoe_deg"].as_f64().unwrap(), j["power_on_bias"]["aoe_deg"].as_f64().unwrap());
        assert_eq!(j["compared_with_deg"].as_f64().unwrap(), before.min(pob), "the networks against the better of the two: {j}");
    }
    let (deployed, pob) = deployed_and_power_on_bias(&out, &later, d);
    eprintln!("V2_01 (held out): adapted on V1_03 with the offset {deployed:.3}°, power-on bias {pob:.3}°");
    assert!(deployed < pob, "V2_01 {deployed}° against {pob}°\n{err}");

    let out = d.join("alone.pt");
    let (alone, err) = adapt(&support, &[], &out);
    assert!(alone["query_calibrated_with_offset"]["aoe_deg"].is_f64(), "{alone}");
    assert_ne!(alone["kind"], "calibration_with_offset", "{err}");
    assert!(err.contains("bias offset in motion"), "the offset and why it is not kept are said:\n{err}");
}
