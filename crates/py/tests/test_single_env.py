"""The single-drone environment passes Gymnasium's environment checker."""

import gymnasium as gym
import numpy as np
from gymnasium.utils.env_checker import check_env

import rotorhive


def test_check_env_passes():
    check_env(rotorhive.NavigateEnv(generated_lanes=1), skip_render_check=True)


def test_make_and_an_episode_to_its_end():
    env = gym.make("rotorhive/NavigateSingle-v0", max_steps=20)
    obs, info = env.reset(seed=7)
    assert env.observation_space.contains(obs)
    for t in range(25):
        obs, reward, terminated, truncated, info = env.step(t % 2)
        if terminated or truncated:
            break
    assert terminated or truncated
    assert info["done"] in (rotorhive.COLLISION, rotorhive.GOAL, rotorhive.TIMEOUT)
    assert info["success"] == (info["done"] == rotorhive.GOAL)
    assert info["episode_length"] == t + 1


def test_one_drone_of_the_vector_env_flies_as_the_single_env():
    single = rotorhive.NavigateEnv(seed=4)
    vec = rotorhive.NavigateVectorEnv(1, seed=4)
    a, _ = single.reset(seed=8)
    b, _ = vec.reset(seed=8)
    np.testing.assert_array_equal(a["depth"], b["depth"][0])
    for t in range(10):
        a, ra, *_ = single.step(t % 2)
        b, rb, *_ = vec.step(np.array([t % 2]))
        np.testing.assert_array_equal(a["depth"], b["depth"][0])
        assert ra == rb[0]
