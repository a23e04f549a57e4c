//! `hive sim`: one simulator process. Publishes an observation batch, waits
//! for the matching action batch, steps all its agents, and repeats.

use std::time::Instant;

use anyhow::{Context, Result, bail};
use rotorhive_msg::{ActionHeader, OBS_LEN, ObsHeader, RoleKind, obs_batch_len};
use rotorhive_sim::VecEnv;
use rotorhive_transport::Channel;

use super::{Counters, POLL, STALL_TIMEOUT, open};
use crate::RoleArgs;

/// How long a sim waits for actions before publishing the same step again.
const RESEND: std::time::Duration = std::time::Duration::from_millis(1000);

pub fn run(role: RoleArgs, env_index: usize) -> Result<()> {
    let (cfg, hub) = open(&role, &format!("sim-{env_index}"))?;
    if env_index >= cfg.sim.envs {
        bail!("--env {env_index} is out of range: the config has {} environments", cfg.sim.envs);
    }
    let arena = cfg.arena()?;
    let n = cfg.sim.agents;
    let mut env = VecEnv::new(cfg.sim_config(), arena, cfg.seed.wrapping_mul(1000).wrapping_add(env_index as u64));
    assert_eq!(env.obs_len(), OBS_LEN, "simulator and message layouts disagree");
    let mut obs_tx = hub.sender::<f32, ObsHeader>(&Channel::obs(env_index), obs_batch_len(n), STALL_TIMEOUT)?;
    let mut act_rx = hub.receiver::<u8, ActionHeader>(&Channel::actions(env_index))?;
    let mut tel = Counters::new(&hub, RoleKind::Sim, env_index, roles_of(&cfg))?;
    let mut step = 0u64;
    let mut timing = (0u64, 0u64);
    let mut need_send = true;
    let mut last_send = Instant::now();
    loop {
        if hub.shutdown_requested() {
            break;
        }
        if need_send {
            match send_obs(&mut obs_tx, &env, env_index, step, timing) {
                Ok(()) => {
                    need_send = false;
                    last_send = Instant::now();
                }
                Err(e) => {
                    // The actor is gone or restarting: report, and try again.
                    tracing::warn!("sim {env_index}: {e}");
                    tel.sample.lost += 1;
                    tel.tick(false);
                    continue;
                }
            }
        }
        let t = Instant::now();
        let msg = act_rx.recv_timeout(POLL).context("waiting for actions")?;
        tel.stage(3, t);
        tel.tick(false);
        let Some(msg) = msg else {
            // An actor that subscribed after our send (or restarted) never saw
            // this step: publish it again; the actor answers duplicates.
            if last_send.elapsed() > RESEND {
                need_send = true;
            }
            continue;
        };
        let h = *msg.user_header();
        if h.step != step || msg.payload().len() != n {
            // A stale or foreign batch: count it and keep waiting for the right one.
            tel.sample.lost += 1;
            continue;
        }
        env.step(msg.payload());
        drop(msg);
        step += 1;
        let tm = env.timing();
        timing = (tm.physics_ns, tm.render_ns);
        tel.sample.stage_ns[0] += tm.physics_ns;
        tel.sample.stage_ns[1] += tm.render_ns;
        tel.sample.stage_ns[2] += tm.reset_ns;
        tel.sample.work += n as u64;
        tel.sample.work2 += env.finished().len() as u64;
        need_send = true;
    }
    tel.tick(true);
    Ok(())
}

fn send_obs(tx: &mut rotorhive_transport::Sender<rotorhive_transport::Ipc, f32, ObsHeader>, env: &VecEnv, e: usize, step: u64, timing: (u64, u64)) -> rotorhive_transport::Result<()> {
    let n = env.agents();
    tx.send_with(obs_batch_len(n), |h, p| {
        *h = ObsHeader { env: e as u32, agents: n as u32, step, physics_ns: timing.0, render_ns: timing.1 };
        let (obs, rest) = p.split_at_mut(n * OBS_LEN);
        obs.copy_from_slice(env.observations());
        let (rew, done) = rest.split_at_mut(n);
        rew.copy_from_slice(env.rewards());
        for (d, k) in done.iter_mut().zip(env.dones()) {
            *d = *k as u8 as f32;
        }
    })
}

/// Processes that publish telemetry in a run.
pub fn roles_of(cfg: &crate::config::Config) -> usize {
    2 * cfg.sim.envs + 2
}
