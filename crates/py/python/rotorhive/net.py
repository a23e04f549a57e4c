"""The paper's Q-network for Python users, and `hive train` checkpoints.

rotorhive's learner stores two weights in its own layout: ``conv2.weight``
as ``(32, 3, 3, 16)`` (kernel rows, columns, input channels) and the pooled
features that ``fc1`` reads channels-last (y, x, c). `torch_layout` turns a
checkpoint into PyTorch's layout (``Conv2d`` weights ``(out, in, kh, kw)``,
features flattened (c, y, x)); `numpy_q_values` is the network's forward pass
in numpy on those weights, and `torch_qnet` builds the same network in
PyTorch (when torch is installed) with a checkpoint loaded.

The network: depth (2, 32, 32) -> conv 6x6 stride 2 (16) -> ReLU -> conv 3x3
(32) -> ReLU -> max-pool 2x2 -> 1152 features; velocity (3) -> linear (16) ->
ReLU; both -> linear (64) -> ReLU -> linear (2 Q-values). A network of other
widths (``learner.conv_channels``, ``learner.hidden``: ``QNetwork(conv_channels=...,
hidden=...)``) has other channels and one to three hidden layers (``fc1``,
then ``fc1b``, ``fc1c``); `torch_layout` and `numpy_q_values` read the widths
from the weights' shapes (`torch_qnet` builds the design's network only).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ._rotorhive import QNetwork

FEATURES = 32 * 6 * 6


def torch_layout(weights: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """rotorhive's weights (`QNetwork.weights()`) in PyTorch's layout, keyed
    as `torch_qnet`'s ``state_dict``."""
    w = {k: np.asarray(v, np.float32) for k, v in weights.items()}
    out = dict(w)
    c1, frames = w["conv1.weight"].shape[0], w["conv1.weight"].shape[1] // 36
    c2 = w["conv2.weight"].shape[0]
    out["conv1.weight"] = w["conv1.weight"].reshape(c1, frames, 6, 6)
    out["conv2.weight"] = w["conv2.weight"].reshape(c2, 3, 3, c1).transpose(0, 3, 1, 2)
    fc1 = w["fc1.weight"]
    h, features = fc1.shape[0], c2 * 36
    pooled = fc1[:, :features].reshape(h, 6, 6, c2).transpose(0, 3, 1, 2).reshape(h, features)
    out["fc1.weight"] = np.concatenate([pooled, fc1[:, features:]], axis=1)
    return {k: np.ascontiguousarray(v) for k, v in out.items()}


def load_checkpoint(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A `hive train` checkpoint (``.safetensors``) in PyTorch's layout; a
    missing, truncated or mismatched file raises ValueError naming it."""
    return torch_layout(QNetwork.load(os.fspath(path)).weights())


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


def _conv(x: np.ndarray, w: np.ndarray, b: np.ndarray, stride: int) -> np.ndarray:
    k = w.shape[2]
    win = np.lib.stride_tricks.sliding_window_view(x, (k, k), axis=(2, 3))[:, :, ::stride, ::stride]
    return np.einsum("bcyxij,ocij->boyx", win, w, optimize=True) + b[None, :, None, None]


def numpy_q_values(w: dict[str, np.ndarray], depth: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Q-values ``(B, 2)`` of observations (depth ``(B, 2, 32, 32)``,
    velocity ``(B, 3)``) with weights in PyTorch's layout, in float64."""
    w = {k: v.astype(np.float64) for k, v in w.items()}
    x = _relu(_conv(np.asarray(depth, np.float64), w["conv1.weight"], w["conv1.bias"], 2))
    x = _relu(_conv(x, w["conv2.weight"], w["conv2.bias"], 1))
    b, c2 = x.shape[0], x.shape[1]
    x = x.reshape(b, c2, 6, 2, 6, 2).max(axis=(3, 5)).reshape(b, c2 * 36)
    v = _relu(np.asarray(velocity, np.float64) @ w["vel.weight"].T + w["vel.bias"])
    h = np.concatenate([x, v], axis=1)
    for layer in ("fc1", "fc1b", "fc1c"):
        if layer + ".weight" in w:
            h = _relu(h @ w[layer + ".weight"].T + w[layer + ".bias"])
    return h @ w["fc2.weight"].T + w["fc2.bias"]


def flat_observations(depth: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Observations as the Rust network reads them: ``(B, 2051)`` float32."""
    b = depth.shape[0]
    return np.ascontiguousarray(np.concatenate([depth.reshape(b, -1), velocity.reshape(b, 3)], axis=1), dtype=np.float32)


def torch_qnet(checkpoint: str | os.PathLike | None = None) -> Any:
    """The Q-network as a ``torch.nn.Module`` (``forward(depth, velocity)``),
    with a checkpoint's weights when one is given. Needs torch."""
    import torch
    from torch import nn

    class QNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.conv1 = nn.Conv2d(2, 16, 6, stride=2)
            self.conv2 = nn.Conv2d(16, 32, 3)
            self.vel = nn.Linear(3, 16)
            self.fc1 = nn.Linear(FEATURES + 16, 64)
            self.fc2 = nn.Linear(64, 2)

        def forward(self, depth: "torch.Tensor", velocity: "torch.Tensor") -> "torch.Tensor":
            x = torch.relu(self.conv2(torch.relu(self.conv1(depth))))
            x = torch.nn.functional.max_pool2d(x, 2).flatten(1)
            v = torch.relu(self.vel(velocity))
            return self.fc2(torch.relu(self.fc1(torch.cat([x, v], dim=1))))

    net = QNet()
    if checkpoint is not None:
        net.load_state_dict({k: torch.from_numpy(v) for k, v in load_checkpoint(checkpoint).items()})
    return net
