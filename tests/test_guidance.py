"""CW two-impulse guidance (app/sim/guidance.py) against the ODS itself."""

import numpy as np
import pytest

from app.sim.guidance import two_impulse_transfer, vbar_hold_points
from app.sim.orbital import OdsParams, orbit_rate, rk4_step

W = orbit_rate(800e3)


def _coast(r, v, seconds, dt=1.0):
    y = np.zeros((1, 13))
    y[0, :3], y[0, 3:6], y[0, 6] = r, v, 1.0
    params = OdsParams(W, np.array([100.0]), np.array([[10.0, 10.0, 10.0]]),
                       gravity_gradient=False)
    zero = np.zeros((1, 3))
    for _ in range(int(round(seconds / dt))):
        y = rk4_step(params, y, zero, zero, dt)
    return y[0, :3], y[0, 3:6]


@pytest.mark.parametrize("transfer_s", [600.0, 1500.0, 4000.0])
def test_a_two_impulse_transfer_lands_on_the_next_hold_point_at_rest(transfer_s):
    """Hop along V-bar from y = -100 m to y = -50 m: after Δv1 the ODS (RK4 over Eqs. 1-3,
    not the closed form) coasts onto the hold point, where Δv2 stops it."""
    r0, rf = np.array([0.0, -100.0, 0.0]), np.array([0.0, -50.0, 0.0])
    dv1, dv2 = two_impulse_transfer(r0, np.zeros(3), rf, np.zeros(3), transfer_s, W)
    r, v = _coast(r0, dv1, transfer_s)
    np.testing.assert_allclose(r, rf, atol=1e-6)
    np.testing.assert_allclose(v + dv2, 0.0, atol=1e-9)
    assert dv1[2] == dv2[2] == 0.0  # in-plane


@pytest.mark.parametrize("orbits", [1.0, 0.5])
def test_a_transfer_of_a_whole_or_half_orbit_is_refused(orbits):
    """Φrv is singular in plane at a whole orbit and out of plane (sin ΩT / Ω) at half."""
    with pytest.raises(ValueError, match="a whole number of half orbits"):
        two_impulse_transfer([0, -100, 0], [0, 0, 0], [0, -50, 0], [0, 0, 0],
                             orbits * 2 * np.pi / W, W)


def test_hold_points_on_vbar():
    np.testing.assert_allclose(vbar_hold_points(-100.0, -10.0, 3),
                               [[0, -70, 0], [0, -40, 0], [0, -10, 0]])
