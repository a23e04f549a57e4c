//! A privileged planner: it knows every obstacle and where each moving one
//! will be, and searches the drone's action sequences for one that flies
//! through (to the far end, or to the goal) without a contact. It is not a
//! policy a drone could have (it sees the future); `hive eval --policy
//! planner` flies it to measure what a level's episodes allow: what it
//! flies is a floor under the share of episodes that can be flown at all.
//! Told only what the camera shows ([`Sight::View`], [`Sight::ViewVelocity`],
//! [`Sight::ViewTrack`], [`Sight::ViewMemory`]), it measures what the
//! observation leaves out.
//!
//! The search runs in a kinematic model of the flight: forward at the
//! drone's present forward speed, the lateral velocity approaching its setpoint
//! at the controller's gain (a first-order lag, with the drone's wind),
//! each action moving the setpoint as [`VecEnv::step`] does. Paths are
//! tested with the direct physics path's own collision query against
//! where every obstacle is at each point's time, with a margin for the
//! model's error. A breadth-first search over the actions, the states
//! merged on a grid of lateral position and setpoint, reaches the far end
//! (or passes the goal) or proves that no path in the model does. The
//! planner follows its plan while the drone stays where the plan said, and
//! plans again from the drone's true state when it strays.

use std::collections::HashMap;

use rapier3d::math::Vector;

use crate::env::VecEnv;
use crate::geometry::Geometry;
use crate::{Arena, Motion};

mod search;
#[cfg(test)]
use search::passes;
use search::{clear_way, search};

/// Margins added to the drone's radius in the search (m), widest first:
/// a way through with room for the model's error where there is one.
const MARGINS: [f32; 3] = [0.15, 0.05, 0.0];
/// The margin of a teacher's label's searches ([`Planner::label`]): an
/// action counts as safe where a way starting with it keeps this much room.
const LABEL_MARGIN: f32 = 0.05;
/// The margins of a graded label's searches ([`Planner::graded`]), widest
/// first: the label is the actions whose way keeps the most room.
const GRADED_MARGINS: [f32; 6] = [0.6, 0.45, 0.3, 0.2, 0.1, LABEL_MARGIN];
/// How far the drone may stray from its plan before a new one (m).
const STRAY: f32 = 0.05;

/// One state of the search: after some actions, the lateral position,
/// velocity and setpoint, and how it was reached.
#[derive(Clone, Copy)]
struct Node {
    x: f32,
    y: f32,
    vy: f32,
    sp: f32,
    parent: u32,
    action: u8,
}

/// A plan: the actions from now on and the position (x, y) each leads to.
#[derive(Default)]
struct Plan {
    steps: Vec<(u8, [f32; 2])>,
    next: usize,
    /// Whether it flies through (else it is the longest way found).
    through: bool,
}

/// What the planner knows: one type for the planner, `teacher.sight` and
/// `hive eval --sight` (written and read by its [`Sight::name`]; the
/// memory of [`Sight::ViewMemory`] and [`Sight::PixelsMemory`] is another
/// key, `teacher.memory_s` or `--memory-s`: see [`Sight::with_memory`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Sight {
    /// Every obstacle, and where each moving one will be.
    All,
    /// The obstacles the drone's camera shows now (within the depth range
    /// and the field of view, occluded ones too) and those within
    /// [`NEARBY`] of it (seen before), each moving one's future known. It
    /// plans again at every step.
    View,
    /// As [`Sight::View`], but of each moving obstacle only its present
    /// velocity (what two frames show): it is guessed to go on at that
    /// velocity for [`GUESS_S`] and come back, over and over.
    ViewVelocity,
    /// As [`Sight::View`], but each moving obstacle stands still over its
    /// whole track (the box of every place it goes): where it goes is
    /// known, when it is where is not. A policy that watched a mover long
    /// enough could know this much without knowing its phase.
    ViewTrack,
    /// As [`Sight::View`] for the moving obstacles it has watched (in view
    /// this episode) for half their cycle, long enough to have seen one
    /// turn; the others as in [`Sight::ViewTrack`]. What a pilot with
    /// memory of what its camera showed could know. With a memory of
    /// `Some(s)` seconds, a mover whose half cycle is longer than that is
    /// never known (its turn does not fit in what the pilot remembers).
    ViewMemory(Option<u16>),
    /// What the pixels show: the obstacles that at least one of the
    /// camera's rays meets first in the present frame (occlusion, depth
    /// range and field of view as the renderer has them,
    /// [`VecEnv::visible_obstacles`]), and those within [`NEARBY`]; each
    /// moving one seen as [`Sight::ViewVelocity`] guesses it (what two
    /// frames show). The ceiling of a pilot without memory.
    Pixels,
    /// As [`Sight::Pixels`], and every obstacle a ray met this episode,
    /// within the last `Some(s)` seconds (or the whole episode); each moving
    /// one as [`Sight::ViewMemory`] knows it. The ceiling of a pilot with
    /// memory of what its camera showed.
    PixelsMemory(Option<u16>),
    /// What the agent's camera map (`[sim.map]`) and seen movers
    /// (`[sim.tracks]`) hold: the still obstacles with a cell of the map
    /// marked as met in their footprint, and nothing else (no obstacle
    /// known by nearness); each moving one predicted from its track alone
    /// ([`crate::Track::predicted`]), or without tracks each one with a
    /// marked cell over its whole track. The ceiling of a student that
    /// reads the map and the tracks. Needs an environment with a map
    /// (none: nothing is known).
    Map,
}

impl Sight {
    /// Every sight (the memories the whole episode), in the order the
    /// command line lists them.
    pub const EVERY: [Sight; 8] = [
        Sight::All,
        Sight::View,
        Sight::ViewVelocity,
        Sight::ViewTrack,
        Sight::ViewMemory(None),
        Sight::Pixels,
        Sight::PixelsMemory(None),
        Sight::Map,
    ];

    /// Its name in configs, on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Sight::All => "all",
            Sight::View => "view",
            Sight::ViewVelocity => "view-velocity",
            Sight::ViewTrack => "view-track",
            Sight::ViewMemory(_) => "view-memory",
            Sight::Pixels => "pixels",
            Sight::PixelsMemory(_) => "pixels-memory",
            Sight::Map => "map",
        }
    }

    /// What it knows, in a few words (for logs and `--help`).
    pub fn what(self) -> &'static str {
        match self {
            Sight::All => "every obstacle's motion",
            Sight::View => "what the camera shows, with the movers' future",
            Sight::ViewVelocity => "what the camera shows, the movers' velocity kept 3 s",
            Sight::ViewTrack => "what the camera shows, each mover over its whole track",
            Sight::ViewMemory(_) => {
                "what the camera shows, each mover known once watched for half its cycle"
            }
            Sight::Pixels => "what the pixels show now",
            Sight::PixelsMemory(_) => "what the pixels showed this episode",
            Sight::Map => "what the camera's map holds",
        }
    }

    /// Whether it remembers (takes a memory in seconds).
    pub fn remembers(self) -> bool {
        matches!(self, Sight::ViewMemory(_) | Sight::PixelsMemory(_))
    }

    /// Whether the planner knows only what the pixels show.
    pub fn pixels(self) -> bool {
        matches!(self, Sight::Pixels | Sight::PixelsMemory(_))
    }

    /// The same sight remembering `memory_s` seconds (`None`: the whole
    /// episode); a sight that does not remember is returned as it is.
    pub fn with_memory(self, memory_s: Option<u16>) -> Self {
        match self {
            Sight::ViewMemory(_) => Sight::ViewMemory(memory_s),
            Sight::PixelsMemory(_) => Sight::PixelsMemory(memory_s),
            other => other,
        }
    }
}

impl std::str::FromStr for Sight {
    type Err = String;

    /// A sight by its [`Sight::name`] (a memory the whole episode).
    fn from_str(s: &str) -> Result<Self, String> {
        Sight::EVERY.into_iter().find(|k| k.name() == s).ok_or_else(|| {
            let names: Vec<&str> = Sight::EVERY.iter().map(|k| k.name()).collect();
            format!("unknown sight `{s}` (one of {})", names.join(", "))
        })
    }
}

impl TryFrom<String> for Sight {
    type Error = String;

    fn try_from(s: String) -> Result<Self, String> {
        s.parse()
    }
}

impl From<Sight> for String {
    fn from(s: Sight) -> Self {
        s.name().to_string()
    }
}

impl std::fmt::Display for Sight {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Obstacles this close to a drone (m, from its surface) are known to a
/// planner of [`Sight::View`] wherever they are.
const NEARBY: f32 = 2.0;
/// How long (s) a planner of [`Sight::ViewVelocity`] guesses a moving
/// obstacle keeps its present velocity before it turns back (the levels'
/// movers turn after 2-15 s).
const GUESS_S: f32 = 3.0;

/// Plans and flies every agent of an environment.
pub struct Planner {
    sight: Sight,
    geometry: Geometry,
    plans: Vec<Option<Plan>>,
    /// Episodes whose first search, from the spawn, found no way through.
    hopeless: usize,
    /// Per agent: what it has seen this episode ([`Sight::ViewMemory`],
    /// [`Sight::PixelsMemory`]).
    watched: Vec<Watched>,
    /// Whether a label's searches go depth first ([`clear_way`]) rather
    /// than breadth first ([`search`]).
    depth_first: bool,
}

/// What one agent's camera has shown this episode: per obstacle (its
/// index in the arena), when it was first and last in view.
#[derive(Debug, Clone, Default)]
struct Watched {
    first: HashMap<usize, f64>,
    last: HashMap<usize, f64>,
}

impl Watched {
    fn clear(&mut self) {
        self.first.clear();
        self.last.clear();
    }

    /// Notes that obstacle `k` is in view at time `t`.
    fn see(&mut self, k: usize, t: f64) {
        self.first.entry(k).or_insert(t);
        self.last.insert(k, t);
    }

    /// Notes every obstacle agent `i`'s present frame shows.
    fn see_frame(&mut self, env: &VecEnv, i: usize) {
        let t = env.time();
        for k in env.visible_obstacles(i) {
            self.see(k, t);
        }
    }
}

impl Planner {
    /// A planner for the world of `env` (its lanes side by side) that
    /// knows what `sight` says.
    pub fn new(env: &VecEnv, sight: Sight) -> Self {
        Self {
            sight,
            geometry: Geometry::new(env.arena()),
            plans: (0..env.agents()).map(|_| None).collect(),
            hopeless: 0,
            watched: vec![Watched::default(); env.agents()],
            depth_first: false,
        }
    }

    /// The same planner with a label's searches depth first (`true`:
    /// [`clear_way`], stopping at the first way clear) or breadth first
    /// (`false`, the default: [`search`], every layer whole; the same
    /// answers, dearer); `teacher.label_search`.
    pub fn with_depth_first_labels(mut self, depth_first: bool) -> Self {
        self.depth_first = depth_first;
        self
    }

    /// Episodes so far in which no way through was found from the spawn,
    /// even with no margin: none in the model (an estimate, as the model
    /// is, of the episodes no pilot could fly).
    pub fn hopeless_starts(&self) -> usize {
        self.hopeless
    }

    /// The next action of every agent; agents with `active` false get 0
    /// and no search. An agent at the start of an episode plans anew.
    pub fn actions(&mut self, env: &VecEnv, active: &[bool]) -> Vec<u8> {
        (0..env.agents())
            .map(|i| {
                if !active[i] {
                    self.forget(i);
                    return 0;
                }
                self.act(env, i)
            })
            .collect()
    }

    /// Forgets agent `i`'s plan (it flies without the planner now).
    pub fn forget(&mut self, i: usize) {
        self.plans[i] = None;
    }

    /// Notes what agent `i`'s pixels show now, for a planner of
    /// [`Sight::PixelsMemory`] asked about it only now and then (a
    /// teacher's share of labels): its memory then holds every frame. Does
    /// nothing for other sights.
    pub fn watch(&mut self, env: &VecEnv, i: usize) {
        if matches!(self.sight, Sight::PixelsMemory(_)) {
            self.watched_now(env, i).see_frame(env, i);
        }
    }

    /// What agent `i` has seen this episode (forgotten where one starts).
    fn watched_now(&mut self, env: &VecEnv, i: usize) -> &mut Watched {
        if env.steps_of(i) == 0 {
            self.watched[i].clear();
        }
        &mut self.watched[i]
    }

    /// The next action of agent `i`: its plan's next step while the drone
    /// keeps to the plan (with [`Sight::All`]), else a new search from its
    /// true state. An agent at the start of an episode plans anew.
    pub fn act(&mut self, env: &VecEnv, i: usize) -> u8 {
        self.watched_now(env, i);
        let at = env.drone(i).p;
        let keep = self.sight == Sight::All
            && env.steps_of(i) > 0
            && self.plans[i].as_ref().is_some_and(|p| {
                p.next < p.steps.len()
                    && (p.next == 0 || {
                        let [x, y] = p.steps[p.next - 1].1;
                        (x - at.x).abs().max((y - at.y).abs()) <= STRAY
                    })
            });
        if !keep {
            self.plans[i] = Some(self.search(env, i));
        }
        let plan = self.plans[i].as_mut().expect("planned above");
        match plan.steps.get(plan.next) {
            Some(&(a, _)) => {
                plan.next += 1;
                a
            }
            None => 0,
        }
    }

    /// A teacher's label of agent `i`'s state now: the one action that
    /// starts a way clear for `horizon` actions (or through to the end
    /// sooner), with a margin of [`LABEL_MARGIN`], where exactly one does;
    /// `None` where every action does (the choice does not matter yet) or
    /// none does. One short search per action, each stopping at its first
    /// way through; the agent's plan is left alone.
    pub fn label(&mut self, env: &VecEnv, i: usize, horizon: usize) -> Option<u8> {
        let safe = self.safe_actions(env, i, horizon, &[LABEL_MARGIN], 2);
        (safe.len() == 1).then(|| safe[0])
    }

    /// A graded label of agent `i`'s state now, as bits (bit `a`: action
    /// `a`): the actions whose way clear for `horizon` actions keeps the
    /// most room (the widest of [`GRADED_MARGINS`] at which any action has
    /// one), so that the choice of a gap is taught before only one action
    /// is left; 0 where every action keeps as much room (the choice does
    /// not matter) or none keeps a way. Where [`Planner::label`] names an
    /// action, this is that action alone.
    pub fn graded(&mut self, env: &VecEnv, i: usize, horizon: usize) -> u8 {
        let safe = self.safe_actions(env, i, horizon, &GRADED_MARGINS, usize::MAX);
        let mask = safe.iter().fold(0u8, |m, a| m | 1 << a);
        if safe.len() == env.config().shapes().actions { 0 } else { mask }
    }

    /// Every action of agent `i` now that starts a way clear for `horizon`
    /// actions (as [`Planner::label`] searches), ties kept: empty where
    /// none does. The agreement audit's judge (`hive eval --agree`).
    pub fn allowed(&mut self, env: &VecEnv, i: usize, horizon: usize) -> Vec<u8> {
        self.safe_actions(env, i, horizon, &[LABEL_MARGIN], usize::MAX)
    }

    /// The actions that start a way clear for `horizon` actions, in order,
    /// at the first of `margins` (widest first) at which any does, the
    /// search stopping once `enough` are found; empty where none does at
    /// any.
    fn safe_actions(
        &mut self,
        env: &VecEnv,
        i: usize,
        horizon: usize,
        margins: &[f32],
        enough: usize,
    ) -> Vec<u8> {
        let (sight, depth_first) = (self.sight, self.depth_first);
        let watched = self.watched_now(env, i);
        let seen = (sight != Sight::All).then(|| Geometry::new(&in_view(env, i, sight, watched)));
        let geometry = seen.as_ref().unwrap_or(&self.geometry);
        let actions = env.config().shapes().actions as u8;
        let horizon = horizon.max(1);
        for &margin in margins {
            let mut safe = Vec::new();
            for a in 0..actions {
                if safe.len() >= enough {
                    break;
                }
                let clear = if depth_first {
                    clear_way(geometry, env, i, margin, horizon, a)
                } else {
                    search(geometry, env, i, margin, horizon, Some(a)).through
                };
                if clear {
                    safe.push(a);
                }
            }
            if !safe.is_empty() {
                return safe;
            }
        }
        Vec::new()
    }

    /// A plan for agent `i` from its true state now: with the widest
    /// margin that finds a way through, else the longest way found.
    fn search(&mut self, env: &VecEnv, i: usize) -> Plan {
        let seen = (self.sight != Sight::All)
            .then(|| Geometry::new(&in_view(env, i, self.sight, &mut self.watched[i])));
        let geometry = seen.as_ref().unwrap_or(&self.geometry);
        let mut longest = Plan::default();
        for margin in MARGINS {
            let plan = search(geometry, env, i, margin, usize::MAX, None);
            if plan.through {
                return plan;
            }
            if plan.steps.len() > longest.steps.len() {
                longest = plan;
            }
        }
        if env.steps_of(i) == 0 {
            self.hopeless += 1;
        }
        longest
    }
}

/// The world as agent `i`'s camera shows it now ([`Sight::View`]): the
/// obstacles in view or nearby, moving as they do, or each moving one
/// going on at its present velocity for [`GUESS_S`] and back
/// ([`Sight::ViewVelocity`]), or standing over its track
/// ([`Sight::ViewTrack`]), or as it moves once watched for half its cycle
/// (`watched`: when each was first in view) and over its track until then
/// ([`Sight::ViewMemory`]).
fn in_view(env: &VecEnv, i: usize, sight: Sight, watched: &mut Watched) -> Arena {
    let t = env.time();
    let reach = env.unseen_reach_m();
    let world = env.arena();
    let known = known_obstacles(env, i, sight, watched);
    let obstacles = known
        .into_iter()
        .map(|k| {
            let o = &world.obstacles[k];
            let Some(m) = o.motion().filter(|_| sight != Sight::View) else { return o.clone() };
            match sight {
                Sight::Map if env.tracks_movers() => {
                    let track = env.tracks_of(i).iter().find(|tr| tr.obstacle == k);
                    track.map_or_else(|| over_track(o), |tr| tr.predicted(&o.at(tr.last_t), reach))
                }
                Sight::ViewTrack | Sight::Map => over_track(o),
                Sight::ViewMemory(memory_s) | Sight::PixelsMemory(memory_s) => {
                    let since = *watched.first.entry(k).or_insert(t);
                    let half = half_cycle(m);
                    let fits = memory_s.is_none_or(|s| half <= f64::from(s));
                    if fits && t - since >= half { o.clone() } else { over_track(o) }
                }
                _ => velocity_guess(o, m, t),
            }
        })
        .collect();
    Arena { name: world.name.clone(), spawn: world.spawn.clone(), obstacles, ..*world }
}

/// The obstacles (indices into the world's, ascending) a planner of
/// `sight` knows for agent `i` now; notes what its pixels show in
/// `watched`.
fn known_obstacles(env: &VecEnv, i: usize, sight: Sight, watched: &mut Watched) -> Vec<usize> {
    let (d, t) = (env.drone(i), env.time());
    let world = env.arena();
    if sight == Sight::Map {
        // With the seen movers, a moving obstacle is known from its track
        // alone (not from the cells its sightings marked).
        let tracked = env.tracks_movers();
        return (0..world.obstacles.len())
            .filter(|&k| {
                let o = &world.obstacles[k];
                if tracked && o.motion().is_some() {
                    return env.tracks_of(i).iter().any(|tr| tr.obstacle == k);
                }
                let (lo, hi) = o.at(t).aabb();
                env.map_shows(i, [lo[0], lo[1]], [hi[0], hi[1]])
            })
            .collect();
    }
    if !sight.pixels() {
        return (0..world.obstacles.len())
            .filter(|&k| in_sight(env, d.p, d.q * Vector::X, &world.obstacles[k].at(t)))
            .collect();
    }
    watched.see_frame(env, i);
    let remembered = |k: usize| match (sight, watched.last.get(&k)) {
        (Sight::PixelsMemory(memory_s), Some(&at)) => {
            memory_s.is_none_or(|s| t - at <= f64::from(s))
        }
        (_, Some(&at)) => at == t,
        _ => false,
    };
    (0..world.obstacles.len())
        .filter(|&k| remembered(k) || nearby(d.p, &world.obstacles[k].at(t)))
        .collect()
}

/// Whether an obstacle (where it is now) is within [`NEARBY`] of `p`.
fn nearby(p: Vector, now: &crate::Obstacle) -> bool {
    let (lo, hi) = now.aabb();
    let reach = 0.5 * (hi[0] - lo[0]).hypot(hi[1] - lo[1]);
    let c = now.center();
    (c[0] - p.x).hypot(c[1] - p.y) - reach <= NEARBY
}

/// Whether an obstacle (where it is now) is within the camera's depth
/// range and field of view from `p` looking along `ahead`, or within
/// [`NEARBY`].
fn in_sight(env: &VecEnv, p: Vector, ahead: Vector, now: &crate::Obstacle) -> bool {
    let cfg = env.config();
    let half_fov = (cfg.camera.hfov_deg / 2.0).to_radians();
    let (lo, hi) = now.aabb();
    let reach = 0.5 * (hi[0] - lo[0]).hypot(hi[1] - lo[1]);
    let c = now.center();
    let to = Vector::new(c[0] - p.x, c[1] - p.y, 0.0);
    let dist = to.length();
    let bearing = (ahead.x * to.y - ahead.y * to.x).atan2(ahead.dot(to));
    let seen = dist - reach <= cfg.camera.range && bearing.abs() - reach.atan2(dist) <= half_fov;
    seen || nearby(p, now)
}

/// How long a mover takes to cover half its cycle (s): one end of a
/// segment to the other, half way round a circle.
fn half_cycle(m: &Motion) -> f64 {
    let len = match *m {
        Motion::Segment { offset, .. } => offset[0].hypot(offset[1]),
        Motion::Circle { radius, .. } => std::f32::consts::PI * radius,
    };
    f64::from(len / m.speed().max(1e-6))
}

/// A moving obstacle as [`Sight::ViewVelocity`] guesses it: on at its
/// present velocity for [`GUESS_S`] from where it is now, and back.
fn velocity_guess(o: &crate::Obstacle, m: &Motion, t: f64) -> crate::Obstacle {
    let (a, b) = (m.offset(t), m.offset(t + 0.01));
    let v = [(b[0] - a[0]) / 0.01, (b[1] - a[1]) / 0.01];
    let speed = v[0].hypot(v[1]);
    let mut moving = o.at(t);
    if speed > 1e-4 {
        // A segment whose start it is at now.
        let phase = (-(t as f32) / (2.0 * GUESS_S)).rem_euclid(1.0);
        let offset = [v[0] * GUESS_S, v[1] * GUESS_S];
        moving.set_motion(Some(Motion::Segment { offset, speed, phase }));
    }
    moving
}

/// A still box over every place an obstacle goes (its swept bounds).
fn over_track(o: &crate::Obstacle) -> crate::Obstacle {
    let (lo, hi) = o.swept_aabb();
    let (c, h): (Vec<f32>, Vec<f32>) =
        (0..3).map(|k| ((lo[k] + hi[k]) / 2.0, (hi[k] - lo[k]) / 2.0)).unzip();
    crate::Obstacle::still_box([c[0], c[1], c[2]], [h[0], h[1], h[2]])
}

#[cfg(test)]
mod tests;
