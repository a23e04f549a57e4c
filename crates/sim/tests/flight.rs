//! The direct flight path against the rapier reference, and collisions that
//! nothing tunnels through.

use rotorhive_sim::{Arena, Autoreset, Done, Obstacle, PhysicsKind, SimConfig, Spawn, VecEnv};

fn open_arena(length: f32, width: f32, obstacles: Vec<Obstacle>) -> Arena {
    Arena {
        name: "open".into(),
        length,
        width,
        height: 8.0,
        spawn: Spawn { x: 2.0, y: [0.0, 0.0], z: 3.0 },
        obstacles,
    }
}

/// Action sequences of every kind a policy flies: held one way, alternating,
/// in bursts, and pseudo-random.
fn action(agent: usize, t: usize) -> u8 {
    match agent % 4 {
        0 => u8::from((t / 6).is_multiple_of(2)),
        1 => (t % 2) as u8,
        2 => u8::from(t < 4 || (t / 3) % 3 == 1),
        _ => (((t * 2654435761 + agent * 40503) >> 7) % 2) as u8,
    }
}

#[test]
fn direct_flight_follows_the_rapier_reference() {
    let agents = 12;
    let arena = open_arena(400.0, 400.0, vec![]);
    let make = |physics| {
        let mut env = VecEnv::new(
            SimConfig { agents, physics, max_steps: 1000, ..SimConfig::default() },
            arena.clone(),
            5,
        )
        .unwrap();
        env.set_autoreset(Autoreset::Disabled);
        for i in 0..agents {
            env.place(i, [2.0, i as f32 * 20.0 - 110.0, 3.0], [1.0, 0.0, 0.0]);
        }
        env
    };
    let (mut direct, mut rapier) = (make(PhysicsKind::Direct), make(PhysicsKind::Rapier));
    let (mut worst_pos, mut worst_att, mut worst_vel) = (0.0f32, 0.0f32, 0.0f32);
    for t in 0..40 {
        let actions: Vec<u8> = (0..agents).map(|i| action(i, t)).collect();
        direct.step(&actions).unwrap();
        rapier.step(&actions).unwrap();
        for i in 0..agents {
            let (a, b) = (direct.state(i), rapier.state(i));
            assert_eq!(direct.dones()[i], Done::Running, "agent {i} ended at step {t} in open air");
            worst_pos = worst_pos.max((a.position - b.position).length());
            worst_vel = worst_vel.max((a.velocity - b.velocity).length());
            worst_att = worst_att.max(a.rotation.angle_between(b.rotation).to_degrees());
        }
    }
    eprintln!(
        "agent 0 at {:?} / {:?}, agent 3 at {:?}",
        direct.state(0).position,
        rapier.state(0).position,
        rapier.state(3).position
    );
    eprintln!(
        "after 40 actions of 12 agents: position {worst_pos:.6} m, velocity {worst_vel:.6} m/s, attitude {worst_att:.3} degrees apart at worst"
    );
    // Over 40 s of flight and up to 3 m/s of lateral speed (measured: 4 µm,
    // 3 µm/s and 0.04 degrees; the attitude differs by the frame in which
    // the torque is held over a step).
    assert!(worst_pos < 1e-3, "positions {worst_pos} m apart");
    assert!(worst_vel < 1e-3, "velocities {worst_vel} m/s apart");
    assert!(worst_att < 0.2, "attitudes {worst_att} degrees apart");
}

/// The thinnest an arena's box may be is any positive size: 0.2 mm here.
const THIN: f32 = 1e-4;

#[test]
fn nothing_tunnels_through_the_thinnest_wall_at_the_highest_speed() {
    let agents = 200;
    let cfg = SimConfig { agents, physics: PhysicsKind::Direct, ..SimConfig::default() };
    // A wall along the arena, 0.2 mm thick, crossed sideways at the largest
    // lateral speed; and one across it, met head on.
    let along = Obstacle::still_box([100.0, 3.0, 4.0], [95.0, THIN, 4.0]);
    let across = Obstacle::still_box([150.0, -6.0, 4.0], [THIN, 3.0, 4.0]);
    let arena = open_arena(200.0, 30.0, vec![along, across]);
    let mut env = VecEnv::new(cfg.clone(), arena.clone(), 9).unwrap();
    env.set_autoreset(Autoreset::Disabled);
    let v = cfg.max_lateral_speed;
    for i in 0..agents {
        // From 0.31 m to 3.3 m short of the wall, in steps that put the
        // crossing at every phase of a physics step.
        let gap = 0.31 + 3.0 * i as f32 / agents as f32;
        if i % 2 == 0 {
            env.place(i, [10.0 + 0.4 * i as f32, 3.0 - gap, 3.0], [cfg.forward_speed, v, 0.0]);
        } else {
            env.place(i, [150.0 - gap, -6.0 + 0.01 * i as f32, 3.0], [cfg.forward_speed, 0.0, 0.0]);
        }
    }
    let mut ended = vec![None; agents];
    for t in 0..6 {
        // +lateral_step holds the even agents at the top lateral speed; the
        // odd ones alternate and fly straight.
        let actions: Vec<u8> =
            (0..agents).map(|i| if i % 2 == 0 { 1 } else { (t % 2) as u8 }).collect();
        env.step(&actions).unwrap();
        for (i, d) in env.dones().iter().enumerate() {
            if *d != Done::Running && ended[i].is_none() {
                ended[i] = Some((*d, t));
            }
        }
    }
    for (i, e) in ended.iter().enumerate() {
        // A collision in the action that reaches the wall (3.3 m at 3 m/s
        // sideways, at 1 m/s ahead), not later: the drone flies on through a
        // wall it touched until the action ends, so only the timing shows
        // that the touch was seen when it happened.
        let latest = if i % 2 == 0 { 1 } else { 3 };
        assert!(
            matches!(e, Some((Done::Collision, t)) if *t <= latest),
            "agent {i} ended as {e:?}"
        );
    }
    // Without the walls, the same flights are not collisions.
    let mut clear = VecEnv::new(cfg, open_arena(200.0, 30.0, vec![]), 9).unwrap();
    for _ in 0..2 {
        clear.step(&vec![1; agents]).unwrap();
        assert!(clear.dones().iter().all(|d| *d == Done::Running));
    }
}

/// The physics, the frames' ageing and the observations' copies (the
/// step's reset stage) share the render threads: the same flights and the
/// same observation bytes on one thread as on three, with two frames and
/// with four of stride two (several earlier frames kept), in the env's
/// buffer and written out as the sim process writes them.
#[test]
fn physics_on_the_shared_render_threads_flies_exactly_as_on_one() {
    let arena = Arena::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../configs/arenas/train.toml"
    )))
    .unwrap();
    let run = |threads, (frames, frame_stride)| {
        let cfg = SimConfig {
            agents: 150,
            render_threads: threads,
            frames,
            frame_stride,
            ..SimConfig::default()
        };
        let mut env = VecEnv::new(cfg, arena.clone(), 4).unwrap();
        let mut ends = 0;
        for t in 0..30 {
            let actions: Vec<u8> = (0..150).map(|i| action(i, t)).collect();
            env.step(&actions).unwrap();
            ends += env.finished().len();
        }
        let mut out = vec![f32::NAN; 100 * env.obs_len()];
        env.write_observations(37, &mut out);
        (env.positions(), env.observations().to_vec(), out, ends)
    };
    for stack in [(2, 1), (4, 2)] {
        let (one, three) = (run(1, stack), run(3, stack));
        assert!(one.3 > 0, "some episodes end, so resets are covered");
        assert!(one.2.iter().all(|x| x.is_finite()), "every row written");
        assert!(one == three, "{stack:?}: one thread and three differ");
    }
}
