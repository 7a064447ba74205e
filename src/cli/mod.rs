//! Subcommands of `imu-fsda`, one file each.

/// `println!` that returns the write's error instead of panicking on it: a reader that
/// closes the pipe early (`imu-fsda bag info x.mcap | head -1`) ends the command quietly.
macro_rules! out {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout(), $($arg)*)
    }};
}

mod adapt;
mod attitude;
mod bag;
mod bench;
mod bias_memory;
mod corrector;
mod diagnose;
mod embed;
mod eval;
mod import;
mod inject;
mod node;
mod play;
mod progress;
mod replay;
mod simulate;
mod train;

use clap::{Parser, Subcommand};

/// Few-shot domain-adapted IMU gyroscope denoising for ROS 2.
#[derive(Debug, Parser)]
#[command(name = "imu-fsda", version, about)]
pub struct Cli {
    /// More log output (-v info, -vv debug); RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Inspect MCAP bags.
    #[command(subcommand)]
    Bag(bag::BagCommand),
    /// Import an EuRoC or TUM-VI sequence folder (ASL layout) into a ROS 2 MCAP bag.
    Import(import::ImportArgs),
    /// Evaluate gyro methods on bags: open-loop orientation error (AOE, roll/pitch/yaw RMSE).
    Eval(eval::EvalArgs),
    /// Record each bag's power-on bias (its standstills) in a bias memory file, as the node does.
    BiasMemory(bias_memory::BiasMemoryArgs),
    /// Score the attitude a node published (/imu/denoised) against ground truth, and its covariance.
    Attitude(attitude::AttitudeArgs),
    /// Simulate an IMU on a trajectory and write a bag with ground truth.
    Simulate(simulate::SimulateArgs),
    /// Apply known error terms to a recorded bag (a real recording with a known answer).
    Inject(inject::InjectArgs),
    /// Train a denoising model (FSDA-F, FSDA or DIGDL) and export it to TorchScript.
    Train(train::TrainArgs),
    /// Few-shot adaptation of a model to a new robot/IMU from a recording with ground truth.
    Adapt(adapt::AdaptArgs),
    /// t-SNE figure of a model's Embedding on samples of sequences (EuRoC / TUM-VI / bags).
    Embed(embed::EmbedArgs),
    /// Sim-vs-real diagnosis: locate the mismatch, name and fit the left-out physics.
    Diagnose(diagnose::DiagnoseArgs),
    /// Run the ROS 2 denoising node (subscribes raw IMU, publishes /imu/denoised).
    Node(node::NodeArgs),
    /// Run the node's pipeline over a bag and write its topics beside the input.
    Replay(replay::ReplayArgs),
    /// Publish a bag onto DDS at its recorded rate, like `ros2 bag play`.
    Play(play::PlayArgs),
    /// Measure the node's per-sample cost (the f32 path, its f64 reference, the naive forward) and memory.
    Bench(bench::BenchArgs),
}

// clap value parsers for numeric options: NaN, infinities and values outside an option's
// range are refused when the command line is read, naming the rule, never run with.

/// A finite number.
pub fn finite(s: &str) -> Result<f64, String> {
    let x: f64 = s.trim().parse().map_err(|_| format!("{s:?} is not a number"))?;
    if x.is_finite() {
        Ok(x)
    } else {
        Err(format!("{s} is not a finite number"))
    }
}

/// A finite number ≥ 0.
pub fn non_negative(s: &str) -> Result<f64, String> {
    finite(s).and_then(|x| if x >= 0.0 { Ok(x) } else { Err(format!("{s} is below 0")) })
}

/// A finite number > 0.
pub fn positive(s: &str) -> Result<f64, String> {
    finite(s).and_then(|x| if x > 0.0 { Ok(x) } else { Err(format!("{s} is not above 0")) })
}

/// Seconds, as a duration: finite, ≥ 0 and within what a `Duration` holds.
pub fn seconds(s: &str) -> Result<std::time::Duration, String> {
    non_negative(s).and_then(|x| std::time::Duration::try_from_secs_f64(x).map_err(|_| format!("{s} s is too long")))
}

/// A span of a recording, s: above 0 and within what a nanosecond stamp counts (292 years).
pub fn span_seconds(s: &str) -> Result<f64, String> {
    positive(s).and_then(|x| if x * 1e9 < i64::MAX as f64 { Ok(x) } else { Err(format!("{s} s is longer than any recording")) })
}

/// Ctrl-C / SIGTERM for commands that stop cleanly at the next message or epoch instead of
/// dying half-way: [`interrupts::catch`] arms it, [`interrupts::requested`] is polled. The
/// first signal only sets a flag; a second one, 0.3 s or more later, ends the process at once
/// (sooner, it is the same request delivered twice).
pub mod interrupts {
    use std::sync::atomic::{AtomicBool, Ordering};

    static REQUESTED: AtomicBool = AtomicBool::new(false);
    /// When the first signal came, monotonic ns.
    static FIRST_NS: std::sync::atomic::AtomicI64 = std::sync::atomic::AtomicI64::new(0);

    /// A second signal this soon after the first is the same request delivered twice:
    /// `timeout -s INT` signals the command and then its whole process group, which ended
    /// `play` at once, without its summary, in 3 of 24 runs.
    const SAME_REQUEST_NS: i64 = 300_000_000;

    fn monotonic_ns() -> i64 {
        let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: clock_gettime is async-signal-safe and writes only to `t`.
        unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut t) };
        t.tv_sec * 1_000_000_000 + t.tv_nsec
    }

    extern "C" fn on_signal(signal: libc::c_int) {
        let now = monotonic_ns();
        if REQUESTED.swap(true, Ordering::SeqCst) {
            if now - FIRST_NS.load(Ordering::SeqCst) < SAME_REQUEST_NS {
                return;
            }
            // A second request: end at once, by the signal's default action.
            // SAFETY: signal() and raise() are async-signal-safe.
            unsafe {
                libc::signal(signal, libc::SIG_DFL);
                libc::raise(signal);
            }
            return;
        }
        FIRST_NS.store(now, Ordering::SeqCst);
        // Said at once (a user who sees nothing presses again, which ends it there).
        const SAID: &[u8] = b"\nstopping cleanly at the next message or epoch (a second Ctrl-C stops at once)\n";
        // SAFETY: write() is async-signal-safe; the message is static.
        unsafe {
            libc::write(2, SAID.as_ptr().cast(), SAID.len());
        }
    }

    pub fn catch() {
        for signal in [libc::SIGINT, libc::SIGTERM] {
            // SAFETY: the handler only stores to an atomic and calls write() and signal().
            unsafe {
                libc::signal(signal, on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t);
            }
        }
    }

    pub fn requested() -> bool {
        REQUESTED.load(Ordering::Relaxed)
    }

    /// The error a command returns when it stopped at a signal: `main` exits with 130.
    #[derive(Debug, thiserror::Error)]
    #[error("interrupted: {0}")]
    pub struct Interrupted(pub String);

    /// Whether a command ended at a signal (exit 130), by its own word or a training run's.
    pub fn is_interruption(e: &anyhow::Error) -> bool {
        e.chain().any(|c| {
            c.is::<Interrupted>()
                || c.is::<imu_fsda::train::Stopped>()
                || c.downcast_ref::<imu_fsda::train::error::TrainError>()
                    .is_some_and(|t| matches!(t, imu_fsda::train::error::TrainError::Stopped(_)))
        })
    }
}

/// Whether the command ended because its standard output was closed (a pager or `head`
/// quit): the reader wanted no more, which is not a failure.
pub fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| c.downcast_ref::<std::io::Error>().is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe))
}

/// An error and its causes on one line, as `{e:#}` prints them, but without repeating a cause
/// whose text its parent already ends with (our errors name their source in their own message,
/// so the chain would say it twice: "x.mcap: No such file …: No such file …") and without the
/// C++ backtrace libtorch appends to its messages.
pub fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let cause = cause.to_string();
        let cause = imu_fsda::model::without_torch_backtrace(&cause);
        if text.is_empty() {
            text.push_str(cause);
        } else if !text.ends_with(cause) {
            text.push_str(": ");
            text.push_str(cause);
        }
    }
    text
}

/// What makes two paths the same file: its device and inode when it exists (another
/// spelling, a symbolic or a hard link all agree), else its canonical directory and name.
#[derive(PartialEq, Eq)]
enum FileIdentity {
    Inode(u64, u64),
    Path(std::path::PathBuf),
}

fn file_identity(path: &std::path::Path) -> Option<FileIdentity> {
    use std::os::unix::fs::MetadataExt as _;
    if let Ok(m) = std::fs::metadata(path) {
        return Some(FileIdentity::Inode(m.dev(), m.ino()));
    }
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => std::path::Path::new("."),
    };
    Some(FileIdentity::Path(std::fs::canonicalize(dir).ok()?.join(path.file_name()?)))
}

/// Refuses to write `output` over one of `inputs` (the same file by another spelling or a
/// link too): the command would truncate what it reads, and that recording or model would be
/// lost. An output that does not exist yet cannot be one.
pub fn refuse_overwriting_input(output: &std::path::Path, inputs: &[&std::path::Path]) -> anyhow::Result<()> {
    if !output.exists() {
        return Ok(());
    }
    let out = file_identity(output);
    if let Some(input) = inputs.iter().find(|i| i.exists() && file_identity(i) == out) {
        anyhow::bail!(
            "{} is also an input ({}): writing it would destroy what is being read; choose another output",
            output.display(),
            input.display()
        );
    }
    Ok(())
}

/// Refuses a ground-truth topic that is the IMU topic itself: its orientation (when it has
/// one) is the driver's own estimate, integrated from this very gyro, not a reference.
/// Among several bags, those that could not be scored are rows saying why; the command then
/// exits 1 naming them.
pub fn every_bag_scored(failed: &[String], bags: usize) -> anyhow::Result<()> {
    anyhow::ensure!(
        failed.is_empty(),
        "{} of {bags} bags could not be evaluated ({}); their rows say why",
        failed.len(),
        failed.join(", ")
    );
    Ok(())
}

/// The standstill rule of the node's parameter file (`--params`), else the node's defaults:
/// how `eval`'s and `bias-memory`'s power-on bias is found, as the node finds it.
fn standstill_of(params: Option<&std::path::Path>) -> anyhow::Result<imu_fsda::standstill::StandstillConfig> {
    use anyhow::Context;
    Ok(match params {
        Some(path) => {
            imu_fsda::node::NodeParams::from_yaml_file(path, "imu_fsda")
                .with_context(|| format!("--params {}", path.display()))?
                .pipeline
                .standstill
        }
        None => imu_fsda::standstill::StandstillConfig::default(),
    })
}

pub fn refuse_imu_as_ground_truth(imu_topic: &str, ground_truth_topic: &str) -> anyhow::Result<()> {
    if imu_topic == ground_truth_topic {
        anyhow::bail!(
            "--ground-truth-topic {ground_truth_topic} is the IMU topic: the ground truth must come from another source (motion capture, a reference IMU or an INS on its own topic)"
        );
    }
    Ok(())
}

/// Refuses two outputs of one command that are the same file: the second would silently
/// replace the first.
pub fn refuse_shared_outputs(outputs: &[(&str, &std::path::Path)]) -> anyhow::Result<()> {
    for (i, (a_name, a)) in outputs.iter().enumerate() {
        for (b_name, b) in &outputs[i + 1..] {
            if file_identity(a).is_some_and(|ia| file_identity(b).is_some_and(|ib| ia == ib)) {
                anyhow::bail!(
                    "{a_name} and {b_name} are the same file ({}): the second would replace the first; give each its own path",
                    b.display()
                );
            }
        }
    }
    Ok(())
}

pub fn init_tracing(verbose: u8) {
    // rustdds logs routine network chatter (and shutdown races) at warn/error: keep it quiet
    // unless asked for.
    let default = match verbose {
        0 => "warn,rustdds=off,ros2_client=off",
        1 => "info,rustdds=warn,ros2_client=warn",
        _ => "debug",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).init();
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Bag(c) => bag::run(c),
        Command::Import(a) => import::run(a),
        Command::Eval(a) => eval::run(a),
        Command::BiasMemory(a) => bias_memory::run(a),
        Command::Attitude(a) => attitude::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Inject(a) => inject::run(a),
        Command::Train(a) => train::run(a),
        Command::Adapt(a) => adapt::run(a),
        Command::Diagnose(a) => diagnose::run(a),
        Command::Embed(a) => embed::run(a),
        Command::Node(a) => node::run(a),
        Command::Replay(a) => replay::run(a),
        Command::Play(a) => play::run(a),
        Command::Bench(a) => bench::run(a),
    }
}

#[cfg(test)]
mod error_text_tests {
    use super::error_text;

    #[derive(Debug, thiserror::Error)]
    #[error("{path}: {source}")]
    struct Named {
        path: String,
        #[source]
        source: std::io::Error,
    }

    #[test]
    fn each_cause_is_said_once() {
        let io = || std::io::Error::new(std::io::ErrorKind::NotFound, "No such file");
        let named = anyhow::Error::new(Named { path: "x.mcap".into(), source: io() });
        assert_eq!(error_text(&named), "x.mcap: No such file");
        // Context that does not repeat its cause keeps the whole chain, as `{:#}` does.
        let ctx = anyhow::Error::new(io()).context("reading x.mcap");
        assert_eq!(error_text(&ctx), format!("{ctx:#}"));
        assert_eq!(error_text(&named.context("replaying")), "replaying: x.mcap: No such file");
        let torch = anyhow::Error::msg("PytorchStreamReader failed\nException raised from valid at x.cc:242:\nframe #0: 0x1")
            .context("loading m.pt");
        assert_eq!(error_text(&torch), "loading m.pt: PytorchStreamReader failed");
    }
}
