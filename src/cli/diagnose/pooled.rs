//! `diagnose --real A.mcap --real B.mcap … --noise-model N.yaml -o OUT`: recordings of one IMU,
//! each diagnosed into OUT/<its file name>, then pooled ([`imu_fsda::diagnose::pooled`]):
//! OUT/pooled.json and pooled.md, and a line on stdout.

use anyhow::Context;
use imu_fsda::diagnose::pooled::Pooled;
use imu_fsda::diagnose::DiagnoseOptions;

use super::{diagnose_reporting_failure, DiagnoseArgs};

pub(super) fn run(args: &DiagnoseArgs, opts: &DiagnoseOptions) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.noise_model.is_some() && args.sim.is_none(),
        "several --real recordings are pooled against their own references: give --noise-model, not --sim"
    );
    let mut seen = std::collections::HashSet::new();
    let (mut names, mut fits, mut found, mut failed) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for real in &args.real {
        let name = real.file_stem().map_or_else(|| real.display().to_string(), |s| s.to_string_lossy().into_owned());
        anyhow::ensure!(seen.insert(name.clone()), "two --real recordings named {name}: each is reported in OUT/<its file name>");
        out!("== {name}")?;
        match diagnose_reporting_failure(args, real, &args.out.join(&name), opts) {
            Ok(d) => {
                found.push((name.clone(), d.terms));
                match d.plain {
                    Some(p) => {
                        fits.push(p);
                        names.push(name);
                    }
                    None => failed
                        .push(format!("{name}: no plain calibration (its reference does not excite all three axes, or too few windows)")),
                }
            }
            // One recording that cannot be diagnosed does not lose the others: said, left out.
            Err(e) => {
                tracing::warn!("{}: {e:#}", real.display());
                failed.push(format!("{name}: {}", super::super::error_text(&e)));
            }
        }
    }
    let pooled = Pooled::of(names, &fits).with_context(|| {
        format!("fewer than two recordings to pool ({})", if failed.is_empty() { "none failed".into() } else { failed.join("; ") })
    })?;
    let mut json = pooled.json();
    json["left_out"] = serde_json::json!(failed);
    std::fs::write(args.out.join("pooled.json"), serde_json::to_string_pretty(&json)?)?;
    let mut md = pooled.markdown(&found);
    for f in &failed {
        md += &format!("\nLeft out: {f}\n");
    }
    std::fs::write(args.out.join("pooled.md"), md)?;
    out!("{}", pooled.summary())?;
    for f in &failed {
        out!("left out of the pooling: {f}")?;
    }
    Ok(())
}
