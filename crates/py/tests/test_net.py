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


def test_one_network_class_flies_both_kinds_and_the_old_names_still_work(tmp_path):
    ff = rotorhive.PolicyNetwork(seed=1, frames=4, conv_channels=[8, 16], hidden=[48, 24])
    gru = rotorhive.PolicyNetwork(seed=1, memory=8)
    assert (ff.memory, ff.width, gru.memory, gru.width) == (None, 0, 8, 8)
    # The old names are the same class, with their arguments as before.
    old = rotorhive.RecurrentQNetwork(width=8, seed=1)
    assert isinstance(old, rotorhive.PolicyNetwork) and old.memory == 8
    assert isinstance(rotorhive.QNetwork(1), rotorhive.PolicyNetwork) and rotorhive.QNetwork(1).memory is None
    np.testing.assert_array_equal(old.weights()["gru.weight_ih"], gru.weights()["gru.weight_ih"])
    # A feedforward network steps with a state of no column, as it answers q_values.
    obs = np.random.default_rng(0).random((3, ff.obs_len), dtype=np.float32)
    q, h = ff.step(obs, ff.initial_state(3))
    assert h.shape == (3, 0)
    np.testing.assert_array_equal(q, ff.q_values(obs))
    with pytest.raises(ValueError, match="step"):
        gru.q_values(np.zeros((3, gru.obs_len), np.float32))
    # Each checkpoint loads as what it holds; the old names refuse the other kind by name.
    p_ff, p_gru = tmp_path / "ff.safetensors", tmp_path / "gru.safetensors"
    ff.save(str(p_ff))
    gru.save(str(p_gru))
    assert rotorhive.PolicyNetwork.load(str(p_gru)).memory == 8
    assert rotorhive.PolicyNetwork.load(str(p_ff)).hidden == [48, 24]
    with pytest.raises(ValueError, match="memory none"):
        rotorhive.RecurrentQNetwork.load(str(p_ff))
    # The numpy forward reads every size from the weights.
    g = net.geometry(ff.weights())
    assert (g.frames, g.channels, g.pooled, g.hidden, g.actions) == (4, (8, 16), (6, 6), (48, 24), 2)
    depth, vel = obs[:, : 4 * 1024].reshape(3, 4, 32, 32), obs[:, 4 * 1024 :]
    np.testing.assert_allclose(net.numpy_q_values(net.torch_layout(ff.weights()), depth, vel), ff.q_values(obs), rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError, match="memory"):
        net.torch_layout(gru.weights())


def test_a_network_of_another_camera_converts_and_exports(tmp_path):
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    from rotorhive.export import export_onnx

    # 48 x 40 frames: a pooled map of 10 x 8, neither square nor the paper's.
    rust = rotorhive.PolicyNetwork(seed=4, depth=(48, 40))
    assert rust.depth == (48, 40) and rust.obs_len == 2 * 48 * 40 + 3
    path = tmp_path / "wide.safetensors"
    rust.save(str(path))
    back = rotorhive.PolicyNetwork.load(str(path))
    assert back.depth == (48, 40)
    assert net.pooled_grid((48, 40)) == (10, 8) and net.pooled_grid((32, 32)) == (6, 6)
    rng = np.random.default_rng(1)
    depth, vel = rng.random((7, 2, 48, 40), dtype=np.float32), rng.normal(size=(7, 3)).astype(np.float32)
    want = back.q_values(net.flat_observations(depth, vel))
    np.testing.assert_allclose(net.numpy_q_values(net.load_checkpoint(path), depth, vel), want, rtol=1e-4, atol=1e-5)
    out = export_onnx(path, tmp_path / "wide.onnx")
    model = onnx.load(out)
    onnx.checker.check_model(model, full_check=True)
    dims = [d.dim_value for d in model.graph.input[0].type.tensor_type.shape.dim]
    assert dims[1:] == [2, 48, 40], dims
    got = ort.InferenceSession(out, providers=["CPUExecutionProvider"]).run(["q"], {"depth": depth, "velocity": vel})[0]
    assert np.abs(got - want).max() <= 1e-4
    with pytest.raises(ValueError, match="depth frames of 8 x 40"):
        rotorhive.PolicyNetwork(depth=(8, 40))


def test_an_environment_of_another_camera_observes_its_frames():
    envs = rotorhive.NavigateVectorEnv(3, seed=2, camera={"width": 64, "height": 48, "pool": 2, "hfov_deg": 100.0})
    assert envs.single_observation_space["depth"].shape == (2, 24, 32)
    obs, _ = envs.reset(seed=2)
    assert obs["depth"].shape == (3, 2, 24, 32) and 0.0 <= obs["depth"].min() and obs["depth"].max() <= 1.0
    obs, *_ = envs.step(np.zeros(3, np.int64))
    # A network of that camera flies it.
    q = rotorhive.PolicyNetwork(depth=(24, 32)).q_values(net.flat_observations(obs["depth"], obs["velocity"]))
    assert q.shape == (3, 2)
    with pytest.raises(ValueError, match="sim.camera.pool"):
        rotorhive.NavigateVectorEnv(2, camera={"width": 64, "pool": 3})
