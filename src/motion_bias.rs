//! The gyro bias in motion, observed through gravity.
//!
//! Between standstills the bias is seen only through what it does to the attitude: the gyro
//! integrated with a wrong bias tilts away from the gravity the accelerometer measures. A
//! small Kalman filter carries the attitude (`world_from_body`), the gyro bias and the
//! accelerometer's bias, with a 9-state error (attitude about world x, y, z; the two biases
//! on IMU axes): a consumer accelerometer's bias (up to 0.6 m/s², 3.5° of tilt) turns with the
//! body and would otherwise read as a gyro bias. Each block (`block_s`) the
//! specific force is averaged *in the world frame* of the integrated attitude: a vehicle's own
//! accelerations average out there (its velocity stays bounded), so the block mean is gravity
//! plus a small rest, stated as `accel_stddev`; a quadrotor's thrust-aligned reading does not
//! average out in the body. The block's tilt from vertical is the measurement. Only the bias's
//! horizontal part (in the world) is seen at any one time; the part about gravity becomes
//! visible as the body turns. Heading is not observed: its variance grows.
//!
//! A standstill's bias (`crate::standstill`) is far more precise; [`MotionBias::seed`] sets
//! the filter's bias and variance to it. Per sample: no allocation.

use crate::setting::InvalidSetting;
use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

use crate::core::{ImuSample, STANDARD_GRAVITY};
use crate::so3::{exp, renormalize};

/// The filter's noise model and its gates.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MotionBiasConfig {
    /// Specific force averaged in the world frame over this long per measurement, s.
    pub block_s: f64,
    /// The platform's own acceleration left in a block's world-frame mean, m/s² (1 σ).
    pub accel_stddev: f64,
    /// A block whose ‖mean specific force‖ is farther than this from g is not used, m/s².
    pub max_gravity_error: f64,
    /// The gyro's white noise, rad/s/√Hz.
    pub gyro_noise_density: f64,
    /// The bias before anything is measured: 0 ± this, rad/s.
    pub prior_stddev: f64,
    /// The accelerometer's bias before anything is measured: 0 ± this, m/s².
    pub accel_bias_stddev: f64,
    /// How fast the bias wanders, rad/s/√s.
    pub bias_random_walk: f64,
    /// The attitude's tilt at the first sample (from its specific force): ± this, rad.
    pub initial_tilt_stddev: f64,
    /// An interval longer than this (or a stamp not after the last) restarts the attitude, s.
    pub max_sample_gap_s: f64,
    /// A direction of the bias is applied only once its σ is below this, rad/s …
    pub apply_max_stddev: f64,
    /// … and the estimate along it is this many σ from zero (there is a bias to remove).
    pub apply_min_z: f64,
    /// The model is taken not to fit this platform's motion (nothing is applied for the rest of
    /// the power-on) once the mean normalised innovation squared of the last `fit_blocks`
    /// blocks exceeds this (3 where it fits) …
    pub max_mean_nis: f64,
    /// … judged over this many blocks; nothing is applied before that many were used (the
    /// check has not had its say).
    pub fit_blocks: u32,
    /// … or the accelerometer's bias estimate leaves this many prior σ (sustained accelerations
    /// taken for a bias: a car braking).
    pub max_accel_bias_sigmas: f64,
    /// The gyro's error in proportion to its rate (scale and cross-axis errors left in it), as
    /// a fraction of |ω|: a turn of θ within a block adds (this · θ)² to the attitude's
    /// variance (a systematic error between two measurements, not a white one). 0: none.
    pub rate_error_fraction: f64,
    /// The gyro's scale and cross-axis errors left in it, each of the nine entries of a 3×3
    /// error ΔC (ω read as (I + ΔC) ω) 0 ± this, as states that are *considered*, not
    /// estimated (Schmidt): a constant error turns the attitude by ΔC times the net rotation,
    /// which cancels as a body turns back and forth and about gravity, where the white
    /// `rate_error_fraction` adds up every turn. 0: not modelled.
    pub rate_error_stddev: f64,
    /// A block whose normalised innovation squared exceeds this is not used (a sustained
    /// acceleration: a car braking, a launch); infinite: every block within
    /// `max_gravity_error` is.
    pub max_block_nis: f64,
    /// The bias about the body's mean up direction is applied only once the body has turned
    /// away from that direction by this much (RMS over the blocks used), rad. About gravity
    /// the bias is seen only through tilts, and a level platform's tilts come with its own
    /// accelerations (a multirotor tilts to accelerate, a car rolls in a bend): the two are
    /// confounded, and the estimate about up is confidently wrong. A standstill's bias
    /// ([`MotionBias::seed`]) is exempt.
    pub min_tilt_about_up: f64,
    /// Apply before the model check has had its `fit_blocks` (false: nothing is applied
    /// until then). For a platform whose own accelerations average out within seconds (a
    /// multirotor, a hand-held device, a legged robot); a car's sustained accelerations are
    /// taken for a bias until the check refuses them (docs/poweron.md).
    pub apply_before_check: bool,
    /// A platform that moves along its body x axis (a car: no side slip, no vertical
    /// velocity in its own frame): its forward speed is a state, 0 ± this at the start, m/s
    /// (0: not such a platform). A block's mean acceleration is then the speed's change along
    /// x plus speed × turn rate across it (a bend's centripetal acceleration), not an error.
    pub forward_speed_stddev: f64,
    /// How fast that speed changes, m/s/√s (a braking of 5 m/s² for 2 s is 10 m/s).
    pub forward_speed_walk: f64,
}

impl Default for MotionBiasConfig {
    fn default() -> Self {
        // accel_stddev: a hand-held or flying body's velocity changes by up to ~1 m/s within a
        // second; its mean acceleration over a second is that, over the second.
        // apply_max_stddev: 0.02 rad/s (1.1 °/s) is a fifth of a consumer gyro's turn-on bias;
        // a direction known worse than that is left alone (docs/poweron.md).
        MotionBiasConfig {
            block_s: 1.0,
            accel_stddev: 1.0,
            max_gravity_error: 1.0,
            gyro_noise_density: 1e-3,
            prior_stddev: 0.1,
            accel_bias_stddev: 0.5,
            bias_random_walk: 1e-4,
            initial_tilt_stddev: 0.3,
            max_sample_gap_s: 0.1,
            apply_max_stddev: 0.02,
            apply_min_z: 3.0,
            max_mean_nis: 4.5,
            fit_blocks: 30,
            max_accel_bias_sigmas: 2.0,
            rate_error_fraction: 0.0,
            rate_error_stddev: 0.0,
            max_block_nis: f64::INFINITY,
            min_tilt_about_up: 0.5,
            apply_before_check: false,
            forward_speed_stddev: 0.0,
            forward_speed_walk: 3.0,
        }
    }
}

impl MotionBiasConfig {
    /// Refuses settings the filter cannot run with, naming the key within this section (the
    /// caller names the section: `standstill.motion`, `gravity_aided`).
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        for (key, value) in [
            ("block_s", self.block_s),
            ("accel_stddev", self.accel_stddev),
            ("max_gravity_error", self.max_gravity_error),
            ("gyro_noise_density", self.gyro_noise_density),
            ("prior_stddev", self.prior_stddev),
            ("accel_bias_stddev", self.accel_bias_stddev),
            ("initial_tilt_stddev", self.initial_tilt_stddev),
            ("max_sample_gap_s", self.max_sample_gap_s),
            ("apply_max_stddev", self.apply_max_stddev),
            ("max_mean_nis", self.max_mean_nis),
            ("max_accel_bias_sigmas", self.max_accel_bias_sigmas),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(format!("{key} must be finite and > 0, not {value}").into());
            }
        }
        if !(self.rate_error_fraction.is_finite() && self.rate_error_fraction >= 0.0) {
            return Err(format!("rate_error_fraction must be finite and ≥ 0, not {}", self.rate_error_fraction).into());
        }
        if !(self.rate_error_stddev.is_finite() && self.rate_error_stddev >= 0.0) {
            return Err(format!("rate_error_stddev must be finite and ≥ 0, not {}", self.rate_error_stddev).into());
        }
        if self.max_block_nis.is_nan() || self.max_block_nis <= 0.0 {
            return Err(format!("max_block_nis must be > 0 (.inf: no gate), not {}", self.max_block_nis).into());
        }
        if self.fit_blocks == 0 {
            return Err("fit_blocks must be ≥ 1".into());
        }
        if !(self.min_tilt_about_up.is_finite() && self.min_tilt_about_up >= 0.0) {
            return Err(format!("min_tilt_about_up must be finite and ≥ 0, not {}", self.min_tilt_about_up).into());
        }
        if !(self.apply_min_z.is_finite() && self.apply_min_z >= 0.0) {
            return Err(format!("apply_min_z must be finite and ≥ 0, not {}", self.apply_min_z).into());
        }
        if !(self.bias_random_walk.is_finite() && self.bias_random_walk >= 0.0) {
            return Err(format!("bias_random_walk must be finite and ≥ 0, not {}", self.bias_random_walk).into());
        }
        for (key, value) in [("forward_speed_stddev", self.forward_speed_stddev), ("forward_speed_walk", self.forward_speed_walk)] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(format!("{key} must be finite and ≥ 0, not {value}").into());
            }
        }
        Ok(())
    }
}

/// The current block's world-frame sums.
#[derive(Debug, Clone, Copy)]
struct Block {
    start_ns: i64,
    n: u32,
    /// Σ R̂ f.
    force: Vector3<f64>,
    /// Σ R̂ and Σ R̂ (t − start), s: how a bias error since each sample reaches the block end.
    rotation: Matrix3<f64>,
    rotation_t: Matrix3<f64>,
    /// Σ R̂ (ω × x) and Σ R̂ (ω × x) (t − start), s: a forward speed's centripetal acceleration.
    bend: Vector3<f64>,
    bend_t: Vector3<f64>,
    /// ∫ R̂ D(ω) dt from the block's start to the last sample (D(ω) δc = ΔC ω), and its sum
    /// over the block's samples: how the considered gyro errors reach each sample.
    turned: SMatrix<f64, 3, 9>,
    turned_sum: SMatrix<f64, 3, 9>,
}

impl Block {
    fn empty(start_ns: i64) -> Self {
        Block {
            start_ns,
            n: 0,
            force: Vector3::zeros(),
            rotation: Matrix3::zeros(),
            rotation_t: Matrix3::zeros(),
            bend: Vector3::zeros(),
            bend_t: Vector3::zeros(),
            turned: SMatrix::zeros(),
            turned_sum: SMatrix::zeros(),
        }
    }
}

/// What one block did, for counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockVerdict {
    Used,
    /// ‖mean specific force‖ was not g: free fall, a launch, a crash.
    NotGravity,
    /// Its innovation was beyond `max_block_nis`: the platform's own acceleration.
    Outlier,
}

/// The error state: attitude about world x, y, z (rad), gyro bias (rad/s), accelerometer bias
/// (m/s²), IMU axes for both; the forward speed (m/s; zero and unused unless
/// `forward_speed_stddev` is set); the gyro's scale and cross-axis error ΔC, row by row
/// (considered, never estimated; zero and unused unless `rate_error_stddev` is set).
const N: usize = 19;
type Cov = SMatrix<f64, N, N>;
/// Where the forward speed sits in the state.
const U: usize = 9;
/// Where ΔC's nine entries start.
const C: usize = 10;

/// The running filter.
#[derive(Debug, Clone)]
pub struct MotionBias {
    cfg: MotionBiasConfig,
    world_from_body: Option<UnitQuaternion<f64>>,
    bias: Vector3<f64>,
    accel_bias: Vector3<f64>,
    /// The forward speed at the start of the block in progress, m/s.
    speed: f64,
    p: Cov,
    last: Option<(i64, Vector3<f64>)>,
    block: Block,
    used_blocks: u64,
    skipped_blocks: u64,
    /// The part of the bias that is applied, and its variance along the IMU axes.
    applied: (Vector3<f64>, Vector3<f64>),
    /// Normalised innovation squared per block, averaged over the last ~`fit_blocks`.
    nis: f64,
    /// The model was found not to fit this platform's motion: nothing is applied.
    misfit: bool,
    /// A standstill set the bias ([`Self::seed`]): it is applied without waiting for the fit.
    seeded: bool,
    /// Σ u uᵀ over the blocks used, u the up direction in the body (IMU axes).
    up_scatter: Matrix3<f64>,
    /// The bias about the body's mean up is left out of [`Self::applied`] (`min_tilt_about_up`).
    about_up_withheld: bool,
}

impl MotionBias {
    pub fn new(cfg: MotionBiasConfig) -> Self {
        let mut p = Cov::zeros();
        p.fixed_view_mut::<3, 3>(3, 3).copy_from(&(Matrix3::identity() * cfg.prior_stddev.powi(2)));
        p.fixed_view_mut::<3, 3>(6, 6).copy_from(&(Matrix3::identity() * cfg.accel_bias_stddev.powi(2)));
        p[(U, U)] = cfg.forward_speed_stddev.powi(2);
        p.fixed_view_mut::<9, 9>(C, C).copy_from(&(SMatrix::<f64, 9, 9>::identity() * cfg.rate_error_stddev.powi(2)));
        MotionBias {
            cfg,
            world_from_body: None,
            bias: Vector3::zeros(),
            accel_bias: Vector3::zeros(),
            speed: 0.0,
            p,
            last: None,
            block: Block::empty(0),
            used_blocks: 0,
            skipped_blocks: 0,
            applied: (Vector3::zeros(), Vector3::repeat(cfg.prior_stddev.powi(2))),
            nis: 3.0,
            misfit: false,
            seeded: false,
            up_scatter: Matrix3::zeros(),
            about_up_withheld: false,
        }
    }

    /// True until the model check has had its `fit_blocks` (or a standstill seeded the bias).
    pub fn before_check(&self) -> bool {
        !self.seeded && self.used_blocks < u64::from(self.cfg.fit_blocks)
    }

    /// True once the model was found not to fit the platform's motion (`max_mean_nis`,
    /// `max_accel_bias_sigmas`): nothing is applied until [`Self::restart`].
    pub fn misfit(&self) -> bool {
        self.misfit
    }

    /// The blocks' normalised innovation squared, averaged (3 where the model fits).
    pub fn nis(&self) -> f64 {
        self.nis
    }

    /// The bias estimate, rad/s (IMU axes).
    pub fn bias(&self) -> Vector3<f64> {
        self.bias
    }

    /// Its per-axis variance, (rad/s)².
    pub fn bias_variance(&self) -> Vector3<f64> {
        Vector3::new(self.p[(3, 3)], self.p[(4, 4)], self.p[(5, 5)])
    }

    /// The accelerometer's bias estimate, m/s² (IMU axes).
    pub fn accel_bias(&self) -> Vector3<f64> {
        self.accel_bias
    }

    /// The bias to subtract: the estimate along the directions it is known in (σ below
    /// `apply_max_stddev`, the estimate `apply_min_z` σ from zero); nothing along the others.
    /// With its variance per IMU axis: the estimate's where applied, else the whole bias's.
    pub fn applied(&self) -> (Vector3<f64>, Vector3<f64>) {
        self.applied
    }

    /// True while the bias about the body's mean up is left out of [`Self::applied`]: the body
    /// has stayed within `min_tilt_about_up` of level (`min_tilt_about_up`).
    pub fn withholds_about_up(&self) -> bool {
        self.about_up_withheld
    }

    /// True once some direction of the bias is known well enough to be applied.
    pub fn applies_any(&self) -> bool {
        self.applied.0 != Vector3::zeros()
    }

    /// Re-decides [`Self::applied`] from the estimate and its covariance.
    fn decide_applied(&mut self) {
        if self.misfit || (self.before_check() && !self.cfg.apply_before_check) {
            self.applied = (Vector3::zeros(), Vector3::repeat(self.cfg.prior_stddev.powi(2)));
            return;
        }
        let p_bb: Matrix3<f64> = self.p.fixed_view::<3, 3>(3, 3).into_owned();
        let eig = nalgebra::SymmetricEigen::new((p_bb + p_bb.transpose()) * 0.5);
        let mut bias = Vector3::zeros();
        let mut variance = Matrix3::zeros();
        for i in 0..3 {
            let v = eig.eigenvectors.column(i).into_owned();
            let sigma = eig.eigenvalues[i].max(0.0).sqrt();
            let along = v.dot(&self.bias);
            let known = sigma < self.cfg.apply_max_stddev && along.abs() > self.cfg.apply_min_z * sigma;
            bias += v * if known { along } else { 0.0 };
            // Not applied: the whole bias along it is left, as large as the prior allows.
            let left = if known { sigma * sigma } else { self.cfg.prior_stddev.powi(2).max(sigma * sigma) };
            variance += v * v.transpose() * left;
        }
        let level_up = if self.seeded { None } else { self.level_up() };
        self.about_up_withheld = level_up.is_some();
        if let Some(up) = level_up {
            // Not applied about up: what is left there is the whole bias along it.
            let across = Matrix3::identity() - up * up.transpose();
            bias = across * bias;
            variance = across * variance * across + up * up.transpose() * self.cfg.prior_stddev.powi(2);
        }
        self.applied = (bias, variance.diagonal());
    }

    /// The body's mean up direction (IMU axes) while the body has stayed within
    /// `min_tilt_about_up` (RMS) of it; `None` once it has turned farther.
    fn level_up(&self) -> Option<Vector3<f64>> {
        if self.used_blocks == 0 {
            return None;
        }
        let eig = nalgebra::SymmetricEigen::new(self.up_scatter / self.used_blocks as f64);
        let i = eig.eigenvalues.imax();
        // 1 − λ_max: the mean squared sine of the tilt away from the principal up.
        let tilt_rms = (1.0 - eig.eigenvalues[i]).max(0.0).sqrt().asin();
        (tilt_rms < self.cfg.min_tilt_about_up).then(|| eig.eigenvectors.column(i).into_owned())
    }

    /// The attitude (`world_from_body`, heading from where it started) once started.
    pub fn world_from_body(&self) -> Option<UnitQuaternion<f64>> {
        self.world_from_body
    }

    /// The attitude error's covariance, rad² about world x, y, z.
    pub fn attitude_covariance(&self) -> Matrix3<f64> {
        self.p.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// Starts the attitude at `world_from_body` with its error covariance (rad², about world
    /// axes), from sample `at_ns` (whose rate `gyro` turns it next): an attitude set otherwise
    /// (a gravity start-up averaged over a rest) instead of one sample's specific force.
    pub fn start_at(&mut self, world_from_body: UnitQuaternion<f64>, covariance: Matrix3<f64>, at_ns: i64, gyro: Vector3<f64>) {
        self.world_from_body = Some(world_from_body);
        let mut p = self.p;
        p.fixed_view_mut::<3, N>(0, 0).fill(0.0);
        p.fixed_view_mut::<N, 3>(0, 0).fill(0.0);
        // A tilt found from the specific force carries the accelerometer's bias: level in the
        // estimate means R̂ (f) ∥ z, so δθ_x = (R̂ b_a)_y / g and δθ_y = −(R̂ b_a)_x / g. Its
        // variance and its correlation with b_a are part of the start (without them, the error
        // a bias put into the start is never owned).
        let r = *world_from_body.to_rotation_matrix().matrix();
        let swap = Matrix3::new(0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let j = swap * r / STANDARD_GRAVITY;
        let p_ab: Matrix3<f64> = p.fixed_view::<3, 3>(6, 6).into_owned();
        let cross = j * p_ab;
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&(covariance + cross * j.transpose()));
        p.fixed_view_mut::<3, 3>(0, 6).copy_from(&cross);
        p.fixed_view_mut::<3, 3>(6, 0).copy_from(&cross.transpose());
        self.p = p;
        self.block = Block::empty(at_ns);
        self.last = Some((at_ns, gyro));
    }

    /// Holds the attitude over a hole in the input that ends at `at_ns` (integrating a stale
    /// rate across it would invent motion): nothing is propagated, `added_variance` rad² goes
    /// on each attitude axis, and the block in progress starts again.
    pub fn hold(&mut self, at_ns: i64, added_variance: f64) {
        if self.world_from_body.is_none() {
            return;
        }
        if let Some((_, w)) = self.last {
            self.last = Some((at_ns, w));
        }
        for i in 0..3 {
            self.p[(i, i)] += added_variance;
        }
        self.let_speed_wander((at_ns - self.block.start_ns).max(0) as f64 * 1e-9);
        self.block = Block::empty(at_ns);
    }

    /// The forward speed and its σ, m/s, where it is modelled (`forward_speed_stddev`).
    pub fn forward_speed(&self) -> Option<(f64, f64)> {
        self.models_speed().then(|| (self.speed, self.p[(U, U)].max(0.0).sqrt()))
    }

    /// True where the platform's forward speed is a state (a car).
    fn models_speed(&self) -> bool {
        self.cfg.forward_speed_stddev > 0.0
    }

    /// True where the gyro's scale and cross-axis errors are considered (`rate_error_stddev`).
    pub fn considers_rate_error(&self) -> bool {
        self.cfg.rate_error_stddev > 0.0
    }

    /// The forward speed's variance grown over `seconds` with nothing measured.
    fn let_speed_wander(&mut self, seconds: f64) {
        if self.models_speed() {
            self.p[(U, U)] += self.cfg.forward_speed_walk.powi(2) * seconds;
        }
    }

    /// Blocks used as measurements, and blocks left out.
    pub fn blocks(&self) -> (u64, u64) {
        (self.used_blocks, self.skipped_blocks)
    }

    /// Sets the bias to a standstill's estimate and its variance (no correlation with the
    /// rest of the state is kept: the standstill measured it directly).
    pub fn seed(&mut self, bias: Vector3<f64>, variance: Vector3<f64>) {
        self.bias = bias;
        self.seeded = true;
        let mut p = self.p;
        p.fixed_view_mut::<3, N>(3, 0).fill(0.0);
        p.fixed_view_mut::<N, 3>(0, 3).fill(0.0);
        p.fixed_view_mut::<3, 3>(3, 3).copy_from(&Matrix3::from_diagonal(&variance));
        self.p = p;
        self.decide_applied();
    }

    /// The gyro it is fed has `delta` less bias from now on (removed upstream): the estimate
    /// moves with it, its covariance unchanged.
    pub fn shift_bias(&mut self, delta: Vector3<f64>) {
        self.bias -= delta;
    }

    /// Forgets everything: a new power-on.
    pub fn restart(&mut self) {
        *self = MotionBias::new(self.cfg);
    }

    /// One sample, in stamp order. Returns the verdict on a block this sample closed.
    pub fn push(&mut self, s: &ImuSample) -> Option<BlockVerdict> {
        let mut verdict = None;
        match (self.last, self.world_from_body) {
            // A stamp equal to the last: the end of a hold ([`Self::hold`]), nothing to turn.
            (Some((t, w)), Some(q)) if s.stamp_ns >= t && (s.stamp_ns - t) as f64 * 1e-9 <= self.cfg.max_sample_gap_s => {
                let dt = (s.stamp_ns - t) as f64 * 1e-9;
                self.propagate(q, &w, dt);
                if (s.stamp_ns - self.block.start_ns) as f64 * 1e-9 >= self.cfg.block_s {
                    verdict = Some(self.close_block(s.stamp_ns));
                    self.block = Block::empty(s.stamp_ns);
                }
            }
            _ => self.start_attitude(s),
        }
        self.accumulate(s);
        self.last = Some((s.stamp_ns, s.gyro));
        verdict
    }

    /// The attitude from this sample's specific force (heading 0); the biases and their
    /// variances stay (a gap does not change the sensor).
    fn start_attitude(&mut self, s: &ImuSample) {
        let up = Vector3::z();
        let tilt = UnitQuaternion::rotation_between(&(s.accel - self.accel_bias), &up).unwrap_or_else(UnitQuaternion::identity);
        self.world_from_body = Some(tilt);
        let v = self.cfg.initial_tilt_stddev.powi(2);
        let mut p = self.p;
        p.fixed_view_mut::<3, N>(0, 0).fill(0.0);
        p.fixed_view_mut::<N, 3>(0, 0).fill(0.0);
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::from_diagonal(&Vector3::new(v, v, 1.0)));
        self.p = p;
        self.block = Block::empty(s.stamp_ns);
    }

    fn accumulate(&mut self, s: &ImuSample) {
        let Some(q) = self.world_from_body else { return };
        let r = *q.to_rotation_matrix().matrix();
        let models_speed = self.models_speed();
        let b = &mut self.block;
        b.n += 1;
        b.force += r * (s.accel - self.accel_bias);
        b.rotation += r;
        if self.cfg.rate_error_stddev > 0.0 {
            b.turned_sum += b.turned;
        }
        let t = (s.stamp_ns - b.start_ns) as f64 * 1e-9;
        b.rotation_t += r * t;
        if models_speed {
            // ω × x = (0, ω_z, −ω_y).
            let w = s.gyro - self.bias;
            let bend = r * Vector3::new(0.0, w.z, -w.y);
            b.bend += bend;
            b.bend_t += bend * t;
        }
    }

    /// The attitude turned by the last rate minus the bias; the error's covariance grown:
    /// δθ̇ = −R̂ δb + noise, δḃ = random walk, the accelerometer's bias constant.
    fn propagate(&mut self, q: UnitQuaternion<f64>, w: &Vector3<f64>, dt: f64) {
        let r = *q.to_rotation_matrix().matrix();
        self.world_from_body = Some(renormalize(q * exp(&((w - self.bias) * dt))));
        // Φ = I + E, E's only block A = −R̂ dt at (attitude, bias): Φ P Φᵀ = P + E P + (E P)ᵀ
        // + E P Eᵀ, with E P = A P[bias rows] in the attitude rows (≈ 150 products, not 1,500).
        let a = -r * dt;
        if self.considers_rate_error() {
            // ΔC's block of E: −R̂ D(ω) dt, D(ω) = I ⊗ ωᵀ (entry (i, j) of ΔC adds ω_j to axis i).
            let wb = w - self.bias;
            let mut turned = SMatrix::<f64, 3, 9>::zeros();
            for i in 0..3 {
                for j in 0..3 {
                    turned.set_column(3 * i + j, &(r.column(i) * (wb[j] * dt)));
                }
            }
            let ep: SMatrix<f64, 3, N> = a * self.p.fixed_view::<3, N>(3, 0) - turned * self.p.fixed_view::<9, N>(C, 0);
            let epe = ep.fixed_view::<3, 3>(0, 3) * a.transpose() - ep.fixed_view::<3, 9>(0, C) * turned.transpose();
            self.grow_attitude(&ep, &epe);
            self.block.turned += turned;
        } else {
            // ΔC's rows and columns are zero and stay so: only the first C states take part.
            let ep: SMatrix<f64, 3, C> = a * self.p.fixed_view::<3, C>(3, 0);
            let epe = ep.fixed_view::<3, 3>(0, 3) * a.transpose();
            self.grow_attitude(&ep, &epe);
        }
        // The rate-proportional error: (f |ω| dt)² per step summed over a block of n steps is
        // (f θ)² / n; times n (the steps of a block, block_s / dt) it is the block's (f θ)².
        let rate_error = (self.cfg.rate_error_fraction * (w - self.bias).norm()).powi(2) * dt * self.cfg.block_s;
        let (ng, nb) = (self.cfg.gyro_noise_density.powi(2) * dt + rate_error, self.cfg.bias_random_walk.powi(2) * dt);
        for i in 0..3 {
            self.p[(i, i)] += ng;
            self.p[(i + 3, i + 3)] += nb;
        }
    }

    /// P + E P + (E P)ᵀ + E P Eᵀ in place, E P = `ep` on the first M states' attitude rows and
    /// E P Eᵀ = `epe`.
    fn grow_attitude<const M: usize>(&mut self, ep: &SMatrix<f64, 3, M>, epe: &Matrix3<f64>) {
        let mut rows = self.p.fixed_view_mut::<3, M>(0, 0);
        rows += ep;
        let mut cols = self.p.fixed_view_mut::<M, 3>(0, 0);
        cols += ep.transpose();
        let mut corner = self.p.fixed_view_mut::<3, 3>(0, 0);
        corner += epe;
    }

    /// Closes the block ending at `end_ns`: its measurement; the forward speed carried to the
    /// next block's start even where the block is not used.
    fn close_block(&mut self, end_ns: i64) -> BlockVerdict {
        let verdict = self.measure_block(end_ns);
        if verdict != BlockVerdict::Used {
            self.let_speed_wander((end_ns - self.block.start_ns) as f64 * 1e-9);
        }
        verdict
    }

    /// The block's world-frame mean specific force against gravity: a 3-row update. With a
    /// forward speed u (u_end = u_start + w over the block, linear in between), the block's mean
    /// acceleration is w (mean(R̂ x) / T + mean(R̂ (ω × x) t / T)) + u_start mean(R̂ (ω × x)):
    /// the update is made on the state and this block's w together, then u carried to u_end.
    fn measure_block(&mut self, end_ns: i64) -> BlockVerdict {
        let b = self.block;
        let n = f64::from(b.n.max(1));
        let mean = b.force / n;
        let span_s = (end_ns - b.start_ns) as f64 * 1e-9;
        let car = self.models_speed() && span_s > 0.0;
        // Gravity plus the acceleration the forward speed predicts (a bend's, for a car).
        let predicted = if car { b.bend / n * self.speed } else { Vector3::zeros() };
        if b.n == 0 || ((mean - predicted).norm() - STANDARD_GRAVITY).abs() > self.cfg.max_gravity_error {
            self.skipped_blocks += 1;
            return BlockVerdict::NotGravity;
        }
        let Some(q) = self.world_from_body else { return BlockVerdict::NotGravity };
        // m/g ≈ e_z + e_z × δθ̄ + R̄ δb_a / g + ā / g, with δθ̄ = δθ_end + mean(R̂ (t_end − t)) δb
        // the block's mean attitude error, R̄ its mean attitude and ā the platform's mean
        // acceleration where it is modelled (a forward speed).
        let lag = (b.rotation * span_s - b.rotation_t) / n;
        let (h_speed, h_change, q_w) = if car {
            let h_speed = b.bend / (n * STANDARD_GRAVITY);
            let h_change = (b.rotation.column(0) / span_s + b.bend_t / span_s) / (n * STANDARD_GRAVITY);
            (h_speed, h_change, self.cfg.forward_speed_walk.powi(2) * span_s)
        } else {
            (Vector3::zeros(), Vector3::zeros(), 0.0)
        };
        let residual = mean / STANDARD_GRAVITY - Vector3::z() - h_speed * self.speed;
        // e_z × δθ = (−δθ_y, δθ_x, 0).
        let cross = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        // The state and this block's speed change w (one more, independent of the state).
        let mut h = SMatrix::<f64, 3, { N + 1 }>::zeros();
        h.fixed_view_mut::<3, 3>(0, 0).copy_from(&cross);
        h.fixed_view_mut::<3, 3>(0, 3).copy_from(&(cross * lag));
        h.fixed_view_mut::<3, 3>(0, 6).copy_from(&(b.rotation / (n * STANDARD_GRAVITY)));
        h.fixed_view_mut::<3, 1>(0, U).copy_from(&h_speed);
        h.fixed_view_mut::<3, 1>(0, N).copy_from(&h_change);
        if self.considers_rate_error() {
            // δθ̄ gains (∫ to the end − mean ∫ to each sample) of R̂ D(ω) dt times ΔC.
            h.fixed_view_mut::<3, 9>(0, C).copy_from(&(cross * (b.turned - b.turned_sum / n)));
        }
        let mut p = SMatrix::<f64, { N + 1 }, { N + 1 }>::zeros();
        p.fixed_view_mut::<N, N>(0, 0).copy_from(&self.p);
        p[(N, N)] = q_w;
        let sigma = self.cfg.accel_stddev / STANDARD_GRAVITY;
        let s = h * p * h.transpose() + Matrix3::identity() * sigma * sigma;
        let Some(s_inv) = s.try_inverse() else {
            self.skipped_blocks += 1;
            return BlockVerdict::NotGravity;
        };
        let nis = (residual.transpose() * s_inv * residual)[0];
        if nis > self.cfg.max_block_nis {
            self.skipped_blocks += 1;
            return BlockVerdict::Outlier;
        }
        self.nis += (nis - self.nis) / f64::from(self.cfg.fit_blocks);
        let mut k = p * h.transpose() * s_inv;
        // ΔC is considered, not estimated: no gain on it (its covariance then stays its prior,
        // its correlation with the rest is kept; the Joseph form below holds for any gain).
        k.fixed_view_mut::<9, 3>(C, 0).fill(0.0);
        if self.considers_rate_error() {
            // Nor on the heading, which gravity does not see (through ΔC's correlations a tilt's
            // innovation would turn it), nor on the bias about the body's mean up while it stays
            // near level: there the bias shows only through tilts that come with the platform's
            // own accelerations (`min_tilt_about_up`), and integrated it turns the heading. Without
            // the two, TUM-VI's hand-held rooms drifted 4–38° RMS in heading.
            let block_up = || (b.rotation.transpose() * Vector3::z()).try_normalize(1e-9);
            k.fixed_view_mut::<1, 3>(2, 0).fill(0.0);
            if let Some(up) = if self.used_blocks == 0 { block_up() } else { self.level_up() } {
                let across = Matrix3::identity() - up * up.transpose();
                let kb: SMatrix<f64, 3, 3> = across * k.fixed_view::<3, 3>(3, 0);
                k.fixed_view_mut::<3, 3>(3, 0).copy_from(&kb);
            }
        }
        let dx: SVector<f64, { N + 1 }> = k * residual;
        let i_kh = SMatrix::<f64, { N + 1 }, { N + 1 }>::identity() - k * h;
        let p = i_kh * p * i_kh.transpose() + k * k.transpose() * (sigma * sigma);
        // u_end = u_start + w.
        let mut f = SMatrix::<f64, N, { N + 1 }>::zeros();
        f.fixed_view_mut::<N, N>(0, 0).fill_with_identity();
        f[(U, N)] = 1.0;
        self.p = f * p * f.transpose();
        let dtheta = Vector3::new(dx[0], dx[1], dx[2]);
        self.world_from_body = Some(renormalize(exp(&dtheta) * q));
        self.bias += Vector3::new(dx[3], dx[4], dx[5]);
        self.accel_bias += Vector3::new(dx[6], dx[7], dx[8]);
        if car {
            self.speed += dx[U] + dx[N];
        }
        self.used_blocks += 1;
        let up = b.rotation.transpose() * Vector3::z();
        let up = up.try_normalize(1e-9).unwrap_or_else(Vector3::z);
        self.up_scatter += up * up.transpose();
        if self.nis > self.cfg.max_mean_nis || self.accel_bias.amax() > self.cfg.max_accel_bias_sigmas * self.cfg.accel_bias_stddev {
            self.misfit = true;
        }
        self.decide_applied();
        BlockVerdict::Used
    }
}

/// A body turning about all three axes (so every bias axis is seen), a constant gyro bias, the
/// specific force of gravity plus a wobble that averages out: 200 Hz, for tests.
#[cfg(test)]
pub(crate) fn tumbling(bias: Vector3<f64>, seconds: f64, wobble: f64) -> Vec<ImuSample> {
    tests::tumbling(bias, seconds, wobble)
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(super) fn tumbling(bias: Vector3<f64>, seconds: f64, wobble: f64) -> Vec<ImuSample> {
        let dt = 0.005;
        let mut q = UnitQuaternion::identity();
        (0..(seconds / dt) as usize)
            .map(|k| {
                let t = k as f64 * dt;
                let rate = Vector3::new(0.4 * (0.3 * t).sin(), 0.3 * (0.23 * t).cos(), 0.5 * (0.17 * t).sin());
                let accel_world = Vector3::new((1.3 * t).sin(), (0.9 * t).cos(), (1.1 * t).sin()) * wobble;
                let f = q.inverse() * (Vector3::z() * STANDARD_GRAVITY + accel_world);
                let s = ImuSample { stamp_ns: 1_000_000_000 + (t * 1e9) as i64, gyro: rate + bias, accel: f };
                q = renormalize(q * exp(&(rate * dt)));
                s
            })
            .collect()
    }

    #[test]
    fn a_tumbling_body_reveals_its_bias_within_the_stated_sigma() {
        let bias = Vector3::new(0.03, -0.05, 0.02);
        let mut f = MotionBias::new(MotionBiasConfig::default());
        for s in tumbling(bias, 120.0, 0.5) {
            f.push(&s);
        }
        let err = f.bias() - bias;
        let sigma = f.bias_variance().map(f64::sqrt);
        for i in 0..3 {
            assert!(err[i].abs() < 4.0 * sigma[i] && err[i].abs() < 0.005, "axis {i}: error {} σ {}", err[i], sigma[i]);
        }
        assert!(f.blocks().0 >= 100, "{:?}", f.blocks());
        // A body that turns over sees its bias about every axis: all of it is removed.
        assert!((f.applied().0 - bias).amax() < 0.005 && !f.withholds_about_up(), "{:?}", f.applied());
    }

    /// About gravity alone the bias is not seen: it stays at its prior, its variance too.
    #[test]
    fn a_bias_about_gravity_is_not_seen_while_the_body_stays_level() {
        let dt = 0.005;
        let bias = Vector3::new(0.0, 0.0, 0.04);
        let mut f = MotionBias::new(MotionBiasConfig::default());
        for k in 0..(60.0 / dt) as usize {
            let s =
                ImuSample { stamp_ns: 1_000_000_000 + (k as f64 * dt * 1e9) as i64, gyro: bias, accel: Vector3::z() * STANDARD_GRAVITY };
            f.push(&s);
        }
        assert!(f.bias().z.abs() < 1e-6, "{}", f.bias().z);
        assert!((f.bias_variance().z.sqrt() - 0.1).abs() < 0.01, "{:?}", f.bias_variance());
        // The level axes are measured: held at zero with a small σ.
        assert!(f.bias().xy().norm() < 1e-4 && f.bias_variance().x.sqrt() < 0.01);
    }

    /// A multirotor: level on average, yawing, tilting by up to 0.25 rad to accelerate, its
    /// specific force along its thrust (body z). Its tilts reveal the bias about up only
    /// together with the accelerations they cause.
    fn multirotor(bias: Vector3<f64>, seconds: f64) -> Vec<ImuSample> {
        let dt = 0.005;
        let attitude = |t: f64| {
            UnitQuaternion::from_euler_angles(0.18 * (1.3 * t).sin(), 0.18 * (0.9 * t + 1.0).sin(), 0.4 * (0.11 * t).sin() + 0.2 * t)
        };
        (0..(seconds / dt) as usize)
            .map(|k| {
                let t = k as f64 * dt;
                let (q, q_next) = (attitude(t), attitude(t + dt));
                let rate = (q.inverse() * q_next).scaled_axis() / dt;
                let thrust_up = q * Vector3::z();
                let f_world = thrust_up * (STANDARD_GRAVITY / thrust_up.z);
                ImuSample { stamp_ns: 1_000_000_000 + (t * 1e9) as i64, gyro: rate + bias, accel: q.inverse() * f_world }
            })
            .collect()
    }

    /// What the filter removes on the multirotor: (bias applied, its variance per axis), and
    /// whether it withheld the bias about up.
    fn applied_on_multirotor(cfg: MotionBiasConfig, bias: Vector3<f64>) -> (Vector3<f64>, Vector3<f64>, bool) {
        let mut f = MotionBias::new(cfg);
        for s in multirotor(bias, 180.0) {
            f.push(&s);
        }
        assert!(!f.misfit(), "the model check passes on this motion (mean NIS {})", f.nis());
        (f.applied().0, f.applied().1, f.withholds_about_up())
    }

    #[test]
    fn the_bias_about_up_is_not_removed_while_the_body_stays_near_level() {
        let bias = Vector3::new(0.03, -0.03, 0.03);
        let (applied, variance, withheld) = applied_on_multirotor(MotionBiasConfig::default(), bias);
        assert!(withheld);
        assert!(applied.z.abs() < 2e-3, "removed about up: {applied:?}");
        assert!((applied.xy() - bias.xy()).norm() < 0.01, "across up the bias is removed: {applied:?} for {bias:?}");
        assert!(variance.z.sqrt() >= 0.09, "the bias left about up is stated at its prior: {variance:?}");
        // Without the rule, what the tilts showed about up is removed with confidence, and it
        // is not the bias (−0.06 rad/s for +0.03).
        let (without, _, withheld) = applied_on_multirotor(MotionBiasConfig { min_tilt_about_up: 0.0, ..Default::default() }, bias);
        assert!(!withheld && (without.z - bias.z).abs() > 0.05, "{without:?}");
    }

    /// `apply_before_check`: a consumer gyro's turn-on bias across up is removed within seconds
    /// instead of after the check's 30 blocks; without it nothing is, and the check then
    /// applies the same.
    #[test]
    fn before_the_check_the_bias_is_applied_only_when_asked() {
        let bias = Vector3::new(0.08, -0.06, 0.02);
        let run = |cfg: MotionBiasConfig, seconds: f64| {
            let mut f = MotionBias::new(cfg);
            for s in multirotor(bias, seconds) {
                f.push(&s);
            }
            (f.before_check(), f.applied().0)
        };
        let asked = MotionBiasConfig { apply_before_check: true, ..Default::default() };
        let (before, applied) = run(asked, 15.0);
        assert!(before, "15 s are before the check's 30 blocks");
        assert!((applied.xy() - bias.xy()).norm() < 0.01, "removed across up before the check: {applied:?} for {bias:?}");
        let (before, applied) = run(MotionBiasConfig::default(), 15.0);
        assert!(before && applied == Vector3::zeros(), "{applied:?}");
        let (before, applied) = run(MotionBiasConfig::default(), 60.0);
        assert!(!before && (applied.xy() - bias.xy()).norm() < 0.01, "{applied:?}");
    }

    /// The structured Φ P Φᵀ equals the dense product.
    #[test]
    fn the_covariance_step_is_the_dense_one() {
        let mut f = MotionBias::new(MotionBiasConfig::default());
        let m = Cov::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 * 0.01 - 0.05);
        f.p = m * m.transpose() + Cov::identity() * 0.1;
        // ΔC not considered: its rows and columns are zero, as `new` makes them.
        f.p.fixed_view_mut::<9, N>(C, 0).fill(0.0);
        f.p.fixed_view_mut::<N, 9>(0, C).fill(0.0);
        let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let (w, dt) = (Vector3::new(0.2, -0.4, 0.1), 0.005);
        let mut phi = Cov::identity();
        phi.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-*q.to_rotation_matrix().matrix() * dt));
        let mut dense = phi * f.p * phi.transpose();
        f.propagate(q, &w, dt);
        let (ng, nb) = (f.cfg.gyro_noise_density.powi(2) * dt, f.cfg.bias_random_walk.powi(2) * dt);
        for i in 0..3 {
            dense[(i, i)] += ng;
            dense[(i + 3, i + 3)] += nb;
        }
        assert!((f.p - dense).amax() < 1e-15, "{}", (f.p - dense).amax());
    }

    /// With the gyro's scale and cross-axis errors considered, Φ has a second block at
    /// (attitude, ΔC): −R̂ D(ω) dt.
    #[test]
    fn the_covariance_step_with_rate_errors_is_the_dense_one() {
        let mut f = MotionBias::new(MotionBiasConfig { rate_error_stddev: 0.03, ..MotionBiasConfig::default() });
        let m = Cov::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 * 0.01 - 0.05);
        f.p = m * m.transpose() + Cov::identity() * 0.1;
        f.bias = Vector3::new(0.01, 0.02, -0.03);
        let q = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
        let (w, dt) = (Vector3::new(0.2, -0.4, 0.1), 0.005);
        let r = *q.to_rotation_matrix().matrix();
        let mut phi = Cov::identity();
        phi.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-r * dt));
        let wb = w - f.bias;
        for i in 0..3 {
            for j in 0..3 {
                phi.fixed_view_mut::<3, 1>(0, C + 3 * i + j).copy_from(&(-r.column(i) * wb[j] * dt));
            }
        }
        let mut dense = phi * f.p * phi.transpose();
        f.propagate(q, &w, dt);
        let (ng, nb) = (f.cfg.gyro_noise_density.powi(2) * dt, f.cfg.bias_random_walk.powi(2) * dt);
        for i in 0..3 {
            dense[(i, i)] += ng;
            dense[(i + 3, i + 3)] += nb;
        }
        assert!((f.p - dense).amax() < 1e-15, "{}", (f.p - dense).amax());
    }

    /// A car: level, driving at 12 ± 2 m/s along its x axis through bends of up to 0.3 rad/s
    /// (centripetal accelerations of up to 4 m/s², lasting seconds), braking and speeding up
    /// by 0.2–0.6 m/s²; its gyro biased. Its true up in the body is z throughout.
    fn car(bias: Vector3<f64>, seconds: f64) -> Vec<ImuSample> {
        let dt = 0.005;
        let heading = |t: f64| 1.2 * (0.25 * t).sin() + 0.05 * t;
        let speed = |t: f64| 12.0 + 2.0 * (0.1 * t).sin() + (0.3 * t).cos();
        (0..(seconds / dt) as usize)
            .map(|k| {
                let t = k as f64 * dt;
                let (h, h_rate) = (heading(t), (heading(t + 1e-4) - heading(t - 1e-4)) / 2e-4);
                let velocity = |t: f64| Vector3::new(heading(t).cos(), heading(t).sin(), 0.0) * speed(t);
                let accel = (velocity(t + 1e-4) - velocity(t - 1e-4)) / 2e-4;
                let q = UnitQuaternion::from_euler_angles(0.0, 0.0, h);
                let f = q.inverse() * (accel + Vector3::z() * STANDARD_GRAVITY);
                ImuSample { stamp_ns: 1_000_000_000 + (t * 1e9) as i64, gyro: Vector3::new(0.0, 0.0, h_rate) + bias, accel: f }
            })
            .collect()
    }

    /// The filter's tilt error on the car (RMS over its second half, rad) and the largest
    /// tilt NEES-like ratio error² / stated variance there.
    fn tilt_on_car(cfg: MotionBiasConfig) -> (f64, f64) {
        let imu = car(Vector3::new(0.004, -0.003, 0.002), 600.0);
        let mut f = MotionBias::new(cfg);
        let (mut sq, mut n, mut worst) = (0.0, 0.0, 0.0_f64);
        for (k, s) in imu.iter().enumerate() {
            f.push(s);
            if k > imu.len() / 2 && k % 200 == 0 {
                let q = f.world_from_body().expect("started");
                // The truth is level: the estimate's up in the body against z.
                let tilt = (q.inverse() * Vector3::z()).angle(&Vector3::z());
                sq += tilt * tilt;
                n += 1.0;
                let p = f.attitude_covariance();
                worst = worst.max(tilt * tilt / (p[(0, 0)] + p[(1, 1)]));
            }
        }
        ((sq / n).sqrt(), worst)
    }

    /// On a car the bends' centripetal and the brakings' accelerations last seconds: taken as
    /// the block's noise they tilt the estimate by degrees; with the forward speed as a state
    /// they are predicted (speed × turn rate across, its change along), and the tilt follows
    /// the truth to a fraction of that, within what the filter states.
    #[test]
    fn a_forward_speed_state_holds_a_car_level_through_its_bends() {
        let plain = MotionBiasConfig::default();
        let (without, _) = tilt_on_car(plain);
        let (with, worst) = tilt_on_car(MotionBiasConfig { forward_speed_stddev: 20.0, accel_stddev: 0.5, ..plain });
        eprintln!("car, tilt RMS: {:.3}° without the forward speed, {:.3}° with it", without.to_degrees(), with.to_degrees());
        assert!(with < 0.3 * without, "{with} rad with the forward speed against {without} rad without");
        assert!(worst < 16.0, "an error beyond 4 σ of what is stated: {worst}");
    }

    #[test]
    fn a_seed_sets_the_bias_and_a_gap_keeps_it() {
        let mut f = MotionBias::new(MotionBiasConfig::default());
        let mut imu = tumbling(Vector3::new(0.01, 0.0, 0.0), 5.0, 0.0);
        f.push(&imu[0]);
        f.seed(Vector3::new(0.01, 0.0, 0.0), Vector3::repeat(1e-8));
        // Half a second missing after 2.5 s: the attitude restarts, the bias stays.
        for s in &mut imu[500..] {
            s.stamp_ns += 500_000_000;
        }
        for s in &imu[1..] {
            f.push(s);
        }
        assert!((f.bias() - Vector3::new(0.01, 0.0, 0.0)).norm() < 1e-3, "{:?}", f.bias());
    }
}
