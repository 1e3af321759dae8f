"""Algorithm 1 on the real simulator: short runs that really learn, checkpoints, determinism."""

import numpy as np
import pytest
import torch

import tarl
from tarl import EnvConfig, SACConfig, TrainConfig

# a short schedule with small networks: every phase of Algorithm 1 runs, and both agents update
SMALL_SAC = SACConfig(batch_size=32, buffer_size=5_000, learning_starts=100, hidden=32)
SMALL = TrainConfig(steps=500, sac_fraction=0.3, n_timing=5, n_actor=15, timing_learning_starts=10,
                    log_every=10**9, checkpoint_every=10**9)


@pytest.fixture(scope="module")
def env():
    env = tarl.DrivingEnv(EnvConfig(scenario="intersection"))
    yield env
    env.close()


def test_discounted_sum_is_eq_8_by_hand():
    # r_T = r1 + gamma r2 + gamma^2 r3
    assert tarl.discounted_sum([1.0, 2.0, 3.0], 0.9) == pytest.approx(1.0 + 0.9 * 2.0 + 0.81 * 3.0)
    assert tarl.discounted_sum([0.5], 0.99) == 0.5  # T = 1: the step reward itself


def test_timing_input_carries_the_action_scaled():
    x = tarl.timing_input(np.zeros(tarl.OBS_DIM, np.float32), np.array([2.0]))
    assert x.shape == (tarl.OBS_DIM + 1,) and x[-1] == 1.0
    assert tarl.timing_input(np.zeros(tarl.OBS_DIM), np.array([-3.0]))[-1] == -1.0


def test_short_tarl_run_updates_both_agents_and_writes_a_checkpoint_that_loads(env, tmp_path):
    trainer = tarl.Trainer(env, "tarl", SMALL, SMALL_SAC, seed=1, out=tmp_path, log=lambda *a: None)
    before = [p.detach().clone() for p in trainer.timing_taker.policy.parameters()]
    trainer.run()
    assert trainer.step >= SMALL.steps
    assert trainer.updates["actor"] > 50 and trainer.updates["timing"] > 5  # Alg. 1 lines 13-14, 22-23
    assert any(not torch.equal(a, b) for a, b in zip(before, trainer.timing_taker.policy.parameters()))
    assert len(trainer.timing_buffer) > 0 and trainer.sac_actor is not None
    # the checkpoint loads with weights_only=True into a fresh trainer and acts the same
    state = tarl.load_checkpoint(tmp_path / "ckpt.pt")
    assert state["config"]["algo"] == "tarl" and state["step"] == trainer.step
    fresh = tarl.Trainer(env, "tarl", SMALL, SMALL_SAC, seed=2, log=lambda *a: None)
    fresh.load(state, resume=True)
    obs = np.random.default_rng(0).uniform(0, 1, (4, tarl.OBS_DIM)).astype(np.float32)
    np.testing.assert_array_equal(fresh.actor.act(obs, True), trainer.actor.act(obs, True))
    x = np.concatenate([obs, np.zeros((4, 1), np.float32)], 1)
    np.testing.assert_array_equal(fresh.timing_taker.act(x, True), trainer.timing_taker.act(x, True))
    assert fresh.step == trainer.step and len(fresh.actor_buffer) == len(trainer.actor_buffer)
    log = (tmp_path / "train_log.csv").read_text().splitlines()
    assert log[0] == ",".join(tarl.LOG_HEADER) and len(log) > 1


def test_a_checkpoint_for_another_model_is_refused(env, tmp_path):
    trainer = tarl.Trainer(env, "sac", replace_steps(SMALL, 150), SMALL_SAC, seed=1, out=tmp_path, log=lambda *a: None)
    trainer.run()
    state = tarl.load_checkpoint(tmp_path / "ckpt.pt")
    with pytest.raises(SystemExit, match="--algo sac"):
        tarl.check_config(state, "intersection", "tarl")
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(SystemExit, match="cannot load checkpoint"):
        tarl.load_checkpoint(tmp_path / "bad.pt")
    with pytest.raises(SystemExit, match="not found"):
        tarl.load_checkpoint(tmp_path / "missing.pt")


def replace_steps(tc, steps):
    from dataclasses import replace
    return replace(tc, steps=steps)


def test_same_seed_gives_the_same_evaluation(env):
    def run():
        trainer = tarl.Trainer(env, "tarl", replace_steps(SMALL, 300), SMALL_SAC, seed=5, log=lambda *a: None)
        trainer.run()
        return tarl.evaluate(env, trainer.driver, rounds=2, cases=2, seed=5, log=lambda *a: None)
    first, second = run(), run()
    assert first == second
    assert 0.0 <= first["success_rate"]["mean"] <= 1.0 and "beta_minus" in first
