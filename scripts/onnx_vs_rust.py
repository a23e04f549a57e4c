#!/usr/bin/env python3
"""Batch-50 inference of the exported ONNX policy in onnxruntime beside the
Rust network's (`hive bench learner`), in one run, alternated.

    .venv/bin/python scripts/onnx_vs_rust.py [--rounds 3] [--threads 1]

Needs the Python package (`pip install ./crates/py`), onnx, onnxruntime and
target/release/hive.
"""

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def ort_batch50_us(path, threads, reps=400):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    sess = ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    feed = {"depth": rng.random((50, 2, 32, 32), np.float32), "velocity": rng.standard_normal((50, 3)).astype(np.float32)}
    for _ in range(20):
        sess.run(["q"], feed)
    t = time.perf_counter()
    for _ in range(reps):
        sess.run(["q"], feed)
    return (time.perf_counter() - t) / reps * 1e6


def rust_batch50_us(threads):
    out = subprocess.run([str(ROOT / "target/release/hive"), "bench", "learner", "--threads", str(threads), "--updates", "20", "--json"], capture_output=True, text=True, check=True, cwd=ROOT)
    j = json.loads(out.stdout.strip().splitlines()[-1])
    return j


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    a = p.parse_args()
    import rotorhive
    from rotorhive.export import export_onnx

    with tempfile.TemporaryDirectory() as d:
        ckpt = Path(d) / "w.safetensors"
        rotorhive.QNetwork(seed=1).save(str(ckpt))
        onnx_path = export_onnx(ckpt, Path(d) / "policy.onnx")
        rows = []
        for r in range(a.rounds):
            rust = rust_batch50_us(a.threads)
            ort_us = ort_batch50_us(onnx_path, a.threads)
            rows.append({"round": r, "rust": rust, "onnxruntime_batch50_us": ort_us})
            print(f"round {r}: onnxruntime batch 50 {ort_us:.0f} µs; hive bench learner: {json.dumps({k: v for k, v in rust.items() if 'infer' in k})}")
    print(json.dumps({"bench": "onnx_vs_rust", "threads": a.threads, "rounds": rows}))


if __name__ == "__main__":
    main()
