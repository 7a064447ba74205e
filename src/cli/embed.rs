//! `imu-fsda embed --model M --sequence DIR... -o OUT.png`: the model's Embedding of samples
//! of each sequence, mapped to 2-D by t-SNE, one colour per sequence and one marker per
//! dataset. Writes OUT.png, OUT.csv (the 2-D points) and OUT.json (options and summary).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use imu_fsda::bag::{read_recording, RecordingTopics};
use imu_fsda::core::ImuSample;
use imu_fsda::dataset::{load_sequence, DatasetKind};
use imu_fsda::embed::{sample_indices, short_name, EmbeddingModel};
use imu_fsda::plot::{color, scatter, Marker, Scatter, ScatterGroup};
use imu_fsda::tsne::{tsne, TsneOptions};

#[derive(Debug, clap::Args)]
pub struct EmbedArgs {
    /// Exported FSDA / FSDA-F model (`.pt`, `.ot` or `.json`; the `.json` + `.ot` are read).
    #[arg(long)]
    pub model: PathBuf,
    /// EuRoC / TUM-VI sequence folders (ASL layout) or MCAP bags (repeatable).
    #[arg(long = "sequence", required = true, num_args = 1..)]
    pub sequences: Vec<PathBuf>,
    /// Output PNG; the points go to the same path with `.csv` and `.json`.
    #[arg(short, long)]
    pub out: PathBuf,
    /// IMU topic of the bags (sensor_msgs/Imu); dataset folders are read as they are.
    #[arg(long, default_value = imu_fsda::bag::IMU_TOPIC)]
    pub imu_topic: String,
    /// Samples drawn (uniformly, without replacement) from each sequence.
    #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u32).range(1..))]
    pub points_per_sequence: u32,
    /// Seed of the sampling and of the t-SNE layout.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// t-SNE perplexity (> 1).
    #[arg(long, default_value_t = 30.0, value_parser = perplexity)]
    pub perplexity: f64,
    /// t-SNE gradient steps.
    #[arg(long, default_value_t = 1000)]
    pub iterations: usize,
}

/// A usage error (exit 2) as every other numeric option's, not a run-time one.
fn perplexity(s: &str) -> Result<f64, String> {
    super::finite(s).and_then(|x| if x > 1.0 { Ok(x) } else { Err(format!("{s} is not above 1")) })
}

/// Exact t-SNE is O(n²) in memory and time: beyond this, ask for fewer points.
const MAX_POINTS: usize = 6000;

struct Source {
    name: String,
    dataset: &'static str,
    imu: Vec<ImuSample>,
}

fn load(path: &Path, imu_topic: &str) -> anyhow::Result<Source> {
    if path.is_dir() {
        let (seq, rec, _) = load_sequence(path).with_context(|| format!("reading {}", path.display()))?;
        let dataset = match seq.kind {
            DatasetKind::Euroc => "EuRoC",
            DatasetKind::TumVi => "TUM-VI",
        };
        Ok(Source { name: short_name(&seq.name), dataset, imu: rec.imu })
    } else {
        let topics = RecordingTopics { imu: imu_topic.into(), ground_truth: None, temperature: None };
        let (rec, _) = read_recording(path, &topics)?; // its errors name the bag
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(Source { name, dataset: "bag", imu: rec.imu })
    }
}

pub fn run(args: EmbedArgs) -> anyhow::Result<()> {
    let per_sequence = args.points_per_sequence as usize;
    if per_sequence.saturating_mul(args.sequences.len()) > MAX_POINTS {
        anyhow::bail!(
            "{} sequences × {} points exceed the {MAX_POINTS} points an exact t-SNE handles here; lower --points-per-sequence",
            args.sequences.len(),
            args.points_per_sequence
        );
    }
    // The figure, its CSV and its JSON sidecar must not land on the model or a bag.
    let model_files: Vec<PathBuf> = ["pt", "json", "ot"].iter().map(|e| args.model.with_extension(e)).collect();
    let inputs: Vec<&Path> = model_files.iter().chain(&args.sequences).map(PathBuf::as_path).collect();
    let (csv_path, json_path) = (args.out.with_extension("csv"), args.out.with_extension("json"));
    super::refuse_shared_outputs(&[("--out", &args.out), ("its CSV", &csv_path), ("its JSON", &json_path)])?;
    for out in [args.out.as_path(), &csv_path, &json_path] {
        super::refuse_overwriting_input(out, &inputs)?;
    }
    let opts = TsneOptions { perplexity: args.perplexity, iterations: args.iterations, seed: args.seed, ..Default::default() };
    opts.validate()?; // before any embedding is computed
    let model = EmbeddingModel::load(&args.model).with_context(|| format!("model {}", args.model.display()))?;
    let (labels, x) = embed_sources(&model, &args, per_sequence)?;
    let start = std::time::Instant::now();
    let map = tsne(&x, &opts)?;
    tracing::info!("t-SNE of {} points in {:.1} s, KL {:.3}", x.len(), start.elapsed().as_secs_f64(), map.kl_divergence);

    let groups = scatter_groups(&labels, &map.points);
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        imu_fsda::core::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let sc = Scatter {
        title: format!(
            "t-SNE of the {} Embedding ({} samples per sequence, perplexity {:.0})",
            model.name, args.points_per_sequence, map.perplexity
        ),
        x_label: "t-SNE 1".into(),
        y_label: "t-SNE 2".into(),
        width: 1000,
        height: 750,
        groups,
        marker_size: 3,
    };
    scatter(&args.out, &sc)?;

    let mut csv = String::from("sequence,dataset,sample_index,stamp_ns,x,y\n");
    for ((name, dataset, i, stamp), p) in labels.iter().zip(&map.points) {
        let _ = writeln!(csv, "{name},{dataset},{i},{stamp},{:.6},{:.6}", p[0], p[1]);
    }
    std::fs::write(&csv_path, csv).with_context(|| format!("writing {}", csv_path.display()))?;
    let summary = serde_json::json!({
        "model": args.model,
        "sequences": args.sequences,
        "points_per_sequence": args.points_per_sequence,
        "points": x.len(),
        "embedding_dim": x.first().map_or(0, Vec::len),
        "tsne": opts,
        "perplexity_used": map.perplexity,
        "kl_divergence": map.kl_divergence,
        "points_csv": csv_path.file_name().map(|f| f.to_string_lossy().into_owned()),
    });
    std::fs::write(&json_path, serde_json::to_string_pretty(&summary)?).with_context(|| format!("writing {}", json_path.display()))?;
    out!(
        "wrote {}, {} and {} ({} points, KL {:.3})",
        args.out.display(),
        csv_path.display(),
        json_path.display(),
        x.len(),
        map.kl_divergence
    )?;
    Ok(())
}

/// A point's sequence, dataset, sample index and stamp.
type Label = (String, &'static str, usize, i64);

/// Each sequence's sampled points through the Embedding: their labels and embeddings.
fn embed_sources(model: &EmbeddingModel, args: &EmbedArgs, per_sequence: usize) -> anyhow::Result<(Vec<Label>, Vec<Vec<f64>>)> {
    let mut labels: Vec<Label> = Vec::new();
    let mut x: Vec<Vec<f64>> = Vec::new();
    let sources = args.sequences.iter().map(|p| load(p, &args.imu_topic)).collect::<anyhow::Result<Vec<Source>>>()?;
    // Two of one name (`a/run.mcap`, `b/run.mcap`) were drawn as one group and one label:
    // each is named by its path instead.
    let names: Vec<String> = sources.iter().map(|s| s.name.clone()).collect();
    for (k, (path, mut src)) in args.sequences.iter().zip(sources).enumerate() {
        if names.iter().filter(|n| **n == src.name).count() > 1 {
            src.name = path.display().to_string();
            // The same path given twice: numbered in the order given.
            if args.sequences.iter().filter(|p| *p == path).count() > 1 {
                src.name = format!("{} #{}", src.name, args.sequences[..=k].iter().filter(|p| *p == path).count());
            }
        }
        let idx = sample_indices(&src.imu, per_sequence, args.seed.wrapping_add(k as u64));
        if idx.is_empty() {
            anyhow::bail!("{}: no finite IMU sample", path.display());
        }
        let picked: Vec<ImuSample> = idx.iter().map(|&i| src.imu[i]).collect();
        let e = model.embed(&picked)?;
        tracing::info!("{}: {} samples embedded ({} in the sequence)", src.name, e.len(), src.imu.len());
        for (&i, v) in idx.iter().zip(e) {
            labels.push((src.name.clone(), src.dataset, i, src.imu[i].stamp_ns));
            x.push(v);
        }
    }
    Ok((labels, x))
}

/// One group per sequence in the order given; colours cycle within each dataset, the marker
/// tells the dataset.
fn scatter_groups(labels: &[Label], points: &[[f64; 2]]) -> Vec<ScatterGroup> {
    let mut groups: Vec<ScatterGroup> = Vec::new();
    let mut per_dataset: std::collections::BTreeMap<&str, usize> = Default::default();
    for (k, (name, dataset, _, _)) in labels.iter().enumerate() {
        let p = (points[k][0], points[k][1]);
        match groups.iter_mut().find(|g| g.label.starts_with(&format!("{name} ("))) {
            Some(g) => g.points.push(p),
            None => {
                let n = per_dataset.entry(dataset).or_default();
                let (marker, offset) = match *dataset {
                    "EuRoC" => (Marker::Circle, 0),
                    "TUM-VI" => (Marker::Triangle, 11),
                    _ => (Marker::Cross, 0),
                };
                groups.push(ScatterGroup { label: format!("{name} ({dataset})"), points: vec![p], color: color(offset + *n), marker });
                *n += 1;
            }
        }
    }
    groups
}
