//! The DQN update: online and target networks, the TD-Huber loss and Adam,
//! with the whole learner state (weights, optimiser moments, counters)
//! saved and restored as one safetensors file.

use std::path::Path;
use std::sync::Mutex;
use std::time::Instant;

use candle_core::{D, Tensor};

use crate::checkpoint;
use crate::kernels::{Rows, Workspace, poisoned};
use crate::optimiser::{Optimiser, Schedule};
use crate::{Layers, ModelError, QNet, Result, Shapes, argmax, params};
use rotorhive_msg::{label_action, label_mask};

use crate::teaching::{Teaching, imitation_row, imitation_sum, margin_sum};

/// Hyper-parameters of the DQN update.
#[derive(Debug, Clone, Copy)]
pub struct DqnConfig {
    /// Adam learning rate at the first update.
    pub lr: f64,
    /// Learning rate reached after `lr_decay_updates` updates (linear decay;
    /// held from then on).
    pub lr_final: f64,
    /// Updates over which the learning rate falls from `lr` to `lr_final`;
    /// 0 keeps `lr` throughout.
    pub lr_decay_updates: u64,
    /// Discount.
    pub gamma: f32,
    /// Updates between target-network copies.
    pub target_update: u64,
    /// Huber loss threshold.
    pub huber_delta: f32,
    /// Double DQN: the online network picks the next action, the target
    /// network values it.
    pub double: bool,
    /// Rewards (n-step returns) are multiplied by this in the TD target.
    pub reward_scale: f32,
    /// The gradient's global L2 norm is clipped to this; 0 = no clipping.
    pub max_grad_norm: f32,
    /// DQfD's margin l(a_E, a) for every action but the expert's, in the
    /// large-margin loss of rows with an expert action (see
    /// [`Dqn::set_margin_weight`]).
    pub margin: f32,
}

/// What the last update saw, for the learner's diagnostics: sums over the
/// minibatch's rows, in the network's units (scaled rewards).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UpdateStats {
    /// Rows of the minibatch.
    pub rows: u32,
    /// Sum over rows of max_a Q(s, a).
    pub max_q_sum: f64,
    /// Sum over rows of |Q(s, a) − y|.
    pub abs_td_sum: f64,
    /// Rows with a label (the teacher's losses' rows).
    pub labelled: u32,
    /// Of those, rows whose greedy action is one the label allows.
    pub agree: u32,
    /// Sum over labelled rows of the large-margin loss (unweighted).
    pub margin_sum: f64,
    /// Terminal transitions (done = 1).
    pub terminal: u32,
    /// The gradient's global L2 norm before clipping.
    pub grad_norm: f64,
}

impl UpdateStats {
    fn add(&mut self, o: &UpdateStats) {
        self.rows += o.rows;
        self.max_q_sum += o.max_q_sum;
        self.abs_td_sum += o.abs_td_sum;
        self.terminal += o.terminal;
        self.labelled += o.labelled;
        self.agree += o.agree;
        self.margin_sum += o.margin_sum;
    }
}

/// Time spent in each part of the last update (ns).
#[derive(Debug, Clone, Copy, Default)]
pub struct UpdateTiming {
    /// Target and online forward passes and the loss.
    pub forward_ns: u64,
    /// Backward pass.
    pub backward_ns: u64,
    /// Adam step (and target copy).
    pub optimiser_ns: u64,
}

/// One shard's share of an update.
struct Shard {
    loss: f32,
    forward_ns: u64,
    backward_ns: u64,
    stats: UpdateStats,
}

/// A DQN learner: online network, target network and Adam.
pub struct Dqn {
    /// The online network.
    pub online: QNet,
    pub(crate) target: QNet,
    /// Adam, its schedule, clipping, skips and the target's cadence.
    opt: Optimiser,
    cfg: DqnConfig,
    timing: UpdateTiming,
    shards: usize,
    /// One workspace per shard of the fused path.
    work: Vec<Mutex<Workspace>>,
    /// The generic path's gradients, flat in canonical order (the fused
    /// path sums its shards' into the first workspace).
    grads: Vec<f32>,
    stats: UpdateStats,
    /// Per row of the last update: the absolute TD error.
    td: Vec<f32>,
    /// How the labels weigh now (the learner sets it from `[teacher]`,
    /// the teacher's fade and `learner.td_weight`).
    teaching: Teaching,
}

/// The gradients [`Dqn::compute_gradients`] left, flat in canonical order.
fn gradients_in<'a>(
    net: &QNet,
    generic: &'a mut [f32],
    work: &'a mut [Mutex<Workspace>],
) -> Result<&'a mut [f32]> {
    match (net.fused(), work.first_mut()) {
        (true, Some(ws)) => Ok(&mut ws.get_mut().map_err(poisoned)?.grads[..net.num_params()]),
        (true, None) => Err(ModelError::NoGradient("none computed yet")),
        (false, _) => Ok(generic),
    }
}

/// Checks a minibatch's size and actions; returns its rows.
fn rows_of(batch: &[f32], shapes: Shapes) -> Result<usize> {
    let len = shapes.transition_len();
    if batch.is_empty() || !batch.len().is_multiple_of(len) {
        return Err(ModelError::Shape { what: "minibatch", expected: len, got: batch.len() });
    }
    let one_of = |a: f32| a >= 0.0 && (a as usize) < shapes.actions && a.fract() == 0.0;
    for t in batch.chunks_exact(len) {
        let (a, e) = (t[2 * shapes.obs_len()], t[2 * shapes.obs_len() + 3]);
        if !one_of(a) {
            return Err(ModelError::Shape {
                what: "minibatch action (one of the actions)",
                expected: shapes.actions,
                got: a as usize,
            });
        }
        if label_mask(e, shapes.actions).is_none() {
            return Err(ModelError::Shape {
                what: "minibatch label (-1, one of the actions or a set of them)",
                expected: shapes.actions,
                got: e as usize,
            });
        }
    }
    Ok(batch.len() / len)
}

/// The update policy of `cfg` for a network of `shapes` and `layers`.
fn optimiser(cfg: &DqnConfig, shapes: Shapes, layers: Layers) -> Optimiser {
    let schedule = Schedule {
        lr: cfg.lr as f32,
        lr_final: cfg.lr_final as f32,
        decay: cfg.lr_decay_updates,
        max_grad_norm: cfg.max_grad_norm,
        target_update: cfg.target_update,
    };
    Optimiser::new(schedule, params(shapes, layers).iter().map(|(_, s)| s.iter().product()))
}

impl Dqn {
    /// A learner with freshly initialised networks of the paper's task's
    /// shapes; see [`Dqn::with_shapes`].
    pub fn new(cfg: DqnConfig, seed: u64, device: &candle_core::Device) -> Result<Self> {
        Self::with_shapes(cfg, Shapes::PAPER, seed, device)
    }

    /// A learner with freshly initialised networks for `shapes`.
    pub fn with_shapes(
        cfg: DqnConfig,
        shapes: Shapes,
        seed: u64,
        device: &candle_core::Device,
    ) -> Result<Self> {
        Self::with_layers(cfg, shapes, Layers::DEFAULT, seed, device)
    }

    /// A learner with freshly initialised networks for `shapes` of widths
    /// `layers`.
    pub fn with_layers(
        cfg: DqnConfig,
        shapes: Shapes,
        layers: Layers,
        seed: u64,
        device: &candle_core::Device,
    ) -> Result<Self> {
        let online = QNet::with_layers(shapes, layers, seed, device)?;
        let target = QNet::with_layers(shapes, layers, seed, device)?;
        Ok(Self {
            online,
            target,
            opt: optimiser(&cfg, shapes, layers),
            cfg,
            timing: UpdateTiming::default(),
            shards: 1,
            work: Vec::new(),
            grads: Vec::new(),
            stats: UpdateStats::default(),
            td: Vec::new(),
            teaching: Teaching::default(),
        })
    }

    /// Weight of DQfD's large-margin loss `max_a [Q(s,a) + l(a_E,a)] −
    /// Q(s,a_E)` (l = `margin` for every action but the expert's a_E),
    /// added on every row labelled with one action to the TD loss, both
    /// means over the minibatch's rows. 0 (the default) turns it off: the
    /// update is then exactly the plain one.
    pub fn set_margin_weight(&mut self, weight: f32) {
        self.teaching = Teaching::margin(weight);
    }

    /// How the TD, margin and imitation losses weigh (see [`Teaching`]);
    /// the default is the plain update.
    pub fn set_teaching(&mut self, teaching: Teaching) {
        self.teaching = teaching;
    }

    /// The large-margin loss of one row's Q-values `q` with expert action
    /// `expert`: its value and the action a* that maximises Q + l (the
    /// loss's gradient is +1 on a*, −1 on a_E; none where a* = a_E).
    fn margin_of(&self, q: &[f32], expert: usize) -> (f32, usize) {
        let m = self.cfg.margin;
        let l = |a: usize| if a == expert { 0.0 } else { m };
        let best = (0..q.len()).fold(0, |b, a| if q[a] + l(a) > q[b] + l(b) { a } else { b });
        (q[best] + l(best) - q[expert], best)
    }

    /// Uses the fused CPU path (default on the CPU) or the generic one.
    pub fn set_fused(&mut self, fused: bool) -> Result<()> {
        self.online.set_fused(fused)?;
        self.target.set_fused(fused)
    }

    /// Threads for updates (and the online network's inference): on the
    /// fused path each minibatch is split into this many data-parallel shards.
    pub fn set_threads(&mut self, threads: usize) {
        self.shards = threads.max(1);
        self.online.set_threads(threads);
        self.target.set_threads(threads);
    }

    /// Updates done so far.
    pub fn updates(&self) -> u64 {
        self.opt.updates
    }

    /// Timing of the last update.
    pub fn timing(&self) -> UpdateTiming {
        self.timing
    }

    /// Updates skipped so far because their loss or gradient was not
    /// finite (they count in [`Dqn::updates`] but changed nothing).
    pub fn skipped(&self) -> u64 {
        self.opt.skipped
    }

    /// What the last update's minibatch showed (max-Q, TD error, terminals).
    pub fn stats(&self) -> UpdateStats {
        self.stats
    }

    /// The absolute TD error of every row of the last update, in the
    /// network's units (prioritized replay's new priorities).
    pub fn td_abs(&self) -> &[f32] {
        &self.td
    }

    /// Copies the online weights into the target network.
    pub fn sync_target(&self) -> Result<()> {
        self.target.copy_from(&self.online)
    }

    /// The TD target `r + γ (1 − done) Q'(s', a*)` of transition `t`, given
    /// the target network's and (double DQN) the online network's Q-values
    /// of `s'`.
    fn target_of(&self, t: &[f32], q_target: &[f32], q_online: &[f32]) -> f32 {
        let pick = if self.cfg.double { q_online } else { q_target };
        let at = 2 * self.online.shapes().obs_len();
        let (r, done) = (t[at + 1], t[at + 2]);
        r * self.cfg.reward_scale + self.cfg.gamma * (1.0 - done) * q_target[argmax(pick)]
    }

    /// The Huber loss of `e` and its derivative.
    fn huber(&self, e: f32) -> (f32, f32) {
        let d = self.cfg.huber_delta;
        let loss = if e.abs() <= d { 0.5 * e * e } else { d * (e.abs() - 0.5 * d) };
        (loss, e.clamp(-d, d))
    }

    /// The mean Huber TD loss of a minibatch (`n × transition_len` floats) as
    /// a differentiable candle tensor over stock candle ops: the reference
    /// the fused path is tested against, and the path off the CPU.
    pub fn loss(&self, batch: &[f32]) -> Result<Tensor> {
        let n = rows_of(batch, self.online.shapes())?;
        Ok(self.loss_generic(batch, n, None)?.0)
    }

    /// [`Dqn::loss`] of a checked minibatch of `n` rows, each row's Huber
    /// loss multiplied by its importance weight; also each row's |TD error|.
    fn loss_generic(
        &self,
        batch: &[f32],
        n: usize,
        weights: Option<&[f32]>,
    ) -> Result<(Tensor, Vec<f32>)> {
        let dev = self.online.device();
        let shapes = self.online.shapes();
        let (ol, tl, na) = (shapes.obs_len(), shapes.transition_len(), shapes.actions);
        let column = |from: usize, len: usize| -> Vec<f32> {
            batch.chunks_exact(tl).flat_map(|t| t[from..from + len].to_vec()).collect()
        };
        let s2 = Tensor::from_vec(column(ol, ol), (n, ol), dev)?;
        let q_target =
            self.target.forward_generic(&s2)?.detach().flatten_all()?.to_vec1::<f32>()?;
        let q_online = if self.cfg.double {
            self.online.forward_generic(&s2)?.detach().flatten_all()?.to_vec1::<f32>()?
        } else {
            q_target.clone()
        };
        let y: Vec<f32> = batch
            .chunks_exact(tl)
            .enumerate()
            .map(|(i, t)| {
                self.target_of(t, &q_target[i * na..(i + 1) * na], &q_online[i * na..(i + 1) * na])
            })
            .collect();
        let actions: Vec<u32> = batch.chunks_exact(tl).map(|t| t[2 * ol] as u32).collect();
        let q = self.online.forward_generic(&Tensor::from_vec(column(0, ol), (n, ol), dev)?)?;
        let a = Tensor::from_vec(actions, (n, 1), dev)?;
        let y = Tensor::from_vec(y, (n, 1), dev)?;
        let abs = (q.gather(&a, D::Minus1)? - y)?.abs()?;
        let td = abs.detach().flatten_all()?.to_vec1::<f32>()?;
        let d = self.cfg.huber_delta as f64;
        let c = abs.clamp(0.0, d)?;
        let mut loss = ((c.sqr()? * 0.5)? + ((abs - &c)? * d)?)?;
        if let Some(w) = weights {
            loss = (loss * Tensor::from_slice(w, (n, 1), dev)?)?;
        }
        let k = self.teaching;
        let mut loss = loss.sum_all()?;
        if k.td != 1.0 {
            loss = loss.affine(k.td as f64, 0.0)?;
        }
        let experts: Vec<f32> = batch.chunks_exact(tl).map(|t| t[2 * ol + 3]).collect();
        if k.margin > 0.0
            && let Some(margin) = margin_sum(&q, &experts, self.cfg.margin)?
        {
            loss = (loss + margin.affine(k.margin as f64, 0.0)?)?;
        }
        if k.imitation > 0.0
            && let Some(imitation) = imitation_sum(&q, &experts, k.temperature)?
        {
            loss = (loss + imitation.affine(k.imitation as f64, 0.0)?)?;
        }
        Ok((loss.affine(1.0 / n as f64, 0.0)?, td))
    }

    /// Loss and gradients (into `ws.grads`) of the rows of `part`, a shard
    /// of a minibatch of `denom` rows, on the fused path: the target network
    /// on `s'`, the online network on `s` (and `s'` in the same batch for
    /// double DQN), the loss's gradient on the taken actions, backward.
    fn shard_fused(
        &self,
        part: &[f32],
        weights: Option<&[f32]>,
        denom: usize,
        ws: &mut Workspace,
    ) -> Result<Shard> {
        let t0 = Instant::now();
        let shapes = self.online.shapes();
        let (ol, tl, na) = (shapes.obs_len(), shapes.transition_len(), shapes.actions);
        let n = part.len() / tl;
        let s = Rows { data: part, stride: tl, offset: 0, n, len: ol };
        let s2 = Rows { offset: ol, ..s };
        self.target.with_weights(|w| ws.forward(w, &[s2]))?;
        ws.keep_q(n, na);
        self.online.with_weights(|w| {
            let both = [s, s2];
            ws.forward(w, if self.cfg.double { &both } else { &both[..1] })?;
            // Rows 0..n: Q(s); rows n..2n (double DQN): the online Q(s').
            let mut td = std::mem::take(&mut ws.td);
            td.clear();
            let (q, q_target, dq) = ws.loss_view(n, na);
            let mut loss = 0.0;
            let mut stats = UpdateStats { rows: n as u32, ..UpdateStats::default() };
            for (i, t) in part.chunks_exact(tl).enumerate() {
                let qt = &q_target[i * na..(i + 1) * na];
                let y = self.target_of(
                    t,
                    qt,
                    if self.cfg.double { &q[(n + i) * na..(n + i + 1) * na] } else { qt },
                );
                let at = i * na + t[2 * ol] as usize;
                let (l, g) = self.huber(q[at] - y);
                let (w, k) = (weights.map_or(1.0, |w| w[i]), self.teaching);
                loss += k.td * l * w;
                dq[at] = k.td * g * w / denom as f32;
                let (row, label) = (&q[i * na..(i + 1) * na], t[2 * ol + 3]);
                let mask = label_mask(label, na).unwrap_or(0);
                if k.margin > 0.0
                    && let Some(e) = label_action(label)
                {
                    let (m, best) = self.margin_of(row, e);
                    loss += k.margin * m;
                    dq[i * na + best] += k.margin / denom as f32;
                    dq[i * na + e] -= k.margin / denom as f32;
                    stats.margin_sum += m as f64;
                }
                if k.imitation > 0.0 && mask != 0 {
                    let grad = &mut dq[i * na..(i + 1) * na];
                    let scale = k.imitation / denom as f32;
                    let ce = imitation_row(row, mask, k.temperature, scale, grad);
                    loss += k.imitation * ce;
                }
                if (k.margin > 0.0 || k.imitation > 0.0) && mask != 0 {
                    stats.labelled += 1;
                    stats.agree += (mask >> argmax(row) & 1) as u32;
                }
                stats.max_q_sum +=
                    q[i * na..(i + 1) * na].iter().fold(f32::NEG_INFINITY, |m, v| m.max(*v)) as f64;
                stats.abs_td_sum += (q[at] - y).abs() as f64;
                stats.terminal += (t[2 * ol + 2] != 0.0) as u32;
                td.push((q[at] - y).abs());
            }
            ws.td = td;
            let t1 = Instant::now();
            ws.backward(w, n)?;
            Ok(Shard {
                loss: loss / denom as f32,
                forward_ns: (t1 - t0).as_nanos() as u64,
                backward_ns: t1.elapsed().as_nanos() as u64,
                stats,
            })
        })
    }

    /// Loss and flat gradients of a whole minibatch (`n × transition_len`
    /// floats) on the path in use, without updating anything.
    pub fn gradients(&mut self, batch: &[f32]) -> Result<(f32, Vec<f32>)> {
        let shard = self.compute_gradients(batch, None)?;
        let loss = shard.loss;
        self.stats = shard.stats;
        Ok((loss, gradients_in(&self.online, &mut self.grads, &mut self.work)?.to_vec()))
    }

    /// Loss and gradients of a minibatch into `self.grads`: on the fused path
    /// with several threads, one shard per thread whose forward and backward
    /// passes run in parallel (each single-threaded), their gradients summed.
    fn compute_gradients(&mut self, batch: &[f32], weights: Option<&[f32]>) -> Result<Shard> {
        let shapes = self.online.shapes();
        let (tl, ol) = (shapes.transition_len(), shapes.obs_len());
        let n = rows_of(batch, shapes)?;
        if let Some(w) = weights
            && w.len() != n
        {
            return Err(ModelError::Shape {
                what: "importance weights (one per row)",
                expected: n,
                got: w.len(),
            });
        }
        if !self.online.fused() {
            let t0 = Instant::now();
            let (loss, td) = self.loss_generic(batch, n, weights)?;
            self.td = td;
            let t1 = Instant::now();
            let store = loss.backward()?;
            self.grads.clear();
            for v in self.online.vars() {
                let g = store
                    .get(v.as_tensor())
                    .ok_or_else(|| ModelError::NoGradient("a parameter got none"))?;
                self.grads.extend(g.flatten_all()?.to_vec1::<f32>()?);
            }
            // The generic path (off the CPU) reports the row and terminal
            // counts only.
            let terminal = batch.chunks_exact(tl).filter(|t| t[2 * ol + 2] != 0.0).count() as u32;
            let stats = UpdateStats { rows: n as u32, terminal, ..UpdateStats::default() };
            return Ok(Shard {
                loss: loss.to_scalar::<f32>()?,
                forward_ns: (t1 - t0).as_nanos() as u64,
                backward_ns: t1.elapsed().as_nanos() as u64,
                stats,
            });
        }
        let shards = self.shards.min(n / 8).max(1);
        while self.work.len() < shards {
            self.work.push(Mutex::new(Workspace::default()));
        }
        let rows_per = n.div_ceil(shards);
        let parts: Vec<&[f32]> = batch.chunks(rows_per * tl).collect();
        let part_weights =
            |i: usize| weights.map(|w| &w[i * rows_per..((i + 1) * rows_per).min(n)]);
        let results = crate::ops::sharded(parts.len(), |i| {
            self.shard_fused(
                parts[i],
                part_weights(i),
                n,
                &mut *self.work[i].lock().map_err(poisoned)?,
            )
        });
        // The other shards' gradients are added into the first's.
        let mut results = results.into_iter();
        let Some(first) = results.next() else { unreachable!("a non-empty batch has a shard") };
        let mut total = first?;
        self.td.clear();
        for ws in &mut self.work[..parts.len()] {
            self.td.extend_from_slice(&ws.get_mut().map_err(poisoned)?.td);
        }
        let (head, tail) = self.work.split_at_mut(1);
        let sum = &mut head[0].get_mut().map_err(poisoned)?.grads[..self.online.num_params()];
        for (r, ws) in results.zip(tail) {
            let r = r?;
            total.loss += r.loss;
            total.stats.add(&r.stats);
            sum.iter_mut().zip(&ws.get_mut().map_err(poisoned)?.grads).for_each(|(a, b)| *a += b);
        }
        Ok(total)
    }

    /// One update on a minibatch of `n × transition_len` floats; returns the
    /// loss. A loss or gradient that is not finite skips the step (the
    /// weights and Adam's moments stay as they were), counts in
    /// [`Dqn::skipped`] and returns the non-finite loss; the minibatch still
    /// counts as an update, so the target schedule and a deterministic run's
    /// weight versions go on. With `max_grad_norm` the gradient is scaled
    /// down to that global L2 norm first.
    pub fn update(&mut self, batch: &[f32]) -> Result<f32> {
        self.update_weighted(batch, None)
    }

    /// [`Dqn::update`] with each row's loss multiplied by its importance
    /// weight (prioritized replay); [`Dqn::td_abs`] then holds each row's
    /// |TD error| for its new priority.
    pub fn update_weighted(&mut self, batch: &[f32], weights: Option<&[f32]>) -> Result<f32> {
        let mut total = self.compute_gradients(batch, weights)?;
        let t2 = Instant::now();
        let grads = gradients_in(&self.online, &mut self.grads, &mut self.work)?;
        let step = self.opt.step(self.online.vars(), Some(grads), total.loss)?;
        total.stats.grad_norm = step.grad_norm;
        self.stats = total.stats;
        if step.sync_target {
            self.sync_target()?;
        }
        if !step.applied {
            return Ok(step.reported(total.loss));
        }
        self.timing = UpdateTiming {
            forward_ns: total.forward_ns,
            backward_ns: total.backward_ns,
            optimiser_ns: t2.elapsed().as_nanos() as u64,
        };
        Ok(total.loss)
    }

    /// Saves the whole learner state (both networks, Adam's moments and step,
    /// the update count) as one safetensors file, atomically.
    pub fn save_state(&self, path: &Path) -> Result<()> {
        let nets = (self.online.vars(), self.target.vars());
        let o = &self.opt.adam;
        let specs = params(self.online.shapes(), self.online.layers());
        checkpoint::save_state(path, &specs, nets, (&o.m, &o.v, o.t), self.opt.updates)
    }

    /// Restores a state written by [`Dqn::save_state`], checking every tensor.
    pub fn load_state(&mut self, path: &Path) -> Result<()> {
        let specs = params(self.online.shapes(), self.online.layers());
        let st = checkpoint::read_state(path, &specs)?;
        let file = path.display().to_string();
        self.online.load_named(&st.online, &file)?;
        self.target.load_named(&st.target, &file)?;
        (self.opt.adam.m, self.opt.adam.v, self.opt.adam.t) = (st.m, st.v, st.t);
        self.opt.updates = st.updates;
        Ok(())
    }
}

#[cfg(test)]
impl Dqn {
    /// One Adam step with given gradients (tests compare it with candle-nn).
    pub(crate) fn opt_step(&mut self, grads: &[f32]) -> Result<()> {
        self.opt.adam.step_vars(self.online.vars(), grads)
    }

    /// Adam's first moments, flat (tests check what clipping fed it).
    pub(crate) fn first_moments(&self) -> Vec<f32> {
        self.opt.adam.m.concat()
    }
}

#[cfg(test)]
mod schedule_tests {
    use super::*;

    #[test]
    fn the_learning_rate_falls_linearly_then_holds() {
        let cfg = DqnConfig {
            lr: 1e-3,
            lr_final: 2e-4,
            lr_decay_updates: 100,
            gamma: 0.9,
            target_update: 10,
            huber_delta: 1.0,
            double: true,
            reward_scale: 1.0,
            max_grad_norm: 0.0,
            margin: 0.8,
        };
        let adam = optimiser(&cfg, Shapes::PAPER, Layers::DEFAULT).adam;
        let close = |a: f32, b: f32| (a - b).abs() < 1e-9;
        assert!(close(adam.lr_at(1), 1e-3));
        assert!(close(adam.lr_at(51), 6e-4), "{}", adam.lr_at(51));
        assert!(close(adam.lr_at(101), 2e-4));
        assert!(close(adam.lr_at(10_000), 2e-4));
        let constant =
            optimiser(&DqnConfig { lr_decay_updates: 0, ..cfg }, Shapes::PAPER, Layers::DEFAULT)
                .adam;
        assert!(close(constant.lr_at(10_000), 1e-3));
    }
}
