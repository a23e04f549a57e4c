//! `hive sim`: one simulator process. Publishes an observation batch, waits
//! for the matching action batch, steps all its agents, and repeats.

use std::time::Instant;

use crate::error::{Doing, Result, config_err};
use rotorhive_msg::{
    ActionHeader, NO_EXPERT, ObsHeader, RoleKind, SimStage, Telemetry, WeightsHeader,
};
use rotorhive_sim::VecEnv;
use rotorhive_transport::Channel;

use rotorhive_transport::Service;
use rotorhive_transport::{Hub, Receiver, Sender};

use crate::ctx::{Ctx, POLL, STALL_TIMEOUT, roles_of};
use crate::teacher::Teacher;

/// How long a sim waits for actions before publishing the same step again.
const RESEND: std::time::Duration = std::time::Duration::from_millis(1000);

/// Runs simulator `env_index` until the run stops.
pub fn run<S: Service>(cx: Ctx<'_, S>, env_index: usize) -> Result<()> {
    let (cfg, hub) = (cx.cfg, cx.hub);
    let n = cfg.sim.agents;
    let mut env = open_env(cfg, env_index)?;
    let batched = cfg.batched();
    let shapes = cfg.shapes();
    assert_eq!(env.obs_len(), shapes.obs_len(), "simulator and message layouts disagree");
    // Observations are assembled straight into the loaned sample (send_obs).
    env.drop_observation_buffer();
    let mut obs_tx = hub.sender::<f32, ObsHeader>(
        &Channel::obs(env_index, cfg.obs_messages_per_step()),
        shapes.obs_batch_len(n),
        STALL_TIMEOUT,
    )?;
    let mut act_rx = hub.receiver::<u8, ActionHeader>(&Channel::actions(env_index))?;
    let mut tel = crate::ctx::counters(hub, RoleKind::Sim, env_index, roles_of(cfg))?;
    let mut limiter = RateLimiter::new(hub, cfg)?;
    let mut teacher = Teacher::start(cfg, &env, env_index);
    let mut step = 0u64;
    let mut stage = 0u32;
    let mut renewed = (0u64, false);
    let mut need_send = true;
    let mut last_send = Instant::now();
    while !hub.shutdown_requested() {
        if need_send {
            let taught = teacher.as_ref().map(Teacher::actions);
            match send_obs(&mut obs_tx, &env, step, batched, taught) {
                Ok(()) => {
                    need_send = false;
                    last_send = Instant::now();
                }
                Err(e) => {
                    // The actor is gone, restarting or held up (waiting on
                    // its own receiver): report, and send the same step
                    // again. Nothing is lost, so nothing is counted lost.
                    tracing::warn!("sim {env_index}: {e}");
                    tel.tick(false, Telemetry::beat);
                    continue;
                }
            }
        }
        let t = Instant::now();
        let msg = act_rx.recv_timeout(POLL).doing("waiting for actions")?;
        tel.sample.time_stage(SimStage::TransportWait, t);
        tel.tick(false, Telemetry::beat);
        let Some(msg) = msg else {
            // An actor that subscribed after our send (or restarted) never saw
            // this step: publish it again; the actor answers duplicates.
            if last_send.elapsed() > RESEND {
                need_send = true;
            }
            continue;
        };
        let h = *msg.user_header();
        if h.step < step && msg.payload().len() == n {
            // The actor's answer to a step published again (it was held up):
            // a duplicate, not a loss. Keep waiting for the right one.
            continue;
        }
        if h.step != step || msg.payload().len() != n {
            // A foreign batch: count it and keep waiting for the right one.
            tel.sample.lost += 1;
            continue;
        }
        env.step(msg.payload()).doing("stepping the simulator")?;
        drop(msg);
        step += 1;
        count_step(&mut tel.sample, &env, n);
        need_send = true;
        let mut new_world = follow_curriculum(cfg, &mut env, env_index, step, &mut stage)?;
        new_world |= follow_fresh_layouts(&env, env_index, &mut renewed);
        Teacher::follow(teacher.as_mut(), &env, step, new_world, &mut tel.sample);
        let t = Instant::now();
        limiter.wait(hub, step)?;
        // Waiting on the rate limit is waiting on another process.
        tel.sample.time_stage(SimStage::TransportWait, t);
    }
    tel.tick(true, Telemetry::beat);
    Ok(())
}

/// Simulator `env_index`'s environment: its lanes, seeded for its place
/// among every host's environments.
fn open_env(cfg: &crate::Config, env_index: usize) -> Result<VecEnv> {
    if env_index >= cfg.sim.envs {
        config_err!(
            "--env {env_index} is out of range: the config has {} environments",
            cfg.sim.envs
        );
    }
    let arenas = cfg.lane_arenas(env_index)?;
    let seed = crate::streams::sim(cfg.seed, cfg.cluster.env_offset + env_index);
    let mut env =
        VecEnv::new_lanes(cfg.sim_config(), &arenas, seed).doing("starting the simulator")?;
    if let Some((first, make)) = cfg.fresh_layouts(env_index)? {
        env.renew_lanes(cfg.sim.fresh_layouts, first, arenas, make)
            .doing("starting fresh layouts")?;
    }
    Ok(env)
}

/// Whether the environment renewed a lane since the last step (the
/// teacher's planner then sees the new world); `seen` holds the renewals
/// counted and whether a renewal that stopped was reported.
fn follow_fresh_layouts(env: &VecEnv, env_index: usize, seen: &mut (u64, bool)) -> bool {
    let stats = env.fresh_stats();
    if let Some(e) = env.fresh_error().filter(|_| !seen.1) {
        tracing::warn!("sim {env_index}: fresh layouts stopped: {e}");
        seen.1 = true;
    }
    if stats.renewed == seen.0 {
        return false;
    }
    seen.0 = stats.renewed;
    if stats.renewed.is_power_of_two() {
        let waited = stats.wait_ns as f64 / 1e6;
        tracing::info!(
            "sim {env_index}: {} fresh layouts flown ({waited:.0} ms waited for them)",
            stats.renewed
        );
    }
    true
}

/// Counts a step of `n` agents: its stages' times, its agent-steps and
/// the episodes it finished.
fn count_step(sample: &mut Telemetry, env: &VecEnv, n: usize) {
    let tm = env.timing();
    sample.add_stage(SimStage::Physics, tm.physics_ns);
    sample.add_stage(SimStage::Render, tm.render_ns);
    sample.add_stage(SimStage::Reset, tm.reset_ns);
    sample.work += n as u64;
    sample.work2 += env.finished().len() as u64;
}

/// A curriculum's next stage: new training lanes, once the run's
/// agent-steps (as this sim sees them: its own steps times every host's
/// agents) reach it; true when it replaced them.
fn follow_curriculum(
    cfg: &crate::Config,
    env: &mut VecEnv,
    env_index: usize,
    step: u64,
    stage: &mut u32,
) -> Result<bool> {
    let now = cfg.curriculum_stage(step.saturating_mul(cfg.agents_total() as u64));
    if now == *stage {
        return Ok(false);
    }
    *stage = now;
    env.replace_arenas(&cfg.lane_arenas_at(env_index, now)?)
        .doing("changing the training lanes")?;
    tracing::info!("sim {env_index}: curriculum stage {now}");
    Ok(true)
}

/// Holds a sim back while the transitions inserted since learning began
/// outrun what the learner has sampled divided by `replay.samples_per_insert`
/// (the insert side of the rate limit; the replay holds the sample side).
/// The learner's update count arrives in the header of every weights
/// publication. Both sides count from when learning began, so transitions
/// that never reached the replay (sent before it subscribed, say) cannot
/// make the two sides wait on each other.
pub struct RateLimiter<S: Service> {
    weights: Option<Receiver<S, f32, WeightsHeader>>,
    per_step: f64,
    per_update: f64,
    slack: f64,
    updates: u64,
    /// (step, updates) when this sim first saw the learner's updates.
    base: Option<(u64, u64)>,
    /// The update count at which the learner was found starved: no limit
    /// until it moves on.
    starved_at: Option<u64>,
}

/// How long the learner may make no progress before the limit lets a step through.
const STARVED: std::time::Duration = std::time::Duration::from_secs(1);

impl<S: Service> RateLimiter<S> {
    /// The insert side of the rate limit of the run `cfg` describes.
    pub fn new(hub: &Hub<S>, cfg: &crate::Config) -> Result<Self> {
        let r = &cfg.replay;
        let on = r.samples_per_insert > 0.0;
        let weights = if on {
            let mut rx = hub.receiver::<f32, WeightsHeader>(&Channel::weights(cfg.sim.envs))?;
            // Waiting on the learner is a matter of milliseconds: no polling.
            rx.set_spin(std::time::Duration::ZERO);
            Some(rx)
        } else {
            None
        };
        // Agent-steps one update trains on: a minibatch of transitions, or
        // of sequences of several trained steps each.
        let trained = (r.batch * cfg.steps_per_row()) as f64;
        let per_update = trained / r.samples_per_insert.max(f64::MIN_POSITIVE);
        // Every host's sims feed the one replay memory.
        let agents = cfg.agents_total() as f64;
        Ok(Self {
            weights,
            // Transitions per step across all sims (they run at the same pace).
            per_step: agents,
            per_update,
            // n-step transitions (sequences) leave up to n (a sequence's
            // steps) after their step, and updates are published every
            // `publish_every`.
            slack: (cfg.learner.n_step.max(cfg.memory().map_or(0, |_| cfg.learner.sequence_steps))
                + 1) as f64
                * agents
                + cfg.learner.publish_every as f64 * per_update,
            updates: 0,
            base: None,
            starved_at: None,
        })
    }

    /// Waits until the learner has caught up. A learner that makes no
    /// progress for `STARVED` is starved rather than busy (the replay is
    /// refilling after a restart, or n-step transitions are still pending),
    /// so the limit is off until its update count moves again: it never
    /// deadlocks the run nor slows a refill.
    pub fn wait(&mut self, hub: &Hub<S>, steps: u64) -> Result<()> {
        let Some(rx) = &mut self.weights else {
            return Ok(());
        };
        let start = std::time::Instant::now();
        let mut progress = start;
        let mut latest = rx
            .latest()
            .doing("reading the learner's update count")?
            .map(|m| m.user_header().updates);
        loop {
            if let Some(u) = latest.take() {
                if u > self.updates {
                    progress = std::time::Instant::now();
                } else if u < self.updates {
                    // A restarted learner goes on from its saved state:
                    // count afresh from here.
                    self.base = None;
                }
                self.updates = u;
            }
            if self.updates == 0 {
                // Still filling the replay: no limit.
                return Ok(());
            }
            if let Some(u) = self.starved_at {
                if self.updates <= u {
                    return Ok(());
                }
                // Learning goes on: count afresh from here.
                self.starved_at = None;
                self.base = None;
            }
            let (s0, u0) = *self.base.get_or_insert((steps, self.updates));
            let inserted = steps.saturating_sub(s0) as f64 * self.per_step;
            let allowed = self.updates.saturating_sub(u0) as f64 * self.per_update + self.slack;
            if progress.elapsed() >= STARVED {
                self.starved_at = Some(self.updates);
                return Ok(());
            }
            if inserted <= allowed || hub.shutdown_requested() {
                return Ok(());
            }
            latest = rx
                .recv_timeout(POLL)
                .doing("waiting for the learner")?
                .map(|m| m.user_header().updates);
        }
    }
}

/// Publishes the observations of a step: one message for all agents
/// (batched), or one message per agent (non-batched, the old path on
/// purpose), with the `teacher`'s actions of the agents it flies and its
/// labels (none: [`NO_EXPERT`] for all).
pub fn send_obs<S: Service>(
    tx: &mut Sender<S, f32, ObsHeader>,
    env: &VecEnv,
    step: u64,
    batched: bool,
    teacher: Option<(&[f32], &[f32])>,
) -> rotorhive_transport::Result<()> {
    let total = env.agents();
    let shapes = env.config().shapes();
    let per = if batched { total } else { 1 };
    for first in (0..total).step_by(per) {
        let n = per.min(total - first);
        tx.send_with(shapes.obs_batch_len(n), |h, p| {
            *h = ObsHeader {
                agents: n as u32,
                first: first as u32,
                total: total as u32,
                reserved: 0,
                step,
            };
            let (obs, rest) = p.split_at_mut(n * shapes.obs_len());
            env.write_observations(first, obs);
            let (rew, rest) = rest.split_at_mut(n);
            let (done, rest) = rest.split_at_mut(n);
            let (flies, labels) = rest.split_at_mut(n);
            rew.copy_from_slice(&env.rewards()[first..first + n]);
            for (d, k) in done.iter_mut().zip(&env.dones()[first..first + n]) {
                *d = *k as u8 as f32;
            }
            match teacher {
                Some((f, l)) => {
                    flies.copy_from_slice(&f[first..first + n]);
                    labels.copy_from_slice(&l[first..first + n]);
                }
                None => {
                    flies.fill(NO_EXPERT);
                    labels.fill(NO_EXPERT);
                }
            }
        })?;
    }
    Ok(())
}
