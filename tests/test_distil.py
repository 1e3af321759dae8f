"""The distilled timing (beyond/distil.py, bench/distillation.py): the teacher's labels, the students, on the real simulator."""
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


def test_a_student_that_always_prefers_t2_drives_exactly_as_fixed_2(cases):
    env, recorded = cases
    student = distil.Student("A", world.OBS_DIM + 1)
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


def test_train_splits_by_chunk_and_writes_students_and_their_curve(tmp_path):
    """Five chunks of made-up labels (the teacher's layout): chunk 4 is held out, three students and a curve result."""
    rng, cfg = np.random.default_rng(0), RolloutConfig()
    keep = distillation.folder("roundabout", 0, tmp_path)
    keep.mkdir(parents=True)
    dims = dict(eq5=world.OBS_DIM + 1, deployed=5, routes=13 * 12, kinematics=36)

    def write(keep, k, n=40):
        x = {g: rng.random((n, d)).astype(np.float32) for g, d in dims.items()}
        returns = rng.normal(50.0, 1.0, (n, 4, 3)).astype(np.float32)
        returns[:, 0] += np.where(x["eq5"][:, :1] > 0.5, 20.0, -20.0)  # T = 1 pays where the first input is high
        T = np.array([cfg.candidates[i] for i in returns.mean(-1).argmax(1)])
        meta = dict(scenario="roundabout", actor_seed=0, chunk=k)
        np.savez_compressed(keep / f"chunk{k:03d}.npz", meta=__import__("json").dumps(meta), returns=returns, T=T,
                            case=np.arange(n) // 4, **x)
    for k in range(5):
        write(keep, k)
    distillation.main(["train", "--scenario", "roundabout", "--out", str(tmp_path), "--students", "A", "C-routes"])
    st = __import__("json").loads((tmp_path / "roundabout-s0" / "students.json").read_text())
    assert st["held_out_decisions"] == 40 and st["train_chunks"] == [0, 1, 2, 3]
    assert [c["cases"] for c in st["curve"]["A"]] == [10, 10, 20, 40]  # 1/8 and 1/4 of 4 chunks: at least one
    assert st["results"]["A"]["regret"] < st["baseline"]["T = 2 always"]["regret"]
    student = distil.Student.load(tmp_path / "roundabout-s0" / "C-routes.pt")
    assert student.inputs == "C-routes" and student.mean.numel() == dims["eq5"] + 5 + 36
    # the report: a student "evaluated" as TARL itself (its committed eval.json) ties TARL and does not pass
    (tmp_path / "roundabout-s0" / "eval-A.json").write_text((HERE / "results/runs/roundabout-tarl-s0/eval.json").read_text())
    text = distillation.report(__import__("argparse").Namespace(out=tmp_path, actor_seed=0))
    assert "| TARL | 2 | " in text and "| 0 / 0 | 1 |" in text
    assert "student A **does not pass**" in text and "student C-routes" in text
    # a DAgger round: the states student A drove to join the labels, and its students go apart
    (dagger := distillation.folder("roundabout", 0, tmp_path, "A")).mkdir(parents=True)
    write(dagger, 5)
    distillation.main(["train", "--scenario", "roundabout", "--out", str(tmp_path), "--students", "A", "--dagger", "A"])
    st = __import__("json").loads((tmp_path / "roundabout-s0-dagger" / "students.json").read_text())
    assert st["train_chunks"] == [0, 1, 2, 3, 5] and st["held_out_decisions"] == 40
    text = distillation.report(__import__("argparse").Namespace(out=tmp_path, actor_seed=0))
    assert "## roundabout, actor seed 0, after one DAgger round" in text


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
