//! Direct flight: the quadrotors' equations of motion and their cascaded
//! controller integrated agent by agent, and the arena's collision geometry
//! queried with parry once per action.
//!
//! The drones of one environment never push each other (a contact ends the
//! episode), so they need no rigid-body pipeline: no broad phase over bodies,
//! no islands, no contact solver. Each physics step runs the controller
//! (zero-order hold over `physics_dt`, as the rapier path did) and integrates
//! translation and attitude with semi-implicit Euler over [`INNER`] inner
//! steps, the scheme and rate of rapier's solver (its four substeps of
//! `dt / 4`). Rapier's parry stays what it is for: the arena's shapes, a
//! bounding-volume hierarchy over them, and the point queries against them.
//!
//! Collisions are found per action: the positions of every physics step
//! (the path) are kept, the path's box, widened by the drone's radius, is
//! queried against the hierarchy, and only the obstacles it meets (usually
//! none) are tested against each point of the path, with extra points where
//! two consecutive ones lie further apart than half the radius, so that
//! nothing tunnels through an obstacle however thin or however long
//! `physics_dt` is.
//!
//! Measured with `taskset -c 0 hive bench sim --agents 50` on the 2-core
//! Zen 3 VM: physics 27 µs per agent-step on the rapier path, see README for
//! this path's figure.

use rapier3d::math::{Pose, Rotation, Vector};
use rapier3d::parry::bounding_volume::Aabb;
use rapier3d::parry::partitioning::{Bvh, BvhBuildStrategy};
use rapier3d::parry::shape::SharedShape;

use crate::arena::{Arena, Obstacle};
use crate::dynamics::{GRAVITY, Gains, QuadParams, body_wrench, rotor_thrusts};

/// Inner integration steps per physics step (rapier's solver substeps).
pub(crate) const INNER: usize = 4;

/// Linear velocity damping (1/s), as the rapier path's bodies had.
pub(crate) const LINEAR_DAMPING: f32 = 0.05;

/// The state of one drone.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Drone {
    /// Position (m).
    pub(crate) p: Vector,
    /// Linear velocity, world frame (m/s).
    pub(crate) v: Vector,
    /// Body-to-world rotation.
    pub(crate) q: Rotation,
    /// Angular velocity, body frame (rad/s).
    pub(crate) w: Vector,
    /// Lateral velocity setpoint (m/s).
    pub(crate) lateral_sp: f32,
    /// Touched something during the current action.
    pub(crate) collided: bool,
}

impl Drone {
    /// At rest in the identity attitude at `p` with velocity `v`.
    pub(crate) fn at(p: Vector, v: Vector) -> Self {
        Self { p, v, q: Rotation::IDENTITY, w: Vector::ZERO, lateral_sp: 0.0, collided: false }
    }

    /// Angular velocity in the world frame.
    pub(crate) fn angvel_world(&self) -> Vector {
        self.q * self.w
    }
}

/// What a physics step needs besides the drone.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Flight {
    pub(crate) quad: QuadParams,
    pub(crate) gains: Gains,
    pub(crate) dt: f32,
    pub(crate) forward_speed: f32,
    pub(crate) altitude: f32,
}

impl Flight {
    /// One physics step of one drone: the controller once, then [`INNER`]
    /// semi-implicit Euler steps of the rigid body under the rotor thrusts
    /// (world-frame force held over the step, body-frame torque with the
    /// gyroscopic term), then the linear damping.
    #[inline]
    pub(crate) fn step(&self, d: &mut Drone) {
        let q = &self.quad;
        let axes = [d.q * Vector::X, d.q * Vector::Y, d.q * Vector::Z];
        let sp = Vector::new(self.forward_speed, d.lateral_sp, 0.0);
        let f = rotor_thrusts(q, &self.gains, d.p, d.v, axes, d.w, sp, self.altitude);
        let (thrust, torque) = body_wrench(q, f);
        let acc = axes[2] * (thrust / q.mass) - Vector::Z * GRAVITY;
        let j = Vector::from(q.inertia);
        let h = self.dt / INNER as f32;
        for _ in 0..INNER {
            d.v += acc * h;
            d.w += (torque - d.w.cross(j * d.w)) / j * h;
            d.p += d.v * h;
            let half = d.w * (0.5 * h);
            d.q = (d.q * Rotation::from_xyzw(half.x, half.y, half.z, 1.0)).normalize();
        }
        d.v *= 1.0 / (1.0 + self.dt * LINEAR_DAMPING);
    }
}

/// The arena's solid shapes (obstacles, walls, floor and ceiling) and a
/// bounding-volume hierarchy over them.
pub(crate) struct Geometry {
    shapes: Vec<(Pose, SharedShape)>,
    bvh: Bvh,
}

impl std::fmt::Debug for Geometry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Geometry").field("shapes", &self.shapes.len()).finish()
    }
}

/// Every solid of an arena as a parry shape at its pose: the obstacles, and
/// walls, floor and ceiling as slabs 1 m thick that reach 5 m past each end.
pub(crate) fn solids(arena: &Arena) -> Vec<(Pose, SharedShape)> {
    let mut out: Vec<(Pose, SharedShape)> = arena
        .obstacles
        .iter()
        .map(|o| match *o {
            Obstacle::Box { center, half_extents: h } => (Pose::from_translation(Vector::from(center)), SharedShape::cuboid(h[0], h[1], h[2])),
            // Parry's cylinders stand along y; turn them upright.
            Obstacle::Cylinder { center, radius, half_height } => {
                (Pose::from_parts(Vector::from(center), Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2)), SharedShape::cylinder(half_height, radius))
            }
        })
        .collect();
    let (l, hw, h) = (arena.length, arena.width / 2.0, arena.height);
    let slabs = [
        (Vector::new(l / 2.0, hw + 0.5, h / 2.0), Vector::new(l / 2.0 + 5.0, 0.5, h / 2.0 + 1.0)),
        (Vector::new(l / 2.0, -hw - 0.5, h / 2.0), Vector::new(l / 2.0 + 5.0, 0.5, h / 2.0 + 1.0)),
        (Vector::new(l / 2.0, 0.0, -0.5), Vector::new(l / 2.0 + 5.0, hw + 1.0, 0.5)),
        (Vector::new(l / 2.0, 0.0, h + 0.5), Vector::new(l / 2.0 + 5.0, hw + 1.0, 0.5)),
    ];
    out.extend(slabs.into_iter().map(|(c, e)| (Pose::from_translation(c), SharedShape::cuboid(e.x, e.y, e.z))));
    out
}

impl Geometry {
    pub(crate) fn new(arena: &Arena) -> Self {
        let shapes = solids(arena);
        let boxes: Vec<Aabb> = shapes.iter().map(|(pose, s)| s.compute_aabb(pose)).collect();
        let bvh = Bvh::from_leaves(BvhBuildStrategy::default(), &boxes);
        Self { shapes, bvh }
    }

    /// Whether a sphere of `radius` moved along `path` (its positions, the
    /// start first) touches any solid. Between two points further apart
    /// than half the radius, points are added so that none of the path is
    /// skipped.
    pub(crate) fn path_hits(&self, path: &[Vector], radius: f32) -> bool {
        let Some(first) = path.first() else { return false };
        let (lo, hi) = path.iter().fold((*first, *first), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        let query = Aabb::new(lo - Vector::splat(radius), hi + Vector::splat(radius));
        let touches = |pose: &Pose, shape: &SharedShape, p: Vector| shape.distance_to_point(pose, p, true) <= radius;
        self.bvh.intersect_aabb(&query).any(|leaf| {
            let (pose, shape) = &self.shapes[leaf as usize];
            let mut prev = *first;
            path.iter().any(|p| {
                let gap = (*p - prev).length();
                let extra = (gap / (0.5 * radius)).ceil() as usize;
                let hit = (1..extra).any(|k| touches(pose, shape, prev.lerp(*p, k as f32 / extra as f32))) || touches(pose, shape, *p);
                prev = *p;
                hit
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arena(obstacles: Vec<Obstacle>) -> Arena {
        let mut a = Arena::generate("t", 1, &crate::arena::GenParams::default());
        a.obstacles = obstacles;
        a
    }

    #[test]
    fn a_path_touches_what_lies_within_the_radius_and_nothing_else() {
        let g = Geometry::new(&arena(vec![Obstacle::Box { center: [10.0, 0.0, 2.0], half_extents: [0.5, 0.5, 2.0] }]));
        let z = 2.0;
        // Ends 0.31 m before the box's face at x = 9.5: clear.
        assert!(!g.path_hits(&[Vector::new(8.0, 0.0, z), Vector::new(9.19, 0.0, z)], 0.3));
        // Ends 0.29 m before it: touching.
        assert!(g.path_hits(&[Vector::new(8.0, 0.0, z), Vector::new(9.21, 0.0, z)], 0.3));
        // Jumps clean over a thin box in one long step: the added points see it.
        let thin = Geometry::new(&arena(vec![Obstacle::Box { center: [10.0, 0.0, 2.0], half_extents: [0.001, 3.0, 2.0] }]));
        assert!(thin.path_hits(&[Vector::new(5.0, 0.0, z), Vector::new(15.0, 0.0, z)], 0.3));
        // The floor slab is a solid too.
        assert!(g.path_hits(&[Vector::new(3.0, 0.0, 0.2)], 0.3));
    }
}
