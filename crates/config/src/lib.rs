//! Training configuration in two phases: serde structs with defaults that
//! refuse unknown keys, `--set key=value` overrides applied to the TOML tree,
//! then validation into a config every role can trust. The resolved config is
//! written into the run directory and read back by the roles.

mod arenas;
pub mod camera;
pub mod error;
pub mod levels;
mod sections;
mod sizing;
pub mod streams;
mod validate;

use std::path::Path;

use crate::error::{Result, config_err};
use serde::{Deserialize, Serialize};

use rotorhive_msg::Shapes;

pub use sizing::{SIZED_KEYS, Sizing};

pub use error::{ConfigError, Doing};
pub use sections::{
    ActorSection, ClusterSection, Curriculum, DeviceName, EvalSection, Exploration, LabelSearch,
    LearnerSection, ReplaySection, SimSection, TeacherLabels, TeacherLoss, TeacherPolicy,
    TeacherSection,
};

/// `sim.observation_mode`: the records' enum, so that `summary.json` names
/// the mode with the config's own word.
pub use rotorhive_records::ObservationMode;

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
    /// Cores the run is sized for (0 = all of this machine's; more than
    /// it has are not used): `sim.envs`, `sim.render_threads`,
    /// `actor.threads` and `learner.threads` left at 0 take values in
    /// proportion (`summary.json`'s `sizing`).
    pub cores: usize,
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
    pub teacher: TeacherSection,
    /// The keys this config left at 0 that sizing filled (not a key).
    #[serde(skip)]
    pub sized: Vec<&'static str>,
}

/// The `--set` that turns a config's teacher off, first among the sets of
/// what flies no teacher (an environment, a simulator bench, an
/// evaluation): a level's teacher that reads
/// the camera's map (L4's) then does not refuse the map turned off.
pub const NO_TEACHER: &str = "teacher.policy=\"none\"";

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
            cores: 0,
            sim: SimSection::default(),
            actor: ActorSection::default(),
            replay: ReplaySection::default(),
            learner: LearnerSection::default(),
            eval: EvalSection::default(),
            cluster: ClusterSection::default(),
            teacher: TeacherSection::default(),
            sized: Vec::new(),
        }
    }
}

impl Config {
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

    /// Reads a config file (or the defaults when `path` is `None`), applies
    /// `key=value` overrides and validates the result.
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
            ConfigError::Invalid(format!("config {source}: {}", e.to_string().trim_end()))
        })?;
        for o in overrides {
            apply_override(&mut table, o)?;
        }
        let mut cfg: Config = Config::deserialize(toml::Value::Table(table)).map_err(|e| {
            ConfigError::Invalid(format!("config {source}: {}", e.to_string().trim_end()))
        })?;
        // `sim.depth_range` is the camera's range under its older name.
        if let Some(r) = cfg.sim.depth_range.take() {
            if cfg.sim.camera.range.is_some() {
                return Err(ConfigError::Invalid(format!(
                    "config {source}: keys `sim.depth_range` and `sim.camera.range` name the \
                     same range: set one"
                )));
            }
            cfg.sim.camera.range = Some(r);
        }
        cfg.sized = cfg.size(Sizing::machine_cores());
        cfg.validate().doing_with(|| format!("config {source}"))?;
        Ok(cfg)
    }

    /// The run's observation and action shapes (from `sim.frames`,
    /// `sim.frame_stride`, `[sim.goal]` and `sim.hold_action`): every
    /// role's layouts and the network follow them.
    pub fn shapes(&self) -> Shapes {
        Shapes::task(self.sim.frames, self.sim.goal.enabled, self.sim.hold_action)
            .with_stride(self.sim.frame_stride)
            .with_map(self.sim.map.floats())
            .with_tracks(self.sim.tracks.floats())
            .with_depth(self.camera().observed_depth())
    }

    /// The run's depth camera (`[sim.camera]`, `sim.depth_range` read into
    /// it).
    pub fn camera(&self) -> rotorhive_sim::CameraSpec {
        self.sim.camera.spec()
    }

    /// The GRU width of `learner.memory` (validated): `None` for the
    /// feedforward network.
    pub fn memory(&self) -> Option<usize> {
        self.learner.memory.strip_prefix("gru:").and_then(|w| w.parse().ok())
    }

    /// The stored sequences' layout of a run with memory.
    pub fn seq_layout(&self) -> Option<rotorhive_msg::SeqLayout> {
        let width = self.memory()?;
        Some(rotorhive_msg::SeqLayout {
            shapes: self.shapes(),
            steps: self.learner.sequence_steps,
            width,
        })
    }

    /// What one replay row holds: a packed transition, or with memory a
    /// packed sequence.
    pub fn rows(&self) -> rotorhive_msg::RowLayout {
        match self.seq_layout() {
            Some(l) => rotorhive_msg::RowLayout::Sequence(l),
            None => rotorhive_msg::RowLayout::Transition(self.shapes()),
        }
    }

    /// `u16` words of one replay row.
    pub fn row_len(&self) -> usize {
        self.rows().packed_len()
    }

    /// `replay.capacity` and `replay.min_fill` (transitions) in rows: with
    /// memory, sequences of [`Config::steps_per_row`] trained steps.
    pub fn replay_rows(&self) -> (usize, usize) {
        let k = self.steps_per_row();
        let r = &self.replay;
        ((r.capacity / k).max(r.batch), r.min_fill / k)
    }

    /// Trained steps one replay row holds: 1, or with memory a sequence's
    /// steps after its burn-in (the rate limit counts steps).
    pub fn steps_per_row(&self) -> usize {
        match self.memory() {
            Some(_) => self.learner.sequence_steps - self.learner.burn_in,
            None => 1,
        }
    }

    /// The network's widths (`learner.conv_channels`, `learner.hidden`;
    /// validated: the design's where they were not).
    pub fn layers(&self) -> rotorhive_model::Layers {
        rotorhive_model::Layers::new(&self.learner.conv_channels, &self.learner.hidden)
            .unwrap_or_default()
    }

    /// Floats of the network's flat weights (as the weights channel carries
    /// them).
    pub fn num_params(&self) -> usize {
        match self.memory() {
            Some(w) => rotorhive_model::recurrent_params(self.shapes(), self.layers(), w)
                .iter()
                .map(|(_, s)| s.iter().product::<usize>())
                .sum(),
            None => rotorhive_model::num_params(self.shapes(), self.layers()),
        }
    }

    /// The resolved config as TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a config always serialises")
    }

    /// What a checkpoint's header says of the run that wrote it: the CRC-32C
    /// of the resolved config (`config.toml` of the run directory).
    pub fn checkpoint_tags(&self) -> Vec<(&'static str, String)> {
        let mut tags =
            vec![("config_crc32c", format!("{:08x}", crc32c::crc32c(self.to_toml().as_bytes())))];
        // Named only for a camera other than the paper's, so that those
        // checkpoints keep the bytes of earlier builds.
        if self.camera() != rotorhive_sim::CameraSpec::default() {
            tags.push(("camera", self.sim.camera.name()));
        }
        tags
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
            .ok_or_else(|| {
                ConfigError::Invalid(format!("override {o:?}: `{p}` is not a section"))
            })?;
    }
    t.insert(parts[parts.len() - 1].to_string(), value);
    Ok(())
}

#[cfg(test)]
mod tests;
