"""Two evaluations case by case:  python -m exercises.compare A/eval.json B/eval.json [--algo A [B]]

Matches the test cases of a row of each eval.json (written by tarl.py) by (round, case) and counts, among
the cases both played: the same start (the fingerprint of every vehicle, the ego's route and the
departures to come: the same test case), the same outcome, the same drive (outcome, steps and crossing
time), and where exactly one of the two arrives. Case c of a round is the same test case whatever the
number of cases per round (world.DrivingEnv.record_cases saves the traffic's state every case_gap
seconds, case after case): the first 100 cases of a 200-case round are a 100-case round.
Exits 1 if no case matched or some matched case began differently (then the two did not meet the same
cases, and the rest means nothing), with --identical also if some drive differs; else 0. No simulation.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from pathlib import Path


def read_row(path: Path, algo: str | None = None) -> dict:
    """The row `algo` of an eval.json (default its first, the --algo row of tarl.py), with its scenario and seed."""
    data = json.loads(Path(path).read_text())
    rows = [r for r in data["rows"] if algo in (None, r["algo"])]
    if not rows:
        raise SystemExit(f"{path} has no row {algo!r}: it has {', '.join(r['algo'] for r in data['rows'])}")
    return dict(rows[0], scenario=data["scenario"], seed=data["seed"], path=str(path))


def matched(a: dict, b: dict) -> list[tuple[dict, dict]]:
    """The cases both rows played, as (a's, b's), in order of (round, case)."""
    theirs = {(c["round"], c["case"]): c for c in b["cases"]}
    return [(c, theirs[c["round"], c["case"]]) for c in sorted(a["cases"], key=lambda c: (c["round"], c["case"]))
            if (c["round"], c["case"]) in theirs]


def same_drive(x: dict, y: dict) -> bool:
    """The same outcome, steps and crossing time (to 1e-6 s)."""
    times = (x["crossing_time"] is None and y["crossing_time"] is None) or (
        None not in (x["crossing_time"], y["crossing_time"]) and math.isclose(x["crossing_time"], y["crossing_time"], abs_tol=1e-6))
    return x["outcome"] == y["outcome"] and x["steps"] == y["steps"] and times


def discordant(pairs: list[tuple[dict, dict]]) -> Counter:
    """(a's outcome, b's outcome) of the cases where exactly one of the two arrives."""
    return Counter((x["outcome"], y["outcome"]) for x, y in pairs if (x["outcome"] == "arrival") != (y["outcome"] == "arrival"))


def compare(a: dict, b: dict, identical: bool = False) -> tuple[bool, str]:
    """(did they meet the same cases (and, if identical, drive the same way), the report)."""
    name = lambda r: f"{r['path']} ({r['algo']}, {r['rounds']} x {r['cases_per_round']})"  # noqa: E731
    pairs = matched(a, b)
    lines = [f"{name(a)} against {name(b)}: {len(pairs)} cases in both, matched by (round, case)"]
    if a["scenario"] != b["scenario"] or a["seed"] != b["seed"]:
        lines.append(f"  they are of another scenario or seed: {a['scenario']} seed {a['seed']}, {b['scenario']} seed {b['seed']}")
    if not pairs:
        return False, "\n".join(lines + ["  no case in common"])
    starts = sum(x["start"] == y["start"] for x, y in pairs)
    outcomes = sum(x["outcome"] == y["outcome"] for x, y in pairs)
    drives = [same_drive(x, y) for x, y in pairs]
    only = discordant(pairs)
    lines += [f"  the same start (fingerprint): {starts} of {len(pairs)}",
              f"  the same outcome: {outcomes} of {len(pairs)}; the same drive (outcome, steps, crossing time): "
              f"{sum(drives)} of {len(pairs)}",
              f"  only the first arrives: {only['arrival', 'collision']} (the second collides) + {only['arrival', 'timeout']}"
              f" (times out); only the second arrives: {only['collision', 'arrival']} (the first collides) + "
              f"{only['timeout', 'arrival']} (times out)"]
    if not all(drives):
        x, y = pairs[drives.index(False)]
        lines.append(f"  the first that differs: round {x['round']}, case {x['case']}: {x['outcome']} in {x['steps']} steps "
                     f"against {y['outcome']} in {y['steps']} steps")
    if starts < len(pairs):
        lines.append("  some cases began differently: these are not the same test cases")
    return starts == len(pairs) and (all(drives) or not identical), "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m exercises.compare", description=__doc__.split("\n")[0].split(":")[0])
    p.add_argument("a", type=Path, help="an eval.json")
    p.add_argument("b", type=Path, help="another eval.json")
    p.add_argument("--algo", nargs="+", metavar="ALGO", help="the row of each (one name: the same in both; "
                   "default: the first row of each)")
    p.add_argument("--identical", action="store_true", help="exit 1 unless every matched case is the same drive")
    args = p.parse_args(argv)
    if args.algo and len(args.algo) > 2:
        p.error("--algo takes one name (both files) or two (one each)")
    algos = (args.algo or [None]) * (2 if not args.algo or len(args.algo) == 1 else 1)
    ok, text = compare(read_row(args.a, algos[0]), read_row(args.b, algos[1]), args.identical)
    print(text)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
