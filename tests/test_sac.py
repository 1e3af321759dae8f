"""Tests of tarl's SAC: the actor's and the timing taker's SAC (Section 4, Eqs. (9), (10), (13), (14)).

Run: python -m pytest -q tests/test_sac.py
"""
import math

import numpy as np
import pytest
import torch

from tarl import SAC, ReplayBuffer, SACConfig, critic_loss, policy_loss, td_target, temperature_loss

from plain_sac import PlainSAC  # noqa: E402  (the plain reference SAC, bench/speed.py's too)

OBS_DIM, T_MAX, LOW, HIGH, B = 67, 10, -3.0, 2.0, 32  # sizes of the paper; [m/s^2] bounds of the actor
CFG = SACConfig(hidden=64)  # smaller than Table 2's 256 to keep the tests fast; the code is size-agnostic


def actor(cfg=CFG):
    return SAC(OBS_DIM, act_dim=1, low=LOW, high=HIGH, cfg=cfg)


def timing_taker(cfg=CFG):
    return SAC(OBS_DIM + 1, n_actions=T_MAX, cfg=cfg)  # input (s, a), Eq. (5)


def random_batch(agent, batch_size=B, seed=0):
    """A batch as ReplayBuffer.sample gives it: discount gamma^T for the timing taker, gamma for the actor."""
    g = torch.Generator().manual_seed(seed)
    obs_dim = agent.policy[0].in_features
    if agent.discrete:
        act = torch.randint(1, agent.n_actions + 1, (batch_size,), generator=g)
        discount = agent.cfg.gamma ** act.float()
    else:
        act = LOW + (HIGH - LOW) * torch.rand(batch_size, agent.act_dim, generator=g)
        discount = torch.full((batch_size,), agent.cfg.gamma)
    return {"obs": torch.randn(batch_size, obs_dim, generator=g), "act": act,
            "rew": torch.randn(batch_size, generator=g), "next_obs": torch.randn(batch_size, obs_dim, generator=g),
            "discount": discount, "done": (torch.rand(batch_size, generator=g) < 0.3).float()}


def trained(agent, n=5):
    """A few updates so that target critics differ from the online ones and Adam has state."""
    for i in range(n):
        agent.update(random_batch(agent, seed=100 + i))
    with torch.no_grad():
        agent.log_alpha.fill_(math.log(0.3))  # a temperature away from 1, so that alpha terms matter
    return agent


@pytest.mark.parametrize("make", [actor, timing_taker])
def test_update_lowers_critic_loss_on_a_fixed_batch(make):
    torch.manual_seed(0)
    agent, batch = make(), random_batch(make())

    def loss():
        torch.manual_seed(1)  # the same next-action sample each time
        return critic_loss(agent, batch)[0].item()

    before = loss()
    agent.update(batch)
    assert loss() < before
    for _ in range(19):
        agent.update(batch)
    assert loss() < 0.85 * before  # about 0.75 (actor) and 0.83 (timing taker) with lr 3e-4


def test_timing_distribution_is_a_distribution_over_T():
    torch.manual_seed(0)
    agent = timing_taker()
    probs, _ = agent.timing_distribution(3 * torch.randn(B, OBS_DIM + 1))
    assert probs.shape == (B, T_MAX)
    timings = agent.act(np.random.default_rng(0).normal(size=(2000, OBS_DIM + 1)))
    assert timings.dtype.kind == "i" and timings.min() >= 1 and timings.max() <= T_MAX
    repeated = agent.act(np.ones((2000, OBS_DIM + 1)))  # one (s, a), sampled 2000 times
    assert len(np.unique(repeated)) > 1 and set(np.unique(repeated)) <= set(range(1, T_MAX + 1))
    single = agent.act(np.zeros(OBS_DIM + 1, np.float32))
    assert isinstance(single, int) and 1 <= single <= T_MAX
    greedy = agent.act(np.zeros((1, OBS_DIM + 1)), deterministic=True)  # the most probable T (column T - 1)
    assert greedy[0] == int(agent.timing_distribution(torch.zeros(1, OBS_DIM + 1))[0].argmax()) + 1


def test_timing_taker_target_discounts_by_gamma_to_the_T():
    torch.manual_seed(0)
    agent = trained(timing_taker())
    gamma = agent.cfg.gamma
    timings = torch.tensor([1, 3, 10, 3])
    batch = random_batch(agent, batch_size=4)
    batch.update(act=timings, discount=gamma ** timings.float(), rew=torch.tensor([1.0, -2.0, 0.5, 20.0]),
                 done=torch.tensor([0.0, 0.0, 0.0, 1.0]))
    with torch.no_grad():
        q_next = agent.critic_target(batch["next_obs"])  # (2, 4, T_max)
        probs, log_probs = agent.timing_distribution(batch["next_obs"])
    alpha = math.exp(agent.log_alpha.item())
    expected = []
    for i, T in enumerate(timings.tolist()):
        v = sum(probs[i, j] * (min(q_next[0, i, j], q_next[1, i, j]) - alpha * log_probs[i, j])
                for j in range(T_MAX))
        expected.append(batch["rew"][i] + gamma**T * (1 - batch["done"][i]) * v)
    torch.testing.assert_close(td_target(agent, batch), torch.stack(expected))
    # and the discount really is per-sample: with gamma^1 everywhere the target changes
    flat = dict(batch, discount=torch.full((4,), gamma))
    assert not torch.allclose(td_target(agent, flat)[1:3], td_target(agent, batch)[1:3])


def test_continuous_losses_equal_a_straightforward_computation():
    torch.manual_seed(0)
    agent = trained(actor())
    batch = random_batch(agent)
    plain = PlainSAC.from_sac(agent, torch.float64)  # separate nn.Sequential critics, the textbook Jacobian
    with torch.no_grad():
        torch.manual_seed(1)
        expected_critic = plain.critic_loss(plain.cast(batch))
        torch.manual_seed(2)
        expected_policy, log_prob, _ = plain.policy_loss(plain.cast(batch)["obs"])
        expected_temperature = plain.temperature_loss(log_prob)
    torch.manual_seed(1)
    got_critic = critic_loss(agent, batch)[0]
    torch.manual_seed(2)
    got_policy, entropy = policy_loss(agent, batch["obs"])
    got_temperature = temperature_loss(agent.log_alpha, entropy, agent.target_entropy)
    for got, expected in [(got_critic, expected_critic), (got_policy, expected_policy),
                          (got_temperature, expected_temperature)]:
        assert got.item() == pytest.approx(expected.item(), rel=1e-5, abs=1e-5)


def test_discrete_losses_equal_a_straightforward_computation():
    torch.manual_seed(0)
    agent = trained(timing_taker())
    batch = random_batch(agent)
    plain = PlainSAC.from_sac(agent, torch.float64)
    with torch.no_grad():
        expected_critic = plain.critic_loss(plain.cast(batch))
        expected_policy, log_probs, probs = plain.policy_loss(plain.cast(batch)["obs"])
        expected_temperature = plain.temperature_loss(log_probs, probs)
    got_critic, q = critic_loss(agent, batch)
    for q_obs in (None, q.detach()):  # computed afresh, or reused from the critic's forward pass as in update
        got_policy, entropy = policy_loss(agent, batch["obs"], q_obs)
        got_temperature = temperature_loss(agent.log_alpha, entropy, agent.target_entropy)
        for got, expected in [(got_critic, expected_critic), (got_policy, expected_policy),
                              (got_temperature, expected_temperature)]:
            assert got.item() == pytest.approx(expected.item(), rel=1e-5, abs=1e-5)


@pytest.mark.parametrize("make", [actor, timing_taker])
def test_updates_equal_the_plain_reference_updates(make):
    """tarl.SAC.update (twin critic batched, one fused Adam, one backward of the summed losses) against
    bench/plain_sac.py's (separate critics and Adams, critic step first): five updates from the same weights."""
    torch.manual_seed(0)
    agent = make()
    with torch.no_grad():
        agent.log_alpha.fill_(math.log(0.3))  # a temperature away from 1, so that alpha terms matter
    plain, start = PlainSAC.from_sac(agent, torch.float32), PlainSAC.from_sac(agent, torch.float32)
    for i in range(5):
        batch = random_batch(agent, seed=100 + i)
        torch.manual_seed(10 + i)  # the same a' and a samples in both
        logs = agent.update(batch)
        torch.manual_seed(10 + i)
        expected = [float(logs[k]) for k in ("critic_loss", "policy_loss", "temperature_loss")]
        assert list(plain.update(batch)) == pytest.approx(expected, rel=1e-5, abs=1e-5)
    moved = PlainSAC.from_sac(agent, torch.float32)  # tarl's weights after the updates, laid out as plain's
    for net in ("actor", "qf1", "qf2", "qf1_target", "qf2_target"):  # steps of ~lr = 3e-4; tau moves targets less
        atol = 1e-6 if net.endswith("target") else 1e-5
        for got, expected, before in zip(*(getattr(x, net).parameters() for x in (moved, plain, start))):
            torch.testing.assert_close(got, expected, rtol=0, atol=atol)
        assert max((got - before).abs().max() for got, before in zip(*(getattr(x, net).parameters()
                                                                        for x in (moved, start)))) > 10 * atol
    torch.testing.assert_close(moved.log_alpha, plain.log_alpha, rtol=0, atol=1e-5)
    assert abs(moved.log_alpha.item() - math.log(0.3)) > 1e-3


@pytest.mark.parametrize("make", [actor, timing_taker])
def test_policy_loss_leaves_critics_untouched_and_targets_never_train(make):
    torch.manual_seed(0)
    agent = trained(make())
    batch = random_batch(agent)
    agent.optimizer.zero_grad(set_to_none=True)
    policy_loss(agent, batch["obs"])[0].backward()
    assert all(p.grad is None for p in agent.critic.parameters())
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in agent.policy.parameters())

    optimised = {id(p) for group in agent.optimizer.param_groups for p in group["params"]}
    assert not any(p.requires_grad or id(p) in optimised for p in agent.critic_target.parameters())
    with torch.no_grad():  # move the targets well away from the online critics, so that tau is visible
        for p in agent.critic_target.parameters():
            p.add_(torch.randn_like(p))
    before = [p.clone() for p in agent.critic_target.parameters()]
    agent.update(batch)
    tau = agent.cfg.tau  # Table 2: Q-hat <- (1 - tau) Q-hat + tau Q
    for old, new, online in zip(before, agent.critic_target.parameters(), agent.critic.parameters()):
        torch.testing.assert_close(new, (1 - tau) * old + tau * online)


def test_temperature_falls_when_entropy_exceeds_its_target():
    log_alpha = torch.tensor(0.0, requires_grad=True)
    temperature_loss(log_alpha, torch.full((8,), 1.5), target_entropy=-1.0).backward()
    assert log_alpha.grad.item() == pytest.approx(2.5)  # gradient descent lowers log alpha
    agent = timing_taker()
    assert agent.target_entropy == pytest.approx(CFG.target_entropy_fraction * math.log(T_MAX))
    assert 0 < agent.target_entropy < math.log(T_MAX) and actor().target_entropy == -1.0


def test_continuous_actions_lie_within_per_dimension_bounds():
    torch.manual_seed(0)
    low, high = np.array([-3.0, -1.0], np.float32), np.array([2.0, 0.5], np.float32)
    agent = SAC(OBS_DIM, act_dim=2, low=low, high=high, cfg=CFG)
    obs = 100 * np.random.default_rng(0).normal(size=(4000, OBS_DIM))  # saturates the tanh
    for deterministic in (False, True):
        a = agent.act(obs, deterministic)
        assert a.shape == (4000, 2) and (a >= low).all() and (a <= high).all()
        # the bounds are reached, so the squashing is rescaled to [low, high], not left in [-1, 1]
        assert (a.min(0) < low + 0.05 * (high - low)).all() and (a.max(0) > high - 0.05 * (high - low)).all()
    assert agent.act(obs[0]).shape == (2,)


def test_squashed_gaussian_log_prob_matches_a_histogram_of_its_samples():
    torch.manual_seed(0)
    agent = actor()
    with torch.no_grad():  # every obs -> mu = 0.5, log sigma = 0: actions spread over all of [LOW, HIGH]
        agent.policy[-1].weight.zero_()
        agent.policy[-1].bias.copy_(torch.tensor([0.5, 0.0]))
        a, log_prob = agent.squashed_gaussian(torch.zeros(400_000, OBS_DIM))
    a, density = a.squeeze(1).numpy(), log_prob.exp().numpy()
    edges = np.linspace(LOW, HIGH, 26)
    counts, _ = np.histogram(a, edges)
    bins = np.digitize(a, edges) - 1
    for i in range(1, len(counts) - 1):  # the end bins hold the density's steep fall to 0 at the bounds
        empirical = counts[i] / (len(a) * (edges[1] - edges[0]))
        assert density[bins == i].mean() == pytest.approx(empirical, rel=0.05)


@pytest.mark.parametrize("make", [actor, timing_taker])
def test_state_dict_round_trip_gives_identical_actions(make, tmp_path):
    torch.manual_seed(0)
    agent = trained(make())
    torch.save(agent.state_dict(), tmp_path / "agent.pt")
    torch.manual_seed(1)
    clone = make()
    clone.load_state_dict(torch.load(tmp_path / "agent.pt", weights_only=True))
    obs = np.random.default_rng(0).normal(size=(64, clone.policy[0].in_features)).astype(np.float32)
    np.testing.assert_array_equal(agent.act(obs, deterministic=True), clone.act(obs, deterministic=True))
    torch.manual_seed(2)
    sampled = agent.act(obs)
    torch.manual_seed(2)
    np.testing.assert_array_equal(sampled, clone.act(obs))
    batch = random_batch(agent, seed=7)  # optimizer state came along: the next update is identical too
    torch.manual_seed(3)
    logs = agent.update(batch)
    torch.manual_seed(3)
    assert {k: float(v) for k, v in clone.update(batch).items()} == {k: float(v) for k, v in logs.items()}


def test_replay_buffer_stores_overwrites_samples_and_checkpoints(tmp_path):
    buffer = ReplayBuffer(5, obs_dim=3, act_shape=(), act_dtype=np.int64)  # the timing taker's T
    for i in range(7):
        buffer.add(np.full(3, i), i % T_MAX + 1, float(i), np.full(3, i + 1), 0.99 ** (i % T_MAX + 1), i == 6)
    assert len(buffer) == 5
    assert sorted(buffer.data["rew"].tolist()) == [2.0, 3.0, 4.0, 5.0, 6.0]  # the two oldest were overwritten
    batch = buffer.sample(64, np.random.default_rng(0))
    assert batch["obs"].shape == (64, 3) and batch["obs"].dtype == torch.float32
    assert batch["act"].shape == (64,) and batch["act"].dtype == torch.int64
    torch.testing.assert_close(batch["next_obs"][:, 0], batch["obs"][:, 0] + 1)
    torch.testing.assert_close(batch["discount"], 0.99 ** batch["act"].float())
    torch.testing.assert_close(batch["done"], (batch["rew"] == 6).float())

    partial = ReplayBuffer(100, obs_dim=3)  # the actor's: act (1,) float32
    for i in range(4):
        partial.add(np.full(3, i), [i / 10], float(i), np.full(3, i + 1), 0.99, False)
    torch.save(partial.state_dict(), tmp_path / "buffer.pt")
    state = torch.load(tmp_path / "buffer.pt", weights_only=True)
    assert state["obs"].shape == (4, 3)  # only the filled part is saved
    restored = ReplayBuffer(100, obs_dim=3)
    restored.load_state_dict(state)
    assert len(restored) == 4
    a, b = partial.sample(16, np.random.default_rng(1)), restored.sample(16, np.random.default_rng(1))
    for key in a:
        torch.testing.assert_close(a[key], b[key])
