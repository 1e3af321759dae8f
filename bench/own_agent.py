"""Your own agent beside Table 3: any policy on the test cases every row met, compared with each row case by case.

    python bench/own_agent.py --scenario roundabout --sb3 runs/sb3-sac.zip           # a Stable-Baselines3 model file
    python bench/own_agent.py --scenario intersection --policy mypackage.agent:act   # a function of a module
    python -m exercises.paired --scenario roundabout sb3-sac tarl --seeds 0 --runs runs results/runs   # then, again
    python bench/table3.py --collect-only --extra runs/roundabout-sb3-sac-s0/eval.json   # a row of Table 3's tables

A policy gives the ego's acceleration [m/s^2] (one number; the world clips it to [a_min, a_max] as for every row)
from the observation (67 numbers, Eqs. (27)-(30)), deterministically: a Stable-Baselines3 model or model file
(predict(obs, deterministic=True)), a callable obs -> action, or (obs, env) -> action if it takes two positional
arguments (env: the world.DrivingEnv, whose env.base_action() is the planner's). It drives as the actor of a
tarl.Driver("none") (PolicyDriver), through experiment.evaluate and rollout: no episode loop of its own. So it
plays the R rounds x C test cases of --seed that every row of Table 3 met (10 x 200), in worker processes, a
line with the ETA per round; finished rounds stay in OUT/eval-rounds/ and the same command plays only the others.
It writes OUT/eval.json in tarl.py's layout (default OUT: runs/SCENARIO-NAME-sSEED, where exercises.paired
finds it with --runs runs results/runs), prints its row beside Table 3's rows of that seed and scenario
(results/runs) and compares it case by case with TARL and with the best row (exercises.paired's statistics).
A policy that raises or returns a bad action (NaN, another shape) ends the run in one line naming the case.

In Python: evaluate_policy(policy, "roundabout", seed=0, name="mine") (sys.path: the repository and bench/).
"""
from __future__ import annotations

import argparse
import hashlib
import importlib
import inspect
import json
import os
import pickle
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]
import experiment  # noqa: E402
from exercises.paired import BOOTSTRAP, find_row, p_text, paired  # noqa: E402
from table3 import NAMES, TABLE_ROWS  # noqa: E402
from tarl import Driver  # noqa: E402
from world import OBS_DIM, SCENARIOS, DrivingEnv, EnvConfig  # noqa: E402

RESULTS = ROOT / "results" / "runs"  # Table 3's rows: SCENARIO-ALGO-sSEED/eval.json
MARK = "the policy "  # how a PolicyError's line begins, also after a worker's "evaluation round R failed: "


class PolicyError(Exception):
    """The outside policy raised or returned a bad action: one line naming the case."""


class Policy:
    """An outside policy as a tarl.Driver's actor: act(obs, deterministic, env) -> its action.

    fn: a callable obs -> action or (obs, env) -> action, or an object with predict (a Stable-Baselines3 model).
    file: a Stable-Baselines3 model file instead, loaded by its algorithm's class `sb3` ("SAC", "TD3", ...) where
    it first acts: a worker process receives the path, never the model. key: what names the policy when an
    evaluation resumes. experiment.evaluation_key hashes a hand-written actor by repr(vars(actor)): its vars
    are its name, key and calling convention alone; what it runs lives in slots.
    """

    __slots__ = ("__dict__", "fn", "file", "sb3", "model")

    def __init__(self, name: str, key: str, fn=None, file: Path | None = None, sb3: str = "SAC"):
        self.name, self.key, self.with_env = name, key, fn is not None and takes_env(fn)
        self.fn, self.file, self.sb3, self.model = fn, file, sb3, None

    def __getstate__(self):  # to a worker: the loaded model stays here
        return dict(vars(self)), dict(fn=self.fn, file=self.file, sb3=self.sb3)

    def __setstate__(self, state):
        vars(self).update(state[0])
        self.fn, self.file, self.sb3, self.model = state[1]["fn"], state[1]["file"], state[1]["sb3"], None

    def act(self, obs, deterministic: bool = True, env: DrivingEnv | None = None):
        if self.file is not None and self.model is None:
            self.model = load_sb3(self.file, self.sb3)
        policy = self.fn if self.model is None else self.model
        if hasattr(policy, "predict"):
            return policy.predict(obs, deterministic=deterministic)[0]
        return policy(obs, env) if self.with_env else policy(obs)


class PolicyDriver(Driver):
    """tarl.Driver("none"), SAC's row: beta = 1, the actor alone drives, here a Policy. It hands the policy the env
    and checks each action, naming the case (its round and index, from the case's seed [test_seed(seed, r), c])
    where the policy raises or returns anything but one finite number."""

    def __init__(self, policy: Policy, seed: int):
        super().__init__("none", policy)
        self.eval_seed, self.case, self.steps = seed, (experiment.test_seed(seed, 0), 0), 0

    def new_episode(self, seed=None):
        super().new_episode(seed)
        self.case, self.steps = seed, 0

    def act(self, obs, env: DrivingEnv, deterministic: bool = False, a=None):
        self.steps += 1
        try:
            out = self.actor.act(obs, deterministic, env)
        except Exception as e:
            raise PolicyError(f"{self.where()}: it raised {type(e).__name__}: {first_line(e)}") from None
        try:
            a = np.asarray(out, dtype=float).reshape(1)  # one number, of any shape of size 1
        except (TypeError, ValueError):
            a = np.array([np.nan])
        if not np.isfinite(a[0]):
            raise PolicyError(f"{self.where()}: it returned {first_line(repr(out))[:80]}, not one finite acceleration "
                              "[m/s^2]")
        return super().act(obs, env, deterministic, a)

    def where(self) -> str:
        round_ = self.case[0] - experiment.test_seed(self.eval_seed, 0)
        return (f"{MARK}{self.actor.name} failed at step {self.steps} of case {self.case[1]} of round {round_} "
                "(from 0, as in eval.json)")


def first_line(e) -> str:
    """The first line of an error's or a text's message ("" if none)."""
    return str(e).strip().splitlines()[0] if str(e).strip() else ""


def takes_env(fn) -> bool:
    """Does the callable take (obs, env): two positional parameters?"""
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):  # a builtin without a signature
        return False
    return sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params) >= 2


def digest(*parts) -> str:
    h = hashlib.sha1()
    for part in parts:
        h.update(part if isinstance(part, bytes) else repr(part).encode())
    return h.hexdigest()


def policy_key(fn) -> str:
    """A callable's or model's key: its weights if it has them (an SB3 model's torch policy, a torch module), else
    its code (the source of its function or class). A function reading weights from elsewhere needs key=."""
    module = getattr(fn, "policy", fn)
    if hasattr(module, "state_dict"):
        weights = (t.detach().cpu().numpy().tobytes() for t in module.state_dict().values())
        return digest(type(module).__qualname__, *weights)
    code = fn if inspect.isfunction(fn) or inspect.ismethod(fn) else type(fn)
    try:
        source = inspect.getsource(code)
    except (OSError, TypeError):  # typed in at a prompt
        source = getattr(getattr(code, "__code__", None), "co_code", b"")
    return digest(getattr(code, "__qualname__", ""), source)


def load_sb3(file: Path, algo: str):
    """A Stable-Baselines3 model from its file, by its class in stable_baselines3 or sb3_contrib (imported here)."""
    try:
        import stable_baselines3
    except ImportError:
        raise SystemExit("--sb3 needs Stable-Baselines3, not a dependency of this project: pip install "
                         "stable-baselines3") from None
    classes = [stable_baselines3]
    try:
        import sb3_contrib
        classes.append(sb3_contrib)
    except ImportError:
        pass
    cls = next((getattr(m, algo) for m in classes if hasattr(getattr(m, algo, None), "load")), None)
    if cls is None:
        raise SystemExit(f"--sb3-algo {algo}: not an algorithm of stable_baselines3 (SAC, TD3, PPO, ...) or "
                         "sb3_contrib")
    try:
        return cls.load(file, device="cpu")
    except Exception as e:
        raise SystemExit(f"cannot load {file} as a Stable-Baselines3 {algo} model: {first_line(e)[:200]}") from None


def sb3_file(file: Path, algo: str = "SAC", name: str | None = None) -> tuple[Policy, int]:
    """A Policy of a Stable-Baselines3 model file, checked here (it loads; it sees and does what the world's
    spaces say), and the steps it trained; its key is a hash of the file's bytes."""
    file = Path(file)
    if not file.is_file():
        raise SystemExit(f"--sb3 {file}: no such file")
    model, cfg = load_sb3(file, algo), EnvConfig()
    spaces = model.observation_space, model.action_space
    if spaces[0].shape != (OBS_DIM,) or spaces[1].shape != (1,):
        raise SystemExit(f"{file} sees {spaces[0].shape} and acts {spaces[1].shape}, not the world's observation "
                         f"({OBS_DIM},) and acceleration (1,)")
    if not np.allclose([spaces[1].low[0], spaces[1].high[0]], [cfg.a_min, cfg.a_max]):
        raise SystemExit(f"{file} acts in [{spaces[1].low[0]:g}, {spaces[1].high[0]:g}], not in the world's "
                         f"[{cfg.a_min:g}, {cfg.a_max:g}] m/s^2 (trained through RescaleAction?)")
    policy = Policy(name or slug(file.stem), digest(algo, file.read_bytes()), file=file.resolve(), sb3=algo)
    return policy, int(getattr(model, "num_timesteps", 0))


def imported(spec: str):
    """The callable MODULE:NAME, imported from the current folder or the repository."""
    module, _, attr = spec.partition(":")
    if not (module and attr):
        raise SystemExit(f"--policy {spec}: give MODULE:NAME, e.g. mypackage.agent:act")
    sys.path.append(os.getcwd())
    try:
        fn = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as e:
        raise SystemExit(f"--policy {spec}: {first_line(e)}") from None
    if not callable(fn):
        raise SystemExit(f"--policy {spec}: not callable")
    return fn


def slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "mine"


def sendable(driver: PolicyDriver) -> str | None:
    """Why the driver cannot go to a worker process (pickled, then imported by name there), or None if it can."""
    fn, main = driver.actor.fn, sys.modules["__main__"]
    if fn is not None and "__main__" in (getattr(fn, "__module__", None), type(fn).__module__) \
            and not getattr(main, "__file__", None):
        return "it was defined at a prompt, which a worker cannot import"
    try:
        pickle.dumps(driver)
    except Exception as e:
        return f"it cannot be pickled ({type(e).__name__}: {first_line(e)[:100]})"
    return None


def table3_rows(runs, scenario: str, seed: int) -> dict:
    """Table 3's rows of this seed and scenario, {algo: row of eval.json}, from the first of `runs` that has each."""
    found = {algo: find_row(list(runs), scenario, algo, seed) for algo in TABLE_ROWS}
    return {algo: dict(row, label=NAMES[algo]) for algo, row in found.items() if row is not None}


def versus(a: dict, b: dict) -> str:
    """a against b on the cases both played, a line of report's: the cases where only one arrives (how the other
    failed), McNemar's exact p, the success difference with its 95 % interval (exercises.paired's, seeded 0)."""
    try:
        r = paired(a, b, np.random.default_rng(0))
    except ValueError as e:
        return f"{b['label']:<26}{e} (another SUMO or CPU?)"
    mine, theirs = (f"{sum(n)} ({n[0]} / {n[1]})" for n in (r["counts"][:2], r["counts"][2:]))
    interval = f"{r['diff']:+.3f} [{r['low']:+.3f}, {r['high']:+.3f}]"
    return f"{b['label']:<26}{mine:>22}{theirs:>22}{p_text(r['p']):>12}{interval:>26}"


def report(row: dict, table: dict, scenario: str, seed: int) -> str:
    """The row beside Table 3's rows of its seed and scenario, then case by case against TARL and the best row."""
    best = max(table, key=lambda algo: table[algo]["success_rate"]["mean"])
    sizes = " or ".join(f"{r} x {c}" for r, c in sorted({(r["rounds"], r["cases_per_round"]) for r in table.values()}))
    return "\n".join([
        f"{row['label']}, outside the paper ({row['rounds']} x {row['cases_per_round']} cases), beside Table 3's rows "
        f"of seed {seed} on the {scenario} ({sizes} cases):", experiment.table([*table.values(), row]),
        f"{row['label']} case by case, on the cases both played: where only one arrives (how the other failed: "
        f"collision / timeout), McNemar's exact p, the success difference with a 95 % interval from {BOOTSTRAP:,} "
        "bootstrap resamples of the cases within each round (exercises.paired.paired: why the case)",
        f"{'against':<26}{'only it arrives':>22}{'only the row arrives':>22}{'McNemar p':>12}"
        f"{'success difference':>26}",
        *(versus(row, dict(table[algo], label=table[algo]["label"] + " (best)" * (algo == best != "tarl")))
          for algo in dict.fromkeys(("tarl", best)))])


def evaluate_policy(policy, scenario: str = "roundabout", seed: int = 0, name: str = "mine", label: str | None = None,
                    rounds: int = 10, cases: int = 200, workers: int = 2, out: Path | None = None, runs=(RESULTS,),
                    key: str | None = None, train_steps: int = 0, log=print) -> dict:
    """Evaluate `policy` as Table 3 does on the test cases of `seed`, write OUT/eval.json, print it beside Table 3's
    rows of that seed (found in `runs`) and return its row of eval.json.

    policy: a Policy (sb3_file), or a callable or SB3 model (then Policy(name, key or policy_key(policy), policy)).
    name: its row's algo (and OUT's name), not one of Table 3's; label: its name in the tables (default: name).
    workers: evaluation processes (spawned: a script that calls this needs `if __name__ == "__main__":`); a policy
    that cannot go to one (a lambda, a model holding its env) plays here, which the log says. Everything is
    checked before any case is played: a bad value is one line.
    """
    if scenario not in SCENARIOS:
        raise SystemExit(f"unknown scenario {scenario!r}: choose {' or '.join(sorted(SCENARIOS))}")
    if min(seed, workers) < 0 or min(rounds, cases) < 1:
        raise SystemExit("the seed and workers must be at least 0, rounds and cases at least 1")
    if not re.fullmatch(r"[a-z0-9][a-z0-9-]*", name) or name in (*experiment.ROWS, "tarl-step1"):
        raise SystemExit(f"name {name!r}: lowercase letters, digits and '-', not a row of Table 3 "
                         f"({', '.join(TABLE_ROWS)})")
    table = table3_rows(runs, scenario, seed)
    if "tarl" not in table:
        raise SystemExit(f"no row of Table 3 for seed {seed} on the {scenario} in {', '.join(map(str, runs))}: its "
                         "seeds are 0, 1 and 2")
    policy = policy if isinstance(policy, Policy) else Policy(name, key or policy_key(policy), fn=policy)
    policy.name, policy.key = name, key or policy.key
    out = Path(out or Path("runs") / f"{scenario}-{name}-s{seed}")
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / ".write-test").write_text("")
        (out / ".write-test").unlink()
    except OSError as e:
        raise SystemExit(f"{out} cannot be written: {e.strerror}") from None
    driver, cfg, keep = PolicyDriver(policy, seed), EnvConfig(scenario=scenario), out / "eval-rounds"
    if workers and (why := sendable(driver)):
        log(f"the policy plays in this process, not in {workers} workers: {why}; a function of a module or a model "
            "file can go to workers")
        workers = 0
    log(f"evaluating {name} on the {scenario}, seed {seed}: {rounds} rounds x {cases} test cases, the same as "
        f"Table 3's rows, in {workers or 'no'} worker{'s' * (workers != 1)} -> {out / 'eval.json'}")
    env, t0 = None if workers else DrivingEnv(cfg), time.time()
    try:
        row = dict(algo=name, label=label or name, driver=driver, train_steps=train_steps)
        (result,) = experiment.evaluate(cfg, [row], rounds, cases, seed, workers, env, log=log, keep=keep)
    except (PolicyError, SystemExit) as e:  # here, or from a worker: "evaluation round R failed: the policy ..."
        text = str(e)
        raise SystemExit(text[text.index(MARK):] if MARK in text else text) from None
    except KeyboardInterrupt:
        raise SystemExit(f"kept the finished rounds in {keep}; run the same command again to play the others") from None
    finally:
        if env is not None:
            env.close()
    result["policy"] = dict(source=str(policy.file or getattr(policy.fn, "__qualname__", type(policy.fn).__name__)),
                            key=policy.key, outside_the_paper=True)
    code = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"], capture_output=True,
                          text=True).stdout.strip() or None  # the project's commit, as tarl.py writes it
    (out / "eval.json").write_text(json.dumps(dict(scenario=scenario, seed=seed, code=code,
                                                   world=experiment.world.WORLD_VERSION,
                                                   machine=experiment.machine(), rows=[result])))
    shutil.rmtree(keep, ignore_errors=True)
    log(f"wrote {out / 'eval.json'} in {(time.time() - t0) / 60:.1f} min")
    log(report(result, table, scenario, seed))
    return result


def main(argv=None):
    p = argparse.ArgumentParser(prog="python bench/own_agent.py", description=__doc__.split("\n")[0],
                                formatter_class=experiment.Help)
    p.add_argument("--scenario", choices=sorted(SCENARIOS), default="roundabout")
    p.add_argument("--seed", type=int, default=0, help="the test cases of this seed of Table 3 (0, 1 or 2)")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--sb3", type=Path, metavar="FILE", help="a Stable-Baselines3 model file (model.save)")
    which.add_argument("--policy", metavar="MODULE:NAME", help="a callable obs -> action or (obs, env) -> action "
                       "[m/s^2], imported from the current folder or the repository")
    p.add_argument("--sb3-algo", default="SAC", metavar="CLASS", help="the model's class in stable_baselines3 or "
                   "sb3_contrib")
    p.add_argument("--name", help="its row's name (and OUT's): lowercase, digits, '-' (default: the file's or the "
                   "function's)")
    p.add_argument("--label", help="its name in the tables (default: --name)")
    p.add_argument("--eval-rounds", type=int, default=10, metavar="R", help="R of Table 3")
    p.add_argument("--eval-cases", type=int, default=200, metavar="C", help="C of Table 3: test cases per round (the "
                   "first C of 200)")
    p.add_argument("--workers", type=int, default=2, help="evaluation processes; 0: in this process")
    p.add_argument("--out", type=Path, help="where eval.json goes (default runs/SCENARIO-NAME-sSEED)")
    p.add_argument("--runs", type=Path, nargs="+", default=[RESULTS], help="folders of Table 3's SCENARIO-ALGO-sSEED "
                   "runs")
    args = p.parse_args(argv)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a kill keeps the finished rounds, as Ctrl-C
    if args.sb3:
        policy, steps = sb3_file(args.sb3, args.sb3_algo, args.name)
    else:
        fn = imported(args.policy)
        policy, steps = Policy(args.name or slug(args.policy.partition(":")[2]), policy_key(fn), fn=fn), 0
    evaluate_policy(policy, args.scenario, args.seed, policy.name, args.label, args.eval_rounds, args.eval_cases,
                    args.workers, args.out, args.runs, train_steps=steps)


if __name__ == "__main__":
    main()
