//! Greedy evaluation: a policy flown without exploration for a number of
//! episodes, the success rate and mean reward; per held-out layout and
//! pooled, with Wilson intervals. The policy is a network's greedy choice
//! or the scripted reactive rule, the floor a learned policy must beat.
//! Used by `hive eval`, by the evaluator beside training and by `hive
//! bench seeds`.

use crate::error::Result;

mod record;
use record::Recorder;
pub use record::{
    Agreement, EpisodeLog, LAST_STEPS, LogSpec, NEAR_M, Near, Trap, agreement, traps,
};
use rotorhive_model::PolicyNet;
use rotorhive_sim::{Arena, Done, Planner, Sight, SimConfig, VecEnv};

/// What a greedy evaluation found.
#[derive(Debug, Clone, Copy)]
pub struct EvalStats {
    /// Episodes flown.
    pub episodes: usize,
    /// Episodes that reached the goal.
    pub successes: usize,
    /// Episodes that ended in a collision.
    pub collisions: usize,
    /// Mean episode return.
    pub mean_reward: f64,
    /// With the planner: episodes in which it found no way through from
    /// the spawn ([`Planner::hopeless_starts`]); 0 with other pilots.
    pub hopeless: usize,
}

impl EvalStats {
    /// Share of episodes that reached the goal.
    pub fn success_rate(&self) -> f64 {
        self.successes as f64 / self.episodes.max(1) as f64
    }

    /// The 95 % Wilson score interval of the success rate.
    pub fn wilson(&self) -> [f64; 2] {
        wilson(self.successes, self.episodes)
    }

    /// Several evaluations as one (pooled episodes).
    pub fn pooled(all: &[EvalStats]) -> EvalStats {
        let episodes: usize = all.iter().map(|s| s.episodes).sum();
        let reward: f64 = all.iter().map(|s| s.mean_reward * s.episodes as f64).sum();
        EvalStats {
            episodes,
            successes: all.iter().map(|s| s.successes).sum(),
            collisions: all.iter().map(|s| s.collisions).sum(),
            mean_reward: reward / episodes.max(1) as f64,
            hopeless: all.iter().map(|s| s.hopeless).sum(),
        }
    }
}

/// The spread of a policy over layouts: the quartiles `[q1, median, q3]`
/// of per-layout success (linear between order statistics, as numpy's
/// default) and how many layouts it flies under 50 %; layouts without
/// episodes left out.
pub fn layout_spread(stats: &[EvalStats]) -> ([f64; 3], usize) {
    let mut v: Vec<f64> =
        stats.iter().filter(|s| s.episodes > 0).map(EvalStats::success_rate).collect();
    v.sort_by(f64::total_cmp);
    let under = v.iter().filter(|x| **x < 0.5).count();
    let q = |p: f64| {
        if v.is_empty() {
            return f64::NAN;
        }
        let h = p * (v.len() - 1) as f64;
        let (lo, hi) = (h.floor() as usize, h.ceil() as usize);
        v[lo] + (v[hi] - v[lo]) * (h - lo as f64)
    };
    ([q(0.25), q(0.5), q(0.75)], under)
}

/// The 95 % Wilson score interval of `k` successes in `n` trials.
pub fn wilson(k: usize, n: usize) -> [f64; 2] {
    if n == 0 {
        return [0.0, 1.0];
    }
    let (n, p, z) = (n as f64, k as f64 / n as f64, 1.959_964);
    let z2 = z * z;
    let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
    let half = z * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt() / (1.0 + z2 / n);
    [(centre - half).max(0.0), (centre + half).min(1.0)]
}

/// A freshly initialised network of `cfg`'s shapes and memory, on the CPU
/// (the evaluator's and the harness's, which load weights into it).
pub fn network_for(cfg: &crate::Config) -> Result<PolicyNet> {
    Ok(PolicyNet::new(cfg.shapes(), cfg.layers(), cfg.memory(), 0, &rotorhive_model::Device::Cpu)?)
}

/// Who flies: a network's greedy action, or the scripted reactive rule.
#[derive(Clone, Copy)]
pub enum Pilot<'a> {
    /// The greedy action of a policy network (one with memory carries each
    /// agent's state from step to step, zeroed where its episode starts).
    Net(&'a PolicyNet),
    /// [`reactive`]: steer toward the clearest columns of the depth image.
    Reactive,
    /// [`Planner`]: a search that knows every obstacle's motion
    /// ([`Sight::All`]; privileged: what it flies is a floor under what the
    /// episodes allow), or what the camera shows ([`Sight::View`],
    /// [`Sight::ViewVelocity`]).
    Planner(Sight),
}

impl Pilot<'_> {
    /// The actions of every agent for a batch of observations (rows of
    /// `obs_len` floats: `frames` depth frames of `depth` (rows, columns)
    /// pixels, the velocity).
    pub fn act(
        &self,
        obs: &[f32],
        obs_len: usize,
        depth: [usize; 2],
        frames: usize,
    ) -> Result<Vec<u8>> {
        match self {
            Pilot::Net(net) if net.state_width() == 0 => Ok(net.greedy(obs, &mut Vec::new())?),
            Pilot::Net(_) => Err(crate::error::RoleError::Config(
                "a network with memory flies with its state: see `fly`".into(),
            )),
            Pilot::Reactive => {
                Ok(obs.chunks_exact(obs_len).map(|o| reactive(o, depth, frames)).collect())
            }
            Pilot::Planner(_) => Err(crate::error::RoleError::Config(
                "the planner flies from the environment, not from observations".into(),
            )),
        }
    }
}

/// The reactive rule's settings: chosen on the paper's training arena
/// (87.6 % there, 88.2 % of `configs/arenas/test.toml`;
/// `shared/research/tasks/reactive_depth.py`, whose rule this is).
const REACTIVE_NEAR: f32 = 0.5;
/// Columns on each side that a column's clearance is the minimum over, of
/// 32 (a wider image's window is as wide a share of it).
const REACTIVE_WINDOW: usize = 4;
/// Lateral speed wanted per column of the target off the centre (m/s), of
/// 32 columns (scaled to the image's).
const REACTIVE_GAIN: f32 = 0.12;
/// With a goal: lateral speed wanted per metre of the goal's lateral
/// offset while the way ahead is clear (m/s per m, at most 1 m/s).
const REACTIVE_GOAL_GAIN: f32 = 0.3;

/// A scripted reactive policy on one observation (`frames` depth frames
/// of `depth` (rows, columns) pixels, the current one last, then the body
/// velocity): the
/// nearest depth of each column over the middle rows, widened to the
/// minimum over `REACTIVE_WINDOW` neighbours each side; when straight
/// ahead is nearer than `REACTIVE_NEAR` of the range, the lateral velocity
/// is pushed toward the clearest column, else toward zero (with a goal:
/// toward the goal's side). Action 1 raises the lateral setpoint, 0 lowers
/// it.
pub fn reactive(obs: &[f32], depth: [usize; 2], frames: usize) -> u8 {
    let (side, px) = (depth[1], depth[0] * depth[1]);
    let fd = frames * px;
    let nearest = nearest_per_column(&obs[fd - px..fd], depth);
    let scale = side as f32 / 32.0;
    let w = ((REACTIVE_WINDOW as f32 * scale).round() as usize).max(1);
    // Beyond the image's edges reads as an obstacle at 0.
    let clear: Vec<f32> = (0..side)
        .map(|c| {
            (c as isize - w as isize..=c as isize + w as isize)
                .map(|k| if k < 0 || k >= side as isize { 0.0 } else { nearest[k as usize] })
                .fold(f32::INFINITY, f32::min)
        })
        .collect();
    let mid = (side as f32 - 1.0) / 2.0;
    let mut target = 0;
    let mut best = f32::NEG_INFINITY;
    for (c, v) in clear.iter().enumerate() {
        let score = v - 0.002 * (c as f32 - mid).abs();
        if score > best {
            best = score;
            target = c;
        }
    }
    let centre = clear[side / 2 - 1].min(clear[side / 2]);
    // With a goal (its floats after the velocity), a clear way ahead
    // steers toward the goal's lateral offset instead of straight on.
    let cruise = match obs.get(fd + 5) {
        Some(lat) => (REACTIVE_GOAL_GAIN * 10.0 * lat).clamp(-1.0, 1.0),
        None => 0.0,
    };
    let gain = REACTIVE_GAIN / scale;
    let want = if centre > REACTIVE_NEAR { cruise } else { -gain * (target as f32 - mid) };
    let vy = obs[fd + 1];
    u8::from(want > vy)
}

/// The nearest depth of each column of one depth frame (`depth`: rows,
/// columns) over its middle rows (10 to 21 of 32): the clearance ahead per
/// direction, as the reactive rule reads it.
pub fn nearest_per_column(frame: &[f32], [height, width]: [usize; 2]) -> Vec<f32> {
    let rows = (height * 10 / 32)..(height * 22 / 32).max(height * 10 / 32 + 1);
    (0..width)
        .map(|c| rows.clone().map(|r| frame[r * width + c]).fold(f32::INFINITY, f32::min))
        .collect()
}

/// Flies `episodes` greedy episodes at once, one per agent, each agent's
/// first episode counted; with several arenas, side by side, each agent in
/// one drawn at random (the same ones for the same seed).
pub fn fly_greedy(
    net: &PolicyNet,
    sim: SimConfig,
    arenas: &[Arena],
    episodes: usize,
    seed: u64,
) -> Result<EvalStats> {
    fly(Pilot::Net(net), sim, arenas, episodes, seed)
}

/// [`fly_greedy`] with any pilot.
pub fn fly(
    pilot: Pilot<'_>,
    sim: SimConfig,
    arenas: &[Arena],
    episodes: usize,
    seed: u64,
) -> Result<EvalStats> {
    Ok(fly_logged(pilot, sim, arenas, episodes, seed, None)?.0)
}

/// [`fly`], keeping each episode's [`EpisodeLog`] where `log` asks for it
/// (paths and last steps, and with an auditor the planner's judgement of
/// every action). A logged flight flies the same first episodes as an
/// unlogged one: only a finished agent's restart waits a step, so that
/// where it ended can be read.
pub fn fly_logged(
    pilot: Pilot<'_>,
    sim: SimConfig,
    arenas: &[Arena],
    episodes: usize,
    seed: u64,
    log: Option<LogSpec>,
) -> Result<(EvalStats, Vec<EpisodeLog>)> {
    let n = episodes;
    let mut env = VecEnv::new_lanes(SimConfig { agents: n, ..sim }, arenas, seed)?;
    if log.is_some() {
        env.set_autoreset(rotorhive_sim::Autoreset::NextStep);
    }
    let mut result: Vec<Option<(f32, Done)>> = vec![None; n];
    let max_steps = env.config().max_steps;
    let (obs_len, depth, frames) =
        (env.obs_len(), env.config().camera.observed_depth(), env.config().frames);
    let mut planner = match pilot {
        Pilot::Planner(sight) => Some(Planner::new(&env, sight)),
        _ => None,
    };
    let mut recorder = log.map(|spec| Recorder::new(&env, spec));
    // A pilot's state per agent (a network with memory), zeroed where an
    // episode starts.
    let width = match pilot {
        Pilot::Net(net) => net.state_width(),
        _ => 0,
    };
    let mut state = vec![0.0f32; n * width];
    for _ in 0..max_steps + 1 {
        let active: Vec<bool> = result.iter().map(Option::is_none).collect();
        let actions = match (planner.as_mut(), pilot) {
            (Some(p), _) => p.actions(&env, &active),
            (None, Pilot::Net(net)) => net.greedy(env.observations(), &mut state)?,
            (None, _) => pilot.act(env.observations(), obs_len, depth, frames)?,
        };
        if let Some(r) = recorder.as_mut() {
            r.before(&env, &active, &actions);
        }
        env.step(&actions)?;
        for ep in env.finished() {
            result[ep.agent].get_or_insert((ep.reward, ep.done));
            state[ep.agent * width..(ep.agent + 1) * width].fill(0.0);
        }
        if let Some(r) = recorder.as_mut() {
            r.after(&env, &active);
        }
        if result.iter().all(Option::is_some) {
            break;
        }
    }
    let done: Vec<(f32, Done)> = result.into_iter().flatten().collect();
    let stats = EvalStats {
        episodes: n,
        successes: done.iter().filter(|(_, d)| *d == Done::Goal).count(),
        collisions: done.iter().filter(|(_, d)| *d == Done::Collision).count(),
        mean_reward: done.iter().map(|(r, _)| *r as f64).sum::<f64>() / done.len().max(1) as f64,
        hopeless: planner.map_or(0, |p| p.hopeless_starts()),
    };
    Ok((stats, recorder.map_or_else(Vec::new, Recorder::finish)))
}

/// `total` episodes spread over `layouts` layouts as evenly as they go:
/// every layout `total / layouts`, the first `total % layouts` one more.
pub fn spread(total: usize, layouts: usize) -> Vec<usize> {
    let (each, more) = (total / layouts.max(1), total % layouts.max(1));
    (0..layouts).map(|k| each + usize::from(k < more)).collect()
}

/// Flies `episodes` episodes in all, spread evenly over the layouts
/// ([`spread`]), every layout on its own (the held-out test set): one
/// result per layout, in order; a layout given no episode is not flown.
pub fn fly_layouts(
    pilot: Pilot<'_>,
    sim: &SimConfig,
    layouts: &[Arena],
    episodes: usize,
    seed: u64,
) -> Result<Vec<EvalStats>> {
    Ok(fly_layouts_logged(pilot, sim, layouts, episodes, seed, None)?
        .into_iter()
        .map(|(s, _)| s)
        .collect())
}

/// [`fly_layouts`] with each layout's [`EpisodeLog`]s where `log` asks.
pub fn fly_layouts_logged(
    pilot: Pilot<'_>,
    sim: &SimConfig,
    layouts: &[Arena],
    episodes: usize,
    seed: u64,
    log: Option<LogSpec>,
) -> Result<Vec<(EvalStats, Vec<EpisodeLog>)>> {
    layouts
        .iter()
        .zip(spread(episodes, layouts.len()))
        .enumerate()
        .map(|(k, (a, e))| {
            if e == 0 {
                return Ok((EvalStats::pooled(&[]), Vec::new()));
            }
            let seed = seed.wrapping_add(k as u64);
            fly_logged(pilot, sim.clone(), std::slice::from_ref(a), e, seed, log)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_intervals_match_the_textbook() {
        // 90 of 100: [0.826, 0.945]; 0 of 10: [0, 0.278].
        let [lo, hi] = wilson(90, 100);
        assert!((lo - 0.8256).abs() < 1e-3 && (hi - 0.9448).abs() < 1e-3, "{lo} {hi}");
        let [lo, hi] = wilson(0, 10);
        assert!(lo == 0.0 && (hi - 0.2775).abs() < 1e-3, "{hi}");
    }

    #[test]
    fn episodes_spread_over_layouts_exactly() {
        assert_eq!(spread(500, 50), vec![10; 50]);
        let s = spread(500, 64);
        assert_eq!(s.iter().sum::<usize>(), 500);
        assert_eq!((s[0], s[51], s[52], s[63]), (8, 8, 7, 7));
        assert_eq!(spread(3, 5), vec![1, 1, 1, 0, 0]);
        assert_eq!(spread(0, 2), vec![0, 0]);
    }

    #[test]
    fn the_spread_over_layouts_gives_quartiles_and_layouts_under_half() {
        let st = |k: usize| EvalStats {
            episodes: 10,
            successes: k,
            collisions: 10 - k,
            mean_reward: 0.0,
            hopeless: 0,
        };
        let empty = EvalStats::pooled(&[]);
        let (q, under) = layout_spread(&[st(9), st(2), st(5), st(4), st(10), empty]);
        // Sorted 0.2 0.4 0.5 0.9 1.0: q1 at 1, median at 2, q3 at 3.
        assert_eq!(under, 2);
        let want = [0.4, 0.5, 0.9];
        assert!(q.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12), "{q:?}");
        let (q, _) = layout_spread(&[st(0), st(10)]);
        assert!((q[0] - 0.25).abs() < 1e-12 && (q[2] - 0.75).abs() < 1e-12, "{q:?}");
    }

    #[test]
    fn the_reactive_rule_steers_toward_the_clear_side() {
        let side = 32;
        let px = side * side;
        // A wall ahead on the left half of the image (columns 0-19 near),
        // clear on the right: steer so that the target column is right of
        // the centre, i.e. a negative lateral speed (action 0) from rest.
        let mut obs = vec![1.0; 2 * px + 3];
        for r in 0..side {
            for c in 0..20 {
                obs[px + r * side + c] = 0.2;
            }
        }
        assert_eq!(reactive(&obs, [side, side], 2), 0);
        // Mirrored: steer the other way.
        let mut obs = vec![1.0; 2 * px + 3];
        for r in 0..side {
            for c in 12..side {
                obs[px + r * side + c] = 0.2;
            }
        }
        assert_eq!(reactive(&obs, [side, side], 2), 1);
        // All clear and flying sideways: back toward zero lateral speed.
        let mut obs = vec![1.0; 2 * px + 3];
        obs[2 * px + 1] = 0.5;
        assert_eq!(reactive(&obs, [side, side], 2), 0);
    }

    #[test]
    fn a_network_with_memory_flies_repeatably_and_only_with_its_state() {
        let root =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/arenas/test.toml");
        let arena = Arena::load(&root).unwrap();
        let sim = SimConfig::default();
        let shapes = rotorhive_model::Shapes::PAPER;
        let dev = rotorhive_model::Device::Cpu;
        let net = PolicyNet::new(shapes, Default::default(), Some(8), 1, &dev).unwrap();
        let one = |seed| fly(Pilot::Net(&net), sim.clone(), std::slice::from_ref(&arena), 8, seed);
        let (a, b) = (one(3).unwrap(), one(3).unwrap());
        assert_eq!(a.episodes, 8);
        assert_eq!((a.successes, a.collisions), (b.successes, b.collisions));
        assert_eq!(a.mean_reward, b.mean_reward);
        assert!(a.mean_reward.is_finite());
        let e = Pilot::Net(&net).act(&[0.0; 2051], 2051, [32, 32], 2).unwrap_err().to_string();
        assert!(e.contains("state"), "{e}");
    }

    #[test]
    fn the_reactive_rule_beats_a_random_policy_on_the_paper_test_arena() {
        let root =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/arenas/test.toml");
        let arena = Arena::load(&root).unwrap();
        let sim = SimConfig::default();
        let reactive =
            fly(Pilot::Reactive, sim.clone(), std::slice::from_ref(&arena), 100, 5).unwrap();
        // A uniformly random policy, flown the same way.
        let mut env = VecEnv::new(SimConfig { agents: 100, ..sim }, arena, 5).unwrap();
        let mut rng = rand_pcg::Pcg64Mcg::new(9);
        let mut first: Vec<Option<Done>> = vec![None; 100];
        for _ in 0..401 {
            let actions: Vec<u8> =
                (0..100).map(|_| rand::Rng::random_range(&mut rng, 0..2u8)).collect();
            env.step(&actions).unwrap();
            for ep in env.finished() {
                first[ep.agent].get_or_insert(ep.done);
            }
        }
        let random = first.iter().filter(|d| **d == Some(Done::Goal)).count();
        assert!(reactive.success_rate() > 0.5, "reactive {}", reactive.success_rate());
        assert!(
            (reactive.successes as f64) > 5.0 * random as f64 + 10.0,
            "reactive {} against random {random}",
            reactive.successes
        );
    }
}
