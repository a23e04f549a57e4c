//! The network an actor flies: the feedforward one, or a recurrent one with
//! each agent's state (zeroed where its episode starts), whose steps leave
//! as R2D2's stored sequences ([`Sequences`]).

use rotorhive_model::{QNet, RecurrentQNet};

use super::sequences::Sequences;
use crate::config::Config;
use crate::error::Result;

/// A recurrent policy's network, states and sequence windows.
pub struct Memory {
    net: RecurrentQNet,
    /// Each agent's state now.
    state: Vec<f32>,
    /// Each agent's state before it acted on its last observation.
    pub before: Vec<f32>,
    /// The windows its steps fill.
    pub seqs: Sequences,
}

/// The network an actor flies.
pub enum Policy {
    /// The feedforward network.
    Feedforward(QNet),
    /// The recurrent network and its agents' states.
    Recurrent(Box<Memory>),
}

impl Policy {
    /// The network of `cfg` (`learner.memory`), on `device`, for `agents`
    /// agents.
    pub fn new(cfg: &Config, device: &rotorhive_model::Device, agents: usize) -> Result<Self> {
        let seed = crate::streams::network(cfg.seed);
        let (Some(width), Some(layout)) = (cfg.memory(), cfg.seq_layout()) else {
            let mut net = QNet::with_shapes(cfg.shapes(), seed, device)?;
            net.set_threads(cfg.actor.threads);
            return Ok(Policy::Feedforward(net));
        };
        Ok(Policy::Recurrent(Box::new(Memory {
            net: RecurrentQNet::new(cfg.shapes(), width, seed, device)?,
            state: vec![0.0; agents * width],
            before: vec![0.0; agents * width],
            seqs: Sequences::new(layout, cfg.learner.burn_in, agents),
        })))
    }

    /// Replaces the weights with a flat vector in canonical order.
    pub fn load_flat(&self, flat: &[f32]) -> Result<()> {
        match self {
            Policy::Feedforward(net) => net.load_flat(flat)?,
            Policy::Recurrent(m) => m.net.load_flat(flat)?,
        }
        Ok(())
    }

    /// Greedy actions on `obs`; a recurrent network first zeroes the state
    /// of every agent whose episode starts here (`dones[i] != 0`: its last
    /// one ended, and `obs` is its next one's first), keeps the states it
    /// acts from in `before`, then steps them.
    pub fn greedy(&mut self, obs: &[f32], dones: &[f32]) -> Result<Vec<u8>> {
        match self {
            Policy::Feedforward(net) => Ok(net.greedy(obs)?),
            Policy::Recurrent(m) => {
                let w = m.net.width();
                for (i, _) in dones.iter().enumerate().filter(|(_, d)| **d != 0.0) {
                    m.state[i * w..(i + 1) * w].fill(0.0);
                }
                m.before.copy_from_slice(&m.state);
                Ok(m.net.greedy(obs, &mut m.state)?)
            }
        }
    }

    /// Forgets every agent's state and open window (the sim restarted).
    pub fn restart(&mut self) {
        if let Policy::Recurrent(m) = self {
            m.state.fill(0.0);
            m.seqs.clear();
        }
    }
}
