"""Reproduce Table 3: train and evaluate every model on both scenarios, then write results/table3.md.

    python bench/table3.py                       # default budget, 10 x 200 test cases
    python bench/table3.py --steps 500000        # the paper's budget
    python bench/table3.py --collect-only        # only rebuild the table from runs/ (or --runs DIR)

`--algo tarl` trains TARL and reports TARL, SAC (its step-1 model) and Lattice-IDM on the same
test seeds; `--algo sac-lattice` adds SAC-Lattice. Each run keeps its log, checkpoints and
eval.json in RUNS/SCENARIO-ALGO-sSEED; the table is rebuilt from those eval.json files.
"""
import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("intersection", "roundabout")
ROWS = ("tarl", "sac", "sac-lattice", "lattice-idm")
# Table 3 of the paper: success rate and crossing time [s], mean +- std over 10 rounds of 200 cases
PAPER = {
    ("intersection", "tarl"): (0.881, 0.021, 8.473, 0.145), ("roundabout", "tarl"): (0.912, 0.025, 16.066, 0.095),
    ("intersection", "sac-lattice"): (0.808, 0.032, 8.509, 0.182), ("roundabout", "sac-lattice"): (0.868, 0.037, 16.371, 0.481),
    ("intersection", "lattice-idm"): (0.896, 0.018, 11.349, 0.280), ("roundabout", "lattice-idm"): (0.797, 0.030, 27.293, 0.291),
}


def collect(runs: Path, seed: int) -> dict:
    """(scenario, row) -> result dict, from every eval.json under `runs` for this seed."""
    found = {}
    for scenario in SCENARIOS:
        for algo in ("tarl", "sac-lattice"):
            path = runs / f"{scenario}-{algo}-s{seed}" / "eval.json"
            if path.exists():
                for row in json.loads(path.read_text())["table"]:
                    found.setdefault((scenario, row["algo"]), row)
    return found


def fmt(mean, std, digits):
    return "-" if mean is None else f"{mean:.{digits}f} +- {std:.{digits}f}"


def markdown(found: dict) -> str:
    lines = ["| model | intersection success | crossing [s] | roundabout success | crossing [s] |",
             "|---|---|---|---|---|"]
    for row in ROWS:
        cells = []
        for scenario in SCENARIOS:
            r = found.get((scenario, row))
            cells += [fmt(r["success_rate"]["mean"], r["success_rate"]["std"], 3), fmt(r["crossing_time"]["mean"], r["crossing_time"]["std"], 2)] if r else ["not run", ""]
        budget = sorted({f"{r['rounds']} x {r['cases']}" for (s, name), r in found.items() if name == row})
        lines.append(f"| {row} (this code, {', '.join(budget) or '-'}) | " + " | ".join(cells) + " |")
        if any((s, row) in PAPER for s in SCENARIOS):
            paper = []
            for scenario in SCENARIOS:
                p = PAPER.get((scenario, row))
                paper += [f"{p[0]:.3f} +- {p[1]:.3f}", f"{p[2]:.2f} +- {p[3]:.2f}"] if p else ["", ""]
            lines.append(f"| {row} (paper) | " + " | ".join(paper) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, help="training steps per model (default: tarl.py's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-rounds", type=int, default=10)
    p.add_argument("--eval-cases", type=int, default=200)
    p.add_argument("--runs", type=Path, default=ROOT / "runs")
    p.add_argument("--collect-only", action="store_true")
    a = p.parse_args()
    if not a.collect_only:
        for scenario in SCENARIOS:
            for algo in ("tarl", "sac-lattice"):
                cmd = [sys.executable, str(ROOT / "tarl.py"), "--scenario", scenario, "--algo", algo,
                       "--seed", str(a.seed), "--eval-rounds", str(a.eval_rounds), "--eval-cases", str(a.eval_cases),
                       "--out", str(a.runs / f"{scenario}-{algo}-s{a.seed}")] + (["--steps", str(a.steps)] if a.steps else [])
                print("+", " ".join(cmd), flush=True)
                subprocess.run(cmd, check=True)
    table = markdown(collect(a.runs, a.seed))
    (ROOT / "results").mkdir(exist_ok=True)
    (ROOT / "results" / "table3.md").write_text(table + "\n")
    print(table)
