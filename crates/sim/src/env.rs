//! The vectorised environment: N quadrotors in one arena, stepped together.
//!
//! One `step` applies every agent's action, runs the physics steps of one
//! action period with the cascaded controller (directly, `flight.rs`, or
//! through a rapier pipeline, `rapier_flight.rs`), detects collisions, scores
//! the step, resets finished agents on their own and renders all agents'
//! depth images in one batched call.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rapier3d::math::Vector;

use crate::arena::{Arena, Lanes, Spawn};
use crate::dynamics::DroneState;
use crate::flight::{Body, Drone, Flight};
use crate::geometry::Geometry;
use crate::goal::{Goal, Progress};
use crate::rapier_flight::RapierFlight;
use crate::realism::{PixelNoise, WIND_DRAG};
use crate::render::wgpu::{GpuDepthRenderer, GpuError};
use crate::render::{DepthRenderer, Scene};

/// Why an episode ended: the done codes every process shares (one type,
/// `rotorhive_msg::DoneKind`, so the codes cannot drift apart).
pub use rotorhive_msg::DoneKind as Done;

mod fresh;
mod mapping;
mod observe;
mod settings;
mod tracking;

use fresh::Fresh;
pub use fresh::{FreshStats, LayoutMaker};

pub use settings::{
    Autoreset, Episode, LanesError, PhysicsKind, RendererKind, SimConfig, StepTiming,
};

/// Agents per piece of physics work handed to a pool thread: whole groups
/// of the vectorised flight kernel.
const PHYSICS_CHUNK: usize = 2 * crate::simd::LANES;

/// The flight computation of an environment.
#[derive(Debug)]
enum Physics {
    Direct(Geometry),
    Rapier(Box<RapierFlight>),
}

/// What an environment builds from its world (the lanes side by side):
/// the flight at the world's altitude, the physics, the CPU scene with the
/// lanes' bounds and, with the wgpu renderer, its scene on the GPU. A new
/// world (a curriculum's next stage) builds them again the same way (the
/// rapier path's moving obstacles where they are at the world's time; the
/// scenes are put there before each render).
struct World {
    flight: Flight,
    physics: Physics,
    scene: Scene,
    gpu: Option<GpuDepthRenderer>,
}

impl World {
    fn new(cfg: &SimConfig, arena: &Arena, bounds: &[[f32; 2]], t: f64) -> Result<Self, GpuError> {
        let flight = Flight {
            quad: cfg.quad,
            gains: cfg.gains,
            dt: cfg.physics_dt,
            forward_speed: cfg.forward_speed,
            altitude: arena.spawn.z,
        };
        let physics = match cfg.physics {
            PhysicsKind::Direct => Physics::Direct(Geometry::new(arena)),
            PhysicsKind::Rapier => Physics::Rapier(Box::new(RapierFlight::new(
                arena,
                cfg.agents,
                &flight,
                cfg.drone_radius,
                cfg.interactive,
                t,
            ))),
        };
        let scene = Scene::of_lanes(arena, bounds);
        let gpu = gpu_scene(cfg, &scene)?;
        Ok(Self { flight, physics, scene, gpu })
    }
}

/// The wgpu renderer's copy of `scene`, with that renderer (none with the
/// CPU one).
fn gpu_scene(cfg: &SimConfig, scene: &Scene) -> Result<Option<GpuDepthRenderer>, GpuError> {
    Ok(match cfg.renderer {
        RendererKind::Cpu => None,
        RendererKind::Wgpu => Some(GpuDepthRenderer::new(cfg.camera, scene)?),
    })
}

/// N quadrotors in one arena.
pub struct VecEnv {
    cfg: SimConfig,
    arena: Arena,
    flight: Flight,
    physics: Physics,
    drones: Vec<Drone>,
    /// Positions of every agent over the last action, `(substeps + 1)` each
    /// (the direct path's collision query, and the camera's latency).
    path: Vec<Vector>,
    /// Positions per agent in `path` (0 before the first action).
    path_stride: usize,
    /// Each agent's camera pitch (rad) and latency (physics steps), per episode.
    pitch: Vec<f32>,
    lag: Vec<usize>,
    /// The depth noise's random numbers.
    pixel_noise: PixelNoise,
    /// Arenas that replace the world at the next step (a curriculum).
    pending: Option<Lanes>,
    /// Lanes renewed with fresh layouts, if that is on.
    fresh: Option<Fresh>,
    /// The lane each agent's episode flies in.
    agent_lane: Vec<usize>,
    scene: Scene,
    renderer: DepthRenderer,
    gpu: Option<GpuDepthRenderer>,
    /// Simd centre lines and spawns (one lane: the arena itself).
    lane_offsets: Vec<f32>,
    lane_spawns: Vec<Spawn>,
    /// Agent index of every camera, for the GPU renderer.
    agent_ids: Vec<u32>,
    rng: Pcg64Mcg,
    steps: Vec<u32>,
    returns: Vec<f32>,
    /// Current depth frame per agent, `N` observed frames.
    cur: Vec<f32>,
    /// The frames as rendered, before the camera's min-pool (without one: empty).
    rendered: Vec<f32>,
    /// The earlier depth frames per agent, `N × (frames − 1)` frames,
    /// oldest first (with two frames: the previous one).
    past: Vec<f32>,
    /// Empty once dropped: the caller assembles observations itself.
    obs: Vec<f32>,
    rewards: Vec<f32>,
    dones: Vec<Done>,
    finished: Vec<Episode>,
    timing: StepTiming,
    total_steps: u64,
    /// Physics steps flown: the world's clock, which moves the obstacles.
    ticks: u64,
    /// Each agent's goal (x, y) this episode (with a goal).
    goals: Vec<[f32; 2]>,
    /// Each agent's position before the step (with a goal): the step's
    /// segment and the distance its progress is measured from.
    before: Vec<Vector>,
    /// When an agent whose episode ends starts its next one.
    autoreset: Autoreset,
    /// Agents that started a new episode in the last step (`NextStep`).
    restarted: Vec<bool>,
    /// Each lane's free space along y, and every agent's camera map
    /// (`[sim.map]`; `env/mapping.rs`).
    lane_bounds: Vec<[f32; 2]>,
    maps: Option<crate::map::Maps>,
    /// Every agent's tracker of the movers it saw (`[sim.tracks]`;
    /// `env/tracking.rs`).
    trackers: Option<crate::tracks::Trackers>,
}

impl VecEnv {
    /// Builds the world: obstacles, walls, floor and ceiling as fixed
    /// colliders, one drone per agent at a random spawn pose, and the
    /// renderer (the wgpu one can fail to find an adapter).
    pub fn new(cfg: SimConfig, arena: Arena, seed: u64) -> Result<Self, GpuError> {
        let lanes = Lanes::new(std::slice::from_ref(&arena)).expect("one arena is always a lane");
        Self::with_lanes(cfg, lanes, seed)
    }

    /// Several arenas side by side (see [`Lanes`]): every agent starts each
    /// episode in a lane drawn at random, so one environment trains on many
    /// obstacle layouts at once.
    pub fn new_lanes(cfg: SimConfig, arenas: &[Arena], seed: u64) -> Result<Self, LanesError> {
        let lanes = Lanes::new(arenas)?;
        Ok(Self::with_lanes(cfg, lanes, seed)?)
    }

    fn with_lanes(cfg: SimConfig, lanes: Lanes, seed: u64) -> Result<Self, GpuError> {
        let Lanes { world: arena, offsets: lane_offsets, spawns: lane_spawns, bounds: lane_bounds } =
            lanes;
        assert!(cfg.agents > 0, "a VecEnv needs at least one agent");
        let World { flight, physics, scene, gpu } = World::new(&cfg, &arena, &lane_bounds, 0.0)?;
        let n = cfg.agents;
        let px = cfg.camera.observed().pixels();
        assert!(
            cfg.frames >= 1 && cfg.frame_stride >= 1,
            "an observation holds at least one frame"
        );
        let obs_len = cfg.frames * px + cfg.shapes().scalars;
        let maps = mapping::maps_of(&cfg, &lane_bounds, &arena);
        let trackers = tracking::trackers_of(&cfg);
        let mut env = Self {
            renderer: DepthRenderer::new(cfg.camera, cfg.render_threads),
            gpu,
            lane_offsets,
            lane_spawns,
            agent_ids: (0..n as u32).collect(),
            scene,
            arena,
            flight,
            physics,
            drones: vec![Drone::at(Vector::ZERO, Vector::ZERO, flight.nominal()); n],
            path: Vec::new(),
            path_stride: 0,
            pitch: vec![0.0; n],
            lag: vec![0; n],
            pixel_noise: PixelNoise::new(seed),
            pending: None,
            fresh: None,
            agent_lane: vec![0; n],
            rng: Pcg64Mcg::seed_from_u64(seed),
            steps: vec![0; n],
            returns: vec![0.0; n],
            cur: vec![0.0; n * px],
            rendered: Vec::new(),
            past: vec![0.0; n * (cfg.frames - 1) * cfg.frame_stride * px],
            obs: vec![0.0; n * obs_len],
            rewards: vec![0.0; n],
            dones: vec![Done::Running; n],
            finished: Vec::new(),
            timing: StepTiming::default(),
            total_steps: 0,
            ticks: 0,
            goals: vec![[0.0; 2]; n],
            before: vec![Vector::ZERO; n],
            autoreset: Autoreset::SameStep,
            restarted: vec![false; n],
            maps,
            trackers,
            lane_bounds,
            cfg,
        };
        for i in 0..n {
            env.reset_agent(i);
        }
        env.render()?;
        env.map_frames(None);
        env.track_frames(None);
        for i in 0..n {
            env.fill_past(i);
        }
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

    /// Floats per observation: `frames` depth frames, the body-frame
    /// velocity and, with a goal, the goal's floats.
    pub fn obs_len(&self) -> usize {
        self.cfg.frames * self.px() + self.cfg.shapes().scalars
    }

    /// Pixels in one depth frame as observed (after the camera's min-pool).
    fn px(&self) -> usize {
        self.cfg.camera.observed().pixels()
    }

    /// Earlier frames kept per agent: `(frames − 1) × frame_stride`, the
    /// views of that many action periods back (an observation takes every
    /// `frame_stride`-th of them).
    fn kept(&self) -> usize {
        (self.cfg.frames - 1) * self.cfg.frame_stride
    }

    /// Agent `i`'s earlier frames (`kept() × side²`, oldest first).
    fn past_of(&self, i: usize) -> &[f32] {
        let h = self.kept() * self.px();
        &self.past[i * h..(i + 1) * h]
    }

    /// Agent `i`'s current frame.
    fn cur_of(&self, i: usize) -> &[f32] {
        let px = self.px();
        &self.cur[i * px..(i + 1) * px]
    }

    /// Writes agent `i`'s stacked frames (`frames × side²`, oldest first,
    /// `frame_stride` action periods apart, the current one last) to `out`.
    fn write_depth(&self, i: usize, out: &mut [f32]) {
        let (px, stride) = (self.px(), self.cfg.frame_stride);
        let (earlier, now) = out.split_at_mut((self.cfg.frames - 1) * px);
        let kept = self.past_of(i).chunks_exact(px).step_by(stride);
        earlier.chunks_exact_mut(px).zip(kept).for_each(|(o, f)| o.copy_from_slice(f));
        now.copy_from_slice(self.cur_of(i));
    }

    /// Every earlier frame of agent `i` becomes its current one (a new
    /// episode starts with all its frames its first view).
    fn fill_past(&mut self, i: usize) {
        let (px, h) = (self.px(), self.kept() * self.px());
        let (cur, past) = (&self.cur[i * px..(i + 1) * px], &mut self.past[i * h..(i + 1) * h]);
        past.chunks_exact_mut(px).for_each(|f| f.copy_from_slice(cur));
    }

    /// Before a new frame is drawn: every agent's frames move one older, the
    /// current one joining the earlier ones (one kept: a swap, no copy).
    fn age_frames(&mut self) {
        match self.kept() {
            0 => {}
            1 => std::mem::swap(&mut self.past, &mut self.cur),
            k => {
                let (px, h) = (self.px(), k * self.px());
                let age = |past: &mut [f32], cur: &[f32]| {
                    for (past, cur) in past.chunks_exact_mut(h).zip(cur.chunks_exact(px)) {
                        past.copy_within(px.., 0);
                        past[h - px..].copy_from_slice(cur);
                    }
                };
                // Several earlier frames kept: copies on the render threads
                // too, pieces of PHYSICS_CHUNK agents.
                let pool = self.renderer.pool();
                if pool.threads() == 1 || self.cfg.agents <= PHYSICS_CHUNK {
                    age(&mut self.past, &self.cur);
                    return;
                }
                let pieces = self
                    .past
                    .chunks_mut(PHYSICS_CHUNK * h)
                    .zip(self.cur.chunks(PHYSICS_CHUNK * px));
                pool.share(pieces, |(past, cur)| age(past, cur));
            }
        }
    }

    /// Each agent's goal this episode (x, y; meaningful with a goal).
    pub fn goals(&self) -> &[[f32; 2]] {
        &self.goals
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
        self.drones.iter().map(|d| d.p.to_array()).collect()
    }

    /// Full state of one drone.
    pub fn state(&self, agent: usize) -> DroneState {
        let d = &self.drones[agent];
        DroneState { position: d.p, velocity: d.v, rotation: d.q, angvel: d.angvel_world() }
    }

    /// Drone `i` as the physics holds it (the planner reads it).
    pub(crate) fn drone(&self, i: usize) -> &Drone {
        &self.drones[i]
    }

    /// Steps flown in agent `i`'s episode so far.
    pub(crate) fn steps_of(&self, i: usize) -> u32 {
        self.steps[i]
    }

    /// Places a drone at a pose with a velocity, for tests and tools.
    pub fn place(&mut self, agent: usize, position: [f32; 3], velocity: [f32; 3]) {
        let d = &mut self.drones[agent];
        *d = Drone {
            lateral_sp: velocity[1],
            ..Drone::at(Vector::from(position), Vector::from(velocity), self.flight.nominal())
        };
        if let Physics::Rapier(r) = &mut self.physics {
            r.load(agent, d);
        }
    }

    /// Flies every agent with an explicit lateral velocity setpoint for
    /// `seconds` of simulated time, without scoring or resets (controller tests).
    pub fn fly(&mut self, lateral: &[f32], seconds: f32) {
        for (d, l) in self.drones.iter_mut().zip(lateral) {
            d.lateral_sp = *l;
        }
        let steps = (seconds / self.cfg.physics_dt).round() as usize;
        self.advance(steps, false);
    }

    /// The world's clock (seconds): where moving obstacles are.
    pub fn time(&self) -> f64 {
        self.ticks as f64 * f64::from(self.cfg.physics_dt)
    }

    /// Runs `steps` physics steps of every agent and, with `detect`, marks
    /// those that touched something.
    fn advance(&mut self, steps: usize, detect: bool) {
        let (t0, dt) = (self.time(), f64::from(self.cfg.physics_dt));
        self.ticks += steps as u64;
        match &mut self.physics {
            Physics::Rapier(r) => {
                for k in 0..steps {
                    r.step(&self.flight, &mut self.drones, t0 + k as f64 * dt);
                    if detect && self.cfg.interactive {
                        let n = self.drones.len();
                        let p: Vec<Vector> = self.drones.iter().map(|d| d.p).collect();
                        mark_touching(&mut self.drones, self.cfg.drone_radius, |i| p[i], n);
                    }
                }
            }
            Physics::Direct(geometry) => {
                let stride = steps + 1;
                self.path_stride = stride;
                self.path.resize(self.drones.len() * stride, Vector::ZERO);
                let (flight, radius) = (self.flight, self.cfg.drone_radius);
                let geometry = &*geometry;
                let work = |drones: &mut [Drone], path: &mut [Vector]| {
                    flight.fly(drones, path, steps);
                    if detect {
                        for (d, path) in drones.iter_mut().zip(path.chunks_exact(stride)) {
                            if !d.collided && geometry.path_hits(path, radius, t0, dt) {
                                d.collided = true;
                            }
                        }
                    }
                };
                // The physics shares the render threads: pieces of agents
                // handed out as threads come free.
                let pool = self.renderer.pool();
                if pool.threads() == 1 || self.drones.len() <= PHYSICS_CHUNK {
                    work(&mut self.drones, &mut self.path);
                } else {
                    let pieces = self
                        .drones
                        .chunks_mut(PHYSICS_CHUNK)
                        .zip(self.path.chunks_mut(PHYSICS_CHUNK * stride));
                    pool.share(pieces, |(drones, path)| work(drones, path));
                }
                if detect && self.cfg.interactive {
                    let n = self.drones.len();
                    for k in 1..stride {
                        let path = &self.path;
                        mark_touching(&mut self.drones, radius, |i| path[i * stride + k], n);
                    }
                }
            }
        }
    }

    /// Advances every agent by one action period.
    ///
    /// `actions[i]` is 0 (lateral setpoint −`lateral_step`), 1
    /// (+`lateral_step`) or, with `hold_action`, 2 (the setpoint held).
    /// Only the wgpu renderer can fail.
    pub fn step(&mut self, actions: &[u8]) -> Result<(), GpuError> {
        assert_eq!(actions.len(), self.cfg.agents, "one action per agent");
        let t0 = Instant::now();
        let cfg = &self.cfg;
        if cfg.goal.enabled {
            for (b, d) in self.before.iter_mut().zip(&self.drones) {
                *b = d.p;
            }
        }
        for (d, a) in self.drones.iter_mut().zip(actions) {
            let delta = match *a {
                0 => -cfg.lateral_step,
                2 if cfg.hold_action => 0.0,
                _ => cfg.lateral_step,
            };
            d.lateral_sp =
                (d.lateral_sp + delta).clamp(-cfg.max_lateral_speed, cfg.max_lateral_speed);
            d.collided = false;
        }
        let substeps = cfg.substeps();
        self.advance(substeps, true);
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
            let (reward, done) = self.score(i);
            self.returns[i] += reward;
            self.rewards[i] = reward;
            self.dones[i] = done;
            if done != Done::Running {
                self.finished.push(Episode {
                    agent: i,
                    reward: self.returns[i],
                    steps: self.steps[i],
                    done,
                });
                if self.autoreset == Autoreset::SameStep {
                    self.reset_agent(i);
                    self.restarted[i] = true;
                }
            }
        }
        if let Some(lanes) = self.pending.take() {
            self.change_world(lanes)?;
        }
        self.renew_lane()?;
        let t2 = Instant::now();
        self.age_frames();
        self.render()?;
        self.map_frames(None);
        self.track_frames(None);
        let t3 = Instant::now();
        // A reset agent starts with every frame equal to its first view.
        for i in 0..self.cfg.agents {
            if self.restarted[i] {
                self.fill_past(i);
            }
        }
        self.assemble_obs();
        self.total_steps += 1;
        let t4 = Instant::now();
        self.timing = StepTiming {
            physics_ns: (t1 - t0).as_nanos() as u64,
            render_ns: (t3 - t2).as_nanos() as u64,
            reset_ns: ((t2 - t1) + (t4 - t3)).as_nanos() as u64,
        };
        Ok(())
    }

    /// The reward and end of agent `i`'s step: a collision, the far end
    /// (the paper's task) or the goal reached or missed, the step limit.
    fn score(&self, i: usize) -> (f32, Done) {
        let cfg = &self.cfg;
        let p = self.drones[i].p;
        let goal = cfg.goal.enabled.then(|| cfg.goal.progress(self.goals[i], self.before[i], p));
        let timeout = self.steps[i] >= cfg.max_steps;
        match goal {
            _ if self.drones[i].collided => (cfg.reward_collision, Done::Collision),
            None if p.x >= self.arena.length => (cfg.reward_goal, Done::Goal),
            None if timeout => (cfg.reward_timeout, Done::Timeout),
            None => (cfg.reward_step, Done::Running),
            Some(Progress::Reached) => (cfg.goal.reward_reach, Done::Goal),
            Some(Progress::Missed) => (cfg.goal.reward_miss, Done::Timeout),
            Some(Progress::Flying(_)) if p.x >= self.arena.length => {
                (cfg.goal.reward_miss, Done::Timeout)
            }
            Some(Progress::Flying(d)) => {
                let gained = Goal::distance(self.goals[i], self.before[i]) - d;
                let step = cfg.reward_step + cfg.goal.reward_progress * gained;
                if timeout { (cfg.reward_timeout, Done::Timeout) } else { (step, Done::Running) }
            }
        }
    }

    fn reset_agent(&mut self, i: usize) {
        let lanes = self.lane_offsets.len();
        let lane = match self.fresh.as_ref().and_then(|f| f.retiring) {
            // No episode starts in a lane about to be renewed.
            Some(k) if lanes > 1 => {
                let l = self.rng.random_range(0..lanes - 1);
                if l >= k { l + 1 } else { l }
            }
            _ if lanes > 1 => self.rng.random_range(0..lanes),
            _ => 0,
        };
        self.agent_lane[i] = lane;
        if let Some(m) = &mut self.maps {
            m.clear(i, self.lane_bounds[lane]);
        }
        if let Some(t) = &mut self.trackers {
            t.clear(i);
        }
        let s = &self.lane_spawns[lane];
        let y = self.lane_offsets[lane]
            + if s.y[1] > s.y[0] { self.rng.random_range(s.y[0]..s.y[1]) } else { s.y[0] };
        let (sx, sz) = (s.x, s.z);
        let body = self.draw_body();
        self.drones[i] = Drone::at(Vector::new(sx, y, sz), Vector::new(body.fwd, 0.0, 0.0), body);
        if !self.cfg.randomize.is_off() || !self.cfg.noise.is_off() {
            self.randomize_spawn(i);
        }
        if let Physics::Rapier(r) = &mut self.physics {
            r.load(i, &self.drones[i]);
        }
        if self.cfg.goal.enabled {
            // Drawn after the spawn's draws: a task without a goal draws
            // the same spawns as ever.
            let g = &self.cfg.goal;
            let y = self.lane_offsets[lane] + within(&mut self.rng, g.lateral);
            self.goals[i] = [self.arena.length - g.from_end, y];
        }
        self.steps[i] = 0;
        self.returns[i] = 0.0;
    }

    /// A drone's parameters for a new episode: the nominal ones, or drawn
    /// (`[sim.randomize]`; nothing is drawn when its dynamics are off, so
    /// the paper's task draws the same spawns as ever).
    fn draw_body(&mut self) -> Body {
        let nominal = self.flight.nominal();
        let r = &self.cfg.randomize;
        if !r.dynamics() {
            return nominal;
        }
        let rng = &mut self.rng;
        let (mass, gain, wind) =
            (symmetric(rng, r.mass), symmetric(rng, r.vel_gain), symmetric(rng, r.wind));
        let scale = within(rng, r.forward_speed_scale);
        Body {
            fwd: nominal.fwd * scale,
            mass: nominal.mass * (1.0 + mass),
            vel_gain: nominal.vel_gain * (1.0 + gain),
            push: WIND_DRAG * wind,
        }
    }

    /// The rest of a new episode's draws: spawn x, heading and lateral
    /// velocity, the camera's pitch and latency.
    fn randomize_spawn(&mut self, i: usize) {
        let (r, rng) = (&self.cfg.randomize, &mut self.rng);
        let heading = symmetric(rng, r.spawn_heading_deg).to_radians();
        let lateral = symmetric(rng, r.spawn_lateral_speed);
        self.pitch[i] = symmetric(rng, r.camera_pitch_deg).to_radians();
        let dx = within(rng, [0.0, r.spawn_x]);
        let latency = within(rng, self.cfg.noise.latency_s);
        self.lag[i] = (latency / self.cfg.physics_dt).round() as usize;
        let d = &mut self.drones[i];
        d.p.x += dx;
        d.q = rapier3d::math::Rotation::from_rotation_z(heading);
        d.v.y = lateral;
        d.lateral_sp = lateral;
    }

    /// Replaces the world with `arenas` at the end of the next step (a
    /// curriculum's new stage): every agent still flying then ends its
    /// episode as a timeout and starts the next one in the new lanes.
    pub fn replace_arenas(&mut self, arenas: &[Arena]) -> Result<(), LanesError> {
        self.pending = Some(Lanes::new(arenas)?);
        Ok(())
    }

    /// Swaps the world for `lanes` in the middle of a step, after scoring.
    fn change_world(&mut self, lanes: Lanes) -> Result<(), GpuError> {
        let Lanes { world, offsets, spawns, bounds } = lanes;
        let World { flight, physics, scene, gpu } =
            World::new(&self.cfg, &world, &bounds, self.time())?;
        self.maps = mapping::maps_of(&self.cfg, &bounds, &world);
        self.trackers = tracking::trackers_of(&self.cfg);
        self.lane_bounds = bounds;
        (self.flight, self.physics, self.scene, self.gpu) = (flight, physics, scene, gpu);
        self.arena = world;
        self.lane_offsets = offsets;
        self.lane_spawns = spawns;
        self.path_stride = 0;
        for i in 0..self.cfg.agents {
            if self.dones[i] == Done::Running {
                self.returns[i] += self.cfg.reward_timeout - self.rewards[i];
                self.rewards[i] = self.cfg.reward_timeout;
                self.dones[i] = Done::Timeout;
                self.finished.push(Episode {
                    agent: i,
                    reward: self.returns[i],
                    steps: self.steps[i],
                    done: Done::Timeout,
                });
            }
            // Every agent starts again in the new lanes (those that ended in
            // this step had been placed in the old ones).
            self.reset_agent(i);
            self.restarted[i] = true;
        }
        Ok(())
    }
}

/// A draw from `[-a, a]`, or 0 (nothing drawn) when `a` is 0.
fn symmetric(rng: &mut Pcg64Mcg, a: f32) -> f32 {
    if a > 0.0 { rng.random_range(-a..=a) } else { 0.0 }
}

/// A draw from `[lo, hi]`, or `lo` (nothing drawn) when the range is
/// empty: a setting that is off draws nothing, so the streams of the
/// paper's task stay as they were.
fn within(rng: &mut Pcg64Mcg, [lo, hi]: [f32; 2]) -> f32 {
    if hi > lo { rng.random_range(lo..=hi) } else { lo }
}

/// Marks every two drones closer than twice `radius` as collided (drones'
/// sensors do not report touching each other); `position(i)` is drone `i`'s.
fn mark_touching(drones: &mut [Drone], radius: f32, position: impl Fn(usize) -> Vector, n: usize) {
    let d2 = (2.0 * radius).powi(2);
    for i in 0..n {
        for j in i + 1..n {
            if (position(i) - position(j)).length_squared() < d2 {
                drones[i].collided = true;
                drones[j].collided = true;
            }
        }
    }
}
