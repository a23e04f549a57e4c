//! Plain-data messages that cross process boundaries.
//!
//! Every type here is `#[repr(C)]`, `ZeroCopySend` and carries a stable
//! `#[type_name]`, so iceoryx2 can place it in shared memory and a process of
//! another build can check it is reading the same layout. A tensor message is a
//! header struct (the iceoryx2 *user header*) plus a slice payload of `f32`, `u16` or
//! `u8`; the layouts of those slices are documented on each header and computed
//! by the helpers below, so the sender and the receiver never disagree.
//!
//! This crate is the only one that derives `ZeroCopySend` (besides test-only
//! headers), and only with its `zero-copy` feature: without it the crate is
//! the layout alone (constants, packing, done codes) and needs no iceoryx2,
//! so the domain crates (the model) take their layout from here too.

#[cfg(feature = "zero-copy")]
use iceoryx2::prelude::ZeroCopySend;

mod counters;
pub mod durable;
mod label;
pub mod protobuf;
mod sequence;
mod telemetry;

pub use counters::Counters;
pub use label::{LABEL_SET, label_action, label_mask, label_of_mask};
pub use sequence::{RowLayout, SeqLayout, Unpacked};
pub use telemetry::{
    ActorStage, Delivery, LearnerStage, Learning, LinkStage, ReplayStage, RoleKind, STAGES,
    SimStage, Stage, TeacherCounts, Telemetry, stage_names,
};

/// Side of one square depth image, in pixels.
pub const DEPTH_SIDE: usize = 32;
/// Pixels in one depth image.
pub const DEPTH_PIXELS: usize = DEPTH_SIDE * DEPTH_SIDE;
/// Depth frames stacked in one observation of the paper's task (previous
/// and current); `sim.frames` sets another count ([`Shapes::frames`]).
pub const FRAMES: usize = 2;
/// The most depth frames an observation stacks (`sim.frames`).
pub const MAX_FRAMES: usize = 8;
/// The most action periods between two stacked frames (`sim.frame_stride`).
pub const MAX_FRAME_STRIDE: usize = 8;
/// Components of the body-frame linear velocity in an observation.
pub const VEL_DIM: usize = 3;
/// Floats of the goal in an observation of a task with a goal
/// (`[sim.goal]`): its bearing (rad, body frame), its distance and its
/// lateral offset (body frame), both in tens of metres.
pub const GOAL_DIM: usize = 3;
/// The most floats the camera's map (`[sim.map]`) may add to an
/// observation's scalars.
pub const MAX_MAP_FLOATS: usize = 1024;
/// Floats after `s` and `s'` in a transition: the action taken, the
/// (n-step) reward, done (0 or 1), the teacher's label at `s` (the action
/// it holds the only right one there, or the set it holds best, see
/// [`label_mask`]; [`NO_EXPERT`] where it gave none)
/// and whether the teacher flew the step (1: a demonstration, 0: the
/// student's).
pub const TAIL: usize = 5;
/// The expert action of a transition or observation the teacher did not
/// label.
pub const NO_EXPERT: f32 = -1.0;
/// Number of discrete actions of the paper's task (lateral velocity
/// −0.25 m/s, +0.25 m/s); a task with the hold action has a third.
pub const NUM_ACTIONS: usize = 2;

/// The shapes of a run's observations and actions, taken from its config
/// (`Config::shapes` in the roles): every layout that depends on them
/// (observation batches, transitions as they travel and as the learner reads
/// them, the network's input and output) is computed here from one value,
/// so a sender and a receiver of one run never disagree.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Shapes {
    /// Depth frames stacked in one observation, oldest first (`stride`
    /// action periods apart; the last is the current view).
    pub frames: usize,
    /// Action periods between two stacked frames (1: consecutive views).
    /// No layout depends on it, but a network trained on one stride reads
    /// another's observations wrongly, so checkpoints say it too.
    pub stride: usize,
    /// Floats after the depth frames: the body-frame velocity, then (with a
    /// goal) the goal's [`GOAL_DIM`] floats, then the camera's map's
    /// [`Shapes::map`] floats.
    pub scalars: usize,
    /// Discrete actions.
    pub actions: usize,
    /// Floats of the camera's map at the end of the scalars (0: no map).
    pub map: usize,
}

impl Shapes {
    /// The paper's task: velocity only, two actions.
    pub const PAPER: Shapes =
        Shapes { frames: FRAMES, stride: 1, scalars: VEL_DIM, actions: NUM_ACTIONS, map: 0 };
    /// The most actions any task has.
    pub const MAX_ACTIONS: usize = NUM_ACTIONS + 1;

    /// The shapes of a task: `frames` consecutive depth frames, with or
    /// without a goal in the observation, with or without the hold action.
    pub const fn task(frames: usize, goal: bool, hold: bool) -> Self {
        Self {
            frames,
            stride: 1,
            scalars: VEL_DIM + if goal { GOAL_DIM } else { 0 },
            actions: NUM_ACTIONS + hold as usize,
            map: 0,
        }
    }

    /// The same shapes with `floats` of the camera's map after the other
    /// scalars (replacing any map they had).
    pub const fn with_map(self, floats: usize) -> Self {
        Self { scalars: self.scalars - self.map + floats, map: floats, ..self }
    }

    /// Whether the observation holds a goal's [`GOAL_DIM`] floats (after
    /// the velocity, before the map).
    pub const fn goal(self) -> bool {
        self.scalars >= self.map + VEL_DIM + GOAL_DIM
    }

    /// The same shapes with the stacked frames `stride` action periods apart.
    pub const fn with_stride(self, stride: usize) -> Self {
        Self { stride, ..self }
    }

    /// Depth values in one observation: the stacked frames.
    pub const fn obs_depth(self) -> usize {
        self.frames * DEPTH_PIXELS
    }

    /// Depth values in one packed transition: the frames of `s`, then
    /// those of `s'`.
    pub const fn packed_depth(self) -> usize {
        2 * self.obs_depth()
    }

    /// Floats in one observation: the stacked depth frames, then the scalars.
    pub const fn obs_len(self) -> usize {
        self.obs_depth() + self.scalars
    }

    /// Length of the `f32` payload of an observation batch of `agents`:
    /// their observations, rewards, done codes, the teacher's actions
    /// (where it flies the agent) and its labels.
    pub const fn obs_batch_len(self, agents: usize) -> usize {
        agents * (self.obs_len() + 4)
    }

    /// Floats in one transition as the learner uses it: `s (obs_len) | s'
    /// (obs_len) |` the [`TAIL`] floats (action, reward, done, expert, demo).
    pub const fn transition_len(self) -> usize {
        2 * self.obs_len() + TAIL
    }

    /// `f32` scalars in one packed transition: `s`'s scalars, `s'`'s, then
    /// the [`TAIL`] floats.
    pub const fn packed_scalars(self) -> usize {
        2 * self.scalars + TAIL
    }

    /// `u16` words in one packed transition, as transitions travel (actor →
    /// replay → learner) and as the replay stores them: depth as 16-bit
    /// fixed point (normalised depth × 65,535, rounded: 0.3 mm at a 20 m
    /// range, far under the renderers' 1 cm agreement), then each scalar's
    /// `f32` bits as two words (low, high). Half the bytes of
    /// [`Shapes::transition_len`] floats.
    pub const fn packed_len(self) -> usize {
        self.packed_depth() + 2 * self.packed_scalars()
    }

    /// The `i`-th scalar of a packed transition (`0..scalars` `s`'s,
    /// `scalars..2 × scalars` `s'`'s, then the [`TAIL`]): two `u16`
    /// words after the depth, low then high.
    #[inline]
    pub fn packed_scalar(self, p: &[u16], i: usize) -> f32 {
        word_f32(&p[self.packed_depth() + 2 * i..])
    }

    /// Packs one transition given as its parts (`s` and `s'` of
    /// [`Shapes::obs_len`] floats each, then the [`TAIL`]: action, reward,
    /// done, expert action, demonstration flag) into `out`
    /// ([`Shapes::packed_len`] words).
    pub fn pack(self, s: &[f32], next: &[f32], tail: [f32; TAIL], out: &mut [u16]) {
        let n = self.obs_len();
        assert!(
            s.len() == n && next.len() == n && out.len() == self.packed_len(),
            "pack: wrong lengths"
        );
        let fd = self.obs_depth();
        let (depth, scalars) = out.split_at_mut(self.packed_depth());
        for (o, v) in depth[..fd].iter_mut().zip(&s[..fd]) {
            *o = quantize_depth(*v);
        }
        for (o, v) in depth[fd..].iter_mut().zip(&next[..fd]) {
            *o = quantize_depth(*v);
        }
        let values = s[fd..].iter().chain(&next[fd..]).copied().chain(tail);
        for (o, v) in scalars.chunks_exact_mut(2).zip(values) {
            f32_words(v, o);
        }
    }

    /// Unpacks one transition ([`Shapes::packed_len`] words) into `out`
    /// ([`Shapes::transition_len`] floats, the learner's layout).
    pub fn unpack(self, p: &[u16], out: &mut [f32]) {
        assert!(
            p.len() == self.packed_len() && out.len() == self.transition_len(),
            "unpack: wrong lengths"
        );
        let (fd, k) = (self.obs_depth(), self.scalars);
        let (s, rest) = out.split_at_mut(self.obs_len());
        let (next, tail) = rest.split_at_mut(self.obs_len());
        for (o, q) in s[..fd].iter_mut().zip(&p[..fd]) {
            *o = dequantize_depth(*q);
        }
        for (o, q) in next[..fd].iter_mut().zip(&p[fd..2 * fd]) {
            *o = dequantize_depth(*q);
        }
        for j in 0..k {
            s[fd + j] = self.packed_scalar(p, j);
            next[fd + j] = self.packed_scalar(p, k + j);
        }
        for (j, o) in tail.iter_mut().enumerate() {
            *o = self.packed_scalar(p, 2 * k + j);
        }
    }

    /// True when a packed transition's scalars ([`Shapes::packed_scalars`]
    /// of them, see [`Shapes::packed_scalar`]) are not what an actor writes: an
    /// action that is not one of the run's, a done flag other than 0 or 1,
    /// a label that is none of [`label_mask`]'s,
    /// a demonstration flag other than 0 or 1, or a scalar that is not
    /// finite. A torn or forged write shows
    /// here (16-bit depth has no invalid value to look for).
    pub fn scalars_corrupt(self, scalars: &[f32]) -> bool {
        if scalars.len() != self.packed_scalars() {
            return true;
        }
        let tail = &scalars[2 * self.scalars..];
        let (action, done, expert, demo) = (tail[0], tail[2], tail[3], tail[4]);
        let one_of = |a: f32| a >= 0.0 && a < self.actions as f32 && a.fract() == 0.0;
        let flag = |f: f32| f == 0.0 || f == 1.0;
        !one_of(action)
            || !flag(done)
            || label_mask(expert, self.actions).is_none()
            || !flag(demo)
            || scalars.iter().any(|v| !v.is_finite())
    }

    /// Corrupt transitions (by [`Shapes::scalars_corrupt`]) in a batch of
    /// packed ones.
    pub fn corrupt_transitions(self, batch: &[u16]) -> u64 {
        let mut s = vec![0f32; self.packed_scalars()];
        batch
            .chunks_exact(self.packed_len())
            .filter(|t| {
                for (k, v) in s.iter_mut().enumerate() {
                    *v = self.packed_scalar(t, k);
                }
                self.scalars_corrupt(&s)
            })
            .count() as u64
    }

    /// Checks that the shapes are ones a task has (as a checkpoint's header
    /// claims them): 1 to [`MAX_FRAMES`] depth frames, the velocity with or
    /// without the goal, two actions or three.
    pub fn check(self) -> Result<Self, String> {
        if !(1..=MAX_FRAMES).contains(&self.frames) {
            return Err(format!("{} depth frames (1 to {MAX_FRAMES})", self.frames));
        }
        if !(1..=MAX_FRAME_STRIDE).contains(&self.stride) {
            return Err(format!(
                "a frame stride of {} action periods (1 to {MAX_FRAME_STRIDE})",
                self.stride
            ));
        }
        if self.map > MAX_MAP_FLOATS {
            return Err(format!("{} floats of the map (at most {MAX_MAP_FLOATS})", self.map));
        }
        let task = self.scalars.checked_sub(self.map);
        if task != Some(VEL_DIM) && task != Some(VEL_DIM + GOAL_DIM) {
            return Err(format!(
                "{} observation scalars with {} of the map (a task has {VEL_DIM}, or {} with \
                 a goal, then the map's)",
                self.scalars,
                self.map,
                VEL_DIM + GOAL_DIM
            ));
        }
        if !(NUM_ACTIONS..=Self::MAX_ACTIONS).contains(&self.actions) {
            return Err(format!(
                "{} actions (a task has {NUM_ACTIONS}, or {} with hold)",
                self.actions,
                Self::MAX_ACTIONS
            ));
        }
        Ok(self)
    }
}

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
#[inline]
pub(crate) fn f32_words(v: f32, out: &mut [u16]) {
    let b = v.to_bits();
    out[0] = b as u16;
    out[1] = (b >> 16) as u16;
}

/// The `f32` whose bits are `w[0]` (low) and `w[1]` (high): what
/// [`f32_words`] wrote.
#[inline]
pub(crate) fn word_f32(w: &[u16]) -> f32 {
    f32::from_bits(w[0] as u32 | (w[1] as u32) << 16)
}

/// A normalised depth in [0, 1] as 16-bit fixed point (clamped).
#[inline]
pub fn quantize_depth(d: f32) -> u16 {
    (d.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16
}

/// The normalised depth of a 16-bit fixed-point value, in [0, 1].
#[inline]
pub fn dequantize_depth(q: u16) -> f32 {
    q as f32 / 65535.0
}

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
    fn what_an_honest_actor_never_writes_is_corrupt() {
        let shapes = Shapes::PAPER;
        let obs = vec![0.5f32; shapes.obs_len()];
        let len = shapes.packed_len();
        let mut batch = vec![0u16; 11 * len];
        for (t, (a, r, d, e, demo)) in batch.chunks_exact_mut(len).zip([
            (1.0, 3.0, 0.0, NO_EXPERT, 0.0),
            (1.0, 3.0, 0.0, 0.0, 1.0),
            (0.0, 3.0, 1.0, 1.0, 0.0),
            (0.5, 3.0, 0.0, NO_EXPERT, 0.0),
            (0.0, f32::NAN, 1.0, NO_EXPERT, 0.0),
            (0.0, -100.0, 2.0, NO_EXPERT, 0.0),
            (0.0, -100.0, 1.0, NO_EXPERT, 0.0),
            (2.0, 3.0, 0.0, NO_EXPERT, 0.0),
            // A demonstration without a label (fine), an expert action
            // out of range, a flag neither 0 nor 1.
            (0.0, 3.0, 0.0, NO_EXPERT, 1.0),
            (0.0, 3.0, 0.0, 2.0, 0.0),
            (0.0, 3.0, 0.0, 0.0, 0.5),
        ]) {
            shapes.pack(&obs, &obs, [a, r, d, e, demo], t);
        }
        assert_eq!(shapes.corrupt_transitions(&batch[..3 * len]), 0);
        assert_eq!(shapes.corrupt_transitions(&batch), 6, "action 2 without hold");
        // With the hold action, action 2 is one of the task's.
        let hold = Shapes::task(FRAMES, false, true);
        assert_eq!(hold.packed_len(), len);
        assert_eq!(hold.corrupt_transitions(&batch), 4);
        assert!(!episode_corrupt(&[-100.0, 12.0, 1.0, 0.4]));
        assert!(!episode_corrupt(&[450.0, 150.0, 3.0, 0.0]));
        for bad in [
            [f32::NAN, 1.0, 1.0, 0.1],
            [1.0, 0.0, 1.0, 0.1],
            [1.0, 2.5, 1.0, 0.1],
            [1.0, 2.0, 0.0, 0.1],
            [1.0, 2.0, 4.0, 0.1],
            [1.0, 2.0, 1.0, -0.1],
        ] {
            assert!(episode_corrupt(&bad), "{bad:?}");
        }
        assert!(episode_corrupt(&[1.0, 2.0, 1.0]));
    }

    #[test]
    fn packed_transitions_round_trip_within_the_fixed_point_step() {
        // A task with four frames and a goal: six scalars per observation.
        let shapes = Shapes::task(4, true, true);
        let (obs_len, fd) = (shapes.obs_len(), shapes.obs_depth());
        assert_eq!(obs_len, 4 * 1024 + 6);
        assert_eq!(shapes.packed_len(), 2 * 4 * 1024 + 2 * (2 * 6 + TAIL));
        let s: Vec<f32> = (0..obs_len)
            .map(|i| if i < fd { (i as f32 * 0.618).fract() } else { -1.5 + i as f32 })
            .collect();
        let next: Vec<f32> = (0..obs_len)
            .map(|i| if i < fd { 1.0 - (i as f32 * 0.377).fract() } else { 0.25 * i as f32 })
            .collect();
        let mut p = vec![0u16; shapes.packed_len()];
        shapes.pack(&s, &next, [2.0, -100.0, 1.0, 1.0, 1.0], &mut p);
        let mut t = vec![0f32; shapes.transition_len()];
        shapes.unpack(&p, &mut t);
        for (a, b) in
            t[..fd].iter().zip(&s[..fd]).chain(t[obs_len..obs_len + fd].iter().zip(&next[..fd]))
        {
            assert!((a - b).abs() <= 0.5 / 65535.0 + 1e-7, "{a} vs {b}");
            assert!((0.0..=1.0).contains(a));
        }
        // Scalars travel bit for bit.
        assert_eq!(&t[fd..obs_len], &s[fd..]);
        assert_eq!(&t[obs_len + fd..2 * obs_len], &next[fd..]);
        assert_eq!(&t[2 * obs_len..], &[2.0, -100.0, 1.0, 1.0, 1.0]);
        assert_eq!(
            (dequantize_depth(quantize_depth(0.0)), dequantize_depth(quantize_depth(1.0))),
            (0.0, 1.0)
        );
        assert_eq!(quantize_depth(7.0), u16::MAX);
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
