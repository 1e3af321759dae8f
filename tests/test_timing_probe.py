"""bench/timing_probe.py: a restored state continues as the recorded episode did, and the two loops blend as
Eq. (7) and Eqs. (11)-(12) say. Tiny sizes: one test case of the roundabout, the shipped seed-0 policy."""
import json
import tempfile

import numpy as np
import pytest
import torch

import timing_probe as tp  # noqa: E402
from world import DrivingEnv, EnvConfig  # noqa: E402

tarl, experiment = tp.tarl, tp.experiment


@pytest.fixture(scope="module")
def world():
    """The roundabout, TARL's seed-0 policy, round 0's first test case and its recorded episode."""
    env = DrivingEnv(EnvConfig(scenario="roundabout"))
    trainer = tp.load_tarl(env, "roundabout")
    with tempfile.TemporaryDirectory() as folder:
        case = env.record_cases(experiment.test_seed(0, 0), 1, folder)[0]
        yield env, trainer, case, tp.play(env, trainer, case)
    env.close()


def test_play_is_the_evaluation_rollout(world):
    env, trainer, case, ep = world
    ref = experiment.rollout(env, trainer.driver, {"case": case})
    assert (ep["outcome"], len(ep["actions"])) == (ref["outcome"], ref["steps"])
    assert np.array_equal(ep["actions"], ref["a_bar"])


def test_a_restored_state_continues_as_the_episode_did(world):
    env, trainer, case, ep = world
    k = len(ep["actions"]) // 2
    obs = tp.restore(env, trainer, case, ep, k)  # asserts the replayed observation bit for bit
    same = tp.drive(env, trainer, obs)
    assert same["outcome"] == ep["outcome"] and same["rewards"] == ep["rewards"][k:]
    assert len(same["rewards"]) == len(ep["actions"]) - k


def test_imagination_holds_a_t_and_phases_it_in_by_eq_7(world):
    env, trainer, case, ep = world
    omega, T, trace = trainer.driver.timing_cfg.omega, 5, []
    res = tp.drive(env, trainer, tp.restore(env, trainer, case, ep, 10), "imagination", T, trace)
    a, b, a_base, a_bar = np.array(trace).T
    assert len(trace) == T and np.all(a == a[0])  # one decision: a_t = actor(s_t), held
    assert a[0] == trainer.actor.act(res["obs"][0], deterministic=True)[0]
    assert np.allclose(b, tarl.beta(T, np.arange(1, T + 1), omega=omega)) and b[-1] == 1.0 and np.all(np.diff(b) > 0)
    mixed = b < 1.0  # Eq. (7): a_bar = beta(T, dt) a_t + (1 - beta(T, dt)) a_base,t+dt
    assert np.allclose(a_bar[mixed], b[mixed] * a[mixed] + (1 - b[mixed]) * a_base[mixed]) and a_bar[-1] == a[-1]


def test_real_loop_blends_a_fresh_action_with_beta_T_each_step(world):
    env, trainer, case, ep = world
    omega, T, trace = trainer.driver.timing_cfg.omega, 5, []
    res = tp.drive(env, trainer, tp.restore(env, trainer, case, ep, 10), "real", T, trace)
    a, b, a_base, a_bar = np.array(trace).T
    assert len(trace) == T and np.allclose(b, tarl.beta(T, omega=omega))  # Eq. (11): beta(T_t), dt = 1
    assert np.array_equal(a, [trainer.actor.act(o, deterministic=True)[0] for o in res["obs"][:T]])  # fresh
    assert np.allclose(a_bar, b * a + (1 - b) * a_base)  # Eq. (12)


def test_schedules_and_branch_steps():
    assert [tp.blend_schedule("imagination-const", 3, j, omega=6.0)[1] for j in range(7)] == [1, 0, 0, 1, 0, 0, 1]
    assert tp.blend_schedule("imagination", 4, 3, omega=6.0)[0] == 1.0
    assert tp.blend_schedule("real", 4, 3, omega=6.0)[0] == pytest.approx(0.045, abs=1e-3)
    assert tp.branch_steps(45, 20, False, 5, 0.2) == [(0, "regular"), (20, "regular"), (40, "regular")]
    assert tp.branch_steps(45, 0, True, 5, 0.2) == [(30, "crash"), (35, "crash"), (40, "crash")]
    assert list(tp.ranks([3.0, 1.0, 3.0, 2.0])) == [1.5, 4.0, 1.5, 3.0]
    assert tp.spearman([1, 2, 3], [10, 20, 30]) == pytest.approx(1.0)
    assert tp.spearman([1, 2, 3], [3, 2, 1]) == pytest.approx(-1.0)


def test_probe_end_to_end_writes_the_report(tmp_path):
    res = tp.probe("intersection", cases=1, every=1000, crash_search=1, crash_cases=0, crash_every=5, t_max=2)
    assert [s["k"] for s in res["states"]] == [0]
    assert len(res["branches"]) == 1 + len(tp.LOOPS) * 2
    (tmp_path / "intersection.json").write_text(json.dumps(res))
    tp.report(tmp_path, log=lambda *a: None)
    text = (tmp_path / "summary.md").read_text()
    assert "## intersection" in text and "Spearman" in text and (tmp_path / "ranking.png").stat().st_size > 0


def test_the_critic_is_read_from_a_checkpoint_of_the_shipped_policies_only(world, tmp_path):
    """--critic CKPT: the states of the shipped policies with their timing taker's min Q(s, a, T), no branch
    played; a checkpoint whose policies differ is refused. Here a ckpt.pt of the shipped policies and a fresh
    critic (policy.pt has none)."""
    env, trainer, *_ = world
    trainer.out = tmp_path
    trainer.save()
    res = tp.probe("roundabout", cases=1, every=1000, crash_search=1, crash_cases=0, crash_every=5, t_max=2,
                   critic=tmp_path / "ckpt.pt")
    assert res["branches"] == [] and len(res["states"][0]["taker_q"]) == trainer.tc.timing.t_max
    assert isinstance(res["states"][0]["actor_q"], float)
    res["branches"] = [dict(case=0, k=0, kind="regular", loop=lp, T=T, disc=float(T), outcome="arrival")
                       for lp, T in [("original", 0), *((lp, T) for lp in tp.LOOPS[:2] for T in (1, 2))]]
    text = "\n".join(tp.critic_lines(res))
    assert "| 2 | " in text and "best, imagination" in text and "before collisions" not in text
    weight = next(trainer.actor.policy.parameters())
    shipped = weight.detach().clone()
    with torch.no_grad():
        weight.add_(1.0)
    trainer.save()
    with torch.no_grad():
        weight.copy_(shipped)  # the module's shipped trainer, as it was
    trainer.out = None
    with pytest.raises(SystemExit, match="its actor is not the shipped"):
        tp.probe("roundabout", 1, 1000, 1, 0, 5, t_max=2, critic=tmp_path / "ckpt.pt")
