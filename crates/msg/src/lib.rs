//! Plain-data messages that cross process boundaries.
//!
//! Every type here is `#[repr(C)]`, `ZeroCopySend` and carries a stable
//! `#[type_name]`, so iceoryx2 can place it in shared memory and a process of
//! another build can check it is reading the same layout. A tensor message is a
//! header struct (the iceoryx2 *user header*) plus a slice payload of `f32`, `u16` or
//! `u8`; the layouts of those slices are documented on each header and computed
//! by [`Shapes`], so the sender and the receiver never disagree. The rooms:
//! `shapes` (the task's constants, every length, the 16-bit packing),
//! `headers` (the messages' headers and records), `sequence` (stored
//! sequences), `label` (the teacher's labels), `telemetry` and `counters`
//! (what roles report), `tracking` (lost batches), `durable` and `protobuf`.
//!
//! This crate is the only one that derives `ZeroCopySend` (besides test-only
//! headers), and only with its `zero-copy` feature: without it the crate is
//! the layout alone (constants, packing, done codes) and needs no iceoryx2,
//! so the domain crates (the model) take their layout from here too.

mod counters;
pub mod durable;
mod headers;
mod label;
pub mod protobuf;
mod sequence;
mod shapes;
mod telemetry;
mod tracking;

pub use counters::Counters;
pub use headers::{
    ActionHeader, DoneKind, EPISODE_FIELDS, EpisodeHeader, MAX_AGENTS_PER_ENV, MAX_ENVS_PER_HOST,
    MinibatchHeader, ObsHeader, PICK_WORDS, Pick, PriorityHeader, Receipt, TransitionHeader,
    WeightsHeader, episode_corrupt, layout_fingerprint,
};
pub use label::{LABEL_SET, label_action, label_mask, label_of_mask};
pub use sequence::{RowLayout, SeqLayout, Unpacked};
pub use shapes::{
    DEPTH_PIXELS, DEPTH_SIDE, FRAMES, GOAL_DIM, MAX_DEPTH_SIDE, MAX_FRAME_STRIDE, MAX_FRAMES,
    MAX_MAP_FLOATS, MAX_TRACK_FLOATS, MIN_DEPTH_SIDE, NO_EXPERT, NUM_ACTIONS, Shapes, TAIL,
    TRACK_FLOATS, VEL_DIM, dequantize_depth, quantize_depth,
};
pub(crate) use shapes::{f32_words, word_f32};
pub use telemetry::{
    ActorStage, Delivery, LearnerStage, Learning, LinkStage, ReplayStage, RoleKind, STAGES,
    SimStage, Stage, TeacherCounts, Telemetry, stage_names,
};
pub use tracking::SeqTracker;
