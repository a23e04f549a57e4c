"""The ONNX export gives the Rust network's Q-values in onnxruntime."""

import subprocess
import sys

import numpy as np
import pytest

import rotorhive
from rotorhive.export import export_onnx
from rotorhive.net import flat_observations


def observations(n):
    env = rotorhive.NavigateVectorEnv(n, seed=5)
    obs, _ = env.reset(seed=5)
    depth, vel = [obs["depth"]], [obs["velocity"]]
    for t in range(3):
        obs, *_ = env.step(np.arange(n) % 2 if t % 2 else 1 - np.arange(n) % 2)
        depth.append(obs["depth"])
        vel.append(obs["velocity"])
    return np.concatenate(depth)[:100], np.concatenate(vel)[:100]


@pytest.fixture
def checkpoint(tmp_path):
    # A network whose weights are not the initial ones: random but fixed.
    net = rotorhive.QNetwork(seed=11)
    path = tmp_path / "w.safetensors"
    net.save(str(path))
    return path


def test_onnxruntime_gives_the_rust_q_values(checkpoint, tmp_path):
    import onnx
    import onnxruntime as ort

    out = export_onnx(checkpoint, tmp_path / "policy.onnx")
    model = onnx.load(out)
    onnx.checker.check_model(model, full_check=True)
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["layout"].startswith("rotorhive-qnet/") and meta["actions"] == "2" and meta["obs_len"] == "2051"
    depth, vel = observations(25)
    assert depth.shape == (100, 2, 32, 32)
    want = rotorhive.QNetwork.load(str(checkpoint)).q_values(flat_observations(depth, vel))
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    got = sess.run(["q"], {"depth": depth.astype(np.float32), "velocity": vel.astype(np.float32)})[0]
    assert got.shape == (100, 2)
    assert np.abs(got - want).max() <= 1e-4, np.abs(got - want).max()
    assert (got.argmax(1) == want.argmax(1)).mean() > 0.99


def test_a_network_of_the_cameras_map_exports_it_as_its_own_input(tmp_path):
    import onnxruntime as ort

    net = rotorhive.QNetwork(seed=3, map=72)
    assert net.map == 72 and net.obs_len == 2 * 32 * 32 + 3 + 72
    path = tmp_path / "map.safetensors"
    net.save(str(path))
    loaded = rotorhive.QNetwork.load(str(path))
    assert loaded.map == 72
    rng = np.random.default_rng(4)
    depth = rng.random((20, 2, 32, 32), dtype=np.float32)
    vel = rng.normal(size=(20, 3)).astype(np.float32)
    cells = rng.random((20, 72), dtype=np.float32)
    flat = np.ascontiguousarray(np.concatenate([depth.reshape(20, -1), vel, cells], axis=1), dtype=np.float32)
    want = loaded.q_values(flat)
    out = export_onnx(path, tmp_path / "map.onnx")
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == ["depth", "velocity", "map"]
    got = sess.run(["q"], {"depth": depth, "velocity": vel, "map": cells})[0]
    assert np.abs(got - want).max() <= 1e-4, np.abs(got - want).max()


def test_a_network_of_the_seen_movers_exports_them_after_the_map(tmp_path):
    import onnxruntime as ort

    net = rotorhive.QNetwork(seed=5, map=72, tracks=70)
    assert net.tracks == 70 and net.obs_len == 2 * 32 * 32 + 3 + 72 + 70
    path = tmp_path / "tracks.safetensors"
    net.save(str(path))
    loaded = rotorhive.QNetwork.load(str(path))
    assert (loaded.map, loaded.tracks) == (72, 70)
    rng = np.random.default_rng(6)
    depth = rng.random((20, 2, 32, 32), dtype=np.float32)
    vel = rng.normal(size=(20, 3)).astype(np.float32)
    cells = rng.random((20, 72), dtype=np.float32)
    tracks = rng.normal(size=(20, 70)).astype(np.float32)
    flat = np.ascontiguousarray(np.concatenate([depth.reshape(20, -1), vel, cells, tracks], axis=1), dtype=np.float32)
    want = loaded.q_values(flat)
    out = export_onnx(path, tmp_path / "tracks.onnx")
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == ["depth", "velocity", "map", "tracks"]
    got = sess.run(["q"], {"depth": depth, "velocity": vel, "map": cells, "tracks": tracks})[0]
    assert np.abs(got - want).max() <= 1e-4, np.abs(got - want).max()


def test_the_command_refuses_a_bad_checkpoint(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a checkpoint")
    p = subprocess.run([sys.executable, "-m", "rotorhive.export", "--checkpoint", str(bad), "--out", str(tmp_path / "x.onnx")], capture_output=True, text=True)
    assert p.returncode != 0
    assert "bad.safetensors" in p.stderr
    assert not (tmp_path / "x.onnx").exists()


HIVE = __import__("pathlib").Path(__file__).resolve().parents[3] / "target" / "release" / "hive"


@pytest.mark.skipif(not HIVE.exists(), reason="needs target/release/hive (scripts/test builds it)")
def test_hive_export_writes_the_same_model(checkpoint, tmp_path):
    out = tmp_path / "cli.onnx"
    p = subprocess.run([str(HIVE), "export", "--checkpoint", str(checkpoint), "--out", str(out)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert out.read_bytes() != b""
    import onnxruntime as ort

    depth, vel = observations(10)
    want = rotorhive.QNetwork.load(str(checkpoint)).q_values(flat_observations(depth, vel))
    got = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"]).run(["q"], {"depth": depth, "velocity": vel})[0]
    assert np.abs(got - want).max() <= 1e-4
    bad = subprocess.run([str(HIVE), "export", "--checkpoint", str(tmp_path / "none.safetensors"), "--out", str(tmp_path / "n.onnx")], capture_output=True, text=True)
    assert bad.returncode != 0 and "none.safetensors" in bad.stderr


def test_a_goal_network_exports_its_own_shapes(tmp_path):
    """A network of a goal task with the hold action and four depth frames:
    the checkpoint says its shapes, loads as them, and onnxruntime takes
    four frames and six scalars and gives three Q-values, the Rust ones."""
    import onnxruntime as ort

    net = rotorhive.QNetwork(seed=3, goal=True, hold=True, frames=4)
    assert (net.obs_len, net.actions) == (4 * 32 * 32 + 6, 3)
    path = tmp_path / "goal.safetensors"
    net.save(str(path))
    loaded = rotorhive.QNetwork.load(str(path))
    assert (loaded.obs_len, loaded.actions) == (4102, 3)
    out = export_onnx(path, tmp_path / "goal.onnx")
    rng = np.random.default_rng(1)
    depth = rng.random((7, 4, 32, 32), dtype=np.float32)
    scalars = rng.normal(size=(7, 6)).astype(np.float32)
    want = loaded.q_values(np.concatenate([depth.reshape(7, -1), scalars], axis=1))
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    got = sess.run(["q"], {"depth": depth, "velocity": scalars})[0]
    assert got.shape == (7, 3)
    assert np.abs(got - want).max() <= 1e-4
    with pytest.raises(ValueError, match="shape \\(B, 4102\\)"):
        loaded.q_values(np.zeros((1, 2051), np.float32))


def test_a_network_of_other_widths_round_trips_through_a_checkpoint_onnx_and_numpy(tmp_path):
    import onnx
    import onnxruntime as ort

    from rotorhive.net import load_checkpoint, numpy_q_values

    net = rotorhive.QNetwork(seed=4, conv_channels=[24, 40], hidden=[96, 32])
    path = tmp_path / "wide.safetensors"
    net.save(str(path))
    back = rotorhive.QNetwork.load(str(path))
    assert (back.conv_channels, back.hidden) == ([24, 40], [96, 32])
    depth, vel = observations(25)
    want = back.q_values(flat_observations(depth, vel))
    np.testing.assert_allclose(numpy_q_values(load_checkpoint(path), depth, vel), want, rtol=1e-4, atol=1e-5)
    out = export_onnx(path, tmp_path / "wide.onnx")
    model = onnx.load(out)
    onnx.checker.check_model(model, full_check=True)
    assert {p.key: p.value for p in model.metadata_props}["layers"] == "conv:24,40 hidden:96,32"
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    got = sess.run(["q"], {"depth": depth.astype(np.float32), "velocity": vel.astype(np.float32)})[0]
    assert np.abs(got - want).max() <= 1e-4, np.abs(got - want).max()
    # A recurrent network of other widths too: its GRU reads the last hidden layer.
    gru = rotorhive.RecurrentQNetwork(width=8, seed=3, conv_channels=[8, 16], hidden=[48])
    gpath = tmp_path / "gru-wide.safetensors"
    gru.save(str(gpath))
    gout = export_onnx(gpath, tmp_path / "gru-wide.onnx")
    gsess = ort.InferenceSession(gout, providers=["CPUExecutionProvider"])
    d, v = depth[:25], vel[:25]
    q_rust, h_rust = rotorhive.RecurrentQNetwork.load(str(gpath)).step(flat_observations(d, v), gru.initial_state(25))
    q_onnx, h_onnx = gsess.run(["q", "next_state"], {"depth": d, "velocity": v, "state": np.zeros((25, 8), np.float32)})
    assert np.abs(q_onnx - q_rust).max() <= 1e-4 and np.abs(h_onnx - h_rust).max() <= 1e-4
    with pytest.raises(ValueError, match="hidden has 4 entries"):
        rotorhive.QNetwork(hidden=[8, 8, 8, 8])


def test_a_recurrent_network_exports_its_state_and_matches_over_a_sequence(tmp_path):
    import onnx
    import onnxruntime as ort

    net = rotorhive.RecurrentQNetwork(width=8, seed=3)
    path = tmp_path / "gru.safetensors"
    net.save(str(path))
    back = rotorhive.RecurrentQNetwork.load(str(path))
    assert back.width == 8
    with pytest.raises(ValueError, match="memory gru:8"):
        rotorhive.QNetwork.load(str(path))
    out = tmp_path / "gru.onnx"
    back.to_onnx(str(out))
    model = onnx.load(str(out))
    onnx.checker.check_model(model, full_check=True)
    assert {p.key: p.value for p in model.metadata_props}["memory"] == "gru:8"
    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    depth, vel = observations(25)
    # Four steps of 25 agents, the state carried by each side.
    h_rust, h_onnx = net.initial_state(25), np.zeros((25, 8), np.float32)
    for t in range(4):
        d, v = depth[25 * t : 25 * (t + 1)], vel[25 * t : 25 * (t + 1)]
        q_rust, h_rust = back.step(flat_observations(d, v), h_rust)
        q_onnx, h_onnx = sess.run(["q", "next_state"], {"depth": d, "velocity": v, "state": h_onnx})
        assert np.abs(q_onnx - q_rust).max() <= 1e-4, (t, np.abs(q_onnx - q_rust).max())
        assert np.abs(h_onnx - h_rust).max() <= 1e-4
    # The state matters: from zeros again, the last step's Q-values differ.
    q_fresh, _ = back.step(flat_observations(d, v), net.initial_state(25))
    assert np.abs(q_fresh - q_rust).max() > 1e-4


@pytest.mark.skipif(not HIVE.exists(), reason="needs target/release/hive (scripts/test builds it)")
def test_both_exports_of_a_recurrent_checkpoint_take_the_state(tmp_path):
    import onnxruntime as ort

    path = tmp_path / "gru.safetensors"
    rotorhive.RecurrentQNetwork(width=4, seed=2).save(str(path))
    assert rotorhive._rotorhive.checkpoint_width(str(path)) == 4
    for out in [tmp_path / "cli.onnx", tmp_path / "py.onnx"]:
        if out.name == "cli.onnx":
            p = subprocess.run([str(HIVE), "export", "--checkpoint", str(path), "--out", str(out)], capture_output=True, text=True)
            assert p.returncode == 0 and "next_state (B, 4)" in p.stdout, p.stderr
        else:
            export_onnx(path, out)
        names = [i.name for i in ort.InferenceSession(str(out), providers=["CPUExecutionProvider"]).get_inputs()]
        assert names == ["depth", "velocity", "state"]
