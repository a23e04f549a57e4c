//! Acknowledged delivery of transition batches, worker → head (Kafka's
//! idempotent producer, Reverb's confirmed inserts): each batch carries its
//! link's epoch (the head gives one at every join) and a sequence number;
//! the worker keeps what it sent in a window bounded in bytes ([`Outbox`])
//! until the head acknowledges it; the head takes each slot's batches in
//! order only ([`Inflow`]): a duplicate is dropped and counted, a batch
//! past a gap is dropped and the gap asked for again (go-back-N), and the
//! acknowledgement (cumulative: every batch below `next`) is sent once the
//! replay process has taken the batch (its receipt, not its queue's: a
//! replay killed with batches in its queue has them asked for again from
//! the workers, whose windows still hold them). Nothing here knows Zenoh:
//! the bridges carry [`LinkHeader`] in a batch's attachment and [`Ack`] on
//! the slot's `ack` key.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use rotorhive_msg::Delivery;

/// A batch's place in its link's stream, sent after its `TransitionHeader`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct LinkHeader {
    /// The link's epoch: the head's number for this join of the worker.
    pub epoch: u64,
    /// The batch's number in the epoch, from 0.
    pub seq: u64,
}

/// The head's answer to a worker: every batch of `epoch` below `next` is
/// in the replay; `resend` nonzero: the batch `resend - 1` is missing (a
/// later one came first, or the replay lost it), send the window again from
/// there.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Ack {
    /// The epoch it answers.
    pub epoch: u64,
    /// The first batch not yet taken.
    pub next: u64,
    /// The first batch to send again, plus one; 0 for none.
    pub resend: u64,
}

/// The most bytes of unacknowledged batches a worker keeps (a full one
/// stops its reading of shared memory: back-pressure, as a full queue).
pub const WINDOW_BYTES: usize = 128 << 20;
/// A worker sends its window again when the head's acknowledgements say
/// nothing new and its oldest batch went out this long ago (a lost tail,
/// a session that came back); and no sooner again after a resend request.
pub const RESEND_AFTER: Duration = Duration::from_secs(1);
/// The head acknowledges new batches at most this often, and says where
/// each slot stands at least this often ([`HEARTBEAT`]; [`crate::head::inflow`]).
pub const ACK_EVERY: Duration = Duration::from_millis(5);
/// See [`ACK_EVERY`].
pub const HEARTBEAT: Duration = Duration::from_millis(250);
/// The head asks again for one missing batch at most this often.
pub const NACK_EVERY: Duration = Duration::from_millis(500);

struct Pending<P> {
    seq: u64,
    count: u32,
    bytes: usize,
    sent_at: Instant,
    item: P,
}

/// A worker's window of sent, unacknowledged batches (`P`: what it sends
/// again, a handle to the batch's bytes).
pub struct Outbox<P> {
    epoch: u64,
    next_seq: u64,
    window: VecDeque<Pending<P>>,
    bytes: usize,
    limit: usize,
    /// The highest `next` the head acknowledged.
    acked_next: u64,
    /// The last resend asked for: from which batch, and when.
    resent_from: Option<(u64, Instant)>,
    /// Its counts (in transitions; `ended` stays 0: the link sets it).
    pub counts: Delivery,
}

impl<P: Clone> Outbox<P> {
    /// An empty window of epoch `epoch` holding at most `limit` bytes (one
    /// batch, whatever its size, always fits an empty window).
    pub fn new(epoch: u64, limit: usize) -> Self {
        Self {
            epoch,
            next_seq: 0,
            window: VecDeque::new(),
            bytes: 0,
            limit,
            acked_next: 0,
            resent_from: None,
            counts: Delivery::default(),
        }
    }

    /// The epoch its batches go under.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Whether the window takes another batch (then the worker reads one).
    pub fn has_room(&self) -> bool {
        self.bytes < self.limit
    }

    /// Whether every batch sent was acknowledged.
    pub fn is_empty(&self) -> bool {
        self.window.is_empty()
    }

    /// Batches waiting for their acknowledgement.
    pub fn len(&self) -> usize {
        self.window.len()
    }

    /// Records a batch of `count` transitions and `bytes` bytes, sent now;
    /// the header to send it with.
    pub fn push(&mut self, count: u32, bytes: usize, item: P, now: Instant) -> LinkHeader {
        let seq = self.next_seq;
        self.next_seq += 1;
        self.window.push_back(Pending { seq, count, bytes, sent_at: now, item });
        self.bytes += bytes;
        self.counts.sent += count as u64;
        LinkHeader { epoch: self.epoch, seq }
    }

    /// Takes the head's answer: drops what it acknowledged; from which
    /// batch the window must go out again now, if it must
    /// ([`Outbox::resend`]).
    pub fn on_ack(&mut self, ack: Ack, now: Instant) -> Option<u64> {
        if ack.epoch != self.epoch || ack.next > self.next_seq {
            return None;
        }
        while self.window.front().is_some_and(|p| p.seq < ack.next) {
            if let Some(p) = self.window.pop_front() {
                self.bytes -= p.bytes;
                self.counts.acknowledged += p.count as u64;
            }
        }
        let progress = ack.next > self.acked_next;
        self.acked_next = self.acked_next.max(ack.next);
        let first = self.window.front()?;
        if ack.resend != 0 {
            let from = ack.resend - 1;
            let recent =
                self.resent_from.is_some_and(|(f, at)| f == from && now - at < RESEND_AFTER);
            let held = self.window.back().is_some_and(|p| p.seq >= from);
            return (held && !recent).then_some(from.max(first.seq));
        }
        let stuck = !progress && now.saturating_duration_since(first.sent_at) >= RESEND_AFTER;
        stuck.then_some(first.seq)
    }

    /// The window from batch `from` on, oldest first, with the headers to
    /// send it again with; counted resent and stamped sent now.
    pub fn resend(&mut self, from: u64, now: Instant) -> Vec<(LinkHeader, P)> {
        self.resent_from = Some((from, now));
        let epoch = self.epoch;
        let counts = &mut self.counts;
        self.window
            .iter_mut()
            .filter(|p| p.seq >= from)
            .map(|p| {
                p.sent_at = now;
                counts.resent += p.count as u64;
                (LinkHeader { epoch, seq: p.seq }, p.item.clone())
            })
            .collect()
    }
}

/// A new epoch for a join: random (std's per-process random hash keys mixed
/// with the time), so that a batch of an earlier join is never taken as one
/// of this join's.
pub fn new_epoch() -> u64 {
    rotorhive_transport::fresh_id()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::head::inflow::{Admit, Inflow};
    use proptest::prelude::*;

    /// `batches` batches over a link that loses and duplicates them as
    /// `fate` says (then heals), a round of 30 ms at a time, into a replay
    /// that takes two a round and loses its queue at the rounds in
    /// `restarts`: what the replay took, the worker's counts, and the
    /// duplicates the head dropped.
    fn fly(fate: &[u8], batches: usize, restarts: &[usize]) -> (Vec<u64>, Delivery, u64) {
        let epoch = 7;
        let mut out: Outbox<u64> = Outbox::new(epoch, 8 * 100);
        let mut inflow = Inflow::new(epoch);
        let mut taken = Vec::new();
        let mut dups = 0;
        let mut wire: VecDeque<(LinkHeader, u64)> = VecDeque::new();
        // The replay's queue: link sequence numbers and what they carry.
        let mut queue: VecDeque<(u64, u64)> = VecDeque::new();
        let mut now = Instant::now();
        let mut made = 0u64;
        for round in 0..20 * batches + 200 {
            now += Duration::from_millis(30);
            if made < batches as u64 && out.has_room() {
                let h = out.push(1, 100, made, now);
                wire.push_back((h, made));
                made += 1;
            }
            // The wire: in order; a batch may be lost or delivered twice
            // (until the link heals, late in the run).
            let healed = round > 10 * batches;
            let mut gap = false;
            let mut n = 2;
            while n > 0
                && let Some((h, v)) = wire.pop_front()
            {
                n -= 1;
                let f = fate.get(round % fate.len().max(1)).copied().unwrap_or(0);
                let copies = match f % 8 {
                    _ if healed => 1,
                    0 => 0,
                    1 => 2,
                    _ => 1,
                };
                for _ in 0..copies {
                    match inflow.admit(h) {
                        Admit::Take => {
                            queue.push_back((h.seq, v));
                            inflow.taken();
                        }
                        Admit::Duplicate => dups += 1,
                        Admit::Gap => gap = true,
                        Admit::Stale => unreachable!("one epoch"),
                    }
                }
            }
            if restarts.contains(&round) {
                queue.clear();
                inflow.rewind();
            }
            for (seq, v) in queue.drain(..queue.len().min(2)) {
                taken.push(v);
                inflow.confirm(seq);
            }
            if let Some(ack) = inflow.answer(gap, now)
                && let Some(from) = out.on_ack(ack, now)
            {
                wire.extend(out.resend(from, now));
            }
        }
        (taken, out.counts, dups)
    }

    proptest! {
        /// Whatever the link loses or doubles, and however often the replay
        /// loses its queue, the replay takes every batch exactly once, in
        /// order, and the worker's counts add up.
        #[test]
        fn every_batch_arrives_once_in_order(
            fate in proptest::collection::vec(any::<u8>(), 1..64),
            batches in 1usize..60,
            restarts in proptest::collection::vec(0usize..600, 0..4),
        ) {
            let (taken, counts, _) = fly(&fate, batches, &restarts);
            prop_assert_eq!(taken, (0..batches as u64).collect::<Vec<_>>());
            prop_assert_eq!(counts.sent, batches as u64);
            prop_assert_eq!(counts.acknowledged, batches as u64);
        }
    }

    #[test]
    fn a_clean_link_resends_nothing() {
        let (taken, counts, dups) = fly(&[2], 50, &[]);
        assert_eq!(taken.len(), 50);
        assert_eq!((counts.resent, dups), (0, 0));
    }

    #[test]
    fn a_lost_batch_is_sent_again() {
        // The first batch of every eight is lost on its first trip.
        let (taken, counts, _) = fly(&[0, 2, 2, 2, 2, 2, 2, 2], 40, &[]);
        assert_eq!(taken, (0..40).collect::<Vec<_>>());
        assert!(counts.resent > 0);
    }

    #[test]
    fn what_a_restarted_replay_lost_is_sent_again() {
        // A replay that takes two a round while the link brings two: its
        // queue holds a few when it restarts.
        let (taken, counts, _) = fly(&[2], 40, &[10, 11, 25]);
        assert_eq!(taken, (0..40).collect::<Vec<_>>());
        assert!(counts.resent > 0);
    }

    #[test]
    fn batches_of_another_epoch_are_stale_and_the_window_is_bounded() {
        let inflow = Inflow::new(1);
        assert_eq!(inflow.admit(LinkHeader { epoch: 2, seq: 0 }), Admit::Stale);
        let mut out: Outbox<()> = Outbox::new(1, 250);
        let now = Instant::now();
        out.push(1, 100, (), now);
        out.push(1, 100, (), now);
        assert!(out.has_room());
        out.push(1, 100, (), now);
        assert!(!out.has_room());
        // An answer of another epoch, or of batches never sent, changes nothing.
        assert_eq!(out.on_ack(Ack { epoch: 2, next: 3, resend: 0 }, now), None);
        assert_eq!(out.on_ack(Ack { epoch: 1, next: 9, resend: 0 }, now), None);
        assert_eq!(out.len(), 3);
        assert_eq!(out.on_ack(Ack { epoch: 1, next: 2, resend: 0 }, now), None);
        assert_eq!((out.len(), out.counts.acknowledged), (1, 2));
        assert!(out.has_room());
    }
}
