"""app/sim/small_solve.py: np.linalg.solve's result to the bit, its errors as before."""

import numpy as np
import pytest

from app.sim.small_solve import solve


@pytest.mark.parametrize("n", [2, 3, 6])
def test_the_same_bits_as_numpy_on_random_and_covariance_like_systems(n):
    rng = np.random.default_rng(33)
    for k in range(2000):
        m = rng.standard_normal((n, n)) * 10.0 ** rng.uniform(-6, 6)
        if k % 2:  # symmetric, positive definite, badly scaled: a covariance plus a floor
            m = m @ m.T + 1e-6 * np.eye(n)
        b = rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 6)
        x = solve(m, b)
        assert x.dtype == np.float64 and x.shape == (n,)
        assert x.tobytes() == np.linalg.solve(m, b).tobytes(), (m, b)
    a = np.array([[4.0, 1.0], [1.0, 3.0]])  # and it solves: a x = b
    np.testing.assert_allclose(a @ solve(a, np.array([1.0, 2.0])), [1.0, 2.0], rtol=1e-15)


def test_a_singular_system_raises_as_numpy_does():
    with pytest.warns(RuntimeWarning), pytest.raises(np.linalg.LinAlgError,
                                                     match="Singular matrix"):
        solve(np.zeros((3, 3)), np.ones(3))


def test_other_types_and_shapes_go_to_numpy():
    np.testing.assert_array_equal(solve(np.eye(2, dtype=np.float32), np.ones(2)), [1.0, 1.0])
    x = solve(np.eye(2), np.ones((2, 2)))  # several right-hand sides
    np.testing.assert_array_equal(x, np.ones((2, 2)))
    with pytest.raises(np.linalg.LinAlgError):
        solve(np.ones((2, 3)), np.ones(2))
