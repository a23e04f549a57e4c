//! Seen movers (`[sim.tracks]`): per agent, the moving obstacles its own
//! camera has shown it this episode, as a tracker with memory reports them
//! (NavRL's detector and Kalman tracker, with a detector that never
//! mislabels what the camera shows): where each was at its last sighting,
//! its velocity as its sightings show it, its size, the time since, how
//! long it was watched and the stretch of its track seen so far (where it
//! was seen to turn). The student reads the `count` nearest after its
//! velocity, goal and map; a planner of the map (`Sight::Map`) predicts
//! each mover from its track alone.
//!
//! A track is written only from a sighting: a mover that at least one ray
//! of the agent's frame (through the middle `band` rows) meets first, on
//! the scene at the frame's time, seen from where the camera was (its
//! latency included). Nothing of a mover no ray met, nor of any sighting's
//! future, is ever in it.

use rapier3d::math::Vector;

use std::f32::consts::TAU;

use crate::arena::{Motion, Obstacle};
use crate::map::turned;
use crate::render::scene::{Shape, hit_shape};

/// Floats of one track in an observation: present (1), the position at its
/// last sighting relative to the drone (body frame, tens of metres, 2),
/// its velocity (body frame, m/s, 2) and whether it is known (1), its half
/// size (body frame, m, 2), the time since its last sighting and how long
/// it was watched (both shares of `keep_s`, 2), the centre of the stretch
/// of its track seen so far relative to the drone and that stretch's half
/// lengths (body frame, tens of metres, 4). Zeros where no track is.
pub const TRACK_FLOATS: usize = rotorhive_msg::TRACK_FLOATS;
/// The most tracks an observation may hold (`sim.tracks.count`).
pub const MAX_TRACKS: usize = rotorhive_msg::MAX_TRACK_FLOATS / TRACK_FLOATS;
/// Sightings further apart than this (s) give no velocity: the mover may
/// have turned between them.
pub const VELOCITY_GAP_S: f64 = 2.0;
/// The default of `sim.tracks.unseen_reach_m`: how far (m) beyond where
/// it is now a planner of the tracks takes a mover going back and forth to
/// go on towards an end it was never seen to turn at. Optimistic on
/// purpose: the planner searches again at every step, and still boxes
/// over what a mover might reach closed L4's passages (with the old boxes
/// grown by 1.5 m 22-29 %); chosen on L4's validation layouts
/// (docs/results/map.md).
pub const UNSEEN_REACH_M: f32 = 0.5;

/// How much less far than its speed would take it a mover going back and
/// forth must go between two sightings to have turned in between (m): the
/// sightings are exact, so this is rounding's room only.
const TURN_SLACK_M: f32 = 0.02;

/// The seen movers' settings (`[sim.tracks]`; off by default).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackSpec {
    /// The nearest tracks the observation holds (0: no tracks).
    pub count: usize,
    /// How long a mover unseen is kept (s).
    pub keep_s: f32,
    /// Rows of each frame the detector reads, about its middle (0: every
    /// row).
    pub band: usize,
    /// How far (m) a planner of the tracks takes a mover going back and
    /// forth to go on beyond where it is now, towards an end it was never
    /// seen to turn at (the planner's guess; the observation holds no
    /// such thing).
    pub unseen_reach_m: f32,
}

impl Default for TrackSpec {
    fn default() -> Self {
        Self { count: 0, keep_s: 10.0, band: 2, unseen_reach_m: UNSEEN_REACH_M }
    }
}

impl TrackSpec {
    /// Whether the settings are the defaults (no tracks): a config writes
    /// no `[sim.tracks]` then.
    pub fn is_off(&self) -> bool {
        *self == Self::default()
    }

    /// Whether the observation holds tracks.
    pub fn enabled(&self) -> bool {
        self.count > 0
    }

    /// Floats the tracks add to an observation.
    pub fn floats(&self) -> usize {
        self.count * TRACK_FLOATS
    }

    /// Checks the ranges; the key (under `[sim.tracks]`) and what is wrong.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if self.count > MAX_TRACKS {
            return Err(("count", format!("must be 0 (off) to {MAX_TRACKS}, got {}", self.count)));
        }
        if !(self.keep_s.is_finite() && (0.1..=600.0).contains(&self.keep_s)) {
            return Err(("keep_s", format!("must lie in [0.1, 600], got {}", self.keep_s)));
        }
        if self.band > 1024 {
            return Err(("band", format!("must be 0 (every row) to 1024 rows, got {}", self.band)));
        }
        if !(self.unseen_reach_m.is_finite() && (0.0..=50.0).contains(&self.unseen_reach_m)) {
            let got = self.unseen_reach_m;
            return Err(("unseen_reach_m", format!("must lie in [0, 50] m, got {got}")));
        }
        Ok(())
    }
}

/// What one agent's tracker knows of one moving obstacle.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// The obstacle's index in the world's arena (the detector's label).
    pub obstacle: usize,
    /// When it was first and last seen (s of the world's clock).
    pub first_t: f64,
    pub last_t: f64,
    /// Its centre (x, y) at its first and its last sighting.
    pub first: [f32; 2],
    pub last: [f32; 2],
    /// Its centre and time at the sighting before the last.
    prev: Option<([f32; 2], f64)>,
    /// Its velocity (m/s) between its last two sightings, where they were
    /// at most [`VELOCITY_GAP_S`] apart.
    pub velocity: Option<[f32; 2]>,
    /// The highest speed seen between two sightings (m/s): a turn between
    /// two makes their velocity slower than the mover.
    speed: f32,
    /// The direction of its first velocity seen: the axis a mover going
    /// back and forth keeps.
    axis: Option<[f32; 2]>,
    /// Which way along the axis it went at its last velocity (+1, -1; 0:
    /// none yet).
    going: i8,
    /// How far along the axis from its first sighting it was seen, least
    /// and most (m).
    reach: [f32; 2],
    /// Where along the axis it turned at its low and its high end, where
    /// it was seen to: a turn between two sightings puts the end where
    /// its speed would have taken it and brought it back (m).
    ends: [Option<f32>; 2],
    /// Whether a velocity left the axis by more than 30 degrees: it goes
    /// round, not back and forth.
    pub curved: bool,
    /// Its half size (x, y; m) as seen.
    pub half: [f32; 2],
    /// The box (x, y) of every centre it was seen at.
    pub lo: [f32; 2],
    pub hi: [f32; 2],
}

impl Track {
    fn new(obstacle: usize, t: f64, at: [f32; 2], half: [f32; 2]) -> Self {
        Self {
            obstacle,
            first_t: t,
            last_t: t,
            first: at,
            last: at,
            prev: None,
            velocity: None,
            speed: 0.0,
            axis: None,
            going: 0,
            reach: [0.0; 2],
            ends: [None; 2],
            curved: false,
            half,
            lo: at,
            hi: at,
        }
    }

    /// A sighting at time `t` with its centre at `at`.
    fn see(&mut self, t: f64, at: [f32; 2]) {
        if t <= self.last_t {
            // The same frame seen again (a reset's frame, then the step's).
            self.last = at;
            return;
        }
        let dt = t - self.last_t;
        self.prev = Some((self.last, self.last_t));
        self.velocity = (dt <= VELOCITY_GAP_S).then(|| {
            let k = (1.0 / dt) as f32;
            [(at[0] - self.last[0]) * k, (at[1] - self.last[1]) * k]
        });
        if self.velocity.is_none() {
            // Unseen for long: it may have turned any number of times.
            self.going = 0;
        }
        if let Some(v) = self.velocity.filter(|v| v[0].hypot(v[1]) > 1e-4) {
            let speed = v[0].hypot(v[1]);
            let axis = *self.axis.get_or_insert([v[0] / speed, v[1] / speed]);
            if (axis[0] * v[1] - axis[1] * v[0]).abs() > 0.5 * speed {
                self.curved = true;
            }
            let (a, b) = (self.along(axis, self.last), self.along(axis, at));
            // How far it went at the fastest it was seen to go: a mover
            // going back and forth keeps its speed, so one that went less
            // far turned in between (or went the other way).
            let far = self.speed * dt as f32;
            let g = f32::from(self.going);
            if self.going != 0 && ((b - a) * g < 0.0 || (b - a).abs() < far - TURN_SLACK_M) {
                // Out to the end and back: (end - a) + (end - b) = far.
                self.ends[(self.going > 0) as usize] = Some((a + b + g * far) / 2.0);
                self.going = -self.going;
            } else if (b - a).abs() > 1e-4 {
                self.going = if b > a { 1 } else { -1 };
            }
            self.speed = self.speed.max((b - a).abs() / dt as f32);
        }
        self.last = at;
        self.last_t = t;
        if let Some(axis) = self.axis {
            let s = self.along(axis, at);
            self.reach = [self.reach[0].min(s), self.reach[1].max(s)];
        }
        self.lo = [self.lo[0].min(at[0]), self.lo[1].min(at[1])];
        self.hi = [self.hi[0].max(at[0]), self.hi[1].max(at[1])];
    }

    /// How far along `axis` from its first sighting `p` lies (m).
    fn along(&self, axis: [f32; 2], p: [f32; 2]) -> f32 {
        (p[0] - self.first[0]) * axis[0] + (p[1] - self.first[1]) * axis[1]
    }

    /// Whether it was seen to turn.
    pub fn turned(&self) -> bool {
        self.ends.iter().any(Option::is_some)
    }

    /// The sighting before the last (centre, time), if any.
    pub fn previous(&self) -> Option<([f32; 2], f64)> {
        self.prev
    }

    /// The mover as a planner that knows this track and nothing more
    /// predicts it, `seen` being the obstacle as the detector saw it at its
    /// last sighting (shape and place). Going round: on the circle its
    /// sightings make. Going back and forth: between its ends at the
    /// fastest speed seen, where its last sighting puts it; an end seen
    /// turned at is where the turn was (a turn between two sightings put
    /// where that speed would have taken it and back), the end it goes to
    /// unseen `unseen_reach_m` on from where it was last, the one behind
    /// it unseen at the furthest it was seen. Seen once, or unseen for
    /// longer than [`VELOCITY_GAP_S`] since its sighting before: a still
    /// box over the stretch seen.
    pub fn predicted(&self, seen: &Obstacle, unseen_reach_m: f32) -> Obstacle {
        if self.curved
            && let Some(round) = self.circle(seen)
        {
            return round;
        }
        let axis = match (self.velocity, self.axis) {
            (Some(v), Some(axis)) if !self.curved && v[0].hypot(v[1]) > 1e-4 => axis,
            _ => return self.boxed(seen),
        };
        let speed = self.speed.max(1e-3);
        let now = self.along(axis, self.last);
        // The ends: each seen to turn at where it turned; the one it goes
        // to, unseen, at least `unseen_reach_m` beyond where it is now;
        // the one behind it, unseen, where it was seen furthest (it is
        // not back there before it has turned ahead).
        let [mut s0, mut s1] = self.reach;
        match self.ends[0] {
            Some(e) => s0 = s0.min(e),
            None if self.going < 0 => s0 = s0.min(now - unseen_reach_m),
            None => {}
        }
        match self.ends[1] {
            Some(e) => s1 = s1.max(e),
            None if self.going > 0 => s1 = s1.max(now + unseen_reach_m),
            None => {}
        }
        let len = s1 - s0;
        if len < 0.05 {
            return self.boxed(seen);
        }
        let cycle = 2.0 * len;
        let from_start = (now - s0).clamp(0.0, len);
        let s = if self.going > 0 { from_start } else { cycle - from_start };
        let phase = ((s - speed * self.last_t as f32) / cycle).rem_euclid(1.0);
        let start = [self.first[0] + s0 * axis[0], self.first[1] + s0 * axis[1]];
        let c = seen.center();
        let mut o = seen.shifted([start[0] - c[0], start[1] - c[1], 0.0]);
        o.set_motion(Some(Motion::Segment {
            offset: [axis[0] * len, axis[1] * len],
            speed,
            phase: if phase < 1.0 { phase } else { 0.0 },
        }));
        o
    }

    /// A mover seen going round, on the circle through its first, second
    /// last and last sightings, at the angular speed of the last two,
    /// where its last sighting puts it; `None` where they do not make a
    /// circle of 5 cm to 20 m.
    fn circle(&self, seen: &Obstacle) -> Option<Obstacle> {
        let (b, tb) = self.prev?;
        let (a, c) = (self.first, self.last);
        // The centre: where the perpendicular bisectors of a-b and b-c meet.
        let d = 2.0 * (a[0] * (b[1] - c[1]) + b[0] * (c[1] - a[1]) + c[0] * (a[1] - b[1]));
        if d.abs() < 1e-6 {
            return None;
        }
        let n = |p: [f32; 2]| p[0] * p[0] + p[1] * p[1];
        let (na, nb, nc) = (n(a), n(b), n(c));
        let o = [
            (na * (b[1] - c[1]) + nb * (c[1] - a[1]) + nc * (a[1] - b[1])) / d,
            (na * (c[0] - b[0]) + nb * (a[0] - c[0]) + nc * (b[0] - a[0])) / d,
        ];
        let r = (c[0] - o[0]).hypot(c[1] - o[1]);
        let dt = (self.last_t - tb) as f32;
        if !(0.05..=20.0).contains(&r) || dt <= 0.0 {
            return None;
        }
        let angle = |p: [f32; 2]| (p[1] - o[1]).atan2(p[0] - o[0]);
        let turn =
            (angle(c) - angle(b) + std::f32::consts::PI).rem_euclid(TAU) - std::f32::consts::PI;
        let speed = turn / dt * r;
        if speed.abs() < 1e-4 {
            return None;
        }
        let phase = ((angle(c) - speed * self.last_t as f32 / r) / TAU).rem_euclid(1.0);
        let now = seen.center();
        let mut round = seen.shifted([o[0] - now[0], o[1] - now[1], 0.0]);
        round.set_motion(Some(Motion::Circle {
            radius: r,
            speed,
            phase: if phase < 1.0 { phase } else { 0.0 },
        }));
        Some(round)
    }

    /// A still box over the stretch seen with `seen`'s size.
    fn boxed(&self, seen: &Obstacle) -> Obstacle {
        let (lo, hi) = seen.aabb();
        let half = [(hi[0] - lo[0]) / 2.0, (hi[1] - lo[1]) / 2.0, (hi[2] - lo[2]) / 2.0];
        let (a, b) = (self.lo, self.hi);
        let c = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0, (lo[2] + hi[2]) / 2.0];
        let h = [(b[0] - a[0]) / 2.0 + half[0], (b[1] - a[1]) / 2.0 + half[1], half[2]];
        Obstacle::still_box(c, h)
    }
}

/// Casts `dirs` (cos, sin from the heading, counter-clockwise) turned by
/// the heading `(cos, sin)` level from `p` through `shapes` (the
/// renderers' ray tests): `out[k]` the distance along ray `k` to the
/// first, divided by `range` (1: none within it).
pub(crate) fn cast_through(
    shapes: &[Shape],
    p: Vector,
    heading: (f32, f32),
    dirs: &[(f32, f32)],
    range: f32,
    out: &mut [f32],
) {
    for (&ray, o) in dirs.iter().zip(out) {
        let (dx, dy) = turned(heading, ray);
        let d = Vector::new(dx, dy, 0.0);
        let near = shapes.iter().fold(range, |t, s| hit_shape(s, p, d, t));
        *o = (near / range).min(1.0);
    }
}

/// Every agent's tracker.
#[derive(Debug, Clone)]
pub(crate) struct Trackers {
    spec: TrackSpec,
    tracks: Vec<Vec<Track>>,
}

impl Trackers {
    pub(crate) fn new(spec: &TrackSpec, agents: usize) -> Self {
        Self { spec: spec.clone(), tracks: vec![Vec::new(); agents] }
    }

    pub(crate) fn spec(&self) -> &TrackSpec {
        &self.spec
    }

    /// Forgets agent `i`'s tracks (its episode starts).
    pub(crate) fn clear(&mut self, i: usize) {
        self.tracks[i].clear();
    }

    /// Agent `i`'s tracks now (the oldest sightings may have expired).
    pub(crate) fn of(&self, i: usize) -> &[Track] {
        &self.tracks[i]
    }

    /// Agent `i` sees obstacle `k` at time `t`, its centre at `at` and its
    /// half size `half`.
    pub(crate) fn see(&mut self, i: usize, k: usize, t: f64, at: [f32; 2], half: [f32; 2]) {
        let tracks = &mut self.tracks[i];
        match tracks.iter_mut().find(|tr| tr.obstacle == k) {
            Some(tr) => tr.see(t, at),
            None => tracks.push(Track::new(k, t, at, half)),
        }
    }

    /// Drops agent `i`'s tracks unseen for longer than `keep_s` at `t`.
    pub(crate) fn expire(&mut self, i: usize, t: f64) {
        let keep = f64::from(self.spec.keep_s);
        self.tracks[i].retain(|tr| t - tr.last_t <= keep);
    }

    /// Writes agent `i`'s `count` nearest tracks (by their last sighting,
    /// from `p`) as the observation reads them, turned to `heading`
    /// (rad), at time `t`; zeros after the last. `out` holds
    /// [`TrackSpec::floats`] floats.
    pub(crate) fn encode(&self, i: usize, p: Vector, heading: f32, t: f64, out: &mut [f32]) {
        let out = &mut out[..self.spec.floats()];
        out.fill(0.0);
        let keep = f64::from(self.spec.keep_s);
        // Tracks older than `keep_s` were dropped when the frame was taken
        // (`Trackers::expire`).
        let mut live: Vec<(&Track, f32)> = self.tracks[i]
            .iter()
            .map(|tr| (tr, (tr.last[0] - p.x).hypot(tr.last[1] - p.y)))
            .collect();
        live.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.obstacle.cmp(&b.0.obstacle)));
        let (s, c) = heading.sin_cos();
        // World (x, y) to the body frame: ahead, left.
        let turn = |x: f32, y: f32| [c * x + s * y, -s * x + c * y];
        let size =
            |hx: f32, hy: f32| [(c * hx).abs() + (s * hy).abs(), (s * hx).abs() + (c * hy).abs()];
        for ((tr, _), o) in live.iter().zip(out.chunks_exact_mut(TRACK_FLOATS)) {
            let rel = turn(tr.last[0] - p.x, tr.last[1] - p.y);
            let v = tr.velocity.unwrap_or([0.0; 2]);
            let vb = turn(v[0], v[1]);
            let half = size(tr.half[0], tr.half[1]);
            let mid = turn((tr.lo[0] + tr.hi[0]) / 2.0 - p.x, (tr.lo[1] + tr.hi[1]) / 2.0 - p.y);
            let span = size((tr.hi[0] - tr.lo[0]) / 2.0, (tr.hi[1] - tr.lo[1]) / 2.0);
            o.copy_from_slice(&[
                1.0,
                rel[0] / 10.0,
                rel[1] / 10.0,
                vb[0],
                vb[1],
                tr.velocity.is_some() as u8 as f32,
                half[0],
                half[1],
                ((t - tr.last_t) / keep) as f32,
                ((tr.last_t - tr.first_t) / keep).min(1.0) as f32,
                mid[0] / 10.0,
                mid[1] / 10.0,
                span[0] / 10.0,
                span[1] / 10.0,
            ]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mover going back and forth, sighted every `every` seconds from
    /// `from` to `to`: its track.
    fn sighted(mover: &Obstacle, (from, to, every): (f64, f64, f64)) -> Track {
        let at = |t: f64| {
            let c = mover.at(t).center();
            [c[0], c[1]]
        };
        let mut track = Track::new(0, from, at(from), [0.5, 0.5]);
        let mut t = from + every;
        while t <= to {
            track.see(t, at(t));
            t += every;
        }
        track
    }

    #[test]
    fn turns_between_sightings_put_the_ends_where_the_speed_says() {
        // 2.2 m at 0.4 m/s (a cycle of 11 s), sighted every 0.7 s: no
        // sighting falls on a turn.
        let mut mover = Obstacle::still_box([0.0, 1.0, 1.0], [0.5, 0.5, 1.0]);
        mover.set_motion(Some(Motion::Segment { offset: [0.0, 2.2], speed: 0.4, phase: 0.1 }));
        let track = sighted(&mover, (0.3, 14.3, 0.7));
        assert!(track.ends.iter().all(Option::is_some), "both turns seen: {:?}", track.ends);
        let predicted = track.predicted(&mover.at(track.last_t), UNSEEN_REACH_M);
        for dt in [0.0, 1.3, 4.0, 7.7, 20.0] {
            let t = track.last_t + dt;
            let (p, want) = (predicted.at(t).center(), mover.at(t).center());
            assert!((p[1] - want[1]).abs() < 1e-3, "{dt} s on: {p:?} against {want:?}");
        }
        // Sightings over two seconds apart tell no way: a still box.
        let gaps = sighted(&mover, (0.3, 14.3, 2.5));
        assert!(gaps.predicted(&mover.at(gaps.last_t), UNSEEN_REACH_M).motion().is_none());
    }

    #[test]
    fn rays_cast_through_shapes_meet_them_where_marching_first_enters_them() {
        let shapes = [
            Shape::of(&Obstacle::still_box([2.5, 0.5, 3.0], [0.5, 1.0, 3.0])),
            Shape::of(&Obstacle::still_cylinder([-1.5, 2.0, 3.0], 0.7, 3.0)),
        ];
        let inside = |s: &Shape, p: [f32; 2]| match *s {
            Shape::Box { min, max } => {
                (min.x..=max.x).contains(&p[0]) && (min.y..=max.y).contains(&p[1])
            }
            Shape::Cylinder { cx, cy, r2, .. } => (p[0] - cx).hypot(p[1] - cy) <= r2.sqrt(),
        };
        let range = 10.0;
        let mut met = 0;
        for (n, o) in [[0.0, 0.0], [2.5, 0.0], [-1.0, 2.2], [4.0, 3.0]].into_iter().enumerate() {
            let dirs: Vec<(f32, f32)> = (0..72)
                .map(|k| TAU * (k as f32 + 0.25 * n as f32) / 72.0)
                .map(|a| (a.cos(), a.sin()))
                .collect();
            for s in &shapes {
                let mut got = vec![0.0; dirs.len()];
                cast_through(
                    std::slice::from_ref(s),
                    Vector::new(o[0], o[1], 2.0),
                    (1.0, 0.0),
                    &dirs,
                    range,
                    &mut got,
                );
                for (&(dx, dy), got) in dirs.iter().zip(got) {
                    let want = (0..10_000)
                        .map(|j| j as f32 / 1000.0)
                        .find(|&r| inside(s, [o[0] + r * dx, o[1] + r * dy]));
                    match want {
                        Some(r) => {
                            met += 1;
                            let r = r / range;
                            assert!(
                                (got - r).abs() < 2e-4,
                                "{s:?} from {o:?} along {dx}, {dy}: {got} / {r}"
                            );
                        }
                        None => assert_eq!(got, 1.0, "{s:?} from {o:?} along {dx}, {dy}"),
                    }
                }
            }
        }
        assert!(met > 40, "the rays meet the shapes {met} times");
        // Cast through both: the nearer, a share of the range.
        let dirs = [(1.0, 0.0), (0.0, 1.0)];
        let mut out = [0.0; 2];
        cast_through(&shapes, Vector::new(0.0, 0.0, 2.0), (1.0, 0.0), &dirs, range, &mut out);
        assert_eq!(out, [0.2, 1.0]);
    }
}
