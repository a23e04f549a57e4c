//! The head's side of acknowledged delivery ([`crate::delivery`]) for
//! every worker slot: the slot's stream, its answers on the slot's `ack`
//! key, the replay's receipts that those answers wait for, and what the
//! worker's link reports of its own counts, kept across the worker's joins.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use rotorhive_msg::{Delivery, Receipt, TransitionHeader};
use zenoh::Wait;
use zenoh::qos::CongestionControl;

use crate::delivery::LinkHeader;
use crate::error::{Result, zerr};
use crate::head::admit::{Flow, HeadStats};
use crate::head::host::Host;
use crate::head::inflow::{Admit, Inflow};
use crate::shared::host_key;
use crate::wire;
use crate::wire::Earlier;

/// A worker silent this long counts as ended when the head drains at the
/// run's end (a killed worker sends no last count).
const SILENT: Duration = Duration::from_secs(3);

/// One slot's stream and counts.
struct SlotFlow {
    slot: u32,
    inflow: Inflow,
    ack_pub: zenoh::pubsub::Publisher<'static>,
    /// A batch came past a gap since the last answer.
    gap: bool,
    /// The worker's newest report in this join, and when it came.
    reported: Delivery,
    heard: Option<Instant>,
    /// Its reports of earlier joins.
    base: Delivery,
    /// Transitions taken in this join.
    taken: u64,
}

impl SlotFlow {
    /// Transitions the worker reported sent in this join and the head has
    /// not taken.
    fn untaken(&self) -> u64 {
        self.reported.sent.saturating_sub(self.taken)
    }
}

/// A batch sent into the replay's queue that no receipt covers yet.
struct Unconfirmed {
    slot: u32,
    link: LinkHeader,
    /// Its actor and the actor's sequence number (what a receipt names).
    actor: u64,
    seq: u64,
    count: u32,
}

impl Unconfirmed {
    /// Its slot's flow, while the slot is in the join that sent it.
    fn of<'a>(&self, slots: &'a mut [SlotFlow]) -> Option<&'a mut SlotFlow> {
        slots.iter_mut().find(|s| s.slot == self.slot && s.inflow.epoch() == self.link.epoch)
    }
}

/// Every slot's stream (in the order of the run's hosts).
pub(crate) struct Flows {
    slots: Vec<SlotFlow>,
    /// What went into the replay's queue, oldest first, until a receipt
    /// covers it (the replay takes its queue in order).
    queued: VecDeque<Unconfirmed>,
    /// The replay process the receipts come from.
    incarnation: Option<u64>,
}

impl Flows {
    /// The streams of `hosts`, each answering on its slot's `ack` key.
    pub(crate) fn open(session: &zenoh::Session, run: &str, hosts: &[Host]) -> Result<Self> {
        let mut slots = Vec::with_capacity(hosts.len());
        for h in hosts {
            let ack_pub = session
                .declare_publisher(host_key(run, h.slot, "ack"))
                .congestion_control(CongestionControl::Drop)
                .express(true)
                .wait()
                .map_err(zerr("declare an acknowledgements publisher"))?;
            slots.push(SlotFlow {
                slot: h.slot,
                inflow: Inflow::new(h.epoch),
                ack_pub,
                gap: false,
                reported: Delivery::default(),
                heard: None,
                base: Delivery::default(),
                taken: 0,
            });
        }
        Ok(Self { slots, queued: VecDeque::new(), incarnation: None })
    }

    fn get(&mut self, slot: u32) -> Option<&mut SlotFlow> {
        self.slots.iter_mut().find(|s| s.slot == slot)
    }

    /// What to do with a batch of `slot` with header `h` (a batch past a
    /// gap is asked for again at the next answer).
    pub(crate) fn admit(&mut self, slot: u32, h: LinkHeader) -> Admit {
        let Some(s) = self.get(slot) else { return Admit::Stale };
        let a = s.inflow.admit(h);
        s.gap |= a == Admit::Gap;
        a
    }

    /// The batch of `slot` admitted last (`h`, `link`) went into the
    /// replay's queue.
    pub(crate) fn taken(&mut self, slot: u32, h: &TransitionHeader, link: LinkHeader) {
        if let Some(s) = self.get(slot) {
            s.inflow.taken();
            s.taken += h.count as u64;
            let (actor, seq, count) = (h.actor as u64, h.seq, h.count);
            self.queued.push_back(Unconfirmed { slot, link, actor, seq, count });
        }
    }

    /// The replay's newest receipt: what it covers is acknowledged; a new
    /// replay process means its predecessor's queue is gone, and what that
    /// held is asked of the workers again.
    pub(crate) fn confirm(&mut self, r: Receipt, stats: &HeadStats) {
        if self.incarnation.is_some_and(|i| i != r.incarnation) {
            self.replay_restarted();
        }
        self.incarnation = Some(r.incarnation);
        if r.batches == 0 {
            return;
        }
        let Self { slots, queued, .. } = self;
        let Some(last) = queued.iter().position(|u| (u.actor, u.seq) == (r.actor, r.seq)) else {
            return;
        };
        for u in queued.drain(..=last) {
            if let Some(s) = u.of(slots) {
                s.inflow.confirm(u.link.seq);
                stats.flow(u.slot, |f| f.acknowledged += u.count as u64);
            }
        }
    }

    /// Takes every slot back to the first batch the replay did not confirm.
    fn replay_restarted(&mut self) {
        for u in self.queued.drain(..) {
            if let Some(s) = u.of(&mut self.slots) {
                s.taken -= u.count as u64;
            }
        }
        let again: u64 = self.slots.iter_mut().map(|s| s.inflow.rewind()).sum();
        tracing::warn!("the replay restarted: asking the workers again for {again} batches");
    }

    /// Sends every answer due now (a lost one is made good by the next:
    /// they are cumulative, and each slot's stands again every heartbeat).
    pub(crate) fn answer(&mut self, now: Instant) {
        for s in &mut self.slots {
            if let Some(ack) = s.inflow.answer(std::mem::take(&mut s.gap), now) {
                let _ = s.ack_pub.put(wire::header_bytes(&ack).to_vec()).wait();
            }
        }
    }

    /// The worker link's own report of `slot` (its telemetry).
    pub(crate) fn report(&mut self, slot: u32, d: Delivery, stats: &HeadStats) {
        let Some(s) = self.get(slot) else { return };
        s.reported = d;
        s.heard = Some(Instant::now());
        let (base, taken) = (s.base, s.taken);
        stats.flow(slot, |f| {
            f.sent = base.sent + d.sent.max(taken);
            f.resent = base.resent + d.resent;
        });
    }

    /// `slot` joined again under `epoch`: what the earlier process sent
    /// and the head never took (as its last report said, or its log where
    /// the new process brought it) is lost.
    pub(crate) fn rejoin(&mut self, slot: u32, epoch: u64, earlier: Earlier, stats: &HeadStats) {
        let Some(s) = self.get(slot) else { return };
        if earlier.epoch == s.inflow.epoch() {
            s.reported.sent = s.reported.sent.max(earlier.sent);
        }
        let lost = s.untaken();
        // It sent at least what was taken (its last report may be older).
        s.base.sent += s.reported.sent.max(s.taken);
        s.base.resent += s.reported.resent;
        (s.reported, s.taken, s.inflow) = (Delivery::default(), 0, Inflow::new(epoch));
        stats.flow(slot, |f| f.lost += lost);
    }

    /// Whether every worker sent its last count (or went silent).
    pub(crate) fn all_ended(&self) -> bool {
        self.slots
            .iter()
            .all(|s| s.reported.ended != 0 || s.heard.is_none_or(|t| t.elapsed() > SILENT))
    }

    /// At the run's end: what each worker reported sent and the head did
    /// not take is lost.
    pub(crate) fn settle(&self, stats: &HeadStats) {
        for s in &self.slots {
            let lost = s.untaken();
            if lost > 0 {
                tracing::warn!("worker {}: {lost} transitions sent and never taken", s.slot);
            }
            stats.flow(s.slot, |f| f.lost += lost);
        }
    }
}

impl HeadStats {
    /// Changes the delivery counts of `slot`.
    pub(crate) fn flow(&self, slot: u32, change: impl FnOnce(&mut Flow)) {
        if let Ok(mut f) = self.flows.lock() {
            if f.len() <= slot as usize {
                f.resize(slot as usize + 1, Flow::default());
            }
            change(&mut f[slot as usize]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::delivery::LinkHeader;

    fn batch(seq: u64) -> (TransitionHeader, LinkHeader) {
        (
            TransitionHeader { actor: 3, count: 5, seq, weight_version: 0 },
            LinkHeader { epoch: 10, seq },
        )
    }

    /// Acknowledged only as far as the replay's receipt goes; a restarted
    /// replay makes the slot take its unconfirmed batches again; a killed
    /// worker's loss is counted from the log its successor brings, when it
    /// is of the epoch the head knew, and from its last report otherwise.
    #[test]
    fn receipts_rewinds_and_a_killed_workers_log() {
        let session = crate::options::open(None, None, &Default::default()).unwrap();
        let host = Host {
            name: "w".into(),
            slot: 1,
            envs: 1,
            agents: 5,
            env_offset: 1,
            epoch: 10,
            token: "t".into(),
        };
        let stats = HeadStats::default();
        let mut f = Flows::open(&session, "t", std::slice::from_ref(&host)).unwrap();
        for seq in 0..3 {
            let (h, link) = batch(seq);
            assert_eq!(f.admit(1, link), Admit::Take);
            f.taken(1, &h, link);
        }
        let receipt = |incarnation, batches, seq| Receipt { incarnation, batches, actor: 3, seq };
        f.confirm(receipt(7, 2, 1), &stats);
        assert_eq!(stats.flow_of(1).acknowledged, 10);
        // The replay restarted: the third batch (never confirmed) is taken
        // again, the first two are duplicates.
        f.confirm(receipt(8, 0, 0), &stats);
        assert_eq!(f.admit(1, batch(0).1), Admit::Duplicate);
        assert_eq!(f.admit(1, batch(2).1), Admit::Take);
        let (h, link) = batch(2);
        f.taken(1, &h, link);
        f.confirm(receipt(8, 1, 2), &stats);
        assert_eq!(stats.flow_of(1).acknowledged, 15);
        // Killed: its last report said 10 sent, its log 25 (epoch 10).
        f.report(1, Delivery { sent: 10, ..Delivery::default() }, &stats);
        f.rejoin(1, 11, Earlier { epoch: 10, sent: 25 }, &stats);
        assert_eq!(stats.flow_of(1).lost, 10);
        f.report(1, Delivery::default(), &stats);
        assert_eq!(stats.flow_of(1).sent, 25);
        // A log of another epoch than the head's for the slot is ignored.
        f.report(1, Delivery { sent: 4, ..Delivery::default() }, &stats);
        f.rejoin(1, 12, Earlier { epoch: 10, sent: 1_000 }, &stats);
        assert_eq!(stats.flow_of(1).lost, 14);
    }
}
