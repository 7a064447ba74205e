//! `imu-fsda train --config params/train/X.yaml`: train, evaluate and export a model.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::train::{fit, seeds, TrainConfig};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    /// Training config (YAML with model, dataset and train sections; see params/train/).
    #[arg(long)]
    pub config: PathBuf,
    /// Seed (overrides train.seed; with train.seeds, trains this one seed as <name>).
    #[arg(long)]
    pub seed: Option<u64>,
    /// With train.seeds: runs trained at once (each one libtorch thread; default: the CPUs).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Continue from a checkpoint (`<out-dir>/<name>.ckpt.json`).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Where the model, checkpoint and run summary go.
    #[arg(long, default_value = "models")]
    pub out_dir: PathBuf,
    /// Model name: writes <out-dir>/<name>.{pt,ot,json}, <name>.train.json, <name>.ckpt.*
    /// (default: the config file's stem).
    #[arg(long)]
    pub name: Option<String>,
    /// Override train.epochs (e.g. to time a few epochs of a full config).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let cfg = TrainConfig::load(&args.config)?;
    let name = model_name(&args)?;
    if args.jobs == Some(0) {
        anyhow::bail!("--jobs 0: at least one run at a time");
    }
    // The overrides are checked here, before `train.seeds` starts a child per seed that would
    // each report the same error.
    fit::with_overrides(&cfg, None, args.epochs).with_context(|| args.config.display().to_string())?;
    // The output folder is made now, not at the first checkpoint minutes into the run.
    imu_fsda::core::create_dir_all(&args.out_dir).with_context(|| format!("--out-dir {}", args.out_dir.display()))?;
    // Two runs writing one <name> (two terminals, the default name) would each replace the
    // other's files; the second is refused while the first runs.
    let _lock = RunLock::acquire(&args.out_dir, &name)?;
    refuse_to_replace_an_adapted_model(&args, &name)?;
    if args.seed.is_none() && cfg.train.seeds.len() > 1 {
        if args.resume.is_some() {
            anyhow::bail!(
                "--resume continues one run: give its --seed too (each seed's run resumes from <name>-s<seed>.ckpt.json by itself)"
            );
        }
        return run_seeds(&args, &cfg, &name);
    }
    refuse_to_replace_a_chosen_model(&args, &cfg, &name)?;
    let seed = args.seed.or(cfg.train.seeds.first().copied());
    let opts = fit::RunOptions {
        seed,
        resume: args.resume.clone(),
        out_dir: args.out_dir.clone(),
        name,
        epochs: args.epochs,
        progress: !args.no_progress && std::io::stderr().is_terminal(),
        stop_requested: Some(super::interrupts::requested),
    };
    super::interrupts::catch();
    let s = imu_fsda::train::train(&cfg, &opts)?;
    print_summary(&s, &args.out_dir)
}

/// The model's name: `--name`, else the config's file stem. It becomes file names
/// (<name>.pt, <name>.runs/): an empty one wrote dotfiles.
fn model_name(args: &TrainArgs) -> anyhow::Result<String> {
    let name =
        args.name.clone().unwrap_or_else(|| args.config.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or("model".into()));
    if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
        let from = if args.name.is_some() { "--name" } else { "the config's file name (give --name)" };
        anyhow::bail!("model name {name:?} from {from}: a model name is a file stem, not empty, without a path separator or a leading dot");
    }
    Ok(name)
}

/// An adapted model of this name (`imu-fsda adapt -o`) is a robot's own: a training run
/// replaced it without a word and left its `.adapt.json` describing another model.
fn refuse_to_replace_an_adapted_model(args: &TrainArgs, name: &str) -> anyhow::Result<()> {
    let adapted = args.out_dir.join(format!("{name}.adapt.json"));
    if adapted.exists() && args.out_dir.join(format!("{name}.json")).exists() {
        anyhow::bail!(
            "{} is an adapted model ({}): training would replace it; give this run its own --name or --out-dir",
            args.out_dir.join(format!("{name}.pt")).display(),
            adapted.display()
        );
    }
    Ok(())
}

/// One seed's run must not replace an export chosen among seeds (it would leave
/// <name>.seeds.json describing a model that is no longer there), nor a run shortened or
/// lengthened on the command line the model its config trains (by default models/<name>, the
/// bundled one).
fn refuse_to_replace_a_chosen_model(args: &TrainArgs, cfg: &TrainConfig, name: &str) -> anyhow::Result<()> {
    let selection = args.out_dir.join(format!("{name}.seeds.json"));
    if args.seed.is_some() && args.resume.is_none() && selection.exists() {
        anyhow::bail!(
            "{} was chosen among seeds ({}): --seed would replace it with one run; give this run its own --name",
            args.out_dir.join(format!("{name}.pt")).display(),
            selection.display()
        );
    }
    let existing = args.out_dir.join(format!("{name}.json"));
    if let Some(e) = args.epochs.filter(|e| *e != cfg.train.epochs && args.resume.is_none() && existing.exists()) {
        anyhow::bail!(
            "--epochs {e} (the config trains {}) would replace {}: give a shortened or lengthened run its own --out-dir or --name",
            cfg.train.epochs,
            existing.display()
        );
    }
    Ok(())
}

/// What a finished run prints: its time and loss, the exported epoch, the evaluations at it,
/// and where the model and its summary are.
fn print_summary(s: &imu_fsda::train::report::TrainSummary, out_dir: &std::path::Path) -> anyhow::Result<()> {
    out!(
        "trained {} ({:?}, seed {}): {} epochs in {:.1} s ({:.3} s/epoch, {} threads); loss {:.4} → {:.4}",
        s.name,
        s.mode,
        s.seed,
        s.epochs,
        s.train_seconds,
        s.seconds_per_epoch,
        s.threads,
        s.loss_first,
        s.loss_last
    )?;
    if let Some(planned) = s.epochs_planned {
        out!("stopped by the wall-time budget (train.max_train_seconds) after epoch {} of {planned}", s.epochs)?;
    }
    if s.exported_epoch != s.epochs {
        out!("exported epoch {} (lowest validation score; train.select_best)", s.exported_epoch)?;
    }
    // The exported epoch's evaluation (the last one unless select_best chose another).
    let at_export = |v: &imu_fsda::train::report::SequenceEvals| {
        v.evals.iter().find(|e| e.0 == s.exported_epoch).or(v.evals.last()).map_or(f64::NAN, |e| e.1.aoe_deg)
    };
    for v in &s.validation {
        let gained = s.validation_with_gain.iter().find(|g| g.name == v.name).map_or(String::new(), |g| {
            format!("  with its IMU's correction gain {:8.3}°", g.evals.first().map_or(f64::NAN, |e| e.1.aoe_deg))
        });
        let gaps = v.raw.gap_note().map_or(String::new(), |n| format!("; {n}"));
        out!("validation {:<24} AOE raw {:8.3}°  model {:8.3}°{gained}{gaps}", v.name, v.raw.aoe_deg, at_export(v))?;
    }
    for (imu, g) in &s.correction_gains {
        out!("correction gain {imu}: {g:.3} (train.correction_gains: the test rows of recordings from that IMU apply it)")?;
    }
    for v in &s.monitor {
        let gaps = v.raw.gap_note().map_or(String::new(), |n| format!("; {n}"));
        out!("monitor    {:<24} AOE raw {:8.3}°  model {:8.3}°{gaps}", v.name, v.raw.aoe_deg, at_export(v))?;
    }
    for t in &s.test {
        out!(
            "test {:<30} AOE raw {:8.3}°  model {:8.3}°  (roll {:.3} pitch {:.3} yaw {:.3}, tilt {:.3} heading {:.3}){}",
            t.name,
            t.raw.aoe_deg,
            t.model.aoe_deg,
            t.model.roll_rmse_deg,
            t.model.pitch_rmse_deg,
            t.model.yaw_rmse_deg,
            t.model.tilt_rmse_deg,
            t.model.heading_rmse_deg,
            t.model.gap_note().map_or(String::new(), |n| format!("; {n}"))
        )?;
    }
    out!("model: {}", s.model_json)?;
    out!("summary: {}", fit::summary_path(out_dir, &s.name).display())?;
    let curves = out_dir.join(format!("{}.curves.png", s.name));
    if curves.exists() {
        out!("curves: {}", curves.display())?;
    }
    Ok(())
}

/// `train.seeds`: one child `imu-fsda train --seed S --name <name>-s<S>` per seed in
/// `<out>/<name>.runs/`, `jobs` at a time (each logs to `<name>-s<S>.log` there); a finished run is reused, an interrupted one
/// resumes from its checkpoint; then the lowest validation score is promoted to `<name>`.
fn run_seeds(args: &TrainArgs, cfg: &TrainConfig, name: &str) -> anyhow::Result<()> {
    let seeds = cfg.train.seeds.clone();
    let epochs = args.epochs.unwrap_or(cfg.train.epochs);
    let jobs = args.jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())).max(1);
    let runs = seeds::runs_dir(&args.out_dir, name);
    imu_fsda::core::create_dir_all(&runs).with_context(|| format!("creating {}", runs.display()))?;
    let exe = std::env::current_exe().context("locating the imu-fsda binary")?;
    let started = std::time::Instant::now();

    let bar = seeds_bar(!args.no_progress && std::io::stderr().is_terminal(), seeds.len(), name, jobs);

    // Every finished run is checked against the config before any child starts.
    let mut done = std::collections::BTreeSet::new();
    for &seed in &seeds {
        if seeds::finished(&runs, &seeds::run_name(name, seed), epochs, cfg)? {
            done.insert(seed);
        }
    }
    let mut pending: std::collections::VecDeque<u64> = seeds.iter().copied().collect();
    let mut running: Vec<(u64, std::process::Child, PathBuf)> = Vec::new();
    let mut failed: Vec<String> = Vec::new();
    // Ctrl-C reaches the parent only (each child has its own process group): it stops every
    // running child at its next epoch's checkpoint, starts no more, and waits for them.
    super::interrupts::catch();
    let mut forwarded = false;
    while !pending.is_empty() || !running.is_empty() {
        let interrupted = super::interrupts::requested();
        if interrupted && !forwarded {
            for (_, child, _) in &running {
                // SAFETY: kill() on our own child's pid; it has not been reaped (try_wait below).
                unsafe {
                    libc::kill(child.id() as libc::pid_t, libc::SIGTERM);
                }
            }
            forwarded = true;
        }
        while running.len() < jobs && failed.is_empty() && !interrupted {
            let Some(seed) = pending.pop_front() else { break };
            let run = seeds::run_name(name, seed);
            if done.contains(&seed) {
                out!("seed {seed}: {run} already trained ({epochs} epochs), reused")?;
                bar.inc(1);
                continue;
            }
            let (child, log) = spawn_seed_run(args, &exe, &runs, &run, seed)?;
            out!("seed {seed}: training {run} (log {})", log.display())?;
            running.push((seed, child, log));
        }
        bar.set_message(format!("running {:?}", running.iter().map(|r| r.0).collect::<Vec<_>>()));
        std::thread::sleep(std::time::Duration::from_millis(500));
        let mut still = Vec::new();
        for (seed, mut child, log) in running.drain(..) {
            match child.try_wait()? {
                None => still.push((seed, child, log)),
                Some(status) => {
                    bar.inc(1);
                    if status.success() {
                        tracing::info!("seed {seed} finished");
                    } else if forwarded && status.code() == Some(130) {
                        out!("seed {seed}: stopped at its checkpoint (log {})", log.display())?;
                    } else {
                        failed.push(format!("seed {seed} ({status}): {} (log {})", last_error(&log), log.display()));
                    }
                }
            }
        }
        running = still;
        if (!failed.is_empty() || forwarded) && running.is_empty() {
            break;
        }
    }
    bar.finish_and_clear();
    if forwarded {
        return Err(super::interrupts::Interrupted(format!(
            "the runs in {} stopped at their checkpoints (finished ones are kept); the same command resumes them",
            runs.display()
        ))
        .into());
    }
    if !failed.is_empty() {
        anyhow::bail!("training failed: {}; finished runs are kept, rerun to resume the rest", failed.join(", "));
    }

    print_selection(&args.out_dir, name, &seeds, started)
}

/// The progress bar over the seeds' runs (hidden off a terminal).
fn seeds_bar(visible: bool, seeds: usize, name: &str, jobs: usize) -> ProgressBar {
    let bar = if visible {
        ProgressBar::new(seeds as u64)
    } else {
        ProgressBar::with_draw_target(Some(seeds as u64), ProgressDrawTarget::hidden())
    };
    bar.set_style(
        ProgressStyle::with_template("{prefix} {elapsed_precise} [{bar:25}] {pos}/{len} seeds {msg}")
            .expect("template")
            .progress_chars("=> "),
    );
    bar.set_prefix(format!("{name}: {seeds} seeds, {jobs} at once"));
    bar
}

/// Starts one seed's run as a child `imu-fsda train` logging to `<run>.log` in `runs`,
/// resuming from its checkpoint where one is there.
fn spawn_seed_run(
    args: &TrainArgs,
    exe: &std::path::Path,
    runs: &std::path::Path,
    run: &str,
    seed: u64,
) -> anyhow::Result<(std::process::Child, PathBuf)> {
    let log = runs.join(format!("{run}.log"));
    let mut cmd = std::process::Command::new(exe);
    cmd.arg("-v").arg("train").arg("--config").arg(&args.config).arg("--seed").arg(seed.to_string());
    cmd.arg("--name").arg(run).arg("--out-dir").arg(runs).arg("--no-progress");
    if let Some(e) = args.epochs {
        cmd.arg("--epochs").arg(e.to_string());
    }
    // The `.ot` resumes by itself (its `.json` may be missing after a kill mid-save).
    let (ckpt_ot, ckpt_json) = imu_fsda::train::checkpoint::paths(runs, run);
    if ckpt_ot.exists() {
        cmd.arg("--resume").arg(&ckpt_json);
    }
    // A child outlives a parent stopped by SIGTERM (timeout, systemd, a scheduler): it
    // would go on writing its run while a restarted parent starts a second writer on it.
    // PR_SET_PDEATHSIG has the kernel stop it with its parent.
    // Its own process group keeps a terminal's Ctrl-C to the parent, which forwards it
    // once (a child's second signal would end it before its checkpoint).
    // SAFETY: prctl and setpgid are async-signal-safe and touch no memory of the parent.
    unsafe {
        std::os::unix::process::CommandExt::pre_exec(&mut cmd, || {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            libc::setpgid(0, 0);
            Ok(())
        });
    }
    let out = std::fs::File::create(&log).with_context(|| format!("creating {}", log.display()))?;
    cmd.stdout(out.try_clone()?).stderr(out);
    let child = cmd.spawn().with_context(|| format!("starting {}", exe.display()))?;
    Ok((child, log))
}

/// The seed chosen by its validation score, promoted to `<name>`, and every seed's scores.
fn print_selection(out_dir: &std::path::Path, name: &str, seeds: &[u64], started: std::time::Instant) -> anyhow::Result<()> {
    let (sel, json) = seeds::select_and_promote(out_dir, name, seeds)?;
    out!("{} seeds in {:.1} s; {}:", seeds.len(), started.elapsed().as_secs_f64(), sel.criterion)?;
    for c in &sel.candidates {
        out!(
            "  seed {:<4} validation score {:7.3}°  (test mean AOE {:7.3}°, not used){}",
            c.seed,
            c.validation_score_deg,
            c.test_mean_aoe_deg.unwrap_or(f64::NAN),
            if c.seed == sel.chosen_seed { "  <- exported" } else { "" }
        )?;
    }
    out!("model: {}", json.display())?;
    out!("selection: {}", out_dir.join(format!("{name}.seeds.json")).display())?;
    Ok(())
}

/// The child's error line (its last `Error:` line, else its last line), for the parent's message.
fn last_error(log: &std::path::Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines.iter().rev().find(|l| l.starts_with("Error")).or(lines.last()).map_or("no output".into(), |l| l.trim().to_string())
}

/// `<out>/<name>.lock`, holding the pid of the run writing `<name>`; removed when the run ends.
/// One left by a killed run (its pid gone) is taken over.
struct RunLock {
    path: std::path::PathBuf,
}

impl RunLock {
    fn acquire(out_dir: &std::path::Path, name: &str) -> anyhow::Result<Self> {
        let path = out_dir.join(format!("{name}.lock"));
        let me = std::process::id();
        // The pid is written first and the file linked into place (atomic, and refused if the
        // lock exists), so no run ever reads a lock without its pid and takes it for stale.
        let mine = out_dir.join(format!("{name}.lock.{me}"));
        std::fs::write(&mine, format!("{me}\n")).with_context(|| format!("writing {}", mine.display()))?;
        let linked = (0..2).find_map(|_| {
            match std::fs::hard_link(&mine, &path) {
                Ok(()) => Some(Ok(())),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => match Self::stale(&path, out_dir, name) {
                    Ok(()) => None,
                    Err(e) => Some(Err(e)),
                },
                Err(e) => {
                    // A file system without hard links: not worth refusing the run for.
                    tracing::warn!("no run lock at {} ({e}): a second run of this name would not be refused", path.display());
                    Some(Ok(()))
                }
            }
        });
        let _ = std::fs::remove_file(&mine);
        match linked {
            Some(Ok(())) => Ok(Self { path }),
            Some(Err(e)) => Err(e),
            None => anyhow::bail!("{}: could not be taken over", path.display()),
        }
    }

    /// An existing lock: an error while its run is alive, else removed (taken over).
    fn stale(path: &std::path::Path, out_dir: &std::path::Path, name: &str) -> anyhow::Result<()> {
        let holder = std::fs::read_to_string(path).ok().and_then(|s| s.trim().parse::<i32>().ok());
        // SAFETY: kill with signal 0 only asks whether the process exists.
        let alive = holder.is_some_and(|pid| {
            pid > 0 && (unsafe { libc::kill(pid, 0) } == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM))
        });
        // A pid the system gave to a later process (after a reboot or a long time) is not the
        // run that wrote the lock: that run started before it wrote the file.
        let reused = alive && holder.is_some_and(|pid| Self::started_after_lock(pid, path));
        if alive && !reused {
            anyhow::bail!(
                "another run (pid {}) is writing {} in {}: wait for it, or give this one its own --name or --out-dir \
                     (if no run is writing it, the pid is another program's: delete {})",
                holder.unwrap_or_default(),
                name,
                out_dir.display(),
                path.display()
            );
        }
        let who = match holder {
            Some(p) if reused => format!("pid {p}, since given to a process started after the lock was written"),
            Some(p) => format!("pid {p}"),
            None => "an unreadable pid".to_string(),
        };
        let ckpt = out_dir.join(format!("{name}.ckpt.json"));
        let resume = if ckpt.exists() { format!(" (its checkpoint: --resume {} continues it)", ckpt.display()) } else { String::new() };
        tracing::warn!("{}: left by a run that is gone ({who}); taken over{resume}", path.display());
        let _ = std::fs::remove_file(path);
        Ok(())
    }
}

impl RunLock {
    /// Whether process `pid` cannot be the run that wrote `lock` (Linux): the lock was written
    /// before this boot, or the process started over 10 minutes after the lock was written
    /// (its start time in `/proc/<pid>/stat`; the margin is for a shared file system whose clock
    /// runs behind: a live run's lock must never be taken). False where it cannot be told.
    fn started_after_lock(pid: i32, lock: &std::path::Path) -> bool {
        let boot = || -> Option<f64> {
            std::fs::read_to_string("/proc/stat").ok()?.lines().find_map(|l| l.strip_prefix("btime "))?.trim().parse().ok()
        };
        let started = |boot: f64| -> Option<f64> {
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
            // Field 22, counted after the parenthesised command name (which may hold spaces).
            let ticks: f64 = stat.rsplit_once(')')?.1.split_whitespace().nth(19)?.parse().ok()?;
            // SAFETY: sysconf only reads a system constant.
            let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
            (hz > 0).then(|| boot + ticks / hz as f64)
        };
        let written = std::fs::metadata(lock).and_then(|m| m.modified()).ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok());
        let (Some(boot), Some(written)) = (boot(), written.map(|w| w.as_secs_f64())) else { return false };
        written + 1.0 < boot || started(boot).is_some_and(|s| s > written + 600.0)
    }
}

impl Drop for RunLock {
    fn drop(&mut self) {
        let mine = std::fs::read_to_string(&self.path).ok().and_then(|s| s.trim().parse::<u32>().ok()) == Some(std::process::id());
        if mine {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}
