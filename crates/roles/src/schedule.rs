//! The schedule of a deterministic run (`deterministic = true`): what every
//! role may do after each round, so that a run is a pure function of its
//! config and seed.
//!
//! A round is one step of every environment: round `k` (from 1) is the
//! transitions an actor emits on observation step `k`, after it has acted on
//! that step. The replay inserts rounds whole, environment by environment,
//! and after round `k` sends exactly [`Schedule::minibatches_after`]`(k)`
//! minibatches in all, sampled from a seeded generator; the learner updates
//! on them in order. An actor acting on step `h` uses the weights published
//! after [`Schedule::updates_for_step`]`(h)` updates, and waits for them.
//! The actors emit round `h` after acting on step `h`, so the learner can
//! never publish past what the slowest actor needs: a "latest" weights
//! channel is enough.

use crate::config::Config;

/// The deterministic schedule of one run.
#[derive(Debug, Clone, Copy)]
pub struct Schedule {
    agents: u64,
    min_fill: u64,
    /// Agent-steps one minibatch trains on: `replay.batch` transitions, or
    /// with memory sequences of several trained steps each.
    batch: u64,
    per_insert: f64,
    publish_every: u64,
    rounds: u64,
    /// Minibatches of demonstrations alone sent at `min_fill`
    /// (`teacher.pretrain_updates`).
    pretrain: u64,
}

impl Schedule {
    /// The schedule of `cfg` (validated: deterministic runs have a positive
    /// `samples_per_insert` and `max_env_steps`).
    pub fn new(cfg: &Config) -> Self {
        let agents = cfg.agents_total() as u64;
        let batch = (cfg.replay.batch * cfg.steps_per_row()) as u64;
        // With memory an agent's first sequence leaves after its
        // `sequence_steps`: the memory holds one of each by then.
        let first = cfg.memory().map_or(0, |_| cfg.learner.sequence_steps as u64 * agents);
        Self {
            agents,
            min_fill: (cfg.replay.min_fill as u64).max(batch).max(first),
            batch,
            per_insert: cfg.replay.samples_per_insert,
            publish_every: cfg.learner.publish_every,
            rounds: cfg.max_env_steps.div_ceil(agents.max(1)),
            pretrain: cfg.teacher.pretrain_updates(),
        }
    }

    /// Rounds in the run: `max_env_steps` agent-steps, rounded up to whole rounds.
    pub fn rounds(&self) -> u64 {
        self.rounds
    }

    /// Minibatches sent (and updates made) in all once rounds `1..=k` are
    /// inserted: none before `min_fill` agent-steps, then the pre-training
    /// ones at once and `samples_per_insert` samples per agent-step.
    pub fn minibatches_after(&self, k: u64) -> u64 {
        let steps = k * self.agents;
        if steps < self.min_fill {
            return 0;
        }
        self.pretrain
            + 1
            + (self.per_insert * (steps - self.min_fill) as f64 / self.batch as f64).floor() as u64
    }

    /// The learner's update count whose published weights act on
    /// observation step `h`: the last publication within the updates of
    /// rounds `1..h`.
    pub fn updates_for_step(&self, h: u64) -> u64 {
        let m = if h == 0 { 0 } else { self.minibatches_after(h - 1) };
        m / self.publish_every * self.publish_every
    }

    /// Updates of the whole run.
    pub fn total_updates(&self) -> u64 {
        self.minibatches_after(self.rounds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minibatches_follow_the_inserts_and_weights_the_publications() {
        let mut cfg = Config::default();
        cfg.sim.agents = 4;
        cfg.sim.envs = 2;
        cfg.replay.min_fill = 200;
        cfg.replay.batch = 32;
        cfg.replay.samples_per_insert = 1.0;
        cfg.learner.publish_every = 10;
        cfg.max_env_steps = 2_000;
        let s = Schedule::new(&cfg);
        // 8 agent-steps per round: 250 rounds; min_fill reached at round 25.
        assert_eq!(s.rounds(), 250);
        assert_eq!(s.minibatches_after(24), 0);
        assert_eq!(s.minibatches_after(25), 1);
        // 32 more agent-steps (4 rounds) pay for one more minibatch.
        assert_eq!(s.minibatches_after(28), 1);
        assert_eq!(s.minibatches_after(29), 2);
        assert_eq!(s.total_updates(), 1 + (2_000 - 200) / 32);
        // Weights: the last multiple of 10 updates within rounds before h.
        assert_eq!(s.updates_for_step(0), 0);
        assert_eq!(s.updates_for_step(26), 0);
        let h = (1..250).find(|&h| s.minibatches_after(h - 1) >= 10).unwrap();
        assert_eq!(s.updates_for_step(h), 10);
        assert_eq!(s.updates_for_step(h - 1), 0);
        assert!((1..250).all(|h| s.updates_for_step(h) >= s.updates_for_step(h - 1)));
        // Pre-training on demonstrations: its minibatches all at min_fill,
        // then the same pace; none without a reservoir to draw them from.
        cfg.teacher.pretrain_updates = 40;
        assert_eq!(Schedule::new(&cfg).minibatches_after(25), 1, "no teacher, no pre-training");
        cfg.teacher.policy = crate::teacher::TeacherPolicy::Planner;
        let p = Schedule::new(&cfg);
        assert_eq!((p.minibatches_after(24), p.minibatches_after(25)), (0, 41));
        assert_eq!(p.minibatches_after(29), 42);
        assert_eq!(p.total_updates(), s.total_updates() + 40);
        assert_eq!(p.updates_for_step(26), 40, "the actors fly the pre-trained weights");
        // With memory a minibatch of 32 sequences trains on 32 × 4 steps,
        // and the first is owed once every agent's first sequence is in.
        cfg.teacher.policy = crate::teacher::TeacherPolicy::None;
        cfg.learner.memory = "gru:8".into();
        (cfg.learner.sequence_steps, cfg.learner.burn_in) = (30, 26);
        let m = Schedule::new(&cfg);
        assert_eq!((m.minibatches_after(29), m.minibatches_after(30)), (0, 1));
        assert_eq!(m.minibatches_after(30 + 16), 2, "128 agent-steps a minibatch");
        assert_eq!(m.total_updates(), 1 + (2_000 - 240) / 128);
    }
}
