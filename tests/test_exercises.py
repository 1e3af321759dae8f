"""Tests of exercises/: each checker passes its reference solution and fails the stub and every kept wrong
answer with a message that names the mistake; the stored answers are still the project's; the bug hunt's
copy of world.observe differs from it where it should, and nowhere a shape or a range would show; in vivo,
a solution drives as the project does and a wrong answer is caught at a named case; the paired statistics
are exact and agree with results/table3.md; every command of docs/EXERCISES.md and docs/INSTRUCTORS.md runs at a tiny
budget and exits as its comment says; the student's page gives no answer away. (Instructors only: these tests
name the bug hunt's bug.)"""
import importlib
import json
import math
import re
import runpy
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import experiment  # noqa: I001 (first: through tarl it sets OpenMP's wait policy before torch loads)
import numpy as np
import pytest
import torch
import world
from analysis import paired
from exercises import bughunt_observe, check, in_vivo, make_data
from exercises.common import CFG
from exercises.solutions import ex2_observation

HERE = Path(__file__).resolve().parents[1]
DOCS = HERE / "docs"  # the two pages
NUMBERS = ["1", "2", "3", "4", "5"]
WRONG = sorted((HERE / "exercises" / "wrong").glob("ex*.py"))
PAGES = ("EXERCISES.md", "INSTRUCTORS.md")  # the student's page, then the instructors' (the answers)


# ---- A: the checkers ----------------------------------------------------------------------------

@pytest.mark.parametrize("key", NUMBERS + ["bughunt"])
def test_the_reference_solution_passes_its_checker(key):
    result = check.run(key, check.path_of(key, solution=True))
    assert result.ok, result.report


@pytest.mark.parametrize("key", NUMBERS)
def test_the_stub_fails_as_not_implemented_yet(key, tmp_path):
    """The stub as committed (a student's filled-in copy in the work tree does not change what is tested)."""
    stub = check.path_of(key)
    shipped = subprocess.run(["git", "-C", str(HERE), "show", f"HEAD:{stub.relative_to(HERE)}"],
                             capture_output=True, text=True)
    text = shipped.stdout if shipped.returncode == 0 else stub.read_text()
    assert "raise NotImplementedError" in text
    (tmp_path / stub.name).write_text(text)
    result = check.run(key, tmp_path / stub.name)
    assert not result.ok and "not implemented yet" in result.report, result.report


def test_every_exercise_has_at_least_two_wrong_answers():
    for key in NUMBERS:
        assert len([p for p in WRONG if p.name.startswith(f"ex{key}_")]) >= 2, key


@pytest.mark.parametrize("path", WRONG, ids=lambda p: p.stem)
def test_each_wrong_answer_fails_on_one_function_and_the_message_names_the_mistake(path):
    result = check.run(path.name[2], path)
    assert not result.ok
    assert result.report.count("  FAIL  ") == 1, result.report  # one mistake, the rest is right
    assert check.load(path).CHECKER_SAYS in result.report, result.report


def test_the_command_line_exits_0_on_a_solution_and_1_on_a_wrong_answer():
    run = lambda *args: subprocess.run([sys.executable, "-m", "exercises.check", *args], cwd=HERE,  # noqa: E731
                                       capture_output=True, text=True, timeout=60)
    ok = run("1", "--solution")
    assert ok.returncode == 0 and "exercise 1 is done" in ok.stdout, ok.stdout + ok.stderr
    wrong = run("1", "--file", "exercises/wrong/ex1_dt_T_swapped.py")
    assert wrong.returncode == 1 and "is dt / T swapped?" in wrong.stdout, wrong.stdout + wrong.stderr


def test_the_instructors_page_lists_every_wrong_answer():
    text = (DOCS / "INSTRUCTORS.md").read_text()
    for path in WRONG:
        assert path.stem in text, path.stem


def test_the_students_page_gives_no_answer_away_and_points_to_the_instructors_page_with_a_warning():
    """docs/EXERCISES.md names no kept wrong answer, quotes no message the checker keeps for one, and shows
    neither the bug hunt's line nor its fix; its "For instructors" section links docs/INSTRUCTORS.md as spoilers."""
    text = (DOCS / "EXERCISES.md").read_text()
    for path in WRONG:
        assert path.stem not in text, path.stem
        assert check.load(path).CHECKER_SAYS.lower() not in text.lower(), path.stem
    for line in ("rel = ego_xy - others[:, :2]", "rel = others[:, :2] - ego_xy", "ego_xy - others", "others[:, :2] - ego_xy"):
        assert line not in text, line
    pointer = text.split("## For instructors\n", 1)[1]
    assert "(INSTRUCTORS.md)" in pointer and "Spoilers" in pointer and "don't open it" in pointer, pointer


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_the_links_between_the_two_pages_work():
    """Every relative link of docs/EXERCISES.md and docs/INSTRUCTORS.md names a file that exists and, after #, one of
    its headings; each page links the other."""
    links = {}
    for page in PAGES:
        links[page] = re.findall(r"\]\(([^)\s]+)\)", (DOCS / page).read_text())
        for link in links[page]:
            if re.match(r"[a-z]+:", link):
                continue
            target, _, anchor = link.partition("#")
            path = (DOCS / (target or page)).resolve()
            assert path.exists(), f"{page}: {link}"
            if anchor:
                headings = re.findall(r"^#+ (.*)$", path.read_text(), re.M)
                assert anchor in {slug(h) for h in headings}, f"{page}: {link}"
    assert any(link.startswith("INSTRUCTORS.md") for link in links["EXERCISES.md"])
    assert any(link.startswith("EXERCISES.md") for link in links["INSTRUCTORS.md"])


def test_the_stored_answers_are_still_the_projects():
    """exercises/data/ was made from tarl, world and planner: if they change, run python -m exercises.make_data."""
    make_data.check_constants()
    for n, build in make_data.BUILD.items():
        with np.load(make_data.DATA / f"ex{n}.npz") as stored:
            fresh = build()
            assert sorted(stored.files) == sorted(fresh), n
            for key in stored.files:
                # float32 networks (ex5's q_next) sum in another order on another CPU: 5e-7 apart on an AVX2 machine
                np.testing.assert_allclose(stored[key], fresh[key], rtol=1e-5, atol=1e-6, err_msg=f"ex{n}.npz: {key}")


# ---- B: the bug hunt ----------------------------------------------------------------------------

def sector_of_one_vehicle(observe, deg, heading=0.7):
    """The sector name where observe puts a vehicle 20 m away at deg from the ego's heading (test_world's case)."""
    a = heading + math.radians(deg)
    other = np.array([[20.0 * math.cos(a), 20.0 * math.sin(a), 5.0, heading]])
    presence = observe(np.zeros(2), heading, 3.0, 0, 0, other, world.EnvConfig())[7:].reshape(6, 2, 5)[:, 0, 0]
    assert presence.sum() == 1.0
    return world.SECTOR_NAMES[int(presence.argmax())]


WORLD_CASES = {-150: "rear", -90: "right rear", -30: "right front", 30: "front", 90: "left front", 150: "left rear",
               180: "rear", 0: "front", 60: "left front", -60: "right front", 120: "left rear", -120: "right rear"}


@pytest.mark.parametrize("deg", WORLD_CASES)
def test_the_reference_and_the_solution_put_each_vehicle_in_its_sector(deg):
    assert sector_of_one_vehicle(world.observe, deg) == WORLD_CASES[deg]
    assert sector_of_one_vehicle(ex2_observation.observe, deg) == WORLD_CASES[deg]


@pytest.mark.parametrize("deg", WORLD_CASES)
def test_the_bugged_copy_sees_each_vehicle_where_the_opposite_one_would_be(deg):
    """The bug: rel = ego - other, so the position angle is off by 180 deg: ahead <-> behind, left <-> right."""
    opposite = deg - 180 if deg > 0 else deg + 180
    assert sector_of_one_vehicle(bughunt_observe.observe, deg) == WORLD_CASES[opposite]
    assert sector_of_one_vehicle(bughunt_observe.observe, deg) != sector_of_one_vehicle(world.observe, deg)


def test_a_vehicle_straight_ahead_is_front_but_the_bugged_copy_says_rear():
    assert sector_of_one_vehicle(world.observe, 0.0) == "front"
    assert sector_of_one_vehicle(bughunt_observe.observe, 0.0) == "rear"


def test_the_bug_is_silent_shapes_ranges_and_counts_are_right():
    with np.load(make_data.DATA / "ex2.npz") as d:
        for k in range(int(d["scenes"])):
            scene = {key: d[f"scene{k}_{key}"] for key in ("ego_xy", "ego_heading", "ego_speed", "task", "zone", "others")}
            scene.update(task=int(scene["task"]), zone=int(scene["zone"]))
            bugged, right = bughunt_observe.observe(**scene, cfg=CFG), world.observe(**scene, cfg=world.EnvConfig())
            assert bugged.shape == right.shape and bugged.dtype == right.dtype and np.isfinite(bugged).all()
            assert bugged.min() >= 0.0 and bugged.max() <= 1.0
            np.testing.assert_array_equal(bugged[:7], right[:7])  # s_ego
            assert bugged[7::5].sum() == right[7::5].sum()  # as many vehicles seen
            assert np.array_equal(bugged, right) == (right[7::5].sum() == 0)  # it differs wherever anyone is seen


def test_the_bug_hunt_checker_fails_on_the_bugged_copy_and_passes_once_the_line_is_fixed(tmp_path):
    assert not check.run("bughunt").ok
    source = check.path_of("bughunt").read_text()
    assert source.count("rel = ego_xy - others[:, :2]") == 1
    fixed = tmp_path / "bughunt_fixed.py"
    fixed.write_text(source.replace("rel = ego_xy - others[:, :2]", "rel = others[:, :2] - ego_xy"))
    assert check.run("bughunt", fixed).ok


# ---- In vivo: the student's functions in the simulation -------------------------------------------

def test_in_vivo_passes_on_a_solution_and_names_the_first_case_a_wrong_answer_changes():
    import tarl
    beta, blend = tarl.beta, tarl.blend
    said = []
    assert in_vivo.run("1", check.load(check.path_of("1", solution=True)), "the solution", cases=3, log=said.append), said
    assert "All 3 cases are the project's" in said[-1]
    said = []
    wrong = check.load(HERE / "exercises" / "wrong" / "ex1_dt_T_swapped.py")
    assert not in_vivo.run("1", wrong, "a wrong answer", cases=3, log=said.append)
    report = "\n".join(said)
    # which way case 0 goes depends on the shipped policy; what matters: case 0 is the first case named, and beta
    assert "FAIL  case 0: " in report and "Case 0 is the first of 3 that differs" in report, report
    assert "with only your beta in tarl.beta's place, case 0 differs too" in report, report
    assert (tarl.beta, tarl.blend) == (beta, blend)  # restored


def test_exercise_5_has_no_in_vivo_form_and_says_why():
    run = subprocess.run([sys.executable, "-m", "exercises.check", "5", "--in-vivo"], cwd=HERE, capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 1 and "no in-vivo form" in run.stdout and "never calls them" in run.stdout, run.stdout


def test_the_stored_in_vivo_cases_are_the_committed_evaluations_first_cases():
    """data/in_vivo.json (make_data.py) against results/runs/roundabout-tarl-s0/eval.json: case c of a 20-case
    round is case c of the committed 200-case round."""
    stored = json.loads(in_vivo.REFERENCE.read_text())["cases"]
    committed = json.loads((HERE / "results/runs/roundabout-tarl-s0/eval.json").read_text())["rows"][0]["cases"]
    assert len(stored) == in_vivo.CASES
    for mine, theirs in zip(stored, committed):
        assert theirs["round"] == 0 and mine["case"] == theirs["case"]
        assert {k: mine[k] for k in ("start", "outcome", "steps")} == {k: theirs[k] for k in ("start", "outcome", "steps")}
        assert mine["crossing_time"] == pytest.approx(theirs["crossing_time"]) if theirs["crossing_time"] else mine["crossing_time"] is None


def test_a_swapped_quintic_coefficients_takes_effect_through_the_lru_cache(monkeypatch):
    """planner.lattice caches the quintics of Eq. (19) per config: a plain setattr changes nothing, the
    swap helper (which clears the cache) does, and restoring gives the project's plan back."""
    import planner
    cfg = world.EnvConfig().planner()
    path_s, path_xy = np.array([0.0, 200.0]), np.array([[0.0, 0.0], [200.0, 0.0]])
    ahead = np.array([[40.0, 0.0, 3.0, 0.0, 0.0]])  # a slow car 40 m ahead
    plan = lambda: planner.plan(5.0, 6.0, 0.8, path_s, path_xy, ahead, cfg)  # noqa: E731 (a0 != 0: c4 matters)
    project = plan()
    wrong = check.load(HERE / "exercises" / "wrong" / "ex3_c4_is_a0.py").quintic_coefficients
    with monkeypatch.context() as m:
        m.setattr(planner, "quintic_coefficients", wrong)
        assert plan().a_base == project.a_base  # the cached lattice still holds the project's quintics
    with in_vivo.swapped({("planner", "quintic_coefficients"): wrong}):
        swapped = plan()
    assert swapped.a_base != project.a_base or not np.allclose(swapped.s, project.s)
    restored = plan()
    assert planner.quintic_coefficients is not wrong
    assert restored.a_base == project.a_base and np.array_equal(restored.s, project.s)


# ---- Lab 8: the paired statistics ------------------------------------------------------------------

def test_mcnemar_and_the_sign_flip_test_are_exact():
    assert paired.mcnemar(0, 0) == 1.0 and paired.mcnemar(5, 5) == 1.0
    assert paired.mcnemar(1, 9) == 2 * (1 + 10) / 2**10  # 2 P(X <= 1), X ~ Bin(10, 1/2)
    assert paired.mcnemar(9, 1) == paired.mcnemar(1, 9) and paired.mcnemar(0, 6) == 2 / 64
    assert paired.mcnemar(3000, 0) == 0.0  # underflows cleanly, no OverflowError
    assert paired.sign_flip(np.array([1.0, 2.0, 3.0])) == 0.25 and paired.sign_flip(np.array([1.0, -1.0])) == 1.0


def test_paired_resamples_the_cases_within_each_round_as_worked_by_hand():
    """Round 0: only A arrives in both cases; round 1: only B in one of two. Every resample keeps round 0 at +1
    (it has no other kind of case) and draws round 1's difference from {0, -1/2, -1} with P 1/4, 1/2, 1/4: the
    mean of the rounds, (1 + that) / 2, is 1/2, 1/4 or 0, each end with P 1/4 > 2.5 %: the interval [0, 1/2].
    McNemar on 2 against 1: 2 P(X <= 1), X ~ Bin(3, 1/2), is 1."""
    case = lambda r, c, o: dict(round=r, case=c, start="s", outcome=o)  # noqa: E731
    a = dict(cases=[case(0, 0, "arrival"), case(0, 1, "arrival"), case(1, 0, "timeout"), case(1, 1, "arrival")])
    b = dict(cases=[case(0, 0, "collision"), case(0, 1, "timeout"), case(1, 0, "arrival"), case(1, 1, "arrival")])
    r = paired.paired(a, b, np.random.default_rng(0))
    assert (r["n"], r["mine"], r["other"], r["diff"]) == (4, 0.75, 0.5, 0.25)
    assert (r["counts"], r["p"], r["low"], r["high"]) == ((1, 1, 0, 1), 1.0, 0.0, 0.5)
    pooled = paired.paired([a, a], [b, b], np.random.default_rng(0))  # two seeds alike: each end with P 1/16
    assert (pooled["counts"], pooled["diff"], pooled["low"], pooled["high"]) == ((2, 2, 0, 2), 0.25, 0.0, 0.5)
    b["cases"][0]["start"] = "other"
    with pytest.raises(ValueError, match="1 of 4 cases began differently"):
        paired.paired(a, b, np.random.default_rng(0))


def test_the_rounds_add_no_spread_beyond_their_cases_in_the_committed_results():
    """Why paired.paired resamples cases, not rounds: for TARL against every other row of the same seed at 10^5, the
    variance of the per-round difference over the 10 rounds against the variance its 200 cases predict if they are
    independent draws (1 expected then; clustered cases would lift it). Averaged over the pairs it is at most 1.25."""
    runs, ratios = Path(__file__).resolve().parents[1] / "results" / "runs", []
    for path in sorted(runs.glob("*-s[0-9]*/eval.json")):
        scenario, seed = path.parent.name.split("-")[0], path.parent.name.rsplit("-s", 1)[1]
        mate = runs / f"{scenario}-tarl-s{seed}" / "eval.json"  # a row's seed may land before TARL's: no pair yet
        if not seed.isdigit() or "-tarl-s" in path.parent.name or not mate.exists():
            continue
        tarl = json.loads(mate.read_text())["rows"][0]
        for row in json.loads(path.read_text())["rows"]:
            ok = {(c["round"], c["case"]): c["outcome"] == "arrival" for c in row["cases"]}
            d = np.array([[(c["outcome"] == "arrival") - ok[c["round"], c["case"]] for c in tarl["cases"]
                           if c["round"] == r] for r in range(10)], float)
            ratios.append(d.mean(axis=1).var(ddof=1) / (d.var(axis=1, ddof=1).mean() / d.shape[1]))
    assert len(ratios) >= 60 and np.mean(ratios) <= 1.25, (len(ratios), np.mean(ratios))


@pytest.mark.parametrize("scenario", ["intersection", "roundabout"])
@pytest.mark.parametrize("other", ["tarl-fixed-t", "tarl-random-t", "sac", "lattice-idm"])
def test_the_case_by_case_counts_are_table3s(scenario, other, capsys):
    """paired.main exits 1 where its counts differ from results/table3.md's "Case by case"."""
    assert paired.main(["--scenario", scenario, "tarl", other, "--bootstrap", "200"]) == 0, capsys.readouterr().out
    assert "the same counts for seeds 0, 1, 2" in capsys.readouterr().out


def test_the_labels_it_reads_are_the_rows_labels():
    """paired finds a row in results/table3.md by the label experiment.ROWS gives it."""
    assert paired.LABELS == {algo: row.label for algo, row in experiment.ROWS.items()}


def test_it_compares_every_seed_both_rows_have_unless_told(capsys):
    """Without --seeds, every committed seed of the pair: TARL's ablations have ten, SAC-Lag three; the rows TARL's
    runs hold (tarl-step1, lattice-idm) count as TARL's; a pair with no seed is one line before any work."""
    runs = [HERE / "results" / "runs"]
    ten = set(paired.common_seeds(runs, "roundabout", "tarl", "tarl-fixed-t"))
    assert ten >= set(range(10)) and paired.common_seeds(runs, "roundabout", "tarl", "sac-lag") == [0, 1, 2]
    assert set(paired.common_seeds(runs, "roundabout", "tarl-step1", "lattice-idm")) == set(
        paired.common_seeds(runs, "roundabout", "tarl", "tarl")) >= set(range(10))
    assert paired.common_seeds(runs, "intersection", "tarl", "sac", budget="500k") == [0]
    with pytest.raises(SystemExit) as e:
        paired.main(["--scenario", "roundabout", "tarl", "no-such-row"])
    assert e.value.code == 2 and "no seed has both tarl and no-such-row" in capsys.readouterr().err


# ---- Every command of docs/EXERCISES.md and docs/INSTRUCTORS.md, at a tiny budget ------------------------------

def doc_commands() -> list[tuple[str, int]]:
    """(command, the exit code its comment promises: 1 after `# exits 1`, else 0) of every line of the
    ```bash blocks of docs/EXERCISES.md, then of docs/INSTRUCTORS.md, in order."""
    blocks = [b for page in PAGES for b in re.findall(r"```bash\n(.*?)```", (DOCS / page).read_text(), re.S)]
    lines = [line.strip() for block in blocks for line in block.splitlines()]
    return [(line, 1 if re.search(r"#\s*exits 1", line) else 0) for line in lines if line and not line.startswith("#")]


def option(argv: list[str], flag: str, value: str | None = None, add: bool = True) -> list[str]:
    """argv with flag's value(s) replaced by value (a flag alone if value is None), or flag added."""
    if flag in argv:
        i = argv.index(flag) + 1
        j = i
        while j < len(argv) and not argv[j].startswith("--"):
            j += 1
        return argv[:i] + ([] if value is None else [value]) + argv[j:]
    return argv + [flag] + ([] if value is None else [value]) if add else argv


def tiny(argv: list[str], tmp: Path) -> list[str]:
    """The command at a tiny budget: 1 round of 2 cases, 300 training steps, one process (--workers 0), one
    thread; what it would write into the repository goes to tmp. Only the budget changes, never what runs."""
    program, args = argv[1] if argv[1] != "-m" else argv[2], argv[2:] if argv[1] != "-m" else argv[3:]
    if program == "tarl.py":
        training = "--load" not in args and "--algo lattice-idm" not in " ".join(args)
        for flag, value in (("--eval-rounds", "1"), ("--eval-cases", "2"), ("--workers", "0"), ("--threads", "1")):
            args = option(args, flag, value)
        args = option(args, "--steps", "300") if training else args
    elif program == "exercises.check" and "--in-vivo" in args:
        args = option(args, "--cases", "2")
    elif program == "exercises.bughunt":
        args = option(option(args, "--rounds", "1"), "--cases", "2")
    elif program == "exercises.make_data":
        args = option(option(args, "--out", str(tmp / "data")), "--cases", "2")
    elif program == "bench/figures.py" and args[0] == "case":
        args = option(args, "--cases", str(int(args[args.index("--case") + 1]) + 1))
    elif program == "bench/table3.py" and "--print-commands" not in args:
        for flag, value in (("--steps", "300"), ("--rounds", "1"), ("--cases", "2"), ("--jobs", "1"), ("--threads", "1"),
                            ("--seeds", "0"), ("--work", str(tmp / "grid")), ("--results", str(tmp / "hw"))):
            args = option(args, flag, value)
    return [program, *args]


def run_in_process(program: str, args: list[str]) -> int:
    """`python program args` (or `python -m program args`) here, in this process, as its exit code: the
    interpreter's start and torch's import, ~3 s a command on a busy machine, are left out."""
    argv, handler, threads = sys.argv, signal.getsignal(signal.SIGTERM), torch.get_num_threads()
    try:
        if program == "tarl.py":
            code = experiment.main(args)
        elif program.endswith(".py"):
            sys.argv = [program, *args]
            runpy.run_path(program, run_name="__main__")
            code = 0
        else:
            code = importlib.import_module(program).main(args)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 0 if e.code is None else 1
    finally:
        sys.argv = argv
        signal.signal(signal.SIGTERM, handler)
        torch.set_num_threads(threads)
    return code or 0


def test_every_command_of_exercises_md_runs_and_exits_as_its_comment_says(tmp_path, monkeypatch, capsys):
    """docs/EXERCISES.md's commands, then docs/INSTRUCTORS.md's, in document order in one folder (so that lab 6's
    compare finds lab 6's run), at a tiny budget. The commands read results/, exercises/ and bench/ through
    links; what they write stays in tmp_path."""
    for name in ("results", "exercises", "bench", "scenarios", "analysis", "beyond"):
        (tmp_path / name).symlink_to(HERE / name)
    monkeypatch.chdir(tmp_path)
    commands, failed, times = doc_commands(), [], []
    assert len(commands) >= 30, commands
    for line, want in commands:
        argv = tiny(shlex.split(line, comments=True), tmp_path)
        t0 = time.time()
        code = run_in_process(argv[0], argv[1:])
        times.append(f"{time.time() - t0:5.1f} s  {line}")
        if code != want:
            failed.append(f"{line}\n  as {' '.join(argv)}: exit {code}, the comment says {want}\n"
                          + capsys.readouterr().out[-3000:])
    print("\n".join(times))  # measured, never asserted (python -m pytest -s shows them)
    assert not failed, "\n\n".join(failed)
