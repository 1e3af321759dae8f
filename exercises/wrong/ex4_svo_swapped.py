"""Wrong answer to exercise 4: Eq. (26) mixed the wrong way round, a_svo on the human's own utility."""
import numpy as np

from exercises.solutions.ex4_level_k import CROSS, EGO_GAME_WEIGHTS, YIELD, game_utility, outcome_terms  # noqa: F401

CHECKER_SAYS = "is the mixing the wrong way round?"


def level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, waited_e, alpha_h, svo, cfg):
    m = np.arange(len(t_h))
    me, other = np.array([CROSS, YIELD]).reshape(2, 1, 1), np.array([CROSS, YIELD]).reshape(1, 2, 1)
    U_h = game_utility(alpha_h, *outcome_terms(t_h, t_e, decel_h, waited_h, me, other, cfg), cfg)
    U_e = game_utility(EGO_GAME_WEIGHTS, *outcome_terms(t_e, t_h, decel_e, waited_e, me, other, cfg), cfg)
    h0 = U_h[:, CROSS].argmax(0)
    e1 = U_e[:, h0, m].argmax(0)
    U_svo = svo * U_h[:, e1, m] + (1.0 - svo) * U_e[e1, :, m].T  # the mistake
    return np.where(decel_h > 1.0, CROSS, U_svo.argmax(0))
