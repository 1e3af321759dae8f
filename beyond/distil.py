"""A timing taught by a privileged teacher (beyond the paper, docs/PAPER.md 6): can what the timing taker sees choose T?

The rollout timing (beyond/rollout_timing.py) picks T by simulating every candidate from the saved state. It sees more than
the observation: each human's route, its true braking, acceleration and crossing speed, the vehicles beyond the two
nearest per sector and those waiting to depart. Here it is a teacher, as in "learning by cheating" (Chen et al.,
CoRL 2019): at each of its decisions, Teacher records what a student could see and every candidate's return in each
future; a Student, a small network, learns each candidate's advantage over the default T = 2 from one of three input
sets; DistilledTiming drives with it, a forward pass where the teacher branched, at the teacher's decisions (its gate
and hold), so a case costs what a plain episode costs.

    Input sets (features: groups of numbers, each in about [0, 1] or [-1, 1])
      A   eq5                      Eq. (5)'s input: the observation and the actor's acceleration (what TARL's taker sees)
      B   A + deployed             what a deployed car has too: its progress along its path, the time it has waited,
                                   its last acceleration, the time since it spawned, the planner's a_base
      C   B + routes, kinematics   the privileged: the ego's and each shown human's route (one-hot), the humans' true
                                   braking, acceleration and crossing speed (Table 1's draws)

bench/distillation.py labels (on training traffic, never a test case), trains the three students and evaluates them.
"""
from __future__ import annotations

import hashlib
import io
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from torch import nn

from beyond.rollout_timing import RolloutConfig, RolloutTiming, best_candidate
from tarl import DrivingEnv, TimingConfig, scaled_action, timing_input
from world import HUMAN_RANGES, sector_slots

GROUPS = ("eq5", "deployed", "routes", "kinematics")
INPUTS = {"A": ("eq5",), "B": ("eq5", "deployed"), "C": GROUPS}  # the three students' input sets
SLOTS = 12  # Eq. (28): 6 sectors x 2 vehicles, in s_sur's order
KINEMATICS = ("decel", "accel", "speed")  # the human's p[5:8]: |b_min|, a_max [m/s^2], crossing (game) speed [m/s],
KINEMATICS_SCALE = np.array([HUMAN_RANGES[k][1] for k in KINEMATICS])  # each scaled by Table 1's upper bound


def features(env: DrivingEnv, a) -> dict[str, np.ndarray]:
    """What each input set can see at a decision, the actor's acceleration a [m/s^2] about to be timed (float32)."""
    cfg, sim = env.cfg, env.sim
    t = sim.simulation.getTime() - env.t_spawn  # [s] since the ego spawned
    deployed = [env.s / env.task["dest"], env.waited / cfg.time_limit, scaled_action(env.accel, cfg),
                t / cfg.time_limit, scaled_action(env.base_action(), cfg)]
    n_routes = len(env.routes)
    routes, kinematics = np.zeros((SLOTS + 1, n_routes)), np.zeros((SLOTS, len(KINEMATICS)))
    routes[SLOTS, env.routes.index(env.task["route"])] = 1.0  # the ego's own, last
    i, j, k, _, _ = sector_slots(env.xy, env.heading, env.others, cfg)
    for slot, h in zip(2 * i + j, (env.other_ids[n] for n in k)):
        if h in env.humans:  # as drawn at its departure
            routes[slot, env.routes.index(sim.vehicle.getRouteID(h))] = 1.0
            kinematics[slot] = env.humans[h][5:8] / KINEMATICS_SCALE
    return {"eq5": timing_input(env.obs, a, cfg), "deployed": np.float32(deployed),
            "routes": np.float32(routes.ravel()), "kinematics": np.float32(kinematics.ravel())}


def advantages(returns: np.ndarray, cfg: RolloutConfig) -> np.ndarray:
    """(N, candidates, K) returns -> (N, candidates): each candidate's mean return over the K futures minus the
    default T's, the quantity the teacher maximises."""
    mean = np.asarray(returns).mean(axis=-1)
    return mean - mean[:, [cfg.candidates.index(cfg.default_T)]]


def regret(returns: np.ndarray, chosen, cfg: RolloutConfig) -> np.ndarray:
    """Per decision, the best candidate's mean return minus the chosen T's (0 for the teacher's own choice)."""
    mean = np.asarray(returns).mean(axis=-1)
    idx = [cfg.candidates.index(int(T)) for T in np.asarray(chosen)]
    return mean.max(axis=1) - mean[np.arange(len(mean)), idx]


class Teacher(RolloutTiming):
    """The rollout timing, recording at each decision what the students may see (features) and the labels: every
    candidate's return in each future, and its choice T. self.labels: one dict per decision of the episode.
    With a student, the student's T is executed instead (DAgger, Ross et al. 2011: the teacher labels the states
    the student visits), recorded as "executed"."""

    def __init__(self, actor, seed: int = 0, timing_cfg: TimingConfig = TimingConfig(),
                 cfg: RolloutConfig = RolloutConfig(), student: "Student | None" = None):
        super().__init__(actor, seed, timing_cfg, cfg)
        self.student = student

    def new_episode(self, seed=None):
        super().new_episode(seed)
        self.labels = []

    def choose(self, env: DrivingEnv, a, deterministic: bool) -> int:
        seen = features(env, a)  # before the branches, which leave the env as it was
        T = super().choose(env, a, deterministic)
        executed = T if self.student is None else int(self.student.choose(design(seen, self.student.inputs))[0])
        step = round((env.sim.simulation.getTime() - env.t_spawn) / env.cfg.dt)
        self.labels.append(dict(seen, a=np.float32(a[0]), returns=self.returns.astype(np.float32), T=T,
                                executed=executed, step=step))
        return executed


class Student(nn.Module):
    """x (one input set's features, concatenated in GROUPS' order) -> each candidate's advantage over the default T,
    in units of the reward's 20 (Eq. (31)). Carries its own input scaling, input set, candidates and margin: the
    advantage [return] another T must be predicted to have before it is chosen over the default (most of the teacher's
    choices are the noise of K futures, and an argmax over near-zero predictions would follow it)."""

    SCALE = 20.0  # [reward] +-20 at arrival or collision: the advantages come to about [-2, 2]

    def __init__(self, inputs: str, dim: int, cfg: RolloutConfig = RolloutConfig(), hidden: int = 64):
        super().__init__()
        self.inputs, self.cfg = inputs, cfg
        self.net = nn.Sequential(nn.Linear(dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, len(cfg.candidates)))
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))
        self.register_buffer("margin", torch.zeros(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net((x - self.mean) / self.std)

    def choose(self, x: np.ndarray) -> np.ndarray:
        """The T of each row of x (N, dim): the highest predicted advantage beyond the margin, else the default."""
        with torch.no_grad():
            adv = self(torch.as_tensor(np.atleast_2d(x), dtype=torch.float32)).numpy() * self.SCALE
        other = np.array(self.cfg.candidates) != self.cfg.default_T
        adv = adv - adv[:, ~other] - float(self.margin) * other  # the default's own advantage is 0
        return np.array([best_candidate(self.cfg, row) for row in adv])

    def save(self, path):
        torch.save(dict(inputs=self.inputs, dim=self.mean.numel(), cfg=asdict(self.cfg), state=self.state_dict()),
                   path)

    @classmethod
    def load(cls, path) -> "Student":
        """A saved Student; a missing or foreign file is one line (SystemExit)."""
        if not Path(path).is_file():
            raise SystemExit(f"distilled={path}: no such student file")
        try:
            saved = torch.load(path, map_location="cpu", weights_only=True)
            cfg = RolloutConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in saved["cfg"].items()})
            student = cls(saved["inputs"], saved["dim"], cfg)
            student.load_state_dict(saved["state"])
        except Exception:
            raise SystemExit(f"distilled={path}: not a student (bench/distillation.py writes them)") from None
        return student.eval()

    def key(self) -> str:
        """A hash of its weights and settings (the evaluation's key: a kept round of another student is replayed)."""
        buf = io.BytesIO()
        torch.save(self.state_dict(), buf)
        return hashlib.sha1(buf.getvalue() + repr((self.inputs, asdict(self.cfg))).encode()).hexdigest()[:16]


def groups(inputs: str) -> tuple[str, ...]:
    """The feature groups of an input set: A, B, C, or one of them less a group ("C-routes": C without routes)."""
    base, _, drop = inputs.partition("-")
    if base not in INPUTS or (drop and drop not in INPUTS[base]):
        raise ValueError(f"an input set is one of {sorted(INPUTS)}, or one less a group of it (C-routes), not {inputs!r}")
    return tuple(g for g in INPUTS[base] if g != drop)


def design(data: dict[str, np.ndarray], inputs: str) -> np.ndarray:
    """The (N, dim) input of a student: its groups' features (one array per group, N rows each) side by side."""
    return np.concatenate([np.atleast_2d(data[g]) for g in groups(inputs)], axis=1)


def fit(x: np.ndarray, adv: np.ndarray, inputs: str, cfg: RolloutConfig, seed: int = 0, epochs: int = 200,
        batch: int = 256, lr: float = 1e-3, weight_decay: float = 1e-4) -> Student:
    """A Student fitted to the advantages adv (N, candidates) of inputs x (N, dim) by mean squared error (Adam)."""
    torch.manual_seed(seed)
    student = Student(inputs, x.shape[1], cfg)
    student.mean.copy_(torch.as_tensor(x.mean(0)))
    student.std.copy_(torch.as_tensor(np.where(x.std(0) > 1e-6, x.std(0), 1.0)))  # a constant input stays as it is
    X, Y = torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(adv / Student.SCALE, dtype=torch.float32)
    opt = torch.optim.Adam(student.parameters(), lr=lr, weight_decay=weight_decay)
    rng = np.random.default_rng(seed)
    for _ in range(epochs):
        for idx in np.array_split(rng.permutation(len(X)), max(1, len(X) // batch)):
            loss = ((student(X[idx]) - Y[idx]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    return student.eval()


class DistilledTiming(RolloutTiming):
    """The rollout timing's gate and hold, with T from a Student's forward pass instead of branches."""

    def __init__(self, actor, student: Student, seed: int = 0, timing_cfg: TimingConfig = TimingConfig()):
        super().__init__(actor, seed, timing_cfg, student.cfg)
        self.student, self.timing = student, "distilled"
        self.settings = dict(self.settings, student=student.key())

    def choose(self, env: DrivingEnv, a, deterministic: bool) -> int:
        self.counts["decisions"] += 1
        return int(self.student.choose(design(features(env, a), self.student.inputs))[0])


def parse(spec: str):
    """--timing distilled=PATH: the Student at PATH; None if spec is not a distilled timing."""
    name, eq, path = spec.partition("=")
    if name != "distilled":
        return None
    if not eq or not path:
        raise ValueError(f"{spec}: distilled=PATH, a student written by bench/distillation.py")
    return Student.load(path)

