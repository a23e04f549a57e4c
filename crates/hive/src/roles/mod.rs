//! The four roles of a run, each a process of its own, and what they share:
//! loading the run's config, opening the run's hub, and telemetry.

pub mod actor;
pub mod learner;
pub mod replay;
pub mod sim;

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use iceoryx2::prelude::ZeroCopySend;
use rotorhive_msg::{RoleKind, STAGES, Telemetry};
use rotorhive_transport::{Channel, Hub, Ipc, Sender};

use crate::RoleArgs;
use crate::config::Config;

/// How long a send may wait on a full receiver before the stall is reported.
pub const STALL_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a role sleeps on an empty channel before re-checking for shutdown.
pub const POLL: Duration = Duration::from_millis(100);

/// Every role's start: the validated config and the run's hub. SIGHUP
/// stops the role as SIGTERM does, and the role stops when the supervisor of
/// its run goes (see [`watch_supervisor`]).
pub fn open(role: &RoleArgs, node: &str) -> Result<(Config, Hub<Ipc>)> {
    let cfg = Config::load(role.cfg.config.as_deref(), &role.cfg.set)?;
    rotorhive_transport::handle_hangup();
    let hub = Hub::<Ipc>::new(&role.prefix, node).with_context(|| format!("role {node}"))?;
    watch_supervisor(&role.prefix, node)?;
    Ok((cfg, hub))
}

/// The environment variable through which `hive train` tells its roles its
/// process id.
pub const SUPERVISOR_PID_ENV: &str = "ROTORHIVE_SUPERVISOR_PID";

/// How long a role whose supervisor is gone has to stop cleanly before it
/// exits at once (the whole run is down within 2 s of its supervisor).
const ORPHAN_GRACE: Duration = Duration::from_millis(1500);

/// Stops this role when its run's supervisor is gone, however it went
/// (SIGKILL, the OOM killer): a thread checks every 200 ms whether the
/// supervisor that started it is still its parent, and whether the
/// supervisor's iceoryx2 node (once seen) is alive, which also covers roles
/// started by hand with `--prefix`. It then asks the role to stop, and ends
/// the process if it has not stopped within [`ORPHAN_GRACE`]. (`hive train`
/// also sets `PR_SET_PDEATHSIG`, which signals at once.)
fn watch_supervisor(prefix: &str, node: &str) -> Result<()> {
    let parent: Option<i32> = std::env::var(SUPERVISOR_PID_ENV).ok().and_then(|v| v.parse().ok());
    let supervisor = rotorhive_transport::supervisor_node_name(prefix);
    let node = node.to_string();
    std::thread::Builder::new()
        .name("supervisor-watch".into())
        .spawn(move || {
            let mut seen = false;
            loop {
                std::thread::sleep(Duration::from_millis(200));
                // SAFETY: getppid(2) has no preconditions.
                let orphaned = parent.is_some_and(|p| unsafe { libc::getppid() } != p);
                let state = rotorhive_transport::node_alive(&supervisor);
                seen |= state == Some(true);
                if orphaned || (seen && state != Some(true)) {
                    tracing::warn!("{node}: the supervisor of this run is gone; stopping");
                    rotorhive_transport::request_stop();
                    std::thread::sleep(ORPHAN_GRACE);
                    eprintln!("{node}: did not stop within {ORPHAN_GRACE:?} of its supervisor's end; exiting");
                    // SAFETY: _exit(2) ends the process without running
                    // anything else; shared memory is cleaned by the next start.
                    unsafe { libc::_exit(3) };
                }
            }
        })
        .context("cannot start the supervisor watch")?;
    Ok(())
}

/// Episode summaries, actor → supervisor: header plus `[f32]` triples
/// (return, steps, done code).
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("rotorhive::EpisodeHeader")]
#[repr(C)]
pub struct EpisodeHeader {
    /// Actor index.
    pub actor: u32,
    /// Episodes in the message.
    pub count: u32,
    /// Transitions this actor has produced.
    pub transitions: u64,
    /// Exploration rate in use ×1e6.
    pub epsilon_micro: u64,
}

/// The episodes channel.
pub fn episodes_channel(envs: usize) -> Channel {
    Channel { name: "episodes".into(), publishers: envs, subscribers: 1, buffer: 256, overflow: false, history: 0 }
}

/// A role's telemetry: counters and stage timers, published about once a second.
pub struct Counters {
    pub sample: Telemetry,
    tx: Sender<Ipc, u8, Telemetry>,
    last: Instant,
}

impl Counters {
    pub fn new(hub: &Hub<Ipc>, role: RoleKind, index: usize, roles: usize) -> Result<Self> {
        let tx = hub.sender::<u8, Telemetry>(&Channel::telemetry(roles), 1, Duration::from_millis(10))?;
        let sample = Telemetry { role: role as u32, index: index as u32, pid: std::process::id(), ..Telemetry::default() };
        Ok(Self { sample, tx, last: Instant::now() - Duration::from_secs(10) })
    }

    /// Adds the time since `since` to stage `i`.
    pub fn stage(&mut self, i: usize, since: Instant) {
        debug_assert!(i < STAGES);
        self.sample.stage_ns[i] += since.elapsed().as_nanos() as u64;
    }

    /// Publishes when a second has passed since the last sample (or `force`).
    pub fn tick(&mut self, force: bool) -> bool {
        if !force && self.last.elapsed() < Duration::from_secs(1) {
            return false;
        }
        self.last = Instant::now();
        self.sample.heartbeat += 1;
        let s = self.sample;
        // Telemetry overflows rather than blocks; a failure here is not fatal.
        let _ = self.tx.send_with(1, |h, _| *h = s);
        true
    }
}
