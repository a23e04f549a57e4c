//! Pictures of an environment as it flies, for `hive play` and Gymnasium's
//! `render_mode="rgb_array"`: on the left the arena from above, following
//! the drones, with each drone's path this episode; on the right one
//! drone's last two depth frames (previous, current) and, below them, its
//! actions as bars (their Q-values when a policy gives them, the chosen
//! one highlighted). With the camera's map (`[sim.map]`) the top view
//! shows what the followed drone's map holds (free cells tinted, cells
//! where a ray met an obstacle in orange, so that an obstacle's grey is
//! what it has not seen), and with `[sim.tracks]` the stretch each mover
//! it tracks was seen on, boxed.
//!
//! Drawn by hand into palette indices (a fixed palette of a few colours and
//! 64 greys), so that a GIF frame needs no colour quantisation and an RGB
//! image is one lookup per pixel.

use crate::arena::{Arena, Obstacle};
use crate::env::{Done, VecEnv};
use crate::map::Cell;

/// Image width (pixels).
pub const WIDTH: usize = 640;
/// Image height (pixels).
pub const HEIGHT: usize = 240;
/// Width of the top view; the depth panel takes the rest.
const TOP: usize = 432;
/// Metres of arena shown behind and ahead of the followed point.
const BEHIND: f32 = 6.0;
const AHEAD: f32 = 21.0;

const BG: u8 = 0;
const OBSTACLE: u8 = 1;
const WALL: u8 = 2;
const PANEL: u8 = 3;
const CRASH: u8 = 4;
const GOAL: u8 = 5;
const BAR: u8 = 6;
const CHOSEN: u8 = 7;
/// First of the drones' colours.
const AGENT: u8 = 8;
const AGENT_COLOURS: usize = 12;
/// The followed drone's memory: free cells, met cells, tracked movers.
const MAP_FREE: u8 = 20;
const MAP_HIT: u8 = 21;
const TRACKED: u8 = 22;
/// First of the 64 greys of depth (near dark, far light).
const GREY: u8 = 64;

/// The palette, as RGB triples, index by index (256 entries).
pub fn palette() -> Vec<u8> {
    let mut p = vec![0u8; 256 * 3];
    let fixed: [[u8; 3]; 8] = [
        [250, 250, 247],
        [96, 99, 110],
        [30, 30, 34],
        [236, 236, 240],
        [214, 39, 40],
        [44, 160, 44],
        [160, 160, 170],
        [255, 127, 14],
    ];
    let agents: [[u8; 3]; AGENT_COLOURS] = [
        [31, 119, 180],
        [148, 103, 189],
        [23, 190, 207],
        [140, 86, 75],
        [227, 119, 194],
        [188, 189, 34],
        [57, 59, 121],
        [82, 84, 163],
        [107, 110, 207],
        [99, 121, 57],
        [140, 162, 82],
        [132, 60, 57],
    ];
    let memory: [[u8; 3]; 3] = [[222, 235, 247], [230, 85, 13], [117, 107, 177]];
    for (i, c) in fixed.iter().chain(agents.iter()).chain(memory.iter()).enumerate() {
        p[i * 3..i * 3 + 3].copy_from_slice(c);
    }
    for g in 0..64 {
        let v = (g * 255 / 63) as u8;
        let i = GREY as usize + g;
        p[i * 3..i * 3 + 3].copy_from_slice(&[v, v, v]);
    }
    p
}

/// Each agent's path in its current episode, gathered step by step.
#[derive(Debug, Clone, Default)]
pub struct Tracks {
    paths: Vec<Vec<[f32; 2]>>,
    ends: Vec<Option<Done>>,
}

impl Tracks {
    /// Starts every agent's path at its position now.
    pub fn new(env: &VecEnv) -> Self {
        Self {
            paths: env.positions().iter().map(|p| vec![[p[0], p[1]]]).collect(),
            ends: vec![None; env.agents()],
        }
    }

    /// Adds the positions after a step. An agent whose episode ended in it
    /// keeps its old path with its end marked (`keep_ended`, for a video of
    /// one episode per agent), or starts a new path (and again where it is
    /// reset).
    pub fn record(&mut self, env: &VecEnv, keep_ended: bool) {
        for (i, p) in env.positions().iter().enumerate() {
            if self.ends[i].is_some() && keep_ended {
                continue;
            }
            if let Some(e) = env.finished().iter().find(|e| e.agent == i) {
                if keep_ended {
                    self.ends[i] = Some(e.done);
                    continue;
                }
                self.paths[i].clear();
            }
            // A jump of more than a few metres is a reset (one step flies
            // at most about 3.2 m): a new path.
            if self.paths[i].last().is_some_and(|l| (l[0] - p[0]).hypot(l[1] - p[1]) > 5.0) {
                self.paths[i].clear();
            }
            self.paths[i].push([p[0], p[1]]);
        }
    }

    /// Forgets the paths of the agents in `mask` (they were reset by hand).
    pub fn restart(&mut self, env: &VecEnv, mask: &[bool]) {
        for ((i, p), m) in env.positions().iter().enumerate().zip(mask) {
            if *m {
                self.paths[i] = vec![[p[0], p[1]]];
                self.ends[i] = None;
            }
        }
    }

    /// Whether agent `i`'s episode has ended (with `keep_ended`).
    pub fn ended(&self, i: usize) -> bool {
        self.ends.get(i).is_some_and(Option::is_some)
    }

    /// Whether every agent's episode has ended (with `keep_ended`).
    pub fn all_ended(&self) -> bool {
        self.ends.iter().all(Option::is_some)
    }
}

/// What one picture shows besides the arena and the paths.
#[derive(Debug, Clone, Copy)]
pub struct Focus<'a> {
    /// The drone whose view is shown.
    pub agent: usize,
    /// Its depth frames (`frames × side²`, in [0, 1], oldest first); the
    /// last two are drawn.
    pub depth: &'a [f32],
    /// Q-values of its actions (two, or three with hold), when a policy
    /// is flying.
    pub q: Option<&'a [f32]>,
    /// The action it takes next (or took last).
    pub action: Option<u8>,
}

/// A picture in palette indices, `WIDTH × HEIGHT`, row by row.
pub struct Canvas {
    /// Palette indices.
    pub px: Vec<u8>,
}

impl Default for Canvas {
    fn default() -> Self {
        Self { px: vec![BG; WIDTH * HEIGHT] }
    }
}

impl Canvas {
    /// The picture as RGB bytes (`HEIGHT × WIDTH × 3`).
    pub fn rgb(&self) -> Vec<u8> {
        let pal = palette();
        self.px
            .iter()
            .flat_map(|i| {
                let i = *i as usize * 3;
                [pal[i], pal[i + 1], pal[i + 2]]
            })
            .collect()
    }

    fn put(&mut self, x: i32, y: i32, c: u8, right: usize) {
        if x >= 0 && y >= 0 && (x as usize) < right && (y as usize) < HEIGHT {
            self.px[y as usize * WIDTH + x as usize] = c;
        }
    }

    fn rect(&mut self, x0: i32, y0: i32, x1: i32, y1: i32, c: u8, right: usize) {
        for y in y0.max(0)..y1.min(HEIGHT as i32) {
            for x in x0.max(0)..x1.min(right as i32) {
                self.px[y as usize * WIDTH + x as usize] = c;
            }
        }
    }

    fn disk(&mut self, cx: f32, cy: f32, r: f32, c: u8, right: usize) {
        let (x0, x1, y0, y1) = (
            (cx - r).floor() as i32,
            (cx + r).ceil() as i32,
            (cy - r).floor() as i32,
            (cy + r).ceil() as i32,
        );
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
                if dx * dx + dy * dy <= r * r {
                    self.put(x, y, c, right);
                }
            }
        }
    }

    fn line(&mut self, (x0, y0): (f32, f32), (x1, y1): (f32, f32), c: u8, right: usize) {
        let n = (x1 - x0).abs().max((y1 - y0).abs()).ceil().max(1.0) as i32;
        if n > 4 * WIDTH as i32 {
            return;
        }
        for k in 0..=n {
            let t = k as f32 / n as f32;
            self.put((x0 + (x1 - x0) * t) as i32, (y0 + (y1 - y0) * t) as i32, c, right);
        }
    }
}

/// Draws `env` now (with its agents' `tracks`) and one drone's view into
/// `canvas`.
pub fn draw(env: &VecEnv, tracks: &Tracks, focus: Focus<'_>, canvas: &mut Canvas) {
    canvas.px.fill(BG);
    let arena = env.arena();
    let positions = env.positions();
    // Follow the focused drone along x; the arena's width fills the height.
    let cx = positions.get(focus.agent).map_or(arena.spawn.x, |p| p[0]);
    let x0 = (cx - BEHIND).clamp(-2.0, (arena.length + 2.0 - BEHIND - AHEAD).max(-2.0));
    let scale = (TOP as f32 / (BEHIND + AHEAD)).min((HEIGHT - 8) as f32 / arena.width);
    let top = (HEIGHT as f32 - arena.width * scale) / 2.0;
    let to_px = |x: f32, y: f32| ((x - x0) * scale, top + (arena.width / 2.0 - y) * scale);
    top_view(canvas, arena, &to_px, (scale, env.time()));
    let from_px = |px: f32, py: f32| (x0 + px / scale, arena.width / 2.0 - (py - top) / scale);
    memory_view(canvas, env, focus.agent, &from_px, &to_px);
    // With a goal: the focused drone's, as a ring of its radius.
    let goal = &env.config().goal;
    if let Some(g) = env.goals().get(focus.agent).filter(|_| goal.enabled) {
        let (gx, gy) = to_px(g[0], g[1]);
        let r = (goal.radius * scale).max(3.0);
        canvas.disk(gx, gy, r, GOAL, TOP);
        canvas.disk(gx, gy, (r - 2.0).max(1.0), BG, TOP);
    }
    for (i, path) in tracks.paths.iter().enumerate() {
        let c = AGENT + (i % AGENT_COLOURS) as u8;
        for w in path.windows(2) {
            canvas.line(to_px(w[0][0], w[0][1]), to_px(w[1][0], w[1][1]), c, TOP);
        }
        let Some(last) = path.last() else { continue };
        let (px, py) = to_px(last[0], last[1]);
        let mark = match tracks.ends[i] {
            Some(Done::Collision) => CRASH,
            Some(Done::Goal) => GOAL,
            _ => c,
        };
        let r = (0.3 * scale).max(2.0);
        canvas.disk(
            px,
            py,
            if i == focus.agent { r + 1.5 } else { r },
            if i == focus.agent { CHOSEN } else { mark },
            TOP,
        );
        if i == focus.agent {
            canvas.disk(px, py, r, mark, TOP);
        }
    }
    depth_panel(canvas, focus, env.config().camera.observed_depth());
}

fn top_view(
    canvas: &mut Canvas,
    arena: &Arena,
    to_px: &impl Fn(f32, f32) -> (f32, f32),
    (scale, t): (f32, f64),
) {
    let (lx, ty) = to_px(0.0, arena.width / 2.0);
    let (rx, by) = to_px(arena.length, -arena.width / 2.0);
    // Walls above and below the flying space, the finish line at the end.
    canvas.rect(0, 0, TOP as i32, ty as i32, WALL, TOP);
    canvas.rect(0, by.ceil() as i32, TOP as i32, HEIGHT as i32, WALL, TOP);
    canvas.rect(rx as i32, ty as i32, rx as i32 + 2, by as i32, GOAL, TOP);
    canvas.rect(lx as i32 - 2, ty as i32, lx as i32, by as i32, WALL, TOP);
    // Moving obstacles where they are now.
    for o in arena.obstacles.iter().map(|o| o.at(t)) {
        match o {
            Obstacle::Box { center: c, half_extents: h, .. } => {
                let (ax, ay) = to_px(c[0] - h[0], c[1] + h[1]);
                let (bx, by) = to_px(c[0] + h[0], c[1] - h[1]);
                canvas.rect(
                    ax.floor() as i32,
                    ay.floor() as i32,
                    (bx.ceil() as i32).max(ax as i32 + 1),
                    (by.ceil() as i32).max(ay as i32 + 1),
                    OBSTACLE,
                    TOP,
                );
            }
            Obstacle::Cylinder { center: c, radius, .. } => {
                let (x, y) = to_px(c[0], c[1]);
                canvas.disk(x, y, (radius * scale).max(1.0), OBSTACLE, TOP);
            }
        }
    }
}

/// What drone `agent` remembers, over the top view (`from_px`: where a
/// point of the picture is in the arena, `to_px` the other way): each pixel of
/// the flying space its map holds free tinted, each it holds met in orange
/// (over the obstacle drawn there, or where a mover was), and each mover
/// it tracks as a box over the stretch it was seen on.
fn memory_view(
    canvas: &mut Canvas,
    env: &VecEnv,
    agent: usize,
    from_px: &impl Fn(f32, f32) -> (f32, f32),
    to_px: &impl Fn(f32, f32) -> (f32, f32),
) {
    if env.map_cell(agent, 0.0, 0.0).is_some() {
        for py in 0..HEIGHT {
            for px in 0..TOP {
                let k = py * WIDTH + px;
                let (x, y) = from_px(px as f32 + 0.5, py as f32 + 0.5);
                match (env.map_cell(agent, x, y), canvas.px[k]) {
                    (Some(Cell::Obstacle), BG | OBSTACLE) => canvas.px[k] = MAP_HIT,
                    (Some(Cell::Free), BG) => canvas.px[k] = MAP_FREE,
                    _ => {}
                }
            }
        }
    }
    for tr in env.tracks_of(agent) {
        let (a, b) = (
            to_px(tr.lo[0] - tr.half[0], tr.hi[1] + tr.half[1]),
            to_px(tr.hi[0] + tr.half[0], tr.lo[1] - tr.half[1]),
        );
        for (p, q) in [
            ((a.0, a.1), (b.0, a.1)),
            ((b.0, a.1), (b.0, b.1)),
            ((b.0, b.1), (a.0, b.1)),
            ((a.0, b.1), (a.0, a.1)),
        ] {
            canvas.line(p, q, TRACKED, TOP);
        }
    }
}

/// The panel beside the arena: the last two depth frames (of `rows` x
/// `cols` pixels), then the actions' bars.
fn depth_panel(canvas: &mut Canvas, focus: Focus<'_>, [rows, cols]: [usize; 2]) {
    canvas.rect(TOP as i32, 0, WIDTH as i32, HEIGHT as i32, PANEL, WIDTH);
    let px = rows * cols;
    // Two frames side by side across the panel, and no taller than it.
    let zoom = ((WIDTH - TOP - 24) / 2 / cols.max(1)).min(140 / rows.max(1)).max(1);
    if px > 0 && focus.depth.len().is_multiple_of(px) {
        let last_two = focus.depth.len().saturating_sub(2 * px);
        for (k, frame) in focus.depth[last_two..].chunks_exact(px).enumerate() {
            let ox = TOP + 8 + k * (cols * zoom + 8);
            for (j, d) in frame.iter().enumerate() {
                let g = GREY + (d.clamp(0.0, 1.0) * 63.0).round() as u8;
                let (u, v) = (j % cols, j / cols);
                canvas.rect(
                    (ox + u * zoom) as i32,
                    (12 + v * zoom) as i32,
                    (ox + (u + 1) * zoom) as i32,
                    (12 + (v + 1) * zoom) as i32,
                    g,
                    WIDTH,
                );
            }
        }
    }
    // The actions (left, right, hold) as bars: heights from the Q-values
    // (their range scaled to the panel), or equal without a policy.
    let base = (24 + rows * zoom + 80) as i32;
    let heights: Vec<f32> = match focus.q {
        Some(q) if q.iter().all(|v| v.is_finite()) => {
            let lo = q.iter().copied().fold(f32::INFINITY, f32::min);
            let hi = q.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let span = (hi - lo).max(1e-6);
            q.iter().map(|v| 20.0 + 50.0 * (v - lo) / span).collect()
        }
        _ => vec![40.0; 2],
    };
    let gap = if heights.len() > 2 { 70 } else { 90 };
    for (k, h) in heights.iter().enumerate() {
        let x = (TOP + 40 + k * gap) as i32;
        let c = if focus.action == Some(k as u8) { CHOSEN } else { BAR };
        canvas.rect(x, base - *h as i32, x + 60, base, c, WIDTH);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::SimConfig;

    #[test]
    fn a_picture_shows_obstacles_drones_paths_and_the_depth_frames() {
        let arena = Arena::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../configs/arenas/train.toml"
        )))
        .unwrap();
        let mut env =
            VecEnv::new(SimConfig { agents: 3, ..SimConfig::default() }, arena, 2).unwrap();
        let mut tracks = Tracks::new(&env);
        for t in 0..4 {
            env.step(&[0, 1, (t % 2) as u8]).unwrap();
            tracks.record(&env, true);
        }
        let mut canvas = Canvas::default();
        let mut depth = vec![0.0; 3 * 2 * 32 * 32];
        env.write_observations_split(&mut depth, &mut [0.0; 9]);
        draw(
            &env,
            &tracks,
            Focus { agent: 0, depth: &depth[..2 * 32 * 32], q: Some(&[1.0, 2.0]), action: Some(1) },
            &mut canvas,
        );
        let count = |c: u8| canvas.px.iter().filter(|p| **p == c).count();
        assert!(count(OBSTACLE) > 100, "obstacles drawn");
        assert!(count(WALL) > 100, "walls drawn");
        assert!(count(AGENT + 1) > 10 && count(AGENT + 2) > 10, "paths drawn");
        assert!(
            canvas.px.iter().filter(|p| **p >= GREY).count() >= 2 * 32 * 32,
            "depth frames drawn"
        );
        assert!(count(CHOSEN) > 60 * 20, "the chosen action's bar drawn");
        assert_eq!(canvas.rgb().len(), WIDTH * HEIGHT * 3);
    }

    #[test]
    fn the_followed_drones_map_and_tracks_are_drawn_only_where_it_has_them() {
        let mut arena = Arena::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../configs/arenas/train.toml"
        )))
        .unwrap();
        // Every other obstacle moves: the map holds the still ones, the
        // tracks the movers.
        for o in arena.obstacles.iter_mut().step_by(2) {
            o.set_motion(Some(crate::Motion::Segment {
                offset: [0.0, 1.0],
                speed: 0.3,
                phase: 0.0,
            }));
        }
        let picture = |memory: bool| {
            let mut cfg = SimConfig { agents: 1, ..SimConfig::default() };
            if memory {
                cfg.map =
                    crate::MapSpec { encoding: crate::MapEncoding::Rays, ..Default::default() };
                cfg.tracks = crate::tracks::TrackSpec { count: 5, ..Default::default() };
            }
            let mut env = VecEnv::new(cfg, arena.clone(), 2).unwrap();
            let mut tracks = Tracks::new(&env);
            for _ in 0..6 {
                env.step(&[0]).unwrap();
                tracks.record(&env, true);
            }
            let mut canvas = Canvas::default();
            let focus = Focus { agent: 0, depth: &[], q: None, action: None };
            draw(&env, &tracks, focus, &mut canvas);
            let count = |c: u8| canvas.px.iter().filter(|p| **p == c).count();
            (count(MAP_FREE), count(MAP_HIT), count(TRACKED), env.tracks_of(0).len())
        };
        let (free, hit, tracked, movers) = picture(true);
        assert!(free > 1000 && hit > 10, "the map drawn: {free} free, {hit} met pixels");
        assert!(movers > 0 && tracked > 10, "{movers} tracks drawn in {tracked} pixels");
        assert_eq!(picture(false), (0, 0, 0, 0), "nothing of a memory the drone has not");
    }
}
