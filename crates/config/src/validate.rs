//! A parsed config checked key by key: every value a role relies on,
//! each refused with the key's name.

use super::Config;
use crate::error::{ConfigError, Doing, Result, config_err};
use crate::{LearnerSection, TeacherLoss};
use rotorhive_sim::PhysicsKind;

/// A key that must be a positive number.
fn positive(key: &str, v: f64) -> Result<()> {
    if !(v.is_finite() && v > 0.0) {
        config_err!("key `{key}` must be positive, got {v}");
    }
    Ok(())
}

impl Config {
    /// Checks every value a role relies on.
    pub fn validate(&self) -> Result<()> {
        self.validate_run()?;
        self.validate_sim()?;
        self.validate_learning()
    }

    /// The run's own keys: budget, determinism, cluster, evaluation.
    fn validate_run(&self) -> Result<()> {
        positive("max_seconds", self.max_seconds)?;
        if self.cores > super::sizing::MAX_CORES {
            config_err!(
                "key `cores` must be at most {} (0 = all of this machine's), got {}",
                super::sizing::MAX_CORES,
                self.cores
            );
        }
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
        s.camera.validate()?;
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
        if s.fresh_layouts > 0 {
            if s.generator.is_none() || s.generated_lanes == 0 {
                config_err!(
                    "key `sim.fresh_layouts` renews generated lanes: it needs `[sim.generator]` and `sim.generated_lanes` above 0"
                );
            }
            if s.curriculum.is_some() {
                config_err!(
                    "key `sim.fresh_layouts` and `[sim.curriculum]` both change the lanes: give one"
                );
            }
            if s.physics != rotorhive_sim::PhysicsKind::Direct {
                config_err!("key `sim.fresh_layouts` needs `sim.physics = \"direct\"`");
            }
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
                ConfigError::Invalid(format!("key `sim.generator.{}`: {}", e.key, e.message))
            })?;
        }
        if s.arena.as_os_str().is_empty() && (s.generator.is_none() || s.generated_lanes == 0) {
            config_err!(
                "key `sim.arena` is empty: training then needs `[sim.generator]` and `sim.generated_lanes` above 0"
            );
        }
        self.validate_sections()?;
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

    /// The sim's sections of their own: noise, randomisation, goal and the
    /// camera's map (and a teacher that reads the map needs one).
    fn validate_sections(&self) -> Result<()> {
        let s = &self.sim;
        // Each section names its bad key; the message puts it under its section.
        let section = |name: &str, r: std::result::Result<(), (&str, String)>| {
            r.map_err(|(k, m)| ConfigError::Invalid(format!("key `sim.{name}.{k}` {m}")))
        };
        section("noise", s.noise.validate())?;
        section("randomize", s.randomize.validate())?;
        section("goal", s.goal.validate())?;
        section("map", s.map.validate())?;
        section("tracks", s.tracks.validate())?;
        if s.map.enabled() && !s.map.movers_ahead_s.is_empty() && !s.tracks.enabled() {
            return Err(ConfigError::Invalid(
                "key `sim.map.movers_ahead_s` casts rays through the seen movers, and \
                 `sim.tracks.count` is 0: set it, or `sim.map.movers_ahead_s = []`"
                    .into(),
            ));
        }
        if self.teacher.on() && self.teacher.sight == rotorhive_sim::Sight::Map && !s.map.enabled()
        {
            return Err(ConfigError::Invalid(
                "key `teacher.sight` is \"map\" without the camera's map: set \
                 `sim.map.encoding`, or `teacher.policy = \"none\"` for no teacher"
                    .into(),
            ));
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
        if !(l.average_updates.is_finite() && l.average_updates >= 0.0) {
            config_err!(
                "key `learner.average_updates` must be 0 (off) or positive, got {}",
                l.average_updates
            );
        }
        if let Err(e) = rotorhive_model::Layers::new(&l.conv_channels, &l.hidden) {
            config_err!(
                "keys `learner.conv_channels` {:?} and `learner.hidden` {:?}: {e}",
                l.conv_channels,
                l.hidden
            );
        }
        if !(0.0..=1.0).contains(&l.td_weight) {
            config_err!("key `learner.td_weight` must lie in [0, 1], got {}", l.td_weight);
        }
        if l.td_weight < 1.0 && !(self.teacher.on() && self.teacher.loss == TeacherLoss::Imitation)
        {
            config_err!(
                "key `learner.td_weight` below 1 needs `teacher.loss = \"imitation\"` (and a teacher)"
            );
        }
        if !(l.max_rate_hz.is_finite() && l.max_rate_hz >= 0.0) {
            config_err!(
                "key `learner.max_rate_hz` must be 0 (unlimited) or positive, got {}",
                l.max_rate_hz
            );
        }
        self.validate_memory()
    }

    /// `learner.memory` and its sequences; without memory, a sequence key
    /// set to anything but its default changes nothing and is refused.
    fn validate_memory(&self) -> Result<()> {
        let l = &self.learner;
        if l.memory == "none" {
            let d = LearnerSection::default();
            for (key, set, default) in [
                ("learner.sequence_steps", l.sequence_steps, d.sequence_steps),
                ("learner.burn_in", l.burn_in, d.burn_in),
            ] {
                if set != default {
                    config_err!(
                        "key `{key}` = {set} changes nothing without memory (`learner.memory = \"none\"`): drop it, or set `learner.memory = \"gru:WIDTH\"`"
                    );
                }
            }
            return Ok(());
        }
        let width = self.memory().filter(|w| (1..=rotorhive_model::MAX_WIDTH).contains(w));
        if width.is_none() {
            config_err!(
                "key `learner.memory` must be \"none\" or \"gru:WIDTH\" (WIDTH 1 to {}), got {:?}",
                rotorhive_model::MAX_WIDTH,
                l.memory
            );
        }
        if !(2..=200).contains(&l.sequence_steps) {
            config_err!(
                "key `learner.sequence_steps` must lie in 2..=200, got {}",
                l.sequence_steps
            );
        }
        if l.burn_in >= l.sequence_steps {
            config_err!(
                "key `learner.burn_in` ({}) must be below `learner.sequence_steps` ({})",
                l.burn_in,
                l.sequence_steps
            );
        }
        Ok(())
    }
}

impl Config {
    /// The keys that do nothing in this run, left at values that change
    /// nothing (the run's log names them): the sequences' without memory,
    /// the teacher's without a teacher.
    pub fn unused_keys(&self) -> Vec<&'static str> {
        let mut unused = Vec::new();
        if self.memory().is_none() {
            unused.extend(["learner.sequence_steps", "learner.burn_in"]);
        }
        if !self.teacher.on() {
            unused.push("teacher.* (but teacher.policy)");
        }
        unused
    }
}
