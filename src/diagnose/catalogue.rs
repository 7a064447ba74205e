//! The catalogue of left-out physics the diagnosis can name, as regressors.
//!
//! Every candidate is a vocabulary term of [`crate::physics`]. Its regressors ("atoms") are
//! the term's own forward model, applied to the base signals: the effect of a small step
//! in one parameter, divided by the step (a finite-difference Jacobian at the identity; the
//! exact column for the terms that are linear in their parameters). Nothing here
//! re-implements a term's physics.
//!
//! Parameters of the terms that are not linear are handled as follows: `time_offset` and
//! `mount_rotation` are linear to first order at the sizes that matter (τ ≪ dt,
//! ‖rotvec‖ ≪ 1) and are refined by Gauss–Newton after selection; `gyro_bias_temperature`'s
//! reference temperature and `earth_rotation`'s latitude enter through a fixed linear map of
//! two atoms; `vibration`'s frequency, `low_pass`'s cutoff and `gyro_noise_density`'s factor
//! are 1-D searches in [`super::select`]; `quantization` and `saturation` are read directly
//! off the real samples ([`detect_quantization`], [`detect_saturation`]).

use nalgebra::{DMatrix, Vector3};

use super::residual::Column;
use super::DiagnoseError;
use crate::physics::{self, ImuSignals, Term};

/// One regressor: the effect of a unit parameter step on the six channels.
#[derive(Debug, Clone)]
pub struct Atom {
    /// `term.param[index]`.
    pub label: String,
    pub column: Column,
}

/// How a candidate's parameters map to atoms.
#[derive(Debug, Clone, PartialEq)]
pub enum Map {
    /// One parameter per atom.
    Direct,
    /// k_i (T − T_ref): atoms T·e_i (first three) and the gyro-bias atoms e_i (last three).
    Temperature,
}

/// A term the diagnosis can name.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// Vocabulary name.
    pub name: &'static str,
    /// Atom indices this candidate uses.
    pub atoms: Vec<usize>,
    /// Number of free parameters.
    pub params: usize,
    pub map: Map,
}

/// The catalogue for one recording.
#[derive(Debug, Clone, Default)]
pub struct Catalogue {
    pub atoms: Vec<Atom>,
    pub candidates: Vec<Candidate>,
    /// Why a vocabulary term is not a candidate here.
    pub excluded: Vec<(String, String)>,
}

/// A term's effect on the base signals as a column (None on channels it does not touch).
pub fn effect_column(term: &Term, base: &ImuSignals) -> Result<Column, DiagnoseError> {
    let physics::Effect { gyro: dg, accel: da } = physics::effect(term, base, 0)?;
    Ok(std::array::from_fn(|c| {
        let v: Vec<f64> = if c < 3 { dg.iter().map(|d| d[c]).collect() } else { da.iter().map(|d| d[c - 3]).collect() };
        v.iter().any(|x| *x != 0.0).then_some(v)
    }))
}

/// (column of a step) / step.
fn scaled(mut col: Column, step: f64) -> Column {
    for v in col.iter_mut().flatten() {
        v.iter_mut().for_each(|x| *x /= step);
    }
    col
}

fn unit(i: usize) -> [f64; 3] {
    let mut e = [0.0; 3];
    e[i] = 1.0;
    e
}

/// Off-diagonal (row, col) pairs of a 3×3 matrix, row-major.
pub const OFF_DIAGONAL: [(usize, usize); 6] = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)];

impl Catalogue {
    fn push(&mut self, label: String, column: Column) -> usize {
        self.atoms.push(Atom { label, column });
        self.atoms.len() - 1
    }

    fn linear(
        &mut self,
        name: &'static str,
        labels_terms: Vec<(String, Term, f64)>,
        base: &ImuSignals,
    ) -> Result<Vec<usize>, DiagnoseError> {
        let mut idx = Vec::new();
        for (label, term, step) in labels_terms {
            let col = scaled(effect_column(&term, base)?, step);
            idx.push(self.push(format!("{name}.{label}"), col));
        }
        Ok(idx)
    }

    /// The bias, scale and misalignment of sensor `S`, in that order, as regressors; returns
    /// the bias's atoms (the temperature term extends them).
    fn sensor_terms<S: physics::SensorKind>(&mut self, base: &ImuSignals) -> Result<Vec<usize>, DiagnoseError>
    where
        Term: From<physics::Bias<S>> + From<physics::Scale<S>> + From<physics::Misalignment<S>>,
    {
        use physics::{Bias, ErrorTerm, Misalignment, Scale};
        let step = 1e-3;
        let label = |name: &str, i: usize| format!("{name}[{i}]");
        let bias = (0..3).map(|i| (label("bias", i), Term::from(Bias::<S>::new(unit(i))), 1.0)).collect();
        let bias = self.linear(Bias::<S>::NAME, bias, base)?;
        self.add(Bias::<S>::NAME, bias.clone(), Map::Direct);
        let scale = (0..3).map(|i| (label("scale", i), Term::from(Scale::<S>::new(unit(i).map(|x| x * step))), step)).collect();
        let scale = self.linear(Scale::<S>::NAME, scale, base)?;
        self.add(Scale::<S>::NAME, scale, Map::Direct);
        let off = OFF_DIAGONAL
            .iter()
            .map(|&(r, c)| {
                let mut m = [[0.0; 3]; 3];
                m[r][c] = step;
                (format!("matrix[{r}][{c}]"), Term::from(Misalignment::<S>::new(m)), step)
            })
            .collect();
        let off = self.linear(Misalignment::<S>::NAME, off, base)?;
        self.add(Misalignment::<S>::NAME, off, Map::Direct);
        Ok(bias)
    }

    fn add(&mut self, name: &'static str, atoms: Vec<usize>, map: Map) {
        let params = match map {
            Map::Direct => atoms.len(),
            Map::Temperature => 3,
        };
        self.candidates.push(Candidate { name, atoms, params, map });
    }

    /// Replace the time_offset atom by −ẋ (x(t − τ) − x(t) ≈ −τ ẋ) with the derivatives
    /// given, for signals whose own differences would not give them (window means).
    pub fn set_time_offset_derivatives(&mut self, gyro: &[Vector3<f64>], accel: &[Vector3<f64>]) {
        let Some(c) = self.candidate("time_offset") else { return };
        let atom = self.candidates[c].atoms[0];
        let col: Column = std::array::from_fn(|k| {
            let v: Vec<f64> = if k < 3 { gyro.iter().map(|d| -d[k]).collect() } else { accel.iter().map(|d| -d[k - 3]).collect() };
            self.atoms[atom].column[k].as_ref().map(|_| v)
        });
        self.atoms[atom].column = col;
    }

    /// The candidate called `name`.
    pub fn candidate(&self, name: &str) -> Option<usize> {
        self.candidates.iter().position(|c| c.name == name)
    }

    /// Build the catalogue's linear candidates on the base signals. `has_attitude`: the
    /// attitude is ground truth (needed by gravity_magnitude, earth_rotation);
    /// `temperature_span`: range of the die temperature, K.
    pub fn build(base: &ImuSignals, has_attitude: bool, temperature_span: Option<f64>) -> Result<Self, DiagnoseError> {
        use physics::*;
        let mut cat = Catalogue::default();
        let v3 = |name: &str, i: usize| format!("{name}[{i}]");
        let m3 = |r: usize, c: usize| format!("matrix[{r}][{c}]");
        let mat = |r: usize, c: usize, v: f64| {
            let mut m = [[0.0; 3]; 3];
            m[r][c] = v;
            m
        };

        let gb = cat.sensor_terms::<Gyro>(base)?;
        let step = 1e-3;
        let a = cat.linear(
            "gyro_g_sensitivity",
            (0..9)
                .map(|k| (m3(k / 3, k % 3), Term::GyroGSensitivity(GyroGSensitivity { matrix: mat(k / 3, k % 3, step) }), step))
                .collect(),
            base,
        )?;
        cat.add("gyro_g_sensitivity", a, Map::Direct);
        match temperature_span {
            Some(span) if span > 1.0 => {
                let mut a = cat.linear(
                    "gyro_bias_temperature",
                    (0..3)
                        .map(|i| {
                            (
                                v3("coefficient", i),
                                Term::GyroBiasTemperature(GyroBiasTemperature { coefficient: unit(i), reference_c: 0.0 }),
                                1.0,
                            )
                        })
                        .collect(),
                    base,
                )?;
                a.extend(&gb);
                cat.add("gyro_bias_temperature", a, Map::Temperature);
            }
            _ => cat.excluded.push(("gyro_bias_temperature".into(), "the die temperature is unknown or spans less than 1 K".into())),
        }
        cat.sensor_terms::<Accel>(base)?;
        let rstep = 1e-6;
        let a = cat.linear(
            "mount_rotation",
            (0..3).map(|i| (v3("rotvec", i), Term::MountRotation(MountRotation { rotvec: unit(i).map(|x| x * rstep) }), rstep)).collect(),
            base,
        )?;
        cat.add("mount_rotation", a, Map::Direct);
        let lstep = 1e-2;
        let a = cat.linear(
            "lever_arm",
            (0..3).map(|i| (v3("offset", i), Term::LeverArm(LeverArm { offset: unit(i).map(|x| x * lstep) }), lstep)).collect(),
            base,
        )?;
        cat.add("lever_arm", a, Map::Direct);
        let tstep = 1e-6;
        let a = cat.linear("time_offset", vec![("seconds".into(), Term::TimeOffset(TimeOffset { seconds: tstep }), tstep)], base)?;
        cat.add("time_offset", a, Map::Direct);
        if has_attitude {
            let a = cat.linear(
                "gravity_magnitude",
                vec![("g".into(), Term::GravityMagnitude(GravityMagnitude { g: NOMINAL_GRAVITY + 1e-3 }), 1e-3)],
                base,
            )?;
            cat.add("gravity_magnitude", a, Map::Direct);
            let rate = earth_rotation::EARTH_RATE;
            let a = cat.linear(
                "earth_rotation",
                vec![
                    ("cos_latitude".into(), Term::EarthRotation(EarthRotation { latitude_rad: 0.0, rate_rad_s: rate }), 1.0),
                    (
                        "sin_latitude".into(),
                        Term::EarthRotation(EarthRotation { latitude_rad: std::f64::consts::FRAC_PI_2, rate_rad_s: rate }),
                        1.0,
                    ),
                ],
                base,
            )?;
            cat.add("earth_rotation", a, Map::Direct);
        } else {
            for t in ["gravity_magnitude", "earth_rotation"] {
                cat.excluded.push((t.into(), "no ground-truth attitude".into()));
            }
        }
        Ok(cat)
    }

    /// Keep only the judged sensors' channels in every atom, and drop the candidates left
    /// without any (listed under `excluded`).
    pub fn restrict(&mut self, sensors: super::Sensors) {
        if sensors == super::Sensors::Both {
            return;
        }
        for atom in &mut self.atoms {
            for (c, col) in atom.column.iter_mut().enumerate() {
                if !sensors.judges(c / 3) {
                    *col = None;
                }
            }
        }
        let atoms = &self.atoms;
        let (keep, drop): (Vec<Candidate>, Vec<Candidate>) = std::mem::take(&mut self.candidates)
            .into_iter()
            .partition(|cand| cand.atoms.iter().any(|&a| atoms[a].column.iter().any(Option::is_some)));
        self.candidates = keep;
        for cand in drop {
            self.excluded.push((cand.name.into(), format!("--sensors {}: the term acts only on the sensor not judged", sensors.name())));
        }
        if !sensors.judges(1) {
            self.excluded.push(("vibration".into(), format!("--sensors {}: the accelerometer is not judged", sensors.name())));
        }
        // One sensor alone cannot tell a turned frame from its own cross-axis errors: a small
        // rotation is exactly the antisymmetric part of its misalignment, which reports it.
        let misalignment = if sensors.judges(0) { "gyro_misalignment" } else { "accel_misalignment" };
        if self.candidates.iter().any(|c| c.name == "mount_rotation") {
            self.candidates.retain(|c| c.name != "mount_rotation");
            self.excluded.push((
                "mount_rotation".into(),
                format!(
                    "--sensors {}: with one sensor a small frame rotation is the antisymmetric part of {misalignment}, reported there",
                    sensors.name()
                ),
            ));
        }
    }

    /// Add a vibration candidate at `frequency_hz` (sin and cos atoms per axis); replaces a
    /// previous one.
    pub fn set_vibration(&mut self, frequency_hz: f64, base: &ImuSignals) -> Result<usize, DiagnoseError> {
        let mut labels = Vec::new();
        for (k, phase) in [(0usize, 0.0), (1, std::f64::consts::FRAC_PI_2)] {
            for i in 0..3 {
                let mut ph = [0.0; 3];
                ph[i] = phase;
                let t = Term::Vibration(physics::Vibration { frequency_hz, accel_amplitude: unit(i), phase_rad: ph });
                labels.push((format!("{}[{i}]", if k == 0 { "sin" } else { "cos" }), t, 1.0));
            }
        }
        if let Some(old) = self.candidate("vibration") {
            // Reuse the atom slots.
            let slots = self.candidates[old].atoms.clone();
            for (slot, (label, term, _)) in slots.iter().zip(labels) {
                self.atoms[*slot] = Atom { label: format!("vibration.{label}"), column: effect_column(&term, base)? };
            }
            return Ok(old);
        }
        let a = self.linear("vibration", labels, base)?;
        self.add("vibration", a, Map::Direct);
        Ok(self.candidates.len() - 1)
    }
}

/// The affine map from a candidate's parameters to all atoms (n_atoms × params), given its
/// nonlinear parameter (T_ref for the temperature term).
pub fn atom_map(cat: &Catalogue, cand: usize, nonlinear: f64) -> DMatrix<f64> {
    let c = &cat.candidates[cand];
    let mut a = DMatrix::zeros(cat.atoms.len(), c.params);
    match c.map {
        Map::Direct => {
            for (p, &atom) in c.atoms.iter().enumerate() {
                a[(atom, p)] = 1.0;
            }
        }
        Map::Temperature => {
            for i in 0..3 {
                a[(c.atoms[i], i)] = 1.0;
                a[(c.atoms[3 + i], i)] = -nonlinear;
            }
        }
    }
    a
}

/// Read a fitted candidate's parameters as a physics term.
pub fn to_term(name: &str, beta: &[f64], nonlinear: f64, vibration_hz: f64) -> Term {
    use physics::*;
    let v = |o: usize| [beta[o], beta[o + 1], beta[o + 2]];
    let off = |b: &[f64]| {
        let mut m = [[0.0; 3]; 3];
        for (k, &(r, c)) in OFF_DIAGONAL.iter().enumerate() {
            m[r][c] = b[k];
        }
        m
    };
    match name {
        "gyro_bias" => Term::GyroBias(GyroBias::new(v(0))),
        "gyro_scale" => Term::GyroScale(GyroScale::new(v(0))),
        "gyro_misalignment" => Term::GyroMisalignment(GyroMisalignment::new(off(beta))),
        "gyro_g_sensitivity" => Term::GyroGSensitivity(GyroGSensitivity { matrix: [v(0), v(3), v(6)] }),
        "gyro_bias_temperature" => Term::GyroBiasTemperature(GyroBiasTemperature { coefficient: v(0), reference_c: nonlinear }),
        "accel_bias" => Term::AccelBias(AccelBias::new(v(0))),
        "accel_scale" => Term::AccelScale(AccelScale::new(v(0))),
        "accel_misalignment" => Term::AccelMisalignment(AccelMisalignment::new(off(beta))),
        "mount_rotation" => Term::MountRotation(MountRotation { rotvec: v(0) }),
        "lever_arm" => Term::LeverArm(LeverArm { offset: v(0) }),
        "time_offset" => Term::TimeOffset(TimeOffset { seconds: beta[0] }),
        "gravity_magnitude" => Term::GravityMagnitude(GravityMagnitude { g: NOMINAL_GRAVITY + beta[0] }),
        "earth_rotation" => Term::EarthRotation(EarthRotation {
            latitude_rad: beta[1].atan2(beta[0]).clamp(-std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_2),
            rate_rad_s: earth_rotation::EARTH_RATE,
        }),
        "vibration" => {
            let amp: [f64; 3] = std::array::from_fn(|i| beta[i].hypot(beta[3 + i]));
            let phase: [f64; 3] = std::array::from_fn(|i| beta[3 + i].atan2(beta[i]));
            Term::Vibration(Vibration { frequency_hz: vibration_hz, accel_amplitude: amp, phase_rad: phase })
        }
        other => unreachable!("no linear candidate {other}"),
    }
}

/// A term's parameters in its candidate's atom order (the inverse of [`to_term`]), for the
/// terms with one parameter per atom; `None` for the others.
pub fn parameters(term: &Term) -> Option<Vec<f64>> {
    let off = |m: &[[f64; 3]; 3]| OFF_DIAGONAL.iter().map(|&(r, c)| m[r][c]).collect();
    Some(match term {
        Term::GyroBias(t) => t.bias.to_vec(),
        Term::AccelBias(t) => t.bias.to_vec(),
        Term::GyroScale(t) => t.scale.to_vec(),
        Term::AccelScale(t) => t.scale.to_vec(),
        Term::GyroMisalignment(t) => off(&t.matrix),
        Term::AccelMisalignment(t) => off(&t.matrix),
        Term::GyroGSensitivity(t) => t.matrix.iter().flatten().copied().collect(),
        Term::MountRotation(t) => t.rotvec.to_vec(),
        Term::LeverArm(t) => t.offset.to_vec(),
        Term::TimeOffset(t) => vec![t.seconds],
        Term::GravityMagnitude(t) => vec![t.g - physics::NOMINAL_GRAVITY],
        _ => return None,
    })
}

/// The term with each parameter moved toward zero by up to `k` of its σ (`sd`, in the atom
/// order of [`parameters`]), not past zero: within its ±kσ box, the value nearest a plausible
/// size for every term [`PLAUSIBLE`] measures by size (for `gravity_magnitude`, the nominal g).
/// `None` for the terms with other parameters, or without σ.
pub fn nearest_plausible(term: &Term, sd: &[f64], k: f64) -> Option<Term> {
    let beta = parameters(term)?;
    if sd.len() != beta.len() {
        return None;
    }
    let shrunk: Vec<f64> = beta.iter().zip(sd).map(|(b, s)| b.signum() * (b.abs() - k * s).max(0.0)).collect();
    Some(to_term(term.name(), &shrunk, 0.0, 0.0))
}

/// Parameter names and values of a term as the vocabulary writes them (JSON).
pub fn params_json(term: &Term) -> serde_json::Value {
    let mut v = serde_json::to_value(term).unwrap_or(serde_json::Value::Null);
    if let Some(m) = v.as_object_mut() {
        m.remove("term");
    }
    v
}

/// Is the channel a lattice of step `lsb`: every value within 1e-6 lsb of a multiple?
fn on_lattice(x: &[f64], lsb: f64) -> bool {
    x.iter().all(|v| {
        let r = v / lsb;
        (r - r.round()).abs() < 1e-6 * r.abs().max(1.0)
    })
}

/// The quantisation step of a sensor's three channels, when the real samples sit on a
/// lattice the sim samples do not: the smallest non-zero difference between sorted values,
/// confirmed by every sample being a multiple of it.
pub fn detect_quantization(real: &[Vec<f64>], sim: &[Vec<f64>]) -> Option<f64> {
    let mut vals: Vec<f64> = real.iter().flat_map(|c| c.iter().copied()).collect();
    vals.sort_by(|a, b| a.total_cmp(b));
    vals.dedup();
    if vals.len() > real.iter().map(|c| c.len()).sum::<usize>() / 4 {
        return None; // float data: nearly every value distinct
    }
    let lsb = vals.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).fold(f64::INFINITY, f64::min);
    // The smallest gap can be a multiple of the step only if no two values are one step apart;
    // with noise spanning many steps that does not happen, so accept it when it fits.
    (lsb.is_finite() && real.iter().all(|c| on_lattice(c, lsb)) && !sim.iter().all(|c| on_lattice(c, lsb))).then_some(lsb)
}

/// The clipping level of a sensor's three channels: at least three real samples at the
/// largest magnitude while the sim goes beyond it there.
pub fn detect_saturation(real: &[Vec<f64>], sim: &[Vec<f64>], sim_sigma: f64) -> Option<(f64, Vec<usize>)> {
    let m = real.iter().flat_map(|c| c.iter()).fold(0.0f64, |a, v| a.max(v.abs()));
    let mut idx = Vec::new();
    let mut beyond = 0;
    for (rc, sc) in real.iter().zip(sim) {
        for (i, (r, s)) in rc.iter().zip(sc).enumerate() {
            if r.abs() >= m * (1.0 - 1e-12) {
                idx.push(i);
                if s.abs() > m + 3.0 * sim_sigma {
                    beyond += 1;
                }
            }
        }
    }
    (idx.len() >= 3 && beyond >= 2).then(|| {
        idx.sort_unstable();
        idx.dedup();
        (m, idx)
    })
}

/// The physically plausible range of one catalogue term's size, with why. A fit outside it
/// (or pinned at a bound of its own search) is the best the catalogue can do with a mismatch
/// it does not hold, not a property of a sensor, and is reported apart from the findings.
#[derive(Debug, Clone, Copy)]
pub struct Plausible {
    pub term: &'static str,
    /// What is compared (as [`plausibility_measure`] computes it).
    pub quantity: &'static str,
    pub lo: f64,
    pub hi: f64,
    pub unit: &'static str,
    /// The range as a person reads it.
    pub shown: &'static str,
    pub why: &'static str,
}

/// Datasheet-level ranges, one per term (those without one, e.g. `mount_rotation`,
/// `quantization`, `saturation`, can have any size or are read off the samples).
pub const PLAUSIBLE: &[Plausible] = &[
    Plausible {
        term: "gyro_bias",
        shown: "|bias| ≤ 0.175 rad/s (10 °/s)",
        quantity: "largest |bias|",
        lo: 0.0,
        hi: 0.175,
        unit: "rad/s",
        why: "MEMS gyro turn-on bias is within ±5 °/s on consumer datasheets; 10 °/s is twice that",
    },
    Plausible {
        term: "accel_bias",
        shown: "|bias| ≤ 1.5 m/s²",
        quantity: "largest |bias|",
        lo: 0.0,
        hi: 1.5,
        unit: "m/s²",
        why: "MEMS accelerometer zero-g offset is within ±150 mg (1.5 m/s²) on consumer datasheets",
    },
    Plausible {
        term: "gyro_scale",
        shown: "|scale| ≤ 0.05",
        quantity: "largest |scale|",
        lo: 0.0,
        hi: 0.05,
        unit: "",
        why: "gyro sensitivity tolerance is ±1–3 % on MEMS datasheets",
    },
    Plausible {
        term: "accel_scale",
        shown: "|scale| ≤ 0.05",
        quantity: "largest |scale|",
        lo: 0.0,
        hi: 0.05,
        unit: "",
        why: "accelerometer sensitivity tolerance is ±1–3 % on MEMS datasheets",
    },
    Plausible {
        term: "gyro_misalignment",
        shown: "|off-diagonal| ≤ 0.03",
        quantity: "largest |off-diagonal|",
        lo: 0.0,
        hi: 0.03,
        unit: "",
        why: "cross-axis sensitivity is ±1–2 % on MEMS datasheets (a larger rotation of the whole frame is mount_rotation)",
    },
    Plausible {
        term: "accel_misalignment",
        shown: "|off-diagonal| ≤ 0.03",
        quantity: "largest |off-diagonal|",
        lo: 0.0,
        hi: 0.03,
        unit: "",
        why: "cross-axis sensitivity is ±1–2 % on MEMS datasheets (a larger rotation of the whole frame is mount_rotation)",
    },
    Plausible {
        term: "gyro_g_sensitivity",
        shown: "|element| ≤ 1e-3 rad/s per m/s²",
        quantity: "largest |element|",
        lo: 0.0,
        hi: 1e-3,
        unit: "rad/s per m/s²",
        why: "MEMS gyro linear-g sensitivity is 0.01–0.1 °/s/g (2e-5–2e-4 rad/s per m/s²) on datasheets; 1e-3 is 5× the worst",
    },
    Plausible {
        term: "gyro_bias_temperature",
        shown: "|coefficient| ≤ 3e-3 rad/s per K",
        quantity: "largest |coefficient|",
        lo: 0.0,
        hi: 3e-3,
        unit: "rad/s per K",
        why: "consumer MEMS gyro bias drifts up to ≈ 0.15 °/s per K (3e-3 rad/s per K) over temperature",
    },
    Plausible {
        term: "lever_arm",
        shown: "|offset| ≤ 2 m",
        quantity: "|offset|",
        lo: 0.0,
        hi: 2.0,
        unit: "m",
        why: "an IMU sits within a couple of metres of its body's reference point, even on a car",
    },
    Plausible {
        term: "time_offset",
        shown: "|offset| ≤ 1 sample period",
        quantity: "|seconds| / sample period",
        lo: 0.0,
        hi: 1.0,
        unit: "samples",
        why: "whole-sample lags are removed by the alignment, and the catalogue's delay is first-order, good well within one sample",
    },
    Plausible {
        term: "gravity_magnitude",
        shown: "9.76 ≤ g ≤ 9.84 m/s²",
        quantity: "g",
        lo: 9.76,
        hi: 9.84,
        unit: "m/s²",
        why: "gravity on the Earth's surface is 9.780 (equator) to 9.832 (poles), a little less on mountains",
    },
    Plausible {
        term: "earth_rotation",
        shown: "|latitude| < π/2",
        quantity: "|latitude|",
        lo: 0.0,
        hi: std::f64::consts::FRAC_PI_2 - 1e-6,
        unit: "rad",
        why: "a latitude pinned at ±π/2 is the bound the fit is clamped to when no latitude fits (its cos-latitude part came out negative)",
    },
    Plausible {
        term: "vibration",
        shown: "frequency ≥ 2 Hz",
        quantity: "frequency",
        lo: 2.0,
        hi: f64::INFINITY,
        unit: "Hz",
        why: "rotors, engines and structures vibrate above a few Hz; a slower accelerometer line is the body's motion (steps, gait, waves)",
    },
    Plausible {
        term: "gyro_noise_density",
        shown: "0.5 ≤ factor ≤ 4",
        quantity: "factor",
        lo: 0.5,
        hi: 4.0,
        unit: "× the sim's",
        why: "datasheet noise densities are typical values, units differ by tens of % and vibration can double it; beyond 4× the sim's noise model itself is wrong",
    },
    Plausible {
        term: "low_pass",
        shown: "cutoff below Nyquist (half the sample rate)",
        quantity: "cutoff / sample rate",
        lo: 0.0,
        hi: 0.5,
        unit: "",
        why: "above the Nyquist frequency a first-order filter's effect on the samples is a sub-sample delay, and its cutoff is not identified",
    },
];

/// The quantity of `term` its [`PLAUSIBLE`] range compares (None: the term has no range).
pub fn plausibility_measure(term: &Term, sample_rate_hz: f64) -> Option<f64> {
    let max_abs = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let off = |m: &[[f64; 3]; 3]| OFF_DIAGONAL.iter().fold(0.0f64, |a, &(r, c)| a.max(m[r][c].abs()));
    Some(match term {
        Term::GyroBias(t) => max_abs(&t.bias),
        Term::AccelBias(t) => max_abs(&t.bias),
        Term::GyroScale(t) => max_abs(&t.scale),
        Term::AccelScale(t) => max_abs(&t.scale),
        Term::GyroMisalignment(t) => off(&t.matrix),
        Term::AccelMisalignment(t) => off(&t.matrix),
        Term::GyroGSensitivity(t) => max_abs(t.matrix.as_flattened()),
        Term::GyroBiasTemperature(t) => max_abs(&t.coefficient),
        Term::LeverArm(t) => t.offset.iter().map(|x| x * x).sum::<f64>().sqrt(),
        Term::TimeOffset(t) => t.seconds.abs() * sample_rate_hz,
        Term::GravityMagnitude(t) => t.g,
        Term::EarthRotation(t) => t.latitude_rad.abs(),
        Term::Vibration(t) => t.frequency_hz,
        Term::GyroNoiseDensity(t) => t.factor,
        Term::LowPass(t) => t.cutoff_hz / sample_rate_hz,
        _ => return None,
    })
}

/// Why a fitted term is not physically plausible (None when it is, or has no range).
pub fn implausible(term: &Term, sample_rate_hz: f64) -> Option<String> {
    let range = PLAUSIBLE.iter().find(|p| p.term == term.name())?;
    let v = plausibility_measure(term, sample_rate_hz)?;
    // NaN fails both comparisons: not plausible either.
    (!(v >= range.lo && v <= range.hi)).then(|| {
        let unit = if range.unit.is_empty() { String::new() } else { format!(" {}", range.unit) };
        format!("{} {}{unit}, where plausible is {}: {}", range.quantity, short(v), range.shown, range.why)
    })
}

/// A number with 4 significant digits, without trailing zeros.
fn short(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    if !(1e-3..1e5).contains(&x.abs()) {
        return format!("{x:.3e}");
    }
    let decimals = (3 - x.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{x:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_nearest_plausible_value_is_the_interval_end_toward_zero() {
        use physics::{GyroScale, TimeOffset};
        let t = Term::GyroScale(GyroScale::new([0.06, -0.07, 0.001]));
        let Some(Term::GyroScale(n)) = nearest_plausible(&t, &[0.005, 0.02, 0.01], 1.96) else { panic!() };
        assert!((n.scale[0] - (0.06 - 0.0098)).abs() < 1e-12 && (n.scale[1] + (0.07 - 0.0392)).abs() < 1e-12 && n.scale[2] == 0.0, "{n:?}");
        // A 1.5-sample delay ± 0.4 samples at 100 Hz is beyond one sample at its end too.
        let d = Term::TimeOffset(TimeOffset { seconds: 0.015 });
        let near = nearest_plausible(&d, &[0.002], 1.96).unwrap();
        assert!(implausible(&near, 100.0).is_some());
        assert!(implausible(&nearest_plausible(&d, &[0.003], 1.96).unwrap(), 100.0).is_none());
    }

    #[test]
    fn parameters_read_back_what_to_term_wrote() {
        let beta9: Vec<f64> = (1..=9).map(|k| k as f64 * 1e-4).collect();
        for (name, n) in
            [("gyro_scale", 3), ("accel_misalignment", 6), ("gyro_g_sensitivity", 9), ("time_offset", 1), ("gravity_magnitude", 1)]
        {
            let term = to_term(name, &beta9[..n], 0.0, 0.0);
            let back = parameters(&term).expect(name);
            assert!(back.iter().zip(&beta9).all(|(a, b)| (a - b).abs() < 1e-12), "{name}: {back:?}");
        }
    }
    use crate::physics::*;

    /// Values of the size real sensors have pass; the tester's out-of-catalogue fits (a
    /// g-sensitivity of 0.18 rad/s per m/s², gravity 9.988, a 130 Hz low-pass at 200 Hz, a
    /// latitude pinned at π/2, a 13 % gyro scale) are flagged, each with its range's why.
    #[test]
    fn datasheet_sized_terms_pass_and_absurd_fits_are_flagged() {
        let fs = 200.0;
        let mut g = [[0.0; 3]; 3];
        g[0][1] = 1.6e-4;
        let plausible = [
            Term::GyroGSensitivity(GyroGSensitivity { matrix: g }),
            Term::GyroScale(GyroScale::new([3e-4, -7e-4, 8e-4])),
            Term::LeverArm(LeverArm { offset: [-0.02, 0.03, -0.03] }),
            Term::TimeOffset(TimeOffset { seconds: 7e-5 }),
            Term::Vibration(Vibration { frequency_hz: 56.4, accel_amplitude: [0.01, 0.02, 0.02], phase_rad: [0.0; 3] }),
            Term::GyroBiasTemperature(GyroBiasTemperature { coefficient: [2.6e-4, 7.5e-4, 3.9e-4], reference_c: 25.0 }),
            Term::GravityMagnitude(GravityMagnitude { g: 9.806 }),
            Term::EarthRotation(EarthRotation { latitude_rad: 0.83, rate_rad_s: earth_rotation::EARTH_RATE }),
            Term::LowPass(LowPass { cutoff_hz: 45.0, sensor: LowPassSensor::Both }),
            Term::GyroNoiseDensity(GyroNoiseDensity { factor: 1.5 }),
            Term::AccelBias(AccelBias::new([0.05, -0.07, 0.07])),
        ];
        for t in &plausible {
            assert_eq!(implausible(t, fs), None, "{t:?}");
        }
        g[0][1] = -0.1765;
        let absurd = [
            (Term::GyroGSensitivity(GyroGSensitivity { matrix: g }), "0.1765 rad/s per m/s²"),
            (Term::GravityMagnitude(GravityMagnitude { g: 9.988 }), "9.988 m/s²"),
            (Term::LowPass(LowPass { cutoff_hz: 130.4, sensor: LowPassSensor::Both }), "Nyquist"),
            (Term::EarthRotation(EarthRotation { latitude_rad: std::f64::consts::FRAC_PI_2, rate_rad_s: 7.29e-5 }), "pinned"),
            (Term::GyroScale(GyroScale::new([-0.057, -0.0097, 0.1316])), "0.1316"),
            (Term::TimeOffset(TimeOffset { seconds: -0.009 }), "1.8 samples"),
            (Term::Vibration(Vibration { frequency_hz: 1.09, accel_amplitude: [0.0, 0.0, 0.04], phase_rad: [0.0; 3] }), "motion"),
        ];
        for (t, says) in &absurd {
            let why = implausible(t, fs).unwrap_or_else(|| panic!("{t:?} passed"));
            assert!(why.contains(says), "{t:?}: {why}");
        }
        // Every range names a vocabulary term, once.
        for (i, p) in PLAUSIBLE.iter().enumerate() {
            assert!(Term::NAMES.contains(&p.term), "{}", p.term);
            assert!(PLAUSIBLE[..i].iter().all(|q| q.term != p.term), "{} twice", p.term);
        }
    }
}
