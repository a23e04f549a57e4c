//! A probe, not part of the trainer: does memory let a Q-learner fly a
//! level with moving obstacles (L4) within the issue's five minutes?
//!
//! One process: the level's simulator, an epsilon-greedy actor
//! that carries each agent's GRU state, a replay of overlapping sequences
//! (each with the state it started from: R2D2's stored state, a burn-in of
//! `BURN` steps, `TRAIN` trained steps, `NSTEP`-step double-DQN targets)
//! and a learner unrolling the GRU with candle's stock ops. With `none` the
//! same network has its state zeroed at every step: no memory, all else
//! equal. The depth reaches the network reduced (candle's stock
//! convolutions ran at 0.36 s per update of 16 sequences, 40 times too
//! slow for five minutes): `scan`, each frame's nearest depth per column
//! over the middle rows (as the reactive rule reads it); `pool`, each
//! frame's nearest depth per 4 × 4 block (8 × 8 values); or
//! `features:CHECKPOINT`, the 64 `fc1` activations of a trained
//! checkpoint of the trainer's network (of the level's shapes), frozen:
//! what a memoryless policy learned to see, computed once per observation
//! by the actor (stock convolutions, forward only), so that the probe
//! learns only the memory and the Q head on top.
//!
//! ```text
//! cargo run --release -p rotorhive-experiments --example drqn_probe -- \
//!     LEVEL SECONDS SEED (gru|none) (scan|pool|features:CHECKPOINT) \
//!     [SEQUENCES_PER_UPDATE]
//! ```
//!
//! It prints its progress every 30 s and, at the end, the greedy policy's
//! pooled success over 500 episodes of the level's held-out test layouts.

use anyhow::{Context, bail};
use candle_core::{D, DType, Device, Module, Tensor, Var};
use candle_nn::rnn::{GRU, GRUConfig, GRUState, RNN};
use candle_nn::{AdamW, Linear, Optimizer, VarBuilder, VarMap};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rotorhive_model::{QNet, Shapes, argmax};
use rotorhive_roles::Config;
use rotorhive_roles::eval::nearest_per_column;
use rotorhive_sim::{Arena, Done, SimConfig, VecEnv};
use std::collections::VecDeque;
use std::time::Instant;

/// The GRU's state.
const HID: usize = 64;
/// Steps that only warm the state up.
const BURN: usize = 8;
/// Steps trained per sequence (and between two sequences of one agent).
const TRAIN: usize = 12;
/// Steps of return before bootstrapping.
const NSTEP: usize = 3;
/// Observations in a sequence.
const WIN: usize = BURN + TRAIN + NSTEP;
const GAMMA: f32 = 0.99;
/// As the trainer's `sim.reward_scale`.
const REWARD_SCALE: f32 = 0.01;
/// Sequences kept: 200,000 trained steps, as the trainer's replay.
const CAPACITY: usize = 200_000 / TRAIN;
/// Sequences before the first update: 15,000 steps, as `replay.min_fill`.
const MIN_FILL: usize = 15_000 / TRAIN;
/// Agent-steps over which epsilon falls from 1 to 0.1 (`actor.eps_decay`).
const EPS_DECAY: f64 = 150_000.0;
/// Updates between two copies of the online network to the target.
const TARGET_EVERY: u64 = 100;
const SIDE: usize = 32;

/// How the depth frames reach the network.
enum Input {
    Scan,
    Pool,
    /// The layers up to `fc1` (its 64 activations) of a trained
    /// checkpoint of the trainer's network, frozen.
    Features(Box<Frozen>),
}

impl Input {
    fn name(&self) -> &'static str {
        match self {
            Input::Scan => "scan",
            Input::Pool => "pool",
            Input::Features(_) => "features",
        }
    }

    /// Floats per observation as the network reads it.
    fn width(&self, shapes: Shapes) -> usize {
        match self {
            Input::Scan => shapes.frames * SIDE + shapes.scalars,
            Input::Pool => shapes.frames * 64 + shapes.scalars,
            Input::Features(_) => 64,
        }
    }

    /// Rows of observations (`obs_len` floats: `frames` depth frames, then
    /// the scalars) as the network reads them.
    fn reduce(&self, obs: &[f32], shapes: Shapes) -> anyhow::Result<Vec<f32>> {
        let (ol, frames) = (shapes.obs_len(), shapes.frames);
        if let Input::Features(f) = self {
            return f.features(obs);
        }
        let mut out = Vec::with_capacity(obs.len() / ol * self.width(shapes));
        for o in obs.chunks_exact(ol) {
            for img in o.chunks_exact(SIDE * SIDE).take(frames) {
                if matches!(self, Input::Scan) {
                    out.extend(nearest_per_column(img, SIDE));
                } else {
                    out.extend((0..64).map(|b| {
                        let (by, bx) = (b / 8 * 4, b % 8 * 4);
                        (0..16)
                            .map(|k| img[(by + k / 4) * SIDE + bx + k % 4])
                            .fold(f32::INFINITY, f32::min)
                    }));
                }
            }
            out.extend_from_slice(&o[frames * SIDE * SIDE..]);
        }
        Ok(out)
    }
}

/// A trained network, frozen: its `fc1` activations ([`QNet::features`]).
struct Frozen {
    net: QNet,
    obs_len: usize,
}

impl Frozen {
    fn load(path: &str, shapes: Shapes) -> anyhow::Result<Self> {
        let net = QNet::with_shapes(shapes, 0, &Device::Cpu)?;
        net.load(std::path::Path::new(path)).with_context(|| format!("checkpoint {path}"))?;
        Ok(Frozen { net, obs_len: shapes.obs_len() })
    }

    fn features(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        let x = Tensor::from_slice(obs, (obs.len() / self.obs_len, self.obs_len), &Device::Cpu)?;
        Ok(self.net.features(&x)?.flatten_all()?.to_vec1()?)
    }
}

/// Two dense layers, a GRU cell, the Q head.
struct Net {
    l1: Linear,
    l2: Linear,
    gru: GRU,
    head: Linear,
    memory: bool,
}

impl Net {
    fn new(vm: &VarMap, input: usize, actions: usize, memory: bool) -> candle_core::Result<Self> {
        let vb = VarBuilder::from_varmap(vm, DType::F32, &Device::Cpu);
        Ok(Net {
            l1: candle_nn::linear(input, 128, vb.pp("l1"))?,
            l2: candle_nn::linear(128, HID, vb.pp("l2"))?,
            gru: candle_nn::rnn::gru(HID, HID, GRUConfig::default(), vb.pp("gru"))?,
            head: candle_nn::linear(HID, actions, vb.pp("head"))?,
            memory,
        })
    }

    /// Rows of reduced observations to the GRU's input.
    fn encode(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        self.l2.forward(&self.l1.forward(x)?.relu()?)?.relu()
    }

    /// One step from state `h`: the Q-values and the next state.
    fn step(&self, feat: &Tensor, h: &Tensor) -> candle_core::Result<(Tensor, Tensor)> {
        let h = if self.memory { h.clone() } else { h.zeros_like()? };
        let next = self.gru.step(feat, &GRUState { h })?.h;
        Ok((self.head.forward(&next)?, next))
    }
}

/// `WIN` consecutive steps of one agent (across episode ends).
struct Sequence {
    obs: Vec<f32>,
    actions: Vec<u32>,
    rewards: Vec<f32>,
    dones: Vec<f32>,
    /// The actor's state before the first observation.
    h0: Vec<f32>,
}

/// One step of an agent as the actor saw it.
struct Step {
    obs: Vec<f32>,
    h: Vec<f32>,
    action: u8,
    reward: f32,
    done: bool,
}

/// The command line.
struct Args {
    level: String,
    seconds: f64,
    seed: u64,
    memory: bool,
    input: Input,
    sequences: usize,
}

fn args() -> anyhow::Result<Args> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() < 5 || a.len() > 6 {
        bail!(
            "usage: drqn_probe LEVEL SECONDS SEED (gru|none) (scan|pool|features:CHECKPOINT) \
             [SEQUENCES_PER_UPDATE]"
        );
    }
    let memory = match a[3].as_str() {
        "gru" => true,
        "none" => false,
        m => bail!("memory {m:?}: gru or none"),
    };
    let input = match a[4].as_str() {
        "scan" => Input::Scan,
        "pool" => Input::Pool,
        i if i.starts_with("features:") => {
            let cfg = Config::level(&a[0], &[])?;
            Input::Features(Box::new(Frozen::load(&i[9..], cfg.shapes())?))
        }
        i => bail!("input {i:?}: scan, pool or features:CHECKPOINT"),
    };
    Ok(Args {
        level: a[0].clone(),
        seconds: a[1].parse().with_context(|| format!("SECONDS {:?}", a[1]))?,
        seed: a[2].parse().with_context(|| format!("SEED {:?}", a[2]))?,
        memory,
        input,
        sequences: a.get(5).map_or(Ok(16), |s| s.parse()).context("SEQUENCES_PER_UPDATE")?,
    })
}

fn main() -> anyhow::Result<()> {
    let args = args()?;
    let cfg = Config::level(&args.level, &[format!("seed={}", args.seed)])?;
    let sim = cfg.sim_config();
    let shapes = sim.shapes();
    let input = args.input.width(shapes);
    let (vm, tvm) = (VarMap::new(), VarMap::new());
    let online = Net::new(&vm, input, shapes.actions, args.memory)?;
    let target = Net::new(&tvm, input, shapes.actions, args.memory)?;
    copy_weights(&vm, &tvm)?;
    let params = candle_nn::ParamsAdamW { lr: 5e-4, weight_decay: 0.0, ..Default::default() };
    let opt = AdamW::new(vm.all_vars(), params)?;
    let mut learner = Learner { online, target, vm, tvm, opt, actions: shapes.actions, updates: 0 };
    let t0 = Instant::now();
    train(&mut learner, &args, &sim, &cfg.lane_arenas(0)?, input)?;
    let success = fly(&learner.online, &args, &sim, &cfg.test_arenas()?, 500)?;
    println!(
        "RESULT level={} seed={} memory={} input={} sequences={} seconds={:.0} updates={} \
         test_success={:.1}%",
        args.level,
        args.seed,
        if args.memory { "gru" } else { "none" },
        args.input.name(),
        args.sequences,
        t0.elapsed().as_secs_f64(),
        learner.updates,
        success * 100.0
    );
    Ok(())
}

/// The acting and training loop, for `args.seconds`.
fn train(
    learner: &mut Learner,
    args: &Args,
    sim: &SimConfig,
    arenas: &[Arena],
    input: usize,
) -> anyhow::Result<()> {
    let agents = sim.agents;
    let mut env = VecEnv::new_lanes(sim.clone(), arenas, args.seed)?;
    let mut rng = Pcg64Mcg::seed_from_u64(args.seed);
    let mut h = vec![0.0f32; agents * HID];
    let mut streams: Vec<VecDeque<Step>> = (0..agents).map(|_| VecDeque::new()).collect();
    let mut replay: Vec<Sequence> = Vec::new();
    let (mut steps, mut inserted, mut trained, mut next_print) = (0u64, 0u64, 0u64, 30.0);
    let mut recent: VecDeque<bool> = VecDeque::new();
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < args.seconds {
        let obs = args.input.reduce(env.observations(), sim.shapes())?;
        let eps = (1.0 - (steps * agents as u64) as f64 / EPS_DECAY * 0.9).max(0.1);
        let (actions, mut next_h) = learner.act(&obs, &h, eps, &mut rng)?;
        for (i, s) in streams.iter_mut().enumerate() {
            let step = (&obs[i * input..(i + 1) * input], &h[i * HID..(i + 1) * HID]);
            push_step(s, step, steps, &mut replay, &mut inserted);
        }
        env.step(&actions)?;
        steps += 1;
        for (i, s) in streams.iter_mut().enumerate() {
            let last = s.back_mut().context("a stream with its step")?;
            (last.action, last.reward) = (actions[i], env.rewards()[i] * REWARD_SCALE);
            last.done = env.dones()[i] != Done::Running;
            if last.done {
                next_h[i * HID..(i + 1) * HID].fill(0.0);
            }
        }
        h = next_h;
        for ep in env.finished() {
            recent.push_back(ep.done == Done::Goal);
            if recent.len() > 200 {
                recent.pop_front();
            }
        }
        // A replay ratio of 1: every stored step trained once on average.
        while replay.len() >= MIN_FILL && trained < inserted {
            let batch: Vec<&Sequence> =
                (0..args.sequences).map(|_| &replay[rng.random_range(0..replay.len())]).collect();
            learner.update(&batch, input)?;
            trained += (args.sequences * TRAIN) as u64;
        }
        let el = t0.elapsed().as_secs_f64();
        if el >= next_print {
            next_print += 30.0;
            let goals = recent.iter().filter(|g| **g).count() as f64 / recent.len().max(1) as f64;
            println!(
                "t={el:.0}s agent-steps/s={:.0} updates={} eps={eps:.2} \
                 success of the last 200 episodes={:.1}%",
                (steps * agents as u64) as f64 / el,
                learner.updates,
                goals * 100.0
            );
        }
    }
    Ok(())
}

/// Appends an agent's step (its observation and the state it acted from)
/// to its stream, and stores the stream as a sequence every `TRAIN` steps
/// once `WIN` are there: trained steps never overlap.
fn push_step(
    s: &mut VecDeque<Step>,
    (obs, h): (&[f32], &[f32]),
    steps: u64,
    replay: &mut Vec<Sequence>,
    inserted: &mut u64,
) {
    s.push_back(Step { obs: obs.to_vec(), h: h.to_vec(), action: 0, reward: 0.0, done: false });
    if s.len() > WIN {
        s.pop_front();
    }
    if (steps as usize + 1).checked_sub(WIN).is_some_and(|d| d.is_multiple_of(TRAIN)) {
        let seq = Sequence {
            obs: s.iter().flat_map(|e| e.obs.iter().copied()).collect(),
            actions: s.iter().map(|e| e.action as u32).collect(),
            rewards: s.iter().map(|e| e.reward).collect(),
            dones: s.iter().map(|e| e.done as u8 as f32).collect(),
            h0: s[0].h.clone(),
        };
        let slot = (*inserted / TRAIN as u64) as usize % CAPACITY;
        if replay.len() < CAPACITY {
            replay.push(seq)
        } else {
            replay[slot] = seq
        }
        *inserted += TRAIN as u64;
    }
}

/// The online and target networks and the optimizer.
struct Learner {
    online: Net,
    target: Net,
    vm: VarMap,
    tvm: VarMap,
    opt: AdamW,
    actions: usize,
    updates: u64,
}

impl Learner {
    /// Epsilon-greedy actions of every agent and their next states.
    fn act(
        &self,
        obs: &[f32],
        h: &[f32],
        eps: f64,
        rng: &mut Pcg64Mcg,
    ) -> anyhow::Result<(Vec<u8>, Vec<f32>)> {
        let n = h.len() / HID;
        let (q, next) = forward(&self.online, obs, h)?;
        let na = self.actions;
        let actions = (0..n)
            .map(|i| {
                if rng.random::<f64>() < eps {
                    rng.random_range(0..na as u8)
                } else {
                    argmax(&q[i * na..(i + 1) * na]) as u8
                }
            })
            .collect();
        Ok((actions, next))
    }

    /// One update on a batch of sequences: the target network and the
    /// online one unrolled from each sequence's stored state, the Huber
    /// loss of the `TRAIN` steps after the burn-in, the gradient clipped to
    /// norm 10, an Adam step; the target copied every `TARGET_EVERY`.
    fn update(&mut self, batch: &[&Sequence], input: usize) -> anyhow::Result<()> {
        let na = self.actions;
        let values = |qs: &[Tensor]| -> candle_core::Result<Vec<Vec<f32>>> {
            qs.iter().map(|q| q.detach().flatten_all()?.to_vec1()).collect()
        };
        let tq = values(&unroll(&self.target, batch, input)?)?;
        let qs = unroll(&self.online, batch, input)?;
        let oq = values(&qs)?;
        let mut losses = Vec::new();
        for t in BURN..BURN + TRAIN {
            let mut y = Vec::with_capacity(batch.len());
            for (b, s) in batch.iter().enumerate() {
                let (mut ret, mut disc) = (0.0, 1.0);
                let ended = (0..NSTEP).any(|k| {
                    ret += disc * s.rewards[t + k];
                    disc *= GAMMA;
                    s.dones[t + k] != 0.0
                });
                if !ended {
                    let pick = argmax(&oq[t + NSTEP][b * na..(b + 1) * na]);
                    ret += disc * tq[t + NSTEP][b * na + pick];
                }
                y.push(ret);
            }
            let a: Vec<u32> = batch.iter().map(|s| s.actions[t]).collect();
            let q =
                qs[t].gather(&Tensor::from_vec(a, (batch.len(), 1), &Device::Cpu)?, D::Minus1)?;
            let e = (q - Tensor::from_vec(y, (batch.len(), 1), &Device::Cpu)?)?.abs()?;
            let c = e.clamp(0.0, 1.0)?;
            losses.push(((c.sqr()? * 0.5)? + (e - &c)?)?);
        }
        let mut grads = Tensor::cat(&losses, 0)?.mean_all()?.backward()?;
        let vars: Vec<Var> = self.vm.all_vars();
        let mut norm = 0.0f32;
        for v in &vars {
            if let Some(g) = grads.get(v.as_tensor()) {
                norm += g.sqr()?.sum_all()?.to_scalar::<f32>()?;
            }
        }
        let norm = norm.sqrt();
        if norm > 10.0 {
            for v in &vars {
                if let Some(g) = grads.remove(v.as_tensor()) {
                    grads.insert(v.as_tensor(), (g * f64::from(10.0 / norm))?);
                }
            }
        }
        self.opt.step(&grads)?;
        self.updates += 1;
        if self.updates.is_multiple_of(TARGET_EVERY) {
            copy_weights(&self.vm, &self.tvm)?;
        }
        Ok(())
    }
}

/// One step of `net` for rows of reduced observations from states `h`:
/// the Q-values and the next states, as plain floats.
fn forward(net: &Net, obs: &[f32], h: &[f32]) -> candle_core::Result<(Vec<f32>, Vec<f32>)> {
    let n = h.len() / HID;
    let x = Tensor::from_slice(obs, (n, obs.len() / n), &Device::Cpu)?;
    let h = Tensor::from_slice(h, (n, HID), &Device::Cpu)?;
    let (q, next) = net.step(&net.encode(&x)?, &h)?;
    Ok((q.flatten_all()?.to_vec1()?, next.flatten_all()?.to_vec1()?))
}

/// The Q-values of `net` at every step of the sequences, unrolled from
/// their stored states (the state zeroed after an episode's end, cut from
/// the gradient after the burn-in).
fn unroll(net: &Net, batch: &[&Sequence], input: usize) -> candle_core::Result<Vec<Tensor>> {
    let (n, dev) = (batch.len(), &Device::Cpu);
    // Time-major rows: t × n + b.
    let mut obs = Vec::with_capacity(WIN * n * input);
    for t in 0..WIN {
        for s in batch {
            obs.extend_from_slice(&s.obs[t * input..(t + 1) * input]);
        }
    }
    let feat = net.encode(&Tensor::from_vec(obs, (WIN * n, input), dev)?)?;
    let h0: Vec<f32> = batch.iter().flat_map(|s| s.h0.iter().copied()).collect();
    let mut h = Tensor::from_vec(h0, (n, HID), dev)?;
    let mut qs = Vec::with_capacity(WIN);
    for t in 0..WIN {
        if t > 0 {
            let keep: Vec<f32> = batch.iter().map(|s| 1.0 - s.dones[t - 1]).collect();
            h = h.broadcast_mul(&Tensor::from_vec(keep, (n, 1), dev)?)?;
        }
        if t == BURN {
            h = h.detach();
        }
        let (q, next) = net.step(&feat.narrow(0, t * n, n)?, &h)?;
        h = next;
        qs.push(q);
    }
    Ok(qs)
}

fn copy_weights(from: &VarMap, to: &VarMap) -> anyhow::Result<()> {
    let src = from.data().lock().map_err(|_| anyhow::anyhow!("poisoned"))?;
    let dst = to.data().lock().map_err(|_| anyhow::anyhow!("poisoned"))?;
    for (k, v) in src.iter() {
        dst.get(k).context("the target has every weight")?.set(v.as_tensor())?;
    }
    Ok(())
}

/// Greedy success over the first episodes of `episodes` agents shared
/// among the layouts, each flown alone.
fn fly(
    net: &Net,
    args: &Args,
    sim: &SimConfig,
    layouts: &[Arena],
    episodes: usize,
) -> anyhow::Result<f64> {
    let per = episodes / layouts.len();
    let mut goals = 0;
    for (k, a) in layouts.iter().enumerate() {
        let cfg = SimConfig { agents: per, ..sim.clone() };
        let mut env = VecEnv::new_lanes(cfg, std::slice::from_ref(a), 7 + k as u64)?;
        let mut h = vec![0.0f32; per * HID];
        let mut result: Vec<Option<Done>> = vec![None; per];
        for _ in 0..=sim.max_steps {
            let obs = args.input.reduce(env.observations(), sim.shapes())?;
            let (q, mut next) = forward(net, &obs, &h)?;
            let na = q.len() / per;
            let actions: Vec<u8> =
                (0..per).map(|i| argmax(&q[i * na..(i + 1) * na]) as u8).collect();
            env.step(&actions)?;
            for i in 0..per {
                if env.dones()[i] != Done::Running {
                    next[i * HID..(i + 1) * HID].fill(0.0);
                }
            }
            h = next;
            for ep in env.finished() {
                result[ep.agent].get_or_insert(ep.done);
            }
            if result.iter().all(Option::is_some) {
                break;
            }
        }
        goals += result.iter().filter(|d| **d == Some(Done::Goal)).count();
    }
    Ok(goals as f64 / (per * layouts.len()) as f64)
}
