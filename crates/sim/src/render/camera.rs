//! The camera both renderers draw with: its intrinsics ([`CameraSpec`]), its
//! pose, and [`View`], a camera's basis and the ray of each pixel (with the
//! pixel rectangle a box can reach and the floor plan its range covers).

use rapier3d::math::{Rotation, Vector};

/// Intrinsics shared by every camera: the rendered image's size, its
/// horizontal field of view (the vertical one follows from the aspect, the
/// pixels square), its range, and the min-pool that makes the image the
/// network reads (each `pool` × `pool` block's nearest depth, so thin
/// obstacles survive).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSpec {
    /// Rendered columns.
    pub width: usize,
    /// Rendered rows.
    pub height: usize,
    /// Horizontal field of view in degrees.
    pub hfov_deg: f32,
    /// Depth is clipped at this distance (metres) and divided by it.
    pub range: f32,
    /// Side of the blocks min-pooled into one observed pixel (1: none);
    /// it divides `width` and `height`.
    pub pool: usize,
}

impl Default for CameraSpec {
    /// The paper's: 32 × 32 at 90 degrees, 20 m.
    fn default() -> Self {
        Self { width: 32, height: 32, hfov_deg: 90.0, range: 20.0, pool: 1 }
    }
}

impl CameraSpec {
    /// A square camera of `side` pixels and `fov_deg` degrees both ways,
    /// seeing `range` metres, unpooled.
    pub fn square(side: usize, fov_deg: f32, range: f32) -> Self {
        Self { width: side, height: side, hfov_deg: fov_deg, range, pool: 1 }
    }

    /// Rendered pixels of one image.
    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// Tangent of half the horizontal field of view.
    pub fn tan_h(&self) -> f32 {
        (self.hfov_deg.to_radians() / 2.0).tan()
    }

    /// Tangent of half the vertical field of view (square pixels).
    pub fn tan_v(&self) -> f32 {
        self.tan_h() * self.height as f32 / self.width as f32
    }

    /// The camera the network reads: the same view at `width / pool` ×
    /// `height / pool` pixels, unpooled (what the map and the planners of
    /// the pixels read too).
    pub fn observed(&self) -> Self {
        let p = self.pool.max(1);
        Self { width: self.width / p, height: self.height / p, pool: 1, ..*self }
    }

    /// Rows and columns of the observed image.
    pub fn observed_depth(&self) -> [usize; 2] {
        let o = self.observed();
        [o.height, o.width]
    }
}

/// Min-pools `src` (images of `spec`'s rendered size, one after the other)
/// into `out` (of its observed size): each observed pixel the nearest depth
/// of its `pool` × `pool` block.
pub fn min_pool(spec: &CameraSpec, src: &[f32], out: &mut [f32]) {
    let (w, p) = (spec.width, spec.pool.max(1));
    let o = spec.observed();
    for (img, dst) in src.chunks_exact(spec.pixels()).zip(out.chunks_exact_mut(o.pixels())) {
        for (y, row) in dst.chunks_exact_mut(o.width).enumerate() {
            for (x, px) in row.iter_mut().enumerate() {
                let mut m = f32::INFINITY;
                for r in 0..p {
                    let at = (y * p + r) * w + x * p;
                    m = img[at..at + p].iter().fold(m, |m, &d| m.min(d));
                }
                *px = m;
            }
        }
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

/// A camera's basis and the rays of its pixels.
pub(super) struct View {
    pub(super) o: Vector,
    pub(super) fwd: Vector,
    pub(super) left: Vector,
    pub(super) up: Vector,
    /// Tangents of half the field of view, across and up.
    pub(super) tan_u: f32,
    pub(super) tan_v: f32,
    pub(super) range: f32,
    /// Columns and rows.
    pub(super) nu: usize,
    pub(super) nv: usize,
    half_u: f32,
    half_v: f32,
}

/// Inclusive pixel rectangle `(u0, u1, v0, v1)`.
pub(super) type Rect = (usize, usize, usize, usize);

impl View {
    pub(super) fn new(spec: &CameraSpec, cam: &CameraPose) -> Self {
        Self {
            o: cam.position,
            fwd: cam.rotation * Vector::X,
            left: cam.rotation * Vector::Y,
            up: cam.rotation * Vector::Z,
            tan_u: spec.tan_h(),
            tan_v: spec.tan_v(),
            range: spec.range,
            nu: spec.width,
            nv: spec.height,
            half_u: spec.width as f32 / 2.0,
            half_v: spec.height as f32 / 2.0,
        }
    }

    /// Unnormalised direction of pixel `(u, v)`'s ray, its forward component
    /// 1, so the ray parameter at a hit is the planar depth itself.
    #[inline(always)]
    pub(super) fn dir(&self, u: usize, v: usize) -> Vector {
        let su = (u as f32 + 0.5 - self.half_u) / self.half_u * self.tan_u;
        let sv = (self.half_v - v as f32 - 0.5) / self.half_v * self.tan_v;
        self.fwd - self.left * su + self.up * sv
    }

    /// The pixels whose rays can meet the box `[min, max]` at a planar depth
    /// under the range; `None` when there are none. Conservative: a box
    /// reaching the camera's plane takes the whole image.
    pub(super) fn rect(&self, min: Vector, max: Vector) -> Option<Rect> {
        let mut near = f32::INFINITY;
        let mut far = f32::NEG_INFINITY;
        let (mut a0, mut a1, mut b0, mut b1) =
            (f32::INFINITY, f32::NEG_INFINITY, f32::INFINITY, f32::NEG_INFINITY);
        for k in 0..8 {
            let p = Vector::new(
                if k & 1 == 0 { min.x } else { max.x },
                if k & 2 == 0 { min.y } else { max.y },
                if k & 4 == 0 { min.z } else { max.z },
            ) - self.o;
            let x = p.dot(self.fwd);
            near = near.min(x);
            far = far.max(x);
            // Image-plane coordinates of the corner (valid when x > 0).
            let su = -p.dot(self.left) / x;
            let sv = p.dot(self.up) / x;
            a0 = a0.min(su);
            a1 = a1.max(su);
            b0 = b0.min(sv);
            b1 = b1.max(sv);
        }
        // Every point of the box is farther than the range, or behind the camera.
        if near > self.range || far < 0.0 {
            return None;
        }
        let (last_u, last_v) = (self.nu - 1, self.nv - 1);
        if near <= 1e-3 {
            return Some((0, last_u, 0, last_v));
        }
        // Pixel u's ray has su = (u + 0.5 - half) / half · tan; one pixel of
        // margin each side absorbs rounding.
        let to_u = |su: f32| su / self.tan_u * self.half_u + self.half_u - 0.5;
        let to_v = |sv: f32| self.half_v - 0.5 - sv / self.tan_v * self.half_v;
        let (u0, u1) = (to_u(a0).floor() - 1.0, to_u(a1).ceil() + 1.0);
        let (v0, v1) = (to_v(b1).floor() - 1.0, to_v(b0).ceil() + 1.0);
        let (hu, hv) = (last_u as f32, last_v as f32);
        if u1 < 0.0 || v1 < 0.0 || u0 > hu || v0 > hv {
            return None;
        }
        Some((u0.max(0.0) as usize, u1.min(hu) as usize, v0.max(0.0) as usize, v1.min(hv) as usize))
    }

    /// Lowers each pixel of `rect` to `hit(origin, dir, current)`, in `img`
    /// holding the image's rows from `first_row` on. Scalar on purpose: the
    /// rows of a rectangle are short, and a vectorised version (branch-free
    /// hit tests, `multiversion` per row) measured 12.6 against 6.3 µs of
    /// rendering per agent-step (`taskset -c 0 hive bench sim --agents 50`).
    #[inline]
    pub(super) fn fill(
        &self,
        (u0, u1, v0, v1): Rect,
        img: &mut [f32],
        first_row: usize,
        hit: impl Fn(Vector, Vector, f32) -> f32,
    ) {
        for v in v0..=v1 {
            let row = &mut img[(v - first_row) * self.nu..(v - first_row + 1) * self.nu];
            for (u, px) in row.iter_mut().enumerate().take(u1 + 1).skip(u0) {
                *px = hit(self.o, self.dir(u, v), *px);
            }
        }
    }
}

/// The floor-plan rectangle a camera of `spec` at `cam` can see: the view
/// is inside the fan of the four corner rays out to the range (planar depth
/// ≤ range), so the bounding box of the origin and the four far corners
/// holds it.
pub(crate) fn frustum_floor_plan(spec: &CameraSpec, cam: &CameraPose) -> ([f32; 2], [f32; 2]) {
    let r = cam.rotation;
    let basis = [cam.position, r * Vector::X, r * Vector::Y, r * Vector::Z];
    floor_plan_of(basis, [spec.tan_h(), spec.tan_v()], spec.range)
}

/// [`frustum_floor_plan`] from a camera basis already at hand (origin,
/// forward, left, up) and its half-view tangents (across, up).
pub(super) fn floor_plan_of(
    [o, fwd, left, up]: [Vector; 4],
    [tan_u, tan_v]: [f32; 2],
    range: f32,
) -> ([f32; 2], [f32; 2]) {
    let mut lo = [o.x, o.y];
    let mut hi = [o.x, o.y];
    for (a, b) in [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)] {
        let p = o + (fwd - left * (a * tan_u) + up * (b * tan_v)) * range;
        lo = [lo[0].min(p.x), lo[1].min(p.y)];
        hi = [hi[0].max(p.x), hi[1].max(p.y)];
    }
    (lo, hi)
}
