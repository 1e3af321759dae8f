"""tarl: timing-aware reinforcement learning for autonomous driving, in SUMO.

Reference implementation of Li, Wu, He, "Act Better by Timing: A timing-Aware
Reinforcement Learning for Autonomous Driving". An ego vehicle crosses an
unsignalized intersection or a roundabout among human drivers (IDM car
following plus a level-k game with the ego). The base action comes from
`planner.py` (quintic lattice + state machine + IDM).

    python tarl.py --scenario intersection --algo lattice-idm --eval-rounds 2 --eval-cases 20

Equations are cited by the number printed in the paper's PDF
(../shared/paper/EQUATIONS.md maps them to the LaTeX labels).

Map from the paper to this file
    Sec. 3, Eqs. (1)-(2)        DrivingEnv.step: one SUMO step; SUMO + level-k drivers are xi_t
    Table 1                     SCENARIOS, DrivingEnv._spawn_human
    Eqs. (24)-(26) level-k game game_utility, level_k_decisions, DrivingEnv._play_level_k
    Eqs. (27)-(30) observation  sector_index, observe
    Eq. (31) reward             reward
    Sec. 5.3, Table 3           evaluate, main
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

import planner

HERE = Path(__file__).resolve().parent
EGO = "ego"

# --------------------------------------------------------------------------------------
# Settings
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Scenario:
    """One of the paper's two road networks (Sec. 5.1, Table 1)."""

    name: str
    spawn_gap: float  # t_spawn [s]: mean gap between two departures in the whole network (Table 1)
    t_sim: float  # t_sim [s]: the simulation is restarted after this long (Table 1)
    crossing_speed: tuple[float, float] | None  # v_cr [m/s]: human speed through the junction (Table 1)
    impatience: float  # SUMO's impatience of the humans [0-1], not in the paper: at 0 the two-lane
    #                    roundabout carries 0.69 of the paper's 0.83 veh/s and the entries back up;
    #                    at 1 waiting humans accept shorter gaps and it carries 0.75-0.80 veh/s.
    tasks: tuple[str, ...]  # h1 labels, in one-hot order (Eq. (29))


SCENARIOS = {
    "intersection": Scenario("intersection", 1.8, 5000.0, (4.5, 6.0), 0.0, ("straight", "left", "right")),
    "roundabout": Scenario("roundabout", 1.2, 1000.0, None, 1.0, ("exit1", "exit2", "exit3")),
}


@dataclass(frozen=True)
class EnvConfig:
    """The environment's constants. Where the paper gives none, the comment says why."""

    scenario: str = "intersection"
    dt: float = 0.2  # [s] SUMO step and decision step. Not in the paper: 5 Hz keeps episodes
    #                  at 50-150 decisions, so the +-20 terminal rewards of Eq. (31) weigh as
    #                  much as the speed reward, and T_max steps span ~2 s of "waiting for a chance".
    length: float = 5.0  # L_car [m] (Table 1)
    width: float = 2.0  # W_car [m] (Table 1)
    a_min: float = -3.0  # [m/s^2] ego's strongest braking command (Sec. 5.2)
    a_max: float = 2.0  # [m/s^2] ego's strongest acceleration command (Sec. 5.2)
    perception: float = 60.0  # d_max [m] perception radius (Sec. 5.2, Eq. (27))
    v_norm: float = 16.0  # v_max of Eq. (27) [m/s]: the road speed limit, the fastest anyone drives
    v_min: float = 1.0  # v_min of Eq. (31) [m/s]. Not in the paper: standing still costs a little
    #                     (-0.056 per step), yet waiting out the whole time limit (about -5 discounted)
    #                     still costs less than a collision (-20).
    v_max: float = 10.0  # v_max of Eq. (31) [m/s]. Not in the paper: the middle of the humans'
    #                      desired speeds (8-12 m/s, Table 1).
    ego_depart_speed: float = 8.0  # [m/s] the ego arrives at the scene moving like the traffic.
    destination: float = 20.0  # [m] past the start of the exit road, the ego has arrived.
    time_limit: float = 60.0  # [s] episode limit; a timeout is a failure (the planner's freezing
    #                           on the roundabout then counts against it, as in the paper).
    warmup: float = 120.0  # [s] traffic runs this long after every (re)start before the ego enters.
    spawn_clear: float = 12.0  # [m] the ego's spawn lane must be free this far from its start.
    # Level-k game (Eqs. (24)-(26)); the ranges of Eq. (25)'s min-max normalisation:
    gap_range: float = 5.0  # [s] phi_safe: arrival-time difference saturates here
    wait_range: float = 10.0  # [s] phi_eff: waiting for the other to pass
    emotion_range: float = 30.0  # [s] phi_emo: time already waited
    clear_time: float = 1.5  # [s] how long after the first vehicle the second may reach the conflict point
    game_horizon: float = 60.0  # [m] the ego's distance to a conflict point at which games start
    stop_margin: float = 3.0  # [m] a yielding human stops this far before the conflict point

    @property
    def sc(self) -> Scenario:
        return SCENARIOS[self.scenario]


# Table 1: per-human parameters, drawn uniformly from these ranges.
HUMAN_RANGES = dict(
    accel=(1.5, 3.0),  # a_max [m/s^2]
    decel=(2.0, 4.5),  # |b_min| [m/s^2] (EQUATIONS.md note 4: SUMO's decel is the magnitude)
    min_gap=(2.0, 4.0),  # d_min [m]
    speed=(8.0, 12.0),  # v_cf [m/s], desired car-following speed
    alpha1=(0.5, 0.8),  # safety weight of Eq. (24)
    alpha2=(0.05, 0.2),  # efficiency weight
    alpha3=(0.05, 0.2),  # comfort weight
    alpha4=(0.05, 0.2),  # emotion weight
    svo=(0.0, 0.5),  # alpha_svo of Eq. (26)
)
CONNECTION_SPEED = 6.0  # [m/s] speed attribute of the intersection's connections (scenarios/)
# The ego as the humans picture it in the game: the middle of Table 1's ranges.
EGO_GAME_WEIGHTS = np.array([0.65, 0.125, 0.125, 0.125])

# --------------------------------------------------------------------------------------
# The paper's math as pure functions
# --------------------------------------------------------------------------------------

# Eq. (28): sector edges [deg] of the half-open intervals (lo, hi], and the order of sectors in s_sur.
SECTOR_EDGES = np.array([-150.0, -90.0, -30.0, 30.0, 90.0, 150.0])
SECTOR_NAMES = ("front", "left front", "right front", "left rear", "right rear", "rear")
# searchsorted(SECTOR_EDGES, phi, side="left") = k means SECTOR_EDGES[k-1] < phi <= SECTOR_EDGES[k].
_BIN_TO_SECTOR = np.array([5, 4, 2, 0, 1, 3, 5])
_SECTOR_LOW = np.array([-30.0, 30.0, -90.0, 90.0, -150.0, 150.0])  # phi_low [deg] per sector


def wrap_angle(x):
    """Angle(s) [rad] wrapped into (-pi, pi]."""
    return np.pi - np.mod(np.pi - x, 2.0 * np.pi)


def sector_index(phi_deg):
    """Eq. (28)'s sector of a position angle phi [deg] in (-180, 180], relative to the ego's heading.

    front (-30, 30], left front (30, 90], right front (-90, -30], left rear (90, 150],
    right rear (-150, -90], rear (-180, -150] u (150, 180]. Angles are rounded to 1e-9 deg
    first, so a vehicle placed on a boundary lands where the half-open interval says despite
    floating-point error in atan2.
    """
    phi = np.round(np.asarray(phi_deg, dtype=float), 9)
    return _BIN_TO_SECTOR[np.searchsorted(SECTOR_EDGES, phi, side="left")]


def observe(ego_xy, ego_heading, ego_speed, task, zone, others, cfg: EnvConfig) -> np.ndarray:
    """Eqs. (27)-(30): s = (s_ego, s_sur), 3 + 3 + 1 + 12 x 5 = 67 numbers.

    ego_xy [m] centre, ego_heading [rad, CCW from +x], ego_speed [m/s]; task, zone: the
    indices of the one-hots h1, h2; others: (M, 4) centres x, y [m], speed [m/s], heading [rad].
    """
    s_sur = np.zeros((6, 2, 5))
    if len(others):
        rel = others[:, :2] - ego_xy
        d = np.hypot(rel[:, 0], rel[:, 1])
        seen = d <= cfg.perception
        rel, d, o = rel[seen], d[seen], others[seen]
        phi = np.degrees(wrap_angle(np.arctan2(rel[:, 1], rel[:, 0]) - ego_heading))
        sector = sector_index(phi)
        # the rear sector wraps: measure it on (150, 210] so phi_low < phi <= phi_high holds
        phi = np.where((sector == 5) & (phi <= -150.0), phi + 360.0, phi)
        order = np.lexsort((d, sector))  # by sector, then nearest first
        sector, d, phi, o = sector[order], d[order], phi[order], o[order]
        rank = np.arange(len(sector)) - np.searchsorted(sector, sector, side="left")
        keep = rank < 2  # the two nearest per sector (Eq. (28): j = 1, 2)
        i, j = sector[keep], rank[keep]
        # Eq. (27): d / d_max, v / v_max, (phi - phi_low) / (phi_high - phi_low), (theta - theta_ego + pi) / 2 pi
        s_sur[i, j, 0] = 1.0
        s_sur[i, j, 1] = d[keep] / cfg.perception
        s_sur[i, j, 2] = o[keep, 2] / cfg.v_norm
        s_sur[i, j, 3] = (phi[keep] - _SECTOR_LOW[i]) / 60.0
        s_sur[i, j, 4] = (wrap_angle(o[keep, 3] - ego_heading) + np.pi) / (2.0 * np.pi)
    # Eq. (29): s_ego = (h1, h2, v_ego / v_max)
    s_ego = np.zeros(7)
    s_ego[task] = 1.0
    s_ego[3 + zone] = 1.0
    s_ego[6] = ego_speed / cfg.v_norm
    # Eq. (30): s = (s_ego, s_sur)
    return np.concatenate([s_ego, s_sur.ravel()]).astype(np.float32)


OBS_DIM = 67


def reward(arrived: bool, collided: bool, v: float, v_min: float, v_max: float) -> float:
    """Eq. (31): +20 on arrival, -20 on collision, else min((v - v_min) / (v_max - v_min), 1) x 0.5."""
    if collided:
        return -20.0
    if arrived:
        return 20.0
    return min((v - v_min) / (v_max - v_min), 1.0) * 0.5


def boxes_overlap(center, heading, centers, headings, length, width) -> np.ndarray:
    """Separating-axis test between one oriented length x width box and M others (all [m], [rad]).

    Returns a boolean (M,) array. SUMO's own junction check lags up to two steps and can miss
    a merge overlap (SUMO-NOTES.md), so collisions are decided here, every step.
    """
    centers = np.atleast_2d(centers)
    if len(centers) == 0:
        return np.zeros(0, dtype=bool)
    half = np.array([length / 2.0, width / 2.0])
    u0 = np.array([[math.cos(heading), math.sin(heading)], [-math.sin(heading), math.cos(heading)]])
    c, s = np.cos(headings), np.sin(headings)
    u1 = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], 1)  # (M, 2 axes, 2)
    axes = np.concatenate([np.broadcast_to(u0, u1.shape), u1], 1)  # (M, 4, 2)
    delta = centers - center  # (M, 2)
    dist = np.abs(np.einsum("mak,mk->ma", axes, delta))
    r0 = np.abs(np.einsum("mak,bk->mab", axes, u0)) @ half
    r1 = np.abs(np.einsum("mak,mbk->mab", axes, u1)) @ half
    return np.all(dist < r0 + r1, axis=1)


# Eqs. (24)-(26): the level-k game between one human (h) and the ego (e), each choosing
# CROSS or YIELD at their shared conflict point.
CROSS, YIELD = 0, 1


def game_utility(alpha, gap, wait, decel, waited, cfg: EnvConfig):
    """Eq. (24) with each term min-max normalised by Eq. (25) (minimum 0, ranges in cfg).

    U = a1 phi_safe - a2 phi_eff - a3 phi_comf + a4 phi_emo: the arrival-time gap [s] at the
    conflict point makes it safer; waiting for the other [s] and braking to stop [m/s^2] cost;
    emotion rewards going after having waited [s] (paid only when crossing: `waited` is 0 for YIELD).
    alpha: (..., 4) weights, decel normalised by the player's own braking capability.
    """
    phi_safe = np.clip(gap / cfg.gap_range, 0.0, 1.0)
    phi_eff = np.clip(wait / cfg.wait_range, 0.0, 1.0)
    phi_comf = np.clip(decel, 0.0, 1.0)
    phi_emo = np.clip(waited / cfg.emotion_range, 0.0, 1.0)
    a = np.asarray(alpha)
    return a[..., 0] * phi_safe - a[..., 1] * phi_eff - a[..., 2] * phi_comf + a[..., 3] * phi_emo


def outcome_terms(t_me, t_other, stop_decel, waited, me, other, cfg: EnvConfig):
    """The four terms of Eq. (24) for a player choosing `me` while its opponent chooses `other`.

    t_me, t_other: arrival times [s] at the conflict point keeping the present speed;
    stop_decel: the braking to stop before it, as a fraction of the player's capability.
    """
    tau = cfg.clear_time
    both_yield = (me == YIELD) & (other == YIELD)
    # who reaches the conflict point when: a yielding player goes only after the other has passed
    t_mine = np.where((me == YIELD) & (other == CROSS), np.maximum(t_me, t_other + tau), t_me)
    t_theirs = np.where((other == YIELD) & (me == CROSS), np.maximum(t_other, t_me + tau), t_other)
    # both yielding is a standoff: both wait (the longest wait of Eq. (25)'s range), then
    # the conflict restarts as close as it was
    gap = np.abs(t_mine - t_theirs)
    wait = np.where(both_yield, cfg.wait_range, t_mine - t_me)  # 0 when crossing
    decel = np.where((me == YIELD) & (wait > 0), stop_decel, 0.0)
    emotion = np.where(me == CROSS, waited, 0.0)
    return gap, wait, decel, emotion


def level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, waited_e, alpha_h, svo, cfg: EnvConfig):
    """Level-2 decisions of M humans against the ego (Sec. 5.1, Eqs. (24)-(26)); arrays of shape (M,).

    level 0: the human picks its best action while ignoring the ego (the ego is just a
             vehicle keeping its speed, i.e. it crosses);
    level 1: the ego, as the human pictures it (weights EGO_GAME_WEIGHTS), best-responds to that;
    level 2: the human best-responds to the level-1 ego with U_svo of Eq. (26).
    Returns (M,) of CROSS / YIELD. A human that cannot stop before the conflict point
    (decel_h > 1, i.e. beyond its own braking) has no choice: it crosses.
    """
    alpha_h = np.asarray(alpha_h, dtype=float)

    def u(t_me, t_other, dec, waited, alpha, me, other):
        return game_utility(alpha, *outcome_terms(t_me, t_other, dec, waited, me, other, cfg), cfg)

    cross, yld = np.full(len(t_h), CROSS), np.full(len(t_h), YIELD)
    # level 0: the ego is assumed to go on (CROSS)
    h0 = np.where(u(t_h, t_e, decel_h, waited_h, alpha_h, yld, cross)
                  > u(t_h, t_e, decel_h, waited_h, alpha_h, cross, cross), YIELD, CROSS)
    # level 1: the ego's best response to h0
    e1 = np.where(u(t_e, t_h, decel_e, waited_e, EGO_GAME_WEIGHTS, yld, h0)
                  > u(t_e, t_h, decel_e, waited_e, EGO_GAME_WEIGHTS, cross, h0), YIELD, CROSS)

    # Eq. (26): U_svo = (1 - a_svo) U_self + a_svo U_oppo
    def u_svo(me):
        u_self = u(t_h, t_e, decel_h, waited_h, alpha_h, me, e1)
        u_oppo = u(t_e, t_h, decel_e, waited_e, EGO_GAME_WEIGHTS, e1, me)
        return (1.0 - svo) * u_self + svo * u_oppo

    h2 = np.where(u_svo(yld) > u_svo(cross), YIELD, CROSS)
    return np.where(decel_h > 1.0, CROSS, h2)


# Timing (Sec. 4). Neither w nor T_max is in the paper. By Eq. (11), beta(1) = 1 and
# beta(2) = 1/2 for every w; the text asks beta(3) to be intermediate and beta(T >= 4) close
# to 0. With w = 6: beta(3) = 0.117, beta(4) = 0.045, beta(5) = 0.024, beta(10) = 0.011.
# (w = 4 leaves beta(4) = 0.105; w = 10 makes beta(3) = 0.035, no longer intermediate.)
OMEGA = 6.0  # w of Eq. (6) [-]
T_MAX = 10  # T_max [steps]: 10 x 0.2 s = 2 s, the longest wait "for a better chance"


def beta(T, dt=1, omega: float = OMEGA):
    """Eq. (6): beta(T, dt) = 1/2 (tanh(w (dt / T - 1/2)) / tanh(w / 2) + 1), dt = 1..T.

    With dt = 1 it is the timing factor beta(T) of Eq. (11). Vectorised over T and dt.
    """
    T, dt = np.asarray(T, dtype=float), np.asarray(dt, dtype=float)
    return 0.5 * (np.tanh(omega * (dt / T - 0.5)) / np.tanh(omega / 2.0) + 1.0)


def blend(a, a_base, b):
    """Eqs. (7) and (12): a_bar = beta a + (1 - beta) a_base."""
    return b * a + (1.0 - b) * a_base


# --------------------------------------------------------------------------------------
# SUMO
# --------------------------------------------------------------------------------------


def sumo_home() -> Path:
    try:
        import sumo  # the eclipse-sumo wheel
        return Path(sumo.SUMO_HOME)
    except ImportError:
        if os.environ.get("SUMO_HOME"):
            return Path(os.environ["SUMO_HOME"])
        raise SystemExit("SUMO is not installed: pip install -r requirements.txt (eclipse-sumo, libsumo)")


def import_sumo(gui: bool = False):
    """libsumo (fast, in-process, one simulation per process), or traci for sumo-gui."""
    try:
        if gui:
            import traci as sim
        else:
            import libsumo as sim
    except ImportError:
        raise SystemExit("libsumo/traci is not installed: pip install -r requirements.txt") from None
    return sim


class Box:
    """Bounds of a space, in the shape of gymnasium.spaces.Box (low, high, shape, dtype).

    gymnasium is not a dependency; `gymnasium.spaces.Box(env.observation_space.low,
    env.observation_space.high)` wraps it for libraries that need the real class.
    """

    def __init__(self, low, high):
        self.low, self.high = np.asarray(low, np.float32), np.asarray(high, np.float32)
        self.shape, self.dtype = self.low.shape, np.float32

    def sample(self, rng=np.random):
        return rng.uniform(self.low, self.high).astype(np.float32)

    def contains(self, x) -> bool:
        x = np.asarray(x)
        return x.shape == self.shape and bool(np.all(x >= self.low) and np.all(x <= self.high))


def arrival_time(d, v, accel, v_desired):
    """Time [s] to cover d [m] from speed v [m/s], accelerating at `accel` [m/s^2] up to v_desired."""
    d, v = np.maximum(d, 0.0), np.minimum(v, v_desired)
    t_up = (v_desired - v) / accel
    d_up = 0.5 * (v + v_desired) * t_up
    t_short = (np.sqrt(v * v + 2.0 * accel * d) - v) / accel
    return np.where(d <= d_up, t_short, t_up + (d - d_up) / v_desired)


class DrivingEnv:
    """The ego's task in SUMO with Gymnasium's conventions (reset -> (obs, info); step -> 5-tuple).

    The simulation runs continuously: traffic keeps flowing between episodes, the ego is
    re-spawned on a random free lane and route at every reset, and SUMO restarts (new seed,
    warm-up) after t_sim. `reset(seed=s)` restarts it with seed s, which makes a test round
    reproducible. One action: the ego's acceleration [m/s^2] in [-3, 2].

    info: "collision", "arrival", "timeout" (bools), "crossing_time" [s] from spawn to arrival
    (None before), "time" [s] since spawn, and "cost": the per-step cost signal of the
    constrained baselines, 1.0 at the step the ego collides and 0.0 otherwise.
    """

    def __init__(self, cfg: EnvConfig = EnvConfig(), gui: bool = False,
                 planner_cfg: planner.PlannerConfig | None = None):
        if cfg.scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {cfg.scenario!r}; choose from {sorted(SCENARIOS)}")
        self.cfg, self.gui = cfg, gui
        self.planner_cfg = planner_cfg or planner.PlannerConfig(dt=cfg.dt)
        self.sim = import_sumo(gui)
        self.net_file = HERE / "scenarios" / f"{cfg.scenario}.net.xml"
        self.route_file = HERE / "scenarios" / f"{cfg.scenario}.rou.xml"
        for f in (self.net_file, self.route_file):
            if not f.is_file():
                raise SystemExit(f"missing {f}: rebuild the networks with `python scenarios/build.py`")
        self.observation_space = Box(np.zeros(OBS_DIM), np.ones(OBS_DIM))
        self.action_space = Box([cfg.a_min], [cfg.a_max])
        self.rng = np.random.default_rng()
        self.running = False
        self.ego_alive = False
        self.episodes = 0

    # ---- simulation lifecycle ----------------------------------------------------------

    def _start(self, seed: int):
        c = self.cfg
        binary = str(sumo_home() / "bin" / ("sumo-gui" if self.gui else "sumo"))
        args = ["-n", str(self.net_file), "-r", str(self.route_file), "--step-length", str(c.dt),
                "--seed", str(seed), "--default.carfollowmodel", "IDM",
                "--collision.check-junctions", "true", "--collision.action", "warn",
                "--collision.mingap-factor", "0", "--time-to-teleport", "-1",
                "--no-step-log", "true", "--no-warnings", "true",
                # a human that cannot enter its full spawn lane within 30 s is dropped, so a
                # backlog never sits at a spawn point (about 6 % of the roundabout's demand)
                "--max-depart-delay", "30"]
        if self.gui:
            args += ["--start", "--quit-on-end", "--delay", "50"]
        try:
            if self.running:
                self.sim.load(args)
            else:
                self.sim.start([binary] + args)
        except Exception as e:  # libsumo raises its own exception types; one line is enough
            raise SystemExit(f"SUMO cannot load {self.net_file.name}: {str(e).strip() or type(e).__name__}. "
                             "Rebuild the networks with `python scenarios/build.py`.") from None
        self.running = True
        self.ego_alive = False
        sim = self.sim
        for vt, maxspeed in (("human", 16.0), ("egotype", 16.0)):
            sim.vehicletype.copy("DEFAULT_VEHTYPE", vt)
            sim.vehicletype.setLength(vt, c.length)
            sim.vehicletype.setWidth(vt, c.width)
            sim.vehicletype.setMaxSpeed(vt, maxspeed)
            sim.vehicletype.setSpeedDeviation(vt, 0.0)
        sim.vehicletype.setImpatience("human", c.sc.impatience)
        self.t_start = sim.simulation.getTime()
        self.next_spawn = self.t_start
        self.n_humans = 0
        self.humans: dict[str, np.ndarray] = {}  # id -> (alpha1..4, svo, decel [m/s^2], accel [m/s^2])
        self.decisions: dict[str, int] = {}  # humans now playing the game -> CROSS / YIELD
        self.capped: set[str] = set()  # yielding humans whose speed we cap
        if not hasattr(self, "tasks"):
            self.tasks = self._ego_tasks()
        for _ in range(round(c.warmup / c.dt)):
            self._spawn_humans()
            sim.simulationStep()

    def close(self):
        if self.running:
            self.sim.close()
            self.running = False

    # ---- traffic (Table 1) -------------------------------------------------------------

    def _spawn_humans(self):
        """Departures in the whole network with exponential gaps of mean t_spawn (Table 1)."""
        sim, c, rng = self.sim, self.cfg, self.rng
        now = sim.simulation.getTime()
        while self.next_spawn <= now:
            self.next_spawn += rng.exponential(c.sc.spawn_gap)
            vid = f"h{self.n_humans}"
            self.n_humans += 1
            sim.vehicle.add(vid, self.routes[rng.integers(len(self.routes))], typeID="human",
                            depart="now", departLane="best", departSpeed="max")
            p = {k: rng.uniform(*r) for k, r in HUMAN_RANGES.items()}
            sim.vehicle.setAccel(vid, p["accel"])
            sim.vehicle.setDecel(vid, p["decel"])
            sim.vehicle.setMinGap(vid, p["min_gap"])
            sim.vehicle.setMaxSpeed(vid, p["speed"])
            sim.vehicle.setLaneChangeMode(vid, 0)  # lanes are chosen at departure (SUMO-NOTES)
            if c.sc.crossing_speed:
                # the connections' speed limit times this factor is the human's own v_cr
                sim.vehicle.setSpeedFactor(vid, rng.uniform(*c.sc.crossing_speed) / CONNECTION_SPEED)
            self.humans[vid] = np.array([p["alpha1"], p["alpha2"], p["alpha3"], p["alpha4"],
                                         p["svo"], p["decel"], p["accel"]])

    # ---- the ego's fixed paths ---------------------------------------------------------

    def _ego_tasks(self):
        """Every (route, start lane) the ego can drive without changing lanes, with its path polyline."""
        sim, tasks = self.sim, []
        self.routes = sorted(r for r in sim.route.getIDList() if not r.startswith("!"))
        for rid in self.routes:
            edges = sim.route.getEdges(rid)
            for idx in range(sim.edge.getLaneNumber(edges[0])):
                lanes = self._follow(edges, f"{edges[0]}_{idx}")
                if lanes is None:
                    continue
                shapes = [np.asarray(sim.lane.getShape(lane), dtype=float) for lane in lanes]
                xy = np.concatenate(shapes)
                xy = xy[np.r_[True, np.any(np.abs(np.diff(xy, axis=0)) > 1e-6, axis=1)]]  # joints once
                path_s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
                exit_start = sum(float(np.sum(np.hypot(*np.diff(sh, axis=0).T))) for sh in shapes[:-1])
                tasks.append(dict(route=rid, lane=idx, first=lanes[0], edges=edges, xy=xy, s=path_s,
                                  dest=exit_start + self.cfg.destination,
                                  task=self._task_index(edges, lanes)))
        if not tasks:
            raise SystemExit(f"{self.route_file.name}: no route the ego can drive; rebuild the scenarios")
        return tasks

    def _follow(self, edges, lane):
        """The lanes (internal ones included) a vehicle on `lane` takes along `edges`, or None."""
        lanes = [lane]
        for nxt in edges[1:]:
            links = [l for l in self.sim.lane.getLinks(lanes[-1]) if l[0].rsplit("_", 1)[0] == nxt]
            if not links:
                return None
            via = links[0][4]
            while via:  # an internal lane, possibly split at an internal junction
                lanes.append(via)
                inner = self.sim.lane.getLinks(via)
                via = inner[0][4] if inner and inner[0][4] and inner[0][4] not in lanes else ""
            lanes.append(links[0][0])
        return lanes

    def _task_index(self, edges, lanes) -> int:
        """h1 of Eq. (29): straight/left/right at the intersection, exit 1/2/3 at the roundabout."""
        sim = self.sim
        if self.cfg.scenario == "intersection":
            link = [l for l in sim.lane.getLinks(lanes[0]) if l[0].rsplit("_", 1)[0] == edges[1]][0]
            return {"s": 0, "l": 1, "L": 1, "r": 2, "R": 2}[link[6]]
        # roundabout (counter-clockwise): quarter turns from the entry to the exit = exit number
        a_in, a_out = sim.lane.getShape(lanes[0])[-1], sim.lane.getShape(lanes[-1])[0]
        turn = (math.atan2(a_out[1], a_out[0]) - math.atan2(a_in[1], a_in[0])) % (2 * math.pi)
        return min(2, max(0, round(turn / (math.pi / 2)) - 1))

    # ---- Gymnasium API -----------------------------------------------------------------

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Spawn the ego on a random free lane and route. A seed restarts SUMO and the traffic."""
        c, sim = self.cfg, self.sim
        if seed is not None:
            self.rng = np.random.default_rng(seed)
            self._start(seed)
        elif not self.running or sim.simulation.getTime() - self.t_start > c.sc.t_sim:
            self._start(int(self.rng.integers(2**31)))  # Table 1: the simulation restarts every t_sim
        if self.ego_alive:
            self._end_episode()
        for _ in range(round(60.0 / c.dt)):  # wait (at most 60 s) for a free spawn lane
            free = [t for t in self.tasks if self._lane_start_free(t["first"])]
            if free:
                self.task = free[self.rng.integers(len(free))]
                # "max": the depart speed, lowered by SUMO if that is unsafe behind a queue
                sim.vehicle.add(EGO, self.task["route"], typeID="egotype", depart="now",
                                departLane=str(self.task["lane"]), departPos="0", departSpeed="max")
                sim.vehicle.setSpeedFactor(EGO, c.ego_depart_speed / sim.lane.getMaxSpeed(self.task["first"]))
                sim.vehicle.setSpeedMode(EGO, 32)  # SUMO never overrides the ego (SUMO-NOTES)
                sim.vehicle.setLaneChangeMode(EGO, 0)
                sim.vehicle.setColor(EGO, (255, 0, 0, 255))
            self._spawn_humans()
            sim.simulationStep()
            if free and EGO in sim.vehicle.getIDList():
                break
            if free:  # not inserted after all: take it back and try again
                sim.vehicle.remove(EGO)
        else:
            raise RuntimeError("no free lane to spawn the ego for 60 s: the traffic is jammed")
        V = sim.constants if hasattr(sim, "constants") else sim.tc
        sim.vehicle.subscribe(EGO, [V.VAR_POSITION, V.VAR_ANGLE, V.VAR_SPEED, V.VAR_DISTANCE, V.VAR_ROAD_ID])
        sim.vehicle.subscribeContext(EGO, V.CMD_GET_VEHICLE_VARIABLE, c.perception,
                                     [V.VAR_POSITION, V.VAR_SPEED, V.VAR_ANGLE])
        self.V = V
        self.ego_alive = True
        self.t_spawn = sim.simulation.getTime()
        self.s0 = sim.vehicle.getLanePosition(EGO) - sim.vehicle.getDistance(EGO)  # odometer offset [m]
        self.accel = 0.0
        self.waited = 0.0
        self._read()
        self.episodes += 1
        return self.obs, self._info(False, False, False)

    def step(self, action):
        """Eq. (1): s_{t+1} = f(s_t, a_t, xi_t), one SUMO step with the ego's acceleration a_t."""
        if not self.ego_alive:
            raise RuntimeError("step() after the episode ended: call reset()")
        c, sim = self.cfg, self.sim
        a = float(np.clip(np.asarray(action, dtype=float).reshape(-1)[0], c.a_min, c.a_max))
        v_cmd = max(0.0, self.v + a * c.dt)
        self.accel = (v_cmd - self.v) / c.dt  # realised exactly: speed mode 32
        sim.vehicle.setSpeed(EGO, v_cmd)
        self._spawn_humans()
        sim.simulationStep()
        self._forget_arrived()
        self._read()
        collided = self._collided()
        arrived = not collided and self.s >= self.task["dest"]
        self.waited = self.waited + c.dt if self.v < 0.1 else 0.0
        timeout = sim.simulation.getTime() - self.t_spawn >= c.time_limit - 1e-9
        terminated = collided or arrived
        truncated = timeout and not terminated
        r = reward(arrived, collided, self.v, c.v_min, c.v_max)
        info = self._info(collided, arrived, truncated)
        if terminated or truncated:
            self._end_episode()
        else:
            self._play_level_k()
        return self.obs, r, terminated, truncated, info

    def base_action(self) -> float:
        """a_base of Eq. (23) in the present state, from planner.py (computed once per step)."""
        if self._a_base is None:
            L = self.cfg.length
            self._a_base = planner.base_action(self.s - L / 2, self.v, self.accel, self.task["s"],
                                               self.task["xy"], self.others, self.planner_cfg)[0]
        return self._a_base

    def _info(self, collided, arrived, timeout):
        t = self.sim.simulation.getTime() - self.t_spawn
        return dict(collision=collided, arrival=arrived, timeout=timeout, time=t,
                    crossing_time=t if arrived else None, cost=float(collided),
                    task=self.cfg.sc.tasks[self.task["task"]])

    def _end_episode(self):
        for h in list(self.decisions):
            self._release(h)
        if EGO in self.sim.vehicle.getIDList():
            self.sim.vehicle.remove(EGO)
        self.ego_alive = False

    def _lane_start_free(self, lane) -> bool:
        sim = self.sim
        return all(sim.vehicle.getLanePosition(v) > self.cfg.spawn_clear + self.cfg.length
                   for v in sim.lane.getLastStepVehicleIDs(lane))

    def _forget_arrived(self):
        for h in self.sim.simulation.getArrivedIDList():
            self.humans.pop(h, None)
            self.decisions.pop(h, None)
            self.capped.discard(h)

    # ---- what the ego perceives: Eqs. (27)-(30) ----------------------------------------

    def _read(self):
        """Read the ego and everyone within 60 m (one subscription each), build the observation."""
        sim, V, L = self.sim, self.V, self.cfg.length
        ego = sim.vehicle.getSubscriptionResults(EGO)
        self.v = ego[V.VAR_SPEED]
        self.heading = math.radians(90.0 - ego[V.VAR_ANGLE])  # SUMO: degrees clockwise from north
        front = np.array(ego[V.VAR_POSITION])
        self.xy = front - 0.5 * L * np.array([math.cos(self.heading), math.sin(self.heading)])
        self.s = self.s0 + ego[V.VAR_DISTANCE]  # front bumper's arc length along the path [m]
        road = ego[V.VAR_ROAD_ID]
        zone = 0 if road == self.task["edges"][0] else 2 if road == self.task["edges"][-1] else 1
        ctx = sim.vehicle.getContextSubscriptionResults(EGO)
        ids = [k for k in ctx if k != EGO]
        if ids:
            raw = np.array([(*ctx[k][V.VAR_POSITION], ctx[k][V.VAR_SPEED], ctx[k][V.VAR_ANGLE]) for k in ids])
            heading = np.radians(90.0 - raw[:, 3])
            centre = raw[:, :2] - 0.5 * L * np.stack([np.cos(heading), np.sin(heading)], 1)
            self.others = np.column_stack([centre, raw[:, 2], heading])
        else:
            self.others = np.zeros((0, 4))
        self.other_ids = ids
        self._a_base = None
        self.obs = observe(self.xy, self.heading, self.v, self.task["task"], zone, self.others, self.cfg)

    def _collided(self) -> bool:
        c = self.cfg
        if EGO in self.sim.simulation.getCollidingVehiclesIDList():
            return True
        near = np.hypot(*(self.others[:, :2] - self.xy).T) < math.hypot(c.length, c.width)
        return bool(np.any(boxes_overlap(self.xy, self.heading, self.others[near, :2],
                                         self.others[near, 3], c.length, c.width)))

    # ---- the level-k drivers: Eqs. (24)-(26) enforced in SUMO -------------------------

    def _play_level_k(self):
        """Every human approaching a conflict point it shares with the ego plays the level-2 game.

        YIELD: the human's speed is capped by sqrt(2 b (d - margin)), so it stops before the
        conflict point; CROSS: it stops yielding to the ego (junctionModel.ignoreIDs), keeping
        SUMO's right of way among humans. Decisions are re-evaluated every step; a human
        leaves the game once it reaches the conflict point or the ego has passed it.
        """
        sim, c = self.sim, self.cfg
        foes = {}
        for f in sim.vehicle.getJunctionFoes(EGO, c.game_horizon):
            h, d_e, d_h, someone_yields = f[0], f[1], f[2], f[7] or f[8]
            if (someone_yields and h in self.humans and d_e > 0.0 and d_h > 0.0
                    and (h not in foes or d_e < foes[h][0])):
                foes[h] = (d_e, d_h)
        for h in [h for h in self.decisions if h not in foes]:
            self._release(h)
        if not foes:
            return
        ids = list(foes)
        d_e, d_h = np.array([foes[h] for h in ids]).T
        p = np.array([self.humans[h] for h in ids])
        v_h = np.array([sim.vehicle.getSpeed(h) for h in ids])
        waited_h = np.array([sim.vehicle.getWaitingTime(h) for h in ids])
        t_h = arrival_time(d_h, v_h, p[:, 6], 8.0)
        t_e = arrival_time(d_e, self.v, c.a_max, c.v_max)
        decel_h = v_h**2 / (2.0 * np.maximum(d_h - c.stop_margin, 0.1)) / p[:, 5]
        decel_e = self.v**2 / (2.0 * np.maximum(d_e - c.stop_margin, 0.1)) / -c.a_min
        choice = level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, self.waited, p[:, :4], p[:, 4], c)
        for h, k, dh, vh, b, a in zip(ids, choice, d_h, v_h, p[:, 5], p[:, 6]):
            if self.decisions.get(h) != k:
                sim.vehicle.setParameter(h, "junctionModel.ignoreIDs", EGO if k == CROSS else "")
                self.decisions[h] = k
            limit = math.sqrt(2.0 * b * max(0.0, dh - c.stop_margin))
            if k == YIELD and limit < vh + a * c.dt:  # the stopping profile binds: cap the speed
                sim.vehicle.setSpeed(h, limit)
                self.capped.add(h)
            elif h in self.capped:
                sim.vehicle.setSpeed(h, -1)
                self.capped.discard(h)

    def _release(self, h):
        """Hand a human back to SUMO's own driving."""
        try:
            if self.decisions.pop(h, None) == CROSS:
                self.sim.vehicle.setParameter(h, "junctionModel.ignoreIDs", "")
            if h in self.capped:
                self.sim.vehicle.setSpeed(h, -1)
        except self.sim.TraCIException:  # it has left the network
            pass
        self.capped.discard(h)


# --------------------------------------------------------------------------------------
# Evaluation (Table 3)
# --------------------------------------------------------------------------------------


class LatticeIDM:
    """The base model alone (Table 3's Lattice-IDM row): a = a_base of Eq. (23)."""

    name = "lattice-idm"

    def act(self, obs, env: DrivingEnv, deterministic: bool = True):
        """-> (executed acceleration [m/s^2], timing factor beta or None)."""
        return env.base_action(), None


def test_seed(seed: int, round_: int) -> int:
    """SUMO/traffic seed of evaluation round `round_`: the same for every model, apart from training's."""
    return 1_000_000 + 1000 * seed + round_


def mean_std(x) -> dict:
    x = np.asarray(x, dtype=float)
    return {"mean": float(np.mean(x)) if len(x) else float("nan"), "std": float(np.std(x)) if len(x) else float("nan")}


def evaluate(env: DrivingEnv, driver, rounds: int, cases: int, seed: int = 0, log=print) -> dict:
    """Table 3's protocol: R rounds of C test cases; success rate and crossing time, mean +- std over rounds.

    Round r restarts SUMO with test_seed(seed, r), so every model meets the same traffic at the
    start of a round. Crossing time is averaged over the successful cases of a round.
    """
    rates, times, betas = [], [], []
    t0 = time.time()
    for r in range(rounds):
        success, crossing = [], []
        obs, info = env.reset(seed=test_seed(seed, r))
        for case in range(cases):
            if case:
                obs, info = env.reset()
            done = False
            while not done:
                a, beta = driver.act(obs, env, deterministic=True)
                if beta is not None:
                    betas.append(beta)
                obs, _, terminated, truncated, info = env.step(a)
                done = terminated or truncated
            success.append(info["arrival"])
            if info["arrival"]:
                crossing.append(info["crossing_time"])
        rates.append(np.mean(success))
        times.append(np.mean(crossing) if crossing else float("nan"))
        eta = (time.time() - t0) / (r + 1) * (rounds - r - 1)
        log(f"  {driver.name} round {r + 1}/{rounds}: success {rates[-1]:.3f}, crossing "
            f"{times[-1]:.2f} s  [{time.time() - t0:.0f} s, ETA {eta:.0f} s]")
    return {"scenario": env.cfg.scenario, "algo": driver.name, "rounds": rounds, "cases": cases,
            "seed": seed, "success_rate": mean_std(rates),
            "crossing_time": mean_std([t for t in times if t == t])}


def table(results: list[dict]) -> str:
    """Table 3's layout: success rate and crossing time, mean +- std over the rounds."""
    lines = [f"{'model':<14}{'success rate':>18}{'crossing time [s]':>22}"]
    for res in results:
        s, c = res["success_rate"], res["crossing_time"]
        lines.append(f"{res['algo']:<14}{s['mean']:>10.3f} +- {s['std']:.3f}{c['mean']:>14.2f} +- {c['std']:.2f}")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------

ALGOS = ("lattice-idm",)


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scenario", choices=sorted(SCENARIOS), default="roundabout")
    p.add_argument("--algo", choices=ALGOS, default=ALGOS[0], help="the model to train and evaluate")
    p.add_argument("--seed", type=int, default=0, help="seeds training and the evaluation rounds")
    p.add_argument("--eval-rounds", type=int, default=10, help="R of Table 3")
    p.add_argument("--eval-cases", type=int, default=200, help="C of Table 3: test cases per round")
    p.add_argument("--out", type=Path, help="run directory: eval.json (and the training log, checkpoints)")
    p.add_argument("--gui", action="store_true", help="watch in sumo-gui (uses TraCI instead of libsumo)")
    args = p.parse_args(argv)
    if args.eval_rounds < 1 or args.eval_cases < 1:
        p.error("--eval-rounds and --eval-cases must be at least 1")
    return args


def main(argv=None):
    args = parse_args(argv)
    env = DrivingEnv(EnvConfig(scenario=args.scenario), gui=args.gui)
    try:
        print(f"evaluating {args.algo} on the {args.scenario}: {args.eval_rounds} rounds x {args.eval_cases} cases")
        result = evaluate(env, LatticeIDM(), args.eval_rounds, args.eval_cases, args.seed)
    finally:
        env.close()
    print(table([result]))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "eval.json").write_text(json.dumps(result, indent=2))
        print(f"wrote {args.out / 'eval.json'}")


if __name__ == "__main__":
    main()
