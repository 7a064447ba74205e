//! `imu-fsda bias-memory BAG... -o FILE`: each bag's power-on bias, as its standstills measure
//! it (the pipeline's rule), recorded in a bias memory file: what the node's
//! `power_on_bias_memory` holds after those power-ons, to seed it from recordings or to judge
//! it (`eval --bias-memory`).

use std::path::{Path, PathBuf};

use anyhow::Context;
use imu_fsda::bag::{read_recording, RecordingTopics, IMU_TOPIC};
use imu_fsda::bias_memory::BiasMemory;
use imu_fsda::standstill::BiasTrack;

#[derive(Debug, clap::Args)]
pub struct BiasMemoryArgs {
    /// Recordings of one IMU, each a power-on (MCAP bags).
    #[arg(required = true, value_name = "BAG")]
    pub bags: Vec<PathBuf>,
    /// The bias memory (JSON): created, or added to (a bag already in it is measured again).
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
    #[arg(long, default_value = IMU_TOPIC)]
    pub imu_topic: String,
    /// The node's parameter file: its `pipeline.standstill` is how standstills are found.
    #[arg(long)]
    pub params: Option<PathBuf>,
}

pub fn run(args: BiasMemoryArgs) -> anyhow::Result<()> {
    let cfg = super::standstill_of(args.params.as_deref())?;
    let inputs: Vec<&Path> = args.bags.iter().map(PathBuf::as_path).collect();
    super::refuse_overwriting_input(&args.output, &inputs)?;
    let mut memory = BiasMemory::load(&args.output)?;
    let topics = RecordingTopics { imu: args.imu_topic.clone(), ground_truth: None, temperature: None };
    for bag in &args.bags {
        let (rec, _) = read_recording(bag, &topics).with_context(|| format!("reading {}", bag.display()))?;
        let name = bag.file_stem().map_or_else(|| bag.display().to_string(), |s| s.to_string_lossy().into_owned());
        let track = BiasTrack::over(&rec.imu, &cfg);
        match &track.last {
            Some(e) => {
                memory.remember(&name, e);
                eprintln!("{name}: {}", track.note());
            }
            None => eprintln!("{name}: {} (not recorded)", track.note()),
        }
    }
    memory.save(&args.output)?;
    eprintln!("{}: {} power-ons", args.output.display(), memory.power_ons.len());
    Ok(())
}
