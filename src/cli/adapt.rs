//! `imu-fsda adapt` (in progress).

#[derive(Debug, clap::Args)]
pub struct AdaptArgs {}

pub fn run(_args: AdaptArgs) -> anyhow::Result<()> {
    anyhow::bail!("adapt is not built yet")
}
