//! Quadrotor model and its cascaded flight controller.
//!
//! The controller follows the structure of AirSim's SimpleFlight and
//! gym-pybullet-drones' DSL PID: a velocity setpoint becomes an acceleration
//! command, the acceleration a desired thrust vector and attitude (yaw held at
//! zero), the attitude error desired body rates, the rate error body torques,
//! and a mixer turns thrust and torques into four rotor thrusts, clamped to what
//! the rotors can give. The physics engine then applies those thrusts at the
//! rotor positions. Rotor spin-up is taken as instantaneous.

use rapier3d::math::{Rotation, Vector};

use crate::simd::{Simd, cross, dot, normalize_or};

/// Physical constants of the quadrotor (an X-frame of about 1 kg).
#[derive(Debug, Clone, Copy)]
pub struct QuadParams {
    /// Mass (kg).
    pub mass: f32,
    /// Principal inertia about body x, y, z (kg m²).
    pub inertia: [f32; 3],
    /// Distance from the centre to each rotor (m).
    pub arm: f32,
    /// Maximum thrust of one rotor (N).
    pub max_rotor_thrust: f32,
    /// Rotor drag torque per newton of thrust (m).
    pub torque_coeff: f32,
}

impl Default for QuadParams {
    fn default() -> Self {
        Self {
            mass: 1.0,
            inertia: [0.01, 0.01, 0.018],
            arm: 0.15,
            max_rotor_thrust: 7.0,
            torque_coeff: 0.016,
        }
    }
}

/// Controller gains.
#[derive(Debug, Clone, Copy)]
pub struct Gains {
    /// Velocity error to acceleration (1/s), horizontal.
    pub vel_xy: f32,
    /// Velocity error to acceleration (1/s), vertical.
    pub vel_z: f32,
    /// Altitude error to vertical velocity (1/s).
    pub alt: f32,
    /// Largest horizontal acceleration commanded (m/s²); bounds the tilt.
    pub max_acc_xy: f32,
    /// Attitude error to body rate (1/s).
    pub att: f32,
    /// Yaw error to yaw rate (1/s).
    pub att_yaw: f32,
    /// Body-rate error to angular acceleration (1/s).
    pub rate: f32,
}

impl Default for Gains {
    fn default() -> Self {
        Self {
            vel_xy: 2.5,
            vel_z: 4.0,
            alt: 1.5,
            max_acc_xy: 6.0,
            att: 9.0,
            att_yaw: 3.0,
            rate: 22.0,
        }
    }
}

/// State of one drone as the controller sees it (world frame).
#[derive(Debug, Clone, Copy)]
pub struct DroneState {
    /// Position (m).
    pub position: Vector,
    /// Linear velocity (m/s).
    pub velocity: Vector,
    /// Body-to-world rotation.
    pub rotation: Rotation,
    /// Angular velocity in the world frame (rad/s).
    pub angvel: Vector,
}

/// What the controller asks of the rotors, in the world frame, for one physics step.
#[derive(Debug, Clone, Copy)]
pub struct RotorCommand {
    /// Thrust of each rotor (N), clamped to `[0, max_rotor_thrust]`.
    pub thrusts: [f32; 4],
    /// Rotor positions relative to the centre, world frame (m).
    pub arms_world: [Vector; 4],
    /// Thrust direction, world frame (the body z axis).
    pub thrust_dir: Vector,
    /// Drag torque of the rotors about the body z axis, world frame (N m).
    pub yaw_torque: Vector,
}

/// Rotor positions in the body frame (X configuration) and their spin sense.
fn rotors(arm: f32) -> ([Vector; 4], [f32; 4]) {
    let l = arm / std::f32::consts::SQRT_2;
    (
        [
            Vector::new(l, l, 0.0),
            Vector::new(-l, l, 0.0),
            Vector::new(-l, -l, 0.0),
            Vector::new(l, -l, 0.0),
        ],
        [1.0, -1.0, 1.0, -1.0],
    )
}

/// Runs the cascade once: velocity setpoint (world frame, z ignored) and
/// altitude setpoint in, rotor thrusts out.
pub fn control(
    p: &QuadParams,
    g: &Gains,
    s: &DroneState,
    vel_sp: Vector,
    alt_sp: f32,
) -> RotorCommand {
    let r = s.rotation;
    let axes = [r * Vector::X, r * Vector::Y, r * Vector::Z];
    let v3 = |v: Vector| v.to_array();
    let k = Kinematics {
        position: v3(s.position),
        velocity: v3(s.velocity),
        axes: axes.map(v3),
        w: v3(r.inverse() * s.angvel),
    };
    let f = thrusts(p, g, g.vel_xy, k, [vel_sp.x, vel_sp.y], alt_sp);
    let (arms, spin) = rotors(p.arm);
    let yaw = p.torque_coeff * (spin[0] * f[0] + spin[1] * f[1] + spin[2] * f[2] + spin[3] * f[3]);
    RotorCommand {
        thrusts: f,
        arms_world: arms.map(|a| r * a),
        thrust_dir: axes[2],
        yaw_torque: axes[2] * yaw,
    }
}

/// A drone's motion as the cascade reads it: position and velocity (world
/// frame), the body axes in the world frame (`[bx, by, bz]`, the columns of
/// the rotation) and the body-frame angular velocity, for one drone (`f32`)
/// or a group ([`Simd`]). Vectors are `[x, y, z]`.
#[derive(Clone, Copy)]
pub(crate) struct Kinematics<T> {
    pub(crate) position: [T; 3],
    pub(crate) velocity: [T; 3],
    pub(crate) axes: [[T; 3]; 3],
    pub(crate) w: [T; 3],
}

/// The cascade itself, over any [`Simd`] type: one drone (`f32`, as
/// [`control`] runs it) or a group (the direct path's vectorised kernel,
/// `flight.rs`). The horizontal velocity setpoint `vel_sp` (`[x, y]`) and
/// the altitude setpoint in; the four rotor thrusts (N), clamped, out.
/// `vel_gain` stands for `g.vel_xy` (a drone's own, under domain
/// randomisation).
#[inline(always)]
pub(crate) fn thrusts<T: Simd>(
    p: &QuadParams,
    g: &Gains,
    vel_gain: T,
    k: Kinematics<T>,
    vel_sp: [T; 2],
    alt_sp: T,
) -> [T; 4] {
    let Kinematics { position, velocity, axes: [bx, by, bz], w } = k;
    let c = T::splat;
    // Velocity loop (altitude held by an outer position loop on z).
    let vz_sp = (c(g.alt) * (alt_sp - position[2])).max(c(-2.0)).min(c(2.0));
    let ax = vel_gain * (vel_sp[0] - velocity[0]);
    let ay = vel_gain * (vel_sp[1] - velocity[1]);
    let az = c(g.vel_z) * (vz_sp - velocity[2]);
    let h = (ax * ax + ay * ay).sqrt();
    let limit = h.gt_select(c(g.max_acc_xy), c(g.max_acc_xy) / h, c(1.0));
    let force = [ax * limit * c(p.mass), ay * limit * c(p.mass), (az + c(GRAVITY)) * c(p.mass)];

    // Desired attitude: body z along the force, yaw zero.
    let bz_d = normalize_or(force, [c(0.0), c(0.0), c(1.0)]);
    let by_d = normalize_or([c(0.0), bz_d[2], -bz_d[1]], [c(0.0), c(1.0), c(0.0)]);
    let bx_d = cross(by_d, bz_d);
    let collective = dot(force, bz).max(c(0.0));

    // Attitude error e = ½ vee(R_dᵀR − RᵀR_d) in the body frame (Lee et al.);
    // with M = R_dᵀR, M_ij = bd_i · b_j.
    let half = c(0.5);
    let e = [
        half * (dot(bz_d, by) - dot(by_d, bz)),
        half * (dot(bx_d, bz) - dot(bz_d, bx)),
        half * (dot(by_d, bx) - dot(bx_d, by)),
    ];
    let rate_sp = [c(-g.att) * e[0], c(-g.att) * e[1], c(-g.att_yaw) * e[2]];
    let j = p.inertia.map(c);
    let gyro = cross(w, [j[0] * w[0], j[1] * w[1], j[2] * w[2]]);
    let tau: [T; 3] = std::array::from_fn(|k| j[k] * ((rate_sp[k] - w[k]) * c(g.rate)) + gyro[k]);

    // Mixer for the X frame (see `rotors`), then the rotors' limits.
    let l = p.arm / std::f32::consts::SQRT_2;
    let (t4, x4, y4, z4) = (
        collective / c(4.0),
        tau[0] / c(4.0 * l),
        tau[1] / c(4.0 * l),
        tau[2] / c(4.0 * p.torque_coeff),
    );
    [t4 + x4 - y4 + z4, t4 + x4 + y4 - z4, t4 - x4 + y4 + z4, t4 - x4 - y4 - z4]
        .map(|f| f.max(c(0.0)).min(c(p.max_rotor_thrust)))
}

/// What four rotor thrusts do to the body: the total thrust along body z (N)
/// and the body-frame torque (N m) of the X frame (see `rotors`).
#[inline]
pub fn body_wrench(p: &QuadParams, f: [f32; 4]) -> (f32, Vector) {
    let (thrust, torque) = wrench(p, f);
    (thrust, Vector::from(torque))
}

/// [`body_wrench`] over any [`Simd`] type.
#[inline(always)]
pub(crate) fn wrench<T: Simd>(p: &QuadParams, f: [T; 4]) -> (T, [T; 3]) {
    let l = T::splat(p.arm / std::f32::consts::SQRT_2);
    let torque = [
        l * (f[0] + f[1] - f[2] - f[3]),
        l * (f[1] + f[2] - f[0] - f[3]),
        T::splat(p.torque_coeff) * (f[0] - f[1] + f[2] - f[3]),
    ];
    (f[0] + f[1] + f[2] + f[3], torque)
}

/// Gravity (m/s², along −z).
pub const GRAVITY: f32 = 9.81;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hover_thrust_balances_gravity() {
        let p = QuadParams::default();
        let s = DroneState {
            position: Vector::new(0.0, 0.0, 2.0),
            velocity: Vector::ZERO,
            rotation: Rotation::IDENTITY,
            angvel: Vector::ZERO,
        };
        let c = control(&p, &Gains::default(), &s, Vector::ZERO, 2.0);
        let total: f32 = c.thrusts.iter().sum();
        assert!((total - 9.81).abs() < 1e-3, "{total}");
        assert!(c.thrusts.iter().all(|f| (f - total / 4.0).abs() < 1e-4));
    }

    #[test]
    fn a_forward_setpoint_tilts_the_thrust_forward() {
        let p = QuadParams::default();
        let s = DroneState {
            position: Vector::new(0.0, 0.0, 2.0),
            velocity: Vector::ZERO,
            rotation: Rotation::IDENTITY,
            angvel: Vector::ZERO,
        };
        let c = control(&p, &Gains::default(), &s, Vector::new(1.0, 0.0, 0.0), 2.0);
        // Pitching forward (nose down) is a positive rotation about body y:
        // the rear rotors (1, 2) must push harder than the front ones.
        assert!(c.thrusts[1] + c.thrusts[2] > c.thrusts[0] + c.thrusts[3], "{:?}", c.thrusts);
    }

    #[test]
    fn the_body_wrench_is_the_torque_of_the_rotor_forces_at_their_arms() {
        let p = QuadParams::default();
        let r = Rotation::from_euler(rapier3d::glamx::EulerRot::XYZ, 0.1, -0.2, 0.3);
        let s = DroneState {
            position: Vector::new(1.0, 2.0, 2.5),
            velocity: Vector::new(0.5, -1.0, 0.1),
            rotation: r,
            angvel: Vector::new(0.2, -0.1, 0.3),
        };
        let c = control(&p, &Gains::default(), &s, Vector::new(1.0, 2.0, 0.0), 2.0);
        let world: Vector = c
            .thrusts
            .iter()
            .zip(c.arms_world)
            .map(|(f, a)| a.cross(c.thrust_dir * *f))
            .sum::<Vector>()
            + c.yaw_torque;
        let (total, body) = body_wrench(&p, c.thrusts);
        assert!((r * body - world).length() < 1e-5, "{:?} vs {:?}", r * body, world);
        assert!((total - c.thrusts.iter().sum::<f32>()).abs() < 1e-6);
    }
}
