"""Agent-steps per second through the Python API, beside the Rust `VecEnv`
and beside Gymnasium's `SyncVectorEnv` of single-drone environments, in the
same run (rounds alternate; the medians are reported).

    python -m rotorhive.bench [--agents 1,8,50] [--seconds 2] [--rounds 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import gymnasium as gym
import numpy as np

from . import _rotorhive
from .envs import NavigateEnv, NavigateVectorEnv


def _time_env(env, n: int, seconds: float, actions: np.ndarray) -> float:
    env.reset(seed=1)
    steps = 0
    t0 = time.perf_counter()
    while steps == 0 or time.perf_counter() - t0 < seconds:
        env.step(actions[steps % 64])
        steps += 1
    return steps * n / (time.perf_counter() - t0)


def bench(agents=(1, 8, 50), seconds: float = 2.0, rounds: int = 3, sync: bool = True) -> list[dict]:
    """One row per agent count: median agent-steps/s of the Rust `VecEnv`
    (the same actions, the same autoreset mode, observations written as the
    Python environment writes them), of `rotorhive/Navigate-v0` (default
    settings: copies, NEXT_STEP) and of a `SyncVectorEnv` of `NavigateEnv`s,
    and the ratios."""
    rng = np.random.default_rng(0)
    rows = []
    for n in agents:
        vec = NavigateVectorEnv(n)
        single = gym.vector.SyncVectorEnv([NavigateEnv for _ in range(n)]) if sync else None
        rust, py, sv = [], [], []
        # All three fly the same rows of random actions, in turn.
        actions = rng.integers(0, 2, size=(64, n)).astype(np.uint8)
        for _ in range(rounds):
            rust.append(_rotorhive.rust_agent_steps_per_second(n, seconds, actions=actions))
            py.append(_time_env(vec, n, seconds, actions))
            if single is not None:
                sv.append(_time_env(single, n, seconds, actions))
        row = {"agents": n, "rust_vecenv": statistics.median(rust), "python_vector_env": statistics.median(py)}
        row["python_over_rust"] = row["python_vector_env"] / row["rust_vecenv"]
        if single is not None:
            row["sync_vector_env"] = statistics.median(sv)
            row["python_over_sync"] = row["python_vector_env"] / row["sync_vector_env"]
            single.close()
        vec.close()
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m rotorhive.bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--agents", default="1,8,50", help="comma-separated agent counts")
    p.add_argument("--seconds", type=float, default=2.0, help="seconds per measurement")
    p.add_argument("--rounds", type=int, default=3, help="alternating rounds (the median is reported)")
    p.add_argument("--no-sync", action="store_true", help="skip the SyncVectorEnv baseline")
    p.add_argument("--json", action="store_true", help="one JSON line")
    a = p.parse_args(argv)
    try:
        agents = [int(x) for x in a.agents.split(",")]
    except ValueError:
        p.error(f"--agents must be comma-separated integers, got {a.agents!r}")
    if any(n < 1 for n in agents) or a.seconds <= 0 or a.rounds < 1:
        p.error("--agents, --seconds and --rounds must be positive")
    rows = bench(agents, a.seconds, a.rounds, not a.no_sync)
    if a.json:
        print(json.dumps({"bench": "python", "seconds": a.seconds, "rounds": a.rounds, "rows": rows}))
        return
    print("agent-steps/s (median of alternating rounds)")
    print(f"{'agents':>6} {'Rust VecEnv':>12} {'Navigate-v0':>12} {'py/rust':>8} {'SyncVectorEnv':>14} {'py/sync':>8}")
    for r in rows:
        sv = f"{r['sync_vector_env']:14.0f} {r['python_over_sync']:7.1f}x" if "sync_vector_env" in r else f"{'-':>14} {'-':>8}"
        print(f"{r['agents']:>6} {r['rust_vecenv']:12.0f} {r['python_vector_env']:12.0f} {r['python_over_rust']:7.0%} {sv}")


if __name__ == "__main__":
    main()
