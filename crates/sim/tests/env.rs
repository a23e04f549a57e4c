//! Behaviour of the vectorised environment: flight control, collisions,
//! non-interaction, per-agent reset, determinism and the shipped arenas.

use std::path::PathBuf;

use rotorhive_sim::{
    Arena, Autoreset, Done, Goal, Motion, Noise, Obstacle, PhysicsKind, RendererKind, SimConfig,
    Spawn, VecEnv,
};

fn open_arena(length: f32, obstacles: Vec<Obstacle>) -> Arena {
    Arena {
        name: "open".into(),
        length,
        width: 20.0,
        height: 8.0,
        spawn: Spawn { x: 2.0, y: [0.0, 0.0], z: 3.0 },
        obstacles,
    }
}

fn cfg(agents: usize) -> SimConfig {
    SimConfig { agents, ..SimConfig::default() }
}

fn arena_file(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../configs/arenas").join(name)
}

#[test]
fn hover_holds_altitude() {
    let mut env =
        VecEnv::new(SimConfig { forward_speed: 0.0, ..cfg(1) }, open_arena(100.0, vec![]), 1)
            .unwrap();
    env.place(0, [10.0, 0.0, 3.0], [0.0, 0.0, 0.0]);
    for _ in 0..10 {
        env.fly(&[0.0], 1.0);
        let s = env.state(0);
        assert!((s.position.z - 3.0).abs() < 0.05, "altitude drifted to {}", s.position.z);
        assert!(s.velocity.length() < 0.05, "hover drifts at {:?}", s.velocity);
    }
}

#[test]
fn velocity_setpoint_is_tracked_within_ten_percent_after_two_seconds() {
    for (forward, lateral) in [(1.0f32, 0.0f32), (1.0, 1.0), (1.0, -0.75), (0.0, 2.0)] {
        let mut env = VecEnv::new(
            SimConfig { forward_speed: forward, ..cfg(1) },
            open_arena(200.0, vec![]),
            1,
        )
        .unwrap();
        env.place(0, [10.0, 0.0, 3.0], [0.0, 0.0, 0.0]);
        env.fly(&[lateral], 2.0);
        let v = env.state(0).velocity;
        let want = (forward * forward + lateral * lateral).sqrt();
        let err = ((v.x - forward).powi(2) + (v.y - lateral).powi(2)).sqrt();
        assert!(err <= 0.1 * want, "setpoint ({forward}, {lateral}) reached {v:?}");
        assert!((env.state(0).position.z - 3.0).abs() < 0.15);
    }
}

#[test]
fn flying_into_an_obstacle_is_a_collision_and_resets_only_that_agent() {
    // Agent 0 spawns right in front of a wall; agent 1 flies in open air beside it.
    let wall = Obstacle::still_box([5.0, -5.0, 4.0], [0.5, 4.0, 4.0]);
    let mut env = VecEnv::new(cfg(2), open_arena(100.0, vec![wall]), 3).unwrap();
    env.place(0, [2.0, -5.0, 3.0], [1.0, 0.0, 0.0]);
    env.place(1, [2.0, 5.0, 3.0], [1.0, 0.0, 0.0]);
    let mut hit_at = None;
    for step in 0..6 {
        // Alternate actions keep the lateral setpoint near zero: straight flight.
        env.step(&[(step % 2) as u8, (step % 2) as u8]).unwrap();
        if env.dones()[0] == Done::Collision {
            hit_at = Some(step);
            break;
        }
        assert_eq!(env.dones()[1], Done::Running);
    }
    let hit_at = hit_at.expect("agent 0 never hit the wall");
    assert!(hit_at >= 1, "hit too early at step {hit_at}");
    assert_eq!(env.rewards()[0], -100.0);
    assert_eq!(env.rewards()[1], 3.0);
    assert_eq!(env.finished().len(), 1);
    assert_eq!(env.finished()[0].agent, 0);
    // Agent 0 is back at the spawn, agent 1 went on undisturbed.
    let p = env.positions();
    assert!((p[0][0] - 2.0).abs() < 1e-4, "{p:?}");
    assert!(p[1][0] > 4.0, "{p:?}");
    // A reset agent's two frames are the same first view.
    let obs = env.observations();
    let len = env.obs_len();
    assert_eq!(&obs[..1024], &obs[1024..2048]);
    assert_ne!(&obs[len..len + 1024], &obs[len + 1024..len + 2048]);
    // Written in place (as the sim process does), any rows are the same.
    let mut rows = vec![-1.0; len];
    env.write_observations(1, &mut rows);
    assert_eq!(&rows[..], &obs[len..2 * len]);
    let mut all = vec![-1.0; 2 * len];
    env.write_observations(0, &mut all);
    assert_eq!(&all[..], obs);
    env.drop_observation_buffer();
    env.step(&[0, 0]).unwrap();
    assert!(env.observations().is_empty());
    env.write_observations(0, &mut all);
    assert_ne!(
        &all[len + 1024..len + 2048],
        &rows[1024..2048],
        "agent 1 flew on: its view changed"
    );
}

#[test]
fn agents_pass_through_and_do_not_see_each_other_unless_interactive() {
    // Two drones on crossing paths at the same spot.
    let run = |interactive: bool| {
        let mut env =
            VecEnv::new(SimConfig { interactive, ..cfg(2) }, open_arena(100.0, vec![]), 5).unwrap();
        env.place(0, [10.0, -1.5, 3.0], [1.0, 0.0, 0.0]);
        env.place(1, [10.0, 1.5, 3.0], [1.0, 0.0, 0.0]);
        let front_depth_of_1 =
            |env: &VecEnv| env.observations()[env.obs_len() + 1024..env.obs_len() + 2048].to_vec();
        let mut saw_other = false;
        let mut collided = false;
        let mut clear_view = front_depth_of_1(&env);
        // Agent 0 steers right (+y), agent 1 left (−y), so they meet.
        for _ in 0..6 {
            env.step(&[1, 0]).unwrap();
            collided |= env.dones().contains(&Done::Collision);
            let view = front_depth_of_1(&env);
            saw_other |= view.iter().zip(&clear_view).any(|(a, b)| (a - b).abs() > 0.05);
            clear_view = view;
        }
        (collided, saw_other)
    };
    let (collided, _) = run(false);
    assert!(!collided, "non-interactive drones collided");
    let (collided, _) = run(true);
    assert!(collided, "interactive drones flew through each other");
}

#[test]
fn non_interactive_depth_ignores_other_drones() {
    let mut env = VecEnv::new(cfg(2), open_arena(100.0, vec![]), 5).unwrap();
    env.place(0, [10.0, 0.0, 3.0], [1.0, 0.0, 0.0]);
    env.place(1, [13.0, 0.0, 3.0], [1.0, 0.0, 0.0]);
    env.step(&[0, 1]).unwrap();
    let mut alone = VecEnv::new(cfg(1), open_arena(100.0, vec![]), 5).unwrap();
    alone.place(0, [10.0, 0.0, 3.0], [1.0, 0.0, 0.0]);
    alone.step(&[0]).unwrap();
    assert_eq!(&env.observations()[1024..2048], &alone.observations()[1024..2048]);

    let mut inter =
        VecEnv::new(SimConfig { interactive: true, ..cfg(2) }, open_arena(100.0, vec![]), 5)
            .unwrap();
    inter.place(0, [10.0, 0.0, 3.0], [1.0, 0.0, 0.0]);
    inter.place(1, [13.0, 0.0, 3.0], [1.0, 0.0, 0.0]);
    inter.step(&[0, 1]).unwrap();
    let centre = inter.observations()[1024 + 15 * 32 + 15] * 20.0;
    assert!(centre < 4.0, "interactive drone 0 should see drone 1 about 3 m ahead, read {centre}");
}

#[test]
fn same_seed_same_trajectory() {
    let arena = Arena::load(&arena_file("train.toml")).unwrap();
    let run = |seed: u64| {
        let mut env = VecEnv::new(cfg(4), arena.clone(), seed).unwrap();
        let mut trace = Vec::new();
        for t in 0..30u32 {
            let actions: Vec<u8> = (0..4).map(|i| ((t * 7 + i * 3) % 5 < 2) as u8).collect();
            env.step(&actions).unwrap();
            trace.extend_from_slice(env.observations());
            trace.extend_from_slice(env.rewards());
        }
        trace
    };
    let a = run(11);
    assert_eq!(a, run(11));
    assert_ne!(a, run(12));
}

#[test]
fn timeout_ends_an_episode_with_its_penalty() {
    let mut env = VecEnv::new(
        SimConfig { max_steps: 5, forward_speed: 0.0, ..cfg(1) },
        open_arena(100.0, vec![]),
        1,
    )
    .unwrap();
    for _ in 0..4 {
        env.step(&[(env.total_steps() % 2) as u8]).unwrap();
        assert_eq!(env.dones()[0], Done::Running);
    }
    env.step(&[0]).unwrap();
    assert_eq!(env.dones()[0], Done::Timeout);
    assert_eq!(env.finished()[0].reward, 4.0 * 3.0 - 10.0);
}

#[test]
fn reaching_the_end_is_a_goal() {
    let mut env = VecEnv::new(cfg(1), open_arena(8.0, vec![]), 1).unwrap();
    let mut done = Done::Running;
    for t in 0..10 {
        env.step(&[(t % 2) as u8]).unwrap();
        done = env.dones()[0];
        if done != Done::Running {
            break;
        }
    }
    assert_eq!(done, Done::Goal);
}

/// With a goal: the observation gains its three floats and the action
/// space the hold; a drone that steers to the goal's side reaches it (the
/// step's reward is the arrival bonus), one that holds straight on past an
/// offset goal misses it (a timeout with the miss penalty); the progress
/// reward is the distance gained. On both physics paths.
#[test]
fn a_goal_is_reached_by_steering_to_it_and_missed_by_flying_past() {
    for physics in [PhysicsKind::Direct, PhysicsKind::Rapier] {
        fly_to_a_goal(physics);
    }
}

fn fly_to_a_goal(physics: PhysicsKind) {
    let goal = Goal { enabled: true, lateral: [3.0, 3.0], from_end: 5.0, ..Goal::default() };
    let sim = SimConfig { agents: 2, goal, hold_action: true, physics, ..SimConfig::default() };
    assert_eq!(sim.shapes().scalars, 6);
    assert_eq!(sim.shapes().actions, 3);
    let mut env = VecEnv::new(sim, open_arena(40.0, vec![]), 1).unwrap();
    assert_eq!(env.obs_len(), 2 * 32 * 32 + 6);
    assert_eq!(env.goals()[0], [35.0, 3.0]);
    let g = env.goal_observation(0);
    assert!(
        g[0] > 0.0 && (g[1] - 33.0f32.hypot(3.0) / 10.0).abs() < 0.01 && (g[2] - 0.3).abs() < 0.01
    );
    let row = &env.observations()[..env.obs_len()];
    assert_eq!(&row[2 * 1024 + 3..], &g);
    let (mut ends, mut rewards) = ([None, None], [0.0f32; 2]);
    for t in 0..60 {
        // Agent 0 steers left up to 0.5 m/s, then holds until level with
        // the goal, then brakes; agent 1 holds straight on.
        let vy = env.state(0).velocity.y;
        let y = env.positions()[0][1];
        let a0 = if y < 2.5 {
            if vy < 0.5 { 1 } else { 2 }
        } else if vy > 0.05 {
            0
        } else {
            2
        };
        let x0 = env.positions()[1][0];
        env.step(&[a0, 2]).unwrap();
        for i in 0..2 {
            if ends[i].is_none() && env.dones()[i] != Done::Running {
                ends[i] = Some((env.dones()[i], t));
                rewards[i] = env.rewards()[i];
            }
        }
        if t == 3 {
            let gained = env.positions()[1][0] - x0;
            assert!((env.rewards()[1] - (3.0 + gained)).abs() < 0.05, "{}", env.rewards()[1]);
        }
        if ends.iter().all(Option::is_some) {
            break;
        }
    }
    assert_eq!(ends[0].map(|e| e.0), Some(Done::Goal), "{ends:?}");
    assert_eq!(rewards[0], 100.0);
    assert_eq!(ends[1].map(|e| e.0), Some(Done::Timeout), "{ends:?}");
    assert_eq!(rewards[1], -10.0);
}

/// Straight flight, or always the same action, collides before earning 300
/// from every spawn point of the shipped arenas.
#[test]
fn shipped_arenas_punish_trivial_policies() {
    for name in ["train.toml", "test.toml"] {
        let arena = Arena::load(&arena_file(name)).unwrap();
        let spawns: Vec<f32> = (0..9)
            .map(|k| arena.spawn.y[0] + (arena.spawn.y[1] - arena.spawn.y[0]) * k as f32 / 8.0)
            .collect();
        let n = spawns.len();
        for policy in ["straight", "always-left", "always-right"] {
            let mut env = VecEnv::new(cfg(n), arena.clone(), 9).unwrap();
            for (i, y) in spawns.iter().enumerate() {
                env.place(i, [arena.spawn.x, *y, arena.spawn.z], [1.0, 0.0, 0.0]);
            }
            let mut ended: Vec<Option<f32>> = vec![None; n];
            for t in 0..120u32 {
                let a: Vec<u8> = match policy {
                    "straight" => vec![(t % 2) as u8; n],
                    "always-left" => vec![1; n],
                    _ => vec![0; n],
                };
                env.step(&a).unwrap();
                for ep in env.finished() {
                    ended[ep.agent].get_or_insert(ep.reward);
                }
                if ended.iter().all(Option::is_some) {
                    break;
                }
            }
            for (i, e) in ended.iter().enumerate() {
                let r = e.unwrap_or_else(|| {
                    panic!("{name}: {policy} from y = {} never crashed", spawns[i])
                });
                assert!(r < 300.0, "{name}: {policy} from y = {} earned {r}", spawns[i]);
            }
        }
    }
    let train = Arena::load(&arena_file("train.toml")).unwrap();
    let test = Arena::load(&arena_file("test.toml")).unwrap();
    assert_ne!(train.obstacles, test.obstacles, "train and test arenas must differ");
}

#[test]
fn lanes_put_arenas_side_by_side_and_keep_them_apart() {
    use rotorhive_sim::{CameraPose, CameraSpec, DepthRenderer, Lanes, Scene};
    let a = open_arena(100.0, vec![]);
    let b = open_arena(100.0, vec![Obstacle::still_box([30.0, 0.0, 4.0], [1.0, 1.0, 4.0])]);
    let lanes = Lanes::new(&[a.clone(), b.clone()]).unwrap();
    assert_eq!(lanes.offsets.len(), 2);
    assert!((lanes.offsets[1] - lanes.offsets[0] - 21.0).abs() < 1e-4, "{:?}", lanes.offsets);
    assert_eq!(lanes.world.obstacles.len(), 1 + 4, "one obstacle and two walls per lane");
    // Agents spawn in both lanes, each inside its lane.
    let env = VecEnv::new_lanes(cfg(16), &[a.clone(), b], 3).unwrap();
    let mut used = [false; 2];
    for p in env.positions() {
        let k = lanes
            .offsets
            .iter()
            .position(|o| (p[1] - o).abs() < 10.0)
            .expect("agent outside every lane");
        used[k] = true;
    }
    assert_eq!(used, [true, true]);
    // Looking sideways from lane 0's centre line, a camera sees its own wall
    // (10 m away), not the next lane.
    let spec = CameraSpec::default();
    let scene = Scene::new(&lanes.world);
    let cam = CameraPose {
        position: rapier3d::math::Vector::new(50.0, lanes.offsets[0], 4.0),
        rotation: rapier3d::math::Rotation::from_rotation_z(std::f32::consts::FRAC_PI_2),
    };
    let mut img = vec![0.0; spec.pixels()];
    DepthRenderer::new(spec, 1).render(&scene, &[cam], 0, None, &mut img);
    let centre = img[(spec.height / 2) * spec.width + spec.width / 2] * spec.range;
    assert!((centre - 10.0).abs() < 0.01, "sideways depth {centre}");
    // Lengths must agree.
    assert!(Lanes::new(&[a, open_arena(90.0, vec![])]).is_err());
}

#[test]
fn without_autoreset_an_ended_agent_keeps_its_last_frames_until_it_is_reset() {
    let arena = open_arena(100.0, vec![Obstacle::still_box([30.0, 0.0, 4.0], [0.5, 10.0, 4.0])]);
    let mut env = VecEnv::new(SimConfig { max_steps: 3, ..cfg(2) }, arena, 7).unwrap();
    env.set_autoreset(Autoreset::Disabled);
    let start = env.observations().to_vec();
    let spawn_x = env.positions()[0][0];
    for _ in 0..3 {
        env.step(&[1, 0]).unwrap();
    }
    assert_eq!(env.dones(), &[Done::Timeout, Done::Timeout]);
    assert_eq!(env.finished().len(), 2);
    // Both stayed where their episode ended, and their observation is the
    // last one of that episode, not a fresh spawn's.
    let ended = env.observations().to_vec();
    let ended_pos = env.positions();
    assert!(ended_pos[0][0] > spawn_x + 1.0, "{ended_pos:?}");
    assert_ne!(&ended[..env.obs_len()], &start[..env.obs_len()]);
    // Reset only agent 0.
    env.reset_agents(&[true, false]).unwrap();
    let after = env.observations();
    let n = env.obs_len();
    let px = 32 * 32;
    assert_eq!(env.dones(), &[Done::Running, Done::Timeout]);
    assert!((env.positions()[0][0] - spawn_x).abs() < 1e-4, "agent 0 is back at its spawn");
    assert_eq!(env.positions()[1], ended_pos[1], "agent 1 did not move");
    assert_eq!(&after[n..2 * n], &ended[n..2 * n], "agent 1's observation is unchanged");
    assert_eq!(&after[..px], &after[px..2 * px], "a reset agent's two frames are its first view");
    // Reseeding makes the spawns reproducible.
    let mut a =
        VecEnv::new(SimConfig { max_steps: 3, ..cfg(2) }, open_arena(100.0, vec![]), 1).unwrap();
    let mut b =
        VecEnv::new(SimConfig { max_steps: 3, ..cfg(2) }, open_arena(100.0, vec![]), 2).unwrap();
    for e in [&mut a, &mut b] {
        e.reseed(42);
        e.reset_agents(&[true, true]).unwrap();
    }
    assert_eq!(a.observations(), b.observations());
}

#[test]
fn resetting_ended_agents_by_hand_matches_autoreset_step_for_step() {
    // What Gymnasium's SAME_STEP mode does (step without autoreset, keep the
    // final observations, reset the ended agents) gives the same episodes and
    // observations as the training path's autoreset, for the same seed.
    let arena = Arena::load(&arena_file("train.toml")).unwrap();
    let make = || VecEnv::new(SimConfig { max_steps: 30, ..cfg(6) }, arena.clone(), 11).unwrap();
    let (mut auto, mut by_hand) = (make(), make());
    by_hand.set_autoreset(Autoreset::Disabled);
    let n = auto.obs_len();
    let mut ended = 0;
    for t in 0..80u32 {
        let actions: Vec<u8> = (0..6u32).map(|i| ((t * 7 + i * 3) % 5 < 2) as u8).collect();
        auto.step(&actions).unwrap();
        by_hand.step(&actions).unwrap();
        assert_eq!(auto.rewards(), by_hand.rewards(), "step {t}");
        assert_eq!(auto.dones(), by_hand.dones(), "step {t}");
        let mask: Vec<bool> = by_hand.dones().iter().map(|d| *d != Done::Running).collect();
        // Before the reset, an ended agent's observation is its last view.
        for (i, m) in mask.iter().enumerate() {
            if *m {
                assert_ne!(
                    &by_hand.observations()[i * n..(i + 1) * n],
                    &auto.observations()[i * n..(i + 1) * n],
                    "step {t} agent {i}"
                );
            }
        }
        ended += mask.iter().filter(|m| **m).count();
        by_hand.reset_agents(&mask).unwrap();
        assert_eq!(auto.observations(), by_hand.observations(), "step {t}");
    }
    assert!(ended >= 6, "the test needs ended episodes, saw {ended}");
}

#[test]
fn split_observations_are_the_flat_rows_cut_in_two() {
    let arena = Arena::load(&arena_file("train.toml")).unwrap();
    let mut env = VecEnv::new(cfg(3), arena, 5).unwrap();
    env.step(&[0, 1, 1]).unwrap();
    env.step(&[1, 1, 0]).unwrap();
    let (n, px) = (env.obs_len(), 32 * 32);
    let mut depth = vec![0.0; 3 * 2 * px];
    let mut vel = vec![0.0; 3 * 3];
    env.write_observations_split(&mut depth, &mut vel);
    for i in 0..3 {
        let row = &env.observations()[i * n..(i + 1) * n];
        assert_eq!(&depth[i * 2 * px..(i + 1) * 2 * px], &row[..2 * px]);
        assert_eq!(&vel[i * 3..(i + 1) * 3], &row[2 * px..]);
    }
    assert!(vel.iter().any(|v| *v != 0.0));
}

/// With `frames` depth frames each observation holds the last views
/// `frame_stride` actions apart, oldest first: every step shifts them by one
/// action period, and a new episode starts with all of them its first view.
/// The split observation and the shapes follow.
#[test]
fn an_observation_holds_the_last_frames_oldest_first() {
    let arena = Arena::load(&arena_file("train.toml")).unwrap();
    let px = 32 * 32;
    for (frames, stride) in [(1, 1), (2, 1), (4, 1), (2, 3), (3, 2)] {
        let sim = SimConfig { frames, frame_stride: stride, max_steps: 9, ..cfg(2) };
        assert_eq!(sim.shapes().obs_len(), frames * px + 3);
        let mut env = VecEnv::new(sim, arena.clone(), 3).unwrap();
        env.set_autoreset(Autoreset::Disabled);
        let n = env.obs_len();
        assert_eq!(n, frames * px + 3);
        let first = env.observations()[..n].to_vec();
        for f in 1..frames {
            assert_eq!(first[f * px..(f + 1) * px], first[..px], "frame {f} at the spawn");
        }
        let mut seen = vec![first[(frames - 1) * px..frames * px].to_vec()];
        for t in 0..8 {
            env.step(&[(t % 2) as u8, 1]).unwrap();
            let row = &env.observations()[..n];
            seen.push(row[(frames - 1) * px..frames * px].to_vec());
            for f in 0..frames {
                // Frame f is the view (frames − 1 − f) × stride steps ago
                // (the first view while the episode is younger).
                let back = (seen.len() - 1).saturating_sub((frames - 1 - f) * stride);
                let at = format!("frames {frames}, stride {stride}, t {t}, frame {f}");
                assert_eq!(&row[f * px..(f + 1) * px], &seen[back][..], "{at}");
            }
        }
        assert_ne!(seen[0], seen[8], "the view changes as the drone flies");
        let mut depth = vec![0.0; 2 * frames * px];
        let mut vel = vec![0.0; 2 * 3];
        env.write_observations_split(&mut depth, &mut vel);
        assert_eq!(&depth[..frames * px], &env.observations()[..frames * px]);
        env.reset_agents(&[true, false]).unwrap();
        let row = &env.observations()[..n];
        for f in 0..frames - 1 {
            assert_eq!(row[f * px..(f + 1) * px], row[(frames - 1) * px..frames * px]);
        }
    }
}

/// A camera with latency sees the moving obstacles where they were when
/// its late frame was taken, not where they are: a hovering drone's frame
/// with 0.2 s of latency at t = 1 s is the frame that a camera without
/// latency takes at t = 0.8 s, and not the one at 1 s.
#[test]
fn a_late_camera_sees_the_movers_where_they_were() {
    let mut mover = Obstacle::still_box([8.0, -3.0, 3.0], [0.3, 0.5, 3.0]);
    mover.set_motion(Some(Motion::Segment { offset: [0.0, 6.0], speed: 5.0, phase: 0.0 }));
    let arena = open_arena(30.0, vec![mover]);
    for renderer in [RendererKind::Cpu, RendererKind::Wgpu] {
        let hover = |period: f32, latency: f32| {
            let noise = Noise { latency_s: [latency, latency], ..Noise::default() };
            let sim = SimConfig {
                forward_speed: 0.0,
                action_period: period,
                noise,
                hold_action: true,
                renderer,
                ..cfg(1)
            };
            VecEnv::new(sim, arena.clone(), 4).unwrap()
        };
        let frame = |env: &VecEnv| env.observations()[1024..2048].to_vec();
        let diff = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>();
        // Action 2 holds the setpoint at 0: both drones hover where they
        // spawned.
        let mut late = hover(1.0, 0.2);
        late.step(&[2]).unwrap();
        let mut now = hover(0.2, 0.0);
        let mut frames = Vec::new();
        for _ in 0..5 {
            now.step(&[2]).unwrap();
            frames.push(frame(&now));
        }
        let (then, at_one) = (diff(&frame(&late), &frames[3]), diff(&frame(&late), &frames[4]));
        assert!(diff(&frames[3], &frames[4]) > 5.0, "{renderer:?}: the mover moves in view");
        assert!(
            then * 5.0 < at_one,
            "{renderer:?}: late frame against 0.8 s: {then}, against 1 s: {at_one}"
        );
    }
}

#[test]
fn next_step_autoreset_starts_the_next_episode_one_step_later() {
    let arena = open_arena(100.0, vec![]);
    let mut env = VecEnv::new(SimConfig { max_steps: 3, ..cfg(2) }, arena, 3).unwrap();
    env.set_autoreset(Autoreset::NextStep);
    let n = env.obs_len();
    let px = 32 * 32;
    for _ in 0..3 {
        env.step(&[1, 0]).unwrap();
    }
    assert_eq!(env.dones(), &[Done::Timeout, Done::Timeout]);
    // The ending step shows the episode's last view, not a fresh spawn's.
    let obs = env.observations();
    assert_ne!(&obs[..px], &obs[px..2 * px]);
    env.step(&[1, 1]).unwrap();
    assert_eq!(env.dones(), &[Done::Running, Done::Running]);
    assert_eq!(env.rewards(), &[0.0, 0.0]);
    assert!(env.finished().is_empty());
    let obs = env.observations();
    for i in 0..2 {
        let o = &obs[i * n..(i + 1) * n];
        assert_eq!(&o[..px], &o[px..2 * px], "agent {i} starts with both frames its first view");
        assert!((o[2 * px] - 1.0).abs() < 1e-6, "at the forward speed");
    }
    // And its next episode counts from there: three more steps end it.
    env.step(&[1, 0]).unwrap();
    env.step(&[1, 0]).unwrap();
    assert_eq!(env.dones(), &[Done::Running, Done::Running]);
    env.step(&[1, 0]).unwrap();
    assert_eq!(env.dones(), &[Done::Timeout, Done::Timeout]);
}

#[test]
fn randomised_dynamics_vary_per_drone_and_are_off_by_default() {
    use rotorhive_sim::Randomize;
    let fly = |r: Randomize| {
        let mut env =
            VecEnv::new(SimConfig { randomize: r, ..cfg(20) }, open_arena(200.0, vec![]), 3)
                .unwrap();
        for t in 0..8 {
            env.step(&[(t % 2) as u8; 20]).unwrap();
        }
        env.positions()
    };
    let x_spread = |p: &[[f32; 3]]| {
        p.iter().map(|q| q[0]).fold(f32::MIN, f32::max)
            - p.iter().map(|q| q[0]).fold(f32::MAX, f32::min)
    };
    // Off: every drone flies the same course (same actions, same spawn x).
    assert!(x_spread(&fly(Randomize::default())) < 1e-3);
    // Forward speeds of 0.8-1.5 m/s: after 8 s their x differ by metres.
    let spread =
        x_spread(&fly(Randomize { forward_speed_scale: [0.8, 1.5], ..Randomize::default() }));
    assert!(spread > 2.0, "x spread {spread}");
    // Wind alone pushes drones sideways apart.
    let p = fly(Randomize { wind: 0.5, ..Randomize::default() });
    let y: Vec<f32> = p.iter().map(|q| q[1]).collect();
    let y_spread =
        y.iter().copied().fold(f32::MIN, f32::max) - y.iter().copied().fold(f32::MAX, f32::min);
    assert!(y_spread > 0.2, "y spread {y_spread}");
}

#[test]
fn a_new_world_ends_every_flight_as_a_timeout_and_starts_the_next_in_it() {
    let mut env = VecEnv::new(cfg(4), open_arena(100.0, vec![]), 1).unwrap();
    env.step(&[0, 1, 0, 1]).unwrap();
    // The next world has a wall across the corridor at x = 10.
    let wall = Obstacle::still_box([10.0, 0.0, 4.0], [0.3, 10.0, 4.0]);
    env.replace_arenas(&[open_arena(100.0, vec![wall])]).unwrap();
    env.step(&[0, 1, 0, 1]).unwrap();
    assert!(env.dones().iter().all(|d| *d == Done::Timeout), "{:?}", env.dones());
    assert_eq!(env.finished().len(), 4);
    assert!(env.finished().iter().all(|e| e.steps == 2 && e.reward == 3.0 - 10.0));
    // Everyone starts again at the spawn and meets the new wall.
    assert!(env.positions().iter().all(|p| p[0] < 3.0));
    let mut hit = 0;
    for t in 0..12 {
        env.step(&[(t % 2) as u8; 4]).unwrap();
        hit += env.finished().iter().filter(|e| e.done == Done::Collision).count();
    }
    assert_eq!(hit, 4, "every drone flies into the new wall");
}

/// Fresh layouts: lanes are renewed with new arenas as episodes end, never
/// under an agent in flight (no episode is cut short as a timeout), and
/// two environments of one seed renew the same lanes at the same steps
/// (the builder thread's timing never shows).
#[test]
fn fresh_layouts_renew_lanes_without_cutting_an_episode_and_reproducibly() {
    let box_at = |x: f32| Obstacle::still_box([x, 0.0, 4.0], [0.5, 1.0, 4.0]);
    let arenas: Vec<Arena> =
        (0..3).map(|k| open_arena(40.0, vec![box_at(20.0 + k as f32)])).collect();
    let c = SimConfig { max_steps: 25, ..cfg(8) };
    let start = |seed| {
        let mut env = VecEnv::new_lanes(c.clone(), &arenas, seed).unwrap();
        let make = move |n: u64| open_arena(40.0, vec![box_at(10.0 + (n % 20) as f32)]);
        env.renew_lanes(4, 0, arenas.clone(), Box::new(make)).unwrap();
        env
    };
    let (mut a, mut b) = (start(5), start(5));
    let first = a.arena().obstacles.clone();
    let mut renewals = Vec::new();
    for step in 0..600u32 {
        let actions: Vec<u8> = (0..8u32).map(|i| ((step / 3 + i) % 2) as u8).collect();
        a.step(&actions).unwrap();
        b.step(&actions).unwrap();
        assert_eq!(a.observations(), b.observations(), "step {step}");
        assert_eq!(a.fresh_stats().renewed, b.fresh_stats().renewed, "step {step}");
        for e in a.finished() {
            assert!(
                e.done != Done::Timeout || e.steps == 25,
                "an episode cut short at step {step}: {e:?}"
            );
        }
        renewals.push(a.fresh_stats().renewed);
    }
    let renewed = a.fresh_stats().renewed;
    assert!(renewed >= 5, "{renewed} lanes renewed in 600 steps");
    assert_ne!(a.arena().obstacles, first, "the world holds the new layouts");
    assert!(renewals.windows(2).all(|w| w[1] <= w[0] + 1), "one lane at a time");
    // The rapier pipeline keeps its drones in its world: refused by name.
    let rapier = SimConfig { physics: PhysicsKind::Rapier, ..c.clone() };
    let mut env = VecEnv::new_lanes(rapier, &arenas, 1).unwrap();
    let e =
        env.renew_lanes(4, 0, arenas.clone(), Box::new(|_| open_arena(40.0, vec![]))).unwrap_err();
    assert!(e.to_string().contains("direct physics"), "{e}");
}

/// `sight_rays`: a planner of the pixels told by more rays than the
/// camera's 32 a side knows a thin pole far ahead that falls between the
/// camera's rays; the observation keeps its 32 × 32 pixels.
#[test]
fn more_sight_rays_show_a_thin_pole_between_the_cameras_rays() {
    // 15 m ahead on the axis: the camera's two middle rays pass 0.37 m to
    // either side of it, 256 rays' middle ones 0.05 m.
    let pole = Obstacle::still_box([17.0, 0.0, 3.0], [0.1, 0.1, 3.0]);
    let side = Obstacle::still_box([10.0, 3.0, 3.0], [0.5, 0.5, 3.0]);
    let arena = open_arena(40.0, vec![pole, side]);
    let camera = VecEnv::new(cfg(1), arena.clone(), 1).unwrap();
    assert_eq!(camera.visible_obstacles(0), vec![1]);
    let rays = VecEnv::new(SimConfig { sight_rays: 256, ..cfg(1) }, arena, 1).unwrap();
    assert_eq!(rays.visible_obstacles(0), vec![0, 1]);
    assert_eq!(rays.obs_len(), camera.obs_len());
}
