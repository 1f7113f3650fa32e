"""Baseline differential-IK solvers, with the same per-cycle interface as :class:`Vfdm`.

Each solver keeps its own joint estimate ``q_rad``: ``reset(q)`` once, then
``solve(T_B_C_target) -> q_setpoint`` once per control cycle (one IK update per cycle,
as a plain user would run them in a servo loop). The pose error is the same as VFDM's
(``e = [p* - p ; log(R* R^T)]``, base axes) but unclamped, and nothing limits the joint
step: these are the methods as commonly written, to be compared against VFDM.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from app.sim.ur10e import tcp_jacobian_B, tcp_pose_B
from app.sim.vfdm import pose_error

__all__ = [
    "CartesianSolver",
    "DampedLeastSquaresIK",
    "JacobianTransposeIK",
    "PseudoInverseIK",
]


class CartesianSolver(Protocol):
    """Turns a TCP target pose in B into joint set-points, once per control cycle."""

    q_rad: np.ndarray

    def reset(self, q_rad: np.ndarray) -> None: ...

    def solve(self, T_B_C_target: np.ndarray) -> np.ndarray: ...


class _DiffIK:
    """Shared state: the TCP mounting and the current joint estimate."""

    def __init__(self, T_F_C: np.ndarray, q0_rad: np.ndarray | None = None) -> None:
        self.T_F_C = np.array(T_F_C, dtype=float)
        self.q_rad = np.zeros(6) if q0_rad is None else np.array(q0_rad, dtype=float)

    def reset(self, q_rad: np.ndarray) -> None:
        self.q_rad = np.array(q_rad, dtype=float)

    def solve(self, T_B_C_target: np.ndarray) -> np.ndarray:
        J = tcp_jacobian_B(self.q_rad, self.T_F_C)
        e = pose_error(T_B_C_target, tcp_pose_B(self.q_rad, self.T_F_C))
        self.q_rad = self.q_rad + self._dq(J, e)
        return self.q_rad.copy()

    def _dq(self, J: np.ndarray, e: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class PseudoInverseIK(_DiffIK):
    """``dq = gain * J^+ e`` (Moore-Penrose pseudo-inverse, numpy's default cut-off)."""

    def __init__(self, T_F_C, q0_rad=None, gain: float = 1.0) -> None:
        super().__init__(T_F_C, q0_rad)
        self.gain = gain

    def _dq(self, J: np.ndarray, e: np.ndarray) -> np.ndarray:
        return self.gain * (np.linalg.pinv(J) @ e)


class DampedLeastSquaresIK(_DiffIK):
    """``dq = J^T (J J^T + lambda^2 I)^-1 e`` with a fixed damping ``lambda``."""

    def __init__(self, T_F_C, q0_rad=None, damping: float = 0.05) -> None:
        super().__init__(T_F_C, q0_rad)
        self.damping = damping

    def _dq(self, J: np.ndarray, e: np.ndarray) -> np.ndarray:
        A = J @ J.T + self.damping**2 * np.eye(6)
        return J.T @ np.linalg.solve(A, e)


class JacobianTransposeIK(_DiffIK):
    """``dq = alpha * J^T e`` (gradient step on the squared pose error).

    The default ``alpha = 0.2 ~ 1 / sigma_max(J)^2`` (sigma_max ~ 2.2 for the UR10e TCP
    Jacobian) is about the largest step that stays stable in every posture.
    """

    def __init__(self, T_F_C, q0_rad=None, alpha: float = 0.2) -> None:
        super().__init__(T_F_C, q0_rad)
        self.alpha = alpha

    def _dq(self, J: np.ndarray, e: np.ndarray) -> np.ndarray:
        return self.alpha * (J.T @ e)
