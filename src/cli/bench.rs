//! `imu-fsda bench`: per-sample cost of the node's path, printed as figures.
//!
//! Measures, on one core and in the same run: sustained throughput of
//! decode (CDR) → correct → integrate → encode (CDR) with the incremental (streaming) model
//! in f32 (the node's path), the same in f64 (the reference) and the naive approach (a
//! full-window tch forward per sample), and the resident memory over an hour of simulated
//! 200 Hz input.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use imu_fsda::core::ImuSample;
use imu_fsda::infer::{FullWindowCorrector, GyroCorrector, ModelCorrector, OrientationMode, PassThrough, Pipeline, PipelineConfig};
use imu_fsda::model::export::{export_model, ExportInfo};
use imu_fsda::model::{Config, Mode, Net, Precision};
use imu_fsda::msg::{Imu, RosMessage};
use imu_fsda::node::fill_denoised;
use nalgebra::Vector3;

#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Model to benchmark (`.pt`/`.json`); default: a seeded FSDA-F model of the paper's shape.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Samples timed in the incremental throughput run (after a warm-up of two windows).
    #[arg(long, default_value_t = 50_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub samples: u64,
    /// Samples timed in the naive full-window run (it is slow; after a warm-up of 20).
    #[arg(long, default_value_t = 400, value_parser = clap::value_parser!(u64).range(1..))]
    pub naive_samples: u64,
    /// Hours of simulated 200 Hz input for the memory run (0 = skip; at most 100).
    #[arg(long, default_value_t = 1.0, value_parser = memory_hours)]
    pub memory_hours: f64,
    /// Write the figures as JSON here too.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Also save the seeded default model into this directory, as bench-fsda-f.pt/.ot/.json
    /// (for the DDS latency script).
    #[arg(long, value_name = "DIR", conflicts_with = "model")]
    pub save_model: Option<PathBuf>,
}

/// Hours of the memory run: 0 to 100 (an hour is 720,000 samples, a few minutes).
fn memory_hours(s: &str) -> Result<f64, String> {
    super::non_negative(s).and_then(|h| if h <= 100.0 { Ok(h) } else { Err(format!("{s} h is over the 100 h this run allows")) })
}

/// A synthetic 200 Hz stream (motion + gravity), encoded as the node receives it.
fn encoded_stream(n: usize) -> Vec<Vec<u8>> {
    (0..n)
        .map(|k| {
            let t = k as f64 * 0.005;
            let s = ImuSample {
                stamp_ns: 1_000_000_000 + k as i64 * 5_000_000,
                gyro: Vector3::new(0.3 * (1.3 * t).sin(), -0.2 * (0.7 * t).cos(), 0.1 * (2.1 * t).sin() + 0.08),
                accel: Vector3::new(0.5 * (0.9 * t).sin(), 0.3 * (1.7 * t).cos(), 9.81),
            };
            Imu::from_sample(&s, "imu_link").encode().expect("encode")
        })
        .collect()
}

/// decode → push → fill → encode for every message; samples/s.
fn throughput(pipeline: &mut Pipeline, input: &[Vec<u8>]) -> anyhow::Result<f64> {
    let mut out = Vec::with_capacity(512);
    let start = Instant::now();
    for bytes in input {
        let mut msg = Imu::decode(bytes)?;
        if let Ok(c) = pipeline.push(&msg.sample()) {
            fill_denoised(&mut msg, &c);
            msg.encode_into(&mut out)?;
        }
        std::hint::black_box(&out);
    }
    Ok(input.len() as f64 / start.elapsed().as_secs_f64())
}

fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("VmRSS:")).and_then(|l| l.split_whitespace().nth(1)).and_then(|v| v.parse().ok()))
        .unwrap_or(0)
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    if let Some(dir) = args.save_model.as_ref().filter(|d| d.exists() && !d.is_dir()) {
        anyhow::bail!("--save-model {}: not a directory (the model is saved into it as bench-fsda-f.*)", dir.display());
    }
    tch::set_num_threads(1);
    let tmp = tempfile::tempdir()?;
    let model = match &args.model {
        Some(m) => m.clone(),
        None => untrained_model(args.save_model.as_deref().unwrap_or(tmp.path()))?,
    };
    let loaded = imu_fsda::model::export::load_net(&imu_fsda::model::predict::metadata_path(&model), tch::Device::Cpu)
        .context("loading the model")?;
    let n = loaded.net.receptive_field() as usize;
    let cfg = PipelineConfig { nominal_rate_hz: 200.0, ..Default::default() };

    // Warm the caches and fill the window first, then time the samples that follow (the
    // stream goes on: replaying its start again would be dropped as backwards stamps).
    let (samples, naive_samples) = (args.samples as usize, args.naive_samples as usize);
    let (warm, naive_warm) = (2 * n, 20);
    let input = encoded_stream(warm.max(naive_warm) + samples.max(naive_samples));
    let mut incremental = Pipeline::new(Box::new(ModelCorrector::load(&model, None)?), cfg.clone());
    throughput(&mut incremental, &input[..warm])?;
    let timed = &input[warm..warm + samples];
    let inc = throughput(&mut incremental, timed)?;
    let processed = incremental.counters().processed as usize;
    anyhow::ensure!(processed == warm + samples, "the incremental run processed {processed} of {} samples", warm + samples);

    let mut reference_model = ModelCorrector::load(&model, None)?;
    reference_model.denoiser.set_precision(Precision::F64);
    let mut reference = Pipeline::new(Box::new(reference_model), cfg.clone());
    throughput(&mut reference, &input[..warm])?;
    let reference_f64 = throughput(&mut reference, timed)?;

    let naive_in = &input[naive_warm..naive_warm + naive_samples];
    let mut naive = Pipeline::new(Box::new(FullWindowCorrector::new(loaded.net.inference(), &loaded.metadata.name)), cfg.clone());
    throughput(&mut naive, &input[..naive_warm])?;
    let nai = throughput(&mut naive, naive_in)?;

    let StageCosts { stage_us, staged, bare, aided_us, aided, open } = stage_costs(&cfg, &input[..warm + samples])?;
    out!("model: {} ({:?}), window N = {n}", loaded.metadata.name, loaded.metadata.mode)?;
    out!("decode → correct → integrate → encode, one thread:")?;
    out!("  incremental, f32 (node) : {inc:>12.0} samples/s  ({:.2} µs/sample, {} samples)", 1e6 / inc, timed.len())?;
    out!("  incremental, f64 (ref.) : {reference_f64:>12.0} samples/s  ({:.2} µs/sample, {} samples)", 1e6 / reference_f64, timed.len())?;
    out!("  naive full-window (tch) : {nai:>12.0} samples/s  ({:.2} µs/sample, {} samples)", 1e6 / nai, naive_in.len())?;
    out!("  speed-up                : {:>12.1}× the f64 reference, {:.1}× the naive forward", inc / reference_f64, inc / nai)?;
    let met = |ok: bool| if ok { "met" } else { "NOT met" };
    out!("  target ≥ 60,000 samples/s: {}; ≥ 5× the f64 reference: {}", met(inc >= 60_000.0), met(inc >= 5.0 * reference_f64))?;
    out!(
        "  of which the power-on bias (standstills, bias in motion): {stage_us:.2} µs/sample (no model: {staged:.0} samples/s with it, {bare:.0} without)"
    )?;
    out!("  of which the gravity-aided orientation: {aided_us:.2} µs/sample (no model: {aided:.0} samples/s, open loop {open:.0})")?;

    let memory = if args.memory_hours > 0.0 { resident_memory(&model, cfg, args.memory_hours)? } else { Vec::new() };
    if let Some(path) = &args.json {
        let v = serde_json::json!({
            "model": loaded.metadata.name, "window_n": n,
            "incremental_samples_per_s": inc, "reference_f64_samples_per_s": reference_f64, "naive_samples_per_s": nai,
            "power_on_bias_us_per_sample": stage_us, "gravity_aided_us_per_sample": aided_us,
            "memory_kib": memory.iter().map(|(h, k)| serde_json::json!({"hours": h, "rss_kib": k})).collect::<Vec<_>>(),
        });
        std::fs::write(path, serde_json::to_string_pretty(&v)?)?;
    }
    Ok(())
}

/// A Generator of the bundled shape with untrained weights, exported into `dir`.
fn untrained_model(dir: &std::path::Path) -> anyhow::Result<std::path::PathBuf> {
    tch::manual_seed(0);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let net = Net::new(&Config::for_mode(Mode::FsdaF), &vs.root())?;
    net.set_normalization(&[0.0, 0.02, 0.08, 9.0, 0.0, -3.0], &[0.3, 0.3, 0.3, 1.0, 1.0, 1.0])?;
    Ok(export_model(dir, "bench-fsda-f", &vs, &net, &ExportInfo::default())?.torchscript)
}

/// What two stages of the pipeline cost: µs a sample, and samples/s with and without them.
struct StageCosts {
    stage_us: f64,
    staged: f64,
    bare: f64,
    aided_us: f64,
    aided: f64,
    open: f64,
}

/// The power-on bias stage alone (standstills and the bias seen in motion) and the
/// gravity-aided orientation against the open loop: the pipeline without a model, with each
/// and without it, on the same samples in the same run.
fn stage_costs(cfg: &PipelineConfig, stage_input: &[Vec<u8>]) -> anyhow::Result<StageCosts> {
    let mut without_stage = Pipeline::new(Box::new(PassThrough), PipelineConfig { power_on_bias: false, ..cfg.clone() });
    let mut with_stage = Pipeline::new(Box::new(PassThrough), cfg.clone());
    let bare = throughput(&mut without_stage, stage_input)?;
    let staged = throughput(&mut with_stage, stage_input)?;
    let stage_us = 1e6 / staged - 1e6 / bare;
    let open_loop_cfg = PipelineConfig { orientation: OrientationMode::OpenLoop, ..cfg.clone() };
    let open = throughput(&mut Pipeline::new(Box::new(PassThrough), open_loop_cfg), stage_input)?;
    let aided = throughput(&mut Pipeline::new(Box::new(PassThrough), cfg.clone()), stage_input)?;
    Ok(StageCosts { stage_us, staged, bare, aided_us: 1e6 / aided - 1e6 / open, aided, open })
}

/// Resident memory (hours, KiB) while `hours` of simulated 200 Hz input go through the
/// incremental pipeline, printed as it goes.
fn resident_memory(model: &std::path::Path, cfg: PipelineConfig, hours: f64) -> anyhow::Result<Vec<(f64, u64)>> {
    let mut memory = Vec::new();
    let total = (hours * 3600.0 * 200.0) as usize;
    let mut p = Pipeline::new(Box::new(StreamingDenoiserCorrector(ModelCorrector::load(model, None)?)), cfg);
    let chunk = encoded_stream(20_000);
    let mut done = 0usize;
    let mut stamp_offset = 0i64;
    memory.push((0.0, rss_kib()));
    while done < total {
        let part = &chunk[..chunk.len().min(total - done)];
        for bytes in part {
            let mut msg = Imu::decode(bytes)?;
            let mut s = msg.sample();
            s.stamp_ns += stamp_offset;
            if let Ok(c) = p.push(&s) {
                fill_denoised(&mut msg, &c);
            }
        }
        done += part.len();
        stamp_offset += part.len() as i64 * 5_000_000;
        if done % 144_000 < chunk.len() || done >= total {
            memory.push((done as f64 / 200.0 / 3600.0, rss_kib()));
        }
    }
    out!("resident memory over {:.2} h of simulated 200 Hz input ({} samples):", hours, total)?;
    for (h, kib) in &memory {
        out!("  after {h:>5.2} h: {:>8.1} MiB", *kib as f64 / 1024.0)?;
    }
    Ok(memory)
}

/// The model corrector, by value (the memory run owns its own).
struct StreamingDenoiserCorrector(ModelCorrector);

impl GyroCorrector for StreamingDenoiserCorrector {
    fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
        self.0.step(gyro, accel)
    }
    fn reset(&mut self) {
        self.0.reset()
    }
    fn window(&self) -> usize {
        self.0.window()
    }
    fn rate_hz(&self) -> Option<f64> {
        self.0.rate_hz()
    }
    fn name(&self) -> &str {
        self.0.name()
    }
}
