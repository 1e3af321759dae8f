"""A timing taught by a privileged teacher (beyond the paper, docs/PAPER.md 6): can what the timing taker sees choose T?

The rollout timing (beyond/rollout_timing.py) picks T by simulating every candidate from the saved state. It sees more than
the observation: each human's route, its true braking, acceleration and crossing speed, the vehicles beyond the two
nearest per sector and those waiting to depart. Here it is a teacher, as in "learning by cheating" (Chen et al.,
CoRL 2019): at each of its decisions, Teacher records what a student could see and every candidate's return in each
future; a Student, a small network, learns from one of three input sets which T to choose, from each candidate's
advantage over the default T = 2 (one of two losses); DistilledTiming drives with it, a forward pass where the
teacher branched, at the teacher's decisions (its gate and hold), so a case costs what a plain episode costs.

    Losses (Student.loss)
      decision   a score per candidate, trained for the choice it makes (fit_decision): the expected advantage over
                 T = 2 of the candidate a softmax over the scores picks, stopped early on validation chunks; the
                 default is a candidate at advantage 0, so staying is learnt like any other choice
      mse        each candidate's advantage, by mean squared error on every decision, and a margin (fit): the
                 committed students of results/distil/SCENARIO-sSEED and -dagger

The labels are measured before any student learns from them (reliability, replicated_gain), and a student is put on
test cases only through the gate: a held-out regret below "T = 2 always", a case-bootstrap interval excluding 0.

    Input sets (features: groups of numbers, each in about [0, 1] or [-1, 1])
      A   eq5                      Eq. (5)'s input: the observation and the actor's acceleration (what TARL's taker sees)
      B   A + deployed             what a deployed car has too: its progress along its path, the time it has waited,
                                   its last acceleration, the time since it spawned, the planner's a_base
      C   B + routes, kinematics   the privileged: the ego's and each shown human's route (one-hot), the humans' true
                                   braking, acceleration and crossing speed (Table 1's draws)

bench/distillation.py labels (on training traffic, never a test case), trains the three students and evaluates them.
"""
from __future__ import annotations

import copy
import hashlib
import io
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from torch import nn

from beyond.rollout_timing import RolloutConfig, RolloutTiming, best_candidate
from tarl import TimingConfig, scaled_action, timing_input
from world import HUMAN_RANGES, DrivingEnv, sector_slots

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


def case_bootstrap(values: np.ndarray, cases: np.ndarray, resamples: int = 2000, seed: int = 0) -> dict:
    """The mean of values (one per decision) and its 95 % percentile interval, whole cases resampled (a case's
    decisions share its traffic); cases: one id per decision."""
    ids, inverse = np.unique(cases, return_inverse=True)
    sums, counts = np.bincount(inverse, weights=values), np.bincount(inverse).astype(float)
    pick = np.random.default_rng(seed).integers(0, len(ids), (resamples, len(ids)))
    means = sums[pick].sum(1) / counts[pick].sum(1)
    low, high = np.percentile(means, [2.5, 97.5])
    return dict(mean=float(np.mean(values)), low=float(low), high=float(high), cases=len(ids))


def gate(returns: np.ndarray, chosen, cases: np.ndarray, cfg: RolloutConfig, **bootstrap) -> dict:
    """Whether a student may be put on test cases: its held-out regret (regret, mean per decision) below the default
    T's always, the case-bootstrap 95 % interval of the difference excluding 0. Both regrets are measured in the
    held-out futures, which the student never saw, so the difference is minus the mean advantage of its choices."""
    mine, default = regret(returns, chosen, cfg), regret(returns, np.full(len(returns), cfg.default_T), cfg)
    diff = case_bootstrap(mine - default, cases, **bootstrap)
    return dict(regret=float(mine.mean()), default_regret=float(default.mean()), diff=diff["mean"], low=diff["low"],
                high=diff["high"], cases=diff["cases"], decisions=len(mine), passes=bool(diff["high"] < 0))


def reliability(returns: np.ndarray, cfg: RolloutConfig) -> dict[int, float]:
    """Per candidate T but the default: 1 - noise variance / total variance of its label, the mean over the K futures
    of its advantage over the default (futures shared: common random numbers). Noise variance: s^2 / K of the K
    per-future advantages, averaged over decisions; total: the variance of the labels across decisions."""
    r = np.asarray(returns, dtype=float)
    per_future = r - r[:, [cfg.candidates.index(cfg.default_T)]]
    found = {}
    for c, T in enumerate(cfg.candidates):
        if T != cfg.default_T:
            noise = (per_future[:, c].var(axis=1, ddof=1) / r.shape[-1]).mean()
            total = per_future[:, c].mean(axis=1).var(ddof=1)
            found[T] = float(1 - noise / total) if total > 0 else float("nan")  # nan: the same label everywhere
    return found


def replicated_gain(returns: np.ndarray, cfg: RolloutConfig) -> tuple[np.ndarray, np.ndarray]:
    """The teacher's choice tested on a future it did not see: for each way j of holding out one of the K futures, the
    candidate the other futures choose (best_candidate), scored in future j as its return minus the default T's.
    (N, K) each: that gain, and the chosen candidate's advantage in the futures it was chosen from (what the teacher
    expected of it; 0 where it keeps the default)."""
    r = np.asarray(returns, dtype=float)
    d, n, K = cfg.candidates.index(cfg.default_T), np.arange(len(r)), r.shape[-1]
    if K < 2:
        raise ValueError("a replicated gain needs K >= 2 futures per candidate")
    gain, expected = np.zeros((len(r), K)), np.zeros((len(r), K))
    for j in range(K):
        rest = np.delete(r, j, axis=-1).mean(axis=-1)
        top = rest.max(axis=1)
        chosen = np.where(rest[:, d] == top, d, rest.argmax(axis=1))  # best_candidate's: a tie keeps the default
        gain[:, j] = r[n, chosen, j] - r[:, d, j]
        expected[:, j] = top - rest[:, d]
    return gain, expected


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
    """x (one input set's features, concatenated in GROUPS' order) -> a score per candidate; it chooses the highest.
    loss "decision" (fit_decision): the scores are logits, trained so that their softmax picks candidates of high
    advantage. loss "mse" (fit): each candidate's advantage over the default T, in units of the reward's 20 (Eq.
    (31)), and a margin: the advantage [return] another T must be predicted to have before it is chosen over the
    default (picked on validation chunks, bench/distillation.py). Carries its own input scaling, input set,
    candidates, loss and margin (0 for "decision")."""

    SCALE = 20.0  # [reward] +-20 at arrival or collision: the advantages come to about [-2, 2]
    LOSSES = ("decision", "mse")

    def __init__(self, inputs: str, dim: int, cfg: RolloutConfig = RolloutConfig(), hidden: int = 64,
                 loss: str = "mse"):
        super().__init__()
        if loss not in self.LOSSES:
            raise ValueError(f"a student's loss is one of {self.LOSSES}, not {loss!r}")
        self.inputs, self.cfg, self.loss = inputs, cfg, loss
        self.net = nn.Sequential(nn.Linear(dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, len(cfg.candidates)))
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("std", torch.ones(dim))
        self.register_buffer("margin", torch.zeros(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net((x - self.mean) / self.std)

    @property
    def name(self) -> str:
        """Its input set, after its loss unless "mse" (decision-B): the name of the labels it drives to in DAgger."""
        return tagged(self.inputs, self.loss)

    def choose(self, x: np.ndarray) -> np.ndarray:
        """The T of each row of x (N, dim): the highest score beyond the margin, else (and on a tie) the default."""
        with torch.no_grad():
            adv = self(torch.as_tensor(np.atleast_2d(x), dtype=torch.float32)).numpy() * self.SCALE
        other = np.array(self.cfg.candidates) != self.cfg.default_T
        adv = adv - adv[:, ~other] - float(self.margin) * other  # the default's own advantage is 0
        return np.array([best_candidate(self.cfg, row) for row in adv])

    def save(self, path):
        torch.save(dict(inputs=self.inputs, dim=self.mean.numel(), cfg=asdict(self.cfg), state=self.state_dict(),
                        loss=self.loss), path)

    @classmethod
    def load(cls, path) -> "Student":
        """A saved Student; a missing or foreign file is one line (SystemExit)."""
        if not Path(path).is_file():
            raise SystemExit(f"distilled={path}: no such student file")
        try:
            saved = torch.load(path, map_location="cpu", weights_only=True)
            cfg = RolloutConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in saved["cfg"].items()})
            student = cls(saved["inputs"], saved["dim"], cfg, loss=saved.get("loss", "mse"))  # the first had none
            student.load_state_dict(saved["state"])
        except Exception:
            raise SystemExit(f"distilled={path}: not a student (bench/distillation.py writes them)") from None
        return student.eval()

    def key(self) -> str:
        """A hash of its weights and settings (the evaluation's key: a kept round of another student is replayed)."""
        buf = io.BytesIO()
        torch.save(self.state_dict(), buf)
        settings = (self.inputs, asdict(self.cfg)) + ((self.loss,) if self.loss != "mse" else ())  # mse's keys stay
        return hashlib.sha1(buf.getvalue() + repr(settings).encode()).hexdigest()[:16]


def tagged(inputs: str, loss: str) -> str:
    """An input set named with its loss (B, decision-B): "mse", the first loss, goes unnamed."""
    return inputs if loss == "mse" else f"{loss}-{inputs}"


def groups(inputs: str) -> tuple[str, ...]:
    """The feature groups of an input set: A, B, C, or one of them less a group ("C-routes": C without routes)."""
    base, _, drop = inputs.partition("-")
    if base not in INPUTS or (drop and drop not in INPUTS[base]):
        raise ValueError(f"an input set is one of {sorted(INPUTS)}, or one less a group of it (C-routes), not {inputs!r}")
    return tuple(g for g in INPUTS[base] if g != drop)


def design(data: dict[str, np.ndarray], inputs: str) -> np.ndarray:
    """The (N, dim) input of a student: its groups' features (one array per group, N rows each) side by side."""
    return np.concatenate([np.atleast_2d(data[g]) for g in groups(inputs)], axis=1)


def _new(x: np.ndarray, inputs: str, cfg: RolloutConfig, seed: int, loss: str) -> Student:
    """A Student whose input scaling is x's (N, dim)."""
    torch.manual_seed(seed)
    student = Student(inputs, x.shape[1], cfg, loss=loss)
    student.mean.copy_(torch.as_tensor(x.mean(0)))
    student.std.copy_(torch.as_tensor(np.where(x.std(0) > 1e-6, x.std(0), 1.0)))  # a constant input stays as it is
    return student


def _batches(n: int, batch: int, rng: np.random.Generator):
    return np.array_split(rng.permutation(n), max(1, n // batch))


def fit(x: np.ndarray, adv: np.ndarray, inputs: str, cfg: RolloutConfig, seed: int = 0, epochs: int = 200,
        batch: int = 256, lr: float = 1e-3, weight_decay: float = 1e-4) -> Student:
    """A Student (loss "mse") fitted to the advantages adv (N, candidates) of inputs x (N, dim) by mean squared error
    (Adam)."""
    student = _new(x, inputs, cfg, seed, "mse")
    X, Y = torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(adv / Student.SCALE, dtype=torch.float32)
    opt = torch.optim.Adam(student.parameters(), lr=lr, weight_decay=weight_decay)
    rng = np.random.default_rng(seed)
    for _ in range(epochs):
        for idx in _batches(len(X), batch, rng):
            loss = ((student(X[idx]) - Y[idx]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    return student.eval()


def decision_loss(scores: torch.Tensor, adv: torch.Tensor) -> torch.Tensor:
    """Minus the expected advantage (N, candidates) of the candidate a softmax over the scores picks, mean per
    decision: the cost of the decision itself, differentiable without a policy gradient. Linear in the advantages,
    so a decision weighs what is at stake in it: the few where an outcome turns count most, near-ties little."""
    return -(torch.softmax(scores, dim=1) * adv).sum(dim=1).mean()


def fit_decision(x: np.ndarray, adv: np.ndarray, inputs: str, cfg: RolloutConfig, validation: tuple, seed: int = 0,
                 epochs: int = 200, patience: int = 20, batch: int = 256, lr: float = 1e-3,
                 weight_decay: float = 1e-4) -> tuple[Student, dict]:
    """A Student (loss "decision") fitted to inputs x (N, dim) and advantages adv (N, candidates) by decision_loss
    (Adam), kept at the epoch of least regret on validation = (x, adv) of other cases, stopped after `patience`
    epochs without a better one. It starts at the default T everywhere (its bias, epoch 0, also a candidate): a
    student whose training never beats staying on validation stays. Also returns the epoch kept and the validation
    regret (mean per decision) by epoch."""
    student = _new(x, inputs, cfg, seed, "decision")
    with torch.no_grad():
        student.net[-1].bias.zero_()
        student.net[-1].bias[cfg.candidates.index(cfg.default_T)] = 2.0  # a softmax of about 0.7 on staying
    X, Y = torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(adv / Student.SCALE, dtype=torch.float32)
    x_val, adv_val = validation
    x_val, adv_val = np.asarray(x_val, dtype=np.float32), np.asarray(adv_val, dtype=float)
    columns = {T: c for c, T in enumerate(cfg.candidates)}

    def val_regret() -> float:
        chosen = [columns[T] for T in student.eval().choose(x_val)]
        return float((adv_val.max(1) - adv_val[np.arange(len(adv_val)), chosen]).mean())

    opt = torch.optim.Adam(student.parameters(), lr=lr, weight_decay=weight_decay)
    rng = np.random.default_rng(seed)
    curve, best, kept = [val_regret()], 0, copy.deepcopy(student.state_dict())
    for epoch in range(1, epochs + 1):
        student.train()
        for idx in _batches(len(X), batch, rng):
            loss = decision_loss(student(X[idx]), Y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
        curve.append(val_regret())
        if curve[-1] < curve[best]:
            best, kept = epoch, copy.deepcopy(student.state_dict())
        elif epoch - best >= patience:
            break
    student.load_state_dict(kept)
    return student.eval(), dict(epoch=best, validation_regret=curve)


class DistilledTiming(RolloutTiming):
    """The rollout timing's gate and hold, with T from a Student's forward pass instead of branches."""

    def __init__(self, actor, student: Student, seed: int = 0, timing_cfg: TimingConfig = TimingConfig()):
        super().__init__(actor, seed, timing_cfg, student.cfg)
        self.student, self.timing = student, "distilled"
        self.settings = dict(self.settings, student=student.key())

    def choose(self, env: DrivingEnv, a, deterministic: bool) -> int:
        self.counts["decisions"] += 1
        return int(self.student.choose(design(features(env, a), self.student.inputs))[0])


def driver(spec: str, trainer) -> DistilledTiming:
    """--timing distilled=PATH of a loaded model (experiment.timing_override): its actor, timed by the student."""
    return DistilledTiming(trainer.actor, parse(spec), trainer.seed, trainer.tc.timing)


def parse(spec: str):
    """--timing distilled=PATH: the Student at PATH; None if spec is not a distilled timing."""
    name, eq, path = spec.partition("=")
    if name != "distilled":
        return None
    if not eq or not path:
        raise ValueError(f"{spec}: distilled=PATH, a student written by bench/distillation.py")
    return Student.load(path)

