//! `hive eval`: flies a checkpoint's greedy policy for N episodes (one per
//! agent, all in one environment) and reports the success rate.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use rotorhive_model::{Device, QNet};
pub use rotorhive_roles::eval::fly_greedy;
use rotorhive_sim::{Arena, SimConfig};

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Weights (safetensors) written by `hive train`.
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Arena to fly in.
    #[arg(long, default_value = "configs/arenas/test.toml")]
    pub arena: PathBuf,
    /// Episodes.
    #[arg(long, default_value_t = 100)]
    pub episodes: usize,
    /// Seed of the spawn positions.
    #[arg(long, default_value_t = 12345)]
    pub seed: u64,
    /// Print one JSON object as the last line.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: EvalArgs) -> Result<()> {
    if a.episodes == 0 {
        bail!("--episodes must be positive");
    }
    let net = QNet::new(0, &Device::Cpu)?;
    net.load(&a.checkpoint)?;
    let arena = Arena::load(&a.arena)?;
    let n = a.episodes;
    let st = fly_greedy(&net, SimConfig::default(), std::slice::from_ref(&arena), n, a.seed)?;
    let (success_rate, mean_reward, collisions) = (st.success_rate(), st.mean_reward, st.collisions);
    println!("{n} episodes on {}: success {:.1} %, collisions {collisions}, mean reward {mean_reward:.1}", a.arena.display(), success_rate * 100.0);
    if a.json {
        println!(
            "{}",
            serde_json::json!({ "success_rate": success_rate, "mean_reward": mean_reward, "episodes": n, "collisions": collisions, "arena": a.arena.display().to_string() })
        );
    }
    Ok(())
}
