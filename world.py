"""The world of "Act Better by Timing" (Li, Wu, He): an ego vehicle, human drivers and SUMO.

Sections 3 and 5.1-5.2 of the paper: an unsignalized intersection or a two-lane roundabout
(scenarios/), human drivers who follow IDM with Table 1's parameters and play a level-k (k = 2)
game with the ego at every conflict point, the ego's observation and reward (EnvConfig's
spawn_gap, svo_range and human_level shift the traffic). DrivingEnv is a Gymnasium environment,
registered as tarl/Intersection-v0 and tarl/Roundabout-v0; tarl.py learns in it. Equations are cited
by the number printed in the paper's PDF (PAPER.md maps them to the LaTeX labels and has the notes
cited as "docs/PAPER.md, note n").

    Eqs. (1)-(2)                  DrivingEnv.step: one SUMO step; SUMO + level-k drivers are xi_t
    Table 1                       SCENARIOS, HUMAN_RANGES, DrivingEnv._spawn_humans
    Eqs. (24)-(26) level-k game   game_utility, outcome_terms, level_k_decisions, DrivingEnv._play_level_k
    Eqs. (27)-(30) observation    SECTORS, sector_index, observe;  Eq. (31): reward
    Sec. 5.3 test cases           DrivingEnv.record_cases, reset(options={"case": ...}), fingerprint
    Eqs. (18)-(23) base action    DrivingEnv.plan, base_action (planner.py)
    Watching it                   DrivingEnv.render (scene.py draws), snapshot, show; make (gymnasium.make)
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import gymnasium
import numpy as np
from gymnasium import spaces

import planner
from scenarios import check_network, follow, scenario_files, sumo_home  # noqa: F401 (world.X for experiment.py)

HERE = Path(__file__).resolve().parent
EGO = "ego"
# What a test case plays, raised by every fix that changes it: 2, the humans waiting to depart at a snapshot keep their
# lanes after a load (_sumo_step). Evaluations keep it (eval.json "world"); a kept round of another is played again
WORLD_VERSION = 2

# ---- Settings: every constant has one home (the planner's own tuning is in planner.py) ------------


@dataclass(frozen=True)
class Scenario:
    """One of the paper's two road networks (Sec. 5.1, Table 1)."""

    name: str
    spawn_gap: float  # t_spawn [s]: mean gap between two departures in the whole network (Table 1)
    t_sim: float  # t_sim [s]: the simulation is restarted after this long (Table 1)
    crossing_speed: tuple[float, float] | None  # v_cr [m/s]: human speed through the junction (Table 1)
    impatience: float  # [0-1] SUMO's, not in the paper: at 0 the roundabout's entries back up for good
    tasks: tuple[str, ...]  # h1 labels, in one-hot order (Eq. (29))


SCENARIOS = {"intersection": Scenario("intersection", 1.8, 5000.0, (4.5, 6.0), 0.0, ("straight", "left", "right")),
             "roundabout": Scenario("roundabout", 1.2, 1000.0, None, 1.0, ("exit1", "exit2", "exit3"))}


@dataclass(frozen=True)
class EnvConfig:
    """The environment's constants, the ego's limits among them. "Open": not in the paper (PAPER.md)."""

    scenario: str = "intersection"
    spawn_gap: float | None = None  # [s] overrides the scenario's t_spawn; math.inf: no humans (tests)
    svo_range: tuple[float, float] | None = None  # [0-1] overrides Table 1's alpha_svo range (0, 0.5)
    human_level: int = 2  # the humans' k in the level-k game (Sec. 5.1: 2); 0: best reply to a crossing ego
    dt: float = 0.2  # [s] SUMO and decision step. Open: episodes of 50-150 decisions, T_max steps ~2 s
    length: float = 5.0  # L_car [m] (Table 1)
    width: float = 2.0  # W_car [m] (Table 1)
    a_min: float = -3.0  # [m/s^2] the ego's strongest braking (Sec. 5.2): actor, planner and Eq. (5) alike
    a_max: float = 2.0  # [m/s^2] the ego's strongest acceleration (Sec. 5.2), likewise
    perception: float = 60.0  # d_max [m] of Eq. (27) (Sec. 5.2)
    v_norm: float = 16.0  # v_max of Eq. (27) [m/s]: the road speed limit
    v_min: float = 1.0  # v_min of Eq. (31) [m/s]. Open: standing still costs a little, less than a crash
    v_max: float = 10.0  # v_max of Eq. (31) [m/s]. Open: the middle of the humans' 8-12 m/s (Table 1)
    ego_depart_speed: float = 8.0  # [m/s] the ego arrives moving like the traffic
    destination: float = 20.0  # [m] past the start of the exit road, the ego has arrived
    time_limit: float = 60.0  # [s] episode limit. Open: a timeout is a failure, so freezing counts
    warmup: float = 120.0  # [s] of traffic after every (re)start before the ego enters
    case_gap: float = 30.0  # [s] of traffic between the snapshots of two test cases (record_cases)
    spawn_clear: float = 12.0  # [m] the ego's spawn lane is free this far from its start
    jam_time: float = 20.0  # [s] a human standing this long inside a junction is removed: humans who
    #                         entered it and block each other never move again (SUMO's teleport, off here)
    # Level-k game (Eqs. (24)-(26)), open: the ranges of Eq. (25)'s min-max normalisation and more
    gap_range: float = 5.0  # [s] phi_safe: the arrival-time gap saturates here
    wait_range: float = 10.0  # [s] phi_eff: waiting for the other to pass
    emotion_range: float = 30.0  # [s] phi_emo: time already waited
    clear_time: float = 1.5  # [s] after the first vehicle, the second may reach the conflict point
    game_horizon: float = 60.0  # [m] the ego's distance to a conflict point at which games start
    stop_margin: float = 3.0  # [m] a yielding human stops this far before the conflict point

    @property
    def sc(self) -> Scenario:
        return SCENARIOS[self.scenario]

    def planner(self) -> planner.PlannerConfig:
        """The base planner's settings: the ego's step, limits and size come from here."""
        return planner.PlannerConfig(dt=self.dt, a_min=self.a_min, a_max=self.a_max,
                                     length=self.length, width=self.width)


HUMAN_RANGES = dict(  # Table 1: per-human parameters, drawn uniformly from these ranges
    accel=(1.5, 3.0),  # a_max [m/s^2]
    decel=(2.0, 4.5),  # |b_min| [m/s^2] (PAPER.md, note 4: SUMO's decel is the magnitude)
    min_gap=(2.0, 4.0),  # d_min [m]
    speed=(8.0, 12.0),  # v_cf [m/s], desired car-following speed
    alpha1=(0.5, 0.8), alpha2=(0.05, 0.2), alpha3=(0.05, 0.2), alpha4=(0.05, 0.2),  # weights of Eq. (24)
    svo=(0.0, 0.5))  # alpha_svo of Eq. (26)
CONNECTION_SPEED = 6.0  # [m/s] speed attribute of the intersection's connections (scenarios/)
EGO_GAME_WEIGHTS = np.array([0.65, 0.125, 0.125, 0.125])  # the ego as humans picture it: Table 1's middle

# ---- The world's math as pure functions ------------------------------------------------------------

# Eq. (28): each sector is a half-open interval (phi_low, phi_high] [deg] of the position angle
# relative to the ego's heading, in this order in s_sur. The rear sector wraps: it is (150, 210].
SECTORS = (("front", -30.0, 30.0), ("left front", 30.0, 90.0), ("right front", -90.0, -30.0),
           ("left rear", 90.0, 150.0), ("right rear", -150.0, -90.0), ("rear", 150.0, 210.0))
SECTOR_NAMES = tuple(name for name, _, _ in SECTORS)
PHI_LOW, PHI_HIGH = (np.array([s[k] for s in SECTORS]) for k in (1, 2))
OBS_DIM = 3 + 3 + 1 + 6 * 2 * 5  # Eqs. (28)-(30): h1, h2, v_ego, then 6 sectors x 2 vehicles x 5


def wrap_angle(x):
    """Angle(s) [rad] wrapped into (-pi, pi]."""
    return np.pi - np.mod(np.pi - x, 2.0 * np.pi)


def sector_index(phi_deg):
    """Eq. (28)'s sector of position angles phi [deg]: k with PHI_LOW[k] < phi <= PHI_HIGH[k], and phi
    moved into (-150, 210]. Rounded to 1e-9 deg, so that a vehicle on a boundary lands where the
    half-open interval says despite atan2's round-off."""
    phi = np.asarray(phi_deg, dtype=float)
    rounded = np.round(phi, 9)
    rounded, phi = (np.where(rounded <= -150.0, x + 360.0, x) for x in (rounded, phi))
    return np.argmax((PHI_LOW < rounded[..., None]) & (rounded[..., None] <= PHI_HIGH), axis=-1), phi


def sector_slots(ego_xy, ego_heading, others, cfg: EnvConfig):
    """Eq. (28)'s choice of whom s_sur shows: the two nearest within d_max in each sector. Per vehicle shown, its
    sector i, rank j (0: nearest), row k of others, distance d [m] and position angle phi [deg]."""
    rel = others[:, :2] - ego_xy
    d = np.hypot(rel[:, 0], rel[:, 1])
    k = np.flatnonzero(d <= cfg.perception)
    sector, phi = sector_index(np.degrees(wrap_angle(np.arctan2(rel[k, 1], rel[k, 0]) - ego_heading)))
    order = np.lexsort((d[k], sector))  # by sector, then nearest first
    sector, k, phi = sector[order], k[order], phi[order]
    rank = np.arange(len(sector)) - np.searchsorted(sector, sector, side="left")
    keep = rank < 2  # Eq. (28): the two nearest per sector, j = 1, 2
    return sector[keep], rank[keep], k[keep], d[k[keep]], phi[keep]


def observe(ego_xy, ego_heading, ego_speed, task, zone, others, cfg: EnvConfig) -> np.ndarray:
    """Eqs. (27)-(30): s = (s_ego, s_sur), 67 numbers. ego_xy [m] centre, ego_heading [rad, CCW from +x],
    ego_speed [m/s]; task, zone: indices of the one-hots h1, h2; others (M, >= 4): centre x, y [m],
    speed [m/s], heading [rad]."""
    s_sur = np.zeros((6, 2, 5))
    i, j, k, d, phi = sector_slots(ego_xy, ego_heading, others, cfg)
    # Eq. (27): d / d_max, v / v_max, (phi - phi_low) / (phi_high - phi_low), (theta - theta_ego + pi) / 2 pi
    s_sur[i, j, 0] = 1.0
    s_sur[i, j, 1] = d / cfg.perception
    s_sur[i, j, 2] = others[k, 2] / cfg.v_norm
    s_sur[i, j, 3] = (phi - PHI_LOW[i]) / (PHI_HIGH[i] - PHI_LOW[i])
    s_sur[i, j, 4] = (wrap_angle(others[k, 3] - ego_heading) + np.pi) / (2.0 * np.pi)
    # Eq. (29): s_ego = (h1, h2, v_ego / v_max)
    s_ego = np.zeros(7)
    s_ego[[task, 3 + zone]] = 1.0
    s_ego[6] = ego_speed / cfg.v_norm
    # Eq. (30): s = (s_ego, s_sur)
    return np.concatenate([s_ego, s_sur.ravel()]).astype(np.float32)


def centre(front, heading, length):
    """SUMO's position of a vehicle is its front bumper: its centre [m] lies length / 2 behind, along heading [rad]."""
    return np.asarray(front) - 0.5 * length * np.stack([np.cos(heading), np.sin(heading)], -1)


def reward(arrived: bool, collided: bool, v: float, v_min: float, v_max: float) -> float:
    """Eq. (31): +20 on arrival, -20 on collision, else min((v - v_min) / (v_max - v_min), 1) x 0.5."""
    if collided:
        return -20.0
    return 20.0 if arrived else min((v - v_min) / (v_max - v_min), 1.0) * 0.5


def boxes_overlap(center, heading, centers, headings, length, width) -> np.ndarray:
    """Separating-axis test of one oriented length x width box against M others ([m], [rad]): (M,) bools.
    SUMO's junction check lags and can miss a merge (PAPER.md, SUMO): collisions are decided here."""
    half = np.array([length / 2.0, width / 2.0])
    u0 = np.array([[math.cos(heading), math.sin(heading)], [-math.sin(heading), math.cos(heading)]])
    c, s = np.cos(headings), np.sin(headings)
    u1 = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], 1)  # (M, 2 axes, 2)
    axes = np.concatenate([np.broadcast_to(u0, u1.shape), u1], 1)  # (M, 4, 2)
    dist = np.abs(np.einsum("mak,mk->ma", axes, np.atleast_2d(centers) - center))
    r0 = np.abs(np.einsum("mak,bk->mab", axes, u0)) @ half
    r1 = np.abs(np.einsum("mak,mbk->mab", axes, u1)) @ half
    return np.all(dist < r0 + r1, axis=1)


# Eqs. (24)-(26): the level-k game of one human (h) and the ego (e), each to CROSS or YIELD at their conflict point
CROSS, YIELD = 0, 1


def arrival_time(d, v, accel, v_desired):
    """Time [s] to cover d [m] from speed v [m/s], accelerating at `accel` [m/s^2] up to v_desired [m/s]."""
    d, v = np.maximum(d, 0.0), np.minimum(v, v_desired)
    t_up = (v_desired - v) / accel
    d_up = 0.5 * (v + v_desired) * t_up
    t_short = (np.sqrt(v * v + 2.0 * accel * d) - v) / accel
    return np.where(d <= d_up, t_short, t_up + (d - d_up) / v_desired)


def game_utility(alpha, gap, wait, decel, waited, cfg: EnvConfig):
    """Eq. (24), each term min-max normalised by Eq. (25) (minimum 0, ranges in cfg; docs/PAPER.md, note 6):
    U = a1 phi_safe - a2 phi_eff - a3 phi_comf + a4 phi_emo. The arrival-time gap [s] makes it safer;
    waiting [s] and braking (a fraction of the player's own capability) cost; having waited [s] pays
    when crossing. alpha: (..., 4) weights."""
    a = np.asarray(alpha)
    return (a[..., 0] * np.clip(gap / cfg.gap_range, 0.0, 1.0) - a[..., 1] * np.clip(wait / cfg.wait_range, 0.0, 1.0)
            - a[..., 2] * np.clip(decel, 0.0, 1.0) + a[..., 3] * np.clip(waited / cfg.emotion_range, 0.0, 1.0))


def outcome_terms(t_me, t_other, stop_decel, waited, me, other, cfg: EnvConfig):
    """The four terms of Eq. (24) for a player choosing `me` against `other`: t_me, t_other [s] the two
    arrival times at the conflict point (arrival_time), stop_decel the braking to stop before it."""
    both_yield = (me == YIELD) & (other == YIELD)
    # a yielding player reaches the conflict point only after the other has passed
    t_mine = np.where((me == YIELD) & (other == CROSS), np.maximum(t_me, t_other + cfg.clear_time), t_me)
    t_theirs = np.where((other == YIELD) & (me == CROSS), np.maximum(t_other, t_me + cfg.clear_time), t_other)
    # both yielding is a standoff: both wait the longest wait, then the conflict is as close as it was
    wait = np.where(both_yield, cfg.wait_range, t_mine - t_me)  # 0 when crossing
    decel = np.where((me == YIELD) & (wait > 0), stop_decel, 0.0)
    return np.abs(t_mine - t_theirs), wait, decel, np.where(me == CROSS, waited, 0.0)


def level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, waited_e, alpha_h, svo, cfg: EnvConfig, level=2):
    """Level-k decisions (CROSS / YIELD, (M,)) of M humans against the ego (Sec. 5.1, Eqs. (24)-(26)).

    Level 0 of a player: its own best reply to an other who goes on (crosses). Level k: the ego, as
    the human pictures it (EGO_GAME_WEIGHTS), best-responds to the level k-1 human; the human
    best-responds with U_svo to the level k-1 ego. The paper's k = 2: h0 against a crossing ego, the
    ego's e1 against h0, the human's reply to e1. Level 1: the human's reply to an ego that best-replies
    to a crossing human. A tie goes to CROSS; a human that cannot stop before the conflict point (decel_h > 1) crosses.
    """
    if level < 0:
        raise ValueError(f"the level of the level-k game is an integer >= 0, not {level!r}")
    m = np.arange(len(t_h))
    me, other = np.array([CROSS, YIELD]).reshape(2, 1, 1), np.array([CROSS, YIELD]).reshape(1, 2, 1)
    # Eq. (24) for every pair of choices, the payoff tables (2 mine, 2 theirs, M): U_h[i, j] is the
    # human's utility when it plays i and the ego j; U_e[i, j] the ego's when it plays i
    U_h = game_utility(alpha_h, *outcome_terms(t_h, t_e, decel_h, waited_h, me, other, cfg), cfg)
    U_e = game_utility(EGO_GAME_WEIGHTS, *outcome_terms(t_e, t_h, decel_e, waited_e, me, other, cfg), cfg)
    h, e = U_h[:, CROSS].argmax(0), U_e[:, CROSS].argmax(0)  # level 0
    for _ in range(level):  # Eq. (26): U_svo = (1 - a_svo) U_self + a_svo U_oppo, against the ego one level down
        h, e = ((1.0 - svo) * U_h[:, e, m] + svo * U_e[e, :, m].T).argmax(0), U_e[:, h, m].argmax(0)
    return np.where(decel_h > 1.0, CROSS, h)


class DrivingEnv(gymnasium.Env):
    """The ego's task in SUMO as a Gymnasium environment (reset -> (obs, info); step -> 5-tuple).

    The simulation runs continuously: traffic flows between episodes, the ego is re-spawned on a
    random free lane and route at every reset, and SUMO restarts (new seed, warm-up) after t_sim.
    reset(seed=s) restarts it with seed s; reset(options={"case": c}) starts a test case of
    record_cases(). The action: the ego's acceleration [m/s^2] in [a_min, a_max].
    info: "collision", "arrival", "timeout" (bools), "crossing_time" [s] from spawn to arrival (None
    before), "cost": the constrained baselines' cost, 1.0 at the step the ego collides, else 0.0.
    libsumo runs one simulation per process (traci for sumo-gui): a new env takes it over.
    render_mode "rgb_array": render() draws the scene from above (scene.py); show(T, beta) tells it who drives.
    Methods in reading order: an episode, the base action, collisions, the game, the observation;
    then SUMO's start-up, the humans, the ego's routes, test cases, helpers.
    """

    _owner: dict = {}  # the env that holds this process's libsumo (False) / TraCI (True) simulation
    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}  # 1 / dt: a frame per step plays in real time

    def __init__(self, cfg: EnvConfig = EnvConfig(), gui: bool = False, render_mode: str | None = None):
        if cfg.scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {cfg.scenario!r}; choose from {sorted(SCENARIOS)}")
        if not isinstance(cfg.human_level, (int, np.integer)) or isinstance(cfg.human_level, bool) or cfg.human_level < 0:
            raise ValueError(f"human_level is the humans' k in the level-k game, an integer >= 0, not {cfg.human_level!r}")
        if cfg.svo_range is not None and not (np.shape(cfg.svo_range) == (2,) and 0.0 <= cfg.svo_range[0]
                                              <= cfg.svo_range[1] <= 1.0):
            raise ValueError(f"svo_range is (low, high) with 0 <= low <= high <= 1, not {cfg.svo_range!r}")
        if cfg.spawn_gap is not None and not cfg.spawn_gap > 0.0:
            raise ValueError(f"spawn_gap is a mean gap [s] > 0 (math.inf: no humans), not {cfg.spawn_gap!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode is one of {self.metadata['render_modes']} or None, not {render_mode!r}")
        self.cfg, self.gui, self.planner_cfg, self.render_mode, self._renderer = cfg, gui, cfg.planner(), render_mode, None
        try:
            self.sim = __import__("traci" if gui else "libsumo")
        except ImportError:
            raise SystemExit("libsumo/traci is not installed: pip install -r requirements.txt") from None
        self.V = self.sim.constants
        self.net_file, self.route_file = scenario_files(cfg.scenario)
        self.observation_space = spaces.Box(0.0, 1.0, (OBS_DIM,), np.float32)
        self.action_space = spaces.Box(np.float32(cfg.a_min), np.float32(cfg.a_max), (1,), np.float32)
        self.rng = np.random.default_rng()
        self.running = self.ego_alive = False
        self.tasks: list[dict] | None = None  # the ego's routes, read from SUMO at the first start
        self.jam_removals = 0  # humans removed from a gridlock (_after_sumo_step), since this env was made

    # ---- An episode: Eqs. (1)-(2) ------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None):
        """Spawn the ego on a random free lane and route; a seed restarts SUMO and the traffic.
        options: {"route": "S_N"} picks the ego's route (scenarios/*.rou.xml); {"case": c} a test case."""
        c, sim, options = self.cfg, self.sim, options or {}
        if self.ego_alive:
            self._end_episode()
        if "case" in options:
            self._load_case(options["case"])
        elif seed is not None:
            super().reset(seed=seed)
            self.rng = self.np_random  # the same stream as np.random.default_rng(seed)
            self._start(seed)
        elif not self.running or sim.simulation.getTime() - self.t_start > c.sc.t_sim:
            self._start(int(self.rng.integers(2**31)))  # Table 1: the simulation restarts every t_sim
        for _ in range(round(60.0 / c.dt)):  # wait (at most 60 s) for a free spawn lane
            free = [t for t in self.tasks if self._lane_start_free(t["first"])
                    and t["route"] == options.get("route", t["route"])]
            if free:
                self.task = free[self.rng.integers(len(free))]
                # "max": the depart speed, lowered by SUMO if that is unsafe behind a queue
                sim.vehicle.add(EGO, self.task["route"], typeID="egotype", depart="now",
                                departLane=str(self.task["lane"]), departPos="0", departSpeed="max")
                self._ego_modes()
            self._spawn_humans()
            self._sumo_step()
            if free and EGO in sim.vehicle.getIDList():
                break
            if free:  # not inserted after all: take it back and try again
                sim.vehicle.remove(EGO)
        else:
            raise RuntimeError("no free lane to spawn the ego for 60 s: the traffic is jammed")
        self._subscribe()
        self.ego_alive, self.t_spawn, self.accel, self.waited, self._headings = True, sim.simulation.getTime(), 0.0, 0.0, {}
        self.shown = (None, None)  # who drives: nobody has said yet (show)
        if self.gui:  # follow the ego at a readable zoom [%]
            sim.gui.setSchema("View #0", "tarl")
            sim.gui.trackVehicle("View #0", EGO)
            sim.gui.setZoom("View #0", 150)
        self._read()
        return self.obs, self._info(False, False, False, 0.0)

    def step(self, action):
        """Eq. (1): s_{t+1} = f(s_t, a_t, xi_t), one SUMO step with the ego's acceleration a_t [m/s^2]."""
        if not self.ego_alive:
            raise RuntimeError("step() after the episode ended: call reset()")
        try:
            a = np.asarray(action, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            a = np.zeros(0)
        if a.shape != (1,) or not np.isfinite(a[0]):
            raise ValueError(f"an action is one finite acceleration [m/s^2], not {action!r}")
        c, sim = self.cfg, self.sim
        v_cmd = max(0.0, self.v + min(max(float(a[0]), c.a_min), c.a_max) * c.dt)
        self.accel = (v_cmd - self.v) / c.dt  # realised exactly: speed mode 32
        sim.vehicle.setSpeed(EGO, v_cmd)
        self._spawn_humans()
        self._sumo_step()
        self._after_sumo_step()
        self._read()
        collided = self._collided()
        arrived = not collided and self.s >= self.task["dest"]
        self.waited = self.waited + c.dt if self.v < 0.1 else 0.0
        t = sim.simulation.getTime() - self.t_spawn  # [s] since spawn
        truncated = t >= c.time_limit - 1e-9 and not (collided or arrived)
        info = self._info(collided, arrived, truncated, t)
        if collided or arrived or truncated:
            self._end_episode()
        else:
            self._play_level_k()
        return self.obs, reward(arrived, collided, self.v, c.v_min, c.v_max), collided or arrived, truncated, info

    # ---- The base action: Eqs. (18)-(23), planner.py -----------------------------------------
    def plan(self) -> planner.Plan:
        """The base planner now (once per step): a_base of Eq. (23), the state machine's mode, and the
        planned positions [m] of the ego's centre along its path at the planner's grid times."""
        if self._plan is None:
            self._plan = planner.plan(self.s - self.cfg.length / 2, self.v, self.accel, self.task["s"],
                                      self.task["xy"], self.others, self.planner_cfg)
        return self._plan

    def base_action(self) -> float:
        """a_base of Eq. (23) in the present state, from planner.py."""
        return self.plan().a_base

    def plan_xy(self) -> np.ndarray:
        """The base planner's planned trajectory now as (K, 2) points x, y [m] of the ego's centre."""
        return np.stack([np.interp(self.plan().s, self.task["s"], self.task["xy"][:, k]) for k in (0, 1)], 1)

    # ---- Collisions --------------------------------------------------------------------------
    def _collided(self) -> bool:
        c = self.cfg
        if EGO in self.sim.simulation.getCollidingVehiclesIDList():
            return True
        near = np.hypot(*(self.others[:, :2] - self.xy).T) < math.hypot(c.length, c.width)
        return bool(near.any()) and bool(np.any(boxes_overlap(self.xy, self.heading, self.others[near, :2],
                                                              self.others[near, 3], c.length, c.width)))

    # ---- The level-k game: Eqs. (24)-(26) ----------------------------------------------------
    def _play_level_k(self):
        """Every human approaching a conflict point it shares with the ego plays the level-k game (k: human_level).

        Each player's arrival time accelerates at its own a_max to its own speed: a human's Table 1
        desired speed, or its crossing speed v_cr at the intersection; the ego's v_max of Eq. (31).
        YIELD: the human's speed is capped by sqrt(2 b d_stop), so it stops before the junction of the
        conflict point, or stop_margin before the point itself; CROSS: it stops yielding to the ego
        (junctionModel.ignoreIDs), keeping SUMO's right of way among humans. Decisions are renewed every
        step; a human leaves the game at the conflict point or once the ego has passed it.
        """
        sim, c = self.sim, self.cfg
        foes = {}
        for f in sim.vehicle.getJunctionFoes(EGO, c.game_horizon):
            h, d_e, d_h, someone_yields = f[0], f[1], f[2], f[7] or f[8]
            if someone_yields and h in self.humans and d_e > 0.0 and d_h > 0.0 and (h not in foes or d_e < foes[h][0]):
                foes[h] = (d_e, d_h, f[6])
        for h in [h for h in self.decisions if h not in foes]:
            self._release(h)
        if not foes:
            return
        ids = list(foes)
        d_e, d_h = np.array([foes[h][:2] for h in ids]).T
        p = np.array([self.humans[h] for h in ids])
        v_h = np.array([sim.vehicle.getSpeed(h) for h in ids])
        waited_h = np.array([sim.vehicle.getWaitingTime(h) for h in ids])
        t_h = arrival_time(d_h, v_h, p[:, 6], p[:, 7])
        t_e = arrival_time(d_e, self.v, c.a_max, c.v_max)
        decel_h = v_h**2 / (2.0 * np.maximum(d_h - c.stop_margin, 0.1)) / p[:, 5]
        decel_e = self.v**2 / (2.0 * np.maximum(d_e - c.stop_margin, 0.1)) / -c.a_min
        choice = level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, self.waited, p[:, :4], p[:, 4], c,
                                   c.human_level)
        # A human inside the junction has committed: it clears the junction rather than stop in it
        # (humans stopped mid-junction block each other: the all-way stop gridlocks) ...
        lanes = [sim.vehicle.getLaneID(h) for h in ids]
        inside = np.array([lane.startswith(":") for lane in lanes])
        choice = np.where(inside, CROSS, choice)
        # ... unless the ego is at the conflict point (within a car length): whoever can still stop yields
        choice = np.where((d_e < c.length) & (decel_h <= 1.0), YIELD, choice)
        for h, k, dh, vh, b, a, lane, within in zip(ids, choice, d_h, v_h, p[:, 5], p[:, 6], lanes, inside):
            if self.decisions.get(h) != k:
                sim.vehicle.setParameter(h, "junctionModel.ignoreIDs", EGO if k == CROSS else "")
                self.decisions[h] = k
            if k == YIELD:
                # It stops before the junction of the conflict point if that is the next one (at its
                # stop line, or a ring junction's entry), else stop_margin before the conflict point.
                stop = dh - c.stop_margin
                if not within and sim.edge.getToJunction(lane.rsplit("_", 1)[0]) == foes[h][2][1:].rsplit("_", 2)[0]:
                    stop = min(stop, sim.lane.getLength(lane) - sim.vehicle.getLanePosition(h) - 0.5)
                limit = math.sqrt(2.0 * b * max(0.0, stop))
            if k == YIELD and limit < vh + a * c.dt:  # the stopping profile binds: cap the speed
                sim.vehicle.setSpeed(h, limit)
                self.capped[h] = limit
            elif h in self.capped:
                sim.vehicle.setSpeed(h, -1)
                del self.capped[h]

    def _release(self, h):
        """Hand a human back to SUMO's own driving."""
        try:
            if self.decisions.pop(h, None) == CROSS:
                self.sim.vehicle.setParameter(h, "junctionModel.ignoreIDs", "")
            if h in self.capped:
                self.sim.vehicle.setSpeed(h, -1)
        except self.sim.TraCIException:  # it has left the network
            pass
        self.capped.pop(h, None)

    # ---- The observation: Eqs. (27)-(30) -----------------------------------------------------
    def _read(self):
        """Eqs. (27)-(30): read the ego and everyone within d_max (one subscription each), observe."""
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
        self.other_ids = ids = [k for k in ctx if k != EGO]  # the rows of others
        # others: centre x, y [m] (from the front bumper), speed [m/s], heading [rad], yaw rate [rad/s]
        self.others = np.zeros((len(ids), 5))
        if ids:
            others = np.array([(*ctx[k][V.VAR_POSITION], ctx[k][V.VAR_SPEED], ctx[k][V.VAR_ANGLE], 0.0) for k in ids])
            others[:, 3] = heading = np.radians(90.0 - others[:, 3])
            others[:, :2] = centre(others[:, :2], heading, L)
            before = np.array([self._headings.get(k, h) for k, h in zip(ids, heading.tolist())])
            others[:, 4] = wrap_angle(heading - before) / self.cfg.dt  # over the last step
            self._headings = dict(zip(ids, heading.tolist()))
            self.others = others
        self._plan = None
        self.obs = observe(self.xy, self.heading, self.v, self.task["task"], zone, self.others, self.cfg)

    # ---- SUMO: start-up and restarts ---------------------------------------------------------
    def _start(self, seed: int, warmup: bool = True):
        c, sim = self.cfg, self.sim
        args = ["-n", str(self.net_file), "-r", str(self.route_file), "--step-length", str(c.dt),
                "--seed", str(seed), "--default.carfollowmodel", "IDM", "--collision.check-junctions", "true",
                "--collision.action", "warn", "--collision.mingap-factor", "0", "--time-to-teleport", "-1",
                "--no-step-log", "true", "--no-warnings", "true",
                # a human that cannot enter its spawn lane within 30 s is dropped: no backlog at a spawn point
                "--max-depart-delay", "30",
                # test cases are saved states: keep every digit of the humans' parameters
                "--save-state.precision", "17", "--save-state.rng", "true"]
        if self.gui:  # scenarios/gui.xml: the ego's timing written beside it
            args += ["--start", "--quit-on-end", "--delay", "100", "--window-size", "1000,800",
                     "--gui-settings-file", str(HERE / "scenarios" / "gui.xml")]
        check_network(self.net_file, self.route_file)
        if DrivingEnv._owner.get(self.gui) is not None:  # one simulation per process: take it over
            DrivingEnv._owner[self.gui].running = DrivingEnv._owner[self.gui].ego_alive = False
            sim.load(args)
        else:
            sim.start([str(sumo_home() / "bin" / ("sumo-gui" if self.gui else "sumo")), *args])
        self.running, self.ego_alive, DrivingEnv._owner[self.gui] = True, False, self
        for vt in ("human", "egotype"):
            sim.vehicletype.copy("DEFAULT_VEHTYPE", vt)
            sim.vehicletype.setLength(vt, c.length)
            sim.vehicletype.setWidth(vt, c.width)
            sim.vehicletype.setMaxSpeed(vt, c.v_norm)
            sim.vehicletype.setSpeedDeviation(vt, 0.0)
        sim.vehicletype.setImpatience("human", c.sc.impatience)
        self.t_start = sim.simulation.getTime()
        self.next_spawn = self.t_start + self.rng.exponential(self.spawn_gap)
        self.n_humans = 0
        self.humans: dict[str, np.ndarray] = {}  # id -> alpha1..4, svo, decel, accel, game speed (_spawn_humans)
        self.decisions: dict[str, int] = {}  # humans now playing the game -> CROSS / YIELD
        self.capped: dict[str, float] = {}  # yielding humans whose speed is capped -> the cap [m/s]
        if self.tasks is None:  # the network's, read once (every test case starts a new simulation)
            self.tasks = self._ego_tasks()
            self.internal_lanes = [lane for lane in sim.lane.getIDList() if lane.startswith(":")]
        if warmup:
            self._run_traffic(c.warmup)

    def _run_traffic(self, seconds: float):
        """The humans alone, no ego, for this long."""
        for _ in range(round(seconds / self.cfg.dt)):
            self._spawn_humans()
            self._sumo_step()
            self._after_sumo_step()

    def close(self):
        if self.running:
            self.sim.close()
            self.running, self.ego_alive, DrivingEnv._owner[self.gui] = False, False, None

    @property
    def spawn_gap(self) -> float:
        return self.cfg.sc.spawn_gap if self.cfg.spawn_gap is None else self.cfg.spawn_gap

    # ---- Human drivers: Table 1 --------------------------------------------------------------
    def _spawn_humans(self):
        """Departures in the whole network with exponential gaps of mean t_spawn, on random routes (Table 1)."""
        sim, c, rng = self.sim, self.cfg, self.rng
        while self.next_spawn <= sim.simulation.getTime():
            self.next_spawn += rng.exponential(self.spawn_gap)
            vid = f"h{self.n_humans}"
            self.n_humans += 1
            sim.vehicle.add(vid, self.routes[rng.integers(len(self.routes))], typeID="human",
                            depart="now", departLane="best", departSpeed="max")
            # svo_range replaces one range: the same draws in the same order, whatever it is
            ranges = HUMAN_RANGES if c.svo_range is None else {**HUMAN_RANGES, "svo": c.svo_range}
            p = {k: rng.uniform(*r) for k, r in ranges.items()}
            sim.vehicle.setAccel(vid, p["accel"])
            sim.vehicle.setDecel(vid, p["decel"])
            sim.vehicle.setMinGap(vid, p["min_gap"])
            sim.vehicle.setMaxSpeed(vid, p["speed"])
            sim.vehicle.setLaneChangeMode(vid, 0)  # lanes are chosen at departure (PAPER.md, SUMO)
            v_game = p["speed"]  # [m/s] its speed at the conflict point, in the game
            if c.sc.crossing_speed:  # the connections' speed limit times this factor is its own v_cr
                v_game = rng.uniform(*c.sc.crossing_speed)
                sim.vehicle.setSpeedFactor(vid, v_game / CONNECTION_SPEED)
            self.humans[vid] = np.array([p["alpha1"], p["alpha2"], p["alpha3"], p["alpha4"], p["svo"],
                                         p["decel"], p["accel"], v_game])

    # ---- The ego's routes --------------------------------------------------------------------
    def _ego_tasks(self):
        """Every (route, start lane) the ego can drive without changing lanes, with its path polyline."""
        sim, tasks = self.sim, []
        self.routes = sorted(r for r in sim.route.getIDList() if not r.startswith("!"))
        for rid in self.routes:
            edges = sim.route.getEdges(rid)
            for idx in range(sim.edge.getLaneNumber(edges[0])):
                lanes = follow(sim.lane, edges, f"{edges[0]}_{idx}")
                if lanes is None:
                    continue
                shapes = [np.asarray(sim.lane.getShape(lane), dtype=float) for lane in lanes]
                xy = np.concatenate(shapes)
                xy = xy[np.r_[True, np.any(np.abs(np.diff(xy, axis=0)) > 1e-6, axis=1)]]  # joints once
                drawn = [float(np.sum(np.hypot(*np.diff(sh, axis=0).T))) for sh in shapes]
                starts = np.concatenate([[0.0], np.cumsum(drawn)[:-1]])
                # SUMO's lane lengths differ from the drawn shapes (by ~10 % on the ring): a lane
                # position is scaled to the drawn length, so s is measured along the path xy
                lane_s = {lane: (start, d / sim.lane.getLength(lane)) for lane, start, d in zip(lanes, starts, drawn)}
                tasks.append(dict(route=rid, lane=idx, first=lanes[0], edges=edges, xy=xy, lane_s=lane_s,
                                  s=np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]),
                                  dest=starts[-1] + self.cfg.destination, task=self._task_index(edges, lanes)))
        if not tasks:
            raise SystemExit(f"{self.route_file.name}: no route the ego can drive; rebuild the scenarios")
        return tasks

    def _task_index(self, edges, lanes) -> int:
        """h1 of Eq. (29): straight/left/right at the intersection, exit 1/2/3 at the roundabout."""
        if self.cfg.scenario == "intersection":
            link = [link for link in self.sim.lane.getLinks(lanes[0]) if link[0].rsplit("_", 1)[0] == edges[1]][0]
            return {"s": 0, "l": 1, "L": 1, "r": 2, "R": 2}[link[6]]
        # roundabout (counter-clockwise): quarter turns from the entry to the exit = exit number
        a_in, a_out = self.sim.lane.getShape(lanes[0])[-1], self.sim.lane.getShape(lanes[-1])[0]
        turn = (math.atan2(a_out[1], a_out[0]) - math.atan2(a_in[1], a_in[0])) % (2 * math.pi)
        return min(2, max(0, round(turn / (math.pi / 2)) - 1))

    # ---- Test cases: Sec. 5.3 ----------------------------------------------------------------
    def record_cases(self, seed: int, n: int, folder: Path) -> list[dict]:
        """The n test cases of an evaluation round: SUMO started with `seed` and warmed up, then the
        traffic alone, its state saved every case_gap seconds (restarted after t_sim, as in training).

        Case c is snapshot c with a seed of its own, which draws the ego's route and the humans who
        depart during the episode: every model meets the same traffic, departures and route. What the
        humans do next depends on the ego, through the game. A case loads in about 8 ms (a new
        simulation, then its saved state: _load_case), a new start with its warm-up takes about 50 ms.
        """
        self.rng = np.random.default_rng(seed)
        self._start(seed)
        cases = []
        for c in range(n):
            if self.sim.simulation.getTime() - self.t_start > self.cfg.sc.t_sim:
                self._start(int(self.rng.integers(2**31)))
            self._run_traffic(self.cfg.case_gap)
            file = str(Path(folder) / f"case{c}.xml")
            self.sim.simulation.saveState(file)
            alive = {*self.sim.vehicle.getIDList(), *self.sim.simulation.getPendingVehicles()}
            cases.append(dict(file=file, seed=[seed, c], n_humans=self.n_humans,
                              humans={h: p for h, p in self.humans.items() if h in alive}))
        return cases

    def _load(self, file: str, seed: int):
        """A saved state (a test case, or save_state's) in a new simulation (~10 ms): loadState keeps
        something of the run before it (SUMO 1.28, docs/PAPER.md), a new simulation makes it continue the same."""
        self._start(seed, warmup=False)
        self.sim.simulation.loadState(file)
        for h in self.sim.vehicle.getIDList():
            self.sim.vehicle.setLaneChangeMode(h, 0)  # a saved state forgets it (the ego's too: 0 as well)

    def _sumo_step(self):
        """One SUMO step. A loaded state also forgets the lane-change mode of the humans still waiting to depart, and
        lists them only after a step (SUMO 1.28, docs/PAPER.md): each human gets it back as it enters, before it can change
        lanes (a no-op without a load: _spawn_humans set it)."""
        self.sim.simulationStep()
        for h in self.sim.simulation.getDepartedIDList():
            if h in self.humans:
                self.sim.vehicle.setLaneChangeMode(h, 0)

    def _load_case(self, case: dict):
        self._load(case["file"], case["seed"][0])
        self.humans, self.n_humans, self.decisions, self.capped = dict(case["humans"]), case["n_humans"], {}, {}
        self.rng = np.random.default_rng(case["seed"])
        self.t_start = self.sim.simulation.getTime()
        self.next_spawn = self.t_start + self.rng.exponential(self.spawn_gap)

    # ---- Branching: an episode's whole state, saved and restored (beyond/rollout_timing.py) --------------------
    # The env's own fields of a running episode, which SUMO's file does not hold (test_rollout_timing checks that no
    # field escapes). What _read saw is kept: right after a load, before a step, libsumo's context subscription still
    # returns vehicles of the simulation before it (SUMO 1.28), so the state is not read anew
    EPISODE_STATE = ("humans", "n_humans", "decisions", "capped", "t_start", "next_spawn", "task", "t_spawn", "accel",
                     "waited", "_headings", "shown", "jam_removals", "v", "heading", "xy", "s", "others", "other_ids", "obs")

    def save_state(self, file) -> dict:
        """The whole state between two steps of an episode, for restore_state: SUMO's (saveState to `file`, every
        digit and its rng) and the env's own (EPISODE_STATE, the traffic's rng)."""
        if not self.ego_alive:
            raise RuntimeError("save_state() saves an episode under way: call it between reset() and its end")
        self.sim.simulation.saveState(str(file))
        own = {k: dict(v) if isinstance(v, dict) and k != "task" else v for k, v in vars(self).items()
               if k in self.EPISODE_STATE}
        return dict(file=str(file), env=own, rng=self.rng.bit_generator.state)

    def restore_state(self, state: dict) -> np.ndarray:
        """Back to a save_state(); returns the observation. A new simulation loads SUMO's file: two restores of one
        state continue alike step for step, though not exactly as the run that was saved (SUMO 1.28 reloads
        positions to about 1 cm: docs/PAPER.md, section 4). Then the env's own state, and what SUMO's file forgets: the
        humans' game (who ignores the ego, speed caps), the ego's driving modes and subscriptions."""
        self._load(state["file"], 0)  # SUMO's rng comes from the file (--save-state.rng)
        for k, v in state["env"].items():
            setattr(self, k, dict(v) if isinstance(v, dict) and k != "task" else v)
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = state["rng"]
        for h, k in self.decisions.items():
            self.sim.vehicle.setParameter(h, "junctionModel.ignoreIDs", EGO if k == CROSS else "")
        for h, limit in self.capped.items():
            self.sim.vehicle.setSpeed(h, limit)
        self._ego_modes()
        self._subscribe()
        self.ego_alive, self._plan = True, None
        return self.obs

    def fingerprint(self) -> str:
        """A hash of every vehicle now, the ego's route and the departures to come (the traffic's rng):
        two episodes with the same fingerprint started from the same test case."""
        vehicles = sorted((v, *np.round(self.sim.vehicle.getPosition(v), 2), round(self.sim.vehicle.getSpeed(v), 2))
                          for v in self.sim.vehicle.getIDList())
        state = (vehicles, self.task["route"], self.next_spawn, self.rng.bit_generator.state)
        return hashlib.sha1(repr(state).encode()).hexdigest()[:16]

    # ---- Helpers -----------------------------------------------------------------------------
    def show(self, T: int | None, beta: float | None):
        """Who drives the next step, for render() and beside the ego in sumo-gui (scenarios/gui.xml): the
        timing T (None without one) and beta (1: the actor alone, 0: the planner alone)."""
        self.shown = (T, beta)
        if self.gui:
            self.sim.vehicle.setParameter(EGO, "timing", f"T = {T or '-'}, beta = {beta:.2f}")

    def snapshot(self) -> dict:
        """The scene now as plain data, what render() draws (after the episode's end, its last state): every
        other vehicle in SUMO (ids, (M, 3) centre x, y [m], heading [rad]), the humans in the game with the
        ego and their choice, the ego's (x, y, heading), speed [m/s], zone (h2), time since spawn [s], the base
        planner's path (K, 2) [m] and who drives (show)."""
        sim, c = self.sim, self.cfg
        ids = [v for v in sim.vehicle.getIDList() if v != EGO]
        xyh = np.array([(*sim.vehicle.getPosition(v), math.radians(90.0 - sim.vehicle.getAngle(v))) for v in ids]
                       or np.zeros((0, 3)))
        xyh[:, :2] = centre(xyh[:, :2], xyh[:, 2], c.length)
        T, beta = self.shown
        return dict(t=sim.simulation.getTime() - self.t_spawn, v=self.v, ego=np.array([*self.xy, self.heading]), ids=ids,
                    vehicles=xyh, game={h: ("cross", "yield")[k] for h, k in self.decisions.items()},
                    zone=int(np.argmax(self.obs[3:6])), plan=self.plan_xy(), T=T, beta=beta, length=c.length,
                    width=c.width, perception=c.perception)

    def render(self):
        """render_mode "rgb_array": the scene from above as an (H, W, 3) uint8 frame (scene.py draws it)."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() without a render_mode: make the env with render_mode='rgb_array'")
            return None
        if not hasattr(self, "task"):
            raise RuntimeError("render() before the first reset(): there is no scene yet")
        import scene  # matplotlib loads only when something is drawn
        self._renderer = self._renderer or scene.Renderer(self.net_file)
        return self._renderer.frame(self.snapshot())

    def _ego_modes(self):  # the ego's driving modes, after its insertion or a load (a saved state forgets them)
        sim = self.sim
        sim.vehicle.setSpeedFactor(EGO, self.cfg.ego_depart_speed / sim.lane.getMaxSpeed(self.task["first"]))
        sim.vehicle.setSpeedMode(EGO, 32)  # SUMO never overrides the ego (PAPER.md, SUMO)
        sim.vehicle.setLaneChangeMode(EGO, 0)
        sim.vehicle.setColor(EGO, (255, 0, 0, 255))

    def _subscribe(self):  # what _read reads each step: the ego, and every vehicle within d_max of it
        V = self.V
        self.sim.vehicle.subscribe(EGO, [V.VAR_POSITION, V.VAR_ANGLE, V.VAR_SPEED, V.VAR_LANE_ID, V.VAR_LANEPOSITION])
        self.sim.vehicle.subscribeContext(EGO, V.CMD_GET_VEHICLE_VARIABLE, self.cfg.perception,
                                          [V.VAR_POSITION, V.VAR_SPEED, V.VAR_ANGLE])

    def _info(self, collided, arrived, timeout, t):
        return dict(collision=collided, arrival=arrived, timeout=timeout, crossing_time=t if arrived else None,
                    cost=float(collided))

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
        return all(self.sim.vehicle.getLanePosition(v) > self.cfg.spawn_clear + self.cfg.length
                   for v in self.sim.lane.getLastStepVehicleIDs(lane))

    def _after_sumo_step(self):
        """After every SUMO step: forget the humans who left, and once a second clear the junctions of
        humans stuck in them for jam_time (a gridlock of humans inside the junction lasts for good,
        with the ego driving through a frozen world: at the intersection from ~400 s on)."""
        sim = self.sim
        gone = list(sim.simulation.getArrivedIDList())
        if round(sim.simulation.getTime() / self.cfg.dt) % round(1.0 / self.cfg.dt) == 0:
            stuck = [h for lane in self.internal_lanes for h in sim.lane.getLastStepVehicleIDs(lane)
                     if h != EGO and sim.vehicle.getWaitingTime(h) >= self.cfg.jam_time]
            for h in stuck:
                self._release(h)
                sim.vehicle.remove(h)
            self.jam_removals += len(stuck)
            gone += stuck
        for h in gone:
            self.humans.pop(h, None)
            self.decisions.pop(h, None)
            self.capped.pop(h, None)


def make(render_mode: str | None = None, **fields) -> DrivingEnv:
    """gymnasium.make's entry point: EnvConfig's fields as keyword arguments, e.g. spawn_gap=0.9."""
    return DrivingEnv(EnvConfig(**fields), render_mode=render_mode)


for _name in SCENARIOS:  # gymnasium.make("tarl/Roundabout-v0", render_mode="rgb_array") after `import world`
    gymnasium.register(f"tarl/{_name.title()}-v0", entry_point="world:make", kwargs={"scenario": _name})
