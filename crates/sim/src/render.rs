//! Depth rendering, two renderers side by side: [`cpu`], the batched ray
//! caster (the default), and [`wgpu`], the rasteriser on wgpu (a GPU, or
//! the CPU through lavapipe). Both draw the same [`Scene`] ([`scene`]) for
//! the same cameras ([`camera`]).

pub mod camera;
pub mod cpu;
pub mod scene;
pub mod wgpu;

pub use camera::{CameraPose, CameraSpec};
pub use cpu::{DepthRenderer, Drones};
pub use scene::Scene;
pub use wgpu::{GpuDepthRenderer, GpuError};
