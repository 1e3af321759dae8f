"""The rollout timing (beyond the paper, PAPER.md 6): how good can any state-dependent T be, with this actor?

TARL's timing taker picks T from the state (Eq. (5)); RESULTS.md finds it does no better than a fixed T = 2
or a random T. This driver measures the ceiling of a timing that sees the state, by simulating instead of
learning: a one-step lookahead over a base policy (Bertsekas, rollout algorithms), the base policy being the
actor timed by the default T = 2.

At a decision where T can matter (the actor's and the planner's accelerations differ by at least `gap`), the
whole state is saved (save_state, below) and every candidate T is played from it: held for `hold` steps
(Eqs. (11)-(12), a fresh a_t each step), then T = 2 to the episode's end. Each candidate meets the same K
futures (common random numbers), drawn anew from seeds of their own (resample_future: the humans'
game weights and SVO, the departures to come), never the test case's own future. The T with the best mean
return (Eq. (31), to the episode's end) is executed for `hold` steps; a tie keeps T = 2. Elsewhere T = 2.

    python tarl.py --scenario roundabout --load results/runs/roundabout-tarl-s0/policy.pt --timing rollout \\
        --eval-rows trained --eval-rounds 2
    --timing rollout=2: the control, T = 2 with the same saves and reloads and no branch

Each case's decisions, branch steps and wall time go to eval.json (experiment.summarize).
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import tarl
from tarl import DrivingEnv, TimingConfig, beta, execute
from world import CROSS, EGO, HUMAN_RANGES

# ---- Branching the world: its whole state saved, restored, and its future drawn anew ---------------------
# What SUMO's file does not hold, and what DrivingEnv._read saw: right after a load, before a step, libsumo's context
# subscription still returns vehicles of the simulation before it (SUMO 1.28), so the state is not read anew
OWN_STATE = ("humans", "n_humans", "decisions", "capped", "t_start", "next_spawn", "task", "t_spawn", "accel",
             "waited", "_headings", "shown", "jam_removals", "v", "heading", "xy", "s", "others", "obs")


def save_state(env: DrivingEnv, file) -> dict:
    """The whole state of env between two steps of an episode, for restore_state: SUMO's (saveState to `file`, every
    digit and its rng) and the env's own (OWN_STATE, the traffic's rng)."""
    if not env.ego_alive:
        raise RuntimeError("save_state() saves an episode under way: call it between reset() and its end")
    env.sim.simulation.saveState(str(file))
    own = {k: dict(v) if isinstance(v, dict) and k != "task" else v for k, v in vars(env).items() if k in OWN_STATE}
    return dict(file=str(file), env=own, rng=env.rng.bit_generator.state)


def restore_state(env: DrivingEnv, state: dict) -> np.ndarray:
    """Back to a save_state(); returns the observation. A new simulation loads SUMO's file: two restores of one state
    continue alike step for step, though not exactly as the run that was saved (SUMO 1.28 reloads positions to
    about 1 cm: PAPER.md, section 4). Then the env's own state, and what SUMO's file forgets: the humans' game (who
    ignores the ego, speed caps), the ego's driving modes and subscriptions."""
    env._load(state["file"], 0)  # SUMO's rng comes from the file (--save-state.rng)
    for k, v in state["env"].items():
        setattr(env, k, dict(v) if isinstance(v, dict) and k != "task" else v)
    env.rng = np.random.default_rng()
    env.rng.bit_generator.state = state["rng"]
    for h, k in env.decisions.items():
        env.sim.vehicle.setParameter(h, "junctionModel.ignoreIDs", EGO if k == CROSS else "")
    for h, limit in env.capped.items():
        env.sim.vehicle.setSpeed(h, limit)
    env._ego_modes()
    env._subscribe()
    env.ego_alive, env._plan = True, None
    return env.obs


def resample_future(env: DrivingEnv, rng: np.random.Generator):
    """Draw from rng anew what the ego cannot know (a branch that must not see its test case's future): the game
    weights and SVO of the humans present (Table 1's ranges; their kinematics are in SUMO's state and show in how
    they drive) and every departure to come, its time, route and parameters."""
    ranges = HUMAN_RANGES if env.cfg.svo_range is None else {**HUMAN_RANGES, "svo": env.cfg.svo_range}
    for h, p in env.humans.items():
        env.humans[h] = np.r_[[rng.uniform(*ranges[k]) for k in ("alpha1", "alpha2", "alpha3", "alpha4", "svo")], p[5:]]
    env.rng = rng
    env.next_spawn = env.sim.simulation.getTime() + rng.exponential(env.spawn_gap)  # departures are memoryless


FUTURE_TAG = 0x5EED  # a branch's seed is (FUTURE_TAG, the case's seed, step, k): never the case's own stream


@dataclass(frozen=True)
class RolloutConfig:
    """The lookahead's settings, all open (PAPER.md, 6)."""

    candidates: tuple[int, ...] = (1, 2, 3, 10)  # T tried: the actor alone, half, mostly and only the planner
    futures: int = 3  # K: resampled futures per candidate
    hold: int = 10  # [steps] a candidate is held in its branch, and the chosen T in the episode (2 s)
    gap: float = 1.0  # [m/s^2] |a_t - a_base,t| from which T can matter: below it, every T acts alike
    default_T: int = 2  # the base policy's timing: between decisions, and after a branch's hold


class RolloutTiming(tarl.Driver):
    """A Driver (tarl.Driver's act -> (a, T, beta)) whose T comes from simulated branches. stats(): the
    episode's decisions, branch steps (simulator steps played in branches) and wall time [s]."""

    def __init__(self, actor, seed: int = 0, timing_cfg: TimingConfig = TimingConfig(), cfg: RolloutConfig = RolloutConfig()):
        if not cfg.candidates or min(cfg.candidates) < 1 or cfg.futures < 1 or cfg.hold < 1:
            raise ValueError(f"a rollout timing needs candidates T >= 1, futures >= 1 and hold >= 1, not {cfg}")
        super().__init__("fixed", actor, None, seed, timing_cfg, fixed_T=cfg.default_T)
        self.timing, self.cfg, self.settings, self._folder = "rollout", cfg, asdict(cfg), None
        self.new_episode()

    def __getstate__(self):  # sent to an evaluation worker without its temporary folder
        return {**vars(self), "_folder": None}

    def new_episode(self, seed=None):
        super().new_episode(seed)
        self.case_seed = [] if seed is None else list(np.atleast_1d(seed))
        self.held = None  # [T, steps it is still held]
        self.counts, self.t0 = dict(decisions=0, branch_steps=0), time.perf_counter()

    def stats(self) -> dict:
        return dict(self.counts, wall_s=round(time.perf_counter() - self.t0, 3))

    def act(self, obs, env: DrivingEnv, deterministic: bool = False, a=None):
        a = self.actor.act(obs, deterministic) if a is None else a
        T = self.cfg.default_T
        if self.held is not None and self.held[1] > 0:
            T, self.held[1] = self.held[0], self.held[1] - 1
        elif abs(float(a[0]) - env.base_action()) >= self.cfg.gap:
            T = self.choose(env, deterministic)
            self.held = [T, self.cfg.hold - 1]
        return a, T, float(beta(T, omega=self.timing_cfg.omega))  # Eq. (11)

    def choose(self, env: DrivingEnv, deterministic: bool) -> int:
        """The candidate with the best mean return over the K futures; the env is then back where it was,
        reloaded (restore_state), with its own future."""
        if self._folder is None:
            self._folder = tempfile.TemporaryDirectory(prefix="tarl-rollout-")
        state = save_state(env, Path(self._folder.name) / "state.xml")
        step = round((env.sim.simulation.getTime() - env.t_spawn) / env.cfg.dt)
        self.counts["decisions"] += 1
        best = self.cfg.default_T
        if len(self.cfg.candidates) > 1:
            futures = [[FUTURE_TAG, *self.case_seed, step, k] for k in range(self.cfg.futures)]
            score = {T: np.mean([self.branch(env, state, T, np.random.default_rng(f), deterministic) for f in futures])
                     for T in self.cfg.candidates}  # Eq. (31)'s return to the episode's end, undiscounted
            best = max(score, key=lambda T: (score[T], T == self.cfg.default_T))  # a tie keeps the default
        restore_state(env, state)
        return best

    def branch(self, env: DrivingEnv, state: dict, T: int, rng: np.random.Generator, deterministic: bool) -> float:
        rewards = play_branch(env, self.actor, state, T, rng, self.cfg, self.timing_cfg.omega, deterministic)
        self.counts["branch_steps"] += len(rewards)
        return float(np.sum(rewards))


def play_branch(env: DrivingEnv, actor, state: dict, T: int, rng: np.random.Generator, cfg: RolloutConfig,
                omega: float, deterministic: bool = True, on_step=None) -> list[float]:
    """The rewards (Eq. (31)) of a branch from a saved state, to the episode's end, in the future rng draws: T held
    for cfg.hold steps (Eqs. (11)-(12), a fresh a_t each step), then cfg.default_T. on_step() after each step."""
    obs = restore_state(env, state)
    resample_future(env, rng)
    rewards, done = [], False
    while not done:
        b = float(beta(T if len(rewards) < cfg.hold else cfg.default_T, omega=omega))
        obs, r, terminated, truncated, _ = env.step(execute(env, actor.act(obs, deterministic), b))
        rewards.append(r)
        done = terminated or truncated
        if on_step is not None:
            on_step()
    return rewards


def parse(spec: str) -> RolloutConfig | None:
    """--timing rollout or rollout=T1,T2,... (the candidates); None if spec is not a rollout timing."""
    name, eq, value = spec.partition("=")
    if name != "rollout":
        return None
    if not eq:
        return RolloutConfig()
    Ts = value.split(",")
    if not all(T.isdigit() and int(T) >= 1 for T in Ts):
        raise ValueError(f"{spec}: rollout=T1,T2,... with every T >= 1")
    return RolloutConfig(candidates=tuple(int(T) for T in Ts))
