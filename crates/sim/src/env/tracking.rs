//! The seen movers in the environment (`[sim.tracks]`, `crate::tracks`):
//! built with the world, cleared when an agent's episode starts, fed what
//! each frame the agent takes shows of the moving obstacles (whose hits
//! that frame put in the map are taken out again), and written after the
//! map in its observation.

use super::VecEnv;
use crate::SimConfig;
use crate::render::CameraPose;
use crate::render::scene::{Shape, beyond};
use crate::tracks::{Track, Trackers, cast_through};

/// Every agent's tracker, where the config has tracks.
pub(super) fn trackers_of(cfg: &SimConfig) -> Option<Trackers> {
    cfg.tracks.enabled().then(|| Trackers::new(&cfg.tracks, cfg.agents))
}

impl VecEnv {
    /// The trackers take what the agents' current frames show of the
    /// moving obstacles: `who`'s (just reset, seen from their spawn), or
    /// with `None` every agent's (a step's, seen where each camera was
    /// when its frame was taken), on the scene at the frame's time.
    pub(super) fn track_frames(&mut self, who: Option<&[usize]>) {
        if self.trackers.is_none() {
            return;
        }
        let spec = self.cfg.camera.observed();
        let t = self.time();
        let mut mover = vec![false; self.scene.len()];
        for &(k, ..) in &self.scene.movers {
            mover[k as usize] = true;
        }
        let agents: Vec<(usize, CameraPose)> = match who {
            Some(who) => who.iter().map(|&i| (i, self.camera(i))).collect(),
            None => (0..self.cfg.agents).map(|i| (i, self.camera_at(i))).collect(),
        };
        let trackers = self.trackers.as_mut().expect("checked above");
        let band = trackers.spec().band;
        for (i, cam) in agents {
            for k in self.scene.visible_where(&spec, &cam, band, |k| mover[k]) {
                let (lo, hi) = self.scene.bounds_of(k);
                let at = [(lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0];
                let half = [(hi.x - lo.x) / 2.0, (hi.y - lo.y) / 2.0];
                trackers.see(i, k, t, at, half);
                if let Some(maps) = self.maps.as_mut() {
                    maps.forget_hits(i, [lo.x, lo.y], [hi.x, hi.y]);
                }
            }
            trackers.expire(i, t);
        }
    }

    /// Writes agent `i`'s seen movers as its observation reads them
    /// (nothing without tracks): `out` holds
    /// [`TrackSpec::floats`](crate::tracks::TrackSpec::floats) floats.
    pub fn write_tracks(&self, i: usize, out: &mut [f32]) {
        if let Some(tr) = &self.trackers {
            let d = &self.drones[i];
            let f = d.q * rapier3d::math::Vector::X;
            tr.encode(i, d.p, f.y.atan2(f.x), self.time(), out);
        }
    }

    /// Writes agent `i`'s rays through its seen movers ahead
    /// (`sim.map.movers_ahead_s`): for each time ahead, `dirs` turned by
    /// its heading `yaw` (rad) cast level from the drone through every
    /// mover it tracks where its track alone puts it then
    /// ([`Track::predicted`], as the map's planner takes it), each distance a share of `sim.map.ray_range_m`
    /// (1: none within it; all 1 without tracks).
    pub(super) fn write_movers_ahead(
        &self,
        i: usize,
        yaw: f32,
        dirs: &[(f32, f32)],
        out: &mut [f32],
    ) {
        out.fill(1.0);
        let Some(tr) = &self.trackers else { return };
        let (s, reach) = (&self.cfg.map, tr.spec().unseen_reach_m);
        let (p, t, world) = (self.drones[i].p, self.time(), self.arena());
        let predicted: Vec<_> = tr
            .of(i)
            .iter()
            .map(|track| track.predicted(&world.obstacles[track.obstacle].at(track.last_t), reach))
            .collect();
        let heading = (yaw.cos(), yaw.sin());
        let mut shapes = Vec::with_capacity(predicted.len());
        for (&ahead, out) in s.movers_ahead_s.iter().zip(out.chunks_exact_mut(dirs.len())) {
            shapes.clear();
            shapes.extend(predicted.iter().map(|o| Shape::of(&o.at(t + f64::from(ahead)))));
            cast_through(&shapes, p, heading, dirs, s.ray_range_m, out);
        }
    }

    /// Agent `i`'s tracks of the moving obstacles its camera has shown it
    /// (empty without `[sim.tracks]`).
    pub fn tracks_of(&self, i: usize) -> &[Track] {
        self.trackers.as_ref().map_or(&[], |t| t.of(i))
    }

    /// How far a planner of the tracks takes a mover to go on towards an
    /// end it was never seen to turn at (`sim.tracks.unseen_reach_m`).
    pub fn unseen_reach_m(&self) -> f32 {
        self.trackers.as_ref().map_or(crate::tracks::UNSEEN_REACH_M, |t| t.spec().unseen_reach_m)
    }

    /// The moving obstacle nearest agent `i` in its own lane at the
    /// world's present time: its index in the scene (as a [`Track`] names
    /// it) and the distance in x and y from the drone to its bounding box
    /// (m, 0 inside it); `None` where the lane has no movers. The truth,
    /// for instruments (`hive eval --agree`), never an observation.
    pub fn nearest_mover(&self, i: usize) -> Option<(usize, f32)> {
        let p = self.drones[i].p;
        let lane = self.lane_bounds.get(self.agent_lane[i]).copied();
        let t = self.time();
        self.scene
            .movers
            .iter()
            .map(|&(k, base, motion)| (k as usize, base.moved(motion.offset(t)).aabb()))
            .filter(|&(_, (lo, hi))| lane.is_none_or(|walls| !beyond(walls, lo, hi)))
            .map(|(k, (lo, hi))| {
                let dx = (lo.x - p.x).max(p.x - hi.x).max(0.0);
                let dy = (lo.y - p.y).max(p.y - hi.y).max(0.0);
                (k, dx.hypot(dy))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Whether the environment tracks the movers its cameras see.
    pub fn tracks_movers(&self) -> bool {
        self.trackers.is_some()
    }
}
