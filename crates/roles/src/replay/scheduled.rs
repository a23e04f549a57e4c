//! The replay of a deterministic run: rounds of transition batches in
//! environment order, and exactly the minibatches the schedule names after
//! each, sampled from the seeded generator.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use rotorhive_msg::{ReplayStage, RowLayout, SeqTracker, TransitionHeader};
use rotorhive_replay::Acted;
use rotorhive_transport::Service;

use super::{
    Memory, Stores, check, minibatch_header, minibatch_len, sample, sent_or_stalled, store,
};
use crate::error::{Doing, Result, protocol_err};
use crate::schedule::Schedule;

impl<S: Service> Memory<'_, S> {
    /// The replay of a deterministic run ([`Schedule`]): transition batches
    /// wait per environment until every environment's batch of the next round
    /// is in, then go in environment by environment; after round `k` exactly
    /// `minibatches_after(k)` minibatches have gone out, each sampled (from
    /// the seeded generator) before the next round goes in, and offered until
    /// the learner takes it.
    pub(super) fn run_scheduled(&mut self) -> Result<()> {
        let (cfg, batch) = (self.cfg, self.cfg.replay.batch);
        let schedule = Schedule::new(cfg);
        let mut pending: Vec<VecDeque<(u64, Vec<u16>)>> = vec![VecDeque::new(); cfg.sim.envs];
        let mut next_seq = SeqTracker::new(cfg.sim.envs);
        let (mut rounds, mut sent) = (0u64, 0u64);
        // The next minibatch, sampled once and offered until the learner takes it.
        let mut minibatch = vec![0u16; minibatch_len(self.rows.packed_len(), batch)];
        let mut drawn: Option<(Acted, (usize, f32))> = None;
        // A minibatch sent before the learner subscribes would be lost.
        while self.tx.receivers() == 0 && !self.hub.shutdown_requested() {
            std::thread::sleep(Duration::from_millis(10));
        }
        while !self.hub.shutdown_requested() {
            let t = Instant::now();
            let mut busy = false;
            while let Some(m) = self.rx.try_recv().doing("receiving transitions")? {
                self.queue(&m, &mut pending, &mut next_seq)?;
                busy = true;
            }
            self.tel.sample.time_stage(ReplayStage::Insert, t);
            // The minibatches owed after the rounds in, one at a time (each
            // waiting for its priorities under prioritized replay), then the
            // next round.
            let owed = sent < schedule.minibatches_after(rounds);
            if drawn.is_none()
                && owed
                && self.prio.ready_for(sent, &mut self.mem, &mut self.tel.sample.learning)?
            {
                if self.mem.is_empty() {
                    // The schedule waits for every agent's first row: a
                    // memory still empty is a bug, not a run to go on with.
                    protocol_err!("minibatch {sent} is owed and the replay memory holds nothing");
                }
                let beta = cfg.replay.priority_beta;
                let (rows, teacher) = self.demo_rows(sent);
                let demos = self.demos.as_mut().map(|d| &mut d.mem);
                let acted =
                    sample(&mut self.mem, demos, rows, &mut minibatch, &mut self.picks, beta);
                drawn = Some((acted, (rows, teacher)));
            }
            if let Some((acted, demo)) = drawn {
                if self.send_copy(&minibatch, sent, acted, demo)? {
                    sent += 1;
                    drawn = None;
                    busy = true;
                }
            } else if !owed && rounds < schedule.rounds() && pending.iter().all(|q| !q.is_empty()) {
                insert_round(&mut pending, cfg.rows(), self.stores())?;
                rounds += 1;
                busy = true;
            }
            self.housekeep(sent)?;
            if !busy {
                let t = Instant::now();
                let wait = Duration::from_millis(1);
                if let Some(m) = self.rx.recv_timeout(wait).doing("waiting for transitions")? {
                    self.queue(&m, &mut pending, &mut next_seq)?;
                }
                self.tel.sample.time_stage(ReplayStage::Idle, t);
            }
        }
        Ok(())
    }

    /// Queues a deterministic run's transition batch (see [`enqueue`])
    /// and notes it in the receipts.
    fn queue(
        &mut self,
        m: &rotorhive_transport::Msg<S, u16, TransitionHeader>,
        pending: &mut [VecDeque<(u64, Vec<u16>)>],
        next_seq: &mut SeqTracker,
    ) -> Result<()> {
        let lost = &mut self.tel.sample.lost;
        enqueue(m, pending, self.rows, (next_seq, lost))?;
        self.receipts.took(m.user_header());
        Ok(())
    }

    /// Offers a drawn minibatch (number `seq`); false when the learner's
    /// queue stayed full.
    fn send_copy(
        &mut self,
        minibatch: &[u16],
        seq: u64,
        acted: Acted,
        demo: (usize, f32),
    ) -> Result<bool> {
        let batch = self.cfg.replay.batch;
        let t = Instant::now();
        let res = self.tx.send_with(minibatch.len(), |h, o| {
            o.copy_from_slice(minibatch);
            *h = minibatch_header(batch, seq, acted, demo);
        });
        self.tel.sample.time_stage(ReplayStage::Sample, t);
        sent_or_stalled(res)
    }
}

/// Inserts a deterministic run's next round: each environment's oldest
/// pending batch, in environment order.
fn insert_round(
    pending: &mut [VecDeque<(u64, Vec<u16>)>],
    rows: RowLayout,
    mut stores: Stores<'_>,
) -> Result<()> {
    for q in pending {
        let (version, batch) = q.pop_front().unwrap_or_default();
        store(stores.reborrow(), rows, &batch, version)?;
    }
    Ok(())
}

/// Queues a deterministic run's transition batch behind its environment's
/// earlier ones.
fn enqueue<S: Service>(
    m: &rotorhive_transport::Msg<S, u16, TransitionHeader>,
    pending: &mut [VecDeque<(u64, Vec<u16>)>],
    rows: RowLayout,
    (next_seq, lost): (&mut SeqTracker, &mut u64),
) -> Result<()> {
    let h = *m.user_header();
    let envs = pending.len();
    let Some(q) = pending.get_mut(h.actor as usize) else {
        protocol_err!("transitions from actor {} of a run with {envs} environments", h.actor);
    };
    // A corrupt batch is refused; the round stays whole without it.
    let clean = check(m, rows, next_seq, lost);
    q.push_back((h.weight_version, if clean { m.payload().to_vec() } else { Vec::new() }));
    Ok(())
}
