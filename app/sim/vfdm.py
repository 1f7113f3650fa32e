"""VFDM Cartesian motion controller (paper Section 3, Eqs. 10-13, Table 1).

A *virtual* UR10e with the real arm's kinematics and a conditioned inertia is pulled
towards the target TCP pose by a Cartesian PD "force" (Eq. 13). Its forward dynamics
(Eq. 10, no gravity, no Coriolis) are integrated for a few internal steps per control
cycle; the virtual joint positions are the set-points for the real arm. No Jacobian
inverse appears anywhere: near a singularity the virtual arm just moves slowly in the
directions it cannot move well, instead of demanding unbounded joint speeds.

Conditioned inertia: every link carries ``link_mass_kg`` and ``link_inertia_ratio *
end_inertia_kgm2 * I3`` at its joint origin; the last link carries ``end_mass_kg`` and
``end_inertia_kgm2 * I3`` with its centre of mass at the TCP. Then ``H ~= J^T diag(m_e,
m_e, m_e, I_e, I_e, I_e) J`` plus a tiny regularising term, so the operational-space
inverse inertia ``J H^-1 J^T`` (Eq. 12) is ~diagonal and the same at every posture.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from app.config import VfdmConfig
from app.sim.ur10e import N_JOINTS, POSITION_LIMIT_RAD, LinkInertias, T_J6_F_dh, build_model

try:  # the compiled inner loop (numba); the Python path below stays the reference
    from app.sim.vfdm_kernel import solve_compiled as _solve_compiled
except ImportError:  # pragma: no cover - numba missing
    _solve_compiled = None

__all__ = ["Vfdm", "clamp_norm", "pose_error", "vfdm_kernel_available", "virtual_inertias"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def vfdm_kernel_available() -> bool:
    """Whether the compiled VFDM path (numba) can run."""
    return _solve_compiled is not None


def pose_error(T_B_target: np.ndarray, T_B_C: np.ndarray) -> np.ndarray:
    """Pose error ``e = [p* - p ; log(R* R^T)]`` in base axes (the e of Eq. 13)."""
    e = np.empty(6)
    e[:3] = T_B_target[:3, 3] - T_B_C[:3, 3]
    e[3:] = pin.log3(T_B_target[:3, :3] @ T_B_C[:3, :3].T)
    return e


def clamp_norm(v: np.ndarray, max_norm: float) -> np.ndarray:
    """``v`` scaled down (in place) so that its norm is at most ``max_norm``."""
    n = float(np.sqrt(v @ v))
    if n > max_norm:
        v *= max_norm / n
    return v


def virtual_inertias(cfg: VfdmConfig, T_F_C: np.ndarray) -> LinkInertias:
    """Table 1 conditioned inertia: small links, last link ``m_e, I_e`` centred at the TCP."""
    I_l = cfg.link_inertia_ratio * cfg.end_inertia_kgm2 * np.eye(3)
    small = pin.Inertia(cfg.link_mass_kg, np.zeros(3), I_l)
    p_J6_C = (T_J6_F_dh() @ T_F_C)[:3, 3]
    end = pin.Inertia(cfg.end_mass_kg, p_J6_C, cfg.end_inertia_kgm2 * np.eye(3))
    return LinkInertias((small,) * (N_JOINTS - 1) + (end,))


class Vfdm:
    """One robot's VFDM solver: ``reset(q)`` once, then ``solve(T_B_C_target)`` per cycle."""

    def __init__(
        self, cfg: VfdmConfig, T_F_C: np.ndarray, q0_rad: np.ndarray | None = None
    ) -> None:
        self.cfg = cfg
        self.T_F_C = np.array(T_F_C, dtype=float)
        self.model = build_model(virtual_inertias(cfg, self.T_F_C), self.T_F_C, gravity=False)
        self.data = self.model.createData()
        self.tcp_id = self.model.getFrameId("tcp")
        h = cfg.internal_dt_s
        self._h = h
        # Eq. 13 gains, already multiplied by the error scale; D acts on (e - e_prev) / h.
        s = cfg.error_scale
        self._kp = s * np.array([cfg.kp_lin] * 3 + [cfg.kp_rot] * 3)
        self._kd_over_h = s * np.array([cfg.kd_lin] * 3 + [cfg.kd_rot] * 3) / h
        self._use_kd = bool(np.any(self._kd_over_h))
        self._keep = 1.0 - cfg.damping if cfg.velocity_mode == "damped" else 1.0
        self._q_lim = POSITION_LIMIT_RAD
        self._zero_v = np.zeros(N_JOINTS)
        self.q_rad = np.zeros(N_JOINTS)
        self.qd_radps = np.zeros(N_JOINTS)
        self._e_prev: np.ndarray | None = None
        self.last_error = np.zeros(6)
        """Clamped pose error [m; rad] seen by the last internal step (before its move)."""
        self.use_kernel = _solve_compiled is not None
        """Run solve() through app.sim.vfdm_kernel (same results; ~26x faster)."""
        self.reset(np.zeros(N_JOINTS) if q0_rad is None else q0_rad)

    def reset(self, q_rad: np.ndarray) -> None:
        """Put the virtual arm at ``q_rad``, at rest."""
        self.q_rad = np.clip(np.array(q_rad, dtype=float), -self._q_lim, self._q_lim)
        self.qd_radps[:] = 0.0
        self._e_prev = None

    def tcp_pose(self) -> np.ndarray:
        """Virtual TCP pose ``T_B_C`` at the current virtual ``q``."""
        pin.framesForwardKinematics(self.model, self.data, self.q_rad)
        return self.data.oMf[self.tcp_id].homogeneous

    def solve(self, T_B_C_target: np.ndarray) -> np.ndarray:
        """One control cycle: ``iterations`` internal steps; returns the joint set-points."""
        if self.use_kernel:
            return _solve_compiled(self, T_B_C_target)
        if self.cfg.velocity_mode == "reset":
            self.qd_radps[:] = 0.0  # the paper's "each cycle starts at rest" (Eq. 11)
        for _ in range(self.cfg.iterations):
            self._step(T_B_C_target)
        return self.q_rad.copy()

    def _step(self, T_B_C_target: np.ndarray) -> None:
        """One internal step: Eq. 13 force, Eq. 10 acceleration, semi-implicit Euler."""
        model, data, cfg, h = self.model, self.data, self.cfg, self._h
        q = self.q_rad
        pin.computeJointJacobians(model, data, q)  # also forward kinematics
        oMc = pin.updateFramePlacement(model, data, self.tcp_id)
        J = pin.getFrameJacobian(model, data, self.tcp_id, _LWA)
        e = np.empty(6)
        e[:3] = clamp_norm(T_B_C_target[:3, 3] - oMc.translation, cfg.max_error_lin_m)
        e[3:] = clamp_norm(
            pin.log3(T_B_C_target[:3, :3] @ oMc.rotation.T), cfg.max_error_rot_rad
        )
        f = self._kp * e  # Eq. 13
        if self._use_kd and self._e_prev is not None:
            f += self._kd_over_h * (e - self._e_prev)
        self._e_prev = e
        self.last_error = e
        qdd = self.joint_acceleration(q, J.T @ f)
        qd = self.qd_radps
        qd += h * qdd
        qd *= self._keep
        q += h * qd
        if np.any(np.abs(q) > self._q_lim):
            hit = np.abs(q) > self._q_lim
            np.clip(q, -self._q_lim, self._q_lim, out=q)
            qd[hit] = 0.0

    def joint_acceleration(self, q_rad: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Eq. 10: ``qdd = H(q)^-1 tau`` with ``tau = J^T f`` (Eq. 9).

        ABA with zero velocity on the gravity-free virtual model returns exactly
        ``H^-1 tau`` (the CRBA inertia; Coriolis and gravity terms vanish) in O(n),
        without forming or factorising H.
        """
        return pin.aba(self.model, self.data, q_rad, self._zero_v, tau)
