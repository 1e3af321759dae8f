"""Paired statistics on the committed results (EXERCISES.md, lab 8): is one row of Table 3 better than another?

    python -m exercises.paired --scenario roundabout tarl sac-lag
    python -m exercises.paired --scenario roundabout tarl tarl-consistent --runs results/runs runs/hw/runs

Every row of Table 3 met the same test cases, seed by seed (results/runs/SCENARIO-ALGO-sK/eval.json: 10
rounds x 200 cases, each case's outcome). Two rows are compared on them, on every seed that has both
(or --seeds) and pooled, by `paired`, the project's one paired comparison:

  case by case   the cases where exactly one of the two arrives (the discordant pairs), split by how the
                 other failed: results/table3.md's "Case by case" counts, checked against it where it has them;
  McNemar        the exact test that the discordant pairs split 50:50 (no difference): two-sided
                 p = min(1, 2 P(X <= min(n_a, n_b))), X ~ Binomial(n_a + n_b, 1/2): scipy.stats.binomtest;
  bootstrap      the success difference (A - B, the mean over rounds of the per-round difference)
                 with a 95 % interval from resampling the cases within each round, seeded (--seed).

Pooled: McNemar on the seeds' discordant pairs summed; the bootstrap resamples each seed's cases and
averages the seeds. Both treat the seeds' models as fixed: two trained policies on the same cases, not
two methods; three trained models say little about a fourth. Over seeds, the question a claim "A is
better than B" asks: the seeds' mean differences and an exact sign-flip test on them (with n seeds its p
is at least 2 / 2^n: 0.25 for 3; docs/RESULTS.md's claims table shows it beside its paired t-test,
analysis/claims.py).
Numpy and scipy.stats only: no simulation.
"""
from __future__ import annotations

import argparse
import re
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from scipy import stats

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from analysis.compare import discordant, matched, read_row  # noqa: E402

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


def pairs_by_seed(runs: list[Path], scenario: str, a: str, b: str, budget: str = "", seeds=None) -> dict:
    """Rows A and B of each of `seeds` (None where no run has one); without `seeds`, of every seed in RUNS that
    has both (--seeds' default), each eval.json read once."""
    if seeds is not None:
        return {s: tuple(find_row(runs, scenario, algo, s, budget) for algo in (a, b)) for s in seeds}
    hosts = "|".join(re.escape(algo) for algo in {a, b, *HOSTS})
    name = re.compile(rf"{re.escape(scenario)}-(?:{hosts})-s(\d+){'-' + re.escape(budget) if budget else ''}")
    found = sorted({int(m[1]) for folder in runs if folder.is_dir() for run in folder.iterdir()
                    if (m := name.fullmatch(run.name))})
    return {s: ab for s, ab in pairs_by_seed(runs, scenario, a, b, budget, found).items() if None not in ab}


def common_seeds(runs: list[Path], scenario: str, a: str, b: str, budget: str = "") -> list[int]:
    """Every seed that has both rows in RUNS: --seeds' default."""
    return list(pairs_by_seed(runs, scenario, a, b, budget))


def mcnemar(n_a: int, n_b: int) -> float:
    """Exact two-sided McNemar p-value of n_a against n_b discordant pairs: the binomial test of n_a successes
    in n_a + n_b at p = 1/2."""
    n = int(n_a) + int(n_b)
    return float(stats.binomtest(int(n_a), n, 0.5).pvalue) if n else 1.0


def p_text(p: float) -> str:
    return f"{p:.2g}" if p > 0 else "< 1e-300"  # below the smallest double


def sign_flip(x: np.ndarray) -> float:
    """Exact two-sided sign-flip (permutation) test that the seeds' differences x have mean 0: the share of
    the 2^n sign patterns whose |mean| is at least the observed one (every pattern, not a sample of them)."""
    if len(x) < 2:
        return 1.0  # one seed: its two patterns have the same |mean|
    return float(stats.permutation_test((np.asarray(x, dtype=float),), np.mean, permutation_type="samples",
                                        n_resamples=np.inf).pvalue)


BOOTSTRAP = 10_000  # resamples of the paired interval


def paired(a: dict | list, b: dict | list, rng: np.random.Generator, resamples: int = BOOTSTRAP) -> dict:
    """A against B on the test cases both played: the project's one paired comparison (this module's command,
    bench/table3.py's paper's budget, bench/own_agent.py, bench/rollout_ceiling.py, bench/heldout.py).

    a, b: a row of eval.json each (compare.read_row), or lists of them seed by seed, pooled. Returns n (cases),
    mine and other (A's and B's success: the mean over rounds, then over seeds), counts (only A arrives: B collides
    / times out; only B arrives: A collides / times out), only_mine, only_other, p (McNemar's exact test on those),
    diff (mine - other) and low, high: its 95 % percentile interval, `resamples` resamples. ValueError if two rows
    played no case in common or a case began differently (its start fingerprint): not the same test cases.

    The resampling unit is the test case, within its round: each resample keeps every round's number of cases
    (and, pooled, every seed's rounds), and averages as the difference does. Why the case: the cases are what the
    comparison samples, the McNemar test beside the interval takes them as its independent draws, and the rounds
    add no spread of their own: a round's cases are snapshots of its traffic 30 s apart, each with its own route
    and departures, and the committed rows' per-round differences spread no more than their cases predict
    (tests/test_exercises.py checks it). Why not the round: a percentile bootstrap of 10 rounds is too narrow (about 0.8
    times the t interval of the same 10 values), and of the rollout ceiling's 2 rounds meaningless. Either way
    the trained policies are fixed: the interval says two policies differ on these cases, not two methods; the
    seeds say that (bench/table3.py's claims). A round's cases resampled with replacement are its counts of the
    three kinds of case (only B arrives, the same outcome, only A arrives) drawn from a multinomial: so they are
    drawn here.
    """
    a, b = ([a], [b]) if isinstance(a, dict) else (a, b)
    n, only, success, boot = 0, Counter(), [], []
    for x, y in zip(a, b, strict=True):
        pairs = matched(x, y)
        differ = sum(c["start"] != d["start"] for c, d in pairs)
        if differ or not pairs:
            raise ValueError(f"{differ} of {len(pairs)} cases began differently (start fingerprints): not the same "
                             "test cases" if pairs else "no case in common")
        arrived = np.array([(c["outcome"] == "arrival", d["outcome"] == "arrival") for c, d in pairs], float)
        rounds = np.array([c["round"] for c, _ in pairs])
        each = [arrived[rounds == r] for r in np.unique(rounds)]
        success.append([np.mean([np.mean(r[:, k]) for r in each]) for k in (0, 1)])  # as eval.json's mean
        kinds = [np.bincount((r[:, 0] - r[:, 1] + 1).astype(int), minlength=3) for r in each]
        draws = [rng.multinomial(k.sum(), k / k.sum(), size=resamples) for k in kinds]
        boot.append(np.mean([(d[:, 2] - d[:, 0]) / k.sum() for d, k in zip(draws, kinds)], axis=0))
        n, only = n + len(pairs), only + discordant(pairs)
    mine, other = np.mean(success, axis=0)
    counts = (only["arrival", "collision"], only["arrival", "timeout"], only["collision", "arrival"],
              only["timeout", "arrival"])
    low, high = np.percentile(np.mean(boot, axis=0), [2.5, 97.5])
    return dict(n=n, mine=float(mine), other=float(other), counts=counts, only_mine=sum(counts[:2]),
                only_other=sum(counts[2:]), p=mcnemar(sum(counts[:2]), sum(counts[2:])), diff=float(mine - other),
                low=float(low), high=float(high))


def table3_counts(path: Path, scenario: str, other: str) -> dict:
    """results/table3.md's "Case by case" counts of TARL against `other` at 10^5 steps: {seed: (4 counts)}."""
    if not path.exists() or other not in LABELS:
        return {}
    pattern = re.compile(rf"^\| 100,000 \| {scenario} \| (\d) \| {re.escape(LABELS[other])} \| (\d+) / (\d+) \| (\d+) / (\d+) \|$")
    return {int(m[1]): tuple(map(int, m.groups()[1:])) for line in path.read_text().splitlines() if (m := pattern.match(line))}


def result_line(name: str, r: dict, rates: bool = True) -> str:
    """One line of the command's table: a seed's (or, without `rates`, the pooled) result of `paired`."""
    cases, mine, other = (str(r["n"]), f"{r['mine']:.3f}", f"{r['other']:.3f}") if rates else ("", "", "")
    (a_collides, a_times_out), (b_collides, b_times_out) = r["counts"][2:], r["counts"][:2]
    interval = f"{r['diff']:+.3f} [{r['low']:+.3f}, {r['high']:+.3f}]"
    return (f"{name:<8}{cases:>7}{mine:>11}{other:>11}{f'{b_collides} / {b_times_out}':>32}"
            f"{f'{a_collides} / {a_times_out}':>32}{p_text(r['p']):>12}{interval:>36}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m exercises.paired", description=__doc__.split("\n")[0])
    p.add_argument("a", help="a row of Table 3 (tarl, sac-lag, lattice-idm, tarl-step1, ...)")
    p.add_argument("b", help="another row")
    p.add_argument("--scenario", choices=("intersection", "roundabout"), default="roundabout")
    p.add_argument("--seeds", type=int, nargs="+", help="default: every seed that has both rows")
    p.add_argument("--runs", type=Path, nargs="+", default=[ROOT / "results" / "runs"],
                   help="folders of SCENARIO-ALGO-sK runs, searched in order")
    p.add_argument("--budget", default="", help="runs of another budget, named SCENARIO-ALGO-sK-BUDGET (500k)")
    p.add_argument("--bootstrap", type=int, default=10_000, help="bootstrap resamples")
    p.add_argument("--seed", type=int, default=0, help="the bootstrap's random seed")
    args = p.parse_args(argv)
    pairs = pairs_by_seed(args.runs, args.scenario, args.a, args.b, args.budget, args.seeds)
    if not pairs:
        p.error(f"no seed has both {args.a} and {args.b} on the {args.scenario} in {', '.join(map(str, args.runs))}")
    rng, table = np.random.default_rng(args.seed), ROOT / "results" / "table3.md"
    known = table3_counts(table, args.scenario, args.b) if args.a == "tarl" and not args.budget else {}
    print(f"{args.a} (A) against {args.b} (B) on the {args.scenario}, the same test cases seed by seed")
    print(f"{'seed':<8}{'cases':>7}{'success A':>11}{'success B':>11}{'only A arrives: B coll. / t.o.':>32}"
          f"{'only B arrives: A coll. / t.o.':>32}{'McNemar p':>12}{'A - B, 95 % (cases resampled)':>36}")
    rows, diffs, agree = [], [], []
    for seed, (a, b) in pairs.items():
        if a is None or b is None:
            print(f"{seed:<8}no eval.json has {args.a if a is None else args.b} for seed {seed} in {', '.join(map(str, args.runs))}")
            continue
        try:
            r = paired(a, b, rng, args.bootstrap)
        except ValueError as e:
            print(f"{seed:<8}the two rows did not meet the same test cases: {e}")
            return 1
        print(result_line(str(seed), r))
        rows.append((a, b))
        diffs.append(r["diff"])
        if seed in known:
            agree.append((seed, r["counts"] == known[seed]))
    if len(rows) > 1:
        print(result_line("pooled", paired(*map(list, zip(*rows)), rng, args.bootstrap), rates=False))
        seeds = np.array(diffs)
        print(f"over seeds: A - B = {' '.join(f'{d:+.3f}' for d in seeds)}, mean {seeds.mean():+.3f}, std {seeds.std(ddof=1):.3f}; "
              f"sign-flip test over the {len(seeds)} seeds p = {sign_flip(seeds):.2g} (the smallest possible: "
              f"{2 / 2 ** len(seeds):.2g})")
    if agree:
        same = [s for s, ok in agree if ok]
        print(f"results/table3.md's Case by case: the same counts for seed{'s' * (len(same) != 1)} "
              f"{', '.join(map(str, same)) or 'none'}" + "".join(f"; seed {s} DIFFERS" for s, ok in agree if not ok))
        if not all(ok for _, ok in agree):
            return 1
    return 0 if rows else 1


if __name__ == "__main__":
    sys.exit(main())
