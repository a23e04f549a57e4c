"""A short DQN in PyTorch on rotorhive/Navigate-v0 (needs torch; not run in CI).

    pip install ./crates/py torch
    python examples/dqn_torch.py --agents 50 --steps 200000

The network is the paper's (`rotorhive.net.torch_qnet`); with --init a
`hive train` checkpoint is loaded into it first. Timeouts are truncations:
the TD target bootstraps from the ended episode's last observation
(`SAME_STEP` mode gives it in ``infos["final_obs"]``); collisions and goals
are terminal.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F

import rotorhive  # noqa: F401  (registers the environments)
from rotorhive.net import torch_qnet


class Replay:
    def __init__(self, capacity: int, side: int = 32) -> None:
        self.depth = np.zeros((capacity, 2, side, side), np.float32)
        self.vel = np.zeros((capacity, 3), np.float32)
        self.next_depth = np.zeros_like(self.depth)
        self.next_vel = np.zeros_like(self.vel)
        self.action = np.zeros(capacity, np.int64)
        self.reward = np.zeros(capacity, np.float32)
        self.terminal = np.zeros(capacity, np.float32)
        self.capacity, self.size, self.at = capacity, 0, 0

    def add(self, obs, actions, rewards, next_obs, terminal) -> None:
        for i in range(len(actions)):
            j = self.at
            self.depth[j], self.vel[j] = obs["depth"][i], obs["velocity"][i]
            self.next_depth[j], self.next_vel[j] = next_obs["depth"][i], next_obs["velocity"][i]
            self.action[j], self.reward[j], self.terminal[j] = actions[i], rewards[i], terminal[i]
            self.at = (j + 1) % self.capacity
            self.size = min(self.size + 1, self.capacity)

    def sample(self, batch: int, rng: np.random.Generator, device: torch.device):
        k = rng.integers(0, self.size, batch)
        t = lambda a: torch.from_numpy(a[k]).to(device)  # noqa: E731
        return t(self.depth), t(self.vel), t(self.action), t(self.reward), t(self.next_depth), t(self.next_vel), t(self.terminal)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--agents", type=int, default=50)
    p.add_argument("--steps", type=int, default=200_000, help="agent-steps")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--init", help="a hive train checkpoint to start from")
    p.add_argument("--save", default="dqn_torch.pt")
    a = p.parse_args()

    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    envs = gym.make_vec("rotorhive/Navigate-v0", num_envs=a.agents, seed=a.seed, autoreset_mode="SameStep")
    online = torch_qnet(a.init).to(device)
    target = torch_qnet().to(device)
    target.load_state_dict(online.state_dict())
    opt = torch.optim.Adam(online.parameters(), lr=2.5e-4)
    replay = Replay(100_000)
    gamma, batch, eps_steps = 0.99, 32, a.steps // 3

    obs, _ = envs.reset(seed=a.seed)
    returns: list[float] = []
    successes: list[bool] = []
    t0 = time.time()
    updates = 0
    for step in range(0, a.steps, a.agents):
        eps = max(0.05, 1.0 - step / eps_steps)
        with torch.no_grad():
            q = online(torch.from_numpy(obs["depth"]).to(device), torch.from_numpy(obs["velocity"]).to(device))
        actions = q.argmax(1).cpu().numpy()
        explore = rng.random(a.agents) < eps
        actions[explore] = rng.integers(0, 2, explore.sum())
        next_obs, rewards, term, trunc, infos = envs.step(actions)
        # The transition's next observation: the ended episode's last one.
        stored_next = {k: v.copy() for k, v in next_obs.items()}
        for i in np.flatnonzero(term | trunc):
            for k in stored_next:
                stored_next[k][i] = infos["final_obs"][i][k]
            returns.append(float(infos["episode_return"][i]))
            successes.append(bool(infos["success"][i]))
        replay.add(obs, actions, rewards, stored_next, term.astype(np.float32))
        obs = next_obs
        if replay.size < 2_000:
            continue
        for _ in range(max(1, a.agents // 8)):
            d, v, act, r, nd, nv, terminal = replay.sample(batch, rng, device)
            with torch.no_grad():
                best = online(nd, nv).argmax(1, keepdim=True)
                y = r + gamma * (1 - terminal) * target(nd, nv).gather(1, best).squeeze(1)
            loss = F.smooth_l1_loss(online(d, v).gather(1, act[:, None]).squeeze(1), y)
            opt.zero_grad()
            loss.backward()
            opt.step()
            updates += 1
            if updates % 1000 == 0:
                target.load_state_dict(online.state_dict())
        if returns and step % (50 * a.agents) == 0:
            print(
                f"{step:>8} agent-steps  {time.time() - t0:6.1f} s  eps {eps:.2f}  "
                f"mean return (last 50) {np.mean(returns[-50:]):7.1f}  success {np.mean(successes[-50:]):.0%}"
            )
    torch.save(online.state_dict(), a.save)
    print(f"saved {a.save}")


if __name__ == "__main__":
    main()
