"""The flying start: the arms run up to the satellites' initial motion before t = 0.

A satellite that starts moving (a collision's 8 cm/s, a tumbling target's spin) would
otherwise be carried by an arm that starts at rest: at t = 0 the mockup lags its
satellite and catches up with a jolt that no orbit has (a 0.13 m/s overshoot in the
first 35 ms of the collision). A lab starts the arm on the move instead; so does this
start-up. Over ``[loop] run_up_s`` = T before t = 0 each satellite's pose follows

    p(τ) = p0 + v0 · (T·S(x) − T/2),      q(τ) = q0 ⊗ Exp(ω0 · (T·S(x) − T/2)),
    x = (τ + T) / T ∈ [0, 1],   S(x) = x³ − x⁴/2,

whose rate is v0 · s(x) with s(x) = S'(x) = 3x² − 2x³: from rest (s = s' = 0 at x = 0)
to the initial velocity, at zero acceleration, at t = 0 (s = 1, s' = 0 at x = 1), where
the pose is the initial one. The run-up covers v0·T/2 and peaks at 1.5·|v0|/T of
acceleration. v0 is the velocity in R, ω0 the body's rate relative to R in its own axes
(the ODS's ω is relative to inertial space: the difference is the orbit's rate).
"""

from __future__ import annotations

import numpy as np

from app.sim.orbital import POS, QUAT, VEL
from app.sim.rotations import quat_mul, quat_normalize, quat_to_rotvec, rotvec_to_quat

__all__ = ["relative_rates", "run_up_state", "runs_up"]


def _progress(tau_s: float, run_up_s: float) -> float:
    """T·S(x) − T/2: the signed distance along the initial motion, per unit velocity."""
    x = min(1.0, max(0.0, (tau_s + run_up_s) / run_up_s))
    return run_up_s * (x**3 - 0.5 * x**4) - 0.5 * run_up_s


def relative_rates(y0: np.ndarray, y_after: np.ndarray, dt_s: float) -> np.ndarray:
    """(N, 3) body rates relative to R over dt_s, from two ODS states: the rotation
    q0⁻¹ ⊗ q1 as a rotation vector, per second."""
    rates = np.empty((len(y0), 3))
    for i in range(len(y0)):
        q0_inv = y0[i, QUAT] * np.array([1.0, -1.0, -1.0, -1.0])
        rates[i] = quat_to_rotvec(quat_mul(q0_inv, y_after[i, QUAT])) / dt_s
    return rates


def runs_up(y0: np.ndarray, omega_rel_B: np.ndarray) -> bool:
    """Whether any satellite starts moving (a run-up is needed)."""
    return bool(np.any(np.abs(y0[:, VEL]) > 1e-12) or np.any(np.abs(omega_rel_B) > 1e-12))


def run_up_state(y0: np.ndarray, omega_rel_B: np.ndarray, run_up_s: float,
                 tau_s: float) -> np.ndarray:
    """The state at τ = tau_s ∈ [−T, 0] of the run-up to y0 (module docstring); its
    velocity and rate are the profile's, the rest of y0 as it is."""
    y = y0.copy()
    along = _progress(tau_s, run_up_s)
    x = min(1.0, max(0.0, (tau_s + run_up_s) / run_up_s))
    rate = 3 * x**2 - 2 * x**3
    y[:, POS] = y0[:, POS] + y0[:, VEL] * along
    y[:, VEL] = y0[:, VEL] * rate
    for i in range(len(y0)):
        y[i, QUAT] = quat_normalize(quat_mul(y0[i, QUAT], rotvec_to_quat(omega_rel_B[i] * along)))
    return y
