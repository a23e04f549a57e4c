//! The sections of a run's config (`[sim]`, `[actor]`, `[replay]`,
//! `[learner]`, `[eval]`, `[cluster]`, `[teacher]`) with their defaults;
//! the keys, their defaults and units are listed in `docs/config.md`.

use std::path::PathBuf;

use rotorhive_model::Teaching;
use rotorhive_records::ObservationMode;
use rotorhive_sim::{
    GenParams, Goal, MapSpec, Noise, PhysicsKind, Randomize, RendererKind, Sight, TrackSpec,
};
use serde::{Deserialize, Serialize};

use crate::error::{Result, config_err};

/// `actor.device` and `learner.device`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DeviceName {
    /// The CPU.
    Cpu,
    /// GPU 0 through CUDA (a build with `--features cuda`).
    Cuda,
}

impl DeviceName {
    /// The model's device of this name.
    pub fn kind(self) -> rotorhive_model::DeviceKind {
        match self {
            Self::Cpu => rotorhive_model::DeviceKind::Cpu,
            Self::Cuda => rotorhive_model::DeviceKind::Cuda,
        }
    }
}

/// `actor.exploration`: how each agent's epsilon is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Exploration {
    /// One epsilon for every agent: `eps_start` until the replay holds
    /// `min_fill`, then linear to `eps_end` over `eps_decay` transitions.
    Decay,
    /// Ape-X: agent i of the run's N agents (every host's) explores with
    /// epsilon_i = base^(1 + alpha·i/(N−1)) once the replay holds
    /// `min_fill` (`eps_start` before), so some keep exploring and others
    /// exploit. The rolling reward then counts the episodes of agents at or
    /// below `eps_end` only, the old schedule's floor.
    PerActor,
}

/// `[cluster]`: a run across hosts. The head (`hive train --listen`) waits
/// for `workers` worker hosts (`hive worker --connect`) before its clock
/// starts; the `*_elsewhere` keys are filled in by the head as workers join
/// (they size the channels and the rate limit) and are left at 0 by hand.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClusterSection {
    /// Worker hosts the run waits for; 0 = none.
    pub workers: usize,
    /// How long the head waits for them (s).
    pub join_timeout_s: f64,
    /// How long a worker waits for a head whose session dropped to come
    /// back (s), its unacknowledged batches kept and then sent again.
    pub reconnect_s: f64,
    /// Environments on other hosts (set by the head).
    pub envs_elsewhere: usize,
    /// Agents on other hosts (set by the head).
    pub agents_elsewhere: usize,
    /// Index in the run of this host's first environment (set by a worker
    /// from the head's answer): its sims and actors seed themselves as
    /// those environments of a one-host run would.
    pub env_offset: usize,
}

impl Default for ClusterSection {
    fn default() -> Self {
        Self {
            workers: 0,
            join_timeout_s: 60.0,
            reconnect_s: 60.0,
            envs_elsewhere: 0,
            agents_elsewhere: 0,
            env_offset: 0,
        }
    }
}

/// `[eval]`: `hive train` flies the newest published weights greedily every
/// `every_s` seconds (and at the threshold crossing) and keeps the best as
/// `checkpoints/best.safetensors`, the run's result.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalSection {
    /// Seconds between evaluations; 0 turns evaluation off.
    pub every_s: f64,
    /// Episodes per evaluation (flown at once, one per agent).
    pub episodes: usize,
    /// Arena of the evaluations; empty means `validation_arenas` generated
    /// arenas, side by side.
    pub arena: String,
    /// Generated validation arenas (neither trained on nor the test arena).
    pub validation_arenas: usize,
    /// After the threshold, training goes on until an evaluation reaches
    /// this success rate ...
    pub target_success: f64,
    /// ... or for at most this many seconds.
    pub after_threshold_s: f64,
    /// Episodes on fresh spawns that confirm a candidate for the run's
    /// result: an evaluation that may beat the best so far is flown again
    /// on new spawns, and only that independent score is compared, kept and
    /// checked against `target_success` (no winner's curse from the maximum
    /// of noisy scores). 0: the screening score decides.
    pub confirm_episodes: usize,
    /// Also an evaluation every this many agent-steps (every host's), on
    /// the agent-step clock rather than the wall clock: the learning curve
    /// in experience; 0: none.
    pub every_env_steps: u64,
    /// Held-out test arenas (files), never trained or validated on: what
    /// `hive eval` without `--arena` and `hive bench seeds` score a result on.
    pub test_arenas: Vec<PathBuf>,
    /// Also this many held-out layouts drawn by the level's generator from
    /// seeds no run trains or validates on (`seeds::test_layout`).
    pub test_layouts: usize,
}

impl Default for EvalSection {
    fn default() -> Self {
        Self {
            every_s: 15.0,
            episodes: 100,
            arena: String::new(),
            validation_arenas: 20,
            target_success: 0.9,
            after_threshold_s: 240.0,
            confirm_episodes: 300,
            every_env_steps: 0,
            test_arenas: vec![PathBuf::from("configs/arenas/test.toml")],
            test_layouts: 49,
        }
    }
}

/// `[sim]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimSection {
    /// Simulator processes, one actor each (0 = sized to the cores).
    pub envs: usize,
    /// Agents per simulator.
    pub agents: usize,
    /// Arena file; empty: the `generated_lanes` alone (which `generator`
    /// then needs).
    pub arena: PathBuf,
    /// Generated arenas flown beside `arena` (each a lane of its own, with
    /// different seeds in every environment); agents start each episode in
    /// a lane drawn at random. 0 trains on `arena` alone.
    pub generated_lanes: usize,
    /// Fresh layouts: every this many finished episodes (of one
    /// environment), one generated lane is renewed with a layout never
    /// flown before (built on a thread of its own, swapped in once the
    /// lane's last episode ends); 0 keeps the generated lanes all run.
    pub fresh_layouts: usize,
    /// Forward speed setpoint (m/s).
    pub forward_speed: f32,
    /// Lateral velocity change per action (m/s).
    pub lateral_step: f32,
    /// Largest lateral speed setpoint (m/s).
    pub max_lateral_speed: f32,
    /// Radius of the drone's collision sphere (m).
    pub drone_radius: f32,
    /// Reward of a step that ends in none of the ways below.
    pub reward_step: f32,
    /// Reward of the step that ends in a collision.
    pub reward_collision: f32,
    /// Reward of the step that times out.
    pub reward_timeout: f32,
    /// Reward of the step that reaches the end of the arena.
    pub reward_goal: f32,
    /// The renderer.
    pub renderer: RendererKind,
    /// One observation message per step or one per agent.
    pub observation_mode: ObservationMode,
    /// Drones collide with and see each other.
    pub interactive: bool,
    /// Physics step (s).
    pub physics_dt: f32,
    /// How flight is computed: `direct` (the equations of motion, collision
    /// queries once per action) or `rapier` (a rigid-body pipeline, the
    /// reference).
    pub physics: PhysicsKind,
    /// Simulated seconds per action.
    pub action_period: f32,
    /// Steps before a timeout.
    pub max_steps: u32,
    /// Depth clip range (m): another name of `sim.camera.range` (read into
    /// it; setting both is refused).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_range: Option<f32>,
    /// The depth camera (`[sim.camera]`; every key left out is its
    /// preset's, the paper's 32 × 32 without one).
    #[serde(skip_serializing_if = "crate::camera::CameraSection::is_unset")]
    pub camera: crate::camera::CameraSection,
    /// Depth frames stacked in one observation, one action period apart
    /// (2: the paper's, previous and current); 1 to
    /// [`rotorhive_msg::MAX_FRAMES`].
    pub frames: usize,
    /// Action periods between two stacked frames (1: consecutive; 3 with
    /// four frames: the views of 9, 6 and 3 periods ago and now); 1 to
    /// [`rotorhive_msg::MAX_FRAME_STRIDE`].
    pub frame_stride: usize,
    /// Threads for CPU rendering and physics (0 = sized to the cores).
    pub render_threads: usize,
    /// The generator of the training lanes, the validation arenas and the
    /// generated test layouts; absent: the paper's generator at the size
    /// of `arena`.
    pub generator: Option<GenParams>,
    /// The depth camera's noise, dropout and latency.
    pub noise: Noise,
    /// Per-episode randomisation of dynamics, camera and spawn.
    pub randomize: Randomize,
    /// A generator parameter ramped over the run (training lanes only).
    pub curriculum: Option<Curriculum>,
    /// A goal to reach (`[sim.goal]`; off: the paper's task). With it the
    /// observation gains the goal's floats.
    #[serde(skip_serializing_if = "Goal::is_off")]
    pub goal: Goal,
    /// A third action that holds the lateral setpoint.
    pub hold_action: bool,
    /// The camera's map in the observation (`[sim.map]`; off: none).
    #[serde(skip_serializing_if = "MapSpec::is_off")]
    pub map: MapSpec,
    /// The seen movers in the observation (`[sim.tracks]`; off: none).
    #[serde(skip_serializing_if = "TrackSpec::is_off")]
    pub tracks: TrackSpec,
}

/// `[sim.curriculum]`: one key of `[sim.generator]` ramps linearly from
/// `from` to the generator's own value over `over_env_steps` agent-steps,
/// in `stages` steps; at each stage every simulator regenerates its
/// training lanes (the agents then flying end their episodes as timeouts).
/// Validation and test arenas are always the generator's own.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Curriculum {
    /// The key under `[sim.generator]`, e.g. `spacing`.
    pub key: String,
    /// Its value at the start.
    pub from: f64,
    /// Agent-steps (every host's) until it reaches the generator's value.
    pub over_env_steps: u64,
    /// Changes along the way.
    #[serde(default = "default_stages")]
    pub stages: u32,
}

fn default_stages() -> u32 {
    5
}

/// `[actor]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ActorSection {
    /// Initial exploration rate.
    pub eps_start: f64,
    /// Final exploration rate.
    pub eps_end: f64,
    /// Transitions (across all actors) over which epsilon decays linearly,
    /// counted from the moment the replay memory is full.
    pub eps_decay: u64,
    /// One decaying epsilon, or Ape-X's fixed epsilon per agent.
    pub exploration: Exploration,
    /// Ape-X's base (0.4): the least greedy agent's epsilon.
    pub per_actor_base: f64,
    /// Ape-X's exponent spread (7): the greediest agent's epsilon is
    /// base^(1 + alpha).
    pub per_actor_alpha: f64,
    /// Threads for inference (0 = sized to the cores).
    pub threads: usize,
    /// Device for inference: "cpu", or "cuda" in a build with `--features cuda`.
    pub device: DeviceName,
}

/// `[replay]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplaySection {
    /// Capacity of the FIFO memory (transitions).
    pub capacity: usize,
    /// Transitions stored before training starts.
    pub min_fill: usize,
    /// Minibatch size.
    pub batch: usize,
    /// Minibatches queued ahead for the learner.
    pub prefetch: usize,
    /// Rate limit (as in Reverb): the sims pause while the transitions
    /// produced past `min_fill` exceed the transitions the learner has
    /// sampled divided by this ratio (sampled per inserted). 0 turns it off.
    pub samples_per_insert: f64,
    /// The memory is written through to `RUN_DIR/replay.bin` as it changes
    /// (a restarted or resumed replay starts with every transition it had)
    /// and the file is synced to disk every this many seconds. 0 turns the
    /// file off.
    pub snapshot_every_s: f64,
    /// Prioritized replay (Ape-X): rows are drawn in proportion to
    /// (|TD error| + `priority_eps`)^`priority_alpha`, the learner sends each
    /// minibatch's TD errors back, and each row's loss is weighted by
    /// (N·P)^−`priority_beta` over the batch's largest. False: uniform.
    pub prioritized: bool,
    /// Prioritization exponent (Ape-X: 0.6; 0 is uniform).
    pub priority_alpha: f64,
    /// Importance-sampling exponent (Ape-X: 0.4; 1 corrects fully).
    pub priority_beta: f64,
    /// Added to every |TD error| so that no row's priority is zero.
    pub priority_eps: f64,
}

/// `[learner]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LearnerSection {
    /// Adam learning rate at the first update.
    pub lr: f64,
    /// Learning rate after `lr_decay_updates` updates (linear decay, then held).
    pub lr_final: f64,
    /// Updates over which the learning rate falls from `lr` to `lr_final`; 0
    /// keeps `lr`.
    pub lr_decay_updates: u64,
    /// Discount.
    pub gamma: f64,
    /// Updates between target-network copies.
    pub target_update: u64,
    /// Largest update rate (Hz); 0 is unlimited.
    pub max_rate_hz: f64,
    /// Updates between weight publications.
    pub publish_every: u64,
    /// Polyak averaging of what the learner publishes (0 = off): the actors,
    /// the evaluations and `final.safetensors` get an exponential moving
    /// average of the online network's weights over about this many
    /// updates, folded in at every publication; training is unchanged.
    pub average_updates: f64,
    /// Seconds between checkpoints (`checkpoints/latest.safetensors` and the
    /// learner's whole state): a learner killed at any moment restarts with
    /// at most this much of its updates lost.
    pub checkpoint_every_s: f64,
    /// Threads for training (0 = sized to the cores).
    pub threads: usize,
    /// Huber loss threshold.
    pub huber_delta: f64,
    /// Rewards (n-step returns) are multiplied by this in the TD target, so
    /// that Q-values and TD errors sit in the Huber loss's quadratic range;
    /// episode returns, the threshold and every record stay unscaled.
    pub reward_scale: f64,
    /// The gradient's global L2 norm is clipped to this before Adam's step
    /// (Ape-X: 40); 0 turns clipping off.
    pub max_grad_norm: f64,
    /// Double DQN targets (the online network picks the next action).
    pub double_dqn: bool,
    /// Steps per transition return (n-step, as in Ape-X): the actors sum n
    /// discounted rewards and the learner bootstraps with gamma^n.
    pub n_step: usize,
    /// Device for training: "cpu", or "cuda" in a build with `--features cuda`.
    pub device: DeviceName,
    /// The two convolutions' channels (the design's `[16, 32]`).
    pub conv_channels: Vec<usize>,
    /// The hidden layers' widths, one to three (the design's `[64]`).
    pub hidden: Vec<usize>,
    /// The network's memory: "none" (the feedforward network), or
    /// "gru:WIDTH", a GRU of WIDTH units after the last hidden layer,
    /// trained on stored sequences (R2D2).
    pub memory: String,
    /// With memory: transitions per stored sequence, burn-in included.
    pub sequence_steps: usize,
    /// With memory: steps at a sequence's start that only warm its stored
    /// state up (no loss); sequences overlap by this many steps.
    pub burn_in: usize,
    /// Weight of the TD loss beside `teacher.loss = "imitation"` (1: as
    /// without a teacher; 0: imitation alone), rising to 1 as the teacher
    /// fades.
    pub td_weight: f64,
}

impl Default for SimSection {
    fn default() -> Self {
        Self {
            envs: 0,
            agents: 50,
            arena: PathBuf::from("configs/arenas/train.toml"),
            generated_lanes: 15,
            fresh_layouts: 0,
            renderer: RendererKind::Cpu,
            observation_mode: ObservationMode::Batched,
            interactive: false,
            physics_dt: 0.02,
            physics: PhysicsKind::Direct,
            action_period: 1.0,
            max_steps: 400,
            depth_range: None,
            camera: crate::camera::CameraSection::default(),
            render_threads: 0,
            forward_speed: 1.0,
            lateral_step: 0.25,
            max_lateral_speed: 3.0,
            drone_radius: 0.3,
            reward_step: 3.0,
            reward_collision: -100.0,
            reward_timeout: -10.0,
            reward_goal: 3.0,
            generator: None,
            noise: Noise::default(),
            randomize: Randomize::default(),
            curriculum: None,
            goal: Goal::default(),
            map: MapSpec::default(),
            tracks: TrackSpec::default(),
            hold_action: false,
            frames: rotorhive_msg::FRAMES,
            frame_stride: 1,
        }
    }
}

impl Default for ActorSection {
    fn default() -> Self {
        Self {
            eps_start: 1.0,
            eps_end: 0.1,
            eps_decay: 150_000,
            exploration: Exploration::Decay,
            per_actor_base: 0.4,
            per_actor_alpha: 7.0,
            threads: 0,
            device: DeviceName::Cpu,
        }
    }
}

impl Default for ReplaySection {
    fn default() -> Self {
        Self {
            capacity: 200_000,
            min_fill: 15_000,
            batch: 32,
            prefetch: 4,
            samples_per_insert: 0.75,
            snapshot_every_s: 60.0,
            prioritized: false,
            priority_alpha: 0.6,
            priority_beta: 0.4,
            priority_eps: 1e-3,
        }
    }
}

impl Default for LearnerSection {
    fn default() -> Self {
        Self {
            lr: 5e-4,
            lr_final: 5e-4,
            lr_decay_updates: 0,
            gamma: 0.99,
            target_update: 150,
            max_rate_hz: 0.0,
            publish_every: 10,
            average_updates: 0.0,
            checkpoint_every_s: 1.0,
            threads: 0,
            huber_delta: 1.0,
            reward_scale: 0.01,
            max_grad_norm: 10.0,
            double_dqn: true,
            n_step: 3,
            device: DeviceName::Cpu,
            conv_channels: vec![16, 32],
            hidden: vec![64],
            memory: "none".into(),
            sequence_steps: 22,
            burn_in: 8,
            td_weight: 1.0,
        }
    }
}

/// `teacher.policy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TeacherPolicy {
    /// No teacher: training exactly as without the section.
    None,
    /// The simulator's privileged planner (`hive eval --policy planner`).
    Planner,
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

/// `teacher.label_search`: how a label's searches ask whether an action
/// starts a way clear for `label_horizon` actions (breadth first by
/// default: the levels' teachers were measured so; a level that ships
/// depth first was decided by the seed harness).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LabelSearch {
    /// Breadth first, every layer whole to the horizon.
    Breadth,
    /// Depth first, stopping at the first such way (the states merged on
    /// the planner's grid as breadth first merges them): the same answers
    /// (all 3,200 of a test), several times cheaper where a way exists.
    Depth,
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
    /// What the planner knows (its name, as `hive eval --sight`).
    pub sight: Sight,
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
    /// How a label's searches go: `breadth` (every layer whole) or
    /// `depth` (stopping at the first way clear).
    pub label_search: LabelSearch,
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
            sight: Sight::All,
            memory_s: 0,
            demo_agents: 5,
            label_share: 0.5,
            label_horizon: 10,
            label_search: LabelSearch::Breadth,
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

    /// What the planner is told: its sight, remembering `memory_s` (0:
    /// the whole episode).
    pub fn planner_sight(&self) -> Sight {
        self.sight.with_memory((self.memory_s > 0).then_some(self.memory_s))
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
        if self.memory_s > 0 && !self.sight.remembers() {
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
