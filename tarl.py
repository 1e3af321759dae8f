"""tarl: timing-aware reinforcement learning for autonomous driving, in SUMO: the paper's method.

Reference implementation of Li, Wu, He, "Act Better by Timing: A timing-Aware Reinforcement
Learning for Autonomous Driving", Sec. 4. In the world of world.py, the actor (SAC) picks the ego's
acceleration; the timing taker (discrete SAC) picks when it should be executed, learning in a timing
imagination; the timing factor beta(T) blends the actor's action with the base action of planner.py.
This file holds the method alone. The experiment around it (Table 3's rows, evaluation, the command
line) is experiment.py; the safe-RL rows are baselines.py.

    python tarl.py --scenario roundabout                 # train TARL, then evaluate it as Table 3 does
    python tarl.py --scenario intersection --algo lattice-idm --eval-rounds 2 --eval-cases 20

Equations are cited by the number printed in the paper's PDF (PAPER.md maps them to the LaTeX labels
and has the notes cited as "docs/PAPER.md, note n").

In the order of Sec. 4, the SAC mechanics last:

    Sec. 4, open values           TimingConfig: w of Eq. (6) and T_max, their one home
    Eqs. (6), (11) beta;  Eqs. (7), (12) blend, execute;  Eq. (5) timing_input;  Eq. (8) discounted_sum
    How each row acts             Driver, execute
    Algorithm 1                   TrainConfig, Trainer.run, Trainer.imagination_loop, Trainer.actor_loop
    Table 2                       SACConfig, SAC, ReplayBuffer
    Eqs. (9), (13) td_target, critic_loss;  Eqs. (10), (14) policy_loss
"""
from __future__ import annotations

import collections
import copy
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

# Run as `python tarl.py`: OpenMP's threads wait passively, set before torch loads OpenMP. Spinning, two
# threads beside another busy process trained at 1.6 steps/s instead of 65 (results/LOG.md, "Speed").
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn as nn  # noqa: E402
import torch.nn.functional as F  # noqa: E402

from world import OBS_DIM, DrivingEnv, EnvConfig


# ---- Sec. 4: the timing factor beta, the blend, the timing taker's input and its reward -----------


@dataclass(frozen=True)
class TimingConfig:
    """w and T_max (Sec. 4, both open): their one home. The Trainer (TrainConfig.timing), every Driver, the
    checkpoint and the evaluation workers (each Driver carries its own) read it when they act: to change w,
    pass another, e.g. TrainConfig(timing=TimingConfig(omega=4.0)) or `--omega 4`.

    beta(1) = 1 and beta(2) = 1/2 for every w; the text asks beta(3) to be intermediate and beta(T >= 4)
    near 0 (PAPER.md, note 5): with w = 6, beta(3) = 0.117, beta(4) = 0.045."""

    omega: float = 6.0  # w of Eq. (6) [-]
    t_max: int = 10  # T_max [steps]: 10 x 0.2 s = 2 s, the longest wait "for a better chance"


def beta(T, dt=1, *, omega: float):
    """Eq. (6): beta(T, dt) = 1/2 (tanh(w (dt / T - 1/2)) / tanh(w / 2) + 1), dt = 1..T; with dt = 1
    the timing factor beta(T) of Eq. (11). Vectorised over T and dt; w = omega (TimingConfig)."""
    T, dt = np.asarray(T, dtype=float), np.asarray(dt, dtype=float)
    return 0.5 * (np.tanh(omega * (dt / T - 0.5)) / np.tanh(omega / 2.0) + 1.0)


def blend(a, a_base, b):
    """Eqs. (7) and (12): a_bar = beta a + (1 - beta) a_base."""
    return b * a + (1.0 - b) * a_base


def scaled_action(a, cfg: EnvConfig):
    """An acceleration [m/s^2] mapped from [a_min, a_max] to [-1, 1] (numpy or torch)."""
    return 2.0 * (a - cfg.a_min) / (cfg.a_max - cfg.a_min) - 1.0


def timing_input(obs, a, cfg: EnvConfig):
    """Eq. (5): the timing taker sees the state and the actor's acceleration, scaled to [-1, 1]."""
    return np.append(obs, scaled_action(np.float32(a[0]), cfg)).astype(np.float32)


def discounted_sum(rewards, gamma: float) -> float:
    """Eq. (8): r_T = sum_{dt=1..T} gamma^(dt-1) r(s_t, a_bar_{t+dt})."""
    return float(np.sum(np.asarray(rewards) * gamma ** np.arange(len(rewards))))


# ---- Driving: how each row of Table 3 acts ----------------------------------------------------------


class Driver:
    """How a row of Table 3 acts: act(obs, env) -> (a, T, beta); the ego executes Eq. (12) (execute).

    timing: "taker"   TARL: T ~ the timing taker (Alg. 1 line 18), beta = beta(T) of Eq. (11)
            "phased"  tarl-consistent (beyond the paper, docs/PAPER.md): T ~ the timing taker, then a_t is phased
                      in over T steps by Eq. (7), as in the timing imagination, before T is chosen again
            "fixed"   ablation tarl-fixed-t: T = fixed_T (2) always, beta = 1/2
            "random"  ablation tarl-random-t: T uniform on 1..T_max
            "none"    SAC and the safe-RL rows: beta = 1, the actor alone
            "switch"  SAC-Lattice: the actor's second output > 0 picks a_base (beta = 0), else a (Sec. 5.3)
            "planner" Lattice-IDM: beta = 0, the base action alone (no actor)
    actor: anything with act(obs, deterministic) -> action array (SAC, or a policy of baselines.py).
    timing_cfg: w and T_max (TimingConfig). cap: the timing taker's T capped at this (an experiment's).
    """

    TIMINGS = ("taker", "phased", "fixed", "random", "none", "switch", "planner")

    def __init__(self, timing: str, actor=None, timing_taker: SAC | None = None, seed: int = 0,
                 timing_cfg: TimingConfig = TimingConfig(), fixed_T: int = 2, cap: int | None = None):
        assert timing in self.TIMINGS, timing
        self.timing, self.actor, self.timing_taker, self.rng = timing, actor, timing_taker, np.random.default_rng(seed)
        self.timing_cfg, self.fixed_T, self.cap = timing_cfg, fixed_T, cap
        self.schedule = None  # "phased": [a_t, T, dt] of the decision being executed

    def new_episode(self, seed=None):
        """An episode begins: no decision is under way; seed: the random timings' own, for a test case."""
        self.schedule = None
        if seed is not None:
            self.rng = np.random.default_rng(seed)

    def act(self, obs, env: DrivingEnv, deterministic: bool = False, a=None):
        """a: the actor's action, if already drawn (SAC's uniform warm-up)."""
        omega = self.timing_cfg.omega
        if self.timing == "planner":
            return None, None, 0.0
        if self.schedule is not None and self.schedule[2] < self.schedule[1]:  # "phased", mid-decision
            self.schedule[2] += 1
            a, T, dt = self.schedule
            return a, T, float(beta(T, dt, omega=omega))  # Eq. (7)
        a = self.actor.act(obs, deterministic) if a is None else a
        if self.timing in ("none", "switch"):
            return a, None, 0.0 if self.timing == "switch" and a[1] > 0.0 else 1.0
        if self.timing in ("taker", "phased"):
            T = self.timing_taker.act(timing_input(obs, a, env.cfg), deterministic)
            T = T if self.cap is None else min(T, self.cap)
        else:
            T = self.fixed_T if self.timing == "fixed" else int(self.rng.integers(1, self.timing_cfg.t_max + 1))
        if self.timing == "phased":
            self.schedule = [a, T, 1]
        return a, T, float(beta(T, omega=omega))  # Eq. (11); for "phased", Eq. (7) at dt = 1, the same


def execute(env: DrivingEnv, a, b: float) -> float:
    """Eq. (12): a_bar_t = beta(T_t) a_t + (1 - beta(T_t)) a_base,t; the planner runs only if beta < 1."""
    if b == 1.0:
        return float(a[0])
    return env.base_action() if b == 0.0 else blend(float(a[0]), env.base_action(), b)


# ---- Algorithm 1: the actor, the timing taker, the timing imagination -----------------------------


@dataclass(frozen=True)
class SACConfig:
    """Table 2: SAC's settings, one set for the actor and the timing taker (the SAC class, at the end)."""

    batch_size: int = 256  # B, Table 2
    buffer_size: int = 1_000_000  # N_buffer, Table 2
    learning_starts: int = 2_000  # N_start, Table 2: env steps before the first update
    hidden: int = 256  # D_hidden, Table 2; "simple MLP": two hidden layers, as in SAC (Haarnoja 2018)
    gamma: float = 0.99  # gamma, Table 2; the timing taker discounts a decision by gamma^T, Eq. (9)
    tau: float = 0.005  # tau, Table 2: Polyak weight of the target critics (PAPER.md, note 10)
    lr: float = 3e-4  # lr, Table 2: one Adam rate for policies, critics and temperatures
    init_alpha: float = 1.0  # open: the starting temperature, log alpha = 0 as in SAC
    # Open: the discrete head's target entropy as a fraction of log(n). Atari's 0.98 log n (Christodoulou
    # 2019) asks for a near-uniform pi over T; 0.3 log 10 ~ log 2 lets the timing taker commit, yet explore.
    target_entropy_fraction: float = 0.3


@dataclass(frozen=True)
class TrainConfig:
    """Algorithm 1's schedule; all open (PAPER.md)."""

    steps: int = 100_000  # simulator steps of both loops; ~17 min on a quiet 2-core machine. Table 2: 500000
    sac_fraction: float = 0.4  # Alg. 1 line 2: step 1, plain SAC, trains for this share of the steps
    n_timing: int = 20  # N_T: timing decisions per imagination loop (Alg. 1 lines 4-15)
    n_actor: int = 60  # N_a: real steps per actor loop (lines 16-24). Each loop then runs on to the end
    #                    of its episode, so that every episode, and every row of train_log.csv, is one loop's.
    timing_pretrain: float = 0.05  # share of the steps for step 2 alone after step 1, before anything is
    #                                blended (5,000 steps, ~1,200 decisions, at the default budget)
    timing_learning_starts: int = 500  # decisions in D_T before the timing taker learns
    log_every: int = 2000  # [steps] between progress lines
    checkpoint_every: int = 20_000  # [steps] between checkpoints: an interruption loses little
    timing: TimingConfig = TimingConfig()  # w and T_max
    # What a decision of the timing imagination executes: "phased", Eq. (7) (the paper's); "held", beyond the
    # paper (PAPER.md, 6): beta(T) of Eq. (11) for T steps with a fresh a_t each step, as the real loop does
    imagination: str = "phased"
    timing_updates: int = 1  # updates of the timing taker per decision: 1 in Alg. 1 (lines 13-14); more, beyond the
    #                          paper (PAPER.md, 6): 8 gives it about as many updates as the actor gets


LOG_HEADER = ["step", "loop", "episode_return", "success", "collision", "timeout", "crossing_time", "mean_beta"]


class TrainLog:
    """train_log.csv, one row per episode, and the progress line with its ETA. loop: "step1" (Alg. 1
    step 1), "real" (the real environment) or "imagination" (where beta is beta(T, dt) of Eq. (7));
    the progress line and the training curves show the real environment's episodes (step1, real)."""

    def __init__(self, out: Path | None, total: int, log=print):
        self.out, self.total, self.print, self.rows = out, total, log, []
        self.recent = collections.deque(maxlen=20)  # the last real episodes
        self.clock = collections.deque(maxlen=2)  # (time, step) of the last two calls: the rate of the last log_every steps

    def episode(self, step: int, loop: str, ret: float, info: dict, betas: list):
        row = [step, loop, round(ret, 3), int(info["arrival"]), int(info["collision"]), int(info["timeout"]),
               round(info["crossing_time"], 2) if info["arrival"] else "", round(float(np.mean(betas)), 4) if betas else ""]
        self.rows.append(row)
        if loop != "imagination":
            self.recent.append(row)

    def progress(self, step: int, phase: str, extra: str = "", warm_up: bool = False):
        """A progress line, its rate over the last log_every steps. warm_up: those steps made no update (SAC's
        uniform actions, several times faster), so their rate would promise too soon an end: no ETA yet."""
        self.clock.append((time.time(), step))
        if len(self.clock) < 2:  # the first call starts the clock
            return
        rate = (step - self.clock[0][1]) / max(self.clock[-1][0] - self.clock[0][0], 1e-9)
        eta = "after the warm-up" if warm_up else f"{max(0, self.total - step) / max(rate, 1e-9) / 60:5.1f} min"
        succ, coll, ret = (np.mean([r[k] for r in self.recent]) if self.recent else np.nan for k in (3, 4, 2))
        self.print(f"step {step:>7}/{self.total} [{phase}] {rate:5.0f} steps/s, training ETA {eta} | last "
                   f"{len(self.recent)} real episodes: success {succ:.2f}, collision {coll:.2f}, return {ret:6.1f}{extra}")

    def flush(self):
        if self.out is not None:
            new = not (self.out / "train_log.csv").exists()
            with open(self.out / "train_log.csv", "a") as f:
                f.writelines([",".join(LOG_HEADER) + "\n"] * new + [",".join(map(str, r)) + "\n" for r in self.rows])
            self.rows = []


def save_checkpoint(path: Path, state: dict):
    """torch.save through a temporary file: never a half-written checkpoint."""
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, path.with_suffix(".tmp"))
    os.replace(path.with_suffix(".tmp"), path)


class Trainer:
    """Algorithm 1 for TARL and its ablations; SAC and SAC-Lattice are its actor loop alone.

    The imagination and the real environment share one SUMO world: libsumo runs one simulation per
    process, and Algorithm 1 runs its loops one after the other anyway, each storing only its own
    transitions (D_T, D_a). What they share is the stream of traffic situations.
    """

    def __init__(self, env: DrivingEnv, algo: str, tc: TrainConfig = TrainConfig(), sac_cfg: SACConfig = SACConfig(),
                 seed: int = 0, out: Path | None = None, log=print, timing: str = "taker", step_one: bool = True):
        """algo: the row's name (checkpoints, progress lines); timing: its Driver's; step_one: Alg. 1's step 1 first
        (experiment.ROWS gives both for each row of Table 3)."""
        self.env, self.algo, self.tc, self.sac_cfg, self.seed, self.out = env, algo, tc, sac_cfg, seed, out
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        cfg = env.cfg
        # the actor's bounds are the ego's limits; SAC-Lattice's actor adds its switch in [-1, 1]
        low, high = [cfg.a_min] + [-1.0] * (timing == "switch"), [cfg.a_max] + [1.0] * (timing == "switch")
        self.actor = SAC(OBS_DIM, act_dim=len(low), low=low, high=high, cfg=sac_cfg)
        self.D_a = ReplayBuffer(sac_cfg.buffer_size, OBS_DIM, (len(low),))
        self.timing_taker = self.D_T = None
        if timing in ("taker", "phased"):
            self.timing_taker = SAC(OBS_DIM + 1, n_actions=tc.timing.t_max, cfg=sac_cfg)
            self.D_T = ReplayBuffer(sac_cfg.buffer_size, OBS_DIM + 1, (), np.int64)
        self.driver = Driver(timing, self.actor, self.timing_taker, seed, tc.timing)
        self.plain = Driver("none", self.actor)
        self.step_one = round(tc.sac_fraction * tc.steps) if step_one else 0
        self.sac_actor: SAC | None = None  # the step-1 model, kept when step 1 ends
        self.after_step_one = None  # called once step 1 has ended (experiment.py evaluates the step-1 model then)
        self.step, self.updates, self.episode = 0, {"actor": 0, "timing": 0}, dict(ret=0.0, betas=[])
        self.log = TrainLog(out, tc.steps, log)

    def run(self):
        """Algorithm 1; the steps of both loops count towards TrainConfig.steps."""
        self.obs, _ = self.env.reset(seed=self.seed + self.step)  # resumed: SUMO's state is not saved
        self.log.print(f"a line every {self.tc.log_every:,} steps, by phase: [Alg. 1 step 1, SAC] plain SAC first, "
                       f"[timing imagination] the timing taker learns (lines 4-15), [{self.algo}] the actor in the real"
                       " loop (lines 16-24); the ETA is training's, the evaluation comes after it")
        self.log.progress(self.step, "")
        try:
            # Alg. 1 line 2, step 1: a regular SAC model as the actor
            if self.step < self.step_one:
                while self.step < self.step_one:
                    self.actor_loop(self.plain, "step1")
                self.step_one, self.sac_actor = self.step, copy.deepcopy(self.actor)
                self.save("sac.pt")
                if self.after_step_one is not None:
                    self.after_step_one()
            # step 2 alone first: the timing taker learns on the step-1 actor before anything is blended
            while self.timing_taker is not None and self.step < self.step_one + self.tc.timing_pretrain * self.tc.steps:
                self.imagination_loop()
            # Alg. 1 lines 3-25: step 2 (the timing imagination) and step 3 (the actor) alternate
            while self.step < self.tc.steps:
                if self.timing_taker is not None:
                    self.imagination_loop()  # lines 4-15
                self.actor_loop(self.driver, "real")  # lines 16-24
        except KeyboardInterrupt:
            self.log.print(f"\ninterrupted at step {self.step}: saving")
            self.save()
            raise
        self.save()

    def actor_loop(self, driver: Driver, loop: str):
        """Alg. 1 lines 16-24 (line 2 with the plain actor): N_a real steps, then to the episode's end."""
        n, done, c = 0, False, self.sac_cfg
        while n < self.tc.n_actor or not done:
            s, a = self.obs, None
            if len(self.D_a) < c.learning_starts:  # SAC's warm-up: uniform actions before the first update
                a = self.rng.uniform(self.actor.action_bias - self.actor.action_scale,
                                     self.actor.action_bias + self.actor.action_scale).astype(np.float32)
            a, T, b = driver.act(s, self.env, a=a)  # lines 17-18: a_t ~ pi_a, T_t ~ pi_T
            s2, r, terminated, truncated, info = self.env.step(execute(self.env, a, b))  # lines 19-20, Eq. (12)
            # line 21: D_a <- D_a u {(s_t, a_t, r(s_t, a_bar_t), s_t+1, delta)}: a_t, not a_bar_t
            self.D_a.add(s, a, r, s2, c.gamma, terminated, **self.columns(info))
            self.learn(self.actor, self.D_a.sample, len(self.D_a) >= c.learning_starts, "actor")  # lines 22-23
            done = terminated or truncated
            if done:
                self.obs = self.env.reset()[0]
                driver.new_episode()
            else:
                self.obs = s2
            self.after_step(r, None if driver.timing == "none" else b, info, done, loop)
            n += 1

    def imagination_loop(self):
        """Alg. 1 lines 4-15: N_T decisions of the timing taker, then to the episode's end. A decision
        plays a_t over T steps by Eq. (7), the base action recomputed at each step (TrainConfig.imagination
        "held", beyond the paper: the real loop's beta(T) of Eq. (11) for T steps, a fresh a each step)."""
        n, done, gamma = 0, False, self.sac_cfg.gamma
        while n < self.tc.n_timing or not done:
            s = self.obs
            a = self.actor.act(s)  # line 5
            x = timing_input(s, a, self.env.cfg)
            T = self.timing_taker.act(x)  # line 6
            rewards = []
            a_dt, held = a, self.tc.imagination == "held"
            for dt in range(1, T + 1):  # lines 7-10
                b = float(beta(T, 1 if held else dt, omega=self.tc.timing.omega))
                a_dt = self.actor.act(self.obs) if held and dt > 1 else a_dt
                # Eq. (7): a_bar_{t+dt} = beta(T, dt) a_t + (1 - beta(T, dt)) a_base,t+dt ("held": beta(T) a_t+dt + ...)
                s2, r, terminated, truncated, info = self.env.step(blend(float(a_dt[0]), self.env.base_action(), b))
                rewards.append(r)
                done = terminated or truncated
                self.obs = self.env.reset()[0] if done else s2
                self.after_step(r, b, info, done, "imagination")
                if done:
                    break
            # line 11, Eq. (8): r_T; a decision cut after k < T steps by the time limit bootstraps with gamma^k.
            # line 12: D_T <- D_T u {((s_t, a_t), T_t, r_T, s_t+T, delta)}; the action beside s_t+T is
            # drawn afresh from the actor whenever the transition is used (timing_batch, docs/PAPER.md, note 8).
            self.D_T.add(x, T, discounted_sum(rewards, gamma), np.append(s2, np.float32(0.0)), gamma ** len(rewards),
                         terminated)
            for _ in range(self.tc.timing_updates):  # lines 13-14
                self.learn(self.timing_taker, self.timing_batch, len(self.D_T) >= self.tc.timing_learning_starts,
                           "timing")
            n += 1

    def columns(self, info: dict) -> dict:
        """Further columns of D_a, none here (a constrained baseline stores info["cost"])."""
        return {}

    def timing_batch(self, batch_size: int, rng, idx=None) -> dict[str, torch.Tensor]:
        """A batch of D_T (uniform, or its rows idx) whose a_{t+T} in Eq. (9)'s target comes from the actor of
        now, not of then."""
        batch = self.D_T.sample(batch_size, rng, idx)
        with torch.no_grad():
            a_next = self.actor.squashed_gaussian(batch["next_obs"][:, :OBS_DIM])[0]
        batch["next_obs"][:, OBS_DIM] = scaled_action(a_next[:, 0], self.env.cfg)  # Eq. (5)
        return batch

    def learn(self, agent: SAC, sample, ready: bool, key: str):
        if ready:
            agent.update(sample(self.sac_cfg.batch_size, self.rng))
            self.updates[key] += 1

    def after_step(self, r: float, b: float | None, info: dict, done: bool, loop: str):
        """The bookkeeping of one simulator step: the episode's log row, progress lines, checkpoints."""
        self.step += 1
        self.episode["ret"] += r
        self.episode["betas"] += [] if b is None else [b]
        if done:
            self.log.episode(self.step, loop, self.episode["ret"], info, self.episode["betas"])
            self.episode = dict(ret=0.0, betas=[])
        if self.step % self.tc.log_every == 0:
            phase = {"step1": "Alg. 1 step 1, SAC", "real": self.algo, "imagination": "timing imagination"}[loop]
            self.log.progress(self.step, phase, f" | updates actor {self.updates['actor']}, timing {self.updates['timing']}",
                              warm_up=self.step <= self.sac_cfg.learning_starts)
        if self.step % self.tc.checkpoint_every == 0:
            self.save()

    def save(self, name: str = "ckpt.pt"):
        """ckpt.pt: everything to resume; policy.pt and sac.pt: the policy networks alone, to act (--load).
        Plain tensors and dicts: loadable with torch.load(weights_only=True)."""
        if self.out is None:
            return
        state = {"config": {"scenario": self.env.cfg.scenario, "algo": self.algo, "seed": self.seed, "env":
                            asdict(self.env.cfg), "train": asdict(self.tc), "sac": asdict(self.sac_cfg)},
                 "step": self.step, "step_one": self.step_one}
        nets = {k: v for k, v in (("actor", self.actor), ("timing_taker", self.timing_taker),
                                  ("sac_actor", self.sac_actor)) if v is not None}
        policies = {k: {"policy": v.policy.state_dict()} for k, v in nets.items()}
        if name == "sac.pt":
            return save_checkpoint(self.out / name, {**state, "actor": policies["actor"]})
        save_checkpoint(self.out / "policy.pt", {**state, **policies})
        state.update({k: v.state_dict() for k, v in nets.items()}, actor_buffer=self.D_a.state_dict(),
                     updates=dict(self.updates), rng=self.rng.bit_generator.state, torch_rng=torch.get_rng_state())
        if self.D_T is not None:
            state["timing_buffer"] = self.D_T.state_dict()
        save_checkpoint(self.out / name, state)
        self.log.flush()

    def load(self, state: dict, resume: bool):
        self.actor.load_state_dict(state["actor"])
        if self.timing_taker is not None:
            self.timing_taker.load_state_dict(state["timing_taker"])
        if "sac_actor" in state:
            self.sac_actor = copy.deepcopy(self.actor)
            self.sac_actor.load_state_dict(state["sac_actor"])
        self.step_one, self.step = state["step_one"], state["step"]
        if resume:
            self.updates = state["updates"]
            self.D_a.load_state_dict(state["actor_buffer"])
            if self.D_T is not None:
                self.D_T.load_state_dict(state["timing_buffer"])
            self.rng.bit_generator.state = state["rng"]
            torch.set_rng_state(state["torch_rng"])


# ---- Soft Actor-Critic: one implementation for the actor (continuous) and the timing taker (discrete) ---
# The mechanics of Eqs. (9), (10), (13), (14), tuned for speed; bench/plain_sac.py is the textbook version.


LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # clamp of the Gaussian's log std; Haarnoja et al. (2018)'s values


def mlp(in_dim: int, out_dim: int, hidden: int) -> nn.Sequential:
    """Table 2: two hidden layers of D_hidden units with ReLU."""
    return nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                         nn.Linear(hidden, out_dim))


class TwinCritic(nn.Module):
    """Q1 and Q2 as one batched MLP: (obs (B, obs_dim), act (B, act_dim) or None) -> (2, B, out_dim).

    out_dim is 1 for Q(s, a), n for Q(s, .) of a discrete head. Layer k holds both critics' weights
    stacked, (2, in, out), applied by one torch.baddbmm; the first layer's are two blocks, for obs and act
    (the same as feeding cat(obs, act), without the copy). frozen=True uses detached weights: gradients
    reach act, never the critic (the policy loss).
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
    """SAC agent: continuous if act_dim is given (the actor), discrete if n_actions is (the timing taker).

    The timing taker's input is cat(s, a) (Eq. (5)); its choices are the timings T = 1..n: act returns
    T, the buffer stores T, and column T - 1 of Q(s, .) and pi(.|s) belongs to T. A constrained variant
    (baselines.py) extends `losses`, and adds its networks to `optimizer` and online/target_params.

    Tuned for speed: both critics stacked in one TwinCritic, one fused Adam and one backward pass over the
    summed losses, the squashed Gaussian's log-probability in closed form, the soft update by torch's
    private _foreach_lerp_. The textbook version (two critic modules, an Adam per part, the critic step
    first) is PlainSAC in bench/plain_sac.py; tests/test_sac.py holds the two equal:
        test_updates_equal_the_plain_reference_updates                         five updates, every weight
        test_{continuous,discrete}_losses_equal_a_straightforward_computation  the losses alone
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
            self.action_scale, self.action_bias = torch.as_tensor((high - low) / 2), torch.as_tensor((high + low) / 2)
            self.log_prob_offset = -0.5 * math.log(2 * math.pi) - 2 * math.log(2.0) - self.action_scale.log()
            self.policy = mlp(obs_dim, 2 * act_dim, cfg.hidden)  # mean and log std of pi(a|s), Eq. (14)
            self.critic = TwinCritic(obs_dim, act_dim, 1, cfg.hidden)  # Q(s, a), Eq. (13)
            self.target_entropy = -float(act_dim)  # SAC's heuristic -dim(A) (Haarnoja 2018b)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)  # Q-hat: never trained
        self.log_alpha = torch.tensor(math.log(cfg.init_alpha), requires_grad=True)
        # Adam is per parameter: one optimizer over all of them equals one per network, in one kernel
        params = [*self.policy.parameters(), *self.critic.parameters(), self.log_alpha]
        self.optimizer = torch.optim.Adam(params, lr=cfg.lr, fused=True)
        self.online_params, self.target_params = list(self.critic.parameters()), list(self.critic_target.parameters())

    def squashed_gaussian(self, obs: torch.Tensor, deterministic: bool = False):
        """obs (B, obs_dim) -> a (B, act_dim) in [low, high], log pi(a|s) (B,): a = bias + scale tanh(u),
        u = mu + sigma eps (reparameterised), eps = 0 when deterministic."""
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
        """obs (B, obs_dim) -> pi(T|s) (B, n), log pi(T|s) (B, n), column T - 1 for T."""
        log_probs = F.log_softmax(self.policy(obs), dim=-1)
        return log_probs.exp(), log_probs

    @torch.inference_mode()
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray | int:
        """obs (obs_dim,) or (B, obs_dim) -> action (act_dim,) / (B, act_dim), or timing T (int / (B,) ints)."""
        x = torch.as_tensor(obs, dtype=torch.float32)
        x = x.unsqueeze(0) if obs.ndim == 1 else x
        if self.discrete:
            probs, _ = self.timing_distribution(x)
            T = (probs.argmax(-1) if deterministic else torch.multinomial(probs, 1).squeeze(-1)).numpy() + 1
            return int(T[0]) if obs.ndim == 1 else T
        a = self.squashed_gaussian(x, deterministic)[0].numpy()
        return a[0] if obs.ndim == 1 else a

    def losses(self, batch: dict[str, torch.Tensor], penalty=None) -> dict[str, torch.Tensor]:
        """The critics', the policy's and the temperature's losses on a batch (see ReplayBuffer), all at
        the parameters before the step, as in Haarnoja et al.'s code. Their parameter sets are disjoint
        (frozen critics in the policy loss, no gradient in the target), so one backward of their sum
        gives each network its own gradient. penalty: see policy_loss."""
        loss_q, q = critic_loss(self, batch)
        # the discrete policy loss needs Q(s, .) at these parameters: reuse the critic's forward pass
        loss_pi, entropy = policy_loss(self, batch["obs"], q.detach() if self.discrete else None, penalty)
        return {"critic_loss": loss_q, "policy_loss": loss_pi,
                "temperature_loss": temperature_loss(self.log_alpha, entropy, self.target_entropy)}

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """One gradient step on the sum of `losses`: Alg. 1 lines 13-14 (timing taker), 22-23 (actor)."""
        losses = self.losses(batch)
        self.optimizer.zero_grad(set_to_none=True)
        sum(losses.values()).backward()
        self.optimizer.step()
        with torch.no_grad():  # Table 2: Q-hat <- (1 - tau) Q-hat + tau Q
            torch._foreach_lerp_(self.target_params, self.online_params, self.cfg.tau)
        return {k: v.detach() for k, v in losses.items()}  # 0-d tensors: float() each only to read it

    def state_dict(self) -> dict:
        """Plain tensors and dicts only: loadable with torch.load(weights_only=True)."""
        return {"policy": self.policy.state_dict(), "critic": self.critic.state_dict(),
                "critic_target": self.critic_target.state_dict(), "log_alpha": self.log_alpha.detach().clone(),
                "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        """A full state_dict, or {"policy": ...} alone (policy.pt) to act."""
        self.policy.load_state_dict(state["policy"])
        if "critic" in state:
            self.critic.load_state_dict(state["critic"])
            self.critic_target.load_state_dict(state["critic_target"])
            with torch.no_grad():
                self.log_alpha.copy_(state["log_alpha"])
            self.optimizer.load_state_dict(state["optimizer"])


@torch.no_grad()
def td_target(agent: SAC, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Target y (B,) of both critics: Eq. (9) (timing taker) and Eq. (13) (actor), y = r + discount
    (1 - done) V(s'), discount = gamma^T (gamma for the actor). docs/PAPER.md, note 2: (13) is printed with
    max_{a'} Q-hat; SAC's target is the soft value V(s') = E_{a'~pi}[min Q'(s', a') - alpha log pi(a'|s')]."""
    alpha, next_obs = agent.log_alpha.exp(), batch["next_obs"]
    if agent.discrete:  # the expectation over T' exactly
        probs, log_probs = agent.timing_distribution(next_obs)
        v_next = (probs * (agent.critic_target(next_obs).amin(0) - alpha * log_probs)).sum(-1)
    else:  # one sample a' ~ pi(.|s')
        a_next, log_prob = agent.squashed_gaussian(next_obs)
        v_next = agent.critic_target(next_obs, a_next).amin(0).squeeze(-1) - alpha * log_prob
    # Eq. (9): y = r_T + gamma^T (1 - delta) V(s_{t+T});  Eq. (13): the same with T = 1
    return batch["rew"] + batch["discount"] * (1 - batch["done"]) * v_next


def critic_loss(agent: SAC, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Eqs. (9) and (13), minimised (PAPER.md, note 2): sum_i mean_B (Q_i(s, a) - y)^2. batch: obs (B, obs_dim),
    act (B, act_dim) or (B,) int T in 1..n, rew, discount, done (B,), next_obs (B, obs_dim). Returns the loss
    and the critics at obs: Q(s, a) (2, B), or Q(s, .) (2, B, n) if discrete (the policy loss reuses them)."""
    y = td_target(agent, batch)
    if agent.discrete:
        q = agent.critic(batch["obs"])
        q_taken = q.gather(-1, (batch["act"] - 1).view(1, -1, 1).expand(2, -1, 1)).squeeze(-1)
    else:
        q = q_taken = agent.critic(batch["obs"], batch["act"]).squeeze(-1)
    return (q_taken - y).square().mean(-1).sum(), q


def policy_loss(agent: SAC, obs: torch.Tensor, q_obs: torch.Tensor | None = None, penalty=None):
    """-J(phi) of Eq. (14) (actor) and Eq. (10) (timing taker), minimised, with frozen critics:
    continuous: E_s[alpha log pi(a|s) - min Q(s, a) + penalty(s, a)], a ~ pi(.|s) reparameterised;
    discrete:   E_s[sum_T pi(T|s) (alpha log pi(T|s) - min Q(s, T))], q_obs: Q(s, .) if already computed.
    penalty: None, or (obs, a) -> (B,), a Lagrangian's cost term. Returns the loss and the entropy per
    sample (B,), detached: -log pi(a|s) of the sampled a, or the exact entropy if discrete."""
    alpha = agent.log_alpha.detach().exp()
    if agent.discrete:
        probs, log_probs = agent.timing_distribution(obs)
        if q_obs is None:
            with torch.no_grad():
                q_obs = agent.critic(obs)
        # Eq. (10): max E[Q(s, a, T) + alpha H(pi(.|s, a))], the expectation over T exact
        return (probs * (alpha * log_probs - q_obs.amin(0))).sum(-1).mean(), -(probs * log_probs).sum(-1).detach()
    a, log_prob = agent.squashed_gaussian(obs)
    # Eq. (14): max E[Q(s, a) + alpha H(pi(.|s))], H estimated by -log pi(a|s)
    loss = alpha * log_prob - agent.critic(obs, a, frozen=True).amin(0).squeeze(-1)
    return (loss if penalty is None else loss + penalty(obs, a)).mean(), -log_prob.detach()


def temperature_loss(log_alpha: torch.Tensor, entropy: torch.Tensor, target_entropy: float) -> torch.Tensor:
    """Automatic temperature (Haarnoja 2018b): J(alpha) = E[alpha (H - H_bar)] on log alpha; alpha falls
    when the policy's entropy (B,) exceeds the target H_bar, rises otherwise."""
    return (log_alpha * (entropy - target_entropy)).mean()


class ReplayBuffer:
    """Transitions (s, a, r, s', discount, delta) of D_T (Alg. 1 line 12) and D_a (line 21), preallocated.

    act_shape (act_dim,) float32 for the actor, () int64 for the timing taker's T. discount = gamma^k;
    done = delta, 1 only at a true terminal (arrival or collision), not at the time limit. extra: names of
    further float columns (a constrained baseline's "cost"), given to add() by keyword. The oldest
    transitions are overwritten when full.
    """

    def __init__(self, capacity: int, obs_dim: int, act_shape: tuple = (1,), act_dtype=np.float32, extra=()):
        self.capacity, self.ptr, self.size = capacity, 0, 0
        self.data = {"obs": np.zeros((capacity, obs_dim), np.float32), "act": np.zeros((capacity, *act_shape), act_dtype),
                     **{k: np.zeros(capacity, np.float32) for k in ("rew", "discount", "done", *extra)},
                     "next_obs": np.zeros((capacity, obs_dim), np.float32)}

    def __len__(self) -> int:
        return self.size

    def add(self, obs, act, rew: float, next_obs, discount: float, done: bool, **extra) -> None:
        row = dict(obs=obs, act=act, rew=rew, next_obs=next_obs, discount=discount, done=done, **extra)
        for key, array in self.data.items():
            array[self.ptr] = row[key]
        self.ptr, self.size = (self.ptr + 1) % self.capacity, min(self.size + 1, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator, idx=None) -> dict[str, torch.Tensor]:
        """A uniform batch, or the rows idx if given."""
        idx = rng.integers(0, self.size, batch_size) if idx is None else idx
        return {key: torch.from_numpy(array[idx]) for key, array in self.data.items()}

    def state_dict(self) -> dict:
        """The filled part only, as tensors (torch.save / torch.load(weights_only=True))."""
        return {"ptr": self.ptr, **{key: torch.from_numpy(a[: self.size].copy()) for key, a in self.data.items()}}

    def load_state_dict(self, state: dict) -> None:
        self.size, self.ptr = len(state["obs"]), state["ptr"]
        for key, array in self.data.items():
            array[: self.size] = state[key].numpy()


if __name__ == "__main__":
    import experiment  # the command line: train a row of Table 3, then evaluate it
    experiment.main()
