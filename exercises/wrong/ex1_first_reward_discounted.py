"""Wrong answer to exercise 1: Eq. (8) with gamma^dt in place of gamma^(dt - 1)."""
import numpy as np

from exercises.solutions.ex1_timing import beta, blend  # noqa: F401 (right)

CHECKER_SAYS = "is the first reward discounted?"


def discounted_sum(rewards, gamma):
    return float(np.sum(np.asarray(rewards) * gamma ** np.arange(1, len(rewards) + 1)))
