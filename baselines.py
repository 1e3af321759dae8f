"""baselines: the safe-RL rows of Table 3 (Sec. 5.3), on tarl.py's environment, SAC and Trainer.

Each maximises the return of Eq. (31) subject to J_c <= d, J_c the expected episode sum of DrivingEnv's
info["cost"] (1 at a collision). A collision ends the episode, so J_c is the collision rate, d a rate.

    SAC-Lag  SAC (Haarnoja et al. 2018) + a cost critic and a Lagrange multiplier (Ray, Achiam, Amodei 2019)
    SAC-PID  the same, lambda from a PID controller (Stooke, Achiam, Abbeel 2020)
    PPO-Lag  PPO (Schulman et al. 2017) on the Lagrangian advantage (Ray, Achiam, Amodei 2019)
    CPO      Constrained Policy Optimization (Achiam, Held, Tamar, Abbeel 2017)
    run one: python tarl.py --scenario intersection --algo sac-lag|sac-pid|ppo-lag|cpo --steps 100000

As OmniSafe and Safe-Policy-Optimization (SafePO) do it, departures commented. Map: SafeRLConfig; J_c and lambda:
CostConstraint, Lagrange, PIDLagrange (Stooke's Alg. 2); ConstrainedTrainer (on tarl.Trainer); SAC-Lag, SAC-PID:
ConstrainedSAC, cost_td_target, SafeSACTrainer; PPO-Lag, CPO: OnPolicyTrainer, OnPolicyAgent, GaussianPolicy, gae,
ppo_clip_loss, lagrangian_advantage; CPO's update: conjugate_gradient, fisher_vector_product, cpo_direction,
backtracking_line_search. Eq. (n) alone is the TARL paper's; another paper's carries its name, as "CPO's Eq. (13)".
"""
from __future__ import annotations

import collections
import copy
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
import torch.nn as nn
from torch import Tensor
from torch.nn.utils import parameters_to_vector, vector_to_parameters

import tarl
import world


@dataclass(frozen=True)
class SafeRLConfig:
    """The baselines' constants (SAC's: tarl.SACConfig), SafePO's and OmniSafe's unless a comment says why not."""

    cost_limit: float = 0.05  # d [collisions/episode]: plain SAC's 0.1-0.3 (100k steps) is above; Safety-Gym's 25 is not
    window: int = 50  # [episodes] J_c is the mean cost of the last 50 (SafePO's); 0/1 costs, not normalised
    lagrange_lr: float = 0.1  # SAC-Lag's lambda step per episode, SAC-PID's K_i (OmniSafe: Adam, see Lagrange)
    rollout_lagrange_lr: float = 2.0  # PPO-Lag's per rollout: 0.1 x the ~20 episodes of 2,048 steps
    pid_gains: tuple = (10.0, 0.1, 10.0)  # K_p, K_i, K_d of SAC-PID, not OmniSafe's 1e-6...: see PIDLagrange
    hidden: int = 64  # units of the two tanh layers of the on-policy pi, V_r and V_c (SafePO, OmniSafe)
    init_log_std: float = 0.0  # log sigma at the start (SafePO, CleanRL): sigma 1 in units of half the range
    gamma: float = tarl.SACConfig.gamma  # Table 2's, for every row
    gae_lambda: float = 0.95  # GAE's lambda, for A_r and A_c (SafePO, OmniSafe, CleanRL)
    rollout: int = 2048  # N [steps] per update (CleanRL): SafePO's 20,000 would give 5 updates in 100k steps
    epochs: int = 10  # passes over a rollout, of PPO and of the value fits (CleanRL; SafePO: 40, KL-stopped, 20k)
    minibatch: int = 64  # samples per gradient step (SafePO; CleanRL's 2,048 / 32)
    clip: float = 0.2  # epsilon of PPO (Schulman et al. 2017), Eq. (7)
    policy_lr: float = 3e-4  # PPO-Lag's Adam; constant (SafePO and CleanRL anneal it to 0 over the run)
    value_lr: float = 1e-3  # Adam of V_r and V_c (OmniSafe's critic lr)
    cpo_delta: float = 0.01  # delta of CPO's trust region on the mean KL (SafePO, OmniSafe)
    cg_iters: int = 15  # conjugate-gradient iterations (SafePO's cpo.py)
    cg_damping: float = 0.1  # (H + damping I) v: keeps CG stable when H is near-singular (SafePO, OmniSafe)
    backtrack: float = 0.8  # step fraction per line-search trial (SafePO, OmniSafe)
    search_steps: int = 15  # line-search trials before giving up on the update (SafePO, OmniSafe)


C = SafeRLConfig  # the defaults of the functions below
EPS = 1e-8  # guards divisions by s, lambda and B, as in the reference implementations


def gae(rewards: Tensor, values: Tensor, dones: Tensor, last_value: float, gamma: float, lam: float,
        truncated: Tensor | None = None, final_values: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """GAE on a rollout (N,): rewards or costs, V(s_t), dones (s_{t+1} terminal), V(s_N); where the time limit cut
    after step t (truncated), V(s_{t+1}) = final_values[t] and the lambda-sum stops. Returns A_t, A_t + V(s_t)."""
    next_values, ends = torch.cat([values[1:], values.new_tensor([last_value])]), dones
    if truncated is not None:
        next_values, ends = torch.where(truncated.bool(), final_values, next_values), torch.maximum(dones, truncated)
    # GAE (Schulman et al. 2016), Sec. 3: delta_t = r_t + gamma V(s_{t+1}) - V(s_t), with V(terminal) = 0
    deltas = rewards + gamma * (1.0 - dones) * next_values - values
    advantages, running = torch.zeros_like(values), 0.0
    for t in reversed(range(len(rewards))):
        # GAE (Schulman et al. 2016), Eq. (16): A_t = sum_l (gamma lam)^l delta_{t+l} = delta_t + gamma lam A_{t+1}
        running = deltas[t] + gamma * lam * (1.0 - ends[t]) * running
        advantages[t] = running
    return advantages, advantages + values


def ppo_clip_loss(ratio: Tensor, advantages: Tensor, clip: float) -> Tensor:
    """-L^CLIP of PPO, minimised. ratio (B,): pi_theta(a|s) / pi_old(a|s); clip: epsilon."""
    # PPO (Schulman et al. 2017), Eq. (7): L^CLIP = E[min(r A, clip(r, 1 - eps, 1 + eps) A)]
    return -torch.min(ratio * advantages, ratio.clamp(1.0 - clip, 1.0 + clip) * advantages).mean()


def lagrangian_advantage(adv_r: Tensor, adv_c: Tensor, lagrange_multiplier: float) -> Tensor:
    """PPO-Lag's (A_r - lambda A_c) / (1 + lambda) (Ray et al. 2019): A_r standardised, A_c only centred, its
    scale what lambda trades against; 1 + lambda keeps A_r's scale (safety-starter-agents, SafePO, OmniSafe)."""
    adv_r = (adv_r - adv_r.mean()) / (adv_r.std() + EPS)
    return (adv_r - lagrange_multiplier * (adv_c - adv_c.mean())) / (1.0 + lagrange_multiplier)


class Lagrange:
    """lambda >= 0 of max_pi min_lambda J_r - lambda (J_c - d) by projected gradient ascent; not OmniSafe's Adam,
    whose step is ~lr whatever J_c - d and whose momentum keeps lambda rising after J_c fell under d."""

    def __init__(self, cost_limit: float, lr: float = C.lagrange_lr, init: float = 0.0):
        self.cost_limit, self.lr, self.value = cost_limit, lr, init

    def update(self, episode_cost: float) -> float:
        # dual ascent: d/d lambda of -(lambda (J_c - d)) is -(J_c - d); step, then project onto lambda >= 0
        self.value = max(0.0, self.value + self.lr * (episode_cost - self.cost_limit))
        return self.value


class PIDLagrange:
    """lambda from a PID controller on J_c (Stooke, Achiam, Abbeel 2020, Alg. 2): delta = J_c - d, I = max(0, I +
    K_i delta), P = EMA(delta), D = max(0, EMA(J_c) - EMA(J_c) `delay` updates ago), lambda = max(0, K_p P + I +
    K_d D). Gains for 1,000-2,000 updates of a collision rate (OmniSafe's 1e-6 suit Safety-Gym): an excess of 0.1
    adds 10 in 1,000 episodes by I (20 doubles Eq. (31)'s -20), 1 in ~50 by P; a rise of 0.1 adds up to 0.34 by D."""

    def __init__(self, cost_limit: float, kp=C.pid_gains[0], ki=C.pid_gains[1], kd=C.pid_gains[2], ema=0.95, delay=10):
        self.cost_limit, self.kp, self.ki, self.kd, self.ema, self.delay = cost_limit, kp, ki, kd, ema, delay
        self.integral = self.proportional = self.derivative = self.cost_ema = self.value = 0.0
        self.past_cost_ema = [0.0]  # [0] is EMA(J_c) `delay` updates ago

    def update(self, episode_cost: float) -> float:
        delta = episode_cost - self.cost_limit
        self.integral = max(0.0, self.integral + self.ki * delta)
        self.proportional = self.ema * self.proportional + (1.0 - self.ema) * delta
        self.cost_ema = self.ema * self.cost_ema + (1.0 - self.ema) * episode_cost
        self.derivative = max(0.0, self.cost_ema - self.past_cost_ema[0])
        self.past_cost_ema = (self.past_cost_ema + [self.cost_ema])[-self.delay:]
        self.value = max(0.0, self.kp * self.proportional + self.integral + self.kd * self.derivative)
        return self.value


class CostConstraint:
    """J_c (the mean cost of the last `window` episodes), the multiplier (CPO: None), a history row per update."""

    def __init__(self, cost_limit: float, window: int, multiplier=None, columns=("step", "J_c", "lambda")):
        self.cost_limit, self.multiplier, self.columns, self.history = cost_limit, multiplier, columns, []
        self.episodes = collections.deque(maxlen=window)  # (cost, steps) of each recent episode

    @property
    def cost(self) -> float:  # J_c, 0 before any episode has ended
        return float(np.mean([c for c, _ in self.episodes])) if self.episodes else 0.0

    def update(self, step: int) -> float:  # lambda from J_c, at env step `step`
        self.history.append([step, round(self.cost, 4), round(self.multiplier.update(self.cost), 4)])
        return self.multiplier.value

    def state_dict(self) -> dict:  # plain lists and numbers: torch.load(weights_only=True)
        multiplier = dict(vars(self.multiplier)) if self.multiplier else {}
        return {"episodes": list(self.episodes), "history": self.history, "multiplier": multiplier}

    def load_state_dict(self, state: dict):
        self.episodes.extend(map(tuple, state["episodes"]))
        self.history = state["history"]
        if self.multiplier:
            vars(self.multiplier).update(state["multiplier"])


# ---- CPO's update (Achiam et al. 2017), Eq. (11): max g^T x  s.t.  c + b^T x <= 0,  1/2 x^T H x <= delta
# x = theta - theta_k; g, b: gradients of the reward and cost surrogates; c = J_c - d; H: Hessian of the KL


def conjugate_gradient(Avp: Callable[[Tensor], Tensor], b: Tensor, iters: int = C.cg_iters, tol: float = 1e-10) -> Tensor:
    """x ~ A^-1 b from products A v, A symmetric positive definite: H^-1 g without H (TRPO, App. C)."""
    x, r = torch.zeros_like(b), b.clone()  # residual r = b - A x at x = 0
    p, rr = r.clone(), r @ r
    for _ in range(iters):
        if rr.sqrt() < tol:
            break
        Ap = Avp(p)
        alpha = rr / (p @ Ap)
        x, r = x + alpha * p, r - alpha * Ap
        rr_next = r @ r
        p, rr = r + (rr_next / rr) * p, rr_next
    return x


def fisher_vector_product(params: list[Tensor], kl: Callable[[], Tensor], damping: float = C.cg_damping) -> Callable:
    """v -> (H + damping I) v by double backward, H the Hessian of kl(), mean KL(pi_old || pi) (pi_old detached)."""
    grad = parameters_to_vector(torch.autograd.grad(kl(), params, create_graph=True))
    return lambda v: parameters_to_vector(torch.autograd.grad(grad @ v, params, retain_graph=True)) + damping * v


def cpo_direction(g: Tensor, b: Tensor, c: float, Hinv_g: Tensor, Hinv_b: Tensor, delta: float) -> tuple[Tensor, int]:
    """The step x* for CPO (Achiam et al. 2017), Eq. (11), and its case (numbered as in SafePO and OmniSafe). With
    q = g^T H^-1 g, r = g^T H^-1 b, s = b^T H^-1 b, A = q - r^2 / s, B = 2 delta - c^2 / s:
      4: b ~ 0 and c < 0, 3: c < 0, B < 0 (the trust region is feasible): TRPO's sqrt(2 delta / q) H^-1 g;
      2: c < 0 <= B, 1: c >= 0, B >= 0 (c + b^T x = 0 crosses the trust region): CPO's Eq. (13) from its (12);
      0: c >= 0, B < 0 (no feasible point): the recovery x* = -sqrt(2 delta / s) H^-1 b, CPO's Eq. (14)."""
    q, r, s = float(g @ Hinv_g), float(g @ Hinv_b), float(b @ Hinv_b)
    if float(b @ b) <= 1e-6 and c < 0:  # the cost surrogate is flat: TRPO (Schulman et al. 2015)
        return math.sqrt(2 * delta / (q + EPS)) * Hinv_g, 4
    A, B = q - r * r / (s + EPS), 2 * delta - c * c / (s + EPS)
    if c < 0 and B < 0:
        return math.sqrt(2 * delta / (q + EPS)) * Hinv_g, 3
    if B < 0:  # CPO (Achiam et al. 2017), Eq. (14): the infeasible recovery, the cost's steepest descent in the region
        return -math.sqrt(2 * delta / (s + EPS)) * Hinv_b, 0
    # CPO (Achiam et al. 2017), Eq. (12) in closed form (its appendix): the better of f_a (nu* > 0) and f_b (nu* = 0),
    # each projected on its interval. The appendix minimises g^T x: for our ascent r flips sign (SafePO, OmniSafe: not)
    split = max(-r / (c - EPS if c < 0 else c + EPS), 0.0)  # lambda c + r changes sign (lambda >= 0)
    (lo_a, hi_a), (lo_b, hi_b) = ((0.0, split), (split, math.inf)) if c < 0 else ((split, math.inf), (0.0, split))
    lam_a = min(max(math.sqrt(A / (B + EPS)), lo_a), hi_a)
    lam_b = min(max(math.sqrt(q / (2 * delta)), lo_b), hi_b)
    f_a = -0.5 * (A / (lam_a + EPS) + B * lam_a) + r * c / (s + EPS)
    f_b = -0.5 * (q / (lam_b + EPS) + 2 * delta * lam_b)
    lam_star = lam_a if f_a >= f_b else lam_b
    nu_star = max(0.0, lam_star * c + r) / (s + EPS)
    # CPO (Achiam et al. 2017), Eq. (13): x* = (1 / lambda*) H^-1 (g - nu* b)
    return (Hinv_g - nu_star * Hinv_b) / (lam_star + EPS), 1 if c >= 0 else 2


def backtracking_line_search(step: Tensor, evaluate: Callable[[Tensor], tuple[float, float, float]], c: float,
                             delta: float, fraction: float = C.backtrack, max_steps: int = C.search_steps):
    """The largest fraction^k step that CPO accepts (SafePO, OmniSafe): evaluate(x) -> (reward surrogate gain,
    cost surrogate change, mean KL) at theta_k + x; KL <= delta, the cost rises by at most max(-c, 0) and, if
    feasible (c < 0), the reward does not fall. Returns the step and its trial 1.., or zeros and 0."""
    for k in range(max_steps):
        x = fraction**k * step
        reward_gain, cost_change, kl = evaluate(x)
        if math.isfinite(kl) and kl <= delta and cost_change <= max(-c, 0.0) and (c >= 0 or reward_gain >= 0):
            return x, k + 1
    return torch.zeros_like(step), 0


class ConstrainedTrainer(tarl.Trainer):
    """tarl.Trainer (run, logs, checkpoints; a subclass replaces its SAC) with a cost: J_c over the recent
    episodes in `constraint`, SAC-Lag's and SAC-PID's lambda updated at every episode's end, constraint_log.csv."""

    def __init__(self, env: world.DrivingEnv, algo: str, tc: tarl.TrainConfig, sac_cfg: tarl.SACConfig, seed, out, log,
                 timing: str, step_one: bool):
        assert timing == "none" and not step_one, "a safe-RL row is the actor alone (experiment.ROWS)"
        super().__init__(env, algo, tc, sac_cfg, seed, out, log, timing, step_one)  # plain SAC's actor loop
        self.episode_cost, self.episode_steps = 0.0, 0
        self.log = tarl.TrainLog(out, tc.steps, lambda line: log(f"{line} | J_c {self.constraint.cost:.3f}" + (
            f", lambda {self.constraint.multiplier.value:.3f}" if self.constraint.multiplier else "")))

    def columns(self, info: dict) -> dict:
        return {"cost": info["cost"]}

    def after_step(self, r: float, b: float | None, info: dict, done: bool, loop: str):
        self.episode_cost, self.episode_steps = self.episode_cost + info["cost"], self.episode_steps + 1
        if done:
            self.constraint.episodes.append((self.episode_cost, self.episode_steps))
            self.episode_cost = self.episode_steps = 0
            if self.algo in ("sac-lag", "sac-pid"):  # lambda once per finished episode, from J_c
                self.constraint.update(self.step + 1)
        super().after_step(r, b, info, done, loop)

    def save(self, name: str = "ckpt.pt"):
        super().save(name)  # the constraint's state is in the actor's
        if self.out is not None:
            (self.out / "constraint_log.csv").write_text("".join(
                ",".join(map(str, row)) + "\n" for row in [self.constraint.columns, *self.constraint.history]))


@torch.no_grad()
def cost_td_target(agent: ConstrainedSAC, batch: dict[str, Tensor]) -> Tensor:
    """y_c = c + gamma (1 - done) max_i Q'_c,i(s', a'), a' ~ pi(.|s') (B,): no entropy term (OmniSafe's sac_lag.py)."""
    a_next, _ = agent.squashed_gaussian(batch["next_obs"])
    q_next = agent.cost_critic_target(batch["next_obs"], a_next).amax(0).squeeze(-1)
    return batch["cost"] + batch["discount"] * (1 - batch["done"]) * q_next


class ConstrainedSAC(tarl.SAC):
    """SAC-Lag's and SAC-PID's agent: tarl.SAC, the constraint and twin cost critics (OmniSafe: one). The max of
    two mirrors SAC's min (Fujimoto et al. 2018): the policy minimises Q_c, so it seeks Q_c's underestimates."""

    def __init__(self, obs_dim: int, act_dim: int, low, high, cfg: tarl.SACConfig, constraint: CostConstraint):
        super().__init__(obs_dim, act_dim=act_dim, low=low, high=high, cfg=cfg)
        self.constraint, self.cost_critic = constraint, tarl.TwinCritic(obs_dim, act_dim, 1, cfg.hidden)
        self.cost_critic_target = copy.deepcopy(self.cost_critic).requires_grad_(False)
        self.optimizer.add_param_group({"params": list(self.cost_critic.parameters())})
        self.online_params += self.cost_critic.parameters()
        self.target_params += self.cost_critic_target.parameters()

    def losses(self, batch: dict[str, Tensor], penalty=None) -> dict[str, Tensor]:
        lam = self.constraint.multiplier.value
        # OmniSafe's SAC-Lag: E[alpha log pi - min Q_r + lambda max Q_c] / (1 + lambda), the critics frozen
        losses = super().losses(batch, lambda obs, a: lam * self.cost_critic(obs, a, frozen=True).amax(0).squeeze(-1))
        losses["policy_loss"] = losses["policy_loss"] / (1.0 + lam)
        q_c = self.cost_critic(batch["obs"], batch["act"]).squeeze(-1)
        losses["cost_critic_loss"] = (q_c - cost_td_target(self, batch)).square().mean(-1).sum()
        return losses

    def state_dict(self) -> dict:
        return {**super().state_dict(), "cost_critic": self.cost_critic.state_dict(),
                "cost_critic_target": self.cost_critic_target.state_dict(), "constraint": self.constraint.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        for k in ("cost_critic", "cost_critic_target", "constraint") if "cost_critic" in state else ():  # policy.pt: none
            getattr(self, k).load_state_dict(state[k])


class SafeSACTrainer(ConstrainedTrainer):
    """SAC-Lag ("sac-lag") and SAC-PID ("sac-pid"): plain SAC's actor loop with ConstrainedSAC."""

    def __init__(self, env, algo: str, tc, sac_cfg=tarl.SACConfig(), seed=0, out=None, log=print, timing="none",
                 step_one=False, cfg=SafeRLConfig()):
        super().__init__(env, algo, tc, sac_cfg, seed, out, log, timing, step_one)
        space, d = env.action_space, cfg.cost_limit
        multiplier = Lagrange(d, cfg.lagrange_lr) if algo == "sac-lag" else PIDLagrange(d, *cfg.pid_gains)
        self.constraint = CostConstraint(d, cfg.window, multiplier)
        self.actor = ConstrainedSAC(world.OBS_DIM, len(space.low), space.low, space.high, sac_cfg, self.constraint)
        self.D_a = tarl.ReplayBuffer(sac_cfg.buffer_size, world.OBS_DIM, space.shape, extra=("cost",))
        self.driver = tarl.Driver("none", self.actor)


def tanh_mlp(in_dim: int, out_dim: int, h: int = C.hidden) -> nn.Sequential:  # SafePO's, OmniSafe's
    return nn.Sequential(nn.Linear(in_dim, h), nn.Tanh(), nn.Linear(h, h), nn.Tanh(), nn.Linear(h, out_dim))


def value_net(obs_dim: int, hidden: int = C.hidden) -> nn.Sequential:  # V_r or V_c: obs (B, obs_dim) -> (B,)
    return nn.Sequential(tanh_mlp(obs_dim, 1, hidden), nn.Flatten(0))


class GaussianPolicy(nn.Module):
    """pi(u|s) = N(mu(s), sigma^2), log sigma a parameter; the env's action (high + low) / 2 + (high - low) / 2
    clip(u, -1, 1), clipped, not squashed, as in SafePO and CleanRL: log pi(u|s) stays exact for ratio and KL."""

    def __init__(self, obs_dim: int, act_dim: int, low, high, hidden: int = C.hidden, init_log_std: float = C.init_log_std):
        super().__init__()
        self.mean, self.log_std = tanh_mlp(obs_dim, act_dim, hidden), nn.Parameter(torch.full((act_dim,), init_log_std))
        low, high = (torch.as_tensor(v, dtype=torch.float32).expand(act_dim) for v in (low, high))
        self.scale, self.bias = (high - low) / 2, (high + low) / 2

    def forward(self, obs: Tensor) -> torch.distributions.Normal:
        return torch.distributions.Normal(self.mean(obs), self.log_std.exp())

    def log_prob(self, obs: Tensor, u: Tensor) -> Tensor:  # log pi(u|s), summed over action dimensions: (B,)
        return self(obs).log_prob(u).sum(-1)

    def to_env(self, u: Tensor) -> Tensor:  # the env's action in [low, high] for the policy's sample u
        return self.bias + self.scale * u.clamp(-1.0, 1.0)

    @torch.no_grad()
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:  # for tarl.Driver
        dist = self(torch.as_tensor(obs, dtype=torch.float32))
        return self.to_env(dist.mean if deterministic else dist.sample()).numpy()


class OnPolicyAgent:
    """pi, V_r, V_c, their Adams and the constraint: what tarl.Trainer saves (ckpt.pt; policy.pt: pi alone)."""
    parts = ("policy", "values", "constraint", "policy_optimizer", "values_optimizer")

    def __init__(self, low, high, cfg: SafeRLConfig, constraint: CostConstraint):
        self.policy = GaussianPolicy(world.OBS_DIM, len(low), low, high, cfg.hidden, cfg.init_log_std)
        self.values = nn.ModuleDict({k: value_net(world.OBS_DIM, cfg.hidden) for k in ("rew", "cost")})  # V_r, V_c
        self.policy_optimizer = torch.optim.Adam(self.policy.parameters(), lr=cfg.policy_lr)  # PPO-Lag's
        self.values_optimizer = torch.optim.Adam(self.values.parameters(), lr=cfg.value_lr)
        self.constraint = constraint

    def descend(self, name: str, loss: Tensor):  # one Adam step of "policy" or "values", unclipped (SafePO: 40)
        getattr(self, f"{name}_optimizer").zero_grad(set_to_none=True)
        loss.backward()
        getattr(self, f"{name}_optimizer").step()

    def state_dict(self) -> dict:
        return {k: getattr(self, k).state_dict() for k in self.parts}

    def load_state_dict(self, state: dict):  # ckpt.pt, or policy.pt: {"policy": ...} alone
        for k, v in state.items():
            getattr(self, k).load_state_dict(v)


class OnPolicyTrainer(ConstrainedTrainer):
    """PPO-Lag ("ppo-lag") and CPO ("cpo") as CleanRL's ppo_continuous_action.py: tarl.Trainer.run repeats
    actor_loop, here a rollout of N steps with GAE for reward and cost, a policy update and the value fits."""

    def __init__(self, env, algo: str, tc, sac_cfg=None, seed=0, out=None, log=print, timing="none", step_one=False,
                 cfg=SafeRLConfig()):
        super().__init__(env, algo, tc, tarl.SACConfig(buffer_size=1), seed, out, log, timing, step_one)  # SAC replaced
        multiplier = Lagrange(cfg.cost_limit, cfg.rollout_lagrange_lr) if algo == "ppo-lag" else None
        columns = ("step", "J_c", "lambda") if multiplier else ("step", "J_c", "cpo_case", "trial")
        self.cfg, self.constraint = cfg, CostConstraint(cfg.cost_limit, cfg.window, multiplier, columns)
        self.actor = OnPolicyAgent(env.action_space.low, env.action_space.high, cfg, self.constraint)
        self.policy, self.driver = self.actor.policy, tarl.Driver("none", self.actor.policy)  # D_a stays empty

    def actor_loop(self, driver: tarl.Driver, loop: str):
        """A rollout, the policy update (PPO-Lag's epochs or a CPO step), the value fits."""
        c = self.cfg
        data = self.rollout(min(c.rollout, self.tc.steps - self.step))
        (self.ppo_lag_update if self.algo == "ppo-lag" else self.cpo_update)(data)
        for _ in range(c.epochs):  # the value fits: V_r and V_c on their TD(lambda) targets
            for i in torch.randperm(len(data["obs"])).split(c.minibatch):
                self.actor.descend("values", sum((V(data["obs"][i]) - data[f"ret_{k}"][i]).square().mean()
                                                 for k, V in self.actor.values.items()))
        self.updates["actor"] += 1

    def rollout(self, n: int) -> dict[str, Tensor]:
        """n steps of pi, with log pi_old(u|s) and GAE's advantages and targets of the reward and the cost."""
        steps = []
        for _ in range(n):
            with torch.no_grad():
                u = self.policy(torch.as_tensor(self.obs)).sample()
            next_obs, r, terminated, truncated, info = self.env.step(self.policy.to_env(u).numpy())
            steps.append((self.obs, u.numpy(), r, info["cost"], terminated, truncated, next_obs))  # final_obs: for GAE
            self.obs = self.env.reset()[0] if terminated or truncated else next_obs
            self.after_step(r, None, info, terminated or truncated, "real")  # the log, progress, checkpoints
        keys = ("obs", "u", "rew", "cost", "done", "truncated", "final_obs")
        data = {k: torch.as_tensor(np.array(v), dtype=torch.float32) for k, v in zip(keys, zip(*steps))}
        c, last_obs = self.cfg, torch.as_tensor(self.obs)[None]
        with torch.no_grad():
            data["log_prob"] = self.policy.log_prob(data["obs"], data["u"])
            for k, V in self.actor.values.items():  # V(s_N) after the last step bootstraps the rollout's end
                data[f"adv_{k}"], data[f"ret_{k}"] = gae(data[k], V(data["obs"]), data["done"], float(V(last_obs)),
                                                         c.gamma, c.gae_lambda, data["truncated"], V(data["final_obs"]))
        return data

    def ppo_lag_update(self, data: dict[str, Tensor]):
        """lambda once per rollout, then epochs of minibatch steps on the clipped surrogate L^CLIP of PPO
        (Schulman et al. 2017), Eq. (7)."""
        c, obs = self.cfg, data["obs"]
        lam = self.constraint.update(self.step)  # before the policy, from the recent episodes (SafePO, OmniSafe)
        adv = lagrangian_advantage(data["adv_rew"], data["adv_cost"], lam)
        for _ in range(c.epochs):
            for i in torch.randperm(len(obs)).split(c.minibatch):
                ratio = (self.policy.log_prob(obs[i], data["u"][i]) - data["log_prob"][i]).exp()
                self.actor.descend("policy", ppo_clip_loss(ratio, adv[i], c.clip))

    def cpo_update(self, data: dict[str, Tensor]):
        """One CPO step (Achiam et al. 2017, Alg. 1) on the rollout's reward and cost surrogates."""
        c, obs, params = self.cfg, data["obs"], list(self.policy.parameters())
        adv_r = (data["adv_rew"] - data["adv_rew"].mean()) / (data["adv_rew"].std() + EPS)
        adv_c = data["adv_cost"] - data["adv_cost"].mean()  # as in lagrangian_advantage
        with torch.no_grad():
            old = self.policy(obs)

        def surrogates() -> tuple[Tensor, Tensor]:  # E[ratio A_r], E[ratio A_c]: gradients g, b at theta_k
            ratio = (self.policy.log_prob(obs, data["u"]) - data["log_prob"]).exp()
            return (ratio * adv_r).mean(), (ratio * adv_c).mean()
        kl = lambda: torch.distributions.kl_divergence(old, self.policy(obs)).sum(-1).mean()  # noqa: E731
        reward_0, cost_0 = surrogates()
        g = parameters_to_vector(torch.autograd.grad(reward_0, params, retain_graph=True))
        b = parameters_to_vector(torch.autograd.grad(cost_0, params))
        Hvp = fisher_vector_product(params, kl, c.cg_damping)
        Hinv_g, Hinv_b = conjugate_gradient(Hvp, g, c.cg_iters), conjugate_gradient(Hvp, b, c.cg_iters)
        # c = J_c - d per step, the unit of b^T x (an advantage per step): Achiam's safety-starter-agents
        # divides by the episode length; SafePO and OmniSafe do not (their c would be ~100x too large here)
        e, J_c = self.env.cfg, self.constraint.cost  # before the first episode ends: the longest length
        violation = (J_c - c.cost_limit) / np.mean([n for _, n in self.constraint.episodes] or [e.time_limit / e.dt])
        step, case = cpo_direction(g, b, violation, Hinv_g, Hinv_b, c.cpo_delta)
        theta = parameters_to_vector(params).detach()

        @torch.no_grad()
        def evaluate(x: Tensor) -> tuple[float, float, float]:
            vector_to_parameters(theta + x, params)
            reward, cost = surrogates()
            return float(reward - reward_0), float(cost - cost_0), float(kl())
        x, trial = backtracking_line_search(step, evaluate, violation, c.cpo_delta, c.backtrack, c.search_steps)
        vector_to_parameters(theta + x, params)
        self.constraint.history.append([self.step, round(J_c, 4), case, trial])
