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


def test_the_moving_level_observes_its_cameras_map_and_seen_movers_and_the_dense_one_neither():
    # configs/levels/moving.toml ships the map's 36 rays and the five
    # nearest seen movers (since 2026-12-06), and the 36 rays again through
    # the movers now and 1, 2, 3 s on (since 2026-12-07); L1 keeps the
    # paper's parts.
    def parts(level, **sim):
        envs = gym.make_vec(rotorhive.LEVELS[level], num_envs=2, seed=1, **sim)
        obs, _ = envs.reset(seed=1)
        for _ in range(3):
            obs, *_ = envs.step(np.array([0, 1]))
        assert envs.observation_space.contains(obs)
        envs.close()
        return {k: v.shape[1:] for k, v in obs.items()}, obs

    moving, obs = parts("moving")
    assert moving["map"] == ((2 + 4) * 36,) and moving["tracks"] == (5 * 14,), moving
    # Rays cast through what the camera saw (1: nothing met within reach):
    # some met an obstacle by now.
    assert (obs["map"] < 0.99).any(), obs["map"]
    dense, _ = parts("dense")
    assert set(dense) == {"depth", "velocity"}, dense
    # The level's frames alone, though its teacher reads the map (an
    # environment flies no teacher).
    alone, _ = parts("moving", map={"encoding": "none"}, tracks={"count": 0})
    assert set(alone) == {"depth", "velocity"}, alone


def test_the_noisy_level_sees_dropped_pixels_and_the_dense_one_does_not():
    def zeros(level):
        envs = gym.make_vec(rotorhive.LEVELS[level], num_envs=8, seed=1)
        obs, _ = envs.reset(seed=1)
        envs.close()
        return int((obs["depth"] == 0.0).sum())

    # 3 % dropout of 8 × 2 × 1024 pixels: hundreds read 0; none in the clean level.
    assert zeros("noisy") > 200
    assert zeros("dense") == 0


def test_the_goal_level_observes_its_goal_holds_and_matches_the_rust_env_step_for_step():
    """L5 `goal`: the Dict observation gains `goal` (bearing, distance and
    lateral offset), the action space a third action (hold), and the
    Python environment flies exactly as the Rust `VecEnv` of `hive train`."""
    envs = gym.make_vec(rotorhive.LEVELS["goal"], num_envs=3, seed=4, autoreset_mode="SameStep")
    assert envs.single_action_space == gym.spaces.Discrete(3)
    assert envs.single_observation_space["goal"].shape == (3,)
    obs, _ = envs.reset()
    assert obs["goal"].shape == (3, 3)
    # Distance in tens of metres: the goal 5 m before the far end of 150;
    # the bearing in the body frame (spawn headings vary by ±10°).
    assert (obs["goal"][:, 1] > 12.0).all() and (np.abs(obs["goal"][:, 0]) < 0.3).all()
    rng = np.random.default_rng(2)
    actions = rng.integers(0, 3, size=(12, 3)).astype(np.uint8)
    want_obs, want_rew, want_done = _rotorhive.reference_rollout(actions, 4, level="goal")
    assert want_obs.shape[2] == 2 * 32 * 32 + 6
    for t, a in enumerate(actions):
        flat = np.concatenate([obs["depth"].reshape(3, -1), obs["velocity"], obs["goal"]], axis=1)
        np.testing.assert_array_equal(flat, want_obs[t])
        obs, rew, term, trunc, _ = envs.step(a)
        np.testing.assert_array_equal(rew, want_rew[t])
    with pytest.raises(ValueError, match="Discrete\\(3\\)"):
        envs.step(np.array([3, 0, 0]))
    envs.close()
    # The hold action as a keyword on the paper's task: three actions, no goal.
    paper = gym.make_vec("rotorhive/Navigate-v0", num_envs=2, hold_action=True)
    assert paper.single_action_space == gym.spaces.Discrete(3)
    assert "goal" not in paper.single_observation_space.spaces
    paper.close()


def test_a_level_that_does_not_exist_is_named():
    with pytest.raises(ValueError, match="lava"):
        gym.make_vec("rotorhive/Navigate-v0", num_envs=2, level="lava")


def _step_against_rust(envs, obs, actions, want_obs):
    """Steps `envs` through `actions`, checking each observation (flattened
    as the Rust `VecEnv` writes it) against `want_obs`; returns the last
    observation and each step's current view (the last depth frame)."""
    views = []
    for t, a in enumerate(actions):
        flat = np.concatenate([obs["depth"].reshape(len(a), -1), obs["velocity"]], axis=1)
        np.testing.assert_array_equal(flat, want_obs[t])
        views.append(obs["depth"][:, -1].copy())
        obs, *_ = envs.step(a)
    return obs, views


def test_more_depth_frames_reach_the_spaces_the_rollout_and_the_network():
    """`frames=4` (the key `sim.frames`): the depth part of the observation
    holds the last four views oldest first, as the Rust `VecEnv` writes
    them, and a network of four frames takes those observations."""
    envs = gym.make_vec("rotorhive/Navigate-v0", num_envs=2, seed=3, frames=4, autoreset_mode="SameStep")
    assert envs.single_observation_space["depth"].shape == (4, 32, 32)
    obs, _ = envs.reset()
    assert obs["depth"].shape == (2, 4, 32, 32)
    # A new episode starts with every frame its first view.
    np.testing.assert_array_equal(obs["depth"][:, 0], obs["depth"][:, 3])
    actions = np.array([[0, 1], [1, 1], [0, 0]], np.uint8)
    want_obs, _, _ = _rotorhive.reference_rollout(actions, 3, overrides=["sim.frames=4"])
    assert want_obs.shape[2] == 4 * 32 * 32 + 3
    obs, views = _step_against_rust(envs, obs, actions, want_obs)
    # Each step moves the frames one older.
    np.testing.assert_array_equal(obs["depth"][:, 2], views[-1])
    np.testing.assert_array_equal(obs["depth"][:, 1], views[-2])
    envs.close()
    net = rotorhive.QNetwork(seed=1, frames=4)
    assert net.obs_len == 4 * 32 * 32 + 3
    assert net.q_values(want_obs[0]).shape == (2, 2)
    with pytest.raises(ValueError, match="depth frames"):
        rotorhive.QNetwork(frames=9)


def test_frames_further_apart_reach_the_rollout_and_the_network():
    """`frame_stride=3` (the key `sim.frame_stride`): two frames three
    steps apart, as the Rust `VecEnv` writes them; the network says the
    stride it was made for, and a checkpoint keeps it."""
    envs = gym.make_vec("rotorhive/Navigate-v0", num_envs=2, seed=3, frame_stride=3, autoreset_mode="SameStep")
    assert envs.single_observation_space["depth"].shape == (2, 32, 32)
    obs, _ = envs.reset()
    actions = np.array([[0, 1], [1, 1], [0, 0], [1, 0], [1, 1]], np.uint8)
    want_obs, _, _ = _rotorhive.reference_rollout(actions, 3, overrides=["sim.frame_stride=3"])
    obs, views = _step_against_rust(envs, obs, actions, want_obs)
    # The earlier frame is the view of three steps ago, not the last one.
    np.testing.assert_array_equal(obs["depth"][:, 0], views[-3])
    assert not np.array_equal(obs["depth"][:, 0], views[-1])
    envs.close()
    net = rotorhive.QNetwork(seed=1, frame_stride=3)
    assert net.frame_stride == 3
    with pytest.raises(ValueError, match="frame stride"):
        rotorhive.QNetwork(frame_stride=9)


def test_a_checkpoint_keeps_its_frame_stride(tmp_path):
    path = tmp_path / "s3.safetensors"
    rotorhive.QNetwork(seed=2, frame_stride=3).save(path)
    assert rotorhive.QNetwork.load(path).frame_stride == 3
