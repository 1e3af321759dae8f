"""analysis/claims.py, the claims' test of record, on hand-made tables with answers worked by hand: Student's paired t
over seeds, Holm's step-down over a family, equivalence by two one-sided tests, the seeds to settle, the plan, the
usage errors and the interim marking below the planned n."""
import math

import numpy as np
import pytest
from scipy import stats

from analysis import claims

# Three seeds a claim, + better. A's lead over B: 0.02, 0.03, 0.04 seed by seed (mean 0.03, std 0.01), though the
# rows' seeds spread twice as far (0.02 and 0.01): paired, t = 0.03 / (0.01 / sqrt 3) = sqrt 27 on 2 degrees of
# freedom, whose two-sided p is 1 - t / sqrt(t^2 + 2) = 1 - sqrt(27 / 29); unpaired, Welch's test sees no difference.
NEAR = ({0: 0.90, 1: 0.92, 2: 0.94}, {0: 0.88, 1: 0.89, 2: 0.90})
# Leads 0.10, 0.11, 0.12: t = 0.11 / (0.01 / sqrt 3) = sqrt 363, p = 1 - sqrt(363 / 365).
FAR = ({0: 0.90, 1: 0.92, 2: 0.94}, {0: 0.80, 1: 0.81, 2: 0.82})
# Leads 0.001, 0.002, 0.000: t = sqrt 3, p = 1 - sqrt(3 / 5); inside +-0.03 by far.
SAME = ({0: 0.901, 1: 0.912, 2: 0.920}, {0: 0.90, 1: 0.91, 2: 0.92})


def claim(pair, planned=range(3), margin=0.03, name=None):
    return dict(a=pair[0], b=pair[1], planned=planned, margin=margin, **({"name": name} if name else {}))


def test_the_paired_t_over_seeds_as_worked_by_hand():
    r = claims.paired_t(*NEAR, margin=0.03)
    assert (r["seeds"], r["n"]) == ([0, 1, 2], 3)
    assert r["d"] == pytest.approx(0.03) and r["sd"] == pytest.approx(0.01)
    assert r["p"] == pytest.approx(1 - math.sqrt(27 / 29))  # 0.0351
    half = stats.t.ppf(0.975, 2) * 0.01 / math.sqrt(3)  # 4.303 x 0.00577 = 0.0248
    assert r["ci"] == pytest.approx((0.03 - half, 0.03 + half))
    # TOST: against +0.03 the mean sits on the margin, t = 0, one-sided p = 1/2; against -0.03 far inside
    assert r["tost"] == pytest.approx(0.5)
    assert claims.welch(list(NEAR[0].values()), list(NEAR[1].values()))["p"] > 0.05  # unpaired: nothing seen
    # only the seeds both rows have, in seed order, whatever order the dicts hold them in
    a, b = {2: 0.94, 0: 0.90, 1: 0.92, 7: 0.5}, {1: 0.89, 0: 0.88, 2: 0.90, 9: 0.1}
    assert claims.paired_t(a, b)["p"] == pytest.approx(r["p"]) and claims.paired_t(a, b)["seeds"] == [0, 1, 2]


def test_holm_as_worked_by_hand():
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1: 0.02, 0.03, 0.06, 0.04 -> kept rising: 0.02, 0.03, 0.06, 0.06
    assert claims.holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert claims.holm([0.3, 0.6]) == pytest.approx([0.6, 0.6]) and claims.holm([0.9, 0.8]) == [1.0, 1.0]
    assert claims.holm([0.02]) == [0.02]  # a family of one: no adjustment
    # a claim not yet testable counts as p = 1: ranked last, so 0.01 is multiplied by 3 and 0.5 by 2
    adjusted = claims.holm([0.5, float("nan"), 0.01])
    assert adjusted[0] == pytest.approx(1.0) and math.isnan(adjusted[1]) and adjusted[2] == pytest.approx(0.03)
    assert claims.holm_levels([0.01, 0.04, 0.03]) == pytest.approx([0.05 / 3, 0.05, 0.05 / 2])


def test_a_family_holds_fails_is_equivalent_or_undecided_after_holm():
    """NEAR alone would hold (p 0.035); in a family of three its p is doubled (rank 2 of 3: 0.070) and it is
    undecided. FAR holds (0.0027 x 3), its mirror image fails, SAME is equivalent within +-0.03 (TOST's p,
    Holm-adjusted, far below 0.05) though its own p is 0.23."""
    single = claims.family([claim(NEAR)], np.random.default_rng(0))[0]
    assert single["verdict"] == "holds" and single["p_holm"] == pytest.approx(single["p"])
    near, far, same = claims.family([claim(NEAR), claim(FAR), claim(SAME)], np.random.default_rng(0))
    assert far["p"] == pytest.approx(1 - math.sqrt(363 / 365)) and far["p_holm"] == pytest.approx(3 * far["p"])
    assert near["p_holm"] == pytest.approx(2 * (1 - math.sqrt(27 / 29)))
    assert same["p"] == pytest.approx(1 - math.sqrt(3 / 5)) and same["p_holm"] == pytest.approx(same["p"])
    assert (far["verdict"], near["verdict"], same["verdict"]) == ("holds", "undecided", "equivalent within ±0.03")
    assert not any(r["interim"] for r in (near, far, same)) and far["settle"] is None is same["settle"]
    # NEAR's seeds to settle: at its Holm level, 0.05 / 2, the paired t's power at d / sd = 3 reaches 80 % there
    assert near["level"] == pytest.approx(0.025)

    def power(n, level):
        t, ncp = stats.t.ppf(1 - level / 2, n - 1), 3 * math.sqrt(n)
        return stats.nct.sf(t, n - 1, ncp) + np.nan_to_num(stats.nct.cdf(-t, n - 1, ncp))  # NaN: ~0, far tail

    assert power(near["settle"], 0.025) >= 0.8 > power(near["settle"] - 1, 0.025)
    mirror = claims.family([claim(FAR[::-1]), claim(NEAR)], np.random.default_rng(0))[0]
    assert mirror["verdict"] == "fails" and mirror["d"] == pytest.approx(-0.11)
    crossing = claims.family([claim(SAME, margin=None)], np.random.default_rng(0))[0]
    assert crossing["verdict"] == "undecided" and crossing["tost"] is None  # no margin: never equivalent


def test_seeds_to_settle_is_the_paired_t_tests_power():
    # an effect of one std of the differences needs 10 pairs for 80 % power at 0.05 two-sided, half a std 34
    # (the one-sample / paired t: 0.803 at 10, 0.808 at 34)
    assert claims.seeds_to_settle(1.0, 1.0) == 10 and claims.seeds_to_settle(0.5, 1.0) == 34
    assert claims.seeds_to_settle(-0.5, 1.0) == 34  # either direction
    assert claims.seeds_to_settle(0.5, 1.0, level=0.01) > 34  # a stricter level asks for more
    assert claims.seeds_to_settle(0.0, 1.0) is None and claims.seeds_to_settle(1e-4, 1.0) is None  # beyond 10,000
    # d / sd = 4 at 0.0125: 4 seeds give 0.897 in the near tail alone (3: 0.456); scipy's nct.cdf returns NaN for
    # the far tail there, which must not count as too little power
    t = stats.t.ppf(1 - 0.0125 / 2, 3)
    assert stats.nct.sf(t, 3, 8.0) > 0.8 and claims.seeds_to_settle(4.0, 1.0, level=0.0125) == 4


def test_a_claim_between_rows_with_no_common_seed_is_a_usage_error():
    with pytest.raises(ValueError, match="0 seed.* in common .none.: a paired test over seeds needs two or more"):
        claims.paired_t({0: 0.9, 1: 0.8}, {2: 0.7, 3: 0.6})
    with pytest.raises(ValueError, match="1 seed"):
        claims.paired_t({0: 0.9, 1: 0.8}, {1: 0.7, 3: 0.6})
    with pytest.raises(ValueError, match="mine against theirs: its rows have none of their planned seeds"):
        claims.family([claim(({0: 0.9, 1: 0.8}, {2: 0.7, 3: 0.6}), name="mine against theirs")],
                      np.random.default_rng(0))
    with pytest.raises(ValueError, match="its plan gives both rows 1 seed"):
        claims.family([claim(NEAR, planned=(0,))], np.random.default_rng(0))
    with pytest.raises(ValueError, match="needs two or more"):  # own_agent's test over seeds
        claims.seed_test({0: 0.9}, {0: 0.8}, 0.03, np.random.default_rng(0))


def test_below_its_planned_n_a_family_is_interim_and_calls_no_verdict():
    five = range(5)
    some = claims.family([claim(FAR, planned=five), claim(NEAR)], np.random.default_rng(0))
    # FAR has 3 of its 5 seeds: the whole family is interim, NEAR (complete) too; the numbers are there
    assert [r["verdict"] for r in some] == ["interim, n = 3 of 5", "interim, n = 3 of 3"]
    assert all(r["interim"] and r["settle"] is None for r in some)
    assert some[0]["p"] == pytest.approx(1 - math.sqrt(363 / 365)) and some[0]["ci"] is not None
    one = claims.family([claim(({0: 0.95}, {0: 0.93, 1: 0.9}), planned=five),
                         claim(({0: 0.9, 1: 0.8}, {0: 0.7, 1: 0.65}), planned=five)], np.random.default_rng(0))
    assert one[0]["verdict"] == "interim, n = 1 of 5" and one[0]["d"] == pytest.approx(0.02)
    assert one[0]["ci"] is None and math.isnan(one[0]["p"]) and math.isnan(one[0]["p_holm"])
    # the untestable claim counts as p = 1, ranked last: the testable one is first of two, its p doubled
    assert one[1]["verdict"] == "interim, n = 2 of 5" and one[1]["p_holm"] == pytest.approx(2 * one[1]["p"])
    # seeds beyond the plan stay out of the paired test (not out of the secondary one)
    extra = claims.family([claim(({**FAR[0], 3: 0.0}, {**FAR[1], 3: 1.0}))], np.random.default_rng(0))[0]
    assert extra["n"] == 3 and extra["verdict"] == "holds" and extra["n_all"] == (4, 4)


def test_the_plan_and_the_families():
    assert claims.planned(100_000, "intersection", "tarl", "sac-lattice") == tuple(range(10))
    assert claims.planned(100_000, "roundabout", "tarl", "sac-lattice") == (0, 1, 2)
    assert claims.planned(100_000, "intersection", "tarl", "sac-lag") == (0, 1, 2)
    assert claims.planned(100_000, "roundabout", "tarl", "tarl-random-t") == tuple(range(10))
    assert claims.planned(100_000, "intersection", "lattice-idm", "tarl") == tuple(range(10))
    assert len(claims.FAMILIES[100_000]) == 18 == len(set(claims.FAMILIES[100_000]))
    long = claims.FAMILIES[500_000]
    assert len(long) == 8 and set(long) < set(claims.CLAIMS)
    assert {(a, b) for _, a, b, _ in long} == {("tarl", "tarl-fixed-t"), ("tarl", "tarl-random-t"),
                                               ("tarl", "lattice-idm"), ("lattice-idm", "tarl")}
    assert all(claims.planned(500_000, s, a, b) == (0, 1, 2, 3, 4) for s, a, b, _ in long)


def test_the_secondary_tests_welch_and_the_probability_of_improvement_as_worked_by_hand():
    """Welch over every seed of each row: three seeds a row, stds 0.01 (ddof = 1), so its standard error is
    sqrt(0.01^2 / 3 + 0.01^2 / 3) = 0.00816 on 4 degrees of freedom: 95 % CI d +- 2.776 se. P(A > B): of the 6 pairs
    (3, 2) (3, 0) (2, 2) (2, 0) (1, 2) (1, 0), A wins 4 and ties 1: 4.5 / 6."""
    held = claims.welch([0.90, 0.91, 0.92], [0.80, 0.81, 0.82])
    assert held["d"] == pytest.approx(0.1) and held["ci"] == pytest.approx((0.0773, 0.1227), abs=1e-4)
    rng = np.random.default_rng(0)
    assert claims.improvement([3, 2, 1], [2, 0], rng)[0] == 0.75
    assert claims.improvement([1.0, 2.0], [0.0, 0.5], rng) == (1.0, 1.0, 1.0)  # every resample: A ahead
    both = claims.seed_test(*NEAR, 0.03, np.random.default_rng(0))  # one comparison: unadjusted, it holds
    assert both["verdict"] == "holds" and both["wins"] == (3, 3) and both["sign_flip"] == pytest.approx(0.25)
    assert both["welch"]["p"] > 0.05 and both["n_all"] == (3, 3)
