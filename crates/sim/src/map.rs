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

mod spec;
pub use spec::{MAX_AHEAD, MAX_AHEAD_S, MAX_KEEP_S, MapEncoding, MapSpec};

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
        integrate_frame(&sight, &geo, cells, &mut self.clock[i], depth, spec, cam);
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
                integrate_frame(&sight, &geo, cells, clock, frame, spec, &cams[i]);
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
        map.geo.any_about(self.spec.cell_m, lo, hi, |k| map.cell(map.cells[k]) == Cell::Obstacle)
    }

    /// Agent `i`'s latest frame met a tracked mover within the floor-plan
    /// rectangle `[lo, hi]`: that frame's obstacle cells there (widened by
    /// half a cell, as [`Maps::shows`]) become unknown again, so that the
    /// static map never holds a mover (its tracks do). Earlier frames'
    /// hits there, and walls, stay.
    pub(crate) fn forget_hits(&mut self, i: usize, lo: [f32; 2], hi: [f32; 2]) {
        let Some(latest) = self.clock[i].checked_sub(1) else { return };
        let stamp = HIT + (latest % STAMPS) as u8;
        let (n, geo) = (self.nx * self.ny, self.geo(i));
        let cells = &mut self.cells[i * n..(i + 1) * n];
        geo.any_about(self.spec.cell_m, lo, hi, |k| {
            if cells[k] == stamp {
                cells[k] = UNKNOWN;
            }
            false
        });
    }

    /// Writes agent `i`'s map as its observation reads it (`out`:
    /// [`MapSpec::floats`]; the movers ahead, after it, are the
    /// environment's to write) for a drone at `p` heading `yaw` (rad).
    pub(crate) fn encode(&self, i: usize, p: Vector, yaw: f32, out: &mut [f32]) {
        let s = &self.spec;
        let map = self.reader(i);
        let (c, sn) = (yaw.cos(), yaw.sin());
        match s.encoding {
            MapEncoding::None => {}
            MapEncoding::Grid => read_window(&map, p, (c, sn), s, out),
            MapEncoding::Rays => cast_rays(&map, &self.dirs, p, (c, sn), s, &mut out[..2 * s.rays]),
        }
    }

    /// The `rays` encoding's directions from the heading (cos, sin).
    pub(crate) fn dirs(&self) -> &[(f32, f32)] {
        &self.dirs
    }
}

/// A ray's direction `(cos, sin)`: the heading `(c, sn)` turned by the
/// ray's angle `(ca, sa)` (counter-clockwise).
#[inline]
pub(crate) fn turned((c, sn): (f32, f32), (ca, sa): (f32, f32)) -> (f32, f32) {
    (c * ca - sn * sa, sn * ca + c * sa)
}

/// The `rays` encoding of one agent's map (`map`) for a drone at `p`
/// heading `(cos, sin)`: `out` holds the distances to the first obstacle
/// or wall, then to the first unknown cell, of each of `dirs` turned by
/// the heading. In fixed point (cells × 2^16): the x test is one unsigned
/// compare and the indices a shift; that and the AVX2 build make it 1.6x
/// faster than the f32 stepping it replaced (L1, 36 rays, 2026-12-03).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma+avx+bmi1+bmi2",
    "x86_64+avx2+fma+avx+bmi1+bmi2"
))]
fn cast_rays(
    map: &Reader,
    dirs: &[(f32, f32)],
    p: Vector,
    (c, sn): (f32, f32),
    s: &MapSpec,
    out: &mut [f32],
) {
    let (rays, range) = (s.rays, s.ray_range_m);
    // One sample a cell, in cell units: a ray may pass a cell's corner
    // unread (a distance a cell long at most).
    let g = map.geo;
    let steps = cells_in(range * g.inv);
    let (ox, oy) = ((p.x - g.x0) * g.inv, (p.y - g.lo) * g.inv);
    let (occupied, unknown) = out.split_at_mut(rays);
    let span_x = (g.nx as u32) << FIX;
    let (top, ny) = (g.top as i32, g.ny);
    let dist = |j: u32| {
        if j as usize == steps { 1.0 } else { ((j as f32 + 0.5) * s.cell_m / range).min(1.0) }
    };
    // [`BATCH`] rays side by side, every step of each (none breaks off at
    // its hit): the indices and the cells' classes are computed lane by
    // lane without a branch, which the compiler vectorises, and only the
    // loads are one by one. 2.3x faster than one ray after another, each
    // to its hit (L1, 36 rays, 2026-12-03: the breaks mispredicted).
    for (chunk, (occupied, unknown)) in
        dirs.chunks(BATCH).zip(occupied.chunks_mut(BATCH).zip(unknown.chunks_mut(BATCH)))
    {
        let (mut fx, mut fy) = ([-1i32; BATCH], [0i32; BATCH]);
        let (mut sx, mut sy) = ([0i32; BATCH], [0i32; BATCH]);
        for (l, &(ca, sa)) in chunk.iter().enumerate() {
            let (dx, dy) = turned((c, sn), (ca, sa));
            (fx[l], fy[l]) = (fixed(ox + dx * 0.5), fixed(oy + dy * 0.5 + 1.0));
            (sx[l], sy[l]) = (fixed(dx), fixed(dy));
        }
        // Lanes past the chunk's rays count as done.
        let (mut hit, mut unseen) = ([0u32; BATCH], [steps as u32; BATCH]);
        hit[..chunk.len()].fill(steps as u32);
        let (mut at, mut inside) = ([0u32; BATCH], [false; BATCH]);
        let mut v = [UNKNOWN; BATCH];
        for j in 0..steps as u32 {
            for l in 0..BATCH {
                // Outside the grid along x: index 0 and unknown. Row 0 is
                // the lower wall's ring, `top` the upper's.
                inside[l] = (fx[l] as u32) < span_x;
                let iy = (fy[l].max(0) >> FIX).min(top);
                let k = (fx[l] >> FIX) as u32 * ny as u32 + iy as u32;
                at[l] = if inside[l] { k } else { 0 };
                fx[l] = fx[l].wrapping_add(sx[l]);
                fy[l] = fy[l].wrapping_add(sy[l]);
            }
            for l in 0..BATCH {
                let cell = map.cells[at[l] as usize];
                v[l] = if inside[l] { cell } else { UNKNOWN };
            }
            let mut open = false;
            for l in 0..BATCH {
                let value = i32::from(v[l]);
                let blocked = value == i32::from(WALL) || map.sighted(v[l]);
                hit[l] = hit[l].min(if blocked { j } else { u32::MAX });
                // Unknown, expired, a wall or a sighting: no longer free.
                unseen[l] = unseen[l].min(if value != i32::from(FREE) { j } else { u32::MAX });
                open |= hit[l] == steps as u32;
            }
            if !open {
                break;
            }
        }
        for (l, (o, u)) in occupied.iter_mut().zip(unknown.iter_mut()).enumerate() {
            *o = dist(hit[l]);
            *u = dist(unseen[l]);
        }
    }
}

/// The `grid` encoding of one agent's map (`map`) for a drone at `p`
/// heading `(cos, sin)`: the window's cells, row by row from the back,
/// each 0 (unknown), 1/3 (free), 2/3 (wall) or 1 (obstacle). [`BATCH`]
/// cells at a time, their indices and values computed without a branch
/// (vectorised) and only the loads one by one: 2.1x faster than reading
/// cell by cell (L1, 16 × 16, 2026-12-03).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma+avx+bmi1+bmi2",
    "x86_64+avx2+fma+avx+bmi1+bmi2"
))]
fn read_window(map: &Reader, p: Vector, (c, sn): (f32, f32), s: &MapSpec, out: &mut [f32]) {
    let (w, g) = (s.window, map.geo);
    let mut at = [0u32; BATCH];
    let mut inside = [false; BATCH];
    for (n, chunk) in out.chunks_mut(BATCH).enumerate() {
        for l in 0..BATCH {
            let k = n * BATCH + l;
            let (r, col) = ((k / w) as f32, (k % w) as f32);
            let f = (r - w as f32 / 4.0 + 0.5) * s.cell_m;
            let side = (w as f32 / 2.0 - col - 0.5) * s.cell_m;
            let (x, y) = (p.x + c * f - sn * side, p.y + sn * f + c * side);
            // As [`Geo::index`]: rows 0 and `top` are the walls' rings.
            let fx = (x - g.x0) * g.inv;
            inside[l] = fx >= 0.0 && fx < g.nx as f32;
            let within = (((y - g.lo) * g.inv) as usize + 1).min(g.top - 1);
            let iy = if y <= g.lo {
                0
            } else if y >= g.hi {
                g.top
            } else {
                within
            };
            at[l] = if inside[l] { (fx as usize * g.ny + iy) as u32 } else { 0 };
        }
        for (l, o) in chunk.iter_mut().enumerate() {
            let value = if inside[l] { map.cells[at[l] as usize] } else { UNKNOWN };
            *o = if map.sighted(value) {
                1.0
            } else if value < HIT {
                f32::from(value) / 3.0
            } else {
                0.0
            };
        }
    }
}

/// Rays of the `rays` encoding cast side by side.
const BATCH: usize = 16;

/// `ceil(x)` for `x >= 0`, without libm's call on the baseline target.
#[inline(always)]
fn cells_in(x: f32) -> usize {
    let n = x as usize;
    n + usize::from((n as f32) < x)
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

    /// Visits the cells within the floor-plan rectangle `[lo, hi]`,
    /// widened by half a `cell` (a face's hits may land in the cell before
    /// it), one sample a cell, until `f` returns true; whether it did.
    fn any_about(
        &self,
        cell: f32,
        lo: [f32; 2],
        hi: [f32; 2],
        mut f: impl FnMut(usize) -> bool,
    ) -> bool {
        let h = cell / 2.0;
        // Off the grid's length or a cell past its lane's walls: no cell here.
        let x_end = self.x0 + self.nx as f32 * cell;
        if hi[0] + h < self.x0
            || lo[0] - h >= x_end
            || hi[1] + h < self.lo - cell
            || lo[1] - h > self.hi + cell
        {
            return false;
        }
        let mut x = lo[0] - h;
        while x <= hi[0] + h {
            let mut y = lo[1] - h;
            while y <= hi[1] + h {
                if let Some(k) = self.index(x, y)
                    && f(k)
                {
                    return true;
                }
                y += cell;
            }
            x += cell;
        }
        false
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
                if self.sighted(v) {
                    Cell::Obstacle
                } else {
                    Cell::Unknown
                }
            }
        }
    }

    /// Whether `value` is a sighting of an obstacle not yet expired (a
    /// sighting's age in frames: stamps wrap at [`STAMPS`]). Without a
    /// branch, so that the batched readers vectorise it.
    #[inline(always)]
    fn sighted(&self, value: u8) -> bool {
        let age = self.now as i32 - (i32::from(value) - i32::from(HIT));
        let age = if age < 0 { age + STAMPS as i32 } else { age };
        value >= HIT && (self.keep == 0 || age < self.keep as i32)
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

/// One frame (`depth`, seen from `cam`) into one agent's cells, compiled for
/// AVX2 and AVX-512 beside the baseline (picked at run time).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma+avx+bmi1+bmi2",
    "x86_64+avx2+fma+avx+bmi1+bmi2"
))]
#[allow(clippy::too_many_arguments)]
fn integrate_frame(
    sight: &Sight,
    geo: &Geo,
    cells: &mut [u8],
    clock: &mut u32,
    depth: &[f32],
    spec: &CameraSpec,
    cam: &CameraPose,
) {
    let (cols, height, band) = (spec.width, spec.height, sight.band);
    let (rows, first) =
        if band == 0 || band >= height { (height, 0) } else { (band, (height - band) / 2) };
    let columns = Columns {
        first,
        rows,
        cols,
        half: [cols as f32 / 2.0, height as f32 / 2.0],
        tan: [spec.tan_h(), spec.tan_v()],
        axes: [cam.rotation * Vector::X, cam.rotation * Vector::Y, cam.rotation * Vector::Z],
        o: cam.position,
        range: spec.range,
    };
    let o = cam.position;
    let stamp = HIT + (*clock % STAMPS) as u8;
    let nearest = |u: usize| columns.end(depth, u);
    // At most 64 columns' ends kept on the stack; wider frames
    // compute the rest again.
    let mut ends = [None; 64];
    for u in 0..cols {
        let end = nearest(u);
        if let Some((end, met)) = end {
            cross(geo, cells, sight.keep, o, end, met, sight.reach);
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
        if end.z <= FACE || end.z >= sight.height - FACE {
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

/// A frame's columns: where each one's ray ends.
struct Columns {
    /// The band's first row and rows, and the frame's columns.
    first: usize,
    rows: usize,
    cols: usize,
    /// Half the frame's width and height (pixels), and the tangents of
    /// half its fields of view.
    half: [f32; 2],
    tan: [f32; 2],
    /// The camera's forward, left and up, and where it is.
    axes: [Vector; 3],
    o: Vector,
    range: f32,
}

impl Columns {
    /// Column `u`'s nearest return within the band (a dropped-out pixel
    /// reads 0: no return): where its ray ends, and whether it met
    /// something there (inside the range).
    #[inline(always)]
    fn end(&self, depth: &[f32], u: usize) -> Option<(Vector, bool)> {
        let mut best: Option<(f32, usize)> = None;
        for v in self.first..self.first + self.rows {
            let d = depth[v * self.cols + u];
            if d > 0.0 && best.is_none_or(|(b, _)| d < b) {
                best = Some((d, v));
            }
        }
        let (d, v) = best?;
        let ([half_u, half_v], [tan_u, tan_v]) = (self.half, self.tan);
        let su = (u as f32 + 0.5 - half_u) / half_u * tan_u;
        let sv = (half_v - v as f32 - 0.5) / half_v * tan_v;
        let [fwd, left, up] = self.axes;
        let dir = fwd - left * su + up * sv;
        Some((self.o + dir * (d.min(1.0) * self.range), d < 1.0))
    }
}

/// Marks free the cells a ray from `o` to `end` crossed (up to [`SHY`]
/// before its end when it met something, and no farther than `reach`),
/// one sample a cell: a cell whose corner the ray clips may stay unknown,
/// and no cell it missed is marked.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn cross(geo: &Geo, cells: &mut [u8], keep: u32, o: Vector, end: Vector, met: bool, reach: f32) {
    let (dx, dy) = (end.x - o.x, end.y - o.y);
    let len = (dx * dx + dy * dy).sqrt();
    let upto = if met { len - SHY } else { len }.min(reach);
    if upto <= 0.0 {
        return;
    }
    // In fixed point cell units (× 2^16): x from the grid's first column,
    // y from the lane's lower face (row 1 is the first inside it). Inside
    // the grid and the lane is one unsigned compare each; a crossed cell
    // is marked without a branch (1.5x faster than the f32 stepping it
    // replaced, L1, 2026-12-03).
    let n = cells_in(upto * geo.inv);
    let (sx, sy) = (fixed(dx / len), fixed(dy / len));
    let (mut fx, mut fy) = (fixed((o.x - geo.x0) * geo.inv), fixed((o.y - geo.lo) * geo.inv));
    let span_x = (geo.nx as u32) << FIX;
    // 0 < fy < width: fy - 1 below width - 1, unsigned.
    let span_y = (fixed((geo.hi - geo.lo) * geo.inv) as u32).wrapping_sub(1);
    let (last, ny) = (geo.top as i32 - 1, geo.ny);
    for _ in 0..n {
        if (fy as u32).wrapping_sub(1) < span_y && (fx as u32) < span_x {
            let k = (fx >> FIX) as usize * ny + ((fy >> FIX) + 1).min(last) as usize;
            let c = &mut cells[k];
            // Unknown becomes free; with `keep`, an obstacle's sighting
            // is cleared too (a mover that left); a wall stays.
            *c = if keep > 0 { if *c == WALL { WALL } else { FREE } } else { (*c).max(FREE) };
        }
        fx = fx.wrapping_add(sx);
        fy = fy.wrapping_add(sy);
    }
}

/// Fractional bits of the maps' fixed-point cell coordinates.
const FIX: u32 = 16;

/// `x` cells in fixed point (saturating: far outside any grid).
#[inline(always)]
fn fixed(x: f32) -> i32 {
    (x * (1 << FIX) as f32) as i32
}

#[cfg(test)]
mod tests;
