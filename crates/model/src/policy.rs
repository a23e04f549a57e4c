//! One network to fly with: [`PolicyNet`], the feedforward Q-network or
//! (with memory) the recurrent one behind one type, so that the actor, the
//! evaluations, `hive eval`, `hive play` and `hive export` hold a network
//! without asking which kind it is. A network with memory carries each
//! agent's state through the caller's `state` (`state_width` floats an
//! agent, zeroed where its episode starts); the feedforward one has none
//! (`state_width` 0, `state` empty).

use std::collections::HashMap;
use std::path::Path;

use candle_core::Tensor;

use crate::{
    Device, Layers, QNet, RecurrentQNet, Result, Shapes, checkpoint_layers, checkpoint_memory,
    checkpoint_shapes, params, recurrent_params,
};

/// The two networks a run may train.
enum Net {
    Feedforward(QNet),
    Recurrent(RecurrentQNet),
}

/// A run's policy network: feedforward, or recurrent with a GRU of
/// `memory` units.
pub struct PolicyNet(Net);

impl PolicyNet {
    /// A freshly initialised network of `shapes` and widths `layers` from
    /// `seed` on `device`, recurrent with a GRU of `memory` units where it
    /// is given.
    pub fn new(
        shapes: Shapes,
        layers: Layers,
        memory: Option<usize>,
        seed: u64,
        device: &Device,
    ) -> Result<Self> {
        Ok(Self(match memory {
            Some(w) => Net::Recurrent(RecurrentQNet::with_layers(shapes, layers, w, seed, device)?),
            None => Net::Feedforward(QNet::with_layers(shapes, layers, seed, device)?),
        }))
    }

    /// The network a checkpoint holds (its header's shapes, widths and
    /// memory), on the CPU.
    pub fn load(path: &Path) -> Result<Self> {
        let (shapes, layers) = (checkpoint_shapes(path)?, checkpoint_layers(path)?);
        let net = Self::new(shapes, layers, checkpoint_memory(path)?, 0, &Device::Cpu)?;
        net.load_checkpoint(path)?;
        Ok(net)
    }

    /// The GRU's width of a network with memory; `None` for the
    /// feedforward one.
    pub fn memory(&self) -> Option<usize> {
        match &self.0 {
            Net::Feedforward(_) => None,
            Net::Recurrent(n) => Some(n.width()),
        }
    }

    /// Floats of its flat weights (as the weights channel carries them).
    pub fn num_params(&self) -> usize {
        match &self.0 {
            Net::Feedforward(n) => n.num_params(),
            Net::Recurrent(n) => n.num_params(),
        }
    }

    /// Floats of state an agent carries (0 without memory).
    pub fn state_width(&self) -> usize {
        self.memory().unwrap_or(0)
    }

    /// The observation and action shapes it takes and gives.
    pub fn shapes(&self) -> Shapes {
        match &self.0 {
            Net::Feedforward(n) => n.shapes(),
            Net::Recurrent(n) => n.shapes(),
        }
    }

    /// Its widths.
    pub fn layers(&self) -> Layers {
        match &self.0 {
            Net::Feedforward(n) => n.layers(),
            Net::Recurrent(n) => n.layers(),
        }
    }

    /// Its parameters' names and shapes, in canonical (flat) order.
    pub fn params(&self) -> Vec<(&'static str, Vec<usize>)> {
        match &self.0 {
            Net::Feedforward(n) => params(n.shapes(), n.layers()),
            Net::Recurrent(n) => recurrent_params(n.shapes(), n.layers(), n.width()),
        }
    }

    /// The weights by name.
    pub fn named(&self) -> HashMap<String, Tensor> {
        match &self.0 {
            Net::Feedforward(n) => n.named(),
            Net::Recurrent(n) => n.named(),
        }
    }

    /// Threads of its inference (the feedforward network's data-parallel
    /// shards; the recurrent one runs as it is).
    pub fn set_threads(&mut self, threads: usize) {
        if let Net::Feedforward(n) = &mut self.0 {
            n.set_threads(threads);
        }
    }

    /// Loads a checkpoint into this network (of other shapes or another
    /// memory: refused by name).
    pub fn load_checkpoint(&self, path: &Path) -> Result<()> {
        match &self.0 {
            Net::Feedforward(n) => n.load(path),
            Net::Recurrent(n) => n.load(path),
        }
    }

    /// Replaces the weights with a flat vector in canonical order (as the
    /// weights channel carries them).
    pub fn load_flat(&self, flat: &[f32]) -> Result<()> {
        match &self.0 {
            Net::Feedforward(n) => n.load_flat(flat),
            Net::Recurrent(n) => n.load_flat(flat),
        }
    }

    /// Saves the weights as a checkpoint with `tags` in its header.
    pub fn save(&self, path: &Path, tags: &[(&str, String)]) -> Result<()> {
        match &self.0 {
            Net::Feedforward(n) => n.save_with(path, tags),
            Net::Recurrent(n) => n.save(path, tags),
        }
    }

    /// Writes the network as an ONNX model (one with memory as a single
    /// step that takes and gives the state), `extra` in its metadata.
    pub fn to_onnx(&self, path: &Path, extra: &[(&str, String)]) -> Result<()> {
        match &self.0 {
            Net::Feedforward(n) => n.to_onnx(path, extra),
            Net::Recurrent(n) => n.to_onnx(path, extra),
        }
    }

    /// Q-values of one step's observations, stepping `state` (each agent's
    /// `state_width` floats, in place; sized with zeros when empty).
    pub fn q_values(&self, obs: &[f32], state: &mut Vec<f32>) -> Result<Vec<f32>> {
        match &self.0 {
            Net::Feedforward(n) => n.q_values(obs),
            Net::Recurrent(n) => {
                self.size_state(obs, state);
                n.step(obs, state)
            }
        }
    }

    /// Greedy actions of one step's observations, stepping `state` as
    /// [`PolicyNet::q_values`] does.
    pub fn greedy(&self, obs: &[f32], state: &mut Vec<f32>) -> Result<Vec<u8>> {
        match &self.0 {
            Net::Feedforward(n) => n.greedy(obs),
            Net::Recurrent(n) => {
                self.size_state(obs, state);
                n.greedy(obs, state)
            }
        }
    }

    /// Zeros for every agent of `obs` where `state` is empty; a state of
    /// another size is left for the network to refuse.
    fn size_state(&self, obs: &[f32], state: &mut Vec<f32>) {
        if state.is_empty() {
            let agents = obs.len() / self.shapes().obs_len().max(1);
            state.resize(agents * self.state_width(), 0.0);
        }
    }
}

impl std::fmt::Debug for PolicyNet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (shapes, layers, memory) = (self.shapes(), self.layers().name(), self.memory());
        write!(f, "PolicyNet {{ shapes: {shapes:?}, layers: {layers}, memory: {memory:?} }}")
    }
}
