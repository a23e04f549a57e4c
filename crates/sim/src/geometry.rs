//! The arena's collision geometry, which the direct flight and the planner
//! query: its still solids (obstacles, walls, floor and ceiling) as parry
//! shapes under a bounding-volume hierarchy, the moving obstacles beside
//! it, and paths tested against both so that nothing tunnels (see
//! [`crate::flight`] for how the flight uses it).

use rapier3d::math::{Pose, Rotation, Vector};
use rapier3d::parry::bounding_volume::{Aabb, BoundingVolume};
use rapier3d::parry::partitioning::{Bvh, BvhBuildStrategy};
use rapier3d::parry::shape::SharedShape;

use crate::arena::{Arena, Motion, Obstacle};

/// The arena's solid shapes (still obstacles, walls, floor and ceiling), a
/// bounding-volume hierarchy over them, and the moving obstacles beside it.
pub(crate) struct Geometry {
    shapes: Vec<(Pose, SharedShape)>,
    bvh: Bvh,
    movers: Vec<Mover>,
}

impl std::fmt::Debug for Geometry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Geometry")
            .field("shapes", &self.shapes.len())
            .field("movers", &self.movers.len())
            .finish()
    }
}

/// A moving obstacle: its shape at its centre, its motion, and the box of
/// everywhere it goes.
#[derive(Clone)]
pub(crate) struct Mover {
    pub(crate) pose: Pose,
    pub(crate) shape: SharedShape,
    pub(crate) motion: Motion,
    pub(crate) swept: Aabb,
}

impl Mover {
    /// Its pose at time `t` of the world's clock.
    pub(crate) fn pose_at(&self, t: f64) -> Pose {
        let [dx, dy] = self.motion.offset(t);
        Pose::from_parts(self.pose.translation + Vector::new(dx, dy, 0.0), self.pose.rotation)
    }
}

/// An obstacle's parry shape at its pose (at its centre, for one that moves).
fn solid(o: &Obstacle) -> (Pose, SharedShape) {
    match *o {
        Obstacle::Box { center, half_extents: h, .. } => {
            (Pose::from_translation(Vector::from(center)), SharedShape::cuboid(h[0], h[1], h[2]))
        }
        // Parry's cylinders stand along y; turn them upright.
        Obstacle::Cylinder { center, radius, half_height, .. } => (
            Pose::from_parts(
                Vector::from(center),
                Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2),
            ),
            SharedShape::cylinder(half_height, radius),
        ),
    }
}

/// Every still solid of an arena as a parry shape at its pose: the
/// obstacles that do not move, and walls, floor and ceiling as slabs 1 m
/// thick that reach 5 m past each end.
pub(crate) fn solids(arena: &Arena) -> Vec<(Pose, SharedShape)> {
    let mut out: Vec<(Pose, SharedShape)> =
        arena.obstacles.iter().filter(|o| o.motion().is_none()).map(solid).collect();
    let (l, hw, h) = (arena.length, arena.width / 2.0, arena.height);
    let slabs = [
        (Vector::new(l / 2.0, hw + 0.5, h / 2.0), Vector::new(l / 2.0 + 5.0, 0.5, h / 2.0 + 1.0)),
        (Vector::new(l / 2.0, -hw - 0.5, h / 2.0), Vector::new(l / 2.0 + 5.0, 0.5, h / 2.0 + 1.0)),
        (Vector::new(l / 2.0, 0.0, -0.5), Vector::new(l / 2.0 + 5.0, hw + 1.0, 0.5)),
        (Vector::new(l / 2.0, 0.0, h + 0.5), Vector::new(l / 2.0 + 5.0, hw + 1.0, 0.5)),
    ];
    out.extend(
        slabs
            .into_iter()
            .map(|(c, e)| (Pose::from_translation(c), SharedShape::cuboid(e.x, e.y, e.z))),
    );
    out
}

/// The arena's moving obstacles.
pub(crate) fn movers(arena: &Arena) -> Vec<Mover> {
    arena
        .obstacles
        .iter()
        .filter_map(|o| {
            let motion = *o.motion()?;
            let (pose, shape) = solid(o);
            let (lo, hi) = o.swept_aabb();
            Some(Mover { pose, shape, motion, swept: Aabb::new(lo.into(), hi.into()) })
        })
        .collect()
}

impl Geometry {
    pub(crate) fn new(arena: &Arena) -> Self {
        let shapes = solids(arena);
        let boxes: Vec<Aabb> = shapes.iter().map(|(pose, s)| s.compute_aabb(pose)).collect();
        let bvh = Bvh::from_leaves(BvhBuildStrategy::default(), &boxes);
        Self { shapes, bvh, movers: movers(arena) }
    }

    /// Whether a sphere of `radius` moved along `path` (its positions, the
    /// start first, at time `t0` of the world's clock and every `dt` after)
    /// touches any solid. Between two points further apart than half the
    /// radius, points are added so that none of the path is skipped; against
    /// a moving obstacle, the points are as close in the motion relative to
    /// it, each tested against where the obstacle is at its own time.
    pub(crate) fn path_hits(&self, path: &[Vector], radius: f32, t0: f64, dt: f64) -> bool {
        let Some(first) = path.first() else {
            return false;
        };
        let (lo, hi) = path.iter().fold((*first, *first), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        let query = Aabb::new(lo - Vector::splat(radius), hi + Vector::splat(radius));
        let sweep = Sweep { path, radius, t0, dt };
        self.bvh.intersect_aabb(&query).any(|leaf| {
            let (pose, shape) = &self.shapes[leaf as usize];
            sweep.touches(shape, 0.0, |_| *pose)
        }) || self
            .movers
            .iter()
            .filter(|m| m.swept.intersects(&query))
            .any(|m| sweep.touches(&m.shape, m.motion.speed(), |t| m.pose_at(t)))
    }
}

/// A sphere of `radius` moved along `path` (its positions at time `t0` of
/// the world's clock and every `dt` after).
struct Sweep<'a> {
    path: &'a [Vector],
    radius: f32,
    t0: f64,
    dt: f64,
}

impl Sweep<'_> {
    /// Whether it touches `shape`, which moves at `speed` and is at
    /// `pose_at(t)` at time `t`: each point of the path is tested, and
    /// points are added between two wherever the drone's and the shape's
    /// travel over the step sum to more than half the radius, each tested
    /// against where the shape is at its own time.
    fn touches(&self, shape: &SharedShape, speed: f32, pose_at: impl Fn(f64) -> Pose) -> bool {
        let (path, r, dt) = (self.path, self.radius, self.dt);
        let near = |t: f64, p: Vector| shape.distance_to_point(&pose_at(t), p, true) <= r;
        near(self.t0, path[0])
            || path.windows(2).enumerate().any(|(k, w)| {
                let reach = (w[1] - w[0]).length() + speed * dt as f32;
                let extra = ((reach / (0.5 * r)).ceil() as usize).max(1);
                let ta = self.t0 + k as f64 * dt;
                (1..extra).any(|j| {
                    let f = j as f32 / extra as f32;
                    near(ta + f64::from(f) * dt, w[0].lerp(w[1], f))
                }) || near(ta + dt, w[1])
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arena(obstacles: Vec<Obstacle>) -> Arena {
        let mut a = Arena::generate("t", 1, &crate::generate::GenParams::default());
        a.obstacles = obstacles;
        a
    }

    #[test]
    fn a_path_touches_what_lies_within_the_radius_and_nothing_else() {
        let g = Geometry::new(&arena(vec![Obstacle::still_box([10.0, 0.0, 2.0], [0.5, 0.5, 2.0])]));
        let z = 2.0;
        // Ends 0.31 m before the box's face at x = 9.5: clear.
        assert!(!g.path_hits(
            &[Vector::new(8.0, 0.0, z), Vector::new(9.19, 0.0, z)],
            0.3,
            0.0,
            0.02
        ));
        // Ends 0.29 m before it: touching.
        assert!(g.path_hits(
            &[Vector::new(8.0, 0.0, z), Vector::new(9.21, 0.0, z)],
            0.3,
            0.0,
            0.02
        ));
        // Jumps clean over a thin box in one long step: the added points see it.
        let thin =
            Geometry::new(&arena(vec![Obstacle::still_box([10.0, 0.0, 2.0], [0.001, 3.0, 2.0])]));
        assert!(thin.path_hits(
            &[Vector::new(5.0, 0.0, z), Vector::new(15.0, 0.0, z)],
            0.3,
            0.0,
            0.02
        ));
        // The floor slab is a solid too.
        assert!(g.path_hits(&[Vector::new(3.0, 0.0, 0.2)], 0.3, 0.0, 0.02));
    }
}
