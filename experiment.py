"""The experiment around the method: Table 3's rows, their evaluation (Sec. 5.3, 5.5) and the command line.

    python tarl.py --scenario roundabout                       # train TARL, evaluate it beside Lattice-IDM
    python tarl.py --scenario roundabout --load results/runs/roundabout-tarl-s0/policy.pt --timing fixed=2

tarl.py is the paper's method (Sec. 4); baselines.py the safe-RL rows; this module puts them in a table,
trains a row, and evaluates it as Table 3 does: R rounds of C recorded test cases, the same cases for
every row. Only the entry point (`python tarl.py`) and bench/ import it.

    Table 3's rows              ROWS, make_trainer, trained_rows
    Sec. 5.3, Table 3           rollout, play_round, evaluate, summarize, table
    Sec. 5.5                    summarize: 1 - beta before collisions, the share of each T
    the command line            parse_args, main; its files: run_name (the run's folder), read_eval (its eval.json)
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import importlib
import json
import multiprocessing as mp
import multiprocessing.connection
import os
import platform
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import tarl  # noqa: I001 (first: it sets OpenMP's wait policy before torch loads)
import numpy as np
import torch
import world
from tarl import Driver, SACConfig, TimingConfig, TrainConfig, execute
from world import SCENARIOS, DrivingEnv, EnvConfig


@dataclass(frozen=True)
class Row:
    """A row of Table 3: how it trains and how it acts."""
    label: str
    timing: str  # its tarl.Driver's timing
    step_one: bool  # Algorithm 1's step 1 (plain SAC for TrainConfig.sac_fraction of the steps) comes first
    trainer: type | str | None  # tarl.Trainer, or "module:Class" imported when the row trains; None: nothing to train
    imagination: str = "phased"  # what its timing imagination executes (TrainConfig.imagination)
    timing_updates: int = 1  # its timing taker's updates per decision (TrainConfig.timing_updates)


# baselines.py and beyond/ (PAPER.md, 6) load only when their row trains: `python tarl.py` needs tarl.py and this module
ROWS = {
    "tarl": Row("TARL", "taker", True, tarl.Trainer),
    "tarl-fixed-t": Row("TARL, T = 2 fixed", "fixed", True, tarl.Trainer),  # ablation: no timing taker
    "tarl-random-t": Row("TARL, T random", "random", True, tarl.Trainer),  # ablation: no timing taker
    "tarl-consistent": Row("TARL, phased real loop", "phased", True, tarl.Trainer),  # beyond the paper (PAPER.md)
    "tarl-held": Row("TARL, held imagination", "taker", True, tarl.Trainer, "held"),  # beyond the paper (PAPER.md)
    "tarl-utd": Row("TARL, 8 timing updates", "taker", True, tarl.Trainer, timing_updates=8),  # beyond the paper
    "tarl-actor-target": Row("TARL, actor's critic in Eq. (9)", "taker", True, "beyond.variants:ActorTargetTrainer",
                             timing_updates=0),  # beyond the paper
    "tarl-rare-replay": Row("TARL, collision replay", "taker", True, "beyond.variants:RareReplayTrainer"),  # beyond
    "tarl-min-target": Row("TARL, lower of both critics in Eq. (9)", "taker", True, "beyond.variants:MinTargetTrainer",
                           timing_updates=0),  # beyond the paper
    "tarl-branch": Row("TARL, timing from branches", "taker", True, "beyond.variants:BranchTrainer"),  # beyond
    "sac": Row("SAC", "none", False, tarl.Trainer),  # Algorithm 1's actor loop alone
    "sac-lattice": Row("SAC-Lattice", "switch", False, tarl.Trainer),
    "lattice-idm": Row("Lattice-IDM", "planner", False, None),
    "sac-lag": Row("SAC-Lag", "none", False, "baselines:SafeSACTrainer"),
    "sac-pid": Row("SAC-PID", "none", False, "baselines:SafeSACTrainer"),
    "ppo-lag": Row("PPO-Lag", "none", False, "baselines:OnPolicyTrainer"),
    "cpo": Row("CPO", "none", False, "baselines:OnPolicyTrainer"),
}


def make_trainer(algo: str, env: DrivingEnv, tc: TrainConfig, seed: int = 0, out: Path | None = None, log=print,
                 state: dict | None = None):
    """The trainer of a learned row of Table 3: run(), load(), step, driver. state: a checkpoint whose
    networks' sizes the trainer takes."""
    row = ROWS[algo]
    sac_cfg = SACConfig(**state["config"]["sac"]) if state else SACConfig()
    tc = replace(tc, imagination=row.imagination, timing_updates=row.timing_updates)
    trainer = row.trainer
    if isinstance(trainer, str):  # "module:Class", imported now
        module, _, name = trainer.partition(":")
        trainer = getattr(importlib.import_module(module), name)
    return trainer(env, algo, tc, sac_cfg, seed, out, log, timing=row.timing, step_one=row.step_one)


def trained_rows(trainer) -> list[dict]:
    """The rows a run adds to Table 3: the trained model, and after Algorithm 1's step 1 the step-1 model."""
    rows = [dict(algo=trainer.algo, driver=trainer.driver, train_steps=trainer.step)]
    if trainer.sac_actor is not None:
        rows.append(dict(algo="tarl-step1", label=f"TARL step 1 ({trainer.step_one:,} steps)",
                         driver=Driver("none", trainer.sac_actor), train_steps=trainer.step_one))
    return rows


BEYOND_TIMINGS = {"rollout": "beyond.rollout_timing", "distilled": "beyond.distil"}  # --timing NAME[=...]: its module


def timing_override(spec: str, trainer) -> Driver:
    """--timing of a loaded model: learned, phased, random, fixed=T, cap=T, rollout[=T1,T2,...] or distilled=PATH, with
    the model's actor."""
    name, _, value = spec.partition("=")
    if name in BEYOND_TIMINGS:  # beyond the paper: its module, imported only now, reads the spec
        return importlib.import_module(BEYOND_TIMINGS[name]).driver(spec, trainer)
    timing = {"learned": "taker", "cap": "taker"}.get(name, name)
    return Driver(timing, trainer.actor, trainer.timing_taker, trainer.seed, trainer.tc.timing,
                  fixed_T=int(value) if name == "fixed" else 2, cap=int(value) if name == "cap" else None)


def timing_name(spec: str) -> str:
    """--timing SPEC as a row's label shows it: a student by its file's name (distilled=.../A.pt: distilled A)."""
    return f"distilled {Path(spec.removeprefix('distilled=')).stem}" if spec.startswith("distilled=") else spec


def load_checkpoint(path: Path, scenario: str, algo: str) -> dict:
    """A checkpoint of --scenario, --algo as plain tensors and dicts (a stranger's pickle never runs)."""
    if not Path(path).is_file():
        raise SystemExit(f"checkpoint not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise SystemExit(f"cannot load checkpoint {path}: {str(e).splitlines()[0][:200]}") from None
    cfg = state.get("config") if isinstance(state, dict) else None
    if not cfg or "actor" not in state:
        raise SystemExit(f"{path} is not a tarl checkpoint: it has no config or no actor")
    if (cfg["scenario"], cfg["algo"]) != (scenario, algo):
        raise SystemExit(f"{path} is for --scenario {cfg['scenario']} --algo {cfg['algo']}, "
                         f"not --scenario {scenario} --algo {algo}")
    return state


def checkpoint_timing(state: dict | None) -> TimingConfig:
    """w and T_max a checkpoint was trained with (TimingConfig's defaults before they were saved)."""
    return TimingConfig(**((state or {}).get("config", {}).get("train", {}).get("timing") or {}))


# ---- Evaluation: Sec. 5.3, Table 3, Sec. 5.5 ------------------------------------------------------


def rollout(env: DrivingEnv, driver: Driver, options: dict | None = None, record: bool = False,
            deterministic: bool = True) -> dict:
    """One episode of `driver` from env.reset(options=options), recorded step by step.

    Per step: the actor's a (nan without an actor), T (0 without a timing), beta, a_base (nan where not needed, unless
    record), the executed a_bar, the ego's speed v [m/s]; with record, also the ego's (x, y, heading), the others'
    (M, 3) (x, y, heading) and the base planner's planned (K, 2) x, y. Also: the start's fingerprint, the outcome
    ("arrival", "collision" or "timeout"), the crossing time [s] (None unless arrived) and the number of steps."""
    obs, _ = env.reset(options=options)
    # tarl-random-t: the same timings wherever and whenever the case is played
    driver.new_episode(options["case"]["seed"] if options and "case" in options else None)
    ep = {key: [] for key in ("a", "T", "beta", "a_base", "a_bar", "v") + ("ego", "others", "plan") * record}
    start, done = env.fingerprint(), False
    while not done:
        a, T, b = driver.act(obs, env, deterministic)  # a rollout timing branches here, and restores the env
        env.show(T, b)  # who drives: for render() and sumo-gui
        for key, value in (("a", np.nan if a is None else a[0]), ("T", T or 0), ("beta", b), ("v", env.v),
                           ("a_base", env.base_action() if b < 1.0 or record else np.nan), ("a_bar", execute(env, a, b))):
            ep[key].append(value)
        if record:
            ep["ego"].append((*env.xy, env.heading))
            ep["others"].append(env.others[:, [0, 1, 3]].copy())
            ep["plan"].append(env.plan_xy())
        obs, _, terminated, truncated, info = env.step(ep["a_bar"][-1])
        done = terminated or truncated
    outcome = "collision" if info["collision"] else "arrival" if info["arrival"] else "timeout"
    return dict(start=start, outcome=outcome, crossing_time=info["crossing_time"], steps=len(ep["a"]),
                **{k: v if k in ("others", "plan") else np.array(v) for k, v in ep.items()},
                **getattr(driver, "stats", dict)())  # a rollout timing's decisions, branch steps, wall time


def test_seed(seed: int, round_: int) -> int:
    """SUMO and traffic seed of evaluation round `round_`: the same for every model, apart from training's."""
    return 1_000_000 + 1000 * seed + round_


def play_round(env: DrivingEnv, drivers: list[Driver], cases: int, seed: int, round_: int) -> list[list[dict]]:
    """One round of Table 3 for every driver: the round's test cases (record_cases, once), each played by each driver
    acting deterministically (the actor's mean, the most likely T). Per driver, the rollout() of each case, in order."""
    with tempfile.TemporaryDirectory() as folder:
        recorded = env.record_cases(test_seed(seed, round_), cases, folder)
        return [[dict(rollout(env, driver, {"case": case}), round=round_, case=c) for c, case in enumerate(recorded)]
                for driver in drivers]


def _worker(conn):
    """An evaluation process: plays the rounds it is sent on its own simulation (libsumo: one per process)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's: it ends the workers
    torch.set_num_threads(1)
    env = None
    for cfg, drivers, cases, seed, r in iter(conn.recv, None):  # None: no more rounds
        try:
            env = env if env is not None and env.cfg == cfg else DrivingEnv(cfg)
            conn.send((r, play_round(env, drivers, cases, seed, r), None))
        except (Exception, SystemExit) as e:  # a SystemExit is the world's one-line error
            conn.send((r, None, str(e).splitlines()[0] if str(e) else type(e).__name__))


def play_in_workers(jobs: list[tuple], n: int):
    """Yield (r, episodes) as the rounds of `jobs` finish in n processes. A worker that fails or dies (a SUMO
    crash, an out-of-memory kill) ends the evaluation at once with one line naming its round; the workers
    never outlive this generator."""
    ctx, workers, todo = mp.get_context("spawn"), [], list(jobs)
    try:
        for _ in range(min(n, len(jobs))):
            here, there = ctx.Pipe()
            proc = ctx.Process(target=_worker, args=(there,), daemon=True)
            proc.start()
            there.close()
            workers.append({"proc": proc, "conn": here, "round": None})
        while todo or any(w["round"] is not None for w in workers):
            for w in workers:
                if w["round"] is None and todo:
                    w["round"] = todo[0][-1]
                    with contextlib.suppress(OSError):  # it died idle
                        w["conn"].send(todo.pop(0))
            busy = [w for w in workers if w["round"] is not None]
            mp.connection.wait([w["conn"] for w in busy] + [w["proc"].sentinel for w in busy], timeout=1.0)
            for w in busy:
                r = w["round"]
                try:
                    if not w["conn"].poll():
                        if w["proc"].is_alive():
                            continue
                        raise EOFError
                    r, episodes, error = w["conn"].recv()
                except (EOFError, OSError):
                    w["proc"].join(timeout=2.0)  # its pipe can close before the process is reaped
                    code = w["proc"].exitcode
                    how = f"killed by {signal.Signals(-code).name}" if code and code < 0 else f"exit code {code}"
                    raise SystemExit(f"evaluation round {r + 1} failed: its worker process died ({how}); the "
                                     "finished rounds are kept, run the same command again to play the others") from None
                if error is not None:
                    raise SystemExit(f"evaluation round {r + 1} failed: {error}")
                w["round"] = None
                yield r, episodes
    finally:
        for w in workers:
            w["proc"].terminate()
        for w in workers:
            w["proc"].join(timeout=2.0)
            if w["proc"].is_alive():
                w["proc"].kill()
                w["proc"].join(timeout=2.0)


def evaluate(cfg: EnvConfig, rows: list[dict], rounds: int, cases: int, seed: int = 0, workers: int = 2,
             env: DrivingEnv | None = None, log=print, keep: Path | None = None) -> list[dict]:
    """Table 3's protocol for every row (dicts of algo, driver, optional label and train_steps): R rounds
    of C test cases, round r from test_seed(seed, r), every row on the same cases. The rounds run in
    `workers` processes, or here on `env` if workers is 0 (sumo-gui, tests, a function swapped in this
    process): a round gives the same numbers wherever it runs. keep: a folder where each finished round is
    kept, so that an interrupted evaluation of the same models plays only the rounds it had not finished."""
    drivers, t0, key = [row["driver"] for row in rows], time.time(), evaluation_key(cfg, rows, cases, seed)
    played = {r: kept for r in range(rounds) if (kept := kept_round(keep, r, key)) is not None}
    todo = [r for r in range(rounds) if r not in played]
    if played:
        log(f"  {len(played)} of {rounds} rounds kept in {keep} from an interrupted evaluation")
    if workers and todo:
        world.check_network(*world.scenario_files(cfg.scenario))  # here, before any worker: a broken network is one line
        done = play_in_workers([(cfg, drivers, cases, seed, r) for r in todo], workers)
    else:
        done = ((r, play_round(env, drivers, cases, seed, r)) for r in todo)
    for n, (r, result) in enumerate(done, 1):
        played[r] = [[{k: ep[k].tolist() if k in ("beta", "T") else ep[k] for k in KEPT + BRANCHING if k in ep}
                      for ep in eps] for eps in result]  # what summarize needs, as JSON keeps it
        if keep is not None:
            keep.mkdir(parents=True, exist_ok=True)
            (keep / f"round{r}.json").write_text(json.dumps(dict(key=key, rows=played[r])))
        successes = ", ".join(f"{row['algo']} {np.mean([ep['outcome'] == 'arrival' for ep in eps]):.3f}"
                              for row, eps in zip(rows, result))
        log(f"  round {r + 1}/{rounds}: success {successes}  [{n}/{len(todo)} rounds, {time.time() - t0:.0f} s, "
            f"ETA {(time.time() - t0) / n * (len(todo) - n):.0f} s]")
    return [summarize(row, [played[r][i] for r in range(rounds)], cfg, seed) for i, row in enumerate(rows)]


class Beside:
    """Rows evaluated beside training, each by `evaluate` in one worker process driven from a thread, its rounds kept
    in KEEP/beside-ALGO: start(row) begins one, results() waits for all. A round gives the same numbers wherever it
    runs, so the rows equal an evaluation of all of them together."""

    def __init__(self, cfg: EnvConfig, rounds: int, cases: int, seed: int, keep: Path, log=print):
        self.cfg, self.rounds, self.cases, self.seed, self.keep, self.log = cfg, rounds, cases, seed, keep, log
        self.threads, self.done, self.errors = {}, {}, {}

    def start(self, row: dict):
        self.threads[row["algo"]] = thread = threading.Thread(target=self._run, args=(row,), daemon=True)
        thread.start()

    def _run(self, row: dict):
        try:
            self.done[row["algo"]] = evaluate(self.cfg, [row], self.rounds, self.cases, self.seed, 1,
                                              log=lambda line: self.log(f"  beside training, {row['label']}:{line}"),
                                              keep=self.keep / f"beside-{row['algo']}")[0]
        except BaseException as e:  # a worker that died (one line), or anything else: raised by results()
            self.errors[row["algo"]] = e

    def results(self) -> dict:
        """{algo: its row's result} once every row started has finished; a row that failed ends the run in one line."""
        for thread in self.threads.values():
            thread.join()
        for algo, e in self.errors.items():
            raise SystemExit(f"{algo}, evaluated beside training: {str(e).splitlines()[0] if str(e) else type(e).__name__}")
        return self.done


CASE_KEYS = ("round", "case", "start", "outcome", "crossing_time", "steps")  # of each case, in eval.json
KEPT = (*CASE_KEYS, "beta", "T")  # of an episode: what summarize needs
BRANCHING = ("decisions", "branch_steps", "wall_s")  # of a case played by a rollout timing (beyond/rollout_timing.py)


def evaluation_key(cfg: EnvConfig, rows: list[dict], cases: int, seed: int) -> str:
    """What a kept round was played with: the world's version, the scenario, seed, cases per round, each row's algo,
    timing and weights."""
    timings = [(d.timing, asdict(d.timing_cfg), d.fixed_T, d.cap, *([d.settings] if hasattr(d, "settings") else []))
               for d in (row["driver"] for row in rows)]
    h = hashlib.sha1(repr((world.WORLD_VERSION, asdict(cfg), cases, seed, [row["algo"] for row in rows],
                           timings)).encode())
    for net in (n for row in rows for n in (row["driver"].actor, row["driver"].timing_taker) if n is not None):
        module = getattr(net, "policy", net)
        if not hasattr(module, "state_dict"):  # a hand-written actor (tests, exercises)
            h.update(repr(vars(module)).encode())
            continue
        for tensor in module.state_dict().values():
            h.update(tensor.numpy().tobytes())
    return h.hexdigest()


def kept_round(keep: Path | None, r: int, key: str) -> list[list[dict]] | None:
    """Round r's episodes per row, if `keep` holds it from the same models and cases."""
    try:
        kept = json.loads((keep / f"round{r}.json").read_text()) if keep is not None else {}
    except (OSError, ValueError):  # no file, or one cut short
        return None
    return kept["rows"] if kept.get("key") == key else None


def mean_std(x) -> dict:
    """Mean and standard deviation of the values that are not None; None (null in JSON) if there are none."""
    x = np.asarray([v for v in x if v is not None], dtype=float)
    return {"mean": float(np.mean(x)), "std": float(np.std(x))} if len(x) else {"mean": None, "std": None}


def summarize(row: dict, rounds: list[list[dict]], cfg: EnvConfig, seed: int) -> dict:
    """One row of Table 3 from its rounds of played cases, each number a mean +- std over rounds.

    success, collision and timeout rates (they sum to 1). crossing_time: the mean over a round's successes, the paper's
    measure (a round without any is null, counted in rounds_without_success); crossing_time_all: over the cases that did
    not collide, a timeout counted at the time limit, so a model that times out on hard cases does not look faster.
    Sec. 5.5 (rows that blend): mean (1 - beta) over all steps and in the last 3 s and 1 s before collisions; the
    share of steps at each T. cases: each case's round, case, start fingerprint, outcome, crossing time [s] and steps."""
    rate = lambda outcome: mean_std([np.mean([ep["outcome"] == outcome for ep in r]) for r in rounds])  # noqa: E731
    crossing = [[ep["crossing_time"] for ep in r if ep["outcome"] == "arrival"] for r in rounds]
    crossing_all = [[ep["crossing_time"] or cfg.time_limit for ep in r if ep["outcome"] != "collision"] for r in rounds]
    out = {"algo": row["algo"], "label": row.get("label", row["algo"]), "train_steps": row.get("train_steps", 0),
           "seed": seed, "rounds": len(rounds), "cases_per_round": len(rounds[0]), "success_rate": rate("arrival"),
           "collision_rate": rate("collision"), "timeout_rate": rate("timeout"),
           "crossing_time": mean_std([np.mean(c) if c else None for c in crossing]),
           "crossing_time_all": mean_std([np.mean(c) if c else None for c in crossing_all]),
           "rounds_without_success": sum(not c for c in crossing)}
    episodes, driver = [ep for r in rounds for ep in r], row["driver"]
    crashes, k3, k1 = [ep for ep in episodes if ep["outcome"] == "collision"], round(3.0 / cfg.dt), round(1.0 / cfg.dt)
    if driver.timing in ("taker", "phased", "fixed", "random", "switch", "rollout", "distilled"):
        minus = lambda b: float(np.mean(1.0 - np.concatenate(b))) if b else None  # noqa: E731
        out["beta_minus"] = {"all_steps": minus([ep["beta"] for ep in episodes]),
                             "3s_before_collision": minus([ep["beta"][-k3:] for ep in crashes]),
                             "1s_before_collision": minus([ep["beta"][-k1:] for ep in crashes])}
    if driver.timing in ("taker", "phased", "random", "rollout", "distilled"):
        n = driver.timing_cfg.t_max
        share = lambda T: (np.bincount(np.concatenate(T), minlength=n + 1)[1:] / sum(map(len, T))).round(4).tolist()  # noqa: E731
        out["timing_share"] = {"all_steps": share([ep["T"] for ep in episodes]),  # of T = 1, ..., T_max
                               "3s_before_collision": share([ep["T"][-k3:] for ep in crashes]) if crashes else None}
    if "branch_steps" in episodes[0]:  # a rollout timing: per case, its decisions, the steps of its branches
        out["branching"] = {k: mean_std([np.mean([ep[k] for ep in r]) for r in rounds]) for k in ("steps", *BRANCHING)}
    out["cases"] = [{k: ep[k] for k in (*CASE_KEYS, *BRANCHING) if k in ep} for ep in episodes]
    return out


def table(results: list[dict]) -> str:
    """Table 3's layout: rates and crossing times, mean +- std over the rounds."""
    fmt = lambda m, p=3: f"{m['mean']:.{p}f} +- {m['std']:.{p}f}" if m["mean"] is not None else "-"  # noqa: E731
    lines = [f"{'model':<26}{'success':>16}{'collision':>16}{'timeout':>16}{'crossing [s]':>16}{'with timeouts':>16}"]
    lines += [f"{r['label']:<26}{fmt(r['success_rate']):>16}{fmt(r['collision_rate']):>16}{fmt(r['timeout_rate']):>16}"
              f"{fmt(r['crossing_time'], 2):>16}{fmt(r['crossing_time_all'], 2):>16}" for r in results]
    return "\n".join(lines)


# ---- Command line ------------------------------------------------------------------------------------


class Help(argparse.ArgumentDefaultsHelpFormatter):
    """--help with each default, except those given in the text (None here)."""
    def _get_help_string(self, action):
        return action.help if action.default is None else super()._get_help_string(action)


DEFAULTS = dict(steps=TrainConfig.steps, eval_rounds=10, eval_cases=200)  # Table 3's protocol at the default budget
PRESETS = {"lab": dict(steps=30_000, eval_rounds=2, eval_cases=50)}  # a curve and a short evaluation in a class


def timing_error(spec: str, algo: str) -> str | None:
    """What is wrong with --timing SPEC for a loaded actor of --algo ALGO (timing_override), or None."""
    name, eq, value = spec.partition("=")
    try:
        if name in BEYOND_TIMINGS and importlib.import_module(BEYOND_TIMINGS[name]).parse(spec) is not None:
            return None
    except (ValueError, SystemExit) as e:
        return str(e)
    if name not in ("learned", "phased", "random", "fixed", "cap") or (name in ("fixed", "cap")) != bool(eq) \
            or (eq and not (value.isdigit() and int(value) >= 1)):
        return f"{spec}: choose learned, phased, random, fixed=T, cap=T with T >= 1, rollout[=T1,T2,...] or distilled=PATH"
    if name in ("learned", "phased", "cap") and ROWS[algo].timing not in ("taker", "phased"):
        return f"{name} needs a timing taker: --algo {algo} has none"
    return None


def parse_args(argv=None):
    """The command line, all of it checked before any work: a bad value is one line, not a late traceback."""
    p = argparse.ArgumentParser(prog="tarl.py", description="Train timing-aware RL (or a baseline) in SUMO, then "
                                "evaluate it as Table 3 does.", formatter_class=Help)
    p.add_argument("--scenario", choices=sorted(SCENARIOS), default="roundabout", help="default: %(default)s")
    p.add_argument("--algo", choices=tuple(ROWS), default="tarl",
                   help="the row of Table 3 to train and evaluate; Lattice-IDM is evaluated beside it")
    p.add_argument("--preset", choices=tuple(PRESETS), help="lab: a class's run, a few minutes on 2 cores: "
                   "--steps 30000 --eval-rounds 2 --eval-cases 50 --out runs/lab/SCENARIO-ALGO-sSEED")
    p.add_argument("--steps", type=int, help=f"simulator steps of training (default {TrainConfig.steps:,}; Table 2: "
                   "500,000)")
    p.add_argument("--step-one", type=int, metavar="STEPS", help="steps of Alg. 1's step 1, plain SAC, within --steps "
                   f"(default: the share TrainConfig.sac_fraction = {TrainConfig.sac_fraction})")
    p.add_argument("--seed", type=int, default=0, help="seeds training and the evaluation rounds")
    p.add_argument("--eval-rounds", type=int, help="R of Table 3 (default 10)")
    p.add_argument("--eval-cases", type=int, help="C of Table 3: test cases per round (default 200)")
    p.add_argument("--out", type=Path, help="run directory (default runs/SCENARIO-ALGO-sSEED): train_log.csv, "
                   "ckpt.pt, policy.pt, eval.json (eval-rounds/ while evaluating)")
    p.add_argument("--load", type=Path, metavar="CKPT", help="evaluate this ckpt.pt or policy.pt instead of training")
    p.add_argument("--resume", action="store_true", help="continue the interrupted run in --out")
    p.add_argument("--threads", type=int, default=1, help="torch threads for training: 1, as the grid's cells train, "
                   "gives the committed seed's numbers on its CPU type (float kernels differ with the threads)")
    p.add_argument("--workers", type=int, default=2, help="evaluation processes, one simulation each; 0: in this "
                   "process (where a function swapped in by an exercise takes effect). With 2 or more, a training run "
                   "evaluates Lattice-IDM and its step-1 model beside it, one process each")
    p.add_argument("--eval-rows", choices=("all", "trained"), default="all", help="all: beside the --algo row, "
                   "TARL's step-1 model and Lattice-IDM on the same cases; trained: the --algo row alone")
    p.add_argument("--gui", action="store_true", help="watch in sumo-gui (needs --load unless --algo lattice-idm)")
    g = p.add_argument_group("timing (Sec. 4)")
    g.add_argument("--omega", type=float, help=f"w of Eq. (6) (default: the checkpoint's, else {TimingConfig.omega})")
    g.add_argument("--t-max", type=int, help=f"T_max [steps] of a run to train (default {TimingConfig.t_max})")
    g.add_argument("--timing", metavar="SPEC", help="with --load: how the loaded actor's T is chosen: learned, phased "
                   "(Eq. (7)'s schedule), random, fixed=T, cap=T (the timing taker's T, at most T), rollout[=T1,T2,...] "
                   "(the T of the best simulated branch, beyond/rollout_timing.py) or distilled=PATH (a student of "
                   "bench/distillation.py, beyond/distil.py)")
    w = p.add_argument_group("traffic (Table 1)")
    w.add_argument("--spawn-gap", type=float, help="t_spawn [s]: mean gap between departures (default: the scenario's)")
    w.add_argument("--svo", type=float, nargs=2, metavar=("LOW", "HIGH"), help="range of the humans' alpha_svo of "
                   "Eq. (26) (default 0 0.5)")
    w.add_argument("--human-level", type=int, choices=(0, 2), help="the humans' level k in the game (default 2)")
    args = p.parse_args(argv)
    for key, value in (PRESETS[args.preset] if args.preset else DEFAULTS).items():
        setattr(args, key, value if getattr(args, key) is None else getattr(args, key))
    if min(args.eval_rounds, args.eval_cases, args.steps, args.threads, args.workers + 1) < 1:
        p.error("--steps, --eval-rounds, --eval-cases and --threads must be at least 1, --workers at least 0")
    if args.load and args.resume:
        p.error("--load evaluates a checkpoint, --resume continues training: choose one")
    if args.gui and not args.load and args.algo != "lattice-idm":
        p.error("--gui watches a trained agent: give it --load CKPT")
    if args.omega is not None and not args.omega > 0:
        p.error("--omega must be positive")
    if args.t_max is not None and (args.t_max < 1 or args.load or args.resume):
        p.error("--t-max sets the T_max of a new run (at least 1); a checkpoint keeps its own")
    if args.timing is not None:
        if not args.load or ROWS[args.algo].trainer is None:
            p.error("--timing changes how a loaded actor is timed: give it --load CKPT of a learned row")
        if error := timing_error(args.timing, args.algo):
            p.error(f"--timing {error}")
    if args.step_one is not None and (not ROWS[args.algo].step_one or args.load):
        p.error(f"--step-one sets Alg. 1's step 1 of a run to train: --algo {args.algo} has none, or --load was given")
    if args.step_one is not None and not 0 < args.step_one < args.steps:
        p.error("--step-one must be above 0 and below --steps")
    if args.svo is not None and not 0.0 <= args.svo[0] <= args.svo[1] <= 1.0:
        p.error("--svo LOW HIGH: 0 <= LOW <= HIGH <= 1")
    if args.spawn_gap is not None and not args.spawn_gap > 0:
        p.error("--spawn-gap must be positive [s]")
    args.out = args.out or Path("runs") / ("lab" if args.preset else "") / run_name(args.scenario, args.algo, args.seed)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=args.out).close()  # can it be written?
    except OSError as e:
        raise SystemExit(f"--out {args.out} cannot be written: {e.strerror}") from None
    args.state = None
    if args.load or args.resume:
        args.state = load_checkpoint(args.load or args.out / "ckpt.pt", args.scenario, args.algo)
        # a run that trained its whole --steps and was stopped while evaluating: --resume plays the rounds it lacks
        trained = args.state["step"] >= args.steps == args.state["config"].get("train", {}).get("steps")
        if args.resume and not trained and args.steps < max(args.state["step"], args.state["step_one"]) + 1:
            raise SystemExit(f"--resume: the run in {args.out} is at step {args.state['step']:,} (its step 1 ends at "
                             f"{args.state['step_one']:,}); give --steps above both")
        if args.resume and args.step_one not in (None, args.state["step_one"]):
            raise SystemExit(f"--resume: the run in {args.out} has a step 1 of {args.state['step_one']:,} steps, "
                             f"not --step-one {args.step_one:,}")
    elif (args.out / "ckpt.pt").exists():
        raise SystemExit(f"{args.out} already holds a run: --resume to continue it, or choose another --out")
    return args


def machine() -> str:
    """The CPU type this run is on: a seed repeats itself bit for bit on one type only (float kernels differ)."""
    info = Path("/proc/cpuinfo").read_text().split("\n\n")[0] if Path("/proc/cpuinfo").exists() else ""
    cpu = dict(map(str.strip, line.split(":", 1)) for line in info.splitlines() if ":" in line)  # its first core's
    kind = [cpu.get("model name") or platform.processor() or "unknown CPU"]  # one name, "AMD EPYC", covers several:
    kind += [f"{key} {cpu[key]}" for key in ("cpu family", "model", "stepping") if key in cpu]  # these tell them apart
    kind += [f"flags md5 {hashlib.md5(cpu['flags'].encode()).hexdigest()[:12]}"] * ("flags" in cpu)
    return ", ".join([*kind, f"{os.cpu_count()} cores", platform.machine(), f"torch {torch.__version__}"])


def run_name(scenario: str, algo: str, seed: int, budget: str = "") -> str:
    """A run's folder: SCENARIO-ALGO-sSEED, another budget than the default after it (-500k, -67k-step1-40k)."""
    return f"{scenario}-{algo}-s{seed}" + f"-{budget}" * bool(budget)


def read_eval(path: Path) -> dict:
    """An eval.json (main writes it) as written, of world 1 if it names none (written before worlds had a version)."""
    data = json.loads(Path(path).read_text())
    return {**data, "world": data.get("world", 1)}


def main(argv=None):
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a kill saves like Ctrl-C
    traffic = {k: v for k, v in (("spawn_gap", args.spawn_gap), ("svo_range", args.svo and tuple(args.svo)),
                                 ("human_level", args.human_level)) if v is not None}
    cfg, rows = EnvConfig(scenario=args.scenario, **traffic), []  # the world of the command line: scenario, traffic
    timing = checkpoint_timing(args.state) if args.state else TimingConfig(t_max=args.t_max or TimingConfig.t_max)
    timing = timing if args.omega is None else replace(timing, omega=args.omega)
    code = subprocess.run(["git", "-C", str(Path(__file__).parent), "describe", "--always", "--dirty"],
                          capture_output=True, text=True).stdout.strip() or None  # the commit this run starts from
    env = DrivingEnv(cfg, gui=args.gui)
    workers, keep = 0 if args.gui else args.workers, args.out / "eval-rounds"
    planner = dict(algo="lattice-idm", label="Lattice-IDM", driver=Driver("planner"))
    beside = Beside(cfg, args.eval_rounds, args.eval_cases, args.seed, keep)  # one core trains, one evaluates
    trains = args.algo != "lattice-idm" and not args.load  # a row trained here, not loaded
    try:
        if args.algo != "lattice-idm":
            share = TrainConfig.sac_fraction if args.step_one is None else args.step_one / args.steps
            trainer = make_trainer(args.algo, env, TrainConfig(steps=args.steps, sac_fraction=share, timing=timing),
                                   args.seed, args.out, state=args.state)
            if args.state:
                trainer.load(args.state, resume=args.resume)
            if not args.load:
                if args.eval_rows == "all" and workers >= 2:  # Lattice-IDM and the step-1 model in spare workers
                    beside.start(planner)
                    if trainer.sac_actor is None:
                        trainer.after_step_one = lambda: beside.start(trained_rows(trainer)[1])
                    else:  # resumed after step 1
                        beside.start(trained_rows(trainer)[1])
                print(f"training {args.algo} on the {args.scenario} from step {trainer.step} to {args.steps} -> {args.out}")
                try:
                    trainer.run()
                except KeyboardInterrupt:
                    raise SystemExit(f"saved {args.out / 'ckpt.pt'} and the log; continue with --resume --out "
                                     f"{args.out}") from None
            rows = trained_rows(trainer)[:1 if args.eval_rows == "trained" else None]
            if args.timing:
                rows[0] = dict(rows[0], driver=timing_override(args.timing, trainer),
                               label=f"{ROWS[args.algo].label}, T {timing_name(args.timing)}")
        if args.algo == "lattice-idm" or args.eval_rows == "all":
            rows.append(planner)
        print(f"evaluating on the {args.scenario}: {args.eval_rounds} rounds x {args.eval_cases} test cases, the same "
              "cases for every model")
        if workers:
            env.close()  # the workers run their own simulations
        try:
            here = [row for row in rows if row["algo"] not in beside.threads]
            done = dict(zip((row["algo"] for row in here), evaluate(cfg, here, args.eval_rounds, args.eval_cases,
                                                                     args.seed, workers, env, keep=keep)))
            done.update(beside.results())
            results = [done[row["algo"]] for row in rows]
        except KeyboardInterrupt:
            again = f"continue with --resume --out {args.out}" if trains else "run the same command again"
            raise SystemExit(f"kept the finished rounds in {keep}; {again} to play the others") from None
    finally:
        env.close()
    print(table(results))
    if "beta_minus" in results[0]:
        print("1 - beta, the planner's share (Sec. 5.5): all steps {}, last 3 s before a collision {}, last 1 s {}".format(
              *("-" if v is None else f"{v:.3f}" for v in results[0]["beta_minus"].values())))
    if trains:  # the trained row's gradient updates: {"actor": n, "timing": n}
        results[0]["updates"] = dict(trainer.updates)
    (args.out / "eval.json").write_text(json.dumps(dict(scenario=args.scenario, seed=args.seed, code=code,
                                                        world=world.WORLD_VERSION, machine=machine(), rows=results)))
    print(f"wrote {args.out / 'eval.json'}")
    shutil.rmtree(keep, ignore_errors=True)


if __name__ == "__main__":
    main()
