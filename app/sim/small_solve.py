"""A linear solve of a few unknowns at the cost of its LAPACK call alone.

``np.linalg.solve`` on a 2 × 2 or 3 × 3 system costs about 4 µs, of which about 3 µs are
its Python wrapper (argument checks, the common type, a floating-point error context);
the contact's estimate solves two such systems per cycle in contact (the pair's Newton
check, app/sim/contact_gate.py, and the identified contact law's least squares,
app/sim/contact_identification.py). :func:`solve` calls the very kernel
``np.linalg.solve`` calls (its gufunc, LAPACK ``gesv``, signature ``dd->d``) on float64
arrays, so that its result is the same to the bit; where any of its unknowns is not
finite (a singular or non-finite system) it hands the system to ``np.linalg.solve``, which raises
``LinAlgError`` for a singular one as before (after the kernel's own RuntimeWarning,
"invalid value encountered", which the wrapper's error context would have turned into
that error).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["solve"]

def _kernel():
    """np.linalg.solve's own kernel (numpy >= 1.8, also numpy 2), if this numpy has it
    and it answers a known system as the wrapper does; else None (the wrapper is used)."""
    try:  # a private module: checked here, once, rather than trusted
        from numpy.linalg import _umath_linalg

        kernel = _umath_linalg.solve1
        a, b = np.array([[4.0, 1.0], [2.0, 3.0]]), np.array([1.0, 2.0])
        if np.array_equal(kernel(a, b, signature="dd->d"), np.linalg.solve(a, b)):
            return kernel
    except Exception:  # noqa: BLE001 - pragma: no cover - another numpy: its wrapper
        pass
    return None  # pragma: no cover


_SOLVE1 = _kernel()


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b, for a float64 square matrix ``a`` (n, n) and vector ``b`` (n,):
    ``np.linalg.solve(a, b)`` bit for bit (module doc)."""
    if (_SOLVE1 is None or a.dtype != np.float64 or b.dtype != np.float64
            or b.ndim != 1 or a.shape != (len(b), len(b))):
        return np.linalg.solve(a, b)
    x = _SOLVE1(a, b, signature="dd->d")
    for value in x.tolist():  # a few unknowns: plain floats beat an array reduction
        if not math.isfinite(value):
            return np.linalg.solve(a, b)
    return x
