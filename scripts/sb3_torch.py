#!/usr/bin/env python3
"""Stable-Baselines3 and PyTorch against rotorhive, for real (not in CI: the
only Linux torch the registry offers is the CUDA build, a 5.4 GB
environment). In a virtual environment with the package, torch and SB3:

    python3 -m venv /tmp/torchenv && /tmp/torchenv/bin/pip install ./crates/py torch stable-baselines3
    /tmp/torchenv/bin/python scripts/sb3_torch.py [--steps 4000]

1. SB3's DQN learns for `--steps` steps on `rotorhive.sb3.Sb3VecEnv` with a
   features extractor sized for 32 x 32 depth (the paper's convolutions),
   and its policy flies greedily afterwards;
2. `rotorhive.net.torch_qnet` gives the Rust network's Q-values on recorded
   observations (max |dQ| <= 1e-4);
3. `examples/dqn_torch.py` runs for a few thousand agent-steps.
Prints one JSON line at the end; exits non-zero if a check fails.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3 import DQN
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

import rotorhive
from rotorhive.net import flat_observations, torch_qnet
from rotorhive.sb3 import Sb3VecEnv

ROOT = Path(__file__).resolve().parents[1]


class DepthExtractor(BaseFeaturesExtractor):
    """The paper's convolutions for 32 x 32 depth, and the velocity branch."""

    def __init__(self, observation_space: spaces.Dict) -> None:
        super().__init__(observation_space, features_dim=32 * 6 * 6 + 16)
        self.conv = torch.nn.Sequential(
            torch.nn.Conv2d(2, 16, 6, stride=2), torch.nn.ReLU(), torch.nn.Conv2d(16, 32, 3), torch.nn.ReLU(), torch.nn.MaxPool2d(2), torch.nn.Flatten()
        )
        self.vel = torch.nn.Sequential(torch.nn.Linear(3, 16), torch.nn.ReLU())

    def forward(self, obs):
        return torch.cat([self.conv(obs["depth"]), self.vel(obs["velocity"])], dim=1)


def sb3(steps: int) -> dict:
    env = Sb3VecEnv(num_envs=16, seed=1)
    model = DQN(
        "MultiInputPolicy",
        env,
        policy_kwargs={"features_extractor_class": DepthExtractor, "net_arch": [64]},
        learning_starts=1000,
        buffer_size=20_000,
        train_freq=1,
        gradient_steps=1,
        target_update_interval=500,
        exploration_fraction=0.5,
        seed=1,
        verbose=0,
    )
    t = time.perf_counter()
    model.learn(total_timesteps=steps)
    learn_s = time.perf_counter() - t
    obs = env.reset()
    rewards = np.zeros(16)
    for _ in range(30):
        actions, _ = model.predict(obs, deterministic=True)
        obs, r, _, _ = env.step(actions)
        rewards += r
    return {"steps": steps, "learn_s": learn_s, "steps_per_s": steps / learn_s, "greedy_30_step_return_mean": float(rewards.mean())}


def torch_matches_rust() -> float:
    with tempfile.TemporaryDirectory() as d:
        ckpt = str(Path(d) / "w.safetensors")
        rotorhive.QNetwork(seed=7).save(ckpt)
        env = rotorhive.NavigateVectorEnv(25, seed=3)
        obs, _ = env.reset(seed=3)
        depth, vel = [obs["depth"]], [obs["velocity"]]
        for t in range(3):
            obs, *_ = env.step(np.arange(25) % 2 if t % 2 else 1 - np.arange(25) % 2)
            depth.append(obs["depth"])
            vel.append(obs["velocity"])
        depth, vel = np.concatenate(depth), np.concatenate(vel)
        want = rotorhive.QNetwork.load(ckpt).q_values(flat_observations(depth, vel))
        with torch.no_grad():
            got = torch_qnet(ckpt)(torch.from_numpy(depth), torch.from_numpy(vel)).numpy()
        return float(np.abs(got - want).max())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=4000, help="SB3 DQN steps (each steps all 16 drones)")
    a = p.parse_args()
    torch.set_num_threads(2)
    out = {"torch": torch.__version__}
    out["sb3"] = sb3(a.steps)
    print("SB3 DQN:", out["sb3"])
    out["torch_vs_rust_max_abs_dq"] = torch_matches_rust()
    print("torch_qnet against the Rust network: max |dQ| =", out["torch_vs_rust_max_abs_dq"])
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        ex = subprocess.run([sys.executable, str(ROOT / "examples/dqn_torch.py"), "--agents", "50", "--steps", "5000", "--save", str(Path(d) / "x.pt")], capture_output=True, text=True)
    out["example"] = {"returncode": ex.returncode, "seconds": time.perf_counter() - t, "tail": ex.stdout.strip().splitlines()[-1:] if ex.stdout else ex.stderr[-300:]}
    print("examples/dqn_torch.py:", out["example"])
    print(json.dumps(out))
    ok = out["torch_vs_rust_max_abs_dq"] <= 1e-4 and ex.returncode == 0
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
