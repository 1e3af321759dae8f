"""Shipped policies at traffic densities they were not trained in: does a row keep its place?

    python bench/heldout.py                       # run or resume every cell, committing each one as it finishes
    python bench/heldout.py --collect-only        # rebuild results/heldout/summary.md

Each cell is one shipped seed-0 policy (results/runs/SCENARIO-ALGO-s0/policy.pt) evaluated with `tarl.py --load
... --spawn-gap GAP` on --rounds x --cases test cases recorded at that gap (the same cases for every row of a
gap: they depend on the seed, the round and the traffic only). Table 1's gap is 1.8 s at the intersection and
1.2 s on the roundabout (world.SCENARIOS): 0.9 s is denser traffic on both, 2.7 s sparser on both; 1.8 s is
the intersection's own (its cases are then Table 3's first 100 of each round) and sparser on the roundabout.
No training. Each cell's
eval.json goes to results/heldout/gap-GAP/SCENARIO-ALGO-s0/eval.json, where `python -m exercises.paired --runs
results/heldout/gap-GAP --seeds 0 ...` compares two rows case by case; summary.md sets every row beside the
first of --algos, case by case with McNemar's exact p.
"""
import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "results" / "runs"  # Table 3's runs, each with its shipped policy.pt
sys.path.insert(0, str(ROOT))
import experiment  # noqa: E402
from analysis.compare import read_row  # noqa: E402
from analysis.paired import p_text, paired  # noqa: E402

SCENARIOS = ("intersection", "roundabout")
ALGOS = ("tarl", "tarl-fixed-t", "tarl-random-t")
GAPS = (0.9, 1.8, 2.7)  # [s] mean gaps between departures (Table 1: 1.8 at the intersection, 1.2 on the roundabout)


def folder(results: Path, gap: float, scenario: str, algo: str) -> Path:
    return results / f"gap-{gap:g}" / experiment.run_name(scenario, algo, 0)


def run(gap: float, scenario: str, algo: str, args) -> bool:
    """One evaluation, resumable (its eval-rounds/ keep finished rounds); True if it finished."""
    from table3 import commit, evaluate_policy  # bench/table3.py's, here when they are needed
    out = folder(args.work, gap, scenario, algo)
    done = evaluate_policy(RUNS / experiment.run_name(scenario, algo, 0) / "policy.pt", scenario, algo, 0, out,
                           out.parent / f"{out.name}.log", "--spawn-gap", f"{gap:g}", "--eval-rows", "trained",
                           "--eval-rounds", str(args.rounds), "--eval-cases", str(args.cases))
    if done is None:
        return False
    dst = folder(args.results, gap, scenario, algo) / "eval.json"
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(done, dst)
    collect(args)
    if args.commit:
        commit([dst, args.results / "summary.md"], f"heldout: {algo} seed 0 on the {scenario} at a {gap:g} s gap")
    return True


def collect(args):
    """results/heldout/summary.md: every row at every gap run so far, beside the first of --algos case by case."""
    lines = ["# Shipped seed-0 policies at other traffic densities", "", "Built by `python bench/heldout.py "
             "--collect-only`. Success, collision, timeout: the mean over rounds. Case by case: of the cases where "
             f"exactly one of the row and {args.algos[0]} arrives, how many go to the row (+) and to {args.algos[0]} "
             "(-), and McNemar's exact p.", "",
             "| scenario | gap [s] | row | cases | success | collision | timeout | crossing [s] | vs " + args.algos[0] + " |",
             "|---|---|---|---|---|---|---|---|---|"]
    gaps = sorted(float(p.name[len("gap-"):]) for p in args.results.glob("gap-*"))  # every gap run so far
    for scenario in SCENARIOS:
        for gap in gaps:
            rows = {a: read_row(p, a) for a in args.algos if (p := folder(args.results, gap, scenario, a) / "eval.json").exists()}
            first = rows.get(args.algos[0])
            for algo, row in rows.items():
                cases, m = row["cases"], lambda key: row[key]["mean"]
                versus = "-"
                if algo != args.algos[0] and first is not None:
                    r = paired(row, first, np.random.default_rng(0))  # where exactly one arrives, McNemar
                    versus = f"{r['only_mine']} / {r['only_other']}, p {p_text(r['p'])}"
                lines.append(f"| {scenario} | {gap:g} | {algo} | {len(cases)} | {m('success_rate'):.3f} | "
                             f"{m('collision_rate'):.3f} | {m('timeout_rate'):.3f} | {m('crossing_time'):.1f} | {versus} |")
    args.results.mkdir(parents=True, exist_ok=True)
    (args.results / "summary.md").write_text("\n".join(lines) + "\n")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    p.add_argument("--algos", nargs="+", default=list(ALGOS), help="rows with a shipped seed-0 policy; the first is "
                   "the one the others are compared with")
    p.add_argument("--gaps", type=float, nargs="+", default=list(GAPS), help="[s] mean gaps between departures")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--cases", type=int, default=100)
    p.add_argument("--work", type=Path, default=ROOT / "runs" / "heldout")
    p.add_argument("--results", type=Path, default=ROOT / "results" / "heldout")
    p.add_argument("--commit", action="store_true", help="git commit each finished cell")
    p.add_argument("--collect-only", action="store_true")
    args = p.parse_args()
    if any(not g > 0 for g in args.gaps):
        p.error("--gaps are mean gaps [s] > 0")
    missing = [experiment.run_name(s, a, 0) for s in args.scenarios for a in args.algos
               if not (RUNS / experiment.run_name(s, a, 0) / "policy.pt").exists()]
    if missing and not args.collect_only:
        p.error(f"no shipped policy for: {', '.join(missing)} (results/runs/SCENARIO-ALGO-s0/policy.pt)")
    if not args.collect_only:
        for gap in args.gaps:
            for scenario in args.scenarios:
                for algo in args.algos:
                    if not (folder(args.results, gap, scenario, algo) / "eval.json").exists():
                        run(gap, scenario, algo, args)
    collect(args)
    print((args.results / "summary.md").read_text())


if __name__ == "__main__":
    main()
