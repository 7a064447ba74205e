//! `imu-fsda replay IN.mcap -o OUT.mcap`: the node's pipeline over a bag, offline. Every
//! input message is copied through; `/imu/denoised`, `/imu/gyro_correction` and
//! `/diagnostics` are added, exactly as the live node would publish them.

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::bag::{BagMessage, BagWriter, Channel};
use imu_fsda::infer::Pipeline;
use imu_fsda::msg::{DiagnosticArray, Imu, RosMessage, Time, Vector3Stamped};
use imu_fsda::node::{diagnostics_message, fill_denoised, Liveness, NodeStats, StatusClock};

use super::corrector::load_corrector;
use super::node::NodeConfigArgs;

#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// Input bag with raw IMU.
    pub input: PathBuf,
    /// Output bag: the input plus the node's topics.
    #[arg(short, long)]
    pub output: PathBuf,
    #[command(flatten)]
    pub config: NodeConfigArgs,
    /// Raw IMU topic in the bag; default: the node's input topic if the bag has it, else /imu/data.
    #[arg(long)]
    pub input_topic: Option<String>,
}

/// Diagnostics ticks written over one hole in the bag at most (an hour at 1 Hz): a stray
/// message stamped far from the rest would otherwise fill the bag with ticks.
const MAX_HOLE_TICKS: u64 = 3600;

pub fn run(args: ReplayArgs) -> anyhow::Result<()> {
    let mut params = args.config.load()?;
    // Read, never written: a replay is not a power-on of the IMU.
    if let Some(note) = params.take_bias_memory(false)? {
        tracing::info!("power_on_bias_memory {}: {note}", params.power_on_bias_memory);
    }
    let (corrector, status) = load_corrector(&params.model, &params.imu_calibration)?;
    let pipeline = Pipeline::new(corrector, params.pipeline.clone());
    let (topics, read_error) = imu_fsda::bag::bag_info(&args.input);
    let input_topic = input_topic_of(&args, &params, &topics, read_error)?;
    refuse_clashes(&args, &params, &topics)?;
    super::refuse_overwriting_input(&args.output, &[&args.input])?;
    // From the moment the output exists, a signal finishes it.
    super::interrupts::catch();
    let mut replay = Replay::start(&args, &params, pipeline, status, input_topic)?;
    // A damaged input or Ctrl-C ends the loop; what was replayed before it is kept.
    let (mut damage, mut read) = (None, 0u64);
    // MCAP lets a recorder write out of log-time order; the node would have received in log-time
    // order (in file order, most samples were dropped as backwards).
    for m in imu_fsda::bag::messages_in_log_time_order(&args.input, &topics)? {
        if super::interrupts::requested() {
            break;
        }
        let m = match m {
            Ok(m) => m,
            Err(e) => {
                damage = Some(e);
                break;
            }
        };
        read += 1;
        replay.message(&m)?;
    }
    let done = replay.finish()?;
    let kept = || format!("{} holds the replay of the {read} messages before it", args.output.display());
    if let Some(e) = damage {
        return Err(anyhow::Error::new(e).context(format!("the input is damaged; {}", kept())));
    }
    if super::interrupts::requested() {
        return Err(super::interrupts::Interrupted(kept()).into());
    }
    say_how_it_ran(&args, &params, &done.pipeline, &done.stats, done.live.input_rate_hz, done.decode_errors, &done.input_topic)
}

/// The node's pipeline over a bag's messages: each copied through, the IMU's corrected and
/// published, /diagnostics ticked over the bag's log time as the live node's timer ticks.
struct Replay {
    pipeline: Pipeline,
    writer: BagWriter,
    out_ch: Channel,
    corr_ch: Channel,
    diag_ch: Channel,
    /// The output channel of each input topic, made at its first message.
    channels: std::collections::HashMap<std::sync::Arc<str>, Channel>,
    stats: NodeStats,
    /// The status over the bag's time (log time, receipt): input rate, events.
    clock: StatusClock,
    period_ns: u64,
    next_diag: Option<u64>,
    last_frame: Option<String>,
    decode_errors: u64,
    last_log: u64,
    input_topic: String,
    node_name: String,
    input: PathBuf,
    output: PathBuf,
}

impl Replay {
    fn start(
        args: &ReplayArgs,
        params: &imu_fsda::node::NodeParams,
        pipeline: Pipeline,
        model_status: String,
        input_topic: String,
    ) -> anyhow::Result<Self> {
        let mut writer = BagWriter::create(&args.output)?;
        let out_ch = writer.channel::<Imu>(&params.output_topic)?;
        let corr_ch = writer.channel::<Vector3Stamped>(&params.correction_topic)?;
        let diag_ch = writer.channel::<DiagnosticArray>(&params.diagnostics_topic)?;
        let stats =
            NodeStats { model: pipeline.corrector_name().to_string(), window: pipeline.window(), model_status, ..Default::default() };
        Ok(Replay {
            pipeline,
            writer,
            out_ch,
            corr_ch,
            diag_ch,
            channels: std::collections::HashMap::new(),
            stats,
            clock: StatusClock::default(),
            period_ns: (params.diagnostics_period * 1e9) as u64,
            next_diag: None,
            last_frame: None,
            decode_errors: 0,
            last_log: 0,
            input_topic,
            node_name: args.config.node_name.clone(),
            input: args.input.clone(),
            output: args.output.clone(),
        })
    }

    /// One message: the ticks due before it, the message copied, and corrected where it is
    /// the IMU's.
    fn message(&mut self, m: &BagMessage) -> anyhow::Result<()> {
        self.tick_until(m.log_time_ns)?;
        let ch = match self.channels.get(&m.topic) {
            Some(c) => *c,
            None => {
                let c = self.writer.channel_of(&m.topic, m)?;
                self.channels.insert(m.topic.clone(), c);
                c
            }
        };
        self.writer.write_raw(ch, m.log_time_ns as i64, &m.data)?;
        self.last_log = m.log_time_ns;
        if *m.topic == *self.input_topic {
            self.correct(m)?;
        }
        Ok(())
    }

    /// The live node's timer ticks whether or not input comes: a hole in the IMU stream shows
    /// as "no input" ticks, as on the robot (at most [`MAX_HOLE_TICKS`] per hole).
    fn tick_until(&mut self, log_time_ns: u64) -> anyhow::Result<()> {
        let Some(mut due) = self.next_diag else { return Ok(()) };
        let mut ticks = 0;
        // Strictly after: a message at the tick's own time is received before it.
        while log_time_ns > due {
            if ticks == MAX_HOLE_TICKS {
                due += (log_time_ns - due) / self.period_ns * self.period_ns + self.period_ns;
                break;
            }
            let (status, _) = self.status_at(due);
            self.writer.write(self.diag_ch, due as i64, &status)?;
            due += self.period_ns;
            ticks += 1;
        }
        self.next_diag = Some(due);
        Ok(())
    }

    /// An IMU message through the pipeline: /imu/denoised and /imu/gyro_correction written at
    /// its log time.
    fn correct(&mut self, m: &BagMessage) -> anyhow::Result<()> {
        let mut msg = match Imu::decode(&m.data) {
            Ok(x) => x,
            Err(e) => {
                self.decode_errors += 1;
                tracing::warn!("{}: {e}", self.input.display());
                return Ok(());
            }
        };
        if self.last_frame.as_deref() != Some(msg.header.frame_id.as_str()) {
            if self.last_frame.is_some() {
                self.stats.frame_changes += 1;
            }
            self.last_frame = Some(msg.header.frame_id.clone());
        }
        if let Ok(c) = self.pipeline.push(&msg.sample()) {
            let correction = Vector3Stamped { header: msg.header.clone(), vector: c.correction.into() };
            fill_denoised(&mut msg, &c);
            self.writer.write(self.out_ch, m.log_time_ns as i64, &msg)?;
            self.writer.write(self.corr_ch, m.log_time_ns as i64, &correction)?;
            self.stats.warming_up = c.warming_up;
        }
        self.stats.last_input_ns = Some(m.log_time_ns as i64);
        self.clock.start(m.log_time_ns as i64, self.pipeline.counters().received);
        self.next_diag.get_or_insert(m.log_time_ns + self.period_ns);
        Ok(())
    }

    /// The node's /diagnostics at `now_ns` (the bag's log time), from the pipeline's counters.
    fn status_at(&mut self, now_ns: u64) -> (DiagnosticArray, Liveness) {
        let stats = &mut self.stats;
        stats.counters = self.pipeline.counters().clone();
        stats.decode_errors = self.decode_errors;
        stats.rate_off_nominal = self.pipeline.rate_off_nominal();
        stats.resampling = self.pipeline.resampling();
        stats.take_orientation(&self.pipeline);
        stats.take_power_on(&self.pipeline);
        stats.frame_id = self.last_frame.clone().unwrap_or_default();
        let live = self.clock.tick(stats, now_ns as i64);
        (diagnostics_message(stats, &live, &self.node_name, Time::from_ns(now_ns as i64)), live)
    }

    /// The last status at the last log time, and the bag finished.
    fn finish(mut self) -> anyhow::Result<Finished> {
        let (status, live) = self.status_at(self.last_log);
        self.writer.write(self.diag_ch, self.last_log as i64, &status)?;
        let Replay { writer, pipeline, stats, decode_errors, input_topic, output, .. } = self;
        writer.finish().with_context(|| format!("finishing {}", output.display()))?;
        Ok(Finished { live, pipeline, stats, decode_errors, input_topic })
    }
}

/// What a replay leaves to say how it ran.
struct Finished {
    live: Liveness,
    pipeline: Pipeline,
    stats: NodeStats,
    decode_errors: u64,
    input_topic: String,
}

/// The raw IMU's topic: `--input-topic`, else the node's input topic if the bag has it, else
/// the bag layout's; refused where it is missing or holds another type.
fn input_topic_of(
    args: &ReplayArgs,
    params: &imu_fsda::node::NodeParams,
    topics: &[imu_fsda::bag::TopicInfo],
    read_error: Option<imu_fsda::bag::BagError>,
) -> anyhow::Result<String> {
    let listing = || topics.iter().map(|t| format!("{} [{}]", t.topic, t.type_name)).collect::<Vec<_>>().join(", ");
    let has = |t: &str| topics.iter().any(|i| i.topic == t && i.type_name == Imu::TYPE_NAME);
    let input_topic = match &args.input_topic {
        Some(t) => t.clone(),
        None if has(&params.input_topic) => params.input_topic.clone(),
        None => imu_fsda::bag::IMU_TOPIC.to_string(),
    };
    match topics.iter().find(|t| t.topic == input_topic) {
        Some(t) if t.type_name == Imu::TYPE_NAME => {}
        Some(t) => anyhow::bail!(
            "{}: {input_topic} holds {}, not {}; pass the raw IMU's topic with --input-topic",
            args.input.display(),
            t.type_name,
            Imu::TYPE_NAME
        ),
        // A missing or unreadable bag, not a bag without the topic.
        None if topics.is_empty() && read_error.is_some() => return Err(read_error.expect("checked").into()),
        None => anyhow::bail!(
            "{}: no {input_topic} holding {} (topics: {}); pass --input-topic",
            args.input.display(),
            Imu::TYPE_NAME,
            listing()
        ),
    }
    Ok(input_topic)
}

/// Refuses a bag that already holds a stream the replay would write.
fn refuse_clashes(args: &ReplayArgs, params: &imu_fsda::node::NodeParams, topics: &[imu_fsda::bag::TopicInfo]) -> anyhow::Result<()> {
    // The node's streams must not land on a stream the bag already has (a bag recorded beside
    // the live node holds its /imu/denoised): two publishers mixed on one topic. Other nodes'
    // /diagnostics are the same type and share the topic, as on a live system.
    // Every clash at once: one per run made a user run three times.
    let clashes: Vec<String> = [("output_topic", &params.output_topic), ("correction_topic", &params.correction_topic)]
        .into_iter()
        .filter_map(|(key, topic)| {
            topics.iter().find(|t| t.topic == *topic).map(|t| {
                format!(
                    "{topic} ({} messages of {}): the node's {key} would be mixed into it; remap it, e.g. -r {topic}:={topic}_replay",
                    t.count, t.type_name
                )
            })
        })
        .collect();
    if !clashes.is_empty() {
        anyhow::bail!("{}: the bag already holds {}", args.input.display(), clashes.join("; and "));
    }
    if let Some(t) = topics.iter().find(|t| t.topic == params.diagnostics_topic && t.type_name != DiagnosticArray::TYPE_NAME) {
        anyhow::bail!(
            "{}: the bag's {} holds {}, not {}; remap diagnostics_topic",
            args.input.display(),
            t.topic,
            t.type_name,
            DiagnosticArray::TYPE_NAME
        );
    }
    Ok(())
}

/// What the replay says at its end: how the input's rate was met, stamps that are not the
/// samples' times, an input nothing could be read from, and the counts.
fn say_how_it_ran(
    args: &ReplayArgs,
    params: &imu_fsda::node::NodeParams,
    pipeline: &Pipeline,
    stats: &NodeStats,
    input_rate_hz: f64,
    decode_errors: u64,
    input_topic: &str,
) -> anyhow::Result<()> {
    let switches = pipeline.counters().resampling_switches;
    if pipeline.resampling() || switches > 0 {
        tracing::info!(
            "{}: the input ({:.1} Hz at the end) was fed to the {:.1} Hz model in its periods {} ({switches} switches)",
            args.input.display(),
            input_rate_hz,
            pipeline.corrector_rate_hz().unwrap_or(f64::NAN),
            if pipeline.resampling() { "at the end" } else { "for part of the bag" }
        );
    } else if pipeline.rate_off_nominal() {
        tracing::warn!(
            "{}: the input rate ({:.1} Hz at the end) is off the nominal {:.1} Hz by more than {:.0} %: a model runs at the rate it was trained at (its window spans another time)",
            args.input.display(),
            input_rate_hz,
            pipeline.nominal_rate_hz().unwrap_or(f64::NAN),
            params.pipeline.rate_tolerance * 100.0
        );
    }
    let c = &stats.counters;
    if c.received >= 2 && 2 * (c.dropped_duplicate_stamp + c.dropped_backwards_stamp) > c.received {
        tracing::warn!(
            "{}: {} of {} IMU messages repeat or go back from an earlier header stamp and were dropped: header.stamp is not \
             the sample's time (a driver leaving it at zero?)",
            args.input.display(),
            c.dropped_duplicate_stamp + c.dropped_backwards_stamp,
            c.received
        );
    }
    anyhow::ensure!(
        c.received > 0,
        "{}: none of the messages on {input_topic} could be read as {} ({decode_errors} decode errors): {} holds a copy of the input and nothing denoised",
        args.input.display(),
        Imu::TYPE_NAME,
        args.output.display()
    );
    out!(
        "replayed {} {} messages through {} → {} ({} published on {}, dropped: {} non-finite, {} implausible, {} duplicate, {} backwards stamps; {} gaps; {} decode errors)",
        c.received,
        input_topic,
        stats.model,
        args.output.display(),
        c.processed,
        params.output_topic,
        c.dropped_non_finite,
        c.dropped_implausible,
        c.dropped_duplicate_stamp,
        c.dropped_backwards_stamp,
        c.gaps,
        decode_errors
    )?;
    Ok(())
}
