"""Wrong answer to exercise 5: the next state's value as a max over T' (DQN's target), not SAC's expectation."""
import numpy as np

from exercises.solutions.ex5_timing_target import timing_transition  # noqa: F401 (right)

CHECKER_SAYS = "is it a max over T'?"


def timing_td_target(r_T, discount, done, q_next, probs, log_probs, alpha):
    v_next = (np.min(q_next, axis=0) - alpha * log_probs).max(-1)
    return r_T + discount * (1.0 - done) * v_next
