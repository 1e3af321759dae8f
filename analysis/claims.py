"""The paper's claims as families of paired tests over seeds: the test of record of docs/RESULTS.md's claims tables
(bench/table3.py reads the eval.json files and calls `family`) and of bench/own_agent.py's comparison over seeds
(`seed_test`). Numpy and scipy.stats only.

The rule, written down before the tests it judges:

- A claim "A does better than B" (success: higher; crossing time: lower) in one scenario at one budget compares
  the two rows on the seeds both have, paired by seed: seed k's rows met seed k's test cases. Its test of record is
  Student's paired t on the per-seed differences d_k = A_k - B_k, + in the claim's order (scipy.stats.ttest_rel),
  with its 95 % CI; n is the number of those seeds. A claim with fewer than two seeds in common has no test: a usage
  error. Welch's test over every seed of each row (`welch`) stands beside it, secondary.
- The claims of one table are one family: their two-sided p are adjusted by Holm's step-down (`holm`). A claim
  holds (mean difference > 0) or fails (< 0) where its adjusted p < ALPHA. Otherwise it is equivalent within
  ±margin where the two one-sided paired tests against ±margin (TOST: the larger of their p, Holm-adjusted over
  the family's claims that have a margin) give < ALPHA; crossing time has no margin. Otherwise undecided, with the
  seeds both rows would need (`seeds_to_settle`): the fewest at which the paired t at the claim's Holm level finds
  the observed mean difference with POWER, at the observed spread of the differences.
- Each claim has a planned n, fixed before its seeds were run (PLAN: the seeds the design gives both rows). The
  verdicts of record are those of a family whose every claim has all its planned seeds, tested once at that n,
  on those seeds. Before, the family is interim: its numbers are shown, its verdicts are not called.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from analysis.paired import BOOTSTRAP, sign_flip

ALPHA = 0.05  # the family's error rate: Holm-adjusted p below it holds or fails; TOST's likewise, equivalent
POWER = 0.8  # an undecided claim's seeds to settle it: those at which the paired t finds its difference this often
MARGIN = {"success_rate": 0.03}  # equivalence: the mean difference within +-MARGIN (TOST); crossing time has none
MOST_SEEDS = 10_000  # seeds_to_settle looks no further

# The paper's claims, each (scenario, A, B, measure), "A does better than B" in the measure, A the row the paper's
# Table 3 puts ahead (Lattice-IDM's success at the intersection, 0.896 against TARL's 0.881); for TARL against its
# two ablations, which the paper does not run, its thesis that learning when to act helps.
SCENARIOS = ("intersection", "roundabout")
ABLATIONS = ("tarl-fixed-t", "tarl-random-t")
CLAIMS = tuple((scenario, *(("lattice-idm", "tarl") if (scenario, other) == ("intersection", "lattice-idm")
                             else ("tarl", other)), "success_rate")
               for scenario in SCENARIOS
               for other in ("lattice-idm", "sac-lattice", "sac-lag", "sac-pid", "ppo-lag", "cpo", *ABLATIONS)) + tuple(
    (scenario, "tarl", "lattice-idm", "crossing_time") for scenario in SCENARIOS)
# The families, by training steps: every claim at 10^5; at 5 x 10^5 (the paper's budget) the thesis (TARL against its
# ablations) and TARL against its planner, Lattice-IDM, in success and crossing time, both scenarios.
FAMILIES = {100_000: CLAIMS,
            500_000: tuple(c for c in CLAIMS if {c[1], c[2]} & {*ABLATIONS, "lattice-idm"})}

# The design's seeds, the one place the plan is written: training steps -> (the seeds of every row, {(scenario, row):
# its own seeds}). At 10^5, seeds 0-2 for every row, 0-9 for TARL (its cell also evaluates Lattice-IDM and its step-1
# model), its two ablations, and SAC-Lattice and PPO-Lag at the intersection; at 5 x 10^5, seed 0 for every row and
# 0-4 for the rows of its family. A claim's planned seeds: those both its rows have (`planned`).
TEN = ("tarl", "tarl-step1", "lattice-idm", *ABLATIONS)
PLAN = {100_000: (range(3), {**{(s, algo): range(10) for s in SCENARIOS for algo in TEN},
                             ("intersection", "sac-lattice"): range(10), ("intersection", "ppo-lag"): range(10)}),
        500_000: (range(1), {(s, algo): range(5) for s in SCENARIOS for algo in ("tarl", "lattice-idm", *ABLATIONS)})}


def planned(steps: int, scenario: str, a: str, b: str) -> tuple[int, ...]:
    """The seeds the design (PLAN) gives both rows a and b of `scenario` at `steps` training steps."""
    every, own = PLAN[steps]
    return tuple(sorted(set(own.get((scenario, a), every)) & set(own.get((scenario, b), every))))


def holm(p) -> list[float]:
    """Holm's step-down adjustment of a family's p values (S. Holm, "A simple sequentially rejective multiple test
    procedure", Scand. J. Statist. 6, 65-70, 1979), in their order: sorted ascending, the i-th smallest (i = 1..m)
    is multiplied by m - i + 1, each kept at least the one before it, at most 1. Rejecting where the adjusted p is
    below alpha keeps the chance of any false rejection in the family at most alpha, whatever the dependence. A
    missing p (NaN: a claim not yet testable) counts as 1 and stays NaN."""
    p = np.asarray(p, dtype=float)
    m, order = len(p), np.argsort(np.where(np.isnan(p), 1.0, p), kind="stable")
    steps = np.maximum.accumulate(np.minimum(1.0, (m - np.arange(m)) * np.where(np.isnan(p), 1.0, p)[order]))
    out = np.empty(m)
    out[order] = steps
    return [float("nan") if np.isnan(q) else float(a) for q, a in zip(p, out)]


def holm_levels(p) -> list[float]:
    """Each p's level in Holm's step-down: ALPHA / (m - i + 1), i its rank among the family's p (ascending; a
    missing one last). The level an undecided claim's p would have to pass at its rank."""
    p = np.where(np.isnan(np.asarray(p, dtype=float)), 1.0, np.asarray(p, dtype=float))
    ranks = np.empty(len(p), int)
    ranks[np.argsort(p, kind="stable")] = np.arange(len(p))
    return [ALPHA / (len(p) - int(r)) for r in ranks]


def paired_t(a: dict, b: dict, margin: float | None = None, seeds=None) -> dict:
    """A against B paired by seed, a and b {seed: value, + better}, on `seeds` (default: every seed both have):
    seeds (in order), n, d (the mean of the differences A - B), sd (their std, ddof = 1), ci (95 %) and p
    (two-sided) of Student's paired t (scipy.stats.ttest_rel), diffs; with a margin, tost: the larger p of the two
    one-sided t-tests of the differences against -margin (alternative "greater") and +margin ("less"). ValueError
    under two seeds that both have: a paired test needs two."""
    seeds = sorted(a.keys() & b.keys() & (set(seeds) if seeds is not None else a.keys()))
    if len(seeds) < 2:
        raise ValueError(f"the two rows have {len(seeds)} seed(s) in common ({', '.join(map(str, seeds)) or 'none'}):"
                         " a paired test over seeds needs two or more")
    x, y = (np.array([v[k] for k in seeds], dtype=float) for v in (a, b))
    test, diffs = stats.ttest_rel(x, y), x - y
    tost = None if margin is None else max(stats.ttest_1samp(diffs, -margin, alternative="greater").pvalue,
                                           stats.ttest_1samp(diffs, margin, alternative="less").pvalue)
    return dict(seeds=seeds, n=len(seeds), d=float(diffs.mean()), sd=float(diffs.std(ddof=1)),
                ci=tuple(map(float, test.confidence_interval(1 - ALPHA))), p=float(test.pvalue),
                tost=None if tost is None else float(tost), diffs=diffs)


def welch(a, b) -> dict:
    """Welch's test of mean(a) - mean(b) over every seed of each row, unpaired (scipy.stats.ttest_ind,
    equal_var=False), the secondary test: d, its 95 % CI and p."""
    test = stats.ttest_ind(a, b, equal_var=False)
    return dict(d=float(np.mean(a) - np.mean(b)), ci=tuple(map(float, test.confidence_interval(1 - ALPHA))),
                p=float(test.pvalue))


def verdict(d: float, p: float, tost: float | None, margin: float | None, alpha: float = ALPHA) -> str:
    """"holds" (d > 0) or "fails" (d < 0) where p < alpha; else "equivalent within ±margin" where TOST's p < alpha
    (no margin, crossing time: never); else "undecided". In a family, p and tost as `holm` adjusts them."""
    if p < alpha and d != 0:
        return "holds" if d > 0 else "fails"
    return f"equivalent within ±{margin}" if margin and tost is not None and tost < alpha else "undecided"


def seeds_to_settle(d: float, sd: float, level: float = ALPHA) -> int | None:
    """The fewest seeds both rows need for the two-sided paired t at `level` to find a true mean difference d with
    POWER, the differences' std being sd: its power from the noncentral t (scipy.stats.nct), n - 1 degrees of
    freedom, noncentrality d sqrt(n) / sd. None at d = 0 or beyond MOST_SEEDS. The far tail, P(T < -t), is taken as
    P(T > t) at noncentrality -ncp: scipy's nct.cdf there returns NaN once ncp is large (scipy 1.17), which would
    count as too little power."""
    if d == 0:
        return None
    if sd == 0:
        return 2
    n = np.arange(2, MOST_SEEDS + 1)
    df, ncp = n - 1, abs(d) * np.sqrt(n) / sd
    t = stats.t.ppf(1 - level / 2, df)
    enough = n[stats.nct.sf(t, df, ncp) + stats.nct.sf(t, df, -ncp) >= POWER]
    return int(enough[0]) if len(enough) else None


def improvement(a, b, rng: np.random.Generator, resamples: int = BOOTSTRAP) -> tuple[float, float, float]:
    """P(A > B), the probability of improvement as rliable reports it (Agarwal et al., NeurIPS 2021): the chance that
    a run (seed) of A beats a run of B, ties counting 1/2 (Mann-Whitney's U / (n_a n_b)), with its 95 % percentile
    interval from the stratified bootstrap: each row's runs resampled on their own within each task (here one: a
    claim is one scenario). a, b: the seeds' values, + better."""
    a, b = np.asarray(a), np.asarray(b)
    prob = lambda x, y: (np.sign(x[..., :, None] - y[..., None, :]) + 1).mean(axis=(-2, -1)) / 2  # noqa: E731
    boot = prob(a[rng.integers(len(a), size=(resamples, len(a)))], b[rng.integers(len(b), size=(resamples, len(b)))])
    return float(prob(a, b)), *map(float, np.percentile(boot, [2.5, 97.5]))


def seed_test(a: dict, b: dict, margin: float | None, rng: np.random.Generator, level: float = ALPHA,
              seeds=None) -> dict:
    """One comparison over seeds, a and b {seed: value, + better}: `paired_t` on `seeds` (default: every seed both
    have; ValueError under two), its `verdict` at `level` unadjusted (a family of one, bench/own_agent.py's;
    `family` adjusts a table's), the seeds that would settle it if undecided (`seeds_to_settle` at `level`); A's
    wins over those seeds and the exact sign-flip p of their differences (analysis.paired.sign_flip); and over every
    seed of each row, secondary: n_all (the seeds of each), the means, `welch` and `improvement` (P(A > B) with its
    95 % interval). Each row's seeds are taken in seed order, whatever order the files were read in."""
    test = paired_t(a, b, margin, seeds)
    said = verdict(test["d"], test["p"], test["tost"], margin, level)
    return {**test, **secondary(a, b, rng), "verdict": said,
            "settle": seeds_to_settle(test["d"], test["sd"], level) if said == "undecided" else None,
            "wins": (int((test["diffs"] > 0).sum()), test["n"]), "sign_flip": sign_flip(test["diffs"])}


def secondary(a: dict, b: dict, rng: np.random.Generator | None) -> dict:
    """Over every seed of each row, unpaired: n_all, the means, `welch` (two or more seeds each) and, with a rng,
    `improvement`."""
    x, y = (np.array([seeds[k] for k in sorted(seeds)], dtype=float) for seeds in (a, b))
    return {"n_all": (len(x), len(y)), "means": (float(x.mean()), float(y.mean())),
            "welch": welch(x, y) if min(len(x), len(y)) >= 2 else None,
            "improvement": improvement(x, y, rng) if rng is not None else None}


def family(pairs: list[dict], rng: np.random.Generator) -> list[dict]:
    """A table's claims tested as one family. pairs: one dict per claim: a and b ({seed: value, + better}, every
    seed committed), planned (its planned seeds, `planned`), margin (or None) and optionally name (for errors). Each
    claim is tested on its planned seeds that both rows have (`seed_test`: seeds beyond the plan are left out of the
    paired test, not of the secondary one); `holm` adjusts the family's p (p_holm) and TOST's (tost_holm, over the
    claims with a margin).

    The family is of record once every claim has all its planned seeds: then each claim's verdict is `verdict` of
    the adjusted p and, if undecided, settle: its seeds to settle at its Holm level (`holm_levels`). Before, the
    family is interim (interim True): each verdict reads "interim, n = k of N", nothing is settled, and a claim with
    one seed so far has its one difference d and no test. ValueError, a usage error: a claim whose plan gives its
    rows fewer than two seeds in common, or whose rows have no planned seed in common yet."""
    done = []
    for c in pairs:
        plan, name = tuple(c["planned"]), c.get("name", "a claim")
        if len(plan) < 2:
            raise ValueError(f"{name}: its plan gives both rows {len(plan)} seed(s) in common "
                             f"({', '.join(map(str, plan)) or 'none'}): a paired test over seeds needs two or more")
        common = sorted(c["a"].keys() & c["b"].keys() & set(plan))
        if not common:
            raise ValueError(f"{name}: its rows have none of their planned seeds ({', '.join(map(str, plan))}) in "
                             "common yet: nothing to compare")
        if len(common) >= 2:
            r = seed_test(c["a"], c["b"], c["margin"], rng, seeds=plan)
        else:
            d = np.array([c["a"][common[0]] - c["b"][common[0]]], dtype=float)
            r = dict(seeds=common, n=1, d=float(d[0]), sd=None, ci=None, p=float("nan"), tost=None, diffs=d,
                     wins=(int(d[0] > 0), 1), sign_flip=None, **secondary(c["a"], c["b"], None))
        done.append({**r, "planned": plan, "margin": c["margin"]})
    interim = any(r["n"] < len(r["planned"]) for r in done)
    p = [r["p"] for r in done]
    p_holm, levels = holm(p), holm_levels(p)
    with_margin = [i for i, r in enumerate(done) if r["margin"] is not None]
    tost_holm = dict(zip(with_margin, holm([np.nan if done[i]["tost"] is None else done[i]["tost"]
                                            for i in with_margin])))
    for i, r in enumerate(done):
        r.update(p_holm=p_holm[i], tost_holm=tost_holm.get(i), level=levels[i], interim=interim)
        if interim:
            r.update(verdict=f"interim, n = {r['n']} of {len(r['planned'])}", settle=None)
        else:
            r["verdict"] = verdict(r["d"], r["p_holm"], r["tost_holm"], r["margin"])
            r["settle"] = seeds_to_settle(r["d"], r["sd"], r["level"]) if r["verdict"] == "undecided" else None
    return done
