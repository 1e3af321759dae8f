"""Tests of tarl.py: the timing math by hand, Algorithm 1's buffers and blend on the real simulator."""

import os
import subprocess
import sys

import numpy as np
import pytest

import planner
import tarl
from tarl import EnvConfig, SACConfig, TrainConfig

SMALL_SAC = SACConfig(batch_size=32, buffer_size=5_000, learning_starts=50, hidden=32)
SMALL = TrainConfig(steps=400, sac_fraction=0.3, n_timing=5, n_actor=15, timing_pretrain=0.05,
                    timing_learning_starts=10, log_every=10**9, checkpoint_every=10**9)


# ---- Eqs. (6), (7), (11), (12): timing ------------------------------------------------------

def test_beta_boundary_values():
    T = np.arange(1, 50)
    np.testing.assert_allclose(tarl.beta(T, T), 1.0)  # dt = T: the actor's action in full
    np.testing.assert_allclose(tarl.beta(T, 0), 0.0)  # dt = 0: the base action
    assert tarl.beta(1) == pytest.approx(1.0) and tarl.beta(2) == pytest.approx(0.5)
    for omega in (1.0, 3.0, 10.0):  # whatever w is
        assert tarl.beta(2, omega=omega) == pytest.approx(0.5)
    b = tarl.beta(T)
    assert np.all(np.diff(b) < 0)  # strictly decreasing in T
    assert 0.05 < tarl.beta(3) < 0.5 and tarl.beta(4) < 0.05  # intermediate at 3, near 0 from 4 (Sec. 4)
    assert tarl.beta(10_000) < 1e-3  # tends to 0


def test_beta_within_a_timing_rises_to_one():
    b = tarl.beta(5, np.arange(1, 6))
    assert np.all(np.diff(b) > 0) and b[-1] == pytest.approx(1.0)


def test_blend_at_beta_one_and_zero():
    assert tarl.blend(1.5, -2.0, 1.0) == 1.5  # Eq. (12), beta = 1: the actor's action
    assert tarl.blend(1.5, -2.0, 0.0) == -2.0  # beta = 0: the base action
    assert tarl.blend(1.0, -1.0, tarl.beta(2)) == pytest.approx(0.0)


def test_discounted_sum_is_eq_8_by_hand():
    assert tarl.discounted_sum([1.0, 2.0, 3.0], 0.9) == pytest.approx(1.0 + 0.9 * 2.0 + 0.81 * 3.0)
    assert tarl.discounted_sum([0.5], 0.99) == 0.5  # T = 1: the step reward itself


def test_timing_input_carries_the_action_scaled():
    x = tarl.timing_input(np.zeros(tarl.OBS_DIM, np.float32), np.array([2.0]), EnvConfig())
    assert x.shape == (tarl.OBS_DIM + 1,) and x[-1] == 1.0
    assert tarl.timing_input(np.zeros(tarl.OBS_DIM), np.array([-3.0]), EnvConfig())[-1] == -1.0


def test_an_action_bound_changed_in_its_one_home_reaches_the_planner_the_actor_and_eq_5():
    cfg = EnvConfig(scenario="intersection", a_min=-4.0, a_max=1.5)
    env = tarl.DrivingEnv(cfg)
    assert (env.action_space.low[0], env.action_space.high[0]) == (-4.0, 1.5)
    assert (env.planner_cfg.a_min, env.planner_cfg.a_max) == (-4.0, 1.5)
    trainer = tarl.Trainer(env, "tarl", SMALL, SMALL_SAC, log=lambda *a: None)
    low = float(trainer.actor.action_bias - trainer.actor.action_scale)
    high = float(trainer.actor.action_bias + trainer.actor.action_scale)
    assert (low, high) == (-4.0, 1.5)
    assert tarl.timing_input(np.zeros(tarl.OBS_DIM), np.array([-4.0]), cfg)[-1] == -1.0  # Eq. (5)
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
    env = tarl.DrivingEnv(EnvConfig(scenario="intersection"))
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
        assert 1 <= T <= tarl.T_MAX and b == pytest.approx(float(tarl.beta(T)))
        assert a_bar == pytest.approx(tarl.blend(a[0], a_base, tarl.beta(T)), abs=1e-12)  # Eq. (12)
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
    """Spinning OpenMP threads beside another busy process made training ~40x slower (README, Speed)."""
    show = "import tarl, os; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    here = os.path.dirname(os.path.abspath(__file__))
    assert subprocess.run([sys.executable, "-c", show], env=env, cwd=here, capture_output=True,
                          text=True).stdout.strip() == "PASSIVE"
    assert subprocess.run([sys.executable, "-c", show], env=env | {"OMP_WAIT_POLICY": "ACTIVE"}, cwd=here,
                          capture_output=True, text=True).stdout.strip() == "ACTIVE"
