//! The figures of `imu-fsda eval --plot-dir`, `imu-fsda embed` and `imu-fsda diagnose`:
//! PNGs of the stated size, the points beside the t-SNE, a clear error without a font.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;
use common::bin;

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn run(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("spawn");
    assert!(out.status.success(), "{cmd:?} failed:\n{}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    out
}

/// (width, height) from the IHDR chunk, after checking the PNG signature.
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n", "{} is not a PNG", path.display());
    assert_eq!(&b[12..16], b"IHDR");
    (u32::from_be_bytes(b[16..20].try_into().unwrap()), u32::from_be_bytes(b[20..24].try_into().unwrap()))
}

#[test]
fn eval_plot_dir_writes_orientation_and_error_figures() {
    let d = tempfile::tempdir().unwrap();
    let plots = d.path().join("plots");
    run(Command::new(bin())
        .args(["eval", "--method", "raw", "--method", "static-bias", "--model"])
        .arg(repo("models/fsda-f.pt"))
        // Its metadata holds a NaN metric, written by serde_json as null.
        .arg("--model")
        .arg(repo("models/digdl-euroc.pt"))
        .arg("--plot-dir")
        .arg(&plots)
        .arg(repo("test_bags/sim_handheld.mcap")));
    assert_eq!(png_size(&plots.join("sim_handheld_orientation.png")), (1000, 800));
    assert_eq!(png_size(&plots.join("sim_handheld_error.png")), (1000, 900));

    // A cropped evaluation plots the cropped span.
    let cropped = d.path().join("cropped");
    run(Command::new(bin())
        .args(["eval", "--method", "raw", "--start-s", "5", "--end-s", "12", "--plot-dir"])
        .arg(&cropped)
        .arg(repo("test_bags/sim_car.mcap")));
    assert_eq!(png_size(&cropped.join("sim_car_error.png")), (1000, 900));

    // Without a font: a clear error, no panic.
    let out = Command::new(bin())
        .env("IMU_FSDA_FONT", d.path().join("no-such-font.ttf"))
        .args(["eval", "--method", "raw", "--plot-dir"])
        .arg(d.path().join("nofont"))
        .arg(repo("test_bags/sim_handheld.mcap"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("fonts-dejavu-core") && !err.contains("panicked"), "{err}");
}

#[test]
fn embed_writes_png_and_points() {
    let d = tempfile::tempdir().unwrap();
    let png = d.path().join("tsne.png");
    let out = run(Command::new(bin())
        .args(["embed", "--model"])
        .arg(repo("models/fsda-f.pt"))
        .arg("--sequence")
        .arg(repo("test_bags/sim_handheld.mcap"))
        .arg(repo("test_bags/sim_car.mcap"))
        .args(["--points-per-sequence", "80", "--iterations", "300", "--seed", "3", "-o"])
        .arg(&png));
    assert!(String::from_utf8_lossy(&out.stdout).contains("160 points"));
    assert_eq!(png_size(&png), (1000, 750));
    let csv = std::fs::read_to_string(png.with_extension("csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows[0], "sequence,dataset,sample_index,stamp_ns,x,y");
    assert_eq!(rows.len(), 161);
    assert_eq!(rows.iter().filter(|r| r.starts_with("sim_car,bag,")).count(), 80);
    assert!(rows[1..].iter().all(|r| r.split(',').skip(4).all(|v| v.parse::<f64>().is_ok_and(f64::is_finite))));
    let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(png.with_extension("json")).unwrap()).unwrap();
    assert_eq!(j["points"], 160);
    assert_eq!(j["embedding_dim"], 16);

    // Same seed, same map.
    let again = d.path().join("again.png");
    run(Command::new(bin())
        .args(["embed", "--model"])
        .arg(repo("models/fsda-f.pt"))
        .arg("--sequence")
        .arg(repo("test_bags/sim_handheld.mcap"))
        .arg(repo("test_bags/sim_car.mcap"))
        .args(["--points-per-sequence", "80", "--iterations", "300", "--seed", "3", "-o"])
        .arg(&again));
    assert_eq!(csv, std::fs::read_to_string(again.with_extension("csv")).unwrap());

    // Two bags of one file name in two folders are two groups, each named by its path.
    for sub in ["a", "b"] {
        std::fs::create_dir_all(d.path().join(sub)).unwrap();
        std::fs::copy(repo("test_bags/sim_car.mcap"), d.path().join(sub).join("run.mcap")).unwrap();
    }
    // Each group's name → its rows in the CSV, for these bags embedded together.
    let groups = |bags: &[&str]| -> String {
        let twins = d.path().join("twins.png");
        let mut cmd = Command::new(bin());
        cmd.args(["embed", "--model"]).arg(repo("models/fsda-f.pt")).arg("--sequence");
        bags.iter().for_each(|b| {
            cmd.arg(d.path().join(b));
        });
        run(cmd.args(["--points-per-sequence", "20", "--iterations", "100", "-o"]).arg(&twins));
        std::fs::read_to_string(twins.with_extension("csv")).unwrap()
    };
    let rows = |csv: &str, name: &str| csv.lines().filter(|r| r.starts_with(&format!("{name},bag,"))).count();
    let csv = groups(&["a/run.mcap", "b/run.mcap"]);
    for sub in ["a", "b"] {
        assert_eq!(rows(&csv, &d.path().join(sub).join("run.mcap").display().to_string()), 20, "{csv}");
    }
    // One bag given twice: two groups, numbered.
    let csv = groups(&["a/run.mcap", "a/run.mcap"]);
    for k in [1, 2] {
        assert_eq!(rows(&csv, &format!("{} #{k}", d.path().join("a/run.mcap").display())), 20, "{csv}");
    }

    // DIGDL has no Embedding: an error that says so.
    let out = Command::new(bin())
        .args(["embed", "--model"])
        .arg(repo("models/digdl-euroc.pt"))
        .arg("--sequence")
        .arg(repo("test_bags/sim_car.mcap"))
        .arg("-o")
        .arg(d.path().join("digdl.png"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("no Embedding"), "{err}");
}

#[test]
fn diagnose_out_dir_holds_the_figures() {
    let d = tempfile::tempdir().unwrap();
    // The simulator's noise model of the bag (test_bags/sim_handheld.truth.yaml).
    let model = d.path().join("noise.yaml");
    std::fs::write(
        &model,
        "gyro_noise_density: 0.00016\naccel_noise_density: 0.0028\ngyro_bias_random_walk: 0.000022\naccel_bias_random_walk: 0.00086\n",
    )
    .unwrap();
    let out_dir = d.path().join("diag");
    run(Command::new(bin())
        .args(["diagnose", "--noise-model"])
        .arg(&model)
        .arg("--real")
        .arg(repo("test_bags/sim_handheld.mcap"))
        .arg("-o")
        .arg(&out_dir));
    assert_eq!(png_size(&out_dir.join("psd.png")), (1200, 700));
    assert_eq!(png_size(&out_dir.join("allan.png")), (1200, 700));
    assert_eq!(png_size(&out_dir.join("residual.png")), (1200, 800));
    let md = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    for f in ["psd.png", "allan.png", "residual.png"] {
        assert!(md.contains(&format!("]({f})")), "report.md does not show {f}");
    }
    // report.json keeps its structure (session 40 added the verdict, implausible fits and the
    // real recording's stamp artefacts; 2026-12-06 the terms not found with their limits).
    let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).unwrap()).unwrap();
    let mut keys: Vec<&str> = j.as_object().unwrap().keys().map(String::as_str).collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "findings",
            "findings_are",
            "implausible",
            "located",
            "not_found",
            "not_found_rule",
            "not_judged",
            "notes",
            "recording_artefacts",
            "residual_after",
            "residual_before",
            "seconds",
            "selection_steps",
            "verdict"
        ]
    );
    // The simulator's own handheld bag against its own simulation: explained.
    assert_eq!(j["verdict"]["explained"], serde_json::Value::Bool(true), "{}", j["verdict"]);

    // Without a font the diagnosis is still written, and the report says why.
    let out_dir = d.path().join("nofont");
    run(Command::new(bin())
        .env("IMU_FSDA_FONT", d.path().join("no-such-font.ttf"))
        .args(["diagnose", "--noise-model"])
        .arg(&model)
        .arg("--real")
        .arg(repo("test_bags/sim_handheld.mcap"))
        .arg("-o")
        .arg(&out_dir));
    assert!(out_dir.join("report.json").is_file() && !out_dir.join("psd.png").exists());
    assert!(std::fs::read_to_string(out_dir.join("report.md")).unwrap().contains("Figures were not written"));
}
