"""rotorhive's policy network for Python users, and `hive train` checkpoints.

`PolicyNetwork` is the Rust network itself (feedforward, or with
``memory`` a GRU whose state the caller carries): ``load``, ``save``,
``q_values``, ``step``, ``to_onnx``, ``weights``. ``QNetwork`` and
``RecurrentQNetwork`` are its names from before, kept: ``QNetwork`` the
feedforward one, ``RecurrentQNetwork(width, ...)`` the one with memory.

rotorhive's learner stores two weights in its own layout: ``conv2.weight``
as ``(c2, 3, 3, c1)`` (kernel rows, columns, input channels) and the pooled
features that ``fc1`` reads channels-last (y, x, c). `torch_layout` turns a
feedforward checkpoint's weights into PyTorch's layout (``Conv2d`` weights
``(out, in, kh, kw)``, features flattened (c, y, x)); `numpy_q_values` is
the network's forward pass in numpy on those weights, and `torch_qnet`
builds the same network in PyTorch (when torch is installed) with a
checkpoint loaded.

The design's network: depth (2, 32, 32) -> conv 6x6 stride 2 (16) -> ReLU
-> conv 3x3 (32) -> ReLU -> max-pool 2x2 -> 1152 features; velocity (3) ->
linear (16) -> ReLU; both -> linear (64) -> ReLU -> linear (2 Q-values).
Every size but the kernels (the frames, the channels, the one to three
hidden layers ``fc1``, ``fc1b``, ``fc1c``, the scalars, the actions, the
pooled grid) is read from the weights' shapes (`geometry`), so a network
of other widths, another task or another camera converts the same way.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._rotorhive import PolicyNetwork

# The kernels are the architecture's, not the checkpoint's.
K1, S1, K2 = 6, 2, 3
# The design's pooled features (32 channels on a 6 x 6 grid).
FEATURES = 32 * 6 * 6


class QNetwork(PolicyNetwork):
    """The feedforward network under its name from before: `PolicyNetwork`
    without memory (`load` refuses a checkpoint with one, by name)."""

    @staticmethod
    def load(path: str | os.PathLike) -> PolicyNetwork:
        net = PolicyNetwork.load(path)
        if net.memory is not None:
            raise ValueError(f"checkpoint {os.fspath(path)}: a network with memory gru:{net.memory}: load it with PolicyNetwork.load or RecurrentQNetwork.load")
        return net


class RecurrentQNetwork(PolicyNetwork):
    """The network with memory under its name from before: `PolicyNetwork`
    with a GRU of ``width`` units (`load` refuses a feedforward checkpoint,
    by name)."""

    def __new__(cls, width: int = 64, seed: int = 0, **kwargs: Any) -> RecurrentQNetwork:
        return super().__new__(cls, seed=seed, memory=width, **kwargs)

    @staticmethod
    def load(path: str | os.PathLike) -> PolicyNetwork:
        net = PolicyNetwork.load(path)
        if net.memory is None:
            raise ValueError(f"checkpoint {os.fspath(path)}: a feedforward network's (memory none): load it with PolicyNetwork.load or QNetwork.load")
        return net


@dataclass(frozen=True)
class Geometry:
    """A feedforward network's sizes, as its weights give them."""

    frames: int
    channels: tuple[int, int]
    pooled: tuple[int, int]
    scalars: int
    vel_width: int
    hidden: tuple[int, ...]
    actions: int

    @property
    def features(self) -> int:
        """Pooled features that ``fc1`` reads before the velocity's."""
        return self.channels[1] * self.pooled[0] * self.pooled[1]


def pooled_grid(depth: tuple[int, int]) -> tuple[int, int]:
    """The pooled map's rows and columns on depth frames of ``depth`` (rows,
    columns): conv 6x6 stride 2, conv 3x3 and a 2x2 max-pool, each rounding
    down (``(6, 6)`` on 32 x 32)."""
    return tuple(((d - K1) // S1 + 1 - K2 + 1) // 2 for d in depth)  # type: ignore[return-value]


def geometry(weights: dict[str, np.ndarray], pooled: tuple[int, int] | None = None) -> Geometry:
    """The sizes of a feedforward network's weights (rotorhive's layout, as
    `PolicyNetwork.weights()` gives them). The pooled grid is taken square
    unless ``pooled`` (rows, columns) says otherwise; weights that fit no
    such network raise ValueError naming what does not fit."""
    if "gru.weight_ih" in weights:
        raise ValueError("a network with memory: torch_layout and numpy_q_values take a feedforward network's weights")
    c1, per = weights["conv1.weight"].shape
    if per % (K1 * K1):
        raise ValueError(f"conv1.weight has {per} columns: not frames x {K1} x {K1}")
    c2 = weights["conv2.weight"].shape[0]
    vel_width, scalars = weights["vel.weight"].shape
    cells, rem = divmod(weights["fc1.weight"].shape[1] - vel_width, c2)
    if pooled is None:
        side = math.isqrt(max(cells, 0))
        pooled = (side, side)
    if rem or pooled[0] * pooled[1] != cells or cells <= 0:
        raise ValueError(f"fc1.weight reads {weights['fc1.weight'].shape[1]} features: not {c2} channels on a {pooled[0]} x {pooled[1]} grid and {vel_width} of the velocity")
    hidden = tuple(weights[f"{k}.weight"].shape[0] for k in ("fc1", "fc1b", "fc1c") if f"{k}.weight" in weights)
    return Geometry(per // (K1 * K1), (c1, c2), pooled, scalars, vel_width, hidden, weights["fc2.weight"].shape[0])


def torch_layout(weights: dict[str, np.ndarray], pooled: tuple[int, int] | None = None) -> dict[str, np.ndarray]:
    """rotorhive's weights (`PolicyNetwork.weights()`) in PyTorch's layout,
    keyed as `torch_qnet`'s ``state_dict``."""
    w = {k: np.asarray(v, np.float32) for k, v in weights.items()}
    g = geometry(w, pooled)
    (c1, c2), (ph, pw) = g.channels, g.pooled
    out = dict(w)
    out["conv1.weight"] = w["conv1.weight"].reshape(c1, g.frames, K1, K1)
    out["conv2.weight"] = w["conv2.weight"].reshape(c2, K2, K2, c1).transpose(0, 3, 1, 2)
    fc1 = w["fc1.weight"]
    h = fc1.shape[0]
    grid = fc1[:, : g.features].reshape(h, ph, pw, c2).transpose(0, 3, 1, 2).reshape(h, g.features)
    out["fc1.weight"] = np.concatenate([grid, fc1[:, g.features :]], axis=1)
    return {k: np.ascontiguousarray(v) for k, v in out.items()}


def load_checkpoint(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A feedforward `hive train` checkpoint (``.safetensors``) in PyTorch's
    layout; a missing, truncated or mismatched file raises ValueError
    naming it."""
    net = QNetwork.load(os.fspath(path))
    return torch_layout(net.weights(), pooled_grid(net.depth))


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


def _conv(x: np.ndarray, w: np.ndarray, b: np.ndarray, stride: int) -> np.ndarray:
    k = w.shape[2]
    win = np.lib.stride_tricks.sliding_window_view(x, (k, k), axis=(2, 3))[:, :, ::stride, ::stride]
    return np.einsum("bcyxij,ocij->boyx", win, w, optimize=True) + b[None, :, None, None]


def numpy_q_values(w: dict[str, np.ndarray], depth: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Q-values ``(B, actions)`` of observations (depth ``(B, frames, H,
    W)``, the scalars ``(B, scalars)``) with weights in PyTorch's layout, in
    float64; the pooled grid follows from the depth's size."""
    w = {k: v.astype(np.float64) for k, v in w.items()}
    x = _relu(_conv(np.asarray(depth, np.float64), w["conv1.weight"], w["conv1.bias"], S1))
    x = _relu(_conv(x, w["conv2.weight"], w["conv2.bias"], 1))
    b, c2, hh, ww = x.shape
    x = x[:, :, : hh // 2 * 2, : ww // 2 * 2].reshape(b, c2, hh // 2, 2, ww // 2, 2).max(axis=(3, 5)).reshape(b, -1)
    v = _relu(np.asarray(velocity, np.float64) @ w["vel.weight"].T + w["vel.bias"])
    h = np.concatenate([x, v], axis=1)
    for layer in ("fc1", "fc1b", "fc1c"):
        if layer + ".weight" in w:
            h = _relu(h @ w[layer + ".weight"].T + w[layer + ".bias"])
    return h @ w["fc2.weight"].T + w["fc2.bias"]


def flat_observations(depth: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Observations as the Rust network reads them: ``(B, frames x H x W +
    scalars)`` float32 (``(B, 2051)`` for the paper's task)."""
    b = depth.shape[0]
    return np.ascontiguousarray(np.concatenate([depth.reshape(b, -1), velocity.reshape(b, -1)], axis=1), dtype=np.float32)


def torch_qnet(checkpoint: str | os.PathLike | None = None) -> Any:
    """The Q-network as a ``torch.nn.Module`` (``forward(depth, velocity)``),
    of a feedforward checkpoint's sizes with its weights when one is given
    (else the design's, freshly initialised). Needs torch."""
    import torch
    from torch import nn

    source = QNetwork() if checkpoint is None else QNetwork.load(os.fspath(checkpoint))
    raw = source.weights()
    g = geometry(raw, pooled_grid(source.depth))

    class QNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            (c1, c2), widths = g.channels, (g.features + g.vel_width, *g.hidden)
            self.conv1 = nn.Conv2d(g.frames, c1, K1, stride=S1)
            self.conv2 = nn.Conv2d(c1, c2, K2)
            self.vel = nn.Linear(g.scalars, g.vel_width)
            names = ("fc1", "fc1b", "fc1c")[: len(g.hidden)]
            self.hidden_names = names
            for name, n_in, n_out in zip(names, widths, widths[1:]):
                setattr(self, name, nn.Linear(n_in, n_out))
            self.fc2 = nn.Linear(widths[-1], g.actions)

        def forward(self, depth: "torch.Tensor", velocity: "torch.Tensor") -> "torch.Tensor":
            x = torch.relu(self.conv2(torch.relu(self.conv1(depth))))
            x = torch.nn.functional.max_pool2d(x, 2).flatten(1)
            h = torch.cat([x, torch.relu(self.vel(velocity))], dim=1)
            for name in self.hidden_names:
                h = torch.relu(getattr(self, name)(h))
            return self.fc2(h)

    net = QNet()
    if checkpoint is not None:
        net.load_state_dict({k: torch.from_numpy(v) for k, v in torch_layout(raw, g.pooled).items()})
    return net

