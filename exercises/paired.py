"""Paired statistics on the committed results (EXERCISES.md, lab 8): is one row of Table 3 better than another?

    python -m exercises.paired --scenario roundabout tarl sac-lag
    python -m exercises.paired --scenario roundabout tarl tarl-consistent --runs results/runs runs/hw/runs

Every row of Table 3 met the same test cases, seed by seed (results/runs/SCENARIO-ALGO-sK/eval.json: 10
rounds x 200 cases, each case's outcome). Two rows are compared on them, for each seed and pooled:

  case by case   the cases where exactly one of the two arrives (the discordant pairs), split by how the
                 other failed: results/table3.md's "Case by case" counts, checked against it where it has them;
  McNemar        the exact test that the discordant pairs split 50:50 (no difference): two-sided
                 p = min(1, 2 P(X <= min(n_a, n_b))), X ~ Binomial(n_a + n_b, 1/2), with math.comb;
  bootstrap      the success difference (A - B, the mean over rounds of the per-round difference)
                 with a 95 % interval from resampling the rounds, seeded (--seed).

Pooled: McNemar on the seeds' discordant pairs summed; the bootstrap resamples the rounds within each
seed and averages the seeds. Both treat the seeds' models as fixed: three trained models say
little about a fourth. Over seeds, the question a claim "A is better than B" asks: the seeds' mean
differences and an exact sign-flip test on them (with n seeds its p is at least 2 / 2^n: 0.25 for 3).
Numpy only: no simulation.
"""
from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from exercises.compare import discordant, matched, read_row  # noqa: E402

# experiment.ROWS' labels (without importing torch), as results/table3.md names the rows
LABELS = {"tarl": "TARL", "tarl-fixed-t": "TARL, T = 2 fixed", "tarl-random-t": "TARL, T random",
          "tarl-consistent": "TARL, phased real loop", "tarl-held": "TARL, held imagination",
          "tarl-utd": "TARL, 8 timing updates", "tarl-actor-target": "TARL, actor's critic in Eq. (9)",
          "tarl-rare-replay": "TARL, collision replay",
          "tarl-min-target": "TARL, lower of both critics in Eq. (9)", "tarl-branch": "TARL, timing from branches",
          "sac": "SAC", "sac-lattice": "SAC-Lattice", "lattice-idm": "Lattice-IDM",
          "sac-lag": "SAC-Lag", "sac-pid": "SAC-PID", "ppo-lag": "PPO-Lag", "cpo": "CPO"}
HOSTS = ("tarl",)  # runs whose eval.json also holds lattice-idm and tarl-step1 (--eval-rows all)


def find_row(runs: list[Path], scenario: str, algo: str, seed: int, budget: str = ""):
    """The row `algo` of seed `seed`: from RUNS/SCENARIO-ALGO-sK[-BUDGET]/eval.json, else from a run that
    evaluated it beside its own row (TARL's: lattice-idm, tarl-step1); None if no run has it."""
    tail = f"-s{seed}" + (f"-{budget}" if budget else "")
    for folder in runs:
        for host in (algo, *HOSTS):
            path = folder / f"{scenario}-{host}{tail}" / "eval.json"
            if path.exists():
                try:
                    return read_row(path, algo)
                except SystemExit:  # this run has no such row
                    continue
    return None


def mcnemar(n_a: int, n_b: int) -> float:
    """Exact two-sided McNemar p-value of n_a against n_b discordant pairs (binomial, p = 1/2)."""
    n_a, n_b = int(n_a), int(n_b)  # Python's integers: 2**n is exact
    n = n_a + n_b
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(n_a, n_b) + 1))
    return min(1.0, 2 * tail / 2**n)  # exact integers, one division


def p_text(p: float) -> str:
    return f"{p:.2g}" if p > 0 else "< 1e-300"  # 2**n is exact, the quotient underflows


def sign_flip(x: np.ndarray) -> float:
    """Exact two-sided sign-flip (permutation) test that the seeds' differences x have mean 0: the share of
    the 2^n sign patterns whose |mean| is at least the observed one."""
    signs = np.array(np.meshgrid(*[[-1.0, 1.0]] * len(x))).reshape(len(x), -1).T
    return float(np.mean(np.abs((signs * x).mean(axis=1)) >= abs(x.mean()) - 1e-12))


def per_round_difference(a: dict, b: dict) -> np.ndarray:
    """Per round, A's success rate minus B's, on the cases both played."""
    pairs = matched(a, b)
    rounds = sorted({x["round"] for x, _ in pairs})
    return np.array([np.mean([(x["outcome"] == "arrival") - (y["outcome"] == "arrival") for x, y in pairs if x["round"] == r])
                     for r in rounds])


def bootstrap(diffs: list[np.ndarray], n: int, rng: np.random.Generator) -> tuple[float, float, float]:
    """(mean, 2.5 %, 97.5 %) of the mean over seeds of each seed's mean per-round difference, each seed's
    rounds resampled with replacement n times."""
    means = np.mean([d[rng.integers(len(d), size=(n, len(d)))].mean(axis=1) for d in diffs], axis=0)
    return float(np.mean([d.mean() for d in diffs])), *map(float, np.percentile(means, [2.5, 97.5]))


def table3_counts(path: Path, scenario: str, other: str) -> dict:
    """results/table3.md's "Case by case" counts of TARL against `other` at 10^5 steps: {seed: (4 counts)}."""
    if not path.exists() or other not in LABELS:
        return {}
    pattern = re.compile(rf"^\| 100,000 \| {scenario} \| (\d) \| {re.escape(LABELS[other])} \| (\d+) / (\d+) \| (\d+) / (\d+) \|$")
    return {int(m[1]): tuple(map(int, m.groups()[1:])) for line in path.read_text().splitlines() if (m := pattern.match(line))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m exercises.paired", description=__doc__.split("\n")[0])
    p.add_argument("a", help="a row of Table 3 (tarl, sac-lag, lattice-idm, tarl-step1, ...)")
    p.add_argument("b", help="another row")
    p.add_argument("--scenario", choices=("intersection", "roundabout"), default="roundabout")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--runs", type=Path, nargs="+", default=[ROOT / "results" / "runs"],
                   help="folders of SCENARIO-ALGO-sK runs, searched in order")
    p.add_argument("--budget", default="", help="runs of another budget, named SCENARIO-ALGO-sK-BUDGET (500k)")
    p.add_argument("--bootstrap", type=int, default=10_000, help="bootstrap resamples")
    p.add_argument("--seed", type=int, default=0, help="the bootstrap's random seed")
    args = p.parse_args(argv)
    rng, table = np.random.default_rng(args.seed), ROOT / "results" / "table3.md"
    known = table3_counts(table, args.scenario, args.b) if args.a == "tarl" and not args.budget else {}
    print(f"{args.a} (A) against {args.b} (B) on the {args.scenario}, the same test cases seed by seed")
    print(f"{'seed':<8}{'cases':>7}{'success A':>11}{'success B':>11}{'only A arrives: B coll. / t.o.':>32}"
          f"{'only B arrives: A coll. / t.o.':>32}{'McNemar p':>12}{'A - B, 95 % over rounds resampled':>36}")
    total, diffs, agree = np.zeros(4, int), [], []
    for seed in args.seeds:
        a, b = (find_row(args.runs, args.scenario, algo, seed, args.budget) for algo in (args.a, args.b))
        if a is None or b is None:
            print(f"{seed:<8}no eval.json has {args.a if a is None else args.b} for seed {seed} in {', '.join(map(str, args.runs))}")
            continue
        pairs = matched(a, b)
        if any(x["start"] != y["start"] for x, y in pairs):
            print(f"{seed:<8}the two rows did not meet the same test cases (their start fingerprints differ)")
            return 1
        only = discordant(pairs)
        counts = np.array([only["arrival", "collision"], only["arrival", "timeout"], only["collision", "arrival"],
                           only["timeout", "arrival"]])
        total += counts
        diffs.append(per_round_difference(a, b))
        mean, low, high = bootstrap(diffs[-1:], args.bootstrap, rng)
        success = [np.mean([c[k]["outcome"] == "arrival" for c in pairs]) for k in (0, 1)]
        print(f"{seed:<8}{len(pairs):>7}{success[0]:>11.3f}{success[1]:>11.3f}{f'{counts[0]} / {counts[1]}':>32}"
              f"{f'{counts[2]} / {counts[3]}':>32}{p_text(mcnemar(counts[:2].sum(), counts[2:].sum())):>12}"
              f"{f'{mean:+.3f} [{low:+.3f}, {high:+.3f}]':>36}")
        if seed in known:
            agree.append((seed, tuple(counts) == known[seed]))
    if len(diffs) > 1:
        mean, low, high = bootstrap(diffs, args.bootstrap, rng)
        print(f"{'pooled':<8}{'':>7}{'':>11}{'':>11}{f'{total[0]} / {total[1]}':>32}{f'{total[2]} / {total[3]}':>32}"
              f"{p_text(mcnemar(total[:2].sum(), total[2:].sum())):>12}{f'{mean:+.3f} [{low:+.3f}, {high:+.3f}]':>36}")
        seeds = np.array([d.mean() for d in diffs])
        print(f"over seeds: A - B = {' '.join(f'{d:+.3f}' for d in seeds)}, mean {seeds.mean():+.3f}, std {seeds.std(ddof=1):.3f}; "
              f"sign-flip test over the {len(seeds)} seeds p = {sign_flip(seeds):.2g} (the smallest possible: "
              f"{2 / 2 ** len(seeds):.2g})")
    if agree:
        same = [s for s, ok in agree if ok]
        print(f"results/table3.md's Case by case: the same counts for seed{'s' * (len(same) != 1)} "
              f"{', '.join(map(str, same)) or 'none'}" + "".join(f"; seed {s} DIFFERS" for s, ok in agree if not ok))
        if not all(ok for _, ok in agree):
            return 1
    return 0 if diffs else 1


if __name__ == "__main__":
    sys.exit(main())
