//! The Q-network and the DQN update, on candle.
//!
//! The network is the design's: conv 2→16 (6×6, stride 2) → conv 16→32 (3×3)
//! → max-pool 2 → 1152 features; velocity 3→16 (with a goal: velocity and
//! goal, 6→16); concat → 64 → one Q-value per action (2, or 3 with hold).
//! The observation and action shapes come from the run's config
//! ([`Shapes`]), and so do the widths ([`Layers`]: the convolutions'
//! channels, one to three hidden layers).
//!
//! Two paths compute the same function and gradients:
//! - the fused CPU path ([`kernels`]): forward and hand-written backward over
//!   raw slices in a reused workspace, convolutions as im2col plus one GEMM,
//!   activations channels-last, pooling with its argmax kept, the TD-Huber
//!   loss's gradient on the taken actions, Adam in place; the image gets no
//!   gradient;
//! - the generic path: stock candle ops (`conv2d`, `matmul`, reductions) and
//!   candle's autograd, on any device (CUDA with the `cuda` feature). Pooling
//!   there is a reshape and two `max` reductions, whose gradient is exact
//!   (candle-nn 0.11.1's `max_pool2d` backward is 4× too small).
//!
//! Weights travel as one flat `f32` vector in a canonical order ([`params`]) and
//! are saved as safetensors.

mod checkpoint;
mod dqn;
mod kernels;
mod layers;
mod onnx;
mod ops;
mod optimiser;
mod policy;
mod recurrent;
mod teaching;

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

pub use candle_core::Device;
use candle_core::{Tensor, Var};
pub use checkpoint::{
    CHECKPOINT_LAYOUT, checkpoint_entry, checkpoint_layers, checkpoint_memory, checkpoint_metadata,
    checkpoint_shapes, depth_name, memory_name,
};
pub use dqn::{Dqn, DqnConfig, UpdateStats, UpdateTiming};
use kernels::{Rows, Weights, Workspace};
pub use layers::{Layers, MAX_HIDDEN, MAX_LAYER_WIDTH, num_params, params};
pub use policy::PolicyNet;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
pub use recurrent::{MAX_WIDTH, RecurrentQNet, SeqBatch, SeqConfig, SeqDqn, recurrent_params};
pub use teaching::Teaching;

/// Where a network runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceKind {
    /// The CPU.
    Cpu,
    /// GPU 0 through CUDA (only in a build with the `cuda` feature).
    Cuda,
}

/// The candle device of `kind`; CUDA in a build without it is refused.
pub fn device(kind: DeviceKind) -> Result<Device> {
    match kind {
        DeviceKind::Cpu => Ok(Device::Cpu),
        DeviceKind::Cuda if cfg!(feature = "cuda") => Ok(Device::new_cuda(0)?),
        DeviceKind::Cuda => {
            Err(ModelError::Device("device \"cuda\" needs a build with `--features cuda`"))
        }
    }
}

// The observation and transition layout, defined once in `rotorhive-msg`
// (without its iceoryx2 feature): depth side, frames, velocity components,
// floats per observation, actions, floats per transition.
pub use rotorhive_msg::{FRAMES, Shapes};

// The kernels (the widths are [`Layers`]'s, the maps' sizes
// [`layers::Geometry`]'s): conv1 6×6 stride 2, conv2 3×3, max-pool 2.
const K1: usize = 6;
const S1: usize = 2;
const K2: usize = 3;

/// The trunk (every layer before the Q head, the first
/// [`Layers::trunk_len`] of `p` in canonical order) on stock candle ops: the
/// last hidden layer's activations `[B, out]` of observations `[B,
/// obs_len]`. The feedforward network puts its Q head on top, the recurrent
/// one its GRU.
pub(crate) fn trunk(p: &[Var], shapes: Shapes, layers: Layers, obs: &Tensor) -> Result<Tensor> {
    let p = |i: usize| p[i].as_tensor();
    let b = obs.dim(0)?;
    let frames = shapes.frames;
    let [c1, c2] = layers.conv();
    let g = layers::Geometry::of(shapes);
    let img = obs.narrow(1, 0, shapes.obs_depth())?.contiguous()?.reshape((b, frames, g.h, g.w))?;
    let w1 = p(0).reshape((c1, frames, K1, K1))?;
    let x = img.conv2d(&w1, 0, S1, 1, 1)?.broadcast_add(&p(1).reshape((1, c1, 1, 1))?)?.relu()?;
    let w2 = p(2).reshape((c2, K2, K2, c1))?.permute((0, 3, 1, 2))?.contiguous()?;
    let x = x.conv2d(&w2, 0, 1, 1, 1)?.broadcast_add(&p(3).reshape((1, c2, 1, 1))?)?.relu()?;
    // 2×2 max-pool as two reductions over a split view (an odd last row or
    // column dropped, as the fused path and ONNX drop it), then channels-last.
    let x = x
        .narrow(2, 0, 2 * g.hp)?
        .narrow(3, 0, 2 * g.wp)?
        .contiguous()?
        .reshape((b, c2, g.hp, 2, g.wp, 2))?
        .max(5)?
        .max(3)?
        .permute((0, 2, 3, 1))?
        .reshape((b, layers.pooled(shapes)))?;
    // A column slice is a strided view: candle's CUDA matmul takes only
    // contiguous operands (a GPU run died here at its first update,
    // the H100 machine of `docs/results/performance.md`), so it is copied out first.
    let v = obs.narrow(1, shapes.obs_depth(), shapes.scalars)?.contiguous()?;
    let v = v.matmul(&p(4).t()?)?.broadcast_add(p(5))?.relu()?;
    let mut h = Tensor::cat(&[&x, &v], 1)?;
    for k in 0..layers.hidden().len() {
        h = h.matmul(&p(6 + 2 * k).t()?)?.broadcast_add(p(7 + 2 * k))?.relu()?;
    }
    Ok(h)
}

/// Runs `f` on the CPU slices of `vars` (each read-locked for its
/// duration): the fused path's view of a network's parameters.
pub(crate) fn with_cpu_slices<R>(
    vars: &[Var],
    f: impl FnOnce(&[&[f32]]) -> Result<R>,
) -> Result<R> {
    let guards: Vec<_> = vars.iter().map(|v| v.as_tensor().storage_and_layout()).collect();
    let mut slices = Vec::with_capacity(guards.len());
    for (storage, layout) in &guards {
        let candle_core::Storage::Cpu(cpu) = &**storage else {
            return Err(ModelError::Fused("it runs on the CPU only"));
        };
        let Some((start, end)) = layout.contiguous_offsets() else {
            return Err(ModelError::Fused("a parameter is not contiguous"));
        };
        slices.push(&cpu.as_slice::<f32>()?[start..end]);
    }
    f(&slices)
}

/// Errors of the model layer.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A candle operation failed (candle's error, in the text; not
    /// `source()`, so `{:#}` names it once).
    #[error("tensor operation failed: {0}")]
    Candle(candle_core::Error),
    /// A checkpoint or weight vector does not fit the network.
    #[error("checkpoint {file}: {message}")]
    Checkpoint {
        /// The file (or `weights message`).
        file: String,
        /// What is wrong.
        message: String,
    },
    /// A device that cannot be used.
    #[error("{0}")]
    Device(&'static str),
    /// Network widths that cannot be built.
    #[error("network widths: {0}")]
    Layers(String),
    /// An optimiser step before a backward pass gave every parameter its
    /// gradient.
    #[error("no gradient: {0}")]
    NoGradient(&'static str),
    /// The fused CPU path cannot take these parameters.
    #[error("the fused path: {0}")]
    Fused(&'static str),
    /// A worker thread's scratch space was left poisoned by a panic.
    #[error("a workspace was poisoned by a panic")]
    Poisoned,
    /// A batch has the wrong size.
    #[error("{what}: expected {expected} floats, got {got}")]
    Shape {
        /// What was passed.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
}

impl From<candle_core::Error> for ModelError {
    fn from(e: candle_core::Error) -> Self {
        ModelError::Candle(e)
    }
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, ModelError>;

/// Workspaces of the fused path, one per concurrent forward pass, reused
/// across calls (and shared by clones of a network).
#[derive(Default)]
struct Scratch(Mutex<Vec<Workspace>>);

impl std::fmt::Debug for Scratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Scratch")
    }
}

impl Scratch {
    fn take(&self) -> Workspace {
        self.0.lock().ok().and_then(|mut v| v.pop()).unwrap_or_default()
    }

    fn put(&self, ws: Workspace) {
        if let Ok(mut v) = self.0.lock() {
            v.push(ws);
        }
    }
}

/// The Q-network's parameters, as trainable variables.
#[derive(Debug, Clone)]
pub struct QNet {
    params: Vec<Var>,
    shapes: Shapes,
    layers: Layers,
    scratch: Arc<Scratch>,
    device: Device,
    fused: bool,
    threads: usize,
}

impl QNet {
    /// A freshly initialised network of the paper's task's shapes
    /// ([`Shapes::PAPER`]); see [`QNet::with_shapes`].
    pub fn new(seed: u64, device: &Device) -> Result<Self> {
        Self::with_shapes(Shapes::PAPER, seed, device)
    }

    /// A freshly initialised network for observations and actions of
    /// `shapes` (PyTorch's default uniform ±1/√fan_in), deterministic for a
    /// seed.
    pub fn with_shapes(shapes: Shapes, seed: u64, device: &Device) -> Result<Self> {
        Self::with_layers(shapes, Layers::DEFAULT, seed, device)
    }

    /// [`QNet::with_shapes`] with the widths `layers`.
    pub fn with_layers(shapes: Shapes, layers: Layers, seed: u64, device: &Device) -> Result<Self> {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let specs = params(shapes, layers);
        let mut vars = Vec::with_capacity(specs.len());
        for (i, (_, shape)) in specs.iter().enumerate() {
            // A bias shares the fan-in of the weight before it.
            let fan_in = if i % 2 == 0 { shape[1] } else { specs[i - 1].1[1] };
            let bound = 1.0 / (fan_in as f32).sqrt();
            let n: usize = shape.iter().product();
            let data: Vec<f32> = (0..n).map(|_| rng.random_range(-bound..bound)).collect();
            vars.push(Var::from_tensor(&Tensor::from_vec(data, shape.as_slice(), device)?)?);
        }
        Ok(Self {
            params: vars,
            shapes,
            layers,
            scratch: Arc::default(),
            device: device.clone(),
            fused: device.is_cpu(),
            threads: 1,
        })
    }

    /// The observation and action shapes the network takes and gives.
    pub fn shapes(&self) -> Shapes {
        self.shapes
    }

    /// Its widths.
    pub fn layers(&self) -> Layers {
        self.layers
    }

    /// Floats in its flat weight vector.
    pub fn num_params(&self) -> usize {
        num_params(self.shapes, self.layers)
    }

    /// The device the network lives on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Trainable variables, in canonical order.
    pub fn vars(&self) -> &[Var] {
        &self.params
    }

    fn p(&self, i: usize) -> &Tensor {
        self.params[i].as_tensor()
    }

    /// Whether the fused CPU path is in use (the default on the CPU).
    pub fn fused(&self) -> bool {
        self.fused
    }

    /// Chooses the fused CPU path or the generic one (tests and benches
    /// compare the two; only the generic path runs off the CPU).
    pub fn set_fused(&mut self, fused: bool) -> Result<()> {
        if fused && !self.device.is_cpu() {
            return Err(ModelError::Fused("it runs on the CPU only"));
        }
        self.fused = fused;
        Ok(())
    }

    /// Threads for batched inference on the fused path: batches of 16 or
    /// more are split into this many data-parallel shards.
    pub fn set_threads(&mut self, threads: usize) {
        self.threads = threads.max(1);
    }

    /// Q-values `[B, actions]` of observations `[B, obs_len]`.
    pub fn forward(&self, obs: &Tensor) -> Result<Tensor> {
        if self.fused { self.forward_fused(obs) } else { self.forward_generic(obs) }
    }

    fn forward_fused(&self, obs: &Tensor) -> Result<Tensor> {
        let b = obs.dim(0)?;
        let q = self.q_values(&obs.flatten_all()?.to_vec1::<f32>()?)?;
        Ok(Tensor::from_vec(q, (b, self.shapes.actions), &self.device)?)
    }

    /// Runs `f` on the parameters' CPU slices (read-locked for its duration).
    pub(crate) fn with_weights<R>(&self, f: impl FnOnce(&Weights) -> Result<R>) -> Result<R> {
        with_cpu_slices(&self.params, |s| f(&Weights::new(s, self.shapes, self.layers)))
    }

    /// The same network with stock candle ops (channels-first `conv2d`),
    /// differentiable by candle's autograd.
    pub(crate) fn forward_generic(&self, obs: &Tensor) -> Result<Tensor> {
        let h = self.features(obs)?;
        let head = self.layers.trunk_len();
        Ok(h.matmul(&self.p(head).t()?)?.broadcast_add(self.p(head + 1))?)
    }

    /// The last hidden layer's activations `[B, out]` of observations `[B,
    /// obs_len]`, on stock candle ops (the generic path up to the Q head):
    /// what the network has learned to see, for a probe that reuses it.
    pub fn features(&self, obs: &Tensor) -> Result<Tensor> {
        trunk(&self.params, self.shapes, self.layers, obs)
    }

    /// Q-values of a flat batch of observations (`n × obs_len` floats); on
    /// the fused path, batches of 16 or more are split over the threads.
    pub fn q_values(&self, obs: &[f32]) -> Result<Vec<f32>> {
        let n = obs.len() / self.shapes.obs_len();
        let shards = if self.fused { self.threads.min(n / 8).max(1) } else { 1 };
        self.q_values_sharded(obs, shards)
    }

    /// [`QNet::q_values`] in `shards` data-parallel parts.
    pub fn q_values_sharded(&self, obs: &[f32], shards: usize) -> Result<Vec<f32>> {
        let (len, actions) = (self.shapes.obs_len(), self.shapes.actions);
        if !obs.len().is_multiple_of(len) || obs.is_empty() {
            return Err(ModelError::Shape {
                what: "observation batch",
                expected: len,
                got: obs.len(),
            });
        }
        let n = obs.len() / len;
        if !self.fused {
            let t = Tensor::from_slice(obs, (n, len), &self.device)?;
            return Ok(self.forward_generic(&t)?.flatten_all()?.to_vec1::<f32>()?);
        }
        let parts: Vec<&[f32]> = obs.chunks(n.div_ceil(shards.max(1)) * len).collect();
        let mut spaces: Vec<Mutex<Workspace>> =
            parts.iter().map(|_| Mutex::new(self.scratch.take())).collect();
        let done = self.with_weights(|w| {
            ops::sharded(parts.len(), |i| {
                let mut ws = spaces[i].lock().map_err(kernels::poisoned)?;
                ws.forward(w, &[Rows::packed(parts[i], len)])
            })
            .into_iter()
            .collect::<Result<Vec<usize>>>()
        });
        let mut q = Vec::with_capacity(n * actions);
        for (ws, rows) in spaces.iter_mut().zip(done.as_deref().unwrap_or(&[])) {
            if let Ok(ws) = ws.get_mut() {
                q.extend_from_slice(&ws.q[..rows * actions]);
            }
        }
        for ws in spaces {
            self.scratch.put(ws.into_inner().unwrap_or_default());
        }
        done?;
        Ok(q)
    }

    /// Greedy actions of a flat batch of observations.
    pub fn greedy(&self, obs: &[f32]) -> Result<Vec<u8>> {
        let q = self.q_values(obs)?;
        Ok(q.chunks(self.shapes.actions).map(|c| argmax(c) as u8).collect())
    }

    /// The weights as one flat vector in canonical order.
    pub fn to_flat(&self) -> Result<Vec<f32>> {
        let mut out = Vec::with_capacity(self.num_params());
        for v in &self.params {
            out.extend(v.as_tensor().flatten_all()?.to_vec1::<f32>()?);
        }
        Ok(out)
    }

    /// Writes the weights, flat in canonical order, into `into` (one copy
    /// from each variable's storage on the CPU).
    pub fn write_flat(&self, into: &mut [f32]) -> Result<()> {
        if into.len() != self.num_params() {
            return Err(ModelError::Shape {
                what: "weights buffer",
                expected: self.num_params(),
                got: into.len(),
            });
        }
        if !self.device.is_cpu() {
            into.copy_from_slice(&self.to_flat()?);
            return Ok(());
        }
        self.with_weights(|w| {
            let mut off = 0;
            for p in &w.p {
                into[off..off + p.len()].copy_from_slice(p);
                off += p.len();
            }
            Ok(())
        })
    }

    /// Replaces the weights with a flat vector in canonical order (in place
    /// on the CPU: one copy into each variable's storage).
    pub fn load_flat(&self, flat: &[f32]) -> Result<()> {
        if flat.len() != self.num_params() {
            return Err(ModelError::Shape {
                what: "weights",
                expected: self.num_params(),
                got: flat.len(),
            });
        }
        let mut off = 0;
        for (v, (_, shape)) in self.params.iter().zip(params(self.shapes, self.layers)) {
            let n: usize = shape.iter().product();
            let part = &flat[off..off + n];
            if self.device.is_cpu() {
                v.as_tensor().inplace_op1(&ops::CopyIn(part))?;
            } else {
                v.set(&Tensor::from_slice(part, shape.as_slice(), &self.device)?)?;
            }
            off += n;
        }
        Ok(())
    }

    /// Copies another network's weights into this one (of the same shapes
    /// and widths).
    pub fn copy_from(&self, other: &QNet) -> Result<()> {
        if other.shapes != self.shapes || other.layers != self.layers {
            return Err(ModelError::Shape {
                what: "network to copy",
                expected: self.num_params(),
                got: other.num_params(),
            });
        }
        for (a, b) in self.params.iter().zip(&other.params) {
            a.set(&b.as_tensor().copy()?)?;
        }
        Ok(())
    }

    /// The weights by name.
    pub fn named(&self) -> HashMap<String, Tensor> {
        params(self.shapes, self.layers)
            .iter()
            .zip(&self.params)
            .map(|((n, _), v)| (n.to_string(), v.as_tensor().clone()))
            .collect()
    }

    /// Loads weights by name, checking every name and shape.
    pub fn load_named(&self, tensors: &HashMap<String, Tensor>, file: &str) -> Result<()> {
        let specs = params(self.shapes, self.layers);
        checkpoint::load_vars(&specs, &self.params, tensors, file, &self.device)
    }

    /// Saves the weights as safetensors, with the layout's description in
    /// the header (see [`checkpoint_metadata`]).
    pub fn save(&self, path: &Path) -> Result<()> {
        self.save_with(path, &[])
    }

    /// [`QNet::save`] with more header entries (the learner adds the hash
    /// of its run's config).
    pub fn save_with(&self, path: &Path, extra: &[(&str, String)]) -> Result<()> {
        let mut meta = self.metadata();
        meta.extend(extra.iter().map(|(k, v)| (k.to_string(), v.clone())));
        checkpoint::write(path, self.named(), meta)
    }

    /// Writes the network as an ONNX model (see `onnx.rs`): inputs `depth`
    /// `(B, frames, rows, cols)` (2 × 32 × 32 in the paper's task) and `velocity` `(B, scalars)` (3, or 6 with a goal),
    /// output `q` `(B, actions)`; the checkpoint's header entries (and
    /// `extra`) as metadata properties.
    pub fn to_onnx(&self, path: &Path, extra: &[(&str, String)]) -> Result<()> {
        let mut meta: Vec<(String, String)> = self.metadata().into_iter().collect();
        meta.extend(extra.iter().map(|(k, v)| (k.to_string(), v.clone())));
        meta.sort();
        let bytes = onnx::model(&self.named(), self.shapes, self.layers, None, &meta)?;
        std::fs::write(path, bytes).map_err(|e| ModelError::Checkpoint {
            file: path.display().to_string(),
            message: format!("cannot write: {e}"),
        })
    }

    /// What its checkpoints' headers say of it.
    fn metadata(&self) -> HashMap<String, String> {
        checkpoint::network_metadata(self.shapes, self.layers, None)
    }

    /// Loads weights saved by [`QNet::save`], with a clear error for a missing,
    /// truncated or mismatched file, or one written in another layout.
    pub fn load(&self, path: &Path) -> Result<()> {
        let file = path.display().to_string();
        let tensors = checkpoint::read(path, &self.device, &self.metadata())?;
        self.load_named(&tensors, &file)
    }
}

/// The index of the largest value (the first of equals): the greedy action
/// of one row of Q-values.
pub fn argmax(v: &[f32]) -> usize {
    let mut best = 0;
    for (i, x) in v.iter().enumerate() {
        if *x > v[best] {
            best = i;
        }
    }
    best
}

#[cfg(test)]
mod tests;
