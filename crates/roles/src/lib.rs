//! The roles of a rotorhive run and what they share: the config, the
//! context a role runs in, telemetry counters, and the serial mode that runs
//! every role as a thread of one process.
//!
//! Each role is a function generic over the iceoryx2 service type: `ipc`
//! when `hive` runs it as a process of its own, `local` when it runs as a
//! thread beside the others ([`serial`]), the debugging mode and the home of
//! fast role tests. A role takes a [`Ctx`] and no command-line types.

pub mod actor;
mod ctx;
pub mod error;
pub mod evaluation;
pub mod learner;
pub mod replay;
pub mod schedule;
pub mod sim;
pub mod teacher;

pub use ctx::{Counters, Ctx, POLL, STALL_TIMEOUT, counters, episodes_channel, roles_of};
/// The run's config (its own crate, without the transport).
pub use rotorhive_config as config;
pub use rotorhive_config::{levels, streams};

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::thread::JoinHandle;

use crate::error::{Doing, Result, protocol_err};
pub use rotorhive_msg::EpisodeHeader;
use rotorhive_msg::RoleKind;
use rotorhive_transport::Service;
use rotorhive_transport::{Hub, Local};

pub use config::{Config, DeviceName, Exploration, ObservationMode};

/// The roles of a run, by node name and what starts them: the learner, the
/// replay, and an actor and a sim per environment.
pub fn role_names(cfg: &Config) -> Vec<(String, RoleKind, usize)> {
    let mut v = vec![
        (node_name(RoleKind::Learner, 0), RoleKind::Learner, 0),
        (node_name(RoleKind::Replay, 0), RoleKind::Replay, 0),
    ];
    for e in 0..cfg.sim.envs {
        v.push((node_name(RoleKind::Actor, e), RoleKind::Actor, e));
        v.push((node_name(RoleKind::Sim, e), RoleKind::Sim, e));
    }
    v
}

/// The node (and log) name of role `role` number `index`: `sim-0`,
/// `actor-0`, `replay`, `learner`.
pub fn node_name(role: RoleKind, index: usize) -> String {
    match role {
        RoleKind::Sim | RoleKind::Actor => format!("{}-{index}", role.name()),
        RoleKind::Replay | RoleKind::Learner | RoleKind::Link => role.name().to_string(),
    }
}

/// Runs one role in the calling thread until the run stops.
pub fn run_role<S: Service>(cx: Ctx<'_, S>, role: RoleKind, index: usize) -> Result<()> {
    match role {
        RoleKind::Sim => sim::run(cx, index),
        RoleKind::Actor => actor::run(cx, index),
        RoleKind::Replay => replay::run(cx),
        RoleKind::Learner => learner::run(cx),
        RoleKind::Link => protocol_err!(
            "the link is not a role of its own: it runs inside `hive train --listen` and `hive worker`"
        ),
    }
}

/// Serial mode: every role of the run as a thread of this process, over
/// iceoryx2's `local` service (run `prefix`). Returns each thread's name and
/// handle; setting `stop` (or `rotorhive_transport::request_stop`) ends them.
pub fn spawn_serial(
    cfg: &Config,
    prefix: &str,
    run_dir: &Path,
    stop: &Arc<AtomicBool>,
) -> Result<Vec<(String, JoinHandle<Result<()>>)>> {
    spawn_threads(cfg, prefix, run_dir, stop, role_names(cfg))
}

/// The sims and actors of a host without the learner and replay (a worker
/// host, whose link carries their transitions to the head).
pub fn env_role_names(cfg: &Config) -> Vec<(String, RoleKind, usize)> {
    role_names(cfg)
        .into_iter()
        .filter(|(_, r, _)| matches!(r, RoleKind::Sim | RoleKind::Actor))
        .collect()
}

/// Runs `roles` as threads of this process over iceoryx2's `local` service.
pub fn spawn_threads(
    cfg: &Config,
    prefix: &str,
    run_dir: &Path,
    stop: &Arc<AtomicBool>,
    roles: Vec<(String, RoleKind, usize)>,
) -> Result<Vec<(String, JoinHandle<Result<()>>)>> {
    let mut out = Vec::new();
    for (name, role, index) in roles {
        let (cfg, prefix, dir): (Config, String, PathBuf) =
            (cfg.clone(), prefix.to_string(), run_dir.to_path_buf());
        let (node, stop) = (name.clone(), stop.clone());
        let h = std::thread::Builder::new()
            .name(name.clone())
            .spawn(move || {
                let hub = Hub::<Local>::new(&prefix, &node)
                    .doing_with(|| format!("role {node}"))?
                    .with_stop(stop);
                run_role(Ctx { hub: &hub, cfg: &cfg, run_dir: Some(&dir) }, role, index)
                    .doing_with(|| format!("role {node}"))
            })
            .doing_with(|| format!("cannot start the {name} thread"))?;
        out.push((name, h));
    }
    Ok(out)
}

/// Joins role threads started by [`spawn_threads`] (after their stop was
/// set); returns the first error (each already names its role) or panic.
pub fn join_threads(threads: Vec<(String, JoinHandle<Result<()>>)>) -> Option<String> {
    let mut first = None;
    for (name, h) in threads {
        let err = match h.join() {
            Ok(Ok(())) => None,
            Ok(Err(e)) => Some(format!("{e:#}")),
            Err(_) => Some(format!("role {name} panicked")),
        };
        first = first.or(err);
    }
    first
}
