//! What every role runs in and shares: its context ([`Ctx`]), the waits
//! it keeps, and its telemetry counters.

use std::path::Path;
use std::time::Duration;

use rotorhive_msg::{RoleKind, Telemetry};
use rotorhive_transport::{Channel, Hub, Periodic, Service};

use crate::config::Config;
use crate::error::Result;

/// What a role runs in: its run's hub (the node and the service-name
/// prefix), the run's resolved config and its directory. A role stops when
/// `hub.shutdown_requested()` (a signal, or `rotorhive_transport::request_stop`).
pub struct Ctx<'a, S: Service> {
    /// The role's node in the run.
    pub hub: &'a Hub<S>,
    /// The run's validated config.
    pub cfg: &'a Config,
    /// The run directory (checkpoints, the replay's file); none for a role
    /// that keeps nothing.
    pub run_dir: Option<&'a Path>,
}

/// How long a send may wait on a full receiver before the stall is reported.
pub const STALL_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a role sleeps on an empty channel before re-checking for shutdown.
pub const POLL: Duration = Duration::from_millis(100);

/// The episodes channel, actors → supervisor.
pub fn episodes_channel(envs: usize) -> Channel {
    Channel::episodes(envs)
}

/// Processes (or threads) that publish telemetry in a run.
pub fn roles_of(cfg: &Config) -> usize {
    2 * cfg.sim.envs + 2
}

/// A role's telemetry: its counters and stage timers ([`Telemetry`]),
/// published about once a second by the transport's one periodic publisher.
pub type Counters<S> = Periodic<S, Telemetry>;

/// The counters of role `role` number `index` in a run of `roles` roles.
pub fn counters<S: Service>(
    hub: &Hub<S>,
    role: RoleKind,
    index: usize,
    roles: usize,
) -> Result<Counters<S>> {
    let sample = Telemetry {
        role: role as u32,
        index: index as u32,
        pid: std::process::id(),
        ..Telemetry::default()
    };
    Ok(Periodic::new(hub, &Channel::telemetry(roles), sample)?)
}
