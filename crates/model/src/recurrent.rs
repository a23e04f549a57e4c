//! The recurrent Q-network and its sequence update: the feedforward
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
use std::time::Instant;

use candle_core::{D, DType, Device, Tensor, Var};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::checkpoint;
use crate::dqn::{Adam, UpdateTiming};
use crate::kernels::{Rows, Weights, Workspace, offsets};
use crate::layers::trunk_params;
use crate::teaching::Teaching;
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

/// Hyper-parameters of the sequence update.
#[derive(Debug, Clone, Copy)]
pub struct SeqConfig {
    /// Adam's learning rate.
    pub lr: f32,
    /// Discount.
    pub gamma: f32,
    /// Steps of return before bootstrapping (cut at an episode's end and at
    /// the sequence's).
    pub n_step: usize,
    /// Steps at a sequence's start that only warm its state up.
    pub burn_in: usize,
    /// Updates between target-network copies.
    pub target_update: u64,
    /// Huber loss threshold.
    pub huber_delta: f32,
    /// Rewards are multiplied by this in the target.
    pub reward_scale: f32,
    /// DQfD's margin l(a_E, a) for every action but the expert's (see
    /// [`SeqDqn::set_margin_weight`]).
    pub margin: f32,
}

/// A recurrent DQN learner: online and target networks and Adam, updated on
/// stored sequences (double DQN, n-step, Huber loss).
pub struct SeqDqn {
    /// The online network.
    pub online: RecurrentQNet,
    target: RecurrentQNet,
    cfg: SeqConfig,
    /// The project's Adam (its step count is the update count).
    opt: Adam,
    /// The online trunk's fused pass, kept from its forward for its
    /// backward.
    work: Workspace,
    /// How the labels weigh now (the default: the plain TD update).
    teaching: Teaching,
    /// The last update's priority of each sequence (R2D2's mix of its
    /// trained steps' largest and mean |TD error|).
    priorities: Vec<f32>,
    /// Where the last update's time went.
    timing: UpdateTiming,
}

impl SeqDqn {
    /// A learner with freshly initialised networks (the target a copy of
    /// the online one).
    pub fn new(
        cfg: SeqConfig,
        shapes: Shapes,
        width: usize,
        seed: u64,
        device: &Device,
    ) -> Result<Self> {
        Self::with_layers(cfg, shapes, Layers::DEFAULT, width, seed, device)
    }

    /// [`SeqDqn::new`] with trunks of widths `layers`.
    pub fn with_layers(
        cfg: SeqConfig,
        shapes: Shapes,
        layers: Layers,
        width: usize,
        seed: u64,
        device: &Device,
    ) -> Result<Self> {
        let online = RecurrentQNet::with_layers(shapes, layers, width, seed, device)?;
        let target = RecurrentQNet::with_layers(shapes, layers, width, seed, device)?;
        let sizes = recurrent_params(shapes, layers, width);
        let sizes = sizes.iter().map(|(_, s)| s.iter().product::<usize>());
        let opt = Adam::with_sizes((cfg.lr, cfg.lr, 0), sizes);
        let work = Workspace::default();
        Ok(Self {
            online,
            target,
            cfg,
            opt,
            work,
            teaching: Teaching::default(),
            priorities: Vec::new(),
            timing: UpdateTiming::default(),
        })
    }

    /// Weight of DQfD's large-margin loss `max_a [Q(s,a) + l(a_E,a)] −
    /// Q(s,a_E)` on the trained steps with an expert action, against the
    /// mean TD loss (both divided by the trained steps); 0 turns it off.
    pub fn set_margin_weight(&mut self, weight: f32) {
        self.teaching = Teaching::margin(weight);
    }

    /// How the TD, margin and imitation losses weigh on the trained steps
    /// (see [`Teaching`]); the default is the plain update.
    pub fn set_teaching(&mut self, teaching: Teaching) {
        self.teaching = teaching;
    }

    /// Chooses the fused CPU path for both networks' trunks, or the generic
    /// one.
    pub fn set_fused(&mut self, fused: bool) -> Result<()> {
        self.online.set_fused(fused)?;
        self.target.set_fused(fused)
    }

    /// Updates made.
    pub fn updates(&self) -> u64 {
        self.opt.t
    }

    /// The last update's priority of each of its sequences: `ETA` times
    /// the largest |TD error| of its trained steps plus `1 − ETA` times
    /// their mean (R2D2, η = 0.9).
    pub fn priorities(&self) -> &[f32] {
        &self.priorities
    }

    /// Loads both networks' weights from a checkpoint (a restarted learner's
    /// latest, where no state was saved); the optimiser starts afresh.
    pub fn restore(&mut self, path: &Path) -> Result<()> {
        self.online.load(path)?;
        self.target.copy_from(&self.online)
    }

    /// Saves the whole learner state (both networks, Adam's moments and
    /// step) as one safetensors file, atomically: a restarted learner goes
    /// on as if it had not stopped ([`SeqDqn::load_state`]).
    pub fn save_state(&self, path: &Path) -> Result<()> {
        let specs = recurrent_params(self.online.shapes, self.online.layers, self.online.width);
        let nets = (&self.online.params[..], &self.target.params[..]);
        let o = &self.opt;
        checkpoint::save_state(path, &specs, nets, (&o.m, &o.v, o.t), o.t)
    }

    /// Restores a state written by [`SeqDqn::save_state`], checking every
    /// tensor (one of another memory or width is refused by name).
    pub fn load_state(&mut self, path: &Path) -> Result<()> {
        let specs = recurrent_params(self.online.shapes, self.online.layers, self.online.width);
        let st = checkpoint::read_state(path, &specs)?;
        let (file, dev) = (path.display().to_string(), self.online.device.clone());
        checkpoint::load_vars(&specs, &self.online.params, &st.online, &file, &dev)?;
        checkpoint::load_vars(&specs, &self.target.params, &st.target, &file, &dev)?;
        (self.opt.m, self.opt.v, self.opt.t) = (st.m, st.v, st.t);
        Ok(())
    }

    /// One update on `batch`; the loss. The target network is copied from
    /// the online one every `target_update` updates.
    pub fn update(&mut self, batch: &SeqBatch) -> Result<f32> {
        let (loss, grads) = self.gradients(batch)?;
        let t = Instant::now();
        self.apply(&grads)?;
        self.timing.optimiser_ns = t.elapsed().as_nanos() as u64;
        Ok(loss)
    }

    /// Where the last update's time went: the forward passes and the loss
    /// (burn-in, unrolls, targets), the backward pass (candle's autograd
    /// and the fused trunk's), Adam's step.
    pub fn timing(&self) -> UpdateTiming {
        self.timing
    }

    /// The loss on `batch` and its gradient, flat in canonical order
    /// (nothing is updated).
    pub fn gradients(&mut self, batch: &SeqBatch) -> Result<(f32, Vec<f32>)> {
        let start = Instant::now();
        let (shapes, width) = (self.online.shapes, self.online.width);
        batch.check(shapes, width, self.cfg.burn_in)?;
        let dev = self.online.device.clone();
        let (n, t, burn) = (batch.sequences, batch.steps, self.cfg.burn_in);
        let (obs, keep) = step_major(batch, shapes.obs_len());
        let keep = Tensor::from_vec(keep, (t + 1, n), &dev)?;
        let h0 = Tensor::from_slice(batch.states, (n, width), &dev)?;
        // The fused trunk's activations enter autograd as a variable, whose
        // gradient the fused backward takes up.
        let (feat, leaf) = if self.online.fused {
            let v = Var::from_tensor(&self.online.trunk_fused(&mut self.work, &obs)?)?;
            (v.as_tensor().clone(), Some(v))
        } else {
            (self.online.features(&obs)?, None)
        };
        // The burn-in only warms the state: no gradient flows into it.
        let h = if burn > 0 {
            let (_, h) = self.online.unroll_features(
                &feat.narrow(0, 0, burn * n)?,
                burn,
                n,
                &h0,
                &keep.narrow(0, 0, burn)?,
            )?;
            h.detach()
        } else {
            h0.clone()
        };
        let rest = t + 1 - burn;
        let (q, _) = self.online.unroll_features(
            &feat.narrow(0, burn * n, rest * n)?,
            rest,
            n,
            &h,
            &keep.narrow(0, burn, rest)?,
        )?;
        let qt = self.target.unroll_features(&self.target.features(&obs)?, t + 1, n, &h0, &keep)?.0;
        let y = self.targets(batch, &q.detach().to_vec3::<f32>()?, &qt.to_vec3::<f32>()?);
        let trained = t - burn;
        let mut onehot = vec![0.0f32; trained * n * shapes.actions];
        for (i, a) in batch.actions.chunks_exact(t).enumerate() {
            for s in 0..trained {
                onehot[(s * n + i) * shapes.actions + a[burn + s] as usize] = 1.0;
            }
        }
        let onehot = Tensor::from_vec(onehot, (trained, n, shapes.actions), &dev)?;
        let taken = (q.narrow(0, 0, trained)? * onehot)?.sum(D::Minus1)?;
        let y = Tensor::from_vec(y, (trained, n), &dev)?;
        let err = (taken - y)?;
        self.priorities = sequence_priorities(&err.abs()?.to_vec2::<f32>()?, n);
        let mut loss = if batch.weights.is_empty() {
            huber(&err, self.cfg.huber_delta)?
        } else {
            let w = Tensor::from_slice(batch.weights, (1, n), &dev)?;
            huber_weighted(&err, &w, self.cfg.huber_delta)?
        };
        if self.teaching.td != 1.0 {
            loss = loss.affine(self.teaching.td as f64, 0.0)?;
        }
        if let Some(taught) = self.teacher_loss(batch, &q.narrow(0, 0, trained)?)? {
            loss = (loss + taught)?;
        }
        let value = loss.to_scalar::<f32>()?;
        if !value.is_finite() {
            return Err(ModelError::NoGradient("the sequence loss is not finite"));
        }
        self.timing.forward_ns = start.elapsed().as_nanos() as u64;
        let back = Instant::now();
        let grads = self.backward(&loss, leaf.as_ref(), (t + 1) * n)?;
        self.timing.backward_ns = back.elapsed().as_nanos() as u64;
        Ok((value, grads))
    }

    /// The teacher's losses of the trained steps' Q-values `q`
    /// (`[trained][sequences][actions]`) on the labelled steps: DQfD's
    /// large margin and the imitation loss, weighted and divided by the
    /// trained steps; none without a weight or a label.
    fn teacher_loss(&self, b: &SeqBatch, q: &Tensor) -> Result<Option<Tensor>> {
        let (n, t, burn) = (b.sequences, b.steps, self.cfg.burn_in);
        let (trained, na, k) = (t - burn, self.online.shapes.actions, self.teaching);
        if (k.margin <= 0.0 && k.imitation <= 0.0) || b.experts.is_empty() {
            return Ok(None);
        }
        // The trained steps' labels in `q`'s (step-major) order.
        let experts: Vec<f32> =
            (0..trained).flat_map(|s| (0..n).map(move |i| b.experts[i * t + burn + s])).collect();
        let rows = q.reshape((trained * n, na))?;
        let scale = |w: f32| w as f64 / (trained * n) as f64;
        let mut sum: Option<Tensor> = None;
        let margin = if k.margin > 0.0 {
            crate::teaching::margin_sum(&rows, &experts, self.cfg.margin)?.map(|m| (m, k.margin))
        } else {
            None
        };
        let imitation = if k.imitation > 0.0 {
            crate::teaching::imitation_sum(&rows, &experts, k.temperature)?
                .map(|m| (m, k.imitation))
        } else {
            None
        };
        for (part, w) in [margin, imitation].into_iter().flatten() {
            let part = part.affine(scale(w), 0.0)?;
            sum = Some(match sum {
                Some(s) => (s + part)?,
                None => part,
            });
        }
        Ok(sum)
    }

    /// The gradient of `loss`, flat in canonical order: the GRU's and the
    /// head's from candle's autograd; the trunk's from it too on the generic
    /// path, or from the fused backward of the `rows` activations `leaf`.
    fn backward(&mut self, loss: &Tensor, leaf: Option<&Var>, rows: usize) -> Result<Vec<f32>> {
        let grads = loss.backward()?;
        let grad_of = |t: &Tensor| -> Result<Vec<f32>> {
            let g = grads.get(t).ok_or(ModelError::NoGradient("a recurrent parameter got none"))?;
            Ok(g.flatten_all()?.to_vec1::<f32>()?)
        };
        let mut flat = Vec::with_capacity(self.online.num_params());
        let first = match leaf {
            Some(leaf) => {
                let layers = self.online.layers;
                self.work.trunk_grad(rows, layers).copy_from_slice(&grad_of(leaf.as_tensor())?);
                let (online, work) = (&self.online, &mut self.work);
                online.with_trunk(|w| work.backward_trunk(w, rows))?;
                let t = layers.trunk_len();
                flat.extend_from_slice(&self.work.grads[..offsets(self.online.shapes, layers)[t]]);
                t
            }
            None => 0,
        };
        for var in &self.online.params[first..] {
            flat.extend(grad_of(var.as_tensor())?);
        }
        Ok(flat)
    }

    /// One Adam step with `grads` (flat in canonical order); the target
    /// copied when due.
    fn apply(&mut self, grads: &[f32]) -> Result<()> {
        self.opt.step_vars(&self.online.params, grads)?;
        if self.opt.t.is_multiple_of(self.cfg.target_update.max(1)) {
            self.target.copy_from(&self.online)?;
        }
        Ok(())
    }

    /// The n-step double-DQN targets `[trained][sequences]` of the trained
    /// steps, from the online network's Q-values `q` (from the burn-in's end)
    /// and the target network's `qt` (from the sequence's start).
    fn targets(&self, b: &SeqBatch, q: &[Vec<Vec<f32>>], qt: &[Vec<Vec<f32>>]) -> Vec<f32> {
        let (n, t, burn) = (b.sequences, b.steps, self.cfg.burn_in);
        let c = self.cfg;
        let mut y = vec![0.0; (t - burn) * n];
        for i in 0..n {
            let (r, d) = (&b.rewards[i * t..(i + 1) * t], &b.dones[i * t..(i + 1) * t]);
            for u in burn..t {
                let (mut g, mut disc, mut k) = (0.0f32, 1.0f32, 0);
                let mut boot = true;
                while k < c.n_step.max(1) && u + k < t {
                    g += disc * r[u + k] * c.reward_scale;
                    disc *= c.gamma;
                    k += 1;
                    if d[u + k - 1] {
                        boot = false;
                        break;
                    }
                }
                if boot {
                    let s = u + k;
                    let best = argmax(&q[s - burn][i]);
                    g += disc * qt[s][i][best];
                }
                y[(u - burn) * n + i] = g;
            }
        }
        y
    }
}

/// A batch's observations step major (`[steps + 1][sequences][obs_len]`)
/// and its keep-mask `[steps + 1][sequences]` (0 after an episode's end).
fn step_major(b: &SeqBatch, len: usize) -> (Vec<f32>, Vec<f32>) {
    let (n, t) = (b.sequences, b.steps);
    let mut obs = vec![0.0; (t + 1) * n * len];
    for (i, seq) in b.obs.chunks_exact((t + 1) * len).enumerate() {
        for (s, o) in seq.chunks_exact(len).enumerate() {
            obs[(s * n + i) * len..][..len].copy_from_slice(o);
        }
    }
    let mut keep = vec![1.0f32; (t + 1) * n];
    for (i, d) in b.dones.chunks_exact(t).enumerate() {
        for (s, &done) in d.iter().enumerate() {
            keep[(s + 1) * n + i] = if done { 0.0 } else { 1.0 };
        }
    }
    (obs, keep)
}

/// R2D2's mix of a sequence's largest and mean |TD error|.
pub const ETA: f32 = 0.9;

/// Each of `n` sequences' priority from its trained steps' |TD errors|
/// `abs` (`[trained][sequences]`).
fn sequence_priorities(abs: &[Vec<f32>], n: usize) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let (max, sum) = abs.iter().fold((0.0f32, 0.0f32), |(m, s), r| (m.max(r[i]), s + r[i]));
            ETA * max + (1.0 - ETA) * sum / abs.len().max(1) as f32
        })
        .collect()
}

/// Each Huber loss of the errors `d` with threshold `delta`.
fn huber_each(d: &Tensor, delta: f32) -> Result<Tensor> {
    let a = d.abs()?;
    let quad = a.minimum(delta)?;
    let lin = (a - &quad)?;
    Ok(((quad.sqr()? * 0.5)? + (lin * delta as f64)?)?)
}

/// The mean Huber loss of the errors `d` with threshold `delta`.
fn huber(d: &Tensor, delta: f32) -> Result<Tensor> {
    Ok(huber_each(d, delta)?.mean_all()?)
}

/// The mean Huber loss of the errors `d` (`[trained][sequences]`), each
/// sequence's weighted by `w` (`[1][sequences]`).
fn huber_weighted(d: &Tensor, w: &Tensor, delta: f32) -> Result<Tensor> {
    Ok(huber_each(d, delta)?.broadcast_mul(w)?.mean_all()?)
}

mod batch;
pub use batch::SeqBatch;

#[cfg(test)]
mod tests;
