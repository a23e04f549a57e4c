"""rotorhive from Python: many simulated quadrotors flying through obstacle
fields from depth images, as Gymnasium environments.

    import gymnasium as gym
    import rotorhive  # registers the environments

    envs = gym.make_vec("rotorhive/Navigate-v0", num_envs=50)
    obs, infos = envs.reset(seed=1)
    obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())

``rotorhive/Navigate-v0`` is a native vector environment (N drones of one
simulator, stepped in Rust with the GIL released); ``rotorhive/NavigateSingle-v0``
is one drone. `rotorhive.PolicyNetwork` is the Rust network (feedforward or
with memory; `QNetwork` and `RecurrentQNetwork` its names before);
`rotorhive.net` loads `hive train` checkpoints (numpy, PyTorch),
`rotorhive.sb3` adapts the vector environment to Stable-Baselines3,
`rotorhive.export` writes a checkpoint as ONNX, and
`python -m rotorhive.bench` measures agent-steps per second. Both
environments take ``render_mode="rgb_array"`` (Gymnasium's ``RecordVideo``).
"""

import gymnasium as _gym

from . import _rotorhive
from ._rotorhive import OBS_LEN, PolicyNetwork
from .net import QNetwork, RecurrentQNetwork
from .envs import COLLISION, DONE_NAMES, GOAL, LEVELS, RUNNING, TIMEOUT, NavigateEnv, NavigateVectorEnv, sim_keys

__version__ = _rotorhive.__version__

__all__ = [
    "COLLISION",
    "DONE_NAMES",
    "GOAL",
    "OBS_LEN",
    "RUNNING",
    "TIMEOUT",
    "NavigateEnv",
    "NavigateVectorEnv",
    "LEVELS",
    "PolicyNetwork",
    "QNetwork",
    "RecurrentQNetwork",
    "sim_keys",
]

if "rotorhive/Navigate-v0" not in _gym.registry:
    _gym.register(
        id="rotorhive/Navigate-v0",
        entry_point="rotorhive.envs:NavigateEnv",
        vector_entry_point="rotorhive.envs:NavigateVectorEnv",
        max_episode_steps=None,
    )
if "rotorhive/NavigateSingle-v0" not in _gym.registry:
    _gym.register(id="rotorhive/NavigateSingle-v0", entry_point="rotorhive.envs:NavigateEnv")
# The graded levels: the same environments with a level's settings and lanes
# as defaults (`configs/levels/NAME.toml`).
for _name, _id in LEVELS.items():
    if _name != "paper" and _id not in _gym.registry:
        _gym.register(
            id=_id,
            entry_point="rotorhive.envs:NavigateEnv",
            vector_entry_point="rotorhive.envs:NavigateVectorEnv",
            kwargs={"level": _name},
            max_episode_steps=None,
        )
