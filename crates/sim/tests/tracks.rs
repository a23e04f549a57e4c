//! The seen movers (`[sim.tracks]`): a mover is tracked only once a ray of
//! the agent's own frame met it, its velocity is what its sightings show,
//! nothing of a sighting's future is known, tracks expire after `keep_s`
//! and start empty each episode, and they enter the observation after the
//! map, nearest first.

use rotorhive_sim::map::{MapEncoding, MapSpec};
use rotorhive_sim::tracks::{TRACK_FLOATS, UNSEEN_REACH_M};
use rotorhive_sim::{Arena, Motion, Obstacle, SimConfig, Spawn, TrackSpec, VecEnv};

/// A wide still box `a` at x 9.5-10.5; hidden behind it from the spawn at
/// (2, 0), a mover `b` at x 16 going back and forth across y = 0; in the
/// open to the left, a mover `c` at x 8 going along y from 3.5 over 2 m at
/// 0.5 m/s.
fn arena() -> Arena {
    let moving = |center: [f32; 3], half: [f32; 3], offset: [f32; 2]| Obstacle::Box {
        center,
        half_extents: half,
        motion: Some(Motion::Segment { offset, speed: 0.5, phase: 0.0 }),
    };
    Arena {
        name: "movers".into(),
        length: 100.0,
        width: 20.0,
        height: 8.0,
        spawn: Spawn { x: 2.0, y: [0.0, 0.0], z: 3.0 },
        obstacles: vec![
            Obstacle::still_box([10.0, 0.0, 4.0], [0.5, 1.0, 4.0]),
            moving([16.0, -0.4, 4.0], [0.3, 0.3, 4.0], [0.0, 0.8]),
            moving([8.0, 3.5, 4.0], [0.3, 0.3, 4.0], [0.0, 2.0]),
        ],
    }
}

const B: usize = 1;
const C: usize = 2;

fn env(count: usize, keep_s: f32, map: bool) -> VecEnv {
    let tracks = TrackSpec { count, keep_s, ..TrackSpec::default() };
    let map = if map {
        MapSpec { encoding: MapEncoding::Rays, ..MapSpec::default() }
    } else {
        MapSpec::default()
    };
    let cfg = SimConfig { agents: 1, forward_speed: 0.0, tracks, map, ..SimConfig::default() };
    VecEnv::new(cfg, arena(), 1).unwrap()
}

/// Where mover `k` of the arena is at time `t` (x, y).
fn truth(env: &VecEnv, k: usize, t: f64) -> [f32; 2] {
    let c = env.arena().obstacles[k].at(t).center();
    [c[0], c[1]]
}

/// Keeps the drone at the spawn, facing along x, for one step.
fn hold(env: &mut VecEnv, at: [f32; 3]) {
    env.place(0, at, [0.0; 3]);
    env.step(&[0]).unwrap();
}

#[test]
fn a_mover_is_tracked_only_once_a_ray_met_it() {
    let mut env = env(3, 10.0, false);
    let seen: Vec<usize> = env.tracks_of(0).iter().map(|t| t.obstacle).collect();
    assert_eq!(seen, [C], "c is in view; b is behind a");
    for _ in 0..3 {
        hold(&mut env, [2.0, 0.0, 3.0]);
        assert!(env.tracks_of(0).iter().all(|t| t.obstacle != B), "b is never met from here");
    }
    // From the side, b comes into view.
    hold(&mut env, [2.0, 5.0, 3.0]);
    let seen: Vec<usize> = env.tracks_of(0).iter().map(|t| t.obstacle).collect();
    assert!(seen.contains(&B), "b is seen from the side: {seen:?}");
    // A new episode starts with none.
    env.reset_agents(&[true]).unwrap();
    assert!(env.tracks_of(0).iter().all(|t| t.obstacle != B), "a new episode forgets b");
}

/// Whether two points are within 0.1 mm of each other.
fn same(a: [f32; 2], b: [f32; 2]) -> bool {
    (a[0] - b[0]).abs() < 1e-4 && (a[1] - b[1]).abs() < 1e-4
}

#[test]
fn a_tracked_velocity_is_what_the_sightings_show_and_nothing_later() {
    let mut env = env(3, 10.0, false);
    let mut turned = false;
    // c goes 2 m at 0.5 m/s: at the far end at four seconds, back at its
    // start at eight, at 4.5 m going out again at ten.
    for step in 0..10 {
        hold(&mut env, [2.0, 0.0, 3.0]);
        let t = env.time();
        let c = env.tracks_of(0).iter().find(|tr| tr.obstacle == C).expect("c stays in view");
        // The last sighting is now, where c is now: nothing of its future.
        assert_eq!(c.last_t, t);
        assert!(same(c.last, truth(&env, C, t)), "step {step}: {:?}", c.last);
        let (prev, pt) = c.previous().expect("seen before");
        assert!(same(prev, truth(&env, C, pt)));
        let v = c.velocity.expect("sightings one second apart give a velocity");
        let dt = (t - pt) as f32;
        let shown = [(c.last[0] - prev[0]) / dt, (c.last[1] - prev[1]) / dt];
        assert!(same(v, shown), "{v:?} against {shown:?}");
        turned |= v[1] < 0.0;
        assert_eq!(c.turned(), turned, "step {step}");
        // Predicted as moving from the second sighting on: towards an end
        // it was never seen to turn at, as it goes while it goes on (the
        // prediction turns 0.5 m beyond where it was last seen; c turns at
        // 4 and 8 s); once seen to turn at both ends, where it goes after.
        let predicted = c.predicted(&env.arena().obstacles[C].at(t), UNSEEN_REACH_M);
        assert!(predicted.motion().is_some(), "step {step}");
        let ahead: &[f64] = match t {
            t if t + 1.0 <= 4.0 || (5.0..=7.0).contains(&t) => &[0.0, 0.5, 1.0],
            t if t >= 9.0 => &[0.0, 1.0, 2.5, 6.0, 9.0],
            _ => &[0.0],
        };
        for &dt in ahead {
            let (p, want) = (predicted.at(t + dt).center(), truth(&env, C, t + dt));
            let near = (p[0] - want[0]).abs() < 1e-3 && (p[1] - want[1]).abs() < 1e-3;
            assert!(near, "step {step}, {dt} s on: {p:?} against {want:?}");
        }
    }
    assert!(turned, "c was seen to turn");
    // Its stretch is the segment it was seen on.
    let c = env.tracks_of(0).iter().find(|tr| tr.obstacle == C).unwrap();
    assert!((c.lo[1] - 3.5).abs() < 1e-4 && (c.hi[1] - 5.5).abs() < 1e-4, "{:?}", (c.lo, c.hi));
    // A planner of the track predicts c where its last sighting puts it
    // and, seen to turn at both ends, where it goes after.
    let seen = env.arena().obstacles[C].at(c.last_t);
    let predicted = c.predicted(&seen, UNSEEN_REACH_M);
    for dt in [0.0, 1.0, 2.5, 6.0, 9.0] {
        let t = c.last_t + dt;
        let p = predicted.at(t).center();
        let want = truth(&env, C, t);
        assert!(
            (p[0] - want[0]).abs() < 1e-3 && (p[1] - want[1]).abs() < 1e-3,
            "{dt} s after its last sighting: {p:?} against {want:?}"
        );
    }
}

#[test]
fn tracks_expire_after_keep_s() {
    let mut env = env(3, 1.5, false);
    assert_eq!(env.tracks_of(0).len(), 1);
    // Far past every obstacle, nothing is in view.
    hold(&mut env, [60.0, 0.0, 3.0]);
    assert_eq!(env.tracks_of(0).len(), 1, "one second unseen: kept");
    hold(&mut env, [60.0, 0.0, 3.0]);
    assert!(env.tracks_of(0).is_empty(), "two seconds unseen: forgotten");
    let obs = env.observations();
    assert!(obs[obs.len() - 3 * TRACK_FLOATS..].iter().all(|v| *v == 0.0));
}

#[test]
fn the_observation_reads_the_tracks_after_the_map_nearest_first() {
    let mut env = env(3, 10.0, true);
    hold(&mut env, [2.0, 5.0, 3.0]);
    let floats = 3 * TRACK_FLOATS;
    assert_eq!(env.config().shapes().tracks, floats);
    assert_eq!(env.obs_len(), 2 * 32 * 32 + 3 + 72 + floats);
    let obs = env.observations();
    let tracks = &obs[obs.len() - floats..];
    let mut written = vec![0.0; floats];
    env.write_tracks(0, &mut written);
    assert_eq!(tracks, &written[..]);
    let rows: Vec<&[f32]> = tracks.chunks(TRACK_FLOATS).collect();
    // c (about 6 m away) before b (about 14 m), then nothing.
    assert_eq!((rows[0][0], rows[1][0], rows[2][0]), (1.0, 1.0, 0.0));
    assert!(rows[2].iter().all(|v| *v == 0.0));
    let c = truth(&env, C, env.time());
    let d = env.positions()[0];
    // Ahead and to the side, in tens of metres (the drone faces along x).
    assert!((rows[0][1] - (c[0] - d[0]) / 10.0).abs() < 0.02, "{}", rows[0][1]);
    assert!((rows[0][2] - (c[1] - d[1]) / 10.0).abs() < 0.02, "{}", rows[0][2]);
    assert!(rows[1][1] > rows[0][1], "b is farther ahead");
    // The map's floats sit before the tracks, as they do without them.
    let mut map = vec![0.0; 72];
    env.write_map(0, &mut map);
    assert_eq!(&obs[obs.len() - floats - 72..obs.len() - floats], &map[..]);
    // Without tracks, the observation is as ever.
    assert_eq!(VecEnv::new(SimConfig::default(), arena(), 1).unwrap().obs_len(), 2 * 32 * 32 + 3);
}

#[test]
fn a_tracked_movers_hits_stay_out_of_the_map() {
    // Where c is now, as a floor-plan rectangle.
    let footprint = |env: &VecEnv| {
        let c = truth(env, C, env.time());
        ([c[0] - 0.3, c[1] - 0.3], [c[0] + 0.3, c[1] + 0.3])
    };
    let (mut tracked, mut mapped_only) = (env(3, 10.0, true), env(0, 10.0, true));
    assert!(tracked.tracks_movers() && !mapped_only.tracks_movers());
    for step in 0..4 {
        hold(&mut tracked, [2.0, 0.0, 3.0]);
        hold(&mut mapped_only, [2.0, 0.0, 3.0]);
        let (lo, hi) = footprint(&tracked);
        assert!(tracked.tracks_of(0).iter().any(|t| t.obstacle == C), "step {step}: c tracked");
        assert!(!tracked.map_shows(0, lo, hi), "step {step}: c is in the tracks, not the map");
        assert!(mapped_only.map_shows(0, lo, hi), "step {step}: untracked, c is in the map");
        // The still box stays in the map.
        assert!(tracked.map_shows(0, [9.5, -1.0], [10.5, 1.0]), "step {step}: a is mapped");
    }
}

#[test]
fn bad_track_settings_are_refused_by_key() {
    let bad = [
        TrackSpec { count: 33, ..TrackSpec::default() },
        TrackSpec { keep_s: 0.0, ..TrackSpec::default() },
        TrackSpec { keep_s: f32::NAN, ..TrackSpec::default() },
        TrackSpec { band: 5000, ..TrackSpec::default() },
        TrackSpec { unseen_reach_m: -0.1, ..TrackSpec::default() },
        TrackSpec { unseen_reach_m: f32::INFINITY, ..TrackSpec::default() },
    ];
    let keys: Vec<&str> = bad.iter().map(|s| s.validate().unwrap_err().0).collect();
    assert_eq!(keys, ["count", "keep_s", "keep_s", "band", "unseen_reach_m", "unseen_reach_m"]);
    assert!(TrackSpec::default().validate().is_ok());
    assert!(!TrackSpec::default().enabled());
}

#[test]
fn tracked_runs_are_the_same_bits_for_a_seed() {
    let run = || {
        let mut env = env(3, 10.0, true);
        for k in 0..6 {
            env.step(&[(k % 2) as u8]).unwrap();
        }
        env.observations().to_vec()
    };
    assert_eq!(run(), run());
}

#[test]
fn the_nearest_mover_is_the_truths_at_the_worlds_time() {
    let mut env = env(3, 10.0, false);
    for at in [[2.0, 0.0, 3.0], [8.0, 1.0, 3.0], [15.0, -2.0, 3.0]] {
        hold(&mut env, at);
        let (t, p) = (env.time(), env.positions()[0]);
        // The distance in x and y from the drone to each mover's box
        // (both 0.3 m a half side), where the arena's clock puts it.
        let to = |k: usize| {
            let c = truth(&env, k, t);
            let dx = ((c[0] - p[0]).abs() - 0.3).max(0.0);
            let dy = ((c[1] - p[1]).abs() - 0.3).max(0.0);
            dx.hypot(dy)
        };
        let want = if to(B) < to(C) { (B, to(B)) } else { (C, to(C)) };
        let (k, d) = env.nearest_mover(0).expect("the arena has movers");
        assert_eq!(k, want.0, "from {at:?} at {t} s");
        assert!((d - want.1).abs() < 1e-4, "from {at:?}: {d} against {}", want.1);
    }
    // The still box is no mover; an arena without movers has none.
    let cfg = SimConfig { agents: 1, forward_speed: 0.0, ..SimConfig::default() };
    let still = Arena { obstacles: vec![arena().obstacles[0].clone()], ..arena() };
    assert_eq!(VecEnv::new(cfg, still, 1).unwrap().nearest_mover(0), None);
}

/// Ray `k` of `rays` (counter-clockwise from +x: the drone faces along x)
/// from `p` to the first of the true boxes `boxes` (centre, half sides),
/// as a share of `range` (1: none within it): worked out here by marching
/// in 1 mm steps, independent of the environment's slab test.
fn marched(p: [f32; 2], k: usize, rays: usize, boxes: &[([f32; 2], f32)], range: f32) -> f32 {
    let a = std::f32::consts::TAU * k as f32 / rays as f32;
    let (dx, dy) = (a.cos(), a.sin());
    let steps = (range * 1000.0) as usize;
    (0..steps)
        .map(|s| s as f32 / 1000.0)
        .find(|&r| {
            let (x, y) = (p[0] + r * dx, p[1] + r * dy);
            boxes.iter().any(|(c, h)| (x - c[0]).abs() <= *h && (y - c[1]).abs() <= *h)
        })
        .map_or(1.0, |r| r / range)
}

#[test]
fn the_rays_through_the_movers_ahead_meet_them_where_they_will_be_once_watched() {
    let (rays, range, ahead) = (72, 20.0, [0.0f32, 2.0]);
    let map = MapSpec {
        encoding: MapEncoding::Rays,
        rays,
        ray_range_m: range,
        movers_ahead_s: ahead.to_vec(),
        ..MapSpec::default()
    };
    let tracks = TrackSpec { count: 3, ..TrackSpec::default() };
    let cfg = SimConfig { agents: 1, forward_speed: 0.0, tracks, map, ..SimConfig::default() };
    let mut env = VecEnv::new(cfg, arena(), 1).unwrap();
    assert_eq!(env.config().shapes().map, 4 * rays, "the map's two sets, then one a time ahead");
    assert_eq!(env.obs_len(), 2 * 32 * 32 + 3 + 4 * rays + 3 * TRACK_FLOATS);
    let (mut met_b, mut met_c) = (0, 0);
    // c turns at 4 and 8 s (see above): from 9 s on its track predicts it
    // exactly, so the rays ahead read where the truth puts it.
    for step in 0..12 {
        hold(&mut env, [2.0, 0.0, 3.0]);
        let (t, d) = (env.time(), env.positions()[0]);
        let mut out = vec![0.0; 4 * rays];
        env.write_map(0, &mut out);
        let obs = env.observations();
        let at = obs.len() - 3 * TRACK_FLOATS - 4 * rays;
        assert_eq!(&obs[at..at + 4 * rays], &out[..], "the observation holds them");
        for (h, set) in ahead.iter().zip(out[2 * rays..].chunks(rays)) {
            let when = t + f64::from(*h);
            let (b, c) = ((truth(&env, B, when), 0.3), (truth(&env, C, when), 0.3));
            // b, behind a from here, is never met: nothing of it is known.
            met_b += usize::from(marched([d[0], d[1]], 0, rays, &[b, c], range) < 1.0);
            assert_eq!(set[0], 1.0, "step {step}, {h} s ahead: b is unseen");
            if t >= 9.0 {
                for (k, got) in set.iter().enumerate() {
                    let want = marched([d[0], d[1]], k, rays, &[c], range);
                    assert!(
                        (got - want).abs() < 2e-4,
                        "step {step}, {h} s, ray {k}: {got} / {want}"
                    );
                }
            }
        }
        met_c += usize::from(out[2 * rays..].iter().any(|v| *v < 1.0));
    }
    assert!(met_b > 0, "the truth's b crosses ray 0: the test can see it");
    assert!(met_c >= 6, "c is met at {met_c} steps of 12");
    // A new episode forgets them all.
    env.reset_agents(&[true]).unwrap();
    hold(&mut env, [60.0, 0.0, 3.0]);
    let mut out = vec![0.0; 4 * rays];
    env.write_map(0, &mut out);
    assert!(out[2 * rays..].iter().all(|v| *v == 1.0), "nothing tracked, nothing met");
}

#[test]
fn rays_ahead_without_tracks_or_rays_are_refused_by_key() {
    let ahead =
        MapSpec { encoding: MapEncoding::Grid, movers_ahead_s: vec![1.0], ..MapSpec::default() };
    assert_eq!(ahead.validate().unwrap_err().0, "movers_ahead_s");
    for bad in [vec![-1.0], vec![f32::NAN], vec![1.0; 9]] {
        let s = MapSpec { encoding: MapEncoding::Rays, movers_ahead_s: bad, ..MapSpec::default() };
        assert_eq!(s.validate().unwrap_err().0, "movers_ahead_s");
    }
    // Without a map they are read by nothing (an evaluation turns L4's
    // map off so): not refused, no floats.
    let off = MapSpec { movers_ahead_s: vec![1.0], ..MapSpec::default() };
    assert_eq!((off.validate(), off.floats()), (Ok(()), 0));
    let fine = MapSpec {
        encoding: MapEncoding::Rays,
        movers_ahead_s: vec![0.0, 30.0],
        ..MapSpec::default()
    };
    assert!(fine.validate().is_ok());
    assert_eq!(fine.floats(), 4 * 36);
}
