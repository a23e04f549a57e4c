//! The worker's bridge between its shared memory and Zenoh: weights in,
//! transitions, episodes and telemetry out, and the head's liveliness.

use std::time::{Duration, Instant};

use rotorhive_msg::{
    EpisodeHeader, LinkStage, RoleKind, SeqTracker, Telemetry, TransitionHeader, WeightsHeader,
};
use rotorhive_transport::Service;
use rotorhive_transport::{Channel, Hub};
use zenoh::Wait;
use zenoh::handlers::{FifoChannel, RingChannel};
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;

use crate::delivery::{Outbox, WINDOW_BYTES};
use crate::error::{LinkError, Result, zerr};
use crate::shared::{Fifo, LinkTelemetry, host_key, key, link_telemetry};
use crate::worker::join::SentLog;
use crate::worker::join::{Worker, WorkerEnd, WorkerStats};
use crate::{check, wire};

impl Worker {
    /// Bridges this host's sims and actors (run `prefix` over service `S`,
    /// `envs` environments, `roles` telemetry publishers) to the head until
    /// the head ends the run, the head is lost, or this process stops.
    /// `on_ready` runs once the link takes this host's batches and the head
    /// takes the link's: start the actors then, or their first batches go
    /// nowhere.
    /// Weights that are not `num_params` finite floats are dropped.
    pub fn bridge<S: Service>(
        &self,
        hub: &Hub<S>,
        envs: usize,
        roles: usize,
        num_params: usize,
        stats: &mut WorkerStats,
        on_ready: impl FnOnce(),
    ) -> Result<WorkerEnd> {
        let s = &self.session;
        let decl = |what: &str| zerr(format!("declare {what}"));
        let mut b = WorkerBridge::open(self, hub, [envs, roles, num_params])?;
        let _token = s
            .liveliness()
            .declare_token(key(&self.run, &format!("host/{}", self.slot)))
            .wait()
            .map_err(decl("this host's liveliness"))?;
        // Zenoh drops what no subscriber matches: send nothing before the
        // head's transitions subscriber is known here.
        let t = Instant::now();
        while !b.trans_pub.matching_status().wait().map_err(zerr("matching status"))?.matching() {
            if t.elapsed() > Duration::from_secs(20) {
                return Err(LinkError::LostHead);
            }
            if hub.shutdown_requested() {
                return Ok(WorkerEnd::Stopped);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        on_ready();
        let end = loop {
            if hub.shutdown_requested() {
                break Ok(WorkerEnd::Stopped);
            }
            if let Some(end) = b.head_end(self.reconnect) {
                break end;
            }
            b.weights_in(hub, stats)?;
            b.acks_in()?;
            b.transitions_out()?;
            b.episodes_and_telemetry_out(stats)?;
            b.count(stats);
            b.tel.tick(false, Telemetry::beat);
        };
        // What it sent waits for its acknowledgement (the head takes
        // batches until its replay stops), then the last count goes out.
        let drain = match end {
            Ok(WorkerEnd::RunEnded) => DRAIN,
            Ok(WorkerEnd::Stopped) => Duration::from_secs(1),
            Err(_) => Duration::ZERO,
        };
        b.finish(drain)?;
        b.count(stats);
        end
    }
}

/// How long a worker waits, once the run ends, for the head to acknowledge
/// what it sent (the head waits a little longer: [`crate::head::bridge`]).
pub(crate) const DRAIN: Duration = Duration::from_secs(5);

/// A worker's link at work: its Zenoh publishers and subscribers, its
/// host's shared-memory channels, and what it keeps between rounds.
pub(crate) struct WorkerBridge<S: Service> {
    pub(crate) session: zenoh::Session,
    pub(crate) trans_pub: zenoh::pubsub::Publisher<'static>,
    pub(crate) ack_sub:
        zenoh::pubsub::Subscriber<zenoh::handlers::RingChannelHandler<zenoh::sample::Sample>>,
    /// What it sent and the head has not acknowledged yet.
    pub(crate) outbox: Outbox<(zenoh::bytes::ZBytes, TransitionHeader)>,
    /// Since when the head is away (its session dropped): the link waits
    /// for it, its window kept, and sends it again once it is back.
    away_since: Option<Instant>,
    ep_pub: zenoh::pubsub::Publisher<'static>,
    pub(crate) tel_pub: zenoh::pubsub::Publisher<'static>,
    w_sub: zenoh::pubsub::Subscriber<zenoh::handlers::RingChannelHandler<zenoh::sample::Sample>>,
    end_sub: Fifo,
    head_sub: Fifo,
    pub(crate) trans_rx: rotorhive_transport::Receiver<S, u16, TransitionHeader>,
    ep_rx: rotorhive_transport::Receiver<S, f32, EpisodeHeader>,
    tel_rx: rotorhive_transport::Receiver<S, u8, Telemetry>,
    w_tx: Option<rotorhive_transport::Sender<S, f32, WeightsHeader>>,
    pub(crate) tel: LinkTelemetry<S>,
    /// The batches seen from each actor of this host.
    pub(crate) wseq: SeqTracker,
    head_seen: bool,
    /// What this process has sent, kept in its run directory.
    pub(crate) sent_log: Option<SentLog>,
    pub(crate) off: u32,
    pub(crate) slot: u32,
    pub(crate) envs: usize,
    num_params: usize,
}

impl<S: Service> WorkerBridge<S> {
    /// Declares the worker's publishers and subscribers and opens its
    /// host's channels, for [`envs`, `roles` telemetry publishers,
    /// `num_params` weights].
    pub(crate) fn open(
        worker: &Worker,
        hub: &Hub<S>,
        [envs, roles, num_params]: [usize; 3],
    ) -> Result<Self> {
        let s = &worker.session;
        let run = &worker.run;
        let decl = |what: &str| zerr(format!("declare {what}"));
        let publisher = |what: &str, cc| {
            s.declare_publisher(host_key(run, worker.slot, what))
                .congestion_control(cc)
                .wait()
                .map_err(decl(what))
        };
        Ok(WorkerBridge {
            session: s.clone(),
            trans_pub: publisher("transitions", CongestionControl::Block)?,
            ack_sub: s
                .declare_subscriber(host_key(run, worker.slot, "ack"))
                .with(RingChannel::new(16))
                .wait()
                .map_err(decl("the acknowledgements subscriber"))?,
            outbox: Outbox::new(worker.epoch, WINDOW_BYTES),
            away_since: None,
            ep_pub: publisher("episodes", CongestionControl::Drop)?,
            tel_pub: publisher("telemetry", CongestionControl::Drop)?,
            w_sub: s
                .declare_subscriber(key(run, "weights"))
                .with(RingChannel::new(1))
                .wait()
                .map_err(decl("the weights subscriber"))?,
            end_sub: s
                .declare_subscriber(key(run, "end"))
                .with(FifoChannel::new(4))
                .wait()
                .map_err(decl("the end subscriber"))?,
            head_sub: s
                .liveliness()
                .declare_subscriber(key(run, "head"))
                .history(true)
                .with(FifoChannel::new(16))
                .wait()
                .map_err(decl("the head's liveliness"))?,
            trans_rx: hub.receiver(&Channel::transitions(envs))?,
            ep_rx: hub.receiver(&Channel::episodes(envs))?,
            tel_rx: hub.receiver(&Channel::telemetry(roles))?,
            w_tx: None,
            tel: link_telemetry(hub, roles, 0)?,
            wseq: SeqTracker::new(envs),
            head_seen: false,
            sent_log: worker.sent_log.as_deref().and_then(|p| {
                SentLog::create(p)
                    .map_err(|e| tracing::warn!("cannot keep {}: {e}", p.display()))
                    .ok()
            }),
            off: worker.env_offset,
            slot: worker.slot,
            envs,
            num_params,
        })
    }

    /// The run's end, or the head lost: its liveliness token gone without
    /// the end message right behind it, and not back within `reconnect`;
    /// none while the head is there (or away, and may come back).
    pub(crate) fn head_end(&mut self, reconnect: Duration) -> Option<Result<WorkerEnd>> {
        if self.end_sub.try_recv().ok().flatten().is_some() {
            return Some(Ok(WorkerEnd::RunEnded));
        }
        while let Ok(Some(l)) = self.head_sub.try_recv() {
            match l.kind() {
                SampleKind::Put => {
                    if let Some(t) = self.away_since.take() {
                        tracing::info!(
                            "the head is back after {:.1} s; {} batches wait for it",
                            t.elapsed().as_secs_f64(),
                            self.outbox.len()
                        );
                    }
                    self.head_seen = true;
                }
                SampleKind::Delete if self.head_seen && self.away_since.is_none() => {
                    // The end message may be right behind (over TLS on a
                    // busy machine, up to a few hundred ms): look for 1 s.
                    let t = Instant::now();
                    while t.elapsed() < Duration::from_secs(1) {
                        if self
                            .end_sub
                            .recv_timeout(Duration::from_millis(50))
                            .ok()
                            .flatten()
                            .is_some()
                        {
                            return Some(Ok(WorkerEnd::RunEnded));
                        }
                    }
                    tracing::warn!(
                        "the head went away; waiting up to {:.0} s for it, {} batches kept",
                        reconnect.as_secs_f64(),
                        self.outbox.len()
                    );
                    self.away_since = Some(t);
                }
                SampleKind::Delete => {}
            }
        }
        match self.away_since {
            Some(t) if t.elapsed() > reconnect => Some(Err(LinkError::LostHead)),
            _ => None,
        }
    }

    /// The newest weights in, checked, republished on this host.
    pub(crate) fn weights_in(&mut self, hub: &Hub<S>, stats: &mut WorkerStats) -> Result<()> {
        let t = Instant::now();
        if let Ok(Some(smp)) = self.w_sub.try_recv() {
            let bytes = smp.payload().to_bytes();
            match check::weights(
                self.num_params,
                smp.attachment().map(|a| a.to_bytes()).as_deref(),
                &bytes,
            ) {
                Ok(h) => {
                    if self.w_tx.is_none() {
                        self.w_tx = Some(hub.sender::<f32, WeightsHeader>(
                            &Channel::weights(self.envs),
                            self.num_params,
                            Duration::from_millis(200),
                        )?);
                    }
                    if let Some(tx) = self.w_tx.as_mut() {
                        tx.send_with(self.num_params, |hdr, p| {
                            *hdr = h;
                            wire::payload_bytes_mut(p).copy_from_slice(&bytes);
                        })?;
                    }
                    stats.weights += 1;
                    stats.weight_version = h.version;
                    self.tel.sample.weight_version = h.version;
                }
                Err(why) => {
                    stats.rejected += 1;
                    tracing::warn!("dropped weights from the head: {why}");
                }
            }
        }
        self.tel.sample.time_stage(LinkStage::Weights, t);
        Ok(())
    }

    /// Episodes and telemetry out (they may drop under load: counted), with
    /// this host's environment offset and slot.
    pub(crate) fn episodes_and_telemetry_out(&mut self, stats: &mut WorkerStats) -> Result<()> {
        let t = Instant::now();
        while let Some(m) = self.ep_rx.try_recv()? {
            let mut h = *m.user_header();
            h.actor += self.off;
            if self
                .ep_pub
                .put(wire::payload_bytes(m.payload()).to_vec())
                .attachment(wire::header_bytes(&h).to_vec())
                .wait()
                .is_err()
            {
                stats.dropped += 1;
            }
        }
        while let Some(m) = self.tel_rx.try_recv()? {
            let mut t = *m.user_header();
            if t.role == RoleKind::Link as u32 {
                t.index = self.slot;
            } else {
                t.index += self.off;
            }
            // A process id means nothing on the head's host.
            t.pid = 0;
            if self
                .tel_pub
                .put(Vec::new())
                .attachment(wire::header_bytes(&t).to_vec())
                .wait()
                .is_err()
            {
                stats.dropped += 1;
            }
        }
        self.tel.sample.time_stage(LinkStage::Forward, t);
        Ok(())
    }
}
