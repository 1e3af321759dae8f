"""Tests of baselines.py: the math of SAC-Lag, SAC-PID, PPO-Lag and CPO against hand calculations, and
short training runs of the four on the real simulator.

Run: python -m pytest -q tests/test_baselines.py
"""
import math

import numpy as np
import pytest
import torch
from torch.distributions import Normal, kl_divergence

import experiment
import tarl
import world
from baselines import (ConstrainedSAC, CostConstraint, GaussianPolicy, Lagrange, OnPolicyTrainer, PIDLagrange,
                       SafeRLConfig, SafeSACTrainer, backtracking_line_search, conjugate_gradient, cost_td_target,
                       cpo_direction, fisher_vector_product, gae, lagrangian_advantage, ppo_clip_loss, value_net)

T = torch.tensor


def f64(*x):
    return torch.tensor(x, dtype=torch.float64)


# --------------------------------------------------------------------------------------
# GAE and the PPO losses
# --------------------------------------------------------------------------------------

# Two episodes in one rollout: steps 0-1 end in a terminal state, steps 2-3 run on past the rollout.
REWARDS, VALUES, DONES = f64(1, 2, 3, 4), f64(0.5, 1.0, 1.5, 2.0), f64(0, 1, 0, 0)
LAST_VALUE, GAMMA, LAM = 3.0, 0.9, 0.8


def test_gae_by_hand_across_an_episode_boundary():
    adv, ret = gae(REWARDS, VALUES, DONES, LAST_VALUE, GAMMA, LAM)
    # delta_0 = 1 + 0.9 * 1.0 - 0.5 = 1.4;  delta_1 = 2 - 1.0 = 1.0 (terminal: no bootstrap)
    # delta_2 = 3 + 0.9 * 2.0 - 1.5 = 3.3;  delta_3 = 4 + 0.9 * 3.0 - 2.0 = 4.7 (bootstraps last_value)
    # A_3 = 4.7, A_2 = 3.3 + 0.72 * 4.7 = 6.684, A_1 = 1.0 (the sum stops at the terminal), A_0 = 1.4 + 0.72 * 1.0
    assert adv.tolist() == pytest.approx([2.12, 1.0, 6.684, 4.7])
    assert ret.tolist() == pytest.approx([2.62, 2.0, 8.184, 6.7])


def test_gae_truncation_bootstraps_the_final_state_but_stops_the_sum():
    truncated, final_values = f64(0, 1, 0, 0), f64(0, 5.0, 0, 0)
    adv, _ = gae(REWARDS, VALUES, torch.zeros(4, dtype=torch.float64), LAST_VALUE, GAMMA, LAM,
                 truncated, final_values)
    # delta_1 = 2 + 0.9 * 5.0 - 1.0 = 5.5 (V of the final state, not of the next episode's first, 1.5);
    # A_0 = 1.4 + 0.72 * 5.5 = 5.36; steps 2-3 are untouched
    assert adv.tolist() == pytest.approx([5.36, 5.5, 6.684, 4.7])


def test_gae_with_lambda_one_is_the_discounted_return_minus_the_value():
    adv, ret = gae(REWARDS, VALUES, DONES, LAST_VALUE, GAMMA, 1.0)
    assert ret.tolist() == pytest.approx([1 + 0.9 * 2, 2, 3 + 0.9 * 4 + 0.81 * 3.0, 4 + 0.9 * 3.0])
    assert (ret - adv).tolist() == pytest.approx(VALUES.tolist())


# ratio r, advantage A, min(r A, clip(r, 0.8, 1.2) A), d(-objective)/dr
CLIP_CASES = [
    (1.1, 1.0, 1.1, -1.0),  # inside the range
    (1.5, 1.0, 1.2, 0.0),  # above, A > 0: clipped, no gradient (no incentive to go further)
    (0.5, 1.0, 0.5, -1.0),  # below, A > 0: the unclipped, pessimistic term; the gradient pulls r back up
    (1.5, -1.0, -1.5, 1.0),  # above, A < 0: unclipped, pessimistic
    (0.5, -1.0, -0.8, 0.0),  # below, A < 0: clipped, no gradient
    (0.9, -2.0, -1.8, 2.0),  # inside, A < 0
]


@pytest.mark.parametrize("ratio, adv, objective, grad", CLIP_CASES)
def test_ppo_clip_on_hand_built_ratios(ratio, adv, objective, grad):
    r = T([ratio], requires_grad=True)
    loss = ppo_clip_loss(r, T([adv]), clip=0.2)
    loss.backward()
    assert loss.item() == pytest.approx(-objective)
    assert r.grad.item() == pytest.approx(grad)


def test_ppo_clip_is_the_mean_over_the_batch():
    ratio, adv, objective, _ = map(list, zip(*CLIP_CASES))
    assert ppo_clip_loss(T(ratio), T(adv), 0.2).item() == pytest.approx(-sum(objective) / len(objective))


def test_lagrangian_advantage_standardises_a_r_and_centres_a_c():
    adv_r, adv_c = f64(1, 2, 3, 4), f64(0, 0, 1, 3)
    z = (adv_r - 2.5) / math.sqrt(5 / 3)  # std with Bessel's correction: sqrt(((1.5^2 + 0.5^2) * 2) / 3)
    assert lagrangian_advantage(adv_r, adv_c, 0.0).tolist() == pytest.approx(z.tolist())
    # lambda = 3: (z - 3 (A_c - 1)) / 4, A_c - 1 = (-1, -1, 0, 2)
    expected = (z - 3 * f64(-1, -1, 0, 2)) / 4
    assert lagrangian_advantage(adv_r, adv_c, 3.0).tolist() == pytest.approx(expected.tolist())


# --------------------------------------------------------------------------------------
# The multipliers
# --------------------------------------------------------------------------------------


def test_lagrange_rises_only_above_the_limit_and_never_below_zero():
    lag = Lagrange(cost_limit=0.1, lr=0.5)
    values = [lag.update(j) for j in (0.3, 0.3, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0)]
    # +0.5 * 0.2 twice; no change at J_c = d; -0.5 * 0.1 per safe update down to 0, then held at 0
    assert values == pytest.approx([0.1, 0.2, 0.2, 0.15, 0.1, 0.05, 0.0, 0.0])
    assert Lagrange(0.1, lr=0.5).update(0.0) == 0.0  # starting at 0 under the limit: stays at 0


def test_pid_terms_by_hand():
    pid = PIDLagrange(cost_limit=0.1, kp=2.0, ki=0.5, kd=3.0, ema=0.5, delay=2)
    # (lambda, P, I, D) after each update. EMA(J_c): 0.5, 0.25, 0.125, 0.5625; D compares with 2 updates earlier
    expected = [
        (2.85, 0.45, 0.45, 0.5),  # J=1: delta 0.9, I = 0.5 * 0.9, P = 0.5 * 0.9, D = 0.5 - 0; 2 * 0.45 + 0.45 + 3 * 0.5
        (1.5, 0.175, 0.4, 0.25),  # J=0: delta -0.1, I = 0.45 - 0.05, P = 0.225 - 0.05, D = 0.25 - 0
        (0.425, 0.0375, 0.35, 0.0),  # J=0: D = max(0, 0.125 - 0.5) = 0
        (2.675, 0.46875, 0.8, 0.3125),  # J=1: D = 0.5625 - 0.25
    ]
    for cost, (lam, p, i, d) in zip((1.0, 0.0, 0.0, 1.0), expected):
        assert pid.update(cost) == pytest.approx(lam)
        assert (pid.proportional, pid.integral, pid.derivative) == pytest.approx((p, i, d))


def test_pid_never_negative_and_its_integral_alone_is_lagrange():
    pid = PIDLagrange(cost_limit=0.1, kp=0.0, kd=0.0)
    assert all(pid.update(0.0) == 0.0 for _ in range(50))  # I held at 0, not driven to 50 x -0.01
    assert pid.integral == 0.0 and pid.update(1.0) == pytest.approx(0.09)  # so one violation counts at once
    pid = PIDLagrange(cost_limit=0.1)
    assert all(pid.update(0.0) == 0.0 for _ in range(50))  # with the default gains: P < 0, D = 0
    pid, lag = PIDLagrange(0.1, kp=0.0, ki=0.3, kd=0.0), Lagrange(0.1, lr=0.3)
    for cost in (1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0):
        assert pid.update(cost) == pytest.approx(lag.update(cost))


def test_pid_defaults_move_lambda_within_the_budget():
    # 1,000 episodes at a 20% collision rate against d = 0.05: lambda must grow to the scale of the -20
    # collision reward of Eq. (31), not stay near 0 (library gains of 1e-6 would leave plain SAC)
    pid = PIDLagrange(cost_limit=0.05)
    lam = [pid.update(float(k % 5 == 0)) for k in range(1000)]
    assert lam[99] > 1.0 and 10.0 < lam[-1] < 30.0
    safe = PIDLagrange(cost_limit=0.05)
    assert max(safe.update(0.0) for _ in range(1000)) == 0.0


# --------------------------------------------------------------------------------------
# CPO on a quadratic problem: KL(x) = 1/2 x^T H x, reward surrogate g^T x, cost surrogate c + b^T x
# --------------------------------------------------------------------------------------

H = f64(2.0, 0.5, 0.5, 1.0).reshape(2, 2)
G, B_COST, DELTA = f64(1.0, 0.5), f64(0.3, 1.0), 0.05
# TRPO's step sqrt(2 delta / q) H^-1 g raises the cost surrogate by b^T x = 0.173; the trust region reaches
# b^T x = -sqrt(2 delta s) = -0.32 at most (s = b^T H^-1 b = 1.023): |c| <= 0.32 puts the boundary inside.


def solve(g, b, c, delta=DELTA):
    Hinv = torch.linalg.inv(H)
    return cpo_direction(g, b, c, Hinv @ g, Hinv @ b, delta)


def brute_force(g, b, c, delta=DELTA, n=100_001):
    """max g^T x over the feasible points of the trust region's boundary (a linear objective on a convex
    set peaks at an extreme point, and every extreme point of ellipse-and-half-plane is on the ellipse)."""
    theta = np.linspace(0, 2 * np.pi, n)
    L = np.linalg.cholesky(H.numpy())
    x = math.sqrt(2 * delta) * np.linalg.solve(L.T, np.stack([np.cos(theta), np.sin(theta)]))
    feasible = c + b.numpy() @ x <= 0
    return (g.numpy() @ x)[feasible].max()


def kl(x):
    return 0.5 * float(x @ H @ x)


def test_conjugate_gradient_recovers_the_inverse_product():
    gen = torch.Generator().manual_seed(0)
    M = torch.randn(6, 6, generator=gen, dtype=torch.float64)
    A, g = M @ M.T + 0.5 * torch.eye(6, dtype=torch.float64), torch.randn(6, generator=gen, dtype=torch.float64)
    x = conjugate_gradient(lambda v: A @ v, g, iters=15)
    assert torch.allclose(x, torch.linalg.solve(A, g), atol=1e-8)
    # with fewer iterations than dimensions it is only an approximation, yet better than the start x = 0
    x2 = conjugate_gradient(lambda v: A @ v, g, iters=2)
    assert 1e-6 < (A @ x2 - g).norm() < g.norm()


@pytest.mark.parametrize("c, case", [(-0.3, 2), (-0.1, 2), (-0.01, 2), (0.01, 1), (0.1, 1), (0.3, 1)])
def test_cpo_step_solves_the_linearised_problem(c, case):
    for g, b in ((G, B_COST), (G, -B_COST), (f64(1.0, -0.8), B_COST)):
        x, got = solve(g, b, c)
        assert got == case
        assert kl(x) <= DELTA * (1 + 1e-6)  # inside the trust region
        assert c + float(b @ x) <= 1e-6  # the linearised constraint holds
        assert float(g @ x) == pytest.approx(brute_force(g, b, c), abs=1e-4)  # and no feasible step does better


def test_cpo_step_is_trpo_when_the_constraint_is_inactive():
    Hinv_g = torch.linalg.solve(H, G)
    trpo = math.sqrt(2 * DELTA / float(G @ Hinv_g)) * Hinv_g
    for c, case in ((-1.0, 3), (-0.3, 2)):  # B < 0; B >= 0 but TRPO's step keeps c + b^T x = -0.13 < 0
        x, got = solve(G, B_COST, c)
        assert got == case and torch.allclose(x, trpo, atol=1e-6)
    x, got = solve(G, torch.zeros(2, dtype=torch.float64), -0.1)  # a flat cost surrogate
    assert got == 4 and torch.allclose(x, trpo, atol=1e-6)


def test_cpo_infeasible_recovery_only_reduces_the_cost():
    x, case = solve(G, B_COST, 1.0)  # c = 1: the half-space lies beyond the trust region
    Hinv_b = torch.linalg.solve(H, B_COST)
    assert case == 0
    assert torch.allclose(x, -math.sqrt(2 * DELTA / float(B_COST @ Hinv_b)) * Hinv_b)
    assert float(B_COST @ x) < 0 and kl(x) == pytest.approx(DELTA)
    # the largest cost decrease the trust region allows: min b^T x = -max (-b)^T x
    assert float(B_COST @ x) == pytest.approx(-brute_force(-B_COST, B_COST, -math.inf), abs=1e-4)


def quadratic_surrogates(g, b):
    """evaluate(x) for the line search: reward gain g^T x, cost change b^T x, KL 1/2 x^T H x."""
    return lambda x: (float(g @ x), float(b @ x), kl(x))


def test_line_search_backtracks_until_the_constraint_holds():
    step = f64(0.0, 0.5)  # KL 0.125, cost change 0.5
    # c = -0.1: the cost may rise by 0.1. KL <= 0.5 holds; 0.5 * 0.8^k <= 0.1 first at k = 8 (0.8^7 = 0.21)
    x, trial = backtracking_line_search(step, quadratic_surrogates(G, B_COST), c=-0.1, delta=0.5)
    assert trial == 9 and torch.allclose(x, 0.8**8 * step)
    assert float(B_COST @ x) <= 0.1 < float(B_COST @ (x / 0.8))


def test_line_search_accepts_a_step_that_satisfies_everything_at_once():
    step = f64(0.1, -0.1)  # reward +0.05, cost -0.07, KL 0.01
    x, trial = backtracking_line_search(step, quadratic_surrogates(G, B_COST), c=-0.1, delta=0.05)
    assert trial == 1 and torch.equal(x, step)


def test_line_search_rejects_kl_and_reward_loss_and_cost_rise_when_violated():
    ev = quadratic_surrogates(G, B_COST)
    # KL: 1/2 x^T H x = 2 * 0.8^(2k) <= 0.05 first at k = 9 (0.8^18 = 0.018; 0.8^16 = 0.028 gives 0.056)
    x, trial = backtracking_line_search(f64(1.0, 0.0) * 2 ** 0.5, ev, c=-10.0, delta=0.05)
    assert trial == 10
    # feasible (c < 0): a step that lowers the reward surrogate is never accepted: no update
    x, trial = backtracking_line_search(f64(-0.1, 0.0), ev, c=-0.1, delta=0.05)
    assert trial == 0 and torch.equal(x, torch.zeros(2, dtype=torch.float64))
    # violated (c > 0): lowering the reward is allowed if the cost goes down; raising the cost is not
    x, trial = backtracking_line_search(f64(0.0, -0.1), quadratic_surrogates(f64(0.0, 1.0), B_COST), 0.1, 0.05)
    assert trial == 1
    x, trial = backtracking_line_search(f64(0.1, 0.0), ev, c=0.1, delta=0.05)
    assert trial == 0


# --------------------------------------------------------------------------------------
# Fisher-vector products and the on-policy networks
# --------------------------------------------------------------------------------------


def test_fisher_vector_product_of_a_gaussian_is_its_fisher_information():
    # KL(N(mu0, s0) || N(mu, e^log_s)): Hessian at (mu0, log s0) is diag(1 / s0^2, 2) per dimension
    mu0, s0 = f64(0.3, -1.0), f64(0.5, 2.0)
    mu, log_std = mu0.clone().requires_grad_(), s0.log().requires_grad_()

    def kl_closure():
        return kl_divergence(Normal(mu0, s0), Normal(mu, log_std.exp())).sum()

    Avp = fisher_vector_product([mu, log_std], kl_closure, damping=0.1)
    v = f64(1.0, 2.0, 3.0, 4.0)
    fisher = f64(1 / 0.25, 1 / 4.0, 2.0, 2.0)
    assert torch.allclose(Avp(v), fisher * v + 0.1 * v)
    assert torch.allclose(Avp(2 * v), 2 * (fisher * v + 0.1 * v))  # reusable: one graph, many products
    # conjugate gradients on it invert the damped Fisher matrix
    assert torch.allclose(conjugate_gradient(Avp, v), v / (fisher + 0.1), atol=1e-8)


def test_gaussian_policy_maps_to_the_bounds_it_was_given():
    torch.manual_seed(0)
    policy = GaussianPolicy(obs_dim=5, act_dim=1, low=-3.0, high=2.0)
    # u = 0 is the middle of [-3, 2]; u = +-1 its ends; beyond them the action is clipped
    assert policy.to_env(T([[0.0], [1.0], [-1.0], [4.0], [-4.0]])).flatten().tolist() == [-0.5, 2.0, -3.0, 2.0, -3.0]
    obs, u = torch.randn(7, 5), torch.randn(7, 1)
    dist = policy(obs)
    assert dist.stddev.allclose(torch.ones(7, 1))  # state-independent, e^0 at the start
    expected = -0.5 * ((u - dist.mean) ** 2 + math.log(2 * math.pi)).sum(-1)
    assert policy.log_prob(obs, u).shape == (7,) and policy.log_prob(obs, u).allclose(expected)
    # the KL's Hessian in the log std alone is 2 I: the Fisher product seen through the real policy
    old = Normal(dist.mean.detach(), dist.stddev.detach())
    Avp = fisher_vector_product([policy.log_std], lambda: kl_divergence(old, policy(obs)).sum(-1).mean(), 0.0)
    assert Avp(T([3.0])).item() == pytest.approx(6.0)
    assert value_net(5)(obs).shape == (7,)


# --------------------------------------------------------------------------------------
# SAC-Lag's losses by hand
# --------------------------------------------------------------------------------------

SMALL_SAC = tarl.SACConfig(batch_size=32, buffer_size=5_000, learning_starts=100, hidden=32)


def sac_lag_agent(lam: float) -> tuple[ConstrainedSAC, dict]:
    torch.manual_seed(0)
    agent = ConstrainedSAC(5, 1, -3.0, 2.0, SMALL_SAC, CostConstraint(0.05, 10, Lagrange(0.05, init=lam)))
    with torch.no_grad():  # the target critics apart from the online ones, and a temperature that is not 1
        for p in (*agent.critic_target.parameters(), *agent.cost_critic_target.parameters()):
            p.add_(0.1 * torch.randn_like(p))
        agent.log_alpha.fill_(math.log(0.3))
    B = 8
    batch = {"obs": torch.randn(B, 5), "act": torch.rand(B, 1) * 5 - 3, "rew": torch.randn(B),
             "cost": (torch.arange(B) % 3 == 0).float(), "discount": torch.full((B,), 0.99),
             "done": (torch.arange(B) % 4 == 0).float(), "next_obs": torch.randn(B, 5)}
    return agent, batch


def test_sac_lag_policy_loss_is_the_lagrangian_over_one_plus_lambda():
    agent, batch = sac_lag_agent(lam=3.0)
    torch.manual_seed(1)
    losses = agent.losses(batch)
    # by hand, with the same draws in the same order: a' of the reward target, a ~ pi(.|s), a' of the cost target
    torch.manual_seed(1)
    agent.squashed_gaussian(batch["next_obs"])
    a, log_pi = agent.squashed_gaussian(batch["obs"])
    q_r = agent.critic(batch["obs"], a).amin(0).squeeze(-1)  # min of the twin reward critics
    q_c = agent.cost_critic(batch["obs"], a).amax(0).squeeze(-1)  # max of the twin cost critics
    expected = ((0.3 * log_pi - q_r + 3.0 * q_c) / (1 + 3.0)).mean()
    assert losses["policy_loss"].item() == pytest.approx(expected.item(), rel=1e-5)
    # lambda = 0 is plain SAC's loss; the critics are frozen in it: no gradient reaches Q_r or Q_c
    agent.constraint.multiplier.value = 0.0
    torch.manual_seed(1)
    plain = agent.losses(batch)["policy_loss"]
    assert plain.item() == pytest.approx((0.3 * log_pi - q_r).mean().item(), rel=1e-5)
    plain.backward()
    assert all(p.grad is None for p in (*agent.critic.parameters(), *agent.cost_critic.parameters()))
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in agent.policy.parameters())


def test_the_cost_target_has_no_entropy_term():
    agent, batch = sac_lag_agent(lam=1.0)
    torch.manual_seed(2)
    y = cost_td_target(agent, batch)
    torch.manual_seed(2)
    a_next, _ = agent.squashed_gaussian(batch["next_obs"])
    q_next = agent.cost_critic_target(batch["next_obs"], a_next).amax(0).squeeze(-1)
    assert torch.allclose(y, batch["cost"] + 0.99 * (1 - batch["done"]) * q_next)
    assert torch.equal(y[batch["done"] == 1], batch["cost"][batch["done"] == 1])  # a terminal: the cost alone
    # whatever the temperature: alpha moves the reward target (tarl.td_target), not the cost target
    for log_alpha in (math.log(0.3), 2.0):
        with torch.no_grad():
            agent.log_alpha.fill_(log_alpha)
        torch.manual_seed(2)
        assert torch.equal(cost_td_target(agent, batch), y)
    torch.manual_seed(2)
    hot = tarl.td_target(agent, batch)
    with torch.no_grad():
        agent.log_alpha.fill_(math.log(0.3))
    torch.manual_seed(2)
    assert not torch.allclose(hot, tarl.td_target(agent, batch))
    # the cost critics' loss: both heads regress on y
    torch.manual_seed(1)
    losses = agent.losses(batch)
    torch.manual_seed(1)
    agent.squashed_gaussian(batch["next_obs"])
    agent.squashed_gaussian(batch["obs"])
    y = cost_td_target(agent, batch)
    q_c = agent.cost_critic(batch["obs"], batch["act"]).squeeze(-1)
    assert losses["cost_critic_loss"].item() == pytest.approx(((q_c - y) ** 2).mean(-1).sum().item(), rel=1e-5)


def test_cost_constraint_state_round_trips_through_a_plain_checkpoint(tmp_path):
    pid = CostConstraint(0.05, 3, PIDLagrange(0.05))
    for step, cost in enumerate((1.0, 0.0, 0.0, 1.0, 1.0)):
        pid.episodes.append((cost, 100))
        pid.update(step)
    assert pid.cost == pytest.approx(2 / 3)  # the window holds the last 3 episodes
    torch.save(pid.state_dict(), tmp_path / "c.pt")
    fresh = CostConstraint(0.05, 3, PIDLagrange(0.05))
    fresh.load_state_dict(torch.load(tmp_path / "c.pt", weights_only=True))
    assert fresh.history == pid.history and fresh.cost == pid.cost
    assert fresh.update(5) == pid.update(5) > 0  # the PID's EMAs and delay line came back too


# --------------------------------------------------------------------------------------
# Short training runs on the real simulator: updates, lambda, checkpoints
# --------------------------------------------------------------------------------------

# d < 0 is a limit no policy meets: lambda must rise at every update of so short a run
SMALL_SAFE = SafeRLConfig(cost_limit=-0.5, rollout=128, epochs=2, minibatch=32, hidden=16)
SMALL_TRAIN = tarl.TrainConfig(steps=384, n_actor=15, log_every=10**9, checkpoint_every=10**9)
OBS = np.random.default_rng(0).uniform(0, 1, (6, world.OBS_DIM)).astype(np.float32)


@pytest.fixture(autouse=True, scope="module")
def one_thread():  # small networks: one torch thread is as fast, and never stalls when other processes share the cores
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def env():
    env = world.DrivingEnv(world.EnvConfig(scenario="intersection"))
    yield env
    env.close()


def trainer(algo, env, out=None, seed=1):
    if algo in ("sac-lag", "sac-pid"):
        return SafeSACTrainer(env, algo, SMALL_TRAIN, SMALL_SAC, seed, out, log=lambda *a: None, cfg=SMALL_SAFE)
    return OnPolicyTrainer(env, algo, SMALL_TRAIN, None, seed, out, log=lambda *a: None, cfg=SMALL_SAFE)


@pytest.mark.parametrize("algo", ["sac-lag", "sac-pid", "ppo-lag", "cpo"])
def test_a_short_run_updates_and_its_checkpoint_acts_the_same(algo, env, tmp_path):
    t = trainer(algo, env, tmp_path)
    constraint, policy = t.constraint, t.actor.policy  # the policy network of ConstrainedSAC or OnPolicyAgent
    before = [p.detach().clone() for p in policy.parameters()]
    t.run()
    assert t.step >= SMALL_TRAIN.steps and (algo.startswith("sac") or t.step == SMALL_TRAIN.steps)
    assert any(not torch.equal(a, b) for a, b in zip(before, policy.parameters()))  # the policy learned
    history = constraint.history
    if algo == "cpo":  # one CPO step per rollout of 128 steps: 3, each with its case and line-search trial
        assert [row[0] for row in history] == [128, 256, 384]
        assert all(case in range(5) and 0 <= trial <= SMALL_SAFE.search_steps for _, _, case, trial in history)
        assert any(trial > 0 for *_, trial in history)
    else:  # lambda: SAC once per finished episode, PPO-Lag once per rollout; J_c > d, so it rose every time
        assert len(history) == (len(constraint.episodes) if algo.startswith("sac") else 3) > 0
        lams = [lam for *_, lam in history]
        assert lams[0] > 0 and all(b > a for a, b in zip(lams, lams[1:]))
        if algo != "sac-pid":  # Lagrange: lambda_k = lambda_{k-1} + lr (J_c - d), J_c >= 0
            lr = SMALL_SAFE.lagrange_lr if algo == "sac-lag" else SMALL_SAFE.rollout_lagrange_lr
            expected = np.cumsum([lr * (j + 0.5) for _, j, _ in history])
            assert lams == pytest.approx(expected.tolist(), abs=1e-3)
        assert constraint.multiplier.value == pytest.approx(lams[-1], abs=1e-4)
    # the files: train_log.csv (one row per episode), constraint_log.csv, ckpt.pt and a small policy.pt
    log = (tmp_path / "train_log.csv").read_text().splitlines()
    assert log[0] == ",".join(tarl.LOG_HEADER) and {row.split(",")[1] for row in log[1:]} == {"real"}
    collisions = sum(int(row.split(",")[4]) for row in log[1:])
    assert sum(c for c, _ in constraint.episodes) == collisions  # the window (50 episodes) saw every one
    if algo.startswith("sac"):  # D_a's cost column: 1 at each collision step
        assert t.D_a.data["cost"][: len(t.D_a)].sum() == collisions and len(t.D_a) == t.step
    assert len((tmp_path / "constraint_log.csv").read_text().splitlines()) == len(history) + 1
    assert (tmp_path / "policy.pt").stat().st_size < 1e6
    # ckpt.pt loads into a fresh trainer that acts, and constrains, the same; policy.pt acts the same
    expected = t.driver.actor.act(OBS, True)
    fresh = trainer(algo, env, seed=2)
    fresh.load(experiment.load_checkpoint(tmp_path / "ckpt.pt", "intersection", algo), resume=True)
    np.testing.assert_array_equal(fresh.driver.actor.act(OBS, True), expected)
    assert fresh.step == t.step and fresh.constraint.history == history and fresh.constraint.cost == constraint.cost
    assert fresh.constraint.multiplier is None or vars(fresh.constraint.multiplier) == vars(constraint.multiplier)
    only_policy = trainer(algo, env, seed=3)
    only_policy.load(experiment.load_checkpoint(tmp_path / "policy.pt", "intersection", algo), resume=False)
    np.testing.assert_array_equal(only_policy.driver.actor.act(OBS, True), expected)
    # the Driver of the row acts with it: the env's action, in the ego's limits
    row, = experiment.trained_rows(t)
    a, T, b = row["driver"].act(OBS[0], env, deterministic=True)
    assert row["algo"] == algo and row["train_steps"] == t.step and T is None and b == 1.0
    assert a.shape == (1,) and env.cfg.a_min <= a[0] <= env.cfg.a_max


@pytest.mark.parametrize("algo, cls", [("sac-lag", SafeSACTrainer), ("sac-pid", SafeSACTrainer),
                                       ("ppo-lag", OnPolicyTrainer), ("cpo", OnPolicyTrainer)])
def test_the_experiment_builds_the_safe_rows_from_its_table(algo, cls, env):
    t = experiment.make_trainer(algo, env, SMALL_TRAIN, seed=0, out=None, log=lambda *a: None)
    assert type(t) is cls and t.algo == algo and t.step == 0
    multiplier = t.constraint.multiplier
    assert t.constraint.cost_limit == SafeRLConfig().cost_limit  # the same d for the four rows
    assert type(multiplier).__name__ == {"sac-lag": "Lagrange", "sac-pid": "PIDLagrange",
                                         "ppo-lag": "Lagrange", "cpo": "NoneType"}[algo]
