"""Table 3 of the paper as a grid: its rows and TARL's two ablations x both scenarios x seeds, resumable cell by cell.

    python bench/table3.py                    # run or resume the grid here, 2 cells side by side, 1 thread each
    python bench/table3.py --commit           # the same, and a git commit in this repository per finished cell
    python bench/table3.py --print-commands   # one command per unfinished cell, for a scheduler of your own
    python bench/table3.py --slurm --submit   # the unfinished cells as a Slurm array job (bench/slurm.py)
    python bench/table3.py --collect-only     # build results/table3.md from results/runs/; names unfinished cells
    python bench/table3.py --collect-only --readme   # and the tables in README.md and docs/RESULTS.md
    python bench/table3.py --collect-only --extra runs/roundabout-sb3-sac-s0/eval.json   # your own agent's rows too
    python bench/table3.py --algos sac --seeds 0 --steps 3000 --rounds 1 --cases 10   # a trial: runs/trial/

The grid (--algos): Table 3's learned rows (tarl, sac, sac-lattice, sac-lag, sac-pid, ppo-lag, cpo) and TARL's two
ablations (tarl-fixed-t, tarl-random-t); the other variants (beyond/variants.py) run only when named. Lattice-IDM has no
cell of its own: TARL's cell is the default command, which also evaluates Lattice-IDM and TARL's step-1 model on the
same cases, so `--algos lattice-idm` selects TARL's cell (and says so). A cell is one `python tarl.py --scenario S
--algo A --seed K` run in runs/grid/S-A-sK (its checkpoints) with one torch thread (--threads; the committed cells ran
one each, and every path to a cell has that default: here, --print-commands, --slurm's --cpus-per-task), evaluated on
the fixed test cases of seed K. When it finishes, its own files (eval.json, train_log.csv, constraint_log.csv of the
safe-RL rows, policy.pt, log.txt) go to results/runs/S-A-sK, and nothing else: the table, results/table3.md, is built
once, by --collect-only or when a grid run here ends (a Slurm task never builds it: the file is tracked, and rewriting
it while cells start would record their code as COMMIT-dirty). An interruption loses at most the cells in progress,
which resume from their checkpoints. A cell whose results/runs/S-A-sK/eval.json exists is done and skipped.
--commit (here only, never on Slurm) makes git commits in this repository: after each finished cell it rebuilds
results/table3.md and runs `git add` and `git commit` on that file and the cell's results/runs/S-A-sK, nothing else.
A trial, cells evaluated on other than Table 3's 10 rounds x 200 cases (--rounds, --cases), lands apart from the
committed results unless --work or --results say otherwise: its run directories in runs/trial/grid, its finished
cells and table in runs/trial (runs/CELL, table3.md), which git ignores; `rm -r runs/trial` removes it.
The table's header says what its rows were evaluated on, from their eval.json (rounds x cases), and which rows
differ if some do.
The table reports each number as the mean +- std over seeds of each seed's mean over its rounds,
beside the mean over seeds of the per-round std (Table 3's +-) and the paper's value, with the number of
seeds (n) beside every row; a row of one seed shows its mean and per-round std, no +- over seeds. With
--readme it also writes docs/RESULTS.md's tables of the paper's claims, one family a budget, each claim paired by seed
on its planned seeds with Holm's correction over the family (`claim_rows`: analysis.claims, whose docstring states the
rule), and the paired differences at the paper's budget with a 95 % interval over the cases resampled
(analysis.paired.paired).
--extra reads eval.json files of policies outside the paper (bench/own_agent.py's) as cells at the default budget, of
their file's scenario and seed: each row is listed after Table 3's rows and the ablations as "LABEL (outside the
paper)", with "-" in the paper's columns. Those tables are the user's, not the committed results: they go to stdout and
to --out FILE if given, never to results/table3.md, and --readme does not go with --extra.
"""
import argparse
import contextlib
import fcntl
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import experiment  # noqa: E402
import tarl  # noqa: E402
from analysis import claims, paired  # noqa: E402
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
GRID = (*RUN, *ABLATIONS[:2])  # the grid's default rows: Table 3's learned ones and TARL's two ablations
ROUNDS, CASES = 10, 200  # Table 3's test of a cell: 10 rounds of 200 cases; any other is a trial
TRIAL = ROOT / "runs" / "trial"  # a trial's results (runs/CELL, table3.md) and, in grid/, its run directories
THREADS = 1  # a cell's torch threads and evaluation workers on every path to it, as the committed cells ran
TIME_LIMIT = "2:00:00"  # a Slurm task's default --time: a 10^5-step cell at one thread, with margin


def cell_name(scenario, algo, seed, steps, step_one=None) -> str:
    """S-A-sK; another budget than the default is in the name: S-A-sK-500k (the paper's, Table 2), and a step 1 of
    another length after it: S-A-sK-67k-step1-40k (the ablations with TARL's real-loop budget, docs/RESULTS.md)."""
    budget = f"{steps // 1000}k" + (f"-step1-{step_one // 1000}k" if step_one is not None else "")
    return experiment.run_name(scenario, algo, seed, budget if (steps, step_one) != DEFAULT else "")


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
    cmd = ["python", "tarl.py", "--scenario", scenario, "--algo", algo, "--seed", str(seed), "--steps", str(args.steps),
           "--eval-rounds", str(args.rounds), "--eval-cases", str(args.cases), "--out", shown(out),
           "--eval-rows", "all" if algo == "tarl" else "trained", "--threads", str(threads), "--workers", str(threads)]
    cmd += ["--step-one", str(args.step_one)] if args.step_one is not None else []
    return cmd + ["--resume"] * (out / "ckpt.pt").exists()


def done(cell, args) -> bool:
    """Is the cell finished: its eval.json published in RESULTS/runs/CELL?"""
    return (args.results / "runs" / cell_name(*cell, args.steps, args.step_one) / "eval.json").exists()


def shown(path: Path) -> str:
    """A path as the commands print it: relative to the repository's root (their cwd) where it is inside."""
    return str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path)


def publish(scenario, algo, seed, args):
    """Copy a finished cell's small files to RESULTS/runs/CELL: its own files, nothing else (the table is built once,
    by --collect-only or at the end of a grid run here). With --commit (a grid run here, never a Slurm task) also
    rebuild RESULTS/table3.md and commit both."""
    name = cell_name(scenario, algo, seed, args.steps, args.step_one)
    src, dst = args.work / name, args.results / "runs" / name
    dst.mkdir(parents=True, exist_ok=True)
    # log.txt: the progress lines and the grid's stamps (when each stretch ran, and beside what: wall_times)
    for file in ("train_log.csv", "constraint_log.csv", "policy.pt", "log.txt"):  # ~1 MB each policy: every seed's
        if (src / file).exists():
            shutil.copy(src / file, dst / file)
    shutil.copy(src / "eval.json", dst / "eval.json")  # last: its presence marks the cell done
    if args.commit:
        collect(args)
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
    if done(cell, args):
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
    a cell that spans sessions resumes from its checkpoint (each stretch names the step it started from), and the
    stretches add up. A stretch's end stamp names every cell that ran beside it; its start stamp, those at its start
    (all that older stamps have). A stretch killed without an end stamp (a machine's stop: no signal, no save) is
    timed from its progress lines, the steps of each over its rate (~, training only), and its steps since its last
    checkpoint were trained again by the next stretch."""
    lines = ["| cell | wall time [h] | stretches | each stretch: threads, beside (load at its start) |", "|---|---|---|---|"]
    for path in sorted((results / "runs").glob("*/log.txt")):
        stretches, minutes, killed = [], [], False  # killed: a stretch timed from its progress lines
        for text in re.split(r"^(?=# grid [^:]+:\d\d:\d\d UTC: start, )", path.read_text(), flags=re.M):
            stamps = re.findall(r"^# grid [^:]+:\d\d:\d\d UTC: (.*)$", text, re.M)
            if not stamps:
                continue
            said = stamps[0].removeprefix("start, ") if stamps[0].startswith("start, ") else None
            if said and (ran := re.search(r", beside: (.*), load", stamps[-1])) and len(stamps) > 1:
                said = re.sub(r"beside: .*, load", f"beside: {ran[1]}, load", said)  # the end names all beside it
            start = re.search(r"^training .* from step (\d+) to", text, re.M)
            start = int(start[1]) if start else 0  # a resumed stretch: the step of its checkpoint
            said = said and said + f", from step {start:,}" * bool(start)
            if ended := [float(m) for stamp in stamps for m in re.findall(r"after ([\d.]+) min", stamp)]:
                minutes.append(sum(ended))
            elif said and (steps := re.findall(r"^step +(\d+)/(\d+) .*? (\d+) steps/s, (?:training )?ETA +([\d.]*)",
                                               text, re.M)):  # the rate from the ETA where it has one: 4 digits
                step = [start, *(int(k) for k, *_ in steps)]
                rates = [(int(n) - int(k)) / (60 * float(eta)) if eta and float(eta) else max(int(r), 1)
                         for k, n, r, eta in steps]
                minutes.append(sum((b - a) / r for a, b, r in zip(step, step[1:], rates)) / 60)
                said, killed = said + f", killed without a stamp at step {step[-1]:,} (~{minutes[-1]:.0f} min)", True
            if said:
                stretches.append(said)
        if minutes:
            lines.append(f"| {path.parent.name} | {'~' * killed}{sum(minutes) / 60:.2f} | {len(minutes)} | "
                         f"{'; '.join(stretches)} |")
    return lines


def load(results: Path, extra=()) -> dict:
    """budget -> (scenario, algo) -> {seed: the row of eval.json}; the budget, (steps, step 1), is the cell's
    (its name). `extra`: eval.json files of outside policies (--extra), cells at the default budget whose rows must
    not be Table 3's or an ablation's (NAMES) nor repeat another's row of the same scenario and seed."""
    found = {}
    for path in sorted((results / "runs").glob("*/eval.json")):
        data, suffix = experiment.read_eval(path), re.search(r"-(\d+)k(?:-step1-(\d+)k)?$", path.parent.name)
        budget = (int(suffix[1]) * 1000, suffix[2] and int(suffix[2]) * 1000) if suffix else DEFAULT
        for row in data["rows"]:
            found.setdefault(budget, {}).setdefault((data["scenario"], row["algo"]), {})[data["seed"]] = row
    for path in map(Path, extra):
        try:
            data = experiment.read_eval(path)
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
# paper"); "paper": the same with Table 3's values beside ours, no bold (no test picks a best row) and the ablations in
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


def claim_rows(found: dict, steps: int = STEPS) -> list[dict]:
    """The family of claims at `steps` training steps (analysis.claims.FAMILIES) tested as one
    (analysis.claims.family): each claim's rows' seed values at that budget, + better (a shorter crossing is
    better), with its planned seeds (analysis.claims.planned); the means and differences as measured, signed so
    that + is the claim's order. At a budget other than the default, also the cases only A / only B arrives in,
    summed over the claim's paired seeds (analysis.paired.paired, seeded 0)."""
    budget, rng = (DEFAULT if steps == STEPS else (steps, None)), np.random.default_rng(0)
    cells, out = found.get(budget, {}), []
    for scenario, a, b, key in claims.FAMILIES[steps]:
        better = 1 if key == "success_rate" else -1
        values = [{k: better * r[key]["mean"] for k, r in cells.get((scenario, algo), {}).items()
                   if r[key]["mean"] is not None} for algo in (a, b)]
        out.append(dict(a=values[0], b=values[1], planned=claims.planned(steps, scenario, a, b),
                        margin=claims.MARGIN.get(key), name=f"{scenario}: {NAMES[a]} against {NAMES[b]}, {key}, "
                                                             f"{budget_text(budget)} steps"))
    tested = claims.family(out, rng)
    rows = []
    for (scenario, a, b, key), pair, r in zip(claims.FAMILIES[steps], out, tested):
        better, column = (1, 0) if key == "success_rate" else (-1, 2)
        ref = PAPER[scenario]
        cases = None
        if budget != DEFAULT:
            long = [[cells[scenario, algo][k] for k in r["seeds"]] for algo in (a, b)]
            cases = paired.paired(*long, rng)
        rows.append({"scenario": scenario, "a": a, "b": b, "key": key, **r,
                     "paper": (ref[a][column], ref[b][column]) if a in ref and b in ref else None,
                     "paired_means": tuple(better * np.mean([pair[s][k] for k in r["seeds"]]) for s in "ab"),
                     "means": tuple(better * m for m in r["means"]), "cases": cases})
    return rows


def claim_text(c: dict) -> tuple[str, int, str]:
    """A claim's name in the table, its digits and its paper's two values."""
    word, digits = ("succeeds more often than", 3) if c["key"] == "success_rate" else ("crosses sooner than", 1)
    paper = "no such row (its thesis)" if c["paper"] is None else " vs ".join(f"{v:.{digits}f}" for v in c["paper"])
    return f"{c['scenario']}: {NAMES[c['a']]} {word} {NAMES[c['b']]}", digits, paper


def ci_text(d: float, ci, digits: int) -> str:
    return f"{d:+.{digits}f}" + ("" if ci is None else f" [{ci[0]:+.{digits}f}, {ci[1]:+.{digits}f}]")


def p_cell(p) -> str:
    return "-" if p is None or np.isnan(p) else paired.p_text(p)


def claims_block(found: dict) -> list[str]:
    """docs/RESULTS.md's tables of the paper's claims (`claim_rows`), each with its caption: at 10^5 steps every
    claim of analysis.claims.CLAIMS, one family; at the paper's 5 x 10^5 steps the thesis and TARL against its
    planner, another family, interim until every claim has its planned seeds. Per claim: the paper's two values;
    both rows' means over the paired seeds with n of the planned n; A - B with the paired t's 95 % CI; its p raw and
    Holm-adjusted over the family; the verdict (of record, or interim); the seeds to settle an undecided claim of
    record; at 10^5, A's wins seed by seed, the sign-flip p and, secondary, every seed of each row: Welch's A - B with
    its 95 % CI and P(A > B); at 5 x 10^5, A - B seed by seed and the cases only A / only B arrives in. Each claim
    has an id, C1.. at 10^5 and P1.. at 5 x 10^5 (CLAIMS' order), by which the findings name the rows they rest on."""
    short, long = claim_rows(found), claim_rows(found, PAPER_BUDGET[0])
    lines = [caption(short, STEPS), "",
             "| # | claim | the paper | paired seeds: A vs B (n of planned) | A - B [95 % CI] (paired t) | p | p, Holm | "
             "verdict | seeds to settle | A ahead, seed by seed | sign-flip p | secondary, every seed: A vs B (n), "
             "A - B [95 % CI] (Welch) | P(A > B) [95 % CI] |", "|---" * 13 + "|"]
    for i, c in enumerate(short, 1):
        name, digits, paper = claim_text(c)
        welch = "-" if c["welch"] is None else ci_text(c["welch"]["d"], c["welch"]["ci"], digits)
        every = " vs ".join(f"{m:.{digits}f} (n = {n})" for m, n in zip(c["means"], c["n_all"]))
        chance = "-" if c["improvement"] is None else "{:.2f} [{:.2f}, {:.2f}]".format(*c["improvement"])
        lines.append(f"| C{i} | {name} | {paper} | {c['paired_means'][0]:.{digits}f} vs "
                     f"{c['paired_means'][1]:.{digits}f} "
                     f"({c['n']} of {len(c['planned'])}) | {ci_text(c['d'], c['ci'], digits)} | {p_cell(c['p'])} | "
                     f"{p_cell(c['p_holm'])} | **{c['verdict']}** | {settle_text(c)} | {c['wins'][0]} / {c['wins'][1]} | "
                     f"{p_cell(c['sign_flip'])} | {every}: {welch} | {chance} |")
    lines += ["", caption(long, PAPER_BUDGET[0]), "",
              "| # | claim | the paper | paired seeds: A vs B (n of planned) | A - B, seed by seed | "
              "A - B [95 % CI] (paired t) | p | p, Holm | verdict | seeds to settle | only A / only B arrives (cases of "
              "the paired seeds) |",
              "|---" * 11 + "|"]
    for i, c in enumerate(long, 1):
        name, digits, paper = claim_text(c)
        each = ", ".join(f"seed {k}: {d:+.{digits}f}" for k, d in zip(c["seeds"], c["diffs"]))
        lines.append(f"| P{i} | {name} | {paper} | {c['paired_means'][0]:.{digits}f} vs "
                     f"{c['paired_means'][1]:.{digits}f} ({c['n']} of {len(c['planned'])}) | {each} | "
                     f"{'-' if c['ci'] is None else ci_text(c['d'], c['ci'], digits)} | {p_cell(c['p'])} | "
                     f"{p_cell(c['p_holm'])} | **{c['verdict']}** | {settle_text(c)} | "
                     f"{c['cases']['only_mine']} / {c['cases']['only_other']} |")
    return lines


def settle_text(c: dict) -> str:
    """An undecided claim's seeds to settle (`claims.seeds_to_settle`), "> MOST_SEEDS" where none is near; else -."""
    if c["verdict"] != "undecided":
        return "-"
    return f"> {claims.MOST_SEEDS:,}" if c["settle"] is None else str(c["settle"])


def caption(rows: list[dict], steps: int) -> str:
    """A claims table's caption: its budget, its family, its planned seeds and whether its verdicts are of record."""
    m, plans, have = len(rows), " or ".join(map(str, sorted({len(c["planned"]) for c in rows}))), sorted(
        {c["n"] for c in rows})
    head = (f"**{budget_text((steps, None))} training steps: {m} claims, one family.** Planned n: {plans} seeds, "
            "those the design gives both rows (`analysis/claims.py`, PLAN). ")
    if rows[0]["interim"]:
        return head + (f"**Interim**: n = {' to '.join(map(str, dict.fromkeys((have[0], have[-1]))))} of {plans} "
                       "seeds committed so far; the numbers are shown as they stand and no verdict is called until "
                       "every claim has its planned seeds (then tested once, at that n). The paired t needs two "
                       "seeds; Holm's adjustment counts a claim not yet testable as p = 1.")
    return head + (
        "Every claim is at its planned n: these are the verdicts of record. Test of record: Student's paired t on the "
        "per-seed differences A - B over the seeds both rows have (+ the claim's order), its 95 % CI and two-sided p; "
        f"Holm's step-down over the {m} claims. Holds / fails: Holm p < {claims.ALPHA} and A - B above / below 0; "
        f"equivalent within ±{claims.MARGIN['success_rate']} (success only): the two one-sided paired tests against "
        f"the margin, Holm over the success claims, below {claims.ALPHA}; otherwise undecided. Seeds to settle: the "
        f"fewest seeds both rows need for the paired t to reach {claims.POWER * 100:.0f} % power at the observed mean "
        f"difference and std of the differences, at the claim's Holm level ({claims.ALPHA} / (m - i + 1), i its rank "
        "by raw p; the rank may move as seeds are added). Secondary, unpaired: Welch's test over every seed of each "
        "row and P(A > B) (rliable's probability of improvement, stratified bootstrap).")


def side_block(found: dict, algos, paper: bool = False) -> list[str]:
    """One table of both scenarios side by side at the default budget: per row its seeds (n) and per scenario its
    success (mean +- std over seeds, in brackets the mean per-round std; n = 1: the mean and its per-round std),
    collisions / timeouts and crossing time (means over seeds); with `paper`, Table 3's success (its +-) and crossing
    time beside each, and the ablations in italics. No success is bold: a test, not a maximum, orders rows."""
    table = {algo: {s: found.get(DEFAULT, {}).get((s, algo)) for s in SCENARIOS} for algo in algos}
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
            cells += [cell_text(stats['success_rate'], 3),  # no bold: no test picks a best row (the claims do)
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


def played(found: dict, most: int = 6) -> str:
    """What the rows were evaluated on, from their eval.json (rounds, cases_per_round): "10 rounds x 200 test cases"
    where every row played the same; else each size, the rows of all but the commonest named (`most` of each)."""
    sizes = {}
    for budget, cells_ in found.items():
        for (scenario, algo), seeds in cells_.items():
            for seed, row in seeds.items():
                sizes.setdefault((row.get("rounds"), row.get("cases_per_round")), []).append(
                    f"{scenario} {row_name(algo, {seed: row})} seed {seed}"
                    + (f" at {budget_text(budget)} steps" if budget != DEFAULT else ""))
    text = lambda r, c: ("an unrecorded number of rounds x test cases" if None in (r, c)  # noqa: E731
                         else f"{r} round{'s' * (r != 1)} x {c} test cases")
    if len(sizes) < 2:
        return text(*next(iter(sizes))) if sizes else "its rounds (no finished cell yet)"
    common = max(sizes, key=lambda size: len(sizes[size]))
    others = [f"{text(*size)} in {', '.join(rows[:most])}{f' and {len(rows) - most} more' * (len(rows) > most)}"
              for size, rows in sizes.items() if size != common]
    return "; ".join([f"its rounds, which differ between rows (their eval.json): {text(*common)} in "
                      f"{len(sizes[common])} rows", *others])


def collect(args, extra=(), out: Path | None = None) -> str:
    """Rebuild results/table3.md from the eval.json files under results/runs (or write `out` instead) and return its
    text. With `extra`, eval.json files of outside policies (--extra), their rows join the tables and the text goes to
    `out` alone, if given: never to results/table3.md, the committed results."""
    committed = args.results / "table3.md"
    if extra and out is not None and out.resolve() == committed.resolve():
        raise SystemExit(f"--out {out}: the committed results, which rows outside the paper (--extra) never enter")
    found = load(args.results, extra)
    lines = ["# Table 3, reproduced", "",
             f"Each cell: mean +- std over the n seeds (ddof = 0) of each seed's mean over {played(found)}; in "
             "brackets the mean per-round std (the paper's +-). A row of one seed (n = 1) has "
             "no spread over seeds: its cell is the mean and, in brackets, its per-round std. Crossing: over a round's "
             "successes (the paper's measure); crossing, timeouts at 60 s, no collisions: over the cases that did not "
             "collide (collisions are left out), a timeout counted at the 60 s limit. Paper: Table 3 "
             f"(5 x 10^5 training steps). Built by `python bench/table3.py --collect-only` from "
             f"{shown(args.results)}/runs/*/eval.json.", ""]
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
              "beside it when it started), the load when it started and, if it resumed, the step it resumed from. A "
              "stretch killed with no signal (a machine's stop) has no end stamp: ~, timed from its progress lines "
              "(training only).", "", *wall_times(args.results), ""]
    text = "\n".join(lines)
    if out is not None or not extra:
        (out or committed).parent.mkdir(parents=True, exist_ok=True)  # no cell finished yet: no RESULTS either
        (out or committed).write_text(text)
    if args.readme:
        write_readme(found, ROOT / "README.md")
    return text


def folders(trial: bool) -> tuple[Path, Path]:
    """The default --work and --results: runs/grid and results/, or a trial's runs/trial/grid and runs/trial."""
    return (TRIAL / "grid", TRIAL) if trial else (ROOT / "runs" / "grid", ROOT / "results")


def collect_command(args) -> str:
    """The command that builds this grid's table (and names its unfinished cells)."""
    given = zip(("work", "results"), (args.work, args.results), folders(trial=False))
    return "python bench/table3.py --collect-only" + "".join(
        f" --{name} {shlex.quote(shown(path))}" for name, path, default in given if path != default)


def held(lock: Path) -> bool:
    """Does a process (a grid here, a Slurm task) hold this run directory's lock now (claim)?"""
    if not lock.exists():
        return False
    with open(lock) as f:
        try:
            fcntl.flock(f, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
    return False


def unfinished(work: Path, results: Path) -> list[tuple[str, bool]]:
    """The cells started in WORK and not finished: each run directory with a ckpt.pt or a lock and no eval.json in
    RESULTS/runs, as (its name, whether it runs now: `held`)."""
    return [(out.name, held(out / "lock")) for out in (sorted(work.iterdir()) if work.is_dir() else [])
            if out.is_dir() and ((out / "ckpt.pt").exists() or (out / "lock").exists())
            and not (results / "runs" / out.name / "eval.json").exists()]


def not_in_table(args) -> list[str]:
    """What --collect-only says after the table, on stderr: the cells started and not finished (`unfinished`), and
    the array tasks of this work directory's job still in Slurm's queue (bench/slurm.py's `queued`)."""
    started, lines = unfinished(args.work, args.results), []
    if started:
        running, stopped = [name for name, now in started if now], [name for name, now in started if not now]
        lines.append(f"not in the table: {len(started)} cell(s) started in {shown(args.work)} and not finished"
                     + f"; running now: {', '.join(running)}" * bool(running)
                     + f"; stopped, the same command resumes them: {', '.join(stopped)}" * bool(stopped))
    if (args.work / "grid.sbatch").exists():
        import slurm  # bench/slurm.py (it imports this module)
        tasks = slurm.queued(args.work)
        counts = [f"{len(ids)} {state.lower()} ({', '.join(ids[:8])}{', ...' * (len(ids) > 8)})"
                  for state, ids in tasks.items()]
        if tasks:
            lines.append(f"in Slurm's queue (squeue), tasks of {shown(args.work / 'grid.sbatch')}: {'; '.join(counts)}")
    return lines


class Parser(argparse.ArgumentParser):
    def error(self, message):
        """A mistake on the command line: one line (--help lists the options)."""
        self.exit(2, f"{self.prog}: {message}\n")


def parser() -> argparse.ArgumentParser:
    """The command line of every path to a cell (a grid run here, --print-commands, --slurm) and of the table: each
    option declared once, with one default."""
    p = Parser(prog="bench/table3.py", description=__doc__.split("\n")[0], epilog="A trial, other "
                                f"than Table 3's {ROUNDS} rounds x {CASES} cases, goes to runs/trial/grid and "
                                "runs/trial unless --work or --results say otherwise: `rm -r runs/trial` removes it.")
    grid = p.add_argument_group("the grid: its cells, on every path")
    algos = (*RUN, "lattice-idm", *ABLATIONS)
    grid.add_argument("--algos", nargs="+", default=list(GRID), choices=algos, metavar="ALGO",
                      help=f"the rows, of {', '.join(algos)} (default: Table 3's learned ones and TARL's two "
                      f"ablations, {' '.join(GRID)}; the other variants, beyond/variants.py, only when named). "
                      "lattice-idm has no cell of its own: TARL's cell evaluates it on the same cases, so it selects "
                      "TARL's cell")
    grid.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    grid.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    grid.add_argument("--steps", type=int, default=STEPS, help="training steps of every learned row (another budget's "
                      "cells are S-A-sK-500k, reported apart)")
    grid.add_argument("--step-one", type=int, help="steps of Alg. 1's step 1 in every cell (default: the share "
                      f"TrainConfig.sac_fraction = {tarl.TrainConfig.sac_fraction} of --steps); cells "
                      "S-A-sK-67k-step1-40k")
    grid.add_argument("--rounds", type=int, default=ROUNDS, help=f"evaluation rounds of a cell (Table 3's: {ROUNDS}; "
                      "any other --rounds or --cases is a trial)")
    grid.add_argument("--cases", type=int, default=CASES, help=f"test cases a round (Table 3's: {CASES})")
    grid.add_argument("--work", type=Path, help="the cells' run directories and, on Slurm, the tasks' output files, on "
                      "a disk the compute nodes share (default: runs/grid; a trial's: runs/trial/grid)")
    grid.add_argument("--results", type=Path, help="where finished cells go, RESULTS/runs/CELL, and the table, "
                      "RESULTS/table3.md (default: results; a trial's: runs/trial)")
    here = p.add_argument_group("a grid run here")
    here.add_argument("--jobs", type=int, help="cells side by side (default 2)")
    here.add_argument("--threads", type=int, help=f"torch threads and evaluation workers of each cell, also in "
                      f"--print-commands (default {THREADS}, as the committed cells ran: the same seed at another "
                      "thread count gives other numbers)")
    here.add_argument("--commit", action="store_true", help="make git commits in this repository: after each "
                      "finished cell, rebuild RESULTS/table3.md and `git add` and `git commit` it and the cell's "
                      "RESULTS/runs/CELL, nothing else")
    here.add_argument("--print-commands", action="store_true", help="print one command per unfinished cell and exit")
    on = p.add_argument_group("on a Slurm cluster (bench/slurm.py)")
    on.add_argument("--slurm", action="store_true", help="the unfinished cells as an array job, a task per cell, which "
                    "publishes its own files and never builds the table nor commits; without --submit or --write, "
                    "print the job file")
    on.add_argument("--submit", action="store_true", help="submit the array job (its file: WORK/grid.sbatch)")
    on.add_argument("--write", type=Path, metavar="FILE", help="write the array job's file (to sbatch yourself)")
    on.add_argument("--cpus-per-task", type=int, help=f"each task's CPUs, its cell's torch threads and evaluation "
                    f"workers (default {THREADS}: one-thread cells side by side use the cores best)")
    on.add_argument("--time", help=f"each task's time limit (sbatch --time; default {TIME_LIMIT}: a 10^5-step cell at "
                    "one thread with margin; a 5 x 10^5-step one takes 1.7-3.0 h). A longer cell is warned, saves, and "
                    "its task requeued resumes it")
    on.add_argument("--partition", help="the cluster's partition (default: the cluster's default partition)")
    on.add_argument("--task", action="store_true", help="run the one selected cell as an array task (the job file's "
                    "command)")
    table = p.add_argument_group("the table")
    table.add_argument("--collect-only", action="store_true", help="build RESULTS/table3.md from "
                       "RESULTS/runs/*/eval.json and print it; then name, on stderr, the cells started in WORK and not "
                       "finished and the grid's tasks still in Slurm's queue")
    table.add_argument("--extra", type=Path, nargs="+", default=[], metavar="PATH", help="with --collect-only: "
                       "eval.json files of policies outside the paper (bench/own_agent.py's), each row listed after "
                       "Table 3's rows and the ablations as 'LABEL (outside the paper)'; the tables are then printed "
                       "(and written to --out FILE if given), never to results/table3.md")
    table.add_argument("--out", type=Path, metavar="FILE", help="with --collect-only: write the tables here instead "
                       "(default: results/table3.md, or no file with --extra)")
    table.add_argument("--readme", action="store_true", help="also rewrite the result tables of README.md (the "
                       "headline) and docs/RESULTS.md (the full ones), between their <!-- table3.py NAME --> markers")
    return p


def settle(p: argparse.ArgumentParser, args) -> argparse.Namespace:
    """The parsed command line checked, each mistake one line before any work, and completed: the defaults of the path
    taken, TARL's cell for lattice-idm, a trial's folders, absolute paths (a relative one is the caller's)."""
    actions = [flag for flag, on in (("--print-commands", args.print_commands), ("--collect-only", args.collect_only),
                                     ("--submit", args.submit), ("--write", args.write), ("--task", args.task)) if on]
    if len(actions) > 1:
        p.error(f"{' and '.join(actions)}: choose one")
    if args.slurm:
        for flag, on, why in (
                ("--commit", args.commit, "a Slurm task commits nothing; once the tasks are done, --collect-only "
                 "builds the table: look, and commit it yourself"),
                ("--threads", args.threads is not None, "a task's threads are its CPUs, --cpus-per-task"),
                ("--jobs", args.jobs is not None, "the cluster runs the tasks, one per cell, as many at once as it has "
                 "room for"),
                ("--print-commands", args.print_commands, "--slurm without --submit or --write prints the job file")):
            if on:
                p.error(f"{flag} does not go with --slurm: {why}")
        args.cpus_per_task = THREADS if args.cpus_per_task is None else args.cpus_per_task
        args.time = args.time or TIME_LIMIT
    else:
        given = (("--submit", args.submit), ("--write", args.write), ("--task", args.task),
                 *((f"--{name.replace('_', '-')}", getattr(args, name) is not None)
                   for name in ("cpus_per_task", "time", "partition")))
        slurm_only = [flag for flag, on in given if on]
        if slurm_only:
            p.error(f"{', '.join(slurm_only)}: Slurm's, with --slurm")
        args.jobs = 2 if args.jobs is None else args.jobs
        args.threads = THREADS if args.threads is None else args.threads
        if args.jobs < 1 or args.threads < 1:
            p.error("--jobs and --threads must be at least 1")
    if "lattice-idm" in args.algos:
        args.algos = list(dict.fromkeys("tarl" if algo == "lattice-idm" else algo for algo in args.algos))
        print("--algos lattice-idm: Lattice-IDM has no cell of its own; TARL's cell (tarl) evaluates it on the same "
              "test cases", file=sys.stderr)
    if args.step_one is not None and not 0 < args.step_one < args.steps:
        p.error("--step-one must be above 0 and below --steps")
    if args.step_one is not None and (plain := [a for a in args.algos if not experiment.ROWS[a].step_one]):
        p.error(f"--step-one: {', '.join(plain)} have no step 1")
    if args.rounds < 1 or args.cases < 1:
        p.error("--rounds and --cases must be at least 1")
    if (args.extra or args.out) and not args.collect_only:
        p.error("--extra and --out go with --collect-only")
    if args.extra and args.readme:
        p.error("--readme writes the committed results' tables, which rows outside the paper (--extra) never enter")
    trial = (args.rounds, args.cases) != (ROUNDS, CASES)
    defaults = None in (args.work, args.results)
    work, results = folders(trial)
    # the cells run with cwd=ROOT: a relative --work or --results means the caller's directory, not ROOT
    args.work, args.results = (args.work or work).resolve(), (args.results or results).resolve()
    if args.commit and (not args.results.is_relative_to(ROOT) or args.results.is_relative_to(ROOT / "runs")):
        p.error(f"--commit: {shown(args.results)} is not in the repository's tracked results (git ignores runs/, where "
                "a trial goes): nothing to commit")
    if trial and defaults and not args.task:
        print(f"a trial, {args.rounds} x {args.cases} test cases (Table 3's: {ROUNDS} x {CASES}): its cells in "
              f"{shown(args.work)}, its results in {shown(args.results)}, apart from the committed ones "
              "(`rm -r runs/trial` removes a trial's)", file=sys.stderr)
    return args


def main(argv=None):
    p = parser()
    args = settle(p, p.parse_args(argv))
    if args.collect_only:
        print(collect(args, args.extra, args.out))
        for line in not_in_table(args):
            print(line, file=sys.stderr)
        return
    if args.slurm:
        import slurm  # bench/slurm.py: the array job and its tasks (it imports this module)
        return slurm.run(p, args)
    todo = [c for c in cells(args.algos, args.seeds, args.scenarios) if not done(c, args)]
    if args.print_commands:
        return print("\n".join(" ".join(command(*c, args, args.threads)) for c in todo))
    print(f"{len(todo)} cells to run, {args.jobs} at a time, {args.threads} thread(s) each", flush=True)
    run_grid(todo, args)
    print(collect(args))  # the table, once: the cells published their own files alone


if __name__ == "__main__":
    main()
