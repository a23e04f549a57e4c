//! The transport: one place that names, opens and drives every iceoryx2
//! service of a rotorhive run.
//!
//! Each logical channel is a publish-subscribe service with a `#[repr(C)]`
//! user header and a slice payload, paired with an event service of the same
//! name so receivers sleep on a listener instead of spinning. Every service
//! name starts with the run's prefix, so two runs on one machine never meet.
//! Channels that must not lose data refuse to overflow and apply bounded
//! back-pressure: a sender retries for at most its stall timeout, then gives
//! up on that message with an error it can report, so no process ever blocks
//! forever on a dead peer.
//!
//! Generic over the iceoryx2 service variant: `ipc::Service` between
//! processes, `local::Service` between threads of one process (tests).

use std::fmt::Debug;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::node::NodeView;
use iceoryx2::port::BackpressureAction;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;

pub use iceoryx2::service::ipc::Service as Ipc;
pub use iceoryx2::service::local::Service as Local;

/// The iceoryx2 service kinds a run uses: `Ipc` (processes, the default)
/// and `Local` (threads of one process: `--serial` and tests), with what
/// each promises about a loan's bytes.
pub trait Service: iceoryx2::service::Service + sealed::Sealed {
    /// Whether a fresh loan's payload is initialised memory before it is
    /// written: true for `Ipc`, whose payload lies in a shared-memory
    /// segment mapped from a file descriptor (zero-filled by the OS when
    /// created, later holding earlier samples); false for `Local`, whose
    /// segments come from the heap.
    const LOANS_ARE_INITIALISED: bool;
}

impl Service for Ipc {
    const LOANS_ARE_INITIALISED: bool = true;
}

impl Service for Local {
    const LOANS_ARE_INITIALISED: bool = false;
}

mod sealed {
    /// Only this crate's two service kinds are [`super::Service`]s: the
    /// loan's soundness rests on what each one's memory is.
    pub trait Sealed {}
    impl Sealed for super::Ipc {}
    impl Sealed for super::Local {}
}

/// An iceoryx2 error as it came: the error value itself, boxed (callers may
/// downcast it), shown in its error's text.
pub type Cause = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Errors of the transport, naming the channel and the operation. A cause
/// is part of the text and not also `source()`, so `{:#}` names it once.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// Creating the node failed.
    #[error("cannot create iceoryx2 node `{node}`: {cause}")]
    Node {
        /// The node name.
        node: String,
        /// iceoryx2's error (kept as it came, in the text; not `source()`).
        cause: Cause,
    },
    /// Opening or creating a service or port failed.
    #[error("channel `{channel}`: cannot {op}: {cause}")]
    Open {
        /// The channel.
        channel: String,
        /// What was attempted.
        op: &'static str,
        /// iceoryx2's error (kept as it came, in the text; not `source()`).
        cause: Cause,
    },
    /// Sending or receiving failed.
    #[error("channel `{channel}`: {op} failed: {cause}")]
    Io {
        /// The channel.
        channel: String,
        /// What was attempted.
        op: &'static str,
        /// iceoryx2's error (kept as it came, in the text; not `source()`).
        cause: Cause,
    },
    /// A message could not be delivered within the stall timeout.
    #[error("channel `{channel}`: receiver did not take the message within {timeout:?}")]
    Stalled {
        /// The channel.
        channel: String,
        /// The timeout.
        timeout: Duration,
    },
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, TransportError>;

/// Plain data that may travel as a payload element: `bytemuck::Pod` (no
/// padding, every bit pattern a valid value), so a loan can be handed out
/// before it is written. Every such type is one.
pub trait Plain: bytemuck::Pod + Debug + ZeroCopySend + Default {}
impl<T: bytemuck::Pod + Debug + ZeroCopySend + Default> Plain for T {}

/// Quality of service of one channel. Both sides derive the same spec from
/// the same constructor, so their attributes always match.
#[derive(Debug, Clone)]
pub struct Channel {
    /// Name within the run.
    pub name: String,
    /// Most publishers.
    pub publishers: usize,
    /// Most subscribers.
    pub subscribers: usize,
    /// Samples a subscriber can hold before back-pressure (or overflow).
    pub buffer: usize,
    /// Overwrite the oldest sample instead of back-pressure.
    pub overflow: bool,
    /// Samples a late subscriber receives on connecting.
    pub history: usize,
    /// A send with no receiver is a stall, not a success: the sender waits
    /// up to its stall timeout for one, and a sample that reached nobody is
    /// reported as [`TransportError::Stalled`] (so the caller sends it
    /// again or counts it lost). On for transitions, whose loss matters.
    pub needs_receiver: bool,
}

impl Channel {
    /// Observations of sim `env` to its actor, `per_step` messages a step
    /// (1 batched, one per agent non-batched): room for two steps.
    pub fn obs(env: usize, per_step: usize) -> Self {
        Self {
            name: format!("obs.{env}"),
            publishers: 1,
            subscribers: 1,
            buffer: 2 * per_step.max(1),
            overflow: false,
            history: 0,
            needs_receiver: false,
        }
    }
    /// Action batches of actor `env` to its sim.
    pub fn actions(env: usize) -> Self {
        Self {
            name: format!("act.{env}"),
            publishers: 1,
            subscribers: 1,
            buffer: 2,
            overflow: false,
            history: 0,
            needs_receiver: false,
        }
    }
    /// Transition batches from every actor of this host (and the host's
    /// link, which brings other hosts' batches) to the replay memory.
    pub fn transitions(envs: usize) -> Self {
        Self {
            name: "transitions".into(),
            publishers: envs + 1,
            subscribers: 1,
            buffer: 8,
            overflow: false,
            history: 0,
            needs_receiver: true,
        }
    }
    /// Finished episodes from every actor of this host (and its link) to the supervisor.
    pub fn episodes(envs: usize) -> Self {
        Self {
            name: "episodes".into(),
            publishers: envs + 1,
            subscribers: 1,
            buffer: 256,
            overflow: false,
            history: 0,
            needs_receiver: false,
        }
    }
    /// Minibatches from the replay memory to the learner.
    pub fn minibatches(prefetch: usize) -> Self {
        Self {
            name: "minibatches".into(),
            publishers: 1,
            subscribers: 1,
            buffer: prefetch,
            overflow: false,
            history: 0,
            needs_receiver: false,
        }
    }
    /// Priorities from the learner back to the replay (prioritized replay):
    /// one message per minibatch; room for every minibatch in flight.
    pub fn priorities(prefetch: usize) -> Self {
        Self {
            name: "priorities".into(),
            publishers: 1,
            subscribers: 1,
            buffer: 2 * prefetch + 8,
            overflow: false,
            history: 0,
            needs_receiver: false,
        }
    }
    /// Weights from the learner to every actor (and to every sim, which reads
    /// the update count for rate limiting): only the newest matters, and a
    /// late subscriber gets the last published version. On a worker host the
    /// link is the publisher; on the head it is one more subscriber.
    pub fn weights(envs: usize) -> Self {
        Self {
            name: "weights".into(),
            publishers: 1,
            subscribers: 2 * envs + 3,
            buffer: 1,
            overflow: true,
            history: 1,
            needs_receiver: false,
        }
    }
    /// The replay's receipts to its host's link (only the newest matters;
    /// the link gets the last one on connecting).
    pub fn receipts() -> Self {
        Self {
            name: "receipts".into(),
            publishers: 1,
            subscribers: 1,
            buffer: 1,
            overflow: true,
            history: 1,
            needs_receiver: false,
        }
    }
    /// Telemetry from every role to the supervisor; old samples may be overwritten.
    pub fn telemetry(roles: usize) -> Self {
        Self {
            name: "telemetry".into(),
            publishers: roles + 3,
            subscribers: 2,
            buffer: 64,
            overflow: true,
            history: 0,
            needs_receiver: false,
        }
    }
}

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

/// The sending side of a channel.
pub struct Sender<S: Service, T: Debug + ZeroCopySend + 'static, H: Debug + ZeroCopySend + 'static>
{
    publisher: Publisher<S, [T], H>,
    notifier: Notifier<S>,
    service: iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, [T], H>,
    channel: String,
    stalls: Arc<AtomicU64>,
    stall_timeout: Duration,
    sent: u64,
    needs_receiver: bool,
}

impl<S: Service, T: Plain, H: Debug + ZeroCopySend + Default + 'static> Sender<S, T, H> {
    /// Loans a sample of `len` elements in shared memory, lets `fill` write the
    /// header and the payload in place, sends it and wakes the receivers.
    /// The loan is not pre-filled: `fill` must write every element it means
    /// to send (the rest holds whatever an earlier sample left there).
    pub fn send_with(&mut self, len: usize, fill: impl FnOnce(&mut H, &mut [T])) -> Result<()> {
        match self.try_send_with(len, |h, p| {
            fill(h, p);
            Ok::<(), std::convert::Infallible>(())
        })? {
            Ok(()) => Ok(()),
        }
    }

    /// [`Sender::send_with`], sent again for as long as it stalls (the
    /// receiver is full, or gone) unless `give_up(receivers)` says to stop
    /// trying: true when sent, false when it gave up after a stall. The
    /// bounded back-pressure of the link and the actors: a busy receiver is
    /// waited for, never skipped.
    pub fn send_retrying(
        &mut self,
        len: usize,
        give_up: impl Fn(usize) -> bool,
        mut fill: impl FnMut(&mut H, &mut [T]),
    ) -> Result<bool> {
        loop {
            match self.send_with(len, &mut fill) {
                Ok(()) => return Ok(true),
                Err(TransportError::Stalled { .. }) if !give_up(self.receivers()) => {}
                Err(TransportError::Stalled { .. }) => return Ok(false),
                Err(e) => return Err(e),
            }
        }
    }

    /// As [`Sender::send_with`], with a fill that may fail: when it does, the
    /// loan is given back unsent and its error returned inside `Ok`, so a
    /// half-written message is never published.
    pub fn try_send_with<E>(
        &mut self,
        len: usize,
        fill: impl FnOnce(&mut H, &mut [T]) -> std::result::Result<(), E>,
    ) -> Result<std::result::Result<(), E>> {
        let io =
            |op, e: Cause, ch: &str| TransportError::Io { channel: ch.to_string(), op, cause: e };
        let stalled = || TransportError::Stalled {
            channel: self.channel.clone(),
            timeout: self.stall_timeout,
        };
        if self.needs_receiver && !self.wait_for_receiver() {
            return Err(stalled());
        }
        let uninit = self
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| io("loan", e.into(), &self.channel))?;
        let mut sample = if S::LOANS_ARE_INITIALISED {
            // SAFETY: `S::LOANS_ARE_INITIALISED` (sealed: only `Ipc` says
            // so) means the payload's bytes are initialised memory, and
            // `T: Plain` has no invalid bit pattern, so reading it as `[T]`
            // before `fill` writes it is sound. Skipping iceoryx2's
            // default-fill saves a write of the whole payload per message
            // (code audit T1: 410 KB for a 50-agent observation batch).
            unsafe { uninit.assume_init() }
        } else {
            // The `local` service's segments come from the heap, which
            // promises no initialised bytes: fill first (serial mode and
            // tests only).
            uninit.write_from_fn(|_| T::default())
        };
        {
            let (hdr, payload) = (sample.user_header_mut() as *mut H, sample.payload_mut());
            // SAFETY: the header and the payload are disjoint parts of the one
            // loaned sample; both borrows end before the sample is sent.
            if let Err(e) = fill(unsafe { &mut *hdr }, payload) {
                return Ok(Err(e));
            }
        }
        let before = self.stalls.load(Ordering::Relaxed);
        match sample.send() {
            // The receiver went away between the wait and the send.
            Ok(0) if self.needs_receiver => return Err(stalled()),
            Ok(_) => {}
            Err(e) => {
                if self.stalls.load(Ordering::Relaxed) > before {
                    return Err(stalled());
                }
                return Err(io("send", e.into(), &self.channel));
            }
        }
        self.sent += 1;
        // A missing listener (the receiver is restarting) is not an error.
        let _ = self.notifier.notify();
        Ok(Ok(()))
    }

    /// Messages sent.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Waits up to the stall timeout for a receiver (a restarting receiver
    /// comes back); false when none came.
    fn wait_for_receiver(&self) -> bool {
        let start = std::time::Instant::now();
        while self.receivers() == 0 {
            if start.elapsed() >= self.stall_timeout {
                return false;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        true
    }

    /// Receivers connected to the channel now.
    pub fn receivers(&self) -> usize {
        use iceoryx2::service::port_factory::PortFactory as _;
        self.service.dynamic_config().number_of_subscribers()
    }
}

/// The receiving side of a channel.
pub struct Receiver<
    S: Service,
    T: Debug + ZeroCopySend + 'static,
    H: Debug + ZeroCopySend + 'static,
> {
    subscriber: Subscriber<S, [T], H>,
    listener: Listener<S>,
    channel: String,
    spin: Duration,
}

/// How long a receiver polls before it sleeps on the channel's event.
/// `ROTORHIVE_SPIN_US` sets it (read once per process; 0 turns polling off).
pub fn spin() -> Duration {
    static SPIN: std::sync::OnceLock<Duration> = std::sync::OnceLock::new();
    *SPIN.get_or_init(|| {
        let us = match std::env::var("ROTORHIVE_SPIN_US") {
            Ok(v) => v.trim().parse::<u64>().unwrap_or_else(|_| {
                tracing::warn!("ROTORHIVE_SPIN_US={v:?} is not a whole number of microseconds; using {DEFAULT_SPIN_US}");
                DEFAULT_SPIN_US
            }),
            Err(_) => DEFAULT_SPIN_US,
        };
        Duration::from_micros(us)
    })
}

/// The default polling window of a receiver, in microseconds.
pub const DEFAULT_SPIN_US: u64 = 100;

/// One sleep on a channel's event for `remaining` time: at most 20 ms (a
/// notification can race with the receive before it, so the receiver
/// re-checks), and at least 1 µs: iceoryx2 0.10 hands the timeout to
/// `SO_RCVTIMEO` in whole microseconds, where zero means "block forever"
/// (a sim once hung for minutes on a 0.4 µs remainder).
fn wait_slice(remaining: Duration) -> Duration {
    remaining.clamp(Duration::from_micros(1), Duration::from_millis(20))
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

/// A received message, read in place from shared memory.
pub type Msg<S, T, H> = Sample<S, [T], H>;

impl<
    S: Service,
    T: Debug + ZeroCopySend + Default + Copy + 'static,
    H: Debug + ZeroCopySend + Default + 'static,
> Receiver<S, T, H>
{
    /// The next message, if one is waiting.
    pub fn try_recv(&mut self) -> Result<Option<Msg<S, T, H>>> {
        self.subscriber.receive().map_err(|e| TransportError::Io {
            channel: self.channel.clone(),
            op: "receive",
            cause: e.into(),
        })
    }

    /// The next message, sleeping on the channel's event for at most
    /// `timeout`. It polls for its spin window (`spin()`) first: a message
    /// that arrives that soon is seen without a wake-up through the kernel
    /// (about 10 µs here). Between polls it yields, so a process with work
    /// to do (the learner, on a machine with few cores) gets the core.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<Msg<S, T, H>>> {
        let start = Instant::now();
        let deadline = start + timeout;
        let spin_until = start + self.spin.min(timeout);
        loop {
            if let Some(s) = self.try_recv()? {
                return Ok(Some(s));
            }
            if Instant::now() >= spin_until {
                break;
            }
            std::thread::yield_now();
        }
        loop {
            if let Some(s) = self.try_recv()? {
                return Ok(Some(s));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            match self.listener.timed_wait(|_| {}, wait_slice(deadline - now)) {
                Ok(_) => {}
                // A signal (SIGTERM from the supervisor, Ctrl-C) ends the wait
                // early; the caller checks for shutdown next.
                Err(iceoryx2::port::listener::ListenerWaitError::InterruptSignal) => {
                    return self.try_recv();
                }
                Err(e) => {
                    return Err(TransportError::Io {
                        channel: self.channel.clone(),
                        op: "wait",
                        cause: e.into(),
                    });
                }
            }
        }
    }

    /// Sets how long this receiver polls before sleeping (a channel whose
    /// latency does not matter need not spend a core on it).
    pub fn set_spin(&mut self, spin: Duration) {
        self.spin = spin;
    }

    /// The newest waiting message, dropping older ones (for latest-wins channels).
    pub fn latest(&mut self) -> Result<Option<Msg<S, T, H>>> {
        let mut last = None;
        while let Some(s) = self.try_recv()? {
            last = Some(s);
        }
        Ok(last)
    }
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

static STOP: AtomicBool = AtomicBool::new(false);

/// Asks every loop of this process to stop (as SIGTERM would).
pub fn request_stop() {
    STOP.store(true, Ordering::SeqCst);
}

/// True once [`request_stop`] was called or a handled signal arrived
/// (SIGHUP after [`handle_hangup`]; SIGINT and SIGTERM are seen through a
/// hub's [`Hub::shutdown_requested`]).
pub fn stop_requested() -> bool {
    STOP.load(Ordering::SeqCst)
}

extern "C" fn on_hangup(_: libc::c_int) {
    // Only an atomic store: async-signal-safe.
    STOP.store(true, Ordering::SeqCst);
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

/// Makes SIGHUP (a closed terminal, a dropped SSH session) a request to stop
/// cleanly, like SIGINT and SIGTERM, instead of killing the process with its
/// shared memory left behind.
pub fn handle_hangup() {
    // SAFETY: installs a handler that only stores to an atomic; the
    // sigaction struct is fully initialised (zeroed, then the handler set).
    unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = on_hangup as *const () as libc::sighandler_t;
        libc::sigemptyset(&mut sa.sa_mask);
        libc::sigaction(libc::SIGHUP, &sa, std::ptr::null_mut());
    }
}

/// Makes a child process about to be started by `cmd` receive `signal` when
/// this process's spawning thread ends, however it ends (SIGKILL, the OOM
/// killer): `PR_SET_PDEATHSIG`, set in the child before it runs, and the
/// signal sent at once if this process died before that took effect. The
/// supervisor ties its roles to itself (SIGTERM); `hive bench seeds` and
/// `bench table` tie their runs (SIGINT, which ends a run as Ctrl-C does).
pub fn dies_with_this_process(cmd: &mut std::process::Command, signal: rustix::process::Signal) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id();
    // SAFETY: a pre_exec hook runs in the forked child before exec and may
    // only make async-signal-safe calls: these are plain system calls
    // through rustix (prctl(2), getppid(2), getpid(2), kill(2)), which
    // allocate nothing and take no lock.
    unsafe {
        cmd.pre_exec(move || {
            use rustix::process::{getpid, getppid, kill_process};
            rustix::process::set_parent_process_death_signal(Some(signal))?;
            // The parent may have died before the prctl took effect.
            if getppid().map(|p| p.as_raw_pid() as u32) != Some(parent) {
                kill_process(getpid(), signal)?;
            }
            Ok(())
        });
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Default, Clone, Copy, ZeroCopySend)]
    #[type_name("rotorhive::test::Hdr")]
    #[repr(C)]
    struct Hdr {
        seq: u64,
    }

    #[test]
    fn a_wait_is_never_zero_whole_microseconds() {
        // iceoryx2 truncates to microseconds and blocks forever on zero.
        for ns in [0, 1, 400, 999, 1_000, 25_000_000] {
            let w = wait_slice(Duration::from_nanos(ns));
            assert!(w.as_micros() >= 1 && w <= Duration::from_millis(20), "{ns} ns -> {w:?}");
        }
    }

    #[test]
    fn a_fill_that_fails_publishes_nothing() {
        let hub = Hub::<Local>::new("unit-fail", "unit").unwrap();
        let ch = Channel::weights(1);
        let mut tx = hub.sender::<f32, Hdr>(&ch, 8, Duration::from_millis(200)).unwrap();
        let mut rx = hub.receiver::<f32, Hdr>(&ch).unwrap();
        let failed = tx
            .try_send_with(8, |h, p| {
                h.seq = 1;
                p[0] = 1.0;
                Err("cannot write the weights")
            })
            .unwrap();
        assert_eq!(failed, Err("cannot write the weights"));
        assert_eq!(tx.sent(), 0);
        assert!(rx.try_recv().unwrap().is_none(), "a failed fill was published");
        tx.try_send_with(8, |h, p| {
            h.seq = 2;
            p.fill(2.0);
            Ok::<(), &str>(())
        })
        .unwrap()
        .unwrap();
        let m = rx.try_recv().unwrap().expect("the second message");
        assert_eq!((m.user_header().seq, m.payload()), (2, &[2.0f32; 8][..]));
    }

    #[test]
    fn a_transition_sent_to_nobody_is_a_stall_and_one_sent_to_a_receiver_arrives() {
        let hub = Hub::<Local>::new("unit-nobody", "unit").unwrap();
        let ch = Channel::transitions(1);
        let mut tx = hub.sender::<f32, Hdr>(&ch, 4, Duration::from_millis(50)).unwrap();
        let t = std::time::Instant::now();
        let r = tx.send_with(4, |h, p| {
            h.seq = 1;
            p.fill(1.0);
        });
        assert!(matches!(r, Err(TransportError::Stalled { .. })), "{r:?}");
        assert!(t.elapsed() >= Duration::from_millis(50), "it waited for a receiver first");
        assert_eq!(tx.sent(), 0);
        let mut rx = hub.receiver::<f32, Hdr>(&ch).unwrap();
        tx.send_with(4, |h, p| {
            h.seq = 2;
            p.fill(2.0);
        })
        .unwrap();
        let m = rx.try_recv().unwrap().expect("the sample arrived");
        assert_eq!(m.user_header().seq, 2);
        // Other channels keep sending to nobody as before (telemetry, weights).
        let w = Channel::weights(1);
        let mut wtx = hub.sender::<f32, Hdr>(&w, 4, Duration::from_millis(50)).unwrap();
        wtx.send_with(4, |_, p| p.fill(0.0)).unwrap();
    }

    #[test]
    fn local_channel_delivers_in_order_with_headers() {
        let hub = Hub::<Local>::new("unit", "unit").unwrap();
        let ch = Channel::obs(0, 1);
        let mut tx = hub.sender::<f32, Hdr>(&ch, 16, Duration::from_millis(200)).unwrap();
        let mut rx = hub.receiver::<f32, Hdr>(&ch).unwrap();
        for i in 0..2u64 {
            tx.send_with(16, |h, p| {
                h.seq = i;
                for (k, v) in p.iter_mut().enumerate() {
                    *v = (i * 100 + k as u64) as f32;
                }
            })
            .unwrap();
        }
        // The buffer holds two: a third send meets back-pressure and stalls.
        let e = tx.send_with(16, |_, _| {}).unwrap_err();
        assert!(matches!(e, TransportError::Stalled { .. }), "{e}");
        for i in 0..2u64 {
            let m = rx.recv_timeout(Duration::from_millis(100)).unwrap().unwrap();
            assert_eq!(m.user_header().seq, i);
            assert_eq!(m.payload()[3], (i * 100 + 3) as f32);
        }
        assert!(rx.recv_timeout(Duration::from_millis(10)).unwrap().is_none());
    }
}
