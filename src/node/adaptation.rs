//! The adaptation service (`~/adapt`, std_srvs/Trigger): the ground truth buffered beside
//! the IMU, the service loop, and the job that adapts on its own thread, below the real-time
//! path's priority, and swaps the model in between two samples.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::StreamExt;

use super::log_throttle::{self, LogThrottle, LOG_EVERY};
use super::support_archive::SupportArchive;
use super::{AdaptSetup, NodeParams, NodeStats, TriggerRequest, TriggerResponse};
use crate::adapt::swap::{warm_up, Buffers, SeqSample, SwapHandle};
use crate::infer::{GyroCorrector, ModelCorrector};

pub(super) enum GroundTruthSub {
    Pose(ros2_client::Subscription<crate::msg::PoseStamped>),
    Odometry(ros2_client::Subscription<crate::msg::Odometry>),
}

pub(super) async fn ground_truth_loop(src: &GroundTruthSub, buffers: &Arc<Mutex<Buffers>>) {
    let mut rejected = 0u64;
    let mut push = |p: Option<crate::core::PoseSample>| {
        let ok = p.is_some_and(|p| buffers.lock().expect("buffers lock").push_ground_truth(p));
        if !ok {
            rejected += 1;
            if rejected.is_power_of_two() {
                tracing::warn!("{rejected} ground-truth messages ignored (invalid or out of order)");
            }
        }
    };
    match src {
        GroundTruthSub::Pose(sub) => {
            let stream = sub.async_stream();
            futures::pin_mut!(stream);
            while let Some(m) = stream.next().await {
                if let Ok((m, _)) = m {
                    push(m.sample());
                }
            }
        }
        GroundTruthSub::Odometry(sub) => {
            let stream = sub.async_stream();
            futures::pin_mut!(stream);
            while let Some(m) = stream.next().await {
                if let Ok((m, _)) = m {
                    push(m.sample());
                }
            }
        }
    }
}

/// The result of one adaptation job (run on its own thread).
pub(super) struct JobResult {
    success: bool,
    message: String,
    report: Option<crate::adapt::AdaptReport>,
    model_name: Option<String>,
}

/// `~/adapt`: one adaptation at a time, on a blocking thread; a second request while one runs
/// is answered at once with success = false.
/// The adaptation running on its thread, shared with the end of the run: the request it will
/// answer (answered at shutdown if still open), and the thread with the flag that stops it.
#[derive(Default)]
pub(super) struct RunningJob {
    pub(super) request: Mutex<Option<ros2_client::RmwRequestId>>,
    thread: Mutex<Option<(crate::adapt::CancelFlag, std::thread::JoinHandle<()>)>>,
}

impl RunningJob {
    /// Stops the running adaptation at its next step and waits for its thread, at most
    /// `wait`: true when no thread is left inside libtorch (none ran, or it was joined).
    pub(super) fn cancel_and_join(&self, wait: Duration) -> bool {
        let Some((cancel, thread)) = self.thread.lock().ok().and_then(|mut t| t.take()) else { return true };
        cancel.cancel();
        let start = Instant::now();
        while !thread.is_finished() && start.elapsed() < wait {
            std::thread::sleep(Duration::from_millis(10));
        }
        thread.is_finished() && thread.join().is_ok()
    }
}

pub(super) async fn service_loop(
    server: &ros2_client::service::Server<TriggerRequest, TriggerResponse>,
    buffers: &Arc<Mutex<Buffers>>,
    setup: &AdaptSetup,
    params: &NodeParams,
    stats: Arc<Mutex<NodeStats>>,
    adapting: Arc<AtomicBool>,
    job: &RunningJob,
) {
    let mut running: Option<(ros2_client::RmwRequestId, tokio::sync::oneshot::Receiver<JobResult>, Instant)> = None;
    // Started with the node: its start names this power-on's supports.
    let archive = SupportArchive::new(&params.adapt_support_archive, params.adapt_judge_power_ons).map(Arc::new);
    let (mut refused_log, mut bad_log) = (LogThrottle::new(LOG_EVERY), LogThrottle::new(LOG_EVERY));
    loop {
        let finished = async {
            match running.as_mut() {
                Some((_, rx, _)) => rx.await.ok(),
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            req = server.async_receive_request() => {
                let id = match req {
                    Ok((id, _)) => id,
                    Err(e) => {
                        super::endpoints::bad_request("~/adapt", &e, &mut bad_log, &stats);
                        continue;
                    }
                };
                let caller = caller_of(&id);
                stats.lock().expect("stats lock").adapt_requested_by.clone_from(&caller);
                if let Some((_, _, started)) = &running {
                    // Refused, the model untouched: a flood of these is one line a second.
                    stats.lock().expect("stats lock").adapt_calls_refused += 1;
                    if let Some(n) = refused_log.admit(Instant::now()) {
                        tracing::warn!("~/adapt called by {caller} while an adaptation runs: refused{}", log_throttle::unsaid(n));
                    }
                    let msg = format!("an adaptation is already running (started {:.1} s ago); the current model keeps running — call again when it ends", started.elapsed().as_secs_f64());
                    respond(server, id, false, msg).await;
                    continue;
                }
                // At the default level: a call that starts an adaptation may change the model
                // the node runs.
                tracing::warn!("~/adapt called by {caller}");
                let (tx, rx) = tokio::sync::oneshot::channel();
                let cancel = crate::adapt::CancelFlag::default();
                let known_power_on_bias = stats.lock().ok().and_then(|s| s.standstill_bias);
                let work = Job::of_buffers(setup, params, buffers, known_power_on_bias, archive.clone(), caller, cancel.clone());
                adapting.store(true, Ordering::Relaxed);
                let flag = adapting.clone();
                let nice = params.adapt_thread_nice.clamp(0, 19);
                let spawned = std::thread::Builder::new().name("imu-fsda-adapt".into()).spawn(move || {
                    // Below the real-time path: the scheduler serves the node's threads first.
                    lower_thread_priority(nice);
                    let res = work.run();
                    flag.store(false, Ordering::Relaxed);
                    let _ = tx.send(res);
                });
                match spawned {
                    Ok(thread) => *job.thread.lock().expect("job lock") = Some((cancel, thread)),
                    Err(e) => {
                        adapting.store(false, Ordering::Relaxed);
                        respond(server, id, false, format!("cannot start the adaptation thread: {e}")).await;
                        continue;
                    }
                }
                stats.lock().expect("stats lock").adapt_status = "running".into();
                tracing::info!("adaptation started");
                *job.request.lock().expect("request lock") = Some(id);
                running = Some((id, rx, Instant::now()));
            }
            res = finished => {
                let Some((id, _, started)) = running.take() else { continue };
                *job.request.lock().expect("request lock") = None;
                // The job has answered: its thread is ending, joined here.
                if let Some((_, thread)) = job.thread.lock().expect("job lock").take() {
                    let _ = thread.join();
                }
                // Normally cleared by the job's thread; also when that thread died.
                adapting.store(false, Ordering::Relaxed);
                let res = res.unwrap_or(JobResult { success: false, message: "the adaptation thread died".into(), report: None, model_name: None });
                record_result(&stats, &res, started);
                tracing::info!("adaptation finished: {}", res.message);
                respond(server, id, res.success, res.message).await;
            }
        }
    }
}

/// What an adaptation's end leaves on /diagnostics: its count, time, the query's AOE before
/// and with the candidate kept, the model now running, and the verdict.
fn record_result(stats: &Mutex<NodeStats>, res: &JobResult, started: Instant) {
    let mut s = stats.lock().expect("stats lock");
    s.adaptations += 1;
    s.adapt_seconds = Some(started.elapsed().as_secs_f64());
    if let Some(r) = &res.report {
        s.adapt_query_aoe_before_deg = Some(r.query_before.aoe_deg);
        // The candidate kept (the adapted networks where none was).
        s.adapt_query_aoe_after_deg = Some(r.kept_query().unwrap_or(&r.query_after).aoe_deg);
    }
    if let Some(n) = &res.model_name {
        s.model.clone_from(n);
    }
    s.adapt_status = format!("{}: {}", if res.success { "accepted" } else { "not applied" }, res.message);
}

impl Job {
    /// A job on what the buffers hold now (copied: the node goes on filling them).
    fn of_buffers(
        setup: &AdaptSetup,
        params: &NodeParams,
        buffers: &Arc<Mutex<Buffers>>,
        known_power_on_bias: Option<crate::standstill::BiasEstimate>,
        archive: Option<Arc<SupportArchive>>,
        requested_by: String,
        cancel: crate::adapt::CancelFlag,
    ) -> Job {
        let (imu, gt): (Vec<SeqSample>, Vec<crate::core::PoseSample>) = {
            let b = buffers.lock().expect("buffers lock");
            (b.imu.iter().copied().collect(), b.ground_truth.iter().copied().collect())
        };
        Job {
            model: setup.model.clone(),
            imu_calibration: setup.imu.clone(),
            handle: setup.handle.clone(),
            buffers: buffers.clone(),
            imu,
            gt,
            support_seconds: params.adapt_support_seconds,
            ground_truth: format!("{} as {}", params.ground_truth_topic, params.ground_truth_type),
            out_dir: params.adapted_model_dir.clone(),
            cfg: crate::adapt::AdaptConfig { cancel, ..params.adapt.clone() },
            known_power_on_bias,
            archive,
            requested_by,
        }
    }
}

/// `~/adapt` with nothing to adapt: every call is answered at once with the reason.
pub(super) async fn refusing_service_loop(
    server: &ros2_client::service::Server<TriggerRequest, TriggerResponse>,
    why: &str,
    stats: &Mutex<NodeStats>,
) {
    let (mut refused_log, mut bad_log) = (LogThrottle::new(LOG_EVERY), LogThrottle::new(LOG_EVERY));
    loop {
        match server.async_receive_request().await {
            Ok((id, _)) => {
                let caller = caller_of(&id);
                if let Some(n) = refused_log.admit(Instant::now()) {
                    tracing::warn!("~/adapt called by {caller} (refused: {why}){}", log_throttle::unsaid(n));
                }
                {
                    let mut s = stats.lock().expect("stats lock");
                    s.adapt_requested_by = caller;
                    s.adapt_calls_refused += 1;
                }
                respond(server, id, false, format!("cannot adapt: {why}")).await
            }
            Err(e) => super::endpoints::bad_request("~/adapt", &e, &mut bad_log, stats),
        }
    }
}

/// Who called: the request writer's DDS GUID (its participant's prefix, then the entity) and
/// the request's sequence number. Logged with every call and kept in the adapted model's
/// metadata (`requested_by`): the model a node runs can be traced to whoever asked for it.
pub(super) fn caller_of(id: &ros2_client::RmwRequestId) -> String {
    format!("client {:?} request {}", id.writer_gid, id.sequence_number)
}

/// Lowers the calling thread's scheduling priority to `nice` (Linux: `setpriority` on the
/// thread id changes that thread only). Failure only costs latency: logged, not fatal.
fn lower_thread_priority(nice: i32) {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain syscalls on the calling thread's own id; no memory is passed.
        let rc = unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, nice)
        };
        if rc != 0 {
            tracing::warn!("adaptation thread: setpriority(nice {nice}) failed: {}", std::io::Error::last_os_error());
        } else {
            tracing::debug!("adaptation thread at nice {nice}");
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = nice;
}

pub(super) async fn respond(
    server: &ros2_client::service::Server<TriggerRequest, TriggerResponse>,
    id: ros2_client::RmwRequestId,
    success: bool,
    message: String,
) {
    super::endpoints::reply_spaced(server, id, TriggerResponse { success, message }, "~/adapt").await;
}

/// Why an adaptation job ended without a model (the reply says it, then "the current model
/// keeps running").
#[derive(Debug, thiserror::Error)]
enum JobError {
    #[error("loading {path}: {source}")]
    Load {
        path: String,
        #[source]
        source: crate::model::ModelError,
    },
    #[error(transparent)]
    Model(#[from] crate::model::ModelError),
    #[error(transparent)]
    Adapt(#[from] crate::adapt::AdaptError),
    /// The buffers cannot support an adaptation (nothing yet, too short).
    #[error("{0}")]
    NotEnoughData(String),
}

/// An error and its causes, each once ("loading m.json: m.ot: file not found").
fn with_causes(e: &dyn std::error::Error) -> String {
    let mut said = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let text = c.to_string();
        if !said.contains(&text) {
            said = format!("{said}: {text}");
        }
        cause = c.source();
    }
    said
}

struct Job {
    model: PathBuf,
    imu_calibration: Option<String>,
    handle: SwapHandle,
    buffers: Arc<Mutex<Buffers>>,
    imu: Vec<SeqSample>,
    gt: Vec<crate::core::PoseSample>,
    support_seconds: f64,
    /// "<topic> as <type>", for the reply when none arrived.
    ground_truth: String,
    out_dir: String,
    cfg: crate::adapt::AdaptConfig,
    /// The node's power-on bias from a standstill at the request, if any.
    known_power_on_bias: Option<crate::standstill::BiasEstimate>,
    /// Where supports are kept and earlier power-ons' read from.
    archive: Option<Arc<SupportArchive>>,
    /// [`caller_of`] the request.
    requested_by: String,
}

impl Job {
    /// Keeps the candidate that carries over to the earlier power-ons in the archive
    /// ([`crate::adapt::keep_judged`]), or, with none there, what lasts within this one
    /// (docs/adaptation.md, step 7). Returns what it was judged on, for the reply.
    fn judge(
        &self,
        start: &crate::model::export::LoadedNet,
        mut outcome: crate::adapt::AdaptOutcome,
    ) -> Result<(crate::adapt::AdaptOutcome, String), JobError> {
        let earlier = match &self.archive {
            Some(a) if outcome.adapted.is_some() => a.read_earlier(),
            _ => super::support_archive::EarlierPowerOns { recordings: Vec::new(), skipped: Vec::new() },
        };
        for why in &earlier.skipped {
            tracing::warn!("adapt_support_archive: not judged on {why}");
        }
        let skipped = match earlier.skipped.len() {
            0 => String::new(),
            n => format!(" ({n} bag{} there could not serve: {})", if n == 1 { "" } else { "s" }, earlier.skipped.join("; ")),
        };
        if earlier.recordings.is_empty() {
            let said = match &self.archive {
                Some(a) => format!("no earlier power-on in {} to judge on: what lasts within this one is kept{skipped}", a.dir().display()),
                None => "judged on this power-on alone (no adapt_support_archive)".into(),
            };
            return Ok((crate::adapt::keep_without_judge(outcome, &self.cfg), said));
        }
        crate::adapt::keep_judged(start, &mut outcome, &earlier.recordings, &self.cfg, |_| {})?;
        let n = earlier.recordings.len();
        let ratio = outcome.report.carry_over.map_or(String::new(), |c| {
            format!(": AOE adapted / without {:.3} (95 % bound over {} pieces {})", c.ratio, c.pieces, c.piece_bound_said())
        });
        let said = format!("judged on {n} earlier power-on{}{ratio}{skipped}", if n == 1 { "" } else { "s" });
        Ok((outcome, said))
    }

    fn run(self) -> JobResult {
        match self.run_inner() {
            Ok(r) => r,
            Err(e) => JobResult {
                success: false,
                message: format!("{}; the current model keeps running", with_causes(&e)),
                report: None,
                model_name: None,
            },
        }
    }

    fn run_inner(&self) -> Result<JobResult, JobError> {
        // Off the real-time path, one intra-op thread (the node's setting).
        tch::set_num_threads(1);
        let t0 = Instant::now();
        let meta = crate::model::predict::metadata_path(&self.model);
        let loaded = crate::model::export::load_net(&meta, tch::Device::Cpu)
            .map_err(|source| JobError::Load { path: meta.display().to_string(), source })?;
        loaded.select_imu(self.imu_calibration.as_deref())?;
        if self.imu.is_empty() {
            return Err(JobError::NotEnoughData("no input buffered yet".into()));
        }
        // A publisher of another type on the topic is not matched by DDS, and nothing else says so.
        if self.gt.is_empty() {
            return Err(JobError::NotEnoughData(format!(
                "no ground truth received yet on {} (a publisher of another type there is not matched: set ground_truth_type)",
                self.ground_truth
            )));
        }
        let rec = crate::core::Recording {
            name: "node buffer".into(),
            imu: self.imu.iter().map(|s| s.sample).collect(),
            ground_truth: self.gt.clone(),
            temperature: Vec::new(),
        };
        let (support, query) = crate::adapt::split_recording(&rec, self.support_seconds, None, &self.cfg);
        if query.imu.is_empty() {
            return Err(JobError::NotEnoughData(format!(
                "only {:.1} s buffered: nothing after the {} s support set to judge the adaptation on",
                rec.imu_seconds(),
                self.support_seconds
            )));
        }
        // Kept before adapting: a later power-on judges on it whatever this one decides.
        let kept_as = self.archive.as_ref().map(|a| match a.save(&rec) {
            Ok(path) => format!("support kept as {}", path.display()),
            Err(e) => {
                tracing::warn!("adapt_support_archive: {e}");
                format!("support not kept: {e}")
            }
        });
        let outcome = crate::adapt::adapt_knowing(&loaded, &support, &query, &self.cfg, self.known_power_on_bias.as_ref())?;
        let (outcome, judged_on) = self.judge(&loaded, outcome)?;
        // Stopped while the candidates were scored: nothing is saved or swapped in.
        if self.cfg.cancel.is_cancelled() {
            return Err(crate::adapt::AdaptError::Cancelled.into());
        }
        let mut r = outcome.report;
        r.requested_by = Some(self.requested_by.clone());
        let figures = figures_of(&r);
        let figures = [Some(figures), Some(judged_on), kept_as].into_iter().flatten().collect::<Vec<_>>().join("; ");
        let Some(adapted) = outcome.adapted else {
            return Ok(JobResult { success: false, message: format!("{}; {figures}", r.verdict), report: Some(r), model_name: None });
        };
        let dir =
            if self.out_dir.is_empty() { meta.parent().unwrap_or(Path::new(".")).to_path_buf() } else { PathBuf::from(&self.out_dir) };
        let unix = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
        let name = format!("{}-adapted-{unix}", loaded.metadata.name);
        let paths = crate::adapt::save_adapted(&adapted, &r, &dir, &name)?;
        let swapped = self.hand_over(&paths.torchscript)?;
        Ok(JobResult {
            success: true,
            message: format!(
                "adapted: {figures}; saved {}; {swapped}; total {:.1} s",
                paths.torchscript.display(),
                t0.elapsed().as_secs_f64()
            ),
            report: Some(r),
            model_name: Some(name),
        })
    }
}

impl Job {
    /// The adapted model handed to the pipeline: warmed on the recent history and swapped in
    /// between two samples; says where it was swapped in (or that it will be).
    fn hand_over(&self, torchscript: &Path) -> Result<String, JobError> {
        // Its own (adapted) Ĉ_ω.
        let mut corrector = ModelCorrector::load(torchscript, None)?;
        // Warm the new streaming model on the recent history, then hand it over: the
        // pipeline catches up on what arrived meanwhile and swaps between two samples. While
        // the model is fed periods, the buffer's samples are not its inputs: offered cold, it
        // is warmed at the swap on the corrector's own.
        let (history, periods): (Vec<SeqSample>, bool) = {
            let b = self.buffers.lock().expect("buffers lock");
            let n = corrector.window() + 1;
            (b.imu.iter().skip(b.imu.len().saturating_sub(n)).copied().collect(), b.model_fed_periods)
        };
        let (swaps_before, _) = self.handle.swaps();
        if periods {
            self.handle.offer_cold(Box::new(corrector));
        } else {
            let fed = warm_up(&mut corrector, &history);
            self.handle.offer(Box::new(corrector), fed);
        }
        let wait = Instant::now();
        while self.handle.swaps().0 == swaps_before && wait.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(2));
        }
        let swapped = match self.handle.swaps() {
            (n, Some((seq, fed))) if n > swaps_before && periods => {
                format!("swapped in at model period {seq} (warmed on the last {fed} periods the model was fed)")
            }
            (n, Some((seq, caught_up))) if n > swaps_before => format!("swapped in at sample {seq} (caught up {caught_up} samples)"),
            _ => "will be swapped in at the next sample".to_string(),
        };
        Ok(swapped)
    }
}

/// The adaptation's figures for the reply: the query's AOE before and with the candidate
/// kept, raw, the sets' lengths, the steps; the kind kept first.
fn figures_of(r: &crate::adapt::AdaptReport) -> String {
    let figures = format!(
        "query AOE {:.3}° → {:.3}° (raw gyro {:.3}°), support {:.1} s, query {:.1} s, {} steps in {:.1} s",
        r.query_before.aoe_deg,
        r.kept_query().unwrap_or(&r.query_after).aoe_deg,
        r.query_raw.aoe_deg,
        r.support_seconds,
        r.query_seconds,
        r.steps,
        r.step_seconds
    );
    let rotation = match (r.kind, r.rotation_left_out_said()) {
        (Some(crate::adapt::AdaptedKind::Calibration), Some(said)) => format!(" ({said})"),
        _ => String::new(),
    };
    match r.kind {
        Some(k) => format!("{}{rotation}: {figures}", k.name()),
        None => figures,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reply names the cause under the error, once, as the log would.
    #[test]
    fn a_failed_job_says_its_causes_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "m.ot: no such file");
        let e = JobError::Load { path: "m.json".into(), source: crate::model::ModelError::Io { path: "m.ot".into(), source: io } };
        let said = with_causes(&e);
        assert!(said.starts_with("loading m.json: "), "{said}");
        assert_eq!(said.matches("no such file").count(), 1, "{said}");
    }
}
