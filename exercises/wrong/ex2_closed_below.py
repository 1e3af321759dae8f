"""Wrong answer to exercise 2: the sectors as [phi_low, phi_high), closed on the wrong side."""
import numpy as np

from exercises.solutions.ex2_observation import PHI_HIGH, PHI_LOW, observe, reward  # noqa: F401 (right)

CHECKER_SAYS = "open below, closed above"


def sector_index(phi_deg):
    phi = np.asarray(phi_deg, dtype=float)
    rounded = np.round(phi, 9)
    rounded, phi = (np.where(rounded < -150.0, x + 360.0, x) for x in (rounded, phi))
    return np.argmax((PHI_LOW <= rounded[..., None]) & (rounded[..., None] < PHI_HIGH), axis=-1), phi
