"""The distilled timing (beyond/distil.py, bench/distillation.py): the teacher's labels, the students, on the real simulator."""
import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

from beyond import distil
import experiment
import world
from beyond.rollout_timing import RolloutConfig, best_candidate
from tarl import Driver, beta, blend, timing_input

HERE = Path(__file__).resolve().parents[1]
import distillation  # noqa: E402


class Alternating:
    """An actor whose every call gives another action: a branch that asked it again would not replay the decision."""

    def __init__(self):
        self.n = 0

    def act(self, obs, deterministic=False):
        self.n += 1
        return np.array([2.0 if self.n % 2 else -3.0], np.float32)


class Toward:
    """An actor that accelerates toward 9 m/s, jerkily: it ends its episodes soon, and is never the planner."""

    def act(self, obs, deterministic=False):
        return np.array([2.0 if obs[6] * 16.0 < 9.0 else -3.0], np.float32)


@pytest.fixture(scope="module")
def cases():
    env = world.DrivingEnv(world.EnvConfig(scenario="roundabout"))
    folder = tempfile.TemporaryDirectory()
    yield env, env.record_cases(distillation.label_seed(0), 3, folder.name)
    env.close()
    folder.cleanup()


def test_every_branch_of_a_label_begins_with_the_recorded_action(cases, monkeypatch):
    """Per decision: a restore before each of the candidates x K branches and one back to the episode; the step after
    each is the recorded action blended by that branch's T (by the chosen T, back in the episode)."""
    env, recorded = cases
    cfg = RolloutConfig(candidates=(1, 10), futures=2, hold=10)
    teacher = distil.Teacher(Alternating(), cfg=cfg)
    restore, step, firsts, after = env.restore_state, env.step, [], [False]

    def spy_restore(state):
        after[0] = True
        return restore(state)

    def spy_step(a):
        if after[0]:
            firsts.append((float(a), env.base_action()))
            after[0] = False
        return step(a)

    monkeypatch.setattr(env, "restore_state", spy_restore)
    monkeypatch.setattr(env, "step", spy_step)
    experiment.rollout(env, teacher, {"case": recorded[0]})
    labels, per = teacher.labels, len(cfg.candidates) * cfg.futures + 1
    assert len(labels) >= 2 and len(firsts) == len(labels) * per
    for i, label in enumerate(labels):
        Ts = [T for T in cfg.candidates for _ in range(cfg.futures)] + [label["T"]]
        for (a_bar, a_base), T in zip(firsts[i * per:(i + 1) * per], Ts):
            assert a_bar == pytest.approx(blend(float(label["a"]), a_base, float(beta(T, omega=6.0))), abs=1e-6)
        assert label["returns"].shape == (2, 2) and label["T"] in cfg.candidates
        np.testing.assert_array_equal(label["eq5"][-1], np.float32(2 * (label["a"] + 3.0) / 5.0 - 1.0))


def test_label_seeds_never_meet_a_test_seed():
    firsts = [distillation.label_seed(0), distillation.label_seed(10_000)]
    tests = {experiment.test_seed(s, r) for s in range(20) for r in range(50)}
    assert not set(range(firsts[0], firsts[1] + 1)) & tests
    assert distillation.label_seed(experiment.test_seed(0, 0) - distillation.LABEL_SEED - 1) < experiment.test_seed(0, 0)
    with pytest.raises(ValueError, match="first test seed"):
        distillation.label_seed(experiment.test_seed(0, 0) - distillation.LABEL_SEED)
    assert min(experiment.test_seed(0, 0), experiment.test_seed(9, 0)) == experiment.test_seed(0, 0)


def test_the_features_are_what_the_ego_sees_and_the_privileged_truth(cases):
    env, recorded = cases
    env.reset(options={"case": recorded[1]})
    for _ in range(25):
        env.step([env.base_action()])
    a = np.array([1.0], np.float32)
    x = distil.features(env, a)
    np.testing.assert_array_equal(x["eq5"], timing_input(env.obs, a, env.cfg))
    assert x["deployed"][0] == pytest.approx(env.s / env.task["dest"])
    routes, kin = x["routes"].reshape(13, len(env.routes)), x["kinematics"].reshape(12, 3)
    assert routes[12, env.routes.index(env.task["route"])] == 1.0
    shown = env.obs[7:].reshape(6, 2, 5)[..., 0].ravel()  # who s_sur shows, slot by slot
    np.testing.assert_array_equal(routes[:12].sum(1), shown)  # a route for every human shown, none elsewhere
    i, j, k, _, _ = world.sector_slots(env.xy, env.heading, env.others, env.cfg)
    h = env.other_ids[k[0]]
    np.testing.assert_allclose(kin[2 * i[0] + j[0]], env.humans[h][5:8] / [4.5, 3.0, 12.0], rtol=1e-6)
    assert routes[2 * i[0] + j[0], env.routes.index(env.sim.vehicle.getRouteID(h))] == 1.0


@pytest.mark.parametrize("loss", distil.Student.LOSSES)
def test_a_student_that_always_prefers_t2_drives_exactly_as_fixed_2(cases, loss):
    """Either loss's student (advantages and a margin, or a decision's scores) whose network puts T = 2 first."""
    env, recorded = cases
    student = distil.Student("A", world.OBS_DIM + 1, loss=loss)
    with torch.no_grad():
        last = student.net[-1]
        last.weight.zero_()
        last.bias.copy_(torch.tensor([-1.0, 0.0, -1.0, -1.0]))  # T = 2 ahead of every other, whatever it sees
    actor = Alternating()
    ep = experiment.rollout(env, distil.DistilledTiming(actor, student), {"case": recorded[2]})
    actor.n = 0
    fixed = experiment.rollout(env, Driver("fixed", actor, fixed_T=2), {"case": recorded[2]})
    assert ep["decisions"] >= 1 and ep["branch_steps"] == 0 and set(ep["T"]) == {2}
    np.testing.assert_array_equal(ep["a_bar"], fixed["a_bar"])
    assert (ep["outcome"], ep["steps"]) == (fixed["outcome"], fixed["steps"])


def test_advantages_regret_and_fit_by_hand(tmp_path):
    cfg = RolloutConfig()  # candidates 1, 2, 3, 10; default 2
    returns = np.array([[[10.0, 12.0], [11.0, 11.0], [0.0, 2.0], [11.0, 11.0]]])  # means 11, 11, 1, 11
    np.testing.assert_array_equal(distil.advantages(returns, cfg), [[0.0, 0.0, -10.0, 0.0]])
    np.testing.assert_array_equal(distil.regret(returns, [3], cfg), [10.0])
    # the labels measured: T = 1 is +1 / +3 / +2 over T = 2 in the three futures, T = 3 a tie, T = 10 -5 in each
    base = np.array([[10.0, 20.0, 30.0], [0.0, 0.0, 0.0]])
    returns = np.stack([np.stack([b + [1, 3, 2], b, b, b - 5]) for b in base])
    returns[1, 0] = [-1.0, -3.0, -2.0]  # the second decision: T = 1 -2 on the mean
    # holding out future 0: futures 1, 2 choose T = 1 (+2.5), worth +1 in future 0; out 1: +1.5 chooses, +3 pays; out 2:
    # +2, +2; the second decision keeps T = 2 (a tie with T = 3) each time
    gain, expected = distil.replicated_gain(returns, cfg)
    np.testing.assert_allclose(gain, [[1.0, 3.0, 2.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(expected, [[2.5, 1.5, 2.0], [0.0, 0.0, 0.0]])
    for j in range(3):  # as the teacher itself would choose from the other futures
        assert [best_candidate(cfg, row) for row in np.delete(returns, j, -1).mean(-1)] == [1, 2]
    rel = distil.reliability(returns, cfg)  # T = 1: labels +2 and -2 (variance 8), s^2 = 1 each: noise 1 / 3
    assert rel[1] == pytest.approx(1 - (1 / 3) / 8) and set(rel) == {1, 3, 10}
    # x > 0: T = 1 gains 20, else T = 10 gains 20; a student learns the rule and chooses by it
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 3)).astype(np.float32)
    adv = np.zeros((400, 4))
    adv[:, 0] = np.where(x[:, 0] > 0, 20.0, -20.0)
    adv[:, 3] = -adv[:, 0]
    student = distil.fit(x, adv, "A", cfg, epochs=60)
    student.save(tmp_path / "s.pt")
    again = distil.Student.load(tmp_path / "s.pt")
    test = np.array([[2.0, 0, 0], [-2.0, 0, 0]], np.float32)
    assert again.choose(test).tolist() == [1, 10] and again.key() == student.key()
    assert distil.groups("C-routes") == ("eq5", "deployed", "kinematics")
    with pytest.raises(ValueError, match="input set"):
        distil.groups("B-routes")


def test_a_bad_student_is_one_line_before_any_work(tmp_path):
    (tmp_path / "bad.pt").write_bytes(b"not a student")
    for spec in ("distilled", f"distilled={tmp_path / 'bad.pt'}"):
        proc = subprocess.run([sys.executable, "tarl.py", "--load", "results/runs/roundabout-tarl-s0/policy.pt",
                               "--scenario", "roundabout", "--timing", spec], cwd=HERE, capture_output=True, text=True,
                              timeout=120)
        last = proc.stderr.strip().splitlines()[-1]  # argparse's usage, then one line
        assert proc.returncode == 2 and last.startswith("tarl.py: error: --timing distilled")
        assert ("not a student" if "=" in spec else "distilled=PATH") in last


DIMS = dict(eq5=world.OBS_DIM + 1, deployed=5, routes=13 * 12, kinematics=36)


def write_chunk(keep: Path, k: int, rng: np.random.Generator, n: int = 40):
    """A chunk of made-up labels in the teacher's layout, 10 cases of 4 decisions: T = 1 gains 20 over the others
    where the first input is high, loses 20 elsewhere."""
    x = {g: rng.random((n, d)).astype(np.float32) for g, d in DIMS.items()}
    returns = rng.normal(50.0, 1.0, (n, 4, 3)).astype(np.float32)
    returns[:, 0] += np.where(x["eq5"][:, :1] > 0.5, 20.0, -20.0)
    T = np.array([RolloutConfig().candidates[i] for i in returns.mean(-1).argmax(1)])
    meta = dict(scenario="roundabout", actor_seed=0, chunk=k)
    np.savez_compressed(keep / f"chunk{k:03d}.npz", meta=json.dumps(meta), returns=returns, T=T,
                        case=np.arange(n) // 4, **x)


def test_train_splits_by_chunk_and_writes_students_and_their_curve(tmp_path):
    """Five chunks of made-up labels (the teacher's layout): chunk 4 is held out, three students and a curve result."""
    rng = np.random.default_rng(0)
    keep = distillation.folder("roundabout", 0, tmp_path)
    keep.mkdir(parents=True)
    for k in range(5):
        write_chunk(keep, k, rng)
    distillation.main(["train", "--scenario", "roundabout", "--out", str(tmp_path), "--students", "A", "C-routes",
                       "--loss", "mse"])
    st = json.loads((tmp_path / "roundabout-s0" / "students.json").read_text())
    assert st["held_out_decisions"] == 40 and st["train_chunks"] == [0, 1, 2, 3]
    assert [c["cases"] for c in st["curve"]["A"]] == [10, 10, 20, 40]  # 1/8 and 1/4 of 4 chunks: at least one
    assert st["results"]["A"]["regret"] < st["baseline"]["T = 2 always"]["regret"]
    student = distil.Student.load(tmp_path / "roundabout-s0" / "C-routes.pt")
    assert student.inputs == "C-routes" and student.mean.numel() == DIMS["eq5"] + 5 + 36 and student.loss == "mse"
    # trained for the decision (the default loss), on the same held-out chunk: chunk 3 validates, 0-2 train
    distillation.main(["train", "--scenario", "roundabout", "--out", str(tmp_path), "--students", "A", "B"])
    st = json.loads((tmp_path / "roundabout-s0-decision" / "students.json").read_text())
    assert st["loss"] == "decision" and st["validation_chunks"] == [3] and st["held_out_decisions"] == 40
    assert [c["cases"] for c in st["curve"]["A"]] == [10, 10, 20, 30]
    assert set(st["results"]["A"]["gate"]) >= {"regret", "default_regret", "low", "high", "passes"}
    assert len(st["stopping"]["A"]["validation_regret"]) > st["stopping"]["A"]["epoch"]  # epoch 0: before training
    assert distil.Student.load(tmp_path / "roundabout-s0-decision" / "B.pt").loss == "decision"
    lower = distillation.lower_regret(tmp_path / "roundabout-s0-decision")
    assert st["results"][lower]["regret"] == min(st["results"][s]["regret"] for s in "AB")
    # the report: a student "evaluated" as TARL itself (its committed eval.json) ties TARL and does not pass
    (tmp_path / "roundabout-s0" / "eval-A.json").write_text((HERE / "results/runs/roundabout-tarl-s0/eval.json").read_text())
    text = distillation.report(argparse.Namespace(out=tmp_path, actor_seed=0))
    assert "| TARL | 2 | " in text and "| 0 / 0 | 1 |" in text
    assert "student A **does not pass**" in text and "student C-routes" in text
    assert "## The teacher's labels" in text and "| roundabout | 0 | the teacher | 200 (50) |" in text
    assert "| roundabout | 0 | decision | before | A | 40 (10) |" in text
    assert "## roundabout, actor seed 0, students trained for their decision" in text
    # a DAgger round: the states student A drove to join the labels, and its students go apart
    (dagger := distillation.folder("roundabout", 0, tmp_path, "A")).mkdir(parents=True)
    write_chunk(dagger, 5, rng)
    distillation.main(["train", "--scenario", "roundabout", "--out", str(tmp_path), "--students", "A", "--dagger", "A",
                       "--loss", "mse"])
    st = json.loads((tmp_path / "roundabout-s0-dagger" / "students.json").read_text())
    assert st["train_chunks"] == [0, 1, 2, 3, 5] and st["held_out_decisions"] == 40 and st["dagger"] == ["A"]
    text = distillation.report(argparse.Namespace(out=tmp_path, actor_seed=0))
    assert "## roundabout, actor seed 0, after one DAgger round" in text
    assert "| roundabout | 0 | student A drove (DAgger) | 40 (10) |" in text
    # a decision student's round can join the committed mse round's labels: each named with its loss
    (dagger := distillation.folder("roundabout", 0, tmp_path, "decision-B")).mkdir(parents=True)
    write_chunk(dagger, 6, rng)
    distillation.main(["train", "--scenario", "roundabout", "--out", str(tmp_path), "--students", "A", "--dagger", "B",
                       "mse-A"])
    st = json.loads((tmp_path / "roundabout-s0-decision-dagger" / "students.json").read_text())
    assert st["dagger"] == ["decision-B", "A"] and st["train_chunks"] == [0, 1, 2, 3, 5, 6]


def test_the_gate_refuses_a_student_that_does_not_beat_the_constant(tmp_path, capsys):
    cfg = RolloutConfig()
    returns = np.zeros((8, 4, 3))
    returns[:, 0] = [[1.0, -1.0, 3.0]] * 4 + [[-3.0, -2.0, -1.0]] * 4  # T = 1: +1 in the first 4 decisions, -2 after
    cases = np.arange(8)  # a case per decision
    stay = distil.gate(returns, [2] * 8, cases, cfg)
    assert stay["diff"] == 0 and not stay["passes"]  # the constant does not beat itself
    assert not distil.gate(returns, [1] * 8, cases, cfg)["passes"]  # -2 on half, +1 on half: worse on the mean
    better = distil.gate(returns, [1] * 4 + [2] * 4, cases, cfg)
    assert better["diff"] == pytest.approx(-0.5) and better["high"] < 0 and better["passes"]
    one_case = distil.gate(returns, [1] * 4 + [2] * 4, np.array([0, 0, 0, 0, 1, 2, 3, 4]), cfg)
    assert one_case["diff"] == better["diff"] and not one_case["passes"]  # the gains all of one case of five: cases
    # evaluate: a student that does not pass is never played (the evaluation itself is not reached)
    rng = np.random.default_rng(1)
    keep = distillation.folder("roundabout", 0, tmp_path)
    keep.mkdir(parents=True)
    for k in range(5):
        write_chunk(keep, k, rng)
    students = distillation.students_dir(tmp_path, "roundabout", 0, False, "decision")
    students.mkdir(parents=True)
    student = distil.Student("A", DIMS["eq5"], loss="decision")
    with torch.no_grad():
        student.net[-1].weight.zero_()
        student.net[-1].bias.copy_(torch.tensor([0.0, 5.0, 0.0, 0.0]))  # T = 2 always: the constant itself
    student.save(students / "A.pt")
    (students / "students.json").write_text(json.dumps(dict(loss="decision", dagger=[], results={"A": {}})))
    distillation.main(["evaluate", "--scenario", "roundabout", "--out", str(tmp_path), "--students", "A"])
    assert "student A: held-out regret" in capsys.readouterr().out and not (students / "eval-A.json").exists()


def test_the_decision_loss_picks_the_larger_mean_advantage():
    """Where the first input is high T = 3 gains +1 on the mean (+4 and -2 in turn), T = 1 a steady +0.5; elsewhere
    every T but the default loses on the mean, though T = 3 gains +2 on every other decision: the default is chosen."""
    cfg = RolloutConfig()  # candidates 1, 2, 3, 10

    def labels(n, seed):
        x = np.random.default_rng(seed).normal(size=(n, 2)).astype(np.float32)
        high, turn = x[:, 0] > 0, np.arange(n) % 2 == 0
        adv = np.zeros((n, 4))
        adv[:, 0] = np.where(high, 0.5, -0.5)
        adv[:, 2] = np.where(high, np.where(turn, 4.0, -2.0), np.where(turn, 2.0, -4.0))
        adv[:, 3] = -3.0
        return x, adv

    x, adv = labels(400, 0)
    student, stop = distil.fit_decision(x, adv, "A", cfg, validation=labels(200, 1), batch=32)
    assert student.loss == "decision" and stop["validation_regret"][stop["epoch"]] < stop["validation_regret"][0]
    assert student.choose(np.array([[1.5, 0.0], [-1.5, 0.0]], np.float32)).tolist() == [3, 2]
    scores = torch.tensor([[0.0, 50.0, 0.0, 0.0], [50.0, 0.0, 0.0, 0.0]])  # a sure T = 2, a sure T = 1
    assert float(distil.decision_loss(scores, torch.tensor([[1.0, 0.0, 2.0, 3.0]] * 2))) == pytest.approx(-0.5)


def test_in_dagger_the_student_drives_and_the_teacher_labels(cases):
    env, recorded = cases
    cfg = RolloutConfig(candidates=(1, 2), futures=1, hold=10)
    student = distil.Student("B", world.OBS_DIM + 1 + 5, cfg)
    with torch.no_grad():
        student.net[-1].weight.zero_()
        student.net[-1].bias.copy_(torch.tensor([1.0, 0.0]))  # always T = 1
    teacher = distil.Teacher(Toward(), cfg=cfg, student=student)
    ep = experiment.rollout(env, teacher, {"case": recorded[1]})
    labels = teacher.labels
    assert labels and all(d["executed"] == 1 for d in labels) and ep["branch_steps"] > 0
    assert [d["T"] for d in labels] == [best_candidate(cfg, d["returns"].mean(1)) for d in labels]  # the teacher's
    assert set(ep["T"]) == {1, 2}  # the student's T = 1 at its decisions, held; the default elsewhere


def test_the_registered_test_pools_the_students_of_record_and_asks_two_seeds_ahead(tmp_path):
    """Per seed the student of record (lower held-out regret of A and B) against the seed's tarl-random-t: it passes
    only with pooled McNemar p < 0.025, the student ahead, and ahead on at least 2 of the 3 seeds."""
    def write(path: Path, algo: str, arrived: list[bool]):
        cases = [dict(round=0, case=c, start=f"s{c}", outcome="arrival" if a else "collision", crossing_time=20.0
                      if a else None, steps=100) for c, a in enumerate(arrived)]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(dict(scenario="intersection", seed=0, rows=[dict(algo=algo, cases=cases)])))

    def play(only_student: dict[int, int], only_row: dict[int, int]) -> list[str]:
        runs = tmp_path / "runs"
        for k in (0, 3, 4):
            folder = distillation.students_dir(tmp_path, "intersection", k, True, "decision")
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "students.json").write_text(json.dumps(dict(results={"A": dict(regret=2.0), "B": dict(regret=1.0)})))
            a, b, same = only_student[k], only_row[k], 100
            write(folder / "eval-B.json", "tarl", [True] * a + [False] * b + [True] * same)
            write(runs / f"intersection-tarl-random-t-s{k}" / "eval.json", "tarl-random-t",
                  [False] * a + [True] * b + [True] * same)
        return distillation.registered_test(tmp_path, runs)

    assert distillation.registered_test(tmp_path, tmp_path / "runs") == []  # nothing played yet
    text = "\n".join(play({0: 20, 3: 20, 4: 0}, {0: 5, 3: 5, 4: 5}))  # 40 / 15 pooled, ahead on 2 seeds
    assert "| 0 | B | " in text and "| pooled | " in text and "40 / 15" in text and "**pass**" in text
    assert "**fail**" in "\n".join(play({0: 30, 3: 0, 4: 0}, {0: 1, 3: 5, 4: 5}))  # 30 / 11 pooled, ahead on 1 seed
    assert "**fail**" in "\n".join(play({0: 8, 3: 8, 4: 8}, {0: 5, 3: 5, 4: 5}))  # ahead on 3, p 0.14
