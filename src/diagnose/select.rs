//! Model selection: which left-out terms explain the residual, judged on held-out blocks.
//!
//! Greedy forward selection: at each step every candidate not yet in the model is fitted
//! together with the chosen ones, and scored by its held-out log-likelihood gain (blocks of
//! time left out in turn, [`super::fit::evaluate`]). The best candidate enters when its gain
//! exceeds [`SelectOptions::threshold`] + [`SelectOptions::per_param`] × its parameter count,
//! a held-out likelihood-ratio threshold set on null recordings (no term left out) so that
//! they give no term. A backward pass then drops any chosen term (noise terms included)
//! whose removal costs less than the threshold, so a term that entered early and was made
//! redundant by a better explanation leaves. Competing explanations (delay vs low-pass, bias
//! vs g-sensitivity, misalignment vs mount rotation, walk vs temperature) meet as rival
//! candidates of one step; the one that predicts the held-out blocks better wins. Delay vs
//! low-pass and misalignment vs mount rotation are re-decided after every backward pass
//! ([`exchange`]), since the step that chose one may have come before a confounder was in.
//!
//! The vibration candidate's frequency is the strongest residual line the sim's motion does
//! not carry itself ([`MotionLines`]): at a motion line, the small misfit of any
//! motion-proportional term also makes a residual line.
//!
//! The bias-walk density of the residual is re-estimated (maximum likelihood, golden-section
//! search on log q) after every change of the model, so a slow drift is explained by the walk
//! unless a term predicts it better out of sample.

use nalgebra::DMatrix;

use super::catalogue::{atom_map, Catalogue};
use super::fit::{evaluate_fixed, Fit};
use super::golden::golden;
use super::psd::{periodogram_peak, MotionLines};
use super::residual::{block_stats, blocks, whitened, BlockStats, Column, ResidualNoise};
use super::DiagnoseError;
use crate::physics::{self, ImuSignals, LowPass, LowPassSensor, Term};

/// Options of the selection.
#[derive(Debug, Clone, Copy)]
pub struct SelectOptions {
    /// Time blocks for cross-validation.
    pub folds: usize,
    /// Held-out log-likelihood gain a term needs, plus `per_param` per parameter.
    pub threshold: f64,
    pub per_param: f64,
    /// Family-wise false-alarm probability of the vibration peak search.
    pub vibration_alpha: f64,
}

impl Default for SelectOptions {
    fn default() -> Self {
        SelectOptions { folds: 8, threshold: 12.0, per_param: 0.5, vibration_alpha: 1e-4 }
    }
}

/// A chosen linear candidate with its nonlinear parameter (T_ref; 0 otherwise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chosen {
    pub cand: usize,
    pub nonlinear: f64,
}

/// A noise-model term: changes the residual's noise, not only its mean.
#[derive(Debug, Clone, PartialEq)]
pub enum NoiseTerm {
    NoiseDensity { factor: f64 },
    LowPass { cutoff_hz: f64, sensor: LowPassSensor },
}

/// One step of the selection, for the report.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Step {
    pub action: String,
    pub term: String,
    /// Held-out log-likelihood gain of this step (whitened units).
    pub heldout_gain: f64,
    /// The runner-up candidate and its gain.
    pub runner_up: Option<(String, f64)>,
}

/// Everything the selection needs.
pub struct Problem<'a> {
    pub y: [Vec<f64>; 6],
    pub mask: Vec<bool>,
    pub base: &'a ImuSignals,
    pub catalogue: Catalogue,
    pub noise: ResidualNoise,
    /// The sensor noise the simulator states (per-sample variances), before any noise term.
    pub stated: (f64, f64),
    /// Judge gyro_noise_density (real and sim at the same rate).
    pub judge_noise_density: bool,
    /// The recordings are compared sample by sample (not as window means): the terms that
    /// live at high frequency (low_pass, vibration) are candidates.
    pub full_rate: bool,
    pub temperature: Option<(f64, f64)>,
    pub opts: SelectOptions,
    /// The sensors judged (the others' channels are zero in `y` and in every atom).
    pub sensors: super::Sensors,
    /// The sim recording's six channels (gyro, accel), unsmoothed: the motion's own spectral
    /// lines, where a residual line is a misfit of the motion rather than a vibration.
    pub sim: &'a [Vec<f64>; 6],
    /// The motion's lines ([`MotionLines`] of `sim`), built at the first vibration search.
    pub motion_lines: Option<MotionLines>,
}

/// The result.
#[derive(Debug, Clone)]
pub struct Selection {
    pub chosen: Vec<Chosen>,
    pub noise_terms: Vec<NoiseTerm>,
    pub noise: ResidualNoise,
    pub fit: Fit,
    pub steps: Vec<Step>,
    pub vibration_hz: f64,
    /// The residual the final fit is on (y minus fixed effects of noise terms).
    pub y: [Vec<f64>; 6],
    /// Baseline (no term) held-out log-likelihood per block and its noise model.
    pub baseline: Fit,
    pub baseline_noise: ResidualNoise,
    /// The catalogue, with the vibration candidate as last set.
    pub catalogue: Catalogue,
}

/// The design matrix of a set of chosen candidates.
pub fn design(cat: &Catalogue, chosen: &[Chosen]) -> DMatrix<f64> {
    let maps: Vec<DMatrix<f64>> = chosen.iter().map(|c| atom_map(cat, c.cand, c.nonlinear)).collect();
    let p: usize = maps.iter().map(|m| m.ncols()).sum();
    let mut a = DMatrix::zeros(cat.atoms.len(), p);
    let mut o = 0;
    for m in maps {
        a.view_mut((0, o), (m.nrows(), m.ncols())).copy_from(&m);
        o += m.ncols();
    }
    a
}

/// Statistics restricted to the atoms the chosen candidates use (for quick refits).
fn reduced(p: &Problem, y: &[Vec<f64>; 6], chosen: &[Chosen], noise: &ResidualNoise) -> (Vec<BlockStats>, DMatrix<f64>) {
    let a = design(&p.catalogue, chosen);
    let used: Vec<usize> = (0..a.nrows()).filter(|&r| a.row(r).iter().any(|v| *v != 0.0)).collect();
    let cols: Vec<&Column> = used.iter().map(|&i| &p.catalogue.atoms[i].column).collect();
    let bl = blocks(y[0].len(), p.opts.folds);
    let stats = block_stats(y, &cols, noise, &p.mask, &bl);
    let ar = DMatrix::from_fn(used.len(), a.ncols(), |r, c| a[(used[r], c)]);
    (stats, ar)
}

fn fit_reduced(p: &Problem, y: &[Vec<f64>; 6], chosen: &[Chosen], noise: &ResidualNoise) -> Fit {
    let (s, a) = reduced(p, y, chosen, noise);
    evaluate_fixed(&s, &a, &fixed_in_folds(&p.catalogue, chosen))
}

/// The β indices of the constant biases among `chosen`: held at their all-block values in
/// the held-out fits. A constant bias is told from the bias walk only by the walk's known
/// start (see [`drift_gain`]), i.e. by the first block; the other blocks leave it (nearly)
/// unidentified, so extrapolating it from them makes the first block's held-out prediction
/// arbitrary, and any term correlated with the bias there (accel scale along gravity,
/// gravity magnitude, lever arm, …) then "gains" by repairing that prediction.
fn fixed_in_folds(cat: &Catalogue, chosen: &[Chosen]) -> Vec<usize> {
    let mut out = Vec::new();
    let mut o = 0;
    for c in chosen {
        let cand = &cat.candidates[c.cand];
        if matches!(cand.name, "gyro_bias" | "accel_bias") {
            out.extend(o..o + cand.params);
        }
        o += cand.params;
    }
    out
}

/// The model with these noise terms: the residual with their fixed mean effects removed and
/// the noise model they imply (applied in order to the problem's own), the walk re-estimated,
/// and its fit.
fn with_noise_terms(p: &Problem, chosen: &[Chosen], terms: &[NoiseTerm]) -> Result<(Fit, [Vec<f64>; 6], ResidualNoise), DiagnoseError> {
    let (mut y, mut noise) = (p.y.clone(), p.noise);
    for t in terms {
        (y, noise) = apply_noise_term(p, t, &y, &noise)?;
    }
    estimate_walk(p, &y, chosen, &mut noise);
    let fit = fit_reduced(p, &y, chosen, &noise);
    Ok((fit, y, noise))
}

/// A model in which one explanation replaced its rival.
struct Exchange {
    removed: String,
    added: String,
    chosen: Vec<Chosen>,
    noise_terms: Vec<NoiseTerm>,
    fit: Fit,
}

/// Linear rivals: the same effect to first order, told apart by the rest of the signal.
const LINEAR_RIVALS: [(&str, &str); 2] = [("gyro_misalignment", "mount_rotation"), ("mount_rotation", "gyro_misalignment")];

/// Re-decide the rival explanations (delay vs low-pass, misalignment vs mount rotation) under
/// the current model: the greedy step that chose one of them may have been taken before a
/// confounding term was in. The rival replaces the chosen term when its model predicts the
/// held-out blocks better (per-parameter allowance included).
fn exchange(
    p: &Problem,
    chosen: &[Chosen],
    noise_terms: &[NoiseTerm],
    y: &[Vec<f64>; 6],
    noise: &ResidualNoise,
    current: &Fit,
) -> Result<Option<Exchange>, DiagnoseError> {
    let per_param = p.opts.per_param;
    let score = |fit: &Fit, params: usize| fit.loglik_cv - per_param * params as f64;
    let params_of =
        |p: &Problem, m: &[Chosen], t: &[NoiseTerm]| m.iter().map(|c| p.catalogue.candidates[c.cand].params).sum::<usize>() + t.len();
    let now = score(current, params_of(p, chosen, noise_terms));
    let mut best: Option<(f64, Exchange)> = None;
    let mut consider = |s: f64, x: Exchange| {
        if s > now + 1e-6 && best.as_ref().is_none_or(|b| s > b.0) {
            best = Some((s, x));
        }
    };
    let to = p.catalogue.candidate("time_offset");
    let to_chosen = to.and_then(|k| chosen.iter().position(|c| c.cand == k));
    // A low-pass in the model, time_offset not: try the delay instead.
    if let (Some(k), None) = (to, to_chosen) {
        for (j, t) in noise_terms.iter().enumerate().filter(|(_, t)| matches!(t, NoiseTerm::LowPass { .. })) {
            let mut terms = noise_terms.to_vec();
            terms.remove(j);
            let mut m = chosen.to_vec();
            m.push(Chosen { cand: k, nonlinear: 0.0 });
            let (fit, _, _) = with_noise_terms(p, &m, &terms)?;
            let s = score(&fit, params_of(p, &m, &terms));
            consider(s, Exchange { removed: noise_term_name(t).into(), added: "time_offset".into(), chosen: m, noise_terms: terms, fit });
        }
    }
    // time_offset in the model, no low-pass: try the best low-pass instead.
    if let Some(pos) = to_chosen.filter(|_| !noise_terms.iter().any(|t| matches!(t, NoiseTerm::LowPass { .. }))) {
        let mut m = chosen.to_vec();
        m.remove(pos);
        let (_, y0, n0) = with_noise_terms(p, &m, noise_terms)?;
        for (t, fit, _, _) in noise_candidates(p, &y0, &m, &n0, noise_terms)? {
            if !matches!(t, NoiseTerm::LowPass { .. }) {
                continue;
            }
            let mut terms = noise_terms.to_vec();
            terms.push(t);
            let s = score(&fit, params_of(p, &m, &terms));
            consider(s, Exchange { removed: "time_offset".into(), added: "low_pass".into(), chosen: m.clone(), noise_terms: terms, fit });
        }
    }
    for (have, rival) in LINEAR_RIVALS {
        let (Some(h), Some(r)) = (p.catalogue.candidate(have), p.catalogue.candidate(rival)) else { continue };
        let Some(pos) = chosen.iter().position(|c| c.cand == h) else { continue };
        if chosen.iter().any(|c| c.cand == r) {
            continue;
        }
        let mut m = chosen.to_vec();
        m[pos] = Chosen { cand: r, nonlinear: 0.0 };
        let mut n2 = *noise;
        estimate_walk(p, y, &m, &mut n2);
        let fit = fit_reduced(p, y, &m, &n2);
        let s = score(&fit, params_of(p, &m, noise_terms));
        consider(s, Exchange { removed: have.into(), added: rival.into(), chosen: m, noise_terms: noise_terms.to_vec(), fit });
    }
    Ok(best.map(|b| b.1))
}

/// Re-fit the reference temperature of a temperature term in `m` (in place), by in-sample
/// likelihood under `noise`. With a constant gyro bias beside it, k (T − T_ref) + b leaves
/// T_ref unidentified (the bias takes the constant), so whatever T_ref the term entered with
/// is arbitrary; the model without the bias must be judged at its own best T_ref — the bias
/// is nested in the temperature term's offset −k T_ref only once T_ref is free.
fn refit_reference(p: &Problem, y: &[Vec<f64>; 6], m: &mut [Chosen], noise: &ResidualNoise) {
    let Some(j) = m.iter().position(|c| p.catalogue.candidates[c.cand].name == "gyro_bias_temperature") else { return };
    // Atoms of the model at a non-zero T_ref, so the bias atoms the reference acts through are in.
    let mut probe = m.to_vec();
    probe[j].nonlinear = 1.0;
    let full = design(&p.catalogue, &probe);
    let used: Vec<usize> = (0..full.nrows()).filter(|&r| full.row(r).iter().any(|v| *v != 0.0)).collect();
    let cols: Vec<&Column> = used.iter().map(|&i| &p.catalogue.atoms[i].column).collect();
    let stats = block_stats(y, &cols, noise, &p.mask, &blocks(y[0].len(), p.opts.folds));
    let fixed = fixed_in_folds(&p.catalogue, m);
    let ll = |t: f64| {
        let mut mm = m.to_vec();
        mm[j].nonlinear = t;
        let a = design(&p.catalogue, &mm);
        let ar = DMatrix::from_fn(used.len(), a.ncols(), |r, c| a[(used[r], c)]);
        evaluate_fixed(&stats, &ar, &fixed).loglik
    };
    let (lo, hi) = p.temperature.unwrap_or((0.0, 50.0));
    let (t, best) = golden(lo - 40.0, hi + 40.0, 30, ll);
    if best > ll(m[j].nonlinear) {
        m[j].nonlinear = t;
    }
}

/// Maximum-likelihood walk variance per sensor for the chosen model.
fn estimate_walk(p: &Problem, y: &[Vec<f64>; 6], chosen: &[Chosen], noise: &mut ResidualNoise) {
    for s in (0..2).filter(|s| p.sensors.judges(*s)) {
        let white = noise.sensors[s].white_sim + noise.sensors[s].white_real;
        let lo = (white * 1e-12).log10();
        let hi = (white * 1e-1).log10();
        let (best, _) = golden(lo, hi, 22, |lq| {
            let mut n = *noise;
            n.sensors[s].walk = 10f64.powf(lq);
            fit_reduced(p, y, chosen, &n).loglik
        });
        noise.sensors[s].walk = 10f64.powf(best);
    }
}

/// The residual with the fixed mean effect of a low-pass removed, and its noise model.
fn apply_noise_term(
    p: &Problem,
    term: &NoiseTerm,
    y: &[Vec<f64>; 6],
    noise: &ResidualNoise,
) -> Result<([Vec<f64>; 6], ResidualNoise), DiagnoseError> {
    let mut n = *noise;
    let mut y2 = y.clone();
    match term {
        NoiseTerm::NoiseDensity { factor } => n.sensors[0].white_real = factor * factor * p.stated.0,
        NoiseTerm::LowPass { cutoff_hz, sensor } => {
            let dt = p.base.nominal_dt();
            let pole = (-std::f64::consts::TAU * cutoff_hz * dt).exp();
            for s in sensor.sensors() {
                n.sensors[*s as usize].pole = pole;
            }
            // The mean effect to first order: the filter's low-frequency delay a/(1−a)·dt times
            // the time_offset regressor (−ẋ), on the filtered sensors only. (The exact filter
            // applied to the base signals also filters the sim noise left in them, which the
            // residual does not contain.)
            let delay = pole / (1.0 - pole) * dt;
            let col = p.catalogue.candidate("time_offset").map(|k| &p.catalogue.atoms[p.catalogue.candidates[k].atoms[0]].column);
            for (c, v) in col.into_iter().flat_map(|c| c.iter().enumerate()) {
                let on = sensor.sensors().iter().any(|s| *s as usize == c / 3);
                if let (Some(v), true) = (v, on) {
                    y2[c].iter_mut().zip(v).for_each(|(a, b)| *a -= delay * b);
                }
            }
        }
    }
    Ok((y2, n))
}

/// Best gyro_noise_density and low_pass candidates given the chosen mean model.
fn noise_candidates(
    p: &Problem,
    y: &[Vec<f64>; 6],
    chosen: &[Chosen],
    noise: &ResidualNoise,
    have: &[NoiseTerm],
) -> Result<Vec<NoiseTrial>, DiagnoseError> {
    let mut out = Vec::new();
    if p.judge_noise_density && !have.iter().any(|t| matches!(t, NoiseTerm::NoiseDensity { .. })) {
        let (f, _) = golden(0.05f64.ln(), 5f64.ln(), 24, |lf| {
            let t = NoiseTerm::NoiseDensity { factor: lf.exp() };
            apply_noise_term(p, &t, y, noise).map(|(y2, n2)| fit_reduced(p, &y2, chosen, &n2).loglik).unwrap_or(f64::NEG_INFINITY)
        });
        let t = NoiseTerm::NoiseDensity { factor: f.exp() };
        let (y2, mut n2) = apply_noise_term(p, &t, y, noise)?;
        estimate_walk(p, &y2, chosen, &mut n2);
        let fit = fit_reduced(p, &y2, chosen, &n2);
        out.push((t, fit, n2, y2));
    }
    if p.full_rate && !have.iter().any(|t| matches!(t, NoiseTerm::LowPass { .. })) {
        let fs = 1.0 / p.base.nominal_dt();
        let judged = |sensor: &LowPassSensor| sensor.sensors().iter().all(|s| p.sensors.judges(*s as usize));
        for sensor in [LowPassSensor::Gyro, LowPassSensor::Accel, LowPassSensor::Both].into_iter().filter(judged) {
            let ll = |lc: f64| {
                let t = NoiseTerm::LowPass { cutoff_hz: lc.exp(), sensor };
                apply_noise_term(p, &t, y, noise).map(|(y2, n2)| fit_reduced(p, &y2, chosen, &n2).loglik).unwrap_or(f64::NEG_INFINITY)
            };
            // Coarse log grid, then golden section around the best point.
            let grid: Vec<f64> = (0..10).map(|k| (0.01 * fs).ln() + k as f64 * (100f64.ln() / 9.0)).collect();
            let vals: Vec<f64> = grid.iter().map(|&g| ll(g)).collect();
            let k = (0..grid.len()).max_by(|&a, &b| vals[a].total_cmp(&vals[b])).unwrap_or(0);
            tracing::debug!(
                "low_pass {sensor:?} grid: {:?}",
                grid.iter().zip(&vals).map(|(g, v)| format!("{:.1}:{v:.1}", g.exp())).collect::<Vec<_>>()
            );
            let step = grid[1] - grid[0];
            let (lc, _) = golden(grid[k] - step, grid[k] + step, 16, ll);
            let t = NoiseTerm::LowPass { cutoff_hz: lc.exp(), sensor };
            let (y2, mut n2) = apply_noise_term(p, &t, y, noise)?;
            estimate_walk(p, &y2, chosen, &mut n2);
            let fit = fit_reduced(p, &y2, chosen, &n2);
            out.push((t, fit, n2, y2));
        }
    }
    Ok(out)
}

/// A fitted noise-term candidate: the term, its fit, its noise model and residual.
type NoiseTrial = (NoiseTerm, Fit, ResidualNoise, [Vec<f64>; 6]);

/// A candidate of one round: name, gain, parameter count, the linear candidate or the index
/// of the noise trial.
type Trial = (String, f64, usize, Option<Chosen>, Option<usize>);

fn noise_term_name(t: &NoiseTerm) -> &'static str {
    match t {
        NoiseTerm::NoiseDensity { .. } => "gyro_noise_density",
        NoiseTerm::LowPass { .. } => "low_pass",
    }
}

/// The raw residual minus the fitted model (un-whitened), for peak searches and plots.
pub fn model_residual(cat: &Catalogue, y: &[Vec<f64>; 6], chosen: &[Chosen], beta: &nalgebra::DVector<f64>) -> [Vec<f64>; 6] {
    let a = design(cat, chosen);
    let theta = &a * beta;
    let mut r = y.clone();
    for (j, atom) in cat.atoms.iter().enumerate() {
        if theta[j] == 0.0 {
            continue;
        }
        for (c, col) in atom.column.iter().enumerate() {
            if let Some(v) = col {
                r[c].iter_mut().zip(v).for_each(|(a, b)| *a -= theta[j] * b);
            }
        }
    }
    r
}

/// Terms whose signal is a slow drift, competing with the bias walk.
const DRIFT_TERMS: [&str; 3] = ["gyro_bias", "accel_bias", "gyro_bias_temperature"];

/// The gain of a drift term. A constant bias is told from the bias walk only by the walk's
/// known start (W_0 = 0): its information sits in the first seconds, which no other time
/// block can predict, so cross-validation over blocks cannot see it. For the constant biases
/// the gain is therefore the in-sample log-likelihood ratio with a BIC penalty (p/2 ln n);
/// the temperature term keeps the held-out gain (its drift follows a measured input).
fn drift_gain(name: &str, with: &Fit, current: &Fit, n: usize, params: usize) -> f64 {
    if name == "gyro_bias_temperature" {
        with.loglik_cv - current.loglik_cv
    } else {
        with.loglik - current.loglik - 0.5 * params as f64 * (n as f64).ln()
    }
}

/// Run the selection: forward steps (the best candidate whose held-out gain clears its
/// threshold), each followed by backward drops and exchanges, for at most 12 rounds.
pub fn select(p: Problem) -> Result<Selection, DiagnoseError> {
    let mut s = Stepwise::start(p);
    let (baseline, baseline_noise) = (s.current.clone(), s.noise);
    for _round in 0..12 {
        s.place_vibration_candidate()?;
        let (trials, noise_trials) = s.trials()?;
        if !s.add_best(trials, noise_trials) {
            break;
        }
        s.drop_and_exchange()?;
    }
    let Stepwise { p, chosen, noise_terms, y, noise, steps, vibration_hz, .. } = s;
    let fit = fit_reduced(&p, &y, &chosen, &noise);
    Ok(Selection { chosen, noise_terms, noise, fit, steps, vibration_hz, y, baseline, baseline_noise, catalogue: p.catalogue })
}

/// The selection in progress: the terms chosen, the residual and noise model they are fitted
/// under, the current fit and the steps taken.
struct Stepwise<'a> {
    p: Problem<'a>,
    chosen: Vec<Chosen>,
    noise_terms: Vec<NoiseTerm>,
    y: [Vec<f64>; 6],
    noise: ResidualNoise,
    current: Fit,
    steps: Vec<Step>,
    vibration_hz: f64,
    /// Samples, and the cross-validation blocks over them.
    n: usize,
    blocks: Vec<std::ops::Range<usize>>,
}

impl<'a> Stepwise<'a> {
    /// No term chosen: the baseline fit under the walk estimated from the data.
    fn start(p: Problem<'a>) -> Self {
        let y = p.y.clone();
        let mut noise = p.noise;
        estimate_walk(&p, &y, &[], &mut noise);
        let current = fit_reduced(&p, &y, &[], &noise);
        let n = y[0].len();
        let blocks = blocks(n, p.opts.folds);
        Stepwise { p, chosen: Vec::new(), noise_terms: Vec::new(), y, noise, current, steps: Vec::new(), vibration_hz: 0.0, n, blocks }
    }

    /// The held-out gain a candidate with `params` parameters must clear.
    fn need(&self, params: usize) -> f64 {
        self.p.opts.threshold + self.p.opts.per_param * params as f64
    }

    /// A vibration candidate at the strongest accelerometer line of the current residual.
    fn place_vibration_candidate(&mut self) -> Result<(), DiagnoseError> {
        let p = &mut self.p;
        if !(p.full_rate && p.sensors.judges(1)) || self.chosen.iter().any(|c| p.catalogue.candidates[c.cand].name == "vibration") {
            return Ok(());
        }
        let r = model_residual(&p.catalogue, &self.y, &self.chosen, &self.current.beta);
        let w = whitened(&r, &self.noise, &p.mask);
        let dt = p.base.nominal_dt();
        // A line the motion itself carries (a gait harmonic) is where any motion-proportional
        // term's small misfit also makes a residual line: not evidence of an added vibration,
        // which the sim does not carry at all.
        let motion_lines = p.motion_lines.get_or_insert_with(|| MotionLines::new(&[&p.sim[..3], &p.sim[3..]], dt, p.opts.vibration_alpha));
        let motion_line = |f: f64| motion_lines.carries(f);
        if let Some(f) = periodogram_peak(&w[3..], dt, p.opts.vibration_alpha, motion_line) {
            tracing::debug!("vibration candidate at {f:.4} Hz");
            self.vibration_hz = f;
            p.catalogue.set_vibration(f, p.base)?;
        }
        Ok(())
    }

    /// Every candidate not chosen, with its held-out gain over the current fit, best first;
    /// and the noise terms' fits the trials index.
    fn trials(&self) -> Result<(Vec<Trial>, Vec<NoiseTrial>), DiagnoseError> {
        let (p, chosen, current) = (&self.p, &self.chosen, &self.current);
        // All atoms whitened under the current noise model.
        let cols: Vec<&Column> = p.catalogue.atoms.iter().map(|a| &a.column).collect();
        let stats = block_stats(&self.y, &cols, &self.noise, &p.mask, &self.blocks);
        let mut trials: Vec<Trial> = Vec::new();
        for (ci, cand) in p.catalogue.candidates.iter().enumerate() {
            if chosen.iter().any(|c| c.cand == ci) {
                continue;
            }
            let try_with = |nl: f64| {
                let mut m = chosen.clone();
                m.push(Chosen { cand: ci, nonlinear: nl });
                evaluate_fixed(&stats, &design(&p.catalogue, &m), &fixed_in_folds(&p.catalogue, &m))
            };
            let (nl, fit) = if cand.name == "gyro_bias_temperature" {
                let (lo, hi) = p.temperature.unwrap_or((0.0, 50.0));
                let (t, _) = golden(lo - 40.0, hi + 40.0, 30, |t| try_with(t).loglik);
                (t, try_with(t))
            } else {
                (0.0, try_with(0.0))
            };
            let this = Chosen { cand: ci, nonlinear: nl };
            let gain = if DRIFT_TERMS.contains(&cand.name) {
                // A slow drift competes with the bias walk: re-estimate the walk with the term in.
                let mut m = chosen.clone();
                m.push(this);
                let mut n2 = self.noise;
                estimate_walk(p, &self.y, &m, &mut n2);
                let f2 = fit_reduced(p, &self.y, &m, &n2);
                drift_gain(cand.name, &f2, current, self.n, cand.params)
            } else {
                fit.loglik_cv - current.loglik_cv
            };
            trials.push((cand.name.to_string(), gain, cand.params, Some(this), None));
        }
        let noise_trials = noise_candidates(p, &self.y, chosen, &self.noise, &self.noise_terms)?;
        for (k, (t, fit, _, _)) in noise_trials.iter().enumerate() {
            let params = 1;
            trials.push((noise_term_name(t).into(), fit.loglik_cv - current.loglik_cv, params, None, Some(k)));
        }
        trials.sort_by(|a, b| (b.1 - self.need(b.2)).total_cmp(&(a.1 - self.need(a.2))));
        tracing::debug!("selection round: {:?}", trials.iter().map(|t| format!("{} {:.1}", t.0, t.1)).collect::<Vec<_>>());
        Ok((trials, noise_trials))
    }

    /// Adds the best trial if it clears its threshold; false when none does.
    fn add_best(&mut self, trials: Vec<Trial>, noise_trials: Vec<NoiseTrial>) -> bool {
        let Some(best) = trials.first().cloned() else { return false };
        if best.1 < self.need(best.2) {
            return false;
        }
        let runner_up = trials.get(1).map(|t| (t.0.clone(), t.1));
        match (best.3, best.4) {
            (Some(c), _) => self.chosen.push(c),
            (None, Some(k)) => {
                let (t, _, n2, y2) = noise_trials[k].clone();
                self.noise_terms.push(t);
                self.noise = n2;
                self.y = y2;
            }
            _ => return false,
        }
        self.steps.push(Step { action: "add".into(), term: best.0.clone(), heldout_gain: best.1, runner_up });
        estimate_walk(&self.p, &self.y, &self.chosen, &mut self.noise);
        self.current = fit_reduced(&self.p, &self.y, &self.chosen, &self.noise);
        true
    }

    /// Backward: drop a chosen term whose removal costs less than its threshold; then
    /// re-decide the rival explanations under the model as it now stands.
    fn drop_and_exchange(&mut self) -> Result<(), DiagnoseError> {
        for _ in 0..24 {
            if self.drop_cheapest()? {
                continue;
            }
            let Some(x) = exchange(&self.p, &self.chosen, &self.noise_terms, &self.y, &self.noise, &self.current)? else { break };
            self.steps.push(Step {
                action: "swap".into(),
                term: x.added.clone(),
                heldout_gain: x.fit.loglik_cv - self.current.loglik_cv,
                runner_up: Some((x.removed.clone(), 0.0)),
            });
            (self.chosen, self.noise_terms) = (x.chosen, x.noise_terms);
            (self.current, self.y, self.noise) = with_noise_terms(&self.p, &self.chosen, &self.noise_terms)?;
        }
        Ok(())
    }

    /// Drops the term (or noise term) whose removal costs least, if below its threshold.
    fn drop_cheapest(&mut self) -> Result<bool, DiagnoseError> {
        let p = &self.p;
        let mut worst: Option<(Option<Vec<Chosen>>, usize, f64)> = None;
        for k in 0..self.chosen.len() {
            let mut m = self.chosen.clone();
            let removed = m.remove(k);
            refit_reference(p, &self.y, &mut m, &self.noise);
            let name = p.catalogue.candidates[removed.cand].name;
            let params = p.catalogue.candidates[removed.cand].params;
            let loss = if DRIFT_TERMS.contains(&name) {
                let mut n2 = self.noise;
                estimate_walk(p, &self.y, &m, &mut n2);
                drift_gain(name, &self.current, &fit_reduced(p, &self.y, &m, &n2), self.n, params)
            } else {
                self.current.loglik_cv - fit_reduced(p, &self.y, &m, &self.noise).loglik_cv
            };
            if loss < self.need(params) && worst.as_ref().is_none_or(|w| loss < w.2) {
                worst = Some((Some(m), k, loss));
            }
        }
        for j in 0..self.noise_terms.len() {
            let mut terms = self.noise_terms.clone();
            terms.remove(j);
            let (fit, _, _) = with_noise_terms(p, &self.chosen, &terms)?;
            let loss = self.current.loglik_cv - fit.loglik_cv;
            if loss < self.need(1) && worst.as_ref().is_none_or(|w| loss < w.2) {
                worst = Some((None, j, loss));
            }
        }
        let Some((k, j, loss)) = worst else { return Ok(false) };
        let term = match k {
            Some(m) => {
                let name = self.p.catalogue.candidates[self.chosen[j].cand].name.to_string();
                self.chosen = m;
                name
            }
            None => noise_term_name(&self.noise_terms.remove(j)).to_string(),
        };
        self.steps.push(Step { action: "drop".into(), term, heldout_gain: -loss, runner_up: None });
        (self.current, self.y, self.noise) = with_noise_terms(&self.p, &self.chosen, &self.noise_terms)?;
        Ok(true)
    }
}

/// The fitted physics terms of a selection, with their 1-σ uncertainties per parameter.
pub fn terms_of(sel: &Selection) -> Vec<(Term, Vec<f64>)> {
    let cat = &sel.catalogue;
    let mut out = Vec::new();
    let mut o = 0;
    for c in &sel.chosen {
        let cand = &cat.candidates[c.cand];
        let beta: Vec<f64> = (0..cand.params).map(|k| sel.fit.beta[o + k]).collect();
        let sd: Vec<f64> = (0..cand.params).map(|k| sel.fit.cov[(o + k, o + k)].max(0.0).sqrt()).collect();
        o += cand.params;
        out.push((super::catalogue::to_term(cand.name, &beta, c.nonlinear, sel.vibration_hz), sd));
    }
    for t in &sel.noise_terms {
        let term = match t {
            NoiseTerm::NoiseDensity { factor } => Term::GyroNoiseDensity(physics::GyroNoiseDensity { factor: *factor }),
            NoiseTerm::LowPass { cutoff_hz, sensor } => Term::LowPass(LowPass { cutoff_hz: *cutoff_hz, sensor: *sensor }),
        };
        out.push((term, vec![]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::residual::ChannelNoise;
    use nalgebra::{UnitQuaternion, Vector3};

    /// A gyro bias k (T − 30 °C) on a warming die. Entered beside a constant bias, the
    /// temperature term's T_ref is arbitrary (here 0 °C); re-fitted without the bias it
    /// comes back to the true reference, so the bias is judged against the nested model.
    #[test]
    fn reference_temperature_is_refitted_without_the_bias() {
        let n = 20_000;
        let dt = 0.01;
        let temp: Vec<f64> = (0..n).map(|i| 20.0 + 20.0 * (1.0 - (-(i as f64 * dt) / 60.0).exp())).collect();
        let base = ImuSignals {
            stamps_ns: (0..n as i64).map(|i| i * 10_000_000).collect(),
            world_from_imu: vec![UnitQuaternion::identity(); n],
            alpha_in_imu: vec![Vector3::zeros(); n],
            temperature_c: temp.clone(),
            gyro: (0..n).map(|i| Vector3::new((i as f64 * 0.01).sin(), 0.2, 0.0)).collect(),
            accel: vec![Vector3::new(0.0, 0.0, 9.81); n],
        };
        let cat = Catalogue::build(&base, true, Some(20.0)).unwrap();
        let k = [3e-4, -2e-4, 5e-4];
        let mut u = crate::diagnose::residual::tests::uniform(7);
        let mut noise = || (u() - 0.5) * 1e-3;
        let y: [Vec<f64>; 6] =
            std::array::from_fn(|c| (0..n).map(|i| if c < 3 { k[c] * (temp[i] - 30.0) + noise() } else { noise() }).collect());
        let white = 1e-6 / 12.0;
        let ch = ChannelNoise { white_sim: white / 2.0, white_real: white / 2.0, pole: 0.0, walk: white * 1e-9 };
        let sim: [Vec<f64>; 6] = std::array::from_fn(|_| vec![0.0; n]);
        let p = Problem {
            y: y.clone(),
            mask: vec![true; n],
            base: &base,
            catalogue: cat,
            noise: ResidualNoise { sensors: [ch, ch] },
            stated: (white / 2.0, white / 2.0),
            judge_noise_density: false,
            full_rate: true,
            temperature: Some((20.0, 40.0)),
            opts: SelectOptions::default(),
            sensors: super::super::Sensors::Both,
            sim: &sim,
            motion_lines: None,
        };
        let temp_cand = p.catalogue.candidate("gyro_bias_temperature").unwrap();
        let mut m = vec![Chosen { cand: temp_cand, nonlinear: 0.0 }];
        refit_reference(&p, &y, &mut m, &p.noise);
        assert!((m[0].nonlinear - 30.0).abs() < 0.5, "T_ref {}", m[0].nonlinear);
        // Without a temperature term nothing changes.
        let bias = p.catalogue.candidate("gyro_bias").unwrap();
        let mut only_bias = vec![Chosen { cand: bias, nonlinear: 0.0 }];
        refit_reference(&p, &y, &mut only_bias, &p.noise);
        assert_eq!(only_bias[0].nonlinear, 0.0);
    }
}
