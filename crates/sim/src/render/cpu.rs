//! Batched CPU depth rendering: every agent's depth image of a step in
//! one call, by ray casting against exact boxes, vertical cylinders, the
//! arena's walls, floor and ceiling, and (interactive mode) the other drones.
//!
//! A 2-D uniform grid over the arena floor plan is the spatial index: each
//! camera gathers the few obstacles its range-limited view can reach, and
//! each of those is tested only by the rays inside its projected bounding
//! rectangle. A call's work (whole cameras, or bands of rows when there are
//! few cameras) is shared by a persistent pool of render threads.

use std::sync::{Mutex, PoisonError};

use rapier3d::math::Vector;

use super::camera::{CameraPose, CameraSpec, Rect, View};
use super::scene::{Scene, Shape, beyond, hit_box, hit_cylinder, hit_sphere, planes};
use crate::pool::Pool;

/// Other drones drawn as spheres (interactive mode).
#[derive(Debug, Clone, Copy)]
pub struct Drones<'a> {
    /// Centres of all drones, indexed like the cameras.
    pub positions: &'a [Vector],
    /// Sphere radius (metres).
    pub radius: f32,
}

/// Reusable per-thread scratch space.
#[derive(Debug, Default)]
struct Scratch {
    stamp: Vec<u32>,
    tick: u32,
    candidates: Vec<u32>,
}

/// The batched renderer. Holds scratch space so a step allocates nothing,
/// and a persistent pool of render threads.
#[derive(Debug)]
pub struct DepthRenderer {
    spec: CameraSpec,
    pool: Pool,
    scratch: Vec<Mutex<Scratch>>,
}

impl DepthRenderer {
    /// A renderer with the given camera and thread count (at least 1; fewer
    /// when the system refuses to start more threads).
    pub fn new(spec: CameraSpec, threads: usize) -> Self {
        let pool = Pool::new(threads.max(1))
            .unwrap_or_else(|_| Pool::new(1).expect("a pool of one starts no thread"));
        let scratch = (0..pool.threads()).map(|_| Mutex::new(Scratch::default())).collect();
        Self { spec, pool, scratch }
    }

    /// The render threads, which the physics shares.
    pub(crate) fn pool(&self) -> &Pool {
        &self.pool
    }

    /// Camera intrinsics.
    pub fn spec(&self) -> CameraSpec {
        self.spec
    }

    /// Renders every camera into `out` (`cameras.len() × width × height`,
    /// the rendered size: the caller min-pools), normalised
    /// depth in [0, 1] (planar depth divided by the range, clipped at 1).
    /// With `drones`, camera `i` (drone `first_agent + i`) sees every drone
    /// but its own.
    ///
    /// One call is one submission to the render threads and one
    /// synchronisation with them: the work is cut into pieces (whole
    /// cameras when there are enough of them to share, else bands of rows
    /// of each), handed out as threads come free, and the call returns when
    /// all are drawn.
    pub fn render(
        &mut self,
        scene: &Scene,
        cameras: &[CameraPose],
        first_agent: usize,
        drones: Option<Drones<'_>>,
        out: &mut [f32],
    ) {
        let (n, px) = (self.spec.width, self.spec.pixels());
        assert_eq!(out.len(), cameras.len() * px, "depth buffer has the wrong size");
        let spec = self.spec;
        for s in &mut self.scratch {
            let s = s.get_mut().unwrap_or_else(PoisonError::into_inner);
            if s.stamp.len() != scene.len() {
                s.stamp = vec![0; scene.len()];
                s.tick = 0;
            }
        }
        let threads = self.pool.threads();
        if threads == 1 || cameras.is_empty() {
            let s = self.scratch[0].get_mut().unwrap_or_else(PoisonError::into_inner);
            for (i, (cam, img)) in cameras.iter().zip(out.chunks_mut(px)).enumerate() {
                render_rows(scene, &spec, cam, drones.map(|d| (d, first_agent + i)), s, img, 0);
            }
            return;
        }
        // Pieces: whole cameras, handed out as threads come free (cameras
        // differ in cost); with fewer cameras than threads, each is cut
        // into as many bands of rows as it takes to busy every thread (more
        // bands would only repeat each band's obstacle gathering).
        let bands = threads.div_ceil(cameras.len()).min(self.spec.height);
        let rows = self.spec.height.div_ceil(bands);
        let pieces = out.chunks_mut(px).enumerate().flat_map(|(c, img)| {
            img.chunks_mut(rows * n).enumerate().map(move |(b, part)| (c, b * rows, part))
        });
        let queue = Mutex::new(pieces);
        let scratch = &self.scratch;
        self.pool.run(&|t| {
            let mut s = scratch[t].lock().unwrap_or_else(PoisonError::into_inner);
            loop {
                let next = queue.lock().unwrap_or_else(PoisonError::into_inner).next();
                let Some((c, first_row, part)) = next else {
                    break;
                };
                render_rows(
                    scene,
                    &spec,
                    &cameras[c],
                    drones.map(|d| (d, first_agent + c)),
                    &mut s,
                    part,
                    first_row,
                );
            }
        });
    }
}

/// Draws rows `first_row..` of one camera's image into `img` (whole rows).
fn render_rows(
    scene: &Scene,
    spec: &CameraSpec,
    cam: &CameraPose,
    drones: Option<(Drones<'_>, usize)>,
    s: &mut Scratch,
    img: &mut [f32],
    first_row: usize,
) {
    let view = View::new(spec, cam);
    let n = view.nu;
    let (r0, r1) = (first_row, first_row + img.len() / n);
    s.tick = s.tick.wrapping_add(1);
    if s.tick == 0 {
        s.stamp.fill(0);
        s.tick = 1;
    }
    s.candidates.clear();
    let walls = scene.reach(&view, &mut s.stamp, s.tick, &mut s.candidates);

    // The corridor's planes bound every ray; `img` holds depth in metres
    // until the end.
    for (v, row) in (r0..r1).zip(img.chunks_exact_mut(n)) {
        corridor_row(&view, walls, scene.height, v, row);
    }
    // Each obstacle is tested only by the rays inside its projected bounding
    // rectangle: a ray outside it cannot reach the obstacle. The result is
    // the same minimum as testing every ray against every obstacle.
    let clip = |(u0, u1, v0, v1): Rect| -> Option<Rect> {
        (v0 < r1 && v1 >= r0).then(|| (u0, u1, v0.max(r0), v1.min(r1 - 1)))
    };
    for &ci in &s.candidates {
        let shape = &scene.shapes[ci as usize];
        let (min, max) = shape.aabb();
        if beyond(walls, min, max) {
            continue;
        }
        let Some(rect) = view.rect(min, max).and_then(clip) else {
            continue;
        };
        match *shape {
            Shape::Box { min, max } => {
                view.fill(rect, img, r0, |o, d, t| hit_box(min, max, o, d, t))
            }
            Shape::Cylinder { cx, cy, r2, zmin, zmax } => view
                .fill(rect, img, r0, |o, d, t| hit_cylinder([cx, cy], r2, [zmin, zmax], o, d, t)),
        }
    }
    if let Some((dr, me)) = drones {
        let r = Vector::splat(dr.radius);
        for (k, c) in dr.positions.iter().enumerate() {
            if k == me {
                continue;
            }
            let Some(rect) = view.rect(*c - r, *c + r).and_then(clip) else {
                continue;
            };
            view.fill(rect, img, r0, |o, d, t| hit_sphere(*c, dr.radius, o, d, t));
        }
    }
    normalise(img, view.range);
}

/// Planar depth in metres to normalised depth: divided by the range,
/// clipped to [0, 1].
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma+avx",
    "x86_64+avx2+fma+avx"
))]
fn normalise(img: &mut [f32], range: f32) {
    for px in img.iter_mut() {
        *px = (*px / range).clamp(0.0, 1.0);
    }
}

/// Row `v` of a camera's image drawn with the corridor's planes alone,
/// clipped at the range. Compiled for AVX-512 and AVX2 beside the baseline
/// (picked at run time), the pixels of a row a vector at a time.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma+avx",
    "x86_64+avx2+fma+avx"
))]
fn corridor_row(view: &View, walls: [f32; 2], height: f32, v: usize, row: &mut [f32]) {
    for (u, px) in row.iter_mut().enumerate() {
        *px = view.range.min(planes(walls, height, view.o, view.dir(u, v)));
    }
}

#[cfg(test)]
mod tests;
