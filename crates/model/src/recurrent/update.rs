//! The recurrent network's update ([`SeqDqn`]): R2D2's on stored
//! sequences (burn-in, n-step targets inside a sequence, double DQN or
//! not, each sequence's priority), with the teacher's losses on its
//! labelled steps, under the feedforward update's policy
//! ([`crate::optimiser`]: the learning rate's decay, clipping, a
//! non-finite loss skipped and counted, the target's cadence) and with its
//! gauges ([`UpdateStats`]).

use std::path::Path;
use std::time::Instant;

use candle_core::{D, Device, Tensor, Var};

use super::{RecurrentQNet, SeqBatch, recurrent_params};
use crate::checkpoint;
use crate::dqn::{UpdateStats, UpdateTiming};
use crate::kernels::{Workspace, offsets};
use crate::optimiser::{Optimiser, Schedule};
use crate::teaching::Teaching;
use crate::{Layers, ModelError, Result, Shapes, argmax};

/// Hyper-parameters of the sequence update.
#[derive(Debug, Clone, Copy)]
pub struct SeqConfig {
    /// Adam's learning rate at the first update.
    pub lr: f32,
    /// The learning rate reached after `lr_decay_updates` updates (linear
    /// decay; held from then on).
    pub lr_final: f32,
    /// Updates over which the learning rate falls from `lr` to `lr_final`;
    /// 0 keeps `lr` throughout.
    pub lr_decay_updates: u64,
    /// The gradient's global L2 norm is clipped to this; 0 = no clipping.
    pub max_grad_norm: f32,
    /// Double DQN: the online network picks the next action, the target
    /// network values it; else the target network's largest value.
    pub double: bool,
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
    /// Adam, its schedule, clipping, skips and the target's cadence.
    opt: Optimiser,
    /// What the last update's trained steps showed (max-Q, |TD|,
    /// terminals, the gradient's norm).
    stats: UpdateStats,
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
        let schedule = Schedule {
            lr: cfg.lr,
            lr_final: cfg.lr_final,
            decay: cfg.lr_decay_updates,
            max_grad_norm: cfg.max_grad_norm,
            target_update: cfg.target_update,
        };
        let opt = Optimiser::new(schedule, sizes);
        let work = Workspace::default();
        Ok(Self {
            online,
            target,
            cfg,
            opt,
            stats: UpdateStats::default(),
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

    /// Updates made, skipped ones included.
    pub fn updates(&self) -> u64 {
        self.opt.updates
    }

    /// Updates skipped so far because their loss or gradient was not
    /// finite (they count in [`SeqDqn::updates`] but changed nothing).
    pub fn skipped(&self) -> u64 {
        self.opt.skipped
    }

    /// What the last update's trained steps showed: their count (`rows`),
    /// max-Q and |TD error| sums, terminals, the gradient's norm.
    pub fn stats(&self) -> UpdateStats {
        self.stats
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
        let o = &self.opt.adam;
        checkpoint::save_state(path, &specs, nets, (&o.m, &o.v, o.t), self.opt.updates)
    }

    /// Restores a state written by [`SeqDqn::save_state`], checking every
    /// tensor (one of another memory or width is refused by name).
    pub fn load_state(&mut self, path: &Path) -> Result<()> {
        let specs = recurrent_params(self.online.shapes, self.online.layers, self.online.width);
        let st = checkpoint::read_state(path, &specs)?;
        let (file, dev) = (path.display().to_string(), self.online.device.clone());
        checkpoint::load_vars(&specs, &self.online.params, &st.online, &file, &dev)?;
        checkpoint::load_vars(&specs, &self.target.params, &st.target, &file, &dev)?;
        (self.opt.adam.m, self.opt.adam.v, self.opt.adam.t) = (st.m, st.v, st.t);
        self.opt.updates = st.updates;
        Ok(())
    }

    /// One update on `batch`; the loss. A loss or gradient that is not
    /// finite skips the step (the weights and Adam's moments stay as they
    /// were), counts in [`SeqDqn::skipped`] and is returned; the update
    /// still counts. The target network is copied from the online one every
    /// `target_update` updates.
    pub fn update(&mut self, batch: &SeqBatch) -> Result<f32> {
        let (loss, mut grads) = self.loss_and_gradients(batch)?;
        let t = Instant::now();
        let step = self.opt.step(&self.online.params, grads.as_deref_mut(), loss)?;
        self.stats.grad_norm = step.grad_norm;
        if step.sync_target {
            self.target.copy_from(&self.online)?;
        }
        self.timing.optimiser_ns = t.elapsed().as_nanos() as u64;
        Ok(step.reported(loss))
    }

    /// Where the last update's time went: the forward passes and the loss
    /// (burn-in, unrolls, targets), the backward pass (candle's autograd
    /// and the fused trunk's), Adam's step.
    pub fn timing(&self) -> UpdateTiming {
        self.timing
    }

    /// The loss on `batch` and its gradient, flat in canonical order
    /// (nothing is updated); a loss that is not finite is an error.
    pub fn gradients(&mut self, batch: &SeqBatch) -> Result<(f32, Vec<f32>)> {
        match self.loss_and_gradients(batch)? {
            (loss, Some(grads)) => Ok((loss, grads)),
            _ => Err(ModelError::NoGradient("the sequence loss is not finite")),
        }
    }

    /// The loss on `batch` and, where it is finite, its gradient; the
    /// trained steps' gauges into [`SeqDqn::stats`].
    fn loss_and_gradients(&mut self, batch: &SeqBatch) -> Result<(f32, Option<Vec<f32>>)> {
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
        let q_rows = q.detach().to_vec3::<f32>()?;
        let y = self.targets(batch, &q_rows, &qt.to_vec3::<f32>()?);
        self.stats = trained_stats(batch, &q_rows, &y, burn);
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
        self.timing.forward_ns = start.elapsed().as_nanos() as u64;
        if !value.is_finite() {
            return Ok((value, None));
        }
        let back = Instant::now();
        let grads = self.backward(&loss, leaf.as_ref(), (t + 1) * n)?;
        self.timing.backward_ns = back.elapsed().as_nanos() as u64;
        Ok((value, Some(grads)))
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

    /// The n-step targets `[trained][sequences]` of the trained steps, from
    /// the online network's Q-values `q` (from the burn-in's end) and the
    /// target network's `qt` (from the sequence's start): the next action
    /// the online network's pick under double DQN, else the target's.
    pub(crate) fn targets(
        &self,
        b: &SeqBatch,
        q: &[Vec<Vec<f32>>],
        qt: &[Vec<Vec<f32>>],
    ) -> Vec<f32> {
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
                    let pick = if c.double { &q[s - burn][i] } else { &qt[s][i] };
                    let best = argmax(pick);
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

/// The gauges of a batch's trained steps: their count, the sums of the
/// online network's max-Q (`q`, from the burn-in's end) and of |Q(s, a) −
/// y| against the targets `y` (`[trained][sequences]`), the terminals.
fn trained_stats(b: &SeqBatch, q: &[Vec<Vec<f32>>], y: &[f32], burn: usize) -> UpdateStats {
    let (n, t) = (b.sequences, b.steps);
    let mut st = UpdateStats { rows: ((t - burn) * n) as u32, ..UpdateStats::default() };
    for i in 0..n {
        for u in burn..t {
            let row = &q[u - burn][i];
            // The actions are one of the network's (`SeqBatch::check`).
            let a = b.actions[i * t + u] as usize;
            st.max_q_sum += row[argmax(row)] as f64;
            st.abs_td_sum += (row[a] - y[(u - burn) * n + i]).abs() as f64;
            st.terminal += b.dones[i * t + u] as u32;
        }
    }
    st
}

/// R2D2's mix of a sequence's largest and mean |TD error|.
pub const ETA: f32 = 0.9;

/// Each of `n` sequences' priority from its trained steps' |TD errors|
/// `abs` (`[trained][sequences]`).
pub(crate) fn sequence_priorities(abs: &[Vec<f32>], n: usize) -> Vec<f32> {
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
