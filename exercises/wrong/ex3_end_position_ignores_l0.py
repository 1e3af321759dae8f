"""Wrong answer to exercise 3: row 4 of Eq. (19) solved as if l0 = 0 (l_e where l_e - l0 belongs). The
project always plans from l0 = 0, so this passes there, and fails as soon as l0 is not 0."""
import numpy as np

from exercises.solutions.ex3_base_action import base_acceleration, state_machine  # noqa: F401 (right)

CHECKER_SAYS = "row 4 of Eq. (19) asks l(t_e) = l_e"


def quintic_coefficients(l0, v0, a0, le, ve, ae, te):
    l0, v0, a0, le, ve, ae, te = (np.asarray(x, dtype=float) for x in (l0, v0, a0, le, ve, ae, te))
    dl = le  # the mistake: le - l0
    c3 = (20 * dl - (8 * ve + 12 * v0) * te - (3 * a0 - ae) * te**2) / (2 * te**3)
    c2 = (-30 * dl + (14 * ve + 16 * v0) * te + (3 * a0 - 2 * ae) * te**2) / (2 * te**4)
    c1 = (12 * dl - 6 * (ve + v0) * te + (ae - a0) * te**2) / (2 * te**5)
    return np.stack(np.broadcast_arrays(c1, c2, c3, a0 / 2, v0, l0), axis=-1)
