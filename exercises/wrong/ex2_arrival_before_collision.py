"""Wrong answer to exercise 2: Eq. (31) asks about arrival first, so an arrival in a crash pays +20."""
from exercises.solutions.ex2_observation import observe, sector_index  # noqa: F401 (right)

CHECKER_SAYS = "a collision is never an arrival"


def reward(arrived, collided, v, v_min, v_max):
    if arrived:
        return 20.0
    return -20.0 if collided else min((v - v_min) / (v_max - v_min), 1.0) * 0.5
