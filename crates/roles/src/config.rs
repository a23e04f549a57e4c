//! Training configuration in two phases: serde structs with defaults that
//! refuse unknown keys, `--set key=value` overrides applied to the TOML tree,
//! then validation into a config every role can trust. The resolved config is
//! written into the run directory and read back by the roles.

use std::path::{Path, PathBuf};

use crate::error::{Doing, Result, RoleError, config_err};
use serde::{Deserialize, Serialize};

use rotorhive_msg::Shapes;
use rotorhive_sim::{
    Arena, CameraSpec, GenParams, Goal, Noise, PhysicsKind, Randomize, RendererKind, SimConfig,
};

/// `sim.observation_mode`: the records' enum, so that `summary.json` names
/// the mode with the config's own word.
pub use rotorhive_records::ObservationMode;

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

/// The whole configuration of a run.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Seed of everything random in the run.
    pub seed: u64,
    /// Wall-clock budget of `hive train` (s).
    pub max_seconds: f64,
    /// Rolling mean episode reward that counts as converged.
    pub threshold: f64,
    /// Episodes in the rolling mean.
    pub rolling_window: usize,
    /// A run that is a pure function of its config and seed: the roles
    /// follow [`crate::schedule::Schedule`] instead of their own pace, and
    /// the run ends after `max_env_steps` agent-steps (not at convergence).
    pub deterministic: bool,
    /// Budget in agent-steps (every host's agents); 0 = none. Required by a
    /// deterministic run.
    pub max_env_steps: u64,
    /// Stop at convergence (the threshold, then a good enough evaluation);
    /// false runs to the budget (`hive bench seeds` compares arms so).
    pub early_stop: bool,
    /// TensorBoard event files in `RUN_DIR/tb/` (scalars once a second).
    pub tensorboard: bool,
    /// Simulator settings.
    pub sim: SimSection,
    /// Actor settings.
    pub actor: ActorSection,
    /// Replay settings.
    pub replay: ReplaySection,
    /// Learner settings.
    pub learner: LearnerSection,
    /// Greedy evaluation during training.
    pub eval: EvalSection,
    /// Hosts of the run (`hive train --listen`, `hive worker`).
    pub cluster: ClusterSection,
    /// The privileged teacher (none by default).
    pub teacher: crate::teacher::TeacherSection,
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
            validation_arenas: 10,
            target_success: 0.9,
            after_threshold_s: 240.0,
            confirm_episodes: 300,
            every_env_steps: 0,
            test_arenas: vec![PathBuf::from("configs/arenas/test.toml")],
            test_layouts: 4,
        }
    }
}

/// `[sim]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimSection {
    /// Simulator processes.
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
    /// Depth clip range (m).
    pub depth_range: f32,
    /// Depth frames stacked in one observation, one action period apart
    /// (2: the paper's, previous and current); 1 to
    /// [`rotorhive_msg::MAX_FRAMES`].
    pub frames: usize,
    /// Action periods between two stacked frames (1: consecutive; 3 with
    /// four frames: the views of 9, 6 and 3 periods ago and now); 1 to
    /// [`rotorhive_msg::MAX_FRAME_STRIDE`].
    pub frame_stride: usize,
    /// Threads for CPU rendering.
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
    /// Threads for inference.
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
    /// Seconds between checkpoints (`checkpoints/latest.safetensors` and the
    /// learner's whole state): a learner killed at any moment restarts with
    /// at most this much of its updates lost.
    pub checkpoint_every_s: f64,
    /// Threads for training.
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
}

/// `configs/default.toml`, the one source of the defaults: `hive train`
/// without a config reads it, and the `Default` impls below must agree with
/// it key for key (a test checks), since they fill keys a config leaves out.
pub const DEFAULT_TOML: &str = include_str!("../../../configs/default.toml");

impl Default for Config {
    fn default() -> Self {
        Self {
            seed: 1,
            max_seconds: 600.0,
            threshold: 300.0,
            rolling_window: 50,
            deterministic: false,
            max_env_steps: 0,
            early_stop: true,
            tensorboard: true,
            sim: SimSection::default(),
            actor: ActorSection::default(),
            replay: ReplaySection::default(),
            learner: LearnerSection::default(),
            eval: EvalSection::default(),
            cluster: ClusterSection::default(),
            teacher: crate::teacher::TeacherSection::default(),
        }
    }
}

impl Default for SimSection {
    fn default() -> Self {
        Self {
            envs: 1,
            agents: 50,
            arena: PathBuf::from("configs/arenas/train.toml"),
            generated_lanes: 15,
            renderer: RendererKind::Cpu,
            observation_mode: ObservationMode::Batched,
            interactive: false,
            physics_dt: 0.02,
            physics: PhysicsKind::Direct,
            action_period: 1.0,
            max_steps: 400,
            depth_range: 20.0,
            render_threads: 1,
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
            threads: 1,
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
            checkpoint_every_s: 1.0,
            threads: 1,
            huber_delta: 1.0,
            reward_scale: 0.01,
            max_grad_norm: 10.0,
            double_dqn: true,
            n_step: 3,
            device: DeviceName::Cpu,
        }
    }
}

/// A key that must be a positive number.
fn positive(key: &str, v: f64) -> Result<()> {
    if !(v.is_finite() && v > 0.0) {
        config_err!("key `{key}` must be positive, got {v}");
    }
    Ok(())
}

impl Config {
    /// Reads a config file (or the defaults when `path` is `None`), applies
    /// `key=value` overrides and validates the result.
    /// Whether a sim publishes all its agents' observations in one message.
    pub fn batched(&self) -> bool {
        self.sim.observation_mode == ObservationMode::Batched
    }

    /// Observation messages a sim publishes per step.
    pub fn obs_messages_per_step(&self) -> usize {
        if self.batched() { 1 } else { self.sim.agents }
    }

    /// Environments of the whole run, on every host.
    pub fn envs_total(&self) -> usize {
        self.sim.envs + self.cluster.envs_elsewhere
    }

    /// Agents of the whole run, on every host.
    pub fn agents_total(&self) -> usize {
        self.sim.envs * self.sim.agents + self.cluster.agents_elsewhere
    }

    pub fn load(path: Option<&Path>, overrides: &[String]) -> Result<Self> {
        let (text, source) = match path {
            Some(p) => (
                std::fs::read_to_string(p)
                    .doing_with(|| format!("config {}: cannot read", p.display()))?,
                p.display().to_string(),
            ),
            // The defaults are `configs/default.toml`, built in.
            None => (DEFAULT_TOML.to_string(), "defaults (configs/default.toml)".to_string()),
        };
        Self::parse(&text, &source, overrides)
    }

    /// The config of a level (`configs/levels/NAME.toml`, built in), with
    /// `key=value` overrides.
    pub fn level(name: &str, overrides: &[String]) -> Result<Self> {
        let text = crate::levels::text(name)?;
        Self::parse(text, &format!("level {name} (configs/levels/{name}.toml)"), overrides)
    }

    /// Parses config TOML (`source` names it in messages), applies
    /// overrides and validates.
    pub fn parse(text: &str, source: &str, overrides: &[String]) -> Result<Self> {
        let mut table: toml::Table = toml::from_str(text).map_err(|e| {
            RoleError::Config(format!("config {source}: {}", e.to_string().trim_end()))
        })?;
        for o in overrides {
            apply_override(&mut table, o)?;
        }
        let cfg: Config = Config::deserialize(toml::Value::Table(table)).map_err(|e| {
            RoleError::Config(format!("config {source}: {}", e.to_string().trim_end()))
        })?;
        cfg.validate().doing_with(|| format!("config {source}"))?;
        Ok(cfg)
    }

    /// Checks every value a role relies on.
    pub fn validate(&self) -> Result<()> {
        self.validate_run()?;
        self.validate_sim()?;
        self.validate_learning()
    }

    /// The run's own keys: budget, determinism, cluster, evaluation.
    fn validate_run(&self) -> Result<()> {
        positive("max_seconds", self.max_seconds)?;
        if self.deterministic {
            if self.max_env_steps == 0 {
                config_err!(
                    "key `deterministic` needs a budget: set `max_env_steps` (agent-steps) above 0"
                );
            }
            if self.replay.samples_per_insert <= 0.0 {
                config_err!(
                    "key `deterministic` needs `replay.samples_per_insert` above 0 (the schedule follows it)"
                );
            }
            if self.learner.max_rate_hz != 0.0 {
                config_err!(
                    "key `deterministic` needs `learner.max_rate_hz = 0` (the schedule sets the pace)"
                );
            }
            if self.cluster.workers > 0 || self.cluster.envs_elsewhere > 0 {
                config_err!(
                    "key `deterministic` is not supported across hosts yet (`cluster.workers` is {})",
                    self.cluster.workers
                );
            }
        }
        positive("cluster.join_timeout_s", self.cluster.join_timeout_s)?;
        positive("cluster.reconnect_s", self.cluster.reconnect_s)?;
        positive("rolling_window", self.rolling_window as f64)?;
        let e = &self.eval;
        for (k, v) in [("eval.every_s", e.every_s), ("eval.after_threshold_s", e.after_threshold_s)]
        {
            if !(v.is_finite() && v >= 0.0) {
                config_err!("key `{k}` must be 0 or positive, got {v}");
            }
        }
        positive("eval.episodes", e.episodes as f64)?;
        positive("eval.validation_arenas", e.validation_arenas as f64)?;
        if !(0.0..=1.0).contains(&e.target_success) {
            config_err!(
                "key `eval.target_success` must be a rate between 0 and 1, got {}",
                e.target_success
            );
        }
        Ok(())
    }

    /// The simulator's keys.
    fn validate_sim(&self) -> Result<()> {
        let s = &self.sim;
        positive("sim.envs", s.envs as f64)?;
        positive("sim.agents", s.agents as f64)?;
        positive("sim.physics_dt", s.physics_dt as f64)?;
        positive("sim.action_period", s.action_period as f64)?;
        positive("sim.max_steps", s.max_steps as f64)?;
        positive("sim.depth_range", s.depth_range as f64)?;
        positive("sim.render_threads", s.render_threads as f64)?;
        if s.physics_dt > s.action_period {
            config_err!(
                "key `sim.physics_dt` ({}) must not exceed `sim.action_period` ({})",
                s.physics_dt,
                s.action_period
            );
        }
        if !(1..=rotorhive_msg::MAX_FRAMES).contains(&s.frames) {
            config_err!(
                "key `sim.frames` must be 1 to {}, got {}",
                rotorhive_msg::MAX_FRAMES,
                s.frames
            );
        }
        if !(1..=rotorhive_msg::MAX_FRAME_STRIDE).contains(&s.frame_stride) {
            config_err!(
                "key `sim.frame_stride` must be 1 to {}, got {}",
                rotorhive_msg::MAX_FRAME_STRIDE,
                s.frame_stride
            );
        }
        if s.generated_lanes > 256 {
            config_err!("key `sim.generated_lanes` must be at most 256, got {}", s.generated_lanes);
        }
        let (max_envs, max_agents) =
            (rotorhive_msg::MAX_ENVS_PER_HOST, rotorhive_msg::MAX_AGENTS_PER_ENV);
        if s.envs > max_envs || s.agents > max_agents {
            config_err!(
                "keys `sim.envs` ({}) and `sim.agents` ({}) must be at most {max_envs} and \
                 {max_agents}",
                s.envs,
                s.agents
            );
        }
        self.validate_task()
    }

    /// The task's keys: speeds, rewards, generator, noise, randomisation,
    /// curriculum.
    fn validate_task(&self) -> Result<()> {
        let s = &self.sim;
        positive("sim.forward_speed", s.forward_speed as f64)?;
        positive("sim.lateral_step", s.lateral_step as f64)?;
        if !(s.max_lateral_speed.is_finite() && s.max_lateral_speed >= s.lateral_step) {
            config_err!(
                "key `sim.max_lateral_speed` must be at least `sim.lateral_step` ({}), got {}",
                s.lateral_step,
                s.max_lateral_speed
            );
        }
        if !(s.drone_radius > 0.0 && s.drone_radius <= 2.0) {
            config_err!("key `sim.drone_radius` must lie in (0, 2] m, got {}", s.drone_radius);
        }
        for (k, v) in [
            ("sim.reward_step", s.reward_step),
            ("sim.reward_collision", s.reward_collision),
            ("sim.reward_timeout", s.reward_timeout),
            ("sim.reward_goal", s.reward_goal),
        ] {
            if !(v.is_finite() && v.abs() <= 1e6) {
                config_err!("key `{k}` must be a finite number of at most 1e6 in size, got {v}");
            }
        }
        if let Some(g) = &s.generator {
            g.validate().map_err(|e| {
                RoleError::Config(format!("key `sim.generator.{}`: {}", e.key, e.message))
            })?;
        }
        if s.arena.as_os_str().is_empty() && (s.generator.is_none() || s.generated_lanes == 0) {
            config_err!(
                "key `sim.arena` is empty: training then needs `[sim.generator]` and `sim.generated_lanes` above 0"
            );
        }
        s.noise
            .validate()
            .map_err(|(k, m)| RoleError::Config(format!("key `sim.noise.{k}` {m}")))?;
        s.randomize
            .validate()
            .map_err(|(k, m)| RoleError::Config(format!("key `sim.randomize.{k}` {m}")))?;
        s.goal.validate().map_err(|(k, m)| RoleError::Config(format!("key `sim.goal.{k}` {m}")))?;
        let latency = s.noise.latency_s != [0.0, 0.0];
        if s.physics == PhysicsKind::Rapier && (latency || s.randomize.dynamics()) {
            config_err!(
                "keys `sim.noise.latency_s` and the dynamics of `[sim.randomize]` need `sim.physics = \"direct\"` (the rapier path is the reference)"
            );
        }
        if s.noise.latency_s[1] >= s.action_period {
            config_err!(
                "key `sim.noise.latency_s` must stay below `sim.action_period` ({} s), got {:?}",
                s.action_period,
                s.noise.latency_s
            );
        }
        if let Some(c) = &s.curriculum {
            if c.stages == 0 || c.over_env_steps == 0 {
                config_err!(
                    "keys `sim.curriculum.stages` and `sim.curriculum.over_env_steps` must be positive"
                );
            }
            if s.generator.is_none() || s.generated_lanes == 0 {
                config_err!(
                    "key `sim.curriculum` ramps a key of `[sim.generator]` over the generated lanes: give both"
                );
            }
            self.generator_at_stage(0)?;
        }
        let e = &self.eval;
        if e.test_arenas.is_empty() && e.test_layouts == 0 {
            config_err!(
                "keys `eval.test_arenas` and `eval.test_layouts`: a config needs at least one test arena or layout"
            );
        }
        if e.test_layouts > 64 {
            config_err!("key `eval.test_layouts` must be at most 64, got {}", e.test_layouts);
        }
        Ok(())
    }

    /// The actor's, replay's and learner's keys.
    fn validate_learning(&self) -> Result<()> {
        self.validate_actor()?;
        self.validate_replay()?;
        self.teacher.validate(self.replay.prioritized)?;
        self.validate_learner()
    }

    /// The actor's keys, the n-step return, and both devices.
    fn validate_actor(&self) -> Result<()> {
        let a = &self.actor;
        for (k, v) in [("actor.eps_start", a.eps_start), ("actor.eps_end", a.eps_end)] {
            if !(0.0..=1.0).contains(&v) {
                config_err!("key `{k}` must lie in [0, 1], got {v}");
            }
        }
        positive("actor.threads", a.threads as f64)?;
        if !(a.per_actor_base > 0.0 && a.per_actor_base <= 1.0) {
            config_err!("key `actor.per_actor_base` must lie in (0, 1], got {}", a.per_actor_base);
        }
        if !(a.per_actor_alpha.is_finite() && a.per_actor_alpha >= 0.0) {
            config_err!(
                "key `actor.per_actor_alpha` must be 0 or positive, got {}",
                a.per_actor_alpha
            );
        }
        if !(1..=16).contains(&self.learner.n_step) {
            config_err!(
                "key `learner.n_step` must be between 1 and 16, got {}",
                self.learner.n_step
            );
        }
        if !(self.replay.snapshot_every_s.is_finite() && self.replay.snapshot_every_s >= 0.0) {
            config_err!(
                "key `replay.snapshot_every_s` must be 0 (off) or positive, got {}",
                self.replay.snapshot_every_s
            );
        }
        if !(self.replay.samples_per_insert.is_finite() && self.replay.samples_per_insert >= 0.0) {
            config_err!(
                "key `replay.samples_per_insert` must be 0 (off) or positive, got {}",
                self.replay.samples_per_insert
            );
        }
        for (k, v) in [("actor.device", &a.device), ("learner.device", &self.learner.device)] {
            rotorhive_model::device(v.kind()).doing_with(|| format!("key `{k}`"))?;
        }
        Ok(())
    }

    /// The replay's keys.
    fn validate_replay(&self) -> Result<()> {
        let r = &self.replay;
        positive("replay.capacity", r.capacity as f64)?;
        positive("replay.batch", r.batch as f64)?;
        positive("replay.prefetch", r.prefetch as f64)?;
        if r.batch > r.capacity {
            config_err!(
                "key `replay.batch` ({}) is larger than `replay.capacity` ({})",
                r.batch,
                r.capacity
            );
        }
        for (k, v) in
            [("replay.priority_alpha", r.priority_alpha), ("replay.priority_beta", r.priority_beta)]
        {
            if !(0.0..=1.0).contains(&v) {
                config_err!("key `{k}` must lie in [0, 1], got {v}");
            }
        }
        positive("replay.priority_eps", r.priority_eps)?;
        if r.min_fill > r.capacity {
            config_err!(
                "key `replay.min_fill` ({}) is larger than `replay.capacity` ({})",
                r.min_fill,
                r.capacity
            );
        }
        Ok(())
    }

    /// The learner's keys.
    fn validate_learner(&self) -> Result<()> {
        let l = &self.learner;
        positive("learner.lr", l.lr)?;
        positive("learner.lr_final", l.lr_final)?;
        if !(0.0..1.0).contains(&l.gamma) {
            config_err!("key `learner.gamma` must lie in [0, 1), got {}", l.gamma);
        }
        positive("learner.target_update", l.target_update as f64)?;
        positive("learner.publish_every", l.publish_every as f64)?;
        positive("learner.checkpoint_every_s", l.checkpoint_every_s)?;
        positive("learner.threads", l.threads as f64)?;
        positive("learner.huber_delta", l.huber_delta)?;
        positive("learner.reward_scale", l.reward_scale)?;
        if !(l.max_grad_norm.is_finite() && l.max_grad_norm >= 0.0) {
            config_err!(
                "key `learner.max_grad_norm` must be 0 (off) or positive, got {}",
                l.max_grad_norm
            );
        }
        if !(l.max_rate_hz.is_finite() && l.max_rate_hz >= 0.0) {
            config_err!(
                "key `learner.max_rate_hz` must be 0 (unlimited) or positive, got {}",
                l.max_rate_hz
            );
        }
        Ok(())
    }

    /// Loads the arena this config names.
    pub fn arena(&self) -> Result<Arena> {
        Ok(Arena::load(&self.sim.arena)?)
    }

    /// Loads the training arena, or `None` where `sim.arena` is empty.
    fn base_arena(&self) -> Result<Option<Arena>> {
        if self.sim.arena.as_os_str().is_empty() { Ok(None) } else { self.arena().map(Some) }
    }

    /// `[sim.generator]` with the run's drone radius, where the config
    /// has one.
    pub fn generator(&self) -> Option<GenParams> {
        self.sim
            .generator
            .as_ref()
            .map(|g| GenParams { drone_radius: self.sim.drone_radius, ..g.clone() })
    }

    /// Parameters of generated arenas: `[sim.generator]`, else the paper's
    /// generator at the training arena's size.
    pub fn gen_params(&self) -> Result<GenParams> {
        match self.generator() {
            Some(g) => Ok(g),
            None => Ok(self.gen_params_like(&self.arena()?)),
        }
    }

    /// The generator's parameters like [`Config::gen_params`], for lanes
    /// beside `base`.
    fn gen_params_like(&self, base: &Arena) -> GenParams {
        self.generator().unwrap_or_else(|| GenParams {
            length: base.length,
            width: base.width,
            height: base.height,
            drone_radius: self.sim.drone_radius,
            ..GenParams::default()
        })
    }

    /// The generator at curriculum stage `stage` (0 = the start): the
    /// ramped key set between `from` and the generator's own value.
    pub fn generator_at_stage(&self, stage: u32) -> Result<GenParams> {
        let p = self.gen_params()?;
        let Some(c) = &self.sim.curriculum else {
            return Ok(p);
        };
        let mut table = toml::Table::try_from(&p)
            .map_err(|e| RoleError::Config(format!("key `sim.generator`: {e}")))?;
        let Some(to) = table
            .get(&c.key)
            .and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)))
        else {
            config_err!(
                "key `sim.curriculum.key`: `{}` is not a number of `[sim.generator]`",
                c.key
            );
        };
        let t = (stage.min(c.stages) as f64) / c.stages as f64;
        let value = c.from + (to - c.from) * t;
        let v = if table[&c.key].is_integer() {
            toml::Value::Integer(value.round() as i64)
        } else {
            toml::Value::Float(value)
        };
        table.insert(c.key.clone(), v);
        let q: GenParams = GenParams::deserialize(toml::Value::Table(table))
            .map_err(|e| RoleError::Config(format!("key `sim.curriculum`: {e}")))?;
        q.validate().map_err(|e| {
            RoleError::Config(format!("key `sim.curriculum` at stage {stage}: {e}"))
        })?;
        Ok(GenParams { drone_radius: self.sim.drone_radius, ..q })
    }

    /// The curriculum stage at `env_steps` agent-steps of the run.
    pub fn curriculum_stage(&self, env_steps: u64) -> u32 {
        match &self.sim.curriculum {
            Some(c) => (env_steps.saturating_mul(c.stages as u64) / c.over_env_steps)
                .min(c.stages as u64) as u32,
            None => 0,
        }
    }

    /// The arenas environment `env` trains in: `sim.arena` (unless empty)
    /// and `sim.generated_lanes` generated ones (seeds that no shipped
    /// arena, validation arena or test layout uses).
    pub fn lane_arenas(&self, env: usize) -> Result<Vec<Arena>> {
        self.lane_arenas_at(env, 0)
    }

    /// [`Config::lane_arenas`] at curriculum stage `stage`.
    pub fn lane_arenas_at(&self, env: usize, stage: u32) -> Result<Vec<Arena>> {
        let base = self.base_arena()?;
        let p = match &base {
            Some(b) if self.sim.curriculum.is_none() => self.gen_params_like(b),
            _ => self.generator_at_stage(stage)?,
        };
        Ok(self.lanes_with(base, env, &p))
    }

    /// `base` and the `sim.generated_lanes` generated arenas of environment
    /// `env` beside it, of `base`'s size (what [`Config::lane_arenas`] gives
    /// for an arena that is not a file, as the Python package's).
    pub fn lanes_around(&self, base: Arena, env: usize) -> Vec<Arena> {
        let p = self.gen_params_like(&base);
        self.lanes_with(Some(base), env, &p)
    }

    fn lanes_with(&self, base: Option<Arena>, env: usize, p: &GenParams) -> Vec<Arena> {
        let mut v: Vec<Arena> = base.into_iter().collect();
        for k in 0..self.sim.generated_lanes {
            let seed = crate::seeds::lane(self.seed, env, k);
            v.push(Arena::generate(&format!("lane-{k}"), seed, p));
        }
        v
    }

    /// The held-out test set: `eval.test_arenas` (files) and
    /// `eval.test_layouts` layouts of the generator.
    pub fn test_arenas(&self) -> Result<Vec<Arena>> {
        let mut v = Vec::new();
        for f in &self.eval.test_arenas {
            v.push(Arena::load(f)?);
        }
        if self.eval.test_layouts > 0 {
            let p = self.gen_params()?;
            v.extend((0..self.eval.test_layouts).map(|k| {
                Arena::generate(&format!("test-layout-{}", k + 1), crate::seeds::test_layout(k), &p)
            }));
        }
        Ok(v)
    }

    /// The arenas of greedy evaluations during training: `eval.arena`, or by
    /// default `eval.validation_arenas` generated arenas that are neither
    /// trained on nor the test arena.
    pub fn eval_arenas(&self) -> Result<Vec<Arena>> {
        if !self.eval.arena.is_empty() {
            return Ok(vec![Arena::load(Path::new(&self.eval.arena))?]);
        }
        let p = self.gen_params()?;
        Ok((0..self.eval.validation_arenas)
            .map(|k| {
                Arena::generate(&format!("validation-{k}"), crate::seeds::validation_arena(k), &p)
            })
            .collect())
    }

    /// The simulator settings for one environment.
    pub fn sim_config(&self) -> SimConfig {
        let s = &self.sim;
        SimConfig {
            agents: s.agents,
            physics_dt: s.physics_dt,
            physics: s.physics,
            action_period: s.action_period,
            max_steps: s.max_steps,
            interactive: s.interactive,
            camera: CameraSpec { range: s.depth_range, ..CameraSpec::default() },
            render_threads: s.render_threads,
            renderer: s.renderer,
            batched: self.batched(),
            forward_speed: s.forward_speed,
            lateral_step: s.lateral_step,
            max_lateral_speed: s.max_lateral_speed,
            drone_radius: s.drone_radius,
            reward_step: s.reward_step,
            reward_collision: s.reward_collision,
            reward_timeout: s.reward_timeout,
            reward_goal: s.reward_goal,
            noise: s.noise.clone(),
            randomize: s.randomize.clone(),
            goal: s.goal.clone(),
            hold_action: s.hold_action,
            frames: s.frames,
            frame_stride: s.frame_stride,
            ..SimConfig::default()
        }
    }

    /// The run's observation and action shapes (from `sim.frames`,
    /// `sim.frame_stride`, `[sim.goal]` and `sim.hold_action`): every
    /// role's layouts and the network follow them.
    pub fn shapes(&self) -> Shapes {
        Shapes::task(self.sim.frames, self.sim.goal.enabled, self.sim.hold_action)
            .with_stride(self.sim.frame_stride)
    }

    /// The resolved config as TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a config always serialises")
    }

    /// What a checkpoint's header says of the run that wrote it: the CRC-32C
    /// of the resolved config (`config.toml` of the run directory).
    pub fn checkpoint_tags(&self) -> Vec<(&'static str, String)> {
        vec![("config_crc32c", format!("{:08x}", crc32c::crc32c(self.to_toml().as_bytes())))]
    }
}

/// Applies one `a.b=value` override; the value is parsed as TOML, or taken as
/// a string when it does not parse.
fn apply_override(table: &mut toml::Table, o: &str) -> Result<()> {
    let Some((key, raw)) = o.split_once('=') else {
        config_err!("override {o:?} is not of the form key=value");
    };
    let key = key.trim();
    let value: toml::Value = match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
        Ok(mut t) => t.remove("v").expect("parsed"),
        Err(_) => toml::Value::String(raw.to_string()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        config_err!("override {o:?}: empty key part");
    }
    let mut t = table;
    for p in &parts[..parts.len() - 1] {
        t = t
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| RoleError::Config(format!("override {o:?}: `{p}` is not a section")))?;
    }
    t.insert(parts[parts.len() - 1].to_string(), value);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_are_configs_default_toml() {
        // What `hive train` without a config resolves to, against the file
        // the README trains with and against the built-in defaults.
        let none = Config::load(None, &[]).unwrap().to_toml();
        let file = Config::load(
            Some(
                &std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                    .join("../../configs/default.toml"),
            ),
            &[],
        )
        .unwrap()
        .to_toml();
        assert_eq!(none, file);
        assert_eq!(
            Config::default().to_toml(),
            none,
            "Config::default() and configs/default.toml disagree"
        );
    }

    #[test]
    fn defaults_validate_and_round_trip() {
        let c = Config::default();
        c.validate().unwrap();
        let back: Config = toml::from_str(&c.to_toml()).unwrap();
        assert_eq!(back.to_toml(), c.to_toml());
    }

    #[test]
    fn overrides_apply_and_bad_values_are_named() {
        let c = Config::load(
            None,
            &[
                "sim.agents=7".into(),
                "learner.lr=0.01".into(),
                "sim.observation_mode=batched".into(),
            ],
        )
        .unwrap();
        assert_eq!(c.sim.agents, 7);
        assert_eq!(c.learner.lr, 0.01);
        assert_eq!(c.sim.observation_mode, ObservationMode::Batched);
        let e = format!(
            "{:#}",
            Config::load(None, &["sim.observation_mode=sideways".into()]).unwrap_err()
        );
        assert!(e.contains("sim.observation_mode"), "{e}");
        let e = format!("{:#}", Config::load(None, &["sim.agents=0".into()]).unwrap_err());
        assert!(e.contains("sim.agents"), "{e}");
        let e = format!("{:#}", Config::load(None, &["sim.agnets=3".into()]).unwrap_err());
        assert!(e.contains("agnets"), "{e}");
        let e = format!("{:#}", Config::load(None, &["replay.batch=300000".into()]).unwrap_err());
        assert!(e.contains("replay.batch"), "{e}");
        // The task's keys and sections, named when wrong.
        let c = Config::load(
            None,
            &[
                "sim.forward_speed=2.0".into(),
                "sim.generator.spacing=3.0".into(),
                "sim.noise.dropout=0.02".into(),
            ],
        )
        .unwrap();
        assert_eq!(
            (
                c.sim_config().forward_speed,
                c.gen_params().unwrap().spacing,
                c.sim_config().noise.dropout
            ),
            (2.0, 3.0, 0.02)
        );
        for (set, key) in [
            ("sim.generator.per_row=9", "sim.generator.per_row"),
            ("sim.generator.spacnig=3", "spacnig"),
            ("sim.noise.dropout=0.9", "sim.noise.dropout"),
            ("sim.randomize.mass=-1", "sim.randomize.mass"),
            ("sim.lateral_step=0", "sim.lateral_step"),
            ("sim.frames=0", "sim.frames"),
            ("sim.frames=9", "sim.frames"),
            ("sim.frame_stride=0", "sim.frame_stride"),
            ("sim.frame_stride=9", "sim.frame_stride"),
            ("sim.reward_collision=nan", "sim.reward_collision"),
        ] {
            let e = format!("{:#}", Config::load(None, &[set.into()]).unwrap_err());
            assert!(e.contains(key), "{set}: {e}");
        }
        // Randomised dynamics live on the direct path only.
        let e = format!(
            "{:#}",
            Config::load(None, &["sim.physics=\"rapier\"".into(), "sim.randomize.wind=0.5".into()])
                .unwrap_err()
        );
        assert!(e.contains("direct"), "{e}");
        // A curriculum ramps a generator key between stages.
        let c = Config::load(
            None,
            &[
                "sim.generator.spacing=3.0".into(),
                "sim.curriculum.key=\"spacing\"".into(),
                "sim.curriculum.from=6.0".into(),
                "sim.curriculum.over_env_steps=100000".into(),
                "sim.curriculum.stages=3".into(),
            ],
        )
        .unwrap();
        let at = |s| c.generator_at_stage(s).unwrap().spacing;
        assert_eq!((at(0), at(1), at(3)), (6.0, 5.0, 3.0));
        assert_eq!(
            (c.curriculum_stage(0), c.curriculum_stage(40_000), c.curriculum_stage(10_000_000)),
            (0, 1, 3)
        );
        let e = format!(
            "{:#}",
            Config::load(
                None,
                &[
                    "sim.generator.spacing=3.0".into(),
                    "sim.curriculum.key=\"colour\"".into(),
                    "sim.curriculum.from=1".into(),
                    "sim.curriculum.over_env_steps=5".into()
                ]
            )
            .unwrap_err()
        );
        assert!(e.contains("colour"), "{e}");
        let e = format!("{:#}", Config::load(None, &["sim.agents=\"many\"".into()]).unwrap_err());
        assert!(e.contains("agents") || e.contains("invalid type"), "{e}");
    }
}
