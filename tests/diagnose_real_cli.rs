//! `imu-fsda diagnose` on a real recording against a simulation of its own motion capture:
//! TUM-VI room2 (a calibrated BMI160, 15.5 s of mocap dropouts in 144 s). The calibrated
//! stream is the control; the "uncalibrated" one is the same samples through a known
//! calibration's inverse (per-axis gyro scale errors of several per cent, cross-axis terms,
//! a gyro bias of tens of mrad/s, an accelerometer bias above 1 m/s²), applied by the physics
//! code. Before the comparison at the reference's bandwidth and the dropouts, both streams
//! read "gyro_scale −28…−52 %, implausible" and the two reports did not differ by the
//! calibration.

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::{bin, shared_data};

use imu_fsda::bag::{read_recording, write_recording, RecordingTopics};
use imu_fsda::physics::{apply_terms, AccelBias, GyroBias, GyroMisalignment, GyroScale, ImuSignals, Term, TermContext};

fn room2() -> Option<PathBuf> {
    shared_data().map(|d| d.join("tumvi/dataset-room2_512_16"))
}

/// room2 imported into `dir` as `room2.mcap` (None where ../shared is not there).
fn imported_room2(dir: &Path) -> Option<PathBuf> {
    let bag = dir.join("room2.mcap");
    run(Command::new(bin()).arg("import").arg(room2()?).arg("-o").arg(&bag));
    Some(bag)
}

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().expect("spawn");
    assert!(out.status.success(), "{cmd:?} failed: {}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

const GYRO_SCALE: [f64; 3] = [0.031, -0.022, 0.042];
const GYRO_BIAS: [f64; 3] = [0.031, -0.047, 0.018];

/// The calibrated recording through the inverse of a calibration: what the sensor gave.
fn uncalibrated(calibrated: &Path, out: &Path) {
    let (rec, _) = read_recording(calibrated, &RecordingTopics::default()).unwrap();
    let n = rec.imu.len();
    let mut s = ImuSignals {
        stamps_ns: rec.imu.iter().map(|x| x.stamp_ns).collect(),
        // The calibration's terms act on the samples alone (no kinematic term here).
        world_from_imu: vec![Default::default(); n],
        alpha_in_imu: vec![Default::default(); n],
        temperature_c: vec![25.0; n],
        gyro: rec.imu.iter().map(|x| x.gyro).collect(),
        accel: rec.imu.iter().map(|x| x.accel).collect(),
    };
    let terms = [
        Term::GyroMisalignment(GyroMisalignment::new([[0.0, 0.004, -0.003], [0.002, 0.0, 0.005], [-0.004, 0.003, 0.0]])),
        Term::GyroScale(GyroScale::new(GYRO_SCALE)),
        Term::GyroBias(GyroBias::new(GYRO_BIAS)),
        Term::AccelBias(AccelBias::new([1.2, -0.4, 0.3])),
    ];
    apply_terms(&terms, &mut s, &mut TermContext::new(0)).unwrap();
    write_recording(out, &imu_fsda::core::Recording { imu: s.to_samples(), ..rec }).unwrap();
}

fn diagnose(dir: &Path, real: &Path, name: &str) -> serde_json::Value {
    diagnose_sensors(dir, real, name, "gyro")
}

/// `diagnose --sensors SENSORS` against the simulation of the bag's own ground truth.
fn diagnose_sensors(dir: &Path, real: &Path, name: &str, sensors: &str) -> serde_json::Value {
    let out = dir.join(name);
    let noise = Path::new(env!("CARGO_MANIFEST_DIR")).join("params/noise/bmi160_tumvi.yaml");
    run(Command::new(bin())
        .args(["diagnose", "--sensors", sensors, "--noise-model"])
        .arg(noise)
        .arg("--real")
        .arg(real)
        .arg("-o")
        .arg(&out));
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

fn vec3(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

/// Every fitted term of a report, plausible or not.
fn fitted(r: &serde_json::Value) -> Vec<serde_json::Value> {
    r["findings"].as_array().unwrap().iter().chain(r["implausible"].as_array().unwrap()).cloned().collect()
}

#[test]
fn a_known_calibration_is_found_on_a_real_recording_and_none_on_the_calibrated_stream() {
    let dir = tempfile::tempdir().unwrap();
    let Some(calibrated) = imported_room2(dir.path()) else { return };
    let raw = dir.path().join("room2_uncalibrated.mcap");
    uncalibrated(&calibrated, &raw);
    // The gyro alone, and both sensors (the default): the accelerometer's reference is the
    // mocap's second derivative, and its terms must not take the gyro's.
    for sensors in ["gyro", "both"] {
        let control = diagnose_sensors(dir.path(), &calibrated, &format!("control_{sensors}"), sensors);
        let artefacts = control["recording_artefacts"].to_string();
        assert!(artefacts.contains("dropouts"), "the reference's dropouts are said: {artefacts}");
        assert!(control["notes"].to_string().contains("compared at the reference's bandwidth"), "{}", control["notes"]);
        let own: Vec<String> = fitted(&control).iter().map(|f| f["term"].as_str().unwrap().to_string()).collect();
        assert!(
            !own.iter().any(|t| t == "gyro_scale" || t == "gyro_bias"),
            "{sensors}: the calibrated stream shows no gyro scale or bias: {own:?}"
        );

        let r = diagnose_sensors(dir.path(), &raw, &format!("uncalibrated_{sensors}"), sensors);
        let terms = fitted(&r);
        let find =
            |name: &str| terms.iter().find(|f| f["term"] == name).unwrap_or_else(|| panic!("{sensors}: no {name} in {terms:#?}")).clone();
        eprintln!(
            "{sensors}: control: {own:?}; uncalibrated: {:#}",
            serde_json::Value::Array(
                terms
                    .iter()
                    .map(|f| serde_json::json!({"term": f["term"], "params": f["params"], "sd": f["uncertainty"], "ci": f["interval_95"]}))
                    .collect()
            )
        );
        let scale = find("gyro_scale");
        assert!(scale.get("implausible").is_none(), "{sensors}: {scale}");
        for (got, want) in vec3(&scale["params"]["scale"]).iter().zip(GYRO_SCALE) {
            assert!((got - want).abs() < 0.2 * want.abs(), "{sensors}: gyro scale {got} for {want}");
        }
        // The stated 95 % intervals hold the calibration's values.
        let ci = scale["interval_95"]["scale"].as_array().unwrap().iter().map(vec3).collect::<Vec<_>>();
        for (lohi, want) in ci.iter().zip(GYRO_SCALE) {
            assert!(lohi[0] <= want && want <= lohi[1], "{sensors}: gyro scale {want} outside the stated interval {lohi:?}");
        }
        // The bias is applied after the scale, in the sensor's output: found as applied.
        for (got, want) in vec3(&find("gyro_bias")["params"]["bias"]).iter().zip(GYRO_BIAS) {
            assert!((got - want).abs() < 0.2 * want.abs(), "{sensors}: gyro bias {got} for {want}");
        }
        assert!(terms.iter().any(|f| f["term"] == "gyro_misalignment"), "{sensors}: {terms:#?}");
        if sensors == "both" {
            assert!(terms.iter().any(|f| f["term"] == "accel_bias"), "both: the accelerometer's bias of 1.2 m/s² is found: {terms:#?}");
        }
        // Beside it in the report, the plain per-axis calibration states the same scale and
        // bias, each within its own 95 % interval of the calibration.
        let plain: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join(format!("uncalibrated_{sensors}/plain_calibration.json"))).unwrap(),
        )
        .unwrap();
        for k in 0..3 {
            let (scale, sd) = (plain["matrix"][k][k].as_f64().unwrap() - 1.0, plain["matrix_sigma"][k][k].as_f64().unwrap());
            assert!((scale - GYRO_SCALE[k]).abs() < 0.2 * GYRO_SCALE[k].abs() && sd < 0.01, "plain scale {k}: {scale} ± {sd}");
            let bias = plain["bias_rad_s"][k].as_f64().unwrap();
            assert!((bias - GYRO_BIAS[k]).abs() < 0.2 * GYRO_BIAS[k].abs(), "plain bias {k}: {bias}");
        }
        let md = std::fs::read_to_string(dir.path().join(format!("uncalibrated_{sensors}/report.md"))).unwrap();
        assert!(md.contains("## Beside it: the plain per-axis calibration"), "{md}");
    }
}

/// The injected-effects score (`scripts/score_diagnosis.sh`'s real set) on one recording:
/// per-axis gyro scales and biases of real parts' sizes, each case with its mirror, are all
/// found, to within 20 % of their effect, and nothing else is reported beyond the control.
#[test]
fn injected_scales_and_biases_are_scored_against_the_control() {
    let dir = tempfile::tempdir().unwrap();
    let Some((s, csv)) = score_injected_on_room2(
        dir.path(),
        &["--sensors", "gyro", "--score-only", "gyro_scale,gyro_bias", "--score-draws", "2", "--seed", "3"],
    ) else {
        return;
    };
    assert_eq!(s["cases"], 4, "{s:#}");
    assert_eq!(s["recall"], 1.0, "{s:#}");
    assert_eq!(s["spurious_terms"], 0, "{s:#}");
    assert_eq!(s["parameters_within_20pct"], 1.0, "{s:#}");
    assert!(csv.lines().any(|l| l.starts_with("room2,control,")), "{csv}");
    // The plain per-axis regression, scored beside it, expresses these terms too.
    let plain = &s["plain_calibration"];
    assert_eq!(plain["recall"], 1.0, "{plain:#}");
    assert_eq!(plain["parameters_within_20pct"], 1.0, "{plain:#}");
}

/// A digital low-pass on the gyro (where real parts' filters sit) is found by the diagnosis as
/// the delay it is at the reference's bandwidth; the plain regression beside it has no term
/// for a delay: it finds nothing of it and reports a cross-axis term of its own instead.
#[test]
fn a_low_pass_is_found_where_the_plain_calibration_cannot_express_it() {
    let dir = tempfile::tempdir().unwrap();
    let Some((s, _)) =
        score_injected_on_room2(dir.path(), &["--sensors", "gyro", "--score-only", "low_pass", "--score-draws", "1", "--seed", "1"])
    else {
        return;
    };
    assert_eq!(s["recall"], 1.0, "{s:#}");
    assert_eq!(s["spurious_terms"], 0, "{s:#}");
    let plain = &s["plain_calibration"];
    assert_eq!(plain["recall"], 0.0, "{plain:#}");
    assert!(std::fs::metadata(dir.path().join("score/plain_cases.csv")).is_ok());
}

/// `diagnose --score-injected` on room2 with `args` (the noise model is the TUM-VI BMI160's):
/// its score.json and cases.csv.
fn score_injected_on_room2(dir: &Path, args: &[&str]) -> Option<(serde_json::Value, String)> {
    let bag = imported_room2(dir)?;
    let out = dir.join("score");
    let noise = Path::new(env!("CARGO_MANIFEST_DIR")).join("params/noise/bmi160_tumvi.yaml");
    run(Command::new(bin())
        .arg("diagnose")
        .args(args)
        .arg("--noise-model")
        .arg(noise)
        .arg("--score-injected")
        .arg(&bag)
        .arg("-o")
        .arg(&out));
    let s = serde_json::from_str(&std::fs::read_to_string(out.join("score.json")).unwrap()).unwrap();
    Some((s, std::fs::read_to_string(out.join("cases.csv")).unwrap()))
}

/// An accelerometer bias injected into room2 (both sensors) brings in the recording's own
/// accelerometer scale, which the control (no bias in its model) leaves under the threshold:
/// counted spurious, and found alike in the mirrored case (the bias's sign turned), so the
/// score says it is the recording's, not made by the injection.
#[test]
fn a_term_the_injection_reveals_is_found_alike_in_the_mirror() {
    let dir = tempfile::tempdir().unwrap();
    let Some((s, csv)) = score_injected_on_room2(dir.path(), &["--score-only", "accel_bias", "--score-draws", "1", "--seed", "1"]) else {
        return;
    };
    assert_eq!(s["recall"], 1.0, "{s:#}");
    assert_eq!(s["parameters_within_20pct"], 1.0, "{s:#}");
    let spurious = s["spurious_terms"].as_u64().unwrap();
    assert!(spurious >= 1, "room2's own accelerometer scale comes in with the bias: {s:#}");
    assert_eq!(s["spurious_alike_in_the_mirror"]["terms"].as_u64(), Some(spurious), "{s:#}");
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == "spurious_alike_in_mirror").unwrap();
    for row in csv.lines().filter(|l| l.starts_with("room2,0")) {
        assert!(row.split(',').nth(col).unwrap().contains("accel_scale"), "{row}");
    }
}

/// A reference on its own clock, 0.5 s behind the IMU (a motion-capture system stamping on
/// its own time base): lined up first and said, so the comparison finds what the recording
/// as stamped finds, not a delay or a scale made of the offset.
#[test]
fn a_reference_half_a_second_late_is_lined_up_and_said() {
    let dir = tempfile::tempdir().unwrap();
    let Some(bag) = imported_room2(dir.path()) else { return };
    let (mut rec, _) = read_recording(&bag, &RecordingTopics::default()).unwrap();
    rec.ground_truth.iter_mut().for_each(|p| p.stamp_ns += 500_000_000);
    let late = dir.path().join("late.mcap");
    write_recording(&late, &rec).unwrap();
    let r = diagnose(dir.path(), &late, "late");
    let artefacts = r["recording_artefacts"].to_string();
    let said = artefacts.split("lag the IMU's by ").nth(1).and_then(|t| t.split(" ms").next()).and_then(|v| v.parse::<f64>().ok());
    assert!(said.is_some_and(|ms| (ms - 500.0).abs() <= 5.0), "the lag is said: {artefacts}");
    // The stamps move by whole IMU samples (100 of 5.016 ms); the remainder is a delay.
    let terms = fitted(&r);
    let names: Vec<&str> = terms.iter().map(|f| f["term"].as_str().unwrap()).collect();
    assert!(names.iter().all(|n| *n == "time_offset"), "nothing but the remainder of the lag: {names:?}");
    let remainder_ms = terms.first().map_or(0.0, |f| f["params"]["seconds"].as_f64().unwrap() * 1e3);
    eprintln!("lag said {said:?} ms, remainder {remainder_ms} ms");
    // Within a fifth of a sample (the recording's own offset against its mocap is ≈ 0.3 ms).
    assert!((said.unwrap() - remainder_ms - 500.0).abs() < 1.0, "lag {said:?} ms and remainder {remainder_ms} ms make 500 ms");
}

/// The ppm a report says the reference's clock drifts by (its recording artefact), if it does.
fn drift_ppm(r: &serde_json::Value) -> Option<(f64, f64)> {
    let artefacts = r["recording_artefacts"].to_string();
    let after = artefacts.split("changes by ").nth(1)?;
    let ppm = after.split(" ppm").next()?.parse().ok()?;
    let sigma = after.split("(± ").nth(1)?.split(',').next()?.parse().ok()?;
    Some((ppm, sigma))
}

/// A reference whose clock drifts: room2's motion capture as recorded drifts against its IMU
/// (≈ −13 ppm, found and taken out), and with another 60 ppm put into its stamps the
/// difference between the two reports is the 60 ppm (the recording's own drift cancels), and
/// the drift becomes no sensor term: the terms fitted are those of the recording as stamped.
#[test]
fn a_drifting_reference_clock_is_found_and_taken_out() {
    let dir = tempfile::tempdir().unwrap();
    let Some(bag) = imported_room2(dir.path()) else { return };
    let (mut rec, _) = read_recording(&bag, &RecordingTopics::default()).unwrap();
    const INJECTED_PPM: f64 = 60.0;
    // A pose stamped later by 60 ppm of its time from the recording's middle (its clock runs
    // fast; about the middle, so that no constant offset comes with it, which is time_offset's).
    let middle = (rec.ground_truth[0].stamp_ns + rec.ground_truth[rec.ground_truth.len() - 1].stamp_ns) / 2;
    rec.ground_truth.iter_mut().for_each(|p| p.stamp_ns += ((p.stamp_ns - middle) as f64 * INJECTED_PPM * 1e-6).round() as i64);
    let drifting = dir.path().join("drifting.mcap");
    write_recording(&drifting, &rec).unwrap();
    let own = diagnose(dir.path(), &bag, "own");
    let r = diagnose(dir.path(), &drifting, "drifting");
    let (Some((own_ppm, own_sigma)), Some((ppm, sigma))) = (drift_ppm(&own), drift_ppm(&r)) else {
        panic!("no drift said: {} / {}", own["recording_artefacts"], r["recording_artefacts"])
    };
    eprintln!("room2's own drift {own_ppm} ± {own_sigma} ppm; with {INJECTED_PPM} ppm injected {ppm} ± {sigma} ppm");
    // The IMU's lag behind a reference stamped late grows: the lag falls by what was injected.
    let found = own_ppm - ppm;
    let sigma = own_sigma.hypot(sigma);
    assert!((found - INJECTED_PPM).abs() < 3.0 * sigma.max(1.0), "found {found} ± {sigma} ppm of {INJECTED_PPM}");
    let names = |r: &serde_json::Value| {
        let mut n: Vec<String> = fitted(r).iter().map(|f| f["term"].as_str().unwrap().to_string()).collect();
        n.sort();
        n
    };
    assert_eq!(names(&r), names(&own), "the drift taken out leaves the recording's own terms: {} / {}", r["findings"], own["findings"]);
}

/// A coarse or a short reference: the same recording with its motion capture kept at 20 Hz
/// (every sixth pose), and its first 20 s alone. The coarse one gives nothing (the smoother
/// widens to hold its poses; before, it read as gyro scales of +0.2 to +1.6 %). The short
/// one may give a delay and nothing else: 20-s pieces of these recordings carry delays of
/// +1.9 to −1.6 ms against their mocap (its clock drifts; the whole recording averages them
/// out), which are the recording's, not made up.
#[test]
fn a_20_hz_or_a_short_reference_gives_no_term_of_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let Some(bag) = imported_room2(dir.path()) else { return };
    let (rec, _) = read_recording(&bag, &RecordingTopics::default()).unwrap();
    let coarse = imu_fsda::core::Recording { ground_truth: rec.ground_truth.iter().step_by(6).copied().collect(), ..rec.clone() };
    let t0 = rec.imu[0].stamp_ns;
    let short = imu_fsda::core::Recording {
        imu: rec.imu.iter().filter(|s| s.stamp_ns < t0 + 20_000_000_000).copied().collect(),
        ground_truth: rec.ground_truth.iter().filter(|s| s.stamp_ns < t0 + 20_000_000_000).copied().collect(),
        ..rec.clone()
    };
    for (name, r, allowed) in [("coarse", coarse, &[][..]), ("short", short, &["time_offset"][..])] {
        let path = dir.path().join(format!("{name}.mcap"));
        write_recording(&path, &r).unwrap();
        let report = diagnose(dir.path(), &path, name);
        let terms: Vec<String> = fitted(&report).iter().map(|f| f["term"].as_str().unwrap().to_string()).collect();
        eprintln!("{name}: {}", report["findings"]);
        assert!(terms.iter().all(|t| allowed.contains(&t.as_str())), "{name}: {terms:?}");
        assert!(report["implausible"].as_array().unwrap().is_empty(), "{name}: {}", report["implausible"]);
    }
}

/// What a report says it did not find is a bound the recording holds to: a gyro scale error
/// injected into room2 at twice the smallest value the control states it shows is found,
/// either sign; at a third of it, it is not (the report's `not_found`, not a claim that the
/// sensor has none).
#[test]
fn the_stated_detection_limit_holds_on_a_real_recording() {
    let dir = tempfile::tempdir().unwrap();
    let Some(bag) = imported_room2(dir.path()) else { return };
    let control = diagnose(dir.path(), &bag, "control");
    let scale = control["not_found"].as_array().unwrap().iter().find(|l| l["term"] == "gyro_scale").cloned();
    let scale = scale.unwrap_or_else(|| panic!("the control states no limit for gyro_scale: {:#}", control["not_found"]));
    let limit = scale["smallest_found"]["gyro_scale.scale[0]"].as_f64().unwrap();
    assert!(limit > 0.0 && limit < 0.02, "room2 shows a gyro x scale from {limit} on: {scale:#}");
    for (k, sign) in [(2.0, 1.0), (2.0, -1.0), (1.0 / 3.0, 1.0), (1.0 / 3.0, -1.0)] {
        let s = sign * k * limit;
        let name = format!("scale-{k:.2}-{sign}");
        let injected = dir.path().join(format!("{name}.mcap"));
        run(Command::new(bin())
            .arg("inject")
            .arg(&bag)
            .args(["--term", &format!("{{term: gyro_scale, scale: [{s}, 0, 0]}}"), "-o"])
            .arg(&injected));
        let r = diagnose(dir.path(), &injected, &name);
        let found = fitted(&r).iter().any(|f| f["term"] == "gyro_scale");
        assert_eq!(found, k > 1.0, "a gyro x scale of {s} against the stated {limit}: found {found}; {:#}", r["findings"]);
    }
}
