//! Swapping the node's model between two samples without dropping or repeating one.
//!
//! The pipeline owns a [`SwappableCorrector`]; it counts every `step` (its sequence number
//! equals the pipeline's `processed` counter) and keeps the last few seconds of inputs with
//! the resets between them. The adaptation thread, off the real-time path:
//! 1. builds the new streaming model;
//! 2. warms it on the buffered recent history ([`warm_up`]: the last N samples since the
//!    last reset — after N samples a streaming state depends on those N inputs only, so
//!    the state equals the one it would have had running all along);
//! 3. hands it over with the sequence number of the last sample it was fed ([`SwapHandle::offer`]).
//!
//! At the next `step`, before correcting the new sample, the corrector feeds the new model
//! the samples that arrived during the warm-up (catch-up, usually a handful), then swaps.
//! While the pipeline feeds the model its periods ([`crate::resample`]) the node's buffer holds
//! input samples, not what the model is fed: the model is then offered cold
//! ([`SwapHandle::offer_cold`]) and warmed at the swap on the corrector's own history (one
//! window of steps on the real-time path, once).
//! The real-time path only ever `try_lock`s: it never waits for the adaptation thread.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use nalgebra::Vector3;

use crate::core::{ImuSample, PoseSample};
use crate::infer::GyroCorrector;

/// A processed IMU sample as the node buffers it: sequence number (1 = first processed),
/// the sample, and whether the corrector was reset just before it (a gap).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeqSample {
    pub seq: u64,
    pub sample: ImuSample,
    pub reset_before: bool,
}

/// What the adaptation thread hands over.
struct Offer {
    corrector: Box<dyn GyroCorrector>,
    /// `None`: not warmed; warm it on the corrector's own history at the swap.
    fed_through: Option<u64>,
}

#[derive(Default)]
struct Shared {
    offer: Option<Offer>,
    swaps: u64,
    /// (sequence number of the first sample the new model corrected, catch-up samples).
    last_swap: Option<(u64, usize)>,
}

/// The adaptation side's handle on a [`SwappableCorrector`].
#[derive(Clone)]
pub struct SwapHandle {
    shared: Arc<Mutex<Shared>>,
}

impl SwapHandle {
    /// Hand a warmed corrector over (fed every sample up to and including `fed_through`).
    /// It is installed before the next sample; an earlier offer not yet taken is replaced.
    pub fn offer(&self, corrector: Box<dyn GyroCorrector>, fed_through: u64) {
        let mut s = self.shared.lock().expect("swap lock");
        s.offer = Some(Offer { corrector, fed_through: Some(fed_through) });
    }

    /// Hand a corrector over that was not warmed: at the swap it is fed the corrector's own
    /// recent inputs (from the last reset, at most its window), on the real-time path.
    pub fn offer_cold(&self, corrector: Box<dyn GyroCorrector>) {
        let mut s = self.shared.lock().expect("swap lock");
        s.offer = Some(Offer { corrector, fed_through: None });
    }

    /// True while an offer waits to be installed.
    pub fn pending(&self) -> bool {
        self.shared.lock().expect("swap lock").offer.is_some()
    }

    /// Swaps done, and the last one's (first sequence number corrected by the new model, catch-up samples).
    pub fn swaps(&self) -> (u64, Option<(u64, usize)>) {
        let s = self.shared.lock().expect("swap lock");
        (s.swaps, s.last_swap)
    }
}

/// A [`GyroCorrector`] whose inner corrector can be replaced between two samples.
pub struct SwappableCorrector {
    inner: Box<dyn GyroCorrector>,
    seq: u64,
    reset_flag: bool,
    history: VecDeque<(u64, Vector3<f64>, Vector3<f64>, bool)>,
    capacity: usize,
    shared: Arc<Mutex<Shared>>,
    name: String,
}

impl SwappableCorrector {
    /// `catch_up_capacity`: samples kept for the catch-up (beyond them a late offer is
    /// re-warmed on the real-time path from this history, which costs N steps once).
    pub fn new(inner: Box<dyn GyroCorrector>, catch_up_capacity: usize) -> (Self, SwapHandle) {
        let shared = Arc::new(Mutex::new(Shared::default()));
        let capacity = catch_up_capacity.max(inner.window() + 1);
        let name = inner.name().to_string();
        (
            SwappableCorrector {
                inner,
                seq: 0,
                reset_flag: false,
                history: VecDeque::with_capacity(capacity),
                capacity,
                shared: shared.clone(),
                name,
            },
            SwapHandle { shared },
        )
    }

    fn install(&mut self, mut new: Box<dyn GyroCorrector>, fed_through: Option<u64>) -> usize {
        let first_kept = self.history.front().map_or(self.seq + 1, |h| h.0);
        let mut fed = 0;
        if fed_through.is_some_and(|f| f >= self.seq) {
            // Nothing arrived since the warm-up.
        } else if let Some(fed_through) = fed_through.filter(|f| f + 1 >= first_kept) {
            for (seq, g, a, reset) in &self.history {
                if *seq > fed_through {
                    if *reset {
                        new.reset();
                    }
                    new.step(g, a);
                    fed += 1;
                }
            }
        } else {
            // Cold, or too late for the catch-up buffer: warm on what is kept.
            if let Some(fed_through) = fed_through {
                tracing::warn!("model offer too old (fed through {fed_through}, now {}): re-warming on the stream", self.seq);
            }
            let n = new.window();
            let start = self.history.iter().rposition(|h| h.3).unwrap_or(0).max(self.history.len().saturating_sub(n));
            new.reset();
            for (_, g, a, _) in self.history.iter().skip(start) {
                new.step(g, a);
                fed += 1;
            }
        }
        if self.reset_flag {
            // The pipeline reset the corrector for the sample about to be stepped (a gap).
            new.reset();
        }
        self.name = new.name().to_string();
        self.inner = new;
        fed
    }
}

impl GyroCorrector for SwappableCorrector {
    fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
        let offer = self.shared.try_lock().ok().and_then(|mut s| s.offer.take());
        if let Some(offer) = offer {
            let fed = self.install(offer.corrector, offer.fed_through);
            let mut s = self.shared.lock().expect("swap lock");
            s.swaps += 1;
            s.last_swap = Some((self.seq + 1, fed));
        }
        self.seq += 1;
        if self.history.len() == self.capacity {
            self.history.pop_front();
        }
        self.history.push_back((self.seq, *gyro, *accel, std::mem::take(&mut self.reset_flag)));
        self.inner.step(gyro, accel)
    }
    fn reset(&mut self) {
        self.reset_flag = true;
        self.inner.reset();
    }
    fn window(&self) -> usize {
        self.inner.window()
    }
    fn rate_hz(&self) -> Option<f64> {
        self.inner.rate_hz()
    }
    fn name(&self) -> &str {
        &self.name
    }
    fn domain(&self) -> crate::infer::ModelDomain {
        self.inner.domain()
    }
    fn earlier_power_ons(&self, floor_stddev: f64) -> Option<crate::standstill::BiasPrediction> {
        self.inner.earlier_power_ons(floor_stddev)
    }
}

/// Feeds `corrector` the tail of `history` it needs to reach the running model's state:
/// from the last reset, at most its window N. Returns the last sequence number fed (0 if none).
pub fn warm_up(corrector: &mut dyn GyroCorrector, history: &[SeqSample]) -> u64 {
    let n = corrector.window();
    let start = history.iter().rposition(|h| h.reset_before).unwrap_or(0).max(history.len().saturating_sub(n));
    corrector.reset();
    for h in &history[start..] {
        corrector.step(&h.sample.gyro, &h.sample.accel);
    }
    history.last().map_or(0, |h| h.seq)
}

/// The node's recent input and ground truth for adaptation: bounded by time (the newest
/// `seconds`), oldest dropped first.
#[derive(Debug, Default)]
pub struct Buffers {
    pub seconds: f64,
    pub imu: VecDeque<SeqSample>,
    pub ground_truth: VecDeque<PoseSample>,
    ground_truth_backwards_run: crate::infer::BackwardsRun,
    /// The pipeline feeds the model its periods, not these samples ([`crate::resample`]).
    pub model_fed_periods: bool,
}

impl Buffers {
    pub fn new(seconds: f64) -> Self {
        Buffers { seconds, ..Default::default() }
    }

    fn horizon(&self, newest: i64) -> i64 {
        newest - (self.seconds * 1e9) as i64
    }

    pub fn push_imu(&mut self, s: SeqSample) {
        // The pipeline followed its source's clock back (`infer::CLOCK_JUMP_SAMPLES`): the old
        // timeline cannot be paired with the new one.
        if self.imu.back().is_some_and(|b| s.sample.stamp_ns <= b.sample.stamp_ns) {
            self.imu.clear();
        }
        let h = self.horizon(s.sample.stamp_ns);
        self.imu.push_back(s);
        while self.imu.front().is_some_and(|x| x.sample.stamp_ns < h) {
            self.imu.pop_front();
        }
    }

    /// Poses must come in stamp order; others are ignored (returns false), unless
    /// [`crate::infer::CLOCK_JUMP_SAMPLES`] of them in a row advance among themselves: then the
    /// source's clock went back (or one pose was stamped far ahead) and is followed, the
    /// buffer starting again. Before, one pose hours ahead blocked adaptation until restart.
    pub fn push_ground_truth(&mut self, p: PoseSample) -> bool {
        if self.ground_truth.back().is_some_and(|l| p.stamp_ns <= l.stamp_ns) {
            if !self.ground_truth_backwards_run.follows(p.stamp_ns) {
                return false;
            }
            self.ground_truth.clear();
        }
        self.ground_truth_backwards_run.end();
        let h = self.horizon(p.stamp_ns);
        self.ground_truth.push_back(p);
        while self.ground_truth.front().is_some_and(|x| x.stamp_ns < h) {
            self.ground_truth.pop_front();
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::infer::{ModelCorrector, ModelDomain, Pipeline, PipelineConfig};
    use crate::model::{Config, Mode, Net, StreamingDenoiser};

    fn model(seed: i64) -> ModelCorrector {
        tch::manual_seed(seed);
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let net = Net::new(&Config::for_mode(Mode::FsdaF), &vs.root()).unwrap();
        ModelCorrector {
            denoiser: StreamingDenoiser::from_net(&net).unwrap(),
            name: format!("m{seed}"),
            rate_hz: 200.0,
            domain: ModelDomain::Trained,
            trained_power_ons: Vec::new(),
        }
    }

    fn stream(n: usize) -> Vec<ImuSample> {
        (0..n)
            .map(|k| {
                let t = k as f64 * 0.005;
                // A one-second gap at sample 1500.
                let stamp = k as i64 * 5_000_000 + if k >= 1500 { 1_000_000_000 } else { 0 };
                ImuSample {
                    stamp_ns: stamp,
                    gyro: Vector3::new(0.3 * (1.3 * t).sin(), -0.2 * (0.7 * t).cos(), 0.1 * (2.1 * t).sin()),
                    accel: Vector3::new(0.5 * (0.9 * t).sin(), 0.3 * (1.7 * t).cos(), 9.81),
                }
            })
            .collect()
    }

    /// One pose stamped hours ahead is followed back after `CLOCK_JUMP_SAMPLES` poses; a single
    /// out-of-order pose is only refused.
    #[test]
    fn ground_truth_follows_a_clock_that_jumps_back() {
        let pose =
            |t: i64| PoseSample { stamp_ns: t, position_in_world: Vector3::zeros(), world_from_body: nalgebra::UnitQuaternion::identity() };
        let mut b = Buffers::new(60.0);
        for k in 0..100 {
            assert!(b.push_ground_truth(pose(k * 10_000_000)));
        }
        assert!(b.push_ground_truth(pose(3 * 3600 * 1_000_000_000)));
        let accepted: Vec<bool> = (100..200).map(|k| b.push_ground_truth(pose(k * 10_000_000))).collect();
        let first = accepted.iter().position(|a| *a).unwrap();
        assert_eq!(first + 1, crate::infer::CLOCK_JUMP_SAMPLES as usize);
        assert!(accepted[first..].iter().all(|a| *a));
        assert_eq!(b.ground_truth.front().unwrap().stamp_ns, (100 + first as i64) * 10_000_000);
        assert!(!b.push_ground_truth(pose(150 * 10_000_000)), "one late pose is refused");
        assert!(b.push_ground_truth(pose(200 * 10_000_000)));
    }

    /// After the swap the outputs equal those of the new model run from the start, and every
    /// sample is processed exactly once — whether the swap is before or after a gap, and
    /// with samples arriving during the warm-up.
    #[test]
    fn swap_is_exact_and_loses_nothing() {
        let imu = stream(3000);
        let cfg = PipelineConfig { nominal_rate_hz: 200.0, ..Default::default() };
        // Built once and cloned: tch's global RNG is shared with tests running in parallel,
        // so two seeded constructions are not guaranteed to give the same weights.
        let (old, new) = (model(1), model(2));
        let copy = |m: &ModelCorrector| ModelCorrector {
            denoiser: m.denoiser.clone(),
            name: m.name.clone(),
            rate_hz: m.rate_hz,
            domain: m.domain,
            trained_power_ons: m.trained_power_ons.clone(),
        };
        let mut reference = Pipeline::new(Box::new(copy(&new)), cfg.clone());
        let want: Vec<_> = imu.iter().map(|s| reference.push(s).unwrap()).collect();
        for (offer_at, late) in [(1200usize, 7usize), (1520, 3), (1500, 0), (1497, 3), (2600, 0), (900, 600)] {
            let (sw, handle) = SwappableCorrector::new(Box::new(copy(&old)), 400);
            let mut p = Pipeline::new(Box::new(sw), cfg.clone());
            let mut buf = Buffers::new(120.0);
            let mut got = Vec::new();
            for (k, s) in imu.iter().enumerate() {
                if k == offer_at + late {
                    // The warm-up used the history up to `offer_at`; `late` samples arrived meanwhile.
                    let hist: Vec<SeqSample> = buf.imu.iter().copied().filter(|h| h.seq as usize <= offer_at).collect();
                    let mut m = copy(&new);
                    let fed = warm_up(&mut m, &hist);
                    handle.offer(Box::new(m), fed);
                }
                let c = p.push(s).unwrap();
                buf.push_imu(SeqSample { seq: p.counters().processed, sample: *s, reset_before: c.after_gap });
                got.push(c);
            }
            assert_eq!(p.counters().processed, imu.len() as u64);
            let (swaps, last) = handle.swaps();
            assert_eq!(swaps, 1);
            let (first_new, fed) = last.unwrap();
            assert_eq!(first_new as usize, offer_at + late + 1);
            if late <= 400 {
                assert_eq!(fed, late);
            }
            for k in first_new as usize - 1..imu.len() {
                assert_eq!(got[k].gyro, want[k].gyro, "offer at {offer_at} (+{late}): sample {k} differs");
                assert_eq!(got[k].orientation.is_some(), want[k].orientation.is_some());
            }
            assert_ne!(got[offer_at / 2].gyro, want[offer_at / 2].gyro, "before the swap the old model ran");
        }
    }

    /// At 1 kHz the pipeline feeds the model its 5-ms periods, so the node's buffer of input
    /// samples is not what the model was fed: a model offered cold is warmed at the swap on the
    /// corrector's own inputs, and from the swap on the outputs equal those of the new model run
    /// from the start (before: it was warmed on 1-kHz samples, and was off for 2.6 s).
    #[test]
    fn a_cold_offer_is_exact_while_the_model_is_fed_periods() {
        let imu: Vec<ImuSample> =
            stream(3000).iter().flat_map(|s| (0..5).map(move |j| ImuSample { stamp_ns: s.stamp_ns + j * 1_000_000, ..*s })).collect();
        let cfg = PipelineConfig::default();
        let (old, new) = (model(1), model(2));
        let copy = |m: &ModelCorrector| ModelCorrector {
            denoiser: m.denoiser.clone(),
            name: m.name.clone(),
            rate_hz: m.rate_hz,
            domain: m.domain,
            trained_power_ons: m.trained_power_ons.clone(),
        };
        let mut reference = Pipeline::new(Box::new(copy(&new)), cfg.clone());
        let want: Vec<_> = imu.iter().map(|s| reference.push(s).unwrap()).collect();
        for offer_at in [6000usize, 7400, 9000] {
            let (sw, handle) = SwappableCorrector::new(Box::new(copy(&old)), 400);
            let mut p = Pipeline::new(Box::new(sw), cfg.clone());
            let mut got = Vec::new();
            for (k, s) in imu.iter().enumerate() {
                if k == offer_at {
                    handle.offer_cold(Box::new(copy(&new)));
                }
                got.push(p.push(s).unwrap());
            }
            assert!(p.resampling());
            let (swaps, last) = handle.swaps();
            assert_eq!(swaps, 1);
            // The swap comes at the next period the model is fed: from it, the new model's output.
            let first = (offer_at..imu.len()).find(|&k| got[k].correction != got[k - 1].correction).unwrap();
            assert!(first < offer_at + 5 && last.unwrap().1 > 0, "{first} {last:?}");
            for k in first..imu.len() {
                assert_eq!(got[k].gyro, want[k].gyro, "offer at {offer_at}: sample {k} differs");
            }
            assert_ne!(got[offer_at / 2].gyro, want[offer_at / 2].gyro, "before the swap the old model ran");
        }
    }

    #[test]
    fn buffers_are_bounded_by_time() {
        let mut b = Buffers::new(2.0);
        for k in 0..1000 {
            let s = ImuSample { stamp_ns: k * 5_000_000, gyro: Vector3::zeros(), accel: Vector3::zeros() };
            b.push_imu(SeqSample { seq: k as u64 + 1, sample: s, reset_before: false });
        }
        assert_eq!(b.imu.len(), 401);
        assert!(b.push_ground_truth(pose(0)) && b.push_ground_truth(pose(10)));
        assert!(!b.push_ground_truth(pose(5)), "out of order");
        assert!(b.push_ground_truth(pose(3_000_000_000)));
        assert_eq!(b.ground_truth.len(), 1);
    }

    fn pose(t: i64) -> PoseSample {
        PoseSample { stamp_ns: t, position_in_world: Vector3::zeros(), world_from_body: nalgebra::UnitQuaternion::identity() }
    }
}
