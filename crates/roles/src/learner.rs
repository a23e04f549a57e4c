//! `hive learner`: DQN updates on the minibatches the replay process queues,
//! weights published by version, checkpoints as safetensors. Also the learner
//! benchmark, which measures the same update path.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::error::{Doing, Result, RoleError, protocol_err};
use rotorhive_model::{Dqn, DqnConfig, QNet, Teaching};
use rotorhive_msg::{
    LearnerStage, MinibatchHeader, PICK_WORDS, Pick, PriorityHeader, RoleKind, Shapes, Telemetry,
    WeightsHeader,
};
use rotorhive_transport::Channel;

use rotorhive_transport::Service;

use crate::config::Config;
use crate::ctx::{Ctx, POLL, STALL_TIMEOUT, roles_of};

pub mod recurrent;

/// The DQN settings of a config's `[learner]`.
pub fn dqn_config(cfg: &Config) -> DqnConfig {
    let l = &cfg.learner;
    DqnConfig {
        lr: l.lr,
        lr_final: l.lr_final,
        lr_decay_updates: l.lr_decay_updates,
        gamma: (l.gamma as f32).powi(l.n_step as i32),
        target_update: l.target_update,
        huber_delta: l.huber_delta as f32,
        double: l.double_dqn,
        reward_scale: l.reward_scale as f32,
        max_grad_norm: l.max_grad_norm as f32,
        margin: cfg.teacher.margin as f32,
    }
}

/// Writes a checkpoint (atomically: `QNet::save_with` goes through
/// `rotorhive_msg::durable`).
fn save_atomic(net: &QNet, path: &Path, tags: &[(&str, String)]) -> Result<()> {
    net.save_with(path, tags).doing_with(|| format!("cannot write checkpoint {}", path.display()))
}

/// Writes the learner's whole state (atomically, as `Dqn::save_state` does).
fn save_state_atomic(dqn: &Dqn, path: &Path) -> Result<()> {
    dqn.save_state(path).doing_with(|| format!("cannot write learner state {}", path.display()))
}

/// A learner with the config's network and optimiser; a restarted (or
/// resumed) one goes on from its last saved state at `state_path`:
/// weights, target, Adam moments and counters.
fn restore(cfg: &crate::config::Config, state_path: &Path) -> Result<Dqn> {
    let mut dqn = Dqn::with_layers(
        dqn_config(cfg),
        cfg.shapes(),
        cfg.layers(),
        crate::streams::network(cfg.seed),
        &rotorhive_model::device(cfg.learner.device.kind())?,
    )?;
    dqn.set_threads(cfg.learner.threads);
    if state_path.exists() {
        dqn.load_state(state_path)
            .doing_with(|| format!("restoring the learner from {}", state_path.display()))?;
        tracing::info!(
            "learner restored from {} at update {}",
            state_path.display(),
            dqn.updates()
        );
    }
    Ok(dqn)
}

/// Logs what a checkpoint cost the learner (it saves every
/// `checkpoint_every_s`).
fn log_saves(saves: (u32, Duration)) {
    if saves.0 > 0 {
        tracing::info!(
            "learner: {} checkpoints, {:.2} ms each on average",
            saves.0,
            saves.1.as_secs_f64() * 1e3 / saves.0 as f64
        );
    }
}

/// Saves the newest weights and the whole learner state, counting the
/// saves and their time in `saves`.
fn checkpoint(
    dqn: &Dqn,
    ckpt_dir: &Path,
    state_path: &Path,
    tags: &[(&str, String)],
    saves: &mut (u32, Duration),
) -> Result<()> {
    let t = Instant::now();
    save_atomic(&dqn.online, &ckpt_dir.join("latest.safetensors"), tags)?;
    save_state_atomic(dqn, state_path)?;
    saves.0 += 1;
    saves.1 += t.elapsed();
    Ok(())
}

/// Runs the learner until the run stops.
pub fn run<S: Service>(cx: Ctx<'_, S>) -> Result<()> {
    if let (Some(width), Some(layout)) = (cx.cfg.memory(), cx.cfg.seq_layout()) {
        return recurrent::run(cx, width, layout);
    }
    let (cfg, hub) = (cx.cfg, cx.hub);
    let run_dir = cx.run_dir.map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    let ckpt_dir = run_dir.join("checkpoints");
    std::fs::create_dir_all(&ckpt_dir)
        .doing_with(|| format!("cannot create {}", ckpt_dir.display()))?;
    let state_path = ckpt_dir.join("learner-state.safetensors");
    let mut dqn = restore(cfg, &state_path)?;
    let mut rx =
        hub.receiver::<u16, MinibatchHeader>(&Channel::minibatches(cfg.replay.prefetch))?;
    let mut mb_in = Minibatch::new(hub, cfg)?;
    let mut w_tx = hub.sender::<f32, WeightsHeader>(
        &Channel::weights(cfg.sim.envs),
        cfg.num_params(),
        STALL_TIMEOUT,
    )?;
    let mut tel = crate::ctx::counters(hub, RoleKind::Learner, 0, roles_of(cfg))?;
    let mut version = dqn.updates(); // increasing across restarts
    let mut average = Average::new(cfg);
    publish(&mut w_tx, &dqn, average.as_mut(), &mut version)?;
    let min_period = if cfg.learner.max_rate_hz > 0.0 {
        Duration::from_secs_f64(1.0 / cfg.learner.max_rate_hz)
    } else {
        Duration::ZERO
    };
    let mut last_ckpt = Instant::now();
    let mut saves = (0u32, Duration::ZERO);
    let mut last_update = Instant::now();
    let mut gauges = Gauges::default();
    loop {
        if hub.shutdown_requested() {
            break;
        }
        let t = Instant::now();
        let msg = rx.recv_timeout(POLL).doing("waiting for minibatches")?;
        tel.sample.time_stage(LearnerStage::TransportWait, t);
        if tel.tick(false, Telemetry::beat) {
            gauges = Gauges::default();
        }
        let Some(msg) = msg else { continue };
        // The learner's half of the rate limit.
        let since = last_update.elapsed();
        if since < min_period {
            std::thread::sleep(min_period - since);
        }
        last_update = Instant::now();
        let mb = *msg.user_header();
        let (batch, picks) = (&mut mb_in.batch, &mut mb_in.picks);
        unpack_batch(cfg.shapes(), msg.payload(), mb.batch as usize, batch, picks)?;
        drop(msg);
        teach(cfg, &mut dqn, &mb);
        let loss = mb_in.learn(&mut dqn, mb.seq, cfg.deterministic, &mut tel.sample.lost)?;
        add_timing(&mut tel.sample, dqn.timing());
        tel.sample.work = dqn.updates();
        gauges.add(loss, &mb, version, &mut tel.sample);
        gauges.learn(&dqn, cfg.learner.reward_scale, &mut tel.sample);
        if dqn.updates() % cfg.learner.publish_every == 0 {
            publish(&mut w_tx, &dqn, average.as_mut(), &mut version)?;
            tel.sample.weight_version = version;
            tel.sample.work2 = version;
        }
        if last_ckpt.elapsed().as_secs_f64() >= cfg.learner.checkpoint_every_s {
            checkpoint(&dqn, &ckpt_dir, &state_path, &cfg.checkpoint_tags(), &mut saves)?;
            last_ckpt = Instant::now();
        }
    }
    log_saves(saves);
    save_state_atomic(&dqn, &state_path)?;
    if let Some(avg) = &average {
        // Training is over: the online network becomes the run's average.
        dqn.online.load_flat(avg.weights())?;
    }
    save_atomic(&dqn.online, &run_dir.join("final.safetensors"), &cfg.checkpoint_tags())?;
    tel.tick(true, Telemetry::beat);
    Ok(())
}

/// An update's stages into the learner's telemetry sample.
fn add_timing(sample: &mut Telemetry, tm: rotorhive_model::UpdateTiming) {
    sample.add_stage(LearnerStage::Forward, tm.forward_ns);
    sample.add_stage(LearnerStage::Backward, tm.backward_ns);
    sample.add_stage(LearnerStage::Optimiser, tm.optimiser_ns);
}

/// Sets the teacher's losses to its weight now (the replay's fade, as
/// minibatch `mb` says; without a teacher none: the plain update).
fn teach(cfg: &Config, dqn: &mut Dqn, mb: &MinibatchHeader) {
    if let Some(t) = teaching(cfg, mb) {
        dqn.set_teaching(t);
    }
}

/// How minibatch `mb` weighs the labels: the teacher's weight times the
/// replay's fade (a fade that is not finite counts as 0), the TD loss at
/// `learner.td_weight` beside imitation; none without a teacher.
fn teaching(cfg: &Config, mb: &MinibatchHeader) -> Option<Teaching> {
    cfg.teacher.on().then(|| {
        let fade = if mb.teacher.is_finite() { mb.teacher.clamp(0.0, 1.0) } else { 0.0 };
        cfg.teacher.teaching(fade, cfg.learner.td_weight as f32)
    })
}

/// Publishes the online network (or its running average, [`Average`]) as
/// the next weight version. A failed write
/// publishes nothing (no zero weights under a new version), and neither do
/// weights that are not all finite: the actors keep acting with the last
/// good ones, and the version is not spent.
fn publish<S: Service>(
    w_tx: &mut rotorhive_transport::Sender<S, f32, WeightsHeader>,
    dqn: &Dqn,
    average: Option<&mut Average>,
    version: &mut u64,
) -> Result<()> {
    let net = &dqn.online;
    let write = |p: &mut [f32]| Ok(net.write_flat(p)?);
    publish_flat(w_tx, (net.num_params(), dqn.updates()), write, average, version)
}

/// Polyak averaging of the published weights (`learner.average_updates`):
/// an exponential moving average of the online network's weights, folded
/// in at every publication, which the actors fly, the evaluator scores and
/// `final.safetensors` keeps. Training is unchanged. Not in the learner's
/// state: a restarted learner starts it again from the weights it restored.
pub(crate) struct Average {
    /// The share of each publication's weights: 1 − exp(−publish_every /
    /// average_updates).
    alpha: f32,
    /// The average (empty until the first finite weights).
    avg: Vec<f32>,
    /// The online weights of the last publication.
    fresh: Vec<f32>,
}

impl Average {
    /// The config's average, or none where `learner.average_updates` is 0.
    pub(crate) fn new(cfg: &Config) -> Option<Self> {
        let over = cfg.learner.average_updates;
        (over > 0.0).then(|| Self {
            alpha: (1.0 - (-(cfg.learner.publish_every as f64) / over).exp()) as f32,
            avg: Vec::new(),
            fresh: Vec::new(),
        })
    }

    /// Folds the `len` online weights that `write` puts in place into the
    /// average (the first finite ones start it; weights that are not all
    /// finite are left out of it).
    fn fold(&mut self, len: usize, write: impl FnOnce(&mut [f32]) -> Result<()>) -> Result<()> {
        self.fresh.resize(len, 0.0);
        write(&mut self.fresh)?;
        if !self.fresh.iter().all(|x| x.is_finite()) {
            return Ok(());
        }
        if self.avg.len() == len {
            let a = self.alpha;
            self.avg.iter_mut().zip(&self.fresh).for_each(|(m, w)| *m += a * (w - *m));
        } else {
            self.avg.clone_from(&self.fresh);
        }
        Ok(())
    }

    /// The weights to publish: the average, or the last online weights
    /// while there is none (weights that are not finite, which
    /// [`publish_flat`] refuses).
    pub(crate) fn weights(&self) -> &[f32] {
        if self.avg.is_empty() { &self.fresh } else { &self.avg }
    }
}

/// Publishes `len` weights that `write` puts in place, made after `updates`
/// updates, as the next version, or their running average where there is
/// one (see [`publish`]; the recurrent learner's too).
pub(crate) fn publish_flat<S: Service>(
    w_tx: &mut rotorhive_transport::Sender<S, f32, WeightsHeader>,
    (len, updates): (usize, u64),
    write: impl FnOnce(&mut [f32]) -> Result<()>,
    average: Option<&mut Average>,
    version: &mut u64,
) -> Result<()> {
    match average {
        Some(avg) => {
            avg.fold(len, write)?;
            let w = avg.weights();
            let write = |p: &mut [f32]| {
                p.copy_from_slice(w);
                Ok(())
            };
            send_flat(w_tx, (len, updates), write, version)
        }
        None => send_flat(w_tx, (len, updates), write, version),
    }
}

/// Sends `len` weights that `write` puts in place as the next version (see
/// [`publish`]).
fn send_flat<S: Service>(
    w_tx: &mut rotorhive_transport::Sender<S, f32, WeightsHeader>,
    (len, updates): (usize, u64),
    write: impl FnOnce(&mut [f32]) -> Result<()>,
    version: &mut u64,
) -> Result<()> {
    let v = *version + 1;
    let sent = w_tx.try_send_with(len, |h, p| {
        *h = WeightsHeader { version: v, updates, len: len as u64 };
        write(p)?;
        match p.iter().position(|x| !x.is_finite()) {
            Some(i) => Err(RoleError::Protocol(format!("parameter {i} is {}", p[i]))),
            None => Ok(()),
        }
    })?;
    match sent {
        Ok(()) => *version = v,
        Err(e) => tracing::warn!("learner: weights of update {updates} not published: {e:#}"),
    }
    Ok(())
}

/// The minibatch in hand, in the network's layout, and (prioritized
/// replay) the channel its TD errors go back on.
struct Minibatch<S: Service> {
    /// Transitions as floats (they arrive packed, with 16-bit depth).
    batch: Vec<f32>,
    /// Each row's place and importance weight.
    picks: Vec<Pick>,
    weights: Vec<f32>,
    prio_tx: Option<rotorhive_transport::Sender<S, u16, PriorityHeader>>,
}

impl<S: Service> Minibatch<S> {
    fn new(hub: &rotorhive_transport::Hub<S>, cfg: &Config) -> Result<Self> {
        let prio_tx = if cfg.replay.prioritized {
            Some(hub.sender::<u16, PriorityHeader>(
                &Channel::priorities(cfg.replay.prefetch),
                cfg.replay.batch * PICK_WORDS,
                STALL_TIMEOUT,
            )?)
        } else {
            None
        };
        Ok(Self { batch: Vec::new(), picks: Vec::new(), weights: Vec::new(), prio_tx })
    }

    /// Each row's importance weight from its pick under prioritized replay
    /// (none otherwise: every row weighs 1).
    fn load_weights(&mut self) {
        self.weights.clear();
        if self.prio_tx.is_some() {
            self.weights.extend(self.picks.iter().map(|p| p.value));
        }
    }

    /// One update on the minibatch in hand (importance-weighted, with its
    /// TD errors sent back as priorities, under prioritized replay); the loss.
    fn learn(
        &mut self,
        dqn: &mut Dqn,
        seq: u64,
        deterministic: bool,
        lost: &mut u64,
    ) -> Result<f32> {
        self.load_weights();
        let Some(tx) = &mut self.prio_tx else {
            return dqn.update(&self.batch).doing("learner update");
        };
        let loss = dqn.update_weighted(&self.batch, Some(&self.weights)).doing("learner update")?;
        send_priorities(tx, &mut self.picks, dqn.td_abs(), seq, deterministic, lost)?;
        Ok(loss)
    }
}

/// The learner's gauges in its telemetry, over the updates since the last
/// sample (one minibatch's loss is too noisy to show a trend): the mean loss
/// and the mean policy lag.
#[derive(Default)]
struct Gauges {
    loss: (f64, u32),
    lag: (f64, u32),
    /// Sums of the updates' max-Q, |TD| and terminals, and their rows.
    max_q: f64,
    td: f64,
    terminal: u64,
    rows: u64,
}

impl Gauges {
    /// Adds an update's loss and its minibatch's policy lag: the learner's
    /// weight version minus the mean version the transitions were acted
    /// with (those restored from a snapshot have none).
    fn add(
        &mut self,
        loss: f32,
        mb: &MinibatchHeader,
        version: u64,
        tel: &mut rotorhive_msg::Telemetry,
    ) {
        if loss.is_finite() {
            self.loss = (self.loss.0 + loss as f64, self.loss.1 + 1);
            tel.value_milli = (self.loss.0 / self.loss.1 as f64 * 1e6) as i64;
        }
        if mb.acted > 0 {
            self.lag = (
                self.lag.0 + version as f64 - mb.acted_version_sum as f64 / mb.acted as f64,
                self.lag.1 + 1,
            );
            tel.policy_lag_milli =
                (self.lag.0 / self.lag.1 as f64 * 1e3).clamp(0.0, u32::MAX as f64) as u32;
        }
    }
}

impl Gauges {
    /// Adds the last update's learning diagnostics (in reward units: the
    /// network's values divided by `reward_scale`).
    fn learn(&mut self, dqn: &Dqn, reward_scale: f64, tel: &mut rotorhive_msg::Telemetry) {
        let st = dqn.stats();
        tel.learning.skipped_updates = dqn.skipped().min(u32::MAX as u64) as u32;
        if !(st.max_q_sum.is_finite() && st.abs_td_sum.is_finite()) || st.rows == 0 {
            return;
        }
        (self.max_q, self.td) = (self.max_q + st.max_q_sum, self.td + st.abs_td_sum);
        (self.terminal, self.rows) =
            (self.terminal + st.terminal as u64, self.rows + st.rows as u64);
        let rows = self.rows as f64;
        tel.learning.mean_max_q = (self.max_q / rows / reward_scale) as f32;
        tel.learning.mean_abs_td = (self.td / rows / reward_scale) as f32;
        tel.learning.terminal_share = (self.terminal as f64 / rows) as f32;
    }
}

/// Unpacks a minibatch of `rows` packed transitions and their picks into
/// `out`, the learner's float layout (`transition_len` per transition),
/// and `picks` (each row's place and importance weight).
fn unpack_batch(
    shapes: Shapes,
    packed: &[u16],
    rows: usize,
    out: &mut Vec<f32>,
    picks: &mut Vec<Pick>,
) -> Result<()> {
    let (pl, tl) = (shapes.packed_len(), shapes.transition_len());
    if rows == 0 || packed.len() != rows * (pl + PICK_WORDS) {
        protocol_err!(
            "a minibatch of {} words is not {rows} packed transitions and their picks ({} words each)",
            packed.len(),
            pl + PICK_WORDS
        );
    }
    let (data, tail) = packed.split_at(rows * pl);
    out.resize(rows * tl, 0.0);
    for (p, o) in data.chunks_exact(pl).zip(out.chunks_exact_mut(tl)) {
        shapes.unpack(p, o);
    }
    picks.clear();
    picks.extend(tail.chunks_exact(PICK_WORDS).map(Pick::unpack));
    Ok(())
}

/// Sends minibatch `seq`'s new priorities (each row's |TD error|) back to
/// the replay. A deterministic run cannot lose them (the replay waits for
/// them in order); otherwise a full queue costs only these priorities.
fn send_priorities<S: Service>(
    tx: &mut rotorhive_transport::Sender<S, u16, PriorityHeader>,
    picks: &mut [Pick],
    td: &[f32],
    seq: u64,
    deterministic: bool,
    lost: &mut u64,
) -> Result<()> {
    for (p, t) in picks.iter_mut().zip(td) {
        p.value = *t;
    }
    let n = picks.len().min(td.len());
    let sent = tx.send_with(n * PICK_WORDS, |h, out| {
        *h = PriorityHeader { count: n as u32, reserved: 0, seq };
        for (p, w) in picks.iter().zip(out.chunks_exact_mut(PICK_WORDS)) {
            p.pack(w);
        }
    });
    match sent {
        Ok(()) => Ok(()),
        Err(e) if deterministic => Err(e).doing("a deterministic run cannot lose priorities"),
        // A run that stops lets its replay go first: not a loss.
        Err(e) if rotorhive_transport::stop_requested() => {
            tracing::debug!("learner: priorities of minibatch {seq} sent as the run stopped: {e}");
            Ok(())
        }
        Err(e) => {
            tracing::warn!("learner: priorities of minibatch {seq} not sent: {e}");
            *lost += 1;
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Weights `w` as a publication's `write`.
    fn put(w: &[f32]) -> impl FnOnce(&mut [f32]) -> Result<()> + '_ {
        move |p| {
            p.copy_from_slice(w);
            Ok(())
        }
    }

    fn average(over: f64) -> Option<Average> {
        let mut cfg = Config::default();
        cfg.learner.publish_every = 10;
        cfg.learner.average_updates = over;
        Average::new(&cfg)
    }

    #[test]
    fn the_average_starts_at_the_first_weights_and_follows_the_online_ones() {
        assert!(average(0.0).is_none(), "0 turns averaging off");
        let mut avg = average(100.0).expect("on");
        let alpha = 1.0 - (-0.1f64).exp() as f32;
        avg.fold(2, put(&[1.0, -2.0])).unwrap();
        assert_eq!(avg.weights(), &[1.0, -2.0]);
        avg.fold(2, put(&[3.0, -2.0])).unwrap();
        let w = avg.weights();
        assert!((w[0] - (1.0 + 2.0 * alpha)).abs() < 1e-6 && w[1] == -2.0, "{w:?}");
        // Many publications of the same weights: the average reaches them.
        for _ in 0..400 {
            avg.fold(2, put(&[3.0, 5.0])).unwrap();
        }
        assert!(avg.weights().iter().zip([3.0, 5.0]).all(|(a, b)| (a - b).abs() < 1e-4));
    }

    #[test]
    fn weights_that_are_not_finite_stay_out_of_the_average() {
        let mut avg = average(50.0).expect("on");
        avg.fold(2, put(&[f32::NAN, 1.0])).unwrap();
        assert!(avg.weights()[0].is_nan(), "no average yet: the bad weights, refused when sent");
        avg.fold(2, put(&[1.0, 1.0])).unwrap();
        avg.fold(2, put(&[f32::INFINITY, 1.0])).unwrap();
        assert_eq!(avg.weights(), &[1.0, 1.0]);
    }
}
