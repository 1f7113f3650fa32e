"""UR10e kinematics from the official DH parameters, compiled with numba.

Frames (DESIGN.md "Frames"):

* ``B`` — robot base, DH frame 0 (= the UR controller's "Base" and the URDF link ``base``);
* ``F`` — flange, DH frame 6 (= URDF ``tool0``);
* ``C`` — mockup centre of mass = TCP; ``T_F_C`` is the mockup mounting (RobotConfig).

Joint i (1-based) turns about z of DH frame i-1, so the standard DH link transform
``Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` splits into the joint rotation and a constant
placement ``Tz(d_i) Tx(a_i) Rx(alpha_i)``: the placement of joint i+1 in the frame of joint
i (or of the flange in the frame of joint 6). With those placements the chain is

    R_i = R_{i-1} · Rp_i · Rz(q_i),   p_i = p_{i-1} + R_{i-1} · pp_i

and every result below is in the base frame B unless its name says otherwise. A joint's
Jacobian column at a point c is ``[z_i × (c − p_i); z_i]``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from app.config import UR10E_SPEED_LIMITS_RADPS, RobotConfig
from app.sim.rotations import make_transform, quat_to_matrix

__all__ = [
    "CHAIN_SIZE",
    "DH_A_M",
    "DH_ALPHA_RAD",
    "DH_D_M",
    "JOINT_NAMES",
    "MAX_EFFORT_NM",
    "N_JOINTS",
    "POSITION_LIMIT_RAD",
    "SPEED_LIMITS_RADPS",
    "TcpChain",
    "chain_constants",
    "chain_views",
    "T_F_C_from_config",
    "T_J6_F",
    "T_W_B_from_config",
    "dh_link_transform",
    "flange_pose_B",
    "joint_placements",
    "mockup_state",
    "tcp_chain",
    "tcp_jacobian_B",
    "tcp_pose_B",
    "tcp_position_W",
]

N_JOINTS = 6
DH_D_M = (0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655)
DH_A_M = (0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0)
DH_ALPHA_RAD = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
SHOULDER_B_M = (0.0, 0.0, DH_D_M[0])
"""Where joints 1 and 2's axes meet, in the base frame: the centre of the arm's reach."""
HOLD_RADIUS_M = 1.2
"""How far from the shoulder the arm can hold a mockup's centre (the datasheet's 1.3 m
reach to the flange, less the mockup's offset and a margin for its attitude): beyond it
the arm falls behind its satellite and stops on its tracking error."""
POSITION_LIMIT_RAD = 2.0 * math.pi
SPEED_LIMITS_RADPS = np.array(UR10E_SPEED_LIMITS_RADPS)
MAX_EFFORT_NM = (330.0, 330.0, 150.0, 56.0, 56.0, 56.0)
JOINT_NAMES = (
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
    "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
)


def dh_link_transform(theta_rad: float, d_m: float, a_m: float, alpha_rad: float) -> np.ndarray:
    """Standard DH link transform ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` (4x4)."""
    ct, st = math.cos(theta_rad), math.sin(theta_rad)
    ca, sa = math.cos(alpha_rad), math.sin(alpha_rad)
    return np.array(
        [
            [ct, -st * ca, st * sa, a_m * ct],
            [st, ct * ca, -ct * sa, a_m * st],
            [0.0, sa, ca, d_m],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _dh_placement(i: int) -> np.ndarray:
    """``Tz(d_i) Tx(a_i) Rx(alpha_i)`` of link i (0-based), the joint angle left out."""
    return dh_link_transform(0.0, DH_D_M[i], DH_A_M[i], DH_ALPHA_RAD[i])


T_J6_F = _dh_placement(5)
"""The flange (DH frame 6) in the frame of joint 6 (DH frame 5)."""


def joint_placements() -> tuple[np.ndarray, np.ndarray]:
    """(Rp (6, 3, 3), pp (6, 3)): joint i+1 placed in the frame of joint i; joint 1 at B."""
    Rp, pp = np.zeros((N_JOINTS, 3, 3)), np.zeros((N_JOINTS, 3))
    Rp[0] = np.eye(3)
    for i in range(1, N_JOINTS):
        T = _dh_placement(i - 1)
        Rp[i], pp[i] = T[:3, :3], T[:3, 3]
    return Rp, pp


class TcpChain(NamedTuple):
    """Everything the kernels need to place the TCP of a UR10e mounted in the lab."""

    pR: np.ndarray
    """(6, 3, 3) joint placement rotations (joint i in the frame of joint i-1)."""
    pp: np.ndarray
    """(6, 3) joint placement translations."""
    fR: np.ndarray
    """(3, 3) rotation of the flange in the frame of joint 6."""
    fp: np.ndarray
    """(3,) translation of the flange in the frame of joint 6."""
    T_W_B: np.ndarray
    """(4, 4) base pose in the lab."""
    T_F_C: np.ndarray
    """(4, 4) TCP (mockup COM) in the flange frame."""


def tcp_chain(T_W_B: np.ndarray | None = None, T_F_C: np.ndarray | None = None) -> TcpChain:
    """The :class:`TcpChain` of a UR10e with its base at T_W_B and its TCP at T_F_C."""
    pR, pp = joint_placements()
    return TcpChain(
        pR, pp, np.ascontiguousarray(T_J6_F[:3, :3]), np.ascontiguousarray(T_J6_F[:3, 3]),
        np.ascontiguousarray(np.eye(4) if T_W_B is None else T_W_B, dtype=float),
        np.ascontiguousarray(np.eye(4) if T_F_C is None else T_F_C, dtype=float),
    )


CHAIN_SIZE = 116
"""A TCP chain in one buffer: pR (54), pp (18), fR (9), fp (3), T_W_B (16), T_F_C (16)."""


def chain_constants(chain: TcpChain) -> np.ndarray:
    """(CHAIN_SIZE,) the chain's arrays, one after the other (:func:`chain_views`)."""
    c = np.concatenate([np.ravel(a) for a in chain]).astype(float)
    assert c.shape == (CHAIN_SIZE,)
    return c


# --- kernels ------------------------------------------------------------------------------


@njit(cache=True, fastmath=False, inline="always")
def chain_views(c):
    """(pR, pp, fR, fp, T_W_B, T_F_C) of a :func:`chain_constants` buffer."""
    return (c[0:54].reshape((6, 3, 3)), c[54:72].reshape((6, 3)), c[72:81].reshape((3, 3)),
            c[81:84], c[84:100].reshape((4, 4)), c[100:116].reshape((4, 4)))


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
def end_frame(R, p, fR, fp, T):
    """T (4, 4) := a frame fixed on joint 6 (placement fR, fp) in B (upper 3 rows)."""
    for a in range(3):
        pa = p[5, a]
        for b in range(3):
            pa += R[5, a, b] * fp[b]
            T[a, b] = R[5, a, 0] * fR[0, b] + R[5, a, 1] * fR[1, b] + R[5, a, 2] * fR[2, b]
        T[a, 3] = pa


@njit(cache=True, fastmath=False)
def compose(A, B, out):
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
def jacobian_at(R, p, c, J):
    """J (6, 6) := the geometric Jacobian at point c (B), rows [v; ω] in base axes."""
    for i in range(6):
        dx, dy, dz = c[0] - p[i, 0], c[1] - p[i, 1], c[2] - p[i, 2]
        zx, zy, zz = R[i, 0, 2], R[i, 1, 2], R[i, 2, 2]
        J[0, i] = zy * dz - zz * dy
        J[1, i] = zz * dx - zx * dz
        J[2, i] = zx * dy - zy * dx
        J[3, i], J[4, i], J[5, i] = zx, zy, zz


@njit(cache=True, fastmath=False)
def _flange_pose(q, pR, pp, fR, fp, T_B_F):
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    fk_joints(q, pR, pp, R, p)
    end_frame(R, p, fR, fp, T_B_F)
    T_B_F[3, 0] = T_B_F[3, 1] = T_B_F[3, 2] = 0.0
    T_B_F[3, 3] = 1.0


@njit(cache=True, fastmath=False)
def _tcp_jacobian(q, pR, pp, fR, fp, T_F_C, J):
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    T_B_F = np.empty((4, 4))
    fk_joints(q, pR, pp, R, p)
    end_frame(R, p, fR, fp, T_B_F)
    c = np.empty(3)
    for a in range(3):
        c[a] = (T_B_F[a, 0] * T_F_C[0, 3] + T_B_F[a, 1] * T_F_C[1, 3]
                + T_B_F[a, 2] * T_F_C[2, 3] + T_B_F[a, 3])
    jacobian_at(R, p, c, J)


@njit(cache=True, fastmath=False)
def tcp_position_W(q, pR, pp, fR, fp, T_W_B, T_F_C, out):
    """out (3,) := TCP position in W, ``(T_W_B · T_B_F(q) · T_F_C)[:3, 3]``."""
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    T_B_F = np.empty((4, 4))
    T_W_F = np.empty((4, 4))
    fk_joints(q, pR, pp, R, p)
    end_frame(R, p, fR, fp, T_B_F)
    compose(T_W_B, T_B_F, T_W_F)
    for a in range(3):
        out[a] = (T_W_F[a, 0] * T_F_C[0, 3] + T_W_F[a, 1] * T_F_C[1, 3]
                  + T_W_F[a, 2] * T_F_C[2, 3] + T_W_F[a, 3])


@njit(cache=True, fastmath=False)
def mockup_state(q, qd, pR, pp, fR, fp, T_W_B, T_F_C, T_W_F, T_W_C, v_W, w_W):
    """Flange and TCP poses in W, TCP linear and angular velocity in W (all filled in).

    The twist is the flange Jacobian's (columns ``[z_i × (p_F − p_i); z_i]``) times qd,
    shifted to the TCP: ``v_C = v_F + ω × p_FC``, then rotated by R_W_B.
    """
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    T_B_F = np.empty((4, 4))
    fk_joints(q, pR, pp, R, p)
    end_frame(R, p, fR, fp, T_B_F)
    compose(T_W_B, T_B_F, T_W_F)
    compose(T_W_F, T_F_C, T_W_C)
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


# --- plain functions for callers outside the loop (baselines, benchmarks, tests) -----------

_CHAIN = tcp_chain()


def flange_pose_B(q_rad: np.ndarray) -> np.ndarray:
    """Flange pose ``T_B_F`` (4x4) at the joint positions q_rad."""
    T = np.empty((4, 4))
    c = _CHAIN
    _flange_pose(np.asarray(q_rad, dtype=float), c.pR, c.pp, c.fR, c.fp, T)
    return T


def tcp_pose_B(q_rad: np.ndarray, T_F_C: np.ndarray) -> np.ndarray:
    """TCP (mockup COM) pose ``T_B_C = T_B_F T_F_C``."""
    return flange_pose_B(q_rad) @ T_F_C


def tcp_jacobian_B(q_rad: np.ndarray, T_F_C: np.ndarray) -> np.ndarray:
    """6x6 geometric Jacobian of the TCP, rows ``[v_C; ω]`` in base axes."""
    J = np.empty((6, 6))
    c = _CHAIN
    _tcp_jacobian(np.asarray(q_rad, dtype=float), c.pR, c.pp, c.fR, c.fp,
                  np.ascontiguousarray(T_F_C, dtype=float), J)
    return J


# --- mounting -------------------------------------------------------------------------------


def T_W_B_from_config(robot: RobotConfig) -> np.ndarray:
    """Base pose in the lab, ``T_W_B``, from ``base_position_m`` / ``base_attitude_wxyz``."""
    return make_transform(quat_to_matrix(robot.base_attitude_wxyz), robot.base_position_m)


def T_F_C_from_config(robot: RobotConfig) -> np.ndarray:
    """Mockup mounting ``T_F_C``; the attitude quaternion is read as ``q_F_C`` (C -> F)."""
    return make_transform(quat_to_matrix(robot.mockup_attitude_wxyz), robot.mockup_offset_m)
