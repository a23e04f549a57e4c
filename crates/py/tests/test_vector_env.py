"""The vector environment against Gymnasium's definitions and the Rust VecEnv."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.utils.passive_env_checker import check_obs, data_shares_objects
from gymnasium.vector import AutoresetMode

import rotorhive
from rotorhive import _rotorhive
from rotorhive.envs import COLLISION, GOAL, RUNNING, TIMEOUT

N = 6
# Short episodes, so that every mode sees many ends in a few steps.
SHORT = {"max_steps": 12, "generated_lanes": 2}


def actions_for(t: int, n: int = N) -> np.ndarray:
    return np.array([((t * 7 + i * 3) % 5 < 2) for i in range(n)], dtype=np.int64)


def flat(obs: dict) -> np.ndarray:
    n = obs["depth"].shape[0]
    return np.concatenate([obs["depth"].reshape(n, -1), obs["velocity"]], axis=1)


def is_first_obs(obs: dict, i: int) -> bool:
    """A new episode starts with both frames equal to its first view."""
    return bool(np.array_equal(obs["depth"][i, 0], obs["depth"][i, 1]))


@pytest.mark.parametrize("mode", list(AutoresetMode))
def test_make_vec_gives_the_native_vector_env_with_its_spaces(mode):
    envs = gym.make_vec("rotorhive/Navigate-v0", num_envs=N, autoreset_mode=mode)
    assert isinstance(envs, rotorhive.NavigateVectorEnv)
    assert envs.num_envs == N
    assert envs.metadata["autoreset_mode"] == mode
    assert envs.single_observation_space == gym.spaces.Dict(
        {
            "depth": gym.spaces.Box(0, 1, (2, 32, 32), np.float32),
            "velocity": gym.spaces.Box(-np.inf, np.inf, (3,), np.float32),
        }
    )
    assert envs.single_action_space == gym.spaces.Discrete(2)
    obs, infos = envs.reset(seed=3)
    check_obs(obs, envs.observation_space, "reset")
    assert envs.observation_space.contains(obs)
    obs, rewards, term, trunc, infos = envs.step(envs.action_space.sample())
    check_obs(obs, envs.observation_space, "step")
    assert rewards.shape == (N,) and term.dtype == np.bool_ and trunc.dtype == np.bool_
    envs.close()


def test_the_cameras_map_is_its_own_part_of_the_observation():
    envs = gym.make_vec("rotorhive/Navigate-v0", num_envs=N, map={"encoding": "rays", "rays": 24})
    assert envs.single_observation_space["map"] == gym.spaces.Box(0, 1, (48,), np.float32)
    obs, _ = envs.reset(seed=3)
    assert obs["map"].shape == (N, 48) and envs.observation_space.contains(obs)
    # Straight behind the drone nothing was seen: unknown at once.
    assert (obs["map"][:, 24 + 12] < 0.1).all(), obs["map"][:, 36]
    for _ in range(3):
        obs, *_ = envs.step(envs.action_space.sample())
    check_obs(obs, envs.observation_space, "step")
    envs.close()
    with pytest.raises(ValueError, match="sim.map.rays"):
        gym.make_vec("rotorhive/Navigate-v0", num_envs=N, map={"encoding": "rays", "rays": 1})


def test_the_seen_movers_are_their_own_part_of_the_observation():
    envs = gym.make_vec("rotorhive/Navigate-v0", num_envs=N, map={"encoding": "rays"}, tracks={"count": 3})
    space = envs.single_observation_space
    assert space["tracks"].shape == (3 * 14,) and space["map"].shape == (72,)
    obs, _ = envs.reset(seed=3)
    assert obs["tracks"].shape == (N, 42) and envs.observation_space.contains(obs)
    # The paper's arena has no movers: nothing is tracked.
    assert (obs["tracks"] == 0).all()
    obs, *_ = envs.step(envs.action_space.sample())
    check_obs(obs, envs.observation_space, "step")
    envs.close()
    with pytest.raises(ValueError, match="sim.tracks.count"):
        gym.make_vec("rotorhive/Navigate-v0", num_envs=N, tracks={"count": 99})


def test_same_step_agrees_step_for_step_with_the_rust_vecenv():
    """SAME_STEP returns what `hive train`'s VecEnv gives (reset inside the
    step) for the same seed, arena and actions."""
    steps = 60
    acts = np.stack([actions_for(t) for t in range(steps)]).astype(np.uint8)
    overrides = [f"sim.{k}={v}" for k, v in SHORT.items()]
    ref_obs, ref_rewards, ref_dones = _rotorhive.reference_rollout(acts, seed=9, overrides=overrides)
    envs = rotorhive.NavigateVectorEnv(N, seed=9, autoreset_mode="SameStep", **SHORT)
    # The first reset without a seed keeps the construction's spawns.
    obs, _ = envs.reset()
    np.testing.assert_array_equal(flat(obs), ref_obs[0])
    ends = 0
    for t in range(steps):
        obs, rewards, term, trunc, infos = envs.step(acts[t])
        np.testing.assert_array_equal(flat(obs), ref_obs[t + 1], err_msg=f"step {t}")
        np.testing.assert_array_equal(rewards, ref_rewards[t])
        np.testing.assert_array_equal(term, np.isin(ref_dones[t], [COLLISION, GOAL]))
        np.testing.assert_array_equal(trunc, ref_dones[t] == TIMEOUT)
        ends += int((term | trunc).sum())
    assert ends >= N, f"the comparison needs ended episodes, saw {ends}"


def test_next_step_starts_the_next_episode_one_step_later_ignoring_the_action():
    envs = rotorhive.NavigateVectorEnv(N, seed=2, **SHORT)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    envs.reset(seed=2)
    prev_ended = np.zeros(N, bool)
    checked = 0
    for t in range(40):
        obs, rewards, term, trunc, infos = envs.step(actions_for(t))
        for i in np.flatnonzero(prev_ended):
            assert rewards[i] == 0.0 and not term[i] and not trunc[i], f"step {t} agent {i}"
            assert is_first_obs(obs, i)
            np.testing.assert_allclose(obs["velocity"][i], [1.0, 0.0, 0.0], atol=1e-6)
            checked += 1
        ended = term | trunc
        for i in np.flatnonzero(ended):
            # The ending step returns the episode's last observation.
            assert not is_first_obs(obs, i)
            assert infos["_success"][i] and infos["success"][i] == (infos["done"][i] == GOAL)
            assert infos["done"][i] in (COLLISION, GOAL, TIMEOUT)
            assert 1 <= infos["episode_length"][i] <= SHORT["max_steps"]
        prev_ended = ended
    assert checked >= N


def test_same_step_returns_the_final_observation_in_infos():
    envs = rotorhive.NavigateVectorEnv(N, seed=4, autoreset_mode=AutoresetMode.SAME_STEP, **SHORT)
    envs.reset(seed=4)
    seen = 0
    for t in range(30):
        obs, rewards, term, trunc, infos = envs.step(actions_for(t))
        ended = term | trunc
        if not ended.any():
            assert "final_obs" not in infos
            continue
        np.testing.assert_array_equal(infos["_final_obs"], ended)
        np.testing.assert_array_equal(infos["_final_info"], ended)
        for i in range(N):
            fo = infos["final_obs"][i]
            if not ended[i]:
                assert fo is None
                continue
            assert envs.single_observation_space.contains(fo)
            assert not np.array_equal(fo["depth"][0], fo["depth"][1]), "the final frames are of a flown episode"
            assert is_first_obs(obs, i), "the returned observation starts the next episode"
            done = infos["final_info"]["done"][i]
            assert done == TIMEOUT if trunc[i] else done in (COLLISION, GOAL)
            assert (done == COLLISION) == (rewards[i] == -100.0)
            assert infos["final_info"]["_episode_return"][i]
            seen += 1
    assert seen >= N


def test_disabled_mode_leaves_resets_to_the_user():
    envs = rotorhive.NavigateVectorEnv(N, seed=5, autoreset_mode="Disabled", **SHORT)
    envs.reset(seed=5)
    for t in range(40):
        obs, rewards, term, trunc, infos = envs.step(actions_for(t))
        ended = term | trunc
        if ended.any():
            break
    else:
        pytest.fail("no episode ended")
    for i in np.flatnonzero(ended):
        assert not is_first_obs(obs, i)
    with pytest.raises(gym.error.ResetNeeded, match="reset_mask"):
        envs.step(actions_for(0))
    before = {k: v.copy() for k, v in obs.items()}
    obs2, _ = envs.reset(options={"reset_mask": ended})
    for i in range(N):
        if ended[i]:
            assert is_first_obs(obs2, i)
        else:
            np.testing.assert_array_equal(obs2["depth"][i], before["depth"][i])
            np.testing.assert_array_equal(obs2["velocity"][i], before["velocity"][i])
    envs.step(actions_for(1))


def test_reset_with_a_seed_is_reproducible_and_the_returned_data_is_fresh():
    envs = rotorhive.NavigateVectorEnv(N, seed=0)
    a, _ = envs.reset(seed=11)
    s1 = envs.step(actions_for(0))
    s2 = envs.step(actions_for(1))
    b, _ = envs.reset(seed=11)
    replay = envs.step(actions_for(0))
    c, _ = envs.reset(seed=12)
    assert data_equivalence(a, b, exact=True)
    assert not data_equivalence(a, c)
    assert data_equivalence(replay[0], s1[0], exact=True)
    np.testing.assert_array_equal(replay[1], s1[1])
    assert not data_shares_objects(a, b)
    assert not data_shares_objects(s1[0], s2[0])


def test_copy_false_returns_views_that_the_next_step_overwrites():
    envs = rotorhive.NavigateVectorEnv(N, seed=1, copy=False)
    obs, _ = envs.reset(seed=1)
    snapshot = obs["depth"].copy()
    obs2, *_ = envs.step(actions_for(0))
    assert obs2["depth"] is obs["depth"]
    assert not np.array_equal(obs["depth"], snapshot), "the view shows the new step"


def test_record_episode_statistics_reads_the_autoreset_mode():
    envs = gym.wrappers.vector.RecordEpisodeStatistics(rotorhive.NavigateVectorEnv(N, seed=3, **SHORT))
    envs.reset(seed=3)
    stats = 0
    for t in range(30):
        *_, infos = envs.step(actions_for(t))
        if "episode" in infos:
            stats += int(infos["_episode"].sum())
            np.testing.assert_array_equal(infos["episode"]["r"][infos["_episode"]], infos["episode_return"][infos["_episode"]])
    assert stats >= N


def test_generated_and_file_arenas():
    from pathlib import Path

    test_arena = Path(__file__).resolve().parents[3] / "configs" / "arenas" / "test.toml"
    a = rotorhive.NavigateVectorEnv(2, arena=test_arena, generated_lanes=0)
    b = rotorhive.NavigateVectorEnv(2, arena_seed=77, generated_lanes=0)
    oa, _ = a.reset(seed=1)
    ob, _ = b.reset(seed=1)
    assert not data_equivalence(oa, ob)
