//! The head's bridge between Zenoh and its shared memory ([`HeadLink`], a
//! thread): weights out to every worker, transitions, episodes and
//! telemetry in, each message checked ([`crate::check`]) before any byte of
//! it reaches shared memory, and the hosts that join again.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use rotorhive_msg::{
    EPISODE_FIELDS, EpisodeHeader, LinkStage, Receipt, RoleKind, RowLayout, SeqTracker, Telemetry,
    TransitionHeader, WeightsHeader,
};
use rotorhive_transport::Service;
use rotorhive_transport::{Channel, Hub};
use zenoh::Wait;
use zenoh::qos::CongestionControl;

use crate::error::{LinkError, Result, zerr};
use crate::head::admit::accept;
use crate::head::admit::{ConfigFor, Head, HeadStats, refuse, reply};
use crate::head::flows::Flows;
use crate::head::host::{Host, same_token};
use crate::head::inflow::Admit;
use crate::reject::{Reason, Reject};
use crate::shared::{LinkTelemetry, key, link_telemetry, missing_before};
use crate::wire::Welcome;
use crate::{check, wire};

impl Head {
    /// Starts bridging for the roles of run `prefix` over iceoryx2 service
    /// `S` on this host: a thread that ends (sending the run's end to the
    /// workers) when `stop` is set. `envs` and `roles` size the channels as
    /// the head's roles do; `config_for` gives a returning worker its config.
    pub fn bridge<S: Service>(
        self,
        prefix: String,
        envs: usize,
        roles: usize,
        stop: Arc<AtomicBool>,
        config_for: ConfigFor,
    ) -> Result<HeadLink> {
        let stats = Arc::new(HeadStats::default());
        if self.refused_joins > 0 {
            stats.count(0, Reason::JoinRefused, self.refused_joins);
        }
        let (st, sp) = (stats.clone(), stop.clone());
        let hosts = self.hosts.clone();
        let thread = std::thread::Builder::new()
            .name("link".into())
            .spawn(move || {
                let hub = Hub::<S>::new(&prefix, "link")?.with_stop(sp.clone());
                head_loop(&self, &hub, envs, roles, &sp, &st, config_for)
            })
            .map_err(|_| LinkError::Thread("could not start"))?;
        Ok(HeadLink { thread: Some(thread), stop, stats, hosts })
    }
}

/// The running head link.
pub struct HeadLink {
    thread: Option<std::thread::JoinHandle<Result<()>>>,
    pub(crate) stop: Arc<AtomicBool>,
    /// Its counters.
    pub stats: Arc<HeadStats>,
    /// The workers that joined at the start.
    pub hosts: Vec<Host>,
}

impl HeadLink {
    /// Whether the thread ended (with an error: it runs until stopped).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Ends the run on the workers and stops the thread; returns its error.
    pub fn stop(&mut self) -> Result<()> {
        self.stop.store(true, Ordering::SeqCst);
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(LinkError::Thread("panicked")),
            None => Ok(()),
        }
    }
}

impl Drop for HeadLink {
    fn drop(&mut self) {
        let _ = self.stop();
    }
}

pub(crate) fn head_loop<S: Service>(
    head: &Head,
    hub: &Hub<S>,
    envs: usize,
    roles: usize,
    stop: &AtomicBool,
    stats: &HeadStats,
    config_for: ConfigFor,
) -> Result<()> {
    let s = &head.session;
    let decl = |what: &str| zerr(format!("declare {what}"));
    let publisher = |what: &str, cc| {
        s.declare_publisher(key(&head.run, what)).congestion_control(cc).wait().map_err(decl(what))
    };
    let end_pub = publisher("end", CongestionControl::Block)?;
    let total_envs = envs + head.hosts.iter().map(|h| h.envs as usize).sum::<usize>();
    // A batch holds at most MAX_BATCH transitions, or a sequence of each of
    // a worker's agents (the check refuses more).
    let most_rows = match head.rows {
        RowLayout::Transition(_) => check::MAX_BATCH,
        RowLayout::Sequence(_) => head.hosts.iter().map(|h| h.agents as usize).max().unwrap_or(1),
    };
    let max_batch = head.rows.packed_len() * most_rows.clamp(1, check::MAX_BATCH);
    if let Ok(mut l) = stats.lost_by_env.lock() {
        *l = vec![0; total_envs];
    }
    let mut b = HeadBridge {
        head,
        stats,
        stop,
        // Weights may drop where a worker's link is full or gone (the next
        // version follows): a slow or unreachable worker never holds the
        // head's link, and with it every other worker's transitions.
        w_pub: publisher("weights", CongestionControl::Drop)?,
        trans_tx: hub.sender(&Channel::transitions(envs), max_batch, Duration::from_millis(200))?,
        ep_tx: hub.sender(
            &Channel::episodes(envs),
            EPISODE_FIELDS * 4096,
            Duration::from_millis(200),
        )?,
        w_rx: hub.receiver(&Channel::weights(envs))?,
        receipts: hub.receiver(&Channel::receipts())?,
        receipts_read: Instant::now(),
        tel: link_telemetry(hub, roles, 0)?,
        next_seq: SeqTracker::new(total_envs),
        version: 0,
        flows: Flows::open(s, &head.run, &head.hosts)?,
        deadline: None,
    };
    while !stop.load(Ordering::SeqCst) && !hub.shutdown_requested() {
        b.weights_out()?;
        b.round()?;
        b.rejoins(&config_for);
        b.tel.tick(false, Telemetry::beat);
    }
    // The run's end, so the workers exit 0 instead of reporting a lost head;
    // then what they sent is taken (the replay runs until the link stops)
    // until each has sent its last count.
    let _ = end_pub.put(b"end".to_vec()).wait();
    let deadline = Instant::now() + DRAIN;
    b.deadline = Some(deadline);
    while Instant::now() < deadline
        && !rotorhive_transport::stop_requested()
        && !b.flows.all_ended()
    {
        b.round()?;
    }
    b.flows.settle(stats);
    Ok(())
}

/// The head reads the replay's receipts at most this often (acknowledging
/// goes at most every [`crate::delivery::ACK_EVERY`]).
const RECEIPTS_EVERY: Duration = Duration::from_millis(1);

/// How long the head takes the workers' batches after the run's end: longer
/// than they wait for their acknowledgements ([`crate::worker::bridge`]).
const DRAIN: Duration = Duration::from_secs(7);

/// The head's link at work: what it sends and receives on the head's
/// shared memory, and what it keeps between rounds.
struct HeadBridge<'a, S: Service> {
    head: &'a Head,
    stats: &'a HeadStats,
    pub(crate) stop: &'a AtomicBool,
    w_pub: zenoh::pubsub::Publisher<'static>,
    trans_tx: rotorhive_transport::Sender<S, u16, TransitionHeader>,
    ep_tx: rotorhive_transport::Sender<S, f32, EpisodeHeader>,
    w_rx: rotorhive_transport::Receiver<S, f32, WeightsHeader>,
    receipts: rotorhive_transport::Receiver<S, u8, Receipt>,
    receipts_read: Instant,
    pub(crate) tel: LinkTelemetry<S>,
    /// The batches seen from each actor of the run.
    next_seq: SeqTracker,
    /// The newest weight version sent.
    pub(crate) version: u64,
    /// Each worker slot's stream.
    flows: Flows,
    /// Past the run's end: when the head stops waiting for the replay.
    deadline: Option<Instant>,
}

impl<S: Service> HeadBridge<'_, S> {
    /// One round: a transition batch in (loss-free: the FIFO is bounded
    /// and the send waits), episodes and telemetry, the answers due.
    fn round(&mut self) -> Result<()> {
        let t = Instant::now();
        let got = self.head.subs.transitions.recv_timeout(Duration::from_millis(5)).ok().flatten();
        self.tel.sample.time_stage(LinkStage::Receive, t);
        if let Some(smp) = got {
            self.transitions_in(&smp)?;
        }
        self.episodes_and_telemetry_in();
        if self.receipts_read.elapsed() >= RECEIPTS_EVERY {
            self.receipts_read = Instant::now();
            if let Some(r) = self.receipts.latest()? {
                self.flows.confirm(*r.user_header(), self.stats);
            }
        }
        self.flows.answer(Instant::now());
        Ok(())
    }

    /// Weights out: the newest version, once per host (zenoh fans out).
    fn weights_out(&mut self) -> Result<()> {
        let t = Instant::now();
        if let Some(w) = self.w_rx.latest()? {
            let h = *w.user_header();
            if h.version != self.version {
                self.version = h.version;
                let bytes = wire::payload_bytes(w.payload()).to_vec();
                self.w_pub
                    .put(bytes)
                    .attachment(wire::header_bytes(&h).to_vec())
                    .wait()
                    .map_err(zerr("send weights"))?;
                self.tel.sample.weight_version = self.version;
            }
        }
        self.tel.sample.time_stage(LinkStage::Weights, t);
        Ok(())
    }

    /// One transition batch from a worker: checked, taken only in its
    /// stream's order (a duplicate or a batch past a gap is dropped), its
    /// actor's sequence gap counted, then into the replay's channel (the
    /// send retried while the replay is full or restarting).
    fn transitions_in(&mut self, smp: &zenoh::sample::Sample) -> Result<()> {
        let (stats, hosts, run) = (self.stats, &self.head.hosts, &self.head.run);
        let rows = self.head.rows;
        let t = Instant::now();
        let payload = smp.payload();
        let frags: Vec<&[u8]> = payload.slices().collect();
        let Some((slot, h, link)) = accept(stats, hosts, smp, run, "transitions", |host, att| {
            check::transitions(host, rows, att, &frags).map(|(h, l)| (host.slot, h, l))
        }) else {
            return Ok(());
        };
        let n = h.count as u64;
        let admit = self.flows.admit(slot, link);
        match admit {
            Admit::Take => {}
            Admit::Duplicate => stats.flow(slot, |f| f.duplicates += n),
            Admit::Gap => stats.flow(slot, |f| f.out_of_order += n),
            Admit::Stale => stats.reject(slot, "transitions", &Reject::Epoch(link.epoch)),
        }
        if admit != Admit::Take {
            return Ok(());
        }
        let words = payload.len() / 2;
        let gap = missing_before(&mut self.next_seq, &h, "head link", "");
        if gap > 0 {
            let lost = gap.saturating_mul(n);
            stats.lost_batches.fetch_add(gap, Ordering::Relaxed);
            stats.lost_transitions.fetch_add(lost, Ordering::Relaxed);
            self.tel.sample.lost = self.tel.sample.lost.saturating_add(lost);
            if let Some(l) =
                stats.lost_by_env.lock().ok().as_mut().and_then(|v| v.get_mut(h.actor as usize))
            {
                *l = l.saturating_add(lost);
            }
        }
        let (stop, deadline) = (self.stop, self.deadline);
        let give_up = |_| {
            rotorhive_transport::stop_requested()
                || deadline.map_or(stop.load(Ordering::SeqCst), |d| Instant::now() > d)
        };
        let sent = self.trans_tx.send_retrying(words, give_up, |hdr, p| {
            *hdr = h;
            // Zenoh's fragments straight into the loaned sample (their
            // total is the sample's length: checked above).
            let out = wire::payload_bytes_mut(p);
            let mut at = 0;
            for frag in &frags {
                out[at..at + frag.len()].copy_from_slice(frag);
                at += frag.len();
            }
        })?;
        if sent {
            self.flows.taken(slot, &h, link);
            stats.batches.fetch_add(1, Ordering::Relaxed);
            stats.transitions.fetch_add(h.count as u64, Ordering::Relaxed);
            self.tel.sample.work += h.count as u64;
            self.tel.sample.work2 += payload.len() as u64;
        }
        self.tel.sample.time_stage(LinkStage::SendWait, t);
        Ok(())
    }

    /// The workers' episodes and telemetry, checked, into the head's
    /// records (episodes that find the channel full are counted dropped).
    fn episodes_and_telemetry_in(&mut self) {
        let (stats, hosts, run) = (self.stats, &self.head.hosts, &self.head.run);
        let t = Instant::now();
        while let Ok(Some(smp)) = self.head.subs.episodes.try_recv() {
            let bytes = smp.payload().to_bytes();
            let Some(h) = accept(stats, hosts, &smp, run, "episodes", |host, att| {
                check::episodes(host, att, &bytes)
            }) else {
                continue;
            };
            if self
                .ep_tx
                .send_with(bytes.len() / 4, |hdr, p| {
                    *hdr = h;
                    wire::payload_bytes_mut(p).copy_from_slice(&bytes);
                })
                .is_err()
            {
                stats.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
        while let Ok(Some(smp)) = self.head.subs.telemetry.try_recv() {
            if let Some(t) = accept(stats, hosts, &smp, run, "telemetry", |host, att| {
                check::telemetry(host, att, smp.payload().len())
            }) {
                if t.role == RoleKind::Link as u32 {
                    self.flows.report(t.index, t.delivery, stats);
                }
                self.tel.send(t);
            }
        }
        self.tel.sample.time_stage(LinkStage::Forward, t);
    }

    /// A worker that comes back (restarted) with its join token gets its
    /// old place; anyone else is refused.
    fn rejoins(&mut self, config_for: &ConfigFor) {
        let (head, run) = (self.head, &self.head.run);
        while let Ok(Some(q)) = head.queryable.try_recv() {
            match head.check(&q) {
                Ok((h, slot)) => match head.hosts.iter().find(|x| x.name == h.host) {
                    Some(x) if slot.is_some_and(|s| s != x.slot) => {
                        self.refuse_join(&q, &format!("host {} holds slot {}", x.name, x.slot))
                    }
                    Some(x) if !same_token(&x.token, &h.token) => self.refuse_join(
                        &q,
                        &format!(
                            "host {} is in this run; only the worker that joined under that name (with its join token) may take its place back",
                            x.name
                        ),
                    ),
                    Some(x) if x.envs == h.envs && x.agents == h.agents => {
                        let (config, arena) = config_for(x);
                        let epoch = crate::delivery::new_epoch();
                        self.flows.rejoin(x.slot, epoch, h.earlier, self.stats);
                        reply(
                            &q,
                            &Welcome::Joined {
                                slot: x.slot,
                                env_offset: x.env_offset,
                                epoch,
                                run: run.clone(),
                                config,
                                arena,
                            },
                        );
                        // Its actors start their sequences afresh.
                        for e in x.env_offset as usize..(x.env_offset + x.envs) as usize {
                            self.next_seq.reset(e);
                        }
                        tracing::info!("worker {} joined again", x.name);
                    }
                    Some(x) => self.refuse_join(
                        &q,
                        &format!(
                            "host {} joined with {} × {} agents, and comes back with {} × {}",
                            x.name, x.envs, x.agents, h.envs, h.agents
                        ),
                    ),
                    None => self.refuse_join(&q, "the run has all its worker hosts (`cluster.workers`)"),
                },
                Err(why) => self.refuse_join(&q, &why),
            }
        }
    }

    /// Refuses a join request, and counts it (`join_refused`, on no host).
    fn refuse_join(&self, q: &zenoh::query::Query, why: &str) {
        self.stats.count(0, Reason::JoinRefused, 1);
        refuse(q, why);
    }
}
