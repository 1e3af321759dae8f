"""The quick start's wall time before and after it trained as the grid's cells and evaluated beside training, measured
side by side in one run, and whether it now ends with the committed cell's numbers, case by case.

    python bench/quickstart.py                             # about 50 min on 2 idle cores
    python bench/quickstart.py --before 2e4c1a0 --after HEAD --commit

Each commit is cloned afresh and runs the README's `python tarl.py --scenario roundabout` (this python, its packages),
one after the other on the same machine; measure on idle cores (the load is printed and kept). The new run's
train_log.csv and each row's 2,000 case outcomes are compared with results/runs/roundabout-tarl-s0. Written to
results/quickstart.json.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CELL = ROOT / "results" / "runs" / "roundabout-tarl-s0"
BEFORE = "2e860a9"  # the last commit whose quick start trained with 2 threads and evaluated every row at the end


def run(rev: str, folder: Path) -> dict:
    """The README's first command (after its install) in a fresh clone of `rev`: wall time [min] and its run folder."""
    clone = folder / rev
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    subprocess.run(["git", "-C", str(clone), "checkout", "-q", rev], check=True)
    rev = subprocess.run(["git", "-C", str(clone), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                         check=True).stdout.strip()  # HEAD as the commit it was
    load, t0 = os.getloadavg()[0], time.time()
    print(f"{rev}: python tarl.py --scenario roundabout (load {load:.1f})", flush=True)
    done = subprocess.run([sys.executable, "tarl.py", "--scenario", "roundabout"], cwd=clone)
    if done.returncode != 0:
        raise SystemExit(f"{rev}: the quick start failed (exit code {done.returncode})")
    minutes = (time.time() - t0) / 60
    print(f"{rev}: {minutes:.1f} min", flush=True)
    return dict(rev=rev, minutes=round(minutes, 1), load_before=round(load, 2),
                out=str(clone / "runs" / "roundabout-tarl-s0"))


def same_as_cell(out: Path) -> dict:
    """How the run in `out` compares with the committed cell: its training log and each row's case outcomes."""
    import experiment  # here, after both runs: it loads torch
    mine, cell = (experiment.read_eval(d / "eval.json") for d in (out, CELL))
    rows = {}
    for row in mine["rows"]:
        theirs = {(c["round"], c["case"]): c for c in next(r for r in cell["rows"] if r["algo"] == row["algo"])["cases"]}
        rows[row["algo"]] = dict(success=row["success_rate"]["mean"], cases=len(row["cases"]),
                                 same_outcome=sum(c["outcome"] == theirs[c["round"], c["case"]]["outcome"]
                                                  for c in row["cases"]))
    return dict(train_log_equal=(out / "train_log.csv").read_bytes() == (CELL / "train_log.csv").read_bytes(),
                rows=rows)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--before", default=BEFORE, help="the commit of the old quick start")
    p.add_argument("--after", default="HEAD", help="the commit of the new one")
    p.add_argument("--commit", action="store_true", help="git commit results/quickstart.json")
    args = p.parse_args(argv)
    for rev in (args.before, args.after):
        if subprocess.run(["git", "-C", str(ROOT), "rev-parse", "-q", "--verify", f"{rev}^{{commit}}"],
                          capture_output=True).returncode != 0:
            p.error(f"{rev}: not a commit of this repository")
    with tempfile.TemporaryDirectory(prefix="tarl-quickstart-") as folder:
        before, after = (run(rev, Path(folder)) for rev in (args.before, args.after))
        after["against_the_cell"] = same_as_cell(Path(after.pop("out")))
        before.pop("out")
    import experiment  # here: it loads torch
    result = dict(machine=experiment.machine(), before=before, after=after,
                  ratio=round(after["minutes"] / before["minutes"], 2))
    path = ROOT / "results" / "quickstart.json"
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    if args.commit:
        subprocess.run(["git", "-C", str(ROOT), "add", str(path)], check=True)
        subprocess.run(["git", "-C", str(ROOT), "commit", "-q", "-m", f"quick start: {before['minutes']} -> "
                        f"{after['minutes']} min ({result['ratio']}x)", "--", str(path)], check=True)


if __name__ == "__main__":
    main()
