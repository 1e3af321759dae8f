"""Tests of planner.py: the quintic of Eqs. (18)-(19), IDM, the cost, the FSM and Eqs. (22)-(23),
the predictions at constant speed and yaw rate, and the base planner's behaviour."""
import numpy as np
import pytest

import planner
from planner import PlannerConfig, base_action, idm_acceleration, quintic_coefficients


def config(**changes) -> PlannerConfig:
    """A planner config with the environment's values (world.EnvConfig) for the required fields."""
    return PlannerConfig(dt=0.2, a_min=-3.0, a_max=2.0, length=5.0, width=2.0, **changes)


CFG = config()
STRAIGHT_S = np.array([0.0, 500.0])  # [m] a straight path along +x from the origin
STRAIGHT_XY = np.array([[0.0, 0.0], [500.0, 0.0]])  # [m]
NOBODY = np.zeros((0, 4))
TIMES = planner.lattice(CFG).times  # the grid t_k = k dt [s]


def quintic_at(c, t, derivative=0):
    """l^(n)(t) of Eq. (18) for coefficients c = (c1, ..., c6) on the last axis."""
    exponents = np.arange(5, -1, -1)
    factors = np.array([np.prod(np.arange(e, e - derivative, -1)) if e >= derivative else 0.0
                        for e in exponents])
    return (c * factors * np.asarray(t)[..., None] ** np.maximum(exponents - derivative, 0)).sum(-1)


def drive(s, v, others_at, seconds, path=(STRAIGHT_S, STRAIGHT_XY)):
    """Apply a_base every dt by Euler steps as SUMO does; yields (t, s, v, a_base, mode) after each."""
    a = 0.0
    for n in range(round(seconds / CFG.dt)):
        a_base, mode = base_action(s, v, a, *path, others_at(n * CFG.dt), CFG)
        v_new = max(0.0, v + a_base * CFG.dt)
        a = (v_new - v) / CFG.dt  # the realised acceleration, as the environment passes it
        s, v = s + v_new * CFG.dt, v_new
        yield (n + 1) * CFG.dt, s, v, a_base, mode


def on_path_of(others, path=(STRAIGHT_S, STRAIGHT_XY), segments=None):
    """on_path of `others` at the grid times, as an array (3, M, K): s, s_rate, half_along."""
    segments = planner.path_segments(*path) if segments is None else segments
    return np.array(planner.on_path(others, segments, TIMES, CFG))


def test_the_ego_limits_and_size_must_come_from_the_environment():
    with pytest.raises(TypeError):
        PlannerConfig(dt=0.2)  # a_min, a_max, length and width have no default
    with pytest.raises(TypeError):
        PlannerConfig(0.2, -3.0, 2.0, 5.0, 2.0)  # keywords only
    assert CFG.v_target == 10.0 and CFG.K1 == 1000.0  # the planner's own constants keep theirs


# ---- Eqs. (18)-(19): the quintic --------------------------------------------------------

def test_quintic_meets_the_six_boundary_conditions_of_eq19():
    rng = np.random.default_rng(0)
    n = 500
    l0, le = rng.uniform(-50, 50, n), rng.uniform(-50, 150, n)
    v0, ve = rng.uniform(0, 15, n), rng.uniform(0, 15, n)
    a0, ae = rng.uniform(-3, 2, n), rng.uniform(-3, 2, n)
    te = rng.uniform(0.5, 8.0, n)
    c = quintic_coefficients(l0, v0, a0, le, ve, ae, te)
    assert c.shape == (n, 6)
    for derivative, start, end in ((0, l0, le), (1, v0, ve), (2, a0, ae)):
        np.testing.assert_allclose(quintic_at(c, 0.0 * te, derivative), start, rtol=0, atol=1e-9)
        np.testing.assert_allclose(quintic_at(c, te, derivative), end, rtol=0, atol=1e-9)


def test_rest_to_rest_in_one_second_is_the_smoothstep_quintic():
    # l(t) = 10 t^3 - 15 t^4 + 6 t^5 in the order c1 t^5 + ... + c6
    np.testing.assert_allclose(quintic_coefficients(0, 0, 0, 1, 0, 0, 1), [6, -15, 10, 0, 0, 0], atol=1e-12)


def test_batched_solve_equals_one_by_one_and_broadcasts():
    rng = np.random.default_rng(1)
    args = [rng.uniform(0.5, 5.0, 20) for _ in range(7)]
    batch = quintic_coefficients(*args)
    for i in range(20):
        np.testing.assert_allclose(batch[i], quintic_coefficients(*(a[i] for a in args)), rtol=1e-12)
    grid = quintic_coefficients(0.0, np.arange(3.0)[:, None], 0.0, 10.0, np.arange(4.0), 0.0, 2.0)
    assert grid.shape == (3, 4, 6)
    np.testing.assert_allclose(grid[2, 3], quintic_coefficients(0.0, 2.0, 0.0, 10.0, 3.0, 0.0, 2.0))


def test_lattice_unit_responses_equal_the_full_solve():
    """plan() combines three precomputed responses; they must equal solving Eq. (19) anew."""
    lattice = planner.lattice(CFG)
    v0, a0 = 7.3, -1.2
    combined = np.tensordot((1.0, v0, a0), lattice.responses, axes=1)
    np.testing.assert_allclose(combined, lattice.trajectories(v0, a0), atol=1e-9)
    # Each candidate starts at (0, v0, a0) and, after t_e, keeps v_e at zero acceleration.
    np.testing.assert_allclose(combined[:3, 0], np.array([[0.0], [v0], [a0]]) + 0 * lattice.te, atol=1e-12)
    last = len(lattice.times) - 1
    np.testing.assert_allclose(combined[1, last], lattice.ve, atol=1e-9)
    np.testing.assert_allclose(combined[2, last], 0.0, atol=1e-12)


# ---- IDM, Eqs. (20)-(23) and the FSM, each on its own ------------------------------------------

def test_idm_by_hand():
    params = dict(a_max=2.0, b=2.0, s0=2.0, time_headway=1.5)
    assert idm_acceleration(10.0, 10.0, np.inf, 0.0, **params) == pytest.approx(0.0, abs=1e-12)
    assert idm_acceleration(0.0, 10.0, np.inf, 0.0, **params) == pytest.approx(2.0)
    # v = 10, v0 = 15, gap 20 m, closing at 2 m/s: s* = 2 + 10 * 1.5 + 10 * 2 / (2 sqrt(2 * 2)) = 22 m
    expected = 2.0 * (1 - (10 / 15) ** 4 - (22 / 20) ** 2)
    assert idm_acceleration(10.0, 15.0, 20.0, 2.0, **params) == pytest.approx(expected)
    both = idm_acceleration(np.array([0.0, 10.0]), 15.0, np.array([np.inf, 20.0]), np.array([0.0, 2.0]), **params)
    np.testing.assert_allclose(both, [2.0, expected])


def test_lattice_cost_adds_the_five_weighted_terms_of_eq20():
    lattice = planner.lattice(CFG)
    C, K = len(lattice.te), len(lattice.times)
    calm = planner.lattice_cost(np.zeros(C), np.zeros((K, C)), lattice, CFG)
    np.testing.assert_allclose(calm, CFG.K2 * np.abs(lattice.ve - np.where(lattice.ve > 0, CFG.v_target, 0.0))
                               + CFG.K3 * lattice.te)  # phi_v + phi_t (phi_d = 0)
    assert calm[lattice.drive_ids][-1] == pytest.approx(CFG.K3 * 8.0)  # at v_hat after 8 s: phi_t only
    phi_coll = np.zeros(C)
    phi_coll[3] = 1.0
    jerk = np.full((K, C), -0.5)  # [m/s^3]: phi_jerk = sum |l'''| dt = 0.5 K dt
    cost = planner.lattice_cost(phi_coll, jerk, lattice, CFG)
    np.testing.assert_allclose(cost - calm, CFG.K1 * phi_coll + CFG.K5 * 0.5 * K * CFG.dt)


def test_state_machine_picks_drive_then_stop_then_brake():
    drive_ids, stop_ids, K1 = slice(0, 3), slice(3, 5), 1000.0
    fsm = planner.state_machine
    # the cheapest drive candidate if it is collision-free, even when a stop one is cheaper
    assert fsm(np.array([5.0, 2.0, 1003.0, 0.5, 1.0]), drive_ids, stop_ids, K1) == ("drive", 1)
    # every drive candidate collides or is infeasible: the cheapest stop one
    assert fsm(np.array([1001.0, np.inf, 1002.0, 1004.0, 3.0]), drive_ids, stop_ids, K1) == ("stop", 4)
    # nothing collision-free (or nothing feasible): brake
    assert fsm(np.array([1001.0, 1000.0, np.inf, 1004.0, np.inf]), drive_ids, stop_ids, K1) == ("brake", None)
    assert fsm(np.full(5, np.inf), drive_ids, stop_ids, K1) == ("brake", None)


def test_base_acceleration_is_the_min_of_eq23_with_the_sign_of_eq22():
    assert planner.base_acceleration(1.2, 0.7, CFG) == pytest.approx(0.7)  # IDM caps
    assert planner.base_acceleration(0.4, 1.5, CFG) == pytest.approx(0.4)  # the lattice's a_t1
    assert planner.base_acceleration(-1.3, 1.5, CFG) == pytest.approx(-1.3)  # Eq. (22) can brake
    assert planner.base_acceleration(-2.0, -9.0, CFG) == CFG.a_min  # within the ego's limits
    assert planner.base_acceleration(5.0, np.inf, CFG) == CFG.a_max


def test_collision_term_and_leader_on_hand_made_predictions():
    K = len(TIMES)
    # vehicle 0 stands 30 m ahead of the ego's centre (s0 = 10 m); vehicle 1 follows 8 m behind
    # at the ego's speed; vehicle 2 is not on the path.
    s = np.array([np.full(K, 40.0), 2.0 + 8.0 * TIMES, np.full(K, np.nan)])
    seen = planner.OnPath(s, np.array([np.zeros(K), np.full(K, 8.0), np.full(K, np.nan)]),
                          np.where(np.isnan(s), np.nan, 2.5))
    positions = np.stack([8.0 * TIMES, np.minimum(8.0 * TIMES, 20.0), 1.0 * TIMES], axis=1)  # (K, 3) past s0
    # 30 m ahead with reach 2.5 + 2.5 + 1 = 6 m: the first candidate gets there, the others stop short;
    # the follower, though the third candidate falls back into it, blocks nothing.
    np.testing.assert_array_equal(planner.collision_term(positions, seen, 10.0, CFG), [1.0, 0.0, 0.0])
    assert planner.leader(seen, 10.0, 8.0, CFG) == pytest.approx((30.0 - 2.5 - 2.5, 8.0))
    nobody = planner.OnPath(*np.full((3, 0, K), np.nan))
    assert planner.leader(nobody, 10.0, 8.0, CFG) == (np.inf, 0.0)
    np.testing.assert_array_equal(planner.collision_term(positions, nobody, 10.0, CFG), [0.0, 0.0, 0.0])


# ---- prediction against the path -----------------------------------------------------------

def test_perpendicular_crosser_is_on_the_path_while_in_the_band():
    # 10 m/s northward, 40 m south of the path at x = 40: its 5 x 2 m box is within the band
    # |y| < 1 + 2.5 + 0.5 = 4 m from t = 3.6 s to 4.4 s, at s = 40 m, with 1 m of it along the path.
    s, s_rate, half_along = on_path_of(np.array([[40.0, -40.0, 10.0, np.pi / 2]]))[:, 0]
    on = ~np.isnan(s)
    assert on[19:22].all() and not on[:18].any() and not on[23:].any()  # t = 3.8-4.2 s, not <= 3.4 or >= 4.6
    np.testing.assert_allclose(s[on], 40.0)
    np.testing.assert_allclose(s_rate[on], 0.0, atol=1e-9)
    np.testing.assert_allclose(half_along[on], 1.0)


# ---- the base planner ---------------------------------------------------------------------

def test_drives_up_to_the_target_speed_on_an_empty_road():
    a_first, mode = base_action(0.0, 0.0, 0.0, STRAIGHT_S, STRAIGHT_XY, NOBODY, CFG)
    assert a_first > 0 and mode == "drive"
    run = list(drive(0.0, 0.0, lambda t: NOBODY, seconds=40.0))
    assert all(mode == "drive" for *_, mode in run)
    last_10_s = [v for t, s, v, a, mode in run if t > 30.0]
    assert min(last_10_s) > CFG.v_target - 0.1 and max(last_10_s) < CFG.v_target + 0.1


def test_stops_behind_a_stopped_vehicle_without_reaching_it():
    car = np.array([[30.0, 0.0, 0.0, 0.0]])  # stopped on the path, 30 m ahead (centre to centre)
    a_first, mode = base_action(0.0, 8.0, 0.0, STRAIGHT_S, STRAIGHT_XY, car, CFG)
    assert a_first < 0 and mode == "stop"
    run = list(drive(0.0, 8.0, lambda t: car, seconds=20.0))
    bumper_gaps = [30.0 - s - CFG.length for t, s, v, a, mode in run]
    assert min(bumper_gaps) > 1.0
    assert run[-1][2] < 0.05  # stopped


def test_idm_caps_the_planner_behind_a_close_leader_eq23():
    # Leader 20 m ahead (15 m bumper to bumper) at the ego's 10 m/s: keeping the speed is
    # collision-free, so the lattice says a_t1 = 0, but IDM wants 15 + 2 m of gap and brakes.
    leader = np.array([[20.0, 0.0, 10.0, 0.0]])
    a_base, mode = base_action(0.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, leader, CFG)
    a_idm = idm_acceleration(10.0, CFG.v_target, 15.0, 0.0, CFG.a_max, CFG.idm_comfort_decel,
                             CFG.idm_min_gap, CFG.idm_time_headway, CFG.idm_delta)
    assert mode == "drive" and a_idm < -1.0
    assert a_base == pytest.approx(a_idm)


def test_brakes_in_emergency_when_no_trajectory_is_free():
    car = np.array([[9.0, 0.0, 0.0, 0.0]])  # stopped 4 m ahead of the bumper; at 10 m/s nothing stops in time
    assert base_action(0.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, car, CFG) == (CFG.a_min, "brake")


def test_plan_returns_the_chosen_trajectory_along_the_path():
    empty = planner.plan(20.0, 8.0, 0.0, STRAIGHT_S, STRAIGHT_XY, NOBODY, CFG)
    assert (empty.a_base, empty.mode) == base_action(20.0, 8.0, 0.0, STRAIGHT_S, STRAIGHT_XY, NOBODY, CFG)
    np.testing.assert_allclose(empty.t, TIMES)
    assert empty.s[0] == pytest.approx(20.0) and np.all(np.diff(empty.s) > 0)
    # the plan's second point is where its first acceleration leads: s0 + v0 dt + a_t1 dt^2 / 2 + ...
    assert empty.s[1] == pytest.approx(20.0 + 8.0 * CFG.dt + empty.a_base * CFG.dt**2 / 2, abs=0.01)
    # behind a stopped car the plan stops short of it
    stop = planner.plan(0.0, 8.0, 0.0, STRAIGHT_S, STRAIGHT_XY, np.array([[30.0, 0.0, 0.0, 0.0]]), CFG)
    assert stop.mode == "stop" and stop.s[-1] < 30.0 - CFG.length - CFG.longitudinal_margin
    assert stop.s[-1] == pytest.approx(stop.s[-2])  # standing still at the end
    # braking: a_min until standing still, 10^2 / (2 * 3) = 16.7 m further
    brake = planner.plan(0.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, np.array([[9.0, 0.0, 0.0, 0.0]]), CFG)
    assert brake.mode == "brake" and brake.s[1] == pytest.approx(10.0 * 0.2 - 1.5 * 0.04)
    assert brake.s[-1] == pytest.approx(100.0 / 6.0)


def test_crossing_vehicle_timed_to_meet_the_ego_slows_it_but_one_already_past_does_not():
    empty, _ = base_action(0.0, CFG.v_target, 0.0, STRAIGHT_S, STRAIGHT_XY, NOBODY, CFG)
    # At 10 m/s both reach (40, 0) in 4 s.
    meeting = np.array([[40.0, -40.0, 10.0, np.pi / 2]])
    a_meeting, _ = base_action(0.0, CFG.v_target, 0.0, STRAIGHT_S, STRAIGHT_XY, meeting, CFG)
    assert a_meeting < empty - 0.5
    past = np.array([[40.0, 10.0, 10.0, np.pi / 2]])  # already across, driving away
    assert base_action(0.0, CFG.v_target, 0.0, STRAIGHT_S, STRAIGHT_XY, past, CFG)[0] == pytest.approx(empty)


def test_followers_and_the_next_lane_do_not_slow_the_ego():
    empty = base_action(20.0, 8.0, 0.0, STRAIGHT_S, STRAIGHT_XY, NOBODY, CFG)
    others = np.array([[5.0, 0.0, 12.0, 0.0],  # on the path behind the ego, faster
                       [-10.0, 0.0, 12.0, 0.0],  # behind the path's start, on its extension
                       [40.0, 3.2, 8.0, 0.0],  # next lane, same direction
                       [60.0, 3.2, 10.0, np.pi]])  # next lane, oncoming
    assert base_action(20.0, 8.0, 0.0, STRAIGHT_S, STRAIGHT_XY, others, CFG) == pytest.approx(empty)
    seen = on_path_of(others)
    assert not np.isnan(seen[0, :2, 0]).any()  # the two followers are on the path (its extension too)
    assert np.isnan(seen[0, 2:]).all()  # the next lane never is


def test_follows_a_slower_leader_on_a_bend_at_a_safe_gap():
    bend = np.linspace(0.0, np.pi / 2, 30)  # a left turn of radius 12 m between two straights
    xy = np.vstack([[[-60.0, 0.0]], np.c_[-12 + 12 * np.sin(bend), 12 * (1 - np.cos(bend))], [[0.0, 60.0]]])
    s_nodes = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]

    def leader_at(t):  # 4 m/s along the path from 20 m ahead of the ego's start, heading on the path
        s = 30.0 + 4.0 * t
        i = np.searchsorted(s_nodes, s) - 1
        heading = np.arctan2(*(xy[i + 1] - xy[i])[::-1])
        return np.array([[np.interp(s, s_nodes, xy[:, 0]), np.interp(s, s_nodes, xy[:, 1]), 4.0, heading]])

    run = list(drive(10.0, 8.0, leader_at, seconds=15.0, path=(s_nodes, xy)))
    gaps = [30.0 + 4.0 * t - s - CFG.length for t, s, v, a, mode in run]
    assert min(gaps) > 3.0
    assert abs(run[-1][2] - 4.0) < 1.0  # settled near the leader's speed


# ---- predictions at constant speed and yaw rate (CTRV) ---------------------------------------

def ring_path(radius, segment=3.0, start=-np.pi / 2, turn=1.5 * np.pi):
    """A counter-clockwise circle of `radius` [m] around the origin from angle `start` [rad] over
    `turn` [rad], as a polyline of about `segment` [m] chords (as SUMO's ring lanes): (s, xy)."""
    angle = start + np.linspace(0.0, turn, int(radius * turn / segment) + 1)
    xy = np.c_[radius * np.cos(angle), radius * np.sin(angle)]
    return np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))], xy


def on_ring(radius, angle, v, yaw_rate):
    """One vehicle on the circle of `radius` around the origin at `angle`, heading counter-clockwise."""
    return np.array([[radius * np.cos(angle), radius * np.sin(angle), v, angle + np.pi / 2, yaw_rate]])


def test_zero_yaw_rate_is_the_straight_line_and_four_columns_mean_zero_yaw_rate():
    cars = np.array([[40.0, -40.0, 10.0, np.pi / 2], [30.0, 0.0, 0.0, 0.0], [5.0, 3.2, 12.0, 0.1]])
    for others in (cars, np.c_[cars, np.zeros(3)]):
        centre, heading = planner.predict(others, TIMES, CFG)
        velocity = cars[:, 2] * np.exp(1j * cars[:, 3])  # [m/s]
        straight = (cars[:, 0] + 1j * cars[:, 1])[:, None] + velocity[:, None] * TIMES
        np.testing.assert_allclose(centre, straight, rtol=0, atol=1e-12)
        np.testing.assert_allclose(heading, np.exp(1j * cars[:, 3])[:, None] + 0 * TIMES, rtol=0, atol=1e-15)
    assert (base_action(0.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, cars, CFG)
            == base_action(0.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, np.c_[cars, np.zeros(3)], CFG))


def test_a_tiny_yaw_rate_predicts_the_straight_line():
    # Round-off in a measured heading gives yaw rates like 1e-15 rad/s: a radius of 1e16 m.
    # (Not 40 m south at 10 m/s like the crossers above: there a candidate is exactly at
    # the collision distance, and a 1e-13 m difference decides.)
    crosser = np.array([[37.0, -37.5, 10.0, np.pi / 2, 1e-15]])
    t = np.linspace(0.0, CFG.horizon, 9)
    np.testing.assert_allclose(planner.predict(crosser, t, CFG)[0][0], 37.0 - 37.5j + 10.0j * t, atol=1e-9)
    a_straight, _ = base_action(0.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, crosser[:, :4], CFG)
    assert a_straight < base_action(0.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, NOBODY, CFG)[0] - 0.5
    assert base_action(0.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, crosser, CFG)[0] == pytest.approx(a_straight)


@pytest.mark.parametrize("yaw_sign", [1.0, -1.0])
def test_a_vehicle_circling_at_radius_r_stays_on_its_circle_at_every_grid_time(yaw_sign):
    # 10 m/s at (25, 0) heading north, yaw rate +-0.4 rad/s: the circle of radius 25 m around the
    # origin (counter-clockwise) or around (50, 0) (clockwise), 3.2 rad over the 8 s horizon.
    R, v = 25.0, 10.0
    centre, heading = planner.predict(np.array([[R, 0.0, v, np.pi / 2, yaw_sign * v / R]]), TIMES, CFG)
    middle = 0.0 if yaw_sign > 0 else 2 * R  # of the circle
    start = 0.0 if yaw_sign > 0 else np.pi  # the vehicle's angle seen from there at t = 0
    angle = start + yaw_sign * v / R * TIMES  # by hand, at every grid time
    np.testing.assert_allclose(np.abs(centre[0] - middle), R, rtol=0, atol=1e-9)
    np.testing.assert_allclose(centre[0], middle + R * np.exp(1j * angle), rtol=0, atol=1e-9)
    np.testing.assert_allclose(heading[0], np.exp(1j * (np.pi / 2 + yaw_sign * v / R * TIMES)), atol=1e-12)


def test_yaw_rate_is_clamped_to_the_minimum_turn_radius():
    # 5 m/s with a measured 10 rad/s (a 0.5 m circle) is clamped to 1 rad/s: a 5 m circle.
    centre, _ = planner.predict(np.array([[0.0, 0.0, 5.0, 0.0, 10.0]]), TIMES, CFG)
    np.testing.assert_allclose(np.abs(centre[0] - 5.0j), CFG.min_turn_radius, atol=1e-9)  # around (0, 5)
    after_1_s = 5.0j + 5.0 * np.exp(1j * (1.0 - np.pi / 2))  # 1 rad round that circle
    np.testing.assert_allclose(centre[0, 5], after_1_s, atol=1e-9)


@pytest.mark.parametrize("phase", [-0.2, 0.0, 0.2])
def test_ring_vehicle_beside_the_ego_lane_does_not_block_but_its_tangent_does(phase):
    # The ego drives the circle 3.2 m outside a vehicle circling at radius 25 m (the next lane),
    # `phase` rad ahead of it. Predicted on its circle, the vehicle stays in its lane; predicted
    # along its tangent, it drifts into the ego's lane and the ego brakes for nothing.
    path = ring_path(25.0 + 3.2)
    s0, v = 20.0, 8.0
    angle = -np.pi / 2 + s0 / (25.0 + 3.2) + phase
    empty = base_action(s0, v, 0.0, *path, NOBODY, CFG)
    assert base_action(s0, v, 0.0, *path, on_ring(25.0, angle, v, v / 25.0), CFG) == empty
    a_tangent, _ = base_action(s0, v, 0.0, *path, on_ring(25.0, angle, v, 0.0), CFG)
    assert a_tangent < empty[0] - 0.5


@pytest.mark.parametrize("phase", [-0.2, 0.0, 0.2, 0.4])
def test_ring_vehicle_in_the_next_lane_out_does_not_block(phase):
    # The ego drives the inner circle (a polyline of 4 m segments), the vehicle circles 3.2 m
    # outside it. A segment's band reaching a full band width past each end (rather than closing
    # the bend's outer side only) would put the vehicle in the band: the second half shows it.
    path = ring_path(25.0, segment=4.0)
    s0, v = 20.0, 8.0
    vehicle = on_ring(25.0 + 3.2, -np.pi / 2 + s0 / 25.0 + phase, v, v / (25.0 + 3.2))
    assert base_action(s0, v, 0.0, *path, vehicle, CFG) == base_action(s0, v, 0.0, *path, NOBODY, CFG)
    segments = planner.path_segments(*path)
    assert np.isnan(on_path_of(vehicle, segments=segments)).all()
    full_band = segments._replace(miter_start=np.ones_like(segments.miter_start),
                                  miter_end=np.ones_like(segments.miter_end))
    assert not np.isnan(on_path_of(vehicle, segments=full_band)).all()


def test_vehicle_turning_onto_the_path_blocks_the_ego_but_its_tangent_would_not():
    # 8 m/s eastward 12 m beside the ego's road, turning left at 8 / 12 rad/s: a quarter of the
    # circle around (20, 0) takes it across the road at (32, 0) after 2.36 s, when the ego
    # (8 m from the origin at 10 m/s) gets there. Straight on, it would stay 12 m away.
    empty, _ = base_action(8.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, NOBODY, CFG)
    turner = np.array([[20.0, -12.0, 8.0, 0.0, 8.0 / 12.0]])
    a_turning, _ = base_action(8.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, turner, CFG)
    assert a_turning < empty - 0.5
    assert base_action(8.0, 10.0, 0.0, STRAIGHT_S, STRAIGHT_XY, turner[:, :4], CFG)[0] == pytest.approx(empty)


# ---- implementation details: per-path cache, mixed predictions, the band test ----------------

def test_the_per_path_cache_follows_the_path_passed():
    # plan() finds a path's segments in a cache keyed by the path's values; another path, a copy
    # of one, or lists must give what a fresh start gives.
    ring = ring_path(28.2)
    car = np.array([[40.0, -1.0, 0.0, 0.0], [0.0, -28.2, 0.0, 0.0]])  # stopped: one on each path
    calls = [(0.0, 8.0, 0.0, STRAIGHT_S, STRAIGHT_XY), (10.0, 8.0, 0.0, *ring),
             (0.0, 8.0, 0.0, STRAIGHT_S.copy(), STRAIGHT_XY.copy()),
             (0.0, 8.0, 0.0, list(STRAIGHT_S), STRAIGHT_XY.tolist()),
             (10.0, 8.0, 0.0, *ring), (0.0, 8.0, 0.0, STRAIGHT_S, STRAIGHT_XY)]
    cached = [base_action(*call, car, CFG) for call in calls]
    fresh = []
    for call in calls:
        planner._cached_path_segments.cache_clear()
        planner.lattice.cache_clear()
        fresh.append(base_action(*call, car, CFG))
    assert cached == fresh
    assert cached[0] != cached[1]  # the two paths see different cars
    assert cached[0] == cached[2] == cached[3] == cached[5] and cached[1] == cached[4]


def test_mixed_predictions_are_each_vehicles_own_in_row_order():
    cars = np.array([[40.0, -40.0, 10.0, np.pi / 2, 0.0], [25.0, 0.0, 10.0, np.pi / 2, 0.4],
                     [5.0, 3.2, 0.0, 0.1, 0.3], [0.0, 0.0, 5.0, 0.0, -10.0], [30.0, 0.0, 8.0, 1.0, 0.0]])
    together = planner.predict(cars, TIMES, CFG)
    for i, car in enumerate(cars):
        alone = planner.predict(car[None], TIMES, CFG)
        for field_together, field_alone in zip(together, alone):
            np.testing.assert_allclose(field_together[i], field_alone[0], rtol=0, atol=1e-12)


def test_on_path_equals_the_band_test_of_every_vehicle_time_and_segment():
    # A loop over vehicles, grid times and segments in order, each tested against the band, the
    # first segment holding it taken: what on_path computes at once behind its cheap prefilters.
    # On a ring of short segments the bands overlap at the bends, so many points are in two.
    path = planner.path_segments(*ring_path(25.0))
    others = np.vstack([on_ring(25.0, -1.2, 8.0, 8.0 / 25.0), on_ring(25.0, 0.3, 6.0, 6.0 / 25.0),
                        on_ring(28.2, 0.1, 8.0, 8.0 / 28.2), [[-20.0, -30.0, 5.0, 0.3, 0.0]],
                        [[90.0, 90.0, 3.0, 2.0, 0.0]]])
    centre, heading = planner.predict(others, TIMES, CFG)
    L, W = CFG.length, CFG.width
    expected, in_two = np.full((3, len(others), len(TIMES)), np.nan), 0
    for m in range(len(others)):
        for k in range(len(TIMES)):
            holding = []
            for j in range(len(path.start)):  # in the segment's frame: along the path, to the left
                position = (centre[m, k] - path.start[j]) * path.to_segment[j]
                direction = heading[m, k] * path.to_segment[j]
                cos, sin = abs(direction.real), abs(direction.imag)
                band = W / 2 + CFG.lateral_margin + L / 2 * sin + W / 2 * cos
                if (abs(position.imag) <= band and -band * path.miter_start[j] <= position.real
                        <= path.length[j] + band * path.miter_end[j]):
                    holding.append((path.s_start[j] + position.real, others[m, 2] * direction.real,
                                    L / 2 * cos + W / 2 * sin))
            in_two += len(holding) > 1
            if holding:
                expected[:, m, k] = holding[0]
    seen = on_path_of(others, segments=path)
    np.testing.assert_array_equal(np.isnan(seen), np.isnan(expected))
    np.testing.assert_allclose(seen, expected, rtol=0, atol=1e-9)
    assert (~np.isnan(expected[0])).sum() > 60 and in_two > 10  # many points on the path, many in two bands
    assert np.isnan(expected[0, [2, 4]]).all() and (~np.isnan(expected[0, 3])).sum() > 30  # the next
    # lane out and the far one never; the one by the path's start, along its extension, mostly
