"""The base planner of timing-aware RL: the conservative base action a_base.

Paper: "Act Better by Timing: A timing-Aware Reinforcement Learning for Autonomous
Driving", Section 4, last part ("The base model consists of a finite state machine
(FSM) and a lattice planner ...", Eqs. (18)-(23)). Equation numbers are the printed
ones (paper/EQUATIONS.md).

The ego follows a fixed path through the junction and is controlled only along it; it
stays on its lane centre, so the lateral half of the lattice collapses (d = d0 = d_ref
= 0, v_de = 0, d'' = d''' = 0) and every candidate is a longitudinal quintic l(t). Each
call scores a fixed lattice of end states (t_e, l_e, v_e) all at once with numpy, lets a
three-state FSM pick a trajectory, and caps its next acceleration by IDM toward the
leader on the path. The environment calls base_action() at every simulation step.

delta_traj needs the other vehicles' future. The paper predicts them "at a constant speed";
here each also keeps its yaw rate (constant speed and turn rate, CTRV: a circular arc, the
straight line when the yaw rate is 0), so that a vehicle on a roundabout ring or in a turn
stays in its lane (predict). Each arc is cut into a few chords; each chord, like a straight
line, is on a path segment for a time window found in closed form (path_occupancy).

Map from the paper to this file:
    Eq. (18) l(t) = c1 t^5 + ... + c6        -> _Lattice.powers, _Lattice.trajectories
    Eq. (19) the six boundary conditions     -> quintic_coefficients
    Eq. (20) cost = K1 phi_coll + ... + K5   -> base_action
    Eq. (21) the five terms; delta_traj      -> _Lattice (phi_v, phi_t), base_action;
             from constant-speed predictions    predict, arc_chords, path_occupancy, on_path
    FSM: drive / slow down to stop / brake   -> base_action
    Eq. (22) a_t1, Eq. (23) min(a_t1, a_IDM) -> base_action, idm_acceleration

Units: metres, seconds, radians; angles counter-clockwise from +x; points in the plane as
complex numbers x + iy.

Test: `python -m pytest -q test_planner.py`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

_SLACK = 1e-6  # [m/s] and [m/s^2]: round-off allowed in the feasibility checks
_EXTENSION = 1000.0  # [m] the path continues straight this far past both ends (beyond any plan)


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of the base planner. The paper gives only a_min, a_max, L_car and W_car."""

    dt: float = 0.2  # [s] the environment's step: t1 of Eq. (22) and the step of the time grid
    a_min: float = -3.0  # [m/s^2] ego deceleration limit (paper, Section 5.2), also the emergency brake
    a_max: float = 2.0  # [m/s^2] ego acceleration limit (paper, Section 5.2)
    v_target: float = 10.0  # v_hat [m/s] of the drive set: middle of Table 1's target 8-12 m/s
    v_max: float = 15.0  # [m/s] feasibility cap, above v_hat so a quintic may overshoot a little
    length: float = 5.0  # L_car [m] (Table 1), the ego and the others
    width: float = 2.0  # W_car [m] (Table 1), the ego and the others
    # The lattice (not in the paper). A quintic stop from v0 with a_le = 0 brakes at up to
    # 1.875 v0 / t_e, so stopping from 12 m/s within 3 m/s^2 needs t_e = 8 s; 2 s is agile.
    end_times: tuple[float, ...] = (2.0, 3.0, 4.0, 6.0, 8.0)  # t_e [s]
    # Drive set: v_e spans 0.2-1.0 v_hat, so the ego can also yield by slowing down and still
    # "drive". l_e = f (v0 + v_e) / 2 t_e: f = 1 is the symmetric speed change, f = 0.9 / 1.1
    # change speed later / earlier. 5 t_e x 5 v_e x 3 f = 75 candidates.
    drive_speed_fractions: tuple[float, ...] = (0.2, 0.4, 0.6, 0.8, 1.0)  # v_e / v_hat [-]
    drive_distance_factors: tuple[float, ...] = (0.9, 1.0, 1.1)  # f [-]
    # Stop set: v_e = 0, l_e = f v0 / 2 t_e (f < 1 brakes early). 5 x 4 = 20 candidates.
    stop_distance_factors: tuple[float, ...] = (0.6, 0.8, 1.0, 1.2)  # f [-]
    horizon: float = 8.0  # [s] = the longest t_e: span of predictions, collision check, phi_jerk
    # Eq. (20) weights (not in the paper). K1 exceeds the sum of the other terms (below 10 for
    # any feasible candidate), so the cheapest feasible candidate of a set is collision-free
    # whenever one is; K2 (speed) dominates the rest; K3 and K5 favour short, smooth plans.
    K1: float = 1000.0  # [-] per collision
    K2: float = 1.0  # [s/m]
    K3: float = 0.1  # [1/s]
    K4: float = 1.0  # [1/m], multiplies phi_d = 0 on a fixed path
    K5: float = 0.1  # [s^2/m]
    # Prediction of the others (Eq. (21)'s delta_traj): constant speed AND constant yaw rate
    # (CTRV), see predict(). The paper says only "constant speed".
    # A passenger car turns no tighter than about 5 m (turning radius 5-6 m), so |yaw rate| is
    # clamped to v / 5 m. A larger measured value is noise: the yaw rate is a heading change
    # over one step, SUMO's heading turns where a lane's polyline bends, and at low speed a
    # small heading change is a large one per metre travelled (a crawling car would spin).
    min_turn_radius: float = 5.0  # [m]
    # An arc is followed by chords, each a straight piece with its own closed-form window. A
    # chord turns by at most chord_angle, so its heading is within chord_angle / 2 of the arc's,
    # and lies at most chord_sagitta inside the arc; a lane 3.2 m away leaves 0.7 m to the band
    # below. A ring vehicle (v = 10 m/s, R = 25 m) gets 11 chords over the 8 s horizon. With
    # 0.3 rad and 0.3 m a vehicle circling next to the ego's ring lane, inside or outside it,
    # does not block the ego; with 0.4 rad and 0.5 m it does on a path of 4 m segments.
    chord_angle: float = 0.3  # [rad]
    chord_sagitta: float = 0.3  # [m]
    # Collision check: margins added to the two vehicles' half extents. Laterally a parallel
    # vehicle in the next lane (3.2 m away, Table 1) stays outside the band W + 0.5 = 2.5 m.
    lateral_margin: float = 0.5  # [m]
    # Along the path; a crossing vehicle's contact zone (2 x 4.5 m) is then wider than the
    # ego's travel in one grid step (3 m at v_max), so grid sampling cannot step over it.
    longitudinal_margin: float = 1.0  # [m]
    # IDM of Eq. (23) with the ego's own values (not in the paper; Table 1 gives the humans').
    idm_min_gap: float = 2.0  # s0 [m]: low end of Table 1's d_min 2-4 m
    idm_time_headway: float = 1.5  # T [s]: Treiber's usual value
    idm_comfort_decel: float = 2.0  # b [m/s^2]: low end of Table 1's 2.0-4.5 (a gentle ego)
    idm_delta: float = 4.0  # [-] Treiber's acceleration exponent


def quintic_coefficients(l0: ArrayLike, v0: ArrayLike, a0: ArrayLike, le: ArrayLike,
                         ve: ArrayLike, ae: ArrayLike, te: ArrayLike) -> np.ndarray:
    """Solve Eq. (19) in closed form: (c1, ..., c6) of Eq. (18) on the last axis.

    The arguments broadcast (te > 0); the result has shape broadcast(inputs) + (6,).
    """
    l0, v0, a0, le, ve, ae, te = (np.asarray(x, dtype=float) for x in (l0, v0, a0, le, ve, ae, te))
    # Eq. (19), rows 1-3: c6 = l0, c5 = v_l0, c4 = a_l0 / 2; rows 4-6 then leave three
    # linear equations in (c1, c2, c3), solved by hand:
    dl = le - l0
    c3 = (20 * dl - (8 * ve + 12 * v0) * te - (3 * a0 - ae) * te**2) / (2 * te**3)
    c2 = (-30 * dl + (14 * ve + 16 * v0) * te + (3 * a0 - 2 * ae) * te**2) / (2 * te**4)
    c1 = (12 * dl - 6 * (ve + v0) * te + (ae - a0) * te**2) / (2 * te**5)
    return np.stack(np.broadcast_arrays(c1, c2, c3, a0 / 2, v0, l0), axis=-1)


def idm_acceleration(v: ArrayLike, v_desired: ArrayLike, gap: ArrayLike, dv: ArrayLike,
                     a_max: float, b: float, s0: float, time_headway: float,
                     delta: float = 4.0) -> float | np.ndarray:
    """Intelligent Driver Model (Treiber, Hennecke and Helbing, 2000); vectorised.

    v [m/s] own speed, gap [m] bumper to bumper (np.inf: free road), dv = v - v_leader [m/s],
    a_max and b [m/s^2] maximum and comfortable deceleration, s0 [m] jam distance,
    time_headway [s].
    """
    desired_gap = s0 + np.maximum(0.0, v * time_headway + v * dv / (2 * math.sqrt(a_max * b)))
    # A gap held at 1 cm or more keeps the braking finite for touching vehicles.
    return a_max * (1 - (v / v_desired) ** delta - (desired_gap / np.maximum(gap, 0.01)) ** 2)


class _Lattice:
    """The candidate set and all that depends only on the config; built once by lattice().

    Arrays over time and candidates are (K, C), candidates last (numpy reduces over time
    fastest that way).
    """

    def __init__(self, cfg: PlannerConfig):
        assert max(cfg.end_times) <= cfg.horizon + _SLACK, "the horizon must cover every t_e"
        drive = [(te, fv * cfg.v_target, f) for te in cfg.end_times
                 for fv in cfg.drive_speed_fractions for f in cfg.drive_distance_factors]
        stop = [(te, 0.0, f) for te in cfg.end_times for f in cfg.stop_distance_factors]
        self.te, self.ve, self.f = np.array(drive + stop).T  # (C,) each: t_e [s], v_e [m/s], f [-]
        self.drive_ids = slice(0, len(drive))  # the candidates of the drive set
        self.stop_ids = slice(len(drive), len(drive) + len(stop))  # and of the stop set
        self.times = np.arange(round(cfg.horizon / cfg.dt) + 1) * cfg.dt  # (K,) [s]; times[1] = t1
        # Eq. (18) and its derivatives on the grid: l^(n)(t_k) = powers[n, k] @ (c1, ..., c6).
        exponents = np.arange(5, -1, -1)  # c1 multiplies t^5, ..., c6 t^0

        def derivative_of_powers(n: int) -> np.ndarray:  # (K, 6): d^n/dt^n (t^5, ..., t^0)
            factor = np.array([math.perm(e, n) for e in exponents])  # e!/(e-n)!, 0 if n > e
            return factor * self.times[:, None] ** np.maximum(exponents - n, 0)

        self.powers = np.stack([derivative_of_powers(n) for n in range(4)])  # (4, K, 6): l, l', l'', l'''
        self.after = self.times[:, None] > self.te + _SLACK  # (K, C): past t_e
        # Eq. (19) is linear in (l0, v_l0, a_l0, l_e, v_le, a_le), and l_e = f (v0 + v_e) / 2 t_e
        # is linear in v0, so each candidate is a fixed trajectory plus v0 and a0 times a unit
        # response: three full solves here instead of one per planning step.
        fixed = self.trajectories(0.0, 0.0)
        # (3, 4, K, C): the trajectories from (v0, a0) are (1, v0, a0) @ responses, one pass
        self.responses = np.stack([fixed, self.trajectories(1.0, 0.0) - fixed,
                                   self.trajectories(0.0, 1.0) - fixed])
        self.fixed, self.per_v0, self.per_a0 = self.responses  # (4, K, C) each
        # Feasibility bounds of (speed, acceleration): no reversing, v_max, [a_min, a_max].
        self.lower = np.array([[-_SLACK], [cfg.a_min - _SLACK]])  # [m/s], [m/s^2]
        self.upper = np.array([[cfg.v_max], [cfg.a_max + _SLACK]])  # [m/s], [m/s^2]
        # Eq. (21): phi_v = |sqrt(v_le^2 + v_de^2) - v_hat| = |v_e - v_hat| (v_de = 0), with
        # v_hat the target speed for the drive set and 0 for the stop set
        v_hat = np.where(np.arange(len(self.te)) < len(drive), cfg.v_target, 0.0)
        self.phi_v = np.abs(self.ve - v_hat)
        # Eq. (21): phi_t = t_e
        self.phi_t = self.te
        # Eq. (21): phi_d = |d_e - d0| + |d_e - d_ref| = 0, since the ego stays on its lane centre
        self.phi_d = 0.0
        # The terms of Eq. (20) that depend on the candidate only: K2 phi_v + K3 phi_t + K4 phi_d
        self.cost_fixed = cfg.K2 * self.phi_v + cfg.K3 * self.phi_t + cfg.K4 * self.phi_d

    def trajectories(self, v0: float, a0: float) -> np.ndarray:
        """(4, K, C): l - l0 and its first three derivatives for every candidate, from (v0, a0)."""
        le = self.f * (v0 + self.ve) / 2 * self.te  # [m] past l0
        # Eq. (19) with l0 = 0 and a_le = 0 (the paper's choice), all candidates at once
        c = quintic_coefficients(0.0, v0, a0, le, self.ve, 0.0, self.te)  # (C, 6)
        # Eq. (18): l(t) = c1 t^5 + c2 t^4 + c3 t^3 + c4 t^2 + c5 t + c6, and its derivatives
        polynomial = self.powers @ c.T  # (4, K, C)
        # After t_e a candidate continues at constant speed v_e (l'' = l''' = 0).
        constant_speed = np.zeros_like(polynomial)
        constant_speed[0] = le + self.ve * (self.times[:, None] - self.te)
        constant_speed[1] = self.ve
        return np.where(self.after, constant_speed, polynomial)


@lru_cache(maxsize=8)
def lattice(cfg: PlannerConfig) -> _Lattice:
    """The lattice of a config, built on first use."""
    return _Lattice(cfg)


class PathSegments(NamedTuple):
    """The ego path as S straight segments; points as complex numbers x + iy [m]."""

    start: np.ndarray  # (S,) complex [m] first point of each segment
    to_segment: np.ndarray  # (S,) complex: conj(unit tangent). A vector times it is in the
    #                         segment's frame: real part along the path, imaginary part to the left.
    length: np.ndarray  # (S,) [m]
    s_start: np.ndarray  # (S,) [m] arc length at the first point
    middle: np.ndarray  # (S,) complex [m] middle point
    miter_start: np.ndarray  # (S,) [-] tan(alpha / 2), alpha the path's bend at the first point
    miter_end: np.ndarray  # (S,) [-] the same at the last point


def path_segments(path_s: np.ndarray, path_xy: np.ndarray) -> PathSegments:
    """The path's segments, extended straight by _EXTENSION at both ends (so that a vehicle
    behind the path's start is on it too); repeated points dropped."""
    distinct = np.append(True, np.diff(path_s) > 1e-9)  # a repeated point has no direction
    z, s = path_xy[distinct, 0] + 1j * path_xy[distinct, 1], path_s[distinct]
    first, last = (z[1] - z[0]) / abs(z[1] - z[0]), (z[-1] - z[-2]) / abs(z[-1] - z[-2])
    z = np.concatenate(([z[0] - first * _EXTENSION], z, [z[-1] + last * _EXTENSION]))
    s = np.concatenate(([s[0] - _EXTENSION], s, [s[-1] + _EXTENSION]))
    to_segment = np.conj(np.diff(z) / np.diff(s))
    # The bend alpha at each inner point. A segment's band that reaches band tan(alpha / 2) past
    # its end meets the next segment's band on the bisector: the outer side of the bend is
    # covered, and nothing reaches beyond it. (A full band width past every end would overshoot
    # the outer side: beside a curved path, a vehicle in the next lane out would be in the band.)
    # Capped at a right angle: no lane shape bends more at one point.
    bend = np.abs(np.angle(to_segment[1:] / to_segment[:-1]))  # (S - 1,) [rad]
    miter = np.tan(np.minimum(bend, np.pi / 2) / 2)
    return PathSegments(z[:-1], to_segment, np.diff(s), s[:-1], (z[:-1] + z[1:]) / 2,
                        np.append(0.0, miter), np.append(miter, 0.0))


@lru_cache(maxsize=64)
def _cached_path_segments(s_bytes: bytes, xy_bytes: bytes) -> PathSegments:
    """path_segments keyed by the path's content: a path changes per episode, not per step."""
    return path_segments(np.frombuffer(s_bytes), np.frombuffer(xy_bytes).reshape(-1, 2))


def as_others(others: ArrayLike) -> np.ndarray:
    """The others as an (M, 5) float array: x [m], y [m], speed [m/s], heading [rad], yaw rate
    [rad/s]. An (M, 4) array (no yaw rate) means yaw rate 0, the straight-line prediction."""
    others = np.asarray(others, dtype=float)
    if others.size == 0:
        return np.zeros((0, 5))
    others = others.reshape(-1, others.shape[-1])
    if others.shape[1] == 4:
        others = np.column_stack([others, np.zeros(len(others))])
    assert others.shape[1] == 5, "others: (M, 5) x, y, speed, heading, yaw rate, or (M, 4)"
    return others


class Prediction(NamedTuple):
    """The others' predicted motion as P straight pieces, each at a constant velocity over a
    time interval: vehicle by vehicle (rows of `others`), one piece for a vehicle that does not
    turn, the chords of a turning one in time order."""

    vehicle: np.ndarray  # (P,) int: the vehicle's row in `others`, non-decreasing
    origin: np.ndarray  # (P,) complex [m]: where the piece's line passes at t = 0 (x + iy)
    speed: np.ndarray  # (P,) [m/s]
    direction: np.ndarray  # (P,) complex: exp(i heading), of the motion and of the vehicle's box
    t_from: np.ndarray  # (P,) [s]: the piece holds for t_from <= t <= t_to
    t_to: np.ndarray  # (P,) [s]


def predict(others: ArrayLike, cfg: PlannerConfig) -> Prediction:
    """Each vehicle at constant speed and constant turn rate (CTRV), as straight pieces.

    Paper (Sec. 4): "the planner assumes the surrounding vehicles move at a constant speed"; it
    does not say along what. A straight line at the current heading is the plainest reading, but
    in a turn or on a roundabout ring the tangent leaves the lane: a ring vehicle's tangent cuts
    across the entry lanes, and an inner-ring vehicle's tangent drifts (v t)^2 / 2R = 1.3 m into
    the outer lane in 1 s (R = 25 m, v = 8 m/s), so the ego would yield to vehicles that never
    come. This prediction keeps the paper's assumption, a constant speed, and adds a constant
    yaw rate omega: the vehicle moves on the circle of radius v / |omega| through its position,
    tangent to its heading (counter-clockwise for omega > 0). With omega = 0 that is the straight
    line at the current heading, the paper's plain reading.

    A vehicle with omega = 0 is ONE piece, unbounded in time: exactly the straight-line
    prediction. A turning vehicle's arc is cut into chords (arc_chords).
    """
    x, y, v, psi, omega = as_others(others).T
    # No car turns tighter than min_turn_radius: a larger measured yaw rate is noise.
    limit = v / cfg.min_turn_radius  # [rad/s]
    omega = np.minimum(np.maximum(omega, -limit), limit)  # [rad/s], clipped to [-limit, limit]
    return arc_chords(x + 1j * y, v, psi, omega, cfg)


def arc_chords(z0: np.ndarray, v: np.ndarray, psi: np.ndarray, omega: np.ndarray,
               cfg: PlannerConfig) -> Prediction:
    """The arcs of the vehicles over [0, horizon], each cut into chords of equal duration.

    z0 (M,) complex [m] position x + iy, v (M,) [m/s], psi (M,) [rad] heading, omega (M,) [rad/s]
    turn rate. A vehicle moves on the circle of signed radius r = v / omega through z0,
    tangent to its heading (counter-clockwise for omega > 0): after turning by an angle a it is
    at the end of the chord z0 + 2 r sin(a / 2) exp(i (psi + a / 2)), and heads psi + a. Each arc
    is cut into n chords, n the smallest count for which each chord turns by at most
    cfg.chord_angle and lies at most cfg.chord_sagitta inside the arc. A chord joins two points
    of the arc, so the prediction is exact at the chords' ends. A vehicle with omega = 0 is one
    piece, its straight line, unbounded in time. `vehicle` of the result indexes these M
    vehicles, in order.
    """
    # Over a chord of duration dt the heading turns by |omega| dt, and the chord lies up to
    # |r| (1 - cos(omega dt / 2)) < v |omega| dt^2 / 8 inside the arc.
    abs_omega = np.abs(omega)
    n = np.ceil(np.maximum(abs_omega * cfg.horizon / cfg.chord_angle,
                           cfg.horizon * np.sqrt(v * abs_omega / (8 * cfg.chord_sagitta))))
    straight = n == 0  # (M,) omega = 0: one piece
    n = np.maximum(n, 1).astype(int)
    step = cfg.horizon / n  # (M,) [s] duration of a chord
    turn = omega * step  # (M,) [rad] heading change over a chord
    diameter = 2 * v / np.where(straight, 1.0, omega)  # (M,) [m] 2 r, signed; any value if straight
    half_turn = np.exp(0.5j * turn)  # (M,) exp(i turn / 2), imaginary part sin(turn / 2)
    # A chord over the turn `turn` is 2 r sin(turn / 2) long (signed) and heads half-way round.
    chord_speed = np.where(straight, v, diameter * half_turn.imag / step)  # (M,) [m/s]
    vehicle = np.arange(len(n)).repeat(n)  # (P,)
    index = np.arange(len(vehicle)) - (n.cumsum() - n)[vehicle]  # chord 0, 1, ... of its vehicle
    step = step[vehicle]  # (P,) [s]
    t_from = index * step  # (P,) [s]
    # Before the chord the vehicle has turned by a = index turn: the chord starts at
    # z0 + 2 r sin(a / 2) exp(i (psi + a / 2)) and heads psi + a + turn / 2.
    half_turned = np.exp(0.5j * (turn[vehicle] * index))  # (P,) exp(i a / 2)
    towards_first = np.exp(1j * psi)[vehicle] * half_turned  # (P,) exp(i (psi + a / 2))
    first = z0[vehicle] + diameter[vehicle] * half_turned.imag * towards_first  # (P,) [m]
    direction = towards_first * half_turned * half_turn[vehicle]  # (P,) exp(i (psi + a + turn / 2))
    speed = chord_speed[vehicle]  # (P,) [m/s]
    straight = straight[vehicle]
    return Prediction(vehicle, first - speed * direction * t_from, speed, direction,
                      np.where(straight, -np.inf, t_from), np.where(straight, np.inf, t_from + step))


class Occupancy(NamedTuple):
    """The Q windows in which a piece of the prediction is on a segment of the ego path, (Q,)
    each, ordered by piece, then segment."""

    piece: np.ndarray  # (Q,) int: the piece (entry of the Prediction)
    segment: np.ndarray  # (Q,) int: the segment of the path
    t_in: np.ndarray  # [s] start of the time window
    t_out: np.ndarray  # [s] end of the time window
    s_start: np.ndarray  # [m] the vehicle's arc length on the path at t = 0, measured on the segment
    s_rate: np.ndarray  # [m/s] its speed along the segment: s(t) = s_start + s_rate t
    half_along: np.ndarray  # [m] half its extent along the segment


def _window(x0: np.ndarray, rate: np.ndarray, low: ArrayLike, high: ArrayLike):
    """The times t at which low < x0 + rate t < high, as (start, end) arrays."""
    rate = np.where(np.abs(rate) < 1e-9, 1e-9, rate)  # no motion: a window of all or no time
    t_low, t_high = (low - x0) / rate, (high - x0) / rate
    return np.minimum(t_low, t_high), np.maximum(t_low, t_high)


def path_occupancy(prediction: Prediction, path: PathSegments, cfg: PlannerConfig) -> Occupancy:
    """The windows, overlapping [0, horizon], in which a predicted piece is on a path segment.

    In a segment's frame, a straight piece is linear in time along and across, so the time
    window in which the vehicle is inside the segment's band follows in closed form, with no
    sampled points to project; it is then cut to the piece's own time interval. The band's half
    width is the two vehicles' half extents across the path (each an L x W box at its heading)
    plus a margin; along the path the band reaches past each segment end far enough to cover
    the outer side of a bend (PathSegments.miter_start, miter_end).
    """
    L, W = cfg.length, cfg.width
    pred, horizon = prediction, cfg.horizon
    # A cheap test first, on every (piece, segment) pair: within [0, horizon] a piece stays
    # within half its length of its middle point, and the segment's band (whatever the heading)
    # within `radius` of the segment's middle point. Only the pairs closer than the sum get the
    # closed form.
    band_max = W / 2 + 0.5 * math.hypot(L, W) + cfg.lateral_margin  # [m]
    radius = np.hypot(path.length / 2 + band_max, band_max)  # (S,) [m]
    t_from, t_to = np.maximum(pred.t_from, 0.0), np.minimum(pred.t_to, horizon)  # (P,) [s]
    velocity = pred.speed * pred.direction  # (P,) [m/s]
    middle = pred.origin + velocity * ((t_from + t_to) / 2)  # (P,) [m]
    reach = radius + (pred.speed * (t_to - t_from) / 2)[:, None]  # (P, S) [m]
    near = np.abs(middle[:, None] - path.middle) < reach  # (P, S)
    piece, segment = np.divmod(near.ravel().nonzero()[0], len(path.middle))  # (Q',) each

    to_segment = path.to_segment[segment]
    heading = pred.direction[piece] * to_segment  # cos + i sin of the heading relative to the segment
    position = (pred.origin[piece] - path.start[segment]) * to_segment  # [m] at t = 0
    velocity = velocity[piece] * to_segment  # [m/s]
    cos_rel, sin_rel = np.abs(heading.real), np.abs(heading.imag)
    half_along = L / 2 * cos_rel + W / 2 * sin_rel
    band = W / 2 + cfg.lateral_margin + (L / 2 * sin_rel + W / 2 * cos_rel)  # [m]
    t_in_across, t_out_across = _window(position.imag, velocity.imag, -band, band)
    t_in_along, t_out_along = _window(position.real, velocity.real, -band * path.miter_start[segment],
                                      path.length[segment] + band * path.miter_end[segment])
    t_in = np.maximum(np.maximum(t_in_across, t_in_along), pred.t_from[piece])
    t_out = np.minimum(np.minimum(t_out_across, t_out_along), pred.t_to[piece])
    kept = (np.maximum(t_in, 0.0) <= np.minimum(t_out, horizon)).nonzero()[0]  # overlaps [0, horizon]
    segment = segment[kept]
    return Occupancy(piece[kept], segment, t_in[kept], t_out[kept],
                     path.s_start[segment] + position.real[kept], velocity.real[kept], half_along[kept])


class OnPath(NamedTuple):
    """The others' predictions on the ego path, one entry per (vehicle, grid time) at which the
    vehicle is on the path, ordered by vehicle, then time; (P,) each."""

    vehicle: np.ndarray  # (P,) int: its row in `others`
    k: np.ndarray  # (P,) int: the grid time t_k = k dt
    s: np.ndarray  # (P,) [m] arc length of its centre on the path
    s_rate: np.ndarray  # (P,) [m/s] its speed along the path
    half_along: np.ndarray  # (P,) [m] half its extent along the path


def on_path(others: np.ndarray, path: PathSegments, times: np.ndarray, cfg: PlannerConfig) -> OnPath:
    """Where the predictions of `others` (M, 5) are on the path at the grid times (K,) [s]."""
    nobody = OnPath(np.zeros(0, dtype=int), np.zeros(0, dtype=int), np.zeros(0), np.zeros(0), np.zeros(0))
    if not len(others):
        return nobody
    prediction = predict(others, cfg)
    occ = path_occupancy(prediction, path, cfg)  # Q windows
    if not len(occ.piece):
        return nobody
    # One arc length per (vehicle, grid time): that of the vehicle's first window that holds the
    # time (a turning vehicle's chords share their end times; two segments share a time where
    # the path bends, with arc lengths less than a band width apart).
    window, k = ((occ.t_in[:, None] <= times) & (times <= occ.t_out[:, None])).nonzero()  # holds t_k
    first = np.full((len(others), len(times)), len(occ.piece))  # (M, K) the first window, Q if none
    np.minimum.at(first, (prediction.vehicle[occ.piece[window]], k), window)
    vehicle, k = (first < len(occ.piece)).nonzero()
    window = first[vehicle, k]
    return OnPath(vehicle, k, occ.s_start[window] + occ.s_rate[window] * times[k],
                  occ.s_rate[window], occ.half_along[window])


def base_action(s0: float, v0: float, a0: float, path_s: np.ndarray, path_xy: np.ndarray,
                others: np.ndarray, cfg: PlannerConfig = PlannerConfig()) -> tuple[float, str]:
    """a_base of Eq. (23) in [a_min, a_max] and the FSM's mode: "drive", "stop" or "brake".

    s0 [m], v0 [m/s], a0 [m/s^2]: arc length of the ego's CENTRE on its path, its speed and its
    realised acceleration. path_s (N,) [m]: cumulative Euclidean length along path_xy (N, 2) [m],
    path_s[0] = 0. others (M, 5), M >= 0, the ego excluded: centre x [m], y [m], speed [m/s],
    heading [rad, counter-clockwise from +x], yaw rate [rad/s, counter-clockwise positive]; an
    (M, 4) array without the yaw rate means yaw rate 0 (straight-line predictions).
    """
    s0, v0 = float(s0), float(v0)
    lat = lattice(cfg)
    path = _cached_path_segments(*(np.asarray(p, dtype=float).tobytes() for p in (path_s, path_xy)))
    L = cfg.length
    # round-off in a0 must not make every candidate infeasible
    a0 = min(max(float(a0), cfg.a_min), cfg.a_max)

    # Eqs. (18)-(19): every candidate from (v0, a0) at once (see _Lattice): the position past s0,
    # speed, acceleration and jerk.
    trajectories = np.dot((1.0, v0, a0), lat.responses.reshape(3, -1))  # (4 K C,)
    trajectories = trajectories.reshape(lat.responses.shape[1:])  # (4, K, C)
    pos, acc, jerk = trajectories[0], trajectories[2], trajectories[3]  # (K, C) each
    # Kinematic feasibility: 0 <= v <= v_max (no reversing) and a_min <= a <= a_max throughout.
    speed_acc = trajectories[1:3]  # (2, K, C)
    feasible = ((speed_acc.min(axis=1) >= lat.lower) & (speed_acc.max(axis=1) <= lat.upper)).all(axis=0)
    if not feasible.any():  # FSM: brake in emergency (below), whatever the others do
        return float(cfg.a_min), "brake"

    # The others' predictions (constant speed and turn rate, see predict) on the path.
    others = as_others(others)
    seen = on_path(others, path, lat.times, cfg)
    ahead = seen.s - s0  # (P,) [m] along the path from the ego's centre, < 0 behind it
    now = seen.k == 0
    # A vehicle on the path behind the ego now is a follower: no plan of the ego can avoid
    # it (SUMO's car following brakes it), so it blocks no candidate.
    follower = np.zeros(len(others), dtype=bool)
    follower[seen.vehicle[now & (ahead < 0)]] = True

    # delta_traj: a candidate collides if at some grid time it is closer along the path to a
    # blocking vehicle than their two half lengths plus the margin. Only the (vehicle, time)
    # pairs with a vehicle on the path, and only feasible candidates (no other is ever chosen),
    # are compared; and of the pairs only those within reach of some candidate at their time,
    # from the nearest to the farthest (the same comparisons, so no round-off slips through).
    checked = feasible.nonzero()[0]  # (C',)
    pos = pos[:, checked]  # (K, C') [m] past s0
    reach = L / 2 + seen.half_along + cfg.longitudinal_margin  # (P,) [m]
    k = seen.k
    near = ((pos.min(axis=1)[k] - ahead < reach) & (ahead - pos.max(axis=1)[k] < reach)
            & ~follower[seen.vehicle]).nonzero()[0]  # (P',) blocking and within reach
    close = np.abs(pos[k[near]] - ahead[near, None]) < reach[near, None]  # (P', C')
    # Eq. (21): phi_coll = delta_traj
    phi_coll = np.zeros(len(lat.te))
    phi_coll[checked] = close.any(axis=0)
    # Eq. (21): phi_jerk = sum_t (|l'''(t)| + |d'''(t)|), a Riemann sum over the grid (d''' = 0)
    phi_jerk = np.abs(jerk).sum(axis=0) * cfg.dt
    # Eq. (20): cost = K1 phi_coll + K2 phi_v + K3 phi_t + K4 phi_d + K5 phi_jerk, the middle
    # three fixed per candidate (_Lattice.cost_fixed; phi_d = 0)
    cost = cfg.K1 * phi_coll + lat.cost_fixed + cfg.K5 * phi_jerk
    cost = np.where(feasible, cost, np.inf)

    # FSM: the cheapest drive candidate if it is collision-free, else the cheapest stop
    # candidate if it is, else brake in emergency. (K1 makes the cheapest candidate of a set
    # collision-free whenever a feasible collision-free one exists.)
    for mode, ids in (("drive", lat.drive_ids), ("stop", lat.stop_ids)):
        best = ids.start + int(cost[ids].argmin())
        if cost[best] < cfg.K1:
            # Eq. (22): a_t1 = sqrt(l''(t1)^2 + d''(t1)^2), kept WITH the sign of l''(t1), as d'' = 0
            # on a fixed path: the printed magnitude could never brake (EQUATIONS.md, note 3).
            a_t1 = float(acc[1, best])
            break
    else:  # brake: a_t1 = a_min, and so is a_base of Eq. (23), whatever IDM says
        return float(cfg.a_min), "brake"

    # IDM toward the leader: the nearest vehicle on the path ahead of the ego now.
    leading = (now & (ahead > 0)).nonzero()[0]
    gap, dv = math.inf, 0.0  # free road
    if len(leading):
        gaps = ahead[leading] - L / 2 - seen.half_along[leading]  # bumper to bumper
        leader = int(gaps.argmin())
        gap, dv = float(gaps[leader]), v0 - float(seen.s_rate[leading[leader]])
    a_idm = idm_acceleration(v0, cfg.v_target, gap, dv, cfg.a_max, cfg.idm_comfort_decel,
                             cfg.idm_min_gap, cfg.idm_time_headway, cfg.idm_delta)
    # Eq. (23): a_base = min(a_t1, a_IDM), within the ego's limits
    return float(min(max(min(a_t1, a_idm), cfg.a_min), cfg.a_max)), mode
