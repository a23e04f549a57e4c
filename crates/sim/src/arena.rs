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

/// One obstacle. Boxes are axis-aligned; cylinders have a vertical axis.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum Obstacle {
    /// An axis-aligned box.
    Box {
        /// Centre (metres).
        center: [f32; 3],
        /// Half sizes along x, y, z (metres).
        half_extents: [f32; 3],
    },
    /// A cylinder with a vertical axis.
    Cylinder {
        /// Centre (metres).
        center: [f32; 3],
        /// Radius (metres).
        radius: f32,
        /// Half of the height (metres).
        half_height: f32,
    },
}

impl Obstacle {
    /// Centre of the obstacle.
    pub fn center(&self) -> [f32; 3] {
        match self {
            Obstacle::Box { center, .. } | Obstacle::Cylinder { center, .. } => *center,
        }
    }

    /// Axis-aligned bounds `(min, max)`.
    pub fn aabb(&self) -> ([f32; 3], [f32; 3]) {
        let (c, h) = match self {
            Obstacle::Box { center, half_extents } => (*center, *half_extents),
            Obstacle::Cylinder { center, radius, half_height } => {
                (*center, [*radius, *radius, *half_height])
            }
        };
        ([c[0] - h[0], c[1] - h[1], c[2] - h[2]], [c[0] + h[0], c[1] + h[1], c[2] + h[2]])
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
            for o in &a.obstacles {
                obstacles.push(match *o {
                    Obstacle::Box { center, half_extents } => Obstacle::Box {
                        center: [center[0], center[1] + off, center[2]],
                        half_extents,
                    },
                    Obstacle::Cylinder { center, radius, half_height } => Obstacle::Cylinder {
                        center: [center[0], center[1] + off, center[2]],
                        radius,
                        half_height,
                    },
                });
            }
            // The lane's own walls, longer than the camera sees past either end.
            let hl = a.length / 2.0 + 40.0;
            for side in [-1.0f32, 1.0] {
                obstacles.push(Obstacle::Box {
                    center: [
                        a.length / 2.0,
                        off + side * (a.width / 2.0 + LANE_WALL / 2.0),
                        a.height / 2.0,
                    ],
                    half_extents: [hl, LANE_WALL / 2.0, a.height / 2.0],
                });
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
        let (lo, hi) = o.aabb();
        let hw = self.width / 2.0;
        if lo[0] < -EPS
            || hi[0] > self.length + EPS
            || lo[1] < -hw - EPS
            || hi[1] > hw + EPS
            || lo[2] < -EPS
            || hi[2] > self.height + EPS
        {
            let message = format!(
                "obstacle spans x {:.2}..{:.2}, y {:.2}..{:.2}, z {:.2}..{:.2}, outside the arena \
                 (x 0..{}, y -{hw}..{hw}, z 0..{})",
                lo[0], hi[0], lo[1], hi[1], lo[2], hi[2], self.length, self.height
            );
            return Err((what, "center", message));
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
