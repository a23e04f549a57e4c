//! Criterion micro-benchmarks of the simulator: batched depth rendering and
//! one full environment step, at 1 and 50 agents; a teacher's labels of 16
//! agents on L4's movers (and with L5's hold and goal), searched breadth
//! first and depth first (`teacher.label_search`).

use criterion::{Criterion, criterion_group, criterion_main};
use rotorhive_sim::{
    Arena, CameraPose, CameraSpec, DepthRenderer, GenParams, Goal, Planner, Scene, Sight,
    SimConfig, VecEnv,
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

/// Every agent's label (`Planner::label`, horizon 10, the planner of every
/// obstacle) after 20 steps on an L4 layout, without and with L5's hold
/// action and goal, breadth first against depth first.
fn labels(c: &mut Criterion) {
    let params = GenParams::l4_rows(60.0);
    let arena = Arena::generate("bench-moving", 3, &params);
    for (name, hold_goal) in [("L4", false), ("L5", true)] {
        let goal = Goal { enabled: hold_goal, ..Goal::default() };
        let cfg = SimConfig { agents: 16, hold_action: hold_goal, goal, ..SimConfig::default() };
        let mut env = VecEnv::new(cfg, arena.clone(), 1).unwrap();
        for t in 0..20usize {
            let a: Vec<u8> = (0..16).map(|i| ((t + i) % 2) as u8).collect();
            env.step(&a).unwrap();
        }
        for depth_first in [false, true] {
            let mut planner = Planner::new(&env, Sight::All).with_depth_first_labels(depth_first);
            let search = if depth_first { "depth" } else { "breadth" };
            c.bench_function(&format!("labels {name} 16 agents {search}"), |b| {
                b.iter(|| (0..16).filter_map(|i| planner.label(&env, i, 10)).count())
            });
        }
    }
}

criterion_group!(benches, bench, labels);
criterion_main!(benches);
