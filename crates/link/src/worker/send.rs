//! A worker's transitions on their way to the head through its window of
//! unacknowledged batches ([`crate::delivery`]): sent, acknowledged, sent
//! again, and the last count at the end.

use std::time::{Duration, Instant};

use rotorhive_msg::{Delivery, LinkStage, Telemetry, TransitionHeader};
use rotorhive_transport::Service;
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::qos::CongestionControl;

use crate::delivery::{Ack, LinkHeader};
use crate::error::{Result, zerr};
use crate::shared::missing_before;
use crate::wire;
use crate::wire::Earlier;
use crate::worker::bridge::WorkerBridge;
use crate::worker::join::WorkerStats;

impl<S: Service> WorkerBridge<S> {
    /// One transition batch out, if there is one and the window has room
    /// (a full window waits for the head's acknowledgements: back-pressure
    /// to the actors): a blocking put, so a busy head slows the actors.
    pub(crate) fn transitions_out(&mut self) -> Result<()> {
        let t = Instant::now();
        if !self.outbox.has_room() {
            std::thread::sleep(Duration::from_millis(2));
            self.tel.sample.time_stage(LinkStage::SendWait, t);
            return Ok(());
        }
        let m = self.trans_rx.recv_timeout(Duration::from_millis(5))?;
        self.tel.sample.time_stage(LinkStage::Receive, t);
        let Some(m) = m else { return Ok(()) };
        let t = Instant::now();
        let mut h = *m.user_header();
        missing_before(&mut self.wseq, &h, "worker link", " in shared memory");
        h.actor += self.off;
        let bytes = ZBytes::from(wire::payload_bytes(m.payload()).to_vec());
        let link = self.outbox.push(h.count, bytes.len(), (bytes.clone(), h), Instant::now());
        if let Some(log) = &self.sent_log {
            log.record(Earlier { epoch: link.epoch, sent: self.outbox.counts.sent });
        }
        self.put(&h, &link, bytes)?;
        self.tel.sample.work2 += std::mem::size_of_val(m.payload()) as u64;
        self.tel.sample.time_stage(LinkStage::SendWait, t);
        Ok(())
    }

    /// A batch on the wire (the payload's bytes shared with the window).
    fn put(&self, h: &TransitionHeader, link: &LinkHeader, bytes: ZBytes) -> Result<()> {
        self.trans_pub
            .put(bytes)
            .attachment(wire::transition_attachment(h, link))
            .wait()
            .map_err(zerr("send transitions"))
    }

    /// The head's acknowledgements in: the window shrinks, and goes out
    /// again from the first batch missing when the head asks for it or its
    /// answers say nothing new for [`crate::delivery::RESEND_AFTER`].
    pub(crate) fn acks_in(&mut self) -> Result<()> {
        let now = Instant::now();
        let mut again = None;
        while let Ok(Some(smp)) = self.ack_sub.try_recv() {
            if let Some(ack) = wire::header_from::<Ack>(&smp.payload().to_bytes()) {
                again = again.into_iter().chain(self.outbox.on_ack(ack, now)).min();
            }
        }
        if let Some(from) = again {
            let window = self.outbox.resend(from, now);
            tracing::info!("sending {} unacknowledged batches again", window.len());
            for (link, (bytes, h)) in window {
                self.put(&h, &link, bytes)?;
            }
        }
        Ok(())
    }

    /// The counts into the worker's stats and its link's telemetry.
    pub(crate) fn count(&mut self, stats: &mut WorkerStats) {
        let c = self.outbox.counts;
        (stats.transitions, stats.acknowledged, stats.resent) = (c.sent, c.acknowledged, c.resent);
        self.counts_into_sample();
    }

    /// The window's counts into the link's telemetry sample (its `ended`
    /// kept).
    fn counts_into_sample(&mut self) {
        let c = self.outbox.counts;
        self.tel.sample.work = c.sent;
        self.tel.sample.delivery = Delivery { ended: self.tel.sample.delivery.ended, ..c };
    }

    /// Waits up to `drain` for the head to acknowledge the window (a
    /// head that asks for batches again gets them), then sends the link's
    /// last count to the head, marked ended.
    pub(crate) fn finish(&mut self, drain: Duration) -> Result<()> {
        let t = Instant::now();
        while !self.outbox.is_empty() && t.elapsed() < drain {
            self.acks_in()?;
            std::thread::sleep(Duration::from_millis(2));
        }
        if !self.outbox.is_empty() {
            tracing::warn!("{} batches the head did not acknowledge are lost", self.outbox.len());
        }
        self.tel.sample.delivery.ended = 1;
        self.counts_into_sample();
        let last = Telemetry { index: self.slot, pid: 0, ..self.tel.sample };
        let _ = self
            .session
            .put(self.tel_pub.key_expr().clone(), Vec::new())
            .attachment(wire::header_bytes(&last).to_vec())
            .congestion_control(CongestionControl::Block)
            .wait();
        Ok(())
    }
}
