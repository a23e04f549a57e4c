//! What an environment is made with ([`SimConfig`] and its choices) and
//! what it reports besides observations (finished episodes, timings).

use crate::arena::ArenaError;
use crate::dynamics::{Gains, QuadParams};
use crate::goal::Goal;
use crate::realism::{Noise, Randomize};
use crate::render::CameraSpec;
use crate::render::wgpu::GpuError;
use rotorhive_msg::DoneKind as Done;
use rotorhive_msg::Shapes;

/// When an agent whose episode ended starts its next one (Gymnasium's
/// autoreset modes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Autoreset {
    /// In the same step: the step's observation is the new episode's first
    /// (training's mode; the ended episode's last view is never drawn).
    #[default]
    SameStep,
    /// In the next step, which ignores the agent's action and gives reward 0
    /// and `Done::Running`: the ending step's observation is the episode's
    /// last view.
    NextStep,
    /// Only through [`VecEnv::reset_agents`]; until then the agent keeps its
    /// last frames.
    Disabled,
}

/// Which renderer draws the depth images (named `cpu` or `wgpu` in configs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RendererKind {
    /// Ray casting on the CPU.
    #[default]
    Cpu,
    /// Rasterising with wgpu (a GPU, or lavapipe on the CPU).
    Wgpu,
}

/// How the drones' flight is computed (named `direct` or `rapier` in configs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PhysicsKind {
    /// The equations of motion integrated agent by agent, collisions queried
    /// once per action against the arena's shapes (`flight.rs`).
    #[default]
    Direct,
    /// A rapier rigid-body pipeline, one body per drone (the reference).
    Rapier,
}

/// Why a multi-lane environment could not start.
#[derive(Debug, thiserror::Error)]
pub enum LanesError {
    /// The arenas do not fit side by side.
    #[error(transparent)]
    Arena(#[from] ArenaError),
    /// The renderer could not start.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// Fresh layouts cannot be had here.
    #[error("{0}")]
    Fresh(&'static str),
}

/// Settings of the simulator.
#[derive(Debug, Clone)]
pub struct SimConfig {
    /// Number of drones.
    pub agents: usize,
    /// Physics step (s).
    pub physics_dt: f32,
    /// How flight is computed.
    pub physics: PhysicsKind,
    /// Simulated time per action (s).
    pub action_period: f32,
    /// Constant forward speed setpoint (m/s).
    pub forward_speed: f32,
    /// Lateral velocity change per action (m/s).
    pub lateral_step: f32,
    /// Largest lateral speed setpoint (m/s).
    pub max_lateral_speed: f32,
    /// Steps before an episode times out.
    pub max_steps: u32,
    /// Reward of a step without collision.
    pub reward_step: f32,
    /// Reward of a step that ends in a collision.
    pub reward_collision: f32,
    /// Reward of the step that times out.
    pub reward_timeout: f32,
    /// Reward of the step that reaches the end of the arena.
    pub reward_goal: f32,
    /// The depth camera's noise, dropout and latency.
    pub noise: Noise,
    /// Per-episode randomisation of dynamics, camera and spawn.
    pub randomize: Randomize,
    /// Drones collide with and see each other.
    pub interactive: bool,
    /// Depth camera.
    pub camera: CameraSpec,
    /// Threads for rendering (CPU renderer).
    pub render_threads: usize,
    /// The renderer.
    pub renderer: RendererKind,
    /// All agents' images in one render call per step (true), or one call,
    /// one submission and one synchronisation per agent (false: the
    /// non-batched path of the paper, on purpose).
    pub batched: bool,
    /// Radius of the drone's collision sphere (m).
    pub drone_radius: f32,
    /// Quadrotor constants.
    pub quad: QuadParams,
    /// Controller gains.
    pub gains: Gains,
    /// A goal to reach (off: the paper's task, through the far end).
    pub goal: Goal,
    /// A third action, 2, that holds the lateral setpoint.
    pub hold_action: bool,
    /// Depth frames in one observation, `frame_stride` action periods
    /// apart, oldest first (2: the paper's, previous and current).
    pub frames: usize,
    /// Action periods between two stacked frames (1: consecutive views).
    pub frame_stride: usize,
    /// Rays per side that a planner of the pixels (`Sight::Pixels`,
    /// `Sight::PixelsMemory`) casts to learn what the camera shows (0: the
    /// observed camera's columns, and as many rows as its aspect gives):
    /// what a camera of more or fewer pixels would tell
    /// it. The observation keeps the camera's pixels.
    pub sight_rays: usize,
    /// The camera's map in the observation (`[sim.map]`; off by default).
    pub map: crate::map::MapSpec,
    /// The seen movers in the observation (`[sim.tracks]`; off by
    /// default).
    pub tracks: crate::tracks::TrackSpec,
}

impl SimConfig {
    /// Physics steps per action (at least one).
    pub fn substeps(&self) -> usize {
        ((self.action_period / self.physics_dt).round() as usize).max(1)
    }

    /// The observation and action shapes of this task: the goal's floats
    /// with a goal, the third action with hold.
    pub fn shapes(&self) -> Shapes {
        Shapes::task(self.frames, self.goal.enabled, self.hold_action)
            .with_stride(self.frame_stride)
            .with_map(self.map.floats())
            .with_tracks(self.tracks.floats())
            .with_depth(self.camera.observed_depth())
    }
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            agents: 1,
            physics_dt: 0.02,
            physics: PhysicsKind::Direct,
            action_period: 1.0,
            forward_speed: 1.0,
            lateral_step: 0.25,
            max_lateral_speed: 3.0,
            max_steps: 400,
            reward_step: 3.0,
            reward_collision: -100.0,
            reward_timeout: -10.0,
            reward_goal: 3.0,
            noise: Noise::default(),
            randomize: Randomize::default(),
            interactive: false,
            camera: CameraSpec::default(),
            render_threads: 1,
            renderer: RendererKind::Cpu,
            batched: true,
            drone_radius: 0.3,
            quad: QuadParams::default(),
            gains: Gains::default(),
            goal: Goal::default(),
            hold_action: false,
            frames: rotorhive_msg::FRAMES,
            frame_stride: 1,
            sight_rays: 0,
            map: crate::map::MapSpec::default(),
            tracks: crate::tracks::TrackSpec::default(),
        }
    }
}

/// One finished episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Episode {
    /// Agent index.
    pub agent: usize,
    /// Sum of rewards.
    pub reward: f32,
    /// Steps taken.
    pub steps: u32,
    /// How it ended.
    pub done: Done,
}

/// Nanoseconds spent per stage in the last step.
#[derive(Debug, Clone, Copy, Default)]
pub struct StepTiming {
    /// Controller, dynamics and collision checks.
    pub physics_ns: u64,
    /// Depth rendering.
    pub render_ns: u64,
    /// Reward, done flags, resets and observation assembly.
    pub reset_ns: u64,
}
