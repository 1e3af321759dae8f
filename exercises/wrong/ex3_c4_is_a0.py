"""Wrong answer to exercise 3: c4 = a_l0, forgetting that l''(0) = 2 c4 (row 3 of Eq. (19)); the other
coefficients follow from the same slip."""
import numpy as np

from exercises.solutions.ex3_base_action import base_acceleration, state_machine  # noqa: F401 (right)

CHECKER_SAYS = "row 3 of Eq. (19) asks l''(0) = a_l0"


def quintic_coefficients(l0, v0, a0, le, ve, ae, te):
    l0, v0, a0, le, ve, ae, te = (np.asarray(x, dtype=float) for x in (l0, v0, a0, le, ve, ae, te))
    c4 = a0  # the mistake: l''(0) = 2 c4, so c4 = a0 / 2
    # rows 4-6 solved with l''(0) = 2 c4 = 2 a0 in place of a0
    dl, a0 = le - l0, 2 * c4
    c3 = (20 * dl - (8 * ve + 12 * v0) * te - (3 * a0 - ae) * te**2) / (2 * te**3)
    c2 = (-30 * dl + (14 * ve + 16 * v0) * te + (3 * a0 - 2 * ae) * te**2) / (2 * te**4)
    c1 = (12 * dl - 6 * (ve + v0) * te + (ae - a0) * te**2) / (2 * te**5)
    return np.stack(np.broadcast_arrays(c1, c2, c3, c4, v0, l0), axis=-1)
