//! The rotorhive simulator: N quadrotors in an obstacle arena, physics on
//! rapier, cascaded flight control, and batched CPU depth rendering.
//!
//! Pure domain code: it takes explicit state and never touches the transport.

pub mod arena;
pub mod dynamics;
pub mod env;
pub mod gpu;
mod pool;
pub mod render;

pub use arena::{Arena, ArenaError, GenParams, Lanes, Obstacle, Spawn};
pub use env::{Autoreset, Done, Episode, LanesError, RendererKind, SimConfig, StepTiming, VecEnv};
pub use gpu::{GpuDepthRenderer, GpuError};
pub use render::{CameraPose, CameraSpec, DepthRenderer, Scene};
