"""Table 3 of the paper as a grid: every row x both scenarios x seeds, resumable cell by cell.

    python bench/table3.py                    # run or resume the grid, 2 cells side by side
    python bench/table3.py --print-commands   # one command per cell, for a scheduler (README)
    python bench/table3.py --slurm --submit   # the unfinished cells as a Slurm array job (bench/slurm.py)
    python bench/table3.py --collect-only     # rebuild results/table3.md from results/runs/
    python bench/table3.py --collect-only --readme   # and the tables in README.md and docs/RESULTS.md
    python bench/table3.py --collect-only --extra runs/roundabout-sb3-sac-s0/eval.json   # your own agent's rows too

A cell is one `python tarl.py --scenario S --algo A --seed K` run in runs/grid/S-A-sK (its
checkpoints), evaluated on the fixed test cases of seed K; TARL's cell is the default command, which
also evaluates Lattice-IDM and TARL's step-1 model on the same cases. When it finishes, its eval.json,
train_log.csv, constraint_log.csv (safe-RL rows) and policy.pt go to results/runs/S-A-sK and, with
--commit, committed: an interruption loses at most the cells in progress, which resume from their
checkpoints. A cell whose results/runs/S-A-sK/eval.json exists is done and skipped.
The table reports each number as the mean +- std over seeds of each seed's mean over its rounds,
beside the mean over seeds of the per-round std (Table 3's +-) and the paper's value, with the number of
seeds (n) beside every row; a row of one seed shows its mean and per-round std, no +- over seeds. With
--readme it also writes docs/RESULTS.md's table of the paper's claims, each tested over whatever seeds its rows have
(`claim_rows`: Welch's test by scipy.stats, docs/RESULTS.md, "How the numbers were made"), and the paired differences
at the paper's budget with a 95 % interval over the cases resampled (analysis.paired.paired).
--extra reads eval.json files of policies outside the paper (bench/own_agent.py's) as cells at the default budget, of
their file's scenario and seed: each row is listed after Table 3's rows and the ablations as "LABEL (outside the
paper)", with "-" in the paper's columns. Those tables are the user's, not the committed results: they go to stdout and
to --out FILE if given, never to results/table3.md, and --readme does not go with --extra.
"""
import argparse
import contextlib
import fcntl
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import experiment  # noqa: E402
import tarl  # noqa: E402
from analysis import paired  # noqa: E402
SCENARIOS = ("intersection", "roundabout")
ROWS = ("tarl", "sac", "lattice-idm", "sac-lattice", "sac-lag", "sac-pid", "ppo-lag", "cpo")
# TARL's cell is the default command: it evaluates Lattice-IDM (and TARL's step-1 model) on the same
# cases, so Lattice-IDM has no cell of its own
RUN = tuple(algo for algo in ROWS if algo != "lattice-idm")
# Beyond Table 3 (RESULTS.md, "What the timing adds", "Beyond the paper"): TARL's ablations without a timing taker,
# two variants whose T means the same in both loops, one whose timing taker updates more, and three that give it the
# signal it lacks (beyond/variants.py) (PAPER.md, 6; not in the README's headline)
ABLATIONS = ("tarl-fixed-t", "tarl-random-t", "tarl-consistent", "tarl-held", "tarl-utd", "tarl-actor-target",
             "tarl-rare-replay", "tarl-min-target", "tarl-branch")
NAMES = {algo: row.label for algo, row in experiment.ROWS.items()} | {"tarl-step1": "TARL step 1"}


def row_name(algo: str, rows: dict | None = None) -> str:
    """A row's name in the tables: NAMES', or for any other row (an outside policy's, --extra) its eval.json label
    (of its first seed in `rows`, {seed: row}) or algo, marked "(outside the paper)"."""
    label = next(iter((rows or {}).values()), {}).get("label") or algo
    return NAMES.get(algo) or f"{label} (outside the paper)"


# Table 3 of the paper: success rate and crossing time [s], mean +- std over 10 rounds of 200 cases
PAPER = {"intersection": {"cpo": (0.769, 0.038, 11.901, 0.335), "ppo-lag": (0.739, 0.039, 10.303, 0.515),
                          "sac-lag": (0.828, 0.026, 9.230, 0.134), "sac-pid": (0.810, 0.028, 9.208, 0.133),
                          "tarl": (0.881, 0.021, 8.473, 0.145), "sac-lattice": (0.808, 0.032, 8.509, 0.182),
                          "lattice-idm": (0.896, 0.018, 11.349, 0.280)},
         "roundabout": {"cpo": (0.838, 0.029, 15.437, 0.238), "ppo-lag": (0.797, 0.016, 15.366, 0.181),
                        "sac-lag": (0.872, 0.040, 19.185, 0.334), "sac-pid": (0.907, 0.016, 19.324, 0.109),
                        "tarl": (0.912, 0.025, 16.066, 0.095), "sac-lattice": (0.868, 0.037, 16.371, 0.481),
                        "lattice-idm": (0.797, 0.030, 27.293, 0.291)}}


STEPS = tarl.TrainConfig.steps  # the default budget of every learned row
DEFAULT = (STEPS, None)  # a budget: (training steps, steps of Alg. 1's step 1 or None for TrainConfig.sac_fraction's)


def cell_name(scenario, algo, seed, steps, step_one=None) -> str:
    """S-A-sK; another budget than the default is in the name: S-A-sK-500k (the paper's, Table 2), and a step 1 of
    another length after it: S-A-sK-67k-step1-40k (the ablations with TARL's real-loop budget, docs/RESULTS.md)."""
    return (f"{scenario}-{algo}-s{seed}" + (f"-{steps // 1000}k" if (steps, step_one) != DEFAULT else "")
            + (f"-step1-{step_one // 1000}k" if step_one is not None else ""))


def budget_text(budget) -> str:
    steps, step_one = budget
    return f"{steps:,}" + (f" (step 1: {step_one:,})" if step_one is not None else "")


def by_budget(found: dict) -> list:
    """The budgets of `found` in order: steps, then step 1."""
    return sorted(found, key=lambda b: (b[0], b[1] or 0))


def cells(algos, seeds, scenarios=SCENARIOS):
    """The grid, seed by seed, so that a first complete table comes early."""
    return [(scenario, algo, seed) for seed in seeds for algo in algos for scenario in scenarios]


def command(scenario, algo, seed, args, threads) -> list[str]:
    """The cell's command, run from the repository's root (paths relative to it where they can be)."""
    out = args.work / cell_name(scenario, algo, seed, args.steps, args.step_one)
    shown = out.relative_to(ROOT) if out.is_relative_to(ROOT) else out
    cmd = ["python", "tarl.py", "--scenario", scenario, "--algo", algo, "--seed", str(seed), "--steps", str(args.steps),
           "--eval-rounds", str(args.rounds), "--eval-cases", str(args.cases), "--out", str(shown),
           "--eval-rows", "all" if algo == "tarl" else "trained", "--threads", str(threads), "--workers", str(threads)]
    cmd += ["--step-one", str(args.step_one)] if args.step_one is not None else []
    return cmd + ["--resume"] * (out / "ckpt.pt").exists()


def publish(scenario, algo, seed, args):
    """Copy a finished cell's small files to results/runs and commit them (--commit)."""
    name = cell_name(scenario, algo, seed, args.steps, args.step_one)
    src, dst = args.work / name, args.results / "runs" / name
    dst.mkdir(parents=True, exist_ok=True)
    # log.txt: the progress lines and the grid's stamps (when each stretch ran, and beside what: wall_times)
    for file in ("train_log.csv", "constraint_log.csv", "policy.pt", "log.txt"):  # ~1 MB each policy: every seed's
        if (src / file).exists():
            shutil.copy(src / file, dst / file)
    shutil.copy(src / "eval.json", dst / "eval.json")  # last: its presence marks the cell done
    collect(args)
    if args.commit:
        commit([dst, args.results / "table3.md"], f"Table 3 grid: {algo} on the {scenario}, seed {seed}"
               + (f", {budget_text((args.steps, args.step_one))} steps" if (args.steps, args.step_one) != DEFAULT else ""))


def commit(files: list[Path], message: str):
    """git add and commit just these files; retried, since another grid's git command may hold the index."""
    for attempt in range(5):
        if subprocess.run(["git", "-C", str(ROOT), "add", *map(str, files)]).returncode == 0 and subprocess.run(
                ["git", "-C", str(ROOT), "commit", "-q", "-m", message, "--", *map(str, files)]).returncode == 0:
            return
        time.sleep(5)


def evaluate_policy(policy: Path, scenario: str, algo: str, seed: int, out: Path, log: Path | None, *flags: str,
                    workers: int = 1) -> Path | None:
    """A committed policy evaluated, not trained (`tarl.py --load POLICY`, one thread a process), on seed SEED's test
    cases, with tarl.py's FLAGS; resumable (OUT/eval-rounds keeps finished rounds). Its output goes to LOG (None: the
    terminal). Returns OUT/eval.json, or None once it has printed where to look: the one way the bench scripts
    (retime, heldout, reevaluate, distillation) run a shipped policy again."""
    cmd = [sys.executable, "tarl.py", "--scenario", scenario, "--algo", algo, "--seed", str(seed), "--load",
           str(policy), *flags, "--threads", "1", "--workers", str(workers), "--out", str(out)]
    print(f"{out.name}: {' '.join(cmd[1:])}", flush=True)
    if log is not None:
        log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") if log is not None else contextlib.nullcontext() as f:  # f None: the terminal's
        code = subprocess.run(cmd, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT if log is not None else None).returncode
    if code != 0:
        print(f"FAILED {out.name}: see {log or 'the output above'}; the same command resumes it", flush=True)
        return None
    return out / "eval.json"


def claim(cell, args):
    """The cell's run directory, locked for this process (the lock goes when it ends), or None if the cell is done
    or another grid process runs it: several grids on one machine or a shared disk share the cells out."""
    name = cell_name(*cell, args.steps, args.step_one)
    out = args.work / name
    out.mkdir(parents=True, exist_ok=True)
    lock = open(out / "lock", "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return lock.close()
    if (args.results / "runs" / name / "eval.json").exists():
        return lock.close()
    return out, lock


def stamp(log, text: str):
    """A line of the grid's own in a cell's log.txt: when a stretch of the cell ran and beside what (wall_times)."""
    log.write(f"# grid {datetime.now(timezone.utc):%Y-%m-%d %H:%M:%S} UTC: {text}, load {os.getloadavg()[0]:.1f}\n")
    log.flush()


def run_grid(todo, args):
    """Run the cells, `--jobs` at a time; each one's output goes to its own log.txt. A kill (SIGTERM) ends the cells
    as Ctrl-C does: each saves its checkpoint and the same command resumes them."""
    running = {}

    def ended(cell, code, how):
        proc, log, t0, lock, beside = running.pop(cell)
        minutes = (time.time() - t0) / 60
        stamp(log, f"{how} after {minutes:.1f} min, exit code {code}, beside: {' + '.join(beside) or 'no other cell'}")
        log.close()
        print(f"{how} {' '.join(map(str, cell))} in {minutes:.1f} min", flush=True)
        if code == 0:
            publish(*cell, args)
        lock.close()

    def terminated(signum, frame):
        for proc, *_ in running.values():
            proc.terminate()  # the cell's own handler saves; Ctrl-C reaches the cells from the terminal itself
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, terminated)
    try:
        while todo or running:
            while todo and len(running) < args.jobs:
                cell = todo.pop(0)
                claimed = claim(cell, args)
                if claimed is None:
                    print(f"skipped {' '.join(map(str, cell))}: done or run by another grid", flush=True)
                    continue
                out, lock = claimed
                log, name = open(out / "log.txt", "a"), cell_name(*cell, args.steps, args.step_one)
                beside = [cell_name(*c, args.steps, args.step_one) for c in running]
                stamp(log, f"start, {args.threads} thread(s), beside: {' + '.join(beside) or 'no other cell'}")
                for *_, others in running.values():  # every cell that runs during a stretch is named at its end
                    others.append(name)
                running[cell] = (subprocess.Popen([sys.executable, *command(*cell, args, args.threads)[1:]], stdout=log,
                                                  stderr=subprocess.STDOUT, cwd=ROOT), log, time.time(), lock, beside)
                print(f"started {' '.join(map(str, cell))} ({len(todo)} waiting)", flush=True)
            time.sleep(5)
            for cell, (proc, *_) in list(running.items()):
                if proc.poll() is not None:
                    ended(cell, proc.returncode, "finished" if proc.returncode == 0 else "FAILED")
    except KeyboardInterrupt:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second kill must not cut the cells' saves short
        for cell, (proc, *_) in list(running.items()):
            try:
                proc.wait(timeout=SAVE_WAIT)
            except subprocess.TimeoutExpired:  # never wait forever on a cell that does not end
                proc.kill()
            ended(cell, proc.wait(), "interrupted")
        raise SystemExit("interrupted: the cells saved their checkpoints; the same command resumes them") from None


SAVE_WAIT = 300  # [s] a cell's time to save its checkpoint (its replay buffer) when interrupted


def wall_times(results: Path) -> list[str]:
    """Each cell's wall time (training and evaluation) from the grid's stamps in its log.txt, stretch by stretch:
    a cell that spans sessions resumes from its checkpoint, and the stretches add up. A stretch's end stamp names
    every cell that ran beside it; its start stamp, those at its start (all that older stamps have)."""
    lines = ["| cell | wall time [h] | stretches | each stretch: threads, beside (load at its start) |", "|---|---|---|---|"]
    for path in sorted((results / "runs").glob("*/log.txt")):
        stamps = re.findall(r"^# grid [^:]+:\d\d:\d\d UTC: (.*)$", path.read_text(), re.M)
        minutes = [float(m) for text in stamps for m in re.findall(r"after ([\d.]+) min", text)]
        stretches = []
        for text in stamps:
            if text.startswith("start, "):
                stretches.append(text.removeprefix("start, "))
            elif stretches and (ran := re.search(r", beside: (.*), load", text)):  # the end names all beside it
                stretches[-1] = re.sub(r"beside: .*, load", f"beside: {ran[1]}, load", stretches[-1])
        if minutes:
            lines.append(f"| {path.parent.name} | {sum(minutes) / 60:.2f} | {len(minutes)} | {'; '.join(stretches)} |")
    return lines


def load(results: Path, extra=()) -> dict:
    """budget -> (scenario, algo) -> {seed: the row of eval.json}; the budget, (steps, step 1), is the cell's
    (its name). `extra`: eval.json files of outside policies (--extra), cells at the default budget whose rows must
    not be Table 3's or an ablation's (NAMES) nor repeat another's row of the same scenario and seed."""
    found = {}
    for path in sorted((results / "runs").glob("*/eval.json")):
        data, suffix = json.loads(path.read_text()), re.search(r"-(\d+)k(?:-step1-(\d+)k)?$", path.parent.name)
        budget = (int(suffix[1]) * 1000, suffix[2] and int(suffix[2]) * 1000) if suffix else DEFAULT
        for row in data["rows"]:
            found.setdefault(budget, {}).setdefault((data["scenario"], row["algo"]), {})[data["seed"]] = row
    for path in map(Path, extra):
        try:
            data = json.loads(path.read_text())
            rows, scenario, seed = data["rows"], data["scenario"], data["seed"]
        except OSError as e:
            raise SystemExit(f"--extra {path}: {e.strerror}") from None
        except (ValueError, KeyError, TypeError):
            raise SystemExit(f"--extra {path}: not an eval.json (its rows, scenario and seed)") from None
        for row in rows:
            seeds = found.setdefault(DEFAULT, {}).setdefault((scenario, row["algo"]), {})
            if row["algo"] in NAMES or seed in seeds:
                raise SystemExit(f"--extra {path}: its row {row['algo']!r} of seed {seed} on the {scenario} is "
                                 + ("one of Table 3's or the ablations'" if row["algo"] in NAMES else "already read")
                                 + "; an outside row needs its own name")
            seeds[seed] = row
    return found


def listed(cells: dict, scenario: str) -> list[str]:
    """The rows of one budget's `cells` that the tables list, in order: Table 3's, the ablations, then any other
    (an outside policy's, --extra) in the order read."""
    return [*TABLE_ROWS, *ABLATIONS, *(algo for s, algo in cells if s == scenario and algo not in (*TABLE_ROWS,
                                                                                                  *ABLATIONS))]


def over_seeds(rows: dict, key: str):
    """(mean over seeds of the seed means, their std, mean of the per-round std, seeds with a value)."""
    means = [r[key]["mean"] for r in rows.values() if r[key]["mean"] is not None]
    stds = [r[key]["std"] for r in rows.values() if r[key]["mean"] is not None]
    return (float(np.mean(means)), float(np.std(means)), float(np.mean(stds)), len(means)) if means else None


def cell_text(stats, digits):
    """mean +- std over seeds (mean per-round std); one seed has no spread over seeds: mean (its per-round std)."""
    if stats is None:
        return "-"
    mean, seed_std, round_std, n = stats
    return f"{mean:.{digits}f}" + f" +- {seed_std:.{digits}f}" * (n > 1) + f" ({round_std:.{digits}f})"


def n_text(rows: dict) -> str:
    """The seeds behind a row, written beside it: "n = 3"."""
    return f"n = {len(rows)}"


def same_cases(found: dict) -> list[str]:
    """Per budget, scenario and seed: did every row meet the same test cases? A case's start fingerprint
    (eval.json) against the one most rows had for it, among the rows with the number of cases most rows had (the
    first read on a tie); a row with another number is named as not compared."""
    starts = {}
    for budget, cells in found.items():
        for (scenario, algo), seeds in cells.items():
            for seed, row in seeds.items():
                starts.setdefault((budget, scenario, seed), {})[algo] = ([case["start"] for case in row["cases"]],
                                                                         row_name(algo, {seed: row}))
    lines = []
    for (budget, scenario, seed), rows in sorted(starts.items()):
        size = Counter(len(s) for s, _ in rows.values()).most_common(1)[0][0]
        other = ", ".join(f"{label} ({len(s)} cases)" for s, label in rows.values() if len(s) != size)
        rows = {algo: (s, label) for algo, (s, label) in rows.items() if len(s) == size}
        common = [Counter(case).most_common(1)[0][0] for case in zip(*(s for s, _ in rows.values()))]
        odd = ", ".join(f"{label} {n}" for s, label in rows.values() if (n := sum(a != b for a, b in zip(s, common))))
        lines.append(f"- {scenario}, seed {seed}" + (f", {budget_text(budget)} steps" if budget != DEFAULT else "") +
                     f": {len(rows)} rows, {len(common)} cases; " + (f"cases that began differently: {odd}" if odd
                                                                      else "every row met the same cases")
                     + (f"; not compared, another number of cases: {other}" if other else ""))
    return lines


def outcome_pairs(a: dict, b: dict) -> Counter:
    """(a's outcome, b's outcome) counted over the test cases both rows of eval.json played."""
    mine = {(c["round"], c["case"]): c["outcome"] for c in a["cases"]}
    return Counter((mine[c["round"], c["case"]], c["outcome"]) for c in b["cases"] if (c["round"], c["case"]) in mine)


def case_by_case(found: dict, against=(*ABLATIONS, "sac", "lattice-idm")) -> list[str]:
    """TARL against each of `against` on the same test cases: where exactly one of the two arrives, how the other
    failed (the README's "What the timing adds"). TARL at the same budget, or at the default one if it has no cell
    at that budget (a seed's test cases do not depend on the budget)."""
    lines = ["| budget | scenario | seed | TARL against | only TARL arrives: the other collides / times out | "
             "only the other arrives: TARL collides / times out |", "|---|---|---|---|---|---|"]
    for budget, scenario, algo in [(b, s, a) for b in by_budget(found) for s in SCENARIOS for a in against]:
        for seed, row in sorted(found[budget].get((scenario, algo), {}).items()):
            tarl_row = (found[budget].get((scenario, "tarl")) or found.get(DEFAULT, {}).get((scenario, "tarl"), {})).get(seed)
            if tarl_row is None:
                continue
            pairs = outcome_pairs(tarl_row, row)
            lines.append(f"| {budget_text(budget)} | {scenario} | {seed} | {NAMES[algo]} | {pairs['arrival', 'collision']} / "
                         f"{pairs['arrival', 'timeout']} | {pairs['collision', 'arrival']} / {pairs['timeout', 'arrival']} |")
    return lines


TABLE_ROWS = ("tarl", "tarl-step1", *ROWS[1:])  # TARL's step-1 model: from TARL's cell
# The blocks that --readme writes, by NAME, wherever a `<!-- table3.py NAME -->` marker stands in README.md or
# docs/RESULTS.md: (rows, kind). "side": both scenarios side by side with each row's seeds (RESULTS.md, "Beyond the
# paper"); "paper": the same with Table 3's values beside ours, the best of Table 3's rows in bold and the ablations in
# italics (README.md's headline, docs/RESULTS.md's Table 3); "budget": the paper's budget on one
# seed with TARL's paired differences; "claims": the paper's claims with their verdicts (RESULTS.md's top).
README_ROWS = {"headline": ((*TABLE_ROWS, *ABLATIONS[:2]), "paper"), "results": (TABLE_ROWS, "paper"),
               "timing": (("tarl", *ABLATIONS), "side"),
               "budget": ((*TABLE_ROWS, *ABLATIONS[:2]), "budget"), "claims": ((), "claims")}
PAPER_BUDGET = (500_000, None)  # the paper's training steps (Table 2), as (steps, step 1)
RATES = ("success_rate", "collision_rate", "timeout_rate")  # of each row of eval.json, in the tables' column order


def each_seed(found: dict) -> list[str]:
    """Per budget and scenario, every row's success (collisions / timeouts) and crossing time seed by seed: the
    numbers behind each mean +- std over seeds, which the README's words quote."""
    lines = []
    for budget in by_budget(found):
        seeds = sorted({seed for rows in found[budget].values() for seed in rows})
        lines += ["| budget | scenario | model | " + " | ".join(f"seed {s}" for s in seeds) + " |",
                  "|---|---|---|" + "---|" * len(seeds)]
        for scenario, algo in [(s, a) for s in SCENARIOS for a in listed(found[budget], s)]:
            rows = found[budget].get((scenario, algo), {})
            if rows:
                lines.append(f"| {budget_text(budget)} | {scenario} | {row_name(algo, rows)} | " + " | ".join(
                    "-" if s not in rows else "{:.3f} ({:.3f} / {:.3f}), {:.1f} s".format(
                        *(rows[s][k]["mean"] for k in RATES),
                        rows[s]["crossing_time"]["mean"] or float("nan")) for s in seeds) + " |")
        lines.append("")
    return lines


def budget_block(found: dict, algos, seed: int = 0, budget=PAPER_BUDGET) -> list[str]:
    """docs/RESULTS.md's Table 3 at the paper's budget, one seed (n = 1): each row's success with its per-round std,
    collisions / timeouts and crossing time after `budget` steps, beside the same seed's success at the default budget
    and Table 3's; "not run" where a row has no cell at that budget yet. Paired against TARL at that budget on the same
    cases (analysis.paired.paired, seeded 0): TARL's success minus the row's with its 95 % interval and the cases only
    TARL arrives in / only the row does. One seed: two trained policies on the same cases, no verdict on the methods."""
    lines = [f"| scenario | model | seeds | success, {budget[0]:,} steps (per-round std) | collisions / timeouts | "
             f"crossing [s] | success, {STEPS:,} steps | paper | TARL - row, 95 % interval (cases resampled) | "
             "only TARL / only it arrives (two policies, the same cases) |", "|---" * 10 + "|"]
    for scenario, algo in [(s, a) for s in SCENARIOS for a in algos]:
        long, short = (found.get(b, {}).get((scenario, algo), {}).get(seed) for b in (budget, DEFAULT))
        ref, tarl_row = PAPER[scenario].get(algo), found.get(budget, {}).get((scenario, "tarl"), {}).get(seed)
        if not (long or short):
            continue
        r = paired.paired(tarl_row, long, np.random.default_rng(0)) if long and tarl_row and algo != "tarl" else None
        rates = ("not run", "-", "-") if long is None else (
            f"{long['success_rate']['mean']:.3f} ({long['success_rate']['std']:.3f})",
            f"{long['collision_rate']['mean']:.3f} / {long['timeout_rate']['mean']:.3f}",
            "-" if long["crossing_time"]["mean"] is None else f"{long['crossing_time']['mean']:.1f}")
        lines.append(f"| {scenario} | {NAMES[algo]} | n = 1 | {' | '.join(rates)} | "
                     f"{'-' if short is None else format(short['success_rate']['mean'], '.3f')} | "
                     f"{f'{ref[0]:.3f}' if ref else '-'} | "
                     + ("- | - |" if r is None else f"{r['diff']:+.3f} [{r['low']:+.3f}, {r['high']:+.3f}] | "
                                                    f"{r['only_mine']} / {r['only_other']} |"))
    return lines


# The paper's claims that the claims table tests: (scenario, A, B, measure), "A does better than B" in the measure
# (success: higher; crossing time: lower). Which way the paper orders each pair is read from PAPER; for TARL against
# its ablations, which the paper does not run, it is the paper's thesis that learning when to act helps.
CLAIMS = tuple((scenario, "tarl", other, "success_rate") for scenario in SCENARIOS for other in
               ("lattice-idm", "sac-lattice", "sac-lag", "sac-pid", "ppo-lag", "cpo", *ABLATIONS[:2])) + tuple(
    (scenario, "tarl", "lattice-idm", "crossing_time") for scenario in SCENARIOS)
ALPHA = 0.05  # two-sided: a claim holds or fails where the 95 % CI of its difference excludes 0
POWER = 0.8  # an undecided claim's seeds to settle it: those at which Welch's test finds its difference this often
MARGIN = {"success_rate": 0.03}  # equivalence: the 90 % CI inside +-MARGIN (two one-sided tests at ALPHA each)
MOST_SEEDS = 10_000  # seeds_to_settle looks no further


def welch(a, b) -> dict:
    """Welch's test of mean(a) - mean(b), a and b the seed means of two rows (scipy.stats.ttest_ind, equal_var=False):
    the difference d and its 95 % and 90 % confidence intervals."""
    test = stats.ttest_ind(a, b, equal_var=False)
    return dict(d=float(np.mean(a) - np.mean(b)), ci=tuple(map(float, test.confidence_interval(1 - ALPHA))),
                ci90=tuple(map(float, test.confidence_interval(1 - 2 * ALPHA))))


def verdict(test: dict, margin: float | None) -> str:
    """A claim's verdict from `welch` (+ in the claim's order): "holds" or "fails" where the 95 % CI excludes 0;
    "equivalent within ±margin" where the 90 % CI lies inside ±margin (two one-sided tests; a measure without a
    margin, crossing time, is never equivalent); otherwise "undecided"."""
    (low, high), (low90, high90) = test["ci"], test["ci90"]
    if low > 0 or high < 0:
        return "holds" if low > 0 else "fails"
    return f"equivalent within ±{margin}" if margin and -margin < low90 and high90 < margin else "undecided"


def seeds_to_settle(d: float, s_a: float, s_b: float) -> int | None:
    """The fewest seeds per row at which Welch's two-sided test at ALPHA finds a true difference d with POWER, the two
    rows' stds over seeds (ddof = 1) being s_a and s_b: its power from the noncentral t (scipy.stats.nct) at the
    Welch-Satterthwaite degrees of freedom. None beyond MOST_SEEDS."""
    n = np.arange(2, MOST_SEEDS + 1)
    var = s_a ** 2 + s_b ** 2
    df, ncp = var ** 2 * (n - 1) / (s_a ** 4 + s_b ** 4), abs(d) / np.sqrt(var / n)
    t = stats.t.ppf(1 - ALPHA / 2, df)
    enough = n[stats.nct.sf(t, df, ncp) + stats.nct.cdf(-t, df, ncp) >= POWER]
    return int(enough[0]) if len(enough) else None


def improvement(a, b, rng: np.random.Generator, resamples: int = paired.BOOTSTRAP) -> tuple[float, float, float]:
    """P(A > B), the probability of improvement as rliable reports it (Agarwal et al., NeurIPS 2021): the chance that
    a run (seed) of A beats a run of B, ties counting 1/2 (Mann-Whitney's U / (n_a n_b)), with its 95 % percentile
    interval from the stratified bootstrap: each row's runs resampled on their own within each task (here one: a
    claim is one scenario). a, b: the seeds' values, + better."""
    a, b = np.asarray(a), np.asarray(b)
    prob = lambda x, y: (np.sign(x[..., :, None] - y[..., None, :]) + 1).mean(axis=(-2, -1)) / 2  # noqa: E731
    boot = prob(a[rng.integers(len(a), size=(resamples, len(a)))], b[rng.integers(len(b), size=(resamples, len(b)))])
    return float(prob(a, b)), *map(float, np.percentile(boot, [2.5, 97.5]))


def seed_test(a: dict, b: dict, margin: float | None, rng: np.random.Generator) -> dict:
    """A against B over seeds, the test of a claim (claim_rows) and of an outside policy against a row
    (bench/own_agent.py), a and b the seeds' values {seed: value, + better}: n (seeds of each) and means; `welch`'s d
    with its 95 % and 90 % CIs; the `verdict`; if undecided, the seeds per row that would settle it
    (`seeds_to_settle`, at the observed spread, None beyond MOST_SEEDS); A's wins over the seeds both have, paired by
    seed (a seed's rows met the same cases), with the exact sign-flip p of their differences
    (analysis.paired.sign_flip); `improvement`: P(A > B) with its 95 % interval. Each row's seeds are taken in seed
    order, whatever order the files were read in: a mean that ends in 5 prints as the order sums it."""
    x, y = (np.array([seeds[k] for k in sorted(seeds)]) for seeds in (a, b))
    both = np.array([a[k] - b[k] for k in sorted(a.keys() & b.keys())])
    test = welch(x, y)
    said = verdict(test, margin)
    return {"n": (len(x), len(y)), "means": (x.mean(), y.mean()), **test, "verdict": said,
            "settle": seeds_to_settle(test["d"], x.std(ddof=1), y.std(ddof=1)) if said == "undecided" else None,
            "wins": (int((both > 0).sum()), len(both)), "sign_flip": paired.sign_flip(both),
            "improvement": improvement(x, y, rng)}


def claim_rows(found: dict, seed: int = 0, budget=PAPER_BUDGET) -> list[dict]:
    """Each claim of CLAIMS with its tests at the default budget, over whatever seeds each row has (`seed_test` of
    both rows' seed values, + better; the means as measured). At `budget`, seed `seed` alone and no verdict: both
    values, their difference and the cases only A / only B arrives in (analysis.paired.paired). Differences are
    signed so that + is the paper's order."""
    out, rng = [], np.random.default_rng(0)
    for scenario, a, b, key in CLAIMS:
        ref = PAPER[scenario]
        better, column = (1, 0) if key == "success_rate" else (-1, 2)  # a shorter crossing is better
        if b in ref:  # the paper's order: whichever of the two it has ahead
            a, b = (a, b) if better * (ref[a][column] - ref[b][column]) >= 0 else (b, a)
        seeds = [{k: better * r[key]["mean"] for k, r in found[DEFAULT][(scenario, algo)].items()} for algo in (a, b)]
        test = seed_test(*seeds, MARGIN.get(key), rng)
        long = [found[budget][(scenario, algo)][seed] for algo in (a, b)]
        out.append({"scenario": scenario, "a": a, "b": b, "key": key,
                    "paper": (ref[a][column], ref[b][column]) if b in ref else None, **test,
                    "means": tuple(better * m for m in test["means"]), "cases": paired.paired(*long, rng),
                    "long": better * (long[0][key]["mean"] - long[1][key]["mean"])})
    return out


def claims_block(found: dict) -> list[str]:
    """docs/RESULTS.md's table of the paper's claims, one per line (`claim_rows`): the paper's two values; at the default
    budget both rows' means with their seeds (n), the difference with its 95 % CI, the verdict, the seeds per row
    that would settle an undecided claim, A's wins per seed, the sign-flip p and P(A > B); at the paper's budget,
    seed 0's difference and the cases only A / only B arrives in, with no verdict."""
    lines = ["| claim | the paper | 10^5 steps: A vs B (seeds) | A - B [95 % CI] (Welch) | verdict | seeds per row to "
             "settle | A ahead, seed by seed | sign-flip p over seeds | P(A > B) [95 % CI] | 5 x 10^5, seed 0: A - B; "
             "only A / only B arrives |", "|---|---|---|---|---|---|---|---|---|---|"]
    for c in claim_rows(found):
        word, digits = ("succeeds more often than", 3) if c["key"] == "success_rate" else ("crosses sooner than", 1)
        paper = "no such row (its thesis)" if c["paper"] is None else " vs ".join(f"{v:.{digits}f}" for v in c["paper"])
        means = " vs ".join(f"{m:.{digits}f} (n = {n})" for m, n in zip(c["means"], c["n"]))
        settle = "-" if c["verdict"] != "undecided" else f"> {MOST_SEEDS:,}" if c["settle"] is None else c["settle"]
        chance = "{:.2f} [{:.2f}, {:.2f}]".format(*c["improvement"])
        interval = f"{c['d']:+.{digits}f} [{c['ci'][0]:+.{digits}f}, {c['ci'][1]:+.{digits}f}]"
        lines.append(f"| {c['scenario']}: {NAMES[c['a']]} {word} {NAMES[c['b']]} | {paper} | {means} | {interval} | "
                     f"**{c['verdict']}** | {settle} | {c['wins'][0]} / {c['wins'][1]} | {c['sign_flip']:.2g} | {chance} | "
                     f"{c['long']:+.{digits}f}; {c['cases']['only_mine']} / {c['cases']['only_other']} |")
    return lines


def side_block(found: dict, algos, paper: bool = False) -> list[str]:
    """One table of both scenarios side by side at the default budget: per row its seeds (n) and per scenario its
    success (mean +- std over seeds, in brackets the mean per-round std; n = 1: the mean and its per-round std),
    collisions / timeouts and crossing time (means over seeds); with `paper`, Table 3's success (its +-) and crossing
    time beside each, the best success of Table 3's rows in each scenario in bold and the ablations in italics."""
    table = {algo: {s: found.get(DEFAULT, {}).get((s, algo)) for s in SCENARIOS} for algo in algos}
    best = {s: max((over_seeds(t[s], "success_rate")[0] for algo, t in table.items()
                    if t[s] and algo in TABLE_ROWS), default=None) for s in SCENARIOS}
    lines = ["| model | seeds | " + " | ".join(f"{s}: success | collisions / timeouts | crossing [s]"
                                                + " | paper" * paper for s in SCENARIOS) + " |",
             "|---|---|" + ("---|---|---|" + "---|" * paper) * len(SCENARIOS)]
    for algo, rows in table.items():
        if not any(rows.values()):
            continue
        seeds = " / ".join(dict.fromkeys(n_text(r) for r in rows.values() if r))  # each scenario's, in column order
        cells = []
        for scenario in SCENARIOS:
            ref = PAPER[scenario].get(algo)
            if not rows[scenario]:
                cells += ["-"] * (3 + paper)
                continue
            stats = {k: over_seeds(rows[scenario], k) for k in (*RATES, "crossing_time")}
            bold = "**" * (paper and algo in TABLE_ROWS and stats["success_rate"][0] == best[scenario])
            cells += [f"{bold}{cell_text(stats['success_rate'], 3)}{bold}",
                      " / ".join(f"{stats[k][0]:.3f}" for k in RATES[1:]),
                      "-" if stats["crossing_time"] is None else f"{stats['crossing_time'][0]:.1f}"]
            cells += [f"{ref[0]:.3f} ({ref[1]:.3f}), {ref[2]:.1f} s" if ref else "-"] * paper
        name = f"*{NAMES[algo]}*" if paper and algo in ABLATIONS else NAMES[algo]
        lines.append(f"| {name} | {seeds} | " + " | ".join(cells) + " |")
    return lines


def write_readme(found: dict, readme: Path):
    """Replace each block between `<!-- table3.py NAME -->` and `<!-- /table3.py -->` (NAME in README_ROWS) in
    `readme` and in docs/RESULTS.md beside it, if there is one: the headline tables live in README.md, the full ones
    and the evidence in docs/RESULTS.md."""
    begin, end = "<!-- table3.py {} -->", "<!-- /table3.py -->"
    for path in (readme, readme.parent / "docs" / "RESULTS.md"):
        if not path.exists():
            continue
        text = path.read_text()
        for name, (algos, kind) in README_ROWS.items():
            head, found_begin, rest = text.partition(begin.format(name))
            if not found_begin:
                continue
            block = (budget_block(found, algos) if kind == "budget" else claims_block(found) if kind == "claims"
                     else side_block(found, algos, kind == "paper"))
            text = head + begin.format(name) + "\n" + "\n".join(block) + "\n" + end + rest.partition(end)[2]
        path.write_text(text)


def collect(args, extra=(), out: Path | None = None) -> str:
    """Rebuild results/table3.md from the eval.json files under results/runs (or write `out` instead) and return its
    text. With `extra`, eval.json files of outside policies (--extra), their rows join the tables and the text goes to
    `out` alone, if given: never to results/table3.md, the committed results."""
    committed = args.results / "table3.md"
    if extra and out is not None and out.resolve() == committed.resolve():
        raise SystemExit(f"--out {out}: the committed results, which rows outside the paper (--extra) never enter")
    found = load(args.results, extra)
    lines = ["# Table 3, reproduced", "",
             f"Each cell: mean +- std over the n seeds (ddof = 0) of each seed's mean over {args.rounds} rounds x "
             f"{args.cases} test cases; in brackets the mean per-round std (the paper's +-). A row of one seed (n = 1) has "
             "no spread over seeds: its cell is the mean and, in brackets, its per-round std. Crossing: over a round's "
             "successes (the paper's measure); crossing, timeouts at 60 s, no collisions: over the cases that did not "
             "collide (collisions are left out), a timeout counted at the 60 s limit. Paper: Table 3 "
             f"(5 x 10^5 training steps). Built by `python bench/table3.py --collect-only` from results/runs/*/eval.json.", ""]
    lines += [f"Outside the paper (--extra, not committed results): {', '.join(map(str, extra))}.", ""] * bool(extra)
    for budget, scenario in [(DEFAULT, s) for s in SCENARIOS] + [(b, s) for b in by_budget(found) if b != DEFAULT
                                                                  for s in SCENARIOS]:
        if budget != DEFAULT and not any(key[0] == scenario for key in found[budget]):
            continue
        title = scenario if budget == DEFAULT else f"{scenario}, at {budget_text(budget)} training steps"
        lines += [f"## {title}", "", "| model | seeds | success | collision | timeout | crossing [s] | crossing, "
                  "timeouts at 60 s, no collisions [s] | paper success | paper crossing [s] |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for algo in listed(found.get(budget, {}), scenario):
            rows = found.get(budget, {}).get((scenario, algo))
            if not rows:
                continue
            paper = PAPER[scenario].get(algo)
            steps = {r["train_steps"] for r in rows.values()}
            lines.append(f"| {row_name(algo, rows)} ({'untrained' if steps == {0} else f'{min(steps):,} steps'}) | "
                         f"{n_text(rows)} | "
                         + " | ".join(cell_text(over_seeds(rows, k), 3) for k in RATES)
                         + " | " + " | ".join(cell_text(over_seeds(rows, k), 2) for k in ("crossing_time", "crossing_time_all"))
                         + (f" | {paper[0]:.3f} +- {paper[1]:.3f} | {paper[2]:.3f} +- {paper[3]:.3f} |" if paper else " | - | - |"))
        lines.append("")
    lines += ["## Each seed", "", "Success (collision / timeout) and crossing time of each seed, the mean over its rounds:",
              "", *each_seed(found),
              "## The same test cases for every row", "", "Each case's start fingerprint in eval.json, against the one "
              "most rows of that seed had for it:", "", *same_cases(found), "",
              "## Case by case: TARL against its ablations, plain SAC and its planner", "",
              "Of the same test cases, those where exactly one of the two arrives (the budget is the other row's; TARL's "
              "the same, or the default where TARL has no cell at that budget):", "", *case_by_case(found), "",
              "## Wall time of each cell", "", "From the grid's stamps in each cell's log.txt (cells run before the "
              "stamps have none): training and evaluation, summed over the stretches a cell ran in, and for each stretch "
              "the cells that ran beside it at any time (a stretch stamped before 2026-12-03 22:00 UTC names only those "
              "beside it when it started) and the load when it started.", "", *wall_times(args.results), ""]
    text = "\n".join(lines)
    if out is not None or not extra:
        (out or committed).write_text(text)
    if args.readme:
        write_readme(found, ROOT / "README.md")
    return text


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if "--slurm" in argv:  # the same cells as a Slurm array job: bench/slurm.py takes the rest
        import slurm
        return slurm.main([a for a in argv if a != "--slurm"])
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algos", nargs="+", default=list(RUN + ABLATIONS), choices=RUN + ABLATIONS)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    p.add_argument("--steps", type=int, default=STEPS, help="training steps of every learned row (another budget's "
                   "cells are S-A-sK-500k, reported apart)")
    p.add_argument("--step-one", type=int, help="steps of Alg. 1's step 1 in every cell (default: the share "
                   f"TrainConfig.sac_fraction = {tarl.TrainConfig.sac_fraction} of --steps); cells S-A-sK-67k-step1-40k")
    p.add_argument("--rounds", type=int, default=10)
    p.add_argument("--cases", type=int, default=200)
    p.add_argument("--jobs", type=int, default=2, help="cells side by side")
    p.add_argument("--threads", type=int, help="torch threads and evaluation workers of each cell (default: 2 // "
                   "jobs, at least 1; give 1 when another grid runs beside this one)")
    p.add_argument("--work", type=Path, default=ROOT / "runs" / "grid", help="the cells' run directories")
    p.add_argument("--results", type=Path, default=ROOT / "results")
    p.add_argument("--commit", action="store_true", help="git commit each finished cell's results")
    p.add_argument("--print-commands", action="store_true", help="print one command per unfinished cell (2 threads "
                   "each unless --threads) and exit")
    p.add_argument("--slurm", action="store_true", help="the unfinished cells as a Slurm array job: the rest of the "
                   "command line goes to bench/slurm.py (--submit, --write FILE, --collect, --cpus-per-task, --time, "
                   "--partition; its --help)")
    p.add_argument("--collect-only", action="store_true", help="only rebuild results/table3.md and print it")
    p.add_argument("--extra", type=Path, nargs="+", default=[], metavar="PATH", help="with --collect-only: eval.json "
                   "files of policies outside the paper (bench/own_agent.py's), each row listed after Table 3's rows "
                   "and the ablations as 'LABEL (outside the paper)'; the tables are then printed (and written to "
                   "--out FILE if given), never to results/table3.md")
    p.add_argument("--out", type=Path, metavar="FILE", help="with --collect-only: write the tables here instead "
                   "(default: results/table3.md, or no file with --extra)")
    p.add_argument("--readme", action="store_true", help="also rewrite the result tables of README.md (the headline) "
                   "and docs/RESULTS.md (the full ones), between their <!-- table3.py NAME --> markers")
    args = p.parse_args(argv)
    # the cells run with cwd=ROOT: a relative --work or --results means the caller's directory, not ROOT
    args.work, args.results = args.work.resolve(), args.results.resolve()
    if args.jobs < 1 or (args.threads is not None and args.threads < 1):
        p.error("--jobs and --threads must be at least 1")
    if args.step_one is not None and not 0 < args.step_one < args.steps:
        p.error("--step-one must be above 0 and below --steps")
    if args.step_one is not None and (plain := [a for a in args.algos if not experiment.ROWS[a].step_one]):
        p.error(f"--step-one: {', '.join(plain)} have no step 1")
    if (args.extra or args.out) and not args.collect_only:
        p.error("--extra and --out go with --collect-only")
    if args.extra and args.readme:
        p.error("--readme writes the committed results' tables, which rows outside the paper (--extra) never enter")
    if args.collect_only:
        return print(collect(args, args.extra, args.out))
    todo = [c for c in cells(args.algos, args.seeds, args.scenarios)
            if not (args.results / "runs" / cell_name(*c, args.steps, args.step_one) / "eval.json").exists()]
    if args.print_commands:
        return print("\n".join(" ".join(command(*c, args, args.threads or 2)) for c in todo))
    args.threads = args.threads or max(2 // args.jobs, 1)
    print(f"{len(todo)} cells to run, {args.jobs} at a time", flush=True)
    run_grid(todo, args)
    print((args.results / "table3.md").read_text())


if __name__ == "__main__":
    main()
