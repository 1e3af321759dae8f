"""Variants of TARL beyond the paper that give its timing taker what RESULTS.md found it lacks (PAPER.md, 6).

RESULTS.md ("Why the learned timing does not help"): the timing taker's critic does not learn the value of T in
the rare states that decide an episode. In the last seconds before a collision it expects a good return from
T = 1 (the actor alone) where T = 1 leads to a collision, while the actor's critic, on the same states, does see
the danger. Each variant below is TARL (Algorithm 1, tarl.Trainer) with one change to how the timing taker
learns; how it acts (Eqs. (5), (11)-(12)) is the paper's.

    tarl-actor-target   ActorTargetTrainer: Eq. (9)'s bootstrap from the actor's critic, an update every step
    tarl-rare-replay    RareReplayTrainer: a quarter of every timing batch drawn from D_T's collisions
    tarl-min-target     MinTargetTrainer: Eq. (9)'s bootstrap from the lower of both critics, an update every step
"""
from __future__ import annotations

import numpy as np
import torch

import tarl
from tarl import OBS_DIM


class ActorTargetTrainer(tarl.Trainer):
    """TARL whose timing critic bootstraps from the actor's critic, as TempoRL's skip critic does (Biedenkapp et
    al., ICML 2021, "TempoRL: Learning When to Act": r + gamma^k Q'(s', pi(s')), and a skip-critic update at
    every environment step).

    Eq. (9)'s target y = r_T + gamma^T (1 - delta) V(s_t+T) takes V from the actor, the soft value of Eq. (13)'s
    target, E_a'~pi_a [min Q'_a(s', a') - alpha_a log pi_a(a'|s')], in place of the timing taker's own soft value.
    The actor's critic learns from every real step (D_a), so the danger it sees at s_t+T reaches the timing
    critic at once, instead of through the timing taker's own rare decisions there. The timing taker updates once
    per simulator step of both loops (its row sets TrainConfig.timing_updates = 0: none per decision), about as
    often as the actor. TempoRL's other part, every sub-skip of an executed skip as a sample of its own, does not
    carry over: a sub-decision of T' < T steps of Eq. (7) is not a decision with T' (beta depends on T).
    """

    def timing_batch(self, batch_size: int, rng, idx=None) -> dict[str, torch.Tensor]:
        batch = super().timing_batch(batch_size, rng, idx)
        batch["rew"] = self.target(batch)
        batch["discount"] = torch.zeros_like(batch["discount"])  # so that the timing taker's target is y itself
        return batch

    def target(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """y of Eq. (9) with the actor's V(s_t+T): tarl.td_target of the actor, on the decision's own r_T and
        gamma^T."""
        return tarl.td_target(self.actor, dict(batch, next_obs=batch["next_obs"][:, :OBS_DIM]))

    def after_step(self, r: float, b: float | None, info: dict, done: bool, loop: str):
        """A timing update at every simulator step (imagination and real loop), once D_T holds enough decisions."""
        if self.D_T is not None:
            self.learn(self.timing_taker, self.timing_batch, len(self.D_T) >= self.tc.timing_learning_starts,
                       "timing")
        super().after_step(r, b, info, done, loop)


class RareReplayTrainer(tarl.Trainer):
    """TARL whose timing taker replays its rare collisions more often, as prioritized replay does for rare,
    surprising transitions (Schaul et al., ICLR 2016), here by a fixed share rather than by the TD error.

    D_T holds a collision in about one decision of 65 (RESULTS.md). A quarter of every timing batch is drawn
    uniformly from D_T's decisions that ended in a collision (delta = 1 with r_T < 0: Eq. (31) pays -20 there and
    +20 on arrival), the rest uniformly from all of D_T as in Algorithm 1. No importance weights: the critic is
    meant to weigh those decisions more. Everything else is TARL's.
    """

    RARE_SHARE = 0.25  # [-] of every timing batch drawn from D_T's collision decisions, while it has any

    def timing_batch(self, batch_size: int, rng, idx=None) -> dict[str, torch.Tensor]:
        n, data = len(self.D_T), self.D_T.data
        rare = np.flatnonzero((data["done"][:n] == 1.0) & (data["rew"][:n] < 0.0))
        if not len(rare):  # none yet: Algorithm 1's uniform batch
            return super().timing_batch(batch_size, rng)
        k = round(self.RARE_SHARE * batch_size)
        idx = np.concatenate([rng.integers(0, n, batch_size - k), rare[rng.integers(0, len(rare), k)]])
        return super().timing_batch(batch_size, rng, idx)


class MinTargetTrainer(ActorTargetTrainer):
    """TARL whose timing critic bootstraps from the lower of its own soft value and the actor's, updated every step.

    The actor's value alone (ActorTargetTrainer) lowered the intersection's collisions but froze the ego at the
    roundabout's entry (RESULTS.md, 8): V_a(s_t+T) is the value of the actor driving from s_t+T on, so a long T
    looks as good as T = 1 wherever the actor's critic is content, and the cost of waiting again and again never
    reaches the target. The timing taker's own V does carry that cost (8 timing updates stopped the freeze,
    RESULTS.md, 7) but misses the rare dangers that the actor's critic sees. Eq. (9)'s target takes the lower:

        y = r_T + gamma^T (1 - delta) min(V_T(s_t+T), V_a(s_t+T)),

    V_T the soft value of Eq. (9)'s own target (its target critics, the expectation over T'), V_a that of Eq.
    (13)'s (one a' ~ pi_a). The lower of two estimates as the target is clipped double Q-learning's device
    (Fujimoto et al., ICML 2018), here across the two agents. As in ActorTargetTrainer, an update every simulator
    step.
    """

    def target(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        own = tarl.td_target(self.timing_taker, batch)  # r_T + gamma^T (1 - delta) V_T(s_t+T)
        # gamma^T (1 - delta) >= 0, so the lower target is the one with the lower V
        return torch.minimum(own, super().target(batch))  # ... V_a(s_t+T)
