"""Solution of exercise 1: the timing factor and the blend. Equal to tarl.beta, tarl.blend, tarl.discounted_sum."""
import numpy as np


def beta(T, dt=1, *, omega):
    """Eq. (6): beta(T, dt) = 1/2 (tanh(w (dt / T - 1/2)) / tanh(w / 2) + 1); dt = 1 is Eq. (11)."""
    T, dt = np.asarray(T, dtype=float), np.asarray(dt, dtype=float)
    return 0.5 * (np.tanh(omega * (dt / T - 0.5)) / np.tanh(omega / 2.0) + 1.0)


def blend(a, a_base, b):
    """Eqs. (7) and (12): a_bar = beta a + (1 - beta) a_base."""
    return b * a + (1.0 - b) * a_base


def discounted_sum(rewards, gamma):
    """Eq. (8): r_T = sum_{dt=1..T} gamma^(dt-1) r_dt."""
    return float(np.sum(np.asarray(rewards) * gamma ** np.arange(len(rewards))))
