//! Injected effects on real recordings (`diagnose --score-injected BAG…`): a real IMU
//! recording with its measured ground truth, a known effect added to its IMU samples by the
//! physics code (affine maps, biases, a time offset, g-sensitivity, a low-pass, of the sizes
//! real sensors have, drawn from a seed), diagnosed against the simulation of its ground
//! truth. The unperturbed recording is the control: what it shows is the recording's own,
//! and an injected case is scored against the truth *beyond* the control.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use imu_fsda::bag::{read_recording, RecordingTopics};
use imu_fsda::core::Recording;
use imu_fsda::diagnose::{align, diagnose, kinematics, plain_calibration, DiagnoseOptions, Diagnosis, Sensors};
use imu_fsda::physics::NoiseModel;
use imu_fsda::physics::{self, apply_terms, effect, ImuSignals, Term, TermContext};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};

/// What one run scores on: the recordings, the noise model of their IMU, how to read them.
pub struct InjectedSet<'a> {
    pub bags: &'a [PathBuf],
    pub topics: RecordingTopics,
    pub noise: NoiseModel,
    pub smoothing: Option<f64>,
    pub compare_window: Option<f64>,
    pub real_noise_from_data: bool,
    /// Injected cases per recording (besides its control).
    pub draws: usize,
    pub seed: u64,
    /// Draw only these terms (empty: the whole injectable set).
    pub only: Vec<String>,
}

/// Terms a real IMU's calibration or mounting has, and how large they are on real parts.
const INJECTABLE: [&str; 10] = [
    "gyro_bias",
    "gyro_scale",
    "gyro_misalignment",
    "gyro_g_sensitivity",
    "time_offset",
    "low_pass",
    "accel_bias",
    "accel_scale",
    "accel_misalignment",
    "mount_rotation",
];

fn signed(rng: &mut impl Rng, lo: f64, hi: f64) -> f64 {
    let v = rng.gen_range(lo..hi);
    if rng.gen_bool(0.5) {
        v
    } else {
        -v
    }
}

fn axes(rng: &mut impl Rng, lo: f64, hi: f64) -> [f64; 3] {
    std::array::from_fn(|_| signed(rng, lo, hi))
}

fn off_diagonal(rng: &mut impl Rng, lo: f64, hi: f64) -> [[f64; 3]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| if r == c { 0.0 } else { signed(rng, lo, hi) }))
}

/// One term of a size real MEMS parts have (datasheets of the BMI160, MPU-9250, ADIS16448
/// class, before calibration).
fn draw(name: &str, rng: &mut impl Rng, rate_hz: f64) -> Term {
    use physics::*;
    match name {
        "gyro_bias" => Term::GyroBias(GyroBias::new(axes(&mut *rng, 0.005, 0.05))),
        "gyro_scale" => Term::GyroScale(GyroScale::new(axes(&mut *rng, 0.005, 0.04))),
        "gyro_misalignment" => Term::GyroMisalignment(GyroMisalignment::new(off_diagonal(rng, 0.002, 0.01))),
        "gyro_g_sensitivity" => Term::GyroGSensitivity(GyroGSensitivity { matrix: std::array::from_fn(|_| axes(&mut *rng, 1e-4, 5e-4)) }),
        // Within one sample: a larger offset is a stamping fault, said as implausible.
        "time_offset" => Term::TimeOffset(TimeOffset { seconds: signed(rng, 0.1, 0.8) / rate_hz }),
        // Where real parts' digital low-pass filters sit: 0.1–0.4 of the sample rate.
        "low_pass" => Term::LowPass(LowPass { cutoff_hz: rng.gen_range(0.1..0.4) * rate_hz, sensor: LowPassSensor::Both }),
        "accel_bias" => Term::AccelBias(AccelBias::new(axes(&mut *rng, 0.05, 0.5))),
        "accel_scale" => Term::AccelScale(AccelScale::new(axes(&mut *rng, 0.005, 0.03))),
        "accel_misalignment" => Term::AccelMisalignment(AccelMisalignment::new(off_diagonal(rng, 0.002, 0.01))),
        "mount_rotation" => {
            let u = Vector3::from_fn(|_, _| rng.gen_range(-1.0..1.0)).normalize() * rng.gen_range(0.5f64..3.0).to_radians();
            Term::MountRotation(MountRotation { rotvec: [u.x, u.y, u.z] })
        }
        other => unreachable!("{other}"),
    }
}

/// The terms of one injected case: 1–3 distinct terms, never a delay beside a low-pass (the
/// two are one effect at this motion's bandwidth, item 5 of the diagnosis's limits).
fn draw_case(rng: &mut impl Rng, names: &[&'static str], rate_hz: f64) -> Vec<Term> {
    let k = [1usize, 1, 2, 2, 3][rng.gen_range(0..5)].min(names.len());
    let mut chosen: Vec<&str> = Vec::new();
    while chosen.len() < k {
        let pick = names[rng.gen_range(0..names.len())];
        let clash = chosen.iter().any(|n| *n == pick || matches!((*n, pick), ("low_pass", "time_offset") | ("time_offset", "low_pass")));
        if !clash {
            chosen.push(pick);
        }
    }
    chosen.into_iter().map(|n| draw(n, rng, rate_hz)).collect()
}

/// The real recording cut to its ground truth, the simulation of that ground truth, and the
/// signals the injected terms act on (the real samples, with the ground truth's attitude and
/// angular acceleration).
struct Prepared {
    real: Recording,
    sim: Recording,
    sim_variance: (f64, f64),
    /// The noise-free signals from the ground truth: where effects are compared.
    ideal: ImuSignals,
    /// The real samples as signals the physics terms can change.
    measured: ImuSignals,
    /// Per sample: the ground truth is there (not in or near a dropout, where `ideal` is
    /// made up): the samples effects are compared over.
    judged: Vec<bool>,
}

fn prepare(path: &Path, set: &InjectedSet) -> anyhow::Result<Prepared> {
    let (mut real, _) = read_recording(path, &set.topics)?;
    super::align_reference_clock(&mut real, set.smoothing)?;
    kinematics::crop_to_ground_truth(&mut real, set.smoothing.unwrap_or(0.0));
    let (sim, sim_variance) = kinematics::simulate_from_ground_truth(&real, &set.noise, set.seed, set.smoothing)?;
    let stamps: Vec<i64> = real.imu.iter().map(|s| s.stamp_ns).collect();
    let ideal = kinematics::ideal_from_poses_with(&real.ground_truth, &stamps, set.smoothing)?;
    let measured =
        ImuSignals { gyro: real.imu.iter().map(|s| s.gyro).collect(), accel: real.imu.iter().map(|s| s.accel).collect(), ..ideal.clone() };
    let margin = kinematics::dropout_margin_s(&real.ground_truth, set.smoothing);
    let judged =
        kinematics::near_dropouts(&stamps, &kinematics::reference_dropouts(&real.ground_truth), margin).iter().map(|d| !d).collect();
    Ok(Prepared { real, sim, sim_variance, ideal, measured, judged })
}

fn diagnose_case(p: &Prepared, real: Recording, set: &InjectedSet, opts: &DiagnoseOptions) -> anyhow::Result<Diagnosis> {
    let mut a = align::align(p.sim.clone(), real, Some(p.sim_variance), vec![])?;
    super::leave_out_reference_dropouts(&mut a, set.smoothing);
    let window = super::compare_window(set.compare_window, true, &p.sim.ground_truth);
    a = super::over_windows(a, window);
    if set.real_noise_from_data || a.samples_per_point > 1 {
        a.estimate_real_white_noise();
    }
    Ok(diagnose(&a, opts)?)
}

/// The injected term with its sign turned (the same size the other way), `None` where a sign
/// means nothing (a low-pass).
fn mirrored(t: &Term) -> Option<Term> {
    use physics::*;
    let neg3 = |v: [f64; 3]| v.map(|x| -x);
    let neg33 = |m: [[f64; 3]; 3]| m.map(|r| r.map(|x| -x));
    Some(match t {
        Term::GyroBias(b) => Term::GyroBias(GyroBias::new(neg3(b.bias))),
        Term::GyroScale(b) => Term::GyroScale(GyroScale::new(neg3(b.scale))),
        Term::GyroMisalignment(b) => Term::GyroMisalignment(GyroMisalignment::new(neg33(b.matrix))),
        Term::GyroGSensitivity(b) => Term::GyroGSensitivity(GyroGSensitivity { matrix: neg33(b.matrix) }),
        Term::TimeOffset(b) => Term::TimeOffset(TimeOffset { seconds: -b.seconds }),
        Term::AccelBias(b) => Term::AccelBias(AccelBias::new(neg3(b.bias))),
        Term::AccelScale(b) => Term::AccelScale(AccelScale::new(neg3(b.scale))),
        Term::AccelMisalignment(b) => Term::AccelMisalignment(AccelMisalignment::new(neg33(b.matrix))),
        Term::MountRotation(b) => Term::MountRotation(MountRotation { rotvec: neg3(b.rotvec) }),
        _ => return None,
    })
}

/// ‖e − Δtruth‖ / ‖Δtruth‖ over the recording's judged samples, each sensor weighted by its white-noise
/// variance (as the generated cases score), for an estimated effect e.
fn relative_error(estimate: &physics::Effect, truth: &physics::Effect, var: (f64, f64), judged: &[bool]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for i in (0..truth.gyro.len()).filter(|&i| judged[i]) {
        num += (estimate.gyro[i] - truth.gyro[i]).norm_squared() / var.0 + (estimate.accel[i] - truth.accel[i]).norm_squared() / var.1;
        den += truth.gyro[i].norm_squared() / var.0 + truth.accel[i].norm_squared() / var.1;
    }
    (num / den.max(1e-300)).sqrt()
}

fn difference(a: &physics::Effect, b: &physics::Effect, half: bool) -> physics::Effect {
    let k = if half { 0.5 } else { 1.0 };
    physics::Effect {
        gyro: a.gyro.iter().zip(&b.gyro).map(|(x, y)| (x - y) * k).collect(),
        accel: a.accel.iter().zip(&b.accel).map(|(x, y)| (x - y) * k).collect(),
    }
}

/// The effect of `t` on `s`; a time offset's to first order (−τ ẋ, the catalogue's atom): the
/// exact resampling also smooths the signal by an amount even in τ, which is no part of the
/// delay a fit estimates (at 0.6 samples it is 25 % of the effect's norm on a hand-held
/// recording).
fn linear_effect(t: &Term, s: &ImuSignals) -> Option<physics::Effect> {
    const STEP_S: f64 = 1e-6;
    match t {
        Term::TimeOffset(o) => {
            let unit = effect(&Term::TimeOffset(physics::TimeOffset { seconds: STEP_S }), s, 0).ok()?;
            let k = o.seconds / STEP_S;
            Some(physics::Effect { gyro: unit.gyro.iter().map(|v| v * k).collect(), accel: unit.accel.iter().map(|v| v * k).collect() })
        }
        _ => effect(t, s, 0).ok(),
    }
}

/// The error of the effect found for the injected `truth`. A recording has errors of its own
/// the control may not show alone (a 0.3 % scale below the threshold) but that enter with the
/// injected term, so where the mirrored case found the term too, the found effect is half the
/// difference of the two (the recording's own cancels); otherwise the found term less the
/// control's of that name.
fn effect_error(found: &Term, mirror_found: Option<&Term>, control: Option<&Term>, truth: &Term, p: &Prepared) -> f64 {
    // Only a term with a sign has a mirrored case that differs from this one.
    let s = &p.ideal;
    let e = |t: &Term| linear_effect(t, s);
    let (Some(f), Some(t)) = (e(found), e(truth)) else { return f64::INFINITY };
    let zero = || physics::Effect { gyro: vec![Vector3::zeros(); s.len()], accel: vec![Vector3::zeros(); s.len()] };
    let estimate = match mirror_found.and_then(e) {
        Some(m) => difference(&f, &m, true),
        None => difference(&f, &control.and_then(e).unwrap_or_else(zero), false),
    };
    relative_error(&estimate, &t, p.sim_variance, &p.judged)
}

/// A term found in a case and in its mirror whose effects differ by at most 20 % (the recall's
/// yardstick): it did not turn with the injected sign, so it is the recording's own, its
/// evidence below the threshold in the control and above it once an injected term is in the
/// model (a scale whose bias partner the control lacked).
fn mirror_invariant(here: &Term, mirror: &Term, p: &Prepared) -> bool {
    let (Some(a), Some(b)) = (linear_effect(here, &p.ideal), linear_effect(mirror, &p.ideal)) else { return false };
    relative_error(&a, &b, p.sim_variance, &p.judged) <= 0.2
}

/// Tallies over every injected case.
#[derive(Default)]
struct Tally {
    injected: usize,
    found: usize,
    within: usize,
    reported_beyond_control: usize,
    spurious: usize,
    /// Of the spurious terms, those the mirrored case found alike ([`mirror_invariant`]).
    spurious_own: usize,
    not_explained: usize,
    errors: Vec<f64>,
    /// Per injected term's name: (injected, found).
    by_term: std::collections::BTreeMap<&'static str, (usize, usize)>,
    /// (injected, found) by where the injected value sits against the control's stated
    /// detection limit: at or above it, below it, no limit stated (a drift term, or one the
    /// control found itself).
    by_limit: [(usize, usize); 3],
}

/// Where an injected term sits against what the control says it would have shown: its
/// margin (≥ 1: above the limit), `None` where the control states no limit for it.
fn margin(control: &Diagnosis, t: &Term) -> Option<f64> {
    let limit = control.not_found.iter().find(|l| l.term == t.name())?;
    Some(limit.margin(&imu_fsda::diagnose::catalogue::parameters(t)?))
}

pub fn run(set: &InjectedSet, out: &Path, opts: &DiagnoseOptions) -> anyhow::Result<()> {
    imu_fsda::core::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let names = injectable_names(set)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(set.seed);
    let mut tally = Tally::default();
    // The plain per-axis regression beside the diagnosis: gyro terms only, so on gyro sets.
    let mut plain = (opts.sensors == Sensors::Gyro).then(PlainBeside::default);
    let mut controls = Vec::new();
    let mut csv = String::from(CSV_HEADER);
    for bag in set.bags {
        let name = bag.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let p = prepare(bag, set).with_context(|| format!("{}", bag.display()))?;
        let rate = 1.0 / p.ideal.nominal_dt();
        let window = super::compare_window(set.compare_window, true, &p.sim.ground_truth);
        let control = diagnose_case(&p, p.real.clone(), set, opts)?;
        let own: Vec<&str> = control.terms.iter().map(|t| t.name()).collect();
        out!("{name}: control (as recorded): [{}]  {}", own.join(", "), control.verdict.statement)?;
        controls
            .push(serde_json::json!({"recording": name, "terms": own, "explained": control.verdict.explained, "seconds": control.seconds}));
        let _ = writeln!(csv, "{name},control,,{},,,,,{},{:.2},,", own.join(" "), control.verdict.explained, control.seconds);
        let samples_per_window = ((window * rate).round() as usize).max(1);
        let plain_fit = |gyro: &[Vector3<f64>]| plain_fit(gyro, &p, samples_per_window);
        let plain_control = match &mut plain {
            Some(beside) => Some(beside.control(&name, plain_fit(&p.measured.gyro)?)?),
            None => None,
        };
        let recorded = AsRecorded { name: &name, method: "", p: &p, limits: &control, own_terms: &control.terms, rate, window };
        let plain_recorded = plain_control.as_ref().map(|own| AsRecorded {
            name: &name,
            method: "plain calibration: ",
            p: &p,
            limits: &control,
            own_terms: own,
            rate,
            window,
        });
        for draw in 0..set.draws {
            let truth = draw_case(&mut rng, &names, rate);
            let mirror: Vec<Term> = truth.iter().map(|t| mirrored(t).unwrap_or_else(|| t.clone())).collect();
            let (mut cases, mut plain_cases) = (Vec::new(), Vec::new());
            for terms in [&truth, &mirror] {
                let mut s = p.measured.clone();
                apply_terms(terms, &mut s, &mut TermContext::new(set.seed.wrapping_add(draw as u64)))?;
                if plain_recorded.is_some() {
                    let (terms, seconds, _) = plain_fit(&s.gyro)?;
                    plain_cases.push((terms, seconds));
                }
                cases.push(diagnose_case(&p, Recording { imu: s.to_samples(), ..p.real.clone() }, set, opts)?);
            }
            for (k, terms) in [&truth, &mirror].into_iter().enumerate() {
                let case = format!("{draw}{}", if k == 0 { "+" } else { "-" });
                tally.score_case(&recorded, &case, terms, Found::from(&cases[k]), Found::from(&cases[1 - k]), &mut csv)?;
                if let (Some(r), Some(beside)) = (&plain_recorded, &mut plain) {
                    beside.tally.score_case(
                        r,
                        &case,
                        terms,
                        plain_found(&plain_cases[k]),
                        plain_found(&plain_cases[1 - k]),
                        &mut beside.csv,
                    )?;
                }
            }
        }
    }
    let mut summary = tally.summary(set, controls);
    if let Some(beside) = plain {
        summary["plain_calibration"] = beside.finish(set, out)?;
    }
    out!("{}", serde_json::to_string_pretty(&summary)?)?;
    std::fs::write(out.join("score.json"), serde_json::to_string_pretty(&summary)?)?;
    std::fs::write(out.join("cases.csv"), csv)?;
    Ok(())
}

/// The plain calibration of one stream of the recording against its ground truth: the terms it
/// reports, its time, the fit.
fn plain_fit(gyro: &[Vector3<f64>], p: &Prepared, window: usize) -> anyhow::Result<(Vec<Term>, f64, plain_calibration::PlainCalibration)> {
    let started = std::time::Instant::now();
    let c = plain_calibration::fit(gyro, &p.ideal.gyro, &p.judged, window)?;
    Ok((c.terms(), started.elapsed().as_secs_f64(), c))
}

/// The plain per-axis calibration scored beside the diagnosis: its tally, its controls (and
/// their fits, pooled at the end), its cases.
#[derive(Default)]
struct PlainBeside {
    tally: Tally,
    controls: Vec<serde_json::Value>,
    fits: Vec<plain_calibration::PlainCalibration>,
    csv: String,
}

impl PlainBeside {
    /// A recording as recorded: what the plain fit reports on it (its own terms), said and kept.
    fn control(
        &mut self,
        name: &str,
        (terms, seconds, fitted): (Vec<Term>, f64, plain_calibration::PlainCalibration),
    ) -> anyhow::Result<Vec<Term>> {
        let own: Vec<&str> = terms.iter().map(|t| t.name()).collect();
        out!("{name}: plain calibration of the control: [{}]  {}", own.join(", "), serde_json::to_string(&terms)?)?;
        let mut j = fitted.json();
        if let Some(o) = j.as_object_mut() {
            o.remove("rule"); // said once, beside the tally
        }
        j["recording"] = serde_json::json!(name);
        j["seconds"] = serde_json::json!(seconds);
        self.controls.push(j);
        self.fits.push(fitted);
        Ok(terms)
    }

    /// `score.json`'s `plain_calibration`: the tally, the rule, the controls pooled; writes
    /// plain_cases.csv.
    fn finish(mut self, set: &InjectedSet, out: &Path) -> anyhow::Result<serde_json::Value> {
        let mut s = self.tally.summary(set, std::mem::take(&mut self.controls));
        s["rule"] = serde_json::json!(format!("{}; scored as the diagnosis is", plain_calibration::RULE));
        if let Some((mean, sigma)) = plain_calibration::pooled_lasting_error(&self.fits) {
            s["pooled_controls"] = serde_json::json!({
                "rule": "A - I of the controls (the recordings as recorded) pooled entry by entry by inverse variance: the lasting scale (diagonal) and cross-axis error (off-diagonal) of one IMU over its recordings; meaningful where they are power-ons of one IMU",
                "recordings": self.fits.len(),
                "lasting_error": plain_calibration::rows(&mean),
                "sigma": plain_calibration::rows(&sigma),
            });
            let scale: Vec<String> = (0..3).map(|k| format!("{:+.3} ± {:.3}", 100.0 * mean[(k, k)], 100.0 * sigma[(k, k)])).collect();
            out!("plain calibration, the {} controls pooled: scale {} %", self.fits.len(), scale.join(" / "))?;
        }
        std::fs::write(out.join("plain_cases.csv"), CSV_HEADER.to_string() + &self.csv)?;
        Ok(s)
    }
}

const CSV_HEADER: &str =
    "recording,case,injected,control,found,effect_errors,spurious,spurious_alike_in_mirror,verdict,seconds_taken,margins,injected_terms\n";

/// What one method reported on one case: the diagnosis, or the plain calibration beside it.
#[derive(Clone, Copy)]
struct Found<'a> {
    terms: &'a [Term],
    explained: bool,
    seconds: f64,
}

/// The plain calibration's terms and its time as what it found (it has no verdict).
fn plain_found((terms, seconds): &(Vec<Term>, f64)) -> Found<'_> {
    Found { terms, explained: true, seconds: *seconds }
}

impl<'a> From<&'a Diagnosis> for Found<'a> {
    fn from(d: &'a Diagnosis) -> Self {
        Found { terms: &d.terms, explained: d.verdict.explained, seconds: d.seconds }
    }
}

/// The terms to inject: every injectable one, or those `--score-only` names.
fn injectable_names(set: &InjectedSet) -> anyhow::Result<Vec<&'static str>> {
    if set.only.is_empty() {
        return Ok(INJECTABLE.to_vec());
    }
    set.only
        .iter()
        .map(|n| {
            INJECTABLE
                .iter()
                .copied()
                .find(|k| k == n)
                .with_context(|| format!("--score-only {n}: not an injectable term ({INJECTABLE:?})"))
        })
        .collect()
}

/// One recording as recorded: what the method scored found on it (its own terms), and the
/// control diagnosis's stated detection limits (the classes of `recall_by_limit`, the same for
/// every method).
struct AsRecorded<'a> {
    name: &'a str,
    /// Said before each case's line ("" for the diagnosis).
    method: &'a str,
    p: &'a Prepared,
    limits: &'a Diagnosis,
    own_terms: &'a [Term],
    rate: f64,
    /// The comparison window, s (0: sample by sample).
    window: f64,
}

impl AsRecorded<'_> {
    /// Compared over windows, a low-pass is seen as its delay (and reported as time_offset,
    /// with the filter named beside it): its truth is that delay.
    fn as_compared(&self, t: &Term) -> Term {
        match t {
            Term::LowPass(l) if self.window > 0.0 => Term::TimeOffset(physics::TimeOffset {
                seconds: imu_fsda::diagnose::bandwidth::low_pass_delay_s(l.cutoff_hz, 1.0 / self.rate),
            }),
            _ => t.clone(),
        }
    }
}

impl Tally {
    /// One injected case (`terms` into the recording, diagnosed as `d`; `other` its mirror):
    /// what was found of them, how close, what was reported beyond them; its CSV row.
    fn score_case(&mut self, r: &AsRecorded, case: &str, terms: &[Term], d: Found, other: Found, csv: &mut String) -> anyhow::Result<()> {
        let name = r.name;
        let own: Vec<&str> = r.own_terms.iter().map(|t| t.name()).collect();
        let mut errs = Vec::new();
        let mut margins = Vec::new();
        for injected in terms.iter() {
            let t = &r.as_compared(injected);
            self.injected += 1;
            self.by_term.entry(injected.name()).or_default().0 += 1;
            let m = margin(r.limits, t);
            margins.push(m.map_or_else(|| format!("{} –", t.name()), |m| format!("{} {m:.2}", t.name())));
            let limit_class = match m {
                Some(m) if m >= 1.0 => 0,
                Some(_) => 1,
                None => 2,
            };
            self.by_limit[limit_class].0 += 1;
            let find = |d: Found| d.terms.iter().find(|f| f.name() == t.name()).cloned();
            if let Some(f) = find(d) {
                self.by_limit[limit_class].1 += 1;
                self.found += 1;
                self.by_term.entry(injected.name()).or_default().1 += 1;
                let control_term = r.own_terms.iter().find(|c| c.name() == t.name());
                let mirror_found = mirrored(injected).and(find(other));
                let err = effect_error(&f, mirror_found.as_ref(), control_term, t, r.p);
                self.within += (err <= 0.2) as usize;
                self.errors.push(err);
                errs.push(format!("{} {err:.3}", t.name()));
            }
        }
        // Beyond the control: a term the control did not have and that was not injected.
        let beyond: Vec<&str> = d.terms.iter().map(|t| t.name()).filter(|n| !own.contains(n)).collect();
        let compared: Vec<Term> = terms.iter().map(|t| r.as_compared(t)).collect();
        let spurious: Vec<&str> = beyond.iter().copied().filter(|n| !compared.iter().any(|t| t.name() == *n)).collect();
        let injected_and_own = compared.iter().filter(|t| own.contains(&t.name()) && d.terms.iter().any(|f| f.name() == t.name())).count();
        self.reported_beyond_control += beyond.len() + injected_and_own;
        self.spurious += spurious.len();
        let in_both = |n: &str| d.terms.iter().find(|t| t.name() == n).zip(other.terms.iter().find(|t| t.name() == n));
        let own_of_recording: Vec<&str> =
            spurious.iter().copied().filter(|n| in_both(n).is_some_and(|(a, b)| mirror_invariant(a, b, r.p))).collect();
        self.spurious_own += own_of_recording.len();
        self.not_explained += !d.explained as usize;
        let tn: Vec<&str> = terms.iter().map(|t| t.name()).collect();
        let fnm: Vec<&str> = d.terms.iter().map(|t| t.name()).collect();
        let _ = writeln!(
            csv,
            "{name},{case},{},{},{},{},{},{},{},{:.2},{},\"{}\"",
            tn.join(" "),
            own.join(" "),
            fnm.join(" "),
            errs.join(" "),
            spurious.join(" "),
            own_of_recording.join(" "),
            d.explained,
            d.seconds,
            margins.join(" "),
            serde_json::to_string(terms).unwrap_or_default().replace('"', "'")
        );
        tracing::info!("{name} case {case}: truth {terms:?}; found {:?}", d.terms);
        out!(
            "{name} case {case:3}  {}injected [{}]  found [{}]  {}{}{}",
            r.method,
            tn.join(", "),
            fnm.join(", "),
            errs.join(", "),
            if spurious.is_empty() { String::new() } else { format!("  [spurious: {}]", spurious.join(", ")) },
            if own_of_recording.is_empty() { String::new() } else { format!(" [alike in the mirror: {}]", own_of_recording.join(", ")) }
        )?;
        Ok(())
    }

    fn summary(&mut self, set: &InjectedSet, controls: Vec<serde_json::Value>) -> serde_json::Value {
        self.errors.sort_by(|a, b| a.total_cmp(b));
        serde_json::json!({
            "recordings": set.bags.len(),
            "cases": 2 * set.bags.len() * set.draws,
            "injected_terms": self.injected,
            "recall": self.found as f64 / self.injected.max(1) as f64,
            "spurious_terms": self.spurious,
            "spurious_rate": self.spurious as f64 / self.reported_beyond_control.max(1) as f64,
            "spurious_alike_in_the_mirror": {
                "rule": "of the spurious terms, those the mirrored case (the injected terms' signs turned) found with an effect within 20 % of this case's: the recording's own, not made by the injected sign",
                "terms": self.spurious_own,
                "rate_of_the_others": (self.spurious - self.spurious_own) as f64 / self.reported_beyond_control.max(1) as f64,
            },
            "parameters_within_20pct": self.within as f64 / self.found.max(1) as f64,
            "median_effect_error": self.errors.get(self.errors.len() / 2).copied().unwrap_or(f64::NAN),
            "cases_not_explained": self.not_explained,
            "recall_by_limit": {
                "rule": "each injected term against the smallest value the control (the recording as recorded) says it would have shown (report.json not_found): margin √Σ(θ/θ_min)² ≥ 1 is above it",
                "above_the_limit": {"injected": self.by_limit[0].0, "found": self.by_limit[0].1},
                "below_the_limit": {"injected": self.by_limit[1].0, "found": self.by_limit[1].1},
                "no_limit_stated": {"injected": self.by_limit[2].0, "found": self.by_limit[2].1},
            },
            "recall_by_term": self.by_term.iter().map(|(k, (i, f))| (k.to_string(), serde_json::json!({"injected": i, "found": f}))).collect::<serde_json::Map<_, _>>(),
            "controls": controls,
        })
    }
}
