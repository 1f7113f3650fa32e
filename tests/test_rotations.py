"""Rotation helpers (app/sim/rotations.py)."""

from __future__ import annotations

import numpy as np

from app.sim.rotations import cross3, skew


def test_cross3_is_np_cross_bit_for_bit():
    """cross3 replaces np.cross in the cycle: the same bits on vectors of every scale,
    signs and zeros included."""
    rng = np.random.default_rng(7)
    for scale in (1e-9, 1.0, 1e6):
        for _ in range(200):
            a, b = scale * rng.standard_normal(3), rng.standard_normal(3)
            assert cross3(a, b).tobytes() == np.cross(a, b).tobytes()
    a, b = np.array([0.0, -0.0, 2.0]), np.array([-0.0, 3.0, 0.0])
    assert cross3(a, b).tobytes() == np.cross(a, b).tobytes()
    a = np.array([0.3, -1.2, 2.5])
    np.testing.assert_allclose(cross3(a, [1.0, 2.0, 3.0]), skew(a) @ [1.0, 2.0, 3.0])
