"""TARL's own actor under other timings, on Table 3's test cases: is it the actor or the timing that differs?

    python bench/retime.py                 # run or resume every cell, committing each one as it finishes
    python bench/retime.py --collect-only  # rebuild results/retime/summary.md

The shipped TARL policies (results/runs/SCENARIO-tarl-sSEED/policy.pt) evaluated with `tarl.py --load ...
--timing SPEC` on the same 10 rounds x 200 test cases as every row of Table 3, SPEC in fixed=1, fixed=2,
fixed=3, random (and phased: Eq. (7)'s schedule in the real loop). No training. Each cell's eval.json goes to
results/retime/SCENARIO-tarl-sSEED-SPEC.json; the summary sets each beside TARL's learned timing (its own
eval.json) and beside the ablations trained with that timing (tarl-fixed-t, tarl-random-t), case by case.
"""
import argparse
import re
import shutil
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "results" / "runs"  # Table 3's runs, each with its shipped policy.pt
sys.path.insert(0, str(ROOT))
import experiment  # noqa: E402
from world import WORLD_VERSION  # noqa: E402

SCENARIOS = ("intersection", "roundabout")
TIMINGS = ("fixed=1", "fixed=2", "fixed=3", "random", "phased")
TRAINED_WITH = {"fixed=2": "tarl-fixed-t", "random": "tarl-random-t"}  # the ablation trained with that timing


def cell(scenario: str, seed: int, timing: str) -> str:
    return experiment.run_name(scenario, "tarl", seed) + f"-{timing.replace('=', '')}"  # TARL's run and the timing


def run(scenario: str, seed: int, timing: str, args) -> bool:
    """One evaluation, resumable (its eval-rounds/ keep finished rounds); True if it finished."""
    from table3 import commit, evaluate_policy  # bench/table3.py's, here when they are needed
    name = cell(scenario, seed, timing)
    done = evaluate_policy(RUNS / experiment.run_name(scenario, "tarl", seed) / "policy.pt", scenario, "tarl", seed,
                           args.work / name, args.work / f"{name}.log", "--timing", timing, "--eval-rows", "trained",
                           "--eval-rounds", str(args.rounds), "--eval-cases", str(args.cases), workers=args.workers)
    if done is None:
        return False
    dst = args.results / f"{name}.json"
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(done, dst)
    collect(args)
    if args.commit:
        commit([dst, args.results / "summary.md"], f"retime: TARL seed {seed} on the {scenario} with --timing {timing}")
    return True


def rows(path: Path) -> dict:
    return {row["algo"]: row for row in experiment.read_eval(path)["rows"]} if path.exists() else {}


def rate(row: dict, key: str) -> str:
    return f"{row[key]['mean']:.3f} +- {row[key]['std']:.3f}"


def collect(args):
    """results/retime/summary.md: each timing beside the learned one and the ablation trained with it, every seed."""
    lines = ["# TARL's actor under other timings", "", "Built by `python bench/retime.py --collect-only`. Each row: the "
             "shipped TARL policy evaluated with `--timing`, on the seed's 10 rounds x 200 test cases (success, "
             "collision, timeout: mean +- std over rounds). 'learned' is TARL's own eval.json; 'trained so' the "
             "ablation trained with that timing, on the same cases. Case by case: of the cases where exactly one "
             "of the two arrives, how many go to the timing of the row (+) and to the learned one (-).", "",
             "| scenario | seed | timing | success | collision | timeout | crossing [s] | vs learned: + / - |",
             "|---|---|---|---|---|---|---|---|"]
    seeds = sorted(set(args.seeds) | {int(m[1]) for f in args.results.glob("*.json")  # every seed re-timed so far
                                      if (m := re.fullmatch(r"[a-z]+-tarl-s(\d+)-\w+\.json", f.name))})
    for scenario in SCENARIOS:
        for seed in seeds:
            learned = rows(RUNS / experiment.run_name(scenario, "tarl", seed) / "eval.json").get("tarl")
            if learned is None:
                continue
            mine = {(c["round"], c["case"]): c["outcome"] for c in learned["cases"]}
            entries = [("learned", learned)]
            for timing in TIMINGS:
                row = rows(args.results / f"{cell(scenario, seed, timing)}.json").get("tarl")
                if row is not None:
                    entries.append((timing, row))
                if timing in TRAINED_WITH:
                    trained = rows(RUNS / experiment.run_name(scenario, TRAINED_WITH[timing], seed) /
                                   "eval.json").get(TRAINED_WITH[timing])
                    if trained is not None:
                        entries.append((f"{timing}, trained so ({TRAINED_WITH[timing]})", trained))
            for name, row in entries:
                pairs = Counter((c["outcome"] == "arrival", mine[c["round"], c["case"]] == "arrival")
                                for c in row["cases"] if (c["round"], c["case"]) in mine)
                crossing = row["crossing_time"]["mean"]
                lines.append(f"| {scenario} | {seed} | {name} | {rate(row, 'success_rate')} | {rate(row, 'collision_rate')}"
                             f" | {rate(row, 'timeout_rate')} | {crossing:.1f} | "
                             + ("-" if name == "learned" else f"{pairs[True, False]} / {pairs[False, True]}") + " |")
    args.results.mkdir(parents=True, exist_ok=True)
    (args.results / "summary.md").write_text("\n".join(lines) + "\n")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds whose TARL policy.pt is in results/runs")
    p.add_argument("--timings", nargs="+", default=list(TIMINGS), choices=TIMINGS)
    p.add_argument("--rounds", type=int, default=10)
    p.add_argument("--cases", type=int, default=200)
    p.add_argument("--workers", type=int, default=1, help="evaluation processes of each cell")
    p.add_argument("--work", type=Path, default=ROOT / "runs" / "retime")
    p.add_argument("--results", type=Path, default=ROOT / "results" / "retime")
    p.add_argument("--commit", action="store_true", help="git commit each finished cell")
    p.add_argument("--collect-only", action="store_true")
    args = p.parse_args()
    missing = [s for s in args.scenarios for k in args.seeds
               if not (RUNS / experiment.run_name(s, "tarl", k) / "policy.pt").exists()]
    if missing and not args.collect_only:
        p.error(f"no shipped TARL policy for: {', '.join(missing)} (results/runs/SCENARIO-tarl-sSEED/policy.pt)")
    if not args.collect_only:
        args.work.mkdir(parents=True, exist_ok=True)
        for timing in args.timings:  # in the order given: each timing on both scenarios before the next
            for scenario in args.scenarios:
                for seed in args.seeds:
                    done = args.results / f"{cell(scenario, seed, timing)}.json"
                    if not done.exists() or experiment.read_eval(done)["world"] != WORLD_VERSION:
                        run(scenario, seed, timing, args)  # new, or played in an older world (world.py)
    collect(args)
    print((args.results / "summary.md").read_text())


if __name__ == "__main__":
    main()
