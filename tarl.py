"""tarl: timing-aware reinforcement learning for autonomous driving, in SUMO.

Reference implementation of Li, Wu, He, "Act Better by Timing: A timing-Aware
Reinforcement Learning for Autonomous Driving". An ego vehicle crosses an
unsignalized intersection or a roundabout among human drivers (IDM car following
plus a level-k game with the ego). The actor (SAC) picks an acceleration; the timing
taker (discrete SAC) picks when it should be executed, learning in a timing
imagination; the timing factor beta(T) blends the actor's action with the base action
of `planner.py` (quintic lattice + state machine + IDM).

    python tarl.py --scenario roundabout                 # train TARL, then Table 3
    python tarl.py --scenario intersection --algo lattice-idm --eval-rounds 2 --eval-cases 20

Equations are cited by the number printed in the paper's PDF
(../shared/paper/EQUATIONS.md maps them to the LaTeX labels).

Map from the paper to this file
    Sec. 3, Eqs. (1)-(2)          DrivingEnv.step: one SUMO step; SUMO + level-k drivers are xi_t
    Table 1                       SCENARIOS, HUMAN_RANGES, DrivingEnv._spawn_humans
    Eqs. (24)-(26) level-k game   game_utility, outcome_terms, level_k_decisions, DrivingEnv._play_level_k
    Eqs. (27)-(30) observation    sector_index, observe
    Eq. (31) reward               reward
    Eqs. (6), (11) timing factor  beta;  Eqs. (7), (12) the blends: blend
    Eq. (5) timing-taker input    timing_input;  Eq. (8) r_T: discounted_sum
    Eqs. (9), (13) critics        td_target, critic_loss;  Eqs. (10), (14) policies: policy_loss
    Table 2                       SACConfig;  Algorithm 1: TrainConfig, Trainer (imagine, actor_step, run)
    Sec. 5.3, Table 3, Sec. 5.5   Driver, play_round, evaluate, evaluate_parallel, main
"""
from __future__ import annotations

import argparse
import collections
import copy
import json
import math
import os
import signal
import subprocess
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

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
    spawn_gap: float | None = None  # [s] overrides the scenario's t_spawn; math.inf: no humans (tests)
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
    indices of the one-hots h1, h2; others: (M, >= 4) centres x, y [m], speed [m/s], heading [rad]
    (further columns are ignored).
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
    Returns (M,) of CROSS / YIELD; a tie goes to CROSS. A human that cannot stop before the
    conflict point (decel_h > 1, i.e. beyond its own braking) has no choice: it crosses.
    """
    m = np.arange(len(t_h))
    me, other = np.array([CROSS, YIELD]).reshape(2, 1, 1), np.array([CROSS, YIELD]).reshape(1, 2, 1)
    # Eq. (24) for every pair of choices at once, the payoff tables (2 mine, 2 theirs, M):
    # U_h[i, j] is the human's utility when it plays i and the ego j; U_e[i, j] the ego's when it plays i
    U_h = game_utility(alpha_h, *outcome_terms(t_h, t_e, decel_h, waited_h, me, other, cfg), cfg)
    U_e = game_utility(EGO_GAME_WEIGHTS, *outcome_terms(t_e, t_h, decel_e, waited_e, me, other, cfg), cfg)
    h0 = U_h[:, CROSS].argmax(0)  # level 0: the best reply to an ego that goes on (CROSS)
    e1 = U_e[:, h0, m].argmax(0)  # level 1: the ego's best reply to h0
    # level 2, Eq. (26): U_svo = (1 - a_svo) U_self + a_svo U_oppo, against e1
    U_svo = (1.0 - svo) * U_h[:, e1, m] + svo * U_e[e1, :, m].T
    return np.where(decel_h > 1.0, CROSS, U_svo.argmax(0))


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

    _owner: dict = {}  # the env that holds this process's libsumo (False) / TraCI (True) simulation

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
        if not getattr(self, "checked", False):
            # libsumo takes the whole process down on a broken network: try it in a subprocess first
            check = subprocess.run([str(sumo_home() / "bin" / "sumo")] + args[:4] + ["--end", "0"],
                                   capture_output=True, text=True)
            if check.returncode != 0:
                error = next((line for line in (check.stderr + check.stdout).splitlines() if "rror" in line),
                             f"SUMO crashed reading it (exit code {check.returncode}), is it valid XML?")
                raise SystemExit(f"SUMO cannot load {self.net_file.name}: {error.strip()} "
                                 "Rebuild the networks with `python scenarios/build.py`.")
            self.checked = True
        if DrivingEnv._owner.get(self.gui) is not None:  # one simulation per process: take it over
            DrivingEnv._owner[self.gui].running = False
            self.sim.load(args)
        else:
            self.sim.start([binary] + args)
        self.running = True
        DrivingEnv._owner[self.gui] = self
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
        self.next_spawn = self.t_start + self.rng.exponential(self._spawn_gap)
        self.n_humans = 0
        self.humans: dict[str, np.ndarray] = {}  # id -> (alpha1..4, svo, decel [m/s^2], accel [m/s^2])
        self.decisions: dict[str, int] = {}  # humans now playing the game -> CROSS / YIELD
        self.capped: set[str] = set()  # yielding humans whose speed we cap
        if not hasattr(self, "tasks"):
            self.tasks = self._ego_tasks()
        for _ in range(round(c.warmup / c.dt)):
            self._spawn_humans()
            sim.simulationStep()

    @property
    def _spawn_gap(self) -> float:
        return self.cfg.sc.spawn_gap if self.cfg.spawn_gap is None else self.cfg.spawn_gap

    def close(self):
        if self.running:
            self.sim.close()
            self.running = False
            DrivingEnv._owner[self.gui] = None

    # ---- traffic (Table 1) -------------------------------------------------------------

    def _spawn_humans(self):
        """Departures in the whole network with exponential gaps of mean t_spawn (Table 1)."""
        sim, c, rng = self.sim, self.cfg, self.rng
        now = sim.simulation.getTime()
        while self.next_spawn <= now:
            self.next_spawn += rng.exponential(self._spawn_gap)
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
                drawn = [float(np.sum(np.hypot(*np.diff(sh, axis=0).T))) for sh in shapes]
                starts = np.concatenate([[0.0], np.cumsum(drawn)[:-1]])
                # SUMO's lane lengths differ from the drawn shapes (by ~10 % on the ring): a lane
                # position is scaled to the drawn length, so s is measured along path_xy
                lane_s = {lane: (start, d / sim.lane.getLength(lane)) for lane, start, d in zip(lanes, starts, drawn)}
                exit_start = starts[-1]
                tasks.append(dict(route=rid, lane=idx, first=lanes[0], edges=edges, xy=xy, s=path_s, lane_s=lane_s,
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
        """Spawn the ego on a random free lane and route. A seed restarts SUMO and the traffic.

        options={"route": "S_N"} picks the ego's route (see scenarios/*.rou.xml).
        """
        c, sim = self.cfg, self.sim
        if seed is not None:
            self.rng = np.random.default_rng(seed)
            self._start(seed)
        elif not self.running or sim.simulation.getTime() - self.t_start > c.sc.t_sim:
            self._start(int(self.rng.integers(2**31)))  # Table 1: the simulation restarts every t_sim
        if self.ego_alive:
            self._end_episode()
        for _ in range(round(60.0 / c.dt)):  # wait (at most 60 s) for a free spawn lane
            free = [t for t in self.tasks if self._lane_start_free(t["first"])
                    and t["route"] == (options or {}).get("route", t["route"])]
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
        sim.vehicle.subscribe(EGO, [V.VAR_POSITION, V.VAR_ANGLE, V.VAR_SPEED, V.VAR_LANE_ID, V.VAR_LANEPOSITION])
        sim.vehicle.subscribeContext(EGO, V.CMD_GET_VEHICLE_VARIABLE, c.perception,
                                     [V.VAR_POSITION, V.VAR_SPEED, V.VAR_ANGLE])
        self.V = V
        self.ego_alive = True
        self.t_spawn = sim.simulation.getTime()
        self.accel = 0.0
        self.waited = 0.0
        self._headings = {}
        self._read()
        return self.obs, self._info(False, False, False, 0.0)

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
        t = sim.simulation.getTime() - self.t_spawn  # [s] since spawn
        timeout = t >= c.time_limit - 1e-9
        terminated = collided or arrived
        truncated = timeout and not terminated
        r = reward(arrived, collided, self.v, c.v_min, c.v_max)
        info = self._info(collided, arrived, truncated, t)
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

    def _info(self, collided, arrived, timeout, t):
        return dict(collision=collided, arrival=arrived, timeout=timeout, time=t,
                    crossing_time=t if arrived else None, cost=float(collided),
                    task=self.cfg.sc.tasks[self.task["task"]])

    def _end_episode(self):
        for h in list(self.decisions):
            self._release(h)
        if EGO in self.sim.vehicle.getIDList():
            # unsubscribe first: a subscription outliving its vehicle can fail the next step
            self.sim.vehicle.unsubscribe(EGO)
            self.sim.vehicle.unsubscribeContext(EGO, self.V.CMD_GET_VEHICLE_VARIABLE, self.cfg.perception)
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
        x, y = ego[V.VAR_POSITION]  # the front bumper
        self.xy = np.array([x - 0.5 * L * math.cos(self.heading), y - 0.5 * L * math.sin(self.heading)])
        start, scale = self.task["lane_s"][ego[V.VAR_LANE_ID]]
        self.s = start + scale * ego[V.VAR_LANEPOSITION]  # front bumper's arc length along the path [m]
        road = ego[V.VAR_LANE_ID].rsplit("_", 1)[0]
        zone = 0 if road == self.task["edges"][0] else 2 if road == self.task["edges"][-1] else 1
        ctx = sim.vehicle.getContextSubscriptionResults(EGO)
        ids = [k for k in ctx if k != EGO]
        if ids:
            # columns: x, y (front bumper -> centre), speed, SUMO angle -> heading, yaw rate
            others = np.array([(*ctx[k][V.VAR_POSITION], ctx[k][V.VAR_SPEED], ctx[k][V.VAR_ANGLE], 0.0) for k in ids])
            heading = np.radians(90.0 - others[:, 3])
            others[:, 3] = heading
            others[:, 0] -= 0.5 * L * np.cos(heading)
            others[:, 1] -= 0.5 * L * np.sin(heading)
            before = np.array([self._headings.get(k, h) for k, h in zip(ids, heading.tolist())])
            others[:, 4] = wrap_angle(heading - before) / self.cfg.dt  # [rad/s] over the last step
            self._headings = dict(zip(ids, heading.tolist()))
            self.others = others
        else:
            self.others = np.zeros((0, 5))
        self._a_base = None
        self.obs = observe(self.xy, self.heading, self.v, self.task["task"], zone, self.others, self.cfg)

    def _collided(self) -> bool:
        c = self.cfg
        if EGO in self.sim.simulation.getCollidingVehiclesIDList():
            return True
        near = np.hypot(*(self.others[:, :2] - self.xy).T) < math.hypot(c.length, c.width)
        return bool(near.any()) and bool(np.any(boxes_overlap(self.xy, self.heading, self.others[near, :2],
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
        # A human already inside the junction has committed: it clears the junction rather than
        # stop in it (humans stopped mid-junction block each other: the all-way stop gridlocks).
        inside = np.array([sim.vehicle.getRoadID(h).startswith(":") for h in ids])
        choice = np.where(inside, CROSS, choice)
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
# Soft Actor-Critic: one implementation for the actor (continuous) and the timing taker
# (discrete). Eqs. (9), (10), (13), (14); Table 2. One update per simulator step (5x10^5 on a
# 2-core CPU in the paper's budget), so the twin critics are one batched network and all
# parameters share one fused Adam.
# --------------------------------------------------------------------------------------

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # clamp of the Gaussian's log std; Haarnoja et al. (2018)'s values
LOG_2PI, LOG_2 = math.log(2 * math.pi), math.log(2.0)


@dataclass(frozen=True)
class SACConfig:
    batch_size: int = 256  # B, Table 2
    buffer_size: int = 1_000_000  # N_buffer, Table 2
    learning_starts: int = 2_000  # N_start, Table 2: env steps before the first update
    hidden: int = 256  # D_hidden, Table 2; "simple MLP": two hidden layers, as in SAC (Haarnoja 2018)
    gamma: float = 0.99  # gamma, Table 2; the timing taker discounts a decision by gamma^T, Eq. (9)
    tau: float = 0.005  # tau, Table 2: Polyak weight of the target critics
    lr: float = 3e-4  # lr, Table 2: Adam, for policy, critics and temperature alike (the paper gives one lr)
    init_alpha: float = 1.0  # not in the paper: the starting temperature alpha; log alpha = 0 as in SAC
    # Not in the paper: the discrete head's target entropy is this fraction of log(n). Atari's 0.98 log n
    # (Christodoulou 2019) asks for an almost uniform pi over T, and alpha then grows until the entropy
    # swamps the Q differences. 0.3 log 10 = 0.69 ~ log 2: the entropy of a coin flip between two timings,
    # or of ~87% on one T and the rest spread: the timing taker may commit, but keeps exploring.
    target_entropy_fraction: float = 0.3


def mlp(in_dim: int, out_dim: int, hidden: int) -> nn.Sequential:
    """Table 2: two hidden layers of D_hidden units with ReLU."""
    return nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                         nn.Linear(hidden, out_dim))


class TwinCritic(nn.Module):
    """Q1 and Q2 as one batched MLP: forward(obs (B, obs_dim), act (B, act_dim) or None) -> (2, B, out_dim).

    out_dim is 1 for Q(s, a), n for Q(s, .) of a discrete head. Layer k holds the weights of both critics
    stacked, (2, in, out), and biases (2, 1, out), applied by one torch.baddbmm. The first layer's weights are
    two blocks, w1_obs and w1_act: the same as feeding cat(obs, act), without the copy, and the policy loss
    back-propagates into the act rows only.
    frozen=True evaluates with detached weights: gradients reach act, never the critic (policy loss).
    """

    def __init__(self, obs_dim: int, act_dim: int, out_dim: int, hidden: int):
        super().__init__()

        def uniform(fan_in: int, *shape: int) -> nn.Parameter:  # nn.Linear's default initialisation
            return nn.Parameter(torch.empty(2, *shape).uniform_(-fan_in**-0.5, fan_in**-0.5))

        fan_in = obs_dim + act_dim
        self.w1_obs, self.b1 = uniform(fan_in, obs_dim, hidden), uniform(fan_in, 1, hidden)
        self.w1_act = uniform(fan_in, act_dim, hidden) if act_dim else None
        self.w2, self.b2 = uniform(hidden, hidden, hidden), uniform(hidden, 1, hidden)
        self.w3, self.b3 = uniform(hidden, hidden, out_dim), uniform(hidden, 1, out_dim)

    def forward(self, obs: torch.Tensor, act: torch.Tensor | None = None, frozen: bool = False) -> torch.Tensor:
        params = (self.w1_obs, self.w1_act, self.b1, self.w2, self.b2, self.w3, self.b3)
        w1_obs, w1_act, b1, w2, b2, w3, b3 = (p.detach() if frozen and p is not None else p for p in params)
        h = torch.baddbmm(b1, obs.expand(2, *obs.shape), w1_obs)
        if act is not None:
            h = h.baddbmm_(act.expand(2, *act.shape), w1_act)
        h = torch.baddbmm(b2, h.relu_(), w2).relu_()
        return torch.baddbmm(b3, h, w3)


class SAC:
    """SAC agent: continuous if act_dim is given (actor), discrete if n_actions is given (timing taker).

    The timing taker's observation is cat(s, a) (Eq. (5)), so its obs_dim is the state's plus act_dim. Its
    choices are the paper's timings T = 1..n_actions: `act` returns T, the buffer stores T, and column T - 1
    of Q(s, .) and pi(.|s) belongs to T.
    """

    def __init__(self, obs_dim: int, act_dim: int | None = None, n_actions: int | None = None,
                 low=None, high=None, cfg: SACConfig = SACConfig()):
        assert (act_dim is None) != (n_actions is None), "give act_dim (continuous) or n_actions (discrete)"
        self.cfg, self.discrete = cfg, n_actions is not None
        if self.discrete:
            self.n_actions = n_actions
            self.policy = mlp(obs_dim, n_actions, cfg.hidden)  # logits of pi(T|s, a), Eq. (10)
            self.critic = TwinCritic(obs_dim, 0, n_actions, cfg.hidden)  # Q(s, a, T) for every T, Eq. (9)
            self.target_entropy = cfg.target_entropy_fraction * math.log(n_actions)
        else:
            self.act_dim = act_dim
            low, high = (np.broadcast_to(np.asarray(v, np.float32), (act_dim,)) for v in (low, high))
            assert (low < high).all(), "a continuous head needs per-dimension bounds low < high"
            self.action_scale = torch.as_tensor((high - low) / 2)
            self.action_bias = torch.as_tensor((high + low) / 2)
            self.log_prob_offset = -0.5 * LOG_2PI - 2 * LOG_2 - self.action_scale.log()  # (act_dim,)
            self.policy = mlp(obs_dim, 2 * act_dim, cfg.hidden)  # mean and log std of pi(a|s), Eq. (14)
            self.critic = TwinCritic(obs_dim, act_dim, 1, cfg.hidden)  # Q(s, a), Eq. (13)
            self.target_entropy = -float(act_dim)  # SAC's heuristic -dim(A) (Haarnoja 2018b)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)  # Q-hat: never trained
        self.log_alpha = torch.tensor(math.log(cfg.init_alpha), requires_grad=True)
        # Adam is per parameter, so one optimizer over all of them equals one per network (and is one kernel)
        params = [*self.policy.parameters(), *self.critic.parameters(), self.log_alpha]
        self.optimizer = torch.optim.Adam(params, lr=cfg.lr, fused=True)
        self._online, self._target = list(self.critic.parameters()), list(self.critic_target.parameters())

    def squashed_gaussian(self, obs: torch.Tensor, deterministic: bool = False):
        """Continuous head. obs (B, obs_dim) -> a (B, act_dim) in [low, high], log pi(a|s) (B,).

        a = bias + scale tanh(u), u = mu + sigma eps (reparameterised); eps = 0 when deterministic.
        """
        mu, log_std = self.policy(obs).chunk(2, dim=-1)
        log_std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)
        eps = torch.zeros_like(mu) if deterministic else torch.randn_like(mu)
        u = torch.addcmul(mu, log_std.exp(), eps)
        a = torch.addcmul(self.action_bias, self.action_scale, torch.tanh(u))
        # log pi(a|s) = log N(u; mu, sigma) - log|da/du|, da/du = scale (1 - tanh(u)^2), and
        # log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)), stable for large |u|; constants in log_prob_offset
        log_prob = self.log_prob_offset - log_std - 0.5 * eps.square() + 2 * (u + F.softplus(-2 * u))
        return a, log_prob.sum(-1)

    def timing_distribution(self, obs: torch.Tensor):
        """Discrete head. obs (B, obs_dim) -> pi(T|s) (B, n), log pi(T|s) (B, n), column T - 1 for T."""
        log_probs = F.log_softmax(self.policy(obs), dim=-1)
        return log_probs.exp(), log_probs

    @torch.inference_mode()
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray | int:
        """obs (obs_dim,) or (B, obs_dim) -> action (act_dim,) / (B, act_dim), or timing T (int / (B,) ints)."""
        x = torch.as_tensor(obs, dtype=torch.float32)
        single = x.dim() == 1
        x = x.unsqueeze(0) if single else x
        if self.discrete:
            probs, _ = self.timing_distribution(x)
            choice = probs.argmax(-1) if deterministic else torch.multinomial(probs, 1).squeeze(-1)
            timing = (choice + 1).numpy()
            return int(timing[0]) if single else timing
        a = self.squashed_gaussian(x, deterministic)[0].numpy()
        return a[0] if single else a

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """One gradient step of the critics, the policy and the temperature on one batch (see ReplayBuffer).

        Alg. 1 lines 13-14 (timing taker) and 23-24 (actor). Departure: the three losses are all taken at
        the parameters before the step (as in Haarnoja et al.'s reference implementation), not the policy
        loss after the critic step; this saves two backward passes and, in the discrete case, a critic
        forward pass. They are summed: their parameter sets are disjoint (the policy loss sees frozen critics,
        the target is computed without gradient), so one backward gives each network its own loss's gradient.
        """
        loss_q, q = critic_loss(self, batch)
        # the discrete policy loss needs Q(s, .) at these parameters: reuse the critic's forward pass
        loss_pi, entropy = policy_loss(self, batch["obs"], q.detach() if self.discrete else None)
        loss_alpha = temperature_loss(self.log_alpha, entropy, self.target_entropy)
        self.optimizer.zero_grad(set_to_none=True)
        (loss_q + loss_pi + loss_alpha).backward()
        self.optimizer.step()
        with torch.no_grad():
            # Table 2: Q-hat <- (1 - tau) Q-hat + tau Q. The text before Eq. (13) says theta_a "is copied after
            # several iterations"; Table 2's tau is SAC's Polyak averaging, used here for both agents.
            torch._foreach_lerp_(self._target, self._online, self.cfg.tau)
        # 0-d tensors, float() to read: turning them into numbers at every update costs 3% of it
        return {"critic_loss": loss_q.detach(), "policy_loss": loss_pi.detach(),
                "temperature_loss": loss_alpha.detach()}

    def state_dict(self) -> dict:
        """Plain tensors and dicts only: loadable with torch.load(weights_only=True)."""
        return {"policy": self.policy.state_dict(), "critic": self.critic.state_dict(),
                "critic_target": self.critic_target.state_dict(), "log_alpha": self.log_alpha.detach().clone(),
                "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.policy.load_state_dict(state["policy"])
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.optimizer.load_state_dict(state["optimizer"])


@torch.no_grad()
def td_target(agent: SAC, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Target y (B,) of both critics, without gradient: Eq. (9) (timing taker) and Eq. (13) (actor).

    y = r + discount (1 - done) V(s'), discount = gamma^T (gamma for the actor), with the soft value
    V(s') = E_{a'~pi}[min(Q1', Q2')(s', a') - alpha log pi(a'|s')] of the target critics.
    EQUATIONS.md note 2: (13) is printed with max_{a'} Q-hat; SAC's target is this soft value.
    """
    alpha, next_obs = agent.log_alpha.exp(), batch["next_obs"]
    if agent.discrete:
        probs, log_probs = agent.timing_distribution(next_obs)
        # discrete SAC: V(s') = sum_T' pi(T'|s') [min Q'(s', T') - alpha log pi(T'|s')], the exact expectation
        v_next = (probs * (agent.critic_target(next_obs).amin(0) - alpha * log_probs)).sum(-1)
    else:
        a_next, log_prob = agent.squashed_gaussian(next_obs)
        # Eq. (13), note 2: V(s') = min(Q1', Q2')(s', a') - alpha log pi(a'|s'), one sample a' ~ pi(.|s')
        v_next = agent.critic_target(next_obs, a_next).amin(0).squeeze(-1) - alpha * log_prob
    # Eq. (9): y = r_T + gamma^T (1 - delta) V(s_{t+T});  Eq. (13): the same with T = 1
    return batch["rew"] + batch["discount"] * (1 - batch["done"]) * v_next


def critic_loss(agent: SAC, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared TD error of both critics, sum_i mean_B (Q_i(s, a) - y)^2: Eq. (9) and Eq. (13), minimised.

    batch: obs (B, obs_dim), act (B, act_dim) float or (B,) int T in 1..n, rew (B,), next_obs (B, obs_dim),
    discount (B,), done (B,) in {0, 1} (see ReplayBuffer). Returns the loss and the critics' values at obs:
    Q(s, a) (2, B), or Q(s, .) (2, B, n) if discrete (the discrete policy loss reuses them).
    """
    y = td_target(agent, batch)
    if agent.discrete:
        q = agent.critic(batch["obs"])
        q_taken = q.gather(-1, (batch["act"] - 1).view(1, -1, 1).expand(2, -1, 1)).squeeze(-1)
    else:
        q = q_taken = agent.critic(batch["obs"], batch["act"]).squeeze(-1)
    # Eq. (9), Eq. (13) (note 2: minimised, not maximised): sum_i E[(Q_i(s, a) - y)^2]
    return (q_taken - y).square().mean(-1).sum(), q


def policy_loss(agent: SAC, obs: torch.Tensor, q_obs: torch.Tensor | None = None):
    """-J(phi) of Eq. (14) (actor) and Eq. (10) (timing taker), minimised.

    continuous: E_s[alpha log pi(a|s) - min(Q1, Q2)(s, a)], a ~ pi(.|s) reparameterised;
    discrete:   E_s[sum_T pi(T|s) (alpha log pi(T|s) - min(Q1, Q2)(s, T))].
    obs (B, obs_dim); q_obs: optional critic output (2, B, n) at obs, discrete only (reused, no gradient).
    The critics are frozen here: gradients flow to the policy only. Returns the loss and the per-sample
    entropy estimate (B,) (detached): -log pi(a|s) for the sampled a, or the exact entropy if discrete.
    """
    alpha = agent.log_alpha.detach().exp()
    if agent.discrete:
        probs, log_probs = agent.timing_distribution(obs)
        if q_obs is None:
            with torch.no_grad():
                q_obs = agent.critic(obs)
        # Eq. (10): max E[Q(s, a, T) + alpha H(pi(.|s, a))], expectation over T exact
        loss = (probs * (alpha * log_probs - q_obs.amin(0))).sum(-1).mean()
        entropy = -(probs * log_probs).sum(-1)
    else:
        a, log_prob = agent.squashed_gaussian(obs)
        # Eq. (14): max E[Q(s, a) + alpha H(pi(.|s))], H estimated by -log pi(a|s)
        loss = (alpha * log_prob - agent.critic(obs, a, frozen=True).amin(0).squeeze(-1)).mean()
        entropy = -log_prob
    return loss, entropy.detach()


def temperature_loss(log_alpha: torch.Tensor, entropy: torch.Tensor, target_entropy: float) -> torch.Tensor:
    """Automatic temperature (Haarnoja 2018b): J(alpha) = E[alpha (H - H_bar)], on log alpha.

    entropy (B,) detached; alpha falls when the policy's entropy exceeds the target H_bar, rises otherwise.
    """
    return (log_alpha * (entropy - target_entropy)).mean()


class ReplayBuffer:
    """Transitions (s, a, r, s', discount, delta) of Alg. 1 lines 12 (D_T) and 22 (D_a), in preallocated arrays.

    act_shape=(act_dim,), act_dtype=np.float32 for the actor; act_shape=(), act_dtype=np.int64 for the timing
    taker (it stores T). discount = gamma^T (gamma for the actor); done = delta, 1 only at a true terminal
    (arrival or collision), not at a time limit. Oldest transitions are overwritten when full.
    """

    def __init__(self, capacity: int, obs_dim: int, act_shape: tuple = (1,), act_dtype=np.float32):
        self.capacity, self.ptr, self.size = capacity, 0, 0
        self.data = {"obs": np.zeros((capacity, obs_dim), np.float32),
                     "act": np.zeros((capacity, *act_shape), act_dtype),
                     "rew": np.zeros(capacity, np.float32),
                     "next_obs": np.zeros((capacity, obs_dim), np.float32),
                     "discount": np.zeros(capacity, np.float32),
                     "done": np.zeros(capacity, np.float32)}

    def __len__(self) -> int:
        return self.size

    def add(self, obs, act, rew: float, next_obs, discount: float, done: bool) -> None:
        for key, value in zip(self.data, (obs, act, rew, next_obs, discount, done)):
            self.data[key][self.ptr] = value
        self.ptr, self.size = (self.ptr + 1) % self.capacity, min(self.size + 1, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        idx = rng.integers(0, self.size, batch_size)
        return {key: torch.from_numpy(array[idx]) for key, array in self.data.items()}

    def state_dict(self) -> dict:
        """The filled part only, as tensors (torch.save / torch.load(weights_only=True))."""
        filled = {key: torch.from_numpy(array[: self.size].copy()) for key, array in self.data.items()}
        return {"ptr": self.ptr, **filled}

    def load_state_dict(self, state: dict) -> None:
        self.size, self.ptr = len(state["obs"]), state["ptr"]
        for key, array in self.data.items():
            array[: self.size] = state[key].numpy()


# --------------------------------------------------------------------------------------
# Algorithm 1: the actor, the timing taker, the timing imagination
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrainConfig:
    """Algorithm 1's schedule. None of these is in the paper; each says why its value."""

    steps: int = 100_000  # simulator steps in all (both loops of Alg. 1 count). The default
    #                      budget trains in about 12 minutes here (README, Speed); --steps 500000 is N_train of Table 2.
    sac_fraction: float = 0.4  # Alg. 1 line 2: plain SAC trains for this share of the steps; that
    #                            model is Table 3's SAC row. The rest alternates the two loops.
    n_timing: int = 20  # N_T: timing decisions per imagination loop (Alg. 1 lines 4-15). With T
    #                     averaging ~3-5 steps, imagination takes a little more than half the time.
    n_actor: int = 60  # N_a: real steps per actor loop (Alg. 1 lines 16-24)
    timing_learning_starts: int = 500  # decisions in D_T before the timing taker learns: it gets
    #                                    one sample per decision, ~6x fewer than the actor's N_start
    log_every: int = 2000  # [steps] between progress lines
    checkpoint_every: int = 20_000  # [steps] between checkpoints: an interrupted run loses little


def timing_input(obs, a, low=-3.0, high=2.0):
    """Eq. (5): the timing taker sees the state and the actor's action (scaled to [-1, 1])."""
    a = np.asarray(a, dtype=np.float32).reshape(-1)[:1]
    return np.concatenate([obs, 2.0 * (a - low) / (high - low) - 1.0]).astype(np.float32)


def discounted_sum(rewards, gamma: float) -> float:
    """Eq. (8): r_T = sum_{dt=1..T} gamma^(dt-1) r(s_t, a_bar_{t+dt})."""
    return float(np.sum(np.asarray(rewards) * gamma ** np.arange(len(rewards))))


class Driver:
    """A trained or planned policy for one of Table 3's rows: act(obs, env) -> (a_bar, beta or None).

    tarl:        a ~ actor, T ~ timing taker, Eq. (12): a_bar = beta(T) a + (1 - beta(T)) a_base
    sac:         a_bar = a ~ actor
    sac-lattice: the actor's second output is a switch: a_bar = a_base if it is > 0, else a
                 (Sec. 5.3: SAC "additionally provides the action generated from the baseline
                 strategy as optional action for the agent in each decision step")
    lattice-idm: a_bar = a_base
    """

    def __init__(self, name: str, actor: SAC | None = None, timing_taker: SAC | None = None):
        self.name, self.actor, self.timing_taker = name, actor, timing_taker
        self.sac_cfg = actor.cfg if actor is not None else None

    def act(self, obs, env: DrivingEnv, deterministic: bool = False):
        if self.name == "lattice-idm":
            return env.base_action(), None
        return self.execute(obs, self.actor.act(obs, deterministic), env, deterministic)

    def execute(self, obs, a, env: DrivingEnv, deterministic: bool = False):
        """The executed action for the actor's output a in state obs."""
        if self.name == "sac":
            return float(a[0]), None
        if self.name == "sac-lattice":
            return (env.base_action() if a[1] > 0.0 else float(a[0])), None
        T = self.timing_taker.act(timing_input(obs, a), deterministic)  # Alg. 1 line 18
        b = float(beta(T))
        # Eq. (12): a_bar_t = beta(T_t) a_t + (1 - beta(T_t)) a_base,t
        return blend(float(a[0]), env.base_action(), b), b


def driver_states(driver: Driver) -> dict:
    """The networks a Driver needs, as state_dicts (to rebuild it in another process)."""
    return {k: agent.state_dict() for k, agent in (("actor", driver.actor), ("timing_taker", driver.timing_taker))
            if agent is not None}


def driver_from_states(name: str, states: dict, sac_cfg: SACConfig | None) -> Driver:
    """The Driver of Table 3's row `name` from driver_states()."""
    if name == "lattice-idm":
        return Driver(name)
    low, high = ACT_BOUNDS[name]
    actor = SAC(OBS_DIM, act_dim=len(low), low=low, high=high, cfg=sac_cfg)
    actor.load_state_dict(states["actor"])
    timing_taker = None
    if "timing_taker" in states:
        timing_taker = SAC(OBS_DIM + 1, n_actions=T_MAX, cfg=sac_cfg)
        timing_taker.load_state_dict(states["timing_taker"])
    return Driver(name, actor, timing_taker)


ACT_BOUNDS = {"sac": ([-3.0], [2.0]), "tarl": ([-3.0], [2.0]), "sac-lattice": ([-3.0, -1.0], [2.0, 1.0])}


class Trainer:
    """Algorithm 1 (and plain SAC / SAC-Lattice with the same loop), with its log and checkpoints.

    The imagination and the real environment share one SUMO world. libsumo runs one
    simulation per process, and Algorithm 1 runs its two loops one after the other anyway:
    lines 4-15 drive the ego by Eq. (7) for N_T timing decisions, then lines 16-24 drive it by
    Eq. (12) for N_a steps, each loop storing only its own transitions (D_T, D_a). So each
    loop sees exactly the transitions Algorithm 1 specifies; what they share is the stream
    of traffic situations, which is what the timing taker must learn to judge. An ego
    episode may begin in one loop and end in the other.
    """

    def __init__(self, env: DrivingEnv, algo: str, tc: TrainConfig = TrainConfig(),
                 sac_cfg: SACConfig = SACConfig(), seed: int = 0, out: Path | None = None, log=print):
        self.env, self.algo, self.tc, self.sac_cfg, self.seed, self.out, self.log = env, algo, tc, sac_cfg, seed, out, log
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        low, high = ACT_BOUNDS[algo]
        self.actor = SAC(OBS_DIM, act_dim=len(low), low=low, high=high, cfg=sac_cfg)
        self.actor_buffer = ReplayBuffer(sac_cfg.buffer_size, OBS_DIM, (len(low),))  # D_a
        self.timing_taker = self.timing_buffer = None
        if algo == "tarl":
            self.timing_taker = SAC(OBS_DIM + 1, n_actions=T_MAX, cfg=sac_cfg)
            self.timing_buffer = ReplayBuffer(sac_cfg.buffer_size, OBS_DIM + 1, (), np.int64)  # D_T
        self.driver = Driver(algo, self.actor, self.timing_taker)
        self.step = 0  # simulator steps so far
        self.updates = {"actor": 0, "timing": 0}
        self.sac_actor = None  # the step-1 model (Table 3's SAC row), kept when step 1 ends
        self.episode = dict(ret=0.0, betas=[])
        self.rows: list[list] = []  # log rows not yet written to train_log.csv
        self.recent = collections.deque(maxlen=20)  # the last episodes, for the progress line

    @property
    def sac_steps(self) -> int:
        return round(self.tc.sac_fraction * self.tc.steps) if self.algo == "tarl" else self.tc.steps

    # ---- one simulator step, shared by every loop --------------------------------------

    def _env_step(self, a_bar, b):
        obs2, r, terminated, truncated, info = self.env.step(a_bar)
        self.step += 1
        self.episode["ret"] += r
        if b is not None:
            self.episode["betas"].append(b)
        if terminated or truncated:
            self._episode_end(info)
        return obs2, r, terminated, truncated

    def _episode_end(self, info):
        b = self.episode["betas"]
        row = [self.step, round(self.episode["ret"], 3), int(info["arrival"]), int(info["collision"]),
               round(info["crossing_time"], 2) if info["arrival"] else "", round(float(np.mean(b)), 4) if b else ""]
        self.rows.append(row)
        self.recent.append(row)
        self.episode = dict(ret=0.0, betas=[])
        self.obs, _ = self.env.reset()

    def _learn(self, agent: SAC, buffer: ReplayBuffer, starts: int, key: str):
        if len(buffer) >= starts:
            agent.update(buffer.sample(self.sac_cfg.batch_size, self.rng))
            self.updates[key] += 1

    # ---- Alg. 1 line 2 and lines 16-24: the actor's real steps --------------------------

    def actor_step(self, with_timing: bool):
        """One real step: a_t ~ pi_a, T_t ~ pi_T, execute a_bar_t (Eq. (12) when with_timing),
        store (s_t, a_t, r(s_t, a_bar_t), s_t+1, delta) in D_a, update the actor."""
        obs, c = self.obs, self.sac_cfg
        if len(self.actor_buffer) < c.learning_starts and not with_timing:
            a = self.rng.uniform(self.actor.action_bias - self.actor.action_scale,
                                 self.actor.action_bias + self.actor.action_scale).astype(np.float32)
        else:
            a = self.actor.act(obs)  # Alg. 1 line 17
        if with_timing or self.algo != "tarl":
            a_bar, b = self.driver.execute(obs, a, self.env)  # lines 18-19
        else:
            a_bar, b = float(a[0]), None  # step 1 of TARL is plain SAC
        obs2, r, terminated, truncated = self._env_step(a_bar, b)  # line 20
        # Alg. 1 line 21: D_a <- D_a u {(s_t, a_t, r(s_t, a_bar_t), s_t+1, delta)}: a_t, not a_bar_t
        self.actor_buffer.add(obs, a, r, obs2, c.gamma, terminated)
        self._learn(self.actor, self.actor_buffer, c.learning_starts, "actor")  # lines 22-23
        if not (terminated or truncated):
            self.obs = obs2

    # ---- Alg. 1 lines 4-15: one decision of the timing taker in the timing imagination ---

    def imagine(self):
        """a_t ~ pi_a, T_t ~ pi_T; for dt = 1..T_t execute Eq. (7) with a_base recomputed at each
        step; r_T of Eq. (8); store ((s_t, a_t), T_t, r_T, (s_t+T, a_t+T), delta) in D_T."""
        obs, c = self.obs, self.sac_cfg
        a = self.actor.act(obs)  # line 5
        x = timing_input(obs, a)
        T = self.timing_taker.act(x)  # line 6
        rewards, terminated, truncated = [], False, False
        for dt in range(1, T + 1):  # lines 7-10
            b = float(beta(T, dt))
            # Eq. (7): a_bar_{t+dt} = beta(T, dt) a_t + (1 - beta(T, dt)) a_base,t+dt
            a_bar = blend(float(a[0]), self.env.base_action(), b)
            obs2, r, terminated, truncated = self._env_step(a_bar, b)
            rewards.append(r)
            if terminated or truncated:
                break
        r_T = discounted_sum(rewards, c.gamma)  # line 11, Eq. (8)
        # Eq. (9)'s target needs the actor's action at s_{t+T}: drawn from the current actor
        x2 = timing_input(obs2, self.actor.act(obs2))
        self.timing_buffer.add(x, T, r_T, x2, c.gamma ** T, terminated)  # line 12
        self._learn(self.timing_taker, self.timing_buffer, self.tc.timing_learning_starts, "timing")  # 13-14
        if not (terminated or truncated):
            self.obs = obs2

    # ---- the whole schedule ------------------------------------------------------------

    def run(self):
        tc = self.tc
        if self.step == 0:
            self.obs, _ = self.env.reset(seed=self.seed)
        else:
            self.obs, _ = self.env.reset(seed=self.seed + self.step)  # resumed: SUMO cannot be restored
        t0, step0, next_log = time.time(), self.step, self.step + tc.log_every
        next_ckpt = self.step + tc.checkpoint_every
        try:
            while self.step < tc.steps:
                if self.step < self.sac_steps:  # Alg. 1 line 2: a regular SAC model first
                    self.actor_step(with_timing=False)
                    if self.step >= self.sac_steps and self.algo == "tarl":
                        self.sac_actor = copy.deepcopy(self.actor)
                        self.save("sac.pt", actor_only=True)
                else:  # lines 3-25
                    for _ in range(tc.n_timing):
                        self.imagine()
                    for _ in range(tc.n_actor):
                        self.actor_step(with_timing=True)
                if self.step >= next_log:
                    next_log += tc.log_every
                    self._progress(t0, step0)
                if self.step >= next_ckpt:
                    next_ckpt += tc.checkpoint_every
                    self.save()
        except KeyboardInterrupt:
            self.log(f"\ninterrupted at step {self.step}: saving")
            self.save()
            raise
        self.save()

    def _progress(self, t0, step0):
        rate = (self.step - step0) / max(time.time() - t0, 1e-9)
        eta = max(0, self.tc.steps - self.step) / max(rate, 1e-9)
        recent = self.recent
        succ = np.mean([r[2] for r in recent]) if recent else float("nan")
        coll = np.mean([r[3] for r in recent]) if recent else float("nan")
        ret = np.mean([r[1] for r in recent]) if recent else float("nan")
        phase = self.algo if self.algo != "tarl" else \
            "SAC (Alg. 1 step 1)" if self.step <= self.sac_steps else "imagination + actor"
        self.log(f"step {self.step:>7}/{self.tc.steps} [{phase}] {rate:5.0f} steps/s, ETA {eta / 60:5.1f} min | "
                 f"last 20 episodes: success {succ:.2f}, collision {coll:.2f}, return {ret:6.1f} | "
                 f"updates actor {self.updates['actor']}, timing {self.updates['timing']}")

    # ---- log and checkpoints -----------------------------------------------------------

    def config(self) -> dict:
        return {"scenario": self.env.cfg.scenario, "algo": self.algo, "seed": self.seed,
                "train": vars_of(self.tc), "sac": vars_of(self.sac_cfg), "omega": OMEGA, "t_max": T_MAX}

    def save(self, name: str = "ckpt.pt", actor_only: bool = False):
        """state_dicts and the config only: loadable with torch.load(weights_only=True)."""
        if self.out is None:
            return
        self.out.mkdir(parents=True, exist_ok=True)
        state = {"config": self.config(), "step": self.step, "actor": self.actor.state_dict()}
        if not actor_only:
            if self.timing_taker is not None:
                state["timing_taker"] = self.timing_taker.state_dict()
                state["timing_buffer"] = self.timing_buffer.state_dict()
            if self.sac_actor is not None:
                state["sac_actor"] = self.sac_actor.state_dict()
            state["actor_buffer"] = self.actor_buffer.state_dict()
            state["updates"] = dict(self.updates)
            state["rng"] = self.rng.bit_generator.state
            state["torch_rng"] = torch.get_rng_state()
        tmp = self.out / (name + ".tmp")
        torch.save(state, tmp)
        os.replace(tmp, self.out / name)  # never a half-written checkpoint
        if not actor_only:
            new = not (self.out / "train_log.csv").exists()
            with open(self.out / "train_log.csv", "a") as f:
                if new:
                    f.write(",".join(LOG_HEADER) + "\n")
                f.writelines(",".join(map(str, r)) + "\n" for r in self.rows)
            self.rows = []

    def load(self, state: dict, resume: bool):
        check_config(state, self.env.cfg.scenario, self.algo)
        self.actor.load_state_dict(state["actor"])
        if self.timing_taker is not None and "timing_taker" in state:
            self.timing_taker.load_state_dict(state["timing_taker"])
        if "sac_actor" in state:
            self.sac_actor = copy.deepcopy(self.actor)
            self.sac_actor.load_state_dict(state["sac_actor"])
        if resume:
            self.step = state["step"]
            self.updates = state.get("updates", self.updates)
            self.actor_buffer.load_state_dict(state["actor_buffer"])
            if self.timing_buffer is not None:
                self.timing_buffer.load_state_dict(state["timing_buffer"])
            self.rng.bit_generator.state = state["rng"]
            torch.set_rng_state(state["torch_rng"])


LOG_HEADER = ["step", "episode_return", "success", "collision", "crossing_time", "mean_beta"]


def vars_of(dc) -> dict:
    return {k: getattr(dc, k) for k in dc.__dataclass_fields__}


def load_checkpoint(path: Path) -> dict:
    """A checkpoint as plain tensors and dicts; a pickled object from a stranger never runs."""
    if not Path(path).is_file():
        raise SystemExit(f"checkpoint not found: {path}")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise SystemExit(f"cannot load checkpoint {path}: {str(e).splitlines()[0][:200]}") from None


def check_config(state: dict, scenario: str, algo: str):
    cfg = state.get("config") if isinstance(state, dict) else None
    if not cfg or "actor" not in state:
        raise SystemExit("not a tarl checkpoint: it has no config or no actor")
    if cfg["scenario"] != scenario or cfg["algo"] != algo:
        raise SystemExit(f"checkpoint is for --scenario {cfg['scenario']} --algo {cfg['algo']}, "
                         f"not --scenario {scenario} --algo {algo}")


# --------------------------------------------------------------------------------------
# Evaluation (Table 3, Sec. 5.5)
# --------------------------------------------------------------------------------------


def test_seed(seed: int, round_: int) -> int:
    """SUMO/traffic seed of evaluation round `round_`: the same for every model, apart from training's."""
    return 1_000_000 + 1000 * seed + round_


def mean_std(x) -> dict:
    """Mean and standard deviation; None (null in JSON) for no values."""
    x = np.asarray(x, dtype=float)
    return {"mean": float(np.mean(x)), "std": float(np.std(x))} if len(x) else {"mean": None, "std": None}


def play_round(env: DrivingEnv, driver: Driver, cases: int, seed: int) -> dict:
    """One round of Table 3: SUMO restarted with `seed`, then C test cases one after another.

    The agents act deterministically (the actor's mean, the timing taker's most likely T).
    Returns per-case successes and crossing times, and for TARL the timing factors beta of
    every step and of the last 3 s and 1 s before each collision (Sec. 5.5).
    """
    k3, k1 = round(3.0 / env.cfg.dt), round(1.0 / env.cfg.dt)
    out = dict(success=[], crossing=[], betas=[], before3=[], before1=[])
    obs, info = env.reset(seed=seed)
    for case in range(cases):
        if case:
            obs, info = env.reset()
        done, betas = False, []
        while not done:
            a, b = driver.act(obs, env, deterministic=True)
            betas.append(b)
            obs, _, terminated, truncated, info = env.step(a)
            done = terminated or truncated
        out["success"].append(bool(info["arrival"]))
        if info["arrival"]:
            out["crossing"].append(info["crossing_time"])
        if betas[0] is not None:
            out["betas"] += betas
            if info["collision"]:
                out["before3"] += betas[-k3:]
                out["before1"] += betas[-k1:]
    return out


def summarize(scenario: str, name: str, rounds: list[dict], cases: int, seed: int) -> dict:
    """Success rate and crossing time as mean +- std over rounds (a round's crossing time is
    the mean over its successes; a timeout is a failure), and Sec. 5.5's mean (1 - beta)."""
    result = {"scenario": scenario, "algo": name, "rounds": len(rounds), "cases": cases, "seed": seed,
              "success_rate": mean_std([np.mean(r["success"]) for r in rounds]),
              "crossing_time": mean_std([np.mean(r["crossing"]) for r in rounds if r["crossing"]])}
    if rounds[0]["betas"]:
        minus = lambda key: (float(np.mean(1.0 - np.concatenate([r[key] for r in rounds])))  # noqa: E731
                             if any(r[key] for r in rounds) else None)
        result["beta_minus"] = {"all_steps": minus("betas"), "3s_before_collision": minus("before3"),
                                "1s_before_collision": minus("before1")}
    return result


def evaluate(env: DrivingEnv, driver: Driver, rounds: int, cases: int, seed: int = 0, log=print) -> dict:
    """Table 3's protocol in this process: R rounds of C test cases, round r on test_seed(seed, r)."""
    played, t0 = [], time.time()
    for r in range(rounds):
        played.append(play_round(env, driver, cases, test_seed(seed, r)))
        eta = (time.time() - t0) / (r + 1) * (rounds - r - 1)
        log(f"  {driver.name} round {r + 1}/{rounds}: success {np.mean(played[-1]['success']):.3f}  "
            f"[{time.time() - t0:.0f} s, ETA {eta:.0f} s]")
    return summarize(env.cfg.scenario, driver.name, played, cases, seed)


def _round_worker(job):
    """One (model, round) in a worker process: libsumo runs one simulation per process."""
    scenario, name, states, sac_cfg, cases, seed = job
    torch.set_num_threads(1)
    if not hasattr(_round_worker, "env"):
        _round_worker.env = DrivingEnv(EnvConfig(scenario=scenario))
    return play_round(_round_worker.env, driver_from_states(name, states, sac_cfg), cases, seed)


def evaluate_parallel(scenario: str, drivers: list[Driver], rounds: int, cases: int, seed: int = 0,
                      workers: int = 2, log=print) -> list[dict]:
    """evaluate() for several models, their rounds spread over worker processes.

    Every round restarts SUMO from its own test seed, so a round gives the same numbers
    whichever process plays it: this is the sequential protocol, faster.
    """
    import concurrent.futures as cf
    import multiprocessing as mp
    jobs = [(scenario, d.name, driver_states(d), d.sac_cfg, cases, test_seed(seed, r))
            for d in drivers for r in range(rounds)]
    played, t0 = {}, time.time()
    with cf.ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
        futures = {pool.submit(_round_worker, job): (job[1], i % rounds) for i, job in enumerate(jobs)}
        for n, future in enumerate(cf.as_completed(futures), 1):
            name, r = futures[future]
            played[name, r] = future.result()
            eta = (time.time() - t0) / n * (len(jobs) - n)
            log(f"  {name} round {r + 1}/{rounds}: success {np.mean(played[name, r]['success']):.3f}  "
                f"[{n}/{len(jobs)} rounds, {time.time() - t0:.0f} s, ETA {eta:.0f} s]")
    return [summarize(scenario, d.name, [played[d.name, r] for r in range(rounds)], cases, seed) for d in drivers]


def table(results: list[dict]) -> str:
    """Table 3's layout: success rate and crossing time, mean +- std over the rounds."""
    lines = [f"{'model':<14}{'success rate':>18}{'crossing time [s]':>22}"]
    for res in results:
        s, c = res["success_rate"], res["crossing_time"]
        crossing = f"{c['mean']:>14.2f} +- {c['std']:.2f}" if c["mean"] is not None else f"{'-':>14}"
        lines.append(f"{res['algo']:<14}{s['mean']:>10.3f} +- {s['std']:.3f}{crossing}")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------

ALGOS = ("tarl", "sac", "sac-lattice", "lattice-idm")


def parse_args(argv=None):
    p = argparse.ArgumentParser(
        description="Train timing-aware RL (or a baseline) in SUMO, then evaluate it as Table 3 does.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scenario", choices=sorted(SCENARIOS), default="roundabout")
    p.add_argument("--algo", choices=ALGOS, default="tarl",
                   help="tarl also reports SAC (its step-1 model) and Lattice-IDM on the same test seeds")
    p.add_argument("--steps", type=int, default=TrainConfig.steps,
                   help="simulator steps of training; 500000 is the paper's budget")
    p.add_argument("--seed", type=int, default=0, help="seeds training and the evaluation rounds")
    p.add_argument("--eval-rounds", type=int, default=10, help="R of Table 3")
    p.add_argument("--eval-cases", type=int, default=200, help="C of Table 3: test cases per round")
    p.add_argument("--out", type=Path, help="run directory (default runs/SCENARIO-ALGO-sSEED): "
                   "training log, checkpoints, eval.json")
    p.add_argument("--load", type=Path, metavar="CKPT", help="evaluate this checkpoint instead of training")
    p.add_argument("--resume", action="store_true", help="continue the interrupted run in --out")
    p.add_argument("--threads", type=int, default=min(2, os.cpu_count() or 1),
                   help="torch threads for training; 1 when another busy process shares the cores")
    p.add_argument("--gui", action="store_true", help="watch in sumo-gui (TraCI instead of libsumo); "
                   "needs --load unless --algo lattice-idm")
    args = p.parse_args(argv)
    if args.eval_rounds < 1 or args.eval_cases < 1 or args.steps < 1:
        p.error("--steps, --eval-rounds and --eval-cases must be at least 1")
    if args.load and args.resume:
        p.error("--load evaluates a checkpoint, --resume continues training: choose one")
    if args.gui and not args.load and args.algo != "lattice-idm":
        p.error("--gui watches a trained agent: give it --load CKPT")
    args.out = args.out or Path("runs") / f"{args.scenario}-{args.algo}-s{args.seed}"
    return args


def main(argv=None):
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a kill saves like Ctrl-C
    env = DrivingEnv(EnvConfig(scenario=args.scenario), gui=args.gui)
    drivers = [Driver("lattice-idm")]
    try:
        if args.algo != "lattice-idm":
            trainer = Trainer(env, args.algo, replace(TrainConfig(), steps=args.steps), seed=args.seed, out=args.out)
            if args.load:
                trainer.load(load_checkpoint(args.load), resume=False)
            else:
                ckpt = args.out / "ckpt.pt"
                if args.resume:
                    trainer.load(load_checkpoint(ckpt), resume=True)
                    print(f"resuming {ckpt} at step {trainer.step}")
                elif ckpt.exists():
                    raise SystemExit(f"{args.out} already holds a run: --resume to continue it, or choose another --out")
                print(f"training {args.algo} on the {args.scenario} for {args.steps} steps -> {args.out}")
                try:
                    trainer.run()
                except KeyboardInterrupt:
                    raise SystemExit(f"saved {ckpt} and the log; continue with --resume --out {args.out}") from None
            drivers = [trainer.driver] + ([Driver("sac", trainer.sac_actor)] if trainer.sac_actor else []) + drivers
        print(f"evaluating on the {args.scenario}: {args.eval_rounds} rounds x {args.eval_cases} cases, "
              f"the same test seeds for every model")
        if args.gui:
            results = [evaluate(env, d, args.eval_rounds, args.eval_cases, args.seed) for d in drivers]
        else:
            env.close()  # the workers run their own simulations
            results = evaluate_parallel(args.scenario, drivers, args.eval_rounds, args.eval_cases, args.seed)
    finally:
        env.close()
    print(table(results))
    if "beta_minus" in results[0]:
        print("1 - beta (Sec. 5.5):", json.dumps(results[0]["beta_minus"]))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "eval.json").write_text(json.dumps({**results[0], "table": results}, indent=2))
    print(f"wrote {args.out / 'eval.json'}")


if __name__ == "__main__":
    main()
