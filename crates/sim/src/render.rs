//! Depth rendering, two renderers side by side: [`cpu`], the batched ray
//! caster (the default), and [`wgpu`], the rasteriser on wgpu (a GPU, or
//! the CPU through lavapipe). Both draw the same [`Scene`] for the same
//! cameras.

pub mod cpu;
pub mod wgpu;

pub use cpu::{CameraPose, CameraSpec, DepthRenderer, Drones, Scene};
pub use wgpu::{GpuDepthRenderer, GpuError};
