"""The graded levels as Gymnasium IDs: their settings and lanes are the
level's, the paper's task keeps its ID, and a bad level is named."""

import gymnasium as gym
import numpy as np
import pytest

import rotorhive
from rotorhive import _rotorhive


@pytest.mark.parametrize("level", ["dense", "forest", "noisy", "moving"])
def test_every_level_is_a_vector_environment_with_its_own_lanes(level):
    env_id = rotorhive.LEVELS[level]
    envs = gym.make_vec(env_id, num_envs=4, seed=3)
    obs, _ = envs.reset(seed=3)
    assert obs["depth"].shape == (4, 2, 32, 32) and obs["velocity"].shape == (4, 3)
    for t in range(5):
        obs, rew, term, trunc, info = envs.step(np.array([t % 2] * 4))
    assert np.isfinite(obs["depth"]).all() and ((0.0 <= obs["depth"]) & (obs["depth"] <= 1.0)).all()
    envs.close()
    # The level's generated lanes (no shipped arena among them).
    sim = _rotorhive.Sim(2, 3, None, None, [], level)
    assert sim.lanes == 16
    assert sim.max_steps == (300 if level == "forest" else 400)


def test_the_noisy_level_sees_dropped_pixels_and_the_dense_one_does_not():
    def zeros(level):
        envs = gym.make_vec(rotorhive.LEVELS[level], num_envs=8, seed=1)
        obs, _ = envs.reset(seed=1)
        envs.close()
        return int((obs["depth"] == 0.0).sum())

    # 3 % dropout of 8 × 2 × 1024 pixels: hundreds read 0; none in the clean level.
    assert zeros("noisy") > 200
    assert zeros("dense") == 0


def test_a_level_that_does_not_exist_is_named():
    with pytest.raises(ValueError, match="lava"):
        gym.make_vec("rotorhive/Navigate-v0", num_envs=2, level="lava")
