//! The rotorhive simulator: N quadrotors in an obstacle arena, their flight
//! integrated directly (or through rapier, the reference) with collision
//! queries on parry, cascaded flight control, and batched depth rendering.
//!
//! Pure domain code: it takes explicit state and never touches the transport.

pub mod arena;
pub mod dynamics;
pub mod env;
mod flight;
pub mod gpu;
mod pool;
mod rapier_flight;
pub mod render;
pub mod view;

pub use arena::{Arena, ArenaError, GenParams, Lanes, Obstacle, Spawn};
pub use env::{Autoreset, Done, Episode, LanesError, PhysicsKind, RendererKind, SimConfig, StepTiming, VecEnv};
pub use gpu::{GpuDepthRenderer, GpuError};
pub use render::{CameraPose, CameraSpec, DepthRenderer, Scene};
