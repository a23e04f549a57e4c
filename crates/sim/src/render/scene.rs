//! What the renderers draw: [`Scene`], an arena's obstacles as exact shapes
//! under a 2-D grid of its floor plan (moving ones where the clock puts
//! them, lanes side by side), what a camera's rays meet first
//! ([`Scene::visible`]), and the ray tests of each shape.

use rapier3d::math::Vector;

use super::camera::{CameraPose, CameraSpec, View, floor_plan_of};
use crate::arena::{Arena, Motion, Obstacle};

#[derive(Debug, Clone, Copy)]
pub(crate) enum Shape {
    Box { min: Vector, max: Vector },
    Cylinder { cx: f32, cy: f32, r2: f32, zmin: f32, zmax: f32 },
}

impl Shape {
    /// The exact shape of `o` where it stands (its motion ignored).
    pub(crate) fn of(o: &Obstacle) -> Self {
        match *o {
            Obstacle::Box { center, half_extents, .. } => {
                let c = Vector::from(center);
                let h = Vector::from(half_extents);
                Shape::Box { min: c - h, max: c + h }
            }
            Obstacle::Cylinder { center, radius, half_height, .. } => Shape::Cylinder {
                cx: center[0],
                cy: center[1],
                r2: radius * radius,
                zmin: center[2] - half_height,
                zmax: center[2] + half_height,
            },
        }
    }

    /// The same shape moved by `(dx, dy)`.
    pub(crate) fn moved(&self, [dx, dy]: [f32; 2]) -> Self {
        match *self {
            Shape::Box { min, max } => {
                let d = Vector::new(dx, dy, 0.0);
                Shape::Box { min: min + d, max: max + d }
            }
            Shape::Cylinder { cx, cy, r2, zmin, zmax } => {
                Shape::Cylinder { cx: cx + dx, cy: cy + dy, r2, zmin, zmax }
            }
        }
    }

    /// Axis-aligned bounds.
    pub(crate) fn aabb(&self) -> (Vector, Vector) {
        match *self {
            Shape::Box { min, max } => (min, max),
            Shape::Cylinder { cx, cy, r2, zmin, zmax } => {
                let r = r2.sqrt();
                (Vector::new(cx - r, cy - r, zmin), Vector::new(cx + r, cy + r, zmax))
            }
        }
    }
}

/// The scene: obstacles in a grid, and the corridor's bounding planes. A
/// moving obstacle sits in every cell it passes through, and its shape is
/// where [`Scene::set_time`] last put it.
#[derive(Debug, Clone)]
pub struct Scene {
    pub(crate) shapes: Vec<Shape>,
    /// The moving obstacles: index in `shapes`, shape at its centre, motion.
    pub(crate) movers: Vec<(u32, Shape, Motion)>,
    nx: usize,
    ny: usize,
    x0: f32,
    y0: f32,
    cells: Vec<Vec<u32>>,
    pub(crate) half_width: f32,
    pub(crate) height: f32,
    /// Where the arena starts and ends along x.
    pub(crate) x_extent: (f32, f32),
    /// Lanes' free space along y, between their walls' inner faces (empty:
    /// one arena): a camera in a lane draws its walls as planes and
    /// gathers only its own lane's obstacles, since the walls hide the
    /// rest. With 16 lanes this cut the CPU render time of 50 agents from
    /// 2.86 to 0.5 ms per step (each wall box had filled whole images).
    lanes: Vec<[f32; 2]>,
}

const CELL: f32 = 2.0;

impl Scene {
    /// Builds the scene and its grid index from an arena.
    pub fn new(arena: &Arena) -> Self {
        let mut shapes: Vec<Shape> = arena.obstacles.iter().map(Shape::of).collect();
        let hw = arena.width / 2.0;
        let x0 = -CELL;
        let y0 = -hw - CELL;
        let nx = ((arena.length + 2.0 * CELL) / CELL).ceil() as usize + 1;
        let ny = ((arena.width + 2.0 * CELL) / CELL).ceil() as usize + 1;
        let mut cells = vec![Vec::new(); nx * ny];
        for (i, o) in arena.obstacles.iter().enumerate() {
            let (lo, hi) = o.swept_aabb();
            let (ax, ay) = cell_of(x0, y0, lo[0], lo[1], nx, ny);
            let (bx, by) = cell_of(x0, y0, hi[0], hi[1], nx, ny);
            for gx in ax..=bx {
                for gy in ay..=by {
                    cells[gy * nx + gx].push(i as u32);
                }
            }
        }
        let movers: Vec<(u32, Shape, Motion)> = arena
            .obstacles
            .iter()
            .enumerate()
            .filter_map(|(i, o)| Some((i as u32, shapes[i], *o.motion()?)))
            .collect();
        for &(i, base, m) in &movers {
            shapes[i as usize] = base.moved(m.offset(0.0));
        }
        Self {
            shapes,
            movers,
            nx,
            ny,
            x0,
            y0,
            cells,
            half_width: hw,
            height: arena.height,
            x_extent: (0.0, arena.length),
            lanes: Vec::new(),
        }
    }

    /// Puts every moving obstacle where it is at time `t` (seconds of the
    /// world's clock).
    pub fn set_time(&mut self, t: f64) {
        for &(i, base, m) in &self.movers {
            self.shapes[i as usize] = base.moved(m.offset(t));
        }
    }

    /// The scene of `arena`, its lanes along y at `bounds` (see
    /// [`Scene::set_lanes`]).
    pub fn of_lanes(arena: &Arena, bounds: &[[f32; 2]]) -> Self {
        let mut scene = Self::new(arena);
        scene.set_lanes(bounds);
        scene
    }

    /// Tells the scene where its lanes lie along y (see
    /// [`Lanes::bounds`](crate::Lanes::bounds)), so that a camera inside a
    /// lane looks only at that lane's obstacles.
    pub fn set_lanes(&mut self, bounds: &[[f32; 2]]) {
        self.lanes = if bounds.len() > 1 { bounds.to_vec() } else { Vec::new() };
    }

    /// The lane extent holding `y`, if the scene has lanes.
    fn lane_of(&self, y: f32) -> Option<[f32; 2]> {
        self.lanes.iter().copied().find(|b| (b[0]..=b[1]).contains(&y))
    }

    /// Gathers, without duplicates, the obstacles in cells overlapping the
    /// floor-plan rectangle `[lo, hi]`.
    fn gather(&self, lo: [f32; 2], hi: [f32; 2], stamp: &mut [u32], tick: u32, out: &mut Vec<u32>) {
        let (ax, ay) = cell_of(self.x0, self.y0, lo[0], lo[1], self.nx, self.ny);
        let (bx, by) = cell_of(self.x0, self.y0, hi[0], hi[1], self.nx, self.ny);
        for gy in ay..=by {
            for gx in ax..=bx {
                for &i in &self.cells[gy * self.nx + gx] {
                    if stamp[i as usize] != tick {
                        stamp[i as usize] = tick;
                        out.push(i);
                    }
                }
            }
        }
    }

    /// Gathers into `out` the obstacles a camera's `view` can reach (in
    /// cells of the floor plan its range covers, between its side walls);
    /// the side walls bounding it: its lane's, or the arena's.
    pub(super) fn reach(
        &self,
        view: &View,
        stamp: &mut [u32],
        tick: u32,
        out: &mut Vec<u32>,
    ) -> [f32; 2] {
        let basis = [view.o, view.fwd, view.left, view.up];
        let (mut lo, mut hi) = floor_plan_of(basis, [view.tan_u, view.tan_v], view.range);
        let walls = self.lane_of(view.o.y).unwrap_or([-self.half_width, self.half_width]);
        lo[1] = lo[1].max(walls[0]);
        hi[1] = hi[1].min(walls[1]);
        self.gather(lo, hi, stamp, tick, out);
        walls
    }

    /// Number of obstacles.
    pub fn len(&self) -> usize {
        self.shapes.len()
    }

    /// True when the scene has no obstacles.
    pub fn is_empty(&self) -> bool {
        self.shapes.is_empty()
    }

    /// The obstacles (their indices, ascending) that at least one of the
    /// camera's rays meets first, nearer than the depth range and before the
    /// walls, floor and ceiling: what a depth image of `spec` from `cam`
    /// shows, occlusion as the renderer has it (the obstacles where the
    /// scene has them now; other drones are not obstacles).
    pub fn visible(&self, spec: &CameraSpec, cam: &CameraPose) -> Vec<usize> {
        self.visible_where(spec, cam, 0, |_| true)
    }

    /// As [`Scene::visible`], of the obstacles `wanted` names only (the
    /// others still hide what lies behind them), through the middle `band`
    /// rows of the image (0: every row). Casts no ray where no wanted
    /// obstacle lies within the camera's reach: the tracker's query
    /// (`crate::tracks`), which wants the moving ones.
    pub fn visible_where(
        &self,
        spec: &CameraSpec,
        cam: &CameraPose,
        band: usize,
        wanted: impl Fn(usize) -> bool,
    ) -> Vec<usize> {
        let view = View::new(spec, cam);
        let mut candidates = Vec::new();
        let walls = self.reach(&view, &mut vec![0; self.len()], 1, &mut candidates);
        candidates.retain(|&i| {
            let (min, max) = self.shapes[i as usize].aabb();
            !beyond(walls, min, max)
        });
        if !candidates.iter().any(|&i| wanted(i as usize)) {
            return Vec::new();
        }
        let rows = if band == 0 || band >= view.nv {
            0..view.nv
        } else {
            let first = (view.nv - band) / 2;
            first..first + band
        };
        let mut hit = vec![false; candidates.len()];
        for v in rows {
            for u in 0..view.nu {
                let d = view.dir(u, v);
                let mut nearest = view.range.min(planes(walls, self.height, view.o, d));
                let mut who = None;
                for (k, &i) in candidates.iter().enumerate() {
                    let t = hit_shape(&self.shapes[i as usize], view.o, d, nearest);
                    if t < nearest {
                        (nearest, who) = (t, Some(k));
                    }
                }
                if let Some(k) = who {
                    hit[k] = true;
                }
            }
        }
        let mut seen: Vec<usize> = candidates
            .iter()
            .zip(&hit)
            .filter(|(i, h)| **h && wanted(**i as usize))
            .map(|(&i, _)| i as usize)
            .collect();
        seen.sort_unstable();
        seen
    }

    /// Axis-aligned bounds of obstacle `k` where the scene has it now.
    pub(crate) fn bounds_of(&self, k: usize) -> (Vector, Vector) {
        self.shapes[k].aabb()
    }
}

/// Whether an obstacle's bounds `[min, max]` lie beyond a camera's side
/// `walls` (another lane's obstacles, the walls themselves).
pub(crate) fn beyond(walls: [f32; 2], min: Vector, max: Vector) -> bool {
    max.y <= walls[0] || min.y >= walls[1]
}

fn cell_of(x0: f32, y0: f32, x: f32, y: f32, nx: usize, ny: usize) -> (usize, usize) {
    let gx = ((x - x0) / CELL).floor().clamp(0.0, (nx - 1) as f32) as usize;
    let gy = ((y - y0) / CELL).floor().clamp(0.0, (ny - 1) as f32) as usize;
    (gx, gy)
}

/// Ray parameter of the nearest of the corridor's walls, floor and ceiling
/// (always hit from inside). Without branches, so that a row vectorises.
#[inline(always)]
pub(super) fn planes([y0, y1]: [f32; 2], height: f32, o: Vector, d: Vector) -> f32 {
    let ty = if d.y > 0.0 {
        (y1 - o.y) / d.y
    } else if d.y < 0.0 {
        (y0 - o.y) / d.y
    } else {
        f32::INFINITY
    };
    let tz = if d.z > 0.0 {
        (height - o.z) / d.z
    } else if d.z < 0.0 {
        (0.0 - o.z) / d.z
    } else {
        f32::INFINITY
    };
    ty.min(tz).max(0.0)
}

/// Ray parameter of the first hit of a shape, or `tmax` when none is nearer.
#[inline]
pub(crate) fn hit_shape(shape: &Shape, o: Vector, d: Vector, tmax: f32) -> f32 {
    match *shape {
        Shape::Box { min, max } => hit_box(min, max, o, d, tmax),
        Shape::Cylinder { cx, cy, r2, zmin, zmax } => {
            hit_cylinder([cx, cy], r2, [zmin, zmax], o, d, tmax)
        }
    }
}

/// Ray parameter of the first hit of an axis-aligned box, or `tmax`.
#[inline]
pub(super) fn hit_box(min: Vector, max: Vector, o: Vector, d: Vector, tmax: f32) -> f32 {
    let inv = d.recip();
    let t1 = (min - o) * inv;
    let t2 = (max - o) * inv;
    let tn = t1.min(t2).max_element().max(0.0);
    let tf = t1.max(t2).min_element();
    if tn <= tf && tn < tmax { tn } else { tmax }
}

/// Ray parameter of the first hit of a vertical cylinder (axis at `cx, cy`,
/// squared radius `r2`, from `zmin` to `zmax`), or `tmax`.
#[inline]
pub(super) fn hit_cylinder(
    [cx, cy]: [f32; 2],
    r2: f32,
    [zmin, zmax]: [f32; 2],
    o: Vector,
    d: Vector,
    tmax: f32,
) -> f32 {
    let ox = o.x - cx;
    let oy = o.y - cy;
    let a = d.x * d.x + d.y * d.y;
    let b = ox * d.x + oy * d.y;
    let c = ox * ox + oy * oy - r2;
    let mut best = tmax;
    // Side surface.
    if c <= 0.0 {
        if o.z >= zmin && o.z <= zmax {
            return 0.0;
        }
    } else if a > 0.0 {
        let disc = b * b - a * c;
        if disc >= 0.0 {
            let t = (-b - disc.sqrt()) / a;
            if t >= 0.0 && t < best {
                let z = o.z + t * d.z;
                if z >= zmin && z <= zmax {
                    best = t;
                }
            }
        }
    }
    // Caps.
    if d.z != 0.0 {
        for zc in [zmin, zmax] {
            let t = (zc - o.z) / d.z;
            if t >= 0.0 && t < best {
                let x = ox + t * d.x;
                let y = oy + t * d.y;
                if x * x + y * y <= r2 {
                    best = t;
                }
            }
        }
    }
    best
}

#[inline]
pub(super) fn hit_sphere(c: Vector, r: f32, o: Vector, d: Vector, tmax: f32) -> f32 {
    let oc = o - c;
    let a = d.dot(d);
    let b = oc.dot(d);
    let cc = oc.dot(oc) - r * r;
    let disc = b * b - a * cc;
    if disc < 0.0 {
        return tmax;
    }
    let t = (-b - disc.sqrt()) / a;
    if t >= 0.0 && t < tmax { t } else { tmax }
}
