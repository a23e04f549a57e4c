//! The camera's map (`[sim.map]`): per agent, a top-down grid of what its
//! own depth frames have shown it this episode, built from those frames as
//! it observes them (noise, dropout and latency included) and its own
//! pose, cleared when an episode starts. The student reads it as an
//! egocentric image turned to its heading (`grid`) or as distances cast
//! through it over 360 degrees (`rays`, NavRL's form), after its velocity
//! (and goal) in the observation's scalars.
//!
//! A cell is one byte: unknown, free (a ray crossed it), wall (a ray ended
//! on the lane's wall) or obstacle (a ray ended in it, stamped with the
//! frame it was seen in, so that `keep_s` can let a sighting expire). The
//! map never holds what no ray met: a cell is written only by a ray of the
//! agent's own frames. Rays that end on the floor or the ceiling mark the
//! cells they crossed free and nothing else.

use std::f32::consts::TAU;

use rapier3d::math::Vector;

use crate::render::{CameraPose, CameraSpec};

/// How the map enters the observation (`sim.map.encoding`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MapEncoding {
    /// No map: the observation is depth, velocity (and goal) as ever.
    #[default]
    None,
    /// An egocentric window of `window × window` cells turned to the
    /// heading, the drone a quarter of the way from its back edge; each
    /// cell 0 (unknown), 1/3 (free), 2/3 (wall) or 1 (obstacle).
    Grid,
    /// `rays` distances cast through the map over 360 degrees from the
    /// heading, counter-clockwise, to the first obstacle or wall, then as
    /// many to the first unknown cell; each divided by `ray_range_m` (1:
    /// nothing within it).
    Rays,
}

impl MapEncoding {
    /// Its name in configs (`sim.map.encoding`).
    pub fn name(self) -> &'static str {
        match self {
            MapEncoding::None => "none",
            MapEncoding::Grid => "grid",
            MapEncoding::Rays => "rays",
        }
    }
}

/// The map's settings (`[sim.map]`; off by default).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapSpec {
    /// How the student reads the map (`none`: no map).
    pub encoding: MapEncoding,
    /// Side of one cell (m).
    pub cell_m: f32,
    /// Cells a side of the `grid` encoding's window.
    pub window: usize,
    /// Directions of the `rays` encoding.
    pub rays: usize,
    /// How far the `rays` encoding looks (m).
    pub ray_range_m: f32,
    /// How long a sighting of an obstacle is kept (s; 0: the whole
    /// episode). With it, a ray that crosses a cell clears an earlier
    /// sighting there (an obstacle that moved away); without it sightings
    /// stay (a still obstacle never leaves).
    pub keep_s: f32,
    /// Rows of each frame read, about its middle (0: every row): the band
    /// at the flight's altitude.
    pub band: usize,
}

impl Default for MapSpec {
    fn default() -> Self {
        Self {
            encoding: MapEncoding::None,
            cell_m: 0.5,
            window: 16,
            rays: 36,
            ray_range_m: 10.0,
            keep_s: 0.0,
            band: 4,
        }
    }
}

impl MapSpec {
    /// Whether the settings are the defaults (no map): a config writes no
    /// `[sim.map]` then.
    pub fn is_off(&self) -> bool {
        *self == Self::default()
    }

    /// Whether the observation holds the map.
    pub fn enabled(&self) -> bool {
        self.encoding != MapEncoding::None
    }

    /// Floats the map adds to an observation.
    pub fn floats(&self) -> usize {
        match self.encoding {
            MapEncoding::None => 0,
            MapEncoding::Grid => self.window * self.window,
            MapEncoding::Rays => 2 * self.rays,
        }
    }

    /// How far from the camera a frame's crossed cells are marked free (m):
    /// as far as the encoding reads (the rays' range, the window's far
    /// corner). Farther cells are marked when the drone comes nearer; hits
    /// are marked at any distance.
    pub fn reach(&self) -> f32 {
        match self.encoding {
            MapEncoding::Rays => self.ray_range_m,
            _ => self.window as f32 * self.cell_m * 0.9,
        }
    }

    /// Checks the ranges; the key (under `[sim.map]`) and what is wrong.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        for (key, v, lo, hi) in [
            ("cell_m", self.cell_m, 0.05, 5.0),
            ("ray_range_m", self.ray_range_m, 0.5, 100.0),
            ("keep_s", self.keep_s, 0.0, MAX_KEEP_S),
        ] {
            if !(lo..=hi).contains(&v) {
                return Err((key, format!("must lie in [{lo}, {hi}], got {v}")));
            }
        }
        if !(2..=32).contains(&self.window) {
            return Err(("window", format!("must be 2 to 32 cells, got {}", self.window)));
        }
        if !(4..=360).contains(&self.rays) {
            return Err(("rays", format!("must be 4 to 360 directions, got {}", self.rays)));
        }
        if self.band > 1024 {
            return Err(("band", format!("must be 0 (every row) to 1024 rows, got {}", self.band)));
        }
        if self.floats() > rotorhive_msg::MAX_MAP_FLOATS {
            return Err((
                "encoding",
                format!(
                    "gives {} floats, more than {}",
                    self.floats(),
                    rotorhive_msg::MAX_MAP_FLOATS
                ),
            ));
        }
        Ok(())
    }
}

/// The longest a sighting may be kept (s): stamps count frames modulo
/// [`STAMPS`], and an age must stay under it.
pub const MAX_KEEP_S: f32 = 240.0;

const UNKNOWN: u8 = 0;
const FREE: u8 = 1;
const WALL: u8 = 2;
/// An obstacle cell holds `HIT + frame % STAMPS`.
const HIT: u8 = 3;
const STAMPS: u32 = 253;
/// A ray that ends this close (m) to the lane's wall face, the floor or
/// the ceiling ended on it.
const FACE: f32 = 0.05;
/// Metres before a ray's end up to which the cells it crossed are free:
/// a ray that grazes the corner of an obstacle's cell does not clear it.
const SHY: f32 = 0.5;

/// What a cell of an agent's map holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cell {
    /// No ray met it this episode (or its sighting expired).
    Unknown,
    /// A ray crossed it.
    Free,
    /// A ray ended on the lane's wall there.
    Wall,
    /// A ray ended on an obstacle there.
    Obstacle,
}

/// Every agent's map.
#[derive(Debug, Clone)]
pub(crate) struct Maps {
    spec: MapSpec,
    /// Frames a sighting is kept (0: the episode).
    keep: u32,
    /// x of the grid's first column (m) and columns along x.
    x0: f32,
    nx: usize,
    /// Rows along y: the widest lane's, plus a ring of wall cells each side.
    ny: usize,
    /// The arena's height (m): where the ceiling is.
    height: f32,
    /// `agents × nx × ny` cells, agent by agent, x-major.
    cells: Vec<u8>,
    /// Each agent's lane: free space between its walls' faces along y.
    lane: Vec<[f32; 2]>,
    /// Frames each agent's map has taken this episode.
    clock: Vec<u32>,
    /// The `rays` encoding's directions from the heading (cos, sin).
    dirs: Vec<(f32, f32)>,
}

impl Maps {
    /// Maps for `agents` in a world `length` long and `height` high, whose
    /// lanes are as wide as `widest` at most; every cell unknown.
    pub(crate) fn new(
        spec: &MapSpec,
        agents: usize,
        length: f32,
        height: f32,
        widest: f32,
        action_period: f32,
    ) -> Self {
        let cell = spec.cell_m;
        let x0 = -2.0;
        let nx = ((length + 2.0 - x0) / cell).ceil() as usize;
        let ny = (widest / cell).ceil() as usize + 3;
        let keep = if spec.keep_s > 0.0 {
            ((spec.keep_s / action_period).round() as u32).clamp(1, STAMPS - 2)
        } else {
            0
        };
        Self {
            spec: spec.clone(),
            keep,
            x0,
            nx,
            ny,
            height,
            cells: vec![UNKNOWN; agents * nx * ny],
            lane: vec![[-widest / 2.0, widest / 2.0]; agents],
            clock: vec![0; agents],
            dirs: (0..spec.rays)
                .map(|k| {
                    let a = TAU * k as f32 / spec.rays as f32;
                    (a.cos(), a.sin())
                })
                .collect(),
        }
    }

    /// Bytes of one agent's map.
    pub(crate) fn bytes_per_agent(&self) -> usize {
        self.nx * self.ny
    }

    /// Agent `i`'s placement of its grid.
    fn geo(&self, i: usize) -> Geo {
        Geo::new(self.x0, self.nx, self.ny, self.spec.cell_m, self.lane[i])
    }

    /// Agent `i` starts an episode in the lane whose free space is `lane`
    /// along y: its map forgets everything.
    pub(crate) fn clear(&mut self, i: usize, lane: [f32; 2]) {
        let n = self.nx * self.ny;
        self.cells[i * n..(i + 1) * n].fill(UNKNOWN);
        self.lane[i] = lane;
        self.clock[i] = 0;
    }

    /// What one frame's integration needs besides the agent's cells.
    fn sight(&self) -> Sight {
        Sight {
            keep: self.keep,
            height: self.height,
            band: self.spec.band,
            reach: self.spec.reach(),
        }
    }

    /// Agent `i`'s map takes its frame `depth` (normalised, `spec`'s pixels,
    /// as the agent observes it) seen from `cam`.
    pub(crate) fn integrate(
        &mut self,
        i: usize,
        depth: &[f32],
        spec: &CameraSpec,
        cam: &CameraPose,
    ) {
        let n = self.nx * self.ny;
        let (geo, sight) = (self.geo(i), self.sight());
        let cells = &mut self.cells[i * n..(i + 1) * n];
        sight.integrate(&geo, cells, &mut self.clock[i], depth, spec, cam);
    }

    /// Every agent's map takes its frame (`frames`: `agents` of `spec`'s),
    /// seen from `cams[i]`, on `pool`'s threads.
    pub(crate) fn integrate_all(
        &mut self,
        pool: &crate::pool::Pool,
        frames: &[f32],
        spec: &CameraSpec,
        cams: &[CameraPose],
    ) {
        const CHUNK: usize = 16;
        let n = self.nx * self.ny;
        let px = spec.pixels();
        let sight = self.sight();
        let (x0, nx, ny, cell, lanes) = (self.x0, self.nx, self.ny, self.spec.cell_m, &self.lane);
        let work = |(k, (cells, clock)): (usize, (&mut [u8], &mut [u32]))| {
            let first = k * CHUNK;
            for (j, (cells, clock)) in cells.chunks_exact_mut(n).zip(clock).enumerate() {
                let i = first + j;
                let geo = Geo::new(x0, nx, ny, cell, lanes[i]);
                let frame = &frames[i * px..(i + 1) * px];
                sight.integrate(&geo, cells, clock, frame, spec, &cams[i]);
            }
        };
        let pieces = self.cells.chunks_mut(CHUNK * n).zip(self.clock.chunks_mut(CHUNK)).enumerate();
        if pool.threads() == 1 {
            pieces.for_each(work);
        } else {
            pool.share(pieces, work);
        }
    }

    /// Agent `i`'s cells and how to read them.
    fn reader(&self, i: usize) -> Reader<'_> {
        let n = self.nx * self.ny;
        Reader {
            geo: self.geo(i),
            cells: &self.cells[i * n..(i + 1) * n],
            keep: self.keep,
            now: self.clock[i].wrapping_sub(1) % STAMPS,
        }
    }

    /// What agent `i`'s map holds at `(x, y)`.
    pub fn at(&self, i: usize, x: f32, y: f32) -> Cell {
        self.reader(i).at(x, y)
    }

    /// Whether agent `i`'s map holds an obstacle cell within the floor-plan
    /// rectangle `[lo, hi]` (widened by half a cell: a face's hits may land
    /// in the cell before it).
    pub(crate) fn shows(&self, i: usize, lo: [f32; 2], hi: [f32; 2]) -> bool {
        let map = self.reader(i);
        let h = self.spec.cell_m / 2.0;
        let step = self.spec.cell_m;
        let mut x = lo[0] - h;
        while x <= hi[0] + h {
            let mut y = lo[1] - h;
            while y <= hi[1] + h {
                if map.at(x, y) == Cell::Obstacle {
                    return true;
                }
                y += step;
            }
            x += step;
        }
        false
    }

    /// Writes agent `i`'s map as its observation reads it (`out`:
    /// [`MapSpec::floats`]) for a drone at `p` heading `yaw` (rad).
    pub(crate) fn encode(&self, i: usize, p: Vector, yaw: f32, out: &mut [f32]) {
        let s = &self.spec;
        let map = self.reader(i);
        let (c, sn) = (yaw.cos(), yaw.sin());
        match s.encoding {
            MapEncoding::None => {}
            MapEncoding::Grid => {
                let w = s.window;
                for (k, o) in out.iter_mut().enumerate() {
                    let (r, col) = (k / w, k % w);
                    let f = (r as f32 - w as f32 / 4.0 + 0.5) * s.cell_m;
                    let l = (w as f32 / 2.0 - col as f32 - 0.5) * s.cell_m;
                    let (x, y) = (p.x + c * f - sn * l, p.y + sn * f + c * l);
                    *o = match map.at(x, y) {
                        Cell::Unknown => 0.0,
                        Cell::Free => 1.0 / 3.0,
                        Cell::Wall => 2.0 / 3.0,
                        Cell::Obstacle => 1.0,
                    };
                }
            }
            MapEncoding::Rays => {
                let (rays, range) = (s.rays, s.ray_range_m);
                // One sample a cell, in cell units: a ray may pass a
                // cell's corner unread (a distance a cell long at most).
                let g = map.geo;
                let steps = (range * g.inv).ceil() as usize;
                let nx = g.nx as f32;
                let (ox, oy) = ((p.x - g.x0) * g.inv, (p.y - g.lo) * g.inv);
                let (occupied, unknown) = out.split_at_mut(rays);
                for (k, &(ca, sa)) in self.dirs.iter().enumerate() {
                    // The ray's direction: the heading turned by its angle.
                    let (dx, dy) = (c * ca - sn * sa, sn * ca + c * sa);
                    let (mut fx, mut fy) = (ox + dx * 0.5, oy + dy * 0.5);
                    let (mut hit, mut unseen) = (steps, steps);
                    for j in 0..steps {
                        let cell = if fx >= 0.0 && fx < nx {
                            // Row 0 is the lower wall's ring, `top` the upper's.
                            let iy = ((fy + 1.0).max(0.0) as usize).min(g.top);
                            map.cell(map.cells[fx as usize * g.ny + iy])
                        } else {
                            Cell::Unknown
                        };
                        match cell {
                            Cell::Free => {}
                            Cell::Unknown => unseen = unseen.min(j),
                            Cell::Wall | Cell::Obstacle => {
                                hit = j;
                                unseen = unseen.min(j);
                                break;
                            }
                        }
                        fx += dx;
                        fy += dy;
                    }
                    let dist = |j: usize| {
                        if j == steps {
                            1.0
                        } else {
                            ((j as f32 + 0.5) * s.cell_m / range).min(1.0)
                        }
                    };
                    occupied[k] = dist(hit);
                    unknown[k] = dist(unseen);
                }
            }
        }
    }
}

/// One agent's grid: where it lies and its lane. Row 0 and row `top` are
/// the ring of its lane's walls.
#[derive(Clone, Copy)]
struct Geo {
    x0: f32,
    inv: f32,
    nx: usize,
    lo: f32,
    hi: f32,
    ny: usize,
    top: usize,
}

impl Geo {
    fn new(x0: f32, nx: usize, ny: usize, cell: f32, [lo, hi]: [f32; 2]) -> Self {
        let top = (((hi - lo) / cell).ceil() as usize + 1).min(ny - 1);
        Self { x0, inv: 1.0 / cell, nx, lo, hi, ny, top }
    }

    /// The cell at `(x, y)`, if the grid has one there.
    #[inline(always)]
    fn index(&self, x: f32, y: f32) -> Option<usize> {
        let fx = (x - self.x0) * self.inv;
        if !(fx >= 0.0 && fx < self.nx as f32) {
            return None;
        }
        let iy = if y <= self.lo {
            0
        } else if y >= self.hi {
            self.top
        } else {
            (((y - self.lo) * self.inv) as usize + 1).min(self.top - 1)
        };
        Some(fx as usize * self.ny + iy)
    }
}

/// Reads one agent's cells.
struct Reader<'a> {
    geo: Geo,
    cells: &'a [u8],
    keep: u32,
    /// The stamp of the latest frame the map took.
    now: u32,
}

impl Reader<'_> {
    #[inline(always)]
    fn at(&self, x: f32, y: f32) -> Cell {
        let Some(k) = self.geo.index(x, y) else { return Cell::Unknown };
        self.cell(self.cells[k])
    }

    #[inline(always)]
    fn cell(&self, value: u8) -> Cell {
        match value {
            UNKNOWN => Cell::Unknown,
            FREE => Cell::Free,
            WALL => Cell::Wall,
            v => {
                let age = (self.now + STAMPS - u32::from(v - HIT)) % STAMPS;
                if self.keep > 0 && age >= self.keep { Cell::Unknown } else { Cell::Obstacle }
            }
        }
    }
}

/// What a frame's integration needs besides the agent's cells.
#[derive(Clone, Copy)]
struct Sight {
    keep: u32,
    height: f32,
    band: usize,
    /// How far from the camera crossed cells are marked free (m).
    reach: f32,
}

impl Sight {
    fn integrate(
        &self,
        geo: &Geo,
        cells: &mut [u8],
        clock: &mut u32,
        depth: &[f32],
        spec: &CameraSpec,
        cam: &CameraPose,
    ) {
        let (cols, height, band) = (spec.width, spec.height, self.band);
        let (rows, first) =
            if band == 0 || band >= height { (height, 0) } else { (band, (height - band) / 2) };
        let (tan_u, tan_v) = (spec.tan_h(), spec.tan_v());
        let (half_u, half_v) = (cols as f32 / 2.0, height as f32 / 2.0);
        let (fwd, left, up) =
            (cam.rotation * Vector::X, cam.rotation * Vector::Y, cam.rotation * Vector::Z);
        let o = cam.position;
        let stamp = HIT + (*clock % STAMPS) as u8;
        // The column's nearest return within the band (a dropped-out pixel
        // reads 0: no return), and where its ray ends.
        let nearest = |u: usize| -> Option<(Vector, bool)> {
            let mut best: Option<(f32, usize)> = None;
            for v in first..first + rows {
                let d = depth[v * cols + u];
                if d > 0.0 && best.is_none_or(|(b, _)| d < b) {
                    best = Some((d, v));
                }
            }
            let (d, v) = best?;
            let su = (u as f32 + 0.5 - half_u) / half_u * tan_u;
            let sv = (half_v - v as f32 - 0.5) / half_v * tan_v;
            let dir = fwd - left * su + up * sv;
            Some((o + dir * (d.min(1.0) * spec.range), d < 1.0))
        };
        // At most 64 columns' ends kept on the stack; wider frames
        // compute the rest again.
        let mut ends = [None; 64];
        for u in 0..cols {
            let end = nearest(u);
            if let Some((end, met)) = end {
                cross(geo, cells, self.keep, o, end, met, self.reach);
            }
            if u < ends.len() {
                ends[u] = end;
            }
        }
        // Hits after every crossing of the frame: a ray of this frame never
        // clears what another of this frame met.
        for u in 0..cols {
            let end = if u < ends.len() { ends[u] } else { nearest(u) };
            let Some((end, true)) = end else { continue };
            if end.z <= FACE || end.z >= self.height - FACE {
                continue;
            }
            let (y, value) = if end.y <= geo.lo + FACE {
                (geo.lo - 1.0, WALL)
            } else if end.y >= geo.hi - FACE {
                (geo.hi + 1.0, WALL)
            } else {
                (end.y, stamp)
            };
            if let Some(k) = geo.index(end.x, y) {
                cells[k] = value;
            }
        }
        *clock += 1;
    }
}

/// Marks free the cells a ray from `o` to `end` crossed (up to [`SHY`]
/// before its end when it met something, and no farther than `reach`),
/// one sample a cell: a cell whose corner the ray clips may stay unknown,
/// and no cell it missed is marked.
#[allow(clippy::too_many_arguments)]
fn cross(geo: &Geo, cells: &mut [u8], keep: u32, o: Vector, end: Vector, met: bool, reach: f32) {
    let (dx, dy) = (end.x - o.x, end.y - o.y);
    let len = (dx * dx + dy * dy).sqrt();
    let upto = if met { len - SHY } else { len }.min(reach);
    if upto <= 0.0 {
        return;
    }
    // In cell units: x from the grid's first column, y from the lane's
    // lower face (row 1 is the first inside it).
    let n = (upto * geo.inv).ceil() as usize;
    let (sx, sy) = (dx / len, dy / len);
    let (mut fx, mut fy) = ((o.x - geo.x0) * geo.inv, (o.y - geo.lo) * geo.inv);
    let (nx, width) = (geo.nx as f32, (geo.hi - geo.lo) * geo.inv);
    let last = geo.top - 1;
    for _ in 0..n {
        if fy > 0.0 && fy < width && fx >= 0.0 && fx < nx {
            let k = fx as usize * geo.ny + (fy as usize + 1).min(last);
            let c = &mut cells[k];
            if *c == UNKNOWN || (keep > 0 && *c >= HIT) {
                *c = FREE;
            }
        }
        fx += sx;
        fy += sy;
    }
}
