//! Arenas: the obstacle fields drones fly through, their TOML file format,
//! validation with messages that name the file, obstacle and field, and a seeded
//! procedural generator.

use std::path::Path;

use serde::{Deserialize, Serialize};

/// An error in an arena file or arena description.
#[derive(Debug, thiserror::Error)]
pub enum ArenaError {
    /// The file could not be read.
    #[error("arena {file}: cannot read: {cause}")]
    Io {
        /// The file.
        file: String,
        /// The I/O error (in the text; not `source()`).
        cause: std::io::Error,
    },
    /// The file is not valid TOML or does not match the format.
    #[error("arena {file}: {message}")]
    Parse {
        /// The file.
        file: String,
        /// What the parser said, with the position.
        message: String,
    },
    /// A value is out of range.
    #[error("arena {file}: {what}: field `{field}`: {message}")]
    Invalid {
        /// The file.
        file: String,
        /// `arena` or `obstacle N` (1-based, in file order).
        what: String,
        /// The offending field.
        field: String,
        /// What is wrong with it.
        message: String,
    },
}

/// The spawn region: x and z fixed, y uniform in a range.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Spawn {
    /// Spawn x (metres).
    pub x: f32,
    /// Spawn y range `[min, max]` (metres).
    pub y: [f32; 2],
    /// Spawn altitude, held in flight (metres).
    pub z: f32,
}

/// How an obstacle moves: its centre's offset from the obstacle's `center`
/// as a function of the world's clock (seconds). A moving obstacle is where
/// its motion puts it at every physics step, for collisions and cameras alike.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum Motion {
    /// Back and forth at `speed` (m/s) between `center` and `center +
    /// offset` (x, y; metres).
    Segment {
        /// The far end of the segment, from `center` (metres).
        offset: [f32; 2],
        /// Speed along the segment (m/s).
        speed: f32,
        /// Where on its cycle it is at time 0, as a fraction in [0, 1).
        #[serde(default)]
        phase: f32,
    },
    /// Around a horizontal circle of `radius` centred on `center` at
    /// `speed` (m/s; negative: clockwise).
    Circle {
        /// Radius of the circle its centre follows (metres).
        radius: f32,
        /// Speed along the circle (m/s; negative: clockwise).
        speed: f32,
        /// Where on its cycle it is at time 0, as a fraction in [0, 1).
        #[serde(default)]
        phase: f32,
    },
}

impl Motion {
    /// The centre's offset (x, y) at time `t` (seconds of the world's clock).
    pub fn offset(&self, t: f64) -> [f32; 2] {
        match *self {
            Motion::Segment { offset, speed, phase } => {
                let len = f64::from(offset[0].hypot(offset[1]));
                if len <= 0.0 {
                    return [0.0; 2];
                }
                let cycle = 2.0 * len;
                let s = (f64::from(phase) * cycle + f64::from(speed.abs()) * t).rem_euclid(cycle);
                let along = if s < len { s } else { cycle - s };
                let f = (along / len) as f32;
                [offset[0] * f, offset[1] * f]
            }
            Motion::Circle { radius, speed, phase } => {
                let r = f64::from(radius);
                let a = std::f64::consts::TAU * f64::from(phase) + f64::from(speed) * t / r;
                [(r * a.cos()) as f32, (r * a.sin()) as f32]
            }
        }
    }

    /// The corners (x, y) of the box every offset lies in.
    pub fn reach(&self) -> ([f32; 2], [f32; 2]) {
        match *self {
            Motion::Segment { offset, .. } => {
                ([offset[0].min(0.0), offset[1].min(0.0)], [offset[0].max(0.0), offset[1].max(0.0)])
            }
            Motion::Circle { radius, .. } => ([-radius; 2], [radius; 2]),
        }
    }

    /// Its speed (m/s).
    pub fn speed(&self) -> f32 {
        match *self {
            Motion::Segment { speed, .. } | Motion::Circle { speed, .. } => speed.abs(),
        }
    }

    /// Checks its numbers: the field and what is wrong.
    fn check(&self) -> Result<(), (&'static str, String)> {
        let (speed, phase) = match *self {
            Motion::Segment { offset, speed, phase } => {
                if !offset.iter().all(|v| v.is_finite()) {
                    return Err(("motion.offset", format!("must be finite, got {offset:?}")));
                }
                (speed, phase)
            }
            Motion::Circle { radius, speed, phase } => {
                if !(radius.is_finite() && radius > 0.0) {
                    return Err(("motion.radius", format!("must be positive, got {radius}")));
                }
                (speed, phase)
            }
        };
        if !(speed.is_finite() && speed.abs() <= MAX_OBSTACLE_SPEED) {
            let message = format!(
                "must lie in [-{MAX_OBSTACLE_SPEED}, {MAX_OBSTACLE_SPEED}] m/s, got {speed}"
            );
            return Err(("motion.speed", message));
        }
        if !(phase.is_finite() && (0.0..1.0).contains(&phase)) {
            return Err(("motion.phase", format!("must lie in [0, 1), got {phase}")));
        }
        Ok(())
    }
}

/// The fastest an obstacle may move (m/s): the collision query and the
/// rapier path are checked for tunnelling up to it (`tests/moving.rs`).
pub const MAX_OBSTACLE_SPEED: f32 = 10.0;

/// One obstacle. Boxes are axis-aligned; cylinders have a vertical axis.
/// Either may move (`motion`, absent: it stands still).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum Obstacle {
    /// An axis-aligned box.
    Box {
        /// Centre (metres).
        center: [f32; 3],
        /// Half sizes along x, y, z (metres).
        half_extents: [f32; 3],
        /// How it moves (absent: it stands still).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        motion: Option<Motion>,
    },
    /// A cylinder with a vertical axis.
    Cylinder {
        /// Centre (metres).
        center: [f32; 3],
        /// Radius (metres).
        radius: f32,
        /// Half of the height (metres).
        half_height: f32,
        /// How it moves (absent: it stands still).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        motion: Option<Motion>,
    },
}

impl Obstacle {
    /// A box that stands still.
    pub fn still_box(center: [f32; 3], half_extents: [f32; 3]) -> Self {
        Obstacle::Box { center, half_extents, motion: None }
    }

    /// A cylinder that stands still.
    pub fn still_cylinder(center: [f32; 3], radius: f32, half_height: f32) -> Self {
        Obstacle::Cylinder { center, radius, half_height, motion: None }
    }

    /// Centre of the obstacle (where its motion starts from).
    pub fn center(&self) -> [f32; 3] {
        match self {
            Obstacle::Box { center, .. } | Obstacle::Cylinder { center, .. } => *center,
        }
    }

    /// How it moves, if it does.
    pub fn motion(&self) -> Option<&Motion> {
        match self {
            Obstacle::Box { motion, .. } | Obstacle::Cylinder { motion, .. } => motion.as_ref(),
        }
    }

    /// Sets (or clears) how it moves.
    pub fn set_motion(&mut self, m: Option<Motion>) {
        match self {
            Obstacle::Box { motion, .. } | Obstacle::Cylinder { motion, .. } => *motion = m,
        }
    }

    /// The same obstacle moved by `d` (metres), its motion kept.
    pub fn shifted(&self, d: [f32; 3]) -> Self {
        let mut o = self.clone();
        match &mut o {
            Obstacle::Box { center, .. } | Obstacle::Cylinder { center, .. } => {
                for k in 0..3 {
                    center[k] += d[k];
                }
            }
        }
        o
    }

    /// Where it is at time `t` of the world's clock: a still obstacle at
    /// its motion's offset (itself when it does not move).
    pub fn at(&self, t: f64) -> Self {
        match self.motion() {
            None => self.clone(),
            Some(m) => {
                let [dx, dy] = m.offset(t);
                let mut o = self.shifted([dx, dy, 0.0]);
                o.set_motion(None);
                o
            }
        }
    }

    /// Axis-aligned bounds `(min, max)` at its centre.
    pub fn aabb(&self) -> ([f32; 3], [f32; 3]) {
        let (c, h) = match self {
            Obstacle::Box { center, half_extents, .. } => (*center, *half_extents),
            Obstacle::Cylinder { center, radius, half_height, .. } => {
                (*center, [*radius, *radius, *half_height])
            }
        };
        ([c[0] - h[0], c[1] - h[1], c[2] - h[2]], [c[0] + h[0], c[1] + h[1], c[2] + h[2]])
    }

    /// Axis-aligned bounds `(min, max)` of everywhere it goes.
    pub fn swept_aabb(&self) -> ([f32; 3], [f32; 3]) {
        let (mut lo, mut hi) = self.aabb();
        if let Some(m) = self.motion() {
            let (a, b) = m.reach();
            for k in 0..2 {
                lo[k] += a[k];
                hi[k] += b[k];
            }
        }
        (lo, hi)
    }
}

/// An arena: a corridor from x = 0 to x = `length`, walls at y = ±`width`/2,
/// floor at z = 0 and ceiling at z = `height`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Arena {
    /// Name, for messages and pictures.
    pub name: String,
    /// Length along x (metres); reaching it ends an episode as a success.
    pub length: f32,
    /// Width along y (metres).
    pub width: f32,
    /// Height along z (metres).
    pub height: f32,
    /// Spawn region.
    pub spawn: Spawn,
    /// Obstacles.
    #[serde(default, rename = "obstacle")]
    pub obstacles: Vec<Obstacle>,
}

/// Several arenas side by side along y, as one world.
#[derive(Debug, Clone)]
pub struct Lanes {
    /// The combined arena: every lane's obstacles moved to its place, plus
    /// each lane's two walls as boxes; outer walls, floor and ceiling as usual.
    pub world: Arena,
    /// The y offset of each lane's centre line.
    pub offsets: Vec<f32>,
    /// Each lane's spawn region, in its own coordinates.
    pub spawns: Vec<Spawn>,
    /// Each lane's free space along y, between its walls' inner faces:
    /// nothing beyond them can be seen from inside the lane.
    pub bounds: Vec<[f32; 2]>,
}

/// Thickness of the walls between lanes (metres).
const LANE_WALL: f32 = 0.5;

impl Lanes {
    /// Puts arenas of equal length and height side by side: lane k's centre
    /// line at y = offsets[k], walls of its own width, so an agent neither
    /// sees nor touches another lane. One arena is itself, unchanged.
    pub fn new(arenas: &[Arena]) -> Result<Self, ArenaError> {
        let first = arenas.first().ok_or_else(|| ArenaError::Invalid {
            file: "lanes".into(),
            what: "lanes".into(),
            field: "arenas".into(),
            message: "no arena given".into(),
        })?;
        if arenas.len() == 1 {
            let hw = first.width / 2.0;
            return Ok(Self {
                world: first.clone(),
                offsets: vec![0.0],
                spawns: vec![first.spawn.clone()],
                bounds: vec![[-hw, hw]],
            });
        }
        for a in arenas {
            if a.length != first.length || a.height != first.height {
                return Err(ArenaError::Invalid {
                    file: a.name.clone(),
                    what: format!("arena {:?}", a.name),
                    field: "length/height".into(),
                    message: format!(
                        "lanes must share length and height ({} × {} against {} × {})",
                        a.length, a.height, first.length, first.height
                    ),
                });
            }
        }
        let pitch = arenas.iter().map(|a| a.width).fold(0.0f32, f32::max) + 2.0 * LANE_WALL;
        let total = pitch * arenas.len() as f32;
        let mut obstacles = Vec::new();
        let mut offsets = Vec::new();
        let mut bounds = Vec::new();
        for (k, a) in arenas.iter().enumerate() {
            let off = -total / 2.0 + pitch * (k as f32 + 0.5);
            offsets.push(off);
            bounds.push([off - a.width / 2.0, off + a.width / 2.0]);
            obstacles.extend(a.obstacles.iter().map(|o| o.shifted([0.0, off, 0.0])));
            // The lane's own walls, longer than the camera sees past either end.
            let hl = a.length / 2.0 + 40.0;
            for side in [-1.0f32, 1.0] {
                obstacles.push(Obstacle::still_box(
                    [
                        a.length / 2.0,
                        off + side * (a.width / 2.0 + LANE_WALL / 2.0),
                        a.height / 2.0,
                    ],
                    [hl, LANE_WALL / 2.0, a.height / 2.0],
                ));
            }
        }
        let world = Arena {
            name: format!("{} lanes", arenas.len()),
            length: first.length,
            width: total,
            height: first.height,
            spawn: first.spawn.clone(),
            obstacles,
        };
        Ok(Self {
            world,
            offsets,
            spawns: arenas.iter().map(|a| a.spawn.clone()).collect(),
            bounds,
        })
    }
}

impl Arena {
    /// Reads and validates an arena file.
    pub fn load(path: &Path) -> Result<Self, ArenaError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|cause| ArenaError::Io { file: file.clone(), cause })?;
        Self::parse(&text, &file)
    }

    /// Parses and validates arena TOML; `file` names the source in messages.
    pub fn parse(text: &str, file: &str) -> Result<Self, ArenaError> {
        let arena: Arena = toml::from_str(text).map_err(|e| ArenaError::Parse {
            file: file.to_string(),
            message: e.to_string().trim_end().to_string(),
        })?;
        arena.validate(file)?;
        Ok(arena)
    }

    /// Serialises to the arena file format.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("an arena always serialises")
    }

    /// Checks sizes, the spawn region and that every obstacle lies inside the arena.
    pub fn validate(&self, file: &str) -> Result<(), ArenaError> {
        let bad = |what: String, field: &str, message: String| ArenaError::Invalid {
            file: file.to_string(),
            what,
            field: field.to_string(),
            message,
        };
        let arena = || "arena".to_string();
        for (field, v) in [("length", self.length), ("width", self.width), ("height", self.height)]
        {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(arena(), field, format!("must be a positive number, got {v}")));
            }
        }
        let hw = self.width / 2.0;
        let s = &self.spawn;
        if !(s.x.is_finite() && s.x >= 0.0 && s.x < self.length) {
            return Err(bad(
                arena(),
                "spawn.x",
                format!("must lie in [0, length = {}), got {}", self.length, s.x),
            ));
        }
        if !(s.y[0] <= s.y[1] && s.y[0] > -hw && s.y[1] < hw) {
            return Err(bad(
                arena(),
                "spawn.y",
                format!("must be an ordered range inside (-{hw}, {hw}), got {:?}", s.y),
            ));
        }
        if !(s.z > 0.0 && s.z < self.height) {
            return Err(bad(
                arena(),
                "spawn.z",
                format!("must lie in (0, height = {}), got {}", self.height, s.z),
            ));
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            self.validate_obstacle(i, o)
                .map_err(|(what, field, message)| bad(what, field, message))?;
        }
        Ok(())
    }

    /// Checks obstacle `i`'s sizes and that it lies inside the arena: the
    /// obstacle, the field and the message of what is wrong.
    fn validate_obstacle(
        &self,
        i: usize,
        o: &Obstacle,
    ) -> Result<(), (String, &'static str, String)> {
        const EPS: f32 = 1e-3;
        let kind = match o {
            Obstacle::Box { .. } => "box",
            Obstacle::Cylinder { .. } => "cylinder",
        };
        let what = format!("obstacle {} ({kind})", i + 1);
        let positive = |field: &'static str, v: f32| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err((what.clone(), field, format!("must be positive, got {v}")))
            }
        };
        match o {
            Obstacle::Box { half_extents, .. } => {
                if half_extents.iter().any(|h| !(h.is_finite() && *h > 0.0)) {
                    let message = format!("must be positive, got {half_extents:?}");
                    return Err((what, "half_extents", message));
                }
            }
            Obstacle::Cylinder { radius, half_height, .. } => {
                positive("radius", *radius)?;
                positive("half_height", *half_height)?;
            }
        }
        let c = o.center();
        if c.iter().any(|v| !v.is_finite()) {
            return Err((what, "center", format!("must be finite, got {c:?}")));
        }
        if let Some(m) = o.motion() {
            m.check().map_err(|(field, message)| (what.clone(), field, message))?;
        }
        // A moving obstacle must stay inside wherever it goes.
        let (lo, hi) = o.swept_aabb();
        let hw = self.width / 2.0;
        if lo[0] < -EPS
            || hi[0] > self.length + EPS
            || lo[1] < -hw - EPS
            || hi[1] > hw + EPS
            || lo[2] < -EPS
            || hi[2] > self.height + EPS
        {
            let moving = if o.motion().is_some() { " (where its motion takes it)" } else { "" };
            let message = format!(
                "obstacle spans x {:.2}..{:.2}, y {:.2}..{:.2}, z {:.2}..{:.2}{moving}, outside \
                 the arena (x 0..{}, y -{hw}..{hw}, z 0..{})",
                lo[0], hi[0], lo[1], hi[1], lo[2], hi[2], self.length, self.height
            );
            let field = if o.motion().is_some() { "motion" } else { "center" };
            return Err((what, field, message));
        }
        Ok(())
    }

    /// The lateral position of a straight flight along +x that passes every
    /// obstacle with x below `reach`, or `None` when all are blocked.
    pub fn unblocked_line(&self, drone_radius: f32, reach: f32) -> Option<f32> {
        first_unblocked_line(&self.obstacles, self.width, drone_radius, reach)
    }
}

/// Scans y in 5 cm steps across the corridor and returns the first y whose
/// straight line along +x meets no obstacle (widened by the drone radius) before `reach`.
pub(crate) fn first_unblocked_line(
    obstacles: &[Obstacle],
    width: f32,
    drone_radius: f32,
    reach: f32,
) -> Option<f32> {
    let hw = width / 2.0;
    let steps = (width / 0.05) as i32;
    (0..=steps)
        .map(|i| -hw + drone_radius + i as f32 * 0.05)
        .filter(|y| *y <= hw - drone_radius)
        .find(|&y| {
            !obstacles.iter().any(|o| {
                let (lo, hi) = o.aabb();
                lo[0] < reach && y > lo[1] - drone_radius && y < hi[1] + drone_radius
            })
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
name = "t"
length = 50.0
width = 10.0
height = 5.0
spawn = { x = 2.0, y = [-1.0, 1.0], z = 2.0 }

[[obstacle]]
kind = "box"
center = [20.0, 1.5, 2.5]
half_extents = [0.5, 1.0, 2.5]

[[obstacle]]
kind = "cylinder"
center = [30.0, -2.0, 2.5]
radius = 0.6
half_height = 2.5
"#;

    #[test]
    fn parses_the_documented_format() {
        let a = Arena::parse(GOOD, "good.toml").unwrap();
        assert_eq!(a.obstacles.len(), 2);
        assert!(matches!(a.obstacles[1], Obstacle::Cylinder { radius, .. } if radius == 0.6));
        // And survives a round trip through its own writer.
        assert_eq!(Arena::parse(&a.to_toml(), "x").unwrap(), a);
    }

    fn err(text: &str) -> String {
        Arena::parse(text, "bad.toml").unwrap_err().to_string()
    }

    #[test]
    fn obstacle_outside_bounds_names_file_obstacle_and_field() {
        let m = err(&GOOD.replace("[30.0, -2.0, 2.5]", "[30.0, -9.0, 2.5]"));
        assert!(m.contains("bad.toml") && m.contains("obstacle 2") && m.contains("center"), "{m}");
    }

    #[test]
    fn negative_sizes_are_refused() {
        let m = err(&GOOD.replace("radius = 0.6", "radius = -0.6"));
        assert!(m.contains("obstacle 2") && m.contains("radius"), "{m}");
        let m = err(&GOOD.replace("width = 10.0", "width = -10.0"));
        assert!(m.contains("width") && m.contains("positive"), "{m}");
    }

    const MOVING: &str = r#"
[[obstacle]]
kind = "box"
center = [20.0, 1.0, 2.5]
half_extents = [0.5, 0.5, 2.5]
motion = { kind = "segment", offset = [0.0, -3.0], speed = 0.5 }

[[obstacle]]
kind = "cylinder"
center = [30.0, 0.0, 2.5]
radius = 0.5
half_height = 2.5
motion = { kind = "circle", radius = 1.5, speed = -0.4, phase = 0.25 }
"#;

    #[test]
    fn moving_obstacles_parse_move_and_stay_inside() {
        let head = GOOD.split("[[obstacle]]").next().unwrap();
        let a = Arena::parse(&format!("{head}{MOVING}"), "m.toml").unwrap();
        assert_eq!(Arena::parse(&a.to_toml(), "x").unwrap(), a);
        // A still file writes no motion.
        assert!(!Arena::parse(GOOD, "g").unwrap().to_toml().contains("motion"));
        let seg = &a.obstacles[0];
        // Back and forth at 0.5 m/s over 3 m: at the far end after 6 s, home after 12 s.
        assert_eq!(seg.at(0.0).center(), [20.0, 1.0, 2.5]);
        assert!((seg.at(3.0).center()[1] - -0.5).abs() < 1e-5);
        assert!((seg.at(6.0).center()[1] - -2.0).abs() < 1e-5);
        assert!((seg.at(9.0).center()[1] - -0.5).abs() < 1e-5);
        assert!((seg.at(12.0).center()[1] - 1.0).abs() < 1e-4);
        assert!(seg.at(3.0).motion().is_none());
        // The circle: a quarter turn in, at its top; clockwise a quarter
        // turn later (0.4 m/s on a 1.5 m circle) on its right.
        let c = &a.obstacles[1];
        let at = |t: f64| c.at(t).center();
        assert!((at(0.0)[0] - 30.0).abs() < 1e-5 && (at(0.0)[1] - 1.5).abs() < 1e-5);
        let quarter = std::f64::consts::FRAC_PI_2 * 1.5 / 0.4;
        assert!((at(quarter)[0] - 31.5).abs() < 1e-4 && at(quarter)[1].abs() < 1e-4);
        assert_eq!(c.swept_aabb().0[1], -2.0);
        // Where the motion leaves the arena, the file is refused by name.
        let m = err(&format!("{head}{}", MOVING.replace("[0.0, -3.0]", "[0.0, -6.0]")));
        assert!(
            m.contains("obstacle 1") && m.contains("motion") && m.contains("where its motion"),
            "{m}"
        );
        let m = err(&format!("{head}{}", MOVING.replace("speed = -0.4", "speed = 40.0")));
        assert!(m.contains("obstacle 2") && m.contains("motion.speed"), "{m}");
        let m = err(&format!("{head}{}", MOVING.replace("kind = \"circle\"", "kind = \"spiral\"")));
        assert!(m.contains("spiral"), "{m}");
    }

    #[test]
    fn unknown_keys_and_kinds_are_refused() {
        let m = err(&GOOD.replace("radius = 0.6", "radius = 0.6\ncolour = 3"));
        assert!(m.contains("bad.toml") && m.contains("colour"), "{m}");
        let m = err(&GOOD.replace("kind = \"box\"", "kind = \"sphere\""));
        assert!(m.contains("sphere"), "{m}");
        let m = err(&GOOD.replace("name = \"t\"", "name = \"t\"\nlenght = 3.0"));
        assert!(m.contains("lenght"), "{m}");
    }
}
