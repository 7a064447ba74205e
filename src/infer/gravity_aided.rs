//! The orientation fused with gravity (`pipeline.orientation: gravity_aided`): the corrected
//! gyro integrated as in the open loop, its tilt pulled back by the accelerometer's gravity
//! direction, so the tilt stays bounded where an open-loop attitude drifts without end.
//!
//! The filter is [`crate::motion_bias::MotionBias`], the one that sees the gyro bias in motion,
//! run here on the *corrected* gyro: each block's specific force averaged in the world frame of
//! the integrated attitude (a platform's own accelerations average out there) against gravity,
//! with the corrected gyro's residual bias and the accelerometer's bias as states. A block
//! whose innovation is beyond `max_block_nis` (a car braking for seconds, a launch) is not used.
//! Heading is not observed: its variance grows as only the gyro holds it.

use crate::setting::InvalidSetting;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::core::ImuSample;
use crate::motion_bias::{MotionBias, MotionBiasConfig};

/// χ² with 3 degrees of freedom at 99.9 %: a block beyond is the platform's acceleration.
pub const CHI2_3DOF_999: f64 = 16.27;

/// How [`crate::infer::CorrectedImu::orientation`] is made.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OrientationMode {
    /// The corrected gyro integrated from the gravity start-up (the paper's output).
    OpenLoop,
    /// The same, its tilt corrected by gravity (this module): the default, its tilt lower than
    /// the open loop's on 19 of the 20 recordings of docs/node.md and its covariance
    /// consistent on all.
    #[default]
    GravityAided,
}

/// The gravity-aided filter's noise model and gate (`pipeline.gravity_aided`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GravityAidedConfig {
    /// Specific force averaged in the world frame over this long per measurement, s.
    pub block_s: f64,
    /// The platform's own acceleration left in a block's world-frame mean, m/s² (1 σ).
    pub accel_stddev: f64,
    /// A block whose ‖mean specific force‖ is farther than this from g is not used, m/s².
    pub max_gravity_error: f64,
    /// A block whose normalised innovation squared exceeds this is not used.
    pub max_block_nis: f64,
    /// The corrected gyro's white noise, rad/s/√Hz.
    pub gyro_noise_density: f64,
    /// The gyro's error in proportion to its rate where a model corrects it (the scale and
    /// cross-axis its Ĉ_ω leaves), a fraction of |ω| ([`MotionBiasConfig::rate_error_fraction`]).
    pub rate_error_fraction: f64,
    /// The same where no model runs (the gyro's own scale and cross-axis errors).
    pub uncorrected_rate_error_fraction: f64,
    /// The scale and cross-axis error a model leaves, each entry of ΔC 0 ± this, considered as
    /// a constant ([`MotionBiasConfig::rate_error_stddev`]; 0: not modelled).
    pub rate_error_stddev: f64,
    /// The same where no model runs: the gyro's own scale and cross-axis errors.
    pub uncorrected_rate_error_stddev: f64,
    /// How fast the corrected gyro's residual bias wanders, rad/s/√s.
    pub bias_random_walk: f64,
    /// The accelerometer's bias before anything is measured: 0 ± this, m/s².
    pub accel_bias_stddev: f64,
    /// A platform that moves along its body x (a car): its forward speed's prior σ, m/s (0:
    /// not such a platform) ([`MotionBiasConfig::forward_speed_stddev`]).
    pub forward_speed_stddev: f64,
    /// How fast that speed changes, m/s/√s.
    pub forward_speed_walk: f64,
}

impl Default for GravityAidedConfig {
    fn default() -> Self {
        // The motion filter's noise model (src/motion_bias.rs), a gate at χ²₃ 99.9 %.
        let m = MotionBiasConfig::default();
        GravityAidedConfig {
            // 2-s blocks at 1.4 m/s²: the trust in gravity per second of 1-s blocks at 2 m/s²
            // (1 / (T σ²) the same), averaged over twice as long, so a hand or a drone moving
            // back and forth (its velocity bounded) leaves half as much in a block. TUM-VI's
            // hand-held rooms without a model: mean tilt 1.05 → 0.83°; 2 s at 1 m/s² (twice
            // the trust) left a simulated car hour's error outside its stated σ (NEES 3.45).
            // 2 m/s² at 1 s: a car's bend or braking lasting seconds stays in a block's
            // world-frame mean (at 1 m/s² a simulated car hour's tilt NEES was 9.9). docs/node.md,
            // "Gravity aided"; docs/log/2026-12-07-gravity-block-length.md.
            block_s: 2.0,
            accel_stddev: 1.4,
            max_gravity_error: m.max_gravity_error,
            max_block_nis: CHI2_3DOF_999,
            gyro_noise_density: m.gyro_noise_density,
            // What a fitted Ĉ_ω leaves: a few tenths of a per cent (the ADIS16448's lasting
            // errors, docs/poweron.md), white per block (as ΔC states at 0.5 % the same within
            // 0.06° on EuRoC and TUM-VI).
            rate_error_fraction: 0.005,
            rate_error_stddev: 0.0,
            // Without a model, a consumer gyro's own scale and cross-axis errors (datasheets:
            // ±3 % and ±2 %) as constant ΔC states. White, they had to be 10 % of every turn for
            // a simulated hour's NEES, and then outweighed a good gyro: TUM-VI's calibrated
            // BMI160 tilted 3.03° on average against 1.05° now (docs/node.md).
            uncorrected_rate_error_fraction: 0.0,
            uncorrected_rate_error_stddev: 0.03,
            bias_random_walk: m.bias_random_walk,
            accel_bias_stddev: m.accel_bias_stddev,
            forward_speed_stddev: m.forward_speed_stddev,
            forward_speed_walk: m.forward_speed_walk,
        }
    }
}

impl GravityAidedConfig {
    /// Refuses settings the filter cannot run with, naming the key.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        for model_runs in [true, false] {
            self.filter_config(1e-3, model_runs).validate().map_err(|e| e.within("gravity_aided"))?;
        }
        Ok(())
    }

    /// The motion filter's settings: this module's, the residual bias's prior σ (rad/s) and
    /// the rate-proportional errors where a model runs or none does.
    fn filter_config(&self, bias_stddev: f64, model_runs: bool) -> MotionBiasConfig {
        let (rate_error_fraction, rate_error_stddev) = if model_runs {
            (self.rate_error_fraction, self.rate_error_stddev)
        } else {
            (self.uncorrected_rate_error_fraction, self.uncorrected_rate_error_stddev)
        };
        MotionBiasConfig {
            block_s: self.block_s,
            accel_stddev: self.accel_stddev,
            max_gravity_error: self.max_gravity_error,
            max_block_nis: self.max_block_nis,
            gyro_noise_density: self.gyro_noise_density,
            rate_error_fraction,
            rate_error_stddev,
            bias_random_walk: self.bias_random_walk,
            accel_bias_stddev: self.accel_bias_stddev,
            forward_speed_stddev: self.forward_speed_stddev,
            forward_speed_walk: self.forward_speed_walk,
            prior_stddev: bias_stddev,
            // The pipeline's gaps are held (`hold`), never integrated: no sample gap restarts it.
            max_sample_gap_s: 1e9,
            ..MotionBiasConfig::default()
        }
    }
}

/// The running gravity-aided attitude.
#[derive(Clone)]
pub(super) struct GravityAided {
    filter: MotionBias,
}

impl GravityAided {
    /// `bias_stddev`: the bias left in the corrected gyro (the pipeline's, when it starts);
    /// `model_runs`: a model corrects it (its Ĉ_ω the scale and cross-axis).
    pub(super) fn new(cfg: &GravityAidedConfig, bias_stddev: f64, model_runs: bool) -> Self {
        GravityAided { filter: MotionBias::new(cfg.filter_config(bias_stddev, model_runs)) }
    }

    /// Starts at an attitude already known (the pipeline's gravity start-up) at sample
    /// `stamp_ns`, whose corrected rate is `gyro`.
    pub(super) fn start_at(&mut self, world_from_body: UnitQuaternion<f64>, covariance: Matrix3<f64>, stamp_ns: i64, gyro: &Vector3<f64>) {
        self.filter.start_at(world_from_body, covariance, stamp_ns, *gyro);
    }

    /// One corrected sample (stamps after the last, gaps held first).
    pub(super) fn push(&mut self, stamp_ns: i64, gyro: &Vector3<f64>, accel: &Vector3<f64>) {
        self.filter.push(&ImuSample { stamp_ns, gyro: *gyro, accel: *accel });
    }

    /// The pipeline removes `delta` more of the power-on bias from the gyro from now on: the
    /// residual bias is that much less. `measured`: a standstill's variance of the bias, the
    /// residual then 0 within it (the standstill measured what the filter only inferred).
    pub(super) fn rebase_bias(&mut self, delta: Vector3<f64>, measured: Option<Vector3<f64>>) {
        match measured {
            Some(variance) => self.filter.seed(Vector3::zeros(), variance),
            None => self.filter.shift_bias(delta),
        }
    }

    /// True where its residual bias follows the power-on bias removed upstream
    /// ([`Self::rebase_bias`]): where the gyro's errors are considered constants (a white error
    /// of 10 % of every turn forgets within a block, and following it there was measured mixed:
    /// EuRoC MH_01–03 worse).
    pub(super) fn follows_upstream_bias(&self) -> bool {
        self.filter.considers_rate_error()
    }

    /// Over a hole in the input that ends at `at_ns`: the attitude is held, `added_variance`
    /// rad² on each axis.
    pub(super) fn hold(&mut self, at_ns: i64, added_variance: f64) {
        self.filter.hold(at_ns, added_variance);
    }

    pub(super) fn orientation(&self) -> Option<(UnitQuaternion<f64>, Matrix3<f64>)> {
        self.filter.world_from_body().map(|q| (q, self.filter.attitude_covariance()))
    }

    /// Blocks used, and left out (not gravity, or beyond the gate).
    pub(super) fn blocks(&self) -> (u64, u64) {
        self.filter.blocks()
    }

    /// A car's forward speed and its σ, m/s (`platform: car`).
    pub(super) fn forward_speed(&self) -> Option<(f64, f64)> {
        self.filter.forward_speed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::STANDARD_GRAVITY;
    use crate::infer::{PassThrough, Pipeline, PipelineConfig};
    use crate::so3::{exp, renormalize};

    fn config(orientation: OrientationMode) -> PipelineConfig {
        // The gyro as measured, its bias left in (no standstill, nothing seen in motion).
        PipelineConfig { orientation, gravity_init_seconds: 0.2, power_on_bias: false, ..Default::default() }
    }

    /// The angle between the true and the estimated gravity direction in the body, and the
    /// tilt NEES (the error about world x, y against the stated 2×2 covariance).
    fn tilt(truth: &UnitQuaternion<f64>, (q, p): &(UnitQuaternion<f64>, Matrix3<f64>)) -> (f64, f64) {
        let angle = (q.inverse() * Vector3::z()).angle(&(truth.inverse() * Vector3::z()));
        let e = (q * truth.inverse()).scaled_axis();
        let cov = p.fixed_view::<2, 2>(0, 0).into_owned();
        let nees = cov.try_inverse().map_or(f64::NAN, |c| (e.xy().transpose() * c * e.xy())[0]);
        (angle, nees)
    }

    /// Ten minutes of a body turning about every axis with a 10 mrad/s gyro bias left in: the
    /// open-loop tilt drifts by tens of degrees, the gravity-aided one stays within a degree,
    /// its stated covariance covering it, and the heading is the gyro's alone.
    #[test]
    fn the_tilt_stays_bounded_where_the_open_loop_drifts() {
        let bias = Vector3::new(0.01, -0.01, 0.005);
        let imu = crate::motion_bias::tumbling(bias, 600.0, 0.5);
        let mut truth = UnitQuaternion::identity();
        let mut truths = Vec::with_capacity(imu.len());
        for (k, s) in imu.iter().enumerate() {
            truths.push(truth);
            if let Some(next) = imu.get(k + 1) {
                truth = renormalize(truth * exp(&((s.gyro - bias) * ((next.stamp_ns - s.stamp_ns) as f64 * 1e-9))));
            }
        }
        let run = |mode| {
            let mut p = Pipeline::new(Box::new(PassThrough), config(mode));
            let out: Vec<_> = imu.iter().map(|s| p.push(s).unwrap().orientation).collect();
            (out, p.gravity_aided_blocks())
        };
        let (open, none) = run(OrientationMode::OpenLoop);
        let (aided, blocks) = run(OrientationMode::GravityAided);
        assert!(none.is_none(), "open loop: no blocks");
        let (used, left_out) = blocks.expect("the filter ran");
        let blocks_in_10_min = (600.0 / GravityAidedConfig::default().block_s) as u64;
        assert!(used + 5 >= blocks_in_10_min && left_out == 0, "{used} blocks used, {left_out} left out");
        let after_1_min = 60 * 200;
        let worst = |o: &[Option<(UnitQuaternion<f64>, Matrix3<f64>)>]| {
            (after_1_min..imu.len()).map(|k| tilt(&truths[k], o[k].as_ref().unwrap()).0.to_degrees()).fold(0.0, f64::max)
        };
        let (open_worst, aided_worst) = (worst(&open), worst(&aided));
        assert!(open_worst > 20.0, "the open loop drifts: {open_worst:.1}°");
        let rms = |o: &[Option<(UnitQuaternion<f64>, Matrix3<f64>)>]| {
            let n = imu.len() - after_1_min;
            ((after_1_min..imu.len()).map(|k| tilt(&truths[k], o[k].as_ref().unwrap()).0.powi(2)).sum::<f64>() / n as f64)
                .sqrt()
                .to_degrees()
        };
        eprintln!(
            "tumbling, after the first minute: open loop {:.2}° RMS ({open_worst:.2}° worst), gravity aided {:.2}° ({aided_worst:.2}°)",
            rms(&open),
            rms(&aided)
        );
        assert!(rms(&aided) < 1.0 && aided_worst < 3.0, "gravity aided: {aided_worst:.2}° at worst after the first minute");
        let nees: Vec<f64> = (after_1_min..imu.len()).step_by(200).map(|k| tilt(&truths[k], aided[k].as_ref().unwrap()).1).collect();
        let within = nees.iter().filter(|n| **n < crate::eval::CHI2_2DOF_95).count() as f64 / nees.len() as f64;
        assert!(within >= 0.95, "{:.0} % of the tilt errors within the stated 95 % bound", 100.0 * within);
        // Heading: gravity says nothing of it; it keeps the start's π² (yaw unknown).
        let (_, p_end) = aided[imu.len() - 1].unwrap();
        let (_, p_open) = open[imu.len() - 1].unwrap();
        // The tilt's σ stays bounded where the open loop's grows with time: a few degrees for
        // a gyro turning this fast with no model (`uncorrected_rate_error_stddev` allows 3 %
        // scale and cross-axis errors; this one has a bias alone, so the bound is wide here).
        assert!(
            p_end[(2, 2)] > 0.99 * PipelineConfig::default().initial_yaw_variance
                && p_end[(0, 0)] < 8f64.to_radians().powi(2)
                && p_end[(0, 0)] < 0.25 * p_open[(0, 0)],
            "{p_end} against the open loop's {p_open}"
        );
    }

    /// Ten minutes of the same tumbling read by a gyro with a consumer part's scale and
    /// cross-axis errors (+2.5 / −2 / +1.5 %, up to 2 % across) and no model: considered as
    /// constants (`uncorrected_rate_error_stddev`), they are covered by the stated tilt σ, and
    /// gravity holds the tilt to under half the open loop's.
    #[test]
    fn a_gyro_scale_and_cross_axis_error_is_covered() {
        let error = Matrix3::new(0.025, 0.02, -0.01, -0.015, -0.02, 0.02, 0.01, -0.02, 0.015);
        let imu = crate::motion_bias::tumbling(Vector3::zeros(), 600.0, 0.5);
        let mut truth = UnitQuaternion::identity();
        let mut truths = Vec::with_capacity(imu.len());
        for (k, s) in imu.iter().enumerate() {
            truths.push(truth);
            if let Some(next) = imu.get(k + 1) {
                truth = renormalize(truth * exp(&(s.gyro * ((next.stamp_ns - s.stamp_ns) as f64 * 1e-9))));
            }
        }
        let read: Vec<ImuSample> = imu.iter().map(|s| ImuSample { gyro: s.gyro + error * s.gyro, ..*s }).collect();
        let run = |cfg: PipelineConfig| {
            let mut p = Pipeline::new(Box::new(PassThrough), cfg);
            let out: Vec<_> = read.iter().map(|s| p.push(s).unwrap().orientation).collect();
            let errors: Vec<(f64, f64)> = (60 * 200..imu.len()).step_by(20).map(|k| tilt(&truths[k], out[k].as_ref().unwrap())).collect();
            let rms = (errors.iter().map(|e| e.0.powi(2)).sum::<f64>() / errors.len() as f64).sqrt().to_degrees();
            let within = errors.iter().filter(|e| e.1 < crate::eval::CHI2_2DOF_95).count() as f64 / errors.len() as f64;
            (rms, within)
        };
        let (open, _) = run(config(OrientationMode::OpenLoop));
        let (aided, within) = run(config(OrientationMode::GravityAided));
        let white = GravityAidedConfig { uncorrected_rate_error_fraction: 0.1, uncorrected_rate_error_stddev: 0.0, ..Default::default() };
        let (as_white, white_within) = run(PipelineConfig { gravity_aided: white, ..config(OrientationMode::GravityAided) });
        eprintln!(
            "scale and cross-axis errors, after the first minute: open loop {open:.2}°, gravity aided {aided:.2}° RMS ({:.0} % within 95 %), as white 10 % of every turn {as_white:.2}° ({:.0} %)",
            100.0 * within,
            100.0 * white_within
        );
        assert!(
            aided < 0.5 * open && within >= 0.95,
            "tilt {aided:.2}° RMS (open loop {open:.2}°), {:.0} % within the stated 95 % bound",
            100.0 * within
        );
    }

    /// A level body braking at 5 m/s² for 6 s: the blocks wholly inside it are left out (their
    /// specific force is not g); those it straddles pull the tilt, within the stated 3 σ (on a
    /// still body the accelerometer's unknown bias keeps that σ at degrees), and it returns.
    #[test]
    fn a_sustained_acceleration_is_covered_and_forgotten() {
        let dt_ns = 5_000_000;
        let imu: Vec<ImuSample> = (0..200 * 60)
            .map(|k| {
                let t = k as f64 * 0.005;
                let braking = (20.0..26.0).contains(&t);
                let accel = Vector3::new(if braking { -5.0 } else { 0.0 }, 0.0, STANDARD_GRAVITY);
                ImuSample { stamp_ns: 1_000_000 + k as i64 * dt_ns, gyro: Vector3::zeros(), accel }
            })
            .collect();
        let mut p = Pipeline::new(Box::new(PassThrough), config(OrientationMode::GravityAided));
        let out: Vec<_> = imu.iter().filter_map(|s| p.push(s).unwrap().orientation).collect();
        let (_, left_out) = p.gravity_aided_blocks().unwrap();
        assert!(left_out >= 2, "{left_out} blocks left out");
        let tilt_and_sigma = |(q, p): &(UnitQuaternion<f64>, Matrix3<f64>)| {
            ((q.inverse() * Vector3::z()).angle(&Vector3::z()), p[(0, 0)].max(p[(1, 1)]).sqrt())
        };
        for (k, o) in out.iter().enumerate() {
            let (tilt, sigma) = tilt_and_sigma(o);
            assert!(tilt < 3.0 * sigma, "sample {k}: tilt {:.2}° against σ {:.2}°", tilt.to_degrees(), sigma.to_degrees());
        }
        let (last, _) = tilt_and_sigma(out.last().unwrap());
        assert!(last.to_degrees() < 1.0, "{:.2}° 34 s after the braking", last.to_degrees());
    }

    /// A level body turning about up at `rate(t)` rad/s for `seconds` at 200 Hz, its gyro with
    /// `bias` and `noise(sample)` added to both sensors (gyro, then accelerometer); with the
    /// true heading at each sample.
    fn level_turns(
        bias: Vector3<f64>,
        seconds: f64,
        rate: impl Fn(f64) -> f64,
        mut noise: impl FnMut() -> (Vector3<f64>, Vector3<f64>),
    ) -> (Vec<ImuSample>, Vec<f64>) {
        let dt = 0.005;
        let (mut yaw, mut truth_yaw) = (0.0, Vec::new());
        let imu = (0..(seconds / dt) as usize)
            .map(|k| {
                let w = rate(k as f64 * dt);
                truth_yaw.push(yaw);
                yaw += w * dt;
                let (gyro_noise, accel_noise) = noise();
                let gyro = Vector3::new(0.0, 0.0, w) + bias + gyro_noise;
                let accel = Vector3::z() * STANDARD_GRAVITY + accel_noise;
                ImuSample { stamp_ns: 1_000_000_000 + k as i64 * 5_000_000, gyro, accel }
            })
            .collect();
        (imu, truth_yaw)
    }

    /// The heading error of `q` against a level body at heading `yaw`, degrees.
    fn heading_error_deg(q: &UnitQuaternion<f64>, yaw: f64) -> f64 {
        crate::eval::tilt_heading(&(q * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw).inverse())).1.to_degrees()
    }

    /// A noisy gyro at rest for 10 s, then three minutes of turns about up on a level body:
    /// the bias about up is the rest's alone (gravity never sees it), so the gravity-aided
    /// heading must drift no faster than the open loop's. Until 2026-12-07 the filter kept the
    /// first still window's error (the later windows of the rest moved its residual by their
    /// change instead of resetting it) and drifted faster.
    #[test]
    fn the_whole_first_rest_sets_the_bias_about_up() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (gyro_noise, accel_noise) = (Normal::new(0.0, 0.02).unwrap(), Normal::new(0.0, 0.05).unwrap());
        let rate = |t: f64| if t < 10.0 { 0.0 } else { 0.5 * (0.17 * (t - 10.0)).sin() };
        let noise = || {
            let gyro = Vector3::from_fn(|_, _| gyro_noise.sample(&mut rng));
            (gyro, Vector3::from_fn(|_, _| accel_noise.sample(&mut rng)))
        };
        let (imu, truth_yaw) = level_turns(Vector3::new(0.004, -0.003, 0.02), 190.0, rate, noise);
        let heading_error = |mode| {
            let cfg = PipelineConfig { orientation: mode, gravity_init_seconds: 0.2, ..Default::default() };
            let mut p = Pipeline::new(Box::new(PassThrough), cfg);
            let out: Vec<_> = imu.iter().map(|s| p.push(s).unwrap().orientation).collect();
            let last = imu.len() - 1;
            heading_error_deg(&out[last].unwrap().0, truth_yaw[last])
        };
        let (open, aided) = (heading_error(OrientationMode::OpenLoop), heading_error(OrientationMode::GravityAided));
        eprintln!("heading after 3 min of turns about up: open loop {open:.2}°, gravity aided {aided:.2}°");
        assert!(aided <= open + 0.3, "gravity aided {aided:.2}° against the open loop's {open:.2}°");
    }

    /// A body that turns about up for 20 s with a 30 mrad/s gyro bias, stands still for 10 s,
    /// then turns for two minutes more: at the first standstill the attitude is run again from
    /// the start with the bias known, so the heading published afterwards is not the 34° the
    /// bias turned it by before; what was published before the standstill is unchanged.
    #[test]
    fn the_first_standstill_runs_the_attitude_again_in_hindsight() {
        let rate = |t: f64| if (20.0..30.0).contains(&t) { 0.0 } else { 0.4 * (0.5 * t).sin() };
        let (imu, truth_yaw) = level_turns(Vector3::new(0.002, -0.003, 0.03), 150.0, rate, || (Vector3::zeros(), Vector3::zeros()));
        let run = |hindsight_s: f64| {
            let cfg = PipelineConfig { gravity_init_seconds: 0.2, attitude_hindsight_s: hindsight_s, ..Default::default() };
            let mut p = Pipeline::new(Box::new(PassThrough), cfg);
            imu.iter().map(|s| p.push(s).unwrap().orientation.map(|o| o.0)).collect::<Vec<_>>()
        };
        let (off, on) = (run(0.0), run(60.0));
        let before = 20 * 200;
        assert!(off[..before].iter().zip(&on[..before]).all(|(a, b)| a == b), "published before the standstill: unchanged");
        let last = imu.len() - 1;
        let (h_off, h_on) =
            (heading_error_deg(&off[last].unwrap(), truth_yaw[last]), heading_error_deg(&on[last].unwrap(), truth_yaw[last]));
        eprintln!("heading at the end: {h_off:.2}° without hindsight, {h_on:.2}° with");
        assert!(h_off > 20.0 && h_on < 1.0, "heading at the end: {h_off:.2}° without hindsight, {h_on:.2}° with");
    }

    /// Over a hole in the input the attitude is held and its variance grows.
    #[test]
    fn a_gap_holds_the_gravity_aided_attitude() {
        let mut imu = crate::motion_bias::tumbling(Vector3::zeros(), 20.0, 0.0);
        for s in &mut imu[2000..] {
            s.stamp_ns += 2_000_000_000;
        }
        let mut p = Pipeline::new(Box::new(PassThrough), config(OrientationMode::GravityAided));
        let out: Vec<_> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        let (before, after) = (out[1999].orientation.unwrap(), out[2000].orientation.unwrap());
        assert!(out[2000].after_gap);
        // The last sample's rate turns it over one period only (not over the two seconds).
        assert!(before.0.angle_to(&after.0) < 0.01, "{}", before.0.angle_to(&after.0));
        assert!(after.1.trace() > before.1.trace() + 1.0, "{} → {}", before.1.trace(), after.1.trace());
    }
}
