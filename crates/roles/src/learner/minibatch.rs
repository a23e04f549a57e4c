//! The minibatch in hand: each row's place and importance weight, and the
//! channel its new priorities go back on (prioritized replay).

use rotorhive_msg::{PICK_WORDS, Pick, PriorityHeader};
use rotorhive_transport::{Channel, Service};

use crate::config::Config;
use crate::ctx::STALL_TIMEOUT;
use crate::error::{Doing, Result};

/// The minibatch in hand, in the network's layout, and (prioritized
/// replay) the channel its TD errors go back on.
pub struct Minibatch<S: Service> {
    /// Each row's place and importance weight.
    pub picks: Vec<Pick>,
    /// Each row's importance weight (empty without prioritized replay).
    pub weights: Vec<f32>,
    prio_tx: Option<rotorhive_transport::Sender<S, u16, PriorityHeader>>,
}

impl<S: Service> Minibatch<S> {
    /// The picks and, under prioritized replay, the priorities' channel.
    pub fn new(hub: &rotorhive_transport::Hub<S>, cfg: &Config) -> Result<Self> {
        let prio_tx = if cfg.replay.prioritized {
            Some(hub.sender::<u16, PriorityHeader>(
                &Channel::priorities(cfg.replay.prefetch),
                cfg.replay.batch * PICK_WORDS,
                STALL_TIMEOUT,
            )?)
        } else {
            None
        };
        Ok(Self { picks: Vec::new(), weights: Vec::new(), prio_tx })
    }

    /// Each row's importance weight from its pick under prioritized replay
    /// (none otherwise: every row weighs 1).
    pub fn load_weights(&mut self) {
        self.weights.clear();
        if self.prio_tx.is_some() {
            self.weights.extend(self.picks.iter().map(|p| p.value));
        }
    }

    /// Sends minibatch `seq`'s new priorities (each row's |TD error|
    /// `td`) back under prioritized replay (none otherwise); a send that
    /// fails counts in `lost`.
    pub fn send_back(
        &mut self,
        td: &[f32],
        seq: u64,
        deterministic: bool,
        lost: &mut u64,
    ) -> Result<()> {
        match &mut self.prio_tx {
            Some(tx) => send_priorities(tx, &mut self.picks, td, seq, deterministic, lost),
            None => Ok(()),
        }
    }
}

/// Sends minibatch `seq`'s new priorities (each row's |TD error|) back to
/// the replay. A deterministic run cannot lose them (the replay waits for
/// them in order); otherwise a full queue costs only these priorities.
fn send_priorities<S: Service>(
    tx: &mut rotorhive_transport::Sender<S, u16, PriorityHeader>,
    picks: &mut [Pick],
    td: &[f32],
    seq: u64,
    deterministic: bool,
    lost: &mut u64,
) -> Result<()> {
    for (p, t) in picks.iter_mut().zip(td) {
        p.value = *t;
    }
    let n = picks.len().min(td.len());
    let sent = tx.send_with(n * PICK_WORDS, |h, out| {
        *h = PriorityHeader { count: n as u32, reserved: 0, seq };
        for (p, w) in picks.iter().zip(out.chunks_exact_mut(PICK_WORDS)) {
            p.pack(w);
        }
    });
    match sent {
        Ok(()) => Ok(()),
        Err(e) if deterministic => Err(e).doing("a deterministic run cannot lose priorities"),
        // A run that stops lets its replay go first: not a loss.
        Err(e) if rotorhive_transport::stop_requested() => {
            tracing::debug!("learner: priorities of minibatch {seq} sent as the run stopped: {e}");
            Ok(())
        }
        Err(e) => {
            tracing::warn!("learner: priorities of minibatch {seq} not sent: {e}");
            *lost += 1;
            Ok(())
        }
    }
}
