//! Sim-vs-real diagnosis: locate where a real recording differs from its simulation beyond
//! the simulator's noise model, name the physics the simulator left out (the vocabulary of
//! [`crate::physics`]), fit it, and show the fit improve on held-out time blocks.
//!
//! The pipeline, one module per concern:
//! 1. [`align`]: load both bags, put the real stream on the sim stamps, read the sim's
//!    white-noise variance from its covariance fields; [`frame`]: a gross rotation between
//!    the two frames taken out first (a mirror image refused);
//! 2. [`residual`]: r = real − sim, its noise model (white + an estimated bias walk) and the
//!    Kalman whitening that makes generalised least squares of any regressor cheap;
//! 3. [`locate`]: per axis, time segment and frequency band, χ² and band-power statistics;
//!    [`adequacy`]: the same tests after the fit, the verdict whether the terms explain it;
//! 4. [`catalogue`]: the candidate terms as regressors built by the physics terms themselves;
//! 5. [`select`]: greedy forward/backward selection on held-out log-likelihood ([`fit`]);
//! 6. [`report`]: `report.json`, `report.md`, CSVs, the simulator patch and the corrected bag;
//!    [`figures`]: the PNGs the report shows (PSD, Allan deviation, residual over time).
//!
//! [`plain_calibration`] is the yardstick beside it: the per-axis least-squares calibration
//! (`ω_imu ≈ A ω_ref + b`) every calibration tool starts from, scored on the same cases.
//!
//! ```no_run
//! use imu_fsda::diagnose::{diagnose_bags, DiagnoseOptions};
//! let (aligned, d) = diagnose_bags("sim.mcap".as_ref(), "real.mcap".as_ref(), &DiagnoseOptions::default()).unwrap();
//! for f in &d.findings {
//!     println!("{}: {}", f.term, f.params);
//! }
//! # let _ = aligned;
//! ```

pub mod adequacy;
pub mod align;
pub mod allan;
pub mod bandwidth;
pub mod catalogue;
pub mod detection;
pub mod figures;
pub mod findings;
pub mod fit;
pub mod frame;
pub mod golden;
pub mod kinematics;
pub mod locate;
pub mod plain_calibration;
pub mod pooled;
pub mod psd;
pub mod reference_clock;
pub mod report;
pub mod residual;
pub mod select;

use std::path::{Path, PathBuf};

use nalgebra::{DVector, UnitQuaternion};
use serde::Serialize;

use crate::physics::{ImuSignals, PhysicsError, Term};
use align::Aligned;
use catalogue::Catalogue;
use locate::Located;
use residual::{base_signals, ChannelNoise, ResidualNoise, CHANNELS};
use select::{Problem, SelectOptions, Selection};

/// Errors of the diagnosis.
#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    #[error(transparent)]
    Bag(#[from] crate::bag::BagError),
    #[error("physics: {0}")]
    Physics(#[from] PhysicsError),
    #[error("input: {0}")]
    Input(String),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// Options of a diagnosis.
#[derive(Debug, Clone, Copy)]
pub struct DiagnoseOptions {
    /// Half of the half-width of the Savitzky–Golay derivative of the sim gyro (used for ω̇
    /// when there is no ground truth), s.
    pub half_window_s: f64,
    /// Largest half-width of the leave-centre-out smoother of the sim signals, s (the
    /// window itself is chosen by cross-validation, `residual::cv_smoother`).
    pub max_smoothing_s: f64,
    /// Model selection.
    pub select: SelectOptions,
    /// The sensors judged: with one sensor only, the other's channels are left out of the
    /// residual and every candidate term is restricted to the judged sensor's channels.
    pub sensors: Sensors,
    /// Half-width (s) of the local cubic the ground truth is smoothed by before ω̇ is taken
    /// from it for the regressors: for a measured ground truth (`--noise-model` on a real
    /// bag); `None` (a simulator's noise-free ground truth) differentiates sample to sample.
    pub gt_smoothing_s: Option<f64>,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        DiagnoseOptions {
            half_window_s: 0.01,
            max_smoothing_s: 0.05,
            select: SelectOptions::default(),
            sensors: Sensors::Both,
            gt_smoothing_s: None,
        }
    }
}

/// Which sensors a diagnosis judges.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Sensors {
    /// Gyroscope and accelerometer.
    #[default]
    Both,
    /// The gyroscope alone (e.g. when the simulated accelerometer is not trusted: a real
    /// bag's ground truth differentiated twice).
    Gyro,
    /// The accelerometer alone.
    Accel,
}

impl Sensors {
    /// Is sensor `s` (0 gyro, 1 accel) judged?
    pub fn judges(self, s: usize) -> bool {
        matches!((self, s), (Sensors::Both, _) | (Sensors::Gyro, 0) | (Sensors::Accel, 1))
    }

    pub fn name(self) -> &'static str {
        match self {
            Sensors::Both => "both",
            Sensors::Gyro => "gyro",
            Sensors::Accel => "accel",
        }
    }
}

/// One named left-out term, as `report.json` writes it.
#[derive(Debug, Clone, Serialize)]
pub struct Finding {
    pub term: String,
    pub params: serde_json::Value,
    /// 1-σ uncertainty of each parameter, same layout as `params` where it applies: the GLS
    /// covariance's, widened by √(χ²/n) of the residual after the fit where that exceeds 1
    /// (a noise model the residual does not meet understates every σ by that much).
    pub uncertainty: serde_json::Value,
    /// [low, high] per parameter, ±1.96 σ (`uncertainty`): to put beside a datasheet.
    #[serde(skip_serializing_if = "serde_json::Value::is_null")]
    pub interval_95: serde_json::Value,
    pub evidence: serde_json::Value,
    /// Why the fitted value is not physically plausible (a term in `Diagnosis::implausible`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub implausible: Option<String>,
}

/// Residual figures before or after the fitted terms.
#[derive(Debug, Clone, Serialize, Default)]
pub struct ResidualSummary {
    /// RMS per channel (rad/s, m/s²).
    pub rms: std::collections::BTreeMap<String, f64>,
    /// Mean squared whitened residual per channel (1 when the noise model explains it).
    pub chi2_per_sample: std::collections::BTreeMap<String, f64>,
    /// Held-out log-likelihood, whitened units.
    pub heldout_loglik: f64,
    /// Held-out: "after" residuals are predictions from fits that did not see the block.
    pub note: String,
}

/// Series behind the plots, per channel.
#[derive(Debug, Clone, Default)]
pub struct Curves {
    /// (τ, before, after) per channel.
    pub allan: Vec<Vec<(f64, f64, f64)>>,
    /// (f, before, after) per channel.
    pub psd: Vec<Vec<(f64, f64, f64)>>,
    /// Allan deviation the noise model predicts, per channel (τ, σ).
    pub allan_model: Vec<Vec<(f64, f64)>>,
    /// Block centres (s since the first sample) of the residual block means below.
    pub residual_t: Vec<f64>,
    /// Residual block means per channel, before (real − sim) and after (held-out prediction
    /// of the fitted terms removed); NaN where a block has no unmasked sample.
    pub residual_before: [Vec<f64>; 6],
    pub residual_after: [Vec<f64>; 6],
}

/// A diagnosis.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub notes: Vec<String>,
    /// Stamp artefacts of the real stream (driver / recording, not physics), before any fit.
    pub artefacts: Vec<String>,
    /// The fitted terms whose values are physically plausible.
    pub findings: Vec<Finding>,
    /// Fitted terms outside their plausible range ([`catalogue::PLAUSIBLE`]): in the fit (and
    /// `terms`), not findings.
    pub implausible: Vec<Finding>,
    /// Whether the fit explains the recording ([`adequacy`]).
    pub verdict: adequacy::Verdict,
    /// Every fitted term (the corrected bag and the before/after residual are this fit; the
    /// simulator patch leaves out the implausible ones).
    pub terms: Vec<Term>,
    pub located: Vec<Located>,
    pub residual_before: ResidualSummary,
    pub residual_after: ResidualSummary,
    pub steps: Vec<select::Step>,
    pub excluded: Vec<(String, String)>,
    /// The terms judged and not found, with the smallest value of each parameter this
    /// recording would have shown ([`detection`]).
    pub not_found: Vec<detection::DetectionLimit>,
    pub curves: Curves,
    /// The signals the terms were fitted on (sim bag, smoothed), for effect comparisons.
    pub base: ImuSignals,
    /// Per-sample residual noise after the fit (gyro, accel): white and walk variances.
    pub noise: ResidualNoise,
    /// Wall time of the diagnosis, s.
    pub seconds: f64,
}

/// Load, align and diagnose two bags.
pub fn diagnose_bags(sim: &Path, real: &Path, opts: &DiagnoseOptions) -> Result<(Aligned, Diagnosis), DiagnoseError> {
    let a = align::load(sim, real)?;
    let d = diagnose(&a, opts)?;
    Ok((a, d))
}

/// Diagnose aligned recordings.
pub fn diagnose(a: &Aligned, opts: &DiagnoseOptions) -> Result<Diagnosis, DiagnoseError> {
    let start = std::time::Instant::now();
    check_residual_noise(a, opts.sensors)?;
    // A rotation too large for the linear `mount_rotation` is taken out before the fit, and
    // the fit runs in the real sensor's frame.
    let gross = frame::gross_rotation(a, opts.sensors)?;
    let (mut d, fine) = diagnose_in_frame(a, opts, gross)?;
    // The fit's rotation is linear in its rotation vector: a few degrees leave second-order
    // effects (cos θ − 1 reads as a scale), so a sizeable one is taken out exactly and the
    // fit run again on top of it.
    if fine.norm() > frame::REFIT_ANGLE_RAD {
        let total = gross.map_or(UnitQuaternion::identity(), |g| g.body_from_imu) * crate::so3::exp(&fine);
        d = diagnose_in_frame(a, opts, Some(frame::rotation(a, total, opts.sensors)))?.0;
    }
    d.seconds = start.elapsed().as_secs_f64();
    Ok(d)
}

/// Share of the sim's stated white-noise variance below which the residual cannot be two
/// independent noise draws (σ ratio 0.5; the third-difference estimate on a recording of
/// thousands of samples is good to a few per cent, and motion only adds to it).
const LEAST_RESIDUAL_NOISE_SHARE: f64 = 0.25;

/// real − sim holds the sim's own noise draw beside the real one, so its white part is at
/// least the sim's stated variance. Below it every likelihood of the fit is miscalibrated
/// (two identical bags fitted a noise factor of 0.05, a time offset and a low-pass), so the
/// input is refused with what is wrong instead.
fn check_residual_noise(a: &Aligned, sensors: Sensors) -> Result<(), DiagnoseError> {
    let residual = |c: usize| -> Vec<f64> { a.real[c].iter().zip(&a.sim[c]).map(|(r, s)| r - s).collect() };
    let judged: Vec<usize> = (0..2).filter(|s| sensors.judges(*s)).collect();
    if judged.iter().all(|s| (3 * s..3 * s + 3).all(|c| residual(c).iter().all(|v| *v == 0.0))) {
        return Err(DiagnoseError::Input(
            "the real and the sim IMU streams are identical (real − sim is exactly zero): there is no mismatch to diagnose; was the same recording given twice?"
                .into(),
        ));
    }
    for s in judged {
        let stated = if s == 0 { a.sim_variance.0 } else { a.sim_variance.1 };
        let found = (3 * s..3 * s + 3).map(|c| align::white_variance_from_data(&residual(c))).sum::<f64>() / 3.0;
        if found < LEAST_RESIDUAL_NOISE_SHARE * stated {
            let (sensor, unit) = if s == 0 { ("gyroscope", "(rad/s)²") } else { ("accelerometer", "(m/s²)²") };
            return Err(DiagnoseError::Input(format!(
                "the {sensor} residual real − sim has {:.2}× the white-noise σ the sim bag states ({stated:.3e} {unit} per sample), where two independent noise draws give at least 1×: \
                 the sim's covariance fields overstate the noise it simulated, or the two bags share their noise; correct the covariance (or set it to 0 to have the noise estimated from the data)",
                (found / stated).sqrt()
            )));
        }
    }
    Ok(())
}

/// The diagnosis with the sim first put in the frame `gross` names (none: the sim's own), and
/// the rotation vector of the linear `mount_rotation` the fit added on top (zero if none).
fn diagnose_in_frame(
    a: &Aligned,
    opts: &DiagnoseOptions,
    gross: Option<frame::GrossRotation>,
) -> Result<(Diagnosis, nalgebra::Vector3<f64>), DiagnoseError> {
    let in_real_frame;
    let a = match &gross {
        Some(g) => {
            in_real_frame = frame::into_real_frame(a, g);
            &in_real_frame
        }
        None => a,
    };
    let n = a.len();
    let dt = a.dt();
    let full_rate = a.samples_per_point == 1;
    let mut notes = a.notes.clone();
    scope_notes(gross.as_ref(), opts, &mut notes);
    let base = base_signals(a, opts.half_window_s, opts.max_smoothing_s, opts.gt_smoothing_s);
    let y_all: [Vec<f64>; 6] = std::array::from_fn(|c| a.real[c].iter().zip(&a.sim[c]).map(|(r, s)| r - s).collect());
    // A sensor that is not judged leaves the fit: its residual channels are set to zero (a
    // constant in every model's likelihood) and no regressor touches them.
    let judged = |c: usize| opts.sensors.judges(residual::sensor_of(c));
    let y: [Vec<f64>; 6] = std::array::from_fn(|c| if judged(c) { y_all[c].clone() } else { vec![0.0; n] });

    // Terms read directly off the real samples, and the samples left out of the fit.
    let off = read_off_the_samples(a, opts, &mut notes);
    let (sel, excluded) = select_terms(a, &base, opts, &y, &off)?;
    let OffTheSamples { mut direct, mask, .. } = off;

    // Findings. A gross rotation is composed with the fitted one (real = R_fitᵀ R_grossᵀ sim).
    let mut fitted = select::terms_of(&sel);
    let fine_rotvec = compose_gross_rotation(&mut fitted, &mut direct, gross.as_ref());
    // A frame rotation and both sensors' misalignments share a null space: a small rotation
    // δ is the antisymmetric part [δ]× of each, so only their sum is determined.
    let chosen_names: Vec<&str> = fitted.iter().map(|(t, _)| t.name()).collect();
    if ["mount_rotation", "gyro_misalignment", "accel_misalignment"].iter().all(|n| chosen_names.contains(n)) {
        notes.push("mount_rotation, gyro_misalignment and accel_misalignment are all in the fit: a small frame rotation is the antisymmetric part of both misalignments, so how the three split it is not determined by any recording; only their combined effect is".into());
    }
    let sample_rate_hz = a.samples_per_point as f64 / dt;
    let (to_judge, mut terms) = findings::fitted(&sel, &fitted, &opts.select, sample_rate_hz, full_rate, &mut notes);
    let (exact, exact_terms) = findings::taken_out_exactly(direct);
    terms.extend(exact_terms);

    // Locate under the no-term model.
    let w0 = residual::whitened(&y, &sel.baseline_noise, &mask);
    let mut located = locate::locate(&w0, dt);
    located.retain(|l| (0..2).any(|s| opts.sensors.judges(s) && l.channel.starts_with(["gyro", "accel"][s])));

    let BeforeAfter { after, w1, residual_before, residual_after } =
        before_and_after(&sel, &y_all, &w0, &mask, opts.sensors, opts.select.folds);

    // σ from a noise model the residual exceeds is too small by √(χ²/n): widened by the
    // worst judged channel's excess, and the 95 % intervals from it.
    let excess = excess_over_noise_model(&residual_after, opts.sensors);
    if excess > 1.0 {
        notes.push(format!(
            "the residual after the fit has χ²/n up to {excess:.2}: every stated σ is widened by √{excess:.2} = {:.2}",
            excess.sqrt()
        ));
    }
    let (mut findings, implausible) = findings::judge(to_judge, excess);
    // The terms taken out exactly before the fit come after the fitted ones.
    findings.extend(exact);
    let not_found = detection::detection_limits(&sel, &mask, &opts.select, excess.sqrt());

    // The same tests on the residual after the fit: what is left there, the catalogue does
    // not explain.
    let mut located_after = adequacy::claims_after(&w1, dt);
    located_after.retain(|l| (0..2).any(|s| opts.sensors.judges(s) && l.channel.starts_with(["gyro", "accel"][s])));
    let verdict = adequacy::judge(located_after, &residual_after.chi2_per_sample, terms.len());

    let curves = curves_of(&y_all, &after, &mask, &sel.noise, dt);

    Ok((
        Diagnosis {
            notes,
            artefacts: a.artefacts.clone(),
            findings,
            implausible,
            verdict,
            terms,
            located,
            residual_before,
            residual_after,
            steps: sel.steps.clone(),
            excluded,
            not_found,
            curves,
            base,
            noise: sel.noise,
            seconds: 0.0,
        },
        fine_rotvec,
    ))
}

/// The residual after the fit, each held-out block predicted by a fit on the others, whitened,
/// and both residuals summarised.
struct BeforeAfter {
    after: [Vec<f64>; 6],
    w1: [Vec<f64>; 6],
    residual_before: ResidualSummary,
    residual_after: ResidualSummary,
}

fn before_and_after(
    sel: &Selection,
    y_all: &[Vec<f64>; 6],
    w0: &[Vec<f64>; 6],
    mask: &[bool],
    sensors: Sensors,
    folds: usize,
) -> BeforeAfter {
    let bl = residual::blocks(y_all[0].len(), folds);
    let mut after = heldout_residual(sel, &bl);
    for c in (0..6).filter(|c| !sensors.judges(residual::sensor_of(*c))) {
        after[c] = y_all[c].clone(); // nothing fitted on a sensor that is not judged
    }
    let w1 = residual::whitened(&after, &sel.noise, mask);
    let summary = |r: &[Vec<f64>; 6], w: &[Vec<f64>; 6], ll: f64, note: &str| residual_summary(r, w, mask, sensors, ll, note);
    let residual_before = summary(y_all, w0, sel.baseline.loglik_cv, "real − sim, simulator noise model (bias walk estimated)");
    let residual_after = summary(
        &after,
        &w1,
        sel.fit.loglik_cv,
        "real − (sim + fitted terms), each time block predicted by a fit on the other blocks; noise terms included in the model",
    );
    BeforeAfter { after, w1, residual_before, residual_after }
}

/// What the report says of the comparison's scope: a gross rotation taken out, the sensors
/// judged, the ground truth's smoothing.
fn scope_notes(gross: Option<&frame::GrossRotation>, opts: &DiagnoseOptions, notes: &mut Vec<String>) {
    if let Some(g) = gross {
        notes.push(format!(
            "the real sensor's frame is rotated {:.1}° from the sim's (a mount_rotation too large for the linear fit, taken out exactly before it; it maps the sim's gyro and accelerometer onto the real's with misfit × {:.3}); the residuals and every other term are in the real sensor's frame, after it",
            g.angle_deg(),
            g.misfit_ratio
        ));
    }
    if opts.sensors != Sensors::Both {
        notes.push(format!(
            "--sensors {}: only the {} is judged; the other sensor's residual is left out of the fit and its terms are not judged (its rows in the figures are the raw residual)",
            opts.sensors.name(),
            if opts.sensors == Sensors::Gyro { "gyroscope" } else { "accelerometer" }
        ));
    }
    if let Some(h) = opts.gt_smoothing_s {
        notes.push(format!("ground truth smoothed by a local cubic over ±{h} s before ω̇ is taken from it"));
    }
}

/// The terms selected on the residual `y` (the catalogue this pair determines, under the
/// simulator's noise model and the real noise read off the samples), and the terms excluded
/// from the catalogue with their reasons.
fn select_terms(
    a: &Aligned,
    base: &ImuSignals,
    opts: &DiagnoseOptions,
    y: &[Vec<f64>; 6],
    off: &OffTheSamples,
) -> Result<(Selection, Vec<(String, String)>), DiagnoseError> {
    let full_rate = a.samples_per_point == 1;
    let sim_var = [a.sim_variance.0, a.sim_variance.1];
    let temperature =
        a.temperature_c.as_ref().map(|t| t.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(*v), hi.max(*v))));
    let catalogue = catalogue_for(a, base, opts, temperature)?;
    let excluded = catalogue.excluded.clone();
    let sensor_noise = |s: usize| ChannelNoise { white_sim: sim_var[s], white_real: off.white_real[s], pole: 0.0, walk: sim_var[s] * 1e-6 };
    let noise = ResidualNoise { sensors: [sensor_noise(0), sensor_noise(1)] };
    let problem = Problem {
        y: y.clone(),
        mask: off.mask.clone(),
        base,
        catalogue,
        noise,
        stated: a.real_variance,
        judge_noise_density: a.real_variance == a.sim_variance && off.lsbs[0] == 0.0 && opts.sensors.judges(0) && full_rate,
        full_rate,
        temperature,
        opts: opts.select,
        sensors: opts.sensors,
        sim: &a.sim,
        motion_lines: None,
    };
    Ok((select::select(problem)?, excluded))
}

/// The catalogue of terms judged on this pair: those the sensors and the recording determine
/// (a temperature span, a ground-truth attitude), less those above the compared bandwidth.
fn catalogue_for(
    a: &Aligned,
    base: &ImuSignals,
    opts: &DiagnoseOptions,
    temperature: Option<(f64, f64)>,
) -> Result<Catalogue, DiagnoseError> {
    let mut catalogue = Catalogue::build(base, a.world_from_imu.is_some(), temperature.map(|(lo, hi)| hi - lo))?;
    catalogue.restrict(opts.sensors);
    if let Some((gyro_rate, accel_rate)) = bandwidth::window_mean_derivatives(a, opts.gt_smoothing_s) {
        catalogue.set_time_offset_derivatives(&gyro_rate, &accel_rate);
    }
    if a.samples_per_point != 1 {
        catalogue.candidates.retain(|c| !bandwidth::NOT_JUDGED.contains(&c.name));
        for t in bandwidth::NOT_JUDGED {
            catalogue
                .excluded
                .push((t.into(), format!("compared as means over {} samples: the term lives above that bandwidth", a.samples_per_point)));
        }
    }
    Ok(catalogue)
}

/// A gross rotation taken out before the fit composed with the fitted `mount_rotation`
/// (real = R_fitᵀ R_grossᵀ sim), or added as a term taken out exactly where none was fitted.
/// Returns the fitted rotation vector alone (zero if none).
fn compose_gross_rotation(
    fitted: &mut [(Term, Vec<f64>)],
    direct: &mut Vec<(Term, serde_json::Value)>,
    gross: Option<&frame::GrossRotation>,
) -> nalgebra::Vector3<f64> {
    let fine = fitted.iter().position(|(t, _)| matches!(t, Term::MountRotation(_)));
    let fine_rotvec = fitted
        .iter()
        .find_map(|(t, _)| if let Term::MountRotation(m) = t { Some(nalgebra::Vector3::from(m.rotvec)) } else { None })
        .unwrap_or_else(nalgebra::Vector3::zeros);
    if let Some(g) = gross {
        let total = crate::so3::log(&(g.body_from_imu * crate::so3::exp(&fine_rotvec)));
        let term = Term::MountRotation(crate::physics::MountRotation { rotvec: total.into() });
        match fine {
            Some(i) => fitted[i].0 = term,
            None => direct.push((
                term,
                serde_json::json!({"rule": "a rotation too large for the catalogue's linear term, taken out exactly before the fit (found by mapping the sim's gyro and accelerometer onto the real's, or by a first fit)", "angle_deg": g.angle_deg(), "misfit_ratio": g.misfit_ratio}),
            )),
        }
    }
    fine_rotvec
}

/// RMS per channel of the residual `r` over the samples in the fit, and χ²/n of its whitened
/// form `w` on the judged channels.
fn residual_summary(
    r: &[Vec<f64>; 6],
    w: &[Vec<f64>; 6],
    mask: &[bool],
    sensors: Sensors,
    heldout_loglik: f64,
    note: &str,
) -> ResidualSummary {
    let mut s = ResidualSummary { heldout_loglik, note: note.into(), ..Default::default() };
    for c in 0..6 {
        let m: Vec<f64> = r[c].iter().zip(mask).filter(|(_, m)| **m).map(|(v, _)| *v).collect();
        s.rms.insert(CHANNELS[c].into(), (m.iter().map(|v| v * v).sum::<f64>() / m.len().max(1) as f64).sqrt());
        if sensors.judges(residual::sensor_of(c)) {
            s.chi2_per_sample.insert(CHANNELS[c].into(), w[c].iter().map(|v| v * v).sum::<f64>() / m.len().max(1) as f64);
        }
    }
    s
}

/// The worst judged channel's χ²/n after the fit, at least 1: how far every σ the noise
/// model states falls short.
fn excess_over_noise_model(after: &ResidualSummary, sensors: Sensors) -> f64 {
    after
        .chi2_per_sample
        .iter()
        .filter(|(c, _)| (0..2).any(|s| sensors.judges(s) && c.starts_with(["gyro", "accel"][s])))
        .map(|(_, v)| *v)
        .fold(1.0f64, f64::max)
}

/// What the real samples say before any fit: clipping and quantisation (terms read off
/// them), and the samples the fit leaves out (gaps of the real stream, the reference's
/// dropouts, clipped samples).
struct OffTheSamples {
    direct: Vec<(Term, serde_json::Value)>,
    /// Per sample: in the fit.
    mask: Vec<bool>,
    /// The real white-noise variance per sensor, quantisation included.
    white_real: [f64; 2],
    /// The quantisation step per sensor (0: none).
    lsbs: [f64; 2],
}

fn read_off_the_samples(a: &Aligned, opts: &DiagnoseOptions, notes: &mut Vec<String>) -> OffTheSamples {
    let (n, full_rate) = (a.len(), a.samples_per_point == 1);
    let mut direct: Vec<(Term, serde_json::Value)> = Vec::new();
    // Stamps inside a gap of the real stream hold an interpolation across it, not a sample.
    let flag = |v: &[bool], i: usize| v.get(i).copied().unwrap_or(false);
    let mut mask: Vec<bool> = a.left_out().iter().map(|l| !l).collect();
    let in_gaps = (0..n).filter(|&i| flag(&a.in_real_gap, i)).count();
    if in_gaps > 0 {
        notes.push(format!("{in_gaps} sim stamps inside gaps of the real stream left out of the fit"));
    }
    let in_reference_gaps = (0..n).filter(|&i| flag(&a.in_reference_gap, i)).count();
    if in_reference_gaps > 0 {
        notes.push(format!(
            "{in_reference_gaps} stamps ({:.1} % of the recording) at or near dropouts of the ground truth left out of the fit: the sim there is made up across the hole, not simulated",
            100.0 * in_reference_gaps as f64 / n.max(1) as f64
        ));
    }
    let mut white_real = [a.real_variance.0, a.real_variance.1];
    let sim_var = [a.sim_variance.0, a.sim_variance.1];
    let mut ranges = [f64::INFINITY; 2];
    let mut lsbs = [0.0; 2];
    for s in (0..2).filter(|s| full_rate && opts.sensors.judges(*s)) {
        if let Some((range, idx)) = catalogue::detect_saturation(&a.real[3 * s..3 * s + 3], &a.sim[3 * s..3 * s + 3], sim_var[s].sqrt()) {
            ranges[s] = range;
            for &i in &idx {
                mask[i] = false;
            }
        }
        if let Some(lsb) = catalogue::detect_quantization(&a.real[3 * s..3 * s + 3], &a.sim[3 * s..3 * s + 3]) {
            lsbs[s] = lsb;
            white_real[s] += lsb * lsb / 12.0;
        }
    }
    if ranges.iter().any(|r| r.is_finite()) {
        let clipped = mask.iter().filter(|m| !**m).count();
        let t = Term::Saturation(crate::physics::Saturation { gyro_range: ranges[0], accel_range: ranges[1] });
        direct.push((t, serde_json::json!({"clipped_samples": clipped, "rule": "≥ 3 real samples at the largest magnitude while the sim exceeds it by > 3σ"})));
        notes.push(format!("{clipped} clipped samples left out of the fit"));
    }
    if lsbs.iter().any(|l| *l > 0.0) {
        let t = Term::Quantization(crate::physics::Quantization { gyro_lsb: lsbs[0], accel_lsb: lsbs[1] });
        direct.push((t, serde_json::json!({"rule": "every real sample is a multiple of the step, the sim samples are not"})));
    }
    OffTheSamples { direct, mask, white_real, lsbs }
}

/// The data behind the figures: Allan deviations and spectra of the residual before and
/// after the fit (with the noise model's Allan curve), and ~300 block means of each.
fn curves_of(y_all: &[Vec<f64>; 6], after: &[Vec<f64>; 6], mask: &[bool], noise: &ResidualNoise, dt: f64) -> Curves {
    let mut curves = Curves::default();
    // Left-out samples (gaps, the reference's dropouts, clipping) hold no comparison: the
    // spectra and Allan curves see the last compared value there, not the spikes.
    let held = |x: &[f64]| held_over_mask(x, mask);
    let (y_all, after): ([Vec<f64>; 6], [Vec<f64>; 6]) =
        (std::array::from_fn(|c| held(&y_all[c])), std::array::from_fn(|c| held(&after[c])));
    let n = y_all[0].len();
    for c in 0..6 {
        let ab = allan::allan_deviation(&y_all[c], dt);
        let aa = allan::allan_deviation(&after[c], dt);
        curves.allan.push(ab.iter().zip(&aa).map(|(b, a)| (b.0, b.1, a.1)).collect());
        let ns = noise.sensors[residual::sensor_of(c)];
        let white = ns.white_sim + ns.white_real * (1.0 - ns.pole) / (1.0 + ns.pole);
        curves.allan_model.push(ab.iter().map(|(tau, _)| (*tau, allan::model_allan(white, ns.walk, dt, *tau))).collect());
        let seg = ((20.0 / dt) as usize).next_power_of_two();
        let (f, pb) = psd::welch(&y_all[c], dt, seg);
        let (_, pa) = psd::welch(&after[c], dt, seg);
        curves.psd.push(f.iter().zip(pb.iter().zip(&pa)).map(|(f, (b, a))| (*f, *b, *a)).collect());
    }
    // ~300 block means: the slow part of the residual (what a figure of a long recording
    // can show; the fast part is in the PSD), and a small PNG.
    let block = n.div_ceil(300).max(1);
    curves.residual_t = (0..n).step_by(block).map(|i| (i as f64 + (block.min(n - i) as f64 - 1.0) / 2.0) * dt).collect();
    for c in 0..6 {
        curves.residual_before[c] = block_means(&y_all[c], mask, block);
        curves.residual_after[c] = block_means(&after[c], mask, block);
    }
    curves
}

/// `x` with every sample where `mask` is false replaced by the last one where it is true
/// (the first such before any: the first true one).
fn held_over_mask(x: &[f64], mask: &[bool]) -> Vec<f64> {
    let mut last = mask.iter().position(|m| *m).map_or(0.0, |i| x[i]);
    x.iter()
        .zip(mask)
        .map(|(v, m)| {
            if *m {
                last = *v;
            }
            last
        })
        .collect()
}

/// Means of consecutive blocks of `block` samples, masked samples left out (NaN if none).
fn block_means(x: &[f64], mask: &[bool], block: usize) -> Vec<f64> {
    x.chunks(block)
        .zip(mask.chunks(block))
        .map(|(v, m)| {
            let (s, k) = v.iter().zip(m).filter(|(_, m)| **m).fold((0.0, 0usize), |(s, k), (v, _)| (s + v, k + 1));
            if k > 0 {
                s / k as f64
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// The residual after the fitted terms, each block predicted by the fit without it.
fn heldout_residual(sel: &Selection, bl: &[std::ops::Range<usize>]) -> [Vec<f64>; 6] {
    let mut out = sel.y.clone();
    for (b, r) in bl.iter().enumerate() {
        let beta: &DVector<f64> = sel.fit.beta_folds.get(b).unwrap_or(&sel.fit.beta);
        let pred = select::model_residual(&sel.catalogue, &sel.y, &sel.chosen, beta);
        for c in 0..6 {
            out[c][r.clone()].copy_from_slice(&pred[c][r.clone()]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A slow motion seen by a sim and a real sensor, each with its own white noise of
    /// variance (1e-6, 1e-4); the sim states `stated`.
    fn aligned(stated: (f64, f64), same_noise: bool) -> Aligned {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n = 4000;
        let noise = |rng: &mut rand_chacha::ChaCha8Rng, c: usize| Normal::new(0.0, if c < 3 { 1e-3 } else { 1e-2 }).unwrap().sample(rng);
        let mut sim: [Vec<f64>; 6] = Default::default();
        let mut real: [Vec<f64>; 6] = Default::default();
        for i in 0..n {
            let t = i as f64 * 0.005;
            for c in 0..6 {
                let truth = (0.3 * t + c as f64).sin() + if c == 5 { 9.81 } else { 0.0 };
                let s = truth + noise(&mut rng, c);
                sim[c].push(s);
                real[c].push(if same_noise { s } else { truth + noise(&mut rng, c) });
            }
        }
        Aligned {
            stamps_ns: (0..n as i64).map(|i| i * 5_000_000).collect(),
            sim,
            real,
            sim_variance: stated,
            real_variance: stated,
            world_from_imu: None,
            temperature_c: None,
            notes: vec![],
            artefacts: vec![],
            in_real_gap: vec![],
            in_reference_gap: vec![],
            sim_recording: crate::core::Recording { name: "t".into(), imu: vec![], ground_truth: vec![], temperature: vec![] },
            samples_per_point: 1,
        }
    }

    #[test]
    fn a_residual_quieter_than_the_sims_own_noise_is_refused() {
        // Two independent draws at the stated noise: accepted.
        assert!(check_residual_noise(&aligned((1e-6, 1e-4), false), Sensors::Both).is_ok());
        // The same bag twice.
        let e = check_residual_noise(&aligned((1e-6, 1e-4), true), Sensors::Both).unwrap_err().to_string();
        assert!(e.contains("identical"), "{e}");
        // A covariance 100× the noise simulated: the gyro's σ ratio is √2 / 10.
        let e = check_residual_noise(&aligned((1e-4, 1e-4), false), Sensors::Both).unwrap_err().to_string();
        assert!(e.contains("gyroscope") && e.contains("0.14×"), "{e}");
        // The gyro alone is judged: the accelerometer's covariance is not its business.
        assert!(check_residual_noise(&aligned((1e-6, 1e-2), false), Sensors::Gyro).is_ok());
    }
}
