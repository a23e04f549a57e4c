#!/usr/bin/env python3
"""`hive bench learner` beside a JAX version of the same step (`--jax-script`, a peer's `bench_jax.py`),
in alternating rounds at 1 thread (pinned to core 0) and 2 threads; prints the
medians and their ratios.

    python3 -m venv /some/venv && /some/venv/bin/pip install "jax[cpu]" optax numpy
    scripts/learner_vs_jax.py --python /some/venv/bin/python --jax-script PATH/bench_jax.py [--rounds 3]
"""

import argparse
import json
import re
import statistics
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def hive(threads: int, binary: str) -> dict:
    pin = ["taskset", "-c", "0"] if threads == 1 else []
    out = subprocess.run(pin + [binary, "bench", "learner", "--threads", str(threads), "--json"], check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def jax(threads: int, python: str, script: Path) -> float:
    pin = ["taskset", "-c", "0"] if threads == 1 else []
    out = subprocess.run(pin + [python, str(script), str(threads)], check=True, capture_output=True, text=True).stdout
    m = re.search(r"TRAIN B=32 \(jit, block each step\): [0-9.]+ ms/step = ([0-9.]+) steps/s", out)
    if not m:
        raise SystemExit(f"bench_jax.py printed no TRAIN line:\n{out}")
    return float(m.group(1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--python", required=True, help="a Python with jax, optax and numpy")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--hive", default=str(ROOT / "target/release/hive"))
    ap.add_argument("--jax-script", required=True, help="the JAX peer benchmark (bench_jax.py)")
    a = ap.parse_args()
    rows = []
    for threads in (1, 2):
        ours, theirs, infer = [], [], []
        for r in range(a.rounds):
            theirs.append(jax(threads, a.python, Path(a.jax_script)))
            h = hive(threads, a.hive)
            ours.append(h["updates_per_s"])
            infer.append(h["infer_b50_ms"])
            print(f"threads {threads} round {r + 1}: JAX {theirs[-1]:.1f}, hive {ours[-1]:.1f} updates/s, batch-50 inference {infer[-1]:.3f} ms", flush=True)
        rows.append((threads, statistics.median(theirs), statistics.median(ours), statistics.median(infer)))
    print("\n| threads | JAX steps/s | hive updates/s | hive / JAX | hive batch-50 inference |")
    print("|---:|---:|---:|---:|---:|")
    for threads, j, h, i in rows:
        print(f"| {threads} | {j:.0f} | {h:.0f} | {h / j:.2f}x | {i:.2f} ms |")


if __name__ == "__main__":
    main()
