"""Branching the world (DrivingEnv.save_state / restore_state, rollout_timing.resample_future) and the rollout timing
(beyond/rollout_timing.py), on the real simulator."""
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import experiment
from beyond import rollout_timing
import world
from beyond.rollout_timing import RolloutConfig, RolloutTiming, resample_future

HERE = Path(__file__).resolve().parents[1]


class Toward:
    """An actor that accelerates toward a target speed [m/s], jerkily (never the planner's action)."""

    def __init__(self, v=9.0):
        self.v = v

    def act(self, obs, deterministic=False):
        return np.array([2.0 if obs[6] * 16.0 < self.v else -3.0], np.float32)


@pytest.fixture(scope="module")
def cases():
    env = world.DrivingEnv(world.EnvConfig(scenario="roundabout"))
    folder = tempfile.TemporaryDirectory()
    yield env, env.record_cases(experiment.test_seed(0, 0), 3, folder.name), Path(folder.name)
    env.close()
    folder.cleanup()


def play(env, actions):
    """Each step's (observation, reward, done, info) of these accelerations, to the episode's end."""
    steps = []
    for a in actions:
        obs, r, terminated, truncated, info = env.step([a])
        steps.append((obs, r, terminated or truncated, info))
        if terminated or truncated:
            break
    return steps


def test_a_restored_state_replays_the_recorded_steps_exactly(cases):
    env, recorded, folder = cases
    for case in recorded:
        env.reset(options={"case": case})
        for _ in range(20):
            obs = env.step([env.base_action()])[0]
        state = env.save_state(folder / "state.xml")
        rng = np.random.default_rng(1)
        actions = np.clip(env.base_action() + rng.normal(0.0, 1.5, 400), -3.0, 2.0)
        assert np.array_equal(env.restore_state(state), obs)  # the observation as it was saved
        first = play(env, actions)
        assert first[-1][2], "the episode ran to its end"
        env.reset(options={"case": recorded[-1]})  # something else in between: a restore forgets it
        play(env, [0.0] * 30)
        assert np.array_equal(env.restore_state(state), obs)
        again = play(env, actions)
        assert len(again) == len(first)
        for (o1, r1, d1, i1), (o2, r2, d2, i2) in zip(first, again):
            assert np.array_equal(o1, o2) and r1 == r2 and d1 == d2 and i1 == i2


def test_no_field_of_a_running_episode_escapes_the_saved_state(cases):
    """Every field of the env that an episode's steps change is in DrivingEnv.EPISODE_STATE (or is the traffic's rng,
    saved beside it, or the planner's cache, emptied by a restore): a field added to the env is caught here."""
    env, recorded, _ = cases
    env.reset(options={"case": recorded[0]})
    env.step([env.base_action()])
    here = lambda: {k: pickle.dumps(v) for k, v in vars(env).items() if k not in ("sim", "V")}  # noqa: E731
    before = here()
    for _ in range(15):
        env.step([env.base_action()])
    changed = {k for k, v in here().items() if before.get(k) != v}
    assert {"humans", "v", "obs", "other_ids"} <= changed  # the check sees a step's changes
    assert changed <= {*env.EPISODE_STATE, "rng", "_plan"}


def test_a_state_is_saved_only_in_an_episode(cases):
    env, recorded, folder = cases
    env.reset(options={"case": recorded[0]})
    play(env, [2.0] * 400)
    with pytest.raises(RuntimeError, match="episode under way"):
        env.save_state(folder / "state.xml")


def test_a_resampled_future_keeps_what_the_ego_sees_and_draws_the_rest_anew(cases):
    env, recorded, folder = cases
    env.reset(options={"case": recorded[1]})
    for _ in range(10):
        env.step([env.base_action()])
    state = env.save_state(folder / "state.xml")
    own = [env.rng.random() for _ in range(3)]  # what the case's own stream would draw next
    env.restore_state(state)
    humans = {h: p.copy() for h, p in env.humans.items()}
    resample_future(env, np.random.default_rng([rollout_timing.FUTURE_TAG, 0, 1, 10, 0]))
    assert [env.rng.random() for _ in range(3)] != own
    for h, p in env.humans.items():  # game weights and SVO drawn anew, kinematics kept
        assert not np.allclose(p[:5], humans[h][:5]) and np.array_equal(p[5:], humans[h][5:])
    env.restore_state(state)
    assert [env.rng.random() for _ in range(3)] == own  # a restore brings the case's own future back


def test_the_rollout_timing_branches_from_other_seeds_and_counts_every_branch_step(cases, monkeypatch):
    env, recorded, _ = cases
    cfg = RolloutConfig(candidates=(1, 10), futures=2, hold=5)
    driver = RolloutTiming(Toward(), cfg=cfg)
    seen, steps = [], [0]
    resample, step = rollout_timing.resample_future, env.step

    def spy_resample(env_, rng):  # the branch's stream, and the case's own at the same point
        seen.append((repr(rng.bit_generator.state), repr(env_.rng.bit_generator.state)))
        return resample(env_, rng)

    def count_step(a):
        steps[0] += 1
        return step(a)

    monkeypatch.setattr(rollout_timing, "resample_future", spy_resample)
    monkeypatch.setattr(env, "step", count_step)
    case = recorded[2]
    ep = experiment.rollout(env, driver, {"case": case})
    assert ep["decisions"] >= 1 and len(seen) == ep["decisions"] * len(cfg.candidates) * cfg.futures
    branch, case_own = zip(*seen)
    assert not set(branch) & set(case_own)  # no branch drew the case's own future
    assert len(set(branch)) == ep["decisions"] * cfg.futures  # the candidates share K futures per decision
    assert steps[0] == ep["steps"] + ep["branch_steps"] and ep["branch_steps"] > 0
    assert set(ep["T"]) <= {1, 2, 10}
    # the episode is repeatable: the same case gives the same decisions and outcome
    again = experiment.rollout(env, RolloutTiming(Toward(), cfg=cfg), {"case": case})
    assert (again["outcome"], again["steps"], again["T"].tolist()) == (ep["outcome"], ep["steps"], ep["T"].tolist())


def test_the_control_reloads_at_the_same_decisions_without_a_branch(cases):
    env, recorded, _ = cases
    ep = experiment.rollout(env, RolloutTiming(Toward(), cfg=RolloutConfig(candidates=(2,))), {"case": recorded[0]})
    assert ep["decisions"] >= 1 and ep["branch_steps"] == 0 and set(ep["T"]) == {2}


def test_a_bad_rollout_timing_is_one_line_before_any_work():
    proc = subprocess.run([sys.executable, "tarl.py", "--load", "results/runs/roundabout-tarl-s0/policy.pt",
                           "--timing", "rollout=0,3"], cwd=HERE, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines()[-1].endswith("rollout=T1,T2,... with every T >= 1")
    with pytest.raises(ValueError, match="candidates"):
        RolloutTiming(Toward(), cfg=RolloutConfig(futures=0))
