//! hive eval.
use anyhow::{Result, bail};
#[derive(clap::Args, Debug)]
pub struct EvalArgs {}
pub fn run(_a: EvalArgs) -> Result<()> { bail!("not built yet") }
