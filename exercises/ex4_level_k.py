"""Exercise 4: the level-k humans (paper Sec. 5.1, Eqs. (24)-(26), Table 1).

At each conflict point a human and the ego each CROSS first or YIELD. A player's utility (Eq. (24))
weighs safety (the gap between the two arrival times), efficiency (time spent waiting for the other),
comfort (braking) and emotion (time already waited); each term is min-max normalised (Eq. (25)).
Level-k reasoning, k = 2: the human makes a level-0 choice, the ego (as the human pictures it) a
level-1 reply to it, and the human a level-2 reply to that, weighing its own utility and the ego's by
its social value orientation a_svo (Eq. (26)).

outcome_terms is given: it is the project's reading of what each pair of choices leads to (the paper
does not say). Read it, then fill in the two TODO(student) blocks (numpy):    python -m exercises.check 4
Read docs/PAPER.md, note 6 (the signs of Eq. (24)). Don't read world.py's game_utility and
level_k_decisions before you are done: they are the answer.
"""
import numpy as np

CROSS, YIELD = 0, 1
EGO_GAME_WEIGHTS = np.array([0.65, 0.125, 0.125, 0.125])  # the ego as humans picture it: Table 1's middle


def game_utility(alpha, gap, wait, decel, waited, cfg):
    """Eq. (24) with each term normalised by Eq. (25) (minimum 0, maximum the range in cfg, saturating):

        U = a1 phi_safe - a2 phi_eff - a3 phi_comf + a4 phi_emo,
        phi_safe = gap / cfg.gap_range,  phi_eff = wait / cfg.wait_range,  phi_comf = decel,
        phi_emo = waited / cfg.emotion_range,   each clipped to [0, 1].

    Eq. (24) is printed with + on every term, but waiting and braking are costs (PAPER.md, note 6).
    alpha (..., 4): the weights a1..a4; gap, wait, waited [s], decel [-] (the braking needed as a share
    of the player's capability): arrays that broadcast with alpha[..., 0]. Returns their broadcast shape.
    """
    # TODO(student): Eqs. (24)-(25)
    raise NotImplementedError("Eqs. (24)-(25)")


def outcome_terms(t_me, t_other, stop_decel, waited, me, other, cfg):
    """Given. The four terms of Eq. (24) (gap, wait, decel, waited) for a player choosing `me` (CROSS /
    YIELD) against `other`: t_me, t_other [s] the two arrival times at the conflict point, stop_decel the
    braking it needs to stop before it, waited [s] the time it has already waited. Everything broadcasts."""
    both_yield = (me == YIELD) & (other == YIELD)
    # a yielding player reaches the conflict point only after the other has passed (plus clear_time)
    t_mine = np.where((me == YIELD) & (other == CROSS), np.maximum(t_me, t_other + cfg.clear_time), t_me)
    t_theirs = np.where((other == YIELD) & (me == CROSS), np.maximum(t_other, t_me + cfg.clear_time), t_other)
    # both yielding is a standoff: both wait the longest wait, then the conflict is as close as it was
    wait = np.where(both_yield, cfg.wait_range, t_mine - t_me)  # 0 when crossing
    decel = np.where((me == YIELD) & (wait > 0), stop_decel, 0.0)
    return np.abs(t_mine - t_theirs), wait, decel, np.where(me == CROSS, waited, 0.0)


def level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, waited_e, alpha_h, svo, cfg):
    """The level-2 decisions, CROSS or YIELD (int array (M,)), of M humans each against the ego.

    t_h, t_e (M,) [s]: the human's and the ego's arrival times at their conflict point; decel_h, decel_e
    (M,): the braking each needs to stop before it (a share of its own capability); waited_h (M,),
    waited_e [s]: the time each has already waited; alpha_h (M, 4): the humans' weights of Eq. (24);
    svo (M,): their a_svo. A player's utility for (its choice, the other's):
        game_utility(weights, *outcome_terms(t_mine, t_theirs, its decel, its waited, its choice, theirs, cfg), cfg)
    with the human's weights alpha_h and the ego's EGO_GAME_WEIGHTS.

    level 0: the human's best reply to an ego that goes on (crosses);
    level 1: the ego's best reply to the human's level-0 choice;
    level 2: the human's best reply to the ego's level-1 choice, on U_svo of Eq. (26):
             U_svo = (1 - a_svo) U_self + a_svo U_oppo, U_self the human's utility, U_oppo the ego's.
    A tie goes to CROSS. A human that cannot stop before the conflict point (decel_h > 1) crosses.
    """
    # TODO(student): Eq. (26) and the three levels (vectorised over the M humans: no Python loop needed)
    raise NotImplementedError("Eq. (26), levels 0-2")
