"""Wrong answer to exercise 1: Eq. (12) with beta on the base action."""
from exercises.solutions.ex1_timing import beta, discounted_sum  # noqa: F401 (right)

CHECKER_SAYS = "does beta weigh a_base instead of a?"


def blend(a, a_base, b):
    return b * a_base + (1.0 - b) * a
