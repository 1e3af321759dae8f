"""Wrong answer to exercise 4: level 2 answers an ego that crosses (level 0's assumption), not the ego's
level-1 reply."""
import numpy as np

from exercises.solutions.ex4_level_k import CROSS, EGO_GAME_WEIGHTS, YIELD, game_utility, outcome_terms  # noqa: F401

CHECKER_SAYS = "does level 2 answer an ego that crosses?"


def level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, waited_e, alpha_h, svo, cfg):
    me, other = np.array([CROSS, YIELD]).reshape(2, 1, 1), np.array([CROSS, YIELD]).reshape(1, 2, 1)
    U_h = game_utility(alpha_h, *outcome_terms(t_h, t_e, decel_h, waited_h, me, other, cfg), cfg)
    U_e = game_utility(EGO_GAME_WEIGHTS, *outcome_terms(t_e, t_h, decel_e, waited_e, me, other, cfg), cfg)
    U_svo = (1.0 - svo) * U_h[:, CROSS] + svo * U_e[CROSS, :]  # the mistake: against CROSS, not e1
    return np.where(decel_h > 1.0, CROSS, U_svo.argmax(0))
