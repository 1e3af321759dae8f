"""Wrong answer to exercise 4: Eq. (24) as printed, every term added (waiting and braking then pay)."""
import numpy as np

from exercises.solutions.ex4_level_k import level_k_decisions, outcome_terms  # noqa: F401 (right)

CHECKER_SAYS = "are all four terms added, as Eq. (24) is printed?"


def game_utility(alpha, gap, wait, decel, waited, cfg):
    a = np.asarray(alpha)
    return (a[..., 0] * np.clip(gap / cfg.gap_range, 0.0, 1.0) + a[..., 1] * np.clip(wait / cfg.wait_range, 0.0, 1.0)
            + a[..., 2] * np.clip(decel, 0.0, 1.0) + a[..., 3] * np.clip(waited / cfg.emotion_range, 0.0, 1.0))
