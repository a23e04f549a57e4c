//! `rotorhive._rotorhive`: the native half of the Python package.
//!
//! [`Sim`] owns one [`VecEnv`], built from the same config, arenas, lanes
//! and seeds as `hive train`'s first simulator, and steps it with the GIL
//! released, writing observations, rewards and done codes straight into
//! numpy arrays that the Python environment owns (no copy in between).
//! [`PolicyNetwork`] is the learner's network (`rotorhive_model::PolicyNet`,
//! feedforward or with memory): it loads and saves `.safetensors`
//! checkpoints and computes Q-values, so Python can check a conversion of
//! the weights against it. The Gymnasium classes, the
//! autoreset modes and the argument checks live in `python/rotorhive`.

use std::path::Path;
use std::time::Instant;

use numpy::ndarray::{Array2, Array3};
use numpy::{
    IntoPyArray, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2, PyReadwriteArray1,
    PyReadwriteArray2, PyReadwriteArray4, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rotorhive_config::Config;
use rotorhive_config::SimSection;
use rotorhive_model::Shapes;
use rotorhive_sim::view::{self, Canvas, Focus, Tracks};
use rotorhive_sim::{Arena, Autoreset, GpuError, VecEnv};

/// The shipped training arena: the default of `arena`, as in `hive train`.
const TRAIN_ARENA: &str = include_str!("../../../configs/arenas/train.toml");

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// Where an environment's arenas come from: a file, a generated one, or
/// the level's own (the paper's: the shipped training arena; the others:
/// their generated lanes).
#[derive(Clone, Copy, Default)]
struct Source<'a> {
    arena: Option<&'a str>,
    arena_seed: Option<u64>,
    level: Option<&'a str>,
}

/// The lanes an environment of `cfg` flies in, from `src`.
fn lanes(cfg: &Config, src: Source<'_>) -> PyResult<Vec<Arena>> {
    let params = cfg.generator().unwrap_or_default();
    let base = match (src.arena, src.arena_seed) {
        (Some(_), Some(_)) => {
            return Err(value_error(
                "give `arena` (a file) or `arena_seed` (a generated arena), not both",
            ));
        }
        (Some(p), None) => Arena::load(Path::new(p)).map_err(value_error)?,
        (None, Some(s)) => Arena::generate(&format!("generated-{s}"), s, &params),
        // A level without an arena file trains on its generated lanes alone.
        (None, None) if cfg.sim.arena.as_os_str().is_empty() => {
            return cfg.lane_arenas(0).map_err(value_error);
        }
        (None, None) => Arena::parse(TRAIN_ARENA, "configs/arenas/train.toml")
            .expect("the shipped arena is valid"),
    };
    Ok(cfg.lanes_around(base, 0))
}

/// Builds the environment as `hive sim --env 0` does for the config that
/// the level (or the built-in defaults) and `overrides` (`sim.key=value`)
/// give.
fn build_env(
    agents: usize,
    seed: u64,
    src: Source<'_>,
    overrides: &[String],
) -> PyResult<(VecEnv, usize)> {
    if agents == 0 {
        return Err(value_error("`num_envs` must be at least 1"));
    }
    // An environment flies no teacher: a level's teacher (L4's needs the
    // camera's map) must not refuse a user's `map={"encoding": "none"}`.
    let mut ov = vec![rotorhive_config::NO_TEACHER.to_string()];
    ov.extend_from_slice(overrides);
    ov.push(format!("sim.agents={agents}"));
    ov.push(format!("seed={seed}"));
    let cfg = match src.level {
        Some(l) => Config::level(l, &ov),
        None => Config::load(None, &ov),
    };
    let cfg = cfg.map_err(|e| {
        value_error(format!("{e:#}").replace("config defaults (configs/default.toml): ", ""))
    })?;
    let arenas = lanes(&cfg, src)?;
    let lanes = arenas.len();
    let env =
        VecEnv::new_lanes(cfg.sim_config(), &arenas, rotorhive_config::streams::sim(cfg.seed, 0))
            .map_err(|e| PyRuntimeError::new_err(format!("the simulator could not start: {e}")))?;
    Ok((env, lanes))
}

fn render_error(e: GpuError) -> PyErr {
    PyRuntimeError::new_err(format!("rendering failed: {e}"))
}

/// The simulator's autoreset mode named as the Python layer names it.
fn parse_autoreset(mode: &str) -> PyResult<Autoreset> {
    match mode {
        "next" => Ok(Autoreset::NextStep),
        "same" => Ok(Autoreset::SameStep),
        "disabled" => Ok(Autoreset::Disabled),
        other => Err(value_error(format!(
            "autoreset {other:?} is not \"next\", \"same\" or \"disabled\""
        ))),
    }
}

fn check_len(what: &str, got: usize, want: usize) -> PyResult<()> {
    if got != want {
        return Err(value_error(format!("{what}: expected {want} elements, got {got}")));
    }
    Ok(())
}

fn check_actions(actions: &[u8], agents: usize, count: usize) -> PyResult<()> {
    check_len("actions", actions.len(), agents)?;
    if let Some(i) = actions.iter().position(|a| *a as usize >= count) {
        return Err(value_error(format!(
            "actions[{i}] = {} is out of range: the action space is Discrete({count})",
            actions[i]
        )));
    }
    Ok(())
}

/// N drones of one simulator.
#[pyclass(module = "rotorhive._rotorhive", unsendable)]
struct Sim {
    env: VecEnv,
    lanes: usize,
    /// Every drone's path this episode and its last action, for `render`.
    tracks: Tracks,
    last_actions: Vec<u8>,
}

/// The arrays `Sim.step` writes, read by attribute from the package's
/// buffers object.
#[derive(FromPyObject)]
struct StepBuffers<'py> {
    depth: PyReadwriteArray4<'py, f32>,
    velocity: PyReadwriteArray2<'py, f32>,
    rewards: PyReadwriteArray1<'py, f32>,
    dones: PyReadwriteArray1<'py, u8>,
    ep_return: PyReadwriteArray1<'py, f32>,
    ep_length: PyReadwriteArray1<'py, i32>,
}

impl Sim {
    /// Writes `k` floats a row of every agent into `out` (`agents × k`,
    /// checked by `name`) with `write` (nothing where `k` is 0): the map's
    /// and the seen movers' parts of the observation.
    fn write_rows(
        &self,
        name: &str,
        out: &mut [f32],
        k: usize,
        write: impl Fn(&VecEnv, usize, &mut [f32]),
    ) -> PyResult<()> {
        check_len(name, out.len(), self.env.agents() * k)?;
        if k > 0 {
            for (i, row) in out.chunks_exact_mut(k).enumerate() {
                write(&self.env, i, row);
            }
        }
        Ok(())
    }
}

#[pymethods]
impl Sim {
    /// `overrides` are `sim.key=value` strings, as `hive train --set`.
    #[new]
    #[pyo3(signature = (agents, seed=0, arena=None, arena_seed=None, overrides=Vec::new(), level=None))]
    fn new(
        agents: usize,
        seed: u64,
        arena: Option<String>,
        arena_seed: Option<u64>,
        overrides: Vec<String>,
        level: Option<String>,
    ) -> PyResult<Self> {
        let src = Source { arena: arena.as_deref(), arena_seed, level: level.as_deref() };
        let (mut env, lanes) = build_env(agents, seed, src, &overrides)?;
        env.drop_observation_buffer();
        env.set_autoreset(Autoreset::Disabled);
        let tracks = Tracks::new(&env);
        Ok(Self { last_actions: Vec::new(), tracks, env, lanes })
    }

    #[getter]
    fn agents(&self) -> usize {
        self.env.agents()
    }

    /// Rows and columns of one observed depth frame (the camera's image
    /// after its min-pool).
    #[getter]
    fn depth_shape(&self) -> (usize, usize) {
        let [rows, cols] = self.env.config().camera.observed_depth();
        (rows, cols)
    }

    #[getter]
    fn max_steps(&self) -> u32 {
        self.env.config().max_steps
    }

    #[getter]
    fn lanes(&self) -> usize {
        self.lanes
    }

    #[getter]
    fn arena_name(&self) -> String {
        self.env.arena().name.clone()
    }

    /// Environment steps taken so far.
    #[getter]
    fn total_steps(&self) -> u64 {
        self.env.total_steps()
    }

    /// When an ended agent starts its next episode: `"next"` (in the next
    /// step, its action ignored), `"same"` (in the same step) or
    /// `"disabled"` (the default here: only through `reset`).
    fn set_autoreset(&mut self, mode: &str) -> PyResult<()> {
        self.env.set_autoreset(parse_autoreset(mode)?);
        Ok(())
    }

    /// Seconds spent in the last step's physics, rendering and resets.
    #[getter]
    fn timing(&self) -> (f64, f64, f64) {
        let t = self.env.timing();
        (t.physics_ns as f64 * 1e-9, t.render_ns as f64 * 1e-9, t.reset_ns as f64 * 1e-9)
    }

    /// Draws future spawns from a generator seeded with `seed`.
    fn reseed(&mut self, seed: u64) {
        self.env.reseed(seed);
    }

    /// Steps every agent (by default without autoreset: an ended agent
    /// keeps its last frames) and writes the observations, rewards, done codes and, for
    /// the agents whose episode ended, its return and length.
    /// `out` is any object with the arrays as attributes (the package's
    /// `_Buffers`): `depth`, `velocity`, `rewards`, `dones`, `ep_return`,
    /// `ep_length`.
    fn step(
        &mut self,
        py: Python<'_>,
        actions: PyReadonlyArray1<'_, u8>,
        out: StepBuffers<'_>,
    ) -> PyResult<()> {
        let n = self.env.agents();
        let a = actions.as_slice()?;
        check_actions(a, n, self.env.config().shapes().actions)?;
        let StepBuffers {
            mut depth,
            mut velocity,
            mut rewards,
            mut dones,
            mut ep_return,
            mut ep_length,
        } = out;
        let (d, v) = (depth.as_slice_mut()?, velocity.as_slice_mut()?);
        let (r, k) = (rewards.as_slice_mut()?, dones.as_slice_mut()?);
        let (er, el) = (ep_return.as_slice_mut()?, ep_length.as_slice_mut()?);
        for (what, len) in [
            ("rewards", r.len()),
            ("dones", k.len()),
            ("ep_return", er.len()),
            ("ep_length", el.len()),
        ] {
            check_len(what, len, n)?;
        }
        let (env, tracks) = (&mut self.env, &mut self.tracks);
        self.last_actions.clear();
        self.last_actions.extend_from_slice(a);
        py.detach(|| -> PyResult<()> {
            env.step(a).map_err(render_error)?;
            tracks.record(env, false);
            write_obs(env, d, v)?;
            r.copy_from_slice(env.rewards());
            for (k, done) in k.iter_mut().zip(env.dones()) {
                *k = *done as u8;
            }
            for e in env.finished() {
                er[e.agent] = e.reward;
                el[e.agent] = e.steps as i32;
            }
            Ok(())
        })
    }

    /// Starts new episodes for the agents in `mask` (all of them without a
    /// mask) and writes every agent's observation.
    #[pyo3(signature = (depth, velocity, mask=None))]
    fn reset(
        &mut self,
        py: Python<'_>,
        mut depth: PyReadwriteArray4<'_, f32>,
        mut velocity: PyReadwriteArray2<'_, f32>,
        mask: Option<PyReadonlyArray1<'_, bool>>,
    ) -> PyResult<()> {
        let n = self.env.agents();
        let mask: Vec<bool> = match &mask {
            Some(m) => m.as_slice()?.to_vec(),
            None => vec![true; n],
        };
        check_len("reset_mask", mask.len(), n)?;
        let (d, v) = (depth.as_slice_mut()?, velocity.as_slice_mut()?);
        let (env, tracks) = (&mut self.env, &mut self.tracks);
        py.detach(|| -> PyResult<()> {
            env.reset_agents(&mask).map_err(render_error)?;
            tracks.restart(env, &mask);
            write_obs(env, d, v)
        })
    }

    /// A picture of the arena from above around drone `agent` with every
    /// drone's path this episode, beside that drone's last two depth frames and
    /// its last action: `(240, 640, 3)` `uint8` (Gymnasium's `rgb_array`).
    #[pyo3(signature = (agent=0))]
    fn render<'py>(&self, py: Python<'py>, agent: usize) -> PyResult<Bound<'py, PyArray3<u8>>> {
        if agent >= self.env.agents() {
            return Err(value_error(format!(
                "agent {agent} is out of range: there are {}",
                self.env.agents()
            )));
        }
        let len = self.env.obs_len();
        let mut row = vec![0.0; len];
        self.env.write_observations(agent, &mut row);
        let mut canvas = Canvas::default();
        let focus = Focus {
            agent,
            depth: &row[..len - self.env.config().shapes().scalars],
            q: None,
            action: self.last_actions.get(agent).copied(),
        };
        view::draw(&self.env, &self.tracks, focus, &mut canvas);
        Ok(Array3::from_shape_vec((view::HEIGHT, view::WIDTH, 3), canvas.rgb())
            .expect("an RGB picture")
            .into_pyarray(py))
    }

    /// Number of actions: 2, or 3 with `sim.hold_action` (2 holds the
    /// lateral setpoint).
    #[getter]
    fn num_actions(&self) -> usize {
        self.env.config().shapes().actions
    }

    /// Depth frames in one observation (`sim.frames`; 2, the paper's:
    /// previous and current), oldest first.
    #[getter]
    fn frames(&self) -> usize {
        self.env.config().frames
    }

    /// Action periods between two of an observation's depth frames
    /// (`sim.frame_stride`; 1: consecutive views).
    #[getter]
    fn frame_stride(&self) -> usize {
        self.env.config().frame_stride
    }

    /// Whether episodes have a goal (`[sim.goal]`): observations then have
    /// a `goal` part.
    #[getter]
    fn has_goal(&self) -> bool {
        self.env.config().goal.enabled
    }

    /// Writes every agent's goal floats (`agents × 3`: bearing in rad, then
    /// distance and lateral offset in tens of metres, body frame; zeros
    /// without a goal).
    fn observe_goal(&self, mut goal: PyReadwriteArray2<'_, f32>) -> PyResult<()> {
        let g = goal.as_slice_mut()?;
        check_len("goal", g.len(), self.env.agents() * 3)?;
        for (i, row) in g.chunks_exact_mut(3).enumerate() {
            row.copy_from_slice(&self.env.goal_observation(i));
        }
        Ok(())
    }

    /// Floats of the camera's map in an observation (`[sim.map]`; 0:
    /// none): observations then have a `map` part.
    #[getter]
    fn map_floats(&self) -> usize {
        self.env.config().map.floats()
    }

    /// Writes every agent's camera map as its observation reads it
    /// (`agents × map_floats`, each in [0, 1]; nothing without a map).
    fn observe_map(&self, mut map: PyReadwriteArray2<'_, f32>) -> PyResult<()> {
        let k = self.env.config().map.floats();
        self.write_rows("map", map.as_slice_mut()?, k, VecEnv::write_map)
    }

    /// Floats of the seen movers in an observation (`[sim.tracks]`; 0:
    /// none): observations then have a `tracks` part.
    #[getter]
    fn tracks_floats(&self) -> usize {
        self.env.config().tracks.floats()
    }

    /// Writes every agent's seen movers as its observation reads them
    /// (`agents × tracks_floats`; nothing without tracks).
    fn observe_tracks(&self, mut tracks: PyReadwriteArray2<'_, f32>) -> PyResult<()> {
        let k = self.env.config().tracks.floats();
        self.write_rows("tracks", tracks.as_slice_mut()?, k, VecEnv::write_tracks)
    }

    /// Writes every agent's current observation.
    fn observe(
        &self,
        mut depth: PyReadwriteArray4<'_, f32>,
        mut velocity: PyReadwriteArray2<'_, f32>,
    ) -> PyResult<()> {
        write_obs(&self.env, depth.as_slice_mut()?, velocity.as_slice_mut()?)
    }
}

fn write_obs(env: &VecEnv, depth: &mut [f32], velocity: &mut [f32]) -> PyResult<()> {
    let n = env.agents();
    let px = env.config().camera.observed().pixels();
    check_len("depth", depth.len(), n * env.config().frames * px)?;
    check_len("velocity", velocity.len(), n * 3)?;
    env.write_observations_split(depth, velocity);
    Ok(())
}

/// Agent-steps per second of the Rust `VecEnv` alone for `seconds`: the
/// baseline of `rotorhive.bench`. It flies the rows of `actions` in turn
/// (`K × agents`; random when absent), restarts ended agents as `autoreset`
/// says (`"next"`, the vector environment's default, or `"same"`) and
/// writes each step's observations split as the Python environment does,
/// from the same start (`reset(seed=1)`), so that the two fly the same
/// episodes and differ only by the Python layer.
#[pyfunction]
#[pyo3(signature = (agents, seconds, seed=0, overrides=Vec::new(), actions=None, autoreset="next"))]
fn rust_agent_steps_per_second(
    py: Python<'_>,
    agents: usize,
    seconds: f64,
    seed: u64,
    overrides: Vec<String>,
    actions: Option<PyReadonlyArray2<'_, u8>>,
    autoreset: &str,
) -> PyResult<f64> {
    let (mut env, _) = build_env(agents, seed, Source::default(), &overrides)?;
    env.drop_observation_buffer();
    match parse_autoreset(autoreset)? {
        // Never restarted, ended agents would fly on unscored.
        Autoreset::Disabled => {
            return Err(value_error("the bench's autoreset is \"next\" or \"same\""));
        }
        mode => env.set_autoreset(mode),
    }
    let rows: Vec<u8> = match &actions {
        Some(a) => {
            if a.shape()[1] != agents || a.shape()[0] == 0 {
                return Err(value_error(format!(
                    "actions must have shape (K, {agents}), got {:?}",
                    a.shape()
                )));
            }
            a.as_array().iter().copied().collect()
        }
        None => {
            let mut rng = Pcg64Mcg::seed_from_u64(seed);
            (0..64 * agents).map(|_| rng.random_range(0..2)).collect()
        }
    };
    check_actions(&rows[..agents], agents, env.config().shapes().actions)?;
    py.detach(|| {
        // The start of the bench's Python environments: `reset(seed=1)`.
        env.reseed(1);
        env.reset_agents(&vec![true; agents]).map_err(render_error)?;
        let px = env.config().camera.observed().pixels();
        let (mut depth, mut vel) = (vec![0.0f32; agents * 2 * px], vec![0.0f32; agents * 3]);
        let t0 = Instant::now();
        let mut steps = 0usize;
        while steps == 0 || t0.elapsed().as_secs_f64() < seconds {
            let k = steps % (rows.len() / agents);
            env.step(&rows[k * agents..(k + 1) * agents]).map_err(render_error)?;
            env.write_observations_split(&mut depth, &mut vel);
            steps += 1;
        }
        Ok((steps * agents) as f64 / t0.elapsed().as_secs_f64())
    })
}

/// The Rust `VecEnv` as `hive train` runs it (reset in the step), flown
/// with `actions` (`T × agents`): the observations (`T+1 × agents × obs`,
/// the first from the start), rewards and done codes (`T × agents`). The
/// tests compare the Python environment with it step for step.
#[pyfunction]
#[pyo3(signature = (actions, seed=0, arena=None, arena_seed=None, overrides=Vec::new(), level=None))]
#[allow(clippy::type_complexity)]
fn reference_rollout<'py>(
    py: Python<'py>,
    actions: PyReadonlyArray2<'py, u8>,
    seed: u64,
    arena: Option<String>,
    arena_seed: Option<u64>,
    overrides: Vec<String>,
    level: Option<String>,
) -> PyResult<(Bound<'py, PyArray3<f32>>, Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<u8>>)> {
    let (t, n) = (actions.shape()[0], actions.shape()[1]);
    let acts = actions.as_array();
    let src = Source { arena: arena.as_deref(), arena_seed, level: level.as_deref() };
    let (mut env, _) = build_env(n, seed, src, &overrides)?;
    let len = env.obs_len();
    let mut obs = Array3::<f32>::zeros((t + 1, n, len));
    let mut rewards = Array2::<f32>::zeros((t, n));
    let mut dones = Array2::<u8>::zeros((t, n));
    obs.as_slice_mut().expect("contiguous")[..n * len].copy_from_slice(env.observations());
    for s in 0..t {
        let a: Vec<u8> = acts.row(s).to_vec();
        check_actions(&a, n, env.config().shapes().actions)?;
        env.step(&a).map_err(render_error)?;
        obs.as_slice_mut().expect("contiguous")[(s + 1) * n * len..(s + 2) * n * len]
            .copy_from_slice(env.observations());
        rewards.row_mut(s).as_slice_mut().expect("contiguous").copy_from_slice(env.rewards());
        for (k, d) in dones.row_mut(s).iter_mut().zip(env.dones()) {
            *k = *d as u8;
        }
    }
    Ok((obs.into_pyarray(py), rewards.into_pyarray(py), dones.into_pyarray(py)))
}

/// The graded levels: (name, Gymnasium ID), in order of difficulty.
#[pyfunction]
fn levels() -> Vec<(&'static str, &'static str)> {
    rotorhive_config::levels::LEVELS.iter().map(|(name, id, _)| (*name, *id)).collect()
}

/// The keys of the config's `[sim]` section, which the environments take as
/// keyword arguments.
#[pyfunction]
fn sim_keys() -> Vec<String> {
    let mut keys = match toml::Value::try_from(SimSection::default()) {
        Ok(toml::Value::Table(t)) => t.keys().cloned().collect(),
        _ => Vec::new(),
    };
    // The camera's map, a section left out of a config without it: a
    // keyword argument of a dict (`map={"encoding": "rays"}`); so is the
    // camera (`camera={"width": 64, "height": 64}`), and `depth_range`, its
    // range's older name; and the seen movers (`tracks={"count": 5}`).
    keys.extend(["map", "tracks", "camera", "depth_range"].map(String::from));
    keys.sort();
    keys.dedup();
    keys
}

mod networks;
use networks::{PolicyNetwork, checkpoint_width};

#[pymodule]
fn _rotorhive(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Sim>()?;
    m.add_class::<PolicyNetwork>()?;
    m.add_function(wrap_pyfunction!(rust_agent_steps_per_second, m)?)?;
    m.add_function(wrap_pyfunction!(reference_rollout, m)?)?;
    m.add_function(wrap_pyfunction!(sim_keys, m)?)?;
    m.add_function(wrap_pyfunction!(checkpoint_width, m)?)?;
    m.add_function(wrap_pyfunction!(levels, m)?)?;
    // The paper's task's observation length (a goal task's is longer).
    m.add("OBS_LEN", Shapes::PAPER.obs_len())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
