//! The head's view of one worker slot's stream of transition batches
//! ([`crate::delivery`]): which batch to take next, which the replay has
//! confirmed, and the answer due (an acknowledgement, a heartbeat, or a
//! request to send again from a missing batch).

use std::time::{Duration, Instant};

use crate::delivery::{ACK_EVERY, Ack, HEARTBEAT, LinkHeader, NACK_EVERY};

/// What the head does with a batch of a slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admit {
    /// The next one: into the replay.
    Take,
    /// Taken before (a resend): dropped, counted.
    Duplicate,
    /// Past a gap: dropped (it comes again behind the missing one).
    Gap,
    /// Of another epoch than the slot's join: dropped, counted.
    Stale,
}

/// The head's view of one slot's stream.
#[derive(Debug, Clone)]
pub struct Inflow {
    epoch: u64,
    /// The next batch to take (every one below went into the replay's queue).
    next: u64,
    /// Every batch below this one is in the replay (its receipt said so).
    confirmed: u64,
    /// The `confirmed` last acknowledged, and when.
    acked: u64,
    acked_at: Option<Instant>,
    /// The last resend request: for which batch, and when.
    nacked: Option<(u64, Instant)>,
    /// Taking went back to `confirmed` (the replay lost its queue): the
    /// next answer asks for the window again from there.
    rewound: bool,
}

impl Inflow {
    /// A slot joined under `epoch`, nothing taken yet.
    pub fn new(epoch: u64) -> Self {
        Self {
            epoch,
            next: 0,
            confirmed: 0,
            acked: 0,
            acked_at: None,
            nacked: None,
            rewound: false,
        }
    }

    /// The epoch of the slot's current join.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// What to do with a batch of header `h`.
    pub fn admit(&self, h: LinkHeader) -> Admit {
        match (h.epoch == self.epoch, h.seq.cmp(&self.next)) {
            (false, _) => Admit::Stale,
            (true, std::cmp::Ordering::Less) => Admit::Duplicate,
            (true, std::cmp::Ordering::Greater) => Admit::Gap,
            (true, std::cmp::Ordering::Equal) => Admit::Take,
        }
    }

    /// The batch admitted last went into the replay's queue.
    pub fn taken(&mut self) {
        self.next += 1;
    }

    /// The replay took batch `seq` (and, in order, every one before it).
    pub fn confirm(&mut self, seq: u64) {
        self.confirmed = self.confirmed.max(seq.saturating_add(1)).min(self.next);
    }

    /// The replay lost what its queue held: batches from the first one it
    /// did not confirm are taken again; how many that is.
    pub fn rewind(&mut self) -> u64 {
        let again = self.next - self.confirmed;
        if again > 0 {
            (self.next, self.rewound) = (self.confirmed, true);
        }
        again
    }

    /// The answer due now, if any: a resend request after a gap or a
    /// rewind (at most one per [`NACK_EVERY`] for one batch), else an
    /// acknowledgement of new batches ([`ACK_EVERY`]) or where the slot
    /// stands ([`HEARTBEAT`]).
    pub fn answer(&mut self, gap: bool, now: Instant) -> Option<Ack> {
        let rewound = std::mem::take(&mut self.rewound);
        if rewound || gap {
            let asked = self.nacked.is_some_and(|(n, at)| n == self.next && now - at < NACK_EVERY);
            if asked && !rewound {
                return None;
            }
            self.nacked = Some((self.next, now));
            return Some(self.ack(self.next + 1, now));
        }
        let since = self.acked_at.map_or(Duration::MAX, |at| now.saturating_duration_since(at));
        let due = (self.confirmed != self.acked && since >= ACK_EVERY) || since >= HEARTBEAT;
        due.then(|| self.ack(0, now))
    }

    fn ack(&mut self, resend: u64, now: Instant) -> Ack {
        self.acked = self.confirmed;
        self.acked_at = Some(now);
        Ack { epoch: self.epoch, next: self.confirmed, resend }
    }
}
