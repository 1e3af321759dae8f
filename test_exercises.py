"""Tests of exercises/: each checker passes its reference solution and fails the stub and every kept wrong
answer with a message that names the mistake; the stored answers are still the project's; the bug hunt's
copy of world.observe differs from it where it should, and nowhere a shape or a range would show.
(Instructors only: these tests name the bug hunt's bug.)"""
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import world
from exercises import bughunt_observe, check, make_data
from exercises.common import CFG
from exercises.solutions import ex2_observation

HERE = Path(__file__).resolve().parent
NUMBERS = ["1", "2", "3", "4", "5"]
WRONG = sorted((HERE / "exercises" / "wrong").glob("ex*.py"))


# ---- A: the checkers ----------------------------------------------------------------------------

@pytest.mark.parametrize("key", NUMBERS + ["bughunt"])
def test_the_reference_solution_passes_its_checker(key):
    result = check.run(key, check.path_of(key, solution=True))
    assert result.ok, result.report


@pytest.mark.parametrize("key", NUMBERS)
def test_the_stub_fails_as_not_implemented_yet(key):
    stub = check.path_of(key)
    if "raise NotImplementedError" not in stub.read_text():
        pytest.skip(f"{stub.name} has been filled in")
    result = check.run(key, stub)
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


def test_the_instructors_section_lists_every_wrong_answer():
    text = (HERE / "EXERCISES.md").read_text()
    for path in WRONG:
        assert path.stem in text, path.stem


def test_the_stored_answers_are_still_the_projects():
    """exercises/data/ was made from tarl, world and planner: if they change, run python -m exercises.make_data."""
    make_data.check_constants()
    for n, build in make_data.BUILD.items():
        with np.load(make_data.DATA / f"ex{n}.npz") as stored:
            fresh = build()
            assert sorted(stored.files) == sorted(fresh), n
            for key in stored.files:
                np.testing.assert_allclose(stored[key], fresh[key], rtol=1e-6, atol=1e-7, err_msg=f"ex{n}.npz: {key}")


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
def test_the_bugged_copy_swaps_left_and_right(deg):
    mirror = WORLD_CASES[-deg if deg != 180 else 180]
    assert sector_of_one_vehicle(bughunt_observe.observe, deg) == mirror
    if mirror != WORLD_CASES[deg]:  # all but straight ahead and straight behind
        assert sector_of_one_vehicle(bughunt_observe.observe, deg) != sector_of_one_vehicle(world.observe, deg)


def test_a_vehicle_at_plus_60_degrees_is_left_front_but_the_bugged_copy_says_right_front():
    assert sector_of_one_vehicle(world.observe, 60.0) == "left front"
    assert sector_of_one_vehicle(bughunt_observe.observe, 60.0) == "right front"


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
    assert source.count("ego_heading - bearing") == 1
    fixed = tmp_path / "bughunt_fixed.py"
    fixed.write_text(source.replace("ego_heading - bearing", "bearing - ego_heading"))
    assert check.run("bughunt", fixed).ok
