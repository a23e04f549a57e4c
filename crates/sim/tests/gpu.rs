//! The wgpu renderer against the CPU ray caster: same images on random
//! views (edge pixels excepted), batched equal to non-batched, drones seen in
//! interactive mode, and a golden image. Runs on lavapipe where there is no GPU.

use std::path::PathBuf;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rapier3d::math::{Rotation, Vector};
use rotorhive_sim::render::Drones;
use rotorhive_sim::{
    Arena, CameraPose, CameraSpec, DepthRenderer, GenParams, GpuDepthRenderer, Scene,
};

fn arena() -> Arena {
    Arena::load(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../configs/arenas/train.toml"))
        .expect("train arena")
}

fn gpu(spec: CameraSpec, scene: &Scene) -> GpuDepthRenderer {
    GpuDepthRenderer::new(spec, scene).unwrap_or_else(|e| panic!("{e}"))
}

fn random_views(arena: &Arena, n: usize, seed: u64) -> Vec<CameraPose> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let hw = arena.width / 2.0;
    let mut views = Vec::new();
    while views.len() < n {
        let position = Vector::new(
            rng.random_range(0.0..arena.length),
            rng.random_range(-hw + 0.7..hw - 0.7),
            rng.random_range(0.8..arena.height - 0.8),
        );
        let rotation = Rotation::from_rotation_z(rng.random_range(-1.0..1.0))
            * Rotation::from_rotation_y(rng.random_range(-0.2..0.2))
            * Rotation::from_rotation_x(rng.random_range(-0.2..0.2));
        // Where a drone can be: not inside or touching an obstacle.
        let clear = arena.obstacles.iter().all(|o| {
            let (lo, hi) = o.swept_aabb();
            (0..3).any(|k| position[k] < lo[k] - 0.5 || position[k] > hi[k] + 0.5)
        });
        if clear {
            views.push(CameraPose { position, rotation });
        }
    }
    views
}

/// A pixel at a depth discontinuity: a 4-neighbour in the reference image
/// differs by more than `jump` metres.
fn edge(img: &[f32], [side, rows]: [usize; 2], u: usize, v: usize, jump: f32, range: f32) -> bool {
    let d = img[v * side + u];
    let mut near = Vec::new();
    if u > 0 {
        near.push(img[v * side + u - 1]);
    }
    if u + 1 < side {
        near.push(img[v * side + u + 1]);
    }
    if v > 0 {
        near.push(img[(v - 1) * side + u]);
    }
    if v + 1 < rows {
        near.push(img[(v + 1) * side + u]);
    }
    near.iter().any(|n| (n - d).abs() * range > jump)
}

/// Mean absolute error in metres over the pixels that are not at a depth
/// discontinuity, and the share of all pixels that differ by more than 5 cm.
fn compare(cpu: &[f32], gpu: &[f32], spec: CameraSpec) -> (f64, f64) {
    let (side, px) = (spec.width, spec.pixels());
    let (mut sum, mut count, mut off) = (0.0f64, 0usize, 0usize);
    for (a, b) in cpu.chunks(px).zip(gpu.chunks(px)) {
        for v in 0..spec.height {
            for u in 0..side {
                let err = ((a[v * side + u] - b[v * side + u]).abs() * spec.range) as f64;
                if err > 0.05 {
                    off += 1;
                }
                if edge(a, [side, spec.height], u, v, 0.5, spec.range) {
                    continue;
                }
                sum += err;
                count += 1;
            }
        }
    }
    (sum / count.max(1) as f64, off as f64 / cpu.len() as f64)
}

#[test]
fn wgpu_matches_cpu_on_random_views() {
    // The paper's camera, and one of another aspect and field of view
    // whose atlas rows need padding (8 × 36 texels to 320).
    let wide = CameraSpec { width: 36, height: 20, hfov_deg: 100.0, range: 25.0, pool: 1 };
    for spec in [CameraSpec::default(), wide] {
        random_views_agree(spec);
    }
}

/// The two renderers of `spec` on 100 random views of the arena.
fn random_views_agree(spec: CameraSpec) {
    let arena = arena();
    let scene = Scene::new(&arena);
    let cams = random_views(&arena, 100, 7);
    let px = spec.pixels();
    let mut cpu = vec![0.0; cams.len() * px];
    let mut out = vec![0.0; cams.len() * px];
    DepthRenderer::new(spec, 1).render(&scene, &cams, 0, None, &mut cpu);
    let agents: Vec<u32> = (0..cams.len() as u32).collect();
    let mut g = gpu(spec, &scene);
    g.render(&cams, &agents, None, &mut out).unwrap();
    let (mae, off) = compare(&cpu, &out, spec);
    let all = cpu.iter().zip(&out).map(|(a, b)| ((a - b).abs() * spec.range) as f64).sum::<f64>()
        / cpu.len() as f64;
    println!(
        "adapter {}: mean |wgpu − cpu| {:.2} mm over non-edge pixels ({:.2} mm over all), {:.2} % of pixels off by > 5 cm",
        g.adapter(),
        mae * 1000.0,
        all * 1000.0,
        off * 100.0
    );
    // The views see something: not every pixel at the range.
    assert!(cpu.iter().filter(|d| **d < 0.99).count() > cpu.len() / 4, "views see too little");
    assert!(mae < 0.01, "mean absolute error {mae} m over non-edge pixels");
    // Pixels that differ are rare (edges, where a ray grazes a corner).
    assert!(off < 0.01, "{} % of pixels differ by more than 5 cm", off * 100.0);
    assert_eq!(g.submissions(), 1, "one submission for all cameras");
}

#[test]
fn wgpu_matches_cpu_where_obstacles_move() {
    let params = GenParams { spacing: 3.0, per_row: 2, moving_share: 0.5, ..GenParams::default() };
    let arena = Arena::generate("moving", 5, &params);
    let moving = arena.obstacles.iter().filter(|o| o.motion().is_some()).count();
    assert!(moving > 10, "{moving} obstacles move");
    let mut scene = Scene::new(&arena);
    let spec = CameraSpec::default();
    let cams = random_views(&arena, 60, 11);
    let px = spec.pixels();
    let agents: Vec<u32> = (0..cams.len() as u32).collect();
    let mut g = gpu(spec, &scene);
    let mut before: Option<Vec<f32>> = None;
    for t in [0.0, 4.0, 11.5] {
        scene.set_time(t);
        g.set_time(t);
        let mut cpu = vec![0.0; cams.len() * px];
        let mut out = vec![0.0; cams.len() * px];
        DepthRenderer::new(spec, 1).render(&scene, &cams, 0, None, &mut cpu);
        g.render(&cams, &agents, None, &mut out).unwrap();
        let (mae, off) = compare(&cpu, &out, spec);
        assert!(mae < 0.01, "t = {t}: mean absolute error {mae} m over non-edge pixels");
        assert!(off < 0.01, "t = {t}: {} % of pixels differ by more than 5 cm", off * 100.0);
        // The obstacles did move: the views changed.
        if let Some(b) = &before {
            let changed = b.iter().zip(&cpu).filter(|(a, c)| (*a - *c).abs() * spec.range > 0.1);
            assert!(changed.count() > 200, "t = {t}: the views hardly changed");
        }
        before = Some(cpu);
    }
}

#[test]
fn wgpu_batched_equals_one_camera_at_a_time() {
    let arena = arena();
    let scene = Scene::new(&arena);
    let spec = CameraSpec::default();
    let cams = random_views(&arena, 20, 11);
    let px = spec.pixels();
    let agents: Vec<u32> = (0..cams.len() as u32).collect();
    let mut g = gpu(spec, &scene);
    let mut batched = vec![0.0; cams.len() * px];
    g.render(&cams, &agents, None, &mut batched).unwrap();
    let mut single = vec![0.0; cams.len() * px];
    for (i, img) in single.chunks_mut(px).enumerate() {
        g.render(&cams[i..i + 1], &agents[i..i + 1], None, img).unwrap();
    }
    assert_eq!(g.submissions(), 1 + cams.len() as u64);
    let worst = batched.iter().zip(&single).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst < 1e-4, "batched and one-at-a-time differ by {worst}");
}

#[test]
fn wgpu_shows_other_drones_only_in_interactive_mode() {
    let arena = Arena { obstacles: vec![], ..arena() };
    let scene = Scene::new(&arena);
    let spec = CameraSpec::default();
    // Drone 0 looks along +x at drone 1, 3 m ahead.
    let cams = [
        CameraPose { position: Vector::new(10.0, 0.0, 3.0), rotation: Rotation::IDENTITY },
        CameraPose { position: Vector::new(13.0, 0.0, 3.0), rotation: Rotation::IDENTITY },
    ];
    let positions: Vec<Vector> = cams.iter().map(|c| c.position).collect();
    let drones = Drones { positions: &positions, radius: 0.5 };
    let px = spec.pixels();
    let mut g = gpu(spec, &scene);
    let (mut cpu, mut out, mut hidden) = (vec![0.0; 2 * px], vec![0.0; 2 * px], vec![0.0; 2 * px]);
    DepthRenderer::new(spec, 1).render(&scene, &cams, 0, Some(drones), &mut cpu);
    g.render(&cams, &[0, 1], Some(drones), &mut out).unwrap();
    g.render(&cams, &[0, 1], None, &mut hidden).unwrap();
    let centre = (spec.height / 2) * spec.width + spec.width / 2;
    let expect = 2.5 / spec.range;
    assert!(
        (cpu[centre] - expect).abs() < 0.01,
        "cpu sees the drone at {}",
        cpu[centre] * spec.range
    );
    assert!(
        (out[centre] - cpu[centre]).abs() * spec.range < 0.02,
        "wgpu sees the drone at {} m, cpu at {} m",
        out[centre] * spec.range,
        cpu[centre] * spec.range
    );
    assert!(hidden[centre] > 0.9, "drone visible without interactive mode");
    // Drone 1 does not see itself.
    assert!(out[px + centre] > 0.9, "a camera sees its own drone: {}", out[px + centre]);
}

fn save16(path: &std::path::Path, img: &[f32], side: usize) {
    let data: Vec<u16> = img.iter().map(|d| (d.clamp(0.0, 1.0) * 65535.0).round() as u16).collect();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(side as u32, side as u32, data)
        .expect("size")
        .save(path)
        .expect("write png");
}

/// A fixed view of the training arena against `tests/golden/train_view.png`
/// (16-bit depth). On a mismatch the actual and difference images are
/// written to `target/golden/`. `ROTORHIVE_BLESS=1` rewrites the golden image
/// from the CPU renderer.
#[test]
fn golden_image() {
    let arena = arena();
    let scene = Scene::new(&arena);
    let spec = CameraSpec::default();
    let cam = CameraPose {
        position: Vector::new(8.0, 0.5, 2.0),
        rotation: Rotation::from_rotation_z(0.15),
    };
    let px = spec.pixels();
    let mut cpu = vec![0.0; px];
    DepthRenderer::new(spec, 1).render(&scene, &[cam], 0, None, &mut cpu);
    let mut out = vec![0.0; px];
    gpu(spec, &scene).render(&[cam], &[0], None, &mut out).unwrap();
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let golden_path = dir.join("tests/golden/train_view.png");
    if std::env::var("ROTORHIVE_BLESS").is_ok_and(|v| v == "1") {
        save16(&golden_path, &cpu, spec.width);
    }
    let golden: Vec<f32> = image::open(&golden_path)
        .unwrap_or_else(|e| {
            panic!("golden image {}: {e} (ROTORHIVE_BLESS=1 writes it)", golden_path.display())
        })
        .to_luma16()
        .into_raw()
        .into_iter()
        .map(|v| v as f32 / 65535.0)
        .collect();
    let out_dir = dir.join("../../target/golden");
    let mut failures = Vec::new();
    for (name, img) in [("cpu", &cpu), ("wgpu", &out)] {
        let (mae, _) = compare(&golden, img, spec);
        if mae >= 0.01 {
            std::fs::create_dir_all(&out_dir).expect("golden output dir");
            save16(&out_dir.join(format!("actual_{name}.png")), img, spec.width);
            let diff: Vec<f32> =
                img.iter().zip(&golden).map(|(a, b)| ((a - b).abs() * 10.0).min(1.0)).collect();
            save16(&out_dir.join(format!("diff_{name}.png")), &diff, spec.width);
            failures.push(format!("{name}: mean error {:.1} mm", mae * 1000.0));
        }
    }
    assert!(
        failures.is_empty(),
        "golden image mismatch ({}); actual and diff images in {}",
        failures.join(", "),
        out_dir.display()
    );
}
