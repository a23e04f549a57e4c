//! `hive actor`: paired with one sim. Keeps a local Q-network, picks actions
//! for all the sim's agents in one batched inference (epsilon-greedy),
//! assembles transitions straight into shared memory for the replay process,
//! and picks up newer weights by version.

use std::time::Instant;

use anyhow::{Context, Result, bail};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rotorhive_model::QNet;
use rotorhive_msg::{ActionHeader, OBS_LEN, ObsHeader, RoleKind, TRANSITION_LEN, TransitionHeader, WeightsHeader};
use rotorhive_transport::Channel;

use super::{Counters, EpisodeHeader, POLL, STALL_TIMEOUT, episodes_channel, open};
use crate::RoleArgs;
use crate::config::Config;

/// Exploration rate after `transitions` (across all actors): constant until
/// the replay memory is full, then linear decay.
pub fn epsilon(cfg: &Config, transitions: u64) -> f64 {
    let a = &cfg.actor;
    let start = cfg.replay.min_fill as u64;
    if transitions <= start {
        return a.eps_start;
    }
    let frac = ((transitions - start) as f64 / a.eps_decay.max(1) as f64).min(1.0);
    a.eps_start + (a.eps_end - a.eps_start) * frac
}

pub fn run(role: RoleArgs, e: usize) -> Result<()> {
    let (cfg, hub) = open(&role, &format!("actor-{e}"))?;
    if e >= cfg.sim.envs {
        bail!("--env {e} is out of range: the config has {} environments", cfg.sim.envs);
    }
    let n = cfg.sim.agents;
    let envs = cfg.sim.envs;
    let mut net = QNet::new(cfg.seed, &rotorhive_model::device(&cfg.actor.device)?)?;
    net.set_threads(cfg.actor.threads);
    let mut obs_rx = hub.receiver::<f32, ObsHeader>(&Channel::obs(e))?;
    let mut act_tx = hub.sender::<u8, ActionHeader>(&Channel::actions(e), n, STALL_TIMEOUT)?;
    let mut trans_tx = hub.sender::<f32, TransitionHeader>(&Channel::transitions(envs), n * TRANSITION_LEN, STALL_TIMEOUT)?;
    let mut w_rx = hub.receiver::<f32, WeightsHeader>(&Channel::weights(envs))?;
    let mut ep_tx = hub.sender::<f32, EpisodeHeader>(&episodes_channel(envs), 3 * n, STALL_TIMEOUT)?;
    let mut tel = Counters::new(&hub, RoleKind::Actor, e, super::sim::roles_of(&cfg))?;
    let mut rng = Pcg64Mcg::seed_from_u64(cfg.seed ^ (0xac70 + e as u64));

    let mut version = 0u64;
    let mut prev_obs = vec![0.0f32; n * OBS_LEN];
    let mut prev_actions = vec![0u8; n];
    let mut have_prev = false;
    let mut expected_step = 0u64;
    let mut returns = vec![0.0f32; n];
    let mut lengths = vec![0u32; n];
    let mut episodes = 0u64;
    let mut seq = 0u64;
    let mut transitions = 0u64;
    let mut finished: Vec<f32> = Vec::with_capacity(3 * n);
    let mut actions = vec![0u8; n];
    let mut gather = vec![0.0f32; rotorhive_msg::obs_batch_len(n)];
    let mut gather_step = u64::MAX;
    let mut gathered = 0usize;
    loop {
        if hub.shutdown_requested() {
            break;
        }
        let t = Instant::now();
        if let Some(w) = w_rx.latest().context("reading weights")? {
            let h = *w.user_header();
            // Any other version is newer: a restarted learner goes on from
            // its saved update count, which never lies behind.
            if h.version != version {
                net.load_flat(w.payload()).context("loading published weights")?;
                version = h.version;
                tel.sample.weight_version = version;
            }
        }
        tel.stage(2, t);
        let t = Instant::now();
        let msg = obs_rx.recv_timeout(POLL).context("waiting for observations")?;
        tel.stage(3, t);
        tel.tick(false);
        let Some(msg) = msg else { continue };
        let h = *msg.user_header();
        if h.total as usize != n || h.first as usize + h.agents as usize > n || msg.payload().len() != rotorhive_msg::obs_batch_len(h.agents as usize) {
            bail!("observation batch from sim {e} has agents {}..{} of {}, the config says {n}", h.first, h.first + h.agents, h.total);
        }
        if have_prev && h.step + 1 == expected_step {
            // The sim published this step again: our actions were not seen.
            // Answer with the same actions (once) and record nothing twice.
            drop(msg);
            if h.first == 0 {
                send_actions(&mut act_tx, e, h.step, &prev_actions, &mut tel.sample.lost);
            }
            continue;
        }
        // Non-batched mode: one message per agent, gathered into the layout
        // of a whole batch before anything else happens.
        let mut whole = None;
        if h.agents as usize == n {
            whole = Some(msg);
        } else {
            if h.step != gather_step || gathered == 0 {
                gather_step = h.step;
                gathered = 0;
            }
            let (a, k) = (h.first as usize, h.agents as usize);
            let src = msg.payload();
            gather[a * OBS_LEN..(a + k) * OBS_LEN].copy_from_slice(&src[..k * OBS_LEN]);
            gather[n * OBS_LEN + a..n * OBS_LEN + a + k].copy_from_slice(&src[k * OBS_LEN..k * OBS_LEN + k]);
            gather[n * OBS_LEN + n + a..n * OBS_LEN + n + a + k].copy_from_slice(&src[k * OBS_LEN + k..]);
            drop(msg);
            gathered += k;
            if gathered < n {
                continue;
            }
            gathered = 0;
        }
        let p: &[f32] = match &whole {
            Some(m) => m.payload(),
            None => &gather,
        };
        if h.step != expected_step {
            // The sim restarted (step 0) or a batch was lost: start afresh.
            tel.sample.lost += 1;
            have_prev = false;
        }
        expected_step = h.step + 1;
        let (obs, rest) = p.split_at(n * OBS_LEN);
        let (rewards, dones) = rest.split_at(n);

        let t = Instant::now();
        if have_prev {
            let global = transitions * envs as u64;
            let eps_now = epsilon(&cfg, global);
            // Transitions are assembled in place in the loaned sample.
            let sent = trans_tx.send_with(n * TRANSITION_LEN, |th, out| {
                *th = TransitionHeader { actor: e as u32, count: n as u32, seq, weight_version: version, episodes };
                for i in 0..n {
                    let o = &mut out[i * TRANSITION_LEN..(i + 1) * TRANSITION_LEN];
                    o[..OBS_LEN].copy_from_slice(&prev_obs[i * OBS_LEN..(i + 1) * OBS_LEN]);
                    o[OBS_LEN..2 * OBS_LEN].copy_from_slice(&obs[i * OBS_LEN..(i + 1) * OBS_LEN]);
                    o[2 * OBS_LEN] = prev_actions[i] as f32;
                    o[2 * OBS_LEN + 1] = rewards[i];
                    o[2 * OBS_LEN + 2] = if dones[i] != 0.0 { 1.0 } else { 0.0 };
                }
            });
            match sent {
                Ok(()) => {
                    seq += 1;
                    transitions += n as u64;
                }
                Err(err) => {
                    tracing::warn!("actor {e}: {err}");
                    tel.sample.lost += 1;
                }
            }
            finished.clear();
            for i in 0..n {
                returns[i] += rewards[i];
                lengths[i] += 1;
                if dones[i] != 0.0 {
                    finished.extend_from_slice(&[returns[i], lengths[i] as f32, dones[i]]);
                    returns[i] = 0.0;
                    lengths[i] = 0;
                    episodes += 1;
                }
            }
            if !finished.is_empty() {
                let count = finished.len() / 3;
                let _ = ep_tx.send_with(finished.len(), |eh, out| {
                    *eh = EpisodeHeader { actor: e as u32, count: count as u32, transitions, epsilon_micro: (eps_now * 1e6) as u64 };
                    out.copy_from_slice(&finished);
                });
            }
            tel.sample.value_milli = (eps_now * 1000.0) as i64;
        }
        tel.stage(1, t);

        let t = Instant::now();
        let eps = epsilon(&cfg, transitions * envs as u64);
        let greedy = net.greedy(obs)?;
        for i in 0..n {
            actions[i] = if rng.random::<f64>() < eps { rng.random_range(0..2u8) } else { greedy[i] };
        }
        tel.stage(0, t);
        prev_obs.copy_from_slice(obs);
        drop(whole);
        prev_actions.copy_from_slice(&actions);
        have_prev = true;
        send_actions(&mut act_tx, e, h.step, &actions, &mut tel.sample.lost);
        tel.sample.work = transitions;
        tel.sample.work2 = episodes;
    }
    tel.tick(true);
    Ok(())
}

/// Publishes one action batch answering observation step `step`; a failed
/// send is reported and counted, and the sim will publish the step again.
fn send_actions(tx: &mut rotorhive_transport::Sender<rotorhive_transport::Ipc, u8, ActionHeader>, e: usize, step: u64, actions: &[u8], lost: &mut u64) {
    let n = actions.len();
    if let Err(err) = tx.send_with(n, |ah, out| {
        *ah = ActionHeader { env: e as u32, agents: n as u32, step };
        out.copy_from_slice(actions);
    }) {
        tracing::warn!("actor {e}: {err}");
        *lost += 1;
    }
}
