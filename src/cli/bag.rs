//! `imu-fsda bag info|echo`: what is in a bag, as `ros2 bag info` and `ros2 topic echo` show it.

use std::path::PathBuf;

use anyhow::Context;
use imu_fsda::bag::{bag_info, BagReader};
use imu_fsda::msg::{DiagnosticArray, Imu, Odometry, PoseStamped, RosMessage, Temperature, Vector3Stamped};

#[derive(Debug, clap::Subcommand)]
pub enum BagCommand {
    /// Topics, types, message counts, rates and time span of a bag.
    Info {
        /// The MCAP bag.
        file: PathBuf,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Print the messages of a bag as JSON lines (one message a line), decoded with our types.
    Echo {
        /// The MCAP bag.
        file: PathBuf,
        /// Only this topic (default: all topics).
        #[arg(long)]
        topic: Option<String>,
        /// Stop after this many messages.
        #[arg(long)]
        limit: Option<u64>,
    },
}

pub fn run(cmd: BagCommand) -> anyhow::Result<()> {
    match cmd {
        BagCommand::Info { file, json } => info(file, json),
        BagCommand::Echo { file, topic, limit } => echo(file, topic, limit),
    }
}

fn info(file: PathBuf, json: bool) -> anyhow::Result<()> {
    let (topics, err) = bag_info(&file);
    // Nothing read (missing, not MCAP): the error alone, not a table of zeros before it.
    if let (true, Some(e)) = (topics.is_empty(), &err) {
        anyhow::bail!("{e}");
    }
    let first = topics.iter().map(|t| t.first_ns).min().unwrap_or(0);
    let last = topics.iter().map(|t| t.last_ns).max().unwrap_or(0);
    let total: u64 = topics.iter().map(|t| t.count).sum();
    if json {
        let v = serde_json::json!({
            "file": file.display().to_string(),
            "messages": total,
            "start_ns": first,
            "end_ns": last,
            "duration_s": (last.saturating_sub(first)) as f64 * 1e-9,
            "topics": topics.iter().map(|t| serde_json::json!({"topic": t.topic, "type": t.type_name, "count": t.count, "rate_hz": t.rate_hz(), "first_ns": t.first_ns, "last_ns": t.last_ns})).collect::<Vec<_>>(),
            "complete": err.is_none(),
        });
        out!("{}", serde_json::to_string_pretty(&v)?)?;
    } else {
        out!("Files:     {}", file.display())?;
        out!("Duration:  {} s", seconds(last.saturating_sub(first), 3))?;
        out!("Start:     {} s", seconds(first, 9))?;
        out!("End:       {} s", seconds(last, 9))?;
        out!("Messages:  {total}")?;
        out!("Topics:")?;
        for t in &topics {
            out!(
                "  {:<28} {:<38} {:>9} msgs  {:>9.3} Hz  span {} s",
                t.topic,
                t.type_name,
                t.count,
                t.rate_hz(),
                seconds(t.last_ns.saturating_sub(t.first_ns), 3)
            )?;
        }
    }
    match err {
        None => Ok(()),
        Some(e) => Err(e).context("the bag could be read only up to the figures above"),
    }
}

/// Nanoseconds as seconds with `decimals` digits, from the integer: an f64 of 1.4e18 ns has
/// no digits left for the nanoseconds, and printed them as noise.
fn seconds(ns: u64, decimals: u32) -> String {
    let unit = 10u64.pow(9 - decimals.min(9));
    let rounded = ns / unit + u64::from(ns % unit >= unit / 2 && unit > 1);
    let scale = 10u64.pow(decimals.min(9));
    match decimals {
        0 => format!("{rounded}"),
        d => format!("{}.{:0width$}", rounded / scale, rounded % scale, width = d.min(9) as usize),
    }
}

fn to_json<M: RosMessage + serde::Serialize>(data: &[u8]) -> anyhow::Result<serde_json::Value> {
    Ok(serde_json::to_value(M::decode(data)?)?)
}

fn echo(file: PathBuf, topic: Option<String>, limit: Option<u64>) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mut n = 0u64;
    let mut others: std::collections::BTreeSet<std::sync::Arc<str>> = std::collections::BTreeSet::new();
    for m in BagReader::open(&file)? {
        let m = m?;
        if topic.as_deref().is_some_and(|t| t != &*m.topic) {
            if !others.contains(&m.topic) {
                others.insert(m.topic.clone());
            }
            continue;
        }
        if limit.is_some_and(|l| n >= l) {
            break;
        }
        let value = match &*m.type_name {
            t if t == Imu::TYPE_NAME => to_json::<Imu>(&m.data),
            t if t == PoseStamped::TYPE_NAME => to_json::<PoseStamped>(&m.data),
            t if t == Vector3Stamped::TYPE_NAME => to_json::<Vector3Stamped>(&m.data),
            t if t == Odometry::TYPE_NAME => to_json::<Odometry>(&m.data),
            t if t == Temperature::TYPE_NAME => to_json::<Temperature>(&m.data),
            t if t == DiagnosticArray::TYPE_NAME => to_json::<DiagnosticArray>(&m.data),
            _ => Ok(serde_json::json!({"undecoded_bytes": m.data.len()})),
        }
        .with_context(|| format!("{}: message {} on {}", file.display(), n, m.topic))?;
        writeln!(out, "{}", serde_json::json!({"topic": &*m.topic, "type": &*m.type_name, "log_time_ns": m.log_time_ns, "msg": value}))?;
        n += 1;
    }
    if let (Some(t), 0, false) = (&topic, n, limit == Some(0)) {
        anyhow::bail!("{}: no messages on {t} (topics: {})", file.display(), others.iter().map(|t| &**t).collect::<Vec<_>>().join(", "));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::seconds;

    #[test]
    fn seconds_are_printed_from_the_integer() {
        assert_eq!(seconds(1_403_636_579_758_555_508, 9), "1403636579.758555508");
        assert_eq!(seconds(2_147_400_000_000_000_000, 3), "2147400000.000");
        assert_eq!(seconds(1_999_500_000, 3), "2.000");
        assert_eq!(seconds(1_999_499_999, 3), "1.999");
        assert_eq!(seconds(0, 3), "0.000");
        assert_eq!(seconds(u64::MAX, 9), "18446744073.709551615");
        assert_eq!(seconds(u64::MAX, 3), "18446744073.710");
    }
}
