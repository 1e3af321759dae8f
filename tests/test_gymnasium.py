"""DrivingEnv as a Gymnasium environment, on the real simulator: the checker, the registered ids with
Gymnasium's own wrappers and vector envs, seeding, and that playing through gymnasium.make changes nothing of
the project's results (a committed test case gives the start and outcome its eval.json has)."""
import json
import tempfile
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import world

ROOT = Path(__file__).resolve().parents[1]
IDS = ("tarl/Intersection-v0", "tarl/Roundabout-v0")
# the checker recommends an action space of [-1, 1]; ours is the paper's acceleration in m/s^2 (RescaleAction maps it)
UNSCALED = "For Box action spaces, we recommend using a symmetric and normalized space"


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasiums_checker_passes(env_id):
    env = gymnasium.make(env_id, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any other warning of the checker fails the test
        warnings.filterwarnings("ignore", message=f".*{UNSCALED}")  # (the filter added last is tried first)
        check_env(env.unwrapped)  # seeding, spaces, step and reset types and determinism, rendering
    env.close()


def test_the_ids_take_envconfigs_fields_and_the_render_mode():
    env = gymnasium.make("tarl/Roundabout-v0", render_mode="rgb_array", spawn_gap=0.9, a_min=-4.0)
    cfg = env.unwrapped.cfg
    assert (cfg.scenario, cfg.spawn_gap, cfg.a_min, env.unwrapped.render_mode) == ("roundabout", 0.9, -4.0, "rgb_array")
    assert env.action_space.low[0] == -4.0 and env.metadata["render_fps"] == 1 / cfg.dt
    env.close()
    with pytest.raises(TypeError):
        gymnasium.make("tarl/Roundabout-v0", no_such_field=1)
    with pytest.raises(ValueError, match="render_mode"):
        gymnasium.make("tarl/Roundabout-v0", render_mode="human")


def test_an_episode_runs_through_gymnasiums_standard_wrappers():
    env = gymnasium.make("tarl/Intersection-v0")
    env = gymnasium.wrappers.RescaleAction(env, np.float32(-1.0), np.float32(1.0))  # the ego's [a_min, a_max] as [-1, 1]
    env = gymnasium.wrappers.NormalizeReward(env)
    env = gymnasium.wrappers.RecordEpisodeStatistics(env)
    obs, _ = env.reset(seed=3)
    cfg, returns, done = env.unwrapped.cfg, [], False
    while not done:
        a_base = env.unwrapped.base_action()  # the planner drives, through RescaleAction's [-1, 1]
        scaled = 2.0 * (a_base - cfg.a_min) / (cfg.a_max - cfg.a_min) - 1.0
        obs, r, terminated, truncated, info = env.step(np.array([scaled], np.float32))
        returns.append(r)
        done = terminated or truncated
    assert info["episode"]["l"] == len(returns)
    assert info["episode"]["r"] == pytest.approx(sum(returns), rel=1e-5)
    assert info["arrival"] or info["collision"] or info["timeout"]
    env.close()


def test_an_async_vector_env_of_two_steps_and_closes_cleanly():
    """One SUMO per process (libsumo): two processes, each its own simulation, started with `spawn`."""
    envs = gymnasium.make_vec("tarl/Roundabout-v0", num_envs=2, vectorization_mode="async",
                              vector_kwargs={"context": "spawn"})
    obs, _ = envs.reset(seed=[0, 1])
    assert obs.shape == (2, world.OBS_DIM) and not np.array_equal(obs[0], obs[1])
    for _ in range(20):
        obs, rewards, terminated, truncated, infos = envs.step(np.zeros((2, 1), np.float32))
    assert obs.shape == (2, world.OBS_DIM) and rewards.shape == (2,)
    processes = list(envs.processes)
    envs.close()
    assert not any(p.is_alive() for p in processes)


def test_reset_with_a_seed_gives_the_same_episode():
    env = gymnasium.make("tarl/Intersection-v0")

    def episode(seed):
        obs, _ = env.reset(seed=seed)
        start, trace = env.unwrapped.fingerprint(), [obs]
        for _ in range(30):
            obs, r, terminated, truncated, _ = env.step(np.array([1.0], np.float32))
            trace.append(obs)
            if terminated or truncated:
                break
        return start, np.array(trace)

    first, again, other = episode(7), episode(7), episode(8)
    assert first[0] == again[0] and np.array_equal(first[1], again[1])
    assert first[0] != other[0]
    env.close()


def test_a_committed_test_case_played_through_make_gives_its_eval_json():
    """Nothing of the project's results changes: the intersection's TARL seed 0 and Lattice-IDM, played on test
    case (0, 3) through gymnasium.make, start as eval.json's fingerprint says and end as it says."""
    import experiment  # noqa: I001 (the drivers and the evaluation's seeds)
    import tarl

    run = ROOT / "results" / "runs" / "intersection-tarl-s0"
    rows = {row["algo"]: row for row in json.loads((run / "eval.json").read_text())["rows"]}
    state = experiment.load_checkpoint(run / "policy.pt", "intersection", "tarl")
    env = gymnasium.make("tarl/Intersection-v0")
    trainer = experiment.make_trainer("tarl", env.unwrapped, tarl.TrainConfig(), 0, None, lambda *a: None, state=state)
    trainer.load(state, resume=False)
    round_, case = 0, 3
    with tempfile.TemporaryDirectory() as folder:
        recorded = env.unwrapped.record_cases(experiment.test_seed(0, round_), case + 1, folder)
        for algo, driver in (("tarl", trainer.driver), ("lattice-idm", tarl.Driver("planner"))):
            want = next(c for c in rows[algo]["cases"] if (c["round"], c["case"]) == (round_, case))
            obs, _ = env.reset(options={"case": recorded[case]})
            driver.new_episode(recorded[case]["seed"])
            start, done, steps = env.unwrapped.fingerprint(), False, 0
            while not done:
                a, T, b = driver.act(obs, env.unwrapped, deterministic=True)
                obs, _, terminated, truncated, info = env.step([tarl.execute(env.unwrapped, a, b)])  # float64, as evaluated
                done, steps = terminated or truncated, steps + 1
            outcome = "collision" if info["collision"] else "arrival" if info["arrival"] else "timeout"
            assert (start, outcome, steps) == (want["start"], want["outcome"], want["steps"]), algo
    env.close()
