"""Wrong answer to exercise 5: done = terminated and not truncated, so a collision on the step the time runs out
bootstraps as if the task went on."""
import numpy as np

from exercises.solutions.ex5_timing_target import timing_td_target  # noqa: F401 (right)

CHECKER_SAYS = "does the time limit cancel a terminal?"


def timing_transition(rewards, gamma, terminated, truncated):
    r_T = float(np.sum(np.asarray(rewards) * gamma ** np.arange(len(rewards))))
    return r_T, gamma ** len(rewards), float(terminated and not truncated)
