"""Algorithm 1 on the real simulator: short runs that really learn, checkpoints, determinism, the command line."""
import hashlib
import json
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import experiment
import tarl
import world
from tarl import SACConfig, TrainConfig
from world import EnvConfig

# a short schedule with small networks: every phase of Algorithm 1 runs, and both agents update
SMALL_SAC = SACConfig(batch_size=32, buffer_size=5_000, learning_starts=100, hidden=32)
SMALL = TrainConfig(steps=900, sac_fraction=0.2, n_timing=5, n_actor=15, timing_pretrain=0.1,
                    timing_learning_starts=10, log_every=10**9, checkpoint_every=10**9)
QUIET = dict(log=lambda *a: None)


@pytest.fixture(scope="module")
def env():
    env = world.DrivingEnv(EnvConfig(scenario="intersection"))
    yield env
    env.close()


def test_short_tarl_run_updates_both_agents_and_writes_a_checkpoint_that_loads(env, tmp_path):
    trainer = tarl.Trainer(env, "tarl", SMALL, SMALL_SAC, seed=1, out=tmp_path, **QUIET)
    before = [p.detach().clone() for p in trainer.timing_taker.policy.parameters()]
    trainer.run()
    assert trainer.step >= SMALL.steps
    assert trainer.updates["actor"] > 50 and trainer.updates["timing"] > 5  # Alg. 1 lines 13-14, 22-23
    assert any(not torch.equal(a, b) for a, b in zip(before, trainer.timing_taker.policy.parameters()))
    assert len(trainer.D_T) > SMALL.n_timing and trainer.sac_actor is not None
    assert trainer.step_one >= SMALL.sac_fraction * SMALL.steps
    # the checkpoint loads with weights_only=True into a fresh trainer and acts the same
    state = experiment.load_checkpoint(tmp_path / "ckpt.pt", "intersection", "tarl")
    assert state["step"] == trainer.step
    fresh = tarl.Trainer(env, "tarl", SMALL, SMALL_SAC, seed=2, **QUIET)
    fresh.load(state, resume=True)
    obs = np.random.default_rng(0).uniform(0, 1, (4, world.OBS_DIM)).astype(np.float32)
    np.testing.assert_array_equal(fresh.actor.act(obs, True), trainer.actor.act(obs, True))
    x = np.concatenate([obs, np.zeros((4, 1), np.float32)], 1)
    np.testing.assert_array_equal(fresh.timing_taker.act(x, True), trainer.timing_taker.act(x, True))
    assert fresh.step == trainer.step and len(fresh.D_a) == len(trainer.D_a)
    # policy.pt: the policies alone, small, enough to act
    policy = experiment.load_checkpoint(tmp_path / "policy.pt", "intersection", "tarl")
    actor_only = tarl.Trainer(env, "tarl", SMALL, SMALL_SAC, seed=3, **QUIET)
    actor_only.load(policy, resume=False)
    np.testing.assert_array_equal(actor_only.actor.act(obs, True), trainer.actor.act(obs, True))
    assert actor_only.sac_actor is not None and (tmp_path / "policy.pt").stat().st_size < 1e6
    # train_log.csv: one row per episode, each from one loop
    log = (tmp_path / "train_log.csv").read_text().splitlines()
    assert log[0] == ",".join(tarl.LOG_HEADER)
    loops = {row.split(",")[1] for row in log[1:]}
    assert loops == {"step1", "imagination", "real"}


def test_a_checkpoint_for_another_model_is_refused(env, tmp_path):
    trainer = tarl.Trainer(env, "sac", TrainConfig(steps=150, n_actor=15), SMALL_SAC, seed=1, out=tmp_path, **QUIET)
    trainer.run()
    with pytest.raises(SystemExit, match="--algo sac"):
        experiment.load_checkpoint(tmp_path / "ckpt.pt", "intersection", "tarl")
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(SystemExit, match="cannot load checkpoint"):
        experiment.load_checkpoint(tmp_path / "bad.pt", "intersection", "sac")
    with pytest.raises(SystemExit, match="not found"):
        experiment.load_checkpoint(tmp_path / "missing.pt", "intersection", "sac")


def test_same_seed_gives_the_same_evaluation(env):
    def run():
        trainer = tarl.Trainer(env, "tarl", SMALL, SMALL_SAC, seed=5, **QUIET)
        trainer.run()
        return experiment.evaluate(env.cfg, experiment.trained_rows(trainer), rounds=2, cases=2, seed=5, workers=0, env=env, **QUIET)
    first, second = run(), run()
    assert first == second
    tarl_row = first[0]
    assert "beta_minus" in tarl_row and len(tarl_row["cases"]) == 4
    rates = [tarl_row[k]["mean"] for k in ("success_rate", "collision_rate", "timeout_rate")]
    assert sum(rates) == pytest.approx(1.0)
    assert sum(tarl_row["timing_share"]["all_steps"]) == pytest.approx(1.0, abs=1e-3)


def test_an_interrupted_evaluation_plays_only_the_rounds_it_had_not_finished(env, tmp_path, monkeypatch):
    def rows(weights_seed):
        torch.manual_seed(weights_seed)
        actor = tarl.SAC(world.OBS_DIM, act_dim=1, low=[env.cfg.a_min], high=[env.cfg.a_max], cfg=SMALL_SAC)
        return [dict(algo="sac", driver=tarl.Driver("none", actor)), dict(algo="lattice-idm", driver=tarl.Driver("planner"))]

    def evaluate(rows, **kw):
        return experiment.evaluate(env.cfg, rows, rounds=3, cases=2, seed=0, workers=0, env=env, **kw)

    whole = evaluate(rows(0), **QUIET)

    def stop_after_two_rounds(line):
        if "[2/3 rounds" in line:
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        evaluate(rows(0), log=stop_after_two_rounds, keep=tmp_path)
    played, play_round = [], experiment.play_round
    monkeypatch.setattr(experiment, "play_round", lambda *a: played.append(a[-1]) or play_round(*a))
    assert evaluate(rows(0), keep=tmp_path, **QUIET) == whole  # the same numbers, down to every case
    assert len(played) == 1  # one of the three rounds left
    played.clear()
    evaluate(rows(1), keep=tmp_path, **QUIET)  # another actor: nothing kept applies
    assert played == [0, 1, 2]


@pytest.mark.parametrize("argv", [["--scenario", "highway"], ["--algo", "ppo"], ["--eval-rounds", "0"],
                                  ["--gui", "--algo", "tarl"]])
def test_bad_command_lines_get_argparse_errors(argv, tmp_path):
    with pytest.raises(SystemExit) as e:
        experiment.parse_args([*argv, "--out", str(tmp_path / "run")])
    assert e.value.code == 2


def test_machine_names_the_cpu_type_not_only_its_name():
    """eval.json's machine: one CPU name ("AMD EPYC") covers types on which a seed's floats part, so it also gives
    /proc/cpuinfo's family, model, stepping and its flags' md5, where the kernel reports them."""
    info = Path("/proc/cpuinfo")
    cpu = dict(map(str.strip, line.split(":", 1)) for line in (info.read_text() if info.exists() else "").split(
        "\n\n")[0].splitlines() if ":" in line)  # none without /proc: then the name is platform.processor()'s
    said = experiment.machine().split(", ")
    assert said[0] == (cpu.get("model name") or platform.processor() or "unknown CPU")
    for key in ("cpu family", "model", "stepping"):
        assert key not in cpu or f"{key} {cpu[key]}" in said
    assert "flags" not in cpu or f"flags md5 {hashlib.md5(cpu['flags'].encode()).hexdigest()[:12]}" in said


def test_bad_outputs_and_checkpoints_fail_before_any_work(tmp_path, capsys):
    (tmp_path / "a-file").write_text("")
    with pytest.raises(SystemExit, match="cannot be written"):
        experiment.parse_args(["--out", str(tmp_path / "a-file")])
    with pytest.raises(SystemExit, match="not found"):
        experiment.parse_args(["--out", str(tmp_path / "run"), "--load", str(tmp_path / "missing.pt")])
    with pytest.raises(SystemExit, match="not found"):
        experiment.parse_args(["--out", str(tmp_path / "fresh"), "--resume"])


def test_the_command_line_evaluates_the_planner_and_writes_every_case(tmp_path, capsys):
    experiment.main(["--scenario", "intersection", "--algo", "lattice-idm", "--eval-rounds", "1", "--eval-cases", "3",
               "--out", str(tmp_path), "--workers", "0"])
    result = json.loads((tmp_path / "eval.json").read_text())
    row = result["rows"][0]
    assert row["algo"] == "lattice-idm" and [c["case"] for c in row["cases"]] == [0, 1, 2]
    assert {c["outcome"] for c in row["cases"]} <= {"arrival", "collision", "timeout"}
    assert "Lattice-IDM" in capsys.readouterr().out


def test_the_command_line_keeps_finished_rounds_when_interrupted_and_plays_the_rest_in_a_worker(env, tmp_path,
                                                                                               monkeypatch):
    argv = ["--scenario", "intersection", "--algo", "lattice-idm", "--eval-rounds", "2", "--eval-cases", "2",
            "--out", str(tmp_path)]
    play_round = experiment.play_round

    def interrupt_round_1(*a):
        if a[-1] == 1:
            raise KeyboardInterrupt
        return play_round(*a)
    monkeypatch.setattr(experiment, "play_round", interrupt_round_1)
    with pytest.raises(SystemExit, match="kept the finished rounds in .*eval-rounds; run the same command again"):
        experiment.main([*argv, "--workers", "0"])
    assert [f.name for f in (tmp_path / "eval-rounds").iterdir()] == ["round0.json"]
    monkeypatch.setattr(experiment, "play_round", play_round)
    experiment.main([*argv, "--workers", "1"])  # round 1 in a worker process
    row = json.loads((tmp_path / "eval.json").read_text())["rows"][0]
    whole = experiment.evaluate(env.cfg, [dict(algo="lattice-idm", label="Lattice-IDM", driver=tarl.Driver("planner"))],
                          rounds=2, cases=2, seed=0, workers=0, env=env, **QUIET)[0]
    assert row == json.loads(json.dumps(whole))
    assert not (tmp_path / "eval-rounds").exists()


def test_a_run_stopped_while_evaluating_resumes_to_evaluate_without_training_more(tmp_path, monkeypatch):
    """The grid's case at a session's end: the whole budget trained, the evaluation cut off. --resume with the same
    --steps (what bench/table3.py runs) plays the rounds that are missing and trains no further."""
    argv = ["--scenario", "intersection", "--algo", "sac", "--steps", "150", "--eval-rounds", "2", "--eval-cases", "1",
            "--out", str(tmp_path), "--workers", "0"]
    play_round = experiment.play_round
    monkeypatch.setattr(experiment, "play_round", lambda *a: (_ for _ in ()).throw(KeyboardInterrupt) if a[-1] == 1
                        else play_round(*a))
    with pytest.raises(SystemExit, match="kept the finished rounds in .*; continue with --resume"):
        experiment.main(argv)
    trained = (tmp_path / "train_log.csv").read_text()
    monkeypatch.setattr(experiment, "play_round", play_round)
    experiment.main([*argv, "--resume"])
    assert (tmp_path / "train_log.csv").read_text() == trained
    assert [c["round"] for c in json.loads((tmp_path / "eval.json").read_text())["rows"][0]["cases"]] == [0, 1]


def test_the_progress_eta_follows_the_recent_rate_not_the_fast_warm_up(monkeypatch):
    now, lines = [0.0], []
    monkeypatch.setattr(tarl.time, "time", lambda: now[0])
    log = tarl.TrainLog(None, 100_000, log=lines.append)
    for step in range(2_000, 22_001, 2_000):  # 1,000 steps/s for 4,000 steps, then 100 steps/s
        log.progress(step, "x")
        now[0] += 2.0 if step < 6_000 else 20.0
    assert " 100 steps/s, training ETA  13.0 min" in lines[-1]  # (100,000 - 22,000) / 100 s


def test_the_first_progress_line_gives_no_eta_from_the_warm_up(monkeypatch):
    """The steps before SAC's first update run several times faster: their rate gives no ETA."""
    now, lines = [0.0], []
    monkeypatch.setattr(tarl.time, "time", lambda: now[0])
    log = tarl.TrainLog(None, 100_000, log=lines.append)
    log.progress(0, "")
    now[0] += 2.0
    log.progress(2_000, "Alg. 1 step 1, SAC", warm_up=True)
    now[0] += 20.0
    log.progress(4_000, "Alg. 1 step 1, SAC")
    assert "training ETA after the warm-up" in lines[0] and "ETA  16.0 min" in lines[1]  # 96,000 steps at 100/s


@pytest.mark.parametrize("algo", ["tarl-consistent", "tarl-held", "tarl-utd"])
def test_short_runs_of_the_variants_update_both_agents_and_their_checkpoints_load(algo, env, tmp_path):
    """The variants beyond the paper (PAPER.md, 6), as experiment.ROWS builds them: every phase runs, both
    agents update, and the checkpoint acts the same in a fresh trainer with the variant's own loops."""
    small = dict(config=dict(sac=vars(SMALL_SAC)))  # make_trainer takes the networks' sizes from a checkpoint's
    trainer = experiment.make_trainer(algo, env, SMALL, seed=1, out=tmp_path, state=small, **QUIET)
    assert trainer.driver.timing == experiment.ROWS[algo].timing and trainer.tc.imagination == experiment.ROWS[algo].imagination
    trainer.run()
    assert trainer.updates["actor"] > 50 and trainer.updates["timing"] > 5
    # lines 13-14 after each decision once D_T holds timing_learning_starts: timing_updates updates each
    decisions = len(trainer.D_T) - trainer.tc.timing_learning_starts + 1
    assert trainer.updates["timing"] == experiment.ROWS[algo].timing_updates * decisions == trainer.tc.timing_updates * decisions
    state = experiment.load_checkpoint(tmp_path / "ckpt.pt", "intersection", algo)
    assert state["config"]["train"]["imagination"] == experiment.ROWS[algo].imagination
    fresh = experiment.make_trainer(algo, env, SMALL, seed=2, state=state, **QUIET)
    fresh.load(state, resume=True)
    obs = np.random.default_rng(0).uniform(0, 1, (4, world.OBS_DIM)).astype(np.float32)
    x = np.concatenate([obs, np.zeros((4, 1), np.float32)], 1)
    np.testing.assert_array_equal(fresh.timing_taker.act(x, True), trainer.timing_taker.act(x, True))
    assert fresh.driver.timing == trainer.driver.timing and fresh.tc.imagination == trainer.tc.imagination


def test_a_resumed_run_refuses_a_budget_it_has_already_passed(env, tmp_path):
    trainer = tarl.Trainer(env, "sac", TrainConfig(steps=150, n_actor=15), SMALL_SAC, seed=1, out=tmp_path, **QUIET)
    trainer.run()
    with pytest.raises(SystemExit, match="is at step .*give --steps above both"):
        experiment.parse_args(["--scenario", "intersection", "--algo", "sac", "--out", str(tmp_path), "--resume",
                               "--steps", "100"])
    args = experiment.parse_args(["--scenario", "intersection", "--algo", "sac", "--out", str(tmp_path), "--resume",
                                  "--steps", "5000"])
    assert args.state["step"] == trainer.step and args.steps == 5000
    # the run's own budget, all trained: a run stopped while evaluating resumes to play the rounds it lacks
    args = experiment.parse_args(["--scenario", "intersection", "--algo", "sac", "--out", str(tmp_path), "--resume",
                                  "--steps", "150"])
    assert args.state["step"] >= 150 and args.steps == 150


def test_step_one_sets_the_length_of_step_1_and_a_resumed_run_keeps_its_own(env, tmp_path):
    """--step-one (the budget-equalised ablations of docs/RESULTS.md): Alg. 1's step 1 runs that many steps, then on to
    its episode's end; a resume with another length is refused, and rows without a step 1 refuse it."""
    trainer = tarl.Trainer(env, "tarl-fixed-t", TrainConfig(steps=900, sac_fraction=100 / 900, n_actor=15), SMALL_SAC,
                           seed=1, out=tmp_path, timing="fixed", **QUIET)
    trainer.run()
    assert 100 <= trainer.step_one < 900 and trainer.sac_actor is not None
    base = ["--scenario", "intersection", "--algo", "tarl-fixed-t", "--out", str(tmp_path), "--resume", "--steps", "1000"]
    with pytest.raises(SystemExit, match="has a step 1 of .* not --step-one 200"):
        experiment.parse_args([*base, "--step-one", "200"])
    assert experiment.parse_args([*base, "--step-one", str(trainer.step_one)]).state["step_one"] == trainer.step_one
    for algo, steps in (("sac", "400"), ("tarl-fixed-t", "100")):
        with pytest.raises(SystemExit):  # no step 1; a step 1 as long as the run
            experiment.parse_args(["--algo", algo, "--steps", steps, "--step-one", "100", "--out", str(tmp_path / "x")])


def test_rows_evaluated_beside_training_are_the_rows_evaluated_together(tmp_path):
    """With workers to spare, Lattice-IDM is evaluated while TARL trains and the step-1 model once step 1 ends, each
    in a process of its own: every case comes out as when the finished run's three rows are evaluated together."""
    cases = ["--scenario", "intersection", "--eval-rounds", "1", "--eval-cases", "2"]
    experiment.main([*cases, "--steps", "300", "--step-one", "150", "--out", str(tmp_path / "run"), "--workers", "2"])
    assert (tmp_path / "run" / "sac.pt").exists() and not (tmp_path / "run" / "eval-rounds").exists()
    experiment.main([*cases, "--load", str(tmp_path / "run" / "policy.pt"), "--out", str(tmp_path / "again"),
                     "--workers", "0"])
    beside, together = (json.loads((tmp_path / d / "eval.json").read_text())["rows"] for d in ("run", "again"))
    assert [r["algo"] for r in beside] == [r["algo"] for r in together] == ["tarl", "tarl-step1", "lattice-idm"]
    for x, y in zip(beside, together):
        assert x["cases"] == y["cases"] and x["success_rate"] == y["success_rate"]


def test_the_command_line_loads_baselines_and_beyond_only_for_their_rows():
    """`python tarl.py` needs tarl.py and experiment.py (its import circle), not the safe-RL rows or beyond/."""
    code = "import sys, experiment; print(sorted(m for m in sys.modules if m.split('.')[0] in ('baselines', 'beyond')))"
    out = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).resolve().parents[1], capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == "[]"
