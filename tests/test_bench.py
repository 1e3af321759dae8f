"""The speed benchmark runs end to end (a smoke test: no timing is asserted, the machine is shared)."""
import itertools
import json
import math
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

import speed  # noqa: E402

KEYS = ("sac_updates_per_s", "sac_plain_updates_per_s", "sac_ratio", "timing_updates_per_s",
        "env_steps_per_s", "sumo_raw_steps_per_s", "planner_calls_per_s", "train_steps_per_s", "train_ppo_lag_steps_per_s",
        "train_cpo_steps_per_s", "cases_record_s",
        "cases_load_ms")


def test_speed_quick_prints_every_number_the_issue_asks_for(capsys):
    speed.main(["--quick", "--json"])
    r = json.loads(capsys.readouterr().out)
    for key in KEYS:
        assert key in r, key
    for sc in ("intersection", "roundabout"):
        assert r["env_steps_per_s"][sc] > 0 and r["sumo_raw_steps_per_s"][sc] > 0
        assert r["env"][sc]["vehicles_full"] > 0
    assert r["sac_updates_per_s"] > 0 and r["planner_calls_per_s"] > 0 and r["train_steps_per_s"] > 0
    assert r["train_ppo_lag_steps_per_s"] > 0 and r["train_cpo_steps_per_s"] > 0
    assert r["planner_candidates"] > 1
    assert 0.3 < r["sac_gflop_per_update"] < 2.0  # Table 2's sizes: about 0.64 GFLOP per update


import table3  # noqa: E402


def _row(algo, seed, success, starts):
    stat = lambda m: {"mean": m, "std": 0.01}  # noqa: E731
    return {"algo": algo, "train_steps": 100, "seed": seed, "success_rate": stat(success),
            "collision_rate": stat(1 - success), "timeout_rate": stat(0.0), "crossing_time": stat(20.0),
            "crossing_time_all": stat(20.0), "cases": [{"start": s} for s in starts]}


def _results(tmp_path, cells):
    """A results/ tree with one eval.json per (cell name, scenario, seed, rows)."""
    for name, scenario, seed, rows in cells:
        (tmp_path / "runs" / name).mkdir(parents=True)
        (tmp_path / "runs" / name / "eval.json").write_text(json.dumps({"scenario": scenario, "seed": seed, "rows": rows}))
    return table3.load(tmp_path)


def test_table3_averages_over_seeds_keeps_budgets_apart_and_finds_odd_starts(tmp_path):
    found = _results(tmp_path, [
        ("roundabout-sac-s0", "roundabout", 0, [_row("sac", 0, 0.8, "abc")]),
        ("roundabout-sac-s1", "roundabout", 1, [_row("sac", 1, 0.9, "def")]),
        ("roundabout-tarl-s1", "roundabout", 1, [_row("tarl", 1, 0.7, "dxf"), _row("lattice-idm", 1, 0.5, "def")]),
        ("roundabout-tarl-s0-500k", "roundabout", 0, [_row("tarl", 0, 0.95, "abc")]),
        ("roundabout-tarl-fixed-t-s0-67k-step1-40k", "roundabout", 0, [_row("tarl-fixed-t", 0, 0.6, "abc")])])
    assert table3.cell_name("roundabout", "tarl", 0, 500_000) == "roundabout-tarl-s0-500k"
    assert table3.cell_name("roundabout", "tarl", 0, table3.STEPS) == "roundabout-tarl-s0"
    assert table3.cell_name("roundabout", "tarl-fixed-t", 0, 67_000, 40_000) == "roundabout-tarl-fixed-t-s0-67k-step1-40k"
    assert table3.cell_name("roundabout", "tarl", 0, table3.STEPS, 40_000) == "roundabout-tarl-s0-100k-step1-40k"
    assert table3.by_budget(found) == [(67_000, 40_000), table3.DEFAULT, (500_000, None)]
    mean, seed_std, round_std, n = table3.over_seeds(found[table3.DEFAULT][("roundabout", "sac")], "success_rate")
    assert (round(mean, 6), round(seed_std, 6), round_std, n) == (0.85, 0.05, 0.01, 2)
    # seed 1: TARL's second case began differently from SAC's and Lattice-IDM's
    assert any("seed 1" in line and "TARL 1" in line for line in table3.same_cases(found))
    assert any("seed 0" in line and "every row met the same cases" in line for line in table3.same_cases(found))
    # seed by seed: a row without a seed shows "-" there; each budget has its own table
    seeds = table3.each_seed(found)
    assert "| 100,000 | roundabout | SAC | 0.800 (0.200 / 0.000), 20.0 s | 0.900 (0.100 / 0.000), 20.0 s |" in seeds
    assert "| 100,000 | roundabout | Lattice-IDM | - | 0.500 (0.500 / 0.000), 20.0 s |" in seeds
    assert "| 500,000 | roundabout | TARL | 0.950 (0.050 / 0.000), 20.0 s |" in seeds
    assert "| 67,000 (step 1: 40,000) | roundabout | TARL, T = 2 fixed | 0.600 (0.400 / 0.000), 20.0 s |" in seeds


def test_table3_rewrites_only_the_readme_blocks_between_its_markers(tmp_path):
    found = _results(tmp_path, [("intersection-tarl-s0", "intersection", 0, [_row("tarl", 0, 0.9, "a")]),
                                ("intersection-tarl-s1", "intersection", 1, [_row("tarl", 1, 0.8, "a")])])
    readme = tmp_path / "README.md"
    readme.write_text("before\n<!-- table3.py results -->\nold table\n<!-- /table3.py -->\nbetween\n"
                      "<!-- table3.py timing -->\n<!-- /table3.py -->\nafter\n")
    table3.write_readme(found, readme)
    once = readme.read_text()
    table3.write_readme(found, readme)
    assert readme.read_text() == once  # idempotent
    assert "old table" not in once and once.startswith("before\n") and once.endswith("after\n") and "\nbetween\n" in once
    tarl_lines = [line for line in once.splitlines() if line.startswith("| TARL |")]
    assert len(tarl_lines) == 2  # both blocks; the paper's values only in the results block
    # no bold, even for the only row: no test picks a best row
    assert tarl_lines[0].startswith("| TARL | n = 2 | 0.850 +- 0.050 (0.010) | 0.150 / 0.000 | 20.0 | "
                                    "0.881 (0.021), 8.5 s | - | - | - | - |"), tarl_lines[0]
    assert "0.881" not in tarl_lines[1]


def test_table3_commands_resume_a_cell_with_a_checkpoint(tmp_path):
    args = table3.argparse.Namespace(work=tmp_path, steps=500_000, step_one=None, rounds=10, cases=200)
    cmd = table3.command("roundabout", "tarl", 0, args, 1)
    assert "--resume" not in cmd and cmd[cmd.index("--threads") + 1] == "1" and cmd[cmd.index("--eval-rows") + 1] == "all"
    (tmp_path / "roundabout-tarl-s0-500k").mkdir()
    (tmp_path / "roundabout-tarl-s0-500k" / "ckpt.pt").write_bytes(b"")
    assert table3.command("roundabout", "tarl", 0, args, 1)[-1] == "--resume"
    args.steps, args.step_one = 67_000, 40_000  # the ablations with TARL's real-loop budget
    cmd = table3.command("roundabout", "tarl-fixed-t", 0, args, 1)
    assert cmd[cmd.index("--step-one") + 1] == "40000" and str(tmp_path / "roundabout-tarl-fixed-t-s0-67k-step1-40k") in cmd
    assert [c[0] for c in table3.cells(["tarl"], [0], ["roundabout"])] == ["roundabout"]


def test_table3_a_cell_is_run_by_one_grid_only_and_never_again_once_done(tmp_path):
    args = table3.argparse.Namespace(work=tmp_path / "grid", results=tmp_path / "results", steps=table3.STEPS, step_one=None)
    cell = ("intersection", "sac", 1)
    first = table3.claim(cell, args)
    assert first is not None and first[0] == tmp_path / "grid" / "intersection-sac-s1"
    assert table3.claim(cell, args) is None  # a second grid process skips it while the first holds it
    first[1].close()
    second = table3.claim(cell, args)
    assert second is not None  # released when the first ends
    second[1].close()
    (args.results / "runs" / "intersection-sac-s1").mkdir(parents=True)
    (args.results / "runs" / "intersection-sac-s1" / "eval.json").write_text("{}")
    assert table3.claim(cell, args) is None  # done


def test_table3_counts_case_by_case_where_only_one_of_two_arrives(tmp_path):
    def row(algo, outcomes):
        r = _row(algo, 0, 0.5, "a" * len(outcomes))
        r["cases"] = [{"round": 0, "case": i, "start": "a", "outcome": o} for i, o in enumerate(outcomes)]
        return r
    found = _results(tmp_path, [
        ("roundabout-tarl-s0", "roundabout", 0, [row("tarl", ["arrival", "arrival", "timeout", "collision", "arrival"]),
                                                 row("lattice-idm", ["timeout"] * 5)]),
        ("roundabout-tarl-fixed-t-s0", "roundabout", 0, [row("tarl-fixed-t", ["arrival", "collision", "arrival",
                                                                              "arrival", "timeout"])])])
    lines = table3.case_by_case(found)
    assert "| 100,000 | roundabout | 0 | TARL, T = 2 fixed | 1 / 1 | 1 / 1 |" in lines
    assert "| 100,000 | roundabout | 0 | Lattice-IDM | 0 / 3 | 0 / 0 |" in lines
    assert len(lines) == 4  # the header, its rule and the two comparisons


def test_table3_commits_just_the_files_it_is_given(tmp_path, monkeypatch):
    """The commit of a finished cell (bench/table3.py and bench/retime.py): those files, nothing else staged."""
    git = lambda *a: subprocess.run(["git", "-C", str(tmp_path), *a], capture_output=True, text=True, check=True).stdout  # noqa: E731
    git("init", "-q")
    git("config", "user.email", "t@t")
    git("config", "user.name", "t")
    (tmp_path / "cell.json").write_text("{}")
    (tmp_path / "other.txt").write_text("not this")
    monkeypatch.setattr(table3, "ROOT", tmp_path)
    table3.commit([tmp_path / "cell.json"], "Table 3 grid: a cell")
    assert git("log", "--format=%s") == "Table 3 grid: a cell\n"
    assert git("show", "--name-only", "--format=") == "cell.json\n" and "?? other.txt" in git("status", "--short")


def test_table3_a_relative_work_directory_is_the_callers_not_the_repositorys(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results" / "runs").mkdir(parents=True)
    table3.main(["--work", "cells", "--results", "results", "--algos", "sac", "--seeds", "4",
                 "--scenarios", "intersection", "--print-commands"])
    out = capsys.readouterr().out.split()
    assert out[out.index("--out") + 1] == str(tmp_path / "cells" / "intersection-sac-s4")


def test_table3_sets_the_papers_budget_beside_the_default_one_of_the_same_seed(tmp_path):
    def played(row, outcomes):
        row["cases"] = [{"round": 0, "case": i, "start": "a", "outcome": o} for i, o in enumerate(outcomes)]
        return row
    found = _results(tmp_path, [
        ("roundabout-sac-lag-s0", "roundabout", 0, [_row("sac-lag", 0, 0.9, "a")]),
        ("roundabout-sac-lag-s1", "roundabout", 1, [_row("sac-lag", 1, 0.5, "a")]),
        ("roundabout-sac-lag-s0-500k", "roundabout", 0, [played(_row("sac-lag", 0, 0.95, "a"),
                                                                ["arrival", "collision", "timeout", "arrival"])]),
        ("roundabout-tarl-s0-500k", "roundabout", 0, [played(_row("tarl", 0, 0.75, "a"),
                                                             ["collision", "arrival", "arrival", "arrival"])]),
        ("roundabout-sac-s0", "roundabout", 0, [_row("sac", 0, 0.7, "a")])])
    lines = table3.budget_block(found, ("sac-lag", "sac", "cpo"))
    # case by case against TARL's 500k cell: TARL alone arrives in cases 1 and 2, SAC-Lag alone in case 0; TARL's
    # success minus SAC-Lag's, 3/4 - 2/4. Its interval resamples the 4 cases: (only TARL, only SAC-Lag) arrives in
    # (k, j) of them, multinomial (1/2, 1/4, 1/4 the same); (k - j) / 4 is -3/4 or less with P = 0.0195 < 2.5 % and
    # -1/2 or less with 0.074, 1 with P = 1/16 > 2.5 %: [-0.5, +1]
    assert ("| roundabout | SAC-Lag | n = 1 | 0.950 (0.010) | 0.050 / 0.000 | 20.0 | 0.900 | 0.872 | "
            "+0.250 [-0.500, +1.000] | 2 / 1 |") in lines, lines
    assert "| roundabout | SAC | n = 1 | not run | - | - | 0.700 | - | - | - |" in lines
    assert len(lines) == 4  # the header, its rule, and no line for a row with no cell of seed 0 at all


def test_table3_adds_a_cells_wall_time_over_the_stretches_it_ran_in(tmp_path):
    (tmp_path / "runs" / "roundabout-sac-lag-s0-500k").mkdir(parents=True)
    (tmp_path / "runs" / "roundabout-sac-lag-s0-500k" / "log.txt").write_text(
        "# grid 2026-12-03 18:18:40 UTC: start, 1 thread(s), beside: intersection-sac-lag-s0-500k, load 0.8\n"
        "step 2000/500000 ...\n# grid 2026-12-03 21:00:00 UTC: interrupted after 161.3 min, exit code 1, load 2.1\n"
        "# grid 2026-12-04 09:00:00 UTC: start, 1 thread(s), beside: no other cell, load 0.1\n"
        "# grid 2026-12-04 10:00:00 UTC: finished after 58.7 min, exit code 0, beside: roundabout-cpo-s0-500k + "
        "intersection-cpo-s0-500k, load 1.0\n")  # an older start stamp alone, then a stretch that names all beside it
    assert table3.wall_times(tmp_path)[2] == ("| roundabout-sac-lag-s0-500k | 3.67 | 2 | 1 thread(s), beside: "
                                              "intersection-sac-lag-s0-500k, load 0.8; 1 thread(s), beside: "
                                              "roundabout-cpo-s0-500k + intersection-cpo-s0-500k, load 0.1 |")



def test_table3_times_a_stretch_killed_without_a_stamp_from_its_progress_lines(tmp_path):
    """A machine's stop kills a cell with no signal: no end stamp. Its stretch is timed from its progress lines, each
    one's steps over its rate, the rate from the ETA (4 digits; the printed rate, 0 across a suspended task, is not),
    and marked ~; the next stretch names the step its checkpoint resumed from."""
    (tmp_path / "runs" / "roundabout-tarl-s1-500k").mkdir(parents=True)
    (tmp_path / "runs" / "roundabout-tarl-s1-500k" / "log.txt").write_text(
        "# grid 2026-12-07 15:00:00 UTC: start, 1 thread(s), beside: unknown (Slurm task 1_0 on vm), load 0.5\n"
        "training tarl on the roundabout from step 0 to 500000 -> runs/grid/roundabout-tarl-s1-500k\n"
        "step    2000/500000 [Alg. 1 step 1, SAC]   315 steps/s, training ETA after the warm-up | last 11 ...\n"
        "step    6000/500000 [Alg. 1 step 1, SAC]     0 steps/s, training ETA 4940.0 min | last 20 ...\n"
        "# grid 2026-12-07 16:00:00 UTC: start, 1 thread(s), beside: unknown (Slurm task 5_0 on vm), load 0.4\n"
        "training tarl on the roundabout from step 4000 to 500000 -> runs/grid/roundabout-tarl-s1-500k\n"
        "# grid 2026-12-07 18:00:00 UTC: finished after 120.0 min, exit code 0, beside: unknown, load 1.0\n")
    # 2000 steps at 315 steps/s, then 4000 at 494,000 / (60 * 4940) = 1 2/3 steps/s: 6.3 s + 2400 s, 40.1 min
    assert table3.wall_times(tmp_path)[2] == (
        "| roundabout-tarl-s1-500k | ~2.67 | 2 | 1 thread(s), beside: unknown (Slurm task 1_0 on vm), load 0.5, killed "
        "without a stamp at step 6,000 (~40 min); 1 thread(s), beside: unknown, load 0.4, from step 4,000 |")

GRID = """
import sys
from argparse import Namespace
from pathlib import Path
sys.path.insert(0, {bench!r})
import table3
cell = "import signal, sys, time; signal.signal(signal.SIGTERM, lambda *a: (open(sys.argv[1], 'w').close(), sys.exit(1))); " \\
       "print('ready', flush=True); time.sleep(600)"
# a cell that saves when it is killed, as tarl.py does
table3.command = lambda scenario, *a: ["python", "-c", cell, str(Path({work!r}) / f"{{scenario}}.saved")]
table3.run_grid([("intersection", "sac", 0), ("roundabout", "sac", 0)], Namespace(
    work=Path({work!r}), results=Path({work!r}) / "results", steps=500_000, step_one=None, jobs=2, threads=1))
"""


def test_table3_a_killed_grid_ends_its_cells_so_that_they_save_and_stamps_them(tmp_path):
    """SIGTERM to the grid (a session's end): every running cell gets it too and saves, the grid waits for them,
    stamps each log.txt and ends with one line; nothing is left running."""
    grid = subprocess.Popen([sys.executable, "-c", GRID.format(bench=str(Path(table3.__file__).parent), work=str(tmp_path))],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    logs = [tmp_path / f"{s}-sac-s0-500k" / "log.txt" for s in ("intersection", "roundabout")]
    for _ in range(300):
        if all(log.exists() and "ready" in log.read_text() for log in logs):
            break
        time.sleep(0.1)
    grid.terminate()
    out, err = grid.communicate(timeout=60)
    assert grid.returncode == 1 and err.strip().splitlines()[-1].startswith("interrupted: the cells saved")
    for log in logs:
        text = log.read_text()
        other = {"intersection": "roundabout", "roundabout": "intersection"}[log.parent.name.split("-")[0]]
        assert "UTC: start, 1 thread(s), beside: " in text and "UTC: interrupted after " in text, text
        assert f"exit code 1, beside: {other}-sac-s0-500k, load" in text, text  # the first started names the second too
        assert (tmp_path / f"{log.parent.name.split('-')[0]}.saved").exists()


def test_table3_the_default_grid_is_table_3s_rows_and_two_ablations_at_one_thread_a_cell(tmp_path, capsys):
    """Every path to a cell reads one declaration of the grid's options: by default Table 3's learned rows and TARL's
    two ablations (another variant only when named), one thread a cell (--print-commands as the grid and --slurm's
    tasks); lattice-idm selects TARL's cell, which evaluates it, and says so."""
    dirs = ["--work", str(tmp_path / "grid"), "--results", str(tmp_path / "results")]
    table3.main(["--seeds", "7", "--print-commands", *dirs])
    commands = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert {c[c.index("--algo") + 1] for c in commands} == {*table3.RUN, "tarl-fixed-t", "tarl-random-t"}
    assert len(commands) == 2 * 9 and all(c[c.index("--threads") + 1] == c[c.index("--workers") + 1] == "1"
                                          for c in commands)
    table3.main(["--seeds", "7", "--scenarios", "roundabout", "--algos", "lattice-idm", "tarl", "--print-commands", *dirs])
    out, err = capsys.readouterr()
    assert [c[c.index("--algo") + 1] for c in map(str.split, out.splitlines())] == ["tarl"]
    assert "lattice-idm: Lattice-IDM has no cell of its own; TARL's cell (tarl) evaluates it" in err
    p = table3.parser()
    on_slurm = table3.settle(p, p.parse_args(["--slurm", *dirs]))
    assert on_slurm.algos == list(table3.GRID) and on_slurm.cpus_per_task == table3.THREADS == 1


def test_table3_a_trial_lands_apart_from_the_committed_results_and_is_never_committed(tmp_path, capsys):
    """Other than Table 3's 10 x 200 cases, a cell is a trial: runs/trial/grid and runs/trial (git ignores runs/), said
    on stderr; --work and --results still choose; --commit of a trial is one line, before any work."""
    trial = ["--algos", "sac", "--seeds", "0", "--scenarios", "roundabout", "--steps", "3000", "--rounds", "1",
             "--cases", "10"]
    table3.main([*trial, "--print-commands"])
    out, err = capsys.readouterr()
    assert out.split()[out.split().index("--out") + 1] == "runs/trial/grid/roundabout-sac-s0-3k"
    assert err.startswith("a trial, 1 x 10 test cases (Table 3's: 10 x 200): its cells in runs/trial/grid, its results "
                          "in runs/trial") and "`rm -r runs/trial`" in err
    table3.main([*trial, "--print-commands", "--work", str(tmp_path / "w"), "--results", str(tmp_path / "r")])
    out, err = capsys.readouterr()
    assert str(tmp_path / "w" / "roundabout-sac-s0-3k") in out.split() and not err
    with pytest.raises(SystemExit):
        table3.main([*trial, "--commit"])
    assert capsys.readouterr().err == ("bench/table3.py: --commit: runs/trial is not in the repository's tracked "
                                       "results (git ignores runs/, where a trial goes): nothing to commit\n")


def test_table3_the_header_says_what_the_rows_were_evaluated_on_from_their_eval_json(tmp_path):
    """Not the command's --rounds / --cases: a 1 x 10 trial beside 10 x 200 cells is named as what it is."""
    table3_size = dict(rounds=10, cases_per_round=200)
    _results(tmp_path, [("roundabout-sac-s0", "roundabout", 0, [dict(_row("sac", 0, 0.8, "abc"), **table3_size)]),
                        ("roundabout-sac-s2", "roundabout", 2, [dict(_row("sac", 2, 0.8, "abc"), **table3_size)]),
                        ("intersection-sac-s1-3k", "intersection", 1,
                         [dict(_row("sac", 1, 0.9, "abc"), rounds=1, cases_per_round=10)])])
    args = table3.argparse.Namespace(results=tmp_path, rounds=1, cases=10, readme=False)
    assert ("of each seed's mean over its rounds, which differ between rows (their eval.json): 10 rounds x 200 test "
            "cases in 2 rows; 1 round x 10 test cases in intersection SAC seed 1 at 3,000 steps; in brackets"
            ) in table3.collect(args).splitlines()[2]
    shutil.rmtree(tmp_path / "runs" / "intersection-sac-s1-3k")
    assert "of each seed's mean over 10 rounds x 200 test cases; in brackets" in table3.collect(args).splitlines()[2]


def test_table3_a_finished_cell_publishes_its_own_files_and_no_table(tmp_path):
    """A Slurm task's publish, and a grid's without --commit: the cell's files to RESULTS/runs/CELL, no table3.md (a
    tracked file rewritten while cells start would record their code as COMMIT-dirty), no checkpoint."""
    args = table3.argparse.Namespace(work=tmp_path / "grid", results=tmp_path / "results", steps=table3.STEPS,
                                     step_one=None, commit=False)
    (args.work / "roundabout-sac-s0").mkdir(parents=True)
    for name in ("eval.json", "train_log.csv", "log.txt", "ckpt.pt", "lock"):
        (args.work / "roundabout-sac-s0" / name).write_text("x")
    table3.publish("roundabout", "sac", 0, args)
    assert sorted(str(p.relative_to(args.results)) for p in args.results.rglob("*")) == [
        "runs", "runs/roundabout-sac-s0", *(f"runs/roundabout-sac-s0/{f}" for f in ("eval.json", "log.txt",
                                                                                   "train_log.csv"))]


def test_table3_collect_only_names_the_cells_started_and_not_finished(tmp_path, capsys):
    """--collect-only while cells run: after the table, on stderr, the run directories with a ckpt.pt or a lock and
    no published eval.json, running (a process holds the lock) or stopped; a finished cell is not named."""
    args = table3.argparse.Namespace(work=tmp_path / "grid", results=tmp_path / "results", steps=table3.STEPS,
                                     step_one=None)
    running = table3.claim(("intersection", "sac", 1), args)
    (args.work / "roundabout-cpo-s0").mkdir()
    (args.work / "roundabout-cpo-s0" / "ckpt.pt").write_text("x")  # stopped: its process gone, its lock free
    _results(args.results, [("roundabout-sac-s0", "roundabout", 0, [_row("sac", 0, 0.8, "abc")])])
    (args.work / "roundabout-sac-s0").mkdir()
    (args.work / "roundabout-sac-s0" / "lock").write_text("")  # finished: published
    table3.main(["--collect-only", "--work", str(args.work), "--results", str(args.results)])
    out, err = capsys.readouterr()
    running[1].close()
    assert "| SAC (100 steps) | n = 1 |" in out and (args.results / "table3.md").exists()
    assert err == (f"not in the table: 2 cell(s) started in {args.work} and not finished; running now: "
                   "intersection-sac-s1; stopped, the same command resumes them: roundabout-cpo-s0\n")


import heldout  # noqa: E402


def test_heldout_sets_each_row_beside_the_first_case_by_case(tmp_path):
    """summary.md from hand-made eval.json files: the rates as written, the discordant pairs each way, McNemar."""
    def cell(gap, algo, outcomes):
        path = heldout.folder(tmp_path, gap, "roundabout", algo) / "eval.json"
        path.parent.mkdir(parents=True)
        rate = lambda o: {"mean": outcomes.count(o) / len(outcomes), "std": 0.0}  # noqa: E731
        row = dict(algo=algo, success_rate=rate("arrival"), collision_rate=rate("collision"),
                   timeout_rate=rate("timeout"), crossing_time={"mean": 20.0, "std": 0.0},
                   cases=[dict(round=0, case=i, start="x", outcome=o, crossing_time=None, steps=9)
                          for i, o in enumerate(outcomes)])
        path.write_text(json.dumps(dict(scenario="roundabout", seed=0, rows=[row])))
    cell(0.9, "tarl", ["arrival", "arrival", "collision", "timeout"])
    cell(0.9, "tarl-fixed-t", ["collision", "arrival", "arrival", "arrival"])
    args = SimpleNamespace(results=tmp_path, algos=["tarl", "tarl-fixed-t", "tarl-random-t"])
    heldout.collect(args)
    lines = (tmp_path / "summary.md").read_text().splitlines()
    assert "| roundabout | 0.9 | tarl | 4 | 0.500 | 0.250 | 0.250 | 20.0 | - |" in lines
    assert "| roundabout | 0.9 | tarl-fixed-t | 4 | 0.750 | 0.250 | 0.000 | 20.0 | 2 / 1, p 1 |" in lines
    assert sum(line.startswith("| roundabout") for line in lines) == 2  # none of tarl-random-t


def test_table3_writes_n_beside_every_row_and_a_one_seed_row_without_a_spread_over_seeds(tmp_path):
    """A row of one seed shows its per-round spread and "n = 1", never "+- 0.000"."""
    _results(tmp_path, [("roundabout-sac-s0", "roundabout", 0, [_row("sac", 0, 0.8, "abc")]),
                        ("roundabout-sac-s1", "roundabout", 1, [_row("sac", 1, 0.9, "abc")]),
                        ("roundabout-tarl-s0-500k", "roundabout", 0, [_row("tarl", 0, 0.95, "abc")])])
    args = table3.argparse.Namespace(results=tmp_path, rounds=10, cases=200, readme=False)
    text = table3.collect(args)
    table = (tmp_path / "table3.md").read_text()
    assert "| SAC (100 steps) | n = 2 | 0.850 +- 0.050 (0.010) |" in table
    assert "| TARL (100 steps) | n = 1 | 0.950 (0.010) |" in table
    one_seed = [line for line in table.splitlines() if "| n = 1 |" in line]
    ours = [cell for line in one_seed for cell in line.split(" | ")[2:7]]  # not the paper's columns
    assert one_seed and text and ours and not any("+-" in cell for cell in ours), one_seed


def test_the_claims_tables_verdicts_follow_from_the_committed_data_by_the_paired_t_and_holm():
    """docs/RESULTS.md's two claims tables against the committed eval.json files, recomputed here with scipy.stats and
    without table3's or analysis.claims' code, from the design written out again: at 10^5 steps every seed 0-2, and
    0-9 for TARL (Lattice-IDM and TARL step 1 from its cell), its two ablations, and SAC-Lattice and PPO-Lag at the
    intersection; at 5 x 10^5, 0-4 for the eight claims of that table. Per claim, the seeds both rows have of its
    planned ones, paired: the means with n of the planned n, Student's paired t (ttest_rel) with its 95 % CI and p,
    Holm's step-down over the table's claims (worked here as a loop), the verdict (Holm p < 0.05: holds or fails by
    the sign; else TOST's p within +-0.03, by the t distribution, Holm over the success claims, < 0.05: equivalent;
    else undecided), the seeds to settle (the paired t's power at the claim's Holm level, by the noncentral t,
    reaches 80 % there and not one seed before); A's wins and the exact sign-flip p; the secondary Welch test over
    every seed and P(A > B) by Mann-Whitney's U. A table whose claims are not all at their planned n says interim
    and calls no verdict, nor seeds to settle; at 5 x 10^5, each seed's difference and the cases only A / only B
    arrives in."""
    root = Path(__file__).resolve().parents[1]
    runs = root / "results" / "runs"
    label = {name: algo for algo, name in table3.NAMES.items()}
    ten = {(s, algo) for s in ("intersection", "roundabout")
           for algo in ("tarl", "tarl-step1", "lattice-idm", "tarl-fixed-t", "tarl-random-t")}
    ten |= {("intersection", "sac-lattice"), ("intersection", "ppo-lag")}

    def plan(steps, scenario, algo):
        return set(range(5)) if steps == 500_000 else set(range(10)) if (scenario, algo) in ten else set(range(3))

    def row(path, algo):
        return next(r for r in json.loads(path.read_text())["rows"] if r["algo"] == algo)

    def seeds(scenario, algo, key, suffix=""):  # {seed: value} of every committed cell at that budget
        host = "tarl" if algo in ("lattice-idm", "tarl-step1") else algo
        cells = {int(m[1]): p for p in runs.glob(f"{scenario}-{host}-s*")
                 if (m := re.fullmatch(rf"{scenario}-{host}-s(\d+){suffix}", p.name))}
        return {k: row(cells[k] / "eval.json", algo)[key]["mean"] for k in sorted(cells)}

    def holm(p):  # Holm 1979: the k-th smallest times m - k + 1, the running maximum, at most 1; NaN: last, as 1
        order = sorted(range(len(p)), key=lambda i: 1.0 if math.isnan(p[i]) else p[i])
        out, top = [0.0] * len(p), 0.0
        for k, i in enumerate(order):
            top = max(top, min(1.0, (len(p) - k) * (1.0 if math.isnan(p[i]) else p[i])))
            out[i] = float("nan") if math.isnan(p[i]) else top
        return out, {i: 0.05 / (len(p) - k) for k, i in enumerate(order)}

    def power(n, d, sd, level):  # the far tail P(T < -t) is ~0 where scipy's nct.cdf gives NaN (a large ncp)
        t, ncp = stats.t.ppf(1 - level / 2, n - 1), abs(d) * math.sqrt(n) / sd
        return stats.nct.sf(t, n - 1, ncp) + np.nan_to_num(stats.nct.cdf(-t, n - 1, ncp))

    def text(p):
        return "-" if math.isnan(p) else f"{p:.2g}"

    block = (root / "docs" / "RESULTS.md").read_text().split("<!-- table3.py claims -->")[1].split("<!-- /table3.py -->")[0]
    tables = [[line for line in part.splitlines()[2:]] for part in re.split(r"\n\s*\n", block.strip())
              if part.startswith("|")]
    captions = [part for part in re.split(r"\n\s*\n", block.strip()) if part.startswith("**")]
    assert len(tables) == len(captions) == 2 and len(tables[0]) == 18 and len(tables[1]) == 8
    seen = set()
    for steps, suffix, lines, caption in zip((100_000, 500_000), ("", "-500k"), tables, captions):
        claims_here = []
        for line in lines:
            cells = [c.strip() for c in line.strip("|").split("|")]
            assert cells[0] == f"{'C' if steps == 100_000 else 'P'}{len(claims_here) + 1}", line  # the claim's id
            cells = cells[1:]
            m = re.match(r"(intersection|roundabout): (.+) (succeeds more often than|crosses sooner than) (.+)$",
                         cells[0])
            scenario, a, word, b = m[1], label[m[2]], m[3], label[m[4]]
            key, sign, digits = ("success_rate", 1, 3) if word.startswith("succeeds") else ("crossing_time", -1, 1)
            if cells[1] != "no such row (its thesis)":  # A is the row the paper puts ahead
                ahead, behind = map(float, cells[1].split(" vs "))
                assert sign * (ahead - behind) > 0, line
            of_a, of_b = ({k: sign * v for k, v in seeds(scenario, algo, key, suffix).items()} for algo in (a, b))
            planned = sorted(plan(steps, scenario, a) & plan(steps, scenario, b))
            both = [k for k in planned if k in of_a and k in of_b]
            x, y = np.array([of_a[k] for k in both]), np.array([of_b[k] for k in both])
            assert cells[2] == f"{sign * x.mean():.{digits}f} vs {sign * y.mean():.{digits}f} ({len(both)} of " \
                               f"{len(planned)})", line
            diffs = x - y
            claims_here.append(dict(cells=cells, line=line, key=key, digits=digits, diffs=diffs, n=len(both),
                                    planned=len(planned), of_a=of_a, of_b=of_b, scenario=scenario, a=a, b=b))
            if len(both) < 2:
                c = claims_here[-1]
                c.update(p=float("nan"), tost=float("nan"))
                continue
            test = stats.ttest_rel(x, y)
            low, high = test.confidence_interval(0.95)
            se = diffs.std(ddof=1) / math.sqrt(len(diffs))
            tost = max(stats.t.sf((diffs.mean() + 0.03) / se, len(diffs) - 1),
                       stats.t.cdf((diffs.mean() - 0.03) / se, len(diffs) - 1))
            claims_here[-1].update(p=test.pvalue, tost=tost if key == "success_rate" else None, low=low, high=high)
        interim = any(c["n"] < c["planned"] for c in claims_here)
        assert ("verdicts of record" in caption) == (not interim) and ("**Interim**" in caption) == interim, caption
        p_holm, levels = holm([c["p"] for c in claims_here])
        margins = [i for i, c in enumerate(claims_here) if c["key"] == "success_rate"]
        tost_holm = dict(zip(margins, holm([claims_here[i]["tost"] for i in margins])[0]))
        for i, c in enumerate(claims_here):
            cells, digits, d, line = c["cells"], c["digits"], c["diffs"].mean(), c["line"]
            tested = c["n"] >= 2
            interval = f"{d:+.{digits}f} [{c['low']:+.{digits}f}, {c['high']:+.{digits}f}]" if tested else "-"
            column = 3 if steps == 100_000 else 4
            assert cells[column:column + 3] == [interval, text(c["p"]), text(p_holm[i])], line
            verdict = (f"interim, n = {c['n']} of {c['planned']}" if interim else
                       ("holds" if d > 0 else "fails") if p_holm[i] < 0.05 else
                       "equivalent within ±0.03" if i in tost_holm and tost_holm[i] < 0.05 else "undecided")
            assert cells[column + 3] == f"**{verdict}**", line
            seen.add(verdict)
            settle = cells[7 if steps == 100_000 else 8]
            if verdict == "undecided":
                sd = c["diffs"].std(ddof=1)
                if settle == f"> {10_000:,}":
                    assert power(10_000, d, sd, levels[i]) < 0.8, line
                else:
                    n = int(settle)
                    assert power(n, d, sd, levels[i]) >= 0.8 > (power(n - 1, d, sd, levels[i]) if n > 2 else 0), line
            else:
                assert settle == "-", line
            if steps == 500_000:
                assert cells[3] == ", ".join(f"seed {k}: {v:+.{digits}f}" for k, v in
                                             zip(sorted(c["of_a"].keys() & c["of_b"].keys() & set(range(5))),
                                                 c["diffs"])), line
                long = [[row(runs / table3.cell_name(c["scenario"], "tarl" if algo == "lattice-idm" else algo, k, 500_000)
                             / "eval.json", algo) for k in range(5) if k in c["of_a"] and k in c["of_b"]]
                        for algo in (c["a"], c["b"])]
                only = [0, 0]
                for r_a, r_b in zip(*long):
                    outcome = [{(e["round"], e["case"]): e["outcome"] == "arrival" for e in r["cases"]}
                               for r in (r_a, r_b)]
                    only = [only[j] + sum(outcome[j][k] and not outcome[1 - j][k] for k in outcome[0])
                            for j in (0, 1)]
                assert cells[9] == f"{only[0]} / {only[1]}", line
                continue
            assert cells[8] == f"{(c['diffs'] > 0).sum()} / {c['n']}", line
            flips = [abs(np.dot(signs, c["diffs"])) >= abs(c["diffs"].sum()) - 1e-12
                     for signs in itertools.product((-1, 1), repeat=c["n"])]
            assert cells[9] == f"{np.mean(flips):.2g}", line
            every_a, every_b = (np.array([v[k] for k in sorted(v)]) for v in (c["of_a"], c["of_b"]))
            welch = stats.ttest_ind(every_a, every_b, equal_var=False).confidence_interval(0.95)
            sign = 1 if c["key"] == "success_rate" else -1
            assert cells[10] == (f"{sign * every_a.mean():.{digits}f} (n = {len(every_a)}) vs "
                                 f"{sign * every_b.mean():.{digits}f} (n = {len(every_b)}): "
                                 f"{every_a.mean() - every_b.mean():+.{digits}f} [{welch[0]:+.{digits}f}, "
                                 f"{welch[1]:+.{digits}f}]"), line
            u = stats.mannwhitneyu(every_a, every_b).statistic / (len(every_a) * len(every_b))
            assert cells[11].startswith(f"{u:.2f} ["), line
    assert {"holds", "undecided"} <= seen  # the table of record shows more than one verdict


def _outside(tmp_path, name, cases=None, odd_start=False):
    """A committed eval.json (SAC's, roundabout, seed 0) as an outside policy's (bench/own_agent.py's layout): its row
    renamed, marked outside the paper, with its first `cases` cases or its first case's start changed."""
    data = json.loads((Path(__file__).resolve().parents[1] / "results" / "runs" / "roundabout-sac-s0" / "eval.json").read_text())
    row = data["rows"][0]
    row.update(algo=name, label=name, policy={"source": "test", "key": "k", "outside_the_paper": True})
    row["cases"] = row["cases"][:cases]
    if odd_start:
        row["cases"][0]["start"] = "0" * 16
    (path := tmp_path / f"{name}.json").write_text(json.dumps(data))
    return path


def test_table3_lists_an_outside_row_after_the_committed_ones_which_stay_as_they_are(tmp_path, capsys):
    results = Path(__file__).resolve().parents[1] / "results"
    committed = (results / "table3.md").read_text()
    args = table3.argparse.Namespace(results=results, rounds=10, cases=200, readme=False)
    base = table3.collect(args, out=tmp_path / "base.md").splitlines()
    table3.main(["--collect-only", "--extra", str(_outside(tmp_path, "my-agent"))])
    text = capsys.readouterr().out.splitlines()
    assert (results / "table3.md").read_text() == committed  # --extra writes no committed file
    mine = next(i for i, line in enumerate(text) if line.startswith("| my-agent (outside the paper) (100,154 steps) |"))
    assert text[mine].endswith(" | - | - |") and text[mine + 1] == ""  # no paper values; after every committed row
    assert text[:mine].count("## roundabout") == 1 and "## roundabout" not in text[mine:]
    assert any(line.startswith("| 100,000 | roundabout | my-agent (outside the paper) |") for line in text)
    same = "- roundabout, seed 0: "
    assert [line for line in base if line not in text] == [line for line in base if line.startswith(same)]
    assert all("outside the paper" in line.lower() or line.startswith(same) for line in text if line not in base)
    assert next(line for line in text if line.startswith(same)).endswith("cases; every row met the same cases")
    with pytest.raises(SystemExit):  # never into the committed table
        table3.main(["--collect-only", "--extra", str(tmp_path / "my-agent.json"), "--out", str(results / "table3.md")])


def test_table3_reports_an_outside_row_that_met_other_cases_in_one_line(tmp_path):
    results = Path(__file__).resolve().parents[1] / "results"
    args = table3.argparse.Namespace(results=results, rounds=10, cases=200, readme=False)
    extra = [_outside(tmp_path, "short", cases=200), _outside(tmp_path, "odd", odd_start=True)]
    text = table3.collect(args, extra, out=tmp_path / "table3.md")
    (line,) = [line for line in text.splitlines() if line.startswith("- roundabout, seed 0: ")]
    assert "2000 cases; cases that began differently: odd (outside the paper) 1" in line
    assert line.endswith("; not compared, another number of cases: short (outside the paper) (200 cases)")
    assert "| short (outside the paper) (100,154 steps) | n = 1 |" in text


def test_rollout_ceiling_plays_its_rounds_in_this_process_with_no_workers(tmp_path):
    """--workers 0: the rounds are played here, on the env that loaded the policy (it once crashed with no env), on
    seed 0's test cases, and nothing goes to results/."""
    import rollout_ceiling
    rollout_ceiling.main(["--scenarios", "intersection", "--timing", "rollout=2", "--rounds", "1", "--cases", "2",
                          "--workers", "0", "--out", str(tmp_path)])
    row = json.loads((tmp_path / "intersection-tarl-s0-rollout2.json").read_text())["rows"][0]
    learned = rollout_ceiling.other_row("intersection", "learned")
    assert [c["start"] for c in row["cases"]] == [c["start"] for c in learned["cases"][:2]]
    assert "## intersection, --timing rollout=2" in (tmp_path / "summary.md").read_text()
