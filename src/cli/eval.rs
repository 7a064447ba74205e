//! `imu-fsda eval BAG... --method M...`: the orientation-error table for bags × methods.

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::bag::{read_recording, RecordingTopics};
use imu_fsda::core::{ImuSample, Recording};
use imu_fsda::eval::{
    evaluate, evaluate_with_path, mean_rate_error, BaselineMethod, EvalOptions, OrientationErrors, OrientationPath, RestDetector,
};
use imu_fsda::infer::{choose, predict_from, trained_power_ons, ModelDomain};
use imu_fsda::model::export::load_metadata;
use imu_fsda::model::predict::{correct_with_torchscript_at_model_rate, metadata_path};
use imu_fsda::standstill::{BiasTrack, StandstillConfig};
use nalgebra::Vector3;

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Bags with an IMU topic and a ground-truth topic.
    #[arg(required = true)]
    pub bags: Vec<PathBuf>,
    /// Methods to evaluate (repeat the flag); default: raw and static-bias when no --model is
    /// given either (with --model, only the methods named here are added to the models).
    #[arg(short, long = "method", value_enum)]
    pub methods: Vec<BaselineMethod>,
    /// Exported models to evaluate too (`.pt`/`.json`; repeatable): the TorchScript file is
    /// run over the whole sequence, as deployed.
    #[arg(long = "model")]
    pub models: Vec<PathBuf>,
    /// Which IMU recorded the bags, for models with a Ĉ_ω or correction gain per IMU: `NAME`
    /// for every bag, or `PATTERN=NAME` for the bags whose file name matches PATTERN (`*` any
    /// characters, `?` one); repeatable, the first match wins (`--imu 'room*=tumvi' --imu
    /// euroc`). Without a match a model runs as on a new IMU (the guard: the power-on bias in
    /// its place, its figures beside it); a model with one Ĉ_ω for every IMU is run as the
    /// IMU named where it was trained on it, else as on a new IMU.
    #[arg(long = "imu", value_name = "[PATTERN=]NAME")]
    pub imus: Vec<String>,
    /// IMU topic (sensor_msgs/Imu).
    #[arg(long, default_value = imu_fsda::bag::IMU_TOPIC)]
    pub imu_topic: String,
    /// Ground-truth topic (PoseStamped, Odometry, or an Imu carrying orientation).
    #[arg(long, default_value = imu_fsda::bag::GROUND_TRUTH_TOPIC)]
    pub ground_truth_topic: String,
    /// Longest ground-truth gap interpolated over, ms; samples in longer gaps are not scored.
    #[arg(long, default_value_t = 50.0, value_parser = super::positive)]
    pub max_gap_ms: f64,
    /// Score only from this many seconds after the first IMU sample covered by ground truth
    /// (the trainer's and `adapt`'s clock: `--start-s 60` is the query set after a 60 s
    /// support set). Integration starts there, from the ground-truth attitude. Methods and
    /// models run over the whole recording, as the node would have (the initial rest and a
    /// model's window lie before the span), and are scored on the span.
    #[arg(long, value_parser = super::finite)]
    pub start_s: Option<f64>,
    /// Score only up to this many seconds after the first IMU sample covered by ground truth.
    #[arg(long, value_parser = super::finite)]
    pub end_s: Option<f64>,
    /// Also score every method and model with its own constant error removed (`M − oracle
    /// bias`): the mean of its rate error against the ground truth's rate over the scored
    /// span (pairs of samples inside a ground-truth gap left out). It reads the ground truth,
    /// so it is an oracle reference — what a constant calibration fitted to that very
    /// recording gives — not a method; least squares on the rate, not the AOE-optimal constant.
    #[arg(long)]
    pub oracle_bias: bool,
    /// Score a model on an IMU it was neither trained nor adapted on as the node would run it
    /// with `model_on_new_imu: true`; without it such a model's row is followed by `<model> as
    /// deployed`: the power-on bias the node runs there instead.
    #[arg(long)]
    pub model_on_new_imu: bool,
    /// The node's parameter file: its `pipeline.standstill` is how `power-on-bias` and the
    /// `as deployed` rows find this power-on's bias (default: the node's defaults).
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Earlier power-ons' biases of this IMU (`imu-fsda bias-memory`, the node's
    /// `power_on_bias_memory`): before a bag's first standstill the power-on bias starts from
    /// what they predict, the bag's own entry left out.
    #[arg(long, value_name = "FILE")]
    pub bias_memory: Option<PathBuf>,
    /// Also write the table as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Also write the table as Markdown here.
    #[arg(long)]
    pub markdown: Option<PathBuf>,
    /// Write figures here (created if needed), per bag: `<bag>_orientation.png` (roll, pitch,
    /// yaw over time: ground truth and each method) and `<bag>_error.png` (error per axis).
    #[arg(long)]
    pub plot_dir: Option<PathBuf>,
}

/// One bag being scored: its recording, its name in the rows and the notes every row gets.
struct BagScoring<'a> {
    rec: &'a Recording,
    name: &'a str,
    notes: &'a [String],
}

/// A method's corrected gyro and note, or why it has none.
type Stream = Result<(Vec<Vector3<f64>>, String), String>;

/// One row of the table.
#[derive(Debug, serde::Serialize)]
pub struct Row {
    pub bag: String,
    pub method: String,
    #[serde(flatten)]
    pub errors: Option<OrientationErrors>,
    pub note: String,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let evaluation = Evaluation::new(&args)?;
    let mut rows = Vec::new();
    let mut failed: Vec<String> = Vec::new();
    let bar = super::progress::bar(args.bags.len(), "eval");
    for (bag, name) in args.bags.iter().zip(bag_names(&args.bags)) {
        bar.set_message(name.clone());
        let rows_before = rows.len();
        // One bag that cannot be read or scored is a row saying why when there are others:
        // their rows are kept (before, the first such bag ended the command with nothing).
        if let Err(e) = evaluation.bag(bag, &name, &mut rows) {
            if args.bags.len() == 1 {
                return Err(e);
            }
            let why = super::error_text(&e);
            tracing::error!("{why}");
            rows.truncate(rows_before);
            rows.push(Row { bag: name.clone(), method: "–".into(), errors: None, note: format!("not evaluated: {why}") });
            failed.push(bag.display().to_string());
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let table = markdown_table(&rows);
    out!("{}", table.trim_end_matches('\n'))?;
    if let Some(p) = &args.json {
        std::fs::write(p, serde_json::to_string_pretty(&serde_json::json!({"options": evaluation.opts, "rows": rows}))?)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    if let Some(p) = &args.markdown {
        std::fs::write(p, &table).with_context(|| format!("writing {}", p.display()))?;
    }
    super::every_bag_scored(&failed, args.bags.len())
}

/// What `eval` runs on every bag, checked and loaded once before the first: the methods, the
/// models' metadata, the standstill rule and the bias memory.
struct Evaluation<'a> {
    args: &'a EvalArgs,
    methods: Vec<BaselineMethod>,
    opts: EvalOptions,
    topics: RecordingTopics,
    detector: RestDetector,
    standstill: StandstillConfig,
    memory: Option<imu_fsda::bias_memory::BiasMemory>,
    metas: Vec<imu_fsda::model::export::ModelMetadata>,
    /// Which models know IMUs by name (one Ĉ_ω or a correction gain per IMU; the others ignore --imu).
    per_imu: Vec<bool>,
    labels: Vec<String>,
}

/// A bag read for scoring: the span scored (`rec`), the whole recording the methods run over
/// when a span was asked for, and what reading it found.
struct ScoredRecording {
    whole: Option<Recording>,
    rec: Recording,
    report: imu_fsda::bag::LoadReport,
    implausible: usize,
    clipped: Option<String>,
}

impl<'a> Evaluation<'a> {
    fn new(args: &'a EvalArgs) -> anyhow::Result<Self> {
        let methods = if args.methods.is_empty() && args.models.is_empty() {
            vec![BaselineMethod::Raw, BaselineMethod::StaticBias]
        } else {
            args.methods.clone()
        };
        let model_files: Vec<PathBuf> = args.models.iter().flat_map(|m| [m.clone(), metadata_path(m), m.with_extension("ot")]).collect();
        let inputs: Vec<&std::path::Path> = args.bags.iter().chain(&model_files).map(PathBuf::as_path).collect();
        for out in args.json.iter().chain(&args.markdown) {
            super::refuse_overwriting_input(out, &inputs)?;
        }
        let outputs: Vec<(&str, &std::path::Path)> =
            [("--json", &args.json), ("--markdown", &args.markdown)].into_iter().filter_map(|(n, p)| Some((n, p.as_deref()?))).collect();
        super::refuse_shared_outputs(&outputs)?;
        super::refuse_imu_as_ground_truth(&args.imu_topic, &args.ground_truth_topic)?;
        let standstill = super::standstill_of(args.params.as_deref())?;
        let memory = match &args.bias_memory {
            Some(p) => Some(imu_fsda::bias_memory::BiasMemory::load(p)?),
            None => None,
        };
        let metas = Self::checked_models(args)?;
        Ok(Evaluation {
            args,
            methods,
            opts: EvalOptions { max_gap_ns: (args.max_gap_ms * 1e6) as i64 },
            topics: RecordingTopics { imu: args.imu_topic.clone(), ground_truth: Some(args.ground_truth_topic.clone()), temperature: None },
            detector: RestDetector::default(),
            standstill,
            memory,
            per_imu: metas.iter().map(|m| !m.imu_names().is_empty()).collect(),
            labels: model_labels(&args.models, &metas),
            metas,
        })
    }

    /// The models' metadata, read once, before any bag; the start-up check for each IMU the
    /// bags will be run as, too (a per-IMU Ĉ_ω edited in the `.json` is a mismatch only with
    /// that IMU selected).
    fn checked_models(args: &EvalArgs) -> anyhow::Result<Vec<imu_fsda::model::export::ModelMetadata>> {
        let metas: Vec<imu_fsda::model::export::ModelMetadata> = args
            .models
            .iter()
            .map(|m| load_metadata(&metadata_path(m)).with_context(|| format!("model {}", m.display())))
            .collect::<anyhow::Result<_>>()?;
        let imu_names: std::collections::BTreeSet<&str> =
            args.imus.iter().map(|rule| rule.split_once('=').map_or(rule.as_str(), |(_, name)| name)).filter(|n| !n.is_empty()).collect();
        for (m, meta) in args.models.iter().zip(&metas) {
            super::corrector::check_model_files(m, None)?;
            for name in imu_names.iter().filter(|n| meta.knows_imu(n)) {
                super::corrector::check_model_files(m, Some(name)).with_context(|| format!("run as IMU {name}"))?;
            }
        }
        Ok(metas)
    }

    /// One bag's rows: every method's and model's gyro stream (or why it has none), each
    /// scored on the span with what reading the bag found, then the figures.
    fn bag(&self, bag: &std::path::Path, name: &str, rows: &mut Vec<Row>) -> anyhow::Result<()> {
        let standstill = StandstillConfig {
            remembered: self.memory.as_ref().and_then(|m| m.predict(Some(name), self.standstill.min_power_on_spread)),
            ..self.standstill
        };
        let scored = self.read_for_scoring(bag)?;
        let rec = &scored.rec;
        let notes = self.recording_notes(&scored, bag, name);
        let scoring = BagScoring { rec, name, notes: &notes };
        let source = scored.whole.as_ref().unwrap_or(rec);
        let span = scored_span(source, rec);
        // Each stream scored as soon as it is made and then dropped: one at a time in memory.
        let mut paths: Vec<(String, OrientationPath)> = Vec::new();
        for &m in &self.methods {
            let got = match m.apply(source, &self.detector, &standstill) {
                Ok((g, note)) if span.len() == g.len() => Ok((g, note)),
                Ok((g, note)) => Ok((g[span.clone()].to_vec(), note)),
                Err(imu_fsda::eval::EvalError::Method { why, .. }) => Err(why),
                Err(e) => Err(e.to_string()),
            };
            self.score_stream(&scoring, m.name().into(), got, rows, &mut paths);
        }
        let mut streams: Vec<(String, Stream)> = Vec::new();
        self.model_streams(source, &span, bag, name, &standstill, &mut streams)?;
        for (method, got) in streams {
            self.score_stream(&scoring, method, got, rows, &mut paths);
        }
        self.figures(name, rec, &paths)
    }

    /// One method's or model's row (or why it has none), its path kept for the figures.
    fn score_stream(
        &self,
        scoring: &BagScoring<'_>,
        method: String,
        got: Stream,
        rows: &mut Vec<Row>,
        paths: &mut Vec<(String, OrientationPath)>,
    ) {
        let BagScoring { rec, name, notes } = *scoring;
        let (gyro, mut note) = match got {
            Ok(g) => g,
            Err(why) => {
                rows.push(Row { bag: name.to_string(), method, errors: None, note: why });
                return;
            }
        };
        for n in notes {
            add_note(&mut note, n);
        }
        let scored = if self.args.plot_dir.is_some() {
            evaluate_with_path(rec, &gyro, &self.opts).map(|(e, path)| {
                paths.push((method.clone(), path));
                e
            })
        } else {
            evaluate(rec, &gyro, &self.opts)
        };
        match scored {
            Ok(e) => {
                if let Some(gaps) = e.gap_note() {
                    add_note(&mut note, &gaps);
                }
                rows.push(Row { bag: name.to_string(), method: method.clone(), errors: Some(e), note });
            }
            Err(e) => rows.push(Row { bag: name.to_string(), method: method.clone(), errors: None, note: e.to_string() }),
        }
        if self.args.oracle_bias {
            rows.push(self.oracle_bias_row(rec, name, &method, &gyro));
        }
    }

    /// Reads `bag` and keeps what can be scored: values no IMU measures dropped (as the node
    /// drops them), a bag without ground truth or stamps that are not the samples' times
    /// refused, and the span cut where `--start-s` / `--end-s` ask.
    fn read_for_scoring(&self, bag: &std::path::Path) -> anyhow::Result<ScoredRecording> {
        let args = self.args;
        let (mut rec, report) = read_recording(bag, &self.topics)?;
        // Stamps that are not the samples' times leave nothing to score: the pauses between
        // bursts stamped on arrival are holes, and every method read 0.00°.
        if let Some(why) = report.stamp_problem().or_else(|| imu_fsda::core::burst_stamps(&rec.imu)) {
            anyhow::bail!("{}: {why}", bag.display());
        }
        // One 1e30 rad/s sample would otherwise decide every method's score.
        let before = rec.imu.len();
        rec.imu.retain(ImuSample::is_plausible);
        let implausible = before - rec.imu.len();
        // Clipped samples are scored as recorded (the node integrates them too), and said.
        let clipped = imu_fsda::core::clipped_samples(&rec.imu);
        if let Some(c) = &clipped {
            tracing::warn!("{}: {c}", bag.display());
        }
        if implausible > 0 {
            tracing::warn!("{}: dropped {implausible} IMU samples beyond what any IMU measures", bag.display());
        }
        if rec.ground_truth.is_empty() {
            let (present, _) = imu_fsda::bag::bag_info(bag);
            let present: Vec<String> = present.iter().map(|t| format!("{} [{}]", t.topic, t.type_name)).collect();
            anyhow::bail!(
                "{}: no ground truth on {} (topics: {}); pass --ground-truth-topic",
                bag.display(),
                args.ground_truth_topic,
                present.join(", ")
            );
        }
        if let (Some(a), Some(g0), Some(g1)) = (args.start_s, rec.ground_truth.first(), rec.ground_truth.last()) {
            let covered = (g1.stamp_ns - g0.stamp_ns) as f64 * 1e-9;
            if a >= covered {
                anyhow::bail!(
                    "{}: --start-s {a} is past the ground truth, which covers {covered:.1} s from its first pose: nothing left to score",
                    bag.display()
                );
            }
        }
        // The methods and models run over the whole recording, as the node would have (the
        // initial rest and a model's window lie before a scored span), and are scored on the
        // span: before, a model warmed up again at --start-s, and static-bias found no rest.
        if args.start_s.is_none() && args.end_s.is_none() {
            return Ok(ScoredRecording { whole: None, rec, report, implausible, clipped });
        }
        let span = rec.crop_after_ground_truth_start(args.start_s, args.end_s).with_context(|| {
            format!(
                "{}: fewer than 2 IMU samples between --start-s {} and --end-s {} after the ground truth starts ({:.1} s recorded)",
                bag.display(),
                args.start_s.unwrap_or(0.0),
                args.end_s.map_or("(end)".to_string(), |e| e.to_string()),
                rec.imu_seconds()
            )
        })?;
        Ok(ScoredRecording { whole: Some(rec), rec: span, report, implausible, clipped })
    }

    /// What every row of this bag says about its input: samples skipped or dropped, a clock
    /// offset, ground truth that cannot be this IMU's attitude, an accelerometer not in m/s².
    /// All are scored as recorded (`train` and `adapt` refuse the last two).
    fn recording_notes(&self, scored: &ScoredRecording, bag: &std::path::Path, name: &str) -> Vec<String> {
        let (rec, report) = (&scored.rec, &scored.report);
        let mut notes = Vec::new();
        if report.skipped() > 0 {
            notes.push(skipped_note(report));
        }
        notes.extend(report.imu_stream_note());
        notes.extend(scored.clipped.clone());
        if scored.implausible > 0 {
            notes.push(format!(
                "dropped {} implausible IMU samples (|ω| > {:e} rad/s or |a| > {:e} m/s²)",
                scored.implausible,
                imu_fsda::core::IMPLAUSIBLE_RATE_RAD_S,
                imu_fsda::core::IMPLAUSIBLE_ACCEL_M_S2
            ));
        }
        let lag = imu_fsda::eval::ground_truth_lag(rec, &self.opts, imu_fsda::eval::GROUND_TRUTH_LAG_SEARCH_S);
        if let Some(l) = lag {
            tracing::info!("{name}: ground truth lags the IMU by {:.1} ms (rate correlation {:.3})", l.lag_s * 1e3, l.correlation);
        }
        let lag_note = lag.filter(imu_fsda::eval::GroundTruthLag::is_misaligned).map(|l| {
            let note =
                format!("ground truth lags the IMU by {:.1} ms (rate correlation {:.2}): scored as recorded", l.lag_s * 1e3, l.correlation);
            tracing::warn!("{}: {note}; check the clocks", bag.display());
            note
        });
        // A clock offset also makes the frames disagree: not said twice.
        let follows = imu_fsda::train::data::check_ground_truth_follows_gyro(rec, true).err().filter(|_| lag_note.is_none());
        notes.extend(lag_note);
        for e in [follows, imu_fsda::train::data::check_accel_units(rec).err()].into_iter().flatten() {
            let text = e.to_string();
            let text = text.strip_prefix(&format!("{}: ", rec.name)).unwrap_or(&text).to_string();
            tracing::warn!("{}: {text}", bag.display());
            notes.push(format!("{text}; scored as recorded"));
        }
        notes
    }

    /// Each model's stream as the node runs it on this IMU ([`imu_fsda::infer::choose`]);
    /// where the node would not run it, the model alone and beside it what runs instead.
    fn model_streams(
        &self,
        source: &Recording,
        span: &std::ops::Range<usize>,
        bag: &std::path::Path,
        name: &str,
        standstill: &StandstillConfig,
        streams: &mut Vec<(String, Stream)>,
    ) -> anyhow::Result<()> {
        let imu = imu_for_bag(&self.args.imus, bag);
        for (model_index, (model, &per_imu)) in self.args.models.iter().zip(&self.per_imu).enumerate() {
            // A model with per-IMU tables is run as the IMU named (a name it lacks is an
            // error); one with a single Ĉ_ω as an IMU it was trained on, else as a new one.
            let imu = imu.filter(|n| per_imu || self.metas[model_index].knows_imu(n));
            let (correction, why) = choose(ModelDomain::of(&self.metas[model_index], imu), true, self.args.model_on_new_imu);
            // As the pipeline: a bias memory file wins over the model's training power-ons.
            let standstill = &StandstillConfig {
                remembered: standstill
                    .remembered
                    .or_else(|| predict_from(trained_power_ons(&self.metas[model_index], imu), standstill.min_power_on_spread)),
                ..*standstill
            };
            let track = correction.removes_power_on_bias().then(|| BiasTrack::over(&source.imu, standstill));
            let input = match (&track, correction.runs_model()) {
                (Some(t), true) => t.debiased(&source.imu),
                _ => source.imu.clone(),
            };
            let run = correct_with_torchscript_at_model_rate(model, &input, imu).with_context(|| format!("model {}", model.display()))?;
            let mut corrected = run.corrected;
            if let (Some(t), true) = (&track, correction.runs_model()) {
                t.hold_still_windows(&source.imu, &mut corrected);
            }
            let (gyro, meta) = (corrected[span.clone()].to_vec(), run.metadata);
            let calib = imu.map_or(String::new(), |n| match meta.imu_correction_gains.get(n).filter(|_| meta.adapted_from.is_none()) {
                Some(g) => format!(", as on IMU {n} (correction gain {g:.3})"),
                None if meta.imu_gyro_calibrations.contains_key(n) => format!(", Ĉ_ω of {n}"),
                None => format!(", as on IMU {n} (trained on it)"),
            });
            let mut note = format!("{:?}, N = {}{calib}", meta.mode, meta.window_n);
            // As the node runs it: in the model's periods (the mean rate over each).
            if let Some(rate) = run.resampled_from_hz {
                add_note(&mut note, &format!("the {rate:.1} Hz input run in the model's {:.0} Hz periods", meta.rate_hz));
            }
            let label = self.labels[model_index].clone();
            let non_finite = gyro.iter().filter(|g| !g.iter().all(|v| v.is_finite())).count();
            if non_finite > 0 {
                let why = format!("the model's output is not finite at {non_finite} of {} samples: not scored", gyro.len());
                tracing::error!("{name}: {}: {why}", model.display());
                streams.push((label, Err(why)));
                continue;
            }
            if correction.removes_power_on_bias() && correction.runs_model() {
                add_note(&mut note, &format!("{why}: {}", track.as_ref().map(BiasTrack::note).unwrap_or_default()));
            }
            if correction.runs_model() {
                streams.push((label, Ok((gyro, note))));
                continue;
            }
            // The model alone is scored (what it does here), and beside it what the node runs
            // on this IMU instead.
            add_note(&mut note, &format!("the model alone; as deployed the node runs {}", correction.name()));
            let deployed = match &track {
                Some(t) => (t.corrected_gyro(&source.imu)[span.clone()].to_vec(), format!("{why}: {}", t.note())),
                None => (source.imu[span.clone()].iter().map(|s| s.gyro).collect(), why.to_string()),
            };
            streams.push((label.clone(), Ok((gyro, note))));
            streams.push((format!("{label} as deployed"), Ok(deployed)));
        }
        Ok(())
    }

    /// `M − oracle bias`: the stream with its own mean rate error against the ground truth
    /// removed (it reads the ground truth: a reference, not a method).
    fn oracle_bias_row(&self, rec: &Recording, name: &str, method: &str, gyro: &[Vector3<f64>]) -> Row {
        let bound = format!("{method} − oracle bias");
        let row = mean_rate_error(rec, gyro, &self.opts).and_then(|b| {
            let fixed: Vec<Vector3<f64>> = gyro.iter().map(|g| g - b).collect();
            let e = evaluate(rec, &fixed, &self.opts)?;
            let note = format!("oracle, reads the ground truth: constant [{:.5}, {:.5}, {:.5}] rad/s removed", b.x, b.y, b.z);
            Ok(Row { bag: name.to_string(), method: bound.clone(), errors: Some(e), note })
        });
        row.unwrap_or_else(|e| Row { bag: name.to_string(), method: bound, errors: None, note: e.to_string() })
    }

    fn figures(&self, name: &str, rec: &Recording, paths: &[(String, OrientationPath)]) -> anyhow::Result<()> {
        let Some(dir) = &self.args.plot_dir else { return Ok(()) };
        if paths.is_empty() {
            tracing::warn!("{name}: no method evaluated, no figure");
            return Ok(());
        }
        imu_fsda::core::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let files = imu_fsda::figures::orientation_figures(dir, name, rec, paths).with_context(|| format!("{name}: figures"))?;
        for f in files {
            tracing::info!("wrote {}", f.display());
        }
        Ok(())
    }
}

/// What the bag reader left out, by stream: IMU samples and ground-truth poses are not the same.
fn skipped_note(r: &imu_fsda::bag::LoadReport) -> String {
    let (imu, gt) = (r.imu_skipped(), r.ground_truth_skipped());
    let mut parts = Vec::new();
    // Another sensor's samples are said by `imu_stream_note`.
    let imu = imu - r.imu_other_sensor;
    if imu > 0 {
        parts.push(format!("skipped {imu} IMU samples"));
    }
    if gt > 0 {
        parts.push(format!("skipped {gt} ground-truth poses"));
    }
    if r.ground_truth_frozen > 0 {
        parts.push(format!("{} frozen ground-truth poses left out (one pose repeated while the IMU moved)", r.ground_truth_frozen));
    }
    parts.join("; ")
}

/// Each bag's label in the rows and its figures' file names: the file stem, or the path
/// without its extension where two bags share a stem (`run1/imu.mcap`, `run2/imu.mcap`), so
/// neither row nor figure stands for the other.
fn bag_names(bags: &[PathBuf]) -> Vec<String> {
    let stem = |b: &PathBuf| b.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    bags.iter()
        .map(|b| {
            if bags.iter().filter(|o| stem(o) == stem(b)).count() > 1 {
                b.with_extension("").to_string_lossy().trim_start_matches("./").replace('/', "_")
            } else {
                stem(b)
            }
        })
        .collect()
}

/// Append `more` to a row's note, "; "-separated.
fn add_note(note: &mut String, more: &str) {
    if more.is_empty() {
        return;
    }
    if !note.is_empty() {
        note.push_str("; ");
    }
    note.push_str(more);
}

pub fn markdown_table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| bag | method | AOE° | roll° | pitch° | yaw° | tilt° | heading° | s | note |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        match &r.errors {
            Some(e) => {
                s += &format!(
                    "| {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.0} | {} |\n",
                    r.bag,
                    r.method,
                    e.aoe_deg,
                    e.roll_rmse_deg,
                    e.pitch_rmse_deg,
                    e.yaw_rmse_deg,
                    e.tilt_rmse_deg,
                    e.heading_rmse_deg,
                    e.seconds,
                    r.note
                )
            }
            None => s += &format!("| {} | {} | – | – | – | – | – | – | – | {} |\n", r.bag, r.method, r.note),
        }
    }
    s
}

/// The IMU name `--imu` gives `bag` (see [`EvalArgs::imus`]).
fn imu_for_bag<'a>(rules: &'a [String], bag: &std::path::Path) -> Option<&'a str> {
    let file = bag.file_name().map(|f| f.to_string_lossy()).unwrap_or_default();
    rules.iter().find_map(|rule| match rule.split_once('=') {
        Some((pattern, name)) => glob_match(pattern, &file).then_some(name),
        None => Some(rule.as_str()),
    })
}

/// Shell-style match of the whole of `text`: `*` any characters, `?` one character.
fn glob_match(pattern: &str, text: &str) -> bool {
    let (p, t): (Vec<char>, Vec<char>) = (pattern.chars().collect(), text.chars().collect());
    // The last `*` seen and where in `text` it was tried to end: on a mismatch it takes one
    // more character (linear backtracking; no `*` before means no match).
    let (mut i, mut j, mut star) = (0, 0, None);
    while j < t.len() {
        match p.get(i) {
            Some('*') => {
                star = Some((i, j));
                i += 1;
            }
            Some(&c) if c == '?' || c == t[j] => {
                i += 1;
                j += 1;
            }
            _ => match star {
                Some((si, sj)) => {
                    star = Some((si, sj + 1));
                    i = si + 1;
                    j = sj + 1;
                }
                None => return false,
            },
        }
    }
    p[i..].iter().all(|&c| c == '*')
}

/// Each model's row label: its name, else (two of one name: a renamed copy, two adaptations)
/// its file stem, else its path.
fn model_labels(models: &[std::path::PathBuf], metas: &[imu_fsda::model::export::ModelMetadata]) -> Vec<String> {
    let names: Vec<String> = metas.iter().map(|m| m.name.clone()).collect();
    let stems: Vec<String> = models.iter().map(|m| m.file_stem().map_or(String::new(), |s| s.to_string_lossy().into_owned())).collect();
    let unique = |list: &[String], i: usize| list.iter().filter(|x| **x == list[i]).count() == 1;
    (0..models.len())
        .map(|i| {
            if unique(&names, i) {
                names[i].clone()
            } else if unique(&stems, i) && (names[i] == stems[i] || !names.contains(&stems[i])) {
                stems[i].clone()
            } else {
                models[i].display().to_string()
            }
        })
        .collect()
}

/// Where `span`'s IMU samples lie in `whole`'s (a crop of it: one contiguous run).
fn scored_span(whole: &Recording, span: &Recording) -> std::ops::Range<usize> {
    let start = span.imu.first().map_or(0, |s| whole.imu.partition_point(|w| w.stamp_ns < s.stamp_ns));
    start..start + span.imu.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn imu_rules_match_bag_file_names() {
        let rules: Vec<String> = ["room*=tumvi", "*_0?=x", "MH*easy*=euroc", "default"].iter().map(|s| s.to_string()).collect();
        let at = |p: &str| imu_for_bag(&rules, std::path::Path::new(p));
        assert_eq!(at("/bags/room4.mcap"), Some("tumvi"));
        assert_eq!(at("MH_02_easy.mcap"), Some("euroc"));
        assert_eq!(at("V1_01_easy.mcap"), Some("default"));
        assert_eq!(imu_for_bag(&rules[..1], std::path::Path::new("V1_01_easy.mcap")), None);
        assert!(glob_match("*", "") && glob_match("a*a", "aa") && !glob_match("a*a", "a") && glob_match("*b*", "abc"));
        // `?` is one character, as in the shell (scripts/env.sh names EuRoC's V1_*, V2_* so).
        let paper = ["room*=tumvi", "MH_*=euroc", "V?_*=euroc"].map(String::from);
        assert_eq!(imu_for_bag(&paper, std::path::Path::new("V2_02_medium.mcap")), Some("euroc"));
        assert!(glob_match("V?_*", "V1_01_easy.mcap") && !glob_match("V?_*", "V12_x") && !glob_match("?", ""));
        assert!(glob_match("a*b*c", "aXbYbc") && !glob_match("a*b*c", "aXbYb") && glob_match("**?", "x") && glob_match("ü?", "üß"));
    }
}
