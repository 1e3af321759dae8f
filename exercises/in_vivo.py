"""In vivo: your functions inside the simulation, driving the shipped policy (EXERCISES.md, A and B).

    python -m exercises.check 1 --in-vivo               # exercises/ex1_timing.py's beta and blend in tarl
    python -m exercises.check 3 --in-vivo --solution    # the reference answer, for comparison

The shipped roundabout TARL policy (results/runs/roundabout-tarl-s0/policy.pt) plays the first CASES
test cases of evaluation round 0 (Table 3's protocol, seed 0) in this process, with the file's
functions set in place of the project's (module attributes: SWAPS; restored afterwards). Each case is
compared with the project's own run of it, stored in data/in_vivo.json by make_data.py (so a course
that blanks the project's bodies still has it): the start's fingerprint, the outcome, the steps, the
crossing time and the return (the sum of Eq. (31)'s rewards). The run stops at the first case that
differs, then replays that case with one function swapped at a time, to say which one it was.

In this process (experiment.evaluate's workers=0): an evaluation worker is a fresh process that imports
the project again and would lose the swap. Exercise 5 has none (NO_IN_VIVO says why).
"""
from __future__ import annotations

import contextlib
import json
import math
import sys
import tempfile
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
POLICY = ROOT / "results" / "runs" / "roundabout-tarl-s0" / "policy.pt"
SCENARIO, ALGO, SEED, ROUND = "roundabout", "tarl", 0, 0
REFERENCE = HERE / "data" / "in_vivo.json"
CASES = 20

# exercise: the (module, function) pairs it replaces; the file defines functions of the same names
SWAPS = {
    "1": [("tarl", "beta"), ("tarl", "blend")],  # Eqs. (6), (11); (7), (12): Driver.act, execute
    "2": [("world", "observe"), ("world", "reward")],  # Eqs. (27)-(30); (31): DrivingEnv._read, step
    "3": [("planner", "quintic_coefficients"), ("planner", "state_machine"), ("planner", "base_acceleration")],
    "4": [("world", "game_utility"), ("world", "level_k_decisions")],  # Eqs. (24)-(26): DrivingEnv._play_level_k
    "bughunt": [("world", "observe")],
}
UNUSED = {  # what the file also defines but no evaluation calls
    "1": "discounted_sum (Eq. (8)) scores the timing imagination: only training calls it",
    "2": "sector_index is exercised through your observe",
    "4": "outcome_terms (given) is exercised through your level_k_decisions",
}
NO_IN_VIVO = {"5": (
    "exercise 5 has no in-vivo form: timing_transition and timing_td_target make the timing taker's "
    "training target (Eq. (9), Algorithm 1 lines 7-13), and an evaluation never calls them: the shipped "
    "policy acts with networks already trained. Their test in the simulation would be a training run with "
    "them in place (Part C, lab 10: minutes, and its outcome is noisy), not a 10-second evaluation. "
    "The checker's stored batch (python -m exercises.check 5) is computed by tarl.td_target itself.")}


def modules():
    """The project's modules that SWAPS names (imported here, on first use: check.py stays numpy-only)."""
    import planner
    import tarl
    import world
    return {"tarl": tarl, "world": world, "planner": planner}


def at_level(level_k_decisions):
    """The student's level_k_decisions (level 2 only, no `level` argument) as world calls it."""
    def decisions(t_h, t_e, decel_h, decel_e, waited_h, waited_e, alpha_h, svo, cfg, level=2):
        if level != 2:
            raise ValueError(f"exercise 4's level_k_decisions is level 2; this world asks level {level}")
        return level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, waited_e, alpha_h, svo, cfg)
    return decisions


@contextlib.contextmanager
def swapped(replacements: dict):
    """Set {(module name, attribute): function} in the project's modules; restore them on exit.

    planner.lattice is an lru_cache over _Lattice, which solves the quintics of Eq. (19) once per
    config: the cache is cleared on entry and on exit, so that a swapped quintic_coefficients takes
    effect, and the project's comes back afterwards."""
    mods = modules()
    saved = {(m, name): getattr(mods[m], name) for m, name in replacements}
    try:
        for (m, name), f in replacements.items():
            setattr(mods[m], name, at_level(f) if name == "level_k_decisions" else f)
        mods["planner"].lattice.cache_clear()
        yield
    finally:
        for (m, name), f in saved.items():
            setattr(mods[m], name, f)
        mods["planner"].lattice.cache_clear()


def replacements_of(key: str, module) -> dict:
    """{(module, name): the file's function} for exercise `key`; KeyError names a missing one."""
    missing = [name for _, name in SWAPS[key] if not hasattr(module, name)]
    if missing:
        raise KeyError(f"the file defines no {', '.join(missing)}")
    return {(m, name): getattr(module, name) for m, name in SWAPS[key]}


class Shipped:
    """The shipped roundabout TARL policy on a simulation of its own in this process: play(c) is
    experiment.rollout of test case c of round ROUND, as experiment.play_round plays it, and adds the
    case's return (the sum of whatever world.reward is in place). Close it (or use `with`)."""

    def __init__(self, cases: int, cfg=None):
        import experiment  # first: tarl sets OpenMP's wait policy before torch loads
        import tarl
        import torch
        import world
        self.experiment, self.world, self.torch, self.threads = experiment, world, torch, torch.get_num_threads()
        torch.set_num_threads(1)  # as an evaluation worker acts: one observation at a time
        state = experiment.load_checkpoint(POLICY, SCENARIO, ALGO)
        self.cfg = cfg or world.EnvConfig(scenario=SCENARIO)
        self.env = world.DrivingEnv(self.cfg)
        # the networks as tarl.Trainer builds and loads them (without its 2-second replay buffers)
        sac, timing = tarl.SACConfig(**state["config"]["sac"]), experiment.checkpoint_timing(state)
        actor = tarl.SAC(world.OBS_DIM, act_dim=1, low=[self.cfg.a_min], high=[self.cfg.a_max], cfg=sac)
        taker = tarl.SAC(world.OBS_DIM + 1, n_actions=timing.t_max, cfg=sac)
        actor.load_state_dict(state["actor"])
        taker.load_state_dict(state["timing_taker"])
        self.driver = tarl.Driver("taker", actor, taker, SEED, timing)  # TARL's timing: experiment.ROWS["tarl"]
        self.folder = tempfile.TemporaryDirectory()
        self.cases = self.env.record_cases(experiment.test_seed(SEED, ROUND), cases, self.folder.name)

    def play(self, c: int, driver=None) -> dict:
        """Case c: its start fingerprint, outcome, crossing time [s], steps, return and mean 1 - beta."""
        rewards, reward = [], self.world.reward  # the project's or a swapped one

        def recorded(*args):
            rewards.append(float(reward(*args)))
            return rewards[-1]

        self.world.reward = recorded
        try:
            ep = self.experiment.rollout(self.env, driver or self.driver, {"case": self.cases[c]})
        finally:
            self.world.reward = reward
        beta_minus = float(1.0 - sum(ep["beta"]) / len(ep["beta"]))
        return dict(case=c, start=ep["start"], outcome=ep["outcome"], crossing_time=ep["crossing_time"],
                    steps=ep["steps"], ret=round(sum(rewards), 6), beta_minus=beta_minus)

    def close(self):
        self.env.close()
        self.folder.cleanup()
        self.torch.set_num_threads(self.threads)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def reference_cases(cases: int = CASES, log=print) -> dict:
    """The project's own run of the first `cases` cases (make_data.py stores it as data/in_vivo.json)."""
    t0 = time.time()
    with Shipped(cases) as shipped:
        played = [{k: v for k, v in shipped.play(c).items() if k != "beta_minus"} for c in range(cases)]
    log(f"played {cases} cases of round {ROUND} with the project's functions in {time.time() - t0:.1f} s")
    return dict(policy=str(POLICY.relative_to(ROOT)), scenario=SCENARIO, seed=SEED, round=ROUND, cases=played)


def describe(case: dict, ret: bool = True) -> str:
    when = f"in {case['crossing_time']:.1f} s, " if case["outcome"] == "arrival" else ""
    return f"{case['outcome']} ({when}{case['steps']} steps" + (f", return {case['ret']:.3f})" if ret else ")")


def difference(got: dict, want: dict) -> str | None:
    """What differs between two plays of a case, or None."""
    if got["start"] != want["start"]:
        return (f"it started from another state (fingerprint {got['start']}, the project's {want['start']}): "
                "something changed the traffic before the ego moved")
    if (got["outcome"], got["steps"]) != (want["outcome"], want["steps"]):
        return f"{describe(got)}, but with the project's functions: {describe(want)}"
    if (got["crossing_time"] is None) != (want["crossing_time"] is None) or (
            got["crossing_time"] is not None and not math.isclose(got["crossing_time"], want["crossing_time"], abs_tol=1e-6)):
        return f"crossing time {got['crossing_time']}, the project's {want['crossing_time']}"
    if not math.isclose(got["ret"], want["ret"], abs_tol=1e-4):
        return (f"the same drive ({describe(want, ret=False)}), but the return (the sum of Eq. (31)'s "
                f"rewards) is {got['ret']:.4f}, the project's {want['ret']:.4f}")
    return None


def run(key: str, module, where: str, cases: int = CASES, log=print) -> bool:
    """Exercise `key`'s functions of `module` in the shipped policy's evaluation: True if every case is
    the stored reference's."""
    key = str(key)
    if key in NO_IN_VIVO:
        log(f"Exercise {key} in vivo: {NO_IN_VIVO[key]}")
        return False
    names = ", ".join(f"{m}.{name}" for m, name in SWAPS[key])
    log(f"Exercise {key} in vivo: {where}'s functions in place of {names}, driving the shipped roundabout TARL "
        f"(seed 0) on the first {cases} test cases of round {ROUND}, in this process")
    if key in UNUSED:
        log(f"  (not here: {UNUSED[key]})")
    if not REFERENCE.exists():
        log(f"  FAIL  {REFERENCE.relative_to(ROOT)} is missing: python -m exercises.make_data")
        return False
    stored = json.loads(REFERENCE.read_text())["cases"]
    if cases > len(stored):
        log(f"  FAIL  the reference has {len(stored)} cases, not {cases}")
        return False
    try:
        swaps = replacements_of(key, module)
    except KeyError as e:
        log(f"  FAIL  {e.args[0]}")
        return False
    t0 = time.time()
    with Shipped(cases) as shipped:
        for c in range(cases):
            try:
                with swapped(swaps):
                    got = shipped.play(c)
            except NotImplementedError as e:
                log(f"  TODO  case {c}: not implemented yet ({e}): python -m exercises.check {key} first")
                return False
            except Exception as e:  # noqa: BLE001: whatever the file does wrong in the simulation, say it
                mine = [f for f in traceback.extract_tb(e.__traceback__) if f.filename == getattr(module, "__file__", None)]
                where_ = f" (line {mine[-1].lineno}: {mine[-1].line})" if mine else ""
                log(f"  FAIL  case {c}: raised {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}{where_}")
                return False
            why = difference(got, stored[c])
            if why is None:
                log(f"  ok    case {c}: {describe(got)}")
                continue
            log(f"  FAIL  case {c}: {why}")
            culprits = [f"your {name} in {m}.{name}'s place" for (m, name), f in swaps.items()
                        if len(swaps) > 1 and difference(play_one(shipped, c, {(m, name): f}), stored[c])]
            if culprits:
                log(f"        with only {' or only '.join(culprits)}, case {c} differs too: look there first")
            log(f"Case {c} is the first of {cases} that differs ({time.time() - t0:.0f} s). Does python -m exercises.check "
                f"{key} pass? Then the simulation asks your function something its checks did not.")
            return False
    log(f"All {cases} cases are the project's, case by case ({time.time() - t0:.0f} s): exercise {key} drives as the project does.")
    return True


def play_one(shipped: Shipped, c: int, swaps: dict) -> dict:
    """Case c with only `swaps` in place (an exception counts as a difference)."""
    try:
        with swapped(swaps):
            return shipped.play(c)
    except Exception:  # noqa: BLE001
        return dict(start="raised", outcome="raised", steps=-1, crossing_time=None, ret=math.nan)


if __name__ == "__main__":
    sys.exit("run it as python -m exercises.check N --in-vivo")
