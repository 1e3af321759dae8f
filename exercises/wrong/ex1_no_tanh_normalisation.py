"""Wrong answer to exercise 1: Eq. (6) without the division by tanh(w / 2)."""
import numpy as np

from exercises.solutions.ex1_timing import blend, discounted_sum  # noqa: F401 (right)

CHECKER_SAYS = "is the division by tanh(w / 2) missing?"


def beta(T, dt=1, *, omega):
    T, dt = np.asarray(T, dtype=float), np.asarray(dt, dtype=float)
    return 0.5 * (np.tanh(omega * (dt / T - 0.5)) + 1.0)
