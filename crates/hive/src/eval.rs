//! `hive eval`: flies a checkpoint's greedy policy for N episodes (one per
//! agent, all in one environment) and reports the success rate.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;
use rotorhive_model::{Device, QNet};
use rotorhive_sim::{Arena, Done, SimConfig, VecEnv};

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

/// What a greedy evaluation found.
#[derive(Debug, Clone, Copy)]
pub struct EvalStats {
    pub episodes: usize,
    pub successes: usize,
    pub collisions: usize,
    pub mean_reward: f64,
}

impl EvalStats {
    pub fn success_rate(&self) -> f64 {
        self.successes as f64 / self.episodes.max(1) as f64
    }
}

/// Flies `episodes` greedy episodes at once, one per agent, each agent's
/// first episode counted; with several arenas, side by side, each agent in
/// one drawn at random (the same ones for the same seed).
pub fn fly_greedy(net: &QNet, sim: SimConfig, arenas: &[Arena], episodes: usize, seed: u64) -> Result<EvalStats> {
    let n = episodes;
    let mut env = VecEnv::try_new_lanes(SimConfig { agents: n, ..sim }, arenas, seed)?;
    let mut result: Vec<Option<(f32, Done)>> = vec![None; n];
    let max_steps = env.config().max_steps;
    for _ in 0..max_steps + 1 {
        let actions = net.greedy(env.observations())?;
        env.step(&actions);
        for ep in env.finished() {
            result[ep.agent].get_or_insert((ep.reward, ep.done));
        }
        if result.iter().all(Option::is_some) {
            break;
        }
    }
    let done: Vec<(f32, Done)> = result.into_iter().flatten().collect();
    Ok(EvalStats {
        episodes: n,
        successes: done.iter().filter(|(_, d)| *d == Done::Goal).count(),
        collisions: done.iter().filter(|(_, d)| *d == Done::Collision).count(),
        mean_reward: done.iter().map(|(r, _)| *r as f64).sum::<f64>() / done.len().max(1) as f64,
    })
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
