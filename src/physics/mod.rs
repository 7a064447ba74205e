//! Physical IMU error terms, each written once and shared by the simulator (`sim`) and the
//! sim-vs-real diagnosis.
//!
//! Every term is a small serde struct in its own file, named and parametrised exactly as the
//! vocabulary of `bench/concealed/README.md` says (SI units, continuous-time noise densities).
//! A term is applied to whole signal arrays ([`ImuSignals`]) by [`ErrorTerm::apply`], a pure
//! function of (parameters, signals, [`TermContext`]). The only randomness lives in
//! [`white_noise`] and [`bias_random_walk`]: they draw from a ChaCha8 stream seeded per
//! concern ([`TermContext::rng`]), record what they drew in [`TruthHistory`], and then apply
//! it with a deterministic function.
//!
//! # Order of application
//! A list of terms is applied by [`apply_terms`] in a fixed physical order, whatever the order
//! of the list (terms of the same kind keep their list order):
//!
//! 1. the true kinematics at the sensor: `mount_rotation`, `lever_arm`, `earth_rotation`,
//!    `gravity_magnitude`, `vibration`;
//! 2. sensor intrinsics: `gyro_g_sensitivity` (on the true specific force), `gyro_scale`,
//!    `gyro_misalignment`, `gyro_bias`, `gyro_bias_temperature`, `accel_scale`,
//!    `accel_misalignment`, `accel_bias`;
//! 3. `time_offset` (on the noise-free signal: delaying i.i.d. white noise changes nothing in
//!    distribution, while interpolating it would lower its variance);
//! 4. noise: `white_noise`, `bias_random_walk`, then `gyro_noise_density` (scales the white
//!    noise drawn just before);
//! 5. `low_pass` (the sensor's filter also filters its noise);
//! 6. `quantization`, then `saturation` (so the output never exceeds ±range).
//!
//! Terms read the signals as they are when their turn comes, so in that order `lever_arm`
//! sees the true ω and ω̇ and `gyro_g_sensitivity` sees the true specific force.
//!
//! # Serialisation
//! A term serialises flat, tagged by its name: `{term: gyro_bias, bias: [0.01, 0, 0]}`. It
//! also reads the nested form of `answer.json` (`{term: ..., params: {...}}`); keys starting
//! with `_` (such as `_energy`) are ignored, any other unknown key is an error.
//!
//! ```no_run
//! use imu_fsda::physics::{apply_terms, ImuSignals, Term, TermContext};
//! # fn signals() -> ImuSignals { unimplemented!() }
//! let terms: Vec<Term> = serde_yaml::from_str("- {term: gyro_bias, bias: [0.001, 0, 0]}\n- {term: white_noise, gyro_noise_density: 1.7e-4, accel_noise_density: 2e-3}").unwrap();
//! let mut s = signals();
//! let mut ctx = TermContext::new(42);
//! apply_terms(&terms, &mut s, &mut ctx).unwrap();
//! println!("realised white noise on gyro: {} samples", ctx.history.gyro_white.len());
//! ```

pub mod bias;
pub mod bias_random_walk;
pub mod earth_rotation;
pub mod gravity_magnitude;
pub mod gyro_bias_temperature;
pub mod gyro_g_sensitivity;
pub mod gyro_noise_density;
pub mod lever_arm;
pub mod low_pass;
pub mod misalignment;
pub mod mount_rotation;
pub mod noise_model;
pub mod quantization;
pub mod saturation;
pub mod scale;
pub mod sensor_kind;
pub mod time_offset;
pub mod vibration;
pub mod white_noise;

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use bias::{AccelBias, Bias, GyroBias};
pub use bias_random_walk::BiasRandomWalk;
pub use earth_rotation::EarthRotation;
pub use gravity_magnitude::GravityMagnitude;
pub use gyro_bias_temperature::GyroBiasTemperature;
pub use gyro_g_sensitivity::GyroGSensitivity;
pub use gyro_noise_density::GyroNoiseDensity;
pub use lever_arm::LeverArm;
pub use low_pass::{LowPass, LowPassSensor};
pub use misalignment::{AccelMisalignment, GyroMisalignment, Misalignment};
pub use mount_rotation::MountRotation;
pub use noise_model::NoiseModel;
pub use quantization::Quantization;
pub use saturation::Saturation;
pub use scale::{AccelScale, GyroScale, Scale};
pub use sensor_kind::{Accel, Gyro, SensorKind};
pub use time_offset::TimeOffset;
pub use vibration::Vibration;
pub use white_noise::WhiteNoise;

/// The gravity the true kinematics are generated with, m/s² (world ENU: g_world = (0, 0, −g)).
pub const NOMINAL_GRAVITY: f64 = crate::core::STANDARD_GRAVITY;

/// Errors of the physics layer: bad parameters or signals that do not fit together.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PhysicsError {
    #[error("{term}.{param} = {value} is not finite")]
    NonFinite { term: &'static str, param: &'static str, value: f64 },
    #[error("{term}.{param} = {value} is out of range: {expected}")]
    OutOfRange { term: &'static str, param: &'static str, value: f64, expected: &'static str },
    #[error("signals: {field} has {found} samples, expected {expected} (one per stamp)")]
    LengthMismatch { field: &'static str, expected: usize, found: usize },
    #[error("signals: stamps must increase strictly (sample {index})")]
    StampsNotIncreasing { index: usize },
}

/// The signals the terms work on, one entry per IMU sample, all arrays of equal length.
///
/// Built from the true kinematics (`gyro` = true ω, `accel` = true specific force), then
/// changed in place by each term. `world_from_imu` and `alpha_in_imu` describe the sensor
/// frame's motion; only the kinematic terms change them.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuSignals {
    /// Sample times, ns, strictly increasing.
    pub stamps_ns: Vec<i64>,
    /// Attitude of the sensor frame: rotation taking IMU-frame vectors to the world (ENU).
    pub world_from_imu: Vec<UnitQuaternion<f64>>,
    /// Angular acceleration of the sensor frame, in the sensor frame, rad/s².
    pub alpha_in_imu: Vec<Vector3<f64>>,
    /// Die temperature, °C.
    pub temperature_c: Vec<f64>,
    /// Gyro channel: angular velocity in the sensor frame, rad/s.
    pub gyro: Vec<Vector3<f64>>,
    /// Accelerometer channel: specific force in the sensor frame, m/s².
    pub accel: Vec<Vector3<f64>>,
}

/// Which sensor of the IMU a term acts on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Sensor {
    Gyro,
    Accel,
}

impl ImuSignals {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.stamps_ns.len()
    }

    pub fn is_empty(&self) -> bool {
        self.stamps_ns.is_empty()
    }

    /// Check that every array has one entry per stamp and the stamps increase.
    pub fn validate(&self) -> Result<(), PhysicsError> {
        let n = self.len();
        let lens = [
            ("world_from_imu", self.world_from_imu.len()),
            ("alpha_in_imu", self.alpha_in_imu.len()),
            ("temperature_c", self.temperature_c.len()),
            ("gyro", self.gyro.len()),
            ("accel", self.accel.len()),
        ];
        if let Some((field, found)) = lens.into_iter().find(|(_, l)| *l != n) {
            return Err(PhysicsError::LengthMismatch { field, expected: n, found });
        }
        if let Some(i) = self.stamps_ns.windows(2).position(|w| w[1] <= w[0]) {
            return Err(PhysicsError::StampsNotIncreasing { index: i + 1 });
        }
        Ok(())
    }

    /// Time of sample `i` since the first sample, s.
    pub fn seconds_since_start(&self, i: usize) -> f64 {
        (self.stamps_ns[i] - self.stamps_ns[0]) as f64 * 1e-9
    }

    /// Mean sample interval from the stamps, s (0 with fewer than two samples).
    pub fn nominal_dt(&self) -> f64 {
        match (self.stamps_ns.first(), self.stamps_ns.last()) {
            (Some(a), Some(b)) if self.len() > 1 => (b - a) as f64 * 1e-9 / (self.len() - 1) as f64,
            _ => 0.0,
        }
    }

    /// The channel of one sensor.
    pub fn channel(&self, sensor: Sensor) -> &[Vector3<f64>] {
        match sensor {
            Sensor::Gyro => &self.gyro,
            Sensor::Accel => &self.accel,
        }
    }

    /// The channel of one sensor, to change in place.
    pub fn channel_mut(&mut self, sensor: Sensor) -> &mut Vec<Vector3<f64>> {
        match sensor {
            Sensor::Gyro => &mut self.gyro,
            Sensor::Accel => &mut self.accel,
        }
    }

    /// The IMU readings as samples.
    pub fn to_samples(&self) -> Vec<crate::core::ImuSample> {
        self.stamps_ns
            .iter()
            .zip(self.gyro.iter().zip(&self.accel))
            .map(|(&stamp_ns, (&gyro, &accel))| crate::core::ImuSample { stamp_ns, gyro, accel })
            .collect()
    }
}

/// What kind of continuous-time density a noise parameter is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Density {
    /// White noise density (rad/s/√Hz, m/s²/√Hz): per-sample std σ/√dt.
    White,
    /// Random-walk driving density (rad/s²/√Hz, m/s³/√Hz): per-step increment std σ_b·√dt.
    RandomWalk,
}

/// The one place continuous-time densities become discrete standard deviations:
/// white noise σ_d = σ/√dt, random-walk increment σ_d = σ_b·√dt (dt in s).
pub fn discretise(density: f64, dt: f64, kind: Density) -> f64 {
    match kind {
        Density::White => density / dt.sqrt(),
        Density::RandomWalk => density * dt.sqrt(),
    }
}

/// Random errors as they were drawn: the ground truth of the stochastic terms, one entry per
/// sample (empty when the term was not applied). Sums over terms of the same kind.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TruthHistory {
    /// White noise added to the gyro, rad/s.
    pub gyro_white: Vec<Vector3<f64>>,
    /// White noise added to the accelerometer, m/s².
    pub accel_white: Vec<Vector3<f64>>,
    /// Realised gyro bias random walk, rad/s (starts at 0).
    pub gyro_bias_walk: Vec<Vector3<f64>>,
    /// Realised accelerometer bias random walk, m/s² (starts at 0).
    pub accel_bias_walk: Vec<Vector3<f64>>,
}

/// Context shared by the terms of one application: the seed the random terms derive their
/// streams from, and the record of what they drew.
#[derive(Debug, Clone)]
pub struct TermContext {
    /// Base seed; each concern draws from its own stream derived from it.
    pub seed: u64,
    /// The realised random errors.
    pub history: TruthHistory,
    draws: std::collections::BTreeMap<&'static str, u64>,
}

impl TermContext {
    pub fn new(seed: u64) -> Self {
        TermContext { seed, history: TruthHistory::default(), draws: Default::default() }
    }

    /// A fresh random stream for one concern (e.g. `"gyro_white"`). The n-th call for the
    /// same concern gets the n-th stream, so two terms of one kind draw independently.
    pub fn rng(&mut self, concern: &'static str) -> ChaCha8Rng {
        let count = self.draws.entry(concern).or_insert(0);
        let stream = *count;
        *count += 1;
        ChaCha8Rng::seed_from_u64(derive_seed(self.seed, concern, stream))
    }
}

/// A seed for one concern, mixed from the base seed, the concern's name and a stream index
/// (FNV-1a of the name, then splitmix64): stable across platforms and versions.
pub fn derive_seed(seed: u64, concern: &str, stream: u64) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in concern.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    splitmix64(splitmix64(seed ^ h) ^ stream)
}

/// One step of splitmix64: a good 64-bit mixer.
pub fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// One physical error term.
pub trait ErrorTerm: Clone + std::fmt::Debug + PartialEq + Serialize + for<'de> Deserialize<'de> {
    /// The vocabulary name, also the serde tag.
    const NAME: &'static str;

    /// Parameters with no effect.
    fn identity() -> Self;

    /// Reject parameters that are not finite or out of their physical range.
    fn validate(&self) -> Result<(), PhysicsError>;

    /// Apply the term to whole signal arrays, in place. Deterministic given `ctx` (the random
    /// terms draw from `ctx.rng(..)` and record the draw in `ctx.history`). Parameters are
    /// assumed valid (see [`ErrorTerm::validate`]).
    fn apply(&self, s: &mut ImuSignals, ctx: &mut TermContext);

    /// True when the parameters are the identity.
    fn is_identity(&self) -> bool {
        *self == Self::identity()
    }
}

// ---- shared helpers, so each term reads like its formula ----------------------------------

/// Array → vector.
pub fn vec3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

/// Row-major array → matrix.
pub fn mat3(m: [[f64; 3]; 3]) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| m[r][c])
}

/// Check that every value is finite.
pub fn check_finite(term: &'static str, param: &'static str, values: &[f64]) -> Result<(), PhysicsError> {
    match values.iter().find(|v| !v.is_finite()) {
        Some(&value) => Err(PhysicsError::NonFinite { term, param, value }),
        None => Ok(()),
    }
}

/// Check `value` against a predicate (NaN always fails).
pub fn check_range(term: &'static str, param: &'static str, value: f64, ok: bool, expected: &'static str) -> Result<(), PhysicsError> {
    if value.is_nan() || !ok {
        Err(PhysicsError::OutOfRange { term, param, value, expected })
    } else {
        Ok(())
    }
}

/// Flatten a row-major 3×3 array.
pub fn flat(m: &[[f64; 3]; 3]) -> [f64; 9] {
    let mut out = [0.0; 9];
    for (r, row) in m.iter().enumerate() {
        out[3 * r..3 * r + 3].copy_from_slice(row);
    }
    out
}

/// x ← x + b for every sample.
pub fn add_constant(x: &mut [Vector3<f64>], b: &Vector3<f64>) {
    x.iter_mut().for_each(|v| *v += b);
}

/// x ← A x for every sample.
pub fn left_multiply(x: &mut [Vector3<f64>], a: &Matrix3<f64>) {
    x.iter_mut().for_each(|v| *v = a * *v);
}

// ---- the list of terms --------------------------------------------------------------------

macro_rules! terms {
    ($( $(#[$doc:meta])* $variant:ident($ty:ty) ),* $(,)?) => {
        /// Any error term, tagged by its vocabulary name. Variants are listed in the physical
        /// order in which [`apply_terms`] applies them.
        #[derive(Debug, Clone, PartialEq, Serialize)]
        #[serde(tag = "term", rename_all = "snake_case")]
        pub enum Term {
            $( $(#[$doc])* $variant($ty), )*
        }

        /// The flat, strict form used to read a [`Term`] after normalisation.
        #[derive(Deserialize)]
        #[serde(tag = "term", rename_all = "snake_case")]
        enum TermFlat {
            $( $variant($ty), )*
        }

        impl From<TermFlat> for Term {
            fn from(t: TermFlat) -> Self {
                match t { $( TermFlat::$variant(x) => Term::$variant(x), )* }
            }
        }

        $( impl From<$ty> for Term { fn from(x: $ty) -> Self { Term::$variant(x) } } )*

        impl Term {
            /// Every term name of the vocabulary (plus the simulator's noise model), in
            /// application order.
            pub const NAMES: &'static [&'static str] = &[ $( <$ty as ErrorTerm>::NAME, )* ];

            /// The vocabulary name.
            pub fn name(&self) -> &'static str {
                match self { $( Term::$variant(_) => <$ty as ErrorTerm>::NAME, )* }
            }

            /// Position in the physical application order.
            pub fn rank(&self) -> usize {
                let name = self.name();
                Self::NAMES.iter().position(|n| *n == name).unwrap_or(usize::MAX)
            }

            pub fn validate(&self) -> Result<(), PhysicsError> {
                match self { $( Term::$variant(x) => x.validate(), )* }
            }

            pub fn is_identity(&self) -> bool {
                match self { $( Term::$variant(x) => x.is_identity(), )* }
            }

            /// Apply this one term (see [`ErrorTerm::apply`]).
            pub fn apply(&self, s: &mut ImuSignals, ctx: &mut TermContext) {
                match self { $( Term::$variant(x) => x.apply(s, ctx), )* }
            }

            /// The identity of every term, in application order.
            pub fn identities() -> Vec<Term> {
                vec![ $( Term::$variant(<$ty as ErrorTerm>::identity()), )* ]
            }

            /// The identity of the term called `name`.
            pub fn identity_of(name: &str) -> Option<Term> {
                Self::identities().into_iter().find(|t| t.name() == name)
            }
        }
    };
}

terms! {
    MountRotation(MountRotation),
    LeverArm(LeverArm),
    EarthRotation(EarthRotation),
    GravityMagnitude(GravityMagnitude),
    Vibration(Vibration),
    GyroGSensitivity(GyroGSensitivity),
    GyroScale(GyroScale),
    GyroMisalignment(GyroMisalignment),
    GyroBias(GyroBias),
    GyroBiasTemperature(GyroBiasTemperature),
    AccelScale(AccelScale),
    AccelMisalignment(AccelMisalignment),
    AccelBias(AccelBias),
    TimeOffset(TimeOffset),
    WhiteNoise(WhiteNoise),
    BiasRandomWalk(BiasRandomWalk),
    GyroNoiseDensity(GyroNoiseDensity),
    LowPass(LowPass),
    Quantization(Quantization),
    Saturation(Saturation),
}

impl<'de> Deserialize<'de> for Term {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let value = serde_yaml::Value::deserialize(d)?;
        let serde_yaml::Value::Mapping(map) = value else {
            return Err(D::Error::custom("a term must be a mapping with a `term` key"));
        };
        let mut flat = serde_yaml::Mapping::new();
        for (k, v) in map {
            match k.as_str() {
                Some(key) if key.starts_with('_') => {}
                Some("params") => match v {
                    serde_yaml::Value::Mapping(params) => {
                        for (pk, pv) in params {
                            if !pk.as_str().is_some_and(|s| s.starts_with('_')) {
                                flat.insert(pk, pv);
                            }
                        }
                    }
                    serde_yaml::Value::Null => {}
                    _ => return Err(D::Error::custom("`params` of a term must be a mapping")),
                },
                _ => {
                    flat.insert(k, v);
                }
            }
        }
        let name = flat.get("term").and_then(|t| t.as_str()).map(str::to_owned);
        match &name {
            None => return Err(D::Error::custom("a term needs a `term` key naming it")),
            Some(n) if !Term::NAMES.contains(&n.as_str()) => {
                return Err(D::Error::custom(format!("unknown term `{n}`, expected one of: {}", Term::NAMES.join(", "))));
            }
            _ => {}
        }
        serde_yaml::from_value::<TermFlat>(serde_yaml::Value::Mapping(flat))
            .map(Term::from)
            .map_err(|e| D::Error::custom(format!("term `{}`: {e}", name.unwrap_or_default())))
    }
}

/// The terms in application order (stable: same-kind terms keep their list order).
pub fn in_application_order(terms: &[Term]) -> Vec<&Term> {
    let mut v: Vec<&Term> = terms.iter().collect();
    v.sort_by_key(|t| t.rank());
    v
}

/// Validate the signals and every term, then apply the terms in the physical order.
pub fn apply_terms(terms: &[Term], s: &mut ImuSignals, ctx: &mut TermContext) -> Result<(), PhysicsError> {
    s.validate()?;
    for t in terms {
        t.validate()?;
    }
    for t in in_application_order(terms) {
        t.apply(s, ctx);
    }
    Ok(())
}

/// What a term changed, per sample.
#[derive(Debug, Clone, PartialEq)]
pub struct Effect {
    /// Change of the gyro channel, rad/s.
    pub gyro: Vec<Vector3<f64>>,
    /// Change of the accelerometer channel, m/s².
    pub accel: Vec<Vector3<f64>>,
}

/// The effect of one term on clean signals: `apply(term, s) − s` (the quantity the
/// concealed cases score a diagnosis by). Random terms draw from `seed`.
pub fn effect(term: &Term, s: &ImuSignals, seed: u64) -> Result<Effect, PhysicsError> {
    let mut out = s.clone();
    apply_terms(std::slice::from_ref(term), &mut out, &mut TermContext::new(seed))?;
    let gyro = out.gyro.iter().zip(&s.gyro).map(|(a, b)| a - b).collect();
    let accel = out.accel.iter().zip(&s.accel).map(|(a, b)| a - b).collect();
    Ok(Effect { gyro, accel })
}

#[cfg(test)]
pub(crate) mod test_support {
    //! Signals to test terms on, and the property suite every term runs.
    use super::*;
    use proptest::prelude::*;

    /// A short smooth, tilted, rotating motion at 200 Hz: deterministic, non-trivial on every axis.
    pub fn signals(n: usize) -> ImuSignals {
        let dt_ns = 5_000_000i64;
        let stamps_ns: Vec<i64> = (0..n as i64).map(|k| 1_000_000_000 + k * dt_ns).collect();
        let t = |k: usize| k as f64 * 5e-3;
        let world_from_imu =
            (0..n).map(|k| UnitQuaternion::from_euler_angles(0.3 * (0.7 * t(k)).sin(), -0.2 + 0.1 * t(k).cos(), 0.5 * t(k))).collect();
        let gyro = (0..n).map(|k| Vector3::new(0.5 * (2.0 * t(k)).sin(), -0.3 * (1.3 * t(k)).cos(), 0.2 + 0.1 * t(k).sin())).collect();
        let alpha_in_imu = (0..n).map(|k| Vector3::new((2.0 * t(k)).cos(), 0.39 * (1.3 * t(k)).sin(), 0.1 * t(k).cos())).collect();
        let accel = (0..n).map(|k| Vector3::new(0.4 * t(k).sin(), 1.5 * (0.5 * t(k)).cos(), 9.81 + 0.2 * (3.0 * t(k)).sin())).collect();
        let temperature_c = (0..n).map(|k| 25.0 + 10.0 * (1.0 - (-t(k) / 2.0).exp())).collect();
        ImuSignals { stamps_ns, world_from_imu, alpha_in_imu, temperature_c, gyro, accel }
    }

    /// Apply one term to fresh signals.
    pub fn applied<T: ErrorTerm>(term: &T, s: &ImuSignals) -> ImuSignals {
        let mut out = s.clone();
        term.validate().expect("valid parameters");
        term.apply(&mut out, &mut TermContext::new(7));
        out
    }

    /// Max absolute difference between two channels.
    pub fn max_diff(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
        a.iter().zip(b).map(|(x, y)| (x - y).amax()).fold(0.0, f64::max)
    }

    /// The shared suite: identity is identity; YAML and JSON round trips; a random valid
    /// instance validates, applies without producing non-finite values, and round-trips.
    pub fn suite<T: ErrorTerm + Into<Term>>(random: impl Strategy<Value = T>) {
        let s = signals(300);
        let id = T::identity();
        assert!(id.validate().is_ok(), "{}: identity must validate", T::NAME);
        assert!(id.is_identity());
        let out = applied(&id, &s);
        assert!(
            max_diff(&out.gyro, &s.gyro) < 1e-15 && max_diff(&out.accel, &s.accel) < 1e-15,
            "{}: identity changed the signals",
            T::NAME
        );
        assert_eq!(out.world_from_imu, s.world_from_imu);
        let term: Term = id.clone().into();
        assert_eq!(term.name(), T::NAME);
        assert!(term.is_identity());
        let yaml = serde_yaml::to_string(&term).unwrap();
        assert!(yaml.contains(&format!("term: {}", T::NAME)), "{yaml}");
        assert_eq!(serde_yaml::from_str::<Term>(&yaml).unwrap(), term, "{yaml}");
        let mut runner = proptest::test_runner::TestRunner::new(proptest::test_runner::Config { cases: 48, ..Default::default() });
        runner
            .run(&random, |t| {
                prop_assert!(t.validate().is_ok(), "{t:?}");
                let term: Term = t.clone().into();
                let yaml = serde_yaml::to_string(&term).unwrap();
                prop_assert_eq!(&serde_yaml::from_str::<Term>(&yaml).unwrap(), &term);
                // Through a JSON value (serde_json's text parser is not correctly rounded
                // without its `float_roundtrip` feature).
                let json = serde_json::to_value(&term).unwrap();
                prop_assert_eq!(&serde_json::from_value::<Term>(json).unwrap(), &term);
                let out = applied(&t, &s);
                prop_assert!(out.gyro.iter().chain(&out.accel).all(|v| v.iter().all(|x| x.is_finite())));
                prop_assert!(out.validate().is_ok());
                Ok(())
            })
            .unwrap();
    }

    pub fn v3(max: f64) -> impl Strategy<Value = [f64; 3]> {
        [-max..max, -max..max, -max..max]
    }

    pub fn m3(max: f64) -> impl Strategy<Value = [[f64; 3]; 3]> {
        [v3(max), v3(max), v3(max)]
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::*;
    use super::*;

    #[test]
    fn discretise_white_and_walk() {
        assert!((discretise(1e-3, 0.01, Density::White) - 1e-2).abs() < 1e-15);
        assert!((discretise(1e-3, 0.01, Density::RandomWalk) - 1e-4).abs() < 1e-15);
    }

    #[test]
    fn every_vocabulary_name_is_a_term() {
        for name in [
            "gyro_bias",
            "gyro_scale",
            "gyro_misalignment",
            "gyro_g_sensitivity",
            "gyro_bias_temperature",
            "gyro_noise_density",
            "accel_bias",
            "accel_scale",
            "accel_misalignment",
            "mount_rotation",
            "lever_arm",
            "time_offset",
            "low_pass",
            "gravity_magnitude",
            "earth_rotation",
            "saturation",
            "quantization",
            "vibration",
            "white_noise",
            "bias_random_walk",
        ] {
            let t = Term::identity_of(name).unwrap_or_else(|| panic!("{name} missing"));
            assert_eq!(t.name(), name);
        }
        assert_eq!(Term::identities().len(), Term::NAMES.len());
    }

    #[test]
    fn reads_answer_json_form_and_rejects_typos() {
        let t: Term = serde_json::from_str(r#"{"term": "gyro_scale", "params": {"scale": [0.001, -0.002, 0.0], "_energy": 978}}"#).unwrap();
        assert_eq!(t, Term::GyroScale(GyroScale::new([0.001, -0.002, 0.0])));
        let t: Term = serde_yaml::from_str("{term: gyro_bias, bias: [1, 2, 3]}").unwrap();
        assert_eq!(t, Term::GyroBias(GyroBias::new([1.0, 2.0, 3.0])));
        let e = serde_yaml::from_str::<Term>("{term: gyro_bias, bais: [1, 2, 3]}").unwrap_err().to_string();
        assert!(e.contains("bais"), "{e}");
        let e = serde_yaml::from_str::<Term>("{term: gyro_wobble, x: 1}").unwrap_err().to_string();
        assert!(e.contains("unknown term `gyro_wobble`") && e.contains("gyro_bias"), "{e}");
        let e = serde_yaml::from_str::<Term>("{bias: [1, 2, 3]}").unwrap_err().to_string();
        assert!(e.contains("`term`"), "{e}");
        let e = serde_yaml::from_str::<Term>("{term: gyro_bias, bias: [1, 2]}").unwrap_err().to_string();
        assert!(e.contains("gyro_bias"), "{e}");
    }

    #[test]
    fn nan_parameters_are_rejected_not_applied() {
        let t: Term = serde_yaml::from_str("{term: gyro_bias, bias: [.nan, 0, 0]}").unwrap();
        let mut s = signals(10);
        let err = apply_terms(&[t], &mut s, &mut TermContext::new(0)).unwrap_err();
        assert!(matches!(err, PhysicsError::NonFinite { term: "gyro_bias", .. }), "{err}");
        assert_eq!(s, signals(10));
    }

    #[test]
    fn order_is_physical_whatever_the_list_order() {
        let terms = vec![
            Term::Saturation(Saturation { gyro_range: 0.1, accel_range: f64::INFINITY }),
            Term::GyroBias(GyroBias::new([1.0, 0.0, 0.0])),
            Term::MountRotation(MountRotation { rotvec: [0.0, 0.0, 0.1] }),
        ];
        let names: Vec<_> = in_application_order(&terms).iter().map(|t| t.name()).collect();
        assert_eq!(names, ["mount_rotation", "gyro_bias", "saturation"]);
        let mut s = signals(50);
        apply_terms(&terms, &mut s, &mut TermContext::new(0)).unwrap();
        assert!(s.gyro.iter().all(|g| g.amax() <= 0.1 + 1e-15), "saturation comes last");
    }

    #[test]
    fn mismatched_signals_are_an_error() {
        let mut s = signals(10);
        s.accel.pop();
        let err = apply_terms(&[], &mut s, &mut TermContext::new(0)).unwrap_err();
        assert_eq!(err, PhysicsError::LengthMismatch { field: "accel", expected: 10, found: 9 });
        let mut s = signals(10);
        s.stamps_ns[5] = s.stamps_ns[4];
        assert_eq!(apply_terms(&[], &mut s, &mut TermContext::new(0)).unwrap_err(), PhysicsError::StampsNotIncreasing { index: 5 });
    }

    #[test]
    fn seeds_per_concern_differ_and_repeat() {
        assert_eq!(derive_seed(1, "gyro_white", 0), derive_seed(1, "gyro_white", 0));
        assert_ne!(derive_seed(1, "gyro_white", 0), derive_seed(1, "accel_white", 0));
        assert_ne!(derive_seed(1, "gyro_white", 0), derive_seed(1, "gyro_white", 1));
        assert_ne!(derive_seed(1, "gyro_white", 0), derive_seed(2, "gyro_white", 0));
    }

    #[test]
    fn effect_is_the_difference() {
        let s = signals(20);
        let e = effect(&Term::GyroBias(GyroBias::new([0.0, 0.5, 0.0])), &s, 0).unwrap();
        assert!(e.gyro.iter().all(|d| (d - Vector3::new(0.0, 0.5, 0.0)).norm() < 1e-12));
        assert!(e.accel.iter().all(|d| d.norm() == 0.0));
    }
}
