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

use nalgebra::DMatrix;

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

    fn add(&mut self, name: &'static str, atoms: Vec<usize>, map: Map) {
        let params = match map {
            Map::Direct => atoms.len(),
            Map::Temperature => 3,
        };
        self.candidates.push(Candidate { name, atoms, params, map });
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

        let gb =
            cat.linear("gyro_bias", (0..3).map(|i| (v3("bias", i), Term::GyroBias(GyroBias { bias: unit(i) }), 1.0)).collect(), base)?;
        cat.add("gyro_bias", gb.clone(), Map::Direct);
        let step = 1e-3;
        let a = cat.linear(
            "gyro_scale",
            (0..3).map(|i| (v3("scale", i), Term::GyroScale(GyroScale { scale: unit(i).map(|x| x * step) }), step)).collect(),
            base,
        )?;
        cat.add("gyro_scale", a, Map::Direct);
        let a = cat.linear(
            "gyro_misalignment",
            OFF_DIAGONAL
                .iter()
                .map(|&(r, c)| (m3(r, c), Term::GyroMisalignment(GyroMisalignment { matrix: mat(r, c, step) }), step))
                .collect(),
            base,
        )?;
        cat.add("gyro_misalignment", a, Map::Direct);
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
        let a =
            cat.linear("accel_bias", (0..3).map(|i| (v3("bias", i), Term::AccelBias(AccelBias { bias: unit(i) }), 1.0)).collect(), base)?;
        cat.add("accel_bias", a, Map::Direct);
        let a = cat.linear(
            "accel_scale",
            (0..3).map(|i| (v3("scale", i), Term::AccelScale(AccelScale { scale: unit(i).map(|x| x * step) }), step)).collect(),
            base,
        )?;
        cat.add("accel_scale", a, Map::Direct);
        let a = cat.linear(
            "accel_misalignment",
            OFF_DIAGONAL
                .iter()
                .map(|&(r, c)| (m3(r, c), Term::AccelMisalignment(AccelMisalignment { matrix: mat(r, c, step) }), step))
                .collect(),
            base,
        )?;
        cat.add("accel_misalignment", a, Map::Direct);
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
        "gyro_bias" => Term::GyroBias(GyroBias { bias: v(0) }),
        "gyro_scale" => Term::GyroScale(GyroScale { scale: v(0) }),
        "gyro_misalignment" => Term::GyroMisalignment(GyroMisalignment { matrix: off(beta) }),
        "gyro_g_sensitivity" => Term::GyroGSensitivity(GyroGSensitivity { matrix: [v(0), v(3), v(6)] }),
        "gyro_bias_temperature" => Term::GyroBiasTemperature(GyroBiasTemperature { coefficient: v(0), reference_c: nonlinear }),
        "accel_bias" => Term::AccelBias(AccelBias { bias: v(0) }),
        "accel_scale" => Term::AccelScale(AccelScale { scale: v(0) }),
        "accel_misalignment" => Term::AccelMisalignment(AccelMisalignment { matrix: off(beta) }),
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
