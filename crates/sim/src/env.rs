//! The vectorised environment: N quadrotors in one arena, stepped together.
//!
//! One `step` applies every agent's action, runs the physics substeps of one
//! action period with the cascaded controller, detects collisions through
//! rapier's narrow phase, scores the step, resets finished agents on their own
//! and renders all agents' depth images in one batched call.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rapier3d::prelude::*;

use crate::arena::{Arena, ArenaError, Lanes, Obstacle, Spawn};
use crate::dynamics::{DroneState, Gains, QuadParams, control};
use crate::gpu::{GpuDepthRenderer, GpuError};
use crate::render::{CameraPose, CameraSpec, DepthRenderer, Drones, Scene};

/// Why an episode ended (mirrors `rotorhive_msg::DoneKind` codes).
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Done {
    /// Still flying.
    Running = 0,
    /// Touched an obstacle, wall, floor, ceiling or (interactive) another drone.
    Collision = 1,
    /// Reached the end of the arena.
    Goal = 2,
    /// Ran out of steps.
    Timeout = 3,
}

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

/// Why a multi-lane environment could not start.
#[derive(Debug, thiserror::Error)]
pub enum LanesError {
    /// The arenas do not fit side by side.
    #[error(transparent)]
    Arena(#[from] ArenaError),
    /// The renderer could not start.
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// Settings of the simulator.
#[derive(Debug, Clone)]
pub struct SimConfig {
    /// Number of drones.
    pub agents: usize,
    /// Physics step (s).
    pub physics_dt: f32,
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
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            agents: 1,
            physics_dt: 0.02,
            action_period: 1.0,
            forward_speed: 1.0,
            lateral_step: 0.25,
            max_lateral_speed: 3.0,
            max_steps: 400,
            reward_step: 3.0,
            reward_collision: -100.0,
            reward_timeout: -10.0,
            interactive: false,
            camera: CameraSpec::default(),
            render_threads: 1,
            renderer: RendererKind::Cpu,
            batched: true,
            drone_radius: 0.3,
            quad: QuadParams::default(),
            gains: Gains::default(),
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
    /// Controller, rapier and collision checks.
    pub physics_ns: u64,
    /// Depth rendering.
    pub render_ns: u64,
    /// Reward, done flags, resets and observation assembly.
    pub reset_ns: u64,
}

const GROUP_DRONE: Group = Group::GROUP_1;
const GROUP_WORLD: Group = Group::GROUP_2;

/// N quadrotors in one arena.
pub struct VecEnv {
    cfg: SimConfig,
    arena: Arena,
    world: PhysicsWorld,
    bodies: Vec<RigidBodyHandle>,
    colliders: Vec<ColliderHandle>,
    scene: Scene,
    renderer: DepthRenderer,
    gpu: Option<GpuDepthRenderer>,
    /// Lane centre lines and spawns (one lane: the arena itself).
    lane_offsets: Vec<f32>,
    lane_spawns: Vec<Spawn>,
    /// Agent index of every camera, for the GPU renderer.
    agent_ids: Vec<u32>,
    rng: Pcg64Mcg,
    lateral_sp: Vec<f32>,
    steps: Vec<u32>,
    returns: Vec<f32>,
    collided: Vec<bool>,
    /// Current depth frame per agent, `N × side²`.
    cur: Vec<f32>,
    /// Previous depth frame per agent.
    prev: Vec<f32>,
    /// Empty once dropped: the caller assembles observations itself.
    obs: Vec<f32>,
    rewards: Vec<f32>,
    dones: Vec<Done>,
    finished: Vec<Episode>,
    timing: StepTiming,
    total_steps: u64,
    /// When an agent whose episode ends starts its next one.
    autoreset: Autoreset,
    /// Agents that started a new episode in the last step (`NextStep`).
    restarted: Vec<bool>,
}

impl VecEnv {
    /// Builds the world with the CPU renderer; panics if `cfg.renderer` is
    /// wgpu and no adapter can be opened (use [`VecEnv::try_new`] there).
    pub fn new(cfg: SimConfig, arena: Arena, seed: u64) -> Self {
        Self::try_new(cfg, arena, seed).expect("the renderer could not start")
    }

    /// Builds the world: obstacles, walls, floor and ceiling as fixed
    /// colliders, one drone per agent at a random spawn pose, and the
    /// renderer (the wgpu one can fail to find an adapter).
    pub fn try_new(cfg: SimConfig, arena: Arena, seed: u64) -> Result<Self, GpuError> {
        let lanes = Lanes::new(std::slice::from_ref(&arena)).expect("one arena is always a lane");
        Self::with_lanes(cfg, lanes, seed)
    }

    /// Several arenas side by side (see [`Lanes`]): every agent starts each
    /// episode in a lane drawn at random, so one environment trains on many
    /// obstacle layouts at once.
    pub fn try_new_lanes(cfg: SimConfig, arenas: &[Arena], seed: u64) -> Result<Self, LanesError> {
        let lanes = Lanes::new(arenas)?;
        Ok(Self::with_lanes(cfg, lanes, seed)?)
    }

    fn with_lanes(cfg: SimConfig, lanes: Lanes, seed: u64) -> Result<Self, GpuError> {
        let Lanes { world: arena, offsets: lane_offsets, spawns: lane_spawns, bounds: lane_bounds } = lanes;
        assert!(cfg.agents > 0, "a VecEnv needs at least one agent");
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -9.81);
        world.integration_parameters.dt = cfg.physics_dt;
        let fixed = InteractionGroups::new(GROUP_WORLD, Group::ALL, InteractionTestMode::And);
        for o in &arena.obstacles {
            let c = match *o {
                Obstacle::Box { center, half_extents: h } => ColliderBuilder::cuboid(h[0], h[1], h[2]).translation(Vector::from(center)),
                Obstacle::Cylinder { center, radius, half_height } => {
                    // Rapier's cylinders stand along y; turn them upright.
                    ColliderBuilder::cylinder(half_height, radius)
                        .position(Pose::from_parts(Vector::from(center), Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2)))
                }
            };
            world.colliders.insert(c.collision_groups(fixed));
        }
        // Walls, floor and ceiling as thick slabs, so nothing tunnels through.
        let (l, hw, h) = (arena.length, arena.width / 2.0, arena.height);
        let slabs = [
            (Vector::new(l / 2.0, hw + 0.5, h / 2.0), Vector::new(l / 2.0 + 5.0, 0.5, h / 2.0 + 1.0)),
            (Vector::new(l / 2.0, -hw - 0.5, h / 2.0), Vector::new(l / 2.0 + 5.0, 0.5, h / 2.0 + 1.0)),
            (Vector::new(l / 2.0, 0.0, -0.5), Vector::new(l / 2.0 + 5.0, hw + 1.0, 0.5)),
            (Vector::new(l / 2.0, 0.0, h + 0.5), Vector::new(l / 2.0 + 5.0, hw + 1.0, 0.5)),
        ];
        for (c, e) in slabs {
            world.colliders.insert(ColliderBuilder::cuboid(e.x, e.y, e.z).translation(c).collision_groups(fixed));
        }
        let filter = if cfg.interactive { GROUP_WORLD | GROUP_DRONE } else { GROUP_WORLD };
        let groups = InteractionGroups::new(GROUP_DRONE, filter, InteractionTestMode::And);
        let q = cfg.quad;
        let mut bodies = Vec::with_capacity(cfg.agents);
        let mut colliders = Vec::with_capacity(cfg.agents);
        for _ in 0..cfg.agents {
            let body = RigidBodyBuilder::dynamic()
                .additional_mass_properties(MassProperties::new(Vector::ZERO, q.mass, Vector::from(q.inertia)))
                .linear_damping(0.05)
                .can_sleep(false);
            // The drone's collider is a sensor: it reports contact without
            // bouncing, since a contact ends the episode anyway.
            let collider = ColliderBuilder::ball(cfg.drone_radius)
                .density(0.0)
                .sensor(true)
                .active_collision_types(ActiveCollisionTypes::default() | ActiveCollisionTypes::DYNAMIC_DYNAMIC)
                .collision_groups(groups);
            let (b, c) = world.insert(body, collider);
            bodies.push(b);
            colliders.push(c);
        }
        let n = cfg.agents;
        let px = cfg.camera.side * cfg.camera.side;
        let obs_len = 2 * px + 3;
        let mut scene = Scene::new(&arena);
        scene.set_lanes(&lane_bounds);
        let gpu = match cfg.renderer {
            RendererKind::Cpu => None,
            RendererKind::Wgpu => Some(GpuDepthRenderer::new(cfg.camera, &scene)?),
        };
        let mut env = Self {
            renderer: DepthRenderer::new(cfg.camera, cfg.render_threads),
            gpu,
            lane_offsets,
            lane_spawns,
            agent_ids: (0..n as u32).collect(),
            scene,
            arena,
            world,
            bodies,
            colliders,
            rng: Pcg64Mcg::seed_from_u64(seed),
            lateral_sp: vec![0.0; n],
            steps: vec![0; n],
            returns: vec![0.0; n],
            collided: vec![false; n],
            cur: vec![0.0; n * px],
            prev: vec![0.0; n * px],
            obs: vec![0.0; n * obs_len],
            rewards: vec![0.0; n],
            dones: vec![Done::Running; n],
            finished: Vec::new(),
            timing: StepTiming::default(),
            total_steps: 0,
            autoreset: Autoreset::SameStep,
            restarted: vec![false; n],
            cfg,
        };
        for i in 0..n {
            env.reset_agent(i);
        }
        env.render()?;
        env.prev.copy_from_slice(&env.cur);
        env.assemble_obs();
        Ok(env)
    }

    /// The GPU renderer, when the config chose it.
    pub fn gpu(&self) -> Option<&GpuDepthRenderer> {
        self.gpu.as_ref()
    }

    /// Number of agents.
    pub fn agents(&self) -> usize {
        self.cfg.agents
    }

    /// Floats per observation: two depth frames and the body-frame velocity.
    pub fn obs_len(&self) -> usize {
        2 * self.cfg.camera.side * self.cfg.camera.side + 3
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// The arena.
    pub fn arena(&self) -> &Arena {
        &self.arena
    }

    /// Observations after the last step, `agents × obs_len`. Agents that were
    /// reset in that step show the first observation of their new episode.
    /// Empty after [`drop_observation_buffer`](Self::drop_observation_buffer).
    pub fn observations(&self) -> &[f32] {
        &self.obs
    }

    /// Rewards of the last step.
    pub fn rewards(&self) -> &[f32] {
        &self.rewards
    }

    /// Done flags of the last step.
    pub fn dones(&self) -> &[Done] {
        &self.dones
    }

    /// Episodes that finished in the last step.
    pub fn finished(&self) -> &[Episode] {
        &self.finished
    }

    /// Stage timings of the last step.
    pub fn timing(&self) -> StepTiming {
        self.timing
    }

    /// Environment steps taken so far.
    pub fn total_steps(&self) -> u64 {
        self.total_steps
    }

    /// Position of each drone (m).
    pub fn positions(&self) -> Vec<[f32; 3]> {
        self.bodies.iter().map(|h| self.world.bodies[*h].translation().to_array()).collect()
    }

    /// Full state of one drone.
    pub fn state(&self, agent: usize) -> DroneState {
        let b = &self.world.bodies[self.bodies[agent]];
        DroneState { position: b.translation(), velocity: b.linvel(), rotation: *b.rotation(), angvel: b.angvel() }
    }

    /// Lateral velocity setpoint of an agent (m/s).
    pub fn lateral_setpoint(&self, agent: usize) -> f32 {
        self.lateral_sp[agent]
    }

    /// Places a drone at a pose with a velocity, for tests and tools.
    pub fn place(&mut self, agent: usize, position: [f32; 3], velocity: [f32; 3]) {
        let b = &mut self.world.bodies[self.bodies[agent]];
        b.set_position(Pose::from_parts(Vector::from(position), Rotation::IDENTITY), true);
        b.set_linvel(Vector::from(velocity), true);
        b.set_angvel(Vector::ZERO, true);
        self.lateral_sp[agent] = velocity[1];
    }

    /// Flies every agent with an explicit lateral velocity setpoint for
    /// `seconds` of simulated time, without scoring or resets (controller tests).
    pub fn fly(&mut self, lateral: &[f32], seconds: f32) {
        self.lateral_sp.copy_from_slice(lateral);
        let substeps = (seconds / self.cfg.physics_dt).round() as usize;
        for _ in 0..substeps {
            self.substep();
        }
    }

    fn substep(&mut self) {
        let cfg = &self.cfg;
        for (i, h) in self.bodies.iter().enumerate() {
            let b = &mut self.world.bodies[*h];
            let s = DroneState { position: b.translation(), velocity: b.linvel(), rotation: *b.rotation(), angvel: b.angvel() };
            let sp = Vector::new(cfg.forward_speed, self.lateral_sp[i], 0.0);
            let cmd = control(&cfg.quad, &cfg.gains, &s, sp, self.arena.spawn.z);
            b.reset_forces(false);
            b.reset_torques(false);
            for (f, arm) in cmd.thrusts.iter().zip(cmd.arms_world) {
                b.add_force_at_point(cmd.thrust_dir * *f, s.position + arm, false);
            }
            b.add_torque(cmd.yaw_torque, false);
        }
        self.world.step();
    }

    /// Advances every agent by one action period.
    ///
    /// `actions[i]` is 0 (lateral setpoint −`lateral_step`) or 1
    /// (+`lateral_step`). Panics if the wgpu renderer fails; see
    /// [`VecEnv::try_step`].
    pub fn step(&mut self, actions: &[u8]) {
        self.try_step(actions).expect("rendering failed");
    }

    /// [`VecEnv::step`], with the wgpu renderer's failures returned.
    pub fn try_step(&mut self, actions: &[u8]) -> Result<(), GpuError> {
        assert_eq!(actions.len(), self.cfg.agents, "one action per agent");
        let t0 = Instant::now();
        let cfg = &self.cfg;
        for (sp, a) in self.lateral_sp.iter_mut().zip(actions) {
            let delta = if *a == 0 { -cfg.lateral_step } else { cfg.lateral_step };
            *sp = (*sp + delta).clamp(-cfg.max_lateral_speed, cfg.max_lateral_speed);
        }
        self.collided.fill(false);
        let substeps = ((cfg.action_period / cfg.physics_dt).round() as usize).max(1);
        for _ in 0..substeps {
            self.substep();
            self.detect_collisions();
        }
        let t1 = Instant::now();

        self.finished.clear();
        self.restarted.fill(false);
        for i in 0..self.cfg.agents {
            if self.autoreset == Autoreset::NextStep && self.dones[i] != Done::Running {
                // Ended in the last step: starts again now, its action ignored.
                self.reset_agent(i);
                self.rewards[i] = 0.0;
                self.dones[i] = Done::Running;
                self.restarted[i] = true;
                continue;
            }
            self.steps[i] += 1;
            let x = self.world.bodies[self.bodies[i]].translation().x;
            let (reward, done) = if self.collided[i] {
                (self.cfg.reward_collision, Done::Collision)
            } else if x >= self.arena.length {
                (self.cfg.reward_step, Done::Goal)
            } else if self.steps[i] >= self.cfg.max_steps {
                (self.cfg.reward_timeout, Done::Timeout)
            } else {
                (self.cfg.reward_step, Done::Running)
            };
            self.returns[i] += reward;
            self.rewards[i] = reward;
            self.dones[i] = done;
            if done != Done::Running {
                self.finished.push(Episode { agent: i, reward: self.returns[i], steps: self.steps[i], done });
                if self.autoreset == Autoreset::SameStep {
                    self.reset_agent(i);
                    self.restarted[i] = true;
                }
            }
        }
        let t2 = Instant::now();
        std::mem::swap(&mut self.prev, &mut self.cur);
        self.render()?;
        let t3 = Instant::now();
        // A reset agent starts with both frames equal to its first view.
        let px = self.cfg.camera.side * self.cfg.camera.side;
        for i in 0..self.cfg.agents {
            if self.restarted[i] {
                self.prev[i * px..(i + 1) * px].copy_from_slice(&self.cur[i * px..(i + 1) * px]);
            }
        }
        self.assemble_obs();
        self.total_steps += 1;
        let t4 = Instant::now();
        self.timing =
            StepTiming { physics_ns: (t1 - t0).as_nanos() as u64, render_ns: (t3 - t2).as_nanos() as u64, reset_ns: ((t2 - t1) + (t4 - t3)).as_nanos() as u64 };
        Ok(())
    }

    fn detect_collisions(&mut self) {
        let np = &self.world.narrow_phase;
        for (i, c) in self.colliders.iter().enumerate() {
            if !self.collided[i] && np.intersection_pairs_with(*c).any(|(_, _, hit)| hit) {
                self.collided[i] = true;
            }
        }
        // Sensors do not report touching each other, so interactive drones are
        // checked against each other directly.
        if self.cfg.interactive {
            let p = self.positions();
            let d2 = (2.0 * self.cfg.drone_radius).powi(2);
            for i in 0..p.len() {
                for j in i + 1..p.len() {
                    let d = Vector::from(p[i]) - Vector::from(p[j]);
                    if d.length_squared() < d2 {
                        self.collided[i] = true;
                        self.collided[j] = true;
                    }
                }
            }
        }
    }

    fn reset_agent(&mut self, i: usize) {
        let lane = if self.lane_offsets.len() > 1 { self.rng.random_range(0..self.lane_offsets.len()) } else { 0 };
        let s = &self.lane_spawns[lane];
        let y = self.lane_offsets[lane] + if s.y[1] > s.y[0] { self.rng.random_range(s.y[0]..s.y[1]) } else { s.y[0] };
        let b = &mut self.world.bodies[self.bodies[i]];
        b.set_position(Pose::from_parts(Vector::new(s.x, y, s.z), Rotation::IDENTITY), true);
        b.set_linvel(Vector::new(self.cfg.forward_speed, 0.0, 0.0), true);
        b.set_angvel(Vector::ZERO, true);
        b.reset_forces(false);
        b.reset_torques(false);
        self.lateral_sp[i] = 0.0;
        self.steps[i] = 0;
        self.returns[i] = 0.0;
    }

    fn render(&mut self) -> Result<(), GpuError> {
        let cams: Vec<CameraPose> = (0..self.cfg.agents).map(|i| self.camera(i)).collect();
        let positions: Vec<Vector> = cams.iter().map(|c| c.position).collect();
        let drones = self.cfg.interactive.then_some(Drones { positions: &positions, radius: self.cfg.drone_radius });
        let px = self.cfg.camera.side * self.cfg.camera.side;
        match (&mut self.gpu, self.cfg.batched) {
            (Some(g), true) => g.render(&cams, &self.agent_ids, drones, &mut self.cur)?,
            (None, true) => self.renderer.render(&self.scene, &cams, 0, drones, &mut self.cur),
            // Non-batched: one request, one submission and one
            // synchronisation per agent.
            (Some(g), false) => {
                for (i, img) in self.cur.chunks_mut(px).enumerate() {
                    g.render(&cams[i..i + 1], &self.agent_ids[i..i + 1], drones, img)?;
                }
            }
            (None, false) => {
                for (i, img) in self.cur.chunks_mut(px).enumerate() {
                    self.renderer.render(&self.scene, &cams[i..i + 1], i, drones, img);
                }
            }
        }
        Ok(())
    }

    fn assemble_obs(&mut self) {
        if self.obs.is_empty() {
            return;
        }
        let mut obs = std::mem::take(&mut self.obs);
        self.write_observations(0, &mut obs);
        self.obs = obs;
    }

    /// Writes the observations of agents `first..` (as many whole rows as
    /// `out` holds, `obs_len` floats each) straight into `out`: the sim
    /// process assembles them in the loaned shared-memory sample this way.
    pub fn write_observations(&self, first: usize, out: &mut [f32]) {
        let px = self.cfg.camera.side * self.cfg.camera.side;
        let len = 2 * px + 3;
        assert!(out.len().is_multiple_of(len) && first + out.len() / len <= self.cfg.agents, "observation rows out of range");
        for (j, o) in out.chunks_exact_mut(len).enumerate() {
            let i = first + j;
            o[..px].copy_from_slice(&self.prev[i * px..(i + 1) * px]);
            o[px..2 * px].copy_from_slice(&self.cur[i * px..(i + 1) * px]);
            o[2 * px..].copy_from_slice(&self.body_velocity(i));
        }
    }

    /// When an agent whose episode ends starts its next one (training uses
    /// the default, [`Autoreset::SameStep`]).
    pub fn set_autoreset(&mut self, mode: Autoreset) {
        self.autoreset = mode;
    }

    /// Starts a new episode for every agent whose `mask` entry is true:
    /// a new spawn (drawn from this env's generator), both frames its first
    /// view, reward 0 and `Done::Running`; the other agents keep their state
    /// and observations.
    pub fn reset_agents(&mut self, mask: &[bool]) -> Result<(), GpuError> {
        assert_eq!(mask.len(), self.cfg.agents, "one flag per agent");
        let reset: Vec<usize> = mask.iter().enumerate().filter(|(_, m)| **m).map(|(i, _)| i).collect();
        if reset.is_empty() {
            return Ok(());
        }
        for &i in &reset {
            self.reset_agent(i);
            self.rewards[i] = 0.0;
            self.dones[i] = Done::Running;
        }
        let px = self.cfg.camera.side * self.cfg.camera.side;
        if self.cfg.interactive {
            // Interactive drones see each other: every image may change.
            self.render()?;
        } else {
            // Only the reset agents' views change: draw just those.
            let mut img = vec![0.0; reset.len() * px];
            let cams: Vec<CameraPose> = reset.iter().map(|i| self.camera(*i)).collect();
            match &mut self.gpu {
                Some(g) => {
                    let ids: Vec<u32> = reset.iter().map(|i| *i as u32).collect();
                    g.render(&cams, &ids, None, &mut img)?;
                }
                None => self.renderer.render(&self.scene, &cams, 0, None, &mut img),
            }
            for (k, i) in reset.iter().enumerate() {
                self.cur[i * px..(i + 1) * px].copy_from_slice(&img[k * px..(k + 1) * px]);
            }
        }
        for i in reset {
            self.prev[i * px..(i + 1) * px].copy_from_slice(&self.cur[i * px..(i + 1) * px]);
        }
        self.assemble_obs();
        Ok(())
    }

    /// Writes every agent's observation split in two, as Gymnasium's `Dict`
    /// observation holds it: `depth` (`agents × 2 × side²`, the previous
    /// frame then the current one) and `velocity` (`agents × 3`, body frame).
    pub fn write_observations_split(&self, depth: &mut [f32], velocity: &mut [f32]) {
        let px = self.cfg.camera.side * self.cfg.camera.side;
        let n = self.cfg.agents;
        assert!(depth.len() == n * 2 * px && velocity.len() == n * 3, "observation buffers of the wrong size");
        for (i, (d, v)) in depth.chunks_exact_mut(2 * px).zip(velocity.chunks_exact_mut(3)).enumerate() {
            d[..px].copy_from_slice(&self.prev[i * px..(i + 1) * px]);
            d[px..].copy_from_slice(&self.cur[i * px..(i + 1) * px]);
            v.copy_from_slice(&self.body_velocity(i));
        }
    }

    fn camera(&self, agent: usize) -> CameraPose {
        let b = &self.world.bodies[self.bodies[agent]];
        CameraPose { position: b.translation(), rotation: *b.rotation() }
    }

    fn body_velocity(&self, agent: usize) -> [f32; 3] {
        let b = &self.world.bodies[self.bodies[agent]];
        (b.rotation().inverse() * b.linvel()).to_array()
    }

    /// Draws future spawns from a generator seeded with `seed` (Gymnasium's
    /// `reset(seed=...)`); reset the agents after it for a reproducible start.
    pub fn reseed(&mut self, seed: u64) {
        self.rng = Pcg64Mcg::seed_from_u64(seed);
    }

    /// Stops keeping the [`observations`](Self::observations) buffer (it
    /// becomes empty) for a caller that assembles each step's observations
    /// where it needs them with [`write_observations`](Self::write_observations),
    /// saving a copy per step.
    pub fn drop_observation_buffer(&mut self) {
        self.obs = Vec::new();
    }
}
