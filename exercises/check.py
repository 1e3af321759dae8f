"""Check an exercise:  python -m exercises.check N [--solution | --file PATH] [--in-vivo]   (N = 1..5, or bughunt)

Runs exercise N's checks, function by function, on the student's file exercises/exN_*.py (--solution:
on the reference answer in exercises/solutions/; --file: on any file). The checks use values worked
out by hand and the answers stored in exercises/data/exN.npz (make_data.py), never the project's
code, so they still work where a course has blanked the reference. Prints what is wrong (and, where a
known mistake fits, asks about it); exits 0 when every check passes, 1 otherwise.

--in-vivo: instead, the file's functions drive the shipped roundabout TARL policy in the simulation, case
by case against the project's stored run (in_vivo.py; it needs SUMO and torch, ~10 s).
"""
from __future__ import annotations

import argparse
import importlib.util
import itertools
import math
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:  # a checked file may import exercises.* from anywhere
    sys.path.insert(0, str(HERE.parent))

from exercises.common import CFG, K1, OMEGA, Wrong, expect, expect_all, expect_shape, show  # noqa: E402

# ---- Exercise 1: Eqs. (6)-(8), (11)-(12) -----------------------------------------------------------

SWAPPED = "is dt / T swapped? Eq. (6) has dt / T, which rises to 1 at dt = T"
NO_TANH = "is the division by tanh(w / 2) missing? It is what makes beta(T, T) exactly 1"
BLEND_SWAPPED = "does beta weigh a_base instead of a? Eq. (12): a_bar = beta a + (1 - beta) a_base"
FIRST_DISCOUNTED = "is the first reward discounted? Eq. (8) weighs reward dt by gamma^(dt - 1): the first by 1"


def check_beta(m, d):
    expect("beta(1, omega=6)", m.beta(1, omega=OMEGA), 1.0, "T = 1 executes the actor's action at once, in full",
           {NO_TANH: 0.99752738})
    expect("beta(4, 1, omega=6)", m.beta(4, 1, omega=OMEGA), 0.04517666, "Eq. (6) with T = 4, dt = 1, w = 6",
           {SWAPPED: 1.00248491, NO_TANH: 0.04742587})
    for w in (1.0, 3.0, 10.0):
        expect(f"beta(2, omega={w:g})", m.beta(2, omega=w), 0.5, "beta(2) = 1/2 for every w (PAPER.md, note 5)")
    T = np.arange(1, 11)
    expect("beta(T, T, omega=6) for T = 1..10", m.beta(T, T, omega=OMEGA), np.ones(10),
           "at dt = T the actor's action is executed in full", {NO_TANH: np.full(10, 0.99752738)})
    for w, want in zip(d["omegas"], d["beta"]):
        T, dt = d["beta_T"], d["beta_dt"]
        expect_all(f"beta(T, dt, omega={w:g}) on arrays of shape {T.shape}", m.beta(T, dt, omega=w), want,
                   lambda k: f"beta({T[k]}, {dt[k]}, omega={w:g})")


def check_blend(m, d):
    expect("blend(1.5, -2.0, 1.0)", m.blend(1.5, -2.0, 1.0), 1.5, "beta = 1: the actor's action alone", {BLEND_SWAPPED: -2.0})
    expect("blend(1.5, -2.0, 0.0)", m.blend(1.5, -2.0, 0.0), -2.0, "beta = 0: the base action alone", {BLEND_SWAPPED: 1.5})
    expect("blend(1.0, -1.0, 0.25)", m.blend(1.0, -1.0, 0.25), -0.5, "0.25 x 1 + 0.75 x (-1)", {BLEND_SWAPPED: 0.5})
    a, a_base, b = d["blend_a"], d["blend_a_base"], d["blend_b"]
    expect_all(f"blend on arrays of shape {a.shape}", m.blend(a, a_base, b), d["blend"],
               lambda k: f"blend({a[k]:.4f}, {a_base[k]:.4f}, {b[k]:.4f})")


def check_discounted_sum(m, d):
    expect("discounted_sum([1, 2, 3], 0.9)", m.discounted_sum([1.0, 2.0, 3.0], 0.9), 5.23, "Eq. (8): 1 + 0.9 x 2 + 0.81 x 3",
           {FIRST_DISCOUNTED: 4.707, "is gamma missing? Eq. (8) discounts the later steps": 6.0})
    expect("discounted_sum([0.5], 0.99)", m.discounted_sum([0.5], 0.99), 0.5, "T = 1: the step's reward itself",
           {FIRST_DISCOUNTED: 0.495})
    expect("discounted_sum(np.array([0.5, -20.0]), 0.99)", m.discounted_sum(np.array([0.5, -20.0]), 0.99), -19.3,
           "rewards may come as an array")
    for k, (r, n, g) in enumerate(zip(d["sum_rewards"], d["sum_lengths"], d["sum_gammas"])):
        expect(f"discounted_sum({show(r[:n])}, {g})", m.discounted_sum(list(r[:n]), g), d["sum"][k])


# ---- Exercise 2: Eqs. (27)-(31) -----------------------------------------------------------------

NAMES = ("front", "left front", "right front", "left rear", "right rear", "rear")
MIRROR = {"front": "front", "left front": "right front", "right front": "left front",
          "left rear": "right rear", "right rear": "left rear", "rear": "rear"}
FIELDS = ("presence", "d_hat", "v_hat", "phi_hat", "theta_hat")
BOUNDARIES = (-180.0, -150.0, -90.0, -30.0, 30.0, 90.0, 150.0, 180.0)
WRAP = "the rear sector wraps: it is (150, 210], so move phi <= -150 up by 360 deg before comparing"
HALF_OPEN = ("the sectors are (phi_low, phi_high]: open below, closed above, so a vehicle on a boundary "
             "belongs to the sector it closes (30 deg is front, 90 deg left front)")
ROUND = "compare phi rounded to 1e-9 deg: a vehicle on a boundary comes out of atan2 a hair to either side"
MOVED = "phi comes back moved into (-150, 210] (plus 360 where phi <= -150), so that phi_hat of Eq. (27) works in the rear too"
SIGN = ("is the sign of the position angle flipped? phi = atan2(y - y_ego, x - x_ego) - theta_ego, "
        "counter-clockwise: positive to the ego's left")
SECTOR_CASES = [(0.0, "front"), (60.0, "left front"), (-60.0, "right front"), (120.0, "left rear"),
                (-120.0, "right rear"), (170.0, "rear"), (-170.0, "rear"),  # inside a sector
                (30.0, "front"), (-30.0, "right front"), (90.0, "left front"), (-90.0, "right rear"),
                (150.0, "left rear"), (-150.0, "rear"), (180.0, "rear"),  # on a boundary
                (30.000001, "left front"), (-29.999999, "front"), (150.000001, "rear"), (-150.000001, "rear"),
                (30.0 + 1e-12, "front"), (-150.0 + 1e-12, "rear")]  # atan2's round-off on a boundary


def sector_of(m, phi):
    """(index, moved phi) of sector_index on phi, checked to be a pair."""
    out = m.sector_index(phi)
    if not (isinstance(out, tuple) and len(out) == 2):
        raise Wrong(f"sector_index({phi}) returned {out!r}: it should return (index, phi moved), two arrays")
    return np.asarray(out[0]), np.asarray(out[1], dtype=float)


def check_sector_index(m, d):
    for phi, want in SECTOR_CASES:
        index = sector_of(m, phi)[0]
        expect_shape(f"the shape of sector_index({phi!r})[0]", index, (), "a number in, a number (0-d array) out: keep phi's shape")
        got = NAMES[int(index)] if 0 <= int(index) < 6 else show(index)
        if got != want:
            edge = min(abs(phi - b) for b in BOUNDARIES)
            hint = ROUND if 0 < edge < 1e-9 else WRAP if want == "rear" else HALF_OPEN if edge == 0 else ""
            raise Wrong(f"sector_index({phi!r}) puts phi in '{got}' but it belongs to '{want}'" + (f": {hint}" if hint else ""))
    for phi, want in ((-170.0, 190.0), (60.0, 60.0), (-150.0, 210.0), (180.0, 180.0)):
        expect(f"sector_index({phi:g})[1]", sector_of(m, phi)[1], want, MOVED)
    grid = np.array([[0.0, 60.0], [-170.0, 180.0]])
    index, moved = sector_of(m, grid)
    expect("sector_index(np.array([[0, 60], [-170, 180]]))[0]", index, [[0, 1], [5, 5]], "vectorise over phi's shape")
    expect("sector_index(np.array([[0, 60], [-170, 180]]))[1]", moved, [[0.0, 60.0], [190.0, 180.0]], MOVED)
    phi = d["sector_phi"]
    index, moved = sector_of(m, phi)
    expect_all(f"sector_index on an array of shape {phi.shape}", index, d["sector_index"],
               lambda k: f"sector_index({phi[k]:.6f})[0]")
    expect_all(f"sector_index on an array of shape {phi.shape}", moved, d["sector_moved"],
               lambda k: f"sector_index({phi[k]:.6f})[1]", MOVED)


def observation(m, *args):
    obs = m.observe(*args, CFG)
    if obs is None:
        raise Wrong("observe returned None: is the return missing?")
    obs = np.asarray(obs, dtype=float)
    if obs.shape != (67,):
        raise Wrong(f"observe returned shape {obs.shape} but should return (67,): s_ego (7) then s_sur (6 x 2 x 5), Eq. (30)")
    return obs[:7], obs[7:].reshape(6, 2, 5)


def check_one_vehicle(m, deg, want, heading=0.7, ego_xy=(3.0, -2.0)):
    """A vehicle 20 m from the ego at deg [deg] from its heading, 5 m/s, heading the ego's way."""
    a = heading + math.radians(deg)
    other = np.array([[ego_xy[0] + 20.0 * math.cos(a), ego_xy[1] + 20.0 * math.sin(a), 5.0, heading]])
    s_sur = observation(m, np.array(ego_xy), heading, 3.0, 0, 0, other)[1]
    where = f"a vehicle 20 m away at {deg:+g} deg from the ego's heading (ego heading {heading} rad)"
    flags = np.argwhere(s_sur[:, :, 0] == 1.0)
    if len(flags) != 1 or s_sur[:, :, 0].sum() != 1.0:
        raise Wrong(f"{where}: {len(flags)} presence flags are 1 but exactly one should be (s_sur[i, 0, 0], Eq. (28))")
    i, j = flags[0]
    if NAMES[i] != want:
        hint = SIGN if NAMES[i] == MIRROR[want] != want else HALF_OPEN if deg in BOUNDARIES else (
            "phi is the direction of the vehicle from the ego, atan2(y - y_ego, x - x_ego), minus the ego's heading")
        raise Wrong(f"{where} is seen in '{NAMES[i]}' but should be in '{want}': {hint}")
    if j != 0:
        raise Wrong(f"{where} is in slot j = {j} of its sector but should be in slot 0, the nearest")
    phi_hat = 0.5 if deg not in BOUNDARIES or deg == 180 else 1.0
    for f, value, hint in ((1, 20.0 / 60.0, "d_hat = d / d_max, d_max = cfg.perception"),
                           (2, 5.0 / 16.0, "v_hat = v / v_max, v_max = cfg.v_norm"),
                           (3, phi_hat, "phi_hat = (phi - phi_low) / (phi_high - phi_low) with the sector's bounds, "
                                        "phi in (-150, 210] as sector_index moves it: 1/2 mid-sector, 1 on phi_high"),
                           (4, 0.5, "theta_hat = (theta - theta_ego + pi) / (2 pi): 1/2 for a vehicle heading the ego's way")):
        expect(f"{where}: s_sur['{want}', 0, {FIELDS[f]}]", s_sur[i, 0, f], value, hint, tol=1e-5)


def check_observe(m, d):
    s_ego, s_sur = observation(m, np.zeros(2), 0.0, 8.0, 2, 1, np.zeros((0, 4)))
    expect("observe with nobody around, task 2, zone 1, 8 m/s: s_ego", s_ego, [0, 0, 1, 0, 1, 0, 0.5],
           "Eq. (29): h1 the one-hot of the task (3), h2 of the zone (3), then v_ego / v_max (cfg.v_norm)", tol=1e-6)
    expect("observe with nobody around: s_sur", s_sur, np.zeros((6, 2, 5)), "an empty sector is all zeros")
    for deg, want in [(0, "front"), (60, "left front"), (-60, "right front"), (120, "left rear"), (-120, "right rear"),
                      (180, "rear"), (30, "front"), (-30, "right front"), (90, "left front"), (-90, "right rear"),
                      (150, "left rear"), (-150, "rear")]:
        check_one_vehicle(m, deg, want)
    wrap = "wrap theta - theta_ego into (-pi, pi] first (wrap_angle), so that theta_hat stays in [0, 1] (PAPER.md, note 12)"
    for turn, want in ((1.5 * math.pi, 0.25), (-1.5 * math.pi, 0.75)):
        other = np.array([[20.0 * math.cos(0.7), 20.0 * math.sin(0.7), 5.0, 0.7 + turn]])
        s_sur = observation(m, np.zeros(2), 0.7, 3.0, 0, 0, other)[1]
        expect(f"a vehicle ahead heading {turn / math.pi:+g} pi from the ego's heading: theta_hat", s_sur[0, 0, 4], want, wrap, tol=1e-5)
    # four vehicles straight ahead, at 30, 10, 20 (opposite heading) and 70 m
    others = np.array([[30.0, 0, 1, 0], [10.0, 0, 2, 0], [20.0, 0, 3, math.pi], [70.0, 0, 4, 0]])
    s_sur = observation(m, np.zeros(2), 0.0, 8.0, 2, 1, others)[1]
    expect("vehicles straight ahead at 30, 10, 20 and 70 m: s_sur['front'] (presence, d_hat, v_hat, phi_hat, theta_hat)",
           s_sur[0], [[1, 10 / 60, 2 / 16, 0.5, 0.5], [1, 20 / 60, 3 / 16, 0.5, 1.0]],
           "Eq. (28): the two nearest per sector, nearest first; the one 70 m away is beyond d_max", tol=1e-5)
    for k in range(int(d["scenes"])):
        scene = [d[f"scene{k}_{key}"] for key in ("ego_xy", "ego_heading", "ego_speed", "task", "zone", "others")]
        scene[3:5] = int(scene[3]), int(scene[4])
        s_ego, s_sur = observation(m, *scene)

        def name(idx):
            if idx[0] < 7:
                return f"observe(stored scene {k}: {len(scene[5])} vehicles): s_ego[{idx[0]}]"
            i, j, f = np.unravel_index(idx[0] - 7, (6, 2, 5))
            return f"observe(stored scene {k}: {len(scene[5])} vehicles): s_sur['{NAMES[i]}', {j}, {FIELDS[f]}]"

        expect_all(f"observe(stored scene {k})", np.concatenate([s_ego, s_sur.ravel()]), d[f"scene{k}_obs"], name, tol=1e-5)


def check_reward(m, d):
    for args, want, hint in (((True, False, 9.0, 1.0, 10.0), 20.0, "+20 on arrival"),
                             ((False, True, 9.0, 1.0, 10.0), -20.0, "-20 on a collision"),
                             ((True, True, 9.0, 1.0, 10.0), -20.0, "a collision is never an arrival: check collided first"),
                             ((False, False, 5.5, 1.0, 10.0), 0.25, "(5.5 - 1) / (10 - 1) x 0.5"),
                             ((False, False, 14.0, 1.0, 10.0), 0.5, "min(., 1): never more than 0.5 a step"),
                             ((False, False, 0.0, 1.0, 10.0), -0.5 / 9.0, "below v_min it is negative: Eq. (31) has no max(., 0)"),
                             ((False, False, 4.0, 2.0, 6.0), 0.25, "use the v_min and v_max passed in")):
        expect(f"reward{args}", m.reward(*args), want, hint)
    for case, want in zip(d["reward_cases"], d["reward"]):
        args = (bool(case[0]), bool(case[1]), *map(float, case[2:]))
        expect(f"reward{args}", m.reward(*args), want)


# ---- Exercise 3: Eqs. (18)-(19), (22)-(23), the FSM ------------------------------------------------

MAGNITUDE = ("is a_t1 the magnitude sqrt(l''^2 + d''^2), as printed? Then the planner could never brake: "
             "keep the sign of l''(t1) (PAPER.md, note 3)")


def quintic_value(c, t, n):
    """l^(n)(t) of Eq. (18) for c = (c1, ..., c6)."""
    return sum(c[k] * math.perm(5 - k, n) * t ** (5 - k - n) for k in range(6 - n))


def check_quintic_coefficients(m, d):
    l0, v0, a0, le, ve, ae, te = args = (2.0, 3.0, -1.0, 30.0, 5.0, 0.5, 4.0)
    c = m.quintic_coefficients(*args)
    expect_shape("quintic_coefficients(2, 3, -1, 30, 5, 0.5, 4).shape", c, (6,), "(c1, ..., c6) on the last axis")
    c = np.asarray(c, dtype=float)
    order = " (c1 multiplies t^5 and comes first, c6 the constant comes last)"
    rows = (("l(0) = c6", 0.0, 0, l0, "l_0", order), ("l'(0) = c5", 0.0, 1, v0, "v_l0", order),
            ("l''(0) = 2 c4", 0.0, 2, a0, "a_l0", ", so c4 = a_l0 / 2"), ("l(t_e)", te, 0, le, "l_e", ""),
            ("l'(t_e)", te, 1, ve, "v_le", ""), ("l''(t_e)", te, 2, ae, "a_le", ""))
    for row, (name, t, n, want, symbol, more) in enumerate(rows, 1):
        expect(f"with (l0, v_l0, a_l0, l_e, v_le, a_le, t_e) = (2, 3, -1, 30, 5, 0.5, 4): {name}", quintic_value(c, t, n),
               want, f"row {row} of Eq. (19) asks {name.split(' = ')[0]} = {symbol} = {want:g}{more}", tol=1e-7)
    expect("quintic_coefficients(0, 0, 0, 1, 0, 0, 1)", m.quintic_coefficients(0, 0, 0, 1, 0, 0, 1), [6, -15, 10, 0, 0, 0],
           "rest to rest over 1 m in 1 s is the smoothstep 6 t^5 - 15 t^4 + 10 t^3")
    grid = m.quintic_coefficients(0.0, np.arange(3.0)[:, None], 0.5, 10.0, np.arange(4.0), 0.0, 2.0)
    expect_all("quintic_coefficients(0, v0 (3, 1), 0.5, 10, ve (4,), 0, 2)", grid, d["quintic_grid"],
               lambda k: f"quintic_coefficients(0, v0={k[0]}, 0.5, 10, ve={k[1]}, 0, 2)[{k[2]}] (c{k[2] + 1})",
               "the arguments broadcast", tol=1e-7)
    batch = d["quintic_args"]
    expect_all(f"quintic_coefficients on arrays of shape {batch[0].shape}", m.quintic_coefficients(*batch), d["quintic"],
               lambda k: f"quintic_coefficients{tuple(round(float(x), 3) for x in batch[:, k[0]])}[{k[1]}] (c{k[1] + 1})", tol=1e-7)


def fsm(m, cost, drive_ids, stop_ids):
    out = m.state_machine(np.asarray(cost, dtype=float), drive_ids, stop_ids, K1)
    if not (isinstance(out, tuple) and len(out) == 2):
        raise Wrong(f"state_machine returned {out!r}: it should return (mode, index), e.g. ('drive', 3) or ('brake', None)")
    return str(out[0]), None if out[1] is None else int(out[1])


def check_state_machine(m, d):
    D, S = slice(0, 3), slice(3, 5)
    inf = math.inf
    for cost, want, hint in (
            ([5, 2, 1003, 0.5, 1], ("drive", 1), "drive along the cheapest drive candidate when it is collision-free "
                                                "(cost < K1), even if a stop candidate is cheaper"),
            ([1001, inf, 1002, 1004, 3], ("stop", 4), "no drive candidate is collision-free: slow down to stop along the "
                                                     "cheapest stop candidate, by its index in cost"),
            ([1001, 1000, inf, 1004, inf], ("brake", None), "collision-free means cost < K1 = 1000: nothing is, so brake"),
            ([inf] * 5, ("brake", None), "nothing is feasible: brake")):
        got = fsm(m, cost, D, S)
        if got != want:
            if want[0] == "stop" and got[0] == "brake":
                hint = "when no drive candidate is collision-free, try the stop candidates before braking in emergency"
            elif got[0] == want[0] and got[1] is not None and want[1] is not None:
                hint = "the index is the candidate's index in cost, not within its set (ids.start + ...)"
            raise Wrong(f"state_machine(cost = {cost}, drive 0-2, stop 3-4, K1 = 1000) = {got} but should be {want}: {hint}")
    modes = ("drive", "stop", "brake")
    for cost, mode, index in zip(d["fsm_cost"], d["fsm_mode"], d["fsm_index"]):
        want, got = (modes[mode], None if index < 0 else int(index)), fsm(m, cost, slice(0, 6), slice(6, 10))
        if got != want:
            raise Wrong(f"state_machine(cost = {show(cost)}, drive 0-5, stop 6-9, K1 = 1000) = {got} but should be {want}")


def check_base_acceleration(m, d):
    for (l_dd, a_idm), want, hint, wrong in (
            ((1.2, 0.7), 0.7, "Eq. (23): IDM caps a_t1, a_base = min(a_t1, a_IDM)", {}),
            ((0.4, 1.5), 0.4, "Eq. (23): min(a_t1, a_IDM)", {}),
            ((-1.3, 1.5), -1.3, "the chosen trajectory brakes", {MAGNITUDE: 1.3}),
            ((-2.0, -9.0), -3.0, "a_base stays within [a_min, a_max] = [cfg.a_min, cfg.a_max]", {}),
            ((5.0, math.inf), 2.0, "a_base stays within [a_min, a_max] = [cfg.a_min, cfg.a_max]", {})):
        expect(f"base_acceleration({l_dd}, {a_idm}, cfg with [a_min, a_max] = [-3, 2])", m.base_acceleration(l_dd, a_idm, CFG),
               want, hint, wrong)
    for l_dd, a_idm, want in zip(d["base_l_dd"], d["base_a_idm"], d["base"]):
        expect(f"base_acceleration({l_dd:.4f}, {a_idm:.4f}, cfg)", m.base_acceleration(float(l_dd), float(a_idm), CFG), want)


# ---- Exercise 4: Eqs. (24)-(26) -----------------------------------------------------------------

A = np.array([0.65, 0.125, 0.125, 0.125])
PRINTED_SIGNS = ("are all four terms added, as Eq. (24) is printed? Waiting (phi_eff) and braking (phi_comf) are costs: "
                 "U = a1 phi_safe - a2 phi_eff - a3 phi_comf + a4 phi_emo (PAPER.md, note 6)")
NO_CLIP = "Eq. (25) normalises each term by its range (cfg.gap_range, cfg.wait_range, 1, cfg.emotion_range) and saturates at 1"
NO_LEVEL_1 = ("does level 2 answer an ego that crosses? It answers the ego's level-1 choice, the ego's best reply "
              "to the human's level-0 choice")
SVO_SWAPPED = ("is the mixing the wrong way round? Eq. (26): U_svo = (1 - a_svo) U_self + a_svo U_oppo: "
               "a_svo = 0 is a purely selfish human")


def check_game_utility(m, d):
    u = m.game_utility
    expect("game_utility(a = (0.65, 0.125, 0.125, 0.125), gap=1.5, wait=1.5, decel=0.3, waited=0)", u(A, 1.5, 1.5, 0.3, 0.0, CFG),
           0.13875, "0.65 x 1.5/5 - 0.125 x 1.5/10 - 0.125 x 0.3 + 0.125 x 0/30", {PRINTED_SIGNS: 0.25125})
    expect("game_utility(a = (0.65, 0.125, 0.125, 0.125), gap=10, wait=20, decel=2, waited=60)", u(A, 10.0, 20.0, 2.0, 60.0, CFG),
           0.525, NO_CLIP)
    expect("game_utility(a = (0.65, 0.125, 0.125, 0.125), gap=0, wait=0, decel=0, waited=15)", u(A, 0.0, 0.0, 0.0, 15.0, CFG),
           0.0625, "phi_emo = waited / cfg.emotion_range (30 s)")
    terms = np.ones((4, 2, 2, 3))
    expect_shape("game_utility(alpha (3, 4), terms (2, 2, 3)).shape", u(np.tile(A, (3, 1)), *terms, CFG), (2, 2, 3),
                 "alpha (..., 4): alpha[..., 0] .. alpha[..., 3] broadcast with the terms")
    alpha, args = d["utility_alpha"], d["utility_args"]
    expect_all(f"game_utility on arrays of shape {alpha.shape}", u(alpha, *args, CFG), d["utility"],
               lambda k: f"game_utility({show(alpha[k[0]])}, gap={args[0, k[0]]:.3f}, wait={args[1, k[0]]:.3f}, "
                         f"decel={args[2, k[0]]:.3f}, waited={args[3, k[0]]:.3f})")


def check_outcome_terms(m, d):
    args = d["outcome_args"]
    got = m.outcome_terms(*args[:4], args[4].astype(int), args[5].astype(int), CFG)
    expect_all("outcome_terms", np.array(got, dtype=float), d["outcome"], lambda k: f"outcome_terms, term {k[0]}, case {k[1]}",
               "outcome_terms is given: did it change?")


def decide(m, t_h, t_e, waited_h=0.0, decel_h=0.3, alpha=A, svo=0.0):
    return int(np.asarray(m.level_k_decisions(np.array([t_h]), np.array([t_e]), np.array([decel_h]), np.array([0.3]),
                                              np.array([waited_h]), 0.0, np.array([alpha]), np.array([svo]), CFG))[0])


def check_level_k_decisions(m, d):
    choice = ("CROSS", "YIELD")
    impatient = np.array([0.5, 0.125, 0.125, 0.2])
    for kwargs, want, what, hint in (
            (dict(t_h=2.0, t_e=2.0), 1, "same arrival time, nobody has waited",
             "level 0: crossing leaves a 0 s gap (U = 0), yielding a 1.5 s gap (U = 0.139): YIELD; the ego's level-1 "
             "reply is CROSS, and the human's level-2 reply to that is to YIELD"),
            (dict(t_h=1.0, t_e=5.0), 0, "the human 4 s ahead of the ego", "it crosses at every level"),
            (dict(t_h=2.0, t_e=2.0, decel_h=1.5), 0, "same arrival, the human cannot stop (decel_h = 1.5)",
             "a human that cannot stop before the conflict point (decel_h > 1) crosses"),
            (dict(t_h=2.0, t_e=2.0, alpha=impatient), 1, "same arrival, an impatient human (a4 = 0.2) that has not waited",
             "yielding: U = 0.5 x 0.3 - 0.125 x 0.15 - 0.125 x 0.3 = 0.094 > crossing: U = 0"),
            (dict(t_h=2.0, t_e=2.0, alpha=impatient, waited_h=30.0), 0, "same arrival, an impatient human that has waited 30 s",
             "crossing now pays a4 x 30/30 = 0.2 > 0.094"),
            (dict(t_h=1.0, t_e=2.0, svo=0.1), 0, "the human 1 s ahead of the ego, a_svo = 0.1", NO_LEVEL_1),
            (dict(t_h=2.0, t_e=1.0, waited_h=10.0, svo=0.0), 0, "the ego 1 s ahead, the human has waited 10 s, a_svo = 0",
             SVO_SWAPPED)):
        got = decide(m, **kwargs)
        if got != want:
            raise Wrong(f"level_k_decisions, {what}: {choice[got] if got in (0, 1) else got} but should be {choice[want]}: {hint}")
    three = m.level_k_decisions(np.array([2.0, 1.0, 2.0]), np.array([2.0, 5.0, 2.0]), np.array([0.3, 0.3, 1.5]),
                                np.full(3, 0.3), np.zeros(3), 0.0, np.tile(A, (3, 1)), np.zeros(3), CFG)
    expect("level_k_decisions on the three humans above at once", three, [1, 0, 0], "vectorise over the M humans")
    for b in (0, 1):
        g = {key: d[f"game{b}_{key}"] for key in ("t_h", "t_e", "decel_h", "decel_e", "waited_h", "waited_e", "alpha_h", "svo")}
        g["waited_e"] = float(g["waited_e"])
        expect_all(f"level_k_decisions on {len(g['t_h'])} stored games", m.level_k_decisions(**g, cfg=CFG), d[f"game{b}_decision"],
                   lambda k: (f"level_k_decisions on stored game {k[0]} (t_h = {g['t_h'][k]:.3f}, t_e = {g['t_e'][k]:.3f}, "
                              f"decel_h = {g['decel_h'][k]:.3f}, decel_e = {g['decel_e'][k]:.3f}, waited_h = {g['waited_h'][k]:g}, "
                              f"waited_e = {g['waited_e']:g}, alpha_h = {show(g['alpha_h'][k[0]])}, a_svo = {g['svo'][k]:.3f})"),
                   "0 is CROSS, 1 YIELD")


# ---- Exercise 5: Eq. (9) ------------------------------------------------------------------------

GAMMA_NOT_K = ("is the discount gamma? A decision of k steps is discounted by gamma^k (Eq. (9)), "
               "k the number of steps actually played")
TIME_LIMIT = ("is done set at the time limit? The time limit is not a terminal: the state it cuts still has a value, "
              "so the target bootstraps (done = 0); only arrival and collision end the task")
TERMINAL = "arrival and collision are true terminals: done = 1"
BOTH = ("does the time limit cancel a terminal? With terminated and truncated both true (Gymnasium allows it: an "
        "arrival or collision on the step the time runs out) the task did end, nothing follows: done = 1, "
        "as for any terminal (world.DrivingEnv reports such a step as terminated only)")
EXPECTATION = ("is it a max over T'? The soft value is the expectation over T' ~ pi(.|s'), sum_T' pi(T'|s') [...], "
               "as in SAC, not DQN's max (PAPER.md, note 7)")
ENTROPY = "the soft value subtracts alpha log pi(T'|s') inside the expectation"


def transition(m, rewards, gamma, terminated, truncated):
    out = m.timing_transition(rewards, gamma, terminated, truncated)
    if not (isinstance(out, tuple) and len(out) == 3):
        raise Wrong(f"timing_transition returned {out!r}: it should return (r_T, discount, done)")
    return out


def check_timing_transition(m, d):
    for args, what, want, hints in (
            (([1.0, 2.0, 3.0], 0.9, False, False), "a decision of T = 3 steps played in full", (5.23, 0.729, 0.0),
             ({FIRST_DISCOUNTED: 4.707}, {GAMMA_NOT_K: 0.9}, {})),
            (([1.0, 2.0], 0.9, True, False), "a decision of T = 3 cut after k = 2 steps by an arrival", (2.8, 0.81, 1.0),
             ({}, {GAMMA_NOT_K: 0.9}, {TERMINAL: 0.0})),
            (([1.0, 2.0], 0.9, False, True), "a decision of T = 3 cut after k = 2 steps by the time limit", (2.8, 0.81, 0.0),
             ({}, {GAMMA_NOT_K: 0.9}, {TIME_LIMIT: 1.0})),
            (([1.0, 2.0], 0.9, True, True), "a decision of T = 3 cut after k = 2 steps by a collision as the time runs out",
             (2.8, 0.81, 1.0), ({}, {GAMMA_NOT_K: 0.9}, {BOTH: 0.0}))):
        got = transition(m, *args)
        for name, g, w, wrong in zip(("r_T", "discount", "done"), got, want, hints):
            expect(f"timing_transition{args}, {what}: {name}", float(g), w, "", wrong)
    for k in range(len(d["lengths"])):
        n, term, trunc = int(d["lengths"][k]), bool(d["terminated"][k]), bool(d["truncated"][k])
        rewards = [float(r) for r in d["rewards"][k, :n]]
        got = transition(m, rewards, 0.99, term, trunc)
        for name, g, w, hint in zip(("r_T", "discount", "done"), got, (d["r_T"][k], d["discount"][k], d["done"][k]),
                                    ("", GAMMA_NOT_K, BOTH if term and trunc else TIME_LIMIT if trunc else TERMINAL)):
            expect(f"timing_transition({show(np.array(rewards))}, 0.99, terminated={term}, truncated={trunc}): {name}",
                   float(g), w, hint)


def target(m, q1, q2, probs, alpha=0.0, r=1.0, discount=0.9, done=0.0):
    """y of one decision with n = len(probs) timings."""
    y = m.timing_td_target(np.array([r]), np.array([discount]), np.array([done]), np.array([[q1], [q2]], dtype=float),
                           np.array([probs]), np.log(np.array([probs])), alpha)
    return np.asarray(y, dtype=float)


def check_timing_td_target(m, d):
    p = [0.5, 0.25, 0.25]
    expect("timing_td_target, r_T = 1, done = 1", target(m, [1, 2, 3], [1, 2, 3], p, done=1.0), [1.0],
           "at a true terminal nothing follows: y = r_T")
    expect("timing_td_target, r_T = 1, discount 0.9, Q-hat_1 = Q-hat_2 = (1, 2, 3), pi = (0.5, 0.25, 0.25), alpha = 0",
           target(m, [1, 2, 3], [1, 2, 3], p), [2.575], "1 + 0.9 (0.5 x 1 + 0.25 x 2 + 0.25 x 3)", {EXPECTATION: [3.7]})
    expect("timing_td_target, r_T = 1, discount 0.9, Q-hat_1 = (1, 2, 3), Q-hat_2 = (2, 1, 4), pi = (0.5, 0.25, 0.25), alpha = 0",
           target(m, [1, 2, 3], [2, 1, 4], p), [2.35], "min over the two target critics, per T', then the expectation",
           {"is it the max of the two critics? SAC takes their min": [3.25],
            "is it the mean of the two critics? SAC takes their min": [2.8], EXPECTATION: [3.7]})
    H = -(0.5 * math.log(0.5) + 0.5 * math.log(0.25))
    expect("timing_td_target, r_T = 1, discount 0.9, Q-hat = (1, 1, 1), pi = (0.5, 0.25, 0.25), alpha = 0.5",
           target(m, [1, 1, 1], [1, 1, 1], p, alpha=0.5), [1 + 0.9 * (1 + 0.5 * H)], ENTROPY,
           {"is the sign of alpha log pi flipped? The entropy bonus is - alpha log pi": [1 + 0.9 * (1 - 0.5 * H)],
            "is the entropy term missing? " + ENTROPY: [1.9]})
    expect("timing_td_target, r_T = 1, discount 0.5 (the transition's gamma^k), Q-hat = (1, 2, 3), pi = (0.5, 0.25, 0.25), alpha = 0",
           target(m, [1, 2, 3], [1, 2, 3], p, discount=0.5), [1.875], "use the discount given: it is gamma^k of the transition")
    args = (d["rew32"], d["discount32"], d["done32"], d["q_next"], d["probs"], d["log_probs"], float(d["alpha"]))
    expect_all(f"timing_td_target on a stored batch of {len(d['y'])} (n = {d['probs'].shape[1]})", m.timing_td_target(*args), d["y"],
               lambda k: f"timing_td_target on the stored batch: y[{k[0]}] (r_T = {args[0][k]:.4f}, discount = {args[1][k]:.4f}, "
                         f"done = {args[2][k]:g})", tol=1e-5)


# ---- The runner -----------------------------------------------------------------------------------

EXERCISES = {  # key: (file stem, title, data, checks)
    "1": ("ex1_timing", "the timing factor and the blend, Eqs. (6)-(8), (11)-(12)", "ex1",
          [("beta", check_beta), ("blend", check_blend), ("discounted_sum", check_discounted_sum)]),
    "2": ("ex2_observation", "what the ego sees and earns, Eqs. (27)-(31)", "ex2",
          [("sector_index", check_sector_index), ("observe", check_observe), ("reward", check_reward)]),
    "3": ("ex3_base_action", "the base action, Eqs. (18)-(19), (22)-(23) and the FSM", "ex3",
          [("quintic_coefficients", check_quintic_coefficients), ("state_machine", check_state_machine),
           ("base_acceleration", check_base_acceleration)]),
    "4": ("ex4_level_k", "the level-k humans, Eqs. (24)-(26)", "ex4",
          [("game_utility", check_game_utility), ("outcome_terms", check_outcome_terms),
           ("level_k_decisions", check_level_k_decisions)]),
    "5": ("ex5_timing_target", "the timing taker's critic target, Eq. (9)", "ex5",
          [("timing_transition", check_timing_transition), ("timing_td_target", check_timing_td_target)]),
    "bughunt": ("bughunt_observe", "the bug hunt: the observation of Eqs. (27)-(30)", "ex2",
                [("sector_index", check_sector_index), ("observe", check_observe)]),
}


BUG_NOT_FIXED = "not fixed yet: it still disagrees with Eqs. (27)-(28) on vehicles placed by hand around the ego"


@dataclass
class Result:
    ok: bool
    report: str


def path_of(key: str, solution: bool = False) -> Path:
    """The student's file of exercise `key`, or its reference solution."""
    stem = EXERCISES[key][0]
    if solution:
        return HERE / "solutions" / ("ex2_observation.py" if key == "bughunt" else f"{stem}.py")
    return HERE / f"{stem}.py"


_loaded = itertools.count()


def load(path: Path):
    """Import the file at path as a fresh module (a file checked twice is read twice)."""
    spec = importlib.util.spec_from_file_location(f"_checked_{path.stem}_{next(_loaded)}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def nice(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def run(key, path: str | Path | None = None) -> Result:
    """Every check of exercise `key` on the file at path (default: the student's file)."""
    key = str(key)
    stem, title, data_name, checks = EXERCISES[key]
    path = Path(path) if path else path_of(key)
    lines = [f"Exercise {key}: {title}, on {nice(path)}"]
    try:
        module = load(path)
    except Exception as e:  # noqa: BLE001: whatever the file does wrong, say it
        return Result(False, "\n".join(lines + [f"  FAIL  could not import it: {type(e).__name__}: {e}"]))
    data_path = HERE / "data" / f"{data_name}.npz"
    if not data_path.exists():
        return Result(False, "\n".join(lines + [f"  FAIL  {nice(data_path)} is missing: python -m exercises.make_data"]))
    failed = 0
    with np.load(data_path) as data:
        data = dict(data)
    for name, check in checks:
        if not hasattr(module, name):
            lines.append(f"  FAIL  {name}: the file defines no {name}")
            failed += 1
            continue
        try:
            with np.errstate(all="ignore"):
                check(module, data)
            lines.append(f"  ok    {name}")
        except NotImplementedError as e:
            lines.append(f"  TODO  {name}: not implemented yet ({e})")
            failed += 1
        except Wrong as e:  # the bug hunt's checker only says whether it is fixed: the details would give it away
            lines.append(f"  FAIL  {name}: " + (BUG_NOT_FIXED if key == "bughunt" else str(e)))
            failed += 1
        except Exception as e:  # noqa: BLE001
            frames = [f for f in traceback.extract_tb(e.__traceback__) if Path(f.filename).resolve() == path.resolve()]
            where = f" (line {frames[-1].lineno}: {frames[-1].line})" if frames else ""
            lines.append(f"  FAIL  {name}: raised {type(e).__name__}: {e}{where}")
            failed += 1
    lines.append(f"All {len(checks)} checks pass: exercise {key} is done." if not failed
                 else f"{failed} of {len(checks)} do not pass yet.")
    return Result(failed == 0, "\n".join(lines))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m exercises.check", description=__doc__.split("\n\n")[0])
    parser.add_argument("exercise", choices=list(EXERCISES), help="1-5, or bughunt")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--solution", action="store_true", help="check the reference solution instead")
    which.add_argument("--file", type=Path, help="check this file instead")
    parser.add_argument("--in-vivo", action="store_true", help="drive the shipped roundabout TARL policy with the "
                        "file's functions, case by case against the project's stored run (1-4, bughunt)")
    parser.add_argument("--cases", type=int, default=20, help="with --in-vivo: the first CASES of the 20 stored test cases")
    args = parser.parse_args(argv)
    if args.cases < 1:
        parser.error("--cases must be at least 1")
    path = args.file or path_of(args.exercise, args.solution)
    if args.in_vivo:
        from exercises import in_vivo
        if args.exercise in in_vivo.NO_IN_VIVO:
            return print(f"Exercise {args.exercise} in vivo: {in_vivo.NO_IN_VIVO[args.exercise]}") or 1
        try:
            module = load(path)
        except Exception as e:  # noqa: BLE001
            return print(f"could not import {nice(path)}: {type(e).__name__}: {e}") or 1
        return 0 if in_vivo.run(args.exercise, module, nice(path), args.cases) else 1
    result = run(args.exercise, path)
    print(result.report)
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
