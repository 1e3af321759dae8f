"""Variants of TARL beyond the paper that give its timing taker what docs/RESULTS.md found it lacks (PAPER.md, 6).

docs/RESULTS.md ("Why the learned timing does not help"): the timing taker's critic does not learn the value of T in
the rare states that decide an episode. In the last seconds before a collision it expects a good return from
T = 1 (the actor alone) where T = 1 leads to a collision, while the actor's critic, on the same states, does see
the danger. Each variant below is TARL (Algorithm 1, tarl.Trainer) with one change to how the timing taker
learns; how it acts (Eqs. (5), (11)-(12)) is the paper's.

    tarl-actor-target   ActorTargetTrainer: Eq. (9)'s bootstrap from the actor's critic, an update every step
    tarl-rare-replay    RareReplayTrainer: a quarter of every timing batch drawn from D_T's collisions
    tarl-min-target     MinTargetTrainer: Eq. (9)'s bootstrap from the lower of both critics, an update every step
    tarl-branch         BranchTrainer: Q(s, a, T) learned from measured branches of the real world, in place of the
                        timing imagination (beyond/rollout_timing.py measures what such a timing can reach)
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import torch

from beyond import rollout_timing
import tarl
from world import OBS_DIM


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
    roundabout's entry (docs/RESULTS.md, "Beyond the paper"): V_a(s_t+T) is the value of the actor driving from
    s_t+T on, so a long T looks as good as T = 1 wherever the actor's critic is content, and the cost of waiting
    again and again never reaches the target. The timing taker's own V does carry that cost (8 timing updates
    stopped the freeze, same section) but misses the rare dangers that the actor's critic sees. Eq. (9)'s target
    takes the lower:

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


class BranchTrainer(tarl.Trainer):
    """TARL whose timing taker learns what each T leads to in the real world, measured by branching the world,
    in place of the timing imagination (Algorithm 1 lines 4-15); how it acts is the paper's (Eqs. (11)-(12)).

    The rollout timing (beyond/rollout_timing.py) finds that choosing T by simulating it from the state does better than
    any fixed or random T (RESULTS.md). This loop teaches the timing taker from the same branches. It drives the
    real loop with TARL's learned timing for N_T steps, then to the episode's end. At a step where T can matter
    (the actor's and the planner's accelerations differ by at least RolloutConfig.gap), with probability
    BRANCH_SHARE, the world is saved and CANDIDATES timings T drawn from 1..T_max are each played from it: held
    for RolloutConfig.hold steps, then T = 2 to the episode's end, each in a future of its own (the humans' game
    weights and the departures drawn anew). D_T stores ((s_t, a_t), T, G) with G the branch's discounted return
    of Eq. (8) to its end, and discount 0: Eq. (9)'s target becomes the measured G, a Monte Carlo target. Every
    branch step counts toward the budget, as the imagination's do. Nothing of the main line enters D_a.
    """

    BRANCH_SHARE = 0.2  # [-] of the steps where T can matter that are branched: ~1 in 7 steps of the loop
    CANDIDATES = 3  # timings T branched per decision, drawn without replacement from 1..T_max
    UPDATES = 8  # timing-taker updates per branch stored: D_T holds ~500 branches at the default budget
    LEARNING_STARTS = 100  # branches in D_T before the timing taker learns (D_T fills ~10 x slower than TARL's)

    def imagination_loop(self):
        n, done, env, cfg = 0, False, self.env, rollout_timing.RolloutConfig()
        if not hasattr(self, "_folder"):
            self._folder = tempfile.TemporaryDirectory(prefix="tarl-branch-")
        while n < self.tc.n_timing or not done:
            s = self.obs
            a, T, b = self.driver.act(s, env)  # TARL's, sampling T (Alg. 1 lines 17-18)
            branch = self.step < self.tc.steps and self.rng.random() < self.BRANCH_SHARE  # within the budget
            if branch and abs(float(a[0]) - env.base_action()) >= cfg.gap:
                x = tarl.timing_input(s, a, env.cfg)
                state = env.save_state(Path(self._folder.name) / "state.xml")
                for T_b in self.rng.choice(np.arange(1, self.tc.timing.t_max + 1), self.CANDIDATES, replace=False):
                    future = np.random.default_rng(self.rng.integers(2**63))  # its own: not the main line's
                    rewards = rollout_timing.play_branch(env, self.actor, state, int(T_b), future, cfg,
                                                         self.tc.timing.omega, deterministic=False, on_step=self.branch_step)
                    G = tarl.discounted_sum(rewards, self.sac_cfg.gamma)  # Eq. (8) over the whole branch
                    self.D_T.add(x, int(T_b), G, np.zeros(OBS_DIM + 1, np.float32), 0.0, True)
                    for _ in range(self.UPDATES):
                        self.learn(self.timing_taker, self.timing_batch, len(self.D_T) >= self.LEARNING_STARTS, "timing")
                env.restore_state(state)  # the main line goes on with its own future
            s2, r, terminated, truncated, info = env.step(tarl.execute(env, a, b))
            done = terminated or truncated
            self.obs = env.reset()[0] if done else s2
            self.after_step(r, b, info, done, "imagination")
            n += 1

    def branch_step(self):
        """A simulator step of a branch: it counts toward the budget, the progress lines and the checkpoints, not
        toward an episode of train_log.csv."""
        self.step += 1
        if self.step % self.tc.log_every == 0:
            self.log.progress(self.step, "timing branches", f" | updates actor {self.updates['actor']}, timing "
                              f"{self.updates['timing']}, D_T {len(self.D_T)}")
        if self.step % self.tc.checkpoint_every == 0:
            self.save()

