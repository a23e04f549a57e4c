//! The camera's map (`[sim.map]`): it holds only what the agent's own rays
//! met, tells walls from obstacles, forgets sightings after `keep_s`, starts
//! empty each episode, and enters the observation after the velocity.

use rotorhive_sim::map::{Cell, MapEncoding, MapSpec};
use rotorhive_sim::{Arena, Obstacle, SimConfig, Spawn, VecEnv};

/// A wide box `a` at x 9.5-10.5 and, hidden behind it from the spawn at
/// (2, 0), a narrow one `b` at x 15.5-16.5.
fn arena() -> Arena {
    Arena {
        name: "behind".into(),
        length: 100.0,
        width: 20.0,
        height: 8.0,
        spawn: Spawn { x: 2.0, y: [0.0, 0.0], z: 3.0 },
        obstacles: vec![
            Obstacle::still_box([10.0, 0.0, 4.0], [0.5, 1.0, 4.0]),
            Obstacle::still_box([16.0, 0.0, 4.0], [0.5, 0.5, 4.0]),
        ],
    }
}

fn env(encoding: MapEncoding, keep_s: f32) -> VecEnv {
    let map = MapSpec { encoding, keep_s, ..MapSpec::default() };
    let cfg = SimConfig { agents: 1, forward_speed: 0.0, map, ..SimConfig::default() };
    VecEnv::new(cfg, arena(), 1).unwrap()
}

/// Whether any cell within `r` m of `(x, y)` (on the map's half-cell
/// lattice) holds `want`.
fn near(env: &VecEnv, x: f32, y: f32, r: f32, want: Cell) -> bool {
    let k = (r / 0.25) as i32;
    (-k..=k).any(|i| {
        (-k..=k).any(|j| env.map_cell(0, x + i as f32 * 0.25, y + j as f32 * 0.25) == Some(want))
    })
}

#[test]
fn the_map_holds_what_a_ray_met_and_nothing_behind_it() {
    let mut env = env(MapEncoding::Rays, 0.0);
    // The front face of `a` was met; the cells before it were crossed.
    assert!(near(&env, 9.5, 0.0, 0.25, Cell::Obstacle), "a's front face is in the map");
    for x in [3.0, 5.0, 7.0, 8.5] {
        assert_eq!(env.map_cell(0, x, 0.0), Some(Cell::Free), "a crossed cell at x = {x}");
    }
    // `b` is behind `a`: no ray met it, so nothing of it is known.
    assert!(!near(&env, 16.0, 0.0, 0.75, Cell::Obstacle), "b is unseen");
    assert_eq!(env.map_cell(0, 16.0, 0.0), Some(Cell::Unknown));
    // Nothing behind the camera, nor beyond the walls, was seen.
    assert_eq!(env.map_cell(0, 0.5, 0.0), Some(Cell::Unknown));
    // The walls, met at 45 degrees, are walls, not obstacles.
    assert!(near(&env, 12.0, 10.0, 0.5, Cell::Wall), "the left wall is known as a wall");
    assert!(near(&env, 12.0, -10.0, 0.5, Cell::Wall), "the right wall is known as a wall");
    assert!(!near(&env, 12.0, 9.5, 0.5, Cell::Obstacle), "a wall is never an obstacle");

    // From the side, `b` comes into view; `a`'s sighting stays (keep_s 0).
    env.place(0, [2.0, 5.0, 3.0], [0.0, 0.0, 0.0]);
    env.step(&[0]).unwrap();
    assert!(near(&env, 16.0, 0.0, 0.75, Cell::Obstacle), "b is seen from the side");
    assert!(near(&env, 9.5, 0.0, 0.25, Cell::Obstacle), "a is remembered");

    // A new episode starts with an empty map.
    env.reset_agents(&[true]).unwrap();
    assert!(!near(&env, 16.0, 0.0, 0.75, Cell::Obstacle), "a new episode forgets b");
}

#[test]
fn a_sighting_expires_after_keep_s_and_stays_without_it() {
    for (keep, remembered) in [(1.0, false), (0.0, true)] {
        let mut env = env(MapEncoding::Grid, keep);
        assert!(near(&env, 9.5, 0.0, 0.25, Cell::Obstacle));
        // Where `a` is outside the camera's view.
        env.place(0, [9.0, 9.0, 3.0], [0.0, 0.0, 0.0]);
        env.step(&[0]).unwrap();
        env.step(&[1]).unwrap();
        assert_eq!(
            near(&env, 9.5, 0.0, 0.25, Cell::Obstacle),
            remembered,
            "keep_s {keep}: a's sighting two frames old"
        );
    }
}

#[test]
fn the_observation_reads_the_map_after_the_velocity() {
    let env = env(MapEncoding::Rays, 0.0);
    let spec = MapSpec { encoding: MapEncoding::Rays, ..MapSpec::default() };
    let floats = spec.floats();
    assert_eq!(floats, 72);
    assert_eq!(env.obs_len(), 2 * 32 * 32 + 3 + floats);
    assert_eq!(env.config().shapes().map, floats);
    let obs = env.observations();
    let map = &obs[obs.len() - floats..];
    let (occupied, unknown) = map.split_at(36);
    // Straight ahead, `a` 7.5 m away (of a 10 m reach); behind, unknown at once.
    assert!((0.72..=0.8).contains(&occupied[0]), "ahead: {}", occupied[0]);
    assert_eq!(occupied[18], 1.0, "behind: nothing known to hit");
    assert!(unknown[18] < 0.05, "behind: unknown at once, {}", unknown[18]);
    // Every value is a share of the reach.
    assert!(map.iter().all(|v| (0.0..=1.0).contains(v)));
    // Without a map, the observation is as ever.
    let plain = VecEnv::new(SimConfig::default(), arena(), 1).unwrap();
    assert_eq!(plain.obs_len(), 2 * 32 * 32 + 3);
    assert_eq!(plain.map_bytes_per_agent(), 0);
    assert!(env.map_bytes_per_agent() > 0);
}

#[test]
fn bad_map_settings_are_refused_by_key() {
    let bad = [
        MapSpec { cell_m: 0.0, ..MapSpec::default() },
        MapSpec { window: 1, ..MapSpec::default() },
        MapSpec { rays: 2, ..MapSpec::default() },
        MapSpec { keep_s: -1.0, ..MapSpec::default() },
        MapSpec { ray_range_m: f32::NAN, ..MapSpec::default() },
    ];
    let keys: Vec<&str> = bad.iter().map(|s| s.validate().unwrap_err().0).collect();
    assert_eq!(keys, ["cell_m", "window", "rays", "keep_s", "ray_range_m"]);
    assert!(MapSpec::default().validate().is_ok());
}

#[test]
fn maps_are_the_same_bits_for_a_seed_whatever_the_threads() {
    // Forty agents on a generated layout with depth noise and dropout: the
    // maps (and so the observations) depend on the seed alone.
    let params = rotorhive_sim::GenParams::default();
    let arena = Arena::generate("map-threads", 7, &params);
    let run = |threads: usize| {
        let map = MapSpec { encoding: MapEncoding::Rays, ..MapSpec::default() };
        let noise =
            rotorhive_sim::Noise { depth_sigma: 0.01, dropout: 0.05, latency_s: [0.0, 0.2] };
        let cfg =
            SimConfig { agents: 40, render_threads: threads, map, noise, ..SimConfig::default() };
        let mut env = VecEnv::new(cfg, arena.clone(), 3).unwrap();
        for t in 0..30 {
            let actions: Vec<u8> = (0..40).map(|i| ((t * 7 + i * 3) / 4 % 2) as u8).collect();
            env.step(&actions).unwrap();
        }
        env.observations().to_vec()
    };
    let one = run(1);
    assert_eq!(one, run(1), "the same seed, the same bits");
    assert_eq!(one, run(2), "two threads build the same maps");
}
