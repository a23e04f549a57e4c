//! The rotorhive simulator: N quadrotors in an obstacle arena, their flight
//! integrated directly (or through rapier, the reference) with collision
//! queries on parry, cascaded flight control, and batched depth rendering.
//!
//! Pure domain code: it takes explicit state and never touches the transport.

pub mod arena;
pub mod dynamics;
pub mod env;
mod flight;
pub mod generate;
mod geometry;
pub mod goal;
pub mod map;
pub mod planner;
mod pool;
mod rapier_flight;
pub mod realism;
pub mod render;
mod simd;
pub mod tracks;
pub mod view;

pub use arena::{Arena, ArenaError, Lanes, MAX_OBSTACLE_SPEED, Motion, Obstacle, Spawn};
pub use env::{
    Autoreset, Done, Episode, FreshStats, LanesError, LayoutMaker, PhysicsKind, RendererKind,
    SimConfig, StepTiming, VecEnv,
};
pub use generate::{GenMode, GenParamError, GenParams};
pub use goal::Goal;
pub use map::{MapEncoding, MapSpec};
pub use planner::{Planner, Sight};
pub use realism::{Noise, Randomize};
pub use render::{CameraPose, CameraSpec, DepthRenderer, GpuDepthRenderer, GpuError, Scene};
pub use tracks::{Track, TrackSpec};
