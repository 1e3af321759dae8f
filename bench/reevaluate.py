"""Committed policies evaluated again in today's world (world.WORLD_VERSION), each cell's eval.json replaced.

    python bench/reevaluate.py roundabout-tarl-fixed-t-s0 intersection-tarl-random-t-s0 --commit
    python bench/reevaluate.py --stale          # list the cells whose eval.json is from an older world

A cell is results/runs/CELL with its policy.pt. It is evaluated from that policy (`tarl.py --load ... --eval-rows
trained`, or `all` where its eval.json holds Lattice-IDM and the step-1 model too) on the same 10 x 200 test cases,
resumably (runs/reevaluate/CELL keeps the finished rounds); its eval.json is then replaced, and the number of its cases
whose outcome changed goes to results/reevaluated.md. No training: a cell without policy.pt cannot be re-evaluated.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "results" / "runs"
sys.path.insert(0, str(ROOT))
import experiment  # noqa: E402
from world import WORLD_VERSION  # noqa: E402

TABLE = ROOT / "results" / "reevaluated.md"


def changed(old: dict, new: dict) -> list[str]:
    """Per row of the new eval.json: its label, the cases whose outcome changed, and the success before and after."""
    lines = []
    for row in new["rows"]:
        before = next(r for r in old["rows"] if r["algo"] == row["algo"])
        was = {(c["round"], c["case"]): c["outcome"] for c in before["cases"]}
        n = sum(was[c["round"], c["case"]] != c["outcome"] for c in row["cases"])
        lines.append(f"{row['algo']}: {n} of {len(row['cases'])} outcomes changed, success "
                     f"{before['success_rate']['mean']:.4f} -> {row['success_rate']['mean']:.4f}")
    return lines


def reevaluate(cell: str, args) -> bool:
    folder = RUNS / cell
    old = experiment.read_eval(folder / "eval.json")
    rows = [r["algo"] for r in old["rows"]]
    from table3 import commit, evaluate_policy  # bench/table3.py's, here when they are needed
    done = evaluate_policy(folder / "policy.pt", old["scenario"], rows[0], old["seed"], args.work / cell,
                           args.work / f"{cell}.log", "--eval-rows", "all" if "lattice-idm" in rows[1:] else "trained",
                           workers=args.workers)
    if done is None:
        return False
    new = dict(experiment.read_eval(done), previous=dict(world=old["world"], code=old.get("code")))  # what it replaces
    (folder / "eval.json").write_text(json.dumps(new))
    lines = [f"- {cell} (world {old['world']} -> {new['world']}): " + "; ".join(changed(old, new))]
    print(lines[0], flush=True)
    head = ["# Cells evaluated again in a newer world", "",
            "Written by `python bench/reevaluate.py`: each cell's committed policy on the same test cases, before and "
            "after (world.WORLD_VERSION says what changed).", ""]
    TABLE.write_text("\n".join((TABLE.read_text().splitlines() if TABLE.exists() else head) + lines) + "\n")
    if args.commit:
        commit([folder / "eval.json", TABLE], f"re-evaluated {cell} in world {WORLD_VERSION}: {lines[0].split(': ', 1)[1]}")
    return True


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("cells", nargs="*", help="results/runs/CELL names")
    p.add_argument("--stale", action="store_true", help="list the cells from an older world, with or without policy")
    p.add_argument("--workers", type=int, default=1, help="evaluation processes per cell")
    p.add_argument("--work", type=Path, default=ROOT / "runs" / "reevaluate")
    p.add_argument("--commit", action="store_true", help="git commit each cell as it finishes")
    args = p.parse_args(argv)
    if args.stale:
        for f in sorted(RUNS.glob("*/eval.json")):
            if (played := experiment.read_eval(f)["world"]) != WORLD_VERSION:
                print(f"{f.parent.name}\tworld {played}\t{'policy.pt' if (f.parent / 'policy.pt').exists() else '-'}")
        return
    bad = [c for c in args.cells if not (RUNS / c / "policy.pt").exists() or not (RUNS / c / "eval.json").exists()]
    if bad or not args.cells:
        p.error(f"no committed policy.pt and eval.json for: {', '.join(bad)}" if bad else "name at least one cell")
    todo = [c for c in args.cells if experiment.read_eval(RUNS / c / "eval.json")["world"] != WORLD_VERSION]
    print(f"{len(todo)} of {len(args.cells)} cells to evaluate in world {WORLD_VERSION}", flush=True)
    failed = [c for c in todo if not reevaluate(c, args)]
    if failed:
        raise SystemExit(f"failed: {', '.join(failed)}")


if __name__ == "__main__":
    main()
