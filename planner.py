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

Map from the paper to this file:
    Eq. (18) l(t) = c1 t^5 + ... + c6        -> _Lattice.powers, _Lattice.trajectories
    Eq. (19) the six boundary conditions     -> quintic_coefficients
    Eq. (20) cost = K1 phi_coll + ... + K5   -> base_action
    Eq. (21) the five terms; delta_traj      -> _Lattice (phi_v, phi_t), base_action;
             from constant-speed predictions    path_occupancy
    FSM: drive / slow down to stop / brake   -> base_action
    Eq. (22) a_t1, Eq. (23) min(a_t1, a_IDM) -> base_action, idm_acceleration

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
    desired_gap = s0 + np.maximum(0.0, v * time_headway + v * dv / (2 * np.sqrt(a_max * b)))
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
        self.drive_ids = np.arange(len(drive))
        self.stop_ids = np.arange(len(drive), len(drive) + len(stop))
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
        self.fixed = self.trajectories(0.0, 0.0)
        self.per_v0 = self.trajectories(1.0, 0.0) - self.fixed
        self.per_a0 = self.trajectories(0.0, 1.0) - self.fixed
        # Feasibility bounds of (speed, acceleration): no reversing, v_max, [a_min, a_max].
        self.lower = np.array([[-_SLACK], [cfg.a_min - _SLACK]])  # [m/s], [m/s^2]
        self.upper = np.array([[cfg.v_max], [cfg.a_max + _SLACK]])  # [m/s], [m/s^2]
        # Eq. (21): phi_v = |sqrt(v_le^2 + v_de^2) - v_hat| = |v_e - v_hat| (v_de = 0), with
        # v_hat the target speed for the drive set and 0 for the stop set
        v_hat = np.where(np.arange(len(self.te)) < len(drive), cfg.v_target, 0.0)
        self.phi_v = np.abs(self.ve - v_hat)
        # Eq. (21): phi_t = t_e
        self.phi_t = self.te

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


def path_segments(path_s: np.ndarray, path_xy: np.ndarray) -> PathSegments:
    """The path's segments, extended straight by _EXTENSION at both ends (so that a vehicle
    behind the path's start is on it too); repeated points dropped."""
    distinct = np.append(True, np.diff(path_s) > 1e-9)  # a repeated point has no direction
    z, s = path_xy[distinct, 0] + 1j * path_xy[distinct, 1], path_s[distinct]
    first, last = (z[1] - z[0]) / abs(z[1] - z[0]), (z[-1] - z[-2]) / abs(z[-1] - z[-2])
    z = np.concatenate(([z[0] - first * _EXTENSION], z, [z[-1] + last * _EXTENSION]))
    s = np.concatenate(([s[0] - _EXTENSION], s, [s[-1] + _EXTENSION]))
    return PathSegments(z[:-1], np.conj(np.diff(z) / np.diff(s)), np.diff(s), s[:-1])


@lru_cache(maxsize=64)
def _cached_path_segments(s_bytes: bytes, xy_bytes: bytes) -> PathSegments:
    """path_segments keyed by the path's content: a path changes per episode, not per step."""
    return path_segments(np.frombuffer(s_bytes), np.frombuffer(xy_bytes).reshape(-1, 2))


class Occupancy(NamedTuple):
    """When and where vehicle j's prediction is on segment i of the ego path; each (M, S)."""

    t_in: np.ndarray  # [s] start of the time window (empty if t_in > t_out)
    t_out: np.ndarray  # [s] end of the time window
    s_start: np.ndarray  # [m] its arc length on the path at t = 0, measured on segment i
    s_rate: np.ndarray  # [m/s] its speed along segment i: s(t) = s_start + s_rate t
    half_along: np.ndarray  # [m] half its extent along segment i


def _window(x0: np.ndarray, rate: np.ndarray, low: ArrayLike, high: ArrayLike):
    """The times t at which low < x0 + rate t < high, as (start, end) arrays."""
    rate = np.where(np.abs(rate) < 1e-9, 1e-9, rate)  # no motion: a window of all or no time
    t_low, t_high = (low - x0) / rate, (high - x0) / rate
    return np.minimum(t_low, t_high), np.maximum(t_low, t_high)


def path_occupancy(others: np.ndarray, path: PathSegments, cfg: PlannerConfig) -> Occupancy:
    """The others' predictions against the ego path. Paper: each vehicle keeps its current
    speed and heading, so its prediction is a straight line.

    In a segment's frame, a straight-line motion is linear in time along and across, so the
    time window in which a vehicle is inside the segment's band follows in closed form, with
    no sampled points to project. The band's half width is the two vehicles' half extents
    across the path (each an L x W box at its heading) plus a margin; along the path the band
    reaches that far past each segment end, which covers the outer side of a bend.
    """
    L, W = cfg.length, cfg.width
    heading = np.exp(1j * others[:, 3:4]) * path.to_segment  # (M, S): cos + i sin of the relative heading
    position = (others[:, 0:1] + 1j * others[:, 1:2] - path.start) * path.to_segment  # (M, S) [m]
    velocity = others[:, 2:3] * heading  # (M, S) [m/s]
    cos_rel, sin_rel = np.abs(heading.real), np.abs(heading.imag)
    half_along = 0.5 * (L * cos_rel + W * sin_rel)
    band = W / 2 + 0.5 * (L * sin_rel + W * cos_rel) + cfg.lateral_margin  # [m]
    t_in_across, t_out_across = _window(position.imag, velocity.imag, -band, band)
    t_in_along, t_out_along = _window(position.real, velocity.real, -band, path.length + band)
    return Occupancy(np.maximum(t_in_across, t_in_along), np.minimum(t_out_across, t_out_along),
                     path.s_start + position.real, velocity.real, half_along)


def base_action(s0: float, v0: float, a0: float, path_s: np.ndarray, path_xy: np.ndarray,
                others: np.ndarray, cfg: PlannerConfig = PlannerConfig()) -> tuple[float, str]:
    """a_base of Eq. (23) in [a_min, a_max] and the FSM's mode: "drive", "stop" or "brake".

    s0 [m], v0 [m/s], a0 [m/s^2]: arc length of the ego's CENTRE on its path, its speed and its
    realised acceleration. path_s (N,) [m]: cumulative Euclidean length along path_xy (N, 2) [m],
    path_s[0] = 0. others (M, 4), M >= 0, the ego excluded: centre x [m], y [m], speed [m/s],
    heading [rad, counter-clockwise from +x].
    """
    lat = lattice(cfg)
    L = cfg.length
    a0 = min(max(a0, cfg.a_min), cfg.a_max)  # round-off in a0 must not make every candidate infeasible

    # Eqs. (18)-(19): every candidate from (v0, a0) at once (see _Lattice); positions past s0
    trajectories = lat.fixed + v0 * lat.per_v0 + a0 * lat.per_a0  # (4, K, C)
    pos, acc, jerk = trajectories[0], trajectories[2], trajectories[3]  # (K, C) each
    # Kinematic feasibility: 0 <= v <= v_max (no reversing) and a_min <= a <= a_max throughout.
    speed_acc = trajectories[1:3]  # (2, K, C)
    feasible = ((speed_acc.min(axis=1) >= lat.lower) & (speed_acc.max(axis=1) <= lat.upper)).all(axis=0)

    # The others' constant-speed predictions against the path; only vehicles whose prediction
    # meets the path within the horizon matter.
    others = np.asarray(others, dtype=float).reshape(-1, 4)
    path_s, path_xy = np.asarray(path_s, dtype=float), np.asarray(path_xy, dtype=float)
    occ = path_occupancy(others, _cached_path_segments(path_s.tobytes(), path_xy.tobytes()), cfg)
    meets = ((occ.t_in <= occ.t_out) & (occ.t_in <= cfg.horizon) & (occ.t_out >= 0.0)).any(axis=1)
    occ = Occupancy(*(field[meets] for field in occ))
    # One arc length per (vehicle, grid time): that of the first segment whose window holds the
    # time. Two segments share a time where the path bends (their s differ by < a band width).
    inside = (occ.t_in[..., None] <= lat.times) & (lat.times <= occ.t_out[..., None])  # (M, S, K)
    on_path, seg = inside.any(axis=1), inside.argmax(axis=1)  # (M, K) each
    vehicle = np.arange(len(seg))[:, None]
    s_other = occ.s_start[vehicle, seg] + occ.s_rate[vehicle, seg] * lat.times  # (M, K) [m]
    half_along = occ.half_along[vehicle, seg]  # (M, K) [m]
    # A vehicle on the path behind the ego now is a follower: no plan of the ego can avoid
    # it (SUMO's car following brakes it), so it blocks no candidate.
    follower = on_path[:, 0] & (s_other[:, 0] < s0)  # (M,)
    blocking = on_path & ~follower[:, None]  # (M, K)

    # delta_traj: a candidate collides if at some grid time it is closer along the path to a
    # blocking vehicle than their two half lengths plus the margin. Only the (vehicle, time)
    # pairs with a vehicle on the path, and only feasible candidates (no other is ever chosen),
    # are compared.
    j, k = np.nonzero(blocking)  # (P,) each
    checked = np.flatnonzero(feasible)  # (C',)
    apart = pos[:, checked][k] - (s_other[j, k] - s0)[:, None]  # (P, C') [m]
    close = np.abs(apart) < (L / 2 + half_along[j, k] + cfg.longitudinal_margin)[:, None]
    # Eq. (21): phi_coll = delta_traj
    phi_coll = np.zeros(len(lat.te))
    phi_coll[checked] = close.any(axis=0)
    # Eq. (21): phi_d = |d_e - d0| + |d_e - d_ref| = 0, since the ego stays on its lane centre
    phi_d = 0.0
    # Eq. (21): phi_jerk = sum_t (|l'''(t)| + |d'''(t)|), a Riemann sum over the grid (d''' = 0)
    phi_jerk = np.abs(jerk).sum(axis=0) * cfg.dt
    # Eq. (20): cost = K1 phi_coll + K2 phi_v + K3 phi_t + K4 phi_d + K5 phi_jerk
    cost = cfg.K1 * phi_coll + cfg.K2 * lat.phi_v + cfg.K3 * lat.phi_t + cfg.K4 * phi_d + cfg.K5 * phi_jerk
    cost = np.where(feasible, cost, np.inf)

    # FSM: the cheapest drive candidate if it is collision-free, else the cheapest stop
    # candidate if it is, else brake in emergency. (K1 makes the cheapest candidate of a set
    # collision-free whenever a feasible collision-free one exists.)
    a_t1, mode = cfg.a_min, "brake"
    for name, ids in (("drive", lat.drive_ids), ("stop", lat.stop_ids)):
        best = ids[np.argmin(cost[ids])]
        if cost[best] < cfg.K1:
            # Eq. (22): a_t1 = sqrt(l''(t1)^2 + d''(t1)^2), kept WITH the sign of l''(t1), as d'' = 0
            # on a fixed path: the printed magnitude could never brake (EQUATIONS.md, note 3).
            a_t1, mode = acc[1, best], name
            break

    # IDM toward the leader: the nearest vehicle on the path ahead of the ego now.
    ahead = on_path[:, 0] & (s_other[:, 0] > s0)
    gap, dv = np.inf, 0.0  # free road
    if ahead.any():
        gaps = np.where(ahead, s_other[:, 0] - s0 - L / 2 - half_along[:, 0], np.inf)  # bumper to bumper
        leader = np.argmin(gaps)
        gap, dv = gaps[leader], v0 - occ.s_rate[leader, seg[leader, 0]]
    a_idm = idm_acceleration(v0, cfg.v_target, gap, dv, cfg.a_max, cfg.idm_comfort_decel,
                             cfg.idm_min_gap, cfg.idm_time_headway, cfg.idm_delta)
    # Eq. (23): a_base = min(a_t1, a_IDM), within the ego's limits
    return float(np.clip(min(a_t1, a_idm), cfg.a_min, cfg.a_max)), mode
