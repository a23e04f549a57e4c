//! Direct flight: the quadrotors' equations of motion and their cascaded
//! controller integrated agent by agent; the arena's collision geometry,
//! queried with parry once per action, is [`crate::geometry`]'s.
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
//! The integration runs 16 drones at a time through one kernel over plain
//! `f32` lanes (structure-of-arrays; see [`Flight::fly`]). Measured with
//! `taskset -c 0 hive bench sim --agents 50` on the 2-core Zen 4 VM:
//! physics 29 µs per agent-step on the rapier path, 6.1 µs with this path
//! one drone at a time (glam's SIMD quaternions, which kept the loop over
//! drones scalar), 2.0 µs with the groups.

use crate::dynamics::{GRAVITY, Gains, Kinematics, QuadParams, thrusts, wrench};
use crate::simd::{LANES, Simd, Wide, cross};
use rapier3d::math::{Rotation, Vector};

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
    /// This drone's own parameters (randomised per episode, or nominal).
    pub(crate) body: Body,
}

/// A drone's own physical parameters and setpoints, drawn per episode by
/// domain randomisation (`[sim.randomize]`) or the nominal ones of
/// [`Flight::nominal`]; the kernel reads them lane by lane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Body {
    /// Forward speed setpoint (m/s).
    pub(crate) fwd: f32,
    /// True mass (kg); the controller still assumes the nominal one.
    pub(crate) mass: f32,
    /// Horizontal velocity gain of the controller (1/s).
    pub(crate) vel_gain: f32,
    /// Lateral acceleration of the wind (m/s²).
    pub(crate) push: f32,
}

impl Drone {
    /// At rest in the identity attitude at `p` with velocity `v`.
    pub(crate) fn at(p: Vector, v: Vector, body: Body) -> Self {
        Self {
            p,
            v,
            q: Rotation::IDENTITY,
            w: Vector::ZERO,
            lateral_sp: 0.0,
            collided: false,
            body,
        }
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
    /// The parameters of a drone without randomisation.
    pub(crate) fn nominal(&self) -> Body {
        Body {
            fwd: self.forward_speed,
            mass: self.quad.mass,
            vel_gain: self.gains.vel_xy,
            push: 0.0,
        }
    }

    /// One physics step of one drone: the same kernel as one lane of
    /// [`Flight::fly_group`], so a drone flies the same alone or in a group.
    pub(crate) fn step(&self, d: &mut Drone) {
        let mut s = State::<f32>::gather(std::slice::from_ref(d));
        self.kernel(&mut s);
        s.scatter(std::slice::from_mut(d));
    }

    /// Flies `drones` for `steps` physics steps and writes every drone's
    /// positions into its stretch of `path` (`steps + 1` each, the start
    /// first). Groups of [`LANES`] drones run as structure-of-arrays through
    /// one vectorised kernel; the drones left over run as one padded group
    /// (from [`PAD_FROM`] of them) or the same kernel one by one, with the
    /// same results to the bit (no fused multiply-add is ever formed, and
    /// every lane's arithmetic is the scalar one).
    pub(crate) fn fly(&self, drones: &mut [Drone], path: &mut [Vector], steps: usize) {
        let (stride, grouped) = (steps + 1, drones.len() / LANES * LANES);
        let mut groups = drones.chunks_exact_mut(LANES);
        let mut paths = path.chunks_exact_mut(LANES * stride);
        for (group, path) in (&mut groups).zip(&mut paths) {
            fly_group(self, group, path, steps);
        }
        let rest = groups.into_remainder();
        let rest_path = &mut path[grouped * stride..];
        if rest.len() >= PAD_FROM {
            // A group filled up with copies of one of them, which cost the
            // same as the real drones and are thrown away.
            let mut padded = [rest[0]; LANES];
            padded[..rest.len()].copy_from_slice(rest);
            let mut padded_path = vec![Vector::ZERO; LANES * stride];
            fly_group(self, &mut padded, &mut padded_path, steps);
            rest.copy_from_slice(&padded[..rest.len()]);
            rest_path.copy_from_slice(&padded_path[..rest_path.len()]);
            return;
        }
        for (d, path) in rest.iter_mut().zip(rest_path.chunks_exact_mut(stride)) {
            path[0] = d.p;
            for p in &mut path[1..] {
                self.step(d);
                *p = d.p;
            }
        }
    }

    /// One physics step of a drone's state in plain numbers: the controller
    /// once ([`thrusts`], the cascade over `T`), then
    /// [`INNER`] semi-implicit Euler steps of the rigid body under the rotor
    /// thrusts (world-frame force held over the step, body-frame torque with
    /// the gyroscopic term), then the linear damping.
    #[inline(always)]
    fn kernel<T: Simd>(&self, s: &mut State<T>) {
        let q = &self.quad;
        let c = T::splat;
        let axes = axes(s.q);
        let k = Kinematics { position: s.p, velocity: s.v, axes, w: s.w };
        let f = thrusts(q, &self.gains, s.gain, k, [s.fwd, s.lat], c(self.altitude));
        let (thrust, torque) = wrench(q, f);
        let per_mass = thrust / s.mass;
        let bz = axes[2];
        let acc = [bz[0] * per_mass, bz[1] * per_mass + s.push, bz[2] * per_mass - c(GRAVITY)];
        let j = q.inertia.map(c);
        let h = c(self.dt / INNER as f32);
        for _ in 0..INNER {
            let jw = [j[0] * s.w[0], j[1] * s.w[1], j[2] * s.w[2]];
            let gyro = cross(s.w, jw);
            for k in 0..3 {
                s.v[k] = s.v[k] + acc[k] * h;
                s.w[k] = s.w[k] + (torque[k] - gyro[k]) / j[k] * h;
                s.p[k] = s.p[k] + s.v[k] * h;
            }
            let half = c(0.5) * h;
            s.q = normalize_q(mul_q(s.q, [s.w[0] * half, s.w[1] * half, s.w[2] * half]));
        }
        let damp = c(1.0 / (1.0 + self.dt * LINEAR_DAMPING));
        s.v = s.v.map(|v| v * damp);
    }
}

/// Drones left over from whole groups that still run as a (padded) group:
/// on the AVX-512 machine a group costs about 2 µs per lane per action and
/// one drone alone about 6 µs, so from 6 drones a padded group is cheaper.
const PAD_FROM: usize = 6;

/// Drones' states as plain numbers: position, velocity, rotation
/// (`x, y, z, w`), body-frame angular velocity, lateral setpoint, and the
/// drone's own parameters ([`Body`]: read, never written back).
#[derive(Clone, Copy)]
pub(crate) struct State<T> {
    p: [T; 3],
    v: [T; 3],
    q: [T; 4],
    w: [T; 3],
    lat: T,
    fwd: T,
    mass: T,
    gain: T,
    push: T,
}

impl<T: Simd> State<T> {
    /// Drones' states, one per lane: `lane(value)` builds a `T` from every
    /// drone's `value`.
    #[inline(always)]
    fn gather_with(lane: impl Fn(&dyn Fn(&Drone) -> f32) -> T) -> Self {
        Self {
            p: [lane(&|d| d.p.x), lane(&|d| d.p.y), lane(&|d| d.p.z)],
            v: [lane(&|d| d.v.x), lane(&|d| d.v.y), lane(&|d| d.v.z)],
            q: [lane(&|d| d.q.x), lane(&|d| d.q.y), lane(&|d| d.q.z), lane(&|d| d.q.w)],
            w: [lane(&|d| d.w.x), lane(&|d| d.w.y), lane(&|d| d.w.z)],
            lat: lane(&|d| d.lateral_sp),
            fwd: lane(&|d| d.body.fwd),
            mass: lane(&|d| d.body.mass),
            gain: lane(&|d| d.body.vel_gain),
            push: lane(&|d| d.body.push),
        }
    }
}

impl State<f32> {
    #[inline(always)]
    fn gather(drones: &[Drone]) -> Self {
        Self::gather_with(|f| f(&drones[0]))
    }

    #[inline(always)]
    fn scatter(&self, drones: &mut [Drone]) {
        put(&mut drones[0], self, |x| *x);
    }
}

impl State<Wide> {
    #[inline(always)]
    fn gather(drones: &[Drone]) -> Self {
        Self::gather_with(|f| Wide(std::array::from_fn(|i| f(&drones[i]))))
    }

    #[inline(always)]
    fn scatter(&self, drones: &mut [Drone]) {
        for (i, d) in drones.iter_mut().enumerate() {
            put(d, self, |x| x.0[i]);
        }
    }
}

/// Writes one lane (`lane` reads it from a `T`) of `s` into drone `d`.
#[inline(always)]
fn put<T>(d: &mut Drone, s: &State<T>, lane: impl Fn(&T) -> f32) {
    let v3 = |v: &[T; 3]| Vector::new(lane(&v[0]), lane(&v[1]), lane(&v[2]));
    d.p = v3(&s.p);
    d.v = v3(&s.v);
    d.w = v3(&s.w);
    d.q = Rotation::from_xyzw(lane(&s.q[0]), lane(&s.q[1]), lane(&s.q[2]), lane(&s.q[3]));
}

/// [`LANES`] drones flown `steps` physics steps, their positions written
/// into `path` (`steps + 1` per drone). Compiled for AVX-512 and AVX2 beside
/// the baseline and picked at run time.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx512dq+avx2+fma+avx",
    "x86_64+avx2+fma+avx"
))]
fn fly_group(flight: &Flight, drones: &mut [Drone], path: &mut [Vector], steps: usize) {
    let stride = steps + 1;
    let mut s = State::<Wide>::gather(drones);
    for (i, d) in drones.iter().enumerate() {
        path[i * stride] = d.p;
    }
    for k in 1..stride {
        flight.kernel(&mut s);
        for i in 0..LANES {
            path[i * stride + k] = Vector::new(s.p[0].0[i], s.p[1].0[i], s.p[2].0[i]);
        }
    }
    s.scatter(drones);
}

/// The body axes in the world frame (the rotation's columns) of a unit
/// quaternion `[x, y, z, w]`.
#[inline(always)]
fn axes<T: Simd>([x, y, z, w]: [T; 4]) -> [[T; 3]; 3] {
    let (one, two) = (T::splat(1.0), T::splat(2.0));
    let (xx, yy, zz, xy, xz, yz, wx, wy, wz) =
        (x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z);
    [
        [one - two * (yy + zz), two * (xy + wz), two * (xz - wy)],
        [two * (xy - wz), one - two * (xx + zz), two * (yz + wx)],
        [two * (xz + wy), two * (yz - wx), one - two * (xx + yy)],
    ]
}

/// `q ⊗ (a, b, c, 1)`: a rotation by the small angle vector `2 (a, b, c)`
/// after `q`, unnormalised.
#[inline(always)]
fn mul_q<T: Simd>([x, y, z, w]: [T; 4], [a, b, c]: [T; 3]) -> [T; 4] {
    [
        w * a + x + y * c - z * b,
        w * b - x * c + y + z * a,
        w * c + x * b - y * a + z,
        w - (x * a + y * b + z * c),
    ]
}

#[inline(always)]
fn normalize_q<T: Simd>(q: [T; 4]) -> [T; 4] {
    let inv = T::splat(1.0) / (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    q.map(|x| x * inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arena::{Arena, Motion, Obstacle};
    use crate::geometry::{Geometry, Mover, movers};
    use rapier3d::parry::bounding_volume::{Aabb, BoundingVolume};

    fn arena(obstacles: Vec<Obstacle>) -> Arena {
        let mut a = Arena::generate("t", 1, &crate::generate::GenParams::default());
        a.obstacles = obstacles;
        a
    }

    /// `n` drones in different states; with `varied`, each of its own
    /// randomised body (mass, gain, forward speed, wind).
    fn drones(flight: &Flight, n: usize, varied: bool) -> Vec<Drone> {
        (0..n)
            .map(|i| {
                let t = i as f32;
                let body = if varied {
                    Body {
                        fwd: 0.8 + 0.02 * t,
                        mass: 0.8 + 0.011 * t,
                        vel_gain: 1.75 + 0.04 * t,
                        push: 0.5 - 0.03 * t,
                    }
                } else {
                    flight.nominal()
                };
                let mut d = Drone::at(
                    Vector::new(t, 0.3 * t, 2.0 + 0.01 * t),
                    Vector::new(3.0, 0.1 * (t - 18.0), -0.05 * t),
                    body,
                );
                d.q = Rotation::from_euler(
                    rapier3d::glamx::EulerRot::XYZ,
                    0.01 * t,
                    -0.02 * t,
                    0.005 * t,
                );
                d.w = Vector::new(0.1, -0.05 * t, 0.02);
                d.lateral_sp = if i % 2 == 0 { 1.5 } else { -1.5 };
                d
            })
            .collect()
    }

    #[test]
    fn a_drone_flies_the_same_to_the_bit_alone_or_in_a_group() {
        let flight = Flight {
            quad: QuadParams::default(),
            gains: Gains::default(),
            dt: 0.02,
            forward_speed: 3.0,
            altitude: 2.0,
        };
        let steps = 50;
        // Two groups and five left over (one by one); two groups and 13
        // left over (a padded group).
        // Each with its nominal body, then each with its own (randomised
        // dynamics run through the same lanes).
        for varied in [false, true] {
            for n in [37, 45] {
                fly_and_compare(&flight, n, steps, varied);
            }
        }
    }

    fn fly_and_compare(flight: &Flight, n: usize, steps: usize, varied: bool) {
        let mut group = drones(flight, n, varied);
        let mut path = vec![Vector::ZERO; group.len() * (steps + 1)];
        flight.fly(&mut group, &mut path, steps);
        for (i, (flown, mut alone)) in group.iter().zip(drones(flight, n, varied)).enumerate() {
            assert_eq!(path[i * (steps + 1)], alone.p);
            for k in 1..=steps {
                flight.step(&mut alone);
                assert_eq!(path[i * (steps + 1) + k], alone.p, "drone {i}, step {k}");
            }
            let bits = |d: &Drone| [d.p, d.v, d.w].map(|v| v.to_array().map(f32::to_bits));
            assert_eq!(bits(flown), bits(&alone), "drone {i}");
            assert_eq!(
                flown.q.to_array().map(f32::to_bits),
                alone.q.to_array().map(f32::to_bits),
                "drone {i}"
            );
        }
        // They did fly: every drone moved and turned.
        assert!(
            group
                .iter()
                .zip(drones(flight, n, varied))
                .all(|(a, b)| (a.p - b.p).length() > 1.0 && a.q != b.q)
        );
    }

    /// Obstacles moving across the corridor and around a circle at the
    /// moving level's top speed (0.6 m/s), and with `fast`, a thin one at
    /// the fastest speed an arena allows.
    fn moving_arena(fast: bool) -> Arena {
        let seg = |offset, speed, phase| Some(Motion::Segment { offset, speed, phase });
        let mut obstacles = vec![
            Obstacle::Box {
                center: [20.0, -1.5, 3.0],
                half_extents: [0.4, 0.6, 3.0],
                motion: seg([0.0, 3.0], 0.6, 0.0),
            },
            Obstacle::Cylinder {
                center: [28.0, 0.0, 3.0],
                radius: 0.5,
                half_height: 3.0,
                motion: Some(Motion::Circle { radius: 1.5, speed: 0.6, phase: 0.0 }),
            },
            Obstacle::Box {
                center: [36.0, -4.0, 3.0],
                half_extents: [0.3, 0.8, 3.0],
                motion: seg([0.0, 8.0], -0.6, 0.5),
            },
        ];
        if fast {
            obstacles.push(Obstacle::Box {
                center: [44.0, -5.0, 3.0],
                half_extents: [0.05, 0.5, 3.0],
                motion: seg([0.0, 10.0], crate::arena::MAX_OBSTACLE_SPEED, 0.0),
            });
        }
        let a = arena(obstacles);
        a.validate("moving").unwrap();
        a
    }

    /// 48 drones across the corridor, staggered along x, flying straight on.
    fn moving_drones(flight: &Flight) -> Vec<Drone> {
        (0..48)
            .map(|i| {
                let (y, x) = (-5.0 + 10.0 * i as f32 / 47.0, 2.0 + (i as f32 * 0.61) % 4.0);
                Drone::at(Vector::new(x, y, 3.0), Vector::new(1.0, 0.0, 0.0), flight.nominal())
            })
            .collect()
    }

    /// The least distance (between the drone's centre and the obstacle's
    /// surface) over a physics step from `a` to `b` starting at `t`,
    /// sampled 200 times: the truth the collision queries are held to.
    fn least_distance(movers: &[Mover], a: Vector, b: Vector, t: f64, dt: f64) -> f32 {
        let near = Aabb::new(a.min(b) - Vector::splat(1.0), a.max(b) + Vector::splat(1.0));
        movers
            .iter()
            .filter(|m| m.swept.intersects(&near))
            .flat_map(|m| {
                (0..=200).map(move |j| {
                    let f = j as f32 / 200.0;
                    let pose = m.pose_at(t + f64::from(f) * dt);
                    m.shape.distance_to_point(&pose, a.lerp(b, f), true)
                })
            })
            .fold(f32::INFINITY, f32::min)
    }

    fn moving_flight() -> Flight {
        Flight {
            quad: QuadParams::default(),
            gains: Gains::default(),
            dt: 0.02,
            forward_speed: 1.0,
            altitude: 3.0,
        }
    }

    /// Checks what a path found (`found[i]`: the first step it saw drone
    /// `i` touch) against the truth (`truth[i]`: the first step it came
    /// within 95 % of the radius; `least[i][k]`: its least distance in step
    /// k): every contact found, no later than `late` steps after it began,
    /// and nothing found that did not touch. Returns the drones that hit.
    fn every_contact_found(found: &[Option<usize>], least: &[Vec<f32>], late: usize) -> usize {
        let r = 0.3;
        let mut hits = 0;
        for (i, (f, l)) in found.iter().zip(least).enumerate() {
            let truth = l.iter().position(|d| *d < 0.95 * r);
            if let Some(t) = truth {
                let f = f
                    .unwrap_or_else(|| panic!("drone {i} came within {} m and was not seen", l[t]));
                assert!(f <= t + late, "drone {i}: touched in step {t}, seen in step {f}");
                hits += 1;
            }
            if let Some(f) = *f {
                let near =
                    l[f.saturating_sub(late)..=f].iter().copied().fold(f32::INFINITY, f32::min);
                assert!(near <= r + 1e-3, "drone {i} seen touching in step {f} at {near} m");
            }
        }
        hits
    }

    #[test]
    fn the_direct_path_finds_every_contact_with_moving_obstacles() {
        let a = moving_arena(true);
        let (g, movers) = (Geometry::new(&a), movers(&a));
        let flight = moving_flight();
        let mut drones = moving_drones(&flight);
        let (steps, dt) = (50, f64::from(flight.dt));
        let mut path = vec![Vector::ZERO; drones.len() * (steps + 1)];
        let mut found = vec![None; drones.len()];
        let mut least = vec![Vec::new(); drones.len()];
        for action in 0..50 {
            let t0 = action as f64 * steps as f64 * dt;
            flight.fly(&mut drones, &mut path, steps);
            for (i, p) in path.chunks_exact(steps + 1).enumerate() {
                if found[i].is_none() && g.path_hits(p, 0.3, t0, dt) {
                    found[i] = Some(action);
                }
                let l = (0..steps)
                    .map(|k| least_distance(&movers, p[k], p[k + 1], t0 + k as f64 * dt, dt))
                    .fold(f32::INFINITY, f32::min);
                least[i].push(l);
            }
        }
        let hits = every_contact_found(&found, &least, 0);
        println!("direct: {hits} of 48 drones hit");
        assert!((5..=43).contains(&hits), "{hits} of 48 drones hit: the test must see both");
    }

    #[test]
    fn the_rapier_path_finds_every_contact_with_moving_obstacles() {
        let a = moving_arena(false);
        let movers = movers(&a);
        let flight = moving_flight();
        let mut drones = moving_drones(&flight);
        let mut world =
            crate::rapier_flight::RapierFlight::new(&a, drones.len(), &flight, 0.3, false, 0.0);
        for (i, d) in drones.iter().enumerate() {
            world.load(i, d);
        }
        let dt = f64::from(flight.dt);
        let mut found = vec![None; drones.len()];
        let mut least = vec![Vec::new(); drones.len()];
        for k in 0..2500 {
            let before: Vec<Vector> = drones.iter().map(|d| d.p).collect();
            world.step(&flight, &mut drones, k as f64 * dt);
            for (i, d) in drones.iter().enumerate() {
                if found[i].is_none() && d.collided {
                    found[i] = Some(k);
                }
                least[i].push(least_distance(&movers, before[i], d.p, k as f64 * dt, dt));
            }
        }
        // Contacts are read at the end of each step: within one step of the truth.
        let hits = every_contact_found(&found, &least, 1);
        println!("rapier: {hits} of 48 drones hit");
        assert!((5..=43).contains(&hits), "{hits} of 48 drones hit: the test must see both");
    }
}
