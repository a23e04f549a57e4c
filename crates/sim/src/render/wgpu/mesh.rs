//! The GPU renderer's geometry: the still scene as indexed triangles laid
//! out for culling (what every camera draws, then obstacles by band), and
//! the triangles of each shape and of a drone's sphere.

use crate::render::scene::{Scene, Shape};

/// Facets of a cylinder's side.
const CYLINDER_FACETS: usize = 24;

/// Side of the y bands obstacles are sorted into (metres).
const BAND: f32 = 8.0;
/// Obstacles longer than this along x or y are drawn for every camera.
const BIG: f32 = 8.0;

/// The static scene in world coordinates, laid out for culling: first what
/// every camera draws (walls, floor, ceiling, big obstacles), then the other
/// obstacles sorted by y band and, within a band, by centre x, so that the
/// obstacles a camera can see are one contiguous index range per band.
/// Triangles are indexed (a vertex shared by facets is shaded once) and wound
/// counter-clockwise as seen from inside the arena, outside the obstacles.
pub(super) struct SceneLayout {
    pub(super) vertices: Vec<[f32; 3]>,
    pub(super) indices: Vec<u32>,
    /// Indices every camera draws.
    pub(super) always: u32,
    /// Per band: (band index, sorted centre x, first index) of its obstacles.
    bands: Vec<(i32, Vec<(f32, u32)>)>,
    /// End index of each band's last obstacle.
    band_end: Vec<u32>,
    /// Largest half extent of a banded obstacle (the culling margin).
    margin: f32,
}

impl SceneLayout {
    pub(super) fn new(scene: &Scene, range: f32) -> Self {
        let mut always = Vec::new();
        let (x0, x1) = (scene.x_extent.0 - range - 1.0, scene.x_extent.1 + range + 1.0);
        let (hw, h) = (scene.half_width, scene.height);
        quad(&mut always, [x0, hw, 0.0], [x1, hw, 0.0], [x1, hw, h], [x0, hw, h]);
        quad(&mut always, [x0, -hw, 0.0], [x1, -hw, 0.0], [x1, -hw, h], [x0, -hw, h]);
        quad(&mut always, [x0, -hw, 0.0], [x1, -hw, 0.0], [x1, hw, 0.0], [x0, hw, 0.0]);
        quad(&mut always, [x0, -hw, h], [x1, -hw, h], [x1, hw, h], [x0, hw, h]);
        // Walls, floor and ceiling face the arena's centre line.
        orient(&mut always, |c| [0.0, -c[1], h / 2.0 - c[2]]);
        let mut banded: Vec<(i32, f32, Vec<[f32; 3]>)> = Vec::new();
        let mut margin = 0.0f32;
        let moving: std::collections::HashSet<u32> = scene.movers.iter().map(|m| m.0).collect();
        let still = scene.shapes.iter().enumerate().filter(|(i, _)| !moving.contains(&(*i as u32)));
        for (_, sh) in still {
            let (cx, cy, ex, ey) = match *sh {
                Shape::Box { min, max } => (
                    (min.x + max.x) / 2.0,
                    (min.y + max.y) / 2.0,
                    (max.x - min.x) / 2.0,
                    (max.y - min.y) / 2.0,
                ),
                Shape::Cylinder { cx, cy, r2, .. } => (cx, cy, r2.sqrt(), r2.sqrt()),
            };
            let tris = shape_triangles(sh, h);
            if 2.0 * ex > BIG || 2.0 * ey > BIG {
                always.extend(tris);
            } else {
                margin = margin.max(ex.max(ey));
                banded.push(((cy / BAND).floor() as i32, cx, tris));
            }
        }
        banded.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let mut vertices = always;
        let always = vertices.len() as u32;
        let mut bands: Vec<(i32, Vec<(f32, u32)>)> = Vec::new();
        let mut band_end = Vec::new();
        for (band, cx, tris) in banded {
            if bands.last().is_none_or(|b| b.0 != band) {
                if !bands.is_empty() {
                    band_end.push(vertices.len() as u32);
                }
                bands.push((band, Vec::new()));
            }
            bands.last_mut().expect("just pushed").1.push((cx, vertices.len() as u32));
            vertices.extend(tris);
        }
        if !bands.is_empty() {
            band_end.push(vertices.len() as u32);
        }
        let (vertices, indices) = indexed(&vertices);
        Self { vertices, indices, always, bands, band_end, margin }
    }

    /// The vertex ranges of banded obstacles within `[lo, hi]` (floor plan).
    pub(super) fn visible(&self, lo: [f32; 2], hi: [f32; 2], out: &mut Vec<std::ops::Range<u32>>) {
        out.clear();
        let m = self.margin;
        let (b0, b1) = (((lo[1] - m) / BAND).floor() as i32, ((hi[1] + m) / BAND).floor() as i32);
        for (k, (band, obs)) in self.bands.iter().enumerate() {
            if *band < b0 || *band > b1 {
                continue;
            }
            let a = obs.partition_point(|o| o.0 < lo[0] - m);
            let b = obs.partition_point(|o| o.0 <= hi[0] + m);
            if a < b {
                let end = if b < obs.len() { obs[b].1 } else { self.band_end[k] };
                out.push(obs[a].1..end);
            }
        }
    }
}

/// Shares equal vertices of a triangle list: (vertices, indices), the
/// indices in the list's order.
fn indexed(list: &[[f32; 3]]) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut seen = std::collections::HashMap::new();
    let mut vertices = Vec::new();
    let indices = list
        .iter()
        .map(|v| {
            *seen.entry(v.map(f32::to_bits)).or_insert_with(|| {
                vertices.push(*v);
                vertices.len() as u32 - 1
            })
        })
        .collect();
    (vertices, indices)
}

/// Winds every triangle of a list counter-clockwise as seen from the side
/// `toward(centroid)` points to (its front face for the cameras).
fn orient(t: &mut [[f32; 3]], toward: impl Fn([f32; 3]) -> [f32; 3]) {
    let sub = |a: [f32; 3], b: [f32; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    for tri in t.chunks_exact_mut(3) {
        let (u, v) = (sub(tri[1], tri[0]), sub(tri[2], tri[0]));
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let c = [0, 1, 2].map(|k| (tri[0][k] + tri[1][k] + tri[2][k]) / 3.0);
        let w = toward(c);
        if n[0] * w[0] + n[1] * w[1] + n[2] * w[2] < 0.0 {
            tri.swap(1, 2);
        }
    }
}

fn quad(t: &mut Vec<[f32; 3]>, a: [f32; 3], b: [f32; 3], c: [f32; 3], d: [f32; 3]) {
    t.extend([a, b, c, a, c, d]);
}

/// One obstacle as triangles.
pub(super) fn shape_triangles(sh: &Shape, h: f32) -> Vec<[f32; 3]> {
    let mut t = Vec::new();
    match *sh {
        Shape::Box { min, max } => {
            let c = |i: usize| {
                [
                    if i & 1 == 0 { min.x } else { max.x },
                    if i & 2 == 0 { min.y } else { max.y },
                    if i & 4 == 0 { min.z } else { max.z },
                ]
            };
            for [a, b, cc, d] in
                [[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]]
            {
                quad(&mut t, c(a), c(b), c(cc), c(d));
            }
            let mid = [(min.x + max.x) / 2.0, (min.y + max.y) / 2.0, (min.z + max.z) / 2.0];
            orient(&mut t, |p| [p[0] - mid[0], p[1] - mid[1], p[2] - mid[2]]);
        }
        Shape::Cylinder { cx, cy, r2, zmin, zmax } => {
            // Vertices just outside the circle, so the facets straddle
            // the exact surface: within ±r·(1/cos(π/24) − 1)/2 ≈ 0.4 % of r.
            let half = std::f32::consts::PI / CYLINDER_FACETS as f32;
            let r = r2.sqrt() * (1.0 + 1.0 / half.cos()) / 2.0;
            // Caps inside the floor or ceiling are never seen.
            let (bottom, top) = (zmin > 1e-3, zmax < h - 1e-3);
            let at = |k: usize| {
                let a = k as f32 / CYLINDER_FACETS as f32 * std::f32::consts::TAU;
                (cx + r * a.cos(), cy + r * a.sin())
            };
            for k in 0..CYLINDER_FACETS {
                let (ax, ay) = at(k);
                let (bx, by) = at(k + 1);
                quad(&mut t, [ax, ay, zmin], [bx, by, zmin], [bx, by, zmax], [ax, ay, zmax]);
                if bottom {
                    t.extend([[cx, cy, zmin], [ax, ay, zmin], [bx, by, zmin]]);
                }
                if top {
                    t.extend([[cx, cy, zmax], [ax, ay, zmax], [bx, by, zmax]]);
                }
            }
            let zmid = (zmin + zmax) / 2.0;
            orient(&mut t, |p| [p[0] - cx, p[1] - cy, p[2] - zmid]);
        }
    }
    t
}

/// A unit sphere (icosahedron subdivided twice, 320 triangles).
pub(super) fn sphere_triangles() -> Vec<[f32; 3]> {
    let p = (1.0 + 5f32.sqrt()) / 2.0;
    let v = [
        [-1.0, p, 0.0],
        [1.0, p, 0.0],
        [-1.0, -p, 0.0],
        [1.0, -p, 0.0],
        [0.0, -1.0, p],
        [0.0, 1.0, p],
        [0.0, -1.0, -p],
        [0.0, 1.0, -p],
        [p, 0.0, -1.0],
        [p, 0.0, 1.0],
        [-p, 0.0, -1.0],
        [-p, 0.0, 1.0],
    ];
    let f: [[usize; 3]; 20] = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let norm = |a: [f32; 3]| {
        let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        [a[0] / l, a[1] / l, a[2] / l]
    };
    let mut tris: Vec<[[f32; 3]; 3]> =
        f.iter().map(|t| [norm(v[t[0]]), norm(v[t[1]]), norm(v[t[2]])]).collect();
    for _ in 0..2 {
        let mid = |a: [f32; 3], b: [f32; 3]| {
            norm([(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0, (a[2] + b[2]) / 2.0])
        };
        tris = tris
            .iter()
            .flat_map(|&[a, b, c]| {
                let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
                [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
            })
            .collect();
    }
    tris.into_iter().flatten().collect()
}
