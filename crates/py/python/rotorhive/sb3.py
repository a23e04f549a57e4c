"""Stable-Baselines3 adapter.

SB3 does not take a Gymnasium ``VectorEnv``: it needs its own ``VecEnv``
(``reset() -> obs``, ``step_async``/``step_wait -> (obs, rewards, dones,
infos)`` with the ended episode's last observation in
``info["terminal_observation"]`` and ``info["TimeLimit.truncated"]`` for
timeouts). `Sb3VecEnv` is that, over a `NavigateVectorEnv` in ``SAME_STEP``
mode; it subclasses SB3's ``VecEnv`` when stable-baselines3 is installed::

    from stable_baselines3 import DQN
    from rotorhive.sb3 import Sb3VecEnv
    env = Sb3VecEnv(num_envs=16)
    DQN("MultiInputPolicy", env).learn(100_000)

(SB3's default CNN shrinks a 32x32 image to nothing: pass rotorhive's own
network, see `rotorhive.net`, as a features extractor for real training.)
"""

from __future__ import annotations

import time
from typing import Any, Sequence

import numpy as np
from gymnasium.vector import AutoresetMode

from .envs import GOAL, NavigateVectorEnv

try:  # pragma: no cover - SB3 needs torch, which CI cannot install
    from stable_baselines3.common.vec_env import VecEnv as _Base

    HAVE_SB3 = True
except ImportError:
    _Base = object
    HAVE_SB3 = False


class Sb3VecEnv(_Base):  # type: ignore[misc, valid-type]
    """N drones as a Stable-Baselines3 ``VecEnv``. Keyword arguments are
    `NavigateVectorEnv`'s (but `autoreset_mode`)."""

    def __init__(self, num_envs: int = 1, **kwargs: Any) -> None:
        if "autoreset_mode" in kwargs:
            raise TypeError("Sb3VecEnv resets ended episodes in the same step (SB3's convention): do not pass autoreset_mode")
        self.env = NavigateVectorEnv(num_envs, autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
        obs_space, act_space = self.env.single_observation_space, self.env.single_action_space
        if HAVE_SB3:
            super().__init__(num_envs, obs_space, act_space)
        else:
            self.num_envs, self.observation_space, self.action_space = num_envs, obs_space, act_space
        self._actions: np.ndarray | None = None
        self._seed: int | None = None
        self._t0 = time.monotonic()

    def reset(self) -> dict[str, np.ndarray]:
        obs, _ = self.env.reset(seed=self._seed)
        self._seed = None
        return obs

    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        self._seed = seed
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).reshape(self.num_envs)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async()")
        obs, rewards, terminated, truncated, infos = self.env.step(self._actions)
        self._actions = None
        dones = terminated | truncated
        out: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if dones.any():
            fin = infos["final_info"]
            elapsed = round(time.monotonic() - self._t0, 6)
            for i in np.flatnonzero(dones):
                out[i] = {
                    "terminal_observation": infos["final_obs"][i],
                    "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                    "is_success": bool(fin["done"][i] == GOAL),
                    "episode": {"r": float(fin["episode_return"][i]), "l": int(fin["episode_length"][i]), "t": elapsed},
                }
        return obs, rewards.astype(np.float32), dones, out

    def step(self, actions: np.ndarray):
        self.step_async(actions)
        return self.step_wait()

    def close(self) -> None:
        self.env.close()

    def _indices(self, indices: Any) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self.env, attr_name) for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self.env, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any) -> list[Any]:
        return [getattr(self.env, method_name)(*args, **kwargs) for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs
