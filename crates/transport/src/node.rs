//! What a node is: a role's handle on its run ([`Hub`]), which opens its
//! channels, the periodic telemetry publisher, the shared-memory domain,
//! the run's names, and the liveness and clean-up of nodes.

use std::fmt::Debug;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::node::NodeView;
use iceoryx2::port::BackpressureAction;
use iceoryx2::prelude::*;

use crate::channel::{Channel, Receiver, Sender, spin};
use crate::signal::{request_stop, stop_requested};
use crate::{Cause, Ipc, Plain, Result, Service, TransportError};

/// The publish-subscribe service of a channel and its event service.
type Services<S, T, H> = (
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, [T], H>,
    iceoryx2::service::port_factory::event::PortFactory<S>,
);

/// A role's handle on its run: the iceoryx2 node and the run's name prefix.
pub struct Hub<S: Service> {
    node: Node<S>,
    prefix: String,
    stop: Arc<AtomicBool>,
}

impl<S: Service> Hub<S> {
    /// Creates this process's node for the run `prefix`.
    pub fn new(prefix: &str, node_name: &str) -> Result<Self> {
        let err = |e: Cause| TransportError::Node { node: node_name.to_string(), cause: e };
        let name = NodeName::new(node_name).map_err(|e| err(e.into()))?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(domain_config())
            .create::<S>()
            .map_err(|e| err(e.into()))?;
        Ok(Self { node, prefix: prefix.to_string(), stop: Arc::new(AtomicBool::new(false)) })
    }

    /// Shares `stop` with this hub: setting it stops the loops that use the
    /// hub, as a signal would (the roles of one serial run share one).
    pub fn with_stop(mut self, stop: Arc<AtomicBool>) -> Self {
        self.stop = stop;
        self
    }

    /// The run prefix.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// True once the process was asked to stop: SIGINT, SIGTERM, SIGHUP (see
    /// [`handle_hangup`]) or [`request_stop`]; or this hub's run was (see
    /// [`Hub::with_stop`]). Sticky and process-wide, so
    /// every role thread of a process sees it, however many hubs ask.
    pub fn shutdown_requested(&self) -> bool {
        // iceoryx2 hands a termination signal to the first caller only (it
        // swaps its flag back); keep it for everyone. Its signal handler is
        // read directly: `Node::wait(0)` would also make a nanosleep system
        // call, which costs about 78 µs here (timer slack), in every loop
        // of every role.
        if iceoryx2_bb_posix::signal::SignalHandler::termination_requested() {
            request_stop();
        }
        stop_requested() || self.stop.load(Ordering::SeqCst)
    }

    fn service_name(&self, ch: &Channel) -> Result<ServiceName> {
        let full = format!("rotorhive/{}/{}", self.prefix, ch.name);
        ServiceName::new(&full).map_err(|e| TransportError::Open {
            channel: full.clone(),
            op: "name service",
            cause: e.into(),
        })
    }

    fn open<T, H>(&self, ch: &Channel) -> Result<Services<S, T, H>>
    where
        T: Debug + ZeroCopySend + 'static,
        H: Debug + ZeroCopySend + Default + 'static,
    {
        let name = self.service_name(ch)?;
        let open_err =
            |op, e: Cause| TransportError::Open { channel: ch.name.clone(), op, cause: e };
        use iceoryx2::service::builder::event::{EventOpenError, EventOpenOrCreateError as EvE};
        use iceoryx2::service::builder::publish_subscribe::{
            PublishSubscribeOpenError as PsOpen, PublishSubscribeOpenOrCreateError as PsE,
        };
        let ps = past_hanging_creation(
            || {
                self.node
                    .service_builder(&name)
                    .publish_subscribe::<[T]>()
                    .user_header::<H>()
                    .max_publishers(ch.publishers)
                    .max_subscribers(ch.subscribers)
                    .subscriber_max_buffer_size(ch.buffer)
                    .history_size(ch.history)
                    .enable_safe_overflow(ch.overflow)
                    .open_or_create()
            },
            |e| matches!(e, PsE::PublishSubscribeOpenError(PsOpen::HangsInCreation)),
        )
        .map_err(|e| open_err("open publish-subscribe service", e.into()))?;
        let ev = past_hanging_creation(
            || {
                self.node
                    .service_builder(&name)
                    .event()
                    .max_notifiers(ch.publishers + 1)
                    .max_listeners(ch.subscribers + 1)
                    .open_or_create()
            },
            |e| matches!(e, EvE::EventOpenError(EventOpenError::HangsInCreation)),
        )
        .map_err(|e| open_err("open event service", e.into()))?;
        Ok((ps, ev))
    }

    /// A sender on a channel; `max_len` is the largest payload it will send.
    /// Back-pressure waits at most `stall_timeout` per message.
    pub fn sender<T, H>(
        &self,
        ch: &Channel,
        max_len: usize,
        stall_timeout: Duration,
    ) -> Result<Sender<S, T, H>>
    where
        T: Plain,
        H: Debug + ZeroCopySend + Default + 'static,
    {
        let (ps, ev) = self.open::<T, H>(ch)?;
        let open_err =
            |op, e: Cause| TransportError::Open { channel: ch.name.clone(), op, cause: e };
        let stalls = Arc::new(AtomicU64::new(0));
        let counter = stalls.clone();
        let publisher = ps
            .publisher_builder()
            .initial_max_slice_len(max_len.max(1))
            .set_backpressure_handler(move |info: &iceoryx2::port::BackpressureInfo| {
                // A process asked to stop gives up at once instead of waiting
                // out the stall timeout.
                if info.elapsed_time < stall_timeout && !stop_requested() {
                    // Give the receiver the core instead of spinning on it.
                    std::thread::sleep(Duration::from_micros(50));
                    BackpressureAction::Retry
                } else {
                    counter.fetch_add(1, Ordering::Relaxed);
                    BackpressureAction::DiscardDataAndFail
                }
            })
            .create()
            .map_err(|e| open_err("create publisher", e.into()))?;
        let notifier =
            ev.notifier_builder().create().map_err(|e| open_err("create notifier", e.into()))?;
        Ok(Sender {
            publisher,
            notifier,
            service: ps,
            channel: ch.name.clone(),
            stalls,
            stall_timeout,
            needs_receiver: ch.needs_receiver,
            sent: 0,
        })
    }

    /// A receiver on a channel.
    pub fn receiver<T, H>(&self, ch: &Channel) -> Result<Receiver<S, T, H>>
    where
        T: Debug + ZeroCopySend + Default + Copy + 'static,
        H: Debug + ZeroCopySend + Default + 'static,
    {
        let (ps, ev) = self.open::<T, H>(ch)?;
        let open_err =
            |op, e: Cause| TransportError::Open { channel: ch.name.clone(), op, cause: e };
        let subscriber = ps
            .subscriber_builder()
            .create()
            .map_err(|e| open_err("create subscriber", e.into()))?;
        let listener =
            ev.listener_builder().create().map_err(|e| open_err("create listener", e.into()))?;
        Ok(Receiver { subscriber, listener, channel: ch.name.clone(), spin: spin() })
    }
}

/// Opens a service, trying again (up to three times, after cleaning up
/// dead nodes) while iceoryx2 finds it hanging in creation: seen once when
/// a role SIGKILLed and started again opened its actions' event service.
fn past_hanging_creation<T, E>(
    mut open: impl FnMut() -> std::result::Result<T, E>,
    hangs: impl Fn(&E) -> bool,
) -> std::result::Result<T, E> {
    for _ in 0..3 {
        match open() {
            Err(e) if hangs(&e) => {
                cleanup_dead_nodes();
                std::thread::sleep(Duration::from_millis(100));
            }
            r => return r,
        }
    }
    open()
}

/// A header published about once a second (every role's and link's
/// telemetry): the one publisher of such samples. It overflows rather than
/// blocks, so a slow reader never holds a role back.
pub struct Periodic<S: Service, H: Debug + ZeroCopySend + 'static> {
    /// The sample being filled.
    pub sample: H,
    tx: Sender<S, u8, H>,
    last: Option<Instant>,
}

impl<S: Service, H: Debug + ZeroCopySend + Default + Copy + 'static> Periodic<S, H> {
    /// Publishes `sample` on `ch`; the first [`Periodic::tick`] publishes at once.
    pub fn new(hub: &Hub<S>, ch: &Channel, sample: H) -> Result<Self> {
        let tx = hub.sender::<u8, H>(ch, 1, Duration::from_millis(10))?;
        Ok(Self { sample, tx, last: None })
    }

    /// Publishes the sample when a second has passed since the last one (or
    /// `force`), after `stamp` marks it (a heartbeat); says whether it did.
    pub fn tick(&mut self, force: bool, stamp: impl FnOnce(&mut H)) -> bool {
        if !force && self.last.is_some_and(|t| t.elapsed() < Duration::from_secs(1)) {
            return false;
        }
        self.last = Some(Instant::now());
        stamp(&mut self.sample);
        self.send(self.sample);
        true
    }

    /// Publishes another sample on the same channel now (a link passing on
    /// another host's); a full channel drops it, which is not fatal.
    pub fn send(&mut self, h: H) {
        let _ = self.tx.send_with(1, |slot, _| *slot = h);
    }
}

/// The environment variable that names this process's shared-memory domain
/// (`hive --domain NAME` sets it, and role processes inherit it).
pub const DOMAIN_ENV: &str = "ROTORHIVE_DOMAIN";

/// Checks a domain name: 1 to 32 letters, digits, `-` or `_`.
pub fn check_domain(name: &str) -> std::result::Result<(), String> {
    if name.is_empty()
        || name.len() > 32
        || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        return Err(format!("domain {name:?}: use 1 to 32 letters, digits, '-' or '_'"));
    }
    Ok(())
}

/// The iceoryx2 config of this process's domain: the machine's shared one,
/// or, where `ROTORHIVE_DOMAIN` names one, a domain of its own (its own file
/// prefix and root directory), whose services and nodes the processes of
/// other domains cannot see, exactly as if they ran on another host. Read
/// once per process.
pub fn domain_config() -> &'static Config {
    static DOMAIN: std::sync::OnceLock<Option<Config>> = std::sync::OnceLock::new();
    let own = DOMAIN.get_or_init(|| {
        let name = std::env::var(DOMAIN_ENV).ok().filter(|n| !n.is_empty())?;
        if let Err(e) = check_domain(&name) {
            tracing::warn!("{DOMAIN_ENV}: {e}; using the machine's shared domain");
            return None;
        }
        let mut c = Config::global_config().clone();
        // Both were checked: short, and only characters valid in file names.
        c.global.prefix = FileName::new(format!("rh_{name}_").as_bytes()).ok()?;
        c.global
            .set_root_path(&Path::new(format!("/tmp/iceoryx2/rotorhive-{name}/").as_bytes()).ok()?);
        Some(c)
    });
    own.as_ref().unwrap_or_else(|| Config::global_config())
}

/// A number no other process (or call) is likely to draw: std's random
/// per-process hash keys over the time. For a link's epoch and a replay's
/// incarnation.
pub fn fresh_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.finish()
}

/// A service-name prefix no other run on this machine uses: `kind`, this
/// process's id and the clock's nanoseconds (`run-4242-1a2b3c`), so that a
/// run started again by the same pid after a crash does not meet the first
/// one's leftovers.
pub fn unique_prefix(kind: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!("{kind}-{}-{nanos:x}", std::process::id())
}

/// The name of the supervisor's node of run `prefix`: roles watch for it.
pub fn supervisor_node_name(prefix: &str) -> String {
    format!("train.{prefix}")
}

/// Whether a node called `name` is alive (`Some(true)`), known but dead
/// (`Some(false)`), or not registered at all (`None`).
pub fn node_alive(name: &str) -> Option<bool> {
    let mut state = None;
    let _ = Node::<Ipc>::list(domain_config(), |s| {
        let (alive, details) = match &s {
            NodeState::Alive(v) => (true, v.details().clone()),
            NodeState::Dead(v) => (false, v.details().clone()),
            _ => return CallbackProgression::Continue,
        };
        if details.is_some_and(|d| d.name().as_str() == name) {
            state = Some(state.unwrap_or(false) || alive);
        }
        CallbackProgression::Continue
    });
    state
}

/// Removes the resources of iceoryx2 nodes whose processes died; returns how
/// many dead nodes were cleaned.
pub fn cleanup_dead_nodes() -> usize {
    let mut cleaned = 0;
    let _ = Node::<Ipc>::list(domain_config(), |state| {
        if let NodeState::Dead(dead) = state
            && dead.try_remove_stale_resources().is_ok()
        {
            cleaned += 1;
        }
        CallbackProgression::Continue
    });
    cleaned
}

/// Names of the live iceoryx2 services of service type `S` whose name
/// starts with the run's prefix.
pub fn services_of_run<S: Service>(prefix: &str) -> Vec<String> {
    let want = format!("rotorhive/{prefix}/");
    let mut out = Vec::new();
    let _ = S::list(domain_config(), |s| {
        let name = s.static_details.name().to_string();
        if name.starts_with(&want) {
            out.push(name);
        }
        CallbackProgression::Continue
    });
    out
}
