//! Batched CPU depth rendering: every agent's 32×32 depth image of a step in
//! one call, by ray casting against exact boxes, vertical cylinders, the
//! arena's walls, floor and ceiling, and (interactive mode) the other drones.
//!
//! A 2-D uniform grid over the arena floor plan is the spatial index: each
//! camera gathers the few obstacles its range-limited view can reach, and its
//! 1,024 rays are tested against those alone. Cameras are spread over threads
//! when more than one is allowed.

use rapier3d::math::{Rotation, Vector};

use crate::arena::{Arena, Obstacle};

/// Intrinsics shared by every camera.
#[derive(Debug, Clone, Copy)]
pub struct CameraSpec {
    /// Image side in pixels.
    pub side: usize,
    /// Horizontal (and vertical) field of view in degrees.
    pub fov_deg: f32,
    /// Depth is clipped at this distance (metres) and divided by it.
    pub range: f32,
}

impl Default for CameraSpec {
    fn default() -> Self {
        Self { side: 32, fov_deg: 90.0, range: 20.0 }
    }
}

/// A camera pose: position and body orientation. The camera looks along the
/// body's +x axis with the body's +z up.
#[derive(Debug, Clone, Copy)]
pub struct CameraPose {
    /// Position in the world (metres).
    pub position: Vector,
    /// Body-to-world rotation.
    pub rotation: Rotation,
}

#[derive(Debug, Clone, Copy)]
pub(crate) enum Shape {
    Box { min: Vector, max: Vector },
    Cylinder { cx: f32, cy: f32, r2: f32, zmin: f32, zmax: f32 },
}

/// The static scene: obstacles in a grid, and the corridor's bounding planes.
#[derive(Debug, Clone)]
pub struct Scene {
    pub(crate) shapes: Vec<Shape>,
    cell: f32,
    nx: usize,
    ny: usize,
    x0: f32,
    y0: f32,
    cells: Vec<Vec<u32>>,
    pub(crate) half_width: f32,
    pub(crate) height: f32,
    /// Where the arena starts and ends along x.
    pub(crate) x_extent: (f32, f32),
}

const CELL: f32 = 2.0;

impl Scene {
    /// Builds the scene and its grid index from an arena.
    pub fn new(arena: &Arena) -> Self {
        let shapes: Vec<Shape> = arena
            .obstacles
            .iter()
            .map(|o| match *o {
                Obstacle::Box { center, half_extents } => {
                    let c = Vector::from(center);
                    let h = Vector::from(half_extents);
                    Shape::Box { min: c - h, max: c + h }
                }
                Obstacle::Cylinder { center, radius, half_height } => Shape::Cylinder {
                    cx: center[0],
                    cy: center[1],
                    r2: radius * radius,
                    zmin: center[2] - half_height,
                    zmax: center[2] + half_height,
                },
            })
            .collect();
        let hw = arena.width / 2.0;
        let x0 = -CELL;
        let y0 = -hw - CELL;
        let nx = ((arena.length + 2.0 * CELL) / CELL).ceil() as usize + 1;
        let ny = ((arena.width + 2.0 * CELL) / CELL).ceil() as usize + 1;
        let mut cells = vec![Vec::new(); nx * ny];
        for (i, o) in arena.obstacles.iter().enumerate() {
            let (lo, hi) = o.aabb();
            let (ax, ay) = cell_of(x0, y0, lo[0], lo[1], nx, ny);
            let (bx, by) = cell_of(x0, y0, hi[0], hi[1], nx, ny);
            for gx in ax..=bx {
                for gy in ay..=by {
                    cells[gy * nx + gx].push(i as u32);
                }
            }
        }
        Self { shapes, cell: CELL, nx, ny, x0, y0, cells, half_width: hw, height: arena.height, x_extent: (0.0, arena.length) }
    }

    /// Gathers, without duplicates, the obstacles in cells overlapping the
    /// floor-plan rectangle `[lo, hi]`.
    fn gather(&self, lo: [f32; 2], hi: [f32; 2], stamp: &mut Vec<u32>, tick: u32, out: &mut Vec<u32>) {
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

    /// Number of obstacles.
    pub fn len(&self) -> usize {
        self.shapes.len()
    }

    /// True when the scene has no obstacles.
    pub fn is_empty(&self) -> bool {
        self.shapes.is_empty()
    }

    /// Side of a grid cell (metres).
    pub fn cell_size(&self) -> f32 {
        self.cell
    }
}

fn cell_of(x0: f32, y0: f32, x: f32, y: f32, nx: usize, ny: usize) -> (usize, usize) {
    let gx = ((x - x0) / CELL).floor().clamp(0.0, (nx - 1) as f32) as usize;
    let gy = ((y - y0) / CELL).floor().clamp(0.0, (ny - 1) as f32) as usize;
    (gx, gy)
}

/// Other drones drawn as spheres (interactive mode).
#[derive(Debug, Clone, Copy)]
pub struct Drones<'a> {
    /// Centres of all drones, indexed like the cameras.
    pub positions: &'a [Vector],
    /// Sphere radius (metres).
    pub radius: f32,
}

/// Reusable per-thread scratch space.
#[derive(Debug, Default, Clone)]
struct Scratch {
    stamp: Vec<u32>,
    tick: u32,
    candidates: Vec<u32>,
}

/// The batched renderer. Holds scratch space so a step allocates nothing.
#[derive(Debug, Clone)]
pub struct DepthRenderer {
    spec: CameraSpec,
    threads: usize,
    scratch: Vec<Scratch>,
}

impl DepthRenderer {
    /// A renderer with the given camera and thread count (at least 1).
    pub fn new(spec: CameraSpec, threads: usize) -> Self {
        let threads = threads.max(1);
        Self { spec, threads, scratch: vec![Scratch::default(); threads] }
    }

    /// Camera intrinsics.
    pub fn spec(&self) -> CameraSpec {
        self.spec
    }

    /// Renders every camera into `out` (`cameras.len() × side²`), normalised
    /// depth in [0, 1] (planar depth divided by the range, clipped at 1).
    /// With `drones`, camera `i` (drone `first_agent + i`) sees every drone
    /// but its own.
    #[allow(clippy::too_many_arguments)]
    pub fn render(&mut self, scene: &Scene, cameras: &[CameraPose], first_agent: usize, drones: Option<Drones<'_>>, out: &mut [f32]) {
        let px = self.spec.side * self.spec.side;
        assert_eq!(out.len(), cameras.len() * px, "depth buffer has the wrong size");
        let spec = self.spec;
        for s in &mut self.scratch {
            if s.stamp.len() != scene.len() {
                s.stamp = vec![0; scene.len()];
                s.tick = 0;
            }
        }
        // Threads pay off only with enough cameras to share.
        let threads = self.threads.min(cameras.len().div_ceil(4)).max(1);
        if threads == 1 {
            let s = &mut self.scratch[0];
            for (i, (cam, img)) in cameras.iter().zip(out.chunks_mut(px)).enumerate() {
                render_one(scene, &spec, cam, drones.map(|d| (d, first_agent + i)), s, img);
            }
            return;
        }
        // Blocks of cameras handed out as threads come free (cameras differ
        // in cost), the calling thread working as one of them.
        const BLOCK: usize = 2;
        let blocks: Vec<_> = cameras.chunks(BLOCK).zip(out.chunks_mut(BLOCK * px)).enumerate().collect();
        let queue = std::sync::Mutex::new(blocks.into_iter());
        let work = |s: &mut Scratch| {
            loop {
                let next = queue.lock().unwrap_or_else(std::sync::PoisonError::into_inner).next();
                let Some((b, (cams, imgs))) = next else { break };
                for (j, (cam, img)) in cams.iter().zip(imgs.chunks_mut(px)).enumerate() {
                    render_one(scene, &spec, cam, drones.map(|d| (d, first_agent + b * BLOCK + j)), s, img);
                }
            }
        };
        let (mine, others) = self.scratch.split_first_mut().expect("at least one scratch");
        std::thread::scope(|sc| {
            for s in others.iter_mut().take(threads - 1) {
                sc.spawn(|| work(s));
            }
            work(mine);
        });
    }
}

fn render_one(scene: &Scene, spec: &CameraSpec, cam: &CameraPose, drones: Option<(Drones<'_>, usize)>, s: &mut Scratch, img: &mut [f32]) {
    let fwd = cam.rotation * Vector::X;
    let left = cam.rotation * Vector::Y;
    let up = cam.rotation * Vector::Z;
    let o = cam.position;
    let tan = (spec.fov_deg.to_radians() / 2.0).tan();
    let range = spec.range;
    let n = spec.side;
    let half = n as f32 / 2.0;

    let (lo, hi) = frustum_floor_plan(cam, tan, range);
    s.tick = s.tick.wrapping_add(1);
    if s.tick == 0 {
        s.stamp.fill(0);
        s.tick = 1;
    }
    s.candidates.clear();
    scene.gather(lo, hi, &mut s.stamp, s.tick, &mut s.candidates);

    for v in 0..n {
        let sv = (half - v as f32 - 0.5) / half * tan;
        for u in 0..n {
            let su = (u as f32 + 0.5 - half) / half * tan;
            // Unnormalised direction whose forward component is 1, so the ray
            // parameter at a hit is the planar depth itself.
            let d = fwd - left * su + up * sv;
            let mut t = range;
            t = t.min(planes(scene, o, d));
            for &ci in &s.candidates {
                t = t.min(hit_shape(&scene.shapes[ci as usize], o, d, t));
            }
            if let Some((dr, me)) = drones {
                for (k, c) in dr.positions.iter().enumerate() {
                    if k != me {
                        t = t.min(hit_sphere(*c, dr.radius, o, d, t));
                    }
                }
            }
            img[v * n + u] = (t / range).clamp(0.0, 1.0);
        }
    }
}

/// Nearest hit of the corridor's walls, floor and ceiling (always hit from inside).
/// The floor-plan rectangle a camera's view reaches: the view is inside the
/// fan of the four corner rays out to the range (planar depth ≤ range), so
/// the bounding box of the origin and the four far corners holds it.
pub(crate) fn frustum_floor_plan(cam: &CameraPose, tan: f32, range: f32) -> ([f32; 2], [f32; 2]) {
    let (fwd, left, up, o) = (cam.rotation * Vector::X, cam.rotation * Vector::Y, cam.rotation * Vector::Z, cam.position);
    let mut lo = [o.x, o.y];
    let mut hi = [o.x, o.y];
    for (a, b) in [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)] {
        let p = o + (fwd - left * (a * tan) + up * (b * tan)) * range;
        lo = [lo[0].min(p.x), lo[1].min(p.y)];
        hi = [hi[0].max(p.x), hi[1].max(p.y)];
    }
    (lo, hi)
}

#[inline]
fn planes(scene: &Scene, o: Vector, d: Vector) -> f32 {
    let mut t = f32::INFINITY;
    if d.y > 0.0 {
        t = t.min((scene.half_width - o.y) / d.y);
    } else if d.y < 0.0 {
        t = t.min((-scene.half_width - o.y) / d.y);
    }
    if d.z > 0.0 {
        t = t.min((scene.height - o.z) / d.z);
    } else if d.z < 0.0 {
        t = t.min((0.0 - o.z) / d.z);
    }
    t.max(0.0)
}

/// Ray parameter of the first hit of a shape, or `tmax` when none is nearer.
#[inline]
fn hit_shape(shape: &Shape, o: Vector, d: Vector, tmax: f32) -> f32 {
    match *shape {
        Shape::Box { min, max } => {
            let inv = d.recip();
            let t1 = (min - o) * inv;
            let t2 = (max - o) * inv;
            let tn = t1.min(t2).max_element().max(0.0);
            let tf = t1.max(t2).min_element();
            if tn <= tf && tn < tmax { tn } else { tmax }
        }
        Shape::Cylinder { cx, cy, r2, zmin, zmax } => {
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
    }
}

#[inline]
fn hit_sphere(c: Vector, r: f32, o: Vector, d: Vector, tmax: f32) -> f32 {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arena::Spawn;

    fn arena(obstacles: Vec<Obstacle>) -> Arena {
        Arena {
            name: "t".into(),
            length: 100.0,
            width: 40.0,
            height: 10.0,
            spawn: Spawn { x: 1.0, y: [0.0, 0.0], z: 5.0 },
            obstacles,
        }
    }

    fn render(a: &Arena, cam: CameraPose, spec: CameraSpec) -> Vec<f32> {
        let scene = Scene::new(a);
        let mut r = DepthRenderer::new(spec, 1);
        let mut out = vec![0.0; spec.side * spec.side];
        r.render(&scene, &[cam], 0, None, &mut out);
        out.iter().map(|v| v * spec.range).collect()
    }

    #[test]
    fn a_wall_at_distance_d_reads_d() {
        let spec = CameraSpec { range: 30.0, ..CameraSpec::default() };
        for d in [1.0f32, 3.5, 12.25] {
            let wall = Obstacle::Box { center: [10.0 + d + 0.5, 0.0, 5.0], half_extents: [0.5, 19.0, 4.9] };
            let img = render(&arena(vec![wall]), CameraPose { position: Vector::new(10.0, 0.0, 5.0), rotation: Rotation::IDENTITY }, spec);
            // Planar depth of a wall facing the camera is the same at every
            // pixel that sees it; the central 8×8 see it at every distance here.
            for v in 12..20 {
                for u in 12..20 {
                    let px = img[v * 32 + u];
                    assert!((px - d).abs() < 1e-3, "pixel ({u}, {v}): {px} vs {d}");
                }
            }
        }
    }

    #[test]
    fn cylinder_depth_matches_the_analytic_distance() {
        let spec = CameraSpec { range: 30.0, ..CameraSpec::default() };
        let cyl = Obstacle::Cylinder { center: [20.0, 0.0, 5.0], radius: 1.0, half_height: 5.0 };
        let img = render(&arena(vec![cyl]), CameraPose { position: Vector::new(10.0, 0.0, 5.0), rotation: Rotation::IDENTITY }, spec);
        // Pixel column 16 has its ray at a small angle off the axis: solve exactly.
        let tan = 1.0f32;
        let su = (16.0 + 0.5 - 16.0) / 16.0 * tan;
        // Ray (1, -su) in the floor plan, from (10, 0), against the circle at (20, 0) radius 1.
        let (ox, oy) = (-10.0f32, 0.0f32);
        let (dx, dy) = (1.0f32, -su);
        let a = dx * dx + dy * dy;
        let b = ox * dx + oy * dy;
        let c = ox * ox + oy * oy - 1.0;
        let t = (-b - (b * b - a * c).sqrt()) / a;
        let v = img[16 * 32 + 16];
        assert!((v - t).abs() < 1e-3, "{v} vs {t}");
    }

    #[test]
    fn a_rotated_camera_sees_the_side_wall() {
        let spec = CameraSpec { range: 30.0, ..CameraSpec::default() };
        // Yawed 90° left, the camera at y = 0 faces the wall at y = +20.
        let img = render(&arena(vec![]), CameraPose { position: Vector::new(50.0, 0.0, 5.0), rotation: Rotation::from_rotation_z(std::f32::consts::FRAC_PI_2) }, spec);
        let centre = img[15 * 32 + 15];
        assert!((centre - 20.0).abs() < 1e-3, "{centre}");
    }

    #[test]
    fn far_things_clip_at_the_range_and_threads_agree() {
        let a = Arena::generate("g", 3, &crate::arena::GenParams::default());
        let scene = Scene::new(&a);
        let spec = CameraSpec::default();
        let cams: Vec<CameraPose> = (0..37)
            .map(|i| CameraPose { position: Vector::new(2.0 + i as f32 * 3.0, (i as f32 * 0.37).sin() * 4.0, 2.0), rotation: Rotation::from_rotation_z(i as f32 * 0.05 - 0.9) })
            .collect();
        let mut one = vec![0.0; 37 * 1024];
        let mut two = vec![0.0; 37 * 1024];
        DepthRenderer::new(spec, 1).render(&scene, &cams, 0, None, &mut one);
        DepthRenderer::new(spec, 3).render(&scene, &cams, 0, None, &mut two);
        assert_eq!(one, two);
        assert!(one.iter().all(|v| (0.0..=1.0).contains(v)));
        assert!(one.iter().any(|v| *v < 1.0));
    }

    #[test]
    fn drones_are_seen_only_when_given_and_never_by_themselves() {
        let spec = CameraSpec { range: 30.0, ..CameraSpec::default() };
        let a = arena(vec![]);
        let scene = Scene::new(&a);
        let positions = [Vector::new(10.0, 0.0, 5.0), Vector::new(14.0, 0.0, 5.0)];
        let cams: Vec<CameraPose> = positions.iter().map(|p| CameraPose { position: *p, rotation: Rotation::IDENTITY }).collect();
        let mut out = vec![0.0; 2 * 1024];
        DepthRenderer::new(spec, 1).render(&scene, &cams, 0, Some(Drones { positions: &positions, radius: 0.5 }), &mut out);
        let centre = out[15 * 32 + 15] * spec.range;
        assert!((centre - 3.5).abs() < 0.05, "{centre}");
        // Drone 1 looks away from drone 0 and must not see its own sphere.
        assert!(out[1024 + 15 * 32 + 15] * spec.range > 30.0 - 1e-3);
        let mut hidden = vec![0.0; 2 * 1024];
        DepthRenderer::new(spec, 1).render(&scene, &cams, 0, None, &mut hidden);
        assert!(hidden[15 * 32 + 15] * spec.range > 30.0 - 1e-3);
    }
}
