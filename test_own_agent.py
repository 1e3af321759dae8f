"""An outside policy beside Table 3 (bench/own_agent.py), on the real simulator: the planner as a callable plays
Lattice-IDM's committed test cases case for case, through experiment.evaluate into an eval.json that exercises.paired
reads; its key names it for resuming; a policy that returns NaN or raises ends the run in one line naming the case."""
import json
import pickle
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT / "bench"))
import own_agent  # noqa: E402
import experiment  # noqa: E402
from exercises import paired  # noqa: E402
from world import EnvConfig  # noqa: E402


def planner(obs, env):
    """Lattice-IDM's action as an outside policy: the planner's, through the env it is given."""
    return [env.unwrapped.base_action()]


def nan_policy(obs):
    return [float("nan")]


def raising_policy(obs, env):
    raise ZeroDivisionError("the policy's own bug")


@pytest.mark.parametrize("scenario", ["intersection", "roundabout"])
def test_the_planner_as_a_callable_plays_lattice_idms_committed_cases_case_for_case(scenario, tmp_path):
    out = tmp_path / f"{scenario}-planner-s0"
    row = own_agent.evaluate_policy(planner, scenario, seed=0, name="planner", rounds=2, cases=3, workers=0, out=out,
                                    log=lambda *a: None)
    committed = json.loads((ROOT / "results" / "runs" / f"{scenario}-tarl-s0" / "eval.json").read_text())
    lattice = next(r for r in committed["rows"] if r["algo"] == "lattice-idm")
    lattice = {(c["round"], c["case"]): c for c in lattice["cases"]}
    assert [(c["round"], c["case"]) for c in row["cases"]] == [(r, c) for r in range(2) for c in range(3)]
    for case in row["cases"]:
        want = lattice[case["round"], case["case"]]
        assert (case["start"], case["outcome"], case["steps"]) == (want["start"], want["outcome"], want["steps"])
    written = json.loads((out / "eval.json").read_text())
    assert {"scenario", "seed", "code", "machine", "rows"} <= set(written) and written["rows"][0]["algo"] == "planner"
    assert set(committed["rows"][2]) <= set(written["rows"][0]) and written["rows"][0]["policy"]["outside_the_paper"]
    assert paired.main(["--scenario", scenario, "planner", "lattice-idm", "--seeds", "0", "--runs", str(tmp_path),
                        str(ROOT / "results" / "runs")]) == 0  # exercises.paired reads it unchanged


def test_an_interrupted_evaluation_resumes_by_round(tmp_path):
    def stop_after_a_round(line):
        if "round 1/2" in line:
            raise KeyboardInterrupt
    with pytest.raises(SystemExit, match="kept the finished rounds"):
        own_agent.evaluate_policy(planner, "intersection", name="planner", rounds=2, cases=2, workers=0, out=tmp_path,
                                  log=stop_after_a_round)
    lines = []
    row = own_agent.evaluate_policy(planner, "intersection", name="planner", rounds=2, cases=2, workers=0, out=tmp_path,
                                    log=lines.append)
    assert any("1 of 2 rounds kept" in line for line in lines) and row["rounds"] == 2
    assert not (tmp_path / "eval-rounds").exists()


def test_the_key_names_the_policy_for_resuming():
    def key(fn, name="mine"):
        driver = own_agent.PolicyDriver(own_agent.Policy(name, own_agent.policy_key(fn), fn), 0)
        return experiment.evaluation_key(EnvConfig(), [dict(algo=name, driver=driver)], 5, 0)

    assert key(planner) == key(planner) and key(planner) not in (key(nan_policy), key(planner, "other"))
    driver = pickle.loads(pickle.dumps(own_agent.PolicyDriver(own_agent.Policy("p", "k", planner), 0)))  # to a worker
    assert (driver.actor.fn, driver.actor.key, driver.actor.with_env) == (planner, "k", True)


@pytest.mark.parametrize("policy, workers, says", [
    ("nan_policy", 1, "it returned [nan], not one finite acceleration [m/s^2]"),
    ("raising_policy", 0, "it raised ZeroDivisionError: the policy's own bug")])
def test_a_policy_that_fails_ends_the_run_in_one_line_naming_the_case(policy, workers, says, tmp_path):
    proc = subprocess.run([sys.executable, "bench/own_agent.py", "--scenario", "roundabout", "--policy",
                           f"test_own_agent:{policy}", "--eval-rounds", "1", "--eval-cases", "2", "--workers",
                           str(workers), "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    name = policy.replace("_", "-")
    assert proc.returncode == 1 and "Traceback" not in proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [f"the policy {name} failed at step 1 of case 0 of round 0 (from 0, as "
                                                f"in eval.json): {says}"]


@pytest.mark.parametrize("argv, says", [
    (["--sb3", "no/such/model.zip"], "--sb3 no/such/model.zip: no such file"),
    (["--policy", "test_own_agent:planner", "--seed", "7"], "no row of Table 3 for seed 7 on the roundabout"),
    (["--policy", "test_own_agent:planner", "--name", "tarl"], "name 'tarl': lowercase letters"),
    (["--policy", "test_own_agent:no_such"], "--policy test_own_agent:no_such: module 'test_own_agent' has no")])
def test_bad_input_is_one_line_before_any_work(argv, says, tmp_path):
    with pytest.raises(SystemExit) as e:
        own_agent.main(["--scenario", "roundabout", "--out", str(tmp_path / "out"), *argv])
    assert str(e.value).startswith(says) and not (tmp_path / "out" / "eval.json").exists()
