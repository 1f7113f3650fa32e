"""Compiled (numba) VFDM inner loop for the 6-joint UR10e chain, same maths as Vfdm._step.

One call runs all ``iterations`` internal steps of a control cycle without leaving
machine code: forward kinematics through the model's joint placements, the TCP Jacobian
(LOCAL_WORLD_ALIGNED), the Eq. 13 force, ``H^-1 J^T f`` from the joint-space inertia
(composite-rigid-body algorithm in the world frame, then a 6x6 Cholesky solve; equal to
pinocchio's ABA at zero velocity up to rounding) and the semi-implicit Euler step with
the joint-limit clamp. The model's numbers (placements, inertias, TCP frame) are read
from the pinocchio model, so the kernel and the reference path share one source.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.sim.ur10e_kernel import fk_joints

__all__ = ["model_arrays", "vfdm_steps", "log3"]


def model_arrays(model, tcp_id: int):
    """(placement R (6,3,3), placement p (6,3), mass (6), lever (6,3), I_com (6,3,3),
    tcp R (3,3), tcp p (3)) of a 6-revolute-z chain pinocchio model."""
    n = 6
    pR, pp = np.zeros((n, 3, 3)), np.zeros((n, 3))
    m, c, inertia = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3, 3))
    for i in range(n):
        M = model.jointPlacements[i + 1]
        pR[i], pp[i] = M.rotation, M.translation
        Y = model.inertias[i + 1]
        m[i], c[i], inertia[i] = Y.mass, Y.lever, Y.inertia
    F = model.frames[tcp_id].placement
    return pR, pp, m, c, inertia, np.array(F.rotation), np.array(F.translation)


@njit(cache=True, fastmath=False)
def log3(R):
    """SO(3) logarithm (rotation vector) of a rotation matrix."""
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


@njit(cache=True, fastmath=False)
def _clamp(v, max_norm):
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if n > max_norm:
        s = max_norm / n
        v[0] *= s
        v[1] *= s
        v[2] *= s


@njit(cache=True, fastmath=False)
def vfdm_steps(q, qd, e_prev, state, last_e, Rt, pt, iterations,
               pR, pp, mass, lever, Icom, tR, tp, kp, kdh, use_kd, keep, h, qlim,
               max_lin, max_rot):
    """Run ``iterations`` internal VFDM steps in place on q, qd, e_prev, last_e.

    state[0] is 1.0 when e_prev holds a previous error (the D term is active), else 0.0.
    """
    n = 6
    R = np.empty((n, 3, 3))
    p = np.empty((n, 3))
    z = np.empty((n, 3))
    J = np.empty((6, n))
    H = np.zeros((n, n))
    e = np.empty(6)
    f = np.empty(6)
    tau = np.empty(n)
    Rc = np.empty((3, 3))
    pc = np.empty(3)
    Rerr = np.empty((3, 3))
    s_acc = np.empty(3)
    IO = np.empty((3, 3))
    vS = np.empty((n, 3))
    cw = np.empty(3)
    RI = np.empty((3, 3))
    L = np.zeros((n, n))
    y = np.empty(n)
    qdd = np.empty(n)
    for _ in range(iterations):
        # --- forward kinematics (no temporaries)
        fk_joints(q, pR, pp, R, p)
        for i in range(n):
            for a in range(3):
                z[i, a] = R[i, a, 2]
        R6 = R[n - 1]
        for a in range(3):
            pa = p[n - 1, a]
            for b in range(3):
                pa += R6[a, b] * tp[b]
                Rc[a, b] = R6[a, 0] * tR[0, b] + R6[a, 1] * tR[1, b] + R6[a, 2] * tR[2, b]
            pc[a] = pa
        # --- Eq. 13 force on the clamped pose error
        for a in range(3):
            e[a] = pt[a] - pc[a]
        _clamp(e[:3], max_lin)
        for a in range(3):
            for b in range(3):
                Rerr[a, b] = Rt[a, 0] * Rc[b, 0] + Rt[a, 1] * Rc[b, 1] + Rt[a, 2] * Rc[b, 2]
        w = log3(Rerr)
        _clamp(w, max_rot)
        e[3], e[4], e[5] = w[0], w[1], w[2]
        for a in range(6):
            f[a] = kp[a] * e[a]
        if use_kd and state[0] > 0.5:
            for a in range(6):
                f[a] += kdh[a] * (e[a] - e_prev[a])
        for a in range(6):
            e_prev[a] = e[a]
            last_e[a] = e[a]
        state[0] = 1.0
        # --- TCP Jacobian (base axes) and tau = J^T f
        for i in range(n):
            dx, dy, dz = pc[0] - p[i, 0], pc[1] - p[i, 1], pc[2] - p[i, 2]
            zx, zy, zz = z[i, 0], z[i, 1], z[i, 2]
            J[0, i] = zy * dz - zz * dy
            J[1, i] = zz * dx - zx * dz
            J[2, i] = zx * dy - zy * dx
            J[3, i], J[4, i], J[5, i] = zx, zy, zz
            t = 0.0
            for a in range(6):
                t += J[a, i] * f[a]
            tau[i] = t
        # --- CRBA in the world frame: H[i, j] = S_i . (I^c_j S_j), i <= j
        m_acc = 0.0
        for a in range(3):
            s_acc[a] = 0.0
            for b in range(3):
                IO[a, b] = 0.0
        for i in range(n):  # S_i linear part at the origin: p_i x z_i
            vS[i, 0] = p[i, 1] * z[i, 2] - p[i, 2] * z[i, 1]
            vS[i, 1] = p[i, 2] * z[i, 0] - p[i, 0] * z[i, 2]
            vS[i, 2] = p[i, 0] * z[i, 1] - p[i, 1] * z[i, 0]
        for j in range(n - 1, -1, -1):
            mj = mass[j]
            for a in range(3):
                ca = p[j, a]
                for b in range(3):
                    ca += R[j, a, b] * lever[j, b]
                cw[a] = ca
            for a in range(3):  # RI = R_j I_com
                for b in range(3):
                    RI[a, b] = (R[j, a, 0] * Icom[j, 0, b] + R[j, a, 1] * Icom[j, 1, b]
                                + R[j, a, 2] * Icom[j, 2, b])
            cc = cw[0] * cw[0] + cw[1] * cw[1] + cw[2] * cw[2]
            for a in range(3):
                for b in range(3):
                    iw = RI[a, 0] * R[j, b, 0] + RI[a, 1] * R[j, b, 1] + RI[a, 2] * R[j, b, 2]
                    IO[a, b] += iw - mj * cw[a] * cw[b]
                IO[a, a] += mj * cc
                s_acc[a] += mj * cw[a]
            m_acc += mj
            wx, wy, wz = z[j, 0], z[j, 1], z[j, 2]
            vx, vy, vz = vS[j, 0], vS[j, 1], vS[j, 2]
            sx, sy, sz = s_acc[0], s_acc[1], s_acc[2]
            lx = m_acc * vx + (wy * sz - wz * sy)
            ly = m_acc * vy + (wz * sx - wx * sz)
            lz = m_acc * vz + (wx * sy - wy * sx)
            ax = (sy * vz - sz * vy) + IO[0, 0] * wx + IO[0, 1] * wy + IO[0, 2] * wz
            ay = (sz * vx - sx * vz) + IO[1, 0] * wx + IO[1, 1] * wy + IO[1, 2] * wz
            az = (sx * vy - sy * vx) + IO[2, 0] * wx + IO[2, 1] * wy + IO[2, 2] * wz
            for i in range(j + 1):
                hij = vS[i, 0] * lx + vS[i, 1] * ly + vS[i, 2] * lz
                hij += z[i, 0] * ax + z[i, 1] * ay + z[i, 2] * az
                H[i, j] = hij
                H[j, i] = hij
        # --- qdd = H^-1 tau (Cholesky)
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
            s = tau[i]
            for m in range(i):
                s -= L[i, m] * y[m]
            y[i] = s / L[i, i]
        for i in range(n - 1, -1, -1):
            s = y[i]
            for m in range(i + 1, n):
                s -= L[m, i] * qdd[m]
            qdd[i] = s / L[i, i]
        # --- semi-implicit Euler, joint-limit clamp
        for i in range(n):
            qd[i] += h * qdd[i]
            qd[i] *= keep
            q[i] += h * qd[i]
        for i in range(n):
            if abs(q[i]) > qlim:
                q[i] = qlim if q[i] > 0 else -qlim
                qd[i] = 0.0


def solve_compiled(vfdm, T_B_C_target: np.ndarray) -> np.ndarray:
    """``Vfdm.solve`` through the compiled kernel (same state, same result to rounding)."""
    cfg = vfdm.cfg
    arrays = getattr(vfdm, "_kernel_arrays", None)
    if arrays is None:
        arrays = model_arrays(vfdm.model, vfdm.tcp_id)
        vfdm._kernel_arrays = arrays
        vfdm._kernel_state = np.zeros(1)
        vfdm._kernel_e_prev = np.zeros(6)
    if cfg.velocity_mode == "reset":
        vfdm.qd_radps[:] = 0.0
    state, e_prev = vfdm._kernel_state, vfdm._kernel_e_prev
    if vfdm._e_prev is None:
        state[0] = 0.0
    else:
        state[0] = 1.0
        e_prev[:] = vfdm._e_prev
    last_e = np.empty(6)
    T = np.asarray(T_B_C_target, dtype=float)
    vfdm_steps(vfdm.q_rad, vfdm.qd_radps, e_prev, state, last_e,
               np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
               cfg.iterations, *arrays, vfdm._kp, vfdm._kd_over_h, vfdm._use_kd,
               vfdm._keep, vfdm._h, float(vfdm._q_lim), cfg.max_error_lin_m,
               cfg.max_error_rot_rad)
    vfdm.last_error = last_e
    vfdm._e_prev = last_e.copy()
    return vfdm.q_rad.copy()
