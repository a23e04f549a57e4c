//! What the agents see: each camera's pose (with its latency), the depth
//! rendered for all agents in one call (CPU or wgpu), the stacked frames
//! and the observations written out.

use rapier3d::math::Vector;

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::{Autoreset, Done, VecEnv};
use crate::goal::Goal;
use crate::render::camera::min_pool;
use crate::render::wgpu::GpuError;
use crate::render::{CameraPose, CameraSpec, Drones};

/// Agents per piece of observation writing handed to a pool thread.
const OBS_CHUNK: usize = 16;

impl VecEnv {
    /// Where agent `i`'s camera sees from: its pose, `lag` physics steps
    /// back along the last action's path where it has a latency.
    pub(super) fn camera_at(&self, i: usize) -> CameraPose {
        let mut cam = self.camera(i);
        let lag = self.camera_lag(i);
        if lag > 0 {
            let stride = self.path_stride;
            cam.position = self.path[i * stride + stride - 1 - lag];
        }
        cam
    }

    /// The obstacles (indices into [`VecEnv::arena`]'s, ascending) that
    /// agent `i`'s present depth frame shows: at least one of its camera's
    /// rays meets each first, within the range
    /// ([`Scene::visible`](crate::Scene::visible)); with
    /// [`SimConfig::sight_rays`](crate::SimConfig::sight_rays), that many
    /// rays a side instead of the camera's pixels.
    pub fn visible_obstacles(&self, i: usize) -> Vec<usize> {
        self.scene.visible(&self.sight_camera(), &self.camera_at(i))
    }

    /// The camera a planner of the pixels casts its rays with: the observed
    /// one, or [`SimConfig::sight_rays`](crate::SimConfig::sight_rays)
    /// columns (and as many rows as the aspect gives) of the same view.
    fn sight_camera(&self) -> CameraSpec {
        let (spec, rays) = (self.cfg.camera.observed(), self.cfg.sight_rays);
        if rays == 0 {
            return spec;
        }
        let rows = (rays * spec.height).div_ceil(spec.width).max(1);
        CameraSpec { width: rays, height: rows, ..spec }
    }

    /// How many physics steps back agent `i`'s camera sees (its latency,
    /// within the last action's path; 0 at the start of an episode).
    fn camera_lag(&self, i: usize) -> usize {
        let (lag, stride) = (self.lag[i], self.path_stride);
        if lag > 0 && stride > 0 && !self.restarted[i] && self.path.len() >= (i + 1) * stride {
            lag.min(stride - 1)
        } else {
            0
        }
    }

    /// Puts the renderers' moving obstacles where they are now.
    fn place_obstacles(&mut self) {
        let t = self.time();
        self.scene.set_time(t);
        if let Some(g) = &mut self.gpu {
            g.set_time(t);
        }
    }

    pub(super) fn render(&mut self) -> Result<(), GpuError> {
        let n = self.cfg.agents;
        if !self.cfg.interactive
            && !self.scene.movers.is_empty()
            && (0..n).any(|i| self.camera_lag(i) > 0)
        {
            return self.render_lagged();
        }
        self.place_obstacles();
        let cams: Vec<CameraPose> = (0..self.cfg.agents).map(|i| self.camera_at(i)).collect();
        let positions: Vec<Vector> = cams.iter().map(|c| c.position).collect();
        let drones = self
            .cfg
            .interactive
            .then_some(Drones { positions: &positions, radius: self.cfg.drone_radius });
        let (spec, px) = (self.cfg.camera, self.cfg.camera.pixels());
        // The renderers draw into the frames themselves, or with a min-pool
        // into the rendered frames first.
        let pooled = spec.pool > 1;
        let mut out = if pooled {
            let mut r = std::mem::take(&mut self.rendered);
            r.resize(cams.len() * px, 0.0);
            r
        } else {
            std::mem::take(&mut self.cur)
        };
        let drawn = match (&mut self.gpu, self.cfg.batched) {
            (Some(g), true) => g.render(&cams, &self.agent_ids, drones, &mut out),
            (None, true) => {
                self.renderer.render(&self.scene, &cams, 0, drones, &mut out);
                Ok(())
            }
            // Non-batched: one request, one submission and one
            // synchronisation per agent.
            (Some(g), false) => out.chunks_mut(px).enumerate().try_for_each(|(i, img)| {
                g.render(&cams[i..i + 1], &self.agent_ids[i..i + 1], drones, img)
            }),
            (None, false) => {
                for (i, img) in out.chunks_mut(px).enumerate() {
                    self.renderer.render(&self.scene, &cams[i..i + 1], i, drones, img);
                }
                Ok(())
            }
        };
        if pooled {
            min_pool(&spec, &out, &mut self.cur);
            self.rendered = out;
        } else {
            self.cur = out;
        }
        drawn?;
        self.pixel_noise.apply(&self.cfg.noise, self.cfg.camera.range, &mut self.cur);
        Ok(())
    }

    /// With the camera's latency and moving obstacles: every agent sees
    /// the movers where they were when its late frame was taken, one render
    /// call per latency (the agents of one latency together).
    fn render_lagged(&mut self) -> Result<(), GpuError> {
        let (n, px) = (self.cfg.agents, self.px());
        let (t, dt) = (self.time(), f64::from(self.cfg.physics_dt));
        let lags: Vec<usize> = (0..n).map(|i| self.camera_lag(i)).collect();
        let mut distinct = lags.clone();
        distinct.sort_unstable();
        distinct.dedup();
        let mut img = Vec::new();
        for lag in distinct {
            let who: Vec<usize> = (0..n).filter(|&i| lags[i] == lag).collect();
            let at = t - lag as f64 * dt;
            self.scene.set_time(at);
            if let Some(g) = &mut self.gpu {
                g.set_time(at);
            }
            let cams: Vec<CameraPose> = who.iter().map(|&i| self.camera_at(i)).collect();
            img.resize(who.len() * px, 0.0);
            self.render_some(&who, &cams, &mut img)?;
            self.put_frames(&who, &img);
        }
        self.place_obstacles();
        self.pixel_noise.apply(&self.cfg.noise, self.cfg.camera.range, &mut self.cur);
        Ok(())
    }

    /// Draws the views of agents `who` from `cams` (one each) into `img`
    /// (`who.len()` observed frames), in one render call, without noise:
    /// the obstacles where the scene has them now.
    fn render_some(
        &mut self,
        who: &[usize],
        cams: &[CameraPose],
        img: &mut [f32],
    ) -> Result<(), GpuError> {
        let spec = self.cfg.camera;
        if spec.pool > 1 {
            // The rendered frames' buffer of `render`, reused.
            let mut rendered = std::mem::take(&mut self.rendered);
            rendered.resize(who.len() * spec.pixels(), 0.0);
            let drawn = self.draw_some(who, cams, &mut rendered);
            min_pool(&spec, &rendered, img);
            self.rendered = rendered;
            return drawn;
        }
        self.draw_some(who, cams, img)
    }

    /// [`VecEnv::render_some`] at the rendered size, before the min-pool.
    fn draw_some(
        &mut self,
        who: &[usize],
        cams: &[CameraPose],
        img: &mut [f32],
    ) -> Result<(), GpuError> {
        match &mut self.gpu {
            Some(g) => {
                let ids: Vec<u32> = who.iter().map(|&i| i as u32).collect();
                g.render(cams, &ids, None, img)?;
            }
            None => self.renderer.render(&self.scene, cams, 0, None, img),
        }
        Ok(())
    }

    /// Makes the frames in `img` (one per agent of `who`, in order) those
    /// agents' current frames.
    fn put_frames(&mut self, who: &[usize], img: &[f32]) {
        let px = self.px();
        for (k, &i) in who.iter().enumerate() {
            self.cur[i * px..(i + 1) * px].copy_from_slice(&img[k * px..(k + 1) * px]);
        }
    }

    pub(super) fn assemble_obs(&mut self) {
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
        let fd = self.cfg.frames * self.px();
        let len = self.obs_len();
        assert!(
            out.len().is_multiple_of(len) && first + out.len() / len <= self.cfg.agents,
            "observation rows out of range"
        );
        let write = |first: usize, rows: &mut [f32]| {
            for (j, o) in rows.chunks_exact_mut(len).enumerate() {
                let i = first + j;
                self.write_depth(i, &mut o[..fd]);
                o[fd..fd + 3].copy_from_slice(&self.body_velocity(i));
                let mut k = fd + 3;
                if self.cfg.goal.enabled {
                    o[k..k + 3].copy_from_slice(&self.goal_observation(i));
                    k += 3;
                }
                self.write_map(i, &mut o[k..]);
                k += self.cfg.map.floats();
                self.write_tracks(i, &mut o[k..]);
            }
        };
        // Copies of the frames, the step's largest serial work after
        // physics and rendering (800 agents at 16 threads: 42 % of a step
        // before it shared the render threads, on a 16-core machine):
        // pieces of OBS_CHUNK agents handed out as threads come free, the
        // same bytes whatever the threads.
        let pool = self.renderer.pool();
        if pool.threads() == 1 || out.len() <= OBS_CHUNK * len {
            write(first, out);
            return;
        }
        let pieces = out.chunks_mut(OBS_CHUNK * len).enumerate();
        pool.share(pieces, |(k, rows)| write(first + k * OBS_CHUNK, rows));
    }

    /// Agent `i`'s goal floats (see [`crate::goal`]); zeros without a goal.
    pub fn goal_observation(&self, i: usize) -> [f32; 3] {
        if !self.cfg.goal.enabled {
            return [0.0; 3];
        }
        let d = &self.drones[i];
        Goal::observe(self.goals[i], d.p, d.q)
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
        let reset: Vec<usize> =
            mask.iter().enumerate().filter(|(_, m)| **m).map(|(i, _)| i).collect();
        if reset.is_empty() {
            return Ok(());
        }
        for &i in &reset {
            self.reset_agent(i);
            self.rewards[i] = 0.0;
            self.dones[i] = Done::Running;
        }
        if self.cfg.interactive {
            // Interactive drones see each other: every image may change.
            self.render()?;
        } else {
            // Only the reset agents' views change: draw just those.
            self.place_obstacles();
            let mut img = vec![0.0; reset.len() * self.px()];
            let cams: Vec<CameraPose> = reset.iter().map(|i| self.camera(*i)).collect();
            self.render_some(&reset, &cams, &mut img)?;
            self.pixel_noise.apply(&self.cfg.noise, self.cfg.camera.range, &mut img);
            self.put_frames(&reset, &img);
        }
        self.map_frames(Some(&reset));
        self.track_frames(Some(&reset));
        for i in reset {
            self.fill_past(i);
        }
        self.assemble_obs();
        Ok(())
    }

    /// Writes every agent's observation split in two, as Gymnasium's `Dict`
    /// observation holds it: `depth` (`agents × frames × side²`, oldest
    /// first, the current one last) and `velocity` (`agents × 3`, body frame).
    pub fn write_observations_split(&self, depth: &mut [f32], velocity: &mut [f32]) {
        let fd = self.cfg.frames * self.px();
        let n = self.cfg.agents;
        assert!(
            depth.len() == n * fd && velocity.len() == n * 3,
            "observation buffers of the wrong size"
        );
        for (i, (d, v)) in depth.chunks_exact_mut(fd).zip(velocity.chunks_exact_mut(3)).enumerate()
        {
            self.write_depth(i, d);
            v.copy_from_slice(&self.body_velocity(i));
        }
    }

    pub(super) fn camera(&self, agent: usize) -> CameraPose {
        let d = &self.drones[agent];
        let pitch = self.pitch[agent];
        let rotation =
            if pitch == 0.0 { d.q } else { d.q * rapier3d::math::Rotation::from_rotation_y(pitch) };
        CameraPose { position: d.p, rotation }
    }

    fn body_velocity(&self, agent: usize) -> [f32; 3] {
        let d = &self.drones[agent];
        (d.q.inverse() * d.v).to_array()
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
