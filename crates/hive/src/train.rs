//! hive train.
use anyhow::{Result, bail};
#[derive(clap::Args, Debug)]
pub struct TrainArgs {}
pub fn run(_a: TrainArgs) -> Result<()> { bail!("not built yet") }
