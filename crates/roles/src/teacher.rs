//! The teacher (`[teacher]`): the simulator's privileged planner flying some
//! agents (demonstrations) and labelling the student's steps with its own
//! action (DAgger inside the replay), as in DQfD / Ape-X DQfD. The sims run
//! it ([`Teacher`]); its actions travel with the observations, the actor
//! puts them into the transitions, the replay keeps the demonstrations in a
//! reservoir of their own and the learner adds DQfD's large-margin loss.
//! The student never sees it: checkpoints, `hive eval`, `hive play`, ONNX
//! and Python fly from the observation alone.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rotorhive_msg::{NO_EXPERT, TeacherCounts, Telemetry, label_of_mask};
use rotorhive_sim::{Planner, VecEnv};

pub use crate::config::{LabelSearch, TeacherLabels, TeacherLoss, TeacherPolicy, TeacherSection};

/// Nanoseconds since `t`.
fn elapsed(t: Instant) -> u64 {
    t.elapsed().as_nanos() as u64
}

/// A simulator's teacher: its planner, which agents it flies and which
/// student steps it labels, and its counters.
pub struct Teacher {
    cfg: TeacherSection,
    planner: Planner,
    rng: Pcg64Mcg,
    /// Agent-steps of the whole run per step of this simulator.
    run_agents: u64,
    /// This step's action of each agent it flies ([`NO_EXPERT`]: the
    /// student's) and its label of each agent ([`NO_EXPERT`]: none).
    flies: Vec<f32>,
    labels: Vec<f32>,
    /// What it did so far.
    pub counts: TeacherCounts,
}

impl Teacher {
    /// The teacher of a simulator of `env`, when the run has one.
    pub fn new(cfg: &crate::Config, env: &VecEnv, seed: u64) -> Option<Self> {
        let t = &cfg.teacher;
        t.on().then(|| Self {
            cfg: t.clone(),
            planner: planner(t, env),
            rng: Pcg64Mcg::seed_from_u64(seed),
            run_agents: cfg.agents_total() as u64,
            flies: vec![NO_EXPERT; env.agents()],
            labels: vec![NO_EXPERT; env.agents()],
            counts: TeacherCounts::default(),
        })
    }

    /// The teacher of simulator `env_index` of the run `cfg` describes,
    /// with its labels of `env`'s first observations, when it has one.
    pub fn start(cfg: &crate::Config, env: &VecEnv, env_index: usize) -> Option<Self> {
        let seed = crate::streams::teacher(cfg.seed, cfg.cluster.env_offset + env_index);
        let mut t = Self::new(cfg, env, seed)?;
        t.label(env, 0);
        Some(t)
    }

    /// A teacher's labels after step `step` of `env` (whose lanes were
    /// replaced when `new_world`), and its counts into the sim's telemetry.
    pub fn follow(
        teacher: Option<&mut Self>,
        env: &VecEnv,
        step: u64,
        new_world: bool,
        tel: &mut Telemetry,
    ) {
        let Some(t) = teacher else { return };
        if new_world {
            t.replace_world(env);
        }
        t.label(env, step);
        tel.teacher = t.counts;
    }

    /// The planner's actions at the observations of `env` after `step`
    /// steps of this simulator: the agents it flies (their actions), and
    /// its labels of those and of a share of the others (the one action
    /// that keeps a way clear, where only one does), fading with the run's
    /// agent-steps.
    pub fn label(&mut self, env: &VecEnv, step: u64) {
        let fade = self.cfg.fade(step.saturating_mul(self.run_agents));
        let demo = if fade > 0.0 { self.cfg.demo_agents } else { 0 };
        let share = self.cfg.label_share * fade;
        let horizon = if self.cfg.label_horizon == 0 { usize::MAX } else { self.cfg.label_horizon };
        for i in 0..self.flies.len() {
            let flies = i < demo;
            let c = &mut self.counts;
            self.flies[i] = if flies {
                let t = Instant::now();
                let a = self.planner.act(env, i);
                (c.demo_steps, c.demo_ns) = (c.demo_steps + 1, c.demo_ns + elapsed(t));
                a as f32
            } else {
                self.planner.forget(i);
                NO_EXPERT
            };
            self.labels[i] = if flies || (share > 0.0 && self.rng.random::<f64>() < share) {
                let t = Instant::now();
                let label = match self.cfg.labels {
                    TeacherLabels::Decisive => {
                        self.planner.label(env, i, horizon).map_or(NO_EXPERT, f32::from)
                    }
                    TeacherLabels::Graded => label_of_mask(self.planner.graded(env, i, horizon)),
                };
                (c.labels, c.label_ns) = (c.labels + 1, c.label_ns + elapsed(t));
                label
            } else {
                // A remembering planner sees every frame, labelled or not.
                self.planner.watch(env, i);
                NO_EXPERT
            };
        }
    }

    /// This step's actions of the agents the teacher flies and its labels
    /// ([`NO_EXPERT`] where none).
    pub fn actions(&self) -> (&[f32], &[f32]) {
        (&self.flies, &self.labels)
    }

    /// A planner for the new world of `env` (its lanes replaced).
    pub fn replace_world(&mut self, env: &VecEnv) {
        self.planner = planner(&self.cfg, env);
    }
}

/// The teacher `t`'s planner for the world of `env`.
fn planner(t: &TeacherSection, env: &VecEnv) -> Planner {
    Planner::new(env, t.planner_sight())
        .with_depth_first_labels(t.label_search == LabelSearch::Depth)
}
