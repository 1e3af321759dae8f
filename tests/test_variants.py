"""The variants beyond the paper that give the timing taker the signal it lacks (beyond/variants.py, docs/PAPER.md, 6): each
mechanism checked by hand on a D_T filled here, and a short real run of each that updates and reloads."""
import dataclasses

import numpy as np
import pytest
import torch

import experiment
import tarl
from beyond import variants
from test_train import QUIET, SMALL, SMALL_SAC, env  # noqa: F401 (env: the fixture, the intersection)
from world import OBS_DIM


def fill(trainer, n: int, collisions=()):
    """n decisions in D_T by hand: decision i has obs i / n, T = i % 10 + 1, r_T = i, next obs i / n + 1/2;
    those in `collisions` end in a collision (delta = 1, r_T = -20), every 7th other one arrives (delta = 1, +20)."""
    for i in range(n):
        x = np.full(OBS_DIM + 1, i / n, np.float32)
        crash, arrive = i in collisions, i % 7 == 6 and i not in collisions
        trainer.D_T.add(x, i % 10 + 1, -20.0 if crash else 20.0 if arrive else float(i), x + 0.5,
                        0.99 ** (i % 10 + 1), crash or arrive)


def test_actor_target_bootstraps_eq_9_from_the_actors_soft_value(env):
    """y = r_T + gamma^T (1 - delta) (min Q'_a(s', a') - alpha_a log pi_a(a'|s')), a' ~ pi_a(s'), by hand."""
    trainer = experiment.make_trainer("tarl-actor-target", env, SMALL, seed=1, state=dict(config=dict(sac=vars(SMALL_SAC))), **QUIET)
    fill(trainer, 40)
    idx = np.arange(40)
    torch.manual_seed(5)
    batch = trainer.timing_batch(40, np.random.default_rng(0), idx)
    torch.manual_seed(5)
    plain = tarl.Trainer.timing_batch(trainer, 40, np.random.default_rng(0), idx)  # TARL's batch, the same draws
    s2 = plain["next_obs"][:, :OBS_DIM]
    a2, log_p = trainer.actor.squashed_gaussian(s2)  # the draw after timing_batch's own a_next, as in the variant
    with torch.no_grad():
        q = trainer.actor.critic_target(s2, a2).amin(0).squeeze(-1)
        v = q - trainer.actor.log_alpha.exp() * log_p
    r, disc, done = plain["rew"], plain["discount"], plain["done"]
    torch.testing.assert_close(batch["rew"], r + disc * (1 - done) * v)
    assert torch.equal(batch["discount"], torch.zeros(40))
    assert torch.equal(batch["obs"], plain["obs"]) and torch.equal(batch["act"], plain["act"])
    # the timing taker's Eq. (9) target is then y itself
    torch.testing.assert_close(tarl.td_target(trainer.timing_taker, batch), batch["rew"])
    assert torch.equal(done, torch.tensor([float(i % 7 == 6) for i in range(40)]))  # terminal: y = r_T alone
    torch.testing.assert_close(batch["rew"][done == 1], r[done == 1])


def test_min_target_bootstraps_eq_9_from_the_lower_of_both_soft_values(env):
    """y = r_T + gamma^T (1 - delta) min(V_T(s'), V_a(s')), by hand: V_T the expectation over T' of the timing
    taker's own target critics, V_a one a' ~ pi_a on the actor's; and the lower one is not always the same."""
    trainer = experiment.make_trainer("tarl-min-target", env, SMALL, seed=1, state=dict(config=dict(sac=vars(SMALL_SAC))), **QUIET)
    assert isinstance(trainer, variants.ActorTargetTrainer)  # its update every simulator step
    fill(trainer, 40)
    idx = np.arange(40)
    torch.manual_seed(5)
    plain = tarl.Trainer.timing_batch(trainer, 40, np.random.default_rng(0), idx)
    x2, s2 = plain["next_obs"], plain["next_obs"][:, :OBS_DIM]
    a2, log_p = trainer.actor.squashed_gaussian(s2)  # the draw after timing_batch's own a_next, as in the variant
    with torch.no_grad():
        v_a = trainer.actor.critic_target(s2, a2).amin(0).squeeze(-1) - trainer.actor.log_alpha.exp() * log_p
        probs, log_probs = trainer.timing_taker.timing_distribution(x2)
        q_T = trainer.timing_taker.critic_target(x2).amin(0)
        v_T = (probs * (q_T - trainer.timing_taker.log_alpha.exp() * log_probs)).sum(-1)
        shift = (v_T - v_a).median()  # the actor's critics moved so that each V is the lower on about half
        trainer.actor.critic_target.b3 += shift
        v_a += shift
    torch.manual_seed(5)
    batch = trainer.timing_batch(40, np.random.default_rng(0), idx)
    r, disc, done = plain["rew"], plain["discount"], plain["done"]
    torch.testing.assert_close(batch["rew"], r + disc * (1 - done) * torch.minimum(v_T, v_a))
    assert torch.equal(batch["discount"], torch.zeros(40))
    live = done == 0
    assert (v_T < v_a)[live].any() and (v_a < v_T)[live].any()
    torch.testing.assert_close(batch["rew"][done == 1], r[done == 1])  # terminal: y = r_T alone


def test_rare_replay_draws_a_quarter_of_each_batch_from_d_ts_collisions(env):
    trainer = experiment.make_trainer("tarl-rare-replay", env, SMALL, seed=1, state=dict(config=dict(sac=vars(SMALL_SAC))), **QUIET)
    fill(trainer, 200)  # no collision yet: Algorithm 1's uniform batch, the same draws as TARL's
    torch.manual_seed(0)
    mine = trainer.timing_batch(64, np.random.default_rng(3))
    torch.manual_seed(0)
    theirs = tarl.Trainer.timing_batch(trainer, 64, np.random.default_rng(3))
    assert all(torch.equal(mine[k], theirs[k]) for k in mine)
    trainer.D_T.ptr = trainer.D_T.size = 0
    collisions = {3, 50, 121}
    fill(trainer, 200, collisions)
    for seed in range(5):
        batch = trainer.timing_batch(64, np.random.default_rng(seed))
        rows = np.round(batch["obs"][:, 0].numpy() * 200).astype(int)
        crash = np.isin(rows, list(collisions))
        assert crash[-16:].all()  # the last quarter: collisions only (16 of 64)
        assert crash.sum() < 16 + 5  # the rest uniform over 200 decisions, 3 of them collisions
        assert (batch["done"][crash] == 1).all() and (batch["rew"][crash] == -20).all()


@pytest.mark.parametrize("algo", ["tarl-actor-target", "tarl-rare-replay", "tarl-min-target"])
def test_short_runs_of_the_signal_variants_update_count_their_steps_and_reload(algo, env, tmp_path):
    small = dict(config=dict(sac=vars(SMALL_SAC)))
    trainer = experiment.make_trainer(algo, env, SMALL, seed=1, out=tmp_path, state=small, **QUIET)
    ready = []  # per simulator step: did D_T hold enough decisions for a timing update
    after = trainer.after_step
    trainer.after_step = lambda *a: ready.append(len(trainer.D_T) >= SMALL.timing_learning_starts) or after(*a)
    trainer.run()
    assert trainer.step == len(ready) >= SMALL.steps  # every simulator step of both loops counts
    assert trainer.updates["actor"] > 50
    decisions = len(trainer.D_T) - SMALL.timing_learning_starts + 1
    if algo != "tarl-rare-replay":  # one timing update per simulator step once D_T is ready, none per decision
        assert trainer.updates["timing"] == sum(ready) > decisions
    else:  # Algorithm 1's one per decision
        assert trainer.updates["timing"] == decisions
    state = experiment.load_checkpoint(tmp_path / "ckpt.pt", "intersection", algo)
    fresh = experiment.make_trainer(algo, env, SMALL, seed=2, state=state, **QUIET)
    fresh.load(state, resume=True)
    assert isinstance(fresh, type(trainer)) and len(fresh.D_T) == len(trainer.D_T)
    x = np.random.default_rng(0).uniform(0, 1, (4, OBS_DIM + 1)).astype(np.float32)
    np.testing.assert_array_equal(fresh.timing_taker.act(x, True), trainer.timing_taker.act(x, True))
    assert isinstance(trainer, (variants.ActorTargetTrainer, variants.RareReplayTrainer))


def test_a_short_run_of_tarl_branch_learns_from_measured_branches_counts_their_steps_and_reloads(env, tmp_path,
                                                                                                monkeypatch):
    monkeypatch.setattr(variants.BranchTrainer, "BRANCH_SHARE", 1.0)  # branch wherever T can matter
    monkeypatch.setattr(variants.BranchTrainer, "LEARNING_STARTS", 3)
    small = dataclasses.replace(SMALL, steps=2500)  # a branch can run for the whole 60 s of an episode
    trainer = experiment.make_trainer("tarl-branch", env, small, seed=1, out=tmp_path,
                                      state=dict(config=dict(sac=vars(SMALL_SAC))), **QUIET)
    steps, branches = [0], []
    step, play = env.step, variants.rollout_timing.play_branch
    monkeypatch.setattr(env, "step", lambda a: steps.__setitem__(0, steps[0] + 1) or step(a))
    monkeypatch.setattr(variants.rollout_timing, "play_branch", lambda *a, **k: branches.append(play(*a, **k)) or
                        branches[-1])
    trainer.run()
    assert steps[0] == trainer.step >= small.steps  # every simulator step, of the branches too, counts
    n = len(trainer.D_T)
    assert n == len(branches) >= 2 * variants.BranchTrainer.CANDIDATES and n % variants.BranchTrainer.CANDIDATES == 0
    data = {k: v[:n] for k, v in trainer.D_T.data.items()}
    # Eq. (9)'s target is the measured return: G of Eq. (8) over the whole branch, no bootstrap
    np.testing.assert_allclose(data["rew"], [tarl.discounted_sum(r, SMALL_SAC.gamma) for r in branches], rtol=1e-6)
    assert (data["discount"] == 0).all() and (data["done"] == 1).all() and set(data["act"]) <= set(range(1, 11))
    assert trainer.updates["timing"] == variants.BranchTrainer.UPDATES * (n - 3 + 1) and trainer.updates["actor"] > 50
    state = experiment.load_checkpoint(tmp_path / "ckpt.pt", "intersection", "tarl-branch")
    fresh = experiment.make_trainer("tarl-branch", env, small, seed=2, state=state, **QUIET)
    fresh.load(state, resume=True)
    assert isinstance(fresh, variants.BranchTrainer) and len(fresh.D_T) == n
    x = np.random.default_rng(0).uniform(0, 1, (4, OBS_DIM + 1)).astype(np.float32)
    np.testing.assert_array_equal(fresh.timing_taker.act(x, True), trainer.timing_taker.act(x, True))

