//! Plain-data messages that cross process boundaries.
//!
//! Every type here is `#[repr(C)]`, `ZeroCopySend` and carries a stable
//! `#[type_name]`, so iceoryx2 can place it in shared memory and a process of
//! another build can check it is reading the same layout. A tensor message is a
//! header struct (the iceoryx2 *user header*) plus a slice payload of `f32` or
//! `u8`; the layouts of those slices are documented on each header and computed
//! by the helpers below, so the sender and the receiver never disagree.
//!
//! This crate is the only one that derives `ZeroCopySend`.

use iceoryx2::prelude::ZeroCopySend;

/// Side of one square depth image, in pixels.
pub const DEPTH_SIDE: usize = 32;
/// Pixels in one depth image.
pub const DEPTH_PIXELS: usize = DEPTH_SIDE * DEPTH_SIDE;
/// Depth frames stacked in one observation (previous and current).
pub const FRAMES: usize = 2;
/// Components of the body-frame linear velocity in an observation.
pub const VEL_DIM: usize = 3;
/// Floats in one observation: the stacked depth frames, then the velocity.
pub const OBS_LEN: usize = FRAMES * DEPTH_PIXELS + VEL_DIM;
/// Number of discrete actions (lateral velocity −0.25 m/s, +0.25 m/s).
pub const NUM_ACTIONS: usize = 2;

/// Why an agent's episode ended at a step; stored as `f32` in the observation
/// slice and as `u8` elsewhere.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DoneKind {
    /// The episode goes on.
    Running = 0,
    /// The drone touched an obstacle, a wall, the floor or (interactive) a drone.
    Collision = 1,
    /// The drone reached the end of the arena.
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

/// Header of an observation batch, sim → actor.
///
/// Payload: `[f32]` of length [`obs_batch_len`]`(agents)`: `agents × OBS_LEN`
/// observations, then `agents` rewards, then `agents` done codes
/// ([`DoneKind`] as `f32`). Rows of agents that were reset in this step hold the
/// first observation of their new episode.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("rotorhive::ObsHeader")]
#[repr(C)]
pub struct ObsHeader {
    /// Environment (sim process) index.
    pub env: u32,
    /// Agents in this message: all of them in batched mode, one in
    /// non-batched mode.
    pub agents: u32,
    /// Index of the first agent in this message.
    pub first: u32,
    /// Agents of the environment (the step is complete once `total` agents'
    /// observations have arrived).
    pub total: u32,
    /// Environment step this observation follows (0 after the initial reset).
    pub step: u64,
    /// Nanoseconds the sim spent on physics for this step.
    pub physics_ns: u64,
    /// Nanoseconds the sim spent rendering depth for this step.
    pub render_ns: u64,
}

/// Length of the `f32` payload of an observation batch.
pub const fn obs_batch_len(agents: usize) -> usize {
    agents * (OBS_LEN + 2)
}

/// Header of an action batch, actor → sim. Payload: `[u8]`, one action per agent.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("rotorhive::ActionHeader")]
#[repr(C)]
pub struct ActionHeader {
    /// Environment index.
    pub env: u32,
    /// Agents in the batch.
    pub agents: u32,
    /// The observation step these actions answer.
    pub step: u64,
}

/// Floats in one stored transition: `s`, `s'`, action, reward, done.
pub const TRANSITION_LEN: usize = 2 * OBS_LEN + 3;

/// Header of a transition batch, actor → replay.
///
/// Payload: `[f32]` of `count × TRANSITION_LEN`, each transition laid out as
/// `s (OBS_LEN) | s' (OBS_LEN) | action | reward | done (0 or 1)`.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("rotorhive::TransitionHeader")]
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
    /// Episodes this actor has finished so far.
    pub episodes: u64,
}

/// Header of a minibatch, replay → learner. Payload: `[f32]` of
/// `batch × TRANSITION_LEN`, laid out like a transition batch.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("rotorhive::MinibatchHeader")]
#[repr(C)]
pub struct MinibatchHeader {
    /// Transitions in the minibatch.
    pub batch: u32,
    /// Padding for a stable layout.
    pub _pad: u32,
    /// Sequence number of the minibatch.
    pub seq: u64,
    /// Transitions in the replay memory when it was sampled.
    pub replay_len: u64,
    /// Transitions inserted into the replay memory so far.
    pub inserted: u64,
}

/// Header of a weights message, learner → actors. Payload: `[f32]`, the flat
/// parameters in the model's canonical order.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("rotorhive::WeightsHeader")]
#[repr(C)]
pub struct WeightsHeader {
    /// Version, increasing with every publication (1 is the first).
    pub version: u64,
    /// Learner updates done when these weights were published.
    pub updates: u64,
    /// Number of floats in the payload.
    pub len: u64,
}

/// The role a telemetry sample comes from.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RoleKind {
    /// `hive sim`.
    Sim = 0,
    /// `hive actor`.
    Actor = 1,
    /// `hive replay`.
    Replay = 2,
    /// `hive learner`.
    Learner = 3,
}

impl RoleKind {
    /// Decodes a stored code.
    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            0 => Some(Self::Sim),
            1 => Some(Self::Actor),
            2 => Some(Self::Replay),
            3 => Some(Self::Learner),
            _ => None,
        }
    }

    /// Lower-case name, as used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Sim => "sim",
            Self::Actor => "actor",
            Self::Replay => "replay",
            Self::Learner => "learner",
        }
    }
}

/// Number of stage timers in a telemetry sample.
pub const STAGES: usize = 4;

/// A telemetry sample, every role → `hive train`, about once per second.
///
/// Counters are cumulative since the role started; stage times are cumulative
/// nanoseconds. What each counter and stage means depends on the role (see
/// `stage_names`).
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("rotorhive::Telemetry")]
#[repr(C)]
pub struct Telemetry {
    /// [`RoleKind`] code.
    pub role: u32,
    /// Instance index (environment index for sims and actors).
    pub index: u32,
    /// Process id of the role.
    pub pid: u32,
    /// Padding for a stable layout.
    pub _pad: u32,
    /// Heartbeat: samples sent so far.
    pub heartbeat: u64,
    /// Main work counter (env steps, transitions, minibatches, updates).
    pub work: u64,
    /// Secondary counter (episodes, samples, weight publications).
    pub work2: u64,
    /// Weight version in use (actor) or published (learner).
    pub weight_version: u64,
    /// Lost messages detected by sequence gaps.
    pub lost: u64,
    /// Role's gauge: epsilon ×1000 (actor), replay size (replay), mean loss of the updates
    /// since the previous sample ×1e6 (learner); 0 for sims.
    pub value_milli: i64,
    /// Cumulative nanoseconds per stage.
    pub stage_ns: [u64; STAGES],
}

/// Names of the four stage timers of a role, in `stage_ns` order.
pub fn stage_names(role: RoleKind) -> [&'static str; STAGES] {
    match role {
        RoleKind::Sim => ["physics", "render", "reset", "transport_wait"],
        RoleKind::Actor => ["inference", "assemble", "weights", "transport_wait"],
        RoleKind::Replay => ["insert", "sample", "idle", "transport_wait"],
        RoleKind::Learner => ["forward", "backward", "optimiser", "transport_wait"],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_are_stable() {
        // Headers cross process boundaries, so their sizes are part of the contract.
        assert_eq!(std::mem::size_of::<ObsHeader>(), 40);
        assert_eq!(std::mem::size_of::<ActionHeader>(), 16);
        assert_eq!(std::mem::size_of::<TransitionHeader>(), 32);
        assert_eq!(std::mem::size_of::<MinibatchHeader>(), 32);
        assert_eq!(std::mem::size_of::<WeightsHeader>(), 24);
        assert_eq!(std::mem::size_of::<Telemetry>(), 96);
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
