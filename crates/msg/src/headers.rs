//! The iceoryx2 user headers of every message a run sends, the payload
//! records beside them (picks, episode records, done codes) and the layout's
//! fingerprint that two hosts compare.

#[cfg(feature = "zero-copy")]
use iceoryx2::prelude::ZeroCopySend;

use crate::{STAGES, Shapes, Telemetry};

/// Why an agent's episode ended at a step; stored as `f32` in the observation
/// slice and as `u8` elsewhere.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DoneKind {
    /// The episode goes on.
    Running = 0,
    /// The drone touched an obstacle, a wall, the floor or (interactive) a drone.
    Collision = 1,
    /// The drone reached the end of the arena (with `[sim.goal]`: the goal).
    Goal = 2,
    /// The episode hit the step limit.
    Timeout = 3,
}

impl DoneKind {
    /// Decodes a stored code; unknown codes read as `Running`.
    pub fn from_code(code: u8) -> Self {
        match code {
            1 => Self::Collision,
            2 => Self::Goal,
            3 => Self::Timeout,
            _ => Self::Running,
        }
    }

    /// True when the episode ended.
    pub fn is_done(self) -> bool {
        self != Self::Running
    }
}

/// The most environments one host runs (`sim.envs`); a head believes no
/// joining worker of more.
pub const MAX_ENVS_PER_HOST: usize = 64;
/// The most agents one environment holds (`sim.agents`).
pub const MAX_AGENTS_PER_ENV: usize = 4096;

/// Header of an observation batch, sim → actor.
///
/// Payload: `[f32]` of length [`Shapes::obs_batch_len`]`(agents)`: `agents × obs_len`
/// observations, then `agents` rewards, then `agents` done codes
/// ([`DoneKind`] as `f32`), then `agents` teacher's actions (the action
/// the teacher flies the agent with from this observation, [`NO_EXPERT`]
/// where the student flies it), then `agents` labels (the teacher's
/// action for the student at this observation, [`NO_EXPERT`] where it
/// gives none). Rows of agents that were reset in this step hold the
/// first observation of their new episode.
#[derive(Debug, Clone, Copy, Default)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::ObsHeader"))]
#[repr(C)]
pub struct ObsHeader {
    /// Agents in this message: all of them in batched mode, one in
    /// non-batched mode.
    pub agents: u32,
    /// Index of the first agent in this message.
    pub first: u32,
    /// Agents of the environment (the step is complete once `total` agents'
    /// observations have arrived).
    pub total: u32,
    /// Unused; keeps the header free of padding.
    pub reserved: u32,
    /// Environment step this observation follows (0 after the initial reset).
    pub step: u64,
}

/// Header of an action batch, actor → sim. Payload: `[u8]`, one action per agent.
#[derive(Debug, Clone, Copy, Default)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::ActionHeader"))]
#[repr(C)]
pub struct ActionHeader {
    /// The observation step these actions answer.
    pub step: u64,
}

/// An `f32` as a packed row keeps it: its bits in two `u16` words, low
/// then high, written into `out[..2]`.
/// Header of a transition batch, actor → replay.
///
/// Payload: `[u16]` of `count × packed_len` ([`Shapes::packed_len`]), each
/// transition packed by [`Shapes::pack`].
// Pod: no padding and no invalid bit pattern (checked by the derive), so
// the link sends and reads it as bytes.
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::TransitionHeader"))]
#[repr(C)]
pub struct TransitionHeader {
    /// Actor index (= environment index).
    pub actor: u32,
    /// Transitions in the batch.
    pub count: u32,
    /// Per-actor batch sequence number, starting at 0 and increasing by one;
    /// a gap at the receiver is a lost batch.
    pub seq: u64,
    /// Weight version the acting policy used (for policy lag).
    pub weight_version: u64,
}

/// `u16` words of one [`Pick`] in a message: the row (2 words), its stamp
/// (2) and a value (an `f32`'s bits, 2).
pub const PICK_WORDS: usize = 6;

/// One sampled transition's place in the replay memory and a value: in a
/// minibatch, its importance-sampling weight; in a priorities message, the
/// learner's new priority (its absolute TD error). The stamp (the memory's
/// insert count when the row was written) lets the replay ignore a
/// priority for a row that has been overwritten since.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pick {
    /// Physical row of the replay memory.
    pub row: u32,
    /// The row's stamp when it was sampled.
    pub stamp: u32,
    /// Importance weight (minibatch) or priority (feedback).
    pub value: f32,
}

impl Pick {
    /// Writes the pick as [`PICK_WORDS`] little-endian words.
    pub fn pack(&self, out: &mut [u16]) {
        let v = self.value.to_bits();
        out[..PICK_WORDS].copy_from_slice(&[
            self.row as u16,
            (self.row >> 16) as u16,
            self.stamp as u16,
            (self.stamp >> 16) as u16,
            v as u16,
            (v >> 16) as u16,
        ]);
    }

    /// Reads a pick written by [`Pick::pack`].
    pub fn unpack(w: &[u16]) -> Self {
        let word = |k: usize| w[k] as u32 | (w[k + 1] as u32) << 16;
        Self { row: word(0), stamp: word(2), value: f32::from_bits(word(4)) }
    }
}

/// Header of a minibatch, replay → learner. Payload: `[u16]` of
/// `batch × packed_len` (packed transitions as in a transition batch), then
/// `batch × PICK_WORDS`: each row's [`Pick`] with its importance weight
/// (1 with uniform sampling).
#[derive(Debug, Clone, Copy, Default)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::MinibatchHeader"))]
#[repr(C)]
pub struct MinibatchHeader {
    /// Transitions in the minibatch.
    pub batch: u32,
    /// Transitions whose acting weight version is known (those restored
    /// from a snapshot are not).
    pub acted: u32,
    /// Sequence number of the minibatch.
    pub seq: u64,
    /// Sum of the weight versions the `acted` transitions were acted with
    /// (the learner's policy lag is its version minus their mean).
    pub acted_version_sum: u64,
    /// Rows drawn from the teacher's demonstrations (the first rows of the
    /// minibatch; see `teacher.demo_batch_share`).
    pub demo_rows: u32,
    /// The teacher's weight now, from 1 down to 0 over
    /// `teacher.fade_env_steps` of the replay's inserts (1 without a fade):
    /// the learner multiplies its margin loss's weight by it.
    pub teacher: f32,
}

/// Header of a priorities message, learner → replay (prioritized replay).
/// Payload: `[u16]` of `count × PICK_WORDS`, one [`Pick`] per row of
/// minibatch `seq`, its value the row's new priority.
#[derive(Debug, Clone, Copy, Default)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::PriorityHeader"))]
#[repr(C)]
pub struct PriorityHeader {
    /// Picks in the message.
    pub count: u32,
    /// Zero (keeps the header free of padding).
    pub reserved: u32,
    /// Sequence number of the minibatch they answer.
    pub seq: u64,
}

/// Header of a weights message, learner → actors. Payload: `[f32]`, the flat
/// parameters in the model's canonical order.
// Pod: no padding and no invalid bit pattern (checked by the derive), so
// the link sends and reads it as bytes.
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::WeightsHeader"))]
#[repr(C)]
pub struct WeightsHeader {
    /// Version, increasing with every publication (1 is the first).
    pub version: u64,
    /// Learner updates done when these weights were published.
    pub updates: u64,
    /// Number of floats in the payload.
    pub len: u64,
}

/// Floats per finished episode in an episodes message: return, steps,
/// [`DoneKind`] code, and the highest exploration rate the agent acted with
/// in the episode.
pub const EPISODE_FIELDS: usize = 4;

/// True when an episode record ([`EPISODE_FIELDS`] floats) is not what an
/// actor writes: a return that is not finite, a step count that is not a
/// whole number from 1 to 2^24, a done code other than collision, goal or
/// timeout, or an exploration rate outside 0..=1.
pub fn episode_corrupt(record: &[f32]) -> bool {
    let [ret, steps, done, eps] = record else {
        return true;
    };
    !ret.is_finite()
        || !(1.0..=16_777_216.0).contains(steps)
        || steps.fract() != 0.0
        || !matches!(*done as u8, 1..=3)
        || done.fract() != 0.0
        || !(0.0..=1.0).contains(eps)
}

/// Header of an episodes message, actor → supervisor. Payload: `[f32]`
/// records of [`EPISODE_FIELDS`] (return, steps, [`DoneKind`] code,
/// epsilon), one per finished episode.
// Pod: no padding and no invalid bit pattern (checked by the derive), so
// the link sends and reads it as bytes.
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::EpisodeHeader"))]
#[repr(C)]
pub struct EpisodeHeader {
    /// Actor index.
    pub actor: u32,
    /// Episodes in the message.
    pub count: u32,
    /// The actor's largest exploration rate in use ×1e6 (each agent's own
    /// is in its episode record).
    pub epsilon_micro: u64,
    /// The observation step the episodes ended on (a deterministic run's
    /// round).
    pub step: u64,
}

/// The replay's receipt for the batches its host's link brings (other
/// hosts' actors), replay → link: the head's link acknowledges a worker's
/// batch only once a receipt covers it. Header only (no payload).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::Receipt"))]
#[repr(C)]
pub struct Receipt {
    /// Drawn by the replay process at its start: a new one says the replay
    /// restarted, and that what its predecessor's queue held is gone.
    pub incarnation: u64,
    /// Batches of other hosts' actors this replay process has taken.
    pub batches: u64,
    /// The newest of them: its actor and the actor's sequence number.
    pub actor: u64,
    /// See `actor`.
    pub seq: u64,
}

impl Receipt {
    /// Takes note of a batch of another host's actor.
    pub fn took(&mut self, h: &TransitionHeader) {
        self.batches += 1;
        (self.actor, self.seq) = (h.actor as u64, h.seq);
    }
}

/// A fingerprint of the message layout: every header's size and every
/// payload length this build sends. Two hosts carry messages as raw bytes,
/// so they must agree on it (the link refuses a host whose layout differs).
/// Of the paper's task's shapes: a run's own come with its config.
pub fn layout_fingerprint() -> u64 {
    let shapes = Shapes::PAPER;
    use std::mem::size_of;
    let parts = [
        size_of::<ObsHeader>(),
        size_of::<ActionHeader>(),
        size_of::<TransitionHeader>(),
        size_of::<MinibatchHeader>(),
        size_of::<WeightsHeader>(),
        size_of::<EpisodeHeader>(),
        size_of::<Telemetry>(),
        size_of::<PriorityHeader>(),
        PICK_WORDS,
        shapes.obs_len(),
        shapes.packed_len(),
        shapes.actions,
        STAGES,
        DoneKind::Timeout as usize,
        EPISODE_FIELDS,
    ];
    // FNV-1a over the little-endian values.
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for b in parts.iter().flat_map(|v| (*v as u64).to_le_bytes()) {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Delivery, Learning, TeacherCounts};
    #[test]
    fn layouts_are_stable() {
        // Headers cross process boundaries, so their sizes are part of the contract.
        assert_eq!(std::mem::size_of::<ObsHeader>(), 24);
        assert_eq!(std::mem::size_of::<ActionHeader>(), 8);
        assert_eq!(std::mem::size_of::<TransitionHeader>(), 24);
        assert_eq!(std::mem::size_of::<MinibatchHeader>(), 32);
        assert_eq!(std::mem::size_of::<WeightsHeader>(), 24);
        assert_eq!(std::mem::size_of::<Telemetry>(), 208);
        assert_eq!(std::mem::size_of::<TeacherCounts>(), 48);
        assert_eq!(std::mem::size_of::<Delivery>(), 32);
        assert_eq!(std::mem::size_of::<Learning>(), 32);
        assert_eq!(std::mem::size_of::<PriorityHeader>(), 16);
    }

    #[test]
    fn picks_round_trip() {
        let p = Pick { row: 0x0012_3456, stamp: u32::MAX - 5, value: -0.375 };
        let mut w = [0u16; PICK_WORDS];
        p.pack(&mut w);
        assert_eq!(Pick::unpack(&w), p);
    }

    #[test]
    fn done_codes_round_trip() {
        for kind in [DoneKind::Running, DoneKind::Collision, DoneKind::Goal, DoneKind::Timeout] {
            assert_eq!(DoneKind::from_code(kind as u8), kind);
        }
        assert!(!DoneKind::Running.is_done());
        assert!(DoneKind::Timeout.is_done());
    }
}
