"""Checkpoints in Python: the numpy forward pass on PyTorch-layout weights
gives the Rust network's Q-values (the learner's and `hive eval`'s)."""

import numpy as np
import pytest

import rotorhive
from rotorhive import net


def observations(n=16, seed=3):
    envs = rotorhive.NavigateVectorEnv(n, seed=seed)
    envs.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(5):
        obs, *_ = envs.step(rng.integers(0, 2, n))
    return obs


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_numpy_forward_on_converted_weights_matches_the_rust_network(tmp_path, seed):
    path = tmp_path / "net.safetensors"
    rotorhive.QNetwork(seed).save(str(path))
    rust = rotorhive.QNetwork.load(str(path))
    obs = observations()
    q_rust = rust.q_values(net.flat_observations(obs["depth"], obs["velocity"]))
    w = net.load_checkpoint(path)
    assert w["conv2.weight"].shape == (32, 16, 3, 3) and w["fc1.weight"].shape == (64, 1168)
    q_np = net.numpy_q_values(w, obs["depth"], obs["velocity"])
    assert q_rust.shape == (16, 2)
    np.testing.assert_allclose(q_np, q_rust, rtol=1e-4, atol=1e-5)
    # The check can fail: the rotorhive layout read as PyTorch's gives other values.
    raw = {k: v for k, v in rust.weights().items()}
    raw["conv1.weight"] = raw["conv1.weight"].reshape(16, 2, 6, 6)
    raw["conv2.weight"] = raw["conv2.weight"].reshape(32, 16, 3, 3)
    assert not np.allclose(net.numpy_q_values(raw, obs["depth"], obs["velocity"]), q_rust, rtol=1e-3)


def test_bad_checkpoints_raise_value_errors_naming_the_file(tmp_path):
    with pytest.raises(ValueError, match="missing.safetensors"):
        net.load_checkpoint(tmp_path / "missing.safetensors")
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json at all")
    with pytest.raises(ValueError, match="bad.safetensors"):
        rotorhive.QNetwork.load(str(bad))
    with pytest.raises(ValueError, match="2051"):
        rotorhive.QNetwork(0).q_values(np.zeros((2, 10), np.float32))


def test_torch_module_matches_the_numpy_forward(tmp_path):
    torch = pytest.importorskip("torch", reason="torch is not in the test environment (the registry offers only its 5.4 GB CUDA build): scripts/sb3_torch.py runs it")
    path = tmp_path / "net.safetensors"
    rotorhive.QNetwork(5).save(str(path))
    module = net.torch_qnet(path)
    obs = observations(4)
    with torch.no_grad():
        q_t = module(torch.from_numpy(obs["depth"]), torch.from_numpy(obs["velocity"])).numpy()
    np.testing.assert_allclose(q_t, net.numpy_q_values(net.load_checkpoint(path), obs["depth"], obs["velocity"]), rtol=1e-4, atol=1e-5)
