"""The base planner of timing-aware RL: the conservative base action a_base.

Paper: "Act Better by Timing: A timing-Aware Reinforcement Learning for Autonomous Driving",
Section 4, last part ("The base model consists of a finite state machine (FSM) and a lattice
planner ...", Eqs. (18)-(23)); equation numbers are the printed ones. The ego follows a fixed
path and stays on its lane centre, so the lateral half of the lattice collapses (d = d0 = d_ref
= 0, v_de = 0, d'' = d''' = 0) and every candidate is a longitudinal quintic l(t). Each call
scores a fixed lattice of end states (t_e, l_e, v_e) at once with numpy, lets a three-state FSM
pick a trajectory and caps its next acceleration by IDM toward the leader on the path. For
delta_traj each other vehicle keeps its speed and yaw rate (an arc; the straight line at yaw
rate 0), sampled at the grid times t_k = k dt and placed on the path by a band test.

Map from the paper to this file:
    Eq. (18) l(t) = c1 t^5 + ... + c6        -> _Lattice.powers, _Lattice.trajectories
    Eq. (19) the six boundary conditions     -> quintic_coefficients
    Eq. (20) cost = K1 phi_coll + ... + K5   -> lattice_cost
    Eq. (21) the five terms                  -> _Lattice (phi_v, phi_t, phi_d), lattice_cost
             (phi_jerk), collision_term (phi_coll = delta_traj, from predict and on_path)
    FSM: drive / slow down to stop / brake   -> state_machine
    Eq. (22) a_t1, Eq. (23) min(a_t1, a_IDM) -> base_acceleration, idm_acceleration, leader
    one planning step                        -> plan (and the chosen trajectory), base_action

Units: metres, seconds, radians (counter-clockwise from +x); points as complex numbers x + iy.
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


@dataclass(frozen=True, kw_only=True)
class PlannerConfig:
    """Settings of the base planner. The paper gives only a_min, a_max, L_car and W_car."""
    # The ego's step, limits and size have no default here: their home is world.EnvConfig.
    dt: float  # [s] the environment's step: t1 of Eq. (22) and the step of the time grid
    a_min: float  # [m/s^2] ego deceleration limit (paper, Section 5.2), also the emergency brake
    a_max: float  # [m/s^2] ego acceleration limit (paper, Section 5.2)
    length: float  # L_car [m] (Table 1), the ego and the others
    width: float  # W_car [m] (Table 1), the ego and the others
    v_target: float = 10.0  # v_hat [m/s] of the drive set: middle of Table 1's target 8-12 m/s
    v_max: float = 15.0  # [m/s] feasibility cap, above v_hat so a quintic may overshoot a little
    # The lattice (not in the paper). A quintic stop from v0 with a_le = 0 brakes at up to
    # 1.875 v0 / t_e, so stopping from 12 m/s within 3 m/s^2 needs t_e = 8 s; 2 s is agile.
    end_times: tuple[float, ...] = (2.0, 3.0, 4.0, 6.0, 8.0)  # t_e [s]
    # Drive set: v_e of 0.2-1.0 v_hat (the ego can yield and still "drive"), l_e = f (v0 + v_e) / 2 t_e
    # with f = 1 the symmetric speed change, 0.9 / 1.1 later / earlier: 5 x 5 x 3 = 75 candidates.
    drive_speed_fractions: tuple[float, ...] = (0.2, 0.4, 0.6, 0.8, 1.0)  # v_e / v_hat [-]
    drive_distance_factors: tuple[float, ...] = (0.9, 1.0, 1.1)  # f [-]
    # Stop set: v_e = 0, l_e = f v0 / 2 t_e (f < 1 brakes early). 5 x 4 = 20 candidates.
    stop_distance_factors: tuple[float, ...] = (0.6, 0.8, 1.0, 1.2)  # f [-]
    horizon: float = 8.0  # [s] = the longest t_e: span of predictions, collision check, phi_jerk
    # Eq. (20): weights (not in the paper). K1 exceeds the others' sum (below 10 if feasible): a set's
    # cheapest candidate is collision-free if any is; K2 (speed) dominates; K3, K5 favour short, smooth plans.
    K1: float = 1000.0  # [-] per collision
    K2: float = 1.0  # [s/m]
    K3: float = 0.1  # [1/s]
    K4: float = 1.0  # [1/m], multiplies phi_d = 0 on a fixed path
    K5: float = 0.1  # [s^2/m]
    # The others keep their yaw rate (predict), clamped to v / 5 m: no car turns tighter than about 5 m;
    # more is noise (SUMO's heading jumps where a lane's polyline bends; a crawling car would spin).
    min_turn_radius: float = 5.0  # [m]
    # Collision check: margins added to the two vehicles' half extents. Laterally a parallel
    # vehicle in the next lane (3.2 m away, Table 1) stays outside the band W + 0.5 = 2.5 m.
    lateral_margin: float = 0.5  # [m]
    # Along the path; a crossing vehicle's contact zone (2 x 4.5 m) is then wider than the ego's
    # travel in one grid step (3 m at v_max), so grid sampling cannot step over it.
    longitudinal_margin: float = 1.0  # [m]
    # IDM of Eq. (23) with the ego's own values (not in the paper; Table 1 gives the humans').
    idm_min_gap: float = 2.0  # s0 [m]: low end of Table 1's d_min 2-4 m
    idm_time_headway: float = 1.5  # T [s]: Treiber's usual value
    idm_comfort_decel: float = 2.0  # b [m/s^2]: low end of Table 1's 2.0-4.5 (a gentle ego)
    idm_delta: float = 4.0  # [-] Treiber's acceleration exponent


def quintic_coefficients(l0: ArrayLike, v0: ArrayLike, a0: ArrayLike, le: ArrayLike,
                         ve: ArrayLike, ae: ArrayLike, te: ArrayLike) -> np.ndarray:
    """Solve Eq. (19) in closed form: (c1, ..., c6) of Eq. (18) on the last axis; the arguments
    broadcast (te > 0), the result has shape broadcast(inputs) + (6,). Rows 1-3 of Eq. (19), at t = 0,
    fix c6 = l0, c5 = v0, c4 = a0 / 2; rows 4-6, at t = te, are then A x = b in x = (c1, c2, c3):

        [    te^5     te^4    te^3 ] [c1]   [ le - l0 - v0 te - a0 te^2 / 2 ]
        [  5 te^4   4 te^3  3 te^2 ] [c2] = [ ve - v0 - a0 te               ]
        [ 20 te^3  12 te^2  6 te   ] [c3]   [ ae - a0                       ]

    solved by hand below (test_tarl.py checks all six against numpy.linalg.solve)."""
    l0, v0, a0, le, ve, ae, te = (np.asarray(x, dtype=float) for x in (l0, v0, a0, le, ve, ae, te))
    dl = le - l0
    c3 = (20 * dl - (8 * ve + 12 * v0) * te - (3 * a0 - ae) * te**2) / (2 * te**3)
    c2 = (-30 * dl + (14 * ve + 16 * v0) * te + (3 * a0 - 2 * ae) * te**2) / (2 * te**4)
    c1 = (12 * dl - 6 * (ve + v0) * te + (ae - a0) * te**2) / (2 * te**5)
    return np.stack(np.broadcast_arrays(c1, c2, c3, a0 / 2, v0, l0), axis=-1)


def idm_acceleration(v: ArrayLike, v_desired: ArrayLike, gap: ArrayLike, dv: ArrayLike, a_max: float,
                     b: float, s0: float, time_headway: float, delta: float = 4.0) -> float | np.ndarray:
    """Intelligent Driver Model (Treiber, Hennecke and Helbing, 2000), vectorised: v [m/s] own
    speed, gap [m] bumper to bumper (np.inf: free road), dv = v - v_leader [m/s], a_max and b
    [m/s^2] maximum and comfortable deceleration, s0 [m] jam distance, time_headway [s]."""
    desired_gap = s0 + np.maximum(0.0, v * time_headway + v * dv / (2 * math.sqrt(a_max * b)))
    # A gap held at 1 cm or more keeps the braking finite for touching vehicles.
    return a_max * (1 - (v / v_desired) ** delta - (desired_gap / np.maximum(gap, 0.01)) ** 2)


class _Lattice:
    """The candidates and all that depends only on the config; arrays (K, C), time by candidate."""
    def __init__(self, cfg: PlannerConfig):
        assert max(cfg.end_times) <= cfg.horizon + _SLACK, "the horizon must cover every t_e"
        drive = [(te, fv * cfg.v_target, f) for te in cfg.end_times
                 for fv in cfg.drive_speed_fractions for f in cfg.drive_distance_factors]
        stop = [(te, 0.0, f) for te in cfg.end_times for f in cfg.stop_distance_factors]
        self.te, self.ve, self.f = np.array(drive + stop).T  # (C,) each: t_e [s], v_e [m/s], f [-]
        self.drive_ids, self.stop_ids = slice(0, len(drive)), slice(len(drive), len(drive) + len(stop))
        self.times = np.arange(round(cfg.horizon / cfg.dt) + 1) * cfg.dt  # (K,) [s]; times[1] = t1
        # Eq. (18): l and its derivatives on the grid, l^(n)(t_k) = powers[n, k] @ (c1, ..., c6)
        exponents = np.arange(5, -1, -1)  # c1 multiplies t^5, ..., c6 t^0
        self.powers = np.stack([np.array([math.perm(e, n) for e in exponents])  # e!/(e-n)!
                                * self.times[:, None] ** np.maximum(exponents - n, 0)
                                for n in range(4)])  # (4, K, 6): l, l', l'', l'''
        self.after = self.times[:, None] > self.te + _SLACK  # (K, C): past t_e
        # Eq. (19): linear in (l0, v_l0, a_l0, l_e, v_le, a_le), and l_e is linear in v0, so the
        # trajectories from (v0, a0) are (1, v0, a0) @ responses: (3, 4, K, C), solved once here.
        fixed = self.trajectories(0.0, 0.0)
        self.responses = np.stack([fixed, self.trajectories(1.0, 0.0) - fixed,
                                   self.trajectories(0.0, 1.0) - fixed])
        self.lower = np.array([[-_SLACK], [cfg.a_min - _SLACK]])  # feasible (speed, acc) >= this: no reversing, a_min
        self.upper = np.array([[cfg.v_max], [cfg.a_max + _SLACK]])  # and <= this: v_max, a_max [m/s], [m/s^2]
        # Eq. (21): phi_v = |sqrt(v_le^2 + v_de^2) - v_hat| = |v_e - v_hat| (v_de = 0; v_hat = 0 to stop)
        self.phi_v = np.abs(self.ve - np.where(np.arange(len(self.te)) < len(drive), cfg.v_target, 0.0))
        self.phi_t = self.te  # Eq. (21): phi_t = t_e
        self.phi_d = 0.0  # Eq. (21): phi_d = |d_e - d0| + |d_e - d_ref| = 0, the ego stays on its lane centre

    def trajectories(self, v0: float, a0: float) -> np.ndarray:
        """(4, K, C): l - l0 and its first three derivatives for every candidate, from (v0, a0)."""
        le = self.f * (v0 + self.ve) / 2 * self.te  # [m] past l0
        # Eq. (19): with l0 = 0 and a_le = 0 (the paper's choice), all candidates at once
        c = quintic_coefficients(0.0, v0, a0, le, self.ve, 0.0, self.te)  # (C, 6)
        # Eq. (18): l(t) = c1 t^5 + c2 t^4 + c3 t^3 + c4 t^2 + c5 t + c6, and its derivatives
        polynomial = self.powers @ c.T  # (4, K, C)
        # After t_e a candidate continues at constant speed v_e (l'' = l''' = 0).
        constant_speed = np.zeros_like(polynomial)
        constant_speed[0] = le + self.ve * (self.times[:, None] - self.te)
        constant_speed[1] = self.ve
        return np.where(self.after, constant_speed, polynomial)


lattice = lru_cache(maxsize=8)(_Lattice)  # lattice(cfg): the lattice of a config, built on first use


class PathSegments(NamedTuple):
    """The ego path as S straight segments; points as complex numbers x + iy [m]."""
    start: np.ndarray  # (S,) complex [m] first point of each segment
    to_segment: np.ndarray  # (S,) conj(unit tangent): times it, a vector is in the segment's frame
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
    # The bend alpha at each inner point: a band reaching band tan(alpha / 2) past a segment's end
    # meets the next one's on the bisector, closing the bend's outer side and reaching no further
    # (a full band width would reach the next lane out). Capped at a right angle, the sharpest.
    bend = np.abs(np.angle(to_segment[1:] / to_segment[:-1]))  # (S - 1,) [rad]
    miter = np.tan(np.minimum(bend, np.pi / 2) / 2)
    return PathSegments(z[:-1], to_segment, np.diff(s), s[:-1], (z[:-1] + z[1:]) / 2,
                        np.append(0.0, miter), np.append(miter, 0.0))


@lru_cache(maxsize=64)
def _cached_path_segments(s_bytes: bytes, xy_bytes: bytes) -> PathSegments:
    """path_segments keyed by the path's content: a path changes per episode, not per step."""
    return path_segments(np.frombuffer(s_bytes), np.frombuffer(xy_bytes).reshape(-1, 2))


def as_others(others: ArrayLike) -> np.ndarray:
    """The others (M, 5): x, y [m], speed [m/s], heading [rad], yaw rate [rad/s] (0 if (M, 4))."""
    others = np.asarray(others, dtype=float)
    others = others.reshape(-1, others.shape[-1]) if others.size else np.zeros((0, 5))
    return np.column_stack([others, np.zeros(len(others))]) if others.shape[1] == 4 else others


def predict(others: ArrayLike, times: np.ndarray, cfg: PlannerConfig) -> tuple[np.ndarray, np.ndarray]:
    """Each vehicle at constant speed and turn rate (CTRV) at the times (K,) [s]: its centre x + iy
    [m] and heading exp(i psi), (M, K) complex each. The paper says only "at a constant speed"; on
    a straight line a ring vehicle would cut across the entry lanes, an inner-ring one drift (v t)^2
    / 2R = 1.3 m into the outer lane in 1 s (R = 25 m, v = 8 m/s): the ego would yield for nothing."""
    x, y, v, psi, omega = as_others(others).T
    omega = np.minimum(np.maximum(omega, -v / cfg.min_turn_radius), v / cfg.min_turn_radius)  # [rad/s]
    half = 0.5 * omega[:, None] * times  # (M, K) [rad] half the heading change by t_k
    sin_half = np.sin(half)
    half_turn = np.cos(half) + 1j * sin_half  # exp(i half)
    # The arc z(t) = z0 + (v / omega) (exp(i (psi + omega t)) - exp(i psi)) / i is its chord from
    # z0: 2 (v / omega) sin(half) long (v t when omega = 0, and no round-off near it), heading psi + half.
    chord = np.divide(2 * v[:, None] * sin_half, omega[:, None], out=v[:, None] * times,
                      where=omega[:, None] != 0)  # (M, K) [m]
    heading = np.exp(1j * psi)[:, None] * half_turn  # exp(i (psi + half))
    return (x + 1j * y)[:, None] + chord * heading, heading * half_turn


class OnPath(NamedTuple):
    """The others' predictions on the ego path at the grid times: (M, K) each, NaN off the path."""
    s: np.ndarray  # [m] arc length of its centre along the path
    s_rate: np.ndarray  # [m/s] its speed along the path
    half_along: np.ndarray  # [m] half its extent along the path


def on_path(others: ArrayLike, path: PathSegments, times: np.ndarray, cfg: PlannerConfig) -> OnPath:
    """Where the predictions of `others` (M, 5) are on the path at the grid times (K,) [s]: in
    the band of a segment (the first, where two hold it at a bend). Across, the band is the two
    vehicles' half extents across the path (L x W boxes at their headings) plus the lateral
    margin; along, it reaches band tan(bend / 2) past the segment's ends (PathSegments.miter_*)."""
    others, L, W, K = as_others(others), cfg.length, cfg.width, len(times)
    seen = OnPath(*np.full((3, len(others), K), np.nan))
    centre, heading = predict(others, times, cfg)  # (M, K) each
    # Cheap tests first: the (vehicle, segment) pairs that may meet (a vehicle stays within v t_K / 2
    # of its place at t_K / 2, a band within sqrt(2) band_max of its segment); then of their points
    # at t_k, those within `radius` of the segment's middle.
    band_max = W / 2 + 0.5 * math.hypot(L, W) + cfg.lateral_margin  # [m] the widest band
    radius = np.hypot(path.length / 2 + band_max, band_max)  # (S,) [m]
    midway = (centre[:, K // 2, None] - path.start) * path.to_segment  # (M, S) [m]
    distance = np.abs(midway - np.clip(midway.real, 0.0, path.length))  # [m] to the segment
    v, half_span = others[:, 2], max(times[K // 2], times[-1] - times[K // 2])  # [m/s], [s]
    vehicle, segment = (distance < math.sqrt(2) * band_max + v[:, None] * half_span).nonzero()
    pair, k = (np.abs(centre[vehicle] - path.middle[segment, None]) < radius[segment, None]).nonzero()
    m, segment = vehicle[pair], segment[pair]  # (P,) each, with k: by vehicle, segment, then time
    # In the segment's frame: real part along the path, imaginary part to the left.
    to_segment = path.to_segment[segment]
    position, heading = (centre[m, k] - path.start[segment]) * to_segment, heading[m, k] * to_segment
    cos_rel, sin_rel = np.abs(heading.real), np.abs(heading.imag)
    band = W / 2 + cfg.lateral_margin + (L / 2 * sin_rel + W / 2 * cos_rel)  # [m]
    inside = ((np.abs(position.imag) <= band) & (position.real >= -band * path.miter_start[segment])
              & (position.real <= path.length[segment] + band * path.miter_end[segment])).nonzero()[0]
    # Each (vehicle, time) once, on its first segment (np.unique keeps the first occurrence).
    i = inside[np.unique(m[inside] * K + k[inside], return_index=True)[1]]
    m, k = m[i], k[i]
    seen.s[m, k] = path.s_start[segment[i]] + position.real[i]
    seen.s_rate[m, k] = v[m] * heading.real[i]
    seen.half_along[m, k] = L / 2 * cos_rel[i] + W / 2 * sin_rel[i]
    return seen


def collision_term(positions: np.ndarray, seen: OnPath, s0: float, cfg: PlannerConfig) -> np.ndarray:
    """phi_coll = delta_traj of Eq. (21), (C,): 1 for a candidate (positions (K, C) [m] past s0)
    that at some t_k is closer along the path to a vehicle than half their lengths plus the margin.
    A vehicle on the path behind the ego now (SUMO's car following brakes it) blocks nothing."""
    ahead = seen.s - s0  # (M, K) [m] along the path from the ego's centre, < 0 behind it
    m, k = (~np.isnan(ahead) & ~(ahead[:, :1] < 0)).nonzero()  # on the path, not a follower
    reach = cfg.length / 2 + seen.half_along[m, k, None] + cfg.longitudinal_margin  # (P, 1) [m]
    return (np.abs(positions[k] - ahead[m, k, None]) < reach).any(axis=0).astype(float)


def lattice_cost(phi_coll: np.ndarray, jerk: np.ndarray, lat: _Lattice, cfg: PlannerConfig) -> np.ndarray:
    """Eq. (20) for every candidate, (C,), from phi_coll (C,) and the jerk l''' (K, C) [m/s^3]."""
    # Eq. (21): phi_jerk = sum_t (|l'''(t)| + |d'''(t)|), a Riemann sum over the grid (d''' = 0)
    phi_jerk = np.abs(jerk).sum(axis=0) * cfg.dt
    # Eq. (20): cost = K1 phi_coll + K2 phi_v + K3 phi_t + K4 phi_d + K5 phi_jerk
    return cfg.K1 * phi_coll + cfg.K2 * lat.phi_v + cfg.K3 * lat.phi_t + cfg.K4 * lat.phi_d + cfg.K5 * phi_jerk


def state_machine(cost: np.ndarray, drive_ids: slice, stop_ids: slice, K1: float) -> tuple[str, int | None]:
    """The FSM on the costs (np.inf: infeasible): ("drive", the cheapest drive candidate) if it is
    collision-free (cost < K1), else ("stop", the cheapest stop one) if it is, else ("brake", None)."""
    for mode, ids in (("drive", drive_ids), ("stop", stop_ids)):
        best = ids.start + int(np.argmin(cost[ids]))
        if cost[best] < K1:
            return mode, best
    return "brake", None


def base_acceleration(l_dd_t1: float, a_idm: float, cfg: PlannerConfig) -> float:
    """a_base [m/s^2] in [a_min, a_max] from the chosen candidate's l''(t1) (t1 = dt) and a_IDM."""
    # Eq. (22): a_t1 = sqrt(l''(t1)^2 + d''(t1)^2), kept WITH the sign of l''(t1): on a fixed path
    # d'' = 0, and the printed magnitude could never brake (PAPER.md).
    a_t1 = math.copysign(math.hypot(l_dd_t1, 0.0), l_dd_t1)  # d''(t1) = 0
    # Eq. (23): a_base = min(a_t1, a_IDM)
    return float(min(max(min(a_t1, a_idm), cfg.a_min), cfg.a_max))


def leader(seen: OnPath, s0: float, v0: float, cfg: PlannerConfig) -> tuple[float, float]:
    """IDM's gap [m] and v0 - v_leader [m/s] to the nearest vehicle on the path ahead now; (inf, 0)."""
    ahead = seen.s[:, 0] - s0  # (M,) [m], NaN off the path
    leading = (ahead > 0).nonzero()[0]
    if not len(leading):
        return math.inf, 0.0
    gaps = ahead[leading] - cfg.length / 2 - seen.half_along[leading, 0]
    nearest = leading[int(gaps.argmin())]
    return float(gaps.min()), v0 - float(seen.s_rate[nearest, 0])


class Plan(NamedTuple):
    """One planning step: a_base, the FSM's mode and the chosen trajectory along the path."""
    a_base: float  # [m/s^2] Eq. (23)
    mode: str  # "drive", "stop" or "brake"
    t: np.ndarray  # (K,) [s] the grid times t_k = k dt
    s: np.ndarray  # (K,) [m] ego centre's arc length: the chosen candidate (braking: a_min to a stop)


def plan(s0: float, v0: float, a0: float, path_s: ArrayLike, path_xy: ArrayLike,
         others: ArrayLike, cfg: PlannerConfig) -> Plan:
    """The base planner's step and the chosen trajectory; the arguments are base_action's."""
    s0, v0, lat = float(s0), float(v0), lattice(cfg)
    a0 = min(max(float(a0), cfg.a_min), cfg.a_max)  # round-off must not make every candidate infeasible
    # Eqs. (18)-(19): every candidate's position past s0, speed, acceleration and jerk, (4, K, C)
    trajectories = np.dot((1.0, v0, a0), lat.responses.reshape(3, -1)).reshape(lat.responses.shape[1:])
    positions, acc, jerk = trajectories[0], trajectories[2], trajectories[3]  # (K, C) each
    # Kinematic feasibility: 0 <= v <= v_max (no reversing) and a_min <= a <= a_max throughout.
    feasible = ((trajectories[1:3].min(axis=1) >= lat.lower) & (trajectories[1:3].max(axis=1) <= lat.upper)).all(axis=0)
    phi_coll = np.zeros(len(lat.te))
    if feasible.any():  # (else the FSM brakes, whatever the others do)
        path = _cached_path_segments(*(np.asarray(p, dtype=float).tobytes() for p in (path_s, path_xy)))
        seen = on_path(others, path, lat.times, cfg)
        phi_coll[feasible] = collision_term(positions[:, feasible], seen, s0, cfg)
    cost = np.where(feasible, lattice_cost(phi_coll, jerk, lat, cfg), np.inf)
    mode, best = state_machine(cost, lat.drive_ids, lat.stop_ids, cfg.K1)
    if best is None:  # brake: a_t1 = a_min, and so is a_base of Eq. (23), whatever IDM says
        t = np.minimum(lat.times, v0 / -cfg.a_min)  # [s] braking ends at a standstill
        return Plan(float(cfg.a_min), mode, lat.times, s0 + v0 * t + cfg.a_min / 2 * t**2)
    gap, dv = leader(seen, s0, v0, cfg)
    a_idm = idm_acceleration(v0, cfg.v_target, gap, dv, cfg.a_max, cfg.idm_comfort_decel,
                             cfg.idm_min_gap, cfg.idm_time_headway, cfg.idm_delta)
    return Plan(base_acceleration(float(acc[1, best]), a_idm, cfg), mode, lat.times, s0 + positions[:, best])


def base_action(s0: float, v0: float, a0: float, path_s: ArrayLike, path_xy: ArrayLike,
                others: ArrayLike, cfg: PlannerConfig) -> tuple[float, str]:
    """a_base of Eq. (23) in [a_min, a_max] and the FSM's mode: "drive", "stop" or "brake".

    s0 [m], v0 [m/s], a0 [m/s^2]: arc length of the ego's CENTRE on its path, its speed and its
    realised acceleration. path_s (N,) [m]: cumulative length along path_xy (N, 2) [m], from 0.
    others (M, 5), the ego excluded: centre x [m], y [m], speed [m/s], heading [rad] and yaw rate
    [rad/s], both counter-clockwise; (M, 4) without the yaw rate means yaw rate 0."""
    a_base, mode, _, _ = plan(s0, v0, a0, path_s, path_xy, others, cfg)
    return a_base, mode
