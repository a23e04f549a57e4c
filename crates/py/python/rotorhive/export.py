"""A `hive train` checkpoint as an ONNX model, for any runtime that reads
ONNX (onnxruntime, TensorRT, OpenVINO, a browser); the same file as
``hive export --checkpoint FILE --out FILE.onnx`` writes.

    python -m rotorhive.export --checkpoint runs/X/checkpoints/best.safetensors --out policy.onnx

The model has two inputs, ``depth`` ``(B, 2, 32, 32)`` (the previous and
the current normalised depth frame) and ``velocity`` ``(B, 3)`` (body
frame, m/s), and one output, ``q`` ``(B, 2)``: the Q-values of "left" and
"right"; the greedy action is their argmax. A checkpoint of a task with a
goal takes ``velocity`` ``(B, 6)`` (the velocity, then the goal's bearing,
distance and lateral offset) and, with the hold action, gives ``q``
``(B, 3)``. A recurrent network's (its checkpoint's header names a memory,
``gru:WIDTH``) is one step: it also takes ``state`` ``(B, WIDTH)`` and gives
``next_state``, zeros at an episode's start. Its metadata properties give
the checkpoint layout, the observation, the action count and the memory.
"""

from __future__ import annotations

import argparse
import os

from ._rotorhive import PolicyNetwork


def export_onnx(checkpoint: str | os.PathLike, out: str | os.PathLike) -> str:
    """Writes the checkpoint's network to ``out`` as ONNX; returns the path.
    A missing, truncated or mismatched checkpoint raises ValueError naming it."""
    path = os.fspath(checkpoint)
    # The checkpoint's header names its network (a memory: the recurrent one).
    PolicyNetwork.load(path).to_onnx(os.fspath(out))
    return os.fspath(out)


def main() -> None:
    p = argparse.ArgumentParser(prog="python -m rotorhive.export", description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", required=True, help="weights written by hive train (.safetensors)")
    p.add_argument("--out", required=True, help="the ONNX file to write")
    a = p.parse_args()
    try:
        path = export_onnx(a.checkpoint, a.out)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
