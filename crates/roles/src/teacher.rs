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
use rotorhive_model::Teaching;
use rotorhive_msg::{NO_EXPERT, TeacherCounts, Telemetry, label_of_mask};
use rotorhive_sim::{Planner, Sight, VecEnv};
use serde::{Deserialize, Serialize};

use crate::error::{Result, config_err};

/// `teacher.policy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TeacherPolicy {
    /// No teacher: training exactly as without the section.
    None,
    /// The simulator's privileged planner (`hive eval --policy planner`).
    Planner,
}

/// `teacher.sight`: what the planner may know (as `hive eval --sight`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TeacherSight {
    /// Every obstacle, and where each moving one will be.
    All,
    /// What the camera shows now, with the movers' future.
    View,
    /// What the camera shows now, the movers' present velocity kept 3 s.
    ViewVelocity,
    /// What the camera shows now, each mover standing over its whole track.
    ViewTrack,
    /// What the camera showed over `memory_s` (a mover known once watched
    /// for half its cycle).
    ViewMemory,
    /// What the pixels show now: the obstacles a ray meets first, the
    /// movers' present velocity kept 3 s.
    Pixels,
    /// What the pixels showed over `memory_s` (a mover known once watched
    /// for half its cycle).
    PixelsMemory,
}

/// `teacher.labels`: which of the student's steps a label reaches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TeacherLabels {
    /// Where exactly one action keeps a way clear (the last moments before
    /// a row).
    Decisive,
    /// Also where several do: the actions whose way keeps the most room
    /// (the earlier choice of a gap); none where all keep as much.
    Graded,
}

/// `teacher.loss`: how the labels train the student.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TeacherLoss {
    /// DQfD's large margin on steps labelled with one action.
    Margin,
    /// A cross-entropy of the Q-values' softmax toward the actions a label
    /// allows, on every labelled step; the TD loss at `learner.td_weight`,
    /// handed the whole weight back as the teacher fades.
    Imitation,
}

/// `[teacher]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TeacherSection {
    /// `none` (no teacher) or `planner`.
    pub policy: TeacherPolicy,
    /// What the planner knows.
    pub sight: TeacherSight,
    /// With `sight = "view-memory"`: seconds the planner remembers (0: the
    /// whole episode).
    pub memory_s: u16,
    /// Agents of each simulator (its first ones; at most all) that the
    /// planner flies: their transitions are demonstrations.
    pub demo_agents: usize,
    /// Share of the student's steps labelled with the planner's action at
    /// the student's state.
    pub label_share: f64,
    /// Actions a label's search looks ahead (a way clear for this many;
    /// 0: to the end, as the planner flies, at several times the cost).
    pub label_horizon: usize,
    /// Which steps a label reaches: `decisive` or `graded`.
    pub labels: TeacherLabels,
    /// How labels train: `margin` (DQfD) or `imitation`.
    pub loss: TeacherLoss,
    /// DQfD's margin l(a_E, a) for every action other than the expert's
    /// (in the network's units: scaled rewards).
    pub margin: f64,
    /// With `loss = "imitation"`: the softmax's temperature over the
    /// Q-values (in the network's units: scaled rewards).
    pub temperature: f64,
    /// Weight of the teacher's loss against the TD loss (DQfD: 1).
    pub weight: f64,
    /// Agent-steps (every host's) over which the label share, the
    /// demonstrations, their batch share and the loss weight fall linearly
    /// to zero; 0 = never.
    pub fade_env_steps: u64,
    /// Demonstrations kept in the replay's reservoir (FIFO among
    /// themselves; the student's transitions never overwrite them).
    pub demo_capacity: usize,
    /// Share of each minibatch drawn from the demonstrations (R2D3's rho).
    pub demo_batch_share: f64,
    /// The learner's first updates drawn from the demonstrations alone
    /// (DQfD's pre-training), once the replay holds `replay.min_fill`;
    /// not counted against `replay.samples_per_insert`. A replay that
    /// starts with a restored memory (a resumed run) does not pre-train.
    pub pretrain_updates: u64,
}

impl Default for TeacherSection {
    fn default() -> Self {
        Self {
            policy: TeacherPolicy::None,
            sight: TeacherSight::All,
            memory_s: 0,
            demo_agents: 5,
            label_share: 0.5,
            label_horizon: 10,
            labels: TeacherLabels::Decisive,
            loss: TeacherLoss::Margin,
            margin: 0.8,
            temperature: 0.2,
            weight: 1.0,
            fade_env_steps: 0,
            demo_capacity: 50_000,
            demo_batch_share: 0.25,
            pretrain_updates: 0,
        }
    }
}

impl TeacherSection {
    /// Whether the run has a teacher.
    pub fn on(&self) -> bool {
        self.policy != TeacherPolicy::None
    }

    /// How an update weighs the labels with the teacher at strength `fade`
    /// (1: full; 0: gone) and the TD loss at `td_weight` beside imitation
    /// (handed back to 1 as the teacher fades); the plain update without a
    /// teacher.
    pub fn teaching(&self, fade: f32, td_weight: f32) -> Teaching {
        if !self.on() {
            return Teaching::default();
        }
        let w = self.weight as f32 * fade;
        match self.loss {
            TeacherLoss::Margin => Teaching::margin(w),
            TeacherLoss::Imitation => Teaching {
                td: 1.0 - fade * (1.0 - td_weight),
                margin: 0.0,
                imitation: w,
                temperature: self.temperature as f32,
            },
        }
    }

    /// What the planner is told.
    pub fn planner_sight(&self) -> Sight {
        match self.sight {
            TeacherSight::All => Sight::All,
            TeacherSight::View => Sight::View,
            TeacherSight::ViewVelocity => Sight::ViewVelocity,
            TeacherSight::ViewTrack => Sight::ViewTrack,
            TeacherSight::ViewMemory => {
                Sight::ViewMemory((self.memory_s > 0).then_some(self.memory_s))
            }
            TeacherSight::Pixels => Sight::Pixels,
            TeacherSight::PixelsMemory => {
                Sight::PixelsMemory((self.memory_s > 0).then_some(self.memory_s))
            }
        }
    }

    /// Agents of each simulator the planner flies (none without a teacher).
    pub fn demo_agents(&self) -> usize {
        if self.on() { self.demo_agents } else { 0 }
    }

    /// Whether the replay keeps a demonstration reservoir.
    pub fn demos(&self) -> bool {
        self.on() && self.demo_agents > 0
    }

    /// Minibatches of demonstrations alone before the rest (0 without a
    /// reservoir).
    pub fn pretrain_updates(&self) -> u64 {
        if self.demos() { self.pretrain_updates } else { 0 }
    }

    /// The teacher's strength after `env_steps` agent-steps: 1 without a
    /// fade, else falling linearly to 0 over `fade_env_steps`; 0 without a
    /// teacher.
    pub fn fade(&self, env_steps: u64) -> f64 {
        if !self.on() {
            return 0.0;
        }
        if self.fade_env_steps == 0 {
            return 1.0;
        }
        (1.0 - env_steps as f64 / self.fade_env_steps as f64).max(0.0)
    }

    /// Checks the section (with `replay.prioritized`). `demo_agents` above
    /// a simulator's agents means all of them (a level's config flown by
    /// fewer drones, as Gymnasium's, stays valid).
    pub fn validate(&self, prioritized: bool) -> Result<()> {
        if !self.on() {
            return Ok(());
        }
        for (k, v) in [
            ("teacher.label_share", self.label_share),
            ("teacher.demo_batch_share", self.demo_batch_share),
        ] {
            if !(0.0..=1.0).contains(&v) {
                config_err!("key `{k}` must lie in [0, 1], got {v}");
            }
        }
        if !(self.temperature.is_finite() && self.temperature > 0.0) {
            config_err!("key `teacher.temperature` must be positive, got {}", self.temperature);
        }
        for (k, v) in [("teacher.margin", self.margin), ("teacher.weight", self.weight)] {
            if !(v.is_finite() && v >= 0.0) {
                config_err!("key `{k}` must be 0 or positive, got {v}");
            }
        }
        if self.memory_s > 0
            && !matches!(self.sight, TeacherSight::ViewMemory | TeacherSight::PixelsMemory)
        {
            config_err!(
                "key `teacher.memory_s` needs `teacher.sight = \"view-memory\"` or `\"pixels-memory\"`"
            );
        }
        if self.demos() && self.demo_capacity == 0 {
            config_err!(
                "key `teacher.demo_capacity` must be positive with `teacher.demo_agents` above 0"
            );
        }
        if self.pretrain_updates > 0 && !self.demos() {
            config_err!(
                "key `teacher.pretrain_updates` needs demonstrations (`teacher.demo_agents` above 0)"
            );
        }
        if self.demos() && prioritized {
            config_err!(
                "key `teacher.demo_agents` above 0 is not supported with `replay.prioritized` yet (the demonstrations' reservoir is sampled uniformly)"
            );
        }
        Ok(())
    }
}

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
            planner: Planner::new(env, t.planner_sight()),
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
        let seed = crate::seeds::teacher(cfg.seed, cfg.cluster.env_offset + env_index);
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
        self.planner = Planner::new(env, self.cfg.planner_sight());
    }
}
