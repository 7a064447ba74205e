//! Outputs of a diagnosis: `report.json`, `report.md` (with the PNGs of [`super::figures`]),
//! the CSVs behind the plots, the simulator patch (`patch.yaml`, a list of physics terms in
//! their serde form) and the corrected simulation bag (sim + fitted terms, applied by the
//! physics code).

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Vector3;

use super::align::Aligned;
use super::{DiagnoseError, Diagnosis};
use crate::bag::{BagWriter, GROUND_TRUTH_TOPIC, IMU_FRAME, IMU_TOPIC, TEMPERATURE_TOPIC, WORLD_FRAME};
use crate::msg::{Header, Imu, PoseStamped, Temperature, Time};
use crate::physics::{apply_terms, ImuSignals, Term, TermContext, WhiteNoise};

fn write(path: &Path, text: &str) -> Result<(), DiagnoseError> {
    std::fs::write(path, text).map_err(|source| DiagnoseError::Io { path: path.to_path_buf(), source })
}

/// `report.json`: `{verdict, findings, implausible, located, residual_before, residual_after}`
/// plus context. When `verdict.explained` is false the findings are the best catalogue fit,
/// not a diagnosis (`findings_are`).
pub fn json(d: &Diagnosis) -> serde_json::Value {
    serde_json::json!({
        "recording_artefacts": d.artefacts,
        "verdict": d.verdict,
        "findings_are": if d.verdict.explained { "a diagnosis: the fitted terms explain the recording" } else { "the best catalogue fit, not a diagnosis: the catalogue does not explain the recording (see verdict)" },
        "findings": d.findings,
        "implausible": d.implausible,
        "located": d.located,
        "residual_before": d.residual_before,
        "residual_after": d.residual_after,
        "selection_steps": d.steps,
        "not_judged": d.excluded.iter().map(|(t, why)| serde_json::json!({"term": t, "why": why})).collect::<Vec<_>>(),
        "not_found": d.not_found.iter().map(|l| serde_json::json!({
            "term": l.term,
            "smallest_found": l.smallest_found.iter().map(|(k, v)| (k.clone(), if v.is_finite() { serde_json::json!(v) } else { serde_json::json!("not determined") })).collect::<serde_json::Map<_, _>>(),
        })).collect::<Vec<_>>(),
        "not_found_rule": "a term judged and not found; per parameter, the smallest value this recording shows 19 times in 20 (the others zero, the terms found in the model, σ widened as the findings' are): a sensor's value below it is not ruled out",
        "notes": d.notes,
        "seconds": d.seconds,
    })
}

/// The simulator patch: the fitted terms as the simulator config's `terms:` list, without the
/// implausible ones (no sensor has them), and saying so when the fit does not explain the
/// recording.
pub fn patch_yaml(d: &Diagnosis) -> String {
    let mut s = String::from("# Terms the simulator left out, fitted by `imu-fsda diagnose`; paste under `terms:`.\n");
    if !d.verdict.explained {
        s.push_str("# NOT A DIAGNOSIS: the catalogue does not explain the recording (report.json `verdict`); these are its best fit.\n");
    }
    for f in &d.implausible {
        let _ = writeln!(s, "# left out, implausible: {} ({})", f.term, f.implausible.as_deref().unwrap_or_default());
    }
    let keep: Vec<&Term> = d.terms.iter().filter(|t| !d.implausible.iter().any(|f| f.term == t.name())).collect();
    s.push_str(&serde_yaml::to_string(&keep).unwrap_or_default());
    s
}

/// `report.md`, for a person.
pub fn markdown(d: &Diagnosis) -> String {
    markdown_with_figures(d, None)
}

/// `report.md` with a section showing the figures written beside it (file names), or saying
/// why they could not be written.
pub fn markdown_with_figures(d: &Diagnosis, figures: Option<&Result<Vec<String>, String>>) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Sim-vs-real diagnosis\n");
    inputs_section(&mut s, d);
    verdict_section(&mut s, d);
    findings_section(&mut s, d);
    not_found_section(&mut s, d);
    selection_section(&mut s, d);
    located_section(&mut s, d);
    residual_section(&mut s, d);
    figures_section(&mut s, figures);
    let _ = writeln!(s, "Diagnosis took {:.2} s.", d.seconds);
    s
}

/// What the recordings showed that is not physics: driver artefacts and input notes.
fn inputs_section(s: &mut String, d: &Diagnosis) {
    if !d.artefacts.is_empty() {
        let _ = writeln!(s, "## Recording artefacts (driver / recording, not physics)\n");
        for a in &d.artefacts {
            let _ = writeln!(s, "- {a}");
        }
        s.push('\n');
    }
    if !d.notes.is_empty() {
        let _ = writeln!(s, "## Input notes\n");
        for n in &d.notes {
            let _ = writeln!(s, "- {n}");
        }
        s.push('\n');
    }
}

/// The verdict, and what the fit left unexplained.
fn verdict_section(s: &mut String, d: &Diagnosis) {
    let _ = writeln!(s, "## Verdict\n");
    let _ = writeln!(s, "**{}**\n", d.verdict.statement);
    if !d.verdict.explained {
        let _ = writeln!(s, "Left unexplained after the fit (each block predicted by the fit that did not see it):\n");
        let _ = writeln!(s, "| kind | channel | from | to | statistic | value | z | p |\n|---|---|---|---|---|---|---|---|");
        for l in &d.verdict.located_after {
            let _ = writeln!(
                s,
                "| {} | {} | {:.3} | {:.3} | {} | {:.4} | {:.1} | {:.2e} |",
                l.kind, l.channel, l.from, l.to, l.statistic, l.value, l.z, l.p_value
            );
        }
        s.push('\n');
    }
}

/// The terms found (or the best fit where nothing explains the residual), and those fitted but not plausible.
fn findings_section(s: &mut String, d: &Diagnosis) {
    let heading = if d.verdict.explained { "What was left out" } else { "Best catalogue fit (not a diagnosis)" };
    let _ = writeln!(s, "## {heading}\n");
    if d.findings.is_empty() {
        let _ = writeln!(
            s,
            "{}\n",
            if d.verdict.explained && d.implausible.is_empty() {
                "**Nothing left out**: no term of the catalogue predicts held-out time blocks better than the simulator's own noise model."
            } else {
                "No plausible catalogue term."
            }
        );
    } else {
        let _ = writeln!(s, "| term | parameters | 1σ | 95 % interval | evidence |\n|---|---|---|---|---|");
        for f in &d.findings {
            let _ = writeln!(
                s,
                "| {} | `{}` | `{}` | `{}` | {} |",
                f.term,
                f.params,
                f.uncertainty,
                f.interval_95,
                f.evidence.get("heldout_loglik_gain").map(|g| format!("held-out Δlog L = {g}")).unwrap_or_else(|| f.evidence.to_string())
            );
        }
        s.push('\n');
    }
    if !d.implausible.is_empty() {
        let _ = writeln!(
            s,
            "## Fitted but implausible (not findings)\n\nIn the fit (and the corrected bag), left out of `patch.yaml`: no sensor has these values, so they stand for something the catalogue does not hold.\n"
        );
        let _ = writeln!(s, "| term | parameters | why not plausible |\n|---|---|---|");
        for f in &d.implausible {
            let _ = writeln!(s, "| {} | `{}` | {} |", f.term, f.params, f.implausible.as_deref().unwrap_or_default());
        }
        s.push('\n');
    }
}

/// Per term judged and not found, the smallest value this recording would have shown.
fn not_found_section(s: &mut String, d: &Diagnosis) {
    if !d.not_found.is_empty() {
        let _ = writeln!(
            s,
            "## Judged and not found\n\nThe smallest value of each parameter this recording shows 19 times in 20 (the others zero, the terms found in the model): a sensor's value below it is not ruled out.\n"
        );
        let _ = writeln!(s, "| term | smallest value found 19 times in 20, per parameter |\n|---|---|");
        for l in &d.not_found {
            let limits: Vec<String> = l
                .smallest_found
                .iter()
                .map(|(k, v)| {
                    let name = k.split_once('.').map_or(k.as_str(), |(_, p)| p);
                    if v.is_finite() {
                        format!("{name} {v:.2e}")
                    } else {
                        format!("{name} not determined")
                    }
                })
                .collect();
            let _ = writeln!(s, "| {} | {} |", l.term, limits.join(", "));
        }
        s.push('\n');
    }
}

/// The held-out selection's steps and the terms it could not judge.
fn selection_section(s: &mut String, d: &Diagnosis) {
    let _ = writeln!(s, "## Selection steps\n");
    for st in &d.steps {
        let _ = writeln!(
            s,
            "- {} `{}`: held-out Δlog L = {:.1}{}",
            st.action,
            st.term,
            st.heldout_gain,
            st.runner_up.as_ref().map(|(t, g)| format!(" (runner-up `{t}`: {g:.1})")).unwrap_or_default()
        );
    }
    for (t, why) in &d.excluded {
        let _ = writeln!(s, "- not judged: `{t}` ({why})");
    }
}

/// Where the residual of the no-term model differs, by kind, channel and span.
fn located_section(s: &mut String, d: &Diagnosis) {
    let _ = writeln!(s, "\n## Where the residual differs (no-term model)\n");
    if d.located.is_empty() {
        let _ = writeln!(s, "Nowhere beyond the simulator's noise model (α = {} family-wise per kind).", super::locate::ALPHA);
    } else {
        let _ = writeln!(s, "| kind | channel | from | to | statistic | value | z | p |\n|---|---|---|---|---|---|---|---|");
        for l in &d.located {
            let _ = writeln!(
                s,
                "| {} | {} | {:.3} | {:.3} | {} | {:.4} | {:.1} | {:.2e} |",
                l.kind, l.channel, l.from, l.to, l.statistic, l.value, l.z, l.p_value
            );
        }
    }
}

/// The residual before and after the fit, on the held-out blocks.
fn residual_section(s: &mut String, d: &Diagnosis) {
    let _ = writeln!(s, "\n## Residual before and after (held-out blocks)\n");
    let _ = writeln!(s, "| channel | RMS before | RMS after | χ²/n before | χ²/n after |\n|---|---|---|---|---|");
    for (k, v) in &d.residual_before.rms {
        let _ = writeln!(
            s,
            "| {k} | {v:.4e} | {:.4e} | {:.3} | {:.3} |",
            d.residual_after.rms.get(k).copied().unwrap_or(f64::NAN),
            d.residual_before.chi2_per_sample.get(k).copied().unwrap_or(f64::NAN),
            d.residual_after.chi2_per_sample.get(k).copied().unwrap_or(f64::NAN)
        );
    }
    let _ = writeln!(
        s,
        "\nHeld-out log-likelihood: before {:.1}, after {:.1}.\n",
        d.residual_before.heldout_loglik, d.residual_after.heldout_loglik
    );
    let _ = writeln!(s, "Curves: `allan.csv` (Allan deviation before/after and the noise model's), `psd.csv` (Welch PSD before/after).\n");
}

/// The figures written beside the report, or why they could not be.
fn figures_section(s: &mut String, figures: Option<&Result<Vec<String>, String>>) {
    match figures {
        Some(Ok(files)) if !files.is_empty() => {
            let _ = writeln!(s, "## Figures\n");
            for f in files {
                let caption = match f.as_str() {
                    "psd.png" => "Residual PSD per channel, before and after the fitted terms; located frequency bands shaded",
                    "allan.png" => "Residual Allan deviation per channel, before and after, with the fitted noise model's prediction",
                    "residual.png" => "Residual over time per sensor (block means), before and after; located time segments shaded",
                    _ => "",
                };
                let _ = writeln!(s, "![{caption}]({f})\n\n*{caption}.*\n");
            }
        }
        Some(Err(why)) => {
            let _ = writeln!(s, "Figures were not written: {why}\n");
        }
        _ => {}
    }
}

/// The CSVs behind the plots.
pub fn write_csvs(dir: &Path, d: &Diagnosis) -> Result<(), DiagnoseError> {
    let mut a = String::from("channel,tau_s,before,after,noise_model\n");
    for (c, rows) in d.curves.allan.iter().enumerate() {
        for (k, (tau, b, af)) in rows.iter().enumerate() {
            let m = d.curves.allan_model[c].get(k).map_or(f64::NAN, |x| x.1);
            let _ = writeln!(a, "{},{tau:.6},{b:.6e},{af:.6e},{m:.6e}", super::residual::CHANNELS[c]);
        }
    }
    write(&dir.join("allan.csv"), &a)?;
    let mut p = String::from("channel,freq_hz,before,after\n");
    for (c, rows) in d.curves.psd.iter().enumerate() {
        for (f, b, af) in rows {
            let _ = writeln!(p, "{},{f:.6},{b:.6e},{af:.6e}", super::residual::CHANNELS[c]);
        }
    }
    write(&dir.join("psd.csv"), &p)?;
    let mut r = String::from("channel,rms_before,rms_after\n");
    for (k, v) in &d.residual_before.rms {
        let _ = writeln!(r, "{k},{v:.6e},{:.6e}", d.residual_after.rms.get(k).copied().unwrap_or(f64::NAN));
    }
    write(&dir.join("residual_rms.csv"), &r)
}

/// The sim signals as read (not smoothed), with the diagnosis' attitude, ω̇ and temperature.
fn raw_sim_signals(a: &Aligned, d: &Diagnosis) -> ImuSignals {
    let v3 = |ch: &[Vec<f64>], i: usize| Vector3::new(ch[0][i], ch[1][i], ch[2][i]);
    let n = a.len();
    ImuSignals { gyro: (0..n).map(|i| v3(&a.sim[..3], i)).collect(), accel: (0..n).map(|i| v3(&a.sim[3..], i)).collect(), ..d.base.clone() }
}

/// Sim + fitted terms. The noise-density term becomes extra white noise of the missing
/// variance (the corrected bag's own noise is the sim's, already drawn).
pub fn corrected_signals(a: &Aligned, d: &Diagnosis, seed: u64) -> Result<ImuSignals, DiagnoseError> {
    let mut s = raw_sim_signals(a, d);
    let dt = a.dt();
    let terms: Vec<Term> = d
        .terms
        .iter()
        .filter_map(|t| match t {
            Term::GyroNoiseDensity(g) => {
                let extra = (g.factor * g.factor - 1.0).max(0.0) * a.sim_variance.0;
                (extra > 0.0).then(|| Term::WhiteNoise(WhiteNoise { gyro_noise_density: (extra * dt).sqrt(), accel_noise_density: 0.0 }))
            }
            other => Some(other.clone()),
        })
        .collect();
    apply_terms(&terms, &mut s, &mut TermContext::new(seed))?;
    Ok(s)
}

/// Write the corrected simulation bag: the sim bag's topics with `/imu/data` replaced by
/// sim + fitted terms (covariances kept).
pub fn write_corrected_bag(path: &Path, a: &Aligned, d: &Diagnosis) -> Result<(), DiagnoseError> {
    let s = corrected_signals(a, d, 1)?;
    let mut w = BagWriter::create(path)?;
    let imu_ch = w.channel::<Imu>(IMU_TOPIC)?;
    let gt_ch = w.channel::<PoseStamped>(GROUND_TRUTH_TOPIC)?;
    let rec = &a.sim_recording;
    let mut msg = Imu::from_sample(&crate::core::ImuSample { stamp_ns: s.stamps_ns[0], gyro: s.gyro[0], accel: s.accel[0] }, IMU_FRAME);
    for i in [0, 4, 8] {
        msg.angular_velocity_covariance.0[i] = a.sim_variance.0;
        msg.linear_acceleration_covariance.0[i] = a.sim_variance.1;
    }
    for i in 0..s.len() {
        msg.header.stamp = Time::from_ns(s.stamps_ns[i]);
        msg.angular_velocity = s.gyro[i].into();
        msg.linear_acceleration = s.accel[i].into();
        w.write(imu_ch, s.stamps_ns[i], &msg)?;
    }
    for p in &rec.ground_truth {
        w.write(gt_ch, p.stamp_ns, &PoseStamped::from_sample(p, WORLD_FRAME))?;
    }
    if !rec.temperature.is_empty() {
        let ch = w.channel::<Temperature>(TEMPERATURE_TOPIC)?;
        for t in &rec.temperature {
            w.write(
                ch,
                t.stamp_ns,
                &Temperature {
                    header: Header { stamp: Time::from_ns(t.stamp_ns), frame_id: IMU_FRAME.into() },
                    temperature: t.celsius,
                    variance: 0.0,
                },
            )?;
        }
    }
    Ok(w.finish()?)
}

/// Every file [`write_all`] writes into its directory (figures included).
pub const FILES: &[&str] = &[
    "report.json",
    "report.md",
    "patch.yaml",
    "allan.csv",
    "psd.csv",
    "residual_rms.csv",
    "psd.png",
    "allan.png",
    "residual.png",
    "corrected_sim.mcap",
    "plain_calibration.json",
];

/// Write everything into `dir` (the files of [`FILES`]).
pub fn write_all(dir: &Path, a: &Aligned, d: &Diagnosis) -> Result<(), DiagnoseError> {
    crate::core::create_dir_all(dir).map_err(|source| DiagnoseError::Io { path: dir.to_path_buf(), source })?;
    write(&dir.join("report.json"), &serde_json::to_string_pretty(&json(d)).unwrap_or_default())?;
    // Figures are an extra: without a font the diagnosis is still written, and says why.
    let figures = super::figures::write_figures(dir, d)
        .map(|paths| paths.iter().filter_map(|p| p.file_name()).map(|f| f.to_string_lossy().into_owned()).collect())
        .map_err(|e| {
            tracing::warn!("diagnosis figures not written: {e}");
            e.to_string()
        });
    write(&dir.join("report.md"), &markdown_with_figures(d, Some(&figures)))?;
    write(&dir.join("patch.yaml"), &patch_yaml(d))?;
    write_csvs(dir, d)?;
    write_corrected_bag(&dir.join("corrected_sim.mcap"), a, d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::{align, diagnose, DiagnoseOptions};
    use crate::physics::{apply_terms, GyroBias, TermContext};
    use crate::sim::{simulate, Grade, Profile, SimConfig};

    const LEFT_OUT: [f64; 3] = [0.02, -0.012, 0.015];

    /// A simulated hand-held minute against the same motion measured with another noise draw
    /// and a gyro bias the simulation left out, diagnosed.
    fn diagnosed() -> (Aligned, Diagnosis) {
        let cfg =
            SimConfig { profile: Profile::Handheld, grade: Grade::Mpu9250, rate_hz: 200.0, seconds: 60.0, seed: 11, ..Default::default() };
        let sim = simulate(&cfg).unwrap();
        let mut real = sim.ideal.clone();
        let mut terms = cfg.noise().terms().to_vec();
        terms.push(Term::GyroBias(GyroBias::new(LEFT_OUT)));
        apply_terms(&terms, &mut real, &mut TermContext::new(99)).unwrap();
        let real = crate::core::Recording { imu: real.to_samples(), ..sim.recording.clone() };
        let a = align::align(sim.recording.clone(), real, Some(sim.imu_variance), vec![]).unwrap();
        let d = diagnose(&a, &DiagnoseOptions::default()).unwrap();
        (a, d)
    }

    fn patched_terms(d: &Diagnosis) -> Vec<Term> {
        serde_yaml::from_str(&patch_yaml(d)).unwrap()
    }

    #[test]
    fn the_report_says_the_verdict_first_and_the_patch_holds_what_was_found() {
        let (_, d) = diagnosed();
        let j = json(&d);
        let found: Vec<&str> = j["findings"].as_array().unwrap().iter().map(|f| f["term"].as_str().unwrap()).collect();
        assert!(found.contains(&"gyro_bias"), "{j:#}");
        let md = markdown(&d);
        let (verdict, findings) =
            (md.find("## Verdict").unwrap(), md.find("## What was left out").or(md.find("## Best catalogue fit")).unwrap());
        assert!(verdict < findings, "{md}");
        let bias = patched_terms(&d).into_iter().find_map(|t| if let Term::GyroBias(b) = t { Some(b.bias) } else { None }).unwrap();
        for (got, want) in bias.iter().zip(LEFT_OUT) {
            assert!((got - want).abs() < 0.2 * want.abs(), "patched bias {got} for {want}");
        }
    }

    #[test]
    fn a_fit_that_does_not_explain_and_an_implausible_term_are_said_in_every_output() {
        let (_, mut d) = diagnosed();
        d.verdict.explained = false;
        assert!(json(&d)["findings_are"].as_str().unwrap().contains("not a diagnosis"));
        assert!(patch_yaml(&d).contains("NOT A DIAGNOSIS"));
        assert!(markdown(&d).contains("Best catalogue fit (not a diagnosis)"));
        // A finding judged implausible: listed as such and left out of the simulator patch.
        let k = d.findings.iter().position(|f| f.term == "gyro_bias").unwrap();
        let mut f = d.findings.remove(k);
        f.implausible = Some("beyond every datasheet".into());
        d.implausible.push(f);
        let patch = patch_yaml(&d);
        assert!(patch.contains("# left out, implausible: gyro_bias (beyond every datasheet)"), "{patch}");
        assert!(!patched_terms(&d).iter().any(|t| t.name() == "gyro_bias"), "{patch}");
    }

    #[test]
    fn every_file_is_written_and_the_corrected_bag_reads_back() {
        let (a, d) = diagnosed();
        let dir = tempfile::tempdir().unwrap();
        write_all(dir.path(), &a, &d).unwrap();
        // The figures need a font and are an extra; plain_calibration.json is the CLI's.
        for name in FILES.iter().filter(|n| !n.ends_with(".png") && **n != "plain_calibration.json") {
            assert!(dir.path().join(name).is_file(), "{name} missing");
        }
        let (corrected, _) =
            crate::bag::read_recording(dir.path().join("corrected_sim.mcap"), &crate::bag::RecordingTopics::default()).unwrap();
        assert_eq!(corrected.imu.len(), a.stamps_ns.len());
        // The corrected sim carries the bias found: its gyro mean moves toward the real's.
        let mean = |s: &[crate::core::ImuSample]| s.iter().map(|x| x.gyro).sum::<nalgebra::Vector3<f64>>() / s.len() as f64;
        let (before, after) = (mean(&a.sim_recording.imu), mean(&corrected.imu));
        for (k, want) in LEFT_OUT.iter().enumerate() {
            let moved = (after - before)[k];
            assert!((moved - want).abs() < 0.2 * want.abs(), "axis {k}: {moved} for {want}");
        }
    }
}
