"""render_mode="rgb_array": pictures of the drones flying, and Gymnasium's
RecordVideo writing a video of an episode from them."""

import glob

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import rotorhive


def test_single_env_passes_the_checker_with_its_render_check():
    check_env(rotorhive.NavigateEnv(generated_lanes=1, render_mode="rgb_array"))


def test_pictures_show_the_flight_and_change_as_it_goes():
    env = gym.make("rotorhive/NavigateSingle-v0", render_mode="rgb_array")
    env.reset(seed=3)
    first = env.render()
    assert first.shape == (240, 640, 3) and first.dtype == np.uint8
    # The depth panel holds the drone's view: many grey levels.
    panel = first[:, 432:]
    greys = panel[(panel[..., 0] == panel[..., 1]) & (panel[..., 1] == panel[..., 2])][:, 0]
    assert len(np.unique(greys)) > 10
    for t in range(3):
        env.step(t % 2)
    later = env.render()
    assert (later != first).any(), "the picture follows the flight"


def test_vector_env_renders_all_drones_in_one_picture():
    env = rotorhive.NavigateVectorEnv(4, seed=1, render_mode="rgb_array")
    env.reset(seed=1)
    env.step(np.array([0, 1, 0, 1]))
    frame = env.render()
    assert frame.shape == (240, 640, 3)
    assert rotorhive.NavigateVectorEnv(2).render() is None


def test_unknown_render_modes_are_refused():
    with pytest.raises(ValueError, match="render_mode"):
        rotorhive.NavigateEnv(render_mode="human")
    with pytest.raises(ValueError, match="render_mode"):
        rotorhive.NavigateVectorEnv(2, render_mode="ansi")


def test_record_video_writes_an_episode(tmp_path):
    env = gym.make("rotorhive/NavigateSingle-v0", render_mode="rgb_array", max_steps=12)
    env = gym.wrappers.RecordVideo(env, str(tmp_path), episode_trigger=lambda e: True, disable_logger=True)
    env.reset(seed=2)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.close()
    videos = glob.glob(str(tmp_path / "*.mp4"))
    assert len(videos) == 1
    assert (tmp_path / videos[0]).stat().st_size > 1000
