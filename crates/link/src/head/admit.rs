//! The head's end of the link: the join queryable, the hosts it admitted
//! and its counts of refused messages.

use std::sync::atomic::AtomicU64;
use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::handlers::{FifoChannel, FifoChannelHandler, RingChannel};
use zenoh::query::Query;

use crate::error::{LinkError, Result, zerr};
use crate::head::host::{Host, JoinLimits, place, same_token};
use crate::options::{LinkOptions, open};
use crate::reject::Reason;
use crate::shared::{Fifo, JOIN, key};
use crate::wire::{Hello, Welcome};
use crate::{check, wire};
use rotorhive_msg::{RowLayout, Shapes};

/// Counters of the head's link, shared with the supervisor.
#[derive(Debug, Default)]
pub struct HeadStats {
    /// Transition batches brought in.
    pub batches: AtomicU64,
    /// Transitions brought in.
    pub transitions: AtomicU64,
    /// Transition batches lost between hosts (per-actor sequence gaps).
    pub lost_batches: AtomicU64,
    /// Transitions in the lost batches, estimated at the batch size seen.
    pub lost_transitions: AtomicU64,
    /// The same, per environment of the run (index = actor).
    pub lost_by_env: std::sync::Mutex<Vec<u64>>,
    /// Episode or telemetry messages that could not be delivered.
    pub dropped: AtomicU64,
    /// Messages that failed a check ([`check`]) and were dropped, and join
    /// requests refused, per slot (0: keys that name no host of the run,
    /// and joins) and reason (in [`Reason::ALL`]'s order).
    pub rejected: std::sync::Mutex<Vec<[u64; Reason::ALL.len()]>>,
    /// Delivery per slot ([`crate::delivery`]).
    pub flows: std::sync::Mutex<Vec<Flow>>,
}

/// A worker's delivery to the head over the run, in transitions (across
/// its joins).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Flow {
    /// Sent a first time (the worker's own count, as its link reports it).
    pub sent: u64,
    /// Taken by the head's replay and acknowledged.
    pub acknowledged: u64,
    /// Sent again (the worker's count).
    pub resent: u64,
    /// Arrived again after they were taken: dropped.
    pub duplicates: u64,
    /// Arrived past a missing batch: dropped, and asked for again.
    pub out_of_order: u64,
    /// Sent and never taken: a worker's window when one of its processes
    /// ended (a killed one: as its last report said), or when the run did.
    pub lost: u64,
}

impl HeadStats {
    /// Counts a dropped message from `slot`; logs the first few of each
    /// host and then every thousandth.
    pub(crate) fn reject(&self, slot: u32, what: &str, why: &check::Reject) {
        let n = self.count(slot, why.reason(), 1);
        if n <= 5 || n.is_multiple_of(1000) {
            let from =
                if slot == 0 { "an unknown sender".to_string() } else { format!("worker {slot}") };
            tracing::warn!("dropped {what} from {from}: {why} ({n} dropped from it so far)");
        }
    }

    /// Counts `n` refusals of `slot` for `reason`; the slot's total since.
    pub(crate) fn count(&self, slot: u32, reason: Reason, n: u64) -> u64 {
        let Ok(mut r) = self.rejected.lock() else {
            return 0;
        };
        if r.len() <= slot as usize {
            r.resize(slot as usize + 1, [0; Reason::ALL.len()]);
        }
        let row = &mut r[slot as usize];
        row[reason as usize] += n;
        row.iter().sum()
    }

    /// The delivery counts of `slot`.
    pub fn flow_of(&self, slot: u32) -> Flow {
        self.flows.lock().ok().and_then(|f| f.get(slot as usize).copied()).unwrap_or_default()
    }

    /// Messages (and joins) refused from `slot`.
    pub fn rejected_from(&self, slot: u32) -> u64 {
        self.rejected_by_reason(slot).iter().map(|(_, n)| n).sum()
    }

    /// Refusals of `slot` by reason, the reasons that counted any.
    pub fn rejected_by_reason(&self, slot: u32) -> Vec<(Reason, u64)> {
        let row = self.rejected.lock().ok().and_then(|r| r.get(slot as usize).copied());
        let row = row.unwrap_or_default();
        Reason::ALL.iter().copied().zip(row).filter(|(_, n)| *n > 0).collect()
    }
}

/// The head's end of the link: listens, admits workers, then bridges.
pub struct Head {
    pub(crate) session: zenoh::Session,
    pub(crate) run: String,
    layout: u64,
    pub(crate) queryable: zenoh::query::Queryable<FifoChannelHandler<Query>>,
    _token: zenoh::liveliness::LivelinessToken,
    pub(crate) hosts: Vec<Host>,
    pending: Vec<Pending>,
    /// Workers the run waits for.
    wanted: usize,
    limits: JoinLimits,
    /// Joins refused while gathering (counted into the link's stats).
    pub(crate) refused_joins: u64,
    pub(crate) subs: HeadSubscribers,
    /// The run's replay rows, transitions or sequences (a worker's batches
    /// are checked against them).
    pub(crate) rows: RowLayout,
}

/// A join waiting for its answer: the request, what it says, and the
/// slot it asked for (then the one it got).
struct Pending {
    query: Query,
    hello: Hello,
    slot: Option<u32>,
}

/// The head's subscribers, declared before any worker is admitted, so that
/// a worker's first batch already has somewhere to go.
pub(crate) struct HeadSubscribers {
    pub(crate) transitions: Fifo,
    pub(crate) episodes: Fifo,
    pub(crate) telemetry:
        zenoh::pubsub::Subscriber<zenoh::handlers::RingChannelHandler<zenoh::sample::Sample>>,
}

impl Head {
    /// Listens on `endpoint` for the workers of run `run`.
    pub fn listen(endpoint: &str, run: &str, layout: u64, opts: &LinkOptions) -> Result<Self> {
        let session = open(Some(endpoint), None, opts)?;
        let queryable = session
            .declare_queryable(format!("{JOIN}/**"))
            .with(FifoChannel::new(64))
            .wait()
            .map_err(zerr("declare the join queryable"))?;
        let token = session
            .liveliness()
            .declare_token(key(run, "head"))
            .wait()
            .map_err(zerr("declare the head's liveliness"))?;
        let decl = |what: &str| zerr(format!("declare {what}"));
        let subs = HeadSubscribers {
            transitions: session
                .declare_subscriber(key(run, "host/*/transitions"))
                .with(FifoChannel::new(4))
                .wait()
                .map_err(decl("the transitions subscriber"))?,
            episodes: session
                .declare_subscriber(key(run, "host/*/episodes"))
                .with(FifoChannel::new(256))
                .wait()
                .map_err(decl("the episodes subscriber"))?,
            telemetry: session
                .declare_subscriber(key(run, "host/*/telemetry"))
                .with(RingChannel::new(256))
                .wait()
                .map_err(decl("the telemetry subscriber"))?,
        };
        Ok(Self {
            subs,
            session,
            run: run.to_string(),
            layout,
            queryable,
            _token: token,
            hosts: Vec::new(),
            pending: Vec::new(),
            wanted: 0,
            limits: JoinLimits { default_agents: 1, n_step: 1 },
            refused_joins: 0,
            rows: RowLayout::Transition(Shapes::PAPER),
        })
    }

    /// Sets the run's replay rows (the paper's transitions until then;
    /// with memory sequences): workers' batches are checked against them.
    pub fn with_rows(mut self, rows: RowLayout) -> Self {
        self.rows = rows;
        self
    }

    /// Waits for `wanted` workers (at most `timeout`) and places their
    /// environments after the head's `head_envs`, in the order of their
    /// slots: the slot a worker's certificate holds where it asks for one
    /// (`rotorhive/join/SLOT`; the access control admits only that one),
    /// else the first free, in order of joining. They wait for their answer
    /// until [`Head::admit`].
    /// A worker that asks for 0 agents per environment gets `default_agents`.
    pub fn gather(
        &mut self,
        wanted: usize,
        head_envs: usize,
        limits: JoinLimits,
        timeout: Duration,
        stop: impl Fn() -> bool,
    ) -> Result<Vec<Host>> {
        (self.limits, self.wanted) = (limits, wanted);
        let start = Instant::now();
        while self.pending.len() < wanted {
            if stop() {
                return Err(LinkError::Stopped("worker hosts"));
            }
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(LinkError::TooFewWorkers {
                    joined: self.pending.len(),
                    wanted,
                    secs: timeout.as_secs_f64(),
                });
            }
            if let Ok(Some(q)) = self.queryable.recv_timeout(left.min(Duration::from_millis(100))) {
                self.take_join(q);
            }
        }
        self.assign_slots();
        let envs = self.pending.iter().map(|p| p.hello.envs);
        let Some(offsets) = u32::try_from(head_envs).ok().and_then(|h| place(h, envs)) else {
            return Err(LinkError::Refused {
                endpoint: "this head".into(),
                why: "the workers' environments pass u32::MAX".into(),
            });
        };
        self.hosts.clear();
        for (p, env_offset) in self.pending.iter().zip(offsets) {
            let h = &p.hello;
            self.hosts.push(Host {
                name: h.host.clone(),
                slot: p.slot.unwrap_or(0),
                envs: h.envs,
                agents: h.agents,
                env_offset,
                epoch: crate::delivery::new_epoch(),
                token: h.token.clone(),
            });
        }
        Ok(self.hosts.clone())
    }

    /// A join request while gathering: kept (the newest of one host), or
    /// refused with why.
    fn take_join(&mut self, q: Query) {
        let (hello, slot) = match self.check(&q) {
            Ok(h) => h,
            Err(why) => {
                self.refused_joins += 1;
                return refuse(&q, &why);
            }
        };
        let same_host = self.pending.iter().position(|p| p.hello.host == hello.host);
        let taken = self
            .pending
            .iter()
            .any(|p| p.hello.host != hello.host && slot.is_some() && p.slot == slot);
        let why = match same_host {
            Some(i) if !same_token(&self.pending[i].hello.token, &hello.token) => {
                format!("host {} has already joined this run (another join token)", hello.host)
            }
            _ if taken => format!("slot {} has joined this run already", slot.unwrap_or(0)),
            Some(i) => {
                // The same host asking again (it retried): keep the newest.
                self.pending[i] = Pending { query: q, hello, slot };
                return;
            }
            None => {
                tracing::info!(
                    "worker {} joined: {} × {} agents",
                    hello.host,
                    hello.envs,
                    hello.agents
                );
                self.pending.push(Pending { query: q, hello, slot });
                return;
            }
        };
        self.refused_joins += 1;
        refuse(&q, &why);
    }

    /// Gives each gathered worker its slot (the one it asked for, else the
    /// first free, in order of joining) and puts them in slot order.
    fn assign_slots(&mut self) {
        let taken: Vec<u32> = self.pending.iter().filter_map(|p| p.slot).collect();
        let mut free = (1..=self.wanted as u32).filter(|s| !taken.contains(s));
        for p in &mut self.pending {
            if p.slot.is_none() {
                p.slot = free.next();
            }
        }
        self.pending.sort_by_key(|p| p.slot);
    }

    /// Answers the gathered workers: each gets its place, the config
    /// `welcome` gives it and the arena.
    pub fn admit(&mut self, welcome: impl Fn(&Host) -> (String, String)) {
        for (Pending { query: q, .. }, host) in self.pending.drain(..).zip(&self.hosts) {
            let (config, arena) = welcome(host);
            reply(
                &q,
                &Welcome::Joined {
                    slot: host.slot,
                    env_offset: host.env_offset,
                    epoch: host.epoch,
                    run: self.run.clone(),
                    config,
                    arena,
                },
            );
        }
    }

    /// A join request's hello, checked, and the slot it asks for (its key's
    /// last part, `rotorhive/join/SLOT`; none on `rotorhive/join`).
    pub(crate) fn check(&self, q: &Query) -> std::result::Result<(Hello, Option<u32>), String> {
        let slot = match q.key_expr().as_str().strip_prefix(JOIN).unwrap_or("") {
            "" => None,
            rest => match rest.strip_prefix('/').and_then(|n| n.parse::<u32>().ok()) {
                Some(n) if (1..=self.wanted.max(self.hosts.len()) as u32).contains(&n) => Some(n),
                _ => return Err(format!("{}: not a slot of this run", q.key_expr())),
            },
        };
        let bytes = q.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
        let mut h = Hello::decode(&bytes).ok_or("not a rotorhive worker's join request")?;
        if h.layout != self.layout {
            return Err("message layout mismatch: this worker runs another build of hive (or \
                        another model); run the same build on every host"
                .into());
        }
        self.limits.check(&mut h)?;
        if h.token.is_empty() || h.token.len() > wire::MAX_TOKEN {
            return Err(format!(
                "a join token of 1 to {} bytes is needed, got {}",
                wire::MAX_TOKEN,
                h.token.len()
            ));
        }
        Ok((h, slot))
    }
}

/// Gives a worker that joins again its config and arena.
pub type ConfigFor = Box<dyn Fn(&Host) -> (String, String) + Send>;

pub(crate) fn reply(q: &Query, w: &Welcome) {
    if let Err(e) = q.reply(q.key_expr().clone(), w.encode()).wait() {
        tracing::warn!("cannot answer a worker: {e}");
    }
}

pub(crate) fn refuse(q: &Query, why: &str) {
    tracing::warn!("refused a worker: {why}");
    reply(q, &Welcome::Refused(why.to_string()));
}

/// A message `what` from another host, checked by `check` against the
/// joined host its key names, with its attachment; one that fails (or
/// whose key names no host: slot 0) is counted against its sender and `None`.
pub(crate) fn accept<T>(
    stats: &HeadStats,
    hosts: &[Host],
    smp: &zenoh::sample::Sample,
    run: &str,
    what: &str,
    check: impl FnOnce(&Host, Option<&[u8]>) -> std::result::Result<T, check::Reject>,
) -> Option<T> {
    let Some(host) = crate::head::host::slot_of(smp.key_expr().as_str(), run, what)
        .and_then(|slot| hosts.iter().find(|h| h.slot == slot))
    else {
        stats.reject(0, what, &check::Reject::UnknownSender);
        return None;
    };
    let att = smp.attachment().map(|a| a.to_bytes());
    check(host, att.as_deref()).map_err(|why| stats.reject(host.slot, what, &why)).ok()
}
