"""A stranger on a live head's port (Python's eclipse-zenoh, not rotorhive's
link) sends malformed, NaN, out-of-range, forged and oversized messages
while a head trains from a worker in another shared-memory domain: the run
goes on and ends well, nothing of it reaches the replay or the records, and
every message is counted against the host whose key it came on."""

import json
import os
import re
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
HIVE = ROOT / "target" / "release" / "hive"


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.skipif(not HIVE.exists(), reason="needs target/release/hive (scripts/test builds it)")
def test_a_stranger_cannot_crash_poison_or_stop_a_run(tmp_path):
    pytest.importorskip("zenoh")
    ep = f"tcp/127.0.0.1:{free_port()}"
    run_dir = tmp_path / "head"
    small = ["--quiet", "--set", "sim.agents=8", "--set", "replay.min_fill=300", "--set", "replay.capacity=4000", "--set", "eval.every_s=0"]
    head = subprocess.Popen(
        [str(HIVE), "--domain", "stranger-head", "train", "configs/default.toml", "--listen", ep, "--max-seconds", "30", "--run-dir", str(run_dir)]
        + small
        + ["--set", "threshold=100000", "--set", "cluster.workers=1", "--set", "cluster.join_timeout_s=30"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    worker = subprocess.Popen(
        [str(HIVE), "--domain", "stranger-worker", "worker", "--connect", ep, "--agents", "8", "--name", "honest", "--run-dir", str(tmp_path / "worker")],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        s = subprocess.run(
            [sys.executable, str(ROOT / "scripts" / "stranger.py"), "--connect", ep, "--rate", "300", "--seconds", "12"],
            capture_output=True,
            text=True,
            timeout=90,
        )
        assert s.returncode == 0, s.stderr
        sent = json.loads(s.stdout.strip().splitlines()[-1])
        w_out, w_err = worker.communicate(timeout=90)
        h_out, h_err = head.communicate(timeout=90)
    finally:
        for p in (head, worker):
            if p.poll() is None:
                p.kill()
    assert head.returncode == 0, h_err
    assert worker.returncode == 0, w_err
    assert "panicked" not in h_err + w_err
    assert "the head ended the run" in w_out
    assert sent["slot"] > 1000 and sent["unknown"] > 100, sent

    summary = json.loads((run_dir / "summary.json").read_text())
    hosts = summary["hosts"]
    assert [h["name"] for h in hosts][1] == "honest"
    # Every message is counted once, against the host its key names (a host
    # named `unknown`: keys of no host); the oversized ones never reach rotorhive.
    assert hosts[1]["rejected_messages"] == sent["slot"], (hosts, sent)
    assert hosts[2]["name"] == "unknown" and hosts[2]["rejected_messages"] == sent["unknown"], (hosts, sent)
    assert hosts[0]["rejected_messages"] == 0, hosts
    # Each forged kind was refused for its own reason, kind by kind (a
    # header-size drift once refused every forged transition as a header
    # while the totals still matched).
    assert hosts[1]["rejected_by_reason"] == sent["slot_by_reason"], (hosts[1], sent)
    assert hosts[2]["rejected_by_reason"] == sent["unknown_by_reason"], (hosts[2], sent)
    assert set(sent["slot_by_reason"]) == {"length", "values", "environment", "count", "header", "role", "epoch"}
    total = {}
    for h in hosts:
        for k, v in h["rejected_by_reason"].items():
            total[k] = total.get(k, 0) + v
    assert summary["rejected_by_reason"] == total, summary["rejected_by_reason"]
    # Nothing forged was stored or trained on, nothing honest was lost, and
    # the forged counters did not reach the records.
    assert summary["skipped_updates"] == 0
    assert summary["lost_messages"] == 0
    for h in hosts:
        assert h["lost_transitions"] == 0, hosts
    # Every transition the honest worker sent was taken and acknowledged.
    assert hosts[1]["transitions_sent"] > 0, hosts[1]
    assert hosts[1]["transitions_acknowledged"] == hosts[1]["transitions_sent"], hosts[1]
    assert len(hosts) == 3, hosts
    assert summary["env_steps"] < 10**12, summary["env_steps"]
    assert summary["time_to_threshold_s"] is None
    assert summary["learner_updates"] > 50
    assert hosts[1]["env_steps"] > 1000
    assert os.path.exists(run_dir / "final.safetensors")


def hello(layout, host="odd", token="t"):
    """A worker's join request (`link/src/wire.rs`: `RHJ3`, layout, envs,
    agents, host, token, and the earlier process's epoch and transitions
    sent)."""
    s = lambda v: struct.pack("<I", len(v)) + v.encode()  # noqa: E731
    return b"RHJ3" + struct.pack("<QII", layout, 1, 8) + s(host) + s(token) + struct.pack("<QQ", 0, 0)


@pytest.mark.skipif(not HIVE.exists(), reason="needs target/release/hive (scripts/test builds it)")
def test_a_join_of_another_layout_is_refused_and_the_head_gives_up_in_time(tmp_path):
    """A join request of another build (another message layout) is refused
    with a reason that does not give the head's layout away, and a head
    whose worker never joins gives up when `cluster.join_timeout_s` ends."""
    zenoh = pytest.importorskip("zenoh")
    ep = f"tcp/127.0.0.1:{free_port()}"
    run_dir = tmp_path / "head"
    started = time.monotonic()
    head = subprocess.Popen(
        [str(HIVE), "--domain", "stranger-mismatch", "train", "configs/default.toml", "--listen", ep, "--run-dir", str(run_dir)]
        + ["--quiet", "--set", "sim.agents=8", "--set", "eval.every_s=0", "--set", "cluster.workers=1", "--set", "cluster.join_timeout_s=6"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", json.dumps([ep]))
        conf.insert_json5("listen/endpoints", "[]")
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("scouting/gossip/enabled", "false")
        answer = None
        with zenoh.open(conf) as session:
            # The head may not listen yet: ask until it answers.
            while answer is None and time.monotonic() - started < 20:
                for r in session.get("rotorhive/join", payload=hello(0x0123_4567_89AB_CDEF), timeout=1.0):
                    if r.ok is not None:
                        answer = r.ok.payload.to_bytes()
                time.sleep(0.2)
        h_out, h_err = head.communicate(timeout=60)
    finally:
        if head.poll() is None:
            head.kill()
    assert answer is not None, "the head never answered the join"
    # `RHW2`, 1 (refused), then the reason.
    assert answer[:8] == b"RHW2" + struct.pack("<I", 1), answer[:8]
    (n,) = struct.unpack("<I", answer[8:12])
    why = answer[12 : 12 + n].decode()
    assert "message layout mismatch" in why and "same build" in why, why
    assert not re.search(r"[0-9a-fA-F]{16}", why), why
    assert head.returncode != 0, h_err
    assert "only 0 of 1 worker hosts joined within 6 s" in h_err, h_err
    assert "panicked" not in h_err
    assert time.monotonic() - started < 30
