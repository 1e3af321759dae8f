"""What the exercises and their checker share: the project's constants they need, and how a check
says what is wrong. Nothing here imports the project: a course may blank its reference bodies."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Config:
    """The values of world.EnvConfig() (and of the planner's limits) that the exercises read as cfg.x,
    copied so that the checker runs without the project; make_data.py checks they are still the project's."""

    perception: float = 60.0  # d_max of Eq. (27) [m]
    v_norm: float = 16.0  # v_max of Eq. (27) [m/s]
    v_min: float = 1.0  # v_min of Eq. (31) [m/s]
    v_max: float = 10.0  # v_max of Eq. (31) [m/s]
    a_min: float = -3.0  # the ego's strongest braking [m/s^2]
    a_max: float = 2.0  # the ego's strongest acceleration [m/s^2]
    gap_range: float = 5.0  # [s] phi_safe of Eqs. (24)-(25) saturates here
    wait_range: float = 10.0  # [s] phi_eff
    emotion_range: float = 30.0  # [s] phi_emo
    clear_time: float = 1.5  # [s] a yielder reaches the conflict point this long after the other


CFG = Config()
OMEGA = 6.0  # w of Eq. (6) [-], tarl.TimingConfig.omega
GAMMA = 0.99  # gamma of Table 2, SACConfig.gamma
K1 = 1000.0  # K1 of Eq. (20), PlannerConfig.K1


class Wrong(Exception):
    """A check failed; the message says what is wrong and, where it can, asks about the likely cause."""


def show(x) -> str:
    """A short, readable form of a number or an array."""
    x = np.asarray(x)
    if x.ndim == 0:
        return f"{x.item():.6g}" if x.dtype.kind in "fiu" else repr(x.item())
    return np.array2string(x, precision=4, threshold=8, separator=", ")


def expect(what: str, got, want, hint: str = "", wrong: dict | None = None, tol: float = 1e-6):
    """Raise Wrong unless got equals want (to tol): "<what> = <got> but should be <want>: <question>".
    wrong: {question: value} of known mistakes; the question of the one whose value got equals is asked,
    else hint."""
    if got is None:
        raise Wrong(f"{what} returned None: is the return missing?")
    got_a, want_a = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    if got_a.shape != want_a.shape:
        raise Wrong(f"{what} has shape {got_a.shape} but should have shape {want_a.shape}" + (f": {hint}" if hint else ""))
    if np.allclose(got_a, want_a, rtol=tol, atol=tol, equal_nan=True):
        return
    for question, value in (wrong or {}).items():
        if np.allclose(got_a, value, rtol=1e-4, atol=1e-6):
            hint = question
            break
    raise Wrong(f"{what} = {show(got_a)} but should be {show(want_a)}" + (f": {hint}" if hint else ""))


def first_difference(got, want, tol: float = 1e-6):
    """The index of the first entry where got and want differ (to tol), or None."""
    bad = ~np.isclose(np.asarray(got, dtype=float), np.asarray(want, dtype=float), rtol=tol, atol=tol, equal_nan=True)
    return tuple(int(i) for i in np.argwhere(bad)[0]) if bad.any() else None


def expect_all(name: str, got, want, what, hint: str = "", tol: float = 1e-6):
    """Raise Wrong at the first entry where the array got differs from want; what(index) names it."""
    if got is None:
        raise Wrong(f"{name} returned None: is the return missing?")
    got_a, want_a = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    if got_a.shape != want_a.shape:
        raise Wrong(f"{name} has shape {got_a.shape} but should have shape {want_a.shape}")
    k = first_difference(got_a, want_a, tol)
    if k is not None:
        raise Wrong(f"{what(k)} = {show(got_a[k])} but should be {show(want_a[k])}" + (f": {hint}" if hint else ""))


def expect_shape(what: str, got, want: tuple, hint: str = ""):
    """Raise Wrong unless np.shape(got) == want."""
    if np.shape(got) != want:
        raise Wrong(f"{what} is {np.shape(got)} but should be {want}" + (f": {hint}" if hint else ""))
