//! The actors' exploration: one decaying epsilon, or Ape-X's fixed epsilon
//! per agent (`actor.exploration`).

use crate::config::Config;

/// Exploration rate after `transitions` (across all actors): constant until
/// the replay memory is full, then linear decay.
pub fn epsilon(cfg: &Config, transitions: u64) -> f64 {
    let a = &cfg.actor;
    let start = cfg.replay.min_fill as u64;
    if transitions <= start {
        return a.eps_start;
    }
    let frac = ((transitions - start) as f64 / a.eps_decay.max(1) as f64).min(1.0);
    a.eps_start + (a.eps_end - a.eps_start) * frac
}

/// Ape-X's exploration rate of agent `i` of `n` (every host's agents):
/// base^(1 + alpha·i/(n−1)), from `base` for the first to
/// base^(1 + alpha) for the last.
pub fn per_actor_epsilon(base: f64, alpha: f64, i: usize, n: usize) -> f64 {
    let frac = if n > 1 { i.min(n - 1) as f64 / (n - 1) as f64 } else { 0.0 };
    base.powf(1.0 + alpha * frac)
}

/// The exploration rate of each agent of environment `e` (`out`, one per
/// agent) after `transitions` (across all actors): the config's one
/// schedule, or (per-actor) `eps_start` until the replay holds `min_fill`
/// and then each agent's own fixed Ape-X rate, indexed over the run's
/// agents in environment order.
pub fn agent_epsilons(cfg: &Config, e: usize, transitions: u64, out: &mut [f64]) {
    let a = &cfg.actor;
    match a.exploration {
        crate::Exploration::Decay => out.fill(epsilon(cfg, transitions)),
        crate::Exploration::PerActor if transitions <= cfg.replay.min_fill as u64 => {
            out.fill(a.eps_start)
        }
        crate::Exploration::PerActor => {
            let first = (cfg.cluster.env_offset + e) * cfg.sim.agents;
            for (i, o) in out.iter_mut().enumerate() {
                *o = per_actor_epsilon(
                    a.per_actor_base,
                    a.per_actor_alpha,
                    first + i,
                    cfg.agents_total(),
                );
            }
        }
    }
}
