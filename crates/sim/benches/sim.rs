//! Criterion micro-benchmarks of the simulator: batched depth rendering and
//! one full environment step, at 1 and 50 agents.

use criterion::{Criterion, criterion_group, criterion_main};
use rotorhive_sim::{
    Arena, CameraPose, CameraSpec, DepthRenderer, GenParams, Scene, SimConfig, VecEnv,
};

fn bench(c: &mut Criterion) {
    let arena = Arena::generate("bench", 101, &GenParams::default());
    let scene = Scene::new(&arena);
    for n in [1usize, 50] {
        let cams: Vec<CameraPose> = (0..n)
            .map(|i| CameraPose {
                position: rapier3d::math::Vector::new(
                    2.0 + i as f32 * 2.5,
                    ((i * 7) % 9) as f32 - 4.0,
                    2.0,
                ),
                rotation: rapier3d::math::Rotation::IDENTITY,
            })
            .collect();
        let mut r = DepthRenderer::new(CameraSpec::default(), 1);
        let mut out = vec![0.0; n * 1024];
        c.bench_function(&format!("render {n} agents"), |b| {
            b.iter(|| r.render(&scene, &cams, 0, None, &mut out))
        });
        let mut env =
            VecEnv::new(SimConfig { agents: n, ..SimConfig::default() }, arena.clone(), 1).unwrap();
        let mut t = 0u32;
        c.bench_function(&format!("env step {n} agents"), |b| {
            b.iter(|| {
                t += 1;
                let a: Vec<u8> = (0..n).map(|i| ((t as usize + i) % 2) as u8).collect();
                env.step(&a).unwrap()
            })
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
