//! What a channel is: its name and quality of service ([`Channel`]),
//! its sending and receiving sides, and how a receiver waits.

use std::fmt::Debug;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;

use crate::{Cause, Plain, Result, Service, TransportError};

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

/// The sending side of a channel.
pub struct Sender<S: Service, T: Debug + ZeroCopySend + 'static, H: Debug + ZeroCopySend + 'static>
{
    pub(crate) publisher: Publisher<S, [T], H>,
    pub(crate) notifier: Notifier<S>,
    pub(crate) service: iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, [T], H>,
    pub(crate) channel: String,
    pub(crate) stalls: Arc<AtomicU64>,
    pub(crate) stall_timeout: Duration,
    pub(crate) sent: u64,
    pub(crate) needs_receiver: bool,
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
    pub(crate) subscriber: Subscriber<S, [T], H>,
    pub(crate) listener: Listener<S>,
    pub(crate) channel: String,
    pub(crate) spin: Duration,
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
pub(crate) fn wait_slice(remaining: Duration) -> Duration {
    remaining.clamp(Duration::from_micros(1), Duration::from_millis(20))
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
