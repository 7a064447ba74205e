//! `imu-fsda node`: the live ROS 2 denoising node.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use imu_fsda::adapt::swap::SwappableCorrector;
use imu_fsda::infer::Pipeline;
use imu_fsda::node::{run_node_with_adaptation, AdaptService, AdaptSetup, NodeParams, RosEnvironment, RunLimits};

use super::corrector::load_corrector;

#[derive(Debug, clap::Args)]
pub struct NodeArgs {
    #[command(flatten)]
    pub config: NodeConfigArgs,
    /// Exit after publishing this many messages (tests, benchmarks).
    #[arg(long)]
    pub max_messages: Option<u64>,
    /// Exit when no input arrives for this many seconds after the first (tests, benchmarks).
    #[arg(long, value_parser = super::seconds)]
    pub idle_exit_s: Option<Duration>,
    /// Print the final statistics as JSON on exit.
    #[arg(long)]
    pub stats_json: bool,
    /// Benchmarks only: run the naive full-window forward per sample instead of the
    /// incremental model (same outputs up to f32, cost proportional to N).
    #[arg(long)]
    pub naive_full_window: bool,
    /// The SROS2 enclave whose security files the node uses when `ROS_SECURITY_ENABLE=true`
    /// (rcl's `--ros-args --enclave`; `ROS_SECURITY_ENCLAVE_OVERRIDE` wins; default `/`).
    #[arg(long)]
    pub enclave: Option<String>,
}

/// What configures the node's pipeline, shared by `node` and `replay`.
#[derive(Debug, clap::Args)]
pub struct NodeConfigArgs {
    /// ROS 2 parameter file (`imu_fsda: ros__parameters: …`); defaults apply without one.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Node name (also the section read from the parameter file).
    #[arg(long, default_value = "imu_fsda")]
    pub node_name: String,
    /// Topic remapping `from:=to` (repeatable), as `--ros-args -r`.
    #[arg(short = 'r', long = "remap")]
    pub remaps: Vec<String>,
    /// Model file, overriding the parameter `model` ("" = none).
    #[arg(long)]
    pub model: Option<String>,
    /// The IMU's name, for a model with a Ĉ_ω or correction gain per IMU (its `.json` lists
    /// them), overriding the parameter `imu_calibration` ("" = a new IMU: the whole correction).
    #[arg(long)]
    pub imu: Option<String>,
    /// Run the model even on an IMU it was neither trained nor adapted on (the parameter
    /// `pipeline.model_on_new_imu`); by default the node runs the power-on bias there.
    #[arg(long)]
    pub model_on_new_imu: bool,
}

impl NodeConfigArgs {
    /// The parameter file's section (or the defaults), with the remappings and model override applied.
    pub fn load(&self) -> anyhow::Result<NodeParams> {
        let mut params = match &self.params {
            Some(p) => NodeParams::from_yaml_file(p, &self.node_name)?,
            None => NodeParams::default(),
        };
        for r in &self.remaps {
            params.remap(r)?;
        }
        if !self.remaps.is_empty() {
            params.validate().map_err(|e| anyhow::anyhow!("after the remappings: {e}"))?;
        }
        if let Some(imu) = &self.imu {
            params.imu_calibration.clone_from(imu);
        }
        if let Some(m) = &self.model {
            params.model.clone_from(m);
        }
        params.pipeline.model_on_new_imu |= self.model_on_new_imu;
        Ok(params)
    }
}

pub fn run(args: NodeArgs) -> anyhow::Result<()> {
    let mut params = args.config.load()?;
    if let Some(note) = params.take_bias_memory(true)? {
        tracing::info!("power_on_bias_memory {}: {note}", params.power_on_bias_memory);
    }
    let env = RosEnvironment::from_env(args.enclave.as_deref())?;
    let (corrector, status) = if args.naive_full_window {
        anyhow::ensure!(!params.model.is_empty(), "--naive-full-window needs a model");
        let loaded = imu_fsda::model::export::load_net(
            &imu_fsda::model::predict::metadata_path(std::path::Path::new(&params.model)),
            tch::Device::Cpu,
        )?;
        loaded.select_imu(Some(params.imu_calibration.as_str()).filter(|s| !s.is_empty()))?;
        let c: Box<dyn imu_fsda::infer::GyroCorrector> = Box::new(
            imu_fsda::infer::FullWindowCorrector::new(loaded.net.inference(), &loaded.metadata.name)
                .with_correction_gain(loaded.correction_gain()),
        );
        (c, "ok".to_string())
    } else {
        load_corrector(&params.model, &params.imu_calibration)?
    };
    // `~/adapt`: opt-in, refusing (with the reason) without a model.
    let (corrector, adapt) = if !params.adapt_enabled {
        // Said at start: a client calling a service that is not there waits without an answer.
        tracing::info!("the ~/adapt service is not offered: adapt_enabled is false (the parameter file turns it on)");
        (corrector, AdaptService::Off)
    } else if params.model.is_empty() || args.naive_full_window {
        // Offered all the same, so that a call gets this answer instead of no answer.
        let why = if params.model.is_empty() {
            "no model is loaded (parameter `model` or --model): there is nothing to adapt"
        } else {
            "the node runs with --naive-full-window, which cannot swap models"
        };
        tracing::warn!("~/adapt will refuse every call: {why}");
        (corrector, AdaptService::Unavailable(why.into()))
    } else {
        // The corrector can be swapped for an adapted one; catch-up history: 20 s at 200 Hz.
        let (swappable, handle) = SwappableCorrector::new(corrector, 4000);
        let c: Box<dyn imu_fsda::infer::GyroCorrector> = Box::new(swappable);
        let imu = Some(params.imu_calibration.clone()).filter(|s| !s.is_empty());
        (c, AdaptService::On(AdaptSetup { handle, model: PathBuf::from(&params.model), imu }))
    };
    let pipeline = Pipeline::new(corrector, params.pipeline.clone());
    let limits = RunLimits { max_messages: args.max_messages, idle_exit: args.idle_exit_s };
    // Inference beside an async runtime: one intra-op thread (toolchain.md: sporadic 10–20×
    // slowdowns with two OpenMP threads next to other work).
    tch::set_num_threads(1);
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().context("tokio runtime")?;
    let stats = rt.block_on(run_node_with_adaptation(&args.config.node_name, params, env, pipeline, status, limits, adapt))?;
    let c = &stats.counters;
    eprintln!(
        "imu-fsda node: received {}, published {}, dropped {} (non-finite {}, implausible {}, duplicate {}, backwards {}), gaps {}, clock jumps back {}, decode errors {}, latency p50 {:.0} µs p99 {:.0} µs",
        c.received,
        c.processed,
        c.dropped(),
        c.dropped_non_finite,
        c.dropped_implausible,
        c.dropped_duplicate_stamp,
        c.dropped_backwards_stamp,
        c.gaps,
        c.clock_jumps,
        stats.decode_errors,
        stats.latency.quantile_us(0.5),
        stats.latency.quantile_us(0.99)
    );
    if args.stats_json {
        out!(
            "{}",
            serde_json::json!({
                "counters": c, "latency_p50_us": stats.latency.quantile_us(0.5), "latency_p99_us": stats.latency.quantile_us(0.99),
                "latency_max_us": stats.latency.max_us(), "latency_samples": stats.latency.count(), "frame_changes": stats.frame_changes, "decode_errors": stats.decode_errors, "dropped_wrong_type": stats.dropped_wrong_type,
                "input_writers": stats.input_sequences.writers(), "input_published_before_first": stats.input_sequences.before_first,
                "input_lost": stats.input_sequences.lost, "input_out_of_order": stats.input_sequences.out_of_order,
                "model": stats.model, "adaptation": stats.adapt_status, "adapt_requested_by": stats.adapt_requested_by, "adapt_calls_refused": stats.adapt_calls_refused, "adaptations": stats.adaptations, "adapt_seconds": stats.adapt_seconds,
                "latency_by_adaptation_state": stats.split_latency.summary_json(),
                "latency_by_stage": stats.stage_latency.summary_json(),
                "correction": stats.correction, "power_on_bias": stats.power_on_bias, "power_on_bias_from": stats.power_on_bias_from, "power_on_bias_retakes": stats.power_on_bias_retakes, "power_on_bias_retake_calls": stats.power_on_bias_retake_calls, "power_on_bias_new_power_ons": stats.standstills.new_power_ons, "retake_requested_by": stats.retake_requested_by, "service_request_errors": stats.service_request_errors, "parameters_set": stats.parameters_set, "power_on_bias_memory": stats.power_on_bias_memory, "security": stats.security,
                "incompatible_peers": stats.incompatible_peers, "subscription_counts": stats.subscription_counts, "denoised_published_before_a_reader": stats.denoised_before_a_reader,
            })
        )?;
    }
    if stats.adaptation_abandoned {
        // The adaptation did not stop at its next step in time (it is cancelled and joined
        // otherwise): its thread is still inside libtorch, and the exit-time destructors of
        // libtorch's globals would run under it (SIGSEGV). Everything is said and written.
        use std::io::Write as _;
        let _ = std::io::stdout().flush();
        let _ = std::io::stderr().flush();
        // SAFETY: _exit ends the process at once; no Rust state is used after it.
        unsafe { libc::_exit(0) }
    }
    Ok(())
}
