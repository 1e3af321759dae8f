"""The design card's checks of the method, beside tarl.py: beta of Eq. (6) at its boundaries and the quintic
of Eqs. (18)-(19) against numpy.linalg.solve of its six boundary conditions. The other tests are in tests/."""
import numpy as np
import pytest

import planner
import tarl


@pytest.mark.parametrize("omega", [0.5, 4.0, tarl.TimingConfig.omega, 20.0])
@pytest.mark.parametrize("T", [1, 2, 3, 10])
def test_beta_ends_on_the_actor_and_is_a_weight(T, omega):
    """Eq. (6): beta(T, dt = T) = 1 (the actor's action alone at the last step of the timing), beta(T, 0) = 0,
    beta is in [0, 1] and rises with dt; T = 1 executes the actor's action at once (Eq. (11))."""
    dt = np.arange(0, T + 1)
    b = tarl.beta(T, dt, omega=omega)
    assert b[0] == pytest.approx(0.0, abs=1e-12) and b[-1] == pytest.approx(1.0)
    assert np.all((b >= 0) & (b <= 1)) and np.all(np.diff(b) > 0)
    assert tarl.beta(1, omega=omega) == pytest.approx(1.0)
    assert tarl.beta(2 * T, T, omega=omega) == pytest.approx(0.5)  # halfway: tanh(0) = 0
    assert tarl.blend(3.0, -1.0, tarl.beta(T, T, omega=omega)) == pytest.approx(3.0)  # Eq. (7): a_bar = a


def test_quintic_solves_its_six_boundary_conditions():
    """Eq. (19): l(0) = l0, l'(0) = v0, l''(0) = a0, l(te) = le, l'(te) = ve, l''(te) = ae for
    l(t) = c1 t^5 + ... + c6 (Eq. (18)): the closed form equals numpy.linalg.solve of the 6 x 6 system."""
    rng = np.random.default_rng(0)
    for l0, v0, a0, le, ve, ae, te in rng.uniform([-5, 0, -3, 10, 0, -2, 1], [5, 15, 3, 60, 15, 2, 8], (50, 7)):
        def rows(t):  # l(t), l'(t), l''(t) as rows over (c1, ..., c6)
            return [[t**5, t**4, t**3, t**2, t, 1], [5 * t**4, 4 * t**3, 3 * t**2, 2 * t, 1, 0],
                    [20 * t**3, 12 * t**2, 6 * t, 2, 0, 0]]
        solved = np.linalg.solve(np.array(rows(0.0) + rows(te)), [l0, v0, a0, le, ve, ae])
        np.testing.assert_allclose(planner.quintic_coefficients(l0, v0, a0, le, ve, ae, te), solved, rtol=1e-9,
                                   atol=1e-9)
