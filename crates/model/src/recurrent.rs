//! The recurrent Q-network (its sequence update in `recurrent/update.rs`): the feedforward
//! network's trunk (convolutions, velocity branch, `fc1`), a GRU of `width`
//! units, then the Q head on the GRU's state. It is trained on stored
//! sequences as R2D2 trains (Kapturowski et al. 2019): each sequence starts
//! from the state its actor had there (the stored state), its first
//! `burn_in` steps only warm that state up, and its other steps get n-step
//! double-DQN targets from inside the sequence.
//!
//! Two paths, as for the feedforward network: on the CPU the trunk runs on
//! the fused kernels (forward, and backward from the gradient that candle's
//! autograd gives its activations), the GRU and the head on stock candle
//! ops; the generic path runs all of it on stock ops (any device), and the
//! two give the same gradients (tested).
//!
//! With a teacher, DQfD's large-margin loss joins the TD loss on the
//! trained steps the teacher labelled (its action there), as the
//! feedforward learner's does.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use candle_core::{DType, Device, Tensor, Var};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::checkpoint;
use crate::kernels::{Rows, Weights, Workspace};
use crate::layers::trunk_params;
use crate::{Layers, ModelError, Result, Scratch, Shapes, argmax, trunk};

/// The widest GRU a network may have.
pub const MAX_WIDTH: usize = 1024;

/// Parameter names and shapes of a recurrent network for `shapes` of
/// widths `layers` with a GRU of `width` units, in canonical (flat) order:
/// the feedforward network's trunk (up to its last hidden layer), the GRU's
/// in PyTorch's layout (gates r, z, n stacked), then the Q head on the
/// GRU's state.
pub fn recurrent_params(
    shapes: Shapes,
    layers: Layers,
    width: usize,
) -> Vec<(&'static str, Vec<usize>)> {
    let mut p = trunk_params(shapes, layers);
    p.extend([
        ("gru.weight_ih", vec![3 * width, layers.out()]),
        ("gru.weight_hh", vec![3 * width, width]),
        ("gru.bias_ih", vec![3 * width]),
        ("gru.bias_hh", vec![3 * width]),
        ("fc2.weight", vec![shapes.actions, width]),
        ("fc2.bias", vec![shapes.actions]),
    ]);
    p
}

/// The recurrent Q-network's parameters, as trainable variables.
#[derive(Debug, Clone)]
pub struct RecurrentQNet {
    params: Vec<Var>,
    shapes: Shapes,
    layers: Layers,
    width: usize,
    device: Device,
    fused: bool,
    scratch: Arc<Scratch>,
}

impl RecurrentQNet {
    /// A freshly initialised network (PyTorch's defaults: uniform
    /// ±1/√fan_in, the GRU's and the head's ±1/√width), deterministic for a
    /// seed. A width of 0 or above [`MAX_WIDTH`] is refused.
    pub fn new(shapes: Shapes, width: usize, seed: u64, device: &Device) -> Result<Self> {
        Self::with_layers(shapes, Layers::DEFAULT, width, seed, device)
    }

    /// [`RecurrentQNet::new`] with a trunk of widths `layers`.
    pub fn with_layers(
        shapes: Shapes,
        layers: Layers,
        width: usize,
        seed: u64,
        device: &Device,
    ) -> Result<Self> {
        if width == 0 || width > MAX_WIDTH {
            return Err(ModelError::Shape { what: "GRU width", expected: MAX_WIDTH, got: width });
        }
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let specs = recurrent_params(shapes, layers, width);
        let trunk = layers.trunk_len();
        let mut vars = Vec::with_capacity(specs.len());
        for (i, (_, shape)) in specs.iter().enumerate() {
            let fan_in = match i {
                _ if i >= trunk => width,
                _ if i % 2 == 0 => shape[1],
                _ => specs[i - 1].1[1],
            };
            let bound = 1.0 / (fan_in as f32).sqrt();
            let n: usize = shape.iter().product();
            let data: Vec<f32> = (0..n).map(|_| rng.random_range(-bound..bound)).collect();
            vars.push(Var::from_tensor(&Tensor::from_vec(data, shape.as_slice(), device)?)?);
        }
        Ok(Self {
            params: vars,
            shapes,
            layers,
            width,
            device: device.clone(),
            fused: device.is_cpu(),
            scratch: Arc::default(),
        })
    }

    /// Whether the trunk runs on the fused CPU path (the default on the
    /// CPU).
    pub fn fused(&self) -> bool {
        self.fused
    }

    /// Chooses the fused CPU path for the trunk or the generic one.
    pub fn set_fused(&mut self, fused: bool) -> Result<()> {
        if fused && !self.device.is_cpu() {
            return Err(ModelError::Fused("it runs on the CPU only"));
        }
        self.fused = fused;
        Ok(())
    }

    /// Runs `f` on the trunk's CPU slices (read-locked for its duration):
    /// weights without a Q head, whose forward pass stops at the trunk.
    fn with_trunk<R>(&self, f: impl FnOnce(&Weights) -> Result<R>) -> Result<R> {
        crate::with_cpu_slices(&self.params[..self.layers.trunk_len()], |s| {
            f(&Weights::new(s, self.shapes, self.layers))
        })
    }

    /// The trunk's activations `[rows, out]` of flat observations on the
    /// fused path, in `ws` (kept there for [`Workspace::backward_trunk`]).
    fn trunk_fused(&self, ws: &mut Workspace, obs: &[f32]) -> Result<Tensor> {
        let len = self.shapes.obs_len();
        let n = self.with_trunk(|w| ws.forward(w, &[Rows::packed(obs, len)]))?;
        let out = ws.trunk_out(n, self.layers);
        Ok(Tensor::from_slice(out, (n, self.layers.out()), &self.device)?)
    }

    /// The trunk's activations `[rows, out]` of flat observations, on
    /// either path (differentiable on the generic one).
    fn features(&self, obs: &[f32]) -> Result<Tensor> {
        let len = self.shapes.obs_len();
        if !self.fused {
            let o = Tensor::from_slice(obs, (obs.len() / len, len), &self.device)?;
            return trunk(&self.params, self.shapes, self.layers, &o);
        }
        let mut ws = self.scratch.take();
        let feat = self.trunk_fused(&mut ws, obs);
        self.scratch.put(ws);
        feat
    }

    /// The observation and action shapes the network takes and gives.
    pub fn shapes(&self) -> Shapes {
        self.shapes
    }

    /// The trunk's widths.
    pub fn layers(&self) -> Layers {
        self.layers
    }

    /// Units of the GRU: floats of one agent's state.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Trainable variables, in canonical order.
    pub fn vars(&self) -> &[Var] {
        &self.params
    }

    /// Floats in its flat weight vector.
    pub fn num_params(&self) -> usize {
        recurrent_params(self.shapes, self.layers, self.width)
            .iter()
            .map(|(_, s)| s.iter().product::<usize>())
            .sum()
    }

    fn p(&self, i: usize) -> &Tensor {
        self.params[i].as_tensor()
    }

    /// One GRU step from the input's projection `xp` (`W_ih x + b_ih`,
    /// `[B, 3W]`) and the state `h` (`[B, W]`): the new state.
    fn cell(&self, xp: &Tensor, h: &Tensor) -> Result<Tensor> {
        let w = self.width;
        let g = self.layers.trunk_len();
        let hp = h.matmul(&self.p(g + 1).t()?)?.broadcast_add(self.p(g + 3))?;
        // σ(x) = 1 / (1 + e^−x): candle-core has no sigmoid of its own.
        let sigmoid =
            |x: Tensor| -> Result<Tensor> { Ok(x.neg()?.exp()?.affine(1.0, 1.0)?.recip()?) };
        let r = sigmoid((xp.narrow(1, 0, w)? + hp.narrow(1, 0, w)?)?)?;
        let z = sigmoid((xp.narrow(1, w, w)? + hp.narrow(1, w, w)?)?)?;
        let n = (xp.narrow(1, 2 * w, w)? + (r * hp.narrow(1, 2 * w, w)?)?)?.tanh()?;
        // (1 − z) n + z h
        Ok((&n + (z * (h - &n)?)?)?)
    }

    /// Q-values `[T, B, actions]` and the last state `[B, W]` of `B`
    /// sequences of `T` steps: observations `obs` `[T, B, obs_len]` (step
    /// major), the state `h0` `[B, W]` before the first step, and `keep`
    /// `[T, B]`: 1 where an agent's state carries into the step, 0 where it
    /// is zeroed first (an episode starts there).
    pub fn unroll(&self, obs: &Tensor, h0: &Tensor, keep: &Tensor) -> Result<(Tensor, Tensor)> {
        let (t, b, len) = obs.dims3()?;
        let feat = if self.fused {
            self.features(&obs.flatten_all()?.to_vec1::<f32>()?)?
        } else {
            trunk(&self.params, self.shapes, self.layers, &obs.reshape((t * b, len))?)?
        };
        self.unroll_features(&feat, t, b, h0, keep)
    }

    /// [`RecurrentQNet::unroll`] from the trunk's activations `feat`
    /// `[T × B, out]` (step major).
    fn unroll_features(
        &self,
        feat: &Tensor,
        t: usize,
        b: usize,
        h0: &Tensor,
        keep: &Tensor,
    ) -> Result<(Tensor, Tensor)> {
        let (w, g) = (self.width, self.layers.trunk_len());
        let xp = feat.matmul(&self.p(g).t()?)?.broadcast_add(self.p(g + 2))?;
        let xp = xp.reshape((t, b, 3 * w))?;
        let mut h = h0.clone();
        let mut states = Vec::with_capacity(t);
        for s in 0..t {
            h = h.broadcast_mul(&keep.get(s)?.unsqueeze(1)?)?;
            h = self.cell(&xp.get(s)?, &h)?;
            states.push(h.clone());
        }
        let hs = Tensor::stack(&states, 0)?.reshape((t * b, w))?;
        let q = hs.matmul(&self.p(g + 4).t()?)?.broadcast_add(self.p(g + 5))?;
        Ok((q.reshape((t, b, self.shapes.actions))?, h))
    }

    /// Q-values (`B × actions` floats) of one step's observations (`B ×
    /// obs_len`), each agent's state (`B × width`) carried to the next step
    /// in place. The caller zeroes an agent's state where its episode
    /// starts.
    pub fn step(&self, obs: &[f32], state: &mut [f32]) -> Result<Vec<f32>> {
        let (len, w) = (self.shapes.obs_len(), self.width);
        let b = obs.len() / len;
        if obs.is_empty() || b * len != obs.len() {
            return Err(ModelError::Shape {
                what: "observation batch",
                expected: len,
                got: obs.len(),
            });
        }
        if state.len() != b * w {
            return Err(ModelError::Shape {
                what: "state batch",
                expected: b * w,
                got: state.len(),
            });
        }
        let o = Tensor::from_slice(obs, (1, b, len), &self.device)?;
        let h = Tensor::from_slice(state, (b, w), &self.device)?;
        let keep = Tensor::ones((1, b), DType::F32, &self.device)?;
        let (q, h) = self.unroll(&o, &h, &keep)?;
        state.copy_from_slice(&h.flatten_all()?.to_vec1::<f32>()?);
        Ok(q.flatten_all()?.to_vec1::<f32>()?)
    }

    /// Greedy actions of one step (see [`RecurrentQNet::step`]).
    pub fn greedy(&self, obs: &[f32], state: &mut [f32]) -> Result<Vec<u8>> {
        let q = self.step(obs, state)?;
        Ok(q.chunks(self.shapes.actions).map(|c| argmax(c) as u8).collect())
    }

    /// The weights by name.
    pub fn named(&self) -> HashMap<String, Tensor> {
        recurrent_params(self.shapes, self.layers, self.width)
            .iter()
            .zip(&self.params)
            .map(|((n, _), v)| (n.to_string(), v.as_tensor().clone()))
            .collect()
    }

    /// Saves the weights as safetensors, the header naming the memory
    /// (`memory = "gru:WIDTH"`) with the shapes, and `extra` entries.
    pub fn save(&self, path: &Path, extra: &[(&str, String)]) -> Result<()> {
        let mut meta = self.metadata();
        meta.extend(extra.iter().map(|(k, v)| (k.to_string(), v.clone())));
        checkpoint::write(path, self.named(), meta)
    }

    /// What its checkpoints' headers say of it.
    fn metadata(&self) -> HashMap<String, String> {
        checkpoint::network_metadata(self.shapes, self.layers, Some(self.width))
    }

    /// Loads weights saved by [`RecurrentQNet::save`]; a checkpoint of
    /// another memory (a feedforward network's, another width) or other
    /// shapes is refused by name.
    pub fn load(&self, path: &Path) -> Result<()> {
        let tensors = checkpoint::read(path, &self.device, &self.metadata())?;
        let specs = recurrent_params(self.shapes, self.layers, self.width);
        let file = path.display().to_string();
        checkpoint::load_vars(&specs, &self.params, &tensors, &file, &self.device)
    }

    /// Writes the network as an ONNX model: inputs `depth` `(B, frames, 32,
    /// 32)`, `velocity` `(B, scalars)` and `state` `(B, width)`, outputs `q`
    /// `(B, actions)` and `next_state` `(B, width)`, one step; the
    /// checkpoint's header entries (and `extra`) as metadata properties.
    pub fn to_onnx(&self, path: &Path, extra: &[(&str, String)]) -> Result<()> {
        let mut meta: Vec<(String, String)> = self.metadata().into_iter().collect();
        meta.extend(extra.iter().map(|(k, v)| (k.to_string(), v.clone())));
        meta.sort();
        let (shapes, layers, width) = (self.shapes, self.layers, Some(self.width));
        let bytes = crate::onnx::model(&self.named(), shapes, layers, width, &meta)?;
        std::fs::write(path, bytes).map_err(|e| ModelError::Checkpoint {
            file: path.display().to_string(),
            message: format!("cannot write: {e}"),
        })
    }

    /// Replaces the weights with a flat vector in canonical order (as the
    /// weights channel carries them).
    pub fn load_flat(&self, flat: &[f32]) -> Result<()> {
        if flat.len() != self.num_params() {
            return Err(ModelError::Shape {
                what: "recurrent weights",
                expected: self.num_params(),
                got: flat.len(),
            });
        }
        let mut off = 0;
        let specs = recurrent_params(self.shapes, self.layers, self.width);
        for (v, (_, shape)) in self.params.iter().zip(specs) {
            let n: usize = shape.iter().product();
            v.set(&Tensor::from_slice(&flat[off..off + n], shape.as_slice(), &self.device)?)?;
            off += n;
        }
        Ok(())
    }

    /// Writes the weights, flat in canonical order, into `into`.
    pub fn write_flat(&self, into: &mut [f32]) -> Result<()> {
        if into.len() != self.num_params() {
            return Err(ModelError::Shape {
                what: "recurrent weights buffer",
                expected: self.num_params(),
                got: into.len(),
            });
        }
        let mut off = 0;
        for v in &self.params {
            let p = v.as_tensor().flatten_all()?.to_vec1::<f32>()?;
            into[off..off + p.len()].copy_from_slice(&p);
            off += p.len();
        }
        Ok(())
    }

    /// Copies another network's weights into this one (of the same shapes
    /// and width).
    pub fn copy_from(&self, other: &RecurrentQNet) -> Result<()> {
        if other.shapes != self.shapes || other.layers != self.layers || other.width != self.width {
            return Err(ModelError::Shape {
                what: "recurrent network to copy",
                expected: self.num_params(),
                got: other.num_params(),
            });
        }
        for (a, b) in self.params.iter().zip(&other.params) {
            a.set(&b.as_tensor().copy()?)?;
        }
        Ok(())
    }
}

mod batch;
mod update;
pub use batch::SeqBatch;
pub use update::{SeqConfig, SeqDqn};

#[cfg(test)]
mod tests;
