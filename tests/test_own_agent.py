"""An outside policy beside Table 3 (bench/own_agent.py), on the real simulator: the planner as a callable plays
Lattice-IDM's committed test cases case for case, seed by seed, through experiment.evaluate into eval.json files that
exercises.paired reads, marked privileged (it reads the env); its key names it for resuming, by round and by seed; a
policy that draws random numbers is refused unless --stochastic, then marked; one that returns NaN or raises ends
the run in one line naming the case. The comparison over seeds: paired() per seed and pooled, and the claims' test
(analysis.claims, paired by seed), checked by hand on made-up rows and against the claims table."""
import json
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
import own_agent  # noqa: E402
import experiment  # noqa: E402
import table3  # noqa: E402
from analysis import paired  # noqa: E402
from world import EnvConfig  # noqa: E402

NOISE = np.random.default_rng(0)


def planner(obs, env):
    """Lattice-IDM's action as an outside policy: the planner's, through the env it is given."""
    return [env.unwrapped.base_action()]


def nan_policy(obs):
    return [float("nan")]


def raising_policy(obs, env):
    raise ZeroDivisionError("the policy's own bug")


def noisy_policy(obs):
    """A policy that draws random numbers: each time it plays a case, it plays it differently."""
    return [NOISE.normal()]


@pytest.mark.parametrize("scenario", ["intersection", "roundabout"])
def test_the_planner_as_a_callable_plays_lattice_idms_committed_cases_case_for_case_seed_by_seed(scenario, tmp_path):
    lines = []
    rows = own_agent.evaluate_policy(planner, scenario, seeds=(0, 1), name="planner", rounds=2, cases=2, workers=0,
                                     out=tmp_path, log=lines.append)
    for seed, row in rows.items():
        committed = json.loads((ROOT / "results" / "runs" / experiment.run_name(scenario, "tarl", seed) /
                                "eval.json").read_text())
        lattice = next(r for r in committed["rows"] if r["algo"] == "lattice-idm")
        lattice = {(c["round"], c["case"]): c for c in lattice["cases"]}
        assert [(c["round"], c["case"]) for c in row["cases"]] == [(r, c) for r in range(2) for c in range(2)]
        for case in row["cases"]:
            want = lattice[case["round"], case["case"]]
            assert (case["start"], case["outcome"], case["steps"]) == (want["start"], want["outcome"], want["steps"])
        written = json.loads((tmp_path / f"{scenario}-planner-s{seed}" / "eval.json").read_text())
        assert {"scenario", "seed", "code", "machine", "rows"} <= set(written) and written["seed"] == seed
        assert written["rows"] == [row] and row["algo"] == "planner" and set(committed["rows"][2]) <= set(row)
        assert row["policy"]["outside_the_paper"] and row["policy"]["privileged"] and not row["policy"]["stochastic"]
        assert row["label"] == "planner (privileged)"  # it reads the env: its label says so, in every table
    text = "\n".join(lines)
    assert text.count("\nplanner (privileged)  ") == 2 and "\npooled " in text and "over the 2 seeds" in text
    again = []  # the same command again: both seeds are done
    assert own_agent.evaluate_policy(planner, scenario, seeds=(0, 1), name="planner", rounds=2, cases=2, workers=0,
                                     out=tmp_path, log=again.append) == rows
    assert sum("holds this evaluation already" in line for line in again) == 2
    assert not any("round 1/" in line for line in again)  # nothing played again
    assert paired.main(["--scenario", scenario, "planner", "lattice-idm", "--seeds", "0", "1", "--runs", str(tmp_path),
                        str(ROOT / "results" / "runs")]) == 0  # exercises.paired reads them unchanged


def test_an_interrupted_evaluation_resumes_by_seed_and_round(tmp_path):
    rounds = []

    def stop_after_a_round_of_seed_1(line):
        rounds.append("round 1/2" in line)
        if sum(rounds) == 2:  # seed 0 finished, seed 1 played its first round
            raise KeyboardInterrupt
    with pytest.raises(SystemExit, match="kept the finished rounds"):
        own_agent.evaluate_policy(planner, "intersection", (0, 1), name="planner", rounds=2, cases=1, workers=0,
                                  out=tmp_path, log=stop_after_a_round_of_seed_1)
    lines = []
    rows = own_agent.evaluate_policy(planner, "intersection", (0, 1), name="planner", rounds=2, cases=1, workers=0,
                                     out=tmp_path, log=lines.append)
    assert any(line.startswith("seed 0: ") and "holds this evaluation already" in line for line in lines)
    assert any("1 of 2 rounds kept" in line for line in lines) and sum("round 2/2" in line for line in lines) == 1
    assert [row["rounds"] for row in rows.values()] == [2, 2]
    assert not list(tmp_path.glob("*/eval-rounds"))


def test_a_policy_that_draws_random_numbers_is_refused_unless_stochastic_then_marked(tmp_path):
    run = dict(scenario="intersection", seeds=(0,), name="noisy", rounds=1, cases=1, workers=0, out=tmp_path)
    with pytest.raises(SystemExit) as e:
        own_agent.evaluate_policy(noisy_policy, **run, log=lambda *a: None)
    assert str(e.value).startswith("the policy noisy is not deterministic: case 0 of round 0 of seed 0, played twice, "
                                   "ended in ") and "its actions apart from step 1" in str(e.value)
    assert "\n" not in str(e.value) and not (tmp_path / "intersection-noisy-s0" / "eval.json").exists()
    lines = []
    row = own_agent.evaluate_policy(noisy_policy, **run, stochastic=True, log=lines.append)[0]
    assert row["policy"]["stochastic"] and not row["policy"]["privileged"] and row["label"] == "noisy (stochastic)"
    assert json.loads((tmp_path / "intersection-noisy-s0" / "eval.json").read_text())["rows"] == [row]
    assert any(line.startswith("noisy (stochastic)  ") for text in lines for line in text.splitlines())
    assert own_agent.evaluate_policy(planner, **dict(run, name="planner"), log=lambda *a: None)[0]  # deterministic


def made_up(outcomes: dict) -> dict:
    """Rows of eval.json, {seed: row}, from each seed's outcomes in one round (a: arrival, c: collision, t: timeout)."""
    words = dict(a="arrival", c="collision", t="timeout")
    return {seed: dict(cases=[dict(round=0, case=c, start=f"{seed}-{c}", outcome=words[o]) for c, o in enumerate(text)])
            for seed, text in outcomes.items()}


def test_the_comparison_over_seeds_is_paired_per_seed_and_pooled_and_the_claims_test_over_them():
    mine, theirs = made_up({0: "aaac", 1: "aacc", 2: "aaaa"}), made_up({0: "actc", 1: "aacc", 2: "aaat"})
    lines = own_agent.comparison(mine, theirs, "TARL", np.random.default_rng(0))
    rng = np.random.default_rng(0)  # the same draws in the same order: the lines are paired()'s
    each = [paired.paired(mine[s], theirs[s], rng) for s in mine]
    pooled = paired.paired(list(mine.values()), list(theirs.values()), rng)
    assert lines[:2] == ["against TARL:", own_agent.HEADER]
    assert lines[2:6] == [own_agent.versus(r, name) for r, name in zip([*each, pooled], ["0", "1", "2", "pooled"])]
    # by hand: success 0.75, 0.5, 1 against 0.25, 0.5, 0.75; only mine arrives in cases 1 and 2 of seed 0 (the other
    # collides, times out) and 3 of seed 2 (times out): McNemar's p = 2 / 2^3
    assert lines[5].split()[:9] == ["pooled", "12", "0.750", "0.500", "3", "(1", "/", "2)", "0"]
    assert lines[5].split()[12:14] == ["0.25", "+0.250"]
    # paired by seed: differences 0.5, 0, 0.25, mean 0.25 and std 0.25, so t = sqrt 3 on 2 degrees of freedom,
    # p = 1 - sqrt(3 / 5) = 0.23 and the 95 % CI 0.25 +- 4.303 * 0.1443; an effect of one std of the differences
    # needs 10 seeds for 80 % power; ahead in seeds 0 and 2; sign flips: 4 of the 8 patterns reach |mean| 0.25;
    # P(A > B) = 7 / 9
    assert lines[6].startswith("over the 3 seeds, paired by seed as the paper's claims are tested: it - the row +0.250 "
                               "[-0.371, +0.871] (paired t's 95 % CI, p 0.23): undecided, 10 seeds would settle "
                               "it; ahead in 2 of 3 seeds, sign-flip p 0.5; P(it > the row) 0.78 [") and len(lines) == 7
    assert own_agent.comparison({0: mine[0]}, {0: theirs[0]}, "TARL", np.random.default_rng(0))[2:] == [
        own_agent.versus(paired.paired(mine[0], theirs[0], np.random.default_rng(0)), "0")]  # one seed: no pooling


def test_the_test_over_seeds_is_the_claims_test():
    """On a claim's seeds, own_agent's test gives the claims table's numbers; its verdict is its own, unadjusted (the
    table's is Holm's over its family)."""
    found = table3.load(ROOT / "results")
    claims = [c for c in table3.claim_rows(found) if c["key"] == "success_rate"]
    for c in claims:
        seeds = [{k: r["success_rate"]["mean"] for k, r in found[table3.DEFAULT][c["scenario"], algo].items()}
                 for algo in (c["a"], c["b"])]
        mine = own_agent.seed_test(*seeds, own_agent.MARGIN["success_rate"], np.random.default_rng(0), seeds=c["seeds"])
        assert {k: mine[k] for k in ("seeds", "n", "d", "ci", "p", "tost", "wins", "sign_flip")} == {
            k: c[k] for k in ("seeds", "n", "d", "ci", "p", "tost", "wins", "sign_flip")}
        assert mine["means"] == pytest.approx(c["means"]) and mine["improvement"][0] == c["improvement"][0]


def test_the_key_names_the_policy_for_resuming():
    def key(fn, name="mine"):
        driver = own_agent.PolicyDriver(own_agent.Policy(name, own_agent.policy_key(fn), fn), 0)
        return experiment.evaluation_key(EnvConfig(), [dict(algo=name, driver=driver)], 5, 0)

    assert key(planner) == key(planner) and key(planner) not in (key(nan_policy), key(planner, "other"))
    driver = pickle.loads(pickle.dumps(own_agent.PolicyDriver(own_agent.Policy("p", "k", planner), 0)))  # to a worker
    assert (driver.actor.fn, driver.actor.key, driver.actor.with_env) == (planner, "k", True)


@pytest.mark.parametrize("policy, workers, stochastic, says", [
    ("nan_policy", 1, ["--stochastic"], "it returned [nan], not one finite acceleration [m/s^2]"),  # in a worker
    ("raising_policy", 0, [], "it raised ZeroDivisionError: the policy's own bug")])  # in the check before the run
def test_a_policy_that_fails_ends_the_run_in_one_line_naming_the_case(policy, workers, stochastic, says, tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "bench" / "own_agent.py"), "--scenario", "roundabout", "--policy",
                           f"test_own_agent:{policy}", "--seeds", "1", "--eval-rounds", "1", "--eval-cases", "2",
                           "--workers", str(workers), "--out", str(tmp_path), *stochastic], cwd=ROOT / "tests",
                          capture_output=True, text=True, timeout=120)
    name = policy.replace("_", "-")
    assert proc.returncode == 1 and "Traceback" not in proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [f"the policy {name} failed on seed 1 at step 1 of case 0 of round 0 "
                                                f"(from 0, as in eval.json): {says}"]


@pytest.mark.parametrize("argv, says", [
    (["--sb3", "no/such/model-s{seed}.zip"], "--sb3 no/such/model-s0.zip: no such file"),
    (["--policy", "test_own_agent:planner", "--seeds", "0", "99"], "no row of Table 3 for seed 99 on the roundabout "
     f"in {ROOT / 'results' / 'runs'}: its seeds there are 0, 1, 2"),  # and on, as the grid's seeds land
    (["--policy", "test_own_agent:planner", "--seeds", "1", "1"], "seeds 1 1: one or more, each once"),
    (["--policy", "test_own_agent:planner", "--name", "tarl"], "name 'tarl': lowercase letters"),
    (["--policy", "test_own_agent:no_such"], "--policy test_own_agent:no_such: module 'test_own_agent' has no")])
def test_bad_input_is_one_line_before_any_work(argv, says, tmp_path):
    with pytest.raises(SystemExit) as e:
        own_agent.main(["--scenario", "roundabout", "--out", str(tmp_path / "out"), *argv])
    assert str(e.value).startswith(says) and not (tmp_path / "out").exists()
