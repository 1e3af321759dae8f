"""Wrong answer to exercise 5: + alpha log pi, an entropy penalty in place of the bonus."""
import numpy as np

from exercises.solutions.ex5_timing_target import timing_transition  # noqa: F401 (right)

CHECKER_SAYS = "is the sign of alpha log pi flipped?"


def timing_td_target(r_T, discount, done, q_next, probs, log_probs, alpha):
    v_next = (probs * (np.min(q_next, axis=0) + alpha * log_probs)).sum(-1)
    return r_T + discount * (1.0 - done) * v_next
