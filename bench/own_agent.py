"""Your own agent beside Table 3: any policy on the test cases every row met, compared with each row case by case
and over seeds as the paper's claims are tested.

    python bench/own_agent.py --scenario roundabout --sb3 'runs/sb3-sac-s{seed}.zip'  # a Stable-Baselines3 model a seed
    python bench/own_agent.py --scenario intersection --policy mypackage.agent:act --seeds 0   # a function, one seed
    python -m exercises.paired --scenario roundabout sb3-sac tarl --runs runs results/runs   # then, again
    python bench/table3.py --collect-only --extra runs/roundabout-sb3-sac-s*/eval.json   # its rows in Table 3's tables

A policy gives the ego's acceleration [m/s^2] (one number; the world clips it to [a_min, a_max] as for every row)
from the observation (67 numbers, Eqs. (27)-(30)), deterministically: a Stable-Baselines3 model or model file
(predict(obs, deterministic=True)), a callable obs -> action, or (obs, env) -> action if it takes two positional
arguments (env: the world.DrivingEnv, whose env.base_action() is the planner's). A policy of (obs, env) can read
what no row of Table 3 sees (the humans' true game weights env.humans, the traffic's random stream env.rng, SUMO
itself): its row is marked privileged, in eval.json ("policy") and in its label. Before the run the policy plays one
test case twice; if the two episodes differ (outcome, steps or an action) it is refused in one line, unless
--stochastic: then its row is marked stochastic. `{seed}` in --sb3 or --policy names one model per seed (trained with
that seed, as Table 3's rows are); without it one policy plays every seed's cases.

It drives as the actor of a tarl.Driver("none") (PolicyDriver), through experiment.evaluate and rollout: no episode
loop of its own. For each of --seeds it plays the R rounds x C test cases of that seed that every row of Table 3 met
(10 x 200), in worker processes, a line with the ETA per round; finished rounds stay in OUT/SCENARIO-NAME-sSEED/
eval-rounds/, finished seeds in their eval.json (tarl.py's layout, where exercises.paired finds it with --runs runs
results/runs), and the same command plays only what is left. It prints each seed's row beside Table 3's rows of
that seed and scenario (results/runs), then compares it with TARL and with the best row: case by case for each seed
and pooled (analysis.paired.paired), and over the seeds with the test of the paper's claims, paired by seed
(analysis.claims.seed_test). A policy that raises or returns a bad action (NaN, another shape) ends the run in one
line naming the case.

In Python: evaluate_policy(policy, "roundabout", seeds=(0, 1, 2), name="mine") (sys.path: the repository and bench/).
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
from analysis.paired import BOOTSTRAP, find_row, p_text, paired  # noqa: E402
from analysis.claims import MARGIN, MOST_SEEDS, seed_test  # noqa: E402
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
    """tarl.Driver("none"), SAC's row: beta = 1, the actor alone drives, here a Policy, on the test cases of `seed`.
    It hands the policy the env and checks each action, naming the case (its seed, round and index, from the case's
    seed [test_seed(seed, r), c]) where the policy raises or returns anything but one finite number."""

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
        return (f"{MARK}{self.actor.name} failed on seed {self.eval_seed} at step {self.steps} of case {self.case[1]} "
                f"of round {round_} (from 0, as in eval.json)")


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


def loaded(spec: str, sb3: str | None, name: str) -> tuple[Policy, int]:
    """The policy of --sb3 FILE (a model of class `sb3`) or else of --policy MODULE:NAME, and the steps it trained
    (0: unknown)."""
    if sb3:
        return sb3_file(Path(spec), sb3, name)
    fn = imported(spec)
    return Policy(name, policy_key(fn), fn=fn), 0


def slug(text: str) -> str:
    """A row's name from a file's or a function's: lowercase, digits and '-', without {seed} (and a -s before it)."""
    return re.sub(r"[^a-z0-9]+", "-", re.sub(r"[-_]?s?\{seed\}", "", text).lower()).strip("-") or "mine"


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


def table3_seeds(runs, scenario: str) -> list[int]:
    """The seeds with TARL's row of Table 3 on the scenario in `runs` (their SCENARIO-tarl-sK folders)."""
    names = (path.parent.name for folder in runs for path in Path(folder).glob(f"{scenario}-tarl-s*/eval.json"))
    return sorted({int(seed) for name in names if (seed := name.rpartition("-s")[2]).isdigit()})


def per_seed(value, seeds) -> dict:
    """{seed: value}: a dict of one value per seed as it is (every seed in it), else the same value for every seed."""
    if not isinstance(value, dict):
        return dict.fromkeys(seeds, value)
    if missing := [seed for seed in seeds if seed not in value]:
        raise SystemExit(f"no policy, key or training steps for seed {', '.join(map(str, missing))}")
    return value


def unrepeatable(driver: PolicyDriver, env: DrivingEnv) -> str | None:
    """How two episodes of one test case (case 0 of round 0 of the driver's seed), played here one after the other,
    differ in outcome, steps or an action; None if they do not. A policy that draws random numbers, or carries
    something from one episode to the next, plays each case by chance: its row would not be repeatable."""
    first, second = (eps[0] for eps in experiment.play_round(env, [driver, driver], 1, driver.eval_seed, 0))
    n = min(first["steps"], second["steps"])
    apart = np.flatnonzero(first["a"][:n] != second["a"][:n])
    if (first["outcome"], first["steps"]) == (second["outcome"], second["steps"]) and not apart.size:
        return None
    return (f"case 0 of round 0 of seed {driver.eval_seed}, played twice, ended in "
            + " and in ".join(f"{ep['outcome']} after {ep['steps']} steps" for ep in (first, second))
            + (f", its actions apart from step {apart[0] + 1}" if apart.size else ""))


def marked(label: str, privileged: bool, stochastic: bool) -> str:
    """A row's label with what it is marked: "mine (privileged, stochastic)"."""
    marks = [mark for mark, on in (("privileged", privileged), ("stochastic", stochastic)) if on]
    return f"{label} ({', '.join(marks)})" if marks else label


def planned(driver: PolicyDriver, cfg: EnvConfig, label: str, rounds: int, cases: int, train_steps: int,
            stochastic: bool) -> dict:
    """A seed's row before its cases are played: algo, label (marked), rounds, cases per round, training steps and
    policy: its source, key, marks and evaluation key (experiment.evaluation_key: the world, scenario, seed, cases
    and policy), which describe it in eval.json and tell an earlier run of the same evaluation (finished)."""
    policy = driver.actor
    source = str(policy.file or getattr(policy.fn, "__qualname__", type(policy.fn).__name__))
    key = experiment.evaluation_key(cfg, [dict(algo=policy.name, driver=driver)], cases, driver.eval_seed)
    return dict(algo=policy.name, label=marked(label, policy.with_env, stochastic), rounds=rounds,
                cases_per_round=cases, train_steps=train_steps,
                policy=dict(source=source, key=policy.key, outside_the_paper=True, privileged=policy.with_env,
                            stochastic=stochastic, evaluation_key=key))


def finished(path: Path, want: dict) -> dict | None:
    """The row of an earlier run's eval.json at `path` if it holds the evaluation `want` (planned): the same command
    again plays only the seeds it had not finished."""
    try:
        (row,) = experiment.read_eval(path)["rows"]
    except (OSError, ValueError, KeyError, TypeError):  # none, one cut short, another layout
        return None
    return row if all(row.get(k) == v for k, v in want.items()) else None


def play(driver: PolicyDriver, cfg: EnvConfig, row: dict, rounds: int, cases: int, workers: int,
         env: DrivingEnv | None, out: Path, log) -> dict:
    """One seed's evaluation (the driver's): its rounds, but those kept in OUT/eval-rounds by an interrupted run;
    its row, `row` (algo, label, train_steps, policy) with its outcomes, written to OUT/eval.json in tarl.py's
    layout and returned."""
    keep, seed, t0 = out / "eval-rounds", driver.eval_seed, time.time()
    try:
        (result,) = experiment.evaluate(cfg, [dict(row, driver=driver)], rounds, cases, seed, workers, env, log=log,
                                        keep=keep)
    except KeyboardInterrupt:
        raise SystemExit(f"kept the finished rounds in {keep}; run the same command again to play the others") from None
    result["policy"] = row["policy"]
    code = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"], capture_output=True,
                          text=True).stdout.strip() or None  # the project's commit, as tarl.py writes it
    (out / "eval.json").write_text(json.dumps(dict(scenario=cfg.scenario, seed=seed, code=code,
                                                   world=experiment.world.WORLD_VERSION,
                                                   machine=experiment.machine(), rows=[result])))
    shutil.rmtree(keep, ignore_errors=True)
    log(f"wrote {out / 'eval.json'} in {(time.time() - t0) / 60:.1f} min")
    return result


HEADER = (f"{'seed':<8}{'cases':>7}{'it':>8}{'the row':>9}{'only it arrives':>22}{'only the row arrives':>22}"
          f"{'McNemar p':>12}{'success difference':>26}")


def versus(r: dict, name: str) -> str:
    """A line under HEADER: paired()'s result on a seed's cases, or pooled (name): both successes, the cases where
    only one arrives (how the other failed), McNemar's exact p, the success difference with its 95 % interval."""
    mine, theirs = (f"{sum(n)} ({n[0]} / {n[1]})" for n in (r["counts"][:2], r["counts"][2:]))
    interval = f"{r['diff']:+.3f} [{r['low']:+.3f}, {r['high']:+.3f}]"
    return (f"{name:<8}{r['n']:>7}{r['mine']:>8.3f}{r['other']:>9.3f}{mine:>22}{theirs:>22}{p_text(r['p']):>12}"
            f"{interval:>26}")


def comparison(mine: dict, theirs: dict, label: str, rng: np.random.Generator) -> list[str]:
    """Mine against one row of Table 3 (label), both {seed: row of eval.json}, on the cases both played: each seed's
    paired() line and, over several seeds, the pooled one and the claims' seed_test (analysis.claims) of each seed's
    two successes, paired by seed (paired()'s, on those cases: eval.json's means when both played them all): one
    comparison, its verdict at 0.05 unadjusted (the claims tables adjust theirs over their family)."""
    lines, results = [f"against {label}:", HEADER], {}
    for seed in mine:
        try:
            results[seed] = paired(mine[seed], theirs[seed], rng)
        except ValueError as e:
            lines.append(f"{seed:<8}{e} (another SUMO or CPU?)")
            continue
        lines.append(versus(results[seed], str(seed)))
    if len(results) < 2:
        return lines
    lines.append(versus(paired([mine[s] for s in results], [theirs[s] for s in results], rng), "pooled"))
    t = seed_test(*({s: r[k] for s, r in results.items()} for k in ("mine", "other")), MARGIN["success_rate"], rng)
    settle = f", {t['settle'] or f'> {MOST_SEEDS:,}'} seeds would settle it" * (t["verdict"] == "undecided")
    return lines + [f"over the {len(results)} seeds, paired by seed as the paper's claims are tested: it - the row "
                    f"{t['d']:+.3f} [{t['ci'][0]:+.3f}, {t['ci'][1]:+.3f}] (paired t's 95 % CI, p {p_text(t['p'])}): "
                    f"{t['verdict']}{settle}; ahead in {t['wins'][0]} of {t['wins'][1]} seeds, sign-flip p "
                    f"{t['sign_flip']:.2g}; P(it > the row) " + "{:.2f} [{:.2f}, {:.2f}]".format(*t["improvement"])]


def beside(row: dict, table: dict, scenario: str, seed: int) -> str:
    """The row beside Table 3's rows of its seed and scenario."""
    sizes = " or ".join(f"{r} x {c}" for r, c in sorted({(r["rounds"], r["cases_per_round"]) for r in table.values()}))
    return (f"{row['label']}, outside the paper ({row['rounds']} x {row['cases_per_round']} cases), beside Table 3's "
            f"rows of seed {seed} on the {scenario} ({sizes} cases):\n" + experiment.table([*table.values(), row]))


def report(rows: dict, tables: dict) -> str:
    """Mine ({seed: row}) against TARL and the best row of Table 3 (the highest mean success over these seeds, of
    the rows every seed has), `comparison` each; a note where one policy played every seed's cases."""
    seeds, rng = list(rows), np.random.default_rng(0)
    common = [algo for algo in TABLE_ROWS if all(algo in tables[seed] for seed in seeds)]
    best = max(common, key=lambda algo: np.mean([tables[seed][algo]["success_rate"]["mean"] for seed in seeds]))
    lines = [f"{rows[seeds[0]]['label']} case by case, on the cases both played, seed by seed and pooled (McNemar on "
             "the seeds' discordant pairs summed): where only one arrives (how the other failed: collision / timeout), "
             f"McNemar's exact p, the success difference with a 95 % interval from {BOOTSTRAP:,} bootstrap resamples "
             "of the cases within each round (analysis.paired.paired: why the case); over the seeds, on each seed's "
             "two successes, the test of the paper's claims (analysis.claims.seed_test): the paired t's 95 % CI, its p "
             f"and its verdict at 0.05, unadjusted (equivalent: within +-{MARGIN['success_rate']} by two one-sided "
             "tests; if undecided, the seeds that would settle it), the seeds it is ahead in with the exact sign-flip "
             "p, P(it > the row) with its 95 % interval (rliable's stratified bootstrap)"]
    for algo in dict.fromkeys(("tarl", best)):
        label = tables[seeds[0]][algo]["label"] + " (best)" * (algo == best != "tarl")
        lines += comparison(rows, {seed: tables[seed][algo] for seed in seeds}, label, rng)
    if len(seeds) > 1 and len({row["policy"]["key"] for row in rows.values()}) == 1:
        lines.append("one policy played every seed's cases: its spread over the seeds is the cases' alone, no "
                     "training's, so the test over seeds asks whether it beats the row's trained seeds, not whether "
                     "its method beats the row's (one model per seed: {seed} in --sb3 or --policy)")
    return "\n".join(lines)


def evaluate_policy(policy, scenario: str = "roundabout", seeds=(0, 1, 2), name: str = "mine",
                    label: str | None = None, rounds: int = 10, cases: int = 200, workers: int = 2,
                    out: Path = Path("runs"), runs=(RESULTS,), key: str | None = None, train_steps=0,
                    stochastic: bool = False, log=print) -> dict:
    """Evaluate `policy` as Table 3 does on the test cases of each of `seeds`, write each seed's
    OUT/SCENARIO-NAME-sSEED/eval.json, print its row beside Table 3's rows of that seed (found in `runs`), then the
    comparisons (report), and return {seed: its row of eval.json}.

    policy: a Policy (sb3_file), or a callable or SB3 model (then Policy(name, key or policy_key(policy), policy)),
    or a dict of them, one per seed; key and train_steps likewise. name: its rows' algo (and OUT's name), not one of
    Table 3's; label: its name in the tables (default: name), marked privileged for an (obs, env) policy and
    stochastic if `stochastic`. Unless `stochastic`, a policy that plays one case twice differently is refused.
    workers: evaluation processes (spawned: a script that calls this needs `if __name__ == "__main__":`); a policy
    that cannot go to one (a lambda, a model holding its env) plays here, which the log says. A seed whose eval.json
    holds this evaluation already is not played again. Everything is checked before any case is played: a bad value
    is one line.
    """
    seeds = list(seeds)
    if scenario not in SCENARIOS:
        raise SystemExit(f"unknown scenario {scenario!r}: choose {' or '.join(sorted(SCENARIOS))}")
    if not seeds or len(set(seeds)) < len(seeds):
        raise SystemExit(f"seeds {' '.join(map(str, seeds))}: one or more, each once")
    if min(*seeds, workers) < 0 or min(rounds, cases) < 1:
        raise SystemExit("the seeds and workers must be at least 0, rounds and cases at least 1")
    if not re.fullmatch(r"[a-z0-9][a-z0-9-]*", name) or name in (*experiment.ROWS, "tarl-step1"):
        raise SystemExit(f"name {name!r}: lowercase letters, digits and '-', not a row of Table 3 "
                         f"({', '.join(TABLE_ROWS)})")
    tables = {seed: table3_rows(runs, scenario, seed) for seed in seeds}
    if missing := [seed for seed in seeds if "tarl" not in tables[seed]]:
        raise SystemExit(f"no row of Table 3 for seed {', '.join(map(str, missing))} on the {scenario} in "
                         f"{', '.join(map(str, runs))}: its seeds there are "
                         f"{', '.join(map(str, table3_seeds(runs, scenario))) or 'none'}")
    policies, keys, steps = (per_seed(value, seeds) for value in (policy, key, train_steps))
    policies = {seed: p if isinstance(p, Policy) else Policy(name, keys[seed] or policy_key(p), fn=p)
                for seed, p in policies.items()}
    drivers, outs, cfg = {}, {}, EnvConfig(scenario=scenario)
    for seed in seeds:
        policies[seed].name, policies[seed].key = name, keys[seed] or policies[seed].key
        drivers[seed] = PolicyDriver(policies[seed], seed)
        outs[seed] = Path(out) / experiment.run_name(scenario, name, seed)
        try:
            outs[seed].mkdir(parents=True, exist_ok=True)
            (outs[seed] / ".write-test").write_text("")
            (outs[seed] / ".write-test").unlink()
        except OSError as e:
            raise SystemExit(f"{outs[seed]} cannot be written: {e.strerror}") from None
    if workers and (why := next(filter(None, map(sendable, drivers.values())), None)):
        log(f"the policy plays in this process, not in {workers} workers: {why}; a function of a module or a model "
            "file can go to workers")
        workers = 0
    want = {seed: planned(drivers[seed], cfg, label or name, rounds, cases, steps[seed], stochastic) for seed in seeds}
    rows = {seed: finished(outs[seed] / "eval.json", want[seed]) for seed in seeds}
    todo = [seed for seed in seeds if rows[seed] is None]
    for seed in (seed for seed in seeds if rows[seed] is not None):
        log(f"seed {seed}: {outs[seed] / 'eval.json'} holds this evaluation already")
    if todo:
        log(f"evaluating {name} on the {scenario}, seed{'s' * (len(todo) > 1)} {', '.join(map(str, todo))}: {rounds} "
            f"rounds x {cases} test cases each, the same as Table 3's rows, in {workers or 'no'} "
            f"worker{'s' * (workers != 1)} -> {Path(out) / f'{scenario}-{name}-sSEED' / 'eval.json'}")
    env = DrivingEnv(cfg) if todo and not (workers and stochastic) else None  # the check's; the rounds' with no workers
    try:
        for seed in [] if stochastic else {drivers[seed].actor.key: seed for seed in todo}.values():  # each policy once
            if how := unrepeatable(drivers[seed], env):
                raise SystemExit(f"{MARK}{name} is not deterministic: {how}; --stochastic (stochastic=True) evaluates "
                                 "it anyway, marked stochastic in eval.json and the tables")
        if workers and env is not None:  # the rounds go to workers
            env.close()
            env = None
        for seed in todo:
            rows[seed] = play(drivers[seed], cfg, want[seed], rounds, cases, workers, env, outs[seed], log)
            log(beside(rows[seed], tables[seed], scenario, seed))
    except (PolicyError, SystemExit) as e:  # here, or from a worker: "evaluation round R failed: the policy ..."
        text = str(e)
        raise SystemExit(text[text.index(MARK):] if MARK in text else text) from None
    finally:
        if env is not None:
            env.close()
    for seed in (seed for seed in seeds if seed not in todo):
        log(beside(rows[seed], tables[seed], scenario, seed))
    log(report(rows, tables))
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(prog="python bench/own_agent.py", description=__doc__.split("\n\n")[0],
                                formatter_class=experiment.Help)
    p.add_argument("--scenario", choices=sorted(SCENARIOS), default="roundabout")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], metavar="K", help="the test cases of these "
                   "seeds of Table 3, each seed's run apart, then compared seed by seed, pooled and over the seeds")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--sb3", metavar="FILE", help="a Stable-Baselines3 model file (model.save); {seed} in it: one "
                       "model per seed")
    which.add_argument("--policy", metavar="MODULE:NAME", help="a callable obs -> action or (obs, env) -> action "
                       "[m/s^2] (privileged), imported from the current folder or the repository; {seed} in it: one "
                       "per seed")
    p.add_argument("--sb3-algo", default="SAC", metavar="CLASS", help="the model's class in stable_baselines3 or "
                   "sb3_contrib")
    p.add_argument("--stochastic", action="store_true", help="evaluate a policy that plays a test case twice "
                   "differently, marked stochastic (without it, such a policy is refused)")
    p.add_argument("--name", help="its rows' name (and OUT's): lowercase, digits, '-' (default: the file's or the "
                   "function's, without {seed})")
    p.add_argument("--label", help="its name in the tables (default: --name)")
    p.add_argument("--eval-rounds", type=int, default=10, metavar="R", help="R of Table 3")
    p.add_argument("--eval-cases", type=int, default=200, metavar="C", help="C of Table 3: test cases per round (the "
                   "first C of 200)")
    p.add_argument("--workers", type=int, default=2, help="evaluation processes; 0: in this process")
    p.add_argument("--out", type=Path, default=Path("runs"), help="each seed's run goes to OUT/SCENARIO-NAME-sSEED "
                   "(its eval.json)")
    p.add_argument("--runs", type=Path, nargs="+", default=[RESULTS], help="folders of Table 3's SCENARIO-ALGO-sSEED "
                   "runs")
    args = p.parse_args(argv)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a kill keeps the finished rounds, as Ctrl-C
    spec = args.sb3 or args.policy
    specs = {seed: spec.replace("{seed}", str(seed)) for seed in args.seeds}
    name = args.name or slug(Path(spec).stem if args.sb3 else spec.partition(":")[2])
    made = {s: loaded(s, args.sb3_algo if args.sb3 else None, name) for s in dict.fromkeys(specs.values())}  # once each
    evaluate_policy({seed: made[s][0] for seed, s in specs.items()}, args.scenario, args.seeds, name, args.label,
                    args.eval_rounds, args.eval_cases, args.workers, args.out, args.runs,
                    train_steps={seed: made[s][1] for seed, s in specs.items()}, stochastic=args.stochastic)


if __name__ == "__main__":
    main()
