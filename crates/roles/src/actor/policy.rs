//! The network an actor flies ([`PolicyNet`]) with each agent's state
//! (zeroed where its episode starts; none without memory), and, in a run
//! with memory, the R2D2 windows its steps leave through ([`Sequences`]).

use rotorhive_model::PolicyNet;

use super::sequences::Sequences;
use crate::config::Config;
use crate::error::Result;

/// The network an actor flies, its agents' states and its windows.
pub struct Policy {
    net: PolicyNet,
    /// Each agent's state now (empty without memory).
    state: Vec<f32>,
    /// Each agent's state before it acted on its last observation.
    pub before: Vec<f32>,
    /// With memory: the windows its steps fill, sent as stored sequences.
    pub seqs: Option<Sequences>,
}

impl Policy {
    /// The network of `cfg` (`learner.memory`), on `device`, for `agents`
    /// agents.
    pub fn new(cfg: &Config, device: &rotorhive_model::Device, agents: usize) -> Result<Self> {
        let seed = crate::streams::network(cfg.seed);
        let mut net = PolicyNet::new(cfg.shapes(), cfg.layers(), cfg.memory(), seed, device)?;
        net.set_threads(cfg.actor.threads);
        let width = net.state_width();
        let seqs = cfg.seq_layout().map(|l| Sequences::new(l, cfg.learner.burn_in, agents));
        Ok(Self { net, state: vec![0.0; agents * width], before: vec![0.0; agents * width], seqs })
    }

    /// Replaces the weights with a flat vector in canonical order.
    pub fn load_flat(&self, flat: &[f32]) -> Result<()> {
        Ok(self.net.load_flat(flat)?)
    }

    /// Greedy actions on `obs`; with memory, it first zeroes the state of
    /// every agent whose episode starts here (`dones[i] != 0`: its last one
    /// ended, and `obs` is its next one's first), keeps the states it acts
    /// from in `before`, then steps them.
    pub fn greedy(&mut self, obs: &[f32], dones: &[f32]) -> Result<Vec<u8>> {
        let w = self.net.state_width();
        for (i, _) in dones.iter().enumerate().filter(|(_, d)| **d != 0.0) {
            self.state[i * w..(i + 1) * w].fill(0.0);
        }
        self.before.copy_from_slice(&self.state);
        Ok(self.net.greedy(obs, &mut self.state)?)
    }

    /// Forgets every agent's state and open window (the sim restarted).
    pub fn restart(&mut self) {
        self.state.fill(0.0);
        if let Some(seqs) = self.seqs.as_mut() {
            seqs.clear();
        }
    }
}
