"""Wrong answer to exercise 5: a decision discounted by gamma, as one step of the actor is."""
import numpy as np

from exercises.solutions.ex5_timing_target import timing_td_target  # noqa: F401 (right)

CHECKER_SAYS = "is the discount gamma?"


def timing_transition(rewards, gamma, terminated, truncated):
    r_T = float(np.sum(np.asarray(rewards) * gamma ** np.arange(len(rewards))))
    return r_T, gamma, float(terminated)
