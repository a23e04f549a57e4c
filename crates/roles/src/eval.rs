//! Greedy evaluation: a policy flown without exploration for a number of
//! episodes, the success rate and mean reward. Used by `hive eval`, by the
//! evaluator beside training and by `hive bench seeds`.

use crate::error::Result;
use rotorhive_model::QNet;
use rotorhive_sim::{Arena, Done, SimConfig, VecEnv};

/// What a greedy evaluation found.
#[derive(Debug, Clone, Copy)]
pub struct EvalStats {
    /// Episodes flown.
    pub episodes: usize,
    /// Episodes that reached the goal.
    pub successes: usize,
    /// Episodes that ended in a collision.
    pub collisions: usize,
    /// Mean episode return.
    pub mean_reward: f64,
}

impl EvalStats {
    /// Share of episodes that reached the goal.
    pub fn success_rate(&self) -> f64 {
        self.successes as f64 / self.episodes.max(1) as f64
    }
}

/// Flies `episodes` greedy episodes at once, one per agent, each agent's
/// first episode counted; with several arenas, side by side, each agent in
/// one drawn at random (the same ones for the same seed).
pub fn fly_greedy(net: &QNet, sim: SimConfig, arenas: &[Arena], episodes: usize, seed: u64) -> Result<EvalStats> {
    let n = episodes;
    let mut env = VecEnv::new_lanes(SimConfig { agents: n, ..sim }, arenas, seed)?;
    let mut result: Vec<Option<(f32, Done)>> = vec![None; n];
    let max_steps = env.config().max_steps;
    for _ in 0..max_steps + 1 {
        let actions = net.greedy(env.observations())?;
        env.step(&actions)?;
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
