"""Tests of world.py: the paper's math of the world by hand (sectors, observation, reward, the game)."""
import math

import numpy as np
import pytest

import world
from world import CROSS, YIELD, EnvConfig

CFG = EnvConfig()


# ---- Eq. (28): sectors --------------------------------------------------------------------

@pytest.mark.parametrize("phi, sector", [
    (30.0, "front"), (-30.0, "right front"), (90.0, "left front"), (-90.0, "right rear"),
    (150.0, "left rear"), (-150.0, "rear"), (180.0, "rear"), (0.0, "front"),
    (30.000001, "left front"), (-29.999999, "front"), (150.000001, "rear"), (-150.000001, "rear"),
])
def test_sector_half_open_intervals(phi, sector):
    assert world.SECTOR_NAMES[world.sector_index(phi)[0]] == sector


@pytest.mark.parametrize("deg", [-150, -90, -30, 30, 90, 150, 180])
def test_vehicle_on_a_boundary_angle_lands_in_the_papers_sector(deg):
    """A vehicle placed on each boundary angle, through observe(): (lo, hi] puts it in the lower sector."""
    ego_heading = 0.7  # [rad] any heading: angles are relative to it
    a = ego_heading + math.radians(deg)
    other = np.array([[20.0 * math.cos(a), 20.0 * math.sin(a), 5.0, ego_heading]])
    obs = world.observe(np.zeros(2), ego_heading, 3.0, 0, 0, other, CFG)
    s_sur = obs[7:].reshape(6, 2, 5)
    expected = {-150: "rear", -90: "right rear", -30: "right front", 30: "front",
                90: "left front", 150: "left rear", 180: "rear"}[deg]
    i = world.SECTOR_NAMES.index(expected)
    assert s_sur[i, 0, 0] == 1.0 and s_sur[:, :, 0].sum() == 1.0
    assert s_sur[i, 0, 1] == pytest.approx(20.0 / 60.0)
    # on its sector's upper bound phi_high; 180 deg is the middle of the rear sector (150, 210]
    assert s_sur[i, 0, 3] == pytest.approx(0.5 if deg == 180 else 1.0, abs=1e-6)
    assert s_sur[i, 0, 4] == pytest.approx(0.5)  # same heading as the ego


def test_observation_keeps_two_nearest_per_sector_and_ignores_far_vehicles():
    others = np.array([[30.0, 0, 1, 0], [10.0, 0, 2, 0], [20.0, 0, 3, math.pi], [70.0, 0, 4, 0]])
    obs = world.observe(np.zeros(2), 0.0, 8.0, 2, 1, others, CFG)
    assert obs.shape == (world.OBS_DIM,)
    np.testing.assert_array_equal(obs[:7], [0, 0, 1, 0, 1, 0, 8.0 / 16.0])
    front = obs[7:].reshape(6, 2, 5)[0]
    np.testing.assert_allclose(front[:, :3], [[1, 10 / 60, 2 / 16], [1, 20 / 60, 3 / 16]], rtol=1e-6)
    assert front[1, 4] == pytest.approx(1.0)  # opposite heading: (pi + pi) / 2pi
    assert obs[7:].reshape(6, 2, 5)[:, :, 0].sum() == 2  # the third and the one 70 m away are not seen


# ---- Eq. (31): reward ---------------------------------------------------------------------

def test_reward_cases():
    assert world.reward(True, False, 9.0, 1.0, 10.0) == 20.0
    assert world.reward(False, True, 9.0, 1.0, 10.0) == -20.0
    assert world.reward(True, True, 9.0, 1.0, 10.0) == -20.0  # a collision is never an arrival
    assert world.reward(False, False, 5.5, 1.0, 10.0) == pytest.approx(0.25)
    assert world.reward(False, False, 14.0, 1.0, 10.0) == 0.5  # min(., 1)
    assert world.reward(False, False, 0.0, 1.0, 10.0) == pytest.approx(-0.5 / 9.0)


# ---- collision boxes --------------------------------------------------------------------

def test_boxes_overlap_by_hand():
    L, W = 5.0, 2.0
    centers = np.array([[4.9, 0.0], [5.1, 0.0], [0.0, 1.9], [0.0, 2.1], [3.4, 0.0], [3.6, 0.0]])
    headings = np.array([0.0, 0.0, 0.0, 0.0, math.pi / 2, math.pi / 2])
    # end to end: 5 m apart touches; side by side: 2 m; T-bone: 2.5 + 1 = 3.5 m
    np.testing.assert_array_equal(world.boxes_overlap(np.zeros(2), 0.0, centers, headings, L, W),
                                  [True, False, True, False, True, False])


# ---- Eqs. (24)-(26): the level-k game, worked by hand --------------------------------------

A = np.array([[0.65, 0.125, 0.125, 0.125]])


def decide(t_h, t_e, waited_h=0.0, decel_h=0.3, alpha=A, svo=0.0, level=2):
    return world.level_k_decisions(np.array([t_h]), np.array([t_e]), np.array([decel_h]), np.array([0.3]),
                                  np.array([waited_h]), 0.0, alpha, np.array([svo]), CFG, level)[0]


def test_level_k_same_arrival_human_yields():
    # level 0 (ego goes on): cross -> gap 0, U = 0; yield -> wait to 3.5 s: gap 1.5 s,
    # U = .65 x .3 - .125 x .15 - .125 x .3 = .139 > 0: YIELD. Level 1 ego vs a yielding
    # human: cross U = .195, yield (standoff) U = 0 - .125 - .0375: CROSS. Level 2 = level 0: YIELD.
    assert decide(2.0, 2.0) == YIELD


def test_level_k_human_well_ahead_crosses():
    # human at 1 s, ego at 5 s: crossing keeps a 4 s gap (U = .52); yielding until 6.5 s
    # gives a 1.5 s gap and 5.5 s of waiting (U = .089): CROSS at every level
    assert decide(1.0, 5.0) == CROSS


def test_level_k_human_that_cannot_stop_crosses():
    assert decide(2.0, 2.0, decel_h=1.5) == CROSS


def test_level_k_impatient_human_goes_after_waiting():
    impatient = np.array([[0.5, 0.125, 0.125, 0.2]])
    # no wait yet: yield U = .5 x .3 - .01875 - .0375 = .094 > cross U = 0: YIELD
    assert decide(2.0, 2.0, waited_h=0.0, alpha=impatient) == YIELD
    # 30 s waited: cross U = .2 x 1 = .2 > .094: CROSS
    assert decide(2.0, 2.0, waited_h=30.0, alpha=impatient) == CROSS


def test_level_0_is_selfish_and_level_2_weighs_the_egos_gain_by_svo():
    # human at 2 s, having waited 10 s; ego at 1 s. Human, ego crossing: cross -> gap 1 s, U = .65 x .2
    # + .125 x 10 / 30 = .1717; yield until 2.5 s -> gap 1.5 s, .5 s wait, U = .195 - .00625 - .0375
    # = .1513. Level 0: CROSS. Ego (level 1) against that crossing human: cross U = .13, yield until
    # 3.5 s: U = .195 - .03125 - .0375 = .1263: CROSS. Level 2 against a crossing ego, svo = .5: cross
    # .5 x .1717 + .5 x .13 = .1508, yield .5 x .1513 + .5 x .195 (the ego's gap grows to 1.5 s) = .1731
    assert decide(2.0, 1.0, waited_h=10.0, svo=0.5, level=0) == CROSS
    assert decide(2.0, 1.0, waited_h=10.0, svo=0.5, level=2) == YIELD
    assert decide(2.0, 1.0, waited_h=10.0, svo=0.0, level=2) == CROSS  # without SVO level 2 agrees
    assert decide(2.0, 1.0, waited_h=10.0, svo=0.5, decel_h=1.5, level=2) == CROSS  # cannot stop: crosses
    assert decide(2.0, 1.0, waited_h=10.0, svo=0.5, decel_h=1.5, level=0) == CROSS


def test_level_1_replies_to_an_ego_that_expects_the_human_to_cross():
    # same arrival (test_level_k_same_arrival_human_yields): level 0 and 2 YIELD. The level-0 ego
    # against a crossing human is the level-0 human mirrored (same weights): YIELD; so the level-1
    # human crosses
    assert [decide(2.0, 2.0, level=k) for k in (0, 1, 2)] == [YIELD, CROSS, YIELD]
    with pytest.raises(ValueError, match="level"):
        decide(2.0, 2.0, level=-1)


def test_level_k_is_vectorised():
    d = world.level_k_decisions(np.array([2.0, 1.0, 2.0]), np.array([2.0, 5.0, 2.0]), np.array([0.3, 0.3, 1.5]),
                               np.array([0.3] * 3), np.zeros(3), 0.0, np.repeat(A, 3, 0), np.zeros(3), CFG)
    np.testing.assert_array_equal(d, [YIELD, CROSS, CROSS])



def test_level_k_payoff_tables_equal_one_utility_per_choice():
    """level_k_decisions evaluates Eq. (24) for all four choice pairs at once; here it is one pair at a
    time, level by level as Sec. 5.1 reads, on random games (a third of them exact arrival ties)."""
    rng = np.random.default_rng(0)
    ego_w = world.EGO_GAME_WEIGHTS

    def u(t_me, t_other, dec, waited, alpha, me, other):
        return world.game_utility(alpha, *world.outcome_terms(t_me, t_other, dec, waited, me, other, CFG), CFG)

    for trial in range(300):
        M = int(rng.integers(1, 9))
        t_h, t_e = rng.uniform(0.0, 12.0, M), rng.uniform(0.0, 12.0, M)
        if trial % 3 == 0:
            t_e = t_h.copy()
        dec_h, dec_e = rng.uniform(0.0, 1.5, M), rng.uniform(0.0, 1.5, M)
        w_h, w_e = rng.choice([0.0, 5.0, 40.0], M), float(rng.choice([0.0, 35.0]))
        alpha, svo = rng.uniform([0.5, 0.05, 0.05, 0.05], [0.8, 0.2, 0.2, 0.2], (M, 4)), rng.uniform(0.0, 0.5, M)
        c, y = np.full(M, CROSS), np.full(M, YIELD)
        h0 = np.where(u(t_h, t_e, dec_h, w_h, alpha, y, c) > u(t_h, t_e, dec_h, w_h, alpha, c, c), YIELD, CROSS)
        e1 = np.where(u(t_e, t_h, dec_e, w_e, ego_w, y, h0) > u(t_e, t_h, dec_e, w_e, ego_w, c, h0), YIELD, CROSS)

        def u_svo(me):
            return (1 - svo) * u(t_h, t_e, dec_h, w_h, alpha, me, e1) + svo * u(t_e, t_h, dec_e, w_e, ego_w, e1, me)

        expected = np.where(dec_h > 1.0, CROSS, np.where(u_svo(y) > u_svo(c), YIELD, CROSS))
        np.testing.assert_array_equal(world.level_k_decisions(t_h, t_e, dec_h, dec_e, w_h, w_e, alpha, svo, CFG),
                                      expected)

def test_arrival_time_by_hand():
    # 20 m from 0 m/s at 2 m/s^2 below the cap: sqrt(2 x 20 / 2) = 4.47 s; from 10 m/s at the cap: 2 s
    np.testing.assert_allclose(world.arrival_time(np.array([20.0, 20.0]), np.array([0.0, 10.0]), 2.0, 10.0),
                               [math.sqrt(20.0), 2.0])
