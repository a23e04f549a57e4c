//! What a config makes of its arenas and simulators: the training arena,
//! the generator and its curriculum stages, each environment's lanes, the
//! validation and test arenas, and one environment's `SimConfig`.

use super::Config;
use std::path::Path;

use crate::error::{ConfigError, Result, config_err};
use rotorhive_sim::{Arena, GenParams, LayoutMaker, SimConfig};
use serde::Deserialize;

impl Config {
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
            .map_err(|e| ConfigError::Invalid(format!("key `sim.generator`: {e}")))?;
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
            .map_err(|e| ConfigError::Invalid(format!("key `sim.curriculum`: {e}")))?;
        q.validate().map_err(|e| {
            ConfigError::Invalid(format!("key `sim.curriculum` at stage {stage}: {e}"))
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
        let p = self.lane_params(base.as_ref(), stage)?;
        Ok(self.lanes_with(base, env, &p))
    }

    /// The generator's parameters of the lanes beside `base` at curriculum
    /// stage `stage`: `base`'s size without a curriculum, the stage's
    /// generator otherwise (or without a base).
    fn lane_params(&self, base: Option<&Arena>, stage: u32) -> Result<GenParams> {
        match base {
            Some(b) if self.sim.curriculum.is_none() => Ok(self.gen_params_like(b)),
            _ => self.generator_at_stage(stage),
        }
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
            let seed = crate::streams::lane(self.seed, env, k);
            v.push(Arena::generate(&format!("lane-{k}"), seed, p));
        }
        v
    }

    /// With `sim.fresh_layouts`: environment `env`'s renewals of its lanes:
    /// the first lane that may be renewed (after `sim.arena`, if any) and
    /// the arena of renewal `n`, of the generated lanes' parameters and
    /// seeds of its own ([`crate::streams::fresh_lane`]: never a lane's, a
    /// validation arena's or a test layout's).
    pub fn fresh_layouts(&self, env: usize) -> Result<Option<(usize, LayoutMaker)>> {
        if self.sim.fresh_layouts == 0 {
            return Ok(None);
        }
        // The lanes' own parameters (validation refuses a curriculum here).
        let base = self.base_arena()?;
        let p = self.lane_params(base.as_ref(), 0)?;
        let seed = self.seed;
        let make = move |n: u64| {
            Arena::generate(&format!("fresh-{n}"), crate::streams::fresh_lane(seed, env, n), &p)
        };
        Ok(Some((usize::from(base.is_some()), Box::new(make))))
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
                Arena::generate(
                    &format!("test-layout-{}", k + 1),
                    crate::streams::test_layout(k),
                    &p,
                )
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
                Arena::generate(&format!("validation-{k}"), crate::streams::validation_arena(k), &p)
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
            camera: self.camera(),
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
            map: s.map.clone(),
            tracks: s.tracks.clone(),
            ..SimConfig::default()
        }
    }
}
