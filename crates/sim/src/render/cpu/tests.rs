use rapier3d::math::Rotation;

use super::*;
use crate::arena::{Arena, Obstacle, Spawn};
use crate::render::scene::{hit_shape, hit_sphere, planes};

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

#[test]
fn a_camera_in_a_lane_sees_the_same_with_or_without_the_lane_cut() {
    use crate::{GenParams, Lanes};
    let p = GenParams { length: 60.0, width: 12.0, height: 8.0, ..GenParams::default() };
    let arenas: Vec<Arena> =
        (0..5).map(|k| Arena::generate(&format!("l{k}"), 40 + k, &p)).collect();
    let lanes = Lanes::new(&arenas).unwrap();
    let spec = CameraSpec::default();
    let full = Scene::new(&lanes.world);
    let mut cut = Scene::new(&lanes.world);
    cut.set_lanes(&lanes.bounds);
    // Cameras in every lane, looking ahead and turned towards the walls.
    let mut cams = Vec::new();
    for (k, off) in lanes.offsets.iter().enumerate() {
        for (j, yaw) in [0.0f32, 0.7, -0.7, 1.3].iter().enumerate() {
            let pos = Vector::new(
                3.0 + 9.0 * j as f32,
                off + (j as f32 - 1.5) * 1.5,
                2.0 + 0.5 * k as f32,
            );
            cams.push(CameraPose { position: pos, rotation: Rotation::from_rotation_z(*yaw) });
        }
    }
    let n = spec.pixels();
    let (mut a, mut b) = (vec![0.0; cams.len() * n], vec![0.0; cams.len() * n]);
    DepthRenderer::new(spec, 1).render(&full, &cams, 0, None, &mut a);
    DepthRenderer::new(spec, 1).render(&cut, &cams, 0, None, &mut b);
    // The walls drawn as planes instead of boxes: the same depths, to rounding.
    let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "largest difference {worst}");
    assert!(a.iter().any(|d| *d < 0.99), "the cameras see something");
}

fn render(a: &Arena, cam: CameraPose, spec: CameraSpec) -> Vec<f32> {
    let scene = Scene::new(a);
    let mut r = DepthRenderer::new(spec, 1);
    let mut out = vec![0.0; spec.pixels()];
    r.render(&scene, &[cam], 0, None, &mut out);
    out.iter().map(|v| v * spec.range).collect()
}

#[test]
fn a_wall_at_distance_d_reads_d() {
    let spec = CameraSpec { range: 30.0, ..CameraSpec::default() };
    for d in [1.0f32, 3.5, 12.25] {
        let wall = Obstacle::still_box([10.0 + d + 0.5, 0.0, 5.0], [0.5, 19.0, 4.9]);
        let img = render(
            &arena(vec![wall]),
            CameraPose { position: Vector::new(10.0, 0.0, 5.0), rotation: Rotation::IDENTITY },
            spec,
        );
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
    let cyl = Obstacle::still_cylinder([20.0, 0.0, 5.0], 1.0, 5.0);
    let img = render(
        &arena(vec![cyl]),
        CameraPose { position: Vector::new(10.0, 0.0, 5.0), rotation: Rotation::IDENTITY },
        spec,
    );
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
    let img = render(
        &arena(vec![]),
        CameraPose {
            position: Vector::new(50.0, 0.0, 5.0),
            rotation: Rotation::from_rotation_z(std::f32::consts::FRAC_PI_2),
        },
        spec,
    );
    let centre = img[15 * 32 + 15];
    assert!((centre - 20.0).abs() < 1e-3, "{centre}");
}

#[test]
fn far_things_clip_at_the_range_and_threads_agree() {
    let a = Arena::generate("g", 3, &crate::generate::GenParams::default());
    let scene = Scene::new(&a);
    let spec = CameraSpec::default();
    let cams: Vec<CameraPose> = (0..37)
        .map(|i| CameraPose {
            position: Vector::new(2.0 + i as f32 * 3.0, (i as f32 * 0.37).sin() * 4.0, 2.0),
            rotation: Rotation::from_rotation_z(i as f32 * 0.05 - 0.9),
        })
        .collect();
    let mut one = vec![0.0; 37 * 1024];
    let mut two = vec![0.0; 37 * 1024];
    DepthRenderer::new(spec, 1).render(&scene, &cams, 0, None, &mut one);
    DepthRenderer::new(spec, 3).render(&scene, &cams, 0, None, &mut two);
    assert_eq!(one, two);
    assert!(one.iter().all(|v| (0.0..=1.0).contains(v)));
    assert!(one.iter().any(|v| *v < 1.0));
}

/// Every ray against every candidate: what the rectangle culling of
/// `render_one` must reproduce exactly.
fn brute_force(
    scene: &Scene,
    spec: &CameraSpec,
    cam: &CameraPose,
    drones: Option<(Drones<'_>, usize)>,
    img: &mut [f32],
) {
    let view = View::new(spec, cam);
    for v in 0..view.nv {
        for u in 0..view.nu {
            let d = view.dir(u, v);
            let mut t = view.range.min(planes(
                [-scene.half_width, scene.half_width],
                scene.height,
                view.o,
                d,
            ));
            for shape in &scene.shapes {
                t = t.min(hit_shape(shape, view.o, d, t));
            }
            if let Some((dr, me)) = drones {
                for (k, c) in dr.positions.iter().enumerate() {
                    if k != me {
                        t = t.min(hit_sphere(*c, dr.radius, view.o, d, t));
                    }
                }
            }
            img[v * view.nu + u] = (t / view.range).clamp(0.0, 1.0);
        }
    }
}

#[test]
fn culling_by_projected_rectangles_changes_no_pixel() {
    use rand::{Rng, SeedableRng};
    let a = Arena::generate("g", 11, &crate::generate::GenParams::default());
    let scene = Scene::new(&a);
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(5);
    let mut seen = 0;
    for spec in [
        CameraSpec::default(),
        CameraSpec::square(17, 70.0, 35.0),
        CameraSpec { width: 40, height: 18, hfov_deg: 100.0, range: 25.0, pool: 1 },
    ] {
        let px = spec.pixels();
        let positions: Vec<Vector> = (0..60)
            .map(|_| {
                Vector::new(
                    rng.random_range(0.5..a.length - 0.5),
                    rng.random_range(-a.width / 2.0 + 0.3..a.width / 2.0 - 0.3),
                    rng.random_range(0.3..a.height - 0.3),
                )
            })
            .collect();
        let cams: Vec<CameraPose> = positions
            .iter()
            .map(|p| CameraPose {
                position: *p,
                rotation: Rotation::from_rotation_z(rng.random_range(-3.2..3.2))
                    * Rotation::from_rotation_y(rng.random_range(-0.6..0.6))
                    * Rotation::from_rotation_x(rng.random_range(-0.6..0.6)),
            })
            .collect();
        let drones = Drones { positions: &positions, radius: 0.4 };
        let mut fast = vec![0.0; cams.len() * px];
        DepthRenderer::new(spec, 2).render(&scene, &cams, 0, Some(drones), &mut fast);
        // One camera per call: its rows are cut into bands over the threads.
        let mut banded = vec![0.0; cams.len() * px];
        let mut three = DepthRenderer::new(spec, 3);
        for (i, img) in banded.chunks_mut(px).enumerate() {
            three.render(&scene, &cams[i..i + 1], i, Some(drones), img);
        }
        let mut slow = vec![0.0; px];
        for (i, cam) in cams.iter().enumerate() {
            brute_force(&scene, &spec, cam, Some((drones, i)), &mut slow);
            assert_eq!(&fast[i * px..(i + 1) * px], &slow[..], "camera {i} at {:?}", cam.position);
            assert_eq!(&banded[i * px..(i + 1) * px], &slow[..], "camera {i} alone, in bands");
            seen += slow.iter().filter(|v| **v < 1.0).count();
        }
    }
    assert!(seen > 10_000, "the views saw too little to compare: {seen} pixels");
}

#[test]
fn drones_are_seen_only_when_given_and_never_by_themselves() {
    let spec = CameraSpec { range: 30.0, ..CameraSpec::default() };
    let a = arena(vec![]);
    let scene = Scene::new(&a);
    let positions = [Vector::new(10.0, 0.0, 5.0), Vector::new(14.0, 0.0, 5.0)];
    let cams: Vec<CameraPose> = positions
        .iter()
        .map(|p| CameraPose { position: *p, rotation: Rotation::IDENTITY })
        .collect();
    let mut out = vec![0.0; 2 * 1024];
    DepthRenderer::new(spec, 1).render(
        &scene,
        &cams,
        0,
        Some(Drones { positions: &positions, radius: 0.5 }),
        &mut out,
    );
    let centre = out[15 * 32 + 15] * spec.range;
    assert!((centre - 3.5).abs() < 0.05, "{centre}");
    // Drone 1 looks away from drone 0 and must not see its own sphere.
    assert!(out[1024 + 15 * 32 + 15] * spec.range > 30.0 - 1e-3);
    let mut hidden = vec![0.0; 2 * 1024];
    DepthRenderer::new(spec, 1).render(&scene, &cams, 0, None, &mut hidden);
    assert!(hidden[15 * 32 + 15] * spec.range > 30.0 - 1e-3);
}
