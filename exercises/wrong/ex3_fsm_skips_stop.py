"""Wrong answer to exercise 3: the FSM brakes as soon as no drive candidate is free, never trying to stop."""
import numpy as np

from exercises.solutions.ex3_base_action import base_acceleration, quintic_coefficients  # noqa: F401 (right)

CHECKER_SAYS = "try the stop candidates before braking"


def state_machine(cost, drive_ids, stop_ids, K1):
    best = drive_ids.start + int(np.argmin(cost[drive_ids]))
    return ("drive", best) if cost[best] < K1 else ("brake", None)
