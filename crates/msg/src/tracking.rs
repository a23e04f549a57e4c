//! Loss of transition batches as their receivers count it.

/// The sequence numbers of each actor's transition batches as a receiver
/// sees them (the replay, the head's link, a worker's link): a number past
/// the next one expected is a gap of that many lost batches; a smaller one
/// is a restarted actor (it starts again at 0), not loss.
#[derive(Debug, Clone, Default)]
pub struct SeqTracker {
    next: Vec<Option<u64>>,
}

impl SeqTracker {
    /// A tracker for actors `0..actors`.
    pub fn new(actors: usize) -> Self {
        Self { next: vec![None; actors] }
    }

    /// Batch `seq` of `actor` arrived: the batches missing just before it
    /// (0 when none, or when `actor` is out of range: the message's own
    /// check names that).
    pub fn observe(&mut self, actor: usize, seq: u64) -> u64 {
        let Some(slot) = self.next.get_mut(actor) else {
            return 0;
        };
        let gap = match *slot {
            Some(want) if seq > want => seq - want,
            _ => 0,
        };
        *slot = Some(seq.saturating_add(1));
        gap
    }

    /// A tracker that goes on from `next` (each actor's next batch, `None`
    /// where none was seen): a restarted receiver's predecessor's view.
    pub fn resume(next: Vec<Option<u64>>) -> Self {
        Self { next }
    }

    /// Forgets `actor` (its host joined again: its sequence starts afresh).
    pub fn reset(&mut self, actor: usize) {
        if let Some(slot) = self.next.get_mut(actor) {
            *slot = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seq_tracker_counts_gaps_not_restarts() {
        let mut t = SeqTracker::new(2);
        assert_eq!(t.observe(0, 5), 0, "the first batch seen is no gap");
        assert_eq!(t.observe(0, 6), 0);
        assert_eq!(t.observe(0, 9), 2, "7 and 8 missing");
        assert_eq!(t.observe(0, 0), 0, "a restarted actor");
        assert_eq!(t.observe(0, 1), 0);
        assert_eq!(t.observe(1, 3), 0);
        assert_eq!(t.observe(7, 3), 0, "out of range");
        t.reset(1);
        assert_eq!(t.observe(1, 40), 0, "a host that joined again starts afresh");
        assert_eq!(t.observe(1, 42), 1);
    }
}
