//! Telemetry: the one sample every role sends about once a second (its
//! counters, stage timers, learning diagnostics, delivery between hosts and
//! the teacher's counts), the roles it comes from and their stages.

#[cfg(feature = "zero-copy")]
use iceoryx2::prelude::ZeroCopySend;

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
    /// The link of a host (`hive train --listen`, `hive worker`).
    Link = 4,
}

impl RoleKind {
    /// Decodes a stored code.
    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            0 => Some(Self::Sim),
            1 => Some(Self::Actor),
            2 => Some(Self::Replay),
            3 => Some(Self::Learner),
            4 => Some(Self::Link),
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
            Self::Link => "link",
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
// Pod: no padding and no invalid bit pattern (checked by the derive), so
// the link sends and reads it as bytes.
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::Telemetry"))]
#[repr(C)]
pub struct Telemetry {
    /// [`RoleKind`] code.
    pub role: u32,
    /// Instance index (environment index for sims and actors).
    pub index: u32,
    /// Process id of the role.
    pub pid: u32,
    /// Learner: mean policy lag of its minibatches since the previous
    /// sample, ×1000 weight versions; 0 for the other roles.
    pub policy_lag_milli: u32,
    /// Heartbeat: samples sent so far.
    pub heartbeat: u64,
    /// Main work counter (env steps, transitions, minibatches, updates).
    pub work: u64,
    /// Secondary counter (episodes, samples, weight publications).
    pub work2: u64,
    /// Weight version in use (actor) or published (learner).
    pub weight_version: u64,
    /// What the role counted lost: the replay, transitions of this host's
    /// actors (sequence gaps, at the size of the batch after the gap, and
    /// corrupt ones); an actor, messages it gave up or found missing; the
    /// head's link, transitions missing from another host's actors.
    pub lost: u64,
    /// Role's gauge: epsilon ×1000 (actor), replay size (replay), mean loss of the updates
    /// since the previous sample ×1e6 (learner); 0 for sims.
    pub value_milli: i64,
    /// Cumulative nanoseconds per stage.
    pub stage_ns: [u64; STAGES],
    /// Learning diagnostics (learner) or the exploration spread (actor).
    pub learning: Learning,
    /// Delivery between hosts (a worker's link).
    pub delivery: Delivery,
    /// What the teacher did (sims and actors; zero without one).
    pub teacher: TeacherCounts,
}

/// What a run's teacher did, cumulative since the role started: a sim
/// fills what its planner computed and what it cost, an actor what it
/// sent, the replay what it holds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::TeacherCounts"))]
#[repr(C)]
pub struct TeacherCounts {
    /// Sim: the planner's actions for the student's agents (labels).
    pub labels: u64,
    /// Sim: the planner's actions for the agents it flies (demonstrations).
    pub demo_steps: u64,
    /// Sim: nanoseconds the planner spent on labels.
    pub label_ns: u64,
    /// Sim: nanoseconds the planner spent on the agents it flies.
    pub demo_ns: u64,
    /// Actor: transitions sent flown by the teacher; replay: demonstrations
    /// held in its reservoir.
    pub demo_transitions: u64,
    /// Actor: the student's transitions sent with the teacher's label.
    pub labelled_transitions: u64,
}

/// What a worker's link says of its delivery to the head, in transitions,
/// counted since its join (the other roles leave it zero).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::Delivery"))]
#[repr(C)]
pub struct Delivery {
    /// Transitions sent a first time.
    pub sent: u64,
    /// Transitions the head acknowledged (its replay took them).
    pub acknowledged: u64,
    /// Transitions sent again (asked for again, or after the session came back).
    pub resent: u64,
    /// 1 on the link's last sample: it sends no more (the run ended, or
    /// it was stopped), and what it sent but saw unacknowledged is lost.
    pub ended: u64,
}

/// What a telemetry sample says about learning, so that a collapse can be
/// seen as it starts. The learner fills the means over its updates since
/// the previous sample; an actor fills the smallest and largest epsilon of
/// its agents; the other roles leave it zero.
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[cfg_attr(feature = "zero-copy", derive(ZeroCopySend), type_name("rotorhive::Learning"))]
#[repr(C)]
pub struct Learning {
    /// Learner: mean over the minibatches' rows of max_a Q(s, a), in reward
    /// units (divided by `learner.reward_scale`).
    pub mean_max_q: f32,
    /// Learner: mean absolute TD error, in reward units.
    pub mean_abs_td: f32,
    /// Learner: share of terminal transitions in the minibatches.
    pub terminal_share: f32,
    /// Learner: updates skipped so far for a non-finite loss or gradient.
    pub skipped_updates: u32,
    /// Actor: the smallest epsilon of its agents.
    pub eps_min: f32,
    /// Actor: the largest epsilon of its agents.
    pub eps_max: f32,
    /// Replay: priority updates applied so far.
    pub priority_updates: u32,
    /// Replay: priority updates dropped so far because their row had been
    /// overwritten since it was sampled (or was out of range).
    pub stale_priorities: u32,
}

/// A stage timer of one role: its place in `Telemetry::stage_ns`.
pub trait Stage: Copy {
    /// The stage's index in `stage_ns`.
    fn index(self) -> usize;
}

macro_rules! stages {
    ($(#[$doc:meta])* $name:ident { $($v:ident = $word:literal),* $(,)? }) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum $name {
            $(
                #[doc = concat!("`", $word, "`")]
                $v,
            )*
        }
        impl $name {
            /// The stages' names, in `stage_ns` order.
            pub const NAMES: [&'static str; STAGES] = [$($word),*];
        }
        impl Stage for $name {
            fn index(self) -> usize {
                self as usize
            }
        }
    };
}

stages!(
    /// A simulator's stages.
    SimStage { Physics = "physics", Render = "render", Reset = "reset", TransportWait = "transport_wait" }
);
stages!(
    /// An actor's stages.
    ActorStage { Inference = "inference", Assemble = "assemble", Weights = "weights", TransportWait = "transport_wait" }
);
stages!(
    /// The replay's stages.
    ReplayStage { Insert = "insert", Sample = "sample", Idle = "idle", TransportWait = "transport_wait" }
);
stages!(
    /// The learner's stages.
    LearnerStage { Forward = "forward", Backward = "backward", Optimiser = "optimiser", TransportWait = "transport_wait" }
);
stages!(
    /// A link's stages.
    LinkStage { Receive = "receive", Forward = "forward", Weights = "weights", SendWait = "send_wait" }
);

impl Telemetry {
    /// Adds `ns` nanoseconds to `stage`.
    pub fn add_stage(&mut self, stage: impl Stage, ns: u64) {
        self.stage_ns[stage.index()] += ns;
    }

    /// Adds the time since `since` to `stage`.
    pub fn time_stage(&mut self, stage: impl Stage, since: std::time::Instant) {
        self.add_stage(stage, since.elapsed().as_nanos() as u64);
    }

    /// Marks one more sample sent.
    pub fn beat(&mut self) {
        self.heartbeat += 1;
    }
}

/// Names of the four stage timers of a role, in `stage_ns` order.
pub fn stage_names(role: RoleKind) -> [&'static str; STAGES] {
    match role {
        RoleKind::Sim => SimStage::NAMES,
        RoleKind::Actor => ActorStage::NAMES,
        RoleKind::Replay => ReplayStage::NAMES,
        RoleKind::Learner => LearnerStage::NAMES,
        RoleKind::Link => LinkStage::NAMES,
    }
}
