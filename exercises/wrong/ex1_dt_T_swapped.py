"""Wrong answer to exercise 1: Eq. (6) with T / dt in place of dt / T."""
import numpy as np

from exercises.solutions.ex1_timing import blend, discounted_sum  # noqa: F401 (right)

CHECKER_SAYS = "is dt / T swapped?"


def beta(T, dt=1, *, omega):
    T, dt = np.asarray(T, dtype=float), np.asarray(dt, dtype=float)
    return 0.5 * (np.tanh(omega * (T / dt - 0.5)) / np.tanh(omega / 2.0) + 1.0)
