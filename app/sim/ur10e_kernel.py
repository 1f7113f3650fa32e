"""Compiled (numba) forward kinematics of the 6-revolute UR10e chain, same maths as UR10e.

The chain's numbers (joint placements, the placement of a frame on the last joint) are
read from a pinocchio model built by :func:`app.sim.ur10e.build_model`, so the kernels
and the pinocchio reference path share one source. Used by the loop (mockup pose and
twist of each arm), by the servo (the safety-box TCP check) and by the VFDM kernel.

Joint i turns about z of its frame: ``R_i = R_{i-1} · Rp_i · Rz(q_i)``, ``p_i = p_{i-1} +
R_{i-1} · pp_i``; all results are in the base frame B unless named otherwise.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["TcpChain", "fk_joints", "mockup_state", "tcp_chain", "tcp_position_W"]


class TcpChain(NamedTuple):
    """Everything the kernels need to place a TCP of a UR10e mounted in the lab."""

    pR: np.ndarray
    """(6, 3, 3) joint placement rotations (joint i in the frame of joint i-1)."""
    pp: np.ndarray
    """(6, 3) joint placement translations."""
    fR: np.ndarray
    """(3, 3) rotation of the end frame (flange) in the frame of joint 6."""
    fp: np.ndarray
    """(3,) translation of the end frame in the frame of joint 6."""
    T_W_B: np.ndarray
    """(4, 4) base pose in the lab."""
    T_F_C: np.ndarray
    """(4, 4) TCP (mockup COM) in the end frame."""


def tcp_chain(model, frame_id: int, T_W_B: np.ndarray, T_F_C: np.ndarray) -> TcpChain:
    """The :class:`TcpChain` of a pinocchio UR10e model, ending at frame ``frame_id``."""
    n = 6
    pR, pp = np.zeros((n, 3, 3)), np.zeros((n, 3))
    for i in range(n):
        M = model.jointPlacements[i + 1]
        pR[i], pp[i] = M.rotation, M.translation
    F = model.frames[frame_id].placement
    return TcpChain(
        pR, pp, np.array(F.rotation), np.array(F.translation),
        np.ascontiguousarray(T_W_B, dtype=float), np.ascontiguousarray(T_F_C, dtype=float),
    )


@njit(cache=True, fastmath=False)
def fk_joints(q, pR, pp, R, p):
    """Joint frames in B: fills R (6, 3, 3) and p (6, 3) for the joint positions q."""
    for i in range(6):
        c, s = math.cos(q[i]), math.sin(q[i])
        for a in range(3):
            if i == 0:
                r0, r1, r2 = pR[0, a, 0], pR[0, a, 1], pR[0, a, 2]
                p[0, a] = pp[0, a]
            else:
                r0 = r1 = r2 = 0.0
                pa = p[i - 1, a]
                for b in range(3):
                    rab = R[i - 1, a, b]
                    r0 += rab * pR[i, b, 0]
                    r1 += rab * pR[i, b, 1]
                    r2 += rab * pR[i, b, 2]
                    pa += rab * pp[i, b]
                p[i, a] = pa
            R[i, a, 0] = c * r0 + s * r1
            R[i, a, 1] = -s * r0 + c * r1
            R[i, a, 2] = r2


@njit(cache=True, fastmath=False)
def _end_frame(R, p, fR, fp, T):
    """T (4, 4) := the end frame in B, from the joint frames (fills the upper 3 rows)."""
    for a in range(3):
        pa = p[5, a]
        for b in range(3):
            pa += R[5, a, b] * fp[b]
            T[a, b] = R[5, a, 0] * fR[0, b] + R[5, a, 1] * fR[1, b] + R[5, a, 2] * fR[2, b]
        T[a, 3] = pa


@njit(cache=True, fastmath=False)
def _compose(A, B, out):
    """out (4, 4) := A · B for rigid transforms (bottom rows 0 0 0 1)."""
    for a in range(3):
        for b in range(4):
            v = A[a, 0] * B[0, b] + A[a, 1] * B[1, b] + A[a, 2] * B[2, b]
            if b == 3:
                v += A[a, 3]
            out[a, b] = v
    out[3, 0] = out[3, 1] = out[3, 2] = 0.0
    out[3, 3] = 1.0


@njit(cache=True, fastmath=False)
def tcp_position_W(q, pR, pp, fR, fp, T_W_B, T_F_C, out):
    """out (3,) := TCP position in W, ``(T_W_B · T_B_F(q) · T_F_C)[:3, 3]``."""
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    T_B_F = np.empty((4, 4))
    T_W_F = np.empty((4, 4))
    fk_joints(q, pR, pp, R, p)
    _end_frame(R, p, fR, fp, T_B_F)
    _compose(T_W_B, T_B_F, T_W_F)
    for a in range(3):
        out[a] = (T_W_F[a, 0] * T_F_C[0, 3] + T_W_F[a, 1] * T_F_C[1, 3]
                  + T_W_F[a, 2] * T_F_C[2, 3] + T_W_F[a, 3])


@njit(cache=True, fastmath=False)
def mockup_state(q, qd, pR, pp, fR, fp, T_W_B, T_F_C, T_W_F, T_W_C, v_W, w_W):
    """Flange and TCP poses in W, TCP linear and angular velocity in W (all filled in).

    The twist is the flange Jacobian's (columns ``[z_i × (p_F − p_i); z_i]``) times qd,
    shifted to the TCP: ``v_C = v_F − p_FC × ω`` (as UR10e.tcp_jacobian), then rotated by
    R_W_B.
    """
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    T_B_F = np.empty((4, 4))
    fk_joints(q, pR, pp, R, p)
    _end_frame(R, p, fR, fp, T_B_F)
    _compose(T_W_B, T_B_F, T_W_F)
    _compose(T_W_F, T_F_C, T_W_C)
    vx = vy = vz = wx = wy = wz = 0.0
    for i in range(6):
        dx, dy, dz = T_B_F[0, 3] - p[i, 0], T_B_F[1, 3] - p[i, 1], T_B_F[2, 3] - p[i, 2]
        zx, zy, zz = R[i, 0, 2], R[i, 1, 2], R[i, 2, 2]
        vx += (zy * dz - zz * dy) * qd[i]
        vy += (zz * dx - zx * dz) * qd[i]
        vz += (zx * dy - zy * dx) * qd[i]
        wx += zx * qd[i]
        wy += zy * qd[i]
        wz += zz * qd[i]
    # p_FC in B: R_B_F · p_FC_F
    rx = T_B_F[0, 0] * T_F_C[0, 3] + T_B_F[0, 1] * T_F_C[1, 3] + T_B_F[0, 2] * T_F_C[2, 3]
    ry = T_B_F[1, 0] * T_F_C[0, 3] + T_B_F[1, 1] * T_F_C[1, 3] + T_B_F[1, 2] * T_F_C[2, 3]
    rz = T_B_F[2, 0] * T_F_C[0, 3] + T_B_F[2, 1] * T_F_C[1, 3] + T_B_F[2, 2] * T_F_C[2, 3]
    vx -= ry * wz - rz * wy
    vy -= rz * wx - rx * wz
    vz -= rx * wy - ry * wx
    for a in range(3):
        v_W[a] = T_W_B[a, 0] * vx + T_W_B[a, 1] * vy + T_W_B[a, 2] * vz
        w_W[a] = T_W_B[a, 0] * wx + T_W_B[a, 1] * wy + T_W_B[a, 2] * wz
