//! The DQN update: online and target networks, the TD-Huber loss and Adam,
//! with the whole learner state (weights, optimiser moments, counters)
//! saved and restored as one safetensors file.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use candle_core::{D, DType, Tensor};

use crate::ops::{AdamHyper, AdamStep, TdHuber, adam};
use crate::{ACTIONS, ModelError, OBS_LEN, PARAMS, QNet, Result, TRANSITION_LEN, argmax};

/// Hyper-parameters of the DQN update.
#[derive(Debug, Clone, Copy)]
pub struct DqnConfig {
    /// Adam learning rate.
    pub lr: f64,
    /// Discount.
    pub gamma: f32,
    /// Updates between target-network copies.
    pub target_update: u64,
    /// Huber loss threshold.
    pub huber_delta: f32,
    /// Double DQN: the online network picks the next action, the target
    /// network values it.
    pub double: bool,
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

/// Adam without weight decay; the moments are plain vectors so the fused
/// path updates every parameter in place in one pass.
struct Adam {
    lr: f32,
    t: u64,
    m: Vec<Vec<f32>>,
    v: Vec<Vec<f32>>,
}

impl Adam {
    fn new(lr: f64) -> Self {
        let sizes = PARAMS.iter().map(|(_, s)| s.iter().product::<usize>());
        Self { lr: lr as f32, t: 0, m: sizes.clone().map(|n| vec![0.0; n]).collect(), v: sizes.map(|n| vec![0.0; n]).collect() }
    }

    /// One step with the gradients of every parameter, in canonical order.
    fn step(&mut self, net: &QNet, grads: &[Tensor]) -> Result<()> {
        self.t += 1;
        let hyper = AdamHyper { lr: self.lr, beta1: 0.9, beta2: 0.999, eps: 1e-8, t: self.t };
        for (((var, m), v), g) in net.vars().iter().zip(&mut self.m).zip(&mut self.v).zip(grads) {
            if var.device().is_cpu() {
                let op = AdamStep { moments: Mutex::new((m.as_mut_slice(), v.as_mut_slice())), hyper };
                var.as_tensor().inplace_op2(&g.contiguous()?, &op)?;
            } else {
                let mut p = var.as_tensor().flatten_all()?.to_vec1::<f32>()?;
                let g = g.flatten_all()?.to_vec1::<f32>()?;
                adam(&mut p, &g, m, v, hyper);
                var.set(&Tensor::from_vec(p, var.shape(), var.device())?)?;
            }
        }
        Ok(())
    }
}

/// A minibatch split into its parts.
struct Batch {
    n: usize,
    s: Vec<f32>,
    s2: Vec<f32>,
    actions: Vec<u32>,
    rewards: Vec<f32>,
    dones: Vec<f32>,
}

impl Batch {
    fn split(batch: &[f32]) -> Result<Self> {
        if batch.is_empty() || !batch.len().is_multiple_of(TRANSITION_LEN) {
            return Err(ModelError::Shape { what: "minibatch", expected: TRANSITION_LEN, got: batch.len() });
        }
        let n = batch.len() / TRANSITION_LEN;
        let mut b = Batch {
            n,
            s: Vec::with_capacity(n * OBS_LEN),
            s2: Vec::with_capacity(n * OBS_LEN),
            actions: Vec::with_capacity(n),
            rewards: Vec::with_capacity(n),
            dones: Vec::with_capacity(n),
        };
        for t in batch.chunks_exact(TRANSITION_LEN) {
            b.s.extend_from_slice(&t[..OBS_LEN]);
            b.s2.extend_from_slice(&t[OBS_LEN..2 * OBS_LEN]);
            let a = t[2 * OBS_LEN];
            if !(a >= 0.0 && (a as usize) < ACTIONS && a.fract() == 0.0) {
                return Err(ModelError::Shape { what: "minibatch action (0 or 1)", expected: ACTIONS, got: a as usize });
            }
            b.actions.push(a as u32);
            b.rewards.push(t[2 * OBS_LEN + 1]);
            b.dones.push(t[2 * OBS_LEN + 2]);
        }
        Ok(b)
    }
}

/// One shard's share of an update.
struct Shard {
    loss: f32,
    grads: Vec<Tensor>,
    forward_ns: u64,
    backward_ns: u64,
}

/// A DQN learner: online network, target network and Adam.
pub struct Dqn {
    /// The online network.
    pub online: QNet,
    pub(crate) target: QNet,
    opt: Adam,
    cfg: DqnConfig,
    updates: u64,
    timing: UpdateTiming,
    shards: usize,
}

impl Dqn {
    /// A learner with freshly initialised networks.
    pub fn new(cfg: DqnConfig, seed: u64, device: &candle_core::Device) -> Result<Self> {
        let online = QNet::new(seed, device)?;
        let target = QNet::new(seed, device)?;
        Ok(Self { online, target, opt: Adam::new(cfg.lr), cfg, updates: 0, timing: UpdateTiming::default(), shards: 1 })
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
        self.updates
    }

    /// Timing of the last update.
    pub fn timing(&self) -> UpdateTiming {
        self.timing
    }

    /// Copies the online weights into the target network.
    pub fn sync_target(&self) -> Result<()> {
        self.target.copy_from(&self.online)
    }

    /// The TD targets `r + γ (1 − done) Q'(s', a*)` of a batch.
    fn targets(&self, b: &Batch) -> Result<Vec<f32>> {
        let dev = self.online.device();
        let s2 = Tensor::from_slice(&b.s2, (b.n, OBS_LEN), dev)?;
        let q_target = self.target.forward(&s2)?.detach().flatten_all()?.to_vec1::<f32>()?;
        let next: Vec<f32> = if self.cfg.double {
            let q_online = self.online.forward(&s2)?.detach().flatten_all()?.to_vec1::<f32>()?;
            q_online.chunks(ACTIONS).zip(q_target.chunks(ACTIONS)).map(|(o, t)| t[argmax(o)]).collect()
        } else {
            q_target.chunks(ACTIONS).map(|t| t[argmax(t)]).collect()
        };
        Ok((0..b.n).map(|i| b.rewards[i] + self.cfg.gamma * (1.0 - b.dones[i]) * next[i]).collect())
    }

    /// The Huber TD loss of `b` summed and divided by `denom`.
    fn loss_of(&self, b: &Batch, denom: usize) -> Result<Tensor> {
        let y = self.targets(b)?;
        let dev = self.online.device();
        let q = self.online.forward(&Tensor::from_slice(&b.s, (b.n, OBS_LEN), dev)?)?;
        if self.online.fused() {
            let op = TdHuber { actions: Arc::new(b.actions.clone()), targets: Arc::new(y), delta: self.cfg.huber_delta, denom };
            return Ok(q.apply_op1(op)?);
        }
        let a = Tensor::from_slice(&b.actions, (b.n, 1), dev)?;
        let y = Tensor::from_vec(y, (b.n, 1), dev)?;
        let abs = (q.gather(&a, D::Minus1)? - y)?.abs()?;
        let d = self.cfg.huber_delta as f64;
        let c = abs.clamp(0.0, d)?;
        let loss = ((c.sqr()? * 0.5)? + ((abs - &c)? * d)?)?;
        Ok(loss.sum_all()?.affine(1.0 / denom as f64, 0.0)?)
    }

    /// The mean Huber TD loss of a minibatch (`n × TRANSITION_LEN` floats),
    /// differentiable with respect to the online network.
    pub fn loss(&self, batch: &[f32]) -> Result<Tensor> {
        let b = Batch::split(batch)?;
        self.loss_of(&b, b.n)
    }

    /// Loss and gradients of the rows `part` of a minibatch of `denom` rows.
    fn shard(&self, part: &[f32], denom: usize) -> Result<Shard> {
        let t0 = Instant::now();
        let loss = self.loss_of(&Batch::split(part)?, denom)?;
        let value = loss.to_scalar::<f32>()?;
        let t1 = Instant::now();
        let store = loss.backward()?;
        let grads = self
            .online
            .vars()
            .iter()
            .map(|v| store.get(v.as_tensor()).cloned().ok_or_else(|| ModelError::Device("a parameter got no gradient".into())))
            .collect::<Result<Vec<_>>>()?;
        let t2 = Instant::now();
        Ok(Shard { loss: value, grads, forward_ns: (t1 - t0).as_nanos() as u64, backward_ns: (t2 - t1).as_nanos() as u64 })
    }

    /// One update on a minibatch of `n × TRANSITION_LEN` floats; returns the
    /// loss. On the fused path with several threads, the minibatch is split
    /// into one shard per thread whose forward and backward passes run in
    /// parallel (each single-threaded); their gradients are summed.
    pub fn update(&mut self, batch: &[f32]) -> Result<f32> {
        if batch.is_empty() || !batch.len().is_multiple_of(TRANSITION_LEN) {
            return Err(ModelError::Shape { what: "minibatch", expected: TRANSITION_LEN, got: batch.len() });
        }
        let n = batch.len() / TRANSITION_LEN;
        let shards = if self.online.fused() { self.shards.min(n / 8).max(1) } else { 1 };
        let parts: Vec<&[f32]> = batch.chunks(n.div_ceil(shards) * TRANSITION_LEN).collect();
        let results = crate::ops::sharded(parts.len(), |i| self.shard(parts[i], n));
        let mut shards = results.into_iter().collect::<Result<Vec<_>>>()?.into_iter();
        let Some(mut total) = shards.next() else { unreachable!("a non-empty batch has a shard") };
        for s in shards {
            total.loss += s.loss;
            for (a, b) in total.grads.iter_mut().zip(&s.grads) {
                *a = (&*a + b)?;
            }
        }
        let t2 = Instant::now();
        self.opt.step(&self.online, &total.grads)?;
        self.updates += 1;
        if self.updates.is_multiple_of(self.cfg.target_update) {
            self.sync_target()?;
        }
        self.timing = UpdateTiming { forward_ns: total.forward_ns, backward_ns: total.backward_ns, optimiser_ns: t2.elapsed().as_nanos() as u64 };
        Ok(total.loss)
    }

    /// Saves the whole learner state (both networks, Adam's moments and step,
    /// the update count) as one safetensors file, atomically.
    pub fn save_state(&self, path: &Path) -> Result<()> {
        let dev = candle_core::Device::Cpu;
        let mut map: HashMap<String, Tensor> = HashMap::new();
        for ((name, shape), ((o, t), (m, v))) in PARAMS.iter().zip(self.online.vars().iter().zip(self.target.vars()).zip(self.opt.m.iter().zip(&self.opt.v))) {
            map.insert(format!("online.{name}"), o.as_tensor().to_device(&dev)?);
            map.insert(format!("target.{name}"), t.as_tensor().to_device(&dev)?);
            map.insert(format!("adam_m.{name}"), Tensor::from_slice(m, *shape, &dev)?);
            map.insert(format!("adam_v.{name}"), Tensor::from_slice(v, *shape, &dev)?);
        }
        map.insert("adam_t".into(), Tensor::new(&[self.opt.t as i64], &dev)?);
        map.insert("updates".into(), Tensor::new(&[self.updates as i64], &dev)?);
        let tmp = path.with_extension("tmp");
        candle_core::safetensors::save(&map, &tmp)?;
        std::fs::rename(&tmp, path).map_err(|e| ModelError::Checkpoint { file: path.display().to_string(), message: format!("cannot write: {e}") })?;
        Ok(())
    }

    /// Restores a state written by [`Dqn::save_state`], checking every tensor.
    pub fn load_state(&mut self, path: &Path) -> Result<()> {
        let file = path.display().to_string();
        let bad = |message: String| ModelError::Checkpoint { file: file.clone(), message };
        let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read: {e}")))?;
        let map = candle_core::safetensors::load_buffer(&bytes, &candle_core::Device::Cpu).map_err(|e| bad(format!("not a valid safetensors file: {e}")))?;
        let sub =
            |prefix: &str| -> HashMap<String, Tensor> { map.iter().filter_map(|(k, v)| k.strip_prefix(prefix).map(|n| (n.to_string(), v.clone()))).collect() };
        let counter = |name: &str| -> Result<u64> {
            let t = map.get(name).ok_or_else(|| bad(format!("tensor `{name}` is missing")))?;
            let v = t.to_dtype(DType::I64)?.flatten_all()?.to_vec1::<i64>()?;
            match v.as_slice() {
                [x] if *x >= 0 => Ok(*x as u64),
                _ => Err(bad(format!("tensor `{name}` is not one non-negative count"))),
            }
        };
        let (t, updates) = (counter("adam_t")?, counter("updates")?);
        let mut moments = Vec::new();
        for prefix in ["adam_m.", "adam_v."] {
            let part = sub(prefix);
            let mut vecs = Vec::new();
            for (name, shape) in PARAMS {
                let x = part.get(name).ok_or_else(|| bad(format!("tensor `{prefix}{name}` is missing")))?;
                if x.dims() != shape {
                    return Err(bad(format!("tensor `{prefix}{name}` has shape {:?}, the network needs {shape:?}", x.dims())));
                }
                vecs.push(x.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?);
            }
            moments.push(vecs);
        }
        self.online.load_named(&sub("online."), &file)?;
        self.target.load_named(&sub("target."), &file)?;
        self.opt.v = moments.pop().unwrap_or_default();
        self.opt.m = moments.pop().unwrap_or_default();
        self.opt.t = t;
        self.updates = updates;
        Ok(())
    }
}

#[cfg(test)]
impl Dqn {
    /// One Adam step with given gradients (tests compare it with candle-nn).
    pub(crate) fn opt_step(&mut self, grads: &candle_core::backprop::GradStore) -> Result<()> {
        let grads: Vec<Tensor> = self.online.vars().iter().map(|v| grads.get(v.as_tensor()).unwrap().clone()).collect();
        self.opt.step(&self.online, &grads)
    }
}
