"""Bad arguments raise a Python exception that names the problem."""

import gymnasium as gym
import numpy as np
import pytest

import rotorhive
from rotorhive import _rotorhive


def test_unknown_keyword_names_the_key_and_the_known_ones():
    with pytest.raises(TypeError, match="'speed'.*physics_dt"):
        gym.make_vec("rotorhive/Navigate-v0", num_envs=2, speed=3)


def test_bad_arena_path_names_the_file(tmp_path):
    with pytest.raises(ValueError, match="nowhere.toml"):
        rotorhive.NavigateVectorEnv(2, arena=tmp_path / "nowhere.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("length = 'long'\n")
    with pytest.raises(ValueError, match="bad.toml"):
        rotorhive.NavigateVectorEnv(2, arena=bad)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"physics_dt": -1.0}, ValueError, "physics_dt"),
        ({"renderer": "gpu"}, ValueError, "renderer"),
        ({"max_steps": "many"}, ValueError, "max_steps"),
        ({"interactive": [1]}, TypeError, "interactive"),
        ({"autoreset_mode": "Sometimes"}, ValueError, "autoreset_mode"),
        ({"arena": "a.toml", "arena_seed": 3}, ValueError, "not both"),
        ({"seed": -1}, ValueError, "seed"),
    ],
)
def test_bad_settings(kwargs, error, match):
    with pytest.raises(error, match=match):
        rotorhive.NavigateVectorEnv(2, **kwargs)


@pytest.mark.parametrize("n, error", [(0, ValueError), (2.5, TypeError), ("4", TypeError)])
def test_bad_num_envs(n, error):
    with pytest.raises(error, match="num_envs"):
        rotorhive.NavigateVectorEnv(n)


@pytest.mark.parametrize(
    "actions, error, match",
    [
        (np.zeros(3, np.int64), ValueError, "shape"),
        (np.zeros((2, 1), np.int64), ValueError, "shape"),
        (np.zeros(2, np.float32), TypeError, "dtype"),
        (np.array([0, 2]), ValueError, r"actions\[1\] = 2"),
        (np.array([-1, 0]), ValueError, "out of range"),
        ("01", ValueError, "shape"),
    ],
)
def test_bad_actions(actions, error, match):
    envs = rotorhive.NavigateVectorEnv(2)
    envs.reset()
    with pytest.raises(error, match=match):
        envs.step(actions)
    envs.step(np.array([0, 1]))  # still usable


def test_bad_reset_masks_and_order_of_calls():
    envs = rotorhive.NavigateVectorEnv(3)
    with pytest.raises(gym.error.ResetNeeded):
        envs.step(np.zeros(3, np.int64))
    envs.reset()
    with pytest.raises(TypeError, match="reset_mask"):
        envs.reset(options={"reset_mask": [True, False, True]})
    with pytest.raises(TypeError, match="reset_mask"):
        envs.reset(options={"reset_mask": np.ones(2, bool)})
    with pytest.raises(ValueError, match="at least one True"):
        envs.reset(options={"reset_mask": np.zeros(3, bool)})
    with pytest.raises(ValueError, match="unknown reset option"):
        envs.reset(options={"spawn": 1})
    envs.close()
    with pytest.raises(gym.error.ClosedEnvironmentError):
        envs.step(np.zeros(3, np.int64))


def test_the_native_layer_checks_its_buffers_too():
    sim = _rotorhive.Sim(2)

    class Buffers:  # the arrays `Sim.step` writes, by attribute
        def __init__(self, depth):
            self.depth, self.velocity = depth, np.zeros((2, 3), np.float32)
            self.rewards, self.dones = np.zeros(2, np.float32), np.zeros(2, np.uint8)
            self.ep_return, self.ep_length = np.zeros(2, np.float32), np.zeros(2, np.int32)

    good = Buffers(np.zeros((2, 2, 32, 32), np.float32))
    with pytest.raises(ValueError, match="depth"):
        sim.step(np.zeros(2, np.uint8), Buffers(np.zeros((1, 2, 32, 32), np.float32)))
    with pytest.raises(ValueError, match=r"actions\[0\] = 7"):
        sim.step(np.array([7, 0], np.uint8), good)
    with pytest.raises(TypeError):
        sim.step(np.zeros(2, np.float64), good)
    with pytest.raises((TypeError, AttributeError)):
        sim.step(np.zeros(2, np.uint8), object())
    sim.step(np.zeros(2, np.uint8), good)
    assert good.depth.max() > 0


def test_single_env_bad_actions():
    env = rotorhive.NavigateEnv()
    env.reset()
    for bad, error in [(2, ValueError), (0.5, TypeError), (np.array([0, 1]), TypeError)]:
        with pytest.raises(error):
            env.step(bad)


def test_a_checkpoint_of_broken_weights_is_refused_by_name(tmp_path):
    """Weights holding NaN load nowhere: the error names the file and the
    tensor."""
    path = tmp_path / "w.safetensors"
    rotorhive.QNetwork(seed=1).save(str(path))
    raw = bytearray(path.read_bytes())
    header = 8 + int.from_bytes(raw[:8], "little")
    raw[header:] = b"\xff" * (len(raw) - header)  # every float a NaN
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"w\.safetensors.*not finite"):
        rotorhive.QNetwork.load(str(path))
