//! `hive actor`: paired with one sim. Keeps a local Q-network, picks actions
//! for all the sim's agents in one batched inference (epsilon-greedy),
//! assembles transitions straight into shared memory for the replay process,
//! and picks up newer weights by version. Beside the loop: its exploration
//! (`exploration.rs`), n-step returns (`nstep.rs`), the non-batched mode's
//! gathering (`gather.rs`), the policy it acts with (`policy.rs`) and a
//! recurrent run's stored sequences (`sequences.rs`).

use std::time::Instant;

use crate::error::{Doing, Result, config_err, protocol_err};
use policy::Policy;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rotorhive_msg::{
    ActionHeader, ActorStage, EPISODE_FIELDS, NO_EXPERT, ObsHeader, RoleKind, Shapes, Telemetry,
    TransitionHeader, WeightsHeader,
};
use rotorhive_transport::Channel;

use rotorhive_msg::EpisodeHeader;
use rotorhive_transport::Service;
use rotorhive_transport::{Receiver, Sender};

use crate::config::Config;
use crate::ctx::{Counters, Ctx, POLL, STALL_TIMEOUT, episodes_channel, roles_of};
use crate::schedule::Schedule;

/// Runs the actor of environment `e` until the run stops.
pub fn run<S: Service>(cx: Ctx<'_, S>, e: usize) -> Result<()> {
    let (cfg, hub) = (cx.cfg, cx.hub);
    if e >= cfg.sim.envs {
        config_err!("--env {e} is out of range: the config has {} environments", cfg.sim.envs);
    }
    let mut obs_rx =
        hub.receiver::<f32, ObsHeader>(&Channel::obs(e, cfg.obs_messages_per_step()))?;
    let mut a = Actor::new(cfg, hub, e)?;
    let mut gather = Gather::new(a.n, a.shapes.obs_len());
    if a.schedule.is_some() && !a.wait_for_receivers() {
        return Ok(());
    }
    while !hub.shutdown_requested() {
        let t = Instant::now();
        take_weights(&mut a.w_rx, &a.policy, &mut a.version, &mut a.weights_updates)?;
        a.tel.sample.weight_version = a.version;
        a.tel.sample.time_stage(ActorStage::Weights, t);
        let t = Instant::now();
        let msg = obs_rx.recv_timeout(POLL).doing("waiting for observations")?;
        a.tel.sample.time_stage(ActorStage::TransportWait, t);
        a.tel.tick(false, Telemetry::beat);
        let Some(msg) = msg else { continue };
        let h = *msg.user_header();
        let n = a.n;
        if h.total as usize != n
            || h.first as usize + h.agents as usize > n
            || msg.payload().len() != a.shapes.obs_batch_len(h.agents as usize)
        {
            protocol_err!(
                "observation batch from sim {e} has agents {}..{} of {}, the config says {n}",
                h.first,
                h.first + h.agents,
                h.total
            );
        }
        if a.schedule.is_some_and(|s| h.step > s.rounds()) {
            // A deterministic run's budget is spent: nothing more to act on.
            continue;
        }
        if a.have_prev && h.step + 1 == a.expected_step {
            // The sim published this step again: our actions were not seen.
            // Answer with the same actions (once) and record nothing twice.
            if h.first == 0 {
                send_actions(&mut a.act_tx, e, h.step, &a.prev_actions, &mut a.tel.sample.lost);
            }
            continue;
        }
        // Non-batched mode: one message per agent, gathered into the layout
        // of a whole batch before anything else happens.
        let whole = if h.agents as usize == n {
            Some(msg)
        } else {
            let complete = gather.add(&h, msg.payload());
            drop(msg);
            if !complete {
                continue;
            }
            None
        };
        let p: &[f32] = whole.as_ref().map_or(gather.batch(), |m| m.payload());
        if !a.on_step(&h, p)? {
            break;
        }
    }
    a.tel.tick(true, Telemetry::beat);
    Ok(())
}

/// An actor's state between steps: its network and ports, the n-step
/// window, the previous actions and the episode counters.
struct Actor<'a, S: Service> {
    cfg: &'a Config,
    hub: &'a rotorhive_transport::Hub<S>,
    e: usize,
    n: usize,
    policy: Policy,
    /// The run's observation and action shapes.
    shapes: Shapes,
    act_tx: Sender<S, u8, ActionHeader>,
    trans_tx: Sender<S, u16, TransitionHeader>,
    w_rx: Receiver<S, f32, WeightsHeader>,
    ep_tx: Sender<S, f32, EpisodeHeader>,
    tel: Counters<S>,
    rng: Pcg64Mcg,
    version: u64,
    /// The update count of the weights in use (0: the initial ones, which
    /// the learner's first publication also carries).
    weights_updates: u64,
    schedule: Option<Schedule>,
    nstep: NStep,
    actions: Vec<u8>,
    prev_actions: Vec<u8>,
    /// The teacher's action at each agent's last observation
    /// ([`NO_EXPERT`] where none), and whether it flew the agent there.
    prev_experts: Vec<f32>,
    prev_flown: Vec<bool>,
    /// Whether the teacher flies each agent at this step.
    flown: Vec<bool>,
    /// Agents the teacher flies (the first ones; 0 without a teacher).
    demo_agents: usize,
    /// Whether the teacher flew any step of each agent's current episode,
    /// and of the one it finished last: those are not the student's
    /// episodes, and are not reported.
    episode_flown: Vec<bool>,
    ended_flown: Vec<bool>,
    have_prev: bool,
    expected_step: u64,
    returns: Vec<f32>,
    lengths: Vec<u32>,
    /// Each agent's exploration rate for the current step.
    eps: Vec<f64>,
    /// Each agent's highest exploration rate in its current episode, and
    /// in the episode it finished last: an episode counts in the rolling
    /// reward's floor only if every action of it was that greedy.
    episode_eps: Vec<f64>,
    ended_eps: Vec<f64>,
    finished: Vec<f32>,
    episodes: u64,
    seq: u64,
    transitions: u64,
}

impl<'a, S: Service> Actor<'a, S> {
    fn new(cfg: &'a Config, hub: &'a rotorhive_transport::Hub<S>, e: usize) -> Result<Self> {
        let (n, envs) = (cfg.sim.agents, cfg.sim.envs);
        let shapes = cfg.shapes();
        let policy = Policy::new(cfg, &rotorhive_model::device(cfg.actor.device.kind())?, n)?;
        let steps_n = cfg.learner.n_step;
        // An episode's end can release up to n transitions of one agent; a
        // step at most one sequence of each.
        let most = match cfg.memory() {
            Some(_) => n * cfg.row_len(),
            None => steps_n * n * shapes.packed_len(),
        };
        Ok(Self {
            act_tx: hub.sender::<u8, ActionHeader>(&Channel::actions(e), n, STALL_TIMEOUT)?,
            trans_tx: hub.sender::<u16, TransitionHeader>(
                &Channel::transitions(envs),
                most,
                STALL_TIMEOUT,
            )?,
            w_rx: hub.receiver::<f32, WeightsHeader>(&Channel::weights(envs))?,
            ep_tx: hub.sender::<f32, EpisodeHeader>(
                &episodes_channel(envs),
                EPISODE_FIELDS * n,
                STALL_TIMEOUT,
            )?,
            tel: crate::ctx::counters(hub, RoleKind::Actor, e, roles_of(cfg))?,
            rng: Pcg64Mcg::seed_from_u64(crate::streams::actor(
                cfg.seed,
                cfg.cluster.env_offset + e,
            )),
            schedule: cfg.deterministic.then(|| Schedule::new(cfg)),
            nstep: NStep::new(steps_n, cfg.learner.gamma as f32, n, shapes.obs_len()),
            actions: vec![0; n],
            prev_actions: vec![0; n],
            prev_experts: vec![NO_EXPERT; n],
            prev_flown: vec![false; n],
            flown: vec![false; n],
            demo_agents: cfg.teacher.demo_agents(),
            episode_flown: vec![false; n],
            ended_flown: vec![false; n],
            returns: vec![0.0; n],
            lengths: vec![0; n],
            finished: Vec::with_capacity(EPISODE_FIELDS * n),
            eps: vec![cfg.actor.eps_start; n],
            episode_eps: vec![0.0; n],
            ended_eps: vec![0.0; n],
            version: 0,
            weights_updates: 0,
            have_prev: false,
            expected_step: 0,
            episodes: 0,
            seq: 0,
            transitions: 0,
            cfg,
            hub,
            e,
            n,
            policy,
            shapes,
        })
    }

    /// A message sent before its receiver exists is lost without a trace:
    /// a deterministic run's first round waits for the replay and the
    /// supervisor to be there. False when the run stopped meanwhile.
    fn wait_for_receivers(&self) -> bool {
        while self.trans_tx.receivers() == 0 || self.ep_tx.receivers() == 0 {
            if self.hub.shutdown_requested() {
                return false;
            }
            std::thread::sleep(POLL / 10);
        }
        true
    }

    /// Acts on one whole step's batch `p` (observations, rewards, dones),
    /// then sends the transitions and episodes it completes. False when the
    /// run stopped while a deterministic step waited for its weights.
    fn on_step(&mut self, h: &ObsHeader, p: &[f32]) -> Result<bool> {
        let n = self.n;
        if h.step != self.expected_step {
            // The sim restarted (step 0) or a batch was lost: start afresh.
            self.tel.sample.lost += 1;
            self.have_prev = false;
            self.nstep.clear();
            self.policy.restart();
        }
        self.expected_step = h.step + 1;
        let (obs, rest) = p.split_at(n * self.shapes.obs_len());
        let (rewards, rest) = rest.split_at(n);
        let (dones, rest) = rest.split_at(n);
        let (flies, labels) = rest.split_at(n);
        if !self.wait_weights(h.step)? {
            return Ok(false);
        }
        let t = Instant::now();
        // The episodes that end at this step were acted with the rates of
        // the steps before it: the rates are set after they are reported.
        let greedy = self.policy.greedy(obs, dones)?;
        let actions = self.shapes.actions as u8;
        for (i, g) in greedy.into_iter().enumerate() {
            let eps = self.eps[i];
            self.actions[i] =
                if self.rng.random::<f64>() < eps { self.rng.random_range(0..actions) } else { g };
            // An agent whose episode ended acts on its next episode's first
            // observation (same-step reset).
            if dones[i] != 0.0 {
                self.ended_eps[i] = self.episode_eps[i];
                self.episode_eps[i] = 0.0;
                self.ended_flown[i] = self.episode_flown[i];
                self.episode_flown[i] = false;
            }
            self.episode_eps[i] = self.episode_eps[i].max(eps);
            // The teacher's agents fly its action (while it flies them).
            let flown = i < self.demo_agents && flies[i] != NO_EXPERT;
            if flown {
                self.actions[i] = flies[i] as u8;
                self.episode_flown[i] = true;
            }
            self.flown[i] = flown;
        }
        self.tel.sample.time_stage(ActorStage::Inference, t);
        // The actions leave first; then this step's transitions (round
        // `h.step` of a deterministic run, which must follow the acting).
        send_actions(&mut self.act_tx, self.e, h.step, &self.actions, &mut self.tel.sample.lost);
        let t = Instant::now();
        if self.policy.seqs.is_some() {
            self.send_sequences(obs, rewards, dones)?;
        } else if self.have_prev {
            self.send_transitions(obs, rewards, dones)?;
        }
        if self.have_prev {
            self.report_episodes(h.step, rewards, dones)?;
        }
        // Every environment of the run, on every host, acts at about this
        // actor's pace.
        agent_epsilons(
            self.cfg,
            self.e,
            self.transitions * self.cfg.envs_total() as u64,
            &mut self.eps,
        );
        let (lo, hi) =
            self.eps.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), v| (lo.min(*v), hi.max(*v)));
        self.tel.sample.value_milli = (hi * 1000.0) as i64;
        (self.tel.sample.learning.eps_min, self.tel.sample.learning.eps_max) =
            (lo as f32, hi as f32);
        self.tel.sample.time_stage(ActorStage::Assemble, t);
        self.nstep.store(obs);
        self.prev_actions.copy_from_slice(&self.actions);
        self.prev_experts.copy_from_slice(labels);
        self.prev_flown.copy_from_slice(&self.flown);
        self.have_prev = true;
        self.tel.sample.work = self.transitions;
        self.tel.sample.work2 = self.episodes;
        Ok(true)
    }

    /// A deterministic run acts on `step` with the weights published once
    /// the learner has made exactly the schedule's updates: waits for them.
    /// False when the run stopped meanwhile.
    fn wait_weights(&mut self, step: u64) -> Result<bool> {
        let Some(s) = &self.schedule else {
            return Ok(true);
        };
        let need = s.updates_for_step(step);
        while self.weights_updates != need {
            if self.weights_updates > need {
                protocol_err!(
                    "actor {}: weights of update {} arrived before step {step} needed those of update {need}",
                    self.e,
                    self.weights_updates
                );
            }
            if self.hub.shutdown_requested() {
                return Ok(false);
            }
            if !take_weights(
                &mut self.w_rx,
                &self.policy,
                &mut self.version,
                &mut self.weights_updates,
            )? {
                std::thread::sleep(std::time::Duration::from_micros(200));
            }
            self.tel.sample.weight_version = self.version;
        }
        Ok(true)
    }

    /// n-step transitions leave once n rewards are known or the episode
    /// ended; they are packed in place in the loaned sample. A
    /// deterministic run sends every round, empty or not: the replay
    /// inserts rounds whole.
    fn send_transitions(&mut self, obs: &[f32], rewards: &[f32], dones: &[f32]) -> Result<()> {
        self.nstep.push(
            Taken {
                actions: &self.prev_actions,
                experts: &self.prev_experts,
                flown: &self.prev_flown,
            },
            rewards,
            dones,
        );
        let count = self.nstep.out.len();
        if count == 0 && self.schedule.is_none() {
            return Ok(());
        }
        let (e, nstep) = (self.e, &self.nstep);
        let header = TransitionHeader {
            actor: e as u32,
            count: count as u32,
            seq: self.seq,
            weight_version: self.version,
        };
        // A receiver that is there but busy (a replay or a link held up, a
        // network outage behind the worker's link) is waited for: the batch
        // is sent again, and back-pressure reaches the sim. Only a send that
        // found no receiver within the stall timeout gives the batch up.
        let hub = self.hub;
        let give_up = |receivers| receivers == 0 || hub.shutdown_requested();
        let (shapes, ol) = (self.shapes, self.shapes.obs_len());
        let sent = self.trans_tx.send_retrying(count * shapes.packed_len(), give_up, |th, out| {
            *th = header;
            for (o, t) in out.chunks_exact_mut(shapes.packed_len()).zip(&nstep.out) {
                let next = &obs[t.agent * ol..(t.agent + 1) * ol];
                let tail = [
                    t.action as f32,
                    t.ret,
                    if t.done { 1.0 } else { 0.0 },
                    t.expert,
                    if t.demo { 1.0 } else { 0.0 },
                ];
                shapes.pack(nstep.obs(t.slot, t.agent), next, tail, o);
            }
        });
        if self.sent(sent, count as u64)? {
            let tc = &mut self.tel.sample.teacher;
            for t in &self.nstep.out {
                tc.demo_transitions += t.demo as u64;
                tc.labelled_transitions += (!t.demo && t.expert != NO_EXPERT) as u64;
            }
        }
        Ok(())
    }

    /// Counts what a send of `count` transitions came to; true when sent.
    /// A deterministic run cannot lose any; one that stops loses none.
    fn sent(&mut self, sent: rotorhive_transport::Result<bool>, count: u64) -> Result<bool> {
        let e = self.e;
        match sent {
            Ok(true) => {
                self.seq += 1;
                self.transitions += count;
                return Ok(true);
            }
            Ok(false) if self.schedule.is_some() => {
                protocol_err!(
                    "actor {e}: a deterministic run cannot lose transitions: no replay took them"
                )
            }
            Err(err) if self.schedule.is_some() => {
                protocol_err!("actor {e}: a deterministic run cannot lose transitions: {err}")
            }
            // A run that stops ends its replay first: the batches sent
            // after it are the run's tail, not loss (the final telemetry
            // counts to the very end).
            Ok(false) | Err(_) if self.hub.shutdown_requested() => {
                tracing::debug!("actor {e}: a batch sent as the run stopped reached no replay");
            }
            Ok(false) => {
                tracing::warn!("actor {e}: no replay took a batch within the stall timeout");
                self.tel.sample.lost += 1;
            }
            Err(err) => {
                tracing::warn!("actor {e}: {err}");
                self.tel.sample.lost += 1;
            }
        }
        Ok(false)
    }

    /// With memory: records this step in the agents' sequence windows
    /// (the last actions' outcome, the observations and the states acted
    /// from) and sends the sequences complete now, each counting its
    /// trained steps as transitions (a deterministic run sends every round,
    /// as [`Actor::send_transitions`]).
    fn send_sequences(&mut self, obs: &[f32], rewards: &[f32], dones: &[f32]) -> Result<()> {
        let policy = &mut self.policy;
        let Some(seqs) = policy.seqs.as_mut() else {
            return Ok(());
        };
        let taken = Taken {
            actions: &self.prev_actions,
            experts: &self.prev_experts,
            flown: &self.prev_flown,
        };
        seqs.push(self.have_prev.then_some((taken, rewards, dones)), obs, &policy.before);
        let count = seqs.agents.len();
        // A deterministic run sends every round, empty or not: round `h`
        // holds the outcome of step `h`, so none at a stream's first step.
        if count == 0 && (self.schedule.is_none() || !self.have_prev) {
            return Ok(());
        }
        let header = TransitionHeader {
            actor: self.e as u32,
            count: count as u32,
            seq: self.seq,
            weight_version: self.version,
        };
        let hub = self.hub;
        let give_up = |receivers| receivers == 0 || hub.shutdown_requested();
        let packed = &seqs.out;
        let sent = self.trans_tx.send_retrying(packed.len(), give_up, |th, out| {
            *th = header;
            out.copy_from_slice(packed);
        });
        let (trained, taught) = ((count * seqs.period()) as u64, seqs.taught);
        if self.sent(sent, trained)? {
            let tc = &mut self.tel.sample.teacher;
            tc.demo_transitions += taught.0;
            tc.labelled_transitions += taught.1;
        }
        Ok(())
    }

    /// Sends the episodes that ended at `step` to the supervisor. A
    /// deterministic run reports every round, so that the supervisor can
    /// write episodes in (step, environment) order.
    fn report_episodes(&mut self, step: u64, rewards: &[f32], dones: &[f32]) -> Result<()> {
        self.finished.clear();
        let eps = self.eps.iter().fold(0.0f64, |m, v| m.max(*v));
        for i in 0..self.n {
            self.returns[i] += rewards[i];
            self.lengths[i] += 1;
            if dones[i] != 0.0 && self.ended_flown[i] {
                // The teacher's episode, not the student's.
                self.returns[i] = 0.0;
                self.lengths[i] = 0;
            } else if dones[i] != 0.0 {
                self.finished.extend_from_slice(&[
                    self.returns[i],
                    self.lengths[i] as f32,
                    dones[i],
                    self.ended_eps[i] as f32,
                ]);
                self.returns[i] = 0.0;
                self.lengths[i] = 0;
                self.episodes += 1;
            }
        }
        if self.finished.is_empty() && self.schedule.is_none() {
            return Ok(());
        }
        let count = (self.finished.len() / EPISODE_FIELDS) as u32;
        let header =
            EpisodeHeader { actor: self.e as u32, count, epsilon_micro: (eps * 1e6) as u64, step };
        let finished = &self.finished;
        let sent = self.ep_tx.send_with(finished.len(), |eh, out| {
            *eh = header;
            out.copy_from_slice(finished);
        });
        if let (Err(err), Some(_)) = (sent, &self.schedule) {
            protocol_err!("actor {}: a deterministic run cannot lose episodes: {err}", self.e);
        }
        Ok(())
    }
}
/// Loads the newest published weights when their version differs from
/// `version` (any other version is newer: a restarted learner goes on from
/// its saved update count, which never lies behind), recording their
/// version and update count; true when it did.
fn take_weights<S: Service>(
    rx: &mut Receiver<S, f32, WeightsHeader>,
    net: &Policy,
    version: &mut u64,
    updates: &mut u64,
) -> Result<bool> {
    let Some(w) = rx.latest().doing("reading weights")? else {
        return Ok(false);
    };
    let h = *w.user_header();
    if h.version == *version {
        return Ok(false);
    }
    net.load_flat(w.payload()).doing("loading published weights")?;
    (*version, *updates) = (h.version, h.updates);
    Ok(true)
}

/// Publishes one action batch answering observation step `step`; a failed
/// send is reported and counted, and the sim will publish the step again.
fn send_actions<S: Service>(
    tx: &mut Sender<S, u8, ActionHeader>,
    e: usize,
    step: u64,
    actions: &[u8],
    lost: &mut u64,
) {
    let n = actions.len();
    if let Err(err) = tx.send_with(n, |ah, out| {
        *ah = ActionHeader { step };
        out.copy_from_slice(actions);
    }) {
        tracing::warn!("actor {e}: {err}");
        *lost += 1;
    }
}

mod exploration;
mod gather;
mod nstep;
pub mod policy;
pub mod sequences;

pub use exploration::{agent_epsilons, epsilon, per_actor_epsilon};
pub use gather::Gather;
pub use nstep::{NStep, Ready, Taken};

#[cfg(test)]
mod tests;
