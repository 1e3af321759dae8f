"""Wrong answer to exercise 2: the sectors' intervals taken as they are, the rear one not wrapped, so a
vehicle behind and to the right (phi <= -150) falls in no interval (and argmax says "front")."""
import numpy as np

from exercises.solutions.ex2_observation import PHI_HIGH, PHI_LOW, observe, reward  # noqa: F401 (right)

CHECKER_SAYS = "the rear sector wraps"


def sector_index(phi_deg):
    phi = np.asarray(phi_deg, dtype=float)
    rounded = np.round(phi, 9)
    return np.argmax((PHI_LOW < rounded[..., None]) & (rounded[..., None] <= PHI_HIGH), axis=-1), phi
