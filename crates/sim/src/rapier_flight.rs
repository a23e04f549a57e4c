//! The rapier path (`sim.physics = "rapier"`): every drone a dynamic rigid
//! body of a rapier pipeline, the rotor thrusts applied as forces at the
//! rotors, one pipeline step per physics step, and collisions read from the
//! narrow phase (the drone a sensor ball) after each. It is the reference the
//! direct path (`flight.rs`) is tested against, and the path a researcher can
//! compare with, side by side, in `hive bench sim --physics rapier`.
//!
//! Moving obstacles are kinematic bodies moved to where their motion puts
//! them at the end of every physics step; contacts are found at each step's
//! end, so an obstacle at the fastest speed an arena allows
//! ([`MAX_OBSTACLE_SPEED`](crate::arena::MAX_OBSTACLE_SPEED), 0.2 m a step
//! at 0.02 s) cannot pass through a drone's 0.3 m ball unseen.

use rapier3d::prelude::*;

use crate::arena::Arena;
use crate::dynamics::{DroneState, control};
use crate::flight::{Drone, Flight, LINEAR_DAMPING};
use crate::geometry::{Mover, movers, solids};

const GROUP_DRONE: Group = Group::GROUP_1;
const GROUP_WORLD: Group = Group::GROUP_2;

/// The rapier world of one environment.
pub(crate) struct RapierFlight {
    world: PhysicsWorld,
    bodies: Vec<RigidBodyHandle>,
    colliders: Vec<ColliderHandle>,
    /// The moving obstacles and their kinematic bodies.
    movers: Vec<(Mover, RigidBodyHandle)>,
}

impl std::fmt::Debug for RapierFlight {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RapierFlight").field("bodies", &self.bodies.len()).finish()
    }
}

impl RapierFlight {
    /// The arena's still solids as fixed colliders, its moving obstacles as
    /// kinematic bodies where they are at time `t` of the world's clock, and
    /// one body per agent.
    pub(crate) fn new(
        arena: &Arena,
        agents: usize,
        flight: &Flight,
        radius: f32,
        interactive: bool,
        t: f64,
    ) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -crate::dynamics::GRAVITY);
        world.integration_parameters.dt = flight.dt;
        let fixed = InteractionGroups::new(GROUP_WORLD, Group::ALL, InteractionTestMode::And);
        for (pose, shape) in solids(arena) {
            world
                .colliders
                .insert(ColliderBuilder::new(shape).position(pose).collision_groups(fixed));
        }
        let movers = movers(arena)
            .into_iter()
            .map(|m| {
                let body = RigidBodyBuilder::kinematic_position_based().pose(m.pose_at(t));
                let collider = ColliderBuilder::new(m.shape.clone()).collision_groups(fixed);
                let (handle, _) = world.insert(body, collider);
                (m, handle)
            })
            .collect();
        let filter = if interactive { GROUP_WORLD | GROUP_DRONE } else { GROUP_WORLD };
        let groups = InteractionGroups::new(GROUP_DRONE, filter, InteractionTestMode::And);
        let q = flight.quad;
        let mut bodies = Vec::with_capacity(agents);
        let mut colliders = Vec::with_capacity(agents);
        for _ in 0..agents {
            let body = RigidBodyBuilder::dynamic()
                .additional_mass_properties(MassProperties::new(
                    Vector::ZERO,
                    q.mass,
                    Vector::from(q.inertia),
                ))
                .linear_damping(LINEAR_DAMPING)
                .can_sleep(false);
            // A sensor: it reports contact without bouncing, since a contact
            // ends the episode anyway.
            let collider = ColliderBuilder::ball(radius)
                .density(0.0)
                .sensor(true)
                .active_collision_types(
                    ActiveCollisionTypes::default() | ActiveCollisionTypes::DYNAMIC_DYNAMIC,
                )
                .collision_groups(groups);
            let (b, c) = world.insert(body, collider);
            bodies.push(b);
            colliders.push(c);
        }
        Self { world, bodies, colliders, movers }
    }

    /// Sets body `i` to a drone's state.
    pub(crate) fn load(&mut self, i: usize, d: &Drone) {
        let b = &mut self.world.bodies[self.bodies[i]];
        b.set_position(Pose::from_parts(d.p, d.q), true);
        b.set_linvel(d.v, true);
        b.set_angvel(d.angvel_world(), true);
        b.reset_forces(false);
        b.reset_torques(false);
    }

    /// One physics step of every drone from time `t` of the world's clock
    /// (the moving obstacles moving on to where they are at its end), then
    /// the collisions it found marked on the drones, whose state is read back.
    pub(crate) fn step(&mut self, flight: &Flight, drones: &mut [Drone], t: f64) {
        let end = t + f64::from(flight.dt);
        for (m, h) in &self.movers {
            self.world.bodies[*h].set_next_kinematic_position(m.pose_at(end));
        }
        for (d, h) in drones.iter().zip(&self.bodies) {
            let b = &mut self.world.bodies[*h];
            let s = DroneState {
                position: b.translation(),
                velocity: b.linvel(),
                rotation: *b.rotation(),
                angvel: b.angvel(),
            };
            let sp = Vector::new(flight.forward_speed, d.lateral_sp, 0.0);
            let cmd = control(&flight.quad, &flight.gains, &s, sp, flight.altitude);
            b.reset_forces(false);
            b.reset_torques(false);
            for (f, arm) in cmd.thrusts.iter().zip(cmd.arms_world) {
                b.add_force_at_point(cmd.thrust_dir * *f, s.position + arm, false);
            }
            b.add_torque(cmd.yaw_torque, false);
        }
        self.world.step();
        let np = &self.world.narrow_phase;
        for ((d, h), c) in drones.iter_mut().zip(&self.bodies).zip(&self.colliders) {
            let b = &self.world.bodies[*h];
            d.p = b.translation();
            d.v = b.linvel();
            d.q = *b.rotation();
            d.w = d.q.inverse() * b.angvel();
            if !d.collided && np.intersection_pairs_with(*c).any(|(_, _, hit)| hit) {
                d.collided = true;
            }
        }
    }
}
