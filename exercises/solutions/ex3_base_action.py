"""Solution of exercise 3: the base action. Equal to planner.quintic_coefficients, planner.state_machine,
planner.base_acceleration."""
import math

import numpy as np


def quintic_coefficients(l0, v0, a0, le, ve, ae, te):
    """Eq. (19) solved in closed form: (c1, ..., c6) of Eq. (18) on the last axis."""
    l0, v0, a0, le, ve, ae, te = (np.asarray(x, dtype=float) for x in (l0, v0, a0, le, ve, ae, te))
    # Eq. (19): rows 1-3 give c6 = l0, c5 = v_l0, c4 = a_l0 / 2; rows 4-6 then c3, c2, c1
    dl = le - l0
    c3 = (20 * dl - (8 * ve + 12 * v0) * te - (3 * a0 - ae) * te**2) / (2 * te**3)
    c2 = (-30 * dl + (14 * ve + 16 * v0) * te + (3 * a0 - 2 * ae) * te**2) / (2 * te**4)
    c1 = (12 * dl - 6 * (ve + v0) * te + (ae - a0) * te**2) / (2 * te**5)
    return np.stack(np.broadcast_arrays(c1, c2, c3, a0 / 2, v0, l0), axis=-1)


def state_machine(cost, drive_ids, stop_ids, K1):
    """("drive", cheapest drive candidate) if it is collision-free (cost < K1), else ("stop", cheapest stop
    candidate) if it is, else ("brake", None)."""
    for mode, ids in (("drive", drive_ids), ("stop", stop_ids)):
        best = ids.start + int(np.argmin(cost[ids]))
        if cost[best] < K1:
            return mode, best
    return "brake", None


def base_acceleration(l_dd_t1, a_idm, cfg):
    """a_base [m/s^2] in [a_min, a_max] from the chosen candidate's l''(t1) and a_IDM."""
    # Eq. (22): a_t1 = sqrt(l''(t1)^2 + d''(t1)^2), kept WITH the sign of l''(t1) (PAPER.md, note 3); d'' = 0
    a_t1 = math.copysign(math.hypot(l_dd_t1, 0.0), l_dd_t1)
    # Eq. (23): a_base = min(a_t1, a_IDM)
    return float(min(max(min(a_t1, a_idm), cfg.a_min), cfg.a_max))
