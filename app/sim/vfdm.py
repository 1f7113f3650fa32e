"""VFDM Cartesian motion controller (paper Section 3, Eqs. 9-13, Table 1), compiled.

A *virtual* UR10e with the real arm's kinematics and a conditioned inertia is pulled
towards the target TCP pose by a Cartesian PD "force" (Eq. 13). Its forward dynamics
(Eq. 10, no gravity, no Coriolis) are integrated for a few internal steps per control
cycle; the virtual joint positions are the set-points for the real arm. No Jacobian
inverse appears anywhere: near a singularity the virtual arm just moves slowly in the
directions it cannot move well, instead of demanding unbounded joint speeds.

Conditioned inertia (Table 1): every link carries ``link_mass_kg`` and ``link_inertia_ratio
* end_inertia_kgm2 * I3`` at its joint origin; the last link carries ``end_mass_kg`` and
``end_inertia_kgm2 * I3`` with its centre of mass at the TCP. Then ``H ≈ Jᵀ diag(m_e, m_e,
m_e, I_e, I_e, I_e) J`` plus a tiny regularising term, so the operational-space inverse
inertia ``J H⁻¹ Jᵀ`` (Eq. 12) is nearly diagonal and the same at every posture.

One internal step (:func:`vfdm_steps` runs ``iterations`` of them in machine code):

1. forward kinematics of the virtual arm: joint frames and the TCP pose;
2. Eq. 13: ``f = K_P e + K_D ė`` on the clamped pose error ``e = [p* − p; log(R* Rᵀ)]``;
3. Eq. 9: ``τ = Jᵀ f`` with the TCP Jacobian in base axes;
4. Eq. 10: ``q̈ = H(q)⁻¹ τ``, H from the composite-rigid-body algorithm plus the joints'
   armature, solved by Cholesky;
5. semi-implicit Euler with the velocity damping (or the per-cycle reset of Eq. 11), and
   the joint-limit clamp.

Armature (not in Table 1): near a singularity ``Jᵀ f`` has a small component along the
direction the arm can barely move, but H, whose regularising part (Table 1's 10 g links)
is tiny, is nearly as small there, so q̈ along it is large: the light virtual wrist swings
joints 4 and 6 against each other (≈ 0.5 rad) as q5 passes zero, and the TCP leaves the path
by 22 mm. With ``H = Jᵀ Λ J + a I`` the response along a direction of singular value σ is
``σ / (Λ σ² + a)``: damped least squares with ``λ² = a / Λ``. ``joint_armature_kgm2`` =
0.0025 with Table 1's Λ = 1 is DLS's λ = 0.05 (a virtual rotor inertia on each joint); away
from singularities it changes H by 0.25 % (smooth tracking 2 % slower).

After the iterations, the cycle's joint step is held within the servo's speed and
acceleration limits (:func:`limit_joint_step`): near a singularity the virtual arm, light
as it is, would ask some joints for more than the real arm may do, and the real
controller answers that with a protective stop. The step is scaled down as a whole, so the
motion keeps its direction (the UR controller's own speed scaling), the virtual arm is
put where the set-point sends the real one, and the Cartesian error left over is made up
in the next cycles, once out of the singular region.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from app.config import ServoConfig, VfdmConfig
from app.sim.ur10e import (
    N_JOINTS,
    POSITION_LIMIT_RAD,
    T_J6_F,
    end_frame,
    fk_joints,
    jacobian_at,
    joint_placements,
    tcp_pose_B,
)

__all__ = [
    "JointLimits",
    "VirtualArm",
    "Vfdm",
    "joint_acceleration",
    "limit_joint_step",
    "vfdm_cycle",
    "vfdm_cycle_packed",
    "vfdm_constants",
    "log3",
    "pose_error",
    "virtual_arm",
]


class VirtualArm(NamedTuple):
    """The virtual model's numbers, as the kernels take them."""

    pR: np.ndarray
    """(6, 3, 3) joint placement rotations."""
    pp: np.ndarray
    """(6, 3) joint placement translations."""
    mass: np.ndarray
    """(6,) link masses [kg]."""
    lever: np.ndarray
    """(6, 3) link centres of mass in their joint frames [m]."""
    Icom: np.ndarray
    """(6, 3, 3) link inertias about their centres of mass [kg m²]."""
    tR: np.ndarray
    """(3, 3) rotation of the TCP in the frame of joint 6."""
    tp: np.ndarray
    """(3,) position of the TCP in the frame of joint 6."""
    armature: float
    """Rotor inertia of every joint [kg m²], added to H's diagonal."""


class JointLimits(NamedTuple):
    """What the set-points may ask of the real arm: the servo's limits and the cycle time."""

    speed_radps: np.ndarray
    """(6,) joint speed limits."""
    accel_radps2: float
    cycle_s: float

    @classmethod
    def of_servo(cls, cfg: ServoConfig, cycle_s: float) -> JointLimits:
        return cls(np.array(cfg.speed_limits_radps, dtype=float), cfg.accel_limit_radps2,
                   float(cycle_s))


UR10E_LIMITS_500HZ = JointLimits.of_servo(ServoConfig(), 1.0 / 500.0)
"""The UR10e's data-sheet speeds, the default servo's 40 rad/s², the RTDE's 500 Hz."""


def virtual_arm(cfg: VfdmConfig, T_F_C: np.ndarray) -> VirtualArm:
    """Table 1's conditioned inertia on the UR10e chain: small links, ``m_e, I_e`` at the TCP."""
    pR, pp = joint_placements()
    T_J6_C = T_J6_F @ np.asarray(T_F_C, dtype=float)
    mass = np.full(N_JOINTS, float(cfg.link_mass_kg))
    mass[-1] = cfg.end_mass_kg
    lever = np.zeros((N_JOINTS, 3))
    lever[-1] = T_J6_C[:3, 3]
    Icom = np.tile(cfg.link_inertia_ratio * cfg.end_inertia_kgm2 * np.eye(3), (N_JOINTS, 1, 1))
    Icom[-1] = cfg.end_inertia_kgm2 * np.eye(3)
    return VirtualArm(pR, pp, mass, lever, Icom, np.ascontiguousarray(T_J6_C[:3, :3]),
                      np.ascontiguousarray(T_J6_C[:3, 3]), float(cfg.joint_armature_kgm2))


# --- kernels ------------------------------------------------------------------------------


@njit(cache=True, fastmath=False)
def log3(R):
    """SO(3) logarithm (rotation vector) of a rotation matrix, angle in [0, π]."""
    out = np.empty(3)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    cth = 0.5 * (tr - 1.0)
    if cth > 1.0:
        cth = 1.0
    elif cth < -1.0:
        cth = -1.0
    theta = math.acos(cth)
    vx, vy, vz = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    if theta < 1e-4:
        k = 0.5 + theta * theta / 12.0
        out[0], out[1], out[2] = k * vx, k * vy, k * vz
    elif math.pi - theta < 1e-3:
        # near pi: axis from the symmetric part, sign from the skew part
        for a in range(3):
            d = (R[a, a] - cth) / (1.0 - cth)
            out[a] = math.sqrt(d if d > 0.0 else 0.0)
        sk = (vx, vy, vz)
        big = 0
        for a in range(1, 3):
            if out[a] > out[big]:
                big = a
        if sk[big] < 0.0:
            out[big] = -out[big]
        for a in range(3):
            if a != big:
                s = R[a, big] + R[big, a]
                out[a] = s / (2.0 * out[big] * (1.0 - cth))
        nrm = math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2)
        for a in range(3):
            out[a] *= theta / nrm
    else:
        k = theta / (2.0 * math.sin(theta))
        out[0], out[1], out[2] = k * vx, k * vy, k * vz
    return out


@njit(cache=True, fastmath=False, inline="always")
def _clamp(v, max_norm):
    """Scale the 3-vector v down (in place) to a norm of at most max_norm."""
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if n > max_norm:
        s = max_norm / n
        v[0] *= s
        v[1] *= s
        v[2] *= s


@njit(cache=True, fastmath=False, inline="always")
def clamped_pose_error(Rt, pt, T_B_C, max_lin, max_rot, e, Rerr):
    """e (6,) := [p* − p; log(R* Rᵀ)] (the e of Eq. 13), each part clamped in norm
    (Rerr: a (3, 3) scratch array)."""
    for a in range(3):
        e[a] = pt[a] - T_B_C[a, 3]
    _clamp(e[:3], max_lin)
    for a in range(3):
        for b in range(3):
            Rerr[a, b] = Rt[a, 0] * T_B_C[b, 0] + Rt[a, 1] * T_B_C[b, 1] + Rt[a, 2] * T_B_C[b, 2]
    w = log3(Rerr)
    _clamp(w, max_rot)
    e[3], e[4], e[5] = w[0], w[1], w[2]


@njit(cache=True, fastmath=False, inline="always")
def pd_wrench(e, kp, ff, kdh, use_kd, state, e_prev, last_e, f):
    """f (6,) := kp e + ff, plus kdh (e − e_prev) once e_prev holds the last step's error
    (use_kd and state[0] is 1.0): Eq. 13 with the target feedforward ff; then e_prev and
    last_e take e and state[0] is 1.0."""
    for a in range(6):
        f[a] = kp[a] * e[a] + ff[a]
    if use_kd and state[0] > 0.5:
        for a in range(6):
            f[a] += kdh[a] * (e[a] - e_prev[a])
    for a in range(6):
        e_prev[a] = e[a]
        last_e[a] = e[a]
    state[0] = 1.0


@njit(cache=True, fastmath=False, inline="always")
def joint_space_inertia(R, p, mass, lever, Icom, H, work):
    """H (6, 6) := the joint-space inertia (composite-rigid-body algorithm, world frame).

    Walking from the last link inwards, the composite body of links j..6 (mass, first
    moment, inertia about B's origin) gives ``H[i, j] = S_iᵀ I^c_j S_j`` for i ≤ j, with
    ``S_i = [p_i × z_i; z_i]`` the motion of joint i at B's origin. work: a (14, 3)
    scratch array.
    """
    n = 6
    vS, IO, RI, cw, s_acc = work[0:6], work[6:9], work[9:12], work[12], work[13]
    for a in range(3):
        s_acc[a] = 0.0
        for b in range(3):
            IO[a, b] = 0.0
    for i in range(n):  # S_i linear part at the origin: p_i x z_i
        vS[i, 0] = p[i, 1] * R[i, 2, 2] - p[i, 2] * R[i, 1, 2]
        vS[i, 1] = p[i, 2] * R[i, 0, 2] - p[i, 0] * R[i, 2, 2]
        vS[i, 2] = p[i, 0] * R[i, 1, 2] - p[i, 1] * R[i, 0, 2]
    m_acc = 0.0
    for j in range(n - 1, -1, -1):
        mj = mass[j]
        for a in range(3):  # the link's centre of mass in B
            ca = p[j, a]
            for b in range(3):
                ca += R[j, a, b] * lever[j, b]
            cw[a] = ca
        for a in range(3):  # RI = R_j I_com
            for b in range(3):
                RI[a, b] = (R[j, a, 0] * Icom[j, 0, b] + R[j, a, 1] * Icom[j, 1, b]
                            + R[j, a, 2] * Icom[j, 2, b])
        cc = cw[0] * cw[0] + cw[1] * cw[1] + cw[2] * cw[2]
        for a in range(3):  # parallel axis: inertia about B's origin
            for b in range(3):
                iw = RI[a, 0] * R[j, b, 0] + RI[a, 1] * R[j, b, 1] + RI[a, 2] * R[j, b, 2]
                IO[a, b] += iw - mj * cw[a] * cw[b]
            IO[a, a] += mj * cc
            s_acc[a] += mj * cw[a]
        m_acc += mj
        wx, wy, wz = R[j, 0, 2], R[j, 1, 2], R[j, 2, 2]
        vx, vy, vz = vS[j, 0], vS[j, 1], vS[j, 2]
        sx, sy, sz = s_acc[0], s_acc[1], s_acc[2]
        # the composite body's momentum under S_j: linear l, angular a (about B's origin)
        lx = m_acc * vx + (wy * sz - wz * sy)
        ly = m_acc * vy + (wz * sx - wx * sz)
        lz = m_acc * vz + (wx * sy - wy * sx)
        ax = (sy * vz - sz * vy) + IO[0, 0] * wx + IO[0, 1] * wy + IO[0, 2] * wz
        ay = (sz * vx - sx * vz) + IO[1, 0] * wx + IO[1, 1] * wy + IO[1, 2] * wz
        az = (sx * vy - sy * vx) + IO[2, 0] * wx + IO[2, 1] * wy + IO[2, 2] * wz
        for i in range(j + 1):
            hij = vS[i, 0] * lx + vS[i, 1] * ly + vS[i, 2] * lz
            hij += R[i, 0, 2] * ax + R[i, 1, 2] * ay + R[i, 2, 2] * az
            H[i, j] = hij
            H[j, i] = hij


@njit(cache=True, fastmath=False, inline="always")
def cholesky_solve(H, b, x, L, y):
    """x := H⁻¹ b for a symmetric positive definite n x n H (H = L Lᵀ, two triangular
    solves; n = 6 for the arm, 7 with its rail: app/sim/rail.py; L (n, n) and y (n,) are
    scratch arrays, L's upper triangle is never read)."""
    n = H.shape[0]
    for i in range(n):
        for k in range(i + 1):
            s = H[i, k]
            for m in range(k):
                s -= L[i, m] * L[k, m]
            if i == k:
                L[i, i] = math.sqrt(s)
            else:
                L[i, k] = s / L[k, k]
    for i in range(n):
        s = b[i]
        for m in range(i):
            s -= L[i, m] * y[m]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for m in range(i + 1, n):
            s -= L[m, i] * x[m]
        x[i] = s / L[i, i]


@njit(cache=True, fastmath=False)
def _joint_acceleration(q, tau, pR, pp, mass, lever, Icom, armature, qdd):
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    H = np.zeros((6, 6))
    fk_joints(q, pR, pp, R, p)
    joint_space_inertia(R, p, mass, lever, Icom, H, np.empty((14, 3)))
    for i in range(6):
        H[i, i] += armature
    cholesky_solve(H, tau, qdd, np.zeros((6, 6)), np.empty(6))


@njit(cache=True, fastmath=False)
def vfdm_cycle(q, qd, e_prev, state, last_e, Rt, pt, iterations,
               pR, pp, mass, lever, Icom, tR, tp, armature, kp, kdh, use_kd, ff, keep, h, qlim,
               max_lin, max_rot, max_dq, step_prev, max_step, max_change,
               ff_gain, R_prev, p_prev):
    """One control cycle: :func:`target_feedforward`, :func:`vfdm_steps`, then
    :func:`limit_joint_step` on the cycle's joint step; returns the uniform scale the speed
    limit put on it. state[1] is 1.0 when (R_prev, p_prev) hold the last cycle's target."""
    target_feedforward(Rt, pt, R_prev, p_prev, state, ff_gain, max_lin, max_rot, ff)
    q0 = q.copy()
    vfdm_steps(q, qd, e_prev, state, last_e, Rt, pt, iterations, pR, pp, mass, lever, Icom,
               tR, tp, armature, kp, kdh, use_kd, ff, keep, h, qlim, max_lin, max_rot, max_dq)
    return limit_joint_step(q, qd, q0, step_prev, max_step, max_change, qlim)


@njit(cache=True, fastmath=False)
def target_feedforward(Rt, pt, R_prev, p_prev, state, ff_gain, max_lin, max_rot, ff):
    """ff := the target-velocity feedforward wrench of this cycle (not in the paper).

    The target's motion since the last cycle, ``Δ = [p* − p*_prev; log(R* R*_prevᵀ)]``
    (each part clamped like Eq. 13's error), times ``ff_gain = Λ / (N h) · (1 − k) / (k h)``
    (Λ = diag(m_e, I_e), N internal steps of h, k = 1 − damping): the target's velocity in
    the virtual model's time, and the force that holds the damped virtual arm at that
    velocity (a joint moving at q̇ keeps q̇ when ``h k q̈ = (1 − k) q̇``). Without it the P
    term alone pulls against the damping's drag with a steady lag (24 mrad on the wrist
    path at Table 1's rotational gain). With ``H = Jᵀ Λ J`` it makes ``J q̇ = V*`` a steady
    state; the armature's part of H keeps it out of the directions a singular arm cannot
    move (no inverse of J). None on the first cycle after a reset (state[1] = 0); then
    (R_prev, p_prev) := the target.
    """
    if state[1] > 0.5:
        d = np.empty(3)
        for a in range(3):
            d[a] = pt[a] - p_prev[a]
        _clamp(d, max_lin)
        Rd = np.empty((3, 3))
        for a in range(3):
            for b in range(3):
                Rd[a, b] = (Rt[a, 0] * R_prev[b, 0] + Rt[a, 1] * R_prev[b, 1]
                            + Rt[a, 2] * R_prev[b, 2])
        w = log3(Rd)
        _clamp(w, max_rot)
        for a in range(3):
            ff[a] = ff_gain[a] * d[a]
            ff[3 + a] = ff_gain[3 + a] * w[a]
    else:
        for a in range(6):
            ff[a] = 0.0
    for a in range(3):
        p_prev[a] = pt[a]
        for b in range(3):
            R_prev[a, b] = Rt[a, b]
    state[1] = 1.0


@njit(cache=True, fastmath=False)
def vfdm_steps(q, qd, e_prev, state, last_e, Rt, pt, iterations,
               pR, pp, mass, lever, Icom, tR, tp, armature, kp, kdh, use_kd, ff, keep, h, qlim,
               max_lin, max_rot, max_dq):
    """Run ``iterations`` internal VFDM steps in place on q, qd, e_prev, last_e.

    ff (6,): a constant wrench added to Eq. 13's (the target-velocity feedforward, see
    Vfdm.solve).

    state[0] is 1.0 when e_prev holds a previous error (the D term is active), else 0.0.
    max_dq (6,): the largest move of each virtual joint in one internal step (the real
    joint's speed limit spread over the cycle's steps): the virtual joint's velocity is
    saturated there, and the following steps make up for it with the other joints.
    """
    n = 6
    R = np.empty((n, 3, 3))
    p = np.empty((n, 3))
    T_B_C = np.empty((4, 4))
    J = np.empty((6, n))
    H = np.zeros((n, n))
    e = np.empty(6)
    f = np.empty(6)
    tau = np.empty(n)
    qdd = np.empty(n)
    Rerr, work, L, y = np.empty((3, 3)), np.empty((14, 3)), np.zeros((n, n)), np.empty(n)
    for _ in range(iterations):
        # 1. forward kinematics of the virtual arm
        fk_joints(q, pR, pp, R, p)
        end_frame(R, p, tR, tp, T_B_C)
        # 2. Eq. 13 on the clamped pose error; the D term on (e - e_prev) / h
        clamped_pose_error(Rt, pt, T_B_C, max_lin, max_rot, e, Rerr)
        pd_wrench(e, kp, ff, kdh, use_kd, state, e_prev, last_e, f)
        # 3. Eq. 9: tau = J^T f
        jacobian_at(R, p, T_B_C[:3, 3], J)
        for i in range(n):
            t = 0.0
            for a in range(6):
                t += J[a, i] * f[a]
            tau[i] = t
        # 4. Eq. 10: qdd = H^-1 tau
        joint_space_inertia(R, p, mass, lever, Icom, H, work)
        for i in range(n):
            H[i, i] += armature
        cholesky_solve(H, tau, qdd, L, y)
        # 5. semi-implicit Euler, velocity damping, joint-limit clamp
        for i in range(n):
            qd[i] += h * qdd[i]
            qd[i] *= keep
            if abs(h * qd[i]) > max_dq[i]:  # the real joint's speed limit
                qd[i] = max_dq[i] / h if qd[i] > 0.0 else -max_dq[i] / h
            q[i] += h * qd[i]
        for i in range(n):
            if abs(q[i]) > qlim:
                q[i] = qlim if q[i] > 0 else -qlim
                qd[i] = 0.0


@njit(cache=True, fastmath=False)
def limit_joint_step(q, qd, q0, step_prev, max_step, max_change, qlim):
    """Hold the cycle's joint step ``q − q0`` within the speed and acceleration limits.

    max_step (6,): the largest step a joint may make in one cycle (speed limit × cycle);
    max_change (6,): the largest change of a joint's step from the last one, step_prev
    (acceleration limit × cycle²). A step beyond max_step is scaled down as a whole
    (direction kept); each joint's step is then clamped to step_prev ± max_change. q and the
    virtual velocity qd are changed in place only when a limit acts (qd in proportion to
    its joint's step, so that the virtual arm does not wind up); step_prev becomes the step
    commanded; no joint is taken beyond ±qlim (where its virtual velocity stops). Returns
    the uniform scale applied (1.0: no speed limit acted).
    """
    n = 6
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
        dc = d * s
        lo, hi = step_prev[j] - max_change[j], step_prev[j] + max_change[j]
        if dc < lo:
            dc = lo
        elif dc > hi:
            dc = hi
        if dc > max_step[j]:
            dc = max_step[j]
        elif dc < -max_step[j]:
            dc = -max_step[j]
        ratio = dc / d if d != 0.0 else 0.0
        qd[j] *= min(max(ratio, 0.0), 1.0)
        q[j] = q0[j] + dc
        if abs(q[j]) > qlim:
            q[j] = qlim if q[j] > 0.0 else -qlim
            qd[j] = 0.0
        step_prev[j] = q[j] - q0[j]
    return s


# --- one buffer of constants, one of state -------------------------------------------------

# Vfdm.constants: the virtual arm (VirtualArm), the gains and limits, then the scalars
_C_PR, _C_PP, _C_MASS, _C_LEVER, _C_ICOM, _C_TR, _C_TP = 0, 54, 72, 78, 96, 150, 159
_C_KP, _C_KDH, _C_FFG, _C_MAXDQ, _C_MAXSTEP, _C_MAXCHANGE, _C_SCALARS = (
    162, 168, 174, 180, 186, 192, 198)
N_CONSTANTS = _C_SCALARS + 10
"""Length of :attr:`Vfdm.constants`; its scalars, in order: armature, keep, h, qlim,
max_lin, max_rot, iterations, use_kd, reset_velocity, sync_to_measured (flags as 0.0/1.0)."""
# Vfdm's state: q, qd, e_prev, has_prev (2), step_prev, ff, R_prev (3, 3), p_prev
_X_Q, _X_QD, _X_EP, _X_HP, _X_SP, _X_FF, _X_RP, _X_PP = 0, 6, 12, 18, 20, 26, 32, 41
N_STATE = 44


@njit(cache=True, fastmath=False, inline="always")
def vfdm_constants(c):
    """The views and scalars of a :attr:`Vfdm.constants` buffer, in vfdm_cycle's order:
    (pR, pp, mass, lever, Icom, tR, tp, armature, kp, kdh, use_kd, keep, h, qlim, max_lin,
    max_rot, max_dq, max_step, max_change, ff_gain, iterations, reset_velocity, sync)."""
    s = _C_SCALARS
    return (c[_C_PR:_C_PP].reshape((6, 3, 3)), c[_C_PP:_C_MASS].reshape((6, 3)),
            c[_C_MASS:_C_LEVER], c[_C_LEVER:_C_ICOM].reshape((6, 3)),
            c[_C_ICOM:_C_TR].reshape((6, 3, 3)), c[_C_TR:_C_TP].reshape((3, 3)),
            c[_C_TP:_C_KP], c[s], c[_C_KP:_C_KDH], c[_C_KDH:_C_FFG], c[s + 7] > 0.5,
            c[s + 1], c[s + 2], c[s + 3], c[s + 4], c[s + 5], c[_C_MAXDQ:_C_MAXSTEP],
            c[_C_MAXSTEP:_C_MAXCHANGE], c[_C_MAXCHANGE:_C_SCALARS], c[_C_FFG:_C_MAXDQ],
            int(c[s + 6]), c[s + 8] > 0.5, c[s + 9] > 0.5)


@njit(cache=True, fastmath=False)
def vfdm_cycle_packed(T, c, x, last_e):
    """:func:`vfdm_cycle` on a :class:`Vfdm`'s two buffers: c its constants, x its state
    (q, qd, e_prev, has_prev, step_prev, ff, R_prev, p_prev), towards the target pose
    T (4, 4); with ``velocity_mode = "reset"`` the virtual arm first stops (Eq. 11).
    Returns the uniform scale the speed limit put on the joint step."""
    (pR, pp, mass, lever, Icom, tR, tp, armature, kp, kdh, use_kd, keep, h, qlim, max_lin,
     max_rot, max_dq, max_step, max_change, ff_gain, iterations, reset_velocity,
     _) = vfdm_constants(c)
    q, qd = x[_X_Q:_X_QD], x[_X_QD:_X_EP]
    if reset_velocity:
        for i in range(6):
            qd[i] = 0.0
    Rt, pt = np.empty((3, 3)), np.empty(3)
    for a in range(3):
        pt[a] = T[a, 3]
        for b in range(3):
            Rt[a, b] = T[a, b]
    return vfdm_cycle(q, qd, x[_X_EP:_X_HP], x[_X_HP:_X_SP], last_e, Rt, pt, iterations,
                      pR, pp, mass, lever, Icom, tR, tp, armature, kp, kdh, use_kd,
                      x[_X_FF:_X_RP], keep, h, qlim, max_lin, max_rot, max_dq,
                      x[_X_SP:_X_FF], max_step, max_change, ff_gain,
                      x[_X_RP:_X_PP].reshape((3, 3)), x[_X_PP:N_STATE])


# --- the solver ---------------------------------------------------------------------------


def pose_error(T_B_target: np.ndarray, T_B_C: np.ndarray) -> np.ndarray:
    """Pose error ``e = [p* − p ; log(R* Rᵀ)]`` in base axes (the e of Eq. 13), unclamped."""
    e = np.empty(6)
    e[:3] = T_B_target[:3, 3] - T_B_C[:3, 3]
    e[3:] = log3(np.ascontiguousarray(T_B_target[:3, :3] @ T_B_C[:3, :3].T))
    return e


def joint_acceleration(arm: VirtualArm, q_rad: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Eq. 10: ``q̈ = H(q)⁻¹ τ`` of the virtual model (no gravity, no Coriolis; H with the
    joints' armature)."""
    qdd = np.empty(N_JOINTS)
    _joint_acceleration(np.asarray(q_rad, dtype=float), np.asarray(tau, dtype=float),
                        arm.pR, arm.pp, arm.mass, arm.lever, arm.Icom, arm.armature, qdd)
    return qdd


class Vfdm:
    """One robot's VFDM solver: ``reset(q)`` once, then ``solve(T_B_C_target)`` per cycle.

    ``limits``: the servo's joint speed and acceleration limits and the control cycle that
    the set-points must respect (default: the UR10e's at 500 Hz; None: no limits, for a
    search on the virtual model only).
    """

    def __init__(
        self,
        cfg: VfdmConfig,
        T_F_C: np.ndarray,
        q0_rad: np.ndarray | None = None,
        limits: JointLimits | None = UR10E_LIMITS_500HZ,
    ) -> None:
        self.cfg = cfg
        self.limits = limits
        if limits is None:  # a virtual-only search (e.g. for a start posture): no limits
            self._max_step = self._max_change = np.full(N_JOINTS, np.inf)
        else:
            f, dt = cfg.limit_fraction, limits.cycle_s
            self._max_step = f * np.asarray(limits.speed_radps, dtype=float) * dt
            self._max_change = np.full(N_JOINTS, f * limits.accel_radps2 * dt * dt)
        self._max_dq = self._max_step / cfg.iterations
        self.last_scale = 1.0
        """Uniform scale the speed limit put on the last cycle's joint step (1.0: none)."""
        self.T_F_C = np.array(T_F_C, dtype=float)
        self.arm = virtual_arm(cfg, self.T_F_C)
        h = cfg.internal_dt_s
        self._h = h
        # Eq. 13 gains, already multiplied by the error scale; D acts on (e - e_prev) / h.
        s = cfg.error_scale
        self._kp = s * np.array([cfg.kp_lin] * 3 + [cfg.kp_rot] * 3)
        self._kd_over_h = s * np.array([cfg.kd_lin] * 3 + [cfg.kd_rot] * 3) / h
        self._use_kd = bool(np.any(self._kd_over_h))
        self._keep = 1.0 - cfg.damping if cfg.velocity_mode == "damped" else 1.0
        # target-velocity feedforward (target_feedforward): Λ / (N h) · (1 − k) / (k h)
        lam = np.array([cfg.end_mass_kg] * 3 + [cfg.end_inertia_kgm2] * 3)
        drag = (1.0 - self._keep) / (self._keep * h) if cfg.velocity_feedforward else 0.0
        self._ff_gain = lam * drag / (cfg.iterations * h)
        self.constants = self._pack_constants()
        """(N_CONSTANTS,) everything a cycle reads and never writes, in one buffer (one
        argument of the compiled cycle instead of two dozen): :func:`vfdm_constants`."""
        self._x = np.zeros(N_STATE)
        """The state a cycle carries to the next, in one buffer: q, q̇, the last error and
        whether there is one (the D term), the last step, the feedforward wrench and the
        last target (R, p); the attributes below are views of it."""
        self._R_prev[:] = np.eye(3)
        self.last_error = np.zeros(6)
        """Clamped pose error [m; rad] seen by the last internal step (before its move)."""
        self.reset(np.zeros(N_JOINTS) if q0_rad is None else q0_rad)

    def _pack_constants(self) -> np.ndarray:
        cfg, arm = self.cfg, self.arm
        scalars = [arm.armature, self._keep, self._h, POSITION_LIMIT_RAD, cfg.max_error_lin_m,
                   cfg.max_error_rot_rad, cfg.iterations, self._use_kd,
                   cfg.velocity_mode == "reset", cfg.sync_to_measured]
        c = np.concatenate([np.ravel(a) for a in (
            arm.pR, arm.pp, arm.mass, arm.lever, arm.Icom, arm.tR, arm.tp, self._kp,
            self._kd_over_h, self._ff_gain, self._max_dq, self._max_step, self._max_change,
            np.array(scalars, dtype=float))])
        assert c.shape == (N_CONSTANTS,)
        return c

    # the state, as views of the one buffer (a deep copy copies the buffer, not the views)
    q_rad = property(lambda self: self._x[_X_Q:_X_QD],
                     lambda self, v: self._x.__setitem__(slice(_X_Q, _X_QD), v),
                     doc="(6,) the virtual joints [rad].")
    qd_radps = property(lambda self: self._x[_X_QD:_X_EP],
                        lambda self, v: self._x.__setitem__(slice(_X_QD, _X_EP), v),
                        doc="(6,) the virtual joint velocities [rad/s].")
    _e_prev = property(lambda self: self._x[_X_EP:_X_HP])
    _has_prev = property(lambda self: self._x[_X_HP:_X_SP],
                         doc="[an e_prev (D term), a last target (feedforward)]")
    _step_prev = property(lambda self: self._x[_X_SP:_X_FF])
    _ff = property(lambda self: self._x[_X_FF:_X_RP])
    _R_prev = property(lambda self: self._x[_X_RP:_X_PP].reshape(3, 3))
    _p_prev = property(lambda self: self._x[_X_PP:N_STATE])

    def reset(self, q_rad: np.ndarray) -> None:
        """Put the virtual arm at ``q_rad``, at rest."""
        self.q_rad = np.clip(np.array(q_rad, dtype=float), -POSITION_LIMIT_RAD,
                             POSITION_LIMIT_RAD)
        self.qd_radps[:] = 0.0
        self._has_prev[:] = 0.0
        self._step_prev[:] = 0.0

    def tcp_pose(self) -> np.ndarray:
        """Virtual TCP pose ``T_B_C`` at the current virtual ``q``."""
        return tcp_pose_B(self.q_rad, self.T_F_C)

    def solve(self, T_B_C_target: np.ndarray) -> np.ndarray:
        """One control cycle: ``iterations`` internal steps; returns the joint set-points."""
        last_e = np.empty(6)
        self.last_scale = vfdm_cycle_packed(np.ascontiguousarray(T_B_C_target, dtype=float),
                                            self.constants, self._x, last_e)
        self.last_error = last_e
        return self.q_rad.copy()
