//! Goal-directed flight (`[sim.goal]`): a point near the arena's far end at
//! a lateral offset drawn per episode. Success is coming within `radius` of
//! it; the reward gains the progress toward it and a bonus on arrival; the
//! observation gains its bearing, distance and lateral offset in the body
//! frame (`rotorhive_msg::GOAL_DIM` floats after the velocity).

use rapier3d::math::{Rotation, Vector};

/// The goal's settings (`[sim.goal]`; off by default: the paper's task).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Goal {
    /// Whether episodes have a goal (and observations the goal's floats).
    pub enabled: bool,
    /// Range of the goal's lateral offset from the lane's centre line (m),
    /// drawn per episode.
    pub lateral: [f32; 2],
    /// How far before the arena's far end the goal lies (m).
    pub from_end: f32,
    /// Success: the drone's centre comes within this horizontal distance (m).
    pub radius: f32,
    /// Reward per metre the horizontal distance to the goal shrinks in a
    /// step (negative when it grows), on top of `sim.reward_step`.
    pub reward_progress: f32,
    /// Reward of the step that reaches the goal.
    pub reward_reach: f32,
    /// Reward of the step that flies past the goal without reaching it (the
    /// episode ends as a timeout: the drone cannot turn back).
    pub reward_miss: f32,
}

impl Default for Goal {
    fn default() -> Self {
        Self {
            enabled: false,
            lateral: [-4.0, 4.0],
            from_end: 5.0,
            radius: 1.0,
            reward_progress: 1.0,
            reward_reach: 100.0,
            reward_miss: -10.0,
        }
    }
}

/// What one step did with respect to the goal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Progress {
    /// Still on the way; the horizontal distance now.
    Flying(f32),
    /// Came within the radius during the step.
    Reached,
    /// Passed the goal's line without reaching it.
    Missed,
}

impl Goal {
    /// Whether the settings are the defaults (no goal): a config writes
    /// no `[sim.goal]` then.
    pub fn is_off(&self) -> bool {
        *self == Self::default()
    }

    /// Checks the ranges; the key (under `[sim.goal]`) and what is wrong.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let [lo, hi] = self.lateral;
        if !(lo.is_finite() && hi.is_finite() && lo <= hi && lo.abs().max(hi.abs()) <= 50.0) {
            return Err((
                "lateral",
                format!("must be an ordered range within ±50 m, got {:?}", self.lateral),
            ));
        }
        for (key, v, lo, hi) in [
            ("from_end", self.from_end, 0.0, 100.0),
            ("radius", self.radius, 0.1, 10.0),
            ("reward_progress", self.reward_progress, -100.0, 100.0),
            ("reward_reach", self.reward_reach, -1e4, 1e4),
            ("reward_miss", self.reward_miss, -1e4, 1e4),
        ] {
            if !(lo..=hi).contains(&v) {
                return Err((key, format!("must lie in [{lo}, {hi}], got {v}")));
            }
        }
        Ok(())
    }

    /// The horizontal distance from `p` to the goal at `at`.
    pub(crate) fn distance(at: [f32; 2], p: Vector) -> f32 {
        (at[0] - p.x).hypot(at[1] - p.y)
    }

    /// The horizontal distance from `at` to the straight segment from
    /// `from` to `to`.
    pub(crate) fn closest(at: [f32; 2], from: Vector, to: Vector) -> f32 {
        let (ax, ay) = (from.x, from.y);
        let (dx, dy) = (to.x - ax, to.y - ay);
        let len2 = dx * dx + dy * dy;
        let t = if len2 > 0.0 {
            (((at[0] - ax) * dx + (at[1] - ay) * dy) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (at[0] - (ax + t * dx)).hypot(at[1] - (ay + t * dy))
    }

    /// How a step from `from` to `to` went toward the goal at `at`: within
    /// the radius anywhere on the straight segment between them is reached
    /// (at 1 m/s and 1 s per action the ends alone could step over a 1 m
    /// radius), past its line is missed.
    pub(crate) fn progress(&self, at: [f32; 2], from: Vector, to: Vector) -> Progress {
        if Self::closest(at, from, to) <= self.radius {
            Progress::Reached
        } else if to.x >= at[0] + self.radius {
            Progress::Missed
        } else {
            Progress::Flying(Self::distance(at, to))
        }
    }

    /// The goal's floats of an observation: bearing (rad, body frame,
    /// positive to the left), horizontal distance and lateral offset (body
    /// frame), both in tens of metres.
    pub(crate) fn observe(at: [f32; 2], p: Vector, q: Rotation) -> [f32; 3] {
        let rel = q.inverse() * Vector::new(at[0] - p.x, at[1] - p.y, 0.0);
        let (fwd, lat) = (rel.x, rel.y);
        [lat.atan2(fwd), fwd.hypot(lat) / 10.0, lat / 10.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_that_passes_within_the_radius_reaches_the_goal() {
        let g = Goal::default();
        let at = [100.0, 2.0];
        // Both ends 1.2 m away, the segment between them within 0.5 m.
        let (from, to) = (Vector::new(99.1, 2.5, 2.0), Vector::new(100.9, 2.5, 2.0));
        assert_eq!(g.progress(at, from, to), Progress::Reached);
        // Passing 3 m to the side: missed once past the line.
        let (from, to) = (Vector::new(99.5, 5.0, 2.0), Vector::new(101.5, 5.0, 2.0));
        assert_eq!(g.progress(at, from, to), Progress::Missed);
        // On the way.
        let (from, to) = (Vector::new(50.0, 0.0, 2.0), Vector::new(51.0, 0.0, 2.0));
        let Progress::Flying(d) = g.progress(at, from, to) else { panic!("still flying") };
        assert!((d - 49.0f32.hypot(2.0)).abs() < 1e-4);
    }

    #[test]
    fn the_goal_is_observed_in_the_body_frame() {
        let at = [20.0, 10.0];
        let [b, d, l] = Goal::observe(at, Vector::new(10.0, 0.0, 2.0), Rotation::IDENTITY);
        assert!((b - std::f32::consts::FRAC_PI_4).abs() < 1e-5, "{b}");
        assert!((d - 200f32.sqrt() / 10.0).abs() < 1e-5);
        assert!((l - 1.0).abs() < 1e-5);
        // Heading 45° to the left: the goal is dead ahead.
        let q = Rotation::from_rotation_z(std::f32::consts::FRAC_PI_4);
        let [b, _, l] = Goal::observe(at, Vector::new(10.0, 0.0, 2.0), q);
        assert!(b.abs() < 1e-5 && l.abs() < 1e-5, "{b} {l}");
        assert!(Goal { radius: 0.0, ..Goal::default() }.validate().is_err());
        assert!(Goal { lateral: [3.0, -3.0], ..Goal::default() }.validate().is_err());
        assert!(Goal::default().validate().is_ok());
    }
}
