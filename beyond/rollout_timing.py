"""The rollout timing (beyond the paper, docs/PAPER.md 6): how good can any state-dependent T be, with this actor?

TARL's timing taker picks T from the state (Eq. (5)); docs/RESULTS.md finds it does no better than a fixed T = 2
or a random T. This driver measures the ceiling of a timing that sees the state, by simulating instead of
learning: a one-step lookahead over a base policy (Bertsekas, rollout algorithms), the base policy being the
actor timed by the default T = 2.

At a decision where T can matter (the actor's and the planner's accelerations differ by at least `gap`), the
whole state is saved (DrivingEnv.save_state) and every candidate T is played from it: held for `hold` steps
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
from tarl import TimingConfig, beta, execute
from world import HUMAN_RANGES, DrivingEnv

# ---- Branching the world: DrivingEnv.save_state and restore_state, and a future drawn anew ---------------------


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
            T = self.choose(env, a, deterministic)
            self.held = [T, self.cfg.hold - 1]
        return a, T, float(beta(T, omega=self.timing_cfg.omega))  # Eq. (11)

    def choose(self, env: DrivingEnv, a, deterministic: bool) -> int:
        """The candidate with the best mean return over the K futures, each branch's first step with this decision's
        action a; the env is then back where it was, reloaded (DrivingEnv.restore_state), with its own future.
        self.returns: (candidates, K) the return of each candidate in each future (common random numbers)."""
        if self._folder is None:
            self._folder = tempfile.TemporaryDirectory(prefix="tarl-rollout-")
        state = env.save_state(Path(self._folder.name) / "state.xml")
        step = round((env.sim.simulation.getTime() - env.t_spawn) / env.cfg.dt)
        self.counts["decisions"] += 1
        self.returns = np.zeros((len(self.cfg.candidates), self.cfg.futures))
        if len(self.cfg.candidates) > 1:
            futures = [[FUTURE_TAG, *self.case_seed, step, k] for k in range(self.cfg.futures)]
            self.returns = np.array([[self.branch(env, state, T, np.random.default_rng(f), deterministic, a)
                                      for f in futures] for T in self.cfg.candidates])  # Eq. (31), undiscounted
        env.restore_state(state)
        return best_candidate(self.cfg, self.returns.mean(axis=1))

    def branch(self, env: DrivingEnv, state: dict, T: int, rng: np.random.Generator, deterministic: bool, a) -> float:
        rewards = play_branch(env, self.actor, state, T, rng, self.cfg, self.timing_cfg.omega, deterministic, first=a)
        self.counts["branch_steps"] += len(rewards)
        return float(np.sum(rewards))


def best_candidate(cfg: RolloutConfig, score) -> int:
    """The candidate T with the highest score (one per cfg.candidates); a tie keeps cfg.default_T."""
    score = dict(zip(cfg.candidates, np.asarray(score, dtype=float).tolist()))
    return max(score, key=lambda T: (score[T], T == cfg.default_T))


def play_branch(env: DrivingEnv, actor, state: dict, T: int, rng: np.random.Generator, cfg: RolloutConfig,
                omega: float, deterministic: bool = True, on_step=None, first=None) -> list[float]:
    """The rewards (Eq. (31)) of a branch from a saved state, to the episode's end, in the future rng draws: T held
    for cfg.hold steps (Eqs. (11)-(12), a fresh a_t each step after the first, which is `first` if given: the action
    the decision was taken for), then cfg.default_T. on_step() after each step."""
    obs = env.restore_state(state)
    resample_future(env, rng)
    rewards, done = [], False
    while not done:
        b = float(beta(T if len(rewards) < cfg.hold else cfg.default_T, omega=omega))
        a = first if first is not None and not rewards else actor.act(obs, deterministic)
        obs, r, terminated, truncated, _ = env.step(execute(env, a, b))
        rewards.append(r)
        done = terminated or truncated
        if on_step is not None:
            on_step()
    return rewards


def driver(spec: str, trainer) -> RolloutTiming:
    """--timing rollout[=T1,T2,...] of a loaded model (experiment.timing_override): its actor, timed by the rollout."""
    return RolloutTiming(trainer.actor, trainer.seed, trainer.tc.timing, parse(spec))


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
