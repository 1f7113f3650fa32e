"""The VFDM on a UR10e and its rail (paper Eqs. 9-13 on the 7-joint chain of app/sim/rail.py).

The same cycle as app/sim/vfdm.py's, on the chain ``q = [s, q1 … q6]`` in the base frame
B0 (the carriage at s = 0):

1. forward kinematics of the virtual chain (:func:`app.sim.rail.chain_frames`);
2. Eq. 13 on the clamped pose error, plus the target-velocity feedforward; its D term
   (``kd_lin``, ``kd_rot``) on the change of the error over an internal step, ``K_D (e −
   e_prev) / h``, as app/sim/vfdm.py has it (0 in Table 1);
3. Eq. 9: ``τ = Jᵀ f`` with the 6x7 Jacobian (the rail's column ``[a; 0]`` first);
4. Eq. 10: ``q̈ = H⁻¹ τ`` on the chain's H (the carriage's conditioned mass and Table 1's
   arm), plus the posture spring's acceleration in J's null space, which moves carriage
   and arm against each other with the TCP held so that the arm returns to its posture
   and the rail carries the gross motion;
5. semi-implicit Euler with the velocity damping, each joint's speed limit spread over the
   internal steps, the joint-limit clamp of the arm and the travel clamp of the carriage
   (at a travel end the carriage stops and the arm takes the rest, as far as it reaches).

Then the cycle's step is held within the servos' speed and acceleration limits (the arm's
and the rail's) as app/sim/vfdm.py's limit_joint_step does: a step beyond a speed limit is
scaled down as a whole, its change from the last step clamped per joint.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.config import RailConfig, VfdmConfig
from app.sim.rail import (
    N_CHAIN,
    RailArm,
    add_posture_acceleration,
    chain_frames,
    chain_inertia,
    chain_jacobian_at,
    chain_tcp_pose,
    null_vector_of,
    rail_arm,
    rail_axis_B,
)
from app.sim.ur10e import POSITION_LIMIT_RAD
from app.sim.vfdm import (
    UR10E_LIMITS_500HZ,
    JointLimits,
    cholesky_solve,
    clamped_pose_error,
    pd_wrench,
    target_feedforward,
)

__all__ = ["RailVfdm", "chain_limit_step", "rail_vfdm_steps"]


@njit(cache=True, fastmath=False)
def rail_vfdm_steps(q, qd, e_prev, state, last_e, Rt, pt, iterations, axis, pR, pp, mass,
                    lever, Icom, tR, tp, armature, rail_mass, posture, stiffness, kp, kdh,
                    use_kd, ff, keep, h, q_lo, q_hi, max_lin, max_rot, dq_lo, dq_hi):
    """Run ``iterations`` internal VFDM steps on the chain in place on q, qd (7,), e_prev,
    last_e (6,) (module doc, steps 1-5). kdh (6,): the D gains over h, acting when use_kd
    and state[0] is 1.0 (e_prev holds the last step's error; a reset clears it). q_lo, q_hi
    (7,): the travel (metres) and the arm's joint limits; dq_lo, dq_hi (7,): the range of
    each virtual joint's move in one internal step (:meth:`RailVfdm.step_window`)."""
    n = N_CHAIN
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    T_B_C = np.empty((4, 4))
    J = np.empty((6, n))
    H = np.zeros((n, n))
    e = np.empty(6)
    f = np.empty(6)
    tau = np.empty(n)
    qdd = np.empty(n)
    Rerr, work, L, y = np.empty((3, 3)), np.empty((14, 3)), np.zeros((n, n)), np.empty(n)
    nv, M = np.empty(n), np.empty((6, 6))
    for _ in range(iterations):
        chain_frames(q, axis, pR, pp, tR, tp, R, p, T_B_C)
        clamped_pose_error(Rt, pt, T_B_C, max_lin, max_rot, e, Rerr)
        pd_wrench(e, kp, ff, kdh, use_kd, state, e_prev, last_e, f)
        chain_jacobian_at(R, p, T_B_C[:3, 3], axis, J)
        for i in range(n):
            t = 0.0
            for a in range(6):
                t += J[a, i] * f[a]
            tau[i] = t
        chain_inertia(R, p, axis, mass, lever, Icom, armature, rail_mass, H, work)
        cholesky_solve(H, tau, qdd, L, y)
        add_posture_acceleration(q, H, J, posture, stiffness, qdd, nv, M)
        for i in range(n):
            qd[i] = (qd[i] + h * qdd[i]) * keep
        # the carriage held in its window by a move along J's null space: the TCP's
        # velocity stays, the arm takes what the carriage may not do
        v0 = min(max(qd[0], dq_lo[0] / h), dq_hi[0] / h)
        if v0 != qd[0]:
            null_vector_of(J, nv, M)
            nn = 0.0
            for i in range(n):
                nn += nv[i] * nv[i]
            if nv[0] * nv[0] > 1e-12 * nn:
                g = (v0 - qd[0]) / nv[0]
                for i in range(n):
                    qd[i] += g * nv[i]
            qd[0] = v0
        for i in range(n):
            if h * qd[i] > dq_hi[i]:
                qd[i] = dq_hi[i] / h
            elif h * qd[i] < dq_lo[i]:
                qd[i] = dq_lo[i] / h
            q[i] += h * qd[i]
            if q[i] < q_lo[i]:
                q[i], qd[i] = q_lo[i], 0.0
            elif q[i] > q_hi[i]:
                q[i], qd[i] = q_hi[i], 0.0


@njit(cache=True, fastmath=False)
def chain_limit_step(q, qd, q0, step_prev, max_step, max_change, q_lo, q_hi):
    """app.sim.vfdm.limit_joint_step on any number of joints with per-joint bounds: the
    cycle's step ``q − q0`` scaled down as a whole to the speed limits (max_step), each
    joint's change of step clamped to ± max_change, q kept within [q_lo, q_hi]; qd scaled
    with its joint's step where a limit acts. Returns the uniform scale (1.0: none)."""
    n = q.shape[0]
    s = 1.0
    for j in range(n):
        d = abs(q[j] - q0[j])
        if d * s > max_step[j]:
            s = max_step[j] / d
    acts = s < 1.0
    for j in range(n):
        d = (q[j] - q0[j]) * s
        if d < step_prev[j] - max_change[j] or d > step_prev[j] + max_change[j]:
            acts = True
    if not acts:
        for j in range(n):
            step_prev[j] = q[j] - q0[j]
        return 1.0
    for j in range(n):
        d = q[j] - q0[j]
        dc = min(max(d * s, step_prev[j] - max_change[j]), step_prev[j] + max_change[j])
        dc = min(max(dc, -max_step[j]), max_step[j])
        ratio = dc / d if d != 0.0 else 0.0
        qd[j] *= min(max(ratio, 0.0), 1.0)
        q[j] = min(max(q0[j] + dc, q_lo[j]), q_hi[j])
        if q[j] == q_lo[j] or q[j] == q_hi[j]:
            qd[j] = 0.0
        step_prev[j] = q[j] - q0[j]
    return s


class RailVfdm:
    """One robot-on-rail's VFDM solver: ``reset(q)`` once, then ``solve(T_B0_C_target)`` per
    cycle; q and the set-points are ``[s, q1 … q6]`` (metres, radians), targets in B0.

    ``T_W_B0``: the base's pose with the carriage at s = 0 (the robot's base_position_m and
    base_attitude_wxyz); ``posture``: the arm's comfortable posture (default: the rail's
    posture_rad, or without one the arm's joints in q0). ``limits``: the arm servo's
    (default: the UR10e's at 500 Hz); the rail's come from ``rail``.
    """

    def __init__(self, cfg: VfdmConfig, rail: RailConfig, T_W_B0: np.ndarray,
                 T_F_C: np.ndarray, q0: np.ndarray, posture: np.ndarray | None = None,
                 limits: JointLimits = UR10E_LIMITS_500HZ) -> None:
        self.cfg, self.rail = cfg, rail
        self.T_F_C = np.array(T_F_C, dtype=float)
        self.arm: RailArm = rail_arm(cfg, self.T_F_C, rail_axis_B(rail, T_W_B0),
                                     rail.virtual_mass_kg)
        if posture is None:  # the configured one, or where the arm starts
            posture = np.asarray(q0, dtype=float)[1:] if rail.posture_rad is None \
                else rail.posture_rad
        self.posture = np.array(posture, dtype=float)
        f, dt, N, h = cfg.limit_fraction, limits.cycle_s, cfg.iterations, cfg.internal_dt_s
        speed = np.concatenate([[rail.speed_limit_mps], limits.speed_radps])
        accel = np.concatenate([[rail.accel_limit_mps2], np.full(6, limits.accel_radps2)])
        self._max_step = f * speed * dt
        self._max_change = f * accel * dt * dt
        self._dq_hi = self._max_step / N
        self._dq_lo = -self._dq_hi
        self._q_lo = np.array([rail.travel_m[0]] + [-POSITION_LIMIT_RAD] * 6)
        self._q_hi = np.array([rail.travel_m[1]] + [POSITION_LIMIT_RAD] * 6)
        s = cfg.error_scale
        self._kp = s * np.array([cfg.kp_lin] * 3 + [cfg.kp_rot] * 3)
        self._kd_over_h = s * np.array([cfg.kd_lin] * 3 + [cfg.kd_rot] * 3) / h
        self._use_kd = bool(np.any(self._kd_over_h))
        self._e_prev = np.zeros(6)
        self._keep = 1.0 - cfg.damping if cfg.velocity_mode == "damped" else 1.0
        lam = np.array([cfg.end_mass_kg] * 3 + [cfg.end_inertia_kgm2] * 3)
        drag = (1.0 - self._keep) / (self._keep * h) if cfg.velocity_feedforward else 0.0
        # (no drag, no feedforward: velocity_mode "reset" or damping 0)
        self._ff_gain = lam * drag / (N * h)
        self._ff = np.zeros(6)
        self._R_prev, self._p_prev = np.eye(3), np.zeros(3)
        self._has_prev = np.zeros(2)  # [an e_prev (D term), a last target (feedforward)]
        self._step_prev = np.zeros(N_CHAIN)
        self.last_scale = 1.0
        self.last_error = np.zeros(6)
        self.reset(q0)

    def reset(self, q: np.ndarray) -> None:
        """Put the virtual chain at ``q`` (clipped to the travel and joint limits), at rest."""
        self.q = np.clip(np.array(q, dtype=float), self._q_lo, self._q_hi)
        self.qd = np.zeros(N_CHAIN)
        self._has_prev[:] = 0.0
        self._step_prev[:] = 0.0

    def tcp_pose(self) -> np.ndarray:
        """Virtual TCP pose ``T_B0_C`` at the current virtual q."""
        return chain_tcp_pose(self.arm, self.q)

    def step_window(self) -> None:
        """The carriage's move per internal step this cycle: its cycle step within the
        acceleration limit of the last one (step_prev ± max_change) and the speed limit,
        and short enough to stop before a travel end at the acceleration limit (steps x,
        x − c, x − 2c … cover at most x²/2c + x/2 + c/8 of travel, c = max_change). Held
        inside the internal steps (by a move along J's null space), the arm makes up for it
        in the same cycle, where a clamp after them would leave the TCP off target; the
        speed limit alone bounds the arm's joints."""
        N, c = self.cfg.iterations, self._max_change[0]
        prev, vmax = self._step_prev[0], self._max_step[0]
        lo, hi = max(-vmax, prev - c), min(vmax, prev + c)
        s = self.q[0]
        for room, sign in ((self._q_hi[0] - s, 1.0), (s - self._q_lo[0], -1.0)):
            x = -0.5 * c + math.sqrt(0.25 * c * c + 2.0 * c * max(room - 0.125 * c, 0.0))
            if sign > 0.0:
                hi = max(min(hi, x), lo)
            else:
                lo = min(max(lo, -x), hi)
        self._dq_lo[0], self._dq_hi[0] = lo / N, hi / N

    def solve(self, T_B0_C_target: np.ndarray) -> np.ndarray:
        """One control cycle; returns the set-points ``[s, q1 … q6]``."""
        cfg, a = self.cfg, self.arm
        if cfg.velocity_mode == "reset":
            self.qd[:] = 0.0  # Eq. 11: each cycle starts at rest
        T = np.asarray(T_B0_C_target, dtype=float)
        Rt, pt = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
        target_feedforward(Rt, pt, self._R_prev, self._p_prev, self._has_prev, self._ff_gain,
                           cfg.max_error_lin_m, cfg.max_error_rot_rad, self._ff)
        self.step_window()
        q0 = self.q.copy()
        last_e = np.empty(6)
        rail_vfdm_steps(self.q, self.qd, self._e_prev, self._has_prev, last_e, Rt, pt,
                        cfg.iterations, a.axis, a.pR, a.pp, a.mass, a.lever, a.Icom, a.tR,
                        a.tp, a.armature, a.rail_mass, self.posture,
                        self.rail.posture_stiffness_Nm_per_rad, self._kp, self._kd_over_h,
                        self._use_kd, self._ff, self._keep, cfg.internal_dt_s, self._q_lo,
                        self._q_hi, cfg.max_error_lin_m, cfg.max_error_rot_rad, self._dq_lo,
                        self._dq_hi)
        self.last_scale = chain_limit_step(self.q, self.qd, q0, self._step_prev,
                                           self._max_step, self._max_change, self._q_lo,
                                           self._q_hi)
        self.last_error = last_e
        return self.q.copy()
