//! The planner's searches in its kinematic model of the flight (see the
//! module's comment): breadth first for a plan ([`search`]), depth first
//! for a label's question ([`clear_way`]).

use std::collections::HashSet;

use rapier3d::math::Vector;

use super::{Node, Plan};
use crate::Goal;
use crate::env::VecEnv;
use crate::geometry::Geometry;

/// Width of the grid cells that merge states (m of lateral position).
const CELL_Y: f32 = 0.05;
/// Points per action at which a path is tested (more are added near a
/// moving obstacle).
const POINTS: usize = 10;

/// The kinematic model of one search for agent `i` of `env` (see the
/// module's comment): where each action from a node leads, and whether
/// the way there touches what `geometry` holds.
struct Model<'a> {
    geometry: &'a Geometry,
    period: f64,
    dt: f64,
    fwd: f32,
    gain: f32,
    drift: f32,
    radius: f32,
    margin: f32,
    goal: Option<([f32; 2], f32)>,
    /// Each action's change of the lateral setpoint (the first `actions`).
    deltas: [f32; 3],
    actions: usize,
    max_sp: f32,
    lateral_step: f32,
    x0: f32,
    z: f32,
    t0: f64,
    length: f32,
    /// Actions a way needs to be clear for: the rest of the episode or
    /// the horizon, whichever is shorter.
    limit: usize,
    root: Node,
}

/// Where one action from a node leads.
enum Step {
    /// Its way touches an obstacle, or it passed the goal out of reach.
    Blocked,
    /// Through to the far end, or to the goal.
    Through(Node),
    /// On, not through yet: the node and its key on the merging grid.
    On(Node, (i32, i32)),
}

impl<'a> Model<'a> {
    fn new(geometry: &'a Geometry, env: &VecEnv, i: usize, margin: f32, horizon: usize) -> Self {
        let cfg = env.config();
        let d = env.drone(i);
        let period = cfg.substeps() as f64 * f64::from(cfg.physics_dt);
        // Forward at the speed the drone flies now (its controller holds
        // it a little under the setpoint).
        let (fwd, gain) = (d.v.x, d.body.vel_gain.max(1e-3));
        Self {
            geometry,
            period,
            dt: period / POINTS as f64,
            fwd,
            gain,
            // The wind's push moves the lateral velocity's resting point.
            drift: d.body.push / gain,
            radius: cfg.drone_radius + margin,
            margin,
            goal: cfg.goal.enabled.then(|| (env.goals()[i], cfg.goal.radius)),
            deltas: [-cfg.lateral_step, cfg.lateral_step, 0.0],
            actions: 2 + cfg.hold_action as usize,
            max_sp: cfg.max_lateral_speed,
            lateral_step: cfg.lateral_step,
            x0: d.p.x,
            z: d.p.z,
            t0: env.time(),
            length: env.arena().length,
            limit: (cfg.max_steps.saturating_sub(env.steps_of(i)) as usize).min(horizon),
            root: Node { x: d.p.x, y: d.p.y, vy: d.v.y, sp: d.lateral_sp, parent: 0, action: 0 },
        }
    }

    /// Action `a` from `node`, the `k`-th action from the root (`parent`:
    /// the node's index in its layer).
    fn step(&self, node: &Node, parent: usize, k: usize, a: usize) -> Step {
        let xk = self.x0 + self.fwd * (k as f64 * self.period) as f32;
        let tk = self.t0 + k as f64 * self.period;
        let sp = (node.sp + self.deltas[a]).clamp(-self.max_sp, self.max_sp);
        let rest = sp + self.drift;
        let gain = self.gain;
        let mut path = [Vector::ZERO; POINTS + 1];
        for (j, p) in path.iter_mut().enumerate() {
            let t = (j as f64 * self.dt) as f32;
            let y = node.y + rest * t + (node.vy - rest) * (1.0 - (-gain * t).exp()) / gain;
            *p = Vector::new(xk + self.fwd * t, y, self.z);
        }
        if self.geometry.path_hits(&path, self.radius, tk, self.dt) {
            return Step::Blocked;
        }
        let end = path[POINTS];
        let vy = rest + (node.vy - rest) * (-gain * self.period as f32).exp();
        let child = Node { x: end.x, y: end.y, vy, sp, parent: parent as u32, action: a as u8 };
        let reached = match self.goal {
            Some((at, r)) => match passes(at, r, self.margin, &path) {
                Some(true) => true,
                // Past the goal without passing within reach.
                Some(false) => return Step::Blocked,
                None => false,
            },
            None => end.x >= self.length,
        };
        if reached {
            return Step::Through(child);
        }
        Step::On(child, ((end.y / CELL_Y).round() as i32, (sp / self.lateral_step).round() as i32))
    }
}

/// The breadth-first search of [`Planner`] for agent `i` of `env`: through
/// to the end (or the goal), or clear for `horizon` actions; starting with
/// action `first` where one is given.
pub(super) fn search(
    geometry: &Geometry,
    env: &VecEnv,
    i: usize,
    margin: f32,
    horizon: usize,
    first: Option<u8>,
) -> Plan {
    let m = Model::new(geometry, env, i, margin, horizon);
    let mut layers: Vec<Vec<Node>> = vec![vec![m.root]];
    for k in 0..m.limit {
        let mut next: Vec<Node> = Vec::new();
        let mut seen: HashSet<(i32, i32)> = HashSet::new();
        for (n, node) in layers[k].iter().enumerate() {
            for a in 0..m.actions {
                if k == 0 && first.is_some_and(|f| f as usize != a) {
                    continue;
                }
                match m.step(node, n, k, a) {
                    Step::Blocked => {}
                    Step::Through(child) => {
                        layers.push(vec![child]);
                        return unwind(&layers, 0, true);
                    }
                    Step::On(child, key) => {
                        if seen.insert(key) {
                            next.push(child);
                        }
                    }
                }
            }
        }
        if next.is_empty() {
            break;
        }
        layers.push(next);
    }
    // Clear for the whole horizon (shorter than the episode's rest), or no
    // way through in the model: the longest way found.
    let clear = horizon != usize::MAX && layers.len() == m.limit + 1;
    unwind(&layers, 0, clear)
}

/// Whether a way starting with action `first` is clear for `horizon`
/// actions (or through to the end or the goal sooner) for agent `i` of
/// `env`: the question a label asks of [`search`], answered depth first,
/// stopping at the first such way. The states are merged on the same grid
/// (a state whose cell at its depth was reached before is not searched
/// again), so it answers as the breadth-first search does but where a
/// merged state's representative differs; where a way exists it walks
/// one way instead of every layer whole.
pub(super) fn clear_way(
    geometry: &Geometry,
    env: &VecEnv,
    i: usize,
    margin: f32,
    horizon: usize,
    first: u8,
) -> bool {
    let m = Model::new(geometry, env, i, margin, horizon);
    // The episode's end is no way through (as for [`search`]); the
    // horizon's is.
    let clear_at_limit = horizon != usize::MAX;
    if m.limit == 0 {
        return clear_at_limit;
    }
    // Per depth, the cells reached; the stack holds each node's depth and
    // its next action to try.
    let mut seen: Vec<HashSet<(i32, i32)>> = vec![HashSet::new(); m.limit + 1];
    let mut stack: Vec<(Node, usize, usize)> = vec![(m.root, 0, first as usize)];
    while let Some(top) = stack.last_mut() {
        let (node, k, a) = *top;
        let last = if k == 0 { first as usize } else { m.actions - 1 };
        if a > last {
            stack.pop();
            continue;
        }
        top.2 += 1;
        match m.step(&node, 0, k, a) {
            Step::Blocked => {}
            Step::Through(_) => return true,
            Step::On(child, key) => {
                if k + 1 == m.limit {
                    if clear_at_limit {
                        return true;
                    }
                } else if seen[k + 1].insert(key) {
                    stack.push((child, k + 1, 0));
                }
            }
        }
    }
    false
}

/// Whether a step's `path` passes within `r` of the goal `at` less the
/// margin (Some(true)), has gone `r` past it without (Some(false), the
/// environment's miss), or has not reached it yet.
pub(super) fn passes(at: [f32; 2], r: f32, margin: f32, path: &[Vector]) -> Option<bool> {
    let reach = (r - margin).max(0.05);
    let near = path.windows(2).any(|w| Goal::closest(at, w[0], w[1]) <= reach);
    let end = path[path.len() - 1];
    if near {
        Some(true)
    } else if end.x >= at[0] + r {
        Some(false)
    } else {
        None
    }
}

/// The actions from the root to node `n` of the last layer.
fn unwind(layers: &[Vec<Node>], mut n: usize, through: bool) -> Plan {
    let mut steps = Vec::with_capacity(layers.len());
    for layer in layers[1..].iter().rev() {
        let node = layer[n];
        steps.push((node.action, [node.x, node.y]));
        n = node.parent as usize;
    }
    steps.reverse();
    Plan { steps, next: 0, through }
}
