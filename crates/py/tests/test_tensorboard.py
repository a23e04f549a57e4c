"""hive train's TensorBoard log, read back by TensorBoard's own loader."""

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
HIVE = ROOT / "target" / "release" / "hive"


def scalars(run_dir):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: acc.Scalars(tag) for tag in acc.Tags()["scalars"]}


@pytest.mark.skipif(not HIVE.exists(), reason="needs target/release/hive (scripts/test builds it)")
def test_a_training_run_leaves_a_log_tensorboard_reads(tmp_path):
    run = tmp_path / "run"
    common = ["--quiet", "--set", "threshold=100000", "--set", "eval.every_s=5", "--set", "sim.agents=20", "--set", "replay.min_fill=500"]
    # Short evaluations (no confirmation), so that one ends well inside the
    # run on a slow machine too (the defaults' 100 + 300 episodes took 7 s
    # of these 14 on an AVX2 Zen 3).
    quick = ["--set", "eval.episodes=40", "--set", "eval.confirm_episodes=0"]
    p = subprocess.run([str(HIVE), "train", "configs/default.toml", "--max-seconds", "14", "--run-dir", str(run)] + common + quick, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    s = scalars(run)
    long = [tag for tag, points in s.items() if len(points) >= 10]
    assert len(long) >= 10, {tag: len(points) for tag, points in s.items()}
    for tag in ["rollout/rolling_reward", "rollout/epsilon", "train/loss", "train/mean_max_q", "time/agent_steps_per_s", "train/updates_per_s", "cpu/learner-0", "cpu/sim-0"]:
        assert tag in s, sorted(s)
    # The step axis is agent-steps, rising; the values are the run's.
    steps = [e.step for e in s["rollout/epsilon"]]
    assert steps == sorted(steps) and steps[-1] > 1000
    assert all(0.0 <= e.value <= 1.0 for e in s["rollout/epsilon"])
    assert max(e.value for e in s["time/agent_steps_per_s"]) > 100
    assert "eval/validation_success" in s and all(0.0 <= e.value <= 1.0 for e in s["eval/validation_success"])

    off = tmp_path / "off"
    p = subprocess.run(
        [str(HIVE), "train", "configs/default.toml", "--max-seconds", "3", "--run-dir", str(off), "--set", "tensorboard=false"] + common,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    assert not (off / "tb").exists()
