//! The seeded arena generator (`[sim.generator]` of a config, `hive
//! gen-arena`): rows of boxes and cylinders along the corridor, or a forest
//! of thin cylinders, optionally walls with one door, every straight flight
//! blocked within a distance, and a check that a path through exists.
//!
//! The defaults are the generator of the first three waves, draw for draw:
//! a config without `[sim.generator]` gets the same layouts as before.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use crate::arena::{Arena, MAX_OBSTACLE_SPEED, Motion, Obstacle, Spawn, first_unblocked_line};

/// How obstacles are placed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GenMode {
    /// Rows about `spacing` apart of `1..=per_row` boxes and cylinders.
    #[default]
    Rows,
    /// Vertical cylinders scattered uniformly at `forest_density` per m².
    Forest,
}

/// Parameters of the procedural generator (`[sim.generator]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GenParams {
    /// Arena length (metres).
    pub length: f32,
    /// Arena width (metres).
    pub width: f32,
    /// Arena height (metres).
    pub height: f32,
    /// Rows or forest.
    pub mode: GenMode,
    /// Mean distance between successive rows along x (metres; rows mode).
    pub spacing: f32,
    /// Most obstacles in one row (rows mode; 1 = the paper's generator).
    pub per_row: u32,
    /// Range of a box's half size along x (metres).
    pub box_half_x: [f32; 2],
    /// Range of a box's half size along y (metres).
    pub box_half_y: [f32; 2],
    /// Range of a (rows mode) cylinder's radius (metres).
    pub cylinder_radius: [f32; 2],
    /// Cylinders per m² (forest mode).
    pub forest_density: f32,
    /// Range of a forest cylinder's radius (metres).
    pub forest_radius: [f32; 2],
    /// A wall across the corridor with one door every this many metres
    /// (0: none): passages that must be chosen early.
    pub door_every: f32,
    /// Range of a door's width (metres).
    pub door_width: [f32; 2],
    /// Obstacles start at this x (metres).
    pub first_x: f32,
    /// Every straight line from the spawn region is blocked before this many
    /// metres past the spawn (0: no blocking pass).
    pub block_within: f32,
    /// Narrowest passage the path check lets through (metres): a disc of
    /// this diameter must fit along some path from the spawn region to the
    /// end (0: the drone's own diameter).
    pub min_gap: f32,
    /// Whether every layout must have such a path (layouts without one are
    /// drawn again, then thinned).
    pub require_path: bool,
    /// Steepest lateral slope of that path (metres sideways per metre
    /// forward): what the drone's lateral acceleration allows, with margin.
    pub path_slope: f32,
    /// Share of the rows' (or the forest's) obstacles that move (0: none,
    /// and nothing more is drawn, so the layouts are those of before).
    /// Half of them go back and forth across the corridor, half around a
    /// circle; the path check looks at the obstacles that stand still.
    pub moving_share: f32,
    /// Range of a moving obstacle's speed (m/s).
    pub moving_speed: [f32; 2],
    /// Range of a moving obstacle's travel: a segment's length, a circle's
    /// diameter (metres).
    pub moving_span: [f32; 2],
    /// Radius of the drone (metres): set from `sim.drone_radius`.
    #[serde(skip)]
    pub drone_radius: f32,
}

impl Default for GenParams {
    fn default() -> Self {
        Self {
            length: 150.0,
            width: 12.0,
            height: 6.0,
            mode: GenMode::Rows,
            spacing: 6.0,
            per_row: 1,
            box_half_x: [0.3, 1.0],
            box_half_y: [0.4, 1.2],
            cylinder_radius: [0.4, 0.9],
            forest_density: 0.05,
            forest_radius: [0.15, 0.5],
            door_every: 0.0,
            door_width: [1.2, 2.0],
            first_x: 12.0,
            block_within: 90.0,
            min_gap: 0.0,
            require_path: false,
            path_slope: 0.5,
            moving_share: 0.0,
            moving_speed: [0.2, 0.6],
            moving_span: [1.0, 3.0],
            drone_radius: 0.3,
        }
    }
}

/// A parameter of the generator that is out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("key `{key}`: {message}")]
pub struct GenParamError {
    /// The key under `[sim.generator]`.
    pub key: &'static str,
    /// What is wrong.
    pub message: String,
}

/// Layouts drawn before a layout without a path is thinned instead.
const REDRAWS: usize = 50;

impl GenParams {
    /// L4 `moving`'s rows (`configs/levels/moving.toml`: L1's rows with
    /// three in ten obstacles moving) over `length` metres; the planner's
    /// tests and the labels bench generate from it.
    pub fn l4_rows(length: f32) -> Self {
        Self {
            length,
            spacing: 3.0,
            per_row: 2,
            box_half_x: [0.3, 1.0],
            box_half_y: [0.6, 1.5],
            cylinder_radius: [0.4, 1.0],
            min_gap: 1.2,
            require_path: true,
            moving_share: 0.3,
            moving_speed: [0.2, 0.6],
            ..Self::default()
        }
    }

    /// Checks every value the generator relies on.
    pub fn validate(&self) -> Result<(), GenParamError> {
        let bad = |key, message: String| Err(GenParamError { key, message });
        for (key, v) in [
            ("length", self.length),
            ("width", self.width),
            ("height", self.height),
            ("spacing", self.spacing),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(key, format!("must be positive, got {v}"));
            }
        }
        if !(self.length >= self.first_x + 10.0 && self.first_x >= 4.0) {
            return bad(
                "length",
                format!(
                    "must exceed first_x + 10 = {} m (first_x at least 4 m)",
                    self.first_x + 10.0
                ),
            );
        }
        if self.mode == GenMode::Rows && self.spacing < 0.5 {
            return bad("spacing", format!("must be at least 0.5 m, got {}", self.spacing));
        }
        if !(1..=4).contains(&self.per_row) {
            return bad("per_row", format!("must be 1 to 4, got {}", self.per_row));
        }
        for (key, r, most) in [
            ("box_half_x", self.box_half_x, 5.0),
            ("box_half_y", self.box_half_y, self.width / 4.0),
            ("cylinder_radius", self.cylinder_radius, self.width / 4.0),
            ("forest_radius", self.forest_radius, self.width / 4.0),
            ("door_width", self.door_width, self.width - 1.0),
        ] {
            if !(r[0].is_finite() && r[1].is_finite() && r[0] > 0.0 && r[0] <= r[1] && r[1] <= most)
            {
                return bad(
                    key,
                    format!("must be an ordered range of positive sizes up to {most} m, got {r:?}"),
                );
            }
        }
        if !(self.forest_density.is_finite() && (0.0..=0.5).contains(&self.forest_density)) {
            return bad(
                "forest_density",
                format!("must lie in [0, 0.5] per m², got {}", self.forest_density),
            );
        }
        for (key, v) in [
            ("door_every", self.door_every),
            ("block_within", self.block_within),
            ("min_gap", self.min_gap),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(key, format!("must be 0 or positive, got {v}"));
            }
        }
        if self.door_every > 0.0 && self.door_every < 4.0 {
            return bad(
                "door_every",
                format!("must be 0 (none) or at least 4 m, got {}", self.door_every),
            );
        }
        if self.min_gap > self.width / 2.0 {
            return bad(
                "min_gap",
                format!(
                    "must be at most half the width ({} m), got {}",
                    self.width / 2.0,
                    self.min_gap
                ),
            );
        }
        if !(self.path_slope.is_finite() && self.path_slope > 0.0 && self.path_slope <= 3.0) {
            return bad("path_slope", format!("must lie in (0, 3], got {}", self.path_slope));
        }
        self.validate_moving()
    }

    /// Checks the keys of moving obstacles.
    fn validate_moving(&self) -> Result<(), GenParamError> {
        let bad = |key, message: String| Err(GenParamError { key, message });
        if !(self.moving_share.is_finite() && (0.0..=1.0).contains(&self.moving_share)) {
            return bad("moving_share", format!("must lie in [0, 1], got {}", self.moving_share));
        }
        let [s0, s1] = self.moving_speed;
        if !(s0.is_finite() && s1.is_finite() && 0.0 <= s0 && s0 <= s1 && s1 <= MAX_OBSTACLE_SPEED)
        {
            return bad(
                "moving_speed",
                format!(
                    "must be an ordered range in [0, {MAX_OBSTACLE_SPEED}] m/s, got {:?}",
                    self.moving_speed
                ),
            );
        }
        let [a, b] = self.moving_span;
        if !(a.is_finite() && b.is_finite() && 0.0 < a && a <= b && b <= self.width / 2.0) {
            return bad(
                "moving_span",
                format!(
                    "must be an ordered range of positive lengths up to half the width ({} m), \
                     got {:?}",
                    self.width / 2.0,
                    self.moving_span
                ),
            );
        }
        Ok(())
    }

    /// Clearance the path check keeps from every obstacle and wall.
    fn clearance(&self) -> f32 {
        (self.min_gap / 2.0).max(self.drone_radius)
    }
}

/// A uniform draw from `[lo, hi)`, or `lo` when the range is empty.
fn draw(rng: &mut Pcg64Mcg, [lo, hi]: [f32; 2]) -> f32 {
    if hi > lo { rng.random_range(lo..hi) } else { lo }
}

impl Arena {
    /// Generates a random arena from `params` (see [`GenParams`]): its
    /// obstacles, then more until every straight flight from the spawn
    /// region is blocked within `params.block_within` metres; with
    /// `require_path`, layouts are drawn until one has a path through (then
    /// the last is thinned until it has one).
    pub fn generate(name: &str, seed: u64, params: &GenParams) -> Self {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let mut arena = layout(name, &mut rng, params);
        if !params.require_path {
            return arena;
        }
        for _ in 1..REDRAWS {
            if arena.has_path(params.clearance(), params.path_slope) {
                return arena;
            }
            arena = layout(name, &mut rng, params);
        }
        while !arena.has_path(params.clearance(), params.path_slope) && !arena.obstacles.is_empty()
        {
            let k = rng.random_range(0..arena.obstacles.len());
            arena.obstacles.remove(k);
        }
        arena
    }

    /// Whether a path leads from the spawn region (its y range at spawn x)
    /// to the end of the arena keeping `clearance` from every obstacle and
    /// wall, with a lateral slope of at most `slope`. A grid search in the
    /// horizontal plane (obstacles that do not span the spawn altitude are
    /// ignored, and so are moving ones: they leave any place they cross
    /// free most of the time): x every 0.25 m, y every 0.05 m.
    pub fn has_path(&self, clearance: f32, slope: f32) -> bool {
        const DX: f32 = 0.25;
        const DY: f32 = 0.05;
        let hw = self.width / 2.0;
        let cells = ((self.width - 2.0 * clearance) / DY).floor() as i64 + 1;
        if cells <= 0 {
            return false;
        }
        let cells = cells as usize;
        let y_of = |j: usize| -hw + clearance + j as f32 * DY;
        let z = self.spawn.z;
        let mut solids: Vec<&Obstacle> = self
            .obstacles
            .iter()
            .filter(|o| {
                let (lo, hi) = o.aabb();
                o.motion().is_none() && lo[2] - clearance < z && hi[2] + clearance > z
            })
            .collect();
        solids.sort_by(|a, b| a.aabb().0[0].total_cmp(&b.aabb().0[0]));
        let blocked = |x: f32, y: f32, near: &[&Obstacle]| {
            near.iter().any(|o| match **o {
                Obstacle::Box { center, half_extents, .. } => {
                    let dx = ((x - center[0]).abs() - half_extents[0]).max(0.0);
                    let dy = ((y - center[1]).abs() - half_extents[1]).max(0.0);
                    dx * dx + dy * dy < clearance * clearance
                }
                Obstacle::Cylinder { center, radius, .. } => {
                    let (dx, dy) = (x - center[0], y - center[1]);
                    dx * dx + dy * dy < (radius + clearance) * (radius + clearance)
                }
            })
        };
        let mut reach: Vec<bool> = (0..cells)
            .map(|j| (self.spawn.y[0] - 1e-3..=self.spawn.y[1] + 1e-3).contains(&y_of(j)))
            .collect();
        let spread = ((slope * DX / DY).floor() as usize).max(1);
        let steps = ((self.length - self.spawn.x) / DX).ceil() as usize;
        let mut next = vec![false; cells];
        for k in 0..=steps {
            let x = (self.spawn.x + k as f32 * DX).min(self.length);
            let near: Vec<&Obstacle> = solids
                .iter()
                .copied()
                .filter(|o| {
                    let (lo, hi) = o.aabb();
                    lo[0] - clearance < x && hi[0] + clearance > x
                })
                .collect();
            // Dilate by the slope (a run of reachable cells spreads), then
            // keep the free cells.
            let mut last_reach: Option<usize> = None;
            for j in 0..cells {
                if reach[j] {
                    last_reach = Some(j);
                }
                next[j] = last_reach.is_some_and(|r| j - r <= spread);
            }
            let mut last_reach: Option<usize> = None;
            for j in (0..cells).rev() {
                if reach[j] {
                    last_reach = Some(j);
                }
                next[j] |= last_reach.is_some_and(|r| r - j <= spread);
            }
            for (j, n) in next.iter_mut().enumerate() {
                *n = *n && !blocked(x, y_of(j), &near);
            }
            std::mem::swap(&mut reach, &mut next);
            if !reach.iter().any(|r| *r) {
                return false;
            }
        }
        true
    }
}

/// One layout drawn from `rng`: obstacles in rows or a forest, then the
/// walls with their doors, then obstacles that close every straight line
/// within `block_within`.
fn layout(name: &str, rng: &mut Pcg64Mcg, params: &GenParams) -> Arena {
    let (hw, hz) = (params.width / 2.0, params.height / 2.0);
    let end = params.length - 4.0;
    let mut obstacles = match params.mode {
        GenMode::Rows => rows(rng, params, end),
        GenMode::Forest => forest(rng, params, end),
    };
    if params.moving_share > 0.0 {
        for o in &mut obstacles {
            if rng.random_bool(f64::from(params.moving_share)) {
                set_moving(rng, params, o);
            }
        }
    }
    if params.door_every > 0.0 {
        walls(rng, params, end, &mut obstacles);
    }
    let spawn = Spawn { x: 2.0, y: [-hw * 0.5, hw * 0.5], z: hz.min(2.0) };
    if params.block_within > 0.0 {
        // Close every lateral line that no obstacle within reach blocks yet.
        let reach = (spawn.x + params.block_within).min(end);
        for _ in 0..200 {
            let Some(gap) =
                first_unblocked_line(&obstacles, params.width, params.drone_radius, reach)
            else {
                break;
            };
            let x = rng.random_range(params.first_x..reach - 2.0);
            obstacles.push(random_obstacle(rng, params, x, gap));
        }
    }
    obstacles.sort_by(|a, b| a.center()[0].total_cmp(&b.center()[0]));
    Arena {
        name: name.to_string(),
        length: params.length,
        width: params.width,
        height: params.height,
        spawn,
        obstacles,
    }
}

/// A box or a cylinder (even odds) at (`x`, `y`), kept inside the walls.
fn random_obstacle(rng: &mut Pcg64Mcg, params: &GenParams, x: f32, y: f32) -> Obstacle {
    let (hw, hz) = (params.width / 2.0, params.height / 2.0);
    if rng.random_bool(0.5) {
        let hx = draw(rng, params.box_half_x);
        let hy = draw(rng, params.box_half_y);
        Obstacle::still_box([x, y.clamp(-hw + hy, hw - hy), hz], [hx, hy, hz])
    } else {
        let r = draw(rng, params.cylinder_radius);
        Obstacle::still_cylinder([x, y.clamp(-hw + r, hw - r), hz], r, hz)
    }
}

/// Makes `o` move: back and forth across the corridor over a span drawn
/// from `moving_span`, or around a circle of that diameter (even odds), at
/// a speed drawn from `moving_speed`, from a random point of its cycle; its
/// centre moved so that everywhere it goes lies inside the walls.
fn set_moving(rng: &mut Pcg64Mcg, params: &GenParams, o: &mut Obstacle) {
    let hw = params.width / 2.0;
    let half_y = o.aabb().1[1] - o.center()[1];
    let room = (params.width - 2.0 * half_y - 0.02).max(0.0);
    let span = draw(rng, params.moving_span).min(room);
    let speed = draw(rng, params.moving_speed);
    let phase = rng.random_range(0.0..1.0);
    let y = o.center()[1];
    let (motion, lo, hi) = if rng.random_bool(0.5) {
        // From `y - span / 2` to `y + span / 2`.
        let m = Motion::Segment { offset: [0.0, span], speed, phase };
        (m, -hw + half_y + 0.01, hw - half_y - 0.01 - span)
    } else {
        let r = span / 2.0;
        let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let m = Motion::Circle { radius: r.max(0.01), speed: sign * speed, phase };
        (m, -hw + half_y + r + 0.01, hw - half_y - r - 0.01)
    };
    let base = match motion {
        Motion::Segment { .. } => y - span / 2.0,
        Motion::Circle { .. } => y,
    };
    let cy = if lo <= hi { base.clamp(lo, hi) } else { (lo + hi) / 2.0 };
    *o = o.shifted([0.0, cy - y, 0.0]);
    o.set_motion(Some(motion));
}

/// Rows `spacing` apart (±40 %) up to `end`, of 1 to `per_row` obstacles.
fn rows(rng: &mut Pcg64Mcg, params: &GenParams, end: f32) -> Vec<Obstacle> {
    let hw = params.width / 2.0;
    let mut obstacles = Vec::new();
    let mut x = params.first_x;
    while x < end {
        let y = rng.random_range(-hw..hw);
        obstacles.push(random_obstacle(rng, params, x, y));
        if params.per_row > 1 {
            for _ in 0..rng.random_range(0..params.per_row) {
                let y = rng.random_range(-hw..hw);
                obstacles.push(random_obstacle(rng, params, x, y));
            }
        }
        x += params.spacing * rng.random_range(0.6..1.4);
    }
    obstacles
}

/// Trunks placed uniformly at `forest_density` per square metre up to `end`.
fn forest(rng: &mut Pcg64Mcg, params: &GenParams, end: f32) -> Vec<Obstacle> {
    let (hw, hz) = (params.width / 2.0, params.height / 2.0);
    let count = (params.forest_density * (end - params.first_x) * params.width).round() as usize;
    (0..count)
        .map(|_| {
            let r = draw(rng, params.forest_radius);
            let x = rng.random_range(params.first_x..end);
            let y = rng.random_range(-hw + r..hw - r);
            Obstacle::still_cylinder([x, y, hz], r, hz)
        })
        .collect()
}

/// A wall every `door_every` metres up to `end`, each with one door.
fn walls(rng: &mut Pcg64Mcg, params: &GenParams, end: f32, obstacles: &mut Vec<Obstacle>) {
    let (hw, hz) = (params.width / 2.0, params.height / 2.0);
    let mut x = params.first_x + params.door_every / 2.0;
    while x < end {
        let w = draw(rng, params.door_width);
        let c = rng.random_range(-hw + w / 2.0..=hw - w / 2.0);
        for (lo, hi) in [(-hw, c - w / 2.0), (c + w / 2.0, hw)] {
            if hi - lo > 0.05 {
                obstacles.push(Obstacle::still_box(
                    [x, (lo + hi) / 2.0, hz],
                    [0.25, (hi - lo) / 2.0, hz],
                ));
            }
        }
        x += params.door_every;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generator_is_seeded_valid_and_blocking() {
        let p = GenParams::default();
        let a = Arena::generate("g", 7, &p);
        assert_eq!(a, Arena::generate("g", 7, &p));
        assert_ne!(a, Arena::generate("g", 8, &p));
        a.validate("generated").unwrap();
        assert_eq!(a.unblocked_line(p.drone_radius, a.spawn.x + p.block_within), None);
    }

    #[test]
    fn the_default_generator_draws_the_shipped_arenas() {
        // configs/arenas/train.toml (seed 101) and test.toml (seed 202) were
        // written by the first generator: the defaults still draw them.
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/arenas");
        for (file, seed) in [("train.toml", 101), ("test.toml", 202)] {
            let shipped = Arena::load(&root.join(file)).unwrap();
            let p = GenParams {
                length: shipped.length,
                width: shipped.width,
                height: shipped.height,
                ..GenParams::default()
            };
            let again = Arena::generate(&shipped.name, seed, &p);
            assert_eq!(again.obstacles, shipped.obstacles, "{file}");
        }
    }

    /// Rows of one or two obstacles every 3 m or so, with a path (L1's).
    fn dense() -> GenParams {
        GenParams {
            spacing: 3.0,
            per_row: 2,
            box_half_y: [0.6, 1.8],
            min_gap: 1.2,
            require_path: true,
            ..GenParams::default()
        }
    }

    #[test]
    fn a_share_of_obstacles_moves_inside_the_walls_and_none_without_it() {
        let dense = dense();
        let moving = GenParams { moving_share: 0.3, moving_speed: [0.2, 0.6], ..dense.clone() };
        let (mut movers, mut total, mut circles) = (0, 0, 0);
        for seed in 0..20 {
            let a = Arena::generate("m", seed, &moving);
            a.validate("moving").unwrap();
            assert!(a.has_path(moving.clearance(), moving.path_slope));
            total += a.obstacles.len();
            for m in a.obstacles.iter().filter_map(|o| o.motion()) {
                movers += 1;
                assert!((0.2..=0.6).contains(&m.speed()), "{m:?}");
                circles += usize::from(matches!(m, Motion::Circle { .. }));
            }
            // Without a share nothing moves and nothing more is drawn.
            let still = Arena::generate("m", seed, &dense);
            assert!(still.obstacles.iter().all(|o| o.motion().is_none()));
        }
        let share = movers as f64 / total as f64;
        assert!((0.15..0.35).contains(&share), "{movers} of {total} move");
        assert!(circles > movers / 4 && circles < 3 * movers / 4, "{circles} circles of {movers}");
    }

    #[test]
    fn the_path_check_finds_a_closed_corridor_and_a_door() {
        let wall = |door: Option<(f32, f32)>| {
            let mut a = Arena::generate(
                "w",
                1,
                &GenParams {
                    block_within: 0.0,
                    spacing: 1000.0,
                    first_x: 4.0,
                    length: 60.0,
                    ..GenParams::default()
                },
            );
            a.obstacles.clear();
            let hw = a.width / 2.0;
            match door {
                None => a.obstacles.push(Obstacle::still_box([10.0, 0.0, 3.0], [0.25, hw, 3.0])),
                Some((c, dw)) => {
                    for (lo, hi) in [(-hw, c - dw / 2.0), (c + dw / 2.0, hw)] {
                        a.obstacles.push(Obstacle::still_box(
                            [10.0, (lo + hi) / 2.0, 3.0],
                            [0.25, (hi - lo) / 2.0, 3.0],
                        ));
                    }
                }
            }
            a
        };
        assert!(wall(Some((4.0, 1.5))).has_path(0.3, 0.5), "a 1.5 m door at y = 4 is a path");
        assert!(!wall(Some((4.0, 1.5))).has_path(0.8, 0.5), "but not for a 1.6 m disc");
        assert!(!wall(None).has_path(0.3, 0.5), "a closed wall is no path");
        // A door 2.3 m to the side of the spawn region (y up to 3), 8 m
        // ahead, is reachable at a slope of 0.5 but not of 0.1 (the grid's
        // least slope is 0.2: one 5 cm cell per 25 cm).
        assert!(wall(Some((5.3, 1.0))).has_path(0.3, 0.5));
        assert!(!wall(Some((5.3, 1.0))).has_path(0.3, 0.1));
    }

    #[test]
    fn every_level_layout_has_a_path() {
        let dense = dense();
        let forest = GenParams {
            mode: GenMode::Forest,
            length: 300.0,
            width: 16.0,
            forest_density: 0.08,
            min_gap: 0.8,
            require_path: true,
            ..GenParams::default()
        };
        for p in [dense, forest] {
            p.validate().unwrap();
            for seed in 0..20 {
                let a = Arena::generate("x", seed, &p);
                a.validate("generated").unwrap();
                assert!(a.has_path(p.clearance(), p.path_slope), "seed {seed} of {p:?}");
            }
        }
    }

    #[test]
    fn bad_parameters_are_named() {
        let e = GenParams { per_row: 9, ..GenParams::default() }.validate().unwrap_err();
        assert_eq!(e.key, "per_row");
        let e =
            GenParams { forest_radius: [0.5, 0.1], ..GenParams::default() }.validate().unwrap_err();
        assert_eq!(e.key, "forest_radius");
        let e = GenParams { spacing: f32::NAN, ..GenParams::default() }.validate().unwrap_err();
        assert_eq!(e.key, "spacing");
    }
}
