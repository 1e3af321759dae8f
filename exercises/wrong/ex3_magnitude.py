"""Wrong answer to exercise 3: Eq. (22) as printed, a magnitude: the base planner can never brake."""
import math

from exercises.solutions.ex3_base_action import quintic_coefficients, state_machine  # noqa: F401 (right)

CHECKER_SAYS = "is a_t1 the magnitude"


def base_acceleration(l_dd_t1, a_idm, cfg):
    a_t1 = math.hypot(l_dd_t1, 0.0)
    return float(min(max(min(a_t1, a_idm), cfg.a_min), cfg.a_max))
