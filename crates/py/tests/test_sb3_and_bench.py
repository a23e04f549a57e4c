"""The Stable-Baselines3 adapter's contract (SB3 itself needs torch, which
this machine kind cannot install) and the bench's smoke run."""

import numpy as np

from rotorhive import bench
from rotorhive.sb3 import Sb3VecEnv


def test_sb3_adapter_resets_in_the_same_step_with_terminal_observations():
    env = Sb3VecEnv(num_envs=4, max_steps=10, generated_lanes=1)
    env.seed(3)
    obs = env.reset()
    assert obs["depth"].shape == (4, 2, 32, 32)
    ends = 0
    for t in range(25):
        obs, rewards, dones, infos = env.step(np.array([t % 2, 1, 0, (t // 3) % 2]))
        assert rewards.dtype == np.float32 and dones.dtype == np.bool_ and len(infos) == 4
        for i in np.flatnonzero(dones):
            info = infos[i]
            term = info["terminal_observation"]
            assert term["depth"].shape == (2, 32, 32)
            assert not np.array_equal(term["depth"][0], term["depth"][1])
            assert np.array_equal(obs["depth"][i, 0], obs["depth"][i, 1]), "the next episode has started"
            assert info["TimeLimit.truncated"] == (info["episode"]["l"] == 10 and rewards[i] == -10.0)
            ends += 1
    assert ends >= 4
    assert env.get_attr("max_steps") == [10] * 4
    assert env.env_is_wrapped(object) == [False] * 4
    env.close()
    # Another camera: the adapter's observation space and its terminal
    # observations are of its frames.
    env = Sb3VecEnv(num_envs=2, max_steps=3, camera={"width": 48, "height": 24})
    assert env.observation_space["depth"].shape == (2, 24, 48)
    env.reset()
    for _ in range(4):
        obs, _, dones, infos = env.step(np.array([0, 1]))
        assert obs["depth"].shape == (2, 2, 24, 48)
        for i in np.flatnonzero(dones):
            assert infos[i]["terminal_observation"]["depth"].shape == (2, 24, 48)
    env.close()


def test_bench_measures_all_three_paths():
    rows = bench.bench(agents=(2,), seconds=0.05, rounds=1)
    (row,) = rows
    for k in ("rust_vecenv", "python_vector_env", "sync_vector_env"):
        assert row[k] > 0
