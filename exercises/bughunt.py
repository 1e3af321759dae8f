"""The bug hunt's run (EXERCISES.md, B): the shipped policy with the project's observation and with the copy.

    python -m exercises.bughunt                                  # world.observe, then exercises/bughunt_observe.py
    python -m exercises.bughunt --file my_copy.py --rounds 3 --cases 100

The shipped roundabout TARL policy (results/runs/roundabout-tarl-s0/policy.pt) plays the same R rounds x C
test cases of Table 3's protocol (seed 0) twice in this process (experiment.evaluate, workers=0): with
world.observe (Eqs. (27)-(30)), then with the copy's observe set in its place. Prints both rows'
success, collision and timeout rates (mean +- std over the rounds), crossing time and the mean share
of the base action 1 - beta (Eq. (12)); then the drop in success against the spread over rounds.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:
    sys.path.insert(0, str(HERE.parent))

from exercises import in_vivo  # noqa: E402
from exercises.check import load, nice  # noqa: E402

ROUNDS, CASES = 2, 100  # about a minute a row on a busy 2-core machine (EXERCISES.md, Runtimes)


def evaluate(shipped: in_vivo.Shipped, label: str, rounds: int, cases: int) -> dict:
    """One row of Table 3 (experiment.summarize) for the shipped policy with whatever observe is in place."""
    t0 = time.time()
    row = dict(algo="tarl", label=label, driver=shipped.driver)
    result = shipped.experiment.evaluate(shipped.cfg, [row], rounds, cases, in_vivo.SEED, workers=0, env=shipped.env,
                                         log=lambda line: print(f"  {label}:{line}", flush=True))[0]
    result["wall_time"] = time.time() - t0
    result["per_round"] = [sum(ep["outcome"] == "arrival" for ep in result["cases"] if ep["round"] == r) / cases
                           for r in range(rounds)]
    return result


def report(rows: list[dict]) -> str:
    """Both rows as a table, then the drop in success against 3 x the spread over rounds."""
    fmt = lambda m, p=3: "-" if m["mean"] is None else f"{m['mean']:.{p}f} +- {m['std']:.{p}f}"  # noqa: E731
    lines = [f"{'observation':<28}{'success':>16}{'collision':>16}{'timeout':>16}{'crossing [s]':>16}{'1 - beta':>10}"
             f"{'wall [s]':>10}"]
    for r in rows:
        lines.append(f"{r['label']:<28}{fmt(r['success_rate']):>16}{fmt(r['collision_rate']):>16}"
                     f"{fmt(r['timeout_rate']):>16}{fmt(r['crossing_time'], 1):>16}{r['beta_minus']['all_steps']:>10.2f}"
                     f"{r['wall_time']:>10.0f}")
    (a, b), rounds = rows, rows[0]["rounds"]
    drop = a["success_rate"]["mean"] - b["success_rate"]["mean"]
    spread = max(a["success_rate"]["std"], b["success_rate"]["std"])
    diffs = [x - y for x, y in zip(a["per_round"], b["per_round"])]
    paired = (sum((d - drop) ** 2 for d in diffs) / len(diffs)) ** 0.5
    lines += ["", "success per round: " + "; ".join(f"{r['label']} " + " ".join(f"{s:.3f}" for s in r["per_round"])
                                                    for r in rows),
              f"drop in success {drop:+.3f}; spread over rounds (the larger std of the two rows) {spread:.3f}, "
              f"so the drop is {drop / spread if spread else float('inf'):.1f} x the spread "
              f"({'more' if drop > 3 * spread else 'not more'} than 3 x); the per-round drop "
              + " ".join(f"{d:+.3f}" for d in diffs) + f" has std {paired:.3f}"]
    if rounds < 3:
        lines.append(f"(a std over {rounds} rounds is itself rough: --rounds 5 for a firmer one)")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m exercises.bughunt", description=__doc__.split("\n")[0])
    p.add_argument("--file", type=Path, default=HERE / "bughunt_observe.py", help="the copy of observe to run")
    p.add_argument("--rounds", type=int, default=ROUNDS, help="rounds of test cases (Table 3: 10)")
    p.add_argument("--cases", type=int, default=CASES, help="test cases per round (Table 3: 200)")
    p.add_argument("--json", type=Path, help="also write both rows (experiment.summarize, with each case) here")
    args = p.parse_args(argv)
    if min(args.rounds, args.cases) < 1:
        p.error("--rounds and --cases must be at least 1")
    copy = load(args.file)
    print(f"the shipped roundabout TARL, {args.rounds} rounds x {args.cases} test cases (seed 0), in this process: "
          f"world.observe, then {nice(args.file)}'s observe", flush=True)
    with in_vivo.Shipped(cases=0) as shipped:
        rows = [evaluate(shipped, "world.observe", args.rounds, args.cases)]
        with in_vivo.swapped({("world", "observe"): copy.observe}):
            rows.append(evaluate(shipped, f"{args.file.stem}.observe", args.rounds, args.cases))
    print(report(rows))
    if args.json:
        args.json.write_text(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
