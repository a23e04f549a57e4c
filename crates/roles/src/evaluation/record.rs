//! What a logged evaluation keeps of each episode (`hive eval --failures`,
//! `--agree`): its path, how it ended, its last observations and actions,
//! and, with an auditor, a planner's judgement of every action the pilot
//! took. From them: the traps (places where many of a layout's episodes
//! end together) and the agreement of the pilot with the planner.

use std::collections::VecDeque;

use rotorhive_sim::{Done, Planner, Sight, VecEnv};

/// Steps kept at the end of each episode (observations and actions), and
/// the steps before a crash the audit looks at.
pub const LAST_STEPS: usize = 5;

/// A trap holds the ends of episodes within this distance of each other (m).
const TRAP_SPAN: f32 = 1.0;

/// A moving obstacle this near the drone (m, to its box in x and y) puts
/// a judged step in its [`Near`] class: about two steps' flight.
pub const NEAR_M: f32 = 3.0;

/// What the drone's tracker held of the moving obstacle nearest it at a
/// judged step (within [`NEAR_M`]): where in the audit a pilot parts from
/// its planner, by what its observation could tell of the mover.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Near {
    /// No moving obstacle within [`NEAR_M`].
    #[default]
    None,
    /// One within reach that no track holds (never shown by the camera,
    /// or forgotten).
    Unseen,
    /// Tracked, without a velocity (seen once, or not twice lately).
    Glimpsed,
    /// Tracked with a velocity, never seen to turn.
    Moving,
    /// Tracked with a velocity and seen to turn (or go round).
    Turned,
}

impl Near {
    /// Every class, in the order of [`Agreement::decisive_near`] (each at
    /// its discriminant).
    pub const ALL: [Near; 5] =
        [Near::None, Near::Unseen, Near::Glimpsed, Near::Moving, Near::Turned];

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Near::None => "none",
            Near::Unseen => "unseen",
            Near::Glimpsed => "glimpsed",
            Near::Moving => "moving",
            Near::Turned => "turned",
        }
    }

    /// Agent `i`'s class now in `env`.
    fn of(env: &VecEnv, i: usize) -> Self {
        let Some((k, _)) = env.nearest_mover(i).filter(|&(_, d)| d <= NEAR_M) else {
            return Near::None;
        };
        match env.tracks_of(i).iter().find(|t| t.obstacle == k) {
            None => Near::Unseen,
            Some(t) if t.velocity.is_none() => Near::Glimpsed,
            Some(t) if t.turned() || t.curved => Near::Turned,
            Some(_) => Near::Moving,
        }
    }
}

/// What a logged flight keeps.
#[derive(Debug, Clone, Copy)]
pub struct LogSpec {
    /// Also judge every action by a planner of this sight (the agreement
    /// audit).
    pub audit: Option<Sight>,
    /// Actions the audit's searches look ahead (as a teacher's label's).
    pub horizon: usize,
}

/// One episode as a logged flight kept it.
#[derive(Debug, Clone, Default)]
pub struct EpisodeLog {
    /// How it ended (`None`: not within the flight's steps).
    pub done: Option<Done>,
    /// Where the drone was (x, y) from its spawn to its end, after each step.
    pub path: Vec<[f32; 2]>,
    /// Its last [`LAST_STEPS`] observations, oldest first, each the one its
    /// action was chosen on.
    pub last_obs: VecDeque<Vec<f32>>,
    /// Its last [`LAST_STEPS`] actions, oldest first.
    pub last_actions: VecDeque<u8>,
    /// With an auditor, per step: how many actions the planner allows
    /// there (0: none keeps a way) and whether the pilot's was one of them.
    pub judged: Vec<(u8, bool)>,
    /// With an auditor, per judged step: the nearest mover's [`Near`].
    pub near: Vec<Near>,
}

impl EpisodeLog {
    /// Where it ended (x, y).
    pub fn end(&self) -> [f32; 2] {
        self.path.last().copied().unwrap_or_default()
    }

    /// Whether it did not reach its goal (or the far end).
    pub fn failed(&self) -> bool {
        self.done != Some(Done::Goal)
    }
}

/// Keeps the logs of every agent's first episode while a flight goes on.
pub(super) struct Recorder {
    spec: LogSpec,
    logs: Vec<EpisodeLog>,
    auditor: Option<Planner>,
}

impl Recorder {
    pub(super) fn new(env: &VecEnv, spec: LogSpec) -> Self {
        let logs = env
            .positions()
            .iter()
            .map(|p| EpisodeLog { path: vec![[p[0], p[1]]], ..EpisodeLog::default() })
            .collect();
        Self { spec, logs, auditor: spec.audit.map(|s| Planner::new(env, s)) }
    }

    /// Before a step: what each agent still in its first episode sees and
    /// does, and what the auditor allows it.
    pub(super) fn before(&mut self, env: &VecEnv, active: &[bool], actions: &[u8]) {
        let (obs, len) = (env.observations(), env.obs_len());
        for (i, log) in self.logs.iter_mut().enumerate().filter(|(i, _)| active[*i]) {
            if log.last_actions.len() == LAST_STEPS {
                log.last_obs.pop_front();
                log.last_actions.pop_front();
            }
            log.last_obs.push_back(obs.get(i * len..(i + 1) * len).unwrap_or_default().to_vec());
            log.last_actions.push_back(actions[i]);
            if let Some(p) = self.auditor.as_mut() {
                let allowed = p.allowed(env, i, self.spec.horizon);
                log.judged.push((allowed.len() as u8, allowed.contains(&actions[i])));
                log.near.push(Near::of(env, i));
            }
        }
    }

    /// After a step: where each agent that was in its first episode is,
    /// and how those that ended did.
    pub(super) fn after(&mut self, env: &VecEnv, active: &[bool]) {
        for ep in env.finished() {
            if active[ep.agent] {
                self.logs[ep.agent].done.get_or_insert(ep.done);
            }
        }
        for (i, p) in env.positions().iter().enumerate().filter(|(i, _)| active[*i]) {
            self.logs[i].path.push([p[0], p[1]]);
        }
    }

    pub(super) fn finish(self) -> Vec<EpisodeLog> {
        self.logs
    }
}

/// A place where many episodes of one layout end.
#[derive(Debug, Clone, PartialEq)]
pub struct Trap {
    /// The mean of its episodes' end points (x, y).
    pub at: [f32; 2],
    /// Episodes that end in it.
    pub episodes: usize,
    /// Which of the ends given to [`traps`] (their indices, ascending).
    pub members: Vec<usize>,
}

/// The traps among the end points `ends` of one layout's failed episodes,
/// of `flown` episodes flown there: groups of ends all within [`TRAP_SPAN`]
/// of each other, holding at least a fifth of the layout's episodes (and
/// at least two). Found greedily, the largest group first; an end is in at
/// most one trap.
pub fn traps(ends: &[[f32; 2]], flown: usize) -> Vec<Trap> {
    let least = flown.div_ceil(5).max(2);
    let dist = |a: [f32; 2], b: [f32; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
    let mut left: Vec<[f32; 2]> = ends.to_vec();
    // Where each end of `left` was in `ends`.
    let mut index: Vec<usize> = (0..ends.len()).collect();
    let mut found = Vec::new();
    loop {
        // The largest group around any end: its neighbours nearest first,
        // each taken while within the span of every member.
        let group = |k: usize| -> Vec<usize> {
            let mut near: Vec<usize> = (0..left.len())
                .filter(|&j| j != k && dist(left[k], left[j]) <= TRAP_SPAN)
                .collect();
            near.sort_by(|&a, &b| dist(left[k], left[a]).total_cmp(&dist(left[k], left[b])));
            let mut members = vec![k];
            for j in near {
                if members.iter().all(|&m| dist(left[m], left[j]) <= TRAP_SPAN) {
                    members.push(j);
                }
            }
            members
        };
        let Some(best) = (0..left.len()).map(group).max_by_key(Vec::len) else { break };
        if best.len() < least {
            break;
        }
        let n = best.len() as f32;
        let at =
            best.iter().fold([0.0, 0.0], |s, &m| [s[0] + left[m][0] / n, s[1] + left[m][1] / n]);
        let mut members: Vec<usize> = best.iter().map(|&m| index[m]).collect();
        members.sort_unstable();
        found.push(Trap { at, episodes: best.len(), members });
        let mut drop = best;
        drop.sort_unstable_by(|a, b| b.cmp(a));
        for m in drop {
            left.swap_remove(m);
            index.swap_remove(m);
        }
    }
    found
}

/// How often a pilot's action was one the auditing planner allows; each a
/// pair (agreeing steps, steps judged). Steps where the planner finds no
/// way at all are not judged (counted in `no_way`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Agreement {
    /// Every judged step.
    pub all: (usize, usize),
    /// The decisive ones: one action alone keeps a way.
    pub decisive: (usize, usize),
    /// The last [`LAST_STEPS`] steps before each crash.
    pub before_crash: (usize, usize),
    /// Steps where no action keeps a way (in the planner's model).
    pub no_way: usize,
    /// The decisive steps by the nearest mover's [`Near`] class, in the
    /// order of [`Near::ALL`].
    pub decisive_near: [(usize, usize); 5],
}

impl Agreement {
    /// A pair's share (`None` where no step was judged).
    pub fn share((agree, steps): (usize, usize)) -> Option<f64> {
        (steps > 0).then(|| agree as f64 / steps as f64)
    }
}

/// The agreement over the judged steps of `logs`.
pub fn agreement(logs: &[EpisodeLog]) -> Agreement {
    let mut a = Agreement::default();
    let add = |p: &mut (usize, usize), ok: bool| *p = (p.0 + usize::from(ok), p.1 + 1);
    for log in logs {
        let crash_from = match log.done {
            Some(Done::Collision) => log.judged.len().saturating_sub(LAST_STEPS),
            _ => usize::MAX,
        };
        for (k, &(allowed, ok)) in log.judged.iter().enumerate() {
            if allowed == 0 {
                a.no_way += 1;
                continue;
            }
            add(&mut a.all, ok);
            if allowed == 1 {
                add(&mut a.decisive, ok);
                let near = log.near.get(k).copied().unwrap_or_default();
                add(&mut a.decisive_near[near as usize], ok);
            }
            if k >= crash_from {
                add(&mut a.before_crash, ok);
            }
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn traps_are_groups_of_a_fifth_of_the_episodes_within_a_metre() {
        // 10 episodes flown: a trap needs 2 ends. Three ends close together,
        // two others 0.9 m apart, one alone.
        let ends = [[10.0, 0.0], [10.2, 0.1], [10.1, -0.3], [30.0, 2.0], [30.9, 2.0], [50.0, 0.0]];
        let t = traps(&ends, 10);
        assert_eq!(t.len(), 2, "{t:?}");
        assert_eq!(t[0].episodes, 3);
        assert!((t[0].at[0] - 10.1).abs() < 1e-5 && (t[0].at[1] + 0.2 / 3.0).abs() < 1e-5);
        assert_eq!(t[0].members, vec![0, 1, 2]);
        assert_eq!((t[1].episodes, t[1].members.clone()), (2, vec![3, 4]));
        // 20 episodes flown: a trap needs 4 ends; none here.
        assert!(traps(&ends, 20).is_empty());
        // A chain 0.8 m a link is no trap of three: the ends of it are 1.6 m
        // apart (every member within a metre of every other).
        let chain = [[0.0, 0.0], [0.8, 0.0], [1.6, 0.0]];
        let t = traps(&chain, 10);
        assert_eq!(t.iter().map(|t| t.episodes).collect::<Vec<_>>(), vec![2], "{t:?}");
        assert!(traps(&[], 10).is_empty());
    }

    #[test]
    fn agreement_counts_all_decisive_and_last_steps_before_a_crash() {
        let log = |done, judged: &[(u8, bool)]| EpisodeLog {
            done: Some(done),
            judged: judged.to_vec(),
            ..EpisodeLog::default()
        };
        // A crash after seven steps: the first two outside the last five.
        let crash = log(
            Done::Collision,
            &[(2, true), (1, true), (2, true), (1, false), (2, true), (1, true), (0, false)],
        );
        let flown = log(Done::Goal, &[(2, true), (1, true), (1, false)]);
        let a = agreement(&[crash, flown]);
        assert_eq!(a.no_way, 1);
        assert_eq!(a.all, (7, 9));
        assert_eq!(a.decisive, (3, 5));
        // The last five of the crash: (2,t) (1,f) (2,t) (1,t) and the
        // unjudged (0,f).
        assert_eq!(a.before_crash, (3, 4));
        assert_eq!(Agreement::share(a.all), Some(7.0 / 9.0));
        assert_eq!(Agreement::share((0, 0)), None);
        // No mover classes logged: every decisive step counts as `none`.
        assert_eq!(a.decisive_near, [(3, 5), (0, 0), (0, 0), (0, 0), (0, 0)]);
    }

    #[test]
    fn decisive_steps_are_split_by_the_nearest_movers_class() {
        use Near::*;
        let log = EpisodeLog {
            done: Some(Done::Collision),
            judged: vec![(1, true), (1, false), (2, false), (1, false), (1, true), (0, false)],
            near: vec![None, Unseen, Moving, Moving, Turned, Glimpsed],
            ..EpisodeLog::default()
        };
        let a = agreement(&[log]);
        // The step of two allowed actions (moving) and the one of none
        // (glimpsed) are not decisive.
        assert_eq!(a.decisive_near, [(1, 1), (0, 1), (0, 0), (0, 1), (1, 1)]);
        let total = a.decisive_near.iter().fold((0, 0), |s, p| (s.0 + p.0, s.1 + p.1));
        assert_eq!(total, a.decisive);
    }
}
