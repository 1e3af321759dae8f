"""Tests of tarl.py: the timing math by hand, Algorithm 1's buffers and blend on the real simulator."""

import os
import subprocess
import sys

import numpy as np
import pytest

import planner
import tarl
import world
from tarl import SACConfig, TimingConfig, TrainConfig
from world import EnvConfig

W = TimingConfig().omega  # w of Eq. (6)

SMALL_SAC = SACConfig(batch_size=32, buffer_size=5_000, learning_starts=50, hidden=32)
SMALL = TrainConfig(steps=400, sac_fraction=0.3, n_timing=5, n_actor=15, timing_pretrain=0.05,
                    timing_learning_starts=10, log_every=10**9, checkpoint_every=10**9)


# ---- Eqs. (6), (7), (11), (12): timing ------------------------------------------------------

def test_beta_boundary_values():
    T = np.arange(1, 50)
    np.testing.assert_allclose(tarl.beta(T, T, omega=W), 1.0)  # dt = T: the actor's action in full
    np.testing.assert_allclose(tarl.beta(T, 0, omega=W), 0.0)  # dt = 0: the base action
    assert tarl.beta(1, omega=W) == pytest.approx(1.0) and tarl.beta(2, omega=W) == pytest.approx(0.5)
    for omega in (1.0, 3.0, 10.0):  # whatever w is
        assert tarl.beta(2, omega=omega) == pytest.approx(0.5)
    b = tarl.beta(T, omega=W)
    assert np.all(np.diff(b) < 0)  # strictly decreasing in T
    assert 0.05 < tarl.beta(3, omega=W) < 0.5 and tarl.beta(4, omega=W) < 0.05  # intermediate at 3, near 0 from 4 (Sec. 4)
    assert tarl.beta(10_000, omega=W) < 1e-3  # tends to 0


def test_beta_within_a_timing_rises_to_one():
    b = tarl.beta(5, np.arange(1, 6), omega=W)
    assert np.all(np.diff(b) > 0) and b[-1] == pytest.approx(1.0)


def test_blend_at_beta_one_and_zero():
    assert tarl.blend(1.5, -2.0, 1.0) == 1.5  # Eq. (12), beta = 1: the actor's action
    assert tarl.blend(1.5, -2.0, 0.0) == -2.0  # beta = 0: the base action
    assert tarl.blend(1.0, -1.0, tarl.beta(2, omega=W)) == pytest.approx(0.0)


def test_discounted_sum_is_eq_8_by_hand():
    assert tarl.discounted_sum([1.0, 2.0, 3.0], 0.9) == pytest.approx(1.0 + 0.9 * 2.0 + 0.81 * 3.0)
    assert tarl.discounted_sum([0.5], 0.99) == 0.5  # T = 1: the step reward itself


def test_timing_input_carries_the_action_scaled():
    x = tarl.timing_input(np.zeros(world.OBS_DIM, np.float32), np.array([2.0]), EnvConfig())
    assert x.shape == (world.OBS_DIM + 1,) and x[-1] == 1.0
    assert tarl.timing_input(np.zeros(world.OBS_DIM), np.array([-3.0]), EnvConfig())[-1] == -1.0


def test_an_action_bound_changed_in_its_one_home_reaches_the_planner_the_actor_and_eq_5():
    cfg = EnvConfig(scenario="intersection", a_min=-4.0, a_max=1.5)
    env = world.DrivingEnv(cfg)
    assert (env.action_space.low[0], env.action_space.high[0]) == (-4.0, 1.5)
    assert (env.planner_cfg.a_min, env.planner_cfg.a_max) == (-4.0, 1.5)
    trainer = tarl.Trainer(env, "tarl", SMALL, SMALL_SAC, log=lambda *a: None)
    low = float(trainer.actor.action_bias - trainer.actor.action_scale)
    high = float(trainer.actor.action_bias + trainer.actor.action_scale)
    assert (low, high) == (-4.0, 1.5)
    assert tarl.timing_input(np.zeros(world.OBS_DIM), np.array([-4.0]), cfg)[-1] == -1.0  # Eq. (5)
    # the planner's emergency brake: a stopped car 1 m ahead of the ego at 10 m/s
    path_s, path_xy = np.array([0.0, 200.0]), np.array([[0.0, 0.0], [200.0, 0.0]])
    others = np.array([[56.0, 0.0, 0.0, 0.0, 0.0]])
    assert planner.base_action(50.0, 10.0, 0.0, path_s, path_xy, others, env.planner_cfg)[0] == -4.0


def record_calls(obj, name: str) -> list:
    """Wrap obj.name so that every value it returns is also appended to the returned list (del obj.name undoes it)."""
    calls, method = [], getattr(obj, name)
    setattr(obj, name, lambda *args, **kw: calls.append(method(*args, **kw)) or calls[-1])
    return calls


class Recorder:
    """The environment, with every executed action, the base action before it and the reward recorded."""

    def __init__(self, env):
        self.env, self.steps = env, []

    def __getattr__(self, name):
        return getattr(self.env, name)

    def step(self, a_bar):
        a_base = self.env.base_action()
        out = self.env.step(a_bar)
        self.steps.append((a_bar, a_base, out[1], out[2] or out[3]))
        return out


@pytest.fixture(scope="module")
def trainer():
    env = world.DrivingEnv(EnvConfig(scenario="intersection"))
    trainer = tarl.Trainer(Recorder(env), "tarl", SMALL, SMALL_SAC, seed=3, log=lambda *a: None)
    trainer.obs, _ = trainer.env.reset(seed=3)
    yield trainer
    env.close()


def test_the_real_loop_executes_eq_12_and_stores_the_actors_action_with_the_blended_reward(trainer):
    proposals = record_calls(trainer.driver, "act")
    trainer.env.steps.clear()
    start = len(trainer.D_a)
    trainer.actor_loop(trainer.driver, "real")
    del trainer.driver.act
    assert len(proposals) == len(trainer.env.steps) == len(trainer.D_a) - start >= SMALL.n_actor
    for i, ((a, T, b), (a_bar, a_base, r, _)) in enumerate(zip(proposals, trainer.env.steps)):
        assert 1 <= T <= SMALL.timing.t_max and b == pytest.approx(float(tarl.beta(T, omega=W)))
        assert a_bar == pytest.approx(tarl.blend(a[0], a_base, tarl.beta(T, omega=W)), abs=1e-12)  # Eq. (12)
        # Alg. 1 line 21: a_t as the actor proposed it, with the reward of the executed a_bar_t
        assert trainer.D_a.data["act"][start + i, 0] == pytest.approx(a[0])
        assert trainer.D_a.data["rew"][start + i] == pytest.approx(r)
        assert trainer.D_a.data["discount"][start + i] == pytest.approx(SMALL_SAC.gamma)


def test_the_timing_buffer_holds_r_T_and_gamma_to_the_T(trainer):
    timings = record_calls(trainer.timing_taker, "act")
    trainer.env.steps.clear()
    start = len(trainer.D_T)
    trainer.imagination_loop()
    del trainer.timing_taker.act
    assert len(timings) == len(trainer.D_T) - start >= SMALL.n_timing
    steps, gamma = iter(trainer.env.steps), SMALL_SAC.gamma
    for i, T in enumerate(timings):
        rewards = []
        for dt in range(1, T + 1):
            a_bar, a_base, r, done = next(steps)
            rewards.append(r)
            if done:
                break
        k = len(rewards)  # T, or fewer where the episode ended
        assert trainer.D_T.data["act"][start + i] == T
        assert trainer.D_T.data["rew"][start + i] == pytest.approx(sum(gamma**j * r for j, r in enumerate(rewards)))
        assert trainer.D_T.data["discount"][start + i] == pytest.approx(gamma**k)  # Eq. (9): gamma^T
    assert next(steps, None) is None


def test_torch_threads_wait_passively_unless_the_user_says_otherwise():
    """Spinning OpenMP threads beside another busy process made training ~40x slower (results/LOG.md, "Speed")."""
    show = "import tarl, os; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # the repository's root
    assert subprocess.run([sys.executable, "-c", show], env=env, cwd=here, capture_output=True,
                          text=True).stdout.strip() == "PASSIVE"
    assert subprocess.run([sys.executable, "-c", show], env=env | {"OMP_WAIT_POLICY": "ACTIVE"}, cwd=here,
                          capture_output=True, text=True).stdout.strip() == "ACTIVE"


# ---- w and T_max: one home, read when acting (also in an evaluation worker) ---------------------

class Fixed:
    """An actor that always proposes the same acceleration."""

    def __init__(self, a):
        self.a = np.array([a])

    def act(self, obs, deterministic=False):
        return self.a


def test_w_changed_in_its_home_changes_the_executed_blend_here_and_in_an_evaluation_worker():
    import experiment
    env = world.DrivingEnv(EnvConfig(scenario="intersection"))
    try:
        obs, _ = env.reset(seed=1)
        for omega in (2.0, 20.0):
            driver = tarl.Driver("fixed", Fixed(1.0), fixed_T=3, timing_cfg=TimingConfig(omega=omega))
            assert driver.act(obs, env)[2] == pytest.approx(float(tarl.beta(3, omega=omega)))
        rows = lambda omega: [dict(algo="tarl-fixed-t", driver=tarl.Driver(  # noqa: E731
            "fixed", Fixed(1.0), fixed_T=3, timing_cfg=TimingConfig(omega=omega)))]
        here = experiment.evaluate(env.cfg, rows(W), rounds=1, cases=2, seed=0, workers=0, env=env, log=lambda *a: None)
    finally:
        env.close()
    for omega in (W, 0.5):  # what an evaluation worker executes: beta(3) of this w on every step
        there = experiment.evaluate(env.cfg, rows(omega), rounds=1, cases=2, seed=0, workers=1, log=lambda *a: None)
        assert there[0]["beta_minus"]["all_steps"] == pytest.approx(1.0 - float(tarl.beta(3, omega=omega)))
    assert 1.0 - float(tarl.beta(3, omega=0.5)) < 0.75 < 1.0 - float(tarl.beta(3, omega=W))
    there = experiment.evaluate(env.cfg, rows(W), rounds=1, cases=2, seed=0, workers=1, log=lambda *a: None)
    assert there[0]["cases"] == here[0]["cases"]  # a round is the same wherever it runs


def test_t_max_changed_in_its_home_sizes_the_timing_taker_and_bounds_random_timings():
    env = world.DrivingEnv(EnvConfig(scenario="intersection"))
    trainer = tarl.Trainer(env, "tarl", TrainConfig(steps=400, timing=TimingConfig(t_max=4)), SMALL_SAC, log=lambda *a: None)
    assert trainer.timing_taker.n_actions == 4 and trainer.driver.timing_cfg.t_max == 4
    driver = tarl.Driver("random", Fixed(0.0), timing_cfg=TimingConfig(t_max=3))
    obs, _ = env.reset(seed=2)
    assert {driver.act(obs, env)[1] for _ in range(200)} == {1, 2, 3}
    env.close()


# ---- tarl-consistent (beyond the paper): the real loop executes Eq. (7) as the imagination does ------

def test_the_phased_driver_holds_a_t_over_T_steps_by_eq_7_then_decides_again():
    env = world.DrivingEnv(EnvConfig(scenario="intersection"))
    trainer = tarl.Trainer(env, "tarl-consistent", SMALL, SMALL_SAC, seed=4, log=lambda *a: None, timing="phased")
    obs, _ = env.reset(seed=4)
    decided = record_calls(trainer.timing_taker, "act")
    proposed = record_calls(trainer.actor, "act")
    steps = [trainer.driver.act(obs, env) for _ in range(40)]
    env.close()
    assert len(proposed) == len(decided)  # the actor is asked only when a decision is made
    i = 0
    for a_t, T in zip(proposed, decided):  # each decision: a_t held, beta(T, dt) for dt = 1..T, as imagined
        for dt in range(1, min(T, len(steps) - i) + 1):
            a, T_i, b = steps[i]
            assert a[0] == a_t[0] and T_i == T and b == pytest.approx(float(tarl.beta(T, dt, omega=W)))
            i += 1
    assert i == len(steps) and len(decided) < len(steps)  # fewer decisions than steps: T > 1 was held


def test_the_consistent_variant_executes_in_the_real_loop_what_its_imagination_executes():
    env = world.DrivingEnv(EnvConfig(scenario="intersection"))
    trainer = tarl.Trainer(Recorder(env), "tarl-consistent", SMALL, SMALL_SAC, seed=5, log=lambda *a: None,
                           timing="phased")
    trainer.obs, _ = trainer.env.reset(seed=5)
    decided, proposals = record_calls(trainer.timing_taker, "act"), record_calls(trainer.driver, "act")
    start_a, start_T = len(trainer.D_a), len(trainer.D_T)
    trainer.actor_loop(trainer.driver, "real")
    assert len(trainer.D_T) == start_T  # Alg. 1: only the imagination fills D_T
    steps, i = trainer.env.steps, 0
    for T in decided:  # each decision plays a_t over T steps by Eq. (7), as one imagination decision does
        a = proposals[i][0]
        for dt in range(1, T + 1):
            a_bar, a_base, r, done = steps[i]
            assert proposals[i][0][0] == a[0] and proposals[i][1] == T
            assert a_bar == pytest.approx(tarl.blend(a[0], a_base, tarl.beta(T, dt, omega=W)), abs=1e-12)  # Eq. (7)
            assert trainer.D_a.data["act"][start_a + i, 0] == pytest.approx(a[0])  # the a_t being phased in
            i += 1
            if done or i == len(steps):
                break
        if i == len(steps):
            break
    assert i == len(steps) >= SMALL.n_actor
    env.close()


def test_the_held_imagination_executes_the_real_loops_beta_T_with_a_fresh_action_and_stores_r_T(trainer):
    """tarl-held (beyond the paper): a decision of T holds beta(T) of Eq. (11) for T steps, the actor asked anew at
    each, as the real loop executes it; D_T gets the same (x, T, r_T, gamma^k) as an Eq. (7) decision."""
    import dataclasses
    trainer.obs, _ = trainer.env.reset(seed=6)  # the tests above took the simulation over
    trainer.tc = dataclasses.replace(trainer.tc, imagination="held")
    try:
        timings, proposals = record_calls(trainer.timing_taker, "act"), record_calls(trainer.actor, "act")
        trainer.env.steps.clear()
        start = len(trainer.D_T)
        trainer.imagination_loop()
        del trainer.timing_taker.act, trainer.actor.act
    finally:
        trainer.tc = dataclasses.replace(trainer.tc, imagination="phased")
    steps, asked, gamma = iter(trainer.env.steps), iter(proposals), SMALL_SAC.gamma
    for i, T in enumerate(timings):
        rewards = []
        for dt in range(1, T + 1):
            a_bar, a_base, r, done = next(steps)
            a = next(asked)  # dt = 1: the a_t beside s_t in D_T; then a fresh one each step
            assert a_bar == pytest.approx(tarl.blend(a[0], a_base, tarl.beta(T, omega=W)), abs=1e-12)
            rewards.append(r)
            if done:
                break
        assert trainer.D_T.data["act"][start + i] == T
        assert trainer.D_T.data["rew"][start + i] == pytest.approx(sum(gamma**j * r for j, r in enumerate(rewards)))
        assert trainer.D_T.data["discount"][start + i] == pytest.approx(gamma ** len(rewards))
    assert next(steps, None) is None and next(asked, None) is None
