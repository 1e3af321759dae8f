"""Wrong answer to exercise 5: done at the time limit too, so a timed-out decision never bootstraps."""
import numpy as np

from exercises.solutions.ex5_timing_target import timing_td_target  # noqa: F401 (right)

CHECKER_SAYS = "is done set at the time limit?"


def timing_transition(rewards, gamma, terminated, truncated):
    r_T = float(np.sum(np.asarray(rewards) * gamma ** np.arange(len(rewards))))
    return r_T, gamma ** len(rewards), float(terminated or truncated)
