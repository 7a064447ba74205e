//! What corrects the gyro sample by sample: the trait and its implementations (the raw
//! gyro minus a constant, the gyro as measured, a model's streaming form, the naive window).

use nalgebra::Vector3;

use super::ModelDomain;
use crate::core::ImuSample;

/// Something that corrects a gyro stream sample by sample (causal, stateful).
pub trait GyroCorrector: Send {
    /// Corrected angular velocity (rad/s) of the newest sample.
    fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64>;
    /// Forget the history: the next sample starts a new stream (warm-up again).
    fn reset(&mut self);
    /// Samples of history the correction depends on (N); 1 for memoryless methods.
    fn window(&self) -> usize;
    /// The IMU rate the corrector was made for, Hz, if it has one.
    fn rate_hz(&self) -> Option<f64>;
    /// Short name for diagnostics.
    fn name(&self) -> &str;
    /// True when the output is the input unchanged: its noise is the sensor's own.
    fn passes_through(&self) -> bool {
        false
    }
    /// What this corrector is for the IMU it runs on (which correction [`super::choose`] runs).
    /// A plain correction applies as given.
    fn domain(&self) -> ModelDomain {
        ModelDomain::Trained
    }
    /// What the corrector knows of this IMU's earlier power-ons' biases (a model trained
    /// without them: [`super::trained_power_ons`]); `floor_stddev` as for a
    /// bias memory file.
    fn earlier_power_ons(&self, _floor_stddev: f64) -> Option<crate::standstill::BiasPrediction> {
        None
    }
}

/// The identity: the raw gyro minus a constant bias. The baseline and the model-free mode.
#[derive(Debug, Clone)]
pub struct BiasCorrector {
    pub bias: Vector3<f64>,
}

impl GyroCorrector for BiasCorrector {
    fn step(&mut self, gyro: &Vector3<f64>, _accel: &Vector3<f64>) -> Vector3<f64> {
        gyro - self.bias
    }
    fn reset(&mut self) {}
    fn window(&self) -> usize {
        1
    }
    fn rate_hz(&self) -> Option<f64> {
        None
    }
    fn name(&self) -> &str {
        "bias"
    }
}

/// The gyro as measured: what the node runs with no model configured.
pub struct PassThrough;

impl GyroCorrector for PassThrough {
    fn step(&mut self, gyro: &Vector3<f64>, _accel: &Vector3<f64>) -> Vector3<f64> {
        *gyro
    }
    fn reset(&mut self) {}
    fn window(&self) -> usize {
        1
    }
    fn rate_hz(&self) -> Option<f64> {
        None
    }
    fn name(&self) -> &str {
        "pass-through (no model)"
    }
    fn passes_through(&self) -> bool {
        true
    }
    fn domain(&self) -> ModelDomain {
        ModelDomain::NoModel
    }
}

/// A trained model in its streaming form (pure Rust, f32 networks, constant cost per sample).
pub struct ModelCorrector {
    pub denoiser: crate::model::StreamingDenoiser,
    pub name: String,
    pub rate_hz: f64,
    /// What the model is for the IMU it was loaded as.
    pub domain: ModelDomain,
    /// Its training recordings' power-on biases on this IMU (a model trained without them).
    pub trained_power_ons: Vec<crate::model::export::TrainedPowerOn>,
}

impl ModelCorrector {
    /// Load `<model>.json` + `<model>.ot` (the `.pt` beside them is the TorchScript form),
    /// with IMU `imu`'s Ĉ_ω (`None`: the model's own).
    pub fn load(model: &std::path::Path, imu: Option<&str>) -> Result<Self, crate::model::ModelError> {
        Ok(Self::load_with_metadata(model, imu)?.0)
    }

    /// [`ModelCorrector::load`], also returning the model's metadata.
    pub fn load_with_metadata(
        model: &std::path::Path,
        imu: Option<&str>,
    ) -> Result<(Self, crate::model::ModelMetadata), crate::model::ModelError> {
        let (denoiser, meta) = crate::model::export::load_streaming(&crate::model::predict::metadata_path(model), imu)?;
        let domain = ModelDomain::of(&meta, imu);
        let trained_power_ons = super::trained_power_ons(&meta, imu).to_vec();
        Ok((ModelCorrector { denoiser, name: meta.name.clone(), rate_hz: meta.rate_hz, domain, trained_power_ons }, meta))
    }
}

impl GyroCorrector for ModelCorrector {
    fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
        self.denoiser.step(gyro, accel)
    }
    fn reset(&mut self) {
        self.denoiser.reset();
    }
    fn window(&self) -> usize {
        self.denoiser.receptive_field()
    }
    fn rate_hz(&self) -> Option<f64> {
        (self.rate_hz > 0.0).then_some(self.rate_hz)
    }
    fn name(&self) -> &str {
        &self.name
    }
    fn domain(&self) -> ModelDomain {
        self.domain
    }
    fn earlier_power_ons(&self, floor_stddev: f64) -> Option<crate::standstill::BiasPrediction> {
        super::predict_from(&self.trained_power_ons, floor_stddev)
    }
}

/// The naive approach, for benchmarks: keep the last N samples and run the whole window
/// through the network (tch) for every new sample, keeping only the last output. Same
/// outputs as the streaming form (up to f32), cost proportional to N.
pub struct FullWindowCorrector {
    net: crate::model::InferenceNet,
    window: Vec<ImuSample>,
    n: usize,
    name: String,
    correction_gain: f64,
}

impl FullWindowCorrector {
    pub fn new(net: crate::model::InferenceNet, name: &str) -> Self {
        let n = net.receptive_field() as usize;
        FullWindowCorrector { net, window: Vec::with_capacity(n), n, name: format!("{name} (naive full window)"), correction_gain: 1.0 }
    }

    /// Applies the share `gain` of the model's correction (as [`crate::model::StreamingDenoiser::set_correction_gain`]).
    pub fn with_correction_gain(mut self, gain: f64) -> Self {
        self.correction_gain = gain;
        self
    }
}

impl GyroCorrector for FullWindowCorrector {
    fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
        let s = ImuSample { stamp_ns: 0, gyro: *gyro, accel: *accel };
        if self.window.is_empty() {
            // The model's causal padding: the first sample replicated to the left.
            self.window.resize(self.n, s);
        }
        self.window.rotate_left(1);
        if let Some(last) = self.window.last_mut() {
            *last = s;
        }
        let input = crate::model::predict::imu_tensor(&self.window, tch::Kind::Float);
        let out = tch::no_grad(|| self.net.forward(&input));
        let last = out.select(1, self.n as i64 - 1).reshape([3]).to_kind(tch::Kind::Double);
        match Vec::<f64>::try_from(last) {
            Ok(v) => crate::model::streaming::apply_correction_gain(gyro, &Vector3::new(v[0], v[1], v[2]), self.correction_gain),
            Err(_) => *gyro,
        }
    }
    fn reset(&mut self) {
        self.window.clear();
    }
    fn window(&self) -> usize {
        self.n
    }
    fn rate_hz(&self) -> Option<f64> {
        None
    }
    fn name(&self) -> &str {
        &self.name
    }
}
