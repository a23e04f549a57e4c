"""Gymnasium environments over rotorhive's simulator.

`NavigateVectorEnv` (``rotorhive/Navigate-v0``) is N drones of one Rust
`VecEnv`, stepped in one call with the GIL released; `NavigateEnv`
(``rotorhive/NavigateSingle-v0``) is one drone.

An agent's episode ends in a collision or at the goal (terminations) or after
`max_steps` steps (a truncation: bootstrap from it). Rewards: +3 per step,
-100 for a collision, -10 at the timeout.
"""

from __future__ import annotations

import json
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import _rotorhive

#: Names of the done codes in ``infos["done"]``.
DONE_NAMES = ("running", "collision", "goal", "timeout")
RUNNING, COLLISION, GOAL, TIMEOUT = range(4)

# Keys of the config's [sim] section that are not keyword arguments: the
# agent count is `num_envs`, the arena is `arena` / `arena_seed`.
# The nested sections (generator, noise, randomize, curriculum) come with a
# level (`level="noisy"`), not as keyword arguments.
_NOT_KWARGS = {"agents", "envs", "arena", "generator", "noise", "randomize", "curriculum"}

#: The graded levels and their Gymnasium IDs (``configs/levels/``, as the
#: Rust crate lists them).
LEVELS = dict(_rotorhive.levels())


def _level(level: Any) -> str | None:
    if level is None:
        return None
    if level not in LEVELS:
        raise ValueError(f"level {level!r} is not one of {', '.join(LEVELS)}")
    return str(level)


def sim_keys() -> list[str]:
    """The simulator keys the environments take as keyword arguments."""
    return sorted(set(_rotorhive.sim_keys()) - _NOT_KWARGS)


def _toml(key: str, value: Any) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)
    raise TypeError(f"keyword argument {key!r}: expected a number, a bool or a str, got {type(value).__name__}")


def _overrides(env_id: str, sim: dict[str, Any]) -> list[str]:
    keys = sim_keys()
    out = []
    for k, v in sim.items():
        if k not in keys:
            raise TypeError(f"{env_id}: unknown keyword argument {k!r} (the simulator's keys are {', '.join(keys)})")
        if isinstance(v, dict):
            # A section, e.g. map={"encoding": "rays"}: its keys one by one.
            out.extend(f"sim.{k}.{kk}={_toml(f'{k}.{kk}', vv)}" for kk, vv in v.items())
        else:
            out.append(f"sim.{k}={_toml(k, v)}")
    return out


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int, got {type(value).__name__}")
    if value < minimum:
        raise ValueError(f"{name} must be at least {minimum}, got {value}")
    return int(value)


def _arena(arena: Any) -> str | None:
    if arena is None:
        return None
    import os

    if not isinstance(arena, (str, os.PathLike)):
        raise TypeError(f"arena must be a path to an arena file, got {type(arena).__name__}")
    return os.fspath(arena)


# Frames per second of a video of the environment: one action is one
# simulated second; four a second shows a 150-step episode in under 40 s.
RENDER_FPS = 4


def _check_render_mode(render_mode: str | None) -> None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode {render_mode!r} is not supported: only 'rgb_array' (or None)")


def _spaces(depth: tuple[int, int], goal: bool, frames: int = 2, map_floats: int = 0, tracks_floats: int = 0) -> spaces.Dict:
    parts = {
        # The depth frames, oldest first (``sim.frames``; 2: previous, current).
        "depth": spaces.Box(0.0, 1.0, (frames, *depth), np.float32),
        "velocity": spaces.Box(-np.inf, np.inf, (3,), np.float32),
    }
    if goal:
        # Bearing (rad), distance and lateral offset (tens of metres), body frame.
        parts["goal"] = spaces.Box(-np.inf, np.inf, (3,), np.float32)
    if map_floats:
        # The camera's map (``[sim.map]``): an egocentric grid of cells (0
        # unknown, 1/3 free, 2/3 wall, 1 obstacle) or rays through it (to the
        # first obstacle, then to the first unknown cell, shares of their reach),
        # then, with ``movers_ahead_s``, the same rays through the seen movers
        # where their tracks put them at each time ahead.
        parts["map"] = spaces.Box(0.0, 1.0, (map_floats,), np.float32)
    if tracks_floats:
        # The seen movers (``[sim.tracks]``), nearest first, 14 floats each:
        # present, position at the last sighting (body frame, tens of m, 2),
        # velocity (body frame, m/s, 2), velocity known, half size (m, 2),
        # time since the last sighting and time watched (shares of keep_s),
        # the seen stretch's centre and half lengths (tens of m, 4); zeros
        # where fewer are known.
        parts["tracks"] = spaces.Box(-np.inf, np.inf, (tracks_floats,), np.float32)
    return spaces.Dict(parts)


class _Buffers:
    """The arrays the simulator writes into, owned by the environment."""

    def __init__(self, n: int, depth: tuple[int, int], goal: bool = False, frames: int = 2, map_floats: int = 0, tracks_floats: int = 0) -> None:
        self.depth = np.zeros((n, frames, *depth), np.float32)
        self.velocity = np.zeros((n, 3), np.float32)
        self.goal = np.zeros((n, 3), np.float32) if goal else None
        self.map = np.zeros((n, map_floats), np.float32) if map_floats else None
        self.tracks = np.zeros((n, tracks_floats), np.float32) if tracks_floats else None
        self.rewards = np.zeros(n, np.float32)
        self.dones = np.zeros(n, np.uint8)
        self.ep_return = np.zeros(n, np.float32)
        self.ep_length = np.zeros(n, np.int32)

    def parts(self, i: int | None = None, copy: bool = True) -> dict[str, np.ndarray]:
        """The observation (of agent `i`, or of all: the buffers themselves
        unless copied)."""
        out = {"depth": self.depth, "velocity": self.velocity}
        if self.goal is not None:
            out["goal"] = self.goal
        if self.map is not None:
            out["map"] = self.map
        if self.tracks is not None:
            out["tracks"] = self.tracks
        if i is not None:
            out = {k: v[i] for k, v in out.items()}
        return {k: v.copy() for k, v in out.items()} if copy else out

    def read_goal(self, sim: Any) -> None:
        """Takes the goal's part from the simulator, with a goal (and the
        camera's map and the seen movers, with them)."""
        if self.goal is not None:
            sim.observe_goal(self.goal)
        if self.map is not None:
            sim.observe_map(self.map)
        if self.tracks is not None:
            sim.observe_tracks(self.tracks)


def _check_action_values(a: np.ndarray, count: int) -> None:
    bad = np.flatnonzero((a < 0) | (a >= count))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"actions[{i}] = {a[i]} is out of range: each drone's action space is Discrete({count})")


class NavigateVectorEnv(VectorEnv):
    """N drones of one simulator as a native Gymnasium vector environment.

    Keyword arguments: `seed` (the simulator's seed, as `hive train`'s),
    `arena` (an arena file; default: the shipped training arena) or
    `arena_seed` (a generated arena), `level` (a graded level's settings
    and lanes: `paper`, `dense`, `forest`, `noisy`; the IDs
    ``rotorhive/Dense-v0`` etc. set it), `autoreset_mode` (`NEXT_STEP`,
    `SAME_STEP` or `DISABLED`), `copy` (True: every call returns fresh
    arrays; False: the observation arrays are views of the environment's
    buffers, which the next `step` or `reset` overwrites) and the
    simulator's keys (`sim_keys()`: `generated_lanes`, `renderer`,
    `max_steps`, ...). The defaults are `configs/default.toml`'s.

    ``infos`` carries, for the agents whose episode ended in the step (mask
    ``_success`` etc.): ``success`` (reached the goal), ``done`` (the code,
    see `DONE_NAMES`), ``episode_return`` and ``episode_length``.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"], "render_fps": RENDER_FPS}

    def __init__(
        self,
        num_envs: int = 1,
        *,
        seed: int = 0,
        arena: Any = None,
        arena_seed: int | None = None,
        level: str | None = None,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        copy: bool = True,
        render_mode: str | None = None,
        **sim: Any,
    ) -> None:
        n = _check_int("num_envs", num_envs, 1)
        seed = _check_int("seed", seed, 0)
        if arena_seed is not None:
            arena_seed = _check_int("arena_seed", arena_seed, 0)
        _check_render_mode(render_mode)
        try:
            self.autoreset_mode = AutoresetMode(autoreset_mode)
        except ValueError:
            names = ", ".join(m.name for m in AutoresetMode)
            raise ValueError(f"autoreset_mode {autoreset_mode!r} is not one of {names}") from None
        self._sim = _rotorhive.Sim(n, seed, _arena(arena), arena_seed, _overrides("rotorhive/Navigate-v0", sim), _level(level))
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            # The simulator itself restarts an ended agent in the next step,
            # without drawing it twice.
            self._sim.set_autoreset("next")
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.num_envs = n
        self.copy = bool(copy)
        self.render_mode = render_mode
        self.single_observation_space = _spaces(self._sim.depth_shape, self._sim.has_goal, self._sim.frames, self._sim.map_floats, self._sim.tracks_floats)
        self.single_action_space = spaces.Discrete(self._sim.num_actions)
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._b = _Buffers(n, self._sim.depth_shape, self._sim.has_goal, self._sim.frames, self._sim.map_floats, self._sim.tracks_floats)
        # Agents whose episode ended and that have not started the next one.
        self._ended = np.zeros(n, np.bool_)
        self._needs_reset = True
        self._fresh = True

    @property
    def max_steps(self) -> int:
        return self._sim.max_steps

    def _obs(self) -> dict[str, np.ndarray]:
        return self._b.parts(copy=self.copy)

    def _actions(self, actions: Any) -> np.ndarray:
        a = np.asarray(actions)
        count = self._sim.num_actions
        if a.shape != (self.num_envs,):
            raise ValueError(f"actions must have shape ({self.num_envs},), got {a.shape}")
        if a.dtype.kind not in "iub":
            raise TypeError(f"actions must be integers (Discrete({count}) per drone), got dtype {a.dtype}")
        _check_action_values(a, count)
        return np.ascontiguousarray(a, dtype=np.uint8)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Starts new episodes: every agent's, or with ``options={"reset_mask":
        mask}`` those in the mask. A `seed` reseeds the spawns."""
        super().reset(seed=seed)
        if self._sim is None:
            raise gym.error.ClosedEnvironmentError("the environment is closed")
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; the only option is 'reset_mask'")
        if seed is not None:
            self._sim.reseed(_check_int("seed", seed, 0))
        if mask is not None:
            if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
                raise TypeError(f"options['reset_mask'] must be a numpy bool array of shape ({self.num_envs},)")
            if not mask.any():
                raise ValueError("options['reset_mask'] must have at least one True value")
            if self._needs_reset and not mask.all():
                raise gym.error.ResetNeeded("the first reset must reset every agent")
            mask = np.ascontiguousarray(mask)
        b = self._b
        if self._fresh and seed is None and mask is None:
            # The first reset without a seed keeps the simulator's start,
            # which its construction seed fixed as `hive train`'s.
            self._sim.observe(b.depth, b.velocity)
        else:
            self._sim.reset(b.depth, b.velocity, mask)
        b.read_goal(self._sim)
        self._fresh = False
        if mask is None:
            self._ended[:] = False
        else:
            self._ended[mask] = False
        self._needs_reset = False
        return self._obs(), {}

    def _episode_infos(self, ended: np.ndarray) -> dict[str, Any]:
        b = self._b
        m = ended.copy()
        return {
            "success": b.dones == GOAL,
            "_success": m,
            "done": b.dones.astype(np.int8),
            "_done": m,
            "episode_return": np.where(m, b.ep_return, 0.0).astype(np.float32),
            "_episode_return": m,
            "episode_length": np.where(m, b.ep_length, 0).astype(np.int32),
            "_episode_length": m,
        }

    def step(self, actions: Any):
        if self._sim is None:
            raise gym.error.ClosedEnvironmentError("the environment is closed")
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = self._actions(actions)
        mode = self.autoreset_mode
        if mode == AutoresetMode.DISABLED and self._ended.any():
            left = np.flatnonzero(self._ended).tolist()
            raise gym.error.ResetNeeded(
                f"agents {left} ended their episodes: reset them with reset(options={{'reset_mask': mask}}) before stepping"
            )
        b = self._b
        self._sim.step(a, b)
        b.read_goal(self._sim)
        terminated = (b.dones == COLLISION) | (b.dones == GOAL)
        truncated = b.dones == TIMEOUT
        rewards = b.rewards.astype(np.float64)
        ended = terminated | truncated
        infos: dict[str, Any] = self._episode_infos(ended) if ended.any() else {}
        if mode == AutoresetMode.SAME_STEP and ended.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(ended):
                final_obs[i] = b.parts(i)
            infos["final_obs"] = final_obs
            infos["_final_obs"] = ended.copy()
            infos["final_info"] = self._episode_infos(ended)
            infos["_final_info"] = ended.copy()
            self._sim.reset(b.depth, b.velocity, np.ascontiguousarray(ended))
            b.read_goal(self._sim)
        elif mode == AutoresetMode.DISABLED:
            self._ended = ended
        return self._obs(), rewards, terminated, truncated, infos

    def render(self) -> np.ndarray | None:
        """With ``render_mode="rgb_array"``: one picture of all the drones
        (the arena from above around agent 0, every drone's path this
        episode) beside agent 0's last two depth frames and its last action,
        ``(240, 640, 3)`` ``uint8``; otherwise None."""
        if self.render_mode != "rgb_array":
            return None
        return self._sim.render(0)

    def close_extras(self, **kwargs: Any) -> None:
        self._sim = None


class NavigateEnv(gym.Env):
    """One drone (``rotorhive/NavigateSingle-v0``), for tools that want one
    environment per drone. Same keyword arguments as `NavigateVectorEnv`
    (but `num_envs`, `autoreset_mode` and `copy`); after an episode ends,
    call `reset()`."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": RENDER_FPS}

    def __init__(
        self, *, seed: int = 0, arena: Any = None, arena_seed: int | None = None, level: str | None = None, render_mode: str | None = None, **sim: Any
    ) -> None:
        seed = _check_int("seed", seed, 0)
        if arena_seed is not None:
            arena_seed = _check_int("arena_seed", arena_seed, 0)
        _check_render_mode(render_mode)
        self._sim = _rotorhive.Sim(1, seed, _arena(arena), arena_seed, _overrides("rotorhive/NavigateSingle-v0", sim), _level(level))
        self.render_mode = render_mode
        self.observation_space = _spaces(self._sim.depth_shape, self._sim.has_goal, self._sim.frames, self._sim.map_floats, self._sim.tracks_floats)
        self.action_space = spaces.Discrete(self._sim.num_actions)
        self._b = _Buffers(1, self._sim.depth_shape, self._sim.has_goal, self._sim.frames, self._sim.map_floats, self._sim.tracks_floats)
        self._a = np.zeros(1, np.uint8)
        self._needs_reset = True

    def _obs(self) -> dict[str, np.ndarray]:
        return self._b.parts(0)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}")
        if seed is not None:
            self._sim.reseed(_check_int("seed", seed, 0))
        self._sim.reset(self._b.depth, self._b.velocity, None)
        self._b.read_goal(self._sim)
        self._needs_reset = False
        return self._obs(), {}

    def step(self, action: Any):
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = np.asarray(action)
        count = self._sim.num_actions
        if a.shape != () or a.dtype.kind not in "iub":
            raise TypeError(f"the action must be an int (Discrete({count})), got {action!r}")
        if not 0 <= int(a) < count:
            raise ValueError(f"action {int(a)} is out of range: the action space is Discrete({count})")
        self._a[0] = int(a)
        b = self._b
        self._sim.step(self._a, b)
        b.read_goal(self._sim)
        done = int(b.dones[0])
        terminated, truncated = done in (COLLISION, GOAL), done == TIMEOUT
        info: dict[str, Any] = {}
        if terminated or truncated:
            info = {"success": done == GOAL, "done": done, "episode_return": float(b.ep_return[0]), "episode_length": int(b.ep_length[0])}
        return self._obs(), float(b.rewards[0]), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """With ``render_mode="rgb_array"``: the arena from above around the
        drone with its path this episode, beside its last two depth frames and
        its last action, ``(240, 640, 3)`` ``uint8``; otherwise None."""
        if self.render_mode != "rgb_array":
            return None
        return self._sim.render(0)
