"""A plain SAC, the reference for tarl.SAC: tests/test_sac.py checks tarl.SAC's losses and updates against it, and
bench/speed.py times tarl.SAC.update against its update.

It is written the usual way: two separate critic modules and their two target copies, a standard Adam per
part (critics, policy, temperature), the critic step before the policy step and a per-parameter soft-update
loop; continuous (the actor: a squashed Gaussian in [low, high]) or discrete (the timing taker: choices
1..n_actions). The losses are those of tarl.SAC and of Haarnoja et al.'s code: all three at the parameters
before the step (the policy's at the critics before their step, as in tarl.SAC.losses; Spinning Up and CleanRL
take it after), and the temperature's on log alpha. So one update here equals one tarl.SAC.update.

    plain = PlainSAC(obs_dim, act_dim=1, low=-3.0, high=2.0)    # the actor's head
    plain = PlainSAC(obs_dim, n_actions=10)                      # the timing taker's: T = 1..10
    plain = PlainSAC.from_sac(agent, torch.float64)              # tarl.SAC's weights, separate modules, float64
"""
from __future__ import annotations

import copy
import math
import sys
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tarl import SACConfig, mlp  # noqa: E402  (Table 2's constants and two hidden layers of ReLU)

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # clamp of the Gaussian's log std (Haarnoja et al. 2018)


class PlainSAC:
    """SAC: continuous if act_dim is given, with bounds low < high; discrete if n_actions is (choices 1..n).

    batch (as tarl.ReplayBuffer.sample gives it): obs (B, obs_dim), act (B, act_dim) or (B,) ints 1..n, rew,
    discount (gamma, or gamma^T), done (B,), next_obs (B, obs_dim). dtype: of every network and loss; the
    Gaussian's noise is drawn in float32 as in tarl.SAC (torch.randn), so that a float64 copy samples the same.
    """

    def __init__(self, obs_dim: int, act_dim: int | None = None, n_actions: int | None = None, low=None, high=None,
                 cfg: SACConfig = SACConfig(), dtype: torch.dtype = torch.float32):
        assert (act_dim is None) != (n_actions is None), "give act_dim (continuous) or n_actions (discrete)"
        self.cfg, self.dtype, self.discrete = cfg, dtype, n_actions is not None
        if self.discrete:
            self.n_actions = n_actions
            self.actor = mlp(obs_dim, n_actions, cfg.hidden)  # logits of pi(.|s)
            q_in, q_out = obs_dim, n_actions  # Q(s, .): one output per choice
            self.target_entropy = cfg.target_entropy_fraction * math.log(n_actions)
        else:
            self.act_dim = act_dim
            low, high = (torch.as_tensor(v, dtype=dtype).expand(act_dim) for v in (low, high))
            self.scale, self.bias = (high - low) / 2, (high + low) / 2
            self.actor = mlp(obs_dim, 2 * act_dim, cfg.hidden)  # mean and log std of pi(.|s)
            q_in, q_out = obs_dim + act_dim, 1  # Q(s, a)
            self.target_entropy = -float(act_dim)  # -dim(A) (Haarnoja et al. 2018b)
        self.qf1, self.qf2 = mlp(q_in, q_out, cfg.hidden), mlp(q_in, q_out, cfg.hidden)
        self.actor, self.qf1, self.qf2 = self.actor.to(dtype), self.qf1.to(dtype), self.qf2.to(dtype)
        self.qf1_target, self.qf2_target = copy.deepcopy(self.qf1), copy.deepcopy(self.qf2)
        self.log_alpha = torch.tensor(math.log(cfg.init_alpha), dtype=dtype, requires_grad=True)
        self.q_optimizer = torch.optim.Adam([*self.qf1.parameters(), *self.qf2.parameters()], lr=cfg.lr)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=cfg.lr)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=cfg.lr)

    @classmethod
    def from_sac(cls, agent, dtype: torch.dtype = torch.float64) -> PlainSAC:
        """A PlainSAC with tarl.SAC `agent`'s policy, critics (TwinCritic's two halves as two nn.Sequential),
        target critics, temperature and bounds, in dtype; its optimizers are fresh (no Adam state)."""
        obs_dim, cfg = agent.policy[0].in_features, agent.cfg
        if agent.discrete:
            plain = cls(obs_dim, n_actions=agent.n_actions, cfg=cfg, dtype=dtype)
        else:
            low, high = agent.action_bias - agent.action_scale, agent.action_bias + agent.action_scale
            plain = cls(obs_dim, act_dim=agent.act_dim, low=low, high=high, cfg=cfg, dtype=dtype)
            plain.scale, plain.bias = agent.action_scale.to(dtype), agent.action_bias.to(dtype)  # exactly tarl's
        with torch.no_grad():
            plain.actor.load_state_dict(agent.policy.state_dict())  # copied into plain's dtype
            for twin, nets in ((agent.critic, (plain.qf1, plain.qf2)), (agent.critic_target,
                                                                        (plain.qf1_target, plain.qf2_target))):
                for k, net in enumerate(nets):
                    w1 = twin.w1_obs[k] if twin.w1_act is None else torch.cat([twin.w1_obs[k], twin.w1_act[k]])
                    layers = [(w1, twin.b1[k, 0]), (twin.w2[k], twin.b2[k, 0]), (twin.w3[k], twin.b3[k, 0])]
                    for linear, (w, b) in zip([m for m in net if isinstance(m, nn.Linear)], layers):
                        linear.weight.copy_(w.T)  # TwinCritic applies x @ w, nn.Linear x @ weight.T
                        linear.bias.copy_(b)
            plain.log_alpha.copy_(agent.log_alpha)
        return plain

    def cast(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The batch's floating tensors in the networks' dtype; the discrete choices stay ints."""
        return {k: v.to(self.dtype) if v.is_floating_point() else v for k, v in batch.items()}

    def sample(self, obs: torch.Tensor):
        """a ~ pi(.|s) reparameterised, a = bias + scale tanh(u), u ~ N(mean, std), and log pi(a|s) (B,)."""
        mean, log_std = self.actor(obs).chunk(2, -1)
        std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX).exp()
        u = mean + std * torch.randn(mean.shape).to(self.dtype)
        # change of variables: log pi(a|s) = log N(u; mean, std) - log |da/du|, da/du = scale (1 - tanh(u)^2); as
        # written, without CleanRL's + 1e-6 (tarl.SAC's is exact), so finite while tanh(u) < 1: |u| < 9 in float32
        log_prob = torch.distributions.Normal(mean, std).log_prob(u) - torch.log(self.scale * (1 - torch.tanh(u) ** 2))
        return self.bias + self.scale * torch.tanh(u), log_prob.sum(-1)

    def probs(self, obs: torch.Tensor):
        """pi(.|s) and log pi(.|s) (B, n), column T - 1 for choice T."""
        logits = self.actor(obs)
        return F.softmax(logits, -1), F.log_softmax(logits, -1)

    def critic_loss(self, b: dict[str, torch.Tensor]) -> torch.Tensor:
        """MSE(Q1(s, a), y) + MSE(Q2(s, a), y), y = r + discount (1 - done) (min Q-hat(s', a') - alpha log pi(a'|s')),
        a' ~ pi(.|s') one sample (continuous), or the expectation over the n choices (discrete)."""
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            if self.discrete:
                probs, log_probs = self.probs(b["next_obs"])
                min_q = torch.min(self.qf1_target(b["next_obs"]), self.qf2_target(b["next_obs"]))
                v_next = (probs * (min_q - alpha * log_probs)).sum(1)
            else:
                a_next, log_prob = self.sample(b["next_obs"])
                x_next = torch.cat([b["next_obs"], a_next], 1)
                v_next = torch.min(self.qf1_target(x_next), self.qf2_target(x_next)).squeeze(1) - alpha * log_prob
            y = b["rew"] + b["discount"] * (1 - b["done"]) * v_next
        if self.discrete:
            index = (b["act"] - 1).view(-1, 1)
            q1, q2 = self.qf1(b["obs"]).gather(1, index).squeeze(1), self.qf2(b["obs"]).gather(1, index).squeeze(1)
        else:
            x = torch.cat([b["obs"], b["act"]], 1)
            q1, q2 = self.qf1(x).squeeze(1), self.qf2(x).squeeze(1)
        return F.mse_loss(q1, y) + F.mse_loss(q2, y)

    def policy_loss(self, obs: torch.Tensor):
        """E_s[alpha log pi(a|s) - min Q(s, a)], a ~ pi(.|s) (continuous), or E_s[sum_a pi(a|s) (alpha log pi(a|s)
        - min Q(s, a))] (discrete), with the critics frozen; and log pi, and pi if discrete (else None), detached,
        for the temperature's loss."""
        alpha = self.log_alpha.detach().exp()
        critic_params = [*self.qf1.parameters(), *self.qf2.parameters()]
        for p in critic_params:  # no gradient into the critics (Spinning Up's way)
            p.requires_grad_(False)
        try:
            if self.discrete:
                probs, log_probs = self.probs(obs)
                min_q = torch.min(self.qf1(obs), self.qf2(obs))
                return (probs * (alpha * log_probs - min_q)).sum(1).mean(), log_probs.detach(), probs.detach()
            a, log_prob = self.sample(obs)
            x = torch.cat([obs, a], 1)
            loss = (alpha * log_prob - torch.min(self.qf1(x), self.qf2(x)).squeeze(1)).mean()
            return loss, log_prob.detach(), None
        finally:
            for p in critic_params:
                p.requires_grad_(True)

    def temperature_loss(self, log_pi: torch.Tensor, probs: torch.Tensor | None = None) -> torch.Tensor:
        """E[-log alpha (log pi(a|s) + H_bar)], over the n choices with weights pi if discrete."""
        loss = -self.log_alpha * (log_pi + self.target_entropy)
        return (loss if probs is None else (probs * loss).sum(1)).mean()

    def update(self, batch: dict[str, torch.Tensor]) -> tuple[float, float, float]:
        """One step of each part, critics first, on losses taken before any step; then Q-hat <- (1 - tau) Q-hat
        + tau Q. Returns the critic, policy and temperature losses."""
        b = self.cast(batch)
        qf_loss = self.critic_loss(b)  # draws a' first, then the policy loss a, as tarl.SAC.losses does
        actor_loss, log_pi, probs = self.policy_loss(b["obs"])
        alpha_loss = self.temperature_loss(log_pi, probs)
        self.q_optimizer.zero_grad()
        qf_loss.backward()
        self.actor_optimizer.zero_grad()
        actor_loss.backward()  # before the critic step: its graph holds the critics' weights
        self.alpha_optimizer.zero_grad()
        alpha_loss.backward()
        self.q_optimizer.step()
        self.actor_optimizer.step()
        self.alpha_optimizer.step()
        with torch.no_grad():
            for net, target in ((self.qf1, self.qf1_target), (self.qf2, self.qf2_target)):
                for p, tp in zip(net.parameters(), target.parameters()):
                    tp.copy_(self.cfg.tau * p + (1 - self.cfg.tau) * tp)
        return qf_loss.item(), actor_loss.item(), alpha_loss.item()
