//! The camera's map in the environment (`[sim.map]`, `crate::map`): built
//! with the world, cleared when an agent's episode starts, fed each frame
//! the agent observes (after noise and dropout, from the pose the frame
//! was taken at) and written after the other scalars of its observation.

use super::VecEnv;
use crate::SimConfig;
use crate::arena::Arena;
use crate::map::Maps;
use crate::render::CameraPose;

/// Every agent's map for a world of `arena` with lanes `bounds`, where the
/// config has one.
pub(super) fn maps_of(cfg: &SimConfig, bounds: &[[f32; 2]], arena: &Arena) -> Option<Maps> {
    cfg.map.enabled().then(|| {
        let widest = bounds.iter().map(|[lo, hi]| hi - lo).fold(0.0f32, f32::max);
        Maps::new(&cfg.map, cfg.agents, arena.length, arena.height, widest, cfg.action_period)
    })
}

impl VecEnv {
    /// The maps take the agents' current frames: `who`'s (just reset,
    /// seen from their spawn), or with `None` every agent's (a step's,
    /// seen where each camera was when its frame was taken).
    pub(super) fn map_frames(&mut self, who: Option<&[usize]>) {
        if self.maps.is_none() {
            return;
        }
        // The map reads the frames as observed: the camera's view at the
        // pooled size.
        let spec = self.cfg.camera.observed();
        match who {
            Some(who) => {
                let px = self.px();
                let cams: Vec<CameraPose> = who.iter().map(|&i| self.camera(i)).collect();
                let maps = self.maps.as_mut().expect("checked above");
                for (&i, cam) in who.iter().zip(&cams) {
                    maps.integrate(i, &self.cur[i * px..(i + 1) * px], &spec, cam);
                }
            }
            None => {
                let cams: Vec<CameraPose> =
                    (0..self.cfg.agents).map(|i| self.camera_at(i)).collect();
                let maps = self.maps.as_mut().expect("checked above");
                maps.integrate_all(self.renderer.pool(), &self.cur, &spec, &cams);
            }
        }
    }

    /// Writes agent `i`'s map as its observation reads it (nothing without
    /// a map): `out` holds [`crate::MapSpec::floats`] floats.
    pub fn write_map(&self, i: usize, out: &mut [f32]) {
        if let Some(m) = &self.maps {
            let d = &self.drones[i];
            let f = d.q * rapier3d::math::Vector::X;
            let yaw = f.y.atan2(f.x);
            m.encode(i, d.p, yaw, out);
            let s = &self.cfg.map;
            if !s.movers_ahead_s.is_empty() {
                self.write_movers_ahead(i, yaw, m.dirs(), &mut out[2 * s.rays..s.floats()]);
            }
        }
    }

    /// What agent `i`'s map holds at `(x, y)` (`None` without a map).
    pub fn map_cell(&self, i: usize, x: f32, y: f32) -> Option<crate::map::Cell> {
        self.maps.as_ref().map(|m| m.at(i, x, y))
    }

    /// Whether agent `i`'s map holds an obstacle cell within the floor-plan
    /// rectangle `[lo, hi]` (false without a map).
    pub fn map_shows(&self, i: usize, lo: [f32; 2], hi: [f32; 2]) -> bool {
        self.maps.as_ref().is_some_and(|m| m.shows(i, lo, hi))
    }

    /// Bytes of one agent's map (0 without one).
    pub fn map_bytes_per_agent(&self) -> usize {
        self.maps.as_ref().map_or(0, Maps::bytes_per_agent)
    }
}
