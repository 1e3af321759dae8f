"""Updates per second of tarl.SAC.update against a plain SAC update, side by side.

The plain reference is written here in the usual textbook / CleanRL form: separate critic modules, separate
standard (for-loop) Adam optimizers for critics, policy and temperature, the critic step before the policy
step, a fresh policy sample for the temperature, and a per-parameter Python soft-update loop.
Sizes are the paper's (Table 2): batch 256, two hidden layers of 256, obs 67 (+1 for the timing taker).

Run:  python bench/sac_speed.py [--threads N] [--rounds R] [--updates K]
The machine is a shared VM whose speed drifts: the variants run in alternating blocks of K updates and the
report gives the median rate over R rounds and the median of the per-round (paired) ratios.
"""
from __future__ import annotations

import argparse
import copy
import math
import statistics
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tarl import SAC, SACConfig, mlp  # noqa: E402

OBS_DIM, T_MAX, LOW, HIGH = 67, 10, -3.0, 2.0


class PlainSAC:
    """Plain SAC update for reference: continuous (act_dim) or discrete (n_actions, choices 1..n)."""

    def __init__(self, obs_dim, act_dim=None, n_actions=None, cfg=SACConfig(), target_entropy=None):
        self.cfg, self.discrete = cfg, n_actions is not None
        out = n_actions if self.discrete else 2 * act_dim
        q_in, q_out = (obs_dim, n_actions) if self.discrete else (obs_dim + act_dim, 1)
        self.actor = mlp(obs_dim, out, cfg.hidden)
        self.qf1, self.qf2 = mlp(q_in, q_out, cfg.hidden), mlp(q_in, q_out, cfg.hidden)
        self.qf1_target, self.qf2_target = copy.deepcopy(self.qf1), copy.deepcopy(self.qf2)
        self.q_optimizer = torch.optim.Adam([*self.qf1.parameters(), *self.qf2.parameters()], lr=cfg.lr)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=cfg.lr)
        self.log_alpha = torch.zeros(1, requires_grad=True)
        self.a_optimizer = torch.optim.Adam([self.log_alpha], lr=cfg.lr)
        self.alpha = 1.0
        self.target_entropy = target_entropy if target_entropy is not None else -float(act_dim)
        self.scale, self.bias = (HIGH - LOW) / 2, (HIGH + LOW) / 2

    def get_action(self, obs):
        mean, log_std = self.actor(obs).chunk(2, -1)
        std = log_std.clamp(-20, 2).exp()
        normal = torch.distributions.Normal(mean, std)
        x = normal.rsample()
        y = torch.tanh(x)
        log_prob = normal.log_prob(x) - torch.log(self.scale * (1 - y.pow(2)) + 1e-6)
        return y * self.scale + self.bias, log_prob.sum(1)

    def get_probs(self, obs):
        logits = self.actor(obs)
        return F.softmax(logits, -1), F.log_softmax(logits, -1)

    def update(self, b):
        if self.discrete:
            return self._update_discrete(b)
        with torch.no_grad():
            next_a, next_logp = self.get_action(b["next_obs"])
            x = torch.cat([b["next_obs"], next_a], 1)
            min_q = torch.min(self.qf1_target(x), self.qf2_target(x)).view(-1) - self.alpha * next_logp
            y = b["rew"] + b["discount"] * (1 - b["done"]) * min_q
        x = torch.cat([b["obs"], b["act"]], 1)
        qf_loss = F.mse_loss(self.qf1(x).view(-1), y) + F.mse_loss(self.qf2(x).view(-1), y)
        self.q_optimizer.zero_grad()
        qf_loss.backward()
        self.q_optimizer.step()

        pi, logp = self.get_action(b["obs"])
        x = torch.cat([b["obs"], pi], 1)
        actor_loss = (self.alpha * logp - torch.min(self.qf1(x), self.qf2(x)).view(-1)).mean()
        self.actor_optimizer.zero_grad()
        actor_loss.backward()
        self.actor_optimizer.step()

        with torch.no_grad():
            _, logp = self.get_action(b["obs"])
        alpha_loss = (-self.log_alpha.exp() * (logp + self.target_entropy)).mean()
        self.a_optimizer.zero_grad()
        alpha_loss.backward()
        self.a_optimizer.step()
        self.alpha = self.log_alpha.exp().item()
        self._soft_update()
        return qf_loss.item(), actor_loss.item(), alpha_loss.item()

    def _update_discrete(self, b):
        with torch.no_grad():
            probs, logp = self.get_probs(b["next_obs"])
            min_q = torch.min(self.qf1_target(b["next_obs"]), self.qf2_target(b["next_obs"]))
            v = (probs * (min_q - self.alpha * logp)).sum(1)
            y = b["rew"] + b["discount"] * (1 - b["done"]) * v
        idx = (b["act"] - 1).view(-1, 1)
        q1, q2 = self.qf1(b["obs"]).gather(1, idx).view(-1), self.qf2(b["obs"]).gather(1, idx).view(-1)
        qf_loss = F.mse_loss(q1, y) + F.mse_loss(q2, y)
        self.q_optimizer.zero_grad()
        qf_loss.backward()
        self.q_optimizer.step()

        probs, logp = self.get_probs(b["obs"])
        with torch.no_grad():
            min_q = torch.min(self.qf1(b["obs"]), self.qf2(b["obs"]))
        actor_loss = (probs * (self.alpha * logp - min_q)).sum(1).mean()
        self.actor_optimizer.zero_grad()
        actor_loss.backward()
        self.actor_optimizer.step()

        probs, logp = probs.detach(), logp.detach()
        alpha_loss = (probs * (-self.log_alpha.exp() * (logp + self.target_entropy))).sum(1).mean()
        self.a_optimizer.zero_grad()
        alpha_loss.backward()
        self.a_optimizer.step()
        self.alpha = self.log_alpha.exp().item()
        self._soft_update()
        return qf_loss.item(), actor_loss.item(), alpha_loss.item()

    def _soft_update(self):
        for net, target in ((self.qf1, self.qf1_target), (self.qf2, self.qf2_target)):
            for p, tp in zip(net.parameters(), target.parameters()):
                tp.data.copy_(self.cfg.tau * p.data + (1 - self.cfg.tau) * tp.data)


def random_batches(n, obs_dim, discrete, batch_size=256, seed=0):
    g = torch.Generator().manual_seed(seed)
    out = []
    for _ in range(n):
        if discrete:
            act = torch.randint(1, T_MAX + 1, (batch_size,), generator=g)
            discount = 0.99 ** act.float()
        else:
            act = torch.rand(batch_size, 1, generator=g) * (HIGH - LOW) + LOW
            discount = torch.full((batch_size,), 0.99)
        out.append({"obs": torch.randn(batch_size, obs_dim, generator=g), "act": act,
                    "rew": torch.randn(batch_size, generator=g),
                    "next_obs": torch.randn(batch_size, obs_dim, generator=g),
                    "discount": discount, "done": (torch.rand(batch_size, generator=g) < 0.05).float()})
    return out


def rate(update, batches, k):
    start = time.perf_counter()
    for i in range(k):
        update(batches[i % len(batches)])
    return k / (time.perf_counter() - start)


def compare(name, fast, plain, batches, rounds, k):
    for _ in range(30):  # warm-up
        fast.update(batches[0])
        plain.update(batches[0])
    fast_rates, plain_rates = [], []
    for r in range(rounds):
        order = [(fast, fast_rates), (plain, plain_rates)]
        for agent, rates in order if r % 2 == 0 else order[::-1]:
            rates.append(rate(agent.update, batches, k))
    ratios = [f / p for f, p in zip(fast_rates, plain_rates)]
    med = statistics.median
    print(f"{name:<12} tarl.SAC {med(fast_rates):6.1f} upd/s (best {max(fast_rates):6.1f})   "
          f"plain {med(plain_rates):6.1f} upd/s (best {max(plain_rates):6.1f})   "
          f"ratio {med(ratios):.2f}x (paired median; min {min(ratios):.2f}, max {max(ratios):.2f})")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (the machine has 2 cores)")
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--updates", type=int, default=100, help="updates per timed block")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, batch 256, hidden 256, obs {OBS_DIM}; "
          f"load average before: {Path('/proc/loadavg').read_text().split()[0]} (other processes share the cores)")
    cfg = SACConfig()
    compare("continuous", SAC(OBS_DIM, act_dim=1, low=LOW, high=HIGH, cfg=cfg),
            PlainSAC(OBS_DIM, act_dim=1, cfg=cfg),
            random_batches(8, OBS_DIM, False), args.rounds, args.updates)
    target_entropy = cfg.target_entropy_fraction * math.log(T_MAX)
    compare("discrete", SAC(OBS_DIM + 1, n_actions=T_MAX, cfg=cfg),
            PlainSAC(OBS_DIM + 1, n_actions=T_MAX, cfg=cfg, target_entropy=target_entropy),
            random_batches(8, OBS_DIM + 1, True), args.rounds, args.updates)


if __name__ == "__main__":
    main()
